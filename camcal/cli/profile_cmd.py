"""``camcal profile show|diff``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from camcal.cli.common import console, print_json


def _fmt(v) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.5g}"
    return str(v)


def print_contract(c: dict, title: str = "profile") -> None:
    """A human summary of the contract object (one table per calibrated stage)."""
    cam = c["camera"]
    console.print(f"[bold]{title}[/bold]: {cam['make']} {cam['model']} (serial {cam['serial']}), "
                  f"{cam['cfa_pattern']} {cam['width']}x{cam['height']}, reference ISO {c['reference']['iso']:g} "
                  f"f/{c['reference']['f_number']:g}, schema {c['schema_version']}")
    rows = []
    if c["dark"]:
        d = c["dark"]
        rows += [("bias", "DN", d["bias_dn"]), ("dark current β", "DN/s", d["dark_current_dn_per_s"]),
                 ("read noise", "DN", d["read_noise_dn"])]
    if c["flat"]:
        rows += [("corner gain", "", c["flat"]["corner_gain"]), ("PRNU", "rel.", c["flat"]["prnu_rms"])]
    if c["response"]:
        r = c["response"]
        rows += [(f"γ ({r['kind']})", "", r["gamma"]), (f"α ({r['kind']})", "", r["alpha"])]
        for k, m in r["models"].items():
            if k != r["kind"]:
                rows += [(f"γ ({k})", "", m["gamma"])]
    if c["spectral_sensitivity"]:
        s = c["spectral_sensitivity"]
        rows += [("peak λ", "nm", s["peak_wavelength_nm"]), ("effective λ", "nm", s["effective_wavelength_nm"])]
    table = Table(show_header=True, title_justify="left")
    for col in ("quantity", "unit", "R", "G", "B"):
        table.add_column(col, justify="left" if col in ("quantity", "unit") else "right")
    for name, unit, vals in rows:
        table.add_row(name, unit, *(_fmt((vals or {}).get(ch)) for ch in ("R", "G", "B")))
    console.print(table)
    stages = [k for k in ("dark", "flat", "response", "spectral_sensitivity") if c[k] is None]
    if stages:
        console.print(f"not calibrated: {', '.join(stages)}")
    if c["dark"]:
        d = c["dark"]
        console.print(f"defects: hot pixels {d['hot_pixel_count']}, dead pixels {d['dead_pixel_count']}, "
                      f"noisy pixels {d['noisy_pixel_count']}")
        if not d.get("dark_current_known", True):
            console.print("dark current: unknown (bias-only calibration)")


def register(app: typer.Typer) -> None:
    prof = typer.Typer(help="Inspect and compare calibration profiles.", no_args_is_help=True)
    app.add_typer(prof, name="profile")

    @prof.command("show")
    def show_cmd(
        profile: Path = typer.Argument(..., help="Profile file (.camcal)."),
        as_json: bool = typer.Option(False, "--json", help="Print the JSON contract (docs/profile-format.md)."),
    ) -> None:
        """Show a profile (validated and hash-checked on load)."""
        from camcal.profile import contract, load_profile

        c = contract(load_profile(profile))
        if as_json:
            print_json(c)
        else:
            print_contract(c, title=str(profile))

    @prof.command("diff")
    def diff_cmd(
        a: Path = typer.Argument(..., help="First profile."),
        b: Path = typer.Argument(..., help="Second profile."),
        rel_tol: float = typer.Option(0.0, help="Ignore relative changes up to this size."),
        as_json: bool = typer.Option(False, "--json", help="Print the differences as JSON."),
    ) -> None:
        """List what differs between two profiles (relative change of every number)."""
        from camcal.profile import diff_profiles, load_profile

        rows = diff_profiles(load_profile(a), load_profile(b), rel_tol=rel_tol)
        if as_json:
            print_json(rows)
            return
        if not rows:
            console.print("profiles agree")
            return
        table = Table("key", "A", "B", "relative change")
        for r in rows:
            table.add_row(r["key"], _fmt(r["a"]), _fmt(r["b"]), "—" if r["rel_change"] is None
                          else f"{100 * r['rel_change']:.3g} %")
        console.print(table)

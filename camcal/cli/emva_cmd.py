"""``camcal emva DESCRIPTOR -o SHEET/ [--json]``: the EMVA 1288 data sheet of a measurement in the standard's format."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from camcal.calibrate.emva_descriptor import NS_PER_S, load_measurement, read_descriptor
from camcal.calibrate.emva_standard import evaluate
from camcal.cli.common import console, print_json, progress
from camcal.emva1288.sheet import render_sheet, sheet_from_figures
from camcal.errors import CamcalError
from camcal.io.atomic import atomic_write_text
from camcal.units import DN_PER_ELECTRON, ELECTRONS


def register(app: typer.Typer) -> None:
    @app.command("emva")
    def emva_cmd(
        descriptor: Path = typer.Argument(..., help="EMVA 1288 descriptor file (release 3.0 or 4.0, e.g. "
                                          "EMVA1288_Data.txt) listing the frames (16-bit PNG or TIFF)."),
        output: Path = typer.Option(..., "-o", "--output", help="Folder to write the data sheet to "
                                    "(emva1288.html and emva1288.json)."),
        as_json: bool = typer.Option(False, "--json", help="Print the sheet as JSON (the layout of `camcal profile "
                                     "show --emva --json`)."),
    ) -> None:
        """EMVA 1288 data sheet (K, σ_d, DSNU₁₂₈₈, PRNU₁₂₈₈, saturation, SNR_max, η, DR, LE, plots) of a
        measurement described by the standard's descriptor file."""
        d = read_descriptor(descriptor)
        with progress() as bar:
            task = bar.add_task("EMVA 1288 frames", total=None)
            m = load_measurement(d, lambda done, total: bar.update(task, completed=done, total=total))
        try:
            result = evaluate(m.series, m.bright, m.dark)
        except ValueError as exc:
            raise CamcalError(f"no EMVA 1288 figures: {exc}", descriptor) from None
        t = m.series.exposure_s
        point = {
            "descriptor": str(descriptor), "release_of_measurement": d.release, "bits": d.bits,
            "width": d.width, "height": d.height, "channel": "Y (monochrome)",
            "bright_pairs": int(t.size), "dark_pairs": int(m.series.dark_exposure_s.size),
            "exposure_min_s": float(t.min()), "exposure_max_s": float(t.max()),
            "illumination": "photons per pixel (descriptor)" if m.series.has_photons else "exposure time",
        }
        if m.dark is not None:
            point.update({"dsnu_frames": m.dark.n_frames, "dsnu_exposure_s": m.dark.exposure_s})
        if m.bright is not None:
            point.update({"prnu_frames": m.bright.n_frames, "prnu_exposure_s": m.bright.exposure_s,
                          "prnu_photons": m.bright.photons})
        sheet = sheet_from_figures(result, operating_point=point, notes=m.notes)
        output.mkdir(parents=True, exist_ok=True)
        html_path = atomic_write_text(output / "emva1288.html", render_sheet(sheet, result, str(descriptor)))
        json_path = atomic_write_text(output / "emva1288.json",
                                      json.dumps(sheet.to_dict(), indent=2, allow_nan=False) + "\n")
        if as_json:
            print_json(sheet.to_dict())
            return
        f = sheet.channels["Y"]
        console.print(f"EMVA 1288 ({d.release} measurement, {t.size} pairs, "
                      f"{t.min() * NS_PER_S / 1e3:g}–{t.max() * NS_PER_S / 1e3:g} µs): "
                      f"K {f['K_dn_per_e']:.4g} ± {f['K_unc_dn_per_e']:.2g} {DN_PER_ELECTRON}, "
                      f"σ_d {f['read_noise_e']:.4g} {ELECTRONS}, μ_e.sat {f['saturation_e']:.5g} {ELECTRONS}, "
                      f"SNR_max {f['snr_max']:.4g}, DSNU₁₂₈₈ {_g(f.get('dsnu_e'))} {ELECTRONS}, "
                      f"PRNU₁₂₈₈ {_g(f.get('prnu_pct'))} %")
        console.print(f"wrote {html_path} and {json_path}")


def _g(v) -> str:
    return "—" if v is None else f"{v:.4g}"

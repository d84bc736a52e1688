"""``camcal profile show|diff|import-spectral|export-spectral``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from camcal.cli.common import console, fraction, print_json, progress
from camcal.curves.borrowed import borrowed_table_rows, shipped_borrowed_uncertainty, shipped_table_sha256
from camcal.curves.files import write_spectacle_csv
from camcal.curves.import_spectral import import_spectral
from camcal.errors import CamcalError
from camcal.models.emva import STANDARD, EmvaSheet, sheet_rows
from camcal.models.profile import CameraIdentity, contract, diff_profiles, flats_optics_text, load_profile, save_profile
from camcal.models.spectral import describe_origin
from camcal.units import DN, DN_PER_ELECTRON, DN_PER_S, SPECTRAL_SENSITIVITY


def _fmt(v) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.5g}"
    return str(v)


def print_contract(c: dict, title: str = "profile") -> None:
    """A human summary of the contract object (one table per calibrated stage)."""
    cam = c["camera"]
    sensor = cam["cfa_pattern"] or f"{cam.get('layout') or 'linear'} RAW"
    iso, n = c["reference"]["iso"], c["reference"]["f_number"]
    ref = (f"reference ISO {iso:g} f/{n:g}" if iso is not None and n is not None else
           "no reference setting (no stage normalised exposure)")
    console.print(f"[bold]{title}[/bold]: {cam['make']} {cam['model']} (serial {cam['serial'] or 'unknown'}), "
                  f"{sensor} {cam['width']}x{cam['height']}, {ref}, schema {c['schema_version']}")
    rows = []
    if c["dark"]:
        d = c["dark"]
        rows += [("bias", DN, d["bias_dn"]), ("dark current β", DN_PER_S, d["dark_current_dn_per_s"]),
                 ("read noise", DN, d["read_noise_dn"])]
    if c["flat"]:
        rows += [("corner gain", "", c["flat"]["corner_gain"]), ("PRNU", "rel.", c["flat"]["prnu_rms"])]
    if c["response"]:
        r = c["response"]
        rows += [(f"γ ({r['kind']})", "", r["gamma"]), (f"α ({r['kind']})", "", r["alpha"])]
        for k, m in r["models"].items():
            if k != r["kind"]:
                rows += [(f"γ ({k})", "", m["gamma"])]
        primary = r["models"].get(r["kind"]) or {}
        if primary.get("saturation_dn"):
            rows += [(f"saturation ({r['kind']})", "DN", primary["saturation_dn"]),
                     (f"saturation reached at ({r['kind']})", "s", primary.get("saturation_exposure_s"))]
    if c["spectral_sensitivity"]:
        s = c["spectral_sensitivity"]
        rows += [("peak λ", "nm", s["peak_wavelength_nm"]), ("effective λ", "nm", s["effective_wavelength_nm"])]
    channels = ("Y",) if cam.get("layout") == "mono" else ("R", "G", "B")  # a monochrome sensor has one channel
    table = Table(show_header=True, title_justify="left")
    for col in ("quantity", "unit", *channels):
        table.add_column(col, justify="left" if col in ("quantity", "unit") else "right")
    for name, unit, vals in rows:
        table.add_row(name, unit, *(_fmt((vals or {}).get(ch)) for ch in channels))
    console.print(table)
    if c["flat"]:
        console.print(f"flats at {flats_optics_text(c['flat'])}", soft_wrap=True, markup=False, highlight=False)
    stages = [k for k in ("dark", "flat", "response", "spectral_sensitivity") if c[k] is None]
    if c["dark"] and all(v is None for v in (c["dark"].get("dark_current_dn_per_s") or {}).values()):
        stages.insert(0, "dark current (bias frames only)")
    if stages:
        console.print(f"not calibrated: {', '.join(stages)}")
    for kind, m in ((c["response"] or {}).get("models") or {}).items():
        if m.get("saturated_files"):
            console.print(f"saturated {kind} frames (end of the linear range, not fitted): "
                          f"{', '.join(m['saturated_files'])}", soft_wrap=True, markup=False, highlight=False)
    prov = c.get("provenance") or {}
    for rec in prov.get("not_calibrated") or []:
        console.print(f"stage {rec['stage']} not calibrated: {rec['reason']}", soft_wrap=True, markup=False,
                      highlight=False)
    print_left_out(prov.get("left_out") or [])
    if c["dark"]:
        d = c["dark"]
        console.print(f"defects: hot pixels {d['hot_pixel_count']}, dead pixels {d['dead_pixel_count']}, "
                      f"noisy pixels {d['noisy_pixel_count']}")
        if not d.get("dark_current_known", True):
            console.print("dark current: unknown (bias-only calibration)")
    if c["spectral_sensitivity"]:
        print_spectral_source(c["spectral_sensitivity"]["source"])


def print_left_out(rows: list[dict]) -> None:
    """The frames a calibration left out, as a table (stage, file, reason); nothing when none were."""
    if not rows:
        return
    table = Table("stage", "file", "reason", title=f"left out: {len(rows)} frame{'s' if len(rows) != 1 else ''}",
                  title_justify="left")
    for r in rows:
        table.add_row(escape(r["stage"]), escape(r["file"]), escape(r["reason"]))
    console.print(table)


def print_emva(sheet: EmvaSheet, title: str = "profile") -> None:
    """The EMVA 1288 summary sheet: one column per plane, rows in the standard's order."""
    console.print(f"[bold]{title}[/bold]: {STANDARD} summary at ISO {sheet.iso:g}")
    planes = list(sheet.channels)
    table = Table(show_header=True, title_justify="left")
    for col in ("section", "quantity", "unit", *planes):
        table.add_column(col, justify="left" if col in ("section", "quantity", "unit") else "right")
    last = None
    for section, name, unit, vals in sheet_rows(sheet):
        table.add_row(section if section != last else "", name, unit, *(_fmt(vals.get(p)) for p in planes))
        last = section
    console.print(table)
    sp = sheet.spatial
    if sp.get("dsnu_frames"):
        console.print(f"DSNU from the average of {sp['dsnu_frames']} dark frames at {sp['dsnu_exposure_s']:g} s; "
                      f"PRNU from {sp.get('prnu_frames', '—')} flats (EMVA 1288 eq. 36: temporal noise / L removed)")
    for row in sheet.photon_transfer:
        ks = ", ".join(f"{p} {v['K_dn_per_e']:.4g} ± {v['K_unc_dn_per_e']:.2g}" for p, v in row["channels"].items()
                       if v and v.get("K_dn_per_e") is not None and v.get("K_unc_dn_per_e") is not None)
        console.print(f"photon transfer at ISO {row['iso']:g} ({row.get('pairs', 0)} frame pairs): "
                      f"K {ks} {DN_PER_ELECTRON}",
                      soft_wrap=True)
    qe = sheet.quantum_efficiency
    if qe:
        peaks = []
        for p, v in qe["values"].items():
            arr = [x if x is not None else float("nan") for x in v]
            if arr:
                i = max(range(len(arr)), key=lambda j: arr[j] if arr[j] == arr[j] else -1.0)
                peaks.append(f"{p} {100 * arr[i]:.3g} % at {qe['wavelength_nm'][i]:g} nm")
        console.print(f"quantum efficiency (lens included, pixel pitch {qe['pixel_pitch_um']:g} µm), peak: "
                      + ", ".join(peaks), soft_wrap=True)
    for note in sheet.notes:
        console.print(f"note: {note}", soft_wrap=True)


def print_spectral_source(src: dict) -> None:
    where, how = describe_origin(src)
    console.print(f"c(λ) from: {where}", soft_wrap=True)
    console.print(f"absolute scale: {how}", soft_wrap=True)
    a = src.get("absolute_scale") or {}
    if a.get("method") == "reference_targets":
        planes = list(a["k"])
        table = Table("target", "photos", *(f"residual {p}" for p in planes), title_justify="left")
        for t in a.get("targets") or []:
            table.add_row(t["name"], str(len(t.get("photos") or [])),
                          *(f"{100 * t['residual_rel'][p]:+.3g} %" for p in planes))
        console.print(table)
        console.print("k: " + ", ".join(f"{p} {a['k'][p]:.6g} ± {a['k_unc'][p]:.2g}" for p in planes),
                      soft_wrap=True)
    if src.get("library"):
        print_borrowed_uncertainty(src["library"])


def print_borrowed_uncertainty(lib: dict) -> None:
    """The borrowed-curve uncertainty table a library-based profile's u(c) includes (docs/spectral.md)."""
    table = shipped_borrowed_uncertainty()
    rec = lib.get("borrowed_uncertainty") or {}
    t = Table("λ (nm)", "u(c) R", "u(c) G", "u(c) B", title_justify="left",
              title="borrowed-curve uncertainty u(c), % of each channel's peak (in the profile's u(c))")
    for w, r, g, b in borrowed_table_rows(table):
        t.add_row(f"{w:g}", f"{100 * r:.1f}", f"{100 * g:.1f}", f"{100 * b:.1f}")
    console.print(t)
    console.print(f"from {rec.get('table')} (SHA-256 {str(rec.get('sha256'))[:12]}…): the spread between independent "
                  "measurements of one camera model; outside 400–700 nm the end values apply", soft_wrap=True)
    if rec.get("sha256") != shipped_table_sha256():
        console.print("[red]the profile was made with another version of this table; the rows above are this camcal's"
                      "[/red]", soft_wrap=True)


def _parse_size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    parts = text.lower().split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        w = h = 0
    if len(parts) != 2 or w < 1 or h < 1:
        raise CamcalError(f"--size must be WIDTHxHEIGHT in pixels, e.g. 6000x4000, got {text!r}")
    return w, h


def register(app: typer.Typer) -> None:
    prof = typer.Typer(help="Inspect, compare and assemble calibration profiles.", no_args_is_help=True)
    app.add_typer(prof, name="profile")

    @prof.command("show")
    def show_cmd(
        profile: Path = typer.Argument(..., help="Profile file (.camcal)."),
        as_json: bool = typer.Option(False, "--json", help="Print the JSON contract (docs/profile-format.md)."),
        emva: bool = typer.Option(False, "--emva", help="Print the EMVA 1288 summary sheet (K, noise, DSNU, PRNU, "
                                  "saturation, SNR_max, dynamic range, linearity error) per plane."),
    ) -> None:
        """Show a profile (validated and hash-checked on load)."""
        prof = load_profile(profile)
        if emva:
            if prof.emva is None:
                raise CamcalError("the profile has no EMVA 1288 section (calibrated before camcal wrote it, or "
                                  "without dark, flat and linearity frames)", profile)
            if as_json:
                print_json(prof.emva.to_dict())
            else:
                print_emva(prof.emva, title=str(profile))
            return
        c = contract(prof)
        if as_json:
            print_json(c)
        else:
            print_contract(c, title=str(profile))

    @prof.command("import-spectral")
    def import_cmd(
        curves: Path | None = typer.Argument(None, help="Spectral curves: a SPECTACLE CSV, or a plain table "
                                             "wavelength_nm,R,G,B[,R_unc,G_unc,B_unc] (CSV, or space-separated "
                                             ".dat). Omit with --camera."),
        camera_name: str | None = typer.Option(None, "--camera", help="Take the curves from the bundled library "
                                               "(camcal curves list): a model, e.g. \"Canon EOS 5D Mark III\", or "
                                               "auto (the make and model of --into or of the target photos)."),
        output: Path = typer.Option(..., "-o", "--output", help="Profile to write (.camcal)."),
        into: Path | None = typer.Option(None, "--into", help="Existing profile: keep its dark, flat, response and "
                                         "camera, replace its c(λ) (resampled to its wavelength grid)."),
        fmt: str = typer.Option("auto", "--format", help="auto, spectacle or plain."),
        targets: Path | None = typer.Option(None, "--targets", help="targets.csv (or its folder) of reference-target "
                                            "photos: sets the absolute scale of relative curves."),
        absolute: bool = typer.Option(False, "--absolute",
                                      help=f"The file's values are already absolute ({SPECTRAL_SENSITIVITY})."),
        reference_iso: float | None = typer.Option(None, help="Reference ISO of an absolute scale (default: the "
                                                   "profile's, or the absolute curves' own; relative curves need "
                                                   "none)."),
        reference_f_number: float | None = typer.Option(None, help="Reference f-number of an absolute scale "
                                                        "(default: as --reference-iso)."),
        dark: Path | None = typer.Option(None, "--dark", help="Dark model for the target photos (camcal dark)."),
        flat: Path | None = typer.Option(None, "--flat", help="Flat model for the target photos (camcal flat)."),
        make: str | None = typer.Option(None, help="Camera make of a new profile without photos."),
        model: str | None = typer.Option(None, "--camera-model", help="Camera model of a new profile without "
                                         "photos."),
        size: str | None = typer.Option(None, help="Sensor size WIDTHxHEIGHT of a new profile without photos."),
        as_json: bool = typer.Option(False, "--json", help="Print the spectral source record as JSON."),
    ) -> None:
        """Put spectral curves measured elsewhere into a profile; absolute through reference-target photos."""
        if output.suffix.lower() != ".camcal":
            raise CamcalError("output must be a .camcal file", output)
        if fmt not in ("auto", "spectacle", "plain"):
            raise CamcalError(f"--format must be auto, spectacle or plain, got {fmt!r}")
        if (curves is None) == (camera_name is None):
            raise CamcalError("give a curve file or --camera (the bundled library), one of them")
        if absolute and targets is not None:
            raise CamcalError("--absolute and --targets exclude each other: targets set the scale of relative curves")
        base = load_profile(into) if into is not None else None
        wh = _parse_size(size)
        camera = None
        if wh is not None:
            camera = CameraIdentity(make, model, None, None, wh[0], wh[1])
        elif (make or model) and base is None:
            raise CamcalError("--make/--model need --size WIDTHxHEIGHT as well")
        with progress() as bar:
            bar.add_task("import spectral curves", total=None)
            prof, _ = import_spectral(curves, fmt=fmt, base=base, targets=targets, absolute=absolute,  # type: ignore[arg-type]
                                      reference_iso=reference_iso, reference_f_number=reference_f_number,
                                      dark=dark, flat=flat, camera=camera, library_camera=camera_name)
        saved = save_profile(prof, output)
        src = saved.spectral.origin()
        if as_json:
            print_json({"output": str(output), "content_sha256": saved.content_sha256, "mode": saved.spectral.mode,
                        "source": src})
            return
        print_spectral_source(src)
        console.print(f"wrote {output} (c(λ) {saved.spectral.mode}, {saved.spectral.wavelength_nm.size} wavelengths "
                      f"{saved.spectral.wavelength_nm[0]:g}–{saved.spectral.wavelength_nm[-1]:g} nm)")

    @prof.command("export-spectral")
    def export_cmd(
        profile: Path = typer.Argument(..., help="Profile file (.camcal)."),
        output: Path = typer.Option(..., "-o", "--output", help="CSV to write (SPECTACLE's layout; camcal's metadata "
                                    "goes to <stem>.meta.json beside it)."),
    ) -> None:
        """Write a profile's c(λ) as SPECTACLE writes spectral responses (np.loadtxt(path, delimiter=",") reads it)."""
        if output.suffix.lower() != ".csv":
            raise CamcalError("output must be a .csv file", output)
        p = load_profile(profile, with_maps=False)
        if p.spectral is None:
            raise CamcalError("the profile has no spectral sensitivity", profile)
        write_spectacle_csv(p.spectral, output)
        console.print(f"wrote {output} (+ {output.stem}.meta.json)")

    @prof.command("diff")
    def diff_cmd(
        a: Path = typer.Argument(..., help="First profile."),
        b: Path = typer.Argument(..., help="Second profile."),
        rel_tol: float = typer.Option(0.0, parser=fraction, help="Ignore relative changes up to this size "
                                      "('1%' or 0.01)."),
        as_json: bool = typer.Option(False, "--json", help="Print the differences as JSON."),
    ) -> None:
        """List what differs between two profiles (relative change of every number)."""

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

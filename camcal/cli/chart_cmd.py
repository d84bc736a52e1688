"""``camcal chart``: a calibration profile from photos of a colour chart (no lab: the sun or a known light)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from camcal.chart.detect import parse_corners
from camcal.chart.profile_build import ChartOptions, ChartResult, build_chart_profile
from camcal.cli.common import console, print_json, progress
from camcal.cli.water_cmd import _split_unc
from camcal.errors import CamcalError
from camcal.models.profile import save_profile
from camcal.water.field import DEFAULT_AOD_500NM


def _aerosol(text: str) -> tuple[float, float | None]:
    a, b = _split_unc(text)
    try:
        return float(a), None if b is None else float(b)
    except ValueError:
        raise CamcalError(f"--aerosol {text!r}: give the optical depth at 500 nm and optionally its 1-σ, e.g. "
                          "0.1±0.05") from None


def _ir_cut(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    a, b = _split_unc(text)
    try:
        cut, sigma = float(a), float(b) if b is not None else None
    except ValueError:
        cut = sigma = None
    if cut is None or sigma is None:
        raise CamcalError(f"--ir-cut {text!r}: give the IR-cut filter's half-transmission wavelength and its 1-σ "
                          "in nm, e.g. 650±10 (from the camera module's datasheet)")
    return cut, sigma


def summary(res: ChartResult) -> dict:
    """The JSON summary of ``camcal chart --json``."""
    s = res.profile.spectral
    rms = res.recovered.term_rms_pct_of_peak()
    return {"content_sha256": res.profile.content_sha256, "mode": s.mode, "units": s.units,
            "reference": {"iso": res.profile.reference_iso, "f_number": res.profile.reference_f_number},
            "camera": {"make": res.profile.camera.make, "model": res.profile.camera.model,
                       "layout": res.profile.camera.layout},
            "peak_wavelength_nm": s.peak_wavelength_nm(), "effective_wavelength_nm": s.effective_wavelength_nm(),
            "peak_value": {p: float(np.max(v)) for p, v in s.values.items()},
            "uncertainty_rms_pct_of_peak": rms, "dominant_term": res.recovered.dominant_term(),
            "chi2": res.recovered.chi2, "dof": res.recovered.dof, "light": res.light.source,
            "illuminant_estimate": res.illuminant_estimate,
            "photos": [p.record(None) for p in res.photos],
            "tone": None if res.tone is None else (s.source or {}).get("processed"),
            "white_balance": res.white_balance, "warnings": list(res.warnings), "notes": list(res.notes)}


def print_summary(res: ChartResult, output: Path) -> None:
    prof = res.profile
    s = prof.spectral
    cam = prof.camera
    console.print(f"[bold]{escape(str(output))}[/bold]: {cam.make} {cam.model}, {cam.layout} "
                  f"{cam.width}x{cam.height}, c(λ) {s.mode}"
                  + (f" at ISO {prof.reference_iso:g} f/{prof.reference_f_number:g}" if prof.reference_iso else ""))
    for p in res.photos:
        loc = p.location
        console.print(f"  {escape(p.path.name)}: {p.kind}, chart {loc.method} (neutral-row score "
                      f"{loc.neutral_score:.3f}), {int((~p.patches.saturated).sum())}/24 patches usable",
                      soft_wrap=True, highlight=False)
    light = res.light.source
    if light.get("kind") == "clear_sky":
        sun = light.get("sun") or {}
        console.print(f"light: clear sky (SPECTRL2), sun zenith {light['sun_zenith_deg']:.2f}° ({sun.get('source')}), "
                      f"aerosol {light['aerosol_optical_depth_500nm']:g}"
                      f"±{light['sigma']['aerosol_optical_depth_500nm']:g}"
                      f", water {light['precipitable_water_cm']:g} cm, ozone {light['ozone_atm_cm']:g} atm-cm",
                      soft_wrap=True, highlight=False)
    elif res.illuminant_estimate:
        e = res.illuminant_estimate
        u = e["u_parameter_K"]
        console.print(f"light: estimated from the chart: {e['family']} {e['parameter_K']:.0f} K "
                      f"± {'unconstrained' if not np.isfinite(u) else f'{u:.0f} K'} (shape only: c(λ) relative)",
                      soft_wrap=True, highlight=False)
    else:
        console.print(f"light: {escape(str(light))}", soft_wrap=True, highlight=False)
    rms = res.recovered.term_rms_pct_of_peak()
    dom = res.recovered.dominant_term()
    peak = s.peak_wavelength_nm()
    eff = s.effective_wavelength_nm()
    table = Table("plane", "peak λ (nm)", "effective λ (nm)", "peak c", "u(c) RMS % of peak", "dominant term",
                  "χ²/dof", title="c(λ) recovered from the chart", title_justify="left")
    for p in s.plane_names:
        chi = res.recovered.chi2[p] / max(res.recovered.dof[p], 1e-9)
        table.add_row(p, f"{peak[p]:g}", f"{eff[p]:.1f}", f"{float(np.max(s.values[p])):.4g}",
                      f"{rms[p]['total']:.2g}", dom[p], f"{chi:.3g}")
    console.print(table)
    console.print(f"units: {s.units}", soft_wrap=True, highlight=False)
    if res.tone is not None:
        t = res.tone
        console.print(f"tone curve (sRGB form): exponent {t.exponent:.4f} ± {t.exponent_unc:.2g}, offset "
                      f"{t.offset_a:.4f} ± {t.offset_a_unc:.2g}, RMS {t.rms_dn:.3g} DN over {t.n_points} values"
                      + ("; colour matrix from RAW twins" if t.matrix is not None else ""),
                      soft_wrap=True, highlight=False)
    for n in res.notes:
        console.print(f"note: {escape(n)}", soft_wrap=True, highlight=False)
    for w in res.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(w)}", soft_wrap=True, highlight=False)
    console.print(f"wrote {escape(str(output))} (SHA-256 {prof.content_sha256[:12]}…)", highlight=False)


def register(app: typer.Typer) -> None:
    @app.command("chart")
    def chart_cmd(
        photos: list[Path] = typer.Argument(..., help="Photos of a ColorChecker Classic (RAW/DNG, HEIC or JPEG; a "
                                            "DNG and a HEIC of one name stem are twins of one shot)."),
        output: Path = typer.Option(..., "-o", "--output", help="Profile to write (.camcal)."),
        chart_csv: Path | None = typer.Option(None, "--chart", help="Your chart's measured reflectance: CSV with "
                                              "wavelength_nm and one column per patch (default: the published "
                                              "ColorChecker with the chart-to-chart spread)."),
        corners: str | None = typer.Option(None, "--corners", help="The swatch grid's corners x1,y1,...,x4,y4 in "
                                           "photo pixels, next to patch 1 (dark skin), 6, 24 (black), 19 (white); "
                                           "default: found automatically."),
        illuminant: str | None = typer.Option(None, "--illuminant", help="The light: a CSV (wavelength_nm, "
                                              "irradiance_w_m2_nm[, u_irradiance_w_m2_nm]), a CIE name (D65, A, "
                                              "D5000, blackbody:3200: shape only) or 'estimate' (fitted from the "
                                              "chart); default: the clear sky from the photo's time and GPS."),
        illuminant_relative: bool = typer.Option(False, "--illuminant-relative", help="The CSV spectrum is a shape, "
                                                 "not calibrated W m⁻² nm⁻¹ (c(λ) is then relative)."),
        sun: str | None = typer.Option(None, "--sun", help="ZENITH,AZIMUTH in degrees, instead of the photo's EXIF "
                                       "time and GPS."),
        utc_offset: str | None = typer.Option(None, help="The camera clock's offset from UTC, +HH:MM (photos "
                                              "without a GPS time)."),
        aerosol: str = typer.Option(f"{DEFAULT_AOD_500NM:g}±0.05", help="SPECTRL2: aerosol optical depth at 500 nm "
                                    "and its 1-σ."),
        precipitable_water: float = typer.Option(1.42, help="SPECTRL2: precipitable water, cm."),
        ozone: float = typer.Option(0.344, help="SPECTRL2: ozone, atm-cm."),
        pressure: float = typer.Option(101325.0, help="SPECTRL2: surface pressure, Pa."),
        flat: list[Path] = typer.Option([], "--flat", help="Photo of a uniform surface (an overcast sky through a "
                                        "diffuser, a white wall; repeat): a relative flat (vignetting)."),
        components: int = typer.Option(8, help="Components of the camera basis."),
        ir_cut: str | None = typer.Option(None, "--ir-cut", help="The camera module's IR-cut filter: its "
                                          "half-transmission wavelength and 1-σ in nm from a datasheet, e.g. "
                                          "650±10. A chart cannot see the cut beyond ~640 nm; without this the "
                                          "prior spans 630-700 nm and σ says so."),
        as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
    ) -> None:
        """A calibration profile from photos of a colour chart in the sun (or under a known light)."""
        if output.suffix.lower() != ".camcal":
            raise CamcalError("output must be a .camcal file", output)
        a, sa = _aerosol(aerosol)
        opts = ChartOptions(chart_csv=chart_csv, corners=None if corners is None else parse_corners(corners),
                            illuminant=illuminant, illuminant_absolute=not illuminant_relative, sun=sun,
                            utc_offset=utc_offset, aerosol_optical_depth_500nm=a, aerosol_sigma=sa,
                            precipitable_water_cm=precipitable_water, ozone_atm_cm=ozone, pressure_Pa=pressure,
                            flat=tuple(flat), n_components=components, ir_cut=_ir_cut(ir_cut))
        with progress() as bar:
            task = bar.add_task("chart", total=None)
            res = build_chart_profile(photos, opts, lambda msg: bar.update(task, description=msg))
        saved = save_profile(res.profile, output)
        res = ChartResult(saved, res.recovered, res.light, res.photos, res.tone, res.warnings, res.notes,
                          res.illuminant_estimate, res.white_balance)
        if as_json:
            print_json({"output": str(output), **summary(res)})
            return
        print_summary(res, output)

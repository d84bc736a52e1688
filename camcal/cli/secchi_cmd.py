"""``camcal secchi``: photos of a Secchi disk (a reference in air, submerged at depths) to chlorophyll-a."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from camcal.cli.common import console, print_json, progress
from camcal.cli.water_cmd import _depth_unc, _number, _split_unc, _unc_value
from camcal.errors import CamcalError
from camcal.io.sun import parse_sun_option, photo_sun
from camcal.region import Region
from camcal.units import CONCENTRATION
from camcal.water.band import read_chlorophyll_csv
from camcal.water.field import (
    DEFAULT_AOD_500NM,
    ClearSky,
    FieldGeometry,
    OvercastSky,
    read_sky_csv,
)
from camcal.water.secchi import SecchiResult, all_warnings, result_json, run_secchi, write_diagnostics
from camcal.water.uncertainty import Uncertain

#: Default 1-σ of the stated field inputs (docs/water.md, "The field model").
SUN_SIGMA_DEG = 0.5
DIFFUSE_SIGMA = 0.2
AEROSOL_SIGMA = 0.05


def result_table(res: SecchiResult):
    """A Rich table of the survey: one row per photo, units in the headers (the surround budget is in the JSON
    and on the page)."""
    unit = res.reference.unit or "?"
    t = Table(title=f"camcal secchi (disk L: band radiance, {escape(unit)})", title_justify="left")
    for col in ("photo", "depth (m)", "disk L", "ratio", f"C ± σ_C ({CONCENTRATION})", "dominant σ term"):
        t.add_column(col, justify="left" if col in ("photo", "dominant σ term") else "right",
                     overflow="fold")

    def g(v, digits=4):
        return "—" if v is None or not np.isfinite(v) else f"{v:.{digits}g}"

    for s in [res.reference, *res.submerged]:
        name = escape(s.path.name)
        if s.error:
            t.add_row(name, "" if s.depth_m is None else f"{s.depth_m:g}", g(s.disk_radiance), "", "[red]failed[/red]",
                      "")
        elif s.kind == "reference":
            t.add_row(name, "air", g(s.disk_radiance), "", "", "")
        else:
            dom = max(s.terms, key=s.terms.get) if s.terms else ""
            t.add_row(name, f"{s.depth_m:g}", g(s.disk_radiance), g(s.ratio, 5),
                      f"{s.c_ug_per_L:.4g} ± {s.sigma_ug_per_L:.2g}" + (" [yellow]⚠[/yellow]" if s.warnings else ""),
                      escape(dom))
    return t


def _percent(text: str, what: str) -> float:
    return _unc_value(1.0, text.strip(), _number(what), what)


def register(app: typer.Typer) -> None:
    @app.command("secchi")
    def secchi_cmd(
        profile: Path = typer.Option(..., "--profile", help="Calibration profile (.camcal) of the camera."),
        reference: Path = typer.Option(..., "--reference", help="Photo of the disk in air (dry, horizontal, "
                                       "under the same light), or its radiance EXR from camcal apply with --profile."),
        submerged: list[Path] = typer.Option(..., "--submerged", help="Photo of the disk under water (repeat "
                                             "for several; one --depth each)."),
        depth: list[str] = typer.Option(..., "--depth", help="Disk depth per submerged photo: '0.5m', '50cm', "
                                        "or with its 1-σ '0.5m±5mm'."),
        sun: str = typer.Option("auto", "--sun", help="auto (each photo's own sun from its EXIF time and GPS "
                                "position) or ZENITH,AZIMUTH in degrees (azimuth clockwise from north)."),
        utc_offset: str = typer.Option(None, help="--sun auto: the camera clock's offset from UTC, +HH:MM, for "
                                       "photos without GPS time or OffsetTimeOriginal."),
        sun_unc: float = typer.Option(SUN_SIGMA_DEG, "--sun-unc-deg", help="1-σ of the sun's zenith angle, degrees."),
        sky: str = typer.Option("clear", "--sky", help="clear (SPECTRL2 sun and sky) or overcast (diffuse only)."),
        sky_csv: Path = typer.Option(None, help="Measured sky: CSV wavelength_nm, direct_horizontal, "
                                     "diffuse_horizontal (instead of SPECTRL2)."),
        aerosol: str = typer.Option(f"{DEFAULT_AOD_500NM:g}±{AEROSOL_SIGMA:g}", help="SPECTRL2: aerosol optical "
                                    "depth at 500 nm with its 1-σ."),
        precipitable_water: float = typer.Option(1.42, help="SPECTRL2: precipitable water, cm."),
        ozone: float = typer.Option(0.344, help="SPECTRL2: ozone, atm-cm."),
        pressure: float = typer.Option(101325.0, help="SPECTRL2: surface pressure, Pa."),
        diffuse_unc: str = typer.Option(f"{DIFFUSE_SIGMA:.0%}", help="Relative 1-σ of the diffuse irradiance: "
                                        "'20%' or 0.2."),
        roi: str = typer.Option(None, "--roi", help="The disk's interior by hand, x,y,w,h in photo pixels (all "
                                "photos); the surround is the annulus around it."),
        out: Path = typer.Option(None, "-o", "--output", help="Folder for the diagnostic page (index.html, PNGs, "
                                 "secchi.json)."),
        as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
        band_channel: str = typer.Option("R", help="The channel whose c(λ) defines the band."),
        chlorophyll_csv: Path = typer.Option(None, "--absorber-csv", "--chlorophyll-csv", help="The absorber's "
                                             "spectrum (default: Bricaud 1998 chlorophyll)."),
        epsilon_unc: str = typer.Option(None, help="Relative 1-σ of the absorber spectrum's scale: '3%' or 0.03."),
        albedo: float = typer.Option(1.0, help="Disk albedo relative to the reference."),
        n_water: float = typer.Option(1.33, help="Refractive index of water."),
        background_absorption: float = typer.Option(0.0, help="Background (CDOM) absorption, m⁻¹."),
        view_deg: float = typer.Option(0.0, help="Camera view angle from nadir in air, degrees."),
        reflectance: str = typer.Option("fresnel", help="fresnel (exact) or schlick."),
        transmittance: str = typer.Option("exact", help="Sky part: exact (T(θ) in the integral) or mean (T̄)."),
        allow_other_camera: bool = typer.Option(False, "--allow-other-camera",
                                                help="Accept photos of another camera model than the profile's."),
    ) -> None:
        """Chlorophyll-a from photos of a Secchi disk under the sun: apply the profile, find the disks, form the
        band ratio, invert the field model (direct sun + sky over a flat surface); C ± σ_C and one line per
        photo."""
        if len(depth) != len(submerged):
            raise CamcalError(f"give one --depth per --submerged photo ({len(submerged)} photos, {len(depth)} "
                              "depths)")
        depths = [_depth_unc(t) for t in depth]
        if sky not in ("clear", "overcast"):
            raise CamcalError(f"--sky must be clear or overcast, got {sky!r}")
        if reflectance not in ("fresnel", "schlick") or transmittance not in ("exact", "mean"):
            raise CamcalError("--reflectance must be fresnel or schlick, --transmittance exact or mean")
        if not (0 < albedo < np.inf and 1 <= n_water < 3 and 0 <= background_absorption < np.inf
                and 0 <= view_deg < 90):
            raise CamcalError("--albedo must be > 0, --n-water 1-3, --background-absorption >= 0, --view-deg 0-90")
        inputs = []
        suns = None
        sun_meta: dict = {"source": "not used (overcast)"}
        if sky == "overcast":
            light = OvercastSky()
        else:
            if sun.strip().lower() == "auto":
                ref_sun = photo_sun(reference, utc_offset=utc_offset)
                suns = [photo_sun(p, utc_offset=utc_offset) for p in submerged]
                sun_meta = {"reference": ref_sun.to_dict(), "submerged": [s.to_dict() for s in suns]}
            else:
                ref_sun = parse_sun_option(sun)
                sun_meta = ref_sun.to_dict()
            zen = ref_sun.apparent_zenith_deg  # the direction the light arrives from
            inputs.append(Uncertain("sun_zenith", zen, float(sun_unc), "deg"))
            a_text, a_unc = _split_unc(aerosol)
            aod = _number("--aerosol")(a_text)
            if sky_csv is not None:
                light = read_sky_csv(sky_csv, zen)
            else:
                light = ClearSky(zen, aod, precipitable_water, ozone, pressure)
                inputs.append(Uncertain("aerosol", aod, _unc_value(aod, a_unc, _number("--aerosol"), "--aerosol"),
                                        "AOD"))
            inputs.append(Uncertain("diffuse_fraction", 1.0, _percent(diffuse_unc, "--diffuse-unc"), "relative"))
        if epsilon_unc is not None:
            inputs.append(Uncertain("epsilon", 1.0, _percent(epsilon_unc, "--epsilon-unc"), "relative"))
        geometry = FieldGeometry(albedo=albedo, n_water=n_water, view_angle_rad=float(np.radians(view_deg)),
                                 reflectance=reflectance, transmittance=transmittance)
        chl = read_chlorophyll_csv(chlorophyll_csv) if chlorophyll_csv else None
        region = Region.parse(roi) if roi else None
        with progress() as bar:
            task = bar.add_task("secchi", total=1 + len(submerged))
            res = run_secchi(profile, reference, list(submerged), depths, sky=light, geometry=geometry,
                             inputs=inputs, channel=band_channel, chlorophyll=chl,
                             background_absorption_per_m=background_absorption, roi=region,
                             sun_zeniths_deg=None if suns is None else [s.apparent_zenith_deg for s in suns],
                             progress=lambda: bar.advance(task), allow_other_camera=allow_other_camera,
                             page_dir=out)
        res.meta["sun"] = sun_meta
        page = write_diagnostics(res, out, band_channel) if out is not None else None
        failed = [s for s in res.submerged if s.error]
        if as_json:
            print_json({**result_json(res), "page": None if page is None else str(page)})
        else:
            console.print(result_table(res))
            if np.isfinite(res.c_ug_per_L):
                console.print(f"C = {res.c_ug_per_L:.4g} ± {res.sigma_ug_per_L:.2g} {CONCENTRATION} (1σ; dominant "
                              f"term: {res.dominant})", markup=False)
            for w in all_warnings(res):
                console.print(f"warning: {w}", markup=False, style="yellow")
            for s in res.submerged:
                if s.error:
                    console.print(f"{s.path.name}: failed: {s.error}", markup=False, style="red")
            if page is not None:
                console.print(f"wrote {page}", markup=False)
        if failed and len(failed) == len(res.submerged):
            raise CamcalError(f"no submerged photo gave a concentration: {failed[0].error}")

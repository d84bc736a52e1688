"""``camcal synth phone``: a phone user's sunlit field day as real DNG + HEIC files, with truth.json."""

from __future__ import annotations

from pathlib import Path

import typer

from camcal.cli.common import console, one_output, progress
from camcal.errors import CamcalError
from camcal.synth.exif import place_time_from_text
from camcal.synth.phone import PHONE_SENSORS, PhoneCamera, PhoneParams, sun_sky_at, write_phone_photos
from camcal.units import CONCENTRATION


def _numbers(text: str, option: str) -> tuple[float, ...]:
    """``1,2.5`` -> (1.0, 2.5); one clear line for anything else."""
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise CamcalError(f"{option} takes numbers separated by commas (1,2), got {text!r}") from None
    if not values:
        raise CamcalError(f"{option} takes numbers separated by commas (1,2), got {text!r}")
    return values


def register_phone(synth: typer.Typer) -> None:
    """Add ``phone`` to the ``camcal synth`` group."""

    @synth.command("phone")
    def phone_cmd(
        outdir_arg: Path | None = typer.Argument(None, metavar="OUTDIR", help="Folder to create (or -o)."),
        outdir_opt: Path | None = typer.Option(None, "-o", "--output", help="Folder to create."),
        seed: int = typer.Option(1, help="Random seed."),
        sensor: str = typer.Option("imx219", help=f"Measured phone-sensor curves: {', '.join(PHONE_SENSORS)}."),
        width: int = typer.Option(600, help="Image width, pixels."),
        height: int = typer.Option(400, help="Image height, pixels."),
        utc: str = typer.Option("2026-06-21T10:30:00Z", "--utc", help="Capture instant, ISO 8601 (sets the sun)."),
        utc_offset: str = typer.Option("+02:00", "--utc-offset", help="The phone clock's zone, +HH:MM."),
        gps: str = typer.Option("46.45,6.55,372", "--gps", help="GPS position LAT,LON[,ALT_M] (degrees north, "
                                                               "east; m)."),
        aerosol: float = typer.Option(0.1, help="SPECTRL2 aerosol optical depth at 500 nm of the rendered day."),
        chart_reflectance: str = typer.Option("ColorChecker N Ohta", "--chart-reflectance",
                                              help="The chart's measured reflectances (a colour-science "
                                                   "SDS_COLOURCHECKERS name)."),
        tone: str = typer.Option("srgb", help="Tone curve of the HEIC: srgb or filmic."),
        chlorophyll: float = typer.Option(5.0, help=f"Chlorophyll-a of the lake, {CONCENTRATION}."),
        depths: str = typer.Option("1,2", help="Depths of the submerged Secchi disk, m (comma-separated)."),
        flats: int = typer.Option(3, help="Photos of a uniform diffuse surface (a relative flat); 0: none."),
        formats: str = typer.Option("dng,heic", help="Photo formats, comma-separated: dng, heic, jpg."),
    ) -> None:
        """Write sunlit phone photos (a ColorChecker in perspective, a grey field, flats, Secchi disks) as DNG and
        HEIC from a phone-like camera with measured curves not in the library; the truth in truth.json."""
        outdir = one_output(outdir_arg, outdir_opt, "the output folder")
        place = place_time_from_text(utc, gps, utc_offset)
        if flats < 0:
            raise CamcalError(f"--flats must be 0 or more, got {flats}")
        cam = PhoneCamera(PhoneParams(sensor=sensor, width=width, height=height, tone=tone, seed=seed))
        sky = sun_sky_at(place, aerosol_optical_depth_500nm=aerosol)
        fmts = tuple(f.strip().lower() for f in formats.split(",") if f.strip())
        with progress() as bar:
            task = bar.add_task("phone photos", total=None)
            truth = write_phone_photos(outdir, cam, place=place, sky=sky, chart_reflectance=chart_reflectance,
                                       c_ug_per_L=chlorophyll, depths_m=_numbers(depths, "--depths"),
                                       n_flats=flats, formats=fmts, seed=seed,
                                       progress=lambda done, total: bar.update(task, completed=done, total=total))
        console.print(f"wrote phone photos in {outdir} (sun {truth['sky']['sun_zenith_deg']:.1f}° from the zenith; "
                      f"truth in {Path(outdir) / 'truth.json'})", soft_wrap=True, markup=False, highlight=False)

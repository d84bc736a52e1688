"""``camcal synth station``: the photos of a water-colour station (water, sky, grey card) with their truth."""

from __future__ import annotations

from pathlib import Path

import typer

from camcal.cli.common import console, one_output
from camcal.errors import CamcalError
from camcal.synth.camera import SyntheticCamera, preset
from camcal.synth.phone import PhoneCamera, PhoneParams
from camcal.synth.station import WATERS, place_at, write_station


def register_station(synth: typer.Typer) -> None:
    @synth.command("station")
    def station_cmd(
        outdir_arg: Path | None = typer.Argument(None, metavar="OUTDIR", help="Folder to create (or -o)."),
        outdir_opt: Path | None = typer.Option(None, "-o", "--output", help="Folder to create."),
        water: str = typer.Option("clear", "--water", help=f"Water type: {', '.join(WATERS)}."),
        utc: str = typer.Option("2026-06-21T11:40:00Z", "--utc", help="Capture instant, ISO 8601 (sets the sun)."),
        gps: str = typer.Option("52.0,5.0", "--gps", help="Position LAT,LON in degrees."),
        wind: float = typer.Option(5.0, "--wind", help="Wind speed, m/s."),
        n_water: int = typer.Option(5, "--water-photos", help="Number of water photos."),
        n_sky: int = typer.Option(3, "--sky-photos", help="Number of sky photos."),
        glint: int = typer.Option(None, "--glint-photo", help="Add sun glitter to this water photo (1-based)."),
        camera: str = typer.Option("lab", "--camera", help="lab (the demo's camera, --preset) or phone (the "
                                   "synthetic phone of `camcal synth phone`)."),
        preset_name: str = typer.Option("default", "--preset", help="Camera preset (as `camcal demo`)."),
        seed: int = typer.Option(1, help="Camera seed (the demo's camera is 1)."),
    ) -> None:
        """Write the photos of a water-colour station as real DNGs (water, sky, grey card) and truth.json: a
        bio-optical Rrs under the SPECTRL2 sun and sky, rendered independently of `camcal rrs`."""
        out = one_output(outdir_arg, outdir_opt, "the station folder")
        try:
            lat, lon = (float(v) for v in gps.split(","))
        except ValueError:
            raise CamcalError(f"--gps takes LAT,LON in degrees, got {gps!r}") from None
        if camera not in ("lab", "phone"):
            raise CamcalError(f"--camera {camera!r}: choose lab or phone")
        cam = (PhoneCamera(PhoneParams(seed=seed)) if camera == "phone"
               else SyntheticCamera(preset(preset_name, seed=seed)))
        truth = write_station(out, cam, water=water, place=place_at(utc, lat, lon), wind_m_s=wind, n_water=n_water,
                              n_sky=n_sky, glint_photo=glint)
        rrs = ", ".join(f"{b} {v:.5f}" for b, v in truth["rrs_per_sr"].items())
        console.print(f"wrote station {out} (sun zenith {truth['sun_zenith_deg']:.1f} deg; true Rrs {rrs} sr⁻¹; "
                      f"truth in {out / 'truth.json'})", markup=False)

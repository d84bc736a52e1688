"""``camcal synth session|photo``: write real synthetic DNG/JPEG/HEIC files from known parameters."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from camcal.cli.common import console, one_output, progress
from camcal.cli.synth_phone import register_phone
from camcal.cli.synth_station import register_station
from camcal.errors import CamcalError
from camcal.models.spectra import WAVELENGTHS_NM, gaussian_line, planck_radiance
from camcal.synth.camera import Scene, SyntheticCamera, preset
from camcal.synth.exif import place_time_from_text
from camcal.synth.messy import plant_problems
from camcal.synth.session import STAGES, SessionPlan, write_session
from camcal.synth.sunlit import write_sunlit_photos
from camcal.units import CONCENTRATION, IN_BAND_RADIANCE, SPECTRAL_RADIANCE


def _camera(pattern: str | None, bits: int | None, width: int | None, height: int | None, seed: int,
            sensitivity: str | None, preset_name: str = "default"):
    """The synthetic camera: a preset (:data:`camcal.synth.camera.PRESETS`) with the options given."""

    given = {"cfa_pattern": None if pattern is None else pattern.upper(), "bit_depth": bits, "width": width,
             "height": height, "sensitivity": sensitivity}
    return SyntheticCamera(preset(preset_name, seed=seed, **{k: v for k, v in given.items() if v is not None}))


def _f_numbers(text: str, option: str) -> tuple[float, ...]:
    """``2.8,8`` -> (2.8, 8.0); one clear line for anything else."""
    try:
        values = tuple(float(v) for v in text.replace("f/", "").split(",") if v.strip())
    except ValueError:
        raise CamcalError(f"{option} takes f-numbers separated by commas (2.8,8), got {text!r}") from None
    if not values or any(not 0.5 <= v <= 1000 for v in values):
        raise CamcalError(f"{option} takes f-numbers between 0.5 and 1000 separated by commas, got {text!r}")
    return values


def register(app: typer.Typer) -> None:
    synth = typer.Typer(help="Synthetic camera: real DNG/JPEG files from known parameters.", no_args_is_help=True)
    app.add_typer(synth, name="synth")
    register_phone(synth)
    register_station(synth)  # ``synth station``: camcal.cli.synth_station

    @synth.command("session")
    def session_cmd(
        outdir_arg: Path | None = typer.Argument(None, metavar="SESSION", help="Session folder to create (or -o)."),
        outdir_opt: Path | None = typer.Option(None, "-o", "--output", help="Session folder to create."),
        preset_name: str = typer.Option("default", "--preset",
                                         help="Camera preset: default, imx296 (10-bit, sub-DN read noise, "
                                              "black 60, 1456x1088 BGGR), hot (0.3 % hot pixels that saturate "
                                              "at 30 s), offsets (per-channel black, 0.1 DN jitter); messy: the "
                                              "default camera in a session with a truncated flat, a copied dark "
                                              "frame, another camera's JPEG in flat/, a sweep frame with the "
                                              "shutter closed and two saturated linearity steps (listed under "
                                              "'planted' in truth.json); apertures: mechanical vignetting that "
                                              "falls with the f-number (corner gain 0.42 at f/2.8, 0.60 at f/8), "
                                              "flats in flat/f2.8/ and flat/f8/, photos/ at f/2.8, f/4 and f/8."),
        pattern: str | None = typer.Option(None, help="CFA pattern: RGGB, BGGR, GRBG or GBRG (default: the "
                                                      "preset's, RGGB)."),
        bits: int | None = typer.Option(None, help="Bit depth of the RAW data (default: the preset's, 14)."),
        width: int | None = typer.Option(None, help="Sensor width, pixels (default: the preset's, 384)."),
        height: int | None = typer.Option(None, help="Sensor height, pixels (default: the preset's, 256)."),
        seed: int = typer.Option(1, help="Random seed."),
        sensitivity: str | None = typer.Option(None, help="Spectral sensitivity: nikon-d5100, sigma-sd-merrill."),
        stages: str = typer.Option("bias,dark,flat,linearity,sweep", help="Comma-separated stages to shoot."),
        layout: str = typer.Option("bayer", help="RAW layout: bayer (CFA mosaics) or linear (LinearRaw R, G, B)."),
        fixed_aperture: bool = typer.Option(False, "--fixed-aperture",
                                            help="No f-number in any file or manifest; one in session.toml."),
        flat_f_numbers: str | None = typer.Option(None, "--flat-f-numbers", metavar="N,N,...",
                                                  help="Shoot the flats at these f-numbers, into flat/f<N>/ (default: "
                                                       "the reference f-number, in flat/; preset apertures: 2.8,8)."),
        photo_f_numbers: str | None = typer.Option(None, "--photo-f-numbers", metavar="N,N,...",
                                                   help="Also write photos/ with one photo of a uniform scene at each "
                                                        "f-number (preset apertures: 2.8,4,8)."),
        linearity_pairs: bool = typer.Option(True, "--linearity-pairs/--no-linearity-pairs",
                                             help="Shoot every linearity exposure twice (the frame pairs of EMVA "
                                                  "1288 photon transfer: K, saturation, SNR_max)."),
    ) -> None:
        """Write a whole calibration session (bias, dark, flat, linearity, sweep) with truth.json."""
        outdir = one_output(outdir_arg, outdir_opt, "the session folder")

        chosen = tuple(s.strip() for s in stages.split(",") if s.strip())
        bad = [s for s in chosen if s not in STAGES]
        if bad:
            raise CamcalError(f"unknown stage(s) {bad}; choose from {', '.join(STAGES)}")
        if layout not in ("bayer", "linear"):
            raise CamcalError(f"unknown layout {layout!r}; choose bayer or linear")
        messy = preset_name == "messy"
        if messy and (layout != "bayer" or set(chosen) != set(STAGES)):
            raise CamcalError("--preset messy plants problems in every stage of a Bayer session; give no --stages "
                              "or --layout with it")
        cam = _camera(pattern, bits, width, height, seed, sensitivity, "default" if messy else preset_name)
        with progress() as bar:
            tasks: dict[str, int] = {}

            def tick(stage: str, done: int, total: int) -> None:
                if stage not in tasks:
                    tasks[stage] = bar.add_task(stage, total=total)
                bar.update(tasks[stage], completed=done)

            optics = {"flat_f_numbers": (2.8, 8.0), "photo_f_numbers": (2.8, 4.0, 8.0)} \
                if preset_name == "apertures" else {}
            if flat_f_numbers is not None:
                optics["flat_f_numbers"] = _f_numbers(flat_f_numbers, "--flat-f-numbers")
            if photo_f_numbers is not None:
                optics["photo_f_numbers"] = _f_numbers(photo_f_numbers, "--photo-f-numbers")
            plan = SessionPlan(stages=chosen, layout=layout, fixed_aperture=fixed_aperture,
                               linearity_repeats=2 if linearity_pairs else 1, **optics)
            out = write_session(outdir, cam, plan, progress=tick)
        if messy:
            planted = plant_problems(out, cam)
            for rec in planted:
                console.print(f"planted {rec['problem']}: {rec['file']} ({rec['what']})", soft_wrap=True,
                              markup=False, highlight=False)
        console.print(f"wrote session {out} (truth in {out / 'truth.json'})")

    @synth.command("photo")
    def photo_cmd(
        out_arg: Path | None = typer.Argument(None, metavar="FILE", help="Output file: .dng, .jpg or .heic (or -o)."),
        out_opt: Path | None = typer.Option(None, "-o", "--output", help="Output file: .dng, .jpg or .heic."),
        scene: str = typer.Option("uniform", help="uniform (flat spectrum), line (monochromator), lamp (black body), "
                                  "secchi-sunlit (FILE is a folder: a Secchi disk in a sunlit lake, SPECTRL2 sun "
                                  "and sky, one reference and one submerged photo per --depth, truth.json)."),
        chl: float = typer.Option(60.0, "--chl", help=f"secchi-sunlit: chlorophyll-a, {CONCENTRATION}."),
        depths: str = typer.Option("0.8", "--depths", help="secchi-sunlit: disk depths in m, comma-separated."),
        sun_zenith: float = typer.Option(35.0, "--sun-zenith", help="secchi-sunlit: the sun's zenith angle, deg."),
        sun_azimuth: float = typer.Option(160.0, "--sun-azimuth", help="secchi-sunlit: the sun's azimuth, deg."),
        photo_format: str = typer.Option("dng", "--format", help="secchi-sunlit: dng, jpg or heic, comma-separated."),
        radiance: float = typer.Option(0.02, help=f"uniform: {SPECTRAL_RADIANCE}; line: in-band {IN_BAND_RADIANCE}; "
                                        "lamp: peak."),
        wavelength: float = typer.Option(663.0, help="line centre, nm."),
        fwhm: float = typer.Option(5.0, help="line FWHM, nm."),
        temperature: float = typer.Option(3200.0, help="lamp temperature, K."),
        exposure: float = typer.Option(0.01, help="exposure time, s."),
        iso: float = typer.Option(100.0, help="ISO."),
        f_number: float = typer.Option(4.0, help="f-number."),
        pattern: str = typer.Option("RGGB"),
        bits: int = typer.Option(14),
        width: int = typer.Option(384),
        height: int = typer.Option(256),
        seed: int = typer.Option(1),
        sensitivity: str = typer.Option("nikon-d5100"),
        preset_name: str = typer.Option("default", "--preset", help="Camera preset (see `synth session`)."),
        layout: str = typer.Option("bayer", help="DNG layout: bayer (CFA mosaic) or linear (LinearRaw R, G, B)."),
        heic_bits: int = typer.Option(8, "--heic-bits", help="HEIC bit depth: 8 or 10."),
        utc: str | None = typer.Option(None, "--utc", help="Capture instant, ISO 8601 (2026-06-21T10:30:00Z): "
                                                            "written as DateTimeOriginal in the camera's zone, "
                                                            "OffsetTimeOriginal and the GPS time stamp."),
        utc_offset: str = typer.Option("+00:00", "--utc-offset", help="The camera clock's zone, +HH:MM "
                                                                       "(with --utc)."),
        gps: str | None = typer.Option(None, "--gps", help="GPS position LAT,LON[,ALT_M] (degrees north, east; "
                                                            "m), with --utc."),
        gps_time: bool = typer.Option(True, "--gps-time/--no-gps-time", help="Write the GPS time stamp (--utc)."),
        offset_tag: bool = typer.Option(True, "--offset-tag/--no-offset-tag",
                                        help="Write OffsetTimeOriginal (--utc)."),
    ) -> None:
        """Write one synthetic photo of a simple scene as DNG, JPEG or HEIC, optionally with its capture time
        and GPS position in the EXIF (--utc, --utc-offset, --gps)."""
        out = one_output(out_arg, out_opt, "the output file")
        if gps is not None and utc is None:
            raise CamcalError("--gps needs --utc (the capture instant)")
        place = (place_time_from_text(utc, gps, utc_offset, write_offset=offset_tag, write_gps_time=gps_time)
                 if utc is not None else None)

        cam = _camera(pattern, bits, width, height, seed, sensitivity, preset_name)
        if scene == "secchi-sunlit":
            files = write_sunlit_photos(out, cam, chl=chl, depths=depths, sun_zenith_deg=sun_zenith,
                                        sun_azimuth_deg=sun_azimuth, formats=photo_format, seed=seed, place=place)
            for f in files:
                console.print(f"wrote {f}", markup=False)
            return
        if scene == "uniform":
            spectrum = np.full(WAVELENGTHS_NM.size, radiance)
        elif scene == "line":
            spectrum = radiance * gaussian_line(wavelength, fwhm)
        elif scene == "lamp":
            b = planck_radiance(temperature)
            spectrum = radiance * b / b.max()
        else:
            raise CamcalError(f"unknown scene {scene!r}; choose uniform, line, lamp or secchi-sunlit")
        rng = np.random.default_rng(seed)
        kw = dict(exposure_s=exposure, iso=iso, f_number=f_number, rng=rng, place=place)
        suffix = out.suffix.lower()
        if layout not in ("bayer", "linear"):
            raise CamcalError(f"unknown layout {layout!r}; choose bayer or linear")
        if suffix == ".dng":
            cam.write_dng(out, Scene.uniform(spectrum), layout=layout, **kw)
        elif suffix in (".jpg", ".jpeg"):
            cam.write_jpeg(out, Scene.uniform(spectrum), **kw)
        elif suffix in (".heic", ".heif"):
            if heic_bits not in (8, 10):
                raise CamcalError(f"--heic-bits must be 8 or 10, got {heic_bits}")
            cam.write_heic(out, Scene.uniform(spectrum), bits=heic_bits, **kw)
        else:
            raise CamcalError("output must end in .dng, .jpg or .heic", out)
        console.print(f"wrote {out}")

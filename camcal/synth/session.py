"""Write a whole calibration session folder from one synthetic camera.

Layout (see ``docs/session-layout.md``)::

    SESSION/
      bias/ dark/ flat/ linearity/ sweep/   frames + frames.csv (sweep: sweep.csv)
      session.toml                          session defaults (fixed-aperture cameras only: the f-number)
      truth.json                            the ground truth, for tests and the demo

``SessionPlan(layout="linear")`` writes LinearRaw DNGs (R, G, B; see
:meth:`camcal.synth.camera.SyntheticCamera.write_dng`) in every stage folder instead of mosaics;
``SessionPlan(fixed_aperture=True)`` writes a camera that records no f-number: no FNumber tag in
its DNGs and JPEGs, no ``f_number`` column in frames.csv and sweep.csv, and the lens's f-number
once, in ``session.toml``.

``SessionPlan(flat_f_numbers=(2.8, 8.0))`` shoots the flats at each f-number, into ``flat/f2.8/`` and
``flat/f8/`` (``flat_folders=False``: all in ``flat/``, told apart by their FNumber tag and frames.csv);
``photo_f_numbers`` adds ``photos/``, one photo of a uniform scene at each f-number (after the flats, the
camera's vignetting at that f-number is the only thing between the photo and a flat image). Both are listed
in ``truth.json`` (``flat.f_numbers``, ``photos``), with the true corner gain at each f-number.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np

from camcal.frame import PLANES
from camcal.io.atomic import atomic_write_text
from camcal.models.spectra import WAVELENGTHS_NM, gaussian_line, planck_radiance
from camcal.synth.camera import Scene, SyntheticCamera, frame_rngs, save_truth

STAGES = ("bias", "dark", "flat", "linearity", "sweep")


@dataclass(frozen=True)
class SessionPlan:
    """What to shoot. Exposure times in s; radiances in W m⁻² sr⁻¹ (in-band) or W m⁻² sr⁻¹ nm⁻¹ (spectral)."""

    stages: tuple[str, ...] = STAGES
    n_bias: int = 16
    bias_exposure_s: float = 1 / 4000
    dark_exposures_s: tuple[float, ...] = (2.0, 8.0, 16.0, 32.0)
    n_dark: int = 4
    temperature_c: float = 24.0
    n_flat: int = 8
    flat_level: float = 0.45
    """Target flat level at the optical centre, as a fraction of full scale."""
    flat_temperature_k: float = 5000.0
    linearity_steps: int = 17
    linearity_factor: float = 2**0.5
    linearity_repeats: int = 1
    """RAW frames per linearity exposure; 2 or more give the frame pairs of EMVA 1288 photon transfer
    (the system gain K from the mean–variance line, :mod:`camcal.calibrate.emva`)."""
    linearity_jpeg: bool = True
    jpeg_tone: str = "srgb"
    jpeg_gamma: float = 1 / 2.2
    jpeg_colour_matrix: tuple[tuple[float, float, float], ...] | None = None
    """The camera's 3x3 colour matrix for JPEGs (camera RGB → output RGB); None: no mixing."""
    sweep_jpeg: bool = True
    """Also write a JPEG twin (``<stem>.jpg``, same exposure) of the first sweep frame at each wavelength:
    the chromaticities from which :mod:`camcal.calibrate.colour_matrix` fits the JPEG colour matrix."""
    sweep_start_nm: float = 400.0
    sweep_stop_nm: float = 700.0
    sweep_step_nm: float = 5.0
    sweep_fwhm_nm: float = 5.0
    n_sweep: int = 3
    lamp_temperature_k: float = 3200.0
    sweep_peak_radiance_w_m2_sr: float = 0.2
    """In-band radiance of the monochromator output at the lamp's brightest wavelength (a QTH lamp through a
    5 nm monochromator into an integrating sphere: 0.2 W m⁻² sr⁻¹ keeps 400 nm at a few % of full scale
    within the exposure cap)."""
    sweep_max_exposure_s: float = 30.0
    """Longest exposure the sweep may use, s."""
    sweep_level: float = 0.35
    """Target level of the brightest channel, fraction of full scale."""
    sweep_reference_unc: float = 0.005
    """Relative standard uncertainty of the reference detector, written to sweep.csv."""
    iso: float = 100.0
    layout: str = "bayer"
    """RAW layout of the DNGs: ``"bayer"`` (CFA mosaics) or ``"linear"`` (LinearRaw R, G, B at the plane size)."""
    fixed_aperture: bool = False
    """A fixed-aperture camera: no f-number in any frame's tags or manifest, one in ``session.toml``."""
    session_defaults: bool = True
    """With ``fixed_aperture``, write the f-number to ``session.toml`` (False: the user forgot it)."""
    flat_f_numbers: tuple[float, ...] = ()
    """f-numbers of the flats (``n_flat`` at each); empty: the reference f-number only, in ``flat/``."""
    flat_folders: bool = True
    """With ``flat_f_numbers``: one ``flat/f<N>/`` folder per f-number (False: all in ``flat/``)."""
    photo_f_numbers: tuple[float, ...] = ()
    """One photo of a uniform scene at each of these f-numbers, in ``photos/`` (not a calibration stage)."""
    photo_radiance: float = 0.02
    """Spectral radiance of the photos' uniform scene, W m⁻² sr⁻¹ nm⁻¹ (flat spectrum)."""


def _csv(rows: list[dict[str, object]]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue()


def _white_spectrum(temperature_k: float) -> np.ndarray:
    b = planck_radiance(temperature_k)
    return b / b.max()


def _corner_gains(camera: SyntheticCamera, f_number: float) -> dict[str, float]:
    """True vignetting at the four plane corners, per plane (smallest), at ``f_number``."""
    g = camera.vignetting_map_at(f_number)
    return {c: float(min(g[i, 0, 0], g[i, 0, -1], g[i, -1, 0], g[i, -1, -1])) for i, c in enumerate(PLANES)}


def exposure_for_level(
    camera: SyntheticCamera, spectrum: np.ndarray, level: float, iso: float, f_number: float
) -> float:
    """Exposure time (s) that puts the brightest channel at ``level`` of full scale on axis."""
    p = camera.params
    rate_dn = camera.channel_rates_e(spectrum, f_number).max() * camera.dn_per_electron(iso)
    span = p.white_dn - max(p.black_level_dn)
    return float(level * span / rate_dn)


@dataclass(frozen=True)
class SweepShot:
    """One monochromator frame of the sweep: file name, scene spectrum, exposure and its sweep.csv row."""

    name: str
    wavelength_nm: float
    spectrum: np.ndarray
    """Spectral radiance on :data:`WAVELENGTHS_NM`, W m⁻² sr⁻¹ nm⁻¹."""
    exposure_s: float
    row: dict[str, object]


def sweep_shots(camera: SyntheticCamera, plan: SessionPlan) -> tuple[list[SweepShot], dict]:
    """The sweep's frames (``plan.n_sweep`` per wavelength) and its truth record.

    In-band radiance follows a ``plan.lamp_temperature_k`` black body scaled to
    ``plan.sweep_peak_radiance_w_m2_sr`` at its brightest; the line is a Gaussian of
    ``plan.sweep_fwhm_nm``. Each wavelength's exposure puts its brightest channel at
    ``plan.sweep_level`` of full scale, capped at ``plan.sweep_max_exposure_s``.
    """
    p = camera.params
    n_ref = p.reference_f_number
    wls = np.arange(plan.sweep_start_nm, plan.sweep_stop_nm + 0.5 * plan.sweep_step_nm, plan.sweep_step_nm)
    lamp = planck_radiance(plan.lamp_temperature_k, wls)
    band = plan.sweep_peak_radiance_w_m2_sr * lamp / planck_radiance(plan.lamp_temperature_k, WAVELENGTHS_NM).max()
    shots = []
    for wl, lb in zip(wls, band, strict=True):
        spectrum = lb * gaussian_line(wl, plan.sweep_fwhm_nm)
        t = exposure_for_level(camera, spectrum, plan.sweep_level, plan.iso, n_ref)
        t = float(f"{min(t, plan.sweep_max_exposure_s):.4g}")
        for j in range(plan.n_sweep):
            name = f"sweep_{wl:05.1f}nm_{j:02d}.dng"
            row = {
                "file": name, "wavelength_nm": float(wl), "radiance_W_m2_sr": float(f"{lb:.6g}"),
                "radiance_unc_W_m2_sr": float(f"{lb * plan.sweep_reference_unc:.6g}"),
                "bandwidth_nm": plan.sweep_fwhm_nm, "exposure_s": t, "iso": plan.iso, "f_number": n_ref,
            }
            shots.append(SweepShot(name, float(wl), spectrum, t, row))
    info = {"wavelength_nm": wls.tolist(), "in_band_radiance_W_m2_sr": band.tolist(),
            "fwhm_nm": plan.sweep_fwhm_nm, "lamp_temperature_k": plan.lamp_temperature_k,
            "exposure_s": [s.exposure_s for s in shots[:: max(1, plan.n_sweep)]]}
    return shots, info


def write_session(
    outdir: str | Path,
    camera: SyntheticCamera,
    plan: SessionPlan | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> Path:
    """Synthesise every stage of ``plan`` into ``outdir``; returns the folder.

    ``progress(stage, done, total)`` is called after each frame when given.
    """
    plan = plan or SessionPlan()
    if plan.layout not in ("bayer", "linear"):
        raise ValueError(f"layout must be 'bayer' or 'linear', got {plan.layout!r}")
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    p = camera.params
    n_ref = p.reference_f_number
    t0 = datetime(2026, 6, 1, 9, 0, 0)
    seq = iter(range(10_000))

    def note(stage: str, i: int, n: int) -> None:
        if progress:
            progress(stage, i + 1, n)

    truth = camera.truth(plan.iso)
    truth["plan"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in plan.__dict__.items()}
    if plan.layout == "linear":
        truth["layout"] = {"name": "linear", "channels": {"R": "R", "G": "G1", "B": "B"},
                           "note": "each linear channel is the Bayer plane named here, at the plane size"}
    tag_n = not plan.fixed_aperture

    class _Cam:  # the camera as the plan shoots it: layout and f-number tag
        def write_dng(self, path, scene, **kw):
            return camera.write_dng(path, scene, layout=plan.layout, tag_f_number=tag_n, **kw)

        def write_jpeg(self, path, scene, **kw):
            return camera.write_jpeg(path, scene, tag_f_number=tag_n, **kw)

    def write_manifest(path: Path, rows: list[dict[str, object]]) -> None:  # no f_number for a fixed lens
        if plan.fixed_aperture:
            rows = [{k: v for k, v in r.items() if k != "f_number"} for r in rows]
        atomic_write_text(path, _csv(rows))

    shoot = _Cam()

    if "bias" in plan.stages:
        d = out / "bias"
        rows = []
        rngs = frame_rngs(p.seed, plan.n_bias, 1)
        for i, rng in enumerate(rngs):
            name = f"bias_{i:03d}.dng"
            shoot.write_dng(d / name, Scene.dark(), exposure_s=plan.bias_exposure_s, iso=plan.iso,
                             f_number=n_ref, rng=rng, capture_time=t0 + timedelta(seconds=next(seq)),
                             temperature_c=plan.temperature_c)
            rows.append({"file": name, "exposure_s": plan.bias_exposure_s, "iso": plan.iso, "f_number": n_ref,
                         "temperature_C": plan.temperature_c})
            note("bias", i, plan.n_bias)
        write_manifest(d / "frames.csv", rows)

    if "dark" in plan.stages:
        d = out / "dark"
        rows = []
        total = len(plan.dark_exposures_s) * plan.n_dark
        rngs = frame_rngs(p.seed, total, 2)
        k = 0
        for t in plan.dark_exposures_s:
            for j in range(plan.n_dark):
                name = f"dark_{t:07.3f}s_{j:02d}.dng"
                shoot.write_dng(d / name, Scene.dark(), exposure_s=t, iso=plan.iso, f_number=n_ref, rng=rngs[k],
                                 capture_time=t0 + timedelta(seconds=next(seq)), temperature_c=plan.temperature_c)
                rows.append({"file": name, "exposure_s": t, "iso": plan.iso, "f_number": n_ref,
                             "temperature_C": plan.temperature_c})
                k += 1
                note("dark", k - 1, total)
        write_manifest(d / "frames.csv", rows)

    if "flat" in plan.stages:
        spec = _white_spectrum(plan.flat_temperature_k)
        f_numbers = plan.flat_f_numbers or (n_ref,)
        by_folder = bool(plan.flat_f_numbers) and plan.flat_folders
        rows = []
        times = []
        for g, n in enumerate(f_numbers):
            d = out / "flat" / f"f{n:g}" if by_folder else out / "flat"
            t = exposure_for_level(camera, spec, plan.flat_level, plan.iso, n)
            times.append(t)
            # the first f-number keeps the single-aperture session's random streams
            rngs = frame_rngs(p.seed, plan.n_flat, 3 if g == 0 else 30 + g)
            for i, rng in enumerate(rngs):
                name = (f"flat_f{n:g}_{i:03d}.dng" if plan.flat_f_numbers else f"flat_{i:03d}.dng")
                shoot.write_dng(d / name, Scene.uniform(spec), exposure_s=t, iso=plan.iso, f_number=n, rng=rng,
                                 capture_time=t0 + timedelta(seconds=next(seq)))
                rows.append({"file": name, "exposure_s": t, "iso": plan.iso, "f_number": n})
                note("flat", g * plan.n_flat + i, plan.n_flat * len(f_numbers))
            if by_folder:
                write_manifest(d / "frames.csv", rows)
                rows = []
        if rows:
            write_manifest(out / "flat" / "frames.csv", rows)
        truth["flat"] = {"exposure_s": times[0], "temperature_k": plan.flat_temperature_k}
        if plan.flat_f_numbers:
            truth["flat"] |= {"f_numbers": list(f_numbers), "exposure_s_per_f_number": times,
                              "folders": [f"flat/f{n:g}/" for n in f_numbers] if by_folder else ["flat/"],
                              "corner_gain": {f"{n:g}": _corner_gains(camera, n) for n in f_numbers},
                              "k": {f"{n:g}": list(camera.vignetting_k_at(n)) for n in f_numbers}}

    if "linearity" in plan.stages:
        d = out / "linearity"
        spec = _white_spectrum(plan.flat_temperature_k)
        # start at ~1 % of full scale and step up past saturation
        t_start = exposure_for_level(camera, spec, 0.01, plan.iso, n_ref)
        times = [t_start * plan.linearity_factor**i for i in range(plan.linearity_steps)]
        rows = []
        rngs = frame_rngs(p.seed, 2 * len(times), 4)
        extra = frame_rngs(p.seed, len(times) * max(plan.linearity_repeats - 1, 0), 14)
        for i, t in enumerate(times):
            name = f"lin_{i:03d}.dng"
            shoot.write_dng(d / name, Scene.uniform(spec), exposure_s=t, iso=plan.iso, f_number=n_ref,
                             rng=rngs[2 * i], capture_time=t0 + timedelta(seconds=next(seq)))
            rows.append({"file": name, "exposure_s": t, "iso": plan.iso, "f_number": n_ref})
            for r in range(1, plan.linearity_repeats):  # the pair partners, right after (read in name order)
                rname = f"lin_{i:03d}_{r}.dng"
                shoot.write_dng(d / rname, Scene.uniform(spec), exposure_s=t, iso=plan.iso, f_number=n_ref,
                                 rng=extra[i * (plan.linearity_repeats - 1) + r - 1],
                                 capture_time=t0 + timedelta(seconds=next(seq)))
                rows.append({"file": rname, "exposure_s": t, "iso": plan.iso, "f_number": n_ref})
            if plan.linearity_jpeg:
                jname = f"lin_{i:03d}.jpg"
                shoot.write_jpeg(d / jname, Scene.uniform(spec), exposure_s=t, iso=plan.iso, f_number=n_ref,
                                  rng=rngs[2 * i + 1], tone=plan.jpeg_tone, gamma=plan.jpeg_gamma,
                                  capture_time=t0 + timedelta(seconds=next(seq)),
                                  colour_matrix=plan.jpeg_colour_matrix)
                rows.append({"file": jname, "exposure_s": t, "iso": plan.iso, "f_number": n_ref})
            note("linearity", i, len(times))
        write_manifest(d / "frames.csv", rows)
        rate = camera.channel_rates_e(spec, n_ref) * camera.dn_per_electron(plan.iso)
        truth["linearity"] = {
            "exposure_s": times,
            "rate_dn_per_s_on_axis": {"R": rate[0], "G": rate[1], "B": rate[2]},
            "jpeg_tone": plan.jpeg_tone,
            "jpeg_gamma": plan.jpeg_gamma,
            "jpeg_colour_matrix": plan.jpeg_colour_matrix,
            "spectrum": "normalised black body",
            "spectrum_temperature_k": plan.flat_temperature_k,
        }

    if "sweep" in plan.stages:
        d = out / "sweep"
        shots, info = sweep_shots(camera, plan)
        rows = []
        rngs = frame_rngs(p.seed, len(shots), 5)
        for k, (shot, rng) in enumerate(zip(shots, rngs, strict=True)):
            shoot.write_dng(d / shot.name, Scene.uniform(shot.spectrum), exposure_s=shot.exposure_s, iso=plan.iso,
                             f_number=n_ref, rng=rng, capture_time=t0 + timedelta(seconds=next(seq)))
            if plan.sweep_jpeg and shot.name.endswith("_00.dng"):  # one twin per wavelength is enough
                shoot.write_jpeg(d / Path(shot.name).with_suffix(".jpg"), Scene.uniform(shot.spectrum),
                                  exposure_s=shot.exposure_s, iso=plan.iso, f_number=n_ref,
                                  rng=np.random.default_rng(rng.integers(2**63)), tone=plan.jpeg_tone,
                                  gamma=plan.jpeg_gamma, colour_matrix=plan.jpeg_colour_matrix,
                                  capture_time=t0 + timedelta(seconds=next(seq)))
            rows.append(shot.row)
            note("sweep", k, len(shots))
        write_manifest(d / "sweep.csv", rows)
        truth["sweep"] = info

    if plan.photo_f_numbers:
        d = out / "photos"
        spectrum = np.full(WAVELENGTHS_NM.size, plan.photo_radiance)
        records = []
        rngs = frame_rngs(p.seed, len(plan.photo_f_numbers), 6)
        for n, rng in zip(plan.photo_f_numbers, rngs, strict=True):
            t = float(f"{exposure_for_level(camera, spectrum, plan.flat_level, plan.iso, n):.4g}")
            name = f"photo_f{n:g}.dng"
            shoot.write_dng(d / name, Scene.uniform(spectrum), exposure_s=t, iso=plan.iso, f_number=n, rng=rng,
                             capture_time=t0 + timedelta(seconds=next(seq)))
            records.append({"file": f"photos/{name}", "f_number": n, "exposure_s": t, "iso": plan.iso,
                            "scene": "uniform", "spectral_radiance_W_m2_sr_nm": plan.photo_radiance,
                            "corner_gain": _corner_gains(camera, n)})
        truth["photos"] = records

    if plan.fixed_aperture and plan.session_defaults:
        atomic_write_text(out / "session.toml", "# camera-wide facts of this session (camcal session defaults)\n"
                    f"f_number = {n_ref!r}  # the fixed lens\n")
    save_truth(out / "truth.json", truth)
    return out

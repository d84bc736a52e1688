"""Library functions only the tests call: thin wrappers and slow oracles, kept here rather than in camcal/."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Literal

import numpy as np

from camcal.calibrate.flat import DEFAULT_TERMS, FlatChecks, FlatOptions, fit_flat, measure_flat
from camcal.calibrate.session import StageFrames
from camcal.calibrate.stack import StackOptions, StackResult, combine_frames
from camcal.errors import CamcalError
from camcal.io.folders import folder_files, load_folder_frame
from camcal.io.manifest import _read_session_toml
from camcal.io.store import load_stage
from camcal.models.correct import Calibration, correct_planes
from camcal.models.dark import DarkModel, as_dark_model
from camcal.models.flat import FlatModel
from camcal.models.response import RESPONSE_KIND, ResponseModel
from camcal.models.spectral import SpectralSensitivity
from camcal.water.models import LampModel, RefinedModel, lamp_angle_reaching
from camcal.water.purewater import pure_water_absorption_per_m
from camcal.water.uncertainty import Uncertain, solve_c


def merge_sweeps(a: SpectralSensitivity, b: SpectralSensitivity, *, scale: bool = True,
                 min_overlap: int = 2) -> SpectralSensitivity:
    """Merge two sweeps (e.g. two gratings) into one on the union of their wavelengths.

    ``b`` is first scaled onto ``a`` by one factor k fitted in the overlap
    (weighted least squares over all planes, k = Σ w a b / Σ w b², w = 1/(u_a² + k² u_b²)
    iterated), with k's uncertainty added to b's. Then, where both sweeps cover a
    wavelength (b interpolated linearly onto it), the values are averaged with
    inverse-variance (SNR) weights; elsewhere the covering sweep is used.
    """
    if a.mode != b.mode or a.deconvolved != b.deconvolved:
        raise CamcalError("cannot merge sweeps of different mode or deconvolution")
    if (a.reference_iso, a.reference_f_number) != (b.reference_iso, b.reference_f_number) and a.mode == "absolute":
        raise CamcalError("cannot merge absolute sweeps normalised to different reference settings")
    wa, wb = a.wavelength_nm, b.wavelength_nm
    grid = np.union1d(wa, wb)

    def on(s: SpectralSensitivity, key: str, which: str) -> tuple[np.ndarray, np.ndarray]:
        src = getattr(s, which)[key]
        inside = (grid >= s.wavelength_nm[0]) & (grid <= s.wavelength_nm[-1])
        return np.where(inside, np.interp(grid, s.wavelength_nm, src), np.nan), inside

    k, u_k = 1.0, 0.0
    overlap = (grid >= max(wa[0], wb[0])) & (grid <= min(wa[-1], wb[-1]))
    planes = a.plane_names
    if b.plane_names != planes:
        raise CamcalError(f"cannot merge sweeps of planes {', '.join(planes)} and {', '.join(b.plane_names)}")
    if scale:
        if overlap.sum() < min_overlap:
            raise CamcalError(f"sweeps overlap at {int(overlap.sum())} wavelengths; need {min_overlap} to scale")
        av = np.concatenate([on(a, p, "values")[0][overlap] for p in planes])
        au = np.concatenate([on(a, p, "uncertainty")[0][overlap] for p in planes])
        bv = np.concatenate([on(b, p, "values")[0][overlap] for p in planes])
        bu = np.concatenate([on(b, p, "uncertainty")[0][overlap] for p in planes])
        for _ in range(5):
            wgt = 1.0 / np.maximum(au**2 + k**2 * bu**2, 1e-300)
            k = float(np.sum(wgt * av * bv) / np.sum(wgt * bv**2))
        u_k = float(1.0 / math.sqrt(np.sum(wgt * bv**2)))
    vals, uncs = {}, {}
    for p in planes:
        va, ina = on(a, p, "values")
        ua, _ = on(a, p, "uncertainty")
        vb, inb = on(b, p, "values")
        ub, _ = on(b, p, "uncertainty")
        vb, ub = k * vb, np.hypot(k * ub, u_k * vb)
        wa_ = np.where(ina, 1.0 / np.maximum(ua, 1e-300) ** 2, 0.0)
        wb_ = np.where(inb, 1.0 / np.maximum(ub, 1e-300) ** 2, 0.0)
        tot = wa_ + wb_
        vals[p] = (np.nan_to_num(va) * wa_ + np.nan_to_num(vb) * wb_) / tot
        uncs[p] = 1.0 / np.sqrt(tot)
    notes = (*a.notes, *b.notes, f"merged: second sweep scaled by {k:.6g} ± {u_k:.2g}")
    bws = [x for x in (a.bandwidth_nm, b.bandwidth_nm) if x]
    return SpectralSensitivity(grid, vals, uncs, a.units, a.mode, a.reference_iso, a.reference_f_number,
                               max(bws) if bws else None, a.deconvolved, {**b.n_frames, **a.n_frames}, notes)


def iter_folder(folder: str | Path):
    """Yield ``(path, frame)`` for every image of a folder, manifest applied, one at a time.

    Frames are read lazily so memory does not grow with the number of frames.
    """
    files, manifest = folder_files(folder)
    for p in files:
        yield p, load_folder_frame(p, manifest)


def combine_folder(folder: str | Path, options: StackOptions = StackOptions(), **kwargs) -> StackResult:  # noqa: B008
    """:func:`combine_frames` over every image of ``folder`` (its ``frames.csv`` applied).

    Files listed in ``frames.csv`` but missing from the folder are an error.
    """
    files, manifest = folder_files(folder, kwargs.pop("manifest", None))
    return combine_frames(files, options, manifest=manifest, **kwargs)


def read_session_defaults(path: str | Path) -> dict[str, float | str]:
    """Read a ``session.toml`` into :class:`camcal.frame.Exposure` keywords (camera facts,
    :data:`CAMERA_KEYS`, are checked too and left to :func:`session_camera_facts`).

    The file is TOML with top-level keys from :data:`SESSION_KEYS` (``f_number``, ``iso``,
    ``exposure_s`` in s, ``temperature_C`` in °C), each a number within :data:`PLAUSIBLE_RANGE`,
    and ``utc_offset`` (:data:`SESSION_TEXT_KEYS`), text ``"+HH:MM"`` between −12:00 and +14:00.
    A value fills what a frame's file does not hold (or holds only as LibRaw's reading of a maker
    header); ``frames.csv`` still overrides it. Unknown keys, tables, non-numbers and implausible
    values are refused, naming the file and the key.

    Returns
    -------
    dict such as ``{"f_number": 2.8}`` (Exposure field names).
    """
    return _read_session_toml(Path(path))[0]


def subtract_dark(planes: np.ndarray, model: DarkModel, exposure_s: float, iso: float | None = None) -> np.ndarray:
    """Remove the expected dark frame (bias + β·t) from (4, h, w) planes in DN; float32 result.

    A thin wrapper of the one correction path, :func:`camcal.models.correct.correct_planes` (no flat, no mask).
    """
    planes = np.asarray(planes)
    return correct_planes(planes, Calibration(dark=model), exposure_s=exposure_s, iso=iso, white_level_dn=np.inf,
                          black_level_dn=np.zeros(planes.shape[0])).signal_dn


def correct_flat(planes: np.ndarray, model: FlatModel, with_prnu: bool = False) -> np.ndarray:
    """Divide dark-subtracted planes by the flat-field gain (1 at the optical centre).

    Parameters
    ----------
    planes : (C, h, w) DN above dark (subtract bias/dark first), channels as in ``model.channels``.
    model : the fitted :class:`FlatModel`.
    with_prnu : also divide by the PRNU map.

    Returns
    -------
    (C, h, w) float32: the signal the pixel would have at the optical centre.
    """
    planes = np.asarray(planes)
    cal = Calibration.of(flat=model, with_prnu=with_prnu)
    return correct_planes(planes, cal, exposure_s=None, iso=None, white_level_dn=np.inf,
                          black_level_dn=np.zeros(planes.shape[0]), channels=tuple(model.channels)).signal_dn


def flat_of_folder(
    flat_folder: str | Path | StageFrames,
    dark: DarkModel | str | Path | None = None,
    *,
    model: Literal["radial", "2d"] = "radial",
    downsample: int | None = None,
    n_terms: int = DEFAULT_TERMS,
    degree_2d: int = 4,
    with_prnu: bool = True,
    method: str = "sigma_clip",
    sigma: float = 3.0,
    checks: FlatChecks = FlatChecks(),  # noqa: B008
    jobs: int | None = 1,
    progress: Callable | None = None,
) -> FlatModel:
    """Master flat of a folder, then the vignetting model and PRNU (see :func:`fit_flat_planes`).

    Parameters
    ----------
    flat_folder : folder of RAW flat frames (+ optional ``frames.csv``).
    dark : a ``camcal.models.dark.DarkModel``, a path to a dark model JSON, or None (subtract the
        files' black level only).
    model, downsample, n_terms, degree_2d, with_prnu : see :func:`fit_flat_planes`.
    method, sigma : combine method (``mean``, ``median``, ``sigma_clip``) and clip threshold.
    checks : exposure limits (:class:`FlatChecks`).
    jobs, progress : passed to :func:`camcal.calibrate.stack.combine_frames`.
    """
    options = FlatOptions(model, downsample, n_terms, degree_2d, with_prnu, method, sigma, checks)
    dark_model = as_dark_model(dark)
    return fit_flat(measure_flat(flat_folder, dark_model, options, jobs=jobs, progress=progress), dark_model, options)


def load_response(path: str | Path) -> dict[str, ResponseModel]:
    """Read what :func:`save_response` wrote: ``{kind: ResponseModel}``."""
    data, _ = load_stage(path, RESPONSE_KIND)  # validated against camcal/schemas/response-1.schema.json
    try:
        return {str(k): ResponseModel.from_dict(v) for k, v in data["models"].items()}
    except CamcalError as exc:
        raise CamcalError(exc.message, path) from None


def monte_carlo_sigma(forward: Callable[[float, np.ndarray], np.ndarray], param: Uncertain, ratio: float,
                      samples: int = 400, seed: int = 0) -> float:
    """Standard deviation of C (µg/L) when ``param`` is drawn from N(value, σ) and ``ratio`` re-inverted with
    each draw (the Monte Carlo counterpart of :func:`term_sigma_c`)."""
    rng = np.random.default_rng(seed)
    draws = param.value + param.sigma * rng.standard_normal(samples)
    c = np.array([solve_c(lambda cc, p=p: forward(p, cc), ratio) for p in draws])
    return float(np.nanstd(c, ddof=1))



def to_colour(s: SpectralSensitivity):
    """colour-science :class:`RGB_CameraSensitivities` of R, G (mean of G1, G2), B of ``s``."""
    from colour.characterisation import RGB_CameraSensitivities

    rgb = s.rgb()
    data = np.column_stack([rgb["R"], rgb["G"], rgb["B"]])
    return RGB_CameraSensitivities(data, s.wavelength_nm, name=f"camcal c(λ) [{s.units}]")


def to_colour_planes(s: SpectralSensitivity):
    """colour-science :class:`MultiSpectralDistributions` of ``s``'s planes (R, G1, G2, B)."""
    import colour

    data = np.column_stack([s.values[p] for p in s.plane_names])
    return colour.MultiSpectralDistributions(data, s.wavelength_nm, labels=list(s.plane_names),
                                             name=f"camcal c(λ) planes [{s.units}]")


def refined_at_wavelength(wavelength_nm: float, **kwargs) -> RefinedModel:
    """The refined model at one wavelength: ``water_absorption_per_m`` from Pope & Fry (1997) there."""
    return RefinedModel(water_absorption_per_m=float(pure_water_absorption_per_m(wavelength_nm)), **kwargs)


def lamp_toward(lamp: LampModel, offset_x_m: float, offset_y_m: float, depth_m: float) -> LampModel:
    """The same lamp seen from a disk point offset by (x, y) m from the disk centre (x away from the lamp's
    foot): the lamp angle of the refracted ray reaching that point."""
    x0 = float(lamp.horizontal_offset_m(depth_m))
    target = float(np.hypot(x0 + offset_x_m, offset_y_m))
    return replace(lamp, lamp_angle_rad=lamp_angle_reaching(lamp.height_m, depth_m, target, lamp.n_water))


def read_var_dn2(plan) -> np.ndarray | None:
    """(4, h, w) read-noise variance of an apply plan's dark model at its ISO, DN²."""
    dark = plan.calibration.dark
    return None if dark is None else dark.read_noise_dn.astype(np.float32) ** 2


def band_statistics_reference(x: np.ndarray, method: str, sigma: float) -> tuple[np.ndarray, ...]:
    """The oracle of :func:`camcal.calibrate.band_stats.band_statistics`: its definition, with :func:`numpy.sort`
    along the frame axis and a boolean mask per pass over every value (no sorting network, no rank-wise clipping,
    no float32 sums).

    The arithmetic is the module's: float32 deviations ``d`` from the float32 median (exact for DN: whole or half
    DN); the sums of the kept ``d`` and ``d²`` in float64, rounded once to float32 (what the module's float32 sums
    give where they are exact, and its float64 sums of the loud pixels everywhere else); the variance of all
    values ``max(Σd² − (Σd)²/n, 0)/(n − 1)`` in float32; quartiles by linear interpolation of the sorted
    deviations in float32; pass 1 keeps ``|d| ≤ σ·IQR/1.349`` (the plain standard deviation where the IQR is 0),
    pass 2 keeps ``|d − m₁| ≤ σ·s₁ + 10⁻⁶·|median|``; moments in float64 from the rounded sums. On integer bands
    of up to ``NETWORK_MAX_FRAMES`` frames its results equal the module's bit for bit; on float32 bands (and
    longer integer ones) they may differ by the float32 rounding of the module's sums.
    """
    n = x.shape[0]
    s = np.sort(x.astype(np.float32), axis=0)
    med = s[n // 2] if n % 2 else np.float32(0.5) * (s[n // 2 - 1] + s[n // 2])
    d = s - med

    def sums(keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        dd = np.where(keep, d.astype(np.float64), 0.0)
        return (dd.sum(axis=0).astype(np.float32), (dd * dd).sum(axis=0).astype(np.float32),
                keep.sum(axis=0))

    def moments(keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s1, s2, cnt = sums(keep)
        s1d, s2d, c = s1.astype(np.float64), s2.astype(np.float64), cnt.astype(np.float64)
        with np.errstate(invalid="ignore", divide="ignore"):
            m = s1d / c
            v = (np.maximum(s2d - s1d * m, 0) / (c - 1)).astype(np.float32)
        v[cnt <= 1] = np.nan
        return m.astype(np.float32), v, cnt

    sd, sdd, _ = sums(np.ones(d.shape, bool))
    mean_all = med.astype(np.float64) + sd.astype(np.float64) / n
    with np.errstate(invalid="ignore"):
        var_all = (np.maximum(sdd - sd * sd / n, 0) / (n - 1) if n > 1
                   else np.full(sd.shape, np.nan, np.float32))
    if method == "median":
        return med, mean_all, var_all, np.full(med.shape, n), var_all, mean_all

    def quantile(q: float) -> np.ndarray:
        lo = int(np.floor(q * (n - 1)))
        hi = min(lo + 1, n - 1)
        return d[lo] + np.float32(q * (n - 1) - lo) * (d[hi] - d[lo])

    scale = (quantile(0.75) - quantile(0.25)) / np.float32(1.349)
    scale = np.where(scale > 0, scale, np.fmax(np.sqrt(var_all), 0))
    thr = (sigma * scale).astype(np.float32)
    m, v, _ = moments((d >= -thr) & (d <= thr))
    thr = sigma * np.fmax(np.sqrt(v), 0).astype(np.float32) + np.float32(1e-6) * np.abs(med)
    m, v, cnt = moments((d >= m - thr) & (d <= m + thr))
    mean = m.astype(np.float64) + med.astype(np.float64)
    return mean, mean, v, cnt, var_all, mean_all

"""Spectral sensitivity c(λ) per CFA plane from a monochromator sweep (seed §3.1).

The seed defines, at constant ISO and aperture,

    c(λ) = d(λ) / (r(λ) · t(λ))                                    (seed §3.1)

with d the data (DN above dark), r the radiance and t the exposure time. camcal
normalises every frame to the reference setting (ISO_ref, N_ref) with
:func:`camcal.models.exposure.frame_relative_exposure` (seed §2.1), so t becomes the
relative exposure x = (ISO·t/N²)/(ISO_ref/N_ref²) and d/x is the DN rate at the
reference setting.

Convention stored (finite bandwidth)
------------------------------------
A monochromator does not emit one wavelength: at setting λ_j it emits
L(λ') = L_j · φ_j(λ' − λ_j), where L_j is the *band-integrated* radiance the
reference detector reports (W m⁻² sr⁻¹) and φ_j the slit function (unit
integral, nm⁻¹, FWHM = ``bandwidth_nm``). The DN rate is then (seed §3.1 with a
finite band)

    d_j / x_j = ∫ c(λ') L(λ') dλ' = L_j · (c ⊛ φ_j)(λ_j)

so the ratio rate / L_j measures the **slit-weighted sensitivity**
(c ⊛ φ_j)(λ_j), in DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm (the same unit as c,
because (W m⁻² sr⁻¹ nm⁻¹)·nm = W m⁻² sr⁻¹). That is what
``SpectralSensitivity.values`` holds when ``deconvolved`` is False. Its bias
against c(λ) is, to second order, (σ²/2)·c''(λ) with σ = FWHM/2.3548 for a
Gaussian slit (FWHM²/24·c'' for a triangular one); :meth:`SpectralSensitivity.summary`
reports an estimate of it. With ``deconvolve=True`` the values are a Tikhonov
regularised estimate of c(λ) itself at the same wavelengths
(:func:`deconvolve_slit`).

Relative mode divides everything by the largest value over all planes (the
reference radiance may then be in arbitrary units); absolute mode keeps
DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm at (ISO_ref, N_ref), on axis (the flat
model brings the region of interest to the optical centre).

References
----------
Burggraaff, O. et al. (2019). Standardized spectral and radiometric calibration
of consumer cameras. Optics Express 27(14), 19075 (SPECTACLE; its CSV layout is
read and written by :mod:`camcal.curves.files`).
Hansen, P. C. (2010). Discrete Inverse Problems. SIAM (Tikhonov, GCV).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.interpolate import CubicSpline

from camcal.calibrate.robust import median_and_mad
from camcal.calibrate.screen import FrameFacts, StageJudge
from camcal.calibrate.session import SWEEP_CSV, SWEEP_REQUIRED
from camcal.errors import CamcalError, FrameLeftOut, TooFewFrames
from camcal.frame import MONO, PLANES, RGB, Frame, split_planes
from camcal.io.manifest import exposure_overrides, read_manifest, safe_member
from camcal.io.read import load_frame
from camcal.models.correct import Calibration, correct_planes
from camcal.models.dark import DarkModel, as_dark_model
from camcal.models.exposure import frame_relative_exposure
from camcal.models.flat import FlatModel, as_flat_model
from camcal.models.spectral import (
    ABSOLUTE_UNITS,
    DEFAULT_REFERENCE_F_NUMBER,
    DEFAULT_REFERENCE_ISO,
    SpectralSensitivity,
    to_relative,
)
from camcal.region import DEFAULT_ROI_FRACTION, Region, central_roi
from camcal.threads import thread_count
from camcal.units import IN_BAND_RADIANCE


class SweepWarning(UserWarning):
    """A recoverable problem in a sweep (a skipped saturated frame, a missing flat)."""


class LeftOutWarning(SweepWarning, FrameLeftOut):
    """A sweep frame left out (saturated, or no light recorded); ``camcal calibrate`` lists these in its table."""


MIN_WAVELENGTHS = 4
"""Fewest wavelengths a calibration's c(λ) must keep (:func:`require_wavelengths`, ``camcal calibrate``): the
profile's c(λ) is read off its samples with a not-a-knot cubic spline (:mod:`camcal.apply.radiance`), which needs four;
with fewer, radiance falls back to linear interpolation, biased by the curve's curvature. ``camcal sweep`` on
its own measures whatever wavelengths it is given (at least one)."""

NO_LIGHT_FRACTION = 0.05
"""A sweep frame whose signal per unit exposure and reference radiance is below this fraction of what its repeats
at the same wavelength recorded (or, alone at its wavelength, of both neighbouring wavelengths) recorded no light:
a closed shutter or a missed trigger, while the reference detector saw light. A camera's c(λ) changes by a few
percent between neighbouring 5 nm steps, never twentyfold."""

NO_LIGHT_SIGMAS = 5.0
"""A lone frame is judged against its neighbours only when both are lit by more than this many standard
uncertainties (so the dark ends of a sweep, where every frame is dim, are never judged)."""


# ---- reading a sweep ---------------------------------------------------------------------
@dataclass(frozen=True)
class SweepRow:
    """One row of ``sweep.csv`` (one frame at one monochromator setting)."""

    path: Path
    wavelength_nm: float
    radiance_w_m2_sr: float
    """Band-integrated radiance from the reference detector, W m⁻² sr⁻¹ (or arbitrary units)."""
    radiance_unc_w_m2_sr: float | None
    bandwidth_nm: float | None
    overrides: dict[str, float | None]


def read_sweep(sweep_folder: str | Path) -> list[SweepRow]:
    """Read and check ``SWEEP/sweep.csv``; every listed frame must exist inside the folder.

    Raises
    ------
    CamcalError
        Missing manifest, a row whose frame is missing, a path leaving the folder,
        negative or non-numeric values (from :func:`camcal.io.manifest.read_manifest`).
    """
    folder = Path(sweep_folder)
    if not folder.is_dir():
        raise CamcalError("is not a folder (expected a sweep folder holding sweep.csv)", folder)
    csv_path = folder / SWEEP_CSV
    if not csv_path.is_file():
        raise CamcalError(f"has no {SWEEP_CSV} (columns file,wavelength_nm,radiance_W_m2_sr,...)", folder)
    return sweep_rows(folder, read_manifest(csv_path, required=SWEEP_REQUIRED))


def sweep_rows(sweep_folder: str | Path, manifest: Mapping[str, Mapping[str, float | str | None]]) -> list[SweepRow]:
    """The :class:`SweepRow` of each row of an already read ``sweep.csv`` (:func:`camcal.io.manifest.read_manifest`,
    e.g. by :func:`camcal.calibrate.session.index_session`); every listed frame must exist inside the folder."""
    folder = Path(sweep_folder)
    csv_path = folder / SWEEP_CSV
    if not manifest:
        raise CamcalError("lists no frames", csv_path)
    out = []
    for name, rec in manifest.items():
        path = safe_member(folder, name, csv_path)
        if not path.is_file():
            raise CamcalError(f"lists {name!r} at {rec['wavelength_nm']:g} nm, which is not in the folder", csv_path)
        out.append(SweepRow(
            path=path,
            wavelength_nm=float(rec["wavelength_nm"]),  # type: ignore[arg-type]
            radiance_w_m2_sr=float(rec["radiance_W_m2_sr"]),  # type: ignore[arg-type]
            radiance_unc_w_m2_sr=None if rec.get("radiance_unc_W_m2_sr") is None
            else float(rec["radiance_unc_W_m2_sr"]),  # type: ignore[arg-type]
            bandwidth_nm=None if rec.get("bandwidth_nm") is None else float(rec["bandwidth_nm"]),  # type: ignore[arg-type]
            overrides=exposure_overrides(dict(rec)),
        ))
    return out


def _check_roi(roi: tuple[int, int, int, int], shape_hw: tuple[int, int], where: Path) -> tuple[int, int, int, int]:
    x0, y0, x1, y1 = (int(v) for v in roi)
    h, w = shape_hw
    if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
        raise CamcalError(f"ROI {roi} (x0,y0,x1,y1 in half-resolution plane pixels) is outside the {w}x{h} planes",
                          where)
    return x0, y0, x1, y1


@dataclass(frozen=True)
class _FrameResult:
    row: SweepRow
    planes: np.ndarray  # (C, hr, wr) float32, dark-subtracted, flat-corrected DN (C = 4 Bayer, 3 linear RAW)
    invalid: np.ndarray  # (C, hr, wr) bool: known defects, saturated or clipped (camcal.models.correct)
    relative_exposure_s: float
    saturated_fraction: float  # of the ROI, worst plane, outside known defects
    defect_saturated: int  # known defects at the white level in the ROI (masked, never counted as saturation)


def _process_frame(row: SweepRow, cal: Calibration, roi: tuple[int, int, int, int], ref_iso: float, ref_n: float,
                   roi_shape_check: Callable[[Frame], None], frame: Frame | None = None) -> _FrameResult:
    """Decode one file once (unless its ``frame`` is given) and correct its ROI through :mod:`camcal.models.correct`
    (dark, flat, invalid mask)."""
    frame = load_frame(row.path, row.overrides) if frame is None else frame
    if frame.kind != "raw":
        raise CamcalError("is not a RAW file; the spectral sweep needs linear RAW data", row.path)
    roi_shape_check(frame)
    x_rel = frame_relative_exposure(frame.exposure, ref_iso, ref_n, row.path)
    x0, y0, x1, y1 = roi
    window = (slice(y0, y1), slice(x0, x1))
    if frame.layout == "bayer":
        planes = split_planes(frame.data[2 * y0: 2 * y1, 2 * x0: 2 * x1], frame.cfa_pattern)
        full = (4, frame.shape[0] // 2, frame.shape[1] // 2)
    elif frame.layout == "mono":  # a monochrome sensor: its one plane Y at full resolution
        planes = frame.data[None, y0:y1, x0:x1].astype(np.float32)
        full = (1, *frame.shape)
    else:  # linear RAW: R, G, B at full resolution
        planes = np.moveaxis(frame.data[y0:y1, x0:x1], -1, 0).astype(np.float32)
        full = (3, *frame.shape)
    corr = correct_planes(planes, cal, exposure_s=frame.exposure.exposure_s, iso=frame.exposure.iso,
                          channels=frame.channel_names, cfa_pattern=frame.cfa_pattern,
                          white_level_dn=float(frame.white_level_dn), black_level_dn=frame.black_vector().ravel(),
                          full_shape=full, window=window, path=row.path, inplace=True)
    defect_sat = int(np.count_nonzero(corr.clipped & corr.defective))
    return _FrameResult(row, corr.signal_dn, corr.invalid, x_rel, float(corr.saturated_fraction().max()), defect_sat)


def _robust_mask(m: np.ndarray, valid: np.ndarray | None = None, nsigma: float = 5.0) -> np.ndarray:
    """Valid pixels within ``nsigma`` robust sigmas of the plane median; (hr, wr) bool.

    The robust sigma is the MAD scaled to a normal law (:func:`camcal.calibrate.robust.median_and_mad`, equal to
    ``scipy.stats.median_abs_deviation`` with ``scale="normal"``).

    Median and MAD come from the ``valid`` pixels (all when None), every other row and column when the
    plane has more than 40 000 pixels (their relative sampling error, ~1/√(n/4) < 1 %, moves the 5σ
    threshold by less than 0.05σ).
    """
    ok = np.ones(m.shape, bool) if valid is None else valid
    sub = (m[::2, ::2], ok[::2, ::2]) if m.size > 40_000 else (m, ok)
    sample = sub[0][sub[1]]
    if sample.size == 0:
        return np.zeros(m.shape, bool)
    med, mad = median_and_mad(sample)
    if mad <= 0:
        return ok.copy()
    return ok & (np.abs(m - med) <= nsigma * mad)


def combine_wavelength(results: Sequence[_FrameResult]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-plane sensitivity of one monochromator setting from its frames.

    Each frame's ROI is divided by its relative exposure x_k and in-band radiance
    L_k: y_k = d_k / (x_k L_k) (seed §3.1). Per pixel the temporal mean and
    variance (ddof=1) over the frames are taken; pixels more than 5 robust
    sigmas from the ROI median (hot or dead) and pixels invalid in any frame (known defects, saturated:
    :mod:`camcal.models.correct`) are dropped; the value is the ROI
    mean and its noise variance the mean temporal variance over
    (n_frames · n_pixels). With one frame the spatial variance is used
    instead (it includes PRNU: conservative).

    Returns
    -------
    value (C,), noise standard uncertainty (C,), relative reference uncertainty (scalar array)
    """
    n = len(results)
    c = results[0].planes.shape[0]
    value = np.empty(c)
    u_noise = np.empty(c)
    scale = np.array([1.0 / (r.relative_exposure_s * r.row.radiance_w_m2_sr) for r in results], np.float32)
    for p in range(c):
        y = np.stack([r.planes[p] for r in results])
        y *= scale[:, None, None]
        m = y.sum(axis=0)
        m *= np.float32(1.0 / n)
        valid = ~np.any(np.stack([r.invalid[p] for r in results]), axis=0)
        mask = _robust_mask(m, valid)
        npix = int(mask.sum())
        if npix == 0:
            raise CamcalError(f"no valid pixel is left in plane {p} of the ROI at "
                              f"{results[0].row.wavelength_nm:g} nm (all defective or saturated)",
                              results[0].row.path)
        value[p] = float(np.mean(m, where=mask, dtype=np.float64))
        if n > 1:
            # per-pixel temporal variance (ddof=1) in float32 about the pixel's mean (no cancellation), then
            # its mean over the good pixels in float64
            y -= m
            y *= y
            var = y.sum(axis=0)
            var *= np.float32(1.0 / (n - 1))
            u_noise[p] = math.sqrt(float(np.mean(var, where=mask, dtype=np.float64)) / (n * npix))
        else:
            u_noise[p] = math.sqrt(float(np.var(m, where=mask, dtype=np.float64)) / npix)
    rel = [r.row.radiance_unc_w_m2_sr / r.row.radiance_w_m2_sr for r in results
           if r.row.radiance_unc_w_m2_sr is not None]
    # the frames of one setting share the reference reading's calibration: fully correlated, not /sqrt(n)
    u_ref = float(np.mean(rel)) if rel else 0.0
    return value, u_noise, np.asarray(u_ref)


@dataclass(frozen=True)
class SweepOptions:
    """Options of the sweep stage.

    Attributes
    ----------
    roi : a :class:`camcal.region.Region` (photo pixels, rounded outward to whole planes' pixels), (x0, y0, x1, y1)
        in plane pixels (half resolution for Bayer), or a fraction of each side for a centred box (default 0.2).
    mode : "absolute" (DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm at the reference setting) or "relative" (divided by
        the largest value over all planes).
    deconvolve : remove the slit function (``bandwidth_nm`` required) with :func:`deconvolve_slit`.
    slit : slit function shape for deconvolution.
    regularisation : Tikhonov weight for deconvolution (None: chosen by GCV).
    reference_iso, reference_f_number : the reference setting (seed §2.1).
    max_saturated_fraction : a frame with more than this fraction of clipped ROI pixels is skipped with a
        :class:`SweepWarning`.
    min_frames : frames that must remain per wavelength after skipping.
    """

    roi: Region | tuple[int, int, int, int] | float | None = None
    mode: Literal["relative", "absolute"] = "absolute"
    deconvolve: bool = False
    slit: Literal["gaussian", "triangular"] = "gaussian"
    regularisation: float | None = None
    reference_iso: float = DEFAULT_REFERENCE_ISO
    reference_f_number: float = DEFAULT_REFERENCE_F_NUMBER
    max_saturated_fraction: float = 1e-3
    min_frames: int = 1

    def check(self) -> None:
        if self.mode not in ("relative", "absolute"):
            raise CamcalError(f"mode must be 'relative' or 'absolute', got {self.mode!r}")


@dataclass(frozen=True)
class SweepSetting:
    """The measurement at one monochromator setting (the unsaturated frames at one wavelength combined).

    Attributes
    ----------
    wavelength_nm : the setting, nm.
    value : (C,) c per plane before deconvolution, DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm at the reference
        setting (:func:`combine_wavelength`).
    noise_unc : (C,) its standard uncertainty from the frames' noise, same unit.
    reference_unc_rel : relative standard uncertainty of the reference radiance.
    n_frames : frames used.
    bandwidth_nm : the row's ``bandwidth_nm`` (nm), None when not given.
    """

    wavelength_nm: float
    value: np.ndarray
    noise_unc: np.ndarray
    reference_unc_rel: float
    n_frames: int
    bandwidth_nm: float | None


@dataclass(frozen=True)
class SweepMeasurement:
    """What :func:`measure_sweep` read from the sweep's files: one :class:`SweepSetting` per
    wavelength (ascending), the plane names, notes (dropped wavelengths, saturating defects), ``sweep.csv`` and
    the frames left out with their reasons."""

    settings: tuple[SweepSetting, ...]
    channels: tuple[str, ...]
    notes: tuple[str, ...]
    csv_path: Path
    left_out: tuple[tuple[str, str], ...] = ()
    """(file name, reason) of the frames left out: saturated in the ROI, or no light recorded."""
    n_listed: int = 0
    """Wavelengths listed in ``sweep.csv``."""


def measure_sweep(
    sweep_folder: str | Path,
    rows: Sequence[SweepRow] | None = None,
    options: SweepOptions = SweepOptions(),  # noqa: B008
    *,
    dark: DarkModel | str | Path | None = None,
    flat: FlatModel | str | Path | None = None,
    jobs: int | None = 2,
    progress: Callable[[int, int], None] | None = None,
    judge: StageJudge | None = None,
) -> SweepMeasurement:
    """The file step of the sweep (seed §3.1): decode every frame of ``rows`` once (in threads), correct its ROI
    (:mod:`camcal.models.correct`; the dark model subtracted per pixel at each frame's exposure, else the file's
    black level; the ROI divided by the flat's smooth gain, so absolute values refer to the optical axis), skip
    saturated frames and combine each wavelength (:func:`combine_wavelength`). :func:`fit_sweep` turns the
    measurement into c(λ).

    ``sweep_folder`` holds the frames and ``sweep.csv`` (columns ``file, wavelength_nm, radiance_W_m2_sr``
    required; ``radiance_unc_W_m2_sr, bandwidth_nm, exposure_s, iso, f_number`` optional); ``rows``: its rows
    already read (:func:`sweep_rows` of the session index's manifest), None reads ``sweep_folder/sweep.csv``.
    ``jobs``: decoding threads (None: :func:`camcal.threads.thread_count`); ``progress(done, total)`` after each
    frame.

    ``judge``: the stage's :class:`camcal.calibrate.screen.StageJudge`: each frame is judged as it is decoded
    (unreadable, a copy, another camera, not RAW...) and a frame left out is skipped, as if its row were not
    in ``sweep.csv``; the frames' geometry is then the session's (:attr:`camcal.calibrate.screen.Majority.layout` and
    ``raw_shape``), which every frame kept has. Without a judge, an unreadable frame is an error.

    Raises
    ------
    CamcalError
        Bad manifest, missing frame, path outside the folder, negative or zero radiance, non-RAW frames,
        mismatched sizes, too few unsaturated frames.
    """
    options.check()
    rows = list(rows) if rows is not None else read_sweep(sweep_folder)
    reference_iso, reference_f_number = options.reference_iso, options.reference_f_number
    roi, max_saturated_fraction, min_frames = options.roi, options.max_saturated_fraction, options.min_frames
    csv_path = Path(sweep_folder) / SWEEP_CSV
    for r in rows:
        if r.radiance_w_m2_sr <= 0:
            raise CamcalError(f"{r.path.name} at {r.wavelength_nm:g} nm: radiance_W_m2_sr must be positive, "
                              f"got {r.radiance_w_m2_sr:g}", csv_path)
    dark = as_dark_model(dark)
    flat = as_flat_model(flat)
    notes: list[str] = []

    def warn(msg: str) -> None:
        notes.append(msg)
        warnings.warn(msg, SweepWarning, stacklevel=4)

    if options.mode == "absolute" and flat is None:
        warn("no flat model: absolute values refer to the ROI, not the optical axis (vignetting not removed)")
    if judge is not None and judge.majority.layout is not None and judge.majority.raw_shape is not None:
        # the session's RAW geometry: every frame the judge keeps has it (no frame decoded twice)
        layout, full_shape = judge.majority.layout, judge.majority.raw_shape
        names = PLANES if layout == "bayer" else MONO if layout == "mono" else RGB
    else:  # geometry from the first frame (decoded again by the pool)
        first = load_frame(rows[0].path, rows[0].overrides)
        if first.kind != "raw":
            raise CamcalError("is not a RAW file; the spectral sweep needs linear RAW data", rows[0].path)
        full_shape, layout, names = first.shape, first.layout, first.channel_names
        del first
    shape_hw = (full_shape[0] // 2, full_shape[1] // 2) if layout == "bayer" else full_shape
    if isinstance(roi, Region):
        ys, xs = roi.window(shape_hw, 2 if layout == "bayer" else 1, Path(sweep_folder))
        box = (xs.start, ys.start, xs.stop, ys.stop)
    elif roi is None:
        box = central_roi(shape_hw, DEFAULT_ROI_FRACTION)
    elif isinstance(roi, float | int):
        box = central_roi(shape_hw, float(roi))
    else:
        box = _check_roi(tuple(roi), shape_hw, Path(sweep_folder))  # type: ignore[arg-type]

    cal = Calibration.of(dark, flat)
    if cal.flat_gain is not None and cal.flat_gain.shape[1:] != shape_hw:
        raise CamcalError(f"flat model planes {cal.flat_gain.shape[1:]} do not match the sweep frames' {shape_hw}",
                          Path(sweep_folder))
    def shape_check(frame: Frame) -> None:
        if frame.layout != layout:
            raise CamcalError(f"is a {frame.layout} RAW file, the sweep's first frame is {layout}", frame.path)
        if frame.shape != full_shape:
            raise CamcalError(f"frame is {frame.shape[1]}x{frame.shape[0]} pixels, the sweep's first frame is "
                              f"{full_shape[1]}x{full_shape[0]}", frame.path)

    def work(row: SweepRow) -> tuple[FrameFacts | None, _FrameResult | None]:
        if judge is None:
            return None, _process_frame(row, cal, box, reference_iso, reference_f_number, shape_check)
        frame, facts = judge.load(row.path, lambda p: load_frame(p, row.overrides))
        if frame is None or facts.check_error is not None or judge.majority.mismatch(facts) is not None:
            return facts, None  # left out whatever else the judge finds: nothing to measure
        return facts, _process_frame(row, cal, box, reference_iso, reference_f_number, shape_check, frame)

    # group by wavelength (file order kept inside a group)
    groups: dict[float, list[SweepRow]] = {}
    for r in rows:
        groups.setdefault(r.wavelength_nm, []).append(r)
    wls = sorted(groups)
    ordered = [r for wl in wls for r in groups[wl]]
    threads = thread_count(jobs, len(ordered), full_shape[0] * full_shape[1])

    def measure() -> SweepMeasurement:
        settings: list[SweepSetting] = []
        defect_saturated: dict[float, int] = {}
        done = 0
        total = len(rows)
        left_out: list[tuple[str, str]] = []
        dropped: list[str] = []
        single: dict[float, tuple[SweepRow, float]] = {}  # lone frames, judged against their neighbours
        listed: set[float] = set()  # wavelengths with a frame the judge kept (all, without a judge)

        def leave_out(row: SweepRow, reason: str) -> None:
            left_out.append((row.path.name, reason))
            warnings.warn(f"left out: {row.path.name}: {reason}", LeftOutWarning, stacklevel=5)

        with ThreadPoolExecutor(max_workers=threads) as pool:
            results = pool.map(work, ordered) if threads > 1 else map(work, ordered)
            it = iter(results)
            for wl in wls:
                frames: list[_FrameResult] = []
                rows_kept: list[SweepRow] = []  # the rows of this wavelength the judge kept: as if the only ones
                for row in groups[wl]:
                    facts, res = next(it)
                    done += 1
                    if progress:
                        progress(done, total)
                    if judge is not None and judge.decide(row.path, facts) is not None:
                        continue
                    rows_kept.append(row)
                    if res.defect_saturated:
                        defect_saturated[wl] = max(defect_saturated.get(wl, 0), res.defect_saturated)
                    if res.saturated_fraction > max_saturated_fraction:
                        leave_out(res.row, f"saturated: {100 * res.saturated_fraction:.2g} % of the region of "
                                           f"interest outside known defects is at the white level at {wl:g} nm "
                                           "(shorten the exposure)")
                        continue
                    frames.append(res)
                if not rows_kept:
                    continue
                listed.add(wl)
                dark_frames = no_light(frames)
                for res, reason in dark_frames:
                    leave_out(res.row, reason)
                frames = [r for r in frames if all(r is not d for d, _ in dark_frames)]
                if len(frames) < max(1, min_frames):
                    dropped.append(f"{wl:g} nm ({len(frames)} of {len(rows_kept)} frames usable, "
                                   f"{max(1, min_frames)} needed)")
                    continue
                if len(frames) == 1:
                    single[wl] = (frames[0].row, frame_signal(frames[0])[0])
                v, u, ur = combine_wavelength(frames)
                bws = {r.bandwidth_nm for r in rows_kept if r.bandwidth_nm is not None}
                if len(bws) > 1:
                    raise CamcalError(f"rows at {wl:g} nm give different bandwidth_nm values {sorted(bws)}",
                                      csv_path)
                settings.append(SweepSetting(wl, np.asarray(v, np.float64), np.asarray(u, np.float64), float(ur),
                                             len(frames), bws.pop() if bws else None))
                del frames
        # a frame alone at its wavelength: no light when it records nothing while both neighbours are clearly lit
        by_wl = {st.wavelength_nm: st for st in settings}
        order = [st.wavelength_nm for st in settings]
        for k, wl in enumerate(order):
            if wl not in single or k == 0 or k == len(order) - 1:
                continue
            row, sig = single[wl]
            lit = all(float(np.max(by_wl[order[j]].value)) > NO_LIGHT_SIGMAS * float(
                by_wl[order[j]].noise_unc[int(np.argmax(by_wl[order[j]].value))]) for j in (k - 1, k + 1))
            neighbours = [float(np.max(by_wl[order[j]].value)) for j in (k - 1, k + 1)]
            here = float(np.max(by_wl[wl].value))
            if lit and here < NO_LIGHT_FRACTION * min(neighbours):
                leave_out(row, f"no light recorded (shutter closed or trigger missed): {sig:.3g} DN above dark at "
                               f"{wl:g} nm, where the reference detector read {row.radiance_w_m2_sr:.3g} "
                               f"{IN_BAND_RADIANCE} and the neighbouring wavelengths recorded light")
                dropped.append(f"{wl:g} nm (its only frame recorded no light)")
                del by_wl[wl]
        settings = [by_wl[w] for w in order if w in by_wl]
        out_notes = list(notes)
        if defect_saturated:
            ws = sorted(defect_saturated)
            out_notes.append(f"hot pixels saturate: up to {max(defect_saturated.values())} known defects of the ROI "
                             f"reach the white level at {ws[0]:g}-{ws[-1]:g} nm; they are masked (frames kept)")
        if dropped:
            out_notes.append(f"{len(dropped)} wavelength(s) without a usable frame dropped from c(λ): "
                             f"{', '.join(dropped)}")
        if not settings:
            raise TooFewFrames("sweep", "wavelengths", 1, 0, f"{len(listed)} in sweep.csv; dropped: "
                               f"{', '.join(dropped)}", csv_path)
        return SweepMeasurement(tuple(settings), tuple(names), tuple(out_notes), csv_path, tuple(left_out),
                                len(listed))

    if judge is None:
        return measure()
    while True:
        superseded = len(judge.superseded)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            measured = measure()
        if len(judge.superseded) == superseded:
            for w in caught:  # the warnings of the measurement that is kept
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            return measured
        # a copy first in file order was read after its copy had been used at another wavelength: measured
        # again, the verdicts now fixed (rare: a copy named before its original but listed at a later wavelength)


def require_wavelengths(measured: SweepMeasurement, needed: int = MIN_WAVELENGTHS, listed: int | None = None) -> None:
    """Raise :class:`TooFewFrames` when fewer than ``needed`` wavelengths of the sweep have a usable frame.

    ``listed``: wavelengths in ``sweep.csv`` (default: those of the rows measured)."""
    have = len(measured.settings)
    listed = measured.n_listed if listed is None else listed
    if have < needed:
        raise TooFewFrames("sweep", "wavelengths", needed, have,
                           f"{listed} in sweep.csv, {listed - have} without a usable frame; c(λ) is read with a "
                           "not-a-knot cubic spline, which "
                           f"needs {needed}" + "".join(f"; {n}" for n in measured.notes if "dropped" in n),
                           measured.csv_path)


def frame_signal(res: _FrameResult) -> tuple[float, float]:
    """A sweep frame's signal in its brightest plane: the ROI mean above dark (DN, valid pixels) and its standard
    error (DN, from the spatial spread, so PRNU makes it conservative)."""
    best, best_sem = -np.inf, 0.0
    for p in range(res.planes.shape[0]):
        ok = ~res.invalid[p]
        n = int(ok.sum())
        if n < 2:
            continue
        m = float(np.mean(res.planes[p], where=ok, dtype=np.float64))
        if m > best:
            best, best_sem = m, float(np.std(res.planes[p], where=ok, dtype=np.float64, ddof=1)) / math.sqrt(n)
    return (0.0, 0.0) if not np.isfinite(best) else (best, best_sem)


def no_light(frames: Sequence[_FrameResult]) -> list[tuple[_FrameResult, str]]:
    """The frames of one wavelength that recorded no light while their repeats did (:data:`NO_LIGHT_FRACTION`).

    Each frame's signal per unit exposure and reference radiance, s_k / (x_k L_k), is compared with the median of
    the other frames at the wavelength; a frame is left out when its own is below :data:`NO_LIGHT_FRACTION` of
    that median. Frames alone at their wavelength are judged against the neighbouring wavelengths by
    :func:`measure_sweep`.
    """
    if len(frames) < 2:
        return []
    sig = [frame_signal(r) for r in frames]
    norm = np.array([s / (r.relative_exposure_s * r.row.radiance_w_m2_sr) for (s, _), r in zip(sig, frames,
                                                                                              strict=True)])
    out = []
    for k, r in enumerate(frames):
        others = np.delete(norm, k)
        ref = float(np.median(others))
        s, _sem = sig[k]
        if ref > 0 and norm[k] < NO_LIGHT_FRACTION * ref:
            expected = ref * r.relative_exposure_s * r.row.radiance_w_m2_sr
            out.append((r, f"no light recorded (shutter closed or trigger missed): {s:.3g} DN above dark at "
                           f"{r.row.wavelength_nm:g} nm, where its repeats recorded {expected:.3g} DN for the same "
                           f"exposure and the reference detector read {r.row.radiance_w_m2_sr:.3g} {IN_BAND_RADIANCE}"))
    return out


def fit_sweep(measured: SweepMeasurement, options: SweepOptions = SweepOptions()  # noqa: B008
                              ) -> SpectralSensitivity:
    """c(λ) per plane from the per-wavelength measurements (seed §3.1); pure.

    The total uncertainty combines the frames' noise and the reference radiance's relative uncertainty;
    with ``options.deconvolve`` the slit function is removed (:func:`deconvolve_slit`, ``bandwidth_nm`` needed
    at every wavelength); ``mode="relative"`` divides by the largest value (:func:`to_relative`).
    """
    options.check()
    names = measured.channels
    st = measured.settings
    wl_arr = np.asarray([x.wavelength_nm for x in st], float)
    value = np.stack([x.value for x in st], axis=1) if st else np.empty((len(names), 0))
    u_noise = np.stack([x.noise_unc for x in st], axis=1) if st else np.empty((len(names), 0))
    u_ref = np.asarray([x.reference_unc_rel for x in st], float)
    bw = [x.bandwidth_nm for x in st if x.bandwidth_nm is not None]
    n_used = {f"{x.wavelength_nm:g}": x.n_frames for x in st}
    u_tot = np.hypot(u_noise, value * u_ref[None, :])
    bandwidth = float(np.median(bw)) if bw else None
    out_vals, out_unc = value, u_tot
    if options.deconvolve:
        if len(bw) != len(st):
            raise CamcalError("deconvolution needs a bandwidth_nm value on every sweep.csv row", measured.csv_path)
        out_vals = np.empty_like(value)
        out_unc = np.empty_like(value)
        for p in range(len(names)):
            out_vals[p], out_unc[p] = deconvolve_slit(wl_arr, value[p], u_tot[p], np.asarray(bw), slit=options.slit,
                                                      regularisation=options.regularisation)
    sens = SpectralSensitivity(
        wavelength_nm=wl_arr,
        values={p: out_vals[k] for k, p in enumerate(names)},
        uncertainty={p: out_unc[k] for k, p in enumerate(names)},
        units=ABSOLUTE_UNITS,
        mode="absolute",
        reference_iso=float(options.reference_iso),
        reference_f_number=float(options.reference_f_number),
        bandwidth_nm=bandwidth,
        deconvolved=bool(options.deconvolve),
        n_frames=n_used,
        notes=measured.notes,
    )
    return to_relative(sens) if options.mode == "relative" else sens


# ---- finite bandwidth ----------------------------------------------------------------------
def _gaussian_slits(grid_nm: np.ndarray, centre_nm: np.ndarray, fwhm_nm: np.ndarray) -> np.ndarray:
    """``colour.sd_gaussian(centre, fwhm, method="FWHM")`` on the grid, one row per setting."""
    import colour  # loads matplotlib: kept off paths that do not plot

    grid = colour.SpectralShape(float(grid_nm[0]), float(grid_nm[-1]), float(grid_nm[1] - grid_nm[0]))
    return np.stack([np.asarray(colour.sd_gaussian(float(c), float(f), shape=grid, method="FWHM").values)
                     for c, f in zip(centre_nm, fwhm_nm, strict=True)])


def _triangular_slits(grid_nm: np.ndarray, centre_nm: np.ndarray, fwhm_nm: np.ndarray) -> np.ndarray:
    """1 − |offset|/FWHM, clipped at 0, one row per setting."""
    return np.clip(1.0 - np.abs(grid_nm[None, :] - centre_nm[:, None]) / fwhm_nm[:, None], 0.0, None)


SLIT_SHAPES = {"gaussian": _gaussian_slits, "triangular": _triangular_slits}
"""A monochromator's slit function by name: (grid, centres, FWHMs in nm) → unit-peak rows."""


def slit_functions(grid_nm: np.ndarray, centre_nm: np.ndarray, fwhm_nm: np.ndarray,
                   shape: str = "gaussian") -> np.ndarray:
    """Unit-peak slit functions (n, len(grid)) of the settings ``centre_nm`` on a regular ``grid_nm``, of
    ``shape`` (:data:`SLIT_SHAPES`)."""
    if shape not in SLIT_SHAPES:
        raise CamcalError(f"unknown slit shape {shape!r}; use {' or '.join(SLIT_SHAPES)}")
    return SLIT_SHAPES[shape](np.asarray(grid_nm, float), np.asarray(centre_nm, float), np.asarray(fwhm_nm, float))


def slit_matrix(wavelength_nm: np.ndarray, fwhm_nm: np.ndarray | float, shape: str = "gaussian",
                step_nm: float = 0.1) -> np.ndarray:
    """Forward operator A (n, n): measured (c ⊛ φ_j)(λ_j) = Σ_k A_jk c(λ_k).

    c between the nodes is the natural cubic spline through the node values
    (fourth-order accurate, so the representation error stays well below the
    slit bias being removed); outside the sampled range it is held at the end
    values.
    """
    wl = np.asarray(wavelength_nm, float)
    fwhm = np.broadcast_to(np.asarray(fwhm_nm, float), wl.shape)
    reach = 3.0 * float(fwhm.max())
    fine = np.arange(wl[0] - reach, wl[-1] + reach + step_nm / 2, step_nm)
    basis = CubicSpline(wl, np.eye(wl.size), bc_type="natural")(np.clip(fine, wl[0], wl[-1]))  # (nf, n)
    phi = slit_functions(fine, wl, fwhm, shape)  # (n, nf)
    phi /= np.trapezoid(phi, fine, axis=1)[:, None]
    weights = np.full(fine.size, step_nm)
    weights[[0, -1]] *= 0.5
    return (phi * weights[None, :]) @ basis


def deconvolve_slit(
    wavelength_nm: np.ndarray,
    measured: np.ndarray,
    uncertainty: np.ndarray,
    fwhm_nm: np.ndarray | float,
    *,
    slit: str = "gaussian",
    regularisation: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Tikhonov-regularised removal of the monochromator slit function.

    Solves min_c ||W^½ (A c − m)||² + α ||D₂ c||² with A = :func:`slit_matrix`,
    W = diag(1/u²) and D₂ the second difference per nm² (a smoothness prior);
    α = ``regularisation`` · tr(AᵀWA)/tr(D₂ᵀD₂) (dimensionless ``regularisation``), chosen by
    generalised cross-validation (Hansen 2010, §5.4) over 1e-10..1e2 unless given.
    The uncertainty is propagated through the linear estimator
    R = (AᵀWA + αD₂ᵀD₂)⁻¹AᵀW as sqrt(diag(R diag(u²) Rᵀ)); the regularisation
    bias is not included.

    Returns
    -------
    c (n,), u_c (n,) at ``wavelength_nm``.
    """
    wl = np.asarray(wavelength_nm, float)
    m = np.asarray(measured, float)
    u = np.asarray(uncertainty, float)
    n = wl.size
    if n < 4:
        raise CamcalError("deconvolution needs at least 4 wavelengths")
    scale = max(float(np.max(np.abs(m))), 1e-300)
    u_floor = np.maximum(u, 1e-6 * scale)
    a = slit_matrix(wl, fwhm_nm, slit)
    h = np.diff(wl)
    d2 = np.zeros((n - 2, n))
    for i in range(n - 2):
        h0, h1 = h[i], h[i + 1]
        d2[i, i: i + 3] = 2.0 / (h0 + h1) * np.array([1 / h0, -(1 / h0 + 1 / h1), 1 / h1])
    w = 1.0 / u_floor**2
    ata = a.T @ (w[:, None] * a)
    dtd = d2.T @ d2
    # scale alpha to the problem: trace ratio makes the grid dimensionless
    base = np.trace(ata) / max(np.trace(dtd), 1e-300)

    def solve(alpha: float) -> tuple[np.ndarray, np.ndarray]:
        mat = ata + alpha * dtd
        r = np.linalg.solve(mat, a.T * w[None, :])  # (n, n) estimator
        return r @ m, r

    if regularisation is None:
        best = None
        for lg in np.linspace(-10, 2, 49):
            alpha = base * 10.0**lg
            c, r = solve(alpha)
            resid = np.sqrt(w) * (a @ c - m)
            dof = n - np.trace(a @ r)
            gcv = n * float(resid @ resid) / max(dof, 1e-9) ** 2
            if best is None or gcv < best[0]:
                best = (gcv, c, r)
        _, c, r = best  # type: ignore[misc]
    else:
        c, r = solve(base * float(regularisation))
    cov = (r * u**2) @ r.T
    return c, np.sqrt(np.clip(np.diag(cov), 0.0, None))


# ---- merging ------------------------------------------------------------------------------


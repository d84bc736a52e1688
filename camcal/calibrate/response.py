"""Linearity and response: gain α, gamma γ and offset β per channel (seed eq. 12), RAW and JPEG.

Seed eq. 12 models the value of channel i as

    g_i = α_i · x^γ_i + β_i

with x the exposure ISO·t/N² relative to a reference setting, i.e. the
exposure time in seconds *at the reference ISO and f-number*
(:func:`camcal.models.exposure.relative_exposure`, seed §2.1). RAW data give γ ≈ 1
and β = black level + dark signal; a JPEG encoded for a 2.2 display gives
γ ≈ 1/2.2. The seed's integral of radiance × sensitivity is constant for a
constant source, so an exposure series of one source measures the response
curve g(x).

What this module does, per kind of file present in a folder (``raw`` planes
R, G1, G2, B; ``processed`` channels R, G, B):

1. the mean and its standard error in a central region of interest (ROI) of
   every frame and channel (:func:`measure_response`); optional dark-frame
   subtraction from a dark model (RAW only);
2. saturation: a frame is saturated in a channel when more than 0.1 % of its
   ROI pixels sit at the white level; the top points are also trimmed while
   they fall below the fit by more than 1 % (full-well compression);
3. a weighted least-squares fit of eq. 12 (:func:`scipy.optimize.curve_fit`, bounded
   Trust Region Reflective; weights from the ROI
   standard error, uncertainties scaled by the reduced χ² when it exceeds 1);
4. the EMVA 1288 linearity error (release 3.1 / 4.0, §6.x "Linearity"):
   a straight line μ = a·x + b fitted minimising the *relative* deviations over
   the points between 5 % and 95 % of the saturation signal,
   δ_i = 100 (μ_i − (a x_i + b)) / (a x_i + b) %, and LE = (max δ − min δ)/2;
   and the Pearson correlation r of g with x (SPECTACLE, Burggraaff et al. 2019,
   counts r ≥ 0.98 as linear);
5. JPEG: the sRGB transfer-function form with a free exponent p
   (IEC 61966-2-1 with 1/2.4 replaced by p; offset a = 0.055; linear toe
   tangent from the origin), V = (1 + a)(x/x_w)^p − a, V = g/W; the better of
   the two forms (eq. 12 or sRGB) is inverted by :meth:`ResponseModel.linearise`.

Note: above the toe the sRGB form *is* eq. 12 with β = −a·W, so for an sRGB
JPEG eq. 12's γ is the sRGB exponent 1/2.4 (not 1/2.2, which is only the
"effective" gamma of the whole curve).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import OptimizeWarning, curve_fit, least_squares

from camcal.calibrate.emva import linearity_error, pair_statistics
from camcal.calibrate.screen import StageJudge
from camcal.calibrate.session import StageFrames, folder_of, stage_files
from camcal.errors import CamcalError, TooFewFrames
from camcal.io.folders import load_folder_frame, read_ahead
from camcal.models.correct import Calibration, DarkFrameModel, correct_planes
from camcal.models.exposure import relative_exposure
from camcal.models.response import (
    SRGB_OFFSET_A,
    ChannelResponse,
    ResponseModel,
    _detone,
    srgb_form_encode,
    srgb_form_toe,
)
from camcal.region import Region
from camcal.threads import thread_count

SERIES_ROI_FRACTION = math.sqrt(0.10)
"""Default central fraction of the exposure series, of each side (camcal.region's convention): √0.10 ≈ 0.316,
a window holding 10 % of each plane's area."""

SATURATED_PIXEL_FRACTION = 1e-3
"""A frame is saturated in a channel when more than this fraction of ROI pixels is clipped."""

COMPRESSION_TOLERANCE = 0.01
"""Top points falling below the fit by more than this relative amount (and 5 σ) are excluded."""


MIN_EXPOSURES = 3


# ---------------------------------------------------------------------------------------------------------------
# data classes
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ExposureSeries:
    """ROI statistics of one kind of frame across an exposure series.

    Arrays have shape (n,) per frame or (n, C) per frame and channel, frames
    sorted by relative exposure.

    Attributes
    ----------
    kind : "raw" or "processed"
    channels : channel names (R, G1, G2, B or R, G, B)
    files : file names
    x_s : relative exposure, s at the reference setting
    exposure_s, iso, f_number : the frames' settings
    mean_dn, sem_dn : ROI mean and its standard error, DN (after dark subtraction when a dark model was given)
    clipped_fraction : fraction of ROI pixels at or above the white level
    max_dn : largest ROI value, DN (before dark subtraction)
    white_level_dn : the file's white level, DN
    black_level_dn : black level per channel from the file's metadata, DN
    dark_subtracted : whether a dark model was subtracted
    roi : (y0, y1, x0, x1) fractions of the plane
    pairs : RAW only: the frame pairs of the photon-transfer method (:class:`PairStatistics`), or None
    """

    kind: str
    channels: tuple[str, ...]
    files: tuple[str, ...]
    x_s: np.ndarray
    exposure_s: np.ndarray
    iso: np.ndarray
    f_number: np.ndarray
    mean_dn: np.ndarray
    sem_dn: np.ndarray
    clipped_fraction: np.ndarray
    max_dn: np.ndarray
    white_level_dn: float
    black_level_dn: np.ndarray
    reference_iso: float
    reference_f_number: float
    dark_subtracted: bool = False
    roi: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 1.0)
    folder: str | None = None
    pairs: PairStatistics | None = None


@dataclass(frozen=True)
class PairStatistics:
    """Whole-plane statistics of consecutive RAW frame pairs at one setting (EMVA 1288 photon transfer).

    Arrays are (m,) per pair or (m, C) per pair and channel, in the order the pairs were read.

    Attributes
    ----------
    exposure_s, iso, f_number : the setting of each pair.
    mean_dn : mean of both frames above the zero-exposure dark level (the dark model's bias map, else the
        file's black level), DN; the dark signal β·t is *included* (its electrons are Poisson too).
    variance_dn2 : temporal variance ½·var(y_A − y_B), DN² (:func:`camcal.calibrate.emva.pair_statistics`).
    files : the two file names of each pair.
    bias_source : ``"dark model"`` or ``"black level"``.
    """

    exposure_s: np.ndarray
    iso: np.ndarray
    f_number: np.ndarray
    mean_dn: np.ndarray
    variance_dn2: np.ndarray
    files: tuple[tuple[str, str], ...]
    bias_source: str


def _pair_planes(planes: np.ndarray, bias: np.ndarray | None, black: np.ndarray) -> np.ndarray:
    """Full planes above the zero-exposure dark level, float32."""
    out = np.asarray(planes, np.float32).copy()
    out -= bias if bias is not None else black.astype(np.float32)
    return out


@dataclass(frozen=True)
class Saturation:
    """Where one channel of an exposure series saturates, as EMVA 1288 reports the saturation point.

    Frames at or past saturation are data: they mark the end of the linear range and are not fitted.

    Attributes
    ----------
    level_dn : float
        Saturation level, DN as recorded: the largest ROI value of the saturated frames, else the white level.
    exposure_s : float
        Relative exposure (s at the reference setting) of the first saturated frame; NaN when none saturated.
        The last fitted exposure (``fitted_exposure_s[1]``) and this one bracket the saturation exposure.
    reached : bool
        Whether any frame of the series saturated in this channel.
    n_saturated : int
        Frames at or past saturation (more than :data:`SATURATED_PIXEL_FRACTION` of the ROI clipped).
    fitted_range_dn, fitted_exposure_s : (float, float)
        Lowest and highest ROI mean (DN) and relative exposure (s) of the points the fit used.
    """

    level_dn: float
    exposure_s: float
    reached: bool
    n_saturated: int
    fitted_range_dn: tuple[float, float]
    fitted_exposure_s: tuple[float, float]


def saturation_point(x_s: np.ndarray, mean_dn: np.ndarray, max_dn: np.ndarray, saturated: np.ndarray,
                     used: np.ndarray, white_level_dn: float) -> Saturation:
    """The :class:`Saturation` of one channel of a series (arrays of shape (n,), frames sorted by exposure).

    ``x_s``: relative exposure, s; ``mean_dn``: ROI means as fitted; ``max_dn``: largest ROI value as recorded;
    ``saturated``: frames at or past saturation; ``used``: frames the fit used (unsaturated, uncompressed).
    """
    x_s, mean_dn, max_dn = (np.asarray(a, float) for a in (x_s, mean_dn, max_dn))
    saturated, used = np.asarray(saturated, bool), np.asarray(used, bool)
    reached = bool(saturated.any())
    level = float(np.max(max_dn[saturated])) if reached else float(white_level_dn)
    x_sat = float(np.min(x_s[saturated])) if reached else float("nan")
    g, x = mean_dn[used], x_s[used]
    return Saturation(level, x_sat, reached, int(saturated.sum()),
                      (float(g.min()), float(g.max())) if g.size else (float("nan"),) * 2,  # type: ignore[arg-type]
                      (float(x.min()), float(x.max())) if x.size else (float("nan"),) * 2)  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------------------------
# measuring the series
# ---------------------------------------------------------------------------------------------------------------


def roi_window(roi: float | tuple[float, float, float, float] | None) -> tuple[float, float, float, float]:
    """ROI as fractions (y0, y1, x0, x1) of a plane.

    ``None`` -> the central window of :data:`SERIES_ROI_FRACTION` of each side;
    a float f in (0, 1] -> the central window of f of each side (a central fraction, as in camcal.region);
    a 4-tuple -> taken as (y0, y1, x0, x1) fractions.
    """
    if roi is None:
        roi = SERIES_ROI_FRACTION
    if isinstance(roi, int | float):
        s = float(roi)
        if not 0.0 < s <= 1.0:
            raise CamcalError(f"ROI fraction (a central fraction of each side) must be in (0, 1], got {s}")
        return (0.5 - s / 2, 0.5 + s / 2, 0.5 - s / 2, 0.5 + s / 2)
    try:
        y0, y1, x0, x1 = (float(v) for v in roi)
    except (TypeError, ValueError):
        raise CamcalError(f"ROI must be a fraction or (y0, y1, x0, x1) fractions, got {roi!r}") from None
    if not (0.0 <= y0 < y1 <= 1.0 and 0.0 <= x0 < x1 <= 1.0):
        raise CamcalError(f"ROI (y0, y1, x0, x1) = {roi!r} must satisfy 0 <= y0 < y1 <= 1 and 0 <= x0 < x1 <= 1")
    return (y0, y1, x0, x1)


def roi_slices(shape: tuple[int, int], roi: tuple[float, float, float, float]) -> tuple[slice, slice]:
    h, w = shape
    y0, y1 = int(round(roi[0] * h)), int(round(roi[1] * h))
    x0, x1 = int(round(roi[2] * w)), int(round(roi[3] * w))
    y1, x1 = max(y1, y0 + 1), max(x1, x0 + 1)
    return slice(y0, min(y1, h)), slice(x0, min(x1, w))


@dataclass(frozen=True)
class ResponseOptions:
    """Options of the linearity stage.

    Attributes
    ----------
    roi : a :class:`camcal.region.Region` (photo pixels) or a central fraction of each side (see
        :func:`roi_window`); default :data:`SERIES_ROI_FRACTION` (10 % of each plane's area).
    reference_iso, reference_f_number : the setting x refers to; default the series' most common (ties: the
        smaller value).
    """

    roi: Region | float | tuple[float, float, float, float] | None = None
    reference_iso: float | None = None
    reference_f_number: float | None = None


def measure_response(
    folder: str | Path | StageFrames,
    options: ResponseOptions = ResponseOptions(),  # noqa: B008
    *,
    dark: DarkFrameModel | None = None,
    progress: Callable[[int, int], None] | None = None,
    jobs: int | None = None,
    judge: StageJudge | None = None,
) -> dict[str, ExposureSeries]:
    """The file step of the linearity stage: ROI statistics of every frame of an exposure-series folder (a
    constant source, ``SESSION/linearity``, with an optional frames.csv giving ``exposure_s, iso, f_number``),
    grouped by kind; :func:`fit_response` fits them.

    ``dark``: an optional dark model (``dark_frame_dn(exposure_s, iso)``) subtracted from RAW frames.
    ``progress(done, total)`` after each frame.

    ``judge``: the stage's :class:`camcal.calibrate.screen.StageJudge`: each frame is judged as it is decoded
    (unreadable, a copy, another camera...) and a frame left out is skipped, as if it were not in the folder; without a
    judge, an unreadable frame is an error.

    Frames are read in file order, the next ones decoding in threads while one is measured (``jobs``:
    :func:`camcal.threads.thread_count`); at most one frame per thread plus the one measured are in memory,
    so memory does not grow with their number.
    Without an explicit reference, the most common ISO and f-number of the
    series are used (ties: the smaller value).

    Raises
    ------
    CamcalError
        Folder without images, unreadable files, missing exposure metadata, bad ROI.
    """
    roi, reference_iso, reference_f_number = options.roi, options.reference_iso, options.reference_f_number
    files, manifest = stage_files(folder)
    folder = folder_of(folder)
    region = roi if isinstance(roi, Region) else None
    window = roi_window(None if region is not None else roi)
    cal = Calibration.of(dark) if dark is not None else Calibration()
    rows: dict[str, list[dict]] = {}
    bias = None if dark is None or getattr(dark, "bias_dn", None) is None else np.asarray(dark.bias_dn, np.float32)
    defects = cal.defects
    pairs: list[dict] = []
    previous: tuple | None = None  # (setting, planes above dark, file name) of an unpaired RAW frame
    # the thread rule looks at the frame size: a RAW file's bytes are about two per pixel (no header read)
    threads = thread_count(jobs, len(files), max(files[0].stat().st_size // 2, 1) if files else None)
    if judge is None:
        frames = read_ahead(files, lambda p: load_folder_frame(p, manifest), threads if threads > 1 else 0)
    else:
        frames = read_ahead(files, lambda p: judge.load(p, lambda q: load_folder_frame(q, manifest)),
                            threads if threads > 1 else 0)
    for i, (path, frame) in enumerate(zip(files, frames, strict=True)):
        if judge is not None:
            frame, facts = frame
            if judge.decide(path, facts) is not None:  # left out: as if it were not in the folder
                if progress:
                    progress(i + 1, len(files))
                continue
        e = frame.exposure
        t, iso, n = e.require("exposure_s", path), e.require("iso", path), e.require("f_number", path)
        planes = frame.planes(np.float32)
        if frame.kind == "raw":
            # photon transfer: consecutive frames at one setting form a pair (one frame held at a time)
            b = bias if bias is not None and bias.shape == planes.shape else None
            above = _pair_planes(planes, b, frame.black_vector())
            setting = (float(t), float(iso), float(n), above.shape)
            if previous is not None and previous[0] == setting:
                valid = None if defects is None or defects.shape != above.shape else ~defects
                stats_ = [pair_statistics(previous[1][k], above[k], None if valid is None else valid[k])
                          for k in range(above.shape[0])]
                pairs.append({"t": t, "iso": iso, "n": n, "mean": [m for m, _ in stats_],
                              "var": [v for _, v in stats_], "files": (previous[2], path.name),
                              "bias": "dark model" if b is not None else "black level"})
                previous = None
            else:
                previous = (setting, above, path.name)
            del above
        if region is not None:  # photo pixels -> this frame's planes (half resolution for a Bayer mosaic)
            ys, xs = region.window(planes.shape[1:], 2 if frame.layout == "bayer" else 1, path)
            ph, pw = planes.shape[1:]
            window = (ys.start / ph, ys.stop / ph, xs.start / pw, xs.stop / pw)
        else:
            ys, xs = roi_slices(planes.shape[1:], window)
        raw = frame.kind == "raw"
        roi_planes = np.ascontiguousarray(planes[:, ys, xs])
        nc = roi_planes.shape[0]
        mx = roi_planes.reshape(nc, -1).max(axis=1).astype(np.float64)
        # RAW with a dark model: the signal above dark; otherwise the values as recorded (eq. 12's β holds
        # the black level); known defects and clipped pixels masked (camcal.models.correct)
        corr = correct_planes(roi_planes, cal if raw else Calibration(), exposure_s=t, iso=iso,
                              white_level_dn=float(frame.white_level_dn), black_level_dn=np.zeros(nc),
                              full_shape=planes.shape, window=(ys, xs), channels=frame.channel_names,
                              cfa_pattern=frame.cfa_pattern, path=path, inplace=True)
        del planes
        white = float(frame.white_level_dn)
        clipped = corr.saturated_fraction()
        cut = corr.signal_dn.reshape(nc, -1)
        valid = ~corr.invalid.reshape(nc, -1)
        npx = np.maximum(valid.sum(axis=1), 1)
        mean = np.array([np.mean(cut[k], where=valid[k], dtype=np.float64) if valid[k].any() else np.nan
                         for k in range(nc)])
        std = np.array([np.std(cut[k], where=valid[k], dtype=np.float64, ddof=1) if valid[k].sum() > 1 else 0.0
                        for k in range(nc)])
        # a channel without a valid pixel (all clipped) keeps the plain mean: its clipped fraction excludes it
        mean = np.where(np.isfinite(mean), mean, cut.mean(axis=1))
        sem = std / np.sqrt(npx)
        # 8-bit or integer quantisation: never let a point claim less than a uniform-quantisation error
        sem = np.sqrt(sem**2 + 1.0 / 12.0 / npx)
        rows.setdefault(frame.kind, []).append({
            "file": path.name, "t": t, "iso": iso, "n": n, "mean": mean, "sem": sem, "clipped": clipped, "max": mx,
            "white": white, "black": frame.black_vector()[:, 0, 0], "channels": frame.channel_names,
        })
        if progress:
            progress(i + 1, len(files))
    out = {}
    for kind, rs in rows.items():
        out[kind] = _series_from_rows(kind, rs, window, dark is not None and kind == "raw", folder,
                                      reference_iso, reference_f_number)
    if pairs and "raw" in out:
        out["raw"] = replace(out["raw"], pairs=PairStatistics(
            exposure_s=np.array([p["t"] for p in pairs], float), iso=np.array([p["iso"] for p in pairs], float),
            f_number=np.array([p["n"] for p in pairs], float), mean_dn=np.array([p["mean"] for p in pairs], float),
            variance_dn2=np.array([p["var"] for p in pairs], float), files=tuple(p["files"] for p in pairs),
            bias_source=pairs[0]["bias"]))
    return out


def _mode(values: list[float]) -> float:
    vals, counts = np.unique(np.asarray(values, float), return_counts=True)
    return float(vals[np.argmax(counts)])  # np.unique sorts: ties resolve to the smaller value


def _series_from_rows(kind, rs, window, dark_subtracted, folder, reference_iso, reference_f_number) -> ExposureSeries:
    ref_iso = float(reference_iso) if reference_iso is not None else _mode([r["iso"] for r in rs])
    ref_n = float(reference_f_number) if reference_f_number is not None else _mode([r["n"] for r in rs])
    if ref_iso <= 0 or ref_n <= 0:
        raise CamcalError(f"reference ISO and f-number must be positive, got {ref_iso}, {ref_n}")
    x = np.array([relative_exposure(r["t"], r["iso"], r["n"], ref_iso, ref_n) for r in rs])
    order = np.argsort(x, kind="stable")
    rs = [rs[i] for i in order]
    whites = {r["white"] for r in rs}
    if len(whites) > 1:
        raise CamcalError(f"{kind} frames have different white levels {sorted(whites)}; fit them separately", folder)
    return ExposureSeries(
        kind=kind,
        channels=tuple(rs[0]["channels"]),
        files=tuple(r["file"] for r in rs),
        x_s=x[order],
        exposure_s=np.array([r["t"] for r in rs]),
        iso=np.array([r["iso"] for r in rs]),
        f_number=np.array([r["n"] for r in rs]),
        mean_dn=np.array([r["mean"] for r in rs]),
        sem_dn=np.array([r["sem"] for r in rs]),
        clipped_fraction=np.array([r["clipped"] for r in rs]),
        max_dn=np.array([r["max"] for r in rs]),
        white_level_dn=float(rs[0]["white"]),
        black_level_dn=np.array(rs[0]["black"], float),
        reference_iso=ref_iso,
        reference_f_number=ref_n,
        dark_subtracted=dark_subtracted,
        roi=window,
        folder=str(folder),
    )


# ---------------------------------------------------------------------------------------------------------------
# fitting
# ---------------------------------------------------------------------------------------------------------------


def _eq12(x, a, g, b):
    return a * np.power(x, g) + b


def fit_eq12(x_s: np.ndarray, g_dn: np.ndarray, sigma_dn: np.ndarray, *, gamma0: float = 1.0) -> dict:
    """Weighted least-squares fit of seed eq. 12, g = α x^γ + β, to one channel.

    x is scaled by its geometric mean x0 during the fit (g = A (x/x0)^γ + β,
    α = A x0^-γ) to decorrelate the parameters; the covariance is propagated to α.
    Uncertainties are the covariance with the weights taken as absolute, scaled
    by the reduced χ² when that exceeds 1 (the ROI standard error does not see
    every systematic effect). With exactly three points they are NaN.

    Returns
    -------
    dict with alpha, gamma, beta, their ``_unc``, ``chi2_red``, ``rms_dn``.
    """
    x = np.asarray(x_s, float)
    g = np.asarray(g_dn, float)
    s = np.maximum(np.asarray(sigma_dn, float), 1e-9 * max(1.0, float(np.max(np.abs(g)))))
    x0 = float(np.exp(np.mean(np.log(x))))
    u = x / x0
    # starting point: β from a straight line through the lowest two points extrapolated to x = 0 (γ = 1 case)
    # or 0 for a compressive curve; γ from a log-log slope of g − β
    if gamma0 >= 0.9:
        slope = (g[1] - g[0]) / (x[1] - x[0]) if x[1] > x[0] else (g[-1] - g[0]) / max(x[-1] - x[0], 1e-30)
        b0 = float(g[0] - slope * x[0])
    else:
        b0 = 0.0
    b0 = min(b0, float(g.min()) - 1e-3 * max(1.0, float(np.ptp(g))))
    pos = g - b0
    gam0 = float(np.polyfit(np.log(u), np.log(pos), 1)[0]) if np.all(pos > 0) else gamma0
    gam0 = float(np.clip(gam0, 0.1, 3.0))
    a0 = float(np.exp(np.mean(np.log(pos)) - gam0 * np.mean(np.log(u)))) if np.all(pos > 0) else float(np.ptp(g))
    lo = [0.0, 0.02, -np.inf]
    hi = [np.inf, 10.0, np.inf]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        warnings.simplefilter("ignore", OptimizeWarning)  # a covariance that cannot be estimated is inf
        try:
            popt, pcov = curve_fit(_eq12, u, g, [max(a0, 1e-12), gam0, b0], sigma=s, absolute_sigma=True,
                                   bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=20000)
        except (RuntimeError, ValueError) as exc:
            raise CamcalError(f"the fit of eq. 12 did not converge ({exc})") from None
    a, gam, b = (float(v) for v in popt)
    resid = g - _eq12(u, a, gam, b)
    dof = len(x) - 3
    chi2_red = float(np.sum((resid / s) ** 2) / dof) if dof > 0 else float("nan")
    if dof > 0 and np.all(np.isfinite(pcov)):
        cov = pcov * max(1.0, chi2_red)
        alpha = a * x0 ** (-gam)
        jac = np.array([x0 ** (-gam), -alpha * math.log(x0), 0.0])
        alpha_unc = float(math.sqrt(max(jac @ cov @ jac, 0.0)))
        gamma_unc = float(math.sqrt(max(cov[1, 1], 0.0)))
        beta_unc = float(math.sqrt(max(cov[2, 2], 0.0)))
    else:
        alpha = a * x0 ** (-gam)
        alpha_unc = gamma_unc = beta_unc = float("nan")
    return {"alpha": float(alpha), "alpha_unc": alpha_unc, "gamma": gam, "gamma_unc": gamma_unc, "beta": b,
            "beta_unc": beta_unc, "chi2_red": chi2_red, "rms_dn": float(np.sqrt(np.mean(resid**2)))}


def fit_line(x_s: np.ndarray, g_dn: np.ndarray, sigma_dn: np.ndarray) -> dict:
    """Weighted straight line g = rate·x + offset (eq. 12 with γ = 1); uncertainties scaled by √χ²_red ≥ 1."""
    x, g = np.asarray(x_s, float), np.asarray(g_dn, float)
    w = 1.0 / np.maximum(np.asarray(sigma_dn, float), 1e-9)
    design = np.stack([x, np.ones_like(x)], axis=1) * w[:, None]
    coef, *_ = np.linalg.lstsq(design, g * w, rcond=None)
    dof = len(x) - 2
    resid = (g - design[:, 0] / w * coef[0] - coef[1]) * w
    chi2_red = float(np.sum(resid**2) / dof) if dof > 0 else float("nan")
    try:
        cov = np.linalg.inv(design.T @ design) * (max(1.0, chi2_red) if dof > 0 else float("nan"))
    except np.linalg.LinAlgError:
        cov = np.full((2, 2), float("nan"))
    return {"rate": float(coef[0]), "offset": float(coef[1]), "rate_unc": float(np.sqrt(abs(cov[0, 0]))),
            "offset_unc": float(np.sqrt(abs(cov[1, 1]))), "chi2_red": chi2_red}


def emva_linearity_error(x_s: np.ndarray, signal_dn: np.ndarray, saturation_signal_dn: float) -> float:
    """EMVA 1288 linearity error LE, percent (:func:`camcal.calibrate.emva.linearity_error`): a line fitted minimising
    the relative deviations between 5 % and 95 % of ``saturation_signal_dn``, LE = (max δ − min δ) / 2."""
    return linearity_error(x_s, signal_dn, saturation_signal_dn).error_pct


def _pearson(x: np.ndarray, y: np.ndarray) -> float:
    if len(x) < 2 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return float("nan")
    return float(np.corrcoef(x, y)[0, 1])


# ---- sRGB form with a free exponent -------------------------------------------------------------------------


def fit_srgb_form(x_s: np.ndarray, g_dn: np.ndarray, sigma_dn: np.ndarray, white_dn: float, p0: float,
                  x_white0: float) -> dict:
    """Fit g/W = V((x/x_w), p) of the sRGB form (free exponent p, white exposure x_w in s).

    Weighted least squares in (p, ln x_w) with 0.05 ≤ p ≤ 0.99 by :func:`scipy.optimize.least_squares`
    (Trust Region Reflective, ``x_scale="jac"``); the exponent's
    uncertainty from ``inv(JᵀJ)`` at the solution, scaled by the reduced χ² when above 1.
    """
    x = np.asarray(x_s, float)
    g = np.asarray(g_dn, float)
    s = np.maximum(np.asarray(sigma_dn, float), 1e-6)

    def resid(q):
        p, lxw = q
        return (white_dn * srgb_form_encode(x / math.exp(lxw), p) - g) / s

    q0 = [float(np.clip(p0, 0.05, 0.99)), math.log(x_white0)]
    res = least_squares(resid, q0, bounds=([0.05, -np.inf], [0.99, np.inf]), x_scale="jac")
    p, lxw = (float(v) for v in res.x)
    r = res.fun * s
    dof = len(x) - 2
    chi2_red = float(np.sum(res.fun**2) / dof) if dof > 0 else float("nan")
    p_unc = float("nan")
    if dof > 0:
        try:
            cov = np.linalg.inv(res.jac.T @ res.jac) * max(1.0, chi2_red)
            p_unc = float(math.sqrt(max(cov[0, 0], 0.0)))
        except np.linalg.LinAlgError:
            pass
    lb, slope = srgb_form_toe(p)
    return {"form": "srgb", "exponent": p, "exponent_unc": p_unc, "offset_a": SRGB_OFFSET_A,
            "x_white_s": math.exp(lxw), "toe_linear": lb, "toe_slope": slope, "chi2_red": chi2_red,
            "rms_dn": float(np.sqrt(np.mean(r**2)))}


# ---- the per-channel fit --------------------------------------------------------------------------------------


def _check_monotone(series: ExposureSeries, c: int, ok: np.ndarray) -> None:
    """Means of distinct exposures must not fall as the exposure grows (5 σ tolerance)."""
    x, m, s = series.x_s[ok], series.mean_dn[ok, c], series.sem_dn[ok, c]
    files = np.asarray(series.files)[ok]
    ux = np.unique(x)
    gm, gs, gf = [], [], []
    for v in ux:
        k = x == v
        gm.append(float(np.mean(m[k])))
        gs.append(float(np.sqrt(np.sum(s[k] ** 2)) / k.sum()))
        gf.append(str(files[k][0]))
    for i in range(1, len(ux)):
        drop = gm[i - 1] - gm[i]
        if drop > 5.0 * math.hypot(gs[i - 1], gs[i]) + 1e-6 * abs(gm[i - 1]):
            raise CamcalError(
                f"{series.kind} channel {series.channels[c]} is not monotone in exposure: {gf[i]} "
                f"(x = {ux[i]:.4g} s) has mean {gm[i]:.2f} DN, below {gf[i - 1]} (x = {ux[i - 1]:.4g} s, "
                f"{gm[i - 1]:.2f} DN); check the exposure values in frames.csv",
                series.folder,
            )


def fit_series(series: ExposureSeries) -> ResponseModel:
    """Fit seed eq. 12 (and, for processed files, the sRGB form) to every channel of a series.

    Raises
    ------
    CamcalError
        Fewer than three distinct exposures; all frames saturated; fewer than three
        unsaturated exposures in a channel; signal not monotone in exposure.
    """
    where = series.folder
    n_distinct = len(np.unique(series.x_s))
    if n_distinct < MIN_EXPOSURES:
        raise TooFewFrames(
            "linearity", "distinct exposures", MIN_EXPOSURES, n_distinct,
            f"{series.kind} series has {n_distinct} distinct exposure(s); the fit of eq. 12 (α, γ, β) needs at "
            f"least {MIN_EXPOSURES}", where)
    saturated = series.clipped_fraction > SATURATED_PIXEL_FRACTION  # (n, C)
    if saturated.all():
        raise TooFewFrames(
            "linearity", "unsaturated exposures", MIN_EXPOSURES, 0,
            f"all {len(series.files)} {series.kind} frames are saturated (more than "
            f"{SATURATED_PIXEL_FRACTION:.1%} of ROI pixels at the white level {series.white_level_dn:g} DN); "
            "shorten the exposures", where)
    white = series.white_level_dn
    channels: dict[str, ChannelResponse] = {}
    points: dict[str, dict] = {}
    tone_channels: dict[str, dict] = {}
    for c, name in enumerate(series.channels):
        ok = ~saturated[:, c]
        n_ok = len(np.unique(series.x_s[ok]))
        if n_ok < MIN_EXPOSURES:
            raise TooFewFrames(
                "linearity", "unsaturated exposures", MIN_EXPOSURES, n_ok,
                f"all {series.kind} frames are saturated in channel {name}; shorten the exposures" if n_ok == 0 else
                f"{series.kind} channel {name} has only {n_ok} unsaturated exposure(s); the fit of eq. 12 needs "
                f"at least {MIN_EXPOSURES}", where)
        _check_monotone(series, c, ok)
        used = ok.copy()
        compressed = np.zeros_like(ok)
        gamma0 = 1.0 if series.kind == "raw" else 0.45
        while True:
            idx = np.flatnonzero(used)
            fit = fit_eq12(series.x_s[idx], series.mean_dn[idx, c], series.sem_dn[idx, c], gamma0=gamma0)
            if len(np.unique(series.x_s[idx])) <= MIN_EXPOSURES:
                break
            top = idx[-1]
            pred = fit["alpha"] * series.x_s[top] ** fit["gamma"] + fit["beta"]
            dev = series.mean_dn[top, c] - pred
            if dev < -COMPRESSION_TOLERANCE * (pred - fit["beta"]) and dev < -5 * series.sem_dn[top, c]:
                used[top] = False
                compressed[top] = True
                continue
            break
        idx = np.flatnonzero(used)
        x_used, g_used = series.x_s[idx], series.mean_dn[idx, c]
        point = saturation_point(series.x_s, series.mean_dn[:, c], series.max_dn[:, c], saturated[:, c], used, white)
        sat = point.level_dn
        if series.dark_subtracted:
            sat_signal = sat - float(series.black_level_dn[c]) if series.kind == "raw" else sat - fit["beta"]
        else:
            sat_signal = sat - fit["beta"]
        le = emva_linearity_error(x_used, g_used - fit["beta"], sat_signal)
        rate = fit_line(x_used, g_used, series.sem_dn[idx, c]) if series.kind == "raw" else {}
        channels[name] = ChannelResponse(
            alpha=fit["alpha"], alpha_unc=fit["alpha_unc"], gamma=fit["gamma"], gamma_unc=fit["gamma_unc"],
            beta=fit["beta"], beta_unc=fit["beta_unc"],
            linear_range_dn=point.fitted_range_dn,
            saturation_dn=sat, linearity_error_pct=le, pearson_r=_pearson(x_used, g_used),
            rate_dn_per_s=rate.get("rate", float("nan")), rate_dn_per_s_unc=rate.get("rate_unc", float("nan")),
            offset_dn=rate.get("offset", float("nan")), saturation_exposure_s=point.exposure_s,
            fitted_exposure_s=point.fitted_exposure_s,
        )
        points[name] = {
            "files": list(series.files), "x_s": series.x_s.tolist(), "mean_dn": series.mean_dn[:, c].tolist(),
            "sem_dn": series.sem_dn[:, c].tolist(), "used": used.tolist(), "saturated": saturated[:, c].tolist(),
            "compressed": compressed.tolist(), "clipped_fraction": series.clipped_fraction[:, c].tolist(),
            "chi2_red": fit["chi2_red"], "rms_dn": fit["rms_dn"], "saturation_observed": bool(saturated[:, c].any()),
        }
        if series.kind != "raw":
            tone_channels[name] = _tone_fit(channels[name], fit, x_used, g_used, series.sem_dn[idx, c], white)
    tone = None
    if series.kind != "raw":
        tone = {
            "form": "V = (1 + a) (x / x_white)^p - a for x/x_white above the toe, V = s x/x_white below "
                    "(IEC 61966-2-1 with free exponent p); V = g / white",
            "channels": tone_channels,
        }
    return ResponseModel(
        kind=series.kind, channels=channels, reference_iso=series.reference_iso,
        reference_f_number=series.reference_f_number, tone=tone, white_level_dn=white,
        dark_subtracted=series.dark_subtracted, roi=series.roi, points=points,
    )


def _tone_fit(ch: ChannelResponse, fit: dict, x: np.ndarray, g: np.ndarray, sem: np.ndarray, white: float) -> dict:
    """sRGB-form fit of one processed channel; choose the inverse; proportionality check of the inverse."""
    x_white_eq12 = ((white - ch.beta) / ch.alpha) ** (1.0 / ch.gamma)
    srgb = fit_srgb_form(x, g, sem, white, p0=ch.gamma, x_white0=x_white_eq12)
    # choose the sRGB form unless eq. 12 (one more free parameter) fits clearly better
    use = "srgb" if srgb["rms_dn"] <= max(1.5 * fit["rms_dn"], 0.15) else "eq12"
    x_white = srgb["x_white_s"] if use == "srgb" else x_white_eq12
    rec = {"use": use, "srgb": srgb, "eq12_rms_dn": fit["rms_dn"], "x_white_s": float(x_white),
           "linear_gain_dn_per_s": float(white / x_white)}
    lin = _detone(g, ch, rec, white)
    ratio = lin / x
    rec["linearised_ratio_spread_pct"] = float(100.0 * (ratio.max() - ratio.min()) / np.mean(ratio))
    rec["linearised_linearity_error_pct"] = emva_linearity_error(x, lin, white)
    return rec


# ---------------------------------------------------------------------------------------------------------------
# top level, persistence, plot
# ---------------------------------------------------------------------------------------------------------------


def fit_response(series: dict[str, ExposureSeries]) -> dict[str, ResponseModel]:
    """The fit of the linearity stage, pure: every kind of series measured from one folder
    (:func:`measure_response`), seed eq. 12.

    A processed frame whose RAW twin clips is masked first (:func:`mask_raw_clipped`), then each kind is
    fitted with :func:`fit_series` (seed eq. 12).
    """
    series = dict(series)
    if "raw" in series and "processed" in series:
        series["processed"] = mask_raw_clipped(series["processed"], series["raw"])
    return {kind: fit_series(s) for kind, s in sorted(series.items())}


def mask_raw_clipped(processed: ExposureSeries, raw: ExposureSeries) -> ExposureSeries:
    """Treat a processed frame as saturated in every channel when its RAW twin (same relative exposure)
    clips in any plane.

    A camera's colour matrix mixes the RAW channels before the tone curve, so once one RAW channel
    clips, every processed channel stops being proportional to the exposure, even far below 255
    (``camcal.calibrate.colour_matrix``). Without a RAW twin at the same exposure the frame is kept.
    """
    raw_clipped = (raw.clipped_fraction > SATURATED_PIXEL_FRACTION).any(axis=1)
    bad = np.zeros(len(processed.files), bool)
    for i, x in enumerate(processed.x_s):
        same = np.isclose(raw.x_s, x, rtol=1e-6)
        bad[i] = bool(same.any() and raw_clipped[same].any())
    if not bad.any():
        return processed
    clipped = processed.clipped_fraction.copy()
    clipped[bad] = 1.0
    return replace(processed, clipped_fraction=clipped)

"""Flat fields: master flat, per-channel vignetting with a fitted optical centre, PRNU.

A flat field is a frame of a uniformly radiant target (an integrating sphere, a
diffuser over the lens). Its dark-subtracted signal per CFA plane is

    S(x, y) = A · g(x, y) · P(x, y)                                        [DN]

with A the on-axis level, g the smooth *relative illumination* (vignetting,
cos⁴ falloff, lens shading; 1 at the optical centre) and P the pixel-level
photo-response non-uniformity (PRNU, mean 1). The seed's pixel model (seed
eq. 12, g_i = α_i [∫ ... dλ]^γ_i + β_i) assumes one α per channel; the flat
field makes that true across the frame: radiance = (DN − dark) / (α · g · P).

The smooth part follows the DNG ``FixVignetteRadial`` opcode (Adobe DNG
specification 1.4, opcode list 3, also used by SPECTACLE, Burggraaff et al. 2019)

    g(r) = 1 + k0 r² + k1 r⁴ + k2 r⁶ + k3 r⁸ + k4 r¹⁰

with r the distance from the optical centre (cx, cy) divided by the distance
from the optical centre to the farthest image corner. Distances are measured in
*full-resolution mosaic pixels* (a plane pixel (x, y) of a plane with CFA offset
(ox, oy) sits at mosaic pixel (2x + ox, 2y + oy); the image corners are the
pixel centres (0, 0) and (W − 1, H − 1)), so the k are those a DNG writer would
store. The centre is a free parameter per plane, reported in plane pixels.

Normalisation: g = 1 at the optical centre. Radiance calibration therefore
refers to the on-axis sensitivity (``docs/conventions.md``).

Fitting (fast whatever the sensor size): each plane is block-averaged to about
64 blocks along its long side; for a trial centre the model is linear in
(A, A·k0, ..., A·k4), so a bounded trust-region least squares
(:func:`scipy.optimize.least_squares`, Trust Region Reflective) searches only the
centre (variable projection) and a weighted linear solve gives the rest.
Residuals are relative (data/model − 1): shot noise and PRNU both scale with
the signal. An optional smooth 2-D model (a Legendre series in x and y) serves
lenses that are not radially symmetric. PRNU is the pixel-level residual
master / (A·g), normalised to mean 1.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.polynomial import legendre
from scipy.optimize import least_squares

from camcal.calibrate.emva import Nonuniformity, prnu, spatial_variance
from camcal.calibrate.robust import median
from camcal.calibrate.screen import StageJudge
from camcal.calibrate.session import StageFrames, aperture_folders, folder_of, stage_files
from camcal.calibrate.stack import StackOptions, combine_frames
from camcal.errors import CamcalError
from camcal.frame import PLANES, Exposure, Frame
from camcal.io.folders import list_frames
from camcal.models.blocks import auto_downsample, block_mean
from camcal.models.correct import Calibration, correct_frame, require_valid
from camcal.models.dark import DarkModel, as_dark_model
from camcal.models.flat import (
    DEAD_RESPONSE,
    F_NUMBER_TOLERANCE,
    FOCAL_TOLERANCE,
    N_RADIAL,
    FlatModel,
    Optics,
    PlaneGeometry,
    _legendre_uv,
)

DEFAULT_TERMS = 3
"""Radial terms fitted by default: k0..k2, the vignetting model of Adobe's lens profiles (k3 = k4 = 0).
More terms follow noise at the farthest corner (the only place the data constrain r¹⁰)."""


# ---------------------------------------------------------------------------------------------
# fitting on arrays
# ---------------------------------------------------------------------------------------------


def _radial_design(geom, channel, x, y, cx, cy, n_terms):
    r2 = geom.r2(channel, x, y, cx, cy)
    return np.stack([r2**i for i in range(n_terms + 1)], axis=-1)


def _weighted_solve(design: np.ndarray, data: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    coef, *_ = np.linalg.lstsq(design * weight[:, None], data * weight, rcond=None)
    return coef, design @ coef


def _quadratic_vertex(x: np.ndarray, y: np.ndarray, d: np.ndarray, box: tuple[float, float, float, float]):
    """Start for the centre: the vertex of a quadratic surface fitted to the data, kept inside the central 80 %."""
    x_lo, x_hi, y_lo, y_hi = box
    xm, ym, sx, sy = (x_lo + x_hi) / 2, (y_lo + y_hi) / 2, (x_hi - x_lo) / 2 or 1.0, (y_hi - y_lo) / 2 or 1.0
    u, v = (x - xm) / sx, (y - ym) / sy
    a = np.stack([np.ones_like(u), u, v, u * u, v * v, u * v], axis=-1)
    c, *_ = np.linalg.lstsq(a, d, rcond=None)
    hess = np.array([[2 * c[3], c[5]], [c[5], 2 * c[4]]])
    try:
        uv = np.linalg.solve(hess, -c[1:3])
    except np.linalg.LinAlgError:
        uv = np.zeros(2)
    if not np.all(np.isfinite(uv)):
        uv = np.zeros(2)
    uv = np.clip(uv, -0.8, 0.8)
    return xm + uv[0] * sx, ym + uv[1] * sy


def fit_radial_plane(
    block: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    geom: PlaneGeometry,
    channel: str,
    *,
    n_terms: int = DEFAULT_TERMS,
    centre_guess: tuple[float, float] | None = None,
) -> tuple[float, tuple[float, float], tuple[float, ...], float]:
    """Fit A·g(r) to one downsampled plane, optical centre free.

    Variable projection: for a trial centre, (A, A·k0, ..., A·k_{n-1}) follow from a linear solve
    weighted by 1/data (relative residuals); :func:`scipy.optimize.least_squares` (Trust Region
    Reflective, Branch, Coleman & Li 1999) moves the centre within
    the plane, forward differences of relative step 1e-4.

    Returns
    -------
    level : A, the on-axis level (units of ``block``)
    centre : (cx, cy) in plane pixels
    k : k0..k4 (zeros beyond ``n_terms``)
    rms : relative RMS residual data/model − 1 over the blocks
    """
    ok = np.isfinite(block) & (block > 0)
    d, xs, ys = block[ok], x[ok], y[ok]
    if d.size < 4 * (n_terms + 3):
        raise CamcalError(f"channel {channel}: too few usable blocks ({d.size}) to fit the vignetting model")
    wgt = 1.0 / d

    def resid(p):
        design = _radial_design(geom, channel, xs, ys, p[0], p[1], n_terms)
        _, model = _weighted_solve(design, d, wgt)
        return (model - d) * wgt

    x_lo, x_hi, y_lo, y_hi = float(x.min()), float(x.max()), float(y.min()), float(y.max())
    if centre_guess is None:
        centre_guess = _quadratic_vertex(xs, ys, d, (x_lo, x_hi, y_lo, y_hi))
    sol = least_squares(resid, np.asarray(centre_guess, float), bounds=([x_lo, y_lo], [x_hi, y_hi]),
                        x_scale=[max(1.0, (x_hi - x_lo) / 10)] * 2, diff_step=1e-4, xtol=1e-7, ftol=1e-10)
    cx, cy = (float(v) for v in sol.x)
    design = _radial_design(geom, channel, xs, ys, cx, cy, n_terms)
    coef, model = _weighted_solve(design, d, wgt)
    level = float(coef[0])
    if not level > 0:
        raise CamcalError(f"channel {channel}: the vignetting fit failed (non-positive on-axis level)")
    k = tuple(float(c / level) for c in coef[1:]) + (0.0,) * (N_RADIAL - n_terms)
    rms = float(np.sqrt(np.mean((d / model - 1.0) ** 2)))
    return level, (cx, cy), k, rms


def _total_degree_mask(degree: int) -> np.ndarray:
    """(n+1, n+1) bool: Legendre terms P_i(u) P_j(v) with i + j <= degree."""
    i, j = np.mgrid[0 : degree + 1, 0 : degree + 1]
    return (i + j) <= degree


def fit_2d_plane(
    block: np.ndarray, x: np.ndarray, y: np.ndarray, geom: PlaneGeometry, channel: str, degree: int,
    centre: tuple[float, float],
) -> tuple[float, np.ndarray, float, float]:
    """Weighted linear fit of a 2-D Legendre series of total ``degree`` in u, v to one downsampled plane.

    Returns (level at ``centre``, coefficients normalised so the series is 1 at ``centre``, scale 1.0,
    relative RMS residual).
    """
    ok = np.isfinite(block) & (block > 0)
    d = block[ok]
    n_coef = int(_total_degree_mask(degree).sum())
    if d.size < 2 * n_coef:
        raise CamcalError(f"channel {channel}: too few usable blocks ({d.size}) for a degree-{degree} 2-D model; "
                          f"lower the degree or the downsample factor")
    u, v = _legendre_uv(geom, channel, x[ok], y[ok])
    keep = _total_degree_mask(degree).ravel()
    design = legendre.legvander2d(u, v, [degree, degree])[:, keep]
    sol, model = _weighted_solve(design, d, 1.0 / d)
    coef = np.zeros((degree + 1) ** 2)
    coef[keep] = sol
    coef = coef.reshape(degree + 1, degree + 1)
    uc, vc = _legendre_uv(geom, channel, np.array(centre[0]), np.array(centre[1]))
    level = float(legendre.legval2d(uc, vc, coef))
    if not level > 0:
        raise CamcalError(f"channel {channel}: the 2-D flat model is not positive at the optical centre")
    rms = float(np.sqrt(np.mean((d / model - 1.0) ** 2)))
    return level, coef / level, 1.0, rms


def _check_options(model: str, n_terms: int) -> None:
    if model not in ("radial", "2d"):
        raise CamcalError(f"unknown flat model {model!r}; choose 'radial' or '2d'")
    if not 1 <= n_terms <= N_RADIAL:
        raise CamcalError(f"n_terms must be 1..{N_RADIAL}, got {n_terms}")


def fit_flat_planes(
    master: np.ndarray,
    *,
    channels: tuple[str, ...] = PLANES,
    cfa_pattern: str | None = "RGGB",
    model: Literal["radial", "2d"] = "radial",
    downsample: int | None = None,
    n_terms: int = DEFAULT_TERMS,
    degree_2d: int = 4,
    mask: np.ndarray | None = None,
    with_prnu: bool = True,
    noise_var: np.ndarray | None = None,
    info: dict | None = None,
    smooth_out: list | None = None,
) -> FlatModel:
    """Fit the vignetting model (and PRNU) to a master flat held in memory.

    Parameters
    ----------
    master : (C, h, w) array
        Dark-subtracted master flat, any positive scale per channel (DN, or normalised).
    channels : plane names in ``master`` order.
    cfa_pattern : CFA pattern the planes came from (None: the planes are full resolution).
    model : ``"radial"`` (DNG radial, centre free) or ``"2d"`` (Legendre series; the radial fit
        still gives the optical centre, where the 2-D model is normalised to 1).
    downsample : block size for the fit, photo (full-resolution) pixels, whole CFA cells: a multiple of 2 for
        CFA planes (default: ~64 blocks on the long side). The model's ``info["downsample"]`` is that block in
        plane pixels.
    n_terms : radial coefficients fitted (1..5; the rest are 0).
    degree_2d : degree in x and y of the 2-D model.
    mask : (C, h, w) bool/uint8, True for pixels to ignore (hot pixels from the dark model).
    with_prnu : compute the PRNU map master / (A·g), mean 1 per plane.
    noise_var : (C, h, w) variance of ``master`` (same units squared), to remove temporal noise
        from the PRNU RMS estimate.
    info : provenance to store in the model.
    smooth_out : a list to which the smooth model A·g (float64, (C, h, w), the PRNU map's divisor) is appended
        when the PRNU is computed, for :func:`flat_prnu` of the same fit (:func:`fit_flat`) without evaluating
        the model again.
    """
    master = np.asarray(master)
    if master.ndim != 3 or master.shape[0] != len(channels):
        raise CamcalError(f"a master flat must be ({len(channels)}, h, w), got shape {master.shape}")
    _check_options(model, n_terms)
    if mask is not None and mask.shape != master.shape:
        raise CamcalError(f"defect mask has shape {mask.shape}, the flats have {master.shape}")
    _, h, w = master.shape
    geom = PlaneGeometry.for_planes(channels, (h, w), cfa_pattern)
    if downsample is None:
        factor = auto_downsample((h, w))
    elif int(downsample) < geom.scale or int(downsample) % geom.scale:
        raise CamcalError(f"downsample {downsample}: the block is in photo pixels and must hold whole "
                          f"{geom.scale}x{geom.scale} CFA cells (a positive multiple of {geom.scale})")
    else:
        factor = int(downsample) // geom.scale
    centres, ks, rms, levels, coef2d, scale2d = {}, {}, {}, {}, {}, {}
    for i, c in enumerate(channels):
        block, bx, by = block_mean(master[i], factor, None if mask is None else mask[i])
        level, centre, k, r = fit_radial_plane(block, bx, by, geom, c, n_terms=n_terms)
        centres[c], ks[c], rms[c], levels[c] = centre, k, r, level
        if model == "2d":
            level2, coef, scale, r2d = fit_2d_plane(block, bx, by, geom, c, degree_2d, centre)
            levels[c], rms[c] = level2, r2d
            coef2d[c], scale2d[c] = coef.tolist(), scale
    model_2d = None
    if model == "2d":
        model_2d = {"kind": "legendre2d", "degree": int(degree_2d), "coefficients": coef2d, "scale": scale2d,
                    "domain": "u = 2X/(W-1) - 1, v = 2Y/(H-1) - 1, (X, Y) full-resolution pixel centres"}
    fm = FlatModel(
        channels=tuple(channels), centre_px=centres, k=ks, model_2d=model_2d, prnu=None, residual_rms=rms,
        shape=(h, w), cfa_pattern=cfa_pattern, level_dn=levels,
        info={"downsample": factor, "n_terms": n_terms, **(info or {})},
    )
    if not with_prnu:
        return fm
    fm = fm.with_gain(fm.gain())  # evaluated once: the PRNU here, then the sweep's correction and the profile
    smooth = _smooth_model(fm)
    if smooth_out is not None:
        smooth_out.append(smooth)
    prnu = master / smooth
    prnu_rms = {}
    for i, c in enumerate(channels):
        good = np.isfinite(prnu[i]) & (smooth[i] > 0)
        if mask is not None:
            good &= ~mask[i].astype(bool)
        mean = float(np.mean(prnu[i][good]))
        prnu[i] /= mean
        prnu[i][~good] = 1.0
        # the RMS of responding pixels: dead ones (response < DEAD_RESPONSE) are defects, not PRNU
        good &= (prnu[i] >= DEAD_RESPONSE) & (prnu[i] <= 2.0 - DEAD_RESPONSE)
        var = float(np.var(prnu[i][good]))
        if noise_var is not None:
            var -= float(np.mean((noise_var[i] / smooth[i] ** 2 / mean**2)[good]))
        prnu_rms[c] = float(np.sqrt(max(var, 0.0)))
    return fm.replace(prnu=prnu.astype(np.float32), prnu_rms=prnu_rms)


# ---------------------------------------------------------------------------------------------
# applying
# ---------------------------------------------------------------------------------------------



# ---------------------------------------------------------------------------------------------
# from files: checks, master flat, fit
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FlatChecks:
    """Exposure limits for flat frames.

    Attributes
    ----------
    max_clipped_fraction : float
        Largest fraction of pixels at or above the white level (saturated) a flat may have outside the
        known defects. Fewer are masked (left out of the combine and the fit, :mod:`camcal.models.correct`): stray
        saturated pixels (hot pixels without a dark model, a speck of glare) do not cost the frame; more mean
        an over-exposed region, whose masking would bias the falloff there.
    min_level : float
        Smallest median signal of the weakest plane, as a fraction of the range white − black.
        Below it the flat is too dark for a useful SNR (5 % of a 14-bit range is ~800 DN,
        a shot-noise SNR of ~35 per pixel and frame at 1.6 e⁻/DN).
    max_level : float
        Largest median signal of the brightest plane (fraction of the range); above it the
        bright centre risks the non-linear top of the sensor's range.
    """

    max_clipped_fraction: float = 1e-2
    min_level: float = 0.05
    max_level: float = 0.95


@dataclass(frozen=True)
class FlatOptions:
    """Options of the flat stage: the combine (:func:`measure_flat`) and the fit (:func:`fit_flat`).

    Attributes
    ----------
    model, downsample, n_terms, degree_2d, with_prnu : the fit, see :func:`fit_flat_planes`.
    method, sigma : combine method (``mean``, ``median``, ``sigma_clip``) and clip threshold (standard deviations).
    checks : exposure limits of each flat frame (:class:`FlatChecks`).
    """

    model: Literal["radial", "2d"] = "radial"
    downsample: int | None = None
    n_terms: int = DEFAULT_TERMS
    degree_2d: int = 4
    with_prnu: bool = True
    method: str = "sigma_clip"
    sigma: float = 3.0
    checks: FlatChecks = FlatChecks()  # noqa: RUF009 - frozen, so one shared default is safe

    def fit_kwargs(self) -> dict:
        """The keywords of :func:`fit_flat_planes`."""
        return {"model": self.model, "downsample": self.downsample, "n_terms": self.n_terms,
                "degree_2d": self.degree_2d, "with_prnu": self.with_prnu}


HISTOGRAM_ROWS = 256
"""Rows of a plane counted at a time by :func:`_histogram` (their index copy stays in the cache)."""


def _histogram(plane: np.ndarray) -> np.ndarray:
    """``np.bincount(plane.ravel())`` of a non-negative integer plane, counted in bands of :data:`HISTOGRAM_ROWS`
    rows: :func:`numpy.bincount` converts its input to a platform integer first, a copy 4x the size of a 16-bit
    plane, which per band stays in the cache (twice as fast at 24 MP)."""
    total = np.zeros(0, np.intp)
    for y in range(0, plane.shape[0], HISTOGRAM_ROWS):
        counts = np.bincount(plane[y:y + HISTOGRAM_ROWS].ravel())
        if counts.size < total.size:
            total[:counts.size] += counts
        else:
            counts[:total.size] += total
            total = counts
    return total


def _medians_above(planes: np.ndarray | Sequence[np.ndarray], black: np.ndarray) -> np.ndarray:
    """Per-plane median of ``planes − black`` (C, h, w) − (C, 1, 1), as :func:`numpy.median` gives it.

    ``planes``: one (C, h, w) array or C planes of one shape and type (views of a frame's mosaic,
    :meth:`camcal.frame.Frame.plane_views`). Integer planes (DN) take the two middle order statistics from a
    histogram (:func:`numpy.bincount`, one pass instead of a selection over a float64 copy) and average them minus
    the black level in float64, the very operations of ``np.median(planes - black)``; other planes go to
    :func:`numpy.median`.
    """
    c = len(planes)
    kind = planes[0].dtype.kind
    if kind not in "ui" or planes[0].size == 0 or (kind == "i" and min(int(p.min()) for p in planes) < 0):
        bk = np.asarray(black).reshape(c)
        return np.array([np.median(np.subtract(p, bk[k])) for k, p in enumerate(planes)])
    n = planes[0].size
    out = np.empty(c)
    for k in range(c):
        cum = np.cumsum(_histogram(planes[k]))
        lo, hi = np.searchsorted(cum, [(n - 1) // 2, n // 2], side="right")  # the order statistics' values
        bk = np.float64(black.reshape(c)[k])
        out[k] = ((np.float64(lo) - bk) + (np.float64(hi) - bk)) / 2
    return out


def check_flat_frame(frame: Frame, checks: FlatChecks = FlatChecks(),  # noqa: B008
                     shape: tuple[int, int] | None = None, reference: str | None = None,
                     defects: np.ndarray | None = None) -> None:
    """Raise a one-line :class:`CamcalError` when a flat frame is unusable.

    Checks: RAW (a JPEG's tone curve breaks the flat), same size as ``shape`` (the first flat),
    not saturated outside the known ``defects`` ((C, h, w) bool planes; a hot pixel the dark model
    knows never makes a flat "saturated"), not too dark, not too bright.
    """
    path = frame.path
    if frame.kind != "raw":
        raise CamcalError("flat fields must be RAW frames (a processed image's tone curve distorts the falloff)",
                          path)
    if shape is not None and frame.shape != tuple(shape):
        ref = f" of {reference}" if reference else ""
        raise CamcalError(f"is {frame.shape[1]}x{frame.shape[0]} pixels but the flats{ref} are "
                          f"{shape[1]}x{shape[0]}: mismatched sizes (one camera, one mode)", path)
    white = float(frame.white_level_dn)
    planes = frame.plane_views()  # views in the file's own type: integer DN stay integer (exact), no copy
    n_white = 0
    if frame.may_reach(white):  # else the reader's maximum is below white: nothing to count
        for k, plane in enumerate(planes):
            at_white = plane >= white
            if defects is not None and defects.shape == (len(planes), *plane.shape):
                at_white &= ~defects[k]
            n_white += int(np.count_nonzero(at_white))
    clipped = n_white / (len(planes) * planes[0].size)  # the fraction np.mean gives, without a float pass
    if clipped > checks.max_clipped_fraction:
        raise CamcalError(f"flat is saturated: {100 * clipped:.3g} % of pixels at the white level ({white:g} DN) "
                          f"outside known defects; shorten the exposure or dim the source", path)
    black = frame.black_vector()
    med = _medians_above(planes, black)
    span = white - black.ravel()
    frac = med / span
    lo = int(np.argmin(frac))
    if frac[lo] < checks.min_level:
        raise CamcalError(
            f"flat is too dark for a useful SNR: plane {frame.channel_names[lo]} median {med[lo]:.0f} DN above black "
            f"is {100 * frac[lo]:.2g} % of the range (need {100 * checks.min_level:g} %); lengthen the exposure", path)
    hi = int(np.argmax(frac))
    if frac[hi] > checks.max_level:
        raise CamcalError(
            f"flat is over-exposed: plane {frame.channel_names[hi]} median is {100 * frac[hi]:.3g} % of the range "
            f"(limit {100 * checks.max_level:g} %); shorten the exposure", path)


@dataclass(frozen=True)
class MasterFlat:
    """A combined, dark-subtracted flat, normalised per channel.

    Attributes
    ----------
    value : (C, h, w) float32, each frame's dark-subtracted planes divided by their per-plane median,
        then combined: median ≈ 1 per plane (dimensionless).
    variance_of_mean : (C, h, w) float32, temporal variance of ``value`` divided by the frame count.
    level_dn : per-plane median signal of the first frame, DN above dark (the frames are checked to be
        well exposed; the master itself is normalised).
    n_frames, paths, channels, cfa_pattern, method, exposure_s (per frame).
    mean_all, variance_all : (C, h, w) float32 plain mean and per-frame temporal variance (ddof = 1) of *all*
        normalised frames, before any clipping: the unclipped statistics of EMVA 1288's spatial variance
        (:func:`camcal.calibrate.emva.spatial_variance`); None with a single frame.
    """

    value: np.ndarray
    variance_of_mean: np.ndarray | None
    level_dn: dict[str, float]
    n_frames: int
    paths: tuple[Path, ...]
    channels: tuple[str, ...]
    cfa_pattern: str | None
    method: str
    exposure_s: tuple[float | None, ...]
    mean_all: np.ndarray | None = None
    variance_all: np.ndarray | None = None
    optics: Optics = Optics()  # noqa: RUF009 - frozen, so one shared default is safe


def flats_optics(exposures: list[Exposure] | tuple[Exposure, ...], where: Path | None = None) -> Optics:
    """The f-number and focal length of a set of flats, each with its source (:class:`camcal.models.flat.Optics`).

    A value no frame holds stays None. Frames at several f-numbers are refused (one vignetting model per
    f-number: ``camcal calibrate`` groups a session's flats by f-number); several focal lengths leave the focal
    length unknown, its source naming them.
    """

    def one(name: str, tol: float, unit: str) -> tuple[float | None, str | None]:
        known = [(float(getattr(e, name)), e.source(name) or "unknown source") for e in exposures
                 if getattr(e, name) is not None]
        if not known:
            return None, None
        values = sorted({v for v, _ in known})
        if values[-1] - values[0] > tol * values[0]:
            if name == "f_number":
                raise CamcalError(f"flats at several f-numbers ({', '.join(f'f/{v:g}' for v in values)}): one "
                                  "vignetting model per f-number; calibrate the session (flat/f<N>/ folders or "
                                  "the f-number of each frame) or give the flats of one f-number", where)
            return None, f"mixed: {', '.join(f'{v:g}' for v in values)} {unit}"
        vals = [v for v, _ in known]
        value = max(set(vals), key=vals.count)
        return value, "+".join(sorted({src for _, src in known}))

    n, n_src = one("f_number", F_NUMBER_TOLERANCE, "")
    f, f_src = one("focal_length_mm", FOCAL_TOLERANCE, "mm")
    return Optics(n, n_src, f, f_src)


def measure_flat(
    flat_folder: str | Path | StageFrames,
    dark: DarkModel | str | Path | None = None,
    options: FlatOptions = FlatOptions(),  # noqa: B008
    *,
    jobs: int | None = 1,
    progress: Callable | None = None,
    judge: StageJudge | None = None,
) -> MasterFlat:
    """The file step of the flat stage: correct, normalise and combine every flat of a folder (streaming,
    :mod:`camcal.calibrate.stack`; ``options.method``, ``options.sigma``, ``options.checks``).

    A folder that holds its flats only in per-f-number subfolders (``f<N>/``) is refused, naming them: one
    vignetting model is fitted per f-number (``camcal calibrate`` does each).

    ``judge``: the stage's :class:`camcal.calibrate.screen.StageJudge`, given to
    :func:`camcal.calibrate.stack.combine_frames`: each flat is judged as it is decoded, and one left out is not
    combined.

    Each frame goes through the one correction path (:func:`camcal.models.correct.correct_frame`): its
    planes minus the dark model's expected bias + dark (or, without a dark model, the file's black
    level), known defects and saturated pixels masked (NaN, left out of the combine and the fit).
    The valid pixels are divided by their per-plane median so lamp drift between frames does not
    bias the combine; the combined master is thus normalised per channel (median ≈ 1).
    """
    _check_options(options.model, options.n_terms)
    method, sigma, checks = options.method, options.sigma, options.checks
    subs = aperture_folders(Path(flat_folder)) if not isinstance(flat_folder, StageFrames) else []
    if subs and not list_frames(flat_folder):
        names = ", ".join(f"{d.name}/" for _, d in subs)
        raise CamcalError(f"holds its flats in {names} (one folder per f-number): give one of them, or calibrate "
                          "the session (one vignetting model per f-number)", flat_folder)
    dark_model = as_dark_model(dark)
    cal = Calibration.of(dark_model).remembering_dark_frames()  # one exposure: the dark frame computed once
    paths, manifest = stage_files(flat_folder)
    first: dict = {}  # of the first frame, which combine_frames decodes first, in this thread: shape, level

    def check_first(frame: Frame) -> None:
        plane_shape = (frame.shape[0] // 2, frame.shape[1] // 2) if frame.layout == "bayer" else frame.shape
        if dark_model is not None:
            dshape = tuple(np.asarray(dark_model.bias_dn).shape)
            if dshape[-2:] != plane_shape:
                raise CamcalError(f"the dark model is for {dshape[-1]}x{dshape[-2]} planes but the flats have "
                                  f"{plane_shape[1]}x{plane_shape[0]} planes: mismatched sizes", frame.path)
            dpat = getattr(dark_model, "cfa_pattern", None)
            if dpat and frame.cfa_pattern and dpat != frame.cfa_pattern:
                raise CamcalError(f"the dark model is for CFA pattern {dpat} but the flats are {frame.cfa_pattern}",
                                  frame.path)
        check_flat_frame(frame, checks, defects=cal.defects)

    def check(frame: Frame) -> None:
        if "shape" not in first:
            check_first(frame)
            first["shape"] = frame.shape
            return
        check_flat_frame(frame, checks, shape=first["shape"], reference=paths[0].name, defects=cal.defects)

    def corrected(frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        corr = correct_frame(frame, cal)
        require_valid(corr, frame.path, what="flat")
        med = np.array([median(corr.signal_dn[k][~corr.invalid[k]]) for k in range(corr.signal_dn.shape[0])])
        signal = corr.signal_dn  # this frame's own array (its planes, corrected in place): masked in place
        signal[corr.invalid] = np.nan
        return signal, med

    def preprocess(frame: Frame) -> np.ndarray:
        planes, med = corrected(frame)
        if "level" not in first:  # the first frame: preprocessed first, in this thread
            first["level"] = med
        if np.any(med <= 0):
            raise CamcalError("flat has no signal above dark in some plane", frame.path)
        planes /= med[:, None, None].astype(np.float32)
        return planes

    res = combine_frames(paths, StackOptions(method, sigma, jobs), preprocess=preprocess, manifest=manifest,
                         check=check, progress=progress, rule=judge)
    optics = flats_optics(res.exposures, folder_of(flat_folder))
    # per-plane level in DN: that of the first frame (the check guarantees all are similar)
    level = {c: float(m) for c, m in zip(res.channel_names, first["level"], strict=True)}
    var = None
    if getattr(res, "variance", None) is not None and res.n_frames > 1:
        # variance / max(count, 1), in one new float32 array (not three: 96 MB each at 24 MP)
        var = np.array(res.count, np.float32)  # a copy, whatever the count's type
        np.maximum(var, np.float32(1.0), out=var)
        np.divide(np.asarray(res.variance, np.float32), var, out=var)
    return MasterFlat(
        value=np.asarray(res.value, np.float32), variance_of_mean=var, level_dn=level, n_frames=int(res.n_frames),
        paths=tuple(Path(p) for p in res.paths), channels=tuple(res.channel_names), cfa_pattern=res.cfa_pattern,
        method=str(res.method), exposure_s=tuple(e.exposure_s for e in res.exposures),
        mean_all=None if var is None or res.mean_all is None else np.asarray(res.mean_all, np.float32),
        variance_all=None if var is None or res.variance_all is None else np.asarray(res.variance_all, np.float32),
        optics=optics,
    )



def fit_flat(
    mf: MasterFlat,
    dark_model: DarkModel | None = None,
    options: FlatOptions = FlatOptions(),  # noqa: B008
    *,
    prnu_out: dict[str, Nonuniformity] | None = None,
) -> FlatModel:
    """The fit of the flat stage, pure: the vignetting model and PRNU of a :class:`MasterFlat`
    (:func:`fit_flat_planes` with ``options.fit_kwargs()``; hot pixels of ``dark_model.defects`` masked); levels
    reported in DN.

    ``prnu_out``: a dict filled with the EMVA 1288 PRNU per plane of this fit (:func:`flat_prnu`, about the smooth
    model the fit evaluated already; also without ``with_prnu``), when the master has unclipped statistics.
    """
    mask = ~np.isfinite(mf.value)  # masked in every frame: known defects, saturated (camcal.models.correct)
    if dark_model is not None and getattr(dark_model, "defects", None) is not None:
        defects = np.asarray(dark_model.defects).astype(bool)
        if defects.shape != mf.value.shape:
            raise CamcalError(f"the dark model's defect map has shape {defects.shape}, the flats {mf.value.shape}: "
                              f"mismatched sizes")
        mask |= defects
    mf = dataclasses.replace(mf, value=np.where(mask, np.float32(1.0), mf.value))
    info = {
        "n_frames": mf.n_frames,
        "files": [p.name for p in mf.paths],
        "combine": mf.method,
        "dark": "dark model" if dark_model is not None else "black level only",
        "exposure_s": list(mf.exposure_s),
        "flat_level_dn": mf.level_dn,
    }
    smooth: list[np.ndarray] = []
    _check_options(options.model, options.n_terms)
    with_prnu = options.with_prnu
    fm = fit_flat_planes(mf.value, channels=mf.channels, cfa_pattern=mf.cfa_pattern, mask=mask,
                         noise_var=mf.variance_of_mean, info=info, smooth_out=smooth, **options.fit_kwargs())
    if (with_prnu or prnu_out is not None) and mf.mean_all is not None:
        figures = _prnu_figures(mf, fm.channels, smooth[0] if smooth else _smooth_model(fm), mask)
        if with_prnu:
            fm = fm.replace(prnu_rms={c: p.value for c, p in figures.items()})
        if prnu_out is not None:
            prnu_out.update(figures)
    # the master is normalised per plane: report the on-axis level in DN of the frames
    level_dn = {c: fm.level_dn[c] * mf.level_dn[c] for c in fm.channels}
    return fm.replace(level_dn=level_dn, optics=mf.optics)


def flat_prnu(mf: MasterFlat, fm: FlatModel, mask: np.ndarray | None = None) -> dict[str, Nonuniformity]:
    """EMVA 1288 PRNU per plane of a master flat about the fitted vignetting model (pure).

    The unclipped average of the L normalised flats is divided by the smooth model (vignetting, lamp
    falloff: not pixel nonuniformity) and its spatial variance reduced by the temporal variance left in
    the average, ``s²_y = s²_y.measured − σ²_y.stack / L`` (EMVA 1288 release 4.0, eq. 36,
    :func:`camcal.calibrate.emva.spatial_variance`). The flats are dark-subtracted per pixel with the dark model, so
    the DSNU is already out (the standard's ``− s²_y.dark``). ``fm`` must be the fit of ``mf`` (level_dn in
    the master's normalised units). Pixels masked by ``mask``, non-finite or not responding
    (:data:`DEAD_RESPONSE`) are left out.
    """
    return _prnu_figures(mf, fm.channels, _smooth_model(fm), mask)


def _smooth_model(fm: FlatModel) -> np.ndarray:
    """A·g per plane (float64, (C, h, w)): the fitted vignetting model at the fitted levels ``fm.level_dn``."""
    return fm.gain().astype(np.float64) * np.array([fm.level_dn[c] for c in fm.channels])[:, None, None]


def _prnu_figures(mf: MasterFlat, channels: tuple[str, ...], smooth: np.ndarray,
                  mask: np.ndarray | None) -> dict[str, Nonuniformity]:
    """:func:`flat_prnu` about the smooth model ``smooth`` (:func:`_smooth_model` of the fit)."""
    if mf.mean_all is None or mf.variance_all is None:
        raise CamcalError("the master flat has no unclipped statistics (a single frame?)")
    out = {}
    for i, c in enumerate(channels):
        rel = mf.mean_all[i] / smooth[i]
        good = np.isfinite(rel) & (smooth[i] > 0) & np.isfinite(mf.variance_all[i])
        if mask is not None:
            good &= ~np.asarray(mask[i], bool)
        med = float(median(rel[good]))
        good &= (rel >= DEAD_RESPONSE * med) & (rel <= (2.0 - DEAD_RESPONSE) * med)
        sv = spatial_variance(rel, mf.variance_all[i] / smooth[i] ** 2, mf.n_frames, good)
        out[c] = prnu(sv)
    return out

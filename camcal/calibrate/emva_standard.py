"""EMVA 1288 figures exactly as the standard defines them, from the moments of a measurement (pure functions).

This module computes the figures that carry the standard's names (K, σ_y.dark, σ_d, DSNU₁₂₈₈, PRNU₁₂₈₈, μ_e.sat,
SNR_max, η, DR, LE) from the moments of the standard's measurement: frame *pairs* per illumination step
(:class:`TemporalSeries`) and one averaged stack of bright and one of dark frames (:class:`SpatialStack`). Nothing
here is camcal's own estimator: camcal's vignetting-free PRNU and its quantised-noise read noise live in
:mod:`camcal.calibrate.flat` and :mod:`camcal.calibrate.dark` under their own names.

Definitions (EMVA Standard 1288 release 3.0 (2010) §6-8 and release 4.0 (2021) "Linear" §4-8; the equation
numbers are those of release 3.0 as the reference implementation ``emva1288`` labels them):

- **Temporal moments of a pair** A, B (eqs. 28-29): ``μ_y = ½(⟨y_A⟩ + ⟨y_B⟩)``,
  ``σ²_y = ½ var(y_A − y_B)`` (population variance; its mean-difference term removes a level change).
- **K, photon transfer** (eq. 8): the slope through the origin of ``σ²_y − σ²_y.dark`` against
  ``μ_y − μ_y.dark`` (both with the dark pair of the same exposure), fitted from the darkest point up to the
  last point at or below 70 % of the saturation signal.
- **Saturation point**: the step of maximum temporal variance, searched from the brightest step down
  (:func:`camcal.calibrate.emva.saturation_index`); ``μ_p.sat`` its photon count.
- **Responsivity R** (eq. 9): slope through the origin of ``μ_y − μ_y.dark`` against μ_p in the same range;
  **η = R/K** (eq. 2).
- **σ_y.dark** (eq. 10): the intercept at zero exposure of a line of the dark pairs' variance against exposure
  time (more than two exposure times; otherwise the first), not below 0.24 DN² (the quantisation-dominated
  floor of the standard); **σ_d = √(σ²_y.dark − σ²_q)/K** with σ²_q = 1/12 DN² (eq. 4/10).
- **μ_e.sat = η μ_p.sat** (eq. 11), ``μ_y.sat − μ_y.dark = R μ_p.sat``; **SNR_max = √μ_e.sat** (eq. 20);
  **μ_p.min = (σ_y.dark/K + ½)/η** (eq. 17); **DR = μ_p.sat/μ_p.min** (eq. 19).
- **Linearity** (eqs. 23-24): a line minimising the relative deviations between 5 % and 95 % of the saturation
  signal; ``δ = 100 (μ − (a x + b))/(a x + b)`` %; release 4.0 reports LE_min and LE_max, release 3.0
  ``LE = (max δ − min δ)/2``.
- **Dark current** (eqs. 25-26): slope of the dark mean against exposure time, /K in e⁻ s⁻¹; from the variance,
  slope/K².
- **Spatial variances** (eqs. 33-38): ``⟨y⟩`` the average of L frames; ``s²_y = s²_y.measured − σ²_y.stack/L``
  (σ²_y.stack the mean per-pixel temporal variance, ddof 1). **DSNU₁₂₈₈ = s_y.dark/K** (e⁻; s_y.dark in DN),
  **PRNU₁₂₈₈ = √(s²_y − s²_y.dark)/(μ_y − μ_y.dark)**: the *total* non-uniformity, vignetting and row or column
  patterns included.
- **Row, column and pixel parts** (release 4.0, eq. 41 in the reference implementation's labels): the variances
  of the column means and row means with their temporal parts removed, ``s²_cav``, ``s²_rav``; then for an
  M × N image ``s²_col = (MN − M)/(MN − M − N) s²_cav − N/(MN − M − N)(s²_y − s²_rav)``, the row part likewise,
  ``s²_pixel = MN/(MN − M − N)(s²_y − s²_cav − s²_rav)``.

Uncertainties (one standard deviation) are camcal's, not the standard's (it states none). u(K) is the larger of
two estimates of the scatter of the unweighted slope: the points' own uncertainties propagated through it,
``u(K)² = Σ x_i² u²(σ²_i) / (Σ x_i²)²`` with u(σ²_i) measured on each pair's pixels (:func:`pair_moments`), and a
bootstrap of the points (:func:`camcal.calibrate.emva.gain_bootstrap`); the residual-scatter standard error alone is
optimistic when a few bright points carry the fit (a log-spaced series). Spatial variances by normal theory, the
rest propagated to first order.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from camcal.calibrate.emva import (
    DARK_VARIANCE_FLOOR_DN2,
    QUANTISATION_VAR_DN2,
    SENSITIVITY_FRACTION,
    gain_bootstrap,
    saturation_index,
)

HIGH_PASS_SIZE = 5
"""Box size of the standard's high-pass filter for the PRNU histogram, pixels."""


# ---------------------------------------------------------------------------------------------------------------
# inputs: moments of the measurement
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TemporalSeries:
    """The pair moments of a photon-transfer series, one row per bright step.

    Attributes
    ----------
    exposure_s : (n,) exposure time of each bright step, s.
    photons : (n,) mean photons per pixel μ_p of each step, or all NaN when the irradiance was not measured
        (then every "photon" axis is the exposure time and η, μ_p.min are unknown).
    mean_dn, variance_dn2 : (n,) μ_y (DN) and σ²_y (DN²) of the bright pair.
    dark_mean_dn, dark_variance_dn2 : (n,) μ_y.dark and σ²_y.dark of the dark pair at the same exposure time.
    dark_exposure_s, dark_series_mean_dn, dark_series_variance_dn2 : the dark pairs, one per exposure time
        (σ_y.dark at zero exposure and the dark current come from these).
    variance_unc_dn2, dark_variance_unc_dn2 : (n,) standard uncertainty of each σ²_y and σ²_y.dark from its own
        pixels (:func:`pair_moments`), or None when unknown.
    """

    exposure_s: np.ndarray
    photons: np.ndarray
    mean_dn: np.ndarray
    variance_dn2: np.ndarray
    dark_mean_dn: np.ndarray
    dark_variance_dn2: np.ndarray
    dark_exposure_s: np.ndarray
    dark_series_mean_dn: np.ndarray
    dark_series_variance_dn2: np.ndarray
    variance_unc_dn2: np.ndarray | None = None
    dark_variance_unc_dn2: np.ndarray | None = None

    @property
    def has_photons(self) -> bool:
        """True when μ_p is known for every step."""
        return bool(np.all(np.isfinite(self.photons)) and np.all(self.photons > 0))

    @property
    def x(self) -> np.ndarray:
        """The illumination axis: μ_p (photons per pixel) when known, else the exposure time (s)."""
        return self.photons if self.has_photons else self.exposure_s


@dataclass(frozen=True)
class SpatialStack:
    """The average ⟨y⟩ of L frames and the per-pixel temporal variance (ddof 1) of one plane (eqs. 33-34).

    Attributes
    ----------
    mean_dn : (M, N) average image, DN.
    variance_dn2 : (M, N) per-pixel temporal variance of the L frames, DN².
    n_frames : L.
    exposure_s : exposure time, s (None when unknown).
    photons : μ_p of the bright stack (NaN for a dark stack or when unknown).
    """

    mean_dn: np.ndarray
    variance_dn2: np.ndarray
    n_frames: int
    exposure_s: float | None = None
    photons: float = float("nan")


def pair_moments(first: np.ndarray, second: np.ndarray) -> tuple[float, float, float]:
    """μ_y (DN), σ²_y (DN²) and the standard uncertainty of σ²_y (DN²) of a pair.

    μ_y and σ²_y are the means' average and half the population variance of the difference (release 3.0
    eqs. 28-29; the difference cancels every fixed pattern). σ²_y is the mean of ``½(d − d̄)²`` over N pixels, so
    its uncertainty is the standard error of that mean, ``std(½(d − d̄)²)/√N``: measured on the pixels
    themselves, it holds whatever the distribution (shot noise that differs from pixel to pixel under
    vignetting, quantisation).
    """
    a = np.asarray(first, np.float64).ravel()
    b = np.asarray(second, np.float64).ravel()
    d = a - b
    q = 0.5 * (d - d.mean()) ** 2
    return float(0.5 * (a.mean() + b.mean())), float(q.mean()), float(q.std(ddof=1) / math.sqrt(q.size))


class StackAccumulator:
    """Running sums of a stack of frames, one frame at a time (memory: three float64 planes)."""

    def __init__(self) -> None:
        self.n = 0
        self._sum: np.ndarray | None = None
        self._sq: np.ndarray | None = None
        self._first: np.ndarray | None = None

    def add(self, frame: np.ndarray) -> None:
        f = np.asarray(frame, np.float64)
        if self._sum is None:
            # values relative to the first frame: the sums stay small and exact for integer data
            self._first = f.copy()
            self._sum = np.zeros_like(f)
            self._sq = np.zeros_like(f)
        elif f.shape != self._sum.shape:
            raise ValueError(f"frame of shape {f.shape} in a stack of {self._sum.shape}")
        d = f - self._first
        self._sum += d
        self._sq += d * d
        self.n += 1

    def result(self, exposure_s: float | None = None, photons: float = float("nan")) -> SpatialStack:
        """The :class:`SpatialStack` of the frames added so far (two or more)."""
        if self.n < 2:
            raise ValueError("a spatial stack needs two or more frames")
        mean_d = self._sum / self.n
        var = (self._sq - self.n * mean_d * mean_d) / (self.n - 1)
        return SpatialStack(self._first + mean_d, np.maximum(var, 0.0), self.n, exposure_s, photons)


# ---------------------------------------------------------------------------------------------------------------
# fits
# ---------------------------------------------------------------------------------------------------------------
def slope_through_origin(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares slope of y = m x and its standard error (from the residual scatter, n − 1 dof)."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    sxx = float(np.sum(x * x))
    m = float(np.sum(x * y) / sxx)
    dof = max(x.size - 1, 1)
    return m, float(math.sqrt(np.sum((y - m * x) ** 2) / dof / sxx))


def line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares (slope, intercept) of y = a x + b."""
    a, b = np.polyfit(np.asarray(x, float), np.asarray(y, float), 1)
    return float(a), float(b)


# ---------------------------------------------------------------------------------------------------------------
# spatial non-uniformity
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SpatialParts:
    """Spatial variances of an averaged stack (DN²), temporal parts removed (release 3.0 eq. 36-38, 4.0 split).

    Attributes
    ----------
    mean_dn : μ_y of the average image.
    measured_dn2 : s²_y.measured, spatial variance (ddof 1) of the average.
    stack_dn2 : σ²_y.stack, mean per-pixel temporal variance.
    total_dn2 : s²_y = s²_y.measured − σ²_y.stack / L.
    total_unc_dn2 : its standard uncertainty (normal theory).
    column_dn2, row_dn2, pixel_dn2 : the release 4.0 split of s²_y into column, row and pixel parts.
    rows, cols, n_frames : M, N, L.
    """

    mean_dn: float
    measured_dn2: float
    stack_dn2: float
    total_dn2: float
    total_unc_dn2: float
    column_dn2: float
    row_dn2: float
    pixel_dn2: float
    rows: int
    cols: int
    n_frames: int


def spatial_parts(stack: SpatialStack) -> SpatialParts:
    """The spatial variances of ``stack`` and their row, column and pixel split (see the module docstring)."""
    avg = np.asarray(stack.mean_dn, np.float64)
    m, n = avg.shape
    big_l = int(stack.n_frames)
    mu = float(avg.mean())
    measured = float(np.var(avg, ddof=1))
    sigma2 = float(np.mean(stack.variance_dn2))
    total = measured - sigma2 / big_l
    col_means = avg.mean(axis=0)  # one value per column (N of them)
    row_means = avg.mean(axis=1)  # one value per row (M of them)
    cav = float(np.mean((col_means - mu) ** 2)) - sigma2 / (big_l * m)
    rav = float(np.mean((row_means - mu) ** 2)) - sigma2 / (big_l * n)
    den = m * n - m - n
    col = (m * n - m) / den * cav - n / den * (total - rav)
    row = (m * n - n) / den * rav - m / den * (total - cav)
    pix = m * n / den * (total - cav - rav)
    npx = m * n
    unc = math.sqrt(2.0 / (npx - 1) * measured**2 + 2.0 / (npx * max(big_l - 1, 1)) * (sigma2 / big_l) ** 2)
    return SpatialParts(mu, measured, sigma2, total, unc, col, row, pix, m, n, big_l)


def _root(v: float) -> float:
    """√v, NaN for a negative variance (the standard reports no value then)."""
    return math.sqrt(v) if v >= 0 else float("nan")


def spectrogram(image_dn: np.ndarray, vertical: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The standard's spectrogram of an average image (release 3.0 §8.4, 4.0 §8.3): the power spectrum of every
    row (``vertical``: every column) about its mean, averaged over the rows; returns (frequency in cycles per
    pixel, 0…0.5, and the amplitude √power in the image's unit)."""
    a = np.asarray(image_dn, np.float64)
    if vertical:
        a = a.T
    a = a - a.mean(axis=1, keepdims=True)
    n = a.shape[1]
    power = np.mean(np.abs(np.fft.rfft(a, axis=1)) ** 2, axis=0) / n
    freq = np.fft.rfftfreq(n)
    return freq, np.sqrt(power)


def high_pass(image: np.ndarray, size: int = HIGH_PASS_SIZE) -> np.ndarray:
    """``y − R ⊛ y`` with R a ``size`` × ``size`` box (the standard's high-pass filter for the PRNU histogram),
    on the interior (the border of ``size // 2`` pixels is left out)."""
    a = np.asarray(image, np.float64)
    h = size // 2
    return (a - ndimage.uniform_filter(a, size=size, mode="nearest"))[h:-h or None, h:-h or None]


# ---------------------------------------------------------------------------------------------------------------
# the figures
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StandardFigures:
    """The EMVA 1288 figures of one channel (:func:`evaluate`) and the curves of its plots.

    ``figures`` holds numbers (or None) under the keys of :data:`camcal.models.emva.SHEET_KEYS` and more;
    ``curves`` the arrays the data sheet's plots draw.
    """

    figures: dict[str, float | None]
    curves: dict[str, np.ndarray] = field(repr=False)
    notes: tuple[str, ...] = ()


def _num(x) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def evaluate(series: TemporalSeries, bright: SpatialStack | None = None,
             dark: SpatialStack | None = None) -> StandardFigures:
    """Every EMVA 1288 figure of one channel from a photon-transfer series and (optionally) the spatial stacks.

    Raises ValueError when the series has fewer than two steps below 70 % of saturation.
    """
    notes: list[str] = []
    order = np.lexsort((series.x, series.exposure_s))
    t = np.asarray(series.exposure_s, float)[order]
    x = np.asarray(series.x, float)[order]
    mu = np.asarray(series.mean_dn, float)[order]
    var = np.asarray(series.variance_dn2, float)[order]
    mu_d = np.asarray(series.dark_mean_dn, float)[order]
    var_d = np.asarray(series.dark_variance_dn2, float)[order]
    if t.size < 2:
        raise ValueError("photon transfer needs two or more bright steps")
    signal = mu - mu_d
    photo_var = var - var_d
    isat = saturation_index(var)
    below = np.flatnonzero(signal <= SENSITIVITY_FRACTION * signal[isat])
    if below.size == 0 or below.max() < 1:
        raise ValueError("fewer than two steps below 70 % of the saturation signal")
    fit = slice(0, int(below.max()) + 1)
    k, k_se = slope_through_origin(signal[fit], photo_var[fit])
    k_boot = gain_bootstrap(signal[fit], photo_var[fit])
    k_prop = None
    if series.variance_unc_dn2 is not None and series.dark_variance_unc_dn2 is not None:
        u_pt = np.hypot(np.asarray(series.variance_unc_dn2, float)[order],
                        np.asarray(series.dark_variance_unc_dn2, float)[order])[fit]
        xs_ = signal[fit]
        k_prop = float(math.sqrt(np.sum(xs_**2 * u_pt**2)) / np.sum(xs_**2))
    k_unc = max(k_boot, k_prop or 0.0)
    r, r_se = slope_through_origin(x[fit], signal[fit])
    photons = series.has_photons
    f: dict[str, float | None] = {
        "K_dn_per_e": k, "K_unc_dn_per_e": k_unc, "K_unc_ls_dn_per_e": k_se, "K_unc_bootstrap_dn_per_e": k_boot,
        "K_unc_propagated_dn_per_e": k_prop, "inverse_K_e_per_dn": 1.0 / k,
        "ptc_points": float(t.size), "ptc_fit_points": float(fit.stop),
        "ptc_fit_max_dn": float(signal[fit.stop - 1]), "saturation_index": float(isat),
    }
    # temporal dark noise at zero exposure
    td = np.asarray(series.dark_exposure_s, float)
    vd = np.asarray(series.dark_series_variance_dn2, float)
    md = np.asarray(series.dark_series_mean_dn, float)
    if np.unique(td).size > 2:
        _, v0 = line(td, vd)
    else:
        v0 = float(vd[np.argmin(td)])
    if v0 < DARK_VARIANCE_FLOOR_DN2:
        notes.append(f"σ²_y.dark {v0:.3g} DN² below the standard's floor {DARK_VARIANCE_FLOOR_DN2} DN²: floor used")
        v0 = DARK_VARIANCE_FLOOR_DN2
    sig_yd = math.sqrt(v0)
    read_dn = _root(v0 - QUANTISATION_VAR_DN2)
    f.update({"dark_noise_dn": sig_yd, "read_noise_dn": read_dn, "read_noise_e": read_dn / k,
              "read_noise_unc_e": read_dn / k * k_unc / k})
    # saturation, sensitivity, SNR, dynamic range
    x_sat = float(x[isat])
    sat_dn = r * x_sat
    sat_e = sat_dn / k
    rel_sat = math.hypot(k_unc / k, r_se / r)
    f.update({"saturation_dn": sat_dn, "saturation_e": sat_e, "saturation_unc_e": sat_e * rel_sat,
              "saturation_exposure_s": float(t[isat]), "saturation_mean_dn": float(mu[isat]),
              "snr_max": math.sqrt(sat_e), "snr_max_unc": 0.5 * math.sqrt(sat_e) * rel_sat,
              "snr_max_db": 20 * math.log10(math.sqrt(sat_e)), "snr_max_bits": math.log2(math.sqrt(sat_e)),
              "threshold_e": sig_yd / k + 0.5})
    f["dynamic_range"] = sat_e / f["threshold_e"]
    f["dynamic_range_db"] = 20 * math.log10(f["dynamic_range"])
    if photons:
        eta = r / k
        f.update({"responsivity_dn_per_photon": r, "quantum_efficiency_pct": 100 * eta,
                  "quantum_efficiency_unc_pct": 100 * eta * math.hypot(k_unc / k, r_se / r),
                  "saturation_photons": x_sat, "threshold_photons": f["threshold_e"] / eta})
    else:
        f.update({"responsivity_dn_per_s": r, "quantum_efficiency_pct": None})
        notes.append("no photon counts: η, μ_p.min and μ_p.sat unknown; the illumination axis is exposure time")
    # linearity
    lo = np.flatnonzero(signal >= 0.05 * signal[isat])
    hi = np.flatnonzero((signal <= 0.95 * signal[isat]) & (np.arange(signal.size) <= isat))
    dev = np.full_like(signal, np.nan)
    if lo.size and hi.size and hi.max() - lo.min() >= 2:
        sel = slice(int(lo.min()), int(hi.max()) + 1)
        xs, ys = x[sel], signal[sel]
        design = np.stack([xs / ys, 1.0 / ys], axis=1)
        (a, b), *_ = np.linalg.lstsq(design, np.ones_like(ys), rcond=None)
        dev = 100.0 * (signal - (a * x + b)) / (a * x + b)
        dmin, dmax = float(np.min(dev[sel])), float(np.max(dev[sel]))
        f.update({"linearity_error_min_pct": dmin, "linearity_error_max_pct": dmax,
                  "linearity_error_pct": (dmax - dmin) / 2.0})
    else:
        notes.append("fewer than three steps between 5 % and 95 % of saturation: linearity error unknown")
    # dark current
    if np.unique(td).size > 2:
        slope_mu, _ = line(td, md)
        slope_var, _ = line(td, vd)
        f.update({"dark_current_dn_per_s": slope_mu, "dark_current_e_per_s": slope_mu / k,
                  "dark_current_from_variance_e_per_s": slope_var / k**2})
    else:
        notes.append("dark pairs at fewer than three exposure times: dark current unknown")
    curves: dict[str, np.ndarray] = {
        "exposure_s": t, "x": x, "signal_dn": signal, "variance_dn2": photo_var, "mean_dn": mu,
        "total_variance_dn2": var, "linearity_deviation_pct": dev,
        "fit_mask": np.arange(t.size) < fit.stop, "dark_exposure_s": td, "dark_mean_dn": md, "dark_variance_dn2": vd,
    }
    # spatial
    if dark is not None:
        dp = spatial_parts(dark)
        dsnu_dn = _root(dp.total_dn2)
        f.update({
            "dsnu_dn": dsnu_dn, "dsnu_e": dsnu_dn / k,
            "dsnu_unc_dn": dp.total_unc_dn2 / (2 * dsnu_dn) if dsnu_dn > 0 else None,
            "dsnu_row_e": _root(dp.row_dn2) / k, "dsnu_col_e": _root(dp.column_dn2) / k,
            "dsnu_pixel_e": _root(dp.pixel_dn2) / k, "dsnu_frames": float(dp.n_frames),
            "dsnu_temporal_floor_dn": math.sqrt(dp.stack_dn2 / dp.n_frames), "dark_spatial_mean_dn": dp.mean_dn,
        })
        curves["dsnu_spectrogram_h"] = spectrogram(dark.mean_dn)
        curves["dsnu_spectrogram_v"] = spectrogram(dark.mean_dn, vertical=True)
        curves["dsnu_image_dn"] = np.asarray(dark.mean_dn, float) - dp.mean_dn
    if bright is not None and dark is not None:
        bp = spatial_parts(bright)
        dp = spatial_parts(dark)
        net = bp.mean_dn - dp.mean_dn
        s2 = bp.total_dn2 - dp.total_dn2
        value = _root(s2) / net
        unc_s2 = math.hypot(bp.total_unc_dn2, dp.total_unc_dn2)
        f.update({
            "prnu_pct": 100 * value, "prnu_unc_pct": 100 * unc_s2 / (2 * value * net**2) if value > 0 else None,
            "prnu_row_pct": 100 * _root(bp.row_dn2 - dp.row_dn2) / net,
            "prnu_col_pct": 100 * _root(bp.column_dn2 - dp.column_dn2) / net,
            "prnu_pixel_pct": 100 * _root(bp.pixel_dn2 - dp.pixel_dn2) / net,
            "prnu_frames": float(bp.n_frames), "prnu_mean_dn": net,
            "prnu_temporal_floor_pct": 100 * math.sqrt(bp.stack_dn2 / bp.n_frames) / net,
        })
        img = (np.asarray(bright.mean_dn, float) - np.asarray(dark.mean_dn, float)) / net * 100.0
        curves["prnu_spectrogram_h"] = spectrogram(img)
        curves["prnu_spectrogram_v"] = spectrogram(img, vertical=True)
        curves["prnu_highpass_pct"] = high_pass(img)
    elif bright is not None:
        notes.append("a bright spatial stack without a dark one: PRNU₁₂₈₈ unknown")
    return StandardFigures({key: _num(v) for key, v in f.items()}, curves, tuple(notes))


def prnu_1288_planes(mean: np.ndarray, variance: np.ndarray, n_frames: int, channels: Sequence[str],
                     mask: np.ndarray | None = None) -> dict[str, dict[str, float | None]]:
    """PRNU₁₂₈₈ per plane of an averaged, per-pixel dark-subtracted flat: the total non-uniformity and its release
    4.0 row, column and pixel parts, in % (keys ``prnu_pct``, ``prnu_unc_pct``, ``prnu_row_pct``,
    ``prnu_col_pct``, ``prnu_pixel_pct``).

    ``mean`` (C, h, w) is the plain average of the L flats (any scale: PRNU is relative), ``variance`` the per-pixel
    temporal variance (ddof 1) in the same units squared. The flats are dark-subtracted pixel by pixel, so the
    standard's ``− s²_y.dark`` is already done. Nothing smooth is divided out: vignetting and lamp falloff are part
    of PRNU₁₂₈₈ (camcal's vignetting-free PRNU is :func:`camcal.calibrate.flat.flat_prnu`). Pixels of ``mask`` (known
    defects) and non-finite ones are replaced by the plane mean of the others, so the row and column means keep
    their grid. ``mask`` is any (C, h, w) array, non-zero at a defect (a dark model's flags); another shape is
    ignored.
    """
    out: dict[str, dict[str, float | None]] = {}
    if mask is not None:
        mask = np.asarray(mask) != 0
        if mask.shape != np.shape(mean):
            mask = None
    for i, c in enumerate(channels):
        m = np.asarray(mean[i], np.float64)
        v = np.asarray(variance[i], np.float64)
        good = np.isfinite(m) & np.isfinite(v)
        if mask is not None:
            good &= ~mask[i]
        if good.sum() < 4:
            out[c] = {k: None for k in ("prnu_pct", "prnu_unc_pct", "prnu_row_pct", "prnu_col_pct", "prnu_pixel_pct")}
            continue
        m = np.where(good, m, float(np.mean(m[good])))
        v = np.where(good, v, float(np.mean(v[good])))
        p = spatial_parts(SpatialStack(m, v, int(n_frames)))
        value = _root(p.total_dn2) / p.mean_dn
        out[c] = {
            "prnu_pct": _num(100 * value),
            "prnu_unc_pct": _num(100 * p.total_unc_dn2 / (2 * value * p.mean_dn**2)) if value > 0 else None,
            "prnu_row_pct": _num(100 * _root(p.row_dn2) / p.mean_dn),
            "prnu_col_pct": _num(100 * _root(p.column_dn2) / p.mean_dn),
            "prnu_pixel_pct": _num(100 * _root(p.pixel_dn2) / p.mean_dn),
        }
    return out

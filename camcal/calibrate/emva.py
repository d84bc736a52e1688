"""EMVA 1288 figures of a camera: pure functions, arrays in, dataclasses out.

Definitions follow EMVA Standard 1288, release 4.0 (2021), "Linear" module, and its reference implementation
(the ``emva1288`` Python package, whose labels give the equation numbers cited below):

- **Linear camera model** (§2): ``μ_y = μ_y.dark + K·μ_e``, ``σ²_y = K²σ²_d + σ²_q + K(μ_y − μ_y.dark)``
  with K the overall system gain in DN/e⁻ and σ²_q = 1/12 DN² the quantisation noise (eq. 4 of the linear
  model); camcal's noise model (:mod:`camcal.models.correct`) is this equation.
- **Photon transfer** (§"Sensitivity, linearity and noise", the photon transfer method): the temporal variance
  of a pair of frames at one setting is half the variance of their difference (``σ²_y = ½ var(y_A − y_B)``, the
  difference cancels every fixed pattern), its mean the mean of the pair; K is the slope of
  ``σ²_y − σ²_y.dark`` against ``μ_y − μ_y.dark`` fitted from the darkest point up to 70 % of the saturation
  signal (:func:`photon_transfer`).
- **Saturation** (§ same): the saturation point is the one of maximum temporal variance (:func:`saturation_index`,
  the reference implementation's search); the saturation capacity is the responsivity line at that exposure,
  ``μ_y.sat = R·x_sat`` (DN) and ``μ_e.sat = μ_y.sat / K`` (e⁻).
- **SNR_max = √μ_e.sat**, **absolute sensitivity threshold** ``μ_e.min = σ_y.dark/K + ½`` (e⁻; in photons divided
  by the quantum efficiency), **dynamic range** ``DR = μ_e.sat / μ_e.min`` (in dB: 20·log₁₀ DR).
- **Linearity error** (§ "Linearity"): a line fitted minimising the *relative* deviations between 5 % and 95 % of
  the saturation signal, ``δ = 100 (μ − (a x + b)) / (a x + b)`` %, ``LE = (max δ − min δ)/2``
  (:func:`linearity_error`).
- **Spatial nonuniformity** (§ "Spatial nonuniformity"): from the average ⟨y⟩ of L frames (eq. 38), the spatial
  variance ``s²_y = s²_y.measured − σ²_y.stack / L`` (eq. 36), σ²_y.stack the mean per-pixel temporal variance of
  the stack: the temporal noise left in the average is *not* nonuniformity. ``DSNU = s_y.dark`` (DN; /K in e⁻),
  ``PRNU = √(s²_y − s²_y.dark) / (μ_y − μ_y.dark)`` (:func:`spatial_variance`, :func:`prnu`).
- **Quantum efficiency**: η = R/K with R the responsivity in DN per photon (:func:`quantum_efficiency`).

Uncertainties are one standard deviation: K's from the scatter of the photon-transfer points (the larger of the
least-squares standard error and a bootstrap of the points, :func:`gain_bootstrap`), and for a spatial variance of
N pixels the normal-theory ``var(s²) = 2 s⁴ / (N − 1)`` plus the uncertainty of the subtracted temporal term.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from camcal.models.emva import SHEET_KEYS, EmvaSheet
from camcal.models.spectra import photon_energy_j

QUANTISATION_VAR_DN2 = 1.0 / 12.0
"""σ²_q of integer data, DN² (EMVA 1288 linear model, eq. 4)."""

DARK_VARIANCE_FLOOR_DN2 = 0.24
"""Lowest σ²_y.dark the standard reports, DN² (below it the temporal dark noise is quantisation)."""

SENSITIVITY_FRACTION = 0.7
"""K and the responsivity are fitted from the darkest point up to this fraction of the saturation signal."""

LINEARITY_RANGE = (0.05, 0.95)
"""The linearity error is computed between these fractions of the saturation signal."""

BOOTSTRAP_SAMPLES = 400
"""Resamples of the photon-transfer points for u(K) (:func:`gain_bootstrap`)."""



# ---------------------------------------------------------------------------------------------------------------
# temporal: frame pairs, photon transfer, saturation
# ---------------------------------------------------------------------------------------------------------------
def pair_statistics(first: np.ndarray, second: np.ndarray, valid: np.ndarray | None = None) -> tuple[float, float]:
    """Mean (DN) and temporal variance (DN²) of a pair of frames of one plane at one setting.

    ``σ²_y = ½ · var(y_A − y_B)`` over the valid pixels (population variance, as the reference implementation:
    its mean-difference term removes a level change between the two frames); the mean is that of both frames.
    """
    a = np.asarray(first, np.float64)
    b = np.asarray(second, np.float64)
    if valid is not None:
        a, b = a[valid], b[valid]
    a, b = a.ravel(), b.ravel()
    if a.size < 2:
        return float("nan"), float("nan")
    return float(0.5 * (a.mean() + b.mean())), float(0.5 * np.var(a - b))


def saturation_index(variance_dn2: np.ndarray) -> int:
    """Index of the saturation point: the maximum of the temporal variance (points sorted by exposure).

    Searched from the brightest point down, as the reference implementation does, so that a single noise spike
    below the true maximum does not stop the search: the search ends at the first point where both it and its
    darker neighbour fall below the maximum found so far.
    """
    v = np.asarray(variance_dn2, float)
    best, best_i = -np.inf, 0
    for i in range(len(v) - 1, -1, -1):
        if not np.isfinite(v[i]):
            continue
        prev = v[abs(i - 1)]
        if v[i] >= best or prev >= best:
            best, best_i = v[i], i
        elif v[i] < best and prev < best:
            break
    return int(best_i)


def gain_bootstrap(signal_dn: np.ndarray, variance_dn2: np.ndarray, samples: int = BOOTSTRAP_SAMPLES,
                   seed: int = 1288) -> float:
    """Standard deviation of the photon-transfer slope K over resamples of the points (pairs bootstrap).

    Resampling the (μ, σ²) points, not the residuals, keeps the variance noise that grows with the signal
    (var(σ²_y) ≈ 2σ⁴/N per pair): the scatter of the slope is then that of the points actually measured. The
    result is never below the least-squares standard error. Fixed seed: the same points give the same u(K).
    """
    x = np.asarray(signal_dn, float)
    y = np.asarray(variance_dn2, float)
    n = x.size
    sxx0 = float(np.sum(x * x))
    k0 = float(np.sum(x * y) / sxx0)
    se = float(math.sqrt(np.sum((y - k0 * x) ** 2) / max(n - 1, 1) / sxx0))
    if n < 3:
        return se
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n, size=(samples, n))
    xs, ys = x[idx], y[idx]
    sxx = np.sum(xs * xs, axis=1)
    ok = sxx > 0
    k = np.sum(xs * ys, axis=1)[ok] / sxx[ok]
    return float(max(np.std(k, ddof=1), se))


@dataclass(frozen=True)
class PhotonTransfer:
    """Photon-transfer result of one channel at one ISO.

    Attributes
    ----------
    gain_dn_per_e, gain_unc_dn_per_e : system gain K and its standard error, DN/e⁻.
    dark_variance_dn2 : σ²_y.dark at zero exposure used (or fitted as the intercept), DN² (quantisation included).
    intercept_fitted : True when σ²_y.dark was the free intercept of the fit (no dark model at this ISO).
    fit_range_dn : (lowest, highest) signal of the points fitted, DN above dark.
    n_fit : number of points fitted.
    saturation_index : index (in the sorted points) of the variance maximum.
    saturation_dn : μ_y.sat − μ_y.dark, the responsivity line at the saturation exposure, DN.
    saturation_exposure_s : the exposure x of the saturation point, s (at the series' reference setting).
    responsivity_dn_per_s : slope R of the signal against x in the fit range, DN s⁻¹.
    exposure_s, signal_dn, variance_dn2 : the points, sorted by exposure (signal above the zero-exposure level).
    photo_signal_dn : the points' signal above dark (μ_y − μ_y.dark), DN.
    """

    gain_dn_per_e: float
    gain_unc_dn_per_e: float
    dark_variance_dn2: float
    intercept_fitted: bool
    fit_range_dn: tuple[float, float]
    n_fit: int
    saturation_index: int
    saturation_dn: float
    saturation_exposure_s: float
    responsivity_dn_per_s: float
    exposure_s: np.ndarray = field(repr=False)
    signal_dn: np.ndarray = field(repr=False)
    variance_dn2: np.ndarray = field(repr=False)
    photo_signal_dn: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))

    @property
    def saturation_e(self) -> float:
        """Saturation capacity μ_e.sat = μ_y.sat / K, electrons."""
        return self.saturation_dn / self.gain_dn_per_e if self.gain_dn_per_e > 0 else float("nan")


def photon_transfer(exposure_s: np.ndarray, signal_dn: np.ndarray, variance_dn2: np.ndarray,
                    dark_variance_dn2: float | None = None,
                    dark_signal_dn: np.ndarray | None = None) -> PhotonTransfer:
    """System gain K by the photon transfer method (EMVA 1288 release 4.0), one channel at one ISO.

    Parameters
    ----------
    exposure_s : (n,) exposure of each point (time at a constant source, or any quantity proportional to the
        photon count), s.
    signal_dn : (n,) mean signal above the dark level at zero exposure, DN (dark signal included: dark electrons
        are Poisson like photo-electrons, so ``σ²_y = σ²_y.dark(0) + K·signal`` holds over the whole series).
    variance_dn2 : (n,) temporal variance of each pair, DN².
    dark_variance_dn2 : σ²_y.dark at zero exposure (read noise² + 1/12, DN²) from the dark frames; with it K is the
        slope through that point, as the standard fits ``σ²_y − σ²_y.dark = K(μ_y − μ_y.dark)`` through the origin;
        without, the intercept is fitted too (``scipy.stats.linregress``).
    dark_signal_dn : (n,) dark signal at each point (β·t, DN), subtracted for the responsivity, the saturation
        signal μ_y.sat − μ_y.dark and the 70 % fit limit (the standard's μ_y − μ_y.dark); None: 0.

    Fit range: from the darkest point up to :data:`SENSITIVITY_FRACTION` of the saturation signal (the variance
    maximum, :func:`saturation_index`). Raises ValueError when fewer than two points remain.
    """
    x = np.asarray(exposure_s, float)
    y = np.asarray(signal_dn, float)
    v = np.asarray(variance_dn2, float)
    d = np.zeros_like(y) if dark_signal_dn is None else np.asarray(dark_signal_dn, float)
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(v) & np.isfinite(d)
    order = np.argsort(x[ok], kind="stable")
    x, y, v, d = x[ok][order], y[ok][order], v[ok][order], d[ok][order]
    if x.size < 2:
        raise ValueError("photon transfer needs two or more frame pairs")
    isat = saturation_index(v)
    photo = y - d
    sel = (photo <= SENSITIVITY_FRACTION * photo[isat]) & (np.arange(y.size) <= isat)
    if sel.sum() < 2:
        sel = np.arange(y.size) <= max(isat, 1)
    xs, ys, vs = x[sel], y[sel], v[sel]
    if sel.sum() < 2:
        raise ValueError("photon transfer needs two or more frame pairs below saturation")
    if dark_variance_dn2 is not None and np.isfinite(dark_variance_dn2):
        dv = vs - dark_variance_dn2
        k = float(np.sum(ys * dv) / np.sum(ys * ys))
        dof = max(xs.size - 1, 1)
        k_unc = float(np.sqrt(np.sum((dv - k * ys) ** 2) / dof / np.sum(ys * ys)))
        k_unc = max(k_unc, gain_bootstrap(ys, dv))  # the residual scatter alone is optimistic on few points
        v0, fitted = float(dark_variance_dn2), False
    else:
        if sel.sum() < 3:
            raise ValueError("photon transfer without a dark variance needs three or more frame pairs")
        k, v0, k_unc = _line(ys, vs)
        fitted = True
    # responsivity: the photo signal against exposure through the origin
    ps = photo[sel]
    r = float(np.sum(xs * ps) / np.sum(xs * xs))
    return PhotonTransfer(
        gain_dn_per_e=k, gain_unc_dn_per_e=k_unc, dark_variance_dn2=v0, intercept_fitted=fitted,
        fit_range_dn=(float(ys.min()), float(ys.max())), n_fit=int(sel.sum()), saturation_index=isat,
        saturation_dn=r * float(x[isat]), saturation_exposure_s=float(x[isat]), responsivity_dn_per_s=r,
        exposure_s=x, signal_dn=y, variance_dn2=v, photo_signal_dn=photo,
    )


def _line(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Unweighted straight line y = a·x + b (``scipy.stats.linregress``): a, b and the standard error of a
    (residuals over n − 2 degrees of freedom; NaN with two points)."""
    if x.size >= 3:
        lr = stats.linregress(x, y)
        return float(lr.slope), float(lr.intercept), float(lr.stderr)
    a = (y[-1] - y[0]) / (x[-1] - x[0])
    return float(a), float(y[0] - a * x[0]), float("nan")


@dataclass(frozen=True)
class DarkTemporal:
    """Temporal dark noise against exposure time (EMVA 1288 §"dark current", from the variance).

    Attributes
    ----------
    dark_variance_dn2 : σ²_y.dark extrapolated to zero exposure, DN² (quantisation included).
    slope_dn2_per_s : growth of the dark variance with time, DN²/s (= K² × dark current in e⁻/s).
    read_noise_dn : √(σ²_y.dark − 1/12), DN.
    """

    dark_variance_dn2: float
    slope_dn2_per_s: float
    read_noise_dn: float


def dark_temporal(exposure_s: np.ndarray, variance_dn2: np.ndarray) -> DarkTemporal:
    """σ²_y.dark at zero exposure: a line of the dark temporal variance against exposure time, its intercept
    (one exposure time: its variance), as the reference implementation fits it (unweighted)."""
    t = np.asarray(exposure_s, float)
    v = np.asarray(variance_dn2, float)
    if np.unique(t).size >= 3:
        slope, v0, _ = _line(t, v)
    else:
        i = int(np.argmin(t))
        v0, slope = float(v[i]), float("nan")
    return DarkTemporal(v0, slope, math.sqrt(max(v0 - QUANTISATION_VAR_DN2, 0.0)))


# ---------------------------------------------------------------------------------------------------------------
# spatial nonuniformity
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SpatialVariance:
    """Spatial variance of the average of L frames (EMVA 1288 release 4.0, eqs. 36 and 38).

    Attributes
    ----------
    mean_dn : mean of the average image, DN.
    measured_dn2 : s²_y.measured, the spatial variance (ddof = 1) of the average image, DN².
    stack_dn2 : σ²_y.stack, the mean per-pixel temporal variance of the frames, DN².
    n_frames : L.
    n_pixels : pixels used.
    variance_dn2 : s²_y = s²_y.measured − σ²_y.stack / L (may be negative by noise), DN².
    variance_unc_dn2 : standard uncertainty of ``variance_dn2``, DN².
    """

    mean_dn: float
    measured_dn2: float
    stack_dn2: float
    n_frames: int
    n_pixels: int
    variance_dn2: float
    variance_unc_dn2: float

    @property
    def temporal_floor_dn2(self) -> float:
        """σ²_y.stack / L: the temporal variance left in the average image, DN²."""
        return self.stack_dn2 / self.n_frames


def spatial_variance(average_dn: np.ndarray, temporal_variance_dn2: np.ndarray, n_frames: int,
                     valid: np.ndarray | None = None) -> SpatialVariance:
    """s²_y of one plane from the average of ``n_frames`` frames and the per-pixel temporal variance (ddof = 1).

    ``valid`` (bool, same shape) selects the pixels (defects out). The uncertainty is the normal-theory standard
    error of a sample variance, ``√(2/(N−1))·s²_measured``, combined with that of the subtracted temporal term
    (each per-pixel variance has L − 1 degrees of freedom: ``√(2/(N(L−1)))·σ²_stack/L``).
    """
    avg = np.asarray(average_dn)
    var = np.asarray(temporal_variance_dn2)
    good = np.isfinite(avg) & np.isfinite(var)
    if valid is not None:
        good &= np.asarray(valid, bool)
    # the selected pixels converted to float64 (not the whole planes first: the same values, in the same order)
    a, s = np.asarray(avg[good], np.float64), np.asarray(var[good], np.float64)
    n = int(a.size)
    if n < 2 or n_frames < 2:
        nan = float("nan")
        return SpatialVariance(float(np.mean(a)) if n else nan, nan, nan, int(n_frames), n, nan, nan)
    measured = float(np.var(a, ddof=1))
    stack = float(np.mean(s))
    floor = stack / n_frames
    unc = math.sqrt(2.0 / (n - 1) * measured**2 + 2.0 / (n * (n_frames - 1)) * floor**2)
    return SpatialVariance(float(np.mean(a)), measured, stack, int(n_frames), n, measured - floor, unc)


@dataclass(frozen=True)
class Nonuniformity:
    """A nonuniformity figure and its standard uncertainty (DSNU in DN, PRNU relative)."""

    value: float
    uncertainty: float
    spatial: SpatialVariance


def dsnu(dark: SpatialVariance) -> Nonuniformity:
    """DSNU_1288 = s_y.dark, DN (0 when the temporal noise explains all the spatial variance)."""
    s2 = max(dark.variance_dn2, 0.0)
    value = math.sqrt(s2)
    unc = dark.variance_unc_dn2 / (2 * value) if value > 0 else math.sqrt(max(dark.variance_unc_dn2, 0.0))
    return Nonuniformity(value, unc, dark)


def prnu(bright: SpatialVariance, dark_spatial_dn2: float = 0.0, dark_mean_dn: float = 0.0) -> Nonuniformity:
    """PRNU_1288 = √(s²_y − s²_y.dark) / (μ_y − μ_y.dark), relative (not percent).

    ``dark_spatial_dn2``/``dark_mean_dn`` are s²_y.dark and μ_y.dark of the dark average at the same exposure;
    camcal's flats are already dark-subtracted per pixel (and divided by the smooth vignetting model), so it
    passes the variance of the subtracted dark estimate instead (0 when negligible) and a mean of 0.
    """
    mu = bright.mean_dn - dark_mean_dn
    s2 = bright.variance_dn2 - dark_spatial_dn2
    value = math.sqrt(max(s2, 0.0)) / mu
    unc_s2 = bright.variance_unc_dn2 / mu**2
    unc = unc_s2 / (2 * value) if value > 0 else math.sqrt(max(unc_s2, 0.0))
    return Nonuniformity(value, unc, bright)


def flats_needed(per_frame_variance_rel: float, prnu_rel: float) -> int | None:
    """Number of flats whose average carries less temporal noise than the PRNU: the smallest L with
    ``σ²_frame / L < PRNU²`` (relative units); None when the PRNU is 0 (no number of flats gets below it)."""
    if not (prnu_rel > 0) or not np.isfinite(per_frame_variance_rel):
        return None
    return int(math.floor(per_frame_variance_rel / prnu_rel**2)) + 1


# ---------------------------------------------------------------------------------------------------------------
# linearity and datasheet figures
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Linearity:
    """EMVA 1288 linearity: LE = (max δ − min δ)/2 in percent, with the extremes and the fit."""

    error_pct: float
    min_pct: float
    max_pct: float
    slope: float
    offset: float
    n_points: int


def linearity_error(x: np.ndarray, signal_dn: np.ndarray, saturation_signal_dn: float) -> Linearity:
    """EMVA 1288 linearity error of the signal above dark against the exposure x.

    A line ``μ = a·x + b`` minimising the relative deviations (weights 1/μ²) over the points between 5 % and 95 %
    of ``saturation_signal_dn``; ``δ_i = 100 (μ_i − (a x_i + b)) / (a x_i + b)``; LE = (max δ − min δ)/2.
    When fewer than three points lie in that range all positive points are used.
    """
    x = np.asarray(x, float)
    y = np.asarray(signal_dn, float)
    lo, hi = LINEARITY_RANGE
    sel = (y >= lo * saturation_signal_dn) & (y <= hi * saturation_signal_dn)
    if sel.sum() < 3:
        sel = y > 0
    if sel.sum() < 2:
        nan = float("nan")
        return Linearity(nan, nan, nan, nan, nan, int(sel.sum()))
    xs, ys = x[sel], y[sel]
    design = np.stack([xs / ys, 1.0 / ys], axis=1)
    (a, b), *_ = np.linalg.lstsq(design, np.ones_like(ys), rcond=None)
    fit = a * xs + b
    dev = 100.0 * (ys - fit) / fit
    return Linearity(float((dev.max() - dev.min()) / 2.0), float(dev.min()), float(dev.max()), float(a), float(b),
                     int(sel.sum()))


@dataclass(frozen=True)
class Datasheet:
    """The datasheet figures of one channel (EMVA 1288 release 4.0 summary sheet)."""

    gain_dn_per_e: float
    saturation_dn: float
    saturation_e: float
    threshold_e: float
    snr_max: float
    dynamic_range: float

    @property
    def snr_max_db(self) -> float:
        return 20.0 * math.log10(self.snr_max) if self.snr_max > 0 else float("nan")

    @property
    def dynamic_range_db(self) -> float:
        return 20.0 * math.log10(self.dynamic_range) if self.dynamic_range > 0 else float("nan")


def datasheet(gain_dn_per_e: float, saturation_dn: float, dark_noise_dn: float) -> Datasheet:
    """Saturation capacity, SNR_max, absolute sensitivity threshold and dynamic range.

    ``dark_noise_dn`` is σ_y.dark (temporal dark noise with the quantisation, DN). μ_e.sat = μ_y.sat/K,
    SNR_max = √μ_e.sat, μ_e.min = σ_y.dark/K + ½, DR = μ_e.sat/μ_e.min.
    """
    k = float(gain_dn_per_e)
    sat_e = saturation_dn / k
    thr = dark_noise_dn / k + 0.5
    return Datasheet(k, float(saturation_dn), float(sat_e), float(thr), math.sqrt(max(sat_e, 0.0)), sat_e / thr)


def quantum_efficiency(wavelength_nm: np.ndarray, sensitivity: np.ndarray, gain_dn_per_e: float,
                       pixel_pitch_um: float, f_number: float) -> np.ndarray:
    """η(λ) = R(λ)/K from camcal's absolute spectral sensitivity c(λ).

    ``sensitivity`` is c(λ) in DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm at f-number ``f_number`` on axis: the DN rate
    of a radiance L (W m⁻² sr⁻¹) of a line at λ is ``c·L``. The photon rate on a pixel of area A = p² from that
    radiance through an f/N lens is ``L·π A /(4 N²) / (hc/λ)`` (image-plane irradiance of an aberration-free lens
    on axis, EMVA 1288's μ_p = A E t /(hν) with E = π L / (4N²)), so η = c · 4N² (hc/λ) / (π A K).
    """
    area_m2 = (float(pixel_pitch_um) * 1e-6) ** 2
    photons_per_w = 1.0 / photon_energy_j(wavelength_nm)
    dn_per_photon = np.asarray(sensitivity, float) * 4.0 * f_number**2 / (math.pi * area_m2 * photons_per_w)
    return dn_per_photon / gain_dn_per_e


# ---------------------------------------------------------------------------------------------------------------
# the summary sheet of a calibration
# ---------------------------------------------------------------------------------------------------------------


def _num(x: float | None) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def _dark_groups(darks: tuple, bias) -> list[tuple[float, object]]:
    """The ``(exposure_s, stack)`` groups of two frames or more: the dark stage's ``(t, StackResult)`` groups
    ``darks`` in their order, then its bias stack ``bias`` (or None) at its frames' median exposure time (0 s where
    unknown)."""
    groups = list(darks)
    if bias is not None:
        tb = float(np.median([e.exposure_s or 0.0 for e in bias.exposures]))
        groups.append((tb, bias))
    return [(t, s) for t, s in groups if s.n_frames >= 2]


def dark_spatial_stack(darks: tuple, bias) -> tuple[float, object] | None:
    """The (exposure_s, stack) of the dark stack with the most frames (ties: the shortest exposure): the dark
    average of the spatial figures. ``darks`` are the dark stage's ``(t, StackResult)`` groups, ``bias`` its
    bias stack or None."""
    groups = _dark_groups(darks, bias)
    if not groups:
        return None
    return max(groups, key=lambda g: (g[1].n_frames, -g[0]))


@dataclass(frozen=True)
class DarkNoiseStacks:
    """What :func:`build_sheet` reads of the dark stage's combined frames, and nothing more (:func:`dark_noise_stacks`).

    A calibration keeps this, not the stacks, until the sheet is built after the other stages: at 24 MP the
    stacks' combined values, counts and other means are about 0.8 GB that the flat, linearity and sweep stages
    would otherwise run beside.

    Attributes
    ----------
    groups : ``(exposure_s, n_frames, variance)`` of every group of two frames or more (the dark groups in their
        order, then the bias frames at their median exposure time): ``variance`` (C, h, w), DN², the temporal
        variance (ddof=1) of all of a pixel's values, as stacked (float32).
    spatial : ``(exposure_s, n_frames, mean, variance)`` of the stack the DSNU comes from
        (:func:`dark_spatial_stack`), ``mean`` (C, h, w) in DN, or None without a group of two frames.
    """

    groups: tuple[tuple[float, int, np.ndarray], ...]
    spatial: tuple[float, int, np.ndarray, np.ndarray] | None


def dark_noise_stacks(darks: tuple, bias) -> DarkNoiseStacks:
    """The :class:`DarkNoiseStacks` of the dark stage's ``(t, StackResult)`` groups ``darks`` and its bias stack
    ``bias`` (or None): the arrays are the stacks' own, not copies."""
    def variance(st) -> np.ndarray:
        return st.variance_all if st.variance_all is not None else st.variance

    chosen = dark_spatial_stack(darks, bias)
    spatial = None
    if chosen is not None:
        t_sp, st = chosen
        spatial = (float(t_sp), int(st.n_frames), st.mean_all if st.mean_all is not None else st.mean, variance(st))
    return DarkNoiseStacks(tuple((float(t), int(st.n_frames), variance(st)) for t, st in _dark_groups(darks, bias)),
                           spatial)


def build_sheet(*, channels: tuple[str, ...], iso: float, dark_noise: DarkNoiseStacks | None = None, dark=None,
                prnu_frames: int | None = None, flat_prnu: dict[str, Nonuniformity] | None = None, pairs=None,
                spectral=None, pixel_pitch_um: float | None = None,
                prnu_1288: dict[str, dict] | None = None) -> EmvaSheet:
    """The EMVA 1288 sheet from what the stages measured (every input optional; no file is read).

    Parameters
    ----------
    channels : plane names.
    iso : ISO of the dark model (the figures' ISO).
    dark_noise : what the sheet reads of the dark stage's combined frames (:func:`dark_noise_stacks`): temporal
        dark noise against t (σ²_y.dark at zero exposure) and the DSNU of the largest stack (eq. 36).
    dark : the dark model: bias level (the zero-exposure level of the pairs), dark current β, defects, and its
        quantised-noise read noise below 1 DN and its dark-current gain (the fallback K).
    prnu_frames, flat_prnu : the number of frames of the flat stage's master flat and camcal's PRNU per plane
        about the vignetting model (:func:`camcal.calibrate.flat.flat_prnu`, which holds the per-frame temporal
        variance): ``prnu_devignetted_pct``, not the standard's PRNU₁₂₈₈.
    prnu_1288 : per plane, PRNU₁₂₈₈ as the standard defines it, the total non-uniformity of the averaged flat with
        its row, column and pixel parts (:func:`camcal.calibrate.emva_standard.prnu_1288_planes`): ``prnu_pct`` and the
        ``prnu_*_pct`` parts.
    pairs : the linearity stage's :class:`camcal.calibrate.response.PairStatistics` (photon transfer).
    spectral : absolute c(λ) (:class:`camcal.models.spectral.SpectralSensitivity`) for the quantum efficiency, with
        ``pixel_pitch_um`` (µm).
    """
    notes: list[str] = []
    out: dict[str, dict] = {c: {k: None for k in SHEET_KEYS} for c in channels}
    spatial: dict = {}
    dark_var0: dict[str, float] = {}
    defects = None if dark is None else np.asarray(dark.defects) != 0
    summary = {} if dark is None else dark.channels
    # temporal dark noise σ_y.dark at zero exposure and DSNU
    if dark_noise is not None:
        groups = dark_noise.groups
        if not groups:
            notes.append("no dark exposure with two or more frames: temporal dark noise and DSNU unknown")
        for k, c in enumerate(channels if groups else ()):
            good = np.ones(groups[0][2].shape[1:], bool) if defects is None else ~defects[k]
            ts = [t for t, _, _ in groups]
            # plane k only, converted to float64 after the selection (the same values in the same order)
            vs = [float(np.mean(np.asarray(var[k][good], np.float64))) for _, _, var in groups]
            dt = dark_temporal(np.array(ts), np.array(vs))
            v_std = max(dt.dark_variance_dn2, DARK_VARIANCE_FLOOR_DN2)  # the standard's σ²_y.dark and its floor
            v0 = dt.dark_variance_dn2
            info = summary.get(c) or {}
            tn = info.get("temporal_noise_dn")
            if tn is not None and tn < 1.0 and info.get("read_noise_dn") is not None:
                # camcal's quantised-normal fit below 1 DN: the photon transfer's intercept, under its own name
                v0 = float(info["read_noise_dn"]) ** 2 + QUANTISATION_VAR_DN2
                out[c]["read_noise_quantised_dn"] = _num(float(info["read_noise_dn"]))
            dark_var0[c] = v0
            # EMVA 1288: σ_y.dark and σ_d·K = √(σ²_y.dark − 1/12), whatever camcal's own estimate
            out[c]["dark_noise_dn"] = _num(math.sqrt(v_std))
            out[c]["read_noise_dn"] = _num(math.sqrt(max(v_std - QUANTISATION_VAR_DN2, 0.0)))
        if dark_noise.spatial is not None:
            t_sp, n_sp, mean, var = dark_noise.spatial
            spatial.update({"dsnu_exposure_s": float(t_sp), "dsnu_frames": int(n_sp)})
            for k, c in enumerate(channels):
                good = None if defects is None else ~defects[k]
                d = dsnu(spatial_variance(mean[k], var[k], n_sp, good))
                out[c]["dsnu_dn"], out[c]["dsnu_unc_dn"] = _num(d.value), _num(d.uncertainty)
                out[c]["dsnu_temporal_floor_dn"] = _num(math.sqrt(max(d.spatial.temporal_floor_dn2, 0.0)))
    else:
        notes.append("no dark frames: read noise, DSNU and the dark variance of the photon transfer unknown")
    # photon transfer per ISO
    gains: dict[str, tuple[float, float, str]] = {}
    ptc_at_iso: dict[str, PhotonTransfer] = {}
    ptc_rows: list[dict] = []
    if pairs is not None and len(pairs.exposure_s):
        isos = sorted({float(i) for i in pairs.iso})
        for p_iso in isos:
            rows = np.flatnonzero(pairs.iso == p_iso)
            n_ref = float(np.median(pairs.f_number[rows]))
            x = pairs.exposure_s[rows] * (n_ref / pairs.f_number[rows]) ** 2
            entry = {"iso": p_iso, "pairs": int(rows.size), "channels": {}}
            for k, c in enumerate(channels):
                beta = None
                if dark is not None and dark.dark_current_dn_per_s is not None:
                    beta = float((summary.get(c) or {}).get("dark_current_dn_per_s") or 0.0) * p_iso / iso
                ds = None if beta is None else beta * pairs.exposure_s[rows]
                v0 = dark_var0.get(c) if p_iso == iso else None
                try:
                    pt = photon_transfer(x, pairs.mean_dn[rows, k], pairs.variance_dn2[rows, k], v0, ds)
                except ValueError as exc:
                    entry["channels"][c] = None
                    notes.append(f"photon transfer of {c} at ISO {p_iso:g}: {exc}")
                    continue
                entry["channels"][c] = {
                    "K_dn_per_e": _num(pt.gain_dn_per_e), "K_unc_dn_per_e": _num(pt.gain_unc_dn_per_e),
                    "fit_range_dn": [pt.fit_range_dn[0], pt.fit_range_dn[1]], "n_fit": pt.n_fit,
                    "dark_variance_dn2": _num(pt.dark_variance_dn2), "intercept_fitted": pt.intercept_fitted,
                    "saturation_dn": _num(pt.saturation_dn), "saturation_exposure_s": _num(pt.saturation_exposure_s),
                }
                if p_iso == iso:
                    ptc_at_iso[c] = pt
            ptc_rows.append(entry)
        for c in channels:
            if c in ptc_at_iso:
                pt = ptc_at_iso[c]
                gains[c] = (pt.gain_dn_per_e, pt.gain_unc_dn_per_e, f"photon transfer at ISO {iso:g}")
                continue
            near = [r for r in ptc_rows if (r["channels"].get(c) or {}).get("K_dn_per_e")]
            if near:
                r = min(near, key=lambda r: abs(math.log(r["iso"] / iso)))
                scale = iso / r["iso"]
                k_, ku = r["channels"][c]["K_dn_per_e"], r["channels"][c]["K_unc_dn_per_e"] or 0.0
                gains[c] = (k_ * scale, ku * scale, f"photon transfer at ISO {r['iso']:g} scaled to ISO {iso:g}")
    else:
        notes.append("no RAW frame pairs at one setting in linearity/: K from the dark current's shot noise "
                     "(fallback), saturation, SNR_max, dynamic range and linearity error unknown")
    for c in channels:
        if c not in gains and summary:
            g = float((summary.get(c) or {}).get("gain_dn_per_e_from_dark") or 0.0)
            if g > 0:
                gains[c] = (g, float("nan"), "dark current shot noise (fallback: no photon transfer)")
        if c in gains:
            k_, ku, src = gains[c]
            out[c].update({"K_dn_per_e": _num(k_), "K_unc_dn_per_e": _num(ku), "K_source": src})
    # datasheet figures
    for c in channels:
        row = out[c]
        k_ = row.get("K_dn_per_e")
        if k_:
            if row.get("read_noise_dn") is not None:
                row["read_noise_e"] = row["read_noise_dn"] / k_
            if row.get("dsnu_dn") is not None:
                row["dsnu_e"] = row["dsnu_dn"] / k_
            info = summary.get(c) or {}
            # EMVA 1288 takes the dark current from the mean dark signal: the plane mean of the per-pixel slopes
            # (good pixels), which is the slope of the mean; the dark model's headline figure is their median
            beta = info.get("dark_current_mean_dn_per_s", info.get("dark_current_dn_per_s"))
            if beta is not None:
                row["dark_current_dn_per_s"] = _num(beta)
                row["dark_current_e_per_s"] = _num(beta / k_)
        pt = ptc_at_iso.get(c)
        if pt is not None and k_:
            sheet = datasheet(k_, pt.saturation_dn, row.get("dark_noise_dn") or math.sqrt(pt.dark_variance_dn2))
            lin = linearity_error(pt.exposure_s, pt.photo_signal_dn, float(pt.photo_signal_dn[pt.saturation_index]))
            row.update({
                "saturation_dn": _num(sheet.saturation_dn), "saturation_e": _num(sheet.saturation_e),
                "saturation_exposure_s": _num(pt.saturation_exposure_s), "snr_max": _num(sheet.snr_max),
                "snr_max_db": _num(sheet.snr_max_db), "threshold_e": _num(sheet.threshold_e),
                "dynamic_range": _num(sheet.dynamic_range), "dynamic_range_db": _num(sheet.dynamic_range_db),
                "linearity_error_pct": _num(lin.error_pct), "linearity_error_min_pct": _num(lin.min_pct),
                "linearity_error_max_pct": _num(lin.max_pct),
                "ptc_fit_range_dn": [pt.fit_range_dn[0], pt.fit_range_dn[1]],
            })
    # PRNU₁₂₈₈ (the total), camcal's PRNU about the vignetting model and the noise left in the flat map
    if prnu_1288:
        for c in channels:
            out[c].update({k: _num(v) for k, v in (prnu_1288.get(c) or {}).items()})
    elif flat_prnu:
        notes.append("PRNU_1288 (total non-uniformity) not computed: only camcal's PRNU about the vignetting model")
    if flat_prnu:
        if prnu_frames is not None:
            spatial["prnu_frames"] = int(prnu_frames)
        for c in channels:
            p = flat_prnu.get(c)
            if p is None:
                continue
            row = out[c]
            row["prnu_devignetted_pct"] = _num(100 * p.value)
            row["prnu_devignetted_unc_pct"] = _num(100 * p.uncertainty)
            sv = p.spatial
            rel_frame = sv.stack_dn2 / sv.mean_dn**2  # per-frame temporal variance, relative
            row["flat_map_noise_pct"] = _num(100 * math.sqrt(rel_frame / sv.n_frames))
            row["flats_for_noise_below_prnu"] = flats_needed(rel_frame, p.value)
    else:
        notes.append("no flats: PRNU unknown")
    # quantum efficiency
    qe = None
    if spectral is not None and pixel_pitch_um and getattr(spectral, "mode", None) == "absolute":
        vals = {}
        for c in channels:
            k_ = out[c].get("K_dn_per_e")
            if k_ and c in spectral.values:
                k_ref = k_ * float(spectral.reference_iso) / iso  # K at the ISO c(λ) refers to
                vals[c] = [_num(v) for v in quantum_efficiency(spectral.wavelength_nm, spectral.values[c], k_ref,
                                                                pixel_pitch_um, float(spectral.reference_f_number))]
        qe = {"pixel_pitch_um": float(pixel_pitch_um), "wavelength_nm": [float(w) for w in spectral.wavelength_nm],
              "values": vals}
    elif spectral is not None and not pixel_pitch_um:
        notes.append("quantum efficiency not computed: give pixel_pitch_um in session.toml")
    return EmvaSheet(float(iso), out, tuple(ptc_rows), spatial, qe, tuple(notes))

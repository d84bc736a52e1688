"""From DN rates to radiance: band radiance per channel and spectral radiance at one wavelength.

Input everywhere is the **DN rate at the reference setting, on axis** per channel
R, G, B (dark removed, flat corrected, linearised, divided by the relative
exposure; see :mod:`camcal.apply.photo`), and the channel sensitivities c_i(λ) in
DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm (seed §3.1). The forward model is

    rate_i = ∫ c_i(λ) L(λ) dλ                                   (seed eq. 12/13, γ = 1)

Estimators
----------
``band``
    L_i = rate_i / ∫ c_i dλ, in W m⁻² sr⁻¹ nm⁻¹: the c_i-weighted mean spectral
    radiance over the channel's band. Exact for any spectrum, by definition.
``narrowband``
    Assumes the light is confined to a band much narrower than c_i varies over,
    centred on λ0 (a line, or a scene seen through an interference filter):
    rate_i = c_i(λ0) · L_band, so L_band = rate_i / c_i(λ0) in W m⁻² sr⁻¹ (the
    radiance integrated over the line). The channel with the largest c_i(λ0) is
    used (the red channel at 663 nm). With ``filter_fwhm_nm`` the result is
    divided by that width to give a mean spectral radiance (W m⁻² sr⁻¹ nm⁻¹).
    c_i(λ0) is read off the sampled curve with a cubic spline (linear
    interpolation between 5 nm samples is biased by the curvature: −0.75 % at
    663 nm and +4.8 % at 672 nm on the D5100 red channel). A profile measured
    with a monochromator slit of FWHM s stores c ⊛ slit; a line of FWHM w sees
    c ⊛ line, so with both widths known the curve is corrected to second order,
    c ⊛ line ≈ c ⊛ slit + (σ_w² − σ_s²)/2 · c'' (Gaussian shapes; σ = FWHM/2.355).
    Without ``line_fwhm_nm`` the line is assumed as wide as the slit (no
    correction); a 1 nm line read with a 5 nm-slit curve is then 0.6 % high at 663 nm.
``trained``
    The linear estimator L̂(λ0) = w · rate with the least relative error over the prior spectra of
    :func:`prior_spectra` (black bodies, CIE illuminants, the ColorChecker under D65): w minimises
    Σ_s (w · rate_s / L_s(λ0) − 1)² (ordinary least squares, three unknowns, 32 spectra). Its
    spectral-reconstruction term is the leave-one-out RMS error (each spectrum predicted by weights trained
    without it), an honest figure for a scene not in the set. In W m⁻² sr⁻¹ nm⁻¹.
``auto`` (default)
    The estimator of a spectral radiance at λ0 with the smallest spectral-reconstruction error the profile's
    c(λ) supports, among ``trained`` (leave-one-out RMS) and ``smooth`` (RMS over the priors); the chosen one
    and both figures are in :attr:`RadianceModel.candidates`.
``smooth``
    Assumes L(λ) is smooth (no lines). A regularised linear reconstruction
    (Gaussian-process/Wiener estimate) on the sensitivity grid with prior
    covariance K(λ, λ') = 1 + exp(−(λ−λ')²/(2ℓ²)), ℓ = 60 nm:

        L̂ = K Cᵀ (C K Cᵀ + ε·tr(C K Cᵀ)/m · I)⁻¹ rate

    evaluated at λ0. The estimate is linear in the rates (one dot product per
    pixel) and scale-invariant. Its error for natural spectra is a property of
    the camera's curves; :func:`smooth_error_table` tabulates it (docs/apply.md).

References
----------
Burggraaff, O. et al. (2019). Standardized spectral and radiometric calibration of consumer
cameras. Optics Express 27(14), 19075.
Rasmussen, C. E., Williams, C. K. I. (2006). Gaussian Processes for Machine Learning. MIT Press, ch. 2.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import CubicSpline

from camcal.errors import CamcalError
from camcal.models.spectra import FWHM_TO_SIGMA, planck_radiance
from camcal.units import IN_BAND_RADIANCE, SPECTRAL_RADIANCE

RGB = ("R", "G", "B")
ESTIMATORS = ("narrowband", "smooth", "trained", "auto")
#: Estimators whose L(λ0) is a spectral radiance for broadband light (``narrowband`` is one only with a filter).
SPECTRAL_ESTIMATORS = ("trained", "smooth")


@dataclass(frozen=True)
class RadianceModel:
    """Precomputed linear maps from channel rates (R, G, B) to radiance.

    Attributes
    ----------
    band_integral : (3,) ∫ c_i dλ per channel, DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹).
    band_unc : (3,) its standard uncertainty.
    wavelength_nm : the target wavelength λ0, nm.
    estimator : "narrowband" or "smooth".
    weights : (3,) L(λ0) = weights · rate.
    weights_unc_rel : relative standard uncertainty of L(λ0) from c(λ) alone.
    units : unit of L(λ0).
    channel : the channel used by ``narrowband`` (None for ``smooth``).
    """

    band_integral: np.ndarray
    band_unc: np.ndarray
    wavelength_nm: float
    estimator: str
    weights: np.ndarray
    weights_unc_rel: float
    units: str
    channel: str | None
    spectral_unc_rel: float = 0.0
    """Relative standard uncertainty of L(λ0) from the spectral reconstruction itself (``smooth``: the RMS
    error over the prior spectra of :func:`smooth_error_table`; ``narrowband``: 0, valid only for light
    confined near λ0, see docs/apply.md)."""
    candidates: tuple = ()
    """``auto``: ((estimator, spectral_unc_rel), ...) it chose from, the chosen first."""

    @property
    def in_band(self) -> bool:
        """True when L(λ0) is an in-band radiance (W m⁻² sr⁻¹, ``narrowband`` without a filter width), not a
        spectral radiance."""
        return self.units.startswith(IN_BAND_RADIANCE) and not self.units.startswith(SPECTRAL_RADIANCE)

    @property
    def unc_rel(self) -> float:
        """Relative 1-σ of L(λ0) common to every pixel: c(λ) ⊕ the spectral reconstruction (finite parts)."""
        parts = [v for v in (self.weights_unc_rel, self.spectral_unc_rel) if np.isfinite(v)]
        return float(np.hypot(*parts)) if len(parts) == 2 else (float(parts[0]) if parts else 0.0)

    def describe(self) -> str:
        """One line for a console: the estimator, its channel or weights and the spectral term."""
        what = ("in-band radiance (narrowband, light confined near the wavelength)" if self.in_band
                else "spectral radiance")
        spec = (f"spectral reconstruction ±{100 * self.spectral_unc_rel:.0f} % (1σ)" if self.spectral_unc_rel > 0
                else "no spectral-reconstruction term (exact only for light near the wavelength)")
        chose = ""
        if self.candidates:
            chose = " chosen from " + ", ".join(f"{k} ±{100 * v:.0f} %" for k, v in self.candidates)
        return (f"L{self.wavelength_nm:g}: {what}, {self.units}, estimator {self.estimator}{chose}; {spec}; "
                f"c(λ) ±{100 * self.weights_unc_rel:.1f} %")


def _interp(wl: np.ndarray, values: np.ndarray, at: float, derivative: int = 0) -> float:
    """Not-a-knot cubic-spline value (or derivative) of a sampled curve at ``at`` (scipy CubicSpline); NaN outside."""
    if not wl[0] <= at <= wl[-1]:
        return float("nan")
    if wl.size < 4:
        return float(np.interp(at, wl, values)) if derivative == 0 else 0.0
    return float(CubicSpline(wl, values)(at, derivative))


def smooth_operator(wavelength_nm: np.ndarray, c: np.ndarray, length_nm: float = 60.0, eps: float = 1e-6) -> np.ndarray:
    """The (n, 3) matrix M with L̂(λ_grid) = M · rate for the ``smooth`` estimator.

    ``c`` is (3, n) on ``wavelength_nm`` (any uniform or non-uniform grid; trapezoid weights).
    """
    wl = np.asarray(wavelength_nm, float)
    w = np.gradient(wl)  # trapezoid-like quadrature weights
    cmat = np.asarray(c, float) * w[None, :]  # (3, n): rate = cmat @ L
    d = wl[:, None] - wl[None, :]
    k = 1.0 + np.exp(-0.5 * (d / length_nm) ** 2)
    ckc = cmat @ k @ cmat.T
    reg = eps * np.trace(ckc) / ckc.shape[0]
    return k @ cmat.T @ np.linalg.inv(ckc + reg * np.eye(ckc.shape[0]))


def _trained_row(wl: np.ndarray, c: np.ndarray, target_nm: float) -> tuple[np.ndarray, float]:
    """The ``trained`` estimator's weights on (R, G, B) at ``target_nm`` and its leave-one-out spread
    (:func:`trained_weights`)."""
    return trained_weights(wl, {k: c[i] for i, k in enumerate(RGB)}, target_nm)


def _smooth_row(wl: np.ndarray, c: np.ndarray, target_nm: float) -> tuple[np.ndarray, float]:
    """The ``smooth`` estimator's weights on (R, G, B) at ``target_nm`` (a row of :func:`smooth_operator`) and its
    RMS error over the priors (:func:`smooth_spread_rel`)."""
    m = smooth_operator(wl, c)
    row = np.array([np.interp(target_nm, wl, m[:, i]) for i in range(3)])
    return row, smooth_spread_rel(wl, {k: c[i] for i, k in enumerate(RGB)}, target_nm)


SPECTRAL_ROWS = {"trained": _trained_row, "smooth": _smooth_row}
"""The estimators that reconstruct a spectrum from the three channels: name → (wavelengths, c (3, n), λ0) →
(weights on R, G, B, relative spectral error)."""


def radiance_model(
    wavelength_nm: np.ndarray,
    c_rgb: dict[str, np.ndarray],
    c_rgb_unc: dict[str, np.ndarray] | None,
    target_nm: float = 663.0,
    estimator: str = "narrowband",
    filter_fwhm_nm: float | None = None,
    line_fwhm_nm: float | None = None,
    slit_fwhm_nm: float | None = None,
) -> RadianceModel:
    """Build the linear maps of the estimators for sensitivities ``c_rgb`` (absolute units).

    ``line_fwhm_nm`` (the width of the light, narrowband only) and ``slit_fwhm_nm`` (the
    monochromator slit the curve was measured with; 0 for a deconvolved curve) enable the
    second-order slit correction described in the module docstring.

    Every estimator's spectral-reconstruction term is set here (``spectral_unc_rel``).

    Raises
    ------
    CamcalError
        Unknown estimator, or ``target_nm`` outside the measured range.
    """
    if estimator == "auto":
        built = [radiance_model(wavelength_nm, c_rgb, c_rgb_unc, target_nm, e) for e in SPECTRAL_ESTIMATORS]
        ok = [m for m in built if np.isfinite(m.spectral_unc_rel)]
        if not ok:
            raise CamcalError("no spectral estimator has a finite error over the prior spectra for this c(λ)")
        ranked = sorted(ok, key=lambda m: m.spectral_unc_rel)
        return replace(ranked[0], candidates=tuple((m.estimator, float(m.spectral_unc_rel)) for m in ranked))
    if estimator not in ESTIMATORS:
        raise CamcalError(f"unknown estimator {estimator!r}; choose {', '.join(ESTIMATORS)}")
    wl = np.asarray(wavelength_nm, float)
    if not wl[0] <= target_nm <= wl[-1]:
        raise CamcalError(f"wavelength {target_nm:g} nm is outside the calibrated range {wl[0]:g}-{wl[-1]:g} nm")
    c = np.stack([np.clip(np.asarray(c_rgb[k], float), 0, None) for k in RGB])
    u = np.stack([np.asarray(c_rgb_unc[k], float) for k in RGB]) if c_rgb_unc else np.zeros_like(c)
    band = np.trapezoid(c, wl, axis=1)
    # uncertainty of the integral: samples treated as independent (trapezoid weights)
    qw = np.gradient(wl)
    band_unc = np.sqrt(np.sum((u * qw[None, :]) ** 2, axis=1))
    if np.any(band <= 0):
        raise CamcalError("a channel has no sensitivity at all; the profile's c(λ) is unusable")
    if estimator == "narrowband":
        at = np.array([_interp(wl, c[i], target_nm) for i in range(3)])
        if line_fwhm_nm is not None and slit_fwhm_nm is not None:
            dsig2 = (float(line_fwhm_nm) ** 2 - float(slit_fwhm_nm) ** 2) * FWHM_TO_SIGMA**2
            at = at + 0.5 * dsig2 * np.array([_interp(wl, c[i], target_nm, 2) for i in range(3)])
        best = int(np.nanargmax(at))
        weights = np.zeros(3)
        weights[best] = 1.0 / at[best]
        rel = _interp(wl, u[best], target_nm) / at[best]
        units = f"{IN_BAND_RADIANCE} (in-band)"
        if filter_fwhm_nm:
            weights /= filter_fwhm_nm
            units = f"{SPECTRAL_RADIANCE} (mean over the filter band)"
        return RadianceModel(band, band_unc, float(target_nm), estimator, weights, float(rel), units, RGB[best])
    # relative uncertainty from c(λ): first order, rate ~ c·L so δL/L ~ δc/c of the weighted band
    rel = float(np.sqrt(np.sum((band_unc / band) ** 2) / 3))
    row, spread = SPECTRAL_ROWS[estimator](wl, c, float(target_nm))
    return RadianceModel(band, band_unc, float(target_nm), estimator, row, rel, SPECTRAL_RADIANCE, None,
                         spectral_unc_rel=float(spread))


def radiance_at(
    rates, rate_var, model: RadianceModel, scale: float = 1.0, out: tuple | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Spectral radiance at λ0 and its standard uncertainty, per pixel: the one path of every caller.

    Parameters
    ----------
    rates : sequence of 3 arrays (or a (3, ...) array), the channels R, G, B in any common unit.
    rate_var : their noise variances (same shapes), or None (no noise model: the common terms alone).
    scale : multiplies the rates (1/x, the relative exposure, in :mod:`camcal.apply.photo`).
    out : optional (value, unc) float32 arrays to write into.

    Returns
    -------
    (L, L_unc) in ``model.units``, float32 for float32 rates (else float64): L = Σ_i w_i s rate_i over the
    channels of non-zero weight (a NaN in an unused channel does not spread),
    L_unc² = Σ_i (w_i s)² var_i + (u L)², u = :attr:`RadianceModel.unc_rel` (c(λ) ⊕ the spectral reconstruction).
    """
    idx = [i for i in range(3) if model.weights[i] != 0]
    if not idx:
        raise CamcalError("the radiance estimator has no non-zero weight; the profile's c(λ) is unusable")
    dtype = np.result_type(*(np.asarray(rates[i]).dtype for i in idx), np.float32)  # float32 stays float32
    used = [(i, dtype.type(model.weights[i] * scale)) for i in idx]
    shape = np.shape(rates[idx[0]])
    value, unc = out if out is not None else (np.empty(shape, dtype), np.empty(shape, dtype))
    i0, w0 = used[0]
    np.multiply(rates[i0], w0, out=value)
    for i, wi in used[1:]:
        value += np.asarray(rates[i], dtype) * wi
    if rate_var is None:
        noise = np.zeros(shape, dtype)
    else:
        noise = np.asarray(rate_var[i0], dtype) * (w0 * w0)
        for i, wi in used[1:]:
            noise += np.asarray(rate_var[i], dtype) * (wi * wi)
    rel = dtype.type(model.unc_rel)
    if rel:
        noise += (value * rel) ** 2
    np.sqrt(noise, out=unc)
    return value, unc


def smooth_error_table(wavelength_nm: np.ndarray, c_rgb: dict[str, np.ndarray], target_nm: float = 663.0) -> list[dict]:
    """Relative error of the ``smooth`` estimator at ``target_nm`` for reference spectra.

    Spectra: black bodies 2500–10000 K, CIE D50/D65/A illuminants, and the
    24 ColorChecker patches (Ohta) under D65 — all from colour-science.
    Returns rows ``{"spectrum", "true", "estimate", "error_pct"}``.
    """
    wl = np.asarray(wavelength_nm, float)
    c = np.stack([np.asarray(c_rgb[k], float) for k in RGB])
    m = smooth_operator(wl, c)
    row = np.array([np.interp(target_nm, wl, m[:, i]) for i in range(3)])
    spectra = prior_spectra(wl)
    out = []
    for name, spec in spectra:
        rates = np.trapezoid(c * spec[None, :], wl, axis=1)
        est = float(row @ rates)
        true = float(np.interp(target_nm, wl, spec))
        out.append({"spectrum": name, "true": true, "estimate": est, "error_pct": 100 * (est / true - 1)})
    return out


def prior_spectra(wavelength_nm: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The prior spectra on ``wavelength_nm``: black bodies 2500–10000 K, CIE D50/D65/A and the 24 ColorChecker
    patches (Ohta) under D65, from colour-science (cached per grid)."""
    return list(_prior_spectra(tuple(float(v) for v in np.asarray(wavelength_nm, float))))


@functools.lru_cache(maxsize=4)
def _prior_spectra(grid: tuple) -> tuple:
    import colour  # loads matplotlib: kept off paths that do not plot

    wl = np.asarray(grid, float)
    # aligned (colour-science's interpolation) on a 1 nm grid over the curve's range, then read linearly at the
    # curve's own wavelengths: any grid, however coarse or uneven, and the table's values on its nodes
    lo, hi = float(np.floor(wl[0])), float(np.ceil(wl[-1]))
    shape = colour.SpectralShape(lo, max(hi, lo + 10.0), 1.0)

    def sd_values(sd) -> np.ndarray:
        s = sd.copy().align(shape)
        return np.interp(wl, s.wavelengths, s.values)

    spectra: list[tuple[str, np.ndarray]] = [(f"black body {t} K", planck_radiance(t, wl)) for t in (2500, 3200, 5000,
                                                                                                      6500, 10000)]
    for name in ("D50", "D65", "A"):
        spectra.append((f"CIE {name}", sd_values(colour.SDS_ILLUMINANTS[name])))
    d65 = sd_values(colour.SDS_ILLUMINANTS["D65"])
    checker = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    for name, sd in checker.items():
        spectra.append((f"ColorChecker {name} under D65", d65 * sd_values(sd)))
    return tuple(spectra)


def trained_weights(wavelength_nm: np.ndarray, c_rgb: dict[str, np.ndarray], target_nm: float = 663.0,
                    ) -> tuple[np.ndarray, float]:
    """(w, leave-one-out RMS relative error) of the ``trained`` estimator (module docstring): w minimises
    Σ_s (w · rate_s / L_s(λ0) − 1)² over :func:`prior_spectra` (numpy least squares)."""
    wl = np.asarray(wavelength_nm, float)
    c = np.stack([np.clip(np.asarray(c_rgb[k], float), 0, None) for k in RGB])
    rows = []
    for _, spec in prior_spectra(wl):
        true = float(np.interp(target_nm, wl, spec))
        if true > 0:
            rows.append(np.trapezoid(c * spec[None, :], wl, axis=1) / true)
    a = np.array(rows)
    if a.shape[0] < 4 or not np.all(np.isfinite(a)):
        return np.full(3, np.nan), float("nan")
    scale = np.abs(a).max(axis=0)
    scale[scale == 0] = 1.0
    w = np.linalg.lstsq(a / scale, np.ones(len(a)), rcond=None)[0] / scale
    loo = []
    for i in range(len(a)):
        keep = np.arange(len(a)) != i
        wi = np.linalg.lstsq(a[keep] / scale, np.ones(keep.sum()), rcond=None)[0] / scale
        loo.append(float(a[i] @ wi) - 1.0)
    return w, float(np.sqrt(np.mean(np.square(loo))))


def smooth_spread_rel(wavelength_nm: np.ndarray, c_rgb: dict[str, np.ndarray], target_nm: float = 663.0) -> float:
    """RMS relative error of the ``smooth`` estimator at ``target_nm`` over the prior spectra.

    The spread of :func:`smooth_error_table` (black bodies, CIE illuminants, the ColorChecker under D65):
    the spectral-reconstruction term of ``L<λ0>_unc`` for smooth scenes (docs/apply.md).
    """
    errors = np.array([row["error_pct"] for row in smooth_error_table(wavelength_nm, c_rgb, target_nm)]) / 100.0
    errors = errors[np.isfinite(errors)]
    return float(np.sqrt(np.mean(errors**2))) if errors.size else float("nan")


def mono_model(
    wavelength_nm: np.ndarray,
    c: np.ndarray,
    c_unc: np.ndarray | None,
    target_nm: float = 663.0,
    estimator: str = "auto",
    filter_fwhm_nm: float | None = None,
    line_fwhm_nm: float | None = None,
    slit_fwhm_nm: float | None = None,
) -> RadianceModel | None:
    """The band radiance of a monochrome sensor's one channel ``Y``, and L(λ0) only where it is honest.

    ``band_integral`` is ∫c dλ (``Y = rate / ∫c dλ``, the c-weighted mean spectral radiance, as for R, G, B).
    One broad channel cannot reconstruct a spectrum, so ``auto`` gives no L(λ0) (returns a model of zero
    weight); ``narrowband`` gives L(λ0) = rate / c(λ0) (in-band, W m⁻² sr⁻¹) or, with ``filter_fwhm_nm`` (a
    narrowband filter in front of the lens), rate / (c(λ0) · FWHM) in W m⁻² sr⁻¹ nm⁻¹; ``smooth`` and
    ``trained`` are refused.
    """
    if estimator in SPECTRAL_ESTIMATORS:
        raise CamcalError(f"a monochrome sensor has one channel: the {estimator} estimator needs three to reconstruct "
                          "a spectrum; use --estimator narrowband with --filter-fwhm (a narrowband filter in front "
                          "of the lens), or the default, which writes the band radiance Y alone")
    if estimator not in ESTIMATORS:
        raise CamcalError(f"unknown estimator {estimator!r}; choose {', '.join(ESTIMATORS)}")
    wl = np.asarray(wavelength_nm, float)
    rgb = {k: np.asarray(c, float) for k in RGB}
    unc = None if c_unc is None else {k: np.asarray(c_unc, float) for k in RGB}
    if estimator == "narrowband":
        m = radiance_model(wl, rgb, unc, target_nm, "narrowband", filter_fwhm_nm, line_fwhm_nm, slit_fwhm_nm)
        return replace(m, band_integral=m.band_integral[:1], band_unc=m.band_unc[:1], weights=m.weights[m.weights != 0],
                       channel="Y")
    cc = np.clip(np.asarray(c, float), 0, None)
    band = np.trapezoid(cc, wl)
    if band <= 0:
        raise CamcalError("the channel Y has no sensitivity at all; the profile's c(λ) is unusable")
    u = np.zeros_like(cc) if c_unc is None else np.asarray(c_unc, float)
    band_unc = float(np.sqrt(np.sum((u * np.gradient(wl)) ** 2)))
    return RadianceModel(np.array([band]), np.array([band_unc]), float(target_nm), "none", np.zeros(1), 0.0,
                         IN_BAND_RADIANCE, None)

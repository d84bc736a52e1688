"""Spectral sensitivity c(λ) from the patch signals of one photo of a colour chart.

The model. A Lambertian patch p of reflectance R_p(λ) under irradiance E(λ) has radiance R_p E / π; the camera's
channel i records

    y_i,p = ∫ c_i(λ) R_p(λ) E(λ) / π dλ  ≈  Σ_λ M_pλ c_i(λ),     M_pλ = R_p(λ) E(λ) ω_λ / π,

ω_λ the trapezoid weights of the grid (the convention of :func:`camcal.curves.import_spectral.predicted_rate`).
y is in DN s⁻¹ normalised to the reference exposure (absolute c, :data:`camcal.units.SPECTRAL_SENSITIVITY`)
when E is absolute, otherwise only c's shape is determined.

Twenty-four patches constrain only a few dimensions of c (the patches' spectra are smooth and correlated), so c
is estimated in the space of measured camera curves: the prior of :mod:`camcal.chart.basis`,

    c_i ~ N(s_i μ_i, s_i² Σ_i),   Σ_i = (Σ_basis + Σ_trunc)/λ_reg + Σ_lab,

(Jiang et al. 2013 read as a Gaussian population of cameras; s_i the channel's peak, refined by iteration).
λ_reg < 1 inflates the library's spread: a new camera lies further from the library's mean than the library's
own cameras lie from each other (the library is dominated by a few makes); :data:`DEFAULT_REGULARISATION` is
calibrated by :func:`leave_one_out_recovery` leaving out every camera of the tested one's make. Σ_lab is the
between-lab spread of measured curves (:func:`camcal.chart.basis.lab_covariance`): the library's curves are one
lab's measurements. The maximum a posteriori estimate under c ≥ 0 is the bounded least-squares problem

    min_c ‖N^(-1/2) (M c − y)‖² + ‖(s Σ^(1/2))⁻¹ (c − s μ)‖²,   c ≥ 0

(:func:`scipy.optimize.lsq_linear`), N the covariance of y: the signal noise S plus what the chart's and the
light's uncertainties do to y (C_R: each patch's reflectance error fully correlated over λ, independent between
patches; C_E = Σ_k (M_δE_k c)(M_δE_k c)ᵀ, one row per perturbed spectrum). Tikhonov regularisation with a prior
covariance is exactly this Bayesian estimate (Tarantola 2005, §3.2).

Its uncertainty. With the linear gain G = P Mᵀ N⁻¹, P = (Mᵀ N⁻¹ M + (s²Σ)⁻¹)⁻¹, the error of ĉ is
G (noise) + G (chart) + G (light) + (I − G M)(the prior's deviation), so

    cov ĉ = G S Gᵀ + G C_R Gᵀ + G C_E Gᵀ + Σ_t (I − GM) s²Σ_t (I − GM)ᵀ,   t = basis, truncation, library,

each term kept: ``noise``, ``chart``, ``illuminant``, ``basis`` (the part of c the chart cannot see, filled by
the library's spread), ``truncation`` (what K components of the library miss) and ``library`` (between-lab
spread). Their sum is P. Active bounds (c = 0 where the camera is blind) are not linearised.

References
----------
Jiang, J., Liu, D., Gu, J., Süsstrunk, S. (2013). What is the space of spectral sensitivity functions for digital
color cameras? IEEE WACV, 168-179.
Tarantola, A. (2005). Inverse Problem Theory and Methods for Model Parameter Estimation. SIAM, §3.2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from scipy.optimize import lsq_linear, minimize_scalar

from camcal.chart.basis import DEFAULT_COMPONENTS, CameraBasis, basis_from_curves
from camcal.chart.light import Irradiance, blackbody, daylight
from camcal.chart.targets import ChartReflectance
from camcal.errors import CamcalError
from camcal.models.spectral import ABSOLUTE_UNITS, RELATIVE_UNITS, SpectralSensitivity

#: Uncertainty terms of a recovered curve, in the order they are reported.
TERMS = ("noise", "chart", "illuminant", "basis", "truncation", "library")
#: Channel of the basis each plane is recovered in.
PLANE_CHANNEL = {"R": 0, "G": 1, "G1": 1, "G2": 1, "B": 2}
#: Scale iterations (the prior's scale s is the recovered peak).
SCALE_ITERATIONS = 4
#: Default λ_reg: the library's covariance inflated 4× (a camera outside the library lies further from its mean
#: than the library's spread says; calibrated by :func:`leave_one_out_recovery`, docs/spectral.md).
DEFAULT_REGULARISATION = 0.1
#: Relative jitter added to the prior covariance's diagonal (keeps it invertible).
PRIOR_JITTER = 1e-8


@dataclass(frozen=True, eq=False)
class RecoveredSensitivity:
    """c(λ) per plane recovered from a chart, with its uncertainty split by cause.

    Attributes
    ----------
    wavelength_nm : ndarray (n,)
    values : dict
        Plane -> ĉ(λ): signal units per (W m⁻² sr⁻¹ nm⁻¹) per nm when ``absolute``, else arbitrary (same for all
        planes).
    terms : dict
        Term (:data:`TERMS`) -> plane -> standard uncertainty (n,), same units.
    covariance : dict
        Plane -> (n, n) total covariance.
    absolute : bool
    chi2, dof : dict
        Plane -> χ² of the patch residuals (whitened by N) and its degrees of freedom (24 − effective parameters).
    residual_pct : dict
        Plane -> (24,) patch residuals (y − M ĉ) / y, percent.
    n_components : int
    regularisation : float
    source : dict
        Chart, light and basis records.
    notes : tuple of str
    """

    wavelength_nm: np.ndarray
    values: dict[str, np.ndarray]
    terms: dict[str, dict[str, np.ndarray]]
    covariance: dict[str, np.ndarray]
    absolute: bool
    chi2: dict[str, float]
    dof: dict[str, float]
    residual_pct: dict[str, np.ndarray]
    n_components: int
    regularisation: float
    source: dict[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    @property
    def planes(self) -> tuple[str, ...]:
        return tuple(self.values)

    @property
    def uncertainty(self) -> dict[str, np.ndarray]:
        """Plane -> total standard uncertainty (n,): the terms added in quadrature."""
        return {p: np.sqrt(sum(self.terms[t][p] ** 2 for t in TERMS)) for p in self.planes}

    def dominant_term(self) -> dict[str, str]:
        """Plane -> the term with the largest RMS over wavelength."""
        return {p: max(TERMS, key=lambda t: float(np.sqrt(np.mean(self.terms[t][p] ** 2)))) for p in self.planes}

    def term_rms_pct_of_peak(self) -> dict[str, dict[str, float]]:
        """Plane -> term (and ``total``) -> RMS over wavelength, % of the plane's peak."""
        total = self.uncertainty
        out = {}
        for p in self.planes:
            peak = float(np.max(self.values[p]))
            terms = {**{t: self.terms[t][p] for t in TERMS}, "total": total[p]}
            out[p] = {t: float(100 * np.sqrt(np.mean(u ** 2)) / peak) for t, u in terms.items()}
        return out

    def to_spectral_sensitivity(self, *, reference_iso: float | None = None,
                                reference_f_number: float | None = None) -> SpectralSensitivity:
        """camcal's :class:`~camcal.models.spectral.SpectralSensitivity` (planes as recovered; ``source`` kind
        ``chart``). Relative curves are divided by the largest value over all planes."""
        planes = self.planes
        unc = self.uncertainty
        values = {p: self.values[p] for p in planes}
        if not self.absolute:
            peak = max(float(np.max(v)) for v in values.values())
            values = {p: v / peak for p, v in values.items()}
            unc = {p: u / peak for p, u in unc.items()}
        dom = self.dominant_term()
        notes = (*self.notes, "recovered from a colour chart in a basis of measured camera curves (Jiang et al. "
                 f"2013, {self.n_components} components); dominant uncertainty: "
                 + ", ".join(f"{p} {dom[p]}" for p in planes))
        src = {"kind": "chart", "file": None, "sha256": None, **self.source,
               "absolute_scale": {"method": "chart" if self.absolute else "none",
                                  "description": "chart under a modelled or measured absolute irradiance"
                                  if self.absolute else "relative: the light's scale is unknown"},
               "uncertainty_terms_rms_pct_of_peak": {p: {t: round(v, 4) for t, v in d.items()}
                                                     for p, d in self.term_rms_pct_of_peak().items()}}
        return SpectralSensitivity(
            wavelength_nm=np.asarray(self.wavelength_nm, float), values=values, uncertainty=unc,
            units=ABSOLUTE_UNITS if self.absolute else RELATIVE_UNITS,
            mode="absolute" if self.absolute else "relative",
            reference_iso=reference_iso, reference_f_number=reference_f_number, notes=notes, source=src)


def _trapezoid_weights(wl: np.ndarray) -> np.ndarray:
    w = np.zeros_like(wl)
    d = np.diff(wl)
    w[:-1] += d / 2
    w[1:] += d / 2
    return w


def design_matrix(chart: ChartReflectance, light: Irradiance) -> np.ndarray:
    """(24, n) M_pλ = R_p(λ) E(λ) ω_λ / π on the chart's grid (the light resampled onto it)."""
    e = light.on(chart.wavelength_nm).irradiance_w_m2_nm
    return chart.reflectance * e * _trapezoid_weights(chart.wavelength_nm) / math.pi


def _as_cov(v, n: int, plane: str) -> np.ndarray:
    a = np.asarray(v, float)
    if a.shape == (n,):
        a = np.diag(a)
    if a.shape != (n, n) or not np.all(np.isfinite(a)):
        raise CamcalError(f"signal covariance of plane {plane} must be ({n},) variances or ({n}, {n})")
    return 0.5 * (a + a.T)


def _inv_sqrt(cov: np.ndarray) -> np.ndarray:
    """W with Wᵀ W = cov⁻¹ (symmetric eigen-decomposition; tiny eigenvalues floored)."""
    w, v = np.linalg.eigh(cov)
    floor = max(float(w.max()), 1e-300) * 1e-12
    return (v / np.sqrt(np.maximum(w, floor))).T


@dataclass(frozen=True)
class _Context:
    wl: np.ndarray
    m: np.ndarray            # (P, n) design matrix
    m_u: np.ndarray          # (P, n) the same with u(R) in place of R
    m_de: np.ndarray         # (m, P, n) the same with R δE_k in place of R E
    prior: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]


def _context(chart: ChartReflectance, light: Irradiance, basis: CameraBasis, k: int) -> _Context:
    wl = np.asarray(basis.wavelength_nm, float)
    if chart.wavelength_nm.shape != wl.shape or not np.allclose(chart.wavelength_nm, wl):
        chart = chart.on(wl)
    lt = light.on(wl)
    w = _trapezoid_weights(wl) / math.pi
    m = chart.reflectance * lt.irradiance_w_m2_nm * w
    m_u = chart.u_reflectance * lt.irradiance_w_m2_nm * w
    m_de = np.array([chart.reflectance * d * w for d in lt.perturbations]).reshape(-1, *m.shape)
    return _Context(wl, m, m_u, m_de, {ch: basis.prior(ch, k) for ch in range(3)})


def _prior_cov(ctx: _Context, channel: int, reg: float, between_lab: bool) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(Σ of the normalised curve, its parts): (Σ_basis + Σ_trunc)/λ_reg + Σ_lab."""
    mu, cov_b, cov_t, cov_l = ctx.prior[channel]
    parts = {"basis": cov_b / reg, "truncation": cov_t / reg, "library": cov_l if between_lab else 0 * cov_l}
    return mu, parts


def _solve_plane(y: np.ndarray, s_cov: np.ndarray, ctx: _Context, channel: int, reg: float,
                 nonnegative: bool, between_lab: bool
                 ) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray, float, float]:
    """(ĉ, term covariances, total covariance, χ², dof) for one plane."""
    mu, parts = _prior_cov(ctx, channel, reg, between_lab)
    n = mu.size
    cov_prior = sum(parts.values())
    cov_prior = cov_prior + PRIOR_JITTER * np.trace(cov_prior) / n * np.eye(n)
    m = ctx.m
    pred = m @ mu
    s = float(y @ pred / (pred @ pred)) if pred @ pred > 0 else 1.0
    if not s > 0:
        raise CamcalError("the chart's signals do not look like a camera's (negative scale of the mean curve)")
    c = s * mu
    l_prior = _inv_sqrt(cov_prior)
    for _ in range(SCALE_ITERATIONS):
        c_pos = np.clip(c, 0, None)
        cov_r = np.diag((ctx.m_u @ c_pos) ** 2)
        dy_e = ctx.m_de @ c_pos  # (m, P)
        cov_e = dy_e.T @ dy_e
        n_cov = s_cov + cov_r + cov_e
        wn = _inv_sqrt(n_cov)
        lp = l_prior / s
        a = np.vstack([wn @ m, lp])
        b = np.concatenate([wn @ y, lp @ (s * mu)])
        if nonnegative:
            c = lsq_linear(a, b, bounds=(0.0, np.inf), method="bvls", lsmr_tol="auto").x
        else:
            c = np.linalg.lstsq(a, b, rcond=None)[0]
        s_new = float(np.max(c))
        if not s_new > 0:
            raise CamcalError("the recovered curve is zero everywhere (no signal in the chart's patches?)")
        s = s_new
    n_inv = wn.T @ wn
    prior_prec = (l_prior.T @ l_prior) / s ** 2
    post = np.linalg.inv(m.T @ n_inv @ m + prior_prec)
    post = 0.5 * (post + post.T)
    g = post @ m.T @ n_inv
    i_gm = np.eye(n) - g @ m
    terms = {"noise": g @ s_cov @ g.T, "chart": g @ cov_r @ g.T, "illuminant": g @ cov_e @ g.T,
             **{t: s ** 2 * i_gm @ c @ i_gm.T for t, c in parts.items()}}
    total = sum(terms.values())
    r = wn @ (y - m @ c)
    dof = float(y.size - np.trace(m @ g))
    return c, terms, total, float(r @ r), dof


def recover_sensitivity(signal: dict[str, np.ndarray], signal_cov: dict[str, np.ndarray], chart: ChartReflectance,
                        light: Irradiance, basis: CameraBasis, *, n_components: int = DEFAULT_COMPONENTS,
                        regularisation: float = DEFAULT_REGULARISATION, nonnegative: bool = True,
                        absolute: bool | None = None, between_lab: bool = True) -> RecoveredSensitivity:
    """c(λ) per plane from one chart photo (module docstring).

    Parameters
    ----------
    signal : dict
        Plane (``R``, ``G1``, ``G2``, ``B`` or ``R``, ``G``, ``B``) -> (P,) patch signals y_p, DN s⁻¹ normalised to
        the reference exposure (dark subtracted, flat-fielded where known), in the chart's patch order.
    signal_cov : dict
        Plane -> (P,) variances or (P, P) covariance of ``signal``, (DN s⁻¹)².
    chart : ChartReflectance
        The chart's reflectances and their uncertainty (resampled onto the basis's grid).
    light : Irradiance
        The light on the chart (must cover the basis's grid).
    basis : CameraBasis
    n_components : int
        K, components of the basis spanning the prior's mean and covariance.
    regularisation : float
        λ_reg dividing the library's part of the prior covariance (1: the library's spread as it is).
    nonnegative : bool
        Bound c ≥ 0 (RAW data).
    absolute : bool or None
        Whether ``signal`` and ``light`` are absolute (default: ``light.absolute``).
    between_lab : bool
        Include Σ_lab (False only when the truth is measured by the library's own lab, as in
        :func:`leave_one_out_recovery`).

    Returns
    -------
    RecoveredSensitivity
    """
    if not signal or set(signal) - set(PLANE_CHANNEL) or set(signal) != set(signal_cov):
        raise CamcalError("chart signals need planes R, G1, G2, B (or R, G, B), each with its covariance")
    if not (np.isfinite(regularisation) and regularisation > 0):
        raise CamcalError("regularisation must be > 0")
    ctx = _context(chart, light, basis, int(n_components))
    n_p = ctx.m.shape[0]
    values, terms, cov, chi2, dof, resid = {}, {t: {} for t in TERMS}, {}, {}, {}, {}
    order = [p for p in ("R", "G", "G1", "G2", "B") if p in signal]
    for plane in order:
        y = np.asarray(signal[plane], float)
        if y.shape != (n_p,) or not np.all(np.isfinite(y)):
            raise CamcalError(f"plane {plane}: {n_p} finite patch signals needed")
        s_cov = _as_cov(signal_cov[plane], n_p, plane)
        c, tc, total, x2, df = _solve_plane(y, s_cov, ctx, PLANE_CHANNEL[plane], float(regularisation), nonnegative,
                                            between_lab)
        values[plane] = c
        for t in TERMS:
            terms[t][plane] = np.sqrt(np.clip(np.diag(tc[t]), 0, None))
        cov[plane] = total
        chi2[plane], dof[plane] = x2, df
        with np.errstate(divide="ignore", invalid="ignore"):
            resid[plane] = 100.0 * (y - ctx.m @ c) / y
    absolute = bool(light.absolute if absolute is None else absolute)
    src = {"chart": dict(chart.source), "light": dict(light.source), "basis": dict(basis.source),
           "n_components": int(n_components), "regularisation": float(regularisation),
           "model": "MAP in a Gaussian prior from the camera basis (Jiang et al. 2013), bounded least squares"}
    return RecoveredSensitivity(ctx.wl, values, terms, cov, absolute, chi2, dof, resid, int(n_components),
                                float(regularisation), src)


@dataclass(frozen=True, eq=False)
class IlluminantEstimate:
    """The light fitted from the chart jointly with c(λ).

    family : ``"daylight"`` (CIE D series, CCT) or ``"blackbody"`` (temperature); parameter_K and u_parameter_K:
    the fitted temperature and its standard uncertainty, K (inf when the chart does not constrain it);
    light : the fitted spectrum (shape, with the ±u perturbation as its uncertainty); recovered : c(λ) under it;
    profile_K, profile_objective : the scan of −2 log evidence against the temperature.
    """

    family: Literal["daylight", "blackbody"]
    parameter_K: float
    u_parameter_K: float
    light: Irradiance
    recovered: RecoveredSensitivity
    profile_K: np.ndarray
    profile_objective: np.ndarray
    notes: tuple[str, ...] = ()


def _evidence(signal, signal_cov, chart, light, basis, k, reg) -> float:
    """−2 log p(y | light) summed over planes, c marginalised over its Gaussian prior (scale s by least squares
    on the prior mean), the chart term at the prior mean: Σ rᵀ C⁻¹ r + log det C, C = S + C_R + s² M Σ Mᵀ/λ."""
    ctx = _context(chart, light, basis, k)
    total = 0.0
    for plane, y in signal.items():
        y = np.asarray(y, float)
        mu, parts = _prior_cov(ctx, PLANE_CHANNEL[plane], reg, True)
        pred = ctx.m @ mu
        s = max(float(y @ pred / (pred @ pred)), 1e-300)
        cov = (_as_cov(signal_cov[plane], y.size, plane) + np.diag((ctx.m_u @ (s * mu)) ** 2)
               + s ** 2 * ctx.m @ sum(parts.values()) @ ctx.m.T)
        r = y - s * pred
        sign, logdet = np.linalg.slogdet(cov)
        total += float(r @ np.linalg.solve(cov, r) + logdet)
    return total


ILLUMINANT_FAMILIES = {"daylight": (daylight, (4000.0, 25000.0)), "blackbody": (blackbody, (1500.0, 20000.0))}
"""The lights :func:`estimate_illuminant` searches: family → (spectrum of a temperature in K, the K range searched
by default: CIE daylight's correlated colour temperatures, a black body's temperatures)."""


def estimate_illuminant(signal: dict[str, np.ndarray], signal_cov: dict[str, np.ndarray], chart: ChartReflectance,
                        basis: CameraBasis, *, family: Literal["daylight", "blackbody"] = "daylight",
                        n_components: int = DEFAULT_COMPONENTS, regularisation: float = DEFAULT_REGULARISATION,
                        nonnegative: bool = True, range_K: tuple[float, float] | None = None,
                        n_scan: int = 25) -> IlluminantEstimate:
    """The light's temperature (CIE daylight CCT or black body) and c(λ), jointly, from one chart photo.

    The temperature maximises the evidence p(y | T) = ∫ p(y | c, T) p(c) dc, c marginalised over the basis's
    Gaussian prior (MacKay 1992): the neutral patches fix the light's colour as the camera sees it, and the prior
    on c — cameras' curves being what they are — separates the light's colour from the camera's. Its uncertainty
    is the Laplace approximation, u(T)² = 2 / ∂²(−2 log p)/∂T², from a scan of ``n_scan`` temperatures
    (log-spaced over ``range_K``) refined by :func:`scipy.optimize.minimize_scalar`. c(λ) is then
    :func:`recover_sensitivity` under the fitted light, whose ±u(T) spectra enter its ``illuminant`` term.

    References
    ----------
    MacKay, D. J. C. (1992). Bayesian interpolation. Neural Computation 4(3), 415-447.
    """
    if family not in ILLUMINANT_FAMILIES:
        raise CamcalError(f"unknown illuminant family {family!r}; use {' or '.join(ILLUMINANT_FAMILIES)}")
    make, default_range_K = ILLUMINANT_FAMILIES[family]
    lo, hi = range_K or default_range_K
    wl = basis.wavelength_nm
    k = int(n_components)

    def objective(t: float) -> float:
        return _evidence(signal, signal_cov, chart, make(float(t), wavelength_nm=wl), basis, k, regularisation)

    grid = np.geomspace(lo, hi, int(n_scan))
    prof = np.array([objective(t) for t in grid])
    i = int(np.argmin(prof))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    t_best = float(grid[i])
    if b > a:
        res = minimize_scalar(lambda lt: objective(math.exp(lt)), bounds=(math.log(a), math.log(b)),
                              method="bounded", options={"xatol": 1e-4})
        if res.fun <= prof[i]:
            t_best = float(math.exp(res.x))
    h = 0.02 * t_best
    notes = []
    if t_best - h < lo or t_best + h > hi:
        u = math.inf
        notes.append(f"the fitted temperature lies at the edge of {lo:g}-{hi:g} K: not constrained by the chart")
    else:
        f0, fp, fm = objective(t_best), objective(t_best + h), objective(t_best - h)
        curv = (fp - 2 * f0 + fm) / h ** 2
        u = math.sqrt(2.0 / curv) if curv > 0 else math.inf
        if not math.isfinite(u):
            notes.append("the evidence is flat at the fitted temperature: not constrained by the chart")
    light = make(t_best, wavelength_nm=wl)
    if math.isfinite(u):
        up = make(min(t_best + u, hi), wavelength_nm=wl).irradiance_w_m2_nm
        dn = make(max(t_best - u, lo), wavelength_nm=wl).irradiance_w_m2_nm
        pert = (0.5 * (up - dn))[None, :]
    else:
        pert = np.zeros((0, wl.size))
    light = Irradiance(wl, light.irradiance_w_m2_nm, pert, False,
                       {**light.source, "fitted": True, "u_K": u if math.isfinite(u) else None,
                        "method": "evidence maximised over the temperature, c marginalised (camcal.chart.recovery)"})
    rec = recover_sensitivity(signal, signal_cov, chart, light, basis, n_components=k,
                              regularisation=regularisation, nonnegative=nonnegative, absolute=False)
    return IlluminantEstimate(family, t_best, u, light, rec, grid, prof, tuple(notes))


def render_chart_signals(curves: np.ndarray, chart: ChartReflectance, light: Irradiance) -> np.ndarray:
    """(3, P) noiseless y_i,p = Σ_λ M_pλ c_i(λ) of (3, n) curves on the chart's grid (the forward model)."""
    return np.asarray(curves, float) @ design_matrix(chart, light).T


def leave_one_out_recovery(basis: CameraBasis, chart_true: ChartReflectance, chart_nominal: ChartReflectance,
                           light: Irradiance, *, n_components: int = DEFAULT_COMPONENTS,
                           regularisation: float | None = None, relative_noise: float = 0.003,
                           group: Literal["camera", "make"] = "camera", between_lab: bool = False,
                           cameras: tuple[str, ...] | None = None) -> list[dict[str, Any]]:
    """The whole recovery's error, camera by camera: each library camera's chart signals (rendered with
    ``chart_true``, noise-free, stated noise ``relative_noise`` of each signal) recovered assuming
    ``chart_nominal`` in a basis without that camera (``group`` ``"make"``: without every camera of its make,
    as for a camera unlike the library's). Rows: camera, channel, RMS error % of peak, fraction of wavelengths
    with |error| ≤ 2u, RMS u % of peak. ``cameras`` limits the cameras tested (default: all measured ones)."""
    rows = []
    reg = DEFAULT_REGULARISATION if regularisation is None else regularisation
    for j, name in enumerate(basis.cameras):
        if " × " in name or (cameras is not None and name not in cameras):  # a filter variant is not a camera
            continue
        make = name.split()[0]
        keep = [i for i, n in enumerate(basis.cameras)
                if n.split(" × ")[0] != name and not (group == "make" and n.split()[0] == make)]
        sub = _sub_basis(basis, keep)
        if any(n.split(" × ")[0] == name for n in sub.cameras):
            raise CamcalError(f"leave-one-out: {name} is still in the basis")
        true = basis.curves[j]
        y = render_chart_signals(true, chart_true, light)
        sig = {ch: y[i] for i, ch in enumerate(("R", "G", "B"))}
        cov = {ch: (relative_noise * y[i]) ** 2 for i, ch in enumerate(("R", "G", "B"))}
        rec = recover_sensitivity(sig, cov, chart_nominal, light, sub, n_components=n_components,
                                  regularisation=reg, between_lab=between_lab)
        unc = rec.uncertainty
        for i, ch in enumerate(("R", "G", "B")):
            err = rec.values[ch] - true[i]
            rows.append({"camera": name, "channel": ch, "rms_pct_of_peak": float(100 * np.sqrt(np.mean(err ** 2))),
                         "covered_2u": float(np.mean(np.abs(err) <= 2 * unc[ch])),
                         "u_rms_pct_of_peak": float(100 * np.sqrt(np.mean(unc[ch] ** 2)))})
    return rows


def _sub_basis(basis: CameraBasis, keep: list[int]) -> CameraBasis:
    return basis_from_curves(basis.curves[keep], tuple(basis.cameras[i] for i in keep), basis.wavelength_nm,
                             {**basis.source, "subset_of": basis.source.get("n_cameras")})

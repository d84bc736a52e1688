"""Forward models of a Lambertian disk in a water column (seed §1, §4), vectorised over C and d.

Every model is written in terms of the one-way vertical natural optical depth of the water above the
disk, τ = k d (k the natural absorption coefficient, m⁻¹; for chlorophyll alone k = ln(10) ε C). The
seed's eq. 10 and the refined model share one closed form (physics notes; Abramowitz & Stegun 5.1.4):

    ∫_0^θc e^(−x/cos θ) cos θ sin θ dθ = E₃(x) − μc² E₃(x/μc),   μc = cos θc,

so each model's ratio is  R(τ) = K · e^(−sτ) · I(mτ; μc),  I(x; μc) = E₃(x) − μc² E₃(x/μc)
(:class:`ClosedForm`), with derivative dI/dx = −E₂(x) + μc E₂(x/μc).

References
----------
Seed (Zaman 2018) eq. 10 and eq. 11; Abramowitz, M., Stegun, I. (1964), Handbook of Mathematical
Functions, §5.1 (exponential integrals E_n); Mobley, C. D. (1994), Light and Water, §4.3 (the n² law).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq
from scipy.special import expn

from camcal.water.optics import (
    N_WATER,
    critical_angle,
    gauss_legendre,
    hemispheric_transmittance,
    snell,
    transmittance,
)
from camcal.water.purewater import pure_water_absorption_per_m
from camcal.water.units import EPSILON_SEED_L_PER_MOL_CM, LN10

#: Seed §5: the cutoff angle of the simulations, π/2.1 rad.
SEED_CUTOFF_RAD = np.pi / 2.1
#: Pure-water absorption at 663 nm, m⁻¹, from the shipped Pope & Fry (1997) table (0.424 at 662.5 nm,
#: 0.429 at 665 nm → 0.425).
WATER_ABSORPTION_663_PER_M = float(pure_water_absorption_per_m(663.0))


def e3_integral(x, mu_c):
    """I(x; μc) = ∫_0^θc e^(−x/cos θ) cos θ sin θ dθ = E₃(x) − μc² E₃(x/μc)  (x ≥ 0, 0 < μc < 1)."""
    x = np.asarray(x, dtype=float)
    return expn(3, x) - mu_c * mu_c * expn(3, x / mu_c)


def e3_integral_derivative(x, mu_c):
    """dI/dx = −E₂(x) + μc E₂(x/μc) (negative: I decreases monotonically in x)."""
    x = np.asarray(x, dtype=float)
    return -expn(2, x) + mu_c * expn(2, x / mu_c)


@dataclass(frozen=True)
class ClosedForm:
    """R(τ) = scale · e^(−view_factor·τ) · I(path_factor·τ; mu_c): the shape shared by every model.

    scale : K (dimensionless); view_factor : s (1/cos of the in-water view angle, 0 for the seed);
    path_factor : m (2 for the seed's down-and-up path, 1 for the refined model's downward cone);
    mu_c : cos of the in-water cutoff angle.
    """

    scale: float
    view_factor: float
    path_factor: float
    mu_c: float

    def ratio(self, tau):
        """R(τ)."""
        tau = np.asarray(tau, dtype=float)
        return self.scale * np.exp(-self.view_factor * tau) * e3_integral(self.path_factor * tau, self.mu_c)

    def dlog_ratio_dtau(self, tau):
        """d ln R / dτ = −s + m I'(mτ)/I(mτ) (negative)."""
        x = self.path_factor * np.asarray(tau, dtype=float)
        return -self.view_factor + self.path_factor * e3_integral_derivative(x, self.mu_c) / e3_integral(x, self.mu_c)

    def ratio_derivative(self, tau):
        """dR/dτ."""
        return self.ratio(tau) * self.dlog_ratio_dtau(tau)

    @property
    def ratio_at_zero(self) -> float:
        """R(0) = K (1 − μc²)/2 (= ρ sin²θc for the seed)."""
        return float(self.scale * 0.5 * (1.0 - self.mu_c * self.mu_c))

    @property
    def slope_at_zero(self) -> float:
        """−d ln R/dτ at τ = 0: s + 2m/(1 + μc)."""
        return float(self.view_factor + 2.0 * self.path_factor / (1.0 + self.mu_c))



@functools.lru_cache(maxsize=32)
def _exact_nodes(mu_c: float, n_water: float, reflectance: str, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes μ on [μc, 1] (in-water cosines) and weights w·T_down(μ) (air→water Fresnel at the
    air-side angle of each refracted ray), read-only."""
    x, w = gauss_legendre(nodes)
    mu = 0.5 * (1 - mu_c) * x + 0.5 * (1 + mu_c)
    theta_air = np.arcsin(np.clip(n_water * np.sqrt(1 - mu * mu), 0, 1))
    wt = 0.5 * (1 - mu_c) * w * transmittance(theta_air, 1.0, n_water, reflectance)
    mu.flags.writeable = False
    wt.flags.writeable = False
    return mu, wt


@dataclass(frozen=True)
class ExactTransmittanceForm:
    """R(τ) = scale · e^(−view_factor·τ) · J(τ),  J(τ) = ∫_μc^1 T_down(μ) μ e^(−τ/μ) dμ  (μ = cos θ in water).

    The refined model with the Fresnel transmittance kept inside the angular integral (no mean T̄): J is
    evaluated by ``nodes``-point Gauss-Legendre quadrature in μ, and so is its derivative
    dJ/dτ = −∫ T_down e^(−τ/μ) dμ, so that forward and inverse use one function (round trip to 1e-12).
    Same interface as :class:`ClosedForm` (``ratio``, ``dlog_ratio_dtau``, ``ratio_at_zero``, ...);
    ``path_factor`` is 1 (one downward slant path).
    """

    scale: float
    view_factor: float
    mu_c: float
    n_water: float = N_WATER
    reflectance: str = "fresnel"
    nodes: int = 128

    path_factor = 1.0

    def _j(self, tau):
        mu, wt = _exact_nodes(self.mu_c, self.n_water, self.reflectance, self.nodes)
        e = np.exp(-np.asarray(tau, float)[..., None] / mu)
        return np.sum(wt * mu * e, axis=-1), -np.sum(wt * e, axis=-1)

    def ratio(self, tau):
        tau = np.asarray(tau, dtype=float)
        return self.scale * np.exp(-self.view_factor * tau) * self._j(tau)[0]

    def dlog_ratio_dtau(self, tau):
        j, dj = self._j(tau)
        return -self.view_factor + dj / j

    def ratio_derivative(self, tau):
        return self.ratio(tau) * self.dlog_ratio_dtau(tau)

    @property
    def ratio_at_zero(self) -> float:
        return float(self.ratio(0.0))

    @property
    def slope_at_zero(self) -> float:
        return float(-self.dlog_ratio_dtau(0.0))


@dataclass(frozen=True)
class ExponentialForm:
    """R(τ) = scale · e^(−view_factor·τ): a single straight path down and up (the point lamp, seed §4).

    Same interface as :class:`ClosedForm`; ``path_factor`` is 0 (no angular integral).
    """

    scale: float
    view_factor: float

    path_factor = 0.0

    def ratio(self, tau):
        return self.scale * np.exp(-self.view_factor * np.asarray(tau, dtype=float))

    def dlog_ratio_dtau(self, tau):
        return np.full(np.shape(tau), -self.view_factor)

    def ratio_derivative(self, tau):
        return -self.view_factor * self.ratio(tau)

    @property
    def ratio_at_zero(self) -> float:
        return float(self.scale)

    @property
    def slope_at_zero(self) -> float:
        return float(self.view_factor)


def form_at(model, depth_m: float):
    """The R(τ) form of ``model`` at one depth: ``model.closed_form_at(depth_m)`` for models whose geometry
    depends on the depth (:class:`LampModel`), else ``model.closed_form()``."""
    if hasattr(model, "closed_form_at"):
        return model.closed_form_at(float(depth_m))
    return model.closed_form()


def chlorophyll_tau(c_mol_per_L, depth_m, epsilon_L_per_mol_cm: float):
    """One-way natural optical depth of chlorophyll over depth d: τ = ln(10) ε C (100 d) (d in m → cm)."""
    return LN10 * epsilon_L_per_mol_cm * np.asarray(c_mol_per_L, dtype=float) * 100.0 * np.asarray(depth_m, float)


@dataclass(frozen=True)
class SeedModel:
    """The seed's eq. 10: L_i/L_s = 2ρ ∫_0^θc 10^(−2εdC/cos θ) cos θ sin θ dθ, evaluated exactly.

    epsilon_L_per_mol_cm : decadic molar absorption coefficient (default: the seed's 0.088 L mg⁻¹ cm⁻¹).
    albedo : ρ, the disk's albedo relative to the reference (seed §5 uses 1).
    cutoff_rad : θc (seed §5: π/2.1). No surface, no water absorption: the seed's assumptions.
    """

    epsilon_L_per_mol_cm: float = EPSILON_SEED_L_PER_MOL_CM
    albedo: float = 1.0
    cutoff_rad: float = SEED_CUTOFF_RAD

    name = "seed"
    includes_water = False  # the seed ignores water absorption

    def closed_form(self) -> ClosedForm:
        return ClosedForm(2.0 * self.albedo, 0.0, 2.0, float(np.cos(self.cutoff_rad)))

    def tau(self, c_mol_per_L, depth_m):
        return chlorophyll_tau(c_mol_per_L, depth_m, self.epsilon_L_per_mol_cm)

    def background_tau(self, depth_m):
        return np.zeros_like(np.asarray(depth_m, dtype=float))

    def ratio(self, c_mol_per_L, depth_m):
        """L_i/L_s (seed eq. 10) by the E₃ closed form."""
        return self.closed_form().ratio(self.tau(c_mol_per_L, depth_m))

    def ratio_first_order(self, c_mol_per_L, depth_m, theta0_rad: float = 0.0):
        """The seed's eq. 11 forward: ρ (cos²θ0 − cos²θc) 10^(−2εdC) (1/cos θ ≈ 1; sign corrected)."""
        attenuation = np.exp(-2.0 * self.tau(c_mol_per_L, depth_m))
        return self.albedo * (np.cos(theta0_rad) ** 2 - np.cos(self.cutoff_rad) ** 2) * attenuation

    def invert_first_order(self, ratio, depth_m, theta0_rad: float = 0.0):
        """The seed's eq. 11: C = −log10(L_i / (ρ L_s (cos²θ0 − cos²θc))) / (2 ε d), mol/L (d in cm)."""
        base = self.albedo * (np.cos(theta0_rad) ** 2 - np.cos(self.cutoff_rad) ** 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            return -np.log10(np.asarray(ratio, float) / base) / (
                2.0 * self.epsilon_L_per_mol_cm * 100.0 * np.asarray(depth_m, float))

    # ---- the seed's appendix (§6.1): the second-order (k, q) formula -------------------------------------
    def appendix_k_q(self, depth_m, theta0_rad: float = 0.0):
        """The appendix's angular constants: k = [−cos²θ/2]_θ0^θc = (cos²θ0 − cos²θc)/2 and
        q = ε d ln10 [(2θ sin 2θ + (1 − 2θ²) cos 2θ)/8]_θ0^θc (per mol/L; d in cm inside ε d).

        They come from expanding 10^(−2εdC/cos θ) ≈ 10^(−2εdC)(1 − εdC ln10 θ²) (1/cos θ ≈ 1 + θ²/2, correct to
        second order in θ) and integrating against cos θ sin θ (the antiderivative of θ² cos θ sin θ is right).
        """
        def f(t):
            return (2 * t * np.sin(2 * t) + (1 - 2 * t * t) * np.cos(2 * t)) / 8

        k = 0.5 * (np.cos(theta0_rad) ** 2 - np.cos(self.cutoff_rad) ** 2)
        j = f(self.cutoff_rad) - f(theta0_rad)
        q = self.epsilon_L_per_mol_cm * 100.0 * np.asarray(depth_m, float) * LN10 * j
        return float(k), q

    def ratio_second_order(self, c_mol_per_L, depth_m, theta0_rad: float = 0.0):
        """The appendix's forward model: L_i/L_s = 2ρ 10^(−2εdC) (k − Cq) (negative where Cq > k)."""
        k, q = self.appendix_k_q(depth_m, theta0_rad)
        c = np.asarray(c_mol_per_L, float)
        return 2 * self.albedo * np.exp(-2 * self.tau(c, depth_m)) * (k - c * q)

    def invert_appendix_as_written(self, ratio, depth_m, theta0_rad: float = 0.0):
        """The appendix's last line, as written: C = [ln(L_i 10^(2εd) / (2ρ L_s)) + k − 1] / (q − ln 10).

        Evaluated with ln(10^(2εd)) = 2εd ln10 (ε d in L/mol, so 10^(2εd) overflows). Errata (docs/water.md):
        its second line flips the exponent's sign; ln(k − Cq) is replaced by k − Cq − 1 (valid near 1, but
        k ≤ ½); the C of 10^(−2εdC) is lost, leaving 10^(2εd); the C-terms are collected wrongly (q − ln 10).
        The result is ≈ 2/J mol/L whatever the data (5.55 mol/L for θc = π/2.1, θ0 = 0).
        """
        k, q = self.appendix_k_q(depth_m, theta0_rad)
        ed = self.epsilon_L_per_mol_cm * 100.0 * np.asarray(depth_m, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            return (np.log(np.asarray(ratio, float) / (2 * self.albedo)) + 2 * ed * LN10 + k - 1) / (q - LN10)

    def invert_appendix_corrected(self, ratio, depth_m, theta0_rad: float = 0.0):
        """The appendix's intended algebra, corrected: ln(r/2ρ) = −2 ln10 εdC + ln(k − Cq) with the same
        linearisation ln(k − Cq) ≈ k − Cq − 1, solved for C: C = (k − 1 − ln(r/2ρ)) / (2 ln10 εd + q)."""
        k, q = self.appendix_k_q(depth_m, theta0_rad)
        ed = self.epsilon_L_per_mol_cm * 100.0 * np.asarray(depth_m, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            return (k - 1 - np.log(np.asarray(ratio, float) / (2 * self.albedo))) / (2 * LN10 * ed + q)

    def invert_second_order(self, ratio, depth_m, theta0_rad: float = 0.0):
        """The appendix's (k, q) model solved exactly: 2ρ 10^(−2εdC)(k − Cq) = r for C in [0, k/q) (the left
        side decreases monotonically there; Brent's method per value). NaN where r > 2ρk or r ≤ 0."""
        k, q = self.appendix_k_q(depth_m, theta0_rad)
        r, qq = np.broadcast_arrays(np.asarray(ratio, float), np.asarray(q, float))
        ed = np.broadcast_to(self.epsilon_L_per_mol_cm * 100.0 * np.asarray(depth_m, float), r.shape)
        out = np.full(r.shape, np.nan)
        for i in np.ndindex(r.shape):
            ri, qi, ei = float(r[i]), float(qq[i]), float(ed[i])
            if not (0 < ri <= 2 * self.albedo * k and qi > 0):
                continue

            def g(c, ri=ri, qi=qi, ei=ei):
                return -2 * LN10 * ei * c + np.log(max(k - c * qi, 1e-300)) - np.log(ri / (2 * self.albedo))

            out[i] = brentq(g, 0.0, k / qi, xtol=1e-30, rtol=1e-13)
        return out


@dataclass(frozen=True)
class RefinedModel:
    """Sky light refracted down, absorbed by water + chlorophyll + background, reflected by the disk,
    absorbed on the way up along the camera's view and refracted out (Fresnel both ways, the n² law).

    The ratio is camera radiance over the radiance of the same-albedo reference under the same uniform
    sky in air (L_ref = ρ_ref L_sky). With T̄ the cosine-weighted mean air→water transmittance of the sky
    cone and T_up the water→air transmittance along the view,

        R = 2ρ T̄ T_up e^(−τ/μv) [E₃(τ) − μw² E₃(τ/μw)],  τ = (a_w + a_bg + ln10 ε C) d,

    with μv, μw the cosines of the in-water view angle and of the in-water cutoff (the refracted sky
    cutoff, the critical angle 48.75° for a full sky). The n² factors cancel (n² in, 1/n² out).
    ``transmittance="exact"`` keeps T(θ) inside the angular integral (Gauss-Legendre), forward only.
    """

    epsilon_L_per_mol_cm: float = EPSILON_SEED_L_PER_MOL_CM
    albedo: float = 1.0
    n_water: float = N_WATER
    sky_cutoff_rad: float = np.pi / 2  # air-side zenith angle above which no sky light enters
    view_angle_rad: float = 0.0  # camera's air-side view angle from nadir
    water_absorption_per_m: float = WATER_ABSORPTION_663_PER_M
    background_absorption_per_m: float = 0.0  # CDOM, detritus: natural absorption, m⁻¹
    reflectance: str = "fresnel"  # or "schlick"
    transmittance: str = "mean"  # or "exact"

    name = "refined"
    includes_water = True  # band models default to Pope & Fry water


    def water_cutoff_rad(self) -> float:
        """In-water cutoff: the sky cutoff refracted (the critical angle for a full sky)."""
        if self.sky_cutoff_rad >= np.pi / 2:
            return critical_angle(self.n_water)
        return float(snell(self.sky_cutoff_rad, 1.0, self.n_water))

    def view_water_rad(self) -> float:
        return float(snell(self.view_angle_rad, 1.0, self.n_water))

    def transmittance_up(self) -> float:
        return float(transmittance(self.view_water_rad(), self.n_water, 1.0, self.reflectance))

    def transmittance_down_mean(self) -> float:
        return hemispheric_transmittance(min(self.sky_cutoff_rad, np.pi / 2), self.n_water, self.reflectance)

    def closed_form(self) -> ClosedForm | ExactTransmittanceForm:
        """R(τ): the E₃ closed form with the mean T̄ (``transmittance="mean"``), or the quadrature form with
        T(θ) inside the integral (``"exact"``), both invertible by :mod:`camcal.water.invert`."""
        mu_w = float(np.cos(self.water_cutoff_rad()))
        s = 1.0 / float(np.cos(self.view_water_rad()))
        if self.transmittance == "exact":
            return ExactTransmittanceForm(2.0 * self.albedo * self.transmittance_up(), s, mu_w, float(self.n_water),
                                          self.reflectance)
        if self.transmittance != "mean":
            raise ValueError(f"unknown transmittance {self.transmittance!r}; use 'mean' or 'exact'")
        k = 2.0 * self.albedo * self.transmittance_down_mean() * self.transmittance_up()
        return ClosedForm(k, s, 1.0, mu_w)

    def tau(self, c_mol_per_L, depth_m):
        return self.background_tau(depth_m) + chlorophyll_tau(c_mol_per_L, depth_m, self.epsilon_L_per_mol_cm)

    def background_tau(self, depth_m):
        return (self.water_absorption_per_m + self.background_absorption_per_m) * np.asarray(depth_m, dtype=float)

    def ratio(self, c_mol_per_L, depth_m):
        """Camera radiance over reference radiance."""
        return self.closed_form().ratio(self.tau(c_mol_per_L, depth_m))


@dataclass(frozen=True)
class LampModel:
    """Seed §4: a point lamp over a tank, a Lambertian disk at depth d, photographed submerged and dry.

    The lamp is at height H above the water surface (the seed's "height H above the disk" is H + d); its ray
    to the disk centre leaves at air zenith angle θa, refracts at the flat surface to β (sin θa = n sin β) and
    reaches the disk at horizontal distance X = H tan θa + d tan β from the lamp's foot. Ray-tube irradiance
    through the interface (horizontal disk, per unit lamp intensity I₀):

        E_w = T(θa) e^(−τ/cos β) sin θa / (X dX/dθa),   dX/dθa = H/cos²θa + d cos θa/(n cos³β)

    (→ T(0)/(H + d/n)² at normal incidence); the same disk in the empty tank, same place, same lamp:
    E_air = (H + d)/(X² + (H + d)²)^(3/2). The disk's radiance leaves the water along the camera's view (μv
    in water) with T_up/n² and e^(−τ/μv). So the ratio submerged/dry is a single exponential in τ:

        R(τ) = K(d) e^(−s τ),  K = ρ (E_w/E_air)|_(τ=0) T_up/n²,  s = 1/cos β + 1/μv,

    with τ = (a_w + a_bg + ln10 ε C) d as in :class:`RefinedModel`. :meth:`closed_form_at` gives it as an
    :class:`ExponentialForm` (inverted exactly like the other models). The geometry is that of the disk
    **centre**: every pixel is inverted with K and s of the centre (docs/water.md gives the cost).
    """

    height_m: float = 1.0
    lamp_angle_rad: float = 0.0
    epsilon_L_per_mol_cm: float = EPSILON_SEED_L_PER_MOL_CM
    albedo: float = 1.0  # submerged disk over dry disk (the same disk: 1)
    n_water: float = N_WATER
    view_angle_rad: float = 0.0  # camera's air-side view angle from nadir
    water_absorption_per_m: float = WATER_ABSORPTION_663_PER_M
    background_absorption_per_m: float = 0.0
    reflectance: str = "fresnel"

    name = "lamp"
    includes_water = True

    def refracted_angle_rad(self) -> float:
        """β, the in-water angle of the lamp's ray (sin θa = n sin β)."""
        return float(snell(self.lamp_angle_rad, 1.0, self.n_water))

    def view_water_rad(self) -> float:
        return float(snell(self.view_angle_rad, 1.0, self.n_water))

    def transmittance_up(self) -> float:
        return float(transmittance(self.view_water_rad(), self.n_water, 1.0, self.reflectance))

    def path_factor(self) -> float:
        """s = 1/cos β + 1/μv: slant path lengths down and up per unit depth."""
        return 1.0 / np.cos(self.refracted_angle_rad()) + 1.0 / np.cos(self.view_water_rad())

    def horizontal_offset_m(self, depth_m):
        """X, the disk centre's horizontal distance from the lamp's foot, m."""
        return self.height_m * np.tan(self.lamp_angle_rad) + np.asarray(depth_m, float) * np.tan(
            self.refracted_angle_rad())

    def geometry_factor(self, depth_m):
        """K(d) = ρ (E_w/E_air) T_up/n² at τ = 0 (vectorised over d)."""
        n, h, a = self.n_water, float(self.height_m), float(self.lamp_angle_rad)
        d = np.asarray(depth_m, dtype=float)
        b = self.refracted_angle_rad()
        t_down = float(transmittance(a, 1.0, n, self.reflectance))
        if a == 0.0:
            e_water = t_down / (h + d / n) ** 2
            x = np.zeros_like(d)
        else:
            x = self.horizontal_offset_m(d)
            dx = h / np.cos(a) ** 2 + d * np.cos(a) / (n * np.cos(b) ** 3)
            e_water = t_down * np.sin(a) / (x * dx)
        hd = h + d
        e_air = hd / (x * x + hd * hd) ** 1.5
        return self.albedo * e_water / e_air * self.transmittance_up() / (n * n)


    def closed_form_at(self, depth_m: float) -> ExponentialForm:
        return ExponentialForm(float(self.geometry_factor(depth_m)), float(self.path_factor()))

    def tau(self, c_mol_per_L, depth_m):
        return self.background_tau(depth_m) + chlorophyll_tau(c_mol_per_L, depth_m, self.epsilon_L_per_mol_cm)

    def background_tau(self, depth_m):
        return (self.water_absorption_per_m + self.background_absorption_per_m) * np.asarray(depth_m, dtype=float)

    def ratio(self, c_mol_per_L, depth_m):
        """Camera radiance of the submerged disk over that of the dry disk (broadcast over C and d)."""
        return self.geometry_factor(depth_m) * np.exp(-self.path_factor() * self.tau(c_mol_per_L, depth_m))


def lamp_angle_reaching(height_m: float, depth_m: float, horizontal_m: float, n_water: float = N_WATER) -> float:
    """Air zenith angle α (rad) of the lamp ray that reaches depth d at horizontal distance X from the lamp's
    foot: H tan α + d tan β(α) = X (monotone in α; Brent's method)."""
    if horizontal_m <= 0:
        return 0.0

    def miss(a: float) -> float:
        return height_m * np.tan(a) + depth_m * np.tan(float(snell(a, 1.0, n_water))) - horizontal_m

    return float(brentq(miss, 0.0, np.radians(89.99), xtol=1e-15, rtol=1e-15))


def lamp_ratio(c_mol_per_L, depth_m, height_m: float, lamp_angle_rad: float, model: RefinedModel | None = None):
    """:meth:`LampModel.ratio` with the optics (n, absorption, view angle, reflectance) of ``model``."""
    m = model or RefinedModel()
    lamp = LampModel(float(height_m), float(lamp_angle_rad), m.epsilon_L_per_mol_cm, m.albedo, m.n_water,
                     m.view_angle_rad, m.water_absorption_per_m, m.background_absorption_per_m, m.reflectance)
    return lamp.ratio(c_mol_per_L, depth_m)

"""Tests of :mod:`camcal.water.optics`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from camcal.water.models import RefinedModel
from camcal.water.optics import schlick_reflectance
from tests.helpers import N_WATER, fresnel_t_from_air, schlick_t_from_air


def _render_refined(c_mol_per_L, depth_m, *, view_air_rad, a_bg_per_m, a_w_per_m, eps, exact: bool, albedo=1.0,
                    sky_cutoff_rad=np.pi / 2, n=N_WATER, reflectance="fresnel"):
    """Radiance ratio of a Lambertian disk under a uniform sky (air zenith angles up to ``sky_cutoff_rad``),
    rendered by quadrature over the refracted cone in the water.

    Downwelling: in-water radiance n² T(θa) L_sky in the refracted cone; the disk (albedo ρ) reflects ρE/π with
    E = ∫ L e^(−τ/μ) μ dΩ; upwelling along the view T(θa,view)/n² e^(−τ/μv); the reference is a white disk in air
    under the same sky, radiance L_sky. With ``exact`` False the sky's T(θ) is replaced by its cosine-weighted
    mean over the sky's air angles (what the closed form does).
    """
    t_air = fresnel_t_from_air if reflectance == "fresnel" else schlick_t_from_air
    tau = (a_w_per_m + a_bg_per_m + np.log(10) * eps * c_mol_per_L * 100) * depth_m
    theta_c = np.arcsin(np.sin(sky_cutoff_rad) / n)
    tbar = quad(lambda a: t_air(a, n) * np.cos(a) * np.sin(a), 0, sky_cutoff_rad, epsabs=0, epsrel=1e-12,
                limit=200)[0] / (0.5 * np.sin(sky_cutoff_rad) ** 2)

    def t_down(theta_w):
        return t_air(np.arcsin(min(n * np.sin(theta_w), 1.0)), n) if exact else tbar

    e = 2 * np.pi * quad(lambda th: n * n * t_down(th) * np.exp(-tau / np.cos(th)) * np.cos(th) * np.sin(th),
                         0, theta_c, epsabs=0, epsrel=1e-12, limit=200)[0]
    mu_v = np.sqrt(1 - (np.sin(view_air_rad) / n) ** 2)
    return albedo * e / np.pi * t_air(view_air_rad, n) / (n * n) * np.exp(-tau / mu_v)


@pytest.mark.formula
@pytest.mark.parametrize("transmittance", ["mean", "exact"])
@pytest.mark.parametrize("optics", ["full sky, Fresnel", "sky cone of 1.1 rad, Schlick, n = 1.34, albedo 0.7"])
def test_refined_model_off_nadir_with_chlorophyll_matches_a_rendering(transmittance, optics):
    """Off nadir (0.6 rad), C = 2e-7 mol/L, background absorption: the E₃ closed form (or the Gauss-Legendre
    form) against the radiance transfer integrated by adaptive quadrature; also with a sky cone narrower than the
    hemisphere, Schlick's reflectance, another refractive index and a grey disk.

    Tolerance: 1e-9 for the closed form (exact in E₃); 1e-6 for the Gauss-Legendre form, whose 128 nodes in μ
    converge slowly on T(θ)'s square-root edge at the critical angle (measured 1.6e-7).
    """
    extra = {} if optics.startswith("full") else dict(albedo=0.7, sky_cutoff_rad=1.1, n_water=1.34,
                                                       reflectance="schlick")
    m = RefinedModel(transmittance=transmittance, view_angle_rad=0.6, background_absorption_per_m=0.3,
                     water_absorption_per_m=0.425, **extra)
    render = {k if k != "n_water" else "n": v for k, v in extra.items()}
    for c, d in ((2e-7, 0.25), (5e-8, 0.6)):
        expect = _render_refined(c, d, view_air_rad=0.6, a_bg_per_m=0.3, a_w_per_m=0.425,
                                 eps=m.epsilon_L_per_mol_cm, exact=transmittance == "exact", **render)
        assert float(m.ratio(c, d)) == pytest.approx(expect, rel=1e-9 if transmittance == "mean" else 1e-6)


@pytest.mark.formula
def test_schlick_from_the_water_side_uses_the_air_side_angle():
    """Schlick from below (n1 > n2) is R0 + (1 − R0)(1 − cos θ_air)⁵ with θ_air from Snell, so it equals Schlick
    from above at that angle (reciprocity); R0 = ((n − 1)/(n + 1))² = 0.02006 for n = 1.33."""
    r0 = (0.33 / 2.33) ** 2
    for theta_w in (0.3, 0.6, 0.8):
        theta_a = np.arcsin(N_WATER * np.sin(theta_w))
        expect = r0 + (1 - r0) * (1 - np.cos(theta_a)) ** 5
        assert float(schlick_reflectance(theta_w, N_WATER, 1.0)) == pytest.approx(expect, rel=1e-12)
        assert float(schlick_reflectance(theta_a, 1.0, N_WATER)) == pytest.approx(expect, rel=1e-12)
    # the refined model with Schlick: T_up at an oblique view from the air-side angle
    view = 0.9
    expect = 1 - (r0 + (1 - r0) * (1 - np.cos(view)) ** 5)
    assert RefinedModel(view_angle_rad=view, reflectance="schlick").transmittance_up() == pytest.approx(expect)

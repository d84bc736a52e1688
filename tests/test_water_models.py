"""Water module: surface optics, the E₃ closed form, the forward models (physics notes reference values)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from camcal.water.models import RefinedModel, SeedModel, e3_integral, e3_integral_derivative, lamp_ratio
from camcal.water.optics import (
    critical_angle,
    fresnel_reflectance,
    hemispheric_transmittance,
    schlick_r0,
    schlick_reflectance,
    snell,
)
from camcal.water.units import (
    EPSILON_SEED_L_PER_MOL_CM,
    mol_per_L_to_ug_per_L,
    parse_concentration_mol_per_L,
    parse_epsilon_L_per_mol_cm,
    parse_length_m,
)
from tests.oracles import refined_at_wavelength


def test_fresnel_and_schlick_reference_values():
    # physics notes: air-side 40/53/80/85 deg, n = 1.33 (quoted to 3 significant figures)
    ang = np.radians([40, 53, 80, 85])
    np.testing.assert_allclose(fresnel_reflectance(ang), [0.0242, 0.0384, 0.347, 0.583], atol=6e-4)
    np.testing.assert_allclose(schlick_reflectance(ang), [0.0207, 0.0299, 0.398, 0.641], atol=6e-4)
    assert schlick_r0() == pytest.approx(0.0201, abs=1e-4)
    assert np.degrees(critical_angle()) == pytest.approx(48.75, abs=0.01)
    assert hemispheric_transmittance() == pytest.approx(0.934, abs=1e-3)


def test_total_internal_reflection_from_below():
    below = np.radians([30.0, 48.0, 49.0, 70.0])
    r = fresnel_reflectance(below, 1.33, 1.0)
    assert np.all(r[2:] == 1.0) and np.all(r[:2] < 0.5)
    assert np.all(schlick_reflectance(below, 1.33, 1.0)[2:] == 1.0)
    assert np.isnan(snell(np.radians(60.0), 1.33, 1.0))
    # Snell round trip
    t = snell(np.radians(35.0))
    assert float(snell(t, 1.33, 1.0)) == pytest.approx(np.radians(35.0), rel=1e-12)


def test_closed_form_reference_values():
    assert e3_integral(1.0, np.cos(np.radians(48.6))) == pytest.approx(0.0852629829471, rel=1e-11)
    assert e3_integral(0.5, np.cos(np.radians(48.6))) == pytest.approx(0.154493621161, rel=1e-11)
    assert e3_integral(2.0, np.cos(np.radians(80.0))) == pytest.approx(0.0301333588536, rel=1e-11)


@pytest.mark.parametrize("theta_c_deg", [5.0, 30.0, 48.75, 70.0, 85.7, 89.0])
def test_closed_form_equals_quadrature(theta_c_deg):
    tc = np.radians(theta_c_deg)
    mu = np.cos(tc)
    for a in np.logspace(-6, np.log10(20.0), 9):
        ref = quad(lambda t, a=a: np.exp(-a / np.cos(t)) * np.cos(t) * np.sin(t), 0, tc, epsabs=0, epsrel=1e-13,
                   limit=200)[0]
        assert e3_integral(a, mu) == pytest.approx(ref, rel=1e-10)
        h = 1e-6 * max(a, 1e-3)
        num = (e3_integral(a + h, mu) - e3_integral(a - h, mu)) / (2 * h) if a > h else None
        if num is not None:
            assert e3_integral_derivative(a, mu) == pytest.approx(num, rel=1e-5)


def test_seed_model_limits():
    m = SeedModel()
    assert m.ratio(0.0, 0.2) == pytest.approx(np.sin(np.pi / 2.1) ** 2, rel=1e-14)  # C = 0: ρ sin²θc
    assert SeedModel(albedo=0.5).ratio(0.0, 0.3) == pytest.approx(0.5 * np.sin(np.pi / 2.1) ** 2, rel=1e-14)
    # first order (eq. 11) is exact only at C = 0
    assert m.ratio_first_order(0.0, 0.2) == pytest.approx(m.ratio(0.0, 0.2), rel=1e-14)
    c = np.array([1e-8, 1e-7])
    assert np.all(m.invert_first_order(m.ratio_first_order(c, 0.2), 0.2) == pytest.approx(c, rel=1e-12))


def test_seed_section5_range():
    # physics notes: the seed's §5 range spans ≈0.55 … ≈2e-5
    m = SeedModel()
    assert m.ratio(1e-7, 0.10) == pytest.approx(0.55, abs=0.01)
    assert m.ratio(5e-7, 0.50) == pytest.approx(2e-5, rel=0.05)


def test_seed_path_is_down_and_up():
    """Eq. 10's light goes down to the disk and back up: e^(−2τ/cos θ) in the integral (path factor 2). Given τ,
    so that only the path factor is under test (the chlorophyll τ has its own test below)."""
    m = SeedModel(albedo=0.8)
    tc = m.cutoff_rad
    for tau in (0.05, 0.7, 2.5):
        ref = 2 * 0.8 * quad(lambda t, tau=tau: np.exp(-2 * tau / np.cos(t)) * np.cos(t) * np.sin(t), 0, tc,
                             epsabs=0, epsrel=1e-13, limit=200)[0]
        assert m.closed_form().ratio(tau) == pytest.approx(ref, rel=1e-10)


def test_seed_eq10_and_eq11_against_their_decadic_forms():
    """End to end at C ≠ 0: eq. 10 by quadrature in the seed's own decadic form 2ρ∫10^(−2A/cos θ) cos θ sin θ dθ,
    and eq. 11's first order ρ (1 − cos²θc) 10^(−2A), A = ε C d the decadic absorbance of one vertical pass
    (d in cm). Fails with any of the three errors above."""
    m = SeedModel(albedo=0.8)
    c, d = 2e-7, 0.3
    a = EPSILON_SEED_L_PER_MOL_CM * c * d * 100
    ref = 2 * 0.8 * quad(lambda t: 10 ** (-2 * a / np.cos(t)) * np.cos(t) * np.sin(t), 0, m.cutoff_rad, epsabs=0,
                         epsrel=1e-13, limit=200)[0]
    assert m.ratio(c, d) == pytest.approx(ref, rel=1e-10)
    expect = 0.8 * (1 - np.cos(m.cutoff_rad) ** 2) * 10 ** (-2 * a)
    assert m.ratio_first_order(c, d) == pytest.approx(expect, rel=1e-12)


def test_chlorophyll_optical_depth_is_natural_log_of_the_decadic_absorbance():
    """τ is natural: e^(−τ) = 10^(−εCd) (Beer-Lambert with decadic ε, d in cm), for the seed model and the
    refined model's chlorophyll part."""
    c, d = 3e-7, 0.4
    a = EPSILON_SEED_L_PER_MOL_CM * c * d * 100
    assert np.exp(-SeedModel().tau(c, d)) == pytest.approx(10 ** (-a), rel=1e-12)
    rm = RefinedModel(water_absorption_per_m=0.0)
    assert np.exp(-rm.tau(c, d)) == pytest.approx(10 ** (-a), rel=1e-12)


def test_chlorophyll_a_molar_mass_from_standard_atomic_weights():
    """C55H72MgN4O5 from the IUPAC abridged standard atomic weights (2021): 893.51 g/mol."""
    mass = 55 * 12.011 + 72 * 1.008 + 24.305 + 4 * 14.007 + 5 * 15.999
    assert mass == pytest.approx(893.509, abs=1e-3)
    # 1e-7 mol/L of chlorophyll-a is 89.35 µg/L (1e6 µg per g)
    assert float(mol_per_L_to_ug_per_L(1e-7)) == pytest.approx(1e-7 * mass * 1e6, rel=2e-5)
    assert parse_concentration_mol_per_L("10ug/L") == pytest.approx(10e-6 / mass, rel=2e-5)
    # the seed's ε, 88 L g⁻¹ cm⁻¹, per mole
    assert EPSILON_SEED_L_PER_MOL_CM == pytest.approx(88.0 * mass, rel=2e-5)


def test_refined_model_c0_is_rho_over_n2_times_transmittances():
    rm = RefinedModel(water_absorption_per_m=0.0)
    # C = 0, no water absorption: ρ T̄ T_up sin²θcrit = ρ T̄ T_up / n²
    expect = rm.transmittance_down_mean() * rm.transmittance_up() / 1.33**2
    assert rm.ratio(0.0, 0.2) == pytest.approx(expect, rel=1e-12)
    # the mean-T closed form vs keeping T(θ) inside the integral: T varies < 7 % over the cone, and the
    # weighting shifts to steep rays as τ grows; measured 1.6 % at τ ≈ 3 (docs/water.md)
    exact = RefinedModel(transmittance="exact")
    c = np.array([0.0, 1e-8, 1e-7, 3e-7])
    np.testing.assert_allclose(RefinedModel().ratio(c, 0.3), exact.ratio(c, 0.3), rtol=0.02)


def test_lamp_model_normal_incidence_and_monotone():
    rm = RefinedModel(water_absorption_per_m=0.0)
    h, d = 0.5, 0.2
    t = 1 - fresnel_reflectance(0.0)
    # normal incidence, C = 0: E ratio (H+d)²/(H+d/n)², times T_down T_up / n²
    expect = (h + d) ** 2 / (h + d / 1.33) ** 2 * t * t / 1.33**2
    assert lamp_ratio(0.0, d, h, 0.0, rm) == pytest.approx(expect, rel=1e-12)
    # small angle approaches normal incidence (the ray-tube Jacobian is continuous)
    assert lamp_ratio(0.0, d, h, 1e-5, rm) == pytest.approx(expect, rel=1e-6)
    r = lamp_ratio(np.array([0.0, 1e-7, 3e-7]), d, h, 0.4, rm)
    assert np.all(np.diff(r) < 0)


def test_units():
    assert parse_length_m("20cm") == pytest.approx(0.2)
    assert parse_length_m("0.2m") == pytest.approx(0.2)
    assert parse_concentration_mol_per_L("89.35ug/L") == pytest.approx(1e-7)
    assert parse_concentration_mol_per_L("1e-7mol/L") == pytest.approx(1e-7)
    assert float(mol_per_L_to_ug_per_L(1e-7)) == pytest.approx(89.35)
    assert parse_epsilon_L_per_mol_cm("88L/g/cm") == pytest.approx(EPSILON_SEED_L_PER_MOL_CM)
    assert parse_epsilon_L_per_mol_cm("0.088L/mg/cm") == pytest.approx(EPSILON_SEED_L_PER_MOL_CM)
    assert parse_epsilon_L_per_mol_cm("porra1989") == pytest.approx(85.96 * 893.5)


def test_pope_fry_1997_table():
    from camcal.water.models import WATER_ABSORPTION_663_PER_M
    from camcal.water.purewater import pope_fry_1997, pure_water_absorption_per_m

    wl, a = pope_fry_1997()
    # the full published table: 380-727.5 nm every 2.5 nm, m^-1
    assert wl.size == 140 and wl[0] == 380.0 and wl[-1] == 727.5 and np.all(np.diff(wl) == 2.5)
    # values quoted in the physics notes and the paper's minimum (0.0044 m^-1 near 418 nm)
    np.testing.assert_allclose(pure_water_absorption_per_m([660.0, 662.5, 665.0]), [0.410, 0.424, 0.429])
    assert wl[np.argmin(a)] == 417.5 and a.min() == pytest.approx(0.00442)
    assert pure_water_absorption_per_m(440.0) == pytest.approx(0.00635)
    assert pure_water_absorption_per_m(800.0) == a[-1]  # held beyond the table
    assert WATER_ABSORPTION_663_PER_M == pytest.approx(0.425, abs=1e-12)
    assert RefinedModel().water_absorption_per_m == WATER_ABSORPTION_663_PER_M
    assert refined_at_wavelength(680.0).water_absorption_per_m == pytest.approx(0.465)


def test_seed_appendix_second_order_formula():
    """The appendix (§6.1): its (k, q) model checked by quadrature, its last line as written and corrected."""
    from scipy.integrate import quad

    from camcal.water.simulate import appendix_comparison

    m = SeedModel()
    d, c, tc = 0.2, 1e-7, m.cutoff_rad
    k, q = m.appendix_k_q(d)
    assert k == pytest.approx(0.5 * np.sin(tc) ** 2)
    ed = m.epsilon_L_per_mol_cm * 20.0  # ε d, d in cm
    # q/(ε d ln10) = ∫ θ² cos θ sin θ dθ over [0, θc]: the appendix's antiderivative is right
    j = quad(lambda t: t * t * np.cos(t) * np.sin(t), 0, tc, epsabs=0, epsrel=1e-13)[0]
    assert q == pytest.approx(ed * np.log(10) * j, rel=1e-12)
    # its forward model is eq. 10 with the integrand expanded to second order in θ
    second = 2 * quad(lambda t: 10 ** (-2 * ed * c) * (1 - ed * c * np.log(10) * t * t) * np.cos(t) * np.sin(t),
                      0, tc, epsabs=0, epsrel=1e-13)[0]
    assert m.ratio_second_order(c, d) == pytest.approx(second, rel=1e-10)
    # solved exactly, the (k, q) model inverts itself; read on exact eq. 10 data it is off by +9.4 % here
    assert m.invert_second_order(m.ratio_second_order(c, d), d) == pytest.approx(c, rel=1e-10)
    r = m.ratio(c, d)
    assert m.invert_second_order(r, d) / c - 1 == pytest.approx(0.094, abs=0.001)
    # the last line as written returns ≈ 2/J mol/L whatever the ratio (10^(2εd) dominates)
    for rr in (r, 0.5 * r, 1e-3):
        assert m.invert_appendix_as_written(rr, d) == pytest.approx(2 / j, rel=1e-4)
    # the corrected algebra inverts the linearised model ln(r/2) = −2 ln10 εdC + (k − Cq − 1) exactly
    lin = 2 * np.exp(-2 * np.log(10) * ed * c + k - c * q - 1)
    assert m.invert_appendix_corrected(lin, d) == pytest.approx(c, rel=1e-12)
    rows = appendix_comparison(m)
    assert len(rows) == 20 and all(row["error_eq11"] > 0 for row in rows)

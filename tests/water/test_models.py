"""Water module: surface optics, the E₃ closed form, the forward models (physics notes reference values)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from camcal.water.band import BandModel, ChlorophyllAbsorption
from camcal.water.models import LampModel, RefinedModel, SeedModel, e3_integral, e3_integral_derivative, lamp_ratio
from camcal.water.optics import (
    critical_angle,
    fresnel_reflectance,
    hemispheric_transmittance,
    schlick_r0,
    schlick_reflectance,
    snell,
    transmittance,
)
from camcal.water.uncertainty import (
    Uncertain,
    uncertainty_terms,
)
from camcal.water.units import (
    CHLA_MOLAR_MASS_G_PER_MOL,
    EPSILON_SEED_L_PER_MOL_CM,
    mol_per_L_to_ug_per_L,
    parse_concentration_mol_per_L,
    parse_epsilon_L_per_mol_cm,
    parse_length_m,
)
from tests.helpers import _BAND_WL, BAND_C, BAND_WL, N_WATER, _band_profile, fresnel_t_from_air, schlick_t_from_air
from tests.oracles import (
    lamp_toward,
    refined_at_wavelength,
)

#: Every test here is a fast formula test (the mutation-testing selection, docs/testing.md).
pytestmark = pytest.mark.formula


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


def test_lamp_height_and_angle_terms_from_models_built_at_the_changed_geometry():
    """The lamp's height (m) and angle (degrees) enter through models built with that height or angle (radians):
    σ_C = |∂B/∂p| σ_p / |∂B/∂C|, ∂B/∂p from lamp models built here at p ± σ/2, ∂B/∂C from the closed form."""
    model = LampModel(1.0, np.radians(20.0), water_absorption_per_m=0.0)
    depth, c = 0.3, np.array([60.0, 250.0])
    mol = c / (CHLA_MOLAR_MASS_G_PER_MOL * 1e6)
    inputs = [Uncertain("lamp_height", 1.0, 0.02, "m"), Uncertain("lamp_angle", 20.0, 2.0, "deg")]
    terms = uncertainty_terms(model, depth, c, inputs)
    tau = np.log(10) * model.epsilon_L_per_mol_cm * mol * 100 * depth
    db_dc = model.closed_form_at(depth).ratio_derivative(tau) * tau / c
    hi, lo = LampModel(1.01, np.radians(20.0), water_absorption_per_m=0.0), LampModel(
        0.99, np.radians(20.0), water_absorption_per_m=0.0)
    db_dh = (hi.ratio(mol, depth) - lo.ratio(mol, depth)) / 0.02
    np.testing.assert_allclose(terms["lamp_height"], np.abs(db_dh / db_dc) * 0.02, rtol=1e-3)
    hi, lo = (LampModel(1.0, np.radians(a), water_absorption_per_m=0.0) for a in (21.0, 19.0))
    db_da = (hi.ratio(mol, depth) - lo.ratio(mol, depth)) / 2.0
    np.testing.assert_allclose(terms["lamp_angle"], np.abs(db_da / db_dc) * 2.0, rtol=1e-3)
    assert np.all(terms["lamp_height"] > 0) and np.all(terms["lamp_angle"] > 0)


def test_band_model_of_a_profile_takes_the_channel_its_uncertainty_and_the_options():
    """c(λ) of a plane or of G = (G1 + G2)/2, σ_c of that plane or σ_G = ½ √(σ_G1² + σ_G2²), the profile's grid,
    and the options (geometry, chlorophyll, an illuminant array, water and background absorption) passed on as
    given."""
    from camcal.water.band import band_model_from_profile
    from camcal.water.models import SeedModel

    prof = _band_profile()
    v, u = prof.spectral.values, prof.spectral.uncertainty
    seed = SeedModel()
    chl = ChlorophyllAbsorption(np.array([400.0, 700.0]), np.array([0.02, 0.01]), np.array([0.9, 1.0]), "mine")
    s = np.linspace(0.2, 1.0, _BAND_WL.size)
    for ch, c, sig in (("G", 0.5 * (v["G1"] + v["G2"]), 0.5 * np.sqrt(u["G1"] ** 2 + u["G2"] ** 2)),
                       ("G2", v["G2"], u["G2"]), ("R", v["R"], u["R"]), ("B", v["B"], u["B"])):
        bm = band_model_from_profile(prof, ch, geometry=seed, chlorophyll=chl, illuminant=s,
                                     water_absorption_per_m=0.3, background_absorption_per_m=0.05)
        np.testing.assert_array_equal(bm.wavelengths_nm, _BAND_WL)
        np.testing.assert_allclose(bm.sensitivity, c, rtol=1e-15, err_msg=ch)
        np.testing.assert_allclose(bm.sensitivity_sigma, sig, rtol=1e-15, err_msg=ch)
        assert bm.geometry is seed and bm.chlorophyll is chl and bm.illuminant is s
        assert bm.water_absorption_per_m == 0.3 and bm.background_absorption_per_m == 0.05
    bm = band_model_from_profile(prof, "G1", illuminant=None)
    np.testing.assert_array_equal(bm.sensitivity, v["G1"])
    np.testing.assert_array_equal(bm.sensitivity_sigma, u["G1"])
    assert isinstance(bm.geometry, RefinedModel) and bm.geometry == RefinedModel()
    assert bm.chlorophyll is None and bm.illuminant is None and bm.water_absorption_per_m is None
    assert bm.background_absorption_per_m == 0.0


@pytest.mark.parametrize("geometry", [SeedModel(), RefinedModel(view_angle_rad=0.4, albedo=0.8),
                                      RefinedModel(view_angle_rad=0.4, transmittance="mean")],
                         ids=["seed", "refined-exact", "refined-mean"])
def test_band_ratio_derivative_against_central_differences(geometry):
    """dB/dC at C = 12 µg/L, d = 0.6 m, against (B(C+h) − B(C−h))/2h with h = 1e-3 C (error ~h² ≈ 1e-7 relative),
    through both of ratio_and_derivative's branches (the E₃ closed form, and a form with its own derivative)."""
    model = BandModel(BAND_WL, BAND_C, geometry=geometry, background_absorption_per_m=0.02)
    c, d, h = 12.0, 0.6, 0.012
    numeric = (float(model.ratio(c + h, d)) - float(model.ratio(c - h, d))) / (2 * h)
    b, db = model.ratio_and_derivative(c, d)
    assert float(db) == pytest.approx(numeric, rel=1e-5)
    assert float(model.ratio_derivative(c, d)) == pytest.approx(numeric, rel=1e-5)
    assert float(b) == pytest.approx(float(model.ratio(c, d)), rel=1e-12)


@pytest.mark.parametrize("view_air_rad", [0.5, 1.0])
def test_upward_transmittance_at_oblique_views_is_fresnel_from_air_by_reciprocity(view_air_rad):
    """T_up of the water-leaving ray seen by a camera at air angle θa = the air→water T at θa (reciprocity).

    Both models; at 1 rad the swapped-index formula gives 0.9762 instead of 0.9507 (2.7 %).
    """
    expect = fresnel_t_from_air(view_air_rad)
    assert float(transmittance(view_air_rad)) == pytest.approx(expect, rel=1e-12)  # defaults: air → water, Fresnel
    assert RefinedModel(view_angle_rad=view_air_rad).transmittance_up() == pytest.approx(expect, rel=1e-12)
    assert LampModel(view_angle_rad=view_air_rad).transmittance_up() == pytest.approx(expect, rel=1e-12)


def test_seed_appendix_inversions_off_axis_with_an_albedo():
    """The seed's first-order and appendix inversions with an albedo of 0.7 at θ0 = 0.3 rad (with ρ = 1 at nadir,
    2ρ and 2/ρ agree and θ0 drops out), against the formulas written out here from their docstrings: the
    first-order ratio ρ(cos²θ0 − cos²θc)·10^(−2εdC); k = (cos²θ0 − cos²θc)/2 and
    q = εd ln10 [(2θ sin 2θ + (1 − 2θ²) cos 2θ)/8] from θ0 to θc; the second-order ratio 2ρ 10^(−2εdC)(k − Cq)
    solved back to C (Brent's method to 1e-13: rel 1e-10), with its limits r ∈ (0, 2ρk] and q > 0."""
    m = SeedModel(albedo=0.7)
    th0, d, c = 0.3, 0.2, np.array([1e-7, 3e-7])
    ed = m.epsilon_L_per_mol_cm * 100.0 * d  # ε d, d in cm
    cc = np.cos(th0) ** 2 - np.cos(m.cutoff_rad) ** 2
    r1 = 0.7 * cc * 10.0 ** (-2 * ed * c)
    np.testing.assert_allclose(m.invert_first_order(r1, d, th0), c, rtol=1e-12)

    def f(t):
        return (2 * t * np.sin(2 * t) + (1 - 2 * t * t) * np.cos(2 * t)) / 8

    k = cc / 2
    q = ed * np.log(10) * (f(m.cutoff_rad) - f(th0))
    r2 = 2 * 0.7 * 10.0 ** (-2 * ed * c) * (k - c * q)
    np.testing.assert_allclose(m.invert_second_order(r2, d, th0), c, rtol=1e-10)
    written = (np.log(r2 / 1.4) + 2 * ed * np.log(10) + k - 1) / (q - np.log(10))
    np.testing.assert_allclose(m.invert_appendix_as_written(r2, d, th0), written, rtol=1e-12)
    corrected = (k - 1 - np.log(r2 / 1.4)) / (2 * np.log(10) * ed + q)
    np.testing.assert_allclose(m.invert_appendix_corrected(r2, d, th0), corrected, rtol=1e-12)
    # the limits: r = 2ρk is C = 0; above it, at 0 and below, NaN (and the values after a NaN are still solved)
    top = 2 * 0.7 * k
    got = m.invert_second_order(np.array([top * 1.2, top, 0.0, -1.0, r2[0]]), d, th0)
    assert got.dtype == np.float64 and np.isnan(got[[0, 2, 3]]).all()
    assert got[1] == pytest.approx(0.0, abs=1e-20) and got[4] == pytest.approx(c[0], rel=1e-10)
    # a depth so small that q ≪ 1 per mol/L (1e-8 m): C up to k/q is solved (here 0.9 k/q, beyond k·q); at
    # depth 0 (q = 0) NaN
    tiny = 1e-8
    et = m.epsilon_L_per_mol_cm * 100.0 * tiny
    qt = et * np.log(10) * (f(m.cutoff_rad) - f(th0))
    assert 0 < qt < 0.5
    ct = 0.9 * k / qt  # mol/L (absurd, so that C·q is 0.9 k)
    rt = 2 * 0.7 * 10.0 ** (-2 * et * ct) * (k - ct * qt)
    assert m.invert_second_order(np.array([rt]), tiny, th0)[0] == pytest.approx(ct, rel=1e-10)
    assert np.isnan(m.invert_second_order(np.array([0.5 * top]), 0.0, th0)).all()


def test_lamp_angle_for_a_point_at_the_lamps_foot_is_zero():
    """A disk point straight below the lamp is reached by the vertical ray: angle 0 (and a point 0.1 m away by
    the angle whose air and water legs add up to 0.1 m: H tan a + d tan(asin(sin a / n)) = 0.1)."""
    from camcal.water.models import lamp_angle_reaching

    assert lamp_angle_reaching(0.5, 0.3, 0.0) == 0.0
    a = lamp_angle_reaching(0.5, 0.3, 0.1)
    assert 0.5 * np.tan(a) + 0.3 * np.tan(np.arcsin(np.sin(a) / 1.33)) == pytest.approx(0.1, rel=1e-12)


def test_hemispheric_transmittance_against_quadrature():
    """T̄ = ∫ T cos θ sin θ dθ / ∫ cos θ sin θ dθ for a full sky and for a cone of 1 rad."""
    for tmax in (np.pi / 2, 1.0):
        num = quad(lambda a: fresnel_t_from_air(a) * np.cos(a) * np.sin(a), 0, tmax, epsabs=0, epsrel=1e-12)[0]
        assert hemispheric_transmittance(tmax) == pytest.approx(num / (0.5 * np.sin(tmax) ** 2), rel=1e-9)
    # a sky cutoff below the horizon is the full sky
    full = 2 * quad(lambda a: fresnel_t_from_air(a) * np.cos(a) * np.sin(a), 0, np.pi / 2, epsabs=0, epsrel=1e-12)[0]
    assert RefinedModel(sky_cutoff_rad=2.0).transmittance_down_mean() == pytest.approx(full, rel=1e-9)
    assert RefinedModel(sky_cutoff_rad=2.0).water_cutoff_rad() == pytest.approx(np.arcsin(1 / N_WATER), rel=1e-12)


@pytest.mark.parametrize("reflectance", ["fresnel", "schlick"])
def test_lamp_model_off_axis_with_chlorophyll_matches_a_ray_trace(reflectance):
    """Seed §4's point lamp at 0.5 rad, camera at 0.3 rad, C ≠ 0: the model's ratio against irradiances from an
    independent ray trace, E_w = I T(α) e^(−τ/cos β) sin α / (X dX/dα) with X(α) traced and dX/dα by central
    differences, and the inverse-square law with the cosine for the dry disk."""
    h, alpha, view, d, c = 0.8, 0.5, 0.3, 0.3, 1e-7
    m = LampModel(height_m=h, lamp_angle_rad=alpha, view_angle_rad=view, background_absorption_per_m=0.2,
                  reflectance=reflectance)
    n = N_WATER
    t_air = fresnel_t_from_air if reflectance == "fresnel" else schlick_t_from_air

    def x_of(a):  # horizontal distance from the lamp's foot where the refracted ray reaches depth d
        b = np.arcsin(np.sin(a) / n)
        return h * np.tan(a) + d * np.tan(b)

    da = 1e-5
    dx = (x_of(alpha + da) - x_of(alpha - da)) / (2 * da)
    x = x_of(alpha)
    beta = np.arcsin(np.sin(alpha) / n)
    tau = (m.water_absorption_per_m + 0.2 + np.log(10) * m.epsilon_L_per_mol_cm * c * 100) * d
    e_w = t_air(alpha) * np.exp(-tau / np.cos(beta)) * np.sin(alpha) / (x * dx)
    r = np.hypot(x, h + d)
    e_air = (h + d) / r**3
    mu_v = np.sqrt(1 - (np.sin(view) / n) ** 2)
    expect = e_w / e_air * t_air(view) * np.exp(-tau / mu_v) / n**2
    # tolerance: the central difference's truncation error, O(da²) ≈ 1e-10 relative
    assert float(m.ratio(c, d)) == pytest.approx(expect, rel=1e-8)
    optics = RefinedModel(view_angle_rad=view, background_absorption_per_m=0.2, reflectance=reflectance)
    assert float(lamp_ratio(c, d, h, alpha, optics)) == pytest.approx(expect, rel=1e-8)


def test_seed_first_and_second_order_off_axis_with_albedo():
    """Eq. 11 and the appendix's (k, q) model from a start angle θ0 = 0.2 rad with ρ = 0.6, against the seed's
    integrand in decadic form integrated over [θ0, θc] (second order: 10^(−2A)(1 − A ln10 θ²))."""
    m = SeedModel(albedo=0.6)
    c, d, th0 = 1e-7, 0.2, 0.2
    a = m.epsilon_L_per_mol_cm * c * d * 100
    tc = m.cutoff_rad
    first = 0.6 * (np.cos(th0) ** 2 - np.cos(tc) ** 2) * 10 ** (-2 * a)
    assert m.ratio_first_order(c, d, th0) == pytest.approx(first, rel=1e-12)
    second = 2 * 0.6 * quad(lambda t: 10 ** (-2 * a) * (1 - a * np.log(10) * t * t) * np.cos(t) * np.sin(t), th0, tc,
                            epsabs=0, epsrel=1e-13)[0]
    assert m.ratio_second_order(c, d, th0) == pytest.approx(second, rel=1e-10)


@pytest.mark.parametrize("transmittance", ["mean", "exact"])
def test_ratio_derivatives_against_central_differences(transmittance):
    """dR/dτ of the refined model's form (E₃ closed form or Gauss-Legendre) and of the lamp's exponential form,
    against a central difference of R (step 1e-5: truncation ≈ 1e-10 relative)."""
    forms = [RefinedModel(view_angle_rad=0.4, transmittance=transmittance).closed_form(),
             LampModel(height_m=0.7, lamp_angle_rad=0.4, view_angle_rad=0.2).closed_form_at(0.3)]
    h = 1e-5
    tau = np.array([0.3, 1.7])  # an array of τ, as the inversion passes them
    for f in forms:
        num = (f.ratio(tau + h) - f.ratio(tau - h)) / (2 * h)
        np.testing.assert_allclose(f.ratio_derivative(tau), num, rtol=1e-7)
        np.testing.assert_allclose(f.dlog_ratio_dtau(tau), num / f.ratio(tau), rtol=1e-7)
        assert np.shape(f.dlog_ratio_dtau(tau)) == tau.shape


def test_lamp_toward_a_disk_point_aims_the_ray_there():
    """Per-pixel geometry: the lamp angle of ``toward(dx, dy, d)`` sends the refracted ray (traced here) to the
    horizontal distance √((X0 + dx)² + dy²) from the lamp's foot; the other settings are kept."""
    h, d, n = 0.9, 0.25, 1.34
    lamp = LampModel(height_m=h, lamp_angle_rad=0.35, view_angle_rad=0.1, background_absorption_per_m=0.1, n_water=n)
    x0 = h * np.tan(0.35) + d * np.tan(np.arcsin(np.sin(0.35) / n))
    for dx, dy in ((0.04, 0.0), (-0.03, 0.05)):
        aim = lamp_toward(lamp, dx, dy, d)
        a = aim.lamp_angle_rad
        landed = h * np.tan(a) + d * np.tan(np.arcsin(np.sin(a) / n))
        assert landed == pytest.approx(np.hypot(x0 + dx, dy), rel=1e-10)
        assert (aim.height_m, aim.view_angle_rad, aim.background_absorption_per_m) == (h, 0.1, 0.1)


def test_refined_model_at_a_wavelength_keeps_the_other_settings():
    m = refined_at_wavelength(680.0, view_angle_rad=0.3, background_absorption_per_m=0.2)
    assert (m.view_angle_rad, m.background_absorption_per_m) == (0.3, 0.2)
    assert m.water_absorption_per_m == pytest.approx(0.465)  # Pope & Fry (1997) at 680 nm, m⁻¹


def test_refracted_angles_use_the_models_refractive_index():
    """Snell with n = 1.34 (sea water) rather than the default 1.33, for the view, the lamp ray and T_up."""
    n = 1.34
    for m in (RefinedModel(n_water=n, view_angle_rad=0.7), LampModel(n_water=n, view_angle_rad=0.7,
                                                                      lamp_angle_rad=0.7)):
        assert m.view_water_rad() == pytest.approx(np.arcsin(np.sin(0.7) / n), rel=1e-12)
        assert m.transmittance_up() == pytest.approx(fresnel_t_from_air(0.7, n), rel=1e-12)
    assert LampModel(n_water=n, lamp_angle_rad=0.7).refracted_angle_rad() == pytest.approx(
        np.arcsin(np.sin(0.7) / n), rel=1e-12)


def test_unknown_transmittance_mode_is_named():
    with pytest.raises(ValueError, match="unknown transmittance 'approx'"):
        RefinedModel(transmittance="approx").closed_form()

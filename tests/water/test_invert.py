"""Water module: per-pixel inversion (Newton and table), reasons, uncertainty, band-aware inversion."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from camcal.errors import CamcalError
from camcal.models.spectra import WAVELENGTHS_NM, gaussian_line
from camcal.water.band import BandModel, bricaud_1998, solvent_spectrum
from camcal.water.invert import Reason, TauTable, invert_images, invert_ratio, tau_newton, tau_table
from camcal.water.models import LampModel, RefinedModel, SeedModel
from camcal.water.purewater import pure_water_absorption_per_m
from camcal.water.units import mol_per_L_to_ug_per_L
from tests.helpers import INV_C, INV_WL, _inv_forward, _inv_sigma

#: Every test here is a fast formula test (the mutation-testing selection, docs/testing.md).
pytestmark = pytest.mark.formula


@pytest.fixture(autouse=True)
def _fresh_tau_tables():
    """Each test builds the τ tables it uses: ``tau_table`` caches them per closed form, and a table cached by an
    earlier test (or by the mutation run's clean pass, whose process the workers are forked from) would hide a
    change to ``TauTable`` from every later test."""
    tau_table.cache_clear()
    yield


SEED_C = np.linspace(1e-7, 5e-7, 41)  # seed §5 ranges
SEED_D = np.linspace(0.10, 0.50, 41)[:, None]


@pytest.mark.parametrize("method", ["newton", "table"])
@pytest.mark.parametrize("model", [SeedModel(), RefinedModel(), RefinedModel(view_angle_rad=0.4,
                                                                             background_absorption_per_m=0.3)])
def test_round_trip_within_1e9(method, model):
    ratio = model.ratio(SEED_C, SEED_D)
    inv = invert_ratio(ratio, model, SEED_D, method=method)
    assert np.all(inv.reason == 0)
    np.testing.assert_allclose(inv.c_mol_per_L, np.broadcast_to(SEED_C, ratio.shape), rtol=1e-9)


def test_scalar_depth_fast_path_matches_newton():
    m = SeedModel()
    c = np.logspace(-9, -5, 300)
    r = m.ratio(c, 0.2)
    fast = invert_ratio(r, m, 0.2, sigma_ln_ratio=0.01)
    ref = invert_ratio(r, m, 0.2, sigma_ln_ratio=0.01, method="newton")
    np.testing.assert_allclose(fast.c_mol_per_L, ref.c_mol_per_L, rtol=1e-9)
    np.testing.assert_allclose(fast.sigma_ug_per_L, ref.sigma_ug_per_L, rtol=1e-6)


def test_table_accuracy_over_full_range():
    cf = SeedModel().closed_form()
    tau = np.logspace(-4, np.log10(299.0), 20000)  # below 1e-4 float64 ratios cannot resolve τ to 1e-12
    got, why = tau_table(cf).tau(cf.ratio(tau))
    assert np.all(why == 0)
    np.testing.assert_allclose(got, tau, rtol=1e-10)


def test_uncertainty_matches_finite_difference():
    m = SeedModel()
    r = float(m.ratio(2e-7, 0.3))
    inv = invert_ratio(np.array([r]), m, 0.3, sigma_ln_ratio=0.01)
    hi = invert_ratio(np.array([r * np.exp(0.01)]), m, 0.3).c_ug_per_L
    lo = invert_ratio(np.array([r * np.exp(-0.01)]), m, 0.3).c_ug_per_L
    assert inv.sigma_ug_per_L[0] == pytest.approx(abs(hi - lo)[0] / 2, rel=1e-3)


def test_reasons():
    m = SeedModel()
    r0 = m.closed_form().ratio_at_zero
    r = np.array([np.nan, np.inf, -1.0, 0.0, r0 * 1.001, 1e-300, r0, 0.3])
    for method in ("newton", "table"):
        inv = invert_ratio(r, m, 0.2, method=method)
        assert inv.reason.tolist() == [1, 1, 2, 2, 3, 4, 0, 0]
        assert np.isnan(inv.c_mol_per_L[:6]).all() and inv.c_mol_per_L[6] == 0.0
    # refined: ratio above the clear-water (C = 0) value → ABOVE_CLEAR_WATER
    rm = RefinedModel()
    inv = invert_ratio(np.array([rm.ratio(0.0, 0.2) * 1.01, rm.ratio(0.0, 0.2)]), rm, 0.2)
    assert inv.reason.tolist() == [Reason.ABOVE_CLEAR_WATER, 0] and inv.c_mol_per_L[1] == pytest.approx(0, abs=1e-20)
    assert invert_ratio(np.array([0.3]), m, np.array([-1.0])).reason[0] == Reason.BAD_DEPTH


def test_invert_images_roi_and_reference():
    m = SeedModel()
    truth_c = np.linspace(1e-7, 3e-7, 64 * 48).reshape(48, 64)
    ref = np.full((48, 64), 2.5)
    ref[0, 0] = 0.0
    sub = (m.ratio(truth_c, 0.25) * ref).astype(np.float32)
    inv = invert_images(sub, ref, m, 0.25, sigma_submerged=0.01 * sub, roi=(0, 0, 60, 48))
    assert inv.reason[0, 0] == Reason.BAD_REFERENCE and np.all(inv.reason[:, 60:] == Reason.OUTSIDE_ROI)
    ok = inv.reason == 0
    assert ok.sum() == 48 * 60 - 1
    # float32 radiance: relative ratio error ≤ 6e-8, amplified by |d ln C / d ln r| < 3 here
    np.testing.assert_allclose(inv.c_mol_per_L[ok], truth_c[ok], rtol=3e-7)
    assert np.all(inv.sigma_ug_per_L[ok] > 0)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=1, max_size=20),
       st.floats(min_value=1e-4, max_value=100.0))
def test_inverters_never_raise(values, depth):
    r = np.array(values)
    for method in ("newton", "table"):
        for model in (SeedModel(), RefinedModel()):
            inv = invert_ratio(r, model, depth, sigma_ln_ratio=0.01, method=method)
            bad = inv.reason != 0
            assert np.all(np.isnan(inv.c_mol_per_L[bad]))
            assert np.all(np.isfinite(inv.c_mol_per_L[~bad])) and np.all(inv.c_mol_per_L[~bad] >= 0)
            assert np.all((~np.isfinite(r)) <= (inv.reason == Reason.NOT_FINITE))
            assert np.all((np.isfinite(r) & (r <= 0)) <= (inv.reason == Reason.NOT_POSITIVE))
    tau, why = tau_newton(r, SeedModel().closed_form())
    assert np.all(np.isnan(tau[why != 0]))


def test_band_narrowband_limit_equals_monochromatic():
    # a 0.5 nm line and a flat ε = 88 L/g/cm reproduce eq. 10 at that wavelength
    band = BandModel(WAVELENGTHS_NM, gaussian_line(663.0, 0.5),
                     chlorophyll=solvent_spectrum(WAVELENGTHS_NM, np.full(WAVELENGTHS_NM.size, 88.0)))
    c = np.array([1e-7, 3e-7])
    np.testing.assert_allclose(band.ratio(mol_per_L_to_ug_per_L(c), 0.2), SeedModel().ratio(c, 0.2), rtol=1e-12)


def test_band_round_trip_with_synthetic_camera_red(camera):
    red = camera.spectral_sensitivity()[0]
    band = BandModel(WAVELENGTHS_NM, red, geometry=RefinedModel())
    inverse = band.inverse(0.3)
    c = np.logspace(-1, 3, 60)  # 0.1 … 1000 µg/L
    inv = inverse.concentration(band.ratio(c, 0.3), sigma_ln_ratio=0.01)
    assert np.all(inv.reason == 0)
    np.testing.assert_allclose(inv.c_ug_per_L, c, rtol=1e-8)  # measured 7e-10
    assert np.all(inv.sigma_ug_per_L > 0)
    # the narrowband assumption (Bricaud a* and Pope & Fry a_w at 674 nm, the a* peak) misreads a broad red
    # channel badly: the band also sees 580-650 nm, where water absorbs less, so at 10 µg/L the band ratio is
    # brighter than narrowband clear water allows, and at 100 µg/L the narrowband reading is < 1/5 of the truth
    from scipy.optimize import brentq

    a674 = bricaud_1998().on(np.array([674.0]))
    aw674 = float(pure_water_absorption_per_m(674.0))
    cf = RefinedModel().closed_form()
    assert band.ratio(10.0, 0.3) > cf.ratio(aw674 * 0.3)
    b = band.ratio(100.0, 0.3)
    c_narrow = brentq(lambda x: float(cf.ratio((aw674 + a674.absorption_per_m(x)[0]) * 0.3)) - b, 1e-6, 1e6)
    assert c_narrow < 0.2 * 100.0
    reasons = inverse.concentration(np.array([np.nan, -1.0, 2.0, 1e-300])).reason
    assert reasons.tolist() == [1, 2, 3, 4]


def test_band_images_sigma_roi_and_reasons(camera):
    band = BandModel(WAVELENGTHS_NM, camera.spectral_sensitivity()[0], geometry=RefinedModel())
    c = np.linspace(10.0, 200.0, 12 * 16).reshape(12, 16)
    ref = np.full(c.shape, 2.0)
    sub = band.ratio(c, 0.5) * ref
    sub[0, 0], ref[0, 1], sub[0, 2] = np.nan, 0.0, 3.0  # not finite, bad reference, above clear water
    sig_map = 0.01 * sub
    inv = invert_images(sub, ref, band, 0.5, sigma_submerged=sig_map, sigma_reference=0.0, roi=(0, 0, 16, 10))
    assert inv.reason[0, :3].tolist() == [Reason.NOT_FINITE, Reason.BAD_REFERENCE, Reason.ABOVE_CLEAR_WATER]
    assert np.all(inv.reason[10:] == Reason.OUTSIDE_ROI) and np.all(np.isnan(inv.c_ug_per_L[10:]))
    ok = inv.reason == 0
    np.testing.assert_allclose(inv.c_ug_per_L[ok], c[ok], rtol=1e-8)
    # σ from a 1 % ratio error: C · 0.01 / |d ln B / d ln C| (analytic derivative of the band model)
    b, db = band.ratio_and_derivative(c[ok], 0.5)
    np.testing.assert_allclose(inv.sigma_ug_per_L[ok], 0.01 * b / np.abs(db), rtol=1e-5)


def test_denormal_depth_is_a_reason_not_an_infinity():
    """Found by hypothesis: depth 5e-324 m made C overflow to inf with reason OK."""
    from camcal.water.invert import Reason, invert_ratio
    from camcal.water.models import SeedModel

    for method in ("table", "newton"):
        inv = invert_ratio(np.array([0.5]), SeedModel(), 5e-324, method=method)
        assert inv.reason[0] == Reason.BAD_DEPTH and np.isnan(inv.c_ug_per_L[0])


def _quadrature_ratio(cf, tau):
    """R(τ) = K e^(−vτ) ∫_0^θc e^(−mτ/cos θ) cos θ sin θ dθ by adaptive quadrature (not the E₃ closed form)."""
    from scipy.integrate import quad

    theta_c = np.arccos(cf.mu_c)
    integral = quad(lambda t: np.exp(-cf.path_factor * tau / np.cos(t)) * np.cos(t) * np.sin(t), 0.0, theta_c,
                    epsabs=0.0, epsrel=1e-13, limit=200)[0]
    return cf.scale * np.exp(-cf.view_factor * tau) * integral


@pytest.mark.parametrize("model", [SeedModel(), RefinedModel(view_angle_rad=0.5)], ids=["seed", "refined"])
def test_tau_newton_against_brentq_on_the_quadrature_ratio(model):
    """τ from ``tau_newton`` against Brent's root of ln R(τ) − ln r with R by quadrature, from τ = 1e-6 to near the
    table's end; Newton from the first-order start converges in a few steps (bisection alone would need ~50), so a
    budget of 12 iterations must already give the root. Tolerance: quadrature to 1e-13 relative, so the root to
    ≈1e-13/|d ln R/dτ|·…; 1e-10 relative leaves margin."""
    from scipy.optimize import brentq

    cf = model.closed_form()
    tau_max = 600.0 / (cf.path_factor + cf.view_factor)
    taus = np.array([1e-6, 1e-3, 0.05, 0.7, 3.0, 20.0, 0.9 * tau_max])
    ratios = np.array([_quadrature_ratio(cf, t) for t in taus])
    expect = [brentq(lambda t, r=r: np.log(_quadrature_ratio(cf, t)) - np.log(r), 0.0, tau_max, xtol=1e-300,
                     rtol=1e-14) for r in ratios]
    got, why = tau_newton(ratios, cf, max_iter=12)
    assert why.tolist() == [0] * taus.size
    np.testing.assert_allclose(got, expect, rtol=1e-10)


def test_tau_newton_edges_and_flags():
    """The clear-water ratio gives τ = 0; the ratio at the deepest tabulated τ (600/(m + v)) is solved, not refused,
    and one part in 10⁶ darker is TOO_DARK; NaN, ≤ 0 and above-clear-water ratios are NaN with their reason; the
    shape of the input is kept."""
    cf = RefinedModel(view_angle_rad=0.3).closed_form()
    tau_max = 600.0 / (cf.path_factor + cf.view_factor)
    r0, rmin = cf.ratio_at_zero, float(cf.ratio(tau_max))
    r = np.array([[r0, rmin, rmin * (1 - 1e-6)], [np.nan, -0.5, r0 * (1 + 1e-9)]])
    tau, why = tau_newton(r, cf)
    assert tau.shape == why.shape == (2, 3) and why.dtype == np.uint8
    assert why.tolist() == [[0, 0, Reason.TOO_DARK], [Reason.NOT_FINITE, Reason.NOT_POSITIVE,
                                                       Reason.ABOVE_CLEAR_WATER]]
    assert tau[0, 0] == 0.0
    assert tau[0, 1] == pytest.approx(tau_max, rel=1e-12)
    assert np.isnan(tau[0, 2]) and np.isnan(tau[1]).all()


@pytest.mark.parametrize("method", ["newton", "table"])
def test_per_pixel_depths_match_scenes_rendered_one_depth_at_a_time(method):
    """An array of depths (one per pixel): C, τ and σ_C of each pixel against that pixel's own scene, rendered by
    the model's forward ratio at its scalar depth. τ = (a_w + a_bg + ln10 ε C·100) d is written out; σ_C =
    σ_ln r / |d ln R/dC|, the derivative by central differences of the forward ratio (step 1e-3 relative: error
    ~1e-6). Pixels at the clear-water boundary: τ a hair (5e-11) below the background is clear water (C = 0),
    5e-10 below it (more than the 1e-9·τ_bg the inversion forgives) is brighter than clear water allows. A bad
    depth is named BAD_DEPTH whatever its ratio."""
    m = RefinedModel(view_angle_rad=0.4, background_absorption_per_m=0.3)
    cf = m.closed_form()
    c = np.array([1e-8, 1e-7, 2.5e-7, 4e-7, 1e-6, 3e-7])
    d = np.array([0.12, 0.3, 0.45, 0.2, 0.6, 1e-6])  # the last one exactly the smallest depth inverted
    r = np.array([float(m.ratio(ci, di)) for ci, di in zip(c, d, strict=True)])
    sig = np.array([0.01, 0.02, 0.005, 0.01, 0.03, 0.01])
    inv = invert_ratio(r, m, d, sigma_ln_ratio=sig, method=method)
    assert inv.reason.tolist() == [0] * c.size and inv.reason.dtype == np.uint8
    # the last pixel: at 1 µm C·τ-per-C is ~1e-7 of τ, so only a loose check of C
    np.testing.assert_allclose(inv.c_mol_per_L[:5], c[:5], rtol=1e-8)
    assert inv.c_mol_per_L[5] == pytest.approx(c[5], rel=1e-3)
    np.testing.assert_allclose(inv.c_ug_per_L, mol_per_L_to_ug_per_L(inv.c_mol_per_L), rtol=1e-15)
    tau = (m.water_absorption_per_m + 0.3 + np.log(10) * m.epsilon_L_per_mol_cm * c * 100) * d
    np.testing.assert_allclose(inv.tau, tau, rtol=1e-10)
    h = 1e-3 * c[:5]
    dlnr_dc = (np.log([float(m.ratio(ci + hi, di)) for ci, hi, di in zip(c, h, d, strict=False)])
               - np.log([float(m.ratio(ci - hi, di)) for ci, hi, di in zip(c, h, d, strict=False)])) / (2 * h)
    np.testing.assert_allclose(inv.sigma_ug_per_L[:5], mol_per_L_to_ug_per_L(sig[:5] / np.abs(dlnr_dc)), rtol=1e-5)
    # no σ given: NaN σ, the same C
    plain = invert_ratio(r, m, d, method=method)
    assert plain.sigma_ug_per_L.shape == r.shape and np.isnan(plain.sigma_ug_per_L).all()
    np.testing.assert_allclose(plain.c_mol_per_L[:5], c[:5], rtol=1e-8)
    # the clear-water boundary and bad depths
    dd = np.array([0.25, 0.25, 0.25, np.nan, 0.5 * 1e-6, 0.25])
    tau_bg = (m.water_absorption_per_m + 0.3) * 0.25
    r2 = np.array([float(cf.ratio(tau_bg - 5e-11)), float(cf.ratio(tau_bg - 5e-10)), float(cf.ratio(tau_bg)),
                   float(cf.ratio(0.01)), 0.5, float(m.ratio(2e-7, 0.25))])
    inv2 = invert_ratio(r2, m, dd, sigma_ln_ratio=0.01, method=method)
    assert inv2.reason.tolist() == [0, Reason.ABOVE_CLEAR_WATER, 0, Reason.BAD_DEPTH, Reason.BAD_DEPTH, 0]
    assert inv2.c_mol_per_L[0] == 0.0 and inv2.c_mol_per_L[2] == pytest.approx(0.0, abs=1e-18)
    bad = [1, 3, 4]
    assert np.isnan(inv2.c_mol_per_L[bad]).all() and np.isnan(inv2.tau[bad]).all()
    assert np.isnan(inv2.sigma_ug_per_L[bad]).all()
    assert inv2.c_mol_per_L[5] == pytest.approx(2e-7, rel=1e-8)
    assert inv2.tau[0] == pytest.approx(tau_bg, rel=1e-9)


@pytest.mark.parametrize("method", ["newton", "table"])
def test_lamp_model_per_pixel_depth_array_of_one_depth(method):
    """The lamp model takes an array of depths only if they are all the same (its geometry depends on the depth).
    C of each pixel against the C its scene was rendered with (the forward ratio at the scalar depth); τ written
    out, (a_w + a_bg) d + ln10 ε C·100 d; σ_C = σ_ln r / (s · ln10 ε·100 d) exactly, d ln R/dC of the single
    exponential R = K e^(−sτ) with s = 1/cos β + 1/μv from Snell written out."""
    m = LampModel(height_m=0.8, lamp_angle_rad=0.5, view_angle_rad=0.3, background_absorption_per_m=0.2)
    c = np.array([5e-8, 2e-7, 6e-7])
    r = np.array([float(m.ratio(ci, 0.3)) for ci in c])
    s = 1 / np.cos(np.arcsin(np.sin(0.5) / m.n_water)) + 1 / np.cos(np.arcsin(np.sin(0.3) / m.n_water))
    per_c = np.log(10) * m.epsilon_L_per_mol_cm * 100 * 0.3
    for depth in (0.3, np.array([0.3]), np.full(3, 0.3), np.array([0.3, np.nan, 0.3])):
        inv = invert_ratio(r, m, depth, sigma_ln_ratio=0.02, method=method)
        bad = ~np.isfinite(np.broadcast_to(depth, 3))
        assert inv.reason.tolist() == [Reason.BAD_DEPTH if b else 0 for b in bad]
        ok = ~bad
        np.testing.assert_allclose(inv.c_mol_per_L[ok], c[ok], rtol=1e-9)
        tau = (m.water_absorption_per_m + 0.2) * 0.3 + per_c * c
        np.testing.assert_allclose(inv.tau[ok], tau[ok], rtol=1e-10)
        np.testing.assert_allclose(inv.sigma_ug_per_L[ok], mol_per_L_to_ug_per_L(0.02 / (s * per_c)), rtol=1e-8)
    with pytest.raises(CamcalError, match="one depth at a time"):
        invert_ratio(r, m, np.array([0.3, 0.31, 0.3]), method=method)
    # exactly the smallest depth inverted (1 µm): the geometry of that depth (τ per C is ~1e-7 of the above)
    r_min = np.array([float(m.ratio(ci, 1e-6)) for ci in c])
    for depth in (1e-6, np.full(3, 1e-6)):
        np.testing.assert_allclose(invert_ratio(r_min, m, depth, method=method).c_mol_per_L, c, rtol=1e-3)
    # every depth below 1 µm or not finite, or so deep the geometry overflows: every pixel BAD_DEPTH
    for depth in (np.full(3, 5e-7), np.full(3, np.nan), 1e300, np.full(3, 1e300)):
        inv = invert_ratio(r, m, depth, sigma_ln_ratio=0.02, method=method)
        assert inv.reason.tolist() == [Reason.BAD_DEPTH] * 3 and np.isnan(inv.c_mol_per_L).all()


def test_inversion_summary_counts_and_statistics_written_out():
    """Counts per reason by name and the statistics of the valid pixels, on values whose median, mean and
    linear-interpolation percentiles are known by hand: 1…5 µg/L → median 3, mean 3, p05 = 1 + 0.05·4 = 1.2,
    p95 = 1 + 0.95·4 = 4.8."""
    from camcal.water.invert import Inversion

    c = np.array([3.0, np.nan, 1.0, 5.0, np.nan, 2.0, np.nan, 4.0])
    reason = np.array([0, 1, 0, 0, 4, 0, 4, 0], dtype=np.uint8)
    nan = np.full(c.shape, np.nan)
    s = Inversion(c * 1e-9, c, nan, nan, reason).summary()
    assert s == {"pixels": 8, "valid": 5, "reasons": {"ok": 5, "not_finite": 1, "too_dark": 2},
                 "median_ug_per_L": 3.0, "mean_ug_per_L": 3.0,
                 "p05_ug_per_L": pytest.approx(1.2, rel=1e-12), "p95_ug_per_L": pytest.approx(4.8, rel=1e-12)}
    none = Inversion(nan[:2], nan[:2], nan[:2], nan[:2], np.array([3, 3], dtype=np.uint8)).summary()
    assert none == {"pixels": 2, "valid": 0, "reasons": {"above_clear_water": 2}}


def test_invert_images_sigma_from_both_radiances_and_a_dim_reference():
    """Images of C (rendered by the forward ratio) over a reference radiance that varies from 0.4 to 3 (below 1
    too): C per pixel against the truth; σ_C = √((σ_s/L_s)² + (σ_ref/L_ref)²) / |d ln R/dC| with the derivative
    by central differences of the forward ratio (step 1e-3 relative: error ~1e-6), for both σ given, only the
    reference's, only the submerged one's; a zero reference is BAD_REFERENCE."""
    m = RefinedModel(view_angle_rad=0.2)
    c = np.linspace(5e-8, 6e-7, 20).reshape(4, 5)
    ref = np.linspace(0.4, 3.0, 20).reshape(4, 5)
    ref[3, 4] = 0.0
    d = 0.35
    sub = m.ratio(c, d) * ref
    sub[3, 4] = 0.7
    h = 1e-3 * c
    dlnr_dc = (np.log(m.ratio(c + h, d)) - np.log(m.ratio(c - h, d))) / (2 * h)
    ok = np.ones(c.shape, dtype=bool)
    ok[3, 4] = False
    for s_sub, s_ref, rel in ((0.01 * sub, 0.02 * ref, np.hypot(0.01, 0.02)), (None, 0.02 * ref, 0.02),
                              (0.01 * sub, None, 0.01)):
        inv = invert_images(sub, ref, m, d, sigma_submerged=s_sub, sigma_reference=s_ref)
        assert inv.reason[3, 4] == Reason.BAD_REFERENCE and np.all(inv.reason[ok] == 0)
        assert inv.tau.dtype == inv.c_ug_per_L.dtype == np.float64 and np.isnan(inv.tau[3, 4])
        np.testing.assert_allclose(inv.c_ug_per_L[ok], mol_per_L_to_ug_per_L(c[ok]), rtol=1e-9)
        np.testing.assert_allclose(inv.tau[ok], m.tau(c[ok], d), rtol=1e-10)
        np.testing.assert_allclose(inv.c_mol_per_L[ok], c[ok], rtol=1e-9)
        np.testing.assert_allclose(inv.sigma_ug_per_L[ok], mol_per_L_to_ug_per_L(rel / np.abs(dlnr_dc[ok])),
                                   rtol=1e-5)
    assert np.isnan(invert_images(sub, ref, m, d).sigma_ug_per_L).all()


def test_scalar_depth_fast_path_with_background_absorption():
    """The image path (one depth, one σ) with a background absorption: C, τ and σ_C against scenes rendered by the
    forward ratio, τ written out, σ_C from central differences of the forward ratio (as above); τ 5e-11 below
    the background is clear water (C = 0), 5e-10 below it brighter than clear water allows (the inversion
    forgives 1e-9·τ_bg, τ_bg ≈ 0.18 here)."""
    m = RefinedModel(view_angle_rad=0.4, background_absorption_per_m=0.3)
    cf, d = m.closed_form(), 0.25
    c = np.array([[1e-8, 1e-7], [2.5e-7, 8e-7]])
    r = m.ratio(c, d)
    inv = invert_ratio(r, m, d, sigma_ln_ratio=0.01)
    assert inv.reason.shape == (2, 2) and np.all(inv.reason == 0)
    np.testing.assert_allclose(inv.c_mol_per_L, c, rtol=1e-9)
    tau_bg = (m.water_absorption_per_m + 0.3) * d
    np.testing.assert_allclose(inv.tau, tau_bg + np.log(10) * m.epsilon_L_per_mol_cm * c * 100 * d, rtol=1e-10)
    h = 1e-3 * c
    dlnr_dc = (np.log(m.ratio(c + h, d)) - np.log(m.ratio(c - h, d))) / (2 * h)
    np.testing.assert_allclose(inv.sigma_ug_per_L, mol_per_L_to_ug_per_L(0.01 / np.abs(dlnr_dc)), rtol=1e-5)
    # one σ per pixel (a 1-D array) with the one depth
    sig = np.array([0.01, 0.02, 0.03, 0.04])
    inv1 = invert_ratio(r.ravel(), m, d, sigma_ln_ratio=sig)
    np.testing.assert_allclose(inv1.sigma_ug_per_L, mol_per_L_to_ug_per_L(sig / np.abs(dlnr_dc.ravel())), rtol=1e-5)
    r2 = np.array([float(cf.ratio(tau_bg - 5e-11)), float(cf.ratio(tau_bg - 5e-10))])
    inv2 = invert_ratio(r2, m, d, sigma_ln_ratio=0.01)
    assert inv2.reason.tolist() == [0, Reason.ABOVE_CLEAR_WATER]
    assert inv2.c_mol_per_L[0] == 0.0 and inv2.tau[0] == pytest.approx(tau_bg, rel=1e-9)
    assert np.isnan([inv2.c_mol_per_L[1], inv2.tau[1], inv2.sigma_ug_per_L[1]]).all()


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # the µg/L conversion overflows (reported)
@pytest.mark.parametrize("method", ["newton", "table"])
def test_concentration_that_overflows_is_too_dark(method):
    """A molar absorption so small (1e-305 L/mol/cm) that τ per unit C is ~1e-306: any τ above clear water gives
    C = ∞, which becomes NaN with reason TOO_DARK; the clear-water ratio stays C = 0."""
    m = SeedModel(epsilon_L_per_mol_cm=1e-305)
    cf = m.closed_form()
    r = np.array([cf.ratio_at_zero, float(cf.ratio(0.5))])
    for depth in (0.3, np.full(2, 0.3)):
        inv = invert_ratio(r, m, depth, sigma_ln_ratio=0.01, method=method)
        assert inv.reason.tolist() == [0, Reason.TOO_DARK] and inv.c_mol_per_L[0] == 0.0
        assert np.isnan([inv.c_mol_per_L[1], inv.c_ug_per_L[1], inv.sigma_ug_per_L[1], inv.tau[1]]).all()


def test_tau_table_first_order_below_its_first_node_and_refusals_without_slope():
    """Ratios within 1e-14 (in ln) of clear water are below the table's first node: τ = δ/slope₀ and dτ/d(−ln r)
    = 1/slope₀, slope₀ = −d ln R/dτ at 0 here by a forward difference of the closed form over 1e-9 (error
    ~1e-8·ln: the derivative of E₃ has a log term at 0); and without the slope, bad ratios get their reasons."""
    cf = SeedModel().closed_form()
    table = tau_table(cf)
    r0 = cf.ratio_at_zero
    r = r0 * np.array([1 - 2e-15, 1 - 6e-15])
    delta = np.log(r0) - np.log(r)
    assert np.all((delta > 0) & (delta < 1e-14))
    slope0 = -(np.log(cf.ratio(1e-9)) - np.log(r0)) / 1e-9
    tau, why, slope = table.tau(r, with_slope=True)
    assert why.tolist() == [0, 0] and why.dtype == np.uint8
    np.testing.assert_allclose(tau, delta / slope0, rtol=1e-5)
    np.testing.assert_allclose(slope, 1 / slope0, rtol=1e-5)
    tau, why = table.tau(np.array([np.nan, 2 * r0, -1.0, 1e-300, r[0]]))
    assert why.tolist() == [Reason.NOT_FINITE, Reason.ABOVE_CLEAR_WATER, Reason.NOT_POSITIVE, Reason.TOO_DARK, 0]
    assert np.isnan(tau[:4]).all() and tau[4] > 0


def test_tau_table_keeps_its_closed_form():
    """The table is of the closed form it was built from (callers read ``table.cf`` back)."""
    cf = RefinedModel(view_angle_rad=0.4).closed_form()
    assert tau_table(cf).cf == cf
    assert TauTable(SeedModel().closed_form(), nodes=16).cf == SeedModel().closed_form()


def test_tau_table_last_cells_and_last_node():
    """The table's last cells reach τ_max = 600 / (m + s) (300 for the seed: m = 2, s = 0): ratios rendered by the
    forward closed form at τ within 2 % of τ_max (the last few cells, ~1.4 in τ wide) come back to 1e-9, and the
    ratio at τ_max itself, which lands on the last node (its cell index clipped to the last cell), is τ_max."""
    cf = SeedModel().closed_form()
    tau_max = 600.0 / 2.0
    tau = np.array([294.0, 295.5, 296.9, 297.6, 298.3, 298.9, 299.3, 299.7, 299.95, tau_max])
    got, why = tau_table(cf).tau(cf.ratio(tau))
    assert why.tolist() == [0] * tau.size
    np.testing.assert_allclose(got, tau, rtol=1e-9)
    # the last node at several node counts (where ln δ_max lands on or just past the last node)
    for nodes in (2, 3, 5, 16):
        got, why = TauTable(cf, nodes=nodes).tau(cf.ratio(np.array([tau_max])))
        assert why.tolist() == [0]
        np.testing.assert_allclose(got, [tau_max], rtol=1e-12)


def test_tau_table_first_cells():
    """With 512 nodes the first cells span δ = ln R(0) − ln r from 1e-14 to ~1.2e-14, wide enough for float64
    ratios to fall inside them: there τ = δ/slope₀ to first order (the next term is ~δ ln δ relative),
    slope₀ = 2m/(1 + μc) written out (m = 2, s = 0 for the seed). Tolerance 3 %: the table's own nodes there are
    solved from ratios R(0)·e^(−δ) rounded to ~1e-16, i.e. ~1 % of δ (a node moved to τ_max errs by 10¹⁶)."""
    cf = SeedModel().closed_form()
    r0 = cf.ratio_at_zero
    r = r0 * (1 - np.array([1.02e-14, 1.05e-14, 1.1e-14, 1.2e-14]))
    delta = np.log(r0) - np.log(r)
    assert np.all((delta > 1e-14) & (delta < 1.25e-14))
    got, why = TauTable(cf, nodes=512).tau(r)
    assert why.tolist() == [0] * r.size
    np.testing.assert_allclose(got, delta / (2 * 2 / (1 + cf.mu_c)), rtol=3e-2)


def test_tau_table_float32_ratios_are_read_in_float64():
    """float32 ratios are exact binary numbers: their τ is that of the same value in float64, against Brent's root
    of ln R(τ) = ln r on the forward closed form (a float32 logarithm would err by ~1e-7 relative)."""
    from scipy.optimize import brentq

    cf = SeedModel().closed_form()
    r32 = (cf.ratio_at_zero * np.array([0.9, 0.5, 0.1, 1e-3])).astype(np.float32)
    want = [brentq(lambda t, ri=float(ri): np.log(cf.ratio(t)) - np.log(ri), 1e-9, 300.0, xtol=1e-15, rtol=1e-15)
            for ri in r32]
    got, why = tau_table(cf).tau(r32)
    assert why.tolist() == [0] * 4
    np.testing.assert_allclose(got, want, rtol=1e-9)


def test_one_depth_image_path_reasons_are_uint8():
    """The reasons are one byte per pixel (uint8, as :class:`Reason`'s codes and the per-pixel path), also on the
    one-depth image path."""
    m = SeedModel()
    r = np.array([m.ratio(2e-7, 0.2), np.nan, 2.0])
    for depth in (0.2, np.full(3, 0.2)):
        inv = invert_ratio(r, m, depth)
        assert inv.reason.dtype == np.uint8
        assert inv.reason.tolist() == [0, Reason.NOT_FINITE, Reason.ABOVE_CLEAR_WATER]


def test_lamp_model_geometry_that_overflows_to_an_infinite_ratio_is_bad_depth():
    """At 1e120 m the lamp model's irradiance ratio overflows: (x² + (H+d)²)^1.5 is inf, E_air = 0 and R(0) =
    E_w/E_air = inf while its slope (the path factor) stays finite: every pixel BAD_DEPTH, nothing inverted."""
    m = LampModel(height_m=0.8, lamp_angle_rad=0.5, view_angle_rad=0.3, background_absorption_per_m=0.2)
    with np.errstate(all="ignore"):
        assert np.isinf(m.closed_form_at(1e120).ratio_at_zero)
    for method in ("table", "newton"):
        inv = invert_ratio(np.array([0.5, 0.1]), m, 1e120, method=method)
        assert inv.reason.tolist() == [Reason.BAD_DEPTH] * 2 and np.isnan(inv.c_mol_per_L).all()


@pytest.mark.parametrize("method", ["table", "newton"])
def test_a_disk_that_sends_no_light_back_is_refused_in_one_line(method):
    """A lamp model whose R(0) is 0 (albedo 0) or whose R(τ_max) underflows to 0 (albedo 1e-300 at 1e12 m, where
    the fallback geometry at 1 m still has R(0) ≈ 1e-300) has nothing to invert: a CamcalError naming the cause,
    not an IndexError from the τ table. A seed model with albedo 0 likewise."""
    lamp = LampModel(height_m=0.8, lamp_angle_rad=0.5, view_angle_rad=0.3, albedo=0.0)
    with pytest.raises(CamcalError, match="albedo 0"):
        invert_ratio(np.array([0.5, 0.1]), lamp, 0.3, method=method)
    tiny = LampModel(height_m=0.8, lamp_angle_rad=0.5, view_angle_rad=0.3, albedo=1e-300)
    with pytest.raises(CamcalError, match="albedo"), np.errstate(all="ignore"):
        invert_ratio(np.array([1e-301]), tiny, 1e12, method="table")
    with pytest.raises(CamcalError, match="albedo 0"):
        invert_ratio(np.array([0.5]), SeedModel(albedo=0.0), 0.3, method=method)


# ---- the chunked image path: more chunks than one, in one thread and in two --------------------------------------

def _spy_on_chunks(monkeypatch, chunk: int) -> list[np.ndarray]:
    """Lower the image path's chunk size to ``chunk`` pixels and record the ratios each call of
    ``TauTable.tau_into`` (one chunk of work) receives."""
    from camcal.water import invert

    monkeypatch.setattr(invert, "CHUNK", chunk)
    seen: list[np.ndarray] = []
    original = TauTable.tau_into

    def spy(self, r, tau, reason, slope):
        seen.append(np.array(r, copy=True))
        return original(self, r, tau, reason, slope)

    monkeypatch.setattr(TauTable, "tau_into", spy)
    return seen


def _assert_each_pixel_once(seen: list[np.ndarray], flat: np.ndarray, chunk: int, threads: str) -> None:
    """The chunks partition the image: ⌈n/chunk⌉ one-dimensional pieces of at most ``chunk`` pixels that hold every
    pixel exactly once (in order on one thread; any order on two). Work and memory per chunk stay bounded."""
    assert len(seen) == -(-flat.size // chunk)
    assert all(s.ndim == 1 and 0 < s.size <= chunk for s in seen)
    got = np.concatenate(seen)
    if threads == "1":
        np.testing.assert_array_equal(got, flat)
    else:
        np.testing.assert_array_equal(np.sort(got), np.sort(flat))


@pytest.mark.parametrize("threads", ["1", "2"])
def test_tau_table_over_several_chunks_against_the_forward_ratio(monkeypatch, threads):
    """50 ratios rendered by the forward closed form at known τ (1e-3 … 250), read in chunks of 7 pixels on one and
    on two threads (CAMCAL_THREADS): τ to 1e-9 (the table's accuracy is ~3e-11) and dτ/d(−ln r) against
    −1/(d ln R/dτ) of the closed form, each pixel read exactly once."""
    monkeypatch.setenv("CAMCAL_THREADS", threads)
    seen = _spy_on_chunks(monkeypatch, 7)
    cf = RefinedModel(view_angle_rad=0.4).closed_form()
    tau = np.logspace(-3, np.log10(250.0), 50).reshape(5, 10)
    r = cf.ratio(tau)
    got, why, slope = TauTable(cf, nodes=2048).tau(r, with_slope=True)
    assert got.shape == why.shape == slope.shape == (5, 10) and np.all(why == 0)
    np.testing.assert_allclose(got, tau, rtol=1e-9)
    np.testing.assert_allclose(slope, -1.0 / cf.dlog_ratio_dtau(tau), rtol=1e-6)
    _assert_each_pixel_once(seen, r.ravel(), 7, threads)


@pytest.mark.parametrize("threads", ["1", "2"])
def test_one_depth_image_path_over_several_chunks(monkeypatch, threads):
    """The one-depth image path (invert_ratio with a scalar depth) in chunks of 5 pixels, on one and two threads:
    C of 40 pixels rendered by the forward ratio of a model with a background absorption, against the truth; σ_C
    from central differences of the forward ratio (step 1e-3 relative: ~1e-6); pixels with a reason (not
    finite, brighter than clear water) in different chunks; each pixel read exactly once."""
    monkeypatch.setenv("CAMCAL_THREADS", threads)
    seen = _spy_on_chunks(monkeypatch, 5)
    m = RefinedModel(view_angle_rad=0.3, background_absorption_per_m=0.2)
    d = 0.3
    c = np.linspace(2e-8, 8e-7, 40).reshape(8, 5)
    r = m.ratio(c, d)
    r[1, 2], r[6, 0] = np.nan, 1.5 * m.ratio(0.0, d)
    inv = invert_ratio(r, m, d, sigma_ln_ratio=0.02)
    bad = np.zeros(c.shape, bool)
    bad[1, 2] = bad[6, 0] = True
    assert inv.reason[1, 2] == Reason.NOT_FINITE and inv.reason[6, 0] == Reason.ABOVE_CLEAR_WATER
    assert np.all(inv.reason[~bad] == 0) and np.isnan(inv.c_mol_per_L[bad]).all()
    np.testing.assert_allclose(inv.c_mol_per_L[~bad], c[~bad], rtol=1e-9)
    np.testing.assert_allclose(inv.c_ug_per_L[~bad], mol_per_L_to_ug_per_L(c[~bad]), rtol=1e-9)
    h = 1e-3 * c
    dlnr_dc = (np.log(m.ratio(c + h, d)) - np.log(m.ratio(c - h, d))) / (2 * h)
    np.testing.assert_allclose(inv.sigma_ug_per_L[~bad], mol_per_L_to_ug_per_L(0.02 / np.abs(dlnr_dc[~bad])),
                               rtol=1e-5)
    _assert_each_pixel_once(seen, r.ravel(), 5, threads)


# ---- invert_images with the lamp's per-pixel geometry and with a band model ----------------------------------------

def test_invert_images_with_each_pixels_own_lamp_geometry():
    """``pixel_geometry``: each pixel of a 6 × 8 image rendered with its own lamp geometry (the lamp angle that
    reaches that pixel's disk point, written out with ``lamp_angle_reaching`` and the forward ratio) over a
    reference of 2: C back to 1e-9; σ_C from a 1 % σ of the submerged radiance against central differences of
    that pixel's forward ratio (~1e-6); the centre's geometry would be off by ≥ 1 % at the image's edge."""
    from dataclasses import replace

    from camcal.water.lampfield import PixelGeometry
    from camcal.water.models import lamp_angle_reaching

    lamp = LampModel(0.5, np.radians(30))
    d = 0.3
    geom = PixelGeometry(0.02, (3.5, 2.5), 180.0)
    x = geom.distances_m((6, 8), lamp, d)
    c = np.linspace(5e-8, 3e-7, 48).reshape(6, 8)
    ref = np.full(c.shape, 2.0)
    sub = np.empty(c.shape)
    dlnr_dc = np.empty(c.shape)
    for i in np.ndindex(c.shape):
        here = replace(lamp, lamp_angle_rad=lamp_angle_reaching(0.5, d, float(x[i])))
        sub[i] = float(here.ratio(c[i], d)) * ref[i]
        h = 1e-3 * c[i]
        dlnr_dc[i] = (np.log(float(here.ratio(c[i] + h, d))) - np.log(float(here.ratio(c[i] - h, d)))) / (2 * h)
    inv = invert_images(sub, ref, lamp, d, sigma_submerged=0.01 * sub, pixel_geometry=geom)
    assert np.all(inv.reason == 0)
    np.testing.assert_allclose(inv.c_mol_per_L, c, rtol=1e-9)
    np.testing.assert_allclose(inv.sigma_ug_per_L, mol_per_L_to_ug_per_L(0.01 / np.abs(dlnr_dc)), rtol=1e-5)
    centre = invert_images(sub, ref, lamp, d).c_mol_per_L
    assert np.max(np.abs(centre / c - 1)) > 0.01


def test_invert_images_with_a_band_model_at_one_depth():
    """A band model (a 20 nm-wide channel at 650 nm, refined geometry off nadir): images of C from 5 to 150 µg/L
    rendered by the band's forward ratio B(C) over a reference of 3, inverted by ``invert_images``: C to 1e-8
    (the band inverse is a table, measured ~1e-9), σ_C from a 1 % σ of each radiance as √2 % / |d ln B / d ln C|
    with the derivative by central differences of B (~1e-6)."""
    band = BandModel(WAVELENGTHS_NM, gaussian_line(650.0, 20.0), geometry=RefinedModel(view_angle_rad=0.3))
    d = 0.4
    c = np.linspace(5.0, 150.0, 12).reshape(3, 4)  # µg/L
    ref = np.full(c.shape, 3.0)
    sub = band.ratio(c, d) * ref
    inv = invert_images(sub, ref, band, d, sigma_submerged=0.01 * sub, sigma_reference=0.01 * ref)
    assert np.all(inv.reason == 0)
    np.testing.assert_allclose(inv.c_ug_per_L, c, rtol=1e-8)
    h = 1e-3 * c
    dlnb_dlnc = (np.log(band.ratio(c + h, d)) - np.log(band.ratio(c - h, d))) / (2 * h) * c
    np.testing.assert_allclose(inv.sigma_ug_per_L, np.hypot(0.01, 0.01) * c / np.abs(dlnb_dlnc), rtol=1e-5)


def test_the_uniform_hermite_table_is_exact_for_a_cubic():
    """Cubic Hermite interpolation reproduces a cubic exactly: the table through y = 2 − w + 0.5 w² − 0.25 w³ and
    its slope on 7 uniform nodes gives y and dy/dw at any w (between nodes, on a node, and past the last node,
    where the last cell's cubic goes on) to rounding; the argument is overwritten (documented), and no slope is
    computed unless asked for."""
    from camcal.water.invert import HermiteTable

    def y(w):
        return 2 - w + 0.5 * w**2 - 0.25 * w**3

    def dy(w):
        return -1 + w - 0.75 * w**2

    nodes = np.linspace(-1.0, 2.0, 7)
    table = HermiteTable.from_nodes(nodes, y(nodes), dy(nodes))
    w = np.array([-1.0, -0.83, 0.0, 0.5, 1.37, 2.0, 2.3])
    got, slope = table.evaluate(w.copy(), with_slope=True)
    np.testing.assert_allclose(got, y(w), rtol=0, atol=1e-13)
    np.testing.assert_allclose(slope, dy(w), rtol=0, atol=1e-12)
    arg = w.copy()
    value, none = table.evaluate(arg)
    assert none is None and np.array_equal(value, got) and not np.array_equal(arg, w)


def test_band_inverse_below_the_first_node_at_the_table_ends_and_its_reasons():
    """Below the first node (C < 1e-4 µg/L) C is linear in δ = ln B(0) − ln r: C = 1e-4 δ/δ(1e-4) with
    σ_C = 1e-4 σ_ln r / δ(1e-4), δ from the forward model written out (rel 1e-8); the ratios of the model
    itself at C = 0 and at the table's ends (1e-4, 1e5 µg/L) give those C (not a reason), with σ_C =
    σ_ln r / |d ln B/dC| at the two ends; NaN and ±inf are NOT_FINITE, 0 and negatives NOT_POSITIVE, a
    ratio above clear water's ABOVE_CLEAR_WATER, one below the table's last node TOO_DARK: C and σ NaN."""
    from camcal.water.invert import CHUNK, Reason

    model = BandModel(INV_WL, INV_C, background_absorption_per_m=0.1)
    inv = model.inverse(0.5)
    b0, b_lo = _inv_forward(0.0)[0], _inv_forward(1e-4)[0]
    delta_lo = np.log(b0) - np.log(b_lo)
    r = np.array([b0 * np.exp(-0.3 * delta_lo), b0 * np.exp(-0.8 * delta_lo)])
    low = inv.concentration(r, sigma_ln_ratio=0.01)
    np.testing.assert_allclose(low.c_ug_per_L, [0.3e-4, 0.8e-4], rtol=1e-8)
    np.testing.assert_allclose(low.sigma_ug_per_L, 1e-4 * 0.01 / delta_lo, rtol=1e-8)
    np.testing.assert_allclose(inv.concentration(r, sigma_ln_ratio=np.array([0.01, 0.04])).sigma_ug_per_L,
                               1e-4 * np.array([0.01, 0.04]) / delta_lo, rtol=1e-8)
    ends = inv.concentration(model.ratio(np.array([0.0, 1e-4, 1e5]), 0.5), sigma_ln_ratio=0.01)
    assert not np.any(ends.reason)
    np.testing.assert_allclose(ends.c_ug_per_L, [0.0, 1e-4, 1e5], rtol=1e-9, atol=0)
    np.testing.assert_allclose(ends.sigma_ug_per_L[1:], _inv_sigma(np.array([1e-4, 1e5]), 0.01), rtol=1e-4)
    bad = inv.concentration(np.array([np.nan, np.inf, -np.inf, 0.0, -0.2, 1.01 * b0, 1e-300]), sigma_ln_ratio=0.01)
    assert bad.reason.tolist() == [Reason.NOT_FINITE] * 3 + [Reason.NOT_POSITIVE] * 2 + [
        Reason.ABOVE_CLEAR_WATER, Reason.TOO_DARK]
    assert np.all(np.isnan(bad.c_ug_per_L)) and np.all(np.isnan(bad.sigma_ug_per_L))
    # more pixels than one chunk, each with its own σ_ln r: σ_C/σ_ln r is one number
    many = np.full(CHUNK + 3, _inv_forward(7.0)[0])
    sig = np.linspace(0.01, 0.02, many.size)
    out = inv.concentration(many, sigma_ln_ratio=sig)
    np.testing.assert_allclose(out.sigma_ug_per_L / sig, _inv_sigma(np.array([7.0]), 1.0)[0], rtol=1e-4)

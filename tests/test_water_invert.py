"""Water module: per-pixel inversion (Newton and table), reasons, uncertainty, band-aware inversion."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from camcal.reference_spectra import WAVELENGTHS_NM, gaussian_line
from camcal.water.band import BandModel, bricaud_1998, solvent_spectrum
from camcal.water.invert import Reason, invert_images, invert_ratio, tau_newton, tau_table
from camcal.water.models import RefinedModel, SeedModel
from camcal.water.purewater import pure_water_absorption_per_m
from camcal.water.units import mol_per_L_to_ug_per_L


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

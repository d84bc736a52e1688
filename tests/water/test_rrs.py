"""The water-colour models: sky-glint ρ, the Rrs estimator on numbers, glint screening, products, the column."""

from __future__ import annotations

import numpy as np
import pytest

from camcal.errors import CamcalError
from camcal.water.column import column_radiance, subsurface_rrs, u_from_rrs
from camcal.water.products import (
    SPM_NECHAD_2010,
    TURBIDITY_DOGLIOTTI_2015,
    apply_algorithm,
    at_wavelength,
    band_ratio,
    effective_wavelength_nm,
    product,
)
from camcal.water.purewater import pure_water_absorption_per_m
from camcal.water.rrs import (
    BANDS,
    CARD_REFLECTANCE,
    PhotoStats,
    card_band_reflectance,
    estimate_rrs,
    hydrocolor_rrs,
    profile_term,
    region_stats,
    screen_water,
)
from camcal.water.skyglint import RHO_HYDROCOLOR, cox_munk_mss, rho_flat, rho_rough, rho_with_sigma


def test_rho_flat_is_fresnel_at_the_view_angle():
    assert rho_flat(40.0) == pytest.approx(0.0242, abs=5e-5)  # physics notes: 0.0242 at 40 deg, n = 1.33
    assert rho_rough(40.0, 0.0) == pytest.approx(rho_flat(40.0), rel=0.01)  # Cox-Munk's calm sea, σ² = 0.003
    assert rho_rough(40.0, 0.0) > rho_flat(40.0)


def test_rho_rises_with_wind_and_converges():
    values = [rho_flat(40.0)] + [rho_rough(40.0, w) for w in (0.0, 2.0, 5.0, 10.0)]
    assert np.all(np.diff(values) > 0)
    assert 0.0250 < values[3] < 0.0260  # Cox-Munk, uniform sky, 5 m/s
    assert rho_rough(40.0, 10.0, nodes=96) == pytest.approx(values[4], rel=2e-3)  # the quadrature has converged
    assert cox_munk_mss(5.0) == pytest.approx(0.0286)
    with pytest.raises(CamcalError):
        cox_munk_mss(-1.0)


def test_rho_sigma_covers_mobley_and_hydrocolor():
    r = rho_with_sigma(40.0, 5.0, 2.0)
    assert set(r.terms) == {"wind", "sky_structure"} and r.sigma == pytest.approx(np.hypot(*r.terms.values()))
    assert abs(RHO_HYDROCOLOR - r.value) < 2 * r.sigma  # Mobley (1999)'s 0.028 for a real sky: within 2σ
    flat = rho_with_sigma(40.0, None)
    assert flat.value == rho_flat(40.0) and set(flat.terms) == {"sky_structure"}


def _stats(name, kind, mean, se=1e-6, sat=0.0, bright=0.0):
    return PhotoStats(name, kind, {b: mean[i] for i, b in enumerate(BANDS)}, {b: se for b in BANDS}, 1000, sat,
                      bright)


def test_estimate_rrs_is_the_equation_with_its_terms():
    water = [_stats(f"w{i}", "water", (0.010, 0.020, 0.030)) for i in range(3)]
    sky = [_stats("s", "sky", (0.05, 0.08, 0.12))]
    card = [_stats("c", "card", (0.06, 0.07, 0.08))]
    rho = rho_with_sigma(40.0, 5.0)
    res = estimate_rrs(water, sky, card, rho, card_band_reflectance(None, {}, None))
    for i, b in enumerate(BANDS):
        lt, ls, lc = (0.010, 0.020, 0.030)[i], (0.05, 0.08, 0.12)[i], (0.06, 0.07, 0.08)[i]
        assert res.rrs[b] == pytest.approx((lt - rho.value * ls) * CARD_REFLECTANCE / (np.pi * lc))
        assert res.terms[b]["rho"] == pytest.approx(rho.sigma * ls * CARD_REFLECTANCE / (np.pi * lc))
        assert res.terms[b]["sky_variability"] > 0  # one sky photo: the stated variability
        assert res.dominant[b] == max(res.terms[b], key=res.terms[b].get)
        assert res.hydrocolor[b] == pytest.approx((lt - 0.028 * ls) * 0.18 / (np.pi * lc))
    # a flat card's reflectance and its σ cancel in a band ratio
    r, s = res.ratios["B/G"]
    assert r == pytest.approx(res.rrs["B"] / res.rrs["G"])
    shared_card = res.terms["B"]["card_reflectance"] / res.rrs["B"]
    assert shared_card > 0.01 and s < r * shared_card


def test_band_ratio_shared_terms_cancel():
    assert band_ratio(2.0, 0.0, 1.0, 0.0, {"k": (0.05, 0.05)}) == (2.0, 0.0)
    assert band_ratio(2.0, 0.03, 1.0, 0.04, {})[1] == pytest.approx(2.0 * 0.05)


def test_screening_names_glint_and_keeps_waves():
    rng = np.random.default_rng(5)
    photos = [_stats(f"w{i}", "water", 0.01 * (1 + 0.005 * rng.standard_normal(3)), se=2e-6) for i in range(5)]
    assert len(screen_water(photos)) == 5  # waves alone: nobody is rejected
    photos[1].saturated_fraction = 0.02
    photos[3].mean["G"] *= 1.3  # a whitecap, unsaturated
    photos[4].bright_fraction = 0.05
    kept = screen_water(photos)
    assert [p.name for p in kept] == ["w0", "w2"]
    assert "saturated" in photos[1].rejected and "robust" in photos[3].rejected and "bright" in photos[4].rejected


def test_region_stats_counts_saturation_and_sparkle():
    rng = np.random.default_rng(1)
    ch = {b: 1.0 + 0.01 * rng.standard_normal((40, 60)) for b in BANDS}
    s = region_stats(ch, "x", "water")
    assert s.saturated_fraction == 0 and s.bright_fraction < 1e-3 and s.n_pixels == 20 * 30
    ch["R"][12:14, 20:30] = np.nan
    ch["G"][15:20, 20:30] = 5.0
    s = region_stats(ch, "x", "water")
    assert s.saturated_fraction == pytest.approx(20 / 600) and s.bright_fraction == pytest.approx(50 / 600)


def test_card_reflectance_band_weighting():
    wl = np.arange(400.0, 701.0, 5.0)
    sens = {"R": np.exp(-0.5 * ((wl - 600) / 30) ** 2), "G": np.exp(-0.5 * ((wl - 530) / 30) ** 2),
            "B": np.exp(-0.5 * ((wl - 460) / 30) ** 2)}
    card = card_band_reflectance(wl, sens, None, wl, 0.1 + 0.001 * (wl - 400))  # a sloped card
    assert card["R"][0] == pytest.approx(0.3, abs=2e-3) and card["B"][0] == pytest.approx(0.16, abs=2e-3)
    assert card["G"][1] == pytest.approx(0.02 * card["G"][0], rel=1e-6)
    # profile σ: nothing without one, something with one, zero for an Rrs flat in λ and a flat card
    rrs = {"R": 0.002, "G": 0.004, "B": 0.006}
    assert profile_term(rrs, wl, sens, None, None) == {b: 0.0 for b in BANDS}
    sig = {b: 0.1 * s * (wl - 550) / 150 for b, s in sens.items()}
    assert all(v > 0 for v in profile_term(rrs, wl, sens, sig, None).values())
    flat = profile_term({b: 0.003 for b in BANDS}, wl, sens, sig, None)
    assert max(flat.values()) < 1e-12
    assert effective_wavelength_nm(wl, sens["R"]) == pytest.approx(600.0, abs=0.5)


def test_products_published_values_and_their_range():
    # Dogliotti et al. (2015) at 645 nm: T = 228.1 ρw/(1 − ρw/0.1641)
    t, s, dx = apply_algorithm(TURBIDITY_DOGLIOTTI_2015, 0.02 / np.pi, 1e-4)
    assert float(t) == pytest.approx(228.1 * 0.02 / (1 - 0.02 / 0.1641))
    h = 1e-7
    fd = (apply_algorithm(TURBIDITY_DOGLIOTTI_2015, 0.02 / np.pi + h)[0] - apply_algorithm(
        TURBIDITY_DOGLIOTTI_2015, 0.02 / np.pi - h)[0]) / (2 * h)
    assert float(dx) == pytest.approx(float(fd), rel=1e-5) and float(s) == pytest.approx(float(dx) * 1e-4)
    same, rel = at_wavelength(SPM_NECHAD_2010, 665.0)
    assert same.a == pytest.approx(355.85) and rel == 0
    moved, rel = at_wavelength(SPM_NECHAD_2010, 600.0)
    assert moved.a == pytest.approx(355.85 * pure_water_absorption_per_m(600.0) / pure_water_absorption_per_m(665.0))
    assert rel == pytest.approx(0.13)
    ok = product(TURBIDITY_DOGLIOTTI_2015, 0.005, 1e-4, 645.0)
    assert ok.valid and ok.sigma >= ok.sigma_rrs
    beyond = product(TURBIDITY_DOGLIOTTI_2015, 0.02, 1e-4, 645.0)  # ρw = 0.063 > 0.05
    assert not beyond.valid and "NIR" in beyond.validity
    assert not np.isfinite(product(SPM_NECHAD_2010, -1e-4, 1e-4, 600.0).value)


def test_column_radiance_limits():
    rrs, ed = 0.004, 1.3
    u = u_from_rrs(rrs)
    r = 0.089 * u + 0.125 * u * u
    assert float(r) == pytest.approx(float(subsurface_rrs(rrs)))
    assert float(column_radiance(rrs, ed, 0.0, 0.5)) == 0.0
    assert float(column_radiance(rrs, ed, 100.0, 0.5)) == pytest.approx(rrs * ed)
    shallow, deeper = column_radiance(rrs, ed, [0.2, 0.5], 0.5, sun_zenith_deg=30.0)
    assert 0 < shallow < deeper < rrs * ed


def test_hydrocolor_is_a_fixed_rho():
    one = {b: 1.0 for b in BANDS}
    assert hydrocolor_rrs(one, one, one)["R"] == pytest.approx((1 - 0.028) * 0.18 / np.pi)


def test_rho_of_the_cie_clear_sky_against_mobley_1999():
    from camcal.water.skyglint import cie_sky_relative, rho_sky, rho_sky_with_sigma

    # Mobley (1999): 0.028 at 40° from nadir, 135° from the sun, 5 m/s, with a Hydrolight sky
    r = rho_sky_with_sigma(40.0, 5.0, 2.0, 30.0, 135.0)
    assert r.value == pytest.approx(0.028, abs=0.0008)
    assert set(r.terms) == {"wind", "sky_structure"} and 0 < r.terms["sky_structure"] < 0.05 * r.value
    # a sky brightening to the horizon reflects more than a uniform one; calm water tends to Fresnel
    assert r.value > 1.05 * rho_rough(40.0, 5.0)
    assert rho_sky(40.0, 0.0, 30.0, 135.0) == pytest.approx(rho_rough(40.0, 0.0), rel=0.02)
    # the CIE clear sky: brighter near the sun and towards the horizon than at 90° from the sun at 40° zenith
    mid = cie_sky_relative(np.cos(np.radians(40)), np.pi / 2)
    assert cie_sky_relative(np.cos(np.radians(40)), 0.2) > 3 * mid
    assert cie_sky_relative(np.cos(np.radians(80)), np.pi / 2) > 1.5 * mid

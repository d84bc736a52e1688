"""The formulas of the calibration stages and of the band water model at non-trivial operating points (issue 29).

The companion of ``tests/test_formulas.py`` for dark, flat, response, spectral, radiance and the band/field
water model: each test checks one formula against a value computed by other means (a closed-form integral, a
published constant, exact synthetic data, an independent rendering written out here), never against the
function under test. They were written to kill mutants that survived the rest of the suite (docs/testing.md).
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import colour
import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import erf, eval_legendre, gammainccinv

from camcal import units
from camcal.apply.radiance import (
    RadianceModel,
    _interp,
    radiance_at,
    radiance_model,
    smooth_error_table,
    smooth_operator,
    smooth_spread_rel,
)
from camcal.calibrate.dark import _fit_lines, fit_dark
from camcal.calibrate.dark_frames import DarkOptions, DarkStacks
from camcal.calibrate.dark_noise import noise_model, temporal_noise
from camcal.calibrate.flat import _quadratic_vertex, _total_degree_mask, fit_2d_plane, fit_radial_plane
from camcal.calibrate.response import fit_eq12, fit_line, fit_srgb_form, saturation_point
from camcal.calibrate.stack import StackResult
from camcal.calibrate.sweep import deconvolve_slit, slit_matrix
from camcal.errors import CamcalError
from camcal.frame import PLANES, Exposure
from camcal.models.correct import Corrected, dark_frame, system_gain_dn_per_e
from camcal.models.dark import DEAD, HOT, NOISY, DarkModel
from camcal.models.flat import FlatModel, PlaneGeometry, dead_pixels, radial_gain
from camcal.models.response import (
    ChannelResponse,
    ColourMatrix,
    ResponseModel,
    srgb_form_decode,
    srgb_form_encode,
    srgb_form_toe,
)
from camcal.models.spectral import SpectralSensitivity, to_relative
from camcal.water.band import BandModel, ChlorophyllAbsorption, bricaud_1998, solvent_spectrum
from camcal.water.field import FieldGeometry, MeasuredSky, field_band_model
from camcal.water.models import LampModel, RefinedModel, SeedModel
from camcal.water.purewater import pure_water_absorption_per_m
from camcal.water.uncertainty import Uncertain, combine, interpolate_term, solve_c, term_sigma_c
from tests.oracles import correct_flat, merge_sweeps, monte_carlo_sigma, subtract_dark


def test_pure_water_absorption_is_pope_and_fry():
    """Pope & Fry (1997), table 3: a_w = 0.00635, 0.0204, 0.2224, 0.410, 0.624 m⁻¹ at 440, 500, 600, 660, 700 nm;
    linear between the 2.5 nm nodes (662.5 nm: 0.429 m⁻¹) and the end values held outside 380-727.5 nm."""
    got = pure_water_absorption_per_m(np.array([440.0, 500.0, 600.0, 660.0, 700.0]))
    np.testing.assert_allclose(got, [0.00635, 0.0204, 0.2224, 0.410, 0.624], rtol=1e-9)
    mid = float(pure_water_absorption_per_m(661.25))
    assert mid == pytest.approx(0.5 * (0.410 + float(pure_water_absorption_per_m(662.5))), rel=1e-12)
    assert float(pure_water_absorption_per_m(300.0)) == float(pure_water_absorption_per_m(380.0))


# ---- radiance: the band integral, the narrowband and smooth estimators, the propagation ---------------------

def _gauss(wl, mu, s, a=1.0):
    return a * np.exp(-0.5 * ((np.asarray(wl, float) - mu) / s) ** 2)


def test_band_integral_and_its_uncertainty_are_closed_forms():
    """∫ A exp(−(λ−μ)²/2s²) dλ over 380-780 nm = A s √(π/2) [erf(·)] (the trapezoid rule on a 2 nm grid: 4e-7
    off for the blue curve, cut 4σ from its centre at 380 nm); the band's uncertainty with a constant σ_c per
    2 nm sample (0.3 here) is σ_c · 2 nm · √n."""
    wl = np.arange(380.0, 781.0, 2.0)
    c = {"R": _gauss(wl, 600, 25, 40.0), "G": _gauss(wl, 540, 30, 55.0), "B": _gauss(wl, 460, 20, 30.0)}
    u = {k: np.full(wl.size, 0.3) for k in c}
    m = radiance_model(wl, c, u, 663.0, "smooth")
    expect = [a * s * np.sqrt(np.pi / 2) * (erf((780 - mu) / (s * np.sqrt(2))) - erf((380 - mu) / (s * np.sqrt(2))))
              for mu, s, a in ((600, 25, 40.0), (540, 30, 55.0), (460, 20, 30.0))]
    np.testing.assert_allclose(m.band_integral, expect, rtol=1e-6)
    np.testing.assert_allclose(m.band_unc, 0.3 * 2.0 * np.sqrt(wl.size), rtol=1e-12)
    # the smooth estimator's relative uncertainty: the three bands' relative uncertainties in quadrature / √3
    rel = np.sqrt(np.mean((m.band_unc / m.band_integral) ** 2))
    assert m.weights_unc_rel == pytest.approx(rel, rel=1e-12)


def test_narrowband_estimator_off_a_sample_picks_the_strongest_channel_and_divides_by_the_filter():
    """At 663 nm (off the 5 nm grid) the estimator is 1/c(663) of the channel with the largest c, read off a cubic
    spline (error < 1e-4 of a 25 nm-wide Gaussian sampled every 5 nm); the green channel is the strongest there
    in this set-up, so the weight sits on G. With a 10 nm filter the weight is divided by 10 (mean spectral
    radiance). The relative uncertainty is σ_c(663)/c(663) of that channel (σ_c = 3 % of c here)."""
    wl = np.arange(400.0, 721.0, 5.0)
    c = {"R": _gauss(wl, 600, 25, 40.0), "G": _gauss(wl, 680, 25, 30.0), "B": _gauss(wl, 460, 20, 30.0)}
    u = {k: 0.03 * v for k, v in c.items()}
    c_true = {k: float(_gauss(663.0, mu, s, a)) for k, (mu, s, a) in
              {"R": (600, 25, 40.0), "G": (680, 25, 30.0), "B": (460, 20, 30.0)}.items()}
    assert c_true["G"] > c_true["R"]
    m = radiance_model(wl, c, u, 663.0, "narrowband")
    assert m.channel == "G"
    np.testing.assert_allclose(m.weights, [0.0, 1.0 / c_true["G"], 0.0], rtol=1e-4)
    assert m.weights_unc_rel == pytest.approx(0.03, rel=1e-3)
    assert m.units.startswith(f"{units.IN_BAND_RADIANCE} (")
    mf = radiance_model(wl, c, u, 663.0, "narrowband", filter_fwhm_nm=10.0)
    np.testing.assert_allclose(mf.weights, m.weights / 10.0, rtol=1e-12)
    assert units.SPECTRAL_RADIANCE in mf.units


def test_smooth_estimator_reproduces_a_spectrum_the_prior_explains():
    """The smooth estimator is a Gaussian-process posterior mean with prior K(λ, λ') = 1 + exp(−(λ−λ')²/2ℓ²),
    ℓ = 60 nm. By the representer theorem, a spectrum of the form L = K·cᵀ·a (any a) is reconstructed exactly in
    the noise-free limit: rates = ∫ c L dλ (computed here with the trapezoid rule on curves that vanish at the
    grid's ends) give back L(λ0). The regularisation ε = 1e-6 of the trace biases it by < 1e-4 (measured 2e-6).
    The kernel is written out here; a different length, a missing constant term or a wrong sign of the exponent
    reconstruct another spectrum."""
    wl = np.arange(401.0, 722.0, 2.0)  # a 2 nm step: the quadrature weights are not 1
    c = np.stack([_gauss(wl, 600, 25, 40.0), _gauss(wl, 540, 30, 55.0), _gauss(wl, 460, 20, 30.0)])
    d = wl[:, None] - wl[None, :]
    k = 1.0 + np.exp(-0.5 * (d / 60.0) ** 2)
    spectrum = k @ c.T @ np.array([2e-3, -5e-4, 1e-3])  # W m^-2 sr^-1 nm^-1, positive over the grid
    assert spectrum.min() > 0
    rates = np.trapezoid(c * spectrum[None, :], wl, axis=1)
    m = radiance_model(wl, dict(zip("RGB", c, strict=True)), None, 663.0, "smooth")
    i = int(np.flatnonzero(wl == 663.0)[0])  # a grid node
    assert float(m.weights @ rates) == pytest.approx(spectrum[i], rel=1e-4)
    assert m.channel is None and m.units == units.SPECTRAL_RADIANCE
    assert m.wavelength_nm == 663.0 and m.estimator == "smooth"
    # between grid nodes the estimate is read linearly from the reconstruction on the grid
    m2 = radiance_model(wl, dict(zip("RGB", c, strict=True)), None, 664.0, "smooth")
    assert float(m2.weights @ rates) == pytest.approx(0.5 * (spectrum[i] + spectrum[i + 1]), rel=1e-4)


def test_smooth_estimator_regularisation_is_relative_to_the_trace():
    """With a strong regularisation ε = 0.1 the estimate is the ridge posterior mean
    K Cᵀ (C K Cᵀ + ε tr(C K Cᵀ)/3 · I)⁻¹ (C the rates' quadrature rows, 2 nm weights; K written out): checked
    for every grid point, so a regularisation of another size or sign is seen."""
    wl = np.arange(401.0, 722.0, 2.0)
    c = np.stack([_gauss(wl, 600, 25, 40.0), _gauss(wl, 540, 30, 55.0), _gauss(wl, 460, 20, 30.0)])
    k = 1.0 + np.exp(-0.5 * ((wl[:, None] - wl[None, :]) / 60.0) ** 2)
    cm = 2.0 * c
    ckc = cm @ k @ cm.T
    expect = k @ cm.T @ np.linalg.solve(ckc + 0.1 * np.trace(ckc) / 3 * np.eye(3), np.eye(3))
    np.testing.assert_allclose(smooth_operator(wl, c, eps=0.1), expect, rtol=1e-9, atol=1e-15)


def test_radiance_uncertainty_adds_noise_and_calibration_in_quadrature():
    """σ_L² = Σ w_i² σ_rate,i² + (u_rel · L)², per pixel, with L = Σ w_i rate_i (written out for 2 pixels)."""
    m = RadianceModel(np.ones(3), np.zeros(3), 663.0, "smooth", np.array([0.5, -0.2, 0.1]), 0.04, "u", None)
    rates = np.array([[100.0, 10.0], [50.0, 20.0], [30.0, 40.0]])
    var = np.array([[4.0, 1.0], [9.0, 4.0], [16.0, 25.0]])
    value, unc = radiance_at(rates, var, m)
    expect = np.array([0.5 * 100 - 0.2 * 50 + 0.1 * 30, 0.5 * 10 - 0.2 * 20 + 0.1 * 40])
    np.testing.assert_allclose(value, expect, rtol=1e-12)
    noise = np.array([0.25 * 4 + 0.04 * 9 + 0.01 * 16, 0.25 * 1 + 0.04 * 4 + 0.01 * 25])
    np.testing.assert_allclose(unc, np.sqrt(noise + (0.04 * expect) ** 2), rtol=1e-12)
    _, unc0 = radiance_at(rates, None, m)
    np.testing.assert_allclose(unc0, 0.04 * np.abs(expect), rtol=1e-12)


def test_radiance_wavelength_outside_the_curve_is_refused():
    wl = np.arange(400.0, 701.0, 5.0)
    c = {k: _gauss(wl, 550, 40) for k in "RGB"}
    with pytest.raises(CamcalError, match="outside the calibrated range"):
        radiance_model(wl, c, None, 705.0)
    with pytest.raises(CamcalError, match="unknown estimator"):
        radiance_model(wl, c, None, 663.0, "band")


# ---- flat: the DNG radial model, the 2-D Legendre model, their fits ---------------------------------------------

# A Bayer RGGB sensor of 60 x 80 mosaic pixels (planes 30 x 40), the optical centre off the middle.
FLAT_SHAPE = (30, 40)
FLAT_OFFSETS = {"R": (0, 0), "G1": (0, 1), "G2": (1, 0), "B": (1, 1)}  # (row, column) in the 2x2 cell, RGGB


def _dng_radial_gain(channel, cx, cy, k, xx, yy):
    """DNG FixVignetteRadial written out: r from the optical centre in mosaic pixels, normalised by the distance
    to the farthest corner of the 80 x 60 image; g = 1 + k0 r² + k1 r⁴ + k2 r⁶ + k3 r⁸ + k4 r¹⁰."""
    oy, ox = FLAT_OFFSETS[channel]
    fx, fy = 2 * xx + ox, 2 * yy + oy
    fcx, fcy = 2 * cx + ox, 2 * cy + oy
    rmax = max(np.hypot(cxn - fcx, cyn - fcy) for cxn in (0.0, 79.0) for cyn in (0.0, 59.0))
    r2 = ((fx - fcx) ** 2 + (fy - fcy) ** 2) / rmax**2
    return np.polynomial.polynomial.polyval(r2, [1.0, *k])


def _flat_model(k, centre, model_2d=None, prnu=None):
    chans = ("R", "G1", "G2", "B")
    return FlatModel(channels=chans, centre_px={c: centre for c in chans}, k={c: k for c in chans},
                     model_2d=model_2d, prnu=prnu, residual_rms={}, shape=FLAT_SHAPE, cfa_pattern="RGGB")


def test_radial_flat_gain_off_centre_is_the_dng_polynomial():
    """Every plane's gain against the DNG polynomial written out, with five non-zero k and the centre at plane
    pixel (14.3, 9.6) (off the middle, so the farthest corner and each plane's offset matter)."""
    k = (-0.35, 0.08, -0.05, 0.02, -0.01)
    fm = _flat_model(k, (14.3, 9.6))
    yy, xx = np.mgrid[0:30, 0:40].astype(float)
    g = fm.gain()
    for i, c in enumerate(fm.channels):
        np.testing.assert_allclose(g[i], _dng_radial_gain(c, 14.3, 9.6, k, xx, yy), rtol=2e-7)  # float32 output
        corners = [_dng_radial_gain(c, 14.3, 9.6, k, x, y) for x in (0.0, 39.0) for y in (0.0, 29.0)]
        assert fm.corner_gain()[c] == pytest.approx(min(corners), rel=2e-7)
    assert fm.centre_full_px()["G2"] == pytest.approx((28.6, 20.2))


def test_flat_gain_with_prnu_multiplies_and_dead_pixels_are_below_half():
    prnu = np.full((4, *FLAT_SHAPE), 1.02, np.float32)
    prnu[2, 3, 4] = 0.3
    fm = _flat_model((-0.3, 0.0, 0.0, 0.0, 0.0), (20.0, 15.0), prnu=prnu)
    np.testing.assert_allclose(fm.gain(with_prnu=True), fm.gain() * prnu, rtol=1e-7)
    dead = dead_pixels(fm)
    assert dead.sum() == 1 and dead[2, 3, 4]
    assert dead_pixels(fm, threshold=1.03).all()


def test_2d_flat_gain_is_the_legendre_series_across_the_full_image():
    """g(u, v) = s Σ c_ij P_i(u) P_j(v), u = 2X/(W−1) − 1 and v = 2Y/(H−1) − 1 on full-resolution pixel centres
    (X, Y), with the Legendre polynomials from scipy.special, the scale s = 0.9 and a non-symmetric c."""
    coef = np.array([[1.0, 0.05, -0.1], [0.08, -0.03, 0.0], [-0.2, 0.0, 0.0]])
    m2 = {"kind": "legendre2d", "degree": 2, "coefficients": {c: coef.tolist() for c in FLAT_OFFSETS},
          "scale": {c: 0.9 for c in FLAT_OFFSETS}}
    fm = _flat_model((0.0,) * 5, (20.0, 15.0), model_2d=m2)
    yy, xx = np.mgrid[0:30, 0:40].astype(float)
    g = fm.gain()
    for i, c in enumerate(fm.channels):
        oy, ox = FLAT_OFFSETS[c]
        u, v = 2 * (2 * xx + ox) / 79.0 - 1, 2 * (2 * yy + oy) / 59.0 - 1
        expect = 0.9 * sum(coef[a, b] * eval_legendre(a, u) * eval_legendre(b, v) for a in range(3) for b in range(3))
        np.testing.assert_allclose(g[i], expect, rtol=2e-6, atol=1e-7)


def test_2d_flat_corner_values_are_the_legendre_series_at_each_planes_corners():
    """``corner_values`` evaluates a 2-D model at the four corners of each plane only (no full map): the Legendre
    series written out at the corner pixel centres (X, Y) of each plane's offset in the 80 x 60 mosaic, with a
    non-symmetric c (x and y not interchangeable) and a different scale per plane (planes not interchangeable).
    The corner gain is the smallest of the four, as float32 values."""
    coef = np.array([[1.0, 0.05, -0.1], [0.08, -0.03, 0.0], [-0.2, 0.0, 0.0]])
    scale = {"R": 0.9, "G1": 0.95, "G2": 0.85, "B": 0.8}
    m2 = {"kind": "legendre2d", "degree": 2, "coefficients": {c: coef.tolist() for c in FLAT_OFFSETS},
          "scale": scale}
    fm = _flat_model((0.0,) * 5, (20.0, 15.0), model_2d=m2)
    got = fm.corner_values()
    assert got.shape == (4, 4)
    for i, c in enumerate(fm.channels):
        oy, ox = FLAT_OFFSETS[c]
        xx, yy = np.array([0.0, 39.0, 0.0, 39.0]), np.array([0.0, 0.0, 29.0, 29.0])  # corners in corner_values' order
        u, v = 2 * (2 * xx + ox) / 79.0 - 1, 2 * (2 * yy + oy) / 59.0 - 1
        expect = scale[c] * sum(coef[a, b] * eval_legendre(a, u) * eval_legendre(b, v)
                                for a in range(3) for b in range(3))
        np.testing.assert_allclose(got[i], expect, rtol=1e-12)
        assert fm.corner_gain()[c] == float(np.float32(expect).min())


def test_a_held_flat_gain_given_in_float64_is_kept_in_float32():
    """A calibration may pass ``with_gain`` a float64 map; the model holds and returns float32 (the type of every
    evaluated gain and of the profile's maps), with the values rounded to float32."""
    fm = _flat_model((-0.3, 0.0, 0.0, 0.0, 0.0), (20.0, 15.0))
    g64 = np.full((4, *FLAT_SHAPE), 0.1, np.float64)
    held = fm.with_gain(g64).gain()
    assert held.dtype == np.float32 and np.all(held == np.float32(0.1))


def test_radial_fit_recovers_an_off_centre_vignetting_from_exact_data():
    """A·g(r) rendered exactly (A = 1800 DN, centre (13.2, 17.7) plane px, k = (−0.4, 0.1, −0.05)) on a 36 x 48
    plane: the variable-projection fit returns A, the centre and k to 1e-5 (exact data; the centre search stops
    at xtol 1e-7) and a zero residual."""
    geom = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (36, 48), "RGGB")
    yy, xx = np.mgrid[0:36, 0:48].astype(float)
    fx, fy = 2 * xx + 1, 2 * yy + 0  # G1: column offset 1
    fcx, fcy = 2 * 13.2 + 1, 2 * 17.7
    rmax = max(np.hypot(a - fcx, b - fcy) for a in (0.0, 95.0) for b in (0.0, 71.0))
    r2 = ((fx - fcx) ** 2 + (fy - fcy) ** 2) / rmax**2
    block = 1800.0 * (1 - 0.4 * r2 + 0.1 * r2**2 - 0.05 * r2**3)
    level, centre, k, rms = fit_radial_plane(block, xx, yy, geom, "G1", n_terms=3)
    assert level == pytest.approx(1800.0, rel=1e-6)
    assert centre == pytest.approx((13.2, 17.7), abs=1e-4)
    assert k == pytest.approx((-0.4, 0.1, -0.05, 0.0, 0.0), abs=1e-5)
    assert rms < 1e-6


def test_2d_fit_recovers_a_legendre_surface_normalised_at_the_centre():
    """A degree-2 Legendre surface (scaled by 1500 DN) is fitted back exactly; the returned level is the surface
    at the given centre and the coefficients are those of the surface divided by it."""
    geom = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (36, 48), "RGGB")
    yy, xx = np.mgrid[0:36, 0:48].astype(float)
    u, v = 2 * (2 * xx + 1) / 95.0 - 1, 2 * (2 * yy + 1) / 71.0 - 1  # B: offsets (1, 1)
    coef = np.array([[1.0, 0.05, -0.1], [0.08, -0.03, 0.0], [-0.2, 0.0, 0.0]])

    def surf(uu, vv):
        return 1500.0 * sum(coef[a, b] * eval_legendre(a, uu) * eval_legendre(b, vv)
                            for a in range(3) for b in range(3))

    level, c_norm, scale, rms = fit_2d_plane(surf(u, v), xx, yy, geom, "B", 2, (30.0, 10.0))
    uc, vc = 2 * 61.0 / 95.0 - 1, 2 * 21.0 / 71.0 - 1
    assert level == pytest.approx(surf(uc, vc), rel=1e-9)
    np.testing.assert_allclose(c_norm * level, 1500.0 * coef, atol=1e-8)
    assert scale == 1.0 and rms < 1e-9
    assert _total_degree_mask(2).sum() == 6


def test_correct_flat_divides_by_the_gain():
    fm = _flat_model((-0.3, 0.05, 0.0, 0.0, 0.0), (10.0, 20.0))
    planes = np.full((4, *FLAT_SHAPE), 500.0, np.float32)
    yy, xx = np.mgrid[0:30, 0:40].astype(float)
    g = np.stack([_dng_radial_gain(c, 10.0, 20.0, (-0.3, 0.05, 0.0, 0.0, 0.0), xx, yy) for c in fm.channels])
    np.testing.assert_allclose(correct_flat(planes * g, fm), planes, rtol=1e-5)


def test_flat_corner_gain_is_the_smallest_of_the_four_corners_of_each_plane():
    """Each plane's optical centre near a different corner, so that each plane's smallest corner gain is at a
    different corner (the one farthest from its centre): the four corners of every plane against the DNG
    polynomial written out."""
    k = (-0.35, 0.08, -0.05, 0.02, -0.01)
    centres = {"R": (33.0, 24.0), "G1": (6.0, 25.0), "G2": (34.0, 4.0), "B": (5.0, 5.0)}
    fm = FlatModel(channels=("R", "G1", "G2", "B"), centre_px=centres, k={c: k for c in centres}, model_2d=None,
                   prnu=None, residual_rms={}, shape=FLAT_SHAPE, cfa_pattern="RGGB")
    got = fm.corner_gain()
    for c, (cx, cy) in centres.items():
        corners = {(x, y): float(_dng_radial_gain(c, cx, cy, k, x, y)) for x in (0.0, 39.0) for y in (0.0, 29.0)}
        assert got[c] == pytest.approx(min(corners.values()), rel=2e-7)  # float32 gains
    farthest = {c: min(corners, key=corners.get) for c, corners in
                ((c, {(x, y): float(_dng_radial_gain(c, *centres[c], k, x, y)) for x in (0.0, 39.0)
                      for y in (0.0, 29.0)}) for c in centres)}
    assert sorted(farthest.values()) == [(0.0, 0.0), (0.0, 29.0), (39.0, 0.0), (39.0, 29.0)]


def test_flat_model_returns_the_gain_it_holds_and_its_corner_gains_are_the_float32_maps():
    """A model holding a gain (``with_gain``, as a calibration's fit passes it on) returns that array, read-only,
    not the model evaluated again: a held gain of 0.5 everywhere (the DNG polynomial gives 1 at the centre) comes
    back as 0.5. The corner gains are the float32 values of the map :meth:`gain` evaluates (exactly, not to
    float32 rounding)."""
    k = (-0.35, 0.08, -0.05, 0.02, -0.01)
    centres = {"R": (33.0, 24.0), "G1": (6.0, 25.0), "G2": (34.0, 4.0), "B": (5.0, 5.0)}
    fm = FlatModel(channels=("R", "G1", "G2", "B"), centre_px=centres, k={c: k for c in centres}, model_2d=None,
                   prnu=None, residual_rms={}, shape=FLAT_SHAPE, cfa_pattern="RGGB")
    g = fm.gain()
    assert g.dtype == np.float32
    corners = g[:, [0, 0, -1, -1], [0, -1, 0, -1]]
    assert fm.corner_gain() == {c: float(corners[i].min()) for i, c in enumerate(fm.channels)}
    held = fm.with_gain(np.full(g.shape, 0.5, np.float32)).gain()
    assert held.shape == g.shape and np.all(held == 0.5) and not held.flags.writeable


def test_radial_gain_with_zero_coefficients_is_the_power_sum():
    """``radial_gain`` skips trailing zero coefficients; the values must stay those of g = 1 + Σ kᵢ r^(2i+2)
    (numpy's polyval, written out): no vignetting at all (every k = 0), a zero before a non-zero coefficient,
    and trailing zeros."""
    r2 = np.linspace(0.0, 1.0, 11)
    for k in ((0.0, 0.0, 0.0, 0.0, 0.0), (0.0, 0.05), (-0.3, 0.0, 0.02), (-0.3, 0.05, 0.0, 0.0, 0.0), ()):
        np.testing.assert_allclose(radial_gain(r2, k), np.polynomial.polynomial.polyval(r2, [1.0, *k]),
                                   rtol=1e-15, atol=1e-15)


def test_correct_flat_with_the_prnu_map():
    """``with_prnu=True`` divides by the radial gain times the PRNU map, the default by the gain alone: planes
    made by multiplying a known signal by both come back to it (float32: 2e-7)."""
    k = (-0.3, 0.05, 0.0, 0.0, 0.0)
    prnu = (1.0 + 0.02 * np.random.default_rng(3).standard_normal((4, *FLAT_SHAPE))).astype(np.float32)
    fm = _flat_model(k, (10.0, 20.0), prnu=prnu)
    yy, xx = np.mgrid[0:30, 0:40].astype(float)
    g = np.stack([_dng_radial_gain(c, 10.0, 20.0, k, xx, yy) for c in fm.channels])
    planes = np.full((4, *FLAT_SHAPE), 500.0)
    np.testing.assert_allclose(correct_flat(planes * g * prnu, fm, with_prnu=True), planes, rtol=2e-6)
    np.testing.assert_allclose(correct_flat(planes * g, fm), planes, rtol=2e-6)


def _dark_stack(level, t_s, var_dn2, n=8, white=4095.0, black=1000.0):
    """A combined stack of ``n`` dark frames at ``t_s`` with exact per-pixel levels and variances (no file)."""
    level = np.asarray(level, np.float32)
    var = np.full(level.shape, var_dn2, np.float32)
    e = Exposure(exposure_s=t_s, iso=100.0)
    return StackResult(value=level, mean=level, variance=var.copy(), count=np.full(level.shape, n, np.int16),
                       n_frames=n, method="mean", exposures=(e,) * n,
                       paths=tuple(Path(f"d{t_s:g}_{i}.dng") for i in range(n)), channel_names=PLANES,
                       cfa_pattern="RGGB", black_level_dn=(black,) * 4, white_level_dn=white,
                       frame_shape=(2 * level.shape[1], 2 * level.shape[2]), variance_all=var)


def _dark_model(bias, beta, iso):
    z = np.zeros(bias.shape, np.float32)
    return DarkModel(bias_dn=bias, dark_current_dn_per_s=beta, dark_current_unc_dn_per_s=z, read_noise_dn=z + 2,
                     defects=np.zeros(bias.shape, np.uint8), iso=iso, cfa_pattern="RGGB", temperature_c=None)


# ---- dark: the per-pixel line's uncertainties, the noise line, the dark frame off the reference ISO -------------

def test_dark_line_uncertainties_are_the_least_squares_covariance():
    """var(β) and var(b) of the frame-count-weighted line fit, against the covariance of the linear estimator
    A = (XᵀWX)⁻¹XᵀW applied to means of variance σ_k²/n_k: Cov = A diag(σ²/n) Aᵀ (numpy linear algebra,
    written out here). Unequal frame counts and variances, a non-zero bias and one clipped point (weight 0)."""
    white = 4000.0
    times = np.array([0.5, 2.0, 6.0, 15.0])
    counts = np.array([4.0, 8.0, 5.0, 6.0])
    var_frame = np.array([3.0, 5.0, 9.0, 20.0])  # DN² per frame
    b_true, beta_true = 1012.0, 37.5
    y = b_true + beta_true * times
    y_clip = y.copy()
    y_clip[3] = white  # the 15 s level clipped
    obs = [(float(t), np.array([[yy, yc]]), np.full((1, 2), n), np.full((1, 2), v))
           for t, yy, yc, n, v in zip(times, y, y_clip, counts, var_frame, strict=True)]
    beta, beta_var, b, b_var, n_times = _fit_lines(obs, white)
    for j, use in enumerate((np.ones(4, bool), np.array([True, True, True, False]))):
        x = np.stack([np.ones(use.sum()), times[use]], axis=1)
        w = np.diag(counts[use])
        a = np.linalg.solve(x.T @ w @ x, x.T @ w)
        cov = a @ np.diag(var_frame[use] / counts[use]) @ a.T
        assert beta[0, j] == pytest.approx(beta_true, rel=1e-12)
        assert b[0, j] == pytest.approx(b_true, rel=1e-12)
        assert beta_var[0, j] == pytest.approx(cov[1, 1], rel=1e-10)
        assert b_var[0, j] == pytest.approx(cov[0, 0], rel=1e-10)
        assert n_times[0, j] == use.sum()


def test_dark_line_with_one_point_left_is_not_a_line():
    """Two exposure times, one clipped: no line (NaN), and the number of usable times is 1."""
    obs = [(1.0, np.array([1100.0]), np.array([4.0]), np.array([2.0])),
           (10.0, np.array([4095.0]), np.array([4.0]), np.array([2.0]))]
    beta, beta_var, b, b_var, n_times = _fit_lines(obs, 4095.0)
    assert np.isnan(beta[0]) and np.isnan(b[0]) and np.isnan(beta_var[0]) and np.isnan(b_var[0])
    assert n_times[0] == 1
    # one DN below the white level is still a usable level; two below is
    obs[1] = (10.0, np.array([4093.0]), np.array([4.0]), np.array([2.0]))
    beta, *_ = _fit_lines(obs, 4095.0)
    assert beta[0] == pytest.approx((4093.0 - 1100.0) / 9.0)


def test_dark_noise_line_through_the_stacks_leaves_hot_pixels_out():
    """variance = v0 + g·(level − bias) through three stacks: v0 = 6 DN², g = 0.4 DN/e⁻ exactly; a hot pixel of
    variance 10⁴ DN² in every stack is above 5× the median and must not pull the line."""
    shape = (4, 5, 5)
    bias = np.full(shape, 1000.0)
    stats = []
    for t, signal in ((1.0, 20.0), (4.0, 80.0), (10.0, 200.0)):
        level = bias + signal
        st = _dark_stack(level, t, var_dn2=6.0 + 0.4 * signal)
        st.variance_all[:, 2, 2] = 1e4
        stats.append((t, st))
    v0, g = noise_model(stats, bias)
    np.testing.assert_allclose(v0.ravel(), 6.0, rtol=1e-4)
    np.testing.assert_allclose(g.ravel(), 0.4, rtol=1e-5)
    # a single stack: no slope, v0 is its variance
    v0, g = noise_model(stats[:1], bias)
    np.testing.assert_allclose(v0.ravel(), 14.0, rtol=1e-5)
    assert np.all(g == 0)


def test_dark_frame_off_the_reference_iso_scales_beta_not_the_bias():
    """bias + β·t·(ISO/ISO_ref): at ISO 400 for a model measured at ISO 100, 12 s, β = 2.5 DN/s, bias 1024 DN:
    1024 + 2.5·12·4 = 1144 DN; a window returns the same pixels."""
    shape = (4, 6, 8)
    bias = np.full(shape, 1024.0, np.float32)
    bias[1, 2, 3] = 1030.0
    beta = np.full(shape, 2.5, np.float32)
    model = _dark_model(bias, beta, iso=100.0)
    frame = model.dark_frame_dn(12.0, iso=400.0)
    expect = bias + 2.5 * 12.0 * 4.0
    np.testing.assert_allclose(frame, expect, rtol=1e-7)
    np.testing.assert_allclose(model.dark_frame_dn(12.0), bias + 30.0, rtol=1e-7)
    np.testing.assert_allclose(model.dark_frame_dn(12.0, 400.0, (slice(1, 4), slice(2, 5))),
                               expect[:, 1:4, 2:5], rtol=1e-7)
    planes = expect + 500.0
    np.testing.assert_allclose(subtract_dark(planes, model, 12.0, iso=400.0), 500.0, rtol=1e-6)
    with pytest.raises(CamcalError, match="non-negative"):
        model.dark_frame_dn(-1.0)


# ---- dark: the temporal noise of the read-noise stack, its noisy pixels and read noise; the model's summary -----

NOISE_METHOD = "per-pixel temporal variance minus the quantisation variance 1/12 DN² (EMVA 1288 eq. 4)"


def _read_noise_stack(var, count, frames=(), n_paths=None, level=60.0):
    """A read-noise stack of per-pixel temporal variance ``var`` (C, h, w) over ``count`` frames a pixel, keeping
    ``frames`` (its first frames' planes), written by ``n_paths`` files (``count`` by default; no file is read), at
    ``level`` DN (a number or a (C, h, w) map: the stack's value)."""
    var = np.asarray(var, np.float32)
    level = np.broadcast_to(np.asarray(level, np.float32), var.shape).copy()
    n = int(count) if n_paths is None else n_paths
    e = Exposure(exposure_s=1e-4, iso=100.0)
    return StackResult(value=level, mean=level, variance=var, count=np.full(var.shape, count, np.int16),
                       n_frames=n, method="mean", exposures=(e,) * n,
                       paths=tuple(Path(f"b{i}.dng") for i in range(n)), channel_names=PLANES, cfa_pattern="RGGB",
                       black_level_dn=(60.0,) * 4, white_level_dn=1023.0,
                       frame_shape=(2 * var.shape[1], 2 * var.shape[2]), variance_all=var,
                       kept_planes=tuple(np.asarray(f, np.float32) for f in frames))


def _noisy_bound(dof, noisy_sigma):
    """The noisy-pixel bound on var/v̂: the chi-square upper 1e-6 quantile over dof, here from the inverse
    regularised upper incomplete gamma function (χ²_ν quantile = 2·Q⁻¹(ν/2, p)), or 1 + noisy_sigma·√(2/dof)."""
    return max(2.0 * gammainccinv(dof / 2.0, 1e-6) / dof, 1.0 + noisy_sigma * np.sqrt(2.0 / dof))


def _map_of_variance(var):
    """√(var − 1/12 DN²), 0 below the quantisation variance, NaN where var is NaN (EMVA 1288 eq. 4)."""
    return np.sqrt(np.clip(np.asarray(var, np.float64) - 1.0 / 12.0, 0.0, None))


def test_temporal_noise_plane_means_chi_square_flags_and_read_noise_map():
    """Planes above 1 DN of noise (count 8, dof 7, noisy_sigma 3: the chi-square bound 5.79 is the larger),
    against values set by construction:

    - v̂ is the plain mean over the good, finite pixels, without their top 0.1 % when there are more than 1000:
      R has 1002 (1001 regular variances of 0, 2 and 3 DN², one of 500 DN² left out; the 0.999 quantile is 3 DN²
      exactly, so every pixel at 3 DN² stays), G1 has 1001 (the 500 left out), G2 exactly 1000 (the 500 kept),
      B is 1 DN² everywhere (exactly 1 DN of noise: not below 1 DN, no quantised fit). Defect pixels of
      10⁴ DN² and NaN variances (without a defect bit) are not in v̂.
    - a pixel is noisy where var > v̂·bound, for every pixel (defects too): probes at 0.995 and 1.005 of it;
    - the read-noise map is √(var − 1/12) clipped at 0 (0 DN² gives 0), NaN where var is NaN; no plane
      has a read noise or DSNU of its own (NaN).
    """
    shape = (4, 32, 32)
    dof, noisy_sigma = 7, 3.0
    bound = _noisy_bound(dof, noisy_sigma)
    assert bound == pytest.approx(5.7888, abs=1e-4)  # the chi-square branch; 1 + 3·√(2/7) = 2.60
    var = np.full((4, 1024), 1e4)
    defects = np.full((4, 1024), HOT, np.uint8)
    vhat = np.zeros(4)
    for k, n_good in enumerate((1002, 1001, 1000)):
        regular = np.resize([0.0, 2.0, 3.0], n_good - 1)
        var[k, : n_good - 1], var[k, n_good - 1] = regular, 500.0
        defects[k, :n_good] = 0
        vhat[k] = np.mean(regular) if n_good > 1000 else np.mean(np.append(regular, 500.0))
    var[3, :1000], defects[3, :1000], vhat[3] = 1.0, 0, 1.0
    var[0, 1002:1004], defects[0, 1002:1004] = np.nan, 0  # no variance: not a pixel of v̂, not a defect
    var[:, -2] = vhat * bound * 0.995  # defect pixels just under and over the bound
    var[:, -1] = vhat * bound * 1.005
    var, defects = var.reshape(shape), defects.reshape(shape)
    noise = temporal_noise(_read_noise_stack(var, dof + 1), var.copy(), defects, noisy_sigma)
    np.testing.assert_allclose(noise.temporal_noise_dn, np.sqrt(vhat), rtol=1e-6)
    expect_noisy = np.greater(var, vhat[:, None, None] * bound, where=np.isfinite(var), out=np.zeros(shape, bool))
    np.testing.assert_array_equal(noise.noisy, expect_noisy)
    assert not noise.noisy[:, 31, 30].any() and noise.noisy[:, 31, 31].all()
    np.testing.assert_allclose(noise.read_noise_map_dn, _map_of_variance(var), rtol=1e-6, atol=0)
    assert noise.read_noise_map_dn[0, 0, 0] == 0.0  # a pixel of 0 DN² temporal variance
    assert np.all(np.isnan(noise.read_noise_dn)) and np.all(np.isnan(noise.dsnu_dn))
    np.testing.assert_array_equal(noise.quantised, False)
    assert noise.method == NOISE_METHOD


def test_temporal_noise_bound_at_a_high_noisy_sigma_and_with_two_frames_or_one():
    """The other branches of the noisy-pixel bound, on 3 × 4 planes of 1.5, 2, 4 and 1.25 DN² (B: one good
    pixel, the rest defects), probes (defect pixels) at 0.995 and 1.005 of v̂·bound:

    - count 8 (dof 7), noisy_sigma 12: 1 + 12·√(2/7) = 7.41 is above the chi-square bound 5.79;
    - count 2 (dof 1): the chi-square bound χ²₁(1e-6) = 23.93 (two frames are a bias-only model's minimum);
    - count 1 (dof 0): no bound, no pixel is noisy, not even one of 10⁴ DN².
    """
    shape = (4, 3, 4)
    vhat = np.array([1.5, 2.0, 4.0, 1.25])
    defects = np.zeros(shape, np.uint8)
    defects[:, 2, 2:] = HOT
    defects[3] = HOT
    defects[3, 0, 0] = 0
    for count, noisy_sigma, bound in ((8, 12.0, 1 + 12 * np.sqrt(2 / 7)), (2, 6.0, 23.9281), (1, 6.0, None)):
        var = np.where(defects == 0, vhat[:, None, None], 1e4)
        if bound is not None:
            assert _noisy_bound(count - 1, noisy_sigma) == pytest.approx(bound, rel=1e-5)
            var[:, 2, 2] = vhat * bound * 0.995
            var[:, 2, 3] = vhat * bound * 1.005
        noise = temporal_noise(_read_noise_stack(var, count), var.copy(), defects, noisy_sigma)
        np.testing.assert_allclose(noise.temporal_noise_dn, np.sqrt(vhat), rtol=1e-6)
        expect = np.zeros(shape, bool) if bound is None else var > vhat[:, None, None] * bound
        np.testing.assert_array_equal(noise.noisy, expect, err_msg=f"count {count}")
        np.testing.assert_allclose(noise.read_noise_map_dn, _map_of_variance(var), rtol=1e-6)
        assert noise.method == NOISE_METHOD and not noise.quantised.any()


def test_temporal_noise_below_one_dn_fits_consecutive_frame_pairs():
    """Planes below 1 DN of noise get the quantised-normal read noise and DSNU, the mean over the consecutive pairs
    (0, 1), (1, 2), (2, 3) of the first four kept frames, against the simulation's truth.

    Five frames of 128 × 128 pixels: R at 1.5 DN (not quantised), G1 σ = 0.4 DN and dsnu 0.3 DN, G2 σ = 0.35 DN
    and dsnu 0.5 DN, B a plane whose good pixels read one level in every frame (v̂ = 0: quantised, and no pixel
    is noisy, not even its hot ones). In G1 and G2 frame 3's noise is frame 0's reversed: every consecutive pair is
    independent, (0, 3) is not (σ would come out ~√2 too high there). Defects: 0.5 % hot pixels 150 DN up and 3 %
    2 DN up, both with 1 DN of noise (most of the second kind below the noisy bound, and close enough to the other
    pixels to widen σ by ~7 % if they entered the fit); 0.2 % noisy pixels (4 DN) are found by the chi-square
    bound (dof 4: 8.34 v̂). Neither may enter the fit, and the noisy ones keep √(var − 1/12) in the read-noise
    map, the others the plane's read noise.
    Tolerances: 16 000 pairs give σ to 0.7 % and dsnu to 1 % (standard deviations over 12 seeds): 3 % and 5 %;
    the pair (0, 3) instead of (2, 3) would move σ by +8 % (G1) and +14 % (G2), dsnu by −33 % and −10 %.
    Two frames (two files) are enough: one pair, σ = 0.45 DN to 5 % on 10 000 pixels (spread ~1.2 %).
    """
    rng = np.random.default_rng(2911)
    shape = (4, 128, 128)
    sigma, dsnu = (1.5, 0.4, 0.35, 0.0), (3.0, 0.3, 0.5, 0.5)
    z = rng.standard_normal((5, *shape))
    z[3, 1:3] = -z[0, 1:3]
    frames = np.rint(np.array([200.0, 60.2, 60.2, 60.0])[:, None, None] + np.array(dsnu)[:, None, None]
                     * rng.standard_normal(shape) + np.array(sigma)[:, None, None] * z)
    u = rng.random(shape)
    defects = np.where(u < 0.035, HOT, 0).astype(np.uint8)
    frames += np.where(u < 5e-3, 150.0, 2.0) * defects + defects * np.rint(rng.standard_normal(frames.shape))
    noisy_px = (rng.random(shape) < 2e-3) & (defects == 0)
    noisy_px[[0, 3]] = False  # R is not quantised; in B only the defects change
    frames += noisy_px * np.rint(4.0 * rng.standard_normal(frames.shape))
    var = np.var(frames, axis=0, ddof=1)
    noise = temporal_noise(_read_noise_stack(var, 5, frames), var.astype(np.float64), defects, 6.0)

    bound = _noisy_bound(4, 6.0)
    assert bound == pytest.approx(8.3442, abs=1e-4)
    vhat = np.zeros(4)
    for k in range(4):
        v = np.sort(var[k][defects[k] == 0])
        vhat[k] = np.mean(v[v <= np.quantile(v, 0.999)])  # 16 000 good pixels: the top 0.1 % left out
    assert vhat[3] == 0.0
    np.testing.assert_allclose(noise.temporal_noise_dn, np.sqrt(vhat), rtol=1e-6)
    expect_noisy = var > vhat[:, None, None] * bound
    expect_noisy[3] = False  # v̂ = 0: no bound
    np.testing.assert_array_equal(noise.noisy, expect_noisy)
    assert np.count_nonzero(noise.noisy[1:3] & noisy_px[1:3]) > 0.95 * np.count_nonzero(noisy_px)
    np.testing.assert_array_equal(noise.quantised, [False, True, True, True])
    assert np.isnan(noise.read_noise_dn[0]) and np.isnan(noise.dsnu_dn[0])
    np.testing.assert_allclose(noise.read_noise_dn[1:3], sigma[1:3], rtol=0.03)
    np.testing.assert_allclose(noise.dsnu_dn[1:3], dsnu[1:3], rtol=0.05)
    assert 0 < noise.read_noise_dn[3] < 0.1  # B never changes: no read noise to speak of
    expect_map = _map_of_variance(var)
    for k in (1, 2, 3):
        expect_map[k] = np.where(expect_noisy[k], expect_map[k], noise.read_noise_dn[k])
    np.testing.assert_allclose(noise.read_noise_map_dn, expect_map, rtol=1e-6)
    assert noise.method == ("quantised-normal likelihood of 3 frame pair(s) in planes G1, G2, B (temporal noise "
                            "below 1 DN); elsewhere " + NOISE_METHOD)

    # two frames, two files: one pair
    small = frames[:2, :, :100, :100].copy()
    small[:, 1] = np.rint(60.2 + 0.3 * rng.standard_normal((100, 100)) + 0.45 * rng.standard_normal((2, 100, 100)))
    small_defects = defects[:, :100, :100]
    var2 = np.var(small, axis=0, ddof=1)
    noise = temporal_noise(_read_noise_stack(var2, 2, small), var2.astype(np.float64), small_defects, 6.0)
    assert noise.read_noise_dn[1] == pytest.approx(0.45, rel=0.05)
    assert noise.method.startswith("quantised-normal likelihood of 1 frame pair(s) in planes G1, G2, B (")


def test_dark_model_summary_reports_its_maps_and_per_plane_figures():
    """The summary of a dark model against the model written out: its settings, the plane shape, each per-plane
    figure under its own name (the defect counts as ``*_count_per_plane``), and the totals of the defect map
    counted bit by bit with numpy (pixels with two bits count once in the fraction)."""
    shape = (4, 3, 5)
    defects = np.zeros(shape, np.uint8)
    for (k, i, j), bits in {(0, 0, 0): HOT, (0, 1, 2): HOT | NOISY, (1, 2, 4): DEAD, (2, 0, 1): NOISY,
                            (3, 1, 1): HOT | DEAD, (3, 2, 2): NOISY, (3, 2, 3): NOISY}.items():
        defects[k, i, j] = bits
    channels = {p: {"read_noise_dn": 0.4 + 0.1 * k, "dsnu_bias_dn": 0.25 * k,
                    "hot_pixel_count": int(np.sum(defects[k] & HOT > 0)),
                    "dead_pixel_count": int(np.sum(defects[k] & DEAD > 0)),
                    "noisy_pixel_count": int(np.sum(defects[k] & NOISY > 0))} for k, p in enumerate(PLANES)}
    bias = np.full(shape, 60.0, np.float32)
    model = DarkModel(bias_dn=bias, dark_current_dn_per_s=None, dark_current_unc_dn_per_s=None,
                      read_noise_dn=bias * 0 + 0.5, defects=defects, iso=200.0, cfa_pattern="BGGR",
                      temperature_c=31.5, channels=channels, exposure_times_s=(1e-4, 1.0, 8.0))
    expect = {
        "iso": 200.0, "cfa_pattern": "BGGR", "layout": "bayer", "temperature_c": 31.5,
        "exposure_times_s": [1e-4, 1.0, 8.0], "plane_shape": [3, 5],
        "read_noise_dn": {"R": 0.4, "G1": 0.5, "G2": 0.6000000000000001, "B": 0.7000000000000001},
        "dsnu_bias_dn": {"R": 0.0, "G1": 0.25, "G2": 0.5, "B": 0.75},
        "hot_pixel_count_per_plane": {"R": 2, "G1": 0, "G2": 0, "B": 1},
        "dead_pixel_count_per_plane": {"R": 0, "G1": 1, "G2": 0, "B": 1},
        "noisy_pixel_count_per_plane": {"R": 1, "G1": 0, "G2": 1, "B": 2},
        "hot_pixel_count": 3, "dead_pixel_count": 2, "noisy_pixel_count": 4,
        "defect_fraction": 7 / 60,
    }
    assert model.summary() == expect
    assert expect["defect_fraction"] == np.mean(defects != 0)


# ---- response: eq. 12 and its uncertainties, the straight line, the sRGB form, the inverses -------------------

def _jac_cov(x, alpha, gamma, sigma):
    """Covariance of (α, γ, β) of g = α x^γ + β from the Jacobian in x itself (not the rescaled x/x0 the fit
    uses): inv(Jᵀ diag(1/σ²) J), J = [x^γ, α x^γ ln x, 1]."""
    j = np.stack([x**gamma, alpha * x**gamma * np.log(x), np.ones_like(x)], axis=1) / sigma[:, None]
    return np.linalg.inv(j.T @ j)


def test_eq12_fit_recovers_a_compressive_curve_with_offset_and_its_covariance():
    """g = α x^γ + β with γ = 0.45, β = 12 DN, α such that the brightest of 8 points (x from 0.1 to 20 ms) is
    200 DN: exact data give back α, γ, β (rel 1e-6); their uncertainties (σ = 0.5 DN absolute, χ² = 0 < 1 so
    not rescaled) are the square roots of the diagonal of the Jacobian covariance computed directly in x (the
    fit's rescaling by x0 and propagation to α must give the same numbers)."""
    x = np.geomspace(1e-4, 2e-2, 8)
    alpha, gamma, beta = 188.0 / 2e-2**0.45, 0.45, 12.0
    g = alpha * x**gamma + beta
    sigma = np.full(8, 0.5)
    fit = fit_eq12(x, g, sigma, gamma0=0.5)
    assert fit["alpha"] == pytest.approx(alpha, rel=1e-6)
    assert fit["gamma"] == pytest.approx(gamma, rel=1e-6)
    assert fit["beta"] == pytest.approx(beta, abs=1e-5)
    cov = _jac_cov(x, alpha, gamma, sigma)
    assert fit["alpha_unc"] == pytest.approx(np.sqrt(cov[0, 0]), rel=1e-4)
    assert fit["gamma_unc"] == pytest.approx(np.sqrt(cov[1, 1]), rel=1e-4)
    assert fit["beta_unc"] == pytest.approx(np.sqrt(cov[2, 2]), rel=1e-4)
    assert fit["rms_dn"] < 1e-5


def test_eq12_uncertainties_grow_with_the_reduced_chi2_above_one():
    """A linear sensor (γ = 1, β = 1000 DN black level, 4000 DN/s at the reference) with ±3 DN alternating
    errors and σ = 1 DN: χ²_red = Σ r²/(n − 3) > 1 and each uncertainty is the Jacobian one × √χ²_red (both
    computed here from the fitted curve's residuals)."""
    x = np.linspace(0.01, 0.5, 9)
    g = 1000.0 + 4000.0 * x + 3.0 * np.array([1, -1, 1, -1, 1, -1, 1, -1, 1])
    sigma = np.ones(9)
    fit = fit_eq12(x, g, sigma)
    resid = g - (fit["alpha"] * x ** fit["gamma"] + fit["beta"])
    chi2_red = float(np.sum(resid**2) / 6)
    assert chi2_red > 1.5 and fit["chi2_red"] == pytest.approx(chi2_red, rel=1e-9)
    cov = _jac_cov(x, fit["alpha"], fit["gamma"], sigma) * chi2_red
    assert fit["alpha_unc"] == pytest.approx(np.sqrt(cov[0, 0]), rel=1e-3)
    assert fit["gamma_unc"] == pytest.approx(np.sqrt(cov[1, 1]), rel=1e-3)
    assert fit["beta_unc"] == pytest.approx(np.sqrt(cov[2, 2]), rel=1e-3)
    assert fit["rms_dn"] == pytest.approx(np.sqrt(np.mean(resid**2)), rel=1e-9)
    # three points: no degrees of freedom, no uncertainties
    three = fit_eq12(x[:3], g[:3], sigma[:3])
    assert np.isnan(three["alpha_unc"]) and np.isnan(three["chi2_red"])


def test_straight_line_fit_is_weighted_least_squares():
    """g = rate·x + offset with unequal σ: rate and offset from the weighted normal equations written out
    here; their uncertainties from inv(XᵀWX), × √χ²_red only when χ²_red > 1."""
    x = np.array([0.5, 1.0, 2.0, 4.0, 8.0])
    g = np.array([1052.0, 1099.0, 1203.0, 1398.0, 1801.0])
    sigma = np.array([1.0, 2.0, 1.0, 3.0, 2.0])
    xm = np.stack([x, np.ones_like(x)], axis=1)
    w = np.diag(1 / sigma**2)
    cov = np.linalg.inv(xm.T @ w @ xm)
    coef = cov @ xm.T @ w @ g
    chi2_red = float(np.sum(((g - xm @ coef) / sigma) ** 2) / 3)
    for scale_sigma in (1.0, 100.0):  # χ²_red > 1, then < 1 (no shrinking of the uncertainties)
        fit = fit_line(x, g, sigma * scale_sigma)
        assert fit["rate"] == pytest.approx(coef[0], rel=1e-10)
        assert fit["offset"] == pytest.approx(coef[1], rel=1e-10)
        c2 = chi2_red / scale_sigma**2
        assert fit["chi2_red"] == pytest.approx(c2, rel=1e-9)
        factor = max(1.0, c2) * scale_sigma**2
        assert fit["rate_unc"] == pytest.approx(np.sqrt(cov[0, 0] * factor), rel=1e-9)
        assert fit["offset_unc"] == pytest.approx(np.sqrt(cov[1, 1] * factor), rel=1e-9)
    assert chi2_red > 1


def _srgb_encode_numeric(lin, p, a=0.055):
    """The sRGB form with exponent p from its definition: V = (1 + a) L^p − a above the toe, V = s L below, the
    toe found numerically (brentq) where the line through the origin touches the curve."""
    def tangent_gap(lb):
        return (1 + a) * lb**p - a - lb * (1 + a) * p * lb ** (p - 1)

    lb = brentq(tangent_gap, 1e-9, 0.5)
    s = (1 + a) * p * lb ** (p - 1)
    lin = np.asarray(lin, float)
    return np.where(lin <= lb, s * lin, (1 + a) * np.maximum(lin, lb) ** p - a)


def test_srgb_form_fit_recovers_exponent_and_white_exposure_off_iec():
    """Exact 8-bit-scale data of the sRGB form with p = 0.42 (not IEC's 1/2.4) and white at x_w = 40 ms, from
    0.05 ms (in the toe) to 35 ms: the fit returns p and x_w to 1e-6 and the toe of that p."""
    x = np.geomspace(5e-5, 3.5e-2, 10)
    g = 255.0 * _srgb_encode_numeric(x / 0.04, 0.42)
    fit = fit_srgb_form(x, g, np.full(10, 0.3), 255.0, p0=0.5, x_white0=0.02)
    assert fit["exponent"] == pytest.approx(0.42, rel=1e-6)
    assert fit["x_white_s"] == pytest.approx(0.04, rel=1e-6)
    lb = brentq(lambda v: (1.055) * v**0.42 - 0.055 - v * 1.055 * 0.42 * v ** (0.42 - 1), 1e-9, 0.5)
    assert fit["toe_linear"] == pytest.approx(lb, rel=1e-9)
    assert fit["rms_dn"] < 1e-4
    # the inverse: decode(encode(L)) = L, below and above the toe
    lin = np.array([1e-4, lb / 2, 0.2, 0.9])
    np.testing.assert_allclose(srgb_form_decode(_srgb_encode_numeric(lin, 0.42), 0.42), lin, rtol=1e-9)
    np.testing.assert_allclose(srgb_form_encode(lin, 0.42), _srgb_encode_numeric(lin, 0.42), rtol=1e-9)
    assert float(srgb_form_decode(-0.1, 0.42)) == 0.0


def _channel(alpha=1.0, gamma=1.0, beta=0.0, offset=float("nan"), rate=float("nan")):
    return ChannelResponse(alpha=alpha, alpha_unc=0.0, gamma=gamma, gamma_unc=0.0, beta=beta, beta_unc=0.0,
                           linear_range_dn=(0.0, 1.0), saturation_dn=4095.0, linearity_error_pct=0.0,
                           pearson_r=1.0, rate_dn_per_s=rate, offset_dn=offset)


def test_raw_linearise_subtracts_the_line_offset_and_the_gain_is_its_slope():
    """RAW: values − offset of the γ = 1 line (β when the line is absent); the gain is the line's slope (α
    when absent). Channels along the last axis here."""
    chans = {"R": _channel(alpha=900.0, beta=1010.0, offset=1003.0, rate=950.0),
             "G1": _channel(alpha=1900.0, beta=1020.0), "G2": _channel(beta=1000.0, offset=998.0, rate=1.0),
             "B": _channel(beta=990.0, offset=991.0, rate=2.0)}
    m = ResponseModel(kind="raw", channels=chans, reference_iso=100.0, reference_f_number=4.0)
    v = np.array([[2000.0, 3000.0, 1500.0, 1200.0]])
    np.testing.assert_allclose(m.linearise(v, channel_axis=1), [[997.0, 1980.0, 502.0, 209.0]])
    assert m.linear_gain_dn_per_s("R") == 950.0 and m.linear_gain_dn_per_s("G1") == 1900.0
    assert m.value_scale(1023.0) == 1.0  # RAW values are never rescaled


def test_processed_linearise_inverts_the_power_law_and_rescales_other_bit_depths():
    """Processed, eq. 12 chosen: W·((v − β)/(W − β))^(1/γ) with W = 255, γ = 0.5, β = 5 DN (v = 130 DN →
    255·(125/250)² = 63.75 DN); sRGB chosen: W · decode(v/W). A 10-bit value (W_file = 1023) is first scaled by
    255/1023. Below β the power law gives 0."""
    ch = _channel(alpha=1.0, gamma=0.5, beta=5.0)
    tone = {"channels": {
        "R": {"use": "eq12", "linear_gain_dn_per_s": 1.0},
        "G": {"use": "srgb", "srgb": {"exponent": 0.42, "offset_a": 0.055}, "linear_gain_dn_per_s": 2.0},
        "B": {"use": "eq12", "linear_gain_dn_per_s": 3.0}}}
    m = ResponseModel(kind="processed", channels={"R": ch, "G": ch, "B": ch}, reference_iso=100.0,
                      reference_f_number=4.0, tone=tone, white_level_dn=255.0)
    v = np.array([130.0, 130.0, 2.0])
    lin = m.linearise(v)
    assert lin[0] == pytest.approx(255.0 * (125.0 / 250.0) ** 2)
    g_lin = brentq(lambda L: 255.0 * float(_srgb_encode_numeric(L, 0.42)) - 130.0, 1e-6, 1.0)
    assert lin[1] == pytest.approx(255.0 * g_lin, rel=1e-9)
    assert lin[2] == 0.0
    assert m.value_scale(1023.0) == pytest.approx(255.0 / 1023.0)
    assert m.value_scale(255.0) == 1.0 and m.value_scale(None) == 1.0
    lin10 = m.linearise(v * 1023.0 / 255.0, white_level_dn=1023.0)
    np.testing.assert_allclose(lin10, lin, rtol=1e-9)
    # a file whose white is half the response's: every value doubled first (the scale 2 is not special)
    assert m.value_scale(127.5) == 2.0
    np.testing.assert_allclose(m.linearise(v / 2.0, white_level_dn=127.5), lin, rtol=1e-9)
    with pytest.raises(CamcalError, match=r"processed response has 3 channels \(R, G, B\); values have 4 along axis 0"):
        m.linearise(np.ones((4, 2)))
    assert m.linear_gain_dn_per_s("G") == 2.0


def test_srgb_form_with_another_offset_and_exponents_without_a_toe_and_the_value_scale_guards():
    """The sRGB form with offset a = 0.1, p = 0.5 (not the defaults): encode against the form written out with
    its toe found numerically, decode back, and the processed linearise with that offset in the profile's tone.
    For p ≥ 1 the curve has no toe (no line through the origin touches it from below): L_b = 0, s = 1. The value
    scale is 1 for a white level that is not a positive finite number (0, negative, NaN, ∞, on either side),
    W_response / W_file otherwise (also for a white of 1 DN or less), and exactly 1 within 1e-9 of equal."""
    lin = np.array([0.0, 0.01, 0.03, 0.2, 0.7, 1.0])
    expect = _srgb_encode_numeric(lin, 0.5, a=0.1)
    np.testing.assert_allclose(srgb_form_encode(lin, 0.5, 0.1), expect, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(srgb_form_decode(expect, 0.5, 0.1), lin, rtol=1e-9, atol=1e-15)
    for p in (1.0, 1.5):
        assert srgb_form_toe(p) == (0.0, 1.0)
    ch = _channel()
    tone = {"channels": {k: {"use": "srgb", "srgb": {"exponent": 0.5, "offset_a": 0.1}, "linear_gain_dn_per_s": 1.0}
                         for k in "RGB"}}
    m = ResponseModel(kind="processed", channels={"R": ch, "G": ch, "B": ch}, reference_iso=100.0,
                      reference_f_number=4.0, tone=tone, white_level_dn=255.0)
    np.testing.assert_allclose(m.linearise(255.0 * expect[3:]), 255.0 * lin[3:], rtol=1e-9)
    for w in (0.0, -5.0, float("nan"), float("inf")):
        assert m.value_scale(w) == 1.0
    assert m.value_scale(1.0) == 255.0 and m.value_scale(0.5) == 510.0
    assert m.value_scale(255.0 * (1 + 1e-10)) == 1.0  # within 1e-9 of equal: exactly 1
    for w_resp in (0.0, float("nan")):
        assert replace(m, white_level_dn=w_resp).value_scale(255.0) == 1.0
    assert replace(m, white_level_dn=1.0).value_scale(2.0) == 0.5


def test_saturation_point_of_a_series():
    """The first saturated exposure, the largest value seen when saturated, the fitted range of used points."""
    x = np.array([1.0, 2.0, 4.0, 8.0, 16.0])
    sat = saturation_point(x, [100.0, 200.0, 400.0, 790.0, 800.0], [120, 230, 450, 4000, 4020],
                           [False, False, False, True, True], [False, True, True, False, False], 4095.0)
    assert (sat.level_dn, sat.exposure_s, sat.reached, sat.n_saturated) == (4020.0, 8.0, True, 2)
    assert sat.fitted_range_dn == (200.0, 400.0) and sat.fitted_exposure_s == (2.0, 4.0)
    none = saturation_point(x, [1, 2, 3, 4, 5], [1, 2, 3, 4, 5], [False] * 5, [True] * 5, 4095.0)
    assert none.level_dn == 4095.0 and np.isnan(none.exposure_s) and not none.reached
    assert none.fitted_exposure_s == (1.0, 16.0)


# ---- spectral: the slit operator, its inverse, the derived figures ----------------------------------------------

def _gauss_conv(lam, mu, s, fwhm, a=1.0):
    """A·exp(−(λ−μ)²/2s²) convolved with a unit-area Gaussian of FWHM ``fwhm``: variances add (closed form)."""
    v = s * s + (fwhm / (2 * np.sqrt(2 * np.log(2)))) ** 2
    return a * s / np.sqrt(v) * np.exp(-((np.asarray(lam, float) - mu) ** 2) / (2 * v))


def test_slit_operator_is_the_convolution_with_a_unit_area_slit():
    """A·c on a 5 nm grid, for a Gaussian c (s = 20 nm) and a 10 nm Gaussian slit, against the closed-form
    convolution (rel 2e-4 of the peak: the natural spline between nodes); for a triangular slit of FWHM 10 nm,
    against the convolution (trapezoid rule, 5 pm steps) with the triangle 1 − |x|/10 normalised to unit area."""
    wl = np.arange(500.0, 701.0, 5.0)
    c = _gauss(wl, 600.0, 20.0)
    a = slit_matrix(wl, 10.0, "gaussian", step_nm=0.25)
    np.testing.assert_allclose(a @ c, _gauss_conv(wl, 600.0, 20.0, 10.0), atol=2e-4)
    at = slit_matrix(wl, 10.0, "triangular")
    tri = _tri_conv(wl, 600.0, 20.0, 10.0)
    np.testing.assert_allclose(at @ c, tri, atol=2e-4)
    assert abs(float((a @ c)[20]) - 1.0) > 0.02  # the slit lowers the peak by 2.2 %: the test can see a slit


def _tri_conv(lam, mu, s, fwhm):
    """A unit Gaussian (μ, s) convolved with the unit-area triangle 1 − |x|/FWHM (trapezoid rule, fine steps)."""
    x = np.linspace(-fwhm, fwhm, 4001)
    return np.array([np.trapezoid(_gauss(v - x, mu, s) * (1 - np.abs(x) / fwhm) / fwhm, x) for v in lam])


def test_deconvolution_recovers_the_curve_and_propagates_its_uncertainty_linearly():
    """c ⊛ slit (a 25 nm triangular slit on a 20 nm grid) deconvolved with a fixed small regularisation gives
    back c within 1e-3 of its peak (the convolved curve is up to 1 % off). The estimator is linear, so its
    uncertainty is √Σ_k R_jk² u_k² with R's columns found here by deconvolving unit vectors."""
    wl = np.arange(440.0, 761.0, 20.0)
    truth = _gauss(wl, 600.0, 40.0)
    measured = _tri_conv(wl, 600.0, 40.0, 25.0)
    u = np.full(wl.size, 1e-3)
    u[5] = 4e-3
    c, uc = deconvolve_slit(wl, measured, u, 25.0, slit="triangular", regularisation=1e-6)
    np.testing.assert_allclose(c, truth, atol=1e-3)
    assert np.max(np.abs(measured - truth)) > 0.008
    cols = np.stack([deconvolve_slit(wl, np.eye(wl.size)[k], u, 25.0, slit="triangular", regularisation=1e-6)[0]
                     for k in range(wl.size)], axis=1)
    np.testing.assert_allclose(cols @ measured, c, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(uc, np.sqrt((cols**2) @ u**2), rtol=1e-6)


def _sensitivity(wl, values, **kw):
    return SpectralSensitivity(wavelength_nm=wl, values=values, uncertainty={k: np.zeros_like(v) for k, v in
                                                                             values.items()},
                               units="relative", mode="relative", **kw)


def test_effective_wavelength_bandwidth_and_peak_of_gaussian_curves():
    """Gaussian curves: centroid = μ, equivalent width ∫c/max c = s√(2π) (closed form; the 1 nm grid and the
    tails cut at ≥ 5 s make both exact to 1e-5 nm and 1e-6), peak at μ; G is the mean of G1 and G2. A
    negative noise sample is clipped before the centroid (kept, it would move R's centroid by +2 nm; clipped,
    by −3e-5 nm, the true 4e-6 tail sample it replaced)."""
    wl = np.arange(400.0, 701.0, 1.0)
    vals = {"R": _gauss(wl, 600, 20), "G1": _gauss(wl, 540, 25, 2.0), "G2": _gauss(wl, 540, 25, 2.0),
            "B": _gauss(wl, 470, 12)}
    vals["R"][0] = -0.5
    s = _sensitivity(wl, vals)
    lam = s.effective_wavelength_nm()
    assert lam["R"] == pytest.approx(600.0, abs=1e-4) and lam["G"] == pytest.approx(540.0, abs=1e-5)
    assert lam["B"] == pytest.approx(470.0, abs=1e-5)
    bw = s.effective_bandwidth_nm()
    assert bw["R"] == pytest.approx(20 * np.sqrt(2 * np.pi), rel=1e-6)
    assert bw["G1"] == pytest.approx(25 * np.sqrt(2 * np.pi), rel=1e-6)
    assert s.peak_wavelength_nm() == {"R": 600.0, "G1": 540.0, "G2": 540.0, "B": 470.0, "G": 540.0}


def test_slit_bias_is_half_the_slit_variance_times_the_curvature():
    """(σ²/2)·c'' with σ = FWHM/2.3548 and c'' of a Gaussian in closed form, c·((λ−μ)²/s⁴ − 1/s²), at 5 nm
    samples (the spline's c'' is within 2 % of the peak curvature: measured 1.6 %); zero once deconvolved."""
    wl = np.arange(500.0, 701.0, 5.0)
    c = _gauss(wl, 600, 20)
    s = _sensitivity(wl, {"R": c, "G": c, "B": c}, bandwidth_nm=10.0)
    sigma2 = (10.0 / (2 * np.sqrt(2 * np.log(2)))) ** 2
    expect = 0.5 * sigma2 * c * ((wl - 600) ** 2 / 20.0**4 - 1 / 20.0**2)
    np.testing.assert_allclose(s.slit_bias()["R"], expect, atol=0.02 * np.max(np.abs(expect)))
    assert not np.any(_sensitivity(wl, {"R": c, "G": c, "B": c}, bandwidth_nm=10.0,
                                   deconvolved=True).slit_bias()["R"])
    rel = to_relative(_sensitivity(wl, {"R": 3 * c, "G": c, "B": c}))
    assert float(rel.values["R"].max()) == pytest.approx(1.0) and float(rel.values["G"].max()) == pytest.approx(1 / 3)


# ---- water: the band model, its derivative and sensitivity term, the field mixture, the uncertainty helpers -----

BAND_WL = np.arange(520.0, 761.0, 4.0)
BAND_C = _gauss(BAND_WL, 640.0, 22.0)  # a red channel, negligible at the grid's ends


def _bricaud_per_m(c_ug_per_L):
    """a_chl = A(λ) C^E(λ) on BAND_WL from the Bricaud et al. (1998) table (400-700 nm; no absorption beyond)."""
    chl = bricaud_1998()
    a = np.interp(BAND_WL, chl.wavelengths_nm, chl.coefficient_m2_per_mg, right=0.0)
    return a * c_ug_per_L ** np.interp(BAND_WL, chl.wavelengths_nm, chl.exponent)


def test_band_ratio_is_the_sensitivity_weighted_mean_of_the_per_wavelength_ratio():
    """B(C) = ∫ c S R_λ(τ_λ) dλ / ∫ c S dλ with τ_λ = (a_w + a_bg + A C^E) d, rendered here with the trapezoid
    rule from the Bricaud (1998) and Pope & Fry (1997) tables and the per-wavelength closed form of an oblique
    refined model, under a sloping illuminant, at C = 7 µg/L, d = 0.8 m, a_bg = 0.05 m⁻¹ (rel 1e-6: the two
    quadratures differ only at the ends, where c is 4e-7 of its peak)."""
    geom = RefinedModel(view_angle_rad=0.4, albedo=0.8)
    s = np.linspace(0.7, 1.3, BAND_WL.size)
    model = BandModel(BAND_WL, BAND_C, geometry=geom, illuminant=s, background_absorption_per_m=0.05)
    a_chl = _bricaud_per_m(7.0)
    tau = (pure_water_absorption_per_m(BAND_WL) + 0.05 + a_chl) * 0.8
    r_lambda = geom.closed_form().ratio(tau)
    expect = np.trapezoid(BAND_C * s * r_lambda, BAND_WL) / np.trapezoid(BAND_C * s, BAND_WL)
    assert float(model.ratio(7.0, 0.8)) == pytest.approx(expect, rel=1e-6)
    np.testing.assert_allclose(model.spectral_ratio(7.0, 0.8), r_lambda, rtol=1e-12)
    # the seed's geometry ignores water unless given
    seed_band = BandModel(BAND_WL, BAND_C)
    assert not np.any(seed_band.water_absorption())


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


def test_band_ratio_sigma_from_the_sensitivity_is_the_linear_propagation():
    """σ_B² = Σ_k (∂B/∂c_k · u_k)², ∂B/∂c_k by central differences of the band ratio with the k-th sample of c
    moved (u = 5 % of c plus a floor), at C = 20 µg/L, d = 1 m, under a sloping illuminant."""
    s = np.linspace(1.2, 0.8, BAND_WL.size)
    u = 0.05 * BAND_C + 1e-3
    model = BandModel(BAND_WL, BAND_C, illuminant=s)
    var = 0.0
    for k in range(BAND_WL.size):
        dc = np.zeros_like(BAND_C)
        dc[k] = 1e-3 * BAND_C[k]  # relative: c − dc stays positive at the tails (clipping would bend B)
        up = float(BandModel(BAND_WL, BAND_C + dc, illuminant=s).ratio(20.0, 1.0))
        down = float(BandModel(BAND_WL, BAND_C - dc, illuminant=s).ratio(20.0, 1.0))
        var += ((up - down) / (2 * dc[k]) * u[k]) ** 2
    assert float(model.ratio_sigma_from_sensitivity(20.0, 1.0, u)) == pytest.approx(np.sqrt(var), rel=1e-4)


def test_chlorophyll_absorption_power_law_and_its_derivative():
    """a = A C^E with E ≠ 1 (Bricaud's E at 440 nm is 0.65), its derivative against a central difference, zero
    absorption (and an infinite slope) at C = 0; decadic ε in L g⁻¹ cm⁻¹ → A = ln 10 · ε · 100 cm/m · 1e-6 g/mg
    per (mg/m³ = µg/L) = 2.302585e-4 ε m² mg⁻¹."""
    chl = ChlorophyllAbsorption(np.array([440.0, 675.0]), np.array([0.04, 0.02]), np.array([0.65, 0.9]))
    c = 8.0
    np.testing.assert_allclose(chl.absorption_per_m(c), [0.04 * c**0.65, 0.02 * c**0.9], rtol=1e-12)
    h = 1e-4
    numeric = (chl.absorption_per_m(c + h) - chl.absorption_per_m(c - h)) / (2 * h)
    np.testing.assert_allclose(chl.derivative_per_m(c), numeric, rtol=1e-7)
    assert not np.any(chl.absorption_per_m(0.0)) and np.all(np.isinf(chl.derivative_per_m(0.0)))
    resampled = chl.on(np.array([400.0, 557.5, 700.0]))
    np.testing.assert_allclose(resampled.coefficient_m2_per_mg, [0.0, 0.03, 0.0])  # zero outside the table
    np.testing.assert_allclose(resampled.exponent, [0.65, 0.775, 0.9])
    solvent = solvent_spectrum([663.0], [80.0])
    assert float(solvent.coefficient_m2_per_mg[0]) == pytest.approx(np.log(10) * 80.0 * 100 * 1e-6, rel=1e-12)
    assert float(solvent.exponent[0]) == 1.0 and solvent.source == "solvent ε(λ)"


def test_field_mixture_derivative_and_direct_beam_at_a_sunny_oblique_setting():
    """Field model under a measured sky (diffuse fraction 0.3 → 0.5 across the band), sun at 50°, view 0.3 rad:
    dB/dC against a central difference, and B(C) against the mixture (1 − f) R_dir + f R_sky rendered with the
    trapezoid rule, R_dir = ρ T(θs) T_up / n² exp(−τ (1/cos β + 1/cos θv,w)) from Fresnel written out here."""
    sky_wl = np.arange(500.0, 761.0, 10.0)
    diffuse = np.linspace(0.3, 0.5, sky_wl.size)
    sky = MeasuredSky(50.0, sky_wl, 1.0 - diffuse, diffuse)
    geom = FieldGeometry(view_angle_rad=0.3, albedo=0.9)
    model = field_band_model(BAND_WL, BAND_C, sky=sky, geometry=geom)
    c, d, h = 15.0, 0.5, 0.015
    numeric = (float(model.ratio(c + h, d)) - float(model.ratio(c - h, d))) / (2 * h)
    assert float(model.ratio_derivative(c, d)) == pytest.approx(numeric, rel=1e-5)
    # the rendering
    n = 1.33
    th_s = np.radians(50.0)
    beta = np.arcsin(np.sin(th_s) / n)
    view_w = np.arcsin(np.sin(0.3) / n)
    t_down = 1 - _fresnel_r(th_s, n)
    t_up = 1 - _fresnel_r(0.3, n)  # reciprocity: the same as from below at the refracted angle
    a_chl = _bricaud_per_m(c)
    tau = (pure_water_absorption_per_m(BAND_WL) + a_chl) * d
    r_dir = 0.9 * t_down * t_up / n**2 * np.exp(-tau * (1 / np.cos(beta) + 1 / np.cos(view_w)))
    r_sky = geom.sky_form().ratio(tau)
    f = np.interp(BAND_WL, sky_wl, diffuse)
    r = (1 - f) * r_dir + f * r_sky
    expect = np.trapezoid(BAND_C * r, BAND_WL) / np.trapezoid(BAND_C, BAND_WL)  # global irradiance: flat here
    assert float(model.ratio(c, d)) == pytest.approx(expect, rel=1e-5)


def _fresnel_r(theta_air, n):
    """Unpolarised Fresnel reflectance of air → water (Born & Wolf), from the air-side angle."""
    ci = np.cos(theta_air)
    ct = np.sqrt(1 - (np.sin(theta_air) / n) ** 2)
    rs = ((ci - n * ct) / (ci + n * ct)) ** 2
    rp = ((ct - n * ci) / (ct + n * ci)) ** 2
    return 0.5 * (rs + rp)


def test_uncertainty_helpers_on_closed_forms():
    """With B(C; p) = exp(−p C) (p = 0.03 per µg/L): σ_C from p is |∂B/∂p| σ_p / |∂B/∂C| = C σ_p / p (central
    differences with h = σ_p/2 of an exponential: relative error (h C)²/6 ≤ 7e-7 here); solve_c inverts it to
    ln(1/B)/p; terms combine in quadrature; a term tabulated as a power law is interpolated exactly in log-log,
    clamped at the grid's ends, NaN kept."""
    c = np.array([2.0, 30.0, 400.0])
    p = Uncertain("absorption", 0.03, 1e-5, "per µg/L")

    def forward(pv, cc):
        return np.exp(-pv * np.asarray(cc, float))

    db_dc = -0.03 * np.exp(-0.03 * c)
    np.testing.assert_allclose(term_sigma_c(forward, p, c, db_dc), c * 1e-5 / 0.03, rtol=2e-6)
    assert not np.any(term_sigma_c(forward, Uncertain("x", 0.03, 0.0, ""), c, db_dc))
    assert solve_c(lambda cc: forward(0.03, cc), float(np.exp(-0.03 * 55.0))) == pytest.approx(55.0, rel=1e-9)
    assert np.isnan(solve_c(lambda cc: forward(0.03, cc), 1.5))
    np.testing.assert_allclose(combine({"a": np.array([3.0, 5.0]), "b": np.array([4.0, 12.0]), "c": 0.0}),
                               [5.0, 13.0])
    grid = np.geomspace(0.1, 1000.0, 9)
    term = 0.2 * grid**0.7
    got = interpolate_term(term, np.array([0.37, 52.0, 1e4, 1e-3, np.nan]), grid)
    np.testing.assert_allclose(got[:2], 0.2 * np.array([0.37, 52.0]) ** 0.7, rtol=1e-12)
    assert got[2] == pytest.approx(term[-1]) and got[3] == pytest.approx(term[0]) and np.isnan(got[4])


# ---- correct: the dark frame of other models, the system gain from photon transfer, the frame summaries ----------

class _FrameDark:
    """A third-party model that only evaluates whole frames: a dict per plane, a mosaic, or a scalar."""

    def __init__(self, kind):
        self.kind = kind

    def dark_frame_dn(self, exposure_s, iso):
        level = 64.0 + 0.5 * exposure_s * iso / 100.0
        if self.kind == "dict":
            return {p: np.full((3, 4), level + i) for i, p in enumerate(PLANES)}
        if self.kind == "mosaic":
            return np.arange(48, dtype=float).reshape(6, 8) + level
        return level


def test_dark_frame_of_maps_off_the_reference_iso_on_a_window():
    """bias + β·t·ISO/ISO_dark on a window, for a model offering the maps: ISO 800 against a dark model at ISO
    200, 5 s, β = 1.5 DN/s → bias + 30 DN."""
    rng = np.random.default_rng(3)
    bias = (1000 + rng.integers(0, 20, (4, 3, 4))).astype(np.float32)
    beta = np.full((4, 3, 4), 1.5, np.float32)
    win = (slice(1, 3), slice(0, 2))
    got = dark_frame(_dark_model(bias, beta, 200.0), 5.0, 800.0, (4, 3, 4), win)
    np.testing.assert_allclose(got, bias[:, 1:3, 0:2] + 30.0, rtol=1e-7)
    with pytest.raises(CamcalError, match="non-negative"):
        dark_frame(_dark_model(bias, beta, 200.0), float("nan"), 800.0, (4, 3, 4))
    with pytest.raises(CamcalError, match="do not match"):
        dark_frame(_dark_model(bias, beta, 200.0), 5.0, 800.0, (4, 3, 5))


def test_dark_frame_of_a_whole_frame_model_per_plane_mosaic_or_scalar():
    """A dict per plane is stacked in plane order, a mosaic split by its CFA pattern (RGGB: R at even rows
    and columns), a scalar filled; level 64 + 0.5·t·ISO/100 = 74 DN at 10 s, ISO 200."""
    got = dark_frame(_FrameDark("dict"), 10.0, 200.0, (4, 3, 4))
    np.testing.assert_allclose(got[:, 0, 0], [74.0, 75.0, 76.0, 77.0])
    mosaic = np.arange(48, dtype=float).reshape(6, 8) + 74.0
    got = dark_frame(_FrameDark("mosaic"), 10.0, 200.0, (4, 3, 4), cfa_pattern="RGGB")
    np.testing.assert_allclose(got[0], mosaic[0::2, 0::2])
    np.testing.assert_allclose(got[3], mosaic[1::2, 1::2])
    np.testing.assert_allclose(got[1], mosaic[0::2, 1::2])
    got = dark_frame(_FrameDark("scalar"), 10.0, 200.0, (4, 3, 4), (slice(0, 2), slice(1, 3)))
    assert got.shape == (4, 2, 2) and np.all(got == 74.0)


class _Emva:
    iso = 400.0

    def gain_dn_per_e(self, plane):
        return {"R": 0.8, "G1": None, "G2": float("nan"), "B": 1.2}[plane]


def test_system_gain_from_photon_transfer_scaled_to_the_dark_models_iso():
    """K at the dark model's ISO 100 from an EMVA sheet at ISO 400: K·100/400 (0.8 → 0.2, 1.2 → 0.3 DN/e⁻);
    planes the sheet does not know keep the dark model's own photon-transfer gain."""
    shape = (4, 2, 2)
    dark = _dark_model(np.full(shape, 1000.0, np.float32), np.full(shape, 1.0, np.float32), iso=100.0)
    own = {"R": 0.05, "G1": 0.06, "G2": 0.07, "B": 0.08}
    channels = {p: {"gain_dn_per_e_from_dark": g, "hot_pixel_count": 0, "dead_pixel_count": 0,
                    "noisy_pixel_count": 0} for p, g in own.items()}
    dark = replace(dark, channels=channels)
    np.testing.assert_allclose(system_gain_dn_per_e(dark).ravel(), [0.05, 0.06, 0.07, 0.08], rtol=1e-6)
    k = system_gain_dn_per_e(dark, _Emva())
    assert k.shape == (4, 1, 1)
    np.testing.assert_allclose(k.ravel(), [0.2, 0.06, 0.07, 0.3], rtol=1e-6)
    assert system_gain_dn_per_e(None) is None


def test_corrected_frame_summaries():
    """Valid and saturated fractions per plane and the mean over valid pixels only, written out."""
    sig = np.arange(2 * 3 * 2, dtype=np.float32).reshape(2, 3, 2)
    invalid = np.zeros(sig.shape, bool)
    invalid[0, 0, :] = True
    invalid[1, 2, 1] = True
    saturated = np.zeros(sig.shape, bool)
    saturated[0, 0, 1] = True
    c = Corrected(sig, None, invalid, saturated, np.zeros(sig.shape, bool), saturated, ("R", "G"))
    np.testing.assert_allclose(c.valid_fraction(), [4 / 6, 5 / 6])
    np.testing.assert_allclose(c.saturated_fraction(), [1 / 6, 0.0])
    np.testing.assert_allclose(c.mean_dn(), [np.mean([2, 3, 4, 5]), np.mean([6, 7, 8, 9, 10])])
    m = c.masked(-1.0)
    assert m[0, 0, 0] == -1.0 and m[1, 2, 1] == -1.0 and m[1, 0, 0] == 6.0 and sig[0, 0, 0] == 0.0
    all_bad = Corrected(sig, None, np.ones(sig.shape, bool), saturated, saturated, saturated, ("R", "G"))
    assert np.all(np.isnan(all_bad.mean_dn()))


def test_merged_sweeps_scale_the_second_onto_the_first_and_average_by_inverse_variance():
    """Sweep a (400-600 nm) and sweep b (550-750 nm) = truth / 2.5 with uncertainties 1 % and 2 % of the truth:
    the scale is 2.5 exactly (noise-free overlap), its uncertainty 1/√Σ w b² with w = 1/(u_a² + k² u_b²); in the
    overlap the values are the truth and the uncertainty 1/√(1/u_a² + 1/u_b'²), u_b' = √((k u_b)² + (u_k b)²);
    outside it each sweep's own (b scaled)."""
    wa, wb = np.arange(400.0, 601.0, 10.0), np.arange(550.0, 751.0, 10.0)

    def truth(wl):
        return _gauss(wl, 560.0, 80.0) + 0.1

    planes = ("R", "G", "B")
    a = SpectralSensitivity(wa, {p: truth(wa) for p in planes}, {p: 0.01 * truth(wa) for p in planes},
                            "relative", "relative", bandwidth_nm=5.0)
    b = SpectralSensitivity(wb, {p: truth(wb) / 2.5 for p in planes}, {p: 0.02 * truth(wb) / 2.5 for p in planes},
                            "relative", "relative", bandwidth_nm=8.0)
    m = merge_sweeps(a, b)
    grid = np.arange(400.0, 751.0, 10.0)
    np.testing.assert_allclose(m.wavelength_nm, grid)
    np.testing.assert_allclose(m.values["G"], truth(grid), rtol=1e-12)
    ov = (grid >= 550) & (grid <= 600)
    ua, ubk = 0.01 * truth(grid[ov]), 0.02 * truth(grid[ov])  # b's uncertainty on a's scale: k u_b
    w = 1 / (ua**2 + ubk**2)
    b_ov = truth(grid[ov]) / 2.5
    u_k = 1 / np.sqrt(3 * np.sum(w * b_ov**2))  # three planes alike
    ub_prime = np.hypot(ubk, u_k * b_ov)
    np.testing.assert_allclose(m.uncertainty["R"][ov], 1 / np.sqrt(1 / ua**2 + 1 / ub_prime**2), rtol=1e-9)
    only_a, only_b = grid < 550, grid > 600
    np.testing.assert_allclose(m.uncertainty["B"][only_a], 0.01 * truth(grid[only_a]), rtol=1e-12)
    np.testing.assert_allclose(m.uncertainty["B"][only_b],
                               np.hypot(0.02 * truth(grid[only_b]), u_k * truth(grid[only_b]) / 2.5), rtol=1e-9)
    assert m.bandwidth_nm == 8.0 and "2.5" in m.notes[-1]


# ---- the remaining small formulas: the smooth estimator's error table, predictions, conversions -----------------

def _planck_w_m2_sr_nm(t_k, wl_nm):
    """Planck's law written out with the exact SI constants h, c, k (2019), per nm."""
    h, c, k = 6.62607015e-34, 299792458.0, 1.380649e-23
    lam = np.asarray(wl_nm, float) * 1e-9
    return 2 * h * c**2 / lam**5 / np.expm1(h * c / (lam * k * t_k)) * 1e-9


def test_smooth_error_table_truth_and_estimate_for_a_black_body_and_d65():
    """The table's truth is the spectrum at λ0: Planck's law for the 5000 K black body, and CIE D65 between its
    660 and 665 nm table values (80.2146, 81.2462) at 663 nm, linearly; its estimate is the smooth estimator
    applied to the rates ∫ c S dλ; the error is 100 (estimate/truth − 1); the spread is the RMS of the errors."""
    wl = np.arange(400.0, 721.0, 5.0)
    c = {"R": _gauss(wl, 610, 30, 40.0), "G": _gauss(wl, 540, 35, 55.0), "B": _gauss(wl, 460, 25, 30.0)}
    rows = {r["spectrum"]: r for r in smooth_error_table(wl, c, 663.0)}
    assert len(rows) == 5 + 3 + 24
    bb = rows["black body 5000 K"]
    assert bb["true"] == pytest.approx(float(_planck_w_m2_sr_nm(5000.0, 663.0)), rel=1e-3)  # linear on 5 nm
    weights = radiance_model(wl, c, None, 663.0, "smooth").weights
    spec = _planck_w_m2_sr_nm(5000.0, wl)
    est = float(weights @ np.trapezoid(np.stack([c[k] for k in "RGB"]) * spec, wl, axis=1))
    assert bb["estimate"] == pytest.approx(est, rel=1e-4)
    assert bb["error_pct"] == pytest.approx(100 * (bb["estimate"] / bb["true"] - 1), rel=1e-9)
    assert rows["CIE D65"]["true"] == pytest.approx(80.2146 + 0.6 * (81.2462 - 80.2146), rel=1e-6)
    # D65 on the curve's own 5 nm samples (colour-science's CIE table, 5 nm steps)
    d65 = np.asarray(colour.SDS_ILLUMINANTS["D65"][wl])
    est = float(weights @ np.trapezoid(np.stack([c[k] for k in "RGB"]) * d65, wl, axis=1))
    assert rows["CIE D65"]["estimate"] == pytest.approx(est, rel=1e-9)
    assert {r["spectrum"]: r for r in smooth_error_table(wl, c)}["CIE D65"]["true"] == rows["CIE D65"]["true"]
    errors = np.array([r["error_pct"] for r in rows.values()]) / 100
    assert smooth_spread_rel(wl, c, 663.0) == pytest.approx(np.sqrt(np.mean(errors**2)), rel=1e-12)
    # the default λ0 is the L663 map's 663 nm (camcal apply's default --wavelength)
    assert smooth_spread_rel(wl, c) == pytest.approx(np.sqrt(np.mean(errors**2)), rel=1e-12)
    # a ColorChecker patch under D65: the product of the illuminant and the patch's reflectance at 663 nm
    skin = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["dark skin"]
    at_nodes = [80.2146 * skin[660.0], 81.2462 * skin[665.0]]  # the product on the grid, read linearly at 663 nm
    expect = float(np.interp(663.0, [660.0, 665.0], at_nodes))
    assert rows["ColorChecker dark skin under D65"]["true"] == pytest.approx(expect, rel=1e-6)
    at650 = np.array([r["error_pct"] for r in smooth_error_table(wl, c, 650.0)]) / 100
    assert smooth_spread_rel(wl, c, 650.0) == pytest.approx(np.sqrt(np.mean(at650**2)), rel=1e-12)


def test_smooth_error_table_names_its_spectra_and_nan_curves_give_a_nan_spread():
    """The table's rows, in order: black bodies at 2500, 3200, 5000, 6500, 10000 K, the CIE illuminants D50, D65
    and A, then the 24 Ohta ColorChecker patches under D65 (their names from colour-science's table); each black
    body's truth is Planck's law at its own temperature (written out here). Curves that are NaN everywhere give
    no finite error: the spread is NaN, quietly (no warning from a mean of nothing). A wavelength outside a curve
    is NaN for the spline reader."""
    wl = np.arange(400.0, 721.0, 5.0)
    c = {"R": _gauss(wl, 610, 30, 40.0), "G": _gauss(wl, 540, 35, 55.0), "B": _gauss(wl, 460, 25, 30.0)}
    rows = smooth_error_table(wl, c, 660.0)  # on a grid node: the truth is the spectrum's own sample
    patches = list(colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"])
    assert [r["spectrum"] for r in rows] == (
        [f"black body {t} K" for t in (2500, 3200, 5000, 6500, 10000)] + ["CIE D50", "CIE D65", "CIE A"]
        + [f"ColorChecker {p} under D65" for p in patches])
    for row, t in zip(rows[:5], (2500.0, 3200.0, 5000.0, 6500.0, 10000.0), strict=True):
        assert row["true"] == pytest.approx(float(_planck_w_m2_sr_nm(t, 660.0)), rel=1e-9)
    assert rows[5]["true"] == pytest.approx(float(colour.SDS_ILLUMINANTS["D50"][660.0]), rel=1e-12)
    assert rows[7]["true"] == pytest.approx(float(colour.SDS_ILLUMINANTS["A"][660.0]), rel=1e-12)
    nan = {k: np.full(wl.size, np.nan) for k in "RGB"}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(smooth_spread_rel(wl, nan, 663.0))
    assert np.isnan(_interp(wl, wl, 399.0)) and np.isnan(_interp(wl, wl, 720.5))
    assert _interp(wl, wl, 720.0) == pytest.approx(720.0, rel=1e-12)


def test_channel_prediction_colour_matrix_inverse_and_green_uncertainty():
    """g = α x^γ + β at x = 0.02 s; the colour matrix's to_raw solves j = M r (checked by M · to_raw(j) = j);
    the G uncertainty of a Bayer curve is ½√(u_G1² + u_G2²) (the mean of two independent planes)."""
    ch = _channel(alpha=5000.0, gamma=0.9, beta=12.0)
    assert float(ch.predict(0.02)) == pytest.approx(5000.0 * 0.02**0.9 + 12.0, rel=1e-12)
    m = np.array([[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [0.05, -0.5, 1.45]])
    cm = ColourMatrix(m, np.zeros((3, 3)), (5, 5, 5), (0.0, 0.0, 0.0), ())
    j = np.array([[100.0, 10.0], [200.0, 20.0], [50.0, 5.0]])
    np.testing.assert_allclose(m @ cm.to_raw(j), j, rtol=1e-5)
    wl = np.arange(400.0, 701.0, 100.0)
    s = SpectralSensitivity(wl, {p: np.ones(4) for p in PLANES},
                            {"R": np.full(4, 0.1), "G1": np.full(4, 0.3), "G2": np.full(4, 0.4), "B": np.full(4, 0.2)},
                            "relative", "relative")
    u = s.rgb_uncertainty()
    assert set(u) == {"R", "G", "B"}
    np.testing.assert_allclose([u["R"][0], u["G"][0], u["B"][0]], [0.1, 0.25, 0.2])
    linear = SpectralSensitivity(wl, {p: np.ones(4) for p in "RGB"},
                                 {"R": np.full(4, 0.1), "G": np.full(4, 0.3), "B": np.full(4, 0.2)},
                                 "relative", "relative")
    u = linear.rgb_uncertainty()  # a linear RAW curve: its own G
    assert set(u) == {"R", "G", "B"}
    np.testing.assert_allclose([u["R"][0], u["G"][0], u["B"][0]], [0.1, 0.3, 0.2])
    assert cm.to_raw(j).dtype == np.float32


def test_field_spectral_ratio_is_the_per_wavelength_mixture():
    """Per wavelength, the field model's R_λ is (1 − f) R_dir + f R_sky with f the diffuse fraction: under a
    sky that is all diffuse it is the sky form alone, under one that is all direct the direct beam alone."""
    sky_wl = np.arange(500.0, 761.0, 10.0)
    geom = FieldGeometry(view_angle_rad=0.2, albedo=0.9)
    all_diffuse = field_band_model(BAND_WL, BAND_C, geometry=geom,
                                   sky=MeasuredSky(40.0, sky_wl, np.zeros(sky_wl.size), np.ones(sky_wl.size)))
    all_direct = field_band_model(BAND_WL, BAND_C, geometry=geom,
                                  sky=MeasuredSky(40.0, sky_wl, np.ones(sky_wl.size), np.zeros(sky_wl.size)))
    tau = (pure_water_absorption_per_m(BAND_WL) + _bricaud_per_m(9.0)) * 0.7
    g40 = replace(geom, sun_zenith_rad=np.radians(40.0))
    np.testing.assert_allclose(all_diffuse.spectral_ratio(9.0, 0.7), g40.sky_form().ratio(tau), rtol=1e-10)
    np.testing.assert_allclose(all_direct.spectral_ratio(9.0, 0.7), g40.direct_form().ratio(tau), rtol=1e-10)


def test_monte_carlo_sigma_of_a_linear_inversion():
    """B = exp(−p C) with p ~ N(0.03, 0.0015): C = ln(1/B)/p, so σ_C ≈ C σ_p/p = 5 % of C to first order (the
    1/p nonlinearity adds (σ_p/p)² ≈ 0.25 % relative); 400 draws: the standard error of a standard deviation is
    1/√(2·399) = 3.5 %, so within 12 % (3.4σ)."""
    p = Uncertain("absorption", 0.03, 0.0015, "per µg/L")
    sigma = monte_carlo_sigma(lambda pv, cc: np.exp(-pv * np.asarray(cc, float)), p, float(np.exp(-0.03 * 40.0)))
    assert sigma == pytest.approx(0.05 * 40.0, rel=0.12)


def test_band_ratio_derivative_of_a_lamp_at_depth_for_an_array_of_concentrations():
    """The lamp's form depends on the depth (its path to the disk), so dB/dC must use the form at that depth;
    with an array of C the result has C's shape. Against central differences (h = 1e-3 C)."""
    model = BandModel(BAND_WL, BAND_C, geometry=LampModel(height_m=0.3, lamp_angle_rad=0.2))
    c, d = np.array([3.0, 40.0]), 0.9
    h = 1e-3 * c
    numeric = (model.ratio(c + h, d) - model.ratio(c - h, d)) / (2 * h)
    got = model.ratio_derivative(c, d)
    assert got.shape == (2,)
    np.testing.assert_allclose(got, numeric, rtol=1e-5)
    np.testing.assert_allclose(model.ratio_and_derivative(c, d)[1], numeric, rtol=1e-5)


def test_merging_sweeps_the_other_way_round_and_its_guards():
    """b below a (b: 400-600 nm, a: 550-750 nm) gives the same overlap; without scaling k = 1 and no scale
    uncertainty is added; sweeps without a bandwidth merge to none; different modes, deconvolution, planes, and
    absolute sweeps at different reference settings are refused, while relative ones at different settings
    merge; an overlap of exactly ``min_overlap`` wavelengths is enough."""
    lo, hi = np.arange(400.0, 601.0, 10.0), np.arange(550.0, 751.0, 10.0)

    def sweep(wl, f=1.0, **kw):
        v = _gauss(wl, 560.0, 80.0) + 0.1
        return SpectralSensitivity(wl, {p: v / f for p in "RGB"}, {p: 0.01 * v / f for p in "RGB"}, "relative",
                                   kw.pop("mode", "relative"), **kw)

    m = merge_sweeps(sweep(hi, reference_iso=200.0, reference_f_number=4.0),
                     sweep(lo, 2.5, reference_iso=200.0, reference_f_number=4.0))
    np.testing.assert_allclose(m.values["R"], _gauss(m.wavelength_nm, 560.0, 80.0) + 0.1, rtol=1e-12)
    assert m.units == "relative" and m.mode == "relative" and m.deconvolved is False and m.bandwidth_nm is None
    assert m.n_frames == {}
    assert (m.reference_iso, m.reference_f_number) == (200.0, 4.0)  # the first sweep's setting is kept
    plain = merge_sweeps(sweep(lo), sweep(hi), scale=False)
    only_b = plain.wavelength_nm > 600
    np.testing.assert_allclose(plain.uncertainty["G"][only_b], 0.01 * (_gauss(plain.wavelength_nm[only_b],
                                                                              560.0, 80.0) + 0.1), rtol=1e-12)
    np.testing.assert_allclose(plain.values["G"], _gauss(plain.wavelength_nm, 560.0, 80.0) + 0.1, rtol=1e-12)
    merge_sweeps(sweep(lo), sweep(np.arange(590.0, 700.0, 10.0)))  # 590, 600: two are enough by default
    with pytest.raises(CamcalError, match="overlap at 2 wavelengths; need 3"):
        merge_sweeps(sweep(lo), sweep(np.arange(590.0, 700.0, 10.0)), min_overlap=3)
    with pytest.raises(CamcalError, match="different mode or deconvolution"):
        merge_sweeps(sweep(lo), sweep(hi, deconvolved=True))
    with pytest.raises(CamcalError, match="different mode or deconvolution"):
        merge_sweeps(sweep(lo), sweep(hi, mode="absolute"))
    with pytest.raises(CamcalError, match="different reference settings"):
        merge_sweeps(sweep(lo, mode="absolute"), sweep(hi, mode="absolute", reference_iso=400.0))
    merge_sweeps(sweep(lo), sweep(hi, reference_iso=400.0))
    bayer = SpectralSensitivity(hi, {p: np.ones(hi.size) for p in PLANES}, {p: np.ones(hi.size) for p in PLANES},
                                "relative", "relative")
    with pytest.raises(CamcalError, match="planes R, G, B and R, G1, G2, B"):
        merge_sweeps(sweep(lo), bayer)


def test_radiance_model_at_the_ends_of_the_curve_and_on_short_curves():
    """λ0 on the first or last sample is inside the calibrated range (the value there is the sample); a 4-sample
    curve is read with the cubic through its 4 points (numpy polyfit, exact), a 3-sample one linearly and without
    a slit correction (no second derivative); negative noise samples are clipped before the band integral; a
    channel without sensitivity is refused; the narrowband model keeps the band integrals, the wavelength, the
    estimator name; with only the line width known no slit correction is made."""
    wl = np.arange(400.0, 701.0, 5.0)
    c = {"R": _gauss(wl, 600, 80, 40.0), "G": _gauss(wl, 540, 80, 55.0), "B": _gauss(wl, 460, 80, 30.0)}
    for at in (400.0, 700.0):
        m = radiance_model(wl, c, None, at, "narrowband")
        best = max("RGB", key=lambda k: float(_gauss(at, *{"R": (600, 80, 40.0), "G": (540, 80, 55.0),
                                                            "B": (460, 80, 30.0)}[k])))
        assert m.channel == best
        assert float(m.weights["RGB".index(best)]) == pytest.approx(1 / c[best][0 if at == 400 else -1], rel=1e-12)
    with pytest.raises(CamcalError, match="outside the calibrated range 400-700 nm"):
        radiance_model(wl, c, None, 399.0)
    with pytest.raises(CamcalError, match="choose narrowband, smooth"):
        radiance_model(wl, c, None, 663.0, "band")
    m = radiance_model(wl, c, None)
    assert m.wavelength_nm == 663.0 and m.estimator == "narrowband"
    np.testing.assert_allclose(m.band_integral, [np.trapezoid(c[k], wl) for k in "RGB"], rtol=1e-12)
    assert m.band_unc.shape == (3,) and not np.any(m.band_unc)
    assert radiance_model(wl, c, None, line_fwhm_nm=1.0).weights == pytest.approx(m.weights, rel=1e-15)
    mf = radiance_model(wl, c, None, filter_fwhm_nm=5.0)
    assert mf.units == f"{units.SPECTRAL_RADIANCE} (mean over the filter band)"
    # short curves
    w4 = np.array([600.0, 640.0, 680.0, 720.0])
    r4 = np.array([10.0, 30.0, 25.0, 5.0])
    short = {"R": r4, "G": 0.1 * r4, "B": 0.1 * r4}
    cubic = np.polyval(np.polyfit(w4, r4, 3), 663.0)
    assert radiance_model(w4, short, None, 663.0).weights[0] == pytest.approx(1 / cubic, rel=1e-9)
    w3, r3 = w4[:3], r4[:3]
    three = {"R": r3, "G": 0.1 * r3, "B": 0.1 * r3}
    lin = 30.0 + (663.0 - 640.0) / 40.0 * (25.0 - 30.0)
    m3 = radiance_model(w3, three, None, 663.0, line_fwhm_nm=1.0, slit_fwhm_nm=10.0)
    assert m3.weights[0] == pytest.approx(1 / lin, rel=1e-12)
    # negative noise samples are not sensitivity; a channel without any is refused
    noisy = dict(c, B=np.where(wl > 650, -0.5, c["B"]))
    mb = radiance_model(wl, noisy, None, 663.0, "smooth")
    assert mb.band_integral[2] == pytest.approx(np.trapezoid(np.clip(noisy["B"], 0, None), wl), rel=1e-12)
    with pytest.raises(CamcalError, match="no sensitivity at all"):
        radiance_model(wl, dict(c, G=np.zeros(wl.size)), None, 663.0)


def test_band_sigma_without_an_illuminant_and_with_negative_noise_samples():
    """The same linear propagation with a flat illuminant (none given) and a curve whose tail carries negative
    noise samples: those are clipped out of the band, so their uncertainty does not count."""
    c = BAND_C - 2e-3  # the tails go negative
    u = np.full(BAND_WL.size, 4e-3)
    model = BandModel(BAND_WL, c)
    var = 0.0
    for k in np.flatnonzero(c > 0):
        dc = np.zeros_like(c)
        dc[k] = 1e-3 * c[k]
        up = float(BandModel(BAND_WL, c + dc).ratio(20.0, 1.0))
        down = float(BandModel(BAND_WL, c - dc).ratio(20.0, 1.0))
        var += ((up - down) / (2 * dc[k]) * u[k]) ** 2
    assert np.any(c < 0)
    assert float(model.ratio_sigma_from_sensitivity(20.0, 1.0, u)) == pytest.approx(np.sqrt(var), rel=1e-4)


def test_flat_centre_start_is_the_vertex_of_the_quadratic_kept_inside_the_central_80_percent():
    """The radial fit's start for the optical centre: the vertex of a quadratic surface fitted to the blocks. On
    blocks that lie exactly on d = 5 − 0.002 (x − 36)² − 0.004 (y − 27)² + 0.001 (x − 36)(y − 27) over the box
    x 10…50, y 20…40 (not square, so the axes' scales matter) it is (36, 27) itself. A vertex outside the central
    80 % of the box (x0 = 49, y0 = 21: 95 % and 90 % of the half-widths out) is clipped to it on each side
    (30 + 0.8·20, 30 − 0.8·10); blocks of zeros (no vertex: a singular Hessian) and data with a NaN give the
    box's centre."""
    xs, ys = np.meshgrid(np.linspace(10.0, 50.0, 9), np.linspace(20.0, 40.0, 7))
    x, y = xs.ravel(), ys.ravel()
    box = (10.0, 50.0, 20.0, 40.0)

    def bowl(x0, y0):
        return 5.0 - 0.002 * (x - x0) ** 2 - 0.004 * (y - y0) ** 2 + 0.001 * (x - x0) * (y - y0)

    np.testing.assert_allclose(_quadratic_vertex(x, y, bowl(36.0, 27.0), box), (36.0, 27.0), atol=1e-8)
    np.testing.assert_allclose(_quadratic_vertex(x, y, bowl(49.0, 21.0), box), (46.0, 22.0), atol=1e-8)
    np.testing.assert_allclose(_quadratic_vertex(x, y, bowl(11.0, 39.5), box), (14.0, 38.0), atol=1e-8)
    assert _quadratic_vertex(x, y, np.zeros_like(x), box) == (30.0, 30.0)  # c = 0 exactly: Hessian singular
    with_nan = bowl(36.0, 27.0)
    with_nan[5] = np.nan
    assert _quadratic_vertex(x, y, with_nan, box) == (30.0, 30.0)


def test_srgb_form_fit_without_degrees_of_freedom_reports_no_reduced_chi2():
    """With as many exposures as parameters (two: p and x_w) or fewer, χ²/dof is undefined: NaN, never the
    residual sum divided by 0 or by a negative count (which would read as an infinite or a negative misfit), and
    the exponent has no uncertainty. The two points lie on V(x/0.02, 1/2.4) exactly, which the fit recovers."""
    x = np.array([0.004, 0.01])
    g = 255.0 * srgb_form_encode(x / 0.02, 1 / 2.4)
    for n in (1, 2):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            fit = fit_srgb_form(x[:n], g[:n], np.full(n, 0.3), 255.0, p0=0.5, x_white0=0.02)
        assert np.isnan(fit["chi2_red"]) and np.isnan(fit["exponent_unc"])
    assert fit["exponent"] == pytest.approx(1 / 2.4, rel=1e-6) and fit["x_white_s"] == pytest.approx(0.02, rel=1e-6)


# ---- water: the light's spectrum, describe(), the band inverse ----------------------------------------------------

def _planck_shape(t_k, wl_nm):
    """Planck's law 2hc²/λ⁵ / (exp(hc/λkT) − 1) with the exact SI constants, normalised to its maximum on wl."""
    h, c, k = 6.62607015e-34, 299792458.0, 1.380649e-23
    lam = np.asarray(wl_nm, float) * 1e-9
    b = 2 * h * c**2 / lam**5 / np.expm1(h * c / (lam * k * t_k))
    return b / np.max(b)


def test_illuminant_spectrum_is_planck_the_cie_tables_the_lamp_or_a_measured_csv(tmp_path):
    """S(λ) normalised to a maximum of 1 on the grid asked for: 'NNNNK' is Planck's law written out here (the
    temperature read from the name, 500-50000 K inclusive); a CIE name is colour-science's own table (any
    case), linear between its 5 nm nodes; 'lamp' is the shipped 3200 K black body (tabulated to 6 decimals,
    380-780 nm, NaN outside); a CSV is interpolated linearly, NaN outside its range, whatever its extension;
    'flat' and its synonyms are None."""
    from camcal.water.band import illuminant_spectrum

    wl = np.array([420.0, 555.0, 640.0, 702.5])
    for name in ("flat", " Flat ", "EQUAL", "e", "None"):
        assert illuminant_spectrum(name, wl) is None
    for name, t in (("3000K", 3000.0), ("2856.5k", 2856.5), ("500K", 500.0), ("50000K", 50000.0)):
        np.testing.assert_allclose(illuminant_spectrum(name, wl), _planck_shape(t, wl), rtol=1e-9)
    for name in ("499.9K", "50000.5K"):
        with pytest.raises(CamcalError, match="implausible"):
            illuminant_spectrum(name, wl)
    # CIE D65 and A from colour-science's tables: at their 5 nm nodes, and half-way between two nodes
    nodes = np.arange(400.0, 701.0, 5.0)
    for name, key in ((" d65 ", "D65"), ("a", "A")):
        table = colour.SDS_ILLUMINANTS[key]
        vals = np.array([table[x] for x in nodes])
        np.testing.assert_allclose(illuminant_spectrum(name, nodes), vals / vals.max(), rtol=1e-12)
        two = np.array([0.5 * (table[560.0] + table[565.0]), table[460.0]])
        np.testing.assert_allclose(illuminant_spectrum(name, np.array([562.5, 460.0])), two / two.max(), rtol=1e-12)
    with pytest.raises(CamcalError, match="unknown illuminant"):
        illuminant_spectrum("D99", wl)
    # the shipped lamp: a 3200 K black body, maximum at 780 nm within 380-780 nm
    lamp_wl = np.array([370.0, 400.0, 550.0, 700.0, 780.0, 790.0])
    lamp = illuminant_spectrum("lamp", lamp_wl)
    assert np.isnan(lamp[0]) and np.isnan(lamp[-1])
    np.testing.assert_allclose(lamp[1:-1], _planck_shape(3200.0, lamp_wl[1:-1]), atol=1e-6)
    # a measured spectrum: 1, 3, 2 at 500, 600, 700 nm
    for fname in ("light.csv", "light.txt"):
        f = tmp_path / fname
        f.write_text("# a measured light\nwavelength_nm,relative_radiance\n500,1\n600,3\n700,2\n")
        got = illuminant_spectrum(str(f), np.array([450.0, 550.0, 600.0, 650.0, 750.0]))
        np.testing.assert_allclose(got, [np.nan, 2 / 3, 1.0, 2.5 / 3, np.nan], rtol=1e-12)
    with pytest.raises(CamcalError, match="no such file"):
        illuminant_spectrum(tmp_path / "nowhere.csv", wl)


class _BareGeometry:
    """A geometry given only by its closed form (no name, no ``includes_water``): the seed's R(τ)."""

    def closed_form(self):
        return SeedModel().closed_form()


def test_band_model_describe_and_water_default_follow_the_inputs():
    """describe(): the geometry's name (its class name when it has none), the chlorophyll spectrum's source,
    where a_w comes from (Pope & Fry by default for a geometry that includes water, 'given', or none), the
    effective wavelength ∫ c⁺ S λ dλ / ∫ c⁺ S dλ by the trapezoid rule (c⁺: negative noise samples clipped,
    c below 1 kept as is; exactly zero at both ends, so the quadratures agree to rounding), and the grid's
    ends."""
    wl = np.arange(560.0, 721.0, 4.0)
    c = 0.4 * np.sin(np.pi * (wl - 560.0) / 160.0) ** 2 - 0.02  # negative tails
    s = np.linspace(0.6, 1.2, wl.size)
    cp = np.clip(c, 0.0, None)
    lam_eff = np.trapezoid(cp * s * wl, wl) / np.trapezoid(cp * s, wl)
    d = BandModel(wl, c, geometry=RefinedModel(), illuminant=s).describe()
    assert d == {"geometry": "refined", "chlorophyll": "Bricaud et al. 1998 (a*_ph)",
                 "water_absorption": "Pope & Fry 1997", "effective_wavelength_nm": pytest.approx(lam_eff, rel=1e-12),
                 "wavelength_range_nm": [560.0, 720.0]}
    flat = BandModel(wl, c, geometry=RefinedModel()).describe()
    assert flat["effective_wavelength_nm"] == pytest.approx(np.trapezoid(cp * wl, wl) / np.trapezoid(cp, wl),
                                                            rel=1e-12)
    assert BandModel(wl, c).describe()["water_absorption"] == "none (seed)"
    # a grid twice as fine above 640 nm: the trapezoid weights follow the spacing
    uneven = np.concatenate([np.arange(560.0, 640.0, 4.0), np.arange(640.0, 721.0, 2.0)])
    cu = np.sin(np.pi * (uneven - 560.0) / 160.0) ** 2 * (1.0 + (uneven - 560.0) / 80.0)
    assert BandModel(uneven, cu).describe()["effective_wavelength_nm"] == pytest.approx(
        np.trapezoid(cu * uneven, uneven) / np.trapezoid(cu, uneven), rel=1e-12)
    chl = ChlorophyllAbsorption(np.array([400.0, 800.0]), np.array([0.02, 0.02]), np.array([1.0, 1.0]), "my dye")
    given = BandModel(wl, c, geometry=RefinedModel(), water_absorption_per_m=0.3, chlorophyll=chl).describe()
    assert given["water_absorption"] == "given" and given["chlorophyll"] == "my dye"
    assert BandModel(wl, c, water_absorption_per_m=0.3).describe()["water_absorption"] == "given"
    bare = BandModel(wl, c, geometry=_BareGeometry())
    assert bare.describe()["geometry"] == "_BareGeometry"
    assert bare.describe()["water_absorption"] == "none (seed)"
    assert not np.any(bare.water_absorption())
    np.testing.assert_allclose(BandModel(wl, c, geometry=RefinedModel()).water_absorption(),
                               pure_water_absorption_per_m(wl), rtol=1e-12)


def test_band_background_spectrum_and_a_power_law_below_one_microgram():
    """A background a_bg(λ) given as a spectrum is added per wavelength to a_w (Pope & Fry for the refined
    geometry, zero for the seed's); a = A C^E and da/dC = A E C^(E−1) hold below 1 µg/L too (C = 0.5), and at
    C = 0 da/dC is its limit from above; a spectrum resampled on another grid keeps that grid and its
    source."""
    wl = np.arange(600.0, 701.0, 10.0)
    bg = np.linspace(0.3, 0.05, wl.size)  # CDOM falling with wavelength
    np.testing.assert_allclose(BandModel(wl, np.ones(wl.size), background_absorption_per_m=bg)
                               .absorption_background(), bg, rtol=1e-12)
    np.testing.assert_allclose(BandModel(wl, np.ones(wl.size), geometry=RefinedModel(),
                                         background_absorption_per_m=bg).absorption_background(),
                               pure_water_absorption_per_m(wl) + bg, rtol=1e-12)
    chl = ChlorophyllAbsorption(np.array([600.0, 700.0]), np.array([0.02, 0.01]), np.array([0.7, 0.9]), "table")
    np.testing.assert_allclose(chl.absorption_per_m(0.5), [0.02 * 0.5**0.7, 0.01 * 0.5**0.9], rtol=1e-12)
    np.testing.assert_allclose(chl.derivative_per_m(0.5), [0.02 * 0.7 * 0.5**-0.3, 0.01 * 0.9 * 0.5**-0.1],
                               rtol=1e-12)
    # at C = 0 the slope's limit from above: a linear absorber's A, zero for E > 1 or where A = 0, infinite
    # for E < 1 (a(h)/h = A h^(E-1) for small h)
    four = ChlorophyllAbsorption(np.arange(4.0), np.array([0.02, 0.03, 0.04, 0.0]), np.array([0.7, 1.0, 1.3, 0.8]))
    np.testing.assert_array_equal(four.derivative_per_m(0.0), [np.inf, 0.03, 0.0, 0.0])
    h = 1e-9
    assert four.absorption_per_m(h)[1] / h == pytest.approx(0.03, rel=1e-12)
    assert four.absorption_per_m(h)[2] / h < 1e-2 * 0.04  # A h^0.3: 0.2 % of A at h = 1e-9
    on = chl.on(wl)
    np.testing.assert_array_equal(on.wavelengths_nm, wl)
    assert on.source == "table"
    np.testing.assert_allclose(on.coefficient_m2_per_mg, 0.02 - 0.01 * (wl - 600.0) / 100.0, rtol=1e-12)


def test_band_ratio_of_a_lamp_for_an_image_of_concentrations():
    """B(C) and dB/dC of the lamp's form (not an E₃ closed form: its own ratio and derivative) for a 2 × 3 array
    of C: B against ∫ c R_λ(τ_λ) dλ / ∫ c dλ by the trapezoid rule with τ_λ = (a_w + A C^E) d from the Pope &
    Fry and Bricaud tables and the lamp's per-wavelength R at that depth (rel 1e-6: the quadratures differ only
    at the grid's ends, where c is 4e-7 of its peak), dB/dC against central differences (h = 1e-3 C)."""
    geom = LampModel(height_m=0.3, lamp_angle_rad=0.2)
    model = BandModel(BAND_WL, BAND_C, geometry=geom)
    c, d = np.array([[0.5, 3.0, 20.0], [60.0, 150.0, 400.0]]), 0.7
    form = geom.closed_form_at(d)
    expect = np.empty(c.shape)
    for idx, cv in np.ndenumerate(c):
        r = form.ratio((pure_water_absorption_per_m(BAND_WL) + _bricaud_per_m(cv)) * d)
        expect[idx] = np.trapezoid(BAND_C * r, BAND_WL) / np.trapezoid(BAND_C, BAND_WL)
    b, db = model.ratio_and_derivative(c, d)
    assert b.shape == db.shape == (2, 3)
    np.testing.assert_allclose(b, expect, rtol=1e-6)
    h = 1e-3 * c
    np.testing.assert_allclose(db, (model.ratio(c + h, d) - model.ratio(c - h, d)) / (2 * h), rtol=1e-5)


def test_band_sigma_for_several_concentrations_with_exact_zeros_in_the_curve():
    """σ_B for an array of C under a flat illuminant, with a curve cut to exactly zero outside 580-700 nm (as a
    profile's curve beyond its measured range) and u > 0 there: a zero sample is outside the band, like a
    clipped one, so its u does not count; linear propagation by central differences of B in each c_k > 0."""
    c = np.where((BAND_WL > 580) & (BAND_WL < 700), BAND_C, 0.0)
    u = np.full(BAND_WL.size, 3e-3)
    cs = np.array([5.0, 20.0])
    var = np.zeros(2)
    for k in np.flatnonzero(c > 0):
        dc = np.zeros_like(c)
        dc[k] = 1e-3 * c[k]
        up, down = BandModel(BAND_WL, c + dc).ratio(cs, 1.0), BandModel(BAND_WL, c - dc).ratio(cs, 1.0)
        var += ((up - down) / (2 * dc[k]) * u[k]) ** 2
    got = BandModel(BAND_WL, c).ratio_sigma_from_sensitivity(cs, 1.0, u)
    assert got.shape == (2,)
    np.testing.assert_allclose(got, np.sqrt(var), rtol=1e-4)


INV_WL = np.arange(600.0, 701.0, 2.0)
INV_C = np.sin(np.pi * (INV_WL - 600.0) / 100.0) ** 2  # exactly zero at both ends: trapezoid = the model's weights


def _inv_forward(c_ug_per_L, depth_m=0.5, bg=0.1):
    """B(C) of the seed's geometry over INV_C, written out: the trapezoid rule over the Bricaud table (A C^E, on
    the table's own 2 nm grid here) with the seed's per-wavelength closed form R(τ), τ = (a_bg + A C^E) d."""
    chl = bricaud_1998()
    a = np.interp(INV_WL, chl.wavelengths_nm, chl.coefficient_m2_per_mg)
    e = np.interp(INV_WL, chl.wavelengths_nm, chl.exponent)
    form = SeedModel().closed_form()
    out = []
    for cv in np.atleast_1d(np.asarray(c_ug_per_L, float)):
        r = form.ratio((bg + a * cv**e) * depth_m)
        out.append(np.trapezoid(INV_C * r, INV_WL) / np.trapezoid(INV_C, INV_WL))
    return np.array(out)


def _inv_ratio_and_slope(c_ug_per_L, depth_m=0.5, bg=0.1):
    """B(C) as _inv_forward and dB/dC written out: ∫ c R'(τ) d A E C^(E−1) dλ / ∫ c dλ (R' of the seed's form)."""
    chl = bricaud_1998()
    a = np.interp(INV_WL, chl.wavelengths_nm, chl.coefficient_m2_per_mg)
    e = np.interp(INV_WL, chl.wavelengths_nm, chl.exponent)
    form = SeedModel().closed_form()
    b, db = [], []
    for cv in np.asarray(c_ug_per_L, float):
        tau = (bg + a * cv**e) * depth_m
        b.append(np.trapezoid(INV_C * form.ratio(tau), INV_WL) / np.trapezoid(INV_C, INV_WL))
        db.append(np.trapezoid(INV_C * form.ratio_derivative(tau) * depth_m * a * e * cv ** (e - 1), INV_WL)
                  / np.trapezoid(INV_C, INV_WL))
    return np.array(b), np.array(db)


def _inv_sigma(c, sigma_ln_ratio, depth_m=0.5):
    """σ_C = σ_ln r / |d ln B/dC|, the derivative by central differences (h = 1e-4 C) of the forward model."""
    h = 1e-4 * c
    dln = (np.log(_inv_forward(c + h, depth_m)) - np.log(_inv_forward(c - h, depth_m))) / (2 * h)
    return sigma_ln_ratio / np.abs(dln)


def test_band_inverse_round_trip_through_a_forward_model_written_out():
    """Ratios rendered by _inv_forward at C from just above the table's first node (1e-4 µg/L) to just below
    its last (1e5 µg/L) come back as C (rel 1e-7: the table's interpolation, measured ~1e-9), in mol/L through
    chlorophyll-a's 893.5 g/mol, with σ_C = σ_ln r / |d ln B/dC| (rel 1e-4: the central difference and the
    table's slope) for a scalar and a per-pixel σ_ln r; the model's inverse is cached per depth and passes
    its node count on; an image keeps its shape; without σ_ln r, σ_C is NaN; τ is not defined (NaN). Across
    the table σ_C = σ_ln r · B/|dB/dC| holds to 3e-7 with dB/dC written out."""
    from camcal.water.band import BandInverse

    model = BandModel(INV_WL, INV_C, background_absorption_per_m=0.1)
    c = np.array([1.01e-4, 0.3, 7.0, 250.0, 3000.0, 0.998e5])
    r = _inv_forward(c)
    inv = model.inverse(0.5)
    res = inv.concentration(r, sigma_ln_ratio=0.02)
    assert not np.any(res.reason)
    np.testing.assert_allclose(res.c_ug_per_L, c, rtol=1e-7)
    np.testing.assert_allclose(res.c_mol_per_L, c / (893.5 * 1e6), rtol=1e-7)
    np.testing.assert_allclose(res.sigma_ug_per_L, _inv_sigma(c, 0.02), rtol=1e-4)
    assert res.tau.dtype == np.float64 and np.all(np.isnan(res.tau))
    assert res.reason.dtype == np.uint8
    per_pixel = np.linspace(0.01, 0.06, c.size)
    np.testing.assert_allclose(inv.concentration(r, sigma_ln_ratio=per_pixel).sigma_ug_per_L,
                               _inv_sigma(c, per_pixel), rtol=1e-4)
    img = inv.concentration(r.reshape(2, 3))
    assert img.c_ug_per_L.shape == img.sigma_ug_per_L.shape == img.reason.shape == (2, 3)
    np.testing.assert_allclose(img.c_ug_per_L, c.reshape(2, 3), rtol=1e-7)
    assert np.all(np.isnan(img.sigma_ug_per_L))
    # σ_C = σ_ln r · B/|dB/dC| across the table (400 C from 1.3e-4 to 9e4 µg/L), dB/dC written out: rel 3e-7
    # (the slope of the table's cubics, measured within 1e-7 of it)
    across = np.logspace(-3.9, 4.95, 400)
    b_across, db_across = _inv_ratio_and_slope(across)
    np.testing.assert_allclose(inv.concentration(b_across, sigma_ln_ratio=1.0).sigma_ug_per_L,
                               b_across / np.abs(db_across), rtol=3e-7)
    # another depth: another table
    r1 = _inv_forward(c[1:4], 1.2)
    np.testing.assert_allclose(model.inverse(1.2).concentration(r1).c_ug_per_L, c[1:4], rtol=1e-7)
    assert model.inverse(1.2) is model.inverse(1.2)
    coarse = model.inverse(0.5, nodes=4).concentration(_inv_forward(7.0)).c_ug_per_L
    np.testing.assert_array_equal(coarse, BandInverse(model, 0.5, 4).concentration(_inv_forward(7.0)).c_ug_per_L)
    # a ratio in single precision: its logarithm is taken in double (B of the result matches it to 1e-10)
    r32 = _inv_forward(c[1:5]).astype(np.float32)
    back = _inv_forward(inv.concentration(r32).c_ug_per_L)
    np.testing.assert_allclose(back, r32.astype(np.float64), rtol=1e-10)


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


def test_band_inverse_of_a_four_node_table_and_its_refusals(tmp_path):
    """A table of four nodes (1e-4, 0.1, 100, 1e5 µg/L: the fewest accepted) goes through its nodes (rel 1e-8);
    a depth that is not positive and finite is refused; a spectrum that absorbs nowhere in the band (a dye
    CSV absorbing at 400-450 nm only, or the default Bricaud table, which ends at 700 nm, under a 720-800 nm
    channel) is refused, naming the CSV when there is one."""
    from camcal.water.band import BandInverse, read_chlorophyll_csv

    model = BandModel(INV_WL, INV_C, background_absorption_per_m=0.1)
    four = BandInverse(model, 0.5, nodes=4)
    np.testing.assert_allclose(four.concentration(_inv_forward([1e-4, 0.1, 100.0])).c_ug_per_L,
                               [1e-4, 0.1, 100.0], rtol=1e-8)
    for depth in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(CamcalError, match="depth must be positive"):
            BandInverse(model, depth)
    f = tmp_path / "blue_dye.csv"
    f.write_text("wavelength_nm,A_m2_per_mg\n380,0.05\n450,0.05\n451,0\n800,0\n")
    with pytest.raises(CamcalError, match="does not respond") as err:
        BandInverse(BandModel(INV_WL, INV_C, chlorophyll=read_chlorophyll_csv(f)), 0.5)
    assert err.value.path == f
    with pytest.raises(CamcalError, match="does not respond") as err:  # a spectrum with no file behind it
        BandInverse(BandModel(INV_WL, INV_C, chlorophyll=solvent_spectrum(INV_WL, np.zeros(INV_WL.size))), 0.5)
    assert err.value.path is None
    far_red = np.arange(720.0, 801.0, 4.0)
    with pytest.raises(CamcalError, match="does not respond") as err:
        BandInverse(BandModel(far_red, np.ones(far_red.size)), 0.5)
    assert err.value.path is None


def test_band_inverse_where_the_band_stops_responding_or_underflows():
    """A red channel reaching past the Bricaud table's 700 nm end: B falls to the floor of the light beyond
    700 nm that chlorophyll does not absorb; a ratio on that floor (B at 1e5 µg/L, forward model written out)
    is TOO_DARK, a ratio above it inverts (rel 1e-7). On the way down to the floor (1-1e5 µg/L, 300 ratios)
    each ratio gives C to 1e-5 (the table's check is 1e-6 in ln C at its nodes) or, from some C on, TOO_DARK;
    never a wrong C. A dye absorbing so strongly that B underflows: a ratio of 1e-305 (below the 1e-300 the
    table keeps) is TOO_DARK, a ratio of 1e-150 inverts."""
    from camcal.water.invert import Reason

    wl = np.arange(640.0, 761.0, 2.0)
    c = np.sin(np.pi * (wl - 640.0) / 120.0) ** 2
    chl = bricaud_1998()
    a = np.interp(wl, chl.wavelengths_nm, chl.coefficient_m2_per_mg, right=0.0)
    e = np.interp(wl, chl.wavelengths_nm, chl.exponent)
    form = SeedModel().closed_form()

    def fwd(cv):
        return np.trapezoid(c * form.ratio((0.1 + a * cv**e) * 0.5), wl) / np.trapezoid(c, wl)

    inv = BandModel(wl, c, background_absorption_per_m=0.1).inverse(0.5)
    res = inv.concentration(np.array([fwd(1e5), fwd(5.0), fwd(80.0)]))
    assert res.reason.tolist() == [Reason.TOO_DARK, 0, 0]
    np.testing.assert_allclose(res.c_ug_per_L[1:], [5.0, 80.0], rtol=1e-7)
    cs = np.logspace(0.0, 5.0, 300)
    down = inv.concentration(np.array([fwd(cv) for cv in cs]))
    ok = down.reason == 0
    assert np.all(ok[:170]) and not np.any(ok[np.argmin(ok):])  # C up to 700 µg/L; then TOO_DARK throughout
    assert np.all(down.reason[~ok] == Reason.TOO_DARK)
    np.testing.assert_allclose(down.c_ug_per_L[ok], cs[ok], rtol=1e-5)
    dye = solvent_spectrum(INV_WL, np.full(INV_WL.size, 60.0))  # A = 2.303e-4 · 60 m² mg⁻¹, linear
    dinv = BandModel(INV_WL, INV_C, chlorophyll=dye).inverse(1.0)
    a_dye = float(dye.coefficient_m2_per_mg[0])
    c_dark = brentq(lambda cv: np.log(np.trapezoid(INV_C * form.ratio(np.full(INV_WL.size, a_dye * cv)), INV_WL)
                                      / np.trapezoid(INV_C, INV_WL)) - np.log(1e-150), 1.0, 2e4)
    dark = dinv.concentration(np.array([1e-150, 1e-305]))
    assert dark.reason.tolist() == [0, Reason.TOO_DARK]
    assert dark.c_ug_per_L[0] == pytest.approx(c_dark, rel=1e-7)


def test_bias_only_model_every_field_from_bias_frames_with_planes_below_one_dn(tmp_path):
    """``fit_dark`` on bias frames alone (the bias-only model), every output against values written out here.

    Five frames of 128 × 128 pixels a plane, kept for the quantised fit: R σ = 1.5 DN and B σ = 0.97 DN (temporal
    noise above 1 DN: read noise √(mean var − 1/12) over the good pixels, EMVA 1288 eq. 4, and DSNU
    √(var(bias) − mean(var/n)); B's read noise² (0.94 DN²) and DSNU² (0.25 DN²) are below 1, so the clamps at 0
    show), G1
    σ = 0.4 DN and G2 σ = 0.35 DN (below 1 DN: the quantised-normal fit, against the simulation's truth to 3 % and
    5 % as in ``test_temporal_noise_below_one_dn_fits_consecutive_frame_pairs``); 0.2 % of R's and B's pixels
    noisy (20 DN more noise), flagged NOISY by the χ² bound of 4 degrees of freedom and left out of the figures.
    No dark current (None everywhere), no hot or dead pixels, no system gain from the dark, the file's levels, the
    frames' exposure time and ISO, no temperature; the provenance in full. Frames at two ISO settings are refused,
    naming the bias folder."""
    rng = np.random.default_rng(77)
    shape = (4, 128, 128)
    sigma, dsnu = np.array([1.5, 0.4, 0.35, 0.97]), np.array([3.0, 0.3, 0.5, 0.5])
    mu = np.array([200.0, 60.2, 60.2, 150.0])[:, None, None] + dsnu[:, None, None] * rng.standard_normal(shape)
    frames = np.rint(mu + sigma[:, None, None] * rng.standard_normal((5, *shape)))
    noisy_px = rng.random(shape) < 2e-3
    noisy_px[1:3] = False
    frames += noisy_px * np.rint(20.0 * rng.standard_normal(frames.shape))
    var = np.var(frames, axis=0, ddof=1)
    value = frames.mean(axis=0)
    st = _read_noise_stack(var, 5, frames, level=value)
    exposure = st.exposures[0]  # 1e-4 s at ISO 100
    folder = tmp_path / "bias"
    options = DarkOptions(hot_sigma=7.0, noisy_sigma=6.0, saturation_fraction=0.02)
    model = fit_dark(DarkStacks((), st, bias_folder=folder), options)

    var32 = var.astype(np.float32).astype(np.float64)
    bound = _noisy_bound(4, 6.0)
    vhat = np.zeros(4)
    for k in range(4):  # the plane's temporal variance: the mean with its top 0.1 % left out
        v = np.sort(var32[k].ravel())
        vhat[k] = np.mean(v[v <= np.quantile(v, 0.999)])
    noisy = var32 > vhat[:, None, None] * bound
    assert np.count_nonzero(noisy[[0, 3]] & noisy_px[[0, 3]]) > 0.9 * np.count_nonzero(noisy_px)
    np.testing.assert_array_equal(model.defects, np.where(noisy, NOISY, 0).astype(np.uint8))
    assert model.dark_current_dn_per_s is None and model.dark_current_unc_dn_per_s is None
    np.testing.assert_array_equal(model.bias_dn, value.astype(np.float32))
    assert model.bias_dn.dtype == np.float32 and model.read_noise_dn.dtype == np.float32
    expect_map = _map_of_variance(var32)
    for k in (1, 2):
        expect_map[k] = np.where(noisy[k], expect_map[k], model.channels[PLANES[k]]["read_noise_dn"])
    np.testing.assert_allclose(model.read_noise_dn, expect_map, rtol=1e-6)
    b32 = value.astype(np.float32).astype(np.float64)
    for k, name in enumerate(PLANES):
        got, good = model.channels[name], ~noisy[k]
        bk = b32[k][good]
        assert got["bias_dn"] == pytest.approx(float(np.mean(bk)), rel=1e-12)
        assert got["bias_unc_dn"] == pytest.approx(float(np.sqrt(np.pi / 2) * np.std(bk) / np.sqrt(bk.size)),
                                                   rel=2e-5)  # the code's 1.2533 for √(π/2): 1.1e-5
        assert got["temporal_noise_dn"] == pytest.approx(float(np.sqrt(vhat[k])), rel=1e-6)
        if k in (0, 3):
            assert got["read_noise_dn"] == pytest.approx(float(np.sqrt(np.mean(var32[k][good]) - 1.0 / 12.0)),
                                                         rel=1e-9)
            assert got["dsnu_bias_dn"] == pytest.approx(
                float(np.sqrt(np.var(bk) - np.mean(var32[k][good] / 5.0))), rel=1e-9)
            assert got["dsnu_bias_dn"] == pytest.approx(dsnu[k], rel=0.05)  # 16 000 pixels: ~1 %
        else:
            assert got["read_noise_dn"] == pytest.approx(sigma[k], rel=0.03)
            assert got["dsnu_bias_dn"] == pytest.approx(dsnu[k], rel=0.05)
        assert {key: got[key] for key in got if key not in (
            "bias_dn", "bias_unc_dn", "temporal_noise_dn", "read_noise_dn", "dsnu_bias_dn")} == {
            "dark_current_dn_per_s": None, "dark_current_unc_dn_per_s": None,
            "dark_current_pixel_unc_dn_per_s": None, "dark_current_mean_dn_per_s": None,
            "dsnu_dark_current_dn_per_s": None, "gain_dn_per_e_from_dark": 0.0, "hot_pixel_count": 0,
            "dead_pixel_count": 0, "noisy_pixel_count": int(np.count_nonzero(noisy[k]))}
    assert (model.iso, model.cfa_pattern, model.temperature_c, model.exposure_times_s) == (100.0, "RGGB", None,
                                                                                            (1e-4,))
    assert model.black_level_dn == (60.0,) * 4 and model.white_level_dn == 1023.0
    assert model.provenance == {
        "dark_folder": None, "bias_folder": str(folder), "dark_files": [],
        "bias_files": [f"b{i}.dng" for i in range(5)], "frames_per_exposure": {},
        "options": {"hot_sigma": 7.0, "noisy_sigma": 6.0, "saturation_fraction": 0.02},
        "bias_source": "bias frames", "read_noise_source": "bias frames",
        "read_noise_method": "quantised-normal likelihood of 3 frame pair(s) in planes G1, G2 (temporal noise "
                             "below 1 DN); elsewhere " + NOISE_METHOD,
        "dark_current": "unknown: no dark frames (bias-only calibration); apply subtracts the bias only"}
    assert fit_dark(DarkStacks((), replace(st, cfa_pattern=None), bias_folder=folder),
                           options).cfa_pattern is None
    mixed = replace(st, exposures=(exposure,) * 4 + (Exposure(exposure_s=1e-4, iso=200.0),))
    with pytest.raises(CamcalError, match="mix ISO settings") as err:
        fit_dark(DarkStacks((), mixed, bias_folder=folder), options)
    assert err.value.path == folder


# -- response_model: the model's and the colour matrix's records, read back field by field ------------------------


def _response_record_model():
    """A RAW response with distinct numbers in every field, a colour matrix, a tone record and points."""
    from camcal.models.response import ChannelResponse, ColourMatrix, ResponseModel

    chans = {}
    for k, name in enumerate(("R", "G1", "G2", "B")):
        chans[name] = ChannelResponse(
            alpha=1000.0 + k, alpha_unc=2.0 + k, gamma=0.99 + 0.001 * k, gamma_unc=0.003 + k, beta=60.0 + k,
            beta_unc=0.5 + k, linear_range_dn=(70.0 + k, 3900.0 + k), saturation_dn=4095.0 - k,
            linearity_error_pct=0.25 + k, pearson_r=0.9799 if name == "B" else 0.98 + 0.001 * k,
            rate_dn_per_s=1005.0 + k, rate_dn_per_s_unc=1.5 + k, offset_dn=61.0 + k,
            saturation_exposure_s=4.0 + k, fitted_exposure_s=(0.01 + k, 3.5 + k))
    cm = ColourMatrix(matrix=np.array([[1.5, -0.3, 0.1], [-0.2, 1.4, -0.1], [0.05, -0.4, 1.6]]),
                      matrix_unc=np.array([[0.01, 0.02, 0.03], [0.04, 0.05, 0.06], [0.07, 0.08, 0.09]]),
                      n_frames=(7, 8, 9), residual_rms_rel=(0.011, 0.012, 0.013),
                      sources=("/data/sweep/one", "relative/two"))
    points = {"R": {"x_s": [1.0, 2.0, 4.0], "files": ["c.dng", "a.dng", "b.dng"], "saturated": [True, False, True]},
              "G1": {"files": ["a.dng", "c.dng", "d.dng"], "saturated": [True, True, False]},
              "G2": None, "B": {"files": ["z.dng", "y.dng"], "saturated": [True]}}  # lengths differ: pairs only
    tone = {"channels": {"R": {"linear_gain_dn_per_s": 12.5}}, "note": "tone"}
    return ResponseModel(kind="raw", channels=chans, reference_iso=200.0, reference_f_number=2.8, tone=tone,
                         white_level_dn=4095.0, dark_subtracted=True, roi=(0.1, 0.9, 0.2, 0.8), points=points,
                         colour_matrix=cm)


def test_response_model_record_reads_back_every_field_through_json():
    """to_dict -> JSON text -> from_dict keeps every field, compared with the numbers written in the test; the
    summary carries the equation, the r >= 0.98 flag (0.98 itself passes, 0.9799 does not) and the colour matrix
    record (source folders reduced to their names); saturated files are the union over channels, sorted, once each."""
    import json

    from camcal.models.response import ResponseModel

    m = _response_record_model()
    d = m.to_dict()
    assert d["roi"] == [0.1, 0.9, 0.2, 0.8] and d["points"] is m.points
    assert d["kind"] == "raw" and d["reference_iso"] == 200.0 and d["reference_f_number"] == 2.8
    assert d["white_level_dn"] == 4095.0 and d["dark_subtracted"] is True and d["tone"] == m.tone
    assert d["equation"] == ("g = alpha * x**gamma + beta (seed eq. 12), x = ISO*t/N^2 relative to the reference, s")
    assert [d["channels"][n]["linear_pearson_r_ok"] for n in ("R", "G1", "G2", "B")] == [True, True, True, False]
    assert d["channels"]["G2"]["linear_range_dn"] == [72.0, 3902.0]
    assert d["channels"]["G2"]["fitted_exposure_s"] == [2.01, 5.5]
    assert set(d) == {"kind", "equation", "reference_iso", "reference_f_number", "white_level_dn", "dark_subtracted",
                      "channels", "tone", "colour_matrix", "roi", "points"}
    cmd = d["colour_matrix"]
    assert cmd["sources"] == ["one", "two"] and cmd["n_frames"] == [7, 8, 9]
    assert cmd["residual_rms_rel"] == [0.011, 0.012, 0.013]
    assert cmd["matrix"] == [[1.5, -0.3, 0.1], [-0.2, 1.4, -0.1], [0.05, -0.4, 1.6]]
    assert cmd["matrix_unc"] == [[0.01, 0.02, 0.03], [0.04, 0.05, 0.06], [0.07, 0.08, 0.09]]
    assert cmd["equation"] == ("linearised processed (R,G,B) = matrix @ RAW (R, (G1+G2)/2, B) DN above the "
                               "black level")
    assert set(cmd) == {"matrix", "matrix_unc", "n_frames", "residual_rms_rel", "sources", "equation"}
    s = m.summary()
    assert "roi" not in s and "points" not in s and s["channels"] == d["channels"]
    assert m.saturated_files() == ["a.dng", "b.dng", "c.dng", "z.dng"]  # after G2's missing points too

    back = ResponseModel.from_dict(json.loads(json.dumps(d)))
    assert back.kind == "raw" and back.reference_iso == 200.0 and back.reference_f_number == 2.8
    assert back.white_level_dn == 4095.0 and back.dark_subtracted is True
    assert back.roi == (0.1, 0.9, 0.2, 0.8) and back.tone == m.tone and back.points == m.points
    assert list(back.channels) == ["R", "G1", "G2", "B"]
    for k, name in enumerate(("R", "G1", "G2", "B")):
        c = back.channels[name]
        assert (c.alpha, c.alpha_unc, c.gamma, c.gamma_unc, c.beta, c.beta_unc) == (
            1000.0 + k, 2.0 + k, 0.99 + 0.001 * k, 0.003 + k, 60.0 + k, 0.5 + k)
        assert c.linear_range_dn == (70.0 + k, 3900.0 + k) and c.saturation_dn == 4095.0 - k
        assert c.linearity_error_pct == 0.25 + k
        assert c.pearson_r == (0.9799 if name == "B" else 0.98 + 0.001 * k)
        assert (c.rate_dn_per_s, c.rate_dn_per_s_unc, c.offset_dn) == (1005.0 + k, 1.5 + k, 61.0 + k)
        assert c.saturation_exposure_s == 4.0 + k and c.fitted_exposure_s == (0.01 + k, 3.5 + k)
    cm = back.colour_matrix
    np.testing.assert_array_equal(cm.matrix, [[1.5, -0.3, 0.1], [-0.2, 1.4, -0.1], [0.05, -0.4, 1.6]])
    np.testing.assert_array_equal(cm.matrix_unc, [[0.01, 0.02, 0.03], [0.04, 0.05, 0.06], [0.07, 0.08, 0.09]])
    assert cm.n_frames == (7, 8, 9) and cm.residual_rms_rel == (0.011, 0.012, 0.013)
    assert cm.sources == ("one", "two")


def test_response_model_record_defaults_and_refusals():
    """A minimal record reads back with the documented defaults (NaN for absent or null numbers, no dark
    subtraction, the whole frame, no points, no colour matrix); linear RAW (R, G, B) is accepted; every malformed
    record is refused with one line naming the exception and the problem."""
    import copy
    import math

    from camcal.models.response import ResponseModel

    rec = {"alpha": 1.0, "alpha_unc": 0.1, "gamma": 1.0, "gamma_unc": None, "beta": 2.0, "beta_unc": 0.2,
           "linear_range_dn": [3.0, None], "saturation_dn": 255.0, "linearity_error_pct": 0.5, "pearson_r": 0.99,
           "offset_dn": None}
    d = {"kind": "processed", "reference_iso": 100, "reference_f_number": None,
         "channels": {n: dict(rec) for n in ("R", "G", "B")}}
    m = ResponseModel.from_dict(copy.deepcopy(d))
    assert m.kind == "processed" and m.reference_iso == 100.0 and math.isnan(m.reference_f_number)
    assert m.tone is None and math.isnan(m.white_level_dn) and m.dark_subtracted is False
    assert m.roi == (0.0, 1.0, 0.0, 1.0) and m.points == {} and m.colour_matrix is None
    c = m.channels["G"]
    assert (c.alpha, c.alpha_unc, c.gamma, c.beta, c.beta_unc, c.saturation_dn) == (1.0, 0.1, 1.0, 2.0, 0.2, 255.0)
    assert (c.linearity_error_pct, c.pearson_r, c.linear_range_dn[0]) == (0.5, 0.99, 3.0)
    for v in (c.gamma_unc, c.linear_range_dn[1], c.rate_dn_per_s, c.rate_dn_per_s_unc, c.offset_dn,
              c.saturation_exposure_s, *c.fitted_exposure_s):
        assert math.isnan(v)
    assert len(c.fitted_exposure_s) == 2
    assert ResponseModel.from_dict({**copy.deepcopy(d), "points": None, "colour_matrix": None}).points == {}
    assert ResponseModel(kind="raw", channels={}, reference_iso=1.0, reference_f_number=1.0).saturated_files() == []
    lin = ResponseModel.from_dict({**copy.deepcopy(d), "kind": "raw", "dark_subtracted": 1})
    assert lin.kind == "raw" and list(lin.channels) == ["R", "G", "B"] and lin.dark_subtracted is True

    def refused(bad: dict) -> str:
        with pytest.raises(CamcalError) as info:
            ResponseModel.from_dict(bad)
        return str(info.value)

    expect = ("malformed response model (ValueError: kind {!r} with channels {}; expected raw R, G1, G2, B (or R, G, "
              "B for linear RAW, Y for a monochrome sensor) or processed R, G, B)")
    assert refused({**d, "kind": "jpeg"}) == expect.format("jpeg", "['B', 'G', 'R']")
    four = {n: dict(rec) for n in ("R", "G1", "G2", "B")}
    assert refused({**d, "channels": four}) == expect.format("processed", "['B', 'G1', 'G2', 'R']")
    assert refused({**d, "kind": "raw", "channels": {n: dict(rec) for n in ("R", "G1", "B")}}) == expect.format(
        "raw", "['B', 'G1', 'R']")
    assert refused({k: v for k, v in d.items() if k != "reference_iso"}) == "malformed response model (KeyError: " \
        "'reference_iso')"
    assert refused({k: v for k, v in d.items() if k != "channels"}) == "malformed response model (KeyError: " \
        "'channels')"
    assert refused({**d, "channels": {"R": {**rec, "linear_range_dn": [1.0]}}}) == (
        "malformed response model (IndexError: list index out of range)")
    assert refused({**d, "reference_iso": "fast"}) == ("malformed response model (ValueError: could not convert "
                                                       "string to float: 'fast')")
    assert refused({**d, "channels": {"R": {**rec, "alpha": [1]}}}).startswith("malformed response model (TypeError: ")
    assert refused({**d, "colour_matrix": {"matrix": np.zeros((3, 3)).tolist()}}) == (
        "malformed colour matrix (the colour matrix is singular)")


def test_colour_matrix_record_defaults_and_refusals():
    """ColourMatrix.from_dict: absent uncertainties are zeros, frame counts 0, residuals NaN, no sources; a
    non-3x3 or non-finite matrix, a singular one (|det| below 1e-12 max|m|^3) and per-channel lists of the wrong
    length are refused with one line each."""
    import math

    from camcal.models.response import ColourMatrix

    m = [[2.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 4.0]]
    cm = ColourMatrix.from_dict({"matrix": [[2, 0, 0], [0, 3, 0], [0, 0, 4]], "matrix_unc": [[1, 0, 0]] * 3})
    assert cm.matrix.dtype == np.float64 and cm.matrix_unc.dtype == np.float64  # integers in the file: floats
    np.testing.assert_array_equal(cm.matrix_unc, [[1.0, 0.0, 0.0]] * 3)
    cm = ColourMatrix.from_dict({"matrix": m})
    np.testing.assert_array_equal(cm.matrix, m)
    np.testing.assert_array_equal(cm.matrix_unc, np.zeros((3, 3)))
    assert cm.n_frames == (0, 0, 0) and cm.sources == ()
    assert len(cm.residual_rms_rel) == 3 and all(math.isnan(v) for v in cm.residual_rms_rel)
    cm = ColourMatrix.from_dict({"matrix": m, "n_frames": ["4", 5.0, 6], "residual_rms_rel": ["0.5", 1, 2],
                                 "sources": [1, "b"]})
    assert cm.n_frames == (4, 5, 6) and all(type(v) is int for v in cm.n_frames)
    assert cm.residual_rms_rel == (0.5, 1.0, 2.0) and all(type(v) is float for v in cm.residual_rms_rel)
    assert cm.sources == ("1", "b")
    # the singularity threshold is 1e-12 · max(1, max|m|)^3: it scales with large entries and has a floor of 1
    ok_big = np.diag([1e3, 1e3, 1e3 * 1e-11])  # det 1e-2 >= 1e-12 · 1e9 = 1e-3: kept
    assert ColourMatrix.from_dict({"matrix": ok_big.tolist()}).matrix[2, 2] == 1e-8
    edge = np.diag([1.0, 1.0, 1e-12])  # det 1e-12 (LU: 1.000000000000001e-12), at the threshold: kept
    assert ColourMatrix.from_dict({"matrix": edge.tolist()}).matrix[2, 2] == 1e-12
    ok_small = np.diag([0.5, 0.5, 1e-11])  # det 2.5e-12 >= 1e-12 (scale floor 1): kept
    assert ColourMatrix.from_dict({"matrix": ok_small.tolist()}).matrix[2, 2] == 1e-11

    def refused(bad: dict) -> str:
        with pytest.raises(CamcalError) as info:
            ColourMatrix.from_dict(bad)
        return str(info.value)

    shape = "malformed colour matrix (matrix and matrix_unc must be finite 3x3 arrays)"
    sing = "malformed colour matrix (the colour matrix is singular)"
    three = "malformed colour matrix (n_frames and residual_rms_rel need 3 values)"
    assert refused({"matrix": [[1.0, 0.0], [0.0, 1.0]]}) == shape
    assert refused({"matrix": m, "matrix_unc": [[0.0] * 3] * 2}) == shape
    assert refused({"matrix": [[np.nan, 0, 0], [0, 1, 0], [0, 0, 1]]}) == shape
    assert refused({"matrix": m, "matrix_unc": [[np.inf, 0, 0], [0, 0, 0], [0, 0, 0]]}) == shape
    assert refused({"matrix": np.diag([1e3, 1e3, 1e3 * 1e-13]).tolist()}) == sing  # det 1e-4 < 1e-3
    assert refused({"matrix": np.diag([0.5, 0.5, 1e-12]).tolist()}) == sing  # det 2.5e-13 < 1e-12
    assert refused({"matrix": np.diag([-0.5, 0.5, 1e-12]).tolist()}) == sing  # |det| counts, not det
    assert ColourMatrix.from_dict({"matrix": np.diag([-1.0, 1.0, 1.0]).tolist()}).matrix[0, 0] == -1.0
    assert refused({"matrix": m, "n_frames": [1, 2]}) == three
    assert refused({"matrix": m, "residual_rms_rel": [1, 2, 3, 4]}) == three
    assert refused({}) == "malformed colour matrix ('matrix')"
    assert refused({"matrix": m, "n_frames": 3}) == "malformed colour matrix ('int' object is not iterable)"
    assert refused({"matrix": m, "n_frames": ["x", 1, 2]}) == (
        "malformed colour matrix (invalid literal for int() with base 10: 'x')")


# -- response: the series checks and small helpers -----------------------------------------------------------------


def _exposure_series_record(x_s, mean_dn, sem_dn, files, clipped=None, kind="raw", channels=("R", "G1")):
    """An ExposureSeries with the given per-frame arrays (other fields fixed, unused by the functions tested)."""
    from camcal.calibrate.response import ExposureSeries

    x = np.asarray(x_s, float)
    n, c = np.asarray(mean_dn).shape
    return ExposureSeries(
        kind=kind, channels=tuple(channels), files=tuple(files), x_s=x, exposure_s=x.copy(), iso=np.full(n, 100.0),
        f_number=np.full(n, 2.8), mean_dn=np.asarray(mean_dn, float), sem_dn=np.asarray(sem_dn, float),
        clipped_fraction=np.zeros((n, c)) if clipped is None else np.asarray(clipped, float),
        max_dn=np.full((n, c), 100.0), white_level_dn=4095.0, black_level_dn=np.zeros(c), reference_iso=100.0,
        reference_f_number=2.8, folder="/data/series")


def test_check_monotone_tolerance_is_five_sigma_of_grouped_means():
    """Frames of one exposure are grouped: mean of their means, standard error sqrt(sum sem^2)/k. A drop between
    consecutive groups is refused above 5·hypot(σ_prev, σ_next) + 1e-6·|mean_prev|. Here the frames at x = 2 s
    (means 100, 104; sem 3, 4) give 102 ± 2.5, so with an exact next point the limit is 12.5 + 1.02e-4 DN."""
    from camcal.calibrate.response import _check_monotone

    files = ("a.dng", "b1.dng", "b2.dng", "c.dng", "d.dng")
    x = [1.0, 2.0, 2.0, 4.0, 8.0]
    sem = [[0.0, 0.0], [3.0, 3.0], [4.0, 4.0], [0.0, 0.0], [0.0, 0.0]]
    ok = np.ones(5, bool)

    def series(next_mean, ch1=(50.0, 60.0, 60.0, 70.0, 80.0), last=200.0):
        m = np.column_stack([[90.0, 100.0, 104.0, next_mean, last], ch1])
        return _exposure_series_record(x, m, sem, files)

    assert _check_monotone(series(89.6), 0, ok) is None  # drop 12.4 DN < 12.5001
    with pytest.raises(CamcalError) as info:
        _check_monotone(series(89.4), 0, ok)  # drop 12.6 DN
    assert str(info.value) == ("/data/series: raw channel R is not monotone in exposure: c.dng (x = 4 s) has mean "
                               "89.40 DN, below b1.dng (x = 2 s, 102.00 DN); check the exposure values in frames.csv")
    assert _check_monotone(series(89.4), 1, ok) is None  # the other channel rises
    # the frame that falls is left out by the mask: the remaining groups rise
    assert _check_monotone(series(89.4), 0, np.array([True, True, True, False, True])) is None
    # a drop at the first pair of groups (x = 1 -> 2 s) is checked too: 90 -> 60 ± 2.5 in channel G1
    with pytest.raises(CamcalError) as info:
        _check_monotone(series(200.0, ch1=(90.0, 58.0, 62.0, 70.0, 80.0)), 1, ok)
    assert str(info.value) == ("/data/series: raw channel G1 is not monotone in exposure: b1.dng (x = 2 s) has mean "
                               "60.00 DN, below a.dng (x = 1 s, 90.00 DN); check the exposure values in frames.csv")
    # and the last pair (x = 4 -> 8 s)
    with pytest.raises(CamcalError, match=r"d\.dng \(x = 8 s\) has mean 80\.00 DN, below c\.dng"):
        _check_monotone(series(200.0, last=80.0), 0, ok)
    # with exact means the relative term 1e-6·|mean| is the whole tolerance: 1 DN at 1e6 DN
    exact = [[0.0, 0.0]] * 5
    big = np.column_stack([[1e3, 1e6 + 10, 1e6 + 10, 1e6 + 9.1, 2e6], [1.0, 2.0, 2.0, 3.0, 4.0]])
    assert _check_monotone(_exposure_series_record(x, big, exact, files), 0, ok) is None  # drop 0.9 < 1.00001
    big[3, 0] = 1e6 + 8.9  # drop 1.1 > 1.00001
    with pytest.raises(CamcalError, match="not monotone"):
        _check_monotone(_exposure_series_record(x, big, exact, files), 0, ok)
    # exactly at the limit is not a drop: 0 -> -12.5 DN with σ 2.5 and 0 (means at 0 DN after dark subtraction)
    edge = np.column_stack([[0.0, -12.5, 1.0, 2.0, 3.0], [1.0, 2.0, 3.0, 4.0, 5.0]])
    edge_sem = [[2.5, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]]
    five = ("a", "b", "c", "d", "e")
    assert _check_monotone(_exposure_series_record([1, 2, 3, 4, 5], edge, edge_sem, five), 0, ok) is None
    edge[1, 0] = -12.6
    with pytest.raises(CamcalError, match="not monotone"):
        _check_monotone(_exposure_series_record([1, 2, 3, 4, 5], edge, edge_sem, five), 0, ok)
    # both standard errors count: σ 3 and 4 -> 5σ = 25 DN; a 24 DN drop passes
    edge[1, 0] = -24.0
    edge_sem[1] = [4.0, 0.0]
    edge_sem[0] = [3.0, 0.0]
    assert _check_monotone(_exposure_series_record([1, 2, 3, 4, 5], edge, edge_sem, five), 0, ok) is None
    # -1e6 DN means: the tolerance uses |mean|, 1 DN again
    neg = np.column_stack([[-1e6 - 20, -1e6, -1e6, -1e6 - 0.9, 0.0], [1.0, 2.0, 2.0, 3.0, 4.0]])
    assert _check_monotone(_exposure_series_record(x, neg, exact, files), 0, ok) is None


def test_roi_slices_and_window_by_hand():
    """roi_slices rounds each fraction times the side to the nearest pixel (at least one pixel, clipped to the
    plane); roi_window turns None, a central fraction f or four fractions into (y0, y1, x0, x1) and refuses the
    rest with one line each."""
    from camcal.calibrate.response import roi_slices, roi_window

    assert roi_slices((10, 20), (0.26, 0.74, 0.1, 0.56)) == (slice(3, 7), slice(2, 11))  # 2.6, 7.4; 2.0, 11.2
    assert roi_slices((10, 20), (0.0, 1.0, 0.0, 1.0)) == (slice(0, 10), slice(0, 20))
    assert roi_slices((10, 20), (0.5, 0.52, 0.5, 0.51)) == (slice(5, 6), slice(10, 11))  # one pixel at least
    assert roi_slices((10, 20), (0.96, 1.2, 0.98, 1.3)) == (slice(10, 10), slice(20, 20))  # clipped to the plane
    assert roi_slices((7, 9), (0.3, 0.6, 0.4, 0.9)) == (slice(2, 4), slice(4, 8))  # 2.1, 4.2; 3.6, 8.1
    a = np.arange(200).reshape(10, 20)
    ys, xs = roi_slices(a.shape, (0.26, 0.74, 0.1, 0.56))
    assert a[ys, xs].shape == (4, 9)

    s = np.sqrt(0.10)  # SERIES_ROI_FRACTION: the central window holding 10 % of the plane
    np.testing.assert_allclose(roi_window(None), (0.5 - s / 2, 0.5 + s / 2, 0.5 - s / 2, 0.5 + s / 2), rtol=1e-15)
    assert roi_window(0.5) == (0.25, 0.75, 0.25, 0.75)
    assert roi_window(1) == (0.0, 1.0, 0.0, 1.0)
    assert roi_window((0, "0.5", 0.25, 1)) == (0.0, 0.5, 0.25, 1.0)
    assert all(type(v) is float for v in roi_window((0, 1, 0, 1)))
    assert roi_window([0.1, 0.2, 0.3, 0.4]) == (0.1, 0.2, 0.3, 0.4)

    def refused(roi) -> str:
        with pytest.raises(CamcalError) as info:
            roi_window(roi)
        return str(info.value)

    for f in (0, 0.0, -0.2, 1.0000001, 2):
        assert refused(f) == f"ROI fraction (a central fraction of each side) must be in (0, 1], got {float(f)}"
    for bad in ((0.1, 0.2, 0.3), (0.1, 0.2, 0.3, 0.4, 0.5), ("a", 0.2, 0.3, 0.4), (None, 0.2, 0.3, 0.4), "abcd",
                object()):
        assert refused(bad) == f"ROI must be a fraction or (y0, y1, x0, x1) fractions, got {bad!r}"
    for bad in ((-0.1, 0.5, 0.0, 1.0), (0.5, 0.5, 0.0, 1.0), (0.6, 0.5, 0.0, 1.0), (0.0, 1.01, 0.0, 1.0),
                (0.0, 1.0, -0.01, 0.5), (0.0, 1.0, 0.5, 0.5), (0.0, 1.0, 0.7, 0.5), (0.0, 1.0, 0.0, 1.5)):
        assert refused(bad) == (f"ROI (y0, y1, x0, x1) = {bad!r} must satisfy 0 <= y0 < y1 <= 1 and "
                                "0 <= x0 < x1 <= 1")


def test_mask_raw_clipped_marks_twins_of_clipping_raw_frames():
    """A processed frame becomes saturated in every channel (clipped fraction 1) when a RAW frame at the same
    relative exposure (rtol 1e-6) has more than 1e-3 of its ROI clipped in any plane; other frames are kept."""
    from camcal.calibrate.response import mask_raw_clipped

    pc = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 0.3], [0.0, 0.0, 0.0]])
    proc = _exposure_series_record([1.0, 2.0, 3.0, 4.0, 6.0], np.ones((5, 3)), np.zeros((5, 3)), "abcde", pc,
                                   kind="processed", channels=("R", "G", "B"))
    raw_clip = np.zeros((6, 4))
    raw_clip[1, 3] = 0.0011  # x = 2 (within 1e-6): clips in B -> frame b saturated
    raw_clip[2, 0] = 0.001  # x = 3: exactly 1e-3 is not "more than"
    raw_clip[3, 2] = 0.5  # x = 4 (1 + 5e-6): not the same exposure (5e-6 relative > 1e-6)
    raw_clip[4, 1] = 0.5  # x = 5: no processed twin
    raw_clip[5, 0] = 0.002  # x = 6 (6e-7 relative) -> frame e saturated
    raw_x = [1.0, 2.0 * (1 + 9e-7), 3.0, 4.0 * (1 + 5e-6), 5.0, 6.0 * (1 - 6e-7)]
    raw = _exposure_series_record(raw_x, np.ones((6, 4)), np.zeros((6, 4)), "uvwxyz", raw_clip, channels=PLANES)
    out = mask_raw_clipped(proc, raw)
    expect = pc.copy()
    expect[1] = 1.0
    expect[4] = 1.0
    np.testing.assert_array_equal(out.clipped_fraction, expect)
    np.testing.assert_array_equal(proc.clipped_fraction, pc)  # the input is not changed
    assert out.files == proc.files and out.mean_dn is proc.mean_dn
    raw_clip[1, 3] = raw_clip[5, 0] = 0.0
    assert mask_raw_clipped(proc, replace(raw, clipped_fraction=raw_clip)) is proc  # nothing to mark


def test_pearson_mode_and_pair_planes_small_cases():
    """_pearson is the textbook correlation (NaN for fewer than 2 points or a constant series); _mode the most
    frequent value, the smaller on a tie; _pair_planes subtracts the bias frame, else the black level, in float32,
    leaving the input untouched."""
    from camcal.calibrate.response import _mode, _pair_planes, _pearson

    x = np.array([1.0, 2.0, 3.0, 5.0])
    y = np.array([2.0, 1.0, 4.0, 3.0])
    dx, dy = x - x.mean(), y - y.mean()
    r = float(np.sum(dx * dy) / np.sqrt(np.sum(dx**2) * np.sum(dy**2)))  # 3.5/sqrt(8.75·5) = 0.52915
    assert _pearson(x, y) == pytest.approx(r, rel=1e-12) and abs(r - 0.52915) < 1e-5
    assert _pearson(x, -2 * x) == pytest.approx(-1.0, rel=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a constant series is answered NaN before numpy divides by zero
        for a, b in ((x[:1], y[:1]), (np.full(4, 2.0), y), (x, np.full(4, 7.0)), (x[:0], y[:0])):
            assert np.isnan(_pearson(a, b))
    assert _pearson(x[:2], y[:2]) == pytest.approx(-1.0, rel=1e-12)  # two points: perfectly anti-correlated

    assert _mode([3.0, 1.0, 3.0, 2.0, 2.0]) == 2.0  # 2 and 3 twice each: the smaller
    assert _mode([5.0, 5.0, 1.0, 9.0]) == 5.0
    assert _mode([7]) == 7.0 and type(_mode([7])) is float

    planes = np.array([[[100, 120], [140, 160]], [[10, 20], [30, 40]]], np.uint16)
    before = planes.copy()
    black = np.array([[[64]], [[8]]], np.int32)
    out = _pair_planes(planes, None, black)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, [[[36, 56], [76, 96]], [[2, 12], [22, 32]]])
    bias = np.array([[[99.5, 119.5], [139.5, 170.0]], [[0.0, 0.0], [0.0, 50.0]]], np.float32)
    out = _pair_planes(planes, bias, black)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, [[[0.5, 0.5], [0.5, -10.0]], [[10, 20], [30, -10]]])
    np.testing.assert_array_equal(planes, before)


# -- spectral: the sweep's small pure functions --------------------------------------------------------------------


def test_robust_mask_median_and_normal_scaled_mad_by_hand():
    """_robust_mask keeps valid pixels within nsigma·MAD/Φ⁻¹(0.75) of the median of the valid pixels (a pixel at
    exactly 5σ is kept), sampling every other row and column only above 40 000 pixels; no valid pixel -> none
    kept; a zero MAD keeps every valid pixel."""
    from scipy.stats import norm

    from camcal.calibrate.sweep import _robust_mask

    base = np.array([[-3, -2, -1, 0, 1, 2, 3], [0, 1, -1, 2, -2, 0, 0], [1, 0, 0, -1, 0, 2, -2],
                     [0, 0, 1, -1, 0, 0, 1], [-1, 0, 2, 0, 1, -1, 0], [0, 3, 0, -3, 0, 1, 0],
                     [50.0, -60.0, 70.0, -80.0, 0, 0, 0]])
    valid = np.ones(base.shape, bool)
    valid[0, 0] = valid[3, 3] = False
    sample = base[valid]
    med = float(np.median(sample))
    mad = float(np.median(np.abs(sample - med))) / norm.ppf(0.75)  # the normal-scaled MAD
    assert med == 0.0 and mad > 0
    m = base.copy()
    m[6, 0] = 5.0 * mad  # an outlier moved to exactly 5σ: kept (median and MAD unchanged: still above both)
    m[6, 1] = -5.0 * mad * (1 + 1e-9)  # just beyond -5σ: left out
    m[3, 3] = 0.0  # invalid pixel at the median: stays out
    expect = valid & (np.abs(m - med) <= 5.0 * mad)
    out = _robust_mask(m, valid)
    np.testing.assert_array_equal(out, expect)
    assert out[6, 0] and not out[6, 1] and not out[6, 2] and not out[3, 3] and out.sum() == 47 - 3
    # nsigma: at 1σ the ±2 and ±3 pixels go too (1.4826 < 2)
    np.testing.assert_array_equal(_robust_mask(m, valid, nsigma=1.0), valid & (np.abs(m - med) <= mad))
    # no mask: every pixel is a sample (the corner -3 now counts) and may be kept
    s_all = m.ravel()
    med_all = float(np.median(s_all))
    mad_all = float(np.median(np.abs(s_all - med_all))) / norm.ppf(0.75)
    np.testing.assert_array_equal(_robust_mask(m), np.abs(m - med_all) <= 5.0 * mad_all)
    assert not _robust_mask(m, np.zeros(m.shape, bool)).any()
    flat = np.full((4, 4), 7.0)
    flat[0, 0] = 1000.0  # MAD 0: nothing to judge by, every valid pixel kept
    v = np.ones((4, 4), bool)
    v[1, 1] = False
    kept = _robust_mask(flat, v)
    np.testing.assert_array_equal(kept, v)
    assert kept is not v

    # above 40 000 pixels the statistics come from the (even, even) pixels: here 0 ± 1 there, 100 ± 1 elsewhere
    rng = np.random.default_rng(3)
    big = 100.0 + rng.uniform(-1, 1, (202, 202))
    big[::2, ::2] = rng.uniform(-1, 1, (101, 101))
    got = _robust_mask(big)
    sub = big[::2, ::2].ravel()
    med_s = float(np.median(sub))
    mad_s = float(np.median(np.abs(sub - med_s))) / norm.ppf(0.75)
    np.testing.assert_array_equal(got, np.abs(big - med_s) <= 5.0 * mad_s)
    assert got.sum() == 101 * 101  # only the (even, even) pixels are near that median
    # exactly 40 000 pixels: all of them are the sample, the median is 100-ish, the (even, even) pixels go
    exact = big[:200, :200]
    s40 = exact.ravel()
    med40 = float(np.median(s40))
    mad40 = float(np.median(np.abs(s40 - med40))) / norm.ppf(0.75)
    got40 = _robust_mask(exact)
    np.testing.assert_array_equal(got40, np.abs(exact - med40) <= 5.0 * mad40)
    assert got40.sum() == 40_000 - 100 * 100
    # 40 001 pixels (13 x 3077): sampled again
    odd_shape = 100.0 + rng.uniform(-1, 1, (13, 3077))
    odd_shape[::2, ::2] = rng.uniform(-1, 1, (7, 1539))
    assert _robust_mask(odd_shape).sum() == 7 * 1539
    # a mask that leaves no (even, even) pixel valid leaves no sample: nothing kept
    odd = np.zeros(big.shape, bool)
    odd[1::2, 1::2] = True
    none = _robust_mask(big, odd)
    assert none.dtype == bool and none.shape == big.shape and not none.any()
    # one valid pixel: it is its own median, MAD 0, kept
    one = np.zeros((4, 4), bool)
    one[2, 3] = True
    np.testing.assert_array_equal(_robust_mask(flat, one), one)


def _sweep_frame_record(planes, invalid=None, x=1.0, radiance=2.0, wl=550.0):
    from camcal.calibrate.sweep import SweepRow, _FrameResult

    p = np.asarray(planes, np.float32)
    row = SweepRow(path=Path(f"f{wl:g}.dng"), wavelength_nm=wl, radiance_w_m2_sr=radiance, radiance_unc_w_m2_sr=None,
                   bandwidth_nm=None, overrides={})
    return _FrameResult(row=row, planes=p, invalid=np.zeros(p.shape, bool) if invalid is None else invalid,
                        relative_exposure_s=x, saturated_fraction=0.0, defect_saturated=0)


def test_frame_signal_is_brightest_plane_mean_and_its_standard_error():
    """The signal is the mean of the valid pixels of the plane with the highest such mean; its standard error is
    their sample standard deviation (ddof 1) over √n. Planes with fewer than 2 valid pixels are skipped; none
    left -> (0, 0)."""
    from camcal.calibrate.sweep import frame_signal

    planes = np.array([[[10, 12], [14, 16]], [[20, 30], [25, 1000]], [[500, 0], [0, 0]], [[19, 21], [23, 25]]])
    invalid = np.zeros(planes.shape, bool)
    invalid[1, 1, 1] = True  # the 1000 DN pixel of plane 1 is a defect
    invalid[2] = [[False, True], [True, True]]  # plane 2: one valid pixel only
    s, sem = frame_signal(_sweep_frame_record(planes, invalid))
    v = np.array([20.0, 30.0, 25.0])  # plane 1's valid pixels: mean 25, sd 5
    assert s == 25.0 and sem == pytest.approx(5.0 / np.sqrt(3), rel=1e-12)
    assert sem == pytest.approx(np.sqrt(np.sum((v - 25.0) ** 2) / 2) / np.sqrt(3), rel=1e-12)
    # a later plane with the same mean does not replace the first (its spread differs)
    tie = planes.copy()
    tie[3] = [[22, 28], [25, 25]]  # mean 25, sd sqrt(18/3)
    invalid_tie = invalid.copy()
    s, sem = frame_signal(_sweep_frame_record(tie, invalid_tie))
    assert s == 25.0 and sem == pytest.approx(5.0 / np.sqrt(3), rel=1e-12)
    # two valid pixels are enough: plane 2 with 500 and 0 valid (mean 250, sd 353.55, sem 250)
    invalid2 = invalid.copy()
    invalid2[2, 0, 1] = False
    s, sem = frame_signal(_sweep_frame_record(planes, invalid2))
    assert s == 250.0 and sem == pytest.approx(250.0, rel=1e-6)  # float32 pixels, float64 sums
    # every plane below zero: the least negative one, not 0
    s, sem = frame_signal(_sweep_frame_record(-np.abs(planes[:2]) - 1, np.zeros((2, 2, 2), bool)))
    assert s == -14.0 and sem == pytest.approx(np.std([-11, -13, -15, -17], ddof=1) / 2, rel=1e-12)
    # planes skipped before the brightest usable one: plane 1 wholly invalid, plane 2 with one pixel -> plane 3
    invalid3 = invalid.copy()
    invalid3[1] = True
    s, sem = frame_signal(_sweep_frame_record(planes, invalid3))
    assert s == 22.0 and sem == pytest.approx(np.std([19, 21, 23, 25], ddof=1) / 2, rel=1e-12)
    # the mean is accumulated in float64: (2^24 + 3) / 4 = 4194304.75, which float32 sums round to 4194304
    wide = np.array([[[2.0**24, 1.0], [1.0, 1.0]]], np.float32)
    assert frame_signal(_sweep_frame_record(wide, np.zeros(wide.shape, bool)))[0] == 4194304.75
    assert frame_signal(_sweep_frame_record(planes, np.ones(planes.shape, bool))) == (0.0, 0.0)
    lone = np.ones(planes.shape, bool)
    lone[:, 0, 0] = False  # one valid pixel per plane
    assert frame_signal(_sweep_frame_record(planes, lone)) == (0.0, 0.0)


def test_no_light_compares_signal_per_exposure_and_radiance_with_repeats():
    """A frame is left out when s/(x·L) is below 0.05 of the median of its repeats' s/(x·L) (strictly), with the
    one-line reason giving its signal, the wavelength, the expected signal ref·x·L and the reference reading."""
    from camcal.calibrate.sweep import no_light

    def frame(signal, x, radiance):
        return _sweep_frame_record(np.full((1, 2, 2), signal), x=x, radiance=radiance, wl=612.5)

    # s/(xL): 100/(1·2) = 50, 420/(2·4) = 52.5, 3/(0.5·3) = 2 < 0.05 · median(50, 52.5) = 2.5625
    a, b, c = frame(100.0, 1.0, 2.0), frame(420.0, 2.0, 4.0), frame(3.0, 0.5, 3.0)
    out = no_light([a, b, c])
    assert len(out) == 1 and out[0][0] is c
    expected = 51.25 * 0.5 * 3.0  # the repeats' median rate times this frame's x·L
    assert out[0][1] == (f"no light recorded (shutter closed or trigger missed): 3 DN above dark at 612.5 nm, where "
                         f"its repeats recorded {expected:.3g} DN for the same exposure and the reference detector "
                         "read 3 W m⁻² sr⁻¹")
    assert expected == 76.875
    # exactly 0.05 of the median is kept: 2.5625 · 1.5 = 3.84375 DN
    assert no_light([a, b, frame(3.84375, 0.5, 3.0)]) == []
    assert [r for r, _ in no_light([a, b, frame(3.843, 0.5, 3.0)])] != []
    # the median of the others, not their mean: a rate of 5 is above 0.05 · median(50, 52.5, 1000) = 2.625 but
    # below 0.05 · their mean (18.4)
    big = frame(2000.0, 1.0, 2.0)  # rate 1000
    d = frame(7.5, 0.5, 3.0)  # rate 5: above 0.05 · median(50, 52.5, 1000) = 2.625, below 0.05 · mean = 18.4
    assert [r for r, _ in no_light([a, b, big, d])] == []
    assert no_light([c]) == [] and no_light([]) == []
    # a frame whose repeats saw nothing (median 0) is not judged; the dark repeat is
    e, f = frame(0.0, 1.0, 2.0), frame(40.0, 1.0, 2.0)
    assert [r for r, _ in no_light([e, f])] == [e]
    # repeats at exactly 0 DN judge nothing either, even a frame below zero
    assert no_light([frame(0.0, 1.0, 1.0), frame(0.0, 1.0, 1.0), frame(-5.0, 1.0, 1.0)]) == []
    # the rates are in arbitrary units: below 1 they are judged the same way (0.01 < 0.05 · 0.5)
    low = frame(0.01, 1.0, 1.0)
    assert [r for r, _ in no_light([frame(0.5, 1.0, 1.0), frame(0.5, 1.0, 1.0), low])] == [low]
    # a negative reference (dark-subtracted noise) judges nothing
    assert no_light([frame(-5.0, 1.0, 1.0), frame(-4.0, 1.0, 1.0), frame(-6.0, 1.0, 1.0)]) == []


def test_require_wavelengths_roi_check_and_sweep_mode():
    """require_wavelengths counts the wavelengths with a usable frame against the spline's need and says how many
    sweep.csv listed and which wavelengths were dropped; _check_roi accepts a ROI inside the half-resolution planes
    (integers) and refuses any other; SweepOptions.check accepts the two modes only."""
    from camcal.calibrate.sweep import SweepMeasurement, SweepOptions, _check_roi, require_wavelengths
    from camcal.errors import TooFewFrames

    notes = ("dropped 400 nm: saturated", "3 defects saturate", "dropped 410 nm: no light")
    meas = SweepMeasurement(settings=(object(),) * 3, channels=PLANES, notes=notes, csv_path=Path("/s/sweep.csv"),
                            n_listed=7)
    with pytest.raises(TooFewFrames) as info:
        require_wavelengths(meas)
    assert str(info.value) == ("/s/sweep.csv: the sweep stage needs at least 4 usable wavelengths, 3 remain (7 in "
                               "sweep.csv, 4 without a usable frame; c(λ) is read with a not-a-knot cubic spline, "
                               "which needs 4; dropped 400 nm: saturated; dropped 410 nm: no light)")
    assert (info.value.needed, info.value.remaining, info.value.stage) == (4, 3, "sweep")
    with pytest.raises(TooFewFrames) as info:
        require_wavelengths(meas, needed=5, listed=9)
    assert "needs at least 5 usable wavelengths, 3 remain (9 in sweep.csv, 6 without" in str(info.value)
    assert "which needs 5;" in str(info.value)
    assert require_wavelengths(meas, needed=3) is None  # exactly enough
    four = replace(meas, settings=(object(),) * 4, notes=())
    assert require_wavelengths(four) is None

    where = Path("/s/sweep")
    assert _check_roi((0, 0, 8, 6), (6, 8), where) == (0, 0, 8, 6)  # the whole 8x6 plane
    got = _check_roi((1.0, 2.0, "5", 4), (6, 8), where)
    assert got == (1, 2, 5, 4) and all(type(v) is int for v in got)
    for bad in ((-1, 0, 4, 4), (4, 0, 4, 4), (5, 0, 4, 4), (0, 0, 9, 4), (0, -1, 4, 4), (0, 3, 4, 3), (0, 4, 4, 3),
                (0, 0, 4, 7)):
        with pytest.raises(CamcalError) as info:
            _check_roi(bad, (6, 8), where)
        assert str(info.value) == (f"/s/sweep: ROI {bad} (x0,y0,x1,y1 in half-resolution plane pixels) is outside "
                                   "the 8x6 planes")

    assert SweepOptions(mode="relative").check() is None and SweepOptions().check() is None
    with pytest.raises(CamcalError) as info:
        SweepOptions(mode="Absolute").check()  # type: ignore[arg-type]
    assert str(info.value) == "mode must be 'relative' or 'absolute', got 'Absolute'"


def test_spectral_origin_record_and_its_description():
    """origin() returns the curve's source when it has one, else the sweep's own record (absolute: the reference
    detector set the scale; relative: none); describe_origin turns each kind of record into its two lines, with
    the plural of 'target' only for a count other than one and a 12-character hash prefix."""
    from camcal.models.spectral import describe_origin

    wl = np.array([500.0, 600.0])
    ones = {p: np.ones(2) for p in PLANES}
    absolute = SpectralSensitivity(wl, ones, ones, units="DN", mode="absolute")
    relative = SpectralSensitivity(wl, ones, ones, units="relative", mode="relative")
    assert absolute.origin() == {"kind": "sweep", "file": None, "sha256": None, "absolute_scale": {
        "method": "sweep", "description": "monochromator sweep with a reference detector (camcal sweep)"}}
    assert relative.origin() == {"kind": "sweep", "file": None, "sha256": None, "absolute_scale": {
        "method": "none", "description": "relative: no absolute scale"}}
    src = {"kind": "imported", "file": "c.csv", "sha256": "0123456789abcdef", "format": "csv"}
    assert replace(relative, source=src).origin() is src
    assert replace(absolute, source={}).origin()["absolute_scale"]["method"] == "sweep"  # an empty record: none

    assert describe_origin(absolute.origin()) == ("monochromator sweep (camcal sweep / calibrate)",
                                                  "monochromator sweep with a reference detector (camcal sweep)")
    assert describe_origin(relative.origin()) == ("monochromator sweep (camcal sweep / calibrate)",
                                                  "relative: no absolute scale")
    lib = {"name": "Nikon D700", "file": "nikon.csv", "collection": "CSS", "creator": "Jiang et al.",
           "license": "CC-BY", "matched": "EXIF model"}
    rt = {"method": "reference_targets", "targets": ["grey", "white", "black"], "verdict": "consistent"}
    assert describe_origin({"kind": "library", "library": lib, "absolute_scale": rt}) == (
        "curve library: Nikon D700 (nikon.csv, CSS; measured by Jiang et al., CC-BY), matched from EXIF model",
        "reference targets (3 targets): consistent")
    assert describe_origin({"kind": "library", "absolute_scale": {"method": "reference_targets",
                                                                   "targets": ["grey"]}}) == (
        "curve library: None (None, None; measured by unknown, None), matched from None",
        "reference targets (1 target): ")
    assert describe_origin({"kind": "library", "library": None, "absolute_scale": {
        "method": "reference_targets", "targets": None, "verdict": "none used"}})[1] == (
        "reference targets (0 targets): none used")
    assert describe_origin({"kind": "library", "library": {**lib, "creator": ""}})[0] == (
        "curve library: Nikon D700 (nikon.csv, CSS; measured by unknown, CC-BY), matched from EXIF model")
    assert describe_origin({**src, "absolute_scale": {"method": "none"}}) == (
        "imported from c.csv (csv format, SHA-256 0123456789ab…)", "none")
    assert describe_origin({}) == ("imported from None (None format, SHA-256 None…)", "None")
    assert describe_origin({"kind": "imported", "absolute_scale": None, "sha256": "f" * 64})[0].endswith(
        "SHA-256 ffffffffffff…)")
    assert describe_origin({"absolute_scale": {"method": "m", "description": ""}})[1] == "m"

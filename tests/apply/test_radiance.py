"""Tests of :mod:`camcal.apply.radiance`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

import warnings

import colour
import numpy as np
import pytest
from scipy.special import erf

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
from camcal.errors import CamcalError
from tests.helpers import _gauss


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
def test_radiance_wavelength_outside_the_curve_is_refused():
    wl = np.arange(400.0, 701.0, 5.0)
    c = {k: _gauss(wl, 550, 40) for k in "RGB"}
    with pytest.raises(CamcalError, match="outside the calibrated range"):
        radiance_model(wl, c, None, 705.0)
    with pytest.raises(CamcalError, match="unknown estimator"):
        radiance_model(wl, c, None, 663.0, "band")


def _planck_w_m2_sr_nm(t_k, wl_nm):
    """Planck's law written out with the exact SI constants h, c, k (2019), per nm."""
    h, c, k = 6.62607015e-34, 299792458.0, 1.380649e-23
    lam = np.asarray(wl_nm, float) * 1e-9
    return 2 * h * c**2 / lam**5 / np.expm1(h * c / (lam * k * t_k)) * 1e-9


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
@pytest.mark.parametrize("line_fwhm_nm", [1.0, 9.0])
def test_narrowband_slit_correction_against_gaussian_convolutions(line_fwhm_nm):
    """The narrowband estimator reads c ⊛ line at λ0 from a curve measured through a 5 nm slit (c ⊛ slit).

    With a Gaussian sensitivity c = exp(−(λ−μ)²/2s²) both convolutions are closed forms (variances add):
    (c ⊛ g_σ)(λ) = s/√(s²+σ²) · exp(−(λ−μ)²/2(s²+σ²)). The estimator's second-order correction must give the
    rate of a unit line within 2e-4 (the neglected fourth-order term and the spline's c''; measured 6e-5); the
    correction itself is 0.2-0.5 % at 663 nm on this curve.
    """
    wl = np.arange(400.0, 721.0, 5.0)
    mu, s, slit = 620.0, 30.0, 5.0
    f2s = 1 / (2 * np.sqrt(2 * np.log(2)))

    def conv(lam, fwhm):
        v = s * s + (fwhm * f2s) ** 2
        return 50.0 * s / np.sqrt(v) * np.exp(-((lam - mu) ** 2) / (2 * v))

    c = {"R": conv(wl, slit), "G": 0.1 * conv(wl - 90, slit), "B": 0.05 * conv(wl - 180, slit)}
    model = radiance_model(wl, c, None, 663.0, "narrowband", line_fwhm_nm=line_fwhm_nm, slit_fwhm_nm=slit)
    assert model.channel == "R"
    rate = conv(663.0, line_fwhm_nm)  # DN/s of a line of unit in-band radiance
    assert model.weights[0] * rate == pytest.approx(1.0, abs=2e-4)  # measured 4e-5 (1 nm), 6e-5 (9 nm)
    assert abs(rate / conv(663.0, slit) - 1) > 2e-3  # the correction matters at this precision

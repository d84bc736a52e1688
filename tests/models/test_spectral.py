"""Tests of :mod:`camcal.models.spectral`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from camcal.errors import CamcalError
from camcal.frame import PLANES
from camcal.models.response import (
    ColourMatrix,
)
from camcal.models.spectral import RELATIVE_UNITS, SpectralSensitivity, to_relative
from tests.helpers import _channel, _gauss, _json_round_trip
from tests.oracles import merge_sweeps, to_colour, to_colour_planes


@pytest.mark.formula
def test_merged_sweeps_scale_uncertainty_when_the_second_sweep_lies_below_the_first():
    """a: 550-750 nm, b: 400-600 nm = truth / 2.5 (1 % and 2 % uncertainties). The overlap is 550-600 nm, six
    wavelengths, whichever sweep starts first: u_k = 1/√(Σ w b²) over them (three planes alike), w = 1/(u_a² +
    k² u_b²), and below 550 nm the merged uncertainty is √((k u_b)² + (u_k b)²). One wavelength fewer at either
    end of the overlap changes u_k by ≈ 15 %."""
    wa, wb = np.arange(550.0, 751.0, 10.0), np.arange(400.0, 601.0, 10.0)

    def truth(wl):
        return _gauss(wl, 560.0, 80.0) + 0.1

    a = SpectralSensitivity(wa, {p: truth(wa) for p in "RGB"}, {p: 0.01 * truth(wa) for p in "RGB"},
                            "relative", "relative")
    b = SpectralSensitivity(wb, {p: truth(wb) / 2.5 for p in "RGB"}, {p: 0.02 * truth(wb) / 2.5 for p in "RGB"},
                            "relative", "relative")
    m = merge_sweeps(a, b)
    ov = np.arange(550.0, 601.0, 10.0)
    w = 1 / ((0.01 * truth(ov)) ** 2 + (0.02 * truth(ov)) ** 2)
    u_k = 1 / np.sqrt(3 * np.sum(w * (truth(ov) / 2.5) ** 2))
    only_b = m.wavelength_nm < 550
    t = truth(m.wavelength_nm[only_b])
    np.testing.assert_allclose(m.uncertainty["R"][only_b], np.hypot(0.02 * t, u_k * t / 2.5), rtol=1e-9)
    np.testing.assert_allclose(m.values["R"], truth(m.wavelength_nm), rtol=1e-12)
    assert "2.5" in m.notes[-1] and f"{u_k:.2g}" in m.notes[-1]


def _bayer_curves():
    wl = np.arange(400.0, 701.0, 5.0)
    vals = {"R": _gauss(wl, 600, 30, 2.0), "G1": _gauss(wl, 530, 35, 3.0), "G2": _gauss(wl, 530, 35, 3.4),
            "B": _gauss(wl, 490, 20, 1.5)}
    unc = {p: 0.01 * v + 1e-3 for p, v in vals.items()}
    return SpectralSensitivity(wl, vals, unc, "DN/s per W/(m2 sr nm)", "absolute", 100.0, 4.0, bandwidth_nm=10.0)


@pytest.mark.formula
def test_colour_views_are_the_mean_green_and_the_four_planes():
    s = _bayer_curves()
    cs = to_colour(s)
    np.testing.assert_array_equal(cs.wavelengths, s.wavelength_nm)
    np.testing.assert_allclose(cs.values[:, 1], 0.5 * (s.values["G1"] + s.values["G2"]), rtol=1e-12)
    np.testing.assert_allclose(cs.values[:, 0], s.values["R"], rtol=1e-12)
    np.testing.assert_allclose(cs.values[:, 2], s.values["B"], rtol=1e-12)
    assert cs.name == "camcal c(λ) [DN/s per W/(m2 sr nm)]"
    planes = to_colour_planes(s)
    assert list(planes.labels) == ["R", "G1", "G2", "B"] and planes.name == "camcal c(λ) planes [DN/s per W/(m2 sr nm)]"
    np.testing.assert_allclose(planes.values[:, 2], s.values["G2"], rtol=1e-12)
    np.testing.assert_array_equal(planes.wavelengths, s.wavelength_nm)


@pytest.mark.formula
def test_sensitivity_summary_figures_against_closed_forms():
    """Peak 3.4 (G2) at 530 nm; λ_eff of a Gaussian is its centre and its equivalent width s√(2π) (trapezoid on
    5 nm, curves negligible at the ends); the relative uncertainty at the peak 0.01 + 1e-3/peak; the slit bias
    (σ²/2) c'' with σ = 10 nm FWHM → 4.25 nm and c'' of a Gaussian written out, RMS over the grid / 3.4."""
    s = _bayer_curves()
    sm = s.summary()
    assert sm["peak_value"] == pytest.approx(3.4) and sm["n_wavelengths"] == 61
    assert sm["wavelength_range_nm"] == [400.0, 700.0] and sm["mode"] == "absolute" and sm["bandwidth_nm"] == 10.0
    assert sm["peak_wavelength_nm"] == {"R": 600.0, "G1": 530.0, "G2": 530.0, "B": 490.0, "G": 530.0}
    for k, (mu, sd) in {"R": (600, 30), "G": (530, 35), "B": (490, 20)}.items():
        assert sm["effective_wavelength_nm"][k] == pytest.approx(mu, abs=0.05)
        assert sm["effective_bandwidth_nm"][k] == pytest.approx(sd * np.sqrt(2 * np.pi), rel=2e-3)
    for p, peak in {"R": 2.0, "G1": 3.0, "G2": 3.4, "B": 1.5}.items():
        assert sm["max_relative_uncertainty_at_peak"][p] == pytest.approx(0.01 + 1e-3 / peak, rel=1e-9)
    sigma = 10.0 / (2 * np.sqrt(2 * np.log(2)))
    wl = s.wavelength_nm
    c2 = _gauss(wl, 600, 30, 2.0) * (((wl - 600) / 30**2) ** 2 - 1 / 30**2)
    rms = np.sqrt(np.mean((0.5 * sigma**2 * c2) ** 2)) / 3.4
    assert sm["slit_bias_rms_of_peak"]["R"] == pytest.approx(rms, rel=2e-2)
    assert sm["notes"] == [] and sm["deconvolved"] is False and sm["reference_iso"] == 100.0
    assert sm["reference_f_number"] == 4.0 and sm["units"] == "DN/s per W/(m2 sr nm)"


@pytest.mark.formula
def test_rgb_curves_views_and_figures_of_a_dim_and_an_empty_channel():
    """Linear-RAW curves (R, G, B): rgb() is the planes themselves; a channel that is zero everywhere has no
    effective wavelength or bandwidth (NaN), and a dim one (area 0.05 nm) has them all the same (centroid 550
    nm, equivalent width s√(2π) on a 2 nm grid)."""
    wl = np.arange(450.0, 651.0, 2.0)
    dim = _gauss(wl, 550.0, 10.0, 0.002)
    s = SpectralSensitivity(wl, {"R": np.zeros(wl.size), "G": dim, "B": -0.1 * np.ones(wl.size)},
                            {p: np.full(wl.size, 1e-4) for p in "RGB"}, "relative", "relative")
    rgb = s.rgb()
    assert list(rgb) == ["R", "G", "B"] and rgb["G"] is s.values["G"] and rgb["R"] is s.values["R"]
    assert rgb["B"] is s.values["B"]
    assert list(s.channels()) == ["R", "G", "B"]
    lam, width = s.effective_wavelength_nm(), s.effective_bandwidth_nm()
    assert np.isnan(lam["R"]) and np.isnan(width["R"]) and np.isnan(lam["B"]) and np.isnan(width["B"])
    assert lam["G"] == pytest.approx(550.0, abs=1e-9)
    assert width["G"] == pytest.approx(10.0 * np.sqrt(2 * np.pi), rel=1e-6)
    assert s.peak_wavelength_nm()["G"] == 550.0
    # relative uncertainty at the peak of a curve whose peak is below 1: 1e-4 / 0.002
    assert s.summary()["max_relative_uncertainty_at_peak"]["G"] == pytest.approx(0.05, rel=1e-9)


@pytest.mark.formula
def test_to_relative_divides_by_the_largest_value_over_all_planes():
    s = _bayer_curves()
    r = to_relative(s)
    for p in s.plane_names:
        np.testing.assert_allclose(r.values[p], s.values[p] / 3.4, rtol=1e-12)
        np.testing.assert_allclose(r.uncertainty[p], s.uncertainty[p] / 3.4, rtol=1e-12)
    assert r.mode == "relative" and r.units == RELATIVE_UNITS and r.reference_iso == 100.0
    zero = SpectralSensitivity(s.wavelength_nm, {p: 0 * v for p, v in s.values.items()}, s.uncertainty,
                               "relative", "relative")
    with pytest.raises(CamcalError, match="no positive value; cannot normalise"):
        to_relative(zero)
    small = SpectralSensitivity(s.wavelength_nm, {p: 0.5 * v / 3.4 for p, v in s.values.items()}, s.uncertainty,
                                "relative", "relative")
    assert max(float(v.max()) for v in to_relative(small).values.values()) == pytest.approx(1.0)


@pytest.mark.formula
def test_slit_bias_needs_a_bandwidth_four_samples_and_a_curve_not_deconvolved():
    """Four samples are enough for the not-a-knot spline (a cubic is reproduced exactly: c'' = 6 a λ + 2 b);
    three, no bandwidth, or a deconvolved curve give zeros shaped like the grid."""
    wl = np.array([500.0, 510.0, 520.0, 530.0])
    x = wl - 515.0
    cubic = 1e-4 * x**3 + 0.01 * x**2 + 2.0
    s = SpectralSensitivity(wl, {p: cubic for p in "RGB"}, {p: 0.01 * cubic for p in "RGB"}, "relative",
                            "relative", bandwidth_nm=5.0)
    sigma2 = (5.0 / (2 * np.sqrt(2 * np.log(2)))) ** 2
    np.testing.assert_allclose(s.slit_bias()["G"], 0.5 * sigma2 * (6e-4 * x + 0.02), rtol=1e-9)
    for other in (replace(s, bandwidth_nm=None), replace(s, deconvolved=True),
                  SpectralSensitivity(wl[:3], {p: cubic[:3] for p in "RGB"}, {p: cubic[:3] for p in "RGB"},
                                      "relative", "relative", bandwidth_nm=5.0)):
        bias = other.slit_bias()
        assert list(bias) == ["R", "G", "B"]
        assert all(b.shape == other.wavelength_nm.shape and not b.any() for b in bias.values())


@pytest.mark.formula
@pytest.mark.parametrize("wl", [np.array([[500.0, 510.0]]), np.array([]), np.array([500.0, 510.0, 505.0]),
                                np.array([500.0, 510.0, 510.0])], ids=["2-D", "empty", "decreasing", "repeated"])
def test_spectral_sensitivity_refuses_wavelengths_that_do_not_increase(wl):
    vals = {p: np.ones(wl.shape) for p in "RGB"}
    with pytest.raises(CamcalError, match="wavelengths must be a non-empty increasing 1-D array"):
        SpectralSensitivity(wl, vals, vals, "relative", "relative")


@pytest.mark.formula
def test_spectral_sensitivity_checks_its_planes_and_accepts_one_wavelength():
    one = SpectralSensitivity(np.array([550.0]), {p: np.ones(1) for p in "RGB"}, {p: np.ones(1) for p in "RGB"},
                              "relative", "relative")
    assert one.plane_names == ("R", "G", "B")
    wl = np.array([500.0, 510.0])
    with pytest.raises(CamcalError, match="of 2 values each"):
        SpectralSensitivity(wl, {p: np.ones(3) for p in "RGB"}, {p: np.ones(2) for p in "RGB"}, "relative",
                            "relative")
    with pytest.raises(CamcalError, match="of 2 values each"):
        SpectralSensitivity(wl, {p: np.ones(2) for p in "RG"}, {p: np.ones(2) for p in "RG"}, "relative",
                            "relative")
    with pytest.raises(CamcalError, match="name different planes"):
        SpectralSensitivity(wl, {p: np.ones(2) for p in "RGB"}, {p: np.ones(2) for p in ("R", "G1", "G2", "B")},
                            "relative", "relative")


@pytest.mark.formula
def test_relative_uncertainty_at_the_peak_for_peaks_below_one():
    """The summary's relative uncertainty at each plane's peak is u(λ_peak)/c(λ_peak), also for relative curves
    whose peaks are below 1 (0.125, 0.25, 0.375 here)."""
    wl = np.array([500.0, 510.0, 520.0, 530.0])
    vals = {p: np.array([0.1, 0.5, 0.3, 0.2]) * (i + 1) / 4 for i, p in enumerate("RGB")}
    unc = {p: np.array([0.01, 0.05, 0.02, 0.02]) for p in "RGB"}
    got = SpectralSensitivity(wl, vals, unc, "relative", "relative").summary()["max_relative_uncertainty_at_peak"]
    assert got == pytest.approx({"R": 0.05 / 0.125, "G": 0.05 / 0.25, "B": 0.05 / 0.375}, rel=1e-12)


@pytest.mark.formula
def test_spectral_record_round_trip_keeps_every_field():
    """spectral_to_dict -> JSON text -> spectral_from_dict gives back every field of a Bayer and of a linear-RAW
    curve set, as float arrays; fields left out of a record take their documented defaults."""
    from camcal.models.spectral import spectral_from_dict, spectral_to_dict

    wl = np.array([450.0, 500.5, 550.0, 600.0, 650.0])
    bayer = {"R": [0.1, 0.2, 0.4, 1.5, 0.9], "G1": [0.3, 1.2, 1.4, 0.5, 0.1], "G2": [0.31, 1.1, 1.3, 0.6, 0.2],
             "B": [1.0, 0.8, 0.2, 0.05, 0.01]}
    s = SpectralSensitivity(wl, {p: np.array(v) for p, v in bayer.items()},
                            {p: 0.01 + 0.02 * np.array(v) for p, v in bayer.items()}, "DN s⁻¹ per W", "absolute",
                            reference_iso=200.0, reference_f_number=5.6, bandwidth_nm=4.5, deconvolved=True,
                            n_frames={"450": 3, "500.5": 2}, notes=("skipped one frame", "hot lamp"),
                            source={"kind": "imported", "file": "c.csv", "sha256": "ab"})
    back = spectral_from_dict(_json_round_trip(spectral_to_dict(s)))
    np.testing.assert_array_equal(back.wavelength_nm, wl)
    assert back.wavelength_nm.dtype == np.float64
    assert list(back.values) == ["R", "G1", "G2", "B"] and list(back.uncertainty) == ["R", "G1", "G2", "B"]
    for p, v in bayer.items():
        np.testing.assert_array_equal(back.values[p], v)
        np.testing.assert_array_equal(back.uncertainty[p], 0.01 + 0.02 * np.array(v))
        assert back.values[p].dtype == np.float64 and back.uncertainty[p].dtype == np.float64
    assert (back.units, back.mode, back.reference_iso, back.reference_f_number, back.bandwidth_nm) == (
        "DN s⁻¹ per W", "absolute", 200.0, 5.6, 4.5)
    assert back.deconvolved is True and back.n_frames == {"450": 3, "500.5": 2}
    assert back.notes == ("skipped one frame", "hot lamp")
    assert back.source == {"kind": "imported", "file": "c.csv", "sha256": "ab"}

    rgb = {"R": [0.5, 1.0], "G": [1.0, 0.5], "B": [0.25, 0.0]}
    d = {"wavelength_nm": ["500", 600], "values": rgb, "uncertainty": {p: [0.0, 0.125] for p in rgb},
         "units": "relative", "mode": "whatever", "reference_iso": "400", "reference_f_number": None,
         "n_frames": None, "notes": None, "source": "not a dict", "deconvolved": 1}
    lin = spectral_from_dict(d)
    np.testing.assert_array_equal(lin.wavelength_nm, [500.0, 600.0])
    assert list(lin.values) == ["R", "G", "B"] and list(lin.uncertainty) == ["R", "G", "B"]
    for p, v in rgb.items():
        np.testing.assert_array_equal(lin.values[p], v)
        np.testing.assert_array_equal(lin.uncertainty[p], [0.0, 0.125])
    assert (lin.mode, lin.reference_iso, lin.reference_f_number, lin.bandwidth_nm) == ("relative", 400.0, None, None)
    assert lin.deconvolved is True and lin.n_frames == {} and lin.notes == () and lin.source is None
    assert "source" not in spectral_to_dict(lin)  # a measured sweep has no source: its record has no such key
    minimal = spectral_from_dict({k: d[k] for k in ("wavelength_nm", "values", "uncertainty", "units", "mode")})
    assert (minimal.reference_iso, minimal.reference_f_number, minimal.bandwidth_nm) == (None, None, None)
    assert minimal.deconvolved is False and minimal.n_frames == {} and minimal.notes == () and minimal.source is None
    assert spectral_from_dict({**d, "bandwidth_nm": "2.5", "notes": [1, "b"]}).bandwidth_nm == 2.5
    assert spectral_from_dict({**d, "notes": [1, "b"]}).notes == ("1", "b")


@pytest.mark.formula
@pytest.mark.parametrize(("drop", "change", "says"), [
    ("units", {}, "(KeyError: 'units')"),
    ("mode", {}, "(KeyError: 'mode')"),
    ("wavelength_nm", {}, "(KeyError: 'wavelength_nm')"),
    ("uncertainty", {}, "(KeyError: 'uncertainty')"),
    (None, {"values": {"R": [1, 2], "G": [1, 2]}}, "(KeyError: 'B')"),
    (None, {"reference_iso": "ISO 100"}, "(ValueError: could not convert string to float: 'ISO 100')"),
    (None, {"bandwidth_nm": [1, 2]}, "(TypeError: "),
    (None, {"n_frames": 3}, "(TypeError: "),
])
def test_spectral_record_refusals_say_what_is_wrong(drop, change, says):
    """A record with a missing key or a value of the wrong type is one CamcalError naming the exception."""
    from camcal.models.spectral import spectral_from_dict

    d = {"wavelength_nm": [500, 600], "values": {p: [1, 2] for p in "RGB"},
         "uncertainty": {p: [0, 0] for p in "RGB"}, "units": "relative", "mode": "relative", **change}
    d.pop(drop, None)
    with pytest.raises(CamcalError) as e:
        spectral_from_dict(d)
    assert str(e.value).startswith("malformed spectral sensitivity (") and says in str(e.value)


def _sensitivity(wl, values, **kw):
    return SpectralSensitivity(wavelength_nm=wl, values=values, uncertainty={k: np.zeros_like(v) for k, v in
                                                                             values.items()},
                               units="relative", mode="relative", **kw)


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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

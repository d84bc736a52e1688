"""Tests of :mod:`camcal.models.response`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq

from camcal.calibrate.response import fit_srgb_form
from camcal.errors import CamcalError
from camcal.models.response import (
    ResponseModel,
    srgb_form_decode,
    srgb_form_encode,
    srgb_form_toe,
)
from tests.helpers import _channel


@pytest.mark.formula
def test_srgb_form_fit_exponent_stays_below_one_for_a_response_steeper_than_linear():
    """A response that follows the sRGB form with p = 1.2 above its knee (a curve bending up, which the form's
    documented range 0.05 ≤ p ≤ 0.99 excludes): the fit must stay in range (p ≤ 0.99 and a poor χ²), not follow
    the data to p = 1.2 (χ² ≈ 0), whatever its start."""
    from camcal.models.response import SRGB_OFFSET_A

    x = np.linspace(0.3, 1.0, 8) * 0.03
    g = 255.0 * ((1 + SRGB_OFFSET_A) * (x / 0.03) ** 1.2 - SRGB_OFFSET_A)
    for p0 in (0.5, 0.9):
        fit = fit_srgb_form(x, g, np.full(8, 0.3), 255.0, p0=p0, x_white0=0.03)
        assert 0.05 <= fit["exponent"] <= 0.99 and fit["chi2_red"] > 100.0


def _srgb_encode_numeric(lin, p, a=0.055):
    """The sRGB form with exponent p from its definition: V = (1 + a) L^p − a above the toe, V = s L below, the
    toe found numerically (brentq) where the line through the origin touches the curve."""
    def tangent_gap(lb):
        return (1 + a) * lb**p - a - lb * (1 + a) * p * lb ** (p - 1)

    lb = brentq(tangent_gap, 1e-9, 0.5)
    s = (1 + a) * p * lb ** (p - 1)
    lin = np.asarray(lin, float)
    return np.where(lin <= lb, s * lin, (1 + a) * np.maximum(lin, lb) ** p - a)


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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

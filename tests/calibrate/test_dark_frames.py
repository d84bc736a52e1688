"""Tests of :mod:`camcal.calibrate.dark_frames`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from camcal.calibrate.dark import fit_dark
from camcal.calibrate.dark_frames import DarkOptions, DarkStacks
from camcal.errors import CamcalError
from camcal.frame import PLANES, Exposure
from camcal.models.dark import NOISY
from tests.helpers import NOISE_METHOD, _map_of_variance, _noisy_bound, _read_noise_stack


@pytest.mark.formula
def test_exposure_time_rules_leave_out_lone_frames_and_need_two_times_without_bias():
    """A frame alone at its exposure time is left out (warned, named with its reason) while another time has two
    frames; all times lone keeps them all; without bias frames one exposure time (or none) is too few, with the
    counts and the time in the message."""
    import warnings as _warnings
    from pathlib import Path

    from camcal.calibrate.dark_frames import _exposure_time_rules
    from camcal.errors import FrameLeftOut, TooFewFrames

    a, b, c, d = (Path(f"/d/{n}.dng") for n in "abcd")
    why = "the dark model measures the temporal noise of each exposure time from two or more frames"
    with pytest.warns(FrameLeftOut) as rec:
        groups, left = _exposure_time_rules({0.5: [a, b], 2.0: [c], 0.25: [d]}, True, Path("/d"))
    assert groups == {0.5: [a, b]}
    assert left == (("c.dng", f"alone at its exposure time (2 s): {why}"),
                    ("d.dng", f"alone at its exposure time (0.25 s): {why}"))
    assert [str(w.message) for w in rec] == [f"left out: {n}: {r}" for n, r in left]
    with _warnings.catch_warnings():
        _warnings.simplefilter("error")
        assert _exposure_time_rules({1.0: [a], 2.0: [b]}, False, Path("/d")) == ({1.0: [a], 2.0: [b]}, ())
        assert _exposure_time_rules({1.0: [a, b]}, True, Path("/d")) == ({1.0: [a, b]}, ())
        assert _exposure_time_rules({1.0: [a, b], 3.0: [c, d]}, False, Path("/d")) == (
            {1.0: [a, b], 3.0: [c, d]}, ())
        assert _exposure_time_rules({}, True, Path("/d")) == ({}, ())
        with pytest.raises(TooFewFrames) as e:
            _exposure_time_rules({1.5: [a, b, c]}, False, Path("/d"))
        assert str(e.value) == ("/d: the dark stage needs at least 2 usable exposure times (or bias frames), 1 "
                                "remain (all 3 dark frames have one exposure time (1.5 s); the dark-current fit "
                                "needs two or more exposure times, or bias frames (--bias))")
        assert e.value.path == Path("/d") and (e.value.needed, e.value.remaining) == (2, 1)
        with pytest.raises(TooFewFrames) as e:
            _exposure_time_rules({1.0: [a]}, False, Path("/d"))
        assert "all 1 dark frames have one exposure time (1 s)" in str(e.value)
        with pytest.raises(TooFewFrames) as e:
            _exposure_time_rules({}, False, Path("/d"))
        assert str(e.value) == "/d: the dark stage needs at least 1 usable frames, 0 remain"
        assert e.value.path == Path("/d")
    with pytest.warns(FrameLeftOut), pytest.raises(TooFewFrames) as e:
        _exposure_time_rules({1.0: [a, b], 2.0: [c]}, False, Path("/d"))
    assert "all 2 dark frames have one exposure time (1 s)" in str(e.value)


@pytest.mark.formula
def test_dark_frame_check_refuses_processed_and_saturated_frames():
    """RAW frames only; more than the given fraction of pixels at or above the white level (counted here) is a
    saturated dark frame, the fraction and level in its message."""
    from pathlib import Path

    from camcal.calibrate.dark_frames import dark_frame_check
    from camcal.frame import Frame

    data = np.full((10, 10), 100, np.uint16)
    data.flat[:2] = 4095  # 2 % at the white level
    data.flat[2] = 5000  # above it
    raw = Frame(data=data, kind="raw", cfa_pattern="RGGB", black_level_dn={}, white_level_dn=4095.0,
                path=Path("/d/a.dng"))
    dark_frame_check(0.03)(raw)  # 3 % at or above the white level: not more than 3 %
    with pytest.raises(CamcalError) as e:
        dark_frame_check(0.029)(raw)
    assert str(e.value) == ("/d/a.dng: dark frame is saturated: 3.0 % of pixels at the white level 4095 DN "
                            "(light leak, or not a dark frame?)")
    big = np.zeros((100, 100), np.uint16)
    big.flat[:996] = 4095  # 9.96 %, printed 10.0 %
    with pytest.raises(CamcalError) as e:
        dark_frame_check(0.05)(replace(raw, data=big))
    assert "saturated: 10.0 % of pixels" in str(e.value)
    data.flat[:3] = 100
    dark_frame_check()(raw)  # none saturated
    data.flat[:2] = 4095
    with pytest.raises(CamcalError) as e:
        dark_frame_check()(raw)  # 2 % > the default 1 %
    assert "2.0 % of pixels at the white level 4095 DN" in str(e.value)
    with pytest.raises(CamcalError) as e:
        dark_frame_check()(Frame(data=np.zeros((2, 2, 3), np.uint8), kind="processed", cfa_pattern=None,
                                 black_level_dn={}, white_level_dn=255.0, path=Path("/d/a.dng")))
    assert str(e.value) == "/d/a.dng: bias and dark frames must be RAW files (the dark model works on CFA planes)"


@pytest.mark.formula
def test_dark_stacks_must_share_frame_size_pattern_and_iso():
    """Stacks of one frame size, CFA pattern and ISO give that ISO; another size or pattern is refused naming the
    odd stack's first file and both sizes; mixed ISO settings are refused naming the folder."""
    from pathlib import Path
    from types import SimpleNamespace

    from camcal.calibrate.dark_frames import _check_stacks

    def stack(name, shape=(4, 6), cfa="RGGB", iso=400.0):
        return SimpleNamespace(frame_shape=shape, cfa_pattern=cfa, paths=(Path(f"/d/{name}1.dng"),
                                                                          Path(f"/d/{name}2.dng")),
                               exposures=(Exposure(iso=iso), Exposure(iso=iso)))

    assert _check_stacks([stack("a"), stack("b")], Path("/d")) == 400.0
    for odd, says in ((stack("b", shape=(4, 8)), "frame size 8x4 (RGGB) differs from the first dark frame's 6x4 "
                                                  "(RGGB)"),
                      (stack("b", cfa="BGGR"), "frame size 6x4 (BGGR) differs from the first dark frame's 6x4 "
                                               "(RGGB)")):
        with pytest.raises(CamcalError) as e:
            _check_stacks([stack("a"), odd, stack("c")], Path("/d"))
        assert str(e.value) == f"{Path('/d/b1.dng')}: {says}"
    with pytest.raises(CamcalError) as e:
        _check_stacks([stack("a"), stack("b", iso=800.0)], Path("/d"))
    assert str(e.value) == (f"{Path('/d')}: frames mix ISO settings [400.0, 800.0]; take bias and dark frames at "
                            "one ISO")


@pytest.mark.formula
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

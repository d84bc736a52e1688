"""Dark model against the synthetic camera's truth (real DNG sessions, BGGR and RGGB, 14-bit, black level > 0)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import camcal.calibrate.dark
from camcal.calibrate.dark import _fit_lines, _robust, fit_dark
from camcal.calibrate.dark_frames import measure_dark
from camcal.calibrate.dark_noise import _max_median_mean
from camcal.calibrate.stack import StackOptions, combine_frames
from camcal.errors import CamcalError
from camcal.models.correct import dark_frame
from camcal.models.dark import HOT, DarkModel, load_dark, save_dark
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.dng import write_dng
from camcal.synth.session import SessionPlan, write_session
from tests.conftest import assert_one_line_error, run_cli
from tests.helpers import NORMAL_PER_MAD
from tests.oracles import (
    subtract_dark,
)

PATTERNS = {"BGGR": dict(seed=21, black_level_dn=(1024.0, 1024.0, 1024.0, 1024.0)),
            "RGGB": dict(seed=22, black_level_dn=(512.0, 510.0, 514.0, 512.0))}


@pytest.fixture(scope="module", params=sorted(PATTERNS))
def session(request, tmp_path_factory):
    """A bias + dark session (384x256, 16 bias, darks at 2/8/16/32 s x 4) and its truth and fitted models."""
    pattern = request.param
    cam = SyntheticCamera(SensorParams(cfa_pattern=pattern, **PATTERNS[pattern]))
    root = write_session(tmp_path_factory.mktemp(pattern) / "S", cam, SessionPlan(stages=("bias", "dark")))
    truth = json.loads((root / "truth.json").read_text())
    with_bias = fit_dark(measure_dark(root / "dark", root / "bias", jobs=2))
    without = fit_dark(measure_dark(root / "dark"))
    return root, truth, with_bias, without


def _hot_truth(truth, shape):
    hot = np.zeros(shape, bool)
    for c, y, x in truth["hot_pixels"]:
        hot[c, y, x] = True
    return hot


@pytest.mark.parametrize("variant", ["with_bias", "without_bias"])
def test_recovers_truth(session, variant):
    root, truth, with_bias, without = session
    model = with_bias if variant == "with_bias" else without
    assert model.cfa_pattern == truth["params"]["cfa_pattern"] and model.iso == 100.0
    assert model.temperature_c == pytest.approx(24.0)
    s = model.summary()
    for p in ("R", "G1", "G2", "B"):
        # β: the median of ~24 600 pixels of a log-normal map (sigma 0.25) plus per-pixel fit noise
        # (~0.06 DN/s) has a standard error of ~0.2 %; the target is 2 %.
        assert s["dark_current_dn_per_s"][p] == pytest.approx(truth["dark_current_dn_per_s"][p], rel=0.02)
        # read noise: with bias frames the mean of 24 600 per-pixel variances (15 dof) has a 0.25 %
        # standard error; without, the t = 0 extrapolation of 4 groups of 4 frames ~0.8 %. Target 3 %.
        assert s["read_noise_dn"][p] == pytest.approx(truth["read_noise_dn"][p], rel=0.03)
        # bias: median of the bias map (pattern RMS 0.5 DN); extrapolated without bias frames
        tol = 0.05 if variant == "with_bias" else 0.1
        assert s["bias_dn"][p] == pytest.approx(truth["bias_dn"][p], abs=tol)
    hot = _hot_truth(truth, model.defects.shape)
    found = (model.defects & HOT) > 0
    assert hot.sum() >= 15  # enough injected hot pixels for the 95 % criterion to mean something
    assert (found & hot).sum() >= 0.95 * hot.sum()
    assert (found & ~hot).sum() <= 1e-3 * hot.size
    assert np.all(model.dark_current_dn_per_s[hot] > 20 * np.median(model.dark_current_dn_per_s))


def test_maps_and_dsnu(session):
    root, truth, model, _ = session
    # DSNU of the bias is the pattern RMS (0.5 DN) once the temporal noise of the mean is removed
    for p in ("R", "G1", "G2", "B"):
        assert model.channels[p]["dsnu_bias_dn"] == pytest.approx(0.5, rel=0.1)
        # log-normal sigma 0.25 around 1.25 DN/s: spatial std = 1.25 * sqrt((e^s² - 1) e^s²) ≈ 0.33 DN/s
        assert model.channels[p]["dsnu_dark_current_dn_per_s"] == pytest.approx(0.33, rel=0.1)
    good = model.defects == 0
    assert np.median(model.read_noise_dn[good]) == pytest.approx(1.875, rel=0.05)
    # per-pixel uncertainty of β matches the scatter of β about the truth map
    cam = SyntheticCamera(SensorParams(**truth["params"] | {"black_level_dn": tuple(truth["params"]["black_level_dn"]),
                                                            "dark_current_e_per_s": (2.0,) * 4}))
    true_beta = cam.dark_current_map_e_per_s * cam.dn_per_electron(100.0)
    z = (model.dark_current_dn_per_s - true_beta)[good] / model.dark_current_unc_dn_per_s[good]
    assert 0.85 < np.std(z) < 1.15


def test_subtract_save_load(session, tmp_path):
    root, truth, model, _ = session
    out = save_dark(model, tmp_path / "dark.json")
    assert (tmp_path / "dark.maps.exr").is_file()
    back = load_dark(out)
    np.testing.assert_array_equal(back.defects, model.defects)
    np.testing.assert_allclose(back.dark_current_dn_per_s, model.dark_current_dn_per_s)
    assert back.summary()["hot_pixel_count"] == model.summary()["hot_pixel_count"]
    assert back.temperature_c == model.temperature_c and back.cfa_pattern == model.cfa_pattern
    files = sorted((root / "dark").glob("dark_016.000s_*.dng"))
    st = combine_frames(files, StackOptions(method="mean"))
    resid = subtract_dark(st.value, back, 16.0)
    good = back.defects == 0
    for k in range(4):
        assert abs(np.median(resid[k][good[k]])) < 0.15  # 4-frame mean: per-pixel noise ~2.7 DN, median of 24 k
    # β scales with ISO (gain), the bias does not
    d200 = back.dark_frame_dn(10.0, iso=200.0) - back.bias_dn
    np.testing.assert_allclose(d200, 2 * (back.dark_frame_dn(10.0) - back.bias_dn), rtol=1e-5, atol=1e-4)
    with pytest.raises(CamcalError, match="do not match"):
        subtract_dark(st.value[:, :10], back, 16.0)


def _copy(src, dst, keep):
    dst.mkdir(parents=True)
    lines = (src / "frames.csv").read_text().splitlines()
    rows = [lines[0]] + [ln for ln in lines[1:] if keep(ln.split(",")[0])]
    for ln in rows[1:]:
        shutil.copy(src / ln.split(",")[0], dst)
    (dst / "frames.csv").write_text("\n".join(rows) + "\n")
    return dst


def test_errors(session, tmp_path):
    root = session[0]
    one = _copy(root / "dark", tmp_path / "one", lambda n: n.startswith("dark_008"))
    with pytest.raises(CamcalError, match="one exposure time"):
        fit_dark(measure_dark(one))
    # with bias frames a single dark exposure time is enough
    m = fit_dark(measure_dark(one, root / "bias"))
    assert m.exposure_times_s == (8.0,)
    sat = _copy(root / "dark", tmp_path / "sat", lambda n: n.startswith(("dark_002", "dark_008")))
    mosaic = np.full((256, 384), 16383, np.uint16)
    write_dng(sat / "dark_002.000s_01.dng", mosaic, cfa_pattern=session[1]["params"]["cfa_pattern"],
              black_level_dn=512.0, white_level_dn=16383, exposure_s=2.0, f_number=4.0, iso=100.0)
    with pytest.raises(CamcalError, match=r"dark_002.000s_01.dng: .*saturated"):
        fit_dark(measure_dark(sat))
    size = _copy(root / "dark", tmp_path / "size", lambda n: n.startswith(("dark_002", "dark_008")))
    SyntheticCamera(SensorParams(width=192, height=128)).write_dng(
        size / "dark_008.000s_03.dng", Scene.dark(), exposure_s=8.0, rng=np.random.default_rng(0))
    with pytest.raises(CamcalError, match="frame size 192x128 differs"):
        fit_dark(measure_dark(size, jobs=2))
    proc = run_cli("dark", one, "-o", tmp_path / "x.json")
    assert_one_line_error(proc, "one exposure time", "--bias")
    assert not (tmp_path / "x.json").exists()


def test_cli(session, tmp_path):
    root, truth, _, _ = session
    proc = run_cli("dark", root / "dark", "--bias", root / "bias", "-o", tmp_path / "d.json", "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["dark_current_dn_per_s"]["G1"] == pytest.approx(truth["dark_current_dn_per_s"]["G1"], rel=0.02)
    assert load_dark(tmp_path / "d.json").iso == 100.0
    proc = run_cli("dark", root / "dark", "-o", tmp_path / "t.json")
    assert proc.returncode == 0, proc.stderr
    assert "read noise" in proc.stdout and "G2" in proc.stdout


def test_dark_model_evaluates_itself_on_a_window():
    """DarkModel.dark_frame_dn is bias + β·t·ISO/ISO_dark (seed eq. 12 offset), on a window of each plane, and the
    correction path takes the dark frame from it; a bias-only model gives its bias."""
    rng = np.random.default_rng(3)
    bias = (512 + rng.normal(0, 2, (4, 6, 8))).astype(np.float32)
    beta = rng.uniform(0.5, 4.0, (4, 6, 8)).astype(np.float32)
    zeros = np.zeros((4, 6, 8), np.float32)
    model = DarkModel(bias_dn=bias, dark_current_dn_per_s=beta, dark_current_unc_dn_per_s=zeros, read_noise_dn=zeros,
                      defects=zeros.astype(np.uint8), iso=100.0, cfa_pattern="RGGB", temperature_c=None)
    window = (slice(1, 4), slice(2, 7))
    expect = bias[:, 1:4, 2:7] + beta[:, 1:4, 2:7] * 2.5 * (400.0 / 100.0)
    np.testing.assert_allclose(model.dark_frame_dn(2.5, 400.0, window), expect, rtol=1e-6)
    np.testing.assert_allclose(dark_frame(model, 2.5, 400.0, bias.shape, window), expect, rtol=1e-6)
    np.testing.assert_allclose(model.dark_frame_dn(2.5), bias + beta * 2.5, rtol=1e-6)
    bias_only = DarkModel(bias_dn=bias, dark_current_dn_per_s=None, dark_current_unc_dn_per_s=None,
                          read_noise_dn=zeros, defects=zeros.astype(np.uint8), iso=100.0, cfa_pattern="RGGB",
                          temperature_c=None)
    np.testing.assert_array_equal(bias_only.dark_frame_dn(30.0, 800.0), bias)
    with pytest.raises(CamcalError, match="exposure time"):
        dark_frame(model, -1.0, None, bias.shape, path="x.dng")


def test_png_darks_without_bias_fit_their_offset_instead_of_assuming_zero(tmp_path):
    """One-channel 16-bit PNGs state no black level: without bias frames the offset is the dark series' intercept
    (not a prior of 0 at t = 0, which tilts the line), so the dark current is the truth and the source is recorded."""
    import OpenImageIO as oiio

    from camcal.io.read import load_frame

    rng = np.random.default_rng(3)
    offset_dn, current_dn_per_s, read_dn = 1200.0, 5.0, 3.0  # levels 1205..1280 DN: far from 11 bits' top
    d = tmp_path / "dark"
    d.mkdir()
    rows = ["file,exposure_s,iso"]
    for t in (1.0, 4.0, 16.0):
        for i in range(4):
            level = offset_dn + current_dn_per_s * t
            a = np.clip(np.rint(rng.normal(level, np.sqrt(read_dn**2 + level - offset_dn), (32, 48))), 0, 65535)
            name = f"d_{t:g}_{i}.png"
            out = oiio.ImageOutput.create(str(d / name))
            out.open(str(d / name), oiio.ImageSpec(48, 32, 1, oiio.UINT16))
            out.write_image(np.ascontiguousarray(a.astype(np.uint16)[..., None]))
            out.close()
            rows.append(f"{name},{t},100")
    (d / "frames.csv").write_text("\n".join(rows) + "\n")
    assert load_frame(d / "d_1_0.png").black_level_source == "unknown"
    model = fit_dark(measure_dark(d))
    beta = float(np.median(model.dark_current_dn_per_s))
    bias = float(np.median(model.bias_dn))
    assert beta == pytest.approx(current_dn_per_s, abs=0.1), (beta, bias)  # a prior of 0 at t = 0 would give ≫ 5 DN/s
    assert bias == pytest.approx(offset_dn, abs=1.0), bias
    assert model.provenance["black_level_source"].startswith("unknown")


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
def test_dark_line_fit_cut_one_dn_below_white_and_frame_counts():
    """``_fit_lines``' saturation cut and its usable-time count, one pixel per case against values written out
    (white level 4095 DN: levels at or above 4094 DN get zero weight, the documented cut):

    - a level of exactly 4094 DN is cut, whether it is the band's brightest level (no line: one usable time) or
      another pixel of the band is saturated; 4093.5 DN is kept (β through two points);
    - a group with no frames at a pixel (count 0) is not a usable time there; a group of one frame is.
    """
    white = 4095.0
    one = np.array([1.0])

    def fit(levels_1s, levels_10s, n_1s=(4.0,), n_10s=(4.0,)):
        obs = [(1.0, np.array(levels_1s), np.array(n_1s) * one, 2.0 * one),
               (10.0, np.array(levels_10s), np.array(n_10s) * one, 2.0 * one)]
        return _fit_lines(obs, white)

    beta, _, b, _, n_times = fit([1100.0], [4094.0])
    assert np.isnan(beta[0]) and np.isnan(b[0]) and n_times.tolist() == [1]
    beta, _, _, _, n_times = fit([1100.0, 1100.0], [4094.0, 4095.0])
    assert np.isnan(beta).all() and n_times.tolist() == [1, 1]
    beta, _, b, _, n_times = fit([1100.0, 1100.0], [4093.5, 4095.0])
    assert beta[0] == pytest.approx((4093.5 - 1100.0) / 9.0, rel=1e-12) and n_times.tolist() == [2, 1]
    assert b[0] == pytest.approx(1100.0 - (4093.5 - 1100.0) / 9.0, rel=1e-12)
    # frame counts: none at 10 s → one usable time; one frame at each time (with a saturated pixel in the band)
    beta, _, _, _, n_times = fit([1100.0], [1200.0], n_10s=(0.0,))
    assert np.isnan(beta[0]) and n_times.tolist() == [1]
    beta, _, _, _, n_times = fit([1100.0, 1100.0], [1200.0, 4095.0], n_1s=(1.0, 1.0), n_10s=(1.0, 1.0))
    assert beta[0] == pytest.approx(100.0 / 9.0, rel=1e-12) and n_times.tolist() == [2, 1]


@pytest.mark.formula
def test_dark_line_fit_of_a_band_with_and_without_a_line():
    """A band of two pixels, one with a line and one left with a single usable time (saturated at 10 s), and
    exposures of 10 and 30 ms:

    - the pixel with a line has β, b and their variances of the least squares written out (the covariance
      A diag(σ²/n) Aᵀ of the linear estimator), even at 10-30 ms, where Σn·Σn(t − t̄)² is far below 1 s²;
    - the pixel with one usable time has no line: β, b, var(β), var(b) NaN. With 3 frames at 0.7 s, Σn·Σnt² −
      (Σnt)² rounds to 8.9e-16 instead of 0, so only the count of usable times (not that determinant) may decide.
    """
    white = 4095.0
    for times, n in (((0.01, 0.03), 4.0), ((0.7, 10.0), 3.0)):
        y = np.array([[1100.0, 1100.0], [1100.0 + 50.0 * (times[1] - times[0]), white]])
        obs = [(t, y[i], np.full(2, n), np.full(2, 2.0)) for i, t in enumerate(times)]
        beta, beta_var, b, b_var, n_times = _fit_lines(obs, white)
        assert n_times.tolist() == [2, 1]
        x = np.stack([np.ones(2), np.array(times)], axis=1)
        a = np.linalg.solve(x.T @ (n * x), x.T * n)
        cov = a @ np.diag(np.full(2, 2.0 / n)) @ a.T
        assert beta[0] == pytest.approx(50.0, rel=1e-9) and b[0] == pytest.approx(1100.0 - 50.0 * times[0], rel=1e-12)
        assert beta_var[0] == pytest.approx(cov[1, 1], rel=1e-9) and b_var[0] == pytest.approx(cov[0, 0], rel=1e-9)
        assert np.isnan([beta[1], b[1], beta_var[1], b_var[1]]).all()


@pytest.mark.formula
def test_dark_line_fit_returns_none_for_the_parts_not_asked_for():
    """``with_fit=False`` returns β and b as None, ``with_variance=False`` var(β) and var(b) as None (documented:
    the callers ask for one or the other); the parts asked for are the exact line through two points."""
    obs = [(1.0, np.array([1100.0]), np.array([4.0]), np.array([2.0])),
           (3.0, np.array([1130.0]), np.array([4.0]), np.array([2.0]))]
    beta, beta_var, b, b_var, n_times = _fit_lines(obs, 4095.0, with_variance=False)
    assert beta_var is None and b_var is None and n_times.tolist() == [2]
    assert beta[0] == pytest.approx(15.0, rel=1e-12) and b[0] == pytest.approx(1085.0, rel=1e-12)
    beta, beta_var, b, b_var, n_times = _fit_lines(obs, 4095.0, with_fit=False)
    assert beta is None and b is None and n_times is None
    # var(β) of two points with weights n = 4 and per-frame variance 2: 2 σ²/n / Δt² = 2·0.5/4 = 0.25 (DN/s)²
    assert beta_var[0] == pytest.approx(0.25, rel=1e-12)
    beta, _, b, _, n_times = _fit_lines(obs, 4095.0, with_variance=False, with_count=False)
    assert n_times is None and beta[0] == pytest.approx(15.0, rel=1e-12)


@pytest.mark.formula
def test_dark_line_fit_in_float32_rounds_the_float64_result_once():
    """``_fit_lines(dtype=np.float32)`` (the dark fit's maps, half the memory): β, b, var(β) and var(b) in float32,
    each the float64 result rounded once, on random levels whose values are not exact in float32; the count of
    usable times stays int16."""
    rng = np.random.default_rng(8)
    shape = (4, 9, 11)
    bias = 1000.0 + rng.uniform(0, 7, shape)
    beta = rng.uniform(0.5, 3.0, shape)
    obs = [(t, (bias + beta * t).astype(np.float32), np.full(shape, n), rng.uniform(3.0, 5.0, shape))
           for t, n in ((0.0, 16.0), (0.37, 8.0), (2.9, 6.0))]
    wide = _fit_lines(obs, 4095.0)
    narrow = _fit_lines(obs, 4095.0, dtype=np.float32)
    for a64, a32 in zip(wide[:4], narrow[:4], strict=True):
        assert a32.dtype == np.float32 and a64.dtype == np.float64
        np.testing.assert_array_equal(a32, a64.astype(np.float32))
        assert not np.array_equal(a32.astype(np.float64), a64)  # the float64 values are not float32 ones
    assert narrow[4].dtype == wide[4].dtype == np.int16
    np.testing.assert_array_equal(narrow[4], 3)


@pytest.mark.formula
def test_dark_line_fit_over_many_bands_of_every_shape(monkeypatch):
    """``_fit_lines`` with bands of 4 pixels (instead of 8192), so that every shape it accepts is cut into many
    bands: a single pixel (0-d), a run (1-D), rows of one plane (2-D), planes with fewer rows than planes (3-D),
    and 4-D (one band). Every pixel must be fitted exactly once from its own levels: β, b, var(β), var(b) of the
    line through two levels with σ² = 2 DN² per frame and n = 4 frames at t1 = 1 s, t2 = 3 s:
    var(β) = 2σ²/(nΔt²), var(b) = σ²(t1² + t2²)/(nΔt²)."""
    monkeypatch.setattr(camcal.calibrate.dark, "FIT_BAND_PIXELS", 4)
    rng = np.random.default_rng(9)
    for shape in ((), (7,), (5, 3), (4, 3, 5), (2, 4, 3, 2)):
        b = 1000.0 + rng.integers(-20, 21, shape)
        beta = 0.5 * rng.integers(1, 40, shape)
        obs = [(t, b + beta * t, np.full(shape, 4.0), np.full(shape, 2.0)) for t in (1.0, 3.0)]
        f_beta, f_beta_var, f_b, f_b_var, n_times = _fit_lines(obs, 4095.0)
        assert np.shape(f_beta) == shape
        np.testing.assert_allclose(f_beta, beta, rtol=1e-12)
        np.testing.assert_allclose(f_b, b, rtol=1e-12)
        np.testing.assert_allclose(f_beta_var, 2 * 2.0 / (4.0 * 2.0**2), rtol=1e-12)
        np.testing.assert_allclose(f_b_var, 2.0 * (1.0 + 9.0) / (4.0 * 2.0**2), rtol=1e-12)
        np.testing.assert_array_equal(n_times, np.full(shape, 2))


@pytest.mark.formula
def test_dark_robust_centre_and_spread_and_the_noise_lines_cut_level():
    """``_robust``: the median and the normal-consistent MAD (MAD / Φ⁻¹(3/4)) of the finite values, (NaN, NaN)
    when there are none, (x, 0) for one; ``_max_median_mean``: max(median, mean) of skewed samples either way,
    including one where 3 of 6 values lie at or below the mean while the median is above it (its shortcut needs
    n//2 + 1 of them), and it leaves its input as it was."""
    x = np.array([3.0, np.nan, 1.0, 10.0, np.inf, 2.0, -np.inf, 4.0])
    med, rs = _robust(x.copy())
    assert med == 3.0 and rs == pytest.approx(NORMAL_PER_MAD * 1.0, rel=1e-12)  # |dev| = 0, 2, 7, 1, 1
    assert all(np.isnan(_robust(np.array([np.nan, np.inf]))))
    assert _robust(np.array([2.5])) == (2.5, 0.0)
    for sample, expect in (([1.0, 1.0, 1.0, 1.0, 10.0], 2.8), ([-10.0, -10.0, -1.0, 5.0, 5.0, 5.0], 2.0),
                           ([0.0, 10.0, 10.0, 10.0], 10.0), ([1.0, 2.0, 3.0], 2.0)):
        a = np.array(sample)
        assert _max_median_mean(a) == pytest.approx(expect, rel=1e-12)
        np.testing.assert_array_equal(a, sample)

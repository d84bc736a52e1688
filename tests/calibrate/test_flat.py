"""Flat fields: vignetting model with a fitted optical centre, PRNU, correction, CLI, errors.

Noise budget of the synthetic flats used here (14-bit, 1.6 e-/DN, flat at 45 % of full scale on
axis): ~11 000 e- per pixel and frame on the green planes, shot noise 0.95 % per frame, 0.34 % in
an 8-frame mean; PRNU 1 %. The fit runs on ~3x3-pixel blocks (~2 700 per plane), so each block
carries ~0.35 % relative noise; a 6-parameter model fitted to 2 700 such blocks is determined to
~0.35 % / sqrt(2700 / 6) ≈ 0.02 % in the bulk and ~0.1 % at the extreme corners. The 0.5 % target
of the issue is therefore a genuine check (a wrong centre by 2 px or the wrong radius convention
fails it) with a wide margin against noise.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.special import eval_legendre

from camcal.calibrate.flat import (
    FlatChecks,
    _quadratic_vertex,
    _total_degree_mask,
    fit_2d_plane,
    fit_flat_planes,
    fit_radial_plane,
)
from camcal.errors import CamcalError
from camcal.frame import split_planes
from camcal.io.read import load_frame
from camcal.models.flat import PlaneGeometry, load_flat, radial_gain, save_flat
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, _white_spectrum, exposure_for_level, write_session
from tests.conftest import assert_one_line_error, run_cli
from tests.helpers import _aperture_series
from tests.oracles import (
    correct_flat,
    flat_of_folder,
)

SPECTRUM = _white_spectrum(5000.0)


def _flats(cam: SyntheticCamera, n: int = 8, level: float = 0.45, scene: Scene | None = None, seed: int = 0):
    """n flat exposures as (n, 4, h, w) float DN above the black level."""
    p = cam.params
    t = exposure_for_level(cam, SPECTRUM, level, p.iso_base, p.reference_f_number)
    black = np.asarray(p.black_level_dn, float)[:, None, None]
    scene = scene or Scene.uniform(SPECTRUM)
    return np.stack([cam.expose_planes(scene, exposure_s=t, rng=np.random.default_rng([seed, i])) - black
                     for i in range(n)])


# 40 % corner falloff (1 + k0 + k1 = 0.60), optical centre 5 % of the width off-centre
CAMERAS = {
    "rggb-right": SensorParams(width=384, height=256, cfa_pattern="RGGB", vignetting_k=(-0.30, -0.10, 0, 0, 0),
                               optical_centre=(0.55, 0.50), seed=3),
    "bggr-left-low": SensorParams(width=320, height=240, cfa_pattern="BGGR", vignetting_k=(-0.20, -0.15, -0.05, 0, 0),
                                  optical_centre=(0.45, 0.53), seed=4),
}


@pytest.fixture(scope="module", params=sorted(CAMERAS))
def fitted(request):
    cam = SyntheticCamera(CAMERAS[request.param])
    frames = _flats(cam)
    master = frames.mean(axis=0)
    fm = fit_flat_planes(master, cfa_pattern=cam.params.cfa_pattern, mask=cam.hot_pixel_mask,
                         noise_var=frames.var(axis=0, ddof=1) / len(frames))
    return cam, fm


def test_radial_model_within_half_percent_everywhere(fitted):
    cam, fm = fitted
    rel = fm.gain() / cam.vignetting_map - 1.0
    assert np.abs(rel).max() < 0.005, np.abs(rel).max(axis=(1, 2))
    # and it is a real falloff: the corners are ~40 % down
    assert min(fm.corner_gain().values()) < 0.62


def test_optical_centre_within_one_half_resolution_pixel(fitted, tmp_path):
    cam, fm = fitted
    truth = cam.truth()["vignetting"]["centre_half_px"]
    for c in fm.channels:
        dx, dy = np.subtract(fm.centre_px[c], truth[c])
        assert np.hypot(dx, dy) < 1.0, (c, fm.centre_px[c], truth[c])
    # the centre in full-resolution pixels agrees between planes (one lens): each plane's estimate
    full = np.array(list(fm.centre_full_px().values()))
    assert np.ptp(full, axis=0).max() < 2.0


def test_residual_rms_matches_block_noise(fitted):
    _, fm = fitted
    # blocks of b x b px (b = 3 for 384-px, 2 for 320-px sensors): the per-pixel noise
    # hypot(PRNU 1 %, shot 0.34-0.45 %) / b is 0.35 % (b = 3) or 0.53 % (b = 2); a wrong model adds to it
    b = fm.info["downsample"]
    for c, r in fm.residual_rms.items():
        assert 1.06 / b / 100 * 0.8 < r < 1.10 / b / 100 * 1.2, (c, r, b)


def test_prnu_map_recovers_pixel_response(fitted):
    cam, fm = fitted
    assert fm.prnu is not None and fm.prnu.shape == cam.prnu_map.shape
    for i, c in enumerate(fm.channels):
        good = ~cam.hot_pixel_mask[i]
        # estimate = PRNU x (1 + 0.34 % noise): correlation with truth ~ 1/sqrt(1 + 0.34^2) ≈ 0.95 on green,
        # ~0.90 on R and B (lower signal); a map of noise would give ~0
        corr = np.corrcoef(fm.prnu[i][good], cam.prnu_map[i][good])[0, 1]
        assert corr > 0.85, (c, corr)
        assert abs(float(np.mean(fm.prnu[i])) - 1.0) < 1e-3
        # temporal noise removed from the RMS: the truth is 1 % (sampling error of 24k pixels ~0.5 %)
        assert fm.prnu_rms[c] == pytest.approx(cam.params.prnu_sigma, rel=0.1)


def test_k_follow_dng_convention_when_terms_match():
    """With as many terms as the truth, the k are the truth's (r measured in full-resolution pixels)."""
    cam = SyntheticCamera(CAMERAS["rggb-right"])
    master = _flats(cam, n=4).mean(axis=0)
    fm = fit_flat_planes(master, cfa_pattern="RGGB", n_terms=2, with_prnu=False)
    for c in fm.channels:
        np.testing.assert_allclose(fm.k[c][:2], cam.params.vignetting_k[:2], atol=0.01)
        assert fm.k[c][2:] == (0.0, 0.0, 0.0)
    assert radial_gain(np.array([1.0]), (-0.3, -0.1))[0] == pytest.approx(0.6)


def test_correction_makes_a_uniform_frame_flat(fitted):
    cam, fm = fitted
    frame = _flats(cam, n=1, seed=99)[0]  # an independent exposure
    green = [1, 2]
    corner = min(frame[green, ys, xs].mean() for ys in (slice(0, 8), slice(-8, None))
                 for xs in (slice(0, 8), slice(-8, None)))
    centre = frame[green, 56:72, 88:104].mean()
    assert corner / centre < 0.75  # the uncorrected frame is far from flat

    def spread(x):
        """Relative RMS per plane, hot pixels excluded."""
        return np.array([np.std(x[i][~cam.hot_pixel_mask[i]]) / np.mean(x[i][~cam.hot_pixel_mask[i]])
                         for i in range(4)])

    corrected = correct_flat(frame, fm)
    h, w = fm.shape
    b = 8  # 8x8-pixel block means: PRNU and shot noise averaged to ~0.15 %
    blocks = corrected[:, : h // b * b, : w // b * b].reshape(4, h // b, b, w // b, b).mean(axis=(2, 4))
    rel = blocks / np.median(blocks, axis=(1, 2), keepdims=True) - 1
    assert np.abs(rel).max() < 0.01, np.abs(rel).max(axis=(1, 2))  # 0.5 % model + 5 sigma of 0.15 % noise
    # pixel level: flat to within PRNU (1 %) and shot noise (sqrt(signal e-) / signal e-)
    level_e = np.median(frame, axis=(1, 2)) * cam.params.gain_e_per_dn
    expected = np.hypot(cam.params.prnu_sigma, 1 / np.sqrt(level_e))
    np.testing.assert_allclose(spread(corrected), expected, rtol=0.08)
    # dividing by the PRNU map too leaves the shot noise (+ the noise of the map, 8 frames: /sqrt(8))
    with_prnu = correct_flat(frame, fm, with_prnu=True)
    np.testing.assert_allclose(spread(with_prnu), np.sqrt(1 + 1 / 8) / np.sqrt(level_e), rtol=0.1)


def test_2d_model_handles_a_non_symmetric_lens():
    """Illumination that is not radially symmetric: the 2-D model fits it, the radial model cannot."""
    cam = SyntheticCamera(SensorParams(width=384, height=256, vignetting_k=(0, 0, 0, 0, 0), seed=5))
    hh, ww = 256, 384
    yy, xx = np.mgrid[0:hh, 0:ww].astype(float)
    u, v = (xx - 0.45 * (ww - 1)) / (ww / 2), (yy - 0.55 * (hh - 1)) / (hh / 2)
    weight = (1 - 0.25 * u**2 - 0.12 * v**2 - 0.05 * u * v - 0.03 * u**4) * (1 + 0.04 * u)
    truth = split_planes(weight, "RGGB", dtype=np.float64)
    master = _flats(cam, scene=Scene(((weight, SPECTRUM),))).mean(axis=0)
    fm2 = fit_flat_planes(master, cfa_pattern="RGGB", model="2d", mask=cam.hot_pixel_mask, with_prnu=False)
    radial = fit_flat_planes(master, cfa_pattern="RGGB", model="radial", mask=cam.hot_pixel_mask, with_prnu=False)
    assert fm2.kind == "2d"
    assert np.abs(fm2.gain() / truth - 1).max() < 0.005
    assert np.abs(radial.gain() / truth - 1).max() > 0.05
    # the residual RMS tells the two apart (the 2-D model reaches the block noise)
    assert max(fm2.residual_rms.values()) < 0.005 < min(radial.residual_rms.values())


def test_correct_flat_refuses_other_sizes(fitted):
    _, fm = fitted
    with pytest.raises(CamcalError, match="flat model is for"):
        correct_flat(np.ones((4, 10, 12), np.float32), fm)


def test_save_load_round_trip(fitted, tmp_path):
    cam, fm = fitted
    path = save_flat(fm, tmp_path / "flat.json")
    assert (tmp_path / "flat.maps.exr").is_file()
    back = load_flat(path)
    assert back.centre_px == fm.centre_px and back.k == fm.k and back.shape == fm.shape
    np.testing.assert_allclose(back.gain(with_prnu=True), fm.gain(with_prnu=True), rtol=1e-6)
    doc = json.loads(path.read_text())
    assert doc["kind"] == "flat" and set(doc["maps"]) >= {"gain.G1", "prnu.B"}
    with pytest.raises(CamcalError, match="not a camcal dark file"):
        from camcal.io.store import load_stage

        load_stage(path, "dark")


# ------------------------------------------------------------------------------------------------
# from real DNG files


def test_fit_flat_from_session_dng(session_dir, truth, camera):
    fm = flat_of_folder(session_dir / "flat")
    assert fm.info["n_frames"] == truth["plan"]["n_flat"]
    assert np.abs(fm.gain() / camera.vignetting_map - 1).max() < 0.005
    for c in fm.channels:
        assert np.hypot(*np.subtract(fm.centre_px[c], truth["vignetting"]["centre_half_px"][c])) < 1.0
    # on-axis level in DN: the truth's on-axis DN rate x the flat exposure time; 1 % covers the
    # mean PRNU of the plane (1 % / sqrt(24k) per plane) and the dark current not subtracted (~0.02 %)
    rate = truth["linearity"]["rate_dn_per_s_on_axis"]
    t = truth["flat"]["exposure_s"]
    for c, rgb in (("R", "R"), ("G1", "G"), ("G2", "G"), ("B", "B")):
        assert fm.level_dn[c] == pytest.approx(rate[rgb] * t, rel=0.01)


def _small_session(path, level: float, n: int = 2, **params):
    cam = SyntheticCamera(SensorParams(width=128, height=96, **params))
    return write_session(path, cam, SessionPlan(stages=("flat",), n_flat=n, flat_level=level)) / "flat"


def test_saturated_flats_are_refused(tmp_path):
    folder = _small_session(tmp_path / "S", level=1.3)
    with pytest.raises(CamcalError, match="saturated"):
        flat_of_folder(folder)


def test_dark_flats_are_refused(tmp_path):
    folder = _small_session(tmp_path / "S", level=0.01)
    with pytest.raises(CamcalError, match="too dark for a useful SNR"):
        flat_of_folder(folder)
    # the limit is a documented knob
    fm = flat_of_folder(folder, checks=FlatChecks(min_level=0.001), with_prnu=False)
    assert fm.info["n_frames"] == 2


def test_mismatched_sizes_are_refused(tmp_path):
    folder = _small_session(tmp_path / "S", level=0.4)
    other = _small_session(tmp_path / "T", level=0.4, seed=2)
    # a frame from a differently sized sensor in the same folder
    cam = SyntheticCamera(SensorParams(width=160, height=96))
    # (exposed to ~40 % of full scale: a saturated frame would be refused for that before its size is compared)
    cam.write_dng(folder / "flat_zzz.dng", Scene.uniform(SPECTRUM), exposure_s=8e-5, rng=np.random.default_rng(0))
    with pytest.raises(CamcalError, match="mismatched sizes") as err:
        flat_of_folder(folder)
    assert "flat_zzz.dng" in str(err.value)
    # a flat model applied to frames of another size
    fm = flat_of_folder(other, with_prnu=False)
    with pytest.raises(CamcalError, match="flat model is for"):
        correct_flat(np.ones((4, 48, 80), np.float32), fm)


def test_jpeg_flats_are_refused(tmp_path):
    folder = tmp_path / "flat"
    folder.mkdir()
    cam = SyntheticCamera(SensorParams(width=128, height=96))
    cam.write_jpeg(folder / "f.jpg", Scene.uniform(SPECTRUM), exposure_s=0.05, rng=np.random.default_rng(0))
    with pytest.raises(CamcalError, match="must be RAW"):
        flat_of_folder(folder)


# ------------------------------------------------------------------------------------------------
# CLI


def test_cli_flat_writes_model_maps_and_png(session_dir, truth, dark_json, tmp_path):
    out = tmp_path / "cal" / "flat.json"
    proc = run_cli("flat", session_dir / "flat", "--dark", dark_json, "-o", out, "--json")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    for c, xy in summary["centre_px"].items():
        assert np.hypot(*np.subtract(xy, truth["vignetting"]["centre_half_px"][c])) < 1.0
    assert (tmp_path / "cal" / "flat.maps.exr").is_file()
    png = tmp_path / "cal" / "flat.falloff.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert summary["info"]["dark"] == "dark model"
    fm = load_flat(out)
    assert fm.prnu is not None and fm.prnu.shape == (4, 128, 192)


def test_cli_flat_errors_are_one_line(tmp_path, session_dir):
    sat = _small_session(tmp_path / "S", level=1.3)
    assert_one_line_error(run_cli("flat", sat, "-o", tmp_path / "f.json"), "saturated", "flat_000.dng")
    assert not (tmp_path / "f.json").exists()
    bad = tmp_path / "bad"
    shutil.copytree(session_dir / "flat", bad)
    (bad / "flat_001.dng").write_bytes(b"II*\x00garbage")
    assert_one_line_error(run_cli("flat", bad, "-o", tmp_path / "f.json"), "flat_001.dng")
    assert not (tmp_path / "f.json").exists()


def test_bad_options_and_empty_folders(tmp_path, session_dir):
    from camcal.calibrate.flat import FlatOptions, measure_flat

    with pytest.raises(CamcalError, match="unknown flat model"):
        measure_flat(session_dir / "flat", None, FlatOptions(model="3d"))
    assert_one_line_error(run_cli("flat", session_dir / "flat", "-o", tmp_path / "f.exr"), "must be a .json")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CamcalError, match="no image files"):
        flat_of_folder(tmp_path / "empty")


@pytest.fixture(scope="module")
def dark_json(session_dir, tmp_path_factory):
    from camcal.calibrate.dark import fit_dark
    from camcal.calibrate.dark_frames import measure_dark
    from camcal.models.dark import save_dark

    model = fit_dark(measure_dark(session_dir / "dark", session_dir / "bias"))
    return save_dark(model, tmp_path_factory.mktemp("dark") / "d.json")


def test_fit_flat_with_dark_model(session_dir, truth, camera, dark_json, tmp_path):
    fm = flat_of_folder(session_dir / "flat", dark_json)
    assert fm.info["dark"] == "dark model"
    assert np.abs(fm.gain() / camera.vignetting_map - 1).max() < 0.005
    for c in fm.channels:
        assert np.hypot(*np.subtract(fm.centre_px[c], truth["vignetting"]["centre_half_px"][c])) < 1.0
    # hot pixels flagged by the dark model are neutral (1) in the PRNU map
    hot = camera.hot_pixel_mask
    assert np.all(fm.prnu[hot] == 1.0)
    # a dark model of another sensor size is refused
    other = _small_session(tmp_path / "S", level=0.4)
    with pytest.raises(CamcalError, match="mismatched sizes"):
        flat_of_folder(other, dark_json)


def test_stray_saturated_pixels_are_masked_not_refused(tmp_path):
    """0.2 % pixels stuck at the white level in the flats (hot beyond measure: 1e8 x the dark current) and no dark
    model to know them: the flats are kept (masks, not rejections: issue 15), those pixels left out, and the
    vignetting model as accurate as usual."""
    cam = SyntheticCamera(SensorParams(width=128, height=96, hot_pixel_fraction=2e-3,
                                       hot_pixel_factor=(1e8, 2e8)))
    folder = write_session(tmp_path / "S", cam, SessionPlan(stages=("flat",), n_flat=4)) / "flat"
    frame = load_frame(sorted(folder.glob("*.dng"))[0])
    at_white = np.mean(frame.planes() >= frame.white_level_dn)
    assert 1e-3 < at_white < 1e-2  # saturated hot pixels are really there (the old limit was 1e-4)
    fm = flat_of_folder(folder)
    err = np.abs(fm.gain() / cam.vignetting_map - 1)
    # 4 flats of a 128x96 sensor: the model's largest error is 0.29 / 0.37 % without stuck pixels and
    # 0.52 / 0.25 % with them (seeds 1 / 2; the PRNU maps differ between the two cameras)
    assert float(err.max()) < 0.0075


def test_downsample_is_a_block_in_photo_pixels():
    """``--downsample`` is in photo pixels like every pixel option (issue 30 item 8): 16 photo pixels of a Bayer
    sensor are 8 plane pixels; a block that splits a 2x2 CFA cell is refused; full-resolution planes take it
    as it is."""
    yy, xx = np.mgrid[0:64, 0:96]
    plane = (1.0 - 0.3 * (((xx - 48) / 48.0) ** 2 + ((yy - 32) / 48.0) ** 2)).astype(np.float32)
    master = np.stack([plane] * 4)
    assert fit_flat_planes(master, downsample=16, with_prnu=False).info["downsample"] == 8
    with pytest.raises(CamcalError, match="photo pixels"):
        fit_flat_planes(master, downsample=15, with_prnu=False)
    rgb = np.stack([plane] * 3)
    fm = fit_flat_planes(rgb, channels=("R", "G", "B"), cfa_pattern=None, downsample=5, with_prnu=False)
    assert fm.info["downsample"] == 5


def test_histogram_median_of_integer_planes_is_numpys(rng):
    """The flat check's per-plane median of integer planes (a banded histogram) is exactly ``np.median`` of the
    planes minus the black level: odd and even pixel counts, planes taller than one histogram band, ties, a
    single value, a value 0 and uint16 values near the top of the range."""
    from camcal.calibrate.flat import HISTOGRAM_ROWS, _histogram, _medians_above

    black = np.array([512.0, 511.5, 512.0, 0.0])[:, None, None]
    for h, w in ((HISTOGRAM_ROWS * 2 + 3, 7), (HISTOGRAM_ROWS + 1, 6), (1, 1), (2, 1), (5, 4)):
        planes = rng.integers(400, 700, (4, h, w)).astype(np.uint16)
        planes[1] = 600  # every value tied
        planes[2, 0, 0] = 0
        planes[3].flat[: max(1, planes[3].size // 2)] = 65535
        expect = np.median((planes - black).reshape(4, -1), axis=1)
        assert np.array_equal(_medians_above(planes, black), expect), (h, w)
        assert np.array_equal(_histogram(planes[0]), np.bincount(planes[0].ravel()))


def _legendre_flat(scale):
    """Plane B of a 72 × 96 RGGB frame (36 × 48 planes, B at full-resolution offsets (1, 1)): u, v are the
    full-resolution coordinates mapped to [−1, 1] over the frame, so u = 2 (2x + 1)/95 − 1, v = 2 (2y + 1)/71 − 1."""
    geom = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (36, 48), "RGGB")
    yy, xx = np.mgrid[0:36:3, 0:48:3].astype(float)
    u, v = 2 * (2 * xx + 1) / 95.0 - 1, 2 * (2 * yy + 1) / 71.0 - 1
    surf = scale * (1.0 - 0.15 * eval_legendre(2, u) + 0.1 * u - 0.05 * v - 0.1 * eval_legendre(2, v))
    return geom, xx, yy, u, v, surf


@pytest.mark.formula
def test_2d_flat_fit_is_the_relative_weighted_least_squares_on_positive_blocks():
    """On data with a fixed ±5 % pattern the fit is the least-squares solution with weights 1/d (relative
    residuals), computed here with the Legendre design written out; blocks that are 0 or NaN are left out; the
    level is the series at the centre and the RMS the relative residual."""
    geom, xx, yy, u, v, surf = _legendre_flat(0.8)
    pattern = 1 + 0.05 * np.sin(7 * xx + 3 * yy)
    data = surf * pattern
    data[0, 0], data[2, 3] = 0.0, np.nan
    level, coef, scale, rms = fit_2d_plane(data, xx, yy, geom, "B", 2, (20.0, 12.0))
    ok = np.isfinite(data) & (data > 0)
    d, uu, vv = data[ok], u[ok], v[ok]
    terms = [(i, j) for i in range(3) for j in range(3) if i + j <= 2]
    design = np.stack([eval_legendre(i, uu) * eval_legendre(j, vv) for i, j in terms], axis=1)
    sol = np.linalg.lstsq(design / d[:, None], np.ones(d.size), rcond=None)[0]
    uc, vc = 2 * 41.0 / 95.0 - 1, 2 * 25.0 / 71.0 - 1
    expect_level = sum(c * eval_legendre(i, uc) * eval_legendre(j, vc) for c, (i, j) in zip(sol, terms, strict=True))
    assert level == pytest.approx(expect_level, rel=1e-9)
    for c, (i, j) in zip(sol, terms, strict=True):
        assert coef[i, j] * level == pytest.approx(c, rel=1e-7, abs=1e-12)
    assert coef[2, 2] == 0 and coef[1, 2] == 0 and scale == 1.0
    assert rms == pytest.approx(np.sqrt(np.mean((d / (design @ sol) - 1) ** 2)), rel=1e-9)
    assert level < 1  # a dim flat: levels below 1 DN are fitted too


@pytest.mark.formula
def test_2d_flat_fit_guards_the_number_of_blocks_and_the_sign_at_the_centre():
    """Degree 2 has 6 terms and needs 2 × 6 = 12 usable blocks; a centre where the fitted series is negative
    is refused."""
    geom, xx, yy, u, v, surf = _legendre_flat(1.0)
    data = np.full(surf.shape, np.nan)
    data.flat[:12] = surf.flat[:12]
    fit_2d_plane(data, xx, yy, geom, "B", 2, (20.0, 12.0))
    data.flat[11] = np.nan
    with pytest.raises(CamcalError, match=r"too few usable blocks \(11\) for a degree-2 2-D model"):
        fit_2d_plane(data, xx, yy, geom, "B", 2, (20.0, 12.0))
    tilt = 1.0 + 0.9 * u  # positive on the frame, negative left of it (u < −1.11)
    with pytest.raises(CamcalError, match="not positive at the optical centre"):
        fit_2d_plane(tilt, xx, yy, geom, "B", 1, (-30.0, 12.0))


def _radial_fit_by_definition(d, fx, fy, full_w, full_h, n_terms, start):
    """The relative least-squares fit written out: for a centre (full-resolution px) the coefficients solve the
    normal equations of Σ((A·Σ k_i r²ⁱ − d)/d)²; the centre minimises that sum (Nelder–Mead, not the trust-region
    solver of the code). r² is normalised by the distance to the farthest image corner."""
    def solve(c):
        rmax = max(np.hypot(a - c[0], b - c[1]) for a in (0.0, full_w - 1.0) for b in (0.0, full_h - 1.0))
        r2 = ((fx - c[0]) ** 2 + (fy - c[1]) ** 2) / rmax**2
        a = np.stack([r2**i for i in range(n_terms + 1)], axis=-1) / d[:, None]
        coef = np.linalg.solve(a.T @ a, a.T @ np.ones_like(d))
        return coef, a @ coef - 1.0

    res = minimize(lambda c: float(np.sum(solve(c)[1] ** 2)), start, method="Nelder-Mead",
                   options={"xatol": 1e-9, "fatol": 1e-18, "maxiter": 4000})
    coef, rel = solve(res.x)
    return coef, res.x, 1.0 / (rel + 1.0) - 1.0  # d/model − 1, the RMS the fit reports


@pytest.mark.formula
def test_radial_fit_of_a_tilted_gain_is_the_relative_least_squares_optimum():
    """A normalised flat (on-axis 0.9, below 1 everywhere, so a cut at 1 instead of 0 would drop every block),
    vignetting with an r⁶ term and a 10 % tilt the two-term radial model cannot follow, one NaN, one zero and one
    negative block. The fit must be the minimum of the relative residuals Σ(model/d − 1)² over centre and
    coefficients, computed here by the written-out normal equations and another optimiser: the level, the
    centre, k and the relative RMS."""
    h, w = 16, 20
    geom = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (h, w), "RGGB")
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    fx, fy = 2 * xx + 1, 2 * yy  # G1: column offset 1
    fcx, fcy = 2 * 8.3 + 1, 2 * 7.1
    r2 = ((fx - fcx) ** 2 + (fy - fcy) ** 2) / (2 * w) ** 2
    block = 0.9 * (1 - 0.45 * r2 + 0.1 * r2**2 - 0.3 * r2**3) * (1 + 0.1 * (xx - w / 2) / w)
    block[3, 4], block[10, 15], block[14, 7] = np.nan, 0.0, -0.2
    ok = np.isfinite(block) & (block > 0)
    coef, centre_full, rel = _radial_fit_by_definition(block[ok], fx[ok], fy[ok], 2 * w, 2 * h, 2, (fcx, fcy))
    level, centre, k, rms = fit_radial_plane(block, xx, yy, geom, "G1", n_terms=2)
    assert level == pytest.approx(coef[0], rel=1e-6)
    assert centre == pytest.approx(((centre_full[0] - 1) / 2, centre_full[1] / 2), abs=1e-4)
    np.testing.assert_allclose(k, (coef[1] / coef[0], coef[2] / coef[0], 0.0, 0.0, 0.0), rtol=0, atol=1e-5)
    assert rms == pytest.approx(float(np.sqrt(np.mean(rel**2))), rel=1e-5)
    assert 1e-3 < rms < 0.05  # the model does not fit exactly: a residual that tests the weighting


@pytest.mark.formula
def test_radial_fit_needs_four_blocks_per_parameter():
    """n_terms = 2 fits 5 parameters (A, k0, k1, the centre's x and y): 20 usable blocks are enough, 19 are not
    (the error names the count)."""
    geom = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (4, 5), "RGGB")
    yy, xx = np.mgrid[0:4, 0:5].astype(float)
    block = 0.8 * (1 - 0.2 * ((xx - 2.1) ** 2 + (yy - 1.4) ** 2) / 30.0)
    level, _, _, rms = fit_radial_plane(block, xx, yy, geom, "G1", n_terms=2)
    assert 0.7 < level < 0.9 and rms < 1e-3
    block[0, 0] = np.nan
    with pytest.raises(CamcalError, match=r"channel G1: too few usable blocks \(19\)"):
        fit_radial_plane(block, xx, yy, geom, "G1", n_terms=2)


def _emva_prnu_by_hand(rel, var_rel, n_frames):
    """√(s²_measured − mean(σ²)/L) / μ and its standard uncertainty (EMVA 1288 4.0 eq. 36), written out."""
    n = rel.size
    mu, measured = rel.mean(), rel.var(ddof=1)
    floor = var_rel.mean() / n_frames
    value = np.sqrt(max(measured - floor, 0.0)) / mu
    unc_s2 = np.sqrt(2 / (n - 1) * measured**2 + 2 / (n * (n_frames - 1)) * floor**2) / mu**2
    return value, unc_s2 / (2 * value), mu, measured, floor * n_frames, n


def _master_for_prnu(mean_all, variance_all, n_frames=4):
    from camcal.calibrate.flat import MasterFlat

    return MasterFlat(value=mean_all, variance_of_mean=None, level_dn={"R": 1.0, "G": 1.0}, n_frames=n_frames,
                      paths=(), channels=("R", "G"), cfa_pattern=None, method="mean", exposure_s=(None,) * n_frames,
                      mean_all=mean_all, variance_all=variance_all)


@pytest.mark.formula
def test_prnu_figures_are_the_emva_spatial_variance_of_good_pixels_about_the_smooth_model():
    """PRNU per plane of the unclipped mean over the smooth model A·g: pixels masked, non-finite (mean or
    variance), under a non-positive model, below half or above 1.5 times the median response left out (the
    bounds themselves kept), then the EMVA formula written out with numpy; the refusal without statistics."""
    from camcal.calibrate.flat import _prnu_figures, flat_prnu

    rng = np.random.default_rng(5)
    smooth = np.full((2, 4, 5), 2.0)
    rel = np.round(1.0 + 0.02 * rng.standard_normal((2, 4, 5)), 4)
    var_rel = 1e-4 * (1.0 + rng.random((2, 4, 5)))
    # plane R: the median of the 20 responses is 1 exactly (ten at or below it, ten above), then 2
    spread = np.round(0.001 + 0.02 * np.abs(rng.standard_normal(9)), 4)
    rel[0].flat[:] = np.concatenate([1.0 - spread, [1.0, 1.0], 1.0 + spread])
    rel[0, 0, 0], rel[0, 0, 1] = 0.5, 0.4999  # on the lower bound (kept), just below (out)
    rel[0, 3, 4], rel[0, 3, 3] = 1.5, 1.5001  # on the upper bound (kept), just above (out)
    rel *= 2.0  # responses about 2 (exact in binary): the bounds are 1 and 3, not 0.5 and 1.5
    mask = np.zeros((2, 4, 5), bool)
    mask[1, 1, 1] = True
    mean = rel * smooth
    var = var_rel * smooth**2
    mean[1, 0, 0] = np.nan
    var[1, 0, 1] = np.inf
    smooth[1, 2, 2], mean[1, 2, 2] = -2.0, -2.0  # a response of 1 under a negative model
    mf = _master_for_prnu(mean, var)
    out = _prnu_figures(mf, ("R", "G"), smooth, mask)
    assert list(out) == ["R", "G"]
    keep_r = np.ones((4, 5), bool)
    keep_r[0, 1] = keep_r[3, 3] = False
    keep_g = np.ones((4, 5), bool)
    keep_g[1, 1] = keep_g[0, 0] = keep_g[0, 1] = keep_g[2, 2] = False
    for i, keep in enumerate((keep_r, keep_g)):
        value, unc, mu, measured, stack, n = _emva_prnu_by_hand(rel[i][keep], var_rel[i][keep], 4)
        p = out["RG"[i]]
        assert p.value == pytest.approx(value, rel=1e-9) and p.uncertainty == pytest.approx(unc, rel=1e-9)
        assert p.spatial.n_pixels == n and p.spatial.n_frames == 4
        assert p.spatial.mean_dn == pytest.approx(mu, rel=1e-12)
        assert p.spatial.measured_dn2 == pytest.approx(measured, rel=1e-9)
        assert p.spatial.stack_dn2 == pytest.approx(stack, rel=1e-9)
    # a mask of defect bits (4: noisy) masks the same pixels as the bool mask
    bits = _prnu_figures(mf, ("R", "G"), smooth, mask.astype(np.uint8) * 4)
    assert [bits[c].value for c in "RG"] == [out[c].value for c in "RG"]
    # without a mask every finite pixel of G under a positive model counts; the median is that of those
    out = _prnu_figures(mf, ("R", "G"), smooth, None)
    keep_g[1, 1] = True
    assert out["G"].value == pytest.approx(_emva_prnu_by_hand(rel[1][keep_g], var_rel[1][keep_g], 4)[0], rel=1e-9)
    # flat_prnu divides by the fitted model A·g: a flat model of gain g and levels A written out
    primary, _, _, gains, _ = _aperture_series()
    fm = primary.replace(level_dn={"R": 2.0, "G": 0.5})
    a_g = gains[5.6] * np.array([2.0, 0.5])[:, None, None]
    resp = 1.0 + 0.03 * rng.standard_normal((2, 3, 4))
    v = 2e-4 * (1.0 + rng.random((2, 3, 4)))
    fmask = np.zeros((2, 3, 4), bool)
    fmask[0, 1, 2] = fmask[1, 0, 0] = True
    got = flat_prnu(_master_for_prnu(resp * a_g, v * a_g**2, 3), fm, fmask)
    for i, c in enumerate("RG"):
        value, unc, mu, *_ = _emva_prnu_by_hand(resp[i][~fmask[i]], v[i][~fmask[i]], 3)
        assert got[c].value == pytest.approx(value, rel=1e-6)  # float32 gain map
        assert got[c].uncertainty == pytest.approx(unc, rel=1e-5)
        assert got[c].spatial.mean_dn == pytest.approx(mu, rel=1e-6)  # the response about A·g, mean ≈ 1
        assert got[c].spatial.n_pixels == 11
    for missing in ({"mean_all": None}, {"variance_all": None}):
        with pytest.raises(CamcalError) as e:
            _prnu_figures(replace(mf, **missing), ("R", "G"), smooth, None)
        assert str(e.value) == "the master flat has no unclipped statistics (a single frame?)"


@pytest.mark.formula
@pytest.mark.filterwarnings("ignore:Mean of empty slice:RuntimeWarning")  # the median of an empty plane is NaN
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_medians_above_black_equal_numpy_medians_for_every_dtype_and_histograms_count_in_bands():
    """The per-plane median of planes − black is np.median of the float64 differences (sorted and written out for
    odd and even counts) for unsigned and signed integers, negative values, floats and empty planes; the banded
    histogram is np.bincount whichever band holds the largest value."""
    from camcal.calibrate.flat import HISTOGRAM_ROWS, _histogram, _medians_above

    def by_hand(planes, black):
        out = []
        for p, b in zip(planes, black.reshape(-1), strict=True):
            s = np.sort(p.astype(np.float64).ravel() - b)
            out.append((s[(s.size - 1) // 2] + s[s.size // 2]) / 2)
        return np.array(out)

    rng = np.random.default_rng(3)
    black = np.array([100.5, 3.0, 7.25]).reshape(3, 1, 1)
    for shape in ((3, 3, 5), (3, 4, 5), (3, 1, 1), (3, 1, 2)):
        for dtype in (np.uint16, np.uint8, np.int32):
            planes = rng.integers(0, 200, shape).astype(dtype)
            np.testing.assert_array_equal(_medians_above(planes, black), by_hand(planes, black))
        planes = rng.integers(-50, 200, shape).astype(np.int32)
        planes.flat[0] = -1
        np.testing.assert_array_equal(_medians_above(planes, black), by_hand(planes, black))
        planes = rng.random(shape).astype(np.float32) * 300
        np.testing.assert_allclose(_medians_above(planes, black), by_hand(planes, black), rtol=1e-12)
    # all pixels but a few at one value, the rest above: the middle order statistics straddle a step
    planes = np.full((3, 2, 3), 10, np.uint16)
    planes[:, 1, :] = 12
    planes[1, 1, :] = 10
    np.testing.assert_array_equal(_medians_above(planes, black), by_hand(planes, black))
    one = rng.integers(0, 200, (1, 3, 4)).astype(np.uint16)  # a single plane
    np.testing.assert_array_equal(_medians_above(one, black[:1]), by_hand(one, black[:1]))
    empty = np.zeros((3, 0, 4), np.uint16)
    assert _medians_above(empty, black).shape == (3,) and np.all(np.isnan(_medians_above(empty, black)))
    for top_last in (False, True):
        plane = rng.integers(0, 50, (2 * HISTOGRAM_ROWS + 7, 3)).astype(np.uint16)
        plane[-1 if top_last else 0, 0] = 900
        np.testing.assert_array_equal(_histogram(plane), np.bincount(plane.ravel()))
    np.testing.assert_array_equal(_histogram(np.array([[3, 1]], np.uint16)), [0, 1, 0, 1])
    assert _histogram(np.zeros((0, 3), np.uint16)).size == np.bincount(np.zeros(0, np.uint16)).size == 0


@pytest.mark.formula
def test_flat_fit_options_and_their_refusals():
    """The fit keywords of the flat stage's options; an unknown model or a number of radial terms outside 1..5
    refused with its one-line message."""
    from camcal.calibrate.flat import FlatOptions, _check_options

    o = FlatOptions(model="2d", downsample=8, n_terms=3, degree_2d=2, with_prnu=False, method="mean")
    assert o.fit_kwargs() == {"model": "2d", "downsample": 8, "n_terms": 3, "degree_2d": 2, "with_prnu": False}
    for model, n in (("radial", 1), ("2d", 5)):
        _check_options(model, n)
    with pytest.raises(CamcalError) as e:
        _check_options("poly", 3)
    assert str(e.value) == "unknown flat model 'poly'; choose 'radial' or '2d'"
    for n in (0, 6):
        with pytest.raises(CamcalError) as e:
            _check_options("radial", n)
        assert str(e.value) == f"n_terms must be 1..5, got {n}"


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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

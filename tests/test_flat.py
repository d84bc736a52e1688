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

import numpy as np
import pytest

from camcal.calibrate.flat import FlatChecks, fit_flat_planes
from camcal.errors import CamcalError
from camcal.frame import split_planes
from camcal.io.read import load_frame
from camcal.models.flat import load_flat, radial_gain, save_flat
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, _white_spectrum, exposure_for_level, write_session
from tests.conftest import assert_one_line_error, run_cli
from tests.oracles import correct_flat, flat_of_folder

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

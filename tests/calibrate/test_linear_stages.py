"""Linear multi-channel RAW (DNG LinearRaw, LibRaw stacks) through every stage and apply, and real files through apply.

The synthetic linear frame holds the camera's R, G1 and B planes (truth.json "layout"), so its truth is the
Bayer truth of those planes, and the accuracy targets are the Bayer session's: β 2 %, read noise 3 %, the
vignetting model 0.5 % everywhere, γ 0.005, c(λ) 1 % RMS of the peak, band radiance 1 %.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rawpy

from camcal.calibrate.run import calibrate_session
from camcal.io.exr import read_exr
from camcal.models.profile import contract, save_profile
from camcal.models.spectra import WAVELENGTHS_NM, planck_radiance
from camcal.synth.camera import LINEAR_FROM_PLANES, Scene, SensorParams, SyntheticCamera, preset
from camcal.synth.session import SessionPlan, write_session
from tests.conftest import assert_one_line_error, run_cli

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
LINEAR_DNG = REALDATA / "raw" / "canon_eos_6d_linear.dng"
PI_PHOTOS = sorted(p for p in (REALDATA / "pi").glob("*.dng") if not p.name.startswith("dark_frame")) \
    if REALDATA.is_dir() else []


@pytest.fixture(scope="module")
def linear_session(tmp_path_factory):
    cam = SyntheticCamera(SensorParams())
    out = write_session(tmp_path_factory.mktemp("lin") / "S", cam, SessionPlan(layout="linear", sweep_jpeg=False))
    profile, notes = calibrate_session(out)
    path = tmp_path_factory.mktemp("linprof") / "lin.camcal"
    profile = save_profile(profile, path)
    return cam, json.loads((out / "truth.json").read_text()), profile, path


def test_linear_session_calibrates_as_accurately_as_bayer(linear_session):
    cam, truth, profile, _ = linear_session
    c = contract(profile)
    assert c["camera"]["layout"] == "linear" and c["camera"]["cfa_pattern"] is None
    for ch, plane in (("R", "R"), ("G", "G1"), ("B", "B")):  # a linear frame's G is the camera's G1 plane
        assert c["dark"]["dark_current_dn_per_s"][ch] == pytest.approx(truth["dark_current_dn_per_s"][plane],
                                                                       rel=0.02), ch
        assert c["dark"]["read_noise_dn"][ch] == pytest.approx(truth["read_noise_dn"][plane], rel=0.03), ch
        assert c["response"]["gamma"][ch] == pytest.approx(1.0, abs=0.005), ch
    hot = sum(1 for k, _, _ in truth["hot_pixels"] if k in LINEAR_FROM_PLANES)
    assert c["dark"]["hot_pixel_count"] == hot
    err = np.abs(profile.flat.gain() / cam.vignetting_map[list(LINEAR_FROM_PLANES)] - 1)
    assert float(err.max()) < 0.005, err.max(axis=(1, 2))
    s = c["spectral_sensitivity"]
    wl = np.asarray(truth["spectral_sensitivity"]["wavelength_nm"])
    for ch in ("R", "G", "B"):
        true = np.interp(s["wavelength_nm"], wl, truth["spectral_sensitivity"][ch])
        assert float(np.sqrt(np.mean((np.asarray(s[ch]) - true) ** 2)) / true.max()) < 0.01, ch


def test_linear_photo_to_radiance_and_layout_check(linear_session, tmp_path):
    cam, truth, profile, path = linear_session
    spectrum = 0.02 * planck_radiance(4500.0) / planck_radiance(4500.0).max()
    photo = cam.write_dng(tmp_path / "p" / "lamp.dng", Scene.uniform(spectrum), exposure_s=0.004,
                          rng=np.random.default_rng(7), layout="linear")
    proc = run_cli("apply", path, photo, "-o", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    channels, meta = read_exr(tmp_path / "out" / "lamp.dng.exr")
    assert channels["R"].shape == (128, 192) and meta["resolution"].startswith("full resolution")
    c_true = cam.spectral_sensitivity()
    h, w = channels["R"].shape
    centre = (slice(h // 2 - 8, h // 2 + 8), slice(w // 2 - 8, w // 2 + 8))
    for i, ch in enumerate("RGB"):
        band = float(np.trapezoid(c_true[i] * spectrum, WAVELENGTHS_NM) / np.trapezoid(c_true[i], WAVELENGTHS_NM))
        assert float(np.nanmedian(channels[ch][centre])) == pytest.approx(band, rel=0.01), ch
    # a Bayer photo of the same camera: refused, naming the layouts
    bayer = cam.write_dng(tmp_path / "b" / "lamp.dng", Scene.uniform(spectrum), exposure_s=0.004,
                          rng=np.random.default_rng(8))
    proc = run_cli("apply", path, bayer, "-o", tmp_path / "out2")
    assert proc.returncode == 1
    assert "is a bayer RAW file but the profile was measured on linear RAW frames" in proc.stderr


@pytest.mark.skipif(not LINEAR_DNG.is_file(), reason="../shared/realdata is absent")
def test_real_linear_dng_through_apply(tmp_path):
    """The demosaiced Canon 6D DNG (LibRaw: a 3-colour stack) with a synthetic linear profile of its geometry."""
    cam = SyntheticCamera(preset("default", width=2448, height=1632))  # linear frames of 1224x816
    plan = SessionPlan(stages=("flat", "sweep"), layout="linear", n_flat=2, sweep_step_nm=50.0, n_sweep=1,
                       sweep_jpeg=False)
    out = write_session(tmp_path / "S", cam, plan)
    prof = tmp_path / "six.camcal"
    assert run_cli("calibrate", out, "-o", prof).returncode == 0
    proc = run_cli("apply", prof, LINEAR_DNG, "-o", tmp_path / "out")
    assert_one_line_error(proc, "Canon EOS 6D", "--allow-other-camera")
    proc = run_cli("apply", prof, LINEAR_DNG, "-o", tmp_path / "out", "--allow-other-camera")
    assert proc.returncode == 0, proc.stderr
    channels, meta = read_exr(tmp_path / "out" / f"{LINEAR_DNG.name}.exr")
    assert channels["G"].shape == (816, 1224)
    assert meta["exposure"]["iso"] == 1000 and meta["exposure"]["f_number"] == pytest.approx(5.6)
    assert np.isfinite(channels["G"]).mean() > 0.5 and np.nanmedian(channels["G"]) > 0


@pytest.mark.skipif(not PI_PHOTOS, reason="../shared/realdata is absent")
def test_real_pi_photos_through_apply_with_a_synthetic_pi_profile(tmp_path):
    """A profile of the IMX296 preset at the real geometry (1456x1088 BGGR, 10-bit, black 60) applied to the
    real Pi photos; the lens has no f-number tag, so the photo folder states it in session.toml."""
    cam = SyntheticCamera(preset("imx296"))
    plan = SessionPlan(stages=("bias", "flat", "sweep"), n_bias=2, n_flat=2, sweep_step_nm=50.0, n_sweep=1,
                       sweep_jpeg=False)
    out = write_session(tmp_path / "S", cam, plan)
    prof = tmp_path / "pi.camcal"
    proc = run_cli("calibrate", out, "-o", prof)
    assert proc.returncode == 0, proc.stderr
    photos = tmp_path / "photos"
    photos.mkdir()
    for p in PI_PHOTOS:  # links from a temporary folder: its session.toml applies, not one beside the targets
        (photos / p.name).symlink_to(p)
    proc = run_cli("apply", prof, photos, "-o", tmp_path / "out", "--allow-other-camera")
    assert proc.returncode == 1 and "f_number" in proc.stderr  # no f-number anywhere: every photo listed
    (photos / "session.toml").write_text("f_number = 1.2\n")
    proc = run_cli("apply", prof, photos, "-o", tmp_path / "out", "--allow-other-camera")
    assert proc.returncode == 0, proc.stderr
    for p in PI_PHOTOS:
        channels, meta = read_exr(tmp_path / "out" / f"{p.name}.exr")
        assert channels["R"].shape == (544, 728)
        assert meta["exposure"]["f_number"] == 1.2
        assert any("dark current is unknown" in n for n in meta["notes"])
        # saturated pixels are NaN, the rest finite (2e7ec634_image_0 is a real over-exposed photo: 99.99 %
        # of its pixels at 1023); the profile's defect map (synthetic) masks a few more
        with rawpy.imread(str(p)) as r:
            red = r.raw_image_visible[1::2, 1::2]  # BGGR: R at (1, 1)
            unsaturated = float(np.mean(red < 1023))
        assert np.isfinite(channels["R"]).mean() == pytest.approx(unsaturated, abs=0.01), p.name


def test_linear_profile_report_and_show(linear_session, tmp_path):
    _, _, _, path = linear_session
    proc = run_cli("report", path, "-o", tmp_path / "r.html")
    assert proc.returncode == 0, proc.stderr
    html = (tmp_path / "r.html").read_text()
    assert html.count("data:image/png;base64,") >= 4
    shown = run_cli("profile", "show", path)
    assert shown.returncode == 0 and "linear RAW 192x128" in shown.stdout

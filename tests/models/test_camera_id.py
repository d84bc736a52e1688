"""One camera under two software names (camcal.models.camera_id): the Raspberry Pi's PiDNG and picamera2 files."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from camcal.apply.photo import check_camera
from camcal.calibrate.run import calibrate_session, camera_identity
from camcal.errors import CamcalError
from camcal.io.read import load_frame
from camcal.models.camera_id import Sensor, match, sensor_of
from camcal.models.profile import save_profile
from tests.conftest import run_cli

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
PI = REALDATA / "pi"
DARKS = ("dark_frame_a03fb6b3.dng", "dark_frame_c5dfe1e7.dng")  # written by PiDNG: model "PiDNG / PiCamera2"
PHOTO = "c21ff2bc_image.dng"  # written by picamera2: make "Raspberry Pi", model "imx296"
pytestmark = pytest.mark.skipif(not PI.is_dir(), reason="../shared/realdata is absent")


def _session(root: Path, stages: dict[str, tuple[str, ...]]) -> Path:
    """A session of links to the real files (never copies), with the fixed lens's f-number in session.toml."""
    for stage, names in stages.items():
        (root / stage).mkdir(parents=True)
        for n in names:
            (root / stage / n).symlink_to(PI / n)
    (root / "session.toml").write_text("f_number = 1.6\n")
    return root


@pytest.fixture(scope="module")
def pi_profile(tmp_path_factory):
    root = _session(tmp_path_factory.mktemp("pi") / "S", {"bias": DARKS})
    profile, _ = calibrate_session(root)
    save_profile(profile, root.parent / "pi.camcal")
    return root.parent / "pi.camcal"


def test_pidng_and_picamera2_are_one_camera_across_stages(tmp_path):
    root = _session(tmp_path / "S", {"bias": DARKS, "flat": (PHOTO,)})
    cam = camera_identity(root)
    # the identity recorded is the one that names the sensor, not the writing software
    assert (cam.make, cam.model, cam.width, cam.height, cam.cfa_pattern) == ("Raspberry Pi", "imx296", 1456, 1088,
                                                                             "BGGR")


def test_picamera2_photo_passes_a_pidng_profile_and_a_real_conflict_refuses(pi_profile):
    from camcal.models.profile import load_profile

    profile = load_profile(pi_profile)
    assert profile.camera.model == "PiDNG / PiCamera2"
    frame = load_frame(PI / PHOTO)
    notes = check_camera(frame.exposure, profile, frame.path, False, frame)
    assert len(notes) == 1 and "one camera" in notes[0]
    with pytest.raises(CamcalError, match="Canon EOS 6D"):
        check_camera(replace(frame.exposure, make="Canon", model="EOS 6D"), profile, frame.path, False, frame)


def test_match_needs_the_same_sensor_when_a_model_is_a_placeholder():
    frame = load_frame(PI / DARKS[0])
    pidng = sensor_of(frame)
    pic2 = sensor_of(load_frame(PI / PHOTO))
    assert match(pidng, pic2)[0] and match(pic2, pidng)[0]
    # the same names with another sensor geometry, CFA or white level: a real conflict
    for change in ({"width": 4056, "height": 3040}, {"cfa_pattern": "RGGB"}, {"white_level_dn": 4095.0}):
        assert not match(pidng, replace(pic2, **change))[0], change
    # two real model names that differ are two cameras, whatever the sensor
    assert not match(replace(pidng, model="imx477"), pic2)[0]
    assert match(Sensor("RaspberryPi", "imx296"), Sensor("Raspberry Pi", "IMX296"))[0]  # spelling only


def test_profile_show_prints_unknown_serial_and_not_calibrated(pi_profile):
    proc = run_cli("profile", "show", pi_profile)
    assert proc.returncode == 0, proc.stderr
    out = " ".join(proc.stdout.split())
    assert "serial unknown" in out and "serial None" not in out
    assert "not calibrated: dark current (bias frames only)" in out
    proc = run_cli("report", pi_profile, "-o", pi_profile.with_suffix(".html"))
    assert proc.returncode == 0, proc.stderr
    html = pi_profile.with_suffix(".html").read_text()
    assert "bias only; dark current not calibrated" in html and "Dark current: calibrated" not in html
    assert json.loads(run_cli("profile", "show", pi_profile, "--json").stdout)["camera"]["serial"] is None

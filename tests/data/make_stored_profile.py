"""Write the stored profile, photo and expected radiance of ``tests/models/test_stored_profile.py``.

Run once with the camcal whose output is to be kept (``python tests/data/make_stored_profile.py``); the test
then checks that every later camcal loads that profile and applies it to that photo with the same numbers.
Written on 2026-11-28 by camcal 0.x (profile schema 1.3), before the structure rework of issue 17.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

from camcal.apply.photo import apply
from camcal.calibrate.run import calibrate_session
from camcal.io.read import load_frame
from camcal.models.profile import load_profile, save_profile
from camcal.models.spectra import planck_radiance
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, write_session

HERE = Path(__file__).resolve().parent


def main() -> None:
    cam = SyntheticCamera(SensorParams(width=96, height=64, seed=5))
    with tempfile.TemporaryDirectory() as tmp:
        plan = SessionPlan(n_bias=4, n_dark=2, n_flat=3, linearity_steps=12, linearity_jpeg=False, sweep_jpeg=False,
                           sweep_step_nm=20.0, n_sweep=1)
        session = write_session(Path(tmp) / "S", cam, plan)
        profile, _ = calibrate_session(session)
        save_profile(profile, HERE / "stored.camcal")
    spectrum = 0.02 * planck_radiance(5000.0) / planck_radiance(5000.0).max()
    photo = cam.write_dng(HERE / "stored_photo.dng", Scene.uniform(spectrum), exposure_s=0.004,
                          rng=np.random.default_rng(11))
    image = apply(load_frame(photo), load_profile(HERE / "stored.camcal"))
    np.savez_compressed(HERE / "stored_expected.npz", **{k: np.asarray(v) for k, v in image.channels.items()})
    shutil.rmtree(HERE / "__pycache__", ignore_errors=True)


if __name__ == "__main__":
    main()

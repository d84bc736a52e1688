"""The valid base of the bad-input corpus: a small session, what the stages make of it, and valid files of each kind.

Built once per test run (:func:`tests.conftest.corpus_base`) and read by ``tests/cli/test_bad_inputs.py`` and
``tests/io/test_limits.py``, which derive every damaged input from it in their own folders. :func:`run_main` runs
the CLI in-process as a user sees it.
"""

from __future__ import annotations

import contextlib
import io
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from camcal.cli import main
from camcal.io.exr import write_exr
from camcal.synth.camera import SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, write_session

DARK0 = "dark_002.000s_00.dng"  # the frame replaced by damaged images in folder consumers


@dataclass
class Base:
    root: Path
    session: Path
    dark_json: Path
    profile: Path
    files: dict[str, bytes] = field(default_factory=dict)
    """Valid source bytes by kind: dng, jpeg, tiff, exr, profile, water_sub, water_ref (radiance EXRs)."""


def run_main(argv: list[str], env: dict[str, str] | None = None) -> tuple[int, str, str]:
    """Run the CLI in-process: (exit code, stdout, stderr incl. Python warnings as the interpreter shows them)."""
    out, err = io.StringIO(), io.StringIO()
    saved = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
                warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("default")
            for cat in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
                warnings.filterwarnings("ignore", category=cat)
            code = main([str(a) for a in argv])
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    shown = "".join(warnings.formatwarning(w.message, w.category, w.filename, w.lineno) for w in caught)
    return code, out.getvalue(), err.getvalue() + shown


WATER_SHAPE = (32, 48)  # the half-resolution radiance maps `camcal apply` makes of a 96x64 photo


def water_exrs(folder: Path, shape: tuple[int, int] = WATER_SHAPE, **pixels: np.ndarray) -> dict[str, bytes]:
    """A valid pair of radiance EXRs for ``camcal water invert`` (channels L663 and R, as apply writes).

    The submerged disk is 0.3 times as bright as the reference: a ratio of 0.3 at 20 cm inverts to a finite
    concentration with every model (the refined model's clear water gives 0.43 there: a ratio of 0.5 would be
    above clear water, no valid pixel, an error). ``pixels`` replace the L663 and R pixels of the named image.
    """
    ref = np.linspace(0.1, 1.0, shape[0] * shape[1], dtype=np.float32).reshape(shape)
    images = {"sub": 0.3 * ref, "ref": ref, **pixels}
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for name, img in images.items():
        p = write_exr(folder / f"{name}.exr", {"L663": img, "R": img}, {"source": f"{name} (corpus)"})
        out[name] = p.read_bytes()
    return out


def build_base(root: Path) -> Base:
    """Write the base into ``root``: the session, its dark model and profile, a TIFF and a pair of radiance EXRs."""
    cam = SyntheticCamera(SensorParams(width=96, height=64))
    plan = SessionPlan(n_bias=3, n_dark=2, dark_exposures_s=(2.0, 16.0), n_flat=3, linearity_steps=9,
                       sweep_step_nm=50.0, n_sweep=1)
    session = write_session(root / "S", cam, plan)
    dark_json = root / "models" / "dark.json"
    code, _, err = run_main(["dark", session / "dark", "--bias", session / "bias", "-o", dark_json, "-j", "1"])
    assert code == 0, err
    profile = root / "models" / "p.camcal"
    code, _, err = run_main(["calibrate", session, "-o", profile, "-j", "1"])
    assert code == 0, err
    tiff = root / "rgb.tif"
    spec = oiio.ImageSpec(64, 64, 3, oiio.UINT16)
    spec.attribute("compression", "none")  # 24 kB: truncations at 1 kB really cut the pixel data
    out = oiio.ImageOutput.create(str(tiff))
    assert out.open(str(tiff), spec)
    assert out.write_image(np.random.default_rng(0).integers(0, 60000, (64, 64, 3)).astype(np.uint16))
    out.close()
    water_exrs(root / "water")
    return load_base(root)


def load_base(root: Path) -> Base:
    """The :class:`Base` that :func:`build_base` wrote into ``root`` (read back from its files)."""
    session, models = root / "S", root / "models"
    files = {"dng": (session / "dark" / DARK0).read_bytes(),
             "jpeg": (session / "linearity" / "lin_004.jpg").read_bytes(),
             "tiff": (root / "rgb.tif").read_bytes(), "exr": (models / "dark.maps.exr").read_bytes(),
             "profile": (models / "p.camcal").read_bytes(),
             **{f"water_{name}": (root / "water" / f"{name}.exr").read_bytes() for name in ("sub", "ref")}}
    return Base(root, session, models / "dark.json", models / "p.camcal", files)

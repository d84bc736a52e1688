"""Shared fixtures: synthetic cameras and sessions written once per test run."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from camcal.synth.camera import SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, write_session

# CI runs the property tests on a fixed, derandomised sequence of examples, so a submission's CI result
# does not depend on luck; local runs keep exploring new examples.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.load_profile("ci" if os.environ.get("CI") else "default")


@pytest.fixture(scope="session")
def camera() -> SyntheticCamera:
    return SyntheticCamera(SensorParams())


@pytest.fixture(scope="session")
def session_dir(tmp_path_factory, camera) -> Path:
    """A full synthetic session (RGGB, 14-bit, 384x256), written once."""
    return write_session(tmp_path_factory.mktemp("session") / "S", camera, SessionPlan())


@pytest.fixture(scope="session")
def truth(session_dir) -> dict:
    return json.loads((session_dir / "truth.json").read_text())


@pytest.fixture(scope="session")
def profile_path(session_dir, tmp_path_factory) -> Path:
    """The profile calibrated from ``session_dir`` by the real CLI (written once per test worker)."""
    out = tmp_path_factory.mktemp("profile") / "cam.camcal"
    proc = run_cli("calibrate", session_dir, "-o", out)
    assert proc.returncode == 0, proc.stderr
    return out


def run_cli(*args: str, cwd: Path | None = None, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """Run the real CLI in a subprocess (what a user sees, exit code and all); ``env`` adds variables."""
    return subprocess.run([sys.executable, "-m", "camcal", *map(str, args)], capture_output=True, text=True, cwd=cwd,
                          timeout=600, env=None if env is None else {**os.environ, **env})


def assert_one_line_error(proc: subprocess.CompletedProcess, *fragments: str, code: int = 2) -> None:
    assert proc.returncode == code, (proc.returncode, proc.stdout, proc.stderr)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for frag in fragments:
        assert frag in lines[0], (frag, lines[0])


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)

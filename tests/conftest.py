"""Shared fixtures: synthetic cameras and sessions written once per test run."""

from __future__ import annotations

import contextlib
import fcntl
import io
import json
import os
import shutil
import subprocess
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from camcal.cli import main
from camcal.synth.camera import SensorParams, SyntheticCamera
from camcal.synth.phone import write_phone_photos
from camcal.synth.session import SessionPlan, write_session
from tests.corpus import Base, build_base, load_base

# CI runs the property tests on a fixed, derandomised sequence of examples, so a submission's CI result
# does not depend on luck; local runs keep exploring new examples.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.load_profile("ci" if os.environ.get("CI") else "default")


@pytest.fixture(scope="session")
def camera() -> SyntheticCamera:
    return SyntheticCamera(SensorParams())


def shared_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """The folder ``name``, made by ``build(folder)`` once per test run and shared by every xdist worker.

    Under xdist each worker has its own session fixtures; an expensive, read-only input (the default session, its
    profile, the demo's output) is built by the first worker that asks for it, in the run's common temporary
    folder, under a file lock; the other workers wait for it and read the same files. A build that fails leaves no
    ``.done`` marker, so the next worker builds it again (and fails the same way, visibly). Without xdist this is
    an ordinary folder of the session's temporary directory. Tests must not write into it (they never did: each
    worker's copy used to be shared by all the tests of that worker)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the run's folder, common to gw0, gw1, ...
    folder, done = base / f"shared-{name}", base / f"shared-{name}.done"
    with open(base / f"shared-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not done.exists():
                shutil.rmtree(folder, ignore_errors=True)  # what a failed build left
                build(folder)
                done.touch()
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return folder


@pytest.fixture(scope="session")
def session_dir(tmp_path_factory, camera) -> Path:
    """A full synthetic session (RGGB, 14-bit, 384x256), written once per test run (shared by the workers)."""
    return shared_once(tmp_path_factory, "session", lambda d: write_session(d / "S", camera, SessionPlan())) / "S"


@pytest.fixture(scope="session")
def truth(session_dir) -> dict:
    return json.loads((session_dir / "truth.json").read_text())


@pytest.fixture(scope="session")
def profile_path(session_dir, tmp_path_factory) -> Path:
    """The profile calibrated from ``session_dir`` by the real CLI (written once per test run)."""

    def build(folder: Path) -> None:
        proc = run_cli("calibrate", session_dir, "-o", folder / "cam.camcal")
        assert proc.returncode == 0, proc.stderr

    return shared_once(tmp_path_factory, "profile", build) / "cam.camcal"


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """``camcal demo -o <folder>/camcal-demo`` (the README's first command) run once per test run by the real CLI:
    the demo's folder and the finished process (its exit code, stdout and stderr). tests/demo/test_demo.py checks the
    run; tests/test_docs_run.py runs the docs' examples on its files."""

    def build(folder: Path) -> None:
        folder.mkdir(parents=True)
        proc = run_cli("demo", "-o", folder / "camcal-demo")
        (folder / "returncode").write_text(str(proc.returncode))
        (folder / "stdout").write_text(proc.stdout)
        (folder / "stderr").write_text(proc.stderr)

    folder = shared_once(tmp_path_factory, "demo", build)
    proc = subprocess.CompletedProcess(["camcal", "demo", "-o", str(folder / "camcal-demo")],
                                       int((folder / "returncode").read_text()), (folder / "stdout").read_text(),
                                       (folder / "stderr").read_text())
    return folder / "camcal-demo", proc


@pytest.fixture(scope="session")
def phone_day(tmp_path_factory) -> Path:
    """A sunlit day of the synthetic phone (chart, flats, Secchi disk photos as DNG and HEIC, ``truth.json``),
    written once per test run (shared by the workers)."""
    return shared_once(tmp_path_factory, "phone-day", write_phone_photos)


@pytest.fixture(scope="session")
def corpus_base(tmp_path_factory) -> Base:
    """The bad-input corpus's valid base (:func:`tests.corpus.build_base`), built once per test run (shared by
    the workers); the corpus and the resource-limit tests derive their damaged inputs from it."""
    return load_base(shared_once(tmp_path_factory, "corpus-base", build_base))


#: The fixtures that many tests read and each take seconds to build, by the xdist worker that builds them first.
PREBUILT = {"gw0": ("profile_path", "corpus_base"), "gw1": ("demo_run", "phone_day")}


@pytest.fixture(scope="session", autouse=True)
def _prebuild(request) -> None:
    """Under xdist, each worker first builds its share of :data:`PREBUILT` (those the selected tests use), so the
    two workers build the shared inputs side by side instead of one waiting on the other's lock."""
    wanted = set().union(*(item.fixturenames for item in request.session.items))
    for name in PREBUILT.get(os.environ.get("PYTEST_XDIST_WORKER", ""), ()):
        if name in wanted:
            request.getfixturevalue(name)


def run_cli(*args: str, cwd: Path | None = None, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """Run the real CLI in this process (:func:`camcal.cli.main`, exit code, stdout and stderr as a user sees them).

    ``env`` adds variables; a run with ``env`` goes to a subprocess (:func:`run_cli_subprocess`), since camcal
    reads some variables once per process. ``cwd`` is the working directory of the run."""
    if env is not None:
        return run_cli_subprocess(*args, cwd=cwd, env=env)
    argv = [str(a) for a in args]
    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
            code = main(argv)
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(["camcal", *argv], code, out.getvalue(), err.getvalue())


def run_cli_subprocess(*args: str, cwd: Path | None = None,
                       env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """Run the real CLI in a subprocess (a fresh interpreter: start-up, exit codes, signals); ``env`` adds variables."""
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

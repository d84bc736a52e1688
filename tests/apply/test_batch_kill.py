"""A batch killed with SIGKILL leaves no worker behind, and its rerun completes it (issue 28).

The real CLI runs ``camcal apply --jobs 2`` in a subprocess; the parent is killed outright (as an
out-of-memory killer or a cluster scheduler does) once the first EXR is written. Processes are found
through /proc (Linux only).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from camcal.io.atomic import clear_stale
from camcal.io.exr import read_exr
from camcal.models.spectra import gaussian_line
from camcal.synth.camera import Scene
from tests.conftest import run_cli

N_PHOTOS = 24  # enough that two workers are still busy when the first EXR lands

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")


def _stat(pid: int) -> tuple[int, str] | None:
    """(parent pid, state) of a process, None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return int(fields[1]), fields[0]


def _descendants(root: int) -> set[int]:
    parents = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit() and (st := _stat(int(d.name))) is not None:
            parents[int(d.name)] = st[0]
    found, frontier = set(), {root}
    while frontier:
        frontier = {p for p, pp in parents.items() if pp in frontier} - found
        found |= frontier
    return found


def _exrs(folder: Path) -> list[Path]:
    """Finished EXRs (pathlib's glob also matches the hidden ``.<name>.<pid>-<random>.part.exr`` files)."""
    return [p for p in folder.glob("*.exr") if not p.name.startswith(".")]


def _alive(pid: int) -> bool:
    st = _stat(pid)
    return st is not None and st[1] != "Z"  # a zombie has exited (its new parent has not reaped it yet)


@pytest.fixture(scope="module")
def many_photos(tmp_path_factory, camera):
    d = tmp_path_factory.mktemp("kill-photos")
    rng = np.random.default_rng(28)
    for i in range(N_PHOTOS):
        spec = (1.0 + 0.05 * i) * gaussian_line(663.0, 5.0)
        camera.write_dng(d / f"k{i:02d}.dng", Scene.uniform(spec), exposure_s=0.02, iso=100, f_number=4.0, rng=rng)
    return d


def test_sigkill_leaves_no_worker_and_rerun_completes(tmp_path, profile_path, many_photos):
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "camcal", "apply", str(profile_path), str(many_photos),
                             "-o", str(out), "--jobs", "2", "--estimator", "narrowband"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while not _exrs(out):
            assert proc.poll() is None, "the batch ended before it could be killed"
            assert time.monotonic() < deadline, "no EXR written in 300 s"
            time.sleep(0.01)
        workers = _descendants(proc.pid)
        assert proc.poll() is None, "the batch ended before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert workers, "no worker process was seen"
    t_kill = time.monotonic()
    while any(_alive(p) for p in workers) and time.monotonic() - t_kill < 5.0:
        time.sleep(0.05)
    left = sorted(p for p in workers if _alive(p))
    for p in left:  # do not leave them to the rest of the suite
        os.kill(p, signal.SIGKILL)
    assert not left, f"processes still running 5 s after the parent was killed: {left}"
    n_before = len(_exrs(out))
    assert 0 < n_before < N_PHOTOS  # killed mid-batch

    # a temporary file of a writer that is gone (the killed parent's pid) is cleared by the rerun
    stale = out / f".k00.dng.{proc.pid}-deadbeef.part.exr"
    stale.write_bytes(b"half an EXR")
    rerun = run_cli("apply", profile_path, many_photos, "-o", out, "--jobs", "2", "--estimator", "narrowband")
    assert rerun.returncode == 0, rerun.stderr
    assert f"{N_PHOTOS - n_before} written, {n_before} already done" in rerun.stdout
    assert not [p for p in out.iterdir() if ".part" in p.name]
    for i in range(N_PHOTOS):  # every EXR is complete and holds its photo's radiance (1 % as test_batch.py)
        chans, meta = read_exr(out / f"k{i:02d}.dng.exr", ["L663_inband"])  # a line: its in-band radiance
        assert float(np.nanmean(chans["L663_inband"])) == pytest.approx(1.0 + 0.05 * i, rel=0.01)


def test_clear_stale_keeps_running_writers(tmp_path):
    target = tmp_path / "a.exr"
    mine = tmp_path / f".a.{os.getpid()}-0123abcd.part.exr"
    other = tmp_path / ".b.1-0123abcd.part.exr"  # another output's file is not looked at
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    gone = tmp_path / f".a.{child.pid}-0123abcd.part.exr"
    for p in (mine, other, gone):
        p.write_bytes(b"x")
    assert clear_stale(target) == 1
    assert mine.exists() and other.exists() and not gone.exists()


def test_clear_stale_removes_a_killed_writers_file_before_it_is_reaped(tmp_path):
    """A killed worker adopted by a process that has not reaped it yet is a zombie: ``kill(pid, 0)`` still
    succeeds, but it will never finish its write, so its temporary file is stale (a fresh-clone CI run
    once kept one)."""
    target = tmp_path / "a.exr"
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    try:
        deadline = time.monotonic() + 5.0
        while _alive(pid) and time.monotonic() < deadline:
            time.sleep(0.01)
        zombie = tmp_path / f".a.{pid}-0123abcd.part.exr"
        zombie.write_bytes(b"partial")
        assert clear_stale(target) == 1 and not zombie.exists()
    finally:
        os.waitpid(pid, 0)


def test_orphaned_worker_exits_by_itself(tmp_path):
    """A process that called die_with_parent exits when its parent is killed (the worker start-up rule)."""
    code = ("import os, subprocess, sys, time\n"
            "c = subprocess.Popen([sys.executable, '-c', 'import os, time; from camcal.apply.batch import "
            "die_with_parent; "
            "print(die_with_parent(os.getppid()), flush=True); time.sleep(60)'], stdout=subprocess.PIPE, text=True)\n"
            "print(c.pid, c.stdout.readline().strip(), flush=True); time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    try:
        pid_text, how = parent.stdout.readline().split()
    finally:
        parent.kill()
        parent.wait()
    child = int(pid_text)
    assert how == ("pdeathsig" if sys.platform.startswith("linux") else "poll")
    t0 = time.monotonic()
    while _alive(child) and time.monotonic() - t0 < 5.0:
        time.sleep(0.05)
    alive = _alive(child)
    if alive:
        os.kill(child, signal.SIGKILL)
    assert not alive

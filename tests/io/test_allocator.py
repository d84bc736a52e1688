"""camcal.io.allocator: frame-sized buffers are reused from the heap under camcal's policy, and the user's own
allocator settings stand."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import types

import pytest

from camcal.io import allocator

PROBE = """
import json, resource, sys, threading
import numpy as np
from camcal.io.allocator import use_frame_allocator
on = use_frame_allocator() if sys.argv[1] == "policy" else False
size_bytes = int(sys.argv[2])


def faults_of(fn):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    fn()
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


def in_thread(fn):
    t = threading.Thread(target=fn)
    t.start()
    t.join()


def touch():
    np.ones(size_bytes // 8)  # a buffer, touched, freed


if sys.argv[3] == "thread":  # freed by one thread, asked for again by another (a decode or plane pool)
    in_thread(touch)
    faults = faults_of(lambda: in_thread(touch))
else:
    touch()
    faults = faults_of(touch)
print(json.dumps({"on": on, "faults": faults}))
"""


def _probe(mode: str, size_bytes: int = 24_000_000, where: str = "main", **env: str) -> dict:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_ARENA_MAX", "CAMCAL_MALLOC")}
    proc = subprocess.run([sys.executable, "-c", PROBE, mode, str(size_bytes), where], capture_output=True,
                          text=True, check=True, env={**clean, **env})
    return json.loads(proc.stdout)


# a 24 MB mosaic-sized buffer, a 48 MB float64 plane of a 24 MP sensor, a 192 MB float64 (C, h, w) map; in the
# main thread and from one thread to another
@pytest.mark.parametrize(("size_bytes", "where"), [(24_000_000, "main"), (48_000_000, "main"),
                                                   (48_000_000, "thread"), (192_000_000, "thread")])
def test_a_freed_frame_buffer_is_reused_without_page_faults(size_bytes, where):
    """Under glibc's own policy a buffer of this size freed and asked for again is mapped afresh (above its
    mmap threshold, or in a thread's own arena, whose wholly free heap is unmapped): its pages are faulted in
    again (thousands of 4 KiB faults, or dozens of 2 MiB ones with transparent huge pages). Under camcal's
    policy the same request reuses the freed memory: (almost) no fault."""
    with_policy = _probe("policy", size_bytes, where)
    if not with_policy["on"]:
        pytest.skip("not glibc: the allocator policy does not apply")
    without = _probe("none", size_bytes, where)
    assert without["faults"] >= 10
    assert with_policy["faults"] < without["faults"] / 4


def test_an_older_glibc_gets_the_largest_threshold_it_takes(monkeypatch):
    """An older glibc refuses an mmap threshold above 32 MiB (``HEAP_MAX_SIZE / 2``): the policy falls back to
    32 MiB (and a trim threshold of twice that) instead of giving up or keeping glibc's dynamic threshold."""
    calls = []

    def mallopt(param: int, value: int) -> int:
        calls.append((param, value))
        return 0 if param == allocator.M_MMAP_THRESHOLD and value > 32 * 1024 * 1024 else 1

    libc = types.SimpleNamespace(mallopt=mallopt)  # the C library as ctypes.CDLL gives it: its mallopt
    monkeypatch.setattr(allocator.ctypes, "CDLL", lambda name: libc)
    monkeypatch.setattr(allocator, "_applied", [])
    for v in ("CAMCAL_MALLOC", *allocator.GLIBC_VARIABLES):
        monkeypatch.delenv(v, raising=False)
    assert allocator.use_frame_allocator() is True
    mib = 1024 * 1024
    assert calls == [(allocator.M_MMAP_THRESHOLD, 256 * mib), (allocator.M_MMAP_THRESHOLD, 32 * mib),
                     (allocator.M_TRIM_THRESHOLD, 64 * mib), (allocator.M_ARENA_MAX, 1)]
    calls.clear()
    assert allocator.use_frame_allocator() is True and calls == []  # once per process


@pytest.mark.parametrize("env", [{"MALLOC_TRIM_THRESHOLD_": "65536"}, {"MALLOC_MMAP_THRESHOLD_": "131072"},
                                 {"MALLOC_ARENA_MAX": "4"}, {"CAMCAL_MALLOC": "default"}])
def test_the_users_own_allocator_settings_stand(env):
    assert _probe("policy", **env)["on"] is False

"""camcal.allocator: frame-sized buffers are reused from the heap under camcal's policy, and the user's own
allocator settings stand."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

PROBE = """
import json, resource, sys
import numpy as np
from camcal.allocator import use_frame_allocator
on = use_frame_allocator() if sys.argv[1] == "policy" else False
a = np.ones(24_000_000 // 8)  # a 24 MB buffer, touched, freed
del a
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
b = np.ones(24_000_000 // 8)  # the next frame's buffer of the same size
faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
print(json.dumps({"on": on, "faults": faults}))
"""


def _probe(mode: str, **env: str) -> dict:
    clean = {k: v for k, v in os.environ.items() if k not in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_",
                                                               "CAMCAL_MALLOC")}
    proc = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, check=True,
                          env={**clean, **env})
    return json.loads(proc.stdout)


def test_a_freed_frame_buffer_is_reused_without_page_faults():
    """Under glibc's own policy a 24 MB buffer freed and asked for again is mapped afresh: its pages are
    faulted in again (thousands of 4 KiB faults, or a dozen 2 MiB ones with transparent huge pages). Under
    camcal's policy the same request reuses the freed memory: (almost) no fault."""
    with_policy = _probe("policy")
    if not with_policy["on"]:
        pytest.skip("not glibc: the allocator policy does not apply")
    without = _probe("none")
    assert without["faults"] >= 10
    assert with_policy["faults"] < without["faults"] / 4


@pytest.mark.parametrize("env", [{"MALLOC_TRIM_THRESHOLD_": "65536"}, {"MALLOC_MMAP_THRESHOLD_": "131072"},
                                 {"CAMCAL_MALLOC": "default"}])
def test_the_users_own_allocator_settings_stand(env):
    assert _probe("policy", **env)["on"] is False

"""The C allocator's policy in a camcal process: frame-sized buffers reused, not handed back and faulted in again.

camcal's arrays are large and short-lived: a 24 MP frame's mosaic (48 MB), its planes, masks and band
buffers (6-24 MB), allocated and freed once per frame. glibc's ``malloc`` serves a request above its *mmap
threshold* with a fresh ``mmap`` and returns it to the system when freed, so the next frame's buffer is new
memory again, whose every page the kernel must fault in and zero. The threshold starts at 128 KiB and rises
only when a mapped block of at most 32 MiB is freed, so whether a 24 MB buffer is reused depended on which
temporaries happened to be freed before it: removing two whole-frame temporaries from the frame checks made the
dark stacks of a 24 MP session 40 % slower (5.3 s to 7.4 s, twice the system time), as every later buffer was
mapped afresh.

:func:`use_frame_allocator` sets the policy once, explicitly: ``M_MMAP_THRESHOLD`` 32 MiB (glibc's largest)
and ``M_TRIM_THRESHOLD`` 64 MiB (free memory above that at the top of a heap goes back to the system), so
buffers up to 32 MiB are reused from the heap. Buffers above 32 MiB (a 24 MP mosaic) are still mapped and
unmapped each time. The command line sets it at start and batch workers when they start; a library user may
call it. A value set through glibc's own environment variables (``MALLOC_MMAP_THRESHOLD_``,
``MALLOC_TRIM_THRESHOLD_``, as a Dask nanny sets the latter) is left alone, and ``CAMCAL_MALLOC=default`` keeps
glibc's dynamic policy. Other C libraries (musl, macOS) are left as they are.

Measured on a 2-core machine (benchmarks/RESULTS.md, "calibrate"): a whole 24 MP calibration 30.0 s against
33.4 s under glibc's policy (medians of 3), its dark stacks 5.2 s against 7.4-9.7 s, at a 3 % higher peak
memory (3.64 GB against 3.53 GB); a batch worker's peak is unchanged (1.30 GB).

References
----------
``mallopt(3)``, Linux man-pages: ``M_MMAP_THRESHOLD``, ``M_TRIM_THRESHOLD`` and the dynamic mmap threshold.
"""

from __future__ import annotations

import ctypes
import os

M_TRIM_THRESHOLD = -1
"""``mallopt`` parameter number of the trim threshold (glibc ``malloc.h``)."""

M_MMAP_THRESHOLD = -3
"""``mallopt`` parameter number of the mmap threshold (glibc ``malloc.h``)."""

MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
"""Requests above this size are mapped afresh; glibc refuses a larger threshold on 64-bit systems
(``HEAP_MAX_SIZE / 2``)."""

TRIM_THRESHOLD_BYTES = 64 * 1024 * 1024
"""Free memory at the top of a heap kept for reuse, at most (glibc's dynamic policy uses twice the mmap
threshold, as here)."""

GLIBC_VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_")
"""glibc's environment variables for the same settings: when one is set, the user's (or Dask's) choice stands."""

_applied: list[bool] = []  # the policy is set once per process


def use_frame_allocator() -> bool:
    """Set the allocator policy of the module docstring in this process, once; True when it is in effect.

    False, with nothing changed: not glibc (no ``mallopt``), ``CAMCAL_MALLOC=default``, or one of
    :data:`GLIBC_VARIABLES` set in the environment.
    """
    if _applied:
        return _applied[0]
    ok = False
    if (os.environ.get("CAMCAL_MALLOC", "").strip().lower() != "default"
            and not any(os.environ.get(v) for v in GLIBC_VARIABLES)):
        try:
            mallopt = ctypes.CDLL(None).mallopt
        except (AttributeError, OSError, TypeError):  # no mallopt (macOS), no C library by name (Windows)
            mallopt = None
        if mallopt is not None:
            mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
            mallopt.restype = ctypes.c_int
            # mallopt returns 1 on success, 0 when it refuses the value
            ok = bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
                mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    _applied.append(ok)
    return ok

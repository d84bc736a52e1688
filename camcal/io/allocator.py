"""The C allocator's policy in a camcal process: frame-sized buffers reused, not handed back and faulted in again.

camcal's arrays are large and short-lived: a 24 MP frame's mosaic (48 MB), its planes (96 MB as float32), a
plane's float64 temporaries (48 MB), the fits' float64 maps (192 MB), allocated and freed once per frame or per
plane. glibc's ``malloc`` serves a request above its *mmap threshold* with a fresh ``mmap`` and returns it to
the system when freed, so the next buffer of that size is new memory again, whose every page the kernel must
fault in and zero. So does a request made in a thread that has its own *arena*: a thread arena's heaps are at
most 64 MiB, and a heap left wholly free is unmapped, whatever the thresholds. Zeroing fresh pages is a large
part of a calibration's CPU time, more so on a virtual machine that hands free pages back to its host
(benchmarks/RESULTS.md, "calibrate" and "dark", has the figures). A buffer the process keeps and reuses costs
neither.

:func:`use_frame_allocator` sets the policy once, explicitly:

- ``M_MMAP_THRESHOLD`` 256 MiB (:data:`MMAP_THRESHOLD_BYTES`): buffers up to a 24 MP float64 (C, h, w) map come
  from the heap and are reused (glibc 2.36 takes it). A glibc that refuses it (older ones refused more than
  ``HEAP_MAX_SIZE / 2``, 32 MiB on 64-bit systems) is given 32 MiB (:data:`FALLBACK_MMAP_THRESHOLD_BYTES`);
- ``M_TRIM_THRESHOLD`` twice that (:data:`TRIM_FACTOR`, glibc's own ratio): free memory above it at the
  top of the heap goes back to the system;
- ``M_ARENA_MAX`` 1 (:data:`ARENA_MAX`): every thread allocates from the main heap, so a buffer freed by one
  decode or plane thread is reused by the next, in any thread. camcal's threads allocate a few large buffers
  each, not many small ones (Python's own small objects have their own allocator), so they rarely wait on the
  one arena's lock.

The command line sets it at start and batch workers when they start (before any other thread); a library user
may call it, best before starting threads. A value set through glibc's own environment variables
(:data:`GLIBC_VARIABLES`; a Dask nanny sets ``MALLOC_TRIM_THRESHOLD_``) leaves the whole policy alone, and
``CAMCAL_MALLOC=default`` keeps glibc's dynamic policy. Other C libraries (musl, macOS) are left as they are.

Why: with the policy a calibration takes far fewer page faults and much less system time at the same peak
memory; a batch worker's peak is a little higher (freed buffers stay in the heap for the next photo) and still
flat in the number of photos (benchmarks/RESULTS.md, "calibrate" and "apply").

References
----------
``mallopt(3)``, Linux man-pages: ``M_MMAP_THRESHOLD``, ``M_TRIM_THRESHOLD``, ``M_ARENA_MAX`` and the dynamic mmap
threshold; glibc ``malloc/arena.c`` (``heap_trim``: a wholly free thread heap is unmapped).
"""

from __future__ import annotations

import ctypes
import os

M_TRIM_THRESHOLD = -1
"""``mallopt`` parameter number of the trim threshold (glibc ``malloc.h``)."""

M_MMAP_THRESHOLD = -3
"""``mallopt`` parameter number of the mmap threshold (glibc ``malloc.h``)."""

M_ARENA_MAX = -8
"""``mallopt`` parameter number of the largest number of arenas (glibc ``malloc.h``)."""

MMAP_THRESHOLD_BYTES = 256 * 1024 * 1024
"""Requests above this size are mapped afresh (each time); below it they come from the heap."""

FALLBACK_MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
"""The mmap threshold where glibc refuses :data:`MMAP_THRESHOLD_BYTES` (the largest older versions take on
64-bit systems: ``HEAP_MAX_SIZE / 2``)."""

TRIM_FACTOR = 2
"""The trim threshold in mmap thresholds: free memory at the top of the heap kept for reuse, at most (twice the
mmap threshold in effect, as glibc's dynamic policy keeps it)."""

ARENA_MAX = 1
"""Arenas: one, the main heap, shared by every thread (see the module docstring)."""

GLIBC_VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_ARENA_MAX")
"""glibc's environment variables for the same settings: when one is set, the user's (or Dask's) choice stands,
and camcal changes none of them."""

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
            mmap_bytes = next((b for b in (MMAP_THRESHOLD_BYTES, FALLBACK_MMAP_THRESHOLD_BYTES)
                               if mallopt(M_MMAP_THRESHOLD, b)), 0)
            ok = (mmap_bytes > 0 and bool(mallopt(M_TRIM_THRESHOLD, TRIM_FACTOR * mmap_bytes))
                  and bool(mallopt(M_ARENA_MAX, ARENA_MAX)))
    _applied.append(ok)
    return ok

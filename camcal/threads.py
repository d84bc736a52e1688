"""The one rule for how many threads camcal uses.

``CAMCAL_THREADS`` (a whole number) overrides everything; otherwise the cores this process may run on
(``os.sched_getaffinity``), at most :data:`MAX_DEFAULT_THREADS` (memory bandwidth, not cores, limits the
arithmetic beyond that). An explicit request (``--jobs``) is honoured but never above the usable cores.
Decoding (LibRaw), NumPy and OpenImageIO release the GIL, so threads, not processes, are what camcal uses
inside one process; a batch of photos divides the cores among its worker processes.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from camcal.errors import CamcalError

T = TypeVar("T")
R = TypeVar("R")

MAX_DEFAULT_THREADS = 4
"""Threads used by default, at most."""

SMALL_FRAME_PIXELS = 250_000
"""Below this many pixels per frame, frames are decoded in one thread unless more are asked for explicitly.

Reading a small frame is mostly Python holding the GIL (EXIF, checks, small numpy calls), so a pool's hand-off
costs more than the decode it overlaps. Measured (``benchmarks/bench_threads.py``, RESULTS.md "Start-up"):
2 threads take 1.08x the time of one at 320x240, 0.82x at 640x480, 0.60x at 1456x1088, 0.51x at 2900x2000."""


def usable_cores() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def default_threads() -> int:
    """``CAMCAL_THREADS`` if set, else the usable cores, at most :data:`MAX_DEFAULT_THREADS`.

    Raises
    ------
    CamcalError
        ``CAMCAL_THREADS`` is not a whole number.
    """
    env = os.environ.get("CAMCAL_THREADS", "").strip()
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            raise CamcalError(f"CAMCAL_THREADS must be a whole number of threads, got {env!r}") from None
    return max(1, min(MAX_DEFAULT_THREADS, usable_cores()))


def thread_count(requested: int | None = None, work_items: int | None = None,
                 frame_pixels: int | None = None) -> int:
    """Threads for one job: ``requested`` (capped at the usable cores) or :func:`default_threads`, and never
    more than ``work_items`` (the frames or bands there are to share out).

    ``requested=None`` (automatic) with ``frame_pixels`` below :data:`SMALL_FRAME_PIXELS` gives one thread,
    unless ``CAMCAL_THREADS`` is set; an explicit request is honoured whatever the frame size."""
    if requested is None:
        small = frame_pixels is not None and frame_pixels < SMALL_FRAME_PIXELS
        n = 1 if small and not os.environ.get("CAMCAL_THREADS", "").strip() else default_threads()
    else:
        n = max(1, min(int(requested), usable_cores()))
    if work_items is not None:
        n = min(n, max(1, int(work_items)))
    return n


def thread_map(fn: Callable[[T], R], items: Iterable[T], threads: int, name: str = "camcal") -> list[R]:
    """``[fn(x) for x in items]``, in order, on up to ``threads`` threads (a plain loop for one thread or item).

    The first error of ``fn`` is raised, as the loop would raise it. numpy, LibRaw, OpenImageIO and hashlib
    release the GIL, so bands of an array, planes or files share the cores this way."""
    items = list(items)
    if threads <= 1 or len(items) < 2:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(max_workers=min(threads, len(items)), thread_name_prefix=name) as pool:
        return list(pool.map(fn, items))


def run_bands(work: Callable[[int, int], object], size: int, band: int, threads: int | None = None,
              name: str = "camcal") -> None:
    """Call ``work(start, stop)`` for the consecutive bands of ``band`` items that cover ``range(size)``, on up to
    ``threads`` threads (default :func:`thread_count` for that many bands; :func:`thread_map`): the one band
    runner of the stages that split an array into rows or chunks so that a band's temporaries stay in the CPU
    cache while numpy releases the GIL."""
    bands = [(s, min(s + band, size)) for s in range(0, size, max(1, int(band)))]
    thread_map(lambda b: work(*b), bands, thread_count(work_items=len(bands)) if threads is None else threads, name)

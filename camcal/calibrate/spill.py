"""The spill file of a median or sigma-clipped stack: its slots, and the statistics of its row bands.

A median or sigma-clipped stack spills each decoded frame to a private temporary file
(:func:`camcal.io.atomic.scratch_fd`: in memory while the stack fits in a quarter of the available memory, else on
disk), one slot per frame, and reads it back in row bands with explicit ``preadv`` calls (not ``np.memmap``, whose
touched pages count against the resident set). The band height shrinks as N grows, so the working set stays at
about ``band_mb`` megabytes whatever the number of frames; each band's statistics are
:func:`camcal.calibrate.band_stats.band_statistics`, the bands shared out by :func:`camcal.threads.thread_map`.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Collection

import numpy as np

from camcal.calibrate.band_stats import NETWORK_MAX_FRAMES, band_statistics
from camcal.errors import CamcalError
from camcal.frame import PLANES, plane_offsets, split_planes
from camcal.threads import thread_map

OPTIONAL_STATISTICS = ("mean", "variance", "variance_all", "mean_all")
"""The :class:`camcal.calibrate.stack.StackResult` statistics a caller may leave out (``StackOptions.statistics``);
``value`` and ``count`` always come."""


def count_dtype(n: int) -> type[np.signedinteger]:
    """The integer type of a stack's per-pixel frame count for ``n`` frames: int16 below 2¹⁵, else int32."""
    return np.int16 if n < 2**15 else np.int32


def read_exactly(fd: int, name: str, mv: memoryview, offset: int) -> None:
    """Fill ``mv`` from the spill file ``fd`` (named ``name`` in messages) at byte ``offset``."""
    got = 0
    while got < mv.nbytes:
        r = os.preadv(fd, [mv[got:]], offset + got)
        if r <= 0:
            raise CamcalError(f"{name} ended early (disk or memory full?)")
        got += r


def write_exactly(fd: int, name: str, mv: memoryview, offset: int) -> None:
    """Write all of ``mv`` to the spill file ``fd`` (named ``name`` in messages) at byte ``offset``; a failed
    write (no space left, a quota) is one line naming the spill and what to change."""
    done = 0
    try:
        while done < mv.nbytes:
            done += os.pwrite(fd, mv[done:], offset + done)
    except OSError as exc:
        raise CamcalError(f"cannot write the temporary stack file {name}: {exc.strerror or exc}; point TMPDIR to "
                          f"a folder with room for the stack (or let it stay in memory: CAMCAL_SPILL_MEMORY_MB)"
                          ) from None


def close_up(fd: int, name: str, order: list[int], nbytes: int) -> None:
    """Move the spilled slots ``order`` (ascending) of the spill file ``fd`` down to slots 0, 1, ... (the slots
    between are left out)."""
    if order == list(range(len(order))):
        return
    buf = bytearray(min(nbytes, 1 << 24))
    mv = memoryview(buf)
    for pos, i in enumerate(order):
        if i == pos:
            continue
        for off in range(0, nbytes, len(buf)):
            size = min(len(buf), nbytes - off)
            read_exactly(fd, name, mv[:size], i * nbytes + off)
            write_exactly(fd, name, mv[:size], pos * nbytes + off)


def read_slot(fd: int, name: str, pos: int, shape: tuple[int, int, int], dtype: np.dtype,
               pattern: str | None = None) -> np.ndarray:
    """The planes spilled at slot ``pos`` of the spill file ``fd`` (split out of the spilled mosaic when its CFA
    ``pattern`` is given)."""
    _, h, w = shape
    out = np.empty(shape if pattern is None else (2 * h, 2 * w), dtype)
    mv = memoryview(out.reshape(-1)).cast("B")
    read_exactly(fd, name, mv, pos * mv.nbytes)
    return out if pattern is None else split_planes(out, pattern, dtype=None)


BAND_MB = 16.0
"""Default working-set budget of one row band of a median or sigma-clipped stack, MB (4 bytes a value).

Each band costs a few hundred numpy calls (a 32-frame band: 382 for its sorting network, about 200 more for
its sums and clips), and each call hands the GIL from one band thread to the other: smaller bands hand it over
more often, larger ones no longer stay in a core's cache. With few frames the budget alone would give bands too
large for the cache: hence :data:`MAX_BAND_PIXELS` (benchmarks/RESULTS.md, "dark", has the measurements)."""

MAX_BAND_PIXELS = 1 << 18
"""The most pixels of each frame in one band (all C planes together): with few frames the budget
:data:`BAND_MB` would give bands whose planes no longer fit in a core's cache (see there)."""


def _band_rows(n: int, shape: tuple[int, int, int], band_mb: float) -> int:
    """Rows of a band of ``n`` frames of (C, h, w) planes: within ``band_mb`` MB at 4 bytes a value (so the
    working set does not grow with ``n``) and :data:`MAX_BAND_PIXELS` pixels a frame, at least one row."""
    c, h, w = shape
    return max(1, min(h, int(band_mb * 1e6 / (n * c * w * 4)), MAX_BAND_PIXELS // (c * w)))


def spilled_statistics(fd: int, name: str, n: int, shape: tuple[int, int, int], dtype: np.dtype, method: str,
                       sigma: float, jobs: int, band_mb: float, pattern: str | None = None,
                       wanted: Collection[str] = OPTIONAL_STATISTICS) -> tuple[np.ndarray | None, ...]:
    """Band-wise statistics of the (n, C, h, w) stack spilled to the file ``fd`` (``name`` in messages), or of the
    spilled (n, 2h, 2w) Bayer mosaics when their CFA ``pattern`` is given (C = 4): a band of h-rows ``y0:y1`` is
    then mosaic rows ``2 y0:2 y1`` of each frame, one read per frame, its statistics taken per mosaic pixel and
    split into the planes after. Gives value, mean, variance, count, variance_all and mean_all; of the optional
    ones (:data:`OPTIONAL_STATISTICS`) only those ``wanted`` are allocated and written, the others are None."""
    c, h, w = shape
    rows = _band_rows(n, shape, band_mb)
    bands = [(y0, min(h, y0 + rows)) for y0 in range(0, h, rows)]

    def new(*names: str) -> np.ndarray | None:
        return np.empty(shape, np.float32) if any(v in wanted for v in names) else None

    value = np.empty(shape, np.float32)
    count = np.empty(shape, count_dtype(n))
    if method == "sigma_clip":  # the clipped mean is the value; the unclipped statistics are their own arrays
        mean, var, var_all, mean_all = value, new("variance"), new("variance_all"), new("mean_all")
    else:  # median: the mean and the variance are those of all values
        mean = mean_all = new("mean", "mean_all")
        var = var_all = new("variance", "variance_all")
    item = dtype.itemsize
    # (source rows, source columns) of each output plane in a band's result: the plane itself, or its cells
    # of the mosaic
    cells = ([(slice(r, None, 2), slice(q, None, 2)) for r, q in map(plane_offsets(pattern).get, PLANES)]
             if pattern is not None else None)
    scratch = threading.local()  # each thread reads and sorts every band in the same two buffers

    def one(band: tuple[int, int]) -> None:
        y0, y1 = band
        if not hasattr(scratch, "raw"):
            scratch.raw = np.empty(n * c * rows * w, dtype)
            # a float32 band is sorted into this buffer; an integer band is sorted in place (its own type)
            scratch.work = (np.empty(n * c * rows * w, np.float32) if dtype == np.float32 and n <= NETWORK_MAX_FRAMES
                            else None)
        if cells is None:
            buf = scratch.raw[:n * c * (y1 - y0) * w].reshape(n, c, y1 - y0, w)
            for i in range(n):
                for k in range(c):
                    read_exactly(fd, name, memoryview(buf[i, k]).cast("B"), (((i * c + k) * h) + y0) * w * item)
        else:
            buf = scratch.raw[:n * c * (y1 - y0) * w].reshape(n, 2 * (y1 - y0), 2 * w)
            for i in range(n):
                # mosaic row 2 y0 of frame i
                read_exactly(fd, name, memoryview(buf[i]).cast("B"), (i * c * h * w + 4 * y0 * w) * item)
        results = band_statistics(buf, method, sigma, scratch.work)
        del buf
        outs = (value, mean, var, count, var_all, mean_all)
        for k, (out, res) in enumerate(zip(outs, results, strict=True)):
            if out is None or any(out is outs[j] for j in range(k)):  # not wanted, or written once already
                continue
            if cells is None:
                out[:, y0:y1] = res
            else:
                for p, (r, q) in enumerate(cells):
                    out[p, y0:y1] = res[r, q]

    thread_map(one, bands, jobs, "camcal-bands")
    return value, mean, var, count, var_all, mean_all

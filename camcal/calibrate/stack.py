"""Streaming combination of a stack of frames: mean, median, sigma-clipped mean.

Every calibration stage (bias, dark, flat, sweep, profile) averages N frames of one setting per pixel and per
channel plane. :func:`combine_frames` does it with each file decoded exactly once and a working set that does not
grow with N. A callback given each decoded frame's :class:`camcal.calibrate.screen.FrameFacts` says whether to keep
it (:class:`Keep`; a stage passes its :meth:`camcal.calibrate.screen.StageJudge.keep`, and by default a
:class:`camcal.calibrate.screen.StrictJudge` makes an unusable frame an error):

- ``method="mean"``: running sums of the deviations from the first frame and of their squares in float64 (the
  shifted-data algorithm, Chan, Golub & LeVeque 1983), one frame in memory at a time; a Bayer frame with the
  default planes is summed as its mosaic (the sums are per pixel) and the result split into its planes once, at
  the end.
- ``method="median"`` / ``"sigma_clip"``: each decoded frame is spilled (:mod:`camcal.calibrate.spill`; uint16 when
  the planes are integer DN, as with the default preprocessing, float32 otherwise; a Bayer frame with the default
  planes as its mosaic, split into planes band by band after the statistics, which are per pixel) and the
  statistics computed over row bands of the spill (:func:`camcal.calibrate.band_stats.band_statistics`, whose
  module states the clip).

Decoding can run in 2 threads (``jobs=2``; LibRaw releases the GIL) that write straight into the spill file (the
second frame is decoded while the first, which sets the stack's shape, is decoded in the calling thread); the band
statistics run in ``jobs`` threads (numpy releases the GIL).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Collection, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from camcal.calibrate.screen import FrameFacts, Keep, StrictJudge
from camcal.calibrate.spill import (
    BAND_MB,
    OPTIONAL_STATISTICS,
    close_up,
    count_dtype,
    read_slot,
    spilled_statistics,
    write_exactly,
)
from camcal.errors import CamcalError, TooFewFrames
from camcal.frame import PLANES, Exposure, Frame, plane_offsets, split_planes
from camcal.io.atomic import scratch_fd
from camcal.io.folders import folder_manifest, load_folder_frame
from camcal.threads import thread_count

METHODS = ("mean", "median", "sigma_clip")


@dataclass(frozen=True)
class StackOptions:
    """How :func:`combine_frames` combines a stack.

    Attributes
    ----------
    method : ``"mean"``, ``"median"`` or ``"sigma_clip"`` (sigma-clipped mean,
        :mod:`camcal.calibrate.band_stats`).
    sigma : clipping threshold in standard deviations (``sigma_clip`` only).
    jobs : threads to decode and to compute band statistics in; None: automatic, from the first frame's size
        (:func:`camcal.threads.thread_count`).
    band_mb : working-set budget of one row band, MB (median / sigma_clip); a band holds at most
        :data:`camcal.calibrate.spill.MAX_BAND_PIXELS` pixels of each frame whatever the budget.
    spill_dir : folder for the temporary spill file (default: the system temp folder).
    keep_frames : keep the planes of the first ``keep_frames`` frames (``StackResult.kept_planes``), so
        statistics of single frames need no second decode.
    statistics : the optional statistics to return (:data:`camcal.calibrate.spill.OPTIONAL_STATISTICS`), the
        others None; None: all. A stage asks only for what it uses: a median or sigma-clipped stack then neither
        allocates nor writes the others (a (C, h, w) float32 array each, 96 MB at 24 MP).
    """

    method: str = "mean"
    sigma: float = 3.0
    jobs: int | None = 1
    band_mb: float = BAND_MB
    spill_dir: str | Path | None = None
    keep_frames: int = 0
    statistics: Collection[str] | None = None

    def check(self) -> frozenset[str]:
        """Refuse an unknown method or statistic, or a sigma that is not a positive number; gives the statistics
        wanted."""
        if self.method not in METHODS:
            raise CamcalError(f"unknown combination method {self.method!r}; choose from {', '.join(METHODS)}")
        if not np.isfinite(self.sigma) or self.sigma <= 0:
            raise CamcalError(f"sigma must be a positive number, got {self.sigma}")
        wanted = frozenset(OPTIONAL_STATISTICS if self.statistics is None else self.statistics)
        if not wanted <= set(OPTIONAL_STATISTICS):
            raise CamcalError(f"unknown statistics {sorted(wanted - set(OPTIONAL_STATISTICS))}; choose from "
                              f"{', '.join(OPTIONAL_STATISTICS)} (value and count always come)")
        return wanted


class FrameRule(Protocol):
    """What :func:`combine_frames` asks of each frame: decode it with its facts, then keep it or not.

    ``load`` runs in the decode threads; ``keep`` in the calling thread, frame after frame (in completion order).
    ``stage`` names the frames in :class:`camcal.errors.TooFewFrames`."""

    stage: str

    def load(self, path: Path, loader: Callable[[Path], Frame]) -> tuple[Frame | None, FrameFacts]: ...

    def keep(self, path: Path, facts: FrameFacts) -> Keep: ...


@dataclass(frozen=True)
class StackResult:
    """Per-pixel statistics of a stack of N frames (channel first, (C, h, w)).

    Attributes
    ----------
    value : (C, h, w) float32
        Combined value per ``method`` (mean, median or sigma-clipped mean), in the
        units of the planes (DN for raw and processed frames).
    mean : (C, h, w) float32 or None
        Plain mean of the values used (the same array as ``value`` for ``mean`` and ``sigma_clip``); None when
        not asked for (``combine_frames(statistics=...)``), as are the other optional statistics below.
    variance : (C, h, w) float32 or None
        Temporal variance (ddof=1) of the values used, units squared; NaN where fewer
        than two values were used.
    count : (C, h, w) int16 or int32
        Number of values used per pixel.
    n_frames : int
    method : str
    exposures : tuple of Exposure
        Per frame, with the folder's ``frames.csv`` applied.
    paths : tuple of Path
    channel_names : tuple of str
        :data:`camcal.frame.PLANES` for raw frames, ``("R", "G", "B")`` for processed.
    kind : str
        ``"raw"`` or ``"processed"`` (of the first frame).
    cfa_pattern : str or None
    black_level_dn : tuple of float
        Black level per channel of the first frame, DN.
    white_level_dn : float
        Saturation level of the first frame, DN.
    frame_shape : tuple of int
        Full-resolution (height, width) of the frames.
    variance_all : (C, h, w) float32 or None
        Temporal variance (ddof=1) of *all* values, before clipping (``sigma_clip``);
        the same array as ``variance`` for ``mean`` and ``median``.
    mean_all : (C, h, w) float32 or None
        Plain mean of *all* values, before clipping (``sigma_clip``); the same array as ``mean``
        otherwise. With ``variance_all`` it gives the unclipped statistics EMVA 1288's spatial
        figures need (a clipped mean's variance is not the clipped values' variance over their count).
    kept_planes : tuple of (C, h, w) arrays
        The planes of the first ``keep_frames`` frames (in ``paths`` order) as combined (see
        :func:`combine_frames`), for statistics that need single frames; empty by default.
    """

    value: np.ndarray
    mean: np.ndarray | None
    variance: np.ndarray | None
    count: np.ndarray
    n_frames: int
    method: str
    exposures: tuple[Exposure, ...]
    paths: tuple[Path, ...]
    channel_names: tuple[str, ...]
    kind: str = "raw"
    cfa_pattern: str | None = None
    black_level_dn: tuple[float, ...] = field(default_factory=tuple)
    white_level_dn: float = float("nan")
    frame_shape: tuple[int, int] = (0, 0)
    variance_all: np.ndarray | None = None
    mean_all: np.ndarray | None = None
    kept_planes: tuple[np.ndarray, ...] = ()
    black_level_known: bool = True
    """False when the files state no black level (PNG, TIFF, FITS without one): ``black_level_dn`` is a placeholder."""


# --------------------------------------------------------------------------------------------
# decoding (in the calling thread and the decode threads)

@dataclass(frozen=True)
class _Meta:
    index: int
    exposure: Exposure
    kind: str
    cfa_pattern: str | None
    channel_names: tuple[str, ...]
    black: tuple[float, ...]
    white: float
    frame_shape: tuple[int, int]
    planes_shape: tuple[int, ...]
    layout: str = "bayer"
    black_known: bool = True


def _check_same(meta: _Meta, first: _Meta, path: Path) -> None:
    if meta.frame_shape != first.frame_shape or meta.planes_shape != first.planes_shape:
        h, w = meta.frame_shape
        h0, w0 = first.frame_shape
        raise CamcalError(f"frame size {w}x{h} differs from the first frame's {w0}x{h0}; "
                          "all frames of a stack must have one size", path)
    if meta.kind != first.kind:
        raise CamcalError(f"is a {meta.kind} image but the first frame is {first.kind}; do not mix them", path)
    if meta.cfa_pattern != first.cfa_pattern:
        raise CamcalError(f"CFA pattern {meta.cfa_pattern} differs from the first frame's {first.cfa_pattern}", path)


class _Decoder:
    """The decode settings and spill file of one :func:`combine_frames` call, passed to its decode threads.

    One object per call (no module-global state): two stacks combined at once in one process do not share it.
    """

    def __init__(self, manifest: dict | None, check: Callable[[Frame], None] | None,
                 preprocess: Callable[[Frame], np.ndarray] | None, keep_frames: int, rule: FrameRule) -> None:
        self.manifest = manifest
        self.rule = rule
        self.keep_frames = keep_frames
        self.check = check
        self.preprocess = preprocess
        self.manifests: dict[Path, dict] = {}  # per-folder frames.csv when no manifest is given
        self.first: _Meta | None = None
        self.spill_fd: int | None = None
        """The spill file's read-write descriptor (median/clip), None when nothing is spilled (mean)."""
        self.spill_name = ""
        """The spill file's name in messages."""
        self.spill_dtype = np.dtype(np.uint16 if preprocess is None else np.float32)
        self.mosaic = False
        """Spill (median/clip) or sum (mean) Bayer frames as their mosaic (set for a stack of default planes
        whose first frame is a Bayer mosaic; the pattern is the same in every frame, :func:`_check_same`)."""
        self.lock = threading.Lock()
        self.prefetched: dict[int, Future] = {}
        """Frames whose decode was started ahead (:meth:`prefetch`), by index."""

    def prefetch(self, pool: ThreadPoolExecutor, index: int, path: Path) -> None:
        """Start decoding frame ``index`` in ``pool`` now (the next frame, while the first is decoded in the
        calling thread: the second core is not left idle while the first frame sets the stack's shape)."""
        self.prefetched[index] = pool.submit(self.rule.load, path, self.load)

    def judged_load(self, index: int, path: Path) -> tuple[Frame | None, FrameFacts]:
        """The rule's :meth:`FrameRule.load` of frame ``index``, from :meth:`prefetch` when started."""
        with self.lock:
            ahead = self.prefetched.pop(index, None)
        return ahead.result() if ahead is not None else self.rule.load(path, self.load)

    def _manifest_for(self, path: Path) -> dict:
        if self.manifest is not None:
            return self.manifest
        with self.lock:
            folder = path.parent
            if folder not in self.manifests:
                self.manifests[folder] = folder_manifest(folder)
            return self.manifests[folder]

    def load(self, path: Path) -> Frame:
        return load_folder_frame(path, self._manifest_for(path))

    def planes_of(self, index: int, path: Path, frame: Frame,
                  want_planes: bool = True) -> tuple[_Meta, np.ndarray | None, np.ndarray | None]:
        """The check, the :class:`_Meta`, what to spill and the planes (preprocessed) of a decoded frame.

        What to spill (or, for ``mean``, to sum) is the Bayer mosaic itself when :attr:`mosaic` is set (no
        planes are split out of it: the statistics are per pixel, and split into planes once done), else the
        planes when there is a spill file, else None. The planes are None when not wanted and the mosaic is
        given."""
        if self.check is not None:
            self.check(frame)
        pre = self.preprocess
        if pre is None and self.mosaic and frame.layout == "bayer":
            spill = frame.data
            shape: tuple[int, ...] = (len(PLANES), spill.shape[0] // 2, spill.shape[1] // 2)
            # default planes keep the file's integer type (uint8/uint16): exact, half the bytes to move and spill
            planes = frame.planes(dtype=frame.data.dtype) if want_planes else None
        else:
            planes = (frame.planes(dtype=frame.data.dtype) if pre is None
                      else np.asarray(pre(frame), dtype=np.float32))
            if planes.ndim != 3:
                raise CamcalError(f"preprocessing gave an array of shape {planes.shape}, expected (C, h, w)", path)
            shape = tuple(planes.shape)
            spill = planes if self.spill_fd is not None else None
        meta = _Meta(index, frame.exposure, frame.kind, frame.cfa_pattern, frame.channel_names,
                     tuple(float(v) for v in frame.black_vector().ravel()), float(frame.white_level_dn), frame.shape,
                     shape, str(frame.layout), getattr(frame, "black_level_source", "file") != "unknown")
        return meta, spill, planes

    def spill_write(self, index: int, planes: np.ndarray) -> None:
        dtype = self.spill_dtype
        data = planes.astype(dtype, copy=False) if planes.dtype != dtype else planes
        buf = np.ascontiguousarray(data).view(np.uint8).reshape(-1)
        assert self.spill_fd is not None
        write_exactly(self.spill_fd, self.spill_name, memoryview(buf), index * buf.nbytes)

    def worker(self, item: tuple[int, str]) -> tuple[int, FrameFacts, _Meta | None, np.ndarray | None,
                                                     np.ndarray | None, CamcalError | None]:
        """Decode one frame in a pool thread: (index, facts, meta, planes, mosaic, error).

        A frame that cannot be used (unreadable, the stage check's error in its facts) goes no further. The others
        are checked (``check``, the first frame's size, kind and pattern: an error is returned, and raised only if
        the rule keeps the frame), then spilled (median/clip; their planes returned only when kept) or returned
        (mean: the planes, or the Bayer mosaic with the planes only when kept)."""
        assert self.first is not None  # set from the first frame used before any worker runs
        index, path = item[0], Path(item[1])
        frame, facts = self.judged_load(index, path)
        if frame is None or facts.check_error is not None:
            return index, facts, None, None, None, None
        spilled = self.spill_fd is not None
        try:
            meta, spill, planes = self.planes_of(index, path, frame,
                                                 want_planes=(not spilled and not self.mosaic)
                                                 or index < self.keep_frames)
            _check_same(meta, self.first, path)
        except CamcalError as exc:
            return index, facts, None, None, None, exc
        del frame
        if spilled and spill is not None:
            self.spill_write(index, spill)
            return index, facts, meta, planes if index < self.keep_frames else None, None, None
        return index, facts, meta, planes, spill, None



def combine_frames(
    paths: Sequence[str | Path],
    options: StackOptions = StackOptions(),  # noqa: B008 (frozen)
    *,
    preprocess: Callable[[Frame], np.ndarray] | None = None,
    manifest: dict | None = None,
    check: Callable[[Frame], None] | None = None,
    progress: Callable[[int, int], None] | None = None,
    rule: FrameRule | None = None,
) -> StackResult:
    """Combine frames per pixel and per channel plane, reading each file once.

    Parameters
    ----------
    paths : image files (RAW or processed), all of one size.
    options : :class:`StackOptions` (method, sigma, threads, band budget, spill folder, kept frames, statistics).
    preprocess : ``Frame -> (C, h, w)`` float32 array; default :meth:`Frame.planes`
        (raw: R, G1, G2, B planes in DN; processed: R, G, B).
    manifest : ``frames.csv`` rows (:func:`camcal.io.folders.folder_manifest`) applied to every file;
        None reads each file's own folder manifest.
    check : called with each decoded frame that is kept; raise :class:`CamcalError` to refuse it (an error
        whatever the rule).
    progress : ``progress(done, total)`` after each decoded frame.
    rule : the :class:`FrameRule` that decodes each frame with its facts and keeps it or not (a stage's
        :class:`camcal.calibrate.screen.StageJudge`): a frame not kept is not combined, as if it were not in
        ``paths`` (the result's ``paths``, ``exposures`` and ``n_frames`` are the frames used); a frame kept in
        place of one combined before (:attr:`camcal.calibrate.screen.Keep.replaces`, its copy) takes its place.
        Default: a :class:`camcal.calibrate.screen.StrictJudge`, for which an unreadable frame or a copy is an
        error.

    Returns
    -------
    StackResult

    Raises
    ------
    CamcalError
        No frames, bad options, frames of different sizes, kinds or CFA patterns, or whatever ``check`` raises.
    TooFewFrames
        Every frame left out.

    Notes
    -----
    The first usable frame is decoded in this thread (its size sets the threads and the stack's shape); the
    others in the pool. A copy kept in place of one combined before has the same pixels: the sums are unchanged
    and the slot (median/clip) or the kept planes pass to it. The spilled slots of the frames left out are closed
    up (the frames after them moved down) before the band statistics, so these see the frames used as if alone.
    """
    paths = tuple(Path(p) for p in paths)
    wanted = options.check()
    if not paths:
        raise CamcalError("no frames to combine")
    n = len(paths)
    rule = rule if rule is not None else StrictJudge(paths)
    dec = _Decoder(manifest, check, preprocess, options.keep_frames, rule)  # this call's settings, for the threads
    dec.mosaic = preprocess is None
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress:
            progress(done, n)

    jobs = options.jobs
    ahead = ThreadPoolExecutor(1, thread_name_prefix="camcal-decode") if n > 1 and thread_count(jobs, n) > 1 else None
    try:
        if ahead is not None:
            dec.prefetch(ahead, 1, paths[1])
        return _combine(paths, options, dec, rule, tick, wanted)
    finally:
        if ahead is not None:
            ahead.shutdown(wait=True, cancel_futures=True)


def _combine(paths: tuple[Path, ...], options: StackOptions, dec: _Decoder, rule: FrameRule,
             tick: Callable[[], None], wanted: frozenset[str]) -> StackResult:
    """:func:`combine_frames` once its arguments are checked and its decoder made."""
    method, keep_frames = options.method, options.keep_frames
    n = len(paths)
    start = 0
    first_meta = first_spill = first_planes = None
    while start < n:  # the first usable frame, in this thread
        path = paths[start]
        frame, facts = dec.judged_load(start, path)
        start += 1
        tick()
        if rule.keep(path, facts).keep:
            first_meta, first_spill, first_planes = dec.planes_of(  # type: ignore[arg-type]
                start - 1, path, frame, want_planes=(method == "mean" and not dec.mosaic) or keep_frames > 0)
            del frame
            break
    if first_meta is None:
        raise TooFewFrames(rule.stage, "frames", 1, 0, f"all {n} left out", paths[0].parent)
    first_index = start - 1
    dec.first = first_meta
    dec.mosaic = dec.mosaic and first_meta.layout == "bayer"
    jobs = thread_count(options.jobs, n, first_meta.frame_shape[0] * first_meta.frame_shape[1])
    c, h, w = first_meta.planes_shape
    index_of = {p: i for i, p in enumerate(paths)}
    used: dict[int, _Meta] = {first_index: first_meta}
    kept: dict[int, np.ndarray] = {first_index: first_planes} if keep_frames > 0 else {}
    # median / sigma_clip spill every frame to a private file (in memory when it fits), gone however the block ends
    spill_bytes = n * c * h * w * dec.spill_dtype.itemsize
    spill = (scratch_fd("camcal-stack-", spill_bytes, options.spill_dir) if method != "mean"
             else contextlib.nullcontext((None, "")))
    with spill as (spill_fd, spill_name):
        dec.spill_fd, dec.spill_name = spill_fd, spill_name
        try:
            acc = (_ShiftedSums(first_planes if first_spill is None else first_spill) if method == "mean"
                   else None)
            if acc is None:
                dec.spill_write(first_index, first_planes if first_spill is None else first_spill)
            del first_planes, first_spill
            items = [(i, str(paths[i])) for i in range(start, n)]
            for index, facts, meta, planes, mosaic, error in _run(items, jobs, dec.worker):
                tick()
                verdict = rule.keep(paths[index], facts)
                if not verdict.keep:
                    continue
                if error is not None:
                    raise error
                assert meta is not None
                used[index] = meta
                j = index_of.get(verdict.replaces) if verdict.replaces is not None else None
                if j in used:  # this frame's copy, combined already: the same pixels, now this frame's
                    del used[j]
                    if j in kept:
                        kept[index] = kept.pop(j)
                    continue
                if acc is not None:
                    acc.add(planes if mosaic is None else mosaic)
                if keep_frames > 0 and (len(kept) < keep_frames or index < max(kept)):
                    if planes is None and mosaic is not None:  # a summed mosaic: its planes split here
                        planes = split_planes(mosaic, first_meta.cfa_pattern, dtype=None)
                    if planes is not None:
                        kept[index] = planes
                        if len(kept) > keep_frames:
                            del kept[max(kept)]
            order = sorted(used)
            if acc is not None:
                value, mean, var, count = acc.result(first_meta.cfa_pattern if dec.mosaic else None)
                var_all, mean_all = var, mean
            else:
                close_up(spill_fd, spill_name, order, c * h * w * dec.spill_dtype.itemsize)
                pattern = first_meta.cfa_pattern if dec.mosaic else None
                for pos, i in enumerate(order[:keep_frames]):  # kept planes the threads did not return
                    if i not in kept:
                        kept[i] = read_slot(spill_fd, spill_name, pos, (c, h, w), dec.spill_dtype, pattern)
                value, mean, var, count, var_all, mean_all = spilled_statistics(
                    spill_fd, spill_name, len(order), (c, h, w), dec.spill_dtype, method, options.sigma, jobs,
                    options.band_mb, pattern, wanted)
        finally:
            dec.spill_fd = None
    n_used = len(order)
    n_type = count_dtype(n_used)
    mean, var, var_all, mean_all = (a if name in wanted else None for name, a in
                                    zip(OPTIONAL_STATISTICS, (mean, var, var_all, mean_all), strict=True))
    return StackResult(
        value=value, mean=mean, variance=var, count=count.astype(n_type, copy=False), n_frames=n_used,
        method=method,
        exposures=tuple(used[i].exposure for i in order), paths=tuple(paths[i] for i in order),
        channel_names=first_meta.channel_names, kind=first_meta.kind, cfa_pattern=first_meta.cfa_pattern,
        black_level_dn=first_meta.black, white_level_dn=first_meta.white, frame_shape=first_meta.frame_shape,
        black_level_known=first_meta.black_known,
        variance_all=var_all, mean_all=mean_all,
        kept_planes=tuple(kept[i] for i in order[:keep_frames] if i in kept),
    )


def _run(items: list[tuple[int, str]], jobs: int, worker: Callable[[tuple[int, str]], tuple]):
    """Yield ``worker(item)`` per item, decoding ``jobs`` frames at a time in threads.

    LibRaw and OpenImageIO release the GIL while reading and decoding, so threads
    give most of the gain of processes without forking a process that may hold
    other threads' locks (a forked pool deadlocked under pytest-xdist and Dask).
    At most ``2 * jobs`` frames are in flight, so memory does not grow with the
    number of frames; results come in completion order.
    """
    if jobs <= 1 or len(items) <= 1:
        for item in items:
            yield worker(item)
        return
    pending: set = set()
    queue = iter(items)
    with ThreadPoolExecutor(jobs, thread_name_prefix="camcal-decode") as pool:
        try:
            for item in queue:
                pending.add(pool.submit(worker, item))
                if len(pending) >= 2 * jobs:
                    done, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for fut in done:
                        yield fut.result()
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    yield fut.result()
        finally:
            for fut in pending:
                fut.cancel()


class _ShiftedSums:
    """Running per-pixel mean and variance as sums of deviations from the first frame, float64.

    With d = x − x₀ (x₀ the first frame): mean = x₀ + Σd / n and variance = (Σd² − (Σd)² / n) / (n − 1), the
    shifted-data algorithm (Chan, Golub & LeVeque 1983, "Algorithms for computing the sample variance", §4):
    exact for integer DN (every d and d² is a whole number well inside float64's 2⁵³), and free of the
    cancellation of plain sums for float planes, x₀ being close to the mean. Each frame is added in chunks of
    :data:`CHUNK` values, so the two temporaries stay in the cache: a third of the memory traffic of Welford's
    update (which needs five full-frame float64 temporaries), with the same result within float rounding.
    """

    CHUNK = 1 << 16

    def __init__(self, first: np.ndarray) -> None:
        self.shape = first.shape
        self.shift = np.array(first).reshape(-1)  # a copy in the frame's own type (uint16 DN: 2 bytes a value)
        self.n = 1
        self.s1 = np.zeros(self.shift.size, np.float64)
        self.s2 = np.zeros(self.shift.size, np.float64)

    def add(self, x: np.ndarray) -> None:
        x = np.asarray(x).reshape(-1)
        d = np.empty(min(self.CHUNK, x.size), np.float64)
        for i in range(0, x.size, self.CHUNK):
            j = min(x.size, i + self.CHUNK)
            dd = d[:j - i]
            np.subtract(x[i:j], self.shift[i:j], out=dd, dtype=np.float64)
            self.s1[i:j] += dd
            dd *= dd
            self.s2[i:j] += dd
        self.n += 1

    def result(self, pattern: str | None = None) -> tuple[np.ndarray, ...]:
        """Mean (twice: value and mean), variance and count; written straight into the planes of a summed
        mosaic when its CFA ``pattern`` is given (each value by the same arithmetic, no mosaic-sized copy)."""
        n = self.n
        if pattern is None:
            mean = np.empty(self.shift.size, np.float32)
            var = np.empty(self.shift.size, np.float32)
            for i in range(0, self.shift.size, self.CHUNK):
                j = min(self.shift.size, i + self.CHUNK)
                s1 = self.s1[i:j]
                mean[i:j] = self.shift[i:j] + s1 / n
                if n > 1:
                    var[i:j] = np.maximum(self.s2[i:j] - s1 * s1 / n, 0.0) / (n - 1)
            mean, var = mean.reshape(self.shape), var.reshape(self.shape)
        else:
            hh, ww = self.shape
            src = tuple(a.reshape(hh, ww) for a in (self.shift, self.s1, self.s2))
            mean = np.empty((len(PLANES), hh // 2, ww // 2), np.float32)
            var = np.empty(mean.shape, np.float32)
            rows = max(1, self.CHUNK // (ww // 2))
            for k, (r, q) in enumerate(map(plane_offsets(pattern).get, PLANES)):
                shift, s1p, s2p = (a[r::2, q::2] for a in src)
                for i in range(0, hh // 2, rows):
                    j = min(hh // 2, i + rows)
                    s1 = s1p[i:j]
                    mean[k, i:j] = shift[i:j] + s1 / n
                    if n > 1:
                        var[k, i:j] = np.maximum(s2p[i:j] - s1 * s1 / n, 0.0) / (n - 1)
        if n <= 1:
            var[:] = np.nan
        # the count in the type the stack keeps (int16 below 2¹⁵ frames): no int32 map to convert (96 MB at 24 MP)
        return mean, mean, var, np.full(mean.shape, n, count_dtype(n))



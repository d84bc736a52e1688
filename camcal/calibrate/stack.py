"""Streaming combination of a stack of frames: mean, median, sigma-clipped mean.

Every calibration stage (bias, dark, flat, sweep, profile) averages N frames of one
setting per pixel and per channel plane. :func:`combine_frames` does it with each
file decoded exactly once and a working set that does not grow with N (the frames themselves wait in the
median/clip spill file: in memory only while they fit in a quarter of what is available). Each frame is judged
as it is decoded (the stage's :class:`camcal.calibrate.screen.StageJudge` leaves an unusable frame out; by default a
:class:`camcal.calibrate.screen.StrictJudge` makes it an error):

- ``method="mean"``: running sums of the deviations from the first frame and of their squares in
  float64 (the shifted-data algorithm, Chan, Golub & LeVeque 1983), one frame in memory at a time; a Bayer
  frame with the default planes is summed as its mosaic (the sums are per pixel) and the result split into
  its planes once, at the end.
- ``method="median"`` / ``"sigma_clip"``: each decoded frame is spilled to a temporary
  raw file (:func:`camcal.io.atomic.scratch_fd`: in memory while the stack fits in a quarter of the available
  memory, else on disk; uint16 when the planes are integer DN, as with the default preprocessing,
  float32 otherwise; a Bayer frame with the default planes as its mosaic, split into planes band by band
  after the statistics, which are per pixel); the statistics are then computed over *row bands* read back with
  explicit ``readinto`` calls (not ``np.memmap``, whose touched pages count against the
  resident set). The band height shrinks as N grows so the working set stays at about
  ``band_mb`` megabytes whatever the number of frames.

Decoding can run in 2 threads (``jobs=2``; LibRaw releases the GIL) that write straight into the spill
file (the second frame is decoded while the first, which sets the stack's shape, is decoded in the calling
thread); the band statistics run in ``jobs`` threads (numpy releases the GIL). Each band is sorted along the
frame axis once; integer bands (the default planes) stay integer and a clip takes the values a pixel loses
off the sums of all its values, rank by rank from both ends (:class:`_SortedBand`).

Sigma clipping (``sigma_clip``) per pixel: pass 1 keeps values within ``sigma`` robust
standard deviations (interquartile range / 1.349) of the median; pass 2 keeps
values within ``sigma`` standard deviations (ddof=1) of the mean of the pass-1 values.
The combined value is the mean of the kept values; ``mean``/``variance``/``count`` are
those of the kept values too (for ``mean`` and ``median`` every value is used).
"""

from __future__ import annotations

import contextlib
import functools
import os
import threading
from collections.abc import Callable, Collection, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from camcal.calibrate.screen import FrameFacts, StageJudge, StrictJudge
from camcal.errors import CamcalError, TooFewFrames
from camcal.frame import PLANES, Exposure, Frame, plane_offsets, split_planes
from camcal.io.atomic import scratch_fd
from camcal.io.read import folder_manifest, load_folder_frame
from camcal.threads import thread_count

METHODS = ("mean", "median", "sigma_clip")
IQR_TO_SIGMA = 1.349
"""Interquartile range of a normal law in standard deviations."""


OPTIONAL_STATISTICS = ("mean", "variance", "variance_all", "mean_all")
"""The :class:`StackResult` statistics a caller may leave out (``combine_frames(statistics=...)``); ``value`` and
``count`` always come."""


def _working_count_dtype(n: int) -> type[np.integer]:
    """The integer type of a band's running per-pixel count of ``n`` values: one byte up to 255, so a mask is
    added or taken off as bytes (``mask.view(np.uint8)``) without numpy's buffered bool-to-int32 cast, several
    times slower than the arithmetic itself; int32 above."""
    return np.uint8 if n <= 255 else np.int32


def _count_dtype(n: int) -> type[np.signedinteger]:
    """The integer type of a stack's per-pixel frame count for ``n`` frames: int16 below 2¹⁵, else int32."""
    return np.int16 if n < 2**15 else np.int32


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
                 preprocess: Callable[[Frame], np.ndarray] | None, keep_frames: int, judge: StageJudge) -> None:
        self.manifest = manifest
        self.judge = judge
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
        self.prefetched[index] = pool.submit(self.judge.load, path, self.load)

    def judged_load(self, index: int, path: Path) -> tuple[object | None, FrameFacts]:
        """The judge's :meth:`camcal.calibrate.screen.StageJudge.load` of frame ``index``, from :meth:`prefetch` when
        started."""
        with self.lock:
            ahead = self.prefetched.pop(index, None)
        return ahead.result() if ahead is not None else self.judge.load(path, self.load)

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
        _write_exactly(self.spill_fd, self.spill_name, memoryview(buf), index * buf.nbytes)

    def worker(self, item: tuple[int, str]) -> tuple[int, FrameFacts, _Meta | None, np.ndarray | None,
                                                     np.ndarray | None]:
        """Decode one frame in a pool thread and give what its judge needs
        (:class:`camcal.calibrate.screen.StageJudge`); a frame the judge will leave out (unreadable, another camera, the
        stage check) goes no further, the others are spilled (median/clip; their planes returned only when kept) or
        returned (mean: the planes, or the Bayer mosaic with the planes only when kept). Gives (index, facts, meta,
        planes, mosaic)."""
        assert self.first is not None  # set from the first frame used before any worker runs
        index, path = item[0], Path(item[1])
        frame, facts = self.judged_load(index, path)
        if frame is None or facts.check_error is not None or self.judge.majority.mismatch(facts) is not None:
            return index, facts, None, None, None
        spilled = self.spill_fd is not None
        meta, spill, planes = self.planes_of(index, path, frame,  # type: ignore[arg-type]
                                             want_planes=(not spilled and not self.mosaic)
                                             or index < self.keep_frames)
        del frame
        _check_same(meta, self.first, path)
        if spilled and spill is not None:
            self.spill_write(index, spill)
            return index, facts, meta, planes if index < self.keep_frames else None, None
        return index, facts, meta, planes, spill


# --------------------------------------------------------------------------------------------
# band statistics


def _band_stats(x: np.ndarray, method: str, sigma: float, work: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """Statistics along axis 0 of an (N, ...) band (uint16 or float32; the band is overwritten).

    Returns value, mean, variance, count, the variance and the mean of all values. The band is
    sorted once (a sorting network, :func:`_sorted_planes`); everything else works on values shifted by the
    median in float32, so sums of squares keep their precision. Integer bands (DN) go through
    :func:`_integer_band_stats`, where a clip costs a few operations on the pixels that lose values; float32
    bands (preprocessed frames, NaN = masked) through :func:`_clipped_moments`.
    """
    if x.dtype.kind in "ui" and x.dtype.itemsize <= 2 and x.shape[0] <= NETWORK_MAX_FRAMES:
        return _integer_band_stats(x, method, sigma, work)
    n = x.shape[0]
    d = _sorted_float32(x, work)
    med = _sorted_median(d)
    d -= med
    sd = d.sum(axis=0, dtype=np.float32)
    sdd = np.einsum("i...,i...->...", d, d)
    mean_all = med + sd.astype(np.float64) / n
    var_all = _all_variance(sd, sdd, n)
    if method == "median":
        return med, mean_all, var_all, np.full(med.shape, n, np.int32), var_all, mean_all
    thr = _pass1_threshold(d, var_all, sigma)
    d2 = d.reshape(n, -1)  # (N, pixels) view
    m, v, cnt = _clipped_moments(d2, -thr.reshape(-1), thr.reshape(-1))
    thr = _pass2_threshold(v, med.reshape(-1), sigma)
    m, v, cnt = _clipped_moments(d2, m - thr, m + thr)
    m, v, cnt = (a.reshape(med.shape) for a in (m, v, cnt))
    mean = med + m.astype(np.float64)
    return mean, mean, v, cnt, var_all, mean_all


def _all_variance(sd: np.ndarray, sdd: np.ndarray, n: int) -> np.ndarray:
    """Variance (ddof=1) of n values from the sums of their deviations and of their squares (float32)."""
    if n < 2:
        return np.full(sd.shape, np.nan, np.float32)
    with np.errstate(invalid="ignore"):
        return np.maximum(sdd - sd * sd / n, 0) / (n - 1)


def _pass1_threshold(d: np.ndarray | Sequence[np.ndarray], var_all: np.ndarray, sigma: float) -> np.ndarray:
    """Pass 1 half-width: ``sigma`` robust standard deviations, the interquartile range of the sorted values
    ``d`` (axis 0) / 1.349, or the plain standard deviation where the interquartile range is 0."""
    scale = (_sorted_quantile(d, 0.75) - _sorted_quantile(d, 0.25)) / np.float32(IQR_TO_SIGMA)
    fallback = ~(scale > 0)
    if fallback.any():  # np.fmax(NaN, 0) = 0: a NaN variance (one value) gives 0
        scale[fallback] = np.fmax(np.sqrt(var_all[fallback]), 0)
    return (sigma * scale).astype(np.float32)


class _RankView:
    """Some ranks of a sorted band, indexable by rank (``view[k]``) with ``len`` N, for :func:`_sorted_quantile`."""

    def __init__(self, ranks: dict[int, np.ndarray], n: int) -> None:
        self.ranks = ranks
        self.n = n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, k: int) -> np.ndarray:
        return self.ranks[k]


def _pass2_threshold(v: np.ndarray, med: np.ndarray, sigma: float) -> np.ndarray:
    """Pass 2 half-width: ``sigma`` standard deviations (ddof=1) of the pass-1 values, plus 1e-6 of the median
    so that a pixel whose kept values are all equal keeps them."""
    sd = np.fmax(np.sqrt(v), 0)  # a NaN variance (fewer than 2 values) gives 0
    return sigma * sd.astype(np.float32, copy=False) + np.float32(1e-6) * np.abs(med)


DENSE_RANKS = 2
"""The first ranks from each end of a sorted band that a clip takes off every pixel at once (a 12 MP dark
band: 11-18 % of the pixels lose their lowest or highest value to pass 1, 2-4 % the second); deeper ranks are
followed pixel by pixel."""

EXACT_SQUARES = 2.0**22
"""Below this sum of squared deviations (DN²) a float32 sum of squares of an integer band is exact.

The deviations from the median of integer DN are multiples of 1/2 and their squares multiples of 1/4, which
float32 holds exactly up to 2²⁴ / 4 = 2²²; the terms are not negative, so every partial sum of any order of
summation is at most the computed total, and a total below 2²² proves every partial sum exact. The plain sums
are then exact too (their partial sums are at most √(N·2²²) ≤ 2¹⁵ in size for N ≤ 128)."""


def _integer_band_stats(x: np.ndarray, method: str, sigma: float,
                        work: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """:func:`_band_stats` of an integer (N, ...) band (uint8/uint16 DN; ``x`` is overwritten).

    The band is sorted by a sorting network in its own type (:class:`_SortedBand`); the sums of all
    deviations from the median and of their squares are taken plane by plane in float32 (``work``, when
    given, holds one plane). The values a clip removes from a sorted pixel are its lowest and highest ranks,
    so a clipping pass (:meth:`_SortedBand.clipped_moments`) takes them off those sums rank by rank from
    both ends, following only the pixels that lost the rank before (fewer at each rank: about 11 % of a
    12 MP dark band's pixels lose their lowest value to pass 1, 0.1 % their fourth lowest), instead of
    masking every value of every pixel (:func:`_clipped_moments`). The result is the same: bit for bit
    where the float32 sums are exact (all pixels whose squared deviations sum to less than
    :data:`EXACT_SQUARES`), and the exact value rounded once to float32 for the few pixels above it, which
    are summed in float64 instead.
    """
    n = x.shape[0]
    shape = x.shape[1:]
    band = _SortedBand(x, work)
    med, sd, sdd = band.med, band.sd, band.sdd
    mean_all = sd.astype(np.float64)
    mean_all /= n
    mean_all += med.astype(np.float64)  # converted once: numpy's mixed-type arithmetic is slower, same result
    var_all = _all_variance(sd, sdd, n)
    if method == "median":
        return tuple(a.reshape(shape) for a in (med, mean_all, var_all, np.full(med.size, n, np.int32), var_all,
                                                mean_all))
    thr = _pass1_threshold(_RankView(band.dev, n), var_all, sigma)
    m, v, cnt = band.clipped_moments(-thr, thr)
    thr = _pass2_threshold(v, med, sigma)
    m, v, cnt = band.clipped_moments(m - thr, m + thr)
    mean = m.astype(np.float64)
    mean += med.astype(np.float64)
    var_all, mean_all = var_all.reshape(shape), mean_all.reshape(shape)
    return mean.reshape(shape), mean.reshape(shape), v.reshape(shape), cnt.reshape(shape), var_all, mean_all


class _SortedBand:
    """An integer (N, ...) band sorted along axis 0 (flat planes), with the sums of all its values' deviations
    from their median and of their squares (float32, exact: see :data:`EXACT_SQUARES`)."""

    def __init__(self, x: np.ndarray, work: np.ndarray | None = None) -> None:
        n = x.shape[0]
        self.planes = planes = [p.reshape(-1) for p in _sorted_planes(x)]
        self.med = med = _sorted_median(planes)
        size = med.size
        # plane by plane, so a plane and the sums stay in the cache; the deviations of the first ranks from
        # each end are kept (each clip compares them with its bounds), and those of the quartiles
        self.sd = sd = np.zeros(size, np.float32)
        self.sdd = sdd = np.zeros(size, np.float32)
        square = np.empty(size, np.float32) if work is None else work.reshape(-1)[:size]
        ends = [*range(min(n, DENSE_RANKS)), *range(max(0, n - DENSE_RANKS), n)]
        kept_ranks = {*ends, *_quantile_ranks(n, 0.25), *_quantile_ranks(n, 0.75)}
        self.dev: dict[int, np.ndarray] = {}  # deviations of the ranks used again: the ends, the quartiles
        for k, plane in enumerate(planes):
            dev = np.empty(size, np.float32) if k in kept_ranks else square
            dev[...] = plane
            dev -= med  # exact: a whole DN less a whole or half DN
            sd += dev
            if k in kept_ranks:
                self.dev[k] = dev
            np.multiply(dev, dev, out=square)
            sdd += square
        self.loud = np.flatnonzero(sdd >= EXACT_SQUARES)
        self.loud_dev = np.empty((n, 0))
        if self.loud.size:  # hot pixels, cosmic rays: their sums again, exactly, in float64
            self.loud_dev = np.stack([p[self.loud] for p in planes]).astype(np.float64) - med[self.loud]
            sd[self.loud] = self.loud_dev.sum(axis=0)
            sdd[self.loud] = np.einsum("ij,ij->j", self.loud_dev, self.loud_dev)

    def clipped_moments(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mean, variance (ddof=1) and count of the deviations ``d`` from the median with ``lo <= d <= hi``.

        The same result as :func:`_clipped_moments` (masking every value). A sorted pixel loses its lowest
        ranks below ``lo`` and its highest above ``hi``: the :data:`DENSE_RANKS` first ranks from each end
        are compared for every pixel, each further rank only for the pixels that lost the one before, and
        the values lost are taken off the sums of all values. Exact in float32: every partial result is the
        sum of a subset of the pixel's values (or squares), at most the sum of them all, below
        :data:`EXACT_SQUARES`. The loud pixels above it are summed from their float64 deviations instead.
        """
        n = len(self.planes)
        s1 = self.sd.copy()
        s2 = self.sdd.copy()
        cnt = np.full(s1.shape, n, _working_count_dtype(n))  # one byte (n <= NETWORK_MAX_FRAMES)
        lost_rank = np.empty(s1.shape, bool)
        lost = np.empty(s1.shape, bool)
        lost_count = lost.view(np.uint8) if cnt.dtype == np.uint8 else lost  # what a lost mask takes off the count
        taken = np.empty(s1.shape, np.float32)
        dense = min(n, DENSE_RANKS)
        for ranks, bound, lost_of in ((range(n), lo, np.less), (range(n - 1, -1, -1), hi, np.greater)):
            # the first ranks from each end: many pixels lose them (a tenth of a dark's pixels lose the lowest),
            # so they are taken off every pixel at once (0 or the value); a NaN bound loses nothing here: see
            # "inverted" below
            for k, r in enumerate(ranks[:dense]):
                lost_of(self.dev[r], bound, out=lost_rank)
                if k:
                    lost &= lost_rank  # a rank is lost only if the rank before it is
                else:
                    lost[...] = lost_rank
                np.copyto(taken, lost)  # 0 or 1 (a plain cast; multiplying by the bool mask casts it slowly)
                taken *= self.dev[r]
                s1 -= taken
                taken *= taken
                s2 -= taken
                cnt -= lost_count
            idx = np.flatnonzero(lost)
            for r in ranks[dense:]:  # deeper ranks: only the pixels that lost the one before
                dev = self.planes[r][idx].astype(np.float32) - self.med[idx]
                keep_going = lost_of(dev, bound[idx])
                idx, dev = idx[keep_going], dev[keep_going]
                if not idx.size:
                    break
                s1[idx] -= dev
                s2[idx] -= dev * dev
                cnt[idx] -= 1
        with np.errstate(invalid="ignore"):
            inverted = ~(lo <= hi)
        if inverted.any():  # bounds that keep nothing (NaN, or lo > hi): no value is lost twice
            s1[inverted] = 0
            s2[inverted] = 0
            cnt[inverted] = 0
        if self.loud.size:
            d = self.loud_dev
            keep = (d >= lo[self.loud]) & (d <= hi[self.loud])
            s1[self.loud] = np.where(keep, d, 0).sum(axis=0)
            s2[self.loud] = np.where(keep, d * d, 0).sum(axis=0)
            cnt[self.loud] = keep.sum(axis=0)
        return _moments(s1, s2, cnt)


def _moments(s1: np.ndarray, s2: np.ndarray, cnt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and variance (ddof=1, NaN below 2 values) from the float32 sums of ``cnt`` deviations and of their
    squares."""
    # in float64 (the sums are float32, the count whole): converted once each, as numpy's mixed-type
    # arithmetic would convert them in every operation, several times slower, with the same result
    s1d, s2d, n = s1.astype(np.float64), s2.astype(np.float64), cnt.astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = s1d / n
        s1d *= m
        np.subtract(s2d, s1d, out=s2d)
        np.maximum(s2d, 0, out=s2d)
        n -= 1
        s2d /= n
    v = s2d.astype(np.float32)
    v[cnt <= 1] = np.nan
    return m.astype(np.float32), v, cnt


NETWORK_MAX_FRAMES = 128
"""Integer bands of up to this many frames are sorted by a sorting network, larger ones by :func:`numpy.sort`."""


@functools.cache
def _sorting_network(n: int) -> tuple[tuple[int, int], ...]:
    """Compare-exchange pairs of Batcher's odd-even merge sort for ``n`` inputs (any ``n``).

    Batcher, K. E. (1968), "Sorting networks and their applications", AFIPS Spring Joint Computer
    Conference 32, 307-314; the arbitrary-``n`` form drops the pairs that reach past ``n``
    (Knuth, TAOCP vol. 3, 5.3.4, exercise 12). 191 pairs for 32 inputs.
    """
    pairs = []
    p = 1
    while p < n:
        k = p
        while k >= 1:
            for j in range(k % p, n - k, 2 * k):
                for i in range(min(k, n - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    return tuple(pairs)


def _sorted_float32(x: np.ndarray, work: np.ndarray | None = None) -> np.ndarray:
    """The (N, ...) band sorted along axis 0, as float32 (``x`` is overwritten; ``work``, float32 of at least
    ``x.size`` values, is used for the result when given, so a thread reuses one buffer for all its bands).

    Integer and float32 bands of up to :data:`NETWORK_MAX_FRAMES` frames go through :func:`_sorted_planes`, then
    are converted to float32 plane by plane. Other float types, and more frames, use :func:`numpy.sort`.
    """
    n = x.shape[0]
    integer = x.dtype.kind in "ui"
    if (not integer and x.dtype != np.float32) or n > NETWORK_MAX_FRAMES:
        d = x if x.dtype == np.float32 else x.astype(np.float32)
        d.sort(axis=0)
        return d
    planes = _sorted_planes(x)
    d = np.empty(x.shape, np.float32) if work is None else work.reshape(-1)[:x.size].reshape(x.shape)
    for k, plane in enumerate(planes):
        d[k] = plane
    return d


def _sorted_planes(x: np.ndarray) -> list[np.ndarray]:
    """The planes ``x[0], x[1], ...`` of an (N, ...) integer or float32 band, sorted along axis 0 in their own
    type, as a list of N arrays (views of ``x`` and of one spare plane; ``x`` is overwritten).

    A sorting network of whole planes (:func:`_sorting_network`: per pair one ``np.minimum`` and one
    ``np.maximum`` over a plane, SIMD in the band's own 16-bit type): 2.5x faster than ``np.sort`` of the
    float32 band along axis 0 and 5x faster than ``np.sort`` of the uint16 band at 32 frames (numpy has no
    vectorised 16-bit sort on AVX2), with the same result (a sort is a sort). float32 bands (preprocessed
    frames, NaN = masked) use ``np.fmin`` for the low side: it keeps the number of a (number, NaN) pair low and
    ``np.maximum`` sends the NaN high, so a NaN ends last as with :func:`numpy.sort`.
    """
    low_of = np.minimum if x.dtype.kind in "ui" else np.fmin
    planes = list(x)
    spare = np.empty_like(planes[0])
    for i, j in _sorting_network(x.shape[0]):
        low = low_of(planes[i], planes[j], out=spare)
        spare = planes[i]
        np.maximum(spare, planes[j], out=planes[j])
        planes[i] = low
    return planes


def _clipped_moments(d2: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, variance (ddof=1) and count along axis 0 of the values of ``d2`` in ``[lo, hi]`` (float32).

    ``d2`` is (N, pixels), sorted along axis 0 (NaN last), so the values a pixel loses are its smallest and its
    largest (and its NaN): rows ``i0 <= i < i1``, where no pixel loses a value, are summed as they are (one
    pass, no mask); only the rows below ``i0`` and from ``i1`` up are masked, row by row (about 13 of 32 in a
    12 MP dark band, where some pixel of the band always clips deep). Same results as masking every row.

    A masked row adds its kept values as ``keep · value`` (the mask cast to 0 or 1, then multiplied: a quarter of
    the time of copying the values where kept), and its mask to the count as bytes (without numpy's buffered
    bool-to-int32 cast). The product is exact: the value where kept, a zero where lost. A lost value that is not
    a number (NaN: a masked pixel; ±inf) would give NaN: the few pixels with one (at an end of their sorted
    values) have their masked rows summed again, with the values copied where kept, in the same order.
    """
    n = d2.shape[0]
    i0 = 0
    while i0 < n and not (d2[i0] >= lo).all():  # "not >=": a NaN value (a masked pixel) or bound is lost too
        i0 += 1
    i1 = n
    while i1 > i0 and not (d2[i1 - 1] <= hi).all():
        i1 -= 1
    mid = d2[i0:i1]
    s1 = mid.sum(axis=0, dtype=np.float32)
    s2 = np.einsum("ij,ij->j", mid, mid)
    cnt = np.full(s1.shape, i1 - i0, _working_count_dtype(n))
    masked = (*range(i0), *range(i1, n))
    if not masked:
        return _moments(s1, s2, cnt)
    odd = np.flatnonzero(~(np.isfinite(d2[0]) & np.isfinite(d2[n - 1])))  # sorted: ±inf and NaN at the ends
    odd_sums = (s1[odd], s2[odd], cnt[odd])  # copies: the sums of the rows in the middle
    keep = np.empty(s1.shape, bool)
    keep_count = keep.view(np.uint8) if cnt.dtype == np.uint8 else keep  # what a keep mask adds to the count
    inside = np.empty(s1.shape, bool)
    row = np.empty_like(s1)
    for i in masked:
        np.greater_equal(d2[i], lo, out=keep)
        keep &= np.less_equal(d2[i], hi, out=inside)
        np.copyto(row, keep)  # 0 or 1
        with np.errstate(invalid="ignore"):  # 0 · ±inf (a lost infinity): NaN, summed again below
            row *= d2[i]
        s1 += row
        row *= row
        s2 += row
        cnt += keep_count
    if odd.size:
        sub, lo_odd, hi_odd = d2[:, odd], lo[odd], hi[odd]
        o1, o2, oc = odd_sums
        for i in masked:
            kept = (sub[i] >= lo_odd) & (sub[i] <= hi_odd)
            r = np.where(kept, sub[i], np.float32(0))  # not sub·kept: a lost NaN would make the sum NaN
            o1 += r
            r *= r
            o2 += r
            oc += kept.astype(oc.dtype)
        s1[odd], s2[odd], cnt[odd] = o1, o2, oc
    return _moments(s1, s2, cnt)


def _sorted_median(s: np.ndarray | Sequence[np.ndarray]) -> np.ndarray:
    """Median of sorted values along axis 0 (or of a list of sorted planes), float32."""
    n = len(s)
    if n % 2:
        return s[n // 2].astype(np.float32)
    return np.float32(0.5) * (s[n // 2 - 1].astype(np.float32) + s[n // 2].astype(np.float32))


def _quantile_ranks(n: int, q: float) -> tuple[int, int]:
    """The two ranks of ``n`` sorted values that :func:`_sorted_quantile` interpolates between."""
    lo = int(np.floor(q * (n - 1)))
    return lo, min(lo + 1, n - 1)


def _sorted_quantile(s: np.ndarray | Sequence[np.ndarray], q: float) -> np.ndarray:
    """Quantile of sorted values along axis 0 (linear interpolation, numpy's default).

    ``s``: an array, or anything that gives the sorted planes by rank (``s[k]``) and their number (``len``)."""
    n = len(s)
    lo, hi = _quantile_ranks(n, q)
    f = np.float32(q * (n - 1) - lo)
    return s[lo] + f * (s[hi] - s[lo])


# --------------------------------------------------------------------------------------------


BAND_MB = 16.0
"""Default working-set budget of one row band of a median or sigma-clipped stack, MB (4 bytes a value).

Each band costs a few hundred numpy calls (a 32-frame band: 382 for its sorting network, about 200 more for
its sums and clips), and each call hands the GIL from one band thread to the other: smaller bands hand it over
more often, larger ones no longer stay in a core's cache. With few frames the budget alone would give bands too
large for the cache: hence :data:`MAX_BAND_PIXELS` (benchmarks/RESULTS.md, "dark", has the measurements)."""

MAX_BAND_PIXELS = 1 << 18
"""The most pixels of each frame in one band (all C planes together): with few frames the budget
:data:`BAND_MB` would give bands whose planes no longer fit in a core's cache (see there)."""


def combine_frames(
    paths: Sequence[str | Path],
    *,
    method: str = "mean",
    sigma: float = 3.0,
    preprocess: Callable[[Frame], np.ndarray] | None = None,
    manifest: dict | None = None,
    check: Callable[[Frame], None] | None = None,
    jobs: int | None = 1,
    progress: Callable[[int, int], None] | None = None,
    band_mb: float = BAND_MB,
    spill_dir: str | Path | None = None,
    keep_frames: int = 0,
    judge: StageJudge | None = None,
    statistics: Collection[str] | None = None,
) -> StackResult:
    """Combine frames per pixel and per channel plane, reading each file once.

    Parameters
    ----------
    paths : image files (RAW or processed), all of one size.
    method : ``"mean"``, ``"median"`` or ``"sigma_clip"`` (sigma-clipped mean, see module docs).
    sigma : clipping threshold in standard deviations (``sigma_clip`` only).
    preprocess : ``Frame -> (C, h, w)`` float32 array; default :meth:`Frame.planes`
        (raw: R, G1, G2, B planes in DN; processed: R, G, B).
    manifest : ``frames.csv`` rows (:func:`camcal.io.read.folder_manifest`) applied to every file;
        None reads each file's own folder manifest.
    check : called with each decoded frame the judge keeps; raise :class:`CamcalError` to refuse it (an error
        whatever the judge).
    jobs : threads to decode and to compute band statistics in; None: automatic, from the first frame's size
        (:func:`camcal.threads.thread_count`).
    progress : ``progress(done, total)`` after each decoded frame.
    band_mb : working-set budget of one row band, MB (median / sigma_clip); a band holds at most
        :data:`MAX_BAND_PIXELS` pixels of each frame whatever the budget.
    spill_dir : folder for the temporary spill file (default: the system temp folder).
    keep_frames : keep the planes of the first ``keep_frames`` frames (``StackResult.kept_planes``), so
        statistics of single frames need no second decode.
    judge : the stage's :class:`camcal.calibrate.screen.StageJudge`: each frame is judged as it is decoded; a frame left
        out (unreadable, a copy, another camera, layout or size, the stage's check) is not combined, as if it
        were not in ``paths`` (the result's ``paths``, ``exposures`` and ``n_frames`` are the frames used).
        Raises :class:`camcal.errors.TooFewFrames` when every frame is left out. Default: a
        :class:`camcal.calibrate.screen.StrictJudge`, for which such a frame is an error.
    statistics : the optional statistics to return (:data:`OPTIONAL_STATISTICS`), the others None; default all.
        A stage asks only for what it uses: a median or sigma-clipped stack then neither allocates nor writes
        the others (a (C, h, w) float32 array each, 96 MB at 24 MP), and its memory peak is lower.

    Returns
    -------
    StackResult

    Raises
    ------
    CamcalError
        No frames, an unknown method, frames of different sizes, kinds or CFA patterns, or whatever ``check``
        raises; without a judge, an unreadable file or two frames with the same pixels (a copy).

    Notes
    -----
    The first usable frame is decoded in this thread (its size sets the threads and the stack's shape); the
    others in the pool. Copies: the judge keeps the first in file order
    (:meth:`camcal.calibrate.screen.StageJudge.decide`); when it comes after the copy already combined, the two have the
    same pixels: the sums are unchanged and the slot (median/clip) or the kept planes pass to it. The spilled slots of
    the frames left out are closed up (the frames after them moved down) before the band statistics, so these see the
    frames used as if alone.
    """
    paths = tuple(Path(p) for p in paths)
    if method not in METHODS:
        raise CamcalError(f"unknown combination method {method!r}; choose from {', '.join(METHODS)}")
    if not paths:
        raise CamcalError("no frames to combine")
    if not np.isfinite(sigma) or sigma <= 0:
        raise CamcalError(f"sigma must be a positive number, got {sigma}")
    wanted = frozenset(OPTIONAL_STATISTICS if statistics is None else statistics)
    if not wanted <= set(OPTIONAL_STATISTICS):
        raise CamcalError(f"unknown statistics {sorted(wanted - set(OPTIONAL_STATISTICS))}; choose from "
                          f"{', '.join(OPTIONAL_STATISTICS)} (value and count always come)")
    n = len(paths)
    judge = judge if judge is not None else StrictJudge(paths)
    dec = _Decoder(manifest, check, preprocess, keep_frames, judge)  # this call's settings, given to the threads
    dec.mosaic = preprocess is None
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress:
            progress(done, n)

    ahead = ThreadPoolExecutor(1, thread_name_prefix="camcal-decode") if n > 1 and thread_count(jobs, n) > 1 else None
    try:
        if ahead is not None:
            dec.prefetch(ahead, 1, paths[1])
        return _combine(paths, method, sigma, keep_frames, spill_dir, band_mb, jobs, dec, judge, tick, wanted)
    finally:
        if ahead is not None:
            ahead.shutdown(wait=True, cancel_futures=True)


def _combine(paths: tuple[Path, ...], method: str, sigma: float, keep_frames: int, spill_dir: str | Path | None,
             band_mb: float, jobs: int | None, dec: _Decoder, judge: StageJudge,
             tick: Callable[[], None], wanted: frozenset[str]) -> StackResult:
    """:func:`combine_frames` once its arguments are checked and its decoder made."""
    n = len(paths)
    start = 0
    first_meta = first_spill = first_planes = None
    while start < n:  # the first usable frame, in this thread
        path = paths[start]
        frame, facts = dec.judged_load(start, path)
        start += 1
        tick()
        if judge.decide(path, facts) is None:
            first_meta, first_spill, first_planes = dec.planes_of(  # type: ignore[arg-type]
                start - 1, path, frame, want_planes=(method == "mean" and not dec.mosaic) or keep_frames > 0)
            del frame
            break
    if first_meta is None:
        raise TooFewFrames(judge.stage, "frames", 1, 0, f"all {n} left out", paths[0].parent)
    first_index = start - 1
    dec.first = first_meta
    dec.mosaic = dec.mosaic and first_meta.layout == "bayer"
    jobs = thread_count(jobs, n, first_meta.frame_shape[0] * first_meta.frame_shape[1])
    c, h, w = first_meta.planes_shape
    index_of = {p: i for i, p in enumerate(paths)}
    used: dict[int, _Meta] = {first_index: first_meta}
    kept: dict[int, np.ndarray] = {first_index: first_planes} if keep_frames > 0 else {}
    # median / sigma_clip spill every frame to a private file (in memory when it fits), gone however the block ends
    spill_bytes = n * c * h * w * dec.spill_dtype.itemsize
    spill = (scratch_fd("camcal-stack-", spill_bytes, spill_dir) if method != "mean"
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
            for index, facts, meta, planes, mosaic in _run(items, jobs, dec.worker):
                tick()
                retracted = len(judge.retracted)
                if judge.decide(paths[index], facts) is not None:
                    continue
                assert meta is not None
                used[index] = meta
                copy_of = [index_of[p] for p in judge.retracted[retracted:] if index_of.get(p) in used]
                for j in copy_of:  # this frame's copy, combined already: the same pixels, now this frame's
                    del used[j]
                    if j in kept:
                        kept[index] = kept.pop(j)
                if copy_of:
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
                _close_up(spill_fd, spill_name, order, c * h * w * dec.spill_dtype.itemsize)
                pattern = first_meta.cfa_pattern if dec.mosaic else None
                for pos, i in enumerate(order[:keep_frames]):  # kept planes the threads did not return
                    if i not in kept:
                        kept[i] = _read_slot(spill_fd, spill_name, pos, (c, h, w), dec.spill_dtype, pattern)
                value, mean, var, count, var_all, mean_all = _bands(spill_fd, spill_name, len(order), (c, h, w),
                                                                    dec.spill_dtype, method, sigma, jobs, band_mb,
                                                                    pattern, wanted)
        finally:
            dec.spill_fd = None
    n_used = len(order)
    count_dtype = _count_dtype(n_used)
    mean, var, var_all, mean_all = (a if name in wanted else None for name, a in
                                    zip(OPTIONAL_STATISTICS, (mean, var, var_all, mean_all), strict=True))
    return StackResult(
        value=value, mean=mean, variance=var, count=count.astype(count_dtype, copy=False), n_frames=n_used,
        method=method,
        exposures=tuple(used[i].exposure for i in order), paths=tuple(paths[i] for i in order),
        channel_names=first_meta.channel_names, kind=first_meta.kind, cfa_pattern=first_meta.cfa_pattern,
        black_level_dn=first_meta.black, white_level_dn=first_meta.white, frame_shape=first_meta.frame_shape,
        black_level_known=first_meta.black_known,
        variance_all=var_all, mean_all=mean_all,
        kept_planes=tuple(kept[i] for i in order[:keep_frames] if i in kept),
    )


def _read_exactly(fd: int, name: str, mv: memoryview, offset: int) -> None:
    """Fill ``mv`` from the spill file ``fd`` (named ``name`` in messages) at byte ``offset``."""
    got = 0
    while got < mv.nbytes:
        r = os.preadv(fd, [mv[got:]], offset + got)
        if r <= 0:
            raise CamcalError(f"{name} ended early (disk or memory full?)")
        got += r


def _write_exactly(fd: int, name: str, mv: memoryview, offset: int) -> None:
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


def _close_up(fd: int, name: str, order: list[int], nbytes: int) -> None:
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
            _read_exactly(fd, name, mv[:size], i * nbytes + off)
            _write_exactly(fd, name, mv[:size], pos * nbytes + off)


def _read_slot(fd: int, name: str, pos: int, shape: tuple[int, int, int], dtype: np.dtype,
               pattern: str | None = None) -> np.ndarray:
    """The planes spilled at slot ``pos`` of the spill file ``fd`` (split out of the spilled mosaic when its CFA
    ``pattern`` is given)."""
    _, h, w = shape
    out = np.empty(shape if pattern is None else (2 * h, 2 * w), dtype)
    mv = memoryview(out.reshape(-1)).cast("B")
    _read_exactly(fd, name, mv, pos * mv.nbytes)
    return out if pattern is None else split_planes(out, pattern, dtype=None)


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
        return mean, mean, var, np.full(mean.shape, n, _count_dtype(n))


def _band_rows(n: int, shape: tuple[int, int, int], band_mb: float) -> int:
    """Rows of a band of ``n`` frames of (C, h, w) planes: within ``band_mb`` MB at 4 bytes a value (so the
    working set does not grow with ``n``) and :data:`MAX_BAND_PIXELS` pixels a frame, at least one row."""
    c, h, w = shape
    return max(1, min(h, int(band_mb * 1e6 / (n * c * w * 4)), MAX_BAND_PIXELS // (c * w)))


def _bands(fd: int, name: str, n: int, shape: tuple[int, int, int], dtype: np.dtype, method: str, sigma: float,
           jobs: int, band_mb: float, pattern: str | None = None,
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
    count = np.empty(shape, _count_dtype(n))
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
                    _read_exactly(fd, name, memoryview(buf[i, k]).cast("B"), (((i * c + k) * h) + y0) * w * item)
        else:
            buf = scratch.raw[:n * c * (y1 - y0) * w].reshape(n, 2 * (y1 - y0), 2 * w)
            for i in range(n):
                # mosaic row 2 y0 of frame i
                _read_exactly(fd, name, memoryview(buf[i]).cast("B"), (i * c * h * w + 4 * y0 * w) * item)
        results = _band_stats(buf, method, sigma, scratch.work)
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

    if jobs > 1 and len(bands) > 1:
        with ThreadPoolExecutor(jobs) as ex:
            list(ex.map(one, bands))
    else:
        for b in bands:
            one(b)
    return value, mean, var, count, var_all, mean_all


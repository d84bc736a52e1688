"""Per-pixel statistics of a band of a stack: median, mean and the two-pass sigma clip, along the frame axis.

:func:`band_statistics` is a pure function: an (N, ...) band in, its statistics out (the band is overwritten as it
is sorted). Sigma clipping per pixel: pass 1 keeps the values within ``sigma`` robust standard deviations
(interquartile range / 1.349) of the median; pass 2 keeps the values within ``sigma`` standard deviations (ddof=1)
of the mean of the pass-1 values, widened by 10⁻⁶ of the median so that equal values all stay. The combined value
is the mean of the kept values.

The band is sorted once along the frame axis by a sorting network (Batcher 1968); integer bands (DN, the default
planes) stay integer, and a clip takes the values a pixel loses off the sums of all its values rank by rank from
both ends (:class:`_SortedBand`); float32 bands (preprocessed frames, NaN = masked) mask every value
(:func:`_clipped_moments`). Its oracle is ``tests.oracles.band_statistics_reference``: the same definition,
pixel by pixel with :func:`numpy.sort` and boolean masks, whose results on integer bands it equals bit for bit.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

IQR_TO_SIGMA = 1.349
"""Interquartile range of a normal law in standard deviations."""



def _working_count_dtype(n: int) -> type[np.integer]:
    """The integer type of a band's running per-pixel count of ``n`` values: one byte up to 255, so a mask is
    added or taken off as bytes (``mask.view(np.uint8)``) without numpy's buffered bool-to-int32 cast, several
    times slower than the arithmetic itself; int32 above."""
    return np.uint8 if n <= 255 else np.int32



class BandStatistics(NamedTuple):
    """Statistics along axis 0 of a band (shapes of one frame of the band).

    value : the combined value (median, mean or sigma-clipped mean), the band's units.
    mean, variance, count : mean, variance (ddof=1, NaN below two values) and number of the values used.
    variance_all, mean_all : variance and mean of all values (before clipping).
    """

    value: np.ndarray
    mean: np.ndarray
    variance: np.ndarray
    count: np.ndarray
    variance_all: np.ndarray
    mean_all: np.ndarray


def band_statistics(x: np.ndarray, method: str, sigma: float, work: np.ndarray | None = None) -> BandStatistics:
    """Statistics along axis 0 of an (N, ...) band (uint16 or float32; the band is overwritten).

    Parameters
    ----------
    x : (N, ...) band: N frames of the same pixels, integer DN (uint8/uint16) or float32 (NaN = masked).
    method : ``"median"`` (every value used; the value is the median) or ``"sigma_clip"`` (a stack's ``"mean"``
        needs no band: :class:`camcal.calibrate.stack.StackResult` sums its frames as they come).
    sigma : the clipping threshold in standard deviations (``sigma_clip``).
    work : optional float32 scratch of at least ``x.size`` values (reused by a thread for all its bands).

    Returns
    -------
    BandStatistics

    Notes
    -----
    Everything after the sort works on values shifted by the median in float32, so sums of squares keep their
    precision; integer bands whose squared deviations sum past :data:`EXACT_SQUARES` are summed in float64.
    Oracle: ``tests.oracles.band_statistics_reference`` (module docstring).
    """
    if method not in ("median", "sigma_clip"):
        raise ValueError(f"band statistics are 'median' or 'sigma_clip', not {method!r}")
    return BandStatistics(*_band_stats(x, method, sigma, work))


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

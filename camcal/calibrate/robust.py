"""Robust statistics of large arrays: the exact median by sampled selection, and the median absolute deviation.

A plane of a 24 MP frame has 6 million values; :func:`numpy.median` selects its middle value by introselect
over all of them (about 60 ms for float32 here). :func:`median` finds the same value by selection from a sample
(Floyd and Rivest's idea): a sorted sample of about n^(2/3) values gives two bounds that hold the median with a
margin of several standard errors of the sample's rank; one pass counts the values below the lower bound and
keeps those between the bounds (a few per cent), and :func:`numpy.partition` of those gives the middle value(s).
The result is exactly :func:`numpy.median`'s: when the bounds miss the median (the sample's rank error beyond
the margin, or values that cannot be ordered such as NaN), :func:`numpy.median` of the whole array is taken.

References
----------
Floyd, R. W. and Rivest, R. L. (1975), "Expected time bounds for selection", Communications of the ACM 18(3),
165-172. Rousseeuw, P. J. and Croux, C. (1993), "Alternatives to the median absolute deviation", Journal of the
American Statistical Association 88(424), 1273-1283 (the MAD's scale to a normal standard deviation).
"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtri

SAMPLED_MEDIAN_MIN = 1 << 18
"""Arrays of fewer values than this go to :func:`numpy.median` directly (the sample would not pay for itself)."""

BRACKET_SIGMAS = 4.0
"""Half-width of the bracket around the sample's median rank, in standard errors of that rank (√(m)/2 for a
sample of m): the bracket misses the median with a probability of about 6e-5, and then the whole array is
selected by :func:`numpy.median`: slower, the same result."""

NORMAL_MAD = float(ndtri(0.75))
"""Φ⁻¹(3/4) ≈ 0.6745: the MAD of a normal law over its standard deviation (the ``scale="normal"`` of
:func:`scipy.stats.median_abs_deviation`, which divides by it)."""


def median(x: np.ndarray) -> np.floating:
    """The median of all values of ``x`` (any shape; not modified), equal to ``np.median(x)`` bit for bit.

    Parameters
    ----------
    x : ndarray (any unit; the result has it). Floating-point arrays of :data:`SAMPLED_MEDIAN_MIN` values or more
        are selected from a sample; others (and integer arrays, whose ties numpy's selection handles quickly)
        go to :func:`numpy.median`.

    Returns
    -------
    The median as :func:`numpy.median` gives it: the middle value, or the mean of the two middle values, in the
    array's floating type; NaN when ``x`` holds a NaN.

    Notes
    -----
    Sampled selection (Floyd and Rivest 1975): see the module's docstring. Three passes over the data (two
    comparisons and one selection) against introselect's several: 3-5x faster on a 6 MP plane.
    """
    flat = np.asarray(x).reshape(-1)
    n = flat.size
    if n < SAMPLED_MEDIAN_MIN or flat.dtype.kind != "f":  # integers: numpy's selection is quick on their ties
        return np.median(flat)
    k_lo = (n - 1) // 2
    step = max(1, int(n ** (1.0 / 3.0)))  # a sample of about n^(2/3) values, every step-th one
    sample = np.sort(flat[::step])
    m = sample.size
    centre = (m - 1) * (k_lo + 0.5) / n
    half = BRACKET_SIGMAS * 0.5 * np.sqrt(m)
    lo, hi = sample[max(0, int(centre - half))], sample[min(m - 1, int(np.ceil(centre + half)))]
    found = _median_between(flat, lo, hi)
    return np.median(flat) if found is None else found  # the bracket missed the middle (rare), or a NaN


def _median_between(flat: np.ndarray, lo: np.floating, hi: np.floating) -> np.floating | None:
    """numpy's median of the 1-D float array ``flat`` when its middle value(s) lie between ``lo`` and ``hi``
    (inclusive), found by selection among the values between them; None when they do not, or when ``flat`` holds
    a NaN (numpy's median is then NaN)."""
    n = flat.size
    k_lo, k_hi = (n - 1) // 2, n // 2
    out = np.less(flat, lo)
    n_below = int(np.count_nonzero(out))
    out |= np.greater(flat, hi)
    # lo <= value <= hi, and any NaN (neither below nor above; a NaN bound, from a NaN in the sample, compares
    # false with everything, so every value is "between")
    mid = flat[np.logical_not(out, out=out)]
    if np.isnan(mid).any() or not (n_below <= k_lo and k_hi < n_below + mid.size):
        return None
    part = np.partition(mid, (k_lo - n_below, k_hi - n_below))
    # numpy's own mean of the middle value(s), in its type: one value for an odd size (the mean of a value with
    # itself would overflow for a value above half the type's largest)
    middle = part[[k_lo - n_below, k_hi - n_below]] if k_hi > k_lo else part[[k_lo - n_below]]
    return np.median(middle)


def median_and_mad(x: np.ndarray) -> tuple[float, float]:
    """The median of ``x`` and its median absolute deviation scaled to a normal standard deviation.

    Equal to ``np.median(x)`` and ``scipy.stats.median_abs_deviation(x, scale="normal")`` bit for bit:
    MAD = median(|x - median(x)|) / :data:`NORMAL_MAD` (Rousseeuw and Croux 1993), the deviations in the
    median's type (that of ``x`` for floats, float64 for integers).
    Both medians by :func:`median`. ``x``: finite values (any unit; both results have it); not modified.
    """
    med = median(x)
    dev = np.subtract(x, med)  # in the median's type, as scipy's default centre (np.median) gives it
    np.abs(dev, out=dev)
    return float(med), float(median(dev) / NORMAL_MAD)

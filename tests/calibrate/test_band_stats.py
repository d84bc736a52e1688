"""The band statistics of the stack combiner on integer bands, against plain numpy and the masked float path.

Integer bands (uint16 DN, the default planes) are clipped on their sorted ranks: a pass takes the values a
pixel loses off the sums of all its values, following only the pixels that lost the rank before. Float32
bands (preprocessed frames) mask every value (``_clipped_moments``). Both must give the sigma clip of the
module docstring, computed here a third way, with numpy in float64 on every pixel.
"""

from __future__ import annotations

import numpy as np
import pytest

from camcal.calibrate.band_stats import IQR_TO_SIGMA, band_statistics
from tests.oracles import band_statistics_reference


def _outliers(n: int) -> int:
    """Outliers per pixel that a robust scale (the interquartile range) still sees as such: a tenth."""
    return max(1, n // 10)


def _band(n: int, seed: int) -> np.ndarray:
    """An (n, 4, 8, 60) uint16 dark band: 5 DN of noise on 520 DN, with pixels that clip deep and loud ones."""
    rng = np.random.default_rng(seed)
    x = np.rint(520 + 5 * rng.standard_normal((n, 4, 8, 60))).astype(np.int64)
    x[:, 0, 0, 0] = 16000 + np.rint(30 * rng.standard_normal(n))  # a hot pixel: sums of squares far above 2^22
    x[: n // 4, 0, 0, 1] += 4000  # random telegraph: a quarter of the frames high
    x[:, 0, 0, 2] = 700  # every value equal: nothing to clip
    x[:, 0, 0, 3] = rng.integers(0, 16384, n)  # uniform over the whole range: loud, deep clipping chains
    k = _outliers(n)
    x[:k, 1, 1, 5:9] = 9000  # cosmic rays in k frames: k ranks lost at the top
    x[-k:, 1, 2, 5:9] = 0  # and k values at 0: k ranks lost at the bottom
    x[0, 2, 3, 10] = 65535  # the type's extremes
    x[1, 2, 3, 10] = 0
    return rng.permuted(x, axis=0).astype(np.uint16)  # frames in any order


def _numpy_sigma_clip(x: np.ndarray, sigma: float) -> tuple[np.ndarray, ...]:
    """The module's two-pass sigma clip per pixel, in float64 with numpy's median, quantile, mean and var."""
    v = x.astype(np.float64)
    n = v.shape[0]
    med = np.median(v, axis=0)
    q25, q75 = np.quantile(v, [0.25, 0.75], axis=0)
    scale = (q75 - q25) / IQR_TO_SIGMA
    scale = np.where(scale > 0, scale, v.std(axis=0, ddof=1))
    keep = np.abs(v - med) <= sigma * scale
    m1 = np.where(keep, v, 0).sum(0) / keep.sum(0)
    s1 = np.sqrt(np.where(keep, (v - m1) ** 2, 0).sum(0) / np.maximum(keep.sum(0) - 1, 1))
    keep = np.abs(v - m1) <= sigma * s1 + 1e-6 * np.abs(med)
    cnt = keep.sum(0)
    mean = np.where(keep, v, 0).sum(0) / cnt
    var = np.where(keep, (v - mean) ** 2, 0).sum(0) / (cnt - 1)
    return mean, var, cnt, v.var(axis=0, ddof=1), v.mean(axis=0), med, n


@pytest.mark.parametrize(("n", "seed"), [(32, 1), (9, 2), (64, 3)])
def test_integer_band_sigma_clip_is_numpys(n, seed):
    x = _band(n, seed)
    value, mean, var, cnt, var_all, mean_all = band_statistics(x.copy(), "sigma_clip", 3.0)
    ref_mean, ref_var, ref_cnt, ref_var_all, ref_mean_all, _, _ = _numpy_sigma_clip(x, 3.0)
    # the same values are kept: the comparisons are exact in both (whole DN against float32 bounds)
    np.testing.assert_array_equal(cnt, ref_cnt)
    k = _outliers(n)
    assert cnt[1, 1, 5:9].max() <= n - k and cnt[1, 2, 5:9].max() <= n - k  # the cosmic rays and zeros went
    assert cnt[0, 0, 2] == n  # equal values all stay
    # the rest is float32 rounding of the results (sums exact): relative 2^-24, one unit more for the variance
    np.testing.assert_allclose(value, ref_mean, rtol=2e-7, atol=0)
    np.testing.assert_array_equal(value, mean)
    np.testing.assert_allclose(var, ref_var, rtol=3e-7, atol=1e-12)
    np.testing.assert_allclose(var_all, ref_var_all, rtol=3e-7)
    np.testing.assert_allclose(mean_all, ref_mean_all, rtol=2e-7)


@pytest.mark.parametrize(("n", "seed"), [(32, 4), (7, 5)])
def test_integer_band_matches_the_masked_float_path(n, seed):
    """The rank-wise clip of an integer band gives what masking every value of the same band as float32 gives:
    bit for bit where the float32 sums are exact (deviations from the median squared sum to less than 2^22),
    within float32 rounding at the loud pixels, where the integer path is the exact one."""
    x = _band(n, seed)
    fast = band_statistics(x.copy(), "sigma_clip", 3.0)
    masked = band_statistics(x.astype(np.float32), "sigma_clip", 3.0)
    v = x.astype(np.float64)
    loud = ((v - np.median(v, axis=0)) ** 2).sum(0) >= 2.0**22
    assert 2 <= loud.sum() < loud.size // 10
    for a, b in zip(fast, masked, strict=True):
        np.testing.assert_array_equal(a[~loud], b[~loud])
        np.testing.assert_allclose(a[loud], b[loud], rtol=1e-5)
    med = band_statistics(x.copy(), "median", 3.0)
    for a, b in zip(med, band_statistics(x.astype(np.float32), "median", 3.0), strict=True):
        np.testing.assert_array_equal(a[~loud], b[~loud])
        np.testing.assert_allclose(a[loud], b[loud], rtol=1e-5)
    np.testing.assert_array_equal(med[0], np.median(v, axis=0).astype(np.float32))


def test_float_band_clip_skips_lost_values_that_are_not_numbers():
    """A float32 band (preprocessed frames): an infinity that a clip loses is left out of the sums, not carried
    into them as NaN (the masked rows add keep · value, which is NaN for 0 · inf; those pixels are summed again,
    the values copied where kept). Checked against numpy in float64 on the finite values of each pixel. (A pixel
    masked, NaN, in a few frames: ``test_stack.py``, combined from the others.)"""
    rng = np.random.default_rng(7)
    n, w = 12, 300
    x = (1 + 0.02 * rng.standard_normal((n, 1, 1, w))).astype(np.float32)
    x[0, 0, 0, 0:20] = np.inf  # one value at +inf: lost at the top
    x[1, 0, 0, 20:40] = -np.inf  # and at -inf: lost at the bottom
    x[2, 0, 0, 40:60] = 5.0  # an outlier, finite: lost, as before
    x[3, 0, 0, 60:70] = np.nan  # one masked value: sorted last, lost at the top
    value, _mean, var, cnt, _var_all, _mean_all = band_statistics(x.copy(), "sigma_clip", 3.0)
    assert np.isfinite(value).all() and np.isfinite(var).all()
    assert (cnt[0, 0, :70] <= n - 1).all()  # the infinities, the outlier and the masked value went
    for j in range(w):  # the finite values of each pixel, clipped as the module docstring says, with numpy
        v = x[:, 0, 0, j].astype(np.float64)
        v = v[np.isfinite(v)]
        ref_mean, ref_var, ref_cnt, *_ = _numpy_sigma_clip(v[:, None], 3.0)
        if j < 40 or 60 <= j < 70:  # the infinity or NaN was one of the n values for the median and quartiles
            assert cnt[0, 0, j] <= ref_cnt[0] + 1
            continue
        assert cnt[0, 0, j] == ref_cnt[0], j
        np.testing.assert_allclose(value[0, 0, j], ref_mean[0], rtol=1e-6)
        np.testing.assert_allclose(var[0, 0, j], ref_var[0], rtol=1e-5)


@pytest.mark.parametrize(("n", "seed"), [(32, 11), (9, 12), (64, 13), (2, 14), (3, 15), (128, 16)])
@pytest.mark.parametrize("method", ["sigma_clip", "median"])
def test_integer_band_statistics_are_the_oracles_bit_for_bit(n, seed, method):
    """Every output of :func:`band_statistics` on an integer band equals its oracle
    (``tests.oracles.band_statistics_reference``: numpy.sort and a mask per pass over every value) bit for bit,
    loud pixels (squares past 2^22, summed in float64) and the type's extremes included, up to the sorting
    network's 128 frames."""
    x = _band(n, seed)
    got = band_statistics(x.copy(), method, 3.0)
    want = band_statistics_reference(x, method, 3.0)
    v = x.astype(np.float64)
    assert (((v - np.median(v, axis=0)) ** 2).sum(0) >= 2.0**22).any()  # the loud path is exercised
    for name, a, b in zip(got._fields, got, want, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)
        if name != "count":
            assert np.asarray(a).dtype == np.asarray(b).dtype, name


def test_float_band_statistics_are_the_oracles_within_float32_rounding():
    """A float32 band (preprocessed frames): the same kept values as the oracle, the moments within the float32
    rounding of the module's sums."""
    rng = np.random.default_rng(17)
    x = (1 + 0.02 * rng.standard_normal((16, 2, 4, 50))).astype(np.float32)
    x[:2, 0, 0, :10] = 3.0  # outliers lost by pass 1
    got = band_statistics(x.copy(), "sigma_clip", 3.0)
    want = band_statistics_reference(x, "sigma_clip", 3.0)
    np.testing.assert_array_equal(got.count, want[3])
    for a, b in zip(got, want, strict=True):
        np.testing.assert_allclose(np.asarray(a, np.float64), np.asarray(b, np.float64), rtol=2e-5, atol=1e-9)


def test_band_statistics_refuse_a_method_without_bands():
    with pytest.raises(ValueError, match="median"):
        band_statistics(np.zeros((3, 4), np.uint16), "mean", 3.0)

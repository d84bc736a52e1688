"""camcal.calibrate.robust: the sampled median equals numpy's bit for bit, and the MAD scipy's, whatever the data."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import median_abs_deviation

import camcal.calibrate.robust as robust
from camcal.calibrate.robust import SAMPLED_MEDIAN_MIN, _median_between, median, median_and_mad

#: Every test here is a fast formula test (the mutation-testing selection, docs/testing.md).
pytestmark = pytest.mark.formula

N = SAMPLED_MEDIAN_MIN + 12_345


def _cases():
    rng = np.random.default_rng(7)
    yield "normal float32", rng.normal(500, 20, N).astype(np.float32)
    yield "normal float64, odd size", rng.normal(0.01, 0.002, N + 1)
    yield "sorted", np.sort(rng.normal(0, 1, N))
    yield "reverse sorted", np.sort(rng.normal(0, 1, N))[::-1]
    yield "constant", np.full(N, 3.25, np.float32)
    yield "two values", np.where(rng.random(N) < 0.5, 1.0, 2.0)
    yield "heavy ties", rng.integers(0, 4, N).astype(np.float32)
    yield "outliers and infinities", np.concatenate([rng.normal(0, 1, N), [np.inf] * 1000, [-np.inf] * 10,
                                                     [1e30] * 5000])
    # a periodic pattern whose period is the sample's stride: the sample sees one value only
    step = max(1, int(N ** (1 / 3)))
    periodic = np.tile(np.arange(step, dtype=np.float64), N // step + 1)[:N]
    yield "periodic at the stride", periodic
    yield "2-D plane", rng.normal(10, 1, (600, 700)).astype(np.float32)
    yield "at the threshold", rng.normal(3, 1, SAMPLED_MEDIAN_MIN)
    yield "small", rng.normal(0, 1, 101)
    yield "integers", rng.integers(60, 70, N).astype(np.uint16)


@pytest.mark.parametrize("name, x", list(_cases()), ids=[c[0] for c in _cases()])
def test_median_is_numpys(name, x):
    before = x.copy()
    got, want = median(x), np.median(x)
    assert got.dtype == want.dtype
    assert got == want or (np.isnan(got) and np.isnan(want))
    np.testing.assert_array_equal(x, before)  # not modified


def test_a_nan_gives_nan_as_numpy():
    x = np.random.default_rng(1).normal(0, 1, N)
    x[N // 3] = np.nan
    assert np.isnan(median(x)) and np.isnan(np.median(x))


def test_a_bracket_that_misses_falls_back_to_numpy(monkeypatch):
    """With no margin at all the bracket around the sample's median misses the true median of most samples; the
    result is still numpy's (the whole array is selected)."""
    monkeypatch.setattr(robust, "BRACKET_SIGMAS", 0.0)
    rng = np.random.default_rng(3)
    calls = []
    real = np.median
    monkeypatch.setattr(robust.np, "median", lambda a, *k, **kw: calls.append(np.size(a)) or real(a, *k, **kw))
    for seed in range(5):
        x = rng.normal(seed, 1, N)
        assert median(x) == real(x)
    assert any(size == N for size in calls)  # at least one miss selected the whole array


@pytest.mark.parametrize("name, x", [c for c in _cases() if c[0] in ("normal float32", "normal float64, odd size",
                                                                     "sorted", "outliers and infinities",
                                                                     "2-D plane", "at the threshold")])
def test_the_median_is_selected_from_the_sample_bracket(monkeypatch, name, x):
    """On data with a median, the sampled path does the work: numpy's median only averages the middle value(s),
    never the whole array, and the selection runs over a few per cent of the values (the bracket of
    BRACKET_SIGMAS standard errors of the sample's median rank: about 6 % at this size)."""
    seen: dict[str, list[int]] = {"median": [], "partition": []}
    real_median, real_partition = np.median, np.partition
    monkeypatch.setattr(robust.np, "median", lambda a, *k, **kw: seen["median"].append(np.size(a))
                        or real_median(a, *k, **kw))
    monkeypatch.setattr(robust.np, "partition", lambda a, *k, **kw: seen["partition"].append(np.size(a))
                        or real_partition(a, *k, **kw))
    assert median(x) == real_median(x)
    assert seen["median"] in ([1], [2])
    assert len(seen["partition"]) == 1 and 0 < seen["partition"][0] < 0.1 * x.size


@pytest.mark.parametrize("name, x", [c for c in _cases() if c[0] in ("integers", "small")])
def test_integers_and_small_arrays_go_to_numpy(monkeypatch, name, x):
    seen: list[int] = []
    real = np.median
    monkeypatch.setattr(robust.np, "median", lambda a, *k, **kw: seen.append(np.size(a)) or real(a, *k, **kw))
    assert median(x) == real(x)
    assert seen == [x.size]


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint16])
def test_mad_is_scipys(dtype):
    rng = np.random.default_rng(5)
    x = rng.normal(400, 15, N)
    x[::997] += 5000
    x = x.astype(dtype)
    med, mad = median_and_mad(x)
    assert med == float(np.median(x))
    assert mad == float(median_abs_deviation(x, scale="normal"))


@pytest.mark.parametrize("n", [10, 11])
def test_bounds_at_the_middle_values_themselves(n):
    """The bracket is inclusive: bounds equal to the middle value(s) select them (no fallback); a lower bound
    one step above the lower middle value, or an upper bound one step below the upper one, misses (None),
    rather than selecting a wrong rank or failing."""
    x = np.arange(n, dtype=np.float64)[::-1].copy()
    k_lo, k_hi = (n - 1) // 2, n // 2
    want = np.median(x)
    assert _median_between(x, np.float64(k_lo), np.float64(k_hi)) == want
    assert _median_between(x, np.float64(k_lo), np.float64(k_hi + 0.5)) == want
    assert _median_between(x, np.float64(k_lo + 0.5), np.float64(n)) is None
    assert _median_between(x, np.float64(-1), np.float64(k_hi - 0.5)) is None
    x[3] = np.nan
    assert _median_between(x, np.float64(-1), np.float64(n)) is None


def test_an_odd_sized_median_near_the_types_largest_value_is_that_value():
    """The middle value of an odd number of float32 values is returned as it is: 3e38 stays 3e38 (a mean of
    the value with itself would overflow float32 to infinity)."""
    x = np.full(SAMPLED_MEDIAN_MIN + 1, 3e38, np.float32)
    x[:1000] = 1.0
    assert median(x) == np.median(x) == np.float32(3e38)
    assert _median_between(np.array([1, 3e38, 3e38], np.float32), np.float32(1e38), np.float32(3.2e38)) \
        == np.float32(3e38)

"""Tests of :mod:`camcal.calibrate.dark_noise`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from camcal.calibrate.dark_noise import noise_model, temporal_noise
from camcal.calibrate.stack import StackResult
from camcal.frame import PLANES, Exposure
from camcal.models.dark import HOT
from tests.helpers import NOISE_METHOD, _map_of_variance, _noisy_bound, _read_noise_stack, _stack


def _dark_stack(level, t_s, var_dn2, n=8, white=4095.0, black=1000.0):
    """A combined stack of ``n`` dark frames at ``t_s`` with exact per-pixel levels and variances (no file)."""
    level = np.asarray(level, np.float32)
    var = np.full(level.shape, var_dn2, np.float32)
    e = Exposure(exposure_s=t_s, iso=100.0)
    return StackResult(value=level, mean=level, variance=var.copy(), count=np.full(level.shape, n, np.int16),
                       n_frames=n, method="mean", exposures=(e,) * n,
                       paths=tuple(Path(f"d{t_s:g}_{i}.dng") for i in range(n)), channel_names=PLANES,
                       cfa_pattern="RGGB", black_level_dn=(black,) * 4, white_level_dn=white,
                       frame_shape=(2 * level.shape[1], 2 * level.shape[2]), variance_all=var)


@pytest.mark.formula
def test_dark_noise_line_through_the_stacks_leaves_hot_pixels_out():
    """variance = v0 + g·(level − bias) through three stacks: v0 = 6 DN², g = 0.4 DN/e⁻ exactly; a hot pixel of
    variance 10⁴ DN² in every stack is above 5× the median and must not pull the line."""
    shape = (4, 5, 5)
    bias = np.full(shape, 1000.0)
    stats = []
    for t, signal in ((1.0, 20.0), (4.0, 80.0), (10.0, 200.0)):
        level = bias + signal
        st = _dark_stack(level, t, var_dn2=6.0 + 0.4 * signal)
        st.variance_all[:, 2, 2] = 1e4
        stats.append((t, st))
    v0, g = noise_model(stats, bias)
    np.testing.assert_allclose(v0.ravel(), 6.0, rtol=1e-4)
    np.testing.assert_allclose(g.ravel(), 0.4, rtol=1e-5)
    # a single stack: no slope, v0 is its variance
    v0, g = noise_model(stats[:1], bias)
    np.testing.assert_allclose(v0.ravel(), 14.0, rtol=1e-5)
    assert np.all(g == 0)


@pytest.mark.formula
def test_temporal_noise_below_one_dn_fits_consecutive_frame_pairs():
    """Planes below 1 DN of noise get the quantised-normal read noise and DSNU, the mean over the consecutive pairs
    (0, 1), (1, 2), (2, 3) of the first four kept frames, against the simulation's truth.

    Five frames of 128 × 128 pixels: R at 1.5 DN (not quantised), G1 σ = 0.4 DN and dsnu 0.3 DN, G2 σ = 0.35 DN
    and dsnu 0.5 DN, B a plane whose good pixels read one level in every frame (v̂ = 0: quantised, and no pixel
    is noisy, not even its hot ones). In G1 and G2 frame 3's noise is frame 0's reversed: every consecutive pair is
    independent, (0, 3) is not (σ would come out ~√2 too high there). Defects: 0.5 % hot pixels 150 DN up and 3 %
    2 DN up, both with 1 DN of noise (most of the second kind below the noisy bound, and close enough to the other
    pixels to widen σ by ~7 % if they entered the fit); 0.2 % noisy pixels (4 DN) are found by the chi-square
    bound (dof 4: 8.34 v̂). Neither may enter the fit, and the noisy ones keep √(var − 1/12) in the read-noise
    map, the others the plane's read noise.
    Tolerances: 16 000 pairs give σ to 0.7 % and dsnu to 1 % (standard deviations over 12 seeds): 3 % and 5 %;
    the pair (0, 3) instead of (2, 3) would move σ by +8 % (G1) and +14 % (G2), dsnu by −33 % and −10 %.
    Two frames (two files) are enough: one pair, σ = 0.45 DN to 5 % on 10 000 pixels (spread ~1.2 %).
    """
    rng = np.random.default_rng(2911)
    shape = (4, 128, 128)
    sigma, dsnu = (1.5, 0.4, 0.35, 0.0), (3.0, 0.3, 0.5, 0.5)
    z = rng.standard_normal((5, *shape))
    z[3, 1:3] = -z[0, 1:3]
    frames = np.rint(np.array([200.0, 60.2, 60.2, 60.0])[:, None, None] + np.array(dsnu)[:, None, None]
                     * rng.standard_normal(shape) + np.array(sigma)[:, None, None] * z)
    u = rng.random(shape)
    defects = np.where(u < 0.035, HOT, 0).astype(np.uint8)
    frames += np.where(u < 5e-3, 150.0, 2.0) * defects + defects * np.rint(rng.standard_normal(frames.shape))
    noisy_px = (rng.random(shape) < 2e-3) & (defects == 0)
    noisy_px[[0, 3]] = False  # R is not quantised; in B only the defects change
    frames += noisy_px * np.rint(4.0 * rng.standard_normal(frames.shape))
    var = np.var(frames, axis=0, ddof=1)
    noise = temporal_noise(_read_noise_stack(var, 5, frames), var.astype(np.float64), defects, 6.0)

    bound = _noisy_bound(4, 6.0)
    assert bound == pytest.approx(8.3442, abs=1e-4)
    vhat = np.zeros(4)
    for k in range(4):
        v = np.sort(var[k][defects[k] == 0])
        vhat[k] = np.mean(v[v <= np.quantile(v, 0.999)])  # 16 000 good pixels: the top 0.1 % left out
    assert vhat[3] == 0.0
    np.testing.assert_allclose(noise.temporal_noise_dn, np.sqrt(vhat), rtol=1e-6)
    expect_noisy = var > vhat[:, None, None] * bound
    expect_noisy[3] = False  # v̂ = 0: no bound
    np.testing.assert_array_equal(noise.noisy, expect_noisy)
    assert np.count_nonzero(noise.noisy[1:3] & noisy_px[1:3]) > 0.95 * np.count_nonzero(noisy_px)
    np.testing.assert_array_equal(noise.quantised, [False, True, True, True])
    assert np.isnan(noise.read_noise_dn[0]) and np.isnan(noise.dsnu_dn[0])
    np.testing.assert_allclose(noise.read_noise_dn[1:3], sigma[1:3], rtol=0.03)
    np.testing.assert_allclose(noise.dsnu_dn[1:3], dsnu[1:3], rtol=0.05)
    assert 0 < noise.read_noise_dn[3] < 0.1  # B never changes: no read noise to speak of
    expect_map = _map_of_variance(var)
    for k in (1, 2, 3):
        expect_map[k] = np.where(expect_noisy[k], expect_map[k], noise.read_noise_dn[k])
    np.testing.assert_allclose(noise.read_noise_map_dn, expect_map, rtol=1e-6)
    assert noise.method == ("quantised-normal likelihood of 3 frame pair(s) in planes G1, G2, B (temporal noise "
                            "below 1 DN); elsewhere " + NOISE_METHOD)

    # two frames, two files: one pair
    small = frames[:2, :, :100, :100].copy()
    small[:, 1] = np.rint(60.2 + 0.3 * rng.standard_normal((100, 100)) + 0.45 * rng.standard_normal((2, 100, 100)))
    small_defects = defects[:, :100, :100]
    var2 = np.var(small, axis=0, ddof=1)
    noise = temporal_noise(_read_noise_stack(var2, 2, small), var2.astype(np.float64), small_defects, 6.0)
    assert noise.read_noise_dn[1] == pytest.approx(0.45, rel=0.05)
    assert noise.method.startswith("quantised-normal likelihood of 1 frame pair(s) in planes G1, G2, B (")


def _noise_stack(signal_dn: float, t_s: float, var_all_dn2: float, var_clipped_dn2: float | None,
                 bias: np.ndarray) -> StackResult:
    """A sigma-clipped dark stack at ``bias + signal`` whose unclipped variance (``variance_all``) and clipped
    variance (``variance``) differ; ``var_clipped_dn2=None`` gives a stack that only has ``variance`` (as a stack
    whose variance_all is None), holding ``var_all_dn2``."""
    st = _stack(bias + signal_dn, t_s, 4095.0, 1000.0)
    var_all = np.full(bias.shape, var_all_dn2, np.float32)
    if var_clipped_dn2 is None:
        return replace(st, variance=var_all, variance_all=None)
    return replace(st, variance=np.full(bias.shape, var_clipped_dn2, np.float32), variance_all=var_all)


@pytest.mark.formula
def test_dark_noise_line_reads_the_unclipped_variance_and_its_guards():
    """The temporal-noise line variance = v0 + g·(level − bias) of ``noise_model``, per plane, against values
    written out (all inputs exact in float32, so the two-point line is exact to rounding):

    - it reads each stack's unclipped variance (``variance_all``, v0 = 0.5 DN², g = 0.5 DN/e⁻ through
      (20, 10.5) and (20.5, 10.75)), not the clipped one (twice as large here), and ``variance`` when a stack has
      no ``variance_all``;
    - two stacks are enough for a line, even 0.5 DN apart; two stacks at the same level give no slope (g = 0,
      v0 = the first stack's variance: a fit through one x would return 8, 0.4 for (20, 16), (20, 16));
    - v0 is floored at 1e-6 DN² only: 0.5 DN² and a single stack's 0.625 DN² are kept as they are; a line with a
      negative intercept gives 1e-6, a falling one g = 0;
    - a pixel whose bias is not finite, or whose variance is not finite, is left out of the plane means.
    """
    shape = (4, 3, 3)
    bias = np.full(shape, 1000.0)
    bias[:, 0, 0] = np.nan  # its stack values are finite: only the bias says to leave it out
    stats = [(1.0, _noise_stack(20.0, 1.0, 10.5, 21.0, bias)), (2.0, _noise_stack(20.5, 2.0, 10.75, 21.5, bias))]
    stats[1][1].variance_all[:, 2, 1] = np.nan
    v0, g = noise_model(stats, bias)
    np.testing.assert_allclose(v0.ravel(), 0.5, rtol=1e-9)
    np.testing.assert_allclose(g.ravel(), 0.5, rtol=1e-9)
    # stacks without variance_all: their variance is read
    v0, g = noise_model([(1.0, _noise_stack(20.0, 1.0, 10.5, None, bias)),
                          (2.0, _noise_stack(20.5, 2.0, 10.75, None, bias))], bias)
    np.testing.assert_allclose(v0.ravel(), 0.5, rtol=1e-9)
    np.testing.assert_allclose(g.ravel(), 0.5, rtol=1e-9)
    # two stacks at the same level (no dark current): no line
    v0, g = noise_model([(1.0, _noise_stack(20.0, 1.0, 16.0, 32.0, bias)),
                          (4.0, _noise_stack(20.0, 4.0, 16.0, 32.0, bias))], bias)
    np.testing.assert_allclose(v0.ravel(), 16.0, rtol=1e-12)
    assert np.all(g == 0)
    # one stack below 1 DN² (no variance_all): its variance, not the floor
    v0, g = noise_model([(1.0, _noise_stack(0.25, 1.0, 0.625, None, bias))], bias)
    np.testing.assert_allclose(v0.ravel(), 0.625, rtol=1e-12)
    assert np.all(g == 0)
    # a negative intercept (-1 + 0.5 s) is floored at 1e-6; a falling line (30 - 0.5 s) has g = 0
    v0, g = noise_model([(1.0, _noise_stack(20.0, 1.0, 9.0, 18.0, bias)),
                          (2.0, _noise_stack(24.0, 2.0, 11.0, 22.0, bias))], bias)
    assert np.all(v0 == 1e-6)
    np.testing.assert_allclose(g.ravel(), 0.5, rtol=1e-9)
    v0, g = noise_model([(1.0, _noise_stack(20.0, 1.0, 20.0, 40.0, bias)),
                          (2.0, _noise_stack(24.0, 2.0, 18.0, 36.0, bias))], bias)
    assert np.all(g == 0)
    np.testing.assert_allclose(v0.ravel(), 30.0, rtol=1e-9)


@pytest.mark.formula
def test_dark_noise_line_plane_means_are_float64_sums():
    """The plane means of ``noise_model`` are exact to float64 rounding on a large plane: a million float32 levels
    near 1020 DN with fractional noise, whose float32 sum would be off by about 1e-4 DN in the mean (2e-4 of the
    slope here). The expected line goes through the exact means (``math.fsum`` of the float64 differences)."""
    rng = np.random.default_rng(11)
    shape = (4, 1000, 1000)
    bias = (np.full(shape, 1000.0) + rng.uniform(-0.25, 0.25, shape)).astype(np.float32)  # as the dark fit stores it
    xs, ys, stats = [], [], []
    for t, signal, var in ((1.0, 20.0, 10.5), (2.0, 20.5, 10.75)):
        st = _noise_stack(signal, t, var, var, bias)
        st.value[...] = (bias + signal + rng.normal(0.0, 0.7, shape)).astype(np.float32)
        stats.append((t, st))
        xs.append([math.fsum((st.value[k].astype(np.float64) - bias[k].astype(np.float64)).ravel()) / bias[k].size
                   for k in range(4)])
        ys.append(var)
    v0, g = noise_model(stats, bias)
    for k in range(4):
        slope = (ys[1] - ys[0]) / (xs[1][k] - xs[0][k])
        assert g.ravel()[k] == pytest.approx(slope, rel=1e-9)
        assert v0.ravel()[k] == pytest.approx(ys[0] - slope * xs[0][k], rel=1e-9)


@pytest.mark.formula
def test_dark_noise_line_leaves_out_pixels_noisier_than_five_times_the_plane():
    """A 10 × 10 plane of variance 10.5 / 10.75 DN² (the line v0 = 0.5, g = 0.5 through signals 20 and 20.5) with
    one pixel at 5.8× that in both stacks: the plane mean with it is 1.048×, so 5.8× is above the cut of 5× the
    mean (5.24×) and the line is that of the other 99 pixels (a cut at 6× would keep it: v0 = 5.5, g = 2.8)."""
    shape = (4, 10, 10)
    bias = np.full(shape, 1000.0)
    stats = []
    for t, signal, var in ((1.0, 20.0, 10.5), (2.0, 20.5, 10.75)):
        st = _noise_stack(signal, t, var, var, bias)
        st.variance_all[:, 4, 7] = 5.8 * var
        stats.append((t, st))
    v0, g = noise_model(stats, bias)
    np.testing.assert_allclose(v0.ravel(), 0.5, rtol=1e-9)
    np.testing.assert_allclose(g.ravel(), 0.5, rtol=1e-9)

"""Physical formulas checked at non-trivial operating points against values computed by other means (issue 29).

Each test here guards one formula with an independent value: a closed form against quadrature
(scipy.integrate), a forward model against an independent rendering written out in the test, a unit
conversion against published constants, a fit against exact synthetic data. None of them compares a function
with itself. They were written to kill mutations (one-line changes of the physics) that survived the rest
of the suite; docs/testing.md lists them and how to rerun the mutation campaign.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import ndtri
from scipy.stats import chi2

import camcal.calibrate.dark
from camcal.apply.photo import apply
from camcal.apply.radiance import radiance_model
from camcal.calibrate.dark import _channel_summary, _fit_lines, _robust, fit_dark
from camcal.calibrate.dark_frames import DarkOptions, DarkStacks
from camcal.calibrate.dark_noise import TemporalNoise, _max_median_mean, noise_model
from camcal.calibrate.emva import dark_noise_stacks
from camcal.calibrate.stack import StackResult
from camcal.errors import CamcalError, MissingMetadataError
from camcal.frame import PLANES, Exposure
from camcal.io.read import load_frame
from camcal.models.dark import DEAD, HOT, NOISY
from camcal.models.profile import load_profile
from camcal.models.spectra import gaussian_line
from camcal.synth.camera import Scene
from camcal.synth.session import exposure_for_level
from camcal.water.models import LampModel, RefinedModel, SeedModel, lamp_ratio
from camcal.water.optics import hemispheric_transmittance, schlick_reflectance, transmittance
from tests.oracles import lamp_toward, refined_at_wavelength

N_WATER = 1.33


# ---- Fresnel from the air side, written out independently (Born & Wolf §1.5.3, transmission coefficients) ----

def fresnel_t_from_air(theta_air_rad: float, n: float = N_WATER) -> float:
    """Unpolarised power transmittance of a flat air→water surface at air-side angle θa.

    From the amplitude transmission coefficients t_s = 2 cos θi / (cos θi + n cos θt),
    t_p = 2 cos θi / (n cos θi + cos θt) and the power factor n cos θt / cos θi (not from 1 − R).
    By reciprocity (Stokes relations) it is also the water→air transmittance along the refracted ray.
    """
    ci = np.cos(theta_air_rad)
    ct = np.sqrt(1.0 - (np.sin(theta_air_rad) / n) ** 2)
    k = n * ct / ci
    ts = 2 * ci / (ci + n * ct)
    tp = 2 * ci / (n * ci + ct)
    return float(0.5 * k * (ts * ts + tp * tp))


def schlick_t_from_air(theta_air_rad: float, n: float = N_WATER) -> float:
    """1 − Schlick's R at the air-side angle (either direction, Schlick 1994)."""
    r0 = ((n - 1) / (n + 1)) ** 2
    return float(1 - (r0 + (1 - r0) * (1 - np.cos(theta_air_rad)) ** 5))


# ---- 1. the three mutations that survived the suite ---------------------------------------------------------

@pytest.mark.parametrize("view_air_rad", [0.5, 1.0])
def test_upward_transmittance_at_oblique_views_is_fresnel_from_air_by_reciprocity(view_air_rad):
    """T_up of the water-leaving ray seen by a camera at air angle θa = the air→water T at θa (reciprocity).

    Both models; at 1 rad the swapped-index formula gives 0.9762 instead of 0.9507 (2.7 %).
    """
    expect = fresnel_t_from_air(view_air_rad)
    assert float(transmittance(view_air_rad)) == pytest.approx(expect, rel=1e-12)  # defaults: air → water, Fresnel
    assert RefinedModel(view_angle_rad=view_air_rad).transmittance_up() == pytest.approx(expect, rel=1e-12)
    assert LampModel(view_angle_rad=view_air_rad).transmittance_up() == pytest.approx(expect, rel=1e-12)


def _stack(level: np.ndarray, t_s: float, white: float, black: float, n: int = 8, var_dn2: float = 4.0):
    """A combined stack of ``n`` dark frames at exposure ``t_s`` with exact per-pixel levels (no file)."""
    level = np.asarray(level, np.float32)
    var = np.full(level.shape, var_dn2, np.float32)
    e = Exposure(exposure_s=t_s, iso=100.0)
    return StackResult(value=level, mean=level, variance=var, count=np.full(level.shape, n, np.int16), n_frames=n,
                       method="mean", exposures=(e,) * n, paths=tuple(Path(f"d{t_s:g}_{i}.dng") for i in range(n)),
                       channel_names=PLANES, cfa_pattern="RGGB", black_level_dn=(black,) * 4, white_level_dn=white,
                       frame_shape=(2 * level.shape[1], 2 * level.shape[2]), variance_all=var)


def test_dark_line_fit_leaves_clipped_levels_out():
    """Per-pixel line fit level = b + β t with levels clipped at the white level: exact β and bias.

    Noise-free levels with integer bias and β and dyadic times are exact in float32, so the weighted least
    squares through the unclipped points returns the truth to rounding. A pixel saturated in every dark group
    (only its bias frame unsaturated) has no line: β is the bound (white − black)/t_min, its uncertainty
    infinite, and it is marked hot.
    """
    shape = (4, 6, 6)
    rng = np.random.default_rng(7)
    white, black = 4095.0, 1000.0
    bias = (black + rng.integers(-8, 9, shape)).astype(np.float64)
    beta = rng.integers(1, 4, shape).astype(np.float64)  # DN/s
    beta[0, 1, 1] = 160.0  # clips in the 20 s group only: 1008 + 160·8 < 4095 < 992 + 160·20
    beta[2, 3, 2] = 600.0  # clips at 20 s and 8 s
    beta[3, 4, 4] = 5000.0  # clips in every dark group
    times = (2.0**-13, 1.0, 8.0, 20.0)  # bias frames, then three dark groups
    stacks = [_stack(np.minimum(bias + beta * t, white), t, white, black) for t in times]
    model = fit_dark(DarkStacks(tuple((t, s) for t, s in zip(times[1:], stacks[1:], strict=True)), stacks[0]))
    fitted = np.ones(shape, bool)
    fitted[3, 4, 4] = False
    np.testing.assert_allclose(model.dark_current_dn_per_s[fitted], beta[fitted], rtol=1e-6)
    np.testing.assert_allclose(model.bias_dn[fitted], bias[fitted], rtol=0, atol=1e-3)
    assert model.defects[0, 1, 1] & HOT and model.defects[2, 3, 2] & HOT
    # saturated in all but one observation: the bounded-β branch
    assert model.dark_current_dn_per_s[3, 4, 4] == pytest.approx((white - black) / 1.0)
    assert model.bias_dn[3, 4, 4] == black
    assert np.isinf(model.dark_current_unc_dn_per_s[3, 4, 4])
    assert model.defects[3, 4, 4] & HOT
    # the clipped pixels' uncertainties come from their unclipped points only: finite
    assert np.all(np.isfinite(model.dark_current_unc_dn_per_s[[0, 2], [1, 3], [1, 2]]))


LINE_BAND_W_M2_SR = 2.0


def test_long_dim_photo_at_f8_gives_the_true_radiance(tmp_path, camera, profile_path):
    """A 30 s photo at f/8 (the profile's reference is f/4), 5 % of full scale: the dark current of 30 s
    is ≈ 60 e⁻ per pixel against a signal of a few hundred, so it must be scaled by the frame's own exposure
    time (the relative exposure is 7.5 s here; scaling by it leaves the photo 4 % too bright).

    Truth: the scene's in-band radiance, 2 W m⁻² sr⁻¹ times the dimming. Tolerance 1 %: the noise of the
    frame mean is < 0.05 % (24 576 cells), the dark model's β error over 30 s < 0.3 % of the signal,
    c(λ0) ≈ 0.05 %.
    """
    profile = load_profile(profile_path)
    assert profile.reference_f_number == 4.0
    line = LINE_BAND_W_M2_SR * gaussian_line(663.0, 5.0)
    t = 30.0
    scale = exposure_for_level(camera, line, 0.05, 100, 8.0) / t
    p = tmp_path / "dim_30s_f8.dng"
    camera.write_dng(p, Scene.uniform(line * scale), exposure_s=t, iso=100, f_number=8.0,
                     rng=np.random.default_rng(29))
    got = float(np.nanmean(apply(load_frame(p), profile, 663.0, "narrowband").channels["L663_inband"]))
    assert got == pytest.approx(LINE_BAND_W_M2_SR * scale, rel=0.01)


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


def test_dark_line_fit_cut_one_dn_below_white_and_frame_counts():
    """``_fit_lines``' saturation cut and its usable-time count, one pixel per case against values written out
    (white level 4095 DN: levels at or above 4094 DN get zero weight, the documented cut):

    - a level of exactly 4094 DN is cut, whether it is the band's brightest level (no line: one usable time) or
      another pixel of the band is saturated; 4093.5 DN is kept (β through two points);
    - a group with no frames at a pixel (count 0) is not a usable time there; a group of one frame is.
    """
    white = 4095.0
    one = np.array([1.0])

    def fit(levels_1s, levels_10s, n_1s=(4.0,), n_10s=(4.0,)):
        obs = [(1.0, np.array(levels_1s), np.array(n_1s) * one, 2.0 * one),
               (10.0, np.array(levels_10s), np.array(n_10s) * one, 2.0 * one)]
        return _fit_lines(obs, white)

    beta, _, b, _, n_times = fit([1100.0], [4094.0])
    assert np.isnan(beta[0]) and np.isnan(b[0]) and n_times.tolist() == [1]
    beta, _, _, _, n_times = fit([1100.0, 1100.0], [4094.0, 4095.0])
    assert np.isnan(beta).all() and n_times.tolist() == [1, 1]
    beta, _, b, _, n_times = fit([1100.0, 1100.0], [4093.5, 4095.0])
    assert beta[0] == pytest.approx((4093.5 - 1100.0) / 9.0, rel=1e-12) and n_times.tolist() == [2, 1]
    assert b[0] == pytest.approx(1100.0 - (4093.5 - 1100.0) / 9.0, rel=1e-12)
    # frame counts: none at 10 s → one usable time; one frame at each time (with a saturated pixel in the band)
    beta, _, _, _, n_times = fit([1100.0], [1200.0], n_10s=(0.0,))
    assert np.isnan(beta[0]) and n_times.tolist() == [1]
    beta, _, _, _, n_times = fit([1100.0, 1100.0], [1200.0, 4095.0], n_1s=(1.0, 1.0), n_10s=(1.0, 1.0))
    assert beta[0] == pytest.approx(100.0 / 9.0, rel=1e-12) and n_times.tolist() == [2, 1]


def test_dark_line_fit_of_a_band_with_and_without_a_line():
    """A band of two pixels, one with a line and one left with a single usable time (saturated at 10 s), and
    exposures of 10 and 30 ms:

    - the pixel with a line has β, b and their variances of the least squares written out (the covariance
      A diag(σ²/n) Aᵀ of the linear estimator), even at 10-30 ms, where Σn·Σn(t − t̄)² is far below 1 s²;
    - the pixel with one usable time has no line: β, b, var(β), var(b) NaN. With 3 frames at 0.7 s, Σn·Σnt² −
      (Σnt)² rounds to 8.9e-16 instead of 0, so only the count of usable times (not that determinant) may decide.
    """
    white = 4095.0
    for times, n in (((0.01, 0.03), 4.0), ((0.7, 10.0), 3.0)):
        y = np.array([[1100.0, 1100.0], [1100.0 + 50.0 * (times[1] - times[0]), white]])
        obs = [(t, y[i], np.full(2, n), np.full(2, 2.0)) for i, t in enumerate(times)]
        beta, beta_var, b, b_var, n_times = _fit_lines(obs, white)
        assert n_times.tolist() == [2, 1]
        x = np.stack([np.ones(2), np.array(times)], axis=1)
        a = np.linalg.solve(x.T @ (n * x), x.T * n)
        cov = a @ np.diag(np.full(2, 2.0 / n)) @ a.T
        assert beta[0] == pytest.approx(50.0, rel=1e-9) and b[0] == pytest.approx(1100.0 - 50.0 * times[0], rel=1e-12)
        assert beta_var[0] == pytest.approx(cov[1, 1], rel=1e-9) and b_var[0] == pytest.approx(cov[0, 0], rel=1e-9)
        assert np.isnan([beta[1], b[1], beta_var[1], b_var[1]]).all()


def test_dark_line_fit_returns_none_for_the_parts_not_asked_for():
    """``with_fit=False`` returns β and b as None, ``with_variance=False`` var(β) and var(b) as None (documented:
    the callers ask for one or the other); the parts asked for are the exact line through two points."""
    obs = [(1.0, np.array([1100.0]), np.array([4.0]), np.array([2.0])),
           (3.0, np.array([1130.0]), np.array([4.0]), np.array([2.0]))]
    beta, beta_var, b, b_var, n_times = _fit_lines(obs, 4095.0, with_variance=False)
    assert beta_var is None and b_var is None and n_times.tolist() == [2]
    assert beta[0] == pytest.approx(15.0, rel=1e-12) and b[0] == pytest.approx(1085.0, rel=1e-12)
    beta, beta_var, b, b_var, n_times = _fit_lines(obs, 4095.0, with_fit=False)
    assert beta is None and b is None and n_times is None
    # var(β) of two points with weights n = 4 and per-frame variance 2: 2 σ²/n / Δt² = 2·0.5/4 = 0.25 (DN/s)²
    assert beta_var[0] == pytest.approx(0.25, rel=1e-12)
    beta, _, b, _, n_times = _fit_lines(obs, 4095.0, with_variance=False, with_count=False)
    assert n_times is None and beta[0] == pytest.approx(15.0, rel=1e-12)


def test_dark_line_fit_in_float32_rounds_the_float64_result_once():
    """``_fit_lines(dtype=np.float32)`` (the dark fit's maps, half the memory): β, b, var(β) and var(b) in float32,
    each the float64 result rounded once, on random levels whose values are not exact in float32; the count of
    usable times stays int16."""
    rng = np.random.default_rng(8)
    shape = (4, 9, 11)
    bias = 1000.0 + rng.uniform(0, 7, shape)
    beta = rng.uniform(0.5, 3.0, shape)
    obs = [(t, (bias + beta * t).astype(np.float32), np.full(shape, n), rng.uniform(3.0, 5.0, shape))
           for t, n in ((0.0, 16.0), (0.37, 8.0), (2.9, 6.0))]
    wide = _fit_lines(obs, 4095.0)
    narrow = _fit_lines(obs, 4095.0, dtype=np.float32)
    for a64, a32 in zip(wide[:4], narrow[:4], strict=True):
        assert a32.dtype == np.float32 and a64.dtype == np.float64
        np.testing.assert_array_equal(a32, a64.astype(np.float32))
        assert not np.array_equal(a32.astype(np.float64), a64)  # the float64 values are not float32 ones
    assert narrow[4].dtype == wide[4].dtype == np.int16
    np.testing.assert_array_equal(narrow[4], 3)


# ---- dark: the whole fit of combined stacks, its channel figures, its helpers ---------------------------------

#: σ of a normal distribution over its median absolute deviation: 1/Φ⁻¹(3/4) (scipy's ``scale="normal"``).
NORMAL_PER_MAD = 1.0 / float(ndtri(0.75))
#: Standard error of a median over that of a mean for normal data, √(π/2) (the summary rounds it to 1.2533).
MEDIAN_PER_MEAN_SE = float(np.sqrt(np.pi / 2.0))


def _dark_group(level, var, t_s, n, *, black=(1000.0,) * 4, white=4095.0, cfa="RGGB", iso=100.0,
                temps=None, exposure_s="t") -> StackResult:
    """A combined stack of ``n`` frames at ``t_s`` with exact per-pixel levels and temporal variances (no file).

    ``temps``: the frames' sensor temperatures (one per frame, or None); ``exposure_s=None`` gives frames whose
    exposure time is not known (as bias frames may be)."""
    level = np.asarray(level, np.float32)
    var = np.asarray(var, np.float32)
    temps = [None] * n if temps is None else list(temps)
    es = tuple(Exposure(exposure_s=t_s if exposure_s == "t" else exposure_s, iso=iso, temperature_c=tc)
               for tc in temps)
    return StackResult(value=level, mean=level, variance=var.copy(), count=np.full(level.shape, n, np.int16),
                       n_frames=n, method="mean", exposures=es,
                       paths=tuple(Path(f"d{t_s:g}_{i}.dng") for i in range(n)), channel_names=PLANES,
                       cfa_pattern=cfa, black_level_dn=tuple(black), white_level_dn=white,
                       frame_shape=(2 * level.shape[1], 2 * level.shape[2]), variance_all=var)


def _line_by_hand(points):
    """Per pixel, the frame-weighted least-squares line level = b + β t written out with numpy linear algebra.

    ``points``: ``(t, level, n, per_frame_variance)``, arrays broadcastable to one shape; a level at or above
    white − 1 must be given n = 0. Returns b, β, var(b), var(β) from A = (XᵀWX)⁻¹XᵀW and Cov = A diag(σ²/n) Aᵀ."""
    shape = np.broadcast_shapes(*(np.shape(a) for p in points for a in p))
    t, y, n, v = (np.stack([np.broadcast_to(np.asarray(p[i], float), shape) for p in points], -1) for i in range(4))
    x = np.stack([np.ones_like(t), t], -1)  # (..., m, 2)
    xtw = np.swapaxes(x, -1, -2) * n[..., None, :]
    m = xtw @ x
    line = np.count_nonzero(n > 0, axis=-1) >= 2  # else no line: NaN
    a = np.linalg.solve(np.where(line[..., None, None], m, np.eye(2)), xtw)  # (..., 2, m)
    coef = (a @ y[..., None])[..., 0]
    per = np.where(n > 0, v / np.where(n > 0, n, 1.0), 0.0)
    cov = (a * per[..., None, :]) @ np.swapaxes(a, -1, -2)
    out = coef[..., 0], coef[..., 1], cov[..., 0, 0], cov[..., 1, 1]
    return tuple(np.where(line, o, np.nan) for o in out)


def _plane_figures(k, b, b_var, beta, beta_var, defects, read_noise_var, gain, temporal, dsnu_bias2=None) -> dict:
    """The channel summary of plane k written out with numpy: EMVA 1288-style figures over the good pixels.

    The maps as the model holds them (float32 from :func:`fit_dark`, any float type here): the means and
    variances of their values in float64; the median of the β uncertainties as the model takes it, of the
    square roots in the maps' own type."""
    good = defects[k] == 0
    bk, betak = (np.asarray(a[k][good], np.float64) for a in (b, beta))
    b_var64, beta_var64 = (np.asarray(a[k][good], np.float64) for a in (b_var, beta_var))
    med = float(np.median(betak))
    mad = NORMAL_PER_MAD * float(np.median(np.abs(betak - med)))
    if dsnu_bias2 is None:  # spatial variance of the bias map minus the mean variance of its estimates
        dsnu_bias2 = float(np.var(bk)) - float(np.mean(b_var64))
    dsnu_beta2 = float(np.var(betak)) - float(np.mean(beta_var64))
    return {
        "bias_dn": float(np.mean(bk)),
        "bias_unc_dn": MEDIAN_PER_MEAN_SE * float(np.std(bk)) / np.sqrt(bk.size),
        "dark_current_dn_per_s": med,
        "dark_current_unc_dn_per_s": MEDIAN_PER_MEAN_SE * mad / np.sqrt(betak.size),
        "dark_current_pixel_unc_dn_per_s": float(np.median(np.sqrt(beta_var[k][good]))),
        "dark_current_mean_dn_per_s": float(np.mean(betak)),
        "read_noise_dn": float(np.sqrt(max(read_noise_var, 0.0))),
        "temporal_noise_dn": float(temporal),
        "dsnu_bias_dn": float(np.sqrt(max(dsnu_bias2, 0.0))),
        "dsnu_dark_current_dn_per_s": float(np.sqrt(max(dsnu_beta2, 0.0))),
        "gain_dn_per_e_from_dark": float(gain),
        "hot_pixel_count": int(np.sum((defects[k] & HOT) != 0)),
        "dead_pixel_count": int(np.sum((defects[k] & DEAD) != 0)),
        "noisy_pixel_count": int(np.sum((defects[k] & NOISY) != 0)),
    }


def _assert_figures(got: dict, expect: dict) -> None:
    """Every figure of one plane: the same keys; 1e-9 relative (float64 sums in another order), 1e-4 for the two
    uncertainties that use √(π/2) rounded to 1.2533 (1.1e-5 relative)."""
    assert set(got) == set(expect)
    for key, value in expect.items():
        rel = 1e-4 if key in ("bias_unc_dn", "dark_current_unc_dn_per_s") else 1e-9
        assert got[key] == pytest.approx(value, rel=rel, abs=1e-12), key
        assert type(got[key]) is (int if key.endswith("_count") else float), key


def test_dark_channel_figures_per_plane_against_numpy():
    """``_channel_summary`` against the figures written out with numpy (``_plane_figures``) on random maps with
    hot, dead, noisy and doubly flagged pixels (whose wild values must not enter any figure):

    - read noise: with bias frames the plane mean of the temporal variance minus 1/12 DN²; without, that mean
      over each dark time extrapolated to t = 0 by a least-squares line written out (three times, two times),
      or the one time's mean; in a quantised plane (temporal noise below 1 DN) the quantised fit's value, and
      its DSNU for the bias DSNU (0.4 and 0.3 DN: the square, not twice the value, and not clamped at 1);
    - DSNU of the bias and of β: spatial variance minus the mean variance of the estimates, clamped at 0 (plane
      3's bias map is flatter than its estimates are uncertain); the DSNU of β is between 0 and 1 (DN/s)².
    """
    rng = np.random.default_rng(11)
    shape = (4, 5, 6)
    spread = np.array([3.0, 2.0, 1.5, 0.05])[:, None, None]
    b = 1000.0 + spread * rng.standard_normal(shape)
    b_var = rng.uniform(0.01, 0.05, shape)
    beta = 2.0 + 0.3 * rng.standard_normal(shape)
    beta_var = rng.uniform(0.001, 0.004, shape)
    var_t = rng.uniform(3.5, 4.5, shape)
    defects = np.zeros(shape, np.uint8)
    for (k, y, x), flag in {(0, 1, 1): HOT, (1, 2, 3): NOISY, (2, 0, 5): DEAD, (3, 4, 0): HOT | NOISY,
                            (1, 4, 4): HOT | DEAD, (2, 3, 2): HOT}.items():
        defects[k, y, x] = flag
        b[k, y, x], beta[k, y, x], var_t[k, y, x] = 5000.0, 900.0, 400.0
        b_var[k, y, x] = beta_var[k, y, x] = 50.0
    gain = np.array([0.3, 0.4, 0.5, 0.6])[:, None, None]
    temporal = np.array([0.6, 2.0, 2.1, 1.9])
    noise = TemporalNoise(temporal_noise_dn=temporal, read_noise_dn=np.array([0.4, np.nan, np.nan, np.nan]),
                          dsnu_dn=np.array([0.3, np.nan, np.nan, np.nan]), quantised=temporal < 1.0,
                          noisy=(defects & NOISY) != 0, read_noise_map_dn=np.sqrt(var_t), method="test")
    times = (0.5, 2.0, 8.0)
    stacks = []
    for t in times:  # plane means of the temporal variance curved in t (a line through them is not exact)
        v = var_t + 0.5 * t + 0.1 * t * t + rng.uniform(-0.2, 0.2, shape)
        stacks.append((t, _dark_group(b + beta * t, v, t, 8)))

    def extrapolated(k, sts):
        good = defects[k] == 0
        ts = np.array([t for t, _ in sts])
        vs = np.array([np.mean(np.asarray(s.variance_all[k][good], np.float64)) for _, s in sts])
        if ts.size == 1:
            return vs[0]
        slope = np.sum((ts - ts.mean()) * (vs - vs.mean())) / np.sum((ts - ts.mean()) ** 2)
        return vs.mean() - slope * ts.mean()

    maps32 = tuple(a.astype(np.float32) for a in (b, b_var, beta, beta_var))  # the dark fit's maps are float32
    for have_bias, sts in ((True, stacks), (False, stacks), (False, stacks[:2]), (False, stacks[:1])):
        got = _channel_summary(b, b_var, beta, beta_var, var_t, defects, sts, have_bias, gain, noise, PLANES)
        got32 = _channel_summary(*maps32[:2], *maps32[2:], var_t, defects, sts, have_bias, gain, noise, PLANES)
        assert list(got) == list(PLANES)
        for k, name in enumerate(PLANES):
            if k == 0:
                rn_var, dsnu2 = 0.4**2, 0.3**2
            elif have_bias:
                rn_var, dsnu2 = float(np.mean(var_t[k][defects[k] == 0])) - 1.0 / 12.0, None
            else:
                rn_var, dsnu2 = extrapolated(k, sts) - 1.0 / 12.0, None
            expect = _plane_figures(k, b, b_var, beta, beta_var, defects, rn_var, gain[k, 0, 0], temporal[k], dsnu2)
            _assert_figures(got[name], expect)
            # float32 maps: their means and variances taken in float64 all the same (float32 sums of ~1000 DN
            # values differ by about 1e-7 relative)
            expect = _plane_figures(k, *maps32[:2], *maps32[2:], defects, rn_var, gain[k, 0, 0], temporal[k], dsnu2)
            _assert_figures(got32[name], expect)
    # the guards: 0 < DSNU² of β < 1 in every plane, the bias DSNU² of plane 3 negative before its clamp
    for k in range(4):
        good = defects[k] == 0
        assert 0 < float(np.var(beta[k][good]) - np.mean(beta_var[k][good])) < 1
    assert float(np.var(b[3][defects[3] == 0]) - np.mean(b_var[3][defects[3] == 0])) < 0


def _hot_noisy_by_hand(beta, var_t, dof, hot_sigma=6.0, hot_factor=5.0, noisy_sigma=6.0):
    """The documented defect rules written out: hot if β is not finite or above median + max(hot_sigma robust σ,
    (hot_factor − 1)|median|) of its plane; noisy if the temporal variance is above the plane's mean over the
    non-hot pixels times max(χ²_{1e-6}(dof)/dof, 1 + noisy_sigma √(2/dof))."""
    defects = np.zeros(beta.shape, np.uint8)
    bound = max(float(chi2.isf(1e-6, dof)) / dof, 1.0 + noisy_sigma * np.sqrt(2.0 / dof))
    for k in range(beta.shape[0]):
        fin = beta[k][np.isfinite(beta[k])]
        med = np.median(fin)
        rs = NORMAL_PER_MAD * np.median(np.abs(fin - med))
        hot = ~np.isfinite(beta[k]) | (beta[k] > med + max(hot_sigma * rs, (hot_factor - 1.0) * abs(med)))
        vhat = np.mean(var_t[k][~hot])
        defects[k] = np.where(hot, HOT, 0) | np.where(var_t[k] > vhat * bound, NOISY, 0)
    return defects


def test_dark_noise_stacks_keep_what_the_emva_sheet_reads_and_nothing_more():
    """``dark_noise_stacks``: the groups of two frames or more, the dark groups in their order and then the bias
    frames at their median exposure time (unknown: 0 s); each group's unclipped variance where stacked, else its
    variance; the DSNU stack is the one of most frames (ties: the shorter exposure), its unclipped mean and
    variance. The arrays are the stacks' own (no copy), and the combined values and counts are not kept."""
    shape = (4, 2, 3)
    rng = np.random.default_rng(3)

    def group(t, n, clipped=False, exposure_s="t"):
        st = _dark_group(1000.0 + rng.uniform(0, 5, shape), rng.uniform(3, 5, shape), t, n, exposure_s=exposure_s)
        if clipped:  # a sigma-clipped stack: its unclipped variance and mean are arrays of their own
            st = replace(st, variance=np.zeros(shape, np.float32), mean_all=st.value + np.float32(0.25))
        return st

    lone, short, long_, bias = group(0.1, 1), group(0.5, 8, clipped=True), group(2.0, 8), group(0.0, 16,
                                                                                                 exposure_s=None)
    noise = dark_noise_stacks(((0.1, lone), (0.5, short), (2.0, long_)), bias)
    assert [(t, n) for t, n, _ in noise.groups] == [(0.5, 8), (2.0, 8), (0.0, 16)]
    assert noise.groups[0][2] is short.variance_all and noise.groups[1][2] is long_.variance_all
    assert noise.groups[2][2] is bias.variance_all
    t_sp, n_sp, mean, var = noise.spatial
    assert (t_sp, n_sp) == (0.0, 16) and mean is bias.value and var is bias.variance_all  # the mean stack's mean
    # without bias frames: of the two 8-frame groups the shorter exposure, its unclipped mean
    t_sp, n_sp, mean, var = dark_noise_stacks(((2.0, long_), (0.5, short)), None).spatial
    assert (t_sp, n_sp) == (0.5, 8) and mean is short.mean_all and var is short.variance_all
    no_var_all = replace(long_, variance_all=None)
    assert dark_noise_stacks(((2.0, no_var_all),), None).groups[0][2] is no_var_all.variance
    empty = dark_noise_stacks(((0.1, lone),), None)
    assert empty.groups == () and empty.spatial is None
    kept = {id(a) for g in noise.groups for a in g[2:]} | {id(a) for a in noise.spatial[2:]}
    assert not kept & {id(st.count) for st in (short, long_, bias)} and id(short.value) not in kept


def test_dark_fit_with_bias_frames_and_one_dark_time_against_numpy(tmp_path):
    """``fit_dark`` on bias frames (16, exposure time not recorded: t = 0) and one dark time (4 frames at
    0.5 s), every output against values written out in the test:

    - b and β: the line through the two exact levels; the pixel saturated at 0.5 s has no line: β is the bound
      (white − black)/0.5 s, b the black level, its uncertainty infinite, and it is hot;
    - var(β): the least-squares covariance (``_line_by_hand``) with the per-frame variances of the noise line
      v0 + g·max(level − b, 0), v0 = 4 DN², g = 0.5 DN/e⁻ (each pixel's temporal variance lies on it; the two
      noisy pixels are more than 5× the plane and left out of it); the bias level's signal is 0, not 1 DN, and
      measured from each pixel's own bias, not the black level, also in the plane of the unfitted pixel;
    - hot pixels at the documented threshold median + max(6 robust σ, 4·median) = 10 DN/s in plane 0 (β = 9 and
      exactly 10 are not hot, 13 and 40 are); noisy pixels against the χ² bound of the bias frames' 15 degrees
      of freedom (the 6× pixel of plane 3 is noisy at 15, not at the 3 of the dark frames);
    - the read-noise map √(var − 1/12), every field of the model and its float32 maps, the channel figures (read
      noise from the bias frames), the temperature (mean and range of the dark frames'), the provenance;
    - a bias-only fit of the same bias frames, and frames at two ISO settings refused.
    """
    shape = (4, 6, 8)
    rng = np.random.default_rng(5)
    black, white, t, v0, g = (1000.0, 1002.0, 998.0, 1001.0), 4095.0, 0.5, 4.0, 0.5
    blk = np.asarray(black)[:, None, None]
    bias = blk + rng.integers(-8, 9, shape)
    beta = 2.0 + 0.25 * rng.integers(-1, 2, shape)
    beta[0, 0, :4] = (9.0, 10.0, 13.0, 40.0)
    beta[2, 5, 7] = 8000.0  # saturated at 0.5 s: no line
    level = np.minimum(bias + beta * t, white)
    var_dark = np.where(level >= white, 0.0, v0 + g * beta * t)
    var_bias = np.full(shape, v0)
    var_bias[1, 3, 3] = 100.0 * v0  # noisy
    var_bias[3, 2, 6] = 6.0 * v0  # noisy against the bound of 15 degrees of freedom only
    bias_st = _dark_group(bias, var_bias, 0.0, 16, black=black, exposure_s=None, temps=[30.0] * 16)
    dark_st = _dark_group(level, var_dark, t, 4, black=black, temps=(21.0, 21.5, 22.0, 23.5))
    dark_folder, bias_folder = tmp_path / "dark", tmp_path / "bias"
    stacks = DarkStacks(((t, dark_st),), bias_st, dark_folder, bias_folder, ("d1.dng", "d2.dng"), ("b1.dng",))
    model = fit_dark(stacks)

    fitted = np.ones(shape, bool)
    fitted[2, 5, 7] = False
    b_fit = np.where(fitted, bias, blk)
    weights = np.where(level < white - 1.0, 4.0, 0.0)
    points = [(0.0, bias, 16.0, np.full(shape, v0)),  # the bias level: no dark signal
              (t, level, weights, v0 + g * np.maximum(level - bias, 0.0))]
    e_b, e_beta, e_bvar, e_betavar = _line_by_hand(points)
    e_beta = np.where(fitted, e_beta, (white - blk) / t)
    e_betavar = np.where(fitted, e_betavar, np.inf)
    np.testing.assert_allclose(model.bias_dn, b_fit, rtol=0, atol=1e-9)
    np.testing.assert_allclose(e_beta[fitted], beta[fitted], rtol=1e-12)
    np.testing.assert_allclose(model.dark_current_dn_per_s, e_beta, rtol=1e-7)
    np.testing.assert_allclose(model.dark_current_unc_dn_per_s, np.sqrt(e_betavar), rtol=1e-6)  # float32 maps
    np.testing.assert_allclose(model.read_noise_dn, np.sqrt(var_bias - 1.0 / 12.0), rtol=1e-6)
    for a in (model.bias_dn, model.dark_current_dn_per_s, model.dark_current_unc_dn_per_s, model.read_noise_dn):
        assert a.dtype == np.float32
    e_defects = _hot_noisy_by_hand(np.where(fitted, beta, np.nan), var_bias, 15.0)
    np.testing.assert_array_equal(model.defects, e_defects)
    # plane 0's threshold is exactly 10 DN/s: median 2, 6 robust σ = 6 × 0.25 × 1.4826 < 4 × 2
    assert np.median(beta[0]) == 2.0 and np.median(np.abs(beta[0] - 2.0)) == 0.25
    assert e_defects[0, 0, :4].tolist() == [0, 0, HOT, HOT] and e_defects[2, 5, 7] & HOT
    assert e_defects[1, 3, 3] == NOISY and e_defects[3, 2, 6] == NOISY
    assert not (_hot_noisy_by_hand(np.where(fitted, beta, np.nan), var_bias, 3.0)[3, 2, 6] & NOISY)

    assert model.iso == 100.0 and model.cfa_pattern == "RGGB" and model.exposure_times_s == (0.5,)
    assert model.black_level_dn == black and model.white_level_dn == white
    assert model.temperature_c == pytest.approx(22.0, rel=1e-12)
    for k, name in enumerate(PLANES):
        good = e_defects[k] == 0
        rn_var = float(np.mean(var_bias[k][good])) - 1.0 / 12.0
        # of the maps as the model stores them (float32)
        expect = _plane_figures(k, *(a.astype(np.float32) for a in (b_fit, e_bvar, e_beta, e_betavar)), e_defects,
                                rn_var, g,
                                np.sqrt(np.mean(var_bias[k][(e_defects[k] & HOT) == 0])))
        _assert_figures(model.channels[name], expect)
    assert model.provenance == {
        "dark_folder": str(dark_folder), "bias_folder": str(bias_folder), "dark_files": ["d1.dng", "d2.dng"],
        "bias_files": ["b1.dng"], "frames_per_exposure": {"0.5": 4}, "temperature_range_c": [21.0, 23.5],
        "options": {"method": "sigma_clip", "sigma": 3.0, "hot_sigma": 6.0, "hot_factor": 5.0, "noisy_sigma": 6.0,
                    "saturation_fraction": 0.01, "bias_prior_frames": 1.0},
        "read_noise_method": "per-pixel temporal variance minus the quantisation variance 1/12 DN² (EMVA 1288 eq. 4)",
        "bias_source": "bias frames", "read_noise_source": "bias frames", "black_level_source": "file"}

    # bias only: the bias frames' own model, with the options and folder given
    only = fit_dark(DarkStacks((), bias_st, bias_folder=bias_folder), DarkOptions(hot_sigma=7.0))
    assert only.dark_current_dn_per_s is None
    np.testing.assert_array_equal(only.bias_dn, bias)
    assert only.provenance["bias_folder"] == str(bias_folder) and only.provenance["options"]["hot_sigma"] == 7.0
    # bias frames at another ISO than the darks: refused, naming the dark folder
    with pytest.raises(CamcalError, match="mix ISO") as err:
        fit_dark(replace(stacks, bias=_dark_group(bias, var_bias, 0.0, 16, black=black, iso=200.0)))
    assert err.value.path == dark_folder
    # a frame without an ISO: named in the error
    nameless = replace(dark_st, exposures=(Exposure(exposure_s=t, iso=None),) + dark_st.exposures[1:])
    with pytest.raises(MissingMetadataError) as err:
        fit_dark(replace(stacks, darks=((t, nameless),)))
    assert err.value.path == dark_st.paths[0]


def test_dark_fit_without_bias_frames_takes_the_black_level_as_a_prior(tmp_path):
    """``fit_dark`` on dark frames alone at 0.5, 2 and 8 s (16, 4 and 6 frames), the black level a prior
    point at t = 0 worth 2 frames, against values written out in the test:

    - b and β: the frame-weighted least squares through the prior and the three levels (``_line_by_hand``); the
      levels lie on the line b = black level, so the fit returns the truth, and a prior at another time or
      weight would not; the pixel saturated at every time has the β bound (white − black)/0.5 s;
    - var(β) with the noise line v0 = 4 DN², g = 0.5 DN/e⁻ through the three dark times;
    - the read noise extrapolated to t = 0 from the plane means of the shortest darks (v0 − 1/12 by
      construction), the read-noise map of the shortest darks, noisy pixels against the χ² bound of the shortest
      darks' 15 degrees of freedom; no CFA pattern; temperature unknown when a frame has none; the provenance.
    """
    shape = (4, 6, 8)
    rng = np.random.default_rng(6)
    black, white, v0, g = (1000.0, 1002.0, 998.0, 1001.0), 4095.0, 4.0, 0.5
    blk = np.broadcast_to(np.asarray(black)[:, None, None], shape)
    beta = 2.0 + 0.25 * rng.integers(-1, 2, shape)
    beta[0, 1, 2] = 40.0
    beta[2, 5, 7] = 8000.0  # saturated at every time: no line
    groups = ((0.5, 16), (2.0, 4), (8.0, 6))
    darks, points = [], [(0.0, blk, 2.0, v0)]
    for t, n in groups:
        level = np.minimum(blk + beta * t, white)
        var = np.where(level >= white, 0.0, v0 + g * beta * t)
        if t == 0.5:
            var[3, 2, 6] *= 8.0  # noisy against 15 degrees of freedom, not against the 3 of the 2 s darks
            var_t = var.copy()
        temps = [20.0] * n if t < 8.0 else [None] * n
        darks.append((t, _dark_group(level, var, t, n, black=black, cfa=None, temps=temps)))
        points.append((t, level, np.where(level < white - 1.0, n, 0.0), v0 + g * np.maximum(level - blk, 0.0)))
    model = fit_dark(DarkStacks(tuple(darks), None, tmp_path / "dark"), DarkOptions(bias_prior_frames=2.0))

    fitted = np.ones(shape, bool)
    fitted[2, 5, 7] = False
    e_b, e_beta, e_bvar, e_betavar = _line_by_hand(points)
    e_b = np.where(fitted, e_b, blk)
    e_beta = np.where(fitted, e_beta, (white - blk) / 0.5)
    e_betavar = np.where(fitted, e_betavar, np.inf)
    np.testing.assert_allclose(e_b[fitted], blk[fitted], rtol=1e-12)
    np.testing.assert_allclose(e_beta[fitted], beta[fitted], rtol=1e-12)
    np.testing.assert_allclose(model.bias_dn, e_b, rtol=1e-7)
    np.testing.assert_allclose(model.dark_current_dn_per_s, e_beta, rtol=1e-7)
    np.testing.assert_allclose(model.dark_current_unc_dn_per_s, np.sqrt(e_betavar), rtol=1e-6)
    # the saturated pixel's variance is 0: its read noise is floored at 0, not NaN; computed in float64 from the
    # float32 variances as stacked and stored in float32 (float32 arithmetic differs in the last bit here)
    e_rn = np.sqrt(np.maximum(var_t.astype(np.float32).astype(np.float64) - 1.0 / 12.0, 0.0)).astype(np.float32)
    np.testing.assert_array_equal(model.read_noise_dn, e_rn)
    e_defects = _hot_noisy_by_hand(np.where(fitted, beta, np.nan), var_t, 15.0)
    np.testing.assert_array_equal(model.defects, e_defects)
    assert e_defects[0, 1, 2] == HOT and e_defects[2, 5, 7] == HOT and e_defects[3, 2, 6] == NOISY
    assert not (_hot_noisy_by_hand(np.where(fitted, beta, np.nan), var_t, 3.0)[3, 2, 6] & NOISY)
    assert model.cfa_pattern is None and model.temperature_c is None and model.exposure_times_s == (0.5, 2.0, 8.0)
    for k, name in enumerate(PLANES):
        good = e_defects[k] == 0
        ts = np.array([t for t, _ in groups])
        vs = np.array([np.mean(np.asarray(st.variance_all[k][good], np.float64)) for _, st in darks])
        slope = np.sum((ts - ts.mean()) * (vs - vs.mean())) / np.sum((ts - ts.mean()) ** 2)
        rn_var = vs.mean() - slope * ts.mean() - 1.0 / 12.0
        assert rn_var == pytest.approx(v0 - 1.0 / 12.0, rel=1e-9)
        expect = _plane_figures(k, *(a.astype(np.float32) for a in (e_b, e_bvar, e_beta, e_betavar)), e_defects,
                                rn_var, g,
                                np.sqrt(np.mean(var_t[k][(e_defects[k] & HOT) == 0])))
        _assert_figures(model.channels[name], expect)
    prov = model.provenance
    assert prov["bias_folder"] is None and prov["temperature_range_c"] is None
    assert prov["frames_per_exposure"] == {"0.5": 16, "2": 4, "8": 6}
    assert prov["bias_source"] == "fit of dark frames, black level as prior"
    assert prov["read_noise_source"] == "shortest dark (0.5 s), per-plane value extrapolated to t = 0"


def test_dark_line_fit_over_many_bands_of_every_shape(monkeypatch):
    """``_fit_lines`` with bands of 4 pixels (instead of 8192), so that every shape it accepts is cut into many
    bands: a single pixel (0-d), a run (1-D), rows of one plane (2-D), planes with fewer rows than planes (3-D),
    and 4-D (one band). Every pixel must be fitted exactly once from its own levels: β, b, var(β), var(b) of the
    line through two levels with σ² = 2 DN² per frame and n = 4 frames at t1 = 1 s, t2 = 3 s:
    var(β) = 2σ²/(nΔt²), var(b) = σ²(t1² + t2²)/(nΔt²)."""
    monkeypatch.setattr(camcal.calibrate.dark, "FIT_BAND_PIXELS", 4)
    rng = np.random.default_rng(9)
    for shape in ((), (7,), (5, 3), (4, 3, 5), (2, 4, 3, 2)):
        b = 1000.0 + rng.integers(-20, 21, shape)
        beta = 0.5 * rng.integers(1, 40, shape)
        obs = [(t, b + beta * t, np.full(shape, 4.0), np.full(shape, 2.0)) for t in (1.0, 3.0)]
        f_beta, f_beta_var, f_b, f_b_var, n_times = _fit_lines(obs, 4095.0)
        assert np.shape(f_beta) == shape
        np.testing.assert_allclose(f_beta, beta, rtol=1e-12)
        np.testing.assert_allclose(f_b, b, rtol=1e-12)
        np.testing.assert_allclose(f_beta_var, 2 * 2.0 / (4.0 * 2.0**2), rtol=1e-12)
        np.testing.assert_allclose(f_b_var, 2.0 * (1.0 + 9.0) / (4.0 * 2.0**2), rtol=1e-12)
        np.testing.assert_array_equal(n_times, np.full(shape, 2))


def test_dark_robust_centre_and_spread_and_the_noise_lines_cut_level():
    """``_robust``: the median and the normal-consistent MAD (MAD / Φ⁻¹(3/4)) of the finite values, (NaN, NaN)
    when there are none, (x, 0) for one; ``_max_median_mean``: max(median, mean) of skewed samples either way,
    including one where 3 of 6 values lie at or below the mean while the median is above it (its shortcut needs
    n//2 + 1 of them), and it leaves its input as it was."""
    x = np.array([3.0, np.nan, 1.0, 10.0, np.inf, 2.0, -np.inf, 4.0])
    med, rs = _robust(x.copy())
    assert med == 3.0 and rs == pytest.approx(NORMAL_PER_MAD * 1.0, rel=1e-12)  # |dev| = 0, 2, 7, 1, 1
    assert all(np.isnan(_robust(np.array([np.nan, np.inf]))))
    assert _robust(np.array([2.5])) == (2.5, 0.0)
    for sample, expect in (([1.0, 1.0, 1.0, 1.0, 10.0], 2.8), ([-10.0, -10.0, -1.0, 5.0, 5.0, 5.0], 2.0),
                           ([0.0, 10.0, 10.0, 10.0], 10.0), ([1.0, 2.0, 3.0], 2.0)):
        a = np.array(sample)
        assert _max_median_mean(a) == pytest.approx(expect, rel=1e-12)
        np.testing.assert_array_equal(a, sample)


def test_seed_appendix_inversions_off_axis_with_an_albedo():
    """The seed's first-order and appendix inversions with an albedo of 0.7 at θ0 = 0.3 rad (with ρ = 1 at nadir,
    2ρ and 2/ρ agree and θ0 drops out), against the formulas written out here from their docstrings: the
    first-order ratio ρ(cos²θ0 − cos²θc)·10^(−2εdC); k = (cos²θ0 − cos²θc)/2 and
    q = εd ln10 [(2θ sin 2θ + (1 − 2θ²) cos 2θ)/8] from θ0 to θc; the second-order ratio 2ρ 10^(−2εdC)(k − Cq)
    solved back to C (Brent's method to 1e-13: rel 1e-10), with its limits r ∈ (0, 2ρk] and q > 0."""
    m = SeedModel(albedo=0.7)
    th0, d, c = 0.3, 0.2, np.array([1e-7, 3e-7])
    ed = m.epsilon_L_per_mol_cm * 100.0 * d  # ε d, d in cm
    cc = np.cos(th0) ** 2 - np.cos(m.cutoff_rad) ** 2
    r1 = 0.7 * cc * 10.0 ** (-2 * ed * c)
    np.testing.assert_allclose(m.invert_first_order(r1, d, th0), c, rtol=1e-12)

    def f(t):
        return (2 * t * np.sin(2 * t) + (1 - 2 * t * t) * np.cos(2 * t)) / 8

    k = cc / 2
    q = ed * np.log(10) * (f(m.cutoff_rad) - f(th0))
    r2 = 2 * 0.7 * 10.0 ** (-2 * ed * c) * (k - c * q)
    np.testing.assert_allclose(m.invert_second_order(r2, d, th0), c, rtol=1e-10)
    written = (np.log(r2 / 1.4) + 2 * ed * np.log(10) + k - 1) / (q - np.log(10))
    np.testing.assert_allclose(m.invert_appendix_as_written(r2, d, th0), written, rtol=1e-12)
    corrected = (k - 1 - np.log(r2 / 1.4)) / (2 * np.log(10) * ed + q)
    np.testing.assert_allclose(m.invert_appendix_corrected(r2, d, th0), corrected, rtol=1e-12)
    # the limits: r = 2ρk is C = 0; above it, at 0 and below, NaN (and the values after a NaN are still solved)
    top = 2 * 0.7 * k
    got = m.invert_second_order(np.array([top * 1.2, top, 0.0, -1.0, r2[0]]), d, th0)
    assert got.dtype == np.float64 and np.isnan(got[[0, 2, 3]]).all()
    assert got[1] == pytest.approx(0.0, abs=1e-20) and got[4] == pytest.approx(c[0], rel=1e-10)
    # a depth so small that q ≪ 1 per mol/L (1e-8 m): C up to k/q is solved (here 0.9 k/q, beyond k·q); at
    # depth 0 (q = 0) NaN
    tiny = 1e-8
    et = m.epsilon_L_per_mol_cm * 100.0 * tiny
    qt = et * np.log(10) * (f(m.cutoff_rad) - f(th0))
    assert 0 < qt < 0.5
    ct = 0.9 * k / qt  # mol/L (absurd, so that C·q is 0.9 k)
    rt = 2 * 0.7 * 10.0 ** (-2 * et * ct) * (k - ct * qt)
    assert m.invert_second_order(np.array([rt]), tiny, th0)[0] == pytest.approx(ct, rel=1e-10)
    assert np.isnan(m.invert_second_order(np.array([0.5 * top]), 0.0, th0)).all()


def test_lamp_angle_for_a_point_at_the_lamps_foot_is_zero():
    """A disk point straight below the lamp is reached by the vertical ray: angle 0 (and a point 0.1 m away by
    the angle whose air and water legs add up to 0.1 m: H tan a + d tan(asin(sin a / n)) = 0.1)."""
    from camcal.water.models import lamp_angle_reaching

    assert lamp_angle_reaching(0.5, 0.3, 0.0) == 0.0
    a = lamp_angle_reaching(0.5, 0.3, 0.1)
    assert 0.5 * np.tan(a) + 0.3 * np.tan(np.arcsin(np.sin(a) / 1.33)) == pytest.approx(0.1, rel=1e-12)


# ---- water: the refined model against an independent rendering --------------------------------------------

def _render_refined(c_mol_per_L, depth_m, *, view_air_rad, a_bg_per_m, a_w_per_m, eps, exact: bool, albedo=1.0,
                    sky_cutoff_rad=np.pi / 2, n=N_WATER, reflectance="fresnel"):
    """Radiance ratio of a Lambertian disk under a uniform sky (air zenith angles up to ``sky_cutoff_rad``),
    rendered by quadrature over the refracted cone in the water.

    Downwelling: in-water radiance n² T(θa) L_sky in the refracted cone; the disk (albedo ρ) reflects ρE/π with
    E = ∫ L e^(−τ/μ) μ dΩ; upwelling along the view T(θa,view)/n² e^(−τ/μv); the reference is a white disk in air
    under the same sky, radiance L_sky. With ``exact`` False the sky's T(θ) is replaced by its cosine-weighted
    mean over the sky's air angles (what the closed form does).
    """
    t_air = fresnel_t_from_air if reflectance == "fresnel" else schlick_t_from_air
    tau = (a_w_per_m + a_bg_per_m + np.log(10) * eps * c_mol_per_L * 100) * depth_m
    theta_c = np.arcsin(np.sin(sky_cutoff_rad) / n)
    tbar = quad(lambda a: t_air(a, n) * np.cos(a) * np.sin(a), 0, sky_cutoff_rad, epsabs=0, epsrel=1e-12,
                limit=200)[0] / (0.5 * np.sin(sky_cutoff_rad) ** 2)

    def t_down(theta_w):
        return t_air(np.arcsin(min(n * np.sin(theta_w), 1.0)), n) if exact else tbar

    e = 2 * np.pi * quad(lambda th: n * n * t_down(th) * np.exp(-tau / np.cos(th)) * np.cos(th) * np.sin(th),
                         0, theta_c, epsabs=0, epsrel=1e-12, limit=200)[0]
    mu_v = np.sqrt(1 - (np.sin(view_air_rad) / n) ** 2)
    return albedo * e / np.pi * t_air(view_air_rad, n) / (n * n) * np.exp(-tau / mu_v)


@pytest.mark.parametrize("transmittance", ["mean", "exact"])
@pytest.mark.parametrize("optics", ["full sky, Fresnel", "sky cone of 1.1 rad, Schlick, n = 1.34, albedo 0.7"])
def test_refined_model_off_nadir_with_chlorophyll_matches_a_rendering(transmittance, optics):
    """Off nadir (0.6 rad), C = 2e-7 mol/L, background absorption: the E₃ closed form (or the Gauss-Legendre
    form) against the radiance transfer integrated by adaptive quadrature; also with a sky cone narrower than the
    hemisphere, Schlick's reflectance, another refractive index and a grey disk.

    Tolerance: 1e-9 for the closed form (exact in E₃); 1e-6 for the Gauss-Legendre form, whose 128 nodes in μ
    converge slowly on T(θ)'s square-root edge at the critical angle (measured 1.6e-7).
    """
    extra = {} if optics.startswith("full") else dict(albedo=0.7, sky_cutoff_rad=1.1, n_water=1.34,
                                                       reflectance="schlick")
    m = RefinedModel(transmittance=transmittance, view_angle_rad=0.6, background_absorption_per_m=0.3,
                     water_absorption_per_m=0.425, **extra)
    render = {k if k != "n_water" else "n": v for k, v in extra.items()}
    for c, d in ((2e-7, 0.25), (5e-8, 0.6)):
        expect = _render_refined(c, d, view_air_rad=0.6, a_bg_per_m=0.3, a_w_per_m=0.425,
                                 eps=m.epsilon_L_per_mol_cm, exact=transmittance == "exact", **render)
        assert float(m.ratio(c, d)) == pytest.approx(expect, rel=1e-9 if transmittance == "mean" else 1e-6)


def test_hemispheric_transmittance_against_quadrature():
    """T̄ = ∫ T cos θ sin θ dθ / ∫ cos θ sin θ dθ for a full sky and for a cone of 1 rad."""
    for tmax in (np.pi / 2, 1.0):
        num = quad(lambda a: fresnel_t_from_air(a) * np.cos(a) * np.sin(a), 0, tmax, epsabs=0, epsrel=1e-12)[0]
        assert hemispheric_transmittance(tmax) == pytest.approx(num / (0.5 * np.sin(tmax) ** 2), rel=1e-9)
    # a sky cutoff below the horizon is the full sky
    full = 2 * quad(lambda a: fresnel_t_from_air(a) * np.cos(a) * np.sin(a), 0, np.pi / 2, epsabs=0, epsrel=1e-12)[0]
    assert RefinedModel(sky_cutoff_rad=2.0).transmittance_down_mean() == pytest.approx(full, rel=1e-9)
    assert RefinedModel(sky_cutoff_rad=2.0).water_cutoff_rad() == pytest.approx(np.arcsin(1 / N_WATER), rel=1e-12)


@pytest.mark.parametrize("reflectance", ["fresnel", "schlick"])
def test_lamp_model_off_axis_with_chlorophyll_matches_a_ray_trace(reflectance):
    """Seed §4's point lamp at 0.5 rad, camera at 0.3 rad, C ≠ 0: the model's ratio against irradiances from an
    independent ray trace, E_w = I T(α) e^(−τ/cos β) sin α / (X dX/dα) with X(α) traced and dX/dα by central
    differences, and the inverse-square law with the cosine for the dry disk."""
    h, alpha, view, d, c = 0.8, 0.5, 0.3, 0.3, 1e-7
    m = LampModel(height_m=h, lamp_angle_rad=alpha, view_angle_rad=view, background_absorption_per_m=0.2,
                  reflectance=reflectance)
    n = N_WATER
    t_air = fresnel_t_from_air if reflectance == "fresnel" else schlick_t_from_air

    def x_of(a):  # horizontal distance from the lamp's foot where the refracted ray reaches depth d
        b = np.arcsin(np.sin(a) / n)
        return h * np.tan(a) + d * np.tan(b)

    da = 1e-5
    dx = (x_of(alpha + da) - x_of(alpha - da)) / (2 * da)
    x = x_of(alpha)
    beta = np.arcsin(np.sin(alpha) / n)
    tau = (m.water_absorption_per_m + 0.2 + np.log(10) * m.epsilon_L_per_mol_cm * c * 100) * d
    e_w = t_air(alpha) * np.exp(-tau / np.cos(beta)) * np.sin(alpha) / (x * dx)
    r = np.hypot(x, h + d)
    e_air = (h + d) / r**3
    mu_v = np.sqrt(1 - (np.sin(view) / n) ** 2)
    expect = e_w / e_air * t_air(view) * np.exp(-tau / mu_v) / n**2
    # tolerance: the central difference's truncation error, O(da²) ≈ 1e-10 relative
    assert float(m.ratio(c, d)) == pytest.approx(expect, rel=1e-8)
    optics = RefinedModel(view_angle_rad=view, background_absorption_per_m=0.2, reflectance=reflectance)
    assert float(lamp_ratio(c, d, h, alpha, optics)) == pytest.approx(expect, rel=1e-8)


@pytest.mark.parametrize("line_fwhm_nm", [1.0, 9.0])
def test_narrowband_slit_correction_against_gaussian_convolutions(line_fwhm_nm):
    """The narrowband estimator reads c ⊛ line at λ0 from a curve measured through a 5 nm slit (c ⊛ slit).

    With a Gaussian sensitivity c = exp(−(λ−μ)²/2s²) both convolutions are closed forms (variances add):
    (c ⊛ g_σ)(λ) = s/√(s²+σ²) · exp(−(λ−μ)²/2(s²+σ²)). The estimator's second-order correction must give the
    rate of a unit line within 2e-4 (the neglected fourth-order term and the spline's c''; measured 6e-5); the
    correction itself is 0.2-0.5 % at 663 nm on this curve.
    """
    wl = np.arange(400.0, 721.0, 5.0)
    mu, s, slit = 620.0, 30.0, 5.0
    f2s = 1 / (2 * np.sqrt(2 * np.log(2)))

    def conv(lam, fwhm):
        v = s * s + (fwhm * f2s) ** 2
        return 50.0 * s / np.sqrt(v) * np.exp(-((lam - mu) ** 2) / (2 * v))

    c = {"R": conv(wl, slit), "G": 0.1 * conv(wl - 90, slit), "B": 0.05 * conv(wl - 180, slit)}
    model = radiance_model(wl, c, None, 663.0, "narrowband", line_fwhm_nm=line_fwhm_nm, slit_fwhm_nm=slit)
    assert model.channel == "R"
    rate = conv(663.0, line_fwhm_nm)  # DN/s of a line of unit in-band radiance
    assert model.weights[0] * rate == pytest.approx(1.0, abs=2e-4)  # measured 4e-5 (1 nm), 6e-5 (9 nm)
    assert abs(rate / conv(663.0, slit) - 1) > 2e-3  # the correction matters at this precision


def test_schlick_from_the_water_side_uses_the_air_side_angle():
    """Schlick from below (n1 > n2) is R0 + (1 − R0)(1 − cos θ_air)⁵ with θ_air from Snell, so it equals Schlick
    from above at that angle (reciprocity); R0 = ((n − 1)/(n + 1))² = 0.02006 for n = 1.33."""
    r0 = (0.33 / 2.33) ** 2
    for theta_w in (0.3, 0.6, 0.8):
        theta_a = np.arcsin(N_WATER * np.sin(theta_w))
        expect = r0 + (1 - r0) * (1 - np.cos(theta_a)) ** 5
        assert float(schlick_reflectance(theta_w, N_WATER, 1.0)) == pytest.approx(expect, rel=1e-12)
        assert float(schlick_reflectance(theta_a, 1.0, N_WATER)) == pytest.approx(expect, rel=1e-12)
    # the refined model with Schlick: T_up at an oblique view from the air-side angle
    view = 0.9
    expect = 1 - (r0 + (1 - r0) * (1 - np.cos(view)) ** 5)
    assert RefinedModel(view_angle_rad=view, reflectance="schlick").transmittance_up() == pytest.approx(expect)


def test_seed_first_and_second_order_off_axis_with_albedo():
    """Eq. 11 and the appendix's (k, q) model from a start angle θ0 = 0.2 rad with ρ = 0.6, against the seed's
    integrand in decadic form integrated over [θ0, θc] (second order: 10^(−2A)(1 − A ln10 θ²))."""
    m = SeedModel(albedo=0.6)
    c, d, th0 = 1e-7, 0.2, 0.2
    a = m.epsilon_L_per_mol_cm * c * d * 100
    tc = m.cutoff_rad
    first = 0.6 * (np.cos(th0) ** 2 - np.cos(tc) ** 2) * 10 ** (-2 * a)
    assert m.ratio_first_order(c, d, th0) == pytest.approx(first, rel=1e-12)
    second = 2 * 0.6 * quad(lambda t: 10 ** (-2 * a) * (1 - a * np.log(10) * t * t) * np.cos(t) * np.sin(t), th0, tc,
                            epsabs=0, epsrel=1e-13)[0]
    assert m.ratio_second_order(c, d, th0) == pytest.approx(second, rel=1e-10)


@pytest.mark.parametrize("transmittance", ["mean", "exact"])
def test_ratio_derivatives_against_central_differences(transmittance):
    """dR/dτ of the refined model's form (E₃ closed form or Gauss-Legendre) and of the lamp's exponential form,
    against a central difference of R (step 1e-5: truncation ≈ 1e-10 relative)."""
    forms = [RefinedModel(view_angle_rad=0.4, transmittance=transmittance).closed_form(),
             LampModel(height_m=0.7, lamp_angle_rad=0.4, view_angle_rad=0.2).closed_form_at(0.3)]
    h = 1e-5
    tau = np.array([0.3, 1.7])  # an array of τ, as the inversion passes them
    for f in forms:
        num = (f.ratio(tau + h) - f.ratio(tau - h)) / (2 * h)
        np.testing.assert_allclose(f.ratio_derivative(tau), num, rtol=1e-7)
        np.testing.assert_allclose(f.dlog_ratio_dtau(tau), num / f.ratio(tau), rtol=1e-7)
        assert np.shape(f.dlog_ratio_dtau(tau)) == tau.shape


def test_lamp_toward_a_disk_point_aims_the_ray_there():
    """Per-pixel geometry: the lamp angle of ``toward(dx, dy, d)`` sends the refracted ray (traced here) to the
    horizontal distance √((X0 + dx)² + dy²) from the lamp's foot; the other settings are kept."""
    h, d, n = 0.9, 0.25, 1.34
    lamp = LampModel(height_m=h, lamp_angle_rad=0.35, view_angle_rad=0.1, background_absorption_per_m=0.1, n_water=n)
    x0 = h * np.tan(0.35) + d * np.tan(np.arcsin(np.sin(0.35) / n))
    for dx, dy in ((0.04, 0.0), (-0.03, 0.05)):
        aim = lamp_toward(lamp, dx, dy, d)
        a = aim.lamp_angle_rad
        landed = h * np.tan(a) + d * np.tan(np.arcsin(np.sin(a) / n))
        assert landed == pytest.approx(np.hypot(x0 + dx, dy), rel=1e-10)
        assert (aim.height_m, aim.view_angle_rad, aim.background_absorption_per_m) == (h, 0.1, 0.1)


def test_refined_model_at_a_wavelength_keeps_the_other_settings():
    m = refined_at_wavelength(680.0, view_angle_rad=0.3, background_absorption_per_m=0.2)
    assert (m.view_angle_rad, m.background_absorption_per_m) == (0.3, 0.2)
    assert m.water_absorption_per_m == pytest.approx(0.465)  # Pope & Fry (1997) at 680 nm, m⁻¹


def test_refracted_angles_use_the_models_refractive_index():
    """Snell with n = 1.34 (sea water) rather than the default 1.33, for the view, the lamp ray and T_up."""
    n = 1.34
    for m in (RefinedModel(n_water=n, view_angle_rad=0.7), LampModel(n_water=n, view_angle_rad=0.7,
                                                                      lamp_angle_rad=0.7)):
        assert m.view_water_rad() == pytest.approx(np.arcsin(np.sin(0.7) / n), rel=1e-12)
        assert m.transmittance_up() == pytest.approx(fresnel_t_from_air(0.7, n), rel=1e-12)
    assert LampModel(n_water=n, lamp_angle_rad=0.7).refracted_angle_rad() == pytest.approx(
        np.arcsin(np.sin(0.7) / n), rel=1e-12)


def test_unknown_transmittance_mode_is_named():
    with pytest.raises(ValueError, match="unknown transmittance 'approx'"):
        RefinedModel(transmittance="approx").closed_form()

"""The one correction path (camcal.models.correct), quantisation-aware noise, and the synthetic camera presets.

Real-sensor conditions of issue 15: hot pixels that saturate in the blue of a sweep, a 10-bit sensor with
sub-DN read noise (the Raspberry Pi IMX296's real dark frames in ../shared/realdata/pi), frame-to-frame
offsets, per-channel black levels, dead pixels found by their response.
"""

from __future__ import annotations

import json
import shutil
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import rawpy
from scipy.optimize import minimize
from scipy.special import erfc

from camcal.calibrate.dark import fit_dark
from camcal.calibrate.dark_frames import measure_dark
from camcal.calibrate.dark_noise import quantised_noise_fit
from camcal.calibrate.run import calibrate_session
from camcal.errors import CamcalError
from camcal.frame import PLANES
from camcal.models.correct import (
    Calibration,
    Corrected,
    correct_planes,
    dark_frame,
    require_valid,
    system_gain_dn_per_e,
)
from camcal.models.dark import DEAD, HOT, NOISY, DarkModel
from camcal.models.profile import contract
from camcal.synth.camera import SyntheticCamera, preset
from camcal.synth.session import SessionPlan, write_session
from tests.conftest import assert_one_line_error, run_cli
from tests.helpers import _dark_model

#: Every test here is a fast formula test (the mutation-testing selection, docs/testing.md).
pytestmark = pytest.mark.formula

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
PI_DARKS = sorted((REALDATA / "pi").glob("dark_frame_*.dng")) if REALDATA.is_dir() else []


def _dark(shape, rng, read_noise_dn=None) -> DarkModel:
    """A dark model of known maps at ISO 100: bias ~500 DN, β 1-3 DN/s, read noise 2 DN (or ``read_noise_dn``),
    no defects; per-plane numbers without a gain from the dark (so Calibration.of finds K = 0)."""
    return DarkModel(
        bias_dn=(500 + rng.normal(0, 1, shape)).astype(np.float32),
        dark_current_dn_per_s=rng.uniform(1, 3, shape).astype(np.float32),
        dark_current_unc_dn_per_s=np.zeros(shape, np.float32),
        read_noise_dn=np.full(shape, 2.0, np.float32) if read_noise_dn is None else read_noise_dn,
        defects=np.zeros(shape, np.uint8), iso=100.0, cfa_pattern="RGGB", temperature_c=None,
        channels={p: {"hot_pixel_count": 0, "dead_pixel_count": 0, "noisy_pixel_count": 0} for p in PLANES})


def test_correct_planes_against_independent_formulas(rng):
    shape = (4, 6, 8)
    dark = _dark(shape, rng)
    dark.defects[0, 1, 1] = HOT
    gain = rng.uniform(0.6, 1.0, shape).astype(np.float32)
    k = np.array([0.5, 0.6, 0.6, 0.7], np.float32)[:, None, None]
    cal = Calibration(dark=dark, flat_gain=gain, defects=dark.defects != 0, inv_flat_gain=1 / gain,
                      noise_gain_dn_per_e=k)
    raw = rng.integers(520, 4000, shape).astype(np.float32)
    raw[0, 1, 1] = 4095  # a known hot pixel at the white level
    raw[2, 3, 4] = 4095  # a saturated pixel
    out = correct_planes(raw.copy(), cal, exposure_s=10.0, iso=200.0, white_level_dn=4095,
                         black_level_dn=np.full(4, 512.0), variance=True)
    ds = dark.dark_current_dn_per_s * 10.0 * 2.0
    expect = (raw - dark.bias_dn - ds) / gain
    np.testing.assert_allclose(out.signal_dn, expect, rtol=2e-6, atol=1e-3)
    var = (np.maximum(raw - dark.bias_dn, 0) * k * 2.0 + 4.0 * 4.0) / gain**2
    np.testing.assert_allclose(out.variance_dn2, var, rtol=2e-5)
    # the hot pixel is a defect, never "saturated"; the saturated pixel is invalid and saturated
    assert out.invalid[0, 1, 1] and out.defective[0, 1, 1] and not out.saturated[0, 1, 1]
    assert out.invalid[2, 3, 4] and out.saturated[2, 3, 4]
    assert out.saturated_fraction()[0] == 0.0
    assert out.saturated_fraction()[2] == pytest.approx(1 / 48)
    assert np.count_nonzero(out.invalid) == 2
    # without a dark model: the file's black level per plane; a raw 0 is clipped when the black level is above 0
    raw[1, 0, 0] = 0
    plain = correct_planes(raw, Calibration(), exposure_s=None, iso=None, white_level_dn=4095,
                           black_level_dn=np.array([512.0, 510.0, 514.0, 508.0]))
    np.testing.assert_allclose(plain.signal_dn[3], raw[3] - 508.0)
    assert plain.invalid[1, 0, 0] and plain.saturated[1, 0, 0]


class _Flat:
    def __init__(self, gain):
        self._gain = gain

    def gain(self, with_prnu: bool = False):
        return self._gain


@pytest.mark.parametrize("how", ["of", "gain_only"])
def test_correction_divides_by_the_flat_gain(how):
    """s = (d − bias − β t S/S_dark) / g with g from a flat model (Calibration.of) or given alone."""
    rng = np.random.default_rng(3)
    shape = (4, 5, 7)

    dark = _dark(shape, rng)
    gain = rng.uniform(0.5, 0.9, shape).astype(np.float32)
    cal = Calibration.of(dark, _Flat(gain)) if how == "of" else Calibration(dark=dark, flat_gain=gain)
    raw = rng.uniform(800, 3000, shape).astype(np.float32)
    out = correct_planes(raw.copy(), cal, exposure_s=4.0, iso=400.0, white_level_dn=4095,
                         black_level_dn=np.full(4, 512.0))
    expect = (raw.astype(np.float64) - dark.bias_dn - dark.dark_current_dn_per_s * 4.0 * 4.0) / gain
    np.testing.assert_allclose(out.signal_dn, expect, rtol=1e-5)


def test_correct_planes_on_a_window_equals_the_whole_frame(rng):
    shape = (4, 10, 12)
    dark = _dark(shape, rng)
    cal = Calibration.of(dark)
    raw = rng.integers(520, 4000, shape).astype(np.float32)
    whole = correct_planes(raw.copy(), cal, exposure_s=3.0, iso=100.0, white_level_dn=4095,
                           black_level_dn=np.full(4, 512.0))
    win = (slice(2, 7), slice(3, 11))
    part = correct_planes(raw[:, win[0], win[1]].copy(), cal, exposure_s=3.0, iso=100.0, white_level_dn=4095,
                          black_level_dn=np.full(4, 512.0), full_shape=shape, window=win)
    np.testing.assert_array_equal(part.signal_dn, whole.signal_dn[:, win[0], win[1]])
    with pytest.raises(CamcalError, match="do not match"):
        correct_planes(raw[:, :5], cal, exposure_s=3.0, iso=100.0, white_level_dn=4095,
                       black_level_dn=np.full(4, 512.0))


def test_variance_on_a_window_below_and_near_the_bias(rng):
    """EMVA 1288 variance var = (K k max(s + dark, 0) + σ_read² k²) / g² on a window of the frame, with a
    per-pixel read-noise map and raw values below the bias and within 1 DN above it (the shot term is 0 and
    then tiny there: clipped at 0, not at anything else)."""
    shape = (4, 8, 10)
    dark = _dark(shape, rng, read_noise_dn=rng.uniform(1.0, 4.0, shape).astype(np.float32))
    gain = rng.uniform(0.6, 1.0, shape).astype(np.float32)
    kdn = np.array([0.5, 0.6, 0.6, 0.7], np.float32)[:, None, None]
    cal = Calibration(dark=dark, flat_gain=gain, inv_flat_gain=1 / gain, noise_gain_dn_per_e=kdn)
    t, iso = 0.01, 200.0
    level = dark.bias_dn + dark.dark_current_dn_per_s * t * 2.0
    raw = (level + rng.uniform(-30, 60, shape)).astype(np.float32)
    raw[:, :, :3] = (level[:, :, :3] + rng.uniform(0.05, 0.95, (4, 8, 3))).astype(np.float32)  # 0 < s < 1 DN
    win = (slice(1, 7), slice(2, 9))
    out = correct_planes(raw[:, win[0], win[1]].copy(), cal, exposure_s=t, iso=iso, white_level_dn=4095,
                         black_level_dn=np.full(4, 512.0), full_shape=shape, window=win, variance=True)
    above_bias = raw.astype(np.float64) - dark.bias_dn
    var = (np.maximum(above_bias, 0) * kdn * 2.0 + dark.read_noise_dn.astype(np.float64) ** 2 * 4.0) / gain**2
    assert np.any(above_bias[:, win[0], win[1]] < 0) and np.any((above_bias > 0) & (above_bias < 1))
    np.testing.assert_allclose(out.variance_dn2, var[:, win[0], win[1]], rtol=1e-4)
    plain = correct_planes(raw.copy(), cal, exposure_s=t, iso=iso, white_level_dn=4095,
                           black_level_dn=np.full(4, 512.0))
    assert plain.variance_dn2 is None  # computed only when asked for (the hot path of apply skips it)


def test_raw_zero_is_clipped_only_with_a_black_level_and_float32_out(rng):
    """A raw 0 is clipped when the black level is above 0 (and a raw 1 is not); with a zero black level (processed
    RGB) 0 is a value. The result is float32, also when integer planes are corrected "in place" (they cannot be:
    a float32 copy is made); a dark model without a dark-current attribute still needs t.

    (Named so that the mutation run's test selection, which leaves out ``test_cli*``, keeps it.)"""
    raw = np.full((4, 2, 3), 300.0, np.float32)
    raw[0, 0, 0], raw[1, 0, 0] = 0, 1
    with_black = correct_planes(raw.copy(), Calibration(), exposure_s=None, iso=None, white_level_dn=4095,
                                black_level_dn=np.full(4, 64.0))
    assert with_black.invalid[0, 0, 0] and not with_black.invalid[1, 0, 0]
    assert with_black.clipped[0, 0, 0] and not with_black.clipped[1, 0, 0] and with_black.clipped.sum() == 1
    assert with_black.signal_dn.dtype == np.float32
    ints = raw.astype(np.uint16)
    as_ints = correct_planes(ints, Calibration(), exposure_s=None, iso=None, white_level_dn=4095,
                             black_level_dn=np.full(4, 64.0), inplace=True)
    assert as_ints.signal_dn.dtype == np.float32 and as_ints.signal_dn[2, 1, 1] == 300.0 - 64.0
    assert ints[2, 1, 1] == 300  # the integer input is left as it was
    zero = correct_planes(raw.copy(), Calibration(), exposure_s=None, iso=None, white_level_dn=4095,
                          black_level_dn=np.zeros(4))
    assert not zero.invalid.any()

    class Frameonly:
        def dark_frame_dn(self, exposure_s, iso):
            return np.full((4, 2, 3), 10.0 + exposure_s)

    with pytest.raises(CamcalError, match="needs the exposure time"):
        correct_planes(raw.copy(), Calibration(dark=Frameonly()), exposure_s=None, iso=None, white_level_dn=4095,
                       black_level_dn=np.full(4, 64.0))


def test_require_valid_says_why(rng):
    shape = (4, 10, 10)
    raw = np.full(shape, 1000.0, np.float32)
    raw[1, :6] = 4095  # 60 % of G1 saturated
    defects = np.zeros(shape, bool)
    defects[2, :6] = True  # 60 % of G2 known defects
    out = correct_planes(raw, Calibration(defects=defects), exposure_s=1.0, iso=100.0, white_level_dn=4095,
                         black_level_dn=np.zeros(4))
    with pytest.raises(CamcalError, match=r"only 40 % valid pixels in channel G1 .*: 60 % saturated outside known "
                                          r"defects"):
        require_valid(out, Path("x.dng"))
    require_valid(out, Path("x.dng"), min_valid_fraction=0.3)


def test_require_valid_names_known_defects_the_region_and_passes_at_exactly_the_threshold():
    """The worst channel decides; its message is checked whole against counts made here: G2 with 70 of 100 pixels
    known defects (30 % valid) is named before G1 with 60 saturated (40 % valid), with the region it was measured
    on. A channel at exactly the threshold passes (50 of 100 valid, the default 0.5); equal saturated and defect
    shares are reported as saturation (the cause the user can change)."""
    shape = (4, 10, 10)
    raw = np.full(shape, 1000.0, np.float32)
    raw[1, :6] = 4095
    defects = np.zeros(shape, bool)
    defects[2, :7] = True
    out = correct_planes(raw, Calibration(defects=defects), exposure_s=1.0, iso=100.0, white_level_dn=4095,
                         black_level_dn=np.zeros(4))
    np.testing.assert_allclose(out.valid_fraction(), [1.0, 0.4, 0.3, 1.0], rtol=0, atol=1e-15)  # 1 − k/100
    np.testing.assert_array_equal(out.saturated_fraction(), [0.0, 0.6, 0.0, 0.0])
    with pytest.raises(CamcalError) as err:
        require_valid(out, Path("x.dng"), region="ROI")
    assert str(err.value) == ("x.dng: frame has only 30 % valid pixels in channel G2 (need 50 %): "
                              "70 % of the ROI are known defects (masked)")
    with pytest.raises(CamcalError) as err:
        require_valid(out, Path("x.dng"), what="flat")
    assert str(err.value).endswith("flat has only 30 % valid pixels in channel G2 (need 50 %): "
                                   "70 % are known defects (masked)")
    half = np.full(shape, 1000.0, np.float32)
    half[0, :5] = 4095  # exactly 50 % of R saturated
    tie_defects = np.zeros(shape, bool)
    tie_defects[3, :2] = True  # B: 20 % known defects and 20 % saturated
    half[3, 2:4] = 4095
    out = correct_planes(half, Calibration(defects=tie_defects), exposure_s=1.0, iso=100.0, white_level_dn=4095,
                         black_level_dn=np.zeros(4))
    require_valid(out, Path("x.dng"))  # R at exactly 50 % valid passes the default threshold
    require_valid(correct_planes(np.full(shape, 1000.0, np.float32), Calibration(), exposure_s=1.0, iso=100.0,
                                 white_level_dn=4095, black_level_dn=np.zeros(4)), Path("x.dng"))
    with pytest.raises(CamcalError) as err:
        require_valid(out, Path("x.dng"), min_valid_fraction=0.7)
    assert str(err.value) == ("x.dng: frame has only 50 % valid pixels in channel R (need 70 %): "
                              "50 % saturated outside known defects; shorten the exposure")
    one = Corrected(out.signal_dn[3:], None, out.invalid[3:], out.saturated[3:], out.defective[3:],
                    out.clipped[3:], ("B",))
    with pytest.raises(CamcalError) as err:
        require_valid(one, Path("x.dng"), min_valid_fraction=0.7)
    assert str(err.value).endswith("only 60 % valid pixels in channel B (need 70 %): "
                                   "20 % saturated outside known defects; shorten the exposure")


def _quantised_pairs(rng, n, sigma, dsnu, mean, offset):
    mu = mean + dsnu * rng.standard_normal(n)
    return (np.rint(mu + sigma * rng.standard_normal(n)).astype(np.int64),
            np.rint(mu + offset + sigma * rng.standard_normal(n)).astype(np.int64))


@pytest.mark.parametrize("dsnu", [0.02, 0.3, 2.0])
def test_quantised_noise_fit_recovers_sub_dn_read_noise(rng, dsnu):
    """σ = 0.4 DN: ``var − 1/12`` is off where the pixel means sit near one value; the likelihood is not.

    300 000 pixel pairs: the ML estimate's standard error is ~0.2 %, the tolerance 3 % (the issue's).
    """
    a, b = _quantised_pairs(rng, 300_000, 0.4, dsnu, 60.2, -0.1)
    sigma, sd, off = quantised_noise_fit(a, b)
    assert sigma == pytest.approx(0.4, rel=0.03)
    assert off == pytest.approx(-0.1, abs=0.01)
    if dsnu == 0.02:
        sheppard = np.sqrt(np.var((a - b).astype(float)) / 2 - 1 / 12)
        assert abs(sheppard / 0.4 - 1) > 0.05, sheppard  # the correction this replaces is wrong here


def _quantised_pair_ml(a, b, start_dsnu, start_sigma, eps=1e-4):
    """Maximum likelihood of the model of :func:`camcal.calibrate.dark.quantised_noise_fit`'s docstring, written out
    here: P(k1 = i, k2 = j) = ∫ N(μ; m, dsnu²) p(i | μ) p(j | μ + o) dμ with p(i | c) = Φ((i + ½ − c)/σ) − Φ((i − ½ −
    c)/σ) on the cells [lo, hi]² of the levels between the 0.02 % and 99.98 % quantiles, mixed with a uniform outlier
    weight ``eps`` over those cells, Φ from the complementary error function; the μ integral by the trapezoid rule
    on ±8 dsnu (481 points: steps of σ/3 or less here), maximised by Powell's method from the truth. Returns σ,
    dsnu, o."""
    both = np.concatenate([a, b])
    lo, hi = int(np.floor(np.quantile(both, 2e-4))), int(np.ceil(np.quantile(both, 1 - 2e-4)))
    inside = (a >= lo) & (a <= hi) & (b >= lo) & (b <= hi)
    levels = np.arange(lo, hi + 1, dtype=float)
    counts = np.zeros((levels.size, levels.size))
    np.add.at(counts, (a[inside] - lo, b[inside] - lo), 1.0)
    z = np.linspace(-8.0, 8.0, 481)
    wz = np.exp(-0.5 * z**2) / np.trapezoid(np.exp(-0.5 * z**2), z)

    def cells(centre, s):  # (μ nodes, levels): probability of reading each level, Φ(x) = erfc(−x/√2)/2
        x = (levels[None, :] - centre[:, None]) / (s * np.sqrt(2.0))
        return 0.5 * (erfc(-x - 0.5 / (s * np.sqrt(2.0))) - erfc(-x + 0.5 / (s * np.sqrt(2.0))))

    def nll(p):
        m, o, sd, s = p[0], p[1], np.exp(p[2]), np.exp(p[3])
        mu = m + sd * z
        prob = (cells(mu, s) * (wz * (z[1] - z[0]))[:, None]).T @ cells(mu + o, s)  # trapezoid: ends are 1e-14
        return -float(np.sum(counts * np.log((1 - eps) * prob + eps / levels.size**2)))

    start = [float(a.mean()), float((b - a).mean()), np.log(start_dsnu), np.log(start_sigma)]
    r = minimize(nll, start, method="Powell", options={"xtol": 1e-8, "ftol": 1e-13, "maxfev": 20000})
    return float(np.exp(r.x[3])), float(np.exp(r.x[2])), float(r.x[1])


@pytest.mark.parametrize(("sigma", "dsnu", "telegraph"), [(0.45, 0.35, 3e-3), (0.4, 4.0, 0.0)])
def test_quantised_noise_fit_is_the_maximum_of_the_documented_likelihood(rng, sigma, dsnu, telegraph):
    """σ, dsnu and the frame offset are the maximum of the quantised-normal likelihood with its outlier weight,
    against that likelihood written out and maximised here by another method (``_quantised_pair_ml``).

    20 000 pixel pairs, mean 60.3 DN, offset −0.15 DN:

    - σ = 0.45 DN, dsnu = 0.35 DN and 0.3 % random-telegraph pixels that read 3 DN higher in the second frame:
      more than the 0.02 % the level range leaves out, so the outlier weight must carry them (without it σ would
      grow to cover them);
    - σ = 0.4 DN, dsnu = 4 DN: pixel means spread over many levels, where the μ integral must resolve the 1 DN
      cells (a 48-node Gauss–Hermite rule gave σ = 0.51 DN and dsnu = 3.3 DN here).

    Tolerance 5e-5 DN: the simplex stops at 1e-5 in log σ and log dsnu (5e-6 DN and 4e-5 DN) and the two
    integrals over μ agree to ~1e-6; the estimator's own spread at this size is ~4e-3 DN in σ, so this checks
    the maximum, not the data. The fit warns about nothing.
    """
    n = 20_000
    mu = 60.3 + dsnu * rng.standard_normal(n)
    a = np.rint(mu + sigma * rng.standard_normal(n)).astype(np.int64)
    b = np.rint(mu - 0.15 + sigma * rng.standard_normal(n)).astype(np.int64)
    b[rng.random(n) < telegraph] += 3
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = quantised_noise_fit(a, b)
    expect = _quantised_pair_ml(a, b, dsnu, sigma)
    np.testing.assert_allclose(got, expect, rtol=0, atol=5e-5)
    # and the maximum is the truth, to the estimator's spread (σ ~1 %, dsnu ~1 % at dsnu = 4 DN)
    assert got[0] == pytest.approx(sigma, rel=0.05) and got[1] == pytest.approx(dsnu, rel=0.1)


def test_quantised_noise_fit_carries_far_hot_pixels_in_its_outlier_weight(rng):
    """0.5 % hot pixels 150 DN above a plane of σ = 0.4 DN, dsnu = 0.3 DN (16 000 pixel pairs): more than the 0.02 %
    the level range leaves out, so they are in the histogram. Each costs the outlier weight's log(1e-4/n²) ≈ −19
    nats; a dsnu wide enough to reach them would cost every other pixel ~log(35/0.3) ≈ 4.8 nats, so the maximum is
    the bulk's σ and dsnu. Against the simulation's truth: σ to 5 % and dsnu to 10 % (spreads ~1.5 % and ~2 % at
    this size); a fit started at the moment estimate of dsnu (~10 DN, inflated by the hot pixels) ends in the wide
    minimum, dsnu ≈ 35 DN."""
    n = 16_000
    mu = 60.2 + 0.3 * rng.standard_normal(n)
    mu[rng.random(n) < 5e-3] += 150.0
    a = np.rint(mu + 0.4 * rng.standard_normal(n)).astype(np.int64)
    b = np.rint(mu + 0.4 * rng.standard_normal(n)).astype(np.int64)
    sigma, dsnu, offset = quantised_noise_fit(a, b)
    assert sigma == pytest.approx(0.4, rel=0.05)
    assert dsnu == pytest.approx(0.3, rel=0.1)
    assert offset == pytest.approx(0.0, abs=0.02)  # 4 standard errors (0.0045 DN) of a mean difference of 16 000 pairs


def test_duplicate_frames_refused_by_content(tmp_path, camera):
    d = tmp_path / "bias"
    d.mkdir()
    rngs = [np.random.default_rng(i) for i in range(2)]
    from camcal.synth.camera import Scene

    for i, r in enumerate(rngs):
        camera.write_dng(d / f"b{i}.dng", Scene.dark(), exposure_s=1 / 4000, rng=r)
    shutil.copy(d / "b0.dng", d / "b2.dng")
    with pytest.raises(CamcalError, match="same pixels as b0.dng"):
        fit_dark(measure_dark(None, d))
    proc = run_cli("dark", tmp_path / "x", "--bias", d, "-o", tmp_path / "dark.json")
    assert proc.returncode == 2


# ---- presets: every stage on each, at a reduced geometry ---------------------------------------------------------

PLAN = SessionPlan(n_bias=8, n_dark=4, n_flat=6, linearity_jpeg=False, sweep_jpeg=False, sweep_step_nm=10.0,
                   n_sweep=2)


@pytest.fixture(scope="module")
def preset_session(tmp_path_factory):
    """``get(name)``: a calibrated session of a preset camera, made once per module and worker (the IMX296 at
    384x288: its bits, levels and noise, not its size)."""
    cache: dict[str, tuple] = {}

    def get(name: str) -> tuple:
        if name not in cache:
            size = {"width": 384, "height": 288} if name == "imx296" else {}
            cam = SyntheticCamera(preset(name, **size))
            out = write_session(tmp_path_factory.mktemp(name) / "S", cam, PLAN)
            profile, notes = calibrate_session(out)
            cache[name] = (name, cam, json.loads((out / "truth.json").read_text()), profile, notes)
        return cache[name]

    return get


@pytest.mark.parametrize("name", ["imx296", "hot", "offsets"])
def test_every_stage_on_each_preset(preset_session, name):
    name, cam, truth, profile, notes = preset_session(name)
    c = contract(profile)
    for ch, planes in (("R", ("R",)), ("G", ("G1", "G2")), ("B", ("B",))):
        beta = float(np.mean([truth["dark_current_dn_per_s"][p] for p in planes]))
        assert c["dark"]["dark_current_dn_per_s"][ch] == pytest.approx(beta, rel=0.02), (name, ch)
        rn = float(np.mean([truth["read_noise_dn"][p] for p in planes]))
        assert c["dark"]["read_noise_dn"][ch] == pytest.approx(rn, rel=0.03), (name, ch)
        bias = float(np.mean([truth["bias_dn"][p] for p in planes]))
        assert c["dark"]["bias_dn"][ch] == pytest.approx(bias, abs=0.1), (name, ch)
    assert c["dark"]["hot_pixel_count"] == pytest.approx(truth["hot_pixel_count"], rel=0.05)
    assert c["dark"]["dead_pixel_count"] == 0
    # the vignetting model against the camera's own map, everywhere: PRNU-limited (1 % per pixel, not reduced
    # by more frames) on 6 flats of 192x144 planes; measured 0.08-0.66 % over two seeds of the IMX296 preset
    err = np.abs(profile.flat.gain() / cam.vignetting_map - 1)
    assert float(err.max()) < 0.01, (name, err.max(axis=(1, 2)))
    assert c["response"]["gamma"]["G"] == pytest.approx(1.0, abs=0.005)
    s = c["spectral_sensitivity"]
    wl = np.asarray(truth["spectral_sensitivity"]["wavelength_nm"])
    for ch in ("R", "G", "B"):
        true = np.interp(s["wavelength_nm"], wl, truth["spectral_sensitivity"][ch])
        rms = float(np.sqrt(np.mean((np.asarray(s[ch]) - true) ** 2)) / true.max())
        assert rms < 0.01, (name, ch, rms)  # the clean session's target: 1 % RMS of the peak


def test_hot_pixels_that_saturate_are_masked_not_refused(preset_session):
    """The sweep's 30 s blue frames: 0.3 % hot pixels saturate there; every frame is kept, the pixels masked."""
    name, cam, truth, profile, notes = preset_session("hot")
    sweep = truth["sweep"]
    assert max(sweep["exposure_s"]) == pytest.approx(30.0)
    assert set(profile.spectral.n_frames.values()) == {PLAN.n_sweep}  # no frame skipped
    assert any("hot pixels saturate" in n for n in profile.spectral.notes)
    assert truth["hot_pixel_count"] > 0.002 * 4 * (cam.params.width // 2) * (cam.params.height // 2)


def test_imx296_preset_is_in_the_sub_dn_regime(preset_session):
    name, cam, truth, profile, notes = preset_session("imx296")
    c = contract(profile)
    # recorded temporal noise (quantisation and jitter included) above the read noise, as on the real camera
    assert all(c["dark"]["temporal_noise_dn"][ch] > 1.1 * c["dark"]["read_noise_dn"][ch] for ch in "RGB")
    assert "quantised-normal" in profile.dark.provenance["read_noise_method"]
    assert c["dark"]["noisy_pixel_count"] < 1e-3 * profile.dark.defects.size


def test_dead_pixels_found_by_response_not_by_dark_variance(tmp_path):
    cam = SyntheticCamera(preset("default", width=256, height=192, dead_pixel_fraction=2e-3))
    out = write_session(tmp_path / "S", cam, SessionPlan(stages=("bias", "dark", "flat"), n_bias=8, n_dark=3,
                                                         n_flat=5))
    dark_only = fit_dark(measure_dark(out / "dark", out / "bias"))
    assert np.count_nonzero(dark_only.defects & DEAD) == 0
    profile, _ = calibrate_session(out)
    found = (profile.dark.defects & DEAD) != 0
    truth = cam.dead_pixel_mask
    assert np.count_nonzero(found & truth) >= 0.95 * truth.sum()
    assert np.count_nonzero(found & ~truth) <= 2
    assert contract(profile)["dark"]["dead_pixel_count"] == int(found.sum())


def test_bias_only_session_then_apply_says_what_it_cannot_correct(tmp_path):
    cam = SyntheticCamera(preset("default", width=192, height=128))
    out = write_session(tmp_path / "S", cam, SessionPlan(stages=("bias", "flat", "sweep"), n_bias=4, n_flat=4,
                                                         sweep_step_nm=20.0, n_sweep=1, sweep_jpeg=False))
    prof = tmp_path / "cam.camcal"
    proc = run_cli("calibrate", out, "-o", prof)
    assert proc.returncode == 0, proc.stderr
    assert "dark current unknown" in proc.stderr
    shown = json.loads(run_cli("profile", "show", "--json", prof).stdout)
    assert shown["dark"]["dark_current_dn_per_s"]["G"] is None and shown["dark"]["dark_current_known"] is False
    assert shown["dark"]["read_noise_dn"]["G"] == pytest.approx(1.875, rel=0.05)
    photo = tmp_path / "p.dng"
    assert run_cli("synth", "photo", photo, "--width", 192, "--height", 128, "--exposure", 0.002).returncode == 0
    proc = run_cli("apply", prof, photo, "-o", tmp_path / "exr")
    assert proc.returncode == 0, proc.stderr
    from camcal.io.exr import read_exr

    (exr,) = (tmp_path / "exr").glob("*.exr")
    _, meta = read_exr(exr)
    assert any("dark current is unknown" in n for n in meta["notes"])


# ---- the real IMX296 dark frames -------------------------------------------------------------------------------


@pytest.mark.skipif(len(PI_DARKS) < 2, reason="../shared/realdata/pi is absent")
def test_real_pi_dark_frames_as_a_bias_only_session(tmp_path):
    """Two real 10-bit dark frames (σ ≈ 0.4 DN): enough to run; bias, noise and defects right."""
    d = tmp_path / "S" / "bias"
    d.mkdir(parents=True)
    for p in PI_DARKS:
        (d / p.name).symlink_to(p)
    # a fixed-aperture lens: no f-number in the files, the user states it once (docs/session-layout.md)
    (tmp_path / "S" / "session.toml").write_text("f_number = 1.2\n")
    profile, notes = calibrate_session(tmp_path / "S")
    c = contract(profile)
    frames = []
    for p in PI_DARKS:
        with rawpy.imread(str(p)) as r:
            frames.append(r.raw_image_visible.astype(np.int64).copy())
    stack = np.stack(frames)
    # numpy: per-pixel temporal standard deviation, and the frames' mean, per plane (BGGR: B at (0, 0))
    offsets = {"B": (0, 0), "G1": (0, 1), "G2": (1, 0), "R": (1, 1)}
    for plane, (r, col) in offsets.items():
        s = stack[:, r::2, col::2]
        temporal = float(np.sqrt(np.mean(np.var(s, axis=0, ddof=1))))
        assert c["dark"]["temporal_noise_dn"][plane] == pytest.approx(temporal, rel=0.10), plane
        assert c["dark"]["bias_dn"][plane] == pytest.approx(float(s.mean()), abs=0.1), plane
        # the read noise (quantisation removed) reproduces the recorded frame differences through the
        # quantised-normal model it was fitted with
        rn, sd = c["dark"]["read_noise_dn"][plane], c["dark"]["dsnu_bias_dn"][plane]
        rng = np.random.default_rng(0)
        a, b = _quantised_pairs(rng, s[0].size, rn, sd, float(s[0].mean()), float(s[1].mean() - s[0].mean()))
        sim = np.var((a - b).astype(float))
        real = np.var((s[0] - s[1]).astype(float))
        assert sim == pytest.approx(real, rel=0.05), plane
        assert 0.3 < rn < temporal
    assert c["dark"]["dead_pixel_count"] < 1e-3 * profile.dark.defects.size
    assert c["dark"]["hot_pixel_count"] == 0
    assert c["dark"]["noisy_pixel_count"] < 1e-3 * profile.dark.defects.size
    assert c["dark"]["dark_current_known"] is False
    assert np.count_nonzero(profile.dark.defects & NOISY) == c["dark"]["noisy_pixel_count"]


@pytest.mark.skipif(len(PI_DARKS) < 2, reason="../shared/realdata/pi is absent")
def test_real_pi_same_dark_frame_twice_is_named(tmp_path):
    d = tmp_path / "S" / "bias"
    d.mkdir(parents=True)
    (d / "a.dng").symlink_to(PI_DARKS[0])
    (d / "b.dng").symlink_to(PI_DARKS[0])
    (tmp_path / "S" / "session.toml").write_text("f_number = 1.2\n")
    proc = run_cli("calibrate", tmp_path / "S", "-o", tmp_path / "x.camcal")
    assert_one_line_error(proc, "b.dng", "same pixels as a.dng")


def test_remembered_dark_frame_gives_the_same_correction(rng):
    """A calibration that keeps its dark frames (the master flat's frames share one exposure) corrects exactly as
    one that computes the dark frame for every frame; it computes it once per exposure and ISO, and never for a
    window (a window is cut from the dark model itself)."""
    shape = (4, 6, 8)
    dark = _dark(shape, rng)
    plain = Calibration.of(dark)
    kept = plain.remembering_dark_frames()
    kw = {"iso": 100.0, "white_level_dn": 4095, "black_level_dn": np.full(4, 512.0)}
    for t in (2.0, 2.0, 4.0):
        raw = rng.integers(520, 4000, shape).astype(np.float32)
        a = correct_planes(raw.copy(), plain, exposure_s=t, **kw)
        b = correct_planes(raw.copy(), kept, exposure_s=t, **kw)
        assert np.array_equal(a.signal_dn, b.signal_dn) and np.array_equal(a.invalid, b.invalid)
    assert len(kept.dark_frames) == 2 and plain.dark_frames is None
    window = (slice(1, 4), slice(2, 6))
    raw = rng.integers(520, 4000, (4, 3, 4)).astype(np.float32)
    a = correct_planes(raw.copy(), plain, exposure_s=2.0, full_shape=shape, window=window, **kw)
    b = correct_planes(raw.copy(), kept, exposure_s=2.0, full_shape=shape, window=window, **kw)
    assert np.array_equal(a.signal_dn, b.signal_dn) and len(kept.dark_frames) == 2


def test_calibration_of_a_dark_and_a_flat_model_holds_each_part(rng):
    """Calibration.of keeps the flat model's gain without PRNU unless asked (given in float64, held in float32)
    and its reciprocal in float32; the defect map is every nonzero defect bit (hot 1, dead 2, noisy 4); the
    noise model's system gain is the dark model's photon-transfer gain per plane, replaced by the EMVA sheet's K
    scaled by ISO_dark/ISO_sheet where the sheet has a positive finite K. A gain of 0, below 0 or NaN anywhere is
    refused."""
    shape = (4, 3, 5)
    dark = _dark(shape, rng)
    defects = np.zeros(shape, np.uint8)
    defects[0, 1, 2], defects[2, 0, 0], defects[3, 2, 4] = HOT, DEAD, NOISY | HOT
    dark = replace(dark, defects=defects, channels={
        p: {"hot_pixel_count": 0, "dead_pixel_count": 0, "noisy_pixel_count": 0, "gain_dn_per_e_from_dark": g}
        for p, g in zip(PLANES, (0.5, 0.6, 0.7, 0.8), strict=True)})
    plain = rng.uniform(0.6, 1.0, shape)  # float64, as a model may hold it
    prnu = plain * (1.0 + 0.01 * rng.standard_normal(shape))

    class Flat:
        def gain(self, with_prnu: bool = False):
            return prnu if with_prnu else plain

    class Sheet:  # the profile's EMVA 1288 sheet at ISO 200: K known for R only (G1 none, G2 NaN, B 0)
        iso = 200.0

        def gain_dn_per_e(self, plane):
            return {"R": 2.0, "G1": None, "G2": float("nan"), "B": 0.0}[plane]

    cal = Calibration.of(dark, Flat())
    assert cal.flat_gain.dtype == np.float32 and cal.inv_flat_gain.dtype == np.float32
    np.testing.assert_array_equal(cal.flat_gain, plain.astype(np.float32))
    np.testing.assert_array_equal(cal.inv_flat_gain, (1.0 / plain.astype(np.float32)).astype(np.float32))
    np.testing.assert_array_equal(cal.defects, defects > 0)
    assert cal.defects.dtype == bool and cal.dark is dark
    np.testing.assert_array_equal(cal.noise_gain_dn_per_e.ravel(), np.float32([0.5, 0.6, 0.7, 0.8]))
    np.testing.assert_array_equal(Calibration.of(dark, Flat(), with_prnu=True).flat_gain, prnu.astype(np.float32))
    k = Calibration.of(dark, Flat(), emva=Sheet()).noise_gain_dn_per_e
    np.testing.assert_array_equal(k.ravel(), np.float32([2.0 * 100.0 / 200.0, 0.6, 0.7, 0.8]))
    empty = Calibration.of()
    assert empty.flat_gain is None and empty.inv_flat_gain is None and empty.defects is None
    assert empty.noise_gain_dn_per_e is None
    for bad in (0.0, -0.5, np.nan):
        wrong = plain.copy()
        wrong[1, 2, 3] = bad

        class Bad:
            def gain(self, with_prnu: bool = False, g=wrong):
                return g

        with pytest.raises(CamcalError, match="gain is not positive and finite everywhere"):
            Calibration.of(dark, Bad())


def test_remembered_dark_frames_are_kept_per_iso_read_only_and_in_the_frames_plane_order():
    """A remembered dark frame is keyed by the ISO too (the dark current scales with ISO/ISO_dark: the frame at
    ISO 400 is bias + 4·β·t, written out here), is kept read-only and reused as the same array. A third-party
    model's dark frame given per plane name is stacked in the frame's own plane order, and a mosaic is split by
    the frame's CFA pattern, both when remembered; its failure names the file."""
    shape = (4, 6, 8)
    dark = _dark(shape, np.random.default_rng(11))
    kept = Calibration.of(dark).remembering_dark_frames()
    kw = {"white_level_dn": 1e9, "black_level_dn": np.full(4, 512.0)}
    raw = np.full(shape, 3000.0, np.float32)
    for iso in (100.0, 400.0, 100.0):
        out = correct_planes(raw.copy(), kept, exposure_s=2.0, iso=iso, **kw)
        want = 3000.0 - (dark.bias_dn.astype(np.float64) + dark.dark_current_dn_per_s * 2.0 * iso / 100.0)
        np.testing.assert_allclose(out.signal_dn, want, rtol=0, atol=5e-4)  # float32 of ~2 500 DN: 2.4e-4 DN
    assert sorted(k[1] for k in kept.dark_frames) == [100.0, 400.0]
    first = dict(kept.dark_frames)
    correct_planes(raw.copy(), kept, exposure_s=2.0, iso=400.0, **kw)
    assert all(kept.dark_frames[k] is first[k] for k in first)  # reused, not computed again
    assert not any(f.flags.writeable for f in kept.dark_frames.values())
    assert all(isinstance(f, np.ndarray) and f.shape == shape for f in kept.dark_frames.values())

    class ByName:  # plane p's dark level is 10 × its index in PLANES (R 0, G1 10, G2 20, B 30) + t
        def dark_frame_dn(self, exposure_s, iso):
            return {p: np.full(shape[1:], 10.0 * i + exposure_s) for i, p in enumerate(PLANES)}

    order = ("B", "G2", "G1", "R")
    out = correct_planes(raw.copy(), Calibration(dark=ByName()).remembering_dark_frames(), exposure_s=1.0,
                         iso=None, channels=order, **kw)
    np.testing.assert_array_equal(out.signal_dn[:, 0, 0], [3000.0 - 31.0, 3000.0 - 21.0, 3000.0 - 11.0, 2999.0])

    class Mosaic:  # a whole-sensor dark frame, 2h × 2w, whose value is 1000 × row parity + 100 × column parity
        def dark_frame_dn(self, exposure_s, iso):
            rows, cols = np.indices((2 * shape[1], 2 * shape[2]))
            return 1000.0 * (rows % 2) + 100.0 * (cols % 2)

    out = correct_planes(raw.copy(), Calibration(dark=Mosaic()).remembering_dark_frames(), exposure_s=1.0,
                         iso=None, cfa_pattern="BGGR", **kw)
    # BGGR: R at (1, 1), G1 at (0, 1), G2 at (1, 0), B at (0, 0) of each 2 × 2 cell
    np.testing.assert_array_equal(out.signal_dn[:, 0, 0], [3000.0 - 1100.0, 2900.0, 2000.0, 3000.0])

    class Failing:
        def dark_frame_dn(self, exposure_s, iso):
            raise ValueError("no such exposure")

    for cal in (Calibration(dark=Failing()), Calibration(dark=Failing()).remembering_dark_frames()):
        with pytest.raises(CamcalError) as err:
            correct_planes(raw.copy(), cal, exposure_s=1.0, iso=None, path=Path("frame.dng"), **kw)
        assert str(err.value).startswith("frame.dng: the dark model failed for t = 1.0 s")


class _WholeFrameDark:
    """A dark model that evaluates whole frames only: a dict per named plane, or a CFA mosaic (DN)."""

    def __init__(self, kind):
        self.kind = kind

    def dark_frame_dn(self, exposure_s, iso):
        level = 60.0 + 0.5 * exposure_s * iso / 100.0  # 70 DN at 10 s, ISO 200
        if self.kind == "dict":
            return {p: np.full((3, 4), level + 2.0 * i) for i, p in enumerate(("R", "G", "B"))}
        return np.arange(48, dtype=float).reshape(6, 8) + level


def test_correction_with_a_whole_frame_dark_model_uses_the_frames_planes_and_pattern():
    """Linear RAW planes named R, G, B with a dark model giving a dict per plane: each plane loses its own dark
    level (70, 72, 74 DN). A BGGR mosaic dark frame is split by the frame's pattern: the B plane is the mosaic's
    even rows and columns, R its odd ones."""
    raw = np.full((3, 3, 4), 500.0, np.float32)
    out = correct_planes(raw, Calibration(dark=_WholeFrameDark("dict")), exposure_s=10.0, iso=200.0,
                         white_level_dn=4095, black_level_dn=np.zeros(3), channels=("R", "G", "B"))
    np.testing.assert_allclose(out.signal_dn[:, 0, 0], [430.0, 428.0, 426.0])
    raw4 = np.full((4, 3, 4), 500.0, np.float32)
    out = correct_planes(raw4, Calibration(dark=_WholeFrameDark("mosaic")), exposure_s=10.0, iso=200.0,
                         white_level_dn=4095, black_level_dn=np.zeros(4), cfa_pattern="BGGR")
    mosaic = np.arange(48, dtype=float).reshape(6, 8) + 70.0
    np.testing.assert_allclose(out.signal_dn[3], 500.0 - mosaic[0::2, 0::2])  # B
    np.testing.assert_allclose(out.signal_dn[0], 500.0 - mosaic[1::2, 1::2])  # R


def test_a_dark_model_without_dark_current_needs_no_exposure_time():
    """A dark model that knows only the bias (no dark current, β = None) corrects a frame whose file gives no
    exposure time: the signal is raw − bias."""
    bias = np.full((4, 2, 3), 100.0, np.float32)
    bias[1, 0, 2] = 130.0
    z = np.zeros(bias.shape, np.float32)
    dark = DarkModel(bias_dn=bias, dark_current_dn_per_s=None, dark_current_unc_dn_per_s=None, read_noise_dn=z + 2,
                     defects=np.zeros(bias.shape, np.uint8), iso=100.0, cfa_pattern="RGGB", temperature_c=None)
    raw = np.full((4, 2, 3), 700.0, np.float32)
    out = correct_planes(raw, Calibration(dark=dark), exposure_s=None, iso=100.0, white_level_dn=4095,
                         black_level_dn=np.full(4, 100.0))
    np.testing.assert_array_equal(out.signal_dn, 700.0 - bias)


def test_system_gain_of_third_party_dark_models():
    """K per plane from a dark model's summary ('gain_dn_per_e_from_dark'), in the model's own plane
    order (R, G, B here; R, G1, G2, B for a model that does not say); a plane whose gain is unknown (None, or
    missing) gets 0 (no shot-noise term); a model without read noise, or without a summary, gives None."""
    class Linear:
        read_noise_dn = 2.0
        plane_names = ("R", "G", "B")

        def summary(self):
            return {"gain_dn_per_e_from_dark": {"R": 0.5, "G": None}}

    k = system_gain_dn_per_e(Linear())
    assert k.dtype == np.float32 and k.shape == (3, 1, 1)
    np.testing.assert_array_equal(k[:, 0, 0], [0.5, 0.0, 0.0])

    class NoSummary:
        read_noise_dn = 2.0

    class NoReadNoise(Linear):
        read_noise_dn = None

    assert system_gain_dn_per_e(NoSummary()) is None and system_gain_dn_per_e(NoReadNoise()) is None

    class NoPlaneNames:  # a Bayer model that does not name its planes: R, G1, G2, B
        read_noise_dn = 2.0

        def summary(self):
            return {"gain_dn_per_e_from_dark": {"G2": 0.3}}

    np.testing.assert_array_equal(system_gain_dn_per_e(NoPlaneNames())[:, 0, 0], np.float32([0.0, 0.0, 0.3, 0.0]))


def test_third_party_dark_frame_is_split_only_when_a_mosaic_of_the_frame():
    """A third-party dark model's 2-D frame is split into planes only when the frame has a CFA pattern and the
    2-D frame is exactly the mosaic (2h × 2w); a mosaic-sized frame without a pattern, or a 2-D frame of another
    size with one, is refused with its shape named. The split planes are the mosaic's samples (RGGB: R at
    (0, 0), G at (0, 1) and (1, 0), B at (1, 1))."""
    from camcal.models.correct import dark_frame

    class Mosaic:
        def __init__(self, frame):
            self.frame = frame

        def dark_frame_dn(self, exposure_s, iso):
            return self.frame

    mosaic = np.arange(4 * 6, dtype=float).reshape(4, 6)
    got = dark_frame(Mosaic(mosaic), 1.0, 100.0, (4, 2, 3), cfa_pattern="RGGB")
    np.testing.assert_array_equal(got, np.stack([mosaic[0::2, 0::2], mosaic[0::2, 1::2], mosaic[1::2, 0::2],
                                                 mosaic[1::2, 1::2]]))
    with pytest.raises(CamcalError, match=r"has shape \(4, 6\)"):
        dark_frame(Mosaic(mosaic), 1.0, 100.0, (4, 2, 3), cfa_pattern=None)
    with pytest.raises(CamcalError, match=r"has shape \(2, 3\)"):
        dark_frame(Mosaic(mosaic[:2, :3]), 1.0, 100.0, (4, 2, 3), cfa_pattern="RGGB")


class _FrameDark:
    """A third-party model that only evaluates whole frames: a dict per plane, a mosaic, or a scalar."""

    def __init__(self, kind):
        self.kind = kind

    def dark_frame_dn(self, exposure_s, iso):
        level = 64.0 + 0.5 * exposure_s * iso / 100.0
        if self.kind == "dict":
            return {p: np.full((3, 4), level + i) for i, p in enumerate(PLANES)}
        if self.kind == "mosaic":
            return np.arange(48, dtype=float).reshape(6, 8) + level
        return level


def test_dark_frame_of_maps_off_the_reference_iso_on_a_window():
    """bias + β·t·ISO/ISO_dark on a window, for a model offering the maps: ISO 800 against a dark model at ISO
    200, 5 s, β = 1.5 DN/s → bias + 30 DN."""
    rng = np.random.default_rng(3)
    bias = (1000 + rng.integers(0, 20, (4, 3, 4))).astype(np.float32)
    beta = np.full((4, 3, 4), 1.5, np.float32)
    win = (slice(1, 3), slice(0, 2))
    got = dark_frame(_dark_model(bias, beta, 200.0), 5.0, 800.0, (4, 3, 4), win)
    np.testing.assert_allclose(got, bias[:, 1:3, 0:2] + 30.0, rtol=1e-7)
    with pytest.raises(CamcalError, match="non-negative"):
        dark_frame(_dark_model(bias, beta, 200.0), float("nan"), 800.0, (4, 3, 4))
    with pytest.raises(CamcalError, match="do not match"):
        dark_frame(_dark_model(bias, beta, 200.0), 5.0, 800.0, (4, 3, 5))


def test_dark_frame_of_a_whole_frame_model_per_plane_mosaic_or_scalar():
    """A dict per plane is stacked in plane order, a mosaic split by its CFA pattern (RGGB: R at even rows
    and columns), a scalar filled; level 64 + 0.5·t·ISO/100 = 74 DN at 10 s, ISO 200."""
    got = dark_frame(_FrameDark("dict"), 10.0, 200.0, (4, 3, 4))
    np.testing.assert_allclose(got[:, 0, 0], [74.0, 75.0, 76.0, 77.0])
    mosaic = np.arange(48, dtype=float).reshape(6, 8) + 74.0
    got = dark_frame(_FrameDark("mosaic"), 10.0, 200.0, (4, 3, 4), cfa_pattern="RGGB")
    np.testing.assert_allclose(got[0], mosaic[0::2, 0::2])
    np.testing.assert_allclose(got[3], mosaic[1::2, 1::2])
    np.testing.assert_allclose(got[1], mosaic[0::2, 1::2])
    got = dark_frame(_FrameDark("scalar"), 10.0, 200.0, (4, 3, 4), (slice(0, 2), slice(1, 3)))
    assert got.shape == (4, 2, 2) and np.all(got == 74.0)


class _Emva:
    iso = 400.0

    def gain_dn_per_e(self, plane):
        return {"R": 0.8, "G1": None, "G2": float("nan"), "B": 1.2}[plane]


def test_system_gain_from_photon_transfer_scaled_to_the_dark_models_iso():
    """K at the dark model's ISO 100 from an EMVA sheet at ISO 400: K·100/400 (0.8 → 0.2, 1.2 → 0.3 DN/e⁻);
    planes the sheet does not know keep the dark model's own photon-transfer gain."""
    shape = (4, 2, 2)
    dark = _dark_model(np.full(shape, 1000.0, np.float32), np.full(shape, 1.0, np.float32), iso=100.0)
    own = {"R": 0.05, "G1": 0.06, "G2": 0.07, "B": 0.08}
    channels = {p: {"gain_dn_per_e_from_dark": g, "hot_pixel_count": 0, "dead_pixel_count": 0,
                    "noisy_pixel_count": 0} for p, g in own.items()}
    dark = replace(dark, channels=channels)
    np.testing.assert_allclose(system_gain_dn_per_e(dark).ravel(), [0.05, 0.06, 0.07, 0.08], rtol=1e-6)
    k = system_gain_dn_per_e(dark, _Emva())
    assert k.shape == (4, 1, 1)
    np.testing.assert_allclose(k.ravel(), [0.2, 0.06, 0.07, 0.3], rtol=1e-6)
    assert system_gain_dn_per_e(None) is None


def test_corrected_frame_summaries():
    """Valid and saturated fractions per plane and the mean over valid pixels only, written out."""
    sig = np.arange(2 * 3 * 2, dtype=np.float32).reshape(2, 3, 2)
    invalid = np.zeros(sig.shape, bool)
    invalid[0, 0, :] = True
    invalid[1, 2, 1] = True
    saturated = np.zeros(sig.shape, bool)
    saturated[0, 0, 1] = True
    c = Corrected(sig, None, invalid, saturated, np.zeros(sig.shape, bool), saturated, ("R", "G"))
    np.testing.assert_allclose(c.valid_fraction(), [4 / 6, 5 / 6])
    np.testing.assert_allclose(c.saturated_fraction(), [1 / 6, 0.0])
    np.testing.assert_allclose(c.mean_dn(), [np.mean([2, 3, 4, 5]), np.mean([6, 7, 8, 9, 10])])
    m = c.masked(-1.0)
    assert m[0, 0, 0] == -1.0 and m[1, 2, 1] == -1.0 and m[1, 0, 0] == 6.0 and sig[0, 0, 0] == 0.0
    all_bad = Corrected(sig, None, np.ones(sig.shape, bool), saturated, saturated, saturated, ("R", "G"))
    assert np.all(np.isnan(all_bad.mean_dn()))

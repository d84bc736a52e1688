"""EMVA 1288 figures as the standard defines them (camcal.calibrate.emva_standard) against the synthetic camera's
truth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from camcal.calibrate.emva_standard import (
    StackAccumulator,
    TemporalSeries,
    evaluate,
    pair_moments,
    spatial_parts,
    spectrogram,
)
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.session import _white_spectrum, exposure_for_level

SPEC = _white_spectrum(5000.0)


def _series(cam: SyntheticCamera, rng: np.random.Generator, steps: int = 17, factor: float = 2**0.5,
            plane: int = 1) -> TemporalSeries:
    """A photon-transfer series of one plane as a camcal session shoots it: exposures from ~1 % of full scale up
    by √2, a bright and a dark pair at each (no photon counts: the axis is exposure time)."""
    ts = exposure_for_level(cam, SPEC, 0.01, 100.0, 4.0) * factor ** np.arange(steps)
    rows = []
    for t in ts:
        bright = [cam.expose_planes(Scene.uniform(SPEC), exposure_s=t, rng=rng)[plane] for _ in range(2)]
        dark = [cam.expose_planes(Scene.dark(), exposure_s=t, rng=rng)[plane] for _ in range(2)]
        rows.append((t, *pair_moments(*bright), *pair_moments(*dark)))
    r = np.array(rows)
    return TemporalSeries(r[:, 0], np.full(len(r), np.nan), r[:, 1], r[:, 2], r[:, 4], r[:, 5], r[:, 0], r[:, 4],
                          r[:, 5], variance_unc_dn2=r[:, 3], dark_variance_unc_dn2=r[:, 6])


def test_pair_moments_and_its_uncertainty():
    rng = np.random.default_rng(3)
    a, b = rng.normal(100, 4, 40_000), rng.normal(101, 4, 40_000)
    m, v, u = pair_moments(a, b)
    assert m == pytest.approx(100.5, abs=0.05)
    assert v == pytest.approx(16.0, abs=4 * u)  # ½ var(a − b) = σ²
    assert u == pytest.approx(16.0 * math.sqrt(2 / 40_000), rel=0.05)  # normal theory 2σ⁴/N


def test_stated_u_k_covers_the_error_in_20_synthetic_sessions():
    """u(K) covers K's error within 2σ in at least 18 of 20 sessions of 64×64-pixel planes, and is not inflated
    (its mean within a factor 1.6 of the observed scatter); the residual-scatter standard error alone would cover
    far fewer (it is what u(K) was before)."""
    truth = 1 / 1.6  # K at ISO 100 of SensorParams(gain_e_per_dn=1.6)
    k, u, ls = [], [], []
    for seed in range(20):
        cam = SyntheticCamera(SensorParams(width=128, height=128, seed=seed))
        f = evaluate(_series(cam, np.random.default_rng(1000 + seed))).figures
        k.append(f["K_dn_per_e"])
        u.append(f["K_unc_dn_per_e"])
        ls.append(f["K_unc_ls_dn_per_e"])
    k, u, ls = map(np.array, (k, u, ls))
    z = (k - truth) / u
    assert np.sum(np.abs(z) < 2) >= 18, np.round(z, 2)
    scatter = float(np.std(k - truth, ddof=1))
    assert scatter / 1.6 < u.mean() < 1.6 * scatter, (u.mean(), scatter)
    assert np.sum(np.abs((k - truth) / ls) < 2) < 18  # the optimism the propagated and bootstrap terms remove


def test_prnu_1288_is_the_total_and_its_parts():
    """On a synthetic average with a known column pattern, row pattern and pixel pattern, the release 4.0 split
    recovers each part and PRNU₁₂₈₈ their quadrature sum."""
    rng = np.random.default_rng(5)
    m, n, big_l, mean, temporal = 120, 160, 16, 1000.0, 20.0
    rows, cols, pix = 0.003, 0.002, 0.004
    r_pat, c_pat, p_pat = (rows * rng.standard_normal((m, 1)), cols * rng.standard_normal((1, n)),
                           pix * rng.standard_normal((m, n)))
    gain = 1 + r_pat + c_pat + p_pat
    bright, dark = StackAccumulator(), StackAccumulator()
    for _ in range(big_l):
        bright.add(mean * gain + temporal * rng.standard_normal((m, n)))
        dark.add(10 + 2 * rng.standard_normal((m, n)))
    b, d = bright.result(), dark.result()
    bp = spatial_parts(b)
    assert bp.stack_dn2 == pytest.approx(temporal**2, rel=0.02)
    assert math.sqrt(bp.row_dn2) / mean == pytest.approx(np.std(r_pat), rel=0.1)
    assert math.sqrt(bp.column_dn2) / mean == pytest.approx(np.std(c_pat), rel=0.1)
    # the pixel part within 4 standard uncertainties of s² (normal theory, temporal floor included)
    assert bp.pixel_dn2 == pytest.approx((mean * np.std(p_pat)) ** 2, abs=4 * bp.total_unc_dn2)
    cam = SyntheticCamera(SensorParams(width=128, height=128, seed=0))
    f = evaluate(_series(cam, np.random.default_rng(0), steps=12), b, d).figures
    total = float(np.std(mean * gain, ddof=1)) / f["prnu_mean_dn"] * 100  # relative to the signal above dark
    assert f["prnu_pct"] == pytest.approx(total, abs=3 * f["prnu_unc_pct"])
    assert f["prnu_unc_pct"] < 0.03 * total
    assert f["prnu_row_pct"] ** 2 + f["prnu_col_pct"] ** 2 + f["prnu_pixel_pct"] ** 2 == pytest.approx(
        f["prnu_pct"] ** 2, rel=0.02)
    assert f["dsnu_dn"] is None or f["dsnu_dn"] < 0.2  # a dark stack of temporal noise only


def test_sigma_d_uses_the_standards_quantisation_term():
    cam = SyntheticCamera(SensorParams(width=128, height=128, seed=2, read_noise_e=3.0, bias_pattern_dn=0.0))
    f = evaluate(_series(cam, np.random.default_rng(2), steps=12)).figures
    assert f["read_noise_dn"] == pytest.approx(math.sqrt(f["dark_noise_dn"] ** 2 - 1 / 12))
    assert f["read_noise_e"] == pytest.approx(3.0, rel=0.05)  # the synthetic read noise, e⁻


def test_spectrogram_of_white_noise_is_its_standard_deviation():
    rng = np.random.default_rng(1)
    freq, amp = spectrogram(rng.normal(0, 3.0, (200, 256)))
    assert freq[0] == 0 and freq[-1] == pytest.approx(0.5)
    assert np.median(amp[1:]) == pytest.approx(3.0, rel=0.05)

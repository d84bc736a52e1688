"""σ_C: every stated input carried to C, checked against a Monte Carlo over the same input uncertainties."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from camcal.io.exr import read_exr, write_exr
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import SensorParams, SyntheticCamera
from camcal.water.band import BandModel, illuminant_spectrum
from camcal.water.models import LampModel, RefinedModel
from camcal.water.uncertainty import Uncertain, combine, dominant, forward_for, model_ratio, solve_c, uncertainty_terms
from tests.conftest import run_cli
from tests.oracles import monte_carlo_sigma

DEPTH_M = 0.3
C_UG = 200.0
INPUTS = [Uncertain("depth", DEPTH_M, 0.005, "m"), Uncertain("lamp_height", 1.0, 0.01, "m"),
          Uncertain("lamp_angle", 20.0, 1.0, "deg"), Uncertain("epsilon", 1.0, 0.03, "relative")]
SAMPLES = 300  # the sample standard deviation is good to 1/sqrt(2·300) = 4 % (1 σ)


@pytest.fixture(scope="module")
def band():
    cam = SyntheticCamera(SensorParams(width=64, height=64))
    sens = cam.spectral_sensitivity()[0]
    # a c_R uncertainty of 3 % per wavelength (no floor: where c + noise < 0 the band model clips c to 0, a
    # non-linearity that first-order propagation does not follow; the linear term sets ∂B/∂c = 0 where c ≤ 0)
    u = 0.03 * sens
    return BandModel(WAVELENGTHS_NM, sens, geometry=LampModel(1.0, np.radians(20)),
                     illuminant=illuminant_spectrum("lamp", WAVELENGTHS_NM), sensitivity_sigma=u)


@pytest.mark.parametrize("kind", ["narrowband", "band"])
def test_terms_match_monte_carlo(kind, band):
    model = LampModel(1.0, np.radians(20)) if kind == "narrowband" else band
    c = np.array([C_UG])
    r = float(model_ratio(model, c, DEPTH_M)[0])
    assert solve_c(lambda cc: model_ratio(model, cc, DEPTH_M), r) == pytest.approx(C_UG, rel=1e-9)
    terms = uncertainty_terms(model, DEPTH_M, c, INPUTS)
    for i, q in enumerate(INPUTS):
        mc = monte_carlo_sigma(forward_for(model, DEPTH_M, q.name), q, r, samples=SAMPLES, seed=10 + i)
        assert float(terms[q.name][0]) == pytest.approx(mc, rel=0.10), q.name
    if kind == "band":
        rng = np.random.default_rng(7)
        draws = [solve_c(lambda cc, m=replace(model, sensitivity=model.sensitivity + model.sensitivity_sigma
                                              * rng.standard_normal(model.sensitivity.size)):
                         m.ratio(cc, DEPTH_M), r) for _ in range(SAMPLES)]
        assert float(terms["sensitivity"][0]) == pytest.approx(np.std(draws, ddof=1), rel=0.10)
    # all inputs at once: the root sum of squares against one joint Monte Carlo
    rng = np.random.default_rng(3)
    joint = []
    for _ in range(SAMPLES):
        p = {q.name: q.value + q.sigma * rng.standard_normal() for q in INPUTS}
        geom = LampModel(p["lamp_height"], np.radians(p["lamp_angle"]))
        if kind == "band":
            m = replace(model, geometry=geom, sensitivity=model.sensitivity + model.sensitivity_sigma
                        * rng.standard_normal(model.sensitivity.size))
            m = replace(m, chlorophyll=None)
            f = forward_for(m, p["depth"], "epsilon")
        else:
            f = forward_for(replace(geom), p["depth"], "epsilon")
        joint.append(solve_c(lambda cc, f=f, p=p: f(p["epsilon"], cc), r))
    assert float(combine(terms)[0]) == pytest.approx(np.std(joint, ddof=1), rel=0.10)


def test_dominant_term_and_grid_interpolation(band):
    c = np.array([[20.0, 200.0], [np.nan, 1000.0]])
    terms = uncertainty_terms(band, DEPTH_M, c, INPUTS)
    assert set(terms) == {"depth", "lamp_height", "lamp_angle", "epsilon", "sensitivity"}
    assert np.isnan(terms["depth"][1, 0]) and np.all(terms["depth"][np.isfinite(c)] > 0)
    direct = uncertainty_terms(band, DEPTH_M, np.array([200.0]), INPUTS, grid=np.array([150.0, 200.0, 250.0]))
    for k in terms:  # log-log interpolation on the 161-node grid against direct evaluation
        assert terms[k][0, 1] == pytest.approx(direct[k][0], rel=0.01), k
    dom = dominant(terms)
    assert dom["dominant"] == max(dom["median_terms_ug_per_L"], key=dom["median_terms_ug_per_L"].get)


def test_cli_writes_total_and_terms(tmp_path):
    m = LampModel(1.0, np.radians(20))
    truth_ug = np.linspace(50, 300, 12 * 16).reshape(12, 16)
    ref = np.full(truth_ug.shape, 2.0, np.float32)
    sub = (m.ratio(truth_ug / 893.5e6, DEPTH_M) * ref).astype(np.float32)
    write_exr(tmp_path / "s.exr", {"L663": sub})
    write_exr(tmp_path / "r.exr", {"L663": ref})
    proc = run_cli("water", "invert", "--submerged", tmp_path / "s.exr", "--reference", tmp_path / "r.exr",
                   "--depth", "0.30m±0.005m", "--water-model", "lamp", "--lamp-height", "1m±1cm",
                   "--lamp-angle", "20±1", "--epsilon-unc", "3%", "--relative-sigma", "0.01", "-o", tmp_path / "c.exr")
    assert proc.returncode == 0, proc.stderr
    names = ["chl_ug_per_L", "chl_unc_ug_per_L", "chl_unc_ratio_ug_per_L", "chl_unc_depth_ug_per_L",
             "chl_unc_lamp_height_ug_per_L", "chl_unc_lamp_angle_ug_per_L", "chl_unc_epsilon_ug_per_L"]
    ch, meta = read_exr(tmp_path / "c.exr", names)
    np.testing.assert_allclose(ch["chl_ug_per_L"], truth_ug, rtol=1e-5)
    rss = np.sqrt(sum(ch[n].astype(float) ** 2 for n in names[2:]))
    np.testing.assert_allclose(ch["chl_unc_ug_per_L"], rss, rtol=1e-5)
    unc = meta["summary"]["uncertainty"]
    assert unc["dominant"] == max(unc["median_terms_ug_per_L"], key=unc["median_terms_ug_per_L"].get)
    assert meta["stated_uncertainties"]["depth"]["sigma"] == pytest.approx(0.005)
    # numbers: the same terms in JSON
    proc = run_cli("water", "invert", "--json", "--ratio", repr(float(m.ratio(1e-7, 0.3))), "--depth", "30cm±5mm",
                   "--water-model", "lamp", "--lamp-height", "1m", "--lamp-angle", "20", "--epsilon-unc", "3%")
    out = json.loads(proc.stdout)
    assert set(out["sigma_terms_ug_per_L"]) == {"depth", "epsilon"}
    assert set(out["uncertainty"]["not_stated"]) == {"lamp_height", "lamp_angle", "ratio"}
    assert "not_stated" not in unc  # the EXR run stated every input
    # ε ± 3 % is ± 3 % in C (C ∝ 1/ε); the depth term is ≈ C σ_d/d (plus water and geometry)
    assert out["sigma_terms_ug_per_L"]["epsilon"][0] == pytest.approx(0.03 * 89.35, rel=0.01)
    # no ratio noise stated: no total (the stated terms alone would read like a measured σ_C)
    assert out["sigma_ug_per_L"] == [None] and out["uncertainty"]["total"] is None
    assert out["uncertainty"]["dominant"] is None


def test_refined_narrowband_depth_term_is_c_sigma_over_d():
    """Sanity: seed-like geometry, no water: at fixed r, τ ∝ C d, so σ_C/C = σ_d/d exactly (first order)."""
    m = RefinedModel(water_absorption_per_m=0.0)
    c = np.array([100.0])
    t = uncertainty_terms(m, 0.5, c, [Uncertain("depth", 0.5, 0.01, "m")])
    assert float(t["depth"][0]) == pytest.approx(100.0 * 0.01 / 0.5, rel=1e-3)

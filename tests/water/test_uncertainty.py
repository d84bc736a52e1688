"""σ_C: every stated input carried to C, checked against a Monte Carlo over the same input uncertainties."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from camcal.io.exr import read_exr, write_exr
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import SensorParams, SyntheticCamera
from camcal.water.band import BandModel, ChlorophyllAbsorption, illuminant_spectrum
from camcal.water.field import (
    FieldGeometry,
    MeasuredSky,
    field_band_model,
)
from camcal.water.invert import Inversion
from camcal.water.models import LampModel, RefinedModel
from camcal.water.uncertainty import (
    C_GRID_UG_PER_L,
    Uncertain,
    all_terms,
    combine,
    derivative_c,
    dominant,
    forward_for,
    interpolate_term,
    interpolate_terms,
    model_ratio,
    solve_c,
    term_sigma_c,
    uncertainty_terms,
)
from camcal.water.units import (
    CHLA_MOLAR_MASS_G_PER_MOL,
)
from tests.conftest import run_cli
from tests.helpers import FIELD_C, FIELD_WL, _field_truth
from tests.oracles import monte_carlo_sigma

#: Every test here is a fast formula test (the mutation-testing selection, docs/testing.md).
pytestmark = pytest.mark.formula

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


def test_interpolated_terms_are_log_log_linear_on_the_grid_across_chunks():
    """Power laws tabulated on the default log-uniform grid are interpolated exactly in log-log at per-pixel C
    (≥ 2¹⁸ pixels, so across the chunk boundary), clamped to the end values outside the grid, NaN where C is
    NaN; a table with a zero takes the general path (positive nodes only, same power law); a grid that is not
    log-uniform too."""
    rng = np.random.default_rng(3)
    c = np.exp(rng.uniform(np.log(1e-4), np.log(1e6), size=(2, (1 << 17) + 5)))
    c[0, 7] = c[1, -1] = np.nan
    grid = C_GRID_UG_PER_L
    tables = {"a": 0.2 * grid**0.7, "b": 3.0 * grid**-0.4, "z": np.where(grid < 1e-2, 0.0, 5.0 * grid**0.3)}
    got = interpolate_terms(tables, c, grid)
    cc = np.clip(c, grid[0], grid[-1])
    for name, k, p in (("a", 0.2, 0.7), ("b", 3.0, -0.4)):
        assert got[name].shape == c.shape
        np.testing.assert_allclose(got[name][np.isfinite(c)], (k * cc**p)[np.isfinite(c)], rtol=1e-9)
        assert np.isnan(got[name][0, 7]) and np.isnan(got[name][1, -1])
    above = np.isfinite(c) & (c >= 1e-2)
    np.testing.assert_allclose(got["z"][above], 5.0 * cc[above] ** 0.3, rtol=1e-9)
    assert np.isnan(got["z"][0, 7])
    uneven = np.array([1.0, 2.0, 10.0, 11.0, 100.0])
    out = interpolate_terms({"a": 0.2 * uneven**0.7}, np.array([1.5, 5.0, 50.0, 500.0, np.nan]), uneven)["a"]
    np.testing.assert_allclose(out[:4], 0.2 * np.array([1.5, 5.0, 50.0, 100.0]) ** 0.7, rtol=1e-12)
    assert np.isnan(out[4])
    assert interpolate_terms({}, c, grid) == {}


def test_dominant_term_is_the_largest_median_over_finite_pixels():
    terms = {"depth": np.array([1.0, 2.0, np.nan, 30.0]), "epsilon": np.array([[5.0, np.inf], [4.0, 6.0]]),
             "ratio": np.array([np.nan, np.nan])}
    dom = dominant(terms)
    assert dom == {"median_terms_ug_per_L": {"depth": 2.0, "epsilon": 5.0, "ratio": None}, "dominant": "epsilon"}
    assert dominant({"ratio": np.array([np.nan])}) == {"median_terms_ug_per_L": {"ratio": None}, "dominant": None}


@pytest.mark.parametrize("model", [RefinedModel(water_absorption_per_m=0.0),
                                   LampModel(1.0, 0.3, water_absorption_per_m=0.0)], ids=["refined", "lamp"])
def test_narrowband_terms_of_epsilon_and_depth_against_the_closed_form(model):
    """Without water absorption the chlorophyll optical depth is τ = ln10 ε C (100 d) (ε in L mol⁻¹ cm⁻¹, C in
    mol/L = µg/L / (M 10⁶)). Scaling ε by s scales τ, so at a fixed ratio s C is fixed and σ_C(ε) = C σ_s
    (first order); for the refined model the depth enters only through τ, so σ_C(d) = C σ_d / d. ∂B/∂C is
    (dR/dτ)(τ/C) from the closed form's own τ-derivative. Central differences: relative error ~ (h/p)² ≤ 1e-4."""
    depth, c = 0.4, np.array([50.0, 300.0])
    inputs = [Uncertain("depth", depth, 0.01, "m"), Uncertain("epsilon", 1.0, 0.02, "relative")]
    terms = uncertainty_terms(model, depth, c, inputs)
    np.testing.assert_allclose(terms["epsilon"], c * 0.02, rtol=2e-3)
    if isinstance(model, RefinedModel):
        np.testing.assert_allclose(terms["depth"], c * 0.01 / depth, rtol=2e-3)
    mol = c / (CHLA_MOLAR_MASS_G_PER_MOL * 1e6)
    tau = np.log(10) * model.epsilon_L_per_mol_cm * mol * 100 * depth
    cf = model.closed_form_at(depth) if isinstance(model, LampModel) else model.closed_form()
    np.testing.assert_allclose(model_ratio(model, c, depth), cf.ratio(tau), rtol=1e-12)
    np.testing.assert_allclose(derivative_c(model, c, depth), cf.ratio_derivative(tau) * tau / c, rtol=1e-6)
    np.testing.assert_allclose(forward_for(model, depth, "epsilon")(1.1, c), cf.ratio(1.1 * tau), rtol=1e-12)
    with pytest.raises(ValueError, match="unknown uncertain input 'sun_zenith'"):
        forward_for(model, depth, "sun_zenith")
    assert "epsilon" not in uncertainty_terms(model, depth, c, [Uncertain("epsilon", 1.0, 0.0, "relative")])


def test_all_terms_adds_the_ratio_noise_term_when_one_was_given():
    """The inversion's own σ_C is the 'ratio' term only when it is known somewhere; the stated inputs follow."""
    model = RefinedModel(water_absorption_per_m=0.0)
    c = np.array([[40.0, np.nan], [200.0, 90.0]])
    inputs = [Uncertain("epsilon", 1.0, 0.02, "relative")]
    known = Inversion(c * 0.0, c, np.array([[1.5, np.nan], [2.0, np.nan]]), c * 0.0, np.zeros(c.shape, np.uint8))
    terms = all_terms(known, model, 0.4, inputs)
    assert list(terms) == ["ratio", "epsilon"]
    np.testing.assert_array_equal(terms["ratio"], known.sigma_ug_per_L)
    np.testing.assert_allclose(terms["epsilon"][np.isfinite(c)], 0.02 * c[np.isfinite(c)], rtol=2e-3)
    unknown = Inversion(c * 0.0, c, np.full(c.shape, np.nan), c * 0.0, np.zeros(c.shape, np.uint8))
    assert list(all_terms(unknown, model, 0.4, inputs)) == ["epsilon"]


def test_field_model_inputs_absorbers_and_uncertainty_terms():
    """A field model built with its own chlorophyll spectrum, water and background absorption: B(C) against the
    rendering; its illuminant is the normalised global irradiance; the 'sun_zenith', 'diffuse_fraction' and
    'epsilon' inputs of the uncertainty module re-render with that input changed (ε scales A), and each σ_C term
    is |∂B/∂p| σ_p / |∂B/∂C| with both derivatives from renderings (central differences)."""
    sky_wl = np.arange(500.0, 781.0, 20.0)
    glob = np.linspace(1.0, 2.0, sky_wl.size)
    diffuse = 0.4 * glob
    sky = MeasuredSky(45.0, sky_wl, glob - diffuse, diffuse)
    chl = ChlorophyllAbsorption(np.array([500.0, 640.0, 700.0]), np.array([0.01, 0.02, 0.005]),
                                np.array([0.8, 0.7, 0.9]), "test")
    water = 0.3 + 0.001 * (FIELD_WL - 520.0)
    geom = FieldGeometry(view_angle_rad=0.2)
    u_c = 0.02 * FIELD_C
    model = field_band_model(FIELD_WL, FIELD_C, sky=sky, geometry=geom, chlorophyll=chl,
                             water_absorption_per_m=water, background_absorption_per_m=0.15, sensitivity_sigma=u_c)
    c, d = np.array([8.0, 30.0]), 0.5

    def truth(cc, sun=45.0, dif=1.0, scale=1.0):
        return np.array([_field_truth(sky_wl, glob - diffuse, dif * diffuse, sun, geom, x, d, chl=chl,
                                      a_scale=scale, water=water, background=0.15) for x in np.atleast_1d(cc)])

    np.testing.assert_allclose(model.ratio(c, d), truth(c), rtol=1e-5)
    e_g = np.interp(FIELD_WL, sky_wl, glob)
    np.testing.assert_allclose(model.illuminant, e_g / e_g.max(), rtol=1e-12)  # the shape, largest value 1
    np.testing.assert_array_equal(model.sensitivity_sigma, u_c)
    np.testing.assert_allclose(forward_for(model, d, "sun_zenith")(30.0, c), truth(c, sun=30.0), rtol=1e-5)
    np.testing.assert_allclose(forward_for(model, d, "diffuse_fraction")(1.3, c), truth(c, dif=1.3), rtol=1e-5)
    np.testing.assert_allclose(forward_for(model, d, "epsilon")(1.2, c), truth(c, scale=1.2), rtol=1e-5)
    db_dc = (truth(c * 1.001) - truth(c * 0.999)) / (0.002 * c)
    inputs = [Uncertain("sun_zenith", 45.0, 2.0, "deg"), Uncertain("diffuse_fraction", 1.0, 0.1, "relative"),
              Uncertain("epsilon", 1.0, 0.05, "relative")]
    terms = uncertainty_terms(model, d, c, inputs)
    for q, kw in zip(inputs, [{"sun": 46.0}, {"dif": 1.05}, {"scale": 1.025}], strict=True):
        key, hi = next(iter(kw.items()))
        lo = {"sun": 44.0, "dif": 0.95, "scale": 0.975}[key]
        db_dp = (truth(c, **{key: hi}) - truth(c, **{key: lo})) / (2 * (hi - q.value))
        np.testing.assert_allclose(terms[q.name], np.abs(db_dp / db_dc) * q.sigma, rtol=0.02, err_msg=q.name)
    sb = model.ratio_sigma_from_sensitivity(c, d, u_c)
    np.testing.assert_allclose(terms["sensitivity"], np.abs(sb / db_dc), rtol=0.02)


def test_solve_c_brackets_between_a_millionth_and_the_upper_bound():
    """B(C) = exp(−0.03 C): C = ln(1/B)/0.03 for 0.5 µg/L and 9e4 µg/L (inside 1e-6..1e5); a root at 2e5 or a
    ratio above B(1e-6) is no solution (NaN); the upper bound can be raised."""
    def forward(cc):
        return np.exp(-3e-5 * np.asarray(cc, float))

    for c in (0.5, 9e4):
        assert solve_c(forward, float(np.exp(-3e-5 * c))) == pytest.approx(c, rel=1e-9)
    assert np.isnan(solve_c(forward, float(np.exp(-3e-5 * 2e5))))
    assert solve_c(forward, float(np.exp(-3e-5 * 2e5)), c_hi_ug_per_L=1e6) == pytest.approx(2e5, rel=1e-9)
    assert np.isnan(solve_c(forward, 1.0))


def test_term_with_no_spread_and_a_table_with_no_positive_node():
    """An input without uncertainty gives zeros shaped like C; a table without a positive node interpolates to 0
    where C is finite and NaN where it is not."""
    c = np.array([[1.0, 2.0], [3.0, np.nan]])
    z = term_sigma_c(lambda p, cc: np.exp(-p * cc), Uncertain("x", 0.03, 0.0, ""), c, -np.ones(c.shape))
    assert z.shape == (2, 2) and not z.any()
    out = interpolate_term(np.zeros(C_GRID_UG_PER_L.size), c)
    assert out[0, 0] == 0.0 and out[1, 0] == 0.0 and np.isnan(out[1, 1])


def test_interpolated_terms_follow_the_table_not_a_power_law():
    """A table curved in log-log (not a power law, so extrapolating a neighbouring cell shows), on the default
    log-uniform grid: each C in the top and bottom cells gives the log-log line between its two nodes. A table
    with zeros below a node gives that node's value below it (only positive nodes are used). A grid whose log
    steps differ by less than a factor 2 (not log-uniform) is interpolated between its own nodes."""
    grid = C_GRID_UG_PER_L
    lg = np.log(grid)
    kink = np.exp(0.1 * (lg - lg[grid.size // 2]) ** 2)  # a parabola in log-log: no two cells on one line
    c = np.array([grid[-1] * 0.999, np.sqrt(grid[-2] * grid[-1]), grid[0] * 1.001, np.sqrt(grid[0] * grid[1])])

    def loglog(x, xs, ys):
        i = np.searchsorted(xs, x) - 1
        f = (np.log(x) - np.log(xs[i])) / (np.log(xs[i + 1]) - np.log(xs[i]))
        return np.exp(np.log(ys[i]) + f * (np.log(ys[i + 1]) - np.log(ys[i])))

    got = interpolate_terms({"k": kink}, c, grid)["k"]
    np.testing.assert_allclose(got, [loglog(x, grid, kink) for x in c], rtol=1e-9)
    first = 5  # zeros on the first five nodes
    z = np.where(np.arange(grid.size) < first, 0.0, 2.0 * grid**0.3)
    below = np.array([grid[1], grid[first - 1] * 1.01, np.sqrt(grid[first - 1] * grid[first])])
    np.testing.assert_allclose(interpolate_terms({"z": z}, below, grid)["z"], 2.0 * grid[first] ** 0.3, rtol=1e-12)
    np.testing.assert_allclose(interpolate_term(z, below, grid), 2.0 * grid[first] ** 0.3, rtol=1e-12)
    uneven = np.array([1.0, 2.0, 3.0, 10.0, 20.0])  # log steps 0.69, 0.41, 1.20, 0.69
    vals = np.array([1.0, 4.0, 2.0, 8.0, 3.0])
    x = np.array([1.5, 2.5, 5.0, 15.0])
    np.testing.assert_allclose(interpolate_terms({"u": vals}, x, uneven)["u"],
                               [loglog(v, uneven, vals) for v in x], rtol=1e-12)


def test_a_band_model_without_a_sensitivity_uncertainty_has_no_sensitivity_term():
    """u_c(λ) unknown (None): the terms are those of the stated inputs only."""
    wl = np.arange(600.0, 701.0, 10.0)
    model = BandModel(wl, np.exp(-0.5 * ((wl - 650.0) / 20.0) ** 2), water_absorption_per_m=0.0)
    terms = uncertainty_terms(model, 0.3, np.array([5.0, 50.0]), [Uncertain("depth", 0.3, 0.01, "m")])
    assert set(terms) == {"depth"} and np.all(terms["depth"] > 0)


def test_uncertainty_helpers_on_closed_forms():
    """With B(C; p) = exp(−p C) (p = 0.03 per µg/L): σ_C from p is |∂B/∂p| σ_p / |∂B/∂C| = C σ_p / p (central
    differences with h = σ_p/2 of an exponential: relative error (h C)²/6 ≤ 7e-7 here); solve_c inverts it to
    ln(1/B)/p; terms combine in quadrature; a term tabulated as a power law is interpolated exactly in log-log,
    clamped at the grid's ends, NaN kept."""
    c = np.array([2.0, 30.0, 400.0])
    p = Uncertain("absorption", 0.03, 1e-5, "per µg/L")

    def forward(pv, cc):
        return np.exp(-pv * np.asarray(cc, float))

    db_dc = -0.03 * np.exp(-0.03 * c)
    np.testing.assert_allclose(term_sigma_c(forward, p, c, db_dc), c * 1e-5 / 0.03, rtol=2e-6)
    assert not np.any(term_sigma_c(forward, Uncertain("x", 0.03, 0.0, ""), c, db_dc))
    assert solve_c(lambda cc: forward(0.03, cc), float(np.exp(-0.03 * 55.0))) == pytest.approx(55.0, rel=1e-9)
    assert np.isnan(solve_c(lambda cc: forward(0.03, cc), 1.5))
    np.testing.assert_allclose(combine({"a": np.array([3.0, 5.0]), "b": np.array([4.0, 12.0]), "c": 0.0}),
                               [5.0, 13.0])
    grid = np.geomspace(0.1, 1000.0, 9)
    term = 0.2 * grid**0.7
    got = interpolate_term(term, np.array([0.37, 52.0, 1e4, 1e-3, np.nan]), grid)
    np.testing.assert_allclose(got[:2], 0.2 * np.array([0.37, 52.0]) ** 0.7, rtol=1e-12)
    assert got[2] == pytest.approx(term[-1]) and got[3] == pytest.approx(term[0]) and np.isnan(got[4])


def test_monte_carlo_sigma_of_a_linear_inversion():
    """B = exp(−p C) with p ~ N(0.03, 0.0015): C = ln(1/B)/p, so σ_C ≈ C σ_p/p = 5 % of C to first order (the
    1/p nonlinearity adds (σ_p/p)² ≈ 0.25 % relative); 400 draws: the standard error of a standard deviation is
    1/√(2·399) = 3.5 %, so within 12 % (3.4σ)."""
    p = Uncertain("absorption", 0.03, 0.0015, "per µg/L")
    sigma = monte_carlo_sigma(lambda pv, cc: np.exp(-pv * np.asarray(cc, float)), p, float(np.exp(-0.03 * 40.0)))
    assert sigma == pytest.approx(0.05 * 40.0, rel=0.12)

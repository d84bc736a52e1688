"""Fast formula tests of the physics functions (small arrays, milliseconds each), each against a value computed
here by other means. They are the test selection of the mutation run (docs/testing.md)."""

from __future__ import annotations

import numpy as np
import pytest

from camcal.spectral import merge_sweeps
from camcal.spectral_model import SpectralSensitivity
from camcal.water.models import LampModel, RefinedModel
from camcal.water.uncertainty import (
    C_GRID_UG_PER_L,
    Uncertain,
    derivative_c,
    dominant,
    forward_for,
    interpolate_terms,
    model_ratio,
    uncertainty_terms,
)
from camcal.water.units import CHLA_MOLAR_MASS_G_PER_MOL


def _gauss(wl, mu, s, a=1.0):
    return a * np.exp(-0.5 * ((np.asarray(wl, float) - mu) / s) ** 2)


# ---- spectral: merging sweeps ---------------------------------------------------------------------------------

def test_merged_sweeps_scale_uncertainty_when_the_second_sweep_lies_below_the_first():
    """a: 550-750 nm, b: 400-600 nm = truth / 2.5 (1 % and 2 % uncertainties). The overlap is 550-600 nm, six
    wavelengths, whichever sweep starts first: u_k = 1/√(Σ w b²) over them (three planes alike), w = 1/(u_a² +
    k² u_b²), and below 550 nm the merged uncertainty is √((k u_b)² + (u_k b)²). One wavelength fewer at either
    end of the overlap changes u_k by ≈ 15 %."""
    wa, wb = np.arange(550.0, 751.0, 10.0), np.arange(400.0, 601.0, 10.0)

    def truth(wl):
        return _gauss(wl, 560.0, 80.0) + 0.1

    a = SpectralSensitivity(wa, {p: truth(wa) for p in "RGB"}, {p: 0.01 * truth(wa) for p in "RGB"},
                            "relative", "relative")
    b = SpectralSensitivity(wb, {p: truth(wb) / 2.5 for p in "RGB"}, {p: 0.02 * truth(wb) / 2.5 for p in "RGB"},
                            "relative", "relative")
    m = merge_sweeps(a, b)
    ov = np.arange(550.0, 601.0, 10.0)
    w = 1 / ((0.01 * truth(ov)) ** 2 + (0.02 * truth(ov)) ** 2)
    u_k = 1 / np.sqrt(3 * np.sum(w * (truth(ov) / 2.5) ** 2))
    only_b = m.wavelength_nm < 550
    t = truth(m.wavelength_nm[only_b])
    np.testing.assert_allclose(m.uncertainty["R"][only_b], np.hypot(0.02 * t, u_k * t / 2.5), rtol=1e-9)
    np.testing.assert_allclose(m.values["R"], truth(m.wavelength_nm), rtol=1e-12)
    assert "2.5" in m.notes[-1] and f"{u_k:.2g}" in m.notes[-1]


# ---- water/uncertainty: tabulated terms, the dominant term, the inputs of the narrowband models ---------------

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

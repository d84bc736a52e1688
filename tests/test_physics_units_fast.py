"""Fast formula tests of the physics functions (small arrays, milliseconds each), each against a value computed
here by other means. They are the test selection of the mutation run (docs/testing.md)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pvlib
import pytest

from camcal.errors import CamcalError
from camcal.spectral import merge_sweeps
from camcal.spectral_model import SpectralSensitivity
from camcal.water.band import bricaud_1998
from camcal.water.field import ClearSky, FieldGeometry, MeasuredSky, OvercastSky, field_band_model
from camcal.water.models import LampModel, RefinedModel
from camcal.water.purewater import pure_water_absorption_per_m
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


# ---- water/field: the clear sky, the global-irradiance weights, the varied inputs ----------------------------

FIELD_WL = np.arange(520.0, 761.0, 4.0)
FIELD_C = _gauss(FIELD_WL, 640.0, 22.0)  # a red channel, negligible at the grid's ends


def test_clear_sky_is_spectrl2_with_the_direct_beam_on_a_horizontal_surface():
    """ClearSky is pvlib's SPECTRL2 (Bird & Riordan 1986) for a horizontal surface: E_dir = DNI cos θs (the beam
    on the horizontal), E_dif = DHI, read linearly between SPECTRL2's wavelengths; inputs out of range refused."""
    sky = ClearSky(35.0, aerosol_optical_depth_500nm=0.2, precipitable_water_cm=2.0, ozone_atm_cm=0.3,
                   pressure_Pa=95000.0, day_of_year=100)
    am = float(pvlib.atmosphere.get_relative_airmass(35.0))
    s = pvlib.spectrum.spectrl2(apparent_zenith=35.0, aoi=35.0, surface_tilt=0.0, ground_albedo=0.06,
                                surface_pressure=95000.0, relative_airmass=am, precipitable_water=2.0, ozone=0.3,
                                aerosol_turbidity_500nm=0.2, dayofyear=100)
    wl = np.asarray(s["wavelength"], float)
    x = np.array([wl[40], 0.5 * (wl[60] + wl[61]), 663.0])
    direct, diffuse = sky.irradiance(x)
    dni = np.asarray(s["dni"], float).reshape(-1) * np.cos(np.radians(35.0))
    np.testing.assert_allclose(direct, np.interp(x, wl, dni), rtol=1e-12)
    np.testing.assert_allclose(diffuse, np.interp(x, wl, np.asarray(s["dhi"], float).reshape(-1)), rtol=1e-12)
    assert direct[1] == pytest.approx(0.5 * (dni[60] + dni[61]), rel=1e-12)
    assert sky.with_(sun_zenith_deg=10.0) == ClearSky(10.0, 0.2, 2.0, 0.3, 95000.0, 100)
    for bad in ({"sun_zenith_deg": 89.0}, {"sun_zenith_deg": -1.0}, {"aerosol_optical_depth_500nm": 5.0},
                {"precipitable_water_cm": 15.0}, {"ozone_atm_cm": 0.0}, {"ozone_atm_cm": 1.0},
                {"pressure_Pa": 3e4}, {"pressure_Pa": 1.2e5}):
        with pytest.raises(CamcalError):
            ClearSky(**{"sun_zenith_deg": 35.0, **bad})
    ClearSky(0.0, aerosol_optical_depth_500nm=0.0, precipitable_water_cm=0.0)  # the lower ends are allowed


def test_measured_and_overcast_skies():
    """A measured sky is linear between its samples and NaN outside; the overcast sky is all diffuse."""
    sky = MeasuredSky(30.0, np.array([500.0, 600.0, 700.0]), np.array([1.0, 3.0, 2.0]), np.array([0.5, 0.5, 1.5]))
    d, f = sky.irradiance(np.array([450.0, 550.0, 690.0, 710.0]))
    np.testing.assert_allclose(d[1:3], [2.0, 2.1], rtol=1e-12)
    np.testing.assert_allclose(f[1:3], [0.5, 1.4], rtol=1e-12)
    assert np.isnan(d[0]) and np.isnan(d[3]) and np.isnan(f[0]) and np.isnan(f[3])
    with pytest.raises(CamcalError, match="no aerosol"):
        sky.with_(aerosol_optical_depth_500nm=0.1)
    assert sky.with_(sun_zenith_deg=10.0).sun_zenith_deg == 10.0
    d, f = OvercastSky().irradiance(np.array([500.0, 600.0]))
    assert d.tolist() == [0.0, 0.0] and f.tolist() == [1.0, 1.0]
    assert OvercastSky().with_(sun_zenith_deg=40.0) == OvercastSky()


def _field_truth(sky_wl, direct, diffuse, sun_deg, geom, c, d):
    """B = Σ c E_g R dλ / Σ c E_g dλ (trapezoid rule) with R = (1 − f) R_dir + f R_sky, E_g = E_dir + E_dif,
    f = E_dif / E_g; R_dir and R_sky from the geometry's closed forms at the sun's angle."""
    e_dir, e_dif = np.interp(FIELD_WL, sky_wl, direct), np.interp(FIELD_WL, sky_wl, diffuse)
    glob = e_dir + e_dif
    f = e_dif / glob
    chl = bricaud_1998()
    a = np.interp(FIELD_WL, chl.wavelengths_nm, chl.coefficient_m2_per_mg, right=0.0)
    tau = (pure_water_absorption_per_m(FIELD_WL) + a * c ** np.interp(FIELD_WL, chl.wavelengths_nm,
                                                                       chl.exponent)) * d
    g = replace(geom, sun_zenith_rad=np.radians(sun_deg))
    r = (1 - f) * g.direct_form().ratio(tau) + f * g.sky_form().ratio(tau)
    return np.trapezoid(FIELD_C * glob * r, FIELD_WL) / np.trapezoid(FIELD_C * glob, FIELD_WL)


def test_field_band_ratio_weights_by_the_global_irradiance_and_varies_each_input():
    """Under a sky whose global irradiance doubles across the band and whose diffuse fraction falls from 0.6 to
    0.2, B(C) is the c E_g-weighted mean of the per-wavelength mixture (rendered here); 'diffuse_fraction' = s
    scales the diffuse irradiance (the same as a sky measured with s E_dif), 'sun_zenith' moves the sun."""
    sky_wl = np.arange(500.0, 781.0, 20.0)
    glob = np.linspace(1.0, 2.0, sky_wl.size)
    diffuse = glob * np.linspace(0.6, 0.2, sky_wl.size)
    direct = glob - diffuse
    geom = FieldGeometry(view_angle_rad=0.25, albedo=0.8)
    model = field_band_model(FIELD_WL, FIELD_C, sky=MeasuredSky(45.0, sky_wl, direct, diffuse), geometry=geom)
    c, d = 12.0, 0.6
    assert float(model.ratio(c, d)) == pytest.approx(_field_truth(sky_wl, direct, diffuse, 45.0, geom, c, d),
                                                     rel=1e-5)
    more = model.varied("diffuse_fraction", 1.5)
    assert float(more.ratio(c, d)) == pytest.approx(_field_truth(sky_wl, direct, 1.5 * diffuse, 45.0, geom, c, d),
                                                    rel=1e-5)
    lower = model.varied("sun_zenith", 30.0)
    assert float(lower.ratio(c, d)) == pytest.approx(_field_truth(sky_wl, direct, diffuse, 30.0, geom, c, d),
                                                     rel=1e-5)
    r, dr = model.ratio_and_derivative(np.array([c, 2 * c]), d)
    h = 1e-3 * c
    num = (model.ratio(np.array([c + h, 2 * c + h]), d) - model.ratio(np.array([c - h, 2 * c - h]), d)) / (2 * h)
    np.testing.assert_allclose(dr, num, rtol=1e-5)
    np.testing.assert_allclose(model.ratio_derivative(np.array([c, 2 * c]), d), dr, rtol=1e-12)
    with pytest.raises(CamcalError, match="no aerosol"):
        model.varied("aerosol", 0.1)
    with pytest.raises(ValueError, match="unknown field input 'depth'"):
        model.varied("depth", 1.0)
    short = MeasuredSky(45.0, np.array([600.0, 700.0]), np.ones(2), np.ones(2))
    with pytest.raises(CamcalError, match="does not cover"):
        field_band_model(FIELD_WL, FIELD_C, sky=short)


def test_field_model_aerosol_input_changes_the_clear_sky():
    """'aerosol' rebuilds the clear sky at that optical depth (negative values are held at 0); the field model's
    light is then SPECTRL2's global irradiance."""
    model = field_band_model(FIELD_WL, FIELD_C, sky=ClearSky(40.0, aerosol_optical_depth_500nm=0.1))
    hazy = model.varied("aerosol", 0.4)
    assert hazy.sky == ClearSky(40.0, aerosol_optical_depth_500nm=0.4)
    assert model.varied("aerosol", -0.2).sky == ClearSky(40.0, aerosol_optical_depth_500nm=0.0)
    s = ClearSky(40.0, aerosol_optical_depth_500nm=0.4)
    wl = np.arange(500.0, 781.0, 5.0)
    direct, diffuse = s.irradiance(wl)
    assert float(hazy.ratio(12.0, 0.6)) == pytest.approx(
        _field_truth(wl, direct, diffuse, 40.0, FieldGeometry(), 12.0, 0.6), rel=2e-4)

"""Fast formula tests of the physics functions (small arrays, milliseconds each), each against a value computed
here by other means. They are the test selection of the mutation run (docs/testing.md)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pvlib
import pytest
from scipy.optimize import brentq, minimize
from scipy.special import eval_legendre
from scipy.stats import norm

from camcal.calibrate.flat import fit_2d_plane, fit_radial_plane
from camcal.calibrate.response import emva_linearity_error, fit_eq12, fit_line, fit_srgb_form, saturation_point
from camcal.calibrate.sweep import deconvolve_slit, slit_matrix
from camcal.errors import CamcalError
from camcal.frame import Exposure
from camcal.models.correct import Calibration, correct_planes, system_gain_dn_per_e
from camcal.models.dark import DarkModel
from camcal.models.exposure import frame_relative_exposure
from camcal.models.flat import FlatModel, PlaneGeometry, dead_pixels
from camcal.models.spectral import RELATIVE_UNITS, SpectralSensitivity, to_relative
from camcal.water.band import BandModel, ChlorophyllAbsorption, bricaud_1998
from camcal.water.field import (
    DEFAULT_AOD_500NM,
    DEFAULT_DAY_OF_YEAR,
    DEFAULT_OZONE_ATM_CM,
    DEFAULT_PRECIPITABLE_WATER_CM,
    DEFAULT_PRESSURE_PA,
    ClearSky,
    FieldGeometry,
    MeasuredSky,
    OvercastSky,
    field_band_model,
    read_sky_csv,
)
from camcal.water.invert import Inversion
from camcal.water.models import LampModel, RefinedModel
from camcal.water.purewater import pure_water_absorption_per_m
from camcal.water.uncertainty import (
    C_GRID_UG_PER_L,
    Uncertain,
    all_terms,
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
    parse_concentration_mol_per_L,
    parse_epsilon_L_per_mol_cm,
    parse_length_m,
    specific_absorption_m2_per_mg,
)
from tests.oracles import merge_sweeps, to_colour, to_colour_planes


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


def _field_truth(sky_wl, direct, diffuse, sun_deg, geom, c, d, *, chl=None, a_scale=1.0, water=None,
                 background=0.0):
    """B = Σ c E_g R dλ / Σ c E_g dλ (trapezoid rule) with R = (1 − f) R_dir + f R_sky, E_g = E_dir + E_dif,
    f = E_dif / E_g; R_dir and R_sky from the geometry's closed forms at the sun's angle; τ = (a_w + a_bg +
    s A C^E) d with A, E of ``chl`` (Bricaud et al. 1998 by default) and a_w of Pope & Fry (1997) by default."""
    e_dir, e_dif = np.interp(FIELD_WL, sky_wl, direct), np.interp(FIELD_WL, sky_wl, diffuse)
    glob = e_dir + e_dif
    f = e_dif / glob
    chl = chl or bricaud_1998()
    a = np.interp(FIELD_WL, chl.wavelengths_nm, chl.coefficient_m2_per_mg, left=0.0, right=0.0)
    a_w = pure_water_absorption_per_m(FIELD_WL) if water is None else water
    tau = (a_w + background + a_scale * a * c ** np.interp(FIELD_WL, chl.wavelengths_nm, chl.exponent)) * d
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
    assert r.shape == (2,)
    np.testing.assert_allclose(r, [_field_truth(sky_wl, direct, diffuse, 45.0, geom, cc, d) for cc in (c, 2 * c)],
                               rtol=1e-5)
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


def test_measured_sky_csv_any_column_order_comments_and_refusals(tmp_path):
    """The CSV's columns are found by name (any order, extra columns ignored), '#' lines skipped; a missing
    column, a non-number, fewer than two rows, falling wavelengths, negative or all-zero diffuse are refused."""
    p = tmp_path / "sky.csv"
    p.write_text("# measured at noon\ndiffuse_horizontal,note,wavelength_nm,direct_horizontal\n"
                 "0.5,1,500,1.0\n# a comment\n0.7,2,600,3.0\n\n1.5,3,700,2.0\n")
    sky = read_sky_csv(p, 33.0)
    assert sky.sun_zenith_deg == 33.0 and sky.source == str(p)
    np.testing.assert_array_equal(sky.wavelengths_nm, [500.0, 600.0, 700.0])
    np.testing.assert_array_equal(sky.direct_horizontal, [1.0, 3.0, 2.0])
    np.testing.assert_array_equal(sky.diffuse_horizontal, [0.5, 0.7, 1.5])
    bad = {"columns": "wavelength_nm,direct_horizontal\n500,1\n600,2\n",
           "a row is not numbers": "wavelength_nm,direct_horizontal,diffuse_horizontal\n500,1,x\n600,2,1\n",
           "two complete rows": "wavelength_nm,direct_horizontal,diffuse_horizontal\n500,1,1\n",
           "must increase": "wavelength_nm,direct_horizontal,diffuse_horizontal\n600,1,1\n500,2,1\n",
           "be >= 0": "wavelength_nm,direct_horizontal,diffuse_horizontal\n500,-1,1\n600,2,1\n",
           "diffuse not all 0": "wavelength_nm,direct_horizontal,diffuse_horizontal\n500,1,0\n600,2,0\n"}
    for phrase, text in bad.items():
        p.write_text(text)
        with pytest.raises(CamcalError, match=phrase):
            read_sky_csv(p, 30.0)
    p.write_text("wavelength_nm,direct_horizontal,diffuse_horizontal\n500,1,1\n600,2,nan\n")
    with pytest.raises(CamcalError, match="finite numbers"):
        read_sky_csv(p, 30.0)


def test_field_description_gives_the_in_band_diffuse_fraction_and_the_light():
    """The in-band diffuse fraction is Σ c E_g f dλ / Σ c E_g dλ: with a constant fraction 0.3 it is 0.3; the
    light is described by the sky's own record."""
    sky_wl = np.arange(500.0, 781.0, 20.0)
    sky = MeasuredSky(45.0, sky_wl, 0.7 * np.linspace(1.0, 2.0, sky_wl.size),
                      0.3 * np.linspace(1.0, 2.0, sky_wl.size), source="noon.csv")
    d = field_band_model(FIELD_WL, FIELD_C, sky=sky, geometry=FieldGeometry(transmittance="mean")).describe()
    assert d["diffuse_fraction_in_band"] == pytest.approx(0.3, rel=1e-12)
    assert d["geometry"] == "field (sun + sky, flat surface)" and d["sky_transmittance"] == "mean"
    assert d["light"] == {"sky": "measured", "source": "noon.csv", "sun_zenith_deg": 45.0}
    ramp = MeasuredSky(45.0, sky_wl, np.ones(sky_wl.size), np.linspace(0.0, 1.5, sky_wl.size) ** 2)
    e_dif = np.interp(FIELD_WL, sky_wl, np.linspace(0.0, 1.5, sky_wl.size) ** 2)  # not symmetric about 640 nm
    f = e_dif / (1.0 + e_dif)
    w = FIELD_C * (1.0 + e_dif)
    expect = np.trapezoid(w * f, FIELD_WL) / np.trapezoid(w, FIELD_WL)  # c negligible at the grid's ends
    got = field_band_model(FIELD_WL, FIELD_C, sky=ramp).describe()["diffuse_fraction_in_band"]
    assert got == pytest.approx(expect, rel=1e-6)  # the model's end weights differ from the trapezoid's by c(ends)
    assert OvercastSky().describe() == {"sky": "overcast (diffuse only)"}
    assert ClearSky(20.0).describe() == {
        "sky": "clear (SPECTRL2, Bird & Riordan 1986, pvlib)", "sun_zenith_deg": 20.0,
        "aerosol_optical_depth_500nm": DEFAULT_AOD_500NM, "precipitable_water_cm": DEFAULT_PRECIPITABLE_WATER_CM,
        "ozone_atm_cm": DEFAULT_OZONE_ATM_CM, "pressure_Pa": DEFAULT_PRESSURE_PA,
        "day_of_year": DEFAULT_DAY_OF_YEAR}


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


# ---- spectral_model: the colour-science views and the summary's derived figures -------------------------------

def _bayer_curves():
    wl = np.arange(400.0, 701.0, 5.0)
    vals = {"R": _gauss(wl, 600, 30, 2.0), "G1": _gauss(wl, 530, 35, 3.0), "G2": _gauss(wl, 530, 35, 3.4),
            "B": _gauss(wl, 490, 20, 1.5)}
    unc = {p: 0.01 * v + 1e-3 for p, v in vals.items()}
    return SpectralSensitivity(wl, vals, unc, "DN/s per W/(m2 sr nm)", "absolute", 100.0, 4.0, bandwidth_nm=10.0)


def test_colour_views_are_the_mean_green_and_the_four_planes():
    s = _bayer_curves()
    cs = to_colour(s)
    np.testing.assert_array_equal(cs.wavelengths, s.wavelength_nm)
    np.testing.assert_allclose(cs.values[:, 1], 0.5 * (s.values["G1"] + s.values["G2"]), rtol=1e-12)
    np.testing.assert_allclose(cs.values[:, 0], s.values["R"], rtol=1e-12)
    np.testing.assert_allclose(cs.values[:, 2], s.values["B"], rtol=1e-12)
    assert cs.name == "camcal c(λ) [DN/s per W/(m2 sr nm)]"
    planes = to_colour_planes(s)
    assert list(planes.labels) == ["R", "G1", "G2", "B"] and planes.name == "camcal c(λ) planes [DN/s per W/(m2 sr nm)]"
    np.testing.assert_allclose(planes.values[:, 2], s.values["G2"], rtol=1e-12)
    np.testing.assert_array_equal(planes.wavelengths, s.wavelength_nm)


def test_sensitivity_summary_figures_against_closed_forms():
    """Peak 3.4 (G2) at 530 nm; λ_eff of a Gaussian is its centre and its equivalent width s√(2π) (trapezoid on
    5 nm, curves negligible at the ends); the relative uncertainty at the peak 0.01 + 1e-3/peak; the slit bias
    (σ²/2) c'' with σ = 10 nm FWHM → 4.25 nm and c'' of a Gaussian written out, RMS over the grid / 3.4."""
    s = _bayer_curves()
    sm = s.summary()
    assert sm["peak_value"] == pytest.approx(3.4) and sm["n_wavelengths"] == 61
    assert sm["wavelength_range_nm"] == [400.0, 700.0] and sm["mode"] == "absolute" and sm["bandwidth_nm"] == 10.0
    assert sm["peak_wavelength_nm"] == {"R": 600.0, "G1": 530.0, "G2": 530.0, "B": 490.0, "G": 530.0}
    for k, (mu, sd) in {"R": (600, 30), "G": (530, 35), "B": (490, 20)}.items():
        assert sm["effective_wavelength_nm"][k] == pytest.approx(mu, abs=0.05)
        assert sm["effective_bandwidth_nm"][k] == pytest.approx(sd * np.sqrt(2 * np.pi), rel=2e-3)
    for p, peak in {"R": 2.0, "G1": 3.0, "G2": 3.4, "B": 1.5}.items():
        assert sm["max_relative_uncertainty_at_peak"][p] == pytest.approx(0.01 + 1e-3 / peak, rel=1e-9)
    sigma = 10.0 / (2 * np.sqrt(2 * np.log(2)))
    wl = s.wavelength_nm
    c2 = _gauss(wl, 600, 30, 2.0) * (((wl - 600) / 30**2) ** 2 - 1 / 30**2)
    rms = np.sqrt(np.mean((0.5 * sigma**2 * c2) ** 2)) / 3.4
    assert sm["slit_bias_rms_of_peak"]["R"] == pytest.approx(rms, rel=2e-2)
    assert sm["notes"] == [] and sm["deconvolved"] is False and sm["reference_iso"] == 100.0
    assert sm["reference_f_number"] == 4.0 and sm["units"] == "DN/s per W/(m2 sr nm)"


def test_rgb_curves_views_and_figures_of_a_dim_and_an_empty_channel():
    """Linear-RAW curves (R, G, B): rgb() is the planes themselves; a channel that is zero everywhere has no
    effective wavelength or bandwidth (NaN), and a dim one (area 0.05 nm) has them all the same (centroid 550
    nm, equivalent width s√(2π) on a 2 nm grid)."""
    wl = np.arange(450.0, 651.0, 2.0)
    dim = _gauss(wl, 550.0, 10.0, 0.002)
    s = SpectralSensitivity(wl, {"R": np.zeros(wl.size), "G": dim, "B": -0.1 * np.ones(wl.size)},
                            {p: np.full(wl.size, 1e-4) for p in "RGB"}, "relative", "relative")
    rgb = s.rgb()
    assert list(rgb) == ["R", "G", "B"] and rgb["G"] is s.values["G"] and rgb["R"] is s.values["R"]
    assert rgb["B"] is s.values["B"]
    assert list(s.channels()) == ["R", "G", "B"]
    lam, width = s.effective_wavelength_nm(), s.effective_bandwidth_nm()
    assert np.isnan(lam["R"]) and np.isnan(width["R"]) and np.isnan(lam["B"]) and np.isnan(width["B"])
    assert lam["G"] == pytest.approx(550.0, abs=1e-9)
    assert width["G"] == pytest.approx(10.0 * np.sqrt(2 * np.pi), rel=1e-6)
    assert s.peak_wavelength_nm()["G"] == 550.0
    # relative uncertainty at the peak of a curve whose peak is below 1: 1e-4 / 0.002
    assert s.summary()["max_relative_uncertainty_at_peak"]["G"] == pytest.approx(0.05, rel=1e-9)


def test_to_relative_divides_by_the_largest_value_over_all_planes():
    s = _bayer_curves()
    r = to_relative(s)
    for p in s.plane_names:
        np.testing.assert_allclose(r.values[p], s.values[p] / 3.4, rtol=1e-12)
        np.testing.assert_allclose(r.uncertainty[p], s.uncertainty[p] / 3.4, rtol=1e-12)
    assert r.mode == "relative" and r.units == RELATIVE_UNITS and r.reference_iso == 100.0
    zero = SpectralSensitivity(s.wavelength_nm, {p: 0 * v for p, v in s.values.items()}, s.uncertainty,
                               "relative", "relative")
    with pytest.raises(CamcalError, match="no positive value; cannot normalise"):
        to_relative(zero)
    small = SpectralSensitivity(s.wavelength_nm, {p: 0.5 * v / 3.4 for p, v in s.values.items()}, s.uncertainty,
                                "relative", "relative")
    assert max(float(v.max()) for v in to_relative(small).values.values()) == pytest.approx(1.0)


def test_slit_bias_needs_a_bandwidth_four_samples_and_a_curve_not_deconvolved():
    """Four samples are enough for the not-a-knot spline (a cubic is reproduced exactly: c'' = 6 a λ + 2 b);
    three, no bandwidth, or a deconvolved curve give zeros shaped like the grid."""
    wl = np.array([500.0, 510.0, 520.0, 530.0])
    x = wl - 515.0
    cubic = 1e-4 * x**3 + 0.01 * x**2 + 2.0
    s = SpectralSensitivity(wl, {p: cubic for p in "RGB"}, {p: 0.01 * cubic for p in "RGB"}, "relative",
                            "relative", bandwidth_nm=5.0)
    sigma2 = (5.0 / (2 * np.sqrt(2 * np.log(2)))) ** 2
    np.testing.assert_allclose(s.slit_bias()["G"], 0.5 * sigma2 * (6e-4 * x + 0.02), rtol=1e-9)
    for other in (replace(s, bandwidth_nm=None), replace(s, deconvolved=True),
                  SpectralSensitivity(wl[:3], {p: cubic[:3] for p in "RGB"}, {p: cubic[:3] for p in "RGB"},
                                      "relative", "relative", bandwidth_nm=5.0)):
        bias = other.slit_bias()
        assert list(bias) == ["R", "G", "B"]
        assert all(b.shape == other.wavelength_nm.shape and not b.any() for b in bias.values())


# ---- flat: the weighted 2-D Legendre fit ---------------------------------------------------------------------

def _legendre_flat(scale):
    """Plane B of a 72 × 96 RGGB frame (36 × 48 planes, B at full-resolution offsets (1, 1)): u, v are the
    full-resolution coordinates mapped to [−1, 1] over the frame, so u = 2 (2x + 1)/95 − 1, v = 2 (2y + 1)/71 − 1."""
    geom = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (36, 48), "RGGB")
    yy, xx = np.mgrid[0:36:3, 0:48:3].astype(float)
    u, v = 2 * (2 * xx + 1) / 95.0 - 1, 2 * (2 * yy + 1) / 71.0 - 1
    surf = scale * (1.0 - 0.15 * eval_legendre(2, u) + 0.1 * u - 0.05 * v - 0.1 * eval_legendre(2, v))
    return geom, xx, yy, u, v, surf


def test_2d_flat_fit_is_the_relative_weighted_least_squares_on_positive_blocks():
    """On data with a fixed ±5 % pattern the fit is the least-squares solution with weights 1/d (relative
    residuals), computed here with the Legendre design written out; blocks that are 0 or NaN are left out; the
    level is the series at the centre and the RMS the relative residual."""
    geom, xx, yy, u, v, surf = _legendre_flat(0.8)
    pattern = 1 + 0.05 * np.sin(7 * xx + 3 * yy)
    data = surf * pattern
    data[0, 0], data[2, 3] = 0.0, np.nan
    level, coef, scale, rms = fit_2d_plane(data, xx, yy, geom, "B", 2, (20.0, 12.0))
    ok = np.isfinite(data) & (data > 0)
    d, uu, vv = data[ok], u[ok], v[ok]
    terms = [(i, j) for i in range(3) for j in range(3) if i + j <= 2]
    design = np.stack([eval_legendre(i, uu) * eval_legendre(j, vv) for i, j in terms], axis=1)
    sol = np.linalg.lstsq(design / d[:, None], np.ones(d.size), rcond=None)[0]
    uc, vc = 2 * 41.0 / 95.0 - 1, 2 * 25.0 / 71.0 - 1
    expect_level = sum(c * eval_legendre(i, uc) * eval_legendre(j, vc) for c, (i, j) in zip(sol, terms, strict=True))
    assert level == pytest.approx(expect_level, rel=1e-9)
    for c, (i, j) in zip(sol, terms, strict=True):
        assert coef[i, j] * level == pytest.approx(c, rel=1e-7, abs=1e-12)
    assert coef[2, 2] == 0 and coef[1, 2] == 0 and scale == 1.0
    assert rms == pytest.approx(np.sqrt(np.mean((d / (design @ sol) - 1) ** 2)), rel=1e-9)
    assert level < 1  # a dim flat: levels below 1 DN are fitted too


def test_2d_flat_fit_guards_the_number_of_blocks_and_the_sign_at_the_centre():
    """Degree 2 has 6 terms and needs 2 × 6 = 12 usable blocks; a centre where the fitted series is negative
    is refused."""
    geom, xx, yy, u, v, surf = _legendre_flat(1.0)
    data = np.full(surf.shape, np.nan)
    data.flat[:12] = surf.flat[:12]
    fit_2d_plane(data, xx, yy, geom, "B", 2, (20.0, 12.0))
    data.flat[11] = np.nan
    with pytest.raises(CamcalError, match=r"too few usable blocks \(11\) for a degree-2 2-D model"):
        fit_2d_plane(data, xx, yy, geom, "B", 2, (20.0, 12.0))
    tilt = 1.0 + 0.9 * u  # positive on the frame, negative left of it (u < −1.11)
    with pytest.raises(CamcalError, match="not positive at the optical centre"):
        fit_2d_plane(tilt, xx, yy, geom, "B", 1, (-30.0, 12.0))


# ---- response: the sRGB-form fit's statistics ----------------------------------------------------------------

def _srgb_numeric(lin, p, a=0.055):
    """The sRGB form with exponent p from its definition (toe where the line through 0 touches the curve)."""
    lb = brentq(lambda v: (1 + a) * v**p - a - v * (1 + a) * p * v ** (p - 1), 1e-9, 0.5)
    lin = np.asarray(lin, float)
    return np.where(lin <= lb, (1 + a) * p * lb ** (p - 1) * lin, (1 + a) * np.maximum(lin, lb) ** p - a)


@pytest.mark.parametrize("bump_dn", [0.9, 0.05], ids=["chi2_above_1", "chi2_below_1"])
def test_srgb_form_fit_statistics_are_those_of_weighted_least_squares(bump_dn):
    """Data of p = 0.45, x_w = 30 ms with a fixed ±bump pattern, σ = 0.3 DN (one point 0.6 DN): at
    the returned (p, ln x_w) the weighted residuals r_k = (W V(x/x_w; p) − g)/σ are orthogonal to the Jacobian
    (the normal equations, differences written out here), χ²_red = Σ r²/(n − 2), the RMS in DN, and
    σ_p = √(inv(JᵀJ)₀₀ · max(1, χ²_red))."""
    x = np.geomspace(1e-4, 2.5e-2, 12)
    g = 255.0 * _srgb_numeric(x / 0.03, 0.45) + bump_dn * np.where(np.arange(12) % 2, 1.0, -1.0)
    sig = np.full(12, 0.3)
    sig[4] = 0.6
    s = sig
    fit = fit_srgb_form(x, g, sig, 255.0, p0=0.6, x_white0=0.02)
    p, lxw = fit["exponent"], np.log(fit["x_white_s"])

    def resid(pp, ll):
        return (255.0 * _srgb_numeric(x / np.exp(ll), pp) - g) / s

    r = resid(p, lxw)
    h = 1e-6
    jac = np.stack([(resid(p + h, lxw) - resid(p - h, lxw)) / (2 * h),
                    (resid(p, lxw + h) - resid(p, lxw - h)) / (2 * h)], axis=1)
    assert np.abs(jac.T @ r).max() < 1e-3 * np.abs(jac).sum(axis=0).max()
    chi2 = float(np.sum(r**2) / 10)
    assert fit["chi2_red"] == pytest.approx(chi2, rel=1e-4)
    assert (chi2 > 1) == (bump_dn > 0.5)
    assert fit["rms_dn"] == pytest.approx(float(np.sqrt(np.mean((r * s) ** 2))), rel=1e-4)
    cov = np.linalg.inv(jac.T @ jac) * max(1.0, chi2)
    assert fit["exponent_unc"] == pytest.approx(float(np.sqrt(cov[0, 0])), rel=1e-3)
    assert fit["form"] == "srgb" and fit["offset_a"] == 0.055 and fit["toe_slope"] > 1


def test_srgb_form_fit_bounds_the_exponent_and_needs_three_points_for_statistics():
    """The exponent stays in [0.05, 0.99] whatever the start (a linear response, p = 1, ends at the bound 0.99);
    with two points there is no degree of freedom: χ² and σ_p are NaN."""
    x = np.geomspace(1e-3, 2e-2, 8)
    g = 255.0 * np.minimum(x / 0.03, 1.0)
    fit = fit_srgb_form(x, g, np.full(8, 0.3), 255.0, p0=1.5, x_white0=0.03)
    assert fit["exponent"] == pytest.approx(0.99, abs=1e-9)
    assert 0.05 <= fit_srgb_form(x, g, np.full(8, 0.3), 255.0, p0=0.01, x_white0=0.03)["exponent"] <= 0.99
    two = fit_srgb_form(x[[2, 6]], 255.0 * _srgb_numeric(x[[2, 6]] / 0.03, 0.45), np.full(2, 0.3), 255.0,
                        p0=0.5, x_white0=0.03)
    assert np.isnan(two["chi2_red"]) and np.isnan(two["exponent_unc"])
    three = fit_srgb_form(x[[1, 4, 7]], 255.0 * _srgb_numeric(x[[1, 4, 7]] / 0.03, 0.45) + [0.3, -0.3, 0.3],
                          np.full(3, 0.3), 255.0, p0=0.5, x_white0=0.03)
    assert np.isfinite(three["chi2_red"]) and np.isfinite(three["exponent_unc"])


# ---- water/field: the geometry's two forms at a non-default index, reflectance and view -----------------------

def _schlick_from_air(theta_air, n):
    """Schlick (1994) at the air-side angle: R = R0 + (1 − R0)(1 − cos θ)⁵, R0 = ((n − 1)/(n + 1))²."""
    r0 = ((n - 1) / (n + 1)) ** 2
    return r0 + (1 - r0) * (1 - np.cos(theta_air)) ** 5


@pytest.mark.parametrize("transmittance", ["mean", "exact"])
def test_field_geometry_forms_carry_every_setting(transmittance):
    """n = 1.34, Schlick, albedo 0.7, view 0.35 rad, sun at 50°: the direct beam is
    ρ (1 − R(θs)) (1 − R(θv)) / n² exp(−τ (1/cos β + 1/cos θv,w)) with sin θs = n sin β (Schlick from the air
    side for both crossings, by reciprocity), and the sky part is the refined model with the same settings
    (its exact form on 32 nodes instead of 128: within 2e-5)."""
    n, th_s, view = 1.34, np.radians(50.0), 0.35
    g = FieldGeometry(sun_zenith_rad=th_s, albedo=0.7, n_water=n, view_angle_rad=view, reflectance="schlick",
                      transmittance=transmittance)
    beta, view_w = np.arcsin(np.sin(th_s) / n), np.arcsin(np.sin(view) / n)
    assert g.refracted_sun_rad() == pytest.approx(beta, rel=1e-12)
    tau = np.array([0.0, 0.3, 1.2])
    k = 0.7 * (1 - _schlick_from_air(th_s, n)) * (1 - _schlick_from_air(view, n)) / n**2
    np.testing.assert_allclose(g.direct_form().ratio(tau),
                               k * np.exp(-tau * (1 / np.cos(beta) + 1 / np.cos(view_w))), rtol=1e-9)
    sky = RefinedModel(albedo=0.7, n_water=n, view_angle_rad=view, reflectance="schlick",
                       transmittance=transmittance).closed_form()
    np.testing.assert_allclose(g.sky_form().ratio(tau), sky.ratio(tau), rtol=2e-5)
    if transmittance == "exact":
        assert g.sky_form().nodes == 32


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


def test_lamp_height_and_angle_terms_from_models_built_at_the_changed_geometry():
    """The lamp's height (m) and angle (degrees) enter through models built with that height or angle (radians):
    σ_C = |∂B/∂p| σ_p / |∂B/∂C|, ∂B/∂p from lamp models built here at p ± σ/2, ∂B/∂C from the closed form."""
    model = LampModel(1.0, np.radians(20.0), water_absorption_per_m=0.0)
    depth, c = 0.3, np.array([60.0, 250.0])
    mol = c / (CHLA_MOLAR_MASS_G_PER_MOL * 1e6)
    inputs = [Uncertain("lamp_height", 1.0, 0.02, "m"), Uncertain("lamp_angle", 20.0, 2.0, "deg")]
    terms = uncertainty_terms(model, depth, c, inputs)
    tau = np.log(10) * model.epsilon_L_per_mol_cm * mol * 100 * depth
    db_dc = model.closed_form_at(depth).ratio_derivative(tau) * tau / c
    hi, lo = LampModel(1.01, np.radians(20.0), water_absorption_per_m=0.0), LampModel(
        0.99, np.radians(20.0), water_absorption_per_m=0.0)
    db_dh = (hi.ratio(mol, depth) - lo.ratio(mol, depth)) / 0.02
    np.testing.assert_allclose(terms["lamp_height"], np.abs(db_dh / db_dc) * 0.02, rtol=1e-3)
    hi, lo = (LampModel(1.0, np.radians(a), water_absorption_per_m=0.0) for a in (21.0, 19.0))
    db_da = (hi.ratio(mol, depth) - lo.ratio(mol, depth)) / 2.0
    np.testing.assert_allclose(terms["lamp_angle"], np.abs(db_da / db_dc) * 2.0, rtol=1e-3)
    assert np.all(terms["lamp_height"] > 0) and np.all(terms["lamp_angle"] > 0)


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


def test_deconvolution_needs_four_wavelengths_and_defaults_to_a_gaussian_slit():
    """Four samples are enough (three are refused); the default slit is the Gaussian: a curve convolved with a
    5 nm-FWHM Gaussian by the forward operator is deconvolved back with the default."""
    wl = np.arange(500.0, 561.0, 5.0)
    truth = _gauss(wl, 530.0, 12.0) + 0.1
    measured = slit_matrix(wl, 5.0, "gaussian") @ truth
    c, u = deconvolve_slit(wl, measured, np.full(wl.size, 1e-6), 5.0, regularisation=1e-12)
    np.testing.assert_allclose(c[2:-2], truth[2:-2], rtol=1e-3)
    c4, _ = deconvolve_slit(wl[:4], measured[:4], np.full(4, 1e-3), 5.0)
    assert np.all(np.isfinite(c4))
    with pytest.raises(CamcalError, match="at least 4 wavelengths"):
        deconvolve_slit(wl[:3], measured[:3], np.full(3, 1e-3), 5.0)


# ---- response: the straight line, the saturation point and the EMVA linearity error at their edges -------------

def test_straight_line_fit_at_its_edges():
    """Two points: the line through them, no degree of freedom (χ² and uncertainties NaN); three points: one
    degree of freedom, finite; a σ of 0 is held at 1e-9 (the line passes through that point); all x equal:
    singular normal equations, NaN uncertainties."""
    two = fit_line([1.0, 3.0], [10.0, 16.0], [1.0, 1.0])
    assert two["rate"] == pytest.approx(3.0) and two["offset"] == pytest.approx(7.0)
    assert np.isnan(two["chi2_red"]) and np.isnan(two["rate_unc"]) and np.isnan(two["offset_unc"])
    three = fit_line([1.0, 2.0, 3.0], [10.0, 13.5, 16.0], [0.5, 0.5, 0.5])
    # residuals of the unweighted line 3x + 7.1667: −0.1667, +0.3333, −0.1667 → χ² = 0.1667/0.25 = 2/3 (1 dof)
    assert three["chi2_red"] == pytest.approx(((1 / 6) ** 2 * 2 + (1 / 3) ** 2) / 0.25, rel=1e-9)
    assert np.isfinite(three["rate_unc"])
    pinned = fit_line([1.0, 2.0, 3.0], [10.0, 13.5, 16.0], [1.0, 0.0, 1.0])
    assert pinned["rate"] * 2 + pinned["offset"] == pytest.approx(13.5, abs=1e-6)
    flat = fit_line([2.0, 2.0, 2.0], [10.0, 11.0, 12.0], [1.0, 1.0, 1.0])
    assert np.isnan(flat["rate_unc"]) and np.isnan(flat["offset_unc"])


def test_saturation_point_with_no_frame_used():
    sat = saturation_point(np.array([1.0, 2.0]), [3000.0, 4000.0], [4095.0, 4095.0], [True, True], [False, False],
                           4095.0)
    assert (sat.level_dn, sat.exposure_s, sat.reached, sat.n_saturated) == (4095.0, 1.0, True, 2)
    assert all(np.isnan(v) for v in (*sat.fitted_range_dn, *sat.fitted_exposure_s))
    assert len(sat.fitted_range_dn) == 2 and len(sat.fitted_exposure_s) == 2


def test_emva_linearity_error_is_half_the_spread_of_the_relative_deviations():
    """EMVA 1288 (release 4.0, §8.4): the line μ = a x + b minimising Σ ((μ − a x − b)/μ)² over the points
    between 5 % and 95 % of saturation (here 1000 DN: the first and last points are out), δ = 100 (μ − fit)/fit,
    LE = (max δ − min δ)/2, percent."""
    x = np.array([1.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0])
    mu = np.array([20.0, 152.0, 301.0, 452.0, 597.0, 748.0, 990.0])
    sel = slice(1, 6)
    xs, ys = x[sel], mu[sel]
    a, b = np.linalg.lstsq(np.stack([xs / ys, 1 / ys], axis=1), np.ones(5), rcond=None)[0]
    dev = 100 * (ys - (a * xs + b)) / (a * xs + b)
    assert emva_linearity_error(x, mu, 1000.0) == pytest.approx((dev.max() - dev.min()) / 2, rel=1e-9)
    assert emva_linearity_error(x, 75.0 * x, 1000.0) == pytest.approx(0.0, abs=1e-9)


def test_dead_pixels_are_strictly_below_the_threshold_and_none_without_a_response_map():
    chans = ("R", "G1", "G2", "B")
    prnu = np.ones((4, 2, 3), np.float32)
    prnu[0, 0, 0], prnu[1, 1, 2], prnu[3, 0, 1] = 0.5, 0.49, 0.3
    fm = FlatModel(channels=chans, centre_px={c: (1.0, 1.0) for c in chans}, k={c: (0.0,) for c in chans},
                   model_2d=None, prnu=prnu, residual_rms={}, shape=(2, 3), cfa_pattern="RGGB")
    dead = dead_pixels(fm)
    assert dead.dtype == bool and dead.sum() == 2 and dead[1, 1, 2] and dead[3, 0, 1] and not dead[0, 0, 0]
    assert dead_pixels(fm, threshold=0.6).sum() == 3 and dead_pixels(fm, threshold=0.31).sum() == 1
    none = dead_pixels(replace(fm, prnu=None))
    assert none.shape == (4, 2, 3) and none.dtype == bool and not none.any()


# ---- flat: the radial fit on data the model cannot represent exactly, its masks and guards ---------------------

def _radial_fit_by_definition(d, fx, fy, full_w, full_h, n_terms, start):
    """The relative least-squares fit written out: for a centre (full-resolution px) the coefficients solve the
    normal equations of Σ((A·Σ k_i r²ⁱ − d)/d)²; the centre minimises that sum (Nelder–Mead, not the trust-region
    solver of the code). r² is normalised by the distance to the farthest image corner."""
    def solve(c):
        rmax = max(np.hypot(a - c[0], b - c[1]) for a in (0.0, full_w - 1.0) for b in (0.0, full_h - 1.0))
        r2 = ((fx - c[0]) ** 2 + (fy - c[1]) ** 2) / rmax**2
        a = np.stack([r2**i for i in range(n_terms + 1)], axis=-1) / d[:, None]
        coef = np.linalg.solve(a.T @ a, a.T @ np.ones_like(d))
        return coef, a @ coef - 1.0

    res = minimize(lambda c: float(np.sum(solve(c)[1] ** 2)), start, method="Nelder-Mead",
                   options={"xatol": 1e-9, "fatol": 1e-18, "maxiter": 4000})
    coef, rel = solve(res.x)
    return coef, res.x, 1.0 / (rel + 1.0) - 1.0  # d/model − 1, the RMS the fit reports


def test_radial_fit_of_a_tilted_gain_is_the_relative_least_squares_optimum():
    """A normalised flat (on-axis 0.9, below 1 everywhere, so a cut at 1 instead of 0 would drop every block),
    vignetting with an r⁶ term and a 10 % tilt the two-term radial model cannot follow, one NaN, one zero and one
    negative block. The fit must be the minimum of the relative residuals Σ(model/d − 1)² over centre and
    coefficients, computed here by the written-out normal equations and another optimiser: the level, the
    centre, k and the relative RMS."""
    h, w = 16, 20
    geom = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (h, w), "RGGB")
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    fx, fy = 2 * xx + 1, 2 * yy  # G1: column offset 1
    fcx, fcy = 2 * 8.3 + 1, 2 * 7.1
    r2 = ((fx - fcx) ** 2 + (fy - fcy) ** 2) / (2 * w) ** 2
    block = 0.9 * (1 - 0.45 * r2 + 0.1 * r2**2 - 0.3 * r2**3) * (1 + 0.1 * (xx - w / 2) / w)
    block[3, 4], block[10, 15], block[14, 7] = np.nan, 0.0, -0.2
    ok = np.isfinite(block) & (block > 0)
    coef, centre_full, rel = _radial_fit_by_definition(block[ok], fx[ok], fy[ok], 2 * w, 2 * h, 2, (fcx, fcy))
    level, centre, k, rms = fit_radial_plane(block, xx, yy, geom, "G1", n_terms=2)
    assert level == pytest.approx(coef[0], rel=1e-6)
    assert centre == pytest.approx(((centre_full[0] - 1) / 2, centre_full[1] / 2), abs=1e-4)
    np.testing.assert_allclose(k, (coef[1] / coef[0], coef[2] / coef[0], 0.0, 0.0, 0.0), rtol=0, atol=1e-5)
    assert rms == pytest.approx(float(np.sqrt(np.mean(rel**2))), rel=1e-5)
    assert 1e-3 < rms < 0.05  # the model does not fit exactly: a residual that tests the weighting


def test_radial_fit_needs_four_blocks_per_parameter():
    """n_terms = 2 fits 5 parameters (A, k0, k1, the centre's x and y): 20 usable blocks are enough, 19 are not
    (the error names the count)."""
    geom = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (4, 5), "RGGB")
    yy, xx = np.mgrid[0:4, 0:5].astype(float)
    block = 0.8 * (1 - 0.2 * ((xx - 2.1) ** 2 + (yy - 1.4) ** 2) / 30.0)
    level, _, _, rms = fit_radial_plane(block, xx, yy, geom, "G1", n_terms=2)
    assert 0.7 < level < 0.9 and rms < 1e-3
    block[0, 0] = np.nan
    with pytest.raises(CamcalError, match=r"channel G1: too few usable blocks \(19\)"):
        fit_radial_plane(block, xx, yy, geom, "G1", n_terms=2)


# ---- water/uncertainty: the tabulated terms where a power law would hide the path taken --------------------------

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


# ---- response: eq. 12 with one degree of freedom, small signals, three points ------------------------------------

def test_eq12_fit_with_one_degree_of_freedom_on_a_small_scale_and_through_three_points():
    """Four points of a linear sensor with ±3 alternating errors, all scaled by 1e-4 (α ≈ 0.4, uncertainties
    far below 1) and σ = 0.5e-4: χ²_red = Σ(r/σ)²/(4 − 3) from the fitted curve's residuals, and each
    uncertainty is that of the Jacobian J = (x^γ, α x^γ ln x, 1) written out here, inv(JᵀJ/σ²) × χ²_red.
    Three points: the fitted curve goes through them (α back from the fit's scaled variable)."""
    x = np.array([0.01, 0.12, 0.3, 0.5])
    g = (1000.0 + 4000.0 * x + 3.0 * np.array([1, -1, 1, -1])) * 1e-4
    sigma = np.full(4, 0.5e-4)
    fit = fit_eq12(x, g, sigma)
    a, gam, b = fit["alpha"], fit["gamma"], fit["beta"]
    resid = g - (a * x**gam + b)
    chi2_red = float(np.sum((resid / sigma) ** 2) / 1)
    assert chi2_red > 1.5 and fit["chi2_red"] == pytest.approx(chi2_red, rel=1e-6)
    jac = np.stack([x**gam, a * x**gam * np.log(x), np.ones_like(x)], axis=1) / sigma[:, None]
    cov = np.linalg.inv(jac.T @ jac) * chi2_red
    assert fit["alpha_unc"] < 0.1
    for key, i in (("alpha_unc", 0), ("gamma_unc", 1), ("beta_unc", 2)):
        assert fit[key] == pytest.approx(np.sqrt(cov[i, i]), rel=1e-3)
    three = fit_eq12(x[:3], g[:3], sigma[:3])
    np.testing.assert_allclose(three["alpha"] * x[:3] ** three["gamma"] + three["beta"], g[:3], rtol=1e-6)
    assert np.isnan(three["chi2_red"]) and np.isnan(three["gamma_unc"])


# ---- flat_model: the geometry of a sensor without a mosaic; the gains' storage type -----------------------------

def test_plane_geometry_without_a_mosaic_is_the_identity_and_rmax_the_farthest_corner():
    """A linear-RAW (no CFA) frame: plane pixels are image pixels (scale 1, no offset), and the normalising
    radius is the distance to the farthest of the four corners (0 or W − 1, 0 or H − 1), for a centre near
    each side."""
    geom = PlaneGeometry.for_planes(("R", "G", "B"), (30, 40), None)
    assert geom.full_shape == (30, 40)
    fx, fy = geom.to_full("G", np.array([0.0, 7.5]), np.array([3.0, 29.0]))
    np.testing.assert_array_equal(fx, [0.0, 7.5])
    np.testing.assert_array_equal(fy, [3.0, 29.0])
    for cx, cy in ((37.5, 2.0), (1.5, 27.0), (20.0, 14.5)):
        far = max(np.hypot(x - cx, y - cy) for x in (0.0, 39.0) for y in (0.0, 29.0))
        assert geom.rmax_full("B", cx, cy) == pytest.approx(far, rel=1e-15)
    bayer = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (30, 40), "RGGB")
    assert bayer.full_shape == (60, 80) and bayer.to_full("B", 2.0, 3.0) == (5.0, 7.0)


def test_flat_gains_are_float32_maps():
    """The gain maps are stored and applied as float32 (the correction divides float32 planes by them)."""
    chans = ("R", "G1", "G2", "B")
    prnu = np.full((4, 6, 8), 1.01, np.float32)
    fm = FlatModel(channels=chans, centre_px={c: (3.5, 2.5) for c in chans},
                   k={c: (-0.3, 0.05, 0.0, 0.0, 0.0) for c in chans}, model_2d=None, prnu=prnu, residual_rms={},
                   shape=(6, 8), cfa_pattern="RGGB")
    coef = [[1.0, 0.05, -0.1], [0.08, -0.03, 0.0], [-0.2, 0.0, 0.0]]
    m2 = {"kind": "legendre2d", "degree": 2, "coefficients": {c: coef for c in chans}, "scale": {c: 0.9 for c in chans}}
    for g in (fm.gain(), fm.gain(with_prnu=True), fm.radial_gain(), replace(fm, model_2d=m2).gain()):
        assert g.dtype == np.float32 and g.shape == (4, 6, 8)
    with pytest.raises(CamcalError, match="no PRNU map"):
        replace(fm, prnu=None).gain(with_prnu=True)


# ---- spectral_model: what a spectral sensitivity refuses ---------------------------------------------------------

@pytest.mark.parametrize("wl", [np.array([[500.0, 510.0]]), np.array([]), np.array([500.0, 510.0, 505.0]),
                                np.array([500.0, 510.0, 510.0])], ids=["2-D", "empty", "decreasing", "repeated"])
def test_spectral_sensitivity_refuses_wavelengths_that_do_not_increase(wl):
    vals = {p: np.ones(wl.shape) for p in "RGB"}
    with pytest.raises(CamcalError, match="wavelengths must be a non-empty increasing 1-D array"):
        SpectralSensitivity(wl, vals, vals, "relative", "relative")


def test_spectral_sensitivity_checks_its_planes_and_accepts_one_wavelength():
    one = SpectralSensitivity(np.array([550.0]), {p: np.ones(1) for p in "RGB"}, {p: np.ones(1) for p in "RGB"},
                              "relative", "relative")
    assert one.plane_names == ("R", "G", "B")
    wl = np.array([500.0, 510.0])
    with pytest.raises(CamcalError, match="of 2 values each"):
        SpectralSensitivity(wl, {p: np.ones(3) for p in "RGB"}, {p: np.ones(2) for p in "RGB"}, "relative",
                            "relative")
    with pytest.raises(CamcalError, match="of 2 values each"):
        SpectralSensitivity(wl, {p: np.ones(2) for p in "RG"}, {p: np.ones(2) for p in "RG"}, "relative",
                            "relative")
    with pytest.raises(CamcalError, match="name different planes"):
        SpectralSensitivity(wl, {p: np.ones(2) for p in "RGB"}, {p: np.ones(2) for p in ("R", "G1", "G2", "B")},
                            "relative", "relative")


def test_lamp_inputs_of_a_band_model_change_its_geometry():
    """A band model over a lamp geometry: varying 'lamp_height' (m) or 'lamp_angle' (degrees) gives the ratio of
    the band model built here with a lamp at that height or angle (radians), and differs from the nominal one."""
    wl = np.arange(600.0, 701.0, 10.0)
    s = np.exp(-0.5 * ((wl - 650.0) / 20.0) ** 2)

    def band(height_m, angle_deg):
        return BandModel(wl, s, geometry=LampModel(height_m, np.radians(angle_deg), water_absorption_per_m=0.0),
                         water_absorption_per_m=0.0)

    model, c, depth = band(1.0, 20.0), np.array([5.0, 50.0]), 0.3
    for name, p, built in (("lamp_height", 1.05, band(1.05, 20.0)), ("lamp_angle", 25.0, band(1.0, 25.0))):
        got = forward_for(model, depth, name)(p, c)
        np.testing.assert_allclose(got, built.ratio(c, depth), rtol=1e-12)
        assert np.all(np.abs(got / model.ratio(c, depth) - 1) > 1e-4)


# ---- correct: a third-party dark model that returns whole frames, through the one correction path -------------

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


def test_eq12_fit_keeps_alpha_and_gamma_within_their_bounds():
    """Eq. 12's parameters are bounded, α ≥ 0 and 0.02 ≤ γ ≤ 10: a signal that falls with exposure gives α at
    0 (below 1e-6 DN/s^γ) and γ at its lower bound; one that rises as x¹² gives γ at 10."""
    x = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    falling = fit_eq12(x, 100.0 - 5.0 * x, np.ones(6))
    assert 0.0 <= falling["alpha"] < 1e-6 and falling["gamma"] == pytest.approx(0.02, abs=1e-5)
    steep = fit_eq12(x, 500.0 * (x / 6.0) ** 12 + 5.0, np.ones(6))
    assert steep["gamma"] == pytest.approx(10.0, abs=1e-6)


# ---- spectral: the regularised deconvolution written out on an uneven grid ---------------------------------------

def _tikhonov_by_definition(wl, a, m, u, alpha_rel):
    """min ||W^½(Ac − m)||² + α||D₂c||², W = diag(1/u²), D₂ the second derivative per nm² of the parabola
    through each three neighbouring samples (from its Vandermonde system, not a difference formula), α =
    alpha_rel · tr(AᵀWA)/tr(D₂ᵀD₂); returns c, the estimator R and the GCV score n‖W^½(Ac − m)‖²/(n − tr AR)²
    (Hansen 2010, §5.4)."""
    n = wl.size
    d2 = np.zeros((n - 2, n))
    for i in range(n - 2):
        d2[i, i:i + 3] = 2.0 * np.linalg.solve(np.vander(wl[i:i + 3], 3), np.eye(3))[0]
    w = np.diag(1.0 / u**2)
    ata, dtd = a.T @ w @ a, d2.T @ d2
    alpha = alpha_rel * np.trace(ata) / np.trace(dtd)
    r = np.linalg.inv(ata + alpha * dtd) @ a.T @ w
    c = r @ m
    res = np.sqrt(np.diag(w)) * (a @ c - m)
    return c, r, n * float(res @ res) / (n - np.trace(a @ r)) ** 2


def test_deconvolution_on_an_uneven_grid_is_the_tikhonov_estimator_with_gcv():
    """On an uneven grid (4 nm steps jittered by up to ±1.2 nm) with unequal σ and Gaussian noise of that σ on a
    slit-blurred curve: with a given regularisation the result is the Tikhonov estimator written out here (second
    derivative per nm² from the parabola through each three samples); without one, the estimator whose α
    minimises the GCV score over the 49 values 10⁻¹⁰…10² (relative to the trace ratio); the uncertainty is
    √diag(R diag(u²) Rᵀ). The noise makes GCV choose an interior α (≈ 10^0.5) where a neighbouring grid value
    moves c by ~1e-3, so the grid itself is checked."""
    base = np.arange(400.0, 481.0, 4.0)
    wl = base + np.random.default_rng(5).uniform(-1.2, 1.2, base.size)
    a = slit_matrix(wl, 8.0)
    truth = np.exp(-0.5 * ((wl - 440.0) / 25.0) ** 2)
    u = 0.01 * (1.0 + 0.5 * np.cos(wl / 7.0))
    m = a @ truth + u * np.random.default_rng(1).standard_normal(wl.size)
    # the estimator is written out with explicit inverses here, np.linalg.solve in the code: they agree to ~1e-8
    c, uc = deconvolve_slit(wl, m, u, 8.0, regularisation=1e-3)
    want, r, _ = _tikhonov_by_definition(wl, a, m, u, 1e-3)
    np.testing.assert_allclose(c, want, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(uc, np.sqrt(np.diag(r @ np.diag(u**2) @ r.T)), rtol=1e-6)
    scores = [(_tikhonov_by_definition(wl, a, m, u, 10.0**lg)[2], lg) for lg in np.linspace(-10, 2, 49)]
    best = min(scores)[1]
    assert -10 < best < 2  # an interior minimum: the grid's ends are not what decides
    c, uc = deconvolve_slit(wl, m, u, 8.0)
    want, r, _ = _tikhonov_by_definition(wl, a, m, u, 10.0**best)
    np.testing.assert_allclose(c, want, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(uc, np.sqrt(np.diag(r @ np.diag(u**2) @ r.T)), rtol=1e-6)


def test_deconvolution_with_little_noise_lets_gcv_choose_a_weak_regularisation():
    """With noise of 1e-4 on a broad (σ = 25 nm) curve, GCV's minimum over 10⁻¹⁰…10² lies below 10⁻² (at
    10^-2.75): the search must reach down there, weaker than the trace ratio, not only up from it. The result is
    the estimator written out at that α, and closer to the truth than the one at 10⁻²."""
    base = np.arange(400.0, 481.0, 4.0)
    wl = base + np.random.default_rng(5).uniform(-1.2, 1.2, base.size)
    a = slit_matrix(wl, 8.0)
    truth = np.exp(-0.5 * ((wl - 440.0) / 25.0) ** 2)
    u = 1e-4 * (1.0 + 0.5 * np.cos(wl / 7.0))
    m = a @ truth + u * np.random.default_rng(1).standard_normal(wl.size)
    scores = [(_tikhonov_by_definition(wl, a, m, u, 10.0**lg)[2], lg) for lg in np.linspace(-10, 2, 49)]
    best = min(scores)[1]
    assert -10 < best < -2
    c, uc = deconvolve_slit(wl, m, u, 8.0)
    want, r, _ = _tikhonov_by_definition(wl, a, m, u, 10.0**best)
    np.testing.assert_allclose(c, want, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(uc, np.sqrt(np.diag(r @ np.diag(u**2) @ r.T)), rtol=1e-6)
    stiff = _tikhonov_by_definition(wl, a, m, u, 1e-2)[0]
    assert np.abs(c - truth).max() < np.abs(stiff - truth).max()


def test_slit_matrix_on_a_line_is_the_gaussian_mean_of_the_clamped_line():
    """c(λ) = a + bλ is its own natural cubic spline, held at the end values outside the sampled range, so the
    measured value at λ_j through a Gaussian slit (σ = FWHM/(2√(2 ln 2))) is a + b·E[clip(X, λ_0, λ_n)] with
    X ~ N(λ_j, σ): E[clip] = μ + E[(λ_0 − X)⁺] − E[(X − λ_n)⁺], E[(L − X)⁺] = (L − μ)Φ(z) + σφ(z), z = (L − μ)/σ
    (normal distribution from scipy.stats). A first step of 2.5 FWHM and a last one of 0.5 FWHM make the held
    ends matter over the whole slit."""
    wl = np.array([400.0, 425.0, 430.0, 436.0, 441.0, 447.0, 452.0, 457.0])
    fwhm = 10.0
    sigma = fwhm / (2 * np.sqrt(2 * np.log(2)))
    a, b = 0.3, 0.01
    got = slit_matrix(wl, fwhm) @ (a + b * wl)

    def below(limit, mu):  # E[(limit − X)⁺]
        z = (limit - mu) / sigma
        return (limit - mu) * norm.cdf(z) + sigma * norm.pdf(z)

    def above(limit, mu):  # E[(X − limit)⁺]
        z = (mu - limit) / sigma
        return (mu - limit) * norm.cdf(z) + sigma * norm.pdf(z)

    want = a + b * (wl + below(wl[0], wl) - above(wl[-1], wl))
    np.testing.assert_allclose(got, want, rtol=2e-6)  # quadrature on a 0.1 nm grid
    assert abs(got[0] - (a + b * wl[0])) > 0.01  # the held end is visible (b σ/√(2π) ≈ 0.017)


def test_field_model_with_the_mean_sky_transmittance_and_a_varied_sky_keeps_its_light():
    """With the hemispheric-mean transmittance (a sky form that is not the exact one), B(C) and dB/dC follow the
    rendering (the derivative by central differences of it); a model varied to 1.5× the diffuse irradiance has
    as illuminant the new global irradiance E_dir + 1.5 E_dif on its grid, normalised to a maximum of 1."""
    sky_wl = np.arange(500.0, 781.0, 20.0)
    glob = np.linspace(1.0, 2.0, sky_wl.size)
    diffuse = glob * np.linspace(0.6, 0.2, sky_wl.size)
    direct = glob - diffuse
    geom = FieldGeometry(transmittance="mean")
    model = field_band_model(FIELD_WL, FIELD_C, sky=MeasuredSky(45.0, sky_wl, direct, diffuse), geometry=geom)
    c, d = 12.0, 0.6
    r, dr = model.ratio_and_derivative(np.array([c]), d)
    assert float(r[0]) == pytest.approx(_field_truth(sky_wl, direct, diffuse, 45.0, geom, c, d), rel=1e-5)
    h = 1e-3 * c
    num = (_field_truth(sky_wl, direct, diffuse, 45.0, geom, c + h, d)
           - _field_truth(sky_wl, direct, diffuse, 45.0, geom, c - h, d)) / (2 * h)
    assert float(dr[0]) == pytest.approx(num, rel=1e-4)
    more = model.varied("diffuse_fraction", 1.5)
    light = np.interp(FIELD_WL, sky_wl, direct + 1.5 * diffuse)
    np.testing.assert_allclose(more.illuminant, light / light.max(), rtol=1e-12)


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


def test_relative_uncertainty_at_the_peak_for_peaks_below_one():
    """The summary's relative uncertainty at each plane's peak is u(λ_peak)/c(λ_peak), also for relative curves
    whose peaks are below 1 (0.125, 0.25, 0.375 here)."""
    wl = np.array([500.0, 510.0, 520.0, 530.0])
    vals = {p: np.array([0.1, 0.5, 0.3, 0.2]) * (i + 1) / 4 for i, p in enumerate("RGB")}
    unc = {p: np.array([0.01, 0.05, 0.02, 0.02]) for p in "RGB"}
    got = SpectralSensitivity(wl, vals, unc, "relative", "relative").summary()["max_relative_uncertainty_at_peak"]
    assert got == pytest.approx({"R": 0.05 / 0.125, "G": 0.05 / 0.25, "B": 0.05 / 0.375}, rel=1e-12)


def test_a_band_model_without_a_sensitivity_uncertainty_has_no_sensitivity_term():
    """u_c(λ) unknown (None): the terms are those of the stated inputs only."""
    wl = np.arange(600.0, 701.0, 10.0)
    model = BandModel(wl, np.exp(-0.5 * ((wl - 650.0) / 20.0) ** 2), water_absorption_per_m=0.0)
    terms = uncertainty_terms(model, 0.3, np.array([5.0, 50.0]), [Uncertain("depth", 0.3, 0.01, "m")])
    assert set(terms) == {"depth"} and np.all(terms["depth"] > 0)


def test_measured_sky_csv_limits_of_what_it_accepts(tmp_path):
    """Accepted: an indented '#' comment, wavelength steps of 0.5 nm, zero and sub-unit irradiances (a zero
    direct beam, one zero diffuse value). Refused: a repeated wavelength, a negative diffuse value, a file of
    comments only (no header)."""
    p = tmp_path / "sky.csv"
    p.write_text("wavelength_nm,direct_horizontal,diffuse_horizontal\n   # indented comment\n"
                 "500.0,0.0,0.0\n500.5,0.5,0.4\n501.0,0.9,0.8\n")
    sky = read_sky_csv(p, 20.0)
    np.testing.assert_array_equal(sky.wavelengths_nm, [500.0, 500.5, 501.0])
    np.testing.assert_array_equal(sky.direct_horizontal, [0.0, 0.5, 0.9])
    np.testing.assert_array_equal(sky.diffuse_horizontal, [0.0, 0.4, 0.8])
    head = "wavelength_nm,direct_horizontal,diffuse_horizontal\n"
    for phrase, text in (("must increase", head + "500,1,1\n500,2,1\n600,2,1\n"),
                         ("be >= 0", head + "500,1,-0.1\n600,2,1\n"),
                         ("needs columns", "# nothing but a comment\n")):
        p.write_text(text)
        with pytest.raises(CamcalError, match=phrase):
            read_sky_csv(p, 20.0)


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


def test_field_description_diffuse_fraction_on_an_uneven_grid_with_negative_sensitivity():
    """The in-band diffuse fraction weights each sample by its wavelength step and by the sensitivity clipped at
    0: on a grid whose step grows from 2 to 8 nm, with a measured sensitivity that dips below 0 (noise) in its
    tails, against the trapezoid rule over the clipped sensitivity (its interior weights are the central steps;
    the clipped sensitivity is 0 at the grid's ends, so the end weights do not matter)."""
    wl = np.cumsum(np.r_[520.0, np.linspace(2.0, 8.0, 50)])
    c = _gauss(wl, 600.0, 25.0) - 0.05
    sky_wl = np.arange(500.0, 801.0, 20.0)
    e_dif_sky = np.linspace(0.0, 1.5, sky_wl.size) ** 2
    sky = MeasuredSky(45.0, sky_wl, np.ones(sky_wl.size), e_dif_sky)
    e_dif = np.interp(wl, sky_wl, e_dif_sky)
    f = e_dif / (1.0 + e_dif)
    w = np.clip(c, 0.0, None) * (1.0 + e_dif)
    assert w[0] == 0.0 and w[-1] == 0.0 and np.ptp(np.diff(wl)) > 5.0
    expect = np.trapezoid(w * f, wl) / np.trapezoid(w, wl)
    got = field_band_model(wl, c, sky=sky).describe()["diffuse_fraction_in_band"]
    assert got == pytest.approx(expect, rel=1e-9)


def test_srgb_form_fit_exponent_stays_below_one_for_a_response_steeper_than_linear():
    """A response that follows the sRGB form with p = 1.2 above its knee (a curve bending up, which the form's
    documented range 0.05 ≤ p ≤ 0.99 excludes): the fit must stay in range (p ≤ 0.99 and a poor χ²), not follow
    the data to p = 1.2 (χ² ≈ 0), whatever its start."""
    from camcal.models.response import SRGB_OFFSET_A

    x = np.linspace(0.3, 1.0, 8) * 0.03
    g = 255.0 * ((1 + SRGB_OFFSET_A) * (x / 0.03) ** 1.2 - SRGB_OFFSET_A)
    for p0 in (0.5, 0.9):
        fit = fit_srgb_form(x, g, np.full(8, 0.3), 255.0, p0=p0, x_white0=0.03)
        assert 0.05 <= fit["exponent"] <= 0.99 and fit["chi2_red"] > 100.0


def test_slit_matrix_is_the_slit_mean_of_the_natural_spline_on_a_grid_with_a_long_last_step():
    """The last step (40 nm) longer than the slit's reach (3 FWHM = 15 nm), so the last slit lies wholly beyond
    the one before: on a line, the closed form a + b·E[clip(X, λ_0, λ_n)] (as above); on a parabola, which a
    natural spline does not reproduce near the ends (c'' = 0 there), the Gaussian mean of the clamped natural
    spline through the node values by adaptive quadrature (scipy.integrate.quad). Tolerance: the operator's
    0.1 nm trapezoid rule over a spline with kinks at the clamps (measured 4e-6 on values up to 1, at the end
    nodes); a not-a-knot spline differs by 1e-4 to 4e-3 at four of the six nodes."""
    from scipy.integrate import quad
    from scipy.interpolate import CubicSpline

    wl = np.array([400.0, 404.0, 409.0, 415.0, 420.0, 460.0])
    fwhm = 5.0
    sigma = fwhm / (2 * np.sqrt(2 * np.log(2)))
    a = slit_matrix(wl, fwhm)

    def clamped_mean(f, mu):
        lo, hi = wl[0], wl[-1]
        inside = quad(lambda x: f(x) * norm.pdf(x, mu, sigma), lo, hi, points=list(wl[(wl > mu - 8 * sigma)
                                                                                    & (wl < mu + 8 * sigma)]),
                      epsabs=1e-13, limit=200)[0]
        return inside + f(lo) * norm.cdf(lo, mu, sigma) + f(hi) * norm.sf(hi, mu, sigma)

    line = lambda x: 0.3 + 0.01 * x  # noqa: E731
    np.testing.assert_allclose(a @ line(wl), [clamped_mean(line, m) for m in wl], rtol=1e-6)
    values = ((wl - 400.0) / 60.0) ** 2
    spline = CubicSpline(wl, values, bc_type="natural")
    expect = [clamped_mean(lambda x: float(spline(x)), m) for m in wl]
    np.testing.assert_allclose(a @ values, expect, rtol=0, atol=2e-5)


def test_unit_strings_are_converted_with_the_molar_mass_and_si_prefixes():
    """The water module's unit strings against conversions written out: SI prefixes (µ = 1e-6, n = 1e-9, c = 1e-2,
    m = 1e-3), the molar mass of chlorophyll-a (893.5 g/mol, C55H72MgN4O5) and the bare-number defaults (mol/L,
    L/mol/cm, metres)."""
    m = 893.5  # g/mol, written out (IUPAC standard atomic weights: 55·12.011 + 72·1.008 + 24.305 + 4·14.007 + 5·15.999)
    assert parse_concentration_mol_per_L("2e-7") == pytest.approx(2e-7, rel=1e-15)
    assert parse_concentration_mol_per_L("2e-7mol/L") == pytest.approx(2e-7, rel=1e-15)
    assert parse_concentration_mol_per_L("3umol/L") == pytest.approx(3e-6, rel=1e-15)
    assert parse_concentration_mol_per_L("40 nmol/l") == pytest.approx(40e-9, rel=1e-15)
    assert parse_concentration_mol_per_L("0.17870g/L") == pytest.approx(0.1787 / m, rel=1e-15)
    assert parse_concentration_mol_per_L("89ug/L") == pytest.approx(89e-6 / m, rel=1e-15)
    assert parse_epsilon_L_per_mol_cm("78628") == pytest.approx(78628.0, rel=1e-15)
    assert parse_epsilon_L_per_mol_cm("78628L/mol/cm") == pytest.approx(78628.0, rel=1e-15)
    assert parse_epsilon_L_per_mol_cm("88L/g/cm") == pytest.approx(88.0 * m, rel=1e-15)
    assert parse_epsilon_L_per_mol_cm("0.088L/mg/cm") == pytest.approx(88.0 * m, rel=1e-12)
    assert parse_length_m("0.3") == pytest.approx(0.3, rel=1e-15)
    assert parse_length_m("20cm") == pytest.approx(0.2, rel=1e-15)
    assert parse_length_m("250mm") == pytest.approx(0.25, rel=1e-15)
    # a* (natural log, m² mg⁻¹) of a decadic ε in L g⁻¹ cm⁻¹: 1 L = 1e-3 m³, 1 g = 1e3 mg, 1 cm = 1e-2 m
    assert specific_absorption_m2_per_mg(88.0) == pytest.approx(np.log(10) * 88.0 * 1e-3 / (1e3 * 1e-2), rel=1e-12)


def test_frame_relative_exposure_off_the_reference_setting():
    """x = t·(ISO/ISO_ref)·(N_ref/N)² (seconds at the reference setting): 1/60 s at ISO 400 and f/5.6 for a
    reference of ISO 100 at f/4 is (1/60)·4·(4/5.6)² s."""
    e = Exposure(exposure_s=1 / 60, iso=400.0, f_number=5.6)
    assert frame_relative_exposure(e, 100.0, 4.0) == pytest.approx((1 / 60) * 4 * (4 / 5.6) ** 2, rel=1e-14)


# ---- readers and records: absorber and lamp CSVs, the band model of a profile, stored stages ------------------
# Each file is written here with known numbers and units; what is read back is compared with the numbers
# converted by hand. The stages' records are compared field by field after a round trip through JSON text.

_LN10_PER_CM_TO_PER_M = 100.0 * np.log(10.0)  # decadic per cm -> natural per m
_UG_PER_L_IN_G_PER_L = 1e-6  # 1 µg/L = 1 mg m⁻³ = 1e-6 g/L
CHLA_MOLAR_MASS_PUBLISHED = 893.509  # g/mol, chlorophyll-a C55H72MgN4O5 (PubChem)


def _csv(path, text):
    path.write_text(text)
    return path


def _a_star(eps_L_per_g_cm):
    """a* (m² mg⁻¹) of a decadic ε in L g⁻¹ cm⁻¹: ln 10 ε per cm per (g/L), times 100 cm/m and 1e-6 (g/L)/(µg/L)."""
    return np.asarray(eps_L_per_g_cm, float) * _LN10_PER_CM_TO_PER_M * _UG_PER_L_IN_G_PER_L


def test_absorber_csv_epsilon_columns_are_converted_to_natural_m2_per_mg(tmp_path):
    """ε per gram and per mole (with the published molar mass of chlorophyll-a) give A = 2.3026e-4 ε, E = 1, on
    the file's wavelengths; comments, blank lines and spaces around cells are ignored."""
    from camcal.water.band import read_chlorophyll_csv

    wl = [430.0, 550.0, 662.0]
    eps_g = [101.5, 7.25, 88.0]
    p = _csv(tmp_path / "g.csv", "# chlorophyll-a in acetone\n\n   # indented comment\n"
             " wavelength_nm , epsilon_L_per_g_cm \n"
             + "".join(f"{w}, {e}\n" for w, e in zip(wl, eps_g, strict=True)) + "# end\n")
    a = read_chlorophyll_csv(p)
    np.testing.assert_array_equal(a.wavelengths_nm, wl)
    np.testing.assert_allclose(a.coefficient_m2_per_mg, _a_star(eps_g), rtol=1e-12)  # rounding only
    np.testing.assert_array_equal(a.exponent, np.ones(3))
    assert a.source == f"{p} (ε per gram)"

    eps_mol = [90700.0, 6480.0, 78600.0]  # L mol⁻¹ cm⁻¹
    for line, name in (("# molar_mass_g_per_mol: 893.509 g/mol", "m1.csv"), ("# Molar mass g per mol = 893.509",
                                                                              "m2.csv")):
        p = _csv(tmp_path / name, f"{line}\nwavelength_nm,epsilon_L_per_mol_cm\n"
                 + "".join(f"{w},{e}\n" for w, e in zip(wl, eps_mol, strict=True)))
        b = read_chlorophyll_csv(p)
        np.testing.assert_array_equal(b.wavelengths_nm, wl)
        np.testing.assert_allclose(b.coefficient_m2_per_mg, _a_star(np.divide(eps_mol, CHLA_MOLAR_MASS_PUBLISHED)),
                                   rtol=1e-12)
        np.testing.assert_array_equal(b.exponent, np.ones(3))
        assert b.source == f"{p} (molar ε, M = 893.509 g/mol)"


@pytest.mark.parametrize(("conc", "length", "c_g_per_L", "l_cm", "molar"), [
    ("10 mg/L", "1 cm", 10e-3, 1.0, False),
    ("0.01 g/l", "10 mm", 0.01, 1.0, False),
    ("2500 ug/L", "0.02 m", 2.5e-3, 2.0, False),
    ("2500 µg/L", "2", 2.5e-3, 2.0, False),
    ("5e3 mg/m3", ".5 cm", 5e-3, 0.5, False),
    ("+5000 mg/m^3", "5 MM", 5e-3, 0.5, False),
    ("11.19 umol/L", "1 cm", 11.19e-6 * CHLA_MOLAR_MASS_PUBLISHED, 1.0, True),
    ("11.19 µmol/L", "1cm", 11.19e-6 * CHLA_MOLAR_MASS_PUBLISHED, 1.0, True),
    ("0.01119 mmol/L", "1 cm", 11.19e-6 * CHLA_MOLAR_MASS_PUBLISHED, 1.0, True),
    ("1.119E-5 mol/L", "1 cm", 11.19e-6 * CHLA_MOLAR_MASS_PUBLISHED, 1.0, True),
    ("1.119e-5 M", "1 cm", 11.19e-6 * CHLA_MOLAR_MASS_PUBLISHED, 1.0, True),
])
def test_absorber_csv_absorbance_is_divided_by_concentration_and_path_in_g_per_L_and_cm(tmp_path, conc, length,
                                                                                         c_g_per_L, l_cm, molar):
    """ε = A / (c l) with c converted by hand to g/L (molar ones with M = 893.509 g/mol) and l to cm; an absorbance
    a little below zero (a blank's noise, > -0.01) counts as zero."""
    from camcal.water.band import read_chlorophyll_csv

    wl = [440.0, 600.0, 665.0]
    absorbance = [0.95, -0.01, 0.82]  # -0.01: the lowest absorbance taken as a blank's noise
    meta = f"# concentration: {conc}\n# path_length: {length}\n"
    if molar:
        meta += "# molar_mass_g_per_mol: 893.509\n"
    p = _csv(tmp_path / "abs.csv", meta + "wavelength_nm,absorbance\n"
             + "".join(f"{w},{a}\n" for w, a in zip(wl, absorbance, strict=True)))
    a = read_chlorophyll_csv(p)
    eps = np.array([0.95, 0.0, 0.82]) / (c_g_per_L * l_cm)
    np.testing.assert_array_equal(a.wavelengths_nm, wl)
    np.testing.assert_allclose(a.coefficient_m2_per_mg, _a_star(eps), rtol=1e-12)  # unit factors: rounding only
    np.testing.assert_array_equal(a.exponent, np.ones(3))
    number, unit = conc.split()
    length_number = length.split()[0].rstrip("cmCM")
    length_unit = length[len(length_number):].strip().lower() or "cm"
    how = f"absorbance of {float(number):g} {unit.lower()} over {float(length_number):g} {length_unit}"
    assert a.source == f"{p} ({how})"


def test_absorber_csv_power_law_columns_are_read_as_they_are(tmp_path):
    """A_m2_per_mg and E are taken as written (E = 1 without an E column; E = 2 is allowed); the source is the path."""
    from camcal.water.band import read_chlorophyll_csv

    p = _csv(tmp_path / "pl.csv", "wavelength_nm,E,A_m2_per_mg\n440,0.65,0.0402\n675,2,0.0\n700,1e-3,0.0125\n")
    a = read_chlorophyll_csv(p)
    np.testing.assert_array_equal(a.wavelengths_nm, [440.0, 675.0, 700.0])
    np.testing.assert_array_equal(a.coefficient_m2_per_mg, [0.0402, 0.0, 0.0125])
    np.testing.assert_array_equal(a.exponent, [0.65, 2.0, 1e-3])
    assert a.source == str(p)
    b = read_chlorophyll_csv(_csv(tmp_path / "pl1.csv", "wavelength_nm,A_m2_per_mg\n1,0.03\n2,0.01\n"))
    np.testing.assert_array_equal(b.wavelengths_nm, [1.0, 2.0])
    np.testing.assert_array_equal(b.coefficient_m2_per_mg, [0.03, 0.01])
    np.testing.assert_array_equal(b.exponent, [1.0, 1.0])
    assert b.exponent.shape == b.coefficient_m2_per_mg.shape == (2,)


_ABSORBER_REFUSALS = [
    ("# only a comment\n\n", "chlorophyll CSV is empty (no header row)"),
    ("wavelength_nm,A_m2_per_mg,A_m2_per_mg\n400,1,1\n500,1,1\n",
     "columns in its header ['wavelength_nm', 'A_m2_per_mg', 'A_m2_per_mg']"),
    ("lambda,A_m2_per_mg\n400,1\n500,1\n", "needs a wavelength_nm column (header is lambda,A_m2_per_mg)"),
    ("wavelength_nm,A_m2_per_mg\n400,1\n500\n", "row 3: 1 cells, the header has 2"),
    ("wavelength_nm,A_m2_per_mg\n400,1\n500,x\n", "row 3: not a number in '500,x'"),
    ("wavelength_nm,A_m2_per_mg\n400,1\n500," + "x" * 70 + "\n", "not a number in '500," + "x" * 56 + "'"),
    ("# c\nwavelength_nm,A_m2_per_mg\n400,1\n", "needs at least two rows"),
    ("wavelength_nm,A_m2_per_mg\n", "needs at least two rows"),
    ("wavelength_nm,A_m2_per_mg\n400,1\n500,nan\n", "has non-finite values"),
    ("wavelength_nm,A_m2_per_mg\n400,1\n500,1e400\n", "has non-finite values"),
    ("wavelength_nm,A_m2_per_mg\n500,1\n500,1\n", "wavelengths must be positive and increasing"),
    ("wavelength_nm,A_m2_per_mg\n500,1\n400,1\n", "wavelengths must be positive and increasing"),
    ("wavelength_nm,A_m2_per_mg\n0,1\n400,1\n", "wavelengths must be positive and increasing"),
    ("wavelength_nm,A_m2_per_mg\n400,1\n500,-0.001\n", "A_m2_per_mg must not be negative"),
    ("wavelength_nm,A_m2_per_mg,E\n400,1,1\n500,1,0\n", "exponent E must be in (0, 2]"),
    ("wavelength_nm,A_m2_per_mg,E\n400,1,1\n500,1,2.001\n", "exponent E must be in (0, 2]"),
    ("wavelength_nm,epsilon_L_per_g_cm\n400,1\n500,-1e-9\n", "epsilon_L_per_g_cm must not be negative"),
    ("# molar_mass_g_per_mol: 893.5\nwavelength_nm,epsilon_L_per_mol_cm\n400,-1\n500,1\n",
     "epsilon_L_per_mol_cm must not be negative"),
    ("wavelength_nm,epsilon_L_per_mol_cm\n400,1\n500,1\n",
     "needs a '# molar_mass_g_per_mol: 792.85' line"),
    ("# molar_mass_g_per_mol: 0.8935 kg/mol\nwavelength_nm,epsilon_L_per_mol_cm\n400,1\n500,1\n",
     "molar mass unit 'kg/mol'; give g/mol"),
    ("# molar_mass_g_per_mol: 0\nwavelength_nm,epsilon_L_per_mol_cm\n400,1\n500,1\n",
     "'# molar_mass_g_per_mol: 0' is not a positive number with a unit (e.g. 792.85)"),
    ("# molar_mass_g_per_mol: -893\nwavelength_nm,epsilon_L_per_mol_cm\n400,1\n500,1\n",
     "is not a positive number with a unit"),
    ("# molar_mass_g_per_mol: 1e999 g/mol\nwavelength_nm,epsilon_L_per_mol_cm\n400,1\n500,1\n",
     "is not a positive number with a unit"),
    ("# molar_mass_g_per_mol: heavy\nwavelength_nm,epsilon_L_per_mol_cm\n400,1\n500,1\n",
     "is not a positive number with a unit"),
    ("# path_length: 1 cm\nwavelength_nm,absorbance\n400,1\n500,1\n", "needs a '# concentration: 10 mg/L' line"),
    ("# concentration: 10 mg/L\nwavelength_nm,absorbance\n400,1\n500,1\n", "needs a '# path_length: 1 cm' line"),
    ("# concentration: 10 ppm\n# path_length: 1 cm\nwavelength_nm,absorbance\n400,1\n500,1\n",
     "concentration unit 'ppm'; use g/L"),
    ("# concentration: 1 umol/L\n# path_length: 1 cm\nwavelength_nm,absorbance\n400,1\n500,1\n",
     "needs a '# molar_mass_g_per_mol: 792.85' line"),
    ("# concentration: 10 mg/L\n# path_length: 1 in\nwavelength_nm,absorbance\n400,1\n500,1\n",
     "path length unit 'in'; use cm, mm or m"),
    ("# concentration: 10 mg/L\n# path_length: 1 cm\nwavelength_nm,absorbance\n400,1\n500,-0.0101\n",
     "absorbance below -0.01"),
    ("wavelength_nm,transmittance\n400,1\n500,1\n", "needs an epsilon_L_per_g_cm, epsilon_L_per_mol_cm, absorbance"),
]


@pytest.mark.parametrize(("text", "says"), _ABSORBER_REFUSALS)
def test_absorber_csv_refusals_name_the_file_in_one_line(tmp_path, text, says):
    """Each malformed file, missing column or metadata line and wrong unit is refused with one line that starts
    with the file's path and says what is wrong."""
    from camcal.water.band import read_chlorophyll_csv

    p = _csv(tmp_path / "bad.csv", text)
    with pytest.raises(CamcalError) as e:
        read_chlorophyll_csv(p)
    assert str(e.value).startswith(f"{p}: ") and "\n" not in str(e.value)
    assert says in str(e.value)


def test_absorber_csv_metadata_numbers_take_signs_exponents_and_units_in_any_case(tmp_path):
    """``# key: value`` numbers: a sign, a leading or trailing point, an exponent, a unit glued to the number or
    after spaces, in any case; the value read is the number written (checked through M in A = a*(ε/M))."""
    from camcal.water.band import read_chlorophyll_csv

    for text, m in (("+893.5 G/MOL", 893.5), ("8.935e2g/mol", 893.5), ("893.", 893.0), (".8935E+3  g/mol", 893.5),
                    ("  900  ", 900.0), ("1E3", 1000.0)):
        p = _csv(tmp_path / "m.csv", f"#molar_mass_g_per_mol:{text}\nwavelength_nm,epsilon_L_per_mol_cm\n400,1e5\n"
                 "500,2e5\n")
        a = read_chlorophyll_csv(p)
        np.testing.assert_allclose(a.coefficient_m2_per_mg, _a_star([1e5 / m, 2e5 / m]), rtol=1e-12, err_msg=text)


def test_spectrum_csv_is_read_as_written(tmp_path):
    """The two columns of a lamp spectrum, as written (comments, blank lines and spaces ignored)."""
    from camcal.water.band import read_spectrum_csv

    p = _csv(tmp_path / "lamp.csv", "# tungsten\n  # indented comment\n wavelength_nm , relative_radiance\n\n"
             "380, 0.0\n 500,0.5e0\n"
             "# gap\n720.5,1.25\n")
    wl, v = read_spectrum_csv(p)
    np.testing.assert_array_equal(wl, [380.0, 500.0, 720.5])
    np.testing.assert_array_equal(v, [0.0, 0.5, 1.25])
    wl, v = read_spectrum_csv(_csv(tmp_path / "two.csv", "wavelength_nm,x\n0.5,1\n1,0\n"), "sky CSV")
    np.testing.assert_array_equal(wl, [0.5, 1.0])
    np.testing.assert_array_equal(v, [1.0, 0.0])


@pytest.mark.parametrize(("text", "says"), [
    ("wavelength_nm,v\n400,1\n", "needs a header row and at least two rows"),
    ("# a\nwavelength_nm,v\n\n400,1\n# b\n", "needs a header row and at least two rows"),
    ("wavelength_nm,v,w\n400,1,1\n500,1,1\n", "needs two columns, wavelength_nm and a value (header is "
                                             "'wavelength_nm,v,w')"),
    ("lambda,v\n400,1\n500,1\n", "needs two columns, wavelength_nm and a value"),
    ("v,wavelength_nm\n400,1\n500,1\n", "needs two columns"),
    ("wavelength_nm,v\n400,1\n500,one\n", ": a row is not two numbers"),
    ("wavelength_nm,v\n400,1\n500,1,2\n", ": a row is not two numbers"),
    ("wavelength_nm,v\n400,1,2\n500,1,2\n", ": every row needs two numbers"),
    ("wavelength_nm,v\n400\n500\n", ": every row needs two numbers"),
    ("wavelength_nm,v\n400,1\n500,nan\n", ": values must be finite, >= 0 and not all zero"),
    ("wavelength_nm,v\n400,1\ninf,1\n", ": values must be finite"),
    ("wavelength_nm,v\n400,1\n500,-1e-12\n", ": values must be finite"),
    ("wavelength_nm,v\n400,0\n500,0\n", ": values must be finite"),
    ("wavelength_nm,v\n400,1\n400,1\n", ": wavelengths must be positive and increasing"),
    ("wavelength_nm,v\n-1,1\n400,1\n", ": wavelengths must be positive and increasing"),
    ("wavelength_nm,v\n0,1\n400,1\n", ": wavelengths must be positive and increasing"),
])
def test_spectrum_csv_refusals_name_the_file_and_what_it_is(tmp_path, text, says):
    """Each malformed lamp spectrum is refused with one line: the file's path, what it is, what is wrong."""
    from camcal.water.band import read_spectrum_csv

    p = _csv(tmp_path / "bad.csv", text)
    with pytest.raises(CamcalError) as e:
        read_spectrum_csv(p)
    assert str(e.value).startswith(f"{p}: lamp spectrum CSV") and says in str(e.value)
    with pytest.raises(CamcalError, match=r"^.*bad\.csv: sky CSV"):
        read_spectrum_csv(p, "sky CSV")


_BAND_WL = np.arange(400.0, 701.0, 10.0)


def _band_profile(zero_blue=False):
    """A profile holding only c(λ): R rises from exactly 1 % of its peak at 500 nm (0 below, and 0 at 490 nm) to
    its peak 0.5 at 600 nm; G1, G2 and B are Gaussians; each plane has its own uncertainty."""
    from camcal.models.profile import CalibrationProfile, CameraIdentity, Provenance

    wl = _BAND_WL
    values = {"R": np.interp(wl, [490.0, 500.0, 600.0, 700.0], [0.0, 0.005, 0.5, 0.15]),
              "G1": _gauss(wl, 540.0, 30.0, 0.9), "G2": _gauss(wl, 550.0, 30.0, 0.8),
              "B": np.zeros_like(wl) if zero_blue else _gauss(wl, 460.0, 25.0, 0.7)}
    unc = {p: 0.01 * (k + 1) + 0.03 * v for k, (p, v) in enumerate(values.items())}
    s = SpectralSensitivity(wl, values, unc, RELATIVE_UNITS, "relative")
    return CalibrationProfile(CameraIdentity("m", "x", None, "RGGB", 96, 64), 100.0, 4.0, spectral=s,
                              provenance=Provenance("test", "2026-01-01T00:00:00Z"))


def test_band_model_of_a_profile_takes_the_channel_its_uncertainty_and_the_options():
    """c(λ) of a plane or of G = (G1 + G2)/2, σ_c of that plane or σ_G = ½ √(σ_G1² + σ_G2²), the profile's grid,
    and the options (geometry, chlorophyll, an illuminant array, water and background absorption) passed on as
    given."""
    from camcal.water.band import band_model_from_profile
    from camcal.water.models import SeedModel

    prof = _band_profile()
    v, u = prof.spectral.values, prof.spectral.uncertainty
    seed = SeedModel()
    chl = ChlorophyllAbsorption(np.array([400.0, 700.0]), np.array([0.02, 0.01]), np.array([0.9, 1.0]), "mine")
    s = np.linspace(0.2, 1.0, _BAND_WL.size)
    for ch, c, sig in (("G", 0.5 * (v["G1"] + v["G2"]), 0.5 * np.sqrt(u["G1"] ** 2 + u["G2"] ** 2)),
                       ("G2", v["G2"], u["G2"]), ("R", v["R"], u["R"]), ("B", v["B"], u["B"])):
        bm = band_model_from_profile(prof, ch, geometry=seed, chlorophyll=chl, illuminant=s,
                                     water_absorption_per_m=0.3, background_absorption_per_m=0.05)
        np.testing.assert_array_equal(bm.wavelengths_nm, _BAND_WL)
        np.testing.assert_allclose(bm.sensitivity, c, rtol=1e-15, err_msg=ch)
        np.testing.assert_allclose(bm.sensitivity_sigma, sig, rtol=1e-15, err_msg=ch)
        assert bm.geometry is seed and bm.chlorophyll is chl and bm.illuminant is s
        assert bm.water_absorption_per_m == 0.3 and bm.background_absorption_per_m == 0.05
    bm = band_model_from_profile(prof, "G1", illuminant=None)
    np.testing.assert_array_equal(bm.sensitivity, v["G1"])
    np.testing.assert_array_equal(bm.sensitivity_sigma, u["G1"])
    assert isinstance(bm.geometry, RefinedModel) and bm.geometry == RefinedModel()
    assert bm.chlorophyll is None and bm.illuminant is None and bm.water_absorption_per_m is None
    assert bm.background_absorption_per_m == 0.0


def test_band_model_of_a_profile_by_default_is_the_red_plane_under_d65_daylight():
    """Defaults: channel R, the refined geometry, Bricaud chlorophyll (None), Pope & Fry water (None), no
    background, and D65 (CIE tables: 82.7549 at 400 nm, 117.812 at 460 nm (its largest on this grid), 100 at 560 nm,
    71.6091 at 700 nm) normalised to its largest value."""
    from camcal.water.band import band_model_from_profile

    prof = _band_profile()
    bm = band_model_from_profile(prof)
    np.testing.assert_array_equal(bm.sensitivity, prof.spectral.values["R"])
    np.testing.assert_array_equal(bm.sensitivity_sigma, prof.spectral.uncertainty["R"])
    assert isinstance(bm.geometry, RefinedModel) and bm.chlorophyll is None and bm.water_absorption_per_m is None
    assert bm.background_absorption_per_m == 0.0
    at = {w: bm.illuminant[int(np.argmin(abs(_BAND_WL - w)))] for w in (400.0, 460.0, 560.0, 700.0)}
    np.testing.assert_allclose([at[400.0], at[460.0], at[560.0], at[700.0]],
                               np.array([82.7549, 117.812, 100.0, 71.6091]) / 117.812, rtol=1e-9)


def test_band_model_of_a_profile_needs_a_lamp_spectrum_over_the_band_at_one_percent(tmp_path):
    """A measured lamp CSV shorter than the profile's grid is accepted when it covers every wavelength where
    |c(λ)| ≥ 1 % of its peak (R: 500-700 nm; exactly 1 % at 500 nm), with S = 0 outside it and S linear between
    its rows (normalised to its largest value); a CSV starting at 510 nm is refused, naming the CSV."""
    from camcal.water.band import band_model_from_profile

    prof = _band_profile()
    lamp = _csv(tmp_path / "lamp.csv", "wavelength_nm,relative_radiance\n500,1\n600,3\n700,4\n")
    expected = np.where(_BAND_WL < 500, 0.0, np.where(_BAND_WL <= 600, 1 + (_BAND_WL - 500) / 50,
                                                      3 + (_BAND_WL - 600) / 100)) / 4.0
    for given in (lamp, str(lamp)):
        bm = band_model_from_profile(prof, "R", illuminant=given)
        np.testing.assert_allclose(bm.illuminant, expected, rtol=1e-12, atol=0)  # interpolation: rounding only
    short = _csv(tmp_path / "short.csv", "wavelength_nm,relative_radiance\n510,1\n700,4\n")
    with pytest.raises(CamcalError) as e:
        band_model_from_profile(prof, "R", illuminant=short)
    assert str(e.value).startswith(f"{short}: the light's spectrum {str(short)!r} does not cover channel R's band "
                                   "(500-700 nm")
    # a light given as an array with no value (NaN) inside the band: refused, naming no file (a profile in memory)
    gappy = np.where(_BAND_WL == 550.0, np.nan, 1.0)
    with pytest.raises(CamcalError, match=r"^the light's spectrum .* does not cover channel R's band"):
        band_model_from_profile(prof, "R", illuminant=gappy)
    # a negative c(λ) (noise) of 2 % of the peak at 420 nm is in the band all the same
    neg = _band_profile()
    neg.spectral.values["R"][2] = -0.01
    with pytest.raises(CamcalError, match="channel R's band .420-700 nm"):
        band_model_from_profile(neg, "R", illuminant=lamp)
    # the B plane's band lies below 500 nm: the lamp CSV does not cover it
    with pytest.raises(CamcalError, match="channel B's band"):
        band_model_from_profile(prof, "B", illuminant=lamp)


def test_band_model_of_a_profile_needs_a_chlorophyll_spectrum_over_the_weighted_band(tmp_path):
    """A chlorophyll spectrum must span the band where |c| S ≥ 1 % of its peak (R, flat light: 500-700 nm; with a
    light dark below 550 nm: 550-700 nm; a channel of zero sensitivity: the whole grid); a refusal names the
    chlorophyll file when it came from one, else the profile (none for a profile in memory)."""
    from camcal.water.band import band_model_from_profile, read_chlorophyll_csv

    prof = _band_profile(zero_blue=True)

    def chl(lo, hi, name=None):
        mid = 0.5 * (lo + hi)
        text = f"wavelength_nm,A_m2_per_mg\n{lo},0.02\n{mid},0.03\n{hi},0.01\n"
        return read_chlorophyll_csv(_csv(tmp_path / name, text)) if name else ChlorophyllAbsorption(
            np.array([lo, mid, hi]), np.array([0.02, 0.03, 0.01]), np.array([1.0, 1.0, 1.0]), "table")

    exact = chl(500.0, 700.0)
    assert band_model_from_profile(prof, "R", chlorophyll=exact, illuminant=None).chlorophyll is exact
    for lo, hi in ((510.0, 700.0), (500.0, 690.0)):
        bad = chl(lo, hi, "chl.csv")
        with pytest.raises(CamcalError) as e:
            band_model_from_profile(prof, "R", chlorophyll=bad, illuminant=None)
        assert str(e.value) == (f"{tmp_path / 'chl.csv'}: the chlorophyll spectrum covers {lo:g}–{hi:g} nm; channel "
                                "R's band (c(λ)·illuminant ≥ 1 % of its peak) spans 500–700 nm")
    with pytest.raises(CamcalError, match=r"^the chlorophyll spectrum covers 510–700 nm; .* spans 500–700 nm$"):
        band_model_from_profile(prof, "R", chlorophyll=chl(510.0, 700.0), illuminant=None)
    dark_blue = np.where(_BAND_WL < 550, 0.0, 1.0)
    late = chl(550.0, 700.0)
    assert band_model_from_profile(prof, "R", chlorophyll=late, illuminant=dark_blue).chlorophyll is late
    with pytest.raises(CamcalError, match="spans 550–700 nm"):
        band_model_from_profile(prof, "R", chlorophyll=chl(560.0, 700.0), illuminant=dark_blue)
    with pytest.raises(CamcalError, match="spans 400–700 nm"):
        band_model_from_profile(prof, "B", chlorophyll=exact, illuminant=None)
    assert band_model_from_profile(prof, "B", chlorophyll=chl(400.0, 700.0), illuminant=None).chlorophyll is not None


def test_band_model_of_a_profile_file_and_its_refusals(tmp_path):
    """A profile given by its path gives the same model as the profile in memory; a profile without c(λ) or
    without the channel is refused in one line naming the file (no file for a profile in memory)."""
    from camcal.models.profile import save_profile
    from camcal.water.band import band_model_from_profile

    prof = _band_profile()
    path = tmp_path / "p.camcal"
    save_profile(prof, path)
    bm = band_model_from_profile(path, "G1", illuminant=None)
    np.testing.assert_array_equal(bm.wavelengths_nm, _BAND_WL)
    np.testing.assert_array_equal(bm.sensitivity, prof.spectral.values["G1"])
    np.testing.assert_array_equal(bm.sensitivity_sigma, prof.spectral.uncertainty["G1"])
    np.testing.assert_array_equal(band_model_from_profile(str(path), "B", illuminant=None).sensitivity,
                                  prof.spectral.values["B"])
    with pytest.raises(CamcalError) as e:
        band_model_from_profile(path, "IR")
    assert str(e.value) == f"{path}: profile has no channel 'IR'; use one of B, G, G1, G2, R"
    with pytest.raises(CamcalError) as e:
        band_model_from_profile(prof, "IR")
    assert str(e.value) == "profile has no channel 'IR'; use one of B, G, G1, G2, R"
    bare = replace(prof, spectral=None)
    save_profile(bare, tmp_path / "bare.camcal")
    with pytest.raises(CamcalError) as e:
        band_model_from_profile(tmp_path / "bare.camcal")
    assert str(e.value) == f"{tmp_path / 'bare.camcal'}: profile has no spectral sensitivity stage (calibrate with " \
                           "a sweep)"
    with pytest.raises(CamcalError, match="^profile has no spectral sensitivity stage"):
        band_model_from_profile(bare)


def _json_round_trip(obj):
    import json

    return json.loads(json.dumps(obj))


def test_spectral_record_round_trip_keeps_every_field():
    """spectral_to_dict -> JSON text -> spectral_from_dict gives back every field of a Bayer and of a linear-RAW
    curve set, as float arrays; fields left out of a record take their documented defaults."""
    from camcal.models.spectral import spectral_from_dict, spectral_to_dict

    wl = np.array([450.0, 500.5, 550.0, 600.0, 650.0])
    bayer = {"R": [0.1, 0.2, 0.4, 1.5, 0.9], "G1": [0.3, 1.2, 1.4, 0.5, 0.1], "G2": [0.31, 1.1, 1.3, 0.6, 0.2],
             "B": [1.0, 0.8, 0.2, 0.05, 0.01]}
    s = SpectralSensitivity(wl, {p: np.array(v) for p, v in bayer.items()},
                            {p: 0.01 + 0.02 * np.array(v) for p, v in bayer.items()}, "DN s⁻¹ per W", "absolute",
                            reference_iso=200.0, reference_f_number=5.6, bandwidth_nm=4.5, deconvolved=True,
                            n_frames={"450": 3, "500.5": 2}, notes=("skipped one frame", "hot lamp"),
                            source={"kind": "imported", "file": "c.csv", "sha256": "ab"})
    back = spectral_from_dict(_json_round_trip(spectral_to_dict(s)))
    np.testing.assert_array_equal(back.wavelength_nm, wl)
    assert back.wavelength_nm.dtype == np.float64
    assert list(back.values) == ["R", "G1", "G2", "B"] and list(back.uncertainty) == ["R", "G1", "G2", "B"]
    for p, v in bayer.items():
        np.testing.assert_array_equal(back.values[p], v)
        np.testing.assert_array_equal(back.uncertainty[p], 0.01 + 0.02 * np.array(v))
        assert back.values[p].dtype == np.float64 and back.uncertainty[p].dtype == np.float64
    assert (back.units, back.mode, back.reference_iso, back.reference_f_number, back.bandwidth_nm) == (
        "DN s⁻¹ per W", "absolute", 200.0, 5.6, 4.5)
    assert back.deconvolved is True and back.n_frames == {"450": 3, "500.5": 2}
    assert back.notes == ("skipped one frame", "hot lamp")
    assert back.source == {"kind": "imported", "file": "c.csv", "sha256": "ab"}

    rgb = {"R": [0.5, 1.0], "G": [1.0, 0.5], "B": [0.25, 0.0]}
    d = {"wavelength_nm": ["500", 600], "values": rgb, "uncertainty": {p: [0.0, 0.125] for p in rgb},
         "units": "relative", "mode": "whatever", "reference_iso": "400", "reference_f_number": None,
         "n_frames": None, "notes": None, "source": "not a dict", "deconvolved": 1}
    lin = spectral_from_dict(d)
    np.testing.assert_array_equal(lin.wavelength_nm, [500.0, 600.0])
    assert list(lin.values) == ["R", "G", "B"] and list(lin.uncertainty) == ["R", "G", "B"]
    for p, v in rgb.items():
        np.testing.assert_array_equal(lin.values[p], v)
        np.testing.assert_array_equal(lin.uncertainty[p], [0.0, 0.125])
    assert (lin.mode, lin.reference_iso, lin.reference_f_number, lin.bandwidth_nm) == ("relative", 400.0, None, None)
    assert lin.deconvolved is True and lin.n_frames == {} and lin.notes == () and lin.source is None
    assert "source" not in spectral_to_dict(lin)  # a measured sweep has no source: its record has no such key
    minimal = spectral_from_dict({k: d[k] for k in ("wavelength_nm", "values", "uncertainty", "units", "mode")})
    assert (minimal.reference_iso, minimal.reference_f_number, minimal.bandwidth_nm) == (None, None, None)
    assert minimal.deconvolved is False and minimal.n_frames == {} and minimal.notes == () and minimal.source is None
    assert spectral_from_dict({**d, "bandwidth_nm": "2.5", "notes": [1, "b"]}).bandwidth_nm == 2.5
    assert spectral_from_dict({**d, "notes": [1, "b"]}).notes == ("1", "b")


@pytest.mark.parametrize(("drop", "change", "says"), [
    ("units", {}, "(KeyError: 'units')"),
    ("mode", {}, "(KeyError: 'mode')"),
    ("wavelength_nm", {}, "(KeyError: 'wavelength_nm')"),
    ("uncertainty", {}, "(KeyError: 'uncertainty')"),
    (None, {"values": {"R": [1, 2], "G": [1, 2]}}, "(KeyError: 'B')"),
    (None, {"reference_iso": "ISO 100"}, "(ValueError: could not convert string to float: 'ISO 100')"),
    (None, {"bandwidth_nm": [1, 2]}, "(TypeError: "),
    (None, {"n_frames": 3}, "(TypeError: "),
])
def test_spectral_record_refusals_say_what_is_wrong(drop, change, says):
    """A record with a missing key or a value of the wrong type is one CamcalError naming the exception."""
    from camcal.models.spectral import spectral_from_dict

    d = {"wavelength_nm": [500, 600], "values": {p: [1, 2] for p in "RGB"},
         "uncertainty": {p: [0, 0] for p in "RGB"}, "units": "relative", "mode": "relative", **change}
    d.pop(drop, None)
    with pytest.raises(CamcalError) as e:
        spectral_from_dict(d)
    assert str(e.value).startswith("malformed spectral sensitivity (") and says in str(e.value)


def _dark_model(planes=("R", "G1", "G2", "B"), known=True):
    """A small dark model with distinct values in every pixel, one unknown β uncertainty (inf) and defects."""
    n = len(planes)
    shape = (n, 2, 3)
    ramp = np.arange(np.prod(shape), dtype=np.float32).reshape(shape)
    unc = 0.01 * ramp + 0.5
    unc[1, 0, 2] = np.inf
    defects = np.zeros(shape, np.uint8)
    defects[0, 1, 1], defects[n - 1, 0, 0], defects[1, 1, 2] = 1, 2 | 4, 4
    channels = {p: {"bias_median_dn": 512.0 + k, "hot_pixel_count": int(np.count_nonzero(defects[k] & 1)),
                    "dead_pixel_count": int(np.count_nonzero(defects[k] & 2)),
                    "noisy_pixel_count": int(np.count_nonzero(defects[k] & 4))} for k, p in enumerate(planes)}
    return DarkModel(bias_dn=512.0 + ramp, dark_current_dn_per_s=(0.25 * ramp - 1.0) if known else None,
                     dark_current_unc_dn_per_s=unc if known else None, read_noise_dn=1.5 + 0.125 * ramp,
                     defects=defects, iso=800.0, cfa_pattern="RGGB" if n == 4 else None, temperature_c=21.5,
                     channels=channels, exposure_times_s=(0.001, 1.0, 30.0), black_level_dn=(512.0,) * n,
                     white_level_dn=15000.0, provenance={"files": ["a.dng"], "options": {"sigma": 5}})


@pytest.mark.parametrize("planes", [("R", "G1", "G2", "B"), ("R", "G", "B")])
@pytest.mark.parametrize("known", [True, False])
def test_dark_record_round_trip_keeps_every_field(planes, known):
    """dark_to_parts -> JSON text for the record (maps as arrays) -> dark_from_parts gives back every map (float32,
    an unknown β uncertainty inf again, defects uint8) and every field; the record names the maps' units and
    counts the defects (hot 1, dead 1, noisy 2, here counted by hand)."""
    from camcal.models.dark import dark_from_parts, dark_to_parts

    m = _dark_model(planes, known)
    data, maps = dark_to_parts(m)
    names = ("bias", "dark_current", "dark_current_unc", "read_noise", "defects") if known else (
        "bias", "read_noise", "defects")
    assert sorted(maps) == sorted(f"{n}.{p}" for n in names for p in planes)
    if known:
        assert maps["dark_current_unc.G1" if len(planes) == 4 else "dark_current_unc.G"][0, 2] == np.float32(3e38)
        np.testing.assert_array_equal(maps[f"dark_current.{planes[2]}"], 0.25 * np.arange(12, 18).reshape(2, 3) - 1)
    np.testing.assert_array_equal(maps[f"bias.{planes[1]}"], 512.0 + np.arange(6, 12).reshape(2, 3))
    np.testing.assert_array_equal(maps[f"defects.{planes[0]}"], [[0, 0, 0], [0, 1, 0]])
    assert maps[f"defects.{planes[0]}"].dtype == np.float32
    assert data["iso"] == 800.0 and data["cfa_pattern"] == (None if len(planes) == 3 else "RGGB")
    assert data["layout"] == ("bayer" if len(planes) == 4 else "linear") and data["temperature_c"] == 21.5
    assert data["exposure_times_s"] == [0.001, 1.0, 30.0] and data["black_level_dn"] == [512.0] * len(planes)
    assert data["white_level_dn"] == 15000.0 and data["channels"] == m.channels
    assert data["dark_current_known"] is known and data["provenance"] == m.provenance
    assert data["units"] == {"bias": "DN", "dark_current": "DN s⁻¹ at iso", "dark_current_unc": "DN s⁻¹",
                             "read_noise": "DN", "defects": "bits: 1 hot, 2 dead, 4 noisy"}
    summ = data["summary"]
    assert (summ["hot_pixel_count"], summ["dead_pixel_count"], summ["noisy_pixel_count"]) == (1, 1, 2)
    assert summ["plane_shape"] == [2, 3] and summ["iso"] == 800.0

    back = dark_from_parts(_json_round_trip(data), {k: np.array(v) for k, v in maps.items()}, "d.json")
    for got, want in ((back.bias_dn, m.bias_dn), (back.read_noise_dn, m.read_noise_dn),
                      (back.dark_current_dn_per_s, m.dark_current_dn_per_s),
                      (back.dark_current_unc_dn_per_s, m.dark_current_unc_dn_per_s)):
        if want is None:
            assert got is None
            continue
        assert got.dtype == np.float32 and got.shape == (len(planes), 2, 3)
        np.testing.assert_array_equal(got, want)
    if known:
        assert back.dark_current_unc_dn_per_s[1, 0, 2] == np.inf
    assert back.defects.dtype == np.uint8
    np.testing.assert_array_equal(back.defects, m.defects)
    assert back.plane_names == planes
    assert (back.iso, back.cfa_pattern, back.temperature_c) == (m.iso, m.cfa_pattern, m.temperature_c)
    assert back.channels == m.channels and back.provenance == m.provenance
    assert back.exposure_times_s == (0.001, 1.0, 30.0) and back.black_level_dn == (512.0,) * len(planes)
    assert back.white_level_dn == 15000.0


def test_dark_record_optional_fields_and_defects_read_from_floats():
    """Missing optional fields take their defaults (no CFA, no temperature, no times or levels, white level NaN);
    numbers given as text are read as numbers; defect bits stored as floats are rounded to the nearest integer."""
    from camcal.models.dark import dark_from_parts

    maps = {f"{m}.{p}": np.full((1, 2), 2.0, np.float32) for m in ("bias", "read_noise") for p in "RGB"}
    maps.update({f"defects.{p}": np.array([[0.9999, 4.0001]], np.float32) for p in "RGB"})
    data = {"iso": "200", "layout": "linear", "dark_current_known": False, "cfa_pattern": None,
            "exposure_times_s": ["0.5", 2], "black_level_dn": [64, "64", 64.5], "temperature_c": "19"}
    m = dark_from_parts(data, maps)
    assert m.iso == 200.0 and m.cfa_pattern is None and m.temperature_c == 19.0
    assert m.exposure_times_s == (0.5, 2.0) and m.black_level_dn == (64.0, 64.0, 64.5)
    assert m.dark_current_dn_per_s is None and m.dark_current_unc_dn_per_s is None
    np.testing.assert_array_equal(m.defects, np.tile(np.array([[1, 4]], np.uint8), (3, 1, 1)))
    m = dark_from_parts({"iso": 100, "layout": "linear", "dark_current_known": False}, maps)
    assert m.cfa_pattern is None and m.temperature_c is None and m.channels == {} and m.provenance == {}
    assert m.exposure_times_s == () and m.black_level_dn == () and np.isnan(m.white_level_dn)
    assert m.bias_dn.dtype == np.float32 and m.bias_dn.shape == (3, 1, 2)
    m = dark_from_parts({"iso": 100, "layout": "linear", "dark_current_known": False, "white_level_dn": 0,
                         "cfa_pattern": "GRBG"}, maps)
    assert np.isnan(m.white_level_dn) and m.cfa_pattern == "GRBG"  # 0 is no white level


@pytest.mark.parametrize(("data", "drop", "says"), [
    ({"iso": 100}, "bias.G2", "dark model lacks maps bias.G2"),
    ({"iso": 100}, "dark_current.R", "dark model lacks maps dark_current.R"),
    ({"iso": 100, "dark_current_known": None}, "dark_current_unc.B", "dark model lacks maps dark_current_unc.B"),
    ({"iso": 100, "layout": "linear"}, None,
     "dark model lacks maps bias.G, dark_current.G, dark_current_unc.G, read_noise.G"),
    ({"cfa_pattern": "RGGB"}, None, "malformed dark model ('iso')"),
    ({"iso": "high"}, None, "malformed dark model (could not convert string to float: 'high')"),
    ({"iso": 100, "channels": 5}, None, "malformed dark model ("),
    (["iso", 100], None, "malformed dark model (list indices must be integers"),
])
def test_dark_record_refusals_name_the_file(data, drop, says):
    """A record lacking a map (the first four named) or with a malformed field: one line naming the file."""
    from camcal.models.dark import dark_from_parts

    maps = {f"{m}.{p}": np.ones((1, 2), np.float32) for m in ("bias", "dark_current", "dark_current_unc",
                                                               "read_noise", "defects") for p in PLANES4}
    maps.pop(drop, None)
    with pytest.raises(CamcalError) as e:
        dark_from_parts(data, maps, "cam/dark.json")
    assert str(e.value).startswith(f"cam/dark.json: {says}") and "\n" not in str(e.value)
    if "lacks maps" in says:  # the first four missing maps, no more
        assert str(e.value).split("lacks maps ")[1] == says.split("lacks maps ")[1]


PLANES4 = ("R", "G1", "G2", "B")


def _flat_models():
    """A radial Bayer model at f/5.6 with a PRNU map and a model of the same planes at f/11; a 2-D linear one."""
    from camcal.models.flat import Optics

    ch = ("R", "G1", "G2", "B")
    prnu = (1.0 + 0.001 * np.arange(4 * 3 * 5).reshape(4, 3, 5)).astype(np.float32)
    kw = {"channels": ch, "model_2d": None, "shape": (3, 5), "cfa_pattern": "RGGB"}
    f11 = FlatModel(centre_px={c: (2.0 + 0.1 * i, 1.0 - 0.05 * i) for i, c in enumerate(ch)},
                    k={c: (-0.2 - 0.01 * i, 0.01, 0.0, 0.0, 0.0) for i, c in enumerate(ch)}, prnu=None,
                    residual_rms={c: 0.002 for c in ch}, level_dn={c: 900.0 for c in ch}, info={"n_terms": 2},
                    optics=Optics(11.0, "folder flat/f11/", 35.0, "tag"), **kw)
    radial = FlatModel(centre_px={c: (2.25 - 0.125 * i, 1.5 + 0.25 * i) for i, c in enumerate(ch)},
                       k={c: (-0.4 + 0.02 * i, 0.05, -0.01, 0.002, 0.0) for i, c in enumerate(ch)}, prnu=prnu,
                       residual_rms={c: 0.001 * (i + 1) for i, c in enumerate(ch)},
                       level_dn={c: 1000.0 + i for i, c in enumerate(ch)},
                       prnu_rms={c: 0.004 + 0.001 * i for i, c in enumerate(ch)},
                       info={"n_terms": 2, "frames": ["a.dng", "b.dng"]}, optics=Optics(5.6, "tag", 35.0, "libraw"),
                       apertures=(f11,), **kw)
    coef = {c: [[1.0, 0.0, -0.1], [0.02 * i, 0.0, 0.0], [-0.08, 0.0, 0.0]] for i, c in enumerate("RGB")}
    two_d = FlatModel(channels=("R", "G", "B"), centre_px={c: (1.5, 1.0) for c in "RGB"},
                      k={c: (0.0,) * 5 for c in "RGB"},
                      model_2d={"kind": "legendre2d", "degree": 2, "coefficients": coef,
                                "scale": {c: 1.0 + 0.01 * i for i, c in enumerate("RGB")}},
                      prnu=None, residual_rms={c: 0.003 for c in "RGB"}, shape=(3, 4), cfa_pattern=None)
    return radial, f11, two_d


def _same_flat(a, b, prnu=True):
    assert (a.channels, a.shape, a.cfa_pattern, a.model_2d, a.optics) == (b.channels, b.shape, b.cfa_pattern,
                                                                        b.model_2d, b.optics)
    assert (a.centre_px, a.k, a.residual_rms, a.level_dn, a.prnu_rms, a.info) == (
        b.centre_px, b.k, b.residual_rms, b.level_dn, b.prnu_rms, b.info)
    if prnu:
        assert (a.prnu is None) == (b.prnu is None)
        if a.prnu is not None:
            assert a.prnu.dtype == np.float32
            np.testing.assert_array_equal(a.prnu, b.prnu)


def test_flat_record_round_trip_keeps_every_field_and_the_other_apertures():
    """flat_to_parts -> JSON text for the record -> flat_from_parts gives back every field of a radial model with
    a PRNU map and a model at another f-number (which shares the PRNU map), and of a 2-D Legendre model; the gain
    of the model read back is the DNG radial sum 1 + k0 r² + k1 r⁴ + ... written out here."""
    from camcal.models.flat import flat_from_parts, flat_to_parts

    radial, f11, two_d = _flat_models()
    data, maps = flat_to_parts(radial)
    back = flat_from_parts(_json_round_trip(data), {n: np.asarray(m, float) for n, m in maps.items()}, "f.json")
    _same_flat(back, radial)
    assert len(back.apertures) == 1
    _same_flat(back.apertures[0], f11, prnu=False)
    np.testing.assert_array_equal(back.apertures[0].prnu, radial.prnu)
    assert back.apertures[0].apertures == ()
    # the gain of the R plane (offset (0, 0), 2 mosaic px per plane px) from the radial sum written out
    cx, cy = radial.centre_px["R"]
    yy, xx = np.mgrid[0:3, 0:5].astype(float)
    fx, fy = 2 * cx, 2 * cy
    rmax = max(np.hypot(x - fx, y - fy) for x in (0.0, 9.0) for y in (0.0, 5.0))
    r2 = ((2 * xx - fx) ** 2 + (2 * yy - fy) ** 2) / rmax**2
    g = 1 + sum(kk * r2 ** (i + 1) for i, kk in enumerate(radial.k["R"]))
    np.testing.assert_allclose(back.gain()[0], g, rtol=1e-6)  # float32 map

    # a record whose other model says it has a PRNU map: that model takes this model's all the same
    data2 = _json_round_trip(data)
    data2["apertures"][0]["has_prnu"] = True
    np.testing.assert_array_equal(flat_from_parts(data2, dict(maps)).apertures[0].prnu, radial.prnu)

    data, maps = flat_to_parts(two_d)
    back = flat_from_parts(_json_round_trip(data), dict(maps))
    _same_flat(back, two_d)
    assert back.apertures == () and back.prnu is None
    u = 2.0 * np.arange(4) / 3.0 - 1.0
    v = 2.0 * np.arange(3) / 2.0 - 1.0
    p2 = lambda t: 1.5 * t * t - 0.5  # noqa: E731 - Legendre P2
    gb = 1.01 * (1.0 - 0.1 * p2(v)[:, None] + 0.02 * u[None, :] - 0.08 * p2(u)[None, :])
    np.testing.assert_allclose(back.gain()[1], gb, rtol=1e-6)  # float32 map

    # a 2-D model with a 2-D model at another f-number: the other model's own coefficients come back
    from camcal.models.flat import Optics

    coef = {c: [[1.0, 0.0, -0.2], [0.01, 0.0, 0.0], [-0.05, 0.0, 0.0]] for c in "RGB"}
    other = replace(two_d, model_2d={**two_d.model_2d, "coefficients": coef}, optics=Optics(8.0, "tag", 35.0, "tag"))
    with_other = replace(two_d, optics=Optics(4.0, "tag", 35.0, "tag"), apertures=(other,))
    data, maps = flat_to_parts(with_other)
    back = flat_from_parts(_json_round_trip(data), dict(maps))
    assert back.apertures[0].model_2d == other.model_2d and back.apertures[0].optics == other.optics
    assert back.apertures[0].prnu is None


def test_flat_model_summary_names_its_kind_normalisation_full_frame_centres_and_corner_gains():
    """The summary a profile and a report show: the kind of model, the normalisation in words, each plane's
    optical centre in mosaic pixels (RGGB: plane pixel (x, y) of R is mosaic (2x, 2y), of G1 (2x + 1, 2y), of G2
    (2x, 2y + 1), of B (2x + 1, 2y + 1)) and the smallest gain at the plane's four corners, from the radial sum
    1 + Σ k_i r^(2i+2) written out at the corners of the R plane."""
    radial, _, two_d = _flat_models()
    s = radial.summary()
    assert s["model"] == "radial" and two_d.summary()["model"] == "2d"
    assert s["normalisation"] == "gain = 1 at the optical centre (radiance refers to on-axis sensitivity)"
    offsets = {"R": (0, 0), "G1": (1, 0), "G2": (0, 1), "B": (1, 1)}
    for c, (ox, oy) in offsets.items():
        cx, cy = radial.centre_px[c]
        assert s["centre_full_px"][c] == [pytest.approx(2 * cx + ox), pytest.approx(2 * cy + oy)]
    cx, cy = radial.centre_px["R"]
    fx, fy = 2 * cx, 2 * cy
    rmax = max(np.hypot(x - fx, y - fy) for x in (0.0, 9.0) for y in (0.0, 5.0))
    corners = [((2 * x - fx) ** 2 + (2 * y - fy) ** 2) / rmax**2 for x in (0.0, 4.0) for y in (0.0, 2.0)]
    g = [1 + sum(kk * r2 ** (i + 1) for i, kk in enumerate(radial.k["R"])) for r2 in corners]
    assert s["corner_gain"]["R"] == pytest.approx(min(g), rel=1e-6)  # float32 map values


def test_flat_record_optional_fields_take_their_defaults():
    """A record with only the required fields: no CFA, no levels, PRNU RMS, info or optics, radial."""
    from camcal.models.flat import Optics, flat_from_parts

    m = flat_from_parts({"channels": ["R", "G", "B"], "shape": ["2", 3.0], "centre_px": {c: ["1", 0.5] for c in "RGB"},
                         "k": {c: ["-0.1", 0] for c in "RGB"}, "residual_rms": {c: "0.01" for c in "RGB"},
                         "level_dn": None, "has_prnu": False}, {})
    assert m.channels == ("R", "G", "B") and m.shape == (2, 3) and m.cfa_pattern is None and m.model_2d is None
    assert m.centre_px == {c: (1.0, 0.5) for c in "RGB"} and m.k == {c: (-0.1, 0.0) for c in "RGB"}
    assert m.residual_rms == {c: 0.01 for c in "RGB"} and m.prnu is None and m.apertures == ()
    assert m.level_dn == {} and m.prnu_rms == {} and m.info == {} and m.optics == Optics()


def _legendre_2x2(a, b, big=0.5e308):
    """A 2-D model (linear planes R, G, B on 3 x 4) g = big (1 + a u)(1 + b v): it overflows to inf at the corner
    (u, v) = (a, b) only (2e308 there; 0 or big elsewhere on the corners)."""
    return {"kind": "legendre2d", "degree": 1, "coefficients": {c: [[big, b * big], [a * big, a * b * big]]
                                                               for c in "RGB"}, "scale": {c: 1.0 for c in "RGB"}}


def _flat_record(model_2d=None, k=(-0.3, 0.0), centre=(1.5, 1.0)):
    return {"channels": ["R", "G", "B"], "shape": [3, 4], "centre_px": {c: list(centre) for c in "RGB"},
            "k": {c: list(k) for c in "RGB"}, "residual_rms": {c: 0.01 for c in "RGB"}, "model_2d": model_2d}


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # the overflow the probe must see
@pytest.mark.parametrize(("a", "b"), [(-1, -1), (1, -1), (-1, 1), (1, 1)])
def test_flat_record_is_probed_at_each_of_the_four_plane_corners(a, b):
    """A model that is not finite at one plane corner is refused, whichever corner; a model finite at the four
    corners (g = 1.7e308 u, or v, which would overflow beyond them) is accepted."""
    from camcal.models.flat import flat_from_parts

    with pytest.raises(CamcalError) as e:
        flat_from_parts(_flat_record(_legendre_2x2(a, b)), {}, "f.json")
    assert str(e.value) == ("f.json: not a valid camcal flat file (ValueError: the vignetting model of R is not "
                            "finite at the corners)")
    edge = {"kind": "legendre2d", "degree": 1, "scale": {c: 1.0 for c in "RGB"},
            "coefficients": {c: [[0.0, 0.0], [1.7e308, 0.0]] if a > 0 else [[0.0, 1.7e308], [0.0, 0.0]]
                             for c in "RGB"}}
    assert flat_from_parts(_flat_record(edge), {}).kind == "2d"
    # radial: centre on the (a, b) corner's opposite, huge k: r² = 1 (overflow) only at the (a, b) corner
    centre = (0.0 if a > 0 else 3.0, 0.0 if b > 0 else 2.0)
    with pytest.raises(CamcalError, match="the vignetting model of R is not finite at the corners"):
        flat_from_parts(_flat_record(k=(1e308, 1e308), centre=centre), {})


@pytest.mark.parametrize(("change", "maps", "says"), [
    ({"has_prnu": True}, {f"prnu.{c}": np.ones((3, 3)) for c in "RGB"},
     "(ValueError: PRNU maps do not match the recorded shape)"),
    ({"has_prnu": True}, {f"prnu.{c}": np.ones((2, 4)) for c in "RGB"},
     "(ValueError: PRNU maps do not match the recorded shape)"),
    ({"has_prnu": True}, {"prnu.R": np.ones((3, 4))}, "(KeyError: 'prnu.G')"),
    ({"apertures": [{**_flat_record(), "shape": [3, 5]}]}, {},
     "(ValueError: a model of another f-number has other planes or another shape)"),
    ({"apertures": [{**_flat_record(), "shape": [4, 4]}]}, {},
     "(ValueError: a model of another f-number has other planes or another shape)"),
    ({"apertures": [{**_flat_record(), "channels": ["R", "G", "X"], "centre_px": {c: [1, 1] for c in "RGX"},
                     "k": {c: [0] for c in "RGX"}, "residual_rms": {c: 0 for c in "RGX"}}]}, {},
     "(ValueError: a model of another f-number has other planes or another shape)"),
    ({"channels": ["R", "G", "X"]}, {}, "(KeyError: 'X')"),
    ({"shape": [3]}, {}, "(IndexError: "),
    ({"k": {c: [float("nan")] for c in "RGB"}}, {}, "(ValueError: the vignetting model of R is not finite"),
    ({"model_2d": {"kind": "legendre2d", "coefficients": {c: [[1.0]] for c in "RGB"}}}, {}, "(KeyError: 'scale')"),
    ({"centre_px": None}, {}, "(TypeError: "),
])
def test_flat_record_refusals_name_the_file_and_the_fault(change, maps, says):
    """A record whose PRNU maps, other f-number models or fields do not fit: one line naming the file and the
    exception."""
    from camcal.models.flat import flat_from_parts

    with pytest.raises(CamcalError) as e:
        flat_from_parts({**_flat_record(), **change}, maps, "cam/flat.json")
    assert str(e.value).startswith(f"cam/flat.json: not a valid camcal flat file {says}")


def test_band_model_of_a_profile_reads_a_spectral_stage_of_rgb_curves_only():
    """A spectral stage that gives only R, G, B curves (``rgb()``, no planes and no uncertainty) gives the band
    model of those curves without σ_c; an object with no spectral stage at all is refused."""
    from types import SimpleNamespace

    from camcal.water.band import band_model_from_profile

    wl = np.array([500.0, 550.0, 600.0])
    rgb = {"R": np.array([0.1, 0.5, 1.0]), "G": np.array([0.5, 1.0, 0.4]), "B": np.array([0.2, 0.1, 0.0])}
    prof = SimpleNamespace(spectral=SimpleNamespace(wavelength_nm=wl, rgb=lambda: rgb))
    for ch in "RGB":
        bm = band_model_from_profile(prof, ch, illuminant=None)
        np.testing.assert_array_equal(bm.wavelengths_nm, wl)
        np.testing.assert_array_equal(bm.sensitivity, rgb[ch])
        assert bm.sensitivity_sigma is None
    with pytest.raises(CamcalError, match="^profile has no channel 'G1'; use one of B, G, R$"):
        band_model_from_profile(prof, "G1")
    with pytest.raises(CamcalError, match="^profile has no spectral sensitivity stage"):
        band_model_from_profile(SimpleNamespace(dark=None))


def test_readers_name_what_they_were_asked_to_read_when_it_is_not_a_file(tmp_path):
    """A folder given for an absorber or lamp CSV: one line naming the folder and what was expected there."""
    from camcal.water.band import read_chlorophyll_csv, read_spectrum_csv

    with pytest.raises(CamcalError) as e:
        read_chlorophyll_csv(tmp_path)
    assert str(e.value) == f"{tmp_path}: absorber (chlorophyll/dye) CSV is not a regular file"
    with pytest.raises(CamcalError) as e:
        read_spectrum_csv(tmp_path)
    assert str(e.value) == f"{tmp_path}: lamp spectrum CSV is not a regular file"
    with pytest.raises(CamcalError) as e:
        read_spectrum_csv(tmp_path, "sky CSV")
    assert str(e.value) == f"{tmp_path}: sky CSV is not a regular file"


def test_flat_record_with_a_malformed_model_of_another_f_number_names_the_file():
    """A record whose model of another f-number lacks a field is refused naming the file, like the record itself."""
    from camcal.models.flat import flat_from_parts

    other = {k: v for k, v in _flat_record().items() if k != "k"}
    with pytest.raises(CamcalError) as e:
        flat_from_parts({**_flat_record(), "apertures": [other]}, {}, "cam/flat.json")
    assert str(e.value) == "cam/flat.json: not a valid camcal flat file (KeyError: 'k')"


def _vignetting(k, centre, shape):
    """The DNG radial gain 1 + k0 r² + k1 r⁴ of one plane without a mosaic, r normalised to the farthest corner."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    cx, cy = centre
    rmax2 = max((x - cx) ** 2 + (y - cy) ** 2 for x in (0.0, w - 1.0) for y in (0.0, h - 1.0))
    r2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / rmax2
    return 1.0 + k[0] * r2 + k[1] * r2**2


def _aperture_series():
    """Radial models (planes R, G on 3 x 4, no mosaic) at f/2.8, f/5.6 and f/11 (35 mm), their hand-computed gains
    and one shared PRNU map; the f/5.6 model is the primary one, holding the others (given out of order)."""
    from camcal.models.flat import Optics

    ks = {2.8: {"R": (-0.5, 0.1), "G": (-0.42, 0.07)}, 5.6: {"R": (-0.3, 0.05), "G": (-0.26, 0.03)},
          11.0: {"R": (-0.12, 0.02), "G": (-0.1, 0.01)}}
    centre = {"R": (1.0, 1.0), "G": (2.0, 0.5)}
    prnu = (1.0 + 0.01 * np.arange(24).reshape(2, 3, 4)).astype(np.float32)

    def model(n, **kw):
        return FlatModel(channels=("R", "G"), centre_px=centre, k={c: (*ks[n][c], 0.0, 0.0, 0.0) for c in "RG"},
                         model_2d=None, prnu=prnu, residual_rms={c: 0.001 for c in "RG"}, shape=(3, 4),
                         info={"n_terms": 2}, optics=Optics(n, "tag", 35.0, "tag"), **kw)

    m28, m11 = model(2.8), model(11.0)
    primary = model(5.6, apertures=(m11, m28))
    gains = {n: np.stack([_vignetting(ks[n][c], centre[c], (3, 4)) for c in "RG"]) for n in ks}
    return primary, m28, m11, gains, prnu


def _corners(g):
    return np.stack([g[:, 0, 0], g[:, 0, -1], g[:, -1, 0], g[:, -1, -1]], axis=1)


def test_flat_choice_interpolates_ln_gain_in_inverse_f_number_squared_between_the_nearest_models():
    """A photo at f/4 between flats at f/2.8 and f/5.6 (and f/11): weights of ln g from 1/N² written out, the gain
    exp(w ln g_2.8 + (1 - w) ln g_5.6) pixel by pixel (times the shared PRNU when asked), the corner uncertainty
    as the largest |ratio - 1| at the corners against interpolating in ln N instead, the warning, description and
    record; float32 maps, so rtol 1e-6."""
    from camcal.models.flat import choose_flat

    primary, m28, m11, gains, prnu = _aperture_series()
    assert primary.models() == (m28, primary, m11) and primary.f_numbers() == [2.8, 5.6, 11.0]
    c = choose_flat(primary, 4.0, 35.0)
    w = (1 / 16 - 1 / 5.6**2) / (1 / 2.8**2 - 1 / 5.6**2)
    assert c.how == "interpolated" and c.mismatch is True
    assert [m for m, _ in c.parts] == [m28, primary]
    assert [x for _, x in c.parts] == [pytest.approx(w, rel=1e-12), pytest.approx(1 - w, rel=1e-12)]
    assert c.photo_f_number == 4.0 and c.photo_focal_length_mm == 35.0
    g = np.exp(w * np.log(gains[2.8]) + (1 - w) * np.log(gains[5.6]))
    assert c.gain().dtype == np.float32 and c.gain(with_prnu=True).dtype == np.float32
    np.testing.assert_allclose(c.gain(), g, rtol=1e-6)
    np.testing.assert_allclose(c.gain(with_prnu=True), g * prnu, rtol=1e-6)
    wl = np.log(5.6 / 4.0) / np.log(5.6 / 2.8)
    la, lb = np.log(_corners(gains[2.8])), np.log(_corners(gains[5.6]))
    diff = np.max(np.abs(np.exp(w * la + (1 - w) * lb) / np.exp(wl * la + (1 - wl) * lb) - 1))
    assert c.corner_difference_rel == pytest.approx(diff, rel=1e-9)
    assert c.warning == ("f/4 photo between the flats' f/2.8, 35 mm and f/5.6, 35 mm: vignetting interpolated (ln g "
                         f"linear in 1/N²); corners uncertain by up to ±{100 * diff:.2g} % (the difference from "
                         "interpolating in ln N)")
    assert c.describe() == "f/2.8, 35 mm and f/5.6, 35 mm (ln g interpolated linearly in 1/N²)"
    assert c.key == ((2.8, round(w, 9)), (5.6, round(1 - w, 9)))
    assert c.record(primary) == {
        "photo_f_number": 4.0, "photo_focal_length_mm": 35.0, "flat_f_numbers": [2.8, 5.6, 11.0],
        "flat_focal_length_mm": [35.0, 35.0, 35.0], "vignetting_model": c.describe(), "how": "interpolated",
        "weights": [[2.8, c.parts[0][1]], [5.6, c.parts[1][1]]], "corner_difference_rel": c.corner_difference_rel,
        "warning": c.warning, "mismatch": True,
        "rule": "ln g linear in 1/N² between measured f-numbers of models of the same form; outside: the nearest "
                "(docs/flat.md)"}
    # between f/5.6 and f/11 the pair is (5.6, 11), not the outermost models
    c8 = choose_flat(primary, 8.0, None)
    w8 = (1 / 64 - 1 / 121) / (1 / 5.6**2 - 1 / 121)
    assert [m for m, _ in c8.parts] == [primary, m11] and c8.parts[0][1] == pytest.approx(w8, rel=1e-12)
    np.testing.assert_allclose(c8.gain(), np.exp(w8 * np.log(gains[5.6]) + (1 - w8) * np.log(gains[11.0])),
                               rtol=1e-6)
    # the warning at f/10, between f/5.6 and f/11 (its percentage rounded to two digits: 1.2 %)
    w10, wl10 = (1 / 100 - 1 / 121) / (1 / 5.6**2 - 1 / 121), np.log(11 / 10) / np.log(11 / 5.6)
    la, lb = np.log(_corners(gains[5.6])), np.log(_corners(gains[11.0]))
    d10 = np.max(np.abs(np.exp((w10 - wl10) * (la - lb)) - 1))
    assert choose_flat(primary, 10.0, None).warning == (
        "f/10 photo between the flats' f/5.6, 35 mm and f/11, 35 mm: vignetting interpolated (ln g linear in "
        f"1/N²); corners uncertain by up to ±{100 * d10:.2g} % (the difference from interpolating in ln N)")
    assert f"{100 * d10:.2g}" == "1.2"
    # without a PRNU map an interpolated gain with PRNU is refused
    bare = [replace(m, prnu=None) for m in (m28, primary)]
    c0 = replace(c, parts=((bare[0], w), (bare[1], 1 - w)))
    np.testing.assert_allclose(c0.gain(), g, rtol=1e-6)
    with pytest.raises(CamcalError) as e:
        c0.gain(with_prnu=True)
    assert str(e.value) == "this flat model has no PRNU map (fitted without it)"


def test_flat_choice_at_a_measured_f_number_and_outside_the_measured_range():
    """At a measured f-number (within 3 %: 2.83 is f/2.8) the model as it is, no warning; beyond the range the
    nearest model in 1/N², its corners' change extrapolated linearly in 1/N² from the next model written out."""
    from camcal.models.flat import choose_flat

    primary, m28, m11, gains, prnu = _aperture_series()
    for n, m in ((2.83, m28), (5.6, primary), (10.8, m11)):
        c = choose_flat(primary, n, 35.0)
        assert (c.how, c.parts, c.corner_difference_rel, c.mismatch, c.warning) == (
            "measured", ((m, 1.0),), None, False, None)
        np.testing.assert_allclose(c.gain(), gains[m.optics.f_number], rtol=1e-6)
        np.testing.assert_allclose(c.gain(with_prnu=True), gains[m.optics.f_number] * prnu, rtol=1e-6)
        assert c.describe() == f"{m.optics.label()} (measured at the photo's f-number)"
    for n, near, other in ((16.0, 11.0, 5.6), (2.0, 2.8, 5.6)):
        c = choose_flat(primary, n, 35.0)
        assert c.how == "nearest" and c.mismatch is True and c.parts[0][0].optics.f_number == near
        assert c.parts[0][1] == 1.0 and c.describe() == f"f/{near:g}, 35 mm (the nearest measured f-number)"
        ln, lo = np.log(_corners(gains[near])), np.log(_corners(gains[other]))
        ext = ln + (ln - lo) / (1 / near**2 - 1 / other**2) * (1 / n**2 - 1 / near**2)
        diff = np.max(np.abs(np.exp(ext - ln) - 1))
        assert c.corner_difference_rel == pytest.approx(diff, rel=1e-9)
        assert c.warning == (f"f/{n:g} photo, outside the flats' f/2.8, 35 mm – f/11, 35 mm: the f/{near:g}, 35 mm "
                             f"vignetting model is used; the corners may differ by about {100 * diff:.2g} %, "
                             f"extrapolating the change from f/{other:g}, 35 mm to f/{near:g}, 35 mm")


def test_flat_choice_with_one_model_of_its_form_bounds_stopping_down_only():
    """Flats of one f-number: stopping down over-corrects the corners by at most 1/g_corner - 1; opening up has
    no bound. A pair of models of different forms is not interpolated: the nearest in 1/N² is used alone."""
    from camcal.models.flat import Optics, choose_flat

    primary, m28, m11, gains, _ = _aperture_series()
    only = replace(primary, apertures=())
    g_corner = float(np.min(_corners(gains[5.6])))
    c = choose_flat(only, 8.0, 35.0)
    assert (c.how, c.parts, c.mismatch) == ("nearest", ((only, 1.0),), True)
    assert c.corner_difference_rel == pytest.approx(1 / g_corner - 1, rel=1e-9)
    assert c.warning == (f"f/8 photo, flats at f/5.6, 35 mm only: the f/5.6, 35 mm vignetting model is used; the "
                         f"corners may differ by up to +{100 * (1 / g_corner - 1):.3g} % (stopping down reduces the "
                         f"flats' corner falloff of {100 * (1 - g_corner):.2g} %, so the corners are over-corrected "
                         "by at most 1/g - 1)")
    c = choose_flat(only, 4.0, 35.0)
    assert (c.how, c.parts, c.corner_difference_rel, c.mismatch) == ("nearest", ((only, 1.0),), None, True)
    assert c.warning == (f"f/4 photo, flats at f/5.6, 35 mm only: the f/5.6, 35 mm vignetting model is used; the "
                         f"corners may differ by an amount one flat cannot bound (a wider aperture vignettes more "
                         f"than the flats' {100 * (1 - g_corner):.2g} % corner falloff: the corners are "
                         "under-corrected, by tens of percent between f/2.8 and f/8 on real lenses)")
    # a model whose smallest corner gain is 1 - 0.3 + 0.056 = 0.756 (r² = 1 at the farthest corner): its
    # falloff, 24.4 %, in each message that gives it
    odd = replace(only, k={c: (-0.3, 0.056, 0.0, 0.0, 0.0) for c in "RG"})
    assert choose_flat(odd, 8.0, 35.0).warning.endswith(
        f"up to +{100 / 0.756 - 100:.3g} % (stopping down reduces the flats' corner falloff of 24 %, so the corners "
        "are over-corrected by at most 1/g - 1)")
    assert "more than the flats' 24 % corner falloff:" in choose_flat(odd, 4.0, 35.0).warning
    c = choose_flat(replace(odd, optics=Optics(5.6, "tag", 100.0, "tag")), 5.6, 99.0)
    assert c.corner_difference_rel == pytest.approx(0.244, rel=1e-6)  # float32 corner values
    assert c.warning.endswith("the corners may differ by as much as the flats' corner falloff, 24 %")
    # f/8 between f/5.6 and an f/11 model of three radial terms: not interpolated; f/11 is nearer in 1/N²
    three = replace(m11, info={"n_terms": 3})
    pair = replace(primary, apertures=(three,))
    g11 = float(np.min(_corners(gains[11.0])))
    c = choose_flat(pair, 8.0, 35.0)
    assert (c.how, c.parts, c.corner_difference_rel, c.mismatch) == ("nearest", ((three, 1.0),), None, True)
    assert c.warning.startswith("f/8 photo, outside the flats' f/5.6, 35 mm – f/11, 35 mm: the f/11, 35 mm "
                                f"vignetting model is used; the corners may differ by an amount one flat cannot "
                                f"bound (a wider aperture vignettes more than the flats' {100 * (1 - g11):.2g} %")
    # f/7 is nearer f/5.6 in 1/N² (1/49 - 1/121 > 1/31.36 - 1/49): f/5.6, stopped down
    c = choose_flat(pair, 7.0, 35.0)
    assert c.parts == ((pair, 1.0),) and c.corner_difference_rel == pytest.approx(1 / g_corner - 1, rel=1e-9)


def test_flat_choice_unknown_f_numbers_and_another_focal_length():
    """An unknown f-number (the photo's or the flats') leaves the primary model unchecked, with a warning naming
    what to record; a focal length off by more than 1 % warns that the corners may differ by the flats' corner
    falloff 1 - min g (or the interpolation's uncertainty, if larger)."""
    from camcal.models.flat import Optics, choose_flat

    primary, m28, m11, gains, _ = _aperture_series()
    c = choose_flat(primary, None, 35.0)
    assert (c.how, c.parts, c.corner_difference_rel, c.mismatch) == ("unchecked", ((primary, 1.0),), None, True)
    assert c.warning == ("the photo's f-number is unknown: the vignetting model (flats at f/2.8, 35 mm, f/5.6, 35 mm, "
                         "f/11, 35 mm) is not checked")
    assert c.describe() == "f/5.6, 35 mm (f-number not checked)"
    unknown = replace(primary, optics=Optics(None, None, 35.0, "tag"), apertures=())
    for n, txt in ((8.0, "f/8"), (None, "f/?")):
        c = choose_flat(unknown, n, 35.0)
        assert (c.how, c.parts, c.corner_difference_rel, c.mismatch) == ("unchecked", ((unknown, 1.0),), None, True)
        assert c.warning == (f"the flats' f-number is unknown: the vignetting of this {txt} photo is not checked "
                             "(record f_number in the flats' frames.csv or session.toml)")
    assert unknown.optics.label() == "f/?, 35 mm" and Optics(8.0).label() == "f/8"
    # a model of unknown f-number among the apertures sorts last and is never chosen
    anon = replace(m11, optics=Optics(None, None, 35.0, "tag"))
    mixed = replace(primary, apertures=(anon, m28))
    assert mixed.models() == (m28, mixed, anon) and mixed.f_numbers() == [2.8, 5.6, None]
    assert choose_flat(mixed, 16.0, 35.0).parts[0][0] is mixed
    # focal length: 100 mm flats, a photo at 101 mm is the same setting (1 % of the shorter), 99 mm is not
    g_corner = float(np.min(_corners(gains[5.6])))
    at100 = replace(primary, optics=Optics(5.6, "tag", 100.0, "tag"), apertures=())
    assert choose_flat(at100, 5.6, 101.0).warning is None and choose_flat(at100, 5.6, 101.0).mismatch is False
    assert choose_flat(at100, 5.6, None).warning is None
    c = choose_flat(at100, 5.6, 99.0)
    assert c.mismatch is True and c.corner_difference_rel == pytest.approx(1 - g_corner, rel=1e-6)
    assert c.warning == ("focal length 99 mm, the flats' 100 mm: vignetting changes with the focal length, the "
                         f"corners may differ by as much as the flats' corner falloff, {100 * (1 - g_corner):.2g} %")
    # interpolated at another focal length: the larger of the interpolation's uncertainty and the falloff of
    # either model; the two notes joined by "; "
    c = choose_flat(primary, 4.0, 50.0)
    falloff = 1 - float(np.min(_corners(gains[2.8])))
    assert c.corner_difference_rel == pytest.approx(falloff, rel=1e-6)
    first = choose_flat(primary, 4.0, 35.0).warning
    assert c.warning == (f"{first}; focal length 50 mm, the flats' 35 mm: vignetting changes with the focal "
                         "length, the corners may differ by as much as the flats' corner falloff, "
                         f"{100 * falloff:.2g} %")
    # a model without a focal length is not checked against the photo's
    nofocal = replace(at100, optics=Optics(5.6, "tag", None, None))
    assert choose_flat(nofocal, 5.6, 50.0).warning is None


def test_same_f_number_within_three_percent_of_the_smaller_and_same_form():
    """f-numbers within 3 % of the smaller are one (103 vs 100: exactly 3 %; 97 vs 100: 3.09 %); None is never
    the same. Models of the same kind, planes, shape, CFA and number of terms (radial) or degree (2-D) may be
    interpolated; any difference refuses."""
    from camcal.models.flat import same_f_number, same_form

    assert same_f_number(100.0, 103.0) and same_f_number(103.0, 100.0)
    assert not same_f_number(100.0, 97.0) and not same_f_number(97.0, 100.0)
    assert not same_f_number(None, 8.0) and not same_f_number(8.0, None) and not same_f_number(None, None)
    primary, m28, *_ = _aperture_series()
    _, _, two_d = _flat_models()
    assert same_form(primary, m28)
    assert not same_form(primary, replace(m28, info={"n_terms": 3}))
    assert not same_form(primary, replace(m28, info={}))
    assert not same_form(primary, replace(m28, channels=("G", "R")))
    assert not same_form(primary, replace(m28, shape=(3, 5)))
    assert not same_form(primary, replace(m28, cfa_pattern="RGGB"))
    assert not same_form(primary, replace(m28, model_2d=two_d.model_2d))
    assert same_form(two_d, replace(two_d, info={"n_terms": 7}))
    assert not same_form(two_d, replace(two_d, model_2d={**two_d.model_2d, "degree": 3}))
    assert not same_form(two_d, replace(two_d, model_2d={k: v for k, v in two_d.model_2d.items() if k != "degree"}))


def test_flat_model_replace_keeps_the_evaluated_gain_only_while_the_model_is_unchanged():
    """A model holding its gain keeps it through a change of provenance or optics; a change of coefficients,
    centres, planes or shape evaluates the new model (the DNG sum written out)."""
    from camcal.models.flat import Optics

    primary, _, _, gains, _ = _aperture_series()
    held = np.full((2, 3, 4), 0.5, np.float32)
    m = primary.with_gain(held)
    kept = m.replace(info={"n_terms": 2, "note": "x"}, optics=Optics(8.0))
    np.testing.assert_array_equal(kept.gain(), held)
    assert kept.info["note"] == "x" and kept.optics.f_number == 8.0
    np.testing.assert_allclose(primary.replace(info={}).gain(), gains[5.6], rtol=1e-6)
    k = {"R": (-0.2, 0.0, 0.0, 0.0, 0.0), "G": (-0.1, 0.0, 0.0, 0.0, 0.0)}
    changed = m.replace(k=k, info={})
    np.testing.assert_allclose(changed.gain(), np.stack([_vignetting(k[c][:2], primary.centre_px[c], (3, 4))
                                                         for c in "RG"]), rtol=1e-6)


def _emva_prnu_by_hand(rel, var_rel, n_frames):
    """√(s²_measured − mean(σ²)/L) / μ and its standard uncertainty (EMVA 1288 4.0 eq. 36), written out."""
    n = rel.size
    mu, measured = rel.mean(), rel.var(ddof=1)
    floor = var_rel.mean() / n_frames
    value = np.sqrt(max(measured - floor, 0.0)) / mu
    unc_s2 = np.sqrt(2 / (n - 1) * measured**2 + 2 / (n * (n_frames - 1)) * floor**2) / mu**2
    return value, unc_s2 / (2 * value), mu, measured, floor * n_frames, n


def _master_for_prnu(mean_all, variance_all, n_frames=4):
    from camcal.calibrate.flat import MasterFlat

    return MasterFlat(value=mean_all, variance_of_mean=None, level_dn={"R": 1.0, "G": 1.0}, n_frames=n_frames,
                      paths=(), channels=("R", "G"), cfa_pattern=None, method="mean", exposure_s=(None,) * n_frames,
                      mean_all=mean_all, variance_all=variance_all)


def test_prnu_figures_are_the_emva_spatial_variance_of_good_pixels_about_the_smooth_model():
    """PRNU per plane of the unclipped mean over the smooth model A·g: pixels masked, non-finite (mean or
    variance), under a non-positive model, below half or above 1.5 times the median response left out (the
    bounds themselves kept), then the EMVA formula written out with numpy; the refusal without statistics."""
    from camcal.calibrate.flat import _prnu_figures, flat_prnu

    rng = np.random.default_rng(5)
    smooth = np.full((2, 4, 5), 2.0)
    rel = np.round(1.0 + 0.02 * rng.standard_normal((2, 4, 5)), 4)
    var_rel = 1e-4 * (1.0 + rng.random((2, 4, 5)))
    # plane R: the median of the 20 responses is 1 exactly (ten at or below it, ten above), then 2
    spread = np.round(0.001 + 0.02 * np.abs(rng.standard_normal(9)), 4)
    rel[0].flat[:] = np.concatenate([1.0 - spread, [1.0, 1.0], 1.0 + spread])
    rel[0, 0, 0], rel[0, 0, 1] = 0.5, 0.4999  # on the lower bound (kept), just below (out)
    rel[0, 3, 4], rel[0, 3, 3] = 1.5, 1.5001  # on the upper bound (kept), just above (out)
    rel *= 2.0  # responses about 2 (exact in binary): the bounds are 1 and 3, not 0.5 and 1.5
    mask = np.zeros((2, 4, 5), bool)
    mask[1, 1, 1] = True
    mean = rel * smooth
    var = var_rel * smooth**2
    mean[1, 0, 0] = np.nan
    var[1, 0, 1] = np.inf
    smooth[1, 2, 2], mean[1, 2, 2] = -2.0, -2.0  # a response of 1 under a negative model
    mf = _master_for_prnu(mean, var)
    out = _prnu_figures(mf, ("R", "G"), smooth, mask)
    assert list(out) == ["R", "G"]
    keep_r = np.ones((4, 5), bool)
    keep_r[0, 1] = keep_r[3, 3] = False
    keep_g = np.ones((4, 5), bool)
    keep_g[1, 1] = keep_g[0, 0] = keep_g[0, 1] = keep_g[2, 2] = False
    for i, keep in enumerate((keep_r, keep_g)):
        value, unc, mu, measured, stack, n = _emva_prnu_by_hand(rel[i][keep], var_rel[i][keep], 4)
        p = out["RG"[i]]
        assert p.value == pytest.approx(value, rel=1e-9) and p.uncertainty == pytest.approx(unc, rel=1e-9)
        assert p.spatial.n_pixels == n and p.spatial.n_frames == 4
        assert p.spatial.mean_dn == pytest.approx(mu, rel=1e-12)
        assert p.spatial.measured_dn2 == pytest.approx(measured, rel=1e-9)
        assert p.spatial.stack_dn2 == pytest.approx(stack, rel=1e-9)
    # a mask of defect bits (4: noisy) masks the same pixels as the bool mask
    bits = _prnu_figures(mf, ("R", "G"), smooth, mask.astype(np.uint8) * 4)
    assert [bits[c].value for c in "RG"] == [out[c].value for c in "RG"]
    # without a mask every finite pixel of G under a positive model counts; the median is that of those
    out = _prnu_figures(mf, ("R", "G"), smooth, None)
    keep_g[1, 1] = True
    assert out["G"].value == pytest.approx(_emva_prnu_by_hand(rel[1][keep_g], var_rel[1][keep_g], 4)[0], rel=1e-9)
    # flat_prnu divides by the fitted model A·g: a flat model of gain g and levels A written out
    primary, _, _, gains, _ = _aperture_series()
    fm = primary.replace(level_dn={"R": 2.0, "G": 0.5})
    a_g = gains[5.6] * np.array([2.0, 0.5])[:, None, None]
    resp = 1.0 + 0.03 * rng.standard_normal((2, 3, 4))
    v = 2e-4 * (1.0 + rng.random((2, 3, 4)))
    fmask = np.zeros((2, 3, 4), bool)
    fmask[0, 1, 2] = fmask[1, 0, 0] = True
    got = flat_prnu(_master_for_prnu(resp * a_g, v * a_g**2, 3), fm, fmask)
    for i, c in enumerate("RG"):
        value, unc, mu, *_ = _emva_prnu_by_hand(resp[i][~fmask[i]], v[i][~fmask[i]], 3)
        assert got[c].value == pytest.approx(value, rel=1e-6)  # float32 gain map
        assert got[c].uncertainty == pytest.approx(unc, rel=1e-5)
        assert got[c].spatial.mean_dn == pytest.approx(mu, rel=1e-6)  # the response about A·g, mean ≈ 1
        assert got[c].spatial.n_pixels == 11
    for missing in ({"mean_all": None}, {"variance_all": None}):
        with pytest.raises(CamcalError) as e:
            _prnu_figures(replace(mf, **missing), ("R", "G"), smooth, None)
        assert str(e.value) == "the master flat has no unclipped statistics (a single frame?)"


@pytest.mark.filterwarnings("ignore:Mean of empty slice:RuntimeWarning")  # the median of an empty plane is NaN
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
def test_medians_above_black_equal_numpy_medians_for_every_dtype_and_histograms_count_in_bands():
    """The per-plane median of planes − black is np.median of the float64 differences (sorted and written out for
    odd and even counts) for unsigned and signed integers, negative values, floats and empty planes; the banded
    histogram is np.bincount whichever band holds the largest value."""
    from camcal.calibrate.flat import HISTOGRAM_ROWS, _histogram, _medians_above

    def by_hand(planes, black):
        out = []
        for p, b in zip(planes, black.reshape(-1), strict=True):
            s = np.sort(p.astype(np.float64).ravel() - b)
            out.append((s[(s.size - 1) // 2] + s[s.size // 2]) / 2)
        return np.array(out)

    rng = np.random.default_rng(3)
    black = np.array([100.5, 3.0, 7.25]).reshape(3, 1, 1)
    for shape in ((3, 3, 5), (3, 4, 5), (3, 1, 1), (3, 1, 2)):
        for dtype in (np.uint16, np.uint8, np.int32):
            planes = rng.integers(0, 200, shape).astype(dtype)
            np.testing.assert_array_equal(_medians_above(planes, black), by_hand(planes, black))
        planes = rng.integers(-50, 200, shape).astype(np.int32)
        planes.flat[0] = -1
        np.testing.assert_array_equal(_medians_above(planes, black), by_hand(planes, black))
        planes = rng.random(shape).astype(np.float32) * 300
        np.testing.assert_allclose(_medians_above(planes, black), by_hand(planes, black), rtol=1e-12)
    # all pixels but a few at one value, the rest above: the middle order statistics straddle a step
    planes = np.full((3, 2, 3), 10, np.uint16)
    planes[:, 1, :] = 12
    planes[1, 1, :] = 10
    np.testing.assert_array_equal(_medians_above(planes, black), by_hand(planes, black))
    one = rng.integers(0, 200, (1, 3, 4)).astype(np.uint16)  # a single plane
    np.testing.assert_array_equal(_medians_above(one, black[:1]), by_hand(one, black[:1]))
    empty = np.zeros((3, 0, 4), np.uint16)
    assert _medians_above(empty, black).shape == (3,) and np.all(np.isnan(_medians_above(empty, black)))
    for top_last in (False, True):
        plane = rng.integers(0, 50, (2 * HISTOGRAM_ROWS + 7, 3)).astype(np.uint16)
        plane[-1 if top_last else 0, 0] = 900
        np.testing.assert_array_equal(_histogram(plane), np.bincount(plane.ravel()))
    np.testing.assert_array_equal(_histogram(np.array([[3, 1]], np.uint16)), [0, 1, 0, 1])
    assert _histogram(np.zeros((0, 3), np.uint16)).size == np.bincount(np.zeros(0, np.uint16)).size == 0


def test_flat_fit_options_and_their_refusals():
    """The fit keywords of the flat stage's options; an unknown model or a number of radial terms outside 1..5
    refused with its one-line message."""
    from camcal.calibrate.flat import FlatOptions, _check_options

    o = FlatOptions(model="2d", downsample=8, n_terms=3, degree_2d=2, with_prnu=False, method="mean")
    assert o.fit_kwargs() == {"model": "2d", "downsample": 8, "n_terms": 3, "degree_2d": 2, "with_prnu": False}
    for model, n in (("radial", 1), ("2d", 5)):
        _check_options(model, n)
    with pytest.raises(CamcalError) as e:
        _check_options("poly", 3)
    assert str(e.value) == "unknown flat model 'poly'; choose 'radial' or '2d'"
    for n in (0, 6):
        with pytest.raises(CamcalError) as e:
            _check_options("radial", n)
        assert str(e.value) == f"n_terms must be 1..5, got {n}"


def test_dead_pixels_join_the_dark_defect_map_with_their_counts_and_source():
    """Dead pixels (bit 2) are OR-ed into the defect map, other bits kept; each plane's dead count is the number
    of its pixels with bit 2 set, counted here with a loop; the source joins the provenance; a map of another
    shape is refused."""
    from camcal.models.dark import DEAD, with_dead_pixels

    m = _dark_model(("R", "G", "B"), True)
    dead = np.zeros(m.defects.shape, bool)
    dead[0, 1, 1] = dead[0, 0, 0] = dead[2, 1, 2] = True  # R: a hot pixel and a clean one; B: a noisy one
    out = with_dead_pixels(m, dead.astype(int) * 5, "flat.json")  # any non-zero value marks a dead pixel
    expect = m.defects.copy()
    for idx in zip(*np.nonzero(dead), strict=True):
        expect[idx] |= DEAD
    assert out.defects.dtype == np.uint8 and DEAD == 2
    np.testing.assert_array_equal(out.defects, expect)
    for k, p in enumerate(("R", "G", "B")):
        count = sum(1 for v in expect[k].ravel() if v & 2)
        assert out.channels[p] == {**m.channels[p], "dead_pixel_count": count}
    assert [out.channels[p]["dead_pixel_count"] for p in "RGB"] == [2, 0, 2]  # B had one dead pixel already
    assert out.provenance == {**m.provenance, "dead_pixels": "flat.json"}
    np.testing.assert_array_equal(out.bias_dn, m.bias_dn)
    assert m.provenance.get("dead_pixels") is None  # the model given is left as it was
    with pytest.raises(CamcalError) as e:
        with_dead_pixels(m, np.zeros((3, 2, 2), bool), "flat.json")
    assert str(e.value) == "dead-pixel map (3, 2, 2) does not match the dark model's (3, 2, 3)"


def test_exposure_time_rules_leave_out_lone_frames_and_need_two_times_without_bias():
    """A frame alone at its exposure time is left out (warned, named with its reason) while another time has two
    frames; all times lone keeps them all; without bias frames one exposure time (or none) is too few, with the
    counts and the time in the message."""
    import warnings as _warnings
    from pathlib import Path

    from camcal.calibrate.dark_frames import _exposure_time_rules
    from camcal.errors import FrameLeftOut, TooFewFrames

    a, b, c, d = (Path(f"/d/{n}.dng") for n in "abcd")
    why = "the dark model measures the temporal noise of each exposure time from two or more frames"
    with pytest.warns(FrameLeftOut) as rec:
        groups, left = _exposure_time_rules({0.5: [a, b], 2.0: [c], 0.25: [d]}, True, Path("/d"))
    assert groups == {0.5: [a, b]}
    assert left == (("c.dng", f"alone at its exposure time (2 s): {why}"),
                    ("d.dng", f"alone at its exposure time (0.25 s): {why}"))
    assert [str(w.message) for w in rec] == [f"left out: {n}: {r}" for n, r in left]
    with _warnings.catch_warnings():
        _warnings.simplefilter("error")
        assert _exposure_time_rules({1.0: [a], 2.0: [b]}, False, Path("/d")) == ({1.0: [a], 2.0: [b]}, ())
        assert _exposure_time_rules({1.0: [a, b]}, True, Path("/d")) == ({1.0: [a, b]}, ())
        assert _exposure_time_rules({1.0: [a, b], 3.0: [c, d]}, False, Path("/d")) == (
            {1.0: [a, b], 3.0: [c, d]}, ())
        assert _exposure_time_rules({}, True, Path("/d")) == ({}, ())
        with pytest.raises(TooFewFrames) as e:
            _exposure_time_rules({1.5: [a, b, c]}, False, Path("/d"))
        assert str(e.value) == ("/d: the dark stage needs at least 2 usable exposure times (or bias frames), 1 "
                                "remain (all 3 dark frames have one exposure time (1.5 s); the dark-current fit "
                                "needs two or more exposure times, or bias frames (--bias))")
        assert e.value.path == Path("/d") and (e.value.needed, e.value.remaining) == (2, 1)
        with pytest.raises(TooFewFrames) as e:
            _exposure_time_rules({1.0: [a]}, False, Path("/d"))
        assert "all 1 dark frames have one exposure time (1 s)" in str(e.value)
        with pytest.raises(TooFewFrames) as e:
            _exposure_time_rules({}, False, Path("/d"))
        assert str(e.value) == "/d: the dark stage needs at least 1 usable frames, 0 remain"
        assert e.value.path == Path("/d")
    with pytest.warns(FrameLeftOut), pytest.raises(TooFewFrames) as e:
        _exposure_time_rules({1.0: [a, b], 2.0: [c]}, False, Path("/d"))
    assert "all 2 dark frames have one exposure time (1 s)" in str(e.value)


def test_dark_frame_check_refuses_processed_and_saturated_frames():
    """RAW frames only; more than the given fraction of pixels at or above the white level (counted here) is a
    saturated dark frame, the fraction and level in its message."""
    from pathlib import Path

    from camcal.calibrate.dark_frames import dark_frame_check
    from camcal.frame import Frame

    data = np.full((10, 10), 100, np.uint16)
    data.flat[:2] = 4095  # 2 % at the white level
    data.flat[2] = 5000  # above it
    raw = Frame(data=data, kind="raw", cfa_pattern="RGGB", black_level_dn={}, white_level_dn=4095.0,
                path=Path("/d/a.dng"))
    dark_frame_check(0.03)(raw)  # 3 % at or above the white level: not more than 3 %
    with pytest.raises(CamcalError) as e:
        dark_frame_check(0.029)(raw)
    assert str(e.value) == ("/d/a.dng: dark frame is saturated: 3.0 % of pixels at the white level 4095 DN "
                            "(light leak, or not a dark frame?)")
    big = np.zeros((100, 100), np.uint16)
    big.flat[:996] = 4095  # 9.96 %, printed 10.0 %
    with pytest.raises(CamcalError) as e:
        dark_frame_check(0.05)(replace(raw, data=big))
    assert "saturated: 10.0 % of pixels" in str(e.value)
    data.flat[:3] = 100
    dark_frame_check()(raw)  # none saturated
    data.flat[:2] = 4095
    with pytest.raises(CamcalError) as e:
        dark_frame_check()(raw)  # 2 % > the default 1 %
    assert "2.0 % of pixels at the white level 4095 DN" in str(e.value)
    with pytest.raises(CamcalError) as e:
        dark_frame_check()(Frame(data=np.zeros((2, 2, 3), np.uint8), kind="processed", cfa_pattern=None,
                                 black_level_dn={}, white_level_dn=255.0, path=Path("/d/a.dng")))
    assert str(e.value) == "/d/a.dng: bias and dark frames must be RAW files (the dark model works on CFA planes)"


def test_dark_exposure_times_take_the_index_then_the_manifest_then_the_file_tag(tmp_path):
    """Each frame's exposure time: the session index's value first, then the frames.csv row, then the file's
    EXIF ExposureTime (a JPEG tagged 1/4 s here); none of them: the missing-metadata error naming the file."""
    from PIL import Image
    from PIL.TiffImagePlugin import IFDRational

    from camcal.calibrate.dark_frames import _exposure_times
    from camcal.calibrate.session import FrameRef, StageFrames
    from camcal.errors import MissingMetadataError

    a, b, c, d = (tmp_path / f"{n}.jpg" for n in "abcd")
    exif = Image.Exif()
    exif[0x829A] = IFDRational(1, 4)
    for p in (a, b, c):
        Image.new("RGB", (2, 2)).save(p, exif=exif.tobytes())
    d.write_bytes(b"not an image")
    manifest = {"a.jpg": {"exposure_s": 9.0}, "b.jpg": {"exposure_s": 2}, "c.jpg": {"exposure_s": None}}
    frames = StageFrames("dark", tmp_path, (FrameRef(a, exposure_s=0.5), FrameRef(b), FrameRef(c)), manifest)
    times = _exposure_times(frames, [a, b, c], manifest)
    assert times == [0.5, 2.0, 0.25] and all(type(t) is float for t in times)
    assert _exposure_times(tmp_path, [a, b, c], manifest) == [9.0, 2.0, 0.25]
    assert _exposure_times(tmp_path, [c], {}) == [0.25]
    with pytest.raises(MissingMetadataError) as e:
        _exposure_times(tmp_path, [b, d], manifest)
    assert e.value.field == "exposure_s" and e.value.path == d
    assert str(e.value).startswith(f"{d}: missing exposure_s: not in the file's metadata; add a 'exposure_s' column")


def test_dark_stacks_must_share_frame_size_pattern_and_iso():
    """Stacks of one frame size, CFA pattern and ISO give that ISO; another size or pattern is refused naming the
    odd stack's first file and both sizes; mixed ISO settings are refused naming the folder."""
    from pathlib import Path
    from types import SimpleNamespace

    from camcal.calibrate.dark_frames import _check_stacks

    def stack(name, shape=(4, 6), cfa="RGGB", iso=400.0):
        return SimpleNamespace(frame_shape=shape, cfa_pattern=cfa, paths=(Path(f"/d/{name}1.dng"),
                                                                          Path(f"/d/{name}2.dng")),
                               exposures=(Exposure(iso=iso), Exposure(iso=iso)))

    assert _check_stacks([stack("a"), stack("b")], Path("/d")) == 400.0
    for odd, says in ((stack("b", shape=(4, 8)), "frame size 8x4 (RGGB) differs from the first dark frame's 6x4 "
                                                  "(RGGB)"),
                      (stack("b", cfa="BGGR"), "frame size 6x4 (BGGR) differs from the first dark frame's 6x4 "
                                               "(RGGB)")):
        with pytest.raises(CamcalError) as e:
            _check_stacks([stack("a"), odd, stack("c")], Path("/d"))
        assert str(e.value) == f"{Path('/d/b1.dng')}: {says}"
    with pytest.raises(CamcalError) as e:
        _check_stacks([stack("a"), stack("b", iso=800.0)], Path("/d"))
    assert str(e.value) == (f"{Path('/d')}: frames mix ISO settings [400.0, 800.0]; take bias and dark frames at "
                            "one ISO")

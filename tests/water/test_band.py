"""Tests of :mod:`camcal.water.band`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

from dataclasses import replace

import colour
import numpy as np
import pytest
from scipy.optimize import brentq

from camcal.errors import CamcalError
from camcal.water.band import BandModel, ChlorophyllAbsorption, bricaud_1998, solvent_spectrum
from camcal.water.models import LampModel, RefinedModel, SeedModel
from camcal.water.purewater import pure_water_absorption_per_m
from camcal.water.uncertainty import (
    forward_for,
)
from tests.helpers import (
    _BAND_WL,
    BAND_C,
    BAND_WL,
    INV_C,
    INV_WL,
    _band_profile,
    _bricaud_per_m,
    _inv_forward,
    _inv_sigma,
)


@pytest.mark.formula
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


_LN10_PER_CM_TO_PER_M = 100.0 * np.log(10.0)  # decadic per cm -> natural per m


_UG_PER_L_IN_G_PER_L = 1e-6  # 1 µg/L = 1 mg m⁻³ = 1e-6 g/L


CHLA_MOLAR_MASS_PUBLISHED = 893.509  # g/mol, chlorophyll-a C55H72MgN4O5 (PubChem)


def _csv(path, text):
    path.write_text(text)
    return path


def _a_star(eps_L_per_g_cm):
    """a* (m² mg⁻¹) of a decadic ε in L g⁻¹ cm⁻¹: ln 10 ε per cm per (g/L), times 100 cm/m and 1e-6 (g/L)/(µg/L)."""
    return np.asarray(eps_L_per_g_cm, float) * _LN10_PER_CM_TO_PER_M * _UG_PER_L_IN_G_PER_L


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
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


@pytest.mark.formula
def test_band_ratio_is_the_sensitivity_weighted_mean_of_the_per_wavelength_ratio():
    """B(C) = ∫ c S R_λ(τ_λ) dλ / ∫ c S dλ with τ_λ = (a_w + a_bg + A C^E) d, rendered here with the trapezoid
    rule from the Bricaud (1998) and Pope & Fry (1997) tables and the per-wavelength closed form of an oblique
    refined model, under a sloping illuminant, at C = 7 µg/L, d = 0.8 m, a_bg = 0.05 m⁻¹ (rel 1e-6: the two
    quadratures differ only at the ends, where c is 4e-7 of its peak)."""
    geom = RefinedModel(view_angle_rad=0.4, albedo=0.8)
    s = np.linspace(0.7, 1.3, BAND_WL.size)
    model = BandModel(BAND_WL, BAND_C, geometry=geom, illuminant=s, background_absorption_per_m=0.05)
    a_chl = _bricaud_per_m(7.0)
    tau = (pure_water_absorption_per_m(BAND_WL) + 0.05 + a_chl) * 0.8
    r_lambda = geom.closed_form().ratio(tau)
    expect = np.trapezoid(BAND_C * s * r_lambda, BAND_WL) / np.trapezoid(BAND_C * s, BAND_WL)
    assert float(model.ratio(7.0, 0.8)) == pytest.approx(expect, rel=1e-6)
    np.testing.assert_allclose(model.spectral_ratio(7.0, 0.8), r_lambda, rtol=1e-12)
    # the seed's geometry ignores water unless given
    seed_band = BandModel(BAND_WL, BAND_C)
    assert not np.any(seed_band.water_absorption())


@pytest.mark.formula
def test_band_ratio_sigma_from_the_sensitivity_is_the_linear_propagation():
    """σ_B² = Σ_k (∂B/∂c_k · u_k)², ∂B/∂c_k by central differences of the band ratio with the k-th sample of c
    moved (u = 5 % of c plus a floor), at C = 20 µg/L, d = 1 m, under a sloping illuminant."""
    s = np.linspace(1.2, 0.8, BAND_WL.size)
    u = 0.05 * BAND_C + 1e-3
    model = BandModel(BAND_WL, BAND_C, illuminant=s)
    var = 0.0
    for k in range(BAND_WL.size):
        dc = np.zeros_like(BAND_C)
        dc[k] = 1e-3 * BAND_C[k]  # relative: c − dc stays positive at the tails (clipping would bend B)
        up = float(BandModel(BAND_WL, BAND_C + dc, illuminant=s).ratio(20.0, 1.0))
        down = float(BandModel(BAND_WL, BAND_C - dc, illuminant=s).ratio(20.0, 1.0))
        var += ((up - down) / (2 * dc[k]) * u[k]) ** 2
    assert float(model.ratio_sigma_from_sensitivity(20.0, 1.0, u)) == pytest.approx(np.sqrt(var), rel=1e-4)


@pytest.mark.formula
def test_chlorophyll_absorption_power_law_and_its_derivative():
    """a = A C^E with E ≠ 1 (Bricaud's E at 440 nm is 0.65), its derivative against a central difference, zero
    absorption (and an infinite slope) at C = 0; decadic ε in L g⁻¹ cm⁻¹ → A = ln 10 · ε · 100 cm/m · 1e-6 g/mg
    per (mg/m³ = µg/L) = 2.302585e-4 ε m² mg⁻¹."""
    chl = ChlorophyllAbsorption(np.array([440.0, 675.0]), np.array([0.04, 0.02]), np.array([0.65, 0.9]))
    c = 8.0
    np.testing.assert_allclose(chl.absorption_per_m(c), [0.04 * c**0.65, 0.02 * c**0.9], rtol=1e-12)
    h = 1e-4
    numeric = (chl.absorption_per_m(c + h) - chl.absorption_per_m(c - h)) / (2 * h)
    np.testing.assert_allclose(chl.derivative_per_m(c), numeric, rtol=1e-7)
    assert not np.any(chl.absorption_per_m(0.0)) and np.all(np.isinf(chl.derivative_per_m(0.0)))
    resampled = chl.on(np.array([400.0, 557.5, 700.0]))
    np.testing.assert_allclose(resampled.coefficient_m2_per_mg, [0.0, 0.03, 0.0])  # zero outside the table
    np.testing.assert_allclose(resampled.exponent, [0.65, 0.775, 0.9])
    solvent = solvent_spectrum([663.0], [80.0])
    assert float(solvent.coefficient_m2_per_mg[0]) == pytest.approx(np.log(10) * 80.0 * 100 * 1e-6, rel=1e-12)
    assert float(solvent.exponent[0]) == 1.0 and solvent.source == "solvent ε(λ)"


@pytest.mark.formula
def test_band_ratio_derivative_of_a_lamp_at_depth_for_an_array_of_concentrations():
    """The lamp's form depends on the depth (its path to the disk), so dB/dC must use the form at that depth;
    with an array of C the result has C's shape. Against central differences (h = 1e-3 C)."""
    model = BandModel(BAND_WL, BAND_C, geometry=LampModel(height_m=0.3, lamp_angle_rad=0.2))
    c, d = np.array([3.0, 40.0]), 0.9
    h = 1e-3 * c
    numeric = (model.ratio(c + h, d) - model.ratio(c - h, d)) / (2 * h)
    got = model.ratio_derivative(c, d)
    assert got.shape == (2,)
    np.testing.assert_allclose(got, numeric, rtol=1e-5)
    np.testing.assert_allclose(model.ratio_and_derivative(c, d)[1], numeric, rtol=1e-5)


@pytest.mark.formula
def test_band_sigma_without_an_illuminant_and_with_negative_noise_samples():
    """The same linear propagation with a flat illuminant (none given) and a curve whose tail carries negative
    noise samples: those are clipped out of the band, so their uncertainty does not count."""
    c = BAND_C - 2e-3  # the tails go negative
    u = np.full(BAND_WL.size, 4e-3)
    model = BandModel(BAND_WL, c)
    var = 0.0
    for k in np.flatnonzero(c > 0):
        dc = np.zeros_like(c)
        dc[k] = 1e-3 * c[k]
        up = float(BandModel(BAND_WL, c + dc).ratio(20.0, 1.0))
        down = float(BandModel(BAND_WL, c - dc).ratio(20.0, 1.0))
        var += ((up - down) / (2 * dc[k]) * u[k]) ** 2
    assert np.any(c < 0)
    assert float(model.ratio_sigma_from_sensitivity(20.0, 1.0, u)) == pytest.approx(np.sqrt(var), rel=1e-4)


def _planck_shape(t_k, wl_nm):
    """Planck's law 2hc²/λ⁵ / (exp(hc/λkT) − 1) with the exact SI constants, normalised to its maximum on wl."""
    h, c, k = 6.62607015e-34, 299792458.0, 1.380649e-23
    lam = np.asarray(wl_nm, float) * 1e-9
    b = 2 * h * c**2 / lam**5 / np.expm1(h * c / (lam * k * t_k))
    return b / np.max(b)


@pytest.mark.formula
def test_illuminant_spectrum_is_planck_the_cie_tables_the_lamp_or_a_measured_csv(tmp_path):
    """S(λ) normalised to a maximum of 1 on the grid asked for: 'NNNNK' is Planck's law written out here (the
    temperature read from the name, 500-50000 K inclusive); a CIE name is colour-science's own table (any
    case), linear between its 5 nm nodes; 'lamp' is the shipped 3200 K black body (tabulated to 6 decimals,
    380-780 nm, NaN outside); a CSV is interpolated linearly, NaN outside its range, whatever its extension;
    'flat' and its synonyms are None."""
    from camcal.water.band import illuminant_spectrum

    wl = np.array([420.0, 555.0, 640.0, 702.5])
    for name in ("flat", " Flat ", "EQUAL", "e", "None"):
        assert illuminant_spectrum(name, wl) is None
    for name, t in (("3000K", 3000.0), ("2856.5k", 2856.5), ("500K", 500.0), ("50000K", 50000.0)):
        np.testing.assert_allclose(illuminant_spectrum(name, wl), _planck_shape(t, wl), rtol=1e-9)
    for name in ("499.9K", "50000.5K"):
        with pytest.raises(CamcalError, match="implausible"):
            illuminant_spectrum(name, wl)
    # CIE D65 and A from colour-science's tables: at their 5 nm nodes, and half-way between two nodes
    nodes = np.arange(400.0, 701.0, 5.0)
    for name, key in ((" d65 ", "D65"), ("a", "A")):
        table = colour.SDS_ILLUMINANTS[key]
        vals = np.array([table[x] for x in nodes])
        np.testing.assert_allclose(illuminant_spectrum(name, nodes), vals / vals.max(), rtol=1e-12)
        two = np.array([0.5 * (table[560.0] + table[565.0]), table[460.0]])
        np.testing.assert_allclose(illuminant_spectrum(name, np.array([562.5, 460.0])), two / two.max(), rtol=1e-12)
    with pytest.raises(CamcalError, match="unknown illuminant"):
        illuminant_spectrum("D99", wl)
    # the shipped lamp: a 3200 K black body, maximum at 780 nm within 380-780 nm
    lamp_wl = np.array([370.0, 400.0, 550.0, 700.0, 780.0, 790.0])
    lamp = illuminant_spectrum("lamp", lamp_wl)
    assert np.isnan(lamp[0]) and np.isnan(lamp[-1])
    np.testing.assert_allclose(lamp[1:-1], _planck_shape(3200.0, lamp_wl[1:-1]), atol=1e-6)
    # a measured spectrum: 1, 3, 2 at 500, 600, 700 nm
    for fname in ("light.csv", "light.txt"):
        f = tmp_path / fname
        f.write_text("# a measured light\nwavelength_nm,relative_radiance\n500,1\n600,3\n700,2\n")
        got = illuminant_spectrum(str(f), np.array([450.0, 550.0, 600.0, 650.0, 750.0]))
        np.testing.assert_allclose(got, [np.nan, 2 / 3, 1.0, 2.5 / 3, np.nan], rtol=1e-12)
    with pytest.raises(CamcalError, match="no such file"):
        illuminant_spectrum(tmp_path / "nowhere.csv", wl)


class _BareGeometry:
    """A geometry given only by its closed form (no name, no ``includes_water``): the seed's R(τ)."""

    def closed_form(self):
        return SeedModel().closed_form()


@pytest.mark.formula
def test_band_model_describe_and_water_default_follow_the_inputs():
    """describe(): the geometry's name (its class name when it has none), the chlorophyll spectrum's source,
    where a_w comes from (Pope & Fry by default for a geometry that includes water, 'given', or none), the
    effective wavelength ∫ c⁺ S λ dλ / ∫ c⁺ S dλ by the trapezoid rule (c⁺: negative noise samples clipped,
    c below 1 kept as is; exactly zero at both ends, so the quadratures agree to rounding), and the grid's
    ends."""
    wl = np.arange(560.0, 721.0, 4.0)
    c = 0.4 * np.sin(np.pi * (wl - 560.0) / 160.0) ** 2 - 0.02  # negative tails
    s = np.linspace(0.6, 1.2, wl.size)
    cp = np.clip(c, 0.0, None)
    lam_eff = np.trapezoid(cp * s * wl, wl) / np.trapezoid(cp * s, wl)
    d = BandModel(wl, c, geometry=RefinedModel(), illuminant=s).describe()
    assert d == {"geometry": "refined", "chlorophyll": "Bricaud et al. 1998 (a*_ph)",
                 "water_absorption": "Pope & Fry 1997", "effective_wavelength_nm": pytest.approx(lam_eff, rel=1e-12),
                 "wavelength_range_nm": [560.0, 720.0]}
    flat = BandModel(wl, c, geometry=RefinedModel()).describe()
    assert flat["effective_wavelength_nm"] == pytest.approx(np.trapezoid(cp * wl, wl) / np.trapezoid(cp, wl),
                                                            rel=1e-12)
    assert BandModel(wl, c).describe()["water_absorption"] == "none (seed)"
    # a grid twice as fine above 640 nm: the trapezoid weights follow the spacing
    uneven = np.concatenate([np.arange(560.0, 640.0, 4.0), np.arange(640.0, 721.0, 2.0)])
    cu = np.sin(np.pi * (uneven - 560.0) / 160.0) ** 2 * (1.0 + (uneven - 560.0) / 80.0)
    assert BandModel(uneven, cu).describe()["effective_wavelength_nm"] == pytest.approx(
        np.trapezoid(cu * uneven, uneven) / np.trapezoid(cu, uneven), rel=1e-12)
    chl = ChlorophyllAbsorption(np.array([400.0, 800.0]), np.array([0.02, 0.02]), np.array([1.0, 1.0]), "my dye")
    given = BandModel(wl, c, geometry=RefinedModel(), water_absorption_per_m=0.3, chlorophyll=chl).describe()
    assert given["water_absorption"] == "given" and given["chlorophyll"] == "my dye"
    assert BandModel(wl, c, water_absorption_per_m=0.3).describe()["water_absorption"] == "given"
    bare = BandModel(wl, c, geometry=_BareGeometry())
    assert bare.describe()["geometry"] == "_BareGeometry"
    assert bare.describe()["water_absorption"] == "none (seed)"
    assert not np.any(bare.water_absorption())
    np.testing.assert_allclose(BandModel(wl, c, geometry=RefinedModel()).water_absorption(),
                               pure_water_absorption_per_m(wl), rtol=1e-12)


@pytest.mark.formula
def test_band_background_spectrum_and_a_power_law_below_one_microgram():
    """A background a_bg(λ) given as a spectrum is added per wavelength to a_w (Pope & Fry for the refined
    geometry, zero for the seed's); a = A C^E and da/dC = A E C^(E−1) hold below 1 µg/L too (C = 0.5), and at
    C = 0 da/dC is its limit from above; a spectrum resampled on another grid keeps that grid and its
    source."""
    wl = np.arange(600.0, 701.0, 10.0)
    bg = np.linspace(0.3, 0.05, wl.size)  # CDOM falling with wavelength
    np.testing.assert_allclose(BandModel(wl, np.ones(wl.size), background_absorption_per_m=bg)
                               .absorption_background(), bg, rtol=1e-12)
    np.testing.assert_allclose(BandModel(wl, np.ones(wl.size), geometry=RefinedModel(),
                                         background_absorption_per_m=bg).absorption_background(),
                               pure_water_absorption_per_m(wl) + bg, rtol=1e-12)
    chl = ChlorophyllAbsorption(np.array([600.0, 700.0]), np.array([0.02, 0.01]), np.array([0.7, 0.9]), "table")
    np.testing.assert_allclose(chl.absorption_per_m(0.5), [0.02 * 0.5**0.7, 0.01 * 0.5**0.9], rtol=1e-12)
    np.testing.assert_allclose(chl.derivative_per_m(0.5), [0.02 * 0.7 * 0.5**-0.3, 0.01 * 0.9 * 0.5**-0.1],
                               rtol=1e-12)
    # at C = 0 the slope's limit from above: a linear absorber's A, zero for E > 1 or where A = 0, infinite
    # for E < 1 (a(h)/h = A h^(E-1) for small h)
    four = ChlorophyllAbsorption(np.arange(4.0), np.array([0.02, 0.03, 0.04, 0.0]), np.array([0.7, 1.0, 1.3, 0.8]))
    np.testing.assert_array_equal(four.derivative_per_m(0.0), [np.inf, 0.03, 0.0, 0.0])
    h = 1e-9
    assert four.absorption_per_m(h)[1] / h == pytest.approx(0.03, rel=1e-12)
    assert four.absorption_per_m(h)[2] / h < 1e-2 * 0.04  # A h^0.3: 0.2 % of A at h = 1e-9
    on = chl.on(wl)
    np.testing.assert_array_equal(on.wavelengths_nm, wl)
    assert on.source == "table"
    np.testing.assert_allclose(on.coefficient_m2_per_mg, 0.02 - 0.01 * (wl - 600.0) / 100.0, rtol=1e-12)


@pytest.mark.formula
def test_band_ratio_of_a_lamp_for_an_image_of_concentrations():
    """B(C) and dB/dC of the lamp's form (not an E₃ closed form: its own ratio and derivative) for a 2 × 3 array
    of C: B against ∫ c R_λ(τ_λ) dλ / ∫ c dλ by the trapezoid rule with τ_λ = (a_w + A C^E) d from the Pope &
    Fry and Bricaud tables and the lamp's per-wavelength R at that depth (rel 1e-6: the quadratures differ only
    at the grid's ends, where c is 4e-7 of its peak), dB/dC against central differences (h = 1e-3 C)."""
    geom = LampModel(height_m=0.3, lamp_angle_rad=0.2)
    model = BandModel(BAND_WL, BAND_C, geometry=geom)
    c, d = np.array([[0.5, 3.0, 20.0], [60.0, 150.0, 400.0]]), 0.7
    form = geom.closed_form_at(d)
    expect = np.empty(c.shape)
    for idx, cv in np.ndenumerate(c):
        r = form.ratio((pure_water_absorption_per_m(BAND_WL) + _bricaud_per_m(cv)) * d)
        expect[idx] = np.trapezoid(BAND_C * r, BAND_WL) / np.trapezoid(BAND_C, BAND_WL)
    b, db = model.ratio_and_derivative(c, d)
    assert b.shape == db.shape == (2, 3)
    np.testing.assert_allclose(b, expect, rtol=1e-6)
    h = 1e-3 * c
    np.testing.assert_allclose(db, (model.ratio(c + h, d) - model.ratio(c - h, d)) / (2 * h), rtol=1e-5)


@pytest.mark.formula
def test_band_sigma_for_several_concentrations_with_exact_zeros_in_the_curve():
    """σ_B for an array of C under a flat illuminant, with a curve cut to exactly zero outside 580-700 nm (as a
    profile's curve beyond its measured range) and u > 0 there: a zero sample is outside the band, like a
    clipped one, so its u does not count; linear propagation by central differences of B in each c_k > 0."""
    c = np.where((BAND_WL > 580) & (BAND_WL < 700), BAND_C, 0.0)
    u = np.full(BAND_WL.size, 3e-3)
    cs = np.array([5.0, 20.0])
    var = np.zeros(2)
    for k in np.flatnonzero(c > 0):
        dc = np.zeros_like(c)
        dc[k] = 1e-3 * c[k]
        up, down = BandModel(BAND_WL, c + dc).ratio(cs, 1.0), BandModel(BAND_WL, c - dc).ratio(cs, 1.0)
        var += ((up - down) / (2 * dc[k]) * u[k]) ** 2
    got = BandModel(BAND_WL, c).ratio_sigma_from_sensitivity(cs, 1.0, u)
    assert got.shape == (2,)
    np.testing.assert_allclose(got, np.sqrt(var), rtol=1e-4)


def _inv_ratio_and_slope(c_ug_per_L, depth_m=0.5, bg=0.1):
    """B(C) as _inv_forward and dB/dC written out: ∫ c R'(τ) d A E C^(E−1) dλ / ∫ c dλ (R' of the seed's form)."""
    chl = bricaud_1998()
    a = np.interp(INV_WL, chl.wavelengths_nm, chl.coefficient_m2_per_mg)
    e = np.interp(INV_WL, chl.wavelengths_nm, chl.exponent)
    form = SeedModel().closed_form()
    b, db = [], []
    for cv in np.asarray(c_ug_per_L, float):
        tau = (bg + a * cv**e) * depth_m
        b.append(np.trapezoid(INV_C * form.ratio(tau), INV_WL) / np.trapezoid(INV_C, INV_WL))
        db.append(np.trapezoid(INV_C * form.ratio_derivative(tau) * depth_m * a * e * cv ** (e - 1), INV_WL)
                  / np.trapezoid(INV_C, INV_WL))
    return np.array(b), np.array(db)


@pytest.mark.formula
def test_band_inverse_round_trip_through_a_forward_model_written_out():
    """Ratios rendered by _inv_forward at C from just above the table's first node (1e-4 µg/L) to just below
    its last (1e5 µg/L) come back as C (rel 1e-7: the table's interpolation, measured ~1e-9), in mol/L through
    chlorophyll-a's 893.5 g/mol, with σ_C = σ_ln r / |d ln B/dC| (rel 1e-4: the central difference and the
    table's slope) for a scalar and a per-pixel σ_ln r; the model's inverse is cached per depth and passes
    its node count on; an image keeps its shape; without σ_ln r, σ_C is NaN; τ is not defined (NaN). Across
    the table σ_C = σ_ln r · B/|dB/dC| holds to 3e-7 with dB/dC written out."""
    from camcal.water.band import BandInverse

    model = BandModel(INV_WL, INV_C, background_absorption_per_m=0.1)
    c = np.array([1.01e-4, 0.3, 7.0, 250.0, 3000.0, 0.998e5])
    r = _inv_forward(c)
    inv = model.inverse(0.5)
    res = inv.concentration(r, sigma_ln_ratio=0.02)
    assert not np.any(res.reason)
    np.testing.assert_allclose(res.c_ug_per_L, c, rtol=1e-7)
    np.testing.assert_allclose(res.c_mol_per_L, c / (893.5 * 1e6), rtol=1e-7)
    np.testing.assert_allclose(res.sigma_ug_per_L, _inv_sigma(c, 0.02), rtol=1e-4)
    assert res.tau.dtype == np.float64 and np.all(np.isnan(res.tau))
    assert res.reason.dtype == np.uint8
    per_pixel = np.linspace(0.01, 0.06, c.size)
    np.testing.assert_allclose(inv.concentration(r, sigma_ln_ratio=per_pixel).sigma_ug_per_L,
                               _inv_sigma(c, per_pixel), rtol=1e-4)
    img = inv.concentration(r.reshape(2, 3))
    assert img.c_ug_per_L.shape == img.sigma_ug_per_L.shape == img.reason.shape == (2, 3)
    np.testing.assert_allclose(img.c_ug_per_L, c.reshape(2, 3), rtol=1e-7)
    assert np.all(np.isnan(img.sigma_ug_per_L))
    # σ_C = σ_ln r · B/|dB/dC| across the table (400 C from 1.3e-4 to 9e4 µg/L), dB/dC written out: rel 3e-7
    # (the slope of the table's cubics, measured within 1e-7 of it)
    across = np.logspace(-3.9, 4.95, 400)
    b_across, db_across = _inv_ratio_and_slope(across)
    np.testing.assert_allclose(inv.concentration(b_across, sigma_ln_ratio=1.0).sigma_ug_per_L,
                               b_across / np.abs(db_across), rtol=3e-7)
    # another depth: another table
    r1 = _inv_forward(c[1:4], 1.2)
    np.testing.assert_allclose(model.inverse(1.2).concentration(r1).c_ug_per_L, c[1:4], rtol=1e-7)
    assert model.inverse(1.2) is model.inverse(1.2)
    coarse = model.inverse(0.5, nodes=4).concentration(_inv_forward(7.0)).c_ug_per_L
    np.testing.assert_array_equal(coarse, BandInverse(model, 0.5, 4).concentration(_inv_forward(7.0)).c_ug_per_L)
    # a ratio in single precision: its logarithm is taken in double (B of the result matches it to 1e-10)
    r32 = _inv_forward(c[1:5]).astype(np.float32)
    back = _inv_forward(inv.concentration(r32).c_ug_per_L)
    np.testing.assert_allclose(back, r32.astype(np.float64), rtol=1e-10)


@pytest.mark.formula
def test_band_inverse_of_a_four_node_table_and_its_refusals(tmp_path):
    """A table of four nodes (1e-4, 0.1, 100, 1e5 µg/L: the fewest accepted) goes through its nodes (rel 1e-8);
    a depth that is not positive and finite is refused; a spectrum that absorbs nowhere in the band (a dye
    CSV absorbing at 400-450 nm only, or the default Bricaud table, which ends at 700 nm, under a 720-800 nm
    channel) is refused, naming the CSV when there is one."""
    from camcal.water.band import BandInverse, read_chlorophyll_csv

    model = BandModel(INV_WL, INV_C, background_absorption_per_m=0.1)
    four = BandInverse(model, 0.5, nodes=4)
    np.testing.assert_allclose(four.concentration(_inv_forward([1e-4, 0.1, 100.0])).c_ug_per_L,
                               [1e-4, 0.1, 100.0], rtol=1e-8)
    for depth in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(CamcalError, match="depth must be positive"):
            BandInverse(model, depth)
    f = tmp_path / "blue_dye.csv"
    f.write_text("wavelength_nm,A_m2_per_mg\n380,0.05\n450,0.05\n451,0\n800,0\n")
    with pytest.raises(CamcalError, match="does not respond") as err:
        BandInverse(BandModel(INV_WL, INV_C, chlorophyll=read_chlorophyll_csv(f)), 0.5)
    assert err.value.path == f
    with pytest.raises(CamcalError, match="does not respond") as err:  # a spectrum with no file behind it
        BandInverse(BandModel(INV_WL, INV_C, chlorophyll=solvent_spectrum(INV_WL, np.zeros(INV_WL.size))), 0.5)
    assert err.value.path is None
    far_red = np.arange(720.0, 801.0, 4.0)
    with pytest.raises(CamcalError, match="does not respond") as err:
        BandInverse(BandModel(far_red, np.ones(far_red.size)), 0.5)
    assert err.value.path is None


@pytest.mark.formula
def test_band_inverse_where_the_band_stops_responding_or_underflows():
    """A red channel reaching past the Bricaud table's 700 nm end: B falls to the floor of the light beyond
    700 nm that chlorophyll does not absorb; a ratio on that floor (B at 1e5 µg/L, forward model written out)
    is TOO_DARK, a ratio above it inverts (rel 1e-7). On the way down to the floor (1-1e5 µg/L, 300 ratios)
    each ratio gives C to 1e-5 (the table's check is 1e-6 in ln C at its nodes) or, from some C on, TOO_DARK;
    never a wrong C. A dye absorbing so strongly that B underflows: a ratio of 1e-305 (below the 1e-300 the
    table keeps) is TOO_DARK, a ratio of 1e-150 inverts."""
    from camcal.water.invert import Reason

    wl = np.arange(640.0, 761.0, 2.0)
    c = np.sin(np.pi * (wl - 640.0) / 120.0) ** 2
    chl = bricaud_1998()
    a = np.interp(wl, chl.wavelengths_nm, chl.coefficient_m2_per_mg, right=0.0)
    e = np.interp(wl, chl.wavelengths_nm, chl.exponent)
    form = SeedModel().closed_form()

    def fwd(cv):
        return np.trapezoid(c * form.ratio((0.1 + a * cv**e) * 0.5), wl) / np.trapezoid(c, wl)

    inv = BandModel(wl, c, background_absorption_per_m=0.1).inverse(0.5)
    res = inv.concentration(np.array([fwd(1e5), fwd(5.0), fwd(80.0)]))
    assert res.reason.tolist() == [Reason.TOO_DARK, 0, 0]
    np.testing.assert_allclose(res.c_ug_per_L[1:], [5.0, 80.0], rtol=1e-7)
    cs = np.logspace(0.0, 5.0, 300)
    down = inv.concentration(np.array([fwd(cv) for cv in cs]))
    ok = down.reason == 0
    assert np.all(ok[:170]) and not np.any(ok[np.argmin(ok):])  # C up to 700 µg/L; then TOO_DARK throughout
    assert np.all(down.reason[~ok] == Reason.TOO_DARK)
    np.testing.assert_allclose(down.c_ug_per_L[ok], cs[ok], rtol=1e-5)
    dye = solvent_spectrum(INV_WL, np.full(INV_WL.size, 60.0))  # A = 2.303e-4 · 60 m² mg⁻¹, linear
    dinv = BandModel(INV_WL, INV_C, chlorophyll=dye).inverse(1.0)
    a_dye = float(dye.coefficient_m2_per_mg[0])
    c_dark = brentq(lambda cv: np.log(np.trapezoid(INV_C * form.ratio(np.full(INV_WL.size, a_dye * cv)), INV_WL)
                                      / np.trapezoid(INV_C, INV_WL)) - np.log(1e-150), 1.0, 2e4)
    dark = dinv.concentration(np.array([1e-150, 1e-305]))
    assert dark.reason.tolist() == [0, Reason.TOO_DARK]
    assert dark.c_ug_per_L[0] == pytest.approx(c_dark, rel=1e-7)


@pytest.mark.formula
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

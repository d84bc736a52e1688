"""The light on the chart: SPECTRL2's global horizontal irradiance and its atmosphere perturbations, CIE
illuminants, a measured spectrum."""

from __future__ import annotations

import math

import numpy as np
import pvlib
import pytest

from camcal.chart.light import blackbody, cie_illuminant, clear_sky_irradiance, daylight, read_irradiance_csv
from camcal.chart.targets import GRID_NM
from camcal.errors import CamcalError


def test_clear_sky_is_direct_times_cos_plus_diffuse_from_spectrl2():
    z = 50.0
    e = clear_sky_irradiance(z, aerosol_optical_depth_500nm=0.2, precipitable_water_cm=2.0, day_of_year=100)
    s = pvlib.spectrum.spectrl2(apparent_zenith=z, aoi=z, surface_tilt=0.0, ground_albedo=0.06,
                                surface_pressure=101325.0, relative_airmass=pvlib.atmosphere.get_relative_airmass(z),
                                precipitable_water=2.0, ozone=0.344, aerosol_turbidity_500nm=0.2, dayofyear=100)
    glob = np.asarray(s["dni"]).ravel() * math.cos(math.radians(z)) + np.asarray(s["dhi"]).ravel()
    np.testing.assert_allclose(e.irradiance_w_m2_nm, np.interp(GRID_NM, np.asarray(s["wavelength"]), glob),
                               rtol=1e-9)
    assert e.absolute and e.source["aerosol_optical_depth_500nm"] == 0.2 and e.source["day_of_year_known"]
    # three perturbed spectra: aerosol (blue, broad), water vapour (the 720 nm band), ozone (Chappuis, ~600 nm)
    assert e.perturbations.shape == (3, GRID_NM.size)
    aer, water, ozone = np.abs(e.perturbations) / e.irradiance_w_m2_nm
    assert aer[GRID_NM == 450][0] > 0.01
    assert water[GRID_NM == 720][0] > 5 * water[GRID_NM == 550][0]
    assert ozone[GRID_NM == 600][0] > ozone[GRID_NM == 450][0]
    np.testing.assert_allclose(e.covariance.diagonal(), e.uncertainty ** 2)
    assert not clear_sky_irradiance(z).source["day_of_year_known"]
    with pytest.raises(CamcalError):
        clear_sky_irradiance(95.0)


def test_cie_illuminants_by_name():
    import colour

    d65 = cie_illuminant("D65")
    ref = colour.SDS_ILLUMINANTS["D65"]
    assert d65.irradiance_w_m2_nm[GRID_NM == 560][0] == pytest.approx(
        ref[560] / max(ref[GRID_NM]), rel=0.02)
    assert not d65.absolute and d65.perturbations.shape[0] == 0
    a = cie_illuminant("a")
    np.testing.assert_allclose(a.irradiance_w_m2_nm, blackbody(2856.0).irradiance_w_m2_nm, rtol=0.01)
    np.testing.assert_allclose(cie_illuminant("D5000").irradiance_w_m2_nm, daylight(5000).irradiance_w_m2_nm)
    np.testing.assert_allclose(cie_illuminant("blackbody:3000").irradiance_w_m2_nm,
                               blackbody(3000).irradiance_w_m2_nm)
    assert np.argmax(blackbody(3000).irradiance_w_m2_nm) == GRID_NM.size - 1  # red-rich
    assert cie_illuminant("D65", relative_uncertainty=0.02).perturbations.shape == (1, GRID_NM.size)
    with pytest.raises(CamcalError, match="unknown illuminant"):
        cie_illuminant("sodium")
    with pytest.raises(CamcalError, match="4000-25000"):
        daylight(3000)


def test_measured_spectrum_csv(tmp_path):
    wl = np.arange(350.0, 801.0, 2.0)
    e = 1.0 + wl / 1000
    p = tmp_path / "lamp.csv"
    p.write_text("# a lamp\nwavelength_nm,irradiance_w_m2_nm,u_irradiance_w_m2_nm\n"
                 + "\n".join(f"{a:g},{b:g},{0.01 * b:g}" for a, b in zip(wl, e, strict=True)))
    got = read_irradiance_csv(p, absolute=True)
    np.testing.assert_allclose(got.irradiance_w_m2_nm, 1.0 + GRID_NM / 1000)
    np.testing.assert_allclose(got.uncertainty, 0.01 * got.irradiance_w_m2_nm)
    assert got.absolute and got.source["sha256"]
    assert read_irradiance_csv(p).irradiance_w_m2_nm.max() == pytest.approx(1.0)
    short = tmp_path / "short.csv"
    short.write_text("wavelength_nm,irradiance_w_m2_nm\n400,1\n700,1\n")
    with pytest.raises(CamcalError, match="covers 400-700") as err:
        read_irradiance_csv(short)
    assert "short.csv" in str(err.value)
    bad = tmp_path / "bad.csv"
    bad.write_text("wavelength_nm,E\n400,1\n700,1\n")
    with pytest.raises(CamcalError, match="needs columns"):
        read_irradiance_csv(bad)

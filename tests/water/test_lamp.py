"""The lamp model (seed §4) and the exact-transmittance refined model, inverted as the other models are."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad

from camcal.errors import CamcalError
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import SensorParams, SyntheticCamera
from camcal.water.band import BandModel, illuminant_spectrum
from camcal.water.invert import Reason, invert_ratio
from camcal.water.models import ExponentialForm, LampModel, RefinedModel, lamp_ratio
from camcal.water.optics import fresnel_reflectance, snell
from tests.conftest import assert_one_line_error, run_cli
from tests.test_properties import check_inversion

C_MOL = np.array([1e-9, 1e-8, 1e-7, 3e-7, 5e-7])


def test_lamp_model_is_a_single_exponential_and_matches_lamp_ratio():
    m = LampModel(0.8, np.radians(25))
    d = 0.3
    cf = m.closed_form_at(d)
    assert isinstance(cf, ExponentialForm)
    beta = float(snell(np.radians(25)))
    assert cf.view_factor == pytest.approx(1 / np.cos(beta) + 1.0)
    np.testing.assert_allclose(m.ratio(C_MOL, d), cf.ratio(m.tau(C_MOL, d)), rtol=1e-14)
    np.testing.assert_allclose(m.ratio(C_MOL, d), lamp_ratio(C_MOL, d, 0.8, np.radians(25)), rtol=1e-14)
    # normal incidence, no absorption: (H+d)²/(H+d/n)² T² / n²
    m0 = LampModel(0.5, 0.0, water_absorption_per_m=0.0)
    t = 1 - fresnel_reflectance(0.0)
    assert m0.ratio(0.0, 0.2) == pytest.approx((0.7 / (0.5 + 0.2 / 1.33)) ** 2 * t * t / 1.33**2, rel=1e-12)


def test_lamp_geometry_factor_against_numerical_ray_tube():
    """K(d) against an independent numerical Jacobian: trace rays, difference their landing points."""
    h, a, d, n = 0.6, np.radians(30), 0.25, 1.33
    m = LampModel(h, a, water_absorption_per_m=0.0)

    def land(alpha):
        return h * np.tan(alpha) + d * np.tan(np.arcsin(np.sin(alpha) / n))

    da = 1e-6
    x = land(a)
    dx = (land(a + da) - land(a - da)) / (2 * da)
    e_w = (1 - fresnel_reflectance(a)) * np.sin(a) / (x * dx)  # flux per solid angle over the landing ring
    e_air = (h + d) / (x * x + (h + d) ** 2) ** 1.5
    t_up = 1 - fresnel_reflectance(0.0, 1.33, 1.0)
    assert m.geometry_factor(d) == pytest.approx(e_w / e_air * t_up / n**2, rel=1e-8)


def test_lamp_round_trip_dense_grid_in_process():
    worst = 0.0
    for h in np.linspace(0.3, 2.0, 5):
        for a in np.radians(np.linspace(0, 40, 5)):
            for d in np.linspace(0.1, 0.5, 5):
                m = LampModel(float(h), float(a))
                inv = invert_ratio(m.ratio(C_MOL, d), m, d)
                assert np.all(inv.reason == 0)
                worst = max(worst, float(np.max(np.abs(inv.c_mol_per_L / C_MOL - 1))))
    assert worst < 1e-9  # measured 4e-10 (the τ table; C = 1e-9 mol/L is a small excess over water)


# Two geometries through the CLI (a lamp overhead, one low and oblique): the parsing, the JSON and the round trip
# are the same code for every geometry, and the dense grid above covers the physics of the ones between (1 m at
# 20 degrees among them).
@pytest.mark.parametrize("h,angle", [("0.3m", "0"), ("2m", "40")])
def test_lamp_round_trip_through_the_cli(h, angle):
    lamp = ["--water-model", "lamp", "--lamp-height", h, "--lamp-angle", angle]
    conc = ",".join(f"{float(c)!r}mol/L" for c in C_MOL)
    proc = run_cli("water", "forward", "--json", "--concentration", conc, "--depth", "0.1m,0.5m", *lamp)
    assert proc.returncode == 0, proc.stderr
    ratios = json.loads(proc.stdout)["ratio"]
    for depth, row in zip(("0.1m", "0.5m"), ratios, strict=True):
        proc = run_cli("water", "invert", "--json", "--ratio", ",".join(repr(r) for r in row), "--depth", depth, *lamp)
        assert proc.returncode == 0, proc.stderr
        out = json.loads(proc.stdout)
        assert out["reason"] == ["ok"] * len(C_MOL)
        np.testing.assert_allclose(out["c_mol_per_L"], C_MOL, rtol=1e-9)


def test_lamp_reasons_and_errors():
    m = LampModel(1.0, np.radians(10))
    r0 = m.ratio(0.0, 0.3)
    inv = invert_ratio(np.array([np.nan, -1.0, 1.01 * r0, 1e-300, 0.5 * r0]), m, 0.3)
    assert list(inv.reason) == [Reason.NOT_FINITE, Reason.NOT_POSITIVE, Reason.ABOVE_CLEAR_WATER, Reason.TOO_DARK,
                                Reason.OK]
    with pytest.raises(CamcalError, match="one depth at a time"):
        invert_ratio(np.array([0.1, 0.1]), m, np.array([0.2, 0.3]))
    assert_one_line_error(run_cli("water", "invert", "--json", "--ratio", "0.3", "--depth", "0.2m", "--water-model",
                                  "lamp"),
                          "--lamp-height")
    assert_one_line_error(run_cli("water", "forward", "--json", "--concentration", "1e-7", "--depth", "0.2m",
                                  "--water-model", "lamp", "--lamp-height", "1m", "--lamp-angle", "89"), "--lamp-angle")


def test_exact_transmittance_refined_model_inverts():
    exact = RefinedModel(transmittance="exact")
    # the quadrature against adaptive quadrature of the defining integral (τ = 0.3, in-water μ from μc to 1)
    cf = exact.closed_form()
    tau = 0.3

    def integrand(mu):
        theta_air = np.arcsin(min(1.0, 1.33 * np.sqrt(1 - mu * mu)))
        return (1 - fresnel_reflectance(theta_air)) * mu * np.exp(-tau / mu)

    ref = cf.scale * np.exp(-cf.view_factor * tau) * quad(integrand, cf.mu_c, 1.0, epsabs=0, epsrel=1e-12)[0]
    # T(θ_air) has a square-root edge at the critical angle: 128 Gauss-Legendre nodes give 2e-7 there
    assert cf.ratio(tau) == pytest.approx(ref, rel=1e-6)
    for d in (0.1, 0.3, 1.0):
        r = exact.ratio(C_MOL, d)
        for method in ("table", "newton"):
            inv = invert_ratio(r, exact, d, method=method)
            np.testing.assert_allclose(inv.c_mol_per_L, C_MOL, rtol=1e-9)
    # the mean-T model reading exact-T data: the cost of T̄ (under-reads by a few per cent at 1e-7 mol/L)
    mean_reading = invert_ratio(exact.ratio(1e-7, 0.3), RefinedModel(), 0.3).c_mol_per_L
    assert 0.005 < abs(mean_reading / 1e-7 - 1) < 0.2


def test_exact_refined_through_the_cli():
    proc = run_cli("water", "forward", "--json", "--concentration", "1e-7mol/L", "--depth", "0.3m", "--water-model",
                   "refined", "--transmittance", "exact")
    r = json.loads(proc.stdout)["ratio"][0][0]
    assert r == pytest.approx(float(RefinedModel(transmittance="exact").ratio(1e-7, 0.3)), rel=1e-12)
    proc = run_cli("water", "invert", "--json", "--ratio", repr(r), "--depth", "0.3m", "--water-model", "refined",
                   "--transmittance", "exact")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["c_mol_per_L"][0] == pytest.approx(1e-7, rel=1e-9) and out["transmittance"] == "exact"


def test_band_aware_lamp_round_trip_and_narrowband_reading():
    cam = SyntheticCamera(SensorParams(width=64, height=64))
    geom = LampModel(1.0, np.radians(20))
    band = BandModel(WAVELENGTHS_NM, cam.spectral_sensitivity()[0], geometry=geom,
                     illuminant=illuminant_spectrum("lamp", WAVELENGTHS_NM))
    assert band.describe()["water_absorption"] == "Pope & Fry 1997"
    c = np.array([5.0, 50.0, 200.0, 1000.0])
    for d in (0.1, 0.3, 0.5):
        inv = band.inverse(d).concentration(band.ratio(c, d))
        np.testing.assert_allclose(inv.c_ug_per_L, c, rtol=1e-7)
    # the lamp's spectrum matters: the same ratio read with daylight's is biased
    d65 = BandModel(WAVELENGTHS_NM, cam.spectral_sensitivity()[0], geometry=geom,
                    illuminant=illuminant_spectrum("D65", WAVELENGTHS_NM))
    c_d65 = d65.inverse(0.5).concentration(band.ratio(200.0, 0.5)).c_ug_per_L
    assert abs(c_d65 / 200.0 - 1) > 0.01


def test_illuminant_names_and_lamp_csv(tmp_path):
    wl = WAVELENGTHS_NM
    lamp = illuminant_spectrum("lamp", wl)
    np.testing.assert_allclose(lamp, illuminant_spectrum("3200K", wl), rtol=1e-4)  # shipped table = Planck
    assert np.nanmax(lamp) == 1.0 and lamp[0] < lamp[-1]  # a tungsten lamp is red-rich
    f = tmp_path / "lamp.csv"
    f.write_text("# measured\nwavelength_nm,relative_radiance\n400,0.2\n700,1.0\n")
    s = illuminant_spectrum(str(f), wl)
    assert np.isnan(s[0]) and s[np.searchsorted(wl, 550)] == pytest.approx(0.6)
    f.write_text("wavelength_nm,relative_radiance\n400,-1\n700,1\n")
    with pytest.raises(CamcalError, match=">= 0"):
        illuminant_spectrum(str(f), wl)
    with pytest.raises(CamcalError, match="unknown illuminant"):
        illuminant_spectrum("candle", wl)


def test_per_pixel_geometry_narrowband_is_exact():
    """Each pixel's own lamp geometry: random pixels of a ratio image made pixel by pixel are read back to 1e-9."""
    from dataclasses import replace

    from camcal.water.lampfield import PixelGeometry, invert_per_pixel
    from camcal.water.models import lamp_angle_reaching

    lamp = LampModel(0.5, np.radians(30))
    geom = PixelGeometry(0.002, (63.5, 47.5), 180.0)
    x = geom.distances_m((96, 128), lamp, 0.3)
    idx = np.random.default_rng(0).integers(0, x.size, 60)
    r = np.full(x.shape, np.nan)
    for i in idx:
        r.flat[i] = replace(lamp, lamp_angle_rad=lamp_angle_reaching(0.5, 0.3, float(x.flat[i]))).ratio(1e-7, 0.3)
    inv = invert_per_pixel(r, lamp, 0.3, geom, sigma_ln_ratio=0.01)
    np.testing.assert_allclose(inv.c_mol_per_L.flat[idx], 1e-7, rtol=1e-9)
    assert np.all(inv.reason.flat[idx] == 0) and np.all(inv.sigma_ug_per_L.flat[idx] > 0)
    # the centre's geometry on the same pixels: off by up to ±2 % at 13 cm from the centre
    centre = invert_ratio(r, lamp, 0.3).c_mol_per_L.flat[idx]
    assert 0.01 < np.max(np.abs(centre / 1e-7 - 1)) < 0.05
    # the lamp's direction matters: the lamp on the other side mirrors the error
    mirrored = invert_per_pixel(r, lamp, 0.3, PixelGeometry(0.002, (63.5, 47.5), 0.0))
    assert np.max(np.abs(mirrored.c_mol_per_L.flat[idx] / 1e-7 - 1)) > 0.02
    with pytest.raises(CamcalError, match="lamp model"):
        invert_per_pixel(r, RefinedModel(), 0.3, geom)


def test_per_pixel_geometry_through_the_cli(tmp_path):
    from dataclasses import replace

    from camcal.io.exr import read_exr, write_exr
    from camcal.water.lampfield import PixelGeometry
    from camcal.water.models import lamp_angle_reaching

    lamp = LampModel(0.5, np.radians(30))
    geom = PixelGeometry(0.004, (15.5, 11.5), 180.0)
    x = geom.distances_m((24, 32), lamp, 0.3)
    xs = np.unique(x)
    rs = {v: float(replace(lamp, lamp_angle_rad=lamp_angle_reaching(0.5, 0.3, float(v))).ratio(1e-7, 0.3)) for v in xs}
    sub = np.vectorize(rs.get)(x).astype(np.float32)
    write_exr(tmp_path / "s.exr", {"L663": sub})
    write_exr(tmp_path / "r.exr", {"L663": np.ones_like(sub)})
    args = ["water", "invert", "--submerged", tmp_path / "s.exr", "--reference", tmp_path / "r.exr", "--depth", "0.3m",
            "--water-model", "lamp", "--lamp-height", "0.5m", "--lamp-angle", "30"]
    proc = run_cli(*args, "--disk-pixel-size", "4mm", "--disk-centre-px", "15.5,11.5", "-o", tmp_path / "c.exr")
    assert proc.returncode == 0, proc.stderr
    ch, meta = read_exr(tmp_path / "c.exr", ["chl_ug_per_L"])
    assert meta["lamp_geometry"]["per_pixel"] is True
    np.testing.assert_allclose(ch["chl_ug_per_L"], 89.35, rtol=2e-6)  # float32 ratios
    proc = run_cli(*args, "-o", tmp_path / "c2.exr")
    ch2, meta2 = read_exr(tmp_path / "c2.exr", ["chl_ug_per_L"])
    assert meta2["lamp_geometry"]["per_pixel"] is False and np.max(np.abs(ch2["chl_ug_per_L"] / 89.35 - 1)) > 0.01
    assert_one_line_error(run_cli(*args, "--disk-pixel-size", "4mm", "-o", tmp_path / "c3.exr"), "--disk-centre-px")


def test_epsilon_unc_as_percent_or_fraction():
    r = repr(float(LampModel(1.0, 0.2).ratio(1e-7, 0.3)))
    base = ["water", "invert", "--json", "--ratio", r, "--depth", "0.3m", "--water-model", "lamp", "--lamp-height",
            "1m", "--lamp-angle", str(np.degrees(0.2))]
    a = json.loads(run_cli(*base, "--epsilon-unc", "3%").stdout)["sigma_terms_ug_per_L"]["epsilon"][0]
    b = json.loads(run_cli(*base, "--epsilon-unc", "0.03").stdout)["sigma_terms_ug_per_L"]["epsilon"][0]
    assert a == pytest.approx(b) and a == pytest.approx(0.03 * 89.35, rel=0.01)
    assert_one_line_error(run_cli(*base, "--epsilon-unc", "lots"), "--epsilon-unc")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=1, max_size=8),
       st.floats(allow_nan=False, allow_infinity=False), st.sampled_from(["table", "newton"]), st.booleans())
def test_lamp_and_exact_models_any_finite_input(ratio, depth, method, lamp):
    """The same safeguards as the other models: no exception, NaN exactly where a reason is given."""
    model = LampModel(0.8, 0.3) if lamp else RefinedModel(transmittance="exact")
    inv = invert_ratio(np.asarray(ratio), model, depth, sigma_ln_ratio=0.01, method=method)
    check_inversion(inv, ratio, np.asarray(depth, float))

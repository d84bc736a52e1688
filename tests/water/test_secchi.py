"""Secchi-disk scenes: real DNG photos of a reference and a submerged disk, their ratio, and chlorophyll-a back."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import binary_erosion

from camcal.errors import CamcalError
from camcal.io.read import load_frame
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.secchi import daylight_white_radiance, disk_weight, secchi_scenes, suggest_exposure_s
from camcal.water import BandModel, RefinedModel, bricaud_1998, illuminant_spectrum, invert_images
from camcal.water.purewater import pure_water_absorption_per_m

C_UG_PER_L = 60.0  # eutrophic water
DEPTH_M = 0.8  # d ln B_R / d ln C ≈ −0.3 here: 1 % in the ratio is ≈ 3 % in C


@pytest.fixture(scope="module")
def cam() -> SyntheticCamera:
    return SyntheticCamera(SensorParams(width=256, height=192, seed=3))


@pytest.fixture(scope="module")
def scenes(cam):
    return secchi_scenes(cam, c_ug_per_L=C_UG_PER_L, depth_m=DEPTH_M, radius_fraction=0.6)


@pytest.fixture(scope="module")
def rates(cam, scenes, tmp_path_factory):
    """Dark-subtracted R-plane DN rates of both photos (real DNGs decoded by LibRaw), and the disk interior."""
    tmp = tmp_path_factory.mktemp("secchi")
    rng = np.random.default_rng(2024)

    def shoot(name: str, scene: Scene, t: float, n: int = 1) -> np.ndarray:
        planes = [load_frame(cam.write_dng(tmp / f"{name}{k}.dng", scene, exposure_s=t, rng=rng)).planes()[0]
                  for k in range(n)]
        return np.mean(planes, axis=0, dtype=np.float64)

    t_ref = suggest_exposure_s(cam, scenes.reference_radiance)
    t_sub = suggest_exposure_s(cam, scenes.submerged_radiance)  # longer: the submerged disk is darker
    ref = (shoot("ref", scenes.reference, t_ref) - shoot("dark_ref", Scene.dark(), t_ref, 4)) / t_ref
    sub = (shoot("sub", scenes.submerged, t_sub) - shoot("dark_sub", Scene.dark(), t_sub, 4)) / t_sub
    inside = binary_erosion(scenes.weight[0::2, 0::2] >= 1.0, iterations=2)  # R plane of RGGB, edge pixels off
    return sub, ref, inside


def test_scene_structure(cam, scenes):
    t = scenes.truth
    assert t["c_ug_per_L"] == C_UG_PER_L and t["depth_m"] == DEPTH_M and t["model"] == "refined"
    assert t["c_mol_per_L"] == pytest.approx(C_UG_PER_L / 893.5e6)
    h, w = cam.params.height, cam.params.width
    assert scenes.weight.shape == (h, w)
    assert scenes.weight[h // 2, w // 2] == 1.0 and scenes.weight[0, 0] == 0.0
    assert scenes.weight.sum() == pytest.approx(np.pi * t["disk_radius_px"] ** 2, rel=0.01)
    # the submerged disk is rendered independently of the inversion (numerical integration over sky angles,
    # Fresnel per ray): it equals the exact-transmittance model's quadrature to 3e-7 and differs from the
    # mean-T̄ closed form the inversion uses by up to +1.4 % at this depth (the approximation's real cost)
    assert t["renderer"] == "independent"
    r_lambda = scenes.submerged_radiance / scenes.reference_radiance
    chl = bricaud_1998().on(WAVELENGTHS_NM).absorption_per_m(C_UG_PER_L)
    tau = (pure_water_absorption_per_m(WAVELENGTHS_NM) + chl) * DEPTH_M
    np.testing.assert_allclose(r_lambda, RefinedModel(transmittance="exact").closed_form().ratio(tau), rtol=3e-7)
    closed = scenes.band_model.spectral_ratio(C_UG_PER_L, DEPTH_M)
    assert 0.0 <= np.min(r_lambda / closed - 1) and np.max(r_lambda / closed - 1) < 0.02
    assert np.all(scenes.submerged_radiance < scenes.reference_radiance)
    cf = secchi_scenes(cam, c_ug_per_L=C_UG_PER_L, depth_m=DEPTH_M, radius_fraction=0.6, renderer="closed-form")
    np.testing.assert_allclose(cf.submerged_radiance, closed * cf.reference_radiance)
    assert cf.truth["rendered_red_band_ratio"] == pytest.approx(cf.truth["predicted_red_band_ratio"], rel=1e-4)
    # daylight: D65 scaled to 1.2 W m^-2 nm^-1 at 560 nm, white radiance E/π; disk albedo 0.85
    assert np.interp(560.0, WAVELENGTHS_NM, daylight_white_radiance()) == pytest.approx(1.2 / np.pi)
    assert t["reference_disk_radiance_560_W_m2_sr_nm"] == pytest.approx(0.85 * 1.2 / np.pi)
    # the predicted band ratio is what the camera integrates (its own quadrature): agreement to 1e-4
    rates_e = cam.channel_rates_e(scenes.submerged_radiance, 4.0) / cam.channel_rates_e(scenes.reference_radiance, 4.0)
    np.testing.assert_allclose(rates_e, [t["rendered_band_ratio"][k] for k in "RGB"], rtol=1e-4)
    assert 0 < t["predicted_red_band_ratio"] < 0.45  # below the clear-water C = 0 value of the refined model
    # the closed form's band ratio (mean T̄) under-predicts the rendered one by < 1 % in the red band here
    assert 0 < t["rendered_red_band_ratio"] / t["predicted_red_band_ratio"] - 1 < 0.01


def test_disk_weight_and_errors():
    wgt = disk_weight((64, 64), 10.0, (20.0, 30.0))
    assert wgt[30, 20] == 1.0 and wgt[30, 31] == 0.0 and 0 < wgt[30, 30] < 1
    cam = SyntheticCamera(SensorParams(width=64, height=64))
    for kwargs, frag in [({"c_ug_per_L": -1.0, "depth_m": 1.0}, ">= 0"), ({"c_ug_per_L": 1.0, "depth_m": 0.0}, "depth"),
                         ({"c_ug_per_L": 1.0, "depth_m": 1.0, "background_albedo": 0.9}, "albedo"),
                         ({"c_ug_per_L": 1.0, "depth_m": 1.0, "model": "lamp"}, "water model"),
                         ({"c_ug_per_L": 1.0, "depth_m": 1.0, "renderer": "magic"}, "renderer")]:
        with pytest.raises(CamcalError, match=frag):
            secchi_scenes(cam, **kwargs)


def test_rendered_ratio_matches_band_prediction(scenes, rates):
    sub, ref, inside = rates
    assert inside.sum() > 1500
    measured = sub[inside].sum() / ref[inside].sum()  # PRNU and vignetting cancel pixel by pixel
    per_pixel = sub[inside] / ref[inside]
    # noise: shot + read noise of one photo each (≈ 1.5 % per pixel); 4 standard errors of the mean
    sem = per_pixel.std() / per_pixel.mean() / np.sqrt(inside.sum())
    assert sem < 1e-3
    assert measured / scenes.truth["rendered_red_band_ratio"] - 1 == pytest.approx(0.0, abs=4 * sem)


def test_round_trip_chlorophyll_from_photos(cam, rates):
    """C → independently rendered photos → per-pixel band inversion (mean-T̄ closed form) on DN rates → C,
    within 5 % (median over the disk; measured −1.1 %: the mean-T̄ approximation, not the noise)."""
    sub, ref, inside = rates
    # what a user knows: the camera's red c(λ), daylight D65, the refined model with Pope & Fry water
    band = BandModel(WAVELENGTHS_NM, cam.spectral_sensitivity()[0], geometry=RefinedModel(),
                     illuminant=illuminant_spectrum("D65", WAVELENGTHS_NM))
    inv = invert_images(sub, ref, band, DEPTH_M)
    c = inv.c_ug_per_L[inside]
    assert np.all(inv.reason[inside] == 0)
    # per-pixel ratio noise ≈ 1.5 % → ≈ 5 % per pixel in C; the median of > 1500 pixels is good to ≈ 0.2 %
    assert np.median(c) == pytest.approx(C_UG_PER_L, rel=0.05)
    # the exact-transmittance model (T(θ) inside the integral, as the renderer) removes the mean-T̄ bias:
    # measured 59.34 µg/L (−1.1 %) with T̄ and 59.99 (−0.01 %) with T(θ)
    ex = BandModel(WAVELENGTHS_NM, cam.spectral_sensitivity()[0], geometry=RefinedModel(transmittance="exact"),
                   illuminant=illuminant_spectrum("D65", WAVELENGTHS_NM))
    c_exact = np.median(invert_images(sub, ref, ex, DEPTH_M).c_ug_per_L[inside])
    assert c_exact == pytest.approx(C_UG_PER_L, rel=0.01)
    assert abs(c_exact - C_UG_PER_L) < abs(np.median(c) - C_UG_PER_L)
    assert np.std(c) / C_UG_PER_L < 0.15
    # the flat-light band model (wrong illuminant) is biased: the light's spectrum matters at this sensitivity
    flat = BandModel(WAVELENGTHS_NM, cam.spectral_sensitivity()[0], geometry=RefinedModel())
    c_flat = np.median(invert_images(sub, ref, flat, DEPTH_M).c_ug_per_L[inside])
    assert abs(c_flat / C_UG_PER_L - 1) > abs(np.median(c) / C_UG_PER_L - 1)

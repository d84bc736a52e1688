"""The synthetic phone (camcal.synth.phone): measured curves not in the library, real DNG and HEIC files whose
pixels equal the truth computed here from the shipped table, the sun and the stated parameters."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pillow_heif
import pvlib
import pytest
import rawpy

from camcal.errors import CamcalError
from camcal.io.read import read_photo_metadata
from camcal.synth.camera import Scene
from camcal.synth.exif import PlaceTime
from camcal.synth.phone import (
    DEFAULT_PLACE,
    PhoneCamera,
    PhoneParams,
    chart_reflectances,
    chart_scene,
    phone_sensitivities,
    sun_sky_at,
    write_phone_photos,
)
from tests.conftest import assert_one_line_error, run_cli

ROOT = Path(__file__).resolve().parents[2]
H_PLANCK, C_LIGHT = 6.62607015e-34, 299792458.0
WL = np.arange(380.0, 781.0, 1.0)


@pytest.fixture(scope="module")
def day(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("phone")
    truth = write_phone_photos(out, PhoneCamera(), depths_m=(1.0,), n_flats=2, seed=4)
    return out, truth


def _table(sensor: str) -> tuple[np.ndarray, np.ndarray]:
    path = ROOT / "calibration_data" / "camera_curves" / "phone" / f"{sensor}_qe_400_700_1.csv"
    values = np.loadtxt(path, delimiter=",", comments="#", skiprows=5)
    return values[:, 0], values[:, 1:].T / 100.0


def _true_c(truth: dict) -> np.ndarray:
    """c_i(λ) (DN s⁻¹ per W m⁻² sr⁻¹ nm⁻¹ per nm) from the shipped table and the stated parameters alone:
    A π/(4N²) τ QE_i λ/(hc) / K, QE_i = qe_peak · q_i T / max(q T), T the logistic UV-IR-cut filter."""
    ph = truth["camera"]["phone"]
    wl_tab, q = _table(ph["sensor"])
    filt = 1.0 / (1.0 + np.exp((ph["uv_cut_nm"] - WL) / 5.0)) / (1.0 + np.exp((WL - ph["ir_cut_nm"]) / 7.0))
    qt = np.stack([np.interp(WL, wl_tab, qi) for qi in q]) * filt
    qe = ph["qe_peak"] * qt / qt.max()
    area = (ph["pixel_pitch_um"] * 1e-6) ** 2
    return (area * np.pi / (4 * ph["f_number"] ** 2) * ph["lens_transmittance"] * qe * (WL * 1e-9)
            / (H_PLANCK * C_LIGHT) / ph["gain_e_per_dn"])


def _light(truth: dict) -> np.ndarray:
    """DNI cos θ + DHI on a horizontal surface from pvlib's SPECTRL2 with the truth's sky, W m⁻² nm⁻¹."""
    s = truth["sky"]
    z = s["sun_zenith_deg"]
    sp = pvlib.spectrum.spectrl2(apparent_zenith=z, aoi=z, surface_tilt=0.0, ground_albedo=0.06,
                                 surface_pressure=s["pressure_Pa"],
                                 relative_airmass=float(pvlib.atmosphere.get_relative_airmass(z)),
                                 precipitable_water=s["precipitable_water_cm"], ozone=s["ozone_atm_cm"],
                                 aerosol_turbidity_500nm=s["aerosol_optical_depth_500nm"], dayofyear=s["day_of_year"])
    wl = np.asarray(sp["wavelength"], float)
    dni = np.interp(WL, wl, np.asarray(sp["dni"], float).ravel())
    dhi = np.interp(WL, wl, np.asarray(sp["dhi"], float).ravel())
    return dni * np.cos(np.radians(z)) + dhi


def _cos4(truth: dict, xx: np.ndarray, yy: np.ndarray) -> np.ndarray:
    ph = truth["camera"]["phone"]
    w, h = ph["width"], ph["height"]
    cx, cy = ph["optical_centre"][0] * (w - 1), ph["optical_centre"][1] * (h - 1)
    rmax = max(np.hypot(x - cx, y - cy) for x in (0, w - 1) for y in (0, h - 1))
    r = np.hypot(xx - cx, yy - cy) / rmax
    return (1.0 + r**2 * np.tan(np.radians(ph["corner_field_angle_deg"])) ** 2) ** -2


def _planes(path: Path) -> tuple[dict[str, list[np.ndarray]], dict[str, list[tuple[int, int]]]]:
    """Raw DN (float) of each colour's Bayer positions and the (row, col) offsets of each, from LibRaw."""
    with rawpy.imread(str(path)) as raw:
        img = raw.raw_image_visible.astype(float)
        desc = raw.color_desc.decode()
        pattern = raw.raw_pattern.copy()
    planes: dict[str, list[np.ndarray]] = {"R": [], "G": [], "B": []}
    offs: dict[str, list[tuple[int, int]]] = {"R": [], "G": [], "B": []}
    for r in range(2):
        for c in range(2):
            ch = desc[pattern[r, c]]
            planes[ch].append(img[r::2, c::2])
            offs[ch].append((r, c))
    return planes, offs


def _rate_over(truth, path, exposure_s, ch, rows, cols) -> float:
    """Mean of (DN − black)/(t g) of channel ``ch`` over full-resolution rows × cols, g the cos⁴ falloff."""
    planes, offs = _planes(path)
    black = truth["camera"]["phone"]["black_level_dn"]
    vals = []
    for plane, (r0, c0) in zip(planes[ch], offs[ch], strict=True):
        rr = np.arange(plane.shape[0]) * 2 + r0
        cc = np.arange(plane.shape[1]) * 2 + c0
        sel_r = (rr >= rows[0]) & (rr < rows[1])
        sel_c = (cc >= cols[0]) & (cc < cols[1])
        yy, xx = np.meshgrid(rr[sel_r], cc[sel_c], indexing="ij")
        vals.append((plane[np.ix_(sel_r, sel_c)] - black) / (exposure_s * _cos4(truth, xx, yy)))
    return float(np.mean(np.concatenate([v.ravel() for v in vals])))


# ---- curves ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("sensor", ["imx219", "ov5647"])
def test_phone_curves_are_not_any_library_camera(sensor):
    """Each shipped phone sensor differs from every one of the 52 library cameras by more than 5 % of the peak
    (RMS, worst channel): an estimator meets a camera it has not seen."""
    wl = np.arange(380.0, 781.0, 5.0)
    c = phone_sensitivities(sensor, wl).rgb
    np.testing.assert_allclose(c.max(axis=1), 1.0)
    files = sorted((ROOT / "calibration_data" / "camera_curves" / "rawtoaces").glob("*_380_780_5.json"))
    assert len(files) == 52
    worst = []
    for f in files:
        main = json.loads(f.read_text())["spectral_data"]["data"]["main"]
        w = np.array([float(k) for k in main])
        v = np.array([main[k] for k in main], float)[np.argsort(w)]
        lib = np.stack([np.interp(wl, np.sort(w), v[:, i]) for i in range(3)])
        lib /= lib.max(axis=1, keepdims=True)
        worst.append(np.sqrt(np.mean((lib - c) ** 2, axis=1)).max())
    assert min(worst) > 0.05, min(worst)


def test_bare_sensor_is_the_table_and_the_filter_cuts_ir():
    wl_tab, q = _table("imx219")
    bare = phone_sensitivities("imx219", wl_tab, uv_cut_nm=None, ir_cut_nm=None)
    np.testing.assert_allclose(bare.rgb, q / q.max(axis=1, keepdims=True), rtol=1e-12)
    phone = phone_sensitivities("imx219")
    assert phone.r[WL == 700][0] < 0.01 < bare.r[-1]  # the hot mirror removes the sensor's 50 % red at 700 nm
    with pytest.raises(CamcalError, match="unknown phone sensor"):
        phone_sensitivities("nokia")


# ---- files ----------------------------------------------------------------------------------------------------

def test_dng_is_real_10_bit_with_the_phone_exif(day):
    out, truth = day
    shot = truth["chart"]["shots"][0]
    path = out / shot["files"]["dng"]
    with rawpy.imread(str(path)) as raw:
        assert raw.white_level == 1023
        assert list(raw.black_level_per_channel) == [64, 64, 64, 64]
        assert raw.raw_image_visible.shape == (400, 600)
        assert raw.raw_image_visible.max() <= 1023
    for p in (path, out / shot["files"]["heic"]):
        e = read_photo_metadata(p)
        assert e.f_number == pytest.approx(1.8) and e.iso == 50
        assert e.exposure_s == pytest.approx(shot["exposure_s"], rel=1e-6)
        assert e.gps_time_utc == "2026-06-21T10:30:00+00:00" and e.utc_offset == "+02:00"
        assert e.capture_time == "2026-06-21T12:30:00"
        assert (e.latitude_deg, e.longitude_deg) == pytest.approx((46.45, 6.55), abs=1e-6)
        assert e.model == "Synthetic Phone IMX219"
    heif = pillow_heif.open_heif(str(out / shot["files"]["heic"]))
    assert heif.size == (600, 400) and heif.mode == "RGB" and heif.info["bit_depth"] == 8


def test_grey_field_signal_equals_the_independent_truth(day):
    """Centre of the sunlit grey field, per channel: (DN − black)/(t cos⁴) = ∫ c ρ E/π dλ with c from the shipped
    table and E from SPECTRL2 here. Noise: ~2100 e⁻ per pixel over 256 pixels per plane is 0.15 %; 0.6 % is 4σ."""
    out, truth = day
    g = truth["grey"]
    c = _true_c(truth)
    radiance = np.asarray(g["reflectance"]) * _light(truth) / np.pi
    np.testing.assert_allclose(radiance, g["radiance_W_m2_sr_nm"], rtol=1e-9)
    expected = np.trapezoid(c * radiance, WL, axis=1)
    for i, ch in enumerate("RGB"):
        got = _rate_over(truth, out / g["files"]["dng"], g["exposure_s"], ch, (184, 216), (284, 316))
        assert got == pytest.approx(expected[i], rel=0.006), ch
        assert g["dn_rate_on_axis"][ch] == pytest.approx(expected[i], rel=1e-6)


def test_vignetting_is_cos4_to_040_in_the_corners(day):
    """The flats' falloff against the cos⁴ law of a 37.4° corner field angle: rings at r = 0.3 … 0.95 and the
    corners, within 1 % (the polynomial represents cos⁴ to 1e-4; the noise of a ring is below 0.1 %)."""
    out, truth = day
    vig = truth["camera"]["vignetting"]
    assert vig["corner_gain"] == pytest.approx(0.398, abs=0.002)
    planes = [_planes(out / s["files"]["dng"])[0]["G"] for s in truth["flat"]["shots"]]
    g_img = np.mean([np.mean(p, axis=0) for p in planes], axis=0) - 64.0  # G1 and G2 at almost the same place
    yy, xx = np.mgrid[0:200, 0:300] * 2.0 + 0.5
    model = _cos4(truth, xx, yy)
    cx, cy = 299.5, 199.5
    r = np.hypot(xx - cx, yy - cy) / np.hypot(cx, cy)
    centre = g_img[r < 0.05].mean() / model[r < 0.05].mean()
    for lo, hi in ((0.28, 0.32), (0.58, 0.62), (0.88, 0.92), (0.95, 1.01)):
        ring = (r >= lo) & (r < hi)
        assert g_img[ring].mean() / centre == pytest.approx(model[ring].mean(), rel=0.01), (lo, hi)
    assert g_img[r > 0.97].mean() / centre == pytest.approx(0.40, abs=0.015)


def test_heic_is_the_stated_pipeline_of_the_raw(day):
    """The grey field's HEIC at the centre: the truth's linear value through the stated white balance, colour
    matrix and sRGB curve (colour-science), within 1.5 of 255."""
    import colour

    out, truth = day
    g, proc = truth["grey"], truth["camera"]["processing"]
    lin = np.asarray([g["dn_rate_on_axis"][ch] for ch in "RGB"]) * g["exposure_s"] / (1023 - 64)
    lin = np.clip(lin * np.asarray(proc["white_balance"]), 0, 1)
    lin = np.clip(np.asarray(proc["colour_matrix"]) @ lin, 0, 1)
    expected = 255 * colour.cctf_encoding(lin, function="sRGB")
    img = np.asarray(pillow_heif.open_heif(str(out / g["files"]["heic"])), float)
    got = img[190:210, 290:310].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(got, expected, atol=1.5)
    assert np.ptp(expected) < 25  # a grey field stays near grey through the daylight white balance


def test_chart_is_where_the_truth_says_and_a_detector_finds_it(day):
    """Patches' raw signal over their interior equals the truth's rate × the falloff there; the card's corners
    are in the image; colour-checker-detection finds one chart centred on the truth's grid."""
    import colour
    import colour_checker_detection as ccd

    out, truth = day
    chart, shot = truth["chart"], truth["chart"]["shots"][0]
    assert chart["reflectance_name"] == "ColorChecker N Ohta"
    corners = np.asarray(chart["card_corners_px"])
    assert np.all((corners >= 0) & (corners <= [599, 399]))
    for k in (18, 19, 21):  # white, neutral 8, neutral 5: every channel well exposed
        p = chart["patches"][k]
        cx, cy = p["centre_px"]
        half = 0.25 * np.min(np.ptp(np.asarray(p["corners_px"]), axis=0))
        rows, cols = (int(cy - half), int(cy + half)), (int(cx - half), int(cx + half))
        for ch in "RGB":
            got = _rate_over(truth, out / shot["files"]["dng"], shot["exposure_s"], ch, rows, cols)
            assert got == pytest.approx(p["dn_rate_on_axis"][ch], rel=0.02), (p["name"], ch)
    img = np.asarray(pillow_heif.open_heif(str(out / shot["files"]["heic"])), float) / 255.0
    found = ccd.detect_colour_checkers_segmentation(colour.cctf_decoding(img, function="sRGB"), additional_data=True)
    assert len(found) == 1
    scale = 600 / 1440  # the detector works at 1440 pixels across
    centre = np.asarray(found[0].quadrilateral, float).mean(axis=0) * scale
    assert np.hypot(*(centre - np.asarray(chart["grid_corners_px"]).mean(axis=0))) < 10


def test_secchi_ratio_in_the_dng_is_the_rendered_one(day):
    out, truth = day
    sec = truth["secchi"]["shots"][0]
    t = sec["truth"]
    files = sec["files"]
    cx, cy = t["disk_centre_px"]
    rows, cols = (int(cy) - 20, int(cy) + 20), (int(cx) - 20, int(cx) + 20)
    for ch in "RG":
        ref = _rate_over(truth, out / files["ref"]["dng"], files["exposure_s"]["ref"], ch, rows, cols)
        sub = _rate_over(truth, out / files["sub"]["dng"], files["exposure_s"]["sub"], ch, rows, cols)
        expected = t["rendered_band_ratio"][ch] + t["reflected_over_reference"][ch]
        assert sub / ref == pytest.approx(expected, rel=0.01), ch
    assert truth["secchi"]["c_ug_per_L"] == 5.0


# ---- parameters and CLI ---------------------------------------------------------------------------------------

def test_the_aperture_is_fixed_and_parameters_are_checked(tmp_path):
    cam = PhoneCamera(PhoneParams(width=128, height=96))
    with pytest.raises(CamcalError, match="fixed at f/1.8"):
        cam.write_dng(tmp_path / "x.dng", Scene.dark(), exposure_s=0.01, f_number=4.0, rng=np.random.default_rng(0))
    with pytest.raises(CamcalError, match="tone curve"):
        PhoneParams(tone="log")
    sky = sun_sky_at(DEFAULT_PLACE)
    _, rho = chart_reflectances("BabelColor Average")
    perturbed = chart_scene(cam, sky, reflectance=rho * 1.03)  # a chart 3 % brighter than the average
    nominal = chart_scene(cam, sky, reflectance="BabelColor Average")
    np.testing.assert_allclose(perturbed.patch_radiance, 1.03 * nominal.patch_radiance, rtol=1e-12)
    assert perturbed.truth["reflectance_name"] == "given" and len(perturbed.truth["patch_reflectance"]) == 24
    with pytest.raises(CamcalError, match="24 rows"):
        chart_scene(cam, sky, reflectance=rho[:, :100])
    with pytest.raises(CamcalError, match="GPS position"):
        write_phone_photos(tmp_path / "p", cam, place=PlaceTime(DEFAULT_PLACE.utc))
    assert not (tmp_path / "p").exists()


def test_cli_writes_the_day_and_refuses_bad_input(tmp_path):
    from camcal.cli import main

    assert main(["synth", "phone", str(tmp_path / "d"), "--seed", "3", "--sensor", "ov5647", "--width", "320",
                 "--height", "240", "--depths", "1.5", "--flats", "0", "--formats", "dng", "--tone", "filmic"]) == 0
    truth = json.loads((tmp_path / "d" / "truth.json").read_text())
    assert truth["camera"]["phone"]["sensor"] == "ov5647" and truth["seed"] == 3
    assert sorted(p.name for p in (tmp_path / "d" / "secchi").iterdir()) == ["d1.5m_ref.dng", "d1.5m_sub.dng"]
    proc = run_cli("synth", "phone", tmp_path / "e", "--depths", "0")
    assert_one_line_error(proc, "depths in (0, 20] m")
    assert not (tmp_path / "e").exists()

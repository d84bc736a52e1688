"""HEIC/HEIF photos (issue 26, item 3): read through pillow-heif like JPEG, inspected, measured, applied.

Truth:
- real HEICs (``../shared/realdata/heic``): the tags in ``exif_tags.csv`` (an independent EXIF reader) and the
  facts of the folder's README (size, 8 bits, Display P3, OffsetTimeOriginal only on the iPhone 15 Pro);
- synthetic HEICs: the same synthetic camera, scene and processing as the calibration session's JPEG twins,
  encoded as HEVC by libheif/x265 (8 or 10 bits); their radiance must match the camera's true band radiance
  as the JPEG's does (test_apply.py: 3 %; a whole-frame mean carries ≈0.01 % noise, the processed path's
  de-toning ≈1–2 %, HEVC at quality 97 on a uniform field < 0.5 DN of 255).
"""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from camcal.apply.photo import apply
from camcal.calibrate.inspect import describe
from camcal.calibrate.response import fit_response, measure_response
from camcal.errors import CamcalError
from camcal.io.exr import read_exr
from camcal.io.kinds import is_raw_path
from camcal.io.read import load_frame
from camcal.models.profile import load_profile, save_profile
from camcal.models.spectra import WAVELENGTHS_NM, gaussian_line
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.heic import write_heic
from camcal.synth.session import exposure_for_level
from tests.conftest import assert_one_line_error, run_cli

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "realdata"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason="../shared/realdata is absent")
HEICS = ("iphone7_IMG_2682.heic", "iphone15pro.heic")

LINE_BAND_W_M2_SR = 2.0
LINE = LINE_BAND_W_M2_SR * gaussian_line(663.0, 5.0)


@needs_real
@pytest.mark.parametrize("name", HEICS)
def test_real_heic_described_like_its_tags(name):
    rows = {r["file"]: r for r in csv.DictReader(open(REAL / "exif_tags.csv", encoding="utf-8"))}
    tags = rows[f"heic/{name}"]
    d = describe(REAL / "heic" / name)
    assert (d["kind"], d["layout"], d["format"], d["bit_depth"], d["white_level_dn"]) == (
        "processed", "processed", "heic", 8, 255.0)
    assert (d["width"], d["height"]) == ((4032, 3024) if "iphone7" in name else (3024, 4032))
    assert d["icc_profile"] == "Display P3"
    assert d["make"] == tags["make"] and d["model"] == tags["model"]
    assert d["exposure_s"] == pytest.approx(float(tags["exposure_time_tag"]), rel=1e-6)
    assert d["f_number"] == float(tags["f_number_tag"]) and d["iso"] == float(tags["iso_tag"])
    assert d["capture_time"] == tags["datetime_original_tag"].replace(":", "-", 2).replace(" ", "T")
    assert all(d["sources"][k] == "tag" for k in ("exposure_s", "f_number", "iso", "capture_time", "latitude_deg",
                                                   "longitude_deg", "altitude_m", "gps_time_utc"))
    if name == "iphone15pro.heic":  # 52°27'34.58" N, 13°19'18.63" E; OffsetTimeOriginal +01:00
        assert d["utc_offset"] == "+01:00" and d["sources"]["utc_offset"] == "tag"
        assert d["latitude_deg"] == pytest.approx(52 + 27 / 60 + 34.58 / 3600, abs=1e-9)
        assert d["longitude_deg"] == pytest.approx(13 + 19 / 60 + 18.63 / 3600, abs=1e-9)
        assert d["capture_time_utc"] == "2023-10-31T10:44:43+00:00"
    else:  # 41°13'13.08" N, 96°4'17.85" W; no offset tag; GPS 16:04:21.01 UTC
        assert d["utc_offset"] is None and d["sources"]["utc_offset"] is None
        assert d["latitude_deg"] == pytest.approx(41 + 13 / 60 + 13.08 / 3600, abs=1e-9)
        assert d["longitude_deg"] == pytest.approx(-(96 + 4 / 60 + 17.85 / 3600), abs=1e-9)
        assert d["capture_time_utc"] == "2019-03-21T16:04:21.010000+00:00"
    assert d["time_source"] == "GPS time stamp" and d["sun"]["zenith_deg"] is not None


@needs_real
def test_real_heic_inspect_table():
    proc = run_cli("inspect", REAL / "heic" / "iphone15pro.heic", "--all")
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    for text in ("Apple", "iPhone 15 Pro", "0.0166667 s  (tag)", "2.2  (tag)", "400  (tag)",
                 "2023-10-31T11:44:43  (tag)", "+01:00  (tag)", "(GPS time stamp)", "52.4596", "13.3218",
                 "Display P3", "sun.zenith_deg", "sun.azimuth_deg", "sun.source"):
        assert text in out, text


@pytest.fixture(scope="module")
def profile(profile_path):
    return load_profile(profile_path)


@pytest.fixture(scope="module")
def heic_photos(tmp_path_factory, camera):
    """The session camera's photos of a 663 nm line: as 8-bit and 10-bit HEICs and as a JPEG (written once)."""
    d = tmp_path_factory.mktemp("heic")
    rng = np.random.default_rng(26)
    t = exposure_for_level(camera, LINE, 0.4, 100, 4.0)
    out = {}
    for bits in (8, 10):
        out[bits] = camera.write_heic(d / f"line{bits}.heic", Scene.uniform(LINE), exposure_s=t, iso=100,
                                      f_number=4.0, rng=rng, bits=bits)
    out["jpeg"] = camera.write_jpeg(d / "line.jpg", Scene.uniform(LINE), exposure_s=t, iso=100, f_number=4.0,
                                    rng=rng)
    return out


def true_band(camera: SyntheticCamera, spectrum: np.ndarray) -> np.ndarray:
    c = camera.spectral_sensitivity()
    return np.trapezoid(c * spectrum, WAVELENGTHS_NM, axis=1) / np.trapezoid(c, WAVELENGTHS_NM, axis=1)


@pytest.mark.parametrize("bits", [8, 10])
def test_synthetic_heic_radiance_within_3pct(heic_photos, profile, camera, bits):
    frame = load_frame(heic_photos[bits])
    assert frame.kind == "processed" and frame.white_level_dn == 2**bits - 1
    assert frame.data.dtype == (np.uint8 if bits == 8 else np.uint16)
    img = apply(frame, profile, 663.0, "narrowband")
    assert img.metadata["kind"] == "processed" and img.shape == (128, 192)
    tb = true_band(camera, LINE)
    for i, ch in enumerate("RGB"):
        assert float(np.nanmean(img.channels[ch])) == pytest.approx(tb[i], rel=0.03), (bits, ch)
    assert float(np.nanmean(img.channels["L663_inband"])) == pytest.approx(LINE_BAND_W_M2_SR, rel=0.03)
    scaled = [n for n in img.metadata["notes"] if "values scaled by" in n]
    assert bool(scaled) == (bits == 10)
    # the HEIC and the JPEG of the same scene agree (the same processing; only the codec differs)
    jpg = apply(load_frame(heic_photos["jpeg"]), profile, 663.0, "narrowband")
    assert float(np.nanmean(img.channels["L663_inband"])) == pytest.approx(
        float(np.nanmean(jpg.channels["L663_inband"])), rel=0.01)


def test_value_scale_of_other_bit_depths(profile):
    proc, raw = profile.response["processed"], profile.response["raw"]
    assert proc.white_level_dn == 255.0
    assert proc.value_scale(1023.0) == pytest.approx(255 / 1023)
    assert proc.value_scale(255.0) == 1.0 and proc.value_scale(None) == 1.0 and raw.value_scale(1023.0) == 1.0
    v = np.array([[40.0], [128.0], [200.0]])
    assert np.allclose(proc.linearise(v * 1023 / 255, white_level_dn=1023.0), proc.linearise(v))


def test_heic_exposure_series_through_the_processed_response(tmp_path):
    """The linearity stage's JPEG path with HEIC twins: the de-toned HEIC means are proportional to exposure."""
    cam = SyntheticCamera(SensorParams(width=128, height=96))
    folder = tmp_path / "linearity"
    folder.mkdir()
    rng = np.random.default_rng(5)
    t0 = exposure_for_level(cam, LINE, 0.5, 100, 4.0)
    for i, k in enumerate((0.05, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0)):
        cam.write_dng(folder / f"f{i}.dng", Scene.uniform(LINE), exposure_s=k * t0, iso=100, f_number=4.0, rng=rng)
        cam.write_heic(folder / f"f{i}.heic", Scene.uniform(LINE), exposure_s=k * t0, iso=100, f_number=4.0,
                       rng=rng)
    models = fit_response(measure_response(folder))
    assert set(models) == {"raw", "processed"}
    proc = models["processed"]
    assert proc.white_level_dn == 255.0 and len(proc.points["R"]["x_s"]) == 8
    x = np.asarray(proc.points["R"]["x_s"])
    g = np.asarray(proc.points["R"]["mean_dn"])
    lin = proc.linearise(np.stack([g, g, g]))[0] / x  # constant when the tone curve was recovered
    used = np.asarray(proc.points["R"]["used"], bool)
    assert np.ptp(lin[used]) / np.median(lin[used]) < 0.03  # 8-bit quantisation and the sRGB-form fit: ~1 %


@needs_real
def test_real_heic_apply_writes_radiance(tmp_path, profile):
    """``camcal apply`` on a real iPhone HEIC with a processed-image profile without per-pixel maps.

    The profile is the synthetic session's (RAW + JPEG response, absolute c(λ)) without its dark and flat
    maps, which are the sensor's size: a profile of response and spectral sensitivity alone applies to a
    photo of any size. It is another camera's, so ``--allow-other-camera``; the numbers are not the iPhone's
    radiance, the test checks that a HEIC of 4032x3024 goes through and becomes radiance."""
    bare = dataclasses.replace(profile, dark=None, flat=None)
    prof = save_profile(bare, tmp_path / "bare.camcal")
    photo = REAL / "heic" / "iphone7_IMG_2682.heic"
    out = tmp_path / "out"
    proc = run_cli("apply", tmp_path / "bare.camcal", photo, "-o", out, "--allow-other-camera", "-j", "1")
    assert proc.returncode == 0, proc.stderr
    channels, meta = read_exr(out / f"{photo.name}.exr")
    assert channels["L663"].shape == (1512, 2016)  # half resolution of 3024x4032
    good = np.isfinite(channels["R"])
    assert good.mean() > 0.95  # only saturated pixels (255) are NaN
    good &= np.isfinite(channels["L663"])  # L663 (every channel enters) is NaN where any channel saturated
    # through the colour matrix of another camera, saturated colours may give values below zero
    assert all(np.nanmedian(channels[c]) > 0 for c in "RGB")
    assert float(np.median(channels["L663"][good])) > 0
    assert meta["source_name"] == photo.name and prof.content_sha256
    # the photo's place and time travel with its radiance (for the sun of a later inversion)
    assert meta["exposure"]["gps_time_utc"] == "2019-03-21T16:04:21.010000+00:00"
    assert meta["place"]["latitude_deg"] == pytest.approx(41.2203, abs=1e-6)


def test_heic_detected_by_content_and_damaged_refused(tmp_path):
    p = write_heic(tmp_path / "x.heic", np.full((64, 64, 3), 100, np.uint8))
    renamed = tmp_path / "x.jpg.bin"
    renamed.write_bytes(p.read_bytes())
    assert not is_raw_path(renamed) and load_frame(renamed).kind == "processed"  # the ftyp box, not the name
    broken = tmp_path / "broken.heic"
    broken.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2])
    with pytest.raises(CamcalError) as err:
        load_frame(broken)
    assert str(err.value).startswith(str(broken)) and "\n" not in str(err.value)
    assert_one_line_error(run_cli("inspect", broken), "broken.heic")

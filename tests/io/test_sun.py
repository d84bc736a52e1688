"""The sun from a photo (issue 26, item 2): UTC capture time, GPS position, pvlib's solar position.

Truth:
- real photos (``../shared/realdata``): the tags as an independent EXIF reader (exifread, used directly here)
  sees them, turned into a UTC instant by this test's own code in the documented order (GPS time stamp;
  DateTimeOriginal + OffsetTimeOriginal), and the sun pvlib computes at that instant. camcal's value must agree
  within 0.1° (it reads the same tags through its own parsing, offset handling and time-source choice;
  measured: identical), and within 0.1° of NOAA's solar calculator (Meeus), an algorithm independent of
  pvlib written out here (measured differences ≤ 0.011°);
- synthetic photos: the place and instant the synthetic camera wrote (:class:`camcal.synth.exif.PlaceTime`).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import struct
from datetime import UTC, datetime, timedelta
from fractions import Fraction
from pathlib import Path

import exifread
import numpy as np
import pandas as pd
import pvlib
import pytest

from camcal.errors import CamcalError
from camcal.io.read import load_frame, read_photo_metadata
from camcal.io.sun import (
    SOURCE_GPS,
    SOURCE_OFFSET,
    SOURCE_SESSION,
    parse_sun_option,
    photo_sun,
    photo_time_utc,
    sun_position,
)
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.exif import _ASCII, _IFD, _LONG, _RATIONAL, PlaceTime
from camcal.synth.heic import write_heic
from camcal.synth.session import exposure_for_level
from tests.conftest import assert_one_line_error, run_cli
from tests.oracles import read_session_defaults

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "realdata"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason="../shared/realdata is absent")

TOL_DEG = 0.1  # the target


# ---- independent reading of the real files ---------------------------------------------------------------------
def _ratios(tag) -> list[float]:
    return [float(Fraction(v.num, v.den)) for v in tag.values]


def noaa_sun(utc: datetime, lat: float, lon: float) -> tuple[float, float]:
    """(zenith, azimuth clockwise from north), degrees, by NOAA's solar calculator (Meeus, *Astronomical
    Algorithms*, low-precision Sun, as in NOAA's spreadsheet): an algorithm independent of pvlib's SPA,
    good to about 0.01° for 1900–2100 (no refraction, no parallax, 0.0024°)."""
    rad, deg = np.radians, np.degrees
    jd = (utc - datetime(2000, 1, 1, 12, tzinfo=UTC)).total_seconds() / 86400.0 + 2451545.0
    jc = (jd - 2451545.0) / 36525.0
    l0 = (280.46646 + jc * (36000.76983 + jc * 0.0003032)) % 360
    m = 357.52911 + jc * (35999.05029 - 0.0001537 * jc)
    e = 0.016708634 - jc * (0.000042037 + 0.0000001267 * jc)
    c = (np.sin(rad(m)) * (1.914602 - jc * (0.004817 + 0.000014 * jc)) + np.sin(rad(2 * m)) * (0.019993 - 0.000101 * jc)
         + np.sin(rad(3 * m)) * 0.000289)
    app_long = l0 + c - 0.00569 - 0.00478 * np.sin(rad(125.04 - 1934.136 * jc))
    obliq = 23 + (26 + (21.448 - jc * (46.815 + jc * (0.00059 - jc * 0.001813))) / 60) / 60
    obliq += 0.00256 * np.cos(rad(125.04 - 1934.136 * jc))
    decl = deg(np.arcsin(np.sin(rad(obliq)) * np.sin(rad(app_long))))
    y = np.tan(rad(obliq / 2)) ** 2
    eot_min = 4 * deg(y * np.sin(2 * rad(l0)) - 2 * e * np.sin(rad(m))
                      + 4 * e * y * np.sin(rad(m)) * np.cos(2 * rad(l0))
                      - 0.5 * y * y * np.sin(4 * rad(l0)) - 1.25 * e * e * np.sin(2 * rad(m)))
    minutes = utc.hour * 60 + utc.minute + (utc.second + utc.microsecond / 1e6) / 60
    tst = (minutes + eot_min + 4 * lon) % 1440
    ha = tst / 4 - 180  # hour angle, degrees (tst in [0, 1440) min)
    sl, cl = np.sin(rad(lat)), np.cos(rad(lat))
    zen = deg(np.arccos(sl * np.sin(rad(decl)) + cl * np.cos(rad(decl)) * np.cos(rad(ha))))
    a = deg(np.arccos((sl * np.cos(rad(zen)) - np.sin(rad(decl))) / (cl * np.sin(rad(zen)))))
    az = (a + 180) % 360 if ha > 0 else (540 - a) % 360
    return float(zen), float(az)


def independent_sun(path: Path) -> tuple[float, float, str, tuple[float, float]] | None:
    """(zenith, azimuth, time source, NOAA's (zenith, azimuth)) from exifread tags and pvlib (and NOAA's
    algorithm), or None when the file cannot place the sun."""
    with open(path, "rb") as fh:
        t = exifread.process_file(fh, details=False)
    if "GPS GPSLatitude" not in t or "GPS GPSLongitude" not in t:
        return None
    lat = sum(x / 60**i for i, x in enumerate(_ratios(t["GPS GPSLatitude"])))
    lon = sum(x / 60**i for i, x in enumerate(_ratios(t["GPS GPSLongitude"])))
    lat = -lat if str(t["GPS GPSLatitudeRef"]) == "S" else lat
    lon = -lon if str(t["GPS GPSLongitudeRef"]) == "W" else lon
    alt = _ratios(t["GPS GPSAltitude"])[0] if "GPS GPSAltitude" in t else None
    if "GPS GPSTimeStamp" in t and "GPS GPSDate" in t:
        h, m, s = _ratios(t["GPS GPSTimeStamp"])
        y, mo, d = map(int, str(t["GPS GPSDate"]).split(":"))
        utc = datetime(y, mo, d, tzinfo=UTC) + timedelta(hours=h, minutes=m, seconds=s)
        source = "GPS time stamp"
    elif "EXIF OffsetTimeOriginal" in t:
        local = datetime.strptime(str(t["EXIF DateTimeOriginal"]), "%Y:%m:%d %H:%M:%S")
        sign = -1 if str(t["EXIF OffsetTimeOriginal"])[0] == "-" else 1
        hh, mm = map(int, str(t["EXIF OffsetTimeOriginal"])[1:].split(":"))
        utc = (local - sign * timedelta(hours=hh, minutes=mm)).replace(tzinfo=UTC)
        source = "DateTimeOriginal+OffsetTimeOriginal"
    else:
        return None
    pos = pvlib.solarposition.get_solarposition(pd.DatetimeIndex([utc]), lat, lon, altitude=alt).iloc[0]
    return float(pos["zenith"]), float(pos["azimuth"]), source, noaa_sun(utc, lat, lon)


def _real_photos() -> list[Path]:
    return sorted((REAL / "jpeg").glob("*.jpg")) + sorted((REAL / "heic").glob("*.heic")) if REAL.is_dir() else []


@pytest.fixture(scope="module")
def inspected() -> dict[str, dict]:
    """``camcal inspect --json`` of every real JPEG and HEIC, by the real CLI, once."""
    files = _real_photos()
    proc = run_cli("inspect", "--json", *files)
    assert proc.returncode == 0, proc.stderr
    return {Path(e["file"]).name: e for e in json.loads(proc.stdout)}


@needs_real
def test_real_photos_sun_within_0p1_deg_of_pvlib(inspected):
    placed = 0
    for path in _real_photos():
        entry = inspected[path.name]
        expected = independent_sun(path)
        sun = entry["sun"]
        if expected is None:
            assert sun["zenith_deg"] is None and sun["source"] is None, path.name
            assert "--sun ZENITH,AZIMUTH" in sun["reason"], path.name
            continue
        placed += 1
        zen, az, source, (noaa_zen, noaa_az) = expected
        assert abs(sun["zenith_deg"] - zen) < TOL_DEG, (path.name, sun, zen)
        assert abs(sun["azimuth_deg"] - az) < TOL_DEG, (path.name, sun, az)
        # and an algorithm that is not pvlib's: NOAA's (measured differences ≤ 0.01°)
        assert abs(sun["zenith_deg"] - noaa_zen) < TOL_DEG and abs(sun["azimuth_deg"] - noaa_az) < TOL_DEG
        assert entry["time_source"] == source and sun["source"].startswith(source), (path.name, entry["time_source"])
        assert sun["apparent_zenith_deg"] < sun["zenith_deg"]  # refraction lifts the sun
    assert placed == 3  # the Coolpix JPEG and the two iPhone HEICs hold a GPS position and a GPS time


@needs_real
def test_real_photos_without_gps_ask_for_sun(inspected):
    # the photos with no GPS position: the Canon 40D and SX60 HS write an empty GPS block, the D70 and Jolla none
    for name in ("Canon_40D.jpg", "Nikon_D70.jpg", "canon_hdr_NO.jpg", "jolla.jpg"):
        assert inspected[name]["latitude_deg"] is None and inspected[name]["capture_time_utc"] is None
        with pytest.raises(CamcalError) as err:
            photo_sun(REAL / "jpeg" / name)
        msg = str(err.value)
        assert "\n" not in msg and msg.startswith(str(REAL / "jpeg" / name)) and "--sun ZENITH,AZIMUTH" in msg
        assert "no GPS position" in msg and "no time zone" in msg


@needs_real
def test_coolpix_gps_date_a_day_after_its_local_date_is_flagged(inspected):
    e = inspected["DSCN0010.jpg"]
    # the file's own tags: DateTimeOriginal 2008:10:22 16:28:39, GPS 2008:10:23 14:27:07.24 UTC, no offset
    assert e["capture_time"] == "2008-10-22T16:28:39" and e["utc_offset"] is None
    assert e["capture_time_utc"].startswith("2008-10-23T14:27:07.24")
    assert any("disagrees with the local date" in n and "2008-10-23" in n for n in e["notes"]), e["notes"]
    ct = photo_time_utc(read_photo_metadata(REAL / "jpeg" / "DSCN0010.jpg"))
    assert ct.gps_date_disagrees and ct.source == SOURCE_GPS
    assert ct.implied_offset_min == pytest.approx(-(21 * 60 + 58) - 28.24 / 60 + 0 * 1, abs=0.02)
    # the other photos with a GPS time agree with their clocks: iPhone 7 implies -05:00 (US Central, summer
    # time in March 2019), the iPhone 15 Pro +01:00 as its OffsetTimeOriginal says
    for name, implied in (("iphone7_IMG_2682.heic", -300.0), ("iphone15pro.heic", 60.0)):
        ct = photo_time_utc(read_photo_metadata(REAL / "heic" / name))
        assert not ct.gps_date_disagrees and ct.implied_offset_min == pytest.approx(implied, abs=0.1), name
        assert not ct.notes


@needs_real
def test_real_offset_second_in_order():
    """Without its GPS block the iPhone 15 Pro's time would come from DateTimeOriginal + OffsetTimeOriginal;
    the two sources agree to the second for this file (the instant is the same)."""
    e = read_photo_metadata(REAL / "heic" / "iphone15pro.heic")

    no_gps = dataclasses.replace(e, gps_time_utc=None)
    ct = photo_time_utc(no_gps)
    assert ct.source == SOURCE_OFFSET and ct.utc == datetime(2023, 10, 31, 10, 44, 43, tzinfo=UTC)
    assert photo_time_utc(e).utc == ct.utc


# ---- synthetic photos with GPS and time --------------------------------------------------------------------------
PLACES = {
    "north-east": PlaceTime(datetime(2026, 6, 21, 9, 30, 12, 500000), 120, 47.37123456, 8.54098765, 408.5),
    "south-west": PlaceTime(datetime(2026, 1, 15, 18, 5, 0), -180, -34.6037, -58.3816, 25.0),
}


@pytest.fixture(scope="module")
def small_camera() -> SyntheticCamera:
    return SyntheticCamera(SensorParams(width=64, height=64))


def _write(cam: SyntheticCamera, kind: str, path: Path, place: PlaceTime | None, **kw) -> Path:
    spectrum = np.full(WAVELENGTHS_NM.shape, 0.02)  # W m^-2 sr^-1 nm^-1, grey
    scene = Scene.uniform(spectrum)
    rng = np.random.default_rng(7)
    t = exposure_for_level(cam, spectrum, 0.4, 100, 4.0)
    args = dict(exposure_s=t, iso=100, f_number=4.0, rng=rng, place=place, **kw)
    if kind == "dng":
        return cam.write_dng(path, scene, **args)
    if kind == "linear-dng":
        return cam.write_dng(path, scene, layout="linear", **args)
    if kind == "jpeg":
        return cam.write_jpeg(path, scene, **args)
    if kind == "heic":
        return cam.write_heic(path, scene, **args)
    if kind == "heic10":
        return cam.write_heic(path, scene, bits=10, **args)
    raise ValueError(kind)


KINDS = {"dng": ".dng", "linear-dng": ".dng", "jpeg": ".jpg", "heic": ".heic", "heic10": ".heic"}


@pytest.mark.parametrize("kind", list(KINDS))
@pytest.mark.parametrize("where", list(PLACES))
def test_synthetic_place_and_time_round_trip(tmp_path, small_camera, kind, where):
    place = PLACES[where]
    p = _write(small_camera, kind, tmp_path / f"photo{KINDS[kind]}", place)
    e = load_frame(p).exposure
    # positions are written as deg/min/sec rationals with seconds to 1e-6 (3e-11 deg)
    assert e.latitude_deg == pytest.approx(place.latitude_deg, abs=1e-9)
    assert e.longitude_deg == pytest.approx(place.longitude_deg, abs=1e-9)
    assert e.altitude_m == pytest.approx(place.altitude_m, abs=1e-6)
    assert datetime.fromisoformat(e.gps_time_utc) == place.utc_aware  # GPSTimeStamp seconds to 1 ms
    assert e.capture_time == place.local_time.replace(microsecond=0).isoformat()  # DateTimeOriginal: whole s
    assert e.utc_offset == place.offset
    assert all(e.source(k) == "tag" for k in ("latitude_deg", "longitude_deg", "altitude_m", "gps_time_utc",
                                              "utc_offset", "capture_time"))
    sun = photo_sun(p)
    truth = sun_position(place.utc_aware, place.latitude_deg, place.longitude_deg, place.altitude_m)
    assert sun.zenith_deg == pytest.approx(truth.zenith_deg, abs=1e-6)
    assert sun.azimuth_deg == pytest.approx(truth.azimuth_deg, abs=1e-6)
    noaa = noaa_sun(place.utc_aware, place.latitude_deg, place.longitude_deg)
    assert abs(sun.zenith_deg - noaa[0]) < 0.05 and abs(sun.azimuth_deg - noaa[1]) < 0.05, (sun, noaa)
    assert sun.source == "GPS time stamp + GPS position" and not sun.notes


def test_time_source_order(tmp_path, small_camera):
    base = PLACES["north-east"]

    # 2: no GPS time, OffsetTimeOriginal written
    p = _write(small_camera, "heic", tmp_path / "a.heic", dataclasses.replace(base, write_gps_time=False))
    ct = photo_time_utc(read_photo_metadata(p))
    assert ct.source == SOURCE_OFFSET and ct.utc == base.utc_aware.replace(microsecond=0)  # DateTimeOriginal: s
    # 3: neither; the session's utc_offset
    sub = tmp_path / "s"
    sub.mkdir()
    p = _write(small_camera, "jpeg", sub / "b.jpg", dataclasses.replace(base, write_gps_time=False,
                                                                          write_offset=False))
    with pytest.raises(CamcalError, match="no time zone"):
        photo_sun(p)
    (sub / "session.toml").write_text('utc_offset = "+02:00"\n')
    e = read_photo_metadata(p)
    assert e.utc_offset == "+02:00" and e.source("utc_offset") == "session"
    ct = photo_time_utc(e)
    assert ct.source == SOURCE_SESSION and ct.utc == base.utc_aware.replace(microsecond=0)
    # the file's own offset wins over the session's, the GPS time over both
    (sub / "session.toml").write_text('# a wrong zone\nutc_offset = "-07:00"\n')  # another size: not cached
    p2 = _write(small_camera, "dng", sub / "c.dng", dataclasses.replace(base, write_gps_time=False))
    assert photo_time_utc(read_photo_metadata(p2)).source == SOURCE_OFFSET
    p3 = _write(small_camera, "dng", sub / "d.dng", base)
    ct = photo_time_utc(read_photo_metadata(p3))
    assert ct.source == SOURCE_GPS and ct.utc == base.utc_aware and not ct.notes  # its own offset agrees
    # a session offset disagreeing with the GPS time by 9 h is noted (not a whole day: not the date flag)
    p4 = _write(small_camera, "dng", sub / "e.dng", dataclasses.replace(base, write_offset=False))
    ct = photo_time_utc(read_photo_metadata(p4))
    assert ct.source == SOURCE_GPS and ct.utc == base.utc_aware
    assert any("differ by +540 min" in n for n in ct.notes) and not ct.gps_date_disagrees, ct.notes
    # a caller's offset ranks with the session's
    e = read_photo_metadata(p)
    assert photo_time_utc(e, utc_offset="+02:00").utc == base.utc_aware.replace(microsecond=0)


def test_synthetic_gps_date_a_day_late_is_flagged(tmp_path, small_camera):

    for write_offset in (False, True):
        place = dataclasses.replace(PLACES["north-east"], gps_date_shift_days=1, write_offset=write_offset)
        p = _write(small_camera, "jpeg", tmp_path / f"late{write_offset}.jpg", place)
        ct = photo_time_utc(read_photo_metadata(p))
        assert ct.gps_date_disagrees and any("disagrees with the local date" in n for n in ct.notes), ct
        assert ct.source == SOURCE_GPS
    # a correct file is not flagged
    ct = photo_time_utc(read_photo_metadata(_write(small_camera, "jpeg", tmp_path / "ok.jpg", PLACES["north-east"])))
    assert not ct.gps_date_disagrees and not ct.notes


def test_photo_without_time_or_gps_one_line_asks_for_sun(tmp_path, small_camera):
    p = _write(small_camera, "jpeg", tmp_path / "plain.jpg", None)  # DateTimeOriginal only
    with pytest.raises(CamcalError) as err:
        photo_sun(p)
    msg = str(err.value)
    assert msg.startswith(str(p)) and "\n" not in msg and "--sun ZENITH,AZIMUTH" in msg
    proc = run_cli("inspect", p, "--json")
    assert proc.returncode == 0
    sun = json.loads(proc.stdout)[0]["sun"]
    assert sun["zenith_deg"] is None and "--sun ZENITH,AZIMUTH" in sun["reason"]
    proc = run_cli("inspect", p, "--sun", "35,160.5", "--json")
    sun = json.loads(proc.stdout)[0]["sun"]
    assert (sun["zenith_deg"], sun["azimuth_deg"], sun["source"]) == (35.0, 160.5, "--sun")
    proc = run_cli("inspect", p, "--sun", "35,160.5")
    assert "zenith 35.00°, azimuth 160.50°" in proc.stdout and "--sun" in proc.stdout
    proc = run_cli("inspect", p, "--sun", "35,160.5", "--all")
    assert "sun.zenith_deg" in proc.stdout and "35.000" in proc.stdout and "--sun" in proc.stdout
    assert_one_line_error(run_cli("inspect", p, "--sun", "95,10"), "zenith")


def test_parse_sun_option():
    s = parse_sun_option("30,145")
    assert (s.zenith_deg, s.azimuth_deg, s.apparent_zenith_deg, s.source) == (30.0, 145.0, 30.0, "--sun")
    assert parse_sun_option(" 12.5° , 360 ").azimuth_deg == 0.0
    for bad in ("30", "a,b", "90,10", "-1,10", "30,361", "1,2,3"):
        with pytest.raises(CamcalError, match="--sun"):
            parse_sun_option(bad)


def test_sun_position_known_values():
    """pvlib's SPA against the published example of Reda & Andreas (2004), Table A5.1 (at 2003-10-17 12:30:30
    local time −7 h, 39.742476° N, 105.1786° W, 1830.14 m, 820 mbar, 11 °C, ΔT 67 s): topocentric zenith with
    refraction 50.11162°, azimuth 194.34024°. pvlib's pressure from the altitude (815 mbar), 12 °C and its
    ΔT differ slightly from the paper's, hence 0.01°; the refraction (≈0.016° here) is the difference of
    the true and apparent zenith angles."""
    s = sun_position(datetime(2003, 10, 17, 19, 30, 30, tzinfo=UTC), 39.742476, -105.1786, 1830.14)
    assert s.apparent_zenith_deg == pytest.approx(50.11162, abs=0.01)
    assert 0.01 < s.zenith_deg - s.apparent_zenith_deg < 0.025
    assert s.azimuth_deg == pytest.approx(194.34024, abs=0.01)


def test_session_utc_offset_validated(tmp_path):
    p = tmp_path / "session.toml"
    p.write_text('utc_offset = "-05:30"\nf_number = 2.8\n')
    assert read_session_defaults(p) == {"utc_offset": "-05:30", "f_number": 2.8}
    for bad in ('utc_offset = "CET"', 'utc_offset = "+15:00"', "utc_offset = 2", 'utc_offset = "+1:00"'):
        p.write_text(bad + "\n")
        with pytest.raises(CamcalError, match="utc_offset") as err:
            read_session_defaults(p)
        assert "\n" not in str(err.value)


@needs_real
def test_exif_tags_csv_dates_match(inspected):
    """The capture time shown is the file's DateTimeOriginal (exif_tags.csv), never shifted by an offset."""
    rows = {r["file"]: r for r in csv.DictReader(open(REAL / "exif_tags.csv", encoding="utf-8"))}
    for path in _real_photos():
        rel = f"{path.parent.name}/{path.name}"
        cell = rows[rel]["datetime_original_tag"]
        assert inspected[path.name]["capture_time"] == cell.replace(":", "-", 2).replace(" ", "T"), rel


def test_synth_photo_cli_writes_place_and_time(tmp_path):
    out = tmp_path / "field.heic"
    proc = run_cli("synth", "photo", out, "--width", "64", "--height", "64", "--utc", "2026-06-21T10:30:00Z",
                   "--utc-offset", "+02:00", "--gps", "47.37,8.54,408", "--heic-bits", "10")
    assert proc.returncode == 0, proc.stderr
    e = load_frame(out).exposure
    assert e.utc_offset == "+02:00" and e.altitude_m == 408.0
    assert e.latitude_deg == pytest.approx(47.37, abs=1e-9) and e.longitude_deg == pytest.approx(8.54, abs=1e-9)
    assert e.capture_time == "2026-06-21T12:30:00" and e.gps_time_utc == "2026-06-21T10:30:00+00:00"
    truth = sun_position(datetime(2026, 6, 21, 10, 30, tzinfo=UTC), 47.37, 8.54, 408.0)
    assert photo_sun(out).zenith_deg == pytest.approx(truth.zenith_deg, abs=1e-6)
    assert_one_line_error(run_cli("synth", "photo", tmp_path / "x.jpg", "--utc", "noon"), "--utc")
    assert_one_line_error(run_cli("synth", "photo", tmp_path / "x.jpg", "--utc", "2026-06-21T10:30:00",
                                  "--gps", "95,8"), "--gps")


def _tiff(exif_entries: dict, gps_entries: dict) -> bytes:
    """An EXIF block (TIFF structure) with the given Exif and GPS entries {tag: (type, values)}."""
    ifd0, exif, gps = _IFD(), _IFD(), _IFD()
    ifd0.add(271, _ASCII, "camcal")
    ifd0.add(272, _ASCII, "Odd GPS")
    ifd0.add(34665, _LONG, [0])
    ifd0.add(34853, _LONG, [0])
    for tag, (ftype, values) in exif_entries.items():
        exif.add(tag, ftype, values)
    for tag, (ftype, values) in gps_entries.items():
        gps.add(tag, ftype, values)
    exif_off = 8 + ifd0.total_size()
    exif_off += exif_off & 1
    gps_off = exif_off + exif.total_size()
    gps_off += gps_off & 1
    ifd0.add(34665, _LONG, [exif_off])
    ifd0.add(34853, _LONG, [gps_off])
    out = bytearray(b"II*\x00" + struct.pack("<I", 8)) + ifd0.pack(8)
    out += b"\x00" * (exif_off - len(out)) + exif.pack(exif_off)
    out += b"\x00" * (gps_off - len(out)) + gps.pack(gps_off)
    return bytes(out)


def test_gps_and_offset_tags_that_cannot_be_used_are_unknown_with_a_note(tmp_path):
    """Real receivers write 0°, 0° without a fix; some files lack the N/S letter, the GPS date, or hold an
    offset that is no zone. Each is unknown (never a guess), with a note; the photo then asks for --sun."""
    when = (_ASCII, "2026:06:21 12:30:00")
    cases = {
        "null-island": ({36867: when, 36881: (_ASCII, "CET")},
                        {1: (_ASCII, "N"), 2: (_RATIONAL, [0.0, 0.0, 0.0]), 3: (_ASCII, "E"),
                         4: (_RATIONAL, [0.0, 0.0, 0.0]), 7: (_RATIONAL, [10.0, 30.0, 0.0])}),
        "no-ref": ({36867: when}, {2: (_RATIONAL, [47.0, 22.0, 0.0]), 4: (_RATIONAL, [8.0, 32.0, 0.0])}),
    }
    img = np.full((64, 64, 3), 90, np.uint8)
    for name, (exif_entries, gps_entries) in cases.items():
        p = write_heic(tmp_path / f"{name}.heic", img, exif=_tiff(exif_entries, gps_entries))
        e = load_frame(p).exposure
        assert e.latitude_deg is None and e.longitude_deg is None and e.gps_time_utc is None, name
        assert e.utc_offset is None and e.capture_time == "2026-06-21T12:30:00", name
        notes = " | ".join(e.notes)
        if name == "null-island":
            assert "0°, 0°" in notes and "GPS time stamp without a GPS date" in notes and "'CET'" in notes, notes
        else:
            assert "without its N/S or E/W reference" in notes, notes
        with pytest.raises(CamcalError, match=r"no time zone .* and no GPS position; give --sun"):
            photo_sun(p)

"""Frame layouts (Bayer, linear RAW, processed), metadata sources, session defaults, frames without data.

All files are real DNGs written by :mod:`camcal.synth` and decoded by LibRaw.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

from camcal.calibrate.run import calibrate_session
from camcal.errors import CamcalError
from camcal.frame import Exposure, Frame
from camcal.io.read import _layout_name, _mostly_below, check_has_data, load_frame
from camcal.synth.camera import LINEAR_FROM_PLANES, Scene, SensorParams, SyntheticCamera
from camcal.synth.dng import encode_dng, write_dng, write_linear_dng
from camcal.synth.session import SessionPlan, write_session
from tests.conftest import assert_one_line_error, run_cli
from tests.oracles import read_session_defaults

SMALL = dict(n_bias=3, n_dark=2, dark_exposures_s=(2.0, 16.0), n_flat=3, linearity_steps=9, linearity_jpeg=False,
             sweep_jpeg=False, sweep_step_nm=50.0, n_sweep=1)


def _noise(shape, lo=100, hi=4000, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).integers(lo, hi, shape).astype(np.uint16)


# ---- the frame model ---------------------------------------------------------------------------------------------

def test_frame_layout_defaults_from_kind_and_is_checked():
    raw = Frame(np.zeros((4, 4), np.uint16), "raw", "RGGB", {}, 4095.0)
    assert raw.layout == "bayer" and raw.channel_names == ("R", "G1", "G2", "B") and raw.planes().shape == (4, 2, 2)
    lin = Frame(np.zeros((4, 6, 3), np.uint16), "raw", None, {"R": 1.0, "G": 2.0, "B": 3.0}, 4095.0, layout="linear")
    assert lin.channel_names == ("R", "G", "B") and lin.planes().shape == (3, 4, 6)
    assert lin.black_vector().ravel().tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(CamcalError, match="layout"):
        Frame(np.zeros((4, 4, 3), np.uint8), "processed", None, {}, 255.0, layout="linear")
    with pytest.raises(CamcalError, match="unknown frame layout"):
        Frame(np.zeros((4, 4), np.uint16), "raw", "RGGB", {}, 4095.0, layout="xtrans")


def test_exposure_sources_merge_and_fill():
    e = Exposure(exposure_s=0.01, iso=84.0, sources=(("exposure_s", "tag"), ("iso", "libraw")))
    assert e.source("exposure_s") == "tag" and e.source("f_number") is None
    s = e.filled("session", f_number=2.8, iso=100.0, exposure_s=5.0)  # fills unknown and LibRaw-only values
    assert (s.f_number, s.iso, s.exposure_s) == (2.8, 100.0, 0.01)
    assert (s.source("f_number"), s.source("iso"), s.source("exposure_s")) == ("session", "session", "tag")
    m = s.merged("frames.csv", exposure_s=0.02, f_number=None)
    assert m.exposure_s == 0.02 and m.source("exposure_s") == "frames.csv" and m.source("f_number") == "session"


# ---- linear RAW: writing and reading ------------------------------------------------------------------------------

def test_bayer_dng_bytes_unchanged():
    """The Bayer writer is bit-identical to the one before linear DNGs (sha256 of a fixed input)."""
    m = np.random.default_rng(1).integers(0, 4000, (8, 12)).astype(np.uint16)
    data = encode_dng(m, cfa_pattern="BGGR", black_level_dn=(1, 2, 3, 4), white_level_dn=4095, exposure_s=0.01,
                      f_number=4, iso=100, temperature_c=20)
    assert hashlib.sha256(data).hexdigest() == "235b73906ec86562afb4bcbfc1726eefd9beabb523d545af748147f65dffb6f7"


def test_linear_dng_round_trip_through_libraw(tmp_path):
    rgb = _noise((32, 48, 3))
    p = write_linear_dng(tmp_path / "l.dng", rgb, black_level_dn=(64, 65, 66), white_level_dn=4095, exposure_s=0.01,
                         f_number=None, iso=200)
    f = load_frame(p)
    assert f.kind == "raw" and f.layout == "linear" and f.cfa_pattern is None
    assert np.array_equal(f.data, rgb) and f.data.dtype == np.uint16
    assert f.black_level_dn == {"R": 64.0, "G": 65.0, "B": 66.0} and f.white_level_dn == 4095
    assert np.array_equal(f.planes(None), np.moveaxis(rgb, -1, 0))
    e = f.exposure
    assert (e.exposure_s, e.iso, e.f_number) == (0.01, 200.0, None)  # no FNumber tag: unknown
    assert e.source("exposure_s") == "tag" and e.source("f_number") is None


def test_synthetic_linear_frame_is_the_bayer_planes_r_g1_b(tmp_path):
    cam = SyntheticCamera(SensorParams(width=96, height=64))
    scene = Scene.uniform(np.full(401, 0.002))
    b = cam.write_dng(tmp_path / "b.dng", scene, exposure_s=0.01, rng=np.random.default_rng(3))
    lin = cam.write_dng(tmp_path / "l.dng", scene, exposure_s=0.01, rng=np.random.default_rng(3), layout="linear")
    fb, fl = load_frame(b), load_frame(lin)
    assert fl.layout == "linear" and fl.shape == (32, 48)
    assert np.array_equal(fl.planes(None), fb.planes(None)[list(LINEAR_FROM_PLANES)])
    assert [fl.black_level_dn[c] for c in "RGB"] == [fb.black_level_dn[c] for c in ("R", "G1", "B")]
    assert fl.exposure.f_number == 4.0


def test_linear_session_has_every_folder_and_frame(tmp_path):
    cam = SyntheticCamera(SensorParams(width=96, height=64))
    lin = write_session(tmp_path / "L", cam, SessionPlan(layout="linear", **SMALL))
    bay = write_session(tmp_path / "B", cam, SessionPlan(**SMALL))
    names = sorted(str(p.relative_to(lin)) for p in lin.rglob("*") if p.name != "truth.json")
    assert names == sorted(str(p.relative_to(bay)) for p in bay.rglob("*") if p.name != "truth.json")
    for stage in ("bias", "dark", "flat", "linearity", "sweep"):
        f = load_frame(sorted((lin / stage).glob("*.dng"))[0])
        assert f.layout == "linear" and f.data.shape == (32, 48, 3), stage
    truth = json.loads((lin / "truth.json").read_text())
    assert truth["layout"]["channels"] == {"R": "R", "G": "G1", "B": "B"} and truth["plan"]["layout"] == "linear"
    with pytest.raises(ValueError, match="layout"):
        write_session(tmp_path / "X", cam, SessionPlan(layout="xtrans", stages=("bias",)))


def test_inspect_linear_dng(tmp_path):
    cam = SyntheticCamera(SensorParams(width=96, height=64))
    p = cam.write_dng(tmp_path / "l.dng", Scene.dark(), exposure_s=0.01, rng=np.random.default_rng(0),
                      layout="linear")
    info = json.loads(run_cli("inspect", "--json", p).stdout)[0]
    assert info["layout"] == "linear" and info["channels"] == ["R", "G", "B"] and info["cfa_pattern"] is None
    assert (info["width"], info["height"]) == (48, 32)


# ---- frames without data ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("what, mosaic, message", [
    ("zeros", np.zeros((64, 64), np.uint16), "every pixel is 0"),
    ("constant", np.full((64, 64), 700, np.uint16), r"same value \(700 DN\)"),
    ("below black", np.where(np.arange(64 * 64).reshape(64, 64) % 500 == 0, 900, 3).astype(np.uint16),
     "below the black level"),
])
def test_raw_without_data_is_refused(tmp_path, what, mosaic, message):
    p = write_dng(tmp_path / f"{what.replace(' ', '_')}.dng", mosaic, cfa_pattern="RGGB", black_level_dn=64,
                  white_level_dn=4095, exposure_s=0.01, f_number=4, iso=100)
    with pytest.raises(CamcalError, match=message) as err:
        load_frame(p)
    assert p.name in str(err.value)
    assert_one_line_error(run_cli("inspect", p), p.name, "no ")


@pytest.mark.parametrize("above, refused", [(100, True), (101, False), (5000, False)])
@pytest.mark.parametrize("where", ["first", "last"])
def test_the_below_black_test_stops_counting_only_when_it_cannot_refuse(above, refused, where):
    """check_has_data refuses a frame with 99 % or more of its values below the black level; it stops counting
    once more than 1 % are at or above it, wherever in the frame they are (the first chunk or the last one):
    10 000 values with exactly 100 at the black level are refused, with 101 they are not."""
    data = np.full(10_000, 3, np.uint16)
    data[:above] = 64
    if where == "last":
        data = data[::-1].copy()
    data = data.reshape(100, 100)
    if refused:
        with pytest.raises(CamcalError, match=r"99.0 % of the pixels are below the black level"):
            check_has_data(Path("x.dng"), data, 64, 4095)
    else:
        assert check_has_data(Path("x.dng"), data, 64, 4095) == (3, 64)
    assert _mostly_below(data, 64, chunk=256) is refused
    assert _mostly_below(data.reshape(-1), 64, chunk=256) is refused  # 1-D: one block


def test_fully_saturated_raw_is_an_image_reported_as_saturated(tmp_path):
    """Every pixel at the white level is an over-exposed image, not a file without data: read, and inspect says
    it is saturated (only files with no image, all zero or constant below white, are refused)."""
    p = write_dng(tmp_path / "over.dng", np.full((64, 64), 4095, np.uint16), cfa_pattern="RGGB", black_level_dn=64,
                  white_level_dn=4095, exposure_s=0.01, f_number=4, iso=100)
    assert load_frame(p).data.min() == 4095
    proc = run_cli("inspect", "--json", p)
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)[0]
    assert info["saturated_pct"] == 100.0 and info["saturated"].startswith("fully saturated")
    assert "fully saturated" in run_cli("inspect", p).stdout


def test_low_noise_dark_frame_is_kept(tmp_path):
    """A 10-bit sensor with 0.5 DN of read noise (like the Pi's): most pixels at the black level, some below."""
    rng = np.random.default_rng(0)
    mosaic = np.clip(np.rint(60 + 0.5 * rng.standard_normal((64, 64))), 0, 1023).astype(np.uint16)
    p = write_dng(tmp_path / "d.dng", mosaic, cfa_pattern="BGGR", black_level_dn=60, white_level_dn=1023,
                  exposure_s=0.001, f_number=None, iso=100)
    assert np.array_equal(load_frame(p).data, mosaic)


def test_other_sensor_layouts_are_named():
    assert "X-Trans" in _layout_name(NS(raw_pattern=np.zeros((6, 6)), color_desc=b"RGBG", num_colors=3))
    assert "Foveon" in _layout_name(NS(raw_pattern=None, color_desc=b"RGBG", num_colors=3))
    assert "4-colour CMYG" in _layout_name(NS(raw_pattern=np.zeros((2, 2)), color_desc=b"CMYG", num_colors=4))


def test_raw_too_small_for_its_pixels_is_refused(tmp_path):
    p = write_dng(tmp_path / "s.dng", _noise((512, 768)), cfa_pattern="RGGB", black_level_dn=64, white_level_dn=4095,
                  exposure_s=0.01, f_number=4, iso=100)
    data = bytearray(p.read_bytes()[:4000])
    p.write_bytes(bytes(data))
    with pytest.raises(CamcalError, match="cannot hold its 768x512 pixels"):
        load_frame(p)


# ---- session defaults and the reference setting -------------------------------------------------------------------

def test_session_defaults_file_is_strict(tmp_path):
    p = tmp_path / "session.toml"
    p.write_text("f_number = 2.8\niso = 100\ntemperature_C = -5\n")
    assert read_session_defaults(p) == {"f_number": 2.8, "iso": 100.0, "temperature_c": -5.0}
    for text, msg in (("fnumber = 2.8", "unknown key 'fnumber'"), ('f_number = "2.8"', "must be a number"),
                      ("f_number = 0", "must be positive"), ("f_number = 2000", "plausible range"),
                      ("f_number = 2.8\nf_number = 4", "not valid TOML"), ("[camera]\nf_number = 2", "unknown key"),
                      ("f_number = true", "must be a number")):
        p.write_text(text)
        with pytest.raises(CamcalError, match=msg) as err:
            read_session_defaults(p)
        assert "session.toml" in str(err.value) and "\n" not in str(err.value)


def test_session_defaults_rank_below_tags_and_frames_csv(tmp_path):
    d = tmp_path / "S" / "flat"
    d.mkdir(parents=True)
    p = write_dng(d / "a.dng", _noise((64, 64)), cfa_pattern="RGGB", black_level_dn=64, white_level_dn=4095,
                  exposure_s=0.01, f_number=None, iso=100)
    (tmp_path / "S" / "session.toml").write_text("f_number = 2.8\niso = 400\n")  # found from the stage folder
    e = load_frame(p).exposure
    assert (e.f_number, e.source("f_number"), e.iso, e.source("iso")) == (2.8, "session", 100.0, "tag")
    e = load_frame(p, {"f_number": 5.6}).exposure
    assert (e.f_number, e.source("f_number")) == (5.6, "frames.csv")
    assert load_frame(p, defaults={}).exposure.f_number is None


def test_fixed_aperture_session_calibrates_with_one_session_default(tmp_path):
    cam = SyntheticCamera(SensorParams(width=96, height=64))
    s = write_session(tmp_path / "S", cam, SessionPlan(fixed_aperture=True, **SMALL))
    assert "f_number" not in (s / "sweep" / "sweep.csv").read_text()
    assert "f_number" not in (s / "dark" / "frames.csv").read_text()
    assert load_frame(s / "sweep" / "sweep_400.0nm_00.dng", defaults={}).exposure.f_number is None  # no tag
    assert read_session_defaults(s / "session.toml") == {"f_number": 4.0}
    profile, notes = calibrate_session(s)
    assert profile.reference_f_number == 4.0 and profile.reference_iso == 100.0
    assert "reference f-number 4 from session.toml" in notes
    (s / "session.toml").unlink()
    proc = run_cli("calibrate", s, "-o", tmp_path / "p.camcal", "-j", "1")
    assert_one_line_error(proc, "reference f-number is unknown", "f_number = N", "session.toml", "sweep")
    assert not (tmp_path / "p.camcal").exists()


def test_inspect_many_reports_good_files_and_lists_failures(tmp_path):
    good = write_dng(tmp_path / "good.dng", _noise((64, 64)), cfa_pattern="RGGB", black_level_dn=64,
                     white_level_dn=4095, exposure_s=0.01, f_number=4, iso=100)
    bad = tmp_path / "bad.dng"
    bad.write_bytes(b"II*\x00garbage")
    missing = tmp_path / "missing.dng"
    proc = run_cli("inspect", "--json", bad, good, missing)
    assert proc.returncode == 1
    entries = json.loads(proc.stdout)
    assert [Path(e["file"]).name for e in entries] == ["bad.dng", "good.dng", "missing.dng"]
    assert entries[1]["error"] is None and entries[1]["iso"] == 100
    assert "bad.dng" in entries[0]["error"] and "no such file" in entries[2]["error"]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 2 and all(ln.startswith("camcal: failed: ") for ln in lines)
    table = run_cli("inspect", good, bad)
    assert table.returncode == 1 and "RGGB" in table.stdout and "1 of 2 files read" in table.stdout
    assert run_cli("inspect", good, good).returncode == 0


def test_fixed_aperture_camera_end_to_end_with_session_toml(tmp_path):
    """CLI: a fixed-aperture session and its photos; session.toml gives the f-number to calibrate and apply."""
    cam = SyntheticCamera(SensorParams(width=96, height=64))
    s = write_session(tmp_path / "S", cam, SessionPlan(fixed_aperture=True, **{**SMALL, "stages": ("bias", "dark",
                                                                                                "sweep")}))
    prof = tmp_path / "p.camcal"
    assert run_cli("calibrate", s, "-o", prof, "-j", "1").returncode == 0
    photos = tmp_path / "photos"
    cam.write_dng(photos / "a.dng", Scene.uniform(np.full(401, 0.002)), exposure_s=0.01,
                  rng=np.random.default_rng(5), tag_f_number=False)
    proc = run_cli("apply", prof, photos, "-o", tmp_path / "out1", "-j", "1")
    assert proc.returncode == 1 and "missing f_number" in proc.stderr and "session.toml" in proc.stderr
    (photos / "session.toml").write_text("f_number = 4.0\n")
    proc = run_cli("apply", prof, photos, "-o", tmp_path / "out2", "-j", "1")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "out2" / "a.dng.exr").is_file()


def test_synth_cli_layout_and_fixed_aperture(tmp_path):
    proc = run_cli("synth", "session", tmp_path / "S", "--layout", "linear", "--fixed-aperture", "--width", "96",
                   "--height", "64", "--stages", "bias")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(run_cli("inspect", "--json", tmp_path / "S" / "bias" / "bias_000.dng").stdout)[0]
    assert info["layout"] == "linear" and info["f_number"] == 4.0 and info["sources"]["f_number"] == "session"
    assert_one_line_error(run_cli("synth", "session", tmp_path / "T", "--layout", "xtrans"), "unknown layout")


def test_the_reader_keeps_the_value_range_it_measured(tmp_path):
    """load_frame of a RAW file keeps the (smallest, largest) value its data check measured; the checks after it
    use that range instead of going over the frame again: a dark frame with 2 % of its pixels at the white
    level is still refused, one whose maximum is below it passes. A frame made with dataclasses.replace (other
    data) measures its range again; a processed frame measures it when asked."""
    import dataclasses

    from camcal.calibrate.dark_frames import dark_frame_check

    mosaic = np.full((64, 64), 70, np.uint16)
    mosaic[0, :7] = 60
    mosaic.flat[100:182] = 4095  # 2 % at the white level
    p = write_dng(tmp_path / "d.dng", mosaic, cfa_pattern="RGGB", black_level_dn=64, white_level_dn=4095,
                  exposure_s=1.0, f_number=None, iso=100)
    frame = load_frame(p)
    assert frame.value_range_dn == frame.data_range() == (60, 4095)
    with pytest.raises(CamcalError, match="dark frame is saturated: 2.0 %"):
        dark_frame_check()(frame)
    mosaic.flat[100:182] = 4094
    q = write_dng(tmp_path / "e.dng", mosaic, cfa_pattern="RGGB", black_level_dn=64, white_level_dn=4095,
                  exposure_s=1.0, f_number=None, iso=100)
    ok = load_frame(q)
    assert ok.value_range_dn == (60, 4094)
    dark_frame_check()(ok)
    other = dataclasses.replace(ok, data=np.full((4, 4), 9, np.uint16))
    assert other.value_range_dn is None and other.data_range() == (9, 9)
    rgb = Frame(np.arange(12, dtype=np.uint8).reshape(2, 2, 3), "processed", None, {}, 255.0)
    assert rgb.value_range_dn is None and rgb.data_range() == (0, 11)
    # a manifest row or session defaults change the exposure, not the data: the range is kept with them
    over = load_frame(q, overrides={"exposure_s": 2.0}, defaults={"f_number": 2.8})
    assert over.exposure.exposure_s == 2.0 and over.exposure.f_number == 2.8
    assert over.value_range_dn == (60, 4094)


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_plane_views_are_the_planes_without_a_copy(pattern):
    """Frame.plane_views gives the planes of Frame.planes (in the frame's own type) as views of its data, for a
    mosaic of every CFA pattern and for a linear RAW frame; a mosaic with an odd side is refused."""
    rng = np.random.default_rng(0)
    mosaic = rng.integers(0, 4096, (6, 8)).astype(np.uint16)
    frame = Frame(mosaic, "raw", pattern, {}, 4095.0)
    views = frame.plane_views()
    assert len(views) == 4
    np.testing.assert_array_equal(np.stack(views), frame.planes(dtype=None))
    assert all(np.shares_memory(v, mosaic) for v in views)
    linear = Frame(rng.integers(0, 4096, (4, 5, 3)).astype(np.uint16), "raw", None, {}, 4095.0, layout="linear")
    lviews = linear.plane_views()
    np.testing.assert_array_equal(np.stack(lviews), linear.planes(dtype=None))
    assert all(np.shares_memory(v, linear.data) for v in lviews)
    with pytest.raises(CamcalError, match="even sides"):
        Frame(mosaic[:5], "raw", pattern, {}, 4095.0).plane_views()

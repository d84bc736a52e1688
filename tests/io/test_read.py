"""Real files through real decoders: DNG via LibRaw (rawpy), JPEG via OpenImageIO/exifread."""

import subprocess
import sys
import textwrap
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
import rawpy

from camcal.errors import CamcalError, MissingMetadataError
from camcal.frame import PATTERNS, PLANES, split_planes
from camcal.io.read import frame_header, load_frame
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.dng import encode_linear_dng, write_dng
from tests.oracles import iter_folder


@pytest.mark.parametrize("bits", [12, 14])
@pytest.mark.parametrize("pattern", PATTERNS)
def test_dng_round_trip(tmp_path, rng, pattern, bits):
    mosaic = rng.integers(0, 2**bits, size=(64, 96)).astype(np.uint16)
    black = (256.0, 257.0, 258.0, 259.0)  # per position of the 2x2 cell
    path = write_dng(tmp_path / "x.dng", mosaic, cfa_pattern=pattern, black_level_dn=black, white_level_dn=2**bits - 1,
                     exposure_s=1 / 320, f_number=7.1, iso=1600, make="Acme", model="Cam 1", serial="S42",
                     capture_time=datetime(2026, 5, 4, 3, 2, 1))
    # LibRaw itself, no camcal in between
    with rawpy.imread(str(path)) as raw:
        np.testing.assert_array_equal(raw.raw_image_visible, mosaic)
        assert raw.white_level == 2**bits - 1
    frame = load_frame(path)
    np.testing.assert_array_equal(frame.data, mosaic)
    assert frame.cfa_pattern == pattern
    assert frame.white_level_dn == 2**bits - 1
    # black level of each plane = the value written at that plane's cell position
    from camcal.frame import plane_offsets

    for name in PLANES:
        r, c = plane_offsets(pattern)[name]
        assert frame.black_level_dn[name] == black[2 * r + c]
    e = frame.exposure
    assert e.exposure_s == pytest.approx(1 / 320, rel=1e-6)
    assert e.f_number == pytest.approx(7.1, rel=1e-6)
    assert e.iso == 1600
    assert (e.make, e.model, e.serial) == ("Acme", "Cam 1", "S42")
    assert e.capture_time == "2026-05-04T03:02:01"


def test_jpeg_metadata_and_pixels(tmp_path, camera):
    spectrum = np.full(401, 0.01)
    path = camera.write_jpeg(tmp_path / "p.jpg", Scene.uniform(spectrum), exposure_s=1 / 60, iso=400, f_number=2.8,
                             rng=np.random.default_rng(1))
    frame = load_frame(path)
    assert frame.kind == "processed" and frame.data.shape == (256, 384, 3) and frame.data.dtype == np.uint8
    assert frame.exposure.exposure_s == pytest.approx(1 / 60)
    assert frame.exposure.iso == 400 and frame.exposure.f_number == pytest.approx(2.8)
    assert frame.exposure.make == "camcal" and frame.white_level_dn == 255
    import OpenImageIO as oiio

    spec = oiio.ImageInput.open(str(path)).spec()
    assert spec.getattribute("Exif:PhotographicSensitivity") == 400


def test_manifest_overrides_file_metadata(tmp_path, camera):
    d = tmp_path / "dark"
    camera.write_dng(d / "a.dng", Scene.dark(), exposure_s=2.0, rng=np.random.default_rng(0))
    camera.write_dng(d / "b.dng", Scene.dark(), exposure_s=2.0, rng=np.random.default_rng(1))
    (d / "frames.csv").write_text("file,exposure_s,iso,temperature_C\r\na.dng,4.5,,-3.5\r\n", encoding="utf-8-sig")
    frames = dict((p.name, f) for p, f in iter_folder(d))
    assert frames["a.dng"].exposure.exposure_s == 4.5
    assert frames["a.dng"].exposure.iso == 100  # empty cell keeps the file's value
    assert frames["a.dng"].exposure.temperature_c == -3.5
    assert frames["b.dng"].exposure.exposure_s == 2.0


def test_missing_metadata_error_names_file_field_and_fix(tmp_path):
    mosaic = np.random.default_rng(0).integers(100, 200, (64, 64)).astype(np.uint16)
    path = write_dng(tmp_path / "m.dng", mosaic, cfa_pattern="RGGB", black_level_dn=0, white_level_dn=4095,
                     exposure_s=0.01, f_number=4, iso=0)
    frame = load_frame(path)
    assert frame.exposure.iso is None
    with pytest.raises(MissingMetadataError) as err:
        frame.exposure.require("iso", frame.path)
    msg = str(err.value)
    assert "m.dng" in msg and "iso" in msg and "frames.csv" in msg


def test_synthetic_photon_transfer_is_physical(tmp_path):
    """Mean and variance of a flat exposure follow Poisson + read noise at the set gain."""
    cam = SyntheticCamera(SensorParams(prnu_sigma=0.0, vignetting_k=(0, 0, 0, 0, 0), dark_current_e_per_s=(0,) * 4,
                                       hot_pixel_fraction=0.0, bias_pattern_dn=0.0))
    spectrum = np.full(401, 0.002)
    a = cam.expose_planes(Scene.uniform(spectrum), exposure_s=0.01, rng=np.random.default_rng(1)).astype(float)
    b = cam.expose_planes(Scene.uniform(spectrum), exposure_s=0.01, rng=np.random.default_rng(2)).astype(float)
    k = cam.dn_per_electron(100)
    for i in range(4):
        signal_dn = a[i].mean() - 512
        expected_e = cam.channel_rates_e(spectrum, 4.0)[[0, 1, 1, 2][i]] * 0.01
        assert signal_dn == pytest.approx(expected_e * k, rel=0.01)
        var_dn = np.var(a[i] - b[i]) / 2  # difference of two frames removes fixed pattern
        expected_var = (expected_e + cam.params.read_noise_e**2) * k**2 + 1 / 12
        # sampling error of a variance over n=24576 px: sqrt(2/n) ~ 0.9 %
        assert var_dn == pytest.approx(expected_var, rel=0.05)


def test_synthetic_frames_clip_at_white_level(camera):
    planes = camera.expose_planes(Scene.uniform(np.full(401, 1.0)), exposure_s=1.0, rng=np.random.default_rng(0))
    assert planes.max() == camera.params.white_dn


def test_split_of_loaded_dng_matches_camera_planes(tmp_path, camera):
    rng = np.random.default_rng(3)
    path = camera.write_dng(tmp_path / "x.dng", Scene.uniform(np.full(401, 0.001)), exposure_s=0.01, rng=rng)
    frame = load_frame(path)
    planes = frame.planes()
    again = split_planes(frame.data, camera.params.cfa_pattern)
    np.testing.assert_array_equal(planes, again)


@pytest.mark.parametrize(
    "make_file, fragment",
    [
        (lambda p: p.write_bytes(b""), "empty"),
        (lambda p: p.write_text("this is not a raw file\n" * 50), "LibRaw"),
        (lambda p: p.mkdir(), "directory"),
        (lambda p: None, "no such file"),
    ],
)
def test_bad_files_raise_one_line_errors(tmp_path, make_file, fragment):
    p = tmp_path / "bad.dng"
    make_file(p)
    with pytest.raises(CamcalError) as err:
        load_frame(p)
    assert fragment in str(err.value) and "bad.dng" in str(err.value) and "\n" not in str(err.value)


def test_truncated_dng_is_refused(tmp_path, camera):
    path = camera.write_dng(tmp_path / "t.dng", Scene.dark(), exposure_s=0.01, rng=np.random.default_rng(0))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])
    with pytest.raises(CamcalError, match="damaged or truncated"):
        load_frame(path)


def test_pixel_limit_refuses_before_decoding(tmp_path, camera, monkeypatch):
    path = camera.write_dng(tmp_path / "t.dng", Scene.dark(), exposure_s=0.01, rng=np.random.default_rng(0))
    monkeypatch.setenv("CAMCAL_MAX_PIXELS", "1000")
    with pytest.raises(CamcalError, match="above the limit"):
        load_frame(path)


def test_read_ahead_keeps_order_bounds_frames_in_flight_and_raises_in_turn(tmp_path, rng):
    """Frames come back in file order however the threads finish; never more than threads + 1 are held; a
    damaged file raises when its turn comes (the frames before it were all delivered)."""
    import threading
    import time

    from camcal.io.folders import read_ahead

    paths = []
    for i in range(6):
        mosaic = rng.integers(0, 4000, size=(32, 48)).astype(np.uint16)
        paths.append(write_dng(tmp_path / f"f{i}.dng", mosaic, cfa_pattern="RGGB", black_level_dn=(256.0,) * 4,
                               white_level_dn=4095, exposure_s=1 / (i + 1), f_number=4, iso=100))
    (tmp_path / "f3.dng").write_bytes(b"II*\x00 damaged")
    held, peak, lock = [0], [0], threading.Lock()

    def load(p):
        time.sleep(0.02 * (7 - int(p.stem[1:])))  # later files finish first
        frame = load_frame(p)
        with lock:
            held[0] += 1
            peak[0] = max(peak[0], held[0])
        return frame

    got = []
    with pytest.raises(CamcalError, match="f3.dng"):
        for frame in read_ahead(paths, load, threads=2):
            got.append(frame.path.name)
            with lock:
                held[0] -= 1
    assert got == ["f0.dng", "f1.dng", "f2.dng"]
    assert peak[0] <= 3
    assert [f.path.name for f in read_ahead(paths[:3], load_frame, threads=0)] == got


def test_file_hash_is_remembered_until_the_file_changes(tmp_path):
    """A remembered SHA-256 is that of the file's bytes now: the file rewritten (another size, so that its state
    differs even within one tick of the file system's clock) is hashed again; a hash not asked to be remembered
    is never reused, whatever the clock."""
    import hashlib

    from camcal.io.hashing import hash_files, sha256_file

    def sha(b):
        return hashlib.sha256(b).hexdigest()

    p = tmp_path / "a.bin"
    p.write_bytes(b"x" * 5000)
    assert sha256_file(p, remember=True) == sha(b"x" * 5000)
    assert sha256_file(p) == sha(b"x" * 5000)
    p.write_bytes(b"y" * 5001)
    assert sha256_file(p) == sha(b"y" * 5001)
    q = tmp_path / "b.bin"
    q.write_bytes(b"z" * 7)
    assert sha256_file(q) == sha(b"z" * 7)
    q.write_bytes(b"w" * 7)  # same size, maybe the same clock tick: not remembered, so read again
    assert hash_files([p, q], threads=2) == {p: sha(b"y" * 5001), q: sha(b"w" * 7)}


_REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "realdata"
_HEADER_FILES = sorted(p for d in ("raw", "pi", "jpeg", "heic") for p in (_REAL / d).glob("*") if p.is_file())


@pytest.mark.skipif(not _HEADER_FILES, reason="../shared/realdata is absent")
@pytest.mark.parametrize("path", _HEADER_FILES, ids=lambda p: p.name)
def test_frame_header_tells_what_the_decode_tells(path):
    """The header read the session screening uses instead of a decode (issue 28) gives the kind, size, make and
    model the decode gives; the RAW layout too, or None (never a wrong one) when only the decode can tell."""
    head = frame_header(path)
    frame = load_frame(path)
    assert (head.kind, head.shape, head.make, head.model) == (frame.kind, tuple(frame.shape), frame.exposure.make,
                                                              frame.exposure.model)
    assert head.layout in (None, frame.layout)


def test_frame_header_of_synthetic_bayer_and_linear_dngs(tmp_path):
    rgb = np.random.default_rng(1).integers(100, 4000, (64, 96, 3)).astype(np.uint16)
    (tmp_path / "lin.dng").write_bytes(encode_linear_dng(rgb, black_level_dn=64, white_level_dn=4095,
                                                         exposure_s=0.01, f_number=4, iso=100))
    SyntheticCamera(SensorParams(width=66, height=64)).write_dng(tmp_path / "cfa.dng", Scene.dark(),
                                                                   exposure_s=0.01, iso=100, f_number=4,
                                                                   rng=np.random.default_rng(2))
    for name, layout, shape in (("lin.dng", "linear", (64, 96)), ("cfa.dng", "bayer", (64, 66))):
        head = frame_header(tmp_path / name)
        assert (head.kind, head.layout, head.shape) == ("raw", layout, shape)
        assert head.shape == load_frame(tmp_path / name).shape
    with pytest.raises(CamcalError):
        (tmp_path / "cut.dng").write_bytes((tmp_path / "cfa.dng").read_bytes()[:200])
        frame_header(tmp_path / "cut.dng")


QUIET_SCRIPT = textwrap.dedent("""
    import os, sys, threading
    from camcal.io.read import quiet_stderr
    from camcal.io.terminal import err_console
    inside, leave = threading.Event(), threading.Event()
    def decode():  # a decode thread, with LibRaw silenced
        with quiet_stderr():
            inside.set()
            leave.wait()
    t = threading.Thread(target=decode)
    t.start()
    inside.wait()
    print("camcal: interrupted", file=sys.stderr)
    err_console.print("camcal: failed: one photo")
    os.write(2, b"LibRaw: data corrupted\\n")
    with quiet_stderr():  # nested in this thread too
        print("camcal: warning: nested", file=sys.stderr)
        os.write(2, b"libpng: nested\\n")
    leave.set()
    t.join()
    print("camcal: after", file=sys.stderr)
    os.write(2, b"C after\\n")
""")


def test_quiet_stderr_silences_c_libraries_not_the_lines_python_writes_meanwhile():
    """While a decode thread silences fd 2 for LibRaw, a line the main thread prints (the command line's
    "interrupted", a failed photo) still reaches standard error; what C code writes to fd 2 does not, until the
    last block ends. (Before, those lines went to the null device: an interrupted calibrate exited 130 in
    silence.)"""
    proc = subprocess.run([sys.executable, "-c", QUIET_SCRIPT], capture_output=True, text=True, timeout=60,
                          cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines() == ["camcal: interrupted", "camcal: failed: one photo", "camcal: warning: nested",
                                        "camcal: after", "C after"]


# ---- monochrome sensors: one-sample DNG, one-channel 16-bit PNG/TIFF, FITS ------------------------------------
def _mono(shape=(48, 64), seed=0):
    return (100 + np.random.default_rng(seed).poisson(500, shape)).astype(np.uint16)


def test_monochrome_dng_reads_as_one_channel_y(tmp_path):
    from camcal.synth.dng import encode_mono_dng

    a = _mono()
    p = tmp_path / "m.dng"
    p.write_bytes(encode_mono_dng(a, black_level_dn=100, white_level_dn=4095, exposure_s=0.01, f_number=2.0,
                                  iso=200))
    f = load_frame(p, defaults={})
    assert (f.layout, f.kind, f.channel_names, f.cfa_pattern) == ("mono", "raw", ("Y",), None)
    assert np.array_equal(f.data, a) and f.black_level_dn == {"Y": 100.0} and f.white_level_dn == 4095
    assert f.planes().shape == (1, 48, 64) and f.exposure.iso == 200
    assert frame_header(p).layout == "mono"


def test_monochrome_png_with_the_sessions_bit_depth(tmp_path):
    import OpenImageIO as oiio

    a = _mono()
    p = tmp_path / "m.png"
    out = oiio.ImageOutput.create(str(p))
    out.open(str(p), oiio.ImageSpec(64, 48, 1, oiio.UINT16))
    out.write_image(a[..., None])
    out.close()
    f = load_frame(p, defaults={})
    assert f.layout == "mono" and np.array_equal(f.data, a) and f.white_level_dn == 65535
    assert frame_header(p).layout == "mono"
    (tmp_path / "session.toml").write_text("bits_per_sample = 12\n")
    assert load_frame(p).white_level_dn == 4095
    (tmp_path / "session.toml").write_text("bits_per_sample = 8\n")
    with pytest.raises(CamcalError, match="8-bit range"):
        load_frame(p)


def test_fits_frames(tmp_path):
    from astropy.io import fits

    a = _mono()
    hdr = fits.Header()
    hdr["EXPTIME"] = 2.5
    hdr["DATE-OBS"] = "2026-01-02T03:04:05"
    fits.PrimaryHDU(a, header=hdr).writeto(tmp_path / "m.fits")
    f = load_frame(tmp_path / "m.fits", defaults={})
    assert f.layout == "mono" and np.array_equal(f.data, a)
    assert f.exposure.exposure_s == 2.5 and f.exposure.source("exposure_s") == "tag"
    assert f.exposure.iso is None  # not a FITS key: unknown, not a default
    assert f.exposure.capture_time == "2026-01-02T03:04:05" and f.exposure.utc_offset == "+00:00"
    fits.PrimaryHDU(np.zeros((3, 8, 8), np.uint16)).writeto(tmp_path / "cube.fits")
    with pytest.raises(CamcalError, match="3 axes"):
        load_frame(tmp_path / "cube.fits", defaults={})
    fits.PrimaryHDU(np.zeros((8, 8), np.float32)).writeto(tmp_path / "float.fits")
    with pytest.raises(CamcalError, match="BITPIX -32"):
        load_frame(tmp_path / "float.fits", defaults={})
    raw = (tmp_path / "m.fits").read_bytes()
    (tmp_path / "cut.fits").write_bytes(raw[:2880 + 100])
    with pytest.raises(CamcalError, match="truncated"):
        load_frame(tmp_path / "cut.fits", defaults={})


def test_a_session_of_fits_frames_through_calibrate(tmp_path):
    """FITS darks and flats (exposure time from EXPTIME, no black level stated) through ``camcal calibrate``: a
    one-channel profile whose dark current and offset are the truth (offset from the dark series' intercept)."""
    from astropy.io import fits

    from camcal.cli import main
    from camcal.models.profile import load_profile

    rng = np.random.default_rng(1)
    root = tmp_path / "S"
    yy, xx = np.mgrid[0:48, 0:64]
    vignetting = 1 - 0.2 * (((xx - 32) / 32) ** 2 + ((yy - 24) / 24) ** 2)
    for stage, times, lit in (("dark", (1.0, 4.0, 16.0), False), ("flat", (0.5,), True)):
        (root / stage).mkdir(parents=True)
        for t in times:
            for i in range(4):
                level = 1200 + 5 * t + (20000 * vignetting if lit else np.zeros((48, 64)))
                a = np.clip(np.rint(rng.normal(level, np.sqrt(9 + level - 1200))), 0, 65535).astype(np.uint16)
                hdr = fits.Header()
                hdr["EXPTIME"] = t
                fits.PrimaryHDU(a, header=hdr).writeto(root / stage / f"{stage}_{t:g}_{i}.fits")
    (root / "session.toml").write_text("iso = 100\nf_number = 4.0\n")
    assert main(["calibrate", str(root), "-o", str(tmp_path / "p.camcal")]) == 0
    p = load_profile(tmp_path / "p.camcal")
    assert p.camera.layout == "mono" and p.flat is not None and p.flat.channels == ("Y",)
    assert float(np.median(p.dark.dark_current_dn_per_s)) == pytest.approx(5.0, abs=0.1)
    assert float(np.median(p.dark.bias_dn)) == pytest.approx(1200.0, abs=1.0)
    assert p.dark.provenance["black_level_source"].startswith("unknown")

import numpy as np
import OpenImageIO as oiio
import pytest

from camcal.errors import CamcalError
from camcal.io.exr import HALF_MIN_NORMAL, read_exr, read_exr_header, write_exr


def test_round_trip_named_channels_and_metadata(tmp_path, rng):
    chans = {"R": rng.random((20, 30), dtype=np.float32), "L663": rng.random((20, 30), dtype=np.float32),
             "L663_unc": rng.random((20, 30), dtype=np.float32)}
    meta = {"wavelength_nm": 663.0, "units": "W m-2 sr-1 nm-1", "frames": 3, "exposure": {"iso": 100, "t": 0.01}}
    path = write_exr(tmp_path / "o.exr", chans, meta, compression="piz")
    back, m = read_exr(path, ["L663_unc", "R"])
    np.testing.assert_array_equal(back["L663_unc"], chans["L663_unc"])
    np.testing.assert_array_equal(back["R"], chans["R"])
    assert m == meta
    # the file is a real EXR for OpenImageIO itself
    spec = oiio.ImageInput.open(str(path)).spec()
    assert spec.get_string_attribute("compression") == "piz"
    assert sorted(spec.channelnames) == sorted(chans)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_half_precision(tmp_path):
    a = np.linspace(0, 1, 64, dtype=np.float32).reshape(8, 8)
    write_exr(tmp_path / "h.exr", {"Y": a}, half=True)
    assert oiio.ImageInput.open(str(tmp_path / "h.exr")).spec().format == oiio.HALF
    np.testing.assert_allclose(read_exr(tmp_path / "h.exr")[0]["Y"], a, atol=1e-3)


def _formats(path) -> dict[str, str]:
    """{channel: pixel type} of an EXR, read with OpenImageIO itself."""
    spec = oiio.ImageInput.open(str(path)).spec()
    formats = list(spec.channelformats) or [spec.format] * spec.nchannels
    return {n: str(f) for n, f in zip(spec.channelnames, formats, strict=True)}


def test_mixed_precision_stores_the_uncertainty_in_half(tmp_path, rng):
    """``mixed``: radiance float32 and bit-exact, the *_unc channels half (rounded to 11 significant bits)."""
    shape = (16, 24)
    value = (0.01 + rng.random(shape, dtype=np.float32)).astype(np.float32)
    sigma = (value * np.float32(0.011)).astype(np.float32)  # 1.1 % noise, as the benchmark photo
    sigma[0, 0], sigma[0, 1], value[1, 1] = np.nan, 0.0, np.nan  # NaN and zero are exact in half
    chans = {"R": value, "R_unc": sigma, "L663": value * 2, "L663_unc": sigma * 2}
    path = write_exr(tmp_path / "m.exr", chans, precision="mixed", compression="none")
    assert _formats(path) == {"R": "float", "L663": "float", "R_unc": "half", "L663_unc": "half"}
    head = read_exr_header(path)
    assert head["exr_pixel_type"] == "mixed" and head["uncertainty_precision"] == "half"
    back, _ = read_exr(path)
    for name in ("R", "L663"):
        np.testing.assert_array_equal(back[name], chans[name])  # lossless
    for name in ("R_unc", "L663_unc"):
        ok = np.isfinite(chans[name]) & (chans[name] > 0)
        rel = np.abs(back[name][ok] / chans[name][ok] - 1)
        # round to nearest with 11 significant bits in half's normal range: at most 2^-11 relative (half a step
        # of 2^-10 at the bottom of a binade)
        assert 0 < rel.max() <= 2.0**-11 * (1 + 1e-6)
        assert np.isnan(back[name][0, 0]) and back[name][0, 1] == 0


@pytest.mark.parametrize("outside", [0.5 * HALF_MIN_NORMAL, 7.0e4])
def test_mixed_precision_keeps_float_when_half_cannot_hold_the_uncertainty(tmp_path, rng, outside):
    """A 1σ value below half's normal range (fewer than 11 significant bits) or above its largest value: the file's
    uncertainty channels stay float32, and the header says why."""
    sigma = np.full((8, 8), 1e-3, np.float32)
    sigma[3, 4] = outside
    chans = {"G": np.ones((8, 8), np.float32), "G_unc": sigma}
    path = write_exr(tmp_path / "f.exr", chans, precision="mixed")
    assert _formats(path) == {"G": "float", "G_unc": "float"}
    head = read_exr_header(path)
    assert head["exr_pixel_type"] == "float"
    assert head["uncertainty_precision"].startswith("float (") and "normal range" in head["uncertainty_precision"]
    np.testing.assert_array_equal(read_exr(path)[0]["G_unc"], sigma)
    with pytest.raises(CamcalError, match="precision"):
        write_exr(tmp_path / "x.exr", chans, precision="double")


def test_errors(tmp_path):
    with pytest.raises(CamcalError, match="no channel"):
        write_exr(tmp_path / "a.exr", {"A": np.zeros((2, 2))})
        read_exr(tmp_path / "a.exr", ["B"])
    with pytest.raises(CamcalError, match="compression"):
        write_exr(tmp_path / "a.exr", {"A": np.zeros((2, 2))}, compression="lzma")
    (tmp_path / "bad.exr").write_bytes(b"\x76\x2f\x31\x01garbage")
    with pytest.raises(CamcalError):
        read_exr(tmp_path / "bad.exr")

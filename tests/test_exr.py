import numpy as np
import OpenImageIO as oiio
import pytest

from camcal.errors import CamcalError
from camcal.exr import read_exr, write_exr


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


def test_errors(tmp_path):
    with pytest.raises(CamcalError, match="no channel"):
        write_exr(tmp_path / "a.exr", {"A": np.zeros((2, 2))})
        read_exr(tmp_path / "a.exr", ["B"])
    with pytest.raises(CamcalError, match="compression"):
        write_exr(tmp_path / "a.exr", {"A": np.zeros((2, 2))}, compression="lzma")
    (tmp_path / "bad.exr").write_bytes(b"\x76\x2f\x31\x01garbage")
    with pytest.raises(CamcalError):
        read_exr(tmp_path / "bad.exr")

import json
import zipfile

import numpy as np
import pytest

from camcal.container import JSON_MEMBER, MAPS_MEMBER, read_container, write_container
from camcal.errors import CamcalError


@pytest.fixture
def written(tmp_path, rng):
    maps = {"dark.bias.R": rng.random((16, 24), dtype=np.float32), "flat.gain.B": rng.random((16, 24),
                                                                                            dtype=np.float32)}
    doc = {"schema_version": "1.0", "camera": {"make": "camcal", "width": 48, "height": 32},
           "maps": {"dark": ["dark.bias.R"], "flat": ["flat.gain.B"]}, "x": [1.5, 2.5]}
    return write_container(tmp_path / "p.camcal", doc, maps), doc, maps


def test_round_trip(written):
    path, doc, maps = written
    back, bmaps = read_container(path)
    assert {k: v for k, v in back.items() if k != "integrity"} == doc
    for k in maps:
        np.testing.assert_array_equal(bmaps[k], maps[k])


def _rewrite(path, json_bytes=None, maps_bytes=None, extra=None):
    with zipfile.ZipFile(path) as zf:
        j = zf.read(JSON_MEMBER)
        m = zf.read(MAPS_MEMBER)
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr(JSON_MEMBER, json_bytes if json_bytes is not None else j)
        zf.writestr(MAPS_MEMBER, maps_bytes if maps_bytes is not None else m)
        if extra:
            zf.writestr(extra, b"x")


def test_edited_number_is_refused(written):
    path = written[0]
    with zipfile.ZipFile(path) as zf:
        doc = json.loads(zf.read(JSON_MEMBER))
    doc["x"][0] = 1.6
    _rewrite(path, json_bytes=json.dumps(doc).encode())
    with pytest.raises(CamcalError, match="content hash mismatch"):
        read_container(path)


def test_replaced_maps_are_refused(written):
    path = written[0]
    with zipfile.ZipFile(path) as zf:
        m = bytearray(zf.read(MAPS_MEMBER))
    m[-10] ^= 0xFF
    _rewrite(path, maps_bytes=bytes(m))
    with pytest.raises(CamcalError, match="maps hash mismatch"):
        read_container(path)
    with pytest.raises(CamcalError, match="maps hash mismatch"):  # also when the maps are not decoded
        read_container(path, decode_maps=False)


def test_truncated_extra_member_and_not_zip(written, tmp_path):
    path = written[0]
    data = path.read_bytes()
    (tmp_path / "t.camcal").write_bytes(data[: len(data) // 2])
    with pytest.raises(CamcalError, match="not a camcal profile|corrupted"):
        read_container(tmp_path / "t.camcal")
    _rewrite(path, extra="../evil.sh")
    with pytest.raises(CamcalError, match="members"):
        read_container(path)
    (tmp_path / "j.camcal").write_text("{}")
    with pytest.raises(CamcalError, match="ZIP"):
        read_container(tmp_path / "j.camcal")


def test_nan_in_json_is_refused(written):
    path = written[0]
    with zipfile.ZipFile(path) as zf:
        text = zf.read(JSON_MEMBER).decode().replace("1.5", "NaN")
    _rewrite(path, json_bytes=text.encode())
    with pytest.raises(CamcalError, match="not valid JSON"):
        read_container(path)

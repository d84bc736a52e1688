import json
import zipfile

import numpy as np
import pytest

from camcal.errors import CamcalError
from camcal.io.container import JSON_MEMBER, MAPS_MEMBER, read_container, write_container


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


# ---- limits before work (issue 19) -----------------------------------------------------------------------------
def _raw_members(path, members):
    """Rewrite ``path`` with ``(name, bytes, compress_type)`` members."""
    with zipfile.ZipFile(path, "w") as zf:
        for name, data, ctype in members:
            zf.writestr(name, data, compress_type=ctype)


def test_maps_larger_than_the_sensor_needs_are_refused_before_reading(written):
    """The bound comes from the profile's own camera (48x32: planes of 24x16) and map list (2 maps):
    2 x 24 x 16 x 4 B x 1.05 + 1 MiB. 2 MiB of zeros (6 kB deflated) declares more and is never read."""
    from camcal.io.limits import maps_size_bound

    path, doc, _ = written
    bound, needs = maps_size_bound(doc)
    assert bound == int(2 * 24 * 16 * 4 * 1.05) + 1024 * 1024 and "2 maps of a 48x32 sensor" in needs
    with zipfile.ZipFile(path) as zf:
        j = zf.read(JSON_MEMBER)
    _raw_members(path, [(JSON_MEMBER, j, zipfile.ZIP_DEFLATED), (MAPS_MEMBER, bytes(2 * 1024 * 1024),
                                                                 zipfile.ZIP_DEFLATED)])
    with pytest.raises(CamcalError, match=r"maps.exr declares 2.0 MiB, above the limit of 1.0 MiB \(2 maps"):
        read_container(path, decode_maps=False)


def test_member_ratio_and_json_size_are_refused(written):
    path = written[0]
    _raw_members(path, [(JSON_MEMBER, b" " * (9 * 1024 * 1024), zipfile.ZIP_DEFLATED)])
    with pytest.raises(CamcalError, match="profile.json declares 9.0 MiB, above the limit of 8.0 MiB"):
        read_container(path)
    _raw_members(path, [(JSON_MEMBER, b"{" + b" " * (3 * 1024 * 1024) + b"}", zipfile.ZIP_DEFLATED)])
    with pytest.raises(CamcalError, match="expands .*-fold .* above the limit of 200:1"):
        read_container(path)


def test_too_many_members_refused_from_the_end_record(written):
    path = written[0]
    _raw_members(path, [(JSON_MEMBER, b"{}", zipfile.ZIP_STORED)] + [(f"m{i}", b"", zipfile.ZIP_STORED)
                                                                      for i in range(5)])
    with pytest.raises(CamcalError, match="declares 6 members, a profile has at most 2"):
        read_container(path)


@pytest.mark.parametrize("text", [b"[" * 100_000 + b"]" * 100_000, b'{"a":' * 65 + b"1" + b"}" * 65])
def test_deep_json_refused_before_parsing(written, text):
    path = written[0]
    _raw_members(path, [(JSON_MEMBER, text, zipfile.ZIP_STORED)])
    with pytest.raises(CamcalError, match="profile.json is nested .* levels deep, above the limit of 64"):
        read_container(path)


def test_json_at_the_depth_limit_is_parsed(written):
    path = written[0]
    _raw_members(path, [(JSON_MEMBER, b'{"a":' * 63 + b"[1]" + b"}" * 63, zipfile.ZIP_STORED)])
    with pytest.raises(CamcalError, match="no integrity record"):  # parsed; refused for what it lacks
        read_container(path)


def test_zip64_end_record_is_read(tmp_path):
    """A ZIP64 end record (written for maps above 4 GiB or more than 65535 members) gives the real counts."""
    import struct

    from camcal.io.limits import check_zip_directory, zip_directory_size

    def zip64(entries: int) -> bytes:
        body = b""
        cd = b""  # an empty directory is enough for the end records
        rec = struct.pack("<IQHHIIQQQQ", 0x06064B50, 44, 45, 45, 0, 0, entries, entries, len(cd), len(body))
        loc = struct.pack("<IIQI", 0x07064B50, 0, len(body) + len(cd), 1)
        eocd = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, 0xFFFF, 0xFFFF, 0xFFFFFFFF, 0xFFFFFFFF, 0)
        return body + cd + rec + loc + eocd

    p = tmp_path / "z64.camcal"
    p.write_bytes(zip64(70000))
    assert zip_directory_size(p) == (70000, 0)
    with pytest.raises(CamcalError, match="declares 70000 members"):
        check_zip_directory(p)
    with pytest.raises(CamcalError, match="declares 70000 members"):
        read_container(p)

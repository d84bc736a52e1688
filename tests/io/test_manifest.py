import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from camcal.errors import CamcalError
from camcal.io.manifest import read_manifest, safe_member


def write(tmp_path, text, encoding="utf-8"):
    p = tmp_path / "frames.csv"
    p.write_bytes(text.encode(encoding))
    return p


def test_bom_crlf_comments_and_spaces(tmp_path):
    p = write(tmp_path, "# lab notes\r\n file , exposure_s ,iso\r\n\r\na.dng, 0.5 ,100\r\n", "utf-8-sig")
    rows = read_manifest(p)
    assert rows == {"a.dng": {"file": "a.dng", "exposure_s": 0.5, "iso": 100.0}}


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("file,exposure_s\na.dng,fast\n", "non-numeric"),
        ("file,exposure_s\na.dng,nan\n", "non-finite"),
        ("file,exposure_s\na.dng,-1\n", "negative"),
        ("file,exposure_s\na.dng,0\n", "positive"),
        ("file,exposure_s\na.dng,1\na.dng,2\n", "twice"),
        ("file,exposure_s\na.dng,1,5\n", "cells"),
        ("exposure_s\n1\n", "missing required column 'file'"),
        ("file,exposure_s\n../../etc/passwd,1\n", "leaves the session folder"),
        ("file,exposure_s\n/etc/passwd,1\n", "absolute"),
        ("", "empty"),
    ],
)
def test_bad_manifests(tmp_path, text, fragment):
    with pytest.raises(CamcalError, match=fragment) as err:
        read_manifest(write(tmp_path, text))
    assert "frames.csv" in str(err.value)


def test_symlink_out_of_folder_is_refused(tmp_path):
    inner = tmp_path / "s"
    inner.mkdir()
    (inner / "link.dng").symlink_to(tmp_path / "outside.dng")
    with pytest.raises(CamcalError, match="leaves"):
        safe_member(inner, "link.dng")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.lists(st.text(max_size=8), min_size=1, max_size=5), max_size=6))
def test_parser_never_crashes(tmp_path_factory, rows):
    """Any CSV text gives either a table or a CamcalError: never another exception."""
    d = tmp_path_factory.mktemp("m")
    text = "file,exposure_s,iso\n" + "\n".join(",".join(r) for r in rows)
    p = d / "frames.csv"
    p.write_text(text, encoding="utf-8", errors="surrogatepass") if False else p.write_bytes(
        text.encode("utf-8", "surrogatepass"))
    try:
        out = read_manifest(p)
    except CamcalError:
        return
    for rec in out.values():
        for k in ("exposure_s", "iso"):
            v = rec.get(k)
            assert v is None or (math.isfinite(v) and v > 0)

"""Real files from real cameras (``../shared/realdata``, see its README): read truthfully.

Every file goes through ``camcal inspect --json`` and is compared with ``exif_tags.csv``, the tags as an
independent EXIF reader sees them: a tag's value is reported from the tag; a tag that is absent or holds
zero is unknown (null), or, when absent, a value LibRaw alone decodes, marked ``libraw``; no capture time
is invented. Files whose image data were stripped are refused in one line naming them.
Skipped only when ``../shared/realdata`` is absent (CI has it).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from camcal.io.read import load_frame
from tests.conftest import assert_one_line_error, run_cli

REALDATA = Path(__file__).resolve().parents[1].parent / "shared" / "realdata"
pytestmark = pytest.mark.skipif(not REALDATA.is_dir(), reason="../shared/realdata is absent")

FOLDERS = ("pi", "raw", "jpeg", "stripped")


def _images() -> list[Path]:
    return sorted(p for p in REALDATA.glob("*/*") if p.parent.name in FOLDERS) if REALDATA.is_dir() else []


def _tags() -> dict[str, dict[str, str]]:
    with open(REALDATA / "exif_tags.csv", newline="", encoding="utf-8") as fh:
        return {row["file"]: row for row in csv.DictReader(fh)}


@pytest.fixture(scope="module")
def inspected() -> dict[str, dict]:
    """``camcal inspect --json`` over every real file at once: {relative path: entry}."""
    files = _images()
    proc = run_cli("inspect", "--json", *files)
    assert proc.returncode == 1, proc.stderr  # the stripped files fail, the rest are reported
    entries = json.loads(proc.stdout)
    assert [e["file"] for e in entries] == [str(p) for p in files]
    failed = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(failed) == len([e for e in entries if e["error"]]), proc.stderr
    assert all(ln.startswith("camcal: failed: ") for ln in failed), proc.stderr
    return {str(Path(e["file"]).relative_to(REALDATA)): e for e in entries}


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-6 * abs(b)


@pytest.mark.parametrize("field, column", [("exposure_s", "exposure_time_tag"), ("f_number", "f_number_tag"),
                                           ("iso", "iso_tag")])
def test_exposure_values_are_the_tags_or_unknown(inspected, field, column):
    tags = _tags()
    checked = 0
    for rel, entry in inspected.items():
        if rel not in tags or entry["error"]:
            continue
        cell, value, source = tags[rel][column], entry[field], entry["sources"][field]
        if cell == "":  # no tag: unknown, or LibRaw's own decoding of a maker header, said so
            assert value is None or source == "libraw", (rel, field, value, source)
        elif float(cell) == 0:  # a tag holding zero: unknown, never LibRaw's placeholder
            assert value is None and source is None, (rel, field, value, source)
        else:
            assert value is not None and _close(value, float(cell)) and source == "tag", (rel, field, value, source)
        checked += 1
    assert checked >= 12


def test_capture_time_is_never_invented(inspected):
    tags = _tags()
    for rel, entry in inspected.items():
        if rel not in tags or entry["error"]:
            continue
        cell, value = tags[rel]["datetime_original_tag"], entry["capture_time"]
        source = entry["sources"]["capture_time"]
        if cell:
            assert value == cell[:19].replace(":", "-", 2).replace(" ", "T") and source == "tag", (rel, value)
        else:  # the Pi files and the Kiss X4: no date (LibRaw's 1970 placeholder is not one)
            assert value is None or (source == "libraw" and not value.startswith("1970")), (rel, value, source)
    for rel in ("pi/dark_frame_a03fb6b3.dng", "raw/canon_kissx4_colorchart.dng"):
        assert inspected[rel]["capture_time"] is None


def test_black_and_white_levels_of_mosaics_are_the_tags(inspected):
    tags = _tags()
    for rel, entry in inspected.items():
        row = tags.get(rel)
        if not row or entry["error"] or row["photometric"] != "32803":
            continue
        assert entry["layout"] == "bayer" and entry["channels"] == ["R", "G1", "G2", "B"]
        black = {float(v) for v in row["black_level_tag"].split()}
        assert set(entry["black_level_dn"].values()) == black
        assert entry["white_level_dn"] == float(row["white_level_tag"])


def test_zero_tags_are_unknown_and_libraw_placeholders_are_noted(inspected):
    x4 = inspected["raw/canon_kissx4_colorchart.dng"]
    assert (x4["exposure_s"], x4["f_number"], x4["iso"], x4["exposure_value_s"]) == (None, None, None, None)
    assert any("LibRaw's 1 s is not used" in n for n in x4["notes"]), x4["notes"]
    assert any(n.startswith("f_number:") for n in x4["notes"]), x4["notes"]


def test_libraw_only_values_are_marked_libraw(inspected):
    kdc = inspected["raw/RAW_KODAK_DC50_é.KDC"]  # a non-ASCII file name, an old proprietary RAW
    assert kdc["iso"] == 84 and kdc["sources"]["iso"] == "libraw"
    assert kdc["capture_time"] == "1997-04-23T08:00:47" and kdc["sources"]["capture_time"] == "libraw"
    assert kdc["exposure_s"] == pytest.approx(0.00435) and kdc["sources"]["exposure_s"] == "tag"


def test_fixed_aperture_pi_has_no_f_number(inspected):
    for rel, entry in inspected.items():
        if rel.startswith("pi/"):
            assert entry["f_number"] is None and entry["sources"]["f_number"] is None, rel
            assert entry["cfa_pattern"] == "BGGR" and (entry["width"], entry["height"]) == (1456, 1088)


def test_stripped_files_are_refused_in_one_line(inspected):
    stripped = {rel: e for rel, e in inspected.items() if rel.startswith("stripped/")}
    assert len(stripped) == 6
    for rel, entry in stripped.items():
        assert entry["error"] and "\n" not in entry["error"] and Path(rel).name in entry["error"], entry
        assert set(entry) == {"file", "error"}
    for rel in ("stripped/DNG.dng", "stripped/Panasonic.rw2"):  # decoded to zeros before: now refused
        assert "holds no image data" in stripped[rel]["error"]
        assert_one_line_error(run_cli("inspect", REALDATA / rel), Path(rel).name, "no image data")


def test_every_other_file_is_read(inspected):
    for rel, entry in inspected.items():
        if not rel.startswith("stripped/"):
            assert entry["error"] is None, entry


def test_linear_dng_is_a_three_plane_frame(inspected):
    entry = inspected["raw/canon_eos_6d_linear.dng"]
    assert entry["kind"] == "raw" and entry["layout"] == "linear" and entry["cfa_pattern"] is None
    assert entry["channels"] == ["R", "G", "B"] and (entry["width"], entry["height"]) == (1224, 816)
    assert entry["black_level_dn"] == {"R": 0.0, "G": 0.0, "B": 0.0}
    f = load_frame(REALDATA / "raw" / "canon_eos_6d_linear.dng")
    planes = f.planes()
    assert planes.shape == (3, 816, 1224) and f.black_vector().shape == (3, 1, 1)
    # three distinct colour planes (LibRaw's unused 4th plane is dropped), with real image content
    assert all(planes[k].std() > 100 for k in range(3))
    assert not np.array_equal(planes[0], planes[2])


def test_session_defaults_give_the_fixed_lens_f_number(tmp_path):
    """A Pi frame in a folder with session.toml: the f-number is the session's, marked so; the tags stay tags."""
    (tmp_path / "f.dng").symlink_to(REALDATA / "pi" / "dark_frame_a03fb6b3.dng")
    (tmp_path / "session.toml").write_text("f_number = 2.8  # the Pi GS camera's 6 mm lens\n")
    info = json.loads(run_cli("inspect", "--json", tmp_path / "f.dng").stdout)[0]
    assert info["f_number"] == 2.8 and info["sources"]["f_number"] == "session"
    assert info["sources"]["exposure_s"] == "tag" and info["exposure_s"] == pytest.approx(1 / 1008, rel=1e-6)
    assert info["exposure_value_s"] == pytest.approx(100 * (1 / 1008) / 2.8**2, rel=1e-6)


def test_human_table_shows_value_and_source():
    proc = run_cli("inspect", REALDATA / "raw" / "RAW_KODAK_DC50_é.KDC", REALDATA / "stripped" / "Nikon.nef")
    assert proc.returncode == 1
    assert "84  (libraw)" in proc.stdout and "(tag)" in proc.stdout and "1 of 2 files read" in proc.stdout
    assert proc.stderr.count("camcal: failed: ") == 1 and "Nikon.nef" in proc.stderr

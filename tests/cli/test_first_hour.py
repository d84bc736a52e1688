"""A new user's first hour (issue 30): commands that agree, and no silent nonsense."""

from __future__ import annotations

import json
import shutil

import numpy as np

from camcal.io.exr import read_exr, write_exr
from tests.conftest import assert_one_line_error, run_cli


def test_old_spellings_are_gone():
    """The old option names of an unreleased version are refused as unknown options, not rewritten."""
    new = run_cli("water", "forward", "--concentration", "89ug/L", "--depth", "20cm", "--water-model", "seed")
    old = run_cli("water", "forward", "--concentration", "89ug/L", "--depth", "20cm", "--model", "seed")
    assert new.returncode == 0, new.stderr
    assert old.returncode == 2 and "--model" in old.stderr and "Traceback" not in old.stderr
    # the default is the refined model: water, surface and all
    default = run_cli("water", "forward", "--json", "--concentration", "89ug/L", "--depth", "20cm")
    assert json.loads(default.stdout)["model"] == "refined"


def test_inversion_with_no_valid_pixel_exits_non_zero_with_reasons(tmp_path):
    ref = np.ones((16, 16), np.float32)
    write_exr(tmp_path / "r.exr", {"R": ref, "R_unc": 0.01 * ref, "L663_unc": 0.01 * ref})
    write_exr(tmp_path / "s.exr", {"R": 0.3 * ref, "R_unc": 0.003 * ref, "L663_unc": 0.003 * ref})
    base = ["water", "invert", "--submerged", tmp_path / "s.exr", "--reference", tmp_path / "r.exr", "--depth", "20cm",
            "--channel", "R", "-o", tmp_path / "c.exr"]
    # a region away from every valid pixel (the disk here fills the image: the region is outside it)
    proc = run_cli(*base, "--roi", "0,0,2,2", "--depth", "5m")
    assert_one_line_error(proc, "no valid concentration", "above_clear_water", "outside_roi")
    assert not (tmp_path / "c.exr").exists()
    # another band's σ is refused
    assert_one_line_error(run_cli(*base, "--sigma-channel", "L663_unc"), "L663_unc", "R_unc")
    # no ratio noise: no total, the summary says what is missing
    proc = run_cli(*base)
    assert proc.returncode == 0, proc.stderr
    ch, meta = read_exr(tmp_path / "c.exr", ["chl_unc_ug_per_L"])
    unc = meta["summary"]["uncertainty"]
    assert unc["total"] is None and "ratio" in unc["not_stated"] and np.all(np.isnan(ch["chl_unc_ug_per_L"]))
    proc = run_cli(*base, "--sigma-channel", "R_unc")
    assert proc.returncode == 0, proc.stderr
    ch, meta = read_exr(tmp_path / "c.exr", ["chl_unc_ug_per_L"])
    assert "total" not in meta["summary"]["uncertainty"] and meta["summary"]["uncertainty"]["dominant"] == "ratio"
    assert np.all(ch["chl_unc_ug_per_L"] > 0)
    # percentages as 1.5% or 0.015
    sig = []
    for text in ("1.5%", "0.015"):
        assert run_cli(*base, "--relative-sigma", text).returncode == 0
        sig.append(read_exr(tmp_path / "c.exr", ["chl_unc_ug_per_L"])[0]["chl_unc_ug_per_L"])
    np.testing.assert_array_equal(sig[0], sig[1])


def test_dark_bias_alone_and_frames_given_twice(session_dir, tmp_path):
    proc = run_cli("dark", "--bias", session_dir / "bias", "-o", tmp_path / "bias.json", "--json", "-j", "1")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["dark_current_dn_per_s"]["R"] is None and out["read_noise_dn"]["R"] > 0
    assert "Warning" not in proc.stderr
    # the same frames as darks and as bias (here a copy under another name): refused, naming both
    (tmp_path / "dark").mkdir()
    first = sorted((session_dir / "bias").glob("*.dng"))[0]
    for p in sorted((session_dir / "dark").glob("*.dng"))[:4]:
        shutil.copy(p, tmp_path / "dark" / p.name)
    shutil.copy(first, tmp_path / "dark" / "dark_copy.dng")
    proc = run_cli("dark", tmp_path / "dark", "--bias", session_dir / "bias", "-o", tmp_path / "d.json", "-j", "1")
    assert_one_line_error(proc, "given twice", first.name)
    assert_one_line_error(run_cli("dark", "-o", tmp_path / "d.json"), "--bias")


def test_inspect_reads_frames_csv_through_the_session_index(session_dir, tmp_path):
    root = tmp_path / "S"
    (root / "dark").mkdir(parents=True)
    frames = sorted((session_dir / "dark").glob("*.dng"))[:4]
    for p in frames:
        shutil.copy(p, root / "dark" / p.name)
    rows = (session_dir / "dark" / "frames.csv").read_text().splitlines()
    keep = [rows[0]] + [r for r in rows[1:] if r.split(",")[0] in {p.name for p in frames}]
    first = keep[1].split(",")
    tag_s = float(first[1])
    first[1] = repr(tag_s + 0.5)  # the manifest says otherwise than the file's tag
    (root / "dark" / "frames.csv").write_text("\n".join([keep[0], ",".join(first), *keep[2:]]) + "\n")
    proc = run_cli("inspect", root / "dark" / frames[0].name, "--json")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)[0]
    assert info["exposure_s"] == tag_s + 0.5 and info["sources"]["exposure_s"] == "frames.csv"
    # a file outside any session: its own tag
    shutil.copy(frames[0], tmp_path / frames[0].name)
    info = json.loads(run_cli("inspect", tmp_path / frames[0].name, "--json").stdout)[0]
    assert info["exposure_s"] == tag_s and info["sources"]["exposure_s"] == "tag"

"""``camcal water`` CLI: real subprocesses, real EXR files."""

from __future__ import annotations

import json

import numpy as np

from camcal.exr import read_exr, write_exr
from camcal.water.models import SeedModel
from tests.conftest import assert_one_line_error, run_cli


def test_invert_exr_round_trip(tmp_path):
    m = SeedModel()
    truth = np.linspace(1e-7, 4e-7, 32 * 24).reshape(24, 32)
    ref = np.full(truth.shape, 1.5, np.float32)
    sub = (m.ratio(truth, 0.2) * ref).astype(np.float32)
    sub[0, 0] = np.nan
    write_exr(tmp_path / "a.exr", {"L663": sub})
    write_exr(tmp_path / "b.exr", {"L663": ref})
    proc = run_cli("water", "invert", "--submerged", tmp_path / "a.exr", "--reference", tmp_path / "b.exr",
                   "--depth", "20cm", "--relative-sigma", "0.01", "-o", tmp_path / "chl.exr")
    assert proc.returncode == 0, proc.stderr
    ch, meta = read_exr(tmp_path / "chl.exr", ["chl_ug_per_L", "chl_unc_ug_per_L", "reason"])
    assert ch["reason"][0, 0] == 1 and np.isnan(ch["chl_ug_per_L"][0, 0])
    ok = ch["reason"] == 0
    # float32 storage of radiances and of the output: ~1e-6 relative
    np.testing.assert_allclose(ch["chl_ug_per_L"][ok], truth[ok] * 893.5e6, rtol=2e-6)
    assert np.all(ch["chl_unc_ug_per_L"][ok] > 0)
    assert meta["summary"]["valid"] == truth.size - 1


def test_invert_numbers_and_forward_json():
    proc = run_cli("water", "forward", "--concentration", "1e-7mol/L", "--depth", "10cm")
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)["ratio"][0][0]
    assert abs(r - 0.545) < 0.01
    proc = run_cli("water", "invert", "--ratio", f"{r!r},2", "--depth", "0.1m")
    out = json.loads(proc.stdout)
    assert abs(out["c_mol_per_L"][0] / 1e-7 - 1) < 1e-9 and out["c_mol_per_L"][1] is None
    assert out["reason"] == ["ok", "above_clear_water"]


def test_simulate_writes_csv_and_png(tmp_path):
    proc = run_cli("water", "simulate", "-o", tmp_path / "sim")
    assert proc.returncode == 0, proc.stderr
    for name in ("depth", "concentration"):
        assert (tmp_path / "sim" / f"ratio_vs_{name}.png").read_bytes()[:4] == b"\x89PNG"
        rows = np.loadtxt(tmp_path / "sim" / f"ratio_vs_{name}.csv", delimiter=",", comments="#", skiprows=2)
        assert rows.shape[1] == 4 and np.all(np.diff(rows[:, 1]) < 0)


def test_errors_are_one_line(tmp_path):
    assert_one_line_error(run_cli("water", "invert", "--ratio", "0.3", "--depth", "2furlongs"), "length unit")
    assert_one_line_error(run_cli("water", "invert", "--submerged", tmp_path / "no.exr", "--reference",
                                  tmp_path / "no.exr", "--depth", "1m", "-o", tmp_path / "o.exr"), "no such EXR")
    write_exr(tmp_path / "a.exr", {"L663": np.ones((4, 4), np.float32)})
    assert_one_line_error(run_cli("water", "invert", "--submerged", tmp_path / "a.exr", "--reference",
                                  tmp_path / "a.exr", "--depth", "1m", "--channel", "R", "-o", tmp_path / "o.exr"),
                          "no channel")
    assert not (tmp_path / "o.exr").exists()

"""``camcal water`` CLI: real subprocesses, real EXR files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from camcal.apply.photo import RESOLUTION_NOTE
from camcal.errors import CamcalError
from camcal.io.exr import read_exr, write_exr
from camcal.io.read import load_frame
from camcal.synth.camera import Scene
from camcal.synth.secchi import secchi_scenes, suggest_exposure_s
from camcal.water.band import band_model_from_profile
from camcal.water.invert import invert_images
from camcal.water.models import RefinedModel, SeedModel
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
                   "--depth", "20cm", "--relative-sigma", "0.01", "--water-model", "seed", "-o", tmp_path / "chl.exr")
    assert proc.returncode == 0, proc.stderr
    ch, meta = read_exr(tmp_path / "chl.exr", ["chl_ug_per_L", "chl_unc_ug_per_L", "reason"])
    assert ch["reason"][0, 0] == 1 and np.isnan(ch["chl_ug_per_L"][0, 0])
    ok = ch["reason"] == 0
    # float32 storage of radiances and of the output: ~1e-6 relative
    np.testing.assert_allclose(ch["chl_ug_per_L"][ok], truth[ok] * 893.5e6, rtol=2e-6)
    assert np.all(ch["chl_unc_ug_per_L"][ok] > 0)
    assert meta["summary"]["valid"] == truth.size - 1


def test_invert_numbers_and_forward_json():
    proc = run_cli("water", "forward", "--json", "--concentration", "1e-7mol/L", "--depth", "10cm", "--water-model",
                   "seed")
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)["ratio"][0][0]
    assert abs(r - 0.545) < 0.01
    proc = run_cli("water", "invert", "--json", "--ratio", f"{r!r},2", "--depth", "0.1m", "--water-model", "seed")
    out = json.loads(proc.stdout)
    assert abs(out["c_mol_per_L"][0] / 1e-7 - 1) < 1e-9 and out["c_mol_per_L"][1] is None
    assert out["reason"] == ["ok", "above_clear_water"]


def test_simulate_writes_csv_and_png(tmp_path):
    proc = run_cli("water", "simulate", "-o", tmp_path / "sim")
    assert proc.returncode == 0, proc.stderr
    for name in ("depth", "concentration"):
        assert (tmp_path / "sim" / f"ratio_vs_{name}.png").read_bytes()[:4] == b"\x89PNG"
        rows = np.loadtxt(tmp_path / "sim" / f"ratio_vs_{name}.csv", delimiter=",", comments="#", skiprows=2)
        assert rows.shape[1] == 5 and np.all(np.diff(rows[:, 1]) < 0)
    table = (tmp_path / "sim" / "appendix_comparison.md").read_text()
    assert "appendix as written" in table and table.count("\n") == 2 + 20
    head = (tmp_path / "sim" / "appendix_comparison.csv").read_text().splitlines()[1].split(",")
    assert {"error_eq11", "c_appendix_as_written", "error_second_order_exact"} <= set(head)


def test_errors_are_one_line(tmp_path):
    assert_one_line_error(run_cli("water", "invert", "--json", "--ratio", "0.3", "--depth", "2furlongs"), "length unit")
    assert_one_line_error(run_cli("water", "invert", "--submerged", tmp_path / "no.exr", "--reference",
                                  tmp_path / "no.exr", "--depth", "1m", "-o", tmp_path / "o.exr"), "no such EXR")
    write_exr(tmp_path / "a.exr", {"L663": np.ones((4, 4), np.float32)})
    assert_one_line_error(run_cli("water", "invert", "--submerged", tmp_path / "a.exr", "--reference",
                                  tmp_path / "a.exr", "--depth", "1m", "--channel", "R", "-o", tmp_path / "o.exr"),
                          "no channel")
    assert not (tmp_path / "o.exr").exists()


@pytest.fixture(scope="module")
def secchi_exrs(camera, tmp_path_factory):
    """Photos (real DNGs) of a Secchi disk by the calibrated camera; EXR channel R = dark-subtracted R-plane DN
    rate, which is the band radiance up to the constant ∫c_R dλ that cancels in the ratio."""
    tmp = tmp_path_factory.mktemp("secchi_exr")
    sc = secchi_scenes(camera, c_ug_per_L=60.0, depth_m=0.8, radius_fraction=0.6)
    rng = np.random.default_rng(99)

    def rate(name, scene, t):
        light = load_frame(camera.write_dng(tmp / f"{name}.dng", scene, exposure_s=t, rng=rng)).planes()[0]
        dark = np.mean([load_frame(camera.write_dng(tmp / f"{name}_d{k}.dng", Scene.dark(), exposure_s=t,
                                                    rng=rng)).planes()[0] for k in range(3)], axis=0)
        return ((light - dark) / t).astype(np.float32)

    for name, scene, spec in (("ref", sc.reference, sc.reference_radiance), ("sub", sc.submerged,
                                                                           sc.submerged_radiance)):
        write_exr(tmp / f"{name}.exr", {"R": rate(name, scene, suggest_exposure_s(camera, spec))},
                  {"resolution": RESOLUTION_NOTE})  # R-plane pixels: half resolution, as apply writes
    return tmp / "sub.exr", tmp / "ref.exr", sc.truth


def test_invert_band_aware_with_profile(profile_path, secchi_exrs, tmp_path):
    sub, ref, truth = secchi_exrs
    roi = "152,88,80,80"  # photo pixels = R-plane 76,44,40,40, well inside the disk (centre 95.75,63.75; radius 38.4)
    proc = run_cli("water", "invert", "--submerged", sub, "--reference", ref, "--depth", "80cm",
                   "--water-model", "refined", "--profile", profile_path, "--roi", roi, "-o", tmp_path / "chl.exr")
    assert proc.returncode == 0, proc.stderr
    ch, meta = read_exr(tmp_path / "chl.exr", ["chl_ug_per_L", "reason"])
    assert meta["inversion"] == "band" and meta["channel"] == "R" and meta["illuminant"] == "D65"
    assert meta["summary"]["valid"] == 1600
    assert meta["roi"]["exr_pixels_x_y_w_h"] == [76, 44, 40, 40]  # photo pixels halved onto the EXR's grid
    ok = ch["reason"] == 0
    # the profile's c_R (from the noisy sweep) biases C by < 1 % here; ≈ 5 % per-pixel noise averages out
    assert np.median(ch["chl_ug_per_L"][ok]) == pytest.approx(truth["c_ug_per_L"], rel=0.05)
    # numbers only, on the predicted ratio: the profile's band model reproduces the camera's truth to 1 %
    proc = run_cli("water", "invert", "--json", "--ratio", repr(truth["predicted_red_band_ratio"]), "--depth", "0.8m",
                   "--water-model", "refined", "--profile", profile_path)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["band_model"]["water_absorption"] == "Pope & Fry 1997"
    assert out["c_ug_per_L"][0] == pytest.approx(truth["c_ug_per_L"], rel=0.01)
    # the profile's u_c(λ) carried to C (no other input stated): a positive term, and the only one
    sens = out["sigma_terms_ug_per_L"]["sensitivity"][0]
    assert set(out["sigma_terms_ug_per_L"]) == {"sensitivity"} and 0 < sens < 0.2 * truth["c_ug_per_L"]
    # ... but no total: the ratio's noise is not stated, so the summary says what is missing instead
    assert out["uncertainty"]["total"] is None and out["sigma_ug_per_L"] == [None]
    assert "ratio" in out["uncertainty"]["not_stated"]
    # the narrowband reading of the same broad red channel (ε at 663 nm, in-process) is far off
    rs, _ = read_exr(sub, ["R"])
    rr, _ = read_exr(ref, ["R"])
    nb = invert_images(rs["R"], rr["R"], RefinedModel(), 0.8, roi=(76, 44, 40, 40))
    assert not np.nanmedian(nb.c_ug_per_L) == pytest.approx(truth["c_ug_per_L"], rel=0.3)


def test_profile_errors(profile_path, tmp_path):
    assert_one_line_error(run_cli("water", "invert", "--json", "--ratio", "0.3", "--depth", "1m", "--profile",
                                  tmp_path / "none.camcal"))
    with pytest.raises(CamcalError, match="no channel"):
        band_model_from_profile(profile_path, "IR")
    with pytest.raises(CamcalError, match="illuminant"):
        band_model_from_profile(profile_path, "R", illuminant="candle")


def test_invert_refuses_exrs_of_another_profile_or_mixed_scales(tmp_path, demo_run, profile_path):
    """The EXRs store the hash of the profile that made them: another --profile is refused naming both, and so is
    a pair of EXRs from two profiles or of relative and absolute radiance (exit 2, one line)."""
    demo, _ = demo_run
    sub, ref = demo / "radiance" / "disk_submerged.dng.exr", demo / "radiance" / "disk_reference.dng.exr"
    base = ("water", "invert", "--depth", "0.8m", "-o", tmp_path / "c.exr")
    ok = run_cli(*base, "--submerged", sub, "--reference", ref, "--profile", demo / "camera.camcal")
    assert ok.returncode == 0, ok.stderr
    proc = run_cli(*base, "--submerged", sub, "--reference", ref, "--profile", profile_path)
    assert_one_line_error(proc, "disk_submerged.dng.exr", "was made by the profile", str(profile_path))
    _, meta = read_exr(sub)
    assert meta["profile_sha256"][:12] in proc.stderr
    img = np.ones((8, 8), np.float32)
    write_exr(tmp_path / "abs.exr", {"R": img}, {"radiance_scale": "absolute", "profile_sha256": "a" * 64})
    write_exr(tmp_path / "rel.exr", {"R": img}, {"radiance_scale": "relative", "profile_sha256": "a" * 64})
    write_exr(tmp_path / "oth.exr", {"R": img}, {"radiance_scale": "absolute", "profile_sha256": "b" * 64})
    pair = ("water", "invert", "--depth", "0.5m", "--channel", "R", "-o", tmp_path / "d.exr", "--relative-sigma",
            "1%")
    proc = run_cli(*pair, "--submerged", tmp_path / "rel.exr", "--reference", tmp_path / "abs.exr")
    assert_one_line_error(proc, "rel.exr", "relative radiance", "abs.exr", "absolute radiance")
    proc = run_cli(*pair, "--submerged", tmp_path / "oth.exr", "--reference", tmp_path / "abs.exr")
    assert_one_line_error(proc, "oth.exr", "bbbbbbbbbbbb", "abs.exr", "aaaaaaaaaaaa")


def test_water_outputs_are_tables_and_json_only_when_asked():
    """Tables for people by default; --json prints JSON with its characters as they are (σ, not \\u03c3)."""
    proc = run_cli("water", "forward", "--concentration", "30ug/L,60ug/L", "--depth", "0.5m,1m")
    assert proc.returncode == 0, proc.stderr
    assert "depth (m)" in proc.stdout and "C = 30 µg/L" in proc.stdout and "0.16613" in proc.stdout
    assert not proc.stdout.lstrip().startswith("{")
    proc = run_cli("water", "invert", "--ratio", "0.3,0.25", "--depth", "0.3m", "--relative-sigma", "1%")
    assert proc.returncode == 0, proc.stderr
    assert "C (µg/L)" in proc.stdout and "σ_C (µg/L)" in proc.stdout and not proc.stdout.lstrip().startswith("{")
    proc = run_cli("water", "invert", "--json", "--ratio", "0.3", "--depth", "0.3m")
    assert "\\u03c3" not in proc.stdout and "σ_C" in proc.stdout
    assert json.loads(proc.stdout)["c_ug_per_L"][0] > 0


def test_bare_depth_is_refused_listing_the_units():
    for argv in (("water", "invert", "--ratio", "0.3", "--depth", "0.8"),
                 ("water", "forward", "--concentration", "30ug/L", "--depth", "0.8")):
        assert_one_line_error(run_cli(*argv), "--depth 0.8 has no unit", "0.8m", "0.8cm", "m, cm, mm")
    assert run_cli("water", "invert", "--ratio", "0.3", "--depth", "80cm").returncode == 0

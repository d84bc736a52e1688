"""The README's first command: `camcal demo` runs end to end and every check is within tolerance."""

from camcal.io.exr import read_exr
from camcal.models.profile import load_profile


def test_demo_end_to_end(demo_run):
    out, proc = demo_run  # `camcal demo -o DIR` by the real CLI, run once for this file and tests/test_docs_run.py
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "all checks within tolerance" in proc.stdout
    assert "✗" not in proc.stdout
    # the files it promises are real
    profile = load_profile(out / "camera.camcal")
    assert profile.spectral is not None and profile.dark is not None
    chans, meta = read_exr(out / "radiance" / "disk_submerged.dng.exr", ["R", "G", "B", "L663", "L663_unc"])
    assert chans["R"].shape == (128, 192)
    chl, _ = read_exr(out / "chlorophyll.exr", ["chl_ug_per_L"])
    assert 57.0 < float(__import__("numpy").nanmedian(chl["chl_ug_per_L"][54:74, 86:106])) < 63.0
    assert (out / "report.html").stat().st_size > 100_000


def test_phone_demo_end_to_end(tmp_path):
    """`camcal demo --phone`: chart (with the module's datasheet IR cut) → profile → apply → secchi; every check
    within its tolerance (grey field 3 %, chlorophyll-a 5 % DNG and 10 % HEIC in the 20 µg/L lake, σ_C covering),
    and the chart-only profile's chlorophyll reported beside."""
    import json

    from tests.conftest import run_cli

    proc = run_cli("demo", "--phone", "-o", tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "all checks within tolerance" in proc.stdout
    out = json.loads((tmp_path / "phone_demo.json").read_text())
    chl = [c for c in out["checks"] if c["quantity"].startswith("chlorophyll")]
    assert len(chl) == 2 and all(c["ok"] and c["truth"] == 20.0 for c in chl)
    assert set(out["chart_only"]) == {"dng", "heic"}
    prof = load_profile(tmp_path / "phone.camcal")
    assert prof.provenance.options["chart"]["ir_cut"]["cut_nm"] == 650.0
    assert prof.spectral.source["basis"]["ir_cut"]["sigma_nm"] == 10.0

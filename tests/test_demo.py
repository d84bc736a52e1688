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

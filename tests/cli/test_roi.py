"""One ``--roi`` (x,y,w,h photo pixels, rounded outward to the grid a stage works on) for linearity and sweep:
a region given in photo pixels measures exactly the pixels of the centred fraction it equals. ``--roi-fraction``
is a fraction of each side for both commands (camcal.region's convention)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from camcal.calibrate.response import SERIES_ROI_FRACTION, roi_slices, roi_window
from camcal.io.read import load_frame
from camcal.region import DEFAULT_ROI_FRACTION, central_roi
from tests.conftest import assert_one_line_error, run_cli


def _linearity(folder, out, *extra):
    proc = run_cli("linearity", folder, "-o", out, "--json", "--no-plot", *extra)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)["models"]["raw"]["channels"]


def test_linearity_roi_in_photo_pixels(session_dir, tmp_path):
    folder = session_dir / "linearity"
    first = load_frame(sorted(folder.glob("*.dng"))[0])
    ys, xs = roi_slices((first.shape[0] // 2, first.shape[1] // 2), roi_window(None))  # the default window
    region = f"{2 * xs.start},{2 * ys.start},{2 * (xs.stop - xs.start)},{2 * (ys.stop - ys.start)}"
    default = _linearity(folder, tmp_path / "a.json")
    same = _linearity(folder, tmp_path / "b.json", "--roi", region)
    fraction = _linearity(folder, tmp_path / "c.json", "--roi-fraction", repr(SERIES_ROI_FRACTION))  # √0.1 a side
    for ch in ("R", "G1", "G2", "B"):
        assert same[ch]["alpha"] == pytest.approx(default[ch]["alpha"], rel=1e-12)
        assert fraction[ch]["alpha"] == pytest.approx(default[ch]["alpha"], rel=1e-12)
    # a region one plane pixel narrower measures other pixels: the option is not ignored
    narrower = f"{2 * xs.start + 2},{2 * ys.start},{2 * (xs.stop - xs.start) - 2},{2 * (ys.stop - ys.start)}"
    other = _linearity(folder, tmp_path / "d.json", "--roi", narrower)
    assert other["R"]["alpha"] != default["R"]["alpha"]


def _every_50_nm(sweep: Path, out: Path) -> Path:
    """The sweep's frames at 400, 450, ... 700 nm (7 wavelengths, every repeat) and their sweep.csv rows: the ROI is
    the same at every wavelength, so 7 of the 61 exercise the same pixels and code as all of them."""
    out.mkdir()
    lines = (sweep / "sweep.csv").read_text().splitlines(keepends=True)
    kept = [ln for ln in lines[1:] if float(ln.split(",")[1]) % 50 == 0]
    assert len(kept) == 7 * len([ln for ln in lines[1:] if ln.split(",")[1] == "400.0"])
    (out / "sweep.csv").write_text(lines[0] + "".join(kept))
    for ln in kept:
        shutil.copyfile(sweep / ln.split(",")[0], out / ln.split(",")[0])
    return out


def test_sweep_roi_in_photo_pixels(session_dir, tmp_path):
    folder = _every_50_nm(session_dir / "sweep", tmp_path / "sweep")
    first = load_frame(sorted(folder.glob("*.dng"))[0])
    x0, y0, x1, y1 = central_roi((first.shape[0] // 2, first.shape[1] // 2), DEFAULT_ROI_FRACTION)
    runs = {}
    for name, extra in (("default", ()), ("region", ("--roi", f"{2 * x0},{2 * y0},{2 * (x1 - x0)},{2 * (y1 - y0)}")),
                        ("fraction", ("--roi-fraction", repr(DEFAULT_ROI_FRACTION)))):
        out = tmp_path / f"{name}.csv"
        proc = run_cli("sweep", folder, "-o", out, "--sweep-mode", "relative", "--json", "--jobs", "1", *extra)
        assert proc.returncode == 0, proc.stderr
        runs[name] = out.read_text()
    assert runs["region"] == runs["default"] and runs["fraction"] == runs["default"]


@pytest.mark.parametrize("cmd", ["linearity", "sweep"])
def test_roi_and_fraction_together_or_old_forms_are_one_line_errors(session_dir, tmp_path, cmd):
    out = tmp_path / ("o.csv" if cmd == "sweep" else "o.json")
    folder = session_dir / cmd
    assert_one_line_error(run_cli(cmd, folder, "-o", out, "--roi", "0,0,8,8", "--roi-fraction", "0.1"),
                          "--roi-fraction")
    assert_one_line_error(run_cli(cmd, folder, "-o", out, "--roi", "0.1"), "--roi", "x,y,w,h")
    assert not out.exists()

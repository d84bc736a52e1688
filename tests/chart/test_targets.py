"""The ColorChecker's reflectances, their chart-to-chart spread, and the reader of a user's measured chart."""

from __future__ import annotations

import numpy as np
import pytest

from camcal.chart.targets import (
    GRID_NM,
    NEUTRAL_PATCHES,
    PATCH_NAMES,
    U_EXTRAPOLATED_RELATIVE,
    chart_spread,
    published_chart,
    read_chart_csv,
)
from camcal.errors import CamcalError


def test_published_charts_follow_colour_science_and_differ_by_their_spread():
    import colour

    a, b = published_chart("BabelColor Average"), published_chart("ColorChecker N Ohta")
    assert a.reflectance.shape == (24, GRID_NM.size) and a.names == PATCH_NAMES
    sd = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["neutral 5 (.70 D)"]
    assert b.reflectance[21, GRID_NM == 550][0] == pytest.approx(sd[550], abs=1e-12)
    # neutrals: flat, white to black, the six last patches
    neutral = a.reflectance[list(NEUTRAL_PATCHES)][:, (GRID_NM >= 420) & (GRID_NM <= 680)]
    assert np.all(np.diff(neutral.mean(axis=1)) < 0)
    assert np.all(neutral.std(axis=1) / neutral.mean(axis=1) < 0.1)
    # the spread is what separates the two published charts: their difference is inside ~2u almost everywhere
    inside = (GRID_NM <= 730)
    z = np.abs(a.reflectance - b.reflectance)[:, inside] / chart_spread()[:, inside]
    assert np.mean(z <= 2) > 0.95 and np.all(chart_spread() > 0)
    # BabelColor stops at 730 nm: held, with a larger u beyond
    out = GRID_NM > 730
    assert np.all(a.u_reflectance[:, out] >= U_EXTRAPOLATED_RELATIVE * a.reflectance[:, out] - 1e-12)
    with pytest.raises(CamcalError, match="unknown published chart"):
        published_chart("PMC")


def _write(path, header, rows):
    path.write_text("\n".join([",".join(header)] + [",".join(f"{v:g}" for v in r) for r in rows]) + "\n")
    return path


def test_measured_chart_csv_by_name_or_order(tmp_path):
    ref = published_chart("ColorChecker N Ohta")
    wl = np.arange(400.0, 701.0, 10.0)
    r = np.array([np.interp(wl, ref.wavelength_nm, row) for row in ref.reflectance])
    names = [n.upper().replace(" ", "_") for n in PATCH_NAMES[::-1]]  # other spelling, other order
    p = _write(tmp_path / "chart.csv", ["wavelength_nm", *names], np.column_stack([wl, r[::-1].T]))
    got = read_chart_csv(p)
    inside = (GRID_NM >= 400) & (GRID_NM <= 700)
    np.testing.assert_allclose(got.reflectance[:, inside], ref.reflectance[:, inside], atol=0.02)
    assert got.source["kind"] == "measured" and len(got.source["sha256"]) == 64
    assert np.all(got.u_reflectance[:, ~inside] >= U_EXTRAPOLATED_RELATIVE * got.reflectance[:, ~inside] - 1e-12)
    p2 = _write(tmp_path / "ordered.csv", ["wavelength_nm", *[f"p{i}" for i in range(24)]], np.column_stack([wl, r.T]))
    np.testing.assert_allclose(read_chart_csv(p2).reflectance, got.reflectance)
    assert read_chart_csv(p2, u_reflectance=0.01).u_reflectance[0, 10] == pytest.approx(0.01)


@pytest.mark.parametrize("content,message", [
    ("wl,a\n1,2\n3,4\n", "wavelength_nm"),
    ("wavelength_nm," + ",".join(f"p{i}" for i in range(23)) + "\n" + "\n".join(
        ",".join(["400"] + ["0.5"] * 23) for _ in range(3)) + "\n", "one column per patch"),
    ("wavelength_nm," + ",".join(f"p{i}" for i in range(24)) + "\n500," + ",".join(["50"] * 24) + "\n510,"
     + ",".join(["50"] * 24) + "\n", "percentage"),
    ("wavelength_nm," + ",".join(f"p{i}" for i in range(24)) + "\n500," + ",".join(["0.5"] * 24) + "\n490,"
     + ",".join(["0.5"] * 24) + "\n", "increase"),
    ("wavelength_nm," + ",".join(f"p{i}" for i in range(24)) + "\n500," + ",".join(["x"] * 24) + "\n510,"
     + ",".join(["0.5"] * 24) + "\n", "not numbers"),
    ("wavelength_nm," + ",".join(f"p{i}" for i in range(24)) + "\n500,0.5\n510,0.5\n", "cells"),
])
def test_bad_chart_csv_is_refused_in_one_line(tmp_path, content, message):
    p = tmp_path / "bad.csv"
    p.write_text(content)
    with pytest.raises(CamcalError, match=message) as e:
        read_chart_csv(p)
    assert "\n" not in str(e.value) and "bad.csv" in str(e.value)


def test_chart_csv_size_is_bounded(tmp_path):
    p = tmp_path / "huge.csv"
    p.write_bytes(b"wavelength_nm," + b"1," * (3 * 1024 * 1024))
    with pytest.raises(CamcalError, match="larger|line"):
        read_chart_csv(p)

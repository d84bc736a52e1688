"""HTML report: self-contained page, embedded PNG plots, rendered by headless Chromium with its plots visible."""

from __future__ import annotations

import base64
import io
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from camcal.errors import CamcalError
from camcal.models.profile import contract, load_profile
from camcal.report.page import render_report, write_report
from camcal.synth.session import SessionPlan, write_session
from tests.conftest import assert_one_line_error, run_cli

IMG_SRC = re.compile(r'<img\b[^>]*\bsrc="([^"]*)"')
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync")
WINDOW = (1200, 3000)
CHROMIUM_TIMEOUT_S = 60

# Appended to a COPY of the report (the report itself has no scripts): after the load event, record
# each image's decoded size and its box in CSS pixels, so that --dump-dom shows them.
PROBE = ('<script>window.addEventListener("load",()=>{for(const im of document.images){const r='
         'im.getBoundingClientRect();im.setAttribute("data-probe",[im.naturalWidth,im.naturalHeight,'
         'im.complete?1:0,Math.round(r.left),Math.round(r.top+window.scrollY),Math.round(r.width),'
         'Math.round(r.height)].join(","));}document.body.setAttribute("data-probed","1");});</script>')


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        found = shutil.which(name)
        if found:
            return found
    return None


def _run_chromium(binary: str, tmp: Path, *args: str) -> subprocess.CompletedProcess:
    profile_dir = tmp / f"chromium-profile-{len(list(tmp.glob('chromium-profile-*')))}"
    profile_dir.mkdir()
    cmd = [binary, *CHROMIUM_FLAGS, f"--user-data-dir={profile_dir}", f"--window-size={WINDOW[0]},{WINDOW[1]}", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=CHROMIUM_TIMEOUT_S, stdin=subprocess.DEVNULL)


def _n_colours(rgb: np.ndarray) -> int:
    """Distinct colours of an (..., 3) uint8 array (packed to one integer each: fast)."""
    flat = rgb.reshape(-1, 3).astype(np.uint32)
    return int(np.unique((flat[:, 0] << 16) | (flat[:, 1] << 8) | flat[:, 2]).size)


def _images(page: str) -> list[bytes]:
    srcs = IMG_SRC.findall(page)
    prefix = "data:image/png;base64,"
    assert all(s.startswith(prefix) for s in srcs), [s[:40] for s in srcs]
    return [base64.b64decode(s[len(prefix):], validate=True) for s in srcs]


def _assert_self_contained(page: str) -> None:
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert "<script" not in page.lower() and "<link" not in page.lower()
    # every src/href is embedded data or an in-page anchor: nothing to fetch
    for attr in re.findall(r'\b(?:src|href)="([^"]*)"', page):
        assert attr.startswith(("data:", "#")), attr[:60]
    assert "url(" not in page  # no CSS resource either


def _contract_in_page(page: str) -> dict:
    m = re.search(r"<pre>(.*?)</pre>", page, re.S)
    assert m, "the JSON contract block is missing"
    import html

    return json.loads(html.unescape(m.group(1)))


# ---------------------------------------------------------------------------------------------
# fixtures: a full profile (the session_dir fixture) and a dark-only one
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def full_report(profile_path, tmp_path_factory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("report_full")
    prof = profile_path
    html_path = tmp / "out" / "report.html"
    proc = run_cli("report", prof, "-o", html_path)
    assert proc.returncode == 0, proc.stderr
    assert "wrote" in proc.stdout and "not calibrated" not in proc.stdout
    return prof, html_path


@pytest.fixture(scope="module")
def dark_only_profile(camera, tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("report_dark")
    # few frames: this profile only has to exist, its numbers are tested in test_dark.py
    session = write_session(tmp / "S", camera, SessionPlan(stages=("bias", "dark"), n_bias=8, n_dark=3))
    prof = tmp / "dark.camcal"
    proc = run_cli("calibrate", session, "-o", prof)
    assert proc.returncode == 0, proc.stderr
    return prof


# ---------------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------------
def test_full_report_is_self_contained_with_png_plots(full_report):
    prof, html_path = full_report
    page = html_path.read_text(encoding="utf-8")
    _assert_self_contained(page)
    pngs = _images(page)
    # dark, flat, response RAW, response JPEG, c(λ)
    assert len(pngs) == 5
    for png in pngs:
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        im = Image.open(io.BytesIO(png))
        im.load()  # a full decode: a truncated or corrupt stream raises here
        assert im.format == "PNG" and 800 <= im.width <= 2000 and 300 <= im.height <= 1200, im.size
        rgb = np.asarray(im.convert("RGB")).reshape(-1, 3)
        # a plot has axes, text and coloured data: many colours and a good share of non-white pixels
        assert _n_colours(rgb) > 200
        assert np.mean(np.any(rgb < 235, axis=1)) > 0.05
    for section in ("dark", "flat", "response", "spectral_sensitivity", "provenance"):
        assert f'<section id="{section}">' in page
    assert 'class="missing"' not in page
    assert "RAW" in page and "JPEG / processed" in page


def test_full_report_numbers_follow_the_contract(full_report):
    prof, html_path = full_report
    page = html_path.read_text(encoding="utf-8")
    profile = load_profile(prof)
    c = contract(profile)
    assert _contract_in_page(page) == json.loads(json.dumps(c))
    # tables and provenance carry the contract's numbers (formatted to 5 significant digits)
    assert f"{c['dark']['dark_current_dn_per_s']['G']:.5g}" in page
    assert f"{c['dark']['read_noise_dn']['R']:.5g}" in page
    assert f"{c['flat']['corner_gain']['B']:.5g}" in page
    assert f"{c['response']['gamma']['G1']:.5g}" in page
    assert f"<td>{c['dark']['hot_pixel_count']}</td>" in page
    assert profile.content_sha256 and profile.content_sha256 in page
    assert profile.provenance.created_utc in page
    n = len(profile.provenance.inputs)
    assert n > 0 and f"{n} (bias:" in page
    assert f"camcal version (profile)</td><td class=\"l\">{profile.provenance.camcal_version}" in page
    assert "sweep_mode" in page  # options table
    cm = profile.response["processed"].colour_matrix  # the session has JPEG twins in its sweep
    assert cm is not None and "Colour matrix" in page
    assert f"{cm.matrix[1, 1]:.5g} ± {cm.matrix_unc[1, 1]:.2g}" in page


def test_report_renders_in_headless_chromium(full_report, tmp_path):
    binary = _chromium()
    if binary is None:
        pytest.skip("no chromium binary on PATH (Debian: apt-get install chromium; .ci/run installs it)")
    _, html_path = full_report
    shot = tmp_path / "shot.png"
    proc = _run_chromium(binary, tmp_path, f"--screenshot={shot}", html_path.resolve().as_uri())
    assert proc.returncode == 0 and shot.exists(), proc.stderr[-2000:]
    screen = np.asarray(Image.open(shot).convert("RGB"))
    assert screen.shape[:2] == (WINDOW[1], WINDOW[0])
    flat_rgb = screen.reshape(-1, 3)
    assert _n_colours(flat_rgb) > 1000, "screenshot looks blank"

    # where the images are, and whether Chromium decoded them
    probe = tmp_path / "probe.html"
    probe.write_text(html_path.read_text(encoding="utf-8").replace("</body>", PROBE + "</body>"), encoding="utf-8")
    proc = _run_chromium(binary, tmp_path, "--dump-dom", probe.resolve().as_uri())
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert 'data-probed="1"' in proc.stdout
    boxes = [tuple(int(v) for v in m.split(",")) for m in re.findall(r'data-probe="([^"]*)"', proc.stdout)]
    assert len(boxes) == 5
    visible = 0
    for nat_w, nat_h, complete, x, y, w, h in boxes:
        assert complete == 1 and nat_w >= 800 and nat_h >= 300, (nat_w, nat_h, complete)
        assert w > 500 and h > 150  # laid out at a readable size
        if y + h > WINDOW[1]:
            continue  # below the screenshot
        visible += 1
        region = screen[y + 5:y + h - 5, x + 5:x + w - 5].reshape(-1, 3)
        # the plot is painted: not white, colourful (colour maps, channel colours)
        assert np.mean(np.any(region < 235, axis=1)) > 0.05, (x, y, w, h)
        assert _n_colours(region) > 200, (x, y, w, h)
        saturation = region.max(axis=1).astype(int) - region.min(axis=1)
        assert np.mean(saturation > 60) > 0.01, "no coloured pixels in the plot area"
    assert visible >= 2  # the dark and flat figures are within the first 3000 px


def test_partial_profile_has_not_calibrated_notes(dark_only_profile, tmp_path):
    out = tmp_path / "dark.html"
    proc = run_cli("report", dark_only_profile, "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "not calibrated: flat, response, spectral_sensitivity" in " ".join(proc.stdout.split())
    page = out.read_text(encoding="utf-8")
    _assert_self_contained(page)
    assert len(_images(page)) == 1  # the dark figure only
    missing = re.findall(r'<section id="(\w+)"><h2>[^<]*</h2><p class="missing">not calibrated', page)
    assert missing == ["flat", "response", "spectral_sensitivity"]
    assert '<section id="dark"><h2>' in page and 'alt="dark current histogram and map"' in page
    c = _contract_in_page(page)
    assert c["flat"] is None and c["response"] is None and c["spectral_sensitivity"] is None
    assert c["dark"]["hot_pixel_count"] == contract(load_profile(dark_only_profile))["dark"]["hot_pixel_count"]


def test_render_is_pure_and_write_is_atomic(dark_only_profile, tmp_path):
    profile = load_profile(dark_only_profile)
    calls = []
    a = render_report(profile, progress=lambda s, d, t: calls.append((s, d, t)))
    assert a == render_report(profile)  # no time stamps, no randomness
    assert calls[-1] == ("done", 5, 5) and [d for _, d, _ in calls] == list(range(6))
    target = tmp_path / "r.html"
    target.write_text("old")
    write_report(profile, target)
    assert target.read_text(encoding="utf-8") == a
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.html"]  # no temporary file left
    with pytest.raises(CamcalError, match="is a folder"):
        write_report(profile, tmp_path)


def test_report_cli_errors(tmp_path, dark_only_profile):
    assert_one_line_error(run_cli("report", tmp_path / "nope.camcal", "-o", tmp_path / "r.html"), "nope.camcal")
    bad = tmp_path / "truncated.camcal"
    bad.write_bytes(dark_only_profile.read_bytes()[:1000])
    assert_one_line_error(run_cli("report", bad, "-o", tmp_path / "r.html"), "truncated.camcal")
    assert not (tmp_path / "r.html").exists()
    assert_one_line_error(run_cli("report", dark_only_profile, "-o", tmp_path), "is a folder")


def test_bias_only_profile_shows_the_bias(camera, tmp_path):
    """A bias-only calibration has no dark current (β unknown): the dark figure shows the bias instead."""
    session = write_session(tmp_path / "S", camera, SessionPlan(stages=("bias",), n_bias=4))
    prof = tmp_path / "bias.camcal"
    proc = run_cli("calibrate", session, "-o", prof)
    assert proc.returncode == 0, proc.stderr
    assert load_profile(prof).dark.dark_current_dn_per_s is None
    out = tmp_path / "bias.html"
    proc = run_cli("report", prof, "-o", out)
    assert proc.returncode == 0, proc.stderr
    page = out.read_text(encoding="utf-8")
    _assert_self_contained(page)
    (png,) = _images(page)
    im = Image.open(io.BytesIO(png))
    im.load()
    assert im.format == "PNG" and im.width >= 800
    assert _n_colours(np.asarray(im.convert("RGB"))) > 200

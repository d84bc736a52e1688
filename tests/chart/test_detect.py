"""camcal.chart.detect and camcal.chart.patches: the ColorChecker found, oriented and its patches read."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from camcal.chart.detect import ChartLocation, detect_chart, locate_chart, neutral_score, parse_corners
from camcal.chart.patches import sample_patches
from camcal.errors import CamcalError
from camcal.frame import Frame

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
CANON_CHART = REALDATA / "raw" / "canon_kissx4_colorchart.dng"


def _srgb_chart() -> np.ndarray:
    """(24, 3) 8-bit sRGB of the ColorChecker's patches (colour-science's reference values)."""
    import colour

    cc = colour.CCS_COLOURCHECKERS["ColorChecker24 - After November 2014"]
    xyz = colour.xyY_to_XYZ(np.array(list(cc.data.values())))
    rgb = colour.XYZ_to_sRGB(xyz, cc.illuminant)  # encoded (the sRGB transfer function applied)
    return np.clip(np.round(255 * rgb), 0, 255)


def _render(corners: np.ndarray, size=(900, 1200), noise=2.0, seed=0) -> np.ndarray:
    """A processed image of the chart: patches with black gaps on a grey card, warped onto ``corners``."""
    cell = 60
    w, h = 6 * cell, 4 * cell
    flat = np.full((h, w, 3), 20.0)
    rgb = _srgb_chart()
    for k in range(24):
        r, c = divmod(k, 6)
        flat[r * cell + 6:(r + 1) * cell - 6, c * cell + 6:(c + 1) * cell - 6] = rgb[k]
    src = np.array([[0, 0], [w, 0], [w, h], [0, h]], np.float32)
    m = cv2.getPerspectiveTransform(src, corners.astype(np.float32))
    out = cv2.warpPerspective(flat.astype(np.float32), m, (size[1], size[0]), flags=cv2.INTER_LINEAR,
                              borderValue=(128, 120, 110))
    out += np.random.default_rng(seed).normal(0, noise, out.shape)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def _frame(img: np.ndarray) -> Frame:
    return Frame(img, "processed", None, {"R": 0.0, "G": 0.0, "B": 0.0}, 255.0)


CORNERS = np.array([[300.0, 250.0], [900.0, 280.0], [880.0, 680.0], [310.0, 650.0]])


@pytest.mark.parametrize("turn", [0, 2])
def test_a_rendered_chart_is_found_and_oriented(turn):
    """The detector finds the grid; the neutral row fixes which corner is patch 1's, also upside down."""
    corners = np.roll(CORNERS, turn, axis=0)  # turn 2: the chart photographed upside down
    loc = detect_chart(_frame(_render(corners)))
    assert loc.method == "detected"
    # the detector fits a rectangle to the swatches: under perspective its corners are off by up to ~40 px, but
    # every patch centre falls inside the central half of its ~100-pixel patch
    truth = ChartLocation(corners, "corners").patch_centres_px()
    assert np.max(np.hypot(*(loc.patch_centres_px() - truth).T)) < 25
    assert loc.neutral_score < 0.1


@pytest.mark.parametrize("corners", [
    np.array([[150.0, 400.0], [750.0, 420.0], [740.0, 800.0], [160.0, 780.0]]),  # a level chart, phone upright
    np.array([[700.0, 250.0], [690.0, 850.0], [290.0, 840.0], [300.0, 240.0]]),  # the chart turned by 90°
])
def test_a_portrait_photo_is_turned_for_the_detector_and_back(corners):
    img = _render(corners, size=(1200, 900))
    loc = detect_chart(_frame(img))
    truth = ChartLocation(corners, "corners").patch_centres_px()
    assert np.max(np.hypot(*(loc.patch_centres_px() - truth).T)) < 25


def test_no_chart_names_the_corners_option():
    img = np.random.default_rng(1).integers(100, 140, (600, 800, 3)).astype(np.uint8)
    with pytest.raises(CamcalError, match="--corners"):
        detect_chart(_frame(img))


def test_patches_are_read_in_their_centres_with_the_covariance_of_the_mean():
    img = _render(CORNERS, noise=4.0)
    ps = sample_patches(_frame(img), ChartLocation(CORNERS, "corners"))
    assert np.max(np.abs(ps.mean_dn - _srgb_chart())) < 1.5  # the patch colour, not its gap or border
    n = ps.n_pixels
    assert np.all(n > 400)
    sem = ps.sem_dn()
    # the rendered noise is 4 DN per pixel (rounded): the standard error of the mean is 4/sqrt(n)
    clear = ps.mean_dn > 12  # away from 0, where the rendered noise is clipped
    np.testing.assert_allclose(sem[clear], np.broadcast_to(4.0 / np.sqrt(n)[:, None], sem.shape)[clear], rtol=0.25)
    assert not ps.saturated.any()


def test_saturated_pixels_flag_their_patch():
    img = _render(CORNERS)
    ps0 = sample_patches(_frame(img), ChartLocation(CORNERS, "corners"))
    c = ChartLocation(CORNERS, "corners").patch_centres_px()[18]
    img[int(c[1]) - 10:int(c[1]) + 10, int(c[0]) - 10:int(c[0]) + 10] = 255
    ps = sample_patches(_frame(img), ChartLocation(CORNERS, "corners"))
    assert ps.saturated[18] and ps.saturated.sum() == 1 and "19" in ps.notes[0]
    assert ps.n_pixels[18] < ps0.n_pixels[18]


def test_corners_option_is_parsed_and_checked():
    c = parse_corners("1,2,300,2,300,200,1,200")
    assert c.shape == (4, 2) and c[2, 0] == 300
    for bad in ("1,2,3", "a,b,c,d,e,f,g,h", "0,0,1,0,1,1,0,1"):
        with pytest.raises(CamcalError, match="--corners"):
            parse_corners(bad)
    with pytest.raises(CamcalError, match="outside"):
        locate_chart(_frame(_render(CORNERS)), np.array([[0, 0], [5000, 0], [5000, 10], [0, 10]], float))


def test_the_neutral_row_score_tells_the_grey_row_from_colours():
    rgb = _srgb_chart().astype(float)
    assert neutral_score(rgb) < 0.05
    assert neutral_score(rgb[::-1]) > 0.5  # upside down: the grey row is on top, falling the wrong way


@pytest.mark.skipif(not CANON_CHART.is_file(), reason="../shared/realdata is absent")
def test_the_real_canon_chart_is_found_automatically():
    """A real ColorChecker Passport indoors (a crop of a Canon EOS Kiss X4 DNG): found, oriented, 24 patches."""
    from camcal.io.read import load_frame

    frame = load_frame(CANON_CHART)
    loc = detect_chart(frame)
    assert loc.neutral_score < 0.05
    ps = sample_patches(frame, loc)
    assert ps.channels == ("R", "G1", "G2", "B") and np.all(ps.n_pixels > 300) and not ps.saturated.any()
    grey = ps.mean_dn[18:24, 0]
    assert np.all(np.diff(grey) < 0) and grey[0] / grey[-1] > 20  # white to black, falling
    # the corners given by hand (the detected ones, rounded) read the same patches
    hand = locate_chart(frame, np.round(loc.corners_px))
    np.testing.assert_allclose(sample_patches(frame, hand).mean_dn, ps.mean_dn, rtol=0.02)

"""camcal.models.falloff: the uncorrected cos⁴ fall-off and the corner field angle taken from EXIF."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from camcal.frame import Exposure
from camcal.io.read import load_frame
from camcal.models.falloff import (
    ASSUMED_CORNER_FIELD_DEG,
    corner_field,
    corner_field_deg_of,
    cos4_falloff,
    uncorrected_sigma_rel,
)

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"


def test_corner_field_from_the_35mm_equivalent_focal_length():
    # 36 × 24 mm: half-diagonal 21.633 mm; a 28 mm equivalent sees its corner at 37.69°, 14 mm at 57.09°
    assert corner_field_deg_of(28.0) == pytest.approx(math.degrees(math.atan(21.6333 / 28.0)), abs=1e-3)
    assert corner_field_deg_of(14.0) == pytest.approx(57.09, abs=0.01)
    got = corner_field(Exposure(exposure_s=0.01, focal_length_35mm_mm=26.0), "a.heic")
    assert got["focal_length_35mm_mm"] == 26.0 and "FocalLengthIn35mmFilm of a.heic" in got["source"]
    missing = corner_field(Exposure(exposure_s=0.01), "b.dng")
    assert missing["corner_field_deg"] == ASSUMED_CORNER_FIELD_DEG and missing["focal_length_35mm_mm"] is None
    assert "assumed" in missing["source"] and "b.dng holds no FocalLengthIn35mmFilm" in missing["source"]


def test_cos4_and_its_uniform_bias_sigma():
    r = np.array([0.0, 0.5, 1.0])
    kept = cos4_falloff(r, 45.0)  # tan 45° = 1: cos⁴θ = (1 + r²)⁻²
    np.testing.assert_allclose(kept, [1.0, 1 / 1.25 ** 2, 0.25], rtol=1e-6)
    loss = 1 - kept
    np.testing.assert_allclose(uncorrected_sigma_rel(r, 45.0), loss / (kept * math.sqrt(3)), rtol=1e-6)


def test_the_synthetic_phone_and_real_iphones_state_their_field_in_exif(tmp_path):
    from camcal.synth.phone import write_phone_photos

    truth = write_phone_photos(tmp_path, chart_evs=(0.0,), depths_m=(1.0,), n_flats=0)
    f35 = truth["camera"]["lens"]["exif_focal_length_35mm_mm"]
    assert f35 == 28  # 21.63 mm / tan 37.4°, in whole mm
    for ext in ("dng", "heic"):
        assert load_frame(tmp_path / truth["grey"]["files"][ext]).exposure.focal_length_35mm_mm == f35
    if not REALDATA.is_dir():
        pytest.skip("../shared/realdata is absent")
    # the real iPhones' HEICs hold the tag: 14 mm (iPhone 15 Pro's ultra-wide), 28 mm (iPhone 7)
    assert load_frame(REALDATA / "heic" / "iphone15pro.heic").exposure.focal_length_35mm_mm == 14.0
    assert load_frame(REALDATA / "heic" / "iphone7_IMG_2682.heic").exposure.focal_length_35mm_mm == 28.0

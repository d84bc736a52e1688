import numpy as np
import pytest

from camcal.errors import CamcalError
from camcal.frame import PATTERNS, PLANES, merge_planes, plane_offsets, rgb_from_planes, split_planes


@pytest.mark.parametrize("pattern", PATTERNS)
def test_split_merge_round_trip(pattern, rng):
    mosaic = rng.integers(0, 2**14, size=(8, 12)).astype(np.uint16)
    planes = split_planes(mosaic, pattern, dtype=None)
    assert planes.shape == (4, 4, 6) and planes.dtype == np.uint16
    np.testing.assert_array_equal(merge_planes(planes, pattern), mosaic)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_planes_pick_the_right_colours(pattern):
    # a mosaic whose value encodes the colour letter at each site
    code = {"R": 1, "G": 2, "B": 3}
    cell = np.array([code[c] for c in pattern]).reshape(2, 2)
    mosaic = np.tile(cell, (3, 4))
    planes = split_planes(mosaic, pattern)
    for k, name in enumerate(PLANES):
        assert np.all(planes[k] == code[name[0]])
    # G1 sits on the first row of the cell, G2 on the second
    assert plane_offsets(pattern)["G1"][0] == 0 and plane_offsets(pattern)["G2"][0] == 1


def test_rgb_from_planes_averages_greens():
    planes = np.stack([np.full((2, 2), v, float) for v in (1.0, 2.0, 4.0, 8.0)])
    np.testing.assert_allclose(rgb_from_planes(planes)[:, 0, 0], [1.0, 3.0, 8.0])


def test_bad_pattern_and_odd_shape():
    with pytest.raises(CamcalError, match="unsupported CFA pattern"):
        split_planes(np.zeros((4, 4)), "RGBG")
    with pytest.raises(CamcalError, match="even"):
        split_planes(np.zeros((5, 4)), "RGGB")

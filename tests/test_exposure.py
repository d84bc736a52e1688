import pytest

from camcal.errors import MissingMetadataError
from camcal.exposure import frame_relative_exposure, relative_exposure
from camcal.frame import Exposure


def test_relative_exposure_scales_as_iso_t_over_n2():
    assert relative_exposure(1.0, 100, 4.0, 100, 4.0) == 1.0
    assert relative_exposure(0.5, 200, 4.0, 100, 4.0) == pytest.approx(1.0)
    assert relative_exposure(1.0, 100, 8.0, 100, 4.0) == pytest.approx(0.25)


def test_missing_field_names_it():
    with pytest.raises(MissingMetadataError, match="f_number"):
        frame_relative_exposure(Exposure(exposure_s=1, iso=100), 100, 4, "x.dng")

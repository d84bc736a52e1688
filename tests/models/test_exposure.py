
import numpy as np
import pytest

from camcal.errors import MissingMetadataError
from camcal.frame import Exposure
from camcal.models.exposure import frame_relative_exposure, normalise, relative_exposure

#: Every test here is a fast formula test (the mutation-testing selection, docs/testing.md).
pytestmark = pytest.mark.formula


def test_relative_exposure_scales_as_iso_t_over_n2():
    assert relative_exposure(1.0, 100, 4.0, 100, 4.0) == 1.0
    assert relative_exposure(0.5, 200, 4.0, 100, 4.0) == pytest.approx(1.0)
    assert relative_exposure(1.0, 100, 8.0, 100, 4.0) == pytest.approx(0.25)


def test_missing_field_names_it():
    with pytest.raises(MissingMetadataError, match="f_number"):
        frame_relative_exposure(Exposure(exposure_s=1, iso=100), 100, 4, "x.dng")


@pytest.mark.parametrize("missing", ["exposure_s", "iso", "f_number"])
def test_missing_field_names_the_file(missing):
    fields = {"exposure_s": 1.0, "iso": 100.0, "f_number": 4.0}
    del fields[missing]
    with pytest.raises(MissingMetadataError, match=missing) as err:
        frame_relative_exposure(Exposure(**fields), 100, 4, "IMG_0042.dng")
    assert "IMG_0042.dng" in str(err.value)


def test_relative_exposure_off_the_reference_setting():
    # ISO 400, 1/250 s, f/5.6 against ISO 100, f/4: 4 × 0.004 s × (4/5.6)² = 8.163e-3 s at the reference setting
    assert relative_exposure(1 / 250, 400, 5.6, 100, 4.0) == pytest.approx(4 * 0.004 * 16 / 31.36, rel=1e-12)
    assert normalise(np.array([6.0]), 1.5)[0] == pytest.approx(4.0)
    assert normalise(6.0, 1.5) == pytest.approx(4.0)


def test_frame_relative_exposure_off_the_reference_setting():
    """x = t·(ISO/ISO_ref)·(N_ref/N)² (seconds at the reference setting): 1/60 s at ISO 400 and f/5.6 for a
    reference of ISO 100 at f/4 is (1/60)·4·(4/5.6)² s."""
    e = Exposure(exposure_s=1 / 60, iso=400.0, f_number=5.6)
    assert frame_relative_exposure(e, 100.0, 4.0) == pytest.approx((1 / 60) * 4 * (4 / 5.6) ** 2, rel=1e-14)

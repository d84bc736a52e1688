"""The JPEG colour matrix (camcal.calibrate.colour_matrix): a camera that mixes its channels before the tone curve.

Truth: the synthetic camera renders its JPEGs as tone(M · linear RAW) with the matrix M below (rows sum
to 1: white stays white; negative off-diagonals as in real cameras' camera-RGB → sRGB matrices). The
session has JPEG twins of the linearity series and of every sweep frame. Photos: uniform fields of three
broadband spectra (daylight-like grey, greenish, reddish), each shot as DNG and as JPEG.

Tolerances: the RAW result is the reference (it is within 0.1 % of the truth, tests/apply/test_photo.py).
JPEG through the fitted matrix: measured within 0.6 %; asserted 1.5 % (8-bit quantisation and the fit's
stated uncertainty of the weakly constrained entries, ~0.5 %), inside the issue's 3 % target. The same
JPEGs with the matrix removed from the profile (one gain per channel, the pre-matrix behaviour) are off
by 9–90 %: asserted > 5 % somewhere, so the test fails if the matrix stops being used.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from camcal.apply.photo import apply
from camcal.calibrate.colour_matrix import fit_colour_matrix, measure_colour_matrix, twin_pairs
from camcal.calibrate.run import calibrate_session
from camcal.errors import CamcalError
from camcal.io.read import load_frame
from camcal.models.profile import load_profile, save_profile
from camcal.models.response import ColourMatrix
from camcal.models.spectra import WAVELENGTHS_NM, planck_radiance
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, exposure_for_level, write_session

M = ((1.65, -0.45, -0.20), (-0.25, 1.55, -0.30), (-0.05, -0.55, 1.60))
_WL = WAVELENGTHS_NM
_PL = planck_radiance(5500.0, _WL)
_PL = 0.05 * _PL / np.interp(663.0, _WL, _PL)
SCENES = {"grey": _PL, "green": _PL * (0.3 + 0.7 * np.exp(-(((_WL - 550) / 60) ** 2))),
          "red": _PL * (0.2 + 0.8 / (1 + np.exp(-(_WL - 600) / 15)))}


@pytest.fixture(scope="module")
def matrix_camera():
    return SyntheticCamera(SensorParams(width=192, height=128))


@pytest.fixture(scope="module")
def matrix_session(tmp_path_factory, matrix_camera):
    root = tmp_path_factory.mktemp("colour")
    plan = SessionPlan(jpeg_colour_matrix=M, sweep_jpeg=True, sweep_step_nm=10.0, n_sweep=1, n_bias=4, n_dark=2,
                       dark_exposures_s=(2.0, 16.0), n_flat=3)
    session = write_session(root / "S", matrix_camera, plan)
    profile, notes = calibrate_session(session)
    path = root / "m.camcal"
    save_profile(profile, path)
    rng = np.random.default_rng(1)
    photos = {}
    for name, spec in SCENES.items():
        t = exposure_for_level(matrix_camera, spec, 0.4, 100, 4.0)
        for kind in ("dng", "jpg"):
            p = root / f"{name}.{kind}"
            if kind == "dng":
                matrix_camera.write_dng(p, Scene.uniform(spec), exposure_s=t, iso=100, f_number=4.0, rng=rng)
            else:
                matrix_camera.write_jpeg(p, Scene.uniform(spec), exposure_s=t, iso=100, f_number=4.0, rng=rng,
                                         colour_matrix=M)
            photos[(name, kind)] = p
    return session, load_profile(path), notes, photos


def _means(img) -> np.ndarray:
    return np.array([np.nanmean(img.channels[k]) for k in ("R", "G", "B", "L663")])


def test_matrix_is_fitted_and_stored(matrix_session):
    session, profile, notes, _ = matrix_session
    cm = profile.response["processed"].colour_matrix
    assert cm is not None and not any("colour matrix" in n for n in notes)
    assert len(twin_pairs(session / "sweep")) == 31 and len(twin_pairs(session / "linearity")) == 17
    assert all(n >= 10 for n in cm.n_frames)
    assert max(cm.residual_rms_rel) < 0.01  # the model j = A r fits every usable frame within 1 %
    # A = diag(c) · M · diag(1/s): per-column scale s and per-row scale c; the well-determined entries
    # (the diagonal and the large off-diagonals) reproduce M's shape
    a = cm.matrix
    ratio = a / np.asarray(M)
    for i, j in ((0, 0), (0, 1), (1, 0), (1, 1), (1, 2), (2, 1), (2, 2)):
        assert ratio[i, j] == pytest.approx(ratio[1, 1], rel=0.05), (i, j, ratio)


def test_jpeg_through_the_matrix_matches_raw(matrix_session):
    _, profile, _, photos = matrix_session
    nomat = dataclasses.replace(profile, response={**profile.response, "processed": dataclasses.replace(
        profile.response["processed"], colour_matrix=None)})
    worst_without = 0.0
    for name in SCENES:
        raw = _means(apply(load_frame(photos[(name, "dng")]), profile))
        img = apply(load_frame(photos[(name, "jpg")]), profile)
        assert any("colour matrix" in n for n in img.metadata["notes"])
        np.testing.assert_allclose(_means(img), raw, rtol=0.015, err_msg=name)
        without = _means(apply(load_frame(photos[(name, "jpg")]), nomat))
        worst_without = max(worst_without, float(np.max(np.abs(without / raw - 1))))
    assert worst_without > 0.05, worst_without  # the matrix matters: per-channel gains are far off


def test_matrix_round_trip_and_bad_matrices(matrix_session, tmp_path):
    _, profile, _, _ = matrix_session
    cm = profile.response["processed"].colour_matrix
    back = ColourMatrix.from_dict(cm.to_dict())
    np.testing.assert_array_equal(back.matrix, cm.matrix)
    lin = np.abs(np.random.default_rng(0).normal(100, 20, (3, 4, 5)))
    np.testing.assert_allclose(back.matrix @ back.to_raw(lin).reshape(3, -1), lin.reshape(3, -1), rtol=1e-4)
    for bad in ({"matrix": [[1, 0, 0], [0, 1, 0], [1, 0, 0]]}, {"matrix": [[1, 0], [0, 1]]},
                {"matrix": [[1, 0, 0], [0, float("nan"), 0], [0, 0, 1]]}, {}):
        with pytest.raises(CamcalError, match="colour matrix"):
            ColourMatrix.from_dict(bad)


def test_fit_needs_colours(matrix_session):
    """The linearity series alone is one chromaticity: no channel row can be solved from it."""
    session, profile, _, _ = matrix_session
    with pytest.raises(CamcalError, match="colour matrix|singular"):
        fit_colour_matrix(measure_colour_matrix([session / "linearity"], profile.response["processed"]),
                          min_frames=20)
    assert measure_colour_matrix([session / "flat"], profile.response["processed"]) is None  # no twins at all

"""The camera basis: PCA_Jiang2013 over the bundled library, its leave-one-camera-out error and floors."""

from __future__ import annotations

import numpy as np
import pytest

from camcal.chart.basis import (
    _pca,
    _uncentred_components,
    camera_basis,
    leave_one_out_table,
    projection_floor,
)
from camcal.chart.targets import GRID_NM
from camcal.errors import CamcalError


@pytest.fixture(scope="module")
def basis():
    return camera_basis()


def test_basis_is_pca_jiang2013_of_the_library(basis):
    assert basis.curves.shape == (52, 3, GRID_NM.size) and np.allclose(basis.curves.max(axis=2), 1.0)
    comps = _uncentred_components(basis.curves, 5)
    ref, _ = _pca(basis.curves, 5, GRID_NM)
    for ch in range(3):  # same subspace (signs of eigenvectors are arbitrary)
        np.testing.assert_allclose(np.abs(np.sum(comps[ch] * ref[ch], axis=0)), 1.0, atol=1e-9)
    # a library camera in the full basis is reproduced; its leave-one-out residual is not zero
    assert max(projection_floor(basis, basis.curves[3], basis.max_components).values()) < 1e-6
    table = leave_one_out_table(basis, 8)
    assert len(table) == 52 * 3 and all(r["rms_pct_of_peak"] > 0 for r in table)
    assert np.median([r["rms_pct_of_peak"] for r in table]) < 1.5
    # more components, smaller leave-one-out error
    t3 = np.mean([r["rms_pct_of_peak"] for r in leave_one_out_table(basis, 3)])
    assert np.mean([r["rms_pct_of_peak"] for r in table]) < t3


def test_prior_and_truncation(basis):
    mu, cov_b, cov_t = basis.prior(0, 8)
    assert mu.shape == GRID_NM.shape and 0.8 < mu.max() < 1.05
    np.testing.assert_allclose(np.diag(cov_t), basis.truncation_variance(8)[0])
    assert np.all(np.linalg.eigvalsh(cov_b) > -1e-12)


def test_exclude(basis):
    b = camera_basis(exclude=("Nikon D5100",))
    assert len(b.cameras) == 51 and "Nikon D5100" not in b.cameras
    d5100 = basis.curves[basis.cameras.index("Nikon D5100")]
    assert max(projection_floor(b, d5100, 8).values()) > 0.1
    with pytest.raises(CamcalError, match="not a camera of the curve library"):
        camera_basis(exclude=("Apple iPhone 15 Pro",))

"""The camera basis: PCA_Jiang2013 over the bundled library, its leave-one-camera-out error and floors."""

from __future__ import annotations

import numpy as np
import pytest

from camcal.chart.basis import (
    _pca,
    _uncentred_components,
    camera_basis,
    ir_cut_nodes,
    leave_one_out_table,
    projection_floor,
)
from camcal.chart.targets import GRID_NM
from camcal.errors import CamcalError


@pytest.fixture(scope="module")
def basis():
    return camera_basis(filter_variants=False)


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
    mu, cov_b, cov_t, cov_lab = basis.prior(0, 8)
    assert mu.shape == GRID_NM.shape and 0.8 < mu.max() < 1.05
    np.testing.assert_allclose(np.diag(cov_t), basis.truncation_variance(8)[0])
    assert np.all(np.linalg.eigvalsh(cov_b) > -1e-12) and np.all(np.linalg.eigvalsh(cov_lab) > -1e-12)
    # the between-lab term is the borrowed-curve table: 7 % of peak at 620 nm in R (docs/spectral.md)
    assert np.sqrt(cov_lab[GRID_NM == 620, GRID_NM == 620][0]) == pytest.approx(0.07, abs=0.005)


def test_filter_variants_widen_the_basis_towards_phone_cut_filters(basis):
    wide = camera_basis()
    assert len(wide.cameras) == 52 * 6 and wide.source["n_measured_cameras"] == 52
    assert "Canon EOS 600D × IR-cut 650 nm" in wide.cameras
    i = wide.cameras.index("Canon EOS 600D × IR-cut 650 nm")
    assert np.all(wide.curves[i, 0, GRID_NM >= 700] < 0.02) and wide.curves[i, 0].max() == pytest.approx(1.0)
    # a camera is left out with its variants: the leave-one-out error stays that of a new camera
    t = leave_one_out_table(wide, 8)
    assert len(t) == 52 * 3
    assert np.median([r["rms_pct_of_peak"] for r in t]) > 0.5 * np.median(
        [r["rms_pct_of_peak"] for r in leave_one_out_table(basis, 8)])


def test_exclude(basis):
    b = camera_basis(exclude=("Nikon D5100",), filter_variants=False)
    assert len(b.cameras) == 51 and "Nikon D5100" not in b.cameras
    d5100 = basis.curves[basis.cameras.index("Nikon D5100")]
    assert max(projection_floor(b, d5100, 8).values()) > 0.1
    with pytest.raises(CamcalError, match="not a camera of the curve library"):
        camera_basis(exclude=("Apple iPhone 15 Pro",))


def test_a_known_ir_cut_takes_every_camera_behind_that_edge_and_none_without_it():
    nodes = ir_cut_nodes(650.0, 10.0)
    assert np.mean(nodes) == pytest.approx(650.0) and np.var(nodes) == pytest.approx(100.0)
    assert ir_cut_nodes(650.0, 0.0) == (650.0,)
    b = camera_basis(ir_cut=(650.0, 10.0))
    assert b.source["ir_cut"] == {"cut_nm": 650.0, "sigma_nm": 10.0, "source": "user (the module's datasheet)"}
    assert all("IR-cut" in n for n in b.cameras) and len(b.cameras) == 52 * 3 * 3  # 3 edges, bare + 2 UV each
    assert b.source["filter_variants"]["bare_included"] is False
    # every R curve has lost most of its response beyond the edge, whatever the DSLR's own filter did
    assert np.all(b.curves[:, 0, GRID_NM >= 690] < 0.1)
    for bad in ((900.0, 10.0), (650.0, -1.0), (650.0, float("nan"))):
        with pytest.raises(CamcalError, match="IR cut"):
            camera_basis(ir_cut=bad)

"""Batches: 20 photos with 2 corrupt ones, resuming, atomic outputs, a Dask LocalCluster (issue 8)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from camcal.apply.batch import BatchOptions, run_batch
from camcal.io.exr import read_exr
from camcal.models.spectra import gaussian_line
from camcal.synth.camera import Scene
from tests.conftest import run_cli

N_GOOD = 18


@pytest.fixture(scope="module")
def photo_dir(tmp_path_factory, camera):
    d = tmp_path_factory.mktemp("batch-photos")
    rng = np.random.default_rng(77)
    for i in range(N_GOOD):
        spec = (1.0 + 0.1 * i) * gaussian_line(663.0, 5.0)
        camera.write_dng(d / f"p{i:02d}.dng", Scene.uniform(spec), exposure_s=0.02, iso=100, f_number=4.0, rng=rng)
    (d / "corrupt_header.dng").write_bytes(b"II*\x00" + b"\x00garbage" * 200)
    data = (d / "p00.dng").read_bytes()
    (d / "truncated.dng").write_bytes(data[: len(data) // 3])
    return d


def _report(outdir):
    with open(outdir / "apply_report.csv", newline="") as fh:
        return {r["file"].rsplit("/", 1)[-1]: r for r in csv.DictReader(fh)}


def test_batch_failures_atomic_and_resume(tmp_path, profile_path, photo_dir):
    out = tmp_path / "out"
    proc = run_cli("apply", profile_path, photo_dir, "-o", out, "--jobs", "2", "--estimator", "narrowband")
    assert proc.returncode == 1, proc.stderr
    exrs = sorted(out.glob("*.exr"))
    assert len(exrs) == N_GOOD
    # no partial or temporary files, nothing under the corrupt photos' names
    assert not list(out.glob(".*")) and not (out / "truncated.dng.exr").exists()
    failed = [ln for ln in proc.stderr.splitlines() if ln.startswith("camcal: failed:")]
    assert len(failed) == 2 and any("truncated.dng" in ln for ln in failed)
    assert any("corrupt_header.dng" in ln for ln in failed)
    rep = _report(out)
    assert sum(r["status"] == "done" for r in rep.values()) == N_GOOD
    assert {k for k, r in rep.items() if r["status"] == "failed"} == {"truncated.dng", "corrupt_header.dng"}
    # the radiance follows the scene: photo i has (1 + 0.1 i) W m^-2 sr^-1 in the line (1 % target)
    chans, _ = read_exr(out / "p05.dng.exr", ["L663_inband"])  # a line: the in-band radiance, W m⁻² sr⁻¹
    assert float(np.nanmean(chans["L663_inband"])) == pytest.approx(1.5, rel=0.01)

    mtimes = {p.name: p.stat().st_mtime_ns for p in exrs}
    proc = run_cli("apply", profile_path, photo_dir, "-o", out, "--jobs", "2", "--estimator", "narrowband")
    assert proc.returncode == 1
    assert f"0 written, {N_GOOD} already done" in proc.stdout
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.exr")} == mtimes  # no work twice
    rep = _report(out)
    assert sum(r["status"] == "skipped" for r in rep.values()) == N_GOOD

    # another wavelength makes the outputs stale: redone, not skipped
    res = run_batch(profile_path, [photo_dir / "p00.dng"], out, BatchOptions(wavelength_nm=560.0))
    assert res.counts == {"done": 1, "skipped": 0, "failed": 0}
    assert "L560" in read_exr(out / "p00.dng.exr")[0]


def test_dask_local_cluster_identical(tmp_path, profile_path, photo_dir):
    from dask.distributed import LocalCluster

    photos = [photo_dir / f"p{i:02d}.dng" for i in range(4)] + [photo_dir / "truncated.dng"]
    pool = run_batch(profile_path, photos, tmp_path / "pool", jobs=1)
    assert pool.counts == {"done": 4, "skipped": 0, "failed": 1}
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None)
    try:
        dask = run_batch(profile_path, photos, tmp_path / "dask", scheduler=cluster.scheduler_address)
    finally:
        cluster.close()
    assert dask.counts == pool.counts and dask.exit_code == 1
    assert "truncated.dng" in dask.failed[0].error
    for p in photos[:4]:
        a = (tmp_path / "pool" / f"{p.name}.exr").read_bytes()
        b = (tmp_path / "dask" / f"{p.name}.exr").read_bytes()
        assert a == b, p.name  # byte-identical files

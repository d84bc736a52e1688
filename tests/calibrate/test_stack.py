"""The streaming stack combiner against numpy on the same decoded frames (real DNG files via LibRaw)."""

from __future__ import annotations

import os
import shutil
import tempfile

import numpy as np
import pytest

from camcal import threads
from camcal.calibrate import spill, stack
from camcal.calibrate.screen import Majority, StageJudge
from camcal.calibrate.spill import read_slot
from camcal.calibrate.stack import StackOptions, combine_frames
from camcal.errors import CamcalError
from camcal.io.read import load_frame
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera, frame_rngs
from tests.oracles import combine_folder


@pytest.fixture(scope="module")
def stack_dir(tmp_path_factory):
    """9 dark frames of a small BGGR sensor, one with a 'cosmic ray' streak, plus a frame of another size."""
    d = tmp_path_factory.mktemp("stack")
    cam = SyntheticCamera(SensorParams(width=128, height=96, cfa_pattern="BGGR", seed=5))
    for i, rng in enumerate(frame_rngs(5, 9, 1)):
        cam.write_dng(d / f"f{i}.dng", Scene.dark(), exposure_s=4.0, iso=200, f_number=4.0, rng=rng)
    # a cosmic-ray hit: rewrite frame 3 with a bright streak on row 10 (raw mosaic)
    from camcal.synth.dng import write_dng

    fr = load_frame(d / "f3.dng")
    mosaic = fr.data.copy()
    mosaic[10, 20:60] = 9000
    pos = [512.0] * 4
    write_dng(d / "f3.dng", mosaic, cfa_pattern="BGGR", black_level_dn=tuple(pos), white_level_dn=16383,
              exposure_s=4.0, f_number=4.0, iso=200)
    other = tmp_path_factory.mktemp("other")
    SyntheticCamera(SensorParams(width=160, height=96, seed=6)).write_dng(
        other / "big.dng", Scene.dark(), exposure_s=4.0, rng=np.random.default_rng(1))
    return d, other / "big.dng"


def _cube(folder):
    files = sorted(folder.glob("f*.dng"))
    return files, np.stack([load_frame(p).planes() for p in files]).astype(np.float64)


@pytest.mark.parametrize("jobs", [1, 2])
def test_mean_and_median_match_numpy(stack_dir, jobs):
    files, x = _cube(stack_dir[0])
    res = combine_frames(files, StackOptions(method="mean", jobs=jobs))
    assert res.n_frames == 9 and res.channel_names == ("R", "G1", "G2", "B") and res.cfa_pattern == "BGGR"
    np.testing.assert_allclose(res.value, x.mean(0), rtol=0, atol=1e-3)
    np.testing.assert_allclose(res.variance, x.var(0, ddof=1), rtol=1e-4, atol=1e-3)
    assert res.count.min() == res.count.max() == 9
    assert [e.iso for e in res.exposures] == [200.0] * 9
    med = combine_frames(files, StackOptions(method="median", jobs=jobs, band_mb=0.05))  # tiny bands: many band reads
    np.testing.assert_array_equal(med.value, np.median(x, 0).astype(np.float32))
    np.testing.assert_allclose(med.mean, x.mean(0), atol=1e-3)
    np.testing.assert_allclose(med.variance, x.var(0, ddof=1), rtol=1e-4, atol=1e-3)


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_mean_stack_summed_as_mosaics_keeps_the_planes_of_its_first_frames(stack_dir, jobs):
    """The mean stack sums Bayer mosaics and splits the result into planes at the end: the planes it keeps
    are still the frames' own, in file order and integer type (split from the mosaic of a frame whose planes
    the decode thread did not return), and the value and variance land in the right planes."""
    files, x = _cube(stack_dir[0])
    res = combine_frames(files, StackOptions(method="mean", jobs=jobs, keep_frames=4))
    assert len(res.kept_planes) == 4
    for p, kept in zip(files, res.kept_planes, strict=False):
        frame = load_frame(p)
        np.testing.assert_array_equal(kept, frame.planes(dtype=frame.data.dtype))
        assert kept.dtype == np.uint16
    # float32 results of sums that are exact in float64 (integer DN): within a float32 step of numpy's
    np.testing.assert_allclose(res.value, x.mean(0), rtol=0, atol=1e-3)
    np.testing.assert_allclose(res.variance, x.var(0, ddof=1), rtol=1e-4, atol=1e-3)
    assert res.value.shape == res.variance.shape == res.count.shape == x.shape[1:]


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_spilled_stack_keeps_the_planes_of_its_first_frames(stack_dir, jobs):
    """A Bayer stack is spilled as mosaics, not planes: the planes it keeps for single-frame statistics are
    still the frames' own planes, in file order, in their integer type, and so are the planes read back from
    a spilled mosaic's slot (when a kept frame's planes were not returned by its decode thread)."""
    files, _ = _cube(stack_dir[0])
    res = combine_frames(files, StackOptions(method="median", jobs=jobs, keep_frames=4, band_mb=0.05))
    assert len(res.kept_planes) == 4
    frames = [load_frame(p) for p in files]
    for frame, kept in zip(frames, res.kept_planes, strict=False):
        np.testing.assert_array_equal(kept, frame.planes(dtype=frame.data.dtype))
        assert kept.dtype == np.uint16
    spill = stack_dir[0].parent / f"spill{jobs}.raw"
    spill.write_bytes(b"".join(f.data.tobytes() for f in frames[:3]))
    planes = frames[2].planes(dtype=np.uint16)
    fd = os.open(spill, os.O_RDONLY)
    try:
        np.testing.assert_array_equal(read_slot(fd, str(spill), 2, planes.shape, np.dtype(np.uint16), "BGGR"),
                                      planes)
        with pytest.raises(CamcalError, match="ended early"):  # a slot past the end: a short file
            read_slot(fd, str(spill), 3, planes.shape, np.dtype(np.uint16), "BGGR")
    finally:
        os.close(fd)


def test_sigma_clip_rejects_the_cosmic_ray(stack_dir):
    files, x = _cube(stack_dir[0])
    res = combine_frames(files, StackOptions(method="sigma_clip", sigma=3.0, jobs=2, band_mb=0.1))
    hit = np.zeros(x.shape[1:], bool)
    # row 10 of a BGGR mosaic is an even row: B at even columns, G1 at odd columns (plane row 5)
    hit[3, 5, 10:30] = True
    hit[1, 5, 10:30] = True
    assert np.all(res.count[hit] <= 8)  # the streak value is gone (normal values may go too with 9 frames)
    others = np.delete(x, 3, axis=0)
    # the clipped mean stays within the noise of the mean of the 8 clean frames (per-frame sigma ~5 DN)
    assert np.all(np.abs(res.value[hit] - others.mean(0)[hit]) < 6.0)
    # elsewhere clipping of a normal sample removes few values: 0.3 % beyond 3 sigma, ~3 % measured with 9
    # frames as the robust scale (MAD) of 9 quantised values is itself noisy; 10 % would mean a broken clip
    assert np.mean(res.count[~hit]) > 8.1
    assert np.all(res.variance_all[hit] > 1e5)  # the unclipped variance still sees it
    plain = combine_frames(files, StackOptions(method="mean"))
    assert np.all(plain.value[hit] > res.value[hit] + 500)


def test_sigma_clip_combines_a_pixel_masked_in_some_frames_from_the_others(stack_dir):
    """NaN marks a masked pixel (the flat stage masks saturated pixels per frame): masked in one frame, the
    sigma-clipped value is that of the other frames; masked in every frame, it stays NaN with count 0."""
    files, x = _cube(stack_dir[0])
    files, x = files[:3] + files[4:], np.delete(x, 3, axis=0)  # the 8 frames without the cosmic ray

    def masked(frame):
        planes = frame.planes()
        if frame.path.name == files[2].name:
            planes[0, 7, 3:9] = np.nan  # masked in this frame only
        planes[2, 4, 4] = np.nan  # masked in every frame
        return planes

    res = combine_frames(files, StackOptions(method="sigma_clip", jobs=1), preprocess=masked)
    others = np.delete(x, 2, axis=0)[:, 0, 7, 3:9]  # the 7 unmasked values of those pixels
    assert np.all(res.count[0, 7, 3:9] <= 7) and np.all(res.count[0, 7, 3:9] >= 6)
    # the clipped mean of 7 values of ~5 DN noise: within 3 DN of their plain mean (at most one clipped value)
    assert np.all(np.isfinite(res.value[0, 7, 3:9]))
    assert np.all(np.abs(res.value[0, 7, 3:9] - others.mean(0)) < 3.0)
    assert np.isnan(res.value[2, 4, 4]) and res.count[2, 4, 4] == 0


def test_processed_frames_and_custom_preprocess(tmp_path):
    cam = SyntheticCamera(SensorParams(width=96, height=64, seed=3))
    scene = Scene.uniform(np.ones(401) * 0.02)
    for i, rng in enumerate(frame_rngs(3, 3, 1)):
        cam.write_jpeg(tmp_path / f"j{i}.jpg", scene, exposure_s=0.01, rng=rng)
    res = combine_folder(tmp_path, StackOptions("median"))
    assert res.channel_names == ("R", "G", "B") and res.value.shape == (3, 64, 96) and res.kind == "processed"
    x = np.stack([load_frame(p).planes() for p in sorted(tmp_path.glob("*.jpg"))])
    np.testing.assert_array_equal(res.value, np.median(x, 0))
    half = combine_folder(tmp_path, StackOptions("sigma_clip", jobs=2), preprocess=lambda f: f.planes() * 0.5)
    assert half.value.dtype == np.float32
    np.testing.assert_allclose(np.median(half.value), 0.5 * np.median(x), rtol=0.02)


def test_errors(stack_dir, tmp_path):
    files, _ = _cube(stack_dir[0])
    with pytest.raises(CamcalError, match="differs from the first frame"):
        combine_frames([*files[:2], stack_dir[1]], StackOptions(method="median", jobs=2))
    with pytest.raises(CamcalError, match="differs from the first frame"):
        combine_frames([*files[:2], stack_dir[1]], StackOptions(method="mean"))
    with pytest.raises(CamcalError, match="unknown combination method"):
        combine_frames(files, StackOptions(method="mode"))
    with pytest.raises(CamcalError, match="no frames"):
        combine_frames([])

    def refuse(frame):
        if frame.path.name == "f2.dng":
            raise CamcalError("refused by check", frame.path)

    with pytest.raises(CamcalError, match="f2.dng: refused by check"):
        combine_frames(files, StackOptions(jobs=2, method="median"), check=refuse)
    bad = tmp_path / "x.dng"
    bad.write_bytes(b"II*\x00garbage" * 10)
    with pytest.raises(CamcalError, match="x.dng"):
        combine_frames([files[0], bad])
    assert not list(tmp_path.glob("camcal-stack-*"))


def test_the_thread_rule(monkeypatch):
    """Automatic (None): one thread for frames under SMALL_FRAME_PIXELS (a pool costs more than it gains there,
    benchmarks/RESULTS.md), the default count above; an explicit request and CAMCAL_THREADS are honoured."""
    monkeypatch.delenv("CAMCAL_THREADS", raising=False)
    monkeypatch.setattr(threads, "usable_cores", lambda: 2)
    small, large = threads.SMALL_FRAME_PIXELS - 1, threads.SMALL_FRAME_PIXELS
    assert threads.thread_count(None, 50, small) == 1
    assert threads.thread_count(None, 50, large) == 2
    assert threads.thread_count(None, 50) == 2  # size unknown: the default
    assert threads.thread_count(2, 50, small) == 2  # asked for: honoured
    assert threads.thread_count(8, 50, small) == 2  # but never above the usable cores
    assert threads.thread_count(None, 1, large) == 1  # never more than the work items
    monkeypatch.setenv("CAMCAL_THREADS", "3")
    assert threads.thread_count(None, 50, small) == 3


def test_automatic_threads_give_the_same_stack(stack_dir):
    files, _ = _cube(stack_dir[0])
    auto = combine_frames(files, StackOptions(method="sigma_clip", jobs=None, band_mb=0.1))
    two = combine_frames(files, StackOptions(method="sigma_clip", jobs=2, band_mb=0.1))
    np.testing.assert_array_equal(auto.value, two.value)
    np.testing.assert_array_equal(auto.count, two.count)


def test_a_stack_spilled_to_disk_equals_one_held_in_memory(stack_dir, monkeypatch, tmp_path):
    """Where the spill lives (an anonymous memory file within CAMCAL_SPILL_MEMORY_MB, else the temporary folder)
    changes nothing in the result, with a frame left out (its slot closed up) and kept planes read back."""
    files, _ = _cube(stack_dir[0])
    copy = tmp_path / "copy.dng"
    shutil.copyfile(files[1], copy)
    files = [*files[:2], copy, *files[2:]]  # a copy of the frame before: left out by the stage's judge
    runs = {}
    for limit in ("0", "1000"):
        monkeypatch.setenv("CAMCAL_SPILL_MEMORY_MB", limit)
        judge = StageJudge("dark", Majority(), None, {p: i for i, p in enumerate(files)})
        runs[limit] = combine_frames(files, StackOptions(method="sigma_clip", jobs=2, band_mb=0.05, keep_frames=3),
                                     rule=judge)
        assert judge.reasons[copy] is not None
    disk, memory = runs["0"], runs["1000"]
    assert disk.n_frames == memory.n_frames == len(files) - 1
    for a, b in ((disk.value, memory.value), (disk.variance, memory.variance), (disk.count, memory.count),
                 *zip(disk.kept_planes, memory.kept_planes, strict=True)):
        np.testing.assert_array_equal(a, b)


def test_a_spill_that_cannot_be_written_is_one_line_naming_it(stack_dir, monkeypatch, tmp_path):
    """A full disk while frames are spilled (the write fails with ENOSPC): a CamcalError naming the spill file and
    what to change, not an OSError without a file name; the spill file is removed."""
    import errno

    import camcal.calibrate.spill as spill_module

    files, _ = _cube(stack_dir[0])
    monkeypatch.setenv("CAMCAL_SPILL_MEMORY_MB", "0")
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(tempfile, "tempdir", None)

    def full(fd, data, offset):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(spill_module.os, "pwrite", full)
    with pytest.raises(CamcalError, match=r"cannot write the temporary stack file .*camcal-stack-.*: No space left "
                                          r"on device; point TMPDIR"):
        combine_frames(files, StackOptions(method="sigma_clip", jobs=1))
    assert not list(tmp_path.glob("camcal-stack-*"))


@pytest.mark.parametrize(("method", "statistics"), [("sigma_clip", ("variance_all", "mean_all")),
                                                    ("sigma_clip", ()), ("median", ("mean",)),
                                                    ("median", ("variance_all",)), ("mean", ("variance",))])
def test_a_stage_gets_only_the_statistics_it_asks_for(stack_dir, method, statistics, monkeypatch):
    """``statistics`` leaves out the optional statistics a stage does not use (None in the result, and never
    allocated by the band statistics); what it does ask for, and the value and count, are those of the full
    stack, bit for bit. The median's mean and variance are those of all values (mean_all, variance_all): asking
    for either name gives the one array."""
    files, _ = _cube(stack_dir[0])
    full = combine_frames(files, StackOptions(method=method, jobs=2, band_mb=0.05))
    made = []
    bands = stack.spilled_statistics

    def recording(*args, **kwargs):
        out = bands(*args, **kwargs)
        made.append({id(a) for a in out if a is not None})
        return out

    monkeypatch.setattr(stack, "spilled_statistics", recording)
    part = combine_frames(files, StackOptions(method=method, jobs=2, band_mb=0.05, statistics=statistics))
    if method != "mean":  # the band statistics made the value, the count and what was asked for, no more
        asked = {id(part.value), id(part.count)} | {id(getattr(part, n)) for n in statistics}
        assert made == [asked]
    np.testing.assert_array_equal(part.value, full.value)
    np.testing.assert_array_equal(part.count, full.count)
    for name in ("mean", "variance", "variance_all", "mean_all"):
        got = getattr(part, name)
        if name in statistics:
            np.testing.assert_array_equal(got, getattr(full, name))
        else:
            assert got is None, name


def test_an_unknown_statistic_is_refused(stack_dir):
    files, _ = _cube(stack_dir[0])
    with pytest.raises(CamcalError, match="unknown statistics.*'stdev'"):
        combine_frames(files, StackOptions(method="sigma_clip", statistics=("variance", "stdev")))


def test_a_band_stays_within_its_budget_and_its_pixel_cap_whatever_the_frames():
    """The band rule of a median or clipped stack: the working set (4 bytes a value) within the budget at any
    number of frames, so memory does not grow with them; at most MAX_BAND_PIXELS pixels of a frame however large
    the budget; at least one row."""
    shape = (4, 1500, 2000)  # a 12 MP mosaic's planes
    c, h, w = shape
    for n in (2, 8, 16, 32, 64, 128):
        rows = spill._band_rows(n, shape, spill.BAND_MB)
        assert 1 <= rows <= h
        assert n * c * rows * w * 4 <= spill.BAND_MB * 1e6
        assert c * rows * w <= spill.MAX_BAND_PIXELS
        # the largest band within both: one more row breaks one of them
        assert (n * c * (rows + 1) * w * 4 > spill.BAND_MB * 1e6 or c * (rows + 1) * w > spill.MAX_BAND_PIXELS)
    assert spill._band_rows(32, shape, 16.0) == 15  # 16e6 / (32 · 4 · 2000 · 4) = 15.6 rows
    assert spill._band_rows(8, shape, 16.0) == 32  # the cap: 2^18 / 8000 = 32.8 rows (the budget allows 62)
    assert spill._band_rows(32, shape, 1e-6) == 1  # a tiny budget: one row
    assert spill._band_rows(2, (1, 3, 2000), 1e3) == 3  # never more rows than the planes have

"""The session index (camcal.calibrate.session): a session read once, exposures resolved with their source, checks
that need no pixels. Sessions are real DNG/JPEG files written by :mod:`camcal.synth`."""

from __future__ import annotations

import shutil
import sys
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import camcal.io.manifest
from camcal.calibrate.dark import fit_dark
from camcal.calibrate.dark_frames import DarkOptions, measure_dark
from camcal.calibrate.run import calibrate_session
from camcal.calibrate.session import StageFrames, index_session
from camcal.calibrate.sweep import (
    SweepOptions,
    fit_sweep,
    measure_sweep,
    read_sweep,
)
from camcal.errors import CamcalError
from camcal.models.dark import dark_to_parts
from camcal.synth.camera import SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, write_session

SMALL = dict(n_bias=3, n_dark=2, dark_exposures_s=(2.0, 16.0), n_flat=3, linearity_steps=9, linearity_jpeg=True,
             sweep_jpeg=True, sweep_step_nm=50.0, n_sweep=1)


@pytest.fixture(scope="module")
def small_session(tmp_path_factory) -> Path:
    cam = SyntheticCamera(SensorParams(width=96, height=64))
    return write_session(tmp_path_factory.mktemp("idx") / "S", cam, SessionPlan(**SMALL))


def _count_manifest_reads(monkeypatch) -> Counter:
    """Wrap camcal.io.manifest.read_manifest (and every camcal module's imported name of it) with a counter."""
    original = camcal.io.manifest.read_manifest
    reads: Counter = Counter()

    def counting(path, **kw):
        reads[Path(path).resolve()] += 1
        return original(path, **kw)

    for name, mod in list(sys.modules.items()):
        if name.startswith("camcal") and getattr(mod, "read_manifest", None) is original:
            monkeypatch.setattr(mod, "read_manifest", counting)
    return reads


def test_calibrate_reads_each_manifest_once(small_session, monkeypatch):
    manifests = sorted(p.resolve() for p in small_session.glob("*/*.csv"))
    assert len(manifests) == 5  # frames.csv of bias, dark, flat, linearity; sweep.csv
    reads = _count_manifest_reads(monkeypatch)
    profile, _ = calibrate_session(small_session)
    assert profile.dark is not None and profile.flat is not None and profile.spectral is not None
    assert profile.response["processed"].colour_matrix is not None  # the colour stage ran (JPEG twins)
    assert sorted(reads) == manifests
    assert set(reads.values()) == {1}, reads


def test_index_resolves_exposures_with_their_source(small_session):
    index = index_session(small_session)
    assert index.stages == ("bias", "dark", "flat", "linearity", "sweep")
    dark = index.stage("dark")
    assert isinstance(dark, StageFrames) and len(dark.frames) == 2 * 2
    assert {f.exposure_s for f in dark.frames} == {2.0, 16.0}
    assert {f.exposure_source for f in dark.frames} == {"frames.csv"}
    assert {f.iso for f in dark.frames} == {100.0}
    sweep_rows, name = index.manifest_of("sweep")
    assert name == "sweep.csv" and len(sweep_rows) == len(index.sweep_manifest)
    twins = [f for f in index.stage("sweep").frames if f.path.suffix == ".jpg"]
    assert twins and all(f.exposure_source == "tag" for f in twins)  # not in sweep.csv: the JPEG's own tag
    assert index.stage("missing") is None


def test_index_checks_without_decoding(tmp_path, small_session):
    s = tmp_path / "S"
    shutil.copytree(small_session, s)
    csv = s / "dark" / "frames.csv"
    text = csv.read_text()
    lines = text.splitlines()
    header = lines[0].split(",")
    i_iso = header.index("iso")
    row = lines[1].split(",")
    row[i_iso] = "200"
    csv.write_text("\n".join([lines[0], ",".join(row), *lines[2:]]) + "\n")
    with pytest.raises(CamcalError, match="mix ISO settings"):
        index_session(s)
    csv.write_text(text + "ghost.dng" + "," * (len(header) - 1) + "\n")
    with pytest.raises(CamcalError, match="frames.csv lists 'ghost.dng'"):
        index_session(s)
    csv.write_text(text)
    (s / "sweep" / "sweep.csv").write_text("file,wavelength_nm\nsweep_400.0nm_00.dng,400\n")
    with pytest.raises(CamcalError, match="radiance_W_m2_sr"):
        index_session(s)


def test_fits_read_no_file(tmp_path, small_session):
    """The pure steps work on what the file steps produced after the files are gone, and give what the
    one-call stage functions give."""
    s = tmp_path / "S"
    shutil.copytree(small_session, s)
    whole = fit_dark(measure_dark(s / "dark", s / "bias", DarkOptions(method="median")), DarkOptions(method="median"))
    bias_only = fit_dark(measure_dark(None, s / "bias"))
    opts = DarkOptions(method="median")
    stacks = measure_dark(s / "dark", s / "bias", opts)
    stacks_bias = measure_dark(None, s / "bias")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sweep_opts = SweepOptions(mode="relative")
        sens = fit_sweep(measure_sweep(s / "sweep", None, sweep_opts, dark=whole), sweep_opts)
        measured = measure_sweep(s / "sweep", read_sweep(s / "sweep"), sweep_opts, dark=whole)
    shutil.rmtree(s)
    for a, b in ((fit_dark(stacks, opts), whole), (fit_dark(stacks_bias), bias_only)):
        (da, ma), (db, mb) = dark_to_parts(a), dark_to_parts(b)
        assert da == db and ma.keys() == mb.keys()
        assert all(np.array_equal(ma[k], mb[k], equal_nan=True) for k in ma)
    again = fit_sweep(measured, sweep_opts)
    assert again.plane_names == sens.plane_names and again.mode == "relative"
    for p in sens.plane_names:
        assert np.array_equal(again.values[p], sens.values[p]) and np.array_equal(again.uncertainty[p],
                                                                                   sens.uncertainty[p])


@pytest.mark.formula
def test_dark_exposure_times_take_the_index_then_the_manifest_then_the_file_tag(tmp_path):
    """Each frame's exposure time: the session index's value first, then the frames.csv row, then the file's
    EXIF ExposureTime (a JPEG tagged 1/4 s here); none of them: the missing-metadata error naming the file."""
    from PIL import Image
    from PIL.TiffImagePlugin import IFDRational

    from camcal.calibrate.dark_frames import _exposure_times
    from camcal.calibrate.session import FrameRef, StageFrames
    from camcal.errors import MissingMetadataError

    a, b, c, d = (tmp_path / f"{n}.jpg" for n in "abcd")
    exif = Image.Exif()
    exif[0x829A] = IFDRational(1, 4)
    for p in (a, b, c):
        Image.new("RGB", (2, 2)).save(p, exif=exif.tobytes())
    d.write_bytes(b"not an image")
    manifest = {"a.jpg": {"exposure_s": 9.0}, "b.jpg": {"exposure_s": 2}, "c.jpg": {"exposure_s": None}}
    frames = StageFrames("dark", tmp_path, (FrameRef(a, exposure_s=0.5), FrameRef(b), FrameRef(c)), manifest)
    times = _exposure_times(frames, [a, b, c], manifest)
    assert times == [0.5, 2.0, 0.25] and all(type(t) is float for t in times)
    assert _exposure_times(tmp_path, [a, b, c], manifest) == [9.0, 2.0, 0.25]
    assert _exposure_times(tmp_path, [c], {}) == [0.25]
    with pytest.raises(MissingMetadataError) as e:
        _exposure_times(tmp_path, [b, d], manifest)
    assert e.value.field == "exposure_s" and e.value.path == d
    assert str(e.value).startswith(f"{d}: missing exposure_s: not in the file's metadata; add a 'exposure_s' column")

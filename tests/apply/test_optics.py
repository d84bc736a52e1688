"""Flats know their optics (issue 30, item 9): the flats' f-number and focal length in the profile, one vignetting
model per f-number, the photo's model picked by apply, warnings and --strict.

The synthetic camera has mechanical vignetting that falls with the f-number (``aperture_vignetting_k1``: corner
gain 0.42 at f/2.8, 0.60 at f/8), so a model of the wrong aperture is off by tens of percent at the corners.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from camcal.apply.batch import BatchOptions, run_batch
from camcal.apply.photo import apply
from camcal.calibrate.flat import fit_flat, measure_flat
from camcal.calibrate.run import calibrate_session
from camcal.calibrate.session import index_session
from camcal.errors import CamcalError
from camcal.io.exr import read_exr_header
from camcal.io.manifest import read_manifest
from camcal.io.read import load_frame
from camcal.models.flat import choose_flat
from camcal.models.profile import contract, flats_optics_text, load_profile, save_profile
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, write_session
from tests.conftest import run_cli
from tests.oracles import read_session_defaults

DATA = Path(__file__).resolve().parents[1] / "data"

PARAMS = SensorParams(width=128, height=96, aperture_vignetting_k1=-0.2, focal_length_mm=35.0)
PLAN = SessionPlan(stages=("flat", "sweep"), n_flat=4, flat_f_numbers=(2.8, 8.0),
                   photo_f_numbers=(2.8, 4.0, 8.0, 11.0), sweep_step_nm=20.0, n_sweep=1, sweep_jpeg=False)
CORNER = 8
"""Side of the corner blocks, output (half-resolution) pixels."""


@pytest.fixture(scope="module")
def optics_session(tmp_path_factory):
    """Flats at f/2.8 and f/8 (flat/f2.8/, flat/f8/), a coarse sweep at f/4, photos at f/2.8, 4, 8 and 11."""
    root = write_session(tmp_path_factory.mktemp("optics") / "S", SyntheticCamera(PARAMS), PLAN)
    profile, _ = calibrate_session(root)
    path = save_profile(profile, root.parent / "cam.camcal")
    return root, json.loads((root / "truth.json").read_text()), root.parent / "cam.camcal", path


def _photo(root, n):
    return load_frame(root / "photos" / f"photo_f{n:g}.dng")


def _corner_errors(image) -> dict[str, float]:
    """Per band: mean of the four corner blocks over the block at the optical centre, minus 1.

    The scene is uniform, so a correct flat leaves every pixel at one value. Noise of one corner mean: shot noise
    ~1.4 % and PRNU 1 % per pixel at the f/2.8 corners, over 4 x 64 pixels: 0.11 %; the centre (256 pixels):
    0.1 %; the flat model from 4 flats adds less than that. 1 % is thus > 5 sigma, while the other aperture's
    model is off by 10-25 %.
    """
    out = {}
    for band in ("R", "G", "B"):
        a = image.channels[band].astype(np.float64)
        h, w = a.shape
        cy, cx = int(round(PARAMS.optical_centre[1] * h)), int(round(PARAMS.optical_centre[0] * w))
        centre = np.nanmean(a[cy - 8: cy + 8, cx - 8: cx + 8])
        b = CORNER
        corners = np.nanmean([np.nanmean(a[:b, :b]), np.nanmean(a[:b, -b:]), np.nanmean(a[-b:, :b]),
                              np.nanmean(a[-b:, -b:])])
        out[band] = float(corners / centre - 1.0)
    return out


def test_profile_records_the_flats_f_numbers_and_focal_length(optics_session):
    root, truth, path, _ = optics_session
    profile = load_profile(path)
    flat = profile.flat
    assert flat.f_numbers() == [2.8, 8.0]
    for m in flat.models():
        assert m.optics.f_number_source == "frames.csv"  # the synthetic session lists f_number in frames.csv
        assert (m.optics.focal_length_mm, m.optics.focal_length_source) == (35.0, "tag")
        # each model fitted on its own flats: corner gain of its f-number (4 flats: ~0.3 % noise per corner)
        for c, g in m.corner_gain().items():
            assert g == pytest.approx(truth["flat"]["corner_gain"][f"{m.optics.f_number:g}"][c], abs=0.01)
    assert flat.apertures[0].prnu is flat.prnu  # one PRNU map, the pixels'
    shown = flats_optics_text(contract(profile)["flat"])  # what profile show and the report print
    assert shown.startswith("f/2.8 (frames.csv), f/8 (frames.csv); 35 mm (tag); one vignetting model per f-number")


@pytest.mark.parametrize(("n", "other"), [(2.8, 8.0), (8.0, 2.8)])
def test_each_photo_is_corrected_with_its_own_model(optics_session, n, other):
    root, truth, path, _ = optics_session
    profile = load_profile(path)
    image = apply(_photo(root, n), profile)
    assert image.metadata["optics"]["how"] == "measured" and image.metadata["optics"]["warning"] is None
    errors = _corner_errors(image)
    assert max(abs(e) for e in errors.values()) < 0.01, errors
    # the other aperture's model alone: the corners are off by tens of percent
    models = {m.optics.f_number: m for m in profile.flat.models()}
    wrong = dataclasses.replace(profile, flat=dataclasses.replace(models[other], apertures=()))
    wrong_image = apply(_photo(root, n), wrong)
    assert min(abs(e) for e in _corner_errors(wrong_image).values()) > 0.08
    assert "flats at f/" in " ".join(wrong_image.metadata["notes"])  # and that photo is warned about


def test_between_the_flats_interpolated_outside_the_nearest(optics_session):
    root, truth, path, _ = optics_session
    profile = load_profile(path)
    image = apply(_photo(root, 4.0), profile)
    rec = image.metadata["optics"]
    assert rec["how"] == "interpolated"
    w28 = (1 / 4.0**2 - 1 / 8.0**2) / (1 / 2.8**2 - 1 / 8.0**2)  # ln g linear in 1/N²
    assert rec["weights"] == [[2.8, pytest.approx(w28)], [8.0, pytest.approx(1 - w28)]]
    assert "interpolated" in rec["warning"] and rec["warning"] in image.metadata["notes"]
    errors = _corner_errors(image)
    assert max(abs(e) for e in errors.values()) <= rec["corner_difference_rel"], (errors, rec)
    assert max(abs(e) for e in errors.values()) < 0.03, errors  # the truth's a(N) ∝ 1/N²: close to the rule
    far = apply(_photo(root, 11.0), profile).metadata["optics"]
    assert far["how"] == "nearest" and far["weights"] == [[8.0, 1.0]]
    assert "outside the flats' f/2.8" in far["warning"] and "the f/8, 35 mm vignetting model is used" in far["warning"]
    assert 0 < far["corner_difference_rel"] < 0.2


def test_strict_refuses_such_photos_and_the_batch_goes_on(optics_session, tmp_path):
    root, _, path, _ = optics_session
    proc = run_cli("apply", path, root / "photos", "-o", tmp_path / "warn", "--jobs", "1")
    assert proc.returncode == 0, proc.stderr
    warnings = [ln for ln in proc.stderr.splitlines() if ln.startswith("camcal: warning:")]
    assert len(warnings) == 2, proc.stderr
    assert {"photo_f4.dng", "photo_f11.dng"} == {ln.split(": ")[2] for ln in warnings}, proc.stderr
    with open(tmp_path / "warn" / "apply_report.csv", newline="") as fh:
        rows = {r["file"].rsplit("/", 1)[-1]: r for r in csv.DictReader(fh)}
    assert rows["photo_f2.8.dng"]["warning"] == "" and "interpolated" in rows["photo_f4.dng"]["warning"]
    header = read_exr_header(tmp_path / "warn" / "photo_f11.dng.exr")
    assert header["optics"]["mismatch"] and "outside" in header["optics"]["warning"]

    proc = run_cli("apply", path, root / "photos", "-o", tmp_path / "strict", "--jobs", "1", "--strict")
    assert proc.returncode == 1
    failed = [ln for ln in proc.stderr.splitlines() if ln.startswith("camcal: failed:")]
    assert len(failed) == 2 and all("refused by --strict" in ln for ln in failed), proc.stderr
    assert sorted(p.name for p in (tmp_path / "strict").glob("*.exr")) == ["photo_f2.8.dng.exr",
                                                                           "photo_f8.dng.exr"]
    # a rerun with --strict does not take the warned EXRs of the first run as done
    shutil.copy(tmp_path / "warn" / "photo_f4.dng.exr", tmp_path / "strict")
    report = run_batch(path, [root / "photos" / "photo_f4.dng"], tmp_path / "strict", BatchOptions(strict=True))
    assert report.counts["failed"] == 1 and "refused by --strict" in report.results[0].error
    # without --strict the rerun keeps it, and still reports its warning
    report = run_batch(path, [root / "photos" / "photo_f4.dng"], tmp_path / "warn", BatchOptions())
    assert report.counts["skipped"] == 1 and "interpolated" in report.results[0].warning


def test_one_flat_aperture_warns_by_its_corner_falloff(optics_session):
    root, _, path, _ = optics_session
    profile = load_profile(path)
    only = dataclasses.replace(profile, flat=dataclasses.replace(profile.flat, apertures=()))  # f/2.8 only
    choice = choose_flat(only.flat, 8.0, 35.0)
    bound = 1 / float(np.min(only.flat.corner_values())) - 1  # stopped down: the true gain is between g and 1
    assert choice.how == "nearest" and choice.mismatch
    assert choice.corner_difference_rel == pytest.approx(bound)
    assert "flats at f/2.8, 35 mm only" in choice.warning and f"up to +{100 * bound:.3g} %" in choice.warning
    # the truth at f/8 is within that bound: corrected with the f/2.8 model, the corners come out too bright
    errors = _corner_errors(apply(_photo(root, 8.0), only))
    assert all(0.08 < e <= bound for e in errors.values()), errors
    wider = choose_flat(dataclasses.replace(profile.flat.apertures[0], apertures=()), 2.8, 35.0)  # flats at f/8
    assert wider.how == "nearest" and wider.corner_difference_rel is None and "under-corrected" in wider.warning
    with pytest.raises(CamcalError, match="refused by --strict"):
        apply(_photo(root, 8.0), only, strict=True)
    zoomed = choose_flat(profile.flat, 2.8, 50.0)
    assert zoomed.mismatch and "focal length 50 mm, the flats' 35 mm" in zoomed.warning
    assert choose_flat(profile.flat, 2.83, 35.0).how == "measured"  # 2√2 is f/2.8


def test_old_profile_flats_of_unknown_optics(optics_session):
    root, _, _, _ = optics_session
    stored = load_profile(DATA / "stored.camcal")  # schema 1.3: no optics
    assert stored.flat.optics.f_number is None and stored.flat.f_numbers() == [None]
    choice = choose_flat(stored.flat, 4.0, None)
    assert choice.how == "unchecked" and "the flats' f-number is unknown" in choice.warning


def test_flats_in_one_folder_grouped_by_their_f_number(tmp_path):
    plan = dataclasses.replace(PLAN, stages=("flat",), flat_folders=False, photo_f_numbers=())
    root = write_session(tmp_path / "S", SyntheticCamera(PARAMS), plan)
    assert not (root / "flat" / "f8").exists()
    profile, notes = calibrate_session(root)
    assert profile.flat.f_numbers() == [2.8, 8.0]
    assert any("one vignetting model per f-number" in n for n in notes)


def test_aperture_folder_names_the_f_number_and_a_contradiction_is_refused(tmp_path):
    cam = SyntheticCamera(SensorParams(width=64, height=64))
    spec = np.full(WAVELENGTHS_NM.size, 0.02)
    for n in (2.8, 8.0):
        cam.write_dng(tmp_path / "S" / "flat" / f"f{n:g}" / f"a{n:g}.dng", Scene.uniform(spec), exposure_s=0.01,
                      f_number=n, tag_f_number=False, rng=np.random.default_rng(1))
    refs = {r.path.name: r for r in index_session(tmp_path / "S").frames["flat"].frames}
    assert (refs["a2.8.dng"].f_number, refs["a2.8.dng"].f_number_source) == (2.8, "folder flat/f2.8/")
    assert refs["a8.dng"].f_number == 8.0
    cam.write_dng(tmp_path / "S" / "flat" / "f8" / "b.dng", Scene.uniform(spec), exposure_s=0.01, f_number=2.8,
                  rng=np.random.default_rng(2))
    with pytest.raises(CamcalError, match=r"is in flat/f8/ but its f-number is f/2.8 \(tag\)"):
        index_session(tmp_path / "S")


def test_focal_length_from_frames_csv_and_session_toml(tmp_path):
    (tmp_path / "frames.csv").write_text("file,focal_length_mm\na.dng,50\n")
    (tmp_path / "a.dng").write_bytes(b"")
    assert read_manifest(tmp_path / "frames.csv")["a.dng"]["focal_length_mm"] == 50.0
    (tmp_path / "session.toml").write_text("focal_length_mm = 24.0\n")
    assert read_session_defaults(tmp_path / "session.toml") == {"focal_length_mm": 24.0}
    (tmp_path / "frames.csv").write_text("file,focal_length_mm\na.dng,0\n")
    with pytest.raises(CamcalError, match="focal_length_mm"):
        read_manifest(tmp_path / "frames.csv")


def test_flat_stage_refuses_several_f_numbers_with_the_next_step(optics_session, tmp_path):
    root, _, _, _ = optics_session
    with pytest.raises(CamcalError, match=r"holds its flats in f2\.8/, f8/ \(one folder per f-number\)"):
        measure_flat(root / "flat")
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for n in ("2.8", "8"):
        for i in range(2):
            shutil.copy(root / "flat" / f"f{n}" / f"flat_f{n}_{i:03d}.dng", mixed)
    with pytest.raises(CamcalError, match=r"flats at several f-numbers \(f/2\.8, f/8\)"):
        measure_flat(mixed)
    model = fit_flat(measure_flat(root / "flat" / "f8"))
    assert (model.optics.f_number, model.optics.focal_length_mm) == (8.0, 35.0)

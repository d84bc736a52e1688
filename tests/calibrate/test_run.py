"""Messy sessions: every frame gets a verdict, the unusable ones are left out and named, the rest calibrates.

Each test plants a known problem in a synthetic session (``camcal.synth.messy`` or by hand) and asserts that the
planted file, and only it, is left out with the expected reason, against the planted truth.
"""

from __future__ import annotations

import json
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import camcal.io.read as camcal_io
from camcal.calibrate.response import MIN_EXPOSURES, fit_series, measure_response, saturation_point
from camcal.calibrate.run import calibrate_session, stage_checks
from camcal.calibrate.screen import screen_session
from camcal.calibrate.session import index_session
from camcal.calibrate.stack import StackOptions, combine_frames
from camcal.calibrate.sweep import MIN_WAVELENGTHS
from camcal.errors import CamcalError, FrameLeftOut
from camcal.models.profile import load_profile
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.dng import write_dng
from camcal.synth.messy import plant_problems
from camcal.synth.session import SessionPlan, write_session
from tests.conftest import assert_one_line_error, run_cli

TINY = dict(n_bias=3, n_dark=2, dark_exposures_s=(2.0, 16.0), n_flat=3, linearity_steps=9, linearity_jpeg=False,
            sweep_jpeg=False, sweep_step_nm=50.0, n_sweep=2)
REALDATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "realdata"
PI = sorted((REALDATA / "pi").glob("*.dng"))


@pytest.fixture(scope="module")
def tiny_camera() -> SyntheticCamera:
    return SyntheticCamera(SensorParams(width=96, height=64))


@pytest.fixture(scope="module")
def tiny_session(tmp_path_factory, tiny_camera) -> Path:
    """A small clean session (96x64, few frames, 50 nm sweep steps with two repeats), written once."""
    return write_session(tmp_path_factory.mktemp("tiny") / "S", tiny_camera, SessionPlan(**TINY))


@pytest.fixture
def tiny(tmp_path, tiny_session) -> Path:
    """A private copy of the tiny session to plant problems in."""
    return Path(shutil.copytree(tiny_session, tmp_path / "S"))


def _left_out(index_or_root) -> dict[str, str]:
    index = index_session(index_or_root)
    return {f"{v.stage}/{v.file}": v.reason for v in screen_session(index, stage_checks()).left_out()}


# ---- one verdict kind at a time ------------------------------------------------------------------------------


def test_clean_session_leaves_nothing_out(tiny):
    assert _left_out(tiny) == {}


def test_truncated_flat_is_left_out_as_unreadable(tiny):
    victim = tiny / "flat" / "flat_001.dng"
    victim.write_bytes(victim.read_bytes()[:3000])
    out = _left_out(tiny)
    assert list(out) == ["flat/flat_001.dng"]
    assert out["flat/flat_001.dng"].startswith("unreadable: ")


def test_copied_dark_frame_keeps_the_first_copy(tiny):
    shutil.copyfile(tiny / "dark" / "dark_016.000s_00.dng", tiny / "dark" / "dark_016.000s_00_copy.dng")
    out = _left_out(tiny)
    assert list(out) == ["dark/dark_016.000s_00_copy.dng"]  # the first in name order is kept
    assert out["dark/dark_016.000s_00_copy.dng"].startswith("duplicate: the same pixels as dark_016.000s_00.dng")


def test_jpeg_of_another_camera_and_size_in_flat_is_left_out(tiny):
    other = SyntheticCamera(SensorParams(width=80, height=64, make="Othercam", model="Phone 7"))
    other.write_jpeg(tiny / "flat" / "IMG_0001.jpg", Scene.uniform(np.full(401, 0.02)), exposure_s=0.01,
                     iso=100, f_number=4, rng=np.random.default_rng(1))
    out = _left_out(tiny)
    assert list(out) == ["flat/IMG_0001.jpg"]
    assert out["flat/IMG_0001.jpg"].startswith("another camera and size: Othercam Phone 7, 80x64 pixels")


def test_raw_of_another_size_is_left_out(tiny):
    other = SyntheticCamera(SensorParams(width=64, height=64))
    other.write_dng(tiny / "bias" / "bias_999.dng", Scene.dark(), exposure_s=1 / 4000, iso=100, f_number=4,
                    rng=np.random.default_rng(2))
    out = _left_out(tiny)
    assert out == {"bias/bias_999.dng": "another size: 64x64 pixels; the session's frames are 96x64 pixels"}


def test_flat_saturated_beyond_use_is_left_out(tiny, tiny_camera):
    p = tiny_camera.params
    write_dng(tiny / "flat" / "flat_009.dng", np.full((p.height, p.width), p.white_dn, np.uint16),
              cfa_pattern=p.cfa_pattern, black_level_dn=tiny_camera.black_by_position(), white_level_dn=p.white_dn,
              exposure_s=0.01, f_number=4.0, iso=100.0, make=p.make, model=p.model, serial=p.serial)
    out = _left_out(tiny)
    assert list(out) == ["flat/flat_009.dng"]
    assert out["flat/flat_009.dng"].startswith("flat is saturated: 100 % of pixels at the white level")


def test_sweep_frame_with_shutter_closed_is_left_out(tiny, tiny_camera):
    rows = (tiny / "sweep" / "sweep.csv").read_text().splitlines()
    row = next(r for r in rows if r.startswith("sweep_550.0nm_01.dng"))
    exposure_s = float(row.split(",")[5])
    tiny_camera.write_dng(tiny / "sweep" / "sweep_550.0nm_01.dng", Scene.dark(), exposure_s=exposure_s, iso=100,
                          f_number=4.0, rng=np.random.default_rng(3))
    with pytest.warns(FrameLeftOut, match=r"left out: sweep_550.0nm_01.dng: no light recorded"):
        profile, _ = calibrate_session(tiny)
    left = {r["file"]: r["reason"] for r in profile.provenance.left_out}
    assert list(left) == ["sweep/sweep_550.0nm_01.dng"]
    assert left["sweep/sweep_550.0nm_01.dng"].startswith("no light recorded (shutter closed or trigger missed)")
    assert profile.spectral is not None and profile.spectral.n_frames["550"] == 1  # its lit repeat is used


def test_dark_frame_alone_at_its_exposure_time_is_left_out(tiny):
    """Two darks at 2 s, one of them unreadable: the other has no temporal noise to measure alone, so it is left out
    too, and the dark current is fitted from 16 s and the bias frames."""
    (tiny / "dark" / "dark_002.000s_01.dng").write_bytes(b"II*\x00 truncated")
    with pytest.warns(FrameLeftOut, match=r"left out: dark_002.000s_00.dng: alone at its exposure time"):
        profile, _ = calibrate_session(tiny)
    left = {r["file"]: r["reason"] for r in profile.provenance.left_out}
    assert left["dark/dark_002.000s_01.dng"].startswith("unreadable: ")
    assert left["dark/dark_002.000s_00.dng"].startswith("alone at its exposure time (2 s)")
    assert len(left) == 2 and profile.dark is not None and profile.dark.dark_current_dn_per_s is not None


def test_too_few_sweep_wavelengths_writes_the_profile_without_c_and_exits_1(tiny, tmp_path):
    """A 50 nm sweep from 400 to 700 nm has 7 wavelengths; with 4 of them unreadable, 3 remain of the 4 needed."""
    for wl in (450, 500, 550, 600):
        for j in (0, 1):
            (tiny / "sweep" / f"sweep_{wl:.1f}nm_{j:02d}.dng").write_bytes(b"II*\x00 truncated")
    out = tmp_path / "p.camcal"
    proc = run_cli("calibrate", tiny, "-o", out)
    assert proc.returncode == 1, proc.stderr
    assert (f"the sweep stage needs at least {MIN_WAVELENGTHS} usable wavelengths, 3 remain (7 in sweep.csv, 4 "
            "without a usable frame" in " ".join(proc.stderr.split()))
    profile = load_profile(out)
    assert profile.spectral is None and profile.dark is not None and profile.flat is not None and profile.response
    assert [r["stage"] for r in profile.provenance.not_calibrated] == ["sweep"]
    assert len(profile.provenance.left_out) == 8
    show = json.loads(run_cli("profile", "show", out, "--json").stdout)
    assert show["spectral_sensitivity"] is None
    assert "3 remain" in show["provenance"]["not_calibrated"][0]["reason"]
    assert "3 remain" in " ".join(run_cli("profile", "show", out).stdout.split())
    # --strict: the first left-out frame refuses the session, nothing written
    strict = tmp_path / "strict.camcal"
    assert_one_line_error(run_cli("calibrate", tiny, "-o", strict, "--strict"), "sweep_450.0nm_00.dng",
                          "unreadable", "--strict")
    assert not strict.exists()


def test_too_few_linearity_exposures_skips_the_stage(tiny):
    for p in sorted((tiny / "linearity").glob("lin_*.dng"))[MIN_EXPOSURES - 1:]:
        p.write_bytes(b"II*\x00 stripped")
    profile, _ = calibrate_session(tiny)
    assert profile.response is None and profile.spectral is not None
    (rec,) = profile.provenance.not_calibrated
    assert rec["stage"] == "linearity"
    assert f"needs at least {MIN_EXPOSURES} usable distinct exposures, {MIN_EXPOSURES - 1} remain" in rec["reason"]


# ---- saturation is data -------------------------------------------------------------------------------------


def test_saturation_point_brackets_the_saturation_exposure():
    x = np.array([1.0, 2.0, 4.0, 8.0, 16.0])
    mean = np.array([10.0, 20.0, 40.0, 80.0, 100.0])
    sat = saturation_point(x, mean, np.array([12, 22, 44, 95, 100.0]), np.array([0, 0, 0, 1, 1], bool),
                           np.array([1, 1, 1, 0, 0], bool), 100.0)
    assert sat.reached and sat.n_saturated == 2 and sat.level_dn == 100.0 and sat.exposure_s == 8.0
    assert sat.fitted_range_dn == (10.0, 40.0) and sat.fitted_exposure_s == (1.0, 4.0)


def test_fully_saturated_top_steps_are_used_and_end_the_linear_range(tiny, tiny_camera):
    """Two more steps with every pixel at the white level: read (not refused), marked saturated, not fitted; the
    fit (α, γ, β) is the same as without them, exactly, since they carry no weight in it."""
    before = fit_series(measure_response(index_session(tiny).frames["linearity"])["raw"])
    p = tiny_camera.params
    rows = (tiny / "linearity" / "frames.csv").read_text().splitlines()
    for k, t in enumerate((1.0, 2.0)):
        name = f"lin_{90 + k}.dng"
        write_dng(tiny / "linearity" / name, np.full((p.height, p.width), p.white_dn, np.uint16),
                  cfa_pattern=p.cfa_pattern, black_level_dn=tiny_camera.black_by_position(),
                  white_level_dn=p.white_dn, exposure_s=t, f_number=4.0, iso=100.0, make=p.make, model=p.model,
                  serial=p.serial)
        rows.append(f"{name},{t},100.0,4.0")
    (tiny / "linearity" / "frames.csv").write_text("\n".join(rows) + "\n")
    assert _left_out(tiny) == {}  # two fully saturated frames are alike but not copies of one another
    after = fit_series(measure_response(index_session(tiny).frames["linearity"])["raw"])
    for ch in ("R", "G1", "G2", "B"):
        b, a = before.channels[ch], after.channels[ch]
        assert (a.alpha, a.gamma, a.beta) == (b.alpha, b.gamma, b.beta), ch
        pts = after.points[ch]
        for name in ("lin_90.dng", "lin_91.dng"):
            i = pts["files"].index(name)
            assert pts["saturated"][i] and not pts["used"][i]
        # the clean tiny series stops at 16 % of full scale; the first saturated step is at 1 s (ISO 100, f/4:
        # the reference setting, so x = t)
        assert np.isnan(b.saturation_exposure_s) and a.saturation_dn == p.white_dn
        assert a.saturation_exposure_s == pytest.approx(1.0) and a.fitted_exposure_s[1] < 1.0


# ---- a stage asks only for what it uses ---------------------------------------------------------------------


def test_bias_only_session_needs_no_f_number(tmp_path, tiny_camera):
    s = write_session(tmp_path / "S", tiny_camera, SessionPlan(stages=("bias",), fixed_aperture=True,
                                                               session_defaults=False, n_bias=3))
    out = tmp_path / "b.camcal"
    proc = run_cli("calibrate", s, "-o", out)
    assert proc.returncode == 0, proc.stderr
    profile = load_profile(out)
    assert profile.reference_f_number is None and profile.dark is not None
    assert "f-number" not in proc.stderr


@pytest.mark.skipif(len(PI) < 2, reason="../shared/realdata/pi is absent")
def test_real_pi_frames_in_bias_calibrate_without_f_number(tmp_path):
    """The real IMX296 frames (no f-number tag) in bias/, no session.toml: no f-number or ISO is asked for.
    Per the realdata README two files are lit scenes with clipped pixels and one was written by another program
    (Model 'imx296'): those are left out and named; the dark frames and dim scenes calibrate."""
    (tmp_path / "S" / "bias").mkdir(parents=True)
    for p in PI:
        shutil.copyfile(p, tmp_path / "S" / "bias" / p.name)
    out = tmp_path / "pi.camcal"
    proc = run_cli("calibrate", tmp_path / "S", "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "reference" not in proc.stderr and "f_number" not in proc.stderr
    profile = load_profile(out)
    assert profile.reference_f_number is None and profile.dark is not None
    left = {r["file"]: r["reason"] for r in profile.provenance.left_out}
    assert left["bias/c21ff2bc_image.dng"].startswith("another camera")
    assert all(not f.startswith("bias/dark_frame") for f in left)


# ---- the messy preset --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def messy(tmp_path_factory, session_dir, camera) -> tuple[Path, list[dict], Path, object]:
    """The full default session with every problem planted (camcal.synth.messy), calibrated by the CLI."""
    root = Path(shutil.copytree(session_dir, tmp_path_factory.mktemp("messy") / "S"))
    planted = plant_problems(root, camera)
    out = root.parent / "messy.camcal"
    proc = run_cli("calibrate", root, "-o", out, env={"COLUMNS": "240"})  # the summary table unwrapped
    return root, planted, out, proc


def test_messy_preset_names_every_planted_problem(messy):
    root, planted, out, proc = messy
    assert proc.returncode == 0, proc.stderr
    assert json.loads((root / "truth.json").read_text())["planted"] == planted
    assert {p["problem"] for p in planted} == {"truncated", "duplicate", "other_camera", "no_light", "saturated"}
    left = {r["file"]: r["reason"] for r in load_profile(out).provenance.left_out}
    shown = {r["file"]: r["reason"] for r in
             json.loads(run_cli("profile", "show", out, "--json").stdout)["provenance"]["left_out"]}
    assert shown == left
    html = run_cli("report", out, "-o", root.parent / "r.html")
    assert html.returncode == 0, html.stderr
    report = (root.parent / "r.html").read_text()
    summary = " ".join(proc.stdout.split())
    saturated = json.loads(run_cli("profile", "show", out, "--json").stdout)["response"]["models"]["raw"][
        "saturated_files"]
    for p in planted:
        if p["verdict"] == "used":  # saturated linearity steps: data that end the linear range, named as such
            name = p["file"].split("/")[1]
            assert p["file"] not in left and name in saturated and name in summary and name in report
            continue
        assert left[p["file"]].startswith(p["reason"]), p
        assert p["file"] in summary and p["file"] in report
    assert len(left) == sum(p["verdict"] == "left out" for p in planted)


def test_messy_preset_matches_the_clean_accuracy(messy, profile_path, truth, camera):
    """Tolerances of the issue: c(λ) within 1 % RMS of the peak, β within 2 %, vignetting within 1 % of the
    camera's own map. The clean session reaches 0.1-0.4 %, 0.03-0.3 % and 0.16 % (seed 1); the left-out frames
    (one of eight flats, one of three sweep repeats at 550 nm) move them by less than 0.01 %."""
    _, _, out, _ = messy
    profile = load_profile(out)
    clean = load_profile(profile_path)
    s = profile.spectral
    wl_true = np.asarray(truth["spectral_sensitivity"]["wavelength_nm"])
    rgb = s.rgb()
    for ch in ("R", "G", "B"):
        true = np.interp(s.wavelength_nm, wl_true, truth["spectral_sensitivity"][ch])
        assert np.sqrt(np.mean((rgb[ch] - true) ** 2)) / true.max() < 0.01, ch
    for p in ("R", "G1", "G2", "B"):
        beta = float(profile.dark.summary()["dark_current_dn_per_s"][p])
        assert beta == pytest.approx(truth["dark_current_dn_per_s"][p], rel=0.02), p
    assert np.max(np.abs(profile.flat.gain() / camera.vignetting_map - 1)) < 0.01
    for ch in ("R", "G1", "G2", "B"):  # the saturated top steps carry no weight: the same fit as the clean one
        m, c = profile.response["raw"].channels[ch], clean.response["raw"].channels[ch]
        assert (m.alpha, m.gamma, m.beta) == pytest.approx((c.alpha, c.gamma, c.beta), rel=1e-9), ch
        assert np.isfinite(m.saturation_exposure_s) and m.saturation_dn == camera.params.white_dn


def test_messy_preset_strict_refuses(messy, tmp_path):
    root, _, _, _ = messy
    out = tmp_path / "strict.camcal"
    proc = run_cli("calibrate", root, "-o", out, "--strict")
    assert_one_line_error(proc, "--strict")
    assert proc.returncode == 2 and not out.exists()


def test_calibrate_refuses_when_no_stage_can_be_calibrated(tmp_path, tiny_camera):
    s = write_session(tmp_path / "S", tiny_camera, SessionPlan(stages=("bias",), n_bias=2))
    shutil.copyfile(s / "bias" / "bias_000.dng", s / "bias" / "bias_001.dng")
    with pytest.raises(CamcalError, match="no stage could be calibrated.*2 usable frames.*1 remain"):
        calibrate_session(s)


# ---- each frame decoded once (issue 28) ------------------------------------------------------------------------


def test_every_frame_is_decoded_once(tiny, monkeypatch):
    """Each stage judges its own frames as it decodes them: in a whole calibration every frame is decoded once
    (the screening reads only headers). Counted at the RAW decoder, which every stage reaches through
    camcal.io.read.load_frame."""
    counts: Counter = Counter()
    real = camcal_io._load_raw

    def counting(path):
        counts[Path(path).relative_to(tiny).as_posix()] += 1
        return real(path)

    monkeypatch.setattr(camcal_io, "_load_raw", counting)
    profile, _ = calibrate_session(tiny)
    assert profile.dark is not None and profile.response and profile.spectral is not None
    for stage in ("bias", "dark", "flat", "linearity", "sweep"):
        names = sorted(p.name for p in (tiny / stage).glob("*.dng"))
        assert names and {n: counts[f"{stage}/{n}"] for n in names} == dict.fromkeys(names, 1), stage


def test_messy_bias_judged_while_stacked_gives_the_clean_stack(tiny):
    """A copy and a truncated file among the bias frames, judged as they are stacked (2 decode threads): the
    same verdicts as the screening gives, and exactly the stack of the clean frames alone (mean and
    sigma-clipped, kept planes included)."""
    clean = sorted((tiny / "bias").glob("bias_*.dng"))
    shutil.copyfile(clean[0], tiny / "bias" / "bias_000_copy.dng")
    (tiny / "bias" / "bias_000_cut.dng").write_bytes(clean[1].read_bytes()[:5000])
    index = index_session(tiny)
    names = {r.path.name for r in index.frames["bias"].frames}
    expected = _left_out(tiny)
    assert set(expected) == {"bias/bias_000_copy.dng", "bias/bias_000_cut.dng"}
    for method in ("mean", "sigma_clip"):
        screening = screen_session(index, stage_checks(), defer={"bias": names})
        assert screening.left_out() == []  # nothing judged before the stage
        judge = screening.judge("bias", stage_checks()["bias"])
        got = combine_frames(index.frames["bias"].paths, StackOptions(method=method, jobs=2, keep_frames=2), rule=judge)
        want = combine_frames(clean, StackOptions(method=method, jobs=1, keep_frames=2))
        assert {f"bias/{v.file}": v.reason for v in judge.left_out()} == expected
        assert got.paths == want.paths and got.n_frames == len(clean)
        for name in ("value", "mean", "variance", "count", "variance_all", "mean_all"):
            assert np.array_equal(getattr(got, name), getattr(want, name), equal_nan=True), (method, name)
        assert all(np.array_equal(a, b) for a, b in zip(got.kept_planes, want.kept_planes, strict=True))


def test_a_copy_read_before_its_original_passes_its_place_to_the_original(tiny):
    """Frames given out of file order (the copy before the frame it copies): the copy is combined first, then
    found to be the copy when the original comes; the original takes its place, and the stack is that of the
    frames without the copy."""
    b = sorted((tiny / "bias").glob("bias_*.dng"))
    copy = tiny / "bias" / "bias_000_copy.dng"
    shutil.copyfile(b[0], copy)
    index = index_session(tiny)
    names = {r.path.name for r in index.frames["bias"].frames}
    for method in ("mean", "sigma_clip"):
        judge = screen_session(index, stage_checks(), defer={"bias": names}).judge("bias", stage_checks()["bias"])
        got = combine_frames([b[1], copy, b[0], b[2]], StackOptions(method=method, jobs=1, keep_frames=3), rule=judge)
        want = combine_frames([b[1], b[0], b[2]], StackOptions(method=method, jobs=1, keep_frames=3))
        assert [v.file for v in judge.left_out()] == [copy.name] and judge.superseded == [copy]
        assert got.paths == want.paths
        for name in ("value", "mean", "variance", "count"):
            assert np.array_equal(getattr(got, name), getattr(want, name), equal_nan=True), (method, name)
        assert all(np.array_equal(x, y) for x, y in zip(got.kept_planes, want.kept_planes, strict=True))


def test_copies_in_the_linearity_series_and_the_sweep_are_left_out_as_they_are_measured(tiny, tiny_session):
    """A copy of a linearity frame and of a sweep row, judged by their stages as they decode them: each left out
    as a duplicate of its original, and the response and c(λ) exactly those of the clean session."""
    clean, _ = calibrate_session(tiny_session)
    lin = sorted((tiny / "linearity").glob("lin_*.dng"))[3]
    shutil.copyfile(lin, lin.with_name(lin.stem + "_copy.dng"))
    sweep = tiny / "sweep" / "sweep_600.0nm_01.dng"
    shutil.copyfile(tiny / "sweep" / "sweep_600.0nm_00.dng", sweep)  # the second repeat is a copy of the first
    profile, _ = calibrate_session(tiny)
    left = {r["file"]: r["reason"] for r in profile.provenance.left_out}
    assert left == {
        f"linearity/{lin.stem}_copy.dng": f"duplicate: the same pixels as {lin.name} (a copy of one exposure); the "
                                          "first copy is kept",
        "sweep/sweep_600.0nm_01.dng": "duplicate: the same pixels as sweep_600.0nm_00.dng (a copy of one "
                                      "exposure); the first copy is kept"}
    for ch in ("R", "G1", "G2", "B"):
        m, c = profile.response["raw"].channels[ch], clean.response["raw"].channels[ch]
        assert (m.alpha, m.gamma, m.beta) == (c.alpha, c.gamma, c.beta), ch
    assert profile.spectral.n_frames["600"] == 1 and clean.spectral.n_frames["600"] == 2


def test_a_dark_copy_given_another_exposure_time_is_left_out_and_not_stacked(tiny, tiny_session):
    """A copy of a 16 s dark listed at 2 s in frames.csv: stacked with the 2 s frames before its original (16 s)
    shows it is a copy; the darks are stacked again without it, and the dark model is exactly the clean one."""
    clean, _ = calibrate_session(tiny_session)
    copy = tiny / "dark" / "dark_016.000s_00_copy.dng"
    shutil.copyfile(tiny / "dark" / "dark_016.000s_00.dng", copy)
    with (tiny / "dark" / "frames.csv").open("a") as fh:
        fh.write(f"{copy.name},2.0,100.0,4.0,24.0\n")
    profile, _ = calibrate_session(tiny)
    assert {r["file"]: r["reason"] for r in profile.provenance.left_out} == {
        f"dark/{copy.name}": "duplicate: the same pixels as dark_016.000s_00.dng (a copy of one exposure); the "
                             "first copy is kept"}
    for name in ("bias_dn", "dark_current_dn_per_s", "read_noise_dn"):
        a, b = getattr(profile.dark, name, None), getattr(clean.dark, name, None)
        assert a is not None and np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True), name

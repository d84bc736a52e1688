"""Spectral curves from elsewhere (issue 18): SPECTACLE files both ways, curves into a profile, and the
absolute scale from photos of reference targets ("calibrating without a monochromator").

SPECTACLE's reader is ``np.loadtxt(path, delimiter=",").T`` (``spectacle.spectral.load_spectral_response``)
and its writer ``np.savetxt(path, data, delimiter=",", header="Wavelength, R, G, B, G2, R_err, G_err, B_err,
G2_err")``; the ``pyspectacle`` package itself does not import with scipy >= 1.14 (``scipy.integrate.simps``
is gone), so the tests call those two numpy functions exactly as SPECTACLE does.

Noise budget of the synthetic targets (default sensor, region = central 20 % of each side ≈ 950 plane pixels
at 40 % of full scale): per-pixel scatter ≈ 1.5 % (shot ≈ 1 %, PRNU 1 %), so the region's mean carries
≈ 0.05 %; the dark and flat models add < 0.1 %. Hence k within 0.5 % and residuals of order 0.05 %.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from camcal.apply.photo import apply, prepare
from camcal.curves.files import (
    SPECTACLE_HEADER,
    read_curve_table,
    read_spectacle_csv,
    read_spectral_file,
    spectacle_array,
    write_spectacle_csv,
)
from camcal.curves.import_spectral import import_spectral, predicted_rate, radiance_target, region_rate
from camcal.errors import CamcalError
from camcal.frame import PLANES
from camcal.io.exr import read_exr
from camcal.io.hashing import sha256_file
from camcal.io.read import load_frame
from camcal.models.profile import contract, load_profile, save_profile
from camcal.models.spectra import WAVELENGTHS_NM, camera_sensitivities, planck_radiance
from camcal.models.spectral import RELATIVE_UNITS, SpectralSensitivity
from camcal.synth.camera import Scene
from camcal.synth.session import exposure_for_level
from camcal.synth.targets import grey_card_reflectance, smooth_target_spectra, write_target_photos
from tests.conftest import assert_one_line_error, run_cli

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "realdata" / "spectral"
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason="../shared/realdata is absent")


def spectacle_read(path: Path) -> np.ndarray:
    """SPECTACLE's reader, exactly (spectacle.spectral.load_spectral_response)."""
    return np.loadtxt(path, delimiter=",").T


def spectacle_write(path: Path, data: np.ndarray) -> None:
    """SPECTACLE's writer call, exactly (calibration/spectral_response_monochromator.py)."""
    np.savetxt(path, data, delimiter=",", header="Wavelength, R, G, B, G2, R_err, G_err, B_err, G2_err")


def curves(rgb: np.ndarray, wl: np.ndarray = WAVELENGTHS_NM, unc: float = 0.0) -> SpectralSensitivity:
    v = {"R": rgb[0], "G1": rgb[1], "G2": rgb[1], "B": rgb[2]}
    return SpectralSensitivity(wl, v, {p: unc * v[p] for p in PLANES}, RELATIVE_UNITS, "relative")


# ---- SPECTACLE's format ------------------------------------------------------------------------------------
def test_export_is_read_by_spectacles_reader(tmp_path):
    rng = np.random.default_rng(3)
    s = curves(rng.random((3, 41)), np.arange(400.0, 601.0, 5.0), unc=0.01)
    path = write_spectacle_csv(s, tmp_path / "c.csv")
    assert path.read_text().splitlines()[0] == "# " + SPECTACLE_HEADER
    data = spectacle_read(path)
    assert data.shape == (9, 41)
    np.testing.assert_array_equal(data, spectacle_array(s).T)  # %.18e: every float64 exactly
    np.testing.assert_array_equal(data[1], s.values["R"])
    np.testing.assert_array_equal(data[5], s.uncertainty["R"])
    back = read_spectacle_csv(path)
    for p in PLANES:
        np.testing.assert_array_equal(back.values[p], s.values[p])


def test_spectacle_written_file_imports(tmp_path):
    wl = np.arange(390.0, 701.0, 10.0)
    data = np.stack([wl, *np.random.default_rng(5).random((8, wl.size))]).T
    spectacle_write(tmp_path / "s.csv", data)
    s, fmt = read_spectral_file(tmp_path / "s.csv")
    assert fmt == "spectacle" and s.mode == "relative"
    np.testing.assert_array_equal(s.wavelength_nm, wl)
    for i, p in enumerate(("R", "G1", "B", "G2")):
        np.testing.assert_array_equal(s.values[p], data[:, 1 + i])
        np.testing.assert_array_equal(s.uncertainty[p], data[:, 5 + i])
    # written back: byte for byte what SPECTACLE's writer made
    write_spectacle_csv(s, tmp_path / "again.csv")
    assert (tmp_path / "again.csv").read_bytes() == (tmp_path / "s.csv").read_bytes()


@needs_real
def test_real_spectacle_files_round_trip_byte_for_byte(tmp_path):
    for f in sorted(REAL.glob("*_spectral_response.csv")):
        s = read_spectacle_csv(f)
        np.testing.assert_array_equal(spectacle_array(s).T, spectacle_read(f))
        out = write_spectacle_csv(s, tmp_path / f.name)
        assert out.read_bytes() == f.read_bytes(), f.name


@needs_real
def test_both_real_cameras_load_into_profiles(tmp_path):
    for dat in sorted(REAL.glob("*_response.dat")):
        if dat.name.endswith("_spectral_response.dat"):
            continue
        csv = dat.with_name(dat.name.replace("_response.dat", "_spectral_response.csv"))
        made = {}
        for src in (dat, csv):
            out = tmp_path / f"{src.stem}.camcal"
            proc = run_cli("profile", "import-spectral", src, "--make", "X", "--camera-model", dat.stem, "--size",
                           "6000x4000", "-o", out, "--json")
            assert proc.returncode == 0, proc.stderr
            rec = json.loads(proc.stdout)
            assert rec["mode"] == "relative" and rec["source"]["sha256"] == sha256_file(src)
            p = load_profile(out)
            assert p.spectral.wavelength_nm.size == 176 and p.spectral.wavelength_nm[0] == 380.0
            assert any(i["sha256"] == sha256_file(src) for i in p.provenance.inputs)
            made[src.suffix] = p.spectral
        # the CSV was made from the .dat: the same curves up to one factor
        nz = made[".dat"].values["G1"] > 0
        ratio = made[".csv"].values["G1"][nz] / made[".dat"].values["G1"][nz]
        assert np.ptp(ratio) / ratio.mean() < 1e-3
        assert made[".dat"].origin()["format"] == "plain" and made[".csv"].origin()["format"] == "spectacle"


def test_plain_tables_and_bad_files(tmp_path):
    (tmp_path / "p.csv").write_text("wavelength_nm,R,G,B,R_unc,G_unc,B_unc\n400,0.1,0.2,0.9,0.01,0.01,0.02\n"
                                    "410,0.2,0.3,1.0,0.01,0.01,0.02\n")
    s = read_curve_table(tmp_path / "p.csv")
    assert s.values["B"].tolist() == [0.9, 1.0] and s.uncertainty["B"].tolist() == [0.02, 0.02]
    assert s.values["G2"].tolist() == s.values["G1"].tolist()
    (tmp_path / "r.dat").write_text("400.0 0.1 0.2 0.3\n402.0 0.2 0.3 0.4\n")
    assert read_spectral_file(tmp_path / "r.dat")[1] == "plain"
    for text, msg in (("wavelength_nm,R,Q,B\n400,1,2,3\n", "unknown column 'Q'"),
                      ("400,1,2,3,4\n410,1,2,3,4\n", "5 unnamed columns"),
                      ("400 1 2 3\n400 1 2 3\n", "twice"),
                      ("wavelength_nm,R,G,B\n400,1,nan,3\n", "NaN"),
                      ("# Wavelength, R, G, B\n400,1,2\n", "header names 4 columns")):
        (tmp_path / "bad.csv").write_text(text)
        with pytest.raises(CamcalError, match=msg):
            read_spectral_file(tmp_path / "bad.csv")
    assert_one_line_error(run_cli("profile", "import-spectral", tmp_path / "bad.csv", "--size", "64x64", "-o",
                                  tmp_path / "o.camcal"), "bad.csv", "header")
    assert_one_line_error(run_cli("profile", "import-spectral", tmp_path / "p.csv", "-o", tmp_path / "o.camcal"),
                          "identity")
    assert not (tmp_path / "o.camcal").exists()


# ---- reference targets on the synthetic camera ----------------------------------------------------------
@pytest.fixture(scope="module")
def targets(tmp_path_factory, camera):
    """Relative truth curves, the Sigma's curves, and target folders (written once)."""
    d = tmp_path_factory.mktemp("targets")
    c = camera.spectral_sensitivity()
    write_spectacle_csv(curves(c / c.max()), d / "truth_rel.csv")
    sig = camera_sensitivities("sigma-sd-merrill")
    write_spectacle_csv(curves(sig / sig.max()), d / "sigma_rel.csv")
    sp = smooth_target_spectra()
    write_target_photos(d / "one", camera, {"lamp_2856K": sp["lamp_2856K"]})
    write_target_photos(d / "three", camera, sp, stated_unc_rel=0.0, seed=7)
    irr = 2.0 * planck_radiance(5000.0) / planck_radiance(5000.0).max()  # W m^-2 nm^-1
    write_target_photos(d / "card", camera, {}, reflectance={"grey": (grey_card_reflectance(), irr)}, seed=9,
                        n_photos=2)
    return d, float(c.max())


def test_one_target_gives_k_and_band_radiance_of_the_sweep(targets, profile_path, camera, tmp_path):
    d, k_true = targets
    base = load_profile(profile_path)
    prof, scale = import_spectral(d / "truth_rel.csv", base=base, targets=d / "one")
    # k within 0.5 % of the truth (measured ≈ 0.1 %), its uncertainty from the stated 0.2 % and the noise
    for p in PLANES:
        assert scale.k[p] == pytest.approx(k_true, rel=0.005), p
        assert 0.002 <= scale.k_unc[p] / scale.k[p] < 0.003
    assert scale.consistent is None and "one target" in scale.verdict
    # resampled to the sweep profile's grid, absolute, provenance with the source file's hash
    np.testing.assert_array_equal(prof.spectral.wavelength_nm, base.spectral.wavelength_nm)
    assert prof.spectral.mode == "absolute"
    src = prof.spectral.origin()
    assert src["kind"] == "imported" and src["sha256"] == sha256_file(d / "truth_rel.csv")
    assert src["absolute_scale"]["method"] == "reference_targets"
    path = tmp_path / "imp.camcal"
    save_profile(prof, path)
    assert contract(load_profile(path))["spectral_sensitivity"]["source"]["absolute_scale"]["k"]["R"] == scale.k["R"]
    # band radiance of survey photos (two spectra unlike the target's) within 1 % of the sweep profile's
    rng = np.random.default_rng(11)
    for spec in (0.05 * planck_radiance(5500.0) / planck_radiance(5500.0).max(),
                 0.03 * np.exp(-(((WAVELENGTHS_NM - 600.0) / 60.0) ** 2)) + 0.005):
        t = exposure_for_level(camera, spec, 0.4, 100, 4.0)
        photo = camera.write_dng(tmp_path / "survey.dng", Scene.uniform(spec), exposure_s=t, iso=100,
                                 f_number=4.0, rng=rng)
        frame = load_frame(photo)
        a, b = apply(frame, load_profile(path), 663.0), apply(frame, base, 663.0)
        for ch in ("R", "G", "B"):
            assert np.nanmean(a.channels[ch]) == pytest.approx(np.nanmean(b.channels[ch]), rel=0.01), ch


def test_three_targets_residuals_at_noise_level(targets, profile_path):
    d, k_true = targets
    _, scale = import_spectral(d / "truth_rel.csv", base=load_profile(profile_path), targets=d / "three")
    assert scale.consistent is True and scale.dof == 8 and "agree" in scale.verdict
    z = np.array([[t["z"][p] for p in PLANES] for t in scale.targets])
    resid = np.array([[t["residual_rel"][p] for p in PLANES] for t in scale.targets])
    assert np.max(np.abs(z)) < 3.0                     # the photo noise alone (no stated target uncertainty)
    assert np.max(np.abs(resid)) < 0.002               # ≈ 0.05 % measured
    for p in PLANES:
        assert scale.k[p] == pytest.approx(k_true, rel=0.005)


def test_another_cameras_curves_leave_residuals_and_the_report_says_so(targets, profile_path, tmp_path):
    d, _ = targets
    out = tmp_path / "sigma.camcal"
    proc = run_cli("profile", "import-spectral", d / "sigma_rel.csv", "--into", profile_path, "--targets",
                   d / "three", "-o", out, "--json")
    assert proc.returncode == 0, proc.stderr
    a = json.loads(proc.stdout)["source"]["absolute_scale"]
    assert a["consistent"] is False and a["p_value"] < 1e-6
    assert max(abs(v) for t in a["targets"] for v in t["residual_rel"].values()) > 0.05
    show = run_cli("profile", "show", out)
    assert show.returncode == 0 and "do not belong to this camera" in " ".join(show.stdout.split())
    proc = run_cli("report", out, "-o", tmp_path / "r.html")
    assert proc.returncode == 0, proc.stderr
    html = (tmp_path / "r.html").read_text()
    assert 'id="spectral-source"' in html and "do not belong to this camera" in html and "sigma_rel.csv" in html


def test_reflectance_standard_under_measured_irradiance(targets, profile_path):
    d, k_true = targets
    _, scale = import_spectral(d / "truth_rel.csv", base=load_profile(profile_path), targets=d / "card")
    assert "ρE/π" in scale.targets[0]["description"]
    assert len(scale.targets) == 1 and len(scale.targets[0]["photos"]) == 2  # two photos, one target
    for p in PLANES:
        assert scale.k[p] == pytest.approx(k_true, rel=0.005)


def test_imported_profile_runs_through_apply_and_water_invert(targets, profile_path, camera, tmp_path):
    d, _ = targets
    out = tmp_path / "imp.camcal"
    proc = run_cli("profile", "import-spectral", d / "truth_rel.csv", "--into", profile_path, "--targets",
                   d / "one", "-o", out)
    assert proc.returncode == 0, proc.stderr
    assert "c(λ) from: imported from truth_rel.csv" in proc.stdout
    spec = 0.05 * planck_radiance(5500.0) / planck_radiance(5500.0).max()
    t = exposure_for_level(camera, spec, 0.4, 100, 4.0)
    camera.write_dng(tmp_path / "in" / "s.dng", Scene.uniform(spec), exposure_s=t, rng=np.random.default_rng(1))
    res = {}
    for name, prof in (("imp", out), ("sweep", profile_path)):
        proc = run_cli("apply", prof, tmp_path / "in", "-o", tmp_path / name, "--estimator", "smooth", "-j", "1")
        assert proc.returncode == 0, proc.stderr
        ch, _ = read_exr(tmp_path / name / "s.dng.exr", ["L663"])
        res[name] = float(np.nanmean(ch["L663"]))
        proc = run_cli("water", "invert", "--json", "--ratio", "0.3", "--depth", "0.8m", "--water-model", "refined",
                       "--profile", prof)
        assert proc.returncode == 0, proc.stderr
        res[name + "_chl"] = json.loads(proc.stdout)["c_ug_per_L"][0]
    assert res["imp"] == pytest.approx(res["sweep"], rel=0.01)
    assert res["imp_chl"] == pytest.approx(res["sweep_chl"], rel=0.01)


def test_region_rate_is_applys_correction(profile_path, camera, tmp_path):
    """The target's DN rate is what apply computes on the same pixels (apply's R, G, B times ∫c dλ)."""
    prof = load_profile(profile_path)
    spec = 0.05 * planck_radiance(4000.0) / planck_radiance(4000.0).max()
    t = exposure_for_level(camera, spec, 0.4, 200, 5.6)
    frame = load_frame(camera.write_dng(tmp_path / "p.dng", Scene.uniform(spec), exposure_s=t, iso=200, f_number=5.6,
                                        rng=np.random.default_rng(4)))
    box = (60, 40, 120, 90)
    rr = region_rate(frame, box, dark=prof.dark, flat=prof.flat, reference_iso=prof.reference_iso,
                     reference_f_number=prof.reference_f_number)
    assert rr.relative_exposure_s == pytest.approx(t * 2 * 16 / 5.6**2)
    plan = prepare(prof, 663.0)
    img = apply(frame, prof, 663.0)
    rate = {"R": rr.rate_dn_per_s[0], "G": 0.5 * (rr.rate_dn_per_s[1] + rr.rate_dn_per_s[2]), "B": rr.rate_dn_per_s[3]}
    for i, ch in enumerate("RGB"):
        via_apply = np.nanmean(img.channels[ch][40:90, 60:120]) * plan.model.band_integral[i]
        assert rate[ch] == pytest.approx(via_apply, rel=1e-3), ch  # (region_rate also drops > 5σ outliers)
    # and it is ∫ c L dλ with the camera's true c on axis, to the noise and the models' accuracy
    truth = np.trapezoid(camera.spectral_sensitivity() * spec, WAVELENGTHS_NM, axis=1)
    assert rr.rate_dn_per_s[0] == pytest.approx(truth[0], rel=0.005)
    with pytest.raises(CamcalError, match="outside"):
        region_rate(frame, (0, 0, 500, 10), reference_iso=100, reference_f_number=4)


def test_profile_export_is_spectacles_file_and_imports_back_absolute(profile_path, tmp_path):
    base = load_profile(profile_path)
    proc = run_cli("profile", "export-spectral", profile_path, "-o", tmp_path / "c.csv")
    assert proc.returncode == 0, proc.stderr
    data = spectacle_read(tmp_path / "c.csv")
    np.testing.assert_array_equal(data[0], base.spectral.wavelength_nm)
    for row, p in zip(data[1:5], ("R", "G1", "B", "G2"), strict=True):
        np.testing.assert_array_equal(row, base.spectral.values[p])
    (tmp_path / "c.meta.json").unlink()  # as from another tool: the values alone, declared absolute
    out = tmp_path / "back.camcal"
    proc = run_cli("profile", "import-spectral", tmp_path / "c.csv", "--into", profile_path, "--absolute", "-o", out)
    assert proc.returncode == 0, proc.stderr
    back = load_profile(out).spectral
    assert back.mode == "absolute" and back.origin()["absolute_scale"]["method"] == "file"
    for p in PLANES:
        np.testing.assert_array_equal(back.values[p], base.spectral.values[p])
    assert_one_line_error(run_cli("profile", "import-spectral", tmp_path / "c.csv", "--into", profile_path,
                                  "--absolute", "--targets", tmp_path, "-o", tmp_path / "x.camcal"), "exclude")


def test_target_errors(targets, tmp_path, profile_path):
    d, _ = targets
    narrow = tmp_path / "narrow.csv"
    narrow.write_text("wavelength_nm,L\n500,0.05\n600,0.05\n")
    with pytest.raises(CamcalError, match="uncovered"):
        predicted_rate(read_spectacle_csv(d / "truth_rel.csv"), radiance_target("n", narrow))
    (tmp_path / "t").mkdir()
    (tmp_path / "t" / "targets.csv").write_text("file,radiance\n../x.dng,a.csv\n")
    assert_one_line_error(run_cli("profile", "import-spectral", d / "truth_rel.csv", "--into", profile_path,
                                  "--targets", tmp_path / "t", "-o", tmp_path / "o.camcal"), "leaves")
    (tmp_path / "t" / "targets.csv").write_text("file\nx.dng\n")
    (tmp_path / "t" / "x.dng").write_bytes(b"")
    assert_one_line_error(run_cli("profile", "import-spectral", d / "truth_rel.csv", "--into", profile_path,
                                  "--targets", tmp_path / "t", "-o", tmp_path / "o.camcal"), "radiance file")
    assert not (tmp_path / "o.camcal").exists()


def test_a_relative_import_has_no_reference_setting_and_an_absolute_one_asks_for_it(tmp_path):
    """Issue 30: a value the user did not give is never a default. Relative curves need no exposure setting: the
    profile keeps none (not ISO 100, f/4). Curves declared absolute do: without one, one line names the options;
    given, it is kept."""
    (tmp_path / "p.csv").write_text("wavelength_nm,R,G,B\n400,0.1,0.2,0.9\n410,0.2,0.3,1.0\n")
    rel = tmp_path / "rel.camcal"
    proc = run_cli("profile", "import-spectral", tmp_path / "p.csv", "--make", "X", "--camera-model", "Y",
                   "--size", "64x64", "-o", rel)
    assert proc.returncode == 0, proc.stderr
    p = load_profile(rel)
    assert p.spectral.mode == "relative" and p.spectral.reference_iso is None and p.reference_iso is None
    assert p.spectral.reference_f_number is None and p.reference_f_number is None
    args = ("profile", "import-spectral", tmp_path / "p.csv", "--absolute", "--make", "X", "--camera-model", "Y",
            "--size", "64x64", "-o", tmp_path / "abs.camcal")
    assert_one_line_error(run_cli(*args), "--reference-iso and --reference-f-number")
    assert not (tmp_path / "abs.camcal").exists()
    proc = run_cli(*args, "--reference-iso", "200", "--reference-f-number", "2.8")
    assert proc.returncode == 0, proc.stderr
    a = load_profile(tmp_path / "abs.camcal")
    assert (a.spectral.reference_iso, a.spectral.reference_f_number, a.reference_iso) == (200.0, 2.8, 200.0)

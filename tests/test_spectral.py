"""Spectral sensitivity c(λ) from a monochromator sweep (issue 6, seed §3.1), against the synthetic truth.

Noise budget behind the tolerances: the default session puts the brightest channel at 35 % of
full scale (≈ 5 500 DN, ≈ 8 900 e-) per setting, 3 frames, and the 20 % central ROI of a
192x128 plane holds ≈ 1 000 pixels, so photon noise on c(λ) is ≈ 0.02 % of the peak. The
remaining systematic errors are the slit bias of the 5 nm line ((σ²/2)c'' ≈ 0.2 % of the peak
at most for the Nikon curves), the vignetting over the ROI when no flat model is used
(≤ 0.7 %), and for the Sigma curves the 680 nm cut-off that the slit smears (≈ 0.7 % RMS).
The targets of the issue (1 % relative, 3 % absolute RMS of the peak) hold with margin; a
wrong exposure normalisation, a missing black level or a swapped plane breaks them by far.
"""

from __future__ import annotations

import csv
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from camcal.calibrate.dark import fit_dark
from camcal.calibrate.dark_frames import measure_dark
from camcal.calibrate.sweep import LeftOutWarning, SweepOptions, SweepWarning, deconvolve_slit, fit_sweep, measure_sweep
from camcal.curves.files import SPECTACLE_HEADER, read_spectacle_csv, write_spectacle_csv
from camcal.errors import CamcalError, TooFewFrames
from camcal.frame import PLANES
from camcal.models.spectra import WAVELENGTHS_NM, gaussian_line
from camcal.models.spectral import SpectralSensitivity
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, write_session
from camcal.units import SPECTRAL_SENSITIVITY
from tests.conftest import assert_one_line_error, run_cli
from tests.oracles import flat_of_folder, merge_sweeps, to_colour, to_colour_planes

PLANE_TO_RGB = {"R": 0, "G1": 1, "G2": 1, "B": 2}


def truth_at(camera: SyntheticCamera, wl: np.ndarray) -> np.ndarray:
    """True c(λ) (3, n) at the sweep wavelengths, absolute units at the reference setting."""
    c = camera.spectral_sensitivity()
    return np.stack([np.interp(wl, WAVELENGTHS_NM, c[i]) for i in range(3)])


def rms_of_peak(s: SpectralSensitivity, truth: np.ndarray) -> dict[str, float]:
    return {p: float(np.sqrt(np.mean((s.values[p] - truth[i]) ** 2)) / truth[i].max())
            for p, i in PLANE_TO_RGB.items()}


def assert_peaks_within_sampling(s: SpectralSensitivity, camera: SyntheticCamera) -> None:
    """Measured peak is a sample adjacent to the true (1 nm) peak: exact to the 5 nm sampling."""
    c = camera.spectral_sensitivity()
    step = float(np.median(np.diff(s.wavelength_nm)))
    for p, i in PLANE_TO_RGB.items():
        true_peak = WAVELENGTHS_NM[int(np.argmax(c[i]))]
        measured = s.wavelength_nm[int(np.argmax(s.values[p]))]
        assert abs(measured - true_peak) < step, (p, measured, true_peak)


def quiet_measure(folder, dark=None, flat=None, **options) -> SpectralSensitivity:
    """The sweep stage's two calls with its warnings silenced; ``options``: :class:`SweepOptions` fields."""
    opts = SweepOptions(**options)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SweepWarning)
        return fit_sweep(measure_sweep(folder, None, opts, dark=dark, flat=flat), opts)


@pytest.fixture(scope="module")
def dark_model(session_dir):
    return fit_dark(measure_dark(session_dir / "dark", session_dir / "bias"))


@pytest.fixture(scope="module")
def flat_model(session_dir, dark_model):
    return flat_of_folder(session_dir / "flat", dark_model)


@pytest.fixture(scope="module")
def sigma_session(tmp_path_factory):
    cam = SyntheticCamera(SensorParams(width=192, height=128, sensitivity="sigma-sd-merrill", seed=3))
    out = write_session(tmp_path_factory.mktemp("sigma") / "S", cam, SessionPlan(stages=("sweep",)))
    return out, cam


# ---- accuracy against the truth ---------------------------------------------------------------
def test_nikon_relative_within_1_percent(session_dir, camera):
    s = quiet_measure(session_dir / "sweep", mode="relative")
    assert s.mode == "relative" and s.units == "relative"
    assert s.wavelength_nm[0] == 400 and s.wavelength_nm[-1] == 700 and s.wavelength_nm.size == 61
    truth = truth_at(camera, s.wavelength_nm)
    truth /= truth.max()
    errs = rms_of_peak(s, truth)
    assert max(errs.values()) < 0.01, errs
    assert_peaks_within_sampling(s, camera)
    # uncertainty: the reference detector's 0.5 % dominates at the peak; photon noise adds ≈ 0.02 %
    for p in PLANES:
        k = int(np.argmax(s.values[p]))
        assert 0.005 <= s.uncertainty[p][k] / s.values[p][k] < 0.0056, p


def test_nikon_absolute_with_dark_and_flat_within_3_percent(session_dir, camera, dark_model, flat_model):
    s = quiet_measure(session_dir / "sweep", mode="absolute", dark=dark_model, flat=flat_model)
    assert not s.notes
    assert s.mode == "absolute" and s.units == SPECTRAL_SENSITIVITY
    assert (s.reference_iso, s.reference_f_number) == (100.0, 4.0)
    errs = rms_of_peak(s, truth_at(camera, s.wavelength_nm))
    # with the flat the ROI is brought on axis: only slit bias and noise remain (≈ 0.2 %)
    assert max(errs.values()) < 0.03, errs
    assert max(errs.values()) < 0.006, errs
    assert_peaks_within_sampling(s, camera)


def test_absolute_without_flat_warns(session_dir, camera):
    with pytest.warns(SweepWarning, match="no flat model"):
        opts = SweepOptions(mode="absolute", roi=0.1)
        s = fit_sweep(measure_sweep(session_dir / "sweep", None, opts), opts)
    errs = rms_of_peak(s, truth_at(camera, s.wavelength_nm))
    assert max(errs.values()) < 0.03, errs


def test_sigma_merrill_relative_and_absolute(sigma_session):
    out, cam = sigma_session
    s = quiet_measure(out / "sweep", mode="relative")
    truth = truth_at(cam, s.wavelength_nm)
    errs_rel = rms_of_peak(s, truth / truth.max())
    assert max(errs_rel.values()) < 0.01, errs_rel
    assert_peaks_within_sampling(s, cam)
    # the curves stop at 680 nm: nothing measured beyond (noise only)
    beyond = s.wavelength_nm > 682
    assert all(np.all(np.abs(s.values[p][beyond]) < 2e-3) for p in PLANES)
    a = quiet_measure(out / "sweep", mode="absolute")
    errs_abs = rms_of_peak(a, truth)
    assert max(errs_abs.values()) < 0.03, errs_abs


def test_exposure_normalisation_matters(session_dir, camera, tmp_path):
    """Claiming twice the exposure time in sweep.csv halves c(λ): the manifest's exposure is used."""
    src = session_dir / "sweep"
    dst = tmp_path / "sweep"
    dst.mkdir()
    with open(src / "sweep.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    keep = [r for r in rows if float(r["wavelength_nm"]) in (500.0, 550.0, 600.0, 650.0)]
    for r in keep:
        shutil.copy(src / r["file"], dst / r["file"])
        r["exposure_s"] = str(2 * float(r["exposure_s"]))
    with open(dst / "sweep.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(keep)
    s = quiet_measure(dst, mode="absolute")
    ratio = s.values["G1"] / truth_at(camera, s.wavelength_nm)[1]
    np.testing.assert_allclose(ratio, 0.5, rtol=0.01)


# ---- finite bandwidth -----------------------------------------------------------------------
@pytest.mark.parametrize("sensitivity", ["nikon-d5100", "sigma-sd-merrill"])
def test_deconvolution_removes_slit_bias(sensitivity):
    """A 12 nm line sampled every 5 nm, 0.03 % noise: deconvolution at least halves the error (arrays only).

    Noise-free it removes the bias entirely (< 0.01 % of the peak); with noise the regularisation
    (chosen by GCV) trades the remaining bias against amplified noise.
    """
    cam = SyntheticCamera(SensorParams(sensitivity=sensitivity))
    c = cam.spectral_sensitivity()
    wl = np.arange(400.0, 701.0, 5.0)
    fwhm = 12.0
    rng = np.random.default_rng(5)
    for i in range(3):
        if sensitivity == "sigma-sd-merrill" and i != 1:
            continue  # the 680 nm cut-off is not smooth: test the smooth green curve only
        measured = np.array([np.trapezoid(c[i] * gaussian_line(x, fwhm), WAVELENGTHS_NM) for x in wl])
        u = 3e-4 * measured.max() * np.ones_like(measured)
        noisy = measured + u * rng.standard_normal(wl.size)
        truth = np.interp(wl, WAVELENGTHS_NM, c[i])
        est, u_est = deconvolve_slit(wl, noisy, u, fwhm)
        err_raw = np.sqrt(np.mean((noisy - truth) ** 2))
        err_dec = np.sqrt(np.mean((est - truth) ** 2))
        assert err_dec < err_raw / 2, (i, err_raw / truth.max(), err_dec / truth.max())
        assert np.all(u_est > 0)


def test_measure_with_deconvolution(session_dir, camera):
    s = quiet_measure(session_dir / "sweep", mode="relative", deconvolve=True)
    assert s.deconvolved and s.bandwidth_nm == 5.0
    truth = truth_at(camera, s.wavelength_nm)
    plain = quiet_measure(session_dir / "sweep", mode="relative")
    errs_dec = rms_of_peak(s, truth / truth.max())
    errs_plain = rms_of_peak(plain, truth / truth.max())
    assert max(errs_dec.values()) < 0.01
    assert sum(errs_dec.values()) < sum(errs_plain.values())
    # without deconvolution the summary states the slit bias that remains
    bias = plain.summary()["slit_bias_rms_of_peak"]
    assert 0 < max(bias.values()) < 0.01


# ---- merging, export, derived figures --------------------------------------------------------
def _analytic(wl: np.ndarray, centres=(600.0, 540.0, 540.0, 460.0), sigma=20.0, scale=1.0) -> SpectralSensitivity:
    vals = {p: scale * np.exp(-0.5 * ((wl - c) / sigma) ** 2) for p, c in zip(PLANES, centres, strict=True)}
    unc = {p: 0.002 * scale * np.ones_like(wl) for p in PLANES}
    return SpectralSensitivity(wl, vals, unc, "relative", "relative", bandwidth_nm=5.0)


def test_effective_wavelength_and_bandwidth():
    s = _analytic(np.arange(300.0, 801.0, 1.0))
    eff = s.effective_wavelength_nm()
    bw = s.effective_bandwidth_nm()
    assert eff["R"] == pytest.approx(600.0, abs=1e-6) and eff["B"] == pytest.approx(460.0, abs=1e-6)
    # equivalent width of a Gaussian: σ √(2π)
    assert bw["G"] == pytest.approx(20.0 * np.sqrt(2 * np.pi), rel=1e-4)
    assert s.peak_wavelength_nm()["G1"] == 540.0


def test_merge_sweeps_scales_and_weights():
    rng = np.random.default_rng(2)
    lo = _analytic(np.arange(400.0, 581.0, 5.0))
    hi_true = _analytic(np.arange(550.0, 701.0, 5.0), scale=1.25)  # other grating, other reference scale
    hi = SpectralSensitivity(hi_true.wavelength_nm,
                             {p: v + 0.002 * 1.25 * rng.standard_normal(v.size) for p, v in hi_true.values.items()},
                             hi_true.uncertainty, "relative", "relative", bandwidth_nm=5.0)
    m = merge_sweeps(lo, hi)
    assert m.wavelength_nm[0] == 400 and m.wavelength_nm[-1] == 700
    ref = _analytic(m.wavelength_nm)
    for p in PLANES:
        np.testing.assert_allclose(m.values[p], ref.values[p], atol=0.01)
    overlap = (m.wavelength_nm >= 550) & (m.wavelength_nm <= 580)
    # SNR weighting: two measurements give a smaller uncertainty than either alone
    assert np.all(m.uncertainty["G1"][overlap] < lo.uncertainty["G1"][0])
    with pytest.raises(CamcalError, match="overlap"):
        merge_sweeps(_analytic(np.arange(400.0, 501.0, 5.0)), _analytic(np.arange(600.0, 701.0, 5.0)))


def test_spectacle_csv_round_trip_and_colour(tmp_path):
    s = _analytic(np.arange(400.0, 701.0, 5.0), centres=(600.0, 540.0, 545.0, 460.0))
    path = write_spectacle_csv(s, tmp_path / "sens.csv")
    header = path.read_text().splitlines()[0]
    assert header == "# " + SPECTACLE_HEADER == "# Wavelength, R, G, B, G2, R_err, G_err, B_err, G2_err"
    back = read_spectacle_csv(path)
    for p in PLANES:
        np.testing.assert_allclose(back.values[p], s.values[p], rtol=1e-8)
        np.testing.assert_allclose(back.uncertainty[p], s.uncertainty[p], rtol=1e-8)
    assert back.mode == "relative" and back.bandwidth_nm == 5.0
    rgb = to_colour(s)
    assert rgb.__class__.__name__ == "RGB_CameraSensitivities"
    np.testing.assert_allclose(rgb.values[:, 1], 0.5 * (s.values["G1"] + s.values["G2"]))
    planes = to_colour_planes(s)
    assert list(planes.labels) == ["R", "G1", "G2", "B"]
    np.testing.assert_allclose(planes.values[:, 2], s.values["G2"])
    (tmp_path / "bad.csv").write_text("Wavelength,R,G\n400,1,2\n")
    with pytest.raises(CamcalError, match="missing column 'B'"):
        read_spectacle_csv(tmp_path / "bad.csv")
    (tmp_path / "bad.csv").write_text("Wavelength,R,G,B\n400,1,x,3\n")
    with pytest.raises(CamcalError, match="non-numeric"):
        read_spectacle_csv(tmp_path / "bad.csv")


# ---- bad input --------------------------------------------------------------------------------
def _mini_sweep(folder: Path, *, saturate: tuple[str, ...] = (), wavelengths=(500.0, 550.0, 600.0), n=2) -> Path:
    """A tiny real sweep (128x128 DNG); files named in ``saturate`` get a 50x longer exposure."""
    cam = SyntheticCamera(SensorParams(width=128, height=128))
    folder.mkdir(parents=True)
    rows = []
    rng = np.random.default_rng(9)
    for wl in wavelengths:
        spectrum = 0.02 * gaussian_line(wl, 5.0)
        t = 0.35 * 15871 / (cam.channel_rates_e(spectrum, 4.0).max() * cam.dn_per_electron(100))
        for j in range(n):
            name = f"s_{wl:.0f}_{j}.dng"
            cam.write_dng(folder / name, Scene.uniform(spectrum), rng=rng, iso=100, f_number=4.0,
                          exposure_s=t * (50 if name in saturate else 1))
            rows.append(f"{name},{wl},0.02,0.0001,5,{t:.6g},100,4")
    (folder / "sweep.csv").write_text(
        "file,wavelength_nm,radiance_W_m2_sr,radiance_unc_W_m2_sr,bandwidth_nm,exposure_s,iso,f_number\n"
        + "\n".join(rows) + "\n")
    return folder


def _edit_csv(folder: Path, old: str, new: str) -> None:
    p = folder / "sweep.csv"
    p.write_text(p.read_text().replace(old, new, 1))


def test_missing_frame_is_a_clear_error(tmp_path):
    d = _mini_sweep(tmp_path / "sw")
    (d / "s_550_1.dng").unlink()
    with pytest.raises(CamcalError, match=r"lists 's_550_1.dng' at 550 nm, which is not in the folder"):
        fit_sweep(measure_sweep(d))
    proc = run_cli("sweep", d, "-o", tmp_path / "o.csv")
    assert_one_line_error(proc, "sweep.csv", "s_550_1.dng", "not in the folder")


def test_path_outside_and_negative_radiance(tmp_path):
    d = _mini_sweep(tmp_path / "sw")
    shutil.copy(d / "s_500_0.dng", tmp_path / "outside.dng")
    _edit_csv(d, "s_500_0.dng", "../outside.dng")
    assert_one_line_error(run_cli("sweep", d, "-o", tmp_path / "o.csv"), "leaves the session folder")
    d2 = _mini_sweep(tmp_path / "sw2")
    _edit_csv(d2, ",0.02,", ",-0.02,")
    assert_one_line_error(run_cli("sweep", d2, "-o", tmp_path / "o.csv"), "radiance_W_m2_sr", "negative")
    d3 = _mini_sweep(tmp_path / "sw3")
    _edit_csv(d3, ",0.02,", ",0,")
    with pytest.raises(CamcalError, match="must be positive"):
        fit_sweep(measure_sweep(d3, None, SweepOptions(mode="relative")), SweepOptions(mode="relative"))


def test_saturated_frames_left_out_and_wavelengths_dropped(tmp_path):
    d = _mini_sweep(tmp_path / "sw", saturate=("s_550_0.dng",))
    with pytest.warns(LeftOutWarning, match=r"left out: s_550_0.dng: saturated: .* at the white level at 550 nm"):
        s = fit_sweep(measure_sweep(d, None, SweepOptions(mode="relative")), SweepOptions(mode="relative"))
    assert s.n_frames == {"500": 2, "550": 1, "600": 2}
    d2 = _mini_sweep(tmp_path / "sw2", saturate=("s_600_0.dng", "s_600_1.dng"))
    s2 = quiet_measure(d2, mode="relative")  # no usable frame at 600 nm: the wavelength is dropped, and said
    assert s2.n_frames == {"500": 2, "550": 2}
    assert any("600 nm (0 of 2 frames usable, 1 needed)" in n for n in s2.notes)
    s3 = quiet_measure(d, mode="relative", min_frames=2)
    assert s3.n_frames == {"500": 2, "600": 2}
    only = _mini_sweep(tmp_path / "sw3", saturate=("s_550_0.dng", "s_550_1.dng"), wavelengths=(550.0,))
    with pytest.raises(TooFewFrames, match="needs at least 1 usable wavelengths, 0 remain"):
        quiet_measure(only, mode="relative")


def test_bad_roi_and_mode(tmp_path):
    d = _mini_sweep(tmp_path / "sw", wavelengths=(550.0,), n=1)
    with pytest.raises(CamcalError, match="ROI"):
        quiet_measure(d, roi=(0, 0, 100, 10))
    with pytest.raises(CamcalError, match="mode"):
        fit_sweep(measure_sweep(d, None, SweepOptions(mode="absolut")), SweepOptions(mode="absolut"))  # type: ignore[arg-type]
    with pytest.raises(CamcalError, match="bandwidth_nm"):
        _edit_csv(d, ",5,", ",,")
        quiet_measure(d, deconvolve=True)


# ---- CLI --------------------------------------------------------------------------------------
def test_cli_sweep_writes_csv_meta_and_png(session_dir, camera, tmp_path):
    out = tmp_path / "res" / "sensitivity.csv"
    proc = run_cli("sweep", session_dir / "sweep", "-o", out, "--sweep-mode", "relative", "--json")
    assert proc.returncode == 0, proc.stderr
    assert out.is_file() and out.with_suffix(".png").stat().st_size > 1000
    assert (out.parent / "sensitivity.meta.json").is_file()
    s = read_spectacle_csv(out)
    assert s.mode == "relative"
    truth = truth_at(camera, s.wavelength_nm)
    assert max(rms_of_peak(s, truth / truth.max()).values()) < 0.01
    assert '"peak_wavelength_nm"' in proc.stdout
    bad = run_cli("sweep", session_dir / "sweep", "-o", tmp_path / "x.txt")
    assert_one_line_error(bad, "x.txt", ".csv")


def test_monochrome_sweep_measures_one_plane_y(tmp_path):
    """A sweep of one-sample LinearRaw DNGs (one plane of the synthetic camera: a monochrome sensor) gives c(λ) of
    one plane ``Y``, the plane's true curve within 1 % of its peak (relative)."""
    import shutil

    from camcal.frame import split_planes
    from camcal.io.read import load_frame
    from camcal.synth.dng import encode_mono_dng

    cam = SyntheticCamera(SensorParams(width=96, height=64, seed=5))
    src = write_session(tmp_path / "S", cam, SessionPlan(stages=("sweep",)))
    mono = tmp_path / "M" / "sweep"
    mono.mkdir(parents=True)
    for f in (src / "sweep").iterdir():
        if f.suffix.lower() != ".dng":
            shutil.copyfile(f, mono / f.name)
            continue
        fr = load_frame(f)
        plane = split_planes(fr.data, fr.cfa_pattern)[1]  # G1
        e = fr.exposure
        (mono / f.name).write_bytes(encode_mono_dng(plane, black_level_dn=fr.black_vector().ravel()[1],
                                                    white_level_dn=fr.white_level_dn, exposure_s=e.exposure_s,
                                                    f_number=e.f_number, iso=int(e.iso)))
    s = quiet_measure(mono, mode="relative")
    assert s.plane_names == ("Y",) and s.mono
    truth = truth_at(cam, s.wavelength_nm)[1]
    truth /= truth.max()
    err = float(np.sqrt(np.mean((s.values["Y"] - truth) ** 2)))
    assert err < 0.01, err

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
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import norm

from camcal.calibrate.dark import fit_dark
from camcal.calibrate.dark_frames import measure_dark
from camcal.calibrate.sweep import (
    LeftOutWarning,
    SweepOptions,
    SweepWarning,
    deconvolve_slit,
    fit_sweep,
    measure_sweep,
    slit_matrix,
)
from camcal.curves.files import SPECTACLE_HEADER, read_spectacle_csv, write_spectacle_csv
from camcal.errors import CamcalError, TooFewFrames
from camcal.frame import PLANES
from camcal.models.spectra import WAVELENGTHS_NM, gaussian_line
from camcal.models.spectral import SpectralSensitivity
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, write_session
from camcal.units import SPECTRAL_SENSITIVITY
from tests.conftest import assert_one_line_error, run_cli
from tests.helpers import _gauss
from tests.oracles import (
    flat_of_folder,
    merge_sweeps,
    to_colour,
    to_colour_planes,
)

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


@pytest.mark.formula
def test_deconvolution_needs_four_wavelengths_and_defaults_to_a_gaussian_slit():
    """Four samples are enough (three are refused); the default slit is the Gaussian: a curve convolved with a
    5 nm-FWHM Gaussian by the forward operator is deconvolved back with the default."""
    wl = np.arange(500.0, 561.0, 5.0)
    truth = _gauss(wl, 530.0, 12.0) + 0.1
    measured = slit_matrix(wl, 5.0, "gaussian") @ truth
    c, u = deconvolve_slit(wl, measured, np.full(wl.size, 1e-6), 5.0, regularisation=1e-12)
    np.testing.assert_allclose(c[2:-2], truth[2:-2], rtol=1e-3)
    c4, _ = deconvolve_slit(wl[:4], measured[:4], np.full(4, 1e-3), 5.0)
    assert np.all(np.isfinite(c4))
    with pytest.raises(CamcalError, match="at least 4 wavelengths"):
        deconvolve_slit(wl[:3], measured[:3], np.full(3, 1e-3), 5.0)


def _tikhonov_by_definition(wl, a, m, u, alpha_rel):
    """min ||W^½(Ac − m)||² + α||D₂c||², W = diag(1/u²), D₂ the second derivative per nm² of the parabola
    through each three neighbouring samples (from its Vandermonde system, not a difference formula), α =
    alpha_rel · tr(AᵀWA)/tr(D₂ᵀD₂); returns c, the estimator R and the GCV score n‖W^½(Ac − m)‖²/(n − tr AR)²
    (Hansen 2010, §5.4)."""
    n = wl.size
    d2 = np.zeros((n - 2, n))
    for i in range(n - 2):
        d2[i, i:i + 3] = 2.0 * np.linalg.solve(np.vander(wl[i:i + 3], 3), np.eye(3))[0]
    w = np.diag(1.0 / u**2)
    ata, dtd = a.T @ w @ a, d2.T @ d2
    alpha = alpha_rel * np.trace(ata) / np.trace(dtd)
    r = np.linalg.inv(ata + alpha * dtd) @ a.T @ w
    c = r @ m
    res = np.sqrt(np.diag(w)) * (a @ c - m)
    return c, r, n * float(res @ res) / (n - np.trace(a @ r)) ** 2


@pytest.mark.formula
def test_deconvolution_on_an_uneven_grid_is_the_tikhonov_estimator_with_gcv():
    """On an uneven grid (4 nm steps jittered by up to ±1.2 nm) with unequal σ and Gaussian noise of that σ on a
    slit-blurred curve: with a given regularisation the result is the Tikhonov estimator written out here (second
    derivative per nm² from the parabola through each three samples); without one, the estimator whose α
    minimises the GCV score over the 49 values 10⁻¹⁰…10² (relative to the trace ratio); the uncertainty is
    √diag(R diag(u²) Rᵀ). The noise makes GCV choose an interior α (≈ 10^0.5) where a neighbouring grid value
    moves c by ~1e-3, so the grid itself is checked."""
    base = np.arange(400.0, 481.0, 4.0)
    wl = base + np.random.default_rng(5).uniform(-1.2, 1.2, base.size)
    a = slit_matrix(wl, 8.0)
    truth = np.exp(-0.5 * ((wl - 440.0) / 25.0) ** 2)
    u = 0.01 * (1.0 + 0.5 * np.cos(wl / 7.0))
    m = a @ truth + u * np.random.default_rng(1).standard_normal(wl.size)
    # the estimator is written out with explicit inverses here, np.linalg.solve in the code: they agree to ~1e-8
    c, uc = deconvolve_slit(wl, m, u, 8.0, regularisation=1e-3)
    want, r, _ = _tikhonov_by_definition(wl, a, m, u, 1e-3)
    np.testing.assert_allclose(c, want, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(uc, np.sqrt(np.diag(r @ np.diag(u**2) @ r.T)), rtol=1e-6)
    scores = [(_tikhonov_by_definition(wl, a, m, u, 10.0**lg)[2], lg) for lg in np.linspace(-10, 2, 49)]
    best = min(scores)[1]
    assert -10 < best < 2  # an interior minimum: the grid's ends are not what decides
    c, uc = deconvolve_slit(wl, m, u, 8.0)
    want, r, _ = _tikhonov_by_definition(wl, a, m, u, 10.0**best)
    np.testing.assert_allclose(c, want, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(uc, np.sqrt(np.diag(r @ np.diag(u**2) @ r.T)), rtol=1e-6)


@pytest.mark.formula
def test_deconvolution_with_little_noise_lets_gcv_choose_a_weak_regularisation():
    """With noise of 1e-4 on a broad (σ = 25 nm) curve, GCV's minimum over 10⁻¹⁰…10² lies below 10⁻² (at
    10^-2.75): the search must reach down there, weaker than the trace ratio, not only up from it. The result is
    the estimator written out at that α, and closer to the truth than the one at 10⁻²."""
    base = np.arange(400.0, 481.0, 4.0)
    wl = base + np.random.default_rng(5).uniform(-1.2, 1.2, base.size)
    a = slit_matrix(wl, 8.0)
    truth = np.exp(-0.5 * ((wl - 440.0) / 25.0) ** 2)
    u = 1e-4 * (1.0 + 0.5 * np.cos(wl / 7.0))
    m = a @ truth + u * np.random.default_rng(1).standard_normal(wl.size)
    scores = [(_tikhonov_by_definition(wl, a, m, u, 10.0**lg)[2], lg) for lg in np.linspace(-10, 2, 49)]
    best = min(scores)[1]
    assert -10 < best < -2
    c, uc = deconvolve_slit(wl, m, u, 8.0)
    want, r, _ = _tikhonov_by_definition(wl, a, m, u, 10.0**best)
    np.testing.assert_allclose(c, want, rtol=1e-6, atol=1e-10)
    np.testing.assert_allclose(uc, np.sqrt(np.diag(r @ np.diag(u**2) @ r.T)), rtol=1e-6)
    stiff = _tikhonov_by_definition(wl, a, m, u, 1e-2)[0]
    assert np.abs(c - truth).max() < np.abs(stiff - truth).max()


@pytest.mark.formula
def test_slit_matrix_on_a_line_is_the_gaussian_mean_of_the_clamped_line():
    """c(λ) = a + bλ is its own natural cubic spline, held at the end values outside the sampled range, so the
    measured value at λ_j through a Gaussian slit (σ = FWHM/(2√(2 ln 2))) is a + b·E[clip(X, λ_0, λ_n)] with
    X ~ N(λ_j, σ): E[clip] = μ + E[(λ_0 − X)⁺] − E[(X − λ_n)⁺], E[(L − X)⁺] = (L − μ)Φ(z) + σφ(z), z = (L − μ)/σ
    (normal distribution from scipy.stats). A first step of 2.5 FWHM and a last one of 0.5 FWHM make the held
    ends matter over the whole slit."""
    wl = np.array([400.0, 425.0, 430.0, 436.0, 441.0, 447.0, 452.0, 457.0])
    fwhm = 10.0
    sigma = fwhm / (2 * np.sqrt(2 * np.log(2)))
    a, b = 0.3, 0.01
    got = slit_matrix(wl, fwhm) @ (a + b * wl)

    def below(limit, mu):  # E[(limit − X)⁺]
        z = (limit - mu) / sigma
        return (limit - mu) * norm.cdf(z) + sigma * norm.pdf(z)

    def above(limit, mu):  # E[(X − limit)⁺]
        z = (mu - limit) / sigma
        return (mu - limit) * norm.cdf(z) + sigma * norm.pdf(z)

    want = a + b * (wl + below(wl[0], wl) - above(wl[-1], wl))
    np.testing.assert_allclose(got, want, rtol=2e-6)  # quadrature on a 0.1 nm grid
    assert abs(got[0] - (a + b * wl[0])) > 0.01  # the held end is visible (b σ/√(2π) ≈ 0.017)


@pytest.mark.formula
def test_slit_matrix_is_the_slit_mean_of_the_natural_spline_on_a_grid_with_a_long_last_step():
    """The last step (40 nm) longer than the slit's reach (3 FWHM = 15 nm), so the last slit lies wholly beyond
    the one before: on a line, the closed form a + b·E[clip(X, λ_0, λ_n)] (as above); on a parabola, which a
    natural spline does not reproduce near the ends (c'' = 0 there), the Gaussian mean of the clamped natural
    spline through the node values by adaptive quadrature (scipy.integrate.quad). Tolerance: the operator's
    0.1 nm trapezoid rule over a spline with kinks at the clamps (measured 4e-6 on values up to 1, at the end
    nodes); a not-a-knot spline differs by 1e-4 to 4e-3 at four of the six nodes."""
    from scipy.integrate import quad
    from scipy.interpolate import CubicSpline

    wl = np.array([400.0, 404.0, 409.0, 415.0, 420.0, 460.0])
    fwhm = 5.0
    sigma = fwhm / (2 * np.sqrt(2 * np.log(2)))
    a = slit_matrix(wl, fwhm)

    def clamped_mean(f, mu):
        lo, hi = wl[0], wl[-1]
        inside = quad(lambda x: f(x) * norm.pdf(x, mu, sigma), lo, hi, points=list(wl[(wl > mu - 8 * sigma)
                                                                                    & (wl < mu + 8 * sigma)]),
                      epsabs=1e-13, limit=200)[0]
        return inside + f(lo) * norm.cdf(lo, mu, sigma) + f(hi) * norm.sf(hi, mu, sigma)

    line = lambda x: 0.3 + 0.01 * x  # noqa: E731
    np.testing.assert_allclose(a @ line(wl), [clamped_mean(line, m) for m in wl], rtol=1e-6)
    values = ((wl - 400.0) / 60.0) ** 2
    spline = CubicSpline(wl, values, bc_type="natural")
    expect = [clamped_mean(lambda x: float(spline(x)), m) for m in wl]
    np.testing.assert_allclose(a @ values, expect, rtol=0, atol=2e-5)


def _gauss_conv(lam, mu, s, fwhm, a=1.0):
    """A·exp(−(λ−μ)²/2s²) convolved with a unit-area Gaussian of FWHM ``fwhm``: variances add (closed form)."""
    v = s * s + (fwhm / (2 * np.sqrt(2 * np.log(2)))) ** 2
    return a * s / np.sqrt(v) * np.exp(-((np.asarray(lam, float) - mu) ** 2) / (2 * v))


@pytest.mark.formula
def test_slit_operator_is_the_convolution_with_a_unit_area_slit():
    """A·c on a 5 nm grid, for a Gaussian c (s = 20 nm) and a 10 nm Gaussian slit, against the closed-form
    convolution (rel 2e-4 of the peak: the natural spline between nodes); for a triangular slit of FWHM 10 nm,
    against the convolution (trapezoid rule, 5 pm steps) with the triangle 1 − |x|/10 normalised to unit area."""
    wl = np.arange(500.0, 701.0, 5.0)
    c = _gauss(wl, 600.0, 20.0)
    a = slit_matrix(wl, 10.0, "gaussian", step_nm=0.25)
    np.testing.assert_allclose(a @ c, _gauss_conv(wl, 600.0, 20.0, 10.0), atol=2e-4)
    at = slit_matrix(wl, 10.0, "triangular")
    tri = _tri_conv(wl, 600.0, 20.0, 10.0)
    np.testing.assert_allclose(at @ c, tri, atol=2e-4)
    assert abs(float((a @ c)[20]) - 1.0) > 0.02  # the slit lowers the peak by 2.2 %: the test can see a slit


def _tri_conv(lam, mu, s, fwhm):
    """A unit Gaussian (μ, s) convolved with the unit-area triangle 1 − |x|/FWHM (trapezoid rule, fine steps)."""
    x = np.linspace(-fwhm, fwhm, 4001)
    return np.array([np.trapezoid(_gauss(v - x, mu, s) * (1 - np.abs(x) / fwhm) / fwhm, x) for v in lam])


@pytest.mark.formula
def test_deconvolution_recovers_the_curve_and_propagates_its_uncertainty_linearly():
    """c ⊛ slit (a 25 nm triangular slit on a 20 nm grid) deconvolved with a fixed small regularisation gives
    back c within 1e-3 of its peak (the convolved curve is up to 1 % off). The estimator is linear, so its
    uncertainty is √Σ_k R_jk² u_k² with R's columns found here by deconvolving unit vectors."""
    wl = np.arange(440.0, 761.0, 20.0)
    truth = _gauss(wl, 600.0, 40.0)
    measured = _tri_conv(wl, 600.0, 40.0, 25.0)
    u = np.full(wl.size, 1e-3)
    u[5] = 4e-3
    c, uc = deconvolve_slit(wl, measured, u, 25.0, slit="triangular", regularisation=1e-6)
    np.testing.assert_allclose(c, truth, atol=1e-3)
    assert np.max(np.abs(measured - truth)) > 0.008
    cols = np.stack([deconvolve_slit(wl, np.eye(wl.size)[k], u, 25.0, slit="triangular", regularisation=1e-6)[0]
                     for k in range(wl.size)], axis=1)
    np.testing.assert_allclose(cols @ measured, c, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(uc, np.sqrt((cols**2) @ u**2), rtol=1e-6)


@pytest.mark.formula
def test_robust_mask_median_and_normal_scaled_mad_by_hand():
    """_robust_mask keeps valid pixels within nsigma·MAD/Φ⁻¹(0.75) of the median of the valid pixels (a pixel at
    exactly 5σ is kept), sampling every other row and column only above 40 000 pixels; no valid pixel -> none
    kept; a zero MAD keeps every valid pixel."""
    from scipy.stats import norm

    from camcal.calibrate.sweep import _robust_mask

    base = np.array([[-3, -2, -1, 0, 1, 2, 3], [0, 1, -1, 2, -2, 0, 0], [1, 0, 0, -1, 0, 2, -2],
                     [0, 0, 1, -1, 0, 0, 1], [-1, 0, 2, 0, 1, -1, 0], [0, 3, 0, -3, 0, 1, 0],
                     [50.0, -60.0, 70.0, -80.0, 0, 0, 0]])
    valid = np.ones(base.shape, bool)
    valid[0, 0] = valid[3, 3] = False
    sample = base[valid]
    med = float(np.median(sample))
    mad = float(np.median(np.abs(sample - med))) / norm.ppf(0.75)  # the normal-scaled MAD
    assert med == 0.0 and mad > 0
    m = base.copy()
    m[6, 0] = 5.0 * mad  # an outlier moved to exactly 5σ: kept (median and MAD unchanged: still above both)
    m[6, 1] = -5.0 * mad * (1 + 1e-9)  # just beyond -5σ: left out
    m[3, 3] = 0.0  # invalid pixel at the median: stays out
    expect = valid & (np.abs(m - med) <= 5.0 * mad)
    out = _robust_mask(m, valid)
    np.testing.assert_array_equal(out, expect)
    assert out[6, 0] and not out[6, 1] and not out[6, 2] and not out[3, 3] and out.sum() == 47 - 3
    # nsigma: at 1σ the ±2 and ±3 pixels go too (1.4826 < 2)
    np.testing.assert_array_equal(_robust_mask(m, valid, nsigma=1.0), valid & (np.abs(m - med) <= mad))
    # no mask: every pixel is a sample (the corner -3 now counts) and may be kept
    s_all = m.ravel()
    med_all = float(np.median(s_all))
    mad_all = float(np.median(np.abs(s_all - med_all))) / norm.ppf(0.75)
    np.testing.assert_array_equal(_robust_mask(m), np.abs(m - med_all) <= 5.0 * mad_all)
    assert not _robust_mask(m, np.zeros(m.shape, bool)).any()
    flat = np.full((4, 4), 7.0)
    flat[0, 0] = 1000.0  # MAD 0: nothing to judge by, every valid pixel kept
    v = np.ones((4, 4), bool)
    v[1, 1] = False
    kept = _robust_mask(flat, v)
    np.testing.assert_array_equal(kept, v)
    assert kept is not v

    # above 40 000 pixels the statistics come from the (even, even) pixels: here 0 ± 1 there, 100 ± 1 elsewhere
    rng = np.random.default_rng(3)
    big = 100.0 + rng.uniform(-1, 1, (202, 202))
    big[::2, ::2] = rng.uniform(-1, 1, (101, 101))
    got = _robust_mask(big)
    sub = big[::2, ::2].ravel()
    med_s = float(np.median(sub))
    mad_s = float(np.median(np.abs(sub - med_s))) / norm.ppf(0.75)
    np.testing.assert_array_equal(got, np.abs(big - med_s) <= 5.0 * mad_s)
    assert got.sum() == 101 * 101  # only the (even, even) pixels are near that median
    # exactly 40 000 pixels: all of them are the sample, the median is 100-ish, the (even, even) pixels go
    exact = big[:200, :200]
    s40 = exact.ravel()
    med40 = float(np.median(s40))
    mad40 = float(np.median(np.abs(s40 - med40))) / norm.ppf(0.75)
    got40 = _robust_mask(exact)
    np.testing.assert_array_equal(got40, np.abs(exact - med40) <= 5.0 * mad40)
    assert got40.sum() == 40_000 - 100 * 100
    # 40 001 pixels (13 x 3077): sampled again
    odd_shape = 100.0 + rng.uniform(-1, 1, (13, 3077))
    odd_shape[::2, ::2] = rng.uniform(-1, 1, (7, 1539))
    assert _robust_mask(odd_shape).sum() == 7 * 1539
    # a mask that leaves no (even, even) pixel valid leaves no sample: nothing kept
    odd = np.zeros(big.shape, bool)
    odd[1::2, 1::2] = True
    none = _robust_mask(big, odd)
    assert none.dtype == bool and none.shape == big.shape and not none.any()
    # one valid pixel: it is its own median, MAD 0, kept
    one = np.zeros((4, 4), bool)
    one[2, 3] = True
    np.testing.assert_array_equal(_robust_mask(flat, one), one)


def _sweep_frame_record(planes, invalid=None, x=1.0, radiance=2.0, wl=550.0):
    from camcal.calibrate.sweep import SweepRow, _FrameResult

    p = np.asarray(planes, np.float32)
    row = SweepRow(path=Path(f"f{wl:g}.dng"), wavelength_nm=wl, radiance_w_m2_sr=radiance, radiance_unc_w_m2_sr=None,
                   bandwidth_nm=None, overrides={})
    return _FrameResult(row=row, planes=p, invalid=np.zeros(p.shape, bool) if invalid is None else invalid,
                        relative_exposure_s=x, saturated_fraction=0.0, defect_saturated=0)


@pytest.mark.formula
def test_frame_signal_is_brightest_plane_mean_and_its_standard_error():
    """The signal is the mean of the valid pixels of the plane with the highest such mean; its standard error is
    their sample standard deviation (ddof 1) over √n. Planes with fewer than 2 valid pixels are skipped; none
    left -> (0, 0)."""
    from camcal.calibrate.sweep import frame_signal

    planes = np.array([[[10, 12], [14, 16]], [[20, 30], [25, 1000]], [[500, 0], [0, 0]], [[19, 21], [23, 25]]])
    invalid = np.zeros(planes.shape, bool)
    invalid[1, 1, 1] = True  # the 1000 DN pixel of plane 1 is a defect
    invalid[2] = [[False, True], [True, True]]  # plane 2: one valid pixel only
    s, sem = frame_signal(_sweep_frame_record(planes, invalid))
    v = np.array([20.0, 30.0, 25.0])  # plane 1's valid pixels: mean 25, sd 5
    assert s == 25.0 and sem == pytest.approx(5.0 / np.sqrt(3), rel=1e-12)
    assert sem == pytest.approx(np.sqrt(np.sum((v - 25.0) ** 2) / 2) / np.sqrt(3), rel=1e-12)
    # a later plane with the same mean does not replace the first (its spread differs)
    tie = planes.copy()
    tie[3] = [[22, 28], [25, 25]]  # mean 25, sd sqrt(18/3)
    invalid_tie = invalid.copy()
    s, sem = frame_signal(_sweep_frame_record(tie, invalid_tie))
    assert s == 25.0 and sem == pytest.approx(5.0 / np.sqrt(3), rel=1e-12)
    # two valid pixels are enough: plane 2 with 500 and 0 valid (mean 250, sd 353.55, sem 250)
    invalid2 = invalid.copy()
    invalid2[2, 0, 1] = False
    s, sem = frame_signal(_sweep_frame_record(planes, invalid2))
    assert s == 250.0 and sem == pytest.approx(250.0, rel=1e-6)  # float32 pixels, float64 sums
    # every plane below zero: the least negative one, not 0
    s, sem = frame_signal(_sweep_frame_record(-np.abs(planes[:2]) - 1, np.zeros((2, 2, 2), bool)))
    assert s == -14.0 and sem == pytest.approx(np.std([-11, -13, -15, -17], ddof=1) / 2, rel=1e-12)
    # planes skipped before the brightest usable one: plane 1 wholly invalid, plane 2 with one pixel -> plane 3
    invalid3 = invalid.copy()
    invalid3[1] = True
    s, sem = frame_signal(_sweep_frame_record(planes, invalid3))
    assert s == 22.0 and sem == pytest.approx(np.std([19, 21, 23, 25], ddof=1) / 2, rel=1e-12)
    # the mean is accumulated in float64: (2^24 + 3) / 4 = 4194304.75, which float32 sums round to 4194304
    wide = np.array([[[2.0**24, 1.0], [1.0, 1.0]]], np.float32)
    assert frame_signal(_sweep_frame_record(wide, np.zeros(wide.shape, bool)))[0] == 4194304.75
    assert frame_signal(_sweep_frame_record(planes, np.ones(planes.shape, bool))) == (0.0, 0.0)
    lone = np.ones(planes.shape, bool)
    lone[:, 0, 0] = False  # one valid pixel per plane
    assert frame_signal(_sweep_frame_record(planes, lone)) == (0.0, 0.0)


@pytest.mark.formula
def test_no_light_compares_signal_per_exposure_and_radiance_with_repeats():
    """A frame is left out when s/(x·L) is below 0.05 of the median of its repeats' s/(x·L) (strictly), with the
    one-line reason giving its signal, the wavelength, the expected signal ref·x·L and the reference reading."""
    from camcal.calibrate.sweep import no_light

    def frame(signal, x, radiance):
        return _sweep_frame_record(np.full((1, 2, 2), signal), x=x, radiance=radiance, wl=612.5)

    # s/(xL): 100/(1·2) = 50, 420/(2·4) = 52.5, 3/(0.5·3) = 2 < 0.05 · median(50, 52.5) = 2.5625
    a, b, c = frame(100.0, 1.0, 2.0), frame(420.0, 2.0, 4.0), frame(3.0, 0.5, 3.0)
    out = no_light([a, b, c])
    assert len(out) == 1 and out[0][0] is c
    expected = 51.25 * 0.5 * 3.0  # the repeats' median rate times this frame's x·L
    assert out[0][1] == (f"no light recorded (shutter closed or trigger missed): 3 DN above dark at 612.5 nm, where "
                         f"its repeats recorded {expected:.3g} DN for the same exposure and the reference detector "
                         "read 3 W m⁻² sr⁻¹")
    assert expected == 76.875
    # exactly 0.05 of the median is kept: 2.5625 · 1.5 = 3.84375 DN
    assert no_light([a, b, frame(3.84375, 0.5, 3.0)]) == []
    assert [r for r, _ in no_light([a, b, frame(3.843, 0.5, 3.0)])] != []
    # the median of the others, not their mean: a rate of 5 is above 0.05 · median(50, 52.5, 1000) = 2.625 but
    # below 0.05 · their mean (18.4)
    big = frame(2000.0, 1.0, 2.0)  # rate 1000
    d = frame(7.5, 0.5, 3.0)  # rate 5: above 0.05 · median(50, 52.5, 1000) = 2.625, below 0.05 · mean = 18.4
    assert [r for r, _ in no_light([a, b, big, d])] == []
    assert no_light([c]) == [] and no_light([]) == []
    # a frame whose repeats saw nothing (median 0) is not judged; the dark repeat is
    e, f = frame(0.0, 1.0, 2.0), frame(40.0, 1.0, 2.0)
    assert [r for r, _ in no_light([e, f])] == [e]
    # repeats at exactly 0 DN judge nothing either, even a frame below zero
    assert no_light([frame(0.0, 1.0, 1.0), frame(0.0, 1.0, 1.0), frame(-5.0, 1.0, 1.0)]) == []
    # the rates are in arbitrary units: below 1 they are judged the same way (0.01 < 0.05 · 0.5)
    low = frame(0.01, 1.0, 1.0)
    assert [r for r, _ in no_light([frame(0.5, 1.0, 1.0), frame(0.5, 1.0, 1.0), low])] == [low]
    # a negative reference (dark-subtracted noise) judges nothing
    assert no_light([frame(-5.0, 1.0, 1.0), frame(-4.0, 1.0, 1.0), frame(-6.0, 1.0, 1.0)]) == []


@pytest.mark.formula
def test_require_wavelengths_roi_check_and_sweep_mode():
    """require_wavelengths counts the wavelengths with a usable frame against the spline's need and says how many
    sweep.csv listed and which wavelengths were dropped; _check_roi accepts a ROI inside the half-resolution planes
    (integers) and refuses any other; SweepOptions.check accepts the two modes only."""
    from camcal.calibrate.sweep import SweepMeasurement, SweepOptions, _check_roi, require_wavelengths
    from camcal.errors import TooFewFrames

    notes = ("dropped 400 nm: saturated", "3 defects saturate", "dropped 410 nm: no light")
    meas = SweepMeasurement(settings=(object(),) * 3, channels=PLANES, notes=notes, csv_path=Path("/s/sweep.csv"),
                            n_listed=7)
    with pytest.raises(TooFewFrames) as info:
        require_wavelengths(meas)
    assert str(info.value) == ("/s/sweep.csv: the sweep stage needs at least 4 usable wavelengths, 3 remain (7 in "
                               "sweep.csv, 4 without a usable frame; c(λ) is read with a not-a-knot cubic spline, "
                               "which needs 4; dropped 400 nm: saturated; dropped 410 nm: no light)")
    assert (info.value.needed, info.value.remaining, info.value.stage) == (4, 3, "sweep")
    with pytest.raises(TooFewFrames) as info:
        require_wavelengths(meas, needed=5, listed=9)
    assert "needs at least 5 usable wavelengths, 3 remain (9 in sweep.csv, 6 without" in str(info.value)
    assert "which needs 5;" in str(info.value)
    assert require_wavelengths(meas, needed=3) is None  # exactly enough
    four = replace(meas, settings=(object(),) * 4, notes=())
    assert require_wavelengths(four) is None

    where = Path("/s/sweep")
    assert _check_roi((0, 0, 8, 6), (6, 8), where) == (0, 0, 8, 6)  # the whole 8x6 plane
    got = _check_roi((1.0, 2.0, "5", 4), (6, 8), where)
    assert got == (1, 2, 5, 4) and all(type(v) is int for v in got)
    for bad in ((-1, 0, 4, 4), (4, 0, 4, 4), (5, 0, 4, 4), (0, 0, 9, 4), (0, -1, 4, 4), (0, 3, 4, 3), (0, 4, 4, 3),
                (0, 0, 4, 7)):
        with pytest.raises(CamcalError) as info:
            _check_roi(bad, (6, 8), where)
        assert str(info.value) == (f"/s/sweep: ROI {bad} (x0,y0,x1,y1 in half-resolution plane pixels) is outside "
                                   "the 8x6 planes")

    assert SweepOptions(mode="relative").check() is None and SweepOptions().check() is None
    with pytest.raises(CamcalError) as info:
        SweepOptions(mode="Absolute").check()  # type: ignore[arg-type]
    assert str(info.value) == "mode must be 'relative' or 'absolute', got 'Absolute'"

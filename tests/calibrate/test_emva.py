"""EMVA 1288 figures (issue 31) against the standard's reference implementation and against the truth.

The reference implementation (the ``emva1288`` package, release 1.0.2) simulates a camera and analyses its
exposure-variant data set. Its own simulated camera (12 bit, K = 0.499 DN/e⁻, 1.49 DN of DSNU, 0.5 % PRNU,
300 e⁻/s of dark current, 128×128 pixels, 16 exposure steps with a dark and a bright pair each, 16 dark and 16
bright frames for the spatial test) writes the same pixels as the DNG frames of a camcal session:

- temporal dark pairs and the spatial dark frames → ``dark/`` (the spatial ones at the middle exposure);
- temporal bright pairs → ``linearity/`` (photon transfer), spatial bright frames → ``flat/``.

The monochrome sensor is written as an RGGB mosaic, so camcal measures each quarter of the pixels as one plane;
the reference measures all of them. Pooled over the four planes camcal sees the reference's pixels, so the
pooled figures are compared with the reference (within 2 %, the issue's target) and each plane with the truth
of its own pixels, within the uncertainty camcal states (3σ) or, where it states none, a bound from the noise.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
from emva1288.camera.camera import Camera  # the reference implementation (test dependency)
from emva1288.camera.points_generator import PointsGenerator
from emva1288.process import Data1288, Results1288
from emva1288.process.routines import get_int_imgs

from camcal.apply.photo import apply, prepare
from camcal.calibrate.emva import (
    dark_noise_stacks,
    dark_temporal,
    flats_needed,
    linearity_error,
    pair_statistics,
    photon_transfer,
    saturation_index,
    spatial_variance,
)
from camcal.calibrate.run import calibrate_session
from camcal.cli import main
from camcal.io.read import load_frame
from camcal.models.emva import sheet_rows
from camcal.models.profile import save_profile
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.dng import write_dng
from camcal.synth.session import SessionPlan, _white_spectrum, exposure_for_level, write_session
from tests.conftest import run_cli
from tests.helpers import _dark_group

SIZE = 128
STEPS = 16
L_SPATIAL = 16
K_SET = 0.5  # the simulator snaps it to its gain grid: 0.4992 DN/e⁻
DSNU_DN = 1.49
DARK_E_PER_S = 300.0
PLANES = ("R", "G1", "G2", "B")
OFFSET = {"R": (0, 0), "G1": (0, 1), "G2": (1, 0), "B": (1, 1)}


def _asfarray(a, dtype=np.float64):
    return np.asarray(a, dtype=dtype)


def simulate(root, *, prnu_pct: float, seed: int, steps: int = STEPS, l_spatial: int = L_SPATIAL) -> dict:
    """Run the reference simulator, write its frames as a camcal session, and analyse them with the reference.

    Returns the reference's figures, the truth (the simulator's maps) and the session folder.
    """
    rng = np.random.default_rng(seed)
    dsnu_e = rng.normal(0.0, DSNU_DN / K_SET, (SIZE, SIZE))
    prnu = 1.0 + rng.normal(0.0, prnu_pct / 100.0, (SIZE, SIZE)) if prnu_pct else None
    cam = Camera(bit_depth=12, width=SIZE, height=SIZE, K=K_SET, blackoffset=64, temperature=30,
                      temperature_ref=30, dark_current_ref=DARK_E_PER_S, dsnu=dsnu_e, prnu=prnu, seed=seed)
    cam.exposure = cam.exposure_min
    points = PointsGenerator(cam, steps=steps).points
    data: dict = {"temporal": {}, "spatial": {}, "height": SIZE, "width": SIZE}
    for d in ("dark", "flat", "linearity"):
        (root / d).mkdir(parents=True)
    (root / "session.toml").write_text("iso = 100\nf_number = 8\n")
    # the black level a camera writes is its dark level at zero exposure: the offset plus K times the
    # simulator's constant electronic offset (dark_signal_0 = 10 e⁻)
    black = round(cam.blackoffset + cam.K * 10.0)
    n = 0
    for kind in ("temporal", "spatial"):
        frames = 2 if kind == "temporal" else l_spatial
        for texp_ns, radiances in points[kind].items():
            cam.exposure = texp_ns
            for rad in radiances:
                dark = float(np.mean(rad)) == 0.0
                imgs = [cam.grab(rad) for _ in range(frames)]
                photons = 0.0 if dark else float(np.round(np.sum(cam.get_photons(rad), axis=2).mean(), 3))
                stats = get_int_imgs(imgs)
                if kind == "temporal":
                    stats = {"sum": np.sum(stats["sum"]), "pvar": np.sum(stats["pvar"]), "dmean": stats["dmean"]}
                data[kind].setdefault(texp_ns, {})[photons] = stats
                folder = "dark" if dark else ("linearity" if kind == "temporal" else "flat")
                for img in imgs:
                    write_dng(root / folder / f"f{n:05d}.dng", img.astype(np.uint16), cfa_pattern="RGGB",
                              black_level_dn=black, white_level_dn=cam.img_max, exposure_s=texp_ns * 1e-9,
                              f_number=8.0, iso=100.0)
                    n += 1
    with pytest.MonkeyPatch.context() as mp:  # release 1.0.2 calls np.asfarray, removed in numpy 2
        if not hasattr(np, "asfarray"):
            mp.setattr(np, "asfarray", _asfarray, raising=False)
        r = Results1288(Data1288(data).data, loglevel=40)
        ref = {"K": float(r.K), "read_noise_dn": float(r.sigma_d * r.K), "dsnu_dn": float(r.DSNU1288_DN()),
               "prnu_pct": float(r.PRNU1288), "saturation_e": float(r.u_e_sat), "snr_max": float(r.SNR_max),
               "dynamic_range_db": float(r.DR_dB()), "dark_current_dn_per_s": float(r.u_I_mean_DN),
               "linearity_error_pct": float((r.LE_max - r.LE_min) / 2)}
    truth = {"K": float(cam.K), "dsnu_e": dsnu_e, "prnu": prnu, "dark_current_dn_per_s": DARK_E_PER_S * cam.K}
    return {"root": root, "reference": ref, "truth": truth}


def _plane(a: np.ndarray, p: str) -> np.ndarray:
    y, x = OFFSET[p]
    return a[y::2, x::2]


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory):
    """The reference simulator's camera with DSNU and PRNU, calibrated by camcal (written once)."""
    out = simulate(tmp_path_factory.mktemp("emva_ref") / "S", prnu_pct=0.5, seed=3)
    profile, _ = calibrate_session(out["root"])
    out["path"] = out["root"].parent / "ref.camcal"
    save_profile(profile, out["path"])
    out["profile"] = profile
    return out


def _pooled(profile, key: str, how: str = "mean") -> float:
    vals = np.array([profile.emva.channels[p][key] for p in PLANES], float)
    return float(np.sqrt(np.mean(vals**2))) if how == "rms" else float(np.mean(vals))


def test_figures_match_the_reference_implementation(reference_run):
    ref, prof = reference_run["reference"], reference_run["profile"]
    # pooled over the planes camcal sees the reference's pixels: the 2 % target (measured: 0.0-0.8 %)
    for key, how in (("K_dn_per_e", "mean"), ("read_noise_dn", "rms"), ("dsnu_dn", "rms"), ("prnu_pct", "rms"),
                     ("saturation_e", "mean")):
        want = ref["K" if key == "K_dn_per_e" else key]
        assert _pooled(prof, key, how) == pytest.approx(want, rel=0.02), (key, _pooled(prof, key, how), want)
    for key in ("snr_max", "dynamic_range_db"):
        assert _pooled(prof, key) == pytest.approx(ref[key], rel=0.02), key
    # the dark current keeps its 0.1 %: the dark model's figure (median of the per-pixel slopes, measured +0.08 %)
    # and the sheet's (their mean, the standard's slope of the mean dark signal, measured +0.04 %)
    beta = np.mean([prof.dark.channels[p]["dark_current_dn_per_s"] for p in PLANES])
    assert beta == pytest.approx(ref["dark_current_dn_per_s"], rel=0.001)
    assert _pooled(prof, "dark_current_dn_per_s") == pytest.approx(ref["dark_current_dn_per_s"], rel=0.001)


def test_figures_match_the_truth(reference_run):
    prof, truth = reference_run["profile"], reference_run["truth"]
    sheet = prof.emva
    for p in PLANES:
        row = sheet.channels[p]
        assert row["K_source"].startswith("photon transfer")
        # K: within 3 standard errors of the fit (stated ≈ 0.4 %)
        assert abs(row["K_dn_per_e"] - truth["K"]) < 3 * row["K_unc_dn_per_e"], (p, row["K_dn_per_e"])
        # DSNU: the spatial spread of this plane's own offsets, in DN (stated uncertainty ≈ 1.7 %)
        dsnu_true = float(np.std(_plane(truth["dsnu_e"], p), ddof=1)) * truth["K"]
        assert abs(row["dsnu_dn"] - dsnu_true) < 3 * row["dsnu_unc_dn"], (p, row["dsnu_dn"], dsnu_true)
        # PRNU: the relative spread of this plane's own gains (stated uncertainty ≈ 1.8 %)
        g = _plane(truth["prnu"], p)
        prnu_true = 100 * float(np.std(g, ddof=1) / np.mean(g))
        assert abs(row["prnu_pct"] - prnu_true) < 3 * row["prnu_unc_pct"], (p, row["prnu_pct"], prnu_true)
        # the noise left in the per-pixel flat map: σ of one flat over √L, relative to the level; one flat's
        # temporal variance is σ²_y.dark(0) + K·(flat level + dark signal) (the linear model, truth K)
        lvl = prof.flat.level_dn[p]
        t_flat = prof.flat.info["exposure_s"][0]
        var_frame = row["dark_noise_dn"] ** 2 + truth["K"] * (lvl + truth["dark_current_dn_per_s"] * t_flat)
        assert row["flat_map_noise_pct"] == pytest.approx(100 * math.sqrt(var_frame / L_SPATIAL) / lvl, rel=0.05)
        # the number of flats that brings that noise below the PRNU: with it the noise is below, with one less not
        need, noise, prnu_pct = row["flats_for_noise_below_prnu"], row["flat_map_noise_pct"], row["prnu_pct"]
        assert noise * math.sqrt(L_SPATIAL / need) < prnu_pct <= noise * math.sqrt(L_SPATIAL / max(need - 1, 1e-9))
    dc = np.mean([prof.dark.channels[p]["dark_current_dn_per_s"] for p in PLANES])
    assert dc == pytest.approx(truth["dark_current_dn_per_s"], rel=0.002)  # 0.2 %: the noise of 4×4096 slopes


def test_sensor_without_prnu(tmp_path_factory):
    # What limits a PRNU of 0: eq. 36 removes the temporal noise left in the average of L flats (≈ 0.39 % of the
    # level with 16 flats here, 0.2 % with 64), but the spatial variance it is removed from is itself measured on
    # N pixels, with a standard error √(2/N) of that floor; so a true 0 reads (2/N)^¼ × floor (1σ): 0.058 % for
    # one 64×64 plane and 16 flats, 0.029 % with 64 flats. The 0.05 % needs the 64 flats per plane.
    run = simulate(tmp_path_factory.mktemp("emva_flat") / "S", prnu_pct=0.0, seed=5, steps=8, l_spatial=64)
    profile, _ = calibrate_session(run["root"])
    for p in PLANES:
        row = profile.emva.channels[p]
        assert row["prnu_pct"] < 0.05, (p, row["prnu_pct"])
        assert row["flat_map_noise_pct"] > 0.15  # the floor an estimate without eq. 36 would count as PRNU
        assert row["flats_for_noise_below_prnu"] is None or row["flats_for_noise_below_prnu"] > 64
    assert run["reference"]["prnu_pct"] < 0.05  # the reference implementation on all 16 384 pixels


def test_profile_show_emva_and_report(reference_run, tmp_path, capsys, monkeypatch):
    proc = run_cli("profile", "show", reference_run["path"], "--emva", env={"COLUMNS": "160"})
    assert proc.returncode == 0, proc.stderr
    for text in ("EMVA 1288 release 4.0", "overall system gain K", "saturation capacity", "SNR_max",
                 "dynamic range", "linearity error", "DSNU_1288", "PRNU_1288", "flats for map noise < PRNU",
                 "photon transfer at ISO 100"):
        assert text in proc.stdout, text
    k = reference_run["profile"].emva.channels["R"]["K_dn_per_e"]
    assert f"{k:.5g}" in proc.stdout
    # the same command in process (a subprocess costs seconds): JSON sheet, contract, report
    assert main(["profile", "show", str(reference_run["path"]), "--emva", "--json"]) == 0
    sheet = json.loads(capsys.readouterr().out)
    assert sheet["channels"]["R"]["K_dn_per_e"] == pytest.approx(k) and sheet["standard"].startswith("EMVA 1288")
    assert main(["profile", "show", str(reference_run["path"]), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["emva1288"]["channels"]["G1"]["saturation_e"] > 0
    html = tmp_path / "r.html"
    assert main(["report", str(reference_run["path"]), "-o", str(html)]) == 0
    text = html.read_text()
    assert 'id="emva1288"' in text and "EMVA 1288 summary" in text and "saturation capacity μ_e.sat" in text
    assert f"{k:.5g}" in text
    # a profile without the section: one clear line, exit 2
    sheetless = tmp_path / "old.camcal"
    prof = reference_run["profile"]
    save_profile(type(prof)(camera=prof.camera, reference_iso=prof.reference_iso,
                            reference_f_number=prof.reference_f_number, dark=prof.dark), sheetless)
    capsys.readouterr()
    assert main(["profile", "show", str(sheetless), "--emva"]) == 2
    assert "no EMVA 1288 section" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------------------------
# the pure functions on known numbers
# ---------------------------------------------------------------------------------------------------------------
def test_pair_statistics_and_spatial_variance_are_unbiased(rng):
    # pixels with a fixed pattern of 2 DN and temporal noise of 5 DN: the pair difference sees only the 5 DN
    pattern = rng.normal(100, 2.0, 200_000)
    a, b = pattern + rng.normal(0, 5, pattern.size), pattern + rng.normal(0, 5, pattern.size)
    m, v = pair_statistics(a, b)
    assert m == pytest.approx(100, abs=0.05) and v == pytest.approx(25, rel=0.01)  # 0.3 % (1σ) on 2e5 pixels
    # L = 8 frames: the average carries 25/8 DN² of temporal variance; eq. 36 leaves the 4 DN² of pattern
    frames = pattern + rng.normal(0, 5, (8, pattern.size))
    sv = spatial_variance(frames.mean(0), frames.var(0, ddof=1), 8)
    assert sv.measured_dn2 == pytest.approx(4 + 25 / 8, rel=0.01)
    assert sv.variance_dn2 == pytest.approx(4, abs=3 * sv.variance_unc_dn2)
    assert sv.variance_unc_dn2 == pytest.approx(math.sqrt(2 / pattern.size) * sv.measured_dn2, rel=0.1)


def test_photon_transfer_and_saturation_on_a_model_sensor(rng):
    # K = 0.25 DN/e⁻, σ²_y.dark = 4 DN², a full well clipping at 3000 DN: the variance peaks before the clip
    k, v0, t = 0.25, 4.0, np.linspace(0.01, 1.2, 40)
    electrons = 12000 * t
    sig, var = [], []
    for e in electrons:
        y = np.minimum(k * rng.poisson(e, (2, 20000)) + rng.normal(0, 2, (2, 20000)), 3000)
        s, v = pair_statistics(y[0], y[1])
        sig.append(s)
        var.append(v)
    pt = photon_transfer(t, np.array(sig), np.array(var), v0)
    assert pt.gain_dn_per_e == pytest.approx(k, abs=3 * pt.gain_unc_dn_per_e)
    assert pt.gain_unc_dn_per_e < 0.01 * k
    assert 2500 < np.array(sig)[saturation_index(np.array(var))] <= 3000
    assert pt.fit_range_dn[1] <= 0.7 * pt.photo_signal_dn[pt.saturation_index] + 1e-9
    free = photon_transfer(t, np.array(sig), np.array(var))  # intercept fitted
    assert free.intercept_fitted and free.dark_variance_dn2 == pytest.approx(v0, abs=3.0)
    assert free.gain_dn_per_e == pytest.approx(k, rel=0.02)
    dt = dark_temporal(np.array([0.0, 1.0, 2.0, 4.0]), np.array([4.0, 5.0, 6.0, 8.0]))
    assert dt.dark_variance_dn2 == pytest.approx(4.0) and dt.read_noise_dn == pytest.approx(math.sqrt(4 - 1 / 12))


def test_linearity_error_definition():
    x = np.linspace(1, 10, 10)
    y = 3 * x + 2
    assert linearity_error(x, y, 40).error_pct == pytest.approx(0, abs=1e-9)
    bent = y * (1 + 0.01 * np.sin(x))
    le = linearity_error(x, bent, 40)
    assert le.error_pct == pytest.approx((le.max_pct - le.min_pct) / 2) and 0.5 < le.error_pct < 1.5


def test_flats_needed():
    # per-frame relative temporal variance 1e-4 (1 %), PRNU 0.5 %: L > 1e-4 / 2.5e-5 = 4 → 5 flats
    assert flats_needed(1e-4, 0.005) == 5
    assert flats_needed(1e-4, 0.0) is None


# ---------------------------------------------------------------------------------------------------------------
# the synthetic camera: K from photon transfer drives the σ maps of apply; QE with the pixel pitch
# ---------------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def pair_session(tmp_path_factory):
    """A small synthetic session whose linearity series is shot in pairs, calibrated once."""
    cam = SyntheticCamera(SensorParams(width=192, height=128))
    root = tmp_path_factory.mktemp("pairs") / "S"
    write_session(root, cam, SessionPlan(linearity_repeats=2, linearity_jpeg=False, sweep_jpeg=False,
                                         sweep_step_nm=10.0, n_sweep=1))
    (root / "session.toml").write_text(f"pixel_pitch_um = {cam.params.pixel_pitch_um}\n")
    profile, _ = calibrate_session(root)
    return cam, profile


def test_sigma_maps_match_the_scatter_of_repeated_photos(pair_session, tmp_path):
    cam, profile = pair_session
    for p in PLANES:
        row = profile.emva.channels[p]
        assert row["K_source"] == "photon transfer at ISO 100"
        # truth 1/1.6 = 0.625 DN/e⁻; the fit's standard error is ≈ 0.6 %: 3 % bounds it with margin
        assert row["K_dn_per_e"] == pytest.approx(1 / cam.params.gain_e_per_dn, rel=0.03), p
    spec = _white_spectrum(5000.0)
    t = exposure_for_level(cam, spec, 0.4, 100, 4.0)
    rng = np.random.default_rng(11)
    plan_rel = prepare(profile, 663.0, "narrowband", with_prnu=True).model.weights_unc_rel
    values, sigmas = [], []
    for i in range(10):
        path = tmp_path / f"p{i}.dng"
        cam.write_dng(path, Scene.uniform(spec), exposure_s=t, iso=100, f_number=4.0, rng=rng)
        img = apply(load_frame(path), profile, 663.0, "narrowband", with_prnu=True)
        L, u = img.channels["L663_inband"], img.channels["L663_inband_unc"]
        values.append(L)
        sigmas.append(np.sqrt(np.maximum(u**2 - (plan_rel * L) ** 2, 0)))  # the noise part of the map
    values, sigmas = np.array(values), np.array(sigmas)
    ok = np.all(np.isfinite(values), axis=0)
    scatter = float(np.sqrt(np.mean(np.var(values, axis=0, ddof=1)[ok])))
    predicted = float(np.sqrt(np.mean(sigmas[:, ok] ** 2)))
    # 6 000 pixels × 9 degrees of freedom: the scatter is known to 0.3 %; the target is 5 %
    assert predicted == pytest.approx(scatter, rel=0.05), (predicted, scatter)


def test_quantum_efficiency_with_the_pixel_pitch(pair_session):
    cam, profile = pair_session
    qe = profile.emva.quantum_efficiency
    assert qe is not None and qe["pixel_pitch_um"] == pytest.approx(cam.params.pixel_pitch_um)
    # camcal's η is the system's (lens transmittance τ = 0.9 included): its peak is τ times the sensor's
    # peak QE; c(λ) is sampled every 10 nm with a 5 nm slit, so the sampled peak may sit a few % low
    for plane, peak in (("R", cam.params.qe_peak[0]), ("G1", cam.params.qe_peak[1]), ("B", cam.params.qe_peak[2])):
        got = max(v for v in qe["values"][plane] if v is not None)
        assert got == pytest.approx(cam.params.lens_transmittance * peak, rel=0.05), plane


# ---------------------------------------------------------------------------------------------------------------
# the standard's PRNU₁₂₈₈ and camcal's own PRNU, each under its own name
# ---------------------------------------------------------------------------------------------------------------
def test_prnu_1288_is_the_total_and_camcals_prnu_the_pixel_part(tmp_path):
    """A synthetic sensor with known vignetting (corner gain 0.62) and 1 % pixel PRNU: the profile's PRNU₁₂₈₈ is the
    total non-uniformity of the flat (vignetting × PRNU), camcal's PRNU about the vignetting model the pixel part,
    each within 3 of its stated standard uncertainties; the release 4.0 parts add up to the total."""
    cam = SyntheticCamera(SensorParams(width=192, height=128, prnu_sigma=0.01))
    root = tmp_path / "S"
    write_session(root, cam, SessionPlan(stages=("bias", "dark", "flat"), n_flat=16, dark_exposures_s=(2.0, 8.0)))
    profile, _ = calibrate_session(root)
    response = cam.vignetting_map_at(cam.params.reference_f_number) * cam.prnu_map
    for i, p in enumerate(PLANES):
        row = profile.emva.channels[p]
        total = 100 * np.std(response[i], ddof=1) / np.mean(response[i])
        pixel = 100 * np.std(cam.prnu_map[i], ddof=1) / np.mean(cam.prnu_map[i])
        assert total > 8 * pixel  # the vignetting dominates: the two figures are far apart
        assert abs(row["prnu_pct"] - total) < 3 * row["prnu_unc_pct"], (p, row["prnu_pct"], total)
        assert abs(row["prnu_devignetted_pct"] - pixel) < 3 * row["prnu_devignetted_unc_pct"], (p, row, pixel)
        parts = row["prnu_row_pct"] ** 2 + row["prnu_col_pct"] ** 2 + row["prnu_pixel_pct"] ** 2
        assert parts == pytest.approx(row["prnu_pct"] ** 2, rel=0.03)
    names = [q for _, q, _, _ in sheet_rows(profile.emva)]
    assert "PRNU_1288 (total)" in names and "camcal: PRNU about the vignetting model (not EMVA 1288)" in names


def test_synth_session_shoots_linearity_pairs(tmp_path):
    out = tmp_path / "S"
    assert main(["synth", "session", str(out), "--stages", "linearity", "--width", "64", "--height", "64"]) == 0
    names = sorted(p.name for p in (out / "linearity").glob("*.dng"))
    assert "lin_000.dng" in names and "lin_000_1.dng" in names and len(names) % 2 == 0


# ---------------------------------------------------------------------------------------------------------------
# a monochrome sensor end to end: one-sample LinearRaw DNGs through calibrate
# ---------------------------------------------------------------------------------------------------------------
def test_monochrome_dng_session_through_calibrate(tmp_path):
    """One plane of the synthetic camera written as one-sample LinearRaw DNGs (a monochrome camera): dark, flat and
    linearity pairs calibrate to a one-channel profile (Y) whose K, read noise and PRNU₁₂₈₈ match the truth."""
    from camcal.synth.dng import encode_mono_dng

    cam = SyntheticCamera(SensorParams(width=256, height=192, prnu_sigma=0.01, hot_pixel_fraction=0.0))
    p = cam.params
    rng = np.random.default_rng(7)
    spec = _white_spectrum(5000.0)
    black = p.black_level_dn[1]

    def shoot(folder: str, name: str, t: float, lit: bool) -> None:
        d = tmp_path / "S" / folder
        d.mkdir(parents=True, exist_ok=True)
        planes = cam.expose_planes(Scene.uniform(spec) if lit else Scene.dark(), exposure_s=t, rng=rng)
        (d / name).write_bytes(encode_mono_dng(planes[1], black_level_dn=black, white_level_dn=p.white_dn,
                                               exposure_s=t, f_number=4.0, iso=100))

    for t in (1 / 4000, 2.0, 8.0):
        for i in range(4):
            shoot("dark", f"d_{t:g}_{i}.dng", t, False)
    t_flat = exposure_for_level(cam, spec, 0.45, 100, 4.0)
    for i in range(8):
        shoot("flat", f"f_{i}.dng", t_flat, True)
    t0 = exposure_for_level(cam, spec, 0.02, 100, 4.0)
    for k in range(12):
        for r in range(2):
            shoot("linearity", f"lin_{k:03d}_{r}.dng", t0 * 1.4**k, True)
    profile, _ = calibrate_session(tmp_path / "S")
    assert profile.camera.layout == "mono" and list(profile.emva.channels) == ["Y"]
    y = profile.emva.channels["Y"]
    truth_k = 1 / p.gain_e_per_dn
    assert abs(y["K_dn_per_e"] - truth_k) < 3 * y["K_unc_dn_per_e"], (y["K_dn_per_e"], y["K_unc_dn_per_e"])
    assert y["read_noise_e"] == pytest.approx(p.read_noise_e, rel=0.1)
    response = (cam.vignetting_map_at(4.0) * cam.prnu_map)[1]
    total = 100 * np.std(response, ddof=1) / np.mean(response)
    assert abs(y["prnu_pct"] - total) < 3 * y["prnu_unc_pct"], (y["prnu_pct"], total)
    assert profile.flat is not None and profile.flat.channels == ("Y",)


@pytest.mark.formula
def test_dark_noise_stacks_keep_what_the_emva_sheet_reads_and_nothing_more():
    """``dark_noise_stacks``: the groups of two frames or more, the dark groups in their order and then the bias
    frames at their median exposure time (unknown: 0 s); each group's unclipped variance where stacked, else its
    variance; the DSNU stack is the one of most frames (ties: the shorter exposure), its unclipped mean and
    variance. The arrays are the stacks' own (no copy), and the combined values and counts are not kept."""
    shape = (4, 2, 3)
    rng = np.random.default_rng(3)

    def group(t, n, clipped=False, exposure_s="t"):
        st = _dark_group(1000.0 + rng.uniform(0, 5, shape), rng.uniform(3, 5, shape), t, n, exposure_s=exposure_s)
        if clipped:  # a sigma-clipped stack: its unclipped variance and mean are arrays of their own
            st = replace(st, variance=np.zeros(shape, np.float32), mean_all=st.value + np.float32(0.25))
        return st

    lone, short, long_, bias = group(0.1, 1), group(0.5, 8, clipped=True), group(2.0, 8), group(0.0, 16,
                                                                                                 exposure_s=None)
    noise = dark_noise_stacks(((0.1, lone), (0.5, short), (2.0, long_)), bias)
    assert [(t, n) for t, n, _ in noise.groups] == [(0.5, 8), (2.0, 8), (0.0, 16)]
    assert noise.groups[0][2] is short.variance_all and noise.groups[1][2] is long_.variance_all
    assert noise.groups[2][2] is bias.variance_all
    t_sp, n_sp, mean, var = noise.spatial
    assert (t_sp, n_sp) == (0.0, 16) and mean is bias.value and var is bias.variance_all  # the mean stack's mean
    # without bias frames: of the two 8-frame groups the shorter exposure, its unclipped mean
    t_sp, n_sp, mean, var = dark_noise_stacks(((2.0, long_), (0.5, short)), None).spatial
    assert (t_sp, n_sp) == (0.5, 8) and mean is short.mean_all and var is short.variance_all
    no_var_all = replace(long_, variance_all=None)
    assert dark_noise_stacks(((2.0, no_var_all),), None).groups[0][2] is no_var_all.variance
    empty = dark_noise_stacks(((0.1, lone),), None)
    assert empty.groups == () and empty.spatial is None
    kept = {id(a) for g in noise.groups for a in g[2:]} | {id(a) for a in noise.spatial[2:]}
    assert not kept & {id(st.count) for st in (short, long_, bias)} and id(short.value) not in kept

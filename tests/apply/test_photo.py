"""Apply a profile to synthetic survey photos of known spectral radiance (issue 8).

Truth: a uniform field of spectral radiance L(λ) photographed by the same synthetic camera the
session was shot with. True band radiance per channel: ∫c_i L dλ / ∫c_i dλ with the camera's true
c_i; true in-band radiance of a line: its band radiance (the line has unit integral).

Noise budget (default sensor 384x256 → 192x128 output, 24 576 cells): the per-pixel scatter of a
frame at ~40 % of full scale is ≈1.5 % (shot noise ≈1 % + PRNU 1 %), so a whole-frame mean carries
≈0.01 % noise and a 20x20 block ≈0.08 %; the profile's c(λ) samples match the truth to ≈0.05 %.
"""

from __future__ import annotations

import numpy as np
import pytest

from camcal.apply.photo import apply, next_step_for_c, prepare, radiance_channel_name, roi_mask, roi_statistics
from camcal.apply.radiance import radiance_model, smooth_error_table
from camcal.errors import CamcalError
from camcal.io.exr import read_exr
from camcal.io.read import load_frame
from camcal.models.profile import load_profile
from camcal.models.spectra import WAVELENGTHS_NM, gaussian_line, planck_radiance
from camcal.region import Region
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
from camcal.synth.session import exposure_for_level
from camcal.units import BAND_RADIANCE, IN_BAND_RADIANCE
from tests.conftest import assert_one_line_error, run_cli
from tests.oracles import read_var_dn2

LINE_BAND_W_M2_SR = 2.0
LINE = LINE_BAND_W_M2_SR * gaussian_line(663.0, 5.0)
_PLANCK = planck_radiance(5500.0)
SMOOTH = 0.05 * _PLANCK / np.interp(663.0, WAVELENGTHS_NM, _PLANCK)  # 0.05 W m^-2 sr^-1 nm^-1 at 663 nm


@pytest.fixture(scope="module")
def profile(profile_path):
    return load_profile(profile_path)


@pytest.fixture(scope="module")
def photos(tmp_path_factory, camera):
    """RAW and JPEG photos of the line and of the smooth spectrum at several settings (written once)."""
    d = tmp_path_factory.mktemp("photos")
    rng = np.random.default_rng(2024)
    out = {}
    for name, spec in (("line", LINE), ("smooth", SMOOTH)):
        for iso, n, k in ((100, 4.0, 1.0), (200, 4.0, 1.0), (100, 8.0, 0.5)):
            t = k * exposure_for_level(camera, spec, 0.4, iso, n)
            p = d / f"{name}_iso{iso}_f{n:g}.dng"
            camera.write_dng(p, Scene.uniform(spec), exposure_s=t, iso=iso, f_number=n, rng=rng)
            out[(name, "raw", iso, n)] = p
        p = d / f"{name}.jpg"
        t = exposure_for_level(camera, spec, 0.4, 100, 4.0)
        camera.write_jpeg(p, Scene.uniform(spec), exposure_s=t, iso=100, f_number=4.0, rng=rng)
        out[(name, "jpeg", 100, 4.0)] = p
    # long exposure of a dim line: dark current (and hot pixels) matter
    t = 10.0
    dim = LINE * exposure_for_level(camera, LINE, 0.15, 100, 4.0) / t
    p = d / "dim_long.dng"
    camera.write_dng(p, Scene.uniform(dim), exposure_s=t, iso=100, f_number=4.0, rng=rng)
    out["dim"] = (p, float(dim.max() / LINE.max()))
    return out


def true_band(camera: SyntheticCamera, spectrum: np.ndarray) -> np.ndarray:
    c = camera.spectral_sensitivity()
    return np.trapezoid(c * spectrum, WAVELENGTHS_NM, axis=1) / np.trapezoid(c, WAVELENGTHS_NM, axis=1)


def mean(a: np.ndarray) -> float:
    return float(np.nanmean(a))


def test_narrowband_line_within_1pct(photos, profile, camera):
    img = apply(load_frame(photos[("line", "raw", 100, 4.0)]), profile, 663.0, "narrowband")
    # an in-band radiance (W m⁻² sr⁻¹) is named for what it is, not L663 (a spectral radiance)
    assert set(img.channels) == {"R", "G", "B", "L663_inband", "L663_inband_unc", "R_unc", "G_unc", "B_unc"}
    assert img.shape == (128, 192)  # half resolution of 384x256
    assert img.metadata["estimator_channel"] == "R"
    assert img.metadata["units"]["L663_inband"].startswith(IN_BAND_RADIANCE)
    # target 1 %; measured ≈0.05 % (noise 0.01 %, c(λ0) spline 0.05 %)
    assert mean(img.channels["L663_inband"]) == pytest.approx(LINE_BAND_W_M2_SR, rel=0.01)
    tb = true_band(camera, LINE)
    for i, ch in enumerate("RGB"):
        assert mean(img.channels[ch]) == pytest.approx(tb[i], rel=0.005), ch


def test_vignetting_and_dark_removed(photos, profile):
    img = apply(load_frame(photos[("line", "raw", 100, 4.0)]), profile, 663.0, "narrowband")
    L = img.channels["L663_inband"]
    centre = mean(L[54:74, 86:106])
    # the raw corner gain is 0.62; after the flat every 20x20 corner block agrees with the centre
    # to within 0.5 % (block noise 0.08 %, flat-model residual a few 0.1 %)
    for block in (L[:20, :20], L[:20, -20:], L[-20:, :20], L[-20:, -20:]):
        assert mean(block) == pytest.approx(centre, rel=0.005)
    # 10 s exposure of a dim line: dark current ≈ 1 % of the signal and hot pixels up to 300x are removed
    path, scale = photos["dim"]
    dim = apply(load_frame(path), profile, 663.0, "narrowband").channels["L663_inband"]
    assert mean(dim) == pytest.approx(LINE_BAND_W_M2_SR * scale, rel=0.005)
    finite = dim[np.isfinite(dim)]
    z = np.abs(finite - np.median(finite)) / (1.4826 * np.median(np.abs(finite - np.median(finite))))
    assert z.max() < 6.0  # no hot pixel survives (a hot pixel is > 30 σ)


def test_defects_are_nan(photos, profile):
    img = apply(load_frame(photos[("line", "raw", 100, 4.0)]), profile)
    bad_r = profile.dark.defects[0] != 0
    assert bad_r.any()
    assert np.all(np.isnan(img.channels["R"][bad_r])) and np.all(np.isnan(img.channels["L663"][bad_r]))
    both_g = (profile.dark.defects[1] != 0) & (profile.dark.defects[2] != 0)
    one_g = (profile.dark.defects[1] != 0) ^ (profile.dark.defects[2] != 0)
    assert np.all(np.isnan(img.channels["G"][both_g])) and np.all(np.isfinite(img.channels["G"][one_g]))


def test_exposure_settings_give_the_same_radiance(photos, profile):
    vals = [mean(apply(load_frame(photos[("line", "raw", iso, n)]), profile).channels["L663"])
            for iso, n in ((100, 4.0), (200, 4.0), (100, 8.0))]
    # ISO 200 / f/8 at half the signal: noise of the means < 0.03 %; the dark model scales with ISO
    assert np.ptp(vals) / np.mean(vals) < 0.003, vals


def test_uncertainty_map_matches_scatter(photos, profile):
    img = apply(load_frame(photos[("line", "raw", 100, 4.0)]), profile, 663.0, "narrowband")
    L, u = img.channels["L663_inband"], img.channels["L663_inband_unc"]
    rel_unc = float(np.nanmedian(u / L))
    # the map = noise (shot + read + PRNU) ⊕ c(λ0) uncertainty (0.5 %, the reference detector)
    c_rel = 0.005
    noise = np.sqrt(max(rel_unc**2 - c_rel**2, 0.0))
    scatter = float(np.nanstd(L) / np.nanmean(L))
    assert noise == pytest.approx(scatter, rel=0.15), (noise, scatter)


def test_band_uncertainty_matches_scatter(photos, profile):
    """R_unc, G_unc, B_unc: the 1-σ noise of each band (the existing noise model), against the pixel scatter of a
    uniform scene after the flat (the scatter holds the same shot, read and PRNU noise; 15 %: flat residuals)."""
    img = apply(load_frame(photos[("line", "raw", 100, 4.0)]), profile)
    for ch in "RGB":
        v, u = img.channels[ch], img.channels[f"{ch}_unc"]
        assert np.all(u[np.isfinite(v)] > 0), ch
        scatter = float(np.nanstd(v) / np.nanmean(v))
        assert float(np.nanmedian(u / v)) == pytest.approx(scatter, rel=0.15), ch
    # the c(λ) scale (common to every photo, cancels in a ratio) is stated apart, not in the map
    assert all(0 < r < 0.05 for r in img.metadata["band_scale_unc_rel"])


def test_smooth_estimator_has_its_spectral_term(photos, profile):
    """L663_unc of the smooth estimator holds the reconstruction's spread over the prior spectra."""
    img = apply(load_frame(photos[("smooth", "raw", 100, 4.0)]), profile, 663.0, "smooth")
    spread = img.metadata["spectral_unc_rel"]
    s = profile.spectral
    errors = [r["error_pct"] / 100 for r in smooth_error_table(s.wavelength_nm, s.rgb())]
    assert spread == pytest.approx(float(np.sqrt(np.mean(np.square(errors)))), rel=1e-6) and spread > 0.05
    assert float(np.nanmedian(img.channels["L663_unc"] / img.channels["L663"])) >= spread
    narrow = apply(load_frame(photos[("line", "raw", 100, 4.0)]), profile, 663.0, "narrowband")
    assert narrow.metadata["spectral_unc_rel"] == 0 and "unbounded" in narrow.metadata["spectral_assumption"]


def test_smooth_estimator_documented_error(photos, profile, camera):
    img = apply(load_frame(photos[("smooth", "raw", 100, 4.0)]), profile, 663.0, "smooth")
    true = 0.05
    s = profile.spectral
    model = radiance_model(s.wavelength_nm, s.rgb(), s.rgb_uncertainty(), 663.0, "smooth")
    c = camera.spectral_sensitivity()
    predicted = float(model.weights @ np.trapezoid(c * SMOOTH, WAVELENGTHS_NM, axis=1))
    got = mean(img.channels["L663"])
    # the pipeline delivers what the estimator predicts for the true rates (band accuracy ≈0.1 %) ...
    assert got == pytest.approx(predicted, rel=0.005)
    # ... and the estimator's error for a 5500 K black body lies between the documented 5000 K and
    # 6500 K rows of smooth_error_table (docs/apply.md: −8.5 % and +1.8 %)
    table = {r["spectrum"]: r["error_pct"] for r in smooth_error_table(s.wavelength_nm, s.rgb())}
    err = 100 * (got / true - 1)
    assert table["black body 5000 K"] - 0.5 < err < table["black body 6500 K"] + 0.5, (err, table)
    assert abs(err) > 1  # the smooth estimator is not exact here: the test would notice a change of method


def test_jpeg_within_3pct(photos, profile, camera):
    for name, spec, est, truth in (("line", LINE, "narrowband", LINE_BAND_W_M2_SR), ("smooth", SMOOTH, "band", None)):
        img = apply(load_frame(photos[(name, "jpeg", 100, 4.0)]), profile, 663.0,
                    "narrowband" if est == "narrowband" else "smooth")
        assert img.metadata["kind"] == "processed" and img.shape == (128, 192)
        tb = true_band(camera, spec)
        for i, ch in enumerate("RGB"):
            assert mean(img.channels[ch]) == pytest.approx(tb[i], rel=0.03), (name, ch)
        if truth is not None:
            assert mean(img.channels["L663_inband"]) == pytest.approx(truth, rel=0.03)
        assert any("through the profile's colour matrix" in n for n in img.metadata["notes"])  # sweep twins


def test_other_camera_refused(tmp_path, profile, profile_path):
    other = SyntheticCamera(SensorParams(model="Other Cam 9"))
    p = other.write_dng(tmp_path / "other.dng", Scene.uniform(LINE), exposure_s=0.02, iso=100, f_number=4.0,
                        rng=np.random.default_rng(1))
    with pytest.raises(CamcalError, match="Other Cam 9"):
        apply(load_frame(p), profile)
    img = apply(load_frame(p), profile, allow_other_camera=True)
    assert any("allowed" in n for n in img.metadata["notes"])
    proc = run_cli("apply", profile_path, p, "-o", tmp_path / "out")
    assert_one_line_error(proc, "other.dng", "Other Cam 9", "--allow-other-camera")
    assert not (tmp_path / "out" / "other.dng.exr").exists()
    proc = run_cli("apply", profile_path, p, "-o", tmp_path / "out", "--allow-other-camera", "-j", "1")
    assert proc.returncode == 0, proc.stderr


def test_channel_names_follow_wavelength(photos, profile):
    img = apply(load_frame(photos[("line", "raw", 100, 4.0)]), profile, 560.0, "narrowband")
    assert radiance_channel_name(560) == "L560" and radiance_channel_name(560, in_band=True) == "L560_inband"
    assert "L560_inband" in img.channels and "L560_inband_unc" in img.channels
    assert img.metadata["estimator_channel"] == "G"
    with pytest.raises(CamcalError, match="outside the calibrated range"):
        prepare(profile, 900.0)
    with pytest.raises(CamcalError, match="unknown estimator"):
        prepare(profile, 663.0, "magic")


def test_cli_exr_and_roi_stats(tmp_path, photos, profile_path, profile):
    src = photos[("line", "raw", 100, 4.0)]
    out = tmp_path / "out"
    proc = run_cli("apply", profile_path, src, "-o", out, "--roi", "100,60,80,60", "-j", "1", "--estimator",
                   "narrowband")
    assert proc.returncode == 0, proc.stderr
    assert "in-band radiance" in proc.stdout and "estimator narrowband" in proc.stdout  # the summary says what L is
    chans, meta = read_exr(out / f"{src.name}.exr")
    assert set(chans) == {"R", "G", "B", "L663_inband", "L663_inband_unc", "R_unc", "G_unc", "B_unc"}
    assert meta["profile_sha256"] == profile.content_sha256
    assert meta["wavelength_nm"] == pytest.approx(663.0) and meta["estimator"] == "narrowband"
    assert meta["source_name"] == src.name and meta["exposure"]["iso"] == 100
    assert meta["units"]["R"] == BAND_RADIANCE and "half resolution" in meta["resolution"]
    rows = (out / "roi_stats.csv").read_text().splitlines()
    assert rows[0] == "file,channel,n,mean,median,sigma,unit,region"
    stats = {r.split(",")[1]: r.split(",") for r in rows[1:]}
    assert int(stats["L663_inband"][2]) <= 40 * 30
    m = roi_mask((128, 192), Region(100, 60, 80, 60))
    ref = {r["channel"]: r for r in roi_statistics(chans, m)}
    assert float(stats["L663_inband"][3]) == pytest.approx(ref["L663_inband"]["mean"], rel=1e-6)
    assert float(stats["L663_inband"][3]) == pytest.approx(LINE_BAND_W_M2_SR, rel=0.01)
    # a mask image over the same region gives the same numbers
    import OpenImageIO as oiio

    mask = np.zeros((256, 384), np.uint8)
    mask[60:120, 100:180] = 255
    spec = oiio.ImageSpec(384, 256, 1, oiio.UINT8)
    mo = oiio.ImageOutput.create(str(tmp_path / "mask.png"))
    mo.open(str(tmp_path / "mask.png"), spec)
    mo.write_image(mask[..., None])
    mo.close()
    proc = run_cli("apply", profile_path, src, "-o", out, "--mask", tmp_path / "mask.png", "-j", "1", "--estimator",
                   "narrowband")
    assert proc.returncode == 0, proc.stderr
    rows2 = (out / "roi_stats.csv").read_text().splitlines()
    assert [r.split(",")[:6] for r in rows2[1:]] == [r.split(",")[:6] for r in rows[1:]]


def test_bad_roi_and_profile(tmp_path, photos, profile_path):
    with pytest.raises(CamcalError, match="x,y,w,h"):
        Region.parse("1,2,3")
    with pytest.raises(CamcalError, match="outside"):
        roi_mask((128, 192), Region(1000, 10, 5, 5))
    proc = run_cli("apply", profile_path, photos[("line", "raw", 100, 4.0)], "-o", tmp_path, "--roi", "a,b")
    assert_one_line_error(proc, "--roi")
    bad = tmp_path / "bad.camcal"
    bad.write_bytes(b"not a profile")
    proc = run_cli("apply", bad, photos[("line", "raw", 100, 4.0)], "-o", tmp_path / "o")
    assert_one_line_error(proc, "bad.camcal")


def test_mask_over_the_pixel_limit_is_refused_before_reading(tmp_path, monkeypatch):
    """The mask reader shares camcal.io.read.open_image: declared size checked before any pixel is read."""
    import OpenImageIO as oiio

    from camcal.apply.photo import read_mask

    path = tmp_path / "mask.png"
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(64, 48, 1, oiio.UINT8))
    out.write_image(np.full((48, 64), 255, np.uint8))
    out.close()
    assert read_mask(path).shape == (48, 64)
    monkeypatch.setenv("CAMCAL_MAX_PIXELS", "1000")
    with pytest.raises(CamcalError, match="above the limit"):
        read_mask(path)


def _reference_raw(frame, plan, notes_dark: bool = True):
    """The RAW chain of the module docstring on whole float64 planes (an independent reading of it)."""
    prof, model = plan.profile, plan.model
    e = frame.exposure
    x = (e.iso * e.exposure_s / e.f_number**2) / (prof.reference_iso / prof.reference_f_number**2)
    planes = frame.planes(np.float64)
    invalid = planes >= frame.white_level_dn
    var = None
    if prof.dark is not None:
        s = e.iso / prof.dark.iso
        ds = prof.dark.dark_current_dn_per_s * e.exposure_s * s
        planes = planes - prof.dark.bias_dn - ds
        invalid |= prof.dark.defects != 0
        var = np.maximum(planes + ds, 0) * plan.gain_dn_per_e * s + read_var_dn2(plan) * s * s
    else:
        planes = planes - frame.black_vector()
    if plan.flat_planes is not None:
        planes = planes / plan.flat_planes
        var = None if var is None else var / plan.flat_planes**2
    planes[invalid] = np.nan
    g = np.where(invalid[1], planes[2], np.where(invalid[2], planes[1], 0.5 * (planes[1] + planes[2])))
    signal = np.stack([planes[0], g, planes[3]])
    if var is not None:
        vg = np.where(invalid[1], var[2], np.where(invalid[2], var[1], 0.25 * (var[1] + var[2])))
        var = np.stack([var[0], vg, var[3]])
        if plan.prnu_rel is not None:
            var = var + (plan.prnu_rel * signal) ** 2
    w = np.asarray(model.weights, float)[:, None, None] / x
    used = np.asarray(model.weights) != 0
    value = np.sum(signal[used] * w[used], axis=0)
    noise = np.zeros_like(value) if var is None else np.sum(var[used] * w[used] ** 2, axis=0)
    rel = np.hypot(model.weights_unc_rel, model.spectral_unc_rel)  # c(λ) ⊕ the spectral reconstruction (smooth)
    unc = np.sqrt(noise + (value * rel) ** 2)
    k = 1 / x / np.asarray(model.band_integral)[:, None, None]
    band = signal * k
    name = radiance_channel_name(model.wavelength_nm, model.in_band)
    out = {"R": band[0], "G": band[1], "B": band[2], name: value, f"{name}_unc": unc}
    if var is not None:  # the band noise maps: the same variance, through the band's own scale
        band_unc = np.sqrt(var) * k
        out.update({"R_unc": band_unc[0], "G_unc": band_unc[1], "B_unc": band_unc[2]})
    return out


@pytest.mark.parametrize("variant", ["as calibrated", "smooth estimator", "no dark model", "no flat model"])
def test_banded_threaded_raw_path_matches_whole_frame_reference(photos, profile, monkeypatch, variant):
    """The RAW hot path runs in row bands on threads; uneven bands, 1 or 3 threads: same numbers as
    the whole-frame formula (float32 arithmetic against float64: rel 1e-5), identical across threads."""
    import dataclasses

    import camcal.apply.photo as ap

    prof = {"no dark model": dataclasses.replace(profile, dark=None),
            "no flat model": dataclasses.replace(profile, flat=None)}.get(variant, profile)
    plan = prepare(prof, estimator="smooth" if variant == "smooth estimator" else "narrowband")
    assert variant != "smooth estimator" or all(w != 0 for w in plan.model.weights)  # every channel enters
    assert variant != "as calibrated" or plan.prnu_rel is not None  # the PRNU term is exercised
    monkeypatch.setattr(ap, "BAND_ROWS", 7)  # 128 rows: 18 full bands and a short one
    frame = load_frame(photos["dim"][0])
    one = ap.apply_prepared(frame, plan, threads=1)
    three = ap.apply_prepared(frame, plan, threads=3)
    ref = _reference_raw(frame, plan)
    for name, want in ref.items():
        got = one.channels[name]
        assert np.array_equal(got, three.channels[name], equal_nan=True), name
        assert np.array_equal(np.isnan(got), np.isnan(want)), name
        ok = np.isfinite(want)
        np.testing.assert_allclose(got[ok], want[ok], rtol=1e-5, atol=1e-7 * np.nanmax(np.abs(want)), err_msg=name)
    if variant == "no dark model":
        assert any("no dark model" in n for n in one.metadata["notes"])


def test_exr_of_interleaved_channels_is_written_without_reordering(tmp_path, photos, profile):
    """apply's channels are views of one (h, w, 5) array; the EXR holds each under its own name."""
    from camcal.io.exr import interleaved, write_exr

    img = apply(load_frame(photos[("line", "raw", 100, 4.0)]), profile)
    arrays = list(img.channels.values())
    assert interleaved(arrays) is not None and interleaved(arrays[::-1]) is None
    write_exr(tmp_path / "a.exr", img.channels, compression="zip")
    write_exr(tmp_path / "b.exr", {k: np.array(v) for k, v in reversed(img.channels.items())}, compression="zip")
    a, _ = read_exr(tmp_path / "a.exr")
    b, _ = read_exr(tmp_path / "b.exr")
    for k in img.channels:
        assert np.array_equal(a[k], img.channels[k], equal_nan=True)
        assert np.array_equal(b[k], img.channels[k], equal_nan=True)


def test_camcal_threads_environment(monkeypatch, tmp_path, photos, profile_path):
    """CAMCAL_THREADS sets the threads of one photo's arithmetic; a bad value refuses the batch (exit 2)."""
    from camcal.apply.photo import default_threads

    monkeypatch.setenv("CAMCAL_THREADS", "3")
    assert default_threads() == 3
    monkeypatch.setenv("CAMCAL_THREADS", "0")
    assert default_threads() == 1
    monkeypatch.delenv("CAMCAL_THREADS")
    assert 1 <= default_threads() <= 4
    monkeypatch.setenv("CAMCAL_THREADS", "many")
    with pytest.raises(CamcalError, match="CAMCAL_THREADS"):
        default_threads()
    proc = run_cli("apply", profile_path, photos[("line", "raw", 100, 4.0)], "-o", tmp_path / "out",
                   env={"CAMCAL_THREADS": "many"})
    assert_one_line_error(proc, "CAMCAL_THREADS")
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_relative_profile_gives_relative_radiance_for_ratios(photos, profile):
    """A relative c(λ) (imported curves without targets, a sweep without its reference detector) still serves a
    ratio: every map is relative radiance, labelled so, and the ratio of two photos equals the absolute one."""
    from dataclasses import replace

    from camcal.apply.photo import RELATIVE_UNITS
    from camcal.models.spectral import to_relative

    rel = replace(profile, spectral=to_relative(profile.spectral))
    a_line = apply(load_frame(photos[("line", "raw", 100, 4.0)]), profile)
    a_dim = apply(load_frame(photos["dim"][0]), profile)
    r_line = apply(load_frame(photos[("line", "raw", 100, 4.0)]), rel)
    r_dim = apply(load_frame(photos["dim"][0]), rel)
    assert r_line.metadata["radiance_scale"] == "relative" and a_line.metadata["radiance_scale"] == "absolute"
    assert r_line.metadata["units"]["R"] == RELATIVE_UNITS and r_line.metadata["units"]["L663"] == RELATIVE_UNITS
    assert any("relative radiance" in n for n in r_line.metadata["notes"])
    # the scale cancels: float32 maps, ~1e-6 relative
    assert mean(r_dim.channels["R"]) / mean(r_line.channels["R"]) == pytest.approx(
        mean(a_dim.channels["R"]) / mean(a_line.channels["R"]), rel=1e-5)
    assert not mean(r_line.channels["R"]) == pytest.approx(mean(a_line.channels["R"]), rel=0.5)


def test_no_spectral_names_the_next_step(profile):
    from dataclasses import replace

    bias_only = replace(profile, spectral=None, flat=None, response=None)
    with pytest.raises(CamcalError, match="monochromator sweep"):
        prepare(bias_only, 663.0)
    imported = replace(profile, spectral=replace(profile.spectral, mode="relative",
                                                 source={"kind": "imported", "file": "c.csv"}))
    assert "--targets" in next_step_for_c(imported)


def test_uniform_grey_scene_l663_is_its_spectral_radiance(tmp_path, profile_path):
    """A uniform 0.02 W m⁻² sr⁻¹ nm⁻¹ grey scene (`camcal synth photo`) through `camcal apply`: L663 is a spectral
    radiance (per nm) from the default estimator and lies within its stated 2σ (noise ⊕ c(λ) ⊕ the spectral
    reconstruction) of 0.02; the console names the estimator and the spectral term."""
    photo = tmp_path / "grey.dng"
    assert run_cli("synth", "photo", photo, "--scene", "uniform", "--radiance", "0.02").returncode == 0
    proc = run_cli("apply", profile_path, photo, "-o", tmp_path / "out", "-j", "1")
    assert proc.returncode == 0, proc.stderr
    assert "L663: spectral radiance" in proc.stdout and "spectral reconstruction" in proc.stdout, proc.stdout
    chans, meta = read_exr(tmp_path / "out" / "grey.dng.exr")
    assert meta["units"]["L663"] == "W m⁻² sr⁻¹ nm⁻¹" and meta["options"]["estimator"] == "auto"
    assert meta["estimator"] in ("trained", "smooth") and meta["spectral_unc_rel"] > 0
    value, sigma = float(np.nanmedian(chans["L663"])), float(np.nanmedian(chans["L663_unc"]))
    assert abs(value - 0.02) <= 2 * sigma, (value, sigma)
    assert sigma >= meta["spectral_unc_rel"] * value  # the spectral term is in the stated σ
    for ch in "RGB":  # a flat spectrum: every band radiance is the spectral radiance itself
        assert float(np.nanmedian(chans[ch])) == pytest.approx(0.02, rel=0.01), ch


# ---- a monochrome sensor: band radiance Y -------------------------------------------------------------------------
def test_monochrome_session_calibrate_then_apply_gives_y_within_2_sigma(tmp_path):
    """One plane of the synthetic camera as one-sample LinearRaw DNGs: calibrate (dark, flat, linearity) with the
    plane's true c(λ) as its spectral sensitivity, then ``camcal apply`` on a uniform scene of known radiance: the
    band radiance Y = ∫L c dλ / ∫c dλ within 2σ of its mean over a centre ROI, and no L663 (one broad channel)."""
    import dataclasses

    from camcal.calibrate.run import CalibrateOptions, calibrate_session
    from camcal.cli import main
    from camcal.models.profile import save_profile
    from camcal.models.spectral import ABSOLUTE_UNITS, SpectralSensitivity
    from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
    from camcal.synth.dng import encode_mono_dng
    from camcal.synth.session import _white_spectrum, exposure_for_level

    cam = SyntheticCamera(SensorParams(width=128, height=96, prnu_sigma=0.005, hot_pixel_fraction=0.0))
    p = cam.params
    rng = np.random.default_rng(11)
    spec = _white_spectrum(5000.0)

    def shoot(path, t, scene):
        path.parent.mkdir(parents=True, exist_ok=True)
        planes = cam.expose_planes(scene, exposure_s=t, rng=rng)
        path.write_bytes(encode_mono_dng(planes[1], black_level_dn=p.black_level_dn[1], white_level_dn=p.white_dn,
                                         exposure_s=t, f_number=4.0, iso=100))

    for t in (1 / 4000, 2.0, 8.0):
        for i in range(3):
            shoot(tmp_path / "S" / "dark" / f"d_{t:g}_{i}.dng", t, Scene.dark())
    t_flat = exposure_for_level(cam, spec, 0.45, 100, 4.0)
    for i in range(8):
        shoot(tmp_path / "S" / "flat" / f"f_{i}.dng", t_flat, Scene.uniform(spec))
    profile, _ = calibrate_session(tmp_path / "S", CalibrateOptions(reference_iso=100, reference_f_number=4.0))
    c = cam.spectral_sensitivity(100, 4.0)[1]  # the G plane's true c(λ) at the reference setting
    sens = SpectralSensitivity(WAVELENGTHS_NM, {"Y": c}, {"Y": 0.002 * c}, ABSOLUTE_UNITS, "absolute", 100.0, 4.0)
    save_profile(dataclasses.replace(profile, spectral=sens), tmp_path / "mono.camcal")
    scene = 1.7 * spec
    t = exposure_for_level(cam, scene, 0.4, 100, 4.0)
    shoot(tmp_path / "photo.dng", t, Scene.uniform(scene))
    assert main(["apply", str(tmp_path / "mono.camcal"), str(tmp_path / "photo.dng"), "-o", str(tmp_path / "out"),
                 "--roi", "16,12,32,24"]) == 0
    img = read_exr(next((tmp_path / "out").glob("*.exr")))
    ch = img[0]
    assert set(ch) == {"Y", "Y_unc"}
    truth = float(np.trapezoid(scene * c, WAVELENGTHS_NM) / np.trapezoid(c, WAVELENGTHS_NM))
    y, u = ch["Y"][12:36, 16:48], ch["Y_unc"][12:36, 16:48]  # the 64x48 plane's centre
    assert abs(np.nanmean(y) - truth) < 2 * np.nanmean(u) / np.sqrt(np.isfinite(y).sum()) + 0.004 * truth
    assert np.nanstd(y) == pytest.approx(np.nanmean(u), rel=0.15)  # the stated σ is the pixels' scatter
    with pytest.raises(CamcalError, match="one channel"):
        prepare(dataclasses.replace(profile, spectral=sens), estimator="smooth")
    filt = prepare(dataclasses.replace(profile, spectral=sens), estimator="narrowband", filter_fwhm_nm=10.0)
    assert filt.model.weights[0] == pytest.approx(1 / (10.0 * np.interp(663.0, WAVELENGTHS_NM, c)), rel=1e-3)
    # the profile reads as a one-channel profile everywhere: its summary has a Y column, its report renders
    shown = run_cli("profile", "show", tmp_path / "mono.camcal")
    assert shown.returncode == 0, shown.stderr
    header = next(line for line in shown.stdout.splitlines() if "quantity" in line)
    assert "Y" in header and " R " not in header
    report = run_cli("report", tmp_path / "mono.camcal", "-o", tmp_path / "mono.html")
    assert report.returncode == 0, report.stderr
    html = (tmp_path / "mono.html").read_text()
    assert "u(Y)" in html and "u(R)" not in html  # the c(λ) table of the one channel


@pytest.mark.formula
def test_long_dim_photo_at_f8_gives_the_true_radiance(tmp_path, camera, profile_path):
    """A 30 s photo at f/8 (the profile's reference is f/4), 5 % of full scale: the dark current of 30 s
    is ≈ 60 e⁻ per pixel against a signal of a few hundred, so it must be scaled by the frame's own exposure
    time (the relative exposure is 7.5 s here; scaling by it leaves the photo 4 % too bright).

    Truth: the scene's in-band radiance, 2 W m⁻² sr⁻¹ times the dimming. Tolerance 1 %: the noise of the
    frame mean is < 0.05 % (24 576 cells), the dark model's β error over 30 s < 0.3 % of the signal,
    c(λ0) ≈ 0.05 %.
    """
    profile = load_profile(profile_path)
    assert profile.reference_f_number == 4.0
    line = LINE_BAND_W_M2_SR * gaussian_line(663.0, 5.0)
    t = 30.0
    scale = exposure_for_level(camera, line, 0.05, 100, 8.0) / t
    p = tmp_path / "dim_30s_f8.dng"
    camera.write_dng(p, Scene.uniform(line * scale), exposure_s=t, iso=100, f_number=8.0,
                     rng=np.random.default_rng(29))
    got = float(np.nanmean(apply(load_frame(p), profile, 663.0, "narrowband").channels["L663_inband"]))
    assert got == pytest.approx(LINE_BAND_W_M2_SR * scale, rel=0.01)

"""``camcal demo``: the whole pipeline on synthetic data, with truth against recovered values.

1. synthesise a calibration session (bias, dark, flat, linearity RAW+JPEG, monochromator sweep) from a
   camera with the NPL-measured Nikon D5100 spectral sensitivities;
2. calibrate it into a profile and write the HTML report;
3. synthesise two survey photos of a Secchi disk in daylight (CIE D65): the reference disk above water
   and the disk submerged at a known depth in water with a known chlorophyll-a concentration; and a sunlit pair
   (:mod:`camcal.synth.sunlit`: SPECTRL2 sun and sky, surface glare) in ``survey/sunlit/``, read by
   :func:`camcal.water.secchi.run_secchi`;
4. apply the profile: radiance EXRs (band radiance R, G, B and L663);
5. invert the red-band ratio per pixel for chlorophyll-a with the band-aware model built from the
   profile's measured c_R(λ) (Bricaud et al. 1998 absorption, Pope & Fry 1997 water);
6. print a table of truth against recovered values for every stage, with the tolerances of the stage issues.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.table import Table

from camcal.apply.batch import BatchOptions, run_batch
from camcal.calibrate.run import calibrate_session
from camcal.errors import CamcalError
from camcal.io.exr import read_exr, write_exr
from camcal.io.terminal import console, progress
from camcal.models.profile import contract, save_profile
from camcal.report.page import write_report
from camcal.synth.camera import LINEAR_FROM_PLANES, SyntheticCamera, frame_rngs, preset
from camcal.synth.secchi import secchi_scenes, suggest_exposure_s
from camcal.synth.session import SessionPlan, write_session
from camcal.synth.sunlit import SunSky, write_sunlit_survey
from camcal.units import CONCENTRATION, DN_PER_ELECTRON, DN_PER_S
from camcal.water.band import BandInverse, band_model_from_profile
from camcal.water.field import ClearSky, FieldGeometry
from camcal.water.secchi import run_secchi

CHL_UG_PER_L = 60.0
DEPTH_M = 0.80
#: The sun of the sunlit Secchi photos (survey/sunlit/), degrees.
SUNLIT_ZENITH_DEG = 35.0
SUNLIT_AZIMUTH_DEG = 160.0


@dataclass(frozen=True)
class Check:
    """One row of the demo table: a recovered value against the truth and the stage tolerance."""

    stage: str
    quantity: str
    truth: float
    recovered: float
    tolerance: float
    relative: bool = True

    @property
    def error(self) -> float:
        d = self.recovered - self.truth
        return d / self.truth if self.relative else d

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.recovered) and abs(self.error) <= self.tolerance)


def checks_table(title: str, checks: list[Check], absolute_bound: str = "±") -> Table:
    """The demo's table of truth against recovered: one row per :class:`Check`, its error and tolerance (relative
    in %, else absolute with ``absolute_bound``, ``±`` or ``≤``) and a tick or a cross."""
    table = Table(title=title, title_justify="left", pad_edge=False)
    for col in ("stage", "quantity", "truth", "recovered", "error", "tolerance", ""):
        table.add_column(col, justify="left" if col in ("stage", "quantity") else "right")
    for c in checks:
        err = f"{100 * c.error:+.2f}%" if c.relative else f"{c.error:+.2g}"
        tol = f"±{100 * c.tolerance:g}%" if c.relative else f"{absolute_bound}{c.tolerance:g}"
        table.add_row(c.stage, c.quantity, f"{c.truth:.4g}", f"{c.recovered:.4g}", err, tol,
                      "[green]✓[/green]" if c.ok else "[red]✗[/red]")
    return table


def _checks(truth: dict, contract: dict, survey: dict, vignetting_error: float) -> list[Check]:
    rows: list[Check] = []
    d = contract["dark"]
    for ch in ("R", "G", "B"):
        planes = ("G1", "G2") if ch == "G" else (ch,)
        t = float(np.mean([truth["dark_current_dn_per_s"][p] for p in planes]))
        rows.append(Check("dark", f"β {ch} ({DN_PER_S})", t, d["dark_current_dn_per_s"][ch], 0.02))
    t = float(np.mean(list(truth["read_noise_dn"].values())))
    rows.append(Check("dark", "read noise G (DN)", t, d["read_noise_dn"]["G"], 0.03))
    linear = contract["camera"].get("layout") == "linear"
    # a linear frame holds the camera's R, G1 and B planes (truth.json "layout"): its hot pixels are those
    hot = (sum(1 for c, _, _ in truth["hot_pixels"] if c in LINEAR_FROM_PLANES) if linear
           else truth["hot_pixel_count"])
    rows.append(Check("dark", "hot pixels", hot, d["hot_pixel_count"], 0.05))
    e = contract.get("emva1288")
    if e:  # the linearity series is shot in pairs: K by EMVA 1288 photon transfer
        g = e["channels"].get("G1") or e["channels"]["G"]
        rows.append(Check("emva", f"K G ({DN_PER_ELECTRON})", 1.0 / truth["gain_e_per_dn_at_iso"], g["K_dn_per_e"],
                           0.03))
    f = contract["flat"]
    # the vignetting model against the camera's own map, its largest error over every pixel of every plane
    rows.append(Check("flat", "vignetting max error", 0.0, vignetting_error, 0.005, relative=False))
    cx, _ = truth["vignetting"]["centre_px"]
    if contract["camera"].get("layout") == "linear":  # linear frames are the R, G1, B planes: G1's centre
        cx = truth["vignetting"]["centre_half_px"]["G1"][0]
    rows.append(Check("flat", "centre x (px)", cx, float(np.mean([v[0] for v in f["centre_full_px"].values()])),
                      2.0, relative=False))
    r = contract["response"]
    rows.append(Check("response", "γ RAW G", 1.0, r["gamma"]["G"], 0.005))
    if "processed" in r["models"]:
        rows.append(Check("response", "γ JPEG G (sRGB 1/2.4)", 1 / 2.4, r["models"]["processed"]["gamma"]["G"], 0.01))
    s = contract["spectral_sensitivity"]
    wl_true = np.asarray(truth["spectral_sensitivity"]["wavelength_nm"])
    for ch in ("R", "G", "B"):
        true = np.interp(s["wavelength_nm"], wl_true, truth["spectral_sensitivity"][ch])
        rms = float(np.sqrt(np.mean((np.asarray(s[ch]) - true) ** 2)) / true.max())
        rows.append(Check("sweep", f"c_{ch}(λ) RMS/peak", 0.0, rms, 0.03, relative=False))
    rows.append(Check("apply", "disk L_R (W/m²/sr/nm)", survey["true_band_R"],
                      survey["band_R"], 0.03))
    rows.append(Check("apply", "ratio sub/ref R", survey["true_ratio"], survey["ratio"], 0.03))
    rows.append(Check("water", f"chl-a ({CONCENTRATION})", survey["true_chl"], survey["chl"], 0.05))
    return rows


def run_demo(out: str | Path, *, size: tuple[int, int] = (384, 256), preset_name: str = "default",
             layout: str = "bayer") -> dict:
    """Run the demo into ``out``; returns ``{"checks": [...], "ok": bool, "files": {...}, "seconds": s}``.

    ``preset_name`` picks the synthetic camera (:data:`camcal.synth.camera.PRESETS`: its bit depth, black
    levels, noise and defects) at the demo's ``size`` (the full IMX296 geometry would take minutes).
    ``layout="linear"`` shoots every frame and photo as a LinearRaw DNG (R, G, B planes) instead of a mosaic.
    """

    t0 = time.perf_counter()
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CamcalError("is a file, not a folder; give --out a folder for the demo's files", out)
    out.mkdir(parents=True, exist_ok=True)
    cam = SyntheticCamera(preset(preset_name, width=size[0], height=size[1]))
    with progress() as bar:
        tasks: dict[str, int] = {}

        def tick(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done, total=total)

        session = write_session(out / "session", cam, SessionPlan(layout=layout, linearity_repeats=2),
                                progress=lambda s, d, n: tick(f"synthesise {s}", d, n))
        profile, notes = calibrate_session(session, progress=lambda s, d, n: tick(f"calibrate {s}", d, n))
        profile = save_profile(profile, out / "camera.camcal")
        write_report(profile, out / "report.html")

        # survey photos of a Secchi disk
        scenes = secchi_scenes(cam, c_ug_per_L=CHL_UG_PER_L, depth_m=DEPTH_M)
        survey = out / "survey"
        rng_ref, rng_sub = frame_rngs(cam.params.seed, 2, 99)
        t_ref = suggest_exposure_s(cam, scenes.reference_radiance, fill=0.5)
        t_sub = suggest_exposure_s(cam, scenes.submerged_radiance, fill=0.5)
        ref_path = cam.write_dng(survey / "disk_reference.dng", scenes.reference, exposure_s=float(f"{t_ref:.3g}"),
                                 rng=rng_ref, layout=layout)
        sub_path = cam.write_dng(survey / "disk_submerged.dng", scenes.submerged, exposure_s=float(f"{t_sub:.3g}"),
                                 rng=rng_sub, layout=layout)
        report = run_batch(out / "camera.camcal", [ref_path, sub_path], out / "radiance", BatchOptions(), jobs=1,
                           progress=lambda d, n, _r: tick("apply", d, n))
        if report.failed:
            raise RuntimeError(f"demo photos failed: {[r.error for r in report.failed]}")
        ref, _ = read_exr(out / "radiance" / "disk_reference.dng.exr", ["R"])
        sub, _ = read_exr(out / "radiance" / "disk_submerged.dng.exr", ["R"])

        # chlorophyll-a per pixel from the red-band ratio
        inverse = BandInverse(band_model_from_profile(profile, "R"), DEPTH_M)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = sub["R"] / ref["R"]
        inv = inverse.concentration(ratio, sigma_ln_ratio=0.01)
        write_exr(out / "chlorophyll.exr", {"chl_ug_per_L": inv.c_ug_per_L, "chl_unc_ug_per_L": inv.sigma_ug_per_L,
                                            "reason": inv.reason.astype(np.float32)},
                  {"units": CONCENTRATION, "depth_m": DEPTH_M, "model": "band-aware, refined geometry, profile c_R"})
        tick("water", 1, 1)

        # sunlit Secchi photos (SPECTRL2 sun and sky, surface glare), read by `camcal secchi`'s stage
        sunlit = write_sunlit_survey(survey / "sunlit", cam, sky=SunSky(SUNLIT_ZENITH_DEG, SUNLIT_AZIMUTH_DEG),
                                     depths_m=[DEPTH_M], c_ug_per_L=CHL_UG_PER_L, rng=frame_rngs(cam.params.seed, 1,
                                                                                                  45)[0])
        files_sun = sunlit["shots"][0]["files"]
        sec = run_secchi(out / "camera.camcal", files_sun["ref"]["dng"], [files_sun["sub"]["dng"]], [(DEPTH_M, 0.0)],
                         sky=ClearSky(SUNLIT_ZENITH_DEG), geometry=FieldGeometry(), inputs=[])
        tick("secchi", 1, 1)

    # the disk region at half resolution, away from its edge
    weight = scenes.weight[::2, ::2]
    disk = weight > 0.99
    h, w = disk.shape
    yy, xx = np.mgrid[0:h, 0:w]
    cx, cy = (w - 1) / 2, (h - 1) / 2
    core = disk & (np.hypot(xx - cx, yy - cy) < 0.6 * scenes.truth["disk_radius_px"] / 2)
    c_true = cam.spectral_sensitivity()[0]
    wl = scenes.wavelengths_nm
    true_band_r = float(np.trapezoid(c_true * scenes.reference_radiance, wl) / np.trapezoid(c_true, wl))
    survey_vals = {
        "band_R": float(np.nanmedian(ref["R"][core])),
        "true_band_R": true_band_r,
        "ratio": float(np.nanmedian(ratio[core])),
        "true_ratio": float(scenes.truth["rendered_red_band_ratio"]),  # what the camera saw
        "chl": float(np.nanmedian(inv.c_ug_per_L[core])),
        "true_chl": CHL_UG_PER_L,
    }
    truth = json.loads((session / "truth.json").read_text())
    planes = list(LINEAR_FROM_PLANES) if layout == "linear" else [0, 1, 2, 3]
    vig = float(np.max(np.abs(profile.flat.gain() / cam.vignetting_map[planes] - 1)))
    checks = _checks(truth, contract(profile), survey_vals, vig)
    checks.append(Check("secchi", f"chl-a sunlit ({CONCENTRATION})", CHL_UG_PER_L, sec.c_ug_per_L, 0.03))

    console.print(checks_table(f"camcal demo: truth against recovered (chl-a {CHL_UG_PER_L:g} {CONCENTRATION} at "
                               f"{100 * DEPTH_M:g} cm)", checks))
    for n in notes:
        console.print(f"note: {n}")
    seconds = time.perf_counter() - t0
    files = {"session": session, "profile": out / "camera.camcal", "report": out / "report.html",
             "photos": survey, "radiance": out / "radiance", "chlorophyll": out / "chlorophyll.exr"}
    for k, v in files.items():
        console.print(f"{k:12s} {v}")
    ok = all(c.ok for c in checks)
    console.print(f"{'all checks within tolerance' if ok else 'SOME CHECKS FAILED'} — {seconds:.0f} s")
    return {"checks": checks, "ok": ok, "files": files, "seconds": seconds}

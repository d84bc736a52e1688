"""``camcal demo --phone``: a phone and no lab, from a chart in the sun to chlorophyll-a, truth against recovered.

1. the synthetic phone's field day (:func:`camcal.synth.phone.write_phone_photos`: measured phone-sensor curves
   not in the bundled library, a measured chart that is not the nominal one, cos⁴ vignetting, DNG + HEIC
   through white balance, colour matrix and tone curve): the chart at two exposures, flats, a grey field,
   Secchi-disk photos;
2. ``camcal chart --ir-cut 650±10``: the chart's DNG + HEIC twins and the flats into a profile (c(λ) under the
   clear-sky sun of the photos' GPS time and place; the HEIC's tone curve and colour matrix), the module's IR cut
   from its datasheet (a chart cannot see it beyond ~640 nm: docs/spectral.md); the chart alone is run too and
   its chlorophyll printed beside;
3. ``camcal apply``: the grey field's band radiance at the image centre (DNG and HEIC) against the truth;
4. ``camcal secchi``: chlorophyll-a from the disk photos (DNG and HEIC) with σ_C, against the truth, in a lake of
   :data:`LAKE_C_UG_PER_L` (at 5 µg/L the same profiles err by the same ~0.5-1 µg/L, 10-20 %: the user guide's
   table).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from camcal.apply.photo import apply
from camcal.chart.profile_build import ChartOptions, build_chart_profile
from camcal.demo.lab import Check, checks_table
from camcal.errors import CamcalError
from camcal.io.read import load_frame
from camcal.io.sun import photo_sun
from camcal.io.terminal import console, progress
from camcal.models.profile import save_profile
from camcal.synth.phone import write_phone_photos
from camcal.units import CONCENTRATION
from camcal.water.field import DEFAULT_AOD_500NM, ClearSky, FieldGeometry
from camcal.water.secchi import run_secchi
from camcal.water.uncertainty import Uncertain

#: Tolerances of the phone route (docs/user-guide.md, "A phone in the field").
GREY_TOLERANCE = 0.03
CHL_TOLERANCE = {"dng": 0.05, "heic": 0.10}
#: The demo lake's chlorophyll-a, µg/L (mesotrophic).
LAKE_C_UG_PER_L = 20.0
#: The synthetic module's IR-cut filter as its datasheet would state it: half transmission and 1-σ, nm.
DATASHEET_IR_CUT_NM = (650.0, 10.0)


def _secchi(profile: Path, folder: Path, ext: str, truth: dict) -> tuple[float, float]:
    shots = truth["secchi"]["shots"]
    ref = folder / f"d{shots[0]['depth_m']:g}m_ref.{ext}"
    subs = [folder / f"d{s['depth_m']:g}m_sub.{ext}" for s in shots]
    sun = photo_sun(ref)
    zen = sun.apparent_zenith_deg
    inputs = [Uncertain("sun_zenith", zen, 0.5, "deg"), Uncertain("aerosol", DEFAULT_AOD_500NM, 0.05, "AOD"),
              Uncertain("diffuse_fraction", 1.0, 0.2, "relative")]
    res = run_secchi(profile, ref, subs, [(float(s["depth_m"]), 0.005) for s in shots], sky=ClearSky(zen),
                     geometry=FieldGeometry(), inputs=inputs,
                     sun_zeniths_deg=[photo_sun(p).apparent_zenith_deg for p in subs])
    return res.c_ug_per_L, res.sigma_ug_per_L


def run_phone_demo(out: str | Path) -> dict:
    """Run the phone demo into ``out``; returns ``{"checks": [...], "ok": bool, "files": {...}, "seconds": s}``."""
    t0 = time.perf_counter()
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CamcalError("is a file, not a folder; give --output a folder for the demo's files", out)
    out.mkdir(parents=True, exist_ok=True)
    day = out / "phone"
    checks: list[Check] = []
    with progress() as bar:
        task = bar.add_task("synthesise the phone's day", total=5)
        truth = write_phone_photos(day, c_ug_per_L=LAKE_C_UG_PER_L)
        bar.update(task, advance=1, description="camcal chart")
        photos = [day / s["files"][ext] for s in truth["chart"]["shots"] for ext in ("dng", "heic")]
        flats = tuple(day / s["files"]["dng"] for s in truth["flat"]["shots"])
        res = build_chart_profile(photos, ChartOptions(flat=flats, ir_cut=DATASHEET_IR_CUT_NM))
        profile = save_profile(res.profile, out / "phone.camcal")
        save_profile(build_chart_profile(photos, ChartOptions(flat=flats)).profile, out / "phone_chart_only.camcal")
        bar.update(task, advance=1, description="camcal apply (grey field)")
        grey = truth["grey"]
        for ext in ("dng", "heic"):
            img = apply(load_frame(day / grey["files"][ext]), profile)
            h, w = img.shape
            centre = (slice(h // 2 - 10, h // 2 + 10), slice(w // 2 - 10, w // 2 + 10))
            for ch in "RGB":
                checks.append(Check(f"apply {ext.upper()}", f"grey field band radiance {ch} at the centre",
                                    float(grey["band_radiance"][ch]), float(np.nanmean(img.channels[ch][centre])),
                                    GREY_TOLERANCE))
        bar.update(task, advance=1, description="camcal secchi")
        c_true = float(truth["secchi"]["c_ug_per_L"])
        sigmas = {}
        chart_only: dict[str, tuple[float, float]] = {}
        for ext in ("dng", "heic"):
            c, sigma = _secchi(out / "phone.camcal", day / "secchi", ext, truth)
            sigmas[ext] = sigma
            checks.append(Check(f"secchi {ext.upper()}", f"chlorophyll-a ({CONCENTRATION})", c_true, c,
                                CHL_TOLERANCE[ext]))
            checks.append(Check(f"secchi {ext.upper()}", "|C − truth| / σ_C (≤ 2)", 0.0,
                                abs(c - c_true) / sigma if sigma > 0 else float("inf"), 2.0, relative=False))
            chart_only[ext] = _secchi(out / "phone_chart_only.camcal", day / "secchi", ext, truth)
        bar.update(task, advance=2)
    console.print(checks_table(f"camcal demo --phone: a chart in the sun, then the lake (chl-a {c_true:g} "
                               f"{CONCENTRATION})", checks, absolute_bound="≤"))
    cut, u_cut = DATASHEET_IR_CUT_NM
    console.print(f"c(λ) with the module's datasheet IR cut {cut:g} ± {u_cut:g} nm; the chart alone (no --ir-cut): "
                  + ", ".join(f"{e.upper()} {c:.2f} ± {u:.2f} {CONCENTRATION}" for e, (c, u) in chart_only.items()),
                  highlight=False)
    rms = res.recovered.term_rms_pct_of_peak()
    console.print("c(λ) from the chart: u(c) RMS % of peak " + ", ".join(f"{p} {v['total']:.2g}"
                                                                        for p, v in rms.items()), highlight=False)
    for wtext in res.warnings:
        console.print(f"note: {wtext}", soft_wrap=True, highlight=False)
    seconds = time.perf_counter() - t0
    files = {"photos": day, "truth": day / "truth.json", "profile": out / "phone.camcal",
             "chart only": out / "phone_chart_only.camcal"}
    for k, v in files.items():
        console.print(f"{k:12s} {v}")
    ok = all(c.ok for c in checks)
    console.print(f"{'all checks within tolerance' if ok else 'SOME CHECKS FAILED'} — {seconds:.0f} s")
    (out / "phone_demo.json").write_text(json.dumps(
        {"checks": [{"stage": c.stage, "quantity": c.quantity, "truth": c.truth, "recovered": c.recovered,
                     "error": c.error, "tolerance": c.tolerance, "ok": c.ok} for c in checks],
         "sigma_ug_per_L": sigmas,
         "chart_only": {e: {"c_ug_per_L": c, "sigma_ug_per_L": u} for e, (c, u) in chart_only.items()}}, indent=1))
    return {"checks": checks, "ok": ok, "files": files, "seconds": seconds}

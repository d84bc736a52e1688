"""Accuracy of ``run_rrs`` on synthetic stations (clear, turbid, green × two suns × seeds), ρ of a uniform sky
against ρ of the CIE standard clear sky. Usage:
``python benchmarks/bench_rrs_stations.py PROFILE.camcal [SEEDS]`` (the demo's profile: ``camcal demo -o D``), or
``python benchmarks/bench_rrs_stations.py phone [SEEDS]``: the synthetic phone (:class:`camcal.synth.phone.
PhoneCamera`) photographs the stations, and its profile is made as a phone user makes one, by ``camcal chart``
from its sunlit chart photos (DNG twins of the HEICs and three flats, no IR cut given)."""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from camcal.chart.profile_build import ChartOptions, build_chart_profile
from camcal.io.sun import photo_sun
from camcal.models.profile import save_profile
from camcal.synth.camera import SensorParams, SyntheticCamera
from camcal.synth.phone import PhoneCamera, write_phone_photos
from camcal.synth.station import place_at, write_station
from camcal.water.products import SPM_NECHAD_2010, TURBIDITY_DOGLIOTTI_2015, product
from camcal.water.rrs_photos import run_rrs

SUNS = {"high": "2026-06-21T11:40:00Z", "low": "2026-06-21T16:40:00Z"}


def phone_profile(folder: Path) -> Path:
    """The chart profile of the synthetic phone: ``camcal chart`` on its sunlit chart DNGs with its DNG flats."""
    truth = write_phone_photos(folder / "day", formats=("dng",), depths_m=(1.0,))
    photos = [folder / "day" / s["files"]["dng"] for s in truth["chart"]["shots"]]
    flats = tuple(folder / "day" / s["files"]["dng"] for s in truth["flat"]["shots"])
    out = folder / "phone.camcal"
    save_profile(build_chart_profile(photos, ChartOptions(flat=flats)).profile, out)
    return out


def main(profile: str, seeds: int = 8) -> None:
    counts = {m: {"rrs": 0, "ratio": 0, "cover": 0, "product": 0, "n_rrs": 0, "n_ratio": 0, "n_prod": 0}
              for m in ("uniform", "cie")}
    glint = {"named": 0, "clean": 0, "moved": 0.0, "n": 0}
    with tempfile.TemporaryDirectory() as tmp:
        if profile == "phone":
            cam = PhoneCamera()
            profile = str(phone_profile(Path(tmp)))
        else:
            cam = SyntheticCamera(SensorParams())
        for water in ("clear", "turbid", "green"):
            for sun_name, utc in SUNS.items():
                for seed in range(seeds):
                    d = Path(tmp) / f"{water}_{sun_name}_{seed}"
                    write_station(d, cam, water=water, place=place_at(utc), rng=np.random.default_rng([seed, 49]))
                    truth = json.loads((d / "truth.json").read_text())
                    t = truth["rrs_per_sr"]
                    for m, c in counts.items():
                        st = run_rrs(profile, sorted(d.glob("water_*.dng")), sorted(d.glob("sky_*.dng")),
                                     [d / "card.dng"], sun=photo_sun(d / "card.dng"), sky_model=m)
                        r, s = st.result.rrs, st.result.sigma
                        for b in "RGB":
                            c["n_rrs"] += 1
                            c["rrs"] += abs(r[b] - t[b]) <= max(0.05 * t[b], 2e-4)
                            c["cover"] += abs(r[b] - t[b]) <= 2 * s[b]
                        for k, (num, den) in {"B/G": ("B", "G"), "G/R": ("G", "R")}.items():
                            c["n_ratio"] += 1
                            c["ratio"] += abs(st.result.ratios[k][0] / (t[num] / t[den]) - 1) <= 0.02
                        for alg in (TURBIDITY_DOGLIOTTI_2015, SPM_NECHAD_2010):
                            eff = st.effective_wavelength_nm["R"]
                            true = product(alg, t["R"], 0.0, eff).value
                            c["n_prod"] += 1
                            c["product"] += abs(st.products[alg.quantity].value / true - 1) <= 0.05
                        print(water, sun_name, seed, m, f"rho={st.result.rho.value:.4f}", "truth rho_eff="
                              f"{truth['rho_eff']:.4f}", {b: round(r[b] / t[b] - 1, 4) for b in "RGB"}, flush=True)
                        if m == "cie":  # the same station (same noise) with glint in water_2
                            g = d.with_name(d.name + "_glint")
                            write_station(g, cam, water=water, place=place_at(utc), glint_photo=2,
                                          rng=np.random.default_rng([seed, 49]))
                            sg = run_rrs(profile, sorted(g.glob("water_*.dng")), sorted(g.glob("sky_*.dng")),
                                         [g / "card.dng"], sun=photo_sun(g / "card.dng"), sky_model=m)
                            named = [p.name for p in sg.water if p.rejected]
                            glint["named"] += named == ["water_2.dng"]
                            glint["clean"] += not any(p.rejected for p in st.water)
                            move = max(abs(sg.result.rrs[b] - r[b]) / s[b] for b in "RGB")
                            glint["moved"] = max(glint["moved"], move)
                            glint["n"] += 1
    for m, c in counts.items():
        print(f"{m}: Rrs {c['rrs']}/{c['n_rrs']}, 2σ covers {c['cover']}/{c['n_rrs']}, ratios within 2 % "
              f"{c['ratio']}/{c['n_ratio']}, products within 5 % {c['product']}/{c['n_prod']}")
    print(f"glint in water_2 (CIE ρ): only water_2 named and left out {glint['named']}/{glint['n']}, none left out "
          f"without glint {glint['clean']}/{glint['n']}, result moved at most {glint['moved']:.2f} σ")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 8)

"""Accuracy of ``run_rrs`` on synthetic stations (clear, turbid, green × two suns × seeds), ρ of a uniform sky
against ρ of the CIE standard clear sky. Usage:
``python benchmarks/bench_rrs_stations.py PROFILE.camcal [SEEDS]`` (the demo's profile: ``camcal demo -o D``)."""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from camcal.io.sun import photo_sun
from camcal.synth.camera import SensorParams, SyntheticCamera
from camcal.synth.station import place_at, write_station
from camcal.water.products import SPM_NECHAD_2010, TURBIDITY_DOGLIOTTI_2015, product
from camcal.water.rrs_photos import run_rrs

SUNS = {"high": "2026-06-21T11:40:00Z", "low": "2026-06-21T16:40:00Z"}


def main(profile: str, seeds: int = 8) -> None:
    cam = SyntheticCamera(SensorParams())
    counts = {m: {"rrs": 0, "ratio": 0, "cover": 0, "product": 0, "n_rrs": 0, "n_ratio": 0, "n_prod": 0}
              for m in ("uniform", "cie")}
    with tempfile.TemporaryDirectory() as tmp:
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
    for m, c in counts.items():
        print(f"{m}: Rrs {c['rrs']}/{c['n_rrs']}, 2σ covers {c['cover']}/{c['n_rrs']}, ratios within 2 % "
              f"{c['ratio']}/{c['n_ratio']}, products within 5 % {c['product']}/{c['n_prod']}")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 8)

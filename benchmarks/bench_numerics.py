"""Benchmark: camcal's numpy-only numerics (camcal.special, camcal.optimize) against scipy, the baseline.

Run: ``python benchmarks/bench_numerics.py [--runs 7]`` (prints a Markdown section for RESULTS.md).

- import cost, whole processes (interleaved, medians): ``import numpy`` (baseline of both), ``import
  camcal.special, camcal.optimize`` and ``import scipy.optimize, scipy.special`` (what dark, flat and response
  imported before);
- the fits of calibrate at their real sizes, camcal's routine against the scipy call it replaces, same inputs
  (best of ``--runs`` repeats, ms per call): the quantised read-noise likelihood of ``camcal.dark`` (Nelder–Mead
  over ndtr, 40 000 pixel pairs of an IMX296-like plane), the flat's optical centre (TRF over a 64-block plane),
  seed eq. 12 (curve_fit, 17 points) and the sRGB form (least_squares, 17 points), and ``chi2_isf``.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np
import scipy.optimize as so
import scipy.special as sp

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT.parent))

from camcal import optimize as co  # noqa: E402
from camcal import special as cs  # noqa: E402

IMPORTS = {
    "import numpy (baseline)": "import numpy",
    "import camcal.special, camcal.optimize": "import camcal.special, camcal.optimize",
    "import scipy.optimize, scipy.special": "import numpy, scipy.optimize, scipy.special",
}


def import_times(runs: int) -> dict[str, list[float]]:
    env = dict(os.environ, PYTHONPATH=str(ROOT.parent))
    out: dict[str, list[float]] = {k: [] for k in IMPORTS}
    for _ in range(runs):
        for k, code in IMPORTS.items():
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-c", code], check=True, env=env, capture_output=True)
            out[k].append(time.perf_counter() - t0)
    return out


def best_ms(f, runs: int, number: int) -> float:
    f()
    best = math.inf
    for _ in range(runs):
        t0 = time.perf_counter()
        for _ in range(number):
            f()
        best = min(best, (time.perf_counter() - t0) / number)
    return best * 1e3


def problems():
    rng = np.random.default_rng(0)
    # quantised likelihood (camcal.dark.quantised_noise_fit's nll), ndtr of both frames in one call
    mu = 60 + 0.3 * rng.normal(size=40_000)
    k1 = np.round(mu + 0.38 * rng.normal(size=mu.size)).astype(int)
    k2 = np.round(mu + 0.1 + 0.38 * rng.normal(size=mu.size)).astype(int)
    lo = int(min(k1.min(), k2.min()))
    n = int(max(k1.max(), k2.max())) - lo + 1
    hist = np.bincount((k1 - lo) * n + (k2 - lo), minlength=n * n).reshape(n, n).astype(float)
    edges = np.arange(n + 1) - 0.5
    nodes, weights = np.polynomial.hermite_e.hermegauss(48)
    weights = weights / weights.sum()

    def nll_with(ndtr):
        def nll(p):
            m, o, lsd, ls = p
            sd, sg = np.exp(lsd), np.exp(ls)
            mq = m + sd * nodes
            cdf = ndtr(np.stack([(edges[None, :] - mq[:, None]) / sg, (edges[None, :] - (mq[:, None] + o)) / sg]))
            prob = 0.9999 * np.einsum("q,qi,qj->ij", weights, np.diff(cdf[0], axis=1), np.diff(cdf[1], axis=1))
            return -float(np.sum(hist * np.log(prob + 1e-4 / (n * n))))
        return nll

    x0 = [float(k1.mean() - lo), 0.1, math.log(0.3), math.log(0.4)]
    nm = {"xatol": 1e-5, "fatol": 1e-4, "maxiter": 4000}
    # flat centre: 64 x 48 blocks of a radial falloff, centre free within the plane
    yy, xx = np.mgrid[0:48, 0:64].astype(float)
    r2 = ((xx - 33.3) ** 2 + (yy - 22.1) ** 2) / 40.0**2
    data = (1 - 0.3 * r2 + 0.05 * r2**2) * (1 + 0.002 * rng.normal(size=r2.shape))
    d, xs, ys = data.ravel(), xx.ravel(), yy.ravel()

    def flat_resid(c):
        rr = ((xs - c[0]) ** 2 + (ys - c[1]) ** 2) / 40.0**2
        design = np.stack([np.ones_like(rr), rr, rr**2, rr**3], axis=1) / d[:, None]
        coef, *_ = np.linalg.lstsq(design, np.ones_like(d), rcond=None)
        return design @ coef - 1.0

    flat_kw = {"bounds": ([0, 0], [63, 47]), "x_scale": [6.3, 6.3], "diff_step": 1e-4, "xtol": 1e-7, "ftol": 1e-10}
    # eq. 12 and the sRGB form, 17 points
    x = np.geomspace(1e-3, 1, 17)
    u = x / np.exp(np.mean(np.log(x)))
    g = 9000 * u**0.98 + 64 + rng.normal(size=17)

    def eq12(t, a, gam, b):
        return a * np.power(t, gam) + b

    eq_kw = {"bounds": ([0, 0.02, -np.inf], [np.inf, 10, np.inf]), "x_scale": "jac", "max_nfev": 20000}
    gj = 255 * np.power(x / 0.7, 1 / 2.4) + 0.3 * rng.normal(size=17)

    def srgb_resid(q):
        return (255 * np.power(x / math.exp(q[1]), q[0]) - gj) / 0.3

    srgb_kw = {"bounds": ([0.05, -np.inf], [0.99, np.inf]), "x_scale": "jac"}
    return [
        ("quantised read-noise likelihood (Nelder–Mead over ndtr)",
         lambda: co.nelder_mead(nll_with(cs.ndtr), x0, **nm),
         lambda: so.minimize(nll_with(sp.ndtr), x0, method="Nelder-Mead", options=nm), 2),
        ("flat optical centre (bounded TRF, 3072 blocks)",
         lambda: co.least_squares(flat_resid, [30.0, 25.0], **flat_kw),
         lambda: so.least_squares(flat_resid, [30.0, 25.0], **flat_kw), 5),
        ("seed eq. 12 (curve_fit, 17 points)",
         lambda: co.curve_fit(eq12, u, g, [8000, 1.0, 60], sigma=np.ones(17), **eq_kw),
         lambda: so.curve_fit(eq12, u, g, p0=[8000, 1.0, 60], sigma=np.ones(17), absolute_sigma=True,
                              method="trf", **eq_kw), 50),
        ("sRGB form (least_squares, 17 points)",
         lambda: co.least_squares(srgb_resid, [0.5, 0.0], **srgb_kw),
         lambda: so.least_squares(srgb_resid, [0.5, 0.0], **srgb_kw), 50),
        ("chi2_isf(1e-6, 15) (noisy-pixel bound)", lambda: cs.chi2_isf(1e-6, 15.0), lambda: sp.chdtri(15.0, 1e-6),
         500),
    ]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    imp = import_times(args.runs)
    rows = [(name, best_ms(ours, args.runs, number), best_ms(ref, args.runs, number))
            for name, ours, ref, number in problems()]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"### numpy-only numerics of calibrate ({date.today().isoformat()})\n")
    print(f"Machine: {os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}; "
          f"`python benchmarks/bench_numerics.py --runs {args.runs}`, load {load:.1f} (1-minute).\n")
    base = statistics.median(imp["import numpy (baseline)"])
    print("| import (whole process, median) | s | above `import numpy` (s) |\n|---|---:|---:|")
    for k, v in imp.items():
        m = statistics.median(v)
        print(f"| `{k}` | {m:.3f} | {m - base:.3f} |")
    print("\n| fit (same inputs, best of runs) | camcal (ms) | scipy (ms) | camcal / scipy |\n|---|---:|---:|---:|")
    for name, ours, ref in rows:
        print(f"| {name} | {ours:.3f} | {ref:.3f} | {ours / ref:.2f} |")


if __name__ == "__main__":
    main()

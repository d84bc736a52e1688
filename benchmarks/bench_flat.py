"""Benchmark: flat-field vignetting fit, downsampled variable projection vs a full-resolution fit.

Run ``python benchmarks/bench_flat.py``; prints a Markdown section for ``benchmarks/RESULTS.md``.

Baseline: the straightforward approach, :func:`scipy.optimize.least_squares` over all parameters
(level, centre x/y, k0..k2) on every pixel of the plane, from a fair start. camcal:
:func:`camcal.calibrate.flat.fit_flat_planes` (block means, ~64 blocks on the long side; the centre searched by
least_squares, the rest by a linear solve). Both fit the same synthetic 4-plane master flat of an 800x600 sensor (40 %
corner falloff, centre 5 % off, 1 % PRNU, 0.35 % shot noise; the baseline takes minutes on bigger ones); camcal is
also timed on a 12-Mpixel sensor. The table gives times and the accuracy against the truth.
"""

from __future__ import annotations

import datetime
import os
import platform
import time

import numpy as np
from scipy.optimize import least_squares

from camcal.calibrate.flat import fit_flat_planes
from camcal.models.flat import PlaneGeometry, radial_gain

SIZES = ((600, 800), (3000, 4000))
"""Full-resolution sensors (H, W): the baseline runs on the first only (minutes on the second)."""
K_TRUE = (-0.30, -0.10, 0.0, 0.0, 0.0)
CENTRE_FRAC = (0.55, 0.50)


def synthetic_master(height: int, width: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, PlaneGeometry]:
    rng = np.random.default_rng(seed)
    h, w = height // 2, width // 2
    geom = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (h, w), "RGGB")
    cx_full, cy_full = CENTRE_FRAC[0] * (width - 1), CENTRE_FRAC[1] * (height - 1)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    truth = np.empty((4, h, w))
    for i, c in enumerate(("R", "G1", "G2", "B")):
        oy, ox = geom.offsets[c]
        truth[i] = radial_gain(geom.r2(c, xx, yy, (cx_full - ox) / 2, (cy_full - oy) / 2), K_TRUE)
    noise = 1 + 0.01 * rng.standard_normal(truth.shape) + 0.0035 * rng.standard_normal(truth.shape)
    return (5000.0 * truth * noise).astype(np.float32), truth, geom


def baseline_fit(master: np.ndarray, geom: PlaneGeometry) -> np.ndarray:
    """All parameters by least_squares on every pixel (one plane at a time)."""
    _, h, w = master.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    x, y = xx.ravel(), yy.ravel()
    out = np.empty(master.shape)
    for i, c in enumerate(("R", "G1", "G2", "B")):
        d = master[i].ravel().astype(np.float64)

        def resid(p, c=c, d=d):
            g = radial_gain(geom.r2(c, x, y, p[1], p[2]), p[3:])
            return p[0] * g / d - 1.0

        p0 = [float(np.max(d)), w / 2, h / 2, -0.3, 0.0, 0.0]  # a fair start: centre mid-frame, typical k0
        lo, hi = [0, 0, 0, -np.inf, -np.inf, -np.inf], [np.inf, w - 1, h - 1, np.inf, np.inf, np.inf]
        sol = least_squares(resid, p0, bounds=(lo, hi), x_scale="jac")
        out[i] = radial_gain(geom.r2(c, xx, yy, sol.x[1], sol.x[2]), sol.x[3:])
    return out


def time_camcal(master: np.ndarray, truth: np.ndarray) -> tuple[float, float, float, int]:
    t0 = time.perf_counter()
    fm = fit_flat_planes(master, cfa_pattern="RGGB", with_prnu=False)
    g = fm.gain()
    t_fit = time.perf_counter() - t0
    t0 = time.perf_counter()
    fit_flat_planes(master, cfa_pattern="RGGB", with_prnu=True)
    t_prnu = time.perf_counter() - t0
    return t_fit, t_prnu, float(np.abs(g / truth - 1).max()), int(fm.info["downsample"])


def main() -> None:
    print("## flat\n")
    print(f"Machine: {os.cpu_count()} cores, {platform.processor() or platform.machine()}, Python "
          f"{platform.python_version()}, {datetime.date.today().isoformat()}. Shared machine: absolute times are "
          "indicative, the ratio is the result.\n")
    print("Vignetting fit of 4 CFA planes, 3 radial terms, centre free; synthetic master with 40 % corner "
          "falloff, centre 5 % off, 1 % PRNU, 0.35 % noise.\n")
    print("| sensor | method | time (s) | max relative error vs truth |")
    print("|---|---|---|---|")
    ratio = None
    for i, (hh, ww) in enumerate(SIZES):
        master, truth, geom = synthetic_master(hh, ww)
        t_fit, t_prnu, err, b = time_camcal(master, truth)
        mp = f"{ww}x{hh}"
        if i == 0:
            t0 = time.perf_counter()
            g_base = baseline_fit(master, geom)
            t_base = time.perf_counter() - t0
            err_base = float(np.abs(g_base / truth - 1).max())
            print(f"| {mp} | baseline: least_squares on every pixel | {t_base:.2f} | {100 * err_base:.3f} % |")
            ratio = t_base / t_fit
        print(f"| {mp} | camcal `fit_flat_planes` (blocks of {b} px) | {t_fit:.2f} | {100 * err:.3f} % |")
        print(f"| {mp} | camcal, with the PRNU map | {t_prnu:.2f} | |")
    print(f"\nSpeed-up of the model fit over the baseline: **{ratio:.0f}x** at equal accuracy (both far inside the "
          "0.5 % target); camcal's fit time hardly grows with the sensor size (the PRNU map is per pixel).\n")


if __name__ == "__main__":
    main()

"""Experiment (issue 28): the master dark's band statistics as one compiled per-pixel kernel, against camcal's numpy.

camcal does not use this: it needs numba (``pip install numba``), which is not a camcal dependency. It measures
what the decision left open by issue 28 would buy: the master dark of 32 frames of 12 MP within 2x the 2-thread
decode needs the band statistics (``camcal.calibrate.band_stats._integer_band_stats``) in fewer passes than numpy's
whole-plane calls allow, so ``python benchmarks/bench_band_kernel.py`` prints a Markdown section for
``benchmarks/RESULTS.md``:

1. **Identity.** The kernel reproduces ``camcal.calibrate.band_stats.band_statistics(x, "sigma_clip", 3.0)`` on
   integer bands (uint16, 2 to 64 frames, noise from 0.3 to 400 DN, cosmic rays, constant pixels): every
   output, bit for bit.
   It follows the same arithmetic: float32 deviations from the median (exact); their sums and the sums of
   their squares in float64 (exact: whole and half DN) rounded once to float32, which is what numpy's path
   gives (float32 sums, exact below ``EXACT_SQUARES``; above it, float64 sums rounded once); the pass-1
   half-width from the interquartile range of the deviations (``_pass1_threshold``), the moments in float64
   (``_moments``), the pass-2 half-width (``_pass2_threshold``). A value is kept when ``lo <= d <= hi``: the
   values a clip removes from a sorted pixel are its lowest and highest ranks, so masking every value gives the
   rank-wise result.
2. **The band phase.** ``camcal.calibrate.spill.spilled_statistics`` over the spilled 32 x 12 MP mosaics of
   ``benchmarks/bench_dark.py`` (its frames, written by its ``prepare``), in camcal's 2 band threads, once with
   camcal's numpy statistics
   and once with the kernel in their place (each band thread runs the kernel, which releases the GIL),
   interleaved, medians of ``--runs``.
3. **The whole master dark.** ``bench_dark.py``'s three measurements in fresh processes, in one shuffled order:
   the 2-thread decode, camcal's master dark, and the same with the kernel in place of the numpy statistics.

The kernel: a block of 256 pixels of every frame is copied into a (N, 256) buffer that stays in the core's
first-level cache, sorted by camcal's sorting network (``camcal.calibrate.band_stats._sorting_network``: one min and
one max per pair, vectorised over the block's pixels), then every statistic is taken on that block, each step a loop
over the block's pixels that the compiler vectorises.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import random
import resource
import statistics
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # run from a checkout without installing
sys.path.insert(0, str(HERE))

from camcal.calibrate import band_stats as numpy_band_stats  # noqa: E402
from camcal.calibrate import spill  # noqa: E402
from camcal.calibrate.band_stats import IQR_TO_SIGMA  # noqa: E402

NUMPY_BAND_STATS = numpy_band_stats.band_statistics
"""camcal's own band statistics (numpy), kept before any run puts the kernel in their place."""

BLOCK = 256
"""Pixels of a block: (N, BLOCK) uint16 plus a few float rows stay in a core's first-level cache at N <= 64."""


def _kernel():
    """The compiled kernel (numba imported here: the module loads without it, to say what is missing)."""
    from numba import njit

    @njit(nogil=True, boundscheck=False)  # no cache: numba's cache files are pickles
    def clip_stats(x, pairs, sigma, value, var, count, var_all, mean_all):  # pragma: no cover - compiled
        n, npix = x.shape
        sg = np.float32(sigma)
        nf = np.float32(n)
        iqr = np.float32(IQR_TO_SIGMA)
        half = np.float32(0.5)
        zero = np.float32(0.0)
        eps = np.float32(1e-6)  # camcal.calibrate.band_stats._pass2_threshold's share of the median
        q1a = int(math.floor(0.25 * (n - 1)))
        q1b = min(q1a + 1, n - 1)
        q1f = np.float32(0.25 * (n - 1) - q1a)
        q3a = int(math.floor(0.75 * (n - 1)))
        q3b = min(q3a + 1, n - 1)
        q3f = np.float32(0.75 * (n - 1) - q3a)
        buf = np.empty((n, BLOCK), np.uint16)
        med = np.empty(BLOCK, np.float32)
        s1 = np.empty(BLOCK, np.float64)
        s2 = np.empty(BLOCK, np.float64)
        cnt = np.empty(BLOCK, np.int64)
        lo = np.empty(BLOCK, np.float32)
        hi = np.empty(BLOCK, np.float32)
        for j0 in range(0, npix, BLOCK):
            m = min(npix, j0 + BLOCK) - j0
            for i in range(n):
                for k in range(m):
                    buf[i, k] = x[i, j0 + k]
            for p in range(pairs.shape[0]):
                ra = buf[pairs[p, 0]]
                rb = buf[pairs[p, 1]]
                for k in range(m):
                    u = ra[k]
                    w = rb[k]
                    ra[k] = min(u, w)
                    rb[k] = max(u, w)
            for k in range(m):
                if n % 2:
                    med[k] = np.float32(buf[n // 2, k])
                else:
                    med[k] = half * (np.float32(buf[n // 2 - 1, k]) + np.float32(buf[n // 2, k]))
                s1[k] = 0.0
                s2[k] = 0.0
            # the sums in float64, exact for whole and half DN, rounded once to float32: numpy's float32 sums
            # where they are exact (below EXACT_SQUARES), its float64 sums of the loud pixels above it
            for i in range(n):
                for k in range(m):
                    d = np.float64(np.float32(buf[i, k]) - med[k])
                    s1[k] += d
                    s2[k] += d * d
            for k in range(m):
                sd = np.float32(s1[k])
                sdd = np.float32(s2[k])
                va = np.float32(np.nan)
                if n >= 2:
                    va = max(sdd - sd * sd / nf, zero) / np.float32(n - 1)
                var_all[j0 + k] = va
                mean_all[j0 + k] = np.float64(sd) / n + np.float64(med[k])
                a = np.float32(buf[q1a, k]) - med[k]
                q1 = a + q1f * ((np.float32(buf[q1b, k]) - med[k]) - a)
                a = np.float32(buf[q3a, k]) - med[k]
                q3 = a + q3f * ((np.float32(buf[q3b, k]) - med[k]) - a)
                scale = (q3 - q1) / iqr
                if not scale > 0:
                    scale = np.float32(math.sqrt(va)) if va >= 0 else zero
                t = sg * scale
                lo[k] = -t
                hi[k] = t
            for rep in range(2):
                for k in range(m):
                    s1[k] = 0.0
                    s2[k] = 0.0
                    cnt[k] = 0
                for i in range(n):
                    for k in range(m):
                        d = np.float32(buf[i, k]) - med[k]
                        if d >= lo[k] and d <= hi[k]:
                            dd = np.float64(d)
                            s1[k] += dd
                            s2[k] += dd * dd
                            cnt[k] += 1
                for k in range(m):
                    c = np.float64(cnt[k])
                    a1 = np.float64(np.float32(s1[k]))
                    a2 = np.float64(np.float32(s2[k]))
                    mm = a1 / c if cnt[k] else np.nan
                    v = max(a2 - a1 * mm, 0.0) / (c - 1.0) if cnt[k] > 1 else np.nan
                    m32 = np.float32(mm)
                    v32 = np.float32(v)
                    if rep == 0:
                        sd_ = np.float32(math.sqrt(v32)) if v32 >= 0 else zero
                        t = sg * sd_ + eps * abs(med[k])
                        lo[k] = m32 - t
                        hi[k] = m32 + t
                    else:
                        value[j0 + k] = np.float64(m32) + np.float64(med[k])
                        var[j0 + k] = v32
                        count[j0 + k] = cnt[k]

    return clip_stats


_CLIP_STATS = None


def band_stats(x: np.ndarray, method: str, sigma: float, work: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """``camcal.calibrate.band_stats.band_statistics`` with the kernel for integer sigma-clipped bands (camcal's numpy
    otherwise)."""
    global _CLIP_STATS
    if x.dtype.kind not in "ui" or x.dtype.itemsize > 2 or method != "sigma_clip" or x.shape[0] > 128:
        return NUMPY_BAND_STATS(x, method, sigma, work)
    if _CLIP_STATS is None:
        _CLIP_STATS = _kernel()
    n, shape = x.shape[0], x.shape[1:]
    flat = x.reshape(n, -1)
    pairs = np.array(numpy_band_stats._sorting_network(n), np.int64).reshape(-1, 2)
    # value and mean_all in float64, as numpy's path gives them (the stack writes both into float32 maps)
    outs = [np.empty(flat.shape[1], t) for t in (np.float64, np.float32, np.uint8, np.float32, np.float64)]
    _CLIP_STATS(flat, pairs, sigma, *outs)
    value, var, count, var_all, mean_all = (a.reshape(shape) for a in outs)
    return value, value, var, count, var_all, mean_all


def check_identity(seed: int = 5, bands: int = 200) -> list[str]:
    """Bit-identity of :func:`band_stats` with camcal's numpy path on random integer bands.

    ``bands`` bands of 2 to 64 frames and up to 4000 pixels, noise from 0.3 DN (most pixels read a few values)
    to 400 DN (most pixels' squares above ``EXACT_SQUARES``: numpy's float64 path), cosmic rays in up to 5 % of
    the values, and constant pixels. Gives one line: how many bands were identical in every output."""
    rng = np.random.default_rng(seed)
    different = []
    for b in range(bands):
        n = int(rng.integers(2, 65))
        shape = (int(rng.integers(1, 5)), int(rng.integers(50, 1000)))
        noise = float(np.exp(rng.uniform(np.log(0.3), np.log(400))))
        x = np.clip(rng.normal(1000, noise, (n, *shape)), 0, 16383).astype(np.uint16)
        hot = int(rng.integers(0, max(1, x.size // 20)))
        idx = tuple(rng.integers(0, s, hot) for s in (n, *shape))
        x[idx] = rng.integers(0, 16384, hot)  # cosmic rays and dead values, both ends
        x[:, 0, :3] = 700  # constant pixels: a zero interquartile range, the plain deviation instead
        ref = NUMPY_BAND_STATS(x.copy(), "sigma_clip", 3.0)
        got = band_stats(x.copy(), "sigma_clip", 3.0)
        same = [np.array_equal(np.asarray(a), np.asarray(b_), equal_nan=True) for a, b_ in zip(ref, got, strict=True)]
        if not all(same):
            which = [i for i, s_ in enumerate(same) if not s_]
            different.append(f"band {b} ({n} frames, noise {noise:.3g} DN): outputs {which} differ")
    return [f"{bands - len(different)} of {bands} random bands identical in every output", *different]


def _cpu_s() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    return own.ru_utime + own.ru_stime


def measure_bands(runs: int) -> dict[str, list[tuple[float, float]]]:
    """The band phase of the 32-frame 12 MP master dark, numpy against the kernel, interleaved: (wall, CPU) s."""
    import bench_dark

    from camcal.calibrate.dark_frames import DARK_STATISTICS
    from camcal.io.read import load_frame

    n = bench_dark.N_MAX
    fd = os.memfd_create("camcal-bench-spill")
    for i in range(n):
        frame = load_frame(bench_dark._dng(i))
        data = np.ascontiguousarray(frame.data, np.uint16)
        os.pwrite(fd, memoryview(data).cast("B"), i * data.nbytes)
    h, w = data.shape[0] // 2, data.shape[1] // 2
    band_stats(np.zeros((n, 8), np.uint16), "sigma_clip", 3.0)  # compiled before timing
    own = NUMPY_BAND_STATS
    times: dict[str, list[tuple[float, float]]] = {"numpy": [], "kernel": []}
    try:
        for _ in range(runs):
            for name, fn in (("numpy", own), ("kernel", band_stats)):
                spill.band_statistics = fn
                c0, t0 = _cpu_s(), time.perf_counter()
                spill.spilled_statistics(fd, "spill", n, (4, h, w), np.dtype(np.uint16), "sigma_clip", 3.0, 2,
                                         spill.BAND_MB, frame.cfa_pattern, frozenset(DARK_STATISTICS))
                times[name].append((time.perf_counter() - t0, _cpu_s() - c0))
    finally:
        spill.band_statistics = own
        os.close(fd)
    return times


def compile_seconds() -> float:
    """Seconds to compile the kernel (its first call, on a tiny band): every process pays it, as numba's on-disk
    cache, which would spare it, is made of pickles."""
    t0 = time.perf_counter()
    band_stats(np.zeros((8, 8), np.uint16), "sigma_clip", 3.0)
    return time.perf_counter() - t0


def _run_calibrate(kernel: bool) -> dict:
    """``calibrate_session`` + ``save_profile`` of ``bench_calibrate.py``'s 24 MP session in this process, under the
    command line's allocator policy, imports and the kernel's compilation excluded: {"seconds": ...}."""
    import tempfile

    import bench_calibrate

    from camcal.calibrate.run import calibrate_session
    from camcal.io.allocator import use_frame_allocator
    from camcal.models.profile import save_profile

    use_frame_allocator()
    if kernel:
        compile_seconds()
        spill.band_statistics = band_stats
    session = bench_calibrate.session_dir(6000, 4000)
    if not (session / "truth.json").is_file():
        raise SystemExit(f"no session at {session}: run python benchmarks/bench_calibrate.py --prepare first")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        profile, _ = calibrate_session(session)
        save_profile(profile, Path(tmp) / "p.camcal")
        return {"seconds": time.perf_counter() - t0}


def _run_one(which: str) -> dict:
    import bench_dark

    if which in ("calibrate", "calibrate_kernel"):
        return _run_calibrate(which == "calibrate_kernel")
    if which == "decode":
        return bench_dark.run_decode(bench_dark.N_MAX, 2)
    if which == "kernel":
        band_stats(np.zeros((bench_dark.N_MAX, 8), np.uint16), "sigma_clip", 3.0)  # compiled before timing
        spill.band_statistics = band_stats
    return bench_dark.run_camcal(bench_dark.N_MAX, 2)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--one", choices=["decode", "camcal", "kernel", "calibrate", "calibrate_kernel"],
                    help=argparse.SUPPRESS)
    ap.add_argument("--runs", type=int, default=5, help="runs of each measurement (medians)")
    ap.add_argument("--calibrate", type=int, default=0, metavar="RUNS",
                    help="also the whole 24 MP calibration of bench_calibrate.py (prepared first), RUNS pairs")
    args = ap.parse_args()
    try:
        import numba
    except ImportError:
        raise SystemExit("this experiment needs numba (pip install numba); camcal itself does not") from None
    if args.one:
        print(json.dumps(_run_one(args.one)))
        return
    import bench_dark

    bench_dark._set_size(bench_dark.WIDTH, bench_dark.HEIGHT, bench_dark.N_MAX, 0)  # no ccdproc files
    bench_dark.prepare()
    compile_s = compile_seconds()  # the first call: before anything else uses the kernel
    identity = check_identity()
    bands = measure_bands(args.runs)
    order = [w for w in ("decode", "camcal", "kernel") for _ in range(args.runs)]
    random.Random(28).shuffle(order)
    whole: dict[str, list[dict]] = {"decode": [], "camcal": [], "kernel": []}
    for which in order:
        out = subprocess.run([sys.executable, __file__, "--one", which], capture_output=True, text=True, check=True)
        whole[which].append(json.loads(out.stdout.strip().splitlines()[-1]))
    calib: dict[str, list[dict]] = {"calibrate": [], "calibrate_kernel": []}
    for _ in range(args.calibrate):
        for which in calib:
            out = subprocess.run([sys.executable, __file__, "--one", which], capture_output=True, text=True,
                                 check=True)
            calib[which].append(json.loads(out.stdout.strip().splitlines()[-1]))

    def med(rows: list, i: int) -> float:
        return statistics.median(r[i] for r in rows)

    def wmed(which: str, key: str = "seconds") -> float:
        return statistics.median(r[key] for r in whole[which])

    dec = wmed("decode")
    print(f"### {date.today().isoformat()}: the band statistics as a compiled kernel, an experiment (issue 28)\n")
    print(f"Machine: {os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}, "
          f"numba {numba.__version__}; load average {os.getloadavg()[0]:.1f} at the end of the run.\n")
    print("`python benchmarks/bench_band_kernel.py` (needs numba, which camcal does not use): the master dark of "
          f"`bench_dark.py` ({bench_dark.N_MAX} x {bench_dark.WIDTH}x{bench_dark.HEIGHT}, sigma clipping), "
          f"{args.runs} runs of each, medians.\n")
    print("Identity with camcal's numpy path (value, mean, variance, count, variance of all, mean of all; "
          "bit for bit):\n")
    for line in identity:
        print(f"- {line}")
    print(f"\nCompiling the kernel: {compile_s:.1f} s, in every process (numba's on-disk cache is left off: its files "
          "are pickles).")
    print("\n| what | wall (s) | CPU (s) | ratio to the decode (wall) |\n|---|---:|---:|---:|")
    print(f"| 2-thread decode (fresh process) | {dec:.2f} | {wmed('decode', 'cpu_s'):.2f} | 1.00 |")
    for which, label in (("camcal", "master dark, camcal's numpy statistics"),
                         ("kernel", "master dark, the kernel in their place")):
        print(f"| {label} (fresh process) | {wmed(which):.2f} | {wmed(which, 'cpu_s'):.2f} | "
              f"**{wmed(which) / dec:.2f}** |")
    for name, label in (("numpy", "band phase alone, camcal's numpy statistics"),
                        ("kernel", "band phase alone, the kernel")):
        print(f"| {label} (one process, interleaved) | {med(bands[name], 0):.2f} | {med(bands[name], 1):.2f} | "
              f"{med(bands[name], 0) / dec:.2f} |")
    whole_runs = "; ".join(k + " " + ", ".join(f"{r['seconds']:.2f}" for r in v) for k, v in whole.items())
    band_runs = "; ".join(k + " " + ", ".join(f"{t[0]:.2f}" for t in v) for k, v in bands.items())
    print(f"\nRuns, wall (s): {whole_runs}; band phase alone: {band_runs}.")
    if args.calibrate:
        c0, c1 = (statistics.median(r["seconds"] for r in calib[w]) for w in calib)
        print(f"\nThe whole 24 MP calibration of `bench_calibrate.py` (`calibrate_session` + `save_profile` in one "
              f"process, imports and compilation excluded; {args.calibrate} pairs, medians): {c0:.2f} s with camcal's "
              f"numpy statistics, {c1:.2f} s with the kernel (runs: "
              + "; ".join(w + " " + ", ".join(f"{r['seconds']:.2f}" for r in calib[w]) for w in calib) + ").")


if __name__ == "__main__":
    main()

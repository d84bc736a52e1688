"""Benchmark: time and size of every OpenEXR compression, float32, half and mixed, on camcal's radiance output.

Run ``python benchmarks/bench_encoding.py [WIDTH HEIGHT]`` (default 3000x2000, a 6 MP photo → a 1500x1000
output with R, G, B, L663, L663_unc); prints a Markdown section for ``benchmarks/RESULTS.md``.

One synthetic RGGB 14-bit DNG (the 24 MP benchmark's camera and profile, built by ``bench_apply.build`` at the
size asked) goes through :func:`camcal.apply.photo.apply_prepared` once; its channels are then written with
:func:`camcal.io.exr.write_exr` for each compression and precision (best of ``REPEATS``, interleaved), read back,
and compared with the float32 zip file (lossless; the default before issue 28): maximum and median relative change
of the radiance channels (R, G, B, L663) over the valid pixels, and of the 1σ channels. The pixels' own noise is
``L663_unc / L663`` (photon and read noise, docs/apply.md), to which half's relative step is compared. Times
(wall and the CPU time of this process, OpenImageIO's threads included: what a batch of busy workers pays) are
ratios to float32 zip of the same run. ``mixed`` (radiance float32, 1σ channels half) falls back to float32 for
the whole file's 1σ channels when one of them is outside half's normal range; the header's note is printed.
The default output (:class:`camcal.apply.batch.BatchOptions`) is marked.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout without installing
sys.path.insert(0, str(Path(__file__).resolve().parent))
REPEATS = 2
RADIANCE = ("R", "G", "B", "L663")


def main(width: int = 3000, height: int = 2000) -> None:
    import bench_apply

    from camcal.apply.batch import BatchOptions
    from camcal.apply.photo import apply_prepared, prepare
    from camcal.io.exr import COMPRESSIONS, PRECISIONS, read_exr, read_exr_header, write_exr
    from camcal.io.read import load_frame

    bench_apply.WIDTH, bench_apply.HEIGHT, bench_apply.N_BATCH = width, height, 1
    work = Path(__file__).resolve().parent / "_work" / f"encoding{width}x{height}"
    profile, _, photos = bench_apply.build(work)
    plan = prepare(profile, 663.0, "narrowband")
    image = apply_prepared(load_frame(photos[0]), plan)
    channels = image.channels
    h, w = next(iter(channels.values())).shape
    cases = [(c, p) for c in COMPRESSIONS for p in PRECISIONS]
    default = (BatchOptions.compression, BatchOptions.precision)
    times: dict[tuple, float] = {}
    cpus: dict[tuple, float] = {}
    sizes: dict[tuple, int] = {}
    failed: dict[tuple, str] = {}
    with tempfile.TemporaryDirectory(dir=work) as tmp:
        for _ in range(REPEATS):
            for case in cases:
                if case in failed:
                    continue
                out = Path(tmp) / f"{case[0]}_{case[1]}.exr"
                t0, c0 = time.perf_counter(), os.times()
                try:
                    write_exr(out, channels, image.metadata, precision=case[1], compression=case[0])
                except Exception as exc:  # noqa: BLE001 - a compression this OpenImageIO does not offer
                    failed[case] = f"{type(exc).__name__}: {exc}"
                    continue
                dt, c1 = time.perf_counter() - t0, os.times()
                times[case] = min(dt, times.get(case, np.inf))
                cpus[case] = min(c1.user + c1.system - c0.user - c0.system, cpus.get(case, np.inf))
                sizes[case] = out.stat().st_size
        ref, _ = read_exr(Path(tmp) / "zip_float.exr", list(channels))
        valid = np.all([np.isfinite(ref[c]) & (ref[c] > 0) for c in RADIANCE], axis=0)
        rel_noise = (ref["L663_unc"] / ref["L663"])[valid]
        sigmas = [c for c in channels if c.endswith("_unc")]
        changes: dict[tuple, tuple[float, ...]] = {}
        mixed_note = ""
        for case in times:
            got, _ = read_exr(Path(tmp) / f"{case[0]}_{case[1]}.exr", list(channels))
            rel = np.concatenate([np.abs(got[c][valid].astype(np.float64) / ref[c][valid] - 1) for c in RADIANCE])
            l_rel = np.abs(got["L663"][valid].astype(np.float64) / ref["L663"][valid] - 1)
            s_rel = np.concatenate([np.abs(got[c][valid].astype(np.float64) / ref[c][valid] - 1) for c in sigmas])
            changes[case] = (float(rel.max()), float(np.median(rel)), float(np.max(l_rel / rel_noise)),
                             float(s_rel.max()))
            if case[1] == "mixed" and not mixed_note:
                mixed_note = str(read_exr_header(Path(tmp) / f"{case[0]}_{case[1]}.exr").get("uncertainty_precision"))
    base_t, base_s, base_c = times[("zip", "float")], sizes[("zip", "float")], cpus[("zip", "float")]
    load = os.getloadavg()[0]
    print(f"Machine: {os.cpu_count()} cores, CPython {platform.python_version()}, {platform.machine()}; "
          f"{datetime.date.today()}; load average {load:.1f} at the end of the run.\n")
    print(f"`python benchmarks/bench_encoding.py {width} {height}`: camcal's output of one {width}x{height} RGGB "
          f"14-bit DNG ({h}x{w}, channels {', '.join(channels)}); write time best of {REPEATS}, interleaved; "
          f"{int(valid.sum())} valid pixels.\n")
    print("| compression | precision | write (s) | time vs float zip | CPU (s) | CPU vs float zip | size (MB) "
          "| size vs float zip | max rel. change R,G,B,L663 | median rel. change | max change of L663 / its noise "
          "| max rel. change of the 1σ channels |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for case in cases:
        name = f"**{case[0]}** (default)" if case == default else case[0]
        if case in failed:
            print(f"| {name} | {case[1]} | not offered: {failed[case]} | | | | | | | | | |")
            continue
        mx, med, over_noise, s_mx = changes[case]
        print(f"| {name} | {case[1]} | {times[case]:.3f} | {times[case] / base_t:.2f} | {cpus[case]:.2f} "
              f"| {cpus[case] / base_c:.2f} | {sizes[case] / 1e6:.1f} | {sizes[case] / base_s:.2f} | {mx:.2e} "
              f"| {med:.2e} | {over_noise:.3f} | {s_mx:.2e} |")
    q = np.quantile(rel_noise, [0.0, 0.01, 0.5])
    print(f"\nThe pixels' own relative noise L663_unc/L663: min {q[0]:.2e}, 1st percentile {q[1]:.2e}, "
          f"median {q[2]:.2e}; half's relative step 2^-11 = {2.0**-11:.2e} (rounding to nearest: at most "
          f"{2.0**-12:.2e}... {2.0**-11:.2e} relative).")
    s_pos = np.concatenate([ref[c][np.isfinite(ref[c]) & (ref[c] > 0)] for c in sigmas])
    print(f"\nThe 1σ channels ({', '.join(sigmas)}) range from {s_pos.min():.3g} to {s_pos.max():.3g} "
          f"(half's normal range: 6.1e-05 to 65504); the mixed files' header: uncertainty_precision = {mixed_note!r}.")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("width", type=int, nargs="?", default=3000, help="photo width, pixels (default 3000)")
    parser.add_argument("height", type=int, nargs="?", default=2000, help="photo height, pixels (default 2000)")
    cli = parser.parse_args()
    main(cli.width, cli.height)

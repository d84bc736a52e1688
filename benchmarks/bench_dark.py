"""Benchmark: master dark (sigma-clipped) of a 12-megapixel mosaic, camcal against ccdproc.

Run ``python benchmarks/bench_dark.py`` (prints a Markdown section for ``benchmarks/RESULTS.md``).

1. ``prepare``: the synthetic camera writes 64 dark DNG frames of a 4000x3000 RGGB 14-bit mosaic
   into ``benchmarks/_work/dark12mp/`` once (git-ignored), and the first 32 decoded mosaics as
   float32 FITS files for ccdproc (ccdproc reads FITS, not DNG; the conversion is *not* charged to
   ccdproc, so the comparison favours it).
2. Each measurement runs in its own subprocess; peak memory is ``ru_maxrss`` of that process plus
   its children (the decode pool), read with :mod:`resource`.

   - camcal: ``combine_frames(paths, method="sigma_clip", jobs=2)`` on the DNG files (decode included).
   - ccdproc: ``ccdproc.combine(fits_files, method="median", sigma_clip=True, 3, 3,
     mem_limit=1.5e9)``: sigma clipping about the mean (ccdproc's default) then the median.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # run from a checkout without installing
WORK = HERE / "_work" / "dark12mp"
WIDTH, HEIGHT = 4000, 3000
N_MAX = 64
N_CCDPROC = 32
EXPOSURE_S = 8.0


def _dng(i: int) -> Path:
    return WORK / f"dark_{i:03d}.dng"


def _fits(i: int) -> Path:
    return WORK / "fits" / f"dark_{i:03d}.fits"


def _write_one(i: int) -> None:
    import numpy as np

    from camcal.synth.camera import Scene, SensorParams, SyntheticCamera, frame_rngs

    cam = SyntheticCamera(SensorParams(width=WIDTH, height=HEIGHT, seed=11))
    if not _dng(i).exists():
        rng = frame_rngs(11, N_MAX, 2)[i]
        cam.write_dng(_dng(i), Scene.dark(), exposure_s=EXPOSURE_S, iso=100.0, f_number=4.0, rng=rng)
    if i < N_CCDPROC and not _fits(i).exists():
        from astropy.io import fits

        from camcal.io import load_frame

        mosaic = load_frame(_dng(i)).data.astype(np.float32)
        tmp = _fits(i).with_suffix(".tmp")
        fits.PrimaryHDU(mosaic).writeto(tmp, overwrite=True)
        os.replace(tmp, _fits(i))


def prepare() -> None:
    from concurrent.futures import ProcessPoolExecutor

    (WORK / "fits").mkdir(parents=True, exist_ok=True)
    todo = [i for i in range(N_MAX) if not _dng(i).exists() or (i < N_CCDPROC and not _fits(i).exists())]
    if todo:
        with ProcessPoolExecutor(2) as ex:
            list(ex.map(_write_one, todo))


def _peak_mb() -> float:
    """Peak resident memory of this process plus the largest of its (waited-for) children, MB.

    Linux ``ru_maxrss`` is in KiB; for children it is the largest single child, so with a 2-process
    pool this is an upper bound of the true peak only if both workers peak together (they do: same work).
    """
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return (own + kids) / 1024.0


def _cpu_s() -> float:
    """CPU time (user + system) of this process and its children, s: insensitive to other load."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run_camcal(n: int, jobs: int) -> dict:
    from camcal.stack import combine_frames

    paths = [_dng(i) for i in range(n)]
    c0 = _cpu_s()
    t0 = time.perf_counter()
    res = combine_frames(paths, method="sigma_clip", jobs=jobs)
    dt = time.perf_counter() - t0
    import numpy as np

    return {"seconds": dt, "cpu_s": _cpu_s() - c0, "peak_mb": _peak_mb(), "median_value": float(np.median(res.value))}


def run_ccdproc(n: int) -> dict:
    import warnings

    import ccdproc
    import numpy as np

    warnings.simplefilter("ignore")
    files = [str(_fits(i)) for i in range(n)]
    c0 = _cpu_s()
    t0 = time.perf_counter()
    out = ccdproc.combine(files, method="median", sigma_clip=True, sigma_clip_low_thresh=3,
                          sigma_clip_high_thresh=3, mem_limit=1.5e9, unit="adu")
    dt = time.perf_counter() - t0
    return {"seconds": dt, "cpu_s": _cpu_s() - c0, "peak_mb": _peak_mb(), "median_value": float(np.median(out.data))}


def _sub(*args: str) -> dict:
    proc = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"benchmark subprocess {args} failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--one", choices=["camcal", "ccdproc"])
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--skip-ccdproc", action="store_true")
    args = ap.parse_args()
    if args.one == "camcal":
        print(json.dumps(run_camcal(args.n, args.jobs)))
        return
    if args.one == "ccdproc":
        print(json.dumps(run_ccdproc(args.n)))
        return

    prepare()
    # warm the page cache for both inputs so neither side pays the first disk read
    for i in range(N_MAX):
        _dng(i).read_bytes()
    for i in range(N_CCDPROC):
        _fits(i).read_bytes()
    cam = {n: _sub("--one", "camcal", "--n", str(n), "--jobs", str(args.jobs)) for n in (16, 32, 64)}
    cam1 = _sub("--one", "camcal", "--n", "32", "--jobs", "1")
    ccd = None if args.skip_ccdproc else _sub("--one", "ccdproc", "--n", str(N_CCDPROC))

    c32 = cam[32]
    lines = [
        "## dark",
        "",
        f"Master dark (sigma-clipped) of {N_CCDPROC} frames of a {WIDTH}x{HEIGHT} (12 MP) 14-bit RGGB mosaic "
        f"written by the synthetic camera. Machine: {os.cpu_count()} cores, {platform.machine()}, "
        f"Python {platform.python_version()}, {date.today().isoformat()}. "
        "`python benchmarks/bench_dark.py`; each row is a separate subprocess, peak memory = ru_maxrss of the "
        "process plus its children.",
        "",
        "| run | frames | wall time (s) | CPU time (s) | peak memory (MB) |",
        "|---|---:|---:|---:|---:|",
    ]
    if ccd:
        lines.append(f"| ccdproc.combine (median, sigma_clip 3/3, mem_limit 1.5 GB), FITS input | {N_CCDPROC} "
                     f"| {ccd['seconds']:.1f} | {ccd['cpu_s']:.1f} | {ccd['peak_mb']:.0f} |")
    lines.append(f"| camcal combine_frames (sigma_clip, jobs=1), DNG input incl. decode | 32 "
                 f"| {cam1['seconds']:.1f} | {cam1['cpu_s']:.1f} | {cam1['peak_mb']:.0f} |")
    for n in (16, 32, 64):
        lines.append(f"| camcal combine_frames (sigma_clip, jobs={args.jobs}), DNG input incl. decode | {n} "
                     f"| {cam[n]['seconds']:.1f} | {cam[n]['cpu_s']:.1f} | {cam[n]['peak_mb']:.0f} |")
    lines.append("")
    lines.append(f"- Load average (1 min) at the end of the run: {os.getloadavg()[0]:.1f} (other jobs share the "
                 "machine; wall times are sensitive to it, CPU times much less).")
    if ccd:
        lines.append(f"- Speed-up over ccdproc at {N_CCDPROC} frames: **{ccd['seconds'] / c32['seconds']:.1f}x** "
                     f"(jobs={args.jobs}), {ccd['seconds'] / cam1['seconds']:.1f}x (jobs=1) in wall time; "
                     f"{ccd['cpu_s'] / c32['cpu_s']:.1f}x in CPU time. "
                     f"Median of the master dark: camcal {c32['median_value']:.2f} DN, "
                     f"ccdproc {ccd['median_value']:.2f} DN.")
        lines.append(f"- Peak memory at {N_CCDPROC} frames: camcal {c32['peak_mb']:.0f} MB, "
                     f"ccdproc {ccd['peak_mb']:.0f} MB.")
    lines.append(f"- camcal peak memory at 16 / 32 / 64 frames: {cam[16]['peak_mb']:.0f} / {c32['peak_mb']:.0f} / "
                 f"{cam[64]['peak_mb']:.0f} MB (row bands shrink as frames grow, so the peak does not grow).")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""Benchmark: master dark (sigma-clipped) of a 12-megapixel mosaic against the 2-thread decode of the same files.

Run ``python benchmarks/bench_dark.py`` (prints a Markdown section for ``benchmarks/RESULTS.md``); ``--quick``
for a small smoke run (1000x750, 4 and 8 frames); ``--width/--height/--frames/--runs`` to choose; ``--ccdproc``
adds the ccdproc row (about a minute at 12 MP).

1. ``prepare``: the synthetic camera writes the largest frame count of dark DNG frames of a WIDTHxHEIGHT RGGB
   14-bit mosaic into ``benchmarks/_work/dark{W}x{H}/`` once (git-ignored), and (``--ccdproc``) the first 32
   decoded mosaics as float32 FITS files for ccdproc (ccdproc reads FITS, not DNG; the conversion is *not*
   charged to ccdproc, so the comparison favours it).
2. Each measurement runs in its own subprocess; peak memory is ``ru_maxrss`` of that process plus
   its children, read with :mod:`resource`. All runs go in one shuffled order (a fixed seed) and the medians
   are reported.

   - baseline: ``camcal.io.read.load_frame`` + ``Frame.planes`` (uint16) of every file in 2 threads: the decode
     the stack itself does, nothing else.
   - camcal: ``combine_frames(paths, StackOptions("sigma_clip", jobs=2,
     statistics=camcal.calibrate.dark_frames.DARK_STATISTICS))`` on
     the DNG files (decode included): the master dark as the dark stage makes it, with the statistics that stage
     asks for (the clipped value and count, the variance and the mean of all values); its spill is held in memory
     when it fits (``camcal.io.atomic.scratch_fd``);
   - camcal with every statistic (the clipped values' variance as well, one more result map), at the largest
     frame count: what the entries before 3 December 2026 measured;
   - the decode and the spill alone, at the largest frame count: the baseline plus each mosaic written to its
     slot of one memory file, as the stack holds its frames (the memory every median or clipped stack fills,
     and on a virtual machine the kernel's zeroing of it), before any statistics;
   - camcal with the spill on disk (``CAMCAL_SPILL_MEMORY_MB=0``, the system temporary folder), at the largest
     frame count: what the memory spill saves.
   - ccdproc: ``ccdproc.combine(fits_files, method="median", sigma_clip=True, 3, 3,
     mem_limit=1.5e9)``: sigma clipping about the mean (ccdproc's default) then the median.
"""

from __future__ import annotations

import argparse
import contextlib
import json
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

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # run from a checkout without installing
WIDTH, HEIGHT = 4000, 3000
WORK = HERE / "_work" / f"dark{WIDTH}x{HEIGHT}"
N_MAX = 32
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

        from camcal.io.read import load_frame

        mosaic = load_frame(_dng(i)).data.astype(np.float32)
        tmp = _fits(i).with_suffix(".tmp")
        fits.PrimaryHDU(mosaic).writeto(tmp, overwrite=True)
        os.replace(tmp, _fits(i))


def _set_size(width: int, height: int, n_max: int, n_ccdproc: int) -> None:
    global WIDTH, HEIGHT, WORK, N_MAX, N_CCDPROC
    WIDTH, HEIGHT, N_MAX, N_CCDPROC = width, height, n_max, n_ccdproc
    WORK = HERE / "_work" / f"dark{width}x{height}"


def _write_sized(args: tuple[int, int, int, int, int]) -> None:
    _set_size(*args[:4])
    _write_one(args[4])


def prepare() -> None:
    from concurrent.futures import ProcessPoolExecutor

    (WORK / "fits").mkdir(parents=True, exist_ok=True)
    todo = [i for i in range(N_MAX) if not _dng(i).exists() or (i < N_CCDPROC and not _fits(i).exists())]
    if todo:
        with ProcessPoolExecutor(2) as ex:
            list(ex.map(_write_sized, [(WIDTH, HEIGHT, N_MAX, N_CCDPROC, i) for i in todo]))


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


def run_camcal(n: int, jobs: int, every_statistic: bool = False) -> dict:
    """The master dark of the first ``n`` frames as the dark stage makes it (its statistics), or with every
    statistic (``every_statistic``)."""
    from camcal.calibrate.dark_frames import DARK_STATISTICS
    from camcal.calibrate.stack import StackOptions, combine_frames

    paths = [_dng(i) for i in range(n)]
    c0 = _cpu_s()
    t0 = time.perf_counter()
    res = combine_frames(paths, StackOptions(method="sigma_clip", jobs=jobs,
                                             statistics=None if every_statistic else DARK_STATISTICS))
    dt = time.perf_counter() - t0
    import numpy as np

    return {"seconds": dt, "cpu_s": _cpu_s() - c0, "peak_mb": _peak_mb(), "median_value": float(np.median(res.value))}


def run_decode(n: int, jobs: int, spill: bool = False) -> dict:
    """The baseline: decode the same files into uint16 planes in ``jobs`` threads, nothing kept.

    ``spill``: each frame's mosaic is also written to its slot of one memory file
    (:func:`camcal.io.atomic.scratch_fd`), as the stack holds its frames: the decode plus the memory every
    median or clipped stack must fill, before any statistics."""
    from concurrent.futures import ThreadPoolExecutor

    import numpy as np

    from camcal.io.atomic import scratch_fd
    from camcal.io.read import load_frame

    paths = [_dng(i) for i in range(n)]
    c0 = _cpu_s()
    t0 = time.perf_counter()
    with (scratch_fd("bench-spill-", n * 2 * WIDTH * HEIGHT) if spill else contextlib.nullcontext((None, ""))
          ) as (fd, _name):

        def one(i: int) -> int:
            frame = load_frame(paths[i], defaults={})
            if spill:
                data = np.ascontiguousarray(frame.data)
                mv = memoryview(data.reshape(-1)).cast("B")
                done = 0
                while done < mv.nbytes:
                    done += os.pwrite(fd, mv[done:], i * mv.nbytes + done)
            return int(frame.planes(dtype=frame.data.dtype)[0, 0, 0])

        with ThreadPoolExecutor(jobs) as pool:
            list(pool.map(one, range(n)))
    dt = time.perf_counter() - t0
    return {"seconds": dt, "cpu_s": _cpu_s() - c0, "peak_mb": _peak_mb(), "median_value": float(np.nan)}


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


def _sub(*args: str, env: dict[str, str] | None = None) -> dict:
    size = ("--width", str(WIDTH), "--height", str(HEIGHT))
    proc = subprocess.run([sys.executable, __file__, *size, *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})})
    if proc.returncode:
        raise SystemExit(f"benchmark subprocess {args} failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _median(runs: list[dict], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--one", choices=["camcal", "camcal_all", "ccdproc", "decode", "decode_spill"])
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--width", type=int, default=4000)
    ap.add_argument("--height", type=int, default=3000)
    ap.add_argument("--frames", default="8,16,32", help="frame counts, comma-separated")
    ap.add_argument("--runs", type=int, default=3, help="runs of each measurement, in a shuffled order (medians)")
    ap.add_argument("--ccdproc", action="store_true", help="add ccdproc at 32 frames (slow)")
    ap.add_argument("--quick", action="store_true", help="smoke run: 1000x750, 4 and 8 frames, 1 run")
    args = ap.parse_args()
    if args.quick:
        args.width, args.height, args.frames, args.runs = 1000, 750, "4,8", 1
    counts = [int(v) for v in args.frames.split(",")]
    _set_size(args.width, args.height, max(counts), N_CCDPROC if args.ccdproc else 0)
    if args.one in ("camcal", "camcal_all"):
        print(json.dumps(run_camcal(args.n, args.jobs, every_statistic=args.one == "camcal_all")))
        return
    if args.one in ("decode", "decode_spill"):
        print(json.dumps(run_decode(args.n, args.jobs, spill=args.one == "decode_spill")))
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
    load_start = os.getloadavg()[0]
    dec: dict[int, list[dict]] = {n: [] for n in counts}
    cam: dict[int, list[dict]] = {n: [] for n in counts}
    disk: list[dict] = []
    floor: list[dict] = []
    every: list[dict] = []
    # every run in a shuffled order (fixed seed): on a virtual machine a run is slower or faster by up to a quarter
    # depending on what the run before it did with memory (measured: the same code 1.53-1.94 s in fixed orders),
    # so a fixed alternation can favour one side
    plan = [(kind, n) for _ in range(args.runs) for n in counts for kind in ("decode", "camcal")]
    plan += [(kind, max(counts)) for kind in ("disk", "decode_spill", "camcal_all") for _ in range(args.runs)]
    random.Random(0).shuffle(plan)
    for kind, n in plan:
        if kind == "decode":
            dec[n].append(_sub("--one", "decode", "--n", str(n), "--jobs", str(args.jobs)))
        elif kind == "camcal":
            cam[n].append(_sub("--one", "camcal", "--n", str(n), "--jobs", str(args.jobs)))
        elif kind == "decode_spill":
            floor.append(_sub("--one", "decode_spill", "--n", str(n), "--jobs", str(args.jobs)))
        elif kind == "camcal_all":
            every.append(_sub("--one", "camcal_all", "--n", str(n), "--jobs", str(args.jobs)))
        else:
            disk.append(_sub("--one", "camcal", "--n", str(n), "--jobs", str(args.jobs),
                             env={"CAMCAL_SPILL_MEMORY_MB": "0"}))
    ccd = _sub("--one", "ccdproc", "--n", str(N_CCDPROC)) if args.ccdproc else None

    mp = WIDTH * HEIGHT / 1e6
    lines = [
        "## dark",
        "",
        f"Master dark (sigma-clipped) of {WIDTH}x{HEIGHT} ({mp:.0f} MP) 14-bit RGGB dark frames written by the "
        f"synthetic camera, against decoding the same files in {args.jobs} threads. Machine: {os.cpu_count()} "
        f"cores, {platform.machine()}, Python {platform.python_version()}, {date.today().isoformat()}. "
        f"`python benchmarks/bench_dark.py --width {WIDTH} --height {HEIGHT} --frames {args.frames} --runs "
        f"{args.runs}{' --ccdproc' if args.ccdproc else ''}`; each run a separate subprocess, all runs in a "
        "shuffled order, medians; peak memory = ru_maxrss of the process plus its children.",
        "",
        f"| frames | decode, {args.jobs} threads: wall (s) | CPU (s) | peak (MB) | camcal combine_frames "
        f"(sigma_clip, jobs={args.jobs}, the dark stage's statistics): wall (s) | CPU (s) | peak (MB) | ratio wall "
        "| ratio CPU |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n in counts:
        dw, dc, dm = (_median(dec[n], k) for k in ("seconds", "cpu_s", "peak_mb"))
        cw, cc, cm = (_median(cam[n], k) for k in ("seconds", "cpu_s", "peak_mb"))
        lines.append(f"| {n} | {dw:.2f} | {dc:.2f} | {dm:.0f} | {cw:.2f} | {cc:.2f} | {cm:.0f} | **{cw / dw:.2f}** "
                     f"| {cc / dc:.2f} |")
    lines.append("")
    lines.append(f"- Load average (1 min) at the start and the end of the run: {load_start:.1f}, "
                 f"{os.getloadavg()[0]:.1f} (other jobs share the machine; wall times are sensitive to it, CPU times "
                 "much less).")
    lines.append("- camcal runs, wall (s): " + "; ".join(
        f"{n} frames " + ", ".join(f"{r['seconds']:.2f}" for r in cam[n]) for n in counts)
        + "; decode: " + "; ".join(f"{n} frames " + ", ".join(f"{r['seconds']:.2f}" for r in dec[n])
                                    for n in counts) + ".")
    nmax = max(counts)
    dw = _median(dec[nmax], "seconds")
    lines.append(f"- The spill on disk instead (`CAMCAL_SPILL_MEMORY_MB=0`, {nmax} frames): "
                 f"{_median(disk, 'seconds'):.2f} s wall, {_median(disk, 'cpu_s'):.2f} s CPU, "
                 f"{_median(disk, 'peak_mb'):.0f} MB, **{_median(disk, 'seconds') / dw:.2f}x** the decode (runs: "
                 + ", ".join(f"{r['seconds']:.2f}" for r in disk) + ").")
    fw = _median(floor, "seconds")
    cw = _median(cam[nmax], "seconds")
    lines.append(f"- The decode and the spill alone ({nmax} frames decoded in {args.jobs} threads, each mosaic "
                 "written to its slot of one memory file as the stack holds it, no statistics): "
                 f"{fw:.2f} s wall, {_median(floor, 'cpu_s'):.2f} s CPU, {fw / dw:.2f}x the decode (runs: "
                 + ", ".join(f"{r['seconds']:.2f}" for r in floor) + f"). camcal is **{cw / fw:.2f}x** that: the "
                 f"band statistics and the result maps take {cw - fw:.2f} s.")
    ew = _median(every, "seconds")
    lines.append(f"- Every statistic instead ({nmax} frames; the clipped values' variance too, one more result map, "
                 f"as the entries before 3 December measured): {ew:.2f} s wall, {_median(every, 'cpu_s'):.2f} s CPU, "
                 f"{_median(every, 'peak_mb'):.0f} MB, **{ew / dw:.2f}x** the decode (runs: "
                 + ", ".join(f"{r['seconds']:.2f}" for r in every) + ").")
    lines.append("- camcal peak memory at " + " / ".join(str(n) for n in counts) + " frames: "
                 + " / ".join(f"{_median(cam[n], 'peak_mb'):.0f}" for n in counts)
                 + " MB (row bands shrink as frames grow, so the peak does not grow).")
    if ccd:
        c = cam.get(N_CCDPROC)
        cmp = (f"; **{ccd['seconds'] / _median(c, 'seconds'):.1f}x** slower than camcal in wall time, "
               f"{ccd['cpu_s'] / _median(c, 'cpu_s'):.1f}x in CPU time" if c else "")
        lines.append(f"- ccdproc.combine (median, sigma_clip 3/3, mem_limit 1.5 GB), FITS input, {N_CCDPROC} frames: "
                     f"{ccd['seconds']:.1f} s wall, {ccd['cpu_s']:.1f} s CPU, {ccd['peak_mb']:.0f} MB{cmp}; median "
                     f"of the master dark {ccd['median_value']:.2f} DN"
                     + (f" (camcal {c[0]['median_value']:.2f} DN)." if c else "."))
    print("\n".join(lines))


if __name__ == "__main__":
    main()

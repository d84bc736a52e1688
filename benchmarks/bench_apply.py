"""Benchmark: one 24-megapixel DNG to a radiance EXR, against the floor; batch throughput on 2 cores.

Run ``python benchmarks/bench_apply.py``; prints a Markdown section for ``benchmarks/RESULTS.md``.
``--batch`` measures only the batch (below) at ``--counts 8,16,32`` photos; ``--quick`` is a small smoke run
(1200x800, 2 and 4 photos); ``--width/--height`` choose the photo size.

Batch (``--batch``): ``run_batch(profile, photos[:n], out, BatchOptions(), jobs=2)`` (the CLI's default
output, ``BatchOptions``' precision and compression) in a fresh subprocess per run, against the floor of the
same photos: a 2-process (spawn) pool whose workers do the floor's rawpy decode + OpenImageIO write per photo.
Photos/s of each, their ratio, and the peak RSS of the largest worker (``RUSAGE_CHILDREN``, fresh per run), at
each count: flat in the count. All runs in one shuffled order; medians.

Floor (the unavoidable work, measured in the same run): ``rawpy`` decode of the DNG (mosaic copied
out) plus an OpenImageIO write of an EXR of the same size as camcal's output (8 float32 channels at
3000x2000, with ``BatchOptions``' default compression). camcal: :func:`camcal.io.read.load_frame` +
:func:`camcal.apply.photo.apply_prepared` +
:func:`camcal.io.exr.write_exr` (what a batch worker does per photo; the profile-dependent maps are
prepared once per worker and timed separately). Target: camcal ≤ 1.3x the floor.

The 24-megapixel profile is assembled from the synthetic camera's truth (dark maps, radial
vignetting) and the spectral sensitivity and responses of a calibrated small session: a speed
benchmark, not an accuracy one. Files go to ``benchmarks/_work/`` (git-ignored) and are written once.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
import platform
import random
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

WORK = Path(__file__).resolve().parent / "_work" / "apply24mp"
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout without installing
WIDTH, HEIGHT = 6000, 4000
N_BATCH = 8
REPEATS = 5


def _small_profile(work: Path):
    from camcal.calibrate.run import calibrate_session
    from camcal.models.profile import load_profile, save_profile
    from camcal.synth.camera import SyntheticCamera
    from camcal.synth.session import SessionPlan, write_session

    path = work / "small.camcal"
    if not path.exists():
        session = write_session(work / "small_session", SyntheticCamera(), SessionPlan())
        profile, _ = calibrate_session(session)
        save_profile(profile, path)
        shutil.rmtree(work / "small_session", ignore_errors=True)
    return load_profile(path)


def build(work: Path):
    """The 24 MP camera, profile and photos (written once)."""
    from camcal.frame import PLANES
    from camcal.models.dark import DarkModel
    from camcal.models.flat import FlatModel
    from camcal.models.profile import CameraIdentity, load_profile, save_profile
    from camcal.models.spectra import gaussian_line
    from camcal.synth.camera import Scene, SensorParams, SyntheticCamera
    from camcal.synth.session import exposure_for_level

    work.mkdir(parents=True, exist_ok=True)
    cam = SyntheticCamera(SensorParams(width=WIDTH, height=HEIGHT))
    prof_path = work / "cam24.camcal"
    photos = [work / f"photo_{i:02d}.dng" for i in range(N_BATCH)]
    if prof_path.exists() and photos[0].exists():
        for ph in photos[1:]:
            if not ph.exists():
                shutil.copyfile(photos[0], ph)  # same content: throughput does not depend on it
        # written again by this code, so its maps are stored as camcal stores them now (their encoding sets how
        # long a worker takes to load them)
        return save_profile(load_profile(prof_path), prof_path), prof_path, photos
    small = _small_profile(work)
    p = cam.params
    k = cam.dn_per_electron(p.iso_base)
    black = np.asarray(p.black_level_dn, np.float32)[:, None, None]
    dark = DarkModel(
        bias_dn=(black + cam._maps["bias_dn"]).astype(np.float32),
        dark_current_dn_per_s=(cam.dark_current_map_e_per_s * k).astype(np.float32),
        dark_current_unc_dn_per_s=np.full((4, HEIGHT // 2, WIDTH // 2), 0.05, np.float32),
        read_noise_dn=np.full((4, HEIGHT // 2, WIDTH // 2), p.read_noise_e * k, np.float32),
        defects=cam.hot_pixel_mask.astype(np.uint8), iso=p.iso_base, cfa_pattern=p.cfa_pattern, temperature_c=None,
        channels=small.dark.channels, black_level_dn=tuple(p.black_level_dn), white_level_dn=float(p.white_dn),
    )
    cx, cy = cam.optical_centre_px
    from camcal.frame import plane_offsets

    off = plane_offsets(p.cfa_pattern)
    flat = FlatModel(channels=PLANES, centre_px={c: ((cx - off[c][1]) / 2, (cy - off[c][0]) / 2) for c in PLANES},
                     k={c: tuple(p.vignetting_k) for c in PLANES}, model_2d=None, prnu=None,
                     residual_rms={c: 0.0 for c in PLANES}, shape=(HEIGHT // 2, WIDTH // 2), cfa_pattern=p.cfa_pattern)
    profile = dataclasses.replace(
        small, camera=CameraIdentity(p.make, p.model, p.serial, p.cfa_pattern, WIDTH, HEIGHT), dark=dark, flat=flat,
        content_sha256=None)
    profile = save_profile(profile, prof_path)
    line = 2.0 * gaussian_line(663.0, 5.0)
    t = exposure_for_level(cam, line, 0.4, 100, 4.0)
    rng = np.random.default_rng(5)
    cam.write_dng(photos[0], Scene.uniform(line), exposure_s=t, iso=100, f_number=4.0, rng=rng)
    for ph in photos[1:]:
        shutil.copyfile(photos[0], ph)  # same content: throughput does not depend on it
    return load_profile(prof_path), prof_path, photos


def floor_once(photo: Path, out: Path) -> float:
    """Decode ``photo`` with rawpy and write an EXR of camcal's output size with its default encoding (seconds).

    Eight float32 channels at half resolution (R, G, B, L663 and a 1σ channel each), with the compression of
    ``BatchOptions()``: the floor writes what camcal writes, so the ratio reads as camcal's distance to it.
    """
    import OpenImageIO as oiio
    import rawpy

    from camcal.apply.batch import BatchOptions

    compression = BatchOptions().compression
    t0 = time.perf_counter()
    with rawpy.imread(str(photo)) as raw:
        mosaic = np.array(raw.raw_image_visible, dtype=np.uint16, copy=True)
    h, w = mosaic.shape[0] // 2, mosaic.shape[1] // 2
    pixels = np.empty((h, w, 8), np.float32)
    pixels[..., :4] = np.moveaxis(mosaic.reshape(h, 2, w, 2).transpose(1, 3, 0, 2).reshape(4, h, w), 0, -1)
    pixels[..., 4:] = pixels[..., :4]
    pixels *= np.float32(1.2345678e-4)  # non-integer floats, so a compression sees them like camcal's radiances
    spec = oiio.ImageSpec(w, h, 8, oiio.FLOAT)
    spec.channelnames = ("R", "G", "B", "L663", "L663_unc", "R_unc", "G_unc", "B_unc")
    spec.attribute("DateTime", "2026:01:01 12:00:00")
    spec.attribute("compression", compression)
    o = oiio.ImageOutput.create(str(out))
    o.open(str(out), spec)
    o.write_image(pixels)
    o.close()
    return time.perf_counter() - t0


def camcal_once(photo: Path, plan, out: Path) -> float:
    from camcal.apply.batch import BatchOptions
    from camcal.apply.photo import apply_prepared
    from camcal.io.exr import write_exr
    from camcal.io.read import load_frame

    opts = BatchOptions()  # the default output
    t0 = time.perf_counter()
    image = apply_prepared(load_frame(photo), plan)
    write_exr(out, image.channels, image.metadata, precision=opts.precision, compression=opts.compression)
    return time.perf_counter() - t0


def breakdown(photo: Path, plan, out: Path) -> dict[str, float]:
    """Seconds of each step of :func:`camcal_once` (wall and CPU of this process)."""
    from camcal.apply.batch import BatchOptions
    from camcal.apply.photo import apply_prepared
    from camcal.io.exr import write_exr
    from camcal.io.read import load_frame

    def clock():
        r = resource.getrusage(resource.RUSAGE_SELF)
        return time.perf_counter(), r.ru_utime + r.ru_stime

    c0 = clock()
    frame = load_frame(photo)
    c1 = clock()
    image = apply_prepared(frame, plan)
    c2 = clock()
    opts = BatchOptions()  # the default output
    write_exr(out, image.channels, image.metadata, precision=opts.precision, compression=opts.compression)
    c3 = clock()
    return {"decode": (c1[0] - c0[0], c1[1] - c0[1]), "apply": (c2[0] - c1[0], c2[1] - c1[1]),
            "write": (c3[0] - c2[0], c3[1] - c2[1])}


def _floor_photo(args: tuple[str, str]) -> float:
    return floor_once(Path(args[0]), Path(args[1]))


def batch_once(kind: str, n: int, jobs: int) -> dict:
    """One batch of the first ``n`` photos, in this (fresh) process: wall time and the largest worker's peak RSS."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from camcal.apply.batch import BatchOptions, run_batch

    _, prof_path, photos = build(WORK)
    with tempfile.TemporaryDirectory(dir=WORK) as tmp:
        t0 = time.perf_counter()
        if kind == "camcal":
            rep = run_batch(prof_path, photos[:n], Path(tmp) / "out", BatchOptions(), jobs=jobs)
            assert rep.counts["done"] == n, rep.counts
        else:
            ctx = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(jobs, mp_context=ctx) as pool:
                list(pool.map(_floor_photo, [(str(p), str(Path(tmp) / f"{p.name}.exr")) for p in photos[:n]]))
        dt = time.perf_counter() - t0
    return {"seconds": dt, "worker_peak_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}


def batch_section(counts: list[int], jobs: int, runs: int) -> None:
    from camcal.apply.batch import BatchOptions

    build(WORK)
    opts = BatchOptions()
    size = ["--width", str(WIDTH), "--height", str(HEIGHT), "--counts", ",".join(map(str, counts))]

    def sub(kind: str, n: int) -> dict:
        proc = subprocess.run([sys.executable, __file__, *size, "--one", kind, "--n", str(n), "--jobs", str(jobs)],
                              capture_output=True, text=True)
        if proc.returncode:
            raise SystemExit(f"batch run {kind} {n} failed:\n{proc.stderr}")
        return json.loads(proc.stdout.strip().splitlines()[-1])

    res: dict[tuple[str, int], list[dict]] = {(k, n): [] for k in ("floor", "camcal") for n in counts}
    plan = [key for _ in range(runs) for key in res]
    random.Random(0).shuffle(plan)  # one shuffled order: a run's time depends on the run before it (bench_dark.py)
    for kind, n in plan:
        res[kind, n].append(sub(kind, n))

    def med(kind: str, n: int, key: str) -> float:
        return statistics.median(r[key] for r in res[kind, n])

    mp = WIDTH * HEIGHT / 1e6
    print("### batch\n")
    print(f"Machine: {os.cpu_count()} cores, CPython {platform.python_version()}, {platform.machine()}; "
          f"{datetime.date.today().isoformat()}; load average {os.getloadavg()[0]:.1f} at the end of the run.\n")
    print(f"`python benchmarks/bench_apply.py --batch --width {WIDTH} --height {HEIGHT} --counts "
          f"{','.join(map(str, counts))} --jobs {jobs} --runs {runs}`: {WIDTH}x{HEIGHT} ({mp:.0f} MP) RGGB 14-bit "
          f"DNGs → EXR (R, G, B, L663 and their 1σ channels, {opts.precision} {opts.compression}: the default "
          f"output), `run_batch(jobs={jobs})` in a "
          f"fresh process per run against the floor (rawpy decode + OpenImageIO write of the same size, a {jobs}-"
          f"process spawn pool, start-up included in both); medians of {runs} runs each, all in one shuffled order.\n")
    print("| photos | floor (photos/s) | floor worker peak (MB) | camcal (photos/s) | camcal worker peak (MB) "
          "| camcal / floor (throughput) |")
    print("|---:|---:|---:|---:|---:|---:|")
    for n in counts:
        f, c = n / med("floor", n, "seconds"), n / med("camcal", n, "seconds")
        print(f"| {n} | {f:.2f} | {med('floor', n, 'worker_peak_mb'):.0f} | **{c:.2f}** | "
              f"{med('camcal', n, 'worker_peak_mb'):.0f} | {c / f:.2f} |")
    print()
    print("Runs, wall (s): " + "; ".join(
        f"{n} photos: camcal " + ", ".join(f"{r['seconds']:.1f}" for r in res["camcal", n])
        + " / floor " + ", ".join(f"{r['seconds']:.1f}" for r in res["floor", n]) for n in counts) + ".")


def main() -> None:
    import argparse

    global WIDTH, HEIGHT, N_BATCH, WORK
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=WIDTH)
    ap.add_argument("--height", type=int, default=HEIGHT)
    ap.add_argument("--batch", action="store_true", help="only the batch throughput, at --counts photos")
    ap.add_argument("--counts", default="8,16,32", help="batch sizes, comma-separated")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--runs", type=int, default=2, help="runs per batch size, in one shuffled order (medians)")
    ap.add_argument("--quick", action="store_true", help="smoke run: 1200x800, batches of 2 and 4, one run")
    ap.add_argument("--one", choices=["camcal", "floor"], help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=8, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.quick:
        args.width, args.height, args.counts, args.runs = 1200, 800, "2,4", 1
    counts = [int(v) for v in args.counts.split(",")]
    WIDTH, HEIGHT = args.width, args.height
    N_BATCH = max(counts + [N_BATCH])
    if (WIDTH, HEIGHT) != (6000, 4000):
        WORK = WORK.parent / f"apply{WIDTH}x{HEIGHT}"
    if args.one:
        print(json.dumps(batch_once(args.one, args.n, args.jobs)))
        return
    if args.batch:
        batch_section(counts, args.jobs, args.runs)
        return
    single_section()
    print()
    batch_section(counts, args.jobs, args.runs)


def single_section() -> None:
    from camcal.apply.batch import BatchOptions, run_batch
    from camcal.apply.photo import prepare

    profile, prof_path, photos = build(WORK)
    n_batch = min(8, len(photos))
    photos = photos[:n_batch]
    t0 = time.perf_counter()
    plan = prepare(profile)
    t_prepare = time.perf_counter() - t0
    with tempfile.TemporaryDirectory(dir=WORK) as tmp:
        tmp = Path(tmp)
        floor, ours = [], []
        for _ in range(REPEATS):  # interleaved, best of
            floor.append(floor_once(photos[0], tmp / "floor.exr"))
            ours.append(camcal_once(photos[0], plan, tmp / "camcal.io.exr"))
        f, c = min(floor), min(ours)
        size_floor = (tmp / "floor.exr").stat().st_size / 1e6
        size_ours = (tmp / "camcal.io.exr").stat().st_size / 1e6
        # where camcal's time goes (one more run, timed per step)
        steps = breakdown(photos[0], plan, tmp / "steps.exr")
        # batch throughput: the CLI's path (process pool of 2, profile loaded once per worker); the
        # workers' peak RSS after a batch of 2 and after one of n_batch (it must not grow with N)
        run_batch(prof_path, photos[:2], tmp / "batch2", BatchOptions(), jobs=2)
        rss2 = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        t0 = time.perf_counter()
        rep = run_batch(prof_path, photos, tmp / "batch", BatchOptions(), jobs=2)
        t_batch = time.perf_counter() - t0
        rss_n = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        assert rep.counts["done"] == n_batch, rep.counts
        per_photo = sorted(r.seconds for r in rep.results)
        t0 = time.perf_counter()
        run_batch(prof_path, photos, tmp / "batch", BatchOptions(), jobs=2)
        t_resume = time.perf_counter() - t0
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = float("nan")
    print("## apply\n")
    print(f"Machine: {os.cpu_count()} cores, CPython {platform.python_version()}, {platform.machine()}; "
          f"{datetime.date.today().isoformat()}; load average {load:.1f} at the end of the run.\n")
    print(f"`python benchmarks/bench_apply.py`: one {WIDTH}x{HEIGHT} (24 MP) RGGB 14-bit DNG → EXR with R, G, B, "
          f"L663 and their 1σ channels at {WIDTH // 2}x{HEIGHT // 2}, {BatchOptions().precision} "
          f"{BatchOptions().compression} (the default); best of {REPEATS}, interleaved.\n")
    print("| what | time (s) | ratio to floor |")
    print("|---|---:|---:|")
    print(f"| floor: rawpy decode + OpenImageIO EXR write of the same size ({size_floor:.0f} MB) | {f:.3f} | 1.00 |")
    print(f"| camcal: load_frame + apply + write_exr ({size_ours:.0f} MB) | {c:.3f} | **{c / f:.2f}** |")
    print(f"| once per worker: prepare (flat gain maps, estimator) | {t_prepare:.3f} | |")
    print()
    print(f"Target ≤ 1.3x the floor: {'met' if c / f <= 1.3 else 'NOT met'} ({c / f:.2f}x).\n")
    print("Where camcal's time goes (one more run; CPU > wall means threads):\n")
    print("| step | wall (s) | CPU (s) |")
    print("|---|---:|---:|")
    for k, (wall, cpu) in steps.items():
        print(f"| {k} | {wall:.3f} | {cpu:.3f} |")
    print()
    print(f"Batch of {n_batch} photos on a process pool of 2 (`run_batch(..., jobs=2)`, spawn start, profile "
          f"loaded once per worker): {t_batch:.1f} s = **{n_batch / t_batch:.2f} photos/s** (per photo in a "
          f"worker: {per_photo[0]:.1f}–{per_photo[-1]:.1f} s, the first of each worker includes loading the "
          f"profile); the rerun skips all {n_batch} from the EXR headers in {t_resume:.2f} s. Peak RSS of a "
          f"worker: {rss2:.0f} MB after a batch of 2, {rss_n:.0f} MB after a batch of {n_batch} (the maximum "
          "over all workers so far; it does not grow with the number of photos).")

if __name__ == "__main__":
    sys.exit(main())

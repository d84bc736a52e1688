"""Benchmark: a whole ``camcal calibrate`` of a realistic 24 MP session against decoding each of its files once.

Run ``python benchmarks/bench_calibrate.py`` (prints a Markdown section for ``benchmarks/RESULTS.md``);
``--quick`` for a smoke run (600x400); ``--width/--height`` for another sensor size; ``--runs`` runs of each;
``--prepare`` only writes the session (the synthetic camera takes several minutes at 24 MP: write it beforehand).

The session (written once by the synthetic camera into ``benchmarks/_work/calib{W}x{H}/``, git-ignored): 16 bias,
3 x 8 dark (8, 16, 32 s), 8 flat, 20 linearity steps and 61 sweep wavelengths (400-700 nm, one frame each),
RAW only: 129 DNG files.

Each measurement is a fresh process (medians; all runs in one shuffled order):

- baseline: ``camcal.io.read.load_frame`` + ``Frame.planes`` of every file once, in 2 threads (camcal's own decode);
- the same under camcal's allocator policy (``camcal.io.allocator.use_frame_allocator``, which the command line
  sets): the decode's own speed-up from it, so that the ratio is not flattered by it;
- the same plus each file's SHA-256 (``camcal.io.hashing.sha256_file``, the hash every input gets in the profile's
  provenance): the floor of a calibration that records what it was made from;
- ``camcal calibrate SESSION -o P.camcal``: the whole command, wall and CPU time (children included), and the
  same with glibc's own allocator policy (``CAMCAL_MALLOC=default``);
- where the time goes: ``calibrate_session`` + ``save_profile`` in one process with each stage's entry point
  timed (wall, CPU, system CPU and minor page faults of the process, all its threads): screening (every frame's
  header read: each stage judges its frames as it decodes them), dark stacks and fit, flat, linearity, sweep,
  EMVA sheet, input hashes, writing the profile; ``--runs`` such runs among the others, each stage's median and
  its share of the median total, imports excluded, under the command line's allocator policy.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))  # run from a checkout without installing

# (module attribute of camcal.calibrate.run, label): the stages' entry points, timed where calibrate calls them
STAGES = (
    ("index_session", "index the session (folders, manifests)"),
    ("screen_session", "screening: every frame's header read (its stage decodes and judges it)"),
    ("measure_dark", "dark + bias stacks (each frame decoded and judged once)"),
    ("fit_dark", "dark fit"),
    ("measure_flat", "master flat (each frame decoded and judged once)"),
    ("fit_flat", "flat fit"),
    ("measure_response", "linearity series (each frame decoded and judged once)"),
    ("fit_response", "linearity fit"),
    ("measure_sweep", "sweep (each row decoded and judged once)"),
    ("fit_sweep", "spectral sensitivity fit"),
    ("build_sheet", "EMVA 1288 sheet"),
    ("_inputs", "input hashes"),
)


def plan():
    from camcal.synth.session import SessionPlan

    return SessionPlan(n_bias=16, dark_exposures_s=(8.0, 16.0, 32.0), n_dark=8, n_flat=8, linearity_steps=20,
                       n_sweep=1, linearity_jpeg=False, sweep_jpeg=False)


def session_dir(width: int, height: int) -> Path:
    return HERE / "_work" / f"calib{width}x{height}" / "session"


def prepare(width: int, height: int) -> Path:
    """Write the session once (a finished session has ``truth.json``)."""
    import shutil

    from camcal.synth.camera import SensorParams, SyntheticCamera
    from camcal.synth.session import write_session

    out = session_dir(width, height)
    if (out / "truth.json").is_file():
        return out
    shutil.rmtree(out, ignore_errors=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    write_session(out, SyntheticCamera(SensorParams(width=width, height=height)), plan())
    print(f"wrote {out} in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return out


def files(session: Path) -> list[Path]:
    from camcal.io.folders import list_frames

    return [p for d in sorted(session.iterdir()) if d.is_dir() for p in list_frames(d)]


def _cpu_s() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run_decode(session: Path, hashed: bool = False, policy: bool = False) -> dict:
    """Decode every file once in 2 threads (and, ``hashed``, take its SHA-256 right after, as calibrate does;
    ``policy``: under camcal's allocator policy)."""
    from concurrent.futures import ThreadPoolExecutor

    from camcal.io.allocator import use_frame_allocator
    from camcal.io.hashing import sha256_file
    from camcal.io.read import load_frame

    if policy and not use_frame_allocator():
        raise SystemExit("the allocator policy does not apply here (not glibc, or set in the environment)")

    def one(path: Path) -> int:
        frame = load_frame(path)
        if hashed:
            sha256_file(path)
        return int(frame.planes(dtype=frame.data.dtype)[0, 0, 0])

    paths = files(session)
    c0, t0 = _cpu_s(), time.perf_counter()
    with ThreadPoolExecutor(2) as pool:
        list(pool.map(one, paths))
    return {"seconds": time.perf_counter() - t0, "cpu_s": _cpu_s() - c0, "files": len(paths)}


def run_cli(session: Path, glibc_policy: bool = False) -> dict:
    env = {**os.environ, "CAMCAL_MALLOC": "default"} if glibc_policy else None
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "p.camcal"
        c0, t0 = _cpu_s(), time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "camcal", "calibrate", str(session), "-o", str(out)],
                              capture_output=True, text=True, env=env)
        dt = time.perf_counter() - t0
        if proc.returncode:
            raise SystemExit(f"camcal calibrate failed:\n{proc.stderr}")
    return {"seconds": dt, "cpu_s": _cpu_s() - c0}


def run_stages(session: Path) -> dict:
    """calibrate_session + save_profile in this process, each stage's entry point timed (wall, CPU, system CPU,
    minor page faults) and the process's peak resident memory when it ended (MB: the stage that raises it is the
    one that sets the calibration's peak)."""
    import camcal.calibrate.run as cal
    from camcal.io.allocator import use_frame_allocator
    from camcal.models.profile import save_profile

    use_frame_allocator()  # as the command line does
    spent: dict[str, list[float]] = {}
    peak: dict[str, float] = {}

    def usage() -> list[float]:
        """Wall, CPU, system CPU (s) and minor page faults of this process so far (all its threads)."""
        r = resource.getrusage(resource.RUSAGE_SELF)
        return [time.perf_counter(), time.process_time(), r.ru_stime, float(r.ru_minflt)]

    def add(name: str, start: list[float]) -> None:
        acc = spent.setdefault(name, [0.0, 0.0, 0.0, 0.0])
        for k, (a, b) in enumerate(zip(usage(), start, strict=True)):
            acc[k] += a - b
        peak[name] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    def timed(name, fn):
        def wrapper(*args, **kwargs):
            start = usage()
            try:
                return fn(*args, **kwargs)
            finally:
                add(name, start)
        return wrapper

    for name, _ in STAGES:
        if hasattr(cal, name):
            setattr(cal, name, timed(name, getattr(cal, name)))
    with tempfile.TemporaryDirectory() as tmp:
        start = usage()
        profile, _ = cal.calibrate_session(session)
        saving = usage()
        save_profile(profile, Path(tmp) / "p.camcal")
        add("save_profile", saving)
        total = [a - b for a, b in zip(usage(), start, strict=True)]
    return {"total": total, "spent": spent, "peak_mb": peak}


def _sub(*args: str) -> dict:
    proc = subprocess.run([sys.executable, __file__, *args], capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"benchmark subprocess {args} failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=6000)
    ap.add_argument("--height", type=int, default=4000)
    ap.add_argument("--runs", type=int, default=3, help="runs of each measurement, in one shuffled order (medians)")
    ap.add_argument("--quick", action="store_true", help="smoke run: 600x400, one run")
    ap.add_argument("--prepare", action="store_true", help="only write the session (once; it is kept)")
    ap.add_argument("--one", choices=["decode", "decode_policy", "hashed", "cli", "cli_glibc", "stages"],
                    help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.quick:
        args.width, args.height, args.runs = 600, 400, 1
    session = session_dir(args.width, args.height)
    if args.one:
        run = {"decode": run_decode, "decode_policy": lambda s: run_decode(s, policy=True),
               "hashed": lambda s: run_decode(s, hashed=True), "cli": run_cli,
               "cli_glibc": lambda s: run_cli(s, glibc_policy=True), "stages": run_stages}[args.one]
        print(json.dumps(run(session)))
        return
    prepare(args.width, args.height)
    if args.prepare:
        return
    for p in files(session):
        p.read_bytes()  # page cache warm for every run
    size = ("--width", str(args.width), "--height", str(args.height))
    runs: dict[str, list[dict]] = {"decode": [], "decode_policy": [], "hashed": [], "cli": [], "cli_glibc": [],
                                   "stages": []}
    plan = [kind for _ in range(args.runs) for kind in runs]
    random.Random(0).shuffle(plan)  # one shuffled order: a run's time depends on the run before it (bench_dark.py)
    for kind in plan:
        runs[kind].append(_sub(*size, "--one", kind))
    dec, hashed, cli = runs["decode"], runs["hashed"], runs["cli"]
    dec_p, cli_g = runs["decode_policy"], runs["cli_glibc"]
    # each stage's median over the runs (a stage moves by up to 2 s between runs of the same code)
    names = {name for r in runs["stages"] for name in r["spent"]}
    spent = {name: [statistics.median(r["spent"].get(name, [0.0] * 4)[k] for r in runs["stages"]) for k in range(4)]
             for name in names}
    peaks = {name: statistics.median(r["peak_mb"][name] for r in runs["stages"] if name in r["peak_mb"])
             for name in names}
    total_wall, total_cpu, total_sys, total_faults = (statistics.median(r["total"][k] for r in runs["stages"])
                                                      for k in range(4))

    def med(runs: list[dict], key: str) -> float:
        return statistics.median(r[key] for r in runs)

    d, h, c = med(dec, "seconds"), med(hashed, "seconds"), med(cli, "seconds")
    dp, cg = med(dec_p, "seconds"), med(cli_g, "seconds")
    n = dec[0]["files"]
    lines = [
        "## calibrate",
        "",
        f"Machine: {os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}, "
        f"{date.today().isoformat()}; load average {os.getloadavg()[0]:.1f} at the end of the run.",
        "",
        f"`python benchmarks/bench_calibrate.py --width {args.width} --height {args.height} --runs {args.runs}`: "
        f"a {args.width}x{args.height} ({args.width * args.height / 1e6:.0f} MP) synthetic session of {n} DNGs "
        "(16 bias, 3 x 8 dark, 8 flat, 20 linearity, 61 sweep), each measurement a fresh process, all runs in one "
        "shuffled order, medians.",
        "",
        "| what | wall (s) | CPU (s) | ratio to the decode (wall) |",
        "|---|---:|---:|---:|",
        f"| baseline: decode each file once (load_frame + planes, 2 threads) | {d:.2f} | {med(dec, 'cpu_s'):.2f} "
        "| 1.00 |",
        f"| the same under camcal's allocator policy (`camcal.io.allocator`) | {dp:.2f} | {med(dec_p, 'cpu_s'):.2f} "
        f"| {dp / d:.2f} |",
        f"| the same, and each file's SHA-256 (as the profile's provenance records it) | {h:.2f} | "
        f"{med(hashed, 'cpu_s'):.2f} | {h / d:.2f} |",
        f"| `camcal calibrate SESSION -o P.camcal` (whole process) | {c:.2f} | {med(cli, 'cpu_s'):.2f} "
        f"| **{c / d:.2f}** ({c / h:.2f} to the decode and hash, {c / dp:.2f} to the decode under the same "
        "allocator policy) |",
        f"| the same with glibc's own allocator policy (`CAMCAL_MALLOC=default`) | {cg:.2f} | "
        f"{med(cli_g, 'cpu_s'):.2f} | {cg / d:.2f} |",
        "",
        f"Where the time goes ({args.runs} more runs in the same shuffled order: `calibrate_session` + "
        "`save_profile` in one process, each stage's median; imports excluded; CPU counts every thread; system: "
        "the kernel's share of that CPU time (page faults: zeroing fresh memory, reads, the spill file); page "
        "faults: minor faults, each a 4 KiB or a 2 MiB page):",
        "",
        "| stage | wall (s) | CPU (s) | of which system (s) | page faults (thousands) | process peak at its end (GB) "
        "| share of the wall time |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    labels = dict(STAGES, save_profile="writing the profile (maps EXR, hashes, schema validation)")
    accounted = 0.0
    for name, (wall, cpu, sys_s, faults) in sorted(spent.items(), key=lambda kv: -kv[1][0]):
        accounted += wall
        lines.append(f"| {labels.get(name, name)} | {wall:.2f} | {cpu:.2f} | {sys_s:.2f} | {faults / 1e3:.0f} | "
                     f"{peaks.get(name, float('nan')) / 1e3:.2f} | {wall / total_wall:.0%} |")
    lines.append(f"| the rest (verdicts, notes, identity, provenance) | {total_wall - accounted:.2f} | | | | | "
                 f"{(total_wall - accounted) / total_wall:.0%} |")
    lines.append(f"| **total** (the median of the runs' totals, not the sum of the medians) | {total_wall:.2f} | "
                 f"{total_cpu:.2f} | {total_sys:.2f} | {total_faults / 1e3:.0f} | {max(peaks.values()) / 1e3:.2f} "
                 "| 100% |")
    lines.append("")
    lines.append("Runs, wall (s): calibrate " + ", ".join(f"{r['seconds']:.1f}" for r in cli) + "; decode "
                 + ", ".join(f"{r['seconds']:.1f}" for r in dec) + "; decode and hash "
                 + ", ".join(f"{r['seconds']:.1f}" for r in hashed) + "; decode under the policy "
                 + ", ".join(f"{r['seconds']:.1f}" for r in dec_p) + "; calibrate under glibc's policy "
                 + ", ".join(f"{r['seconds']:.1f}" for r in cli_g) + ".")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

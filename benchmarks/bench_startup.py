"""Benchmark: start-up of the ``camcal`` command, and ``calibrate`` of a small session against a bare decode.

Run: ``python benchmarks/bench_startup.py [--runs 5] [--before DIR]`` (prints a Markdown section for RESULTS.md).

Every figure is a whole process (``python -m camcal ...``), as a user runs it:

- (a) ``camcal --version``;
- (b) ``camcal inspect FILE`` of one DNG of the session;
- (c) ``camcal calibrate SESSION -o P.camcal`` of a 116-DNG 320x240 synthetic session (bias 16, dark 16,
  flat 8, linearity 17, sweep 59 = 400…690 nm in 5 nm steps, one frame each; no JPEG twins, so that the
  baseline decodes exactly the files calibrate reads);
- the baseline: a fresh ``python -c`` that imports rawpy and decodes the same 116 DNGs
  (``rawpy.imread`` + a copy of ``raw_image_visible``), and, for reference, ``python -c pass``.

The runs are interleaved (a, b, c, baseline, pass; repeated ``--runs`` times) so that the load of the shared
machine falls on all of them alike; the medians are reported. ``--before DIR`` also times (a)–(c) of the camcal
found in DIR (a source tree, e.g. an older commit from ``git archive``), interleaved with the rest.
Start-up is measured, not a goal: a ``calibrate`` runs once per camera, and its fits call scipy. The session is
written once into ``benchmarks/_work/startup_session/`` (git-ignored). Every process runs from
byte-code, as an installed camcal does (pip compiles it on install): an untimed warm-up round writes it to
``benchmarks/_work/pycache/`` (``PYTHONPYCACHEPREFIX``), whatever ``PYTHONDONTWRITEBYTECODE`` says.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT.parent))

from camcal.synth.camera import SyntheticCamera, preset  # noqa: E402
from camcal.synth.session import SessionPlan, write_session  # noqa: E402

WORK = ROOT / "_work" / "startup_session"
# 16 + 16 + 8 + 17 + 59 = 116 DNGs and nothing else: the baseline decodes the very files calibrate reads
PLAN = SessionPlan(sweep_stop_nm=690.0, n_sweep=1, linearity_jpeg=False, sweep_jpeg=False)
DECODE = ("import sys, rawpy\n"
          "for f in open(sys.argv[1]).read().split('\\n'):\n"
          "    with rawpy.imread(f) as r:\n"
          "        r.raw_image_visible.copy()\n")


#: Records every module a real ``camcal calibrate`` run loads (``sys.modules`` at its end), as JSON on stdout.
LOADED = ("import json, sys\n"
          "from camcal.cli import run\n"
          "sys.argv = ['camcal', 'calibrate', sys.argv[1], '-o', sys.argv[2]]\n"
          "try:\n"
          "    run()\n"
          "except SystemExit as e:\n"
          "    assert not e.code, e.code\n"
          "sys.stdout.flush()\n"
          "print('\\nMODULES ' + json.dumps(sorted(sys.modules)))\n")

#: Imports the modules of a list (one name per line in the file argv[1]), as a calibrate run loads them.
IMPORT_LIST = ("import importlib, sys\n"
               "for m in open(sys.argv[1]).read().split():\n"
               "    try:\n"
               "        importlib.import_module(m)\n"
               "    except Exception:\n"
               "        pass\n")

#: ``calibrate_session`` + ``save_profile`` inside one process after every import, printed as seconds.
WORK_ONLY = ("import sys, time\n"
        "from camcal.calibrate.run import CalibrateOptions, calibrate_session\n"
        "from camcal.models.profile import save_profile\n"
        "calibrate_session(sys.argv[1])  # loads whatever is lazily imported\n"
        "t = time.perf_counter()\n"
        "profile, _ = calibrate_session(sys.argv[1])\n"
        "save_profile(profile, sys.argv[2])\n"
        "print(time.perf_counter() - t)\n")


def loaded_modules(folder: Path, env: dict[str, str], tmp: Path) -> list[str]:
    """Every module a ``camcal calibrate`` of ``folder`` loads (its ``sys.modules`` at the end)."""
    proc = subprocess.run([sys.executable, "-c", LOADED, str(folder), str(tmp / "loaded.camcal")],
                          capture_output=True, text=True, env=env, cwd=tmp)
    if proc.returncode != 0 or "MODULES " not in proc.stdout:
        raise SystemExit(f"calibrate failed: {proc.stderr[-2000:]}")
    import json

    names = json.loads(proc.stdout.rsplit("MODULES ", 1)[1])
    return [m for m in names if m not in ("__main__", "__mp_main__") and not m.startswith("_")]


def session() -> tuple[Path, list[Path]]:
    """The 116-DNG session (written once) and its DNGs."""
    if not (WORK / "truth.json").is_file():
        cam = SyntheticCamera(preset("default", seed=1, width=320, height=240))
        write_session(WORK, cam, PLAN)
    dngs = sorted(WORK.rglob("*.dng"))
    if len(dngs) != 116:
        raise SystemExit(f"{WORK} holds {len(dngs)} DNGs, not 116: delete it and run again")
    return WORK, dngs


def timed(argv: list[str], env: dict[str, str], cwd: Path) -> float:
    """Wall time of one whole process, s; a failure stops the benchmark."""
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=cwd)
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return dt


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5, help="interleaved runs of each command (medians reported)")
    ap.add_argument("--before", type=Path, default=None, help="source tree of an older camcal to time too")
    args = ap.parse_args()
    folder, dngs = session()
    # byte-code as an installed camcal has it (pip compiles on install): written once to a cache folder by the
    # warm-up round, whatever PYTHONDONTWRITEBYTECODE the shell sets (else every run recompiles camcal's sources)
    base = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    base["PYTHONPYCACHEPREFIX"] = str(ROOT / "_work" / "pycache")
    env = {**base, "PYTHONPATH": str(ROOT.parent)}
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        listing = Path(tmp) / "files.txt"
        listing.write_text("\n".join(str(p) for p in dngs))
        modules = loaded_modules(folder, env, Path(tmp))
        (Path(tmp) / "modules.txt").write_text("\n".join(modules))
        # the floor: what a calibrate run loads that is not camcal's own (numpy, rawpy, Typer with the pydantic it
        # coerces parameters with, Rich, jsonschema, OpenImageIO, exifread, the standard library)
        (Path(tmp) / "others.txt").write_text("\n".join(m for m in modules if m.split(".")[0] != "camcal"))
        cmds = {
            "version": [py, "-m", "camcal", "--version"],
            "inspect": [py, "-m", "camcal", "inspect", str(dngs[0])],
            "inspect start-up": [py, "-c", "from camcal.cli import register_commands, commands_for\n"
                                 "register_commands(commands_for(['inspect']))"],
            "calibrate": [py, "-m", "camcal", "calibrate", str(folder), "-o", str(Path(tmp) / "p.camcal")],
            "calibrate start-up": [py, "-c", IMPORT_LIST, str(Path(tmp) / "modules.txt")],
            "floor": [py, "-c", IMPORT_LIST, str(Path(tmp) / "others.txt")],
            "decode": [py, "-c", DECODE, str(listing)],
            "pass": [py, "-c", "pass"],
        }
        envs = dict.fromkeys(cmds, env)
        if args.before is not None:
            old = {**base, "PYTHONPATH": str(args.before.resolve())}
            for k in ("version", "inspect", "calibrate"):  # an older tree has no commands_for: no start-up row
                cmds[f"{k} before"], envs[f"{k} before"] = cmds[k], old
        times: dict[str, list[float]] = {k: [] for k in cmds}
        work: list[float] = []
        for name, argv in cmds.items():  # warm-up round, not timed: writes the byte-code cache
            timed(argv, envs[name], Path(tmp))
        for _ in range(args.runs):
            for name, argv in cmds.items():
                times[name].append(timed(argv, envs[name], Path(tmp)))
            proc = subprocess.run([py, "-c", WORK_ONLY, str(folder), str(Path(tmp) / "w.camcal")], capture_output=True,
                                  text=True, env=env, cwd=tmp, check=True)
            work.append(float(proc.stdout.split()[-1]))
    med = {k: statistics.median(v) for k, v in times.items()}
    load = os.getloadavg()[0]
    print(f"### start-up and a small session, {date.today()}\n")
    print(f"Machine: {os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}; "
          f"load average {load:.1f} (1-minute) at the end; medians of {args.runs} interleaved runs.\n")
    print("| what (whole process) | median (s) | runs (s) | ratio to the bare decode |")
    print("|---|---:|---:|---:|")
    labels = {"version": "`camcal --version`", "inspect": "`camcal inspect` one DNG",
              "inspect start-up": "`inspect`'s start-up alone: interpreter, imports, registration (no file)",
              "calibrate": "`camcal calibrate` 116 DNGs 320x240",
              "calibrate start-up": "`calibrate`'s imports alone (every module a calibrate run loads, no file)",
              "floor": "the same without camcal's own modules: numpy, rawpy, typer (+ pydantic), rich, jsonschema, "
                       "OpenImageIO, exifread, the standard library",
              "decode": "baseline: python + rawpy decode of "
              "the 116 DNGs", "pass": "`python -c pass`"}
    for k in ("version", "inspect", "calibrate"):
        if f"{k} before" in med:
            labels[f"{k} before"] = f"before ({args.before}): {labels[k]}"
    for k, label in labels.items():
        runs = ", ".join(f"{t:.2f}" for t in times[k])
        print(f"| {label} | {med[k]:.3f} | {runs} | {med[k] / med['decode']:.2f} |")
    heavy = sorted({m.split(".")[0] for m in modules} & {"scipy", "skimage", "colour", "matplotlib", "dask"})
    print(f"| `calibrate`'s work alone: `calibrate_session` + `save_profile` in one process after every import "
          f"| {statistics.median(work):.3f} | {', '.join(f'{t:.2f}' for t in work)} | "
          f"{statistics.median(work) / med['decode']:.2f} |")
    print(f"\nA calibrate run loads {len(modules)} modules; of scipy, scikit-image, colour-science, matplotlib and "
          f"dask it loads: {', '.join(heavy) or 'none'}.")
    print(f"\nStart-up above the interpreter's: `--version` {med['version'] - med['pass']:.3f} s, `inspect` "
          f"{med['inspect'] - med['pass']:.3f} s (of which start-up {med['inspect start-up'] - med['pass']:.3f} s); "
          "calibrate / bare decode = "
          f"**{med['calibrate'] / med['decode']:.2f}x** (its imports alone "
          f"{med['calibrate start-up'] / med['decode']:.2f}x) (measured, no goal: a calibrate runs once per camera).")


if __name__ == "__main__":
    main()

"""Benchmark: peak memory of ``camcal secchi`` for a survey of 10 and of 200 photos.

secchi streams its photos: each photo's full-size radiance and disk masks are dropped once it is measured, and its
page image is drawn (downsampled) before that, so the peak memory should not grow with the number of photos. The
baseline is the same survey of 10 photos, run in the same script: the figure is the ratio of the peak resident set
size (``ru_maxrss`` of a fresh process running the whole stage and writing its page) for 200 photos to that for 10.

Photos: a 384x256 synthetic camera (the demo's), one sunlit reference and N submerged disks (SPECTRL2 sun at 35°,
60 µg/L, depths cycling 0.5-1.5 m), real DNGs with their own noise; the profile is calibrated from a synthetic
session first. Prints Markdown.

    python benchmarks/bench_secchi_memory.py            # 10 and 200 photos
    python benchmarks/bench_secchi_memory.py --n 10 50  # other sizes
    python benchmarks/bench_secchi_memory.py --keep     # + 200 photos keeping their maps (the old behaviour)
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # run from a checkout without installing

from camcal.calibrate.run import calibrate_session  # noqa: E402
from camcal.models.profile import save_profile  # noqa: E402
from camcal.synth.camera import SensorParams, SyntheticCamera  # noqa: E402
from camcal.synth.session import SessionPlan, write_session  # noqa: E402
from camcal.synth.sunlit import SunSky, sunlit_scenes, write_sunlit_pair  # noqa: E402

DEPTHS_M = (0.5, 0.8, 1.0, 1.2, 1.5)

CHILD = r"""
import json, resource, sys, time
sys.path.insert(0, sys.argv[1])
import camcal.water.secchi as secchi
from camcal.water.secchi import run_secchi, write_diagnostics
from camcal.water.field import ClearSky, FieldGeometry
if sys.argv[7] == "keep":  # the behaviour before streaming: every photo keeps its full-size maps to the end
    drop = secchi.finish_photo
    def keep(s, *args):
        held = (s.channels, s.fit)
        drop(s, *args)
        s.channels, s.fit = held
    secchi.finish_photo = keep
profile, ref, page = sys.argv[2:5]
subs, depths = json.loads(sys.argv[5]), json.loads(sys.argv[6])
t0 = time.perf_counter()
res = run_secchi(profile, ref, subs, [(d, 0.005) for d in depths], sky=ClearSky(35.0), geometry=FieldGeometry(),
                 inputs=[], page_dir=page)
write_diagnostics(res, page)
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"seconds": time.perf_counter() - t0, "maxrss_kib": rss, "c": res.c_ug_per_L,
                  "failed": sum(s.error is not None for s in res.submerged)}))
"""


def photos(folder: Path, cam: SyntheticCamera, n: int) -> tuple[Path, list[Path], list[float]]:
    """One reference and ``n`` submerged DNGs (depths cycling through :data:`DEPTHS_M`, each its own noise)."""
    rng = np.random.default_rng(45)
    sky = SunSky(35.0, 160.0)
    scenes = {d: sunlit_scenes(cam, sky=sky, c_ug_per_L=60.0, depth_m=d) for d in DEPTHS_M}
    files = write_sunlit_pair(folder, cam, scenes[DEPTHS_M[0]], stem="ref", rng=rng)
    ref = Path(files["ref"]["dng"])
    subs, depths = [], []
    for i in range(n):
        d = DEPTHS_M[i % len(DEPTHS_M)]
        f = write_sunlit_pair(folder, cam, scenes[d], stem=f"p{i:03d}", rng=rng, write_reference=False)
        subs.append(Path(f["sub"]["dng"]))
        depths.append(d)
    return ref, subs, depths


def run(profile: Path, ref: Path, subs: list[Path], depths: list[float], page: Path, keep: bool = False) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(ROOT), str(profile), str(ref), str(page),
                          json.dumps([str(p) for p in subs]), json.dumps(depths), "keep" if keep else "stream"],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, nargs="+", default=[10, 200])
    ap.add_argument("--keep", action="store_true", help="also the largest survey with every photo's maps kept")
    args = ap.parse_args()
    cam = SyntheticCamera(SensorParams())
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        profile, _ = calibrate_session(write_session(tmp / "S", cam, SessionPlan()))
        profile_path = tmp / "cam.camcal"
        save_profile(profile, profile_path)
        ref, subs, depths = photos(tmp / "photos", cam, max(args.n))
        rows = []
        for n in args.n:
            rows.append((f"{n}", n, run(profile_path, ref, subs[:n], depths[:n], tmp / f"page{n}")))
        if args.keep:
            n = max(args.n)
            rows.append((f"{n}, maps kept (before streaming)", n,
                         run(profile_path, ref, subs[:n], depths[:n], tmp / f"keep{n}", keep=True)))
    base = rows[0][2]["maxrss_kib"]
    print(f"## secchi memory ({dt.date.today().isoformat()}, {platform.machine()}, {os.cpu_count()} cores, "
          f"load {os.getloadavg()[0]:.1f})\n")
    print("| photos | peak RSS (MiB) | ratio to the first | stage (s) | s per photo | C (µg/L) | failed |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for label, n, r in rows:
        print(f"| {label} | {r['maxrss_kib'] / 1024:.1f} | {r['maxrss_kib'] / base:.3f} | {r['seconds']:.1f} | "
              f"{r['seconds'] / (n + 1):.3f} | {r['c']:.2f} | {r['failed']} |")


if __name__ == "__main__":
    main()

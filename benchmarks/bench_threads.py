"""Benchmark: reading DNG frames in 2 threads against 1, by frame size (the small-frame rule of camcal.threads).

Run: ``python benchmarks/bench_threads.py [--runs 5]``. For each size, 40 (below 1 MP) or 16 random-mosaic DNGs
are written once into a temporary folder; each run reads them all (``camcal.io.read.load_frame`` + float32 planes:
decode, EXIF, checks) serially and in a 2-thread pool, interleaved; the medians per frame and their ratio are
printed. :data:`camcal.threads.SMALL_FRAME_PIXELS` sits where the pool stops paying.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from camcal.io.read import load_frame  # noqa: E402
from camcal.synth.dng import write_dng  # noqa: E402
from camcal.threads import SMALL_FRAME_PIXELS  # noqa: E402

SIZES = ((320, 240), (640, 480), (1024, 768), (1456, 1088), (2900, 2000))


def read(path: Path) -> float:
    frame = load_frame(path)
    return float(frame.planes(dtype=np.float32).mean())


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(1)
    print(f"| frame | pixels | 1 thread (ms/frame) | 2 threads (ms/frame) | 2 / 1 |  (SMALL_FRAME_PIXELS = "
          f"{SMALL_FRAME_PIXELS:,})")
    print("|---|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for w, h in SIZES:
            n = 40 if w * h < 1_000_000 else 16
            files = []
            for i in range(n):
                p = Path(tmp) / f"f{w}_{i}.dng"
                write_dng(p, rng.integers(0, 4000, (h, w)).astype(np.uint16), cfa_pattern="RGGB",
                          black_level_dn=64, white_level_dn=4095, exposure_s=0.01, f_number=2.8, iso=100)
                files.append(p)
            times: dict[int, list[float]] = {1: [], 2: []}
            for _ in range(args.runs):
                for jobs in (1, 2):
                    t0 = time.perf_counter()
                    if jobs == 1:
                        list(map(read, files))
                    else:
                        with ThreadPoolExecutor(2) as pool:
                            list(pool.map(read, files))
                    times[jobs].append((time.perf_counter() - t0) / n * 1e3)
            one, two = statistics.median(times[1]), statistics.median(times[2])
            print(f"| {w}x{h} | {w * h:,} | {one:.2f} | {two:.2f} | {two / one:.2f} |")


if __name__ == "__main__":
    main()

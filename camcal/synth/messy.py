"""A messy calibration session: a clean synthetic session with the problems of real lab sessions planted.

``camcal synth session SESSION --preset messy`` writes the default session (:mod:`camcal.synth.session`), then
plants, each once:

- ``truncated``: one flat cut short, as a card reader or an interrupted copy leaves it;
- ``duplicate``: a copy of one dark frame under another name (listed in ``frames.csv`` too);
- ``other_camera``: a JPEG of another camera, of another size, dropped into ``flat/``;
- ``no_light``: one sweep frame taken with the shutter closed (the reference detector saw the lamp; its row in
  ``sweep.csv`` is unchanged), a repeat at a wavelength whose other frames are lit;
- ``saturated``: two more linearity steps at the top of the series, every pixel at the white level.

``truth.json`` lists them under ``planted``: per problem the file (``stage/name``), what it is and the verdict a
careful calibration gives (``left out`` with the start of its reason, or ``used``: saturated linearity frames are
data, they end the linear range).
"""

from __future__ import annotations

import csv
import json
import shutil
from datetime import datetime
from pathlib import Path

import numpy as np

from camcal.io.atomic import atomic_write_bytes, atomic_write_text
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera, frame_rngs, save_truth
from camcal.synth.dng import write_dng
from camcal.units import IN_BAND_RADIANCE

TRUNCATED_FRACTION = 0.6
"""The planted truncated flat keeps this fraction of its bytes (the image data end early)."""

SATURATED_STEPS = 2
"""Linearity steps added past the top of the series, fully saturated."""


def _rows(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def _write_rows(path: Path, fields: list[str], rows: list[dict[str, str]]) -> None:
    lines = [",".join(fields)] + [",".join(str(r.get(f, "")) for f in fields) for r in rows]
    atomic_write_text(path, "\n".join(lines) + "\n")


def plant_problems(session: str | Path, camera: SyntheticCamera) -> list[dict[str, str]]:
    """Plant the problems of the module docstring in a session written by :func:`write_session` with
    ``camera`` (every stage present, the default plan); returns the planted list (also added to truth.json)."""
    root = Path(session)
    p = camera.params
    planted: list[dict[str, str]] = []

    # one truncated flat
    flats = sorted((root / "flat").glob("flat_*.dng"))
    victim = flats[len(flats) // 2]
    data = victim.read_bytes()
    atomic_write_bytes(victim, data[: int(TRUNCATED_FRACTION * len(data))])
    planted.append({"problem": "truncated", "file": f"flat/{victim.name}", "verdict": "left out",
                    "reason": "unreadable", "what": f"flat cut to {TRUNCATED_FRACTION:.0%} of its bytes"})

    # a copy of one dark frame, listed in frames.csv like the others
    darks = sorted((root / "dark").glob("dark_*.dng"))
    original = darks[1]
    copy = original.with_name(original.stem + "_copy.dng")
    shutil.copyfile(original, copy)
    fields, rows = _rows(root / "dark" / "frames.csv")
    row = dict(next(r for r in rows if r["file"] == original.name), file=copy.name)
    _write_rows(root / "dark" / "frames.csv", fields, [*rows, row])
    planted.append({"problem": "duplicate", "file": f"dark/{copy.name}", "verdict": "left out",
                    "reason": "duplicate", "what": f"a byte-for-byte copy of dark/{original.name}"})

    # a JPEG of another camera and size in flat/
    other = SyntheticCamera(SensorParams(width=p.width * 5 // 12 * 2, height=p.height * 5 // 12 * 2, make="Othercam",
                                         model="Phone 7", serial="OTHER01", seed=p.seed + 7))
    jpeg = root / "flat" / "IMG_0001.jpg"
    other.write_jpeg(jpeg, Scene.uniform(np.full(WAVELENGTHS_NM.size, 0.02)), exposure_s=0.01, iso=100.0,
                     f_number=4.0, rng=np.random.default_rng(7))
    planted.append({"problem": "other_camera", "file": f"flat/{jpeg.name}", "verdict": "left out",
                    "reason": "another camera", "what": f"a JPEG of {other.params.make} {other.params.model}, "
                                                        f"{other.params.width}x{other.params.height} pixels"})

    # a sweep frame with the shutter closed: a repeat at a wavelength near the peak
    fields, rows = _rows(root / "sweep" / "sweep.csv")
    target = next(r for r in rows if float(r["wavelength_nm"]) == 550.0 and r["file"].endswith("_01.dng"))
    frame = root / "sweep" / target["file"]
    camera.write_dng(frame, Scene.dark(), exposure_s=float(target["exposure_s"]), iso=float(target["iso"]),
                     f_number=float(target["f_number"]), rng=frame_rngs(p.seed, 1, 77)[0],
                     capture_time=datetime(2026, 6, 1, 12, 0, 0))
    planted.append({"problem": "no_light", "file": f"sweep/{frame.name}", "verdict": "left out",
                    "reason": "no light recorded",
                    "what": f"shutter closed at {float(target['wavelength_nm']):g} nm while the reference detector "
                            f"read {target['radiance_W_m2_sr']} {IN_BAND_RADIANCE}"})

    # the top of the linearity series: two more steps, fully saturated
    fields, rows = _rows(root / "linearity" / "frames.csv")
    raw_rows = [r for r in rows if r["file"].endswith(".dng")]
    last = raw_rows[-1]
    n = len(raw_rows)
    for k in range(SATURATED_STEPS):
        t = float(last["exposure_s"]) * 2.0 ** (0.5 * (k + 1))
        name = f"lin_{n + k:03d}.dng"
        mosaic = np.full((p.height, p.width), p.white_dn, np.uint16)
        write_dng(root / "linearity" / name, mosaic, cfa_pattern=p.cfa_pattern,
                  black_level_dn=camera.black_by_position(), white_level_dn=p.white_dn,
                  exposure_s=float(f"{t:.6g}"), f_number=float(last["f_number"]), iso=float(last["iso"]),
                  make=p.make, model=p.model, serial=p.serial, capture_time=datetime(2026, 6, 1, 13, 0, k))
        rows.append({**last, "file": name, "exposure_s": f"{t:.6g}"})
        planted.append({"problem": "saturated", "file": f"linearity/{name}", "verdict": "used",
                        "reason": "saturated", "what": f"every pixel at the white level {p.white_dn} DN at "
                                                       f"{t:.4g} s: the series runs past saturation"})
    _write_rows(root / "linearity" / "frames.csv", fields, rows)

    truth_path = root / "truth.json"
    truth = json.loads(truth_path.read_text())
    truth["planted"] = planted
    save_truth(truth_path, truth)
    return planted

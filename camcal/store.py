"""Saving and loading a stage result: a JSON file plus its maps in an EXR beside it.

A stage result (dark model, flat model, ...) has small scalar parts and large
per-pixel maps. ``save_stage(path, kind, data, maps)`` writes

- ``path`` (``.json``): ``{"kind", "camcal_version", "data", "maps_file", "maps_sha256", "maps"}``
- ``<stem>.maps.exr``: every map as a named float32 channel (all maps of one shape)

The JSON records the SHA-256 of the EXR; loading refuses a mismatch. Both files
are written atomically. The calibration profile (``camcal.profile``) packs the
same two parts into a single file.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from camcal import __version__
from camcal.atomic import atomic_write_text
from camcal.errors import CamcalError
from camcal.exr import read_exr, write_exr
from camcal.hashing import sha256_file
from camcal.limits import MAX_STAGE_JSON_BYTES, check_json_depth
from camcal.manifest import read_text_file


def to_jsonable(obj):
    """numpy scalars/arrays -> Python; NaN/inf -> None (JSON has no NaN)."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def maps_path(path: str | Path) -> Path:
    path = Path(path)
    return path.with_name(path.stem + ".maps.exr")


def save_stage(path: str | Path, kind: str, data: dict, maps: dict[str, np.ndarray] | None = None) -> Path:
    """Write a stage result (see module docstring); returns the JSON path."""
    path = Path(path)
    doc = {"kind": kind, "camcal_version": __version__, "data": to_jsonable(data), "maps_file": None,
           "maps_sha256": None, "maps": []}
    if maps:
        mp = maps_path(path)
        write_exr(mp, maps, {"kind": kind})
        doc.update(maps_file=mp.name, maps_sha256=sha256_file(mp), maps=list(maps))
    atomic_write_text(path, json.dumps(doc, indent=1, allow_nan=False))
    return path


def load_stage(path: str | Path, kind: str) -> tuple[dict, dict[str, np.ndarray]]:
    """Load a stage result written by :func:`save_stage`; check kind and the maps' hash."""

    path = Path(path)
    text = read_text_file(path, f"{kind} file", MAX_STAGE_JSON_BYTES, max_line_bytes=None)  # camcal.limits
    check_json_depth(text.encode("utf-8"), path, f"{kind} file")
    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise CamcalError(f"not a camcal {kind} file (invalid JSON: {' '.join(str(exc).split())[:100]})",
                          path) from None
    if not isinstance(doc, dict) or doc.get("kind") != kind or not isinstance(doc.get("data"), dict):
        raise CamcalError(f"not a camcal {kind} file", path)
    maps: dict[str, np.ndarray] = {}
    if doc.get("maps_file"):
        mp = path.parent / Path(str(doc["maps_file"])).name
        if not mp.is_file():
            raise CamcalError(f"its maps file {mp.name} is missing", path)
        if sha256_file(mp) != doc.get("maps_sha256"):
            raise CamcalError(f"its maps file {mp.name} does not match the recorded SHA-256 (modified?)", path)
        maps, _ = read_exr(mp, list(doc.get("maps") or []))
    return doc["data"], maps

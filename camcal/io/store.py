"""Saving and loading a stage result: a JSON file plus its maps in an EXR beside it.

A stage result (dark model, flat model, ...) has small scalar parts and large
per-pixel maps. ``save_stage(path, kind, data, maps)`` writes

- ``path`` (``.json``): ``{"kind", "camcal_version", "data", "maps_file", "maps_sha256", "maps"}``
- ``<stem>.maps.exr``: every map as a named float32 channel (all maps of one shape)

The JSON records the SHA-256 of the EXR; loading refuses a mismatch. Both files
are written atomically. The calibration profile (``camcal.models.profile``) packs the
same two parts into a single file.
"""

from __future__ import annotations

import functools
import json
import math
from importlib import resources
from pathlib import Path

import jsonschema
import numpy as np
from referencing import Registry, Resource

from camcal import __version__
from camcal.errors import CamcalError
from camcal.io.atomic import atomic_write_text
from camcal.io.container import parse_json
from camcal.io.exr import read_exr, write_exr
from camcal.io.hashing import sha256_file
from camcal.io.limits import MAX_STAGE_JSON_BYTES
from camcal.io.manifest import read_text_file


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


#: The stage files that have a schema, ``camcal/schemas/<kind>-1.schema.json``.
STAGE_KINDS = ("dark", "flat", "response")


@functools.cache
def _schema_text(name: str) -> str:
    return resources.files("camcal").joinpath(f"schemas/{name}-1.schema.json").read_text(encoding="utf-8")


@functools.cache
def _stage_validator(kind: str):
    """A Draft 2020-12 validator of the stage file ``kind``; its ``data`` refers to the profile schema's $defs."""
    profile = json.loads(_schema_text("profile"))
    registry = Registry().with_resource(profile["$id"], Resource.from_contents(profile))
    return jsonschema.Draft202012Validator(json.loads(_schema_text(kind)), registry=registry)


def validate_stage(doc: dict, kind: str, where: str | Path) -> None:
    """Validate a stage file's JSON against ``camcal/schemas/<kind>-1.schema.json``; one line naming the field."""
    errors = sorted(_stage_validator(kind).iter_errors(doc), key=lambda e: [str(p) for p in e.absolute_path])
    if errors:
        err = errors[0]
        loc = "/".join(str(p) for p in err.absolute_path) or "(top level)"
        raise CamcalError(f"not a valid camcal {kind} file at {loc}: {' '.join(err.message.split())[:160]}", where)


def load_stage(path: str | Path, kind: str) -> tuple[dict, dict[str, np.ndarray]]:
    """Load a stage result written by :func:`save_stage`; check kind, its schema and the maps' hash.

    The JSON is parsed as a profile's is (NaN, Infinity and out-of-range numbers refused, nesting depth
    bounded) and, for the kinds of :data:`STAGE_KINDS`, validated against the stage's JSON Schema.
    """
    path = Path(path)
    text = read_text_file(path, f"{kind} file", MAX_STAGE_JSON_BYTES, max_line_bytes=None)  # camcal.io.limits
    doc = parse_json(text.encode("utf-8"), path, f"{kind} file")
    if not isinstance(doc, dict) or doc.get("kind") != kind or not isinstance(doc.get("data"), dict):
        raise CamcalError(f"not a camcal {kind} file", path)
    if kind in STAGE_KINDS:
        validate_stage(doc, kind, path)
    maps: dict[str, np.ndarray] = {}
    if doc.get("maps_file"):
        mp = path.parent / Path(str(doc["maps_file"])).name
        if not mp.is_file():
            raise CamcalError(f"its maps file {mp.name} is missing", path)
        if sha256_file(mp) != doc.get("maps_sha256"):
            raise CamcalError(f"its maps file {mp.name} does not match the recorded SHA-256 (modified?)", path)
        maps, _ = read_exr(mp, list(doc.get("maps") or []))
    return doc["data"], maps

"""The profile container: one file holding a JSON document and an EXR of maps.

A profile file is a ZIP archive (``.camcal``) with exactly two members:

- ``profile.json`` — the human-readable document (UTF-8 JSON, deflated);
- ``maps.exr`` — every per-pixel map as a named float32 channel (stored; EXR
  compresses itself). Absent when the profile holds no maps.

``profile.json`` carries ``integrity.content_sha256``, the SHA-256 of the
document's canonical JSON (sorted keys, no spaces) *without* the ``integrity``
member, and ``integrity.maps_sha256``, the SHA-256 of ``maps.exr``. Reading
refuses archives with other members, oversized members (a zip bomb), invalid
JSON, NaN/inf, and any hash mismatch. Nothing is ever unpickled or extracted to
disk except the EXR, which is read from a private temporary folder.
"""

from __future__ import annotations

import hashlib
import json
import math
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from camcal.atomic import atomic_path
from camcal.errors import CamcalError
from camcal.exr import read_exr, write_exr

JSON_MEMBER = "profile.json"
MAPS_MEMBER = "maps.exr"
MAX_JSON_BYTES = 64 * 1024 * 1024
MAX_MAPS_BYTES = 4 * 1024 * 1024 * 1024


def canonical_json(doc: dict) -> bytes:
    """Canonical bytes of a document (sorted keys, compact, no NaN)."""
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")


def content_hash(doc: dict) -> str:
    """SHA-256 of the canonical JSON of ``doc`` without its ``integrity`` member."""
    body = {k: v for k, v in doc.items() if k != "integrity"}
    return hashlib.sha256(canonical_json(body)).hexdigest()


def write_container(path: str | Path, doc: dict, maps: dict[str, np.ndarray]) -> Path:
    """Write ``doc`` and ``maps`` to one profile file, atomically; fills ``doc['integrity']``."""
    path = Path(path)
    with tempfile.TemporaryDirectory(prefix="camcal-profile-") as tdir:
        maps_bytes = b""
        if maps:
            mp = Path(tdir) / MAPS_MEMBER
            write_exr(mp, maps, {"content": "camcal profile maps"}, compression="zip")
            maps_bytes = mp.read_bytes()
        doc = dict(doc)
        doc["integrity"] = {
            "algorithm": "sha256",
            "content_sha256": content_hash(doc),
            "maps_sha256": hashlib.sha256(maps_bytes).hexdigest() if maps else None,
        }
        text = json.dumps(doc, indent=1, sort_keys=False, allow_nan=False).encode("utf-8")
        with atomic_path(path) as tmp:
            with zipfile.ZipFile(tmp, "w") as zf:
                zf.writestr(zipfile.ZipInfo(JSON_MEMBER, date_time=(2020, 1, 1, 0, 0, 0)), text,
                            compress_type=zipfile.ZIP_DEFLATED)
                if maps:
                    zf.writestr(zipfile.ZipInfo(MAPS_MEMBER, date_time=(2020, 1, 1, 0, 0, 0)), maps_bytes,
                                compress_type=zipfile.ZIP_STORED)
    return path


def _reject_constant(value: str):
    raise ValueError(f"{value} is not allowed")


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:20]} is out of range")
    return value


def read_container(path: str | Path, *, decode_maps: bool = True) -> tuple[dict, dict[str, np.ndarray]]:
    """Read and verify a profile file; returns ``(doc, maps)``. See the module docstring.

    ``decode_maps=False``: both hashes are still verified, but ``maps.exr`` is not decoded (``maps`` is
    empty) — for a check of the profile's identity before the work goes to other processes.
    """
    path = Path(path)
    if not path.is_file():
        raise CamcalError("no such profile file", path)
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError):
        raise CamcalError("not a camcal profile (not a ZIP container, or truncated)", path) from None
    with zf:
        names = [i.filename for i in zf.infolist()]
        if JSON_MEMBER not in names or set(names) - {JSON_MEMBER, MAPS_MEMBER} or len(names) != len(set(names)):
            raise CamcalError(f"not a camcal profile (members {names})", path)
        info = zf.getinfo(JSON_MEMBER)
        if info.file_size > MAX_JSON_BYTES:
            raise CamcalError("profile.json is implausibly large; refused", path)
        try:
            raw = zf.read(JSON_MEMBER)
            maps_bytes = zf.read(MAPS_MEMBER) if MAPS_MEMBER in names else b""
        except (zipfile.BadZipFile, OSError, EOFError, zlib_error()) as exc:
            raise CamcalError(f"profile is corrupted ({exc})", path) from None
        if MAPS_MEMBER in names and zf.getinfo(MAPS_MEMBER).file_size > MAX_MAPS_BYTES:
            raise CamcalError("maps.exr is implausibly large; refused", path)
    try:
        doc = json.loads(raw.decode("utf-8"), parse_constant=_reject_constant, parse_float=_finite_float)
    except (UnicodeDecodeError, ValueError) as exc:
        raise CamcalError(f"profile.json is not valid JSON ({' '.join(str(exc).split())[:100]})", path) from None
    if not isinstance(doc, dict) or not isinstance(doc.get("integrity"), dict):
        raise CamcalError("profile.json has no integrity record", path)
    integ = doc["integrity"]
    if integ.get("content_sha256") != content_hash(doc):
        raise CamcalError("content hash mismatch: the profile was modified after it was written", path)
    expected_maps = integ.get("maps_sha256")
    if bool(maps_bytes) != bool(expected_maps) or (
        maps_bytes and hashlib.sha256(maps_bytes).hexdigest() != expected_maps
    ):
        raise CamcalError("maps hash mismatch: maps.exr was modified or replaced", path)
    maps: dict[str, np.ndarray] = {}
    if maps_bytes and decode_maps:
        with tempfile.TemporaryDirectory(prefix="camcal-profile-") as tdir:
            mp = Path(tdir) / MAPS_MEMBER
            mp.write_bytes(maps_bytes)
            del maps_bytes  # not held while the maps are decoded (peak memory of a profile load)
            try:
                maps, _ = read_exr(mp)
            except CamcalError as exc:
                raise CamcalError(f"{MAPS_MEMBER}: {exc.message}", path) from None
    return doc, maps


def zlib_error() -> type[Exception]:
    import zlib

    return zlib.error

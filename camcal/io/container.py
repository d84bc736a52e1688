"""The profile container: one file holding a JSON document and an EXR of maps.

A profile file is a ZIP archive (``.camcal``) with exactly two members:

- ``profile.json`` — the human-readable document (UTF-8 JSON, deflated);
- ``maps.exr`` — every per-pixel map as a named float32 channel (stored; EXR
  compresses itself). Absent when the profile holds no maps.

Members are found by name. ``maps.exr`` is written first, hashed as it is copied in (one read of the maps),
then ``profile.json`` with that hash.

``profile.json`` carries ``integrity.content_sha256``, the SHA-256 of the
document's canonical JSON (sorted keys, no spaces) *without* the ``integrity``
member, and ``integrity.maps_sha256``, the SHA-256 of ``maps.exr``. Reading
refuses archives with other members, oversized members (a zip bomb), invalid
JSON, NaN/inf, and any hash mismatch. Nothing is ever unpickled or extracted to
disk except the EXR, which is streamed (through its hash) into a private temporary folder.
Every declared size is checked first against :mod:`camcal.io.limits` (see :func:`read_container`).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import struct
import tempfile
import zipfile
import zlib
from pathlib import Path

import numpy as np

from camcal.errors import CamcalError
from camcal.io.atomic import atomic_path
from camcal.io.exr import read_exr, write_exr
from camcal.io.limits import (
    MAX_PROFILE_JSON_BYTES,
    STREAM_BLOCK_BYTES,
    check_json_depth,
    check_zip_directory,
    check_zip_member,
    human_bytes,
    maps_size_bound,
)

JSON_MEMBER = "profile.json"
MAPS_MEMBER = "maps.exr"

MAPS_COMPRESSION = "zstd:1"
"""The EXR compression of ``maps.exr`` (lossless). Measured on the 28 maps of a 24 MP profile (6 MP per plane,
672 MB of float32; docs/profile-format.md): zstd level 1 writes in about a third of the CPU time of zip,
makes a file 0.72x the size and reads several times faster. It needs OpenEXR 3.4 or later to read."""


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
        mp = Path(tdir) / MAPS_MEMBER
        if maps:
            write_exr(mp, maps, {"content": "camcal profile maps"}, compression=MAPS_COMPRESSION)
        doc = dict(doc)
        with atomic_path(path) as tmp:
            with zipfile.ZipFile(tmp, "w") as zf:
                maps_sha256 = None
                if maps:  # streamed from the EXR in blocks, hashed as it is copied: read once, never all in memory
                    info = zipfile.ZipInfo(MAPS_MEMBER, date_time=(2020, 1, 1, 0, 0, 0))
                    info.compress_type = zipfile.ZIP_STORED
                    info.file_size = mp.stat().st_size
                    digest = hashlib.sha256()
                    with open(mp, "rb") as src, zf.open(info, "w") as dst:
                        for block in iter(lambda: src.read(STREAM_BLOCK_BYTES), b""):
                            digest.update(block)
                            dst.write(block)
                    maps_sha256 = digest.hexdigest()
                doc["integrity"] = {"algorithm": "sha256", "content_sha256": content_hash(doc),
                                    "maps_sha256": maps_sha256}
                text = json.dumps(doc, indent=1, sort_keys=False, allow_nan=False).encode("utf-8")
                zf.writestr(zipfile.ZipInfo(JSON_MEMBER, date_time=(2020, 1, 1, 0, 0, 0)), text,
                            compress_type=zipfile.ZIP_DEFLATED)
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

    Every declared size is checked against :mod:`camcal.io.limits` before anything is decompressed or
    parsed: the number of ZIP members and the size of the ZIP directory (from the end record, before
    Python's ``zipfile`` reads the directory), each member's declared size and compression ratio,
    the nesting depth of ``profile.json``, and the declared size of ``maps.exr`` against what the
    profile's own sensor and map list need. ``maps.exr`` is then streamed (1 MiB blocks) through
    SHA-256 into a private temporary file; it is decoded only when its hash matches.

    ``decode_maps=False``: both hashes are still verified, but ``maps.exr`` is not decoded (``maps`` is
    empty) — for a check of the profile's identity before the work goes to other processes.
    """
    path = Path(path)
    if not path.is_file():
        raise CamcalError("no such profile file", path)
    try:
        check_zip_directory(path)
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, struct.error):
        raise CamcalError("not a camcal profile (not a ZIP container, or truncated)", path) from None
    with zf, tempfile.TemporaryDirectory(prefix="camcal-profile-") as tdir:
        names = [i.filename for i in zf.infolist()]
        if JSON_MEMBER not in names or set(names) - {JSON_MEMBER, MAPS_MEMBER} or len(names) != len(set(names)):
            raise CamcalError(f"not a camcal profile (members {names})", path)
        info = zf.getinfo(JSON_MEMBER)
        check_zip_member(path, JSON_MEMBER, info.file_size, info.compress_size, MAX_PROFILE_JSON_BYTES)
        try:
            with zf.open(JSON_MEMBER) as fh:  # bounded even if the declared size lies
                raw = fh.read(MAX_PROFILE_JSON_BYTES + 1)
        except (zipfile.BadZipFile, OSError, EOFError, zlib.error, NotImplementedError) as exc:
            raise CamcalError(f"profile is corrupted ({' '.join(str(exc).split())[:100]})", path) from None
        if len(raw) > MAX_PROFILE_JSON_BYTES:  # pragma: no cover - zipfile stops at the declared size
            raise CamcalError(f"{JSON_MEMBER} is larger than {human_bytes(MAX_PROFILE_JSON_BYTES)}; refused", path)
        doc = parse_json(raw, path, JSON_MEMBER)
        if not isinstance(doc, dict) or not isinstance(doc.get("integrity"), dict):
            raise CamcalError("profile.json has no integrity record", path)
        integ = doc["integrity"]
        if integ.get("content_sha256") != content_hash(doc):
            raise CamcalError("content hash mismatch: the profile was modified after it was written", path)
        expected_maps = integ.get("maps_sha256")
        has_maps = MAPS_MEMBER in names
        if has_maps != bool(expected_maps):
            raise CamcalError("maps hash mismatch: maps.exr was modified or replaced", path)
        if not has_maps:
            return doc, {}
        info = zf.getinfo(MAPS_MEMBER)
        bound, needs = maps_size_bound(doc)
        check_zip_member(path, MAPS_MEMBER, info.file_size, info.compress_size, bound,
                         f"({needs}: at most {human_bytes(bound)})")
        mp = Path(tdir) / MAPS_MEMBER
        digest = hashlib.sha256()
        try:
            with zf.open(MAPS_MEMBER) as src, (open(mp, "wb") if decode_maps else contextlib.nullcontext()) as dst:
                for block in iter(lambda: src.read(STREAM_BLOCK_BYTES), b""):
                    digest.update(block)
                    if dst is not None:
                        dst.write(block)
        except (zipfile.BadZipFile, EOFError, zlib.error, NotImplementedError) as exc:
            raise CamcalError(f"profile is corrupted ({' '.join(str(exc).split())[:100]})", path) from None
        if digest.hexdigest() != expected_maps:
            raise CamcalError("maps hash mismatch: maps.exr was modified or replaced", path)
        if not decode_maps:
            return doc, {}
        try:
            maps, _ = read_exr(mp, max_samples=bound // 4)
        except CamcalError as exc:
            raise CamcalError(f"{MAPS_MEMBER}: {exc.message}", path) from None
    return doc, maps


def parse_json(raw: bytes, where: str | Path, what: str):
    """Parse UTF-8 JSON ``raw`` after checking its nesting depth; NaN, Infinity and ``1e999`` refused."""
    check_json_depth(raw, where, what)
    try:
        return json.loads(raw.decode("utf-8"), parse_constant=_reject_constant, parse_float=_finite_float)
    except (UnicodeDecodeError, ValueError) as exc:
        raise CamcalError(f"{what} is not valid JSON ({' '.join(str(exc).split())[:100]})", where) from None
    except RecursionError:  # pragma: no cover - the depth check comes first
        raise CamcalError(f"{what} is nested too deeply; refused", where) from None



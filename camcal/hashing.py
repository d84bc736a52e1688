"""File hashing: the one SHA-256 of a file's bytes, read in blocks (memory does not grow with the file)."""

from __future__ import annotations

import hashlib
from pathlib import Path

BLOCK_BYTES = 1 << 20
"""Bytes read at a time."""


def sha256_file(path: str | Path) -> str:
    """SHA-256 (lower-case hex) of the bytes of ``path``, streamed in :data:`BLOCK_BYTES` blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(BLOCK_BYTES), b""):
            h.update(block)
    return h.hexdigest()

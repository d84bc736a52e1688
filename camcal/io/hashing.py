"""File hashing: the one SHA-256 of a file's bytes, read in blocks (memory does not grow with the file).

A calibration hashes each input file more than once (a dark frame is compared with the bias frames by content,
and every input goes into the profile's provenance), and 24 MP RAW files are tens of megabytes each. A hash
asked for with ``remember=True`` (the screening of a session's frames, beside their decode, which has just
brought them into the page cache) is therefore remembered, keyed by the file's identity and state (device,
inode, size, modification and change times in nanoseconds), and any later :func:`sha256_file` of the same
unchanged file returns it; a file replaced or rewritten in between is hashed again. Nothing else is remembered,
so a file checked against a recorded hash (a stage file's maps) is read every time.
:func:`hash_files` hashes many files in threads (``hashlib`` releases the GIL while it hashes a block).
"""

from __future__ import annotations

import hashlib
import os
import threading
from collections import OrderedDict
from collections.abc import Iterable
from pathlib import Path

from camcal.threads import thread_map

BLOCK_BYTES = 1 << 20
"""Bytes read at a time."""

MAX_REMEMBERED = 4096
"""File hashes remembered at most (the oldest forgotten first): a few hundred kilobytes."""

_remembered: OrderedDict[tuple, str] = OrderedDict()
_lock = threading.Lock()


def _state(st: os.stat_result) -> tuple:
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


def sha256_file(path: str | Path, *, remember: bool = False) -> str:
    """SHA-256 (lower-case hex) of the bytes of ``path``, streamed in :data:`BLOCK_BYTES` blocks.

    The hash of a file remembered in this process and not changed since (same inode, size, modification and
    change times) is returned without reading it again; ``remember``: remember this one (module docstring).
    """
    with open(path, "rb") as fh:
        key = _state(os.fstat(fh.fileno()))
        with _lock:
            known = _remembered.get(key)
        if known is not None:
            return known
        h = hashlib.sha256()
        for block in iter(lambda: fh.read(BLOCK_BYTES), b""):
            h.update(block)
        after = _state(os.fstat(fh.fileno()))
    digest = h.hexdigest()
    if remember and after == key:  # not written to while it was read
        with _lock:
            _remembered[key] = digest
            while len(_remembered) > MAX_REMEMBERED:
                _remembered.popitem(last=False)
    return digest


def hash_files(paths: Iterable[str | Path], threads: int = 1) -> dict[Path, str]:
    """:func:`sha256_file` of each of ``paths`` (``threads`` at a time); ``{path: hex digest}``."""
    paths = [Path(p) for p in paths]
    return dict(zip(paths, thread_map(sha256_file, paths, threads), strict=True))

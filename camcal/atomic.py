"""Atomic file output: write to a temporary file in the target folder, then rename.

A reader never sees a partial file, and an interrupted write leaves nothing
behind under the final name.
"""

from __future__ import annotations

import contextlib
import os
import signal
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

#: Temporary files of writes in progress (see :func:`remove_pending`).
_PENDING: set[Path] = set()
_LOCK = threading.Lock()


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    The temporary name keeps the extension of ``path`` (format plugins such as
    OpenImageIO choose the format from it). On any exception the temporary file
    is removed and the final path is left untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # Ctrl-C is held back (blocked for this thread) from creating the temporary file until the ``try``
    # that removes it is entered: otherwise an interrupt between the two leaves a .part file behind
    held = _hold_sigint()
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".part{path.suffix}", dir=path.parent)
        tmp_path = Path(tmp)
        with _LOCK:
            _PENDING.add(tmp_path)
    except BaseException:
        _release_sigint(held)
        raise
    try:
        _release_sigint(held)  # a pending Ctrl-C is raised here, inside the try
        try:
            os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual permissions
        finally:
            os.close(fd)
        yield tmp_path
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise
    finally:
        with _LOCK:
            _PENDING.discard(tmp_path)


def remove_pending() -> int:
    """Remove the temporary files of writes still in progress; returns how many.

    The CLI calls it when interrupted: CPython can deliver Ctrl-C between a context manager's
    ``__enter__`` and the start of its ``with`` block, where no ``except`` runs.
    """
    with _LOCK:
        pending = list(_PENDING)
        _PENDING.clear()
    n = 0
    for p in pending:
        with contextlib.suppress(OSError):
            p.unlink()
            n += 1
    return n


def _hold_sigint():
    """Block SIGINT for the calling thread; returns the previous mask (None where unsupported)."""
    if not hasattr(signal, "pthread_sigmask"):
        return None
    return signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


def _release_sigint(previous) -> None:
    if previous is not None:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically and return the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically and return the path."""
    return atomic_write_bytes(path, text.encode("utf-8"))

"""Atomic file output: write to a temporary file in the target folder, then rename.

A reader never sees a partial file, and an interrupted write leaves nothing
behind under the final name.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import signal
import tempfile
import threading
import time
from collections.abc import Iterator
from glob import escape as glob_escape
from pathlib import Path

from camcal.errors import CamcalError

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
    # The name is registered *before* the file is created: the mask only holds the signal back from this
    # thread, and another thread (a BLAS or codec pool) may take it, so Python can still raise
    # KeyboardInterrupt anywhere here; whatever is registered, :func:`remove_pending` removes at exit.
    held = _hold_sigint()
    try:
        while True:
            tmp_path = path.parent / f".{path.stem}.{os.getpid()}-{secrets.token_hex(4)}.part{path.suffix}"
            with _LOCK:
                _PENDING.add(tmp_path)
            try:
                fd = os.open(tmp_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o600)
                break
            except FileExistsError:
                with _LOCK:
                    _PENDING.discard(tmp_path)
            except OSError:  # no permission, no space: nothing was created
                with _LOCK:
                    _PENDING.discard(tmp_path)
                raise
    except BaseException:
        _release_sigint(held)
        raise
    try:
        _release_sigint(held)  # a pending Ctrl-C is raised here, inside the try
        try:
            os.chmod(tmp_path, 0o666 & ~_umask())  # created 0600; outputs get the usual permissions
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


@contextlib.contextmanager
def scratch_file(prefix: str, suffix: str = "", folder: str | Path | None = None) -> Iterator[Path]:
    """Yield the path of a new, empty, private temporary file; it is removed when the block ends, however it ends.

    ``folder`` defaults to the system temporary folder. As :func:`atomic_path`'s temporary files, its name is
    registered before the file is created, so an interrupt between the creation and the block (where no
    ``finally`` of the caller runs yet) still has it removed by :func:`remove_pending` (the CLI calls it at exit).
    """
    base = Path(folder) if folder is not None else Path(tempfile.gettempdir())
    while True:
        path = base / f"{prefix}{secrets.token_hex(6)}{suffix}"
        with _LOCK:
            _PENDING.add(path)
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o600)
            break
        except FileExistsError:
            with _LOCK:
                _PENDING.discard(path)
        except OSError:  # no permission, no space: nothing was created
            with _LOCK:
                _PENDING.discard(path)
            raise
    try:
        os.close(fd)
        yield path
    finally:
        with contextlib.suppress(OSError):
            path.unlink()
        with _LOCK:
            _PENDING.discard(path)


SPILL_MEMORY_FRACTION = 0.25
"""Default largest :func:`scratch_fd` held in memory, as a fraction of the memory still available."""


def available_memory_bytes() -> int | None:
    """Memory the system can still give without swapping, bytes: ``MemAvailable`` of ``/proc/meminfo``, at most
    what this process's control group (cgroup v2 ``memory.max`` less ``memory.current``) has left; None where
    neither can be read (not Linux)."""
    known: list[int] = []
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                known.append(int(line.split()[1]) * 1024)  # kB
                break
    with contextlib.suppress(OSError, ValueError):
        group = Path("/proc/self/cgroup").read_text().splitlines()[0].partition("::")[2]
        folder = Path("/sys/fs/cgroup") / group.lstrip("/")
        limit = (folder / "memory.max").read_text().strip()
        if limit != "max":
            known.append(int(limit) - int((folder / "memory.current").read_text()))
    return max(0, min(known)) if known else None


def spill_memory_limit_bytes() -> int:
    """The largest :func:`scratch_fd` held in memory, bytes: ``CAMCAL_SPILL_MEMORY_MB`` (megabytes, 0 = never) when
    set, else :data:`SPILL_MEMORY_FRACTION` of :func:`available_memory_bytes` (0 where that is unknown)."""
    env = os.environ.get("CAMCAL_SPILL_MEMORY_MB", "").strip()
    if env:
        try:
            return max(0, int(float(env) * 1e6))
        except ValueError:
            raise CamcalError(f"CAMCAL_SPILL_MEMORY_MB must be a number of megabytes, got {env!r}") from None
    avail = available_memory_bytes()
    return 0 if avail is None else int(SPILL_MEMORY_FRACTION * avail)


@contextlib.contextmanager
def scratch_fd(prefix: str, nbytes: int, folder: str | Path | None = None) -> Iterator[tuple[int, str]]:
    """Yield a read-write descriptor of a new, empty, private temporary file meant to hold about ``nbytes``, and
    a name for messages; the file is gone when the block ends, however it ends.

    Held in memory (an anonymous memory file, :func:`os.memfd_create`, Linux) when no ``folder`` is given and
    ``nbytes`` is within :func:`spill_memory_limit_bytes`: it has no name on disk, and its memory goes back
    to the system when the block ends or the process dies, even killed outright. Otherwise a
    :func:`scratch_file` in ``folder`` (default: the system temporary folder). A spill in memory is not
    counted in the process's resident set, but it is memory all the same, as the dirty page cache of a disk
    file is until written back. Writing it costs less: 768 MB in 0.35 s on its own, against 1.2-1.8 s into the
    page cache of a file on this project's 2-core test machine's disk. In a whole stack, where the writes are
    spread between decodes, the runs are steadier rather than faster (benchmarks/RESULTS.md, "dark").
    """
    if folder is None and hasattr(os, "memfd_create") and 0 < nbytes <= spill_memory_limit_bytes():
        try:
            fd = os.memfd_create(prefix, getattr(os, "MFD_CLOEXEC", 0))
        except OSError:  # no memory files here (an old kernel, a sandbox): the file goes on disk
            pass
        else:
            try:
                yield fd, f"temporary {prefix.strip('-')} file in memory"
            finally:
                os.close(fd)
            return
    with scratch_file(prefix, ".raw", folder) as path:
        fd = os.open(path, os.O_RDWR | getattr(os, "O_CLOEXEC", 0))
        try:
            yield fd, str(path)
        finally:
            os.close(fd)


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


def clear_stale(path: str | Path) -> int:
    """Remove the temporary files left beside ``path`` by writers that no longer run; returns how many.

    A writer killed outright (SIGKILL, an out-of-memory killer, a scheduler) runs no cleanup and leaves its
    ``.<stem>.<pid>-<random>.part<ext>`` file behind. A file whose writer's process id is not running on this
    machine is stale; one whose writer still runs (a concurrent write) is kept. Files of the older name form
    without a process id are stale when untouched for an hour.
    """
    path = Path(path)
    n = 0
    try:
        candidates = list(path.parent.glob(f".{glob_escape(path.stem)}.*.part{glob_escape(path.suffix)}"))
    except OSError:
        return 0
    for tmp in candidates:
        middle = tmp.name[len(path.stem) + 2: -len(f".part{path.suffix}")]
        pid_text, sep, _rand = middle.partition("-")
        if sep and pid_text.isdigit():
            stale = not _pid_running(int(pid_text))
        else:
            try:
                stale = time.time() - tmp.stat().st_mtime > 3600.0
            except OSError:
                continue
        if stale:
            with contextlib.suppress(OSError):
                tmp.unlink()
                n += 1
    return n


def _pid_running(pid: int) -> bool:
    """Whether process ``pid`` still runs. A zombie (killed, not yet reaped by whoever adopted it) does not:
    it will never finish its write, and ``kill(pid, 0)`` alone would call it alive."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # exists, owned by someone else (or cannot tell): keep the file
    try:  # Linux: the state is the field after the parenthesised command name of /proc/<pid>/stat
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return stat.rpartition(")")[2].split()[:1] not in (["Z"], ["X"])


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

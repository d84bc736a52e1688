"""The guard around C libraries that write to the process's stderr (LibRaw, libheif, OpenImageIO, cfitsio).

Their messages are captured while a file is read and kept with the file's error or notes, so that a command's output
stays one clear line per problem; a crash still reaches the real stderr.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import threading


class _QuietState:
    """The state of :func:`quiet_stderr`, process-wide as fd 2 is (guarded by ``lock``)."""

    lock = threading.Lock()
    depth = 0
    """Blocks open, in every thread."""
    fd = -1
    """The silenced descriptor (2) from the first open block until the last one restores it, else -1."""
    previous: object = None
    """``sys.stderr`` as it was before the first open block."""
    real: io.TextIOWrapper | None = None
    """A stream on a duplicate of the real standard error (:func:`_real_stderr`)."""
    real_of = -1
    """The descriptor ``real`` duplicates (2)."""
    real_key: tuple[int, int] | None = None
    """(device, inode) of the file ``real`` writes to."""


def _real_stderr(fd: int) -> io.TextIOWrapper:
    """A line-buffered text stream on a duplicate of ``fd`` (standard error, not silenced).

    One for as long as ``fd`` refers to the same file: a camcal process keeps a single duplicate and never closes
    it while a thread may still write to it. When ``fd`` has been pointed at another file since (a test harness
    capturing each test's output), a new duplicate replaces the old one."""
    st = os.fstat(fd)
    key = (st.st_dev, st.st_ino)
    if _QuietState.real is None or _QuietState.real_key != key or _QuietState.real_of != fd:
        old = _QuietState.real
        enc = getattr(sys.stderr, "encoding", None) or "utf-8"
        # the stream does not own the duplicate (closefd=False): it stays open to the process's end, with nothing
        # to close or to warn about at exit, whatever thread or interrupt still holds the stream then
        _QuietState.real = open(os.dup(fd), "w", buffering=1, encoding=enc, errors="backslashreplace",  # noqa: SIM115
                                closefd=False)
        _QuietState.real_of, _QuietState.real_key = fd, key
        if old is not None:
            old.flush()
            os.close(old.fileno())
    return _QuietState.real


@contextlib.contextmanager
def quiet_stderr():
    """Silence C libraries (LibRaw, libpng, libjpeg print their warnings to fd 2) for the block, not Python.

    fd 2 is process-wide, so concurrent blocks share one redirection (reference-counted): the first to enter
    points fd 2 at the null device, the last to leave points it back. Meanwhile ``sys.stderr`` is a stream on a
    duplicate of the real standard error (:func:`_real_stderr`), so what Python writes, in any thread, still
    reaches it: a stage's warning, a failed photo, the command line's "interrupted" while another thread decodes.

    The steps are ordered so that an interrupt (KeyboardInterrupt, which Python raises between any two of them)
    leaves ``sys.stderr`` writing to the real standard error, and a later block finishes what it left: the stream
    is swapped in before fd 2 is silenced, and fd 2 is restored before the stream is swapped out.
    """
    state = _QuietState
    if sys.stderr is not None and sys.stderr is state.real:
        fd = state.real_of  # a block is open in another thread (or was left open by an interrupt)
    else:
        try:
            fd = sys.stderr.fileno()
        except (AttributeError, OSError, ValueError):
            yield
            return
    with state.lock:
        if state.depth == 0:
            if state.fd == -1:  # fd is the real standard error: keep a stream on it, then silence it
                sys.stderr.flush()
                real = _real_stderr(fd)
                if sys.stderr is not real:
                    state.previous = sys.stderr
                sys.stderr = real
                state.fd = fd
            null = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(null, state.fd)
            finally:
                os.close(null)
        state.depth += 1
    try:
        yield
    finally:
        with state.lock:
            state.depth -= 1
            if state.depth == 0 and state.real is not None and state.fd != -1:
                state.real.flush()
                os.dup2(state.real.fileno(), state.fd)
                if sys.stderr is state.real and state.previous is not None:
                    sys.stderr = state.previous  # unless something else replaced it meanwhile
                state.fd, state.previous = -1, None

"""Folders of frames: the image files of a folder, its ``frames.csv`` applied, and frames decoded ahead in threads.
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TypeVar

from camcal.errors import CamcalError
from camcal.frame import Frame
from camcal.io.kinds import IMAGE_EXTENSIONS
from camcal.io.manifest import (
    FRAMES_CSV,
    exposure_overrides,
    read_manifest,
)
from camcal.io.read import load_frame

T = TypeVar("T")


R = TypeVar("R")


def list_frames(folder: str | Path) -> list[Path]:
    """Image files in ``folder`` (not recursive), sorted by name; hidden and partial files skipped."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CamcalError("is not a folder", folder)
    return sorted(
        p
        for p in folder.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_EXTENSIONS
    )


def folder_manifest(folder: str | Path) -> dict[str, dict[str, float | str | None]]:
    """The folder's ``frames.csv`` rows keyed by file name ({} when absent)."""
    path = Path(folder) / FRAMES_CSV
    return read_manifest(path) if path.exists() else {}


def load_folder_frame(path: Path, manifest: dict[str, dict[str, float | str | None]]) -> Frame:
    """Load ``path`` with the exposure overrides of its manifest row, if any."""
    return load_frame(path, exposure_overrides(manifest.get(path.name)))


def folder_files(
    folder: str | Path, manifest: dict[str, dict[str, float | str | None]] | None = None
) -> tuple[list[Path], dict[str, dict[str, float | str | None]]]:
    """The image files of a folder and its manifest rows (read from ``frames.csv`` unless given).

    Rows of ``frames.csv`` naming anything but an image file of the folder (absent, another extension,
    a sub-folder), and a folder without images, are errors.
    """
    folder = Path(folder)
    files = list_frames(folder)
    if manifest is None:
        manifest = folder_manifest(folder)
    names = {p.name for p in files}
    for name in manifest:
        if name not in names:
            raise CamcalError(f"frames.csv lists {name!r}, which is not an image file in the folder", folder)
    if not files:
        raise CamcalError("holds no image files", folder)
    return files, manifest


def read_ahead(items: Iterable[T], load: Callable[[T], R], threads: int = 1) -> Iterator[R]:
    """``load(item)`` of each item, in order, with up to ``threads`` of the next items loading in threads meanwhile.

    The caller works on one frame while the next ones decode (LibRaw and OpenImageIO release the GIL). At most
    ``threads + 1`` results exist at once, so memory does not grow with the number of items. An error of
    ``load`` is raised when its item's turn comes, as a plain loop would; ``threads <= 0`` is that plain loop.
    """
    if threads <= 0:
        yield from map(load, items)
        return
    it = iter(items)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        pending = deque(pool.submit(load, x) for x in itertools.islice(it, threads))
        try:
            while pending:
                done = pending.popleft()
                for x in itertools.islice(it, 1):
                    pending.append(pool.submit(load, x))
                yield done.result()
        finally:
            for f in pending:  # the caller stopped early (an error): do not decode what nobody will read
                f.cancel()

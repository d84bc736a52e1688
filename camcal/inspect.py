"""A plain description of image files: what ``camcal inspect`` prints."""

from __future__ import annotations

from pathlib import Path

from camcal.errors import CamcalError
from camcal.frame import TRACKED
from camcal.io import folder_manifest, load_frame
from camcal.manifest import exposure_overrides
from camcal.session import STAGES, index_session


def describe(path: str | Path) -> dict[str, object]:
    """Decode ``path`` and return its layout and exposure metadata as a JSON-ready dict.

    Keys: file, kind (raw/processed), layout (bayer/linear/processed), format, width, height,
    channels (plane names), cfa_pattern, black_level_dn (per plane), white_level_dn,
    exposure_s, f_number, iso, exposure_value_s (ISO·t/N², s), make, model, serial,
    capture_time, sources (where each of exposure_s, f_number, iso, capture_time came from:
    ``tag``, ``libraw``, ``frames.csv``, ``session``; null when unknown), notes (disagreements
    between readers, values set aside), error (null).

    An unknown value is null (None): never a library's placeholder. The file's values are read the way
    ``calibrate`` and ``apply`` read them (:func:`manifest_row`): a stage folder of a session through the
    session index (its ``frames.csv`` or ``sweep.csv`` row, marked ``frames.csv``), any other folder through
    its own ``frames.csv``; session defaults (``session.toml`` beside the file or in its parent folder)
    apply, marked ``session``.
    """
    overrides, index_note = manifest_row(Path(path))
    f = load_frame(path, overrides)
    e = f.exposure
    h, w = f.shape
    ev = e.iso * e.exposure_s / e.f_number**2 if (e.iso and e.exposure_s and e.f_number) else None
    return {
        "file": str(path),
        "kind": f.kind,
        "layout": f.layout,
        "format": Path(path).suffix.lower().lstrip("."),
        "width": w,
        "height": h,
        "channels": list(f.channel_names),
        "cfa_pattern": f.cfa_pattern,
        "black_level_dn": f.black_level_dn,
        "white_level_dn": f.white_level_dn,
        "exposure_s": e.exposure_s,
        "f_number": e.f_number,
        "iso": e.iso,
        "exposure_value_s": ev,
        "make": e.make,
        "model": e.model,
        "serial": e.serial,
        "capture_time": e.capture_time,
        "sources": {name: e.source(name) for name in TRACKED},
        "notes": list(e.notes) + ([index_note] if index_note else []),
        "error": None,
    }


def manifest_row(path: Path) -> tuple[dict[str, float | None], str | None]:
    """The manifest overrides ``calibrate`` or ``apply`` would give ``path``, and a note when it could not say.

    In a session's stage folder (``SESSION/dark/x.dng``): the row the session index resolves for the file
    (:func:`camcal.session.index_session`, as ``calibrate`` reads it). In any other folder: the folder's own
    ``frames.csv`` row (as ``apply`` reads a folder of photos).
    """
    folder = path.parent
    if folder.name in STAGES:
        try:
            index = index_session(folder.parent)
        except CamcalError as exc:  # the file is still described, with the reason its session is not read
            return exposure_overrides(folder_manifest(folder).get(path.name)), f"session index: {exc}"
        stage = index.stage(folder.name)
        if stage is not None:
            for ref in stage.frames:
                if ref.path.name == path.name:
                    return dict(ref.overrides), None
            return {}, None
    return exposure_overrides(folder_manifest(folder).get(path.name)), None


def describe_many(paths: list[str | Path]) -> tuple[list[dict[str, object]], list[dict[str, str]]]:
    """:func:`describe` every file; one that cannot be read does not stop the others.

    Returns
    -------
    (entries, failures): ``entries`` in the order given, a failed file as ``{"file", "error"}``
    (the one-line reason); ``failures`` those failed entries alone.
    """
    entries: list[dict[str, object]] = []
    failures: list[dict[str, str]] = []
    for p in paths:
        try:
            entries.append(describe(p))
        except CamcalError as exc:
            failures.append({"file": str(p), "error": str(exc)})
            entries.append(failures[-1])  # type: ignore[arg-type]
    return entries, failures

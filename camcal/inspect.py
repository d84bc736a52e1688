"""A plain description of image files: what ``camcal inspect`` prints."""

from __future__ import annotations

from pathlib import Path

from camcal.errors import CamcalError
from camcal.frame import TRACKED
from camcal.io import load_frame, saturated_fraction


def describe(path: str | Path) -> dict[str, object]:
    """Decode ``path`` and return its layout and exposure metadata as a JSON-ready dict.

    Keys: file, kind (raw/processed), layout (bayer/linear/processed), format, width, height,
    channels (plane names), cfa_pattern, black_level_dn (per plane), white_level_dn,
    exposure_s, f_number, iso, exposure_value_s (ISO·t/N², s), make, model, serial,
    capture_time, saturated_pct (percent of the values at or above the white level), saturated (a note
    when a quarter of them or more are: "fully saturated" or the percentage; null otherwise), sources
    (where each of exposure_s, f_number, iso, capture_time came from:
    ``tag``, ``libraw``, ``frames.csv``, ``session``; null when unknown), notes (disagreements
    between readers, values set aside), error (null).

    An unknown value is null (None): never a library's placeholder. Session defaults
    (``session.toml`` beside the file or in its parent folder) apply, marked ``session``.
    """
    f = load_frame(path)
    e = f.exposure
    h, w = f.shape
    sat = 100.0 * saturated_fraction(f.data, f.white_level_dn)
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
        "saturated_pct": round(sat, 3),
        "saturated": ("fully saturated: every value at the white level" if sat >= 100.0 else
                      f"{min(sat, 99.99):.4g} % of the values at the white level" if sat >= 25.0 else None),
        "sources": {name: e.source(name) for name in TRACKED},
        "notes": list(e.notes),
        "error": None,
    }


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

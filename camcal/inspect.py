"""A plain description of an image file: what ``camcal inspect`` prints."""

from __future__ import annotations

from pathlib import Path

from camcal.io import load_frame


def describe(path: str | Path) -> dict[str, object]:
    """Decode ``path`` and return its layout and exposure metadata as a JSON-ready dict.

    Keys: file, kind, format, width, height, cfa_pattern, black_level_dn (per plane),
    white_level_dn, exposure_s, f_number, iso, exposure_value (ISO·t/N², s),
    make, model, serial, capture_time.
    """
    f = load_frame(path)
    e = f.exposure
    h, w = f.shape
    ev = e.iso * e.exposure_s / e.f_number**2 if (e.iso and e.exposure_s and e.f_number) else None
    return {
        "file": str(path),
        "kind": f.kind,
        "format": Path(path).suffix.lower().lstrip("."),
        "width": w,
        "height": h,
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
    }

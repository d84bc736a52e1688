"""EXIF and time: a file's exposure tags, where and when it was taken, and LibRaw's values reconciled with the tags.

Tags are read by exifread (a HEIC's EXIF block taken out by libheif); a tag that holds zero or nothing is unknown.
Where and when (:data:`camcal.frame.PLACE_TIME`): OffsetTimeOriginal, the GPS position and altitude, and the UTC
GPSDateStamp + GPSTimeStamp; a position of exactly 0°, 0°, a missing reference letter and a GPS time without a date
are unknown, with a note. LibRaw fills only what no tag holds, never from its placeholders (shutter 1 s, f/1, the
1970 timestamp), and a note says where it disagrees with a tag.
"""

from __future__ import annotations

import dataclasses
import io
import logging
import math
from datetime import UTC, datetime
from fractions import Fraction
from pathlib import Path

import exifread
import pillow_heif

from camcal.errors import CamcalError
from camcal.frame import TRACKED, Exposure
from camcal.io.kinds import is_heif
from camcal.io.manifest import (
    parse_utc_offset,
)
from camcal.io.stderr import quiet_stderr


def clean_number(value) -> float | None:
    """rawpy gives float32 values (0.004000000189...): round to 7 significant digits."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    if not math.isfinite(v) or v <= 0:
        return None
    return float(f"{v:.7g}")


def _exif_reader():
    log = logging.getLogger("exifread")  # it logs "File format not recognized." to stderr on non-EXIF files
    if log.level == logging.NOTSET:
        log.setLevel(logging.ERROR)
    return exifread


def exif_from_block(block: bytes | None) -> dict[str, object]:
    """EXIF tags of an EXIF block (TIFF structure, optionally after ``Exif\\0\\0``) via exifread; {} on failure."""
    if not block:
        return {}
    if block.startswith(b"Exif\x00\x00"):
        block = block[6:]
    try:
        return _exif_reader().process_file(io.BytesIO(block), details=False, debug=False)
    except Exception:  # exifread raises many types on damaged blocks; metadata is optional here
        return {}


def _heif_exif_block(path: Path) -> bytes | None:
    """The EXIF block libheif finds in a HEIF file (exifread knows only some HEIF brands); None when none."""
    try:
        with quiet_stderr():
            return pillow_heif.open_heif(str(path)).info.get("exif")
    except Exception:  # a damaged file: the pixel decoder reports it; metadata is optional here
        return None


def exif_tags(path: Path) -> dict[str, object]:
    """EXIF tags via exifread (header only); {} when the file has none or is damaged.

    HEIF files: the EXIF block libheif takes out of the file, read by exifread.
    """
    try:
        if is_heif(path):
            return exif_from_block(_heif_exif_block(path))
    except CamcalError:  # unreadable: the decoder reports it; metadata is optional here
        return {}
    try:
        exifread = _exif_reader()
        with open(path, "rb") as fh:
            return exifread.process_file(fh, details=False, debug=False)
    except Exception:  # exifread raises many types on damaged files; metadata is optional here
        return {}


def exif_value(tags: dict[str, object], *names: str) -> float | str | None:
    for name in names:
        tag = tags.get(name)
        if tag is None:
            continue
        vals = getattr(tag, "values", None)
        if isinstance(vals, str):
            s = vals.strip("\x00 ").strip()
            if s:
                return s
            continue
        if isinstance(vals, list | tuple) and vals:
            v = vals[0]
            try:
                if hasattr(v, "num"):
                    return float(Fraction(v.num, v.den)) if v.den else None
                return float(v)
            except (TypeError, ValueError, ZeroDivisionError):
                continue
    return None


#: exifread names of the tags of each tracked field, first found wins.
TAG_NAMES: dict[str, tuple[str, ...]] = {
    "exposure_s": ("EXIF ExposureTime", "Image ExposureTime"),
    "f_number": ("EXIF FNumber", "Image FNumber"),
    "iso": ("EXIF ISOSpeedRatings", "EXIF PhotographicSensitivity", "EXIF ISOSpeed", "Image ISOSpeedRatings"),
    "capture_time": ("EXIF DateTimeOriginal", "Image DateTimeOriginal"),
    "focal_length_mm": ("EXIF FocalLength", "Image FocalLength"),
    "focal_length_35mm_mm": ("EXIF FocalLengthIn35mmFilm",),
}
"""The capture time is DateTimeOriginal only: IFD0 ``DateTime`` is when the file was last written."""


def tag_present(tags: dict[str, object], field_name: str) -> bool:
    return any(n in tags for n in TAG_NAMES[field_name])


def _ratios(tags: dict[str, object], name: str) -> list[float] | None:
    """The rational values of tag ``name`` as floats; None when absent or a denominator is zero."""
    tag = tags.get(name)
    vals = getattr(tag, "values", None)
    if not isinstance(vals, list | tuple) or not vals:
        return None
    out = []
    for v in vals:
        try:
            out.append(float(Fraction(v.num, v.den)) if hasattr(v, "num") else float(v))
        except (TypeError, ValueError, ZeroDivisionError):
            return None
    return out


def place_time_from_exif(tags: dict[str, object]) -> tuple[dict[str, object], list[str]]:
    """OffsetTimeOriginal and the GPS block (position, altitude, UTC date and time) of exifread ``tags``.

    Returns
    -------
    (values, notes): ``values`` holds the :data:`camcal.frame.PLACE_TIME` fields found (unknown ones left
    out); ``notes`` says why a present tag was not used.
    """
    values: dict[str, object] = {}
    notes: list[str] = []

    def text(name: str) -> str | None:
        v = exif_value(tags, name)
        return v if isinstance(v, str) else None

    off = text("EXIF OffsetTimeOriginal")
    if off is not None:
        if parse_utc_offset(off) is None:
            notes.append(f"OffsetTimeOriginal {off!r} is not an offset of a time zone (±HH:MM); not used")
        else:
            values["utc_offset"] = "+00:00" if off.strip() in ("Z", "z") else off.strip()
    lat, lon = _ratios(tags, "GPS GPSLatitude"), _ratios(tags, "GPS GPSLongitude")
    lat_ref, lon_ref = text("GPS GPSLatitudeRef"), text("GPS GPSLongitudeRef")
    if lat is not None and lon is not None:
        deg = [sum(x / 60.0**i for i, x in enumerate(v[:3])) for v in (lat, lon)]
        if lat_ref not in ("N", "S") or lon_ref not in ("E", "W"):
            notes.append("GPS position without its N/S or E/W reference; not used")
        elif deg[0] == 0.0 and deg[1] == 0.0:
            notes.append("GPS position 0°, 0° (a receiver without a fix writes it); not used")
        elif deg[0] > 90.0 or deg[1] > 180.0:
            notes.append(f"GPS position {deg[0]:.6g}°, {deg[1]:.6g}° is out of range; not used")
        else:
            values["latitude_deg"] = -deg[0] if lat_ref == "S" else deg[0]
            values["longitude_deg"] = -deg[1] if lon_ref == "W" else deg[1]
    alt = _ratios(tags, "GPS GPSAltitude")
    if alt is not None and "latitude_deg" in values:
        ref = _ratios(tags, "GPS GPSAltitudeRef")
        values["altitude_m"] = -alt[0] if ref and ref[0] == 1 else alt[0]
    hms, date = _ratios(tags, "GPS GPSTimeStamp"), text("GPS GPSDate") or text("GPS GPSDateStamp")
    if hms is not None and len(hms) == 3:
        if date is None:
            notes.append("GPS time stamp without a GPS date; not used (the UTC date is unknown)")
        else:
            try:
                day = datetime.strptime(date.strip(), "%Y:%m:%d")
                h, m, sec = hms
                if not (0 <= h < 24 and 0 <= m < 60 and 0 <= sec < 61):
                    raise ValueError
                whole = int(sec)
                utc = day.replace(hour=int(h), minute=int(m), second=min(whole, 59),
                                  microsecond=int(round((sec - whole) * 1e6)) % 1_000_000, tzinfo=UTC)
                values["gps_time_utc"] = utc.isoformat()
            except ValueError:
                notes.append(f"GPS date/time {date} {hms} is not a valid date and time; not used")
    return values, notes


def iso_time(exif_time: str | None) -> str | None:
    if not exif_time or not exif_time.strip(" 0:"):  # "0000:00:00 00:00:00" is the EXIF way of saying unknown
        return None
    parts = exif_time.replace(":", "-", 2).split(" ")
    return "T".join(parts) if len(parts) == 2 else exif_time


def libraw_time(ts) -> str | None:
    """LibRaw's timestamp as ISO text; its placeholder (the 1970 epoch, no date in the file) is None."""
    if not hasattr(ts, "isoformat") or getattr(ts, "year", 1970) <= 1970:
        return None
    return ts.replace(microsecond=0).isoformat()


def _fmt(name: str, v: float | str) -> str:
    return v if isinstance(v, str) else f"{v:.6g}{' s' if name == 'exposure_s' else ''}"


def reconcile_libraw(exp: Exposure, tags: dict[str, object], libraw: dict[str, float | str | None]) -> Exposure:
    """Combine the tag values ``exp`` (from :func:`exposure_from_exif`) with LibRaw's ``libraw`` values.

    Per field of :data:`camcal.frame.TRACKED`: a tag with a value wins (a note when LibRaw disagrees
    by more than 0.1 %); a tag present but zero or empty makes the value unknown, whatever LibRaw says
    (its placeholders: shutter 1 s, f/1, ISO 0, the 1970 epoch); with no tag, LibRaw's value is used
    and marked ``libraw``.
    """
    values: dict[str, object] = {}
    sources = dict(exp.sources)
    notes = list(exp.notes)
    for name in TRACKED:
        tag_v, lib_v = getattr(exp, name), libraw.get(name)
        if tag_v is not None:
            if lib_v is not None and (
                tag_v != lib_v if isinstance(tag_v, str) else abs(float(tag_v) - float(lib_v)) > 1e-3 * float(tag_v)
            ):
                notes.append(f"{name}: the file's tag says {_fmt(name, tag_v)}, LibRaw {_fmt(name, lib_v)}; "
                             "the tag is used")
            continue
        if tags and tag_present(tags, name):
            if lib_v is not None:
                notes.append(f"{name}: the file's tag holds zero or nothing (unknown); LibRaw's "
                             f"{_fmt(name, lib_v)} is not used")
            continue
        if lib_v is not None:
            values[name] = lib_v
            sources[name] = "libraw"
    return dataclasses.replace(exp, **values, sources=tuple(sorted(sources.items())), notes=tuple(notes))


def fill_exposure(primary: Exposure, fallback: Exposure) -> Exposure:
    """Fields of ``primary``, with gaps filled from ``fallback`` (each value keeps its own source)."""
    values, src = {}, {}
    for f in dataclasses.fields(Exposure):
        if f.name in ("sources", "notes"):
            continue
        take = primary if getattr(primary, f.name) is not None else fallback
        values[f.name] = getattr(take, f.name)
        if take.source(f.name) is not None:
            src[f.name] = take.source(f.name)
    return Exposure(**values, sources=tuple(sorted(src.items())), notes=primary.notes + fallback.notes)

"""Reading frames: RAW through rawpy (LibRaw), JPEG/TIFF/PNG through OpenImageIO, HEIC/HEIF through
pillow-heif (libheif).

HEIC/HEIF photos (a phone's default format) are processed images like JPEG: R, G, B of 8 bits, or of
10 or 12 bits held in uint16 (white level 2**bits − 1); the embedded ICC profile's description is noted
on the frame (iPhones write Display P3), not applied. Their EXIF block, taken out by libheif, is read by
the same EXIF reader as every other file.

Where and when (:data:`camcal.frame.PLACE_TIME`), from the EXIF of RAW, JPEG and HEIC alike, each marked
``tag``: OffsetTimeOriginal (the clock's zone), the GPS block's position and altitude, and its UTC
GPSDateStamp + GPSTimeStamp. A position of exactly 0°, 0° (written by receivers without a fix), a
reference letter that is missing, and a GPS time without a date are unknown, with a note. A
``utc_offset`` in ``session.toml`` fills an offset the file does not hold (marked ``session``).

Exposure metadata, each value with its source (:data:`camcal.frame.SOURCES`):

1. the file's tags, read by an EXIF reader (exifread; for processed images also the
   OpenImageIO spec). A tag that is present but holds zero or nothing is *unknown*;
2. for RAW files, LibRaw's value where no tag holds one (e.g. a maker header that only
   LibRaw decodes), marked ``libraw``; LibRaw's placeholders for zero tags (shutter 1 s,
   f/1, the 1970 timestamp) are never used. Where LibRaw and the tag disagree, a note says so;
3. the session defaults file (``session.toml`` in the frame's folder or its parent, see
   :func:`camcal.io.manifest.session_defaults_for`) for values still unknown;
4. the folder's ``frames.csv`` manifest, which overrides all of them.

RAW files are 2x2 Bayer mosaics (``layout == "bayer"``) or linear multi-channel RAW
(DNG LinearRaw, LibRaw ``RawType.Stack``: ``layout == "linear"``); other sensor layouts
(X-Trans, Foveon, 4-colour CFAs) and RAW files without image data are refused.

Every failure to read a file becomes a one-line :class:`~camcal.errors.CamcalError`
naming the file.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import itertools
import logging
import math
import os
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from fractions import Fraction
from pathlib import Path
from typing import TypeVar

import exifread
import numpy as np
import OpenImageIO as oiio
import pillow_heif
import rawpy
from PIL import ImageCms

from camcal.errors import CamcalError
from camcal.frame import PLANES, RGB, TRACKED, Exposure, Frame, pattern_from_rawpy, plane_offsets
from camcal.io.limits import check_expansion, declared_image_bytes, max_pixels
from camcal.io.manifest import (
    FRAMES_CSV,
    exposure_overrides,
    parse_utc_offset,
    read_manifest,
    session_camera_facts,
    session_defaults_for,
)

T = TypeVar("T")
R = TypeVar("R")

RAW_EXTENSIONS = {
    ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".orf", ".rw2", ".raf",
    ".pef", ".srw", ".x3f", ".3fr", ".iiq", ".erf", ".kdc", ".dcr", ".mrw", ".raw", ".rwl",
}
HEIF_EXTENSIONS = {".heic", ".heif", ".hif"}
PROCESSED_EXTENSIONS = {".jpg", ".jpeg", ".tif", ".tiff", ".png"} | HEIF_EXTENSIONS
HEIF_BRANDS = {b"heic", b"heix", b"hevc", b"hevx", b"heim", b"heis", b"hevm", b"hevs", b"mif1", b"msf1", b"mif2"}
"""ISO/IEC 23008-12 major brands of HEVC-coded HEIF files (the ``ftyp`` box, bytes 8–12)."""
FITS_EXTENSIONS = {".fits", ".fit", ".fts"}
"""FITS images (astronomy cameras): monochrome frames read with astropy (:func:`_load_fits`)."""
IMAGE_EXTENSIONS = RAW_EXTENSIONS | PROCESSED_EXTENSIONS | FITS_EXTENSIONS


def _check_pixels(path: Path, width: int, height: int, stored_bytes: float | None = None) -> None:
    """The declared size against the limits (camcal.io.limits); ``stored_bytes`` default: 16-bit mosaic."""
    if width <= 0 or height <= 0:
        raise CamcalError(f"declares an empty image ({width}x{height})", path)
    if width * height > max_pixels():
        raise CamcalError(
            f"declares {width}x{height} pixels, above the limit of {max_pixels()} (set CAMCAL_MAX_PIXELS to raise it)",
            path,
        )
    check_expansion(path, 2.0 * width * height if stored_bytes is None else stored_bytes)


def _clean(value) -> float | None:
    """rawpy gives float32 values (0.004000000189...): round to 7 significant digits."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    if not math.isfinite(v) or v <= 0:
        return None
    return float(f"{v:.7g}")


def _check_file(path: Path) -> None:
    if not path.exists():
        raise CamcalError("no such file", path)
    if path.is_dir():
        raise CamcalError("is a directory, not an image file", path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise CamcalError(f"cannot read: {exc.strerror}", path) from None
    if size == 0:
        raise CamcalError("is empty (0 bytes)", path)


def _magic(path: Path) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read(16)
    except OSError as exc:
        raise CamcalError(f"cannot read: {exc.strerror}", path) from None


def is_heif(path: Path) -> bool:
    """True when the file is an HEVC-coded HEIF (HEIC) image, by its ``ftyp`` box or, failing that, its name."""
    head = _magic(path)
    if head[4:8] == b"ftyp":
        return head[8:12] in HEIF_BRANDS
    return path.suffix.lower() in HEIF_EXTENSIONS and not head.startswith((b"\xff\xd8\xff", b"\x89PNG"))


def _exif_reader():
    log = logging.getLogger("exifread")  # it logs "File format not recognized." to stderr on non-EXIF files
    if log.level == logging.NOTSET:
        log.setLevel(logging.ERROR)
    return exifread


def _exif_from_block(block: bytes | None) -> dict[str, object]:
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


def _exif_tags(path: Path) -> dict[str, object]:
    """EXIF tags via exifread (header only); {} when the file has none or is damaged.

    HEIF files: the EXIF block libheif takes out of the file, read by exifread.
    """
    try:
        if is_heif(path):
            return _exif_from_block(_heif_exif_block(path))
    except CamcalError:  # unreadable: the decoder reports it; metadata is optional here
        return {}
    try:
        exifread = _exif_reader()
        with open(path, "rb") as fh:
            return exifread.process_file(fh, details=False, debug=False)
    except Exception:  # exifread raises many types on damaged files; metadata is optional here
        return {}


def _exif_value(tags: dict[str, object], *names: str) -> float | str | None:
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


def _tag_present(tags: dict[str, object], field_name: str) -> bool:
    return any(n in tags for n in TAG_NAMES[field_name])


def exposure_from_exif(path: Path, tags: dict[str, object] | None = None) -> Exposure:
    """Exposure metadata from a file's EXIF, via exifread; every value found is marked ``tag``.

    A tag that holds zero (or an empty date) gives None: unknown. A FITS file has no EXIF: its header's keys
    (:func:`_fits_exposure`).
    """
    if tags is None and is_fits(path):
        return _fits_exposure(_fits_header(path))
    tags = _exif_tags(path) if tags is None else tags
    if not tags:
        return Exposure()

    def num(*names):
        v = _exif_value(tags, *names)
        return _clean(v) if isinstance(v, float) else None

    def text(*names):
        v = _exif_value(tags, *names)
        return v if isinstance(v, str) else None

    temp = _exif_value(tags, "EXIF Temperature", "EXIF Tag 0x9400")
    values = {
        "exposure_s": num(*TAG_NAMES["exposure_s"]),
        "f_number": num(*TAG_NAMES["f_number"]),
        "iso": num(*TAG_NAMES["iso"]),
        "capture_time": _iso_time(text(*TAG_NAMES["capture_time"])),
        "focal_length_mm": num(*TAG_NAMES["focal_length_mm"]),
        "focal_length_35mm_mm": num(*TAG_NAMES["focal_length_35mm_mm"]),
    }
    place, notes = place_time_from_exif(tags)
    return Exposure(
        **values,
        **place,
        make=text("Image Make"),
        model=text("Image Model"),
        serial=text("EXIF BodySerialNumber", "Image Tag 0xC62F", "MakerNote SerialNumber"),
        temperature_c=float(temp) if isinstance(temp, float) else None,
        sources=tuple(sorted((k, "tag") for k, v in (values | place).items() if v is not None)),
        notes=tuple(notes),
    )


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
        v = _exif_value(tags, name)
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


def _iso_time(exif_time: str | None) -> str | None:
    if not exif_time or not exif_time.strip(" 0:"):  # "0000:00:00 00:00:00" is the EXIF way of saying unknown
        return None
    parts = exif_time.replace(":", "-", 2).split(" ")
    return "T".join(parts) if len(parts) == 2 else exif_time


def _libraw_time(ts) -> str | None:
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
        if tags and _tag_present(tags, name):
            if lib_v is not None:
                notes.append(f"{name}: the file's tag holds zero or nothing (unknown); LibRaw's "
                             f"{_fmt(name, lib_v)} is not used")
            continue
        if lib_v is not None:
            values[name] = lib_v
            sources[name] = "libraw"
    return dataclasses.replace(exp, **values, sources=tuple(sorted(sources.items())), notes=tuple(notes))


def _fill(primary: Exposure, fallback: Exposure) -> Exposure:
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


def _layout_name(raw) -> str:
    """A short name for a RAW file's sensor layout, for the refusal of layouts camcal does not read."""
    pattern = getattr(raw, "raw_pattern", None)
    desc = raw.color_desc.decode("ascii", "replace")
    if pattern is not None and np.shape(pattern) == (6, 6):
        return "X-Trans (6x6 colour filter array)"
    if raw.num_colors == 4 and "R" not in desc:
        return f"a 4-colour {desc} colour filter array"
    if raw.num_colors != 3:
        return f"a {raw.num_colors}-colour sensor ({desc})"
    if pattern is None:
        return "a sensor without a colour filter array (e.g. Foveon) or a monochrome sensor"
    return f"a {np.shape(pattern)[0]}x{np.shape(pattern)[1]} colour filter array"


MIN_RAW_BYTES_PER_PIXEL = 1 / 64
"""Smallest file size per declared pixel of a RAW file that holds its image data (1 bit per 8 pixels:
lossy DNGs hold about 0.4 byte per pixel, files whose image data were stripped 0.002 or less)."""


def _check_size_for_pixels(path: Path, width: int, height: int) -> None:
    """Refuse a RAW file too small to hold the pixels it declares, before LibRaw decodes it: LibRaw then
    reads past the end of the file and returns zeros or whatever its buffer held before."""
    size = path.stat().st_size
    if size < width * height * MIN_RAW_BYTES_PER_PIXEL:
        raise CamcalError(f"holds no image data: {size} bytes cannot hold its {width}x{height} pixels "
                          "(the image data were stripped, or the file is truncated)", path)


def check_has_data(path: Path, data: np.ndarray, black_dn: float, white_dn: float) -> tuple[int, int]:
    """Refuse a RAW frame that holds no image data (stripped or blank); give the (smallest, largest) value of
    ``data`` (DN) otherwise, measured for the check (:attr:`camcal.frame.Frame.value_range_dn`).

    Refused: every pixel 0; every pixel the same value below the white level; 99 % or more of the
    pixels below the black level (a sensor cannot read below its bias: the image data is missing, as in
    files whose data were stripped and decode to zeros). A frame with every pixel at or above the white
    level is an image (over-exposed), not a file without data: it is read, and each stage decides what
    its saturation means (:func:`saturated_fraction`; a linearity series ends there, a flat is left out).

    Raises
    ------
    CamcalError naming the file and what is wrong.
    """
    lo, hi = int(data.min()), int(data.max())
    if hi == 0:
        raise CamcalError("holds no image data: every pixel is 0 (the image data may have been stripped); "
                          "a frame of zeros is not a dark frame", path)
    if lo >= white_dn:  # fully saturated: an over-exposed image, not a file without data
        return lo, hi
    if lo == hi:
        raise CamcalError(f"holds no image data: every pixel has the same value ({lo} DN)", path)
    if black_dn > 0 and lo < black_dn and _mostly_below(data, black_dn):
        below = np.count_nonzero(data < black_dn) / data.size
        if below >= 0.99:
            raise CamcalError(f"holds no image data: {100 * below:.1f} % of the pixels are below the black level "
                              f"({black_dn:g} DN; the image data may have been stripped)", path)
    return lo, hi


def _mostly_below(data: np.ndarray, level_dn: float, chunk: int = 1 << 20) -> bool:
    """Whether 99 % or more of ``data`` may lie below ``level_dn``: False as soon as more than 1 % of the values
    are found at or above it, which in an image with data is found within the first rows (about ``chunk``
    values), instead of counting over the whole frame. True means the whole count decides.

    Row blocks of ``data`` (views: a decoded RAW image is often a strided view of a larger buffer, which
    ``reshape(-1)`` would copy whole)."""
    allowed = data.size - 0.99 * data.size  # at or above: more than this many, and fewer than 99 % are below
    rows = max(1, chunk // max(1, data[0].size)) if data.ndim > 1 else data.shape[0]
    above = 0
    for y in range(0, data.shape[0], rows):
        above += int(np.count_nonzero(data[y:y + rows] >= level_dn))
        if above > allowed:
            return False
    return True


def saturated_fraction(frame: Frame) -> float:
    """Fraction of a frame's values at or above its white level (0…1); 0 without going over the pixels when the
    largest value its reader measured is below the white level (:meth:`camcal.frame.Frame.may_reach`)."""
    white = frame.white_level_dn
    if not frame.may_reach(white):
        return 0.0
    return float(np.count_nonzero(frame.data >= white)) / max(int(frame.data.size), 1)


def _load_raw(path: Path) -> Frame:
    try:
        with quiet_stderr(), rawpy.imread(str(path)) as raw:
            sizes = raw.sizes
            _check_pixels(path, int(sizes.raw_width), int(sizes.raw_height))
            _check_size_for_pixels(path, int(sizes.raw_width), int(sizes.raw_height))
            if raw.raw_type == rawpy.RawType.Stack:
                desc = raw.color_desc.decode("ascii", "replace")
                if raw.num_colors != 3 or any(c not in desc for c in RGB):
                    raise CamcalError(f"is a linear RAW file of {_layout_name(raw)}; camcal reads linear R, G, B "
                                      "RAW and 2x2 Bayer mosaics", path)
                idx = [desc.index(c) for c in RGB]  # stack channel of R, G, B (the 4th is unused for 3 colours)
                stack = raw.raw_image_visible
                if stack.ndim != 3 or stack.shape[2] <= max(idx):
                    raise CamcalError(f"has a linear RAW image of unexpected shape {stack.shape}", path)
                data = np.ascontiguousarray(stack[..., idx], dtype=np.uint16)
                per_color = list(raw.black_level_per_channel)  # after unpacking: LibRaw may measure it then
                layout, pattern = "linear", None
                black = {c: float(per_color[i]) for c, i in zip(RGB, idx, strict=True)}
            elif raw.num_colors == 1 or (raw.raw_pattern is None and np.ndim(raw.raw_image_visible) == 2):
                # a monochrome sensor (a one-sample LinearRaw DNG): one plane Y, no colour filter array
                data = np.array(raw.raw_image_visible, dtype=np.uint16, copy=True)
                if data.ndim != 2:
                    raise CamcalError(f"has a monochrome RAW image of unexpected shape {data.shape}", path)
                per_color = list(raw.black_level_per_channel)
                layout, pattern = "mono", None
                black = {"Y": float(per_color[0])}
            else:
                if raw.num_colors != 3 or raw.raw_pattern is None or raw.raw_pattern.shape != (2, 2):
                    raise CamcalError(f"has {_layout_name(raw)}, which camcal does not read; camcal reads 2x2 "
                                      "Bayer mosaics and linear R, G, B RAW", path)
                pattern = pattern_from_rawpy(raw.raw_pattern, raw.color_desc)
                if pattern not in ("RGGB", "BGGR", "GRBG", "GBRG"):
                    raise CamcalError(f"has an unsupported CFA layout {pattern!r}", path)
                data = np.array(raw.raw_image_visible, dtype=np.uint16, copy=True)
                per_color = list(raw.black_level_per_channel)  # after unpacking: LibRaw may measure it then
                rp = np.asarray(raw.raw_pattern)
                layout = "bayer"
            white = float(raw.white_level)
            other = raw.other
            libraw = {
                "exposure_s": _clean(other.shutter_speed),
                "f_number": _clean(other.aperture),
                "iso": _clean(other.iso_speed),
                "capture_time": _libraw_time(getattr(other, "timestamp", None)),
                "focal_length_mm": _clean(getattr(other, "focal_len", None)),
            }
    except rawpy.LibRawFileUnsupportedError:
        raise CamcalError("is not a RAW file LibRaw can decode (unsupported or not an image)", path) from None
    except rawpy.LibRawError as exc:
        raise CamcalError(f"cannot decode RAW data (damaged or truncated? or its image data stripped): "
                          f"{type(exc).__name__}",
                          path) from None
    except (OSError, ValueError, MemoryError) as exc:
        raise CamcalError(f"cannot decode RAW data (damaged or truncated?): {exc}", path) from None
    if layout == "bayer":
        if data.shape[0] % 2 or data.shape[1] % 2:
            data = data[: data.shape[0] // 2 * 2, : data.shape[1] // 2 * 2]
        off = plane_offsets(pattern)
        black = {name: float(per_color[int(rp[off[name]])]) for name in PLANES}
    lo, hi = check_has_data(path, data, min(black.values()), white)
    tags = _exif_tags(path)
    exp = reconcile_libraw(exposure_from_exif(path, tags), tags, libraw)
    return Frame(
        data=data,
        kind="raw",
        cfa_pattern=pattern,
        black_level_dn=black,
        white_level_dn=white,
        exposure=exp,
        path=path,
        layout=layout,
    ).with_value_range(lo, hi)


@contextlib.contextmanager
def open_image(path: Path, formats: tuple[str, ...] | None = None, what: str = "an image"):
    """Open ``path`` with OpenImageIO and yield ``(input, spec)``, checked before any pixel is read.

    C-library messages are silenced; the format must be one of ``formats`` (OpenImageIO opens any
    format it knows whatever the file's name); the declared size must be within :func:`max_pixels`.
    """
    with quiet_stderr():  # libpng/libjpeg print their own messages to fd 2 on damaged files
        inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()
        raise CamcalError(f"cannot open as {what} (damaged, or not a supported image)", path)
    try:
        spec = inp.spec()
        fmt_name = inp.format_name()
        if formats is not None and fmt_name not in formats:
            raise CamcalError(f"is a {fmt_name} file, not {what}", path)
        _check_pixels(path, spec.width, spec.height, declared_image_bytes(spec))
        yield inp, spec
    finally:
        inp.close()


def read_pixels(inp, spec, path: Path, nchannels: int, fmt) -> np.ndarray:
    """``inp.read_image`` of the first ``nchannels`` channels, C-library chatter silenced; damage is an error."""
    with quiet_stderr():
        data = inp.read_image(0, 0, 0, nchannels, fmt)
    err = inp.geterror()
    if data is None or err:
        raise CamcalError(f"cannot decode image data (damaged or truncated?): {err.strip()[:120]}", path)
    return np.asarray(data).reshape(spec.height, spec.width, nchannels)


def _load_processed(path: Path) -> Frame:
    with open_image(path, ("jpeg", "tiff", "png"), "a JPEG, TIFF or PNG image") as (inp, spec):
        if _is_monochrome_image(inp, spec):
            return _load_monochrome(path)
        if spec.nchannels < 3:
            raise CamcalError(f"has {spec.nchannels} channel(s); camcal needs an RGB image", path)
        fmt = oiio.UINT16 if spec.format.size() > 1 else oiio.UINT8
        data = read_pixels(inp, spec, path, 3, fmt)
        bits = 16 if fmt == oiio.UINT16 else 8

        def attr(*names):
            for n in names:
                v = spec.getattribute(n)
                if v is not None:
                    return v
            return None

        oiio_exp = Exposure(
            exposure_s=_clean(attr("ExposureTime")),
            f_number=_clean(attr("FNumber")),
            iso=_clean(attr("Exif:PhotographicSensitivity", "Exif:ISOSpeedRatings")),
            focal_length_mm=_clean(attr("Exif:FocalLength", "FocalLength")),
            make=attr("Make"),
            model=attr("Model"),
            capture_time=_iso_time(attr("Exif:DateTimeOriginal")),
        )
        icc = spec.getattribute("ICCProfile")
        icc_name = icc_description(None if icc is None else np.asarray(icc, np.uint8).tobytes())
    tags = _exif_tags(path)
    exif_exp = exposure_from_exif(path, tags)
    # both read the file's EXIF; a tag exifread sees holding zero stays unknown
    oiio_exp = dataclasses.replace(
        oiio_exp,
        **{k: None for k in TRACKED if tags and _tag_present(tags, k)},
    )
    oiio_exp = dataclasses.replace(
        oiio_exp, sources=tuple(sorted((k, "tag") for k in TRACKED if getattr(oiio_exp, k) is not None))
    )
    exp = _fill(exif_exp, oiio_exp)
    exp = dataclasses.replace(exp, make=oiio_exp.make or exif_exp.make, model=oiio_exp.model or exif_exp.model)
    return _processed_frame(path, data, bits, exp, icc_name)


def read_monochrome(path: str | Path) -> np.ndarray:
    """The one channel of a monochrome 8- or 16-bit PNG or TIFF (a machine-vision camera's frame), (H, W) uint8
    or uint16, values as stored (no scaling); checked against the limits before decoding. A file with more than
    one channel is refused: its channels are not one sensor's samples."""
    path = Path(path)
    _check_file(path)
    with open_image(path, ("tiff", "png"), "a PNG or TIFF image") as (inp, spec):
        if spec.nchannels != 1:
            raise CamcalError(f"has {spec.nchannels} channels; a monochrome frame has one", path)
        if str(spec.format) in ("half", "float", "double"):
            raise CamcalError(f"holds {spec.format} samples; a monochrome frame holds integer DN", path)
        fmt = oiio.UINT16 if spec.format.size() > 1 else oiio.UINT8
        return read_pixels(inp, spec, path, 1, fmt)[..., 0]


#: TIFF PhotometricInterpretation of RAW data (a CFA mosaic, LinearRaw): a DNG named .tif is not a monochrome frame.
_RAW_TIFF_PHOTOMETRIC = (32803, 34892)


def _is_monochrome_image(inp, spec) -> bool:
    """A one-channel 16-bit PNG or TIFF of sensor values (not a RAW file's TIFF structure under another name)."""
    if spec.nchannels != 1 or spec.format.size() < 2 or inp.format_name() not in ("png", "tiff"):
        return False
    return spec.getattribute("tiff:PhotometricInterpretation") not in _RAW_TIFF_PHOTOMETRIC


def _load_monochrome(path: Path) -> Frame:
    """A one-channel 16-bit PNG or TIFF (a machine-vision camera's frame) as a monochrome RAW frame.

    The values are the sensor's DN as stored (not tone-mapped). Such a file states no black level: 0 is the
    encoded range's floor (the dark frames measure the real offset). The white level is 2^bits − 1 with the bits
    of ``bits_per_sample`` in the ``session.toml`` that applies (a 12-bit camera writing 16-bit files), else the
    file's own (``oiio:BitsPerSample``, else its sample size); a value above it is refused.
    """
    data = read_monochrome(path)
    with open_image(path, ("tiff", "png"), "a PNG or TIFF image") as (_inp, spec):
        bits = int(spec.getattribute("oiio:BitsPerSample") or 8 * spec.format.size())
    stated = session_camera_facts(path.parent).get("bits_per_sample")
    if stated is not None:
        bits = int(stated)
        if int(data.max()) >= 2**bits:
            raise CamcalError(f"holds {int(data.max())}, above the {bits}-bit range of session.toml's "
                              "bits_per_sample", path)
    tags = _exif_tags(path)
    exp = exposure_from_exif(path, tags)
    lo, hi = int(data.min()), int(data.max())
    return Frame(data=np.ascontiguousarray(data, np.uint16), kind="raw", cfa_pattern=None,
                 black_level_dn={"Y": 0.0}, white_level_dn=float(2**bits - 1), exposure=exp, path=path,
                 layout="mono", black_level_source="unknown").with_value_range(lo, hi)


def _processed_frame(path: Path, rgb: np.ndarray, bits: int, exposure: Exposure, icc_profile: str | None) -> Frame:
    """A processed (JPEG, TIFF, PNG, HEIC) frame: (H, W, 3) ``rgb`` of ``bits`` bits, black level 0, white
    level 2^bits − 1 (the encoded range; the tone curve is not undone here)."""
    return Frame(
        data=np.ascontiguousarray(rgb),
        kind="processed",
        cfa_pattern=None,
        black_level_dn={"R": 0.0, "G": 0.0, "B": 0.0},
        white_level_dn=float(2**bits - 1),
        exposure=exposure,
        path=path,
        layout="processed",
        icc_profile=icc_profile,
    )


def icc_description(icc: bytes | None) -> str | None:
    """The description of an ICC profile (its ``desc`` tag, read by Pillow's LittleCMS), e.g. ``Display P3``;
    None when there is no profile or it cannot be read."""
    if not icc:
        return None
    try:
        desc = ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(icc))).strip()
    except (OSError, ValueError, TypeError, ImageCms.PyCMSError):
        return "unreadable ICC profile"
    return desc or None


def _load_heif(path: Path) -> Frame:
    """A HEIC/HEIF photo as a processed frame: R, G, B of 8 bits (uint8) or 10/12 bits (uint16, not rescaled)."""
    try:
        with quiet_stderr():
            heif = pillow_heif.open_heif(str(path), convert_hdr_to_8bit=False)
    except (ValueError, RuntimeError, OSError, SyntaxError) as exc:
        raise CamcalError(f"cannot open as a HEIC/HEIF image (damaged, or not a supported image): {exc}",
                          path) from None
    w, h = heif.size
    bits = int(heif.info.get("bit_depth") or 8)
    mode = str(heif.mode)
    channels = 4 if mode.startswith("RGBA") else 3 if mode.startswith("RGB") else 1
    if channels < 3:
        raise CamcalError(f"has {channels} channel(s) ({mode}); camcal needs an RGB image", path)
    _check_pixels(path, w, h, float(w) * h * channels * bits / 8.0)
    try:
        with quiet_stderr():
            pixels = np.asarray(heif)
    except (ValueError, RuntimeError, OSError) as exc:
        raise CamcalError(f"cannot decode image data (damaged or truncated?): {str(exc)[:120]}", path) from None
    if pixels.ndim != 3 or pixels.shape[:2] != (h, w) or pixels.shape[2] < 3:
        raise CamcalError(f"decodes to an image of unexpected shape {pixels.shape}", path)
    if pixels.dtype == np.uint16 and bits < 16:
        data = pixels[..., :3] >> np.uint16(16 - bits)  # libheif gives the top bits
    else:
        data = pixels[..., :3]
        bits = 8 * data.dtype.itemsize
    exp = exposure_from_exif(path, _exif_from_block(heif.info.get("exif")))
    return _processed_frame(path, data, bits, exp, icc_description(heif.info.get("icc_profile")))


def is_fits(path: Path) -> bool:
    """True when the file is a FITS image (its first card ``SIMPLE  =``)."""
    return _magic(path).startswith(b"SIMPLE  =")


#: BITPIX of the FITS images camcal reads (integer data; 16 with BZERO 32768 is unsigned 16-bit).
FITS_BITPIX = (8, 16, 32)


def _fits_header(path: Path):
    """The primary header of a FITS file (astropy; nothing but the header is read), checked: a 2-D integer image
    within the pixel limit, and a file large enough for the data it declares."""
    from astropy.io import fits  # ~0.7 s to import: paid only by a session of FITS frames

    try:
        with quiet_stderr(), fits.open(path, memmap=False, lazy_load_hdus=True) as hdul:
            header = hdul[0].header.copy()
    except (OSError, ValueError, TypeError) as exc:
        raise CamcalError(f"cannot read the FITS header: {str(exc)[:120]}", path) from None
    naxis = int(header.get("NAXIS", 0))
    bitpix = int(header.get("BITPIX", 0))
    if naxis != 2:
        raise CamcalError(f"is a FITS file of {naxis} axes; camcal reads 2-D monochrome FITS images", path)
    if bitpix not in FITS_BITPIX:
        raise CamcalError(f"holds FITS BITPIX {bitpix} samples; camcal reads integer images (BITPIX 8, 16, 32)",
                          path)
    w, h = int(header.get("NAXIS1", 0)), int(header.get("NAXIS2", 0))
    _check_pixels(path, w, h, float(w) * h * abs(bitpix) / 8.0)
    if path.stat().st_size < w * h * abs(bitpix) // 8:
        raise CamcalError(f"is truncated: its header declares {w}x{h} pixels of {abs(bitpix)} bits", path)
    return header


def _fits_exposure(header) -> Exposure:
    """Exposure time (``EXPTIME`` or ``EXPOSURE``, s), capture time (``DATE-OBS``, UTC) and model (``INSTRUME``) of
    a FITS header, each marked ``tag``."""
    t = _clean(header.get("EXPTIME", header.get("EXPOSURE")))
    when = header.get("DATE-OBS")
    when = when.strip()[:19] if isinstance(when, str) and when.strip() else None
    model = header.get("INSTRUME")
    sources = [("exposure_s", "tag")] if t is not None else []
    if when is not None:  # FITS times are UTC (FITS standard 4.0 §9.1)
        sources += [("capture_time", "tag"), ("utc_offset", "tag")]
    return Exposure(exposure_s=t, capture_time=when, utc_offset=None if when is None else "+00:00",
                    model=None if model is None else str(model).strip(), sources=tuple(sorted(sources)))


def _load_fits(path: Path) -> Frame:
    """A FITS image (an astronomy camera's frame) as a monochrome RAW frame.

    Exposure time from ``EXPTIME`` (or ``EXPOSURE``), s; ``DATE-OBS`` as the capture time (UTC); make/model from
    ``INSTRUME``; the black level from ``PEDESTAL`` when present (else 0, the dark frames measure the offset); the
    white level ``2^bits − 1`` with ``bits_per_sample`` of session.toml, else the BITPIX of the file. ISO and
    f-number are not FITS keys: frames.csv or session.toml give them.
    """
    from astropy.io import fits

    header = _fits_header(path)
    try:
        with quiet_stderr(), fits.open(path, memmap=False) as hdul:
            data = np.asarray(hdul[0].data)
    except (OSError, ValueError, TypeError) as exc:
        raise CamcalError(f"cannot decode FITS data (damaged or truncated?): {str(exc)[:120]}", path) from None
    if data.ndim != 2 or not np.issubdtype(data.dtype, np.integer) and not np.all(np.mod(data, 1) == 0):
        raise CamcalError(f"decodes to {data.dtype} data of shape {data.shape}; camcal reads integer 2-D images",
                          path)
    if data.size and (data.min() < 0 or data.max() > 65535):
        raise CamcalError(f"holds values {data.min():g}..{data.max():g}, outside 0..65535 DN", path)
    bits = int(abs(int(header["BITPIX"])))
    stated = session_camera_facts(path.parent).get("bits_per_sample")
    bits = min(int(stated), 16) if stated is not None else min(bits, 16)
    if data.size and int(data.max()) >= 2**bits:
        raise CamcalError(f"holds {int(data.max())}, above the {bits}-bit range", path)
    exp = _fits_exposure(header)
    pedestal = _clean(header.get("PEDESTAL"))
    out = np.ascontiguousarray(data, np.uint16)
    return Frame(data=out, kind="raw", cfa_pattern=None, black_level_dn={"Y": float(pedestal or 0.0)},
                 white_level_dn=float(2**bits - 1), exposure=exp, path=path,
                 layout="mono", black_level_source="file" if pedestal is not None else "unknown",
                 ).with_value_range(int(out.min()), int(out.max()))


def is_raw_path(path: Path) -> bool:
    """True when the file looks like a RAW file (not JPEG/PNG/HEIF/FITS, not a plain .tif)."""
    head = _magic(path)
    if head.startswith(b"\xff\xd8\xff") or head.startswith(b"\x89PNG") or is_heif(path) or is_fits(path):
        return False
    return path.suffix.lower() not in {".tif", ".tiff", ".jpg", ".jpeg", ".png"} | HEIF_EXTENSIONS


def load_frame(
    path: str | Path,
    overrides: dict[str, float | None] | None = None,
    defaults: dict[str, float | str] | None = None,
) -> Frame:
    """Decode one image file into a :class:`~camcal.frame.Frame`.

    Parameters
    ----------
    path : file path. The format is decided from the file's first bytes, then
        its extension: JPEG, PNG and HEIF by magic; TIFF-based files go to LibRaw
        unless named ``.tif``/``.tiff``; anything else goes to LibRaw.
    overrides : exposure fields that replace the file's metadata (a manifest
        row, see :func:`camcal.io.manifest.exposure_overrides`), marked ``frames.csv``.
    defaults : session defaults (exposure fields) for the values the file does not hold,
        marked ``session``; None (default) reads ``session.toml`` beside the file or in its
        parent folder (:func:`camcal.io.manifest.session_defaults_for`); ``{}`` for none.

    Raises
    ------
    CamcalError
        Missing, empty, damaged or unsupported files, one line naming the file.
    """
    path = Path(path)
    _check_file(path)
    frame = (_load_heif(path) if is_heif(path) else _load_fits(path) if is_fits(path)
             else _load_raw(path) if is_raw_path(path) else _load_processed(path))
    if defaults is None:
        defaults = session_defaults_for(path.parent)
    exp = frame.exposure
    if defaults:
        exp = exp.filled("session", **defaults)
    if overrides:
        exp = exp.merged("frames.csv", **overrides)
    return frame if exp is frame.exposure else frame.with_exposure(exp)


@dataclasses.dataclass(frozen=True)
class FrameHeader:
    """What a file's header says without decoding its pixels (:func:`frame_header`).

    ``layout`` is None when the header does not tell it (a DNG whose image is in a sub-IFD): the file must be
    decoded to know it.
    """

    kind: str
    layout: str | None
    shape: tuple[int, int]
    make: str | None
    model: str | None


#: PhotometricInterpretation of a DNG's colour filter array and of its linear (demosaiced) RAW image.
_CFA_PHOTOMETRIC, _LINEAR_PHOTOMETRIC = "32803", "34892"


def frame_header(path: str | Path) -> FrameHeader:
    """Kind, RAW layout, size, make and model of an image file from its header, no pixel decoded.

    RAW files: LibRaw's open (sizes, before any unpacking) and the EXIF tags (make, model, and the layout when
    the main IFD holds the colour filter array or a linear RAW image; other RAW formats than DNG are Bayer
    mosaics or refused when decoded). Processed images: OpenImageIO's header (JPEG, TIFF, PNG), libheif's
    (HEIC). The size is the one :func:`load_frame` gives (a Bayer mosaic cut to even rows and columns).

    Raises
    ------
    CamcalError
        The header cannot be read (the decode would fail too, with its own message).
    """
    path = Path(path)
    _check_file(path)
    if is_heif(path):
        try:
            with quiet_stderr():
                heif = pillow_heif.open_heif(str(path), convert_hdr_to_8bit=False)
        except (ValueError, RuntimeError, OSError, SyntaxError) as exc:
            raise CamcalError(f"cannot open as a HEIC/HEIF image: {exc}", path) from None
        w, h = heif.size
        exif = exposure_from_exif(path, _exif_from_block(heif.info.get("exif")))
        return FrameHeader("processed", "processed", (int(h), int(w)), exif.make, exif.model)
    if is_fits(path):
        hdr = _fits_header(path)
        model = hdr.get("INSTRUME")
        return FrameHeader("raw", "mono", (int(hdr["NAXIS2"]), int(hdr["NAXIS1"])), None,
                           None if model is None else str(model).strip())
    tags = _exif_tags(path)
    exif = exposure_from_exif(path, tags)
    if not is_raw_path(path):
        with open_image(path, ("jpeg", "tiff", "png"), "a JPEG, TIFF or PNG image") as (_inp, spec):
            make, model = spec.getattribute("Make"), spec.getattribute("Model")
            shape = (int(spec.height), int(spec.width))
            mono = _is_monochrome_image(_inp, spec)
        if mono:  # a machine-vision camera's one-channel 16-bit frame (:func:`_load_monochrome`)
            return FrameHeader("raw", "mono", shape, make or exif.make, model or exif.model)
        return FrameHeader("processed", "processed", shape, make or exif.make, model or exif.model)
    try:
        with quiet_stderr(), rawpy.imread(str(path)) as raw:  # open only: sizes and colours need no unpacking
            sizes = raw.sizes
            h, w = int(sizes.height), int(sizes.width)
            _check_pixels(path, int(sizes.raw_width), int(sizes.raw_height))
            _check_size_for_pixels(path, int(sizes.raw_width), int(sizes.raw_height))
    except (rawpy.LibRawError, OSError, ValueError, MemoryError) as exc:
        raise CamcalError(f"cannot read the RAW header: {type(exc).__name__}", path) from None
    photometric = str(tags.get("Image PhotometricInterpretation", "")) if tags else ""
    if photometric == _CFA_PHOTOMETRIC or (tags and "Image CFARepeatPatternDim" in tags):
        layout: str | None = "bayer"
    elif photometric == _LINEAR_PHOTOMETRIC:
        samples = str(tags.get("Image SamplesPerPixel", "")) if tags else ""
        layout = "mono" if samples == "1" else "linear"  # one sample: a monochrome sensor
    elif path.suffix.lower() == ".dng":
        layout = None  # the image is in a sub-IFD: CFA or linear is known after decoding
    else:
        layout = "bayer"
    if layout == "bayer":
        h, w = h // 2 * 2, w // 2 * 2
    return FrameHeader("raw", layout, (h, w), exif.make, exif.model)


def read_photo_metadata(path: str | Path, defaults: dict[str, float | str] | None = None) -> Exposure:
    """A photo's EXIF metadata (exposure, capture time, offset, GPS), each value with its source, without
    decoding its pixels; ``session.toml`` fills what the file does not hold (``defaults`` as in
    :func:`load_frame`). RAW files: the tags an EXIF reader finds (LibRaw is not opened).

    Raises
    ------
    CamcalError
        A missing, empty or unreadable file.
    """
    path = Path(path)
    _check_file(path)
    exp = exposure_from_exif(path)
    if defaults is None:
        defaults = session_defaults_for(path.parent)
    return exp.filled("session", **defaults) if defaults else exp


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

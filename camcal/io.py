"""Reading frames: RAW through rawpy (LibRaw), JPEG/TIFF/PNG through OpenImageIO.

Exposure metadata comes from rawpy's ``other`` (RAW) or the OpenImageIO spec
(processed), then from EXIF read by exifread as a fallback, and finally from
the folder's ``frames.csv`` manifest, which overrides both.

Every failure to read a file becomes a one-line :class:`~camcal.errors.CamcalError`
naming the file.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
from fractions import Fraction
from pathlib import Path

import numpy as np

from camcal.errors import CamcalError
from camcal.frame import PLANES, Exposure, Frame, pattern_from_rawpy, plane_offsets
from camcal.limits import DEFAULT_MAX_PIXELS, check_expansion, declared_image_bytes, max_pixels  # noqa: F401
from camcal.manifest import FRAMES_CSV, exposure_overrides, read_manifest

RAW_EXTENSIONS = {
    ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".orf", ".rw2", ".raf",
    ".pef", ".srw", ".x3f", ".3fr", ".iiq", ".erf", ".kdc", ".dcr", ".mrw", ".raw", ".rwl",
}
PROCESSED_EXTENSIONS = {".jpg", ".jpeg", ".tif", ".tiff", ".png"}
IMAGE_EXTENSIONS = RAW_EXTENSIONS | PROCESSED_EXTENSIONS


def _check_pixels(path: Path, width: int, height: int, stored_bytes: float | None = None) -> None:
    """The declared size against the limits (camcal.limits); ``stored_bytes`` default: 16-bit mosaic."""
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


def _exif_tags(path: Path) -> dict[str, object]:
    """EXIF tags via exifread (header only); {} when the file has none or is damaged."""
    try:
        import logging

        import exifread

        log = logging.getLogger("exifread")  # it logs "File format not recognized." to stderr on non-EXIF files
        if log.level == logging.NOTSET:
            log.setLevel(logging.ERROR)
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


def exposure_from_exif(path: Path) -> Exposure:
    """Exposure metadata from a file's EXIF, via exifread."""
    tags = _exif_tags(path)
    if not tags:
        return Exposure()

    def num(*names):
        v = _exif_value(tags, *names)
        return _clean(v) if isinstance(v, float) else None

    def text(*names):
        v = _exif_value(tags, *names)
        return v if isinstance(v, str) else None

    when = text("EXIF DateTimeOriginal", "Image DateTime")
    temp = _exif_value(tags, "EXIF Temperature", "EXIF Tag 0x9400")
    return Exposure(
        exposure_s=num("EXIF ExposureTime", "Image ExposureTime"),
        f_number=num("EXIF FNumber", "Image FNumber"),
        iso=num("EXIF ISOSpeedRatings", "EXIF PhotographicSensitivity", "EXIF ISOSpeed", "Image ISOSpeedRatings"),
        make=text("Image Make"),
        model=text("Image Model"),
        serial=text("EXIF BodySerialNumber", "Image Tag 0xC62F", "MakerNote SerialNumber"),
        capture_time=_iso_time(when),
        temperature_c=float(temp) if isinstance(temp, float) else None,
    )


def _iso_time(exif_time: str | None) -> str | None:
    if not exif_time:
        return None
    parts = exif_time.replace(":", "-", 2).split(" ")
    return "T".join(parts) if len(parts) == 2 else exif_time


def _fill(primary: Exposure, fallback: Exposure) -> Exposure:
    """Fields of ``primary``, with gaps filled from ``fallback``."""
    import dataclasses

    return Exposure(
        **{
            f.name: getattr(primary, f.name) if getattr(primary, f.name) is not None else getattr(fallback, f.name)
            for f in dataclasses.fields(Exposure)
        }
    )


_QUIET_LOCK = threading.Lock()
_QUIET_STATE: dict[str, int] = {"depth": 0, "saved": -1, "fd": -1}


@contextlib.contextmanager
def quiet_stderr():
    """Silence C libraries (LibRaw prints decode warnings to fd 2) for the block.

    Thread-safe: fd 2 is process-wide, so concurrent blocks share one redirection
    (reference-counted); the first to enter redirects, the last to leave restores.
    """
    try:
        fd = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        yield
        return
    with _QUIET_LOCK:
        if _QUIET_STATE["depth"] == 0:
            sys.stderr.flush()
            saved = os.dup(fd)
            null = os.open(os.devnull, os.O_WRONLY)
            try:
                os.dup2(null, fd)
            finally:
                os.close(null)
            _QUIET_STATE.update(saved=saved, fd=fd)
        _QUIET_STATE["depth"] += 1
    try:
        yield
    finally:
        with _QUIET_LOCK:
            _QUIET_STATE["depth"] -= 1
            if _QUIET_STATE["depth"] == 0:
                os.dup2(_QUIET_STATE["saved"], _QUIET_STATE["fd"])
                os.close(_QUIET_STATE["saved"])
                _QUIET_STATE.update(saved=-1, fd=-1)


def _load_raw(path: Path) -> Frame:
    import rawpy

    try:
        with quiet_stderr(), rawpy.imread(str(path)) as raw:
            sizes = raw.sizes
            _check_pixels(path, int(sizes.raw_width), int(sizes.raw_height))
            if raw.num_colors != 3 or raw.raw_pattern is None or raw.raw_pattern.shape != (2, 2):
                raise CamcalError("is not a 2x2 Bayer RAW file (unsupported sensor layout)", path)
            pattern = pattern_from_rawpy(raw.raw_pattern, raw.color_desc)
            if pattern not in ("RGGB", "BGGR", "GRBG", "GBRG"):
                raise CamcalError(f"has an unsupported CFA layout {pattern!r}", path)
            mosaic = np.array(raw.raw_image_visible, dtype=np.uint16, copy=True)
            per_color = list(raw.black_level_per_channel)
            rp = np.asarray(raw.raw_pattern)
            white = float(raw.white_level)
            other = raw.other
            ts = getattr(other, "timestamp", None)
            exp = Exposure(
                exposure_s=_clean(other.shutter_speed),
                f_number=_clean(other.aperture),
                iso=_clean(other.iso_speed),
                capture_time=ts.isoformat() if hasattr(ts, "isoformat") else None,
            )
    except rawpy.LibRawFileUnsupportedError:
        raise CamcalError("is not a RAW file LibRaw can decode (unsupported or not an image)", path) from None
    except rawpy.LibRawError as exc:
        raise CamcalError(f"cannot decode RAW data (damaged or truncated?): {type(exc).__name__}", path) from None
    except (OSError, ValueError, MemoryError) as exc:
        raise CamcalError(f"cannot decode RAW data (damaged or truncated?): {exc}", path) from None
    if mosaic.shape[0] % 2 or mosaic.shape[1] % 2:
        mosaic = mosaic[: mosaic.shape[0] // 2 * 2, : mosaic.shape[1] // 2 * 2]
    off = plane_offsets(pattern)
    black = {name: float(per_color[int(rp[off[name]])]) for name in PLANES}
    return Frame(
        data=mosaic,
        kind="raw",
        cfa_pattern=pattern,
        black_level_dn=black,
        white_level_dn=white,
        exposure=_fill(exp, exposure_from_exif(path)),
        path=path,
    )


@contextlib.contextmanager
def open_image(path: Path, formats: tuple[str, ...] | None = None, what: str = "an image"):
    """Open ``path`` with OpenImageIO and yield ``(input, spec)``, checked before any pixel is read.

    C-library messages are silenced; the format must be one of ``formats`` (OpenImageIO opens any
    format it knows whatever the file's name); the declared size must be within :func:`max_pixels`.
    """
    import OpenImageIO as oiio

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
    import OpenImageIO as oiio

    with open_image(path, ("jpeg", "tiff", "png"), "a JPEG, TIFF or PNG image") as (inp, spec):
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

        exp = Exposure(
            exposure_s=_clean(attr("ExposureTime")),
            f_number=_clean(attr("FNumber")),
            iso=_clean(attr("Exif:PhotographicSensitivity", "Exif:ISOSpeedRatings")),
            make=attr("Make"),
            model=attr("Model"),
            capture_time=_iso_time(attr("Exif:DateTimeOriginal", "DateTime")),
        )
    data = np.ascontiguousarray(data)
    return Frame(
        data=data,
        kind="processed",
        cfa_pattern=None,
        black_level_dn={"R": 0.0, "G": 0.0, "B": 0.0},
        white_level_dn=float(2**bits - 1),
        exposure=_fill(exp, exposure_from_exif(path)),
        path=path,
    )


def is_raw_path(path: Path) -> bool:
    """True when the file looks like a RAW file (not JPEG/PNG, not a plain .tif)."""
    head = _magic(path)
    if head.startswith(b"\xff\xd8\xff") or head.startswith(b"\x89PNG"):
        return False
    return path.suffix.lower() not in {".tif", ".tiff", ".jpg", ".jpeg", ".png"}


def load_frame(path: str | Path, overrides: dict[str, float | None] | None = None) -> Frame:
    """Decode one image file into a :class:`~camcal.frame.Frame`.

    Parameters
    ----------
    path : file path. The format is decided from the file's first bytes, then
        its extension: JPEG and PNG by magic; TIFF-based files go to LibRaw
        unless named ``.tif``/``.tiff``; anything else goes to LibRaw.
    overrides : exposure fields that replace the file's metadata (a manifest
        row, see :func:`camcal.manifest.exposure_overrides`).

    Raises
    ------
    CamcalError
        Missing, empty, damaged or unsupported files, one line naming the file.
    """
    path = Path(path)
    _check_file(path)
    frame = _load_raw(path) if is_raw_path(path) else _load_processed(path)
    if overrides:
        import dataclasses

        frame = dataclasses.replace(frame, exposure=frame.exposure.merged(**overrides))
    return frame


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


def iter_folder(folder: str | Path):
    """Yield ``(path, frame)`` for every image of a folder, manifest applied, one at a time.

    Frames are read lazily so memory does not grow with the number of frames.
    """
    files, manifest = folder_files(folder)
    for p in files:
        yield p, load_folder_frame(p, manifest)

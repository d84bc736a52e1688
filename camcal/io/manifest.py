"""Per-folder manifests (``frames.csv``, ``sweep.csv``): a strict, forgiving CSV reader.

Forgiving about form (a UTF-8 byte-order mark, Windows line endings, blank
lines, ``#`` comments, spaces around cells, column order); strict about
content (non-numeric, NaN, infinite or negative values, duplicate rows and
paths that leave the folder are refused with the file, line and column named).

Columns of ``frames.csv``: ``file`` (required), ``exposure_s`` (s), ``iso``,
``f_number``, ``focal_length_mm`` (mm), ``temperature_C`` (degC); later stages read more columns, kept as
given. See ``docs/session-layout.md``.
"""

from __future__ import annotations

import csv
import io
import math
import re
import tomllib
from pathlib import Path

from camcal.errors import CamcalError
from camcal.io.limits import MAX_CSV_COLUMNS, MAX_MANIFEST_BYTES, MAX_TEXT_LINE_BYTES, check_text_shape

FRAMES_CSV = "frames.csv"

#: Numeric columns and whether a negative value is allowed.
NUMERIC_COLUMNS: dict[str, bool] = {
    "exposure_s": False,
    "iso": False,
    "f_number": False,
    "focal_length_mm": False,
    "temperature_C": True,
    "wavelength_nm": False,
    "radiance_W_m2_sr": False,
    "radiance_unc_W_m2_sr": False,
    "bandwidth_nm": False,
}
#: Columns that must be strictly positive when given.
POSITIVE_COLUMNS = {"exposure_s", "iso", "f_number", "focal_length_mm", "wavelength_nm", "bandwidth_nm"}

#: Physically plausible range of numeric columns (inclusive); values outside are typing errors
#: (a missing decimal point, a value in the wrong column) that would overflow or divide by zero later.
PLAUSIBLE_RANGE: dict[str, tuple[float, float]] = {
    "exposure_s": (1e-7, 1e5),
    "iso": (1.0, 1e7),
    "f_number": (0.5, 1000.0),
    "focal_length_mm": (0.1, 10000.0),
    "temperature_C": (-273.15, 500.0),
    "pixel_pitch_um": (0.1, 100.0),
    "bits_per_sample": (8.0, 16.0),
    "wavelength_nm": (100.0, 3000.0),
    "bandwidth_nm": (1e-3, 1000.0),
    "radiance_W_m2_sr": (0.0, 1e30),
    "radiance_unc_W_m2_sr": (0.0, 1e30),
}
#: Smallest non-zero value accepted in any numeric column (below it, products and ratios underflow).
TINY = 1e-30


def safe_member(folder: str | Path, name: str, manifest: str | Path | None = None) -> Path:
    """Resolve ``name`` inside ``folder``; refuse absolute paths and paths that leave it.

    Symbolic links are followed before the check, so a link pointing outside
    the folder is refused as well.
    """
    where = manifest or folder
    if not name or "\x00" in name:
        raise CamcalError("empty or invalid file name in manifest", where)
    p = Path(name)
    if p.is_absolute() or p.drive:
        raise CamcalError(f"path {name!r} is absolute; manifest paths must be relative to the folder", where)
    try:
        root = Path(folder).resolve()
        full = (root / p).resolve()
    except (OSError, RuntimeError):  # a symbolic-link loop
        raise CamcalError(f"path {name!r} is a symbolic-link loop", where) from None
    if full != root and root not in full.parents:
        raise CamcalError(f"path {name!r} leaves the session folder; refused", where)
    return full


def parse_number(text: str, column: str, where: str) -> float:
    """Parse one numeric cell; refuse NaN, inf and forbidden negatives."""
    try:
        value = float(text)
    except ValueError:
        raise CamcalError(f"{where}: column {column!r} has non-numeric value {text!r}") from None
    if not math.isfinite(value):
        raise CamcalError(f"{where}: column {column!r} has non-finite value {text!r}")
    if value < 0 and not NUMERIC_COLUMNS.get(column, True):
        raise CamcalError(f"{where}: column {column!r} is negative ({text})")
    if value == 0 and column in POSITIVE_COLUMNS:
        raise CamcalError(f"{where}: column {column!r} must be positive, got {text}")
    lo, hi = PLAUSIBLE_RANGE.get(column, (-math.inf, math.inf))
    if not lo <= value <= hi or 0 < abs(value) < TINY:
        raise CamcalError(f"{where}: column {column!r} value {text} is outside the plausible range [{lo:g}, {hi:g}]")
    return value


def read_text_file(path: str | Path, what: str, max_bytes: int = MAX_MANIFEST_BYTES, *,
                   max_line_bytes: int | None = MAX_TEXT_LINE_BYTES) -> str:
    """The UTF-8 text (BOM allowed) of a small input file, read with a bound.

    Refuses (CamcalError naming the file and ``what`` it is) a path that is not a regular file, more
    than ``max_bytes`` (a device or pipe is never read to its end: its size says nothing), more lines
    than :data:`camcal.io.limits.MAX_TEXT_LINES` or a line longer than ``max_line_bytes`` (checked on the
    bytes, before anything splits or parses them), and text that is not UTF-8.
    """
    path = Path(path)
    try:
        if not path.is_file():
            raise CamcalError(f"{what} is not a regular file" if path.exists() else "no such file", path)
        with open(path, "rb") as fh:  # bounded read: st_size is 0 for devices and pipes
            raw = fh.read(max_bytes + 1)
    except OSError as exc:
        raise CamcalError(f"cannot read {what}: {exc.strerror or exc}", path) from None
    if len(raw) > max_bytes:
        raise CamcalError(f"{what} larger than {max_bytes // 1024 // 1024} MiB; refused", path)
    check_text_shape(raw, path, what, max_line_bytes=max_line_bytes)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise CamcalError(f"{what} is not UTF-8 text", path) from None


def read_manifest(
    path: str | Path, *, required: tuple[str, ...] = ("file",)
) -> dict[str, dict[str, float | str | None]]:
    """Read a manifest CSV into ``{file name: {column: value}}``.

    Parameters
    ----------
    path : path to the CSV; file names in it are relative to its folder.
    required : columns that must be present.

    Returns
    -------
    dict keyed by the ``file`` cell as written (relative path), in file order.
    Numeric columns (see :data:`NUMERIC_COLUMNS`) are floats, empty cells None.
    """
    path = Path(path)
    text = read_text_file(path, "manifest")
    lines = [ln for ln in io.StringIO(text, newline=None).read().splitlines()]
    numbered = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not numbered:
        raise CamcalError("manifest is empty (no header row)", path)
    try:
        rows = list(csv.reader([ln for _, ln in numbered]))
    except csv.Error as exc:
        raise CamcalError(f"malformed CSV: {exc}", path) from None
    header = [h.strip() for h in rows[0]]
    if len(header) > MAX_CSV_COLUMNS:
        raise CamcalError(f"header has {len(header)} columns, above the limit of {MAX_CSV_COLUMNS}", path)
    if len(set(header)) != len(header):
        raise CamcalError(f"duplicate column names in header {header}", path)
    for col in required:
        if col not in header:
            raise CamcalError(f"missing required column {col!r} (header is {','.join(header)})", path)
    out: dict[str, dict[str, float | str | None]] = {}
    folder = path.parent
    for (lineno, _), row in zip(numbered[1:], rows[1:], strict=True):
        where = f"{path.name} line {lineno}"
        cells = [c.strip() for c in row]
        if len(cells) != len(header):
            raise CamcalError(f"{where}: {len(cells)} cells, header has {len(header)}", path)
        rec: dict[str, float | str | None] = {}
        for col, cell in zip(header, cells, strict=True):
            if cell == "":
                rec[col] = None
            elif col in NUMERIC_COLUMNS:
                rec[col] = parse_number(cell, col, where)
            else:
                rec[col] = cell
        for col in required:
            if rec.get(col) is None:
                raise CamcalError(f"{where}: required column {col!r} is empty", path)
        name = str(rec["file"])
        safe_member(folder, name, path)
        if name in out:
            raise CamcalError(f"{where}: file {name!r} is listed twice", path)
        out[name] = rec
    return out


def exposure_overrides(rec: dict[str, float | str | None] | None) -> dict[str, float | None]:
    """The exposure fields of one manifest row, as :class:`camcal.frame.Exposure` keywords."""
    if not rec:
        return {}
    return {
        "exposure_s": rec.get("exposure_s"),
        "iso": rec.get("iso"),
        "f_number": rec.get("f_number"),
        "focal_length_mm": rec.get("focal_length_mm"),
        "temperature_c": rec.get("temperature_C"),
    }


# ---- session defaults (session.toml) -------------------------------------------------------------------------

SESSION_DEFAULTS = "session.toml"
"""Name of the session defaults file: camera-wide facts given once for a whole session (or photo folder)."""

#: Keys of ``session.toml`` and the :class:`camcal.frame.Exposure` field each one fills.
SESSION_KEYS: dict[str, str] = {
    "f_number": "f_number",
    "focal_length_mm": "focal_length_mm",
    "iso": "iso",
    "exposure_s": "exposure_s",
    "temperature_C": "temperature_c",
}

SESSION_TEXT_KEYS: dict[str, str] = {"utc_offset": "utc_offset"}
"""Text keys of ``session.toml``: ``utc_offset``, the camera clock's offset from UTC as ``"+HH:MM"``
(local time = UTC + offset), used to place a photo in time when its file holds no GPS time and no
OffsetTimeOriginal (see docs/conventions.md, "Time and the sun")."""

#: Keys of ``session.toml`` that state facts of the camera rather than of each frame (not Exposure fields):
#: ``pixel_pitch_um``, the pixel pitch in µm (the quantum efficiency of :mod:`camcal.calibrate.emva` needs the pixel
#area); : ``bits_per_sample``, the bit depth of a monochrome camera whose 16-bit PNG/TIFF frames hold fewer bits (a
#12-bit : machine-vision camera: its white level is 2^bits − 1).
CAMERA_KEYS: tuple[str, ...] = ("pixel_pitch_um", "bits_per_sample")

MAX_SESSION_DEFAULTS_BYTES = 64 * 1024

_DEFAULTS_CACHE: dict[tuple[str, int, int], tuple[dict[str, float | str], dict[str, float]]] = {}



def _read_session_toml(path: Path) -> tuple[dict[str, float | str], dict[str, float]]:
    """(Exposure keywords, camera facts) of a ``session.toml``."""
    text = read_text_file(path, "session defaults file", MAX_SESSION_DEFAULTS_BYTES)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CamcalError(f"is not valid TOML: {exc}", path) from None
    out: dict[str, float | str] = {}
    camera: dict[str, float] = {}
    for key, value in doc.items():
        if key in SESSION_TEXT_KEYS:
            if not isinstance(value, str) or parse_utc_offset(value) is None:
                raise CamcalError(f"key {key!r} must be an offset from UTC as text \"+HH:MM\" between -12:00 "
                                  f"and +14:00 (e.g. utc_offset = \"+02:00\"), got {value!r}", path)
            out[SESSION_TEXT_KEYS[key]] = value.strip()
            continue
        if key not in SESSION_KEYS and key not in CAMERA_KEYS:
            known = ", ".join([*SESSION_KEYS, *SESSION_TEXT_KEYS, *CAMERA_KEYS])
            raise CamcalError(f"unknown key {key!r} (known: {known})", path)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CamcalError(f"key {key!r} must be a number, got {value!r}", path)
        v = float(value)
        lo, hi = PLAUSIBLE_RANGE[key]
        if not math.isfinite(v):
            raise CamcalError(f"key {key!r} is not finite ({value})", path)
        if key in POSITIVE_COLUMNS and v <= 0:
            raise CamcalError(f"key {key!r} must be positive, got {value}", path)
        if not lo <= v <= hi:
            raise CamcalError(f"key {key!r} value {value} is outside the plausible range [{lo:g}, {hi:g}]", path)
        if key in CAMERA_KEYS:
            camera[key] = v
        else:
            out[SESSION_KEYS[key]] = v
    return out, camera


def parse_utc_offset(text: str) -> int | None:
    """Minutes east of UTC of an offset written ``+HH:MM`` / ``-HH:MM`` (Exif OffsetTimeOriginal, ``utc_offset``
    of ``session.toml``) or ``Z``; None when malformed or outside the time zones in use (−12:00 … +14:00)."""
    if text.strip() in ("Z", "z"):
        return 0
    m = re.fullmatch(r"([+-])(\d{2}):(\d{2})", text.strip())
    if not m or int(m.group(3)) >= 60:
        return None
    minutes = (int(m.group(2)) * 60 + int(m.group(3))) * (-1 if m.group(1) == "-" else 1)
    return minutes if -12 * 60 <= minutes <= 14 * 60 else None


def find_session_defaults(folder: str | Path) -> Path | None:
    """The ``session.toml`` that applies to the frames of ``folder``: in the folder itself, else in its
    parent (the session root of a stage folder); None when there is none."""
    folder = Path(folder)
    for d in (folder, folder.parent):
        p = d / SESSION_DEFAULTS
        if p.exists():
            return p
    return None


def _session_toml_for(folder: str | Path) -> tuple[dict[str, float | str], dict[str, float]]:
    p = find_session_defaults(folder)
    if p is None:
        return {}, {}
    try:
        st = p.stat()
    except OSError as exc:
        raise CamcalError(f"cannot read session defaults file: {exc.strerror}", p) from None
    key = (str(p.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _DEFAULTS_CACHE:
        _DEFAULTS_CACHE[key] = _read_session_toml(p)
    return _DEFAULTS_CACHE[key]


def session_defaults_for(folder: str | Path) -> dict[str, float | str]:
    """The exposure keywords of :func:`find_session_defaults`'s ``session.toml`` (``{}`` when none), cached by
    file identity (path, size, modification time)."""
    return dict(_session_toml_for(folder)[0])


def session_camera_facts(folder: str | Path) -> dict[str, float]:
    """The camera facts (:data:`CAMERA_KEYS`, e.g. ``{"pixel_pitch_um": 3.45}``) of the ``session.toml`` that
    applies to ``folder`` (:func:`find_session_defaults`); ``{}`` when none."""
    return dict(_session_toml_for(folder)[1])

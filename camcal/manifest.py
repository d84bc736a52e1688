"""Per-folder manifests (``frames.csv``, ``sweep.csv``): a strict, forgiving CSV reader.

Forgiving about form (a UTF-8 byte-order mark, Windows line endings, blank
lines, ``#`` comments, spaces around cells, column order); strict about
content (non-numeric, NaN, infinite or negative values, duplicate rows and
paths that leave the folder are refused with the file, line and column named).

Columns of ``frames.csv``: ``file`` (required), ``exposure_s`` (s), ``iso``,
``f_number``, ``temperature_C`` (degC); later stages read more columns, kept as
given. See ``docs/session-layout.md``.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

from camcal.errors import CamcalError

FRAMES_CSV = "frames.csv"

#: Numeric columns and whether a negative value is allowed.
NUMERIC_COLUMNS: dict[str, bool] = {
    "exposure_s": False,
    "iso": False,
    "f_number": False,
    "temperature_C": True,
    "wavelength_nm": False,
    "radiance_W_m2_sr": False,
    "radiance_unc_W_m2_sr": False,
    "bandwidth_nm": False,
}
#: Columns that must be strictly positive when given.
POSITIVE_COLUMNS = {"exposure_s", "iso", "f_number", "wavelength_nm", "bandwidth_nm"}

MAX_MANIFEST_BYTES = 16 * 1024 * 1024


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
    root = Path(folder).resolve()
    full = (root / p).resolve()
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
    return value


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
    try:
        if path.stat().st_size > MAX_MANIFEST_BYTES:
            raise CamcalError("manifest larger than 16 MiB; refused", path)
        raw = path.read_bytes()
    except OSError as exc:
        raise CamcalError(f"cannot read manifest: {exc.strerror or exc}", path) from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise CamcalError("manifest is not UTF-8 text", path) from None
    lines = [ln for ln in io.StringIO(text, newline=None).read().splitlines()]
    numbered = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not numbered:
        raise CamcalError("manifest is empty (no header row)", path)
    try:
        rows = list(csv.reader([ln for _, ln in numbered]))
    except csv.Error as exc:
        raise CamcalError(f"malformed CSV: {exc}", path) from None
    header = [h.strip() for h in rows[0]]
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
        "temperature_c": rec.get("temperature_C"),
    }

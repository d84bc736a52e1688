"""Spectral-sensitivity curves in files: SPECTACLE's CSV both ways, plain tables, resampling.

SPECTACLE (Burggraaff et al. 2019) writes a camera's spectral response with::

    np.savetxt(path, data, delimiter=",", header="Wavelength, R, G, B, G2, R_err, G_err, B_err, G2_err")

(``data`` of shape (n, 9); numpy's defaults ``fmt="%.18e"`` and ``comments="# "``), so the file is one
line ``# Wavelength, R, G, B, G2, R_err, G_err, B_err, G2_err`` and then numbers only. It reads them back
with ``np.loadtxt(path, delimiter=",").T`` (``spectacle.spectral.load_spectral_response``): row 0 the
wavelengths in nm, rows 1–4 R, G, B, G2, rows 5–8 their uncertainties. :func:`write_spectacle_csv`
makes exactly that file (camcal's own metadata goes to ``<stem>.meta.json`` beside it, which SPECTACLE
never opens) and :func:`read_spectacle_csv` reads it (and camcal's older CSVs, whose first line
was a header row without ``#``).

:func:`read_curve_table` reads the plain layouts: a CSV with a header
``wavelength_nm,R,G,B[,R_unc,G_unc,B_unc]`` (``G1,G2`` instead of ``G`` allowed), or whitespace-separated
columns ``wavelength R G B`` with or without a header (the open measurement sets such as
ilia3101/SpectralMeasurements ``response.dat``). :func:`read_spectral_file` picks the reader.

All curves read this way are ``relative`` unless the caller says they are absolute
(:func:`as_absolute`), or camcal's ``.meta.json`` beside a SPECTACLE file says so.

References
----------
Burggraaff, O. et al. (2019). Standardized spectral and radiometric calibration of consumer cameras.
Optics Express 27(14), 19075 (SPECTACLE).
"""

from __future__ import annotations

import dataclasses
import io
import json
import re
from pathlib import Path
from typing import Any, Literal

import numpy as np

from camcal.errors import CamcalError
from camcal.frame import PLANES
from camcal.io.atomic import atomic_write_text
from camcal.io.manifest import read_text_file
from camcal.io.store import to_jsonable
from camcal.models.spectral import (
    ABSOLUTE_UNITS,
    RELATIVE_UNITS,
    SpectralSensitivity,
)

#: SPECTACLE's columns, in its order (G is the first green plane, G1 in camcal).
SPECTACLE_COLUMNS = ("Wavelength", "R", "G", "B", "G2", "R_err", "G_err", "B_err", "G2_err")
#: The header SPECTACLE's writer passes to ``np.savetxt`` (numpy prefixes ``"# "``).
SPECTACLE_HEADER = ", ".join(SPECTACLE_COLUMNS)
#: numpy's default ``np.savetxt`` format, which SPECTACLE's writer uses.
SPECTACLE_FMT = "%.18e"
MAX_CURVE_BYTES = 16 * 1024 * 1024

FileFormat = Literal["auto", "spectacle", "plain"]

_WAVELENGTH_NAMES = {"wavelength", "wavelength_nm", "wavelengths", "lambda", "lambda_nm", "wl", "wl_nm", "nm"}
_UNC_SUFFIXES = ("_err", "_unc", "_u", "_sigma", "_std")


def meta_path(path: str | Path) -> Path:
    """``<stem>.meta.json`` beside a curve file: camcal's metadata, which SPECTACLE does not read."""
    path = Path(path)
    return path.with_name(path.stem + ".meta.json")


# ---- SPECTACLE out ---------------------------------------------------------------------------------------
def spectacle_array(s: SpectralSensitivity) -> np.ndarray:
    """(n, 9) array in SPECTACLE's column order (G = G1, G2 = G2)."""
    v, u = s.values, s.uncertainty
    return np.column_stack([s.wavelength_nm, v["R"], v["G1"], v["B"], v["G2"], u["R"], u["G1"], u["B"], u["G2"]])


def write_spectacle_csv(s: SpectralSensitivity, path: str | Path) -> Path:
    """Write ``s`` exactly as SPECTACLE's writer does, plus ``<stem>.meta.json`` beside it.

    The CSV is ``np.savetxt(path, data, delimiter=",", header=SPECTACLE_HEADER)`` with numpy's default
    ``%.18e`` (every float64 round-trips exactly) and ``# `` comment prefix, so SPECTACLE's
    ``np.loadtxt(path, delimiter=",")`` reads it. camcal's metadata (mode, units, reference setting,
    bandwidth, source, summary) goes to the JSON file. Both are written atomically.
    """
    path = Path(path)
    buf = io.StringIO()
    np.savetxt(buf, spectacle_array(s), fmt=SPECTACLE_FMT, delimiter=",", header=SPECTACLE_HEADER)
    meta = {"kind": "camcal.spectral", "mode": s.mode, "units": s.units, "reference_iso": s.reference_iso,
            "reference_f_number": s.reference_f_number, "bandwidth_nm": s.bandwidth_nm,
            "deconvolved": s.deconvolved, "n_frames": s.n_frames, "notes": list(s.notes), "source": s.source,
            "summary": s.summary()}
    atomic_write_text(meta_path(path), json.dumps(to_jsonable(meta), indent=1, allow_nan=False))
    atomic_write_text(path, buf.getvalue())
    return path


# ---- reading tables ---------------------------------------------------------------------------------------
def read_numeric_table(path: Path) -> tuple[list[str] | None, np.ndarray, str]:
    """Numbers of a delimited text table and its column names when it names them.

    Names come from the last ``#`` comment line before the numbers (SPECTACLE's header) or from a first
    non-comment line that is not numeric. The delimiter is a comma when the first data line has one,
    else whitespace. Returns (names or None, (n, m) float array, delimiter description).
    """
    text = read_text_file(path, "spectral curve file", MAX_CURVE_BYTES)
    comment_names: list[str] | None = None
    header: list[str] | None = None
    rows: list[list[float]] = []
    delim: str | None = None
    for lineno, raw in enumerate(io.StringIO(text, newline=None).read().splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            if not rows and header is None:
                body = line.lstrip("#").strip()
                cells = [c.strip() for c in re.split(r"[,\s]+", body) if c.strip()]
                if cells and any(re.search(r"[A-Za-z]", c) for c in cells):
                    comment_names = cells
            continue
        if delim is None:
            delim = "," if "," in line else "whitespace"
        cells = [c.strip() for c in (line.split(",") if delim == "," else line.split())]
        try:
            nums = [float(c) for c in cells]
        except ValueError:
            if not rows and header is None and any(re.search(r"[A-Za-z]", c) for c in cells):
                header = cells
                continue
            raise CamcalError(f"line {lineno}: non-numeric cell in {cells[:9]}", path) from None
        if rows and len(nums) != len(rows[0]):
            raise CamcalError(f"line {lineno}: {len(nums)} columns, earlier rows have {len(rows[0])}", path)
        rows.append(nums)
    if not rows:
        raise CamcalError("holds no rows of numbers", path)
    data = np.asarray(rows, float)
    if not np.all(np.isfinite(data)):
        raise CamcalError("holds a NaN or infinite value", path)
    names = header if header is not None else comment_names
    if names is not None and len(names) != data.shape[1]:
        raise CamcalError(f"header names {len(names)} columns ({', '.join(names)}), the rows have "
                          f"{data.shape[1]}", path)
    return names, data, "comma" if delim == "," else "whitespace"


def _columns_by_name(names: list[str], data: np.ndarray, path: Path) -> dict[str, np.ndarray]:
    """Map named columns to ``wavelength``, ``R, G1, G2, B`` and their ``*_unc``."""
    out: dict[str, np.ndarray] = {}
    for i, raw in enumerate(names):
        key = raw.strip().strip('"').strip()
        low = key.lower()
        if low in _WAVELENGTH_NAMES:
            out["wavelength"] = data[:, i]
            continue
        base, unc = key, False
        for suf in _UNC_SUFFIXES:
            if low.endswith(suf):
                base, unc = key[: -len(suf)], True
                break
        if base.lower().startswith("u_"):
            base, unc = base[2:], True
        plane = {"r": "R", "g": "G1", "g1": "G1", "g2": "G2", "b": "B"}.get(base.lower())
        if plane is None:
            raise CamcalError(f"unknown column {key!r}; expected wavelength_nm, R, G (or G1, G2), B and "
                              f"optional R_unc, G_unc, B_unc (or SPECTACLE's *_err)", path)
        out[plane + ("_unc" if unc else "")] = data[:, i]
    for need in ("wavelength", "R", "G1", "B"):
        if need not in out:
            shown = "G" if need == "G1" else need
            raise CamcalError(f"missing column {shown!r} (columns are {', '.join(names)})", path)
    return out


def _columns_by_position(data: np.ndarray, path: Path, what: str) -> dict[str, np.ndarray]:
    m = data.shape[1]
    if m == 9:
        cols = ["wavelength", "R", "G1", "B", "G2", "R_unc", "G1_unc", "B_unc", "G2_unc"]
    elif m == 4:
        cols = ["wavelength", "R", "G1", "B"]
    elif m == 7:
        cols = ["wavelength", "R", "G1", "B", "R_unc", "G1_unc", "B_unc"]
    else:
        raise CamcalError(f"has {m} unnamed columns; {what} needs 9 (SPECTACLE: Wavelength, R, G, B, G2, R_err, "
                          "G_err, B_err, G2_err), 4 (wavelength R G B) or 7 (with R_unc G_unc B_unc)", path)
    return {c: data[:, i] for i, c in enumerate(cols)}


def _positive_or_none(v: Any) -> float | None:
    """A reference ISO or f-number from a file's metadata: None when the file does not hold a positive number."""
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if x > 0 else None


def _sensitivity(cols: dict[str, np.ndarray], path: Path, notes: list[str],
                 meta: dict[str, Any] | None = None) -> SpectralSensitivity:
    wl = cols["wavelength"]
    order = np.argsort(wl, kind="stable")
    if np.any(np.diff(wl[order]) <= 0):
        raise CamcalError("lists a wavelength twice", path)
    if wl[order][0] <= 0:
        raise CamcalError("has a non-positive wavelength (the first column must be the wavelength in nm)", path)
    zero = np.zeros_like(wl)
    g2 = cols.get("G2", cols["G1"])
    if "G2" not in cols:
        notes.append("one green curve in the file: used for both G1 and G2")
    values = {"R": cols["R"], "G1": cols["G1"], "G2": g2, "B": cols["B"]}
    has_unc = any(k.endswith("_unc") for k in cols)
    if not has_unc:
        notes.append("the file gives no uncertainties: u(c) = 0 (unknown, not zero)")
    unc = {"R": cols.get("R_unc", zero), "G1": cols.get("G1_unc", zero),
           "G2": cols.get("G2_unc", cols.get("G1_unc", zero)), "B": cols.get("B_unc", zero)}
    if any(np.any(u < 0) for u in unc.values()):
        raise CamcalError("has a negative uncertainty", path)
    meta = meta or {}
    mode = "absolute" if meta.get("mode") == "absolute" else "relative"
    if mode == "absolute" and (_positive_or_none(meta.get("reference_iso")) is None
                               or _positive_or_none(meta.get("reference_f_number")) is None):
        raise CamcalError("its metadata says absolute but gives no reference_iso and reference_f_number (the "
                          "setting the values refer to)", path)
    return SpectralSensitivity(
        wavelength_nm=wl[order],
        values={p: values[p][order] for p in PLANES},
        uncertainty={p: unc[p][order] for p in PLANES},
        units=str(meta.get("units") or (ABSOLUTE_UNITS if mode == "absolute" else RELATIVE_UNITS)),
        mode=mode,  # type: ignore[arg-type]
        reference_iso=_positive_or_none(meta.get("reference_iso")),
        reference_f_number=_positive_or_none(meta.get("reference_f_number")),
        bandwidth_nm=None if meta.get("bandwidth_nm") is None else float(meta["bandwidth_nm"]),
        deconvolved=bool(meta.get("deconvolved", False)),
        n_frames=dict(meta.get("n_frames") or {}),
        notes=tuple([*(str(n) for n in meta.get("notes") or ()), *notes]),
        source=meta.get("source") if isinstance(meta.get("source"), dict) else None,
    )


def _read_meta(path: Path) -> dict[str, Any]:
    mp = meta_path(path)
    if not mp.is_file():
        return {}
    try:
        meta = json.loads(read_text_file(mp, "spectral metadata"))
    except ValueError as exc:
        raise CamcalError(f"invalid metadata file: {exc}", mp) from None
    if not isinstance(meta, dict):
        raise CamcalError("invalid metadata file: not a JSON object", mp)
    return meta


def read_spectacle_csv(path: str | Path) -> SpectralSensitivity:
    """Read a SPECTACLE spectral-response CSV (and camcal's ``<stem>.meta.json`` when present).

    Accepts what ``np.loadtxt(path, delimiter=",")`` accepts for a (n, 9) table in SPECTACLE's column
    order (``#`` lines ignored), and the named header row of camcal's older CSVs. Without
    the metadata file the result is ``relative`` with unknown bandwidth.
    """
    path = Path(path)
    names, data, delim = read_numeric_table(path)
    if delim != "comma":
        raise CamcalError("is not comma-separated; SPECTACLE's files are (use the plain reader for .dat)", path)
    if names is not None:
        cols = _columns_by_name(names, data, path)
    else:
        if data.shape[1] != len(SPECTACLE_COLUMNS):
            raise CamcalError(f"has {data.shape[1]} columns; SPECTACLE's layout has 9 ({SPECTACLE_HEADER})", path)
        cols = _columns_by_position(data, path, "SPECTACLE's layout")
    return _sensitivity(cols, path, [], _read_meta(path))


def read_curve_table(path: str | Path) -> SpectralSensitivity:
    """Read a plain curve table: CSV ``wavelength_nm,R,G,B[,R_unc,G_unc,B_unc]`` or whitespace columns.

    A header row (or ``#`` comment line) naming the columns is optional; without one the columns are
    taken by position: ``wavelength R G B`` (4), with ``R_unc G_unc B_unc`` (7), or SPECTACLE's 9. The
    space-separated ``response.dat`` files of open measurement sets (``wavelength R G B``) read as they
    are. The result is ``relative``.
    """
    path = Path(path)
    names, data, _ = read_numeric_table(path)
    cols = _columns_by_name(names, data, path) if names is not None else _columns_by_position(
        data, path, "a plain curve table")
    return _sensitivity(cols, path, [])


def read_spectral_file(path: str | Path, fmt: FileFormat = "auto") -> tuple[SpectralSensitivity, str]:
    """Read curves with the reader ``fmt`` names; ``auto`` picks it. Returns (curves, format used).

    ``auto``: a comma-separated file whose names (or column count, 9) match SPECTACLE's layout is read
    as SPECTACLE; anything else with the plain reader.
    """
    path = Path(path)
    if fmt == "spectacle":
        return read_spectacle_csv(path), "spectacle"
    if fmt == "plain":
        return read_curve_table(path), "plain"
    if fmt != "auto":
        raise CamcalError(f"unknown curve file format {fmt!r}; use auto, spectacle or plain")
    names, data, delim = read_numeric_table(path)
    spectacle = delim == "comma" and (
        (names is not None and [n.strip() for n in names] == list(SPECTACLE_COLUMNS))
        or (names is None and data.shape[1] == len(SPECTACLE_COLUMNS)))
    if spectacle:
        return read_spectacle_csv(path), "spectacle"
    return read_curve_table(path), "plain"


# ---- shaping --------------------------------------------------------------------------------------------
def resample(s: SpectralSensitivity, grid_nm: np.ndarray) -> tuple[SpectralSensitivity, list[str]]:
    """``s`` linearly interpolated onto the part of ``grid_nm`` inside its wavelength range.

    Points of the grid outside the curve's range are left out (c(λ) there is unknown, not zero); a note
    says so. Uncertainties are interpolated the same way.
    """
    grid = np.asarray(grid_nm, float)
    lo, hi = float(s.wavelength_nm[0]), float(s.wavelength_nm[-1])
    inside = grid[(grid >= lo - 1e-9) & (grid <= hi + 1e-9)]
    notes = []
    if inside.size < 2:
        raise CamcalError(f"the curves ({lo:g}–{hi:g} nm) and the profile's wavelength grid "
                          f"({grid[0]:g}–{grid[-1]:g} nm) share fewer than 2 wavelengths")
    if inside.size < grid.size:
        notes.append(f"{grid.size - inside.size} wavelengths of the profile's grid lie outside the curves' "
                     f"{lo:g}–{hi:g} nm and were left out")
    same = inside.size == s.wavelength_nm.size and np.allclose(inside, s.wavelength_nm)
    if same:
        return s, notes
    wl = s.wavelength_nm
    return dataclasses.replace(
        s, wavelength_nm=inside,
        values={p: np.interp(inside, wl, s.values[p]) for p in s.plane_names},
        uncertainty={p: np.interp(inside, wl, s.uncertainty[p]) for p in s.plane_names},
        notes=(*s.notes, *notes)), notes


def as_absolute(s: SpectralSensitivity, reference_iso: float, reference_f_number: float) -> SpectralSensitivity:
    """Declare curves absolute: DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm at (ISO_ref, N_ref), on axis."""
    if not (reference_iso > 0 and reference_f_number > 0):
        raise CamcalError("absolute curves need a positive reference ISO and f-number")
    return dataclasses.replace(s, mode="absolute", units=ABSOLUTE_UNITS, reference_iso=float(reference_iso),
                               reference_f_number=float(reference_f_number))

"""A monochromator sweep measured elsewhere: per-step channel means, not frames.

Laboratories publish the reduced readings of a sweep rather than its frames: for every step the camera's
channel means with the light off (dark) and on (lit), the reference detector's readings likewise, and the
detector's spectral responsivity. This module reads two layouts and reduces them with the sweep's own
maths (seed §3.1, c(λ) = d(λ) / (r(λ)·t(λ)); here the exposure is the same at every step and the reference
radiance is relative, so c is relative):

    d_k = lit_k − dark_k                        camera signal of step k, DN, per channel
    r_k = (ref_lit_k − ref_dark_k) / R(λ_k)     reference radiance (detector signal / its responsivity)
    c(λ_k) = d_k / r_k

``dark_k`` is the mean of the dark readings taken just before and just after the lit one (the one before
when none follows): a drifting dark level is interpolated, not taken from one side. R(λ) is linearly
interpolated. Negative values of d (noise where the camera sees nothing) are kept, not clipped.

The publisher of the open data set in ``../shared/realdata/sweeps`` (ilia3101/SpectralMeasurements,
``process_data.c``) reduces differently in two details: the camera's dark is the reading *before* only and
negative camera signals are clipped to 0. :func:`reduce_sweep` with ``method="publisher"`` does exactly
that (it reproduces their ``response.dat`` to its 6 printed decimals); the default ``"camcal"`` differs from
it by at most 5.5e-4 of the peak on both open cameras (tests/curves/test_published_sweeps.py, docs/spectral.md).

Uncertainty, from the repeats:

- several lit readings at one wavelength (rows of the CSV layout): c is their mean, u(c) the standard error
  of the mean of the per-reading c, but never below what the dark repeats predict for that mean (below: a
  few repeats may scatter little by chance);
- one reading per wavelength (the open data): the readings' noise is estimated from the repeated dark
  readings over the whole sweep: σ = 1.4826·MAD(successive differences)/√2 per channel and for the
  reference (at least 1/√12 count for integer counter readings: their quantisation), u(d)² = σ²(1 + 1/n_dark)
  and likewise u(r); u(c)² = (u(d)/e)² + (c·u(r)/r)² with e = r/R. A lit reading noisier than a dark one (photon
  noise) is not seen this way: the note in the result says the uncertainty is a lower bound then.

Layouts:

- **plain CSV** (:func:`read_means_csv`): header ``wavelength_nm,state,R,G,B,reference`` (or ``G1,G2``
  instead of ``G``), one row per reading in the order taken, ``state`` ``dark`` or ``lit``; a dark row's
  wavelength is not used (may be empty). Lines starting with ``#`` are comments.
- **the open data's layout** (:func:`read_open_sweep`): ``<name>_info.txt`` (line 5 the first wavelength and
  line 6 the step, both in tenths of a nm; line 4 the responsivity file, of which only the base name is used,
  looked up beside the info file), ``<name>_camera.dat`` (rows alternate dark, lit, …; columns R,
  mean(G1, G2), B in raw DN) and ``<name>_diode.dat`` (the detector's counts, alternating the same way).

The responsivity file is ``wavelength_nm, responsivity`` (comma or whitespace separated, any unit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from camcal.curves.files import read_numeric_table
from camcal.errors import CamcalError
from camcal.frame import RGB
from camcal.io.hashing import sha256_file
from camcal.io.manifest import read_text_file, safe_member
from camcal.models.spectral import RELATIVE_UNITS, SpectralSensitivity

Method = Literal["camcal", "publisher"]
#: Robust σ from the MAD of a normal sample.
MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class SweepReadings:
    """Readings of a sweep in the order taken.

    state : (N,) ``"dark"`` or ``"lit"``.
    wavelength_nm : (N,) nm (NaN for dark rows when unknown).
    camera_dn : (N, C) channel means, DN (black level included or not: darks remove it).
    reference : (N,) reference detector readings (counts, A, V: any unit).
    channels : names of the C camera columns (R, G, B or R, G1, G2, B).
    responsivity_nm, responsivity : the reference detector's spectral responsivity (any unit).
    files : ``{"file", "sha256"}`` of the files read.
    """

    state: np.ndarray
    wavelength_nm: np.ndarray
    camera_dn: np.ndarray
    reference: np.ndarray
    channels: tuple[str, ...]
    responsivity_nm: np.ndarray
    responsivity: np.ndarray
    files: tuple[dict, ...] = ()
    name: str = ""


@dataclass(frozen=True)
class SweepReduction:
    """c(λ) from sweep readings.

    wavelength_nm : (n,) nm. response : dict channel -> (n,) c in the publisher's units (camera DN per
    reference signal per responsivity unit). uncertainty : same, standard uncertainty. n_readings : (n,)
    lit readings per wavelength. notes : how it was reduced.
    """

    wavelength_nm: np.ndarray
    response: dict[str, np.ndarray]
    uncertainty: dict[str, np.ndarray]
    n_readings: np.ndarray
    method: str
    notes: tuple[str, ...]

    def to_sensitivity(self, source: dict | None = None) -> SpectralSensitivity:
        """Relative :class:`SpectralSensitivity` (divided by the largest value over all channels)."""
        peak = max(float(np.max(v)) for v in self.response.values())
        if not peak > 0:
            raise CamcalError("the sweep's readings give no positive response")
        return SpectralSensitivity(
            wavelength_nm=self.wavelength_nm, values={k: v / peak for k, v in self.response.items()},
            uncertainty={k: u / peak for k, u in self.uncertainty.items()}, units=RELATIVE_UNITS, mode="relative",
            n_frames={f"{w:g}": int(n) for w, n in zip(self.wavelength_nm, self.n_readings, strict=True)},
            notes=self.notes, source=source)


# ---- readers ---------------------------------------------------------------------------------------------------
def read_responsivity(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``wavelength_nm, responsivity`` (two columns, increasing wavelengths, responsivity ≥ 0)."""
    path = Path(path)
    _, data, _ = read_numeric_table(path)
    if data.shape[1] != 2 or data.shape[0] < 2:
        raise CamcalError(f"responsivity file must have 2 columns (wavelength_nm, responsivity) and 2 rows or more, "
                          f"has {data.shape[1]} columns", path)
    if np.any(np.diff(data[:, 0]) <= 0):
        raise CamcalError("responsivity wavelengths must increase", path)
    if np.any(data[:, 1] < 0):
        raise CamcalError("holds a negative responsivity", path)
    return data[:, 0], data[:, 1]


def _numbers(path: Path, what: str, columns: int) -> np.ndarray:
    _, data, _ = read_numeric_table(path)
    if data.shape[1] != columns:
        raise CamcalError(f"{what} must have {columns} column{'s' if columns > 1 else ''}, has {data.shape[1]}", path)
    return data


def _record(path: Path) -> dict:
    return {"file": path.name, "sha256": sha256_file(path)}


def read_open_sweep(info: str | Path, responsivity: str | Path | None = None) -> SweepReadings:
    """The open data's layout: ``<name>_info.txt``, ``_camera.dat``, ``_diode.dat`` (module docstring).

    ``responsivity``: the detector's responsivity file; default the base name of info line 4, beside the
    info file.
    """
    info = Path(info)
    lines = [ln.strip() for ln in read_text_file(info, "sweep info file", 64 * 1024).splitlines()]
    if len(lines) < 6:
        raise CamcalError(f"sweep info file has {len(lines)} lines; line 5 (start) and 6 (step, tenths of a nm) "
                          "are needed", info)
    try:
        start, step = int(lines[4]) / 10.0, int(lines[5]) / 10.0
    except ValueError:
        raise CamcalError(f"sweep info file: lines 5 and 6 must be whole tenths of a nm, got {lines[4]!r}, "
                          f"{lines[5]!r}", info) from None
    if not (100.0 <= start <= 3000.0 and 0.0 < step <= 100.0):
        raise CamcalError(f"sweep info file: start {start:g} nm or step {step:g} nm is implausible", info)
    stem = info.name[: -len("_info.txt")] if info.name.endswith("_info.txt") else info.stem
    cam_path = info.with_name(f"{stem}_camera.dat")
    dio_path = info.with_name(f"{stem}_diode.dat")
    cam = _numbers(cam_path, "camera readings", 3)
    dio = _numbers(dio_path, "diode readings", 1)[:, 0]
    if cam.shape[0] < 2:
        raise CamcalError("holds fewer than one dark and one lit reading", cam_path)
    if dio.shape[0] != cam.shape[0]:
        raise CamcalError(f"has {dio.shape[0]} readings, the camera file {cam.shape[0]}: they must alternate "
                          "together", dio_path)
    if responsivity is None:
        if not lines[3]:
            raise CamcalError("sweep info file names no responsivity file on line 4; give one", info)
        responsivity = safe_member(info.parent, Path(lines[3].replace("\\", "/")).name, info)
    resp_path = Path(responsivity)
    rwl, rr = read_responsivity(resp_path)
    n = cam.shape[0]
    state = np.array(["dark" if k % 2 == 0 else "lit" for k in range(n)])
    wl = np.full(n, np.nan)
    lit = np.arange(1, n, 2)
    wl[lit] = start + step * np.arange(lit.size)
    return SweepReadings(state, wl, cam, dio, RGB, rwl, rr,
                         tuple(_record(p) for p in (info, cam_path, dio_path, resp_path)), stem)


def read_means_csv(path: str | Path, responsivity: str | Path) -> SweepReadings:
    """The plain CSV layout ``wavelength_nm,state,R,G,B,reference`` (or ``G1,G2``; module docstring)."""
    path = Path(path)
    text = read_text_file(path, "sweep means file")
    rows = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if len(rows) < 3:
        raise CamcalError("sweep means file needs a header and at least one dark and one lit row", path)
    header = [h.strip() for h in rows[0].split(",")]
    chans = ("R", "G", "B") if "G" in header else ("R", "G1", "G2", "B")
    need = ("wavelength_nm", "state", *chans, "reference")
    missing = [c for c in need if c not in header]
    if missing or len(set(header)) != len(header):
        raise CamcalError(f"sweep means file: header must name {', '.join(need)} once each"
                          f"{' (missing ' + ', '.join(missing) + ')' if missing else ''}", path)
    idx = {c: header.index(c) for c in need}
    state, wl, cam, ref = [], [], [], []
    for i, line in enumerate(rows[1:], start=2):
        cells = [c.strip() for c in line.split(",")]
        if len(cells) != len(header):
            raise CamcalError(f"data row {i - 1}: {len(cells)} cells, the header has {len(header)}", path)
        s = cells[idx["state"]].lower()
        if s not in ("dark", "lit"):
            raise CamcalError(f"data row {i - 1}: state must be dark or lit, got {cells[idx['state']]!r}", path)
        try:
            w = float(cells[idx["wavelength_nm"]]) if cells[idx["wavelength_nm"]] else math.nan
            vals = [float(cells[idx[c]]) for c in chans]
            r = float(cells[idx["reference"]])
        except ValueError:
            raise CamcalError(f"data row {i - 1}: a cell is not a number", path) from None
        if not all(math.isfinite(v) for v in (*vals, r)) or (s == "lit" and not 100.0 <= w <= 3000.0):
            raise CamcalError(f"data row {i - 1}: a non-finite value, or a lit row without a plausible "
                              "wavelength_nm", path)
        state.append(s), wl.append(w), cam.append(vals), ref.append(r)
    st = np.array(state)
    if not np.any(st == "dark") or not np.any(st == "lit"):
        raise CamcalError("sweep means file needs dark and lit rows", path)
    rwl, rr = read_responsivity(responsivity)
    return SweepReadings(st, np.array(wl), np.array(cam, float), np.array(ref, float), chans, rwl, rr,
                         (_record(path), _record(Path(responsivity))), path.stem)


def read_sweep_means(path: str | Path, responsivity: str | Path | None = None) -> SweepReadings:
    """Either layout: an ``*_info.txt`` is the open data's, anything else the plain CSV."""
    path = Path(path)
    if path.name.endswith("info.txt"):
        return read_open_sweep(path, responsivity)
    if responsivity is None:
        raise CamcalError("the plain sweep-means layout needs the reference detector's responsivity file "
                          "(--responsivity)", path)
    return read_means_csv(path, responsivity)


# ---- the reduction -----------------------------------------------------------------------------------------------
def _reading_sigma(darks: np.ndarray, integer_floor: bool) -> np.ndarray:
    """σ of one reading per column from successive dark readings (robust), floored at 1/√12 for counters."""
    if darks.shape[0] < 3:
        sig = np.zeros(darks.shape[1])
    else:
        d = np.diff(darks, axis=0)
        sig = MAD_TO_SIGMA * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / math.sqrt(2.0)
    if integer_floor:
        sig = np.maximum(sig, 1.0 / math.sqrt(12.0))
    return sig


def _camcal_dark(cam: np.ndarray, j: int, before: int | None, around: list[int]) -> np.ndarray:
    """Lit reading ``j`` less the mean of the dark readings just before and after it."""
    return cam[j] - cam[around].mean(axis=0)


def _publisher_dark(cam: np.ndarray, j: int, before: int | None, around: list[int]) -> np.ndarray:
    """Lit reading ``j`` less the dark reading before it, clipped at 0 (the publisher's ``process_data.c``)."""
    if before is None:
        raise CamcalError(f"lit reading {j + 1} has no dark reading before it (the publisher's reduction needs one)")
    return np.maximum(cam[j] - cam[before], 0.0)


DARK_REDUCTIONS = {
    "camcal": (_camcal_dark, "dark = mean of the dark readings before and after each lit reading"),
    "publisher": (_publisher_dark, "camera dark = the reading before; negative camera signals clipped to 0 (the "
                                   "publisher's process_data.c)"),
}
"""The camera's dark subtraction of each ``method`` of :func:`reduce_sweep`: (function, note)."""


def reduce_sweep(readings: SweepReadings, method: Method = "camcal") -> SweepReduction:
    """c(λ) per channel from sweep readings (module docstring: the maths, the two methods, u from repeats)."""
    if method not in DARK_REDUCTIONS:
        raise CamcalError(f"unknown sweep-means reduction {method!r}; use {' or '.join(DARK_REDUCTIONS)}")
    lit_minus_dark, dark_note = DARK_REDUCTIONS[method]
    st = readings.state
    dark_idx = np.flatnonzero(st == "dark")
    lit_idx = np.flatnonzero(st == "lit")
    cam, ref = readings.camera_dn, readings.reference
    n_c = cam.shape[1]
    d_list, r_list, nd_list = [], [], []
    for j in lit_idx:
        before = dark_idx[dark_idx < j]
        after = dark_idx[dark_idx > j]
        b = before[-1] if before.size else None
        a = after[0] if after.size else None
        if b is None and a is None:
            raise CamcalError(f"lit reading {int(j) + 1} has no dark reading before or after it")
        around = [k for k in (b, a) if k is not None]
        ref_dark = np.mean(ref[around])
        d_list.append(lit_minus_dark(cam, int(j), b, around))
        r_list.append(ref[j] - ref_dark)
        nd_list.append(len(around))
    d = np.array(d_list)
    r = np.array(r_list)
    wl = readings.wavelength_nm[lit_idx]
    lo, hi = readings.responsivity_nm[0], readings.responsivity_nm[-1]
    if np.any(wl < lo) or np.any(wl > hi):
        raise CamcalError(f"the sweep ({np.nanmin(wl):g}–{np.nanmax(wl):g} nm) leaves the responsivity's range "
                          f"({lo:g}–{hi:g} nm)")
    resp = np.interp(wl, readings.responsivity_nm, readings.responsivity)
    if np.any(resp <= 0) or np.any(r <= 0):
        bad = wl[(resp <= 0) | (r <= 0)]
        raise CamcalError(f"no reference signal (detector reading minus dark ≤ 0, or zero responsivity) at "
                          f"{', '.join(f'{w:g}' for w in bad[:5])} nm")
    e = r / resp  # relative reference radiance
    c = d / e[:, None]
    # noise of one reading, from the dark repeats
    sig_c = _reading_sigma(cam[dark_idx], False)
    sig_r = _reading_sigma(ref[dark_idx][:, None], bool(np.all(ref == np.round(ref))))[0]
    nd = np.array(nd_list, float)
    u_d = sig_c[None, :] * np.sqrt(1.0 + 1.0 / nd[:, None])
    u_r = sig_r * np.sqrt(1.0 + 1.0 / nd)
    u_single = np.hypot(u_d / e[:, None], c * (u_r / r)[:, None])  # c = d/e, e = r/R: ∂c/∂d = 1/e, ∂c/∂r = −c/r
    grid = np.unique(wl)
    out_c = np.empty((grid.size, n_c))
    out_u = np.empty((grid.size, n_c))
    n_read = np.empty(grid.size, int)
    repeated = False
    for k, w in enumerate(grid):
        sel = wl == w
        n = int(sel.sum())
        n_read[k] = n
        out_c[k] = c[sel].mean(axis=0)
        if n >= 2:  # the repeats' scatter, never below the noise the dark repeats predict (few repeats scatter)
            repeated = True
            floor = np.sqrt(np.mean(u_single[sel] ** 2, axis=0) / n)
            out_u[k] = np.maximum(c[sel].std(axis=0, ddof=1) / math.sqrt(n), floor)
        else:
            out_u[k] = u_single[sel][0]
    notes = [f"sweep means ({readings.name}): c = (lit − dark) / ((reference − its dark) / responsivity), "
             f"{method} reduction", dark_note]
    if not repeated:
        notes.append("one reading per wavelength: u(c) from the scatter of the repeated dark readings (a lower "
                     "bound where the lit reading's photon noise dominates)")
    names = readings.channels
    return SweepReduction(grid, {ch: out_c[:, i] for i, ch in enumerate(names)},
                          {ch: out_u[:, i] for i, ch in enumerate(names)}, n_read, method, tuple(notes))


def sweep_means_sensitivity(path: str | Path, responsivity: str | Path | None = None,
                            method: Method = "camcal") -> tuple[SpectralSensitivity, SweepReduction, SweepReadings]:
    """Read either layout, reduce it and return relative curves (with their source record) too."""
    readings = read_sweep_means(path, responsivity)
    red = reduce_sweep(readings, method)
    sens = red.to_sensitivity()
    return sens, red, readings

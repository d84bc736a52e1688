"""The uncertainty of a borrowed curve: a camera model's c(λ) used on another unit of that model.

A library curve (:mod:`camcal.curves.library`) was measured on one unit, in one laboratory, with one set-up.
Used on *your* unit it is wrong by the spread between units, laboratories and set-ups. That spread is
measured by pairs of independent measurements of the same model: for a pair (a, b), each curve linearly
interpolated onto a common grid (400–700 nm every 10 nm, the coarsest grid of the pairs) and normalised to
its channel's largest value there, the difference

    d_p,i(λ) = a_i(λ)/max a_i − b_i(λ)/max b_i

is exactly the error one makes by using a's curve for b's unit (or the reverse). The borrowed-curve standard
uncertainty of channel i, as a fraction of that channel's peak, is the RMS over the pairs

    f_i(λ) = √( (1/P) Σ_p d_p,i(λ)² ),

smoothed by an RMS over ±:data:`SMOOTH_HALF_WIDTH_NM` (three grid points; nine pairs do not resolve finer
structure), and floored at :data:`FLOOR_FRACTION` of its RMS over wavelength (a broadband part: where most pairs
agree, one pair of labs may still differ, e.g. the 5D Mark III's blue channel in the green). No √2 is taken
out: the difference of two measurements is the borrowing error itself, not the error of one of them. Outside
400–700 nm no pair was compared; there f keeps its value at the nearest end (the curves are small there).

The floor is set by a leave-one-out check: each pair compared with f derived from the other eight, the share of
wavelengths with |d| < 2f is 91.8 % without a floor and 94.7 % with it (95.4 % for a normal law); docs/spectral.md.

The table shipped in ``calibration_data/camera_curves/borrowed_curve_uncertainty.csv`` was derived with
:func:`derive_borrowed_uncertainty` from the pairs listed in its header and in ``docs/spectral.md``.
:func:`with_borrowed_uncertainty` puts it into a curve set's u(c): u_i(λ) = f_i(λ) · max c_i, combined in
quadrature with whatever u(c) the curves already had; it then propagates like every other u(c) (to the
absolute scale through reference targets, band radiance and σ_C).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from camcal.errors import CamcalError
from camcal.frame import RGB
from camcal.io.data import read_bundled_table
from camcal.io.hashing import sha256_file
from camcal.models.spectral import SpectralSensitivity

#: The shipped table (relative to the ``calibration_data`` package).
TABLE = "camera_curves/borrowed_curve_uncertainty.csv"
#: Grid on which pairs are compared, nm.
PAIR_GRID_NM = np.arange(400.0, 701.0, 10.0)
#: Half-width of the RMS smoothing window, nm.
SMOOTH_HALF_WIDTH_NM = 10.0
#: f is at least this fraction of its own RMS over the grid (the broadband floor).
FLOOR_FRACTION = 0.3
#: What the profile's notes say about a borrowed curve.
NOTE = ("u(c) includes the borrowed-curve uncertainty: the spread between independent measurements of one camera "
        "model (units, laboratories, set-ups), docs/spectral.md")


@dataclass(frozen=True)
class CurvePair:
    """Two independent measurements of one camera model: wavelengths (nm) and (n, 3) R, G, B curves each."""

    name: str
    wavelength_a_nm: np.ndarray
    curves_a: np.ndarray
    wavelength_b_nm: np.ndarray
    curves_b: np.ndarray


@dataclass(frozen=True)
class BorrowedUncertainty:
    """f_i(λ): the standard uncertainty of a borrowed curve as a fraction of its channel's peak.

    wavelength_nm : (n,) nm. fraction : dict R, G, B -> (n,) fraction of the channel's peak.
    pair_rms : per pair and channel, the RMS of d over the grid (fraction of peak), for the record.
    """

    wavelength_nm: np.ndarray
    fraction: dict[str, np.ndarray]
    pair_rms: dict[str, dict[str, float]] = dataclasses.field(default_factory=dict)

    def at(self, wavelength_nm: np.ndarray) -> dict[str, np.ndarray]:
        """f on other wavelengths: linear inside the table, the end values outside."""
        wl = np.asarray(wavelength_nm, float)
        return {ch: np.interp(wl, self.wavelength_nm, self.fraction[ch]) for ch in RGB}


def _normalised(wl: np.ndarray, curves: np.ndarray, grid: np.ndarray, where: str) -> np.ndarray:
    wl = np.asarray(wl, float)
    curves = np.asarray(curves, float)
    if wl[0] > grid[0] or wl[-1] < grid[-1]:
        raise CamcalError(f"pair {where}: curves cover {wl[0]:g}–{wl[-1]:g} nm, the comparison needs "
                          f"{grid[0]:g}–{grid[-1]:g} nm")
    out = np.column_stack([np.interp(grid, wl, curves[:, i]) for i in range(3)])
    peak = out.max(axis=0)
    if np.any(peak <= 0):
        raise CamcalError(f"pair {where}: a channel has no positive value")
    return out / peak


def derive_borrowed_uncertainty(pairs: Sequence[CurvePair], grid_nm: np.ndarray = PAIR_GRID_NM,
                                half_width_nm: float = SMOOTH_HALF_WIDTH_NM,
                                floor_fraction: float = FLOOR_FRACTION) -> BorrowedUncertainty:
    """f_i(λ) from pairs of independent measurements of the same model (module docstring)."""
    if not pairs:
        raise CamcalError("no curve pairs to derive the borrowed-curve uncertainty from")
    grid = np.asarray(grid_nm, float)
    d2 = []
    pair_rms = {}
    for p in pairs:
        d = _normalised(p.wavelength_a_nm, p.curves_a, grid, p.name) - \
            _normalised(p.wavelength_b_nm, p.curves_b, grid, p.name)
        d2.append(d**2)
        pair_rms[p.name] = {ch: float(np.sqrt(np.mean(d[:, i] ** 2))) for i, ch in enumerate(RGB)}
    ms = np.mean(d2, axis=0)  # (n, 3) mean square over pairs
    smooth = np.empty_like(ms)
    for k, w in enumerate(grid):
        sel = np.abs(grid - w) <= half_width_nm + 1e-9
        smooth[k] = ms[sel].mean(axis=0)
    f = np.sqrt(smooth)
    f = np.maximum(f, floor_fraction * np.sqrt(np.mean(f**2, axis=0))[None, :])
    return BorrowedUncertainty(grid, {ch: f[:, i] for i, ch in enumerate(RGB)}, pair_rms)


def shipped_borrowed_uncertainty() -> BorrowedUncertainty:
    """The table shipped with camcal (``calibration_data/camera_curves/borrowed_curve_uncertainty.csv``)."""
    header, values = read_bundled_table(TABLE)
    if header != ["wavelength_nm", "R", "G", "B"]:
        raise CamcalError(f"shipped table {TABLE} has columns {header}, expected wavelength_nm, R, G, B")
    return BorrowedUncertainty(values[:, 0], {ch: values[:, i + 1] for i, ch in enumerate(RGB)})


def shipped_table_sha256() -> str:
    """SHA-256 of the shipped table (a profile records the one its u(c) was made with)."""
    return sha256_file(Path(str(resources.files("calibration_data").joinpath(TABLE))))


def with_borrowed_uncertainty(curves: SpectralSensitivity, table: BorrowedUncertainty | None = None
                              ) -> SpectralSensitivity:
    """``curves`` with u_i(λ)² → u_i(λ)² + (f_i(λ) · max c_i)² (G1 and G2 take G's f) and a note."""
    table = table or shipped_borrowed_uncertainty()
    f = table.at(curves.wavelength_nm)
    unc = {}
    for plane in curves.plane_names:
        ch = "G" if plane in ("G1", "G2") else plane
        peak = float(np.max(curves.values[plane]))
        unc[plane] = np.hypot(curves.uncertainty[plane], f[ch] * peak)
    notes = tuple(n for n in curves.notes if not n.startswith("the file gives no uncertainties"))
    return dataclasses.replace(curves, uncertainty=unc, notes=(*notes, NOTE))


def borrowed_table_rows(table: BorrowedUncertainty, step_nm: float = 20.0) -> list[tuple[float, float, float, float]]:
    """(λ, f_R, f_G, f_B) every ``step_nm`` over the table's range, for printing."""
    wl = np.arange(table.wavelength_nm[0], table.wavelength_nm[-1] + 1e-9, step_nm)
    f = table.at(wl)
    return [(float(w), float(f["R"][k]), float(f["G"][k]), float(f["B"][k])) for k, w in enumerate(wl)]

"""The X-Rite ColorChecker Classic: its 24 patches' spectral reflectances and their chart-to-chart spread.

Nominal reflectances are colour-science's published data sets (``colour.SDS_COLOURCHECKERS``):

- ``"BabelColor Average"``: the average of 30 charts measured by BabelColor (Pascale 2006), 380-730 nm every
  10 nm;
- ``"ColorChecker N Ohta"``: one chart measured by N. Ohta (380-780 nm every 5 nm; ``"ISO 17321-1"`` holds the
  same numbers).

The chart-to-chart spread u(R) per patch and wavelength. A user's chart is another unit, printed in another
batch and aged differently. "BabelColor Average" is the mean of 30 charts (its own error is about 1/√30 of the
spread); Ohta's is one chart, so their difference d_p(λ) = R_Babel − R_Ohta is one draw of a chart's deviation
from the mean, and d² estimates the chart-to-chart variance. One draw is a poor local estimate (zero where the
curves cross), so it is smoothed over wavelength by the patch's mean square ⟨d_p²⟩:

    u_p(λ)² = (d_p(λ)² + ⟨d_p²⟩_λ) / 2,

with a floor of 0.002 + 1 % of R (the repeatability of a spectrophotometer, CIE 15:2004). Outside the range a
data set covers, its reflectance is held at the nearest value and u(R) there is at least 5 % of R.

References
----------
McCamy, C. S., Marcus, H., Davidson, J. G. (1976). A color-rendition chart. J. Appl. Photogr. Eng. 2(3), 95-99.
Ohta, N. (1997). The basis of color reproduction engineering (Japanese). Corona-sha.
Pascale, D. (2006). RGB coordinates of the Macbeth ColorChecker. BabelColor.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from camcal.errors import CamcalError
from camcal.io.hashing import sha256_file
from camcal.io.limits import MAX_CSV_COLUMNS
from camcal.io.manifest import read_text_file

#: The default working grid of the chart module, nm (the curve library's grid).
GRID_NM = np.arange(380.0, 781.0, 5.0)

#: Patch names in chart order (row by row from the brown patch, colour-science's spelling).
PATCH_NAMES: tuple[str, ...] = (
    "dark skin", "light skin", "blue sky", "foliage", "blue flower", "bluish green",
    "orange", "purplish blue", "moderate red", "purple", "yellow green", "orange yellow",
    "blue", "green", "red", "yellow", "magenta", "cyan",
    "white 9.5 (.05 D)", "neutral 8 (.23 D)", "neutral 6.5 (.44 D)", "neutral 5 (.70 D)",
    "neutral 3.5 (1.05 D)", "black 2 (1.5 D)",
)
N_PATCHES = 24
#: The six neutral patches (white to black), indices into :data:`PATCH_NAMES`.
NEUTRAL_PATCHES: tuple[int, ...] = (18, 19, 20, 21, 22, 23)

#: colour-science data sets of the Classic chart with spectra.
PUBLISHED_CHARTS = ("BabelColor Average", "ColorChecker N Ohta")
DEFAULT_CHART = "BabelColor Average"

#: Floor of u(R): absolute part and fraction of R (spectrophotometer repeatability).
U_FLOOR_ABSOLUTE = 0.002
U_FLOOR_RELATIVE = 0.01
#: Least relative u(R) where a data set is extrapolated.
U_EXTRAPOLATED_RELATIVE = 0.05
#: Largest measured-chart CSV, bytes.
MAX_CHART_CSV_BYTES = 2 * 1024 * 1024


@dataclass(frozen=True, eq=False)
class ChartReflectance:
    """Spectral reflectance of a chart's patches.

    Attributes
    ----------
    wavelength_nm : ndarray (n,)
        nm, increasing.
    reflectance : ndarray (24, n)
        Reflectance factor, dimensionless (0-1), per patch (:data:`PATCH_NAMES` order) and wavelength.
    u_reflectance : ndarray (24, n)
        Standard uncertainty of ``reflectance`` for the chart in the photo (same units).
    names : tuple of str
        Patch names.
    source : dict
        Where the numbers came from (data set or file and its SHA-256, how u(R) was set).
    """

    wavelength_nm: np.ndarray
    reflectance: np.ndarray
    u_reflectance: np.ndarray
    names: tuple[str, ...] = PATCH_NAMES
    source: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        wl = np.asarray(self.wavelength_nm, float)
        r, u = np.asarray(self.reflectance, float), np.asarray(self.u_reflectance, float)
        if wl.ndim != 1 or wl.size < 2 or np.any(np.diff(wl) <= 0):
            raise CamcalError("chart wavelengths must be an increasing 1-D array of at least two values")
        if r.shape != (len(self.names), wl.size) or u.shape != r.shape:
            raise CamcalError(f"chart reflectance must be ({len(self.names)}, {wl.size}) with its uncertainty")
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(u)) and np.all(u >= 0)):
            raise CamcalError("chart reflectance and its uncertainty must be finite (uncertainty >= 0)")

    @property
    def neutral(self) -> tuple[int, ...]:
        """Indices of the neutral patches (those of :data:`NEUTRAL_PATCHES` when the chart is the Classic)."""
        return NEUTRAL_PATCHES if len(self.names) == N_PATCHES else ()

    def on(self, wavelength_nm) -> ChartReflectance:
        """The chart resampled (linear interpolation, held constant outside) on ``wavelength_nm``; u(R) is at
        least :data:`U_EXTRAPOLATED_RELATIVE` of R where extrapolated."""
        x = np.asarray(wavelength_nm, float)
        r = np.array([np.interp(x, self.wavelength_nm, row) for row in self.reflectance])
        u = np.array([np.interp(x, self.wavelength_nm, row) for row in self.u_reflectance])
        out = (x < self.wavelength_nm[0]) | (x > self.wavelength_nm[-1])
        u[:, out] = np.maximum(u[:, out], U_EXTRAPOLATED_RELATIVE * r[:, out])
        return ChartReflectance(x, r, u, self.names, dict(self.source))


def _published(name: str, wavelength_nm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R (24, n) on ``wavelength_nm`` held constant outside the data's range, mask of extrapolated λ)."""
    import colour  # loads matplotlib: kept off paths that do not need it

    if name not in colour.SDS_COLOURCHECKERS or name not in PUBLISHED_CHARTS:
        raise CamcalError(f"unknown published chart {name!r}; use one of {', '.join(PUBLISHED_CHARTS)}")
    sds = colour.SDS_COLOURCHECKERS[name]
    keys = list(sds)
    if tuple(keys) != PATCH_NAMES:
        raise CamcalError(f"colour-science's chart {name!r} does not list the 24 Classic patches in order")
    wl0 = np.asarray(sds[keys[0]].wavelengths, float)
    r = np.array([np.interp(wavelength_nm, wl0, np.asarray(sds[k].values, float)) for k in keys])
    return r, (wavelength_nm < wl0[0]) | (wavelength_nm > wl0[-1])


def chart_spread(wavelength_nm=GRID_NM) -> np.ndarray:
    """u(R) (24, n), the chart-to-chart standard uncertainty of a ColorChecker Classic (module docstring)."""
    x = np.asarray(wavelength_nm, float)
    (ra, ea), (rb, eb) = (_published(n, x) for n in PUBLISHED_CHARTS)
    ok = ~(ea | eb)
    d = ra - rb
    ms = np.mean(d[:, ok] ** 2, axis=1, keepdims=True)
    u = np.sqrt((d ** 2 + ms) / 2.0)
    mean = 0.5 * (ra + rb)
    u = np.maximum(u, U_FLOOR_ABSOLUTE + U_FLOOR_RELATIVE * mean)
    u[:, ~ok] = np.maximum(u[:, ~ok], U_EXTRAPOLATED_RELATIVE * mean[:, ~ok])
    return u


def published_chart(name: str = DEFAULT_CHART, wavelength_nm=GRID_NM) -> ChartReflectance:
    """A published ColorChecker Classic (``"BabelColor Average"`` or ``"ColorChecker N Ohta"``) on
    ``wavelength_nm`` with the chart-to-chart spread as u(R) (:func:`chart_spread`)."""
    x = np.asarray(wavelength_nm, float)
    r, extrapolated = _published(name, x)
    u = chart_spread(x)
    u[:, extrapolated] = np.maximum(u[:, extrapolated], U_EXTRAPOLATED_RELATIVE * r[:, extrapolated])
    import colour

    src = {"kind": "published", "name": name, "library": f"colour-science {colour.__version__} SDS_COLOURCHECKERS",
           "u_reflectance": "chart-to-chart spread: BabelColor Average vs ColorChecker N Ohta (camcal.chart."
                            "targets), floor 0.002 + 1 % of R; >= 5 % of R where extrapolated"}
    return ChartReflectance(x, r, u, PATCH_NAMES, src)


def _patch_key(text: str) -> str:
    return "".join(ch for ch in text.lower() if ch.isalnum())


def read_chart_csv(path: str | Path, wavelength_nm=GRID_NM, *, u_reflectance: float | None = None
                   ) -> ChartReflectance:
    """The user's measured chart: a CSV with ``wavelength_nm`` and one column per patch.

    Columns are matched to the patches by name (:data:`PATCH_NAMES`, case and punctuation ignored) or, when the
    header holds 24 other names, taken in chart order. Reflectance in 0-1.5 (a percentage, all values > 1.5
    somewhere and <= 150, is refused: say 0-1). ``#`` lines are comments. u(R) of a measured chart is the
    spectrophotometer's repeatability (:data:`U_FLOOR_ABSOLUTE` + :data:`U_FLOOR_RELATIVE` of R) unless
    ``u_reflectance`` (absolute) is given; the result is resampled on ``wavelength_nm`` (:meth:`ChartReflectance.on`).

    Raises
    ------
    CamcalError
        One line naming the file and the problem.
    """
    path = Path(path)
    text = read_text_file(path, "chart reflectance CSV", MAX_CHART_CSV_BYTES)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if len(lines) < 3:
        raise CamcalError("chart reflectance CSV needs a header and at least two rows", path)
    header = [h.strip() for h in lines[0].split(",")]
    if len(header) > MAX_CSV_COLUMNS:
        raise CamcalError(f"chart reflectance CSV has more than {MAX_CSV_COLUMNS} columns", path)
    if "wavelength_nm" not in header:
        raise CamcalError(f"chart reflectance CSV needs a wavelength_nm column (header is {','.join(header)[:120]})",
                          path)
    iw = header.index("wavelength_nm")
    others = [i for i in range(len(header)) if i != iw]
    by_key = {_patch_key(h): i for i, h in enumerate(header) if i != iw}
    if all(_patch_key(n) in by_key for n in PATCH_NAMES):
        cols = [by_key[_patch_key(n)] for n in PATCH_NAMES]
    elif len(others) == N_PATCHES:
        cols = others
    else:
        missing = [n for n in PATCH_NAMES if _patch_key(n) not in by_key]
        raise CamcalError(f"chart reflectance CSV needs one column per patch (24): {len(others)} found, "
                          f"missing e.g. {missing[0]!r}", path)
    rows = []
    for k, ln in enumerate(lines[1:], start=2):
        cells = [c.strip() for c in ln.split(",")]
        if len(cells) != len(header):
            raise CamcalError(f"chart reflectance CSV row {k} has {len(cells)} cells, the header {len(header)}",
                              path)
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            raise CamcalError(f"chart reflectance CSV row {k} is not numbers", path) from None
    v = np.array(rows, float)
    if not np.all(np.isfinite(v)):
        raise CamcalError("chart reflectance CSV holds a non-finite value", path)
    wl, r = v[:, iw], v[:, cols].T
    if np.any(np.diff(wl) <= 0):
        raise CamcalError("chart reflectance CSV: wavelengths must increase", path)
    if not (wl[0] >= 200 and wl[-1] <= 1200):
        raise CamcalError("chart reflectance CSV: wavelengths must lie in 200-1200 nm", path)
    if np.any(r < 0) or np.any(r > 1.5):
        hint = " (a percentage? give reflectance as 0-1)" if np.nanmax(r) <= 150 and np.nanmax(r) > 1.5 else ""
        raise CamcalError(f"chart reflectance CSV: reflectance must lie in 0-1.5{hint}", path)
    if u_reflectance is None:
        u = U_FLOOR_ABSOLUTE + U_FLOOR_RELATIVE * r
        how = "spectrophotometer repeatability: 0.002 + 1 % of R"
    else:
        if not (np.isfinite(u_reflectance) and 0 <= u_reflectance < 1):
            raise CamcalError("chart reflectance uncertainty must lie in 0-1", path)
        u = np.full_like(r, float(u_reflectance))
        how = f"stated: {u_reflectance:g}"
    src = {"kind": "measured", "file": str(path), "sha256": sha256_file(path), "u_reflectance": how,
           "wavelength_range_nm": [float(wl[0]), float(wl[-1])]}
    return ChartReflectance(wl, r, u, PATCH_NAMES, src).on(wavelength_nm)

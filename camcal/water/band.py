"""Band-aware inversion: the red-channel ratio predicted by integrating the model over c_R(λ).

A camera channel is not narrowband: its ratio of submerged to reference radiance is

    B(C) = ∫ c_R(λ) S(λ) R_λ(τ_λ(C)) dλ / ∫ c_R(λ) S(λ) dλ,   τ_λ = [a_bg(λ) + a_chl(λ, C)] d,

with R_λ the closed form of the chosen geometry (seed or refined, :mod:`camcal.water.models`), S the
illuminant's spectral radiance (flat by default) and a_chl(λ, C) = A(λ) C^E(λ) (m⁻¹, C in mg m⁻³). The
default chlorophyll spectrum is Bricaud et al. (1998) for natural phytoplankton
(``calibration_data/chlorophyll_a_bricaud_1998.csv``); a solvent spectrum is the linear case E = 1 with
A = a* = 2.303e-4 ε (ε in L g⁻¹ cm⁻¹). B is monotone in C; it is tabulated on 0 and 1e-4…1e5 µg/L with its
analytic derivative and inverted by cubic Hermite interpolation of ln C against ln B.

References
----------
Bricaud, A., Morel, A., Babin, M., Allali, K., Claustre, H. (1998). J. Geophys. Res. 103(C13), 31033-31044.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from camcal.errors import CamcalError
from camcal.water.invert import Inversion, Reason
from camcal.water.models import ClosedForm, SeedModel
from camcal.water.units import specific_absorption_m2_per_mg, ug_per_L_to_mol_per_L

C_GRID_MIN_UG_PER_L = 1e-4
C_GRID_MAX_UG_PER_L = 1e5


@dataclass(frozen=True, eq=False)
class ChlorophyllAbsorption:
    """a_chl(λ, C) = A(λ) C^E(λ), m⁻¹, C in mg m⁻³ (µg/L); A in m² mg⁻¹ (natural log)."""

    wavelengths_nm: np.ndarray
    coefficient_m2_per_mg: np.ndarray
    exponent: np.ndarray
    source: str = ""

    def on(self, wavelengths_nm: np.ndarray) -> ChlorophyllAbsorption:
        """Resampled (linear) on another grid; zero absorption outside the tabulated range."""
        wl = np.asarray(wavelengths_nm, float)
        a = np.interp(wl, self.wavelengths_nm, self.coefficient_m2_per_mg, left=0.0, right=0.0)
        e = np.interp(wl, self.wavelengths_nm, self.exponent)
        return ChlorophyllAbsorption(wl, a, e, self.source)

    def absorption_per_m(self, c_ug_per_L):
        c = np.asarray(c_ug_per_L, float)[..., None]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(c > 0, self.coefficient_m2_per_mg * c ** self.exponent, 0.0)

    def derivative_per_m(self, c_ug_per_L):
        """d a_chl / dC, m⁻¹ per (mg m⁻³)."""
        c = np.asarray(c_ug_per_L, float)[..., None]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(c > 0, self.coefficient_m2_per_mg * self.exponent * c ** (self.exponent - 1), np.inf)


@functools.lru_cache(maxsize=2)
def bricaud_1998(kind: str = "ph") -> ChlorophyllAbsorption:
    """Bricaud et al. (1998) A(λ), E(λ), 400-700 nm: ``kind`` 'ph' (phytoplankton) or 'p' (all particles)."""
    from camcal.data import read_table

    header, v = read_table("chlorophyll_a_bricaud_1998.csv")
    a = v[:, header.index(f"A_{kind}_m2_per_mg")]
    e = v[:, header.index(f"E_{kind}")]
    return ChlorophyllAbsorption(v[:, 0], a, e, "Bricaud et al. 1998 (a*_" + kind + ")")


def solvent_spectrum(wavelengths_nm, epsilon_L_per_g_cm) -> ChlorophyllAbsorption:
    """A linear (Beer-Lambert) spectrum from decadic ε(λ) in L g⁻¹ cm⁻¹ (e.g. chlorophyll-a in acetone)."""
    wl = np.asarray(wavelengths_nm, float)
    eps = np.asarray(epsilon_L_per_g_cm, float)
    return ChlorophyllAbsorption(wl, specific_absorption_m2_per_mg(1.0) * eps, np.ones_like(wl), "solvent ε(λ)")


def read_chlorophyll_csv(path: str | Path) -> ChlorophyllAbsorption:
    """A user spectrum: CSV with ``wavelength_nm`` and either ``epsilon_L_per_g_cm`` (linear) or
    ``A_m2_per_mg`` and optionally ``E`` (power law); ``#`` lines are comments."""
    path = Path(path)
    try:
        lines = [ln for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip() and not ln.startswith("#")]
        header = [h.strip() for h in lines[0].split(",")]
        v = np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]], dtype=float)
    except (OSError, ValueError, IndexError) as exc:
        raise CamcalError(f"cannot read chlorophyll absorption CSV: {exc}", path) from None
    if "wavelength_nm" not in header or v.ndim != 2 or v.shape[0] < 2 or v.shape[1] != len(header):
        raise CamcalError("chlorophyll CSV needs a wavelength_nm column and at least two rows", path)
    if not np.all(np.isfinite(v)) or np.any(np.diff(v[:, header.index("wavelength_nm")]) <= 0):
        raise CamcalError("chlorophyll CSV has non-finite values or wavelengths not increasing", path)
    wl = v[:, header.index("wavelength_nm")]
    if "epsilon_L_per_g_cm" in header:
        return solvent_spectrum(wl, v[:, header.index("epsilon_L_per_g_cm")])
    if "A_m2_per_mg" in header:
        e = v[:, header.index("E")] if "E" in header else np.ones_like(wl)
        return ChlorophyllAbsorption(wl, v[:, header.index("A_m2_per_mg")], e, str(path))
    raise CamcalError("chlorophyll CSV needs an epsilon_L_per_g_cm or an A_m2_per_mg column", path)


@dataclass(frozen=True, eq=False)
class BandModel:
    """A camera channel looking at the disk: see the module docstring.

    wavelengths_nm, sensitivity : the channel's c(λ) (any units; only its shape matters).
    geometry : a model whose ``closed_form()`` gives R(τ) (SeedModel or RefinedModel). Only its geometry
        is used; absorption comes from ``chlorophyll`` and ``background_absorption_per_m`` (a_bg(λ), m⁻¹,
        e.g. pure water and CDOM; default zero).
    illuminant : S(λ), relative spectral radiance of the light (default flat).
    """

    wavelengths_nm: np.ndarray
    sensitivity: np.ndarray
    geometry: object = field(default_factory=SeedModel)
    chlorophyll: ChlorophyllAbsorption | None = None
    background_absorption_per_m: np.ndarray | float = 0.0
    illuminant: np.ndarray | None = None

    def _parts(self):
        wl = np.asarray(self.wavelengths_nm, float)
        c = np.asarray(self.sensitivity, float)
        if wl.ndim != 1 or c.shape != wl.shape or wl.size < 2:
            raise CamcalError("band model needs 1-D wavelength and sensitivity arrays of one length")
        s = np.ones_like(wl) if self.illuminant is None else np.asarray(self.illuminant, float)
        w = np.clip(c * s, 0.0, None)
        dl = np.gradient(wl)  # trapezoid-like weights on a non-uniform grid
        w = w * dl
        if not np.sum(w) > 0:
            raise CamcalError("channel sensitivity is zero everywhere on the grid")
        bg = np.broadcast_to(np.asarray(self.background_absorption_per_m, float), wl.shape)
        used = w > 1e-12 * w.max()  # skip wavelengths the channel does not see
        chl = (self.chlorophyll or bricaud_1998()).on(wl[used])
        return w[used] / np.sum(w[used]), chl, bg[used], self.geometry.closed_form()

    def ratio(self, c_ug_per_L, depth_m: float):
        """Band ratio B(C) at depth ``depth_m`` (m), C in µg/L (any shape)."""
        w, chl, bg, cf = self._parts()
        tau = (bg + chl.absorption_per_m(c_ug_per_L)) * depth_m
        return np.sum(w * cf.ratio(tau), axis=-1)

    def ratio_derivative(self, c_ug_per_L, depth_m: float):
        """dB/dC, per (µg/L): Σ w R'(τ_λ) d ∂a_chl/∂C."""
        w, chl, bg, cf = self._parts()
        tau = (bg + chl.absorption_per_m(c_ug_per_L)) * depth_m
        return np.sum(w * cf.ratio_derivative(tau) * depth_m * chl.derivative_per_m(c_ug_per_L), axis=-1)

    def inverse(self, depth_m: float, nodes: int = 800) -> BandInverse:
        return BandInverse(self, float(depth_m), nodes)


class BandInverse:
    """Tabulated inverse of :meth:`BandModel.ratio` at one depth (cubic Hermite in ln C vs −ln B)."""

    def __init__(self, model: BandModel, depth_m: float, nodes: int = 800) -> None:
        if not (np.isfinite(depth_m) and depth_m > 0):
            raise CamcalError(f"depth must be positive, got {depth_m} m")
        c = np.logspace(np.log10(C_GRID_MIN_UG_PER_L), np.log10(C_GRID_MAX_UG_PER_L), nodes)
        b = model.ratio(c, depth_m)
        db = model.ratio_derivative(c, depth_m)
        self.b0 = float(model.ratio(0.0, depth_m))
        keep = (b > 1e-300) & (db < 0) & np.isfinite(db)
        keep &= np.concatenate([[True], np.diff(-np.log(np.where(b > 0, b, 1e-300))) > 0])
        c, b, db = c[keep], b[keep], db[keep]
        x = -np.log(b)
        y = np.log(c)
        dydx = b / (c * -db)  # d ln C / d(−ln B)
        self._spline = CubicHermiteSpline(x, y, dydx)
        self._deriv = self._spline.derivative()
        self.x_lo, self.x_hi = float(x[0]), float(x[-1])
        self.c_lo = float(c[0])

    def concentration(self, ratio, *, sigma_ln_ratio=None) -> Inversion:
        """C (µg/L and mol/L) per pixel from band ratios, with reasons and propagated σ."""
        r = np.asarray(ratio, dtype=float)
        reason = np.zeros(r.shape, dtype=np.uint8)
        fin = np.isfinite(r)
        reason[~fin] = Reason.NOT_FINITE
        reason[fin & (r <= 0)] = Reason.NOT_POSITIVE
        ok = reason == 0
        reason[ok & (r > self.b0)] = Reason.ABOVE_CLEAR_WATER
        with np.errstate(divide="ignore", invalid="ignore"):
            x = -np.log(np.where(reason == 0, r, 1.0))
        reason[(reason == 0) & (x > self.x_hi)] = Reason.TOO_DARK
        ok = reason == 0
        c = np.full(r.shape, np.nan)
        sig = np.full(r.shape, np.nan)
        main = ok & (x >= self.x_lo)
        y = self._spline(x[main])
        c[main] = np.exp(y)
        if sigma_ln_ratio is not None:
            s = np.broadcast_to(np.asarray(sigma_ln_ratio, float), r.shape)
            sig[main] = c[main] * np.abs(self._deriv(x[main])) * s[main]
        low = ok & (x < self.x_lo)  # between C = 0 and the first node: linear in B
        b_lo = np.exp(-self.x_lo)
        c[low] = self.c_lo * (self.b0 - r[low]) / (self.b0 - b_lo)
        if sigma_ln_ratio is not None:
            sig[low] = self.c_lo * r[low] / (self.b0 - b_lo) * np.broadcast_to(sigma_ln_ratio, r.shape)[low]
        c_mol = ug_per_L_to_mol_per_L(c)
        return Inversion(c_mol, c, sig, np.full(r.shape, np.nan), reason)


def closed_form_of(model) -> ClosedForm:
    """The closed form used for a geometry (re-exported for callers)."""
    return model.closed_form()

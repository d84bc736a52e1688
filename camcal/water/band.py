"""Band-aware inversion: the red-channel ratio predicted by integrating the model over c_R(λ).

A camera channel is not narrowband: its ratio of submerged to reference radiance is

    B(C) = ∫ c_R(λ) S(λ) R_λ(τ_λ(C)) dλ / ∫ c_R(λ) S(λ) dλ,   τ_λ = [a_w(λ) + a_bg(λ) + a_chl(λ, C)] d,

with R_λ the closed form of the chosen geometry (seed or refined, :mod:`camcal.water.models`), S the
reference disk's spectral radiance (the illuminant's shape; flat by default), a_w pure water (Pope & Fry
1997, :mod:`camcal.water.purewater`; the default for the refined geometry, zero for the seed's, which
ignores water), a_bg a background (CDOM) absorption and a_chl(λ, C) = A(λ) C^E(λ) (m⁻¹, C in mg m⁻³). The
default chlorophyll spectrum is Bricaud et al. (1998) for natural phytoplankton
(``calibration_data/chlorophyll_a_bricaud_1998.csv``); a solvent spectrum is the linear case E = 1 with
A = a* = 2.303e-4 ε (ε in L g⁻¹ cm⁻¹). B is monotone in C; it is tabulated on 0 and 1e-4…1e5 µg/L with its
analytic derivative and inverted by cubic Hermite interpolation of ln C against ln B.
:func:`band_model_from_profile` takes c_R(λ) from a calibration profile (its absolute units cancel).

References
----------
Bricaud, A., Morel, A., Babin, M., Allali, K., Claustre, H. (1998). J. Geophys. Res. 103(C13), 31033-31044.
Pope, R. M., Fry, E. S. (1997). Applied Optics 36(33), 8710-8723.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicHermiteSpline
from scipy.special import expn

from camcal.errors import CamcalError
from camcal.io.data import read_bundled_table
from camcal.io.manifest import read_text_file
from camcal.models.profile import load_profile
from camcal.models.spectra import planck_radiance
from camcal.threads import run_bands
from camcal.water.invert import CHUNK, HermiteTable, Inversion, Reason
from camcal.water.models import ClosedForm, RefinedModel, SeedModel, form_at
from camcal.water.purewater import pure_water_absorption_per_m
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
        """d a_chl / dC, m⁻¹ per (mg m⁻³). At C = 0 its limit from above: infinite for E < 1, A for E = 1 (a
        linear absorber), 0 for E > 1 or where A = 0."""
        c = np.asarray(c_ug_per_L, float)[..., None]
        a, e = self.coefficient_m2_per_mg, self.exponent
        at_zero = np.where(a == 0, 0.0, np.where(e < 1, np.inf, np.where(e == 1, a, 0.0)))
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(c > 0, a * e * c ** (e - 1), at_zero)


@functools.lru_cache(maxsize=2)
def bricaud_1998(kind: str = "ph") -> ChlorophyllAbsorption:
    """Bricaud et al. (1998) A(λ), E(λ), 400-700 nm: ``kind`` 'ph' (phytoplankton) or 'p' (all particles)."""

    header, v = read_bundled_table("chlorophyll_a_bricaud_1998.csv")
    a = v[:, header.index(f"A_{kind}_m2_per_mg")]
    e = v[:, header.index(f"E_{kind}")]
    return ChlorophyllAbsorption(v[:, 0], a, e, "Bricaud et al. 1998 (a*_" + kind + ")")


def solvent_spectrum(wavelengths_nm, epsilon_L_per_g_cm) -> ChlorophyllAbsorption:
    """A linear (Beer-Lambert) spectrum from decadic ε(λ) in L g⁻¹ cm⁻¹ (e.g. chlorophyll-a in acetone)."""
    wl = np.asarray(wavelengths_nm, float)
    eps = np.asarray(epsilon_L_per_g_cm, float)
    return ChlorophyllAbsorption(wl, specific_absorption_m2_per_mg(1.0) * eps, np.ones_like(wl), "solvent ε(λ)")


_MASS_CONC_G_PER_L = {"g/l": 1.0, "mg/l": 1e-3, "ug/l": 1e-6, "µg/l": 1e-6, "mg/m3": 1e-6, "mg/m^3": 1e-6}
_MOLAR_CONC_MOL_PER_L = {"mol/l": 1.0, "m": 1.0, "mmol/l": 1e-3, "umol/l": 1e-6, "µmol/l": 1e-6}


def _csv_metadata(text: str) -> dict[str, str]:
    """``# key: value`` (or ``# key = value``) comment lines of a CSV, keys lower-case."""
    meta = {}
    for ln in text.splitlines():
        m = re.fullmatch(r"\s*#\s*([A-Za-z_][\w ]*?)\s*[:=]\s*(.+?)\s*", ln)
        if m:
            meta[m.group(1).strip().lower().replace(" ", "_")] = m.group(2)
    return meta


def _meta_number(meta: dict, key: str, path: Path, example: str) -> tuple[float, str]:
    if key not in meta:
        raise CamcalError(f"absorber CSV needs a '# {key}: {example}' line", path)
    m = re.fullmatch(r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(\S*)", meta[key].strip())
    if not m or not np.isfinite(float(m.group(1))) or float(m.group(1)) <= 0:
        raise CamcalError(f"absorber CSV: '# {key}: {meta[key]}' is not a positive number with a unit "
                          f"(e.g. {example})", path)
    return float(m.group(1)), m.group(2).lower()


def read_chlorophyll_csv(path: str | Path) -> ChlorophyllAbsorption:
    """An absorber's spectrum (chlorophyll, a dye, a pigment standard) from a CSV; ``#`` lines are comments.

    Columns: ``wavelength_nm`` and one of

    - ``epsilon_L_per_g_cm``: decadic specific absorption coefficient (linear, Beer-Lambert);
    - ``epsilon_L_per_mol_cm``: decadic molar coefficient, with a ``# molar_mass_g_per_mol: 792.85`` line
      (C is then reported per mass, µg/L);
    - ``absorbance``: a spectrophotometer's decadic absorbance A(λ) of a known solution, with
      ``# concentration: 10 mg/L`` (mass: g/L, mg/L, µg/L; or molar: mol/L, mmol/L, µmol/L with a molar mass
      line) and ``# path_length: 1 cm`` (cm, mm or m) lines: ε = A / (c l) (blank-subtracted A assumed);
    - ``A_m2_per_mg`` and optionally ``E``: the power law a = A C^E (natural log, m⁻¹, C in mg m⁻³).

    All give a_abs(λ, C) in m⁻¹ with C in µg/L (= mg m⁻³): a = 2.303e-4 ε[L g⁻¹ cm⁻¹] C.
    """

    path = Path(path)
    text = read_text_file(path, "absorber (chlorophyll/dye) CSV")
    meta = _csv_metadata(text)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise CamcalError("chlorophyll CSV is empty (no header row)", path)
    header = [h.strip() for h in lines[0].split(",")]
    if len(set(header)) != len(header):
        raise CamcalError(f"chlorophyll CSV has duplicate columns in its header {header}", path)
    if "wavelength_nm" not in header:
        raise CamcalError(f"chlorophyll CSV needs a wavelength_nm column (header is {','.join(header)})", path)
    rows = []
    for i, ln in enumerate(lines[1:], start=2):
        cells = [c.strip() for c in ln.split(",")]
        if len(cells) != len(header):
            raise CamcalError(f"chlorophyll CSV row {i}: {len(cells)} cells, the header has {len(header)}", path)
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            raise CamcalError(f"chlorophyll CSV row {i}: not a number in {ln.strip()[:60]!r}", path) from None
    v = np.array(rows, dtype=float).reshape(len(rows), len(header))
    if v.shape[0] < 2:
        raise CamcalError("chlorophyll CSV needs at least two rows", path)
    if not np.all(np.isfinite(v)):
        raise CamcalError("chlorophyll CSV has non-finite values (NaN, inf or overflow)", path)
    wl = v[:, header.index("wavelength_nm")]
    if np.any(np.diff(wl) <= 0) or wl[0] <= 0:
        raise CamcalError("chlorophyll CSV: wavelengths must be positive and increasing", path)

    def molar_mass() -> float:
        m, unit = _meta_number(meta, "molar_mass_g_per_mol", path, "792.85")
        if unit not in ("", "g/mol"):
            raise CamcalError(f"absorber CSV: molar mass unit {unit!r}; give g/mol", path)
        return m

    def linear(eps_g: np.ndarray, column: str, how: str) -> ChlorophyllAbsorption:
        if np.any(eps_g < 0):
            raise CamcalError(f"chlorophyll CSV: {column} must not be negative", path)
        return replace(solvent_spectrum(wl, eps_g), source=f"{path} ({how})")

    if "epsilon_L_per_g_cm" in header:
        return linear(v[:, header.index("epsilon_L_per_g_cm")], "epsilon_L_per_g_cm", "ε per gram")
    if "epsilon_L_per_mol_cm" in header:
        mm = molar_mass()
        return linear(v[:, header.index("epsilon_L_per_mol_cm")] / mm, "epsilon_L_per_mol_cm",
                      f"molar ε, M = {mm:g} g/mol")
    if "absorbance" in header:
        c, unit = _meta_number(meta, "concentration", path, "10 mg/L")
        if unit in _MASS_CONC_G_PER_L:
            c_g_per_L = c * _MASS_CONC_G_PER_L[unit]
        elif unit in _MOLAR_CONC_MOL_PER_L:
            c_g_per_L = c * _MOLAR_CONC_MOL_PER_L[unit] * molar_mass()
        else:
            raise CamcalError(f"absorber CSV: concentration unit {unit!r}; use g/L, mg/L, ug/L, mol/L, mmol/L or "
                              "umol/L", path)
        ell, lunit = _meta_number(meta, "path_length", path, "1 cm")
        to_cm = {"cm": 1.0, "mm": 0.1, "m": 100.0, "": 1.0}
        if lunit not in to_cm:
            raise CamcalError(f"absorber CSV: path length unit {lunit!r}; use cm, mm or m", path)
        a = v[:, header.index("absorbance")]
        if np.any(a < -0.01):
            raise CamcalError("absorber CSV: absorbance below -0.01 (blank not subtracted correctly?)", path)
        return linear(np.clip(a, 0.0, None) / (c_g_per_L * ell * to_cm[lunit]), "absorbance",
                      f"absorbance of {c:g} {unit} over {ell:g} {lunit or 'cm'}")
    if "A_m2_per_mg" in header:
        a = v[:, header.index("A_m2_per_mg")]
        e = v[:, header.index("E")] if "E" in header else np.ones_like(wl)
        if np.any(a < 0):
            raise CamcalError("chlorophyll CSV: A_m2_per_mg must not be negative", path)
        if np.any(e <= 0) or np.any(e > 2):
            raise CamcalError("chlorophyll CSV: the power-law exponent E must be in (0, 2]", path)
        return ChlorophyllAbsorption(wl, a, e, str(path))
    raise CamcalError("absorber CSV needs an epsilon_L_per_g_cm, epsilon_L_per_mol_cm, absorbance or A_m2_per_mg "
                      "column", path)


read_absorber_csv = read_chlorophyll_csv


@dataclass(frozen=True, eq=False)
class BandModel:
    """A camera channel looking at the disk: see the module docstring.

    wavelengths_nm, sensitivity : the channel's c(λ) (any units; only its shape matters).
    geometry : a model whose ``closed_form()`` gives R(τ) (SeedModel or RefinedModel). Only its geometry
        is used; absorption comes from ``water_absorption_per_m``, ``background_absorption_per_m`` and
        ``chlorophyll`` (the geometry's scalar absorption and ε are not used).
    chlorophyll : a_chl spectrum (default Bricaud et al. 1998, phytoplankton).
    water_absorption_per_m : a_w(λ), m⁻¹, on ``wavelengths_nm`` (array or scalar). None: Pope & Fry (1997)
        for a RefinedModel geometry, zero for the seed's geometry (the seed ignores water).
    background_absorption_per_m : a_bg(λ), m⁻¹ (CDOM, detritus); default zero.
    illuminant : S(λ), relative spectral radiance of the reference disk (default flat).
    """

    wavelengths_nm: np.ndarray
    sensitivity: np.ndarray
    geometry: object = field(default_factory=SeedModel)
    chlorophyll: ChlorophyllAbsorption | None = None
    background_absorption_per_m: np.ndarray | float = 0.0
    illuminant: np.ndarray | None = None
    water_absorption_per_m: np.ndarray | float | None = None
    sensitivity_sigma: np.ndarray | None = None  # u_c(λ), standard uncertainty of ``sensitivity`` (same units)

    def water_absorption(self) -> np.ndarray:
        """a_w(λ) on ``wavelengths_nm``, m⁻¹ (see the class docstring for the default)."""
        wl = np.asarray(self.wavelengths_nm, float)
        if self.water_absorption_per_m is None:
            if getattr(self.geometry, "includes_water", False):
                return pure_water_absorption_per_m(wl)
            return np.zeros_like(wl)
        return np.broadcast_to(np.asarray(self.water_absorption_per_m, float), wl.shape).copy()

    def absorption_background(self) -> np.ndarray:
        """a_w(λ) + a_bg(λ), m⁻¹: everything but chlorophyll."""
        wl = np.asarray(self.wavelengths_nm, float)
        return self.water_absorption() + np.broadcast_to(np.asarray(self.background_absorption_per_m, float),
                                                         wl.shape)

    @functools.cached_property
    def _parts(self):
        wl = np.asarray(self.wavelengths_nm, float)
        c = np.asarray(self.sensitivity, float)
        if wl.ndim != 1 or c.shape != wl.shape or wl.size < 2:
            raise CamcalError("band model needs 1-D wavelength and sensitivity arrays of one length")
        s = np.ones_like(wl) if self.illuminant is None else np.asarray(self.illuminant, float)
        if s.shape != wl.shape:
            raise CamcalError("band model illuminant must be on the sensitivity's wavelength grid")
        w = np.clip(c * s, 0.0, None)
        dl = np.gradient(wl)  # trapezoid-like weights on a non-uniform grid
        w = w * dl
        if not np.sum(w) > 0:
            raise CamcalError("channel sensitivity is zero everywhere on the grid")
        bg = self.absorption_background()
        used = w > 1e-12 * w.max()  # skip wavelengths the channel does not see
        chl = (self.chlorophyll or bricaud_1998()).on(wl[used])
        return w[used] / np.sum(w[used]), chl, bg[used]

    def form(self, depth_m: float):
        """R(τ) of the geometry at ``depth_m`` (:func:`camcal.water.models.form_at`)."""
        return form_at(self.geometry, depth_m)

    def spectral_ratio(self, c_ug_per_L, depth_m: float) -> np.ndarray:
        """R_λ(τ_λ(C)) on every wavelength of the grid (shape ``C.shape + (n,)``): the per-wavelength ratio
        of submerged to reference radiance, used to render scenes."""
        wl = np.asarray(self.wavelengths_nm, float)
        chl = (self.chlorophyll or bricaud_1998()).on(wl)
        tau = (self.absorption_background() + chl.absorption_per_m(c_ug_per_L)) * depth_m
        return self.form(depth_m).ratio(tau)

    def ratio(self, c_ug_per_L, depth_m: float):
        """Band ratio B(C) at depth ``depth_m`` (m), C in µg/L (any shape)."""
        w, chl, bg = self._parts
        tau = (bg + chl.absorption_per_m(c_ug_per_L)) * depth_m
        return np.sum(w * self.form(depth_m).ratio(tau), axis=-1)

    def ratio_derivative(self, c_ug_per_L, depth_m: float):
        """dB/dC, per (µg/L): Σ w R'(τ_λ) d ∂a_chl/∂C."""
        w, chl, bg = self._parts
        tau = (bg + chl.absorption_per_m(c_ug_per_L)) * depth_m
        return np.sum(w * self.form(depth_m).ratio_derivative(tau) * depth_m * chl.derivative_per_m(c_ug_per_L),
                      axis=-1)

    def ratio_and_derivative(self, c_ug_per_L, depth_m: float):
        """(B(C), dB/dC) in one pass (one evaluation of the exponential integrals)."""
        w, chl, bg = self._parts
        tau = (bg + chl.absorption_per_m(c_ug_per_L)) * depth_m
        cf = self.form(depth_m)
        if not isinstance(cf, ClosedForm):  # exact-transmittance or lamp form: their own ratio and derivative
            r = cf.ratio(tau)
            db = np.sum(w * cf.ratio_derivative(tau) * depth_m * chl.derivative_per_m(c_ug_per_L), axis=-1)
            return np.sum(w * r, axis=-1), db
        x = cf.path_factor * tau
        e3a, e3b = expn(3, x), expn(3, x / cf.mu_c)
        e2a, e2b = expn(2, x), expn(2, x / cf.mu_c)
        att = cf.scale * np.exp(-cf.view_factor * tau)
        integral = e3a - cf.mu_c * cf.mu_c * e3b
        r = att * integral
        dr_dtau = -cf.view_factor * r + att * cf.path_factor * (-e2a + cf.mu_c * e2b)
        db = np.sum(w * dr_dtau * depth_m * chl.derivative_per_m(c_ug_per_L), axis=-1)
        return np.sum(w * r, axis=-1), db

    def ratio_sigma_from_sensitivity(self, c_ug_per_L, depth_m: float, sensitivity_sigma) -> np.ndarray:
        """σ_B from the standard uncertainty u_c(λ) of the channel's c(λ) (independent per wavelength):
        σ_B² = Σ [S Δλ (R_λ − B) u_c / Σ c S Δλ]² (:mod:`camcal.water.uncertainty`). Shape of C."""
        wl = np.asarray(self.wavelengths_nm, float)
        s = np.ones_like(wl) if self.illuminant is None else np.asarray(self.illuminant, float)
        dl = np.gradient(wl)
        total = np.sum(np.clip(np.asarray(self.sensitivity, float), 0, None) * s * dl)
        r = self.spectral_ratio(c_ug_per_L, depth_m)
        b = self.ratio(c_ug_per_L, depth_m)
        u = np.where(np.asarray(self.sensitivity, float) > 0, np.asarray(sensitivity_sigma, float), 0.0)  # clipped c
        return np.sqrt(np.sum(np.square(s * dl * (r - np.asarray(b)[..., None]) * u / total), axis=-1))

    def inverse(self, depth_m: float, nodes: int = 800) -> BandInverse:
        """The tabulated inverse at ``depth_m`` (m), cached per depth."""
        cache = self.__dict__.setdefault("_inverses", {})
        key = (float(depth_m), int(nodes))
        if key not in cache:
            cache[key] = BandInverse(self, float(depth_m), nodes)
        return cache[key]

    def describe(self) -> dict:
        """JSON-ready description (for output metadata)."""
        wl = np.asarray(self.wavelengths_nm, float)
        w = np.clip(np.asarray(self.sensitivity, float), 0, None) * np.gradient(wl)
        if self.illuminant is not None:
            w = w * np.asarray(self.illuminant, float)
        return {"geometry": getattr(self.geometry, "name", type(self.geometry).__name__),
                "chlorophyll": (self.chlorophyll or bricaud_1998()).source,
                "water_absorption": ("Pope & Fry 1997" if self.water_absorption_per_m is None
                                     and getattr(self.geometry, "includes_water", False) else "given" if
                                     self.water_absorption_per_m is not None else "none (seed)"),
                "effective_wavelength_nm": float(np.sum(w * wl) / np.sum(w)),
                "wavelength_range_nm": [float(wl[0]), float(wl[-1])]}


def read_spectrum_csv(path: str | Path, what: str = "lamp spectrum CSV") -> tuple[np.ndarray, np.ndarray]:
    """A measured relative spectrum: CSV with ``wavelength_nm`` and one value column (any name, e.g.
    ``relative_radiance``); ``#`` lines are comments. Returns (wavelength_nm, values), values ≥ 0, finite."""

    path = Path(path)
    text = read_text_file(path, what)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if len(lines) < 3:
        raise CamcalError(f"{what} needs a header row and at least two rows", path)
    header = [h.strip() for h in lines[0].split(",")]
    if len(header) != 2 or header[0] != "wavelength_nm":
        raise CamcalError(f"{what} needs two columns, wavelength_nm and a value (header is {lines[0].strip()!r})",
                          path)
    try:
        v = np.array([[float(c) for c in ln.split(",")] for ln in lines[1:]], dtype=float)
    except ValueError:
        raise CamcalError(f"{what}: a row is not two numbers", path) from None
    if v.ndim != 2 or v.shape[1] != 2:
        raise CamcalError(f"{what}: every row needs two numbers", path)
    if not np.all(np.isfinite(v)) or np.any(v[:, 1] < 0) or not np.any(v[:, 1] > 0):
        raise CamcalError(f"{what}: values must be finite, >= 0 and not all zero", path)
    if np.any(np.diff(v[:, 0]) <= 0) or v[0, 0] <= 0:
        raise CamcalError(f"{what}: wavelengths must be positive and increasing", path)
    return v[:, 0], v[:, 1]


#: Names of the shipped 3200 K lamp spectrum (``calibration_data/lamp_3200K.csv``).
LAMP_NAMES = ("lamp", "3200k", "lamp_3200k", "lamp-3200k")


def illuminant_spectrum(name: str | Path, wavelengths_nm) -> np.ndarray | None:
    """Relative spectral radiance S(λ) of a light on ``wavelengths_nm``, normalised to a maximum of 1.

    ``name``: 'flat' (None); a CIE illuminant of colour-science (``colour.SDS_ILLUMINANTS``: 'D65', 'D50',
    'A' (2856 K tungsten), ...); 'lamp' / '3200K' (the shipped 3200 K black body, the default lamp of the
    tank experiment); 'NNNNK' (a black body at NNNN kelvin, Planck's law); or the path of a measured lamp
    CSV (:func:`read_spectrum_csv`). Linear interpolation; wavelengths outside a CSV's range are NaN (the
    caller decides whether the band needs them: :func:`band_model_from_profile` refuses).
    """
    wl = np.asarray(wavelengths_nm, float)
    text = str(name).strip()
    key = text.lower()
    if key in ("flat", "equal", "e", "none"):
        return None
    if key in LAMP_NAMES:
        header, v = read_bundled_table("lamp_3200K.csv")
        s = np.interp(wl, v[:, 0], v[:, 1], left=np.nan, right=np.nan)
    elif re.fullmatch(r"\d+(\.\d*)?k", key):
        t = float(key[:-1])
        if not 500 <= t <= 50000:
            raise CamcalError(f"black-body temperature {text!r} is implausible (500-50000 K)")
        s = planck_radiance(t, wl)
    elif key.endswith(".csv") or Path(text).is_file():
        lw, lv = read_spectrum_csv(text)
        s = np.interp(wl, lw, lv, left=np.nan, right=np.nan)
    else:
        import colour  # loads matplotlib: kept off paths that do not plot

        ckey = {k.lower(): k for k in colour.SDS_ILLUMINANTS}.get(key)
        if ckey is None:
            raise CamcalError(f"unknown illuminant {text!r}; use flat, D65, D50, A, lamp (3200 K), a temperature "
                              "such as 3000K, another CIE illuminant name or a lamp CSV file")
        sd = colour.SDS_ILLUMINANTS[ckey]
        s = np.interp(wl, sd.wavelengths, sd.values)
    return s / np.nanmax(s)


def band_model_from_profile(profile, channel: str = "R", *, geometry=None, chlorophyll=None,
                            illuminant: str | np.ndarray | None = "D65", water_absorption_per_m=None,
                            background_absorption_per_m=0.0) -> BandModel:
    """The band model of one channel of a calibration profile (its ``spectral`` stage's c(λ)).

    Parameters
    ----------
    profile : a :class:`camcal.models.profile.CalibrationProfile` or the path of a ``.camcal`` file.
    channel : 'R', 'G' or 'B' (``profile.spectral.rgb()``) or a CFA plane ('R', 'G1', 'G2', 'B').
    geometry : SeedModel or RefinedModel (default: RefinedModel(), i.e. Pope & Fry water).
    illuminant : the reference disk's relative spectral radiance: a name for :func:`illuminant_spectrum`
        ('D65' default: daylight), an array on the profile's wavelength grid, or None (flat).
    Other parameters as :class:`BandModel`.

    Raises
    ------
    CamcalError
        The profile has no spectral stage, or no such channel.
    """
    where = None
    if isinstance(profile, str | Path):

        where = Path(profile)
        profile = load_profile(where)
    spectral = getattr(profile, "spectral", None)
    if spectral is None:
        raise CamcalError("profile has no spectral sensitivity stage (calibrate with a sweep)", where)
    curves = dict(spectral.channels()) if hasattr(spectral, "channels") else {}
    curves.update(spectral.rgb())
    if channel not in curves:
        raise CamcalError(f"profile has no channel {channel!r}; use one of {', '.join(sorted(curves))}", where)
    wl = np.asarray(spectral.wavelength_nm, float)
    s = illuminant_spectrum(illuminant, wl) if isinstance(illuminant, str | Path) else illuminant
    if s is not None and np.any(np.isnan(s)):  # a measured lamp CSV shorter than the profile's grid
        c_abs = np.abs(np.asarray(curves[channel], float))
        need = c_abs >= 0.01 * np.max(c_abs)
        if np.any(need & np.isnan(s)):
            raise CamcalError(f"the light's spectrum {str(illuminant)!r} does not cover channel {channel}'s band "
                              f"({wl[need][0]:g}-{wl[need][-1]:g} nm, c(λ) ≥ 1 % of its peak)",
                              Path(illuminant) if Path(str(illuminant)).is_file() else where)
        s = np.nan_to_num(s, nan=0.0)
    if chlorophyll is not None:  # outside its table a user spectrum absorbs nothing: it must span the band
        weight = np.abs(np.asarray(curves[channel], float)) * (1.0 if s is None else np.asarray(s, float))
        band = wl[weight >= 0.01 * np.max(weight)] if np.max(weight) > 0 else wl
        lo, hi = float(chlorophyll.wavelengths_nm[0]), float(chlorophyll.wavelengths_nm[-1])
        if lo > band[0] or hi < band[-1]:
            src = Path(chlorophyll.source) if chlorophyll.source and Path(chlorophyll.source).is_file() else where
            raise CamcalError(f"the chlorophyll spectrum covers {lo:g}–{hi:g} nm; channel {channel}'s band "
                              f"(c(λ)·illuminant ≥ 1 % of its peak) spans {band[0]:g}–{band[-1]:g} nm", src)
    uncs = dict(spectral.uncertainty) if hasattr(spectral, "uncertainty") else {}
    if hasattr(spectral, "rgb_uncertainty"):
        uncs.update(spectral.rgb_uncertainty())
    u = uncs.get(channel)
    return BandModel(wl, np.asarray(curves[channel], float), geometry=geometry or RefinedModel(),
                     chlorophyll=chlorophyll, background_absorption_per_m=background_absorption_per_m,
                     illuminant=s, water_absorption_per_m=water_absorption_per_m,
                     sensitivity_sigma=None if u is None else np.asarray(u, float))


class BandInverse:
    """Tabulated inverse of :meth:`BandModel.ratio` at one depth, for whole images.

    With δ = ln B(0) − ln B (≥ 0, increasing in C), y = ln C is a smooth, nearly linear function of w = ln δ
    (a power law at low C). It is tabulated on nodes log-spaced in C (1e-4…1e5 µg/L) with the analytic slope
    dy/dw = δ B / (C (−dB/dC)), interpolated by a cubic Hermite spline, and resampled onto ``table_nodes``
    nodes uniform in w (a :class:`camcal.water.invert.HermiteTable`, as :class:`camcal.water.invert.TauTable`'s),
    so a pixel costs two logs, one index and a cubic (chunked, two threads). Below the first node C is linear in
    δ; beyond the last the pixel is TOO_DARK, and so beyond the node where the table no longer follows its nodes
    to 1e-6 in ln C (B flattening towards a floor of light the chlorophyll does not absorb).
    σ_C = C |dy/dw| σ_ln r / δ.
    """

    def __init__(self, model: BandModel, depth_m: float, nodes: int = 800, table_nodes: int = 4096) -> None:
        if not (np.isfinite(depth_m) and depth_m > 0):
            raise CamcalError(f"depth must be positive, got {depth_m} m")
        c = np.logspace(np.log10(C_GRID_MIN_UG_PER_L), np.log10(C_GRID_MAX_UG_PER_L), nodes)
        b, db = model.ratio_and_derivative(c, depth_m)
        self.b0 = float(model.ratio(0.0, depth_m))
        self.ln_b0 = float(np.log(self.b0))
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = self.ln_b0 - np.log(b)
            # drop the plateau where B no longer responds to C (light the chlorophyll spectrum does not absorb,
            # e.g. beyond its 700 nm end, floors B): |d ln B/d ln C| < 1e-8 is beyond any measurement
            keep = (b > 1e-300) & np.isfinite(db) & (c * -db > 1e-8 * b) & (delta > 0)
        if np.count_nonzero(keep) < 4:
            src = getattr(getattr(model, "chlorophyll", None), "source", "") or ""
            raise CamcalError("the band model does not respond to chlorophyll at this depth (the chlorophyll "
                              "spectrum absorbs nowhere in the channel's band): nothing to invert",
                              Path(src) if src and Path(src).is_file() else None)
        c, b, db, delta = c[keep], b[keep], db[keep], delta[keep]
        w = np.log(delta)
        mono = np.concatenate([[True], w[1:] > np.maximum.accumulate(w)[:-1]])  # strictly increasing
        c, b, db, delta, w = c[mono], b[mono], db[mono], delta[mono], w[mono]
        spline = CubicHermiteSpline(w, np.log(c), delta * b / (c * -db))
        wu = np.linspace(w[0], w[-1], table_nodes)
        self._table = HermiteTable.from_nodes(wu, spline(wu), spline.derivative()(wu))
        # Where B flattens towards a floor (light that the chlorophyll spectrum does not absorb, e.g. beyond its
        # 700 nm end), y(w) turns vertical within the last cells and their cubics cannot follow it (they gave
        # C = 0 for a ratio a little above the floor): the table ends at the node before the first node it
        # misses by more than 1e-6 in ln C, and a larger δ is TOO_DARK. Node 0 is the table's first node, met
        # exactly.
        yn, _ = self._table.evaluate(w.copy())
        miss = np.flatnonzero(np.abs(yn - np.log(c)) > 1e-6)
        last = int(miss[0]) - 1 if miss.size else c.size - 1
        self.delta_lo, self.delta_hi = float(delta[0]), float(delta[last])
        self.c_lo = float(c[0])

    def _into(self, r, c_out, sig_out, reason_out, sigma) -> None:
        """One chunk: fill C (µg/L), σ_C (or NaN) and the reason code in place."""
        reason_out[...] = 0
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = self.ln_b0 - np.log(r, dtype=np.float64)
            fin = np.isfinite(r)
            reason_out[~fin] = Reason.NOT_FINITE
            reason_out[fin & (r <= 0)] = Reason.NOT_POSITIVE
            reason_out[(reason_out == 0) & (delta < 0)] = Reason.ABOVE_CLEAR_WATER
            reason_out[(reason_out == 0) & (delta > self.delta_hi)] = Reason.TOO_DARK
            ok = reason_out == 0
            main = ok & (delta >= self.delta_lo)
            d = np.where(main, delta, self.delta_lo)
            y, dydw = self._table.evaluate(np.log(d), with_slope=sigma is not None)
        cc = np.exp(y)
        low = ok & ~main  # between C = 0 and the first node: linear in δ
        cc[low] = self.c_lo * delta[low] / self.delta_lo
        cc[~ok] = np.nan
        c_out[...] = cc
        if sigma is None:
            sig_out[...] = np.nan
            return
        with np.errstate(divide="ignore", invalid="ignore"):
            sg = cc * np.abs(dydw) / d * sigma
        sg[low] = (self.c_lo / self.delta_lo * sigma if np.ndim(sigma) == 0 else
                   self.c_lo / self.delta_lo * sigma[low])
        sg[~ok] = np.nan
        sig_out[...] = sg

    def concentration(self, ratio, *, sigma_ln_ratio=None) -> Inversion:
        """C (µg/L and mol/L) per pixel from band ratios, with reasons and propagated σ (σ_ln_ratio: the
        relative 1-σ uncertainty of the ratio, scalar or array)."""

        r = np.asarray(ratio)
        flat = r.reshape(-1)
        c = np.empty(flat.size)
        sig = np.empty(flat.size)
        reason = np.empty(flat.size, dtype=np.uint8)
        s = None
        if sigma_ln_ratio is not None:
            s = np.asarray(sigma_ln_ratio, float)
            s = float(s) if s.ndim == 0 else np.broadcast_to(s, r.shape).reshape(-1)

        def work(start: int) -> None:
            sl = slice(start, min(start + CHUNK, flat.size))
            self._into(flat[sl], c[sl], sig[sl], reason[sl], s if s is None or np.ndim(s) == 0 else s[sl])

        run_bands(lambda start, _stop: work(start), flat.size, CHUNK)
        c = c.reshape(r.shape)
        return Inversion(ug_per_L_to_mol_per_L(c), c, sig.reshape(r.shape), np.full(r.shape, np.nan),
                         reason.reshape(r.shape))


"""The light on the chart: clear-sky sunlight on a level chart, a CIE illuminant, or a measured spectrum.

Sunlight. A chart lying level under a cloudless sky receives the global horizontal irradiance

    E_g(λ) = E_n(λ) cos θs + E_d(λ),

E_n the direct normal and E_d the diffuse horizontal irradiance of the Bird & Riordan (1986) clear-sky model
SPECTRL2 (:class:`camcal.water.field.ClearSky`, the model ``secchi`` uses for the lake, through
:func:`pvlib.spectrum.spectrl2`). Its uncertainty comes from the atmosphere's: the aerosol optical depth at
500 nm and the precipitable water are rarely known better than ±0.05 and ±0.5 cm on a clear day (Gueymard 2008;
AERONET climatologies), the ozone column within ±0.03 atm-cm. Each enters as one perturbed spectrum, the 1-σ
change of E_g(λ) (first order, a symmetric difference), so the covariance of E_g is Σ_k δE_k δE_kᵀ.

A named CIE illuminant (``colour.SDS_ILLUMINANTS``), a CIE daylight of a correlated colour temperature
(:func:`colour.sd_CIE_illuminant_D_series`, CIE 15:2004 §3.1) or a Planckian radiator
(:func:`colour.sd_blackbody`) gives the spectrum's shape only (``absolute`` False): the lamp in the room is not
the standard, and how far it departs is unknown unless stated (``relative_uncertainty``).

References
----------
Bird, R. E., Riordan, C. (1986). Simple solar spectral model for direct and diffuse irradiance on horizontal
and tilted planes at the Earth's surface for cloudless atmospheres. J. Climate Appl. Meteor. 25, 87-97.
CIE 15:2004 Colorimetry, 3rd ed. Gueymard, C. A. (2008). REST2: high-performance solar radiation model for
cloudless-sky irradiance, illuminance and photosynthetically active radiation. Solar Energy 82, 272-285.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from camcal.chart.targets import GRID_NM
from camcal.errors import CamcalError
from camcal.io.hashing import sha256_file
from camcal.io.manifest import read_text_file
from camcal.water.field import (
    DEFAULT_AOD_500NM,
    DEFAULT_DAY_OF_YEAR,
    DEFAULT_OZONE_ATM_CM,
    DEFAULT_PRECIPITABLE_WATER_CM,
    DEFAULT_PRESSURE_PA,
    ClearSky,
)

#: 1-σ of the atmosphere's inputs when not stated (module docstring).
AEROSOL_SIGMA = 0.05
PRECIPITABLE_WATER_SIGMA_CM = 0.5
OZONE_SIGMA_ATM_CM = 0.03
#: Largest measured-spectrum CSV, bytes.
MAX_LIGHT_CSV_BYTES = 2 * 1024 * 1024


@dataclass(frozen=True, eq=False)
class Irradiance:
    """Spectral irradiance on the chart and its uncertainty.

    Attributes
    ----------
    wavelength_nm : ndarray (n,)
        nm, increasing.
    irradiance_w_m2_nm : ndarray (n,)
        E(λ), W m⁻² nm⁻¹ when ``absolute``; otherwise a relative shape (peak 1).
    perturbations : ndarray (m, n)
        m independent 1-σ deviations of E(λ), same units (m may be 0): cov E = Σ_k δE_k δE_kᵀ.
    absolute : bool
        Whether the scale of E is known (a modelled sky or a calibrated measurement).
    source : dict
        The light's model and parameters, or the file and its SHA-256.
    """

    wavelength_nm: np.ndarray
    irradiance_w_m2_nm: np.ndarray
    perturbations: np.ndarray
    absolute: bool
    source: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        wl, e = np.asarray(self.wavelength_nm, float), np.asarray(self.irradiance_w_m2_nm, float)
        p = np.asarray(self.perturbations, float).reshape(-1, wl.size)
        if wl.ndim != 1 or wl.size < 2 or np.any(np.diff(wl) <= 0) or e.shape != wl.shape:
            raise CamcalError("irradiance needs increasing wavelengths and one value per wavelength")
        if not (np.all(np.isfinite(e)) and np.all(e >= 0) and np.any(e > 0) and np.all(np.isfinite(p))):
            raise CamcalError("irradiance must be finite, >= 0 and not all zero")
        object.__setattr__(self, "perturbations", p)

    @property
    def covariance(self) -> np.ndarray:
        """(n, n) covariance of E(λ), units²."""
        return self.perturbations.T @ self.perturbations

    @property
    def uncertainty(self) -> np.ndarray:
        """(n,) standard uncertainty of E(λ)."""
        return np.sqrt(np.sum(self.perturbations ** 2, axis=0))

    def on(self, wavelength_nm) -> Irradiance:
        """Resampled (linear interpolation) on ``wavelength_nm``, which must lie inside the spectrum's range."""
        x = np.asarray(wavelength_nm, float)
        if x[0] < self.wavelength_nm[0] - 1e-9 or x[-1] > self.wavelength_nm[-1] + 1e-9:
            raise CamcalError(f"the light's spectrum covers {self.wavelength_nm[0]:g}-{self.wavelength_nm[-1]:g} nm, "
                              f"not {x[0]:g}-{x[-1]:g} nm")
        rows = np.array([np.interp(x, self.wavelength_nm, p) for p in self.perturbations]).reshape(-1, x.size)
        return Irradiance(x, np.interp(x, self.wavelength_nm, self.irradiance_w_m2_nm), rows, self.absolute,
                          dict(self.source))


def _global(sky: ClearSky, wl: np.ndarray) -> np.ndarray:
    direct, diffuse = sky.irradiance(wl)
    return direct + diffuse


def clear_sky_irradiance(sun_zenith_deg: float, *, aerosol_optical_depth_500nm: float = DEFAULT_AOD_500NM,
                         precipitable_water_cm: float = DEFAULT_PRECIPITABLE_WATER_CM,
                         ozone_atm_cm: float = DEFAULT_OZONE_ATM_CM, pressure_Pa: float = DEFAULT_PRESSURE_PA,
                         day_of_year: int | None = None, aerosol_sigma: float = AEROSOL_SIGMA,
                         precipitable_water_sigma_cm: float = PRECIPITABLE_WATER_SIGMA_CM,
                         ozone_sigma_atm_cm: float = OZONE_SIGMA_ATM_CM, wavelength_nm=GRID_NM) -> Irradiance:
    """Global horizontal irradiance on a level chart under a clear sky, E_g = E_n cos θs + E_d (SPECTRL2).

    Parameters
    ----------
    sun_zenith_deg : float
        θs, degrees (0-89).
    aerosol_optical_depth_500nm, precipitable_water_cm, ozone_atm_cm, pressure_Pa
        SPECTRL2's atmosphere (dimensionless, cm, atm-cm, Pa); defaults those of ``secchi``
        (:mod:`camcal.water.field`).
    day_of_year : int or None
        Sets the Sun-Earth distance (±3.3 % over the year); None: unknown, day 172 is used and the source says so.
    aerosol_sigma, precipitable_water_sigma_cm, ozone_sigma_atm_cm : float
        1-σ of the atmosphere's inputs; each gives one row of :attr:`Irradiance.perturbations`.
    wavelength_nm : array
        Output grid, nm.

    Returns
    -------
    Irradiance
        W m⁻² nm⁻¹, ``absolute`` True.
    """
    wl = np.asarray(wavelength_nm, float)
    doy = DEFAULT_DAY_OF_YEAR if day_of_year is None else int(day_of_year)
    sky = ClearSky(float(sun_zenith_deg), float(aerosol_optical_depth_500nm), float(precipitable_water_cm),
                   float(ozone_atm_cm), float(pressure_Pa), doy)
    e = _global(sky, wl)
    rows = []
    for name, sigma in (("aerosol_optical_depth_500nm", aerosol_sigma),
                        ("precipitable_water_cm", precipitable_water_sigma_cm),
                        ("ozone_atm_cm", ozone_sigma_atm_cm)):
        if not sigma > 0:
            continue
        x0 = getattr(sky, name)
        h = min(float(sigma), 0.999 * x0) if x0 > 0 else float(sigma)
        lo = sky.with_(**{name: x0 - h}) if x0 - h >= 0 else sky
        hi = sky.with_(**{name: x0 + h})
        step = (x0 + h) - (x0 - h if x0 - h >= 0 else x0)
        rows.append((_global(hi, wl) - _global(lo, wl)) / step * float(sigma))
    src = {"kind": "clear_sky", "model": "SPECTRL2 (Bird & Riordan 1986, pvlib), global horizontal: "
                                         "direct x cos(zenith) + diffuse",
           **sky.describe(), "day_of_year_known": day_of_year is not None,
           "sigma": {"aerosol_optical_depth_500nm": aerosol_sigma, "precipitable_water_cm": precipitable_water_sigma_cm,
                     "ozone_atm_cm": ozone_sigma_atm_cm}}
    return Irradiance(wl, e, np.array(rows).reshape(-1, wl.size), True, src)


def _shape(values: np.ndarray) -> np.ndarray:
    return values / np.max(values)


def cie_illuminant(name: str, *, relative_uncertainty: float = 0.0, wavelength_nm=GRID_NM) -> Irradiance:
    """A CIE illuminant's shape by name: a key of ``colour.SDS_ILLUMINANTS`` (``"D65"``, ``"A"``, ``"FL2"``…),
    ``"D<CCT>"`` / ``"daylight:<CCT>"`` for a CIE daylight of that correlated colour temperature in K (4000-25000),
    or ``"blackbody:<T>"`` for a Planckian radiator of T K (1000-20000). ``relative_uncertainty`` (a fraction)
    is a 1-σ departure of the shape, fully correlated in a tilt about 550 nm (the commonest lamp error)."""
    import colour  # loads matplotlib: kept off paths that do not need it

    wl = np.asarray(wavelength_nm, float)
    text = str(name).strip()
    low = text.lower()
    shape = colour.SpectralShape(float(wl[0]), float(wl[-1]), float(wl[1] - wl[0]))
    key = next((k for k in colour.SDS_ILLUMINANTS if k.lower() == low), None)
    if key is None:
        m = re.fullmatch(r"(?:daylight:|d)(\d+(?:\.\d*)?)", low)
        if m:
            return daylight(float(m.group(1)), wavelength_nm=wl, relative_uncertainty=relative_uncertainty)
        m = re.fullmatch(r"blackbody:(\d+(?:\.\d*)?)", low)
        if m:
            return blackbody(float(m.group(1)), wavelength_nm=wl, relative_uncertainty=relative_uncertainty)
        raise CamcalError(f"unknown illuminant {name!r}; use a CIE name (D65, A, FL2…), D<CCT> or blackbody:<K>")
    sd = colour.SDS_ILLUMINANTS[key].copy().align(shape)
    e = np.interp(wl, np.asarray(sd.wavelengths, float), np.asarray(sd.values, float))
    return _relative(e, wl, relative_uncertainty, {"kind": "cie", "name": key,
                                                   "library": f"colour-science {colour.__version__}"})


def _relative(e: np.ndarray, wl: np.ndarray, rel: float, src: dict) -> Irradiance:
    if not (np.isfinite(rel) and 0 <= rel < 1):
        raise CamcalError("illuminant relative uncertainty must lie in 0-1")
    e = _shape(np.clip(e, 0.0, None))
    rows = [rel * e * (wl - 550.0) / 200.0] if rel > 0 else []
    return Irradiance(wl, e, np.array(rows).reshape(-1, wl.size), False,
                      {**src, "relative_uncertainty": rel})


def daylight(cct_K: float, *, wavelength_nm=GRID_NM, relative_uncertainty: float = 0.0) -> Irradiance:
    """CIE daylight of correlated colour temperature ``cct_K`` (4000-25000 K), shape only (CIE 15:2004 §3.1)."""
    import colour

    if not 4000 <= cct_K <= 25000:
        raise CamcalError(f"CIE daylight is defined for 4000-25000 K, not {cct_K:g} K")
    wl = np.asarray(wavelength_nm, float)
    xy = colour.temperature.CCT_to_xy_CIE_D(float(cct_K))
    sd = colour.sd_CIE_illuminant_D_series(xy)
    e = np.interp(wl, np.asarray(sd.wavelengths, float), np.asarray(sd.values, float))
    return _relative(e, wl, relative_uncertainty, {"kind": "daylight", "cct_K": float(cct_K),
                                                   "model": "CIE D series (colour.sd_CIE_illuminant_D_series)"})


def blackbody(temperature_K: float, *, wavelength_nm=GRID_NM, relative_uncertainty: float = 0.0) -> Irradiance:
    """A Planckian radiator of ``temperature_K`` (1000-20000 K), shape only (Planck's law, colour.sd_blackbody)."""
    import colour

    if not 1000 <= temperature_K <= 20000:
        raise CamcalError(f"black body temperature must lie in 1000-20000 K, not {temperature_K:g} K")
    wl = np.asarray(wavelength_nm, float)
    shape = colour.SpectralShape(float(wl[0]), float(wl[-1]), float(wl[1] - wl[0]))
    sd = colour.sd_blackbody(float(temperature_K), shape)
    e = np.interp(wl, np.asarray(sd.wavelengths, float), np.asarray(sd.values, float))
    return _relative(e, wl, relative_uncertainty, {"kind": "blackbody", "temperature_K": float(temperature_K),
                                                   "model": "Planck (colour.sd_blackbody)"})


def read_irradiance_csv(path: str | Path, *, absolute: bool = False, wavelength_nm=GRID_NM) -> Irradiance:
    """A measured spectrum: CSV with ``wavelength_nm``, ``irradiance_w_m2_nm`` and optionally
    ``u_irradiance_w_m2_nm`` (1-σ, independent per wavelength); ``#`` lines are comments. ``absolute``: the
    values are calibrated W m⁻² nm⁻¹ (otherwise a shape). Resampled on ``wavelength_nm``, which the file must
    cover.

    Raises
    ------
    CamcalError
        One line naming the file and the problem.
    """
    path = Path(path)
    text = read_text_file(path, "illuminant spectrum CSV", MAX_LIGHT_CSV_BYTES)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    need = ("wavelength_nm", "irradiance_w_m2_nm")
    if any(n not in header for n in need):
        raise CamcalError(f"illuminant spectrum CSV needs columns {', '.join(need)} "
                          f"(header is {','.join(header)[:120]})", path)
    try:
        v = np.array([[float(c) for c in ln.split(",")] for ln in lines[1:]], dtype=float)
    except ValueError:
        raise CamcalError("illuminant spectrum CSV: a row is not numbers", path) from None
    if v.ndim != 2 or v.shape[0] < 2 or v.shape[1] != len(header) or not np.all(np.isfinite(v)):
        raise CamcalError("illuminant spectrum CSV needs at least two complete rows of finite numbers", path)
    wl, e = v[:, header.index(need[0])], v[:, header.index(need[1])]
    u = v[:, header.index("u_irradiance_w_m2_nm")] if "u_irradiance_w_m2_nm" in header else np.zeros_like(e)
    if np.any(np.diff(wl) <= 0) or np.any(e < 0) or not np.any(e > 0) or np.any(u < 0):
        raise CamcalError("illuminant spectrum CSV: wavelengths must increase, irradiance and its uncertainty be "
                          ">= 0 (not all 0)", path)
    x = np.asarray(wavelength_nm, float)
    if x[0] < wl[0] or x[-1] > wl[-1]:
        raise CamcalError(f"illuminant spectrum CSV covers {wl[0]:g}-{wl[-1]:g} nm; {x[0]:g}-{x[-1]:g} nm needed",
                          path)
    ex, ux = np.interp(x, wl, e), np.interp(x, wl, u)
    rows = np.diag(ux)[ux > 0] if np.any(ux > 0) else np.zeros((0, x.size))
    if not absolute:
        peak = ex.max()
        ex, rows = ex / peak, rows / peak
    return Irradiance(x, ex, rows, bool(absolute), {"kind": "measured", "file": str(path),
                                                    "sha256": sha256_file(path), "absolute": bool(absolute)})

"""Spectral helpers shared by the synthetic camera and the spectral stage.

Spectra are plain float arrays on a wavelength grid in nm; conversion to and
from colour-science types happens at the edges. Spectral radiance is in
W m^-2 sr^-1 nm^-1 throughout.

References
----------
Darrodi, M. M., Finlayson, G., Goodman, T., Mackiewicz, M. (2015). Reference
data set for camera spectral sensitivity estimation. JOSA A 32(3), 381-391
(the NPL-measured curves shipped by colour-science as
``colour.MSDS_CAMERA_SENSITIVITIES``).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from camcal.errors import CamcalError

#: Default wavelength grid of the synthetic camera, nm.
WAVELENGTHS_NM = np.arange(380.0, 781.0, 1.0)

CAMERAS = {"nikon-d5100": "Nikon 5100 (NPL)", "sigma-sd-merrill": "Sigma SDMerill (NPL)"}

H_PLANCK = 6.62607015e-34  # J s
C_LIGHT = 299792458.0  # m s^-1
K_BOLTZMANN = 1.380649e-23  # J K^-1


def camera_sensitivities(name: str, wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> np.ndarray:
    """Measured relative spectral sensitivities (R, G, B), shape (3, n), on ``wavelengths_nm``.

    ``name`` is a key of :data:`CAMERAS` or of ``colour.MSDS_CAMERA_SENSITIVITIES``.
    Outside the measured range the curves are zero (no constant extrapolation).
    Each curve peaks at 1 as published.
    """
    import colour  # lazy: colour-science takes ~1-2 s to import (benchmarks/RESULTS.md, Start-up)

    key = CAMERAS.get(name, name)
    if key not in colour.MSDS_CAMERA_SENSITIVITIES:
        raise CamcalError(
            f"unknown camera sensitivity set {name!r}; known: {', '.join(CAMERAS)} "
            f"or {', '.join(colour.MSDS_CAMERA_SENSITIVITIES)}"
        )
    msds = colour.MSDS_CAMERA_SENSITIVITIES[key]
    wl = np.asarray(msds.wavelengths, float)
    vals = np.asarray(msds.values, float)
    out = np.empty((3, wavelengths_nm.size))
    for i in range(3):
        # cubic (Sprague-like smoothness is not needed for a simulator); zero outside
        spline = CubicSpline(wl, vals[:, i], extrapolate=False)
        y = spline(wavelengths_nm)
        out[i] = np.clip(np.nan_to_num(y, nan=0.0), 0.0, None)
    return out


def gaussian_line(center_nm: float, fwhm_nm: float, wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> np.ndarray:
    """A Gaussian line of unit integral (nm^-1) on the grid: a monochromator's slit function."""
    sigma = fwhm_nm / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    g = np.exp(-0.5 * ((wavelengths_nm - center_nm) / sigma) ** 2)
    area = np.trapezoid(g, wavelengths_nm)
    if area <= 0:
        raise CamcalError(f"line at {center_nm} nm (FWHM {fwhm_nm} nm) lies outside the wavelength grid")
    return g / area


def planck_radiance(temperature_k: float, wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> np.ndarray:
    """Black-body spectral radiance in W m^-2 sr^-1 nm^-1 (Planck's law)."""
    lam = wavelengths_nm * 1e-9
    b = 2 * H_PLANCK * C_LIGHT**2 / lam**5 / np.expm1(H_PLANCK * C_LIGHT / (lam * K_BOLTZMANN * temperature_k))
    return b * 1e-9


def photon_energy_j(wavelengths_nm: np.ndarray) -> np.ndarray:
    """Energy of one photon, J, at each wavelength."""
    return H_PLANCK * C_LIGHT / (np.asarray(wavelengths_nm) * 1e-9)


def band_integral(spectrum: np.ndarray, wavelengths_nm: np.ndarray) -> np.ndarray:
    """Trapezoidal integral over wavelength along the last axis."""
    return np.trapezoid(spectrum, wavelengths_nm, axis=-1)

"""Spectral helpers shared by the synthetic camera and the spectral stage.

Spectra are plain float arrays on a wavelength grid in nm; conversion to and
from colour-science types happens at the edges. Spectral radiance is in
W m⁻² sr⁻¹ nm⁻¹ throughout.

colour-science is imported inside the functions that use it, as matplotlib is: ``import colour`` (or any
``colour.*`` submodule) runs ``colour/__init__.py``, which imports ``colour.plotting`` and with it matplotlib
(about 0.2 s, and 1-3 s for colour itself), so a module-level import would load matplotlib on every path that
reads a spectrum, including ``camcal calibrate``, which ``tests/test_structure.py`` keeps free of it.

References
----------
Darrodi, M. M., Finlayson, G., Goodman, T., Mackiewicz, M. (2015). Reference
data set for camera spectral sensitivity estimation. JOSA A 32(3), 381-391
(the NPL-measured curves shipped by colour-science as
``colour.MSDS_CAMERA_SENSITIVITIES``).
"""

from __future__ import annotations

import numpy as np
import scipy.constants
from scipy.interpolate import CubicSpline

from camcal.errors import CamcalError

#: Default wavelength grid of the synthetic camera, nm.
WAVELENGTHS_NM = np.arange(380.0, 781.0, 1.0)

CAMERAS = {"nikon-d5100": "Nikon 5100 (NPL)", "sigma-sd-merrill": "Sigma SDMerill (NPL)"}

H_PLANCK = scipy.constants.h  # J s
C_LIGHT = scipy.constants.c  # m s⁻¹
K_BOLTZMANN = scipy.constants.k  # J K⁻¹
C1_W_M2 = 2 * np.pi * H_PLANCK * C_LIGHT**2  # first radiation constant, W m^2
C2_M_K = H_PLANCK * C_LIGHT / K_BOLTZMANN  # second radiation constant, m K

FWHM_TO_SIGMA = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))
"""Standard deviation of a Gaussian per unit of its full width at half maximum."""


def camera_sensitivities(name: str, wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> np.ndarray:
    """Measured relative spectral sensitivities (R, G, B), shape (3, n), on ``wavelengths_nm``.

    ``name`` is a key of :data:`CAMERAS` or of ``colour.MSDS_CAMERA_SENSITIVITIES``.
    Outside the measured range the curves are zero (no constant extrapolation).
    Each curve peaks at 1 as published.
    """
    import colour  # loads matplotlib: kept off paths that do not plot

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
    """A Gaussian line of unit integral (nm⁻¹) on a regular grid: a monochromator's slit function.

    The line is ``colour.sd_gaussian(center_nm, fwhm_nm, method="FWHM")`` on the grid's
    :class:`colour.SpectralShape`, divided by its trapezoidal integral over the grid.
    """
    import colour  # loads matplotlib: kept off paths that do not plot

    wl = np.asarray(wavelengths_nm, float)
    step = np.diff(wl)
    if wl.ndim != 1 or wl.size < 2 or not np.allclose(step, step[0], rtol=1e-9, atol=0.0):
        raise CamcalError("a Gaussian line needs a regular 1-D wavelength grid")
    shape = colour.SpectralShape(float(wl[0]), float(wl[-1]), float(step[0]))
    g = np.asarray(colour.sd_gaussian(center_nm, fwhm_nm, shape=shape, method="FWHM").values, float)
    area = np.trapezoid(g, wl)
    if area <= 0:
        raise CamcalError(f"line at {center_nm} nm (FWHM {fwhm_nm} nm) lies outside the wavelength grid")
    return g / area


def planck_radiance(temperature_k: float, wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> np.ndarray:
    """Black-body spectral radiance in W m⁻² sr⁻¹ nm⁻¹ (Planck's law).

    ``colour.colorimetry.planck_law`` (W sr⁻¹ m⁻² per m of wavelength, hence the 1e-9) with the exact SI
    radiation constants c1 = 2πhc² and c2 = hc/k rather than its CIE 15 defaults (c2 = 1.4388e-2 m K, the
    ITS-90 value, 1.6e-5 larger).
    """
    from colour.colorimetry import planck_law  # loads matplotlib: kept off paths that do not plot

    wl = np.asarray(wavelengths_nm, float)
    b = planck_law(wl.ravel() * 1e-9, float(temperature_k), c1=C1_W_M2, c2=C2_M_K)
    return np.reshape(b, wl.shape) * 1e-9


def photon_energy_j(wavelengths_nm: np.ndarray) -> np.ndarray:
    """Energy of one photon, J, at each wavelength."""
    return H_PLANCK * C_LIGHT / (np.asarray(wavelengths_nm) * 1e-9)


def band_integral(spectrum: np.ndarray, wavelengths_nm: np.ndarray) -> np.ndarray:
    """Trapezoidal integral over wavelength along the last axis."""
    return np.trapezoid(spectrum, wavelengths_nm, axis=-1)

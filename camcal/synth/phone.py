"""A phone-like camera for the synthetic world: measured small-sensor curves, the camera, its scenes.

The spectral sensitivities are those of real phone-class sensors (Sony IMX219, OmniVision OV5647: 1.1-1.4 µm
pixels, the sensors of phone camera modules and of the Raspberry Pi cameras), none of them in the bundled
52-camera library, so an estimator that learnt its basis from that library meets them as a new camera.
The shipped tables (``calibration_data/camera_curves/phone/``) are each manufacturer's published relative
quantum efficiency of the bare sensor with its Bayer filters, 400-700 nm. A phone module adds a UV-IR-cut
filter in front of the sensor; :func:`phone_sensitivities` models it as two logistic edges (a typical
phone hot mirror passes half at 650 nm and cuts to ~10 % within ~15 nm) and holds the sensor's QE below
400 nm at its 400 nm value (not measured there), so that the product falls smoothly to zero outside the
filter's pass band.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camcal.data import read_bundled_table
from camcal.errors import CamcalError
from camcal.reference_spectra import WAVELENGTHS_NM

PHONE_SENSORS: dict[str, str] = {
    "imx219": "camera_curves/phone/imx219_qe_400_700_1.csv",
    "ov5647": "camera_curves/phone/ov5647_qe_400_700_1.csv",
}
"""Shipped phone-class sensor curves: key → file in ``calibration_data``."""

SENSOR_NAMES: dict[str, str] = {"imx219": "Sony IMX219", "ov5647": "OmniVision OV5647"}


@dataclass(frozen=True)
class PhoneCurves:
    """Relative spectral sensitivities of a phone camera (sensor × UV-IR-cut filter).

    ``r``, ``g``, ``b`` are dimensionless on ``wavelength_nm`` (nm), each peaking at 1;
    ``channel_peaks`` are the sensor's published peak QE of R, G, B relative to the largest
    (the ratio between channels that the per-channel normalisation removes).
    """

    sensor: str
    wavelength_nm: np.ndarray
    r: np.ndarray
    g: np.ndarray
    b: np.ndarray
    channel_peaks: tuple[float, float, float]
    uv_cut_nm: float | None
    ir_cut_nm: float | None
    source: str

    @property
    def rgb(self) -> np.ndarray:
        """(3, n) R, G, B."""
        return np.stack([self.r, self.g, self.b])


def cut_filter_transmittance(
    wavelengths_nm: np.ndarray, uv_cut_nm: float | None = 400.0, ir_cut_nm: float | None = 650.0,
    uv_width_nm: float = 5.0, ir_width_nm: float = 7.0,
) -> np.ndarray:
    """Transmittance (0..1) of a phone's UV-IR-cut filter: logistic edges, 0.5 at ``uv_cut_nm`` and ``ir_cut_nm``.

    T(λ) = 1/(1 + exp((λ_uv − λ)/w_uv)) · 1/(1 + exp((λ − λ_ir)/w_ir)); an edge of None is absent.
    With w_ir = 7 nm the IR edge falls from 90 % to 10 % over 31 nm (4.4 w), as phone hot mirrors do.
    """
    wl = np.asarray(wavelengths_nm, float)
    t = np.ones_like(wl)
    if uv_cut_nm is not None:
        t = t / (1.0 + np.exp((uv_cut_nm - wl) / uv_width_nm))
    if ir_cut_nm is not None:
        t = t / (1.0 + np.exp((wl - ir_cut_nm) / ir_width_nm))
    return t


def sensor_qe_table(sensor: str = "imx219") -> tuple[np.ndarray, np.ndarray]:
    """The shipped table of ``sensor``: wavelength (nm) and (3, n) relative QE of R, G, B (fraction, as published)."""
    if sensor not in PHONE_SENSORS:
        raise CamcalError(f"unknown phone sensor {sensor!r}; choose from {', '.join(PHONE_SENSORS)}")
    header, values = read_bundled_table(PHONE_SENSORS[sensor])
    if header != ["wavelength_nm", "red_qe", "green_qe", "blue_qe"]:
        raise CamcalError(f"shipped table {PHONE_SENSORS[sensor]} has unexpected columns {header}")
    return values[:, 0], np.clip(values[:, 1:].T / 100.0, 0.0, None)


def phone_sensitivities(
    sensor: str = "imx219",
    wavelengths_nm: np.ndarray = WAVELENGTHS_NM,
    *,
    uv_cut_nm: float | None = 400.0,
    ir_cut_nm: float | None = 650.0,
) -> PhoneCurves:
    """Measured phone-sensor curves through a modelled UV-IR-cut filter, on ``wavelengths_nm``.

    The sensor's QE (linear interpolation of the 1 nm table) is held at its end values outside
    400-700 nm and multiplied by :func:`cut_filter_transmittance`; each channel is then divided by
    its peak. With both edges None the result is the bare sensor, zero outside 400-700 nm.

    Parameters
    ----------
    sensor
        A key of :data:`PHONE_SENSORS` (``"imx219"``, ``"ov5647"``).
    wavelengths_nm
        Output grid, nm (default the camcal grid 380-780 nm / 1 nm).
    uv_cut_nm, ir_cut_nm
        Half-transmission wavelengths of the filter's edges, nm (None: that edge absent).
    """
    wl_tab, qe = sensor_qe_table(sensor)
    wl = np.asarray(wavelengths_nm, float)
    bare = uv_cut_nm is None and ir_cut_nm is None
    out = np.empty((3, wl.size))
    for i in range(3):
        if bare:
            out[i] = np.interp(wl, wl_tab, qe[i], left=0.0, right=0.0)
        else:
            out[i] = np.interp(wl, wl_tab, qe[i]) * cut_filter_transmittance(wl, uv_cut_nm, ir_cut_nm)
    peaks = out.max(axis=1)
    if np.any(peaks <= 0):
        raise CamcalError(f"phone sensor {sensor!r} has no response on the requested grid")
    rel = peaks / peaks.max()
    out = out / peaks[:, None]
    return PhoneCurves(
        sensor=sensor, wavelength_nm=wl, r=out[0], g=out[1], b=out[2],
        channel_peaks=(float(rel[0]), float(rel[1]), float(rel[2])),
        uv_cut_nm=uv_cut_nm, ir_cut_nm=ir_cut_nm,
        source=f"calibration_data/{PHONE_SENSORS[sensor]} ({SENSOR_NAMES[sensor]}, manufacturer's published QE)",
    )

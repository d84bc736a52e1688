"""Exposure normalisation (seed §2.1): signal per unit ISO·t/N², relative to a reference setting.

The photo-electron signal of a linear sensor is proportional to t/N² (exposure
time over the squared f-number: the image-plane irradiance of a scene falls as
1/N²), and the DN per electron is proportional to the ISO setting. So

    relative exposure  x = (ISO · t / N²) / (ISO_ref / N_ref²)         [s]

is the exposure time *at the reference setting* (ISO_ref, N_ref) that gives
the same signal, and ``signal_dn / x`` is the DN rate (DN s⁻¹) at the reference
setting. This is the one function every stage uses.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from camcal.frame import Exposure


def relative_exposure(
    exposure_s: float, iso: float, f_number: float, reference_iso: float, reference_f_number: float
) -> float:
    """x = (ISO·t/N²) / (ISO_ref/N_ref²), in seconds at the reference setting."""
    return float(iso * exposure_s / f_number**2 / (reference_iso / reference_f_number**2))


def frame_relative_exposure(
    exposure: Exposure, reference_iso: float, reference_f_number: float, path: str | Path | None = None
) -> float:
    """:func:`relative_exposure` of a frame's metadata; names the file and field when one is missing."""
    return relative_exposure(
        exposure.require("exposure_s", path),
        exposure.require("iso", path),
        exposure.require("f_number", path),
        reference_iso,
        reference_f_number,
    )


def normalise(signal_dn: np.ndarray | float, x_s: float) -> np.ndarray | float:
    """Signal (DN above dark) divided by the relative exposure: DN s⁻¹ at the reference setting."""
    return np.asarray(signal_dn) / x_s if isinstance(signal_dn, np.ndarray) else signal_dn / x_s

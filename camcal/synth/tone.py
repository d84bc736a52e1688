"""Tone curves of the synthetic JPEG pipeline (and their inverses).

References
----------
IEC 61966-2-1:1999, *Default RGB colour space - sRGB* (the sRGB transfer function).
"""

from __future__ import annotations

import numpy as np

from camcal.errors import CamcalError


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """sRGB opto-electronic transfer function, linear [0, 1] -> encoded [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def srgb_decode(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`srgb_encode`."""
    v = np.clip(v, 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, np.power((v + 0.055) / 1.055, 2.4))


def apply_tone(x: np.ndarray, tone: str, gamma: float = 1 / 2.2) -> np.ndarray:
    """Encode linear values in [0, 1] with ``tone`` (``"srgb"``, ``"power"`` or ``"linear"``)."""
    if tone == "srgb":
        return srgb_encode(x)
    if tone == "power":
        return np.power(np.clip(x, 0.0, 1.0), gamma)
    if tone == "linear":
        return np.clip(x, 0.0, 1.0)
    raise CamcalError(f"unknown tone curve {tone!r}; choose srgb, power or linear")

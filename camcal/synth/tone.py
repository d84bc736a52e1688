"""Tone curves of the synthetic JPEG pipeline.

References
----------
IEC 61966-2-1:1999, *Default RGB colour space - sRGB* (the sRGB transfer function).
"""

from __future__ import annotations

import numpy as np

from camcal.errors import CamcalError


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """sRGB opto-electronic transfer function, linear [0, 1] -> encoded [0, 1] (``colour.cctf_encoding``)."""
    import colour  # loads matplotlib: kept off paths that do not plot

    return colour.cctf_encoding(np.clip(x, 0.0, 1.0), function="sRGB")


def apply_tone(x: np.ndarray, tone: str, gamma: float = 1 / 2.2) -> np.ndarray:
    """Encode linear values in [0, 1] with ``tone`` (``"srgb"``, ``"power"`` or ``"linear"``)."""
    if tone == "srgb":
        return srgb_encode(x)
    if tone == "power":
        return np.power(np.clip(x, 0.0, 1.0), gamma)
    if tone == "linear":
        return np.clip(x, 0.0, 1.0)
    raise CamcalError(f"unknown tone curve {tone!r}; choose srgb, power or linear")

"""Block means and downsampling of a plane (shared by the flat-field fit and the plots).
"""

from __future__ import annotations

import numpy as np

from camcal.errors import CamcalError

DEFAULT_BLOCKS = 64
"""Target number of blocks along the long side of the downsampled plane."""


def auto_downsample(shape: tuple[int, int], blocks: int = DEFAULT_BLOCKS) -> int:
    """Block size giving about ``blocks`` blocks along the long side (at least 1)."""
    return max(1, int(max(shape)) // blocks)


def block_mean(plane: np.ndarray, factor: int, mask: np.ndarray | None = None):
    """Mean of ``factor`` x ``factor`` blocks (remainder rows/columns dropped), ignoring masked pixels.

    Returns
    -------
    mean : (hb, wb) float64 (NaN where every pixel of a block is masked)
    x, y : (hb, wb) plane coordinates of the block centres, plane pixels
    """
    h, w = plane.shape
    hb, wb = h // factor, w // factor
    if hb < 1 or wb < 1:
        raise CamcalError(f"downsample factor {factor} is larger than the plane ({h}x{w})")
    a = np.asarray(plane[: hb * factor, : wb * factor], np.float64).reshape(hb, factor, wb, factor)
    if mask is None:
        mean = a.mean(axis=(1, 3))
    else:
        good = ~np.asarray(mask[: hb * factor, : wb * factor], bool).reshape(hb, factor, wb, factor)
        n = good.sum(axis=(1, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(good, a, 0.0).sum(axis=(1, 3)) / n
        mean[n == 0] = np.nan
    centre = (factor - 1) / 2.0
    y, x = np.mgrid[0:hb, 0:wb].astype(np.float64) * factor + centre
    return mean, x, y

"""The 24 patches' signals of one chart photo: robust means and the covariance of each mean.

Each patch is read over the central :data:`PATCH_FRACTION` of its cell of the swatch grid (a square in chart
coordinates, mapped through the chart's homography: :mod:`camcal.chart.detect`), on the photo's own planes:
the half-resolution CFA planes R, G1, G2, B of a Bayer RAW (black level subtracted; one plane pixel is the
2x2 cell whose centre maps into the patch), the linear RAW's R, G, B, or a processed image's R, G, B in the
file's DN. Pixels at the white level in any channel, and pixels a mask marks, are excluded; the remaining
pixels are clipped robustly (5 normalised MAD from the median in every channel) and averaged. The covariance
of the mean is the pixels' sample covariance over n (all channels of one pixel are one sample: shot noise,
read noise, the chart's texture and PRNU all enter, conservatively). A patch with more than
:data:`MAX_SATURATED_FRACTION` of its pixels saturated is flagged: its mean is biased low and a fit leaves it
out.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import median_abs_deviation

from camcal.chart.detect import COLUMNS, N_PATCHES, ChartLocation
from camcal.errors import CamcalError
from camcal.frame import Frame

#: Side of the sampled square as a fraction of its cell's side (the patch's central part, clear of its edge).
PATCH_FRACTION = 0.5
#: A patch with more saturated pixels than this fraction is flagged as saturated.
MAX_SATURATED_FRACTION = 0.002
#: Fewest usable pixels per patch.
MIN_PIXELS = 16


@dataclass(frozen=True)
class PatchSignals:
    """Per-patch signals of one photo.

    channels : plane names (R, G1, G2, B; or R, G, B).
    mean_dn : (24, C) robust mean, DN above the black level (RAW) or the file's DN (processed).
    cov_dn2 : (24, C, C) covariance of the mean, DN².
    n_pixels : (24,) pixels averaged.
    saturated : (24,) True where more than :data:`MAX_SATURATED_FRACTION` of the patch's pixels are saturated.
    centre_px : (24, 2) the patches' centres, full-resolution photo pixels (x, y).
    white_level_dn : the level treated as saturated, DN (above the black level for RAW).
    """

    channels: tuple[str, ...]
    mean_dn: np.ndarray
    cov_dn2: np.ndarray
    n_pixels: np.ndarray
    saturated: np.ndarray
    centre_px: np.ndarray
    white_level_dn: float
    notes: tuple[str, ...] = field(default_factory=tuple)

    def sem_dn(self) -> np.ndarray:
        """(24, C) standard error of each mean, DN."""
        return np.sqrt(np.einsum("kcc->kc", self.cov_dn2))


def _plane_grid(frame: Frame) -> tuple[np.ndarray, float, float]:
    """(C, h, w) planes (black subtracted for RAW), the photo pixels per plane pixel, the white level above black."""
    planes = frame.planes(np.float32)
    if frame.kind == "raw":
        black = frame.black_vector().astype(np.float32)
        planes -= black
        white = float(frame.white_level_dn) - float(black.max())
    else:
        white = float(frame.white_level_dn)
    step = 2.0 if frame.layout == "bayer" else 1.0
    return planes, step, white


def sample_patches(frame: Frame, location: ChartLocation, *, mask: np.ndarray | None = None,
                   fraction: float = PATCH_FRACTION) -> PatchSignals:
    """Robust mean and covariance of the mean of every patch (module docstring).

    ``mask``: optional boolean (H, W) at full resolution, True where pixels must not be used.
    """
    planes, step, white = _plane_grid(frame)
    if frame.kind == "raw":
        sat = frame.planes(np.float32) >= np.float32(frame.white_level_dn)
    else:
        sat = planes >= np.float32(frame.white_level_dn)
    nc, ph, pw = planes.shape
    h = location.homography()
    hinv = np.linalg.inv(h)
    corners = location.corners_px
    x0 = max(int(np.floor(corners[:, 0].min() / step)) - 1, 0)
    x1 = min(int(np.ceil(corners[:, 0].max() / step)) + 1, pw)
    y0 = max(int(np.floor(corners[:, 1].min() / step)) - 1, 0)
    y1 = min(int(np.ceil(corners[:, 1].max() / step)) + 1, ph)
    if x1 - x0 < COLUMNS or y1 - y0 < 4:
        raise CamcalError("the chart lies outside the photo", frame.path)
    jj, ii = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1))
    xs = (jj + 0.5) * step  # the plane pixel's centre in photo pixels
    ys = (ii + 0.5) * step
    p = hinv @ np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    u, v = p[0] / p[2], p[1] / p[2]
    col, row = np.floor(u), np.floor(v)
    fu, fv = u - col, v - row
    half = fraction / 2
    inside = (np.abs(fu - 0.5) <= half) & (np.abs(fv - 0.5) <= half) & (col >= 0) & (col < COLUMNS) & (row >= 0) \
        & (row < 4)
    patch = np.where(inside, row * COLUMNS + col, -1).astype(int).reshape(xs.shape)
    window = (slice(y0, y1), slice(x0, x1))
    vals = planes[:, window[0], window[1]]
    bad = sat[:, window[0], window[1]].any(0)
    if mask is not None:
        m = np.asarray(mask, bool)
        if m.shape != frame.shape:
            raise CamcalError(f"mask is {m.shape[1]}x{m.shape[0]}, the photo {frame.shape[1]}x{frame.shape[0]}")
        if step == 2:
            m = m[: ph * 2, : pw * 2].reshape(ph, 2, pw, 2).any(axis=(1, 3))
        bad |= m[window[0], window[1]]
    mean = np.full((N_PATCHES, nc), np.nan)
    cov = np.full((N_PATCHES, nc, nc), np.nan)
    npix = np.zeros(N_PATCHES, int)
    saturated = np.zeros(N_PATCHES, bool)
    for k in range(N_PATCHES):
        sel = patch == k
        total = int(sel.sum())
        if total == 0:
            raise CamcalError(f"patch {k + 1} covers no pixel: the chart is too small in the photo", frame.path)
        nsat = int((sel & bad).sum())
        saturated[k] = nsat > MAX_SATURATED_FRACTION * total
        use = sel & ~bad
        x = vals[:, use].astype(np.float64).T  # (n, C)
        if x.shape[0] >= MIN_PIXELS:
            med = np.median(x, axis=0)
            mad = median_abs_deviation(x, axis=0, scale="normal")
            keep = np.all(np.abs(x - med) <= 5.0 * np.maximum(mad, 1e-9), axis=1)
            x = x[keep]
        if x.shape[0] < MIN_PIXELS:
            saturated[k] = True
            continue
        mean[k] = x.mean(0)
        cov[k] = np.atleast_2d(np.cov(x.T, ddof=1)) / x.shape[0]
        npix[k] = x.shape[0]
    notes = []
    if saturated.any():
        notes.append("saturated patches (left out of the fit): " + ", ".join(str(k + 1) for k in np.flatnonzero(
            saturated)))
    return PatchSignals(tuple(frame.channel_names), mean, cov, npix, saturated, location.patch_centres_px(), white,
                        tuple(notes))

"""Each pixel's own lamp geometry (seed §4): the lamp model inverted per pixel position, not at the disk centre.

A point P of the disk at horizontal distance X' from the lamp's foot sees the lamp along the refracted ray that
reaches it (:func:`camcal.water.models.lamp_angle_reaching`); its ratio is R = K(X') e^(−s(X') τ). Where a
pixel lies on the disk plane is given by :class:`PixelGeometry` (the scale on the disk, the disk centre and the
direction of the lamp in the image).

- Narrowband: K and s are tabulated on 48 distances spanning the image (Chebyshev nodes) and interpolated per
  pixel (cubic spline); the pixel's ratio is mapped to the ratio the disk centre would show for the same τ,
  r_c = K_c (r/K')^(s_c/s') (exact for a single exponential), and inverted by the centre's model, so the
  reason codes and the table are those of :func:`camcal.water.invert.invert_ratio`; σ_ln r_c = (s_c/s') σ_ln r.
- Band-aware: a :class:`camcal.water.band.BandInverse` is built for the lamp geometry at each of ``nodes``
  distances (uniform), every pixel is inverted by the two bracketing ones and C interpolated linearly in X'.

References
----------
Seed (Zaman 2018) §4; docs/water.md ("The lamp over a tank").
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import CubicSpline

from camcal.errors import CamcalError
from camcal.water.invert import Inversion, invert_ratio
from camcal.water.models import LampModel, lamp_angle_reaching
from camcal.water.units import mol_per_L_to_ug_per_L

#: Chebyshev nodes of the narrowband K(X'), s(X') tables.
NARROW_NODES = 48


@dataclass(frozen=True)
class PixelGeometry:
    """Where the image's pixels lie on the disk plane.

    metres_per_pixel : size of one image pixel on the disk plane, m (camera at nadir).
    centre_px : (x, y) of the disk centre in image pixels (x right, y down).
    lamp_direction_deg : direction in the image from the disk centre toward the lamp's foot, degrees from +x
        toward +y (0: the lamp is to the right, 90: below, 180: to the left).
    """

    metres_per_pixel: float
    centre_px: tuple[float, float]
    lamp_direction_deg: float = 180.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.metres_per_pixel) and 0 < self.metres_per_pixel < 1):
            raise CamcalError(f"pixel size on the disk must be in (0, 1) m, got {self.metres_per_pixel!r}")

    def distances_m(self, shape_hw: tuple[int, int], lamp: LampModel, depth_m: float) -> np.ndarray:
        """X', the horizontal distance of each pixel's disk point from the lamp's foot, m."""
        h, w = shape_hw
        yy, xx = np.mgrid[0:h, 0:w].astype(float)
        u = (xx - self.centre_px[0]) * self.metres_per_pixel
        v = (yy - self.centre_px[1]) * self.metres_per_pixel
        phi = np.radians(self.lamp_direction_deg)
        away = -(u * np.cos(phi) + v * np.sin(phi))  # along the line from the lamp's foot through the centre
        side = -u * np.sin(phi) + v * np.cos(phi)
        return np.hypot(float(lamp.horizontal_offset_m(depth_m)) + away, side)

    def invert(self, ratio, model, depth_m: float, sigma_ln_ratio=None) -> Inversion:
        """:func:`invert_per_pixel` with this geometry (what :func:`camcal.water.invert.invert_images` calls)."""
        return invert_per_pixel(ratio, model, depth_m, self, sigma_ln_ratio=sigma_ln_ratio)


def _lamp_of(model) -> LampModel:
    lamp = getattr(model, "geometry", model)
    if not isinstance(lamp, LampModel):
        raise CamcalError("per-pixel geometry is for the lamp model (--water-model lamp)")
    return lamp


def _at(lamp: LampModel, depth_m: float, x_m: float) -> LampModel:
    return replace(lamp, lamp_angle_rad=lamp_angle_reaching(lamp.height_m, depth_m, x_m, lamp.n_water))


def invert_per_pixel(ratio, model, depth_m: float, geometry: PixelGeometry, *, sigma_ln_ratio=None,
                     nodes: int = 12) -> Inversion:
    """C per pixel with each pixel's own lamp geometry (see the module docstring).

    ``model`` is a :class:`LampModel` (narrowband) or a band model whose geometry is one; ``ratio`` an (H, W)
    image of submerged over dry radiance; ``sigma_ln_ratio`` its relative 1-σ (scalar or image) or None.
    """
    r = np.asarray(ratio, dtype=float)
    if r.ndim != 2:
        raise CamcalError("per-pixel geometry needs a 2-D ratio image")
    lamp = _lamp_of(model)
    d = float(depth_m)
    x = geometry.distances_m(r.shape, lamp, d)
    lo, hi = float(x.min()), float(x.max())
    if hasattr(model, "inverse"):  # band-aware: inverses at uniform distances, C interpolated linearly in X'
        grid = np.linspace(lo, hi, max(nodes, 2)) if hi > lo else np.array([lo, lo + 1e-9])
        pos = np.clip((x - grid[0]) / (grid[1] - grid[0]), 0, grid.size - 1 - 1e-12).reshape(-1)
        cell = pos.astype(np.intp)
        t = pos - cell
        inverses = [replace(model, geometry=_at(lamp, d, float(xk))).inverse(d) for xk in grid]
        flat = r.reshape(-1)
        s = None if sigma_ln_ratio is None else np.broadcast_to(np.asarray(sigma_ln_ratio, float), r.shape).reshape(-1)
        c = np.full(flat.size, np.nan)
        sig = np.full(flat.size, np.nan)
        reason = np.zeros(flat.size, dtype=np.uint8)
        for k in range(grid.size - 1):
            idx = np.flatnonzero(cell == k)
            if idx.size == 0:
                continue
            sk = None if s is None else s[idx]
            a = inverses[k].concentration(flat[idx], sigma_ln_ratio=sk)
            b = inverses[k + 1].concentration(flat[idx], sigma_ln_ratio=sk)
            tk = t[idx]
            c[idx] = (1 - tk) * a.c_ug_per_L + tk * b.c_ug_per_L
            sig[idx] = (1 - tk) * a.sigma_ug_per_L + tk * b.sigma_ug_per_L
            reason[idx] = np.maximum(a.reason, b.reason)
        bad = reason != 0
        c[bad] = np.nan
        sig[bad] = np.nan
        c, sig, reason = c.reshape(r.shape), sig.reshape(r.shape), reason.reshape(r.shape)
        return Inversion(c / mol_per_L_to_ug_per_L(1.0), c, sig, np.full(r.shape, np.nan), reason)
    # narrowband: map each pixel's ratio to the centre's for the same τ (exact for one exponential)
    k_ = np.arange(NARROW_NODES)
    cheb = 0.5 * (lo + hi) + 0.5 * (hi - lo + 1e-9) * np.cos((2 * k_ + 1) * np.pi / (2 * k_.size))[::-1]
    forms = [_at(lamp, d, float(xk)).closed_form_at(d) for xk in cheb]
    kk = CubicSpline(cheb, [f.scale for f in forms])(x)
    ss = CubicSpline(cheb, [f.view_factor for f in forms])(x)
    centre = lamp.closed_form_at(d)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        rc = centre.scale * np.power(np.where(r > 0, r / kk, r), centre.view_factor / ss)
        rc = np.where(np.isfinite(r) & (r > 0), rc, r)
        sc = None if sigma_ln_ratio is None else np.asarray(sigma_ln_ratio, float) * centre.view_factor / ss
    return invert_ratio(rc, lamp, d, sigma_ln_ratio=sc)

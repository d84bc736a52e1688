"""Finding the Secchi disk in a radiance image (scikit-image): centre, radius, the interior region and the
surround that measures the sky reflected by the water surface.

Steps (:func:`find_disk`), on one channel of a radiance image (``camcal apply``'s band radiance):

1. **Glints and saturation**: pixels the radiance marks invalid (NaN: saturated or defective) and pixels far
   brighter than the disk (> ``GLINT_FACTOR`` × the bright class's median) form the glint mask; isolated NaN
   pixels (defects) are not glints.
2. **Segmentation**: Otsu's threshold (:func:`skimage.filters.threshold_otsu`) on the valid pixels, clipped at
   their 99.5th percentile so that a glint cannot take the upper class; the bright class without glints,
   opened, labelled (:func:`skimage.measure.label`); the largest region is the disk candidate.
3. **Edge**: sub-pixel iso-contours at the level half-way between the disk and the surround
   (:func:`skimage.measure.find_contours`), kept within a band around the candidate's rim and away from glints,
   and a circle fitted to them robustly (:func:`skimage.measure.ransac` with :class:`skimage.measure.CircleModel`).
4. **Regions**: the interior, a disk of ``interior_fraction`` of the radius less a pixel, without glints (dilated)
   and invalid pixels; the surround, an annulus from ``surround_inner`` to ``surround_outer`` radii, the same
   exclusions. Over the submerged disk the camera sees the disk's light plus the sky reflected by the surface;
   the surround water (deep, not scattering) shows the reflection alone, so it is subtracted (the seed's
   L_reflected).

A disk that is missing, too small (radius below ``min_radius_px`` photo pixels) or broken by a glint (the
glint covers more than ``MAX_GLINT_FRACTION`` of the disk, or too few rim points fit one circle) is a
:class:`camcal.errors.CamcalError` naming the file and the reason.

Coordinates: image pixels of the radiance image; :attr:`DiskFit.centre_photo_px` and
:attr:`DiskFit.radius_photo_px` are in photo pixels (``scale`` photo pixels per image pixel: 2 for Bayer
radiance images, the centre of image pixel j is photo coordinate scale·j + (scale − 1)/2).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from skimage import filters, measure, morphology

from camcal.errors import CamcalError
from camcal.region import Region

#: A pixel brighter than this multiple of the disk's median is a glint.
GLINT_FACTOR = 1.6
#: Largest fraction of the disk's area a glint may cover.
MAX_GLINT_FRACTION = 0.25
#: Smallest fraction of rim points on the fitted circle.
MIN_INLIER_FRACTION = 0.5


@dataclass(frozen=True, eq=False)
class DiskFit:
    """A located disk (see the module docstring). Masks are boolean images of the input's shape."""

    centre_px: tuple[float, float]
    radius_px: float
    interior: np.ndarray
    surround: np.ndarray
    glint: np.ndarray
    scale: int = 1
    method: str = "found"
    notes: list = field(default_factory=list)

    @property
    def centre_photo_px(self) -> tuple[float, float]:
        s = self.scale
        return (s * self.centre_px[0] + (s - 1) / 2.0, s * self.centre_px[1] + (s - 1) / 2.0)

    @property
    def radius_photo_px(self) -> float:
        return self.scale * self.radius_px

    def describe(self) -> dict:
        return {"method": self.method, "centre_photo_px": [round(v, 2) for v in self.centre_photo_px],
                "radius_photo_px": round(self.radius_photo_px, 2), "interior_pixels": int(self.interior.sum()),
                "surround_pixels": int(self.surround.sum()), "glint_pixels": int(self.glint.sum()),
                "notes": list(self.notes)}


def _regions(shape, cx, cy, r, valid, glint_zone, interior_fraction, surround_inner, surround_outer):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    dist = np.hypot(xx - cx, yy - cy)
    interior = (dist <= interior_fraction * r - 1.0) & valid & ~glint_zone
    surround = (dist >= surround_inner * r) & (dist <= surround_outer * r) & valid & ~glint_zone
    return interior, surround


def _circle_params(model) -> tuple[float, float, float]:
    if hasattr(model, "center"):  # scikit-image >= 0.26
        return float(model.center[0]), float(model.center[1]), float(model.radius)
    return tuple(float(v) for v in model.params)  # type: ignore[return-value]


def _circle(xy: np.ndarray, fallback) -> tuple[float, float, float]:
    """Least-squares circle through the inlier rim points (x, y)."""
    if hasattr(measure.CircleModel, "from_estimate"):  # scikit-image >= 0.26
        m = measure.CircleModel.from_estimate(xy)
        return _circle_params(m) if m else _circle_params(fallback)
    m = measure.CircleModel()
    return _circle_params(m) if m.estimate(xy) else _circle_params(fallback)


def find_disk(image: np.ndarray, *, scale: int = 1, min_radius_px: float = 12.0, interior_fraction: float = 0.8,
              surround_inner: float = 1.2, surround_outer: float = 1.6, where: str | Path | None = None) -> DiskFit:
    """Locate the bright disk in ``image`` (2-D radiance; NaN = invalid). See the module docstring.

    ``min_radius_px`` is in photo pixels. Raises :class:`CamcalError` (naming ``where``) when there is no disk,
    it is too small or a glint breaks it.
    """
    img = np.asarray(image, float)
    if img.ndim != 2 or min(img.shape) < 8:
        raise CamcalError("no disk found: the image is too small to search", where)
    finite = np.isfinite(img)
    if finite.sum() < 64:
        raise CamcalError("no disk found: the image holds no valid pixels", where)
    vals = img[finite]
    if not vals.max() > vals.min():
        raise CamcalError("no disk found: the image is uniform", where)
    clipped = np.minimum(vals, np.percentile(vals, 99.5))
    t = filters.threshold_otsu(clipped if clipped.max() > clipped.min() else vals)
    bright = finite & (img > t)
    disk_level = float(np.median(img[bright])) if bright.any() else np.inf
    # invalid clusters (not isolated defects) and very bright pixels are glints
    invalid = ~finite
    glint = (finite & (img > GLINT_FACTOR * disk_level)) | (invalid & morphology.opening(invalid,
                                                                                                   morphology.disk(1)))
    dark_level = float(np.median(img[finite & ~bright])) if (finite & ~bright).any() else 0.0
    if not disk_level > 1.5 * max(dark_level, 0.0) + 1e-30:
        raise CamcalError("no disk found: no region stands out from the water (contrast below 1.5)", where)
    cand = morphology.opening(bright & ~glint, morphology.disk(1))
    labels = measure.label(cand)
    props = measure.regionprops(labels)
    if not props:
        raise CamcalError("no disk found: nothing brighter than the water", where)
    best = max(props, key=lambda p: p.area)
    min_r = min_radius_px / scale
    r_area = float(np.sqrt(best.area / np.pi))
    if r_area < min_r:
        raise CamcalError(f"no disk found: the brightest region has a radius of {r_area * scale:.1f} photo pixels, "
                          f"below the {min_radius_px:g} needed (disk too small or too far)", where)
    region = labels == best.label
    filled = morphology.remove_small_holes(region, max_size=int(best.area))
    # sub-pixel rim: iso-contour half-way between disk and surround, near the candidate's rim, away from glints
    level = 0.5 * (float(np.median(img[region])) + dark_level)
    work = np.where(finite, img, level * 2)
    glint_zone = morphology.dilation(glint, morphology.disk(3))
    band = morphology.dilation(filled, morphology.disk(3)) & ~morphology.erosion(filled,
                                                                                              morphology.disk(3))
    pts = []
    for cnt in measure.find_contours(work, level):
        ij = np.rint(cnt).astype(int)
        ij[:, 0] = np.clip(ij[:, 0], 0, img.shape[0] - 1)
        ij[:, 1] = np.clip(ij[:, 1], 0, img.shape[1] - 1)
        keep = band[ij[:, 0], ij[:, 1]] & ~glint_zone[ij[:, 0], ij[:, 1]]
        pts.append(cnt[keep])
    pts = np.concatenate(pts) if pts else np.empty((0, 2))
    if len(pts) < 12:
        raise CamcalError("disk broken by a glint: too little of its rim is visible to fit a circle", where)
    xy = pts[:, ::-1]  # (x, y)
    rng = np.random.default_rng(0)
    model, inliers = measure.ransac(xy, measure.CircleModel, min_samples=3, residual_threshold=0.75,
                                    max_trials=200, rng=rng)
    if model is None or inliers is None or inliers.mean() < MIN_INLIER_FRACTION:
        raise CamcalError("disk broken by a glint (or not round): its rim does not fit one circle", where)
    cx, cy, r = _circle(xy[inliers], model)
    if r * scale < min_radius_px:
        raise CamcalError(f"no disk found: the fitted disk has a radius of {r * scale:.1f} photo pixels, below "
                          f"the {min_radius_px:g} needed", where)
    yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    on_disk = np.hypot(xx - cx, yy - cy) <= r
    if (glint & on_disk).sum() > MAX_GLINT_FRACTION * on_disk.sum():
        raise CamcalError(f"disk broken by a glint: {100 * (glint & on_disk).sum() / on_disk.sum():.0f} % of it is "
                          "glint or saturated", where)
    interior, surround = _regions(img.shape, cx, cy, r, finite, glint_zone, interior_fraction, surround_inner,
                                  surround_outer)
    notes = []
    if glint.any():
        notes.append(f"{int(glint.sum())} glint or saturated pixels left out")
    if interior.sum() < 20:
        raise CamcalError("disk broken by a glint: fewer than 20 clean pixels inside it", where)
    return DiskFit((cx, cy), r, interior, surround, glint, int(scale), "found", notes)


def disk_from_roi(image: np.ndarray, roi: Region, *, scale: int = 1, surround_inner: float = 1.2,
                  surround_outer: float = 1.6, where: str | Path | None = None) -> DiskFit:
    """The disk given by hand: ``roi`` (photo pixels) is its interior; the surround is the annulus around the
    circle through the rectangle's corners (``surround_inner`` to ``surround_outer`` of its radius)."""
    img = np.asarray(image, float)
    ys, xs = roi.window(img.shape, scale, where)
    finite = np.isfinite(img)
    interior = np.zeros(img.shape, bool)
    interior[ys, xs] = True
    interior &= finite
    if interior.sum() < 4:
        raise CamcalError(f"--roi {roi} holds fewer than 4 valid pixels", where)
    cx, cy = (xs.start + xs.stop - 1) / 2.0, (ys.start + ys.stop - 1) / 2.0
    r = 0.5 * float(np.hypot(xs.stop - xs.start, ys.stop - ys.start))
    yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    dist = np.hypot(xx - cx, yy - cy)
    surround = (dist >= surround_inner * r) & (dist <= surround_outer * r) & finite
    return DiskFit((cx, cy), r, interior, surround, np.zeros(img.shape, bool), int(scale), "roi", [f"--roi {roi}"])


def region_mean(image: np.ndarray, mask: np.ndarray) -> tuple[float, float, int]:
    """(mean, standard error of the mean, pixel count) of ``image`` over ``mask`` (finite pixels only)."""
    v = np.asarray(image, float)[mask]
    v = v[np.isfinite(v)]
    if v.size < 2:
        return float("nan"), float("nan"), int(v.size)
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(v.size)), int(v.size)

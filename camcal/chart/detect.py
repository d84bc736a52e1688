"""Where the colour chart lies in a photo: an X-Rite ColorChecker Classic (24 patches, 6 x 4).

The chart is found automatically with colour-science's detector (:func:`colour_checker_detection.
detect_colour_checkers_segmentation`, Dallas 2024: the swatches segmented on a grey version of the image,
their cluster's bounding quadrilateral fitted) on a display-like preview of the photo: the half-resolution
CFA planes (R, mean G, B, black subtracted) of a Bayer RAW, the linear RAW's planes, or the processed image,
each channel scaled to its 99.5th percentile (RAW data then encoded with γ = 1/2.2). The detector returns the swatch
grid's outer quadrilateral; camcal then fixes its orientation itself from the chart's defining feature, the
bottom row of six neutral patches (one chromaticity, luminance falling by ~25x from white to black), so that
a camera-space preview without white balance is oriented as reliably as an sRGB one.

The fallback is the user's four corners (``--corners x1,y1,...,x4,y4``, full-resolution photo pixels): the
outer corners of the swatch grid, starting at the corner next to patch 1 (dark skin), then next to patch 6
(bluish green), patch 24 (black) and patch 19 (white).

The model: a homography H from chart coordinates (u ∈ [0, 6] columns, v ∈ [0, 4] rows, patch k = 6·row +
col, numbered 0..23) to photo pixels (x right, y down, full resolution; pixel centres at integer + 0.5).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from camcal.errors import CamcalError
from camcal.frame import Frame

COLUMNS, ROWS = 6, 4
N_PATCHES = COLUMNS * ROWS
#: Indices (0-based) of the neutral patches, white (19) to black (24).
NEUTRAL_PATCHES = tuple(range(18, 24))
#: Width of the detector's working image, pixels (its default setting).
WORKING_WIDTH = 1440
#: Largest side of the preview the detector sees, pixels (larger photos are reduced by area averaging).
PREVIEW_MAX_SIDE = 3000


@dataclass(frozen=True)
class ChartLocation:
    """The swatch grid's outer corners in full-resolution photo pixels and how they were found.

    corners_px : (4, 2) float, (x, y) of the corners next to patch 1, patch 6, patch 24 and patch 19.
    method : ``"detected"`` (colour-checker-detection) or ``"corners"`` (given by the user).
    neutral_score : chromaticity spread of the neutral row (smaller is more neutral; informational).
    """

    corners_px: np.ndarray
    method: str
    neutral_score: float = float("nan")

    def homography(self) -> np.ndarray:
        """(3, 3) H with (x, y, 1) ∝ H (u, v, 1): chart coordinates → photo pixels."""
        src = np.array([[0, 0], [COLUMNS, 0], [COLUMNS, ROWS], [0, ROWS]], np.float32)
        return cv2.getPerspectiveTransform(src, np.asarray(self.corners_px, np.float32)).astype(float)

    def patch_centres_px(self) -> np.ndarray:
        """(24, 2) photo pixel (x, y) of each patch's centre."""
        u, v = np.meshgrid(np.arange(COLUMNS) + 0.5, np.arange(ROWS) + 0.5)
        return to_photo(self.homography(), np.column_stack([u.ravel(), v.ravel()]))

    def to_dict(self) -> dict:
        return {"method": self.method, "corners_px": [[float(a), float(b)] for a, b in self.corners_px],
                "order": "corners next to patch 1 (dark skin), 6 (bluish green), 24 (black), 19 (white)",
                "neutral_score": None if not np.isfinite(self.neutral_score) else float(self.neutral_score)}


def to_photo(h: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(n, 2) chart coordinates → (n, 2) photo pixels through the homography ``h``."""
    p = np.column_stack([uv, np.ones(len(uv))]) @ h.T
    return p[:, :2] / p[:, 2:3]


def parse_corners(text: str) -> np.ndarray:
    """``"x1,y1,x2,y2,x3,y3,x4,y4"`` (photo pixels) → (4, 2) array; one clear error otherwise."""
    try:
        vals = [float(p) for p in str(text).split(",")]
    except ValueError:
        vals = []
    if len(vals) != 8 or not all(np.isfinite(vals)):
        raise CamcalError("--corners must be eight numbers x1,y1,x2,y2,x3,y3,x4,y4: the swatch grid's outer corners "
                          f"in photo pixels, next to patch 1 (dark skin), 6, 24 (black) and 19 (white); got {text!r}")
    c = np.array(vals, float).reshape(4, 2)
    d1, d2 = c[2] - c[0], c[3] - c[1]
    area = 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])  # the quadrilateral's area from its diagonals' cross product
    if area < 24 * 16:
        raise CamcalError(f"--corners {text!r} enclose {area:.0f} square pixels: too small for 24 patches")
    return c


def preview(frame: Frame) -> tuple[np.ndarray, float]:
    """A display-like (h, w, 3) float32 image in 0..1 for the detector and the pixels-per-preview-pixel factor."""
    if frame.layout == "bayer":
        planes = frame.planes(np.float32) - frame.black_vector().astype(np.float32)
        rgb = np.stack([planes[0], 0.5 * (planes[1] + planes[2]), planes[3]], axis=-1)
        scale = 2.0
    else:
        rgb = frame.data.astype(np.float32) - (frame.black_vector().ravel().astype(np.float32)
                                               if frame.layout == "linear" else 0.0)
        scale = 1.0
    side = max(rgb.shape[:2])
    if side > PREVIEW_MAX_SIDE:
        f = PREVIEW_MAX_SIDE / side
        rgb = cv2.resize(rgb, (round(rgb.shape[1] * f), round(rgb.shape[0] * f)), interpolation=cv2.INTER_AREA)
        scale /= f
    rgb = np.maximum(rgb, 0.0)
    top = np.percentile(rgb.reshape(-1, 3), 99.5, axis=0)
    rgb = np.clip(rgb / np.maximum(top, 1e-6), 0.0, 1.0)
    if frame.kind == "raw":  # linear data: encoded for display (a processed image already is)
        rgb = rgb ** (1 / 2.2)
    return np.ascontiguousarray(rgb, np.float32), scale


def _patch_means(img: np.ndarray, corners: np.ndarray, frac: float = 0.4) -> np.ndarray:
    """(24, 3) mean of the central ``frac`` of each cell of the grid with ``corners`` in ``img`` pixels."""
    loc = ChartLocation(corners, "preview")
    h = loc.homography()
    out = np.empty((N_PATCHES, img.shape[2]))
    g = np.linspace(0.5 - frac / 2, 0.5 + frac / 2, 5)
    du, dv = np.meshgrid(g, g)
    for k in range(N_PATCHES):
        r, c = divmod(k, COLUMNS)
        xy = to_photo(h, np.column_stack([(c + du).ravel(), (r + dv).ravel()]))
        xi = np.clip(np.round(xy[:, 0] - 0.5).astype(int), 0, img.shape[1] - 1)
        yi = np.clip(np.round(xy[:, 1] - 0.5).astype(int), 0, img.shape[0] - 1)
        out[k] = img[yi, xi].mean(0)
    return out


def neutral_score(means: np.ndarray) -> float:
    """How unlike the ColorChecker's neutral row patches 19..24 of ``means`` (24, C) are: the spread of their
    chromaticity plus a penalty for each step where the luminance does not fall (0 for a perfect row)."""
    row = np.maximum(np.asarray(means, float)[list(NEUTRAL_PATCHES)], 1e-9)
    lum = row.sum(1)
    chroma = row / lum[:, None]
    spread = float(np.sum(np.std(chroma[:4], axis=0)))  # the darkest two are noisy: the light four decide
    falls = np.sum(np.diff(lum) >= 0)
    return spread + 0.2 * float(falls) + (0.5 if lum[0] < 3 * lum[-1] else 0.0)


def orient(img: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, float]:
    """The cyclic order of ``corners`` (and its score) whose bottom row is most like the neutral row.

    A quadrilateral's four cyclic orders are the chart turned by 0, 90, 180 and 270 degrees; the detector's
    aspect ratio makes the 6-patch side the long one, and the neutral row decides between the rest.
    """
    best = None
    for shift in range(4):
        c = np.roll(corners, -shift, axis=0)
        s = neutral_score(_patch_means(img, c))
        if best is None or s < best[1]:
            best = (c, s)
    return best  # type: ignore[return-value]


def refine(img: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Corners of the homography through the patches' own centres (the detector fits a rectangle, which under
    perspective misplaces the far patches by a third of a patch).

    Each patch's centre is the centroid of the connected region around its predicted centre whose colour lies
    within 3 MAD (at least 0.04) of the colour at the centre; :func:`cv2.findHomography` (RANSAC, 0.15 of a
    patch) maps the grid's centres onto them. Returns ``corners`` unchanged when fewer than 12 patches are found.
    """
    loc = ChartLocation(corners, "preview")
    centres = loc.patch_centres_px()
    cell = float(np.mean(np.hypot(*np.diff(np.vstack([corners, corners[:1]]), axis=0).T)) / 5.0)
    found, grid = [], []
    for k, (cx, cy) in enumerate(centres):
        r = max(int(0.6 * cell), 3)
        x0, y0 = int(round(cx)) - r, int(round(cy)) - r
        if x0 < 0 or y0 < 0 or x0 + 2 * r >= img.shape[1] or y0 + 2 * r >= img.shape[0]:
            continue
        win = img[y0:y0 + 2 * r + 1, x0:x0 + 2 * r + 1]
        q = max(int(0.12 * cell), 1)
        core = win[r - q:r + q + 1, r - q:r + q + 1].reshape(-1, img.shape[2])
        ref = np.median(core, axis=0)
        d = np.max(np.abs(win - ref), axis=2)
        tol = max(0.04, 3.0 * float(np.median(np.max(np.abs(core - ref), axis=1))) * 1.4826)
        n, lab = cv2.connectedComponents((d <= tol).astype(np.uint8), connectivity=4)
        if lab[r, r] == 0:
            continue
        ys, xs = np.nonzero(lab == lab[r, r])
        if xs.size < 0.1 * (2 * r) ** 2 or xs.size > 0.9 * (2 * r + 1) ** 2:  # no patch, or the region leaks out
            continue
        found.append((x0 + xs.mean() + 0.5, y0 + ys.mean() + 0.5))
        row, col = divmod(k, COLUMNS)
        grid.append((col + 0.5, row + 0.5))
    if len(found) < 12:
        return corners
    hm, inliers = cv2.findHomography(np.array(grid, np.float32), np.array(found, np.float32), cv2.RANSAC,
                                     0.15 * cell)
    if hm is None or int(inliers.sum()) < 12:
        return corners
    return to_photo(hm, np.array([[0, 0], [COLUMNS, 0], [COLUMNS, ROWS], [0, ROWS]], float))


def detect_chart(frame: Frame) -> ChartLocation:
    """Find the ColorChecker in ``frame`` (module docstring).

    Raises
    ------
    CamcalError
        No chart was found (naming ``--corners``), or what was found has no neutral row.
    """
    import colour_checker_detection as ccd  # loads colour-science: kept off paths that do not detect charts

    img, scale = preview(frame)
    portrait = img.shape[0] > img.shape[1]
    work = np.ascontiguousarray(np.rot90(img, k=-1)) if portrait else img  # the detector wants landscape
    try:
        found = ccd.detect_colour_checkers_segmentation(work, additional_data=True)
    except (cv2.error, ValueError, IndexError) as exc:  # the detector's failures on odd images
        raise CamcalError(f"the colour-chart detector failed ({type(exc).__name__}); give the chart's corners with "
                          "--corners x1,y1,...,x4,y4", frame.path) from None
    if not found:
        raise CamcalError("no ColorChecker Classic (24 patches) found in the photo; give the chart's corners with "
                          "--corners x1,y1,...,x4,y4 (photo pixels, next to patch 1, 6, 24, 19)", frame.path)
    best = None
    f = work.shape[1] / WORKING_WIDTH
    for d in found:
        q = np.asarray(d.quadrilateral, float) * f  # the detector's working image → preview pixels
        # rectangle order of colour_checker_detection.sample_colour_checker: (W, 0), (W, H), (0, H), (0, 0)
        corners = q[[3, 0, 1, 2]]
        if portrait:  # undo the clockwise turn: (x', y') in the turned image ← (x, y) = (y', h − x')
            corners = np.column_stack([corners[:, 1], img.shape[0] - corners[:, 0]])
        corners, score = orient(img, corners)
        corners = refine(img, corners)
        score = neutral_score(_patch_means(img, corners))
        if best is None or score < best[1]:
            best = (corners, score)
    corners, score = best  # type: ignore[misc]
    if score > 0.35:
        raise CamcalError(f"found a chart-like grid but no neutral row of six grey patches in it (score {score:.2f});"
                          " give the chart's corners with --corners x1,y1,...,x4,y4", frame.path)
    return ChartLocation(corners * scale, "detected", score)


def locate_chart(frame: Frame, corners: np.ndarray | None = None) -> ChartLocation:
    """The chart in ``frame``: the given ``corners`` (photo pixels), else :func:`detect_chart`."""
    if corners is None:
        return detect_chart(frame)
    h, w = frame.shape
    c = np.asarray(corners, float)
    if np.any(c[:, 0] < 0) or np.any(c[:, 0] > w) or np.any(c[:, 1] < 0) or np.any(c[:, 1] > h):
        raise CamcalError(f"--corners lie outside the {w}x{h} photo", frame.path)
    img, scale = preview(frame)
    score = neutral_score(_patch_means(img, c / scale))
    return ChartLocation(c, "corners", score)

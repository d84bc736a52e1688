"""One region type for every command that takes ``--roi``.

Convention (docs/conventions.md): a region is a rectangle ``x,y,w,h`` in **photo pixels at full
resolution** — x to the right and y down from the top-left corner of the image, w and h its width and
height, all whole pixels. Wherever camcal works on a coarser grid (the half-resolution CFA planes of a
Bayer sensor, the half-resolution radiance EXRs written from them), the region is rounded *outward* to
whole cells of that grid, so it never loses a pixel the user asked for.

A *centred* region is given by a **central fraction, a fraction of each side** (never of the area):
:func:`central_roi`; on the command line it is ``--roi-fraction F``, a separate option.
"""

from __future__ import annotations

from dataclasses import dataclass

from camcal.errors import CamcalError

Window = tuple[slice, slice]
"""Rows and columns of an array (a plane or an output image)."""

DEFAULT_ROI_FRACTION = 0.2
"""Default central fraction (of each side: a fifth, 4 % of the area) of the sweep, the JPEG colour twins and
the reference-target photos."""


@dataclass(frozen=True)
class Region:
    """A rectangle in full-resolution photo pixels: top-left ``(x, y)``, width ``w``, height ``h``."""

    x: int
    y: int
    w: int
    h: int

    def __post_init__(self) -> None:
        if self.x < 0 or self.y < 0 or self.w <= 0 or self.h <= 0:
            raise CamcalError(f"a region needs x, y ≥ 0 and w, h > 0 (photo pixels), got "
                              f"{self.x},{self.y},{self.w},{self.h}")

    def __str__(self) -> str:
        return f"{self.x},{self.y},{self.w},{self.h}"

    @staticmethod
    def parse(text: str, option: str = "--roi") -> Region:
        """``"x,y,w,h"`` (whole photo pixels) → :class:`Region`; one clear error naming ``option`` otherwise."""
        parts = [p.strip() for p in str(text).split(",")]
        try:
            vals = [int(p) for p in parts]
        except ValueError:
            vals = []
        if len(vals) != 4 or vals[0] < 0 or vals[1] < 0 or vals[2] <= 0 or vals[3] <= 0:
            raise CamcalError(f"{option} must be x,y,w,h: whole photo pixels at full resolution, x, y ≥ 0 and "
                              f"w, h > 0, got {text!r}")
        return Region(*vals)

    def window(self, grid_shape: tuple[int, int], pixels_per_cell: int = 1, where=None) -> Window:
        """Rows and columns of a grid whose cells are ``pixels_per_cell`` photo pixels on a side.

        Rounded outward to whole cells, clipped to the grid; a region that lies outside the grid is an error.
        """
        p = int(pixels_per_cell)
        gh, gw = grid_shape
        r0, c0 = self.y // p, self.x // p
        r1, c1 = -(-(self.y + self.h) // p), -(-(self.x + self.w) // p)
        if r0 >= gh or c0 >= gw:
            raise CamcalError(f"region {self} (photo pixels) lies outside the photo ({gw * p}x{gh * p})", where)
        return slice(r0, min(r1, gh)), slice(c0, min(c1, gw))


def pixels_per_output_cell(resolution: object) -> int | None:
    """Photo pixels per side of one cell of an image camcal wrote, from its metadata ``"resolution"`` note.

    ``camcal apply`` writes half resolution for Bayer photos (2) and full resolution for linear RAW (1);
    ``None`` when the note is absent or unknown (an image camcal did not write).
    """
    note = str(resolution or "")
    if note.startswith("half resolution"):
        return 2
    if note.startswith("full resolution"):
        return 1
    return None


def central_roi(shape_hw: tuple[int, int], fraction: float = DEFAULT_ROI_FRACTION) -> tuple[int, int, int, int]:
    """A centred box ``(x0, y0, x1, y1)`` (half-open, plane pixels) covering ``fraction`` of each side."""
    if not 0 < fraction <= 1:
        raise CamcalError(f"ROI fraction (a central fraction of each side) must be in (0, 1], got {fraction}")
    h, w = shape_hw
    rw, rh = max(2, round(w * fraction)), max(2, round(h * fraction))
    x0, y0 = (w - rw) // 2, (h - rh) // 2
    return x0, y0, x0 + rw, y0 + rh

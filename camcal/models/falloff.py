"""The natural fall-off of a lens left uncorrected (no flat field measured), and the field angle it needs.

Without a flat, camcal corrects no vignetting and states what that costs instead. The model is the natural
relative illumination of a distortion-free lens, cos⁴ θ, with θ the field angle of the image point (Kingslake
1978): tan θ = r tan θ_c, r the distance from the image centre over the half-diagonal, θ_c the field angle of the
image corner. A pixel's value is then low by a fraction between 0 and ℓ = 1 − cos⁴ θ (a real lens adds
mechanical vignetting, a phone's processing may take some out), so the radiance lies between v and v/(1 − ℓ): a
uniform bias whose RMS is σ = v ℓ/((1 − ℓ)√3) (:func:`uncorrected_sigma_rel`).

The corner's field angle comes from the photo: EXIF FocalLengthIn35mmFilm (tag 0xA405, CIPA DC-008) f₃₅ gives the
half-diagonal field angle θ_c = atan(21.63 mm / f₃₅), 21.63 mm the half-diagonal of the 36 × 24 mm frame (an
equivalent focal length scales the diagonal, the usual definition). A file without the tag leaves θ_c unknown;
only then is :data:`ASSUMED_CORNER_FIELD_DEG` used, and the record says which (:func:`corner_field`).

References
----------
Kingslake, R. (1978). Lens Design Fundamentals. Academic Press (the cos⁴ law of illumination).
CIPA DC-008-2019, Exif 2.32: FocalLengthIn35mmFilm.
"""

from __future__ import annotations

import math

import numpy as np

#: Half-diagonal of the 36 × 24 mm frame, mm.
HALF_DIAGONAL_35MM_MM = math.hypot(36.0, 24.0) / 2.0
#: Corner field angle assumed where the photo does not state its 35 mm equivalent focal length, degrees: a phone's
#: main camera (26 mm equivalent: 39.8° to the corner; 28 mm: 37.7°).
ASSUMED_CORNER_FIELD_DEG = 38.0


def corner_field_deg_of(focal_length_35mm_mm: float) -> float:
    """Half-diagonal field angle θ_c = atan(21.63 mm / f₃₅), degrees."""
    return math.degrees(math.atan(HALF_DIAGONAL_35MM_MM / float(focal_length_35mm_mm)))


def corner_field(exposure, name: str | None = None) -> dict:
    """The corner field angle of a photo and where it came from: ``{"corner_field_deg", "source",
    "focal_length_35mm_mm"}``; ``source`` names the EXIF tag (and ``name``, the file), or the assumption when the
    photo does not hold the tag (its value then None)."""
    f35 = getattr(exposure, "focal_length_35mm_mm", None)
    if f35 is not None and math.isfinite(f35) and f35 > 0:
        where = f" of {name}" if name else ""
        return {"corner_field_deg": corner_field_deg_of(f35), "focal_length_35mm_mm": float(f35),
                "source": f"EXIF FocalLengthIn35mmFilm{where}: atan(21.63 mm / {f35:g} mm)"}
    what = f"{name} holds" if name else "the photo holds"
    return {"corner_field_deg": ASSUMED_CORNER_FIELD_DEG, "focal_length_35mm_mm": None,
            "source": f"assumed ({ASSUMED_CORNER_FIELD_DEG:g}°, a phone's main camera): {what} no "
                      "FocalLengthIn35mmFilm"}


def relative_radius(x_px, y_px, width: int, height: int) -> np.ndarray:
    """Distance of pixel centres (x right, y down, 0 at the first pixel's centre) from the image centre over the
    half-diagonal (1 in the corners)."""
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    return np.hypot(np.asarray(x_px, float) - cx, np.asarray(y_px, float) - cy) / (math.hypot(cx, cy) or 1.0)


def cos4_falloff(r, corner_field_deg: float) -> np.ndarray:
    """Relative illumination cos⁴ θ = (1 + r² tan² θ_c)⁻² at relative radius ``r``."""
    t = np.asarray(r) * np.float32(math.tan(math.radians(corner_field_deg)))
    return 1.0 / (1.0 + t * t) ** 2


def uncorrected_sigma_rel(r, corner_field_deg: float) -> np.ndarray:
    """σ/v of a value left uncorrected for the fall-off at relative radius ``r`` (module docstring):
    ℓ/((1 − ℓ)√3), ℓ = 1 − cos⁴ θ."""
    kept = cos4_falloff(r, corner_field_deg)
    return (1.0 - kept) / (kept * np.float32(math.sqrt(3.0)))

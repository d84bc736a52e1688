"""HEIC writer for synthetic phone photos: HEVC in HEIF through pillow-heif (libheif, x265), with EXIF.

An iPhone saves HEIC by default: an 8-bit (or 10-bit) HEVC image, an EXIF block with the exposure,
DateTimeOriginal, OffsetTimeOriginal and a GPS block, and an ICC profile. :func:`write_heic` writes the
same structure from an (H, W, 3) image, its EXIF built by :func:`camcal.synth.exif.encode_exif_tiff`.

References
----------
ISO/IEC 23008-12, *High Efficiency Image File Format (HEIF)*; CIPA DC-008-2019, *Exif 2.32*.
"""

from __future__ import annotations

import io
from datetime import datetime
from pathlib import Path

import numpy as np
import pillow_heif

from camcal.io.atomic import atomic_write_bytes
from camcal.synth.exif import PlaceTime, encode_exif_tiff


def write_heic(
    path: str | Path,
    rgb: np.ndarray,
    *,
    bits: int | None = None,
    quality: int = 97,
    exposure_s: float | None = None,
    f_number: float | None = None,
    iso: float | None = None,
    make: str = "camcal",
    model: str = "Synthetic",
    capture_time: datetime | None = None,
    place: PlaceTime | None = None,
    exif: bytes | None = None,
    icc_profile: bytes | None = None,
    preset: str | None = None,
    focal_length_mm: float | None = None,
    focal_length_35mm_mm: float | None = None,
) -> Path:
    """Write an (H, W, 3) image as a HEIC file with an EXIF block, atomically.

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3)
        uint8 (8-bit file) or uint16 holding 0..2**bits − 1 (a 10- or 12-bit file).
    bits : 8, 10 or 12; None: 8 for uint8, 10 for uint16.
    quality : HEVC quality 0–100 (pillow-heif's scale); chroma 4:4:4.
    exposure_s, f_number, iso, make, model, capture_time, place, focal_length_mm, focal_length_35mm_mm
        The EXIF tags (:func:`camcal.synth.exif.encode_exif_tiff`); a value None is not written.
    exif : bytes, optional
        A ready TIFF-structure EXIF block instead of the one built from the tags.
    icc_profile : bytes, optional
        An ICC profile to embed (none by default: the pixels are sRGB-encoded).
    preset : str, optional
        x265 speed preset (``ultrafast`` … ``placebo``; None: libheif's default), as a phone's hardware encoder
        trades size for speed.
    """
    rgb = np.ascontiguousarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"a HEIC image must have shape (H, W, 3), got {rgb.shape}")
    if bits is None:
        bits = 8 if rgb.dtype == np.uint8 else 10
    if bits not in (8, 10, 12):
        raise ValueError(f"bits must be 8, 10 or 12, got {bits}")
    h, w, _ = rgb.shape
    if bits == 8:
        if rgb.dtype != np.uint8:
            raise ValueError("an 8-bit HEIC needs uint8 pixels")
        heif = pillow_heif.from_bytes(mode="RGB", size=(w, h), data=rgb.tobytes())
    else:
        if rgb.dtype != np.uint16 or int(rgb.max(initial=0)) >= 2**bits:
            raise ValueError(f"a {bits}-bit HEIC needs uint16 pixels below {2**bits}")
        # pillow-heif takes 16-bit samples and keeps the top ``bits`` bits
        data = (rgb.astype("<u2") << (16 - bits)).tobytes()
        heif = pillow_heif.from_bytes(mode="RGB;16", size=(w, h), data=data)
    if exif is None:
        exif = encode_exif_tiff(exposure_s=exposure_s, f_number=f_number, iso=iso, make=make, model=model,
                                capture_time=capture_time, place=place, focal_length_mm=focal_length_mm,
                                focal_length_35mm_mm=focal_length_35mm_mm)
    buf = io.BytesIO()
    kwargs: dict = {"icc_profile": icc_profile} if icc_profile is not None else {}
    if preset is not None:
        kwargs["enc_params"] = {"preset": preset}
    heif.save(buf, quality=int(quality), chroma=444, exif=b"Exif\x00\x00" + exif, save_to_12bit=bits == 12,
              **kwargs)
    return atomic_write_bytes(path, buf.getvalue())

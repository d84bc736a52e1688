"""Minimal, honest DNG writer for the synthetic camera.

Writes an uncompressed little-endian DNG 1.4 file holding one CFA mosaic
(:func:`encode_dng`, PhotometricInterpretation 32803) or one linear R, G, B image
(:func:`encode_linear_dng`, LinearRaw, PhotometricInterpretation 34892, SamplesPerPixel 3,
which LibRaw reads as a 3-colour stack), with the exposure metadata in an Exif sub-IFD
(where LibRaw reads ISO from) and, given a :class:`~camcal.synth.exif.PlaceTime`, a GPS IFD and
OffsetTimeOriginal, so that ``rawpy`` decodes the file and reports exposure
time, f-number and ISO. A fixed-aperture camera writes no FNumber tag (``f_number=None``).

References
----------
Adobe, *Digital Negative (DNG) Specification*, version 1.4.0.0 (2012).
CIPA DC-008, *Exif 2.3*, tags 33434, 33437, 34855, 36867.
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path

import numpy as np

from camcal.io.atomic import atomic_write_bytes
from camcal.synth.exif import (
    _ASCII,
    _BYTE,
    _IFD,
    _LONG,
    _RATIONAL,
    _SHORT,
    _SRATIONAL,
    _UNDEFINED,
    TAG_GPS_IFD,
    PlaceTime,
    add_time_tags,
    gps_ifd,
    pack_tiff,
)

_CFA_CODE = {"R": 0, "G": 1, "B": 2}


def encode_dng(
    mosaic: np.ndarray,
    *,
    cfa_pattern: str,
    black_level_dn: tuple[float, float, float, float] | float,
    white_level_dn: int,
    exposure_s: float,
    f_number: float | None,
    iso: float,
    make: str = "camcal",
    model: str = "Synthetic",
    serial: str = "0000",
    capture_time: datetime | None = None,
    temperature_c: float | None = None,
    place: PlaceTime | None = None,
    focal_length_mm: float | None = None,
    focal_length_35mm_mm: float | None = None,
) -> bytes:
    """Encode a CFA mosaic as the bytes of an uncompressed DNG file.

    Parameters
    ----------
    mosaic : ndarray of uint16, shape (H, W)
        Raw DN values (H and W even).
    cfa_pattern : str
        One of ``RGGB``, ``BGGR``, ``GRBG``, ``GBRG`` (row-major 2x2 cell).
    black_level_dn : float or 4-tuple
        Black level in DN, per position of the 2x2 CFA cell (row-major).
    white_level_dn : int
        Saturation level in DN.
    exposure_s, f_number, iso : float
        Exposure time in seconds, f-number N (None: no FNumber tag, a fixed-aperture camera),
        ISO speed; written to the Exif IFD.
    """
    mosaic = np.ascontiguousarray(mosaic, dtype="<u2")
    if mosaic.ndim != 2 or mosaic.shape[0] % 2 or mosaic.shape[1] % 2:
        raise ValueError("mosaic must be 2-D with even dimensions")
    if np.isscalar(black_level_dn):
        black = [float(black_level_dn)] * 4
    else:
        black = [float(b) for b in black_level_dn]
    return _encode_image(
        mosaic, [1], 32803, cfa_pattern, black, [int(white_level_dn)], exposure_s=exposure_s, f_number=f_number,
        iso=iso, make=make, model=model, serial=serial, capture_time=capture_time, temperature_c=temperature_c,
        place=place, focal_length_mm=focal_length_mm, focal_length_35mm_mm=focal_length_35mm_mm,
    )


def encode_linear_dng(
    rgb: np.ndarray,
    *,
    black_level_dn: tuple[float, float, float] | float,
    white_level_dn: int,
    exposure_s: float,
    f_number: float | None,
    iso: float,
    make: str = "camcal",
    model: str = "Synthetic",
    serial: str = "0000",
    capture_time: datetime | None = None,
    temperature_c: float | None = None,
    place: PlaceTime | None = None,
    focal_length_mm: float | None = None,
    focal_length_35mm_mm: float | None = None,
) -> bytes:
    """Encode a linear R, G, B image as the bytes of an uncompressed LinearRaw DNG file.

    LinearRaw (PhotometricInterpretation 34892, DNG 1.4 §"LinearRaw"): three samples per pixel,
    16 bits each, chunky; BlackLevel and WhiteLevel per sample (BlackLevelRepeatDim 1x1).
    LibRaw decodes it as a 3-colour stack (``rawpy.RawType.Stack``).

    Parameters
    ----------
    rgb : ndarray of uint16, shape (H, W, 3)
        Raw DN values, channels R, G, B.
    black_level_dn : float or 3-tuple
        Black level in DN per channel R, G, B.
    white_level_dn : int
        Saturation level in DN (all channels).
    exposure_s, f_number, iso : as in :func:`encode_dng`.
    """
    rgb = np.ascontiguousarray(rgb, dtype="<u2")
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError("a linear image must have shape (H, W, 3)")
    black = [float(black_level_dn)] * 3 if np.isscalar(black_level_dn) else [float(b) for b in black_level_dn]
    if len(black) != 3:
        raise ValueError("black_level_dn needs one value per channel R, G, B")
    return _encode_image(
        rgb, [1, 1, 1], 34892, None, black, [int(white_level_dn)] * 3, exposure_s=exposure_s, f_number=f_number,
        iso=iso, make=make, model=model, serial=serial, capture_time=capture_time, temperature_c=temperature_c,
        place=place, focal_length_mm=focal_length_mm, focal_length_35mm_mm=focal_length_35mm_mm,
    )


def encode_mono_dng(
    image: np.ndarray,
    *,
    black_level_dn: float,
    white_level_dn: int,
    exposure_s: float,
    f_number: float | None,
    iso: float,
    make: str = "camcal",
    model: str = "Synthetic Monochrom",
    serial: str = "0000",
    capture_time: datetime | None = None,
) -> bytes:
    """Encode a monochrome image as the bytes of an uncompressed one-sample LinearRaw DNG (as a monochrome camera,
    e.g. Leica's Monochrom, writes): PhotometricInterpretation 34892, SamplesPerPixel 1, 16 bits; LibRaw decodes it
    as a one-colour image."""
    image = np.ascontiguousarray(image, dtype="<u2")
    if image.ndim != 2:
        raise ValueError("a monochrome image must have shape (H, W)")
    return _encode_image(
        image, [1], 34892, None, [float(black_level_dn)], [int(white_level_dn)], exposure_s=exposure_s,
        f_number=f_number, iso=iso, make=make, model=model, serial=serial, capture_time=capture_time,
        temperature_c=None,
    )


def _encode_image(
    image: np.ndarray,
    samples: list[int],
    photometric: int,
    cfa_pattern: str | None,
    black: list[float],
    white: list[int],
    *,
    exposure_s: float,
    f_number: float | None,
    iso: float,
    make: str,
    model: str,
    serial: str,
    capture_time: datetime | None,
    temperature_c: float | None,
    place: PlaceTime | None = None,
    focal_length_mm: float | None = None,
    focal_length_35mm_mm: float | None = None,
) -> bytes:
    """The DNG bytes of a little-endian uint16 ``image`` (H, W) or (H, W, samples)."""
    h, w = image.shape[:2]
    spp = len(samples)
    ifd0 = _IFD()
    exif = _IFD()
    when = add_time_tags(exif, capture_time, place)
    gps = gps_ifd(place) if place is not None and place.has_gps else None
    ifd0.add(254, _LONG, [0])
    ifd0.add(256, _LONG, [w])
    ifd0.add(257, _LONG, [h])
    ifd0.add(258, _SHORT, [16] * spp)
    ifd0.add(259, _SHORT, [1])
    ifd0.add(262, _SHORT, [photometric])
    ifd0.add(271, _ASCII, make)
    ifd0.add(272, _ASCII, model)
    ifd0.add(273, _LONG, [0])  # patched below
    ifd0.add(274, _SHORT, [1])
    ifd0.add(277, _SHORT, [spp])
    ifd0.add(278, _LONG, [h])
    ifd0.add(279, _LONG, [image.nbytes])
    ifd0.add(284, _SHORT, [1])
    ifd0.add(305, _ASCII, "camcal.synth")
    ifd0.add(306, _ASCII, when)
    if cfa_pattern is not None:
        ifd0.add(33421, _SHORT, [2, 2])
        ifd0.add(33422, _BYTE, [_CFA_CODE[c] for c in cfa_pattern])
    ifd0.add(34665, _LONG, [0])  # patched below
    if gps is not None:
        ifd0.add(TAG_GPS_IFD, _LONG, [0])  # patched below
    ifd0.add(50706, _BYTE, [1, 4, 0, 0])
    ifd0.add(50707, _BYTE, [1, 1, 0, 0])
    ifd0.add(50708, _ASCII, f"{make} {model}")
    if cfa_pattern is not None:
        ifd0.add(50710, _BYTE, [0, 1, 2])
        ifd0.add(50711, _SHORT, [1])
        ifd0.add(50713, _SHORT, [2, 2])
    else:
        ifd0.add(50713, _SHORT, [1, 1])
    ifd0.add(50714, _RATIONAL, black)
    ifd0.add(50717, _LONG, white)
    # ColorMatrix1: ColorPlanes x 3 (a monochrome image: one row, the XYZ of the white point D50)
    ifd0.add(50721, _SRATIONAL, [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] if spp == 3 or cfa_pattern else
             [0.9642, 1.0, 0.8249])
    ifd0.add(50735, _ASCII, serial)
    ifd0.add(50778, _SHORT, [21])

    exif.add(33434, _RATIONAL, [exposure_s])
    if f_number is not None:
        exif.add(33437, _RATIONAL, [f_number])
    exif.add(34855, _SHORT, [int(round(iso))])
    if focal_length_mm is not None:
        exif.add(37386, _RATIONAL, [focal_length_mm])  # FocalLength
    if focal_length_35mm_mm is not None:
        exif.add(41989, _SHORT, [int(round(focal_length_35mm_mm))])  # FocalLengthIn35mmFilm
    exif.add(34864, _SHORT, [3])  # SensitivityType: ISO speed
    exif.add(34867, _LONG, [int(round(iso))])  # ISOSpeed
    exif.add(36864, _UNDEFINED, b"0230")
    exif.add(42033, _ASCII, serial)
    if temperature_c is not None:
        exif.add(37888, _SRATIONAL, [temperature_c])  # Exif 2.31 Temperature
    return pack_tiff(ifd0, exif, gps, image.tobytes())


def write_dng(path: str | Path, mosaic: np.ndarray, **kwargs) -> Path:
    """Write :func:`encode_dng` output to ``path`` atomically; returns the path."""
    return atomic_write_bytes(path, encode_dng(mosaic, **kwargs))


def write_linear_dng(path: str | Path, rgb: np.ndarray, **kwargs) -> Path:
    """Write :func:`encode_linear_dng` output to ``path`` atomically; returns the path."""
    return atomic_write_bytes(path, encode_linear_dng(rgb, **kwargs))

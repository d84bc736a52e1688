"""Minimal, honest DNG writer for the synthetic camera.

Writes an uncompressed little-endian DNG 1.4 file holding one CFA mosaic
(:func:`encode_dng`, PhotometricInterpretation 32803) or one linear R, G, B image
(:func:`encode_linear_dng`, LinearRaw, PhotometricInterpretation 34892, SamplesPerPixel 3,
which LibRaw reads as a 3-colour stack), with the exposure metadata in an Exif sub-IFD
(where LibRaw reads ISO from), so that ``rawpy`` decodes the file and reports exposure
time, f-number and ISO. A fixed-aperture camera writes no FNumber tag (``f_number=None``).

References
----------
Adobe, *Digital Negative (DNG) Specification*, version 1.4.0.0 (2012).
CIPA DC-008, *Exif 2.3*, tags 33434, 33437, 34855, 36867.
"""

from __future__ import annotations

import struct
from datetime import datetime
from fractions import Fraction
from pathlib import Path

import numpy as np

from camcal.atomic import atomic_write_bytes

# TIFF field types
_BYTE, _ASCII, _SHORT, _LONG, _RATIONAL, _UNDEFINED, _SRATIONAL = 1, 2, 3, 4, 5, 7, 10
_TYPE_SIZE = {_BYTE: 1, _ASCII: 1, _SHORT: 2, _LONG: 4, _RATIONAL: 8, _UNDEFINED: 1, _SRATIONAL: 8}
_CFA_CODE = {"R": 0, "G": 1, "B": 2}


def _rational(value: float, max_den: int = 1_000_000) -> tuple[int, int]:
    fr = Fraction(value).limit_denominator(max_den)
    return fr.numerator, fr.denominator


def _encode(ftype: int, values) -> bytes:
    if ftype == _ASCII:
        raw = values.encode("ascii", "replace") + b"\x00"
        return raw
    if ftype in (_BYTE, _UNDEFINED):
        return bytes(values)
    if ftype == _SHORT:
        return struct.pack(f"<{len(values)}H", *values)
    if ftype == _LONG:
        return struct.pack(f"<{len(values)}I", *values)
    if ftype == _RATIONAL:
        flat = [x for v in values for x in _rational(v)]
        return struct.pack(f"<{len(flat)}I", *flat)
    if ftype == _SRATIONAL:
        flat = [x for v in values for x in _rational(v, 10_000)]
        return struct.pack(f"<{len(flat)}i", *flat)
    raise ValueError(ftype)


class _IFD:
    def __init__(self) -> None:
        self.entries: dict[int, tuple[int, bytes, int]] = {}

    def add(self, tag: int, ftype: int, values) -> None:
        payload = _encode(ftype, values)
        count = len(payload) // _TYPE_SIZE[ftype]
        self.entries[tag] = (ftype, payload, count)

    def size(self) -> int:
        return 2 + 12 * len(self.entries) + 4

    def data_size(self) -> int:
        n = 0
        for _, payload, _ in self.entries.values():
            if len(payload) > 4:
                n += len(payload) + (len(payload) & 1)
        return n

    def pack(self, offset: int, next_ifd: int = 0) -> bytes:
        """Serialise at file ``offset``; overflow data follows the entry table."""
        data_off = offset + self.size()
        table = [struct.pack("<H", len(self.entries))]
        blobs = []
        for tag in sorted(self.entries):
            ftype, payload, count = self.entries[tag]
            if len(payload) <= 4:
                table.append(struct.pack("<HHI", tag, ftype, count) + payload.ljust(4, b"\x00"))
            else:
                table.append(struct.pack("<HHII", tag, ftype, count, data_off))
                pad = payload + (b"\x00" if len(payload) & 1 else b"")
                blobs.append(pad)
                data_off += len(pad)
        table.append(struct.pack("<I", next_ifd))
        return b"".join(table) + b"".join(blobs)


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
) -> bytes:
    """The DNG bytes of a little-endian uint16 ``image`` (H, W) or (H, W, samples)."""
    h, w = image.shape[:2]
    spp = len(samples)
    when = (capture_time or datetime(2026, 1, 1, 12, 0, 0)).strftime("%Y:%m:%d %H:%M:%S")

    ifd0 = _IFD()
    exif = _IFD()
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
    ifd0.add(50721, _SRATIONAL, [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
    ifd0.add(50735, _ASCII, serial)
    ifd0.add(50778, _SHORT, [21])

    exif.add(33434, _RATIONAL, [exposure_s])
    if f_number is not None:
        exif.add(33437, _RATIONAL, [f_number])
    exif.add(34855, _SHORT, [int(round(iso))])
    exif.add(34864, _SHORT, [3])  # SensitivityType: ISO speed
    exif.add(34867, _LONG, [int(round(iso))])  # ISOSpeed
    exif.add(36864, _UNDEFINED, b"0230")
    exif.add(36867, _ASCII, when)
    exif.add(42033, _ASCII, serial)
    if temperature_c is not None:
        exif.add(37888, _SRATIONAL, [temperature_c])  # Exif 2.31 Temperature

    ifd0_off = 8
    exif_off = ifd0_off + ifd0.size() + ifd0.data_size()
    exif_off += exif_off & 1
    strip_off = exif_off + exif.size() + exif.data_size()
    strip_off += (-strip_off) % 16
    ifd0.add(273, _LONG, [strip_off])
    ifd0.add(34665, _LONG, [exif_off])

    out = bytearray(b"II*\x00" + struct.pack("<I", ifd0_off))
    out += ifd0.pack(ifd0_off)
    out += b"\x00" * (exif_off - len(out))
    out += exif.pack(exif_off)
    out += b"\x00" * (strip_off - len(out))
    out += image.tobytes()
    return bytes(out)


def encode_exif_app1(
    *,
    exposure_s: float | None,
    f_number: float | None,
    iso: float | None,
    make: str,
    model: str,
    capture_time: datetime | None = None,
) -> bytes:
    """An Exif APP1 segment (marker included) for a JPEG, with exact rational exposure tags."""
    when = (capture_time or datetime(2026, 1, 1, 12, 0, 0)).strftime("%Y:%m:%d %H:%M:%S")
    ifd0, exif = _IFD(), _IFD()
    ifd0.add(271, _ASCII, make)
    ifd0.add(272, _ASCII, model)
    ifd0.add(274, _SHORT, [1])
    ifd0.add(305, _ASCII, "camcal.synth")
    ifd0.add(306, _ASCII, when)
    ifd0.add(34665, _LONG, [0])
    if exposure_s:
        exif.add(33434, _RATIONAL, [exposure_s])
    if f_number:
        exif.add(33437, _RATIONAL, [f_number])
    if iso:
        exif.add(34855, _SHORT, [int(round(iso))])
    exif.add(36864, _UNDEFINED, b"0230")
    exif.add(36867, _ASCII, when)
    exif.add(40961, _SHORT, [1])  # ColorSpace: sRGB
    exif_off = 8 + ifd0.size() + ifd0.data_size()
    exif_off += exif_off & 1
    ifd0.add(34665, _LONG, [exif_off])
    tiff = bytearray(b"II*\x00" + struct.pack("<I", 8))
    tiff += ifd0.pack(8)
    tiff += b"\x00" * (exif_off - len(tiff))
    tiff += exif.pack(exif_off)
    payload = b"Exif\x00\x00" + bytes(tiff)
    return b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload


def write_dng(path: str | Path, mosaic: np.ndarray, **kwargs) -> Path:
    """Write :func:`encode_dng` output to ``path`` atomically; returns the path."""
    return atomic_write_bytes(path, encode_dng(mosaic, **kwargs))


def write_linear_dng(path: str | Path, rgb: np.ndarray, **kwargs) -> Path:
    """Write :func:`encode_linear_dng` output to ``path`` atomically; returns the path."""
    return atomic_write_bytes(path, encode_linear_dng(rgb, **kwargs))

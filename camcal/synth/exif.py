"""EXIF blocks for the synthetic camera's files: TIFF IFD primitives, exposure tags, place and time.

The DNG writer (:mod:`camcal.synth.dng`), the JPEG writer (:func:`camcal.synth.camera.write_jpeg_file`)
and the HEIC writer (:func:`camcal.synth.heic.write_heic`) share these, so that a synthetic photo carries
what a phone writes: exposure time, f-number and ISO, DateTimeOriginal (local clock time),
OffsetTimeOriginal (the clock's zone, Exif 2.31), and a GPS block with the position and the UTC
GPSDateStamp/GPSTimeStamp. :class:`PlaceTime` states one capture instant and place; each tag can be left
out (an older phone writes no offset, a camera without a receiver no GPS block) or written wrong in the
way real cameras do (a GPS date off by a day).

References
----------
CIPA DC-008-2019, *Exif 2.32*: tags 33434 ExposureTime, 33437 FNumber, 34855 ISO, 36867
DateTimeOriginal, 36881 OffsetTimeOriginal, 34853 GPSInfo; GPS tags 0–7 and 29 (GPSDateStamp).
Adobe, *TIFF 6.0* §2 (IFD layout, field types).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from fractions import Fraction

from camcal.errors import CamcalError
from camcal.io.manifest import parse_utc_offset

# TIFF field types
_BYTE, _ASCII, _SHORT, _LONG, _RATIONAL, _UNDEFINED, _SRATIONAL = 1, 2, 3, 4, 5, 7, 10
_TYPE_SIZE = {_BYTE: 1, _ASCII: 1, _SHORT: 2, _LONG: 4, _RATIONAL: 8, _UNDEFINED: 1, _SRATIONAL: 8}

TAG_GPS_IFD = 34853
"""IFD0 pointer to the GPS IFD."""
TAG_EXIF_IFD = 34665
"""IFD0 pointer to the Exif IFD."""


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
    """One little-endian TIFF image file directory, serialised with its overflow data after the table."""

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

    def total_size(self) -> int:
        """Bytes of the table and its overflow data."""
        return self.size() + self.data_size()

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


def offset_text(minutes: int) -> str:
    """An offset from UTC in minutes as Exif text, ``+HH:MM`` (e.g. 60 → ``+01:00``, -330 → ``-05:30``)."""
    sign = "-" if minutes < 0 else "+"
    h, m = divmod(abs(int(minutes)), 60)
    return f"{sign}{h:02d}:{m:02d}"


@dataclass(frozen=True)
class PlaceTime:
    """Where and when a synthetic photo is taken, and which of it the file's EXIF states.

    Attributes
    ----------
    utc : datetime
        The capture instant; an aware datetime, or a naive one meaning UTC.
    utc_offset_min : int
        The camera clock's offset from UTC, minutes: DateTimeOriginal = ``utc`` + offset (local clock time).
    latitude_deg, longitude_deg : float or None
        WGS-84 position in degrees (north, east positive); None writes no GPS position.
    altitude_m : float or None
        Altitude above sea level, m; None writes none.
    write_offset : bool
        Write OffsetTimeOriginal (Exif 2.31; phones since about 2017 do, older cameras do not).
    write_gps_time : bool
        Write GPSDateStamp and GPSTimeStamp (UTC) in the GPS block.
    gps_date_shift_days : int
        Days added to the written GPSDateStamp only (0: correct); some Nikon Coolpix cameras write a GPS
        date one day after the true one.
    """

    utc: datetime
    utc_offset_min: int = 0
    latitude_deg: float | None = None
    longitude_deg: float | None = None
    altitude_m: float | None = None
    write_offset: bool = True
    write_gps_time: bool = True
    gps_date_shift_days: int = 0

    @property
    def utc_aware(self) -> datetime:
        return self.utc.replace(tzinfo=UTC) if self.utc.tzinfo is None else self.utc.astimezone(UTC)

    @property
    def local_time(self) -> datetime:
        """The camera clock's reading (naive), as DateTimeOriginal states it."""
        return (self.utc_aware + timedelta(minutes=self.utc_offset_min)).replace(tzinfo=None)

    @property
    def offset(self) -> str:
        """The clock's offset as OffsetTimeOriginal text (``+02:00``)."""
        return offset_text(self.utc_offset_min)

    @property
    def has_gps(self) -> bool:
        return (self.latitude_deg is not None and self.longitude_deg is not None) or self.write_gps_time


def place_time_from_text(utc: str, gps: str | None = None, utc_offset: str = "+00:00", *,
                         write_offset: bool = True, write_gps_time: bool = True) -> PlaceTime:
    """A :class:`PlaceTime` from command-line text: ``utc`` an ISO 8601 instant (``YYYY-MM-DDThh:mm:ssZ``; a
    time without a zone is UTC), ``gps`` ``LAT,LON`` or ``LAT,LON,ALT_M`` (degrees north and east, metres),
    ``utc_offset`` the camera clock's zone ``+HH:MM``.

    Raises
    ------
    CamcalError
        Any part that does not parse or is out of range, in one line.
    """
    try:
        when = datetime.fromisoformat(utc.strip().replace("Z", "+00:00").replace("z", "+00:00"))
    except ValueError:
        raise CamcalError(f"--utc {utc!r}: expected an ISO 8601 time such as 2026-06-21T10:30:00Z") from None
    minutes = parse_utc_offset(utc_offset)
    if minutes is None:
        raise CamcalError(f"--utc-offset {utc_offset!r}: expected +HH:MM between -12:00 and +14:00")
    lat = lon = alt = None
    if gps is not None:
        try:
            parts = [float(x) for x in gps.split(",")]
            if len(parts) not in (2, 3):
                raise ValueError
        except ValueError:
            raise CamcalError(f"--gps {gps!r}: expected LAT,LON or LAT,LON,ALT_M (degrees, metres)") from None
        lat, lon = parts[0], parts[1]
        alt = parts[2] if len(parts) == 3 else None
        if not (-90 <= lat <= 90 and -180 <= lon <= 180) or (lat == 0 and lon == 0):
            raise CamcalError(f"--gps {gps!r}: latitude must be in [-90, 90], longitude in [-180, 180], not 0,0")
    return PlaceTime(when, minutes, lat, lon, alt, write_offset=write_offset, write_gps_time=write_gps_time)


def _dms(value_deg: float) -> list[float]:
    """Degrees as the GPS block's degrees, minutes, seconds (three rationals)."""
    v = abs(float(value_deg))
    d = int(v)
    m = int((v - d) * 60.0)
    s = (v - d - m / 60.0) * 3600.0
    return [float(d), float(m), round(s, 6)]


def gps_ifd(place: PlaceTime) -> _IFD:
    """The GPS IFD of ``place``: version, position, altitude, UTC date and time (what it writes)."""
    gps = _IFD()
    gps.add(0, _BYTE, [2, 3, 0, 0])  # GPSVersionID
    if place.latitude_deg is not None and place.longitude_deg is not None:
        gps.add(1, _ASCII, "N" if place.latitude_deg >= 0 else "S")
        gps.add(2, _RATIONAL, _dms(place.latitude_deg))
        gps.add(3, _ASCII, "E" if place.longitude_deg >= 0 else "W")
        gps.add(4, _RATIONAL, _dms(place.longitude_deg))
    if place.altitude_m is not None:
        gps.add(5, _BYTE, [0 if place.altitude_m >= 0 else 1])
        gps.add(6, _RATIONAL, [abs(float(place.altitude_m))])
    if place.write_gps_time:
        u = place.utc_aware
        sec = u.second + u.microsecond / 1e6
        gps.add(7, _RATIONAL, [float(u.hour), float(u.minute), round(sec, 3)])
        gps.add(29, _ASCII, (u + timedelta(days=place.gps_date_shift_days)).strftime("%Y:%m:%d"))
    return gps


def exif_time_text(when: datetime | None) -> str:
    """DateTimeOriginal text of a naive local time (the synthetic camera's fixed date when None)."""
    return (when or datetime(2026, 1, 1, 12, 0, 0)).strftime("%Y:%m:%d %H:%M:%S")


def add_time_tags(exif: _IFD, when: datetime | None, place: PlaceTime | None) -> str:
    """DateTimeOriginal (and OffsetTimeOriginal when ``place`` says so) into the Exif IFD; returns the text.

    With a ``place``, the local time is its clock reading and ``when`` is ignored.
    """
    text = exif_time_text(place.local_time if place is not None else when)
    exif.add(36867, _ASCII, text)
    if place is not None and place.write_offset:
        exif.add(36881, _ASCII, place.offset)  # OffsetTimeOriginal
    return text


def encode_exif_tiff(
    *,
    exposure_s: float | None,
    f_number: float | None,
    iso: float | None,
    make: str,
    model: str,
    capture_time: datetime | None = None,
    place: PlaceTime | None = None,
    colour_space: int | None = 1,
    focal_length_mm: float | None = None,
    focal_length_35mm_mm: float | None = None,
) -> bytes:
    """The TIFF structure of an EXIF block (IFD0, Exif IFD, GPS IFD when ``place`` has any GPS data).

    Exact rational exposure tags; a value None is not written (the file does not hold it). ``focal_length_35mm_mm``
    is written as FocalLengthIn35mmFilm (a SHORT: whole millimetres, as cameras write it).
    ``colour_space`` 1 is sRGB, 0xFFFF uncalibrated (as phones with Display P3 write), None: no tag.
    """
    ifd0, exif = _IFD(), _IFD()
    ifd0.add(271, _ASCII, make)
    ifd0.add(272, _ASCII, model)
    ifd0.add(274, _SHORT, [1])
    ifd0.add(305, _ASCII, "camcal.synth")
    ifd0.add(TAG_EXIF_IFD, _LONG, [0])
    gps = gps_ifd(place) if place is not None and place.has_gps else None
    if gps is not None:
        ifd0.add(TAG_GPS_IFD, _LONG, [0])
    if exposure_s:
        exif.add(33434, _RATIONAL, [exposure_s])
    if f_number:
        exif.add(33437, _RATIONAL, [f_number])
    if iso:
        exif.add(34855, _SHORT, [int(round(iso))])
    exif.add(36864, _UNDEFINED, b"0230")
    if focal_length_mm:
        exif.add(37386, _RATIONAL, [focal_length_mm])  # FocalLength
    if focal_length_35mm_mm:
        exif.add(41989, _SHORT, [int(round(focal_length_35mm_mm))])  # FocalLengthIn35mmFilm
    when = add_time_tags(exif, capture_time, place)
    ifd0.add(306, _ASCII, when)
    if colour_space is not None:
        exif.add(40961, _SHORT, [int(colour_space)])
    return pack_tiff(ifd0, exif, gps)


def pack_tiff(ifd0: _IFD, exif: _IFD, gps: _IFD | None = None, strip: bytes | None = None) -> bytes:
    """A little-endian TIFF (TIFF 6.0 §2): the header, IFD0 at offset 8, the Exif IFD and the GPS IFD (when
    given) after it at even offsets, then ``strip`` (the image data, when given) at a 16-byte boundary.

    IFD0's pointers to the Exif and GPS IFDs (34665, 34853) and its StripOffsets (273) are set here; IFD0 must
    already hold those tags (any value), so that its size does not change when they are set.
    """
    exif_off = 8 + ifd0.total_size()
    exif_off += exif_off & 1
    gps_off = exif_off + exif.total_size()
    gps_off += gps_off & 1
    end = gps_off + (gps.total_size() if gps is not None else 0)
    strip_off = end + (-end) % 16
    ifd0.add(TAG_EXIF_IFD, _LONG, [exif_off])
    if gps is not None:
        ifd0.add(TAG_GPS_IFD, _LONG, [gps_off])
    if strip is not None:
        ifd0.add(273, _LONG, [strip_off])
    out = bytearray(b"II*\x00" + struct.pack("<I", 8))
    out += ifd0.pack(8)
    out += b"\x00" * (exif_off - len(out))
    out += exif.pack(exif_off)
    if gps is not None:
        out += b"\x00" * (gps_off - len(out))
        out += gps.pack(gps_off)
    if strip is not None:
        out += b"\x00" * (strip_off - len(out))
        out += strip
    return bytes(out)


def encode_exif_app1(
    *,
    exposure_s: float | None,
    f_number: float | None,
    iso: float | None,
    make: str,
    model: str,
    capture_time: datetime | None = None,
    place: PlaceTime | None = None,
    focal_length_mm: float | None = None,
    focal_length_35mm_mm: float | None = None,
) -> bytes:
    """An Exif APP1 segment (marker included) for a JPEG, with exact rational exposure tags."""
    payload = b"Exif\x00\x00" + encode_exif_tiff(exposure_s=exposure_s, f_number=f_number, iso=iso, make=make,
                                                  model=model, capture_time=capture_time, place=place,
                                                  focal_length_mm=focal_length_mm,
                                                  focal_length_35mm_mm=focal_length_35mm_mm)
    return b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload

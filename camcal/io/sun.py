"""The sun from a photo: its UTC capture time, its GPS position, and pvlib's solar position.

A field photo of a Secchi disk in sunshine needs the sun's zenith angle (the direct beam's refracted path)
and azimuth. Both follow from the capture instant in UTC and the place (docs/conventions.md, "Time and the
sun"):

- **UTC time**, from the first of (:func:`photo_time_utc`):

  1. the GPS block's time stamp (GPSDateStamp + GPSTimeStamp, UTC by definition);
  2. DateTimeOriginal (the camera clock, no zone) with OffsetTimeOriginal (Exif 2.31);
  3. DateTimeOriginal with ``utc_offset`` from ``session.toml`` (or given by the caller).

  A time zone is never guessed: without one of these the time is unknown. Where both the GPS time and the
  camera clock are known, their difference is the offset they imply; an implied offset that no time zone has
  (outside −12:00 … +14:00), or that disagrees with the stated offset by more than
  :data:`CLOCK_TOLERANCE_MIN`, is noted (some Nikon Coolpix cameras write a GPS date one day late).
- **Place**: the GPS block's latitude, longitude and altitude (WGS-84).
- **Solar position**: ``pvlib.solarposition.get_solarposition`` (NREL SPA, Reda & Andreas 2004): the true
  zenith angle, the apparent zenith angle (with atmospheric refraction) and the azimuth, degrees clockwise
  from true north (0° north, 90° east).

``--sun ZENITH,AZIMUTH`` (:func:`parse_sun_option`) states the sun instead, for photos that hold neither.

References
----------
Reda, I. & Andreas, A. (2004). Solar position algorithm for solar radiation applications. *Solar Energy* 76,
577–589. CIPA DC-008-2019, *Exif 2.32*, OffsetTimeOriginal (0x9011), GPSTimeStamp (GPS 0x0007),
GPSDateStamp (GPS 0x001D).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pandas as pd
import pvlib

from camcal.errors import CamcalError
from camcal.frame import Exposure
from camcal.io.manifest import parse_utc_offset
from camcal.io.read import read_photo_metadata

CLOCK_TOLERANCE_MIN = 15.0
"""Largest difference, minutes, between the offset the GPS time and the camera clock imply and the stated
offset before it is noted (a camera clock drifts by minutes; a zone or a date error is an hour or a day)."""

SUN_OPTION = "--sun ZENITH,AZIMUTH"
"""How a user states the sun where a photo cannot place it (degrees; azimuth clockwise from north)."""

SOURCE_GPS = "GPS time stamp"
SOURCE_OFFSET = "DateTimeOriginal+OffsetTimeOriginal"
SOURCE_SESSION = "DateTimeOriginal+session.toml utc_offset"
SOURCE_GIVEN = "DateTimeOriginal+utc_offset given"
SOURCE_OPTION = "--sun"


@dataclass(frozen=True)
class SunPosition:
    """Where the sun stands, seen from the photo's place at its capture instant.

    Attributes
    ----------
    zenith_deg : float
        True (geometric) solar zenith angle, degrees from the vertical.
    azimuth_deg : float
        Solar azimuth, degrees clockwise from true north (90° = east).
    apparent_zenith_deg : float
        Zenith angle with atmospheric refraction (pvlib's ``apparent_zenith``), degrees; equal to
        ``zenith_deg`` when the sun is stated with ``--sun``.
    source : str
        Where it came from, e.g. ``"GPS time stamp + GPS position"``, ``"--sun"``.
    utc : datetime or None
        The UTC instant used (None for ``--sun``).
    latitude_deg, longitude_deg, altitude_m : float or None
        The place used (WGS-84; altitude None when the file holds none).
    notes : tuple of str
        Disagreements noted on the way (e.g. a GPS date that disagrees with the camera's date).
    """

    zenith_deg: float
    azimuth_deg: float
    apparent_zenith_deg: float
    source: str
    utc: datetime | None = None
    latitude_deg: float | None = None
    longitude_deg: float | None = None
    altitude_m: float | None = None
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: the angles, the source, the instant (ISO text) and place used, the notes."""
        return {
            "zenith_deg": self.zenith_deg,
            "azimuth_deg": self.azimuth_deg,
            "apparent_zenith_deg": self.apparent_zenith_deg,
            "source": self.source,
            "utc": None if self.utc is None else self.utc.isoformat(),
            "latitude_deg": self.latitude_deg,
            "longitude_deg": self.longitude_deg,
            "altitude_m": self.altitude_m,
            "notes": list(self.notes),
        }


@dataclass(frozen=True)
class CaptureTime:
    """A photo's capture instant in UTC and how it was found.

    Attributes
    ----------
    utc : datetime or None
        Aware UTC datetime; None when no source in the order of :func:`photo_time_utc` gives one.
    source : str or None
        One of ``"GPS time stamp"``, ``"DateTimeOriginal+OffsetTimeOriginal"``,
        ``"DateTimeOriginal+session.toml utc_offset"``, ``"DateTimeOriginal+utc_offset given"``; None when unknown.
    local : str or None
        The camera clock's reading (ISO text, no zone), when known.
    utc_offset : str or None
        The offset used or stated (``+HH:MM``), when known.
    offset_source : str or None
        Where the offset came from: ``tag`` (OffsetTimeOriginal), ``session`` (``session.toml``), ``given``.
    implied_offset_min : float or None
        Camera clock minus GPS time, minutes, when both are known.
    gps_date_disagrees : bool
        The GPS date disagrees with the local date beyond the offset (the flag of a GPS date off by a day).
    notes : tuple of str
        Why a time is unknown, and every disagreement noted.
    """

    utc: datetime | None
    source: str | None
    local: str | None = None
    utc_offset: str | None = None
    offset_source: str | None = None
    implied_offset_min: float | None = None
    gps_date_disagrees: bool = False
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, object]:
        return {
            "utc": None if self.utc is None else self.utc.isoformat(),
            "source": self.source,
            "local": self.local,
            "utc_offset": self.utc_offset,
            "offset_source": self.offset_source,
            "implied_offset_min": self.implied_offset_min,
            "gps_date_disagrees": self.gps_date_disagrees,
            "notes": list(self.notes),
        }


def _fmt_offset(minutes: float) -> str:
    sign = "-" if minutes < 0 else "+"
    h, m = divmod(int(round(abs(minutes))), 60)
    return f"{sign}{h:02d}:{m:02d}"


def photo_time_utc(exposure: Exposure, *, utc_offset: str | None = None) -> CaptureTime:
    """The UTC capture instant of a photo from its metadata, in the order of the module docstring.

    Parameters
    ----------
    exposure : Exposure
        The photo's metadata (:func:`camcal.io.read.read_photo_metadata` or a frame's ``exposure``):
        ``gps_time_utc``, ``capture_time`` (local clock), ``utc_offset`` with their sources.
    utc_offset : str, optional
        ``+HH:MM``: the camera clock's offset, stated by the caller; ranks as ``session.toml``'s
        ``utc_offset`` (after the file's own GPS time and OffsetTimeOriginal) and above it.

    Raises
    ------
    CamcalError
        ``utc_offset`` is not an offset of a time zone.
    """
    given_min = None
    if utc_offset is not None:
        given_min = parse_utc_offset(utc_offset)
        if given_min is None:
            raise CamcalError(f"utc_offset {utc_offset!r} is not an offset from UTC as +HH:MM between -12:00 "
                              "and +14:00")
    notes: list[str] = []
    local = None
    if exposure.capture_time:
        try:
            local = datetime.fromisoformat(exposure.capture_time).replace(tzinfo=None)
        except ValueError:
            notes.append(f"capture time {exposure.capture_time!r} is not a date and time; not used")
    gps = datetime.fromisoformat(exposure.gps_time_utc).astimezone(UTC) if exposure.gps_time_utc else None

    offset_min, offset_src, offset_text = None, None, None
    if exposure.utc_offset is not None and exposure.source("utc_offset") == "tag":
        offset_min, offset_src = parse_utc_offset(exposure.utc_offset), "tag"
    elif given_min is not None:
        offset_min, offset_src = given_min, "given"
    elif exposure.utc_offset is not None:
        offset_min, offset_src = parse_utc_offset(exposure.utc_offset), exposure.source("utc_offset") or "session"
    if offset_min is not None:
        offset_text = _fmt_offset(offset_min)

    implied = disagrees = None
    if gps is not None and local is not None:
        implied = (local - gps.replace(tzinfo=None)).total_seconds() / 60.0
        if offset_min is not None:
            if abs(implied - offset_min) > CLOCK_TOLERANCE_MIN:
                days = round((implied - offset_min) / 1440.0)
                disagrees = days != 0
                what = (f"the GPS date {gps.date().isoformat()} disagrees with the local date "
                        f"{local.date().isoformat()} beyond the offset {offset_text} (by {abs(days)} day"
                        f"{'s' if abs(days) != 1 else ''})" if disagrees else
                        f"the camera clock ({local.isoformat()} {offset_text}) and the GPS time "
                        f"({gps.isoformat()}) differ by {implied - offset_min:+.0f} min")
                notes.append(f"{what}; the GPS time is used")
        elif not -12 * 60 - CLOCK_TOLERANCE_MIN <= implied <= 14 * 60 + CLOCK_TOLERANCE_MIN:
            disagrees = True
            notes.append(f"the GPS date {gps.date().isoformat()} disagrees with the local date "
                         f"{local.date().isoformat()}: GPS time {gps.strftime('%H:%M:%S')} UTC and camera clock "
                         f"{local.strftime('%H:%M:%S')} imply an offset of {_fmt_offset(implied)}, which no time "
                         "zone has (the GPS date may be a day off); the GPS time is used")

    common = dict(local=None if local is None else local.isoformat(), utc_offset=offset_text,
                  offset_source=offset_src, implied_offset_min=implied, gps_date_disagrees=bool(disagrees))
    if gps is not None:
        return CaptureTime(gps, SOURCE_GPS, notes=tuple(notes), **common)
    if local is None:
        notes.append("no capture time: the file holds no GPS time stamp and no DateTimeOriginal")
        return CaptureTime(None, None, notes=tuple(notes), **common)
    if offset_min is None:
        notes.append("no time zone: the file holds no GPS time stamp and no OffsetTimeOriginal, and no utc_offset "
                     "is given (session.toml); a time zone is never guessed")
        return CaptureTime(None, None, notes=tuple(notes), **common)
    source = {"tag": SOURCE_OFFSET, "given": SOURCE_GIVEN}.get(offset_src or "", SOURCE_SESSION)
    utc = (local - timedelta(minutes=offset_min)).replace(tzinfo=UTC)
    return CaptureTime(utc, source, notes=tuple(notes), **common)


def sun_position(utc: datetime, latitude_deg: float, longitude_deg: float, altitude_m: float | None = None,
                 source: str = "") -> SunPosition:
    """pvlib's solar position (NREL SPA) at ``utc`` seen from a place.

    Parameters
    ----------
    utc : datetime
        The instant; aware (any zone), or naive meaning UTC.
    latitude_deg, longitude_deg : float
        WGS-84 degrees, north and east positive.
    altitude_m : float, optional
        Altitude above sea level, m (pvlib's default, 0 m, when None).
    source : str
        Recorded on the result.
    """
    if not (-90.0 <= latitude_deg <= 90.0 and -180.0 <= longitude_deg <= 180.0):
        raise CamcalError(f"position {latitude_deg}°, {longitude_deg}° is outside latitude ±90°, longitude ±180°")
    u = utc.replace(tzinfo=UTC) if utc.tzinfo is None else utc.astimezone(UTC)
    pos = pvlib.solarposition.get_solarposition(pd.DatetimeIndex([u]), latitude_deg, longitude_deg,
                                                altitude=altitude_m)
    row = pos.iloc[0]
    return SunPosition(zenith_deg=float(row["zenith"]), azimuth_deg=float(row["azimuth"]),
                       apparent_zenith_deg=float(row["apparent_zenith"]), source=source, utc=u,
                       latitude_deg=float(latitude_deg), longitude_deg=float(longitude_deg),
                       altitude_m=None if altitude_m is None else float(altitude_m))


def parse_sun_option(text: str) -> SunPosition:
    """``--sun ZENITH,AZIMUTH`` (degrees) as a :class:`SunPosition` with source ``"--sun"``.

    The zenith angle must be in [0, 90) (the sun above the horizon), the azimuth in [0, 360] (clockwise from
    north). Units may be written (``30deg``, ``30°``).
    """
    parts = [p.strip().removesuffix("°").removesuffix("deg").strip() for p in str(text).split(",")]
    try:
        if len(parts) != 2:
            raise ValueError
        zenith, azimuth = float(parts[0]), float(parts[1])
    except ValueError:
        raise CamcalError(f"--sun {text!r}: expected ZENITH,AZIMUTH in degrees, e.g. --sun 35,160") from None
    if not 0.0 <= zenith < 90.0:
        raise CamcalError(f"--sun {text!r}: the zenith angle must be from 0 to below 90 degrees (the sun above "
                          "the horizon)")
    if not 0.0 <= azimuth <= 360.0:
        raise CamcalError(f"--sun {text!r}: the azimuth must be from 0 to 360 degrees, clockwise from north")
    return SunPosition(zenith_deg=zenith, azimuth_deg=azimuth % 360.0, apparent_zenith_deg=zenith,
                       source=SOURCE_OPTION)


def sun_from_metadata(exposure: Exposure, *, utc_offset: str | None = None,
                      path: str | Path | None = None) -> SunPosition:
    """The sun of a photo whose metadata is ``exposure`` (see :func:`photo_sun`)."""
    when = photo_time_utc(exposure, utc_offset=utc_offset)
    missing = []
    if when.utc is None:
        missing.append("no capture time (no GPS time stamp, no DateTimeOriginal)" if when.local is None else
                       "no time zone (no GPS time stamp, no OffsetTimeOriginal, no utc_offset in session.toml)")
    if exposure.latitude_deg is None or exposure.longitude_deg is None:
        missing.append("no GPS position")
    if missing:
        raise CamcalError(f"cannot place the sun: {' and '.join(missing)}; give {SUN_OPTION} (degrees, azimuth "
                          "clockwise from north)", path)
    return _with_notes(sun_position(when.utc, exposure.latitude_deg, exposure.longitude_deg,  # type: ignore[arg-type]
                                    exposure.altitude_m, source=f"{when.source} + GPS position"), when.notes)


def _with_notes(sun: SunPosition, notes: tuple[str, ...]) -> SunPosition:
    return SunPosition(sun.zenith_deg, sun.azimuth_deg, sun.apparent_zenith_deg, sun.source, sun.utc,
                       sun.latitude_deg, sun.longitude_deg, sun.altitude_m, tuple(notes))


def photo_sun(path: str | Path, *, utc_offset: str | None = None) -> SunPosition:
    """The sun of a photo (RAW, JPEG or HEIC) from its EXIF capture time and GPS position.

    Reads the file's tags only (:func:`camcal.io.read.read_photo_metadata`, ``session.toml`` applied), finds the
    UTC time (:func:`photo_time_utc`) and computes :func:`sun_position`.

    Raises
    ------
    CamcalError
        One line naming the file, when it holds no usable time or no GPS position: it asks for
        ``--sun ZENITH,AZIMUTH``.
    """
    return sun_from_metadata(read_photo_metadata(path), utc_offset=utc_offset, path=path)

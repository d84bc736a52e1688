"""The frame model: one image with its sensor layout and exposure metadata.

A :class:`Frame` holds one of three kinds of image, told apart by its :attr:`Frame.layout`:

- ``"bayer"``: a 2x2 CFA mosaic (``kind == "raw"``, shape (H, W), values in DN).
  Calibration works on its four CFA *planes* R, G1, G2, B at half resolution:
  G1 is the green of the first row of the 2x2 CFA cell, G2 the green of the second row.
- ``"linear"``: a linear multi-channel RAW (``kind == "raw"``, shape (H, W, 3), values
  in DN): a DNG LinearRaw (PhotometricInterpretation 34892) or any file LibRaw reads as
  a 3-colour stack (``RawType.Stack``). Planes R, G, B at full resolution, no G2.
- ``"mono"``: a monochrome sensor (``kind == "raw"``, shape (H, W), values in DN, no colour filter):
  a one-sample LinearRaw DNG (as Leica's Monochrom writes), a one-channel 16-bit PNG or TIFF of a
  machine-vision camera. One plane ``Y`` at full resolution.
- ``"processed"``: a processed 3-channel image (JPEG/TIFF/PNG, ``kind == "processed"``,
  shape (H, W, 3), R, G, B, values in DN of the file's bit depth, e.g. 0..255 for an 8-bit JPEG).

Every exposure value (time, f-number, ISO) and the capture time carries its source
(:data:`SOURCES`): an unknown value is None, never a library default.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from camcal.errors import CamcalError, MissingMetadataError

PLANES: tuple[str, str, str, str] = ("R", "G1", "G2", "B")
"""Canonical order of CFA planes in every (4, h, w) array camcal makes."""

RGB: tuple[str, str, str] = ("R", "G", "B")
"""Channel order of linear RAW and processed frames, (3, h, w) arrays."""

MONO: tuple[str] = ("Y",)
"""The one channel of a monochrome sensor, (1, h, w) arrays."""

LAYOUTS: tuple[str, ...] = ("bayer", "linear", "processed", "mono")
"""Frame layouts: 2x2 CFA mosaic, linear multi-channel RAW, processed RGB image, monochrome sensor."""

TRACKED: tuple[str, ...] = ("exposure_s", "f_number", "iso", "capture_time", "focal_length_mm")
"""Exposure fields whose source is recorded."""

PLACE_TIME: tuple[str, ...] = ("utc_offset", "gps_time_utc", "latitude_deg", "longitude_deg", "altitude_m")
"""Where and when the photo was taken (EXIF OffsetTimeOriginal and the GPS block): fields whose source is
recorded as for :data:`TRACKED` (``tag``, or ``session`` for a ``utc_offset`` given in ``session.toml``)."""

SOURCES: tuple[str, ...] = ("tag", "libraw", "frames.csv", "session")
"""Where a value came from: the file's own metadata tag (read by an EXIF reader), LibRaw alone
(its decoding of a maker header, no tag an EXIF reader finds), the folder's ``frames.csv``, the
session defaults file (``session.toml``, see :mod:`camcal.io.manifest`)."""

PATTERNS: tuple[str, ...] = ("RGGB", "BGGR", "GRBG", "GBRG")


@dataclass(frozen=True)
class Exposure:
    """Exposure metadata of one frame.

    Attributes
    ----------
    exposure_s : float or None
        Exposure (integration) time t in seconds.
    f_number : float or None
        Aperture f-number N (dimensionless).
    focal_length_mm : float or None
        Lens focal length, mm (EXIF FocalLength: the lens's real focal length, not the 35 mm equivalent).
    focal_length_35mm_mm : float or None
        The 35 mm equivalent focal length, mm (EXIF FocalLengthIn35mmFilm): with the 36 × 24 mm frame's
        half-diagonal it gives the field angle of the image corner (:mod:`camcal.models.falloff`).
    iso : float or None
        ISO speed (dimensionless, the camera's gain setting).
    make, model, serial : str or None
        Camera identity from the file's metadata.
    capture_time : str or None
        Capture time as ISO 8601 text, local camera time (EXIF DateTimeOriginal: a clock reading
        without a zone).
    temperature_c : float or None
        Sensor or ambient temperature in degrees Celsius, when known.
    utc_offset : str or None
        The camera clock's offset from UTC, ``+HH:MM`` (EXIF OffsetTimeOriginal, or ``utc_offset`` in
        ``session.toml``): local time = UTC + offset. Never guessed.
    gps_time_utc : str or None
        UTC capture time from the GPS block (GPSDateStamp + GPSTimeStamp), ISO 8601 text with ``+00:00``.
    latitude_deg, longitude_deg : float or None
        WGS-84 position from the GPS block, degrees, north and east positive.
    altitude_m : float or None
        GPS altitude above sea level, m (negative below).
    sources : tuple of (field, source) pairs
        Where each known field of :data:`TRACKED` came from (one of :data:`SOURCES`);
        read it with :meth:`source`.
    notes : tuple of str
        Disagreements between readers and values set aside (e.g. LibRaw's placeholder for a zero tag).
    """

    exposure_s: float | None = None
    f_number: float | None = None
    iso: float | None = None
    make: str | None = None
    model: str | None = None
    serial: str | None = None
    capture_time: str | None = None
    temperature_c: float | None = None
    utc_offset: str | None = None
    gps_time_utc: str | None = None
    latitude_deg: float | None = None
    longitude_deg: float | None = None
    altitude_m: float | None = None
    focal_length_mm: float | None = None
    focal_length_35mm_mm: float | None = None
    sources: tuple[tuple[str, str], ...] = ()
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        unknown = sorted({s for _, s in self.sources} - set(SOURCES))
        if unknown:
            raise ValueError(f"unknown metadata source {', '.join(unknown)} (known: {', '.join(SOURCES)})")

    def source(self, name: str) -> str | None:
        """Where field ``name`` (of :data:`TRACKED` or :data:`PLACE_TIME`) came from (one of :data:`SOURCES`);
        None when the value is unknown."""
        if getattr(self, name) is None:
            return None
        return dict(self.sources).get(name)

    def require(self, name: str, path: str | Path | None) -> float:
        """Return the named numeric field or raise :class:`MissingMetadataError`."""
        value = getattr(self, name)
        if value is None or not np.isfinite(value) or value <= 0:
            raise MissingMetadataError(path or "<frame>", name)
        return float(value)

    def merged(self, source: str = "frames.csv", **overrides) -> Exposure:
        """A copy with every non-None override applied (manifest over file), recorded as from ``source``."""
        clean = {k: v for k, v in overrides.items() if v is not None}
        src = dict(self.sources) | {k: source for k in clean if k in TRACKED or k in PLACE_TIME}
        return dataclasses.replace(self, **clean, sources=tuple(sorted(src.items())))

    def filled(self, source: str = "session", **defaults) -> Exposure:
        """A copy with the fields that are unknown, or known only from LibRaw, taken from ``defaults``.

        A session default (a fact the user states once) ranks above LibRaw's reading of a maker
        header, below the file's tag and ``frames.csv``.
        """
        weak = {k for k, v in dict(self.sources).items() if v == "libraw"}
        take = {k: v for k, v in defaults.items() if v is not None and (getattr(self, k) is None or k in weak)}
        if not take:
            return self
        return self.merged(source, **take)


@dataclass(frozen=True)
class Frame:
    """One decoded image and what is known about how it was taken.

    Attributes
    ----------
    data : ndarray
        ``bayer``: (H, W) uint16 CFA mosaic in DN. ``linear``: (H, W, 3) uint16 R, G, B in DN.
        ``processed``: (H, W, 3) in the file's DN (uint8 or uint16).
    kind : {"raw", "processed"}
        ``raw`` for both RAW layouts (``bayer`` and ``linear``).
    cfa_pattern : str or None
        2x2 CFA cell, row-major (``RGGB``...), Bayer frames only.
    black_level_dn : dict
        Black level in DN per plane (``R, G1, G2, B``) for Bayer frames, per
        channel (``R, G, B``) for linear RAW and processed ones (zero for processed).
    white_level_dn : float
        Saturation level in DN (clipping value).
    exposure : Exposure
    path : Path or None
        Source file.
    layout : {"bayer", "linear", "processed"} or None
        Sensor layout (see the module docstring); None (the default) derives it from ``kind``:
        ``raw`` → ``bayer``, ``processed`` → ``processed``.
    icc_profile : str or None
        Processed images: the description of the embedded ICC profile (e.g. ``Display P3`` for an
        iPhone's HEIC), noted, not applied; None when the file embeds none (or it is not read).
    value_range_dn : (int, int) or None
        The smallest and the largest value of ``data`` (DN) when the reader measured them as it checked the
        pixels (RAW files, :meth:`with_value_range`), so that no later check goes over the frame again for them;
        None when not measured (:meth:`data_range` then measures them). Not an argument of the constructor:
        a frame made from another with :func:`dataclasses.replace` (other data, perhaps) measures it again.
    """

    data: np.ndarray
    kind: Literal["raw", "processed"]
    cfa_pattern: str | None
    black_level_dn: dict[str, float]
    white_level_dn: float
    exposure: Exposure = field(default_factory=Exposure)
    path: Path | None = None
    layout: Literal["bayer", "linear", "processed", "mono"] | None = None
    icc_profile: str | None = None
    black_level_source: str = "file"
    """Where ``black_level_dn`` came from: ``"file"`` (its tags), or ``"unknown"`` (a PNG, TIFF or FITS frame that
    states none: the value is a placeholder 0, and the dark fit estimates the offset from the dark series)."""
    value_range_dn: tuple[int, int] | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.layout is None:
            object.__setattr__(self, "layout", "bayer" if self.kind == "raw" else "processed")
        if self.layout not in LAYOUTS:
            raise CamcalError(f"unknown frame layout {self.layout!r}; camcal knows {', '.join(LAYOUTS)}")
        if (self.layout == "processed") != (self.kind == "processed"):
            raise CamcalError(f"a {self.kind} frame cannot have layout {self.layout!r}")

    @property
    def shape(self) -> tuple[int, int]:
        """Full-resolution (height, width) in pixels."""
        return int(self.data.shape[0]), int(self.data.shape[1])

    def with_value_range(self, lo: int, hi: int) -> Frame:
        """This frame, with the (smallest, largest) value of its data that its reader measured (DN)."""
        object.__setattr__(self, "value_range_dn", (int(lo), int(hi)))
        return self

    def with_exposure(self, exposure: Exposure) -> Frame:
        """A new frame with the same data and ``exposure``: the value range its reader measured is kept, since the
        data are the same (:func:`dataclasses.replace` would leave it unmeasured)."""
        new = dataclasses.replace(self, exposure=exposure)
        if self.value_range_dn is not None:
            new.with_value_range(*self.value_range_dn)
        return new

    def may_reach(self, level_dn: float) -> bool:
        """Whether any value may be at or above ``level_dn``: False only when the largest value the reader measured
        (:attr:`value_range_dn`) is below it, so a count at that level can be skipped; True when unmeasured."""
        return self.value_range_dn is None or self.value_range_dn[1] >= level_dn

    def data_range(self) -> tuple[int, int]:
        """(smallest, largest) value of :attr:`data` in DN: :attr:`value_range_dn`, or measured now."""
        if self.value_range_dn is not None:
            return self.value_range_dn
        return int(self.data.min()), int(self.data.max())

    @property
    def channel_names(self) -> tuple[str, ...]:
        """:data:`PLANES` for Bayer frames, :data:`MONO` for monochrome ones, :data:`RGB` for linear RAW and
        processed ones."""
        return PLANES if self.layout == "bayer" else MONO if self.layout == "mono" else RGB

    def planes(self, dtype=np.float32) -> np.ndarray:
        """Channel planes as one array, channel first.

        ``bayer``: (4, H/2, W/2) in :data:`PLANES` order. ``linear`` and ``processed``: (3, H, W). ``mono``:
        (1, H, W).
        """
        if self.layout == "bayer":
            return split_planes(self.data, self.cfa_pattern, dtype=dtype)
        if self.layout == "mono":
            return self.data[None].astype(dtype or self.data.dtype, copy=True)
        return np.moveaxis(self.data, -1, 0).astype(dtype or self.data.dtype, copy=True)

    def plane_views(self) -> tuple[np.ndarray, ...]:
        """The channel planes of :meth:`planes` as views of :attr:`data` in its own type (no copy), in
        :attr:`channel_names` order: strided views of the mosaic for ``bayer`` frames, slices of the last axis
        otherwise. For checks that only read the planes."""
        if self.layout == "bayer":
            _check_mosaic(self.data)
            off = plane_offsets(self.cfa_pattern)
            return tuple(self.data[r::2, c::2] for r, c in map(off.get, PLANES))
        if self.layout == "mono":
            return (self.data,)
        return tuple(self.data[..., i] for i in range(self.data.shape[-1]))

    def black_vector(self) -> np.ndarray:
        """Black level per channel in :attr:`channel_names` order, shape (C, 1, 1)."""
        return np.array([self.black_level_dn.get(c, 0.0) for c in self.channel_names], float)[:, None, None]


def _check_pattern(pattern: str | None) -> str:
    if pattern not in PATTERNS:
        raise CamcalError(f"unsupported CFA pattern {pattern!r}; camcal handles {', '.join(PATTERNS)}")
    return pattern


def plane_offsets(pattern: str) -> dict[str, tuple[int, int]]:
    """Row/column offset within the 2x2 cell of each plane R, G1, G2, B."""
    pattern = _check_pattern(pattern)
    pos = {}
    for i, ch in enumerate(pattern):
        rc = divmod(i, 2)
        if ch == "G":
            pos["G1" if rc[0] == 0 else "G2"] = rc
        else:
            pos[ch] = rc
    return pos


def _check_mosaic(mosaic: np.ndarray) -> None:
    """Refuse an array that cannot be a CFA mosaic of 2x2 cells."""
    if mosaic.ndim != 2 or mosaic.shape[0] % 2 or mosaic.shape[1] % 2:
        raise CamcalError(f"a CFA mosaic must be 2-D with even sides, got shape {mosaic.shape}")


def split_planes(mosaic: np.ndarray, pattern: str, dtype=np.float32) -> np.ndarray:
    """Split a CFA mosaic into its four half-resolution planes.

    Parameters
    ----------
    mosaic : ndarray, shape (H, W), H and W even
    pattern : str
        ``RGGB``, ``BGGR``, ``GRBG`` or ``GBRG``.
    dtype : numpy dtype, optional
        Output type (default float32; ``None`` keeps the input type).

    Returns
    -------
    ndarray, shape (4, H/2, W/2), planes in :data:`PLANES` order.
    """
    _check_mosaic(mosaic)
    off = plane_offsets(pattern)
    out = np.empty((4, mosaic.shape[0] // 2, mosaic.shape[1] // 2), dtype=dtype or mosaic.dtype)
    for k, name in enumerate(PLANES):
        r, c = off[name]
        out[k] = mosaic[r::2, c::2]
    return out


def merge_planes(planes: np.ndarray, pattern: str) -> np.ndarray:
    """Inverse of :func:`split_planes`: interleave (4, h, w) planes into an (2h, 2w) mosaic."""
    if planes.ndim != 3 or planes.shape[0] != 4:
        raise CamcalError(f"expected planes of shape (4, h, w), got {planes.shape}")
    off = plane_offsets(pattern)
    _, h, w = planes.shape
    out = np.empty((2 * h, 2 * w), dtype=planes.dtype)
    for k, name in enumerate(PLANES):
        r, c = off[name]
        out[r::2, c::2] = planes[k]
    return out


def pattern_from_rawpy(raw_pattern: np.ndarray, color_desc: bytes) -> str:
    """Translate rawpy's ``raw_pattern`` and ``color_desc`` into ``RGGB``-style text."""
    desc = color_desc.decode("ascii", "replace")
    letters = "".join(desc[int(i)] for i in np.asarray(raw_pattern)[:2, :2].ravel())
    return letters


def rgb_from_planes(planes: np.ndarray) -> np.ndarray:
    """(4, h, w) R, G1, G2, B planes -> (3, h, w) R, G, B with G the mean of G1 and G2."""
    return np.stack([planes[0], 0.5 * (planes[1] + planes[2]), planes[3]])

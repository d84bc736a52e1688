"""OpenEXR output and input through OpenImageIO.

Channels are written and read *by name* (OpenImageIO does not keep channel
order on read-back). camcal metadata is stored as header attributes prefixed
``camcal:``; values that are not numbers or strings are stored as JSON text
under ``camcal:json:<name>``. Writes are atomic.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from camcal.errors import CamcalError
from camcal.io.atomic import atomic_path
from camcal.io.limits import (
    MAX_EXR_CHANNELS,
    MAX_EXR_EXPANSION,
    declared_image_bytes,
    human_bytes,
    max_exr_samples,
    max_pixels,
)
from camcal.threads import thread_count, thread_map

COMPRESSIONS = ("none", "zip", "zips", "piz", "pxr24", "b44", "dwaa", "dwab", "zstd", "rle")
PRECISIONS = ("float", "half", "mixed")
"""Pixel types of :func:`write_exr`: ``float`` every channel 32-bit, ``half`` every channel 16-bit, ``mixed``
the uncertainty channels (names ending in :data:`UNCERTAINTY_SUFFIX`) 16-bit and the others 32-bit."""
UNCERTAINTY_SUFFIX = "_unc"
"""Channels holding a standard uncertainty (1σ): half float in the ``mixed`` layout."""
HALF_MAX = 65504.0
"""Largest finite half float."""
HALF_MIN_NORMAL = 2.0**-14
"""Smallest normal half float (6.1e-5): below it a half keeps fewer than 11 significant bits."""

BAND_BYTES = 64 << 20
"""Bytes of pixels interleaved and handed to OpenEXR at a time when the channels are separate arrays."""

BAND_ROWS_MULTIPLE = 32
"""A band is a whole number of OpenEXR's largest line blocks (32 rows for piz, pxr24, b44 and zstd), so that no
block is split between two writes."""


def interleaved(arrays: list[np.ndarray]) -> np.ndarray | None:
    """The C-contiguous (H, W, C) float32 array whose channels ``arrays`` are, in order, or None.

    :func:`camcal.apply.photo.apply_prepared` returns its channels as views of one such array; writing it
    directly saves a copy of the whole image.
    """
    base = arrays[0].base
    if not isinstance(base, np.ndarray) or base.dtype != np.float32 or base.ndim != 3:
        return None
    if not base.flags.c_contiguous or base.shape != (*arrays[0].shape, len(arrays)):
        return None
    start = base.__array_interface__["data"][0]
    for i, a in enumerate(arrays):
        if (a.base is not base or a.strides != base.strides[:2]
                or a.__array_interface__["data"][0] != start + i * base.itemsize):
            return None
    return base


def write_exr(
    path: str | Path,
    channels: dict[str, np.ndarray],
    metadata: dict[str, object] | None = None,
    *,
    half: bool = False,
    compression: str = "zip",
    datetime: str | None = None,
    precision: str | None = None,
) -> Path:
    """Write named 2-D float channels to an OpenEXR file, atomically.

    Parameters
    ----------
    path : output path (``.exr``).
    channels : ``{name: (H, W) array}``; all the same shape.
    metadata : header attributes; numbers and strings as-is, other values as JSON.
    half : store 16-bit half floats instead of float32 (the same as ``precision="half"``).
    compression : one of :data:`COMPRESSIONS`; ``zip``, ``zips`` and ``zstd`` may add a level after a colon
        (``zstd:1``: the profile's maps, :mod:`camcal.io.container`).
    precision : one of :data:`PRECISIONS` (default ``"half"`` if ``half`` else ``"float"``). ``"mixed"``: the
        channels named ``*_unc`` are stored as half floats when every finite non-zero value of them lies in
        half's normal range (:data:`HALF_MIN_NORMAL` to :data:`HALF_MAX`, where half keeps 11 significant bits),
        otherwise as float32; the header attribute ``camcal:uncertainty_precision`` says which and why.
    datetime : the header's ``DateTime`` (EXR ``capDate``), ``"YYYY:MM:DD HH:MM:SS"``; by default
        OpenImageIO writes the current time, so two writes of the same data differ in that field.
    """
    if not channels:
        raise CamcalError("no channels to write", path)
    if Path(path).is_dir():
        raise CamcalError("is a folder; give the EXR a file name", path)
    name, _, level = compression.partition(":")
    if name not in COMPRESSIONS or (level and not level.isdigit()):
        raise CamcalError(f"unknown EXR compression {compression!r}; choose from {', '.join(COMPRESSIONS)} (zip, "
                          "zips and zstd may name a level, e.g. zstd:1)")
    precision = precision or ("half" if half else "float")
    if precision not in PRECISIONS:
        raise CamcalError(f"unknown EXR precision {precision!r}; choose from {', '.join(PRECISIONS)}")
    names = list(channels)
    arrays = [np.asarray(channels[n], dtype=np.float32) for n in names]
    shape = arrays[0].shape
    if any(a.shape != shape or a.ndim != 2 for a in arrays):
        raise CamcalError("EXR channels must be 2-D arrays of one shape", path)
    pixels = interleaved(arrays)
    h, w = shape
    spec = oiio.ImageSpec(w, h, len(names), oiio.HALF if precision == "half" else oiio.FLOAT)
    spec.channelnames = tuple(names)
    spec.attribute("compression", compression)
    if precision == "mixed":
        unc = [i for i, n in enumerate(names) if n.endswith(UNCERTAINTY_SUFFIX)]
        fits, why = half_fits([arrays[i] for i in unc]) if unc else (False, "no uncertainty channels")
        if fits:
            spec.channelformats = tuple(oiio.TypeDesc(oiio.HALF if i in unc else oiio.FLOAT)
                                        for i in range(len(names)))
        spec.attribute("camcal:uncertainty_precision", "half" if fits else f"float ({why})")
    if datetime is not None:
        spec.attribute("DateTime", str(datetime))
    for key, value in (metadata or {}).items():
        if isinstance(value, bool) or value is None or not isinstance(value, int | float | str):
            spec.attribute(f"camcal:json:{key}", json.dumps(value, sort_keys=True, default=str))
        elif isinstance(value, int):
            spec.attribute(f"camcal:{key}", float(value)) if abs(value) > 2**31 - 1 else spec.attribute(
                f"camcal:{key}", int(value)
            )
        else:
            spec.attribute(f"camcal:{key}", value)
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise CamcalError(f"cannot write EXR: {oiio.geterror()}", path)
        if pixels is not None:
            ok = out.write_image(pixels)
        else:  # separate maps: interleaved a band of rows at a time (no copy of the whole image in memory)
            rows = max(BAND_ROWS_MULTIPLE, BAND_BYTES // max(1, w * len(arrays) * 4)
                       // BAND_ROWS_MULTIPLE * BAND_ROWS_MULTIPLE)
            band = np.empty((min(rows, h), w, len(arrays)), np.float32)  # one buffer for every band
            ok = all(out.write_scanlines(y, min(h, y + rows), 0, _interleave(arrays, y, min(h, y + rows), band))
                     for y in range(0, h, rows))
        err = out.geterror()
        out.close()
        if not ok:
            raise CamcalError(f"cannot write EXR: {err}", path)
    return Path(path)


INTERLEAVE_ROWS = 4
"""Rows interleaved at a time by :func:`_interleave`: their pixels of every channel (4 x 3000 x 28 x 4 bytes for
the maps of a 24 MP profile) stay in the cache while each channel is written into them, twice as fast as a whole
band at once."""


def _interleave(arrays: list[np.ndarray], y0: int, y1: int, buffer: np.ndarray) -> np.ndarray:
    """Rows ``y0:y1`` of the 2-D ``arrays`` as one (rows, W, C) array (a view of ``buffer``), a few rows at a
    time (:data:`INTERLEAVE_ROWS`)."""
    out = buffer[:y1 - y0]
    for y in range(y0, y1, INTERLEAVE_ROWS):
        stop = min(y1, y + INTERLEAVE_ROWS)
        np.stack([a[y:stop] for a in arrays], axis=-1, out=out[y - y0:stop - y0])
    return out


def half_fits(arrays: list[np.ndarray], rows: int = 64) -> tuple[bool, str]:
    """Whether every finite non-zero value of ``arrays`` lies in half's normal range (its magnitude from
    :data:`HALF_MIN_NORMAL` to :data:`HALF_MAX`), and if not, why (the smallest and largest magnitudes).

    Zeros, NaN and infinities are stored exactly by a half. Row blocks of ``rows`` rows on
    :func:`camcal.threads.thread_count` threads (the arrays may be strided views of one interleaved image).
    """
    if not arrays:
        return True, ""
    h = arrays[0].shape[0]

    def extremes(y: int) -> tuple[float, float]:
        lo, hi = np.inf, 0.0
        for a in arrays:
            m = np.abs(a[y: y + rows])
            np.copyto(m, np.float32(np.inf), where=m == 0)  # zero is exact: not the smallest magnitude
            lo = min(lo, float(np.fmin.reduce(m, axis=None)))  # fmin/fmax skip NaN
            np.copyto(m, np.float32(0), where=np.isinf(m))
            hi = max(hi, float(np.fmax.reduce(m, axis=None)))
        return lo, hi

    starts = range(0, h, rows)
    parts = thread_map(extremes, starts, thread_count(work_items=len(starts)))
    lo = min(p[0] for p in parts)
    hi = max(p[1] for p in parts)
    if lo >= HALF_MIN_NORMAL and hi <= HALF_MAX:
        return True, ""
    return False, (f"finite non-zero values from {lo:.3g} to {hi:.3g}, outside half's normal range "
                   f"{HALF_MIN_NORMAL:.3g} to {HALF_MAX:g}")


def read_exr(
    path: str | Path, channels: list[str] | tuple[str, ...] | None = None, *, max_samples: int | None = None
) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """Read channels (all, or the named ones) and camcal metadata from an EXR file.

    The header is checked before any pixel memory is allocated (:mod:`camcal.io.limits`): at most
    :func:`~camcal.io.limits.max_pixels` pixels, :data:`~camcal.io.limits.MAX_EXR_CHANNELS` channels and
    ``max_samples`` pixels x channels (default :func:`~camcal.io.limits.max_exr_samples`; a profile passes the
    bound of its own sensor and map list); the decoded
    bytes may be at most :data:`~camcal.io.limits.MAX_EXR_EXPANSION` times the file's size (an
    uncompressed file must hold all of them: a short one is truncated).

    Returns
    -------
    (channels, metadata) : ``{name: float32 (H, W)}`` and ``{key: value}`` with the
    ``camcal:`` prefix removed and JSON attributes decoded.
    """
    path = Path(path)
    if not path.is_file():
        raise CamcalError("no such EXR file", path)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()
        raise CamcalError("cannot open as EXR (damaged or not an image)", path)
    try:
        fmt = inp.format_name()
        if fmt != "openexr":  # OIIO opens any image by its content: a JPEG named .exr is not a radiance map
            raise CamcalError(f"is not an OpenEXR file (it is a {fmt or 'unknown'} image)", path)
        spec = inp.spec()
        _check_declared_size(path, spec, max_samples)
        names = list(spec.channelnames)
        want = list(channels) if channels is not None else names
        missing = [c for c in want if c not in names]
        if missing:
            raise CamcalError(f"EXR has no channel(s) {missing}; it has {names}", path)
        data = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        err = inp.geterror()
        if data is None or err:
            raise CamcalError(f"cannot decode EXR pixels (damaged or truncated?): {err.strip()[:120]}", path)
        meta = camcal_attributes(spec, path)
    finally:
        inp.close()
    data = np.asarray(data, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)
    planes = _deinterleave(data, [names.index(c) for c in want])
    return dict(zip(want, planes, strict=True)), meta


def camcal_attributes(spec, path: str | Path) -> dict[str, object]:
    """camcal's metadata in an EXR header (an OpenImageIO ``ImageSpec``): the ``camcal:`` attributes with the
    prefix removed, ``camcal:json:`` ones decoded. The one parser of camcal's EXR metadata.

    Raises
    ------
    CamcalError
        An attribute that should hold JSON does not.
    """
    meta: dict[str, object] = {}
    for attr in spec.extra_attribs:
        if attr.name.startswith("camcal:json:"):
            try:
                meta[attr.name[len("camcal:json:") :]] = json.loads(attr.value)
            except (TypeError, ValueError):
                raise CamcalError(f"EXR attribute {attr.name} is not valid JSON", path) from None
        elif attr.name.startswith("camcal:"):
            meta[attr.name[len("camcal:") :]] = attr.value
    return meta


def read_exr_header(path: str | Path) -> dict[str, object]:
    """camcal's metadata of an EXR file from its header alone (no pixels are read); see :func:`camcal_attributes`.

    The pixel type of the file (``"half"``, ``"float"``, or ``"mixed"`` when its channels differ) is added as
    ``exr_pixel_type``, its compression
    (one of :data:`COMPRESSIONS`) as ``exr_compression``.

    Raises
    ------
    CamcalError
        The file cannot be opened as an image, or its metadata is damaged.
    """
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()
        raise CamcalError("cannot open as EXR (damaged or not an image)", path)
    try:
        spec = inp.spec()
        formats = {str(f) for f in spec.channelformats or []}
        pixel_type = "mixed" if len(formats) > 1 else str(spec.format)
        return {**camcal_attributes(spec, path), "exr_pixel_type": pixel_type,
                "exr_compression": str(spec.getattribute("compression") or "none").lower()}
    finally:
        inp.close()


def _check_declared_size(path: Path, spec, max_samples: int | None) -> None:
    """Refuse an EXR header whose declared pixels, channels or decoded bytes are above the limits."""
    w, h, nch = spec.width, spec.height, spec.nchannels
    if w <= 0 or h <= 0 or nch <= 0:
        raise CamcalError(f"EXR declares an empty image ({w}x{h}x{nch})", path)
    if w * h > max_pixels():  # before any pixel is allocated
        raise CamcalError(f"EXR declares {w}x{h} pixels, above the limit of {max_pixels()} "
                          "(set CAMCAL_MAX_PIXELS to raise it)", path)
    if nch > MAX_EXR_CHANNELS:
        raise CamcalError(f"EXR declares {nch} channels, above the limit of {MAX_EXR_CHANNELS}", path)
    limit = max_exr_samples() if max_samples is None else max_samples  # a profile's own bound replaces it
    if w * h * nch > limit:
        raise CamcalError(f"EXR declares {w}x{h} pixels x {nch} channels, above the limit of {limit} samples", path)
    declared = declared_image_bytes(spec)
    size = path.stat().st_size
    compression = str(spec.getattribute("compression") or "none").lower()
    if compression == "none" and declared > size:
        raise CamcalError(f"EXR declares {human_bytes(declared)} of uncompressed pixels but the file holds "
                          f"{human_bytes(size)} (truncated)", path)
    if declared > MAX_EXR_EXPANSION * size:
        raise CamcalError(f"EXR declares {human_bytes(declared)} of pixel data in a file of {human_bytes(size)}, "
                          f"more than {MAX_EXR_EXPANSION}:1 (a damaged or hostile header); refused", path)


def _deinterleave(data: np.ndarray, index: list[int], rows: int = 8) -> np.ndarray:
    """(H, W, C) interleaved -> (len(index), H, W) channel planes, copied in cache-sized row blocks on
    :func:`camcal.threads.thread_count` threads (a channel-at-a-time copy strides through the whole image once
    per channel)."""
    h = data.shape[0]
    out = np.empty((len(index), h, data.shape[1]), data.dtype)
    sel = index if index != list(range(data.shape[2])) else slice(None)

    def work(y: int) -> None:
        out[:, y: y + rows] = np.moveaxis(data[y: y + rows, :, sel], -1, 0)

    thread_map(work, range(0, h, rows), thread_count(work_items=-(-h // rows)))
    return out

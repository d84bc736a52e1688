"""Decoding frames: RAW through rawpy (LibRaw), JPEG/TIFF/PNG through OpenImageIO, HEIC/HEIF through pillow-heif
(libheif), FITS through astropy; headers read without decoding.

HEIC/HEIF photos (a phone's default format) are processed images like JPEG: R, G, B of 8 bits, or of 10 or 12 bits
held in uint16 (white level 2**bits − 1); the embedded ICC profile's description is noted on the frame (iPhones
write Display P3), not applied.

Exposure metadata, each value with its source (:data:`camcal.frame.SOURCES`):

1. the file's tags (:mod:`camcal.io.exif`; for processed images also the OpenImageIO spec). A tag that is present
   but holds zero or nothing is *unknown*;
2. for RAW files, LibRaw's value where no tag holds one (e.g. a maker header that only LibRaw decodes), marked
   ``libraw`` (:func:`camcal.io.exif.reconcile_libraw`);
3. the session defaults file (``session.toml`` in the frame's folder or its parent, see
   :func:`camcal.io.manifest.session_defaults_for`) for values still unknown;
4. the folder's ``frames.csv`` manifest, which overrides all of them (:mod:`camcal.io.folders`).

RAW files are 2x2 Bayer mosaics (``layout == "bayer"``) or linear multi-channel RAW (DNG LinearRaw, LibRaw
``RawType.Stack``: ``layout == "linear"``); other sensor layouts (X-Trans, Foveon, 4-colour CFAs) and RAW files
without image data are refused. What kind a file is: :mod:`camcal.io.kinds`; the C libraries' stderr is held by
:mod:`camcal.io.stderr`.

Every failure to read a file becomes a one-line :class:`~camcal.errors.CamcalError` naming the file.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pillow_heif
import rawpy
from PIL import ImageCms

from camcal.errors import CamcalError
from camcal.frame import PLANES, RGB, TRACKED, Exposure, Frame, pattern_from_rawpy, plane_offsets
from camcal.io.exif import (
    TAG_NAMES,
    clean_number,
    exif_from_block,
    exif_tags,
    exif_value,
    fill_exposure,
    iso_time,
    libraw_time,
    place_time_from_exif,
    reconcile_libraw,
    tag_present,
)
from camcal.io.kinds import check_file, is_fits, is_heif, is_raw_path
from camcal.io.limits import check_expansion, declared_image_bytes, max_pixels
from camcal.io.manifest import (
    session_camera_facts,
    session_defaults_for,
)
from camcal.io.stderr import quiet_stderr


def _check_pixels(path: Path, width: int, height: int, stored_bytes: float | None = None) -> None:
    """The declared size against the limits (camcal.io.limits); ``stored_bytes`` default: 16-bit mosaic."""
    if width <= 0 or height <= 0:
        raise CamcalError(f"declares an empty image ({width}x{height})", path)
    if width * height > max_pixels():
        raise CamcalError(
            f"declares {width}x{height} pixels, above the limit of {max_pixels()} (set CAMCAL_MAX_PIXELS to raise it)",
            path,
        )
    check_expansion(path, 2.0 * width * height if stored_bytes is None else stored_bytes)


def exposure_from_exif(path: Path, tags: dict[str, object] | None = None) -> Exposure:
    """Exposure metadata from a file's EXIF, via exifread; every value found is marked ``tag``.

    A tag that holds zero (or an empty date) gives None: unknown. A FITS file has no EXIF: its header's keys
    (:func:`_fits_exposure`).
    """
    if tags is None and is_fits(path):
        return _fits_exposure(_fits_header(path))
    tags = exif_tags(path) if tags is None else tags
    if not tags:
        return Exposure()

    def num(*names):
        v = exif_value(tags, *names)
        return clean_number(v) if isinstance(v, float) else None

    def text(*names):
        v = exif_value(tags, *names)
        return v if isinstance(v, str) else None

    temp = exif_value(tags, "EXIF Temperature", "EXIF Tag 0x9400")
    values = {
        "exposure_s": num(*TAG_NAMES["exposure_s"]),
        "f_number": num(*TAG_NAMES["f_number"]),
        "iso": num(*TAG_NAMES["iso"]),
        "capture_time": iso_time(text(*TAG_NAMES["capture_time"])),
        "focal_length_mm": num(*TAG_NAMES["focal_length_mm"]),
        "focal_length_35mm_mm": num(*TAG_NAMES["focal_length_35mm_mm"]),
    }
    place, notes = place_time_from_exif(tags)
    return Exposure(
        **values,
        **place,
        make=text("Image Make"),
        model=text("Image Model"),
        serial=text("EXIF BodySerialNumber", "Image Tag 0xC62F", "MakerNote SerialNumber"),
        temperature_c=float(temp) if isinstance(temp, float) else None,
        sources=tuple(sorted((k, "tag") for k, v in (values | place).items() if v is not None)),
        notes=tuple(notes),
    )


def _layout_name(raw) -> str:
    """A short name for a RAW file's sensor layout, for the refusal of layouts camcal does not read."""
    pattern = getattr(raw, "raw_pattern", None)
    desc = raw.color_desc.decode("ascii", "replace")
    if pattern is not None and np.shape(pattern) == (6, 6):
        return "X-Trans (6x6 colour filter array)"
    if raw.num_colors == 4 and "R" not in desc:
        return f"a 4-colour {desc} colour filter array"
    if raw.num_colors != 3:
        return f"a {raw.num_colors}-colour sensor ({desc})"
    if pattern is None:
        return "a sensor without a colour filter array (e.g. Foveon) or a monochrome sensor"
    return f"a {np.shape(pattern)[0]}x{np.shape(pattern)[1]} colour filter array"


MIN_RAW_BYTES_PER_PIXEL = 1 / 64
"""Smallest file size per declared pixel of a RAW file that holds its image data (1 bit per 8 pixels:
lossy DNGs hold about 0.4 byte per pixel, files whose image data were stripped 0.002 or less)."""


def _check_size_for_pixels(path: Path, width: int, height: int) -> None:
    """Refuse a RAW file too small to hold the pixels it declares, before LibRaw decodes it: LibRaw then
    reads past the end of the file and returns zeros or whatever its buffer held before."""
    size = path.stat().st_size
    if size < width * height * MIN_RAW_BYTES_PER_PIXEL:
        raise CamcalError(f"holds no image data: {size} bytes cannot hold its {width}x{height} pixels "
                          "(the image data were stripped, or the file is truncated)", path)


def check_has_data(path: Path, data: np.ndarray, black_dn: float, white_dn: float) -> tuple[int, int]:
    """Refuse a RAW frame that holds no image data (stripped or blank); give the (smallest, largest) value of
    ``data`` (DN) otherwise, measured for the check (:attr:`camcal.frame.Frame.value_range_dn`).

    Refused: every pixel 0; every pixel the same value below the white level; 99 % or more of the
    pixels below the black level (a sensor cannot read below its bias: the image data is missing, as in
    files whose data were stripped and decode to zeros). A frame with every pixel at or above the white
    level is an image (over-exposed), not a file without data: it is read, and each stage decides what
    its saturation means (:func:`saturated_fraction`; a linearity series ends there, a flat is left out).

    Raises
    ------
    CamcalError naming the file and what is wrong.
    """
    lo, hi = int(data.min()), int(data.max())
    if hi == 0:
        raise CamcalError("holds no image data: every pixel is 0 (the image data may have been stripped); "
                          "a frame of zeros is not a dark frame", path)
    if lo >= white_dn:  # fully saturated: an over-exposed image, not a file without data
        return lo, hi
    if lo == hi:
        raise CamcalError(f"holds no image data: every pixel has the same value ({lo} DN)", path)
    if black_dn > 0 and lo < black_dn and _mostly_below(data, black_dn):
        below = np.count_nonzero(data < black_dn) / data.size
        if below >= 0.99:
            raise CamcalError(f"holds no image data: {100 * below:.1f} % of the pixels are below the black level "
                              f"({black_dn:g} DN; the image data may have been stripped)", path)
    return lo, hi


def _mostly_below(data: np.ndarray, level_dn: float, chunk: int = 1 << 20) -> bool:
    """Whether 99 % or more of ``data`` may lie below ``level_dn``: False as soon as more than 1 % of the values
    are found at or above it, which in an image with data is found within the first rows (about ``chunk``
    values), instead of counting over the whole frame. True means the whole count decides.

    Row blocks of ``data`` (views: a decoded RAW image is often a strided view of a larger buffer, which
    ``reshape(-1)`` would copy whole)."""
    allowed = data.size - 0.99 * data.size  # at or above: more than this many, and fewer than 99 % are below
    rows = max(1, chunk // max(1, data[0].size)) if data.ndim > 1 else data.shape[0]
    above = 0
    for y in range(0, data.shape[0], rows):
        above += int(np.count_nonzero(data[y:y + rows] >= level_dn))
        if above > allowed:
            return False
    return True


def saturated_fraction(frame: Frame) -> float:
    """Fraction of a frame's values at or above its white level (0…1); 0 without going over the pixels when the
    largest value its reader measured is below the white level (:meth:`camcal.frame.Frame.may_reach`)."""
    white = frame.white_level_dn
    if not frame.may_reach(white):
        return 0.0
    return float(np.count_nonzero(frame.data >= white)) / max(int(frame.data.size), 1)


def _load_raw(path: Path) -> Frame:
    try:
        with quiet_stderr(), rawpy.imread(str(path)) as raw:
            sizes = raw.sizes
            _check_pixels(path, int(sizes.raw_width), int(sizes.raw_height))
            _check_size_for_pixels(path, int(sizes.raw_width), int(sizes.raw_height))
            if raw.raw_type == rawpy.RawType.Stack:
                desc = raw.color_desc.decode("ascii", "replace")
                if raw.num_colors != 3 or any(c not in desc for c in RGB):
                    raise CamcalError(f"is a linear RAW file of {_layout_name(raw)}; camcal reads linear R, G, B "
                                      "RAW and 2x2 Bayer mosaics", path)
                idx = [desc.index(c) for c in RGB]  # stack channel of R, G, B (the 4th is unused for 3 colours)
                stack = raw.raw_image_visible
                if stack.ndim != 3 or stack.shape[2] <= max(idx):
                    raise CamcalError(f"has a linear RAW image of unexpected shape {stack.shape}", path)
                data = np.ascontiguousarray(stack[..., idx], dtype=np.uint16)
                per_color = list(raw.black_level_per_channel)  # after unpacking: LibRaw may measure it then
                layout, pattern = "linear", None
                black = {c: float(per_color[i]) for c, i in zip(RGB, idx, strict=True)}
            elif raw.num_colors == 1 or (raw.raw_pattern is None and np.ndim(raw.raw_image_visible) == 2):
                # a monochrome sensor (a one-sample LinearRaw DNG): one plane Y, no colour filter array
                data = np.array(raw.raw_image_visible, dtype=np.uint16, copy=True)
                if data.ndim != 2:
                    raise CamcalError(f"has a monochrome RAW image of unexpected shape {data.shape}", path)
                per_color = list(raw.black_level_per_channel)
                layout, pattern = "mono", None
                black = {"Y": float(per_color[0])}
            else:
                if raw.num_colors != 3 or raw.raw_pattern is None or raw.raw_pattern.shape != (2, 2):
                    raise CamcalError(f"has {_layout_name(raw)}, which camcal does not read; camcal reads 2x2 "
                                      "Bayer mosaics and linear R, G, B RAW", path)
                pattern = pattern_from_rawpy(raw.raw_pattern, raw.color_desc)
                if pattern not in ("RGGB", "BGGR", "GRBG", "GBRG"):
                    raise CamcalError(f"has an unsupported CFA layout {pattern!r}", path)
                data = np.array(raw.raw_image_visible, dtype=np.uint16, copy=True)
                per_color = list(raw.black_level_per_channel)  # after unpacking: LibRaw may measure it then
                rp = np.asarray(raw.raw_pattern)
                layout = "bayer"
            white = float(raw.white_level)
            other = raw.other
            libraw = {
                "exposure_s": clean_number(other.shutter_speed),
                "f_number": clean_number(other.aperture),
                "iso": clean_number(other.iso_speed),
                "capture_time": libraw_time(getattr(other, "timestamp", None)),
                "focal_length_mm": clean_number(getattr(other, "focal_len", None)),
            }
    except rawpy.LibRawFileUnsupportedError:
        raise CamcalError("is not a RAW file LibRaw can decode (unsupported or not an image)", path) from None
    except rawpy.LibRawError as exc:
        raise CamcalError(f"cannot decode RAW data (damaged or truncated? or its image data stripped): "
                          f"{type(exc).__name__}",
                          path) from None
    except (OSError, ValueError, MemoryError) as exc:
        raise CamcalError(f"cannot decode RAW data (damaged or truncated?): {exc}", path) from None
    if layout == "bayer":
        if data.shape[0] % 2 or data.shape[1] % 2:
            data = data[: data.shape[0] // 2 * 2, : data.shape[1] // 2 * 2]
        off = plane_offsets(pattern)
        black = {name: float(per_color[int(rp[off[name]])]) for name in PLANES}
    lo, hi = check_has_data(path, data, min(black.values()), white)
    tags = exif_tags(path)
    exp = reconcile_libraw(exposure_from_exif(path, tags), tags, libraw)
    return Frame(
        data=data,
        kind="raw",
        cfa_pattern=pattern,
        black_level_dn=black,
        white_level_dn=white,
        exposure=exp,
        path=path,
        layout=layout,
    ).with_value_range(lo, hi)


@contextlib.contextmanager
def open_image(path: Path, formats: tuple[str, ...] | None = None, what: str = "an image"):
    """Open ``path`` with OpenImageIO and yield ``(input, spec)``, checked before any pixel is read.

    C-library messages are silenced; the format must be one of ``formats`` (OpenImageIO opens any
    format it knows whatever the file's name); the declared size must be within :func:`max_pixels`.
    """
    with quiet_stderr():  # libpng/libjpeg print their own messages to fd 2 on damaged files
        inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()
        raise CamcalError(f"cannot open as {what} (damaged, or not a supported image)", path)
    try:
        spec = inp.spec()
        fmt_name = inp.format_name()
        if formats is not None and fmt_name not in formats:
            raise CamcalError(f"is a {fmt_name} file, not {what}", path)
        _check_pixels(path, spec.width, spec.height, declared_image_bytes(spec))
        yield inp, spec
    finally:
        inp.close()


def read_pixels(inp, spec, path: Path, nchannels: int, fmt) -> np.ndarray:
    """``inp.read_image`` of the first ``nchannels`` channels, C-library chatter silenced; damage is an error."""
    with quiet_stderr():
        data = inp.read_image(0, 0, 0, nchannels, fmt)
    err = inp.geterror()
    if data is None or err:
        raise CamcalError(f"cannot decode image data (damaged or truncated?): {err.strip()[:120]}", path)
    return np.asarray(data).reshape(spec.height, spec.width, nchannels)


def _load_processed(path: Path) -> Frame:
    with open_image(path, ("jpeg", "tiff", "png"), "a JPEG, TIFF or PNG image") as (inp, spec):
        if _is_monochrome_image(inp, spec):
            return _load_monochrome(path)
        if spec.nchannels < 3:
            raise CamcalError(f"has {spec.nchannels} channel(s); camcal needs an RGB image", path)
        fmt = oiio.UINT16 if spec.format.size() > 1 else oiio.UINT8
        data = read_pixels(inp, spec, path, 3, fmt)
        bits = 16 if fmt == oiio.UINT16 else 8

        def attr(*names):
            for n in names:
                v = spec.getattribute(n)
                if v is not None:
                    return v
            return None

        oiio_exp = Exposure(
            exposure_s=clean_number(attr("ExposureTime")),
            f_number=clean_number(attr("FNumber")),
            iso=clean_number(attr("Exif:PhotographicSensitivity", "Exif:ISOSpeedRatings")),
            focal_length_mm=clean_number(attr("Exif:FocalLength", "FocalLength")),
            make=attr("Make"),
            model=attr("Model"),
            capture_time=iso_time(attr("Exif:DateTimeOriginal")),
        )
        icc = spec.getattribute("ICCProfile")
        icc_name = icc_description(None if icc is None else np.asarray(icc, np.uint8).tobytes())
    tags = exif_tags(path)
    exif_exp = exposure_from_exif(path, tags)
    # both read the file's EXIF; a tag exifread sees holding zero stays unknown
    oiio_exp = dataclasses.replace(
        oiio_exp,
        **{k: None for k in TRACKED if tags and tag_present(tags, k)},
    )
    oiio_exp = dataclasses.replace(
        oiio_exp, sources=tuple(sorted((k, "tag") for k in TRACKED if getattr(oiio_exp, k) is not None))
    )
    exp = fill_exposure(exif_exp, oiio_exp)
    exp = dataclasses.replace(exp, make=oiio_exp.make or exif_exp.make, model=oiio_exp.model or exif_exp.model)
    return _processed_frame(path, data, bits, exp, icc_name)


def read_monochrome(path: str | Path) -> np.ndarray:
    """The one channel of a monochrome 8- or 16-bit PNG or TIFF (a machine-vision camera's frame), (H, W) uint8
    or uint16, values as stored (no scaling); checked against the limits before decoding. A file with more than
    one channel is refused: its channels are not one sensor's samples."""
    path = Path(path)
    check_file(path)
    with open_image(path, ("tiff", "png"), "a PNG or TIFF image") as (inp, spec):
        if spec.nchannels != 1:
            raise CamcalError(f"has {spec.nchannels} channels; a monochrome frame has one", path)
        if str(spec.format) in ("half", "float", "double"):
            raise CamcalError(f"holds {spec.format} samples; a monochrome frame holds integer DN", path)
        fmt = oiio.UINT16 if spec.format.size() > 1 else oiio.UINT8
        return read_pixels(inp, spec, path, 1, fmt)[..., 0]


#: TIFF PhotometricInterpretation of RAW data (a CFA mosaic, LinearRaw): a DNG named .tif is not a monochrome frame.
_RAW_TIFF_PHOTOMETRIC = (32803, 34892)


def _is_monochrome_image(inp, spec) -> bool:
    """A one-channel 16-bit PNG or TIFF of sensor values (not a RAW file's TIFF structure under another name)."""
    if spec.nchannels != 1 or spec.format.size() < 2 or inp.format_name() not in ("png", "tiff"):
        return False
    return spec.getattribute("tiff:PhotometricInterpretation") not in _RAW_TIFF_PHOTOMETRIC


def _load_monochrome(path: Path) -> Frame:
    """A one-channel 16-bit PNG or TIFF (a machine-vision camera's frame) as a monochrome RAW frame.

    The values are the sensor's DN as stored (not tone-mapped). Such a file states no black level: 0 is the
    encoded range's floor (the dark frames measure the real offset). The white level is 2^bits − 1 with the bits
    of ``bits_per_sample`` in the ``session.toml`` that applies (a 12-bit camera writing 16-bit files), else the
    file's own (``oiio:BitsPerSample``, else its sample size); a value above it is refused.
    """
    data = read_monochrome(path)
    with open_image(path, ("tiff", "png"), "a PNG or TIFF image") as (_inp, spec):
        bits = int(spec.getattribute("oiio:BitsPerSample") or 8 * spec.format.size())
    stated = session_camera_facts(path.parent).get("bits_per_sample")
    if stated is not None:
        bits = int(stated)
        if int(data.max()) >= 2**bits:
            raise CamcalError(f"holds {int(data.max())}, above the {bits}-bit range of session.toml's "
                              "bits_per_sample", path)
    tags = exif_tags(path)
    exp = exposure_from_exif(path, tags)
    lo, hi = int(data.min()), int(data.max())
    return Frame(data=np.ascontiguousarray(data, np.uint16), kind="raw", cfa_pattern=None,
                 black_level_dn={"Y": 0.0}, white_level_dn=float(2**bits - 1), exposure=exp, path=path,
                 layout="mono", black_level_source="unknown").with_value_range(lo, hi)


def _processed_frame(path: Path, rgb: np.ndarray, bits: int, exposure: Exposure, icc_profile: str | None) -> Frame:
    """A processed (JPEG, TIFF, PNG, HEIC) frame: (H, W, 3) ``rgb`` of ``bits`` bits, black level 0, white
    level 2^bits − 1 (the encoded range; the tone curve is not undone here)."""
    return Frame(
        data=np.ascontiguousarray(rgb),
        kind="processed",
        cfa_pattern=None,
        black_level_dn={"R": 0.0, "G": 0.0, "B": 0.0},
        white_level_dn=float(2**bits - 1),
        exposure=exposure,
        path=path,
        layout="processed",
        icc_profile=icc_profile,
    )


def icc_description(icc: bytes | None) -> str | None:
    """The description of an ICC profile (its ``desc`` tag, read by Pillow's LittleCMS), e.g. ``Display P3``;
    None when there is no profile or it cannot be read."""
    if not icc:
        return None
    try:
        desc = ImageCms.getProfileDescription(ImageCms.ImageCmsProfile(io.BytesIO(icc))).strip()
    except (OSError, ValueError, TypeError, ImageCms.PyCMSError):
        return "unreadable ICC profile"
    return desc or None


def _load_heif(path: Path) -> Frame:
    """A HEIC/HEIF photo as a processed frame: R, G, B of 8 bits (uint8) or 10/12 bits (uint16, not rescaled)."""
    try:
        with quiet_stderr():
            heif = pillow_heif.open_heif(str(path), convert_hdr_to_8bit=False)
    except (ValueError, RuntimeError, OSError, SyntaxError) as exc:
        raise CamcalError(f"cannot open as a HEIC/HEIF image (damaged, or not a supported image): {exc}",
                          path) from None
    w, h = heif.size
    bits = int(heif.info.get("bit_depth") or 8)
    mode = str(heif.mode)
    channels = 4 if mode.startswith("RGBA") else 3 if mode.startswith("RGB") else 1
    if channels < 3:
        raise CamcalError(f"has {channels} channel(s) ({mode}); camcal needs an RGB image", path)
    _check_pixels(path, w, h, float(w) * h * channels * bits / 8.0)
    try:
        with quiet_stderr():
            pixels = np.asarray(heif)
    except (ValueError, RuntimeError, OSError) as exc:
        raise CamcalError(f"cannot decode image data (damaged or truncated?): {str(exc)[:120]}", path) from None
    if pixels.ndim != 3 or pixels.shape[:2] != (h, w) or pixels.shape[2] < 3:
        raise CamcalError(f"decodes to an image of unexpected shape {pixels.shape}", path)
    if pixels.dtype == np.uint16 and bits < 16:
        data = pixels[..., :3] >> np.uint16(16 - bits)  # libheif gives the top bits
    else:
        data = pixels[..., :3]
        bits = 8 * data.dtype.itemsize
    exp = exposure_from_exif(path, exif_from_block(heif.info.get("exif")))
    return _processed_frame(path, data, bits, exp, icc_description(heif.info.get("icc_profile")))


#: BITPIX of the FITS images camcal reads (integer data; 16 with BZERO 32768 is unsigned 16-bit).
FITS_BITPIX = (8, 16, 32)


def _fits_header(path: Path):
    """The primary header of a FITS file (astropy; nothing but the header is read), checked: a 2-D integer image
    within the pixel limit, and a file large enough for the data it declares."""
    from astropy.io import fits  # ~0.7 s to import: paid only by a session of FITS frames

    try:
        with quiet_stderr(), fits.open(path, memmap=False, lazy_load_hdus=True) as hdul:
            header = hdul[0].header.copy()
    except (OSError, ValueError, TypeError) as exc:
        raise CamcalError(f"cannot read the FITS header: {str(exc)[:120]}", path) from None
    naxis = int(header.get("NAXIS", 0))
    bitpix = int(header.get("BITPIX", 0))
    if naxis != 2:
        raise CamcalError(f"is a FITS file of {naxis} axes; camcal reads 2-D monochrome FITS images", path)
    if bitpix not in FITS_BITPIX:
        raise CamcalError(f"holds FITS BITPIX {bitpix} samples; camcal reads integer images (BITPIX 8, 16, 32)",
                          path)
    w, h = int(header.get("NAXIS1", 0)), int(header.get("NAXIS2", 0))
    _check_pixels(path, w, h, float(w) * h * abs(bitpix) / 8.0)
    if path.stat().st_size < w * h * abs(bitpix) // 8:
        raise CamcalError(f"is truncated: its header declares {w}x{h} pixels of {abs(bitpix)} bits", path)
    return header


def _fits_exposure(header) -> Exposure:
    """Exposure time (``EXPTIME`` or ``EXPOSURE``, s), capture time (``DATE-OBS``, UTC) and model (``INSTRUME``) of
    a FITS header, each marked ``tag``."""
    t = clean_number(header.get("EXPTIME", header.get("EXPOSURE")))
    when = header.get("DATE-OBS")
    when = when.strip()[:19] if isinstance(when, str) and when.strip() else None
    model = header.get("INSTRUME")
    sources = [("exposure_s", "tag")] if t is not None else []
    if when is not None:  # FITS times are UTC (FITS standard 4.0 §9.1)
        sources += [("capture_time", "tag"), ("utc_offset", "tag")]
    return Exposure(exposure_s=t, capture_time=when, utc_offset=None if when is None else "+00:00",
                    model=None if model is None else str(model).strip(), sources=tuple(sorted(sources)))


def _load_fits(path: Path) -> Frame:
    """A FITS image (an astronomy camera's frame) as a monochrome RAW frame.

    Exposure time from ``EXPTIME`` (or ``EXPOSURE``), s; ``DATE-OBS`` as the capture time (UTC); make/model from
    ``INSTRUME``; the black level from ``PEDESTAL`` when present (else 0, the dark frames measure the offset); the
    white level ``2^bits − 1`` with ``bits_per_sample`` of session.toml, else the BITPIX of the file. ISO and
    f-number are not FITS keys: frames.csv or session.toml give them.
    """
    from astropy.io import fits

    header = _fits_header(path)
    try:
        with quiet_stderr(), fits.open(path, memmap=False) as hdul:
            data = np.asarray(hdul[0].data)
    except (OSError, ValueError, TypeError) as exc:
        raise CamcalError(f"cannot decode FITS data (damaged or truncated?): {str(exc)[:120]}", path) from None
    if data.ndim != 2 or not np.issubdtype(data.dtype, np.integer) and not np.all(np.mod(data, 1) == 0):
        raise CamcalError(f"decodes to {data.dtype} data of shape {data.shape}; camcal reads integer 2-D images",
                          path)
    if data.size and (data.min() < 0 or data.max() > 65535):
        raise CamcalError(f"holds values {data.min():g}..{data.max():g}, outside 0..65535 DN", path)
    bits = int(abs(int(header["BITPIX"])))
    stated = session_camera_facts(path.parent).get("bits_per_sample")
    bits = min(int(stated), 16) if stated is not None else min(bits, 16)
    if data.size and int(data.max()) >= 2**bits:
        raise CamcalError(f"holds {int(data.max())}, above the {bits}-bit range", path)
    exp = _fits_exposure(header)
    pedestal = clean_number(header.get("PEDESTAL"))
    out = np.ascontiguousarray(data, np.uint16)
    return Frame(data=out, kind="raw", cfa_pattern=None, black_level_dn={"Y": float(pedestal or 0.0)},
                 white_level_dn=float(2**bits - 1), exposure=exp, path=path,
                 layout="mono", black_level_source="file" if pedestal is not None else "unknown",
                 ).with_value_range(int(out.min()), int(out.max()))


def load_frame(
    path: str | Path,
    overrides: dict[str, float | None] | None = None,
    defaults: dict[str, float | str] | None = None,
) -> Frame:
    """Decode one image file into a :class:`~camcal.frame.Frame`.

    Parameters
    ----------
    path : file path. The format is decided from the file's first bytes, then
        its extension: JPEG, PNG and HEIF by magic; TIFF-based files go to LibRaw
        unless named ``.tif``/``.tiff``; anything else goes to LibRaw.
    overrides : exposure fields that replace the file's metadata (a manifest
        row, see :func:`camcal.io.manifest.exposure_overrides`), marked ``frames.csv``.
    defaults : session defaults (exposure fields) for the values the file does not hold,
        marked ``session``; None (default) reads ``session.toml`` beside the file or in its
        parent folder (:func:`camcal.io.manifest.session_defaults_for`); ``{}`` for none.

    Raises
    ------
    CamcalError
        Missing, empty, damaged or unsupported files, one line naming the file.
    """
    path = Path(path)
    check_file(path)
    frame = (_load_heif(path) if is_heif(path) else _load_fits(path) if is_fits(path)
             else _load_raw(path) if is_raw_path(path) else _load_processed(path))
    if defaults is None:
        defaults = session_defaults_for(path.parent)
    exp = frame.exposure
    if defaults:
        exp = exp.filled("session", **defaults)
    if overrides:
        exp = exp.merged("frames.csv", **overrides)
    return frame if exp is frame.exposure else frame.with_exposure(exp)


@dataclasses.dataclass(frozen=True)
class FrameHeader:
    """What a file's header says without decoding its pixels (:func:`frame_header`).

    ``layout`` is None when the header does not tell it (a DNG whose image is in a sub-IFD): the file must be
    decoded to know it.
    """

    kind: str
    layout: str | None
    shape: tuple[int, int]
    make: str | None
    model: str | None


#: PhotometricInterpretation of a DNG's colour filter array and of its linear (demosaiced) RAW image.
_CFA_PHOTOMETRIC, _LINEAR_PHOTOMETRIC = "32803", "34892"


def frame_header(path: str | Path) -> FrameHeader:
    """Kind, RAW layout, size, make and model of an image file from its header, no pixel decoded.

    RAW files: LibRaw's open (sizes, before any unpacking) and the EXIF tags (make, model, and the layout when
    the main IFD holds the colour filter array or a linear RAW image; other RAW formats than DNG are Bayer
    mosaics or refused when decoded). Processed images: OpenImageIO's header (JPEG, TIFF, PNG), libheif's
    (HEIC). The size is the one :func:`load_frame` gives (a Bayer mosaic cut to even rows and columns).

    Raises
    ------
    CamcalError
        The header cannot be read (the decode would fail too, with its own message).
    """
    path = Path(path)
    check_file(path)
    if is_heif(path):
        try:
            with quiet_stderr():
                heif = pillow_heif.open_heif(str(path), convert_hdr_to_8bit=False)
        except (ValueError, RuntimeError, OSError, SyntaxError) as exc:
            raise CamcalError(f"cannot open as a HEIC/HEIF image: {exc}", path) from None
        w, h = heif.size
        exif = exposure_from_exif(path, exif_from_block(heif.info.get("exif")))
        return FrameHeader("processed", "processed", (int(h), int(w)), exif.make, exif.model)
    if is_fits(path):
        hdr = _fits_header(path)
        model = hdr.get("INSTRUME")
        return FrameHeader("raw", "mono", (int(hdr["NAXIS2"]), int(hdr["NAXIS1"])), None,
                           None if model is None else str(model).strip())
    tags = exif_tags(path)
    exif = exposure_from_exif(path, tags)
    if not is_raw_path(path):
        with open_image(path, ("jpeg", "tiff", "png"), "a JPEG, TIFF or PNG image") as (_inp, spec):
            make, model = spec.getattribute("Make"), spec.getattribute("Model")
            shape = (int(spec.height), int(spec.width))
            mono = _is_monochrome_image(_inp, spec)
        if mono:  # a machine-vision camera's one-channel 16-bit frame (:func:`_load_monochrome`)
            return FrameHeader("raw", "mono", shape, make or exif.make, model or exif.model)
        return FrameHeader("processed", "processed", shape, make or exif.make, model or exif.model)
    try:
        with quiet_stderr(), rawpy.imread(str(path)) as raw:  # open only: sizes and colours need no unpacking
            sizes = raw.sizes
            h, w = int(sizes.height), int(sizes.width)
            _check_pixels(path, int(sizes.raw_width), int(sizes.raw_height))
            _check_size_for_pixels(path, int(sizes.raw_width), int(sizes.raw_height))
    except (rawpy.LibRawError, OSError, ValueError, MemoryError) as exc:
        raise CamcalError(f"cannot read the RAW header: {type(exc).__name__}", path) from None
    photometric = str(tags.get("Image PhotometricInterpretation", "")) if tags else ""
    if photometric == _CFA_PHOTOMETRIC or (tags and "Image CFARepeatPatternDim" in tags):
        layout: str | None = "bayer"
    elif photometric == _LINEAR_PHOTOMETRIC:
        samples = str(tags.get("Image SamplesPerPixel", "")) if tags else ""
        layout = "mono" if samples == "1" else "linear"  # one sample: a monochrome sensor
    elif path.suffix.lower() == ".dng":
        layout = None  # the image is in a sub-IFD: CFA or linear is known after decoding
    else:
        layout = "bayer"
    if layout == "bayer":
        h, w = h // 2 * 2, w // 2 * 2
    return FrameHeader("raw", layout, (h, w), exif.make, exif.model)


def read_photo_metadata(path: str | Path, defaults: dict[str, float | str] | None = None) -> Exposure:
    """A photo's EXIF metadata (exposure, capture time, offset, GPS), each value with its source, without
    decoding its pixels; ``session.toml`` fills what the file does not hold (``defaults`` as in
    :func:`load_frame`). RAW files: the tags an EXIF reader finds (LibRaw is not opened).

    Raises
    ------
    CamcalError
        A missing, empty or unreadable file.
    """
    path = Path(path)
    check_file(path)
    exp = exposure_from_exif(path)
    if defaults is None:
        defaults = session_defaults_for(path.parent)
    return exp.filled("session", **defaults) if defaults else exp



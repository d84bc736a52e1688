"""Resource limits for every file camcal reads, in one place (listed in ``docs/reliability.md``).

A file from a stranger (a profile passed around, a session copied from a field laptop) may declare
sizes it does not hold: a ZIP member of 3 GB of deflated zeros, an image header of 60000x60000
pixels, JSON nested 200 000 levels deep. Every reader checks the *declared* sizes against these
limits **before** it decompresses, decodes or parses anything, and refuses with one line naming the
file and the limit (:class:`camcal.errors.CamcalError`, exit code 2). Hashes are computed by
streaming, never over a whole member held in memory.

The limits are far above what any real input needs (a profile's ``profile.json`` is 40 kB to 2 MB;
its depth is 7) and low enough that refusing costs well under a second and 100 MB.

Only the pixel limit can be raised, with the environment variable ``CAMCAL_MAX_PIXELS``; the
EXR sample limit follows it.
"""

from __future__ import annotations

import os
import re
import struct
from pathlib import Path

import numpy as np

from camcal.errors import CamcalError

MiB = 1024 * 1024

# ---- images (RAW, JPEG/TIFF/PNG, OpenEXR) --------------------------------------------------------------------
#: Largest image, in pixels, camcal allocates (RAW mosaic, processed image, EXR); ``CAMCAL_MAX_PIXELS`` overrides.
DEFAULT_MAX_PIXELS = 250_000_000
#: Every image (RAW, JPEG, TIFF, PNG, EXR): most bytes its header declares (pixels x channels x bits per
#: sample / 8, as stored) per byte of file. zlib's best is about 1030:1, a lossless-JPEG RAW stores at least
#: one bit per pixel, a constant JPEG about 1 bit per 3 pixels: 4096 is above every real file, and a 2 kB
#: JPEG whose header claims 12000x12000 pixels (0.93 GB before it failed to decode) is refused from its header.
MAX_IMAGE_EXPANSION = 4096
#: OpenEXR: most channels in one file (a profile's maps.exr has 28; radiance EXRs a few dozen at most).
MAX_EXR_CHANNELS = 256
#: OpenEXR: most decoded samples (pixels x channels) per allowed pixel: a profile's maps are 7 full-resolution
#: equivalents (28 channels at a quarter of the pixels).
EXR_SAMPLES_PER_PIXEL = 8
#: OpenEXR: the same expansion limit; an uncompressed EXR must hold all its pixel bytes.
MAX_EXR_EXPANSION = MAX_IMAGE_EXPANSION

# ---- JSON (profile.json, stage files, spectral metadata) -----------------------------------------------------
#: ``profile.json`` inside a profile (real ones: 40 kB to 2 MB).
MAX_PROFILE_JSON_BYTES = 8 * MiB
#: A stage JSON file beside its maps EXR (dark.json, flat.json, response JSON; real ones: under 1 MB).
MAX_STAGE_JSON_BYTES = 16 * MiB
#: A camera-curve file of the curve library (rawtoaces-data's are 8 to 20 kB; a 1 nm table of 2000 rows is 200 kB).
MAX_CURVE_JSON_BYTES = 1 * MiB
#: Deepest nesting of arrays/objects in any JSON camcal reads (real profiles: 7).
MAX_JSON_DEPTH = 64

# ---- text files (manifests, CSVs) ----------------------------------------------------------------------------
#: frames.csv, sweep.csv, chlorophyll and spectral-sensitivity CSVs (read with a bounded read; real ones:
#: under 1 MB). 4 MiB of one-character cells still parse in under 300 MB.
MAX_MANIFEST_BYTES = 4 * MiB
#: Lines of any text file camcal reads (counted on the bytes, before the text is split).
MAX_TEXT_LINES = 100_000
#: Longest line of a CSV (counted on the bytes, before the CSV parser sees it).
MAX_TEXT_LINE_BYTES = 64 * 1024
#: Most columns of a manifest (real ones: 4 to 8).
MAX_CSV_COLUMNS = 64

# ---- EMVA 1288 descriptor files ----------------------------------------------------------------------------------
#: Image lines (``i path``) one EMVA 1288 descriptor may list (the standard's reference sets: 300 to 700).
MAX_EMVA_IMAGES = 20_000
#: Illumination steps (``b``/``d`` lines) one descriptor may list (the standard asks for about 50 per series).
MAX_EMVA_STEPS = 5_000

# ---- the profile container (ZIP) ------------------------------------------------------------------------------
#: Members a profile may have (profile.json and maps.exr); counted from the end record, before the
#: central directory is parsed.
MAX_PROFILE_MEMBERS = 2
#: Size of the ZIP central directory (two entries take about 150 bytes).
MAX_CENTRAL_DIRECTORY_BYTES = 64 * 1024
#: Largest ratio of a member's declared size to its compressed size (deflated JSON: 3-10; maps.exr is stored).
MAX_ZIP_RATIO = 200
#: Members up to this size are not subject to the ratio limit (a tiny member cannot be a bomb).
ZIP_RATIO_FREE_BYTES = 1 * MiB
#: maps.exr may exceed the raw size of the maps its profile lists by this factor plus this many bytes
#: (EXR header, offset tables, chunk headers; zip chunks that do not compress are stored raw).
MAPS_SIZE_FACTOR = 1.05
MAPS_SIZE_SLACK_BYTES = 1 * MiB
#: Block size of every streamed read (hashes, member extraction).
STREAM_BLOCK_BYTES = 1 * MiB


def max_pixels() -> int:
    """Largest image (in pixels) camcal will allocate; ``CAMCAL_MAX_PIXELS`` overrides :data:`DEFAULT_MAX_PIXELS`."""
    try:
        return int(os.environ.get("CAMCAL_MAX_PIXELS", DEFAULT_MAX_PIXELS))
    except ValueError:
        return DEFAULT_MAX_PIXELS


def max_exr_samples() -> int:
    """Most samples (pixels x channels) one EXR may decode to: :data:`EXR_SAMPLES_PER_PIXEL` x :func:`max_pixels`."""
    return EXR_SAMPLES_PER_PIXEL * max_pixels()


def human_bytes(n: float) -> str:
    """``1536`` -> ``'1.5 KiB'`` (for refusal messages)."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"  # pragma: no cover


# ---- JSON nesting, checked before parsing ----------------------------------------------------------------------
_JSON_STRING = re.compile(rb'"(?:[^"\\]++|\\.)*+"', re.DOTALL)  # possessive: linear time on any input
_JSON_STEP = np.zeros(256, np.int8)
_JSON_STEP[[ord("["), ord("{")]] = 1
_JSON_STEP[[ord("]"), ord("}")]] = -1


def json_nesting_depth(raw: bytes, block: int = MiB) -> int:
    """Deepest nesting of arrays and objects in JSON text ``raw``, without parsing it.

    Strings are blanked first (brackets inside them do not count); the depth is the running sum of
    ``[{`` (+1) and ``]}`` (-1), computed in blocks with numpy (about 0.1 s per 10 MB). Malformed text
    gives a number too; the parser refuses it afterwards.
    """
    text = _JSON_STRING.sub(b'""', raw)
    a = np.frombuffer(text, np.uint8)
    depth = peak = 0
    for i in range(0, len(a), block):
        run = np.cumsum(_JSON_STEP[a[i:i + block]], dtype=np.int64) + depth
        if run.size:
            peak = max(peak, int(run.max()))
            depth = int(run[-1])
    return peak


def check_json_depth(raw: bytes, where: str | Path, what: str, max_depth: int = MAX_JSON_DEPTH) -> None:
    """Refuse JSON text nested deeper than ``max_depth`` (before the parser recurses into it)."""
    depth = json_nesting_depth(raw)
    if depth > max_depth:
        raise CamcalError(f"{what} is nested {depth} levels deep, above the limit of {max_depth}; refused", where)


# ---- ZIP: the end record, read before the central directory is parsed ------------------------------------------
_EOCD = b"PK\x05\x06"
_EOCD64_LOCATOR = b"PK\x06\x07"
_EOCD64 = b"PK\x06\x06"


def zip_directory_size(path: Path) -> tuple[int, int] | None:
    """``(number of entries, central directory bytes)`` from a ZIP file's end record, or None when absent.

    Reads at most the last 64 KiB + 98 bytes of the file (the end record, its comment and the ZIP64
    locator and record), so a central directory of a million entries is refused before Python's
    ``zipfile`` builds an object for each.
    """
    size = path.stat().st_size
    with open(path, "rb") as fh:
        tail_len = min(size, 22 + 65535 + 20)
        fh.seek(size - tail_len)
        tail = fh.read(tail_len)
        k = tail.rfind(_EOCD)
        if k < 0 or len(tail) - k < 22:
            return None
        entries, cd_size = struct.unpack_from("<HI", tail, k + 10)[0], struct.unpack_from("<I", tail, k + 12)[0]
        if k >= 20 and tail[k - 20:k - 16] == _EOCD64_LOCATOR:  # ZIP64: the real numbers are in the ZIP64 record
            (off64,) = struct.unpack_from("<Q", tail, k - 20 + 8)
            if off64 + 56 > size:
                return None
            fh.seek(off64)
            rec = fh.read(56)
            if len(rec) < 56 or rec[:4] != _EOCD64:
                return None
            entries, cd_size = struct.unpack_from("<QQ", rec, 32)
    return int(entries), int(cd_size)


def check_zip_directory(path: Path, max_members: int = MAX_PROFILE_MEMBERS) -> None:
    """Refuse a ZIP whose end record declares more than ``max_members`` entries or an oversized directory."""
    found = zip_directory_size(path)
    if found is None:
        raise CamcalError("not a camcal profile (not a ZIP container, or truncated)", path)
    entries, cd_size = found
    if entries > max_members:
        raise CamcalError(f"not a camcal profile: the ZIP declares {entries} members, a profile has at most "
                          f"{max_members}; refused", path)
    if cd_size > MAX_CENTRAL_DIRECTORY_BYTES:
        raise CamcalError(f"not a camcal profile: its ZIP directory declares {human_bytes(cd_size)}, above the "
                          f"limit of {human_bytes(MAX_CENTRAL_DIRECTORY_BYTES)}; refused", path)


def check_zip_member(path: Path, name: str, file_size: int, compress_size: int, max_bytes: int,
                     why: str = "") -> None:
    """Refuse a member whose declared size is above ``max_bytes`` or whose ratio is above :data:`MAX_ZIP_RATIO`."""
    if file_size > max_bytes:
        raise CamcalError(f"{name} declares {human_bytes(file_size)}, above the limit of {human_bytes(max_bytes)}"
                          f"{' ' + why if why else ''}; refused", path)
    if file_size > ZIP_RATIO_FREE_BYTES and file_size > MAX_ZIP_RATIO * max(compress_size, 1):
        raise CamcalError(f"{name} expands {file_size / max(compress_size, 1):.0f}-fold "
                          f"({human_bytes(compress_size)} to {human_bytes(file_size)}), above the limit of "
                          f"{MAX_ZIP_RATIO}:1 (a decompression bomb?); refused", path)


def maps_size_bound(doc: dict) -> tuple[int, str]:
    """Most bytes ``maps.exr`` may declare for the profile ``doc`` (its sensor and the maps it lists).

    Every map is one float32 channel at half resolution, ``ceil(width/2) x ceil(height/2)`` (at full resolution
    for a linear-RAW camera, ``camera.layout`` "linear"); the bound is
    that raw size times :data:`MAPS_SIZE_FACTOR` plus :data:`MAPS_SIZE_SLACK_BYTES`. Returns
    ``(bound, description)``; a document without a usable camera size or map list gives 0 (no maps).
    """
    cam = doc.get("camera") if isinstance(doc, dict) else None
    listed = doc.get("maps") if isinstance(doc, dict) else None
    w = cam.get("width") if isinstance(cam, dict) else None
    h = cam.get("height") if isinstance(cam, dict) else None
    if not (isinstance(w, int) and isinstance(h, int) and 0 < w and 0 < h
            and w * h <= max(max_pixels(), DEFAULT_MAX_PIXELS)):  # a lowered pixel limit applies to images
        return 0, "no valid camera width and height"
    n = sum(len(v) for v in listed.values() if isinstance(v, list)) if isinstance(listed, dict) else 0
    linear = isinstance(cam, dict) and cam.get("layout") in ("linear", "mono")  # full-resolution planes
    raw = n * (w * h if linear else ((w + 1) // 2) * ((h + 1) // 2)) * 4
    if n == 0:
        return 0, "no maps listed"
    return int(raw * MAPS_SIZE_FACTOR) + MAPS_SIZE_SLACK_BYTES, f"{n} maps of a {w}x{h} sensor"


# ---- images ----------------------------------------------------------------------------------------------------
def declared_image_bytes(spec) -> float:
    """Bytes an OpenImageIO ``ImageSpec`` declares as stored: pixels x channels x bits per sample / 8.

    Channels of different formats (an EXR with half and float channels) count each at its own size. The one
    rule for image files (:mod:`camcal.io.read`) and EXRs (:mod:`camcal.io.exr`).
    """
    formats = list(spec.channelformats or [])
    if len(formats) == spec.nchannels and formats:
        return float(spec.width) * float(spec.height) * sum(max(1, int(f.size())) for f in formats)
    bits = spec.getattribute("oiio:BitsPerSample") or 8 * spec.format.size()
    return float(spec.width) * float(spec.height) * spec.nchannels * max(int(bits), 1) / 8.0


def check_expansion(path: str | Path, declared_bytes: float) -> None:
    """Refuse an image header declaring more than :data:`MAX_IMAGE_EXPANSION` bytes per byte of file."""
    try:
        size = Path(path).stat().st_size
    except OSError:
        return  # the decoder reports the unreadable file
    if declared_bytes > MAX_IMAGE_EXPANSION * max(size, 1):
        raise CamcalError(f"declares {human_bytes(declared_bytes)} of pixel data in a file of {human_bytes(size)}, "
                          f"more than {MAX_IMAGE_EXPANSION}:1 (a damaged or hostile header); refused", path)


# ---- text --------------------------------------------------------------------------------------------------------
_LINE_BREAKS = np.zeros(256, bool)
_LINE_BREAKS[[0x0A, 0x0B, 0x0C, 0x0D, 0x1C, 0x1D, 0x1E]] = True  # what str.splitlines splits on (ASCII part)


def check_text_shape(raw: bytes, where: str | Path, what: str, max_lines: int | None = MAX_TEXT_LINES,
                     max_line_bytes: int | None = MAX_TEXT_LINE_BYTES) -> None:
    """Refuse text with more than ``max_lines`` lines or a line longer than ``max_line_bytes``, before it is
    split or parsed (numpy over the bytes: the line list of 4 MiB of newlines would take 250 MB)."""
    if max_lines is None and max_line_bytes is None:
        return
    brk = _LINE_BREAKS[np.frombuffer(raw, np.uint8)]
    n = int(np.count_nonzero(brk)) - raw.count(b"\r\n") + sum(raw.count(u) for u in (b"\xc2\x85", b"\xe2\x80\xa8",
                                                                                   b"\xe2\x80\xa9"))
    if max_lines is not None and n > max_lines:
        raise CamcalError(f"{what} has {n} lines, above the limit of {max_lines}; refused", where)
    if max_line_bytes is not None:
        ends = np.concatenate(([-1], np.flatnonzero(brk), [len(raw)]))
        longest = int(np.max(np.diff(ends))) - 1 if len(ends) > 1 else len(raw)
        if longest > max_line_bytes:
            raise CamcalError(f"{what} has a line of {human_bytes(longest)}, above the limit of "
                              f"{human_bytes(max_line_bytes)}; refused", where)

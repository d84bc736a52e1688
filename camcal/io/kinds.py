"""What kind of image a file is: RAW, processed (JPEG, TIFF, PNG, HEIC), FITS; by its extension and first bytes.
"""

from __future__ import annotations

from pathlib import Path

from camcal.errors import CamcalError

RAW_EXTENSIONS = {
    ".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".orf", ".rw2", ".raf",
    ".pef", ".srw", ".x3f", ".3fr", ".iiq", ".erf", ".kdc", ".dcr", ".mrw", ".raw", ".rwl",
}


HEIF_EXTENSIONS = {".heic", ".heif", ".hif"}


PROCESSED_EXTENSIONS = {".jpg", ".jpeg", ".tif", ".tiff", ".png"} | HEIF_EXTENSIONS


HEIF_BRANDS = {b"heic", b"heix", b"hevc", b"hevx", b"heim", b"heis", b"hevm", b"hevs", b"mif1", b"msf1", b"mif2"}
"""ISO/IEC 23008-12 major brands of HEVC-coded HEIF files (the ``ftyp`` box, bytes 8–12)."""


FITS_EXTENSIONS = {".fits", ".fit", ".fts"}
"""FITS images (astronomy cameras): monochrome frames read with astropy (:func:`_load_fits`)."""


IMAGE_EXTENSIONS = RAW_EXTENSIONS | PROCESSED_EXTENSIONS | FITS_EXTENSIONS


def check_file(path: Path) -> None:
    if not path.exists():
        raise CamcalError("no such file", path)
    if path.is_dir():
        raise CamcalError("is a directory, not an image file", path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise CamcalError(f"cannot read: {exc.strerror}", path) from None
    if size == 0:
        raise CamcalError("is empty (0 bytes)", path)


def file_magic(path: Path) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read(16)
    except OSError as exc:
        raise CamcalError(f"cannot read: {exc.strerror}", path) from None


def is_heif(path: Path) -> bool:
    """True when the file is an HEVC-coded HEIF (HEIC) image, by its ``ftyp`` box or, failing that, its name."""
    head = file_magic(path)
    if head[4:8] == b"ftyp":
        return head[8:12] in HEIF_BRANDS
    return path.suffix.lower() in HEIF_EXTENSIONS and not head.startswith((b"\xff\xd8\xff", b"\x89PNG"))


def is_fits(path: Path) -> bool:
    """True when the file is a FITS image (its first card ``SIMPLE  =``)."""
    return file_magic(path).startswith(b"SIMPLE  =")


def is_raw_path(path: Path) -> bool:
    """True when the file looks like a RAW file (not JPEG/PNG/HEIF/FITS, not a plain .tif)."""
    head = file_magic(path)
    if head.startswith(b"\xff\xd8\xff") or head.startswith(b"\x89PNG") or is_heif(path) or is_fits(path):
        return False
    return path.suffix.lower() not in {".tif", ".tiff", ".jpg", ".jpeg", ".png"} | HEIF_EXTENSIONS

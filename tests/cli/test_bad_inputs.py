"""A corpus of bad inputs, derived from valid ones, each run through the real CLI.

Every case builds one damaged input in a fresh folder, runs one CLI command on
it and checks the promise of ``docs/reliability.md``:

- exit code 2 and exactly one line on stderr (``camcal: error: ...``), or exit code 0
  with nothing but ``camcal: warning: ...`` lines where the input is still usable;
- never a traceback, never an internal error (exit 3);
- never a partial output file: on error none of the command's outputs exists, and
  no temporary ``.*.part*`` file is left anywhere in the work folder.

Most cases call :func:`camcal.cli.main` in-process with captured stdout/stderr
(and Python warnings rendered as the interpreter would print them); a sample
(every :data:`SUBPROCESS_EVERY`-th case) runs ``python -m camcal`` in a real subprocess.

The corpus is a product of *input kinds* (a damaged image, frames.csv, sweep.csv,
a stage file, a profile, a session layout) and *consumers* (the commands that read
that kind). Adding a command is one row in :data:`CONSUMERS` (see the comment there).
"""

from __future__ import annotations

import io
import json
import os
import random
import shutil
import struct
import subprocess
import sys
import zipfile
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from camcal.io.container import JSON_MEMBER, MAPS_MEMBER, content_hash
from tests.corpus import DARK0, WATER_SHAPE, Base, run_main, water_exrs

SUBPROCESS_EVERY = 150
OK, ERROR, EITHER = "ok", "error", "either"

# --------------------------------------------------------------------------------------------------------------
# the valid base: a tiny session and what the stages make of it (built once per test process)

SWEEP0 = "sweep_400.0nm_00.dng"
FRAMES_DARK_HEADER = "file,exposure_s,iso,f_number,temperature_C"
FRAMES_LIN_HEADER = "file,exposure_s,iso,f_number"
SWEEP_HEADER = "file,wavelength_nm,radiance_W_m2_sr,radiance_unc_W_m2_sr,bandwidth_nm,exposure_s,iso,f_number"


def run_subprocess(argv: list[str], env: dict[str, str] | None = None) -> tuple[int, str, str]:
    proc = subprocess.run([sys.executable, "-m", "camcal", *map(str, argv)], capture_output=True, text=True,
                          timeout=300, env={**os.environ, **(env or {})}, cwd=Path(__file__).resolve().parents[2])
    return proc.returncode, proc.stdout, proc.stderr



@pytest.fixture(scope="module")
def base(corpus_base: Base) -> Base:
    return corpus_base


# --------------------------------------------------------------------------------------------------------------
# byte-level mutators (deterministic)


def truncate(data: bytes, n: int) -> bytes:
    return data[: max(0, n)]


def bitflip(data: bytes, seed: int, n: int, lo: float = 0.0, hi: float = 1.0) -> bytes:
    rnd = random.Random(seed)
    out = bytearray(data)
    a, b = int(lo * len(out)), max(int(lo * len(out)) + 1, int(hi * len(out)))
    for _ in range(n):
        i = rnd.randrange(a, min(b, len(out)))
        out[i] ^= 1 << rnd.randrange(8)
    return bytes(out)


def tiff_patch(data: bytes, tag: int, value: int) -> bytes:
    """Set a SHORT/LONG tag of a little-endian TIFF/DNG's first IFD (ImageWidth 256, ImageLength 257...)."""
    out = bytearray(data)
    assert out[:4] in (b"II*\x00", b"MM\x00*"), "not a TIFF"
    big = out[:2] == b"MM"
    e16, e32 = (">H", ">I") if big else ("<H", "<I")
    off = struct.unpack_from(e32, out, 4)[0]
    for i in range(struct.unpack_from(e16, out, off)[0]):
        entry = off + 2 + 12 * i
        t, typ = struct.unpack_from(e16, out, entry)[0], struct.unpack_from(e16, out, entry + 2)[0]
        if t == tag:
            struct.pack_into(e16 if typ == 3 else e32, out, entry + 8, value & (0xFFFF if typ == 3 else 0xFFFFFFFF))
            return bytes(out)
    raise KeyError(tag)


def jpeg_sof_patch(data: bytes, width: int, height: int) -> bytes:
    """Set the frame size in a JPEG's start-of-frame segment."""
    out = bytearray(data)
    k = 2
    while out[k + 1] not in (0xC0, 0xC1, 0xC2):
        k += 2 + struct.unpack_from(">H", out, k + 2)[0]
    struct.pack_into(">HH", out, k + 5, height, width)
    return bytes(out)


def exr_window_patch(data: bytes, xmax: int, ymax: int, attr: bytes = b"dataWindow") -> bytes:
    """Set the box2i ``dataWindow`` (or ``displayWindow``) of an OpenEXR header."""
    out = bytearray(data)
    k = out.index(attr + b"\x00box2i\x00") + len(attr) + 7 + 4
    xmin, ymin, _, _ = struct.unpack_from("<4i", out, k)
    struct.pack_into("<4i", out, k, xmin, ymin, xmax, ymax)
    return bytes(out)


# --------------------------------------------------------------------------------------------------------------
# the corpus: cases per input kind


@dataclass(frozen=True)
class Case:
    """One bad input.

    kind : which consumers read it (see :data:`CONSUMERS`).
    make : builds the input; its signature depends on the kind (see the consumers).
    expect : ``ok`` / ``error`` / ``either``, or a dict by consumer name with ``*`` as default.
    env : environment for the run (resource limits).
    """

    kind: str
    category: str
    name: str
    make: Callable
    expect: str | dict[str, str] = ERROR
    env: dict[str, str] | None = None

    def expected(self, consumer: str) -> str:
        if isinstance(self.expect, str):
            return self.expect
        return self.expect.get(consumer, self.expect.get("*", EITHER))


def image_cases() -> list[Case]:
    """Damaged images: ``make(base) -> (suffix, bytes)``."""
    cases: list[Case] = []

    def add(category, name, make, expect=ERROR, env=None):
        cases.append(Case("image", category, name, make, expect, env))

    # decodable but not a RAW frame of this camera; apply reads a processed file by its content
    raw_ok = {"inspect": OK, "apply": OK, "apply-batch": OK, "apply-mask": OK, "*": ERROR}
    image_ok = {"apply-mask": EITHER, "*": ERROR}  # any decodable image of the right size is a valid mask
    for src, suffix in (("dng", ".dng"), ("jpeg", ".jpg"), ("tiff", ".tif")):
        for n in (1, 2, 4, 8, 16, 64, 256, 1024):
            add("truncated", f"{src}-first{n}B", lambda b, s=src, x=suffix, n=n: (x, truncate(b.files[s], n)))
        for frac in (0.1, 0.25, 0.5, 0.75, 0.9, 0.99):
            add("truncated", f"{src}-{int(frac * 100)}pct",
                lambda b, s=src, x=suffix, f=frac: (x, truncate(b.files[s], int(f * len(b.files[s])))),
                ERROR if src != "jpeg" or frac < 0.5 else EITHER)
        add("truncated", f"{src}-minus1B", lambda b, s=src, x=suffix: (x, b.files[s][:-1]),
            ERROR if src == "dng" else EITHER)
        for seed in range(10):
            add("bit-flipped", f"{src}-flip{seed}",
                lambda b, s=src, x=suffix, k=seed: (x, bitflip(b.files[s], k, 1 + k)), EITHER)
        for seed in range(6):
            add("bit-flipped", f"{src}-headflip{seed}",
                lambda b, s=src, x=suffix, k=seed: (x, bitflip(b.files[s][:600], 100 + k, 2) + b.files[s][600:]),
                EITHER)
    # huge (or empty) declared dimensions
    small = {"inspect": EITHER, "apply-mask": EITHER, "*": ERROR}  # a smaller size may decode but never stacks
    for w, h, exp in ((60000, 60000, ERROR), (20000, 20000, ERROR), (65535, 65535, ERROR), (0, 0, ERROR),
                      (1, 1, small), (48, 32, small)):
        add("huge dimensions", f"dng-{w}x{h}",
            lambda b, w=w, h=h: (".dng", tiff_patch(tiff_patch(tiff_patch(b.files["dng"], 256, w), 257, h), 278, h)),
            exp)
        add("huge dimensions", f"tiff-{w}x{h}",
            lambda b, w=w, h=h: (".tif", tiff_patch(tiff_patch(b.files["tiff"], 256, w), 257, h)),
            small if w in (1, 48) else ERROR)
        add("huge dimensions", f"jpeg-{w}x{h}",
            lambda b, w=w, h=h: (".jpg", jpeg_sof_patch(b.files["jpeg"], w, h)), EITHER if w in (1, 48) else ERROR)
    # a valid image above the configured pixel limit (2000: above the profile's maps, 48x32 planes, so that apply
    # lists the photo as failed instead of refusing the profile, whatever ran before in this process)
    for src, suffix in (("dng", ".dng"), ("jpeg", ".jpg"), ("tiff", ".tif")):
        add("pixel limit", f"{src}-over-limit", lambda b, s=src, x=suffix: (x, b.files[s]), ERROR,
            env={"CAMCAL_MAX_PIXELS": "2000"})
    # wrong extensions and wrong contents
    add("wrong extension", "jpeg-as-dng", lambda b: (".dng", b.files["jpeg"]), raw_ok)
    add("wrong extension", "jpeg-as-tif", lambda b: (".tif", b.files["jpeg"]), raw_ok)
    add("wrong extension", "tiff-as-dng", lambda b: (".dng", b.files["tiff"]), EITHER)
    add("wrong extension", "tiff-as-jpg", lambda b: (".jpg", b.files["tiff"]), {"inspect": EITHER, "*": ERROR})
    add("wrong extension", "dng-as-jpg", lambda b: (".jpg", b.files["dng"]), image_ok)
    add("wrong extension", "dng-as-tif", lambda b: (".tif", b.files["dng"]), image_ok)
    add("wrong extension", "dng-as-txt", lambda b: (".txt", b.files["dng"]), {"inspect": OK, "*": EITHER})
    for suffix in (".dng", ".jpg", ".tif", ".nef"):
        add("wrong extension", f"exr-as-{suffix[1:]}", lambda b, x=suffix: (x, b.files["exr"]), image_ok)
        add("wrong extension", f"profile-as-{suffix[1:]}", lambda b, x=suffix: (x, b.files["profile"]), ERROR)
        add("wrong extension", f"text-as-{suffix[1:]}", lambda b, x=suffix: (x, b"file,exposure_s\nx.dng,1\n"), ERROR)
    for suffix in (".dng", ".jpg", ".jpeg", ".tif", ".png", ".cr2"):
        add("zero bytes", f"empty{suffix}", lambda b, x=suffix: (x, b""), ERROR)
    for i, head in enumerate((b"II*\x00", b"MM\x00*", b"\xff\xd8\xff\xe0", b"\x89PNG\r\n\x1a\n", b"v/1\x01")):
        for n in (0, 100, 5000):
            add("garbage", f"magic{i}-plus{n}",
                lambda b, h=head, n=n, i=i: (".dng" if i < 2 else ".jpg", h + np.random.default_rng(n + i).bytes(n)))
    add("garbage", "jpeg-soi-eoi", lambda b: (".jpg", b"\xff\xd8\xff\xd9"))
    return cases


REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"


def realdata_images() -> list[Path]:
    """The image files of ``../shared/realdata`` (none when the folder is absent)."""
    if not REALDATA.is_dir():
        return []
    return sorted(p for p in REALDATA.glob("*/*") if p.parent.name in ("pi", "raw", "jpeg", "stripped"))


def real_image_cases() -> list[Case]:
    """Real files of real cameras (``../shared/realdata``; CI has it; none when absent), as they are.

    Every readable one inspects, and with any other command ends in one line (it is another camera's
    frame); one whose image data were stripped is refused by every command, naming it.
    """
    cases = []
    for f in realdata_images():
        rel = f"{f.parent.name}/{f.name}"
        if f.parent.name == "stripped":
            cases.append(Case("real_image", "real file, image data stripped", rel,
                              lambda b, f=f: (f.suffix, f.read_bytes()), ERROR))
        else:
            cases.append(Case("real_image", "real file", rel, lambda b, f=f: (f.suffix, f.read_bytes()),
                              {"inspect": OK, "*": EITHER}))
    return cases


def _csv_rows(text: str) -> list[list[str]]:
    return [ln.split(",") for ln in text.splitlines()]


def _csv_join(rows: list[list[str]], nl: str = "\n") -> str:
    return nl.join(",".join(r) for r in rows) + nl


def csv_cases(kind: str, header: str, required: tuple[str, ...], positive: set[str],
              negative_ok: set[str], optional_ok: bool = True) -> list[Case]:
    """Damaged manifests: ``make(valid_text) -> bytes``.

    ``optional_ok``: whether an emptied or dropped optional column still leaves the input usable
    (the files' own metadata fills the gap).
    """
    cols = header.split(",")
    cases: list[Case] = []

    def add(category, name, make, expect=ERROR):
        cases.append(Case(kind, category, name, make, expect))

    def set_cell(col: str, value: str, row: int = 1):
        def make(text: str) -> bytes:
            rows = _csv_rows(text)
            rows[row][cols.index(col)] = value
            return _csv_join(rows).encode()
        return make

    for col in cols[1:]:
        for label, value in (("text", "abc"), ("NaN", "NaN"), ("nan", "nan"), ("inf", "inf"), ("-inf", "-Infinity"),
                             ("overflow", "1e400"), ("hex", "0x10"), ("comma", "2,5"), ("percent", "50%")):
            add("non-numeric/NaN", f"{col}-{label}", set_cell(col, value))
        add("negative", f"{col}-negative", set_cell(col, "-1.5"), OK if col in negative_ok else ERROR)
        add("negative", f"{col}-zero", set_cell(col, "0"), ERROR if col in positive else OK)
        add("missing", f"{col}-empty", set_cell(col, ""), ERROR if col in required else (OK if optional_ok else EITHER))
        add("whitespace", f"{col}-padded", lambda t, c=col: set_cell(c, f"  {_csv_rows(t)[1][cols.index(c)]}  ")(t), OK)
        add("extreme", f"{col}-tiny", set_cell(col, "1e-300"), EITHER)
        add("extreme", f"{col}-huge", set_cell(col, "1e300"), EITHER)

        def drop(text: str, c=col) -> bytes:
            i = cols.index(c)
            return _csv_join([r[:i] + r[i + 1:] for r in _csv_rows(text)]).encode()
        add("missing", f"drop-column-{col}", drop, ERROR if col in required else (OK if optional_ok else EITHER))
    for label, value in (("parent", "../escape.dng"), ("parent2", "sub/../../escape.dng"), ("absolute", "/etc/passwd"),
                         ("absolute-dng", "/tmp/x.dng"), ("nul", "a\x00b.dng"), ("missing-file", "nothere.dng"),
                         ("missing-subdir", "sub/nothere.dng"), ("empty", "")):
        add("path escape" if "escape" in value or value.startswith("/") else "missing", f"file-{label}",
            set_cell("file", value))
    add("duplicate", "duplicate-row", lambda t: _csv_join(_csv_rows(t) + [_csv_rows(t)[1]]).encode())
    add("duplicate", "duplicate-file-other-values",
        lambda t: _csv_join(_csv_rows(t) + [[_csv_rows(t)[1][0]] + _csv_rows(t)[2][1:]]).encode())
    add("duplicate", "duplicate-header-column", lambda t: _csv_join(
        [r + ([cols[1]] if i == 0 else ["1"]) for i, r in enumerate(_csv_rows(t))]).encode())
    add("structure", "extra-cell", lambda t: _csv_join([r + (["9"] if i == 2 else []) for i, r in
                                                        enumerate(_csv_rows(t))]).encode())
    add("structure", "missing-cell", lambda t: _csv_join([r[:-1] if i == 2 else r for i, r in
                                                          enumerate(_csv_rows(t))]).encode())
    add("structure", "extra-column", lambda t: _csv_join([r + (["note"] if i == 0 else ["x"]) for i, r in
                                                          enumerate(_csv_rows(t))]).encode(), OK)
    add("structure", "reordered-columns", lambda t: _csv_join([r[::-1] for r in _csv_rows(t)]).encode(), OK)
    add("structure", "header-only", lambda t: (t.splitlines()[0] + "\n").encode(),
        OK if optional_ok and kind == "frames_csv" else ERROR)
    add("structure", "empty-file", lambda t: b"")
    add("structure", "blank-lines-only", lambda t: b"\n \n\t\n")
    add("structure", "no-header", lambda t: "\n".join(t.splitlines()[1:]).encode())
    add("structure", "header-typo", lambda t: t.replace("file,", "fille,", 1).encode())
    add("structure", "tab-separated", lambda t: t.replace(",", "\t").encode())
    add("structure", "semicolon-separated", lambda t: t.replace(",", ";").encode())
    add("structure", "unterminated-quote", lambda t: t.replace("\n", '\n"', 1).encode(), EITHER)
    add("structure", "quoted-newline", lambda t: t.replace("\n", '\n"a\nb",', 1).encode())
    add("encoding", "bom", lambda t: b"\xef\xbb\xbf" + t.encode(), OK)
    add("encoding", "crlf", lambda t: t.replace("\n", "\r\n").encode(), OK)
    add("encoding", "bom-crlf", lambda t: b"\xef\xbb\xbf" + t.replace("\n", "\r\n").encode(), OK)
    add("encoding", "cr-only", lambda t: t.replace("\n", "\r").encode(), OK)
    add("encoding", "comments-blank-lines",
        lambda t: ("# written by hand\n\n" + t.replace("\n", "\n\n", 2)).encode(), OK)
    add("encoding", "utf16", lambda t: t.encode("utf-16"))
    add("encoding", "latin1", lambda t: ("# mesuré à 24 °C\n" + t).encode("latin-1"))
    add("encoding", "nul-bytes", lambda t: t.replace("\n", "\n\x00", 1).encode())
    add("encoding", "binary", lambda t: np.random.default_rng(7).bytes(300))
    add("resource", "over-16MiB", lambda t: t.encode() + b"#" * (16 * 1024 * 1024 + 10) + b"\n")
    return cases


def _rezip(doc: dict | bytes, maps: bytes | None, *, rehash: bool = True, extra: dict[str, bytes] | None = None,
           maps_hash: str | None = None) -> bytes:
    """A profile container with ``doc`` (re-hashed unless told not to) and ``maps``."""
    if isinstance(doc, dict):
        doc = dict(doc)
        if rehash:
            integ = dict(doc.get("integrity") or {})
            integ["content_sha256"] = content_hash(doc)
            if maps_hash is not None:
                integ["maps_sha256"] = maps_hash
            doc["integrity"] = integ
            doc["integrity"]["content_sha256"] = content_hash(doc)
        text = json.dumps(doc, allow_nan=True).encode()
    else:
        text = doc
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr(JSON_MEMBER, text, compress_type=zipfile.ZIP_DEFLATED)
        if maps is not None:
            zf.writestr(MAPS_MEMBER, maps)
        for k, v in (extra or {}).items():
            zf.writestr(k, v)
    return buf.getvalue()


def _profile_parts(b: Base) -> tuple[dict, bytes]:
    with zipfile.ZipFile(io.BytesIO(b.files["profile"])) as zf:
        return json.loads(zf.read(JSON_MEMBER)), zf.read(MAPS_MEMBER)


def _set_path(doc: dict, path: tuple, value, delete: bool = False) -> dict:
    doc = json.loads(json.dumps(doc))
    node = doc
    for k in path[:-1]:
        node = node[k]
    if delete:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


# paths inside profile.json that the corpus mutates (a sample of every section; they must exist in a valid profile)
PROFILE_PATHS: tuple[tuple, ...] = (
    ("format",), ("schema_version",), ("camera",), ("camera", "width"), ("camera", "height"),
    ("camera", "cfa_pattern"), ("camera", "make"), ("reference",), ("reference", "iso"), ("reference", "f_number"),
    ("dark",), ("dark", "iso"), ("dark", "cfa_pattern"), ("dark", "exposure_times_s"), ("dark", "channels"),
    ("dark", "white_level_dn"), ("flat",), ("response",), ("response", "raw"), ("spectral_sensitivity",),
    ("spectral_sensitivity", "wavelength_nm"), ("provenance",), ("provenance", "inputs"), ("maps",),
    ("maps", "dark"), ("integrity",), ("response", "processed", "colour_matrix"),
    ("response", "processed", "colour_matrix", "matrix"), ("response", "processed", "colour_matrix", "matrix_unc"),
)
WRONG_VALUES: tuple[tuple[str, object], ...] = (
    ("string", "x"), ("negative", -1), ("null", None), ("list", []), ("object", {}), ("bool", True),
)


def profile_cases() -> list[Case]:
    """Damaged profiles: ``make(base) -> bytes`` of a ``.camcal`` file."""
    cases: list[Case] = []

    def add(category, name, make, expect=ERROR):
        cases.append(Case("profile", category, name, make, expect))

    for n in (0, 1, 22, 100, 1000):
        add("truncated", f"first{n}B", lambda b, n=n: truncate(b.files["profile"], n))
    for frac in (0.25, 0.5, 0.9, 0.999):
        add("truncated", f"{int(frac * 1000)}permille",
            lambda b, f=frac: truncate(b.files["profile"], int(f * len(b.files["profile"]))))
    for seed in range(12):
        add("bit-flipped", f"flip{seed}", lambda b, k=seed: bitflip(b.files["profile"], 300 + k, 1 + k % 3))
    add("wrong extension", "jpeg-as-profile", lambda b: b.files["jpeg"])
    add("wrong extension", "exr-as-profile", lambda b: b.files["exr"])
    add("wrong extension", "dng-as-profile", lambda b: b.files["dng"])
    add("structure", "extra-member", lambda b: _rezip(*_profile_parts(b), rehash=False, extra={"evil.py": b"x"}))
    add("structure", "no-json", lambda b: _rezip(b"", None, extra={"other.json": b"{}"}))
    add("structure", "maps-missing", lambda b: _rezip(_profile_parts(b)[0], None, rehash=False))
    add("structure", "maps-missing-rehashed", lambda b: _rezip(_profile_parts(b)[0], None, maps_hash=""))
    add("structure", "maps-truncated-rehashed", lambda b: _rezip(
        _profile_parts(b)[0], _profile_parts(b)[1][:500],
        maps_hash=__import__("hashlib").sha256(_profile_parts(b)[1][:500]).hexdigest()))
    add("structure", "maps-bitflip-rehashed", lambda b: _rezip(
        _profile_parts(b)[0], bitflip(_profile_parts(b)[1], 5, 3, 0.0, 0.05),
        maps_hash=__import__("hashlib").sha256(bitflip(_profile_parts(b)[1], 5, 3, 0.0, 0.05)).hexdigest()), EITHER)
    add("structure", "maps-swapped-for-stage-exr", lambda b: _rezip(
        _profile_parts(b)[0], b.files["exr"], maps_hash=__import__("hashlib").sha256(b.files["exr"]).hexdigest()))
    add("structure", "json-not-object", lambda b: _rezip(b"[1, 2]", _profile_parts(b)[1]))
    add("structure", "json-invalid", lambda b: _rezip(b"{\"format\": ", _profile_parts(b)[1]))
    add("structure", "json-not-utf8", lambda b: _rezip(b"\xff\xfe{}", _profile_parts(b)[1]))
    add("tampered hash", "value-changed", lambda b: _rezip(
        _set_path(_profile_parts(b)[0], ("reference", "iso"), 200.0), _profile_parts(b)[1], rehash=False))
    add("tampered hash", "hash-zeroed", lambda b: _rezip(
        _set_path(_profile_parts(b)[0], ("integrity", "content_sha256"), "0" * 64), _profile_parts(b)[1], rehash=False))
    add("tampered hash", "maps-hash-changed", lambda b: _rezip(
        _profile_parts(b)[0], _profile_parts(b)[1], maps_hash="f" * 64))
    add("tampered hash", "maps-bitflip", lambda b: _rezip(
        _profile_parts(b)[0], bitflip(_profile_parts(b)[1], 9, 1), rehash=False))
    add("tampered hash", "integrity-missing", lambda b: _rezip(
        _set_path(_profile_parts(b)[0], ("integrity",), None, delete=True), _profile_parts(b)[1], rehash=False))
    for v, exp in (("2.0", ERROR), ("0.9", ERROR), ("10.0", ERROR), ("x", ERROR), ("", ERROR), ("1.99", EITHER),
                   (1, ERROR), (None, ERROR), ("-1.0", ERROR), ("1", EITHER)):
        add("wrong version", f"schema_version-{v!r}", lambda b, v=v: _rezip(
            _set_path(_profile_parts(b)[0], ("schema_version",), v), _profile_parts(b)[1]), exp)
    add("wrong version", "format-marker", lambda b: _rezip(
        _set_path(_profile_parts(b)[0], ("format",), "camcal-profile-2"), _profile_parts(b)[1]))
    for label, token in (("NaN", "NaN"), ("Infinity", "Infinity"), ("-Infinity", "-Infinity"), ("1e999", "1e999"),
                         ("-1e999", "-1e999")):
        def nan_doc(b, token=token, rehash=True):
            doc = _profile_parts(b)[0]
            doc = _set_path(doc, ("reference", "iso"), 12345.678)
            if rehash:
                doc["integrity"]["content_sha256"] = content_hash(doc)
            text = json.dumps(doc).replace("12345.678", token, 1).encode()
            return _rezip(text, _profile_parts(b)[1])
        add("NaN/inf", f"reference-iso-{label}", nan_doc)
    for path in PROFILE_PATHS:
        key = ".".join(path)
        required_top = len(path) == 1
        add("missing key", f"del-{key}", lambda b, p=path: _rezip(
            _set_path(_profile_parts(b)[0], p, None, delete=True), _profile_parts(b)[1]),
            ERROR if required_top or path[-1] in ("width", "height", "iso", "f_number", "cfa_pattern") else EITHER)
        for label, value in WRONG_VALUES:
            if path == ("integrity",):
                continue
            add("wrong type", f"{key}={label}", lambda b, p=path, v=value: _rezip(
                _set_path(_profile_parts(b)[0], p, v), _profile_parts(b)[1]), EITHER)
    cm_path = ("response", "processed", "colour_matrix", "matrix")
    for label, value in (("singular", [[1, 0, 0], [0, 1, 0], [1, 0, 0]]), ("2x2", [[1, 0], [0, 1]]),
                         ("ragged", [[1, 0, 0], [0, 1], [0, 0, 1]]),
                         ("text-cell", [[1, 0, 0], [0, "x", 0], [0, 0, 1]])):
        add("wrong type", f"colour-matrix-{label}", lambda b, v=value: _rezip(
            _set_path(_profile_parts(b)[0], cm_path, v), _profile_parts(b)[1]))
    for where in ((), ("camera",), ("dark",), ("reference",), ("dark", "channels", "R"), ("flat",),
                  ("flat", "k"), ("response", "raw"), ("response", "raw", "channels", "G1"),
                  ("response", "processed", "tone", "channels", "G", "srgb"), ("spectral_sensitivity",),
                  ("spectral_sensitivity", "values"), ("provenance",), ("integrity",)):
        add("extra key", f"extra-in-{'.'.join(where) or 'top'}", lambda b, w=where: _rezip(
            _set_path(_profile_parts(b)[0], (*w, "surprise"), 1), _profile_parts(b)[1]))  # strict at every level
    return cases


def stage_cases() -> list[Case]:
    """Damaged dark-model files (JSON + maps EXR): ``make(json_path)`` edits the copies in place."""
    cases: list[Case] = []

    def add(category, name, make, expect=ERROR):
        cases.append(Case("stage", category, name, make, expect))

    def maps(p: Path) -> Path:
        return p.with_name(p.stem + ".maps.exr")

    def rehash(p: Path) -> None:
        from camcal.io.store import sha256_file

        doc = json.loads(p.read_text())
        doc["maps_sha256"] = sha256_file(maps(p))
        p.write_text(json.dumps(doc))

    def edit_json(fn: Callable[[dict], object]) -> Callable[[Path], None]:
        def make(p: Path) -> None:
            doc = json.loads(p.read_text())
            doc = fn(doc) or doc
            p.write_text(json.dumps(doc, allow_nan=True))
        return make

    def edit_maps(fn: Callable[[bytes], bytes], do_rehash: bool = True) -> Callable[[Path], None]:
        def make(p: Path) -> None:
            maps(p).write_bytes(fn(maps(p).read_bytes()))
            if do_rehash:
                rehash(p)
        return make

    for n in (0, 10, 300, 2000):
        add("truncated", f"json-first{n}B", lambda p, n=n: p.write_bytes(p.read_bytes()[:n]))
        add("truncated", f"exr-first{n}B-rehashed", edit_maps(lambda d, n=n: d[:n]))
    add("truncated", "exr-minus1B-rehashed", edit_maps(lambda d: d[:-1]))
    add("truncated", "exr-half-rehashed", edit_maps(lambda d: d[: len(d) // 2]))
    add("tampered hash", "exr-bitflip", edit_maps(lambda d: bitflip(d, 3, 1), do_rehash=False))
    for seed in range(6):
        add("bit-flipped", f"exr-flip{seed}-rehashed", edit_maps(lambda d, k=seed: bitflip(d, 40 + k, 1 + k)), EITHER)
    for k, (w, h) in enumerate(((99999, 99999), (10**6, 10), (-5, -5))):
        add("huge dimensions", f"exr-window{k}-rehashed", edit_maps(lambda d, w=w, h=h: exr_window_patch(d, w, h)))
    add("wrong extension", "exr-is-jpeg-rehashed", lambda p: (maps(p).write_bytes(b"\xff\xd8\xff\xd9"), rehash(p)))
    add("missing", "exr-deleted", lambda p: maps(p).unlink())
    add("missing", "exr-zero-bytes", lambda p: maps(p).write_bytes(b""))
    add("symlink", "exr-symlink-outside", lambda p: (maps(p).unlink(), maps(p).symlink_to("/etc/hostname")))
    add("path escape", "maps-file-escapes", edit_json(lambda d: d.update(maps_file="../../../../etc/passwd")))
    add("wrong type", "json-list", lambda p: p.write_text("[]"))
    add("wrong type", "json-null", lambda p: p.write_text("null"))
    add("wrong type", "kind-flat", edit_json(lambda d: d.update(kind="flat")))
    add("wrong type", "data-list", edit_json(lambda d: d.update(data=[])))
    add("wrong type", "maps-names-string", edit_json(lambda d: d.update(maps="bias.R")))
    add("missing key", "maps-names-missing-bias", edit_json(lambda d: d.update(maps=d["maps"][4:])))
    add("encoding", "json-utf16", lambda p: p.write_bytes(p.read_text().encode("utf-16")))
    add("encoding", "json-bom", lambda p: p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes()), EITHER)
    for key in ("iso", "cfa_pattern", "exposure_times_s", "white_level_dn", "black_level_dn", "channels",
                "temperature_c"):
        add("missing key", f"data-del-{key}", edit_json(lambda d, k=key: d["data"].pop(k)),
            ERROR if key in ("iso", "cfa_pattern") else EITHER)
        for label, value in WRONG_VALUES + (("nan", float("nan")), ("inf", float("inf"))):
            add("wrong type", f"data-{key}={label}", edit_json(lambda d, k=key, v=value: d["data"].update({k: v})),
                EITHER)
    return cases


def session_cases() -> list[Case]:
    """Damaged session layouts: ``make(session_dir)`` edits a copy of the valid session in place."""
    cases: list[Case] = []

    def add(category, name, make, expect=ERROR):
        cases.append(Case("session", category, name, make, expect))

    dark0 = f"dark/{DARK0}"
    add("symlink", "frame-symlink-inside", lambda s: ((s / dark0).unlink(), (s / dark0).symlink_to(
        s / "dark" / "dark_002.000s_01.dng")), ERROR)  # the same frame twice: no temporal noise
    add("symlink", "frame-symlink-outside", lambda s: (shutil.move(s / dark0, s.parent / "elsewhere.dng"),
                                                       (s / dark0).symlink_to(s.parent / "elsewhere.dng")), EITHER)
    add("symlink", "frame-dangling", lambda s: ((s / dark0).unlink(), (s / dark0).symlink_to(s / "nothere.dng")))
    add("symlink", "frame-loop", lambda s: ((s / dark0).unlink(), (s / dark0).symlink_to(s / dark0)))
    add("symlink", "frame-to-directory", lambda s: ((s / dark0).unlink(), (s / dark0).symlink_to(s / "flat")))
    add("symlink", "frame-to-dev-zero", lambda s: ((s / dark0).unlink(), (s / dark0).symlink_to("/dev/zero")))
    add("symlink", "stage-folder-symlink", lambda s: (shutil.move(s / "flat", s.parent / "flat-elsewhere"),
                                                      (s / "flat").symlink_to(s.parent / "flat-elsewhere")), OK)
    add("symlink", "manifest-row-symlink-escapes", lambda s: (
        (s / "dark" / "link.dng").symlink_to(s.parent / "outside.dng"), (s.parent / "outside.dng").write_bytes(
            (s / dark0).read_bytes()),
        (s / "dark" / "frames.csv").write_text((s / "dark" / "frames.csv").read_text() + "link.dng,2.0,100,4,24\n")))
    add("symlink", "frames-csv-symlink-to-etc", lambda s: ((s / "dark" / "frames.csv").unlink(),
                                                           (s / "dark" / "frames.csv").symlink_to("/etc/passwd")))
    add("symlink", "frames-csv-to-dev-zero", lambda s: ((s / "dark" / "frames.csv").unlink(),
                                                        (s / "dark" / "frames.csv").symlink_to("/dev/zero")))
    add("structure", "frames-csv-is-directory", lambda s: ((s / "dark" / "frames.csv").unlink(),
                                                           (s / "dark" / "frames.csv").mkdir()))
    add("structure", "sweep-csv-is-directory", lambda s: ((s / "sweep" / "sweep.csv").unlink(),
                                                          (s / "sweep" / "sweep.csv").mkdir()))
    add("structure", "sweep-csv-missing", lambda s: (s / "sweep" / "sweep.csv").unlink(), {"dark": OK, "*": ERROR})
    add("structure", "frame-is-directory", lambda s: ((s / dark0).unlink(), (s / dark0).mkdir()), EITHER)
    add("structure", "stage-folders-empty", lambda s: [shutil.rmtree(s / d) or (s / d).mkdir() for d in
                                                       ("bias", "dark", "flat", "linearity", "sweep")])
    add("structure", "only-non-images", lambda s: [
        shutil.rmtree(s / d) or (s / d).mkdir() or (s / d / "a.txt").write_text("x")
        for d in ("bias", "dark", "flat", "linearity", "sweep")])
    add("structure", "session-is-file", lambda s: (shutil.rmtree(s), s.write_text("not a folder")))
    add("structure", "session-missing", lambda s: shutil.rmtree(s))
    add("structure", "one-dark-exposure", lambda s: [p.unlink() for p in (s / "dark").glob("dark_016*")])
    add("structure", "mixed-cameras", lambda s: shutil.copy(s / "linearity" / "lin_004.jpg", s / "dark" / "z.jpg"))
    partial = {"calibrate": OK, "*": ERROR}  # calibrate runs the stages present; dark needs dark/
    add("structure", "dark-only-bias", lambda s: shutil.rmtree(s / "dark"), partial)
    add("structure", "flat-only", lambda s: [shutil.rmtree(s / d) for d in ("bias", "dark", "linearity", "sweep")],
        partial)
    add("structure", "sweep-only", lambda s: [shutil.rmtree(s / d) for d in ("bias", "dark", "flat", "linearity")],
        partial)
    add("structure", "output-is-directory", lambda s: None, ERROR)
    # session.toml, the session defaults (docs/session-layout.md): strict, one line naming it
    toml = "session.toml"
    for name, text in (("syntax", b"f_number = = 4\n"), ("unknown-key", b"fnumber = 4\n"),
                       ("table", b"[camera]\nf_number = 4\n"), ("string", b'f_number = "4"\n'),
                       ("bool", b"f_number = true\n"), ("zero", b"f_number = 0\n"), ("negative", b"iso = -100\n"),
                       ("implausible", b"exposure_s = 1e9\n"), ("nan", b"f_number = nan\n"),
                       ("inf", b"iso = inf\n"), ("duplicate", b"f_number = 4\nf_number = 5.6\n"),
                       ("not-utf8", b"f_number = 4 # \xff\xfe\n"), ("huge", b"# x\n" * 40000)):
        add("session defaults", f"session-toml-{name}", lambda s, t=text: (s / toml).write_bytes(t))
    add("session defaults", "session-toml-is-directory", lambda s: (s / toml).mkdir())
    add("session defaults", "session-toml-to-dev-zero", lambda s: (s / toml).symlink_to("/dev/zero"))
    add("session defaults", "session-toml-dangling", lambda s: (s / toml).symlink_to(s / "nothere.toml"), EITHER)
    add("session defaults", "session-toml-empty", lambda s: (s / toml).write_bytes(b""), OK)
    add("session defaults", "session-toml-agrees", lambda s: (s / toml).write_text("f_number = 4.0\n"), OK)
    return cases


def water_exr_cases() -> list[Case]:
    """Damaged radiance EXRs for ``camcal water invert``: ``make(base, ws) -> (role, bytes | None | "dir")``.

    ``role`` is the image replaced (``sub``: --submerged, ``ref``: --reference); ``None`` removes the file,
    ``"dir"`` puts a folder in its place. Impossible pixels (NaN, negative, zero) are per-pixel reasons in the
    output's ``reason`` channel, not errors.
    """
    cases: list[Case] = []

    def add(category, name, make, expect=ERROR, env=None):
        cases.append(Case("water_exr", category, name, make, expect, env))

    def variant(ws: Path, **pixels) -> dict[str, bytes]:
        return water_exrs(ws / "variant", **pixels)

    small = np.full((16, 48), 0.5, np.float32)
    for role in ("sub", "ref"):
        src = f"water_{role}"
        for n in (0, 1, 4, 16, 100, 300, 1000):
            add("truncated", f"{role}-first{n}B", lambda b, ws, r=role, s=src, n=n: (r, truncate(b.files[s], n)))
        for frac in (0.25, 0.5, 0.9, 0.99):
            add("truncated", f"{role}-{int(frac * 100)}pct",
                lambda b, ws, r=role, s=src, f=frac: (r, truncate(b.files[s], int(f * len(b.files[s])))))
        add("truncated", f"{role}-minus1B", lambda b, ws, r=role, s=src: (r, b.files[s][:-1]))
        for seed in range(8):
            add("bit-flipped", f"{role}-flip{seed}",
                lambda b, ws, r=role, s=src, k=seed: (r, bitflip(b.files[s], 60 + k, 1 + k)), EITHER)
        for seed in range(4):
            add("bit-flipped", f"{role}-headflip{seed}", lambda b, ws, r=role, s=src, k=seed: (
                r, bitflip(b.files[s][:300], 160 + k, 2) + b.files[s][300:]), EITHER)
        for w, h in ((99999, 99999), (20000, 20000), (10**6, 10), (-5, -5), (0, 0)):
            add("huge dimensions", f"{role}-window{w}x{h}",
                lambda b, ws, r=role, s=src, w=w, h=h: (r, exr_window_patch(b.files[s], w, h)))
        add("huge dimensions", f"{role}-display-window", lambda b, ws, r=role, s=src: (
            r, exr_window_patch(b.files[s], 99999, 99999, b"displayWindow")), EITHER)  # display only: data intact
        add("pixel limit", f"{role}-over-limit", lambda b, ws, r=role, s=src: (r, b.files[s]),
            env={"CAMCAL_MAX_PIXELS": "1000"})
        for k in ("jpeg", "tiff", "dng", "profile"):
            add("wrong extension", f"{role}-{k}-as-exr", lambda b, ws, r=role, k=k: (r, b.files[k]))
        add("wrong extension", f"{role}-text-as-exr", lambda b, ws, r=role: (r, b"L663\n0.5\n"))
        add("zero bytes", f"{role}-empty", lambda b, ws, r=role: (r, b""))
        add("missing", f"{role}-no-file", lambda b, ws, r=role: (r, None))
        add("missing", f"{role}-is-folder", lambda b, ws, r=role: (r, "dir"))
        add("missing channel", f"{role}-other-channels", lambda b, ws, r=role, s=src: (
            r, b.files["exr"]))  # the dark model's maps: bias.R ... but no L663/R
        add("mismatched size", f"{role}-16-rows", lambda b, ws, r=role: (r, variant(ws, **{r: small})[r]))
        add("mismatched size", f"{role}-transposed", lambda b, ws, r=role: (
            r, variant(ws, **{r: np.full(WATER_SHAPE[::-1], 0.5, np.float32)})[r]))
        add("mismatched size", f"{role}-1px", lambda b, ws, r=role: (r, variant(ws, **{r: small[:1, :1]})[r]))

        def odd(value: float, rows: slice = slice(0, 4), role: str = role) -> np.ndarray:
            # the good pixels give a ratio below the refined model's clear water at 20 cm (0.43): valid pixels
            fill = 0.05 if role == "sub" else 0.5
            a = np.full(WATER_SHAPE, fill if value != fill else 0.25 * fill, np.float32)
            a[rows] = value
            return a
        for label, value in (("NaN", np.nan), ("inf", np.inf), ("negative", -1.0), ("zero", 0.0),
                             ("huge", 3e38), ("tiny", 1e-38)):
            add("per-pixel reason", f"{role}-{label}-pixels", lambda b, ws, r=role, v=value, o=odd: (
                r, variant(ws, **{r: o(v)})[r]), OK)
        # no valid pixel at all: an error counting the reasons (exit 2, naming the file), never an empty map
        add("per-pixel reason", f"{role}-all-NaN", lambda b, ws, r=role, o=odd: (
            r, variant(ws, **{r: o(np.nan, slice(None))})[r]), ERROR)
    return cases


CHL_CSV = ("# Bricaud-like power law, a_chl = A·C^(1-E) (C in mg m^-3)\nwavelength_nm,A_m2_per_mg,E\n"
           + "".join(f"{w},{0.02 + 0.01 * np.cos(w / 40.0):.5f},{0.7 + 0.1 * np.sin(w / 50.0):.4f}\n"
                     for w in range(380, 801, 10)))


def chl_csv_cases() -> list[Case]:
    """Damaged ``--chlorophyll-csv`` files: ``make(valid_text) -> bytes``, or None for a link to /dev/zero."""
    cases: list[Case] = []

    def add(category, name, make, expect=ERROR):
        cases.append(Case("chl_csv", category, name, make, expect))

    def set_cell(col: int, value: str, row: int = 3):  # line 3: the first data row after comment and header
        def make(text: str) -> bytes:
            lines = text.splitlines()
            cells = lines[row].split(",")
            cells[col] = value
            lines[row] = ",".join(cells)
            return ("\n".join(lines) + "\n").encode()
        return make

    for col, name in ((0, "wavelength"), (1, "A"), (2, "E")):
        for label, value in (("text", "abc"), ("NaN", "NaN"), ("inf", "inf"), ("overflow", "1e400"), ("empty", ""),
                             ("comma-decimal", "0;5"), ("negative", "-0.5")):
            add("cell", f"{name}-{label}", set_cell(col, value))
        add("cell", f"{name}-padded", lambda t, c=col: set_cell(c, f"  {t.splitlines()[3].split(',')[c]}  ")(t), OK)
    add("cell", "E-zero", set_cell(2, "0"))
    add("cell", "E-huge", set_cell(2, "50"))
    add("cell", "A-zero", set_cell(1, "0"), OK)
    add("cell", "A-zero-everywhere", lambda t: "\n".join(
        ",".join([ln.split(",")[0], "0", ln.split(",")[2]]) if i > 1 else ln
        for i, ln in enumerate(t.splitlines())).encode())
    add("cell", "wavelength-zero", set_cell(0, "0"))
    add("order", "wavelength-repeated", set_cell(0, "380", row=4))
    add("order", "wavelengths-decreasing", lambda t: "\n".join(t.splitlines()[:2] + t.splitlines()[:1:-1]).encode())
    add("structure", "one-row", lambda t: "\n".join(t.splitlines()[:3]).encode())
    add("structure", "header-only", lambda t: "\n".join(t.splitlines()[:2]).encode())
    add("structure", "empty-file", lambda t: b"")
    add("structure", "comments-only", lambda t: b"# nothing\n#\n")
    add("structure", "no-wavelength-column", lambda t: t.replace("wavelength_nm", "lambda").encode())
    add("structure", "no-absorption-column", lambda t: t.replace("A_m2_per_mg", "a_star").encode())
    add("structure", "duplicate-column", lambda t: t.replace(",E\n", ",A_m2_per_mg\n", 1).encode())
    add("structure", "extra-cell", lambda t: t.replace("\n400,", "\n400,9,", 1).encode())
    add("structure", "missing-cell", lambda t: "\n".join(ln.rsplit(",", 1)[0] if i == 4 else ln
                                                         for i, ln in enumerate(t.splitlines())).encode())
    add("structure", "tab-separated", lambda t: t.replace(",", "\t").encode())
    add("structure", "semicolon-separated", lambda t: t.replace(",", ";").encode())
    add("structure", "reordered-columns", lambda t: "\n".join(
        ",".join(ln.split(",")[::-1]) if not ln.startswith("#") else ln for ln in t.splitlines()).encode(), EITHER)
    add("structure", "epsilon-column", lambda t: (
        "wavelength_nm,epsilon_L_per_g_cm\n" + "".join(f"{w},{20 + 60 * np.exp(-((w - 665) / 12) ** 2):.3f}\n"
                                                        for w in range(380, 801, 5))).encode(), OK)
    add("structure", "narrow-range", lambda t: "\n".join(t.splitlines()[:2] + t.splitlines()[30:33]).encode(), EITHER)
    add("encoding", "bom", lambda t: b"\xef\xbb\xbf" + t.encode(), OK)
    add("encoding", "crlf", lambda t: t.replace("\n", "\r\n").encode(), OK)
    add("encoding", "utf16", lambda t: t.encode("utf-16"))
    add("encoding", "latin1", lambda t: ("# mesuré à 24 °C\n" + t).encode("latin-1"))
    add("encoding", "nul-bytes", lambda t: t.replace("\n", "\n\x00", 2).encode())
    add("encoding", "binary", lambda t: np.random.default_rng(11).bytes(400))
    add("resource", "over-16MiB", lambda t: t.encode() + b"#" * (16 * 1024 * 1024 + 10) + b"\n")
    add("resource", "dev-zero", lambda t: None)
    return cases


def argument_cases() -> list[Case]:
    """Bad command-line values: ``make(base, ws) -> (argv, outputs, the token the error line must name)``."""
    cases: list[Case] = []

    def add(category, name, make, expect=ERROR):
        cases.append(Case("arguments", category, name, make, expect))

    def invert(*extra, token=None):
        def make(b: Base, ws: Path):
            sub, ref = ws / "sub.exr", ws / "ref.exr"
            sub.write_bytes(b.files["water_sub"])
            ref.write_bytes(b.files["water_ref"])
            out = ws / "out" / "chl.exr"
            return (["water", "invert", "--submerged", sub, "--reference", ref, "-o", out, *extra],
                    [] if "--ratio" in extra else [out],  # numbers in, JSON out
                    Path(str(token if token is not None else extra[-1])))
        return make

    def forward(concentration="1e-7mol/L", depth="20cm", *extra, token=None):
        def make(b: Base, ws: Path):
            argv = ["water", "forward", "--concentration", concentration, "--depth", depth, *extra]
            return argv, [], Path(str(token))
        return make

    for d, exp in (("-1m", ERROR), ("0", ERROR), ("0m", ERROR), ("-0cm", ERROR), ("abc", ERROR),
                   ("5 furlongs", ERROR), ("10km", ERROR), ("nan", ERROR), ("inf", ERROR), ("1e400m", ERROR),
                   ("1e-320m", ERROR), ("1e300m", ERROR), ("0.2", ERROR), (" 20 cm ", OK)):
        add("depth", f"invert-depth-{d.strip()}", invert("--depth", d), exp)
        add("depth", f"forward-depth-{d.strip()}", forward("1e-7mol/L", d, token=d.strip()), exp)
    add("depth", "invert-depth-empty", invert("--depth", "", token="depth"))
    add("depth", "forward-depth-empty", forward("1e-7mol/L", "", token="--depth"))
    add("depth", "forward-depth-list-with-bad", forward("1e-7mol/L", "10cm,x", token="x"))
    for c, exp in (("abc", ERROR), ("-1mol/L", ERROR), ("nan", ERROR), ("inf", ERROR), ("1e400mol/L", ERROR),
                   ("1e300mol/L", ERROR), ("5 furlongs", ERROR), ("1e-7mol/L,,x", ERROR), ("0ug/L", OK),
                   ("89ug/L,1e-7mol/L", OK)):
        add("concentration", f"forward-c-{c}", forward(c, "20cm", token=c.split(",")[-1]), exp)
    add("concentration", "forward-c-empty", forward("", "20cm", token="--concentration"))
    for r, exp in (("abc", ERROR), ("1,2,3", ERROR), ("-1,0,4,4", ERROR), ("0,0,0,5", ERROR), ("1.5,0,4,4", ERROR),
                   ("0,0,1e9,1", ERROR), (",,,", ERROR), ("0,0,4,4,4", ERROR), ("100,100,4,4", ERROR),
                   ("48,0,4,4", ERROR), ("0,0,1000,1000", OK), ("10,10,4,4", OK)):
        add("roi", f"invert-roi-{r}", invert("--depth", "20cm", "--roi", r), exp)
    for label, extra, exp in (("sigma-negative", ("--relative-sigma", "-1"), ERROR),
                              ("sigma-nan", ("--relative-sigma", "nan"), ERROR),
                              ("channel-missing", ("--channel", "nope"), ERROR),
                              ("sigma-channel-missing", ("--sigma-channel", "nope"), ERROR),
                              ("albedo-negative", ("--albedo", "-1"), ERROR),
                              ("albedo-inf", ("--albedo", "inf"), ERROR),
                              ("epsilon-text", ("--epsilon", "abc"), ERROR),
                              ("epsilon-overflow", ("--epsilon", "1e400L/g/cm"), ERROR),
                              ("model-unknown", ("--water-model", "x"), ERROR),
                              ("model-first-order", ("--water-model", "seed-first-order"), ERROR),
                              ("refined-n-water-nan", ("--water-model", "refined", "--n-water", "nan"), ERROR),
                              ("refined-view-95", ("--water-model", "refined", "--view-deg", "95"), ERROR),
                              ("refined-water-abs-negative", ("--water-model", "refined", "--water-absorption", "-1"),
                               ERROR),
                              ("refined-background-inf", ("--water-model", "refined", "--background-absorption", "inf"),
                               ERROR),
                              ("refined-cutoff-120", ("--water-model", "refined", "--cutoff-deg", "120"), ERROR),
                              ("ratio-text", ("--ratio", "abc"), ERROR),
                              ("ratio-impossible", ("--ratio", "nan,inf,-1,0,2"), OK)):  # NaN with a reason
        token = {"channel-missing": "sub.exr", "sigma-channel-missing": "sub.exr", "albedo-negative": "albedo",
                 "albedo-inf": "albedo", "model-first-order": "seed", "refined-n-water-nan": "--n-water",
                 "refined-view-95": "--view-deg", "refined-water-abs-negative": "--water-absorption",
                 "refined-background-inf": "--background-absorption", "refined-cutoff-120": "cutoff",
                 "sigma-negative": "--relative-sigma", "sigma-nan": "--relative-sigma"}.get(label)
        add("option", f"invert-{label}", invert("--depth", "20cm", *extra, token=token), exp)
    add("profile", "invert-profile-missing", lambda b, ws: invert("--depth", "20cm", "--profile",
                                                                   ws / "nothere.camcal")(b, ws))
    add("profile", "invert-profile-is-folder", lambda b, ws: invert("--depth", "20cm", "--profile", ws)(b, ws))
    add("profile", "invert-profile-is-exr", lambda b, ws: invert("--depth", "20cm", "--profile",
                                                                  ws / "sub.exr")(b, ws))
    add("profile", "invert-band-channel-unknown", lambda b, ws: invert(
        "--depth", "20cm", "--profile", b.profile, "--band-channel", "Q", token="Q")(b, ws))
    add("profile", "invert-illuminant-unknown", lambda b, ws: invert(
        "--depth", "20cm", "--profile", b.profile, "--illuminant", "zzz")(b, ws))

    def output_is_folder(b: Base, ws: Path):
        argv, outs, _ = invert("--depth", "20cm")(b, ws)
        outs[0].mkdir(parents=True)
        return argv, [], outs[0]
    add("output", "invert-output-is-folder", output_is_folder)

    def simulate_out_is_file(b: Base, ws: Path):
        f = ws / "not-a-folder"
        f.write_text("x")
        return ["water", "simulate", "-o", f], [], f
    add("output", "water-simulate-out-is-file", simulate_out_is_file)

    def simulate_out_under_file(b: Base, ws: Path):
        f = ws / "a-file"
        f.write_text("x")
        return ["water", "simulate", "-o", f / "sub"], [], f
    add("output", "water-simulate-out-under-a-file", simulate_out_under_file)

    def demo_out_is_file(b: Base, ws: Path):
        f = ws / "not-a-folder"
        f.write_text("x")
        return ["demo", "-o", f], [], f
    add("output", "demo-out-is-file", demo_out_is_file)
    return cases


# --------------------------------------------------------------------------------------------------------------
# consumers: (command name, input kind) -> how to place the input and build argv + the outputs it may write
#
# To cover a new command, add one row (a builder returning argv, the outputs it may write, the bad input).
# Every command writes under ws/out: after an error nothing may be there (not even an empty report).


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst, symlinks=True)
    return dst


def place_image_in(folder: Path, stem_file: str, csv_name: str, bad: tuple[str, bytes]) -> Path:
    """Replace ``stem_file`` in ``folder`` by the bad bytes (with the case's suffix); fix the manifest's row."""
    suffix, data = bad
    (folder / stem_file).unlink()
    new = (folder / stem_file).with_suffix(suffix)
    new.write_bytes(data)
    csv = folder / csv_name
    csv.write_text(csv.read_text().replace(stem_file, new.name))
    return new


def _image_inspect(ws, b, make):
    suffix, data = make(b)
    p = ws / f"bad{suffix}"
    p.write_bytes(data)
    return ["inspect", "--json", p], [], p


def _image_dark(ws, b, make):
    d = _copy(b.session / "dark", ws / "dark")
    p = place_image_in(d, DARK0, "frames.csv", make(b))
    out = ws / "out" / "dark.json"
    return ["dark", d, "--bias", b.session / "bias", "-o", out, "-j", "1"], [out, out.with_name("dark.maps.exr")], p


def _image_sweep(ws, b, make):
    d = _copy(b.session / "sweep", ws / "sweep")
    p = place_image_in(d, SWEEP0, "sweep.csv", make(b))
    out = ws / "out" / "c.csv"
    return ["sweep", d, "-o", out, "--jobs", "1"], [out, out.with_name("c.meta.json"), out.with_name("c.png")], p


def _image_calibrate(ws, b, make):
    s = _copy(b.session, ws / "S")
    p = place_image_in(s / "dark", DARK0, "frames.csv", make(b))
    out = ws / "out" / "p.camcal"
    # --strict: all or nothing, one line naming the bad frame (without it the frame is left out and listed:
    # tests/calibrate/test_run.py)
    return ["calibrate", s, "-o", out, "-j", "1", "--strict"], [out], p


def _csv_into(folder_name: str, csv_name: str, argv: Callable[[Path, Path, Base], list], outs: list[str]):
    def build(ws, b, make):
        d = _copy(b.session / folder_name, ws / folder_name)
        csv = d / csv_name
        csv.write_bytes(make(csv.read_text()))
        out = ws / "out"
        return [str(a) for a in argv(d, out, b)], [out / o for o in outs], csv
    return build


def _stage_into(argv: Callable[[Path, Path, Base], list], outs: list[str]):
    def build(ws, b, make):
        m = ws / "models"
        m.mkdir()
        dj = m / "dark.json"
        shutil.copy(b.dark_json, dj)
        shutil.copy(b.dark_json.with_name("dark.maps.exr"), m / "dark.maps.exr")
        make(dj)
        out = ws / "out"
        return [str(a) for a in argv(dj, out, b)], [out / o for o in outs], dj
    return build


def _profile_show(ws, b, make):
    p = ws / "bad.camcal"
    p.write_bytes(make(b))
    return ["profile", "show", "--json", p], [], p


def _profile_diff(ws, b, make):
    p = ws / "bad.camcal"
    p.write_bytes(make(b))
    return ["profile", "diff", b.profile, p], [], p


def _image_apply(ws, b, make):
    """One bad photo: a listed failure (exit 1, one ``camcal: failed:`` line), no EXR for it."""
    suffix, data = make(b)
    p = ws / "photos" / f"bad{suffix}"
    p.parent.mkdir()
    p.write_bytes(data)
    out = ws / "out"
    return ["apply", b.profile, p, "-o", out, "-j", "1"], [out / f"{p.name}.exr"], p


def _image_apply_other_camera(ws, b, make):
    """A photo of another camera, applied with --allow-other-camera: it is done, or a listed failure (exit 1)."""
    argv, outputs, p = _image_apply(ws, b, make)
    return [*argv, "--allow-other-camera"], outputs, p


def _image_apply_batch(ws, b, make):
    """A bad photo between two good ones: the good EXRs are written whatever happens to the bad one."""
    argv, outputs, p = _image_apply(ws, b, make)
    for name in ("good_a.dng", "good_z.dng"):
        (p.parent / name).write_bytes(b.files["dng"])
    return [*argv[:2], p.parent / "good_a.dng", p, p.parent / "good_z.dng", *argv[3:]], outputs, p


def _kept_good_photos(ws: Path) -> list[Path]:
    return [ws / "out" / "good_a.dng.exr", ws / "out" / "good_z.dng.exr"]


def _profile_apply(ws, b, make):
    p = ws / "bad.camcal"
    p.write_bytes(make(b))
    photo = ws / "photos" / "a.dng"
    photo.parent.mkdir()
    photo.write_bytes(b.files["dng"])
    out = ws / "out"
    return ["apply", p, photo, "-o", out, "-j", "1"], [out / "a.dng.exr", out / "apply_report.csv"], p


def _profile_report(ws, b, make):
    p = ws / "bad.camcal"
    p.write_bytes(make(b))
    out = ws / "out" / "report.html"
    return ["report", p, "-o", out], [out], p


def _water_pair(ws: Path, b: Base, make) -> tuple[Path, Path, Path]:
    """The valid submerged/reference pair with one of them replaced by the bad input (named bad.exr)."""
    role, data = make(b, ws)
    paths = {}
    for r in ("sub", "ref"):
        paths[r] = ws / ("bad.exr" if r == role else f"{r}.exr")
        if r != role:
            paths[r].write_bytes(b.files[f"water_{r}"])
        elif data == "dir":
            paths[r].mkdir()
        elif data is not None:
            paths[r].write_bytes(data)
    return paths["sub"], paths["ref"], paths[role]


def _water_invert(ws, b, make):
    sub, ref, bad = _water_pair(ws, b, make)
    out = ws / "out" / "chl.exr"
    return ["water", "invert", "--submerged", sub, "--reference", ref, "--depth", "20cm", "-o", out], [out], bad


def _water_invert_band(ws, b, make):
    sub, ref, bad = _water_pair(ws, b, make)
    out = ws / "out" / "chl.exr"
    return ["water", "invert", "--submerged", sub, "--reference", ref, "--depth", "20cm", "--profile", b.profile,
            "-o", out], [out], bad


def _profile_water(ws, b, make):
    p = ws / "bad.camcal"
    p.write_bytes(make(b))
    sub, ref = ws / "sub.exr", ws / "ref.exr"
    sub.write_bytes(b.files["water_sub"])
    ref.write_bytes(b.files["water_ref"])
    out = ws / "out" / "chl.exr"
    return ["water", "invert", "--submerged", sub, "--reference", ref, "--depth", "20cm", "--profile", p,
            "-o", out], [out], p


def _chl_csv_water(ws, b, make):
    """``water invert --profile P --chlorophyll-csv BAD`` on the valid radiance pair."""
    csv = ws / "chl.csv"
    data = make(CHL_CSV)
    if data is None:
        csv.symlink_to("/dev/zero")
    else:
        csv.write_bytes(data)
    sub, ref = ws / "sub.exr", ws / "ref.exr"
    sub.write_bytes(b.files["water_sub"])
    ref.write_bytes(b.files["water_ref"])
    out = ws / "out" / "chl.exr"
    return ["water", "invert", "--submerged", sub, "--reference", ref, "--depth", "20cm", "--profile", b.profile,
            "--chlorophyll-csv", csv, "-o", out], [out], csv


def _image_mask(ws, b, make):
    """A damaged ``--mask`` image for a good photo: refused before any work (exit 2), no EXR, no CSV."""
    suffix, data = make(b)
    mask = ws / "masks" / f"mask{suffix}"
    mask.parent.mkdir()
    mask.write_bytes(data)
    photo = ws / "photos" / "a.dng"
    photo.parent.mkdir()
    photo.write_bytes(b.files["dng"])
    out = ws / "out"
    return (["apply", b.profile, photo, "-o", out, "-j", "1", "--mask", mask],
            [out / "a.dng.exr", out / "roi_stats.csv", out / "apply_report.csv"], mask)


def _arguments(ws, b, make):
    return make(b, ws)


def _session_calibrate(ws, b, make):
    s = _copy(b.session, ws / "S")
    make(s)
    out = ws / "out" / "p.camcal"
    return ["calibrate", s, "-o", out, "-j", "1", "--strict"], [out], s


def _session_dark(ws, b, make):
    s = _copy(b.session, ws / "S")
    make(s)
    out = ws / "out" / "dark.json"
    return ["dark", s / "dark", "-o", out, "-j", "1"], [out, out.with_name("dark.maps.exr")], s / "dark"


@dataclass(frozen=True)
class Consumer:
    name: str
    kind: str
    build: Callable  # (ws, base, case.make) -> (argv, outputs, the bad input's path)
    every: int = 1
    """Use every n-th case of the kind only (to keep the corpus fast where a command is slow)."""
    failure_code: int = 2
    """Exit code of a refused input: 2, or 1 for a batch that lists a bad photo as failed and goes on."""
    kept: Callable[[Path], list[Path]] | None = None
    """Outputs of the *good* inputs of the same run, which must exist whatever the bad input does."""


CONSUMERS: tuple[Consumer, ...] = (
    Consumer("inspect", "image", _image_inspect),
    Consumer("dark", "image", _image_dark, every=4),
    Consumer("sweep", "image", _image_sweep, every=12),
    Consumer("calibrate", "image", _image_calibrate, every=16),
    Consumer("dark", "frames_csv_dark", _csv_into(
        "dark", "frames.csv", lambda d, out, b: ["dark", d, "--bias", b.session / "bias", "-o", out / "dark.json",
                                                 "-j", "1"], ["dark.json", "dark.maps.exr"])),
    Consumer("linearity", "frames_csv_lin", _csv_into(
        "linearity", "frames.csv", lambda d, out, b: ["linearity", d, "-o", out / "r.json", "--no-plot"], ["r.json"])),
    Consumer("sweep", "sweep_csv", _csv_into(
        "sweep", "sweep.csv", lambda d, out, b: ["sweep", d, "-o", out / "c.csv", "--jobs", "1"],
        ["c.csv", "c.meta.json", "c.png"]), every=3),
    Consumer("flat", "stage", _stage_into(
        lambda dj, out, b: ["flat", b.session / "flat", "--dark", dj, "-o", out / "f.json"],
        ["f.json", "f.maps.exr", "f.falloff.png"]), every=10),
    Consumer("linearity", "stage", _stage_into(
        lambda dj, out, b: ["linearity", b.session / "linearity", "--dark", dj, "-o", out / "r.json", "--no-plot"],
        ["r.json"])),
    Consumer("sweep", "stage", _stage_into(
        lambda dj, out, b: ["sweep", b.session / "sweep", "--dark", dj, "-o", out / "c.csv", "--jobs", "1"],
        ["c.csv", "c.meta.json", "c.png"]), every=8),
    Consumer("profile-show", "profile", _profile_show),
    Consumer("profile-diff", "profile", _profile_diff, every=10),
    Consumer("apply", "image", _image_apply, failure_code=1),
    Consumer("apply-batch", "image", _image_apply_batch, every=4, failure_code=1, kept=_kept_good_photos),
    Consumer("apply-mask", "image", _image_mask, every=2),
    Consumer("apply", "profile", _profile_apply, every=2),
    Consumer("report", "profile", _profile_report, every=6),  # ~4 s per report that succeeds
    Consumer("water", "profile", _profile_water, every=3),
    Consumer("water", "water_exr", _water_invert),
    Consumer("water-band", "water_exr", _water_invert_band, every=3),
    Consumer("water-chl", "chl_csv", _chl_csv_water),
    Consumer("cli", "arguments", _arguments),
    Consumer("inspect", "real_image", _image_inspect),
    Consumer("dark", "real_image", _image_dark),
    Consumer("apply", "real_image", _image_apply_other_camera, failure_code=1),
    Consumer("calibrate", "session", _session_calibrate),
    Consumer("dark", "session", _session_dark, every=2),
)

CASES: dict[str, list[Case]] = {
    "image": image_cases(),
    "frames_csv_dark": csv_cases("frames_csv", FRAMES_DARK_HEADER, ("file",), {"exposure_s", "iso", "f_number"},
                                 {"temperature_C"}),
    "frames_csv_lin": csv_cases("frames_csv", FRAMES_LIN_HEADER, ("file",), {"exposure_s", "iso", "f_number"}, set()),
    "sweep_csv": csv_cases("sweep_csv", SWEEP_HEADER, ("file", "wavelength_nm", "radiance_W_m2_sr"),
                           {"exposure_s", "iso", "f_number", "wavelength_nm", "bandwidth_nm", "radiance_W_m2_sr"},
                           set()),
    "stage": stage_cases(),
    "profile": profile_cases(),
    "session": session_cases(),
    "water_exr": water_exr_cases(),
    "chl_csv": chl_csv_cases(),
    "arguments": argument_cases(),
    "real_image": real_image_cases(),
}


def corpus() -> list[tuple[Consumer, Case]]:
    runs = []
    for consumer in CONSUMERS:
        for i, case in enumerate(CASES[consumer.kind]):
            if consumer.kept and case.env:  # a resource limit applies to the good inputs as well
                continue
            if i % consumer.every == 0:
                runs.append((consumer, case))
    return runs


RUNS = corpus()
CORPUS_INPUTS = sum(len(v) for v in CASES.values())


def _partials(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.startswith(".") and ".part" in p.name]


@pytest.mark.parametrize("index", range(len(RUNS)),
                         ids=[f"{c.name}:{k.kind}:{k.category}:{k.name}" for c, k in RUNS])
def test_bad_input(index, base, tmp_path):
    consumer, case = RUNS[index]
    argv, outputs, bad_path = consumer.build(tmp_path, base, case.make)
    if case.name == "output-is-directory":
        outputs[0].mkdir(parents=True)
        outputs = []
    real = index % SUBPROCESS_EVERY == 0
    code, stdout, stderr = (run_subprocess if real else run_main)(argv, case.env)
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert "Traceback" not in stderr, stderr
    failure = consumer.failure_code
    assert code in (0, failure), (code, stderr)
    expected = case.expected(consumer.name)
    if expected != EITHER:
        assert code == (0 if expected == OK else failure), (expected, code, stderr)
    for kept in consumer.kept(tmp_path) if consumer.kept and not case.env else []:  # a limit applies to all
        assert kept.is_file() and kept.stat().st_size > 0, f"good input's output {kept} missing (exit {code})"
    if code == failure:
        assert len(lines) == 1, stderr
        assert lines[0].startswith("camcal: error: " if failure == 2 else "camcal: failed: "), lines[0]
        names = {bad_path.name, bad_path.parent.name} | {Path(a).name for a in argv if "/" in str(a)}
        if failure != 2:  # a listed failure names the bad photo itself
            names = {bad_path.name}
        assert any(n and n in lines[0] for n in names), (names, lines[0])
        for out in outputs:
            assert not out.exists(), f"partial output {out} after an error"
        if failure == 2 and (tmp_path / "out").is_dir():
            assert not [p for p in (tmp_path / "out").rglob("*") if p.is_file()], "output after an error"
    else:
        assert all(ln.startswith("camcal: warning: ") for ln in lines), stderr
        if outputs:
            assert outputs[0].is_file() and outputs[0].stat().st_size > 0
    assert not _partials(tmp_path), _partials(tmp_path)


def _valid_invert(b: Base, ws: Path):
    sub, ref, out = ws / "s.exr", ws / "r.exr", ws / "out" / "chl.exr"
    sub.write_bytes(b.files["water_sub"])
    ref.write_bytes(b.files["water_ref"])
    return ["water", "invert", "--submerged", sub, "--reference", ref, "--depth", "20cm", "-o", out], [out], sub


def test_corpus_size_and_controls(base, tmp_path):
    """At least 300 bad inputs; and every consumer succeeds on the valid input (so the corpus tests the damage)."""
    assert CORPUS_INPUTS >= 300, CORPUS_INPUTS
    assert len(RUNS) >= CORPUS_INPUTS, len(RUNS)
    assert (base.session / "dark" / "frames.csv").read_text().splitlines()[0] == FRAMES_DARK_HEADER
    assert (base.session / "linearity" / "frames.csv").read_text().splitlines()[0] == FRAMES_LIN_HEADER
    assert (base.session / "sweep" / "sweep.csv").read_text().splitlines()[0] == SWEEP_HEADER
    identity: dict[str, Callable] = {
        "image": lambda b: (".dng", b.files["dng"]), "frames_csv_dark": lambda t: t.encode(),
        "frames_csv_lin": lambda t: t.encode(), "sweep_csv": lambda t: t.encode(), "stage": lambda p: None,
        "profile": lambda b: b.files["profile"], "session": lambda s: None,
        "water_exr": lambda b, ws: ("sub", b.files["water_sub"]),
        "chl_csv": lambda t: t.encode(),
        "arguments": _valid_invert,
        "real_image": lambda b: (".dng", b.files["dng"]),
    }
    for i, consumer in enumerate(CONSUMERS):
        ws = tmp_path / f"c{i}"
        ws.mkdir()
        argv, outputs, _ = consumer.build(ws, base, identity[consumer.kind])
        code, _, stderr = run_main(argv)
        assert code == 0, (consumer.name, consumer.kind, stderr)
        for out in outputs + (consumer.kept(ws) if consumer.kept else []):
            assert out.is_file(), out


def corpus_counts() -> dict[str, Counter]:
    """Inputs per kind and category (for docs/reliability.md)."""
    return {kind: Counter(c.category for c in cases) for kind, cases in CASES.items()}


if __name__ == "__main__":  # print the counts table of docs/reliability.md
    counts = corpus_counts()
    print("| input kind | category | inputs |\n|---|---|---:|")
    for kind, cnt in counts.items():
        for cat, n in sorted(cnt.items()):
            print(f"| {kind} | {cat} | {n} |")
    print(f"\n{CORPUS_INPUTS} bad inputs, {len(RUNS)} command runs")


def test_pixel_limit_is_checked_before_decoding(base, tmp_path, monkeypatch):
    """RAW, JPEG, TIFF and EXR: the declared size is refused from the header, before pixels are allocated.

    A DNG declaring 60000x60000 (7.2 GB of uint16 if allocated) is refused by the limit, not by LibRaw or
    a MemoryError; an EXR above ``CAMCAL_MAX_PIXELS`` is refused by :func:`camcal.io.exr.read_exr`.
    """
    from camcal.errors import CamcalError
    from camcal.io.exr import read_exr, write_exr
    from camcal.io.read import load_frame

    big = tmp_path / "big.dng"
    big.write_bytes(tiff_patch(tiff_patch(tiff_patch(base.files["dng"], 256, 60000), 257, 60000), 278, 60000))
    with pytest.raises(CamcalError, match="above the limit"):
        load_frame(big)
    exr = write_exr(tmp_path / "m.exr", {"a": np.ones((30, 40))})
    monkeypatch.setenv("CAMCAL_MAX_PIXELS", str(30 * 40 - 1))
    with pytest.raises(CamcalError, match="above the limit"):
        read_exr(exr)
    for name, data in (("a.jpg", base.files["jpeg"]), ("a.tif", base.files["tiff"]), ("a.dng", base.files["dng"])):
        (tmp_path / name).write_bytes(data)
        with pytest.raises(CamcalError, match="above the limit"):
            load_frame(tmp_path / name)
    monkeypatch.setenv("CAMCAL_MAX_PIXELS", str(30 * 40))
    assert read_exr(exr)[0]["a"].shape == (30, 40)

"""Resource attacks: hostile files that are small on disk but declare huge sizes (issue 19).

Each case builds its hostile input in a temporary folder (a few MB at most; the 3 GiB bomb is 3 MB of
deflate), runs the real CLI in a subprocess and measures that process alone (``os.wait4``): the run
must end with exit code 2 (a listed failure, exit 1, for a photo of ``apply``) and one line naming the
file and the limit broken, within :data:`MAX_PEAK_MB` of peak resident memory and :data:`MAX_CPU_S`
of CPU time beyond the command's start-up (user + system: unlike wall time it does not depend on what else
the machine runs).
Before the fix, the bomb profile took 6.3 GB and 28-42 s, the deep profile ended in a RecursionError
(exit 3), and a 2 kB JPEG claiming 12000x12000 pixels took 0.93 GB.

The CLI runs under an address-space limit (:data:`ADDRESS_SPACE_LIMIT`), so that a regression
fails the test (MemoryError, exit 3) instead of exhausting the machine.

``test_apply_batch_memory_does_not_grow`` checks bounded memory over a long ``apply`` batch: the
peak RSS of one process applying a profile to 8 and to 64 synthetic 768x512 photos is the same within
:data:`BATCH_GROWTH_MB`, and below :data:`BATCH_PEAK_MB`.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from camcal.io.container import JSON_MEMBER, MAPS_MEMBER, content_hash
from camcal.io.limits import (
    MAX_CSV_COLUMNS,
    MAX_JSON_DEPTH,
    MAX_PROFILE_JSON_BYTES,
    MAX_STAGE_JSON_BYTES,
    MAX_TEXT_LINE_BYTES,
    MAX_TEXT_LINES,
    json_nesting_depth,
)
from tests.cli.test_bad_inputs import exr_window_patch, jpeg_sof_patch, tiff_patch
from tests.corpus import Base

MAX_PEAK_MB = 300.0
MAX_CPU_S = 2.0
"""CPU time (s) a refusal may take beyond the command's own start-up (:func:`startup_cpu_s`)."""
COMMAND_GROUPS = ("profile", "water", "synth", "curves")
ADDRESS_SPACE_LIMIT = 3 * 1024**3
MiB = 1 << 20
ROOT = Path(__file__).resolve().parents[2]


# --------------------------------------------------------------------------------------------------------------
# measuring one CLI run


@dataclass
class Run:
    code: int
    stdout: str
    stderr: str
    peak_mb: float
    cpu_s: float
    wall_s: float

    @property
    def lines(self) -> list[str]:
        return [ln for ln in self.stderr.splitlines() if ln.strip()]


#: Runs in a fresh small interpreter: forks the CLI, waits for it and writes its rusage. A child forked
#: straight from pytest would report pytest's own resident memory (Linux carries the high-water mark of
#: the address space replaced by exec into ru_maxrss): 160 MB before camcal reads a byte.
_TRAMPOLINE = """
import json, os, resource, sys
report, limit, argv = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
pid = os.fork()
if pid == 0:
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    if argv[0] == "--import":  # the floor of a command that imports these libraries where it uses them
        libraries, argv = argv[1], argv[2:]
        code = (f"import runpy, sys; import {libraries}; sys.argv[0] = 'camcal'; "
                "runpy.run_module('camcal', run_name='__main__')")
        os.execv(sys.executable, [sys.executable, "-c", code, *argv])
    os.execv(sys.executable, [sys.executable, "-m", "camcal", *argv])
_, status, ru = os.wait4(pid, 0)
with open(report, "w") as fh:
    json.dump({"code": os.waitstatus_to_exitcode(status), "maxrss_kb": ru.ru_maxrss,
               "cpu_s": ru.ru_utime + ru.ru_stime}, fh)
"""


def run_measured(argv: list, env: dict[str, str] | None = None, timeout_s: float = 120.0) -> Run:
    """Run ``python -m camcal argv`` and measure that process alone: peak RSS (MB) and CPU time (s), from
    ``wait4`` in a small trampoline process (see :data:`_TRAMPOLINE`), under :data:`ADDRESS_SPACE_LIMIT`."""
    with tempfile.TemporaryDirectory(prefix="camcal-rl-") as tdir:
        report = Path(tdir) / "rusage.json"
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", _TRAMPOLINE, report, str(ADDRESS_SPACE_LIMIT),
                                 *map(str, argv)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
                                env={**os.environ, **(env or {})}, start_new_session=True)
        try:
            stdout, stderr = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            raise AssertionError(f"camcal {argv[:2]} ran longer than {timeout_s} s") from None
        wall = time.perf_counter() - t0
        usage = json.loads(report.read_text())
    return Run(usage["code"], stdout.decode(errors="replace"), stderr.decode(errors="replace"),
               usage["maxrss_kb"] / 1024.0, usage["cpu_s"], wall)


_STARTUP: dict[tuple[str, ...], float] = {}

#: Libraries a command imports where it uses them (tests/test_structure.py's IMPORTED_WHERE_USED) before it reads
#: its first input, so part of its start-up: ``apply`` chooses its L(663) estimator from the profile's c(λ) with
#: colour-science (which loads matplotlib) before it opens a photo.
LIBRARIES_BEFORE_INPUT = {"apply": ("colour",)}


def startup_cpu_s(argv: list) -> float:
    """CPU time (s) of ``camcal <command> --help``: the interpreter, the command's modules and the libraries
    they import, before a byte of input is read. The bound under test is the work on the hostile input, so
    it is measured above this floor (the libraries' import cost is not camcal's parsing: scipy, colour-science
    and pvlib are imported at the top of the modules that use them). Measured once per command."""
    n = 2 if str(argv[0]) in COMMAND_GROUPS else 1
    key = tuple(str(a) for a in argv[:n])
    if key not in _STARTUP:
        libraries = LIBRARIES_BEFORE_INPUT.get(key[0])
        run = run_measured([*(("--import", ", ".join(libraries)) if libraries else ()), *key, "--help"])
        assert run.code == 0, run.stderr
        _STARTUP[key] = run.cpu_s
    return _STARTUP[key]


# --------------------------------------------------------------------------------------------------------------
# building hostile ZIP members without ever holding their expanded size


def deflated_zeros(n_mib: int) -> tuple[bytes, int, int]:
    """Raw deflate of ``n_mib`` MiB of zeros, its CRC-32 and size, built in ~n_mib KB of memory.

    A full flush resets the compressor, so the deflate of every further MiB of zeros is the same
    1037 bytes: the 3 GiB bomb is 3.2 MB, made in half a second.
    """
    comp = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = comp.compress(bytes(MiB)) + comp.flush(zlib.Z_FULL_FLUSH)
    crc, zeros = 0, bytes(MiB)
    for _ in range(n_mib):
        crc = zlib.crc32(zeros, crc)
    return block * n_mib + comp.flush(zlib.Z_FINISH), crc, n_mib * MiB


def deflated(data: bytes) -> bytes:
    comp = zlib.compressobj(9, zlib.DEFLATED, -15)
    return comp.compress(data) + comp.flush()


def raw_zip(members: list[tuple[str, int, bytes, int, int]], declared_entries: int | None = None) -> bytes:
    """A ZIP from already-compressed members ``(name, method, data, crc32, declared size)``.

    ``declared_entries`` overrides the entry count of the end record (a lie about the directory).
    """
    out, central = bytearray(), bytearray()
    for name, method, data, crc, size in members:
        nb = name.encode()
        offset = len(out)
        out += struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, method, 0, 0x21, crc, len(data), size, len(nb), 0)
        out += nb + data
        central += struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, method, 0, 0x21, crc, len(data), size,
                               len(nb), 0, 0, 0, 0, 0, offset) + nb
    n = len(members) if declared_entries is None else declared_entries
    cd_offset = len(out)
    out += central + struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, n, n, len(central), cd_offset, 0)
    return bytes(out)


def json_member(doc: dict | bytes, stored: bool = False) -> tuple[str, int, bytes, int, int]:
    raw = doc if isinstance(doc, bytes) else json.dumps(doc).encode()
    return JSON_MEMBER, 0 if stored else 8, raw if stored else deflated(raw), zlib.crc32(raw), len(raw)


def profile_parts(b: Base) -> tuple[dict, bytes]:
    with zipfile.ZipFile(io.BytesIO(b.files["profile"])) as zf:
        return json.loads(zf.read(JSON_MEMBER)), zf.read(MAPS_MEMBER)


def rehashed(doc: dict) -> dict:
    doc = json.loads(json.dumps(doc))
    doc["integrity"]["content_sha256"] = content_hash(doc)
    return doc


def deep(n: int, opener: bytes = b"[", closer: bytes = b"]", leaf: bytes = b"0") -> bytes:
    return opener * n + leaf + closer * n


# --------------------------------------------------------------------------------------------------------------
# the cases: each builds a hostile input in ws and returns (argv, the file the error must name, env)


@dataclass(frozen=True)
class Attack:
    family: str
    name: str
    build: Callable[[Path, Base], tuple[list, Path]]
    fragment: str  # a piece of the limit's message
    code: int = 2
    env: dict[str, str] | None = None


def _profile_file(ws: Path, data: bytes, name: str = "hostile.camcal") -> Path:
    p = ws / name
    p.write_bytes(data)
    return p


def _show(data_fn: Callable[[Base], bytes]) -> Callable[[Path, Base], tuple[list, Path]]:
    def build(ws: Path, b: Base):
        p = _profile_file(ws, data_fn(b))
        return ["profile", "show", "--json", p], p
    return build


def _apply_with(data_fn: Callable[[Base], bytes]) -> Callable[[Path, Base], tuple[list, Path]]:
    def build(ws: Path, b: Base):
        p = _profile_file(ws, data_fn(b))
        photo = ws / "photos" / "a.dng"
        photo.parent.mkdir()
        photo.write_bytes(b.files["dng"])
        return ["apply", p, photo, "-o", ws / "out", "-j", "1"], p
    return build


def _bomb_3gib(b: Base) -> bytes:
    doc, _ = profile_parts(b)
    data, crc, size = deflated_zeros(3072)
    return raw_zip([json_member(doc), (MAPS_MEMBER, 8, data, crc, size)])


def _bomb_lying_size(b: Base) -> bytes:
    """Declares the real maps' size but its deflate stream expands to 1 GiB: zipfile stops at the declared
    size, the CRC (of the real maps) then fails."""
    doc, maps = profile_parts(b)
    data, _, _ = deflated_zeros(1024)
    return raw_zip([json_member(doc), (MAPS_MEMBER, 8, data, zlib.crc32(maps), len(maps))])


def _bomb_matching_size(b: Base) -> bytes:
    """A bomb that stays under the sensor bound (1 MiB of zeros, hash re-signed): streamed, then refused by the
    EXR reader (not an EXR) without ever holding the member in memory."""
    doc, _ = profile_parts(b)
    data, crc, size = deflated_zeros(1)
    import hashlib

    doc["integrity"]["maps_sha256"] = hashlib.sha256(bytes(size)).hexdigest()
    return raw_zip([json_member(rehashed(doc)), (MAPS_MEMBER, 8, data, crc, size)])


def _json_bomb(b: Base) -> bytes:
    spaces = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = spaces.compress(b" " * MiB) + spaces.flush(zlib.Z_FULL_FLUSH)
    n = 1024
    crc, chunk = 0, b" " * MiB
    for _ in range(n):
        crc = zlib.crc32(chunk, crc)
    return raw_zip([(JSON_MEMBER, 8, block * n + spaces.flush(zlib.Z_FINISH), crc, n * MiB)])


def _json_wide(b: Base) -> bytes:
    """Under every size limit: a stored profile.json of 7 MiB holding one array of 3.7 million zeros."""
    n = (7 * MiB) // 2
    return raw_zip([json_member(b"[" + b"0," * (n - 1) + b"0]", stored=True)])


def _many_members(n: int, lie: bool = False) -> Callable[[Base], bytes]:
    def make(b: Base) -> bytes:
        members = [json_member(profile_parts(b)[0])] + [(f"m{i:06d}", 0, b"", 0, 0) for i in range(n)]
        return raw_zip(members, declared_entries=2 if lie else None)
    return make


def _deep_profile_json(opener: bytes, closer: bytes, leaf: bytes = b"0", inside: bool = False):
    def make(b: Base) -> bytes:
        if not inside:
            return raw_zip([json_member(deep(200_000, opener, closer, leaf), stored=True)])
        doc, maps = profile_parts(b)
        doc["dark"]["summary"]["note"] = "@@DEEP@@"
        text = json.dumps(rehashed(doc)).encode().replace(b'"@@DEEP@@"', deep(200_000, opener, closer, leaf))
        return raw_zip([json_member(text, stored=True), (MAPS_MEMBER, 0, maps, zlib.crc32(maps), len(maps))])
    return make


def _image(suffix: str, make: Callable[[Base], bytes], command: str = "inspect"):
    def build(ws: Path, b: Base):
        p = ws / f"hostile{suffix}"
        p.write_bytes(make(b))
        if command == "apply":
            return ["apply", b.profile, p, "-o", ws / "out", "-j", "1"], p
        return ["inspect", "--json", p], p
    return build


def _dng_dims(w: int, h: int) -> Callable[[Base], bytes]:
    return lambda b: tiff_patch(tiff_patch(tiff_patch(b.files["dng"], 256, w), 257, h), 278, h)


def _exr_water(make: Callable[[Base, Path], bytes]):
    def build(ws: Path, b: Base):
        sub, ref = ws / "hostile.exr", ws / "ref.exr"
        sub.write_bytes(make(b, ws))
        ref.write_bytes(b.files["water_ref"])
        return ["water", "invert", "--submerged", sub, "--reference", ref, "--depth", "20cm", "-o",
                ws / "out" / "chl.exr"], sub
    return build


def _exr_channels(n: int, shape: tuple[int, int] = (4, 4)):
    def make(b: Base, ws: Path) -> bytes:
        from camcal.io.exr import write_exr

        chans = {f"c{i:03d}": np.zeros(shape, np.float32) for i in range(n)}
        return write_exr(ws / "many.exr", chans).read_bytes()
    return make


def _exr_uncompressed(xmax: int, ymax: int):
    def make(b: Base, ws: Path) -> bytes:
        from camcal.io.exr import write_exr

        img = np.full((32, 48), 0.5, np.float32)
        data = write_exr(ws / "none.exr", {"L663": img, "R": img}, compression="none").read_bytes()
        return exr_window_patch(data, xmax, ymax)
    return make


def _frames_csv(text: Callable[[str], bytes]):
    def build(ws: Path, b: Base):
        d = ws / "dark"
        shutil.copytree(b.session / "dark", d)
        csv = d / "frames.csv"
        csv.write_bytes(text(csv.read_text()))
        return ["dark", d, "--bias", b.session / "bias", "-o", ws / "out" / "dark.json", "-j", "1"], csv
    return build


def _dense_cells(t: str) -> bytes:
    """Under the size, line and column limits: 4 MiB of two-character cells, 64 per line."""
    header = "file," + ",".join(f"c{i}" for i in range(MAX_CSV_COLUMNS - 1)) + "\n"
    row = ",".join(["ab"] * MAX_CSV_COLUMNS) + "\n"
    return (header + row * ((4 * MiB - len(header) - 10) // len(row))).encode()


def _chl_csv(text: bytes):
    def build(ws: Path, b: Base):
        csv = ws / "chl.csv"
        csv.write_bytes(text)
        sub, ref = ws / "sub.exr", ws / "ref.exr"
        sub.write_bytes(b.files["water_sub"])
        ref.write_bytes(b.files["water_ref"])
        return ["water", "invert", "--submerged", sub, "--reference", ref, "--depth", "20cm", "--profile", b.profile,
                "--chlorophyll-csv", csv, "-o", ws / "out" / "chl.exr"], csv
    return build


def _stage_json(edit: Callable[[Path], None]):
    def build(ws: Path, b: Base):
        m = ws / "models"
        m.mkdir()
        dj = m / "dark.json"
        shutil.copy(b.dark_json, dj)
        shutil.copy(b.dark_json.with_name("dark.maps.exr"), m / "dark.maps.exr")
        edit(dj)
        return ["linearity", b.session / "linearity", "--dark", dj, "-o", ws / "out" / "r.json", "--no-plot"], dj
    return build


def _sparse(size: int) -> Callable[[Path], None]:
    def edit(p: Path) -> None:
        with open(p, "r+b") as fh:
            fh.truncate(size)  # a hole: nothing on disk
    return edit


ATTACKS: tuple[Attack, ...] = (
    # decompression bombs in profile members
    Attack("zip bomb", "maps-3GiB-of-zeros-show", _show(_bomb_3gib), "maps.exr declares 3.0 GiB"),
    Attack("zip bomb", "maps-3GiB-of-zeros-apply", _apply_with(_bomb_3gib), "maps.exr declares 3.0 GiB"),
    Attack("zip bomb", "maps-1GiB-declared-small", _show(_bomb_lying_size), "corrupted"),
    Attack("zip bomb", "maps-1MiB-zeros-rehashed", _show(_bomb_matching_size), "maps.exr"),
    Attack("zip bomb", "json-1GiB-of-spaces", _show(_json_bomb), "profile.json declares 1.0 GiB"),
    Attack("zip bomb", "json-7MiB-of-zeros-stored", _show(_json_wide), "no integrity record"),
    # many tiny members, or a directory that lies about their number
    Attack("many members", "60000-empty-members", _show(_many_members(60_000)), "declares 60001 members"),
    Attack("many members", "directory-of-20000-declared-2", _show(_many_members(20_000, lie=True)),
           "ZIP directory declares"),
    # deep nesting
    Attack("deep nesting", "profile-json-200000-arrays", _show(_deep_profile_json(b"[", b"]")),
           "nested 200000 levels deep"),
    Attack("deep nesting", "profile-json-200000-objects", _show(_deep_profile_json(b'{"a":', b"}")),
           "nested 200000 levels deep"),
    Attack("deep nesting", "profile-json-deep-inside-valid-doc", _show(_deep_profile_json(b"[", b"]", inside=True)),
           "levels deep"),
    Attack("deep nesting", "profile-json-deep-apply", _apply_with(_deep_profile_json(b"[", b"]")), "levels deep"),
    Attack("deep nesting", "stage-json-200000-arrays", _stage_json(
        lambda p: p.write_bytes(p.read_bytes().replace(b'"kind"', deep(200_000) + b', "kind"', 1))),
        "levels deep"),
    Attack("oversized file", "stage-json-sparse-20MiB", _stage_json(_sparse(MAX_STAGE_JSON_BYTES + 4 * MiB)),
           "larger than 16 MiB"),
    # oversized declared dimensions
    Attack("declared dimensions", "jpeg-12000x12000-in-2kB", _image(".jpg", lambda b: jpeg_sof_patch(
        b.files["jpeg"], 12000, 12000)), "more than 4096:1"),
    Attack("declared dimensions", "jpeg-12000x12000-apply", _image(".jpg", lambda b: jpeg_sof_patch(
        b.files["jpeg"], 12000, 12000), "apply"), "more than 4096:1", code=1),
    Attack("declared dimensions", "tiff-12000x12000-in-25kB", _image(".tif", lambda b: tiff_patch(tiff_patch(
        b.files["tiff"], 256, 12000), 257, 12000)), "more than 4096:1"),
    Attack("declared dimensions", "dng-12000x12000-in-13kB", _image(".dng", _dng_dims(12000, 12000)),
           "more than 4096:1"),
    Attack("declared dimensions", "dng-60000x60000", _image(".dng", _dng_dims(60000, 60000)), "above the limit"),
    Attack("declared dimensions", "exr-3000x3000-window-in-5kB", _exr_water(
        lambda b, ws: exr_window_patch(b.files["water_sub"], 2999, 2999)), "more than 4096:1"),
    Attack("declared dimensions", "exr-15000x15000-window", _exr_water(
        lambda b, ws: exr_window_patch(b.files["water_sub"], 14999, 14999)), "hostile.exr"),
    Attack("declared dimensions", "exr-uncompressed-1000x1000-in-7kB", _exr_water(_exr_uncompressed(999, 999)),
           "truncated"),
    Attack("declared dimensions", "exr-300-channels", _exr_water(_exr_channels(300)), "300 channels"),
    Attack("declared dimensions", "exr-samples-over-limit", _exr_water(_exr_channels(64, (100, 100))),
           "samples", env={"CAMCAL_MAX_PIXELS": "50000"}),
    # huge CSV lines, many lines, many columns
    Attack("huge csv", "frames-csv-one-3MiB-line", _frames_csv(lambda t: t.encode() + b"x" * (3 * MiB) + b"\n"),
           "has a line of 3.0 MiB"),
    Attack("huge csv", "frames-csv-3MiB-of-cells-one-line", _frames_csv(
        lambda t: t.encode() + b"a," * (3 * MiB // 2) + b"\n"), "has a line of"),
    Attack("huge csv", "frames-csv-2M-lines", _frames_csv(lambda t: t.encode() + b"\n" * (2 * MiB)),
           f"above the limit of {MAX_TEXT_LINES}"),
    Attack("huge csv", "frames-csv-1000-columns", _frames_csv(
        lambda t: t.replace("\n", "," + ",".join(f"x{i}" for i in range(1000)) + "\n", 1).encode()),
        "1005 columns"),
    Attack("huge csv", "frames-csv-4MiB-of-short-cells", _frames_csv(_dense_cells), "frames.csv"),
    Attack("huge csv", "chlorophyll-csv-one-1MiB-line", _chl_csv(b"wavelength_nm,A_m2_per_mg\n" + b"9" * MiB + b"\n"),
           "has a line of 1.0 MiB"),
)


@pytest.fixture(scope="module")
def base(corpus_base: Base) -> Base:
    return corpus_base


@pytest.mark.parametrize("attack", ATTACKS, ids=[f"{a.family}:{a.name}" for a in ATTACKS])
def test_resource_attack(attack: Attack, base: Base, tmp_path: Path):
    argv, hostile = attack.build(tmp_path, base)
    on_disk = sum(p.stat().st_blocks * 512 for p in tmp_path.rglob("*") if p.is_file())
    assert on_disk < 32 * MiB, f"the hostile input should be small on disk ({on_disk} B)"
    run = run_measured(argv, attack.env)
    assert "Traceback" not in run.stderr, run.stderr
    assert run.code == attack.code, (run.code, run.stderr)
    assert len(run.lines) == 1, run.stderr
    assert run.lines[0].startswith("camcal: error: " if attack.code == 2 else "camcal: failed: "), run.lines[0]
    assert hostile.name in run.lines[0] and attack.fragment in run.lines[0], run.lines[0]
    assert run.peak_mb < MAX_PEAK_MB, f"peak RSS {run.peak_mb:.0f} MB"
    floor = startup_cpu_s(argv)
    assert run.cpu_s - floor < MAX_CPU_S, f"CPU {run.cpu_s:.2f} s, of which start-up {floor:.2f} s"
    if attack.code == 2:
        out = tmp_path / "out"
        assert not out.exists() or not [p for p in out.rglob("*") if p.is_file()]


def test_the_issue_cases_one_line_each(base: Base, tmp_path: Path):
    """The two cases of the issue, as a user meets them: ``camcal profile show`` on the 3 MB bomb profile and
    on the profile nested 200 000 levels deep: refused in one line, exit 2, < 2 s CPU beyond the command's
    start-up and < 300 MB."""
    bomb = _profile_file(tmp_path, _bomb_3gib(base), "bomb.camcal")
    assert bomb.stat().st_size < 4 * MiB
    nested = _profile_file(tmp_path, _deep_profile_json(b"[", b"]")(base), "nested.camcal")
    for path, fragment in ((bomb, "3.0 GiB"), (nested, "200000 levels deep")):
        run = run_measured(["profile", "show", path])
        assert run.code == 2 and len(run.lines) == 1 and path.name in run.lines[0] and fragment in run.lines[0], \
            run.stderr
        floor = startup_cpu_s(["profile", "show"])
        assert run.peak_mb < 300 and run.cpu_s - floor < MAX_CPU_S, (run.peak_mb, run.cpu_s, floor)


def test_valid_inputs_pass_the_limits(base: Base, tmp_path: Path):
    """The limits refuse nothing camcal writes: the corpus base profile loads; its depth is far below the limit."""
    doc, _ = profile_parts(base)
    assert json_nesting_depth(json.dumps(doc).encode()) < MAX_JSON_DEPTH // 4
    run = run_measured(["profile", "show", "--json", base.profile])
    assert run.code == 0, run.stderr
    assert len(json.dumps(doc)) < MAX_PROFILE_JSON_BYTES // 50
    lines = (base.session / "sweep" / "sweep.csv").read_bytes().splitlines()
    assert max(map(len, lines)) < MAX_TEXT_LINE_BYTES


@pytest.mark.parametrize("text,depth", [(b"[]", 1), (b"{}", 1), (b'{"a": [1, {"b": []}]}', 4), (b"0", 0),
                                        (b'["[[[[", "\\"[[["]', 1), (b'{"k\\\\": [[]]}', 3), (b"[[[", 3),
                                        (b'"unterminated [[[[', 4)])
def test_json_nesting_depth(text, depth):
    """Brackets inside strings (with escaped quotes and backslashes) do not count; malformed text still gives a
    number (the parser refuses it afterwards)."""
    assert json_nesting_depth(text) == depth
    assert json_nesting_depth(text, block=2) == depth  # the same across block boundaries


# --------------------------------------------------------------------------------------------------------------
# bounded memory over a long apply batch

BATCH_PEAK_MB = 300.0
BATCH_GROWTH_MB = 20.0
BATCH_SENSOR = (768, 512)


@pytest.fixture(scope="module")
def batch_session(tmp_path_factory) -> tuple[Path, Path]:
    """A 768x512 camera calibrated from a minimal session (bias, dark, flat, a 4-wavelength sweep; ~3 s):
    its profile and one of its dark frames as the photo."""
    from camcal.cli import main
    from camcal.synth.camera import SensorParams, SyntheticCamera
    from camcal.synth.session import SessionPlan, write_session

    root = tmp_path_factory.mktemp("batch")
    cam = SyntheticCamera(SensorParams(width=BATCH_SENSOR[0], height=BATCH_SENSOR[1]))
    plan = SessionPlan(stages=("bias", "dark", "flat", "sweep"), n_bias=2, n_dark=2, dark_exposures_s=(2.0, 16.0),
                       n_flat=2, sweep_step_nm=100.0, n_sweep=1, sweep_jpeg=False)
    session = write_session(root / "S", cam, plan)
    profile = root / "cam.camcal"
    assert main(["calibrate", str(session), "-o", str(profile), "-j", "1"]) == 0
    return profile, sorted((session / "dark").glob("*.dng"))[0]


def test_apply_batch_memory_does_not_grow(batch_session, tmp_path: Path):
    """One ``camcal apply`` process over 8 and over 64 synthetic 768x512 photos (one worker, in-process): the
    peak RSS of the longer batch is within :data:`BATCH_GROWTH_MB` of the shorter one and below
    :data:`BATCH_PEAK_MB`.

    Measured: 161 MB for both. Keeping every decoded frame alive (0.79 MB each: a leak of the smallest
    per-photo object) raises the 64-photo peak to 208 MB (+43 MB), so any per-photo leak from 0.36 MB up fails.
    """
    profile, photo = batch_session
    peaks = {}
    for n in (8, 64):
        photos = tmp_path / f"photos{n}"
        photos.mkdir()
        for i in range(n):
            (photos / f"p{i:03d}.dng").write_bytes(photo.read_bytes())
        run = run_measured(["apply", profile, photos, "-o", tmp_path / f"out{n}", "-j", "1"], timeout_s=600)
        assert run.code == 0, run.stderr
        assert len(list((tmp_path / f"out{n}").glob("*.exr"))) == n
        peaks[n] = run.peak_mb
    assert peaks[64] < BATCH_PEAK_MB, peaks
    assert peaks[64] - peaks[8] < BATCH_GROWTH_MB, peaks


@pytest.mark.parametrize("name,channels,fmt,attrs", [
    ("constant.jpg", 3, "uint8", {"quality": 95}), ("constant.png", 1, "uint8", {}),
    ("constant16.tif", 3, "uint16", {"compression": "zip"}),
    ("bilevel.tif", 1, "uint8", {"oiio:BitsPerSample": 1, "compression": "zip"})])
def test_constant_images_pass_the_expansion_limit(tmp_path, name, channels, fmt, attrs):
    """The most compressible real images (one constant value: a mask, a blank frame) expand about 190:1 (JPEG)
    to 1000:1 (deflate), well under :data:`camcal.io.limits.MAX_IMAGE_EXPANSION`."""
    import OpenImageIO as oiio

    from camcal.io.limits import MAX_IMAGE_EXPANSION, declared_image_bytes
    from camcal.io.read import open_image

    path = tmp_path / name
    spec = oiio.ImageSpec(1000, 750, channels, getattr(oiio, fmt.upper()))
    for k, v in attrs.items():
        spec.attribute(k, v)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), oiio.geterror()
    assert out.write_image(np.full((750, 1000, channels), 255, getattr(np, fmt)))
    out.close()
    with open_image(path) as (_, opened):
        ratio = declared_image_bytes(opened) / path.stat().st_size
    assert 50 < ratio < MAX_IMAGE_EXPANSION / 3, ratio

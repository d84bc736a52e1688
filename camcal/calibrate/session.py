"""The session index: a calibration session read once.

:func:`index_session` scans a session folder (the stage folders present), reads every manifest once
(``frames.csv`` of each stage, ``sweep/sweep.csv``) and the session defaults (``session.toml``), resolves
what each frame's exposure is known to be without decoding it, and checks what can be checked without
pixels (manifest rows naming files that are not there, missing exposure times of dark frames, dark and
bias frames at different ISO settings). The stages then receive :class:`StageFrames` (paths and their
manifest rows) from it instead of folder paths, so no stage lists a folder or reads a manifest again.

Precedence of an exposure value (as :func:`camcal.io.read.load_frame` applies it at decode time): the
manifest row (``frames.csv``, or ``sweep.csv`` for the sweep) > the file's tag > ``session.toml`` >
LibRaw's reading of a maker header. The last needs the file opened by LibRaw, so the index leaves such a
value unknown (None, no source); decoding fills it.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from camcal.errors import CamcalError, MissingMetadataError
from camcal.io.folders import folder_files, folder_manifest, list_frames
from camcal.io.kinds import IMAGE_EXTENSIONS, is_raw_path
from camcal.io.manifest import FRAMES_CSV, exposure_overrides, read_manifest, session_defaults_for
from camcal.io.read import exposure_from_exif
from camcal.models.flat import same_f_number

STAGES = ("bias", "dark", "flat", "linearity", "sweep")
"""Stage folders of a session, in calibration order."""

SWEEP_CSV = "sweep.csv"
SWEEP_REQUIRED = ("file", "wavelength_nm", "radiance_W_m2_sr")

Row = Mapping[str, "float | str | None"]

APERTURE_FOLDER = re.compile(r"^[fF]/?(\d+(?:\.\d+)?)$")
"""A sub-folder of ``flat/`` holding the flats of one f-number: ``f2.8``, ``f8`` (also ``F8``)."""



@dataclass(frozen=True)
class FrameRef:
    """One frame of a stage: its path, its manifest row and what is known of its exposure before decoding.

    Attributes
    ----------
    path : the image file.
    overrides : exposure fields of its manifest row (:func:`camcal.io.manifest.exposure_overrides`), given to
        :func:`camcal.io.read.load_frame` when it is decoded.
    exposure_s : exposure time, s; None when only decoding can tell (LibRaw) or nothing holds it.
    exposure_source : where ``exposure_s`` came from: the manifest's name, ``tag`` or ``session``; None when unknown.
    iso, f_number : ISO speed and f-number (same precedence), None when unknown before decoding.
    iso_source, f_number_source : where they came from, as ``exposure_source``.
    focal_length_mm, focal_length_source : the lens's focal length, mm, and where it came from (same precedence).
    """

    path: Path
    overrides: Mapping[str, float | None] = field(default_factory=dict)
    exposure_s: float | None = None
    exposure_source: str | None = None
    iso: float | None = None
    iso_source: str | None = None
    f_number: float | None = None
    f_number_source: str | None = None
    focal_length_mm: float | None = None
    focal_length_source: str | None = None


@dataclass(frozen=True)
class StageFrames:
    """The frames of one stage folder with its manifest rows (read once, by :func:`index_session`).

    Stages accept this wherever they accept a folder path (:func:`stage_files`).
    """

    stage: str
    folder: Path
    frames: tuple[FrameRef, ...]
    manifest: Mapping[str, Row]
    """``frames.csv`` rows keyed by file name ({} when the folder has none)."""

    @property
    def paths(self) -> list[Path]:
        return [f.path for f in self.frames]

    def __fspath__(self) -> str:  # provenance and messages name the folder, as they did with folder paths
        return str(self.folder)

    def __str__(self) -> str:
        return str(self.folder)


@dataclass(frozen=True)
class SessionIndex:
    """One calibration session, read once (see the module docstring).

    Attributes
    ----------
    root : the session folder.
    stages : stage folders holding image files, in :data:`STAGES` order.
    defaults : ``session.toml`` values (:class:`camcal.frame.Exposure` field names), {} when absent.
    frames : per stage, its :class:`StageFrames`.
    sweep_manifest : ``sweep/sweep.csv`` rows, None when the session has no sweep or the sweep no ``sweep.csv``.
    inputs : per stage, every file of its folder a calibration may read (images and ``.csv`` files, hidden files
        left out), sorted by name: what the profile's provenance hashes.
    """

    root: Path
    stages: tuple[str, ...]
    defaults: Mapping[str, float | str]
    frames: Mapping[str, StageFrames]
    sweep_manifest: Mapping[str, Row] | None = None
    inputs: Mapping[str, tuple[Path, ...]] = field(default_factory=dict)

    def stage(self, name: str) -> StageFrames | None:
        """The frames of stage ``name``; None when the session does not hold it."""
        return self.frames.get(name)

    def manifest_of(self, name: str) -> tuple[Mapping[str, Row], str]:
        """The manifest rows that give stage ``name``'s exposures and the manifest's file name: ``sweep.csv``
        for a sweep that has one, else ``frames.csv``."""
        if name == "sweep" and self.sweep_manifest is not None:
            return self.sweep_manifest, SWEEP_CSV
        sf = self.frames.get(name)
        return (sf.manifest if sf is not None else {}), FRAMES_CSV


def present_stages(session: str | Path) -> list[str]:
    """Stage folders of ``session`` that hold at least one image file."""
    session = Path(session)
    if not session.is_dir():
        raise CamcalError("is not a session folder", session)
    out = []
    for s in STAGES:
        d = session / s
        if d.is_dir() and (any(p.suffix.lower() in IMAGE_EXTENSIONS for p in d.iterdir())
                           or (s == "flat" and aperture_folders(d))):
            out.append(s)
    return out


def aperture_folders(flat: Path) -> list[tuple[float, Path]]:
    """Sub-folders ``f<N>`` of a ``flat/`` folder that hold image files, with their f-number N, by N."""
    out = []
    for d in sorted(flat.iterdir()) if flat.is_dir() else ():
        m = APERTURE_FOLDER.match(d.name)
        if m and d.is_dir() and any(p.suffix.lower() in IMAGE_EXTENSIONS for p in d.iterdir()):
            out.append((float(m.group(1)), d))
    return sorted(out, key=lambda x: x[0])


def _flat_files(folder: Path) -> tuple[list[Path], dict[str, Row], dict[Path, tuple[float, str]]]:
    """The flats of ``flat/`` and of its ``f<N>/`` sub-folders, their manifest rows (keyed by file name) and,
    for those in a sub-folder, (N, folder name)."""
    subs = aperture_folders(folder)
    if not subs:
        files, manifest = folder_files(folder)
        return files, manifest, {}
    files = list_frames(folder)
    if files:
        files, manifest = folder_files(folder)
    else:
        manifest = folder_manifest(folder)
        if manifest:
            raise CamcalError(f"frames.csv lists {next(iter(manifest))!r}, which is not an image file in the "
                              "folder (flats of several f-numbers: one frames.csv in each f<N>/ folder)", folder)
    seen = {p.name: p for p in files}
    given: dict[Path, tuple[float, str]] = {}
    for n, sub in subs:
        sub_files, sub_manifest = folder_files(sub)
        for p in sub_files:
            if p.name in seen:
                raise CamcalError(f"has the same file name as {seen[p.name]}; give every flat a file name of "
                                  "its own", p)
            seen[p.name] = p
            given[p] = (n, f"{folder.name}/{sub.name}/")
        files.extend(sub_files)
        manifest.update(sub_manifest)
    return files, manifest, given


def _with_folder_f_number(ref: FrameRef, n: float, folder: str) -> FrameRef:
    """A flat of an ``f<N>/`` folder: the folder names its f-number, above ``session.toml`` (a camera-wide default)
    and below the file's tag and frames.csv; a tag or row that says another f-number is refused."""
    if ref.f_number is not None and ref.f_number_source != "session":
        if not same_f_number(ref.f_number, n):
            raise CamcalError(f"is in {folder} but its f-number is f/{ref.f_number:g} ({ref.f_number_source}); "
                              f"move it to the folder of its f-number", ref.path)
        return ref
    return dataclasses.replace(ref, f_number=n, f_number_source=f"folder {folder}")


@dataclass(frozen=True)
class ApertureGroup:
    """The flats of one f-number.

    Attributes
    ----------
    f_number : the f-number N, None when unknown before decoding (no tag, row, folder or ``session.toml``).
    f_number_source : where it came from (``tag``, ``frames.csv``, ``folder flat/f8/``, ``session``; several
        joined by ``+``).
    frames : the stage's frames of this f-number (its manifest: the stage's).
    """

    f_number: float | None
    f_number_source: str | None
    frames: StageFrames


def aperture_groups(flats: StageFrames) -> list[ApertureGroup]:
    """The flats grouped by f-number (:func:`camcal.models.flat.same_f_number`), by N; frames of unknown N form
    the last group."""
    groups: list[list[FrameRef]] = []
    unknown: list[FrameRef] = []
    for ref in flats.frames:
        if ref.f_number is None:
            unknown.append(ref)
            continue
        for g in groups:
            if same_f_number(g[0].f_number, ref.f_number):
                g.append(ref)
                break
        else:
            groups.append([ref])
    out = []
    for g in sorted(groups, key=lambda g: g[0].f_number) + ([unknown] if unknown else []):
        values = [r.f_number for r in g if r.f_number is not None]
        n = max(set(values), key=values.count) if values else None
        sources = sorted({r.f_number_source for r in g if r.f_number_source})
        out.append(ApertureGroup(n, "+".join(sources) or None, dataclasses.replace(flats, frames=tuple(g))))
    return out


def resolve_exposure(path: Path, row: Row | None, defaults: Mapping[str, float | str],
                     manifest_name: str = FRAMES_CSV) -> FrameRef:
    """What is known of one frame's exposure time, ISO and f-number without decoding it (module docstring).

    The file's EXIF header is read (:func:`camcal.io.read.exposure_from_exif`); pixels are not. For a processed
    image (JPEG, TIFF, PNG) a value the EXIF reader does not find stays unknown here: OpenImageIO may still
    read it when the file is decoded, and it would rank above ``session.toml``.
    """
    raw = is_raw_path(path)
    overrides = {k: v for k, v in exposure_overrides(row).items() if v is not None}
    tags = None
    values: dict[str, tuple[float | None, str | None]] = {}
    for key in ("exposure_s", "iso", "f_number", "focal_length_mm"):
        if overrides.get(key) is not None:
            values[key] = (float(overrides[key]), manifest_name)
            continue
        if tags is None:
            tags = exposure_from_exif(path)
        v = getattr(tags, key)
        if v is not None:
            values[key] = (float(v), "tag")
        elif raw and defaults.get(key) is not None:
            values[key] = (float(defaults[key]), "session")
        else:
            values[key] = (None, None)
    return FrameRef(path, exposure_overrides(row) if row else {}, *values["exposure_s"], *values["iso"],
                    *values["f_number"], *values["focal_length_mm"])


def index_session(session: str | Path) -> SessionIndex:
    """Scan ``session``, read its manifests and defaults once, resolve exposures and check them.

    Raises
    ------
    CamcalError
        Not a folder, no stage folder with images, a ``frames.csv`` row naming a file that is not an image of
        its folder, a bad manifest or ``session.toml``, a dark frame without an exposure time, dark and bias
        frames at different ISO settings.
    """
    root = Path(session)
    stages = present_stages(root)
    if not stages:
        raise CamcalError("holds none of bias/ dark/ flat/ linearity/ sweep/ with image files", root)
    defaults = session_defaults_for(root / stages[0])
    sweep_manifest = None
    frames: dict[str, StageFrames] = {}
    for s in stages:
        folder = root / s
        if s == "sweep":
            # the sweep's frames are the rows of sweep.csv (camcal.calibrate.sweep); its folder may hold more (twins)
            files = list_frames(folder)
            manifest = read_manifest(folder / FRAMES_CSV) if (folder / FRAMES_CSV).exists() else {}
            if (folder / SWEEP_CSV).exists():
                sweep_manifest = read_manifest(folder / SWEEP_CSV, required=SWEEP_REQUIRED)
        elif s == "flat":
            files, manifest, in_folder = _flat_files(folder)
        else:
            files, manifest = folder_files(folder)
        rows, name = (sweep_manifest, SWEEP_CSV) if s == "sweep" and sweep_manifest is not None else (manifest,
                                                                                                      FRAMES_CSV)
        refs = tuple(resolve_exposure(p, rows.get(p.name), defaults, name) for p in files)
        if s == "flat" and in_folder:
            refs = tuple(_with_folder_f_number(r, *in_folder[r.path]) if r.path in in_folder else r for r in refs)
        frames[s] = StageFrames(s, folder, refs, manifest)
    inputs = {s: tuple(p for d in ([root / s] + ([d for _, d in aperture_folders(root / s)] if s == "flat" else []))
                       for p in sorted(d.iterdir()) if p.is_file() and not p.name.startswith(".")
                       and (p.suffix.lower() in IMAGE_EXTENSIONS or p.suffix.lower() == ".csv"))
              for s in stages}
    index = SessionIndex(root, tuple(stages), dict(defaults), frames, sweep_manifest, inputs)
    _check(index)
    return index


def _check(index: SessionIndex) -> None:
    """Checks that need no pixels: dark exposure times known, one ISO for dark and bias frames."""
    dark, bias = index.stage("dark"), index.stage("bias")
    if dark is not None:
        for f in dark.frames:
            if f.exposure_s is None:
                raise MissingMetadataError(f.path, "exposure_s")
    isos = {f.iso for sf in (dark, bias) if sf is not None for f in sf.frames}
    if None not in isos and len(isos) > 1:  # unknown ISOs: decoding decides (camcal.calibrate.dark)
        raise CamcalError(f"frames mix ISO settings {sorted(isos)}; take bias and dark frames at one ISO",
                          (dark or bias).folder)  # type: ignore[union-attr]


def stage_files(source: str | Path | StageFrames) -> tuple[list[Path], dict[str, Row]]:
    """The image files of a stage and their manifest rows: from a :class:`StageFrames` as indexed, or read
    from a folder (:func:`camcal.io.folders.folder_files`) for callers that hold only a path."""
    if isinstance(source, StageFrames):
        return source.paths, dict(source.manifest)
    return folder_files(source)


def folder_of(source: str | Path | StageFrames) -> Path:
    """The folder of a stage source (a path or :class:`StageFrames`)."""
    return source.folder if isinstance(source, StageFrames) else Path(source)

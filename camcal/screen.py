"""Frame verdicts: which frames of a calibration session are used, and which are left out and why.

A real session holds frames a careful person would not fit: a file truncated by a card reader, the
same frame copied twice, a JPEG of another camera dropped into ``flat/``, an over-exposed flat.
:func:`screen_session` decodes every frame of every stage once (threads, one frame in memory per
thread) and gives each a :class:`Verdict`: used, or left out with its reason. The stages then fit the
frames that are used; ``camcal calibrate`` lists the others (``provenance.left_out`` of the profile).
Each file is also hashed (SHA-256, :func:`camcal.hashing.sha256_file`) in the thread that decoded it, while
its bytes are in the page cache; the hash is remembered for the profile's provenance.

Reasons, in the order they are judged (the first that applies is given; docs/reliability.md lists them):

- ``unreadable: <why>``: the file cannot be decoded (truncated, damaged, image data stripped, an
  unsupported layout); ``<why>`` is the reader's one-line message.
- ``duplicate: the same pixels as <file> (a copy of one exposure); the first copy is kept``.
- ``another camera: ...`` / ``another layout: ...`` / ``another size: ...``: the frame's make and model,
  RAW layout or size differ from the session's (the most common among its RAW frames; processed
  images are compared with the session camera's own processed images, else with its Bayer frames' size).
- the stage's own frame check (:data:`StageCheck`), e.g. ``not RAW: ...``, ``saturated: ...``: a dark
  frame with light in it, a flat saturated beyond use or too dark, a sweep row that is not a RAW file.

Judged later, inside the stage that can see it (:mod:`camcal.spectral`): a sweep frame saturated in its
region of interest, and a sweep frame that recorded no light while the reference detector saw light.
A frame of a linearity series at or past saturation is *used*: it marks the end of the linear range
(:mod:`camcal.response`).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections import Counter
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from camcal.errors import CamcalError
from camcal.hashing import sha256_file
from camcal.io import load_frame
from camcal.session import SessionIndex, StageFrames
from camcal.stack import frame_digest
from camcal.threads import thread_count

StageCheck = Callable[["object"], None]
"""A stage's check of one decoded :class:`camcal.frame.Frame`: raises :class:`CamcalError` (its message is the
reason) when the stage cannot use the frame."""

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Verdict:
    """What a stage does with one frame.

    Attributes
    ----------
    stage : the stage folder (``bias``, ``dark``, ``flat``, ``linearity``, ``sweep``).
    file : the file's name inside the stage folder.
    reason : why it is left out; None when it is used.
    """

    stage: str
    file: str
    reason: str | None = None

    @property
    def used(self) -> bool:
        return self.reason is None

    def record(self) -> dict[str, str]:
        """``{"file": "stage/name", "stage", "reason"}``: the row of ``provenance.left_out``."""
        return {"file": f"{self.stage}/{self.file}", "stage": self.stage, "reason": str(self.reason)}


@dataclass(frozen=True)
class FrameFacts:
    """What decoding one frame tells the screening (no pixels are kept).

    ``error``: the reader's message when it cannot be decoded (every other field is then empty);
    ``check_error``: the stage check's message when the stage cannot use it.
    """

    path: Path
    kind: str = ""
    layout: str = ""
    shape: tuple[int, int] = (0, 0)
    cfa_pattern: str | None = None
    make: str | None = None
    model: str | None = None
    serial: str | None = None
    digest: bytes = b""
    """:func:`camcal.stack.frame_digest` of the pixels; empty for a frame with every value at the white level."""
    error: str | None = None
    check_error: str | None = None


@dataclass(frozen=True)
class Screening:
    """The verdicts of a whole session.

    Attributes
    ----------
    kept : per stage, the :class:`StageFrames` of the frames that are used (a stage whose every frame was
        left out keeps an empty one).
    verdicts : one per frame, in stage and file order.
    facts : per path, what decoding told (camera, layout, size of the frames that are used).
    camera : the session's (make, model), the most common among its RAW frames; (None, None) when unknown.
    """

    kept: Mapping[str, StageFrames]
    verdicts: tuple[Verdict, ...]
    facts: Mapping[Path, FrameFacts]
    camera: tuple[str | None, str | None]

    def left_out(self, stage: str | None = None) -> list[Verdict]:
        """Verdicts of the frames left out (of ``stage``, or of every stage)."""
        return [v for v in self.verdicts if not v.used and (stage is None or v.stage == stage)]


def frame_facts(path: Path, overrides: Mapping[str, float | None] | None = None,
                check: StageCheck | None = None) -> FrameFacts:
    """Decode ``path`` once and return its :class:`FrameFacts` (the stage ``check`` run on it)."""
    try:
        frame = load_frame(path, dict(overrides or {}))
    except CamcalError as exc:
        return FrameFacts(path, error=exc.message)
    check_error = None
    if check is not None:
        try:
            check(frame)
        except CamcalError as exc:
            check_error = exc.message
    e = frame.exposure
    # a frame with every value at the white level holds no noise: two separate over-exposed frames have the same
    # pixels without being copies, so it takes no part in the duplicate check
    digest = b"" if int(frame.data.min()) >= frame.white_level_dn else frame_digest(frame.data)
    return FrameFacts(path, frame.kind, frame.layout, tuple(frame.shape), frame.cfa_pattern,  # type: ignore[arg-type]
                      e.make, e.model, e.serial, digest, None, check_error)


def _most_common(values: list) -> object:
    """The most common value; ties go to the one seen first."""
    counts = Counter(values)
    best = max(counts.values())
    return next(v for v in values if counts[v] == best)


def _camera_name(make: str | None, model: str | None) -> str:
    return " ".join(x for x in (make, model) if x) or "an unnamed camera"


def _mismatch(f: FrameFacts, camera: tuple, layout: str | None, shape: tuple | None) -> str | None:
    """The reason a readable frame is not of the session's camera, layout or size; None when it is."""
    parts = []
    if f.model and camera[1] and (f.make, f.model) != camera:
        parts.append(("camera", _camera_name(f.make, f.model), _camera_name(*camera)))
    if layout is not None and f.layout != layout:
        parts.append(("layout", f"{f.layout}", layout))
    if shape is not None and f.shape != shape:
        parts.append(("size", f"{f.shape[1]}x{f.shape[0]} pixels", f"{shape[1]}x{shape[0]} pixels"))
    if not parts:
        return None
    what = " and ".join(p[0] for p in parts)
    this = ", ".join(p[1] for p in parts)
    theirs = ", ".join(p[2] for p in parts)
    return f"another {what}: {this}; the session's frames are {theirs}"


def screen_session(index: SessionIndex, checks: Mapping[str, StageCheck] | None = None, *, jobs: int | None = None,
                   progress: Progress | None = None) -> Screening:
    """Decode every frame of ``index`` once and give each a :class:`Verdict` (module docstring).

    ``checks``: per stage, the stage's own frame check. ``jobs``: decoding threads
    (:func:`camcal.threads.thread_count`). ``progress(done, total)`` after each frame.
    """
    checks = checks or {}
    items = [(s, ref) for s in index.stages for ref in index.frames[s].frames]
    total = len(items)

    def work(item):
        s, ref = item
        facts = frame_facts(ref.path, ref.overrides, checks.get(s))
        with contextlib.suppress(OSError):  # the file is in the page cache now: its provenance hash is cheap
            sha256_file(ref.path, remember=True)
        return facts

    first_pixels = None
    for _s, ref in items[:1]:  # the thread rule looks at the frame size; a header read is not worth it here
        first_pixels = max(ref.path.stat().st_size // 2, 1)
    threads = thread_count(jobs, total, first_pixels)
    facts: list[FrameFacts] = []
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for i, f in enumerate(pool.map(work, items) if threads > 1 else map(work, items)):
            facts.append(f)
            if progress:
                progress(i + 1, total)
    readable = [f for f in facts if f.error is None]
    raw = [f for f in readable if f.kind == "raw"]
    camera = _most_common([(f.make, f.model) for f in raw or readable]) if readable else (None, None)
    layout = _most_common([f.layout for f in raw]) if raw else None
    raw_shape = _most_common([f.shape for f in raw if f.layout == layout]) if raw else None
    # processed images: the size of the session camera's own (JPEG twins), else of its Bayer RAW frames (a camera
    # writes its JPEGs at the sensor's size; a linear RAW frame's size says nothing of them)
    own = [f.shape for f in readable if f.kind != "raw" and (f.make, f.model) == camera]
    processed_shape = _most_common(own) if own else (raw_shape if layout == "bayer" else None)

    verdicts: list[Verdict] = []
    kept: dict[str, list] = {s: [] for s in index.stages}
    seen: dict[tuple[str, bytes], str] = {}
    for (s, ref), f in zip(items, facts, strict=True):
        reason = None
        if f.error is not None:
            reason = f"unreadable: {f.error}"
        else:
            first = seen.setdefault((s, f.digest), ref.path.name) if f.digest else ref.path.name
            if first != ref.path.name:
                reason = f"duplicate: the same pixels as {first} (a copy of one exposure); the first copy is kept"
            elif f.kind == "raw":
                reason = _mismatch(f, camera, layout, raw_shape)  # type: ignore[arg-type]
            else:
                reason = _mismatch(f, camera, None, processed_shape)  # type: ignore[arg-type]
            if reason is None and f.check_error is not None:
                reason = f.check_error
        verdicts.append(Verdict(s, ref.path.name, reason))
        if reason is None:
            kept[s].append(ref)
    kept_frames = {s: dataclasses.replace(index.frames[s], frames=tuple(kept[s])) for s in index.stages}
    return Screening(kept_frames, tuple(verdicts), {f.path: f for f in facts}, camera)  # type: ignore[arg-type]

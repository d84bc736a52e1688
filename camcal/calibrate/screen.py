"""Frame verdicts: which frames of a calibration session are used, and which are left out and why.

A real session holds frames a careful person would not fit: a file truncated by a card reader, the
same frame copied twice, a JPEG of another camera dropped into ``flat/``, an over-exposed flat.
Every frame of every stage gets a :class:`Verdict`: used, or left out with its reason. The stages fit the
frames that are used; ``camcal calibrate`` lists the others (``provenance.left_out`` of the profile).

Where a frame is judged (each frame decoded once for its verdict and its stage):

- :func:`screen_session` reads every frame's header (:func:`camcal.io.read.frame_header`: kind, RAW layout, size,
  make and model, no pixel decoded) for the session's camera, layout and size (:class:`Majority`), and decodes
  (threads, one frame in memory per thread) and judges the frames whose stage does not judge them itself
  (in ``camcal calibrate``: the sweep's JPEG twins, and flats of several f-numbers, grouped on the frames used).
- The stages given a :class:`StageJudge` (``camcal calibrate``: the bias and dark stacks and the master flat,
  :func:`camcal.calibrate.stack.combine_frames`; the linearity series,
  :func:`camcal.calibrate.response.measure_response`; the sweep's rows, :func:`camcal.calibrate.sweep.measure_sweep`)
  judge each frame as they decode it for their
  fit, in their one streaming pass, and leave a frame judged unusable out of what they accumulate. ``--strict`` judges
  every frame in :func:`screen_session` first (all or nothing, refused at the first problem).

Both decode a frame through :func:`decode_facts` and give the same verdicts, formed in one place
(:func:`_reason`), in the same stage and file order. Each file is also hashed (SHA-256,
:func:`camcal.io.hashing.sha256_file`) in the thread that decoded it, while its bytes are in the page cache; the hash
is remembered for the profile's provenance.

A stack combined on its own (``camcal dark``, :func:`camcal.calibrate.stack.combine_frames` without a stage's judge)
goes through the same code with a :class:`StrictJudge`: no frame is left out, an unreadable frame or a copy is an error.

Reasons, in the order they are judged (the first that applies is given; docs/reliability.md lists them):

- ``unreadable: <why>``: the file cannot be decoded (truncated, damaged, image data stripped, an
  unsupported layout); ``<why>`` is the reader's one-line message.
- ``duplicate: the same pixels as <file> (a copy of one exposure); the first copy is kept``: the first copy in
  the stage's file order, whatever order a stage reads its frames in (:meth:`StageJudge.decide`).
- ``another camera: ...`` / ``another layout: ...`` / ``another size: ...``: the frame's make and model,
  RAW layout or size differ from the session's (the most common among its RAW frames; processed
  images are compared with the session camera's own processed images, else with its Bayer frames' size).
  The session's values come from the headers of the frames a stage judges and the decode of the others; a file
  whose header cannot be read takes no part (its decode names the problem), and a DNG whose header does not
  say its layout is decoded to tell it.
- the stage's own frame check (:data:`StageCheck`), e.g. ``not RAW: ...``, ``saturated: ...``: a dark
  frame with light in it, a flat saturated beyond use or too dark, a sweep row that is not a RAW file.

Judged later, inside the stage that can see it: a dark frame alone at its exposure time once its companions
are left out (:mod:`camcal.calibrate.dark`); a sweep frame saturated in its region of interest, and a sweep frame that
recorded no light while the reference detector saw light (:mod:`camcal.calibrate.sweep`). A frame of a linearity
series at or past saturation is *used*: it marks the end of the linear range (:mod:`camcal.calibrate.response`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
from collections import Counter
from collections.abc import Callable, Collection, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camcal.calibrate.session import FrameRef, SessionIndex, StageFrames
from camcal.errors import CamcalError
from camcal.io.hashing import sha256_file
from camcal.io.read import frame_header, load_frame
from camcal.threads import thread_count

StageCheck = Callable[["object"], None]
"""A stage's check of one decoded :class:`camcal.frame.Frame`: raises :class:`CamcalError` (its message is the
reason) when the stage cannot use the frame."""

Progress = Callable[[int, int], None]

DIGEST_STRIDE = 16
"""Every 16th value enters a frame's digest (5 ms for 12 MP instead of 40 ms for every value): two separate
exposures never agree on 750 000 noisy values, even below 1 DN of noise (57 % agree per pixel on the IMX296)."""


def frame_digest(data: np.ndarray) -> bytes:
    """BLAKE2b of every :data:`DIGEST_STRIDE`-th value of a decoded frame (its shape and type included)."""
    h = hashlib.blake2b(repr((data.shape, data.dtype.str)).encode(), digest_size=16)
    h.update(np.ascontiguousarray(data.reshape(-1)[::DIGEST_STRIDE]))
    return h.digest()


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
    """:func:`frame_digest` of the pixels; empty for a frame with every value at the white level."""
    error: str | None = None
    check_error: str | None = None


@dataclass(frozen=True)
class Keep:
    """The verdict a stack's callback gives one decoded frame (:func:`camcal.calibrate.stack.combine_frames`).

    ``keep``: combine it. ``replaces``: a frame combined before that this one takes the place of (a copy of it,
    later in file order: the stack gives its sums or its slot to this one). ``reason``: why it is left out.
    """

    keep: bool
    replaces: Path | None = None
    reason: str | None = None


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
    majority: Majority = dataclasses.field(default_factory=lambda: Majority())
    deferred: Mapping[str, list[str]] = dataclasses.field(default_factory=dict)
    """Per stage, the names of the frames its stage judges itself (:meth:`judge`); not in ``verdicts``."""
    order: Mapping[str, Mapping[Path, int]] = dataclasses.field(default_factory=dict)
    """Per stage, each frame's place in the stage's file order."""
    digests: Mapping[str, Mapping[bytes, tuple[int, str]]] = dataclasses.field(default_factory=dict)
    """Per stage, the pixel digests of the frames decoded here: (place in file order, name) of the first copy."""

    def left_out(self, stage: str | None = None) -> list[Verdict]:
        """Verdicts of the frames left out (of ``stage``, or of every stage)."""
        return [v for v in self.verdicts if not v.used and (stage is None or v.stage == stage)]

    def judge(self, stage: str, check: StageCheck | None = None) -> StageJudge:
        """The :class:`StageJudge` of ``stage``'s deferred frames: the session's majority, the stage's file order
        and the digests of its frames judged here (a deferred copy of one of them is a duplicate)."""
        return StageJudge(stage, self.majority, check, self.order.get(stage, {}), self.digests.get(stage),
                          self.facts)  # type: ignore[arg-type]


def _facts_of(path: Path, frame, check: StageCheck | None) -> FrameFacts:
    """The :class:`FrameFacts` of ``frame`` decoded from ``path`` (the stage ``check`` run on it)."""
    check_error = None
    if check is not None:
        try:
            check(frame)
        except CamcalError as exc:
            check_error = exc.message
    e = frame.exposure
    # a frame with every value at the white level holds no noise: two separate over-exposed frames have the same
    # pixels without being copies, so it takes no part in the duplicate check
    digest = b"" if frame.data_range()[0] >= frame.white_level_dn else frame_digest(frame.data)
    return FrameFacts(path, frame.kind, frame.layout, tuple(frame.shape),  # type: ignore[arg-type]
                      frame.cfa_pattern, e.make, e.model, e.serial, digest, None, check_error)


def decode_facts(path: Path, loader: Callable[[Path], object], check: StageCheck | None = None, *,
                 hash_file: bool = True) -> tuple[object | None, FrameFacts]:
    """Decode ``path`` once: ``(frame, facts)``, the frame ``loader(path)`` decodes (None when it cannot) and what
    judging needs (the stage ``check`` run on it; ``facts.error`` the reader's message when it cannot be decoded).

    The one place a frame is decoded for its verdict, by the screening and by a stage's :class:`StageJudge`.
    ``hash_file``: the file is hashed (:func:`camcal.io.hashing.sha256_file`, remembered for the provenance) right
    after its decode, while its bytes are in the page cache.
    """
    try:
        frame = loader(path)
    except CamcalError as exc:
        frame, facts = None, FrameFacts(path, error=exc.message)
    else:
        facts = _facts_of(path, frame, check)
    if hash_file:
        with contextlib.suppress(OSError):  # the file is in the page cache now: its provenance hash is cheap
            sha256_file(path, remember=True)
    return frame, facts


def _loader(overrides: Mapping[str, float | None] | None) -> Callable[[Path], object]:
    """:func:`camcal.io.read.load_frame` with a frame's manifest ``overrides``."""
    return lambda p: load_frame(p, dict(overrides or {}))


def header_facts(path: Path, overrides: Mapping[str, float | None] | None = None) -> FrameFacts:
    """What the session majority needs of a frame (kind, layout, size, make, model), from its header alone
    (:func:`camcal.io.read.frame_header`); decoded when the header does not tell its RAW layout. ``error`` is set
    when the header cannot be read (the frame's own decode then names the problem)."""
    try:
        h = frame_header(path)
    except CamcalError as exc:
        return FrameFacts(path, error=exc.message)
    if h.layout is None:  # decoded, not hashed: its stage decodes and hashes it again
        return decode_facts(path, _loader(overrides), hash_file=False)[1]
    return FrameFacts(path, h.kind, h.layout, h.shape, None, h.make, h.model)


def _most_common(values: list) -> object:
    """The most common value; ties go to the one seen first."""
    counts = Counter(values)
    best = max(counts.values())
    return next(v for v in values if counts[v] == best)


def _camera_name(make: str | None, model: str | None) -> str:
    return " ".join(x for x in (make, model) if x) or "an unnamed camera"


@dataclass(frozen=True)
class Majority:
    """The session's camera, RAW layout and sizes: the most common among its RAW frames (module docstring).

    ``processed_shape``: the size of the session camera's own processed images (JPEG twins), else of its Bayer
    RAW frames (a camera writes its JPEGs at the sensor's size; a linear RAW frame's size says nothing of them).
    """

    camera: tuple[str | None, str | None] = (None, None)
    layout: str | None = None
    raw_shape: tuple[int, int] | None = None
    processed_shape: tuple[int, int] | None = None

    @classmethod
    def of(cls, facts: list[FrameFacts]) -> Majority:
        readable = [f for f in facts if f.error is None]
        raw = [f for f in readable if f.kind == "raw"]
        camera = _most_common([(f.make, f.model) for f in raw or readable]) if readable else (None, None)
        layout = _most_common([f.layout for f in raw]) if raw else None
        raw_shape = _most_common([f.shape for f in raw if f.layout == layout]) if raw else None
        own = [f.shape for f in readable if f.kind != "raw" and (f.make, f.model) == camera]
        processed_shape = _most_common(own) if own else (raw_shape if layout == "bayer" else None)
        return cls(camera, layout, raw_shape, processed_shape)  # type: ignore[arg-type]

    def mismatch(self, f: FrameFacts) -> str | None:
        """The reason a readable frame is not of the session's camera, layout or size; None when it is."""
        if f.kind == "raw":
            return _mismatch(f, self.camera, self.layout, self.raw_shape)
        return _mismatch(f, self.camera, None, self.processed_shape)


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


def _duplicate(first: str) -> str:
    return f"duplicate: the same pixels as {first} (a copy of one exposure); the first copy is kept"


def _reason(f: FrameFacts, majority: Majority, duplicate_of: str | None) -> str | None:
    """The one place a verdict is formed, in the order of the module docstring: unreadable, duplicate, another
    camera/layout/size, the stage's own check. ``duplicate_of``: the first copy's name when ``f`` is a copy."""
    if f.error is not None:
        return f"unreadable: {f.error}"
    if duplicate_of is not None:
        return _duplicate(duplicate_of)
    return majority.mismatch(f) or f.check_error


class StageJudge:
    """The verdicts of one stage's frames, given while the stage decodes them for its own fit (each frame decoded
    once: no screening decode before the stage).

    :meth:`load` runs in the stage's decode threads: it decodes the frame with the stage's own loader, hashes the
    file beside the decode (its bytes are in the page cache) and runs the stage check (:func:`decode_facts`).
    :meth:`decide` runs in the stage's own thread, frame after frame, and gives the verdict (:func:`_reason`:
    the same reasons as :func:`screen_session`). A copy is told by its pixel digest; the copy first in the
    stage's file order is kept, whatever order the stage reads them in: when the kept copy comes after a copy
    already used, the one used is a duplicate now, and :meth:`keep` names it (the stage puts the new one in its
    place).
    """

    def __init__(self, stage: str, majority: Majority, check: StageCheck | None, order: Mapping[Path, int],
                 seen: Mapping[bytes, tuple[int, str]] | None = None, facts: dict[Path, FrameFacts] | None = None):
        self.stage = stage
        self.majority = majority
        self.check = check
        self.order = dict(order)
        self.seen: dict[bytes, tuple[int, Path]] = {d: (i, Path(n)) for d, (i, n) in (seen or {}).items()}
        self.facts = facts if facts is not None else {}
        self.reasons: dict[Path, str | None] = {}
        self.superseded: list[Path] = []
        """Frames used, then found to be copies of a frame first in file order, in the order found (a stage that
        stacks frames in several groups measures again when one of its groups used one)."""
        self.reported: set[str] = set()
        """Names of the frames whose verdict the caller has recorded already."""

    def load(self, path: Path, loader: Callable[[Path], object]) -> tuple[object | None, FrameFacts]:
        """``(frame, facts)``: the frame ``loader(path)`` decodes (None when it cannot) and what judging needs."""
        return decode_facts(path, loader, self.check)

    def decide(self, path: Path, facts: FrameFacts) -> str | None:
        """The verdict of ``path`` (None: used); recorded. A path judged already keeps its verdict."""
        return self._verdict(path, facts)[0]

    def keep(self, path: Path, facts: FrameFacts) -> Keep:
        """The verdict of ``path`` as a stack's callback wants it (:func:`camcal.calibrate.stack.combine_frames`):
        kept or not, and the frame used before that it replaces (its copy, later in file order)."""
        reason, replaces = self._verdict(path, facts)
        return Keep(reason is None, replaces, reason)

    def _verdict(self, path: Path, facts: FrameFacts) -> tuple[str | None, Path | None]:
        """(reason, the frame used before that is now a duplicate of ``path`` or None); recorded."""
        if path in self.reasons:
            return self.reasons[path], None
        if facts.error is None:
            self.facts[path] = facts
        first = replaces = None
        rank = self.order.get(path)
        if rank is None:  # not a frame of the stage's index: after all of them
            rank = self.order[path] = len(self.order)
        if facts.error is None and facts.digest:
            seen = self.seen.setdefault(facts.digest, (rank, path))
            if seen[0] < rank or (seen[1] != path and seen[1] not in self.reasons):
                first = seen[1].name  # (a frame the screening judged keeps its verdict)
            elif seen[1] != path:  # this one comes first in file order: the one seen before is its copy
                self.seen[facts.digest] = (rank, path)
                if self.reasons.get(seen[1]) is None:
                    replaces = seen[1]
                    self.superseded.append(replaces)
                self.reasons[seen[1]] = _duplicate(path.name)
        reason = _reason(facts, self.majority, first)
        self.reasons[path] = reason
        return reason, (replaces if reason is None else None)

    def judge_all(self, refs: Sequence[FrameRef]) -> list[FrameRef]:
        """Decode and judge ``refs`` one after another (for a stage that cannot judge while it measures);
        returns the ones used."""
        kept = []
        for ref in refs:
            _frame, facts = self.load(ref.path, _loader(ref.overrides))
            if self.decide(ref.path, facts) is None:
                kept.append(ref)
        return [r for r in kept if self.reasons.get(r.path) is None]

    def verdicts(self) -> list[Verdict]:
        """The verdicts given so far, in the stage's file order."""
        return [Verdict(self.stage, p.name, r) for p, r in sorted(self.reasons.items(),
                                                                   key=lambda kv: self.order.get(kv[0], 1 << 30))]

    def left_out(self) -> list[Verdict]:
        return [v for v in self.verdicts() if not v.used]


class StrictJudge(StageJudge):
    """The judge of a stack combined on its own (:func:`camcal.calibrate.stack.combine_frames` without a stage's judge):
    every frame must be usable, none is left out. :meth:`load` lets the reader's error through (an unreadable
    frame is an error); :meth:`decide` refuses a copy (two frames with the same pixels, or one file given twice)
    and passes every other frame. No file is hashed: there is no profile provenance to give.
    """

    def __init__(self, paths: Sequence[Path]) -> None:
        order: dict[Path, int] = {}
        for i, p in enumerate(paths):
            order.setdefault(Path(p), i)
        super().__init__("frames", Majority(), None, order)

    def load(self, path: Path, loader: Callable[[Path], object]) -> tuple[object, FrameFacts]:
        frame = loader(path)
        return frame, FrameFacts(path, digest=frame_digest(frame.data))  # type: ignore[attr-defined]

    def decide(self, path: Path, facts: FrameFacts) -> None:
        """None (used), or :class:`CamcalError` naming the later of two frames with the same pixels."""
        rank = self.order.get(path, len(self.order))
        seen = self.seen.setdefault(facts.digest, (rank, path))
        if seen != (rank, path) or path in self.reasons:
            (_, first), (_, copy) = sorted([seen, (rank, path)])
            raise CamcalError(f"has the same pixels as {first.name} (the same frame twice, or a copy): "
                              "each frame of a stack must be a separate exposure", copy)
        self.reasons[path] = None

    def keep(self, path: Path, facts: FrameFacts) -> Keep:
        """Kept (:meth:`decide` raises for a copy)."""
        self.decide(path, facts)
        return Keep(True)


def screen_session(index: SessionIndex, checks: Mapping[str, StageCheck] | None = None, *, jobs: int | None = None,
                   progress: Progress | None = None,
                   defer: Mapping[str, Collection[str]] | None = None) -> Screening:
    """Give every frame of ``index`` a :class:`Verdict` (module docstring).

    ``checks``: per stage, the stage's own frame check. ``jobs``: decoding threads
    (:func:`camcal.threads.thread_count`). ``progress(done, total)`` after each frame.

    ``defer``: per stage, the names of the frames the stage judges itself while it decodes them
    (:meth:`Screening.judge`): they are not decoded here, only their headers read for the session's camera,
    layout and size (:func:`header_facts`); they stay in ``kept`` until their stage judges them. The other
    frames are decoded here, each once.
    """
    checks = checks or {}
    defer = defer or {}
    items = [(s, ref) for s in index.stages for ref in index.frames[s].frames]
    deferred = {(s, ref.path) for s, ref in items if ref.path.name in defer.get(s, ())}
    total = len(items)

    def work(item):
        s, ref = item
        if (s, ref.path) in deferred:
            return header_facts(ref.path, ref.overrides)
        return decode_facts(ref.path, _loader(ref.overrides), checks.get(s))[1]

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
    majority = Majority.of(facts)

    verdicts: list[Verdict] = []
    kept: dict[str, list] = {s: [] for s in index.stages}
    seen: dict[str, dict[bytes, tuple[int, str]]] = {s: {} for s in index.stages}
    rank = {s: 0 for s in index.stages}
    for (s, ref), f in zip(items, facts, strict=True):
        i = rank[s]
        rank[s] += 1
        if (s, ref.path) in deferred:
            kept[s].append(ref)
            continue
        first = None
        if f.error is None and f.digest:
            j, name = seen[s].setdefault(f.digest, (i, ref.path.name))
            first = name if name != ref.path.name else None
        reason = _reason(f, majority, first)
        verdicts.append(Verdict(s, ref.path.name, reason))
        if reason is None:
            kept[s].append(ref)
    kept_frames = {s: dataclasses.replace(index.frames[s], frames=tuple(kept[s])) for s in index.stages}
    order = {s: {ref.path: i for i, ref in enumerate(index.frames[s].frames)} for s in index.stages}
    return Screening(kept_frames, tuple(verdicts), {f.path: f for f in facts}, majority.camera,  # type: ignore[arg-type]
                     majority, {s: sorted(p.name for t, p in deferred if t == s) for s in index.stages
                                if any(t == s for t, _ in deferred)}, order, seen)

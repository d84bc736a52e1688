"""``camcal calibrate``: run every stage whose folder exists, in order, into one profile.

Order: dark (with bias/ when present) → flat (dark-corrected) → linearity
(dark-corrected) → sweep (dark- and flat-corrected). Each frame is decoded once for its verdict
and its fit (:mod:`camcal.calibrate.screen`): bias, dark, flat (of one f-number) and linearity frames and the sweep's
rows are judged by their stage as it decodes them; the sweep's JPEG twins and flats of several f-numbers by
the screening first. Every input file is hashed (SHA-256) into the profile's provenance: each frame once,
beside its decode (the file is then in the page cache), remembered for the stages that compare files by
content and for the provenance.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path

from camcal import __version__
from camcal.calibrate.colour_matrix import fit_colour_matrix, measure_colour_matrix, twin_pairs
from camcal.calibrate.dark import fit_dark
from camcal.calibrate.dark_frames import DarkOptions, dark_frame_check, measure_dark
from camcal.calibrate.emva import Nonuniformity, build_sheet, dark_noise_stacks
from camcal.calibrate.emva_standard import prnu_1288_planes
from camcal.calibrate.flat import (
    FlatChecks,
    FlatOptions,
    MasterFlat,
    check_flat_frame,
    fit_flat,
    measure_flat,
)
from camcal.calibrate.response import ResponseOptions, fit_response, measure_response
from camcal.calibrate.screen import Screening, StageCheck, StageJudge, Verdict, screen_session
from camcal.calibrate.session import STAGES, SessionIndex, aperture_groups, index_session, present_stages
from camcal.calibrate.sweep import (
    SweepOptions,
    fit_sweep,
    measure_sweep,
    read_sweep,
    require_wavelengths,
    sweep_rows,
)
from camcal.errors import CamcalError, TooFewFrames
from camcal.frame import Frame
from camcal.io.hashing import hash_files
from camcal.io.manifest import SESSION_DEFAULTS, session_camera_facts
from camcal.io.read import load_frame
from camcal.models.camera_id import Sensor, match, preferred, sensor_of
from camcal.models.dark import with_dead_pixels
from camcal.models.flat import DEAD_RESPONSE, FlatModel, choose_flat, dead_pixels, same_f_number
from camcal.models.profile import CalibrationProfile, CameraIdentity, Provenance
from camcal.threads import thread_count

__all__ = ["NORMALISING_STAGES", "STAGES", "CalibrateOptions", "calibrate_session", "camera_identity",
           "present_stages"]

NORMALISING_STAGES = ("linearity", "sweep")
"""Stages that normalise exposure (ISO·t/N², seed §2.1) and so need the reference setting; bias, dark and flat
frames are used as they are."""

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class CalibrateOptions:
    """Options of :func:`calibrate_session` (recorded in the profile's provenance).

    ``reference_iso`` / ``reference_f_number``: the reference setting; by default
    the setting of the sweep frames (where the absolute calibration is measured),
    else the most common one of the linearity series, else of the darks (flats, bias).
    Never defaulted silently: when unknown, calibration stops saying what to add.

    ``jobs``: decoding threads; None chooses them (:func:`camcal.threads.thread_count`: the usable cores, at most
    4, and one thread for frames under 0.25 megapixels, where a pool costs more than it gains).

    ``strict``: all or nothing: any frame left out (:mod:`camcal.calibrate.screen`) or stage with too few usable frames
    refuses the session, naming the first problem. By default such frames are left out and listed, and such a
    stage is not calibrated (the others are).
    """

    reference_iso: float | None = None
    reference_f_number: float | None = None
    dark_method: str = "sigma_clip"
    flat_model: str = "radial"
    sweep_mode: str = "absolute"
    deconvolve: bool = False
    jobs: int | None = None
    strict: bool = False


def _inputs(index: SessionIndex, jobs: int | None = None) -> list[dict]:
    """Provenance rows (stage, file, SHA-256, bytes) of every input file the session index found.

    The frames were hashed beside their decode (:mod:`camcal.calibrate.screen`: by the screening or the stage's judge);
    their remembered hashes are used (:func:`camcal.io.hashing.sha256_file`), the other files hashed in threads."""
    paths = [p for s in index.stages for p in index.inputs.get(s, ())]
    hashes = hash_files(paths, thread_count(jobs, len(paths)))
    return [{"stage": s, "file": p.relative_to(index.root).as_posix() if p.is_relative_to(index.root)
             else f"{s}/{p.name}", "sha256": hashes[p], "bytes": p.stat().st_size}
            for s in index.stages for p in index.inputs.get(s, ())]


def identity_from_screening(index: SessionIndex, screening: Screening) -> CameraIdentity:
    """The camera of a screened session: the facts of its first used RAW frame (else its first used frame)."""
    used = [ref.path for s in index.stages for ref in screening.kept[s].frames]
    if not used:
        first = next((v for v in screening.verdicts if not v.used), None)
        raise CamcalError("no frame of the session can be used"
                          + (f" (the first left out: {first.stage}/{first.file}: {first.reason})" if first else ""),
                          index.root)
    facts = [screening.facts[p] for p in used]
    f = next((x for x in facts if x.kind == "raw"), facts[0])
    h, w = f.shape
    return CameraIdentity(f.make, f.model, f.serial, f.cfa_pattern, w, h, f.layout)


def camera_identity(session: str | Path | SessionIndex, stages: list[str] | None = None) -> CameraIdentity:
    """Identity from the first RAW frame of the session (else the first frame); all stages must agree.

    ``session`` is a :class:`camcal.calibrate.session.SessionIndex` (or a folder, indexed here); ``stages`` limits the
    stages looked at (default: all present).
    """
    index = session if isinstance(session, SessionIndex) else index_session(session)
    seen: dict[str, CameraIdentity] = {}
    sensors: dict[str, Sensor] = {}
    for s in stages if stages is not None else index.stages:
        frames = index.frames[s].paths
        raw = [p for p in frames if p.suffix.lower() not in (".jpg", ".jpeg", ".png", ".tif", ".tiff")]
        f = load_frame((raw or frames)[0])
        h, w = f.shape
        seen[s] = CameraIdentity(f.exposure.make, f.exposure.model, f.exposure.serial, f.cfa_pattern, w, h, f.layout)
        sensors[s] = sensor_of(f)
    named = {s: c for s, c in sensors.items() if c.model}
    for s, c in named.items():  # every stage against every other (camcal.models.camera_id: software names forgiven)
        for t, d in named.items():
            if s < t and not match(c, d)[0]:
                raise CamcalError(f"frames from different cameras in one session: {s}/ is {c.label}, {t}/ is "
                                  f"{d.label}", index.root)
    if named:
        best = preferred(list(named.values()))
        stage = next(s for s, c in named.items() if c is best)
        seen = {stage: seen[stage], **seen}
    layouts = {c.layout for c in seen.values() if c.layout != "processed"}
    if len(layouts) > 1:
        raise CamcalError(f"RAW frames of different layouts in one session: {sorted(layouts)} (one camera mode per "
                          "session)", index.root)
    raw_ids = [c for c in seen.values() if c.layout != "processed"]
    return (raw_ids or list(seen.values()))[0]


_REFERENCE_HINT = {
    "iso": ("ISO", "iso = N", "iso", "--reference-iso"),
    "f_number": ("f-number", "f_number = N", "f_number", "--reference-f-number"),
}


def _reference(index: SessionIndex, opts: CalibrateOptions,
               required: bool = True) -> tuple[float | None, float | None, list[str]]:
    """The reference setting (ISO_ref, N_ref): the options', else the most common setting of the first stage
    present of sweep, linearity, dark, flat, bias (frames.csv / sweep.csv and session.toml applied).

    Never defaulted: when ``required`` (a stage normalises exposure, :data:`NORMALISING_STAGES`), a value no
    frame, manifest or session default gives stops calibration with one line saying what to add; otherwise it
    stays None (unknown). Returns (ISO_ref, N_ref, notes): a note says when a value came from ``session.toml``
    or from LibRaw alone rather than from a tag or a manifest.
    """
    iso, n = opts.reference_iso, opts.reference_f_number
    if iso and n:
        return float(iso), float(n), []
    session = index.root
    for s in ("sweep", "linearity", "dark", "flat", "bias"):
        if s not in index.stages or not index.frames[s].frames:
            continue
        manifest, csv_name = index.manifest_of(s)
        settings: Counter = Counter()
        origin: dict[tuple, tuple[str | None, str | None]] = {}
        for ref in index.frames[s].frames[:64]:
            p = ref.path
            row = manifest.get(p.name, {})
            if ref.iso is not None and ref.f_number is not None:  # manifest, tag or session.toml: no decode
                exp_iso, exp_n, src_iso, src_n = ref.iso, ref.f_number, ref.iso_source, ref.f_number_source
            else:  # only LibRaw (a maker header) can tell: decode
                try:
                    e = load_frame(p).exposure
                except CamcalError:  # unreadable: its stage leaves it out (camcal.calibrate.screen)
                    continue
                exp_iso, exp_n, src_iso, src_n = e.iso, e.f_number, e.source("iso"), e.source("f_number")
            key = (row.get("iso") or exp_iso, row.get("f_number") or exp_n)
            settings[key] += 1
            origin.setdefault(key, (csv_name if row.get("iso") else src_iso,
                                    csv_name if row.get("f_number") else src_n))
        if not settings:  # every frame looked at unreadable
            continue
        (fi, fn), _ = settings.most_common(1)[0]
        iso, n = iso or fi, n or fn
        if not required:
            return (float(iso) if iso else None), (float(n) if n else None), []
        for key, value in (("iso", iso), ("f_number", n)):
            if not value:
                what, toml, col, opt = _REFERENCE_HINT[key]
                raise CamcalError(
                    f"the reference {what} is unknown: the {s}/ frames hold no {what} (no tag, no {col} column); "
                    f"add '{toml}' to {SESSION_DEFAULTS} at the session root (one value for the whole camera), "
                    f"an {col} column to {s}/{csv_name}, or pass {opt}", session)
        notes = [f"reference {what} {value:g} from {SESSION_DEFAULTS if src == 'session' else 'LibRaw alone (no tag)'}"
                 for what, value, src, given in (("ISO", iso, origin[(fi, fn)][0], opts.reference_iso),
                                                 ("f-number", n, origin[(fi, fn)][1], opts.reference_f_number))
                 if not given and src in ("session", "libraw")]
        return float(iso), float(n), notes
    if not required:
        return (float(iso) if iso else None), (float(n) if n else None), []
    raise CamcalError("no stage folder to take the reference setting from; pass --reference-iso and "
                      "--reference-f-number", session)


def _judged(index: SessionIndex, stage: str, judge: StageJudge, record: _Record) -> SessionIndex:
    """Record the verdicts ``judge`` gave while its stage decoded its frames, and take the frames it left out
    out of ``index``."""
    new = [v for v in judge.left_out() if v.file not in judge.reported]
    judge.reported.update(v.file for v in new)
    record.screened(new)
    out = {p for p, r in judge.reasons.items() if r is not None}
    frames = index.frames[stage]
    kept = replace(frames, frames=tuple(r for r in frames.frames if r.path not in out))
    return replace(index, frames={**index.frames, stage: kept})


def stage_checks(options: CalibrateOptions | None = None) -> dict[str, StageCheck]:
    """Each stage's own check of one frame, run when the frame is judged (:mod:`camcal.calibrate.screen`):
    dark and bias frames RAW and not saturated; flats RAW, well exposed and not saturated beyond use
    (:func:`camcal.calibrate.flat.check_flat_frame`); no check for the linearity series (saturated frames are data) and
    for the sweep's RAW rows beyond being RAW (saturation and missing light are judged on the region of interest)."""
    dark = dark_frame_check(DarkOptions(method=(options or CalibrateOptions()).dark_method).saturation_fraction)
    flat_checks = FlatChecks()

    def flat(frame: Frame) -> None:
        check_flat_frame(frame, flat_checks)

    return {"bias": dark, "dark": dark, "flat": flat}


def _sweep_check(index: SessionIndex) -> StageCheck | None:
    """The sweep rows must be RAW frames (their processed twins are for the colour matrix)."""
    if index.sweep_manifest is None:
        return None
    rows = set(index.sweep_manifest)

    def check(frame: Frame) -> None:
        if frame.kind != "raw" and frame.path is not None and frame.path.name in rows:
            raise CamcalError("not RAW: a sweep.csv row must be a RAW file (the spectral sweep needs linear RAW "
                              "data)", frame.path)

    return check


@dataclass
class _Record:
    """What a calibration left out, as it goes (the profile's provenance.left_out and not_calibrated).

    :attr:`left_out` lists first the verdicts of the frames (:mod:`camcal.calibrate.screen`: unreadable, copies, another
    camera, the stage checks), in stage and file order (``order``), whether the screening or the stage itself
    judged them (:meth:`screened`), then what the stages left out from what they measured (:meth:`leave_out`: a
    dark alone at its exposure time, a sweep frame saturated or without light), in the order they were found.
    :attr:`not_calibrated` lists first, in stage order, the stages whose every frame was left out, then the
    others in the order they were skipped. Both are sorted when read (at the end of the calibration).
    """

    strict: bool
    root: Path
    order: Callable[[Verdict], tuple]
    """Sort key of a frame verdict: (stage, place in the stage's file order)."""
    frame_verdicts: list[Verdict] = field(default_factory=list)
    measured: list[Verdict] = field(default_factory=list)
    skipped: list[tuple[bool, dict]] = field(default_factory=list)
    """(every frame of the stage left out?, the not_calibrated row), in the order the stages were skipped."""

    @property
    def left_out(self) -> list[Verdict]:
        return sorted(self.frame_verdicts, key=self.order) + self.measured

    @property
    def not_calibrated(self) -> list[dict]:
        def rank(row: dict) -> int:
            return STAGES.index(row["stage"]) if row["stage"] in STAGES else len(STAGES)

        return (sorted((row for all_out, row in self.skipped if all_out), key=rank)
                + [row for all_out, row in self.skipped if not all_out])

    def _refuse(self, verdicts: list[Verdict]) -> None:
        if self.strict and verdicts:
            v = verdicts[0]
            raise CamcalError(f"{v.reason} (--strict: a frame that cannot be used refuses the session; without "
                              "--strict it is left out and listed)", self.root / v.stage / v.file)

    def leave_out(self, verdicts: list[Verdict]) -> None:
        """Add what a stage left out from what it measured (strict: refuse)."""
        self._refuse(verdicts)
        self.measured.extend(verdicts)

    def screened(self, verdicts: list[Verdict]) -> None:
        """Add frame verdicts, of the screening or of a stage judging its own frames (strict: refuse)."""
        self._refuse(verdicts)
        self.frame_verdicts.extend(verdicts)

    def skip(self, stage: str, exc: TooFewFrames, left_out: bool = False) -> None:
        """Record that ``stage`` is not calibrated (too few usable frames); strict: raise. ``left_out``: ``exc``
        may say every frame of the stage was left out (``all N left out``): such a stage goes first, in stage
        order, whether the screening or the stage itself found its frames unusable."""
        if self.strict:
            raise exc
        all_out = left_out and exc.remaining == 0 and exc.message.endswith(" left out)")
        self.skipped.append((all_out, {"stage": stage, "reason": exc.message}))

    def attempt(self, stage: str, fit: Callable[[], object], left_out: bool = False):
        """``fit()``; None when the stage has too few usable frames (recorded), unless strict."""
        try:
            return fit()
        except TooFewFrames as exc:
            self.skip(stage, exc, left_out)
            return None


@dataclass
class _Judging:
    """The session index of a calibration as its stages judge their frames
    (:class:`camcal.calibrate.screen.StageJudge`).

    ``index`` starts with the frames the screening kept; :meth:`judging` takes out those a stage's judge left
    out as the stage decoded them, and records their verdicts.
    """

    index: SessionIndex
    screening: Screening
    judges: dict[str, StageJudge]
    record: _Record

    @contextmanager
    def judging(self, *stages: str) -> Iterator[None]:
        """Around a stage's decode: afterwards (also when it raised) the verdicts the judges of ``stages`` gave
        are recorded and the frames they left out taken out of :attr:`index` (a judge's verdicts are recorded
        once)."""
        try:
            yield
        finally:
            for s in stages:
                judge = self.judges.get(s)
                if judge is not None and s in self.index.frames:
                    self.index = _judged(self.index, s, judge, self.record)

    def all_left_out(self, stage: str) -> TooFewFrames:
        """``stage`` has no usable frame left: every frame left out, by the screening or by its judge."""
        judge = self.judges.get(stage)
        n = len(self.screening.left_out(stage)) + (len(judge.left_out()) if judge is not None else 0)
        return TooFewFrames(stage, "frames", 1, 0, f"all {n} left out", self.index.root / stage)


def _prnu_1288(master, dark) -> dict[str, dict] | None:
    """PRNU₁₂₈₈ per plane of the master flat's plain average (total, with its row, column and pixel parts), the
    dark model's defects left out; None without unclipped statistics of two frames or more."""
    if master is None or master.mean_all is None or master.variance_all is None or master.n_frames < 2:
        return None
    return prnu_1288_planes(master.mean_all, master.variance_all, master.n_frames, master.channels,
                            None if dark is None else dark.defects)


def _fit_flats(index: SessionIndex, dark, opts: CalibrateOptions, ref_n: float | None, record: _Record,
               notes: list[str], cb, judge: StageJudge | None = None
               ) -> tuple[FlatModel | None, MasterFlat | None, dict[str, Nonuniformity] | None]:
    """The flat stage: one vignetting model per f-number of the flats
    (:func:`camcal.calibrate.session.aperture_groups`).

    The primary model (the profile's ``flat``: dead pixels, PRNU, the sweep's flat correction) is the one at the
    reference f-number, else the one of most frames (the smaller f-number on a tie); the others are its
    :attr:`~camcal.models.flat.FlatModel.apertures`. Flats of unknown f-number beside known ones are left out.
    Returns (primary model, its master flat, its EMVA 1288 PRNU per plane or None without unclipped statistics),
    (None, None, None) when no group could be fitted. The PRNU is the one :func:`camcal.calibrate.flat.fit_flat`
    reduced the primary's PRNU map to (:func:`camcal.calibrate.flat.flat_prnu`), not computed again.

    ``judge``: the flat stage's :class:`camcal.calibrate.screen.StageJudge` when its frames (of one f-number) are judged
    as the master flat decodes them.
    """
    flat_opts = FlatOptions(model=opts.flat_model)
    groups = aperture_groups(index.frames["flat"])
    if len(groups) > 1 and groups[-1].f_number is None:
        record.leave_out([Verdict("flat", r.path.name, "f-number unknown while the flats hold several f-numbers: "
                                  "put it in its flat/f<N>/ folder or give f_number in frames.csv")
                          for r in groups[-1].frames.frames])
        groups = groups[:-1]
    if len(groups) > 1:
        primary = (next((g for g in groups if same_f_number(g.f_number, ref_n)), None)
                   or max(groups, key=lambda g: (len(g.frames.frames), -(g.f_number or 0.0))))
        groups = [primary] + [g for g in groups if g is not primary]
    fitted: list[tuple[FlatModel, MasterFlat, dict[str, Nonuniformity]]] = []
    for i, g in enumerate(groups):
        label = "flat" if len(groups) == 1 else f"flat f/{g.f_number:g}"
        group_opts = flat_opts if i == 0 else replace(flat_opts, with_prnu=False)

        def fit(g=g, label=label, group_opts=group_opts):
            mf = measure_flat(g.frames, dark, group_opts, jobs=opts.jobs, progress=cb(label), judge=judge)
            prnu: dict[str, Nonuniformity] = {}
            # the PRNU figures of the first model fitted (the primary's, unless it could not be fitted)
            fm = fit_flat(mf, dark, group_opts, prnu_out=None if fitted else prnu)
            if g.f_number is not None and fm.optics.f_number is None:  # the folder's f-number (not in the files)
                fm = fm.replace(optics=replace(fm.optics, f_number=g.f_number, f_number_source=g.f_number_source))
            return fm, mf, prnu

        result = record.attempt(label, fit, left_out=judge is not None)
        if result is not None:
            fitted.append(result)
        elif i == 0 and len(groups) > 1:
            notes.append(f"the flats at f/{g.f_number:g} could not be fitted; the next f-number's model is primary")
    if not fitted:
        return None, None, None
    (primary_model, master, prnu), others = fitted[0], [m for m, _, _ in fitted[1:]]
    if not others:
        return primary_model, master, prnu or None
    if primary_model.prnu is None:  # the first fitted was not the primary group: no PRNU map to share
        notes.append("the primary flats could not be fitted: no PRNU map")
    others = [m.replace(prnu=primary_model.prnu) for m in others]
    flat = primary_model.replace(apertures=tuple(sorted(others, key=lambda m: m.optics.f_number or 0.0)))
    notes.append("flats at " + ", ".join(m.optics.label() for m in flat.models()) + ": one vignetting model per "
                 f"f-number; primary (PRNU, dead pixels, the sweep's flat) {primary_model.optics.label()}")
    return flat, master, prnu or None


def calibrate_session(
    session: str | Path, options: CalibrateOptions | None = None, progress: Progress | None = None
) -> tuple[CalibrationProfile, list[str]]:
    """Calibrate every stage present in ``session``; returns the profile and notes (skipped stages...).

    The session is read once (:func:`camcal.calibrate.session.index_session`: stage folders, manifests, session
    defaults) and screened (:func:`camcal.calibrate.screen.screen_session`): the bias, dark, flat (of one f-number) and
    linearity frames and the sweep's rows are judged by their stage as it decodes them
    (:class:`camcal.calibrate.screen.StageJudge`), the others (the sweep's JPEG twins, flats of several f-numbers)
    decoded and judged first (``options.strict``: every frame judged first); every stage receives its usable
    frames from that index. Frames left out are listed in the profile's ``provenance.left_out``; a stage with
    too few usable frames is not calibrated and listed in ``provenance.not_calibrated`` (the other stages are).
    With ``options.strict`` either refuses the session.
    ``progress(stage, done, total)`` is called as frames are processed.
    """
    opts = options or CalibrateOptions()
    index = index_session(session)
    session = index.root

    def cb(stage: str):
        return (lambda done, total: progress(stage, done, total)) if progress else None

    checks = stage_checks(opts)
    sweep_check = _sweep_check(index)
    if sweep_check is not None:
        checks["sweep"] = sweep_check
    # the stages judge their own frames as they decode them (each frame decoded once; the screening reads
    # headers); --strict refuses at the first frame that cannot be used: every frame is judged first
    defer: dict[str, set[str]] = {}
    if not opts.strict:
        for s in ("bias", "dark", "linearity"):
            if s in index.stages:
                defer[s] = {r.path.name for r in index.frames[s].frames}
        # flats of one f-number (flats of several are grouped, and their groups weighed, on the frames used)
        if "flat" in index.stages and len(aperture_groups(index.frames["flat"])) == 1:
            defer["flat"] = {r.path.name for r in index.frames["flat"].frames}
        if "sweep" in index.stages and index.sweep_manifest is not None:
            defer["sweep"] = set(index.sweep_manifest)
    screening = screen_session(index, checks, jobs=opts.jobs, progress=cb("check frames"), defer=defer)
    stage_rank = {s: i for i, s in enumerate(index.stages)}
    file_rank = {s: {p.name: i for p, i in screening.order.get(s, {}).items()} for s in index.stages}
    record = _Record(opts.strict, session, order=lambda v: (stage_rank[v.stage], file_rank[v.stage].get(v.file, 0)))
    record.screened(screening.left_out())
    judges = {s: screening.judge(s, checks.get(s)) for s in screening.deferred}
    run = _Judging(replace(index, frames=dict(screening.kept)), screening, judges, record)
    camera = identity_from_screening(run.index, screening)
    stages = [s for s in run.index.stages if run.index.frames[s].frames]
    for s in run.index.stages:
        if s not in stages:
            record.skip(s, run.all_left_out(s), left_out=True)
    ref_iso, ref_n, notes = _reference(run.index, opts, required=any(s in stages for s in NORMALISING_STAGES))

    dark = flat = spectral = None
    response = None
    # what the EMVA 1288 sheet reads of the dark stacks and the master flat, kept (not the stacks and the master
    # themselves, 1.2 GB at 24 MP) until it is built after the other stages
    dark_noise = prnu_frames = prnu = prnu_1288 = pairs = series = None
    bias_frames = run.index.stage("bias") if "bias" in stages else None
    dark_judge, bias_judge = judges.get("dark"), judges.get("bias")
    if "dark" in stages:
        dark_opts = DarkOptions(method=opts.dark_method)

        def fit_darks():
            nonlocal dark_noise
            with run.judging("bias", "dark"):
                stacks = measure_dark(run.index.frames["dark"], bias_frames, dark_opts, jobs=opts.jobs,
                                     progress=cb("dark"), judge=dark_judge, bias_judge=bias_judge)
            record.leave_out([Verdict("dark", name, reason) for name, reason in stacks.left_out])
            dark_noise = dark_noise_stacks(stacks.darks, stacks.bias)  # the sheet's, even if the fit fails
            # the fit reads no stack's unclipped mean: all but the DSNU stack's (which dark_noise holds) go now,
            # 96 MB each at 24 MP off the fit's peak
            stacks = replace(stacks, darks=tuple((t, replace(st, mean_all=None)) for t, st in stacks.darks))
            return fit_dark(stacks, dark_opts, jobs=opts.jobs)

        dark = record.attempt("dark", fit_darks, left_out=dark_judge is not None)
        if bias_frames is not None and bias_judge is not None and not run.index.frames["bias"].frames:
            record.skip("bias", run.all_left_out("bias"), left_out=True)
            bias_frames = None  # every bias frame left out as the dark stage decoded them
    if dark is None and bias_frames is not None:
        def fit_bias():
            nonlocal dark_noise
            with run.judging("bias"):
                stacks = measure_dark(None, run.index.stage("bias"), jobs=opts.jobs, progress=cb("bias"),
                                     bias_judge=bias_judge)
            dark_noise = dark_noise_stacks(stacks.darks, stacks.bias)
            return fit_dark(stacks, jobs=opts.jobs)

        dark = record.attempt("bias", fit_bias, left_out=bias_judge is not None)
        if dark is not None:
            notes.append("bias/ without dark/: bias, read noise and noisy pixels calibrated; dark current unknown "
                         "(apply subtracts the bias only; add dark frames at two exposure times to measure it)")
    if "flat" in stages:
        with run.judging("flat"):
            flat, master, prnu = _fit_flats(run.index, dark, opts, ref_n, record, notes, cb, judges.get("flat"))
        prnu_frames = None if master is None else master.n_frames
        prnu_1288 = _prnu_1288(master, dark)
        del master  # its maps (0.4 GB at 24 MP) are in the flat model as far as the profile needs them
        if flat is not None:
            dead = dead_pixels(flat)
            if dark is not None:
                dark = with_dead_pixels(dark, dead, f"flat response below {DEAD_RESPONSE:g} of the model")
            elif dead.any():
                notes.append(f"{int(dead.sum())} dead pixels in the flats are not kept: without a dark model the "
                             "profile has no defect map")
    if "linearity" in stages:
        def fit_linearity():
            nonlocal series, pairs
            judge = judges.get("linearity")
            with run.judging("linearity"):
                series = measure_response(run.index.frames["linearity"], ResponseOptions(None, ref_iso, ref_n),
                                          dark=dark, progress=cb("linearity"), jobs=opts.jobs, judge=judge)
            if judge is not None and not run.index.frames["linearity"].frames:
                raise run.all_left_out("linearity")
            pairs = series["raw"].pairs if "raw" in series else None
            return fit_response(series)

        response = record.attempt("linearity", fit_linearity, left_out=True)
    if "sweep" in stages:
        judge = judges.get("sweep")
        if judge is not None and judge.majority.raw_shape is None:
            # no RAW frame to take the sweep's geometry from: its rows are judged before they are measured (their
            # verdicts recorded here; the judge gives no more)
            deferred = set(screening.deferred["sweep"])
            with run.judging("sweep"):
                judge.judge_all([r for r in run.index.frames["sweep"].frames if r.path.name in deferred])
            judge = None
        sweep = run.index.frames["sweep"]
        kept_names = {p.name for p in sweep.paths}
        rows = sweep_rows(sweep.folder, run.index.sweep_manifest) if run.index.sweep_manifest is not None else None
        rows = rows if rows is not None else read_sweep(sweep.folder)
        listed = len({r.wavelength_nm for r in rows})
        rows = [r for r in rows if r.path.name in kept_names]
        sweep_opts = SweepOptions(mode=opts.sweep_mode, deconvolve=opts.deconvolve,  # type: ignore[arg-type]
                                  reference_iso=ref_iso, reference_f_number=ref_n)  # type: ignore[arg-type]
        sweep_opts.check()

        sweep_flat = flat
        if flat is not None and flat.apertures:  # the model of the sweep's f-number (the reference setting)
            choice = choose_flat(flat, ref_n)
            sweep_flat = max(choice.parts, key=lambda mw: mw[1])[0]
            if choice.how != "measured":
                notes.append(f"no flats at the sweep's f/{ref_n:g}: its region of interest corrected with the "
                             f"{sweep_flat.optics.label()} vignetting model")

        def sweep_stage():
            if not rows:
                raise TooFewFrames("sweep", "frames listed in sweep.csv", 1, 0)
            try:
                with run.judging("sweep"):
                    measured = measure_sweep(sweep.folder, rows, sweep_opts, dark=dark, flat=sweep_flat,
                                             jobs=opts.jobs, progress=cb("sweep"), judge=judge)
            except TooFewFrames:
                if judge is None or any(r is None for r in judge.reasons.values()):
                    raise
                # every row left out as it was decoded: as when the screening leaves them out
                if all(r.path in judge.reasons for r in sweep.frames):
                    raise run.all_left_out("sweep") from None
                raise TooFewFrames("sweep", "frames listed in sweep.csv", 1, 0) from None
            record.leave_out([Verdict("sweep", name, reason) for name, reason in measured.left_out])
            require_wavelengths(measured, listed=listed)
            return fit_sweep(measured, sweep_opts)

        spectral = record.attempt("sweep", sweep_stage, left_out=True)
        if spectral is not None and flat is None:
            notes.append("sweep without a flat model: c(λ) refers to the region of interest, not the optical axis")
        if response is not None and "processed" in response:
            if twin_pairs(run.index.frames["sweep"]):  # the sweep's colours; the series adds a broadband one
                twins = measure_colour_matrix([run.index.frames["sweep"], run.index.frames["linearity"]],
                                              response["processed"])
                cm = fit_colour_matrix(twins)  # type: ignore[arg-type] (the sweep has twins)
                response = {**response, "processed": replace(response["processed"], colour_matrix=cm)}
            else:
                notes.append("JPEG response without a colour matrix (the sweep has no JPEG twins): JPEG radiance "
                             "assumes the camera does not mix its channels")
    index = run.index
    if dark is None and flat is None and not response and spectral is None:
        why = "; ".join(f"{r['reason']}" for r in record.not_calibrated) or "no stage was calibrated"
        gone = "; ".join(f"{v.stage}/{v.file}: {v.reason}" for v in record.left_out[:3])
        raise CamcalError(f"no stage could be calibrated: {why}" + (f" (left out: {gone})" if gone else ""), session)
    emva = None
    if dark is not None or pairs is not None or prnu is not None:
        channels = dark.plane_names if dark is not None else (flat.channels if flat is not None else
                                                              tuple(series["raw"].channels))  # type: ignore[index]
        emva = build_sheet(channels=tuple(channels), iso=dark.iso if dark is not None else ref_iso,
                           dark_noise=dark_noise, dark=dark, prnu_frames=prnu_frames, flat_prnu=prnu, pairs=pairs,
                           prnu_1288=prnu_1288,
                           spectral=spectral, pixel_pitch_um=session_camera_facts(session / stages[0]).get(
                               "pixel_pitch_um"))
    if judges:  # the identity from the frames used, as decoded (a stage's frames were known by their header)
        camera = identity_from_screening(index, replace(screening, kept=dict(index.frames)))
    provenance = Provenance(
        camcal_version=__version__,
        created_utc=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        inputs=tuple(_inputs(index, opts.jobs)),
        options={**asdict(opts), "session": session.name, "stages": list(index.stages)},
        left_out=tuple(v.record() for v in record.left_out),
        not_calibrated=tuple(record.not_calibrated),
    )
    profile = CalibrationProfile(camera=camera, reference_iso=ref_iso, reference_f_number=ref_n, dark=dark,
                                 flat=flat, response=response, spectral=spectral, emva=emva,
                                 provenance=provenance)
    return profile, notes

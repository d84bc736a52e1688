"""The file step of the dark stage: the bias and dark frames, grouped by exposure time and stacked.

:func:`measure_dark` lists the frames, groups the darks by exposure time, combines each group and the bias frames
(:func:`camcal.calibrate.stack.combine_frames`, each frame judged as it is decoded), applies the exposure-time rules
to the frames used and checks sizes, patterns and ISO; its :class:`DarkStacks` is what
:func:`camcal.calibrate.dark.fit_dark` fits. Copies within a stage are told by their pixels
(:func:`camcal.calibrate.screen.frame_digest`); a file given both as a dark and as a bias frame is refused by its
bytes before any frame is decoded (:func:`refuse_shared_frames`), because a dark alone at its exposure time is set
aside undecoded and its pixels are never seen.
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from camcal.calibrate.dark_noise import QUANTISED_FIT_FRAMES
from camcal.calibrate.screen import StageJudge
from camcal.calibrate.session import StageFrames, folder_of, stage_files
from camcal.calibrate.stack import METHODS, StackOptions, StackResult, combine_frames
from camcal.errors import CamcalError, FrameLeftOut, MissingMetadataError, TooFewFrames
from camcal.frame import Frame
from camcal.io.hashing import sha256_file
from camcal.io.read import exposure_from_exif, saturated_fraction


def _exposure_times(source: str | Path | StageFrames, files: list[Path], manifest: dict) -> list[float]:
    """Exposure time of each frame, s: as the session index resolved it (manifest row > tag > session.toml),
    else from the manifest row or the file's EXIF header (no decode)."""
    if isinstance(source, StageFrames):
        known = {f.path: f.exposure_s for f in source.frames}
    else:
        known = {}
    out = []
    for path in files:
        t = known.get(path)
        if t is None:
            t = (manifest.get(path.name) or {}).get("exposure_s")
        if t is None:
            t = exposure_from_exif(path).exposure_s
        if t is None:
            raise MissingMetadataError(path, "exposure_s")
        out.append(float(t))
    return out


def dark_frame_check(saturation_fraction: float = 0.01) -> Callable[[Frame], None]:
    """Per-frame check for bias/dark frames: RAW only, not saturated."""

    def check(frame: Frame) -> None:
        if frame.kind != "raw":
            raise CamcalError("bias and dark frames must be RAW files (the dark model works on CFA planes)",
                              frame.path)
        white = frame.white_level_dn
        frac = saturated_fraction(frame)
        if frac > saturation_fraction:
            raise CamcalError(f"dark frame is saturated: {100 * frac:.1f} % of pixels at the white level "
                              f"{white:.0f} DN (light leak, or not a dark frame?)", frame.path)

    return check


def same_iso(stacks: list[StackResult], where: Path) -> float:
    isos = {e.require("iso", p) for s in stacks for e, p in zip(s.exposures, s.paths, strict=True)}
    if len(isos) > 1:
        raise CamcalError(f"frames mix ISO settings {sorted(isos)}; take bias and dark frames at one ISO", where)
    return isos.pop()



@dataclass(frozen=True)
class DarkOptions:
    """Options of the dark fit (recorded in the model's provenance).

    Attributes
    ----------
    method : how each exposure group of darks is combined (:func:`camcal.calibrate.stack.combine_frames`);
        bias frames are always averaged (``mean``) so their variance is the full temporal variance.
    sigma : sigma-clipping threshold, standard deviations.
    hot_sigma, hot_factor : hot if β > median + max(hot_sigma · robust σ_β, (hot_factor - 1) · median).
    noisy_sigma : noisy if the temporal variance is above the plane's model variance by more than
        ``noisy_sigma`` standard errors of a variance and by more than the chi-square bound a
        normal pixel exceeds with probability 1e-6 for the number of frames. Dead pixels are not
        found here (a zero temporal variance is normal below 1 DN of noise): the flat stage finds
        them by their response (:func:`camcal.models.flat.dead_pixels`).
    saturation_fraction : a frame with more than this fraction of pixels at the white level is refused.
    bias_prior_frames : weight, in frames, of the black-level prior at t = 0 (no bias frames only).
    """

    method: str = "sigma_clip"
    sigma: float = 3.0
    hot_sigma: float = 6.0
    hot_factor: float = 5.0
    noisy_sigma: float = 6.0
    saturation_fraction: float = 0.01
    bias_prior_frames: float = 1.0


@dataclass(frozen=True)
class DarkStacks:
    """The combined frames the dark model is fitted to (made by :func:`measure_dark`).

    Attributes
    ----------
    darks : ``(exposure_s, stack)`` per exposure time of the dark frames (s), shortest first; empty for a
        bias-only calibration.
    bias : the averaged bias frames, or None.
    dark_folder, bias_folder, dark_files, bias_files : where the frames came from (provenance only).

    The read-noise stack (bias, else the shortest darks) keeps its first :data:`QUANTISED_FIT_FRAMES`
    frames (``kept_planes``) for the quantised-noise fit, so fitting decodes nothing.
    """

    darks: tuple[tuple[float, StackResult], ...]
    bias: StackResult | None
    dark_folder: Path | None = None
    bias_folder: Path | None = None
    dark_files: tuple[str, ...] = ()
    bias_files: tuple[str, ...] = ()
    left_out: tuple[tuple[str, str], ...] = ()
    """(file name, reason) of dark frames not stacked: a frame alone at its exposure time."""


def _progress_from(progress: Callable[[int, int], None] | None, offset: int,
                   total: int) -> Callable[[int, int], None] | None:
    """``progress`` of one stack among several: its frames counted after ``offset`` of ``total``."""
    if progress is None:
        return None

    def cb(i: int, _n: int) -> None:
        progress(offset + i, total)

    return cb


def _check_stacks(stacks: list[StackResult], where: Path) -> float:
    """One frame size, CFA pattern and ISO over all stacks; returns the ISO."""
    ref = stacks[0]
    for st in stacks:
        if st.frame_shape != ref.frame_shape or st.cfa_pattern != ref.cfa_pattern:
            h, w = st.frame_shape
            h0, w0 = ref.frame_shape
            raise CamcalError(f"frame size {w}x{h} ({st.cfa_pattern}) differs from the first dark frame's "
                              f"{w0}x{h0} ({ref.cfa_pattern})", st.paths[0])
    return same_iso(stacks, where)


def refuse_shared_frames(dark_files: list[Path], bias_files: list[Path]) -> None:
    """Refuse a frame given both as a dark and as a bias frame (the same file, or a copy of it).

    The same exposure counted twice fits a dark current of exactly zero with zero uncertainty, which reads like
    a measurement. A copy is found by content: files of equal size whose sampled blocks agree (:func:`_sample_digest`)
    are compared by their SHA-256.

    Raises
    ------
    CamcalError
        Naming both files.
    """
    if not dark_files or not bias_files:
        return
    by_size: dict[int, list[Path]] = {}
    for p in bias_files:
        by_size.setdefault(p.stat().st_size, []).append(p)
    samples: dict[Path, bytes] = {}
    hashes: dict[Path, str] = {}

    def sample(p: Path) -> bytes:
        if p not in samples:
            samples[p] = _sample_digest(p)
        return samples[p]

    def digest(p: Path) -> str:
        if p not in hashes:
            hashes[p] = sha256_file(p)
        return hashes[p]

    for d in dark_files:
        for b in by_size.get(d.stat().st_size, ()):
            # a copy has every byte equal: files whose samples differ are not copies; equal samples are
            # confirmed by the whole file's hash
            if d.resolve() == b.resolve() or (sample(d) == sample(b) and digest(d) == digest(b)):
                raise CamcalError(f"is given twice: as a dark frame and as the bias frame {b} (the same exposure "
                                  "cannot be both); give each frame once", d)


SAMPLE_BYTES = 1 << 16
"""Bytes read at each of :data:`SAMPLE_POINTS` offsets of a file to tell two files of one size apart."""
SAMPLE_POINTS = 4


def _sample_digest(path: Path) -> bytes:
    """BLAKE2b of :data:`SAMPLE_POINTS` blocks of :data:`SAMPLE_BYTES` spread over the file (the last at its end,
    where a RAW file's pixel data are): two separate exposures of one size differ there by their noise, so
    most pairs are told apart without hashing whole files; equal samples still need the whole file's hash."""
    size = path.stat().st_size
    h = hashlib.blake2b(digest_size=16)
    with path.open("rb") as f:
        for i in range(1, SAMPLE_POINTS + 1):
            f.seek(max(0, size * i // SAMPLE_POINTS - SAMPLE_BYTES))
            h.update(f.read(SAMPLE_BYTES))
    return h.digest()



def _exposure_time_rules(groups: dict[float, list[Path]], have_bias: bool, folder: Path
                         ) -> tuple[dict[float, list[Path]], tuple[tuple[str, str], ...]]:
    """The rules on the dark frames grouped by exposure time (s): a frame alone at its exposure time has no
    temporal noise to measure and is left out (with a :class:`FrameLeftOut` warning) while other times have two
    frames or more; without bias frames, the dark-current fit needs two exposure times.

    Returns
    -------
    groups : the exposure times kept and their frames.
    left_out : ``(file name, reason)`` of the frames left out.

    Raises
    ------
    TooFewFrames
        No bias frames and fewer than two exposure times.
    """
    lone = {t: g for t, g in groups.items() if len(g) < 2}
    left_out: tuple[tuple[str, str], ...] = ()
    if lone and len(lone) < len(groups):
        left_out = tuple((g[0].name, f"alone at its exposure time ({t:g} s): the dark model measures the temporal "
                                     "noise of each exposure time from two or more frames") for t, g in lone.items())
        for name, reason in left_out:
            warnings.warn(f"left out: {name}: {reason}", FrameLeftOut, stacklevel=3)
        groups = {t: g for t, g in groups.items() if t not in lone}
    if not have_bias and len(groups) < 2:
        if not groups:
            raise TooFewFrames("dark", "frames", 1, 0, path=folder)
        ((t0, g0),) = groups.items()
        raise TooFewFrames("dark", "exposure times (or bias frames)", 2, 1,
                           f"all {len(g0)} dark frames have one exposure time ({t0:g} s); the dark-current fit "
                           "needs two or more exposure times, or bias frames (--bias)", folder)
    return groups, left_out


DARK_STATISTICS = ("variance_all", "mean_all")
"""What the dark stage uses of a dark stack (:func:`camcal.calibrate.stack.combine_frames`'s optional statistics): its
value and count, the temporal variance of all its values (the noise model, the read noise without bias frames)
and, with it, their mean (the EMVA 1288 DSNU, :func:`camcal.calibrate.emva.build_sheet`). The clipped values' variance
is not made: 96 MB less per stack at 24 MP. (The bias is a plain mean, whose statistics share two arrays: it keeps
them all.)"""


def measure_dark(
    dark: str | Path | StageFrames | None,
    bias: str | Path | StageFrames | None = None,
    options: DarkOptions = DarkOptions(),  # noqa: B008
    *,
    jobs: int | None = 1,
    progress: Callable[[int, int], None] | None = None,
    judge: StageJudge | None = None,
    bias_judge: StageJudge | None = None,
) -> DarkStacks:
    """The file step of the dark stage: list the frames, group the darks by exposure time, combine each group
    and the bias frames (:func:`camcal.calibrate.stack.combine_frames`), check sizes, patterns and ISO.

    Parameters
    ----------
    dark, bias : folders or the session index's :class:`camcal.calibrate.session.StageFrames`.
    options : the combination method and the saturation limit of the frame check (:func:`dark_frame_check`).
    jobs, progress : as for :func:`camcal.calibrate.stack.combine_frames` (``progress`` counts the frames of all
    stacks).
    judge, bias_judge : the dark and bias stages' :class:`camcal.calibrate.screen.StageJudge`: each frame is judged as
    it
        is stacked, and the rules that follow from what is left out (:func:`_exposure_time_rules`; an exposure
        time whose frames are all left out is as if never taken; every bias frame left out is as without bias
        frames; a bias-only model needs two frames) are applied to the frames used. Without a judge a frame that
        cannot be used is an error (:class:`camcal.calibrate.screen.StrictJudge`), and the exposure-time rules are
        applied to the files before any is decoded.

    Returns
    -------
    DarkStacks

    Raises
    ------
    CamcalError
        Non-RAW or saturated frames, frames of different sizes/patterns/ISO, a single dark
        exposure time without bias frames, fewer than two frames for a bias-only model, missing exposure times.
    """
    if options.method not in METHODS:
        raise CamcalError(f"unknown combination method {options.method!r}; choose from {', '.join(METHODS)}")
    check = dark_frame_check(options.saturation_fraction)
    if dark is None:
        if bias is None:
            raise CamcalError("the dark model needs dark frames, bias frames or both")
        files, manifest = stage_files(bias)
        bias_folder = folder_of(bias)
        st = combine_frames(files, StackOptions("mean", jobs=jobs, keep_frames=QUANTISED_FIT_FRAMES),
                            manifest=manifest, check=check, progress=progress, rule=bias_judge)
        if st.n_frames < 2:
            raise TooFewFrames("bias", "frames (a bias-only calibration measures the read noise between frames)",
                               2, st.n_frames, path=bias_folder)
        _check_stacks([st], bias_folder)
        return DarkStacks((), st, None, bias_folder, (), tuple(p.name for p in st.paths))
    files, manifest = stage_files(dark)
    bias_files, bias_manifest = stage_files(bias) if bias is not None else ([], {})
    refuse_shared_frames(files, bias_files)  # before any frame is left out: a copy is refused, not set aside
    times = _exposure_times(dark, files, manifest)
    dark_folder = folder_of(dark)
    bias_folder = folder_of(bias) if bias is not None else None
    groups: dict[float, list[Path]] = {}
    for p, t in zip(files, times, strict=True):
        groups.setdefault(float(f"{t:.6g}"), []).append(p)
    left_out: tuple[tuple[str, str], ...] = ()
    if judge is None:  # no dark frame is left out by judging: the rules hold for the files, none decoded yet
        groups, left_out = _exposure_time_rules(groups, bias is not None, dark_folder)
    total = sum(len(g) for g in groups.values()) + len(bias_files)
    bias_stack = None
    if bias_files:
        try:
            bias_stack = combine_frames(bias_files, StackOptions("mean", jobs=jobs, keep_frames=QUANTISED_FIT_FRAMES),
                                        manifest=bias_manifest, check=check,
                                        progress=_progress_from(progress, 0, total), rule=bias_judge)
        except TooFewFrames:  # every bias frame left out: as without bias frames
            bias_folder = None
    while True:
        darks: list[tuple[float, StackResult]] = []
        done = len(bias_files)
        superseded = len(judge.superseded) if judge is not None else 0
        for t in sorted(groups):
            # the read-noise stack (the shortest exposure time with two frames or more) keeps its first frames
            keep = QUANTISED_FIT_FRAMES if bias_stack is None and not any(s.n_frames > 1 for _, s in darks) else 0
            try:
                st = combine_frames(groups[t], StackOptions(options.method, options.sigma, jobs, keep_frames=keep,
                                                            statistics=DARK_STATISTICS),
                                    manifest=manifest, check=check, progress=_progress_from(progress, done, total),
                                    rule=judge)
                darks.append((t, st))
            except TooFewFrames:  # every frame at this time left out: as if never taken
                pass
            done += len(groups[t])
        used = {p for _, st in darks for p in st.paths}
        # a copy stacked at one exposure time, its original (first in file order) found at a later one: stacked
        # again with the verdicts fixed (rare: a copy given another exposure time than its original)
        if judge is None or not used & set(judge.superseded[superseded:]):
            break
    if not used:
        n = sum(len(g) for g in groups.values())
        raise TooFewFrames("dark", "frames", 1, 0, f"all {n} left out", dark_folder)
    kept, lone = _exposure_time_rules({t: list(st.paths) for t, st in darks}, bias_folder is not None, dark_folder)
    darks = [(t, st) for t, st in darks if t in kept]
    used = {p for g in kept.values() for p in g}
    _check_stacks([s for _, s in darks] + ([bias_stack] if bias_stack is not None else []), dark_folder)
    return DarkStacks(tuple(darks), bias_stack, dark_folder, bias_folder, tuple(p.name for p in files if p in used),
                      tuple(p.name for p in bias_stack.paths) if bias_stack is not None else (), left_out + lone)



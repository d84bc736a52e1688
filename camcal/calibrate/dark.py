"""The dark model: master bias, read noise, dark current β, defect mask.

Seed eq. 12 writes a pixel value as ``g_i = α_i [...]^γ_i + β_i``; for RAW data the
offset term is ``β_i = bias_i + β_dark,i · t`` (physics notes): a fixed bias (black
level plus a per-pixel pattern) and a dark signal growing linearly with the exposure
time t. This module measures both per pixel and per CFA plane (R, G1, G2, B) from bias
frames (shortest exposure, no light) and dark frames (no light, two or more exposure
times), following EMVA 1288 (release 4.0, §4.3 "dark current", §4.5 "DSNU"):

- **bias** and **dark current**: weighted least squares per pixel of the stacked dark level
  against t, ``dark(t) = bias + β·t``, every stacked level weighted by its frame count.
  With bias frames they enter as one more point at their exposure time; without, the
  black level from the file is a prior point at t = 0 weighted as ``bias_prior_frames``
  frames. β is in DN s⁻¹ at the ISO of the frames.
- **read noise**: the temporal standard deviation in DN of the bias frames (without bias
  frames: of the shortest dark exposure, extrapolated per channel to t = 0 by a line
  through the mean temporal variance against t, EMVA 1288 §4.3 "from the variance"),
  minus the quantisation variance 1/12 DN² (EMVA 1288 eq. 4 σ_q² for integer data). Below
  1 DN of temporal noise that correction is wrong (the pixel means are not spread over whole
  DN), so there the read noise and DSNU come from a quantised-normal likelihood of frame pairs
  (:func:`quantised_noise_fit`); ``temporal_noise_dn`` keeps the recorded standard deviation.
- **DSNU**: the spatial standard deviation of the bias map and of the β map over good
  pixels, with the temporal noise of the estimates removed (EMVA 1288 §4.5).
- **defects** (bit mask): 1 hot (β above the channel median by more than both
  ``hot_sigma`` robust standard deviations and ``(hot_factor - 1)`` medians), 4 noisy
  (temporal variance above the plane's model variance beyond a chi-square bound,
  :func:`temporal_noise`). 2 dead is defined by the response, not by the darks (a pixel that
  reads one value in every dark frame is normal below 1 DN of noise): :func:`camcal.models.flat.dead_pixels`.
- **duplicates**: two frames with identical pixels are refused by content (:mod:`camcal.calibrate.stack`).
- **bias only** (:func:`fit_bias`): bias, read noise, DSNU, noisy pixels; dark current unknown.
"""

from __future__ import annotations

import hashlib
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.special import ndtr
from scipy.stats import chi2

from camcal.calibrate.robust import median, median_and_mad
from camcal.calibrate.screen import StageJudge
from camcal.calibrate.session import StageFrames, folder_of, stage_files
from camcal.calibrate.stack import METHODS, StackOptions, StackResult, combine_frames
from camcal.errors import CamcalError, FrameLeftOut, MissingMetadataError, TooFewFrames
from camcal.frame import Frame
from camcal.io.hashing import sha256_file
from camcal.io.read import exposure_from_exif, saturated_fraction
from camcal.models.dark import DEAD, HOT, NOISY, DarkModel
from camcal.threads import thread_count, thread_map

QUANTISATION_VAR_DN2 = 1.0 / 12.0
"""Variance of rounding to integer DN (EMVA 1288 σ_q²), DN²."""


# --------------------------------------------------------------------------------------------


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


def _same_iso(stacks: list[StackResult], where: Path) -> float:
    isos = {e.require("iso", p) for s in stacks for e, p in zip(s.exposures, s.paths, strict=True)}
    if len(isos) > 1:
        raise CamcalError(f"frames mix ISO settings {sorted(isos)}; take bias and dark frames at one ISO", where)
    return isos.pop()


def _robust(x: np.ndarray) -> tuple[float, float]:
    finite = np.isfinite(x)
    x = x if finite.all() else x[finite]  # not modified below: no copy when every value is finite
    if x.size == 0:
        return float("nan"), float("nan")
    return median_and_mad(x)  # np.median and scipy's normal-scaled MAD, by sampled selection


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
    """The combined frames the dark model is fitted to (made by :func:`stack_darks`).

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
    return _same_iso(stacks, where)


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


def stack_darks(
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


def fit_dark(
    dark_folder: str | Path | StageFrames | None,
    bias_folder: str | Path | StageFrames | None = None,
    *,
    method: str = "sigma_clip",
    sigma: float = 3.0,
    hot_sigma: float = 6.0,
    hot_factor: float = 5.0,
    noisy_sigma: float = 6.0,
    saturation_fraction: float = 0.01,
    bias_prior_frames: float = 1.0,
    jobs: int | None = 1,
    progress: Callable[[int, int], None] | None = None,
) -> DarkModel:
    """Fit the dark model from dark frames (and optionally bias frames): :func:`stack_darks` (files), then
    :func:`fit_dark_stacks` (maths).

    Parameters
    ----------
    dark_folder : folder (or the session index's :class:`camcal.calibrate.session.StageFrames`) of RAW dark
        frames at two or more exposure times (one is enough with bias frames), with an optional
        ``frames.csv`` (``exposure_s``, ``iso``, ``temperature_C``...); None for a bias-only
        calibration (bias, read noise and noisy pixels; the dark current
        is then unknown, ``dark_current_dn_per_s`` None).
    bias_folder : folder of RAW bias frames (shortest exposure, no light), optional.
    method, sigma, hot_sigma, hot_factor, noisy_sigma, saturation_fraction, bias_prior_frames :
        see :class:`DarkOptions`.
    jobs : decoding threads (:func:`camcal.threads.thread_count`).
    progress : ``progress(done, total)`` over all frames.

    Raises
    ------
    CamcalError
        Non-RAW or saturated frames, frames of different sizes/patterns/ISO, a single dark
        exposure time without bias frames, missing exposure times.
    """
    options = DarkOptions(method, sigma, hot_sigma, hot_factor, noisy_sigma, saturation_fraction, bias_prior_frames)
    return fit_dark_stacks(stack_darks(dark_folder, bias_folder, options, jobs=jobs, progress=progress), options)


def fit_dark_stacks(stacks: DarkStacks, options: DarkOptions = DarkOptions(),  # noqa: B008
                    *, jobs: int | None = None) -> DarkModel:
    """Fit the dark model to combined dark (and bias) frames: pure, no file is read.

    Per pixel, level = b + β·t by weighted least squares over the exposure groups (:func:`_fit_lines`; the
    black level as a prior at t = 0 without bias frames); uncertainties from a per-plane photon-transfer
    noise model (EMVA 1288 §4.3); hot pixels from β, noisy pixels and the read noise from the temporal
    noise of the read-noise stack (:func:`temporal_noise`). Without dark stacks, a bias-only model.
    ``jobs``: threads of the per-pixel fit (:func:`camcal.threads.thread_count`; None: the usable cores).
    """
    if not stacks.darks:
        return _fit_bias_stack(stacks.bias, stacks.bias_folder, options)  # type: ignore[arg-type]
    hot_sigma, hot_factor, noisy_sigma = options.hot_sigma, options.hot_factor, options.noisy_sigma
    saturation_fraction, bias_prior_frames = options.saturation_fraction, options.bias_prior_frames
    bias_stack = stacks.bias
    stack_list = list(stacks.darks)
    ref = stack_list[0][1]
    method, sigma = options.method, options.sigma
    iso = _same_iso([s for _, s in stack_list] + ([bias_stack] if bias_stack is not None else []),
                    stacks.dark_folder)  # type: ignore[arg-type]
    black = np.asarray(ref.black_level_dn, np.float64)[:, None, None]
    white = ref.white_level_dn
    # observations (t, level, frames used): the stacks as they are (the band fit reads them in float64); the
    # per-frame variances of the line come from the noise model below
    obs: list[tuple[float, np.ndarray, np.ndarray, None]] = []
    if bias_stack is not None:
        tb = float(np.median([e.exposure_s or 0.0 for e in bias_stack.exposures]))
        obs.append((tb, bias_stack.value, bias_stack.count, None))
    for t, st in stack_list:
        obs.append((t, st.value, st.count, None))
    black_known = bool(getattr(ref, "black_level_known", True))
    if bias_stack is None and black_known:  # the file's black level as a prior point at t = 0 (bias_prior_frames)
        obs.insert(0, (0.0, black, np.float64(bias_prior_frames), None))
    # files that state no black level (PNG, TIFF, FITS): the offset is the dark series' intercept, no prior
    # the maps in float32, as the model stores them (the sums in float64): 0.7 GB less new memory at 24 MP
    beta, _, b, _, _ = _fit_lines(obs, white, with_variance=False, with_count=False, dtype=np.float32, jobs=jobs)
    # Per-pixel temporal variances from 4-16 frames are too noisy to propagate (a t-like tail), so the
    # uncertainties use a noise model per plane instead: var(level) = v0 + g · (level - bias), the
    # photon-transfer line of the dark signal (EMVA 1288 §4.3: dark current from mean and variance),
    # g the system gain in DN per electron, v0 the read-noise variance.
    dark_stats = [(t, st) for t, st in stack_list] + ([(0.0, bias_stack)] if bias_stack is not None else [])
    noise_v0, noise_gain = _noise_model(dark_stats, b, jobs)
    v0_full, g_full = (np.broadcast_to(a, b.shape) for a in (noise_v0, noise_gain))
    black_full = np.broadcast_to(black, b.shape)

    def modelled(level: np.ndarray, idx: tuple) -> np.ndarray:
        """The noise model's per-frame variance of the band's levels, DN²: v0 + g · max(level − bias, 0), the bias
        being the fitted one, the black level where there is no line (per band: no whole-frame copy)."""
        zero_level = b[idx]
        finite = np.isfinite(zero_level)
        if not finite.all():
            zero_level = np.where(finite, zero_level, black_full[idx])
        signal = np.maximum(level - zero_level, 0.0)
        signal *= g_full[idx]
        return v0_full[idx] + signal

    _, beta_var, _, b_var, _ = _fit_lines(obs, white, variance=modelled, with_fit=False, dtype=np.float32,
                                          jobs=jobs)

    # read noise: per-pixel temporal variance of the bias (or shortest dark), quantisation removed
    rn_stack = bias_stack if bias_stack is not None else stack_list[0][1]
    # float32 as stacked: each use converts what it selects to float64 (no whole-stack float64 copy)
    var_t = bias_stack.variance if bias_stack is not None else stack_list[0][1].variance_all
    defects = np.zeros(beta.shape, np.uint8)

    def hot(k: int) -> None:
        med_b, rs_b = _robust(beta[k])
        thresh = med_b + max(hot_sigma * rs_b, (hot_factor - 1.0) * abs(med_b))
        hot_k = np.isfinite(beta[k])  # not finite, or above the threshold: HOT (no int64 product of the plane)
        np.logical_not(hot_k, out=hot_k)
        hot_k |= beta[k] > np.float64(thresh)  # compared in float64, not at the threshold rounded to float32
        np.multiply(hot_k, np.uint8(HOT), out=defects[k])

    _run_planes(hot, beta.shape[0], jobs, beta[0].size)
    noise = temporal_noise(rn_stack, var_t, defects, noisy_sigma, jobs)
    np.bitwise_or(defects, np.uint8(NOISY), out=defects, where=noise.noisy)
    read_noise = noise.read_noise_map_dn
    # pixels without a fit (saturated in all but one group): β lower bound from saturation
    no_fit = ~np.isfinite(beta)
    if np.any(no_fit):  # in place, on those pixels only (no whole-map float64 copies)
        t_min = min(t for t, _ in stack_list)
        b_nf = b[no_fit]
        beta[no_fit] = (white - np.where(np.isfinite(b_nf), b_nf, black_full[no_fit])) / t_min
        no_b = ~np.isfinite(b)
        b[no_b] = black_full[no_b]
        beta_var[no_fit] = np.inf

    channels = _channel_summary(b, b_var, beta, beta_var, var_t, defects, stack_list, bias_stack is not None,
                                noise_gain, noise, ref.channel_names, jobs)
    temps = [e.temperature_c for _, s in stack_list for e in s.exposures]
    temperature = float(np.mean(temps)) if temps and all(t is not None for t in temps) else None
    provenance = {
        "dark_folder": str(stacks.dark_folder),
        "bias_folder": None if stacks.bias_folder is None else str(stacks.bias_folder),
        "dark_files": list(stacks.dark_files),
        "bias_files": list(stacks.bias_files),
        "frames_per_exposure": {f"{t:g}": st.n_frames for t, st in stack_list},
        "temperature_range_c": [min(temps), max(temps)] if temperature is not None else None,
        "options": {"method": method, "sigma": sigma, "hot_sigma": hot_sigma, "hot_factor": hot_factor,
                    "noisy_sigma": noisy_sigma, "saturation_fraction": saturation_fraction,
                    "bias_prior_frames": bias_prior_frames},
        "read_noise_method": noise.method,
        "bias_source": "bias frames" if bias_stack is not None else "fit of dark frames, black level as prior"
        if black_known else "fit of dark frames: intercept at t = 0 (the files state no black level)",
        "black_level_source": "file" if black_known else "unknown (the files state none)",
        "read_noise_source": "bias frames" if bias_stack is not None
        else f"shortest dark ({stack_list[0][0]:g} s), per-plane value extrapolated to t = 0",
    }
    return DarkModel(
        bias_dn=b,  # float32, as fitted
        dark_current_dn_per_s=beta,
        dark_current_unc_dn_per_s=np.sqrt(beta_var, out=beta_var),  # its last use
        read_noise_dn=read_noise,  # float32 already (temporal_noise)
        defects=defects,
        iso=float(iso),
        cfa_pattern=None if ref.cfa_pattern is None else str(ref.cfa_pattern),
        temperature_c=temperature,
        channels=channels,
        exposure_times_s=tuple(float(t) for t, _ in stack_list),
        black_level_dn=tuple(float(x) for x in ref.black_level_dn),
        white_level_dn=float(white),
        provenance=provenance,
    )


#: Below this temporal standard deviation (DN) the quantisation of the data is not a small correction:
#: read noise and DSNU come from a quantised-normal likelihood of frame pairs instead of ``var - 1/12``.
SUB_DN_NOISE = 1.0

#: Frames of the read-noise stack used for the quantised-normal fit (consecutive pairs).
QUANTISED_FIT_FRAMES = 4


@dataclass(frozen=True)
class TemporalNoise:
    """Temporal noise of the read-noise stack (bias frames, or the shortest darks), per plane.

    Attributes
    ----------
    temporal_noise_dn : (C,) standard deviation of the recorded values, DN (quantisation included; the
        per-pixel temporal variance averaged over good pixels, as numpy measures it).
    read_noise_dn : (C,) read noise with the quantisation removed, DN (NaN where not computed here).
    dsnu_dn : (C,) spatial spread of the per-pixel means from the quantised fit, DN (NaN elsewhere).
    quantised : (C,) bool, True where the quantised-normal fit was used (temporal noise < 1 DN).
    noisy : (C, h, w) bool, temporal variance far above the plane's model variance.
    read_noise_map_dn : (C, h, w) float32 per-pixel read noise, DN (computed in float64, stored as the dark
        model stores it).
    method : how the read noise was obtained.
    """

    temporal_noise_dn: np.ndarray
    read_noise_dn: np.ndarray
    dsnu_dn: np.ndarray
    quantised: np.ndarray
    noisy: np.ndarray
    read_noise_map_dn: np.ndarray
    method: str


def quantised_noise_fit(first: np.ndarray, second: np.ndarray, eps: float = 1e-4) -> tuple[float, float, float]:
    """Read noise of integer data below ~1 DN from two frames of one plane (quantised-normal likelihood).

    Each pixel records ``k_f = round(μ + o_f + σ·z_f)`` in frame f: μ its own mean (spread over the plane as a
    normal distribution of standard deviation ``dsnu``), o_f a frame offset (jitter) and z_f standard normal.
    The joint histogram of the pairs (k_1, k_2) is fitted by maximum likelihood of this model (cell
    probabilities integrated exactly over the rounding with the normal CDF :func:`scipy.special.ndtr`, and over μ
    by the trapezoid rule on ±8 dsnu in steps of at most σ/3 at the start values: a fixed Gauss–Hermite rule
    does not resolve the 1 DN cells once dsnu ≫ σ), with a small uniform outlier weight ``eps``, minimised by the
    Nelder–Mead simplex (:func:`scipy.optimize.minimize`, ``method="Nelder-Mead"``). This is right where
    ``var − 1/12`` (Sheppard's correction, EMVA 1288 eq. 4) is not: when σ and the spread of the pixel means are
    both below ~0.5 DN, so that the fractional parts of μ are not uniform (a 10-bit IMX296 at black level 60:
    σ ≈ 0.38 DN, while ``var − 1/12`` gives 0.35–0.38 and the raw temporal standard deviation 0.45–0.48).

    Parameters
    ----------
    first, second : integer arrays of the same pixels (defects removed), DN.

    Returns
    -------
    sigma_dn, dsnu_dn, offset_dn (second − first).
    """
    k1 = np.asarray(first).astype(np.int64).ravel()
    k2 = np.asarray(second).astype(np.int64).ravel()
    lo, hi = np.quantile(np.concatenate([k1, k2]), [2e-4, 1 - 2e-4])
    lo, hi = int(np.floor(lo)), int(np.ceil(hi))
    keep = (k1 >= lo) & (k1 <= hi) & (k2 >= lo) & (k2 <= hi)
    k1, k2 = k1[keep] - lo, k2[keep] - lo
    n = hi - lo + 1
    hist = np.bincount(k1 * n + k2, minlength=n * n).reshape(n, n).astype(np.float64)
    edges = np.arange(n + 1, dtype=np.float64) - 0.5
    m0 = float(k1.mean())
    d = (k2 - k1).astype(np.float64)
    s0 = max(float(np.sqrt(max(d.var() / 2 - 1 / 12, 0.01))), 0.05)
    # the spread of the pair means from their central 95 % (±1.96 standard deviations): far hot pixels, which the
    # outlier weight carries, would otherwise start the fit at a dsnu of tens of DN, in the wrong minimum
    q_lo, q_hi = np.quantile(0.5 * (k1 + k2), [0.025, 0.975])
    spread = float(q_hi - q_lo) / 3.92
    sd0 = max(float(np.sqrt(max(spread**2 - s0**2 / 2 - 1 / 24, 0.0025))), 0.05)
    # μ = m + dsnu·z on z in [-8, 8]: 16·dsnu/(nodes − 1) <= σ/3 at the start; the normal weights are 1e-14 at the
    # ends, so their plain sum is the trapezoid rule
    nodes = np.linspace(-8.0, 8.0, min(max(49, int(np.ceil(48.0 * spread / s0)) + 1), 4001))
    weights = np.exp(-0.5 * nodes**2)
    weights /= weights.sum()

    def nll(p: np.ndarray) -> float:
        m, o, lsd, ls = p
        sd, sg = np.exp(lsd), np.exp(ls)
        mu = m + sd * nodes
        cdf = ndtr(np.stack([(edges[None, :] - mu[:, None]) / sg, (edges[None, :] - (mu[:, None] + o)) / sg]))
        p1, p2 = np.diff(cdf[0], axis=1), np.diff(cdf[1], axis=1)  # one ndtr call: half the numpy overhead
        prob = np.einsum("q,qi,qj->ij", weights, p1, p2)
        prob = (1 - eps) * prob + eps / (n * n)
        return -float(np.sum(hist * np.log(prob)))

    res = minimize(nll, [m0, float(d.mean()), np.log(sd0), np.log(s0)], method="Nelder-Mead",
                   options={"xatol": 1e-5, "fatol": 1e-4, "maxiter": 4000})
    _, o, lsd, ls = res.x
    return float(np.exp(ls)), float(np.exp(lsd)), float(o)


def temporal_noise(stack: StackResult, var_t: np.ndarray, defects: np.ndarray, noisy_sigma: float,
                   jobs: int | None = 1) -> TemporalNoise:
    """Temporal noise, noisy pixels and the read-noise map of the read-noise stack (quantisation-aware).

    Per plane, the model variance v̂ is the mean per-pixel temporal variance over good pixels (the top 0.1 %
    left out). A pixel is *noisy* when its variance exceeds v̂ by more than the chi-square bound a normal pixel
    passes with probability 1e-6 and by ``noisy_sigma`` standard errors of a variance (√(2/dof)); the chi-square
    quantile is ``scipy.stats.chi2.isf``. A zero temporal variance is not a defect: below 1 DN of noise
    most pixels read one value in every frame. Where the temporal noise is below :data:`SUB_DN_NOISE`, the read
    noise is :func:`quantised_noise_fit` of consecutive frame pairs (the first :data:`QUANTISED_FIT_FRAMES`
    frames of the stack, ``stack.kept_planes``), else ``√(var − 1/12)``. The planes run in ``jobs`` threads.
    """
    c = var_t.shape[0]
    dof = float(np.median(stack.count)) - 1.0
    rn_map = np.empty(var_t.shape, np.float32)
    bound = 1.0
    if dof >= 1:
        bound = max(float(chi2.isf(1e-6, dof)) / dof, 1.0 + noisy_sigma * math.sqrt(2.0 / dof))
    temporal = np.zeros(c)
    noisy = np.zeros(var_t.shape, bool)

    def plane(k: int) -> None:
        # in float64 (``var_t`` may be float32 as stacked): converted after the selection, the same values
        v = np.asarray(var_t[k][(defects[k] == 0) & np.isfinite(var_t[k])], np.float64)
        if v.size == 0:
            raise CamcalError(f"plane {stack.channel_names[k]} has no pixel to measure the temporal noise on",
                              stack.paths[0] if stack.paths else None)
        v = v[v <= np.quantile(v, 0.999)] if v.size > 1000 else v
        vhat = float(np.mean(v))
        temporal[k] = math.sqrt(vhat)
        if dof >= 1 and vhat > 0:
            np.greater(var_t[k], np.float64(vhat * bound), out=noisy[k])  # compared in float64
        rn = np.subtract(var_t[k], QUANTISATION_VAR_DN2, dtype=np.float64)  # then max(·, 0) and √ in place
        np.maximum(rn, 0.0, out=rn)
        rn_map[k] = np.sqrt(rn, out=rn)

    _run_planes(plane, c, jobs, var_t[0].size)
    read = np.full(c, np.nan)
    dsnu = np.full(c, np.nan)
    quantised = temporal < SUB_DN_NOISE
    method = "per-pixel temporal variance minus the quantisation variance 1/12 DN² (EMVA 1288 eq. 4)"
    if quantised.any():
        if len(stack.paths) < 2:
            raise CamcalError("the read noise needs two or more frames of one exposure",
                              stack.paths[0] if stack.paths else None)
        frames = list(stack.kept_planes[:QUANTISED_FIT_FRAMES])  # kept by combine_frames: no second decode
        if len(frames) < 2:
            raise ValueError("the read-noise stack must keep its first frames (combine_frames(keep_frames=...))")
        sig = np.zeros((c, len(frames) - 1))
        sds = np.zeros((c, len(frames) - 1))
        for k in np.flatnonzero(quantised):
            good = (defects[k] == 0) & ~noisy[k]
            for j in range(len(frames) - 1):
                sig[k, j], sds[k, j], _ = quantised_noise_fit(frames[j][k][good], frames[j + 1][k][good])
            read[k] = float(np.mean(sig[k]))
            dsnu[k] = float(np.mean(sds[k]))
            rn_map[k] = np.where(noisy[k], rn_map[k], read[k])
        method = (f"quantised-normal likelihood of {len(frames) - 1} frame pair(s) in planes "
                  f"{', '.join(stack.channel_names[k] for k in np.flatnonzero(quantised))} (temporal noise below "
                  f"{SUB_DN_NOISE:g} DN); elsewhere " + method)
    return TemporalNoise(temporal, read, dsnu, quantised, noisy, rn_map, method)


def fit_bias(
    bias_folder: str | Path | StageFrames,
    *,
    hot_sigma: float = 6.0,
    noisy_sigma: float = 6.0,
    saturation_fraction: float = 0.01,
    jobs: int | None = 1,
    progress: Callable[[int, int], None] | None = None,
) -> DarkModel:
    """A bias-only dark model: bias, read noise, DSNU and noisy pixels; dark current unknown (None).

    Two frames are enough. ``hot_sigma`` is recorded but hot pixels need dark frames (their dark
    current), so none are flagged; :mod:`camcal.apply.photo` then subtracts the bias only and says so.
    :func:`stack_darks` (files), then :func:`fit_dark_stacks` (maths).
    """
    options = DarkOptions(hot_sigma=hot_sigma, noisy_sigma=noisy_sigma, saturation_fraction=saturation_fraction)
    return fit_dark_stacks(stack_darks(None, bias_folder, options, jobs=jobs, progress=progress), options)


def _fit_bias_stack(st: StackResult, bias_folder: Path | None, options: DarkOptions) -> DarkModel:
    """The bias-only model of averaged bias frames (see :func:`fit_bias`); pure."""
    hot_sigma, noisy_sigma, saturation_fraction = options.hot_sigma, options.noisy_sigma, options.saturation_fraction
    files = st.paths
    iso = _same_iso([st], bias_folder)  # type: ignore[arg-type]
    var_t = st.variance  # float32 as stacked; converted to float64 where used
    defects = np.zeros(var_t.shape, np.uint8)
    noise = temporal_noise(st, var_t, defects, noisy_sigma)
    np.bitwise_or(defects, np.uint8(NOISY), out=defects, where=noise.noisy)
    b = np.asarray(st.value, np.float64)
    n = np.maximum(np.asarray(st.count, np.float64), 1.0)
    channels = {}
    for k, name in enumerate(st.channel_names):
        good = defects[k] == 0
        bk = b[k][good]
        if noise.quantised[k]:
            rn, dsnu = float(noise.read_noise_dn[k]), float(noise.dsnu_dn[k])
        else:
            rn = math.sqrt(max(float(np.mean(np.asarray(var_t[k][good], np.float64))) - QUANTISATION_VAR_DN2, 0.0))
            dsnu = math.sqrt(max(float(np.var(bk)) - float(np.mean((var_t[k] / n[k])[good])), 0.0))
        channels[name] = {
            "bias_dn": float(np.mean(bk)),  # the mean: a median of quantised levels sticks to half DN
            "bias_unc_dn": float(1.2533 * np.std(bk) / np.sqrt(bk.size)),
            "dark_current_dn_per_s": None,
            "dark_current_unc_dn_per_s": None,
            "dark_current_pixel_unc_dn_per_s": None,
            "dark_current_mean_dn_per_s": None,
            "read_noise_dn": rn,
            "temporal_noise_dn": float(noise.temporal_noise_dn[k]),
            "dsnu_bias_dn": dsnu,
            "dsnu_dark_current_dn_per_s": None,
            "gain_dn_per_e_from_dark": 0.0,
            "hot_pixel_count": 0,
            "dead_pixel_count": 0,
            "noisy_pixel_count": int(np.count_nonzero(defects[k] & NOISY)),
        }
    tb = [e.exposure_s for e in st.exposures]
    return DarkModel(
        bias_dn=b.astype(np.float32), dark_current_dn_per_s=None, dark_current_unc_dn_per_s=None,
        read_noise_dn=noise.read_noise_map_dn, defects=defects, iso=float(iso),
        cfa_pattern=None if st.cfa_pattern is None else str(st.cfa_pattern), temperature_c=None, channels=channels,
        exposure_times_s=tuple(sorted({float(t) for t in tb if t is not None})),
        black_level_dn=tuple(float(x) for x in st.black_level_dn), white_level_dn=float(st.white_level_dn),
        provenance={
            "dark_folder": None, "bias_folder": str(bias_folder), "dark_files": [],
            "bias_files": [p.name for p in files], "frames_per_exposure": {},
            "options": {"hot_sigma": hot_sigma, "noisy_sigma": noisy_sigma,
                        "saturation_fraction": saturation_fraction},
            "bias_source": "bias frames", "read_noise_source": "bias frames",
            "read_noise_method": noise.method,
            "dark_current": "unknown: no dark frames (bias-only calibration); apply subtracts the bias only",
        },
    )


FIT_BAND_PIXELS = 1 << 16
"""Pixels per band of the per-pixel line fit (its float64 temporaries are 512 kB each).

A band takes about 60 numpy calls, and each one releases and takes back the GIL: with smaller bands two threads
spend their time handing the GIL to each other, and larger ones are no faster (benchmarks/RESULTS.md,
"calibrate")."""


def _band_index(shape: tuple[int, ...]) -> list[tuple]:
    """Index tuples cutting an array of ``shape`` into bands of about :data:`FIT_BAND_PIXELS` pixels (row bands of
    each plane of a (C, h, w) array; runs of a 1-D array; the whole array otherwise)."""
    if len(shape) == 0:
        return [()]
    if len(shape) == 1:
        return [(slice(i, i + FIT_BAND_PIXELS),) for i in range(0, shape[0], FIT_BAND_PIXELS)]
    if len(shape) > 3:
        return [(Ellipsis,)]
    rows = max(1, FIT_BAND_PIXELS // max(1, shape[-1]))
    return [(*lead, slice(y0, y0 + rows)) for lead in np.ndindex(*shape[:-2]) for y0 in range(0, shape[-2], rows)]


def _run_bands(one: Callable[[tuple], None], shape: tuple[int, ...], jobs: int | None) -> None:
    """Call ``one(index)`` for every band of ``shape`` (:func:`_band_index`), in ``jobs`` threads
    (:func:`camcal.threads.thread_count`; numpy releases the GIL in its element-wise loops)."""
    bands = _band_index(shape)
    thread_map(one, bands, thread_count(jobs, len(bands), int(np.prod(shape))), "camcal-dark-fit")


def _fit_lines(obs, white: float, *, variance: Callable[[np.ndarray, tuple], np.ndarray] | None = None,
               with_variance: bool = True, with_fit: bool = True, with_count: bool = True,
               dtype: type[np.floating] = np.float64, jobs: int | None = 1):
    """Per-pixel weighted least squares of level = b + β·t (weights = frames used).

    ``obs`` is a list of ``(t_s, level_dn, n_frames, per_frame_variance_dn2)`` (arrays broadcastable to one
    shape, that of the levels); levels at or above ``white - 1`` (saturated) get zero weight.
    Returns β, var(β), b, var(b), and the number of exposure times with non-zero weight; β and b are NaN where
    fewer than two remain. Uncertainties propagate the temporal variances: var(β) = Σ a_k² σ_k²/n_k with
    a_k = n_k (t_k - t̄) / Σ n (t - t̄)² (linear least squares, e.g. Bevington & Robinson §6).

    ``variance(level_band, index)``, when given, replaces the per-frame variances (a noise model of the band's
    levels; the observations' own variances may then be None). ``with_variance=False`` skips the uncertainties
    (var(β) and var(b) are returned as None), ``with_fit=False`` the line itself (β, b and the number of exposure
    times are None), ``with_count=False`` the number of exposure times alone (None).

    ``dtype``: that of the returned maps. The sums and the formulas run in float64 whatever it is; float32 maps
    round each result once, as the dark model stores them, and take half the memory (a float64 map is 192 MB at
    24 MP).

    The closed-form sums run over row bands of about :data:`FIT_BAND_PIXELS` pixels in ``jobs`` threads, in
    float64 with the operations of the whole-array formulas in the same order: the result does not depend on
    the banding or the number of threads (every value is bit-identical). A band whose levels are all below
    saturation and whose weights are all positive (the usual band) skips the masking of the weights; its values
    are the same.
    """
    shape = np.broadcast_shapes(*(np.shape(y) for _, y, _, _ in obs))
    obs = [(t, np.broadcast_to(y, shape), np.broadcast_to(n, shape), None if v is None else np.broadcast_to(v, shape))
           for t, y, n, v in obs]
    beta = np.empty(shape, dtype) if with_fit else None
    b = np.empty(shape, dtype) if with_fit else None
    n_times = np.empty(shape, np.int16) if with_fit and with_count else None
    beta_var = np.empty(shape, dtype) if with_variance else None
    b_var = np.empty(shape, dtype) if with_variance else None

    def one(idx: tuple) -> None:
        ys, ws, used = [], [], []
        s = st = stt = sy = sty = cnt = None
        for t, y, n, _v in obs:
            yb = np.asarray(y[idx], np.float64)
            w = np.asarray(n[idx], np.float64)
            if float(yb.max()) < white - 1.0 and float(w.min()) > 0:
                pos = None  # every level of the band below saturation, every weight positive (the usual band)
            else:
                w = np.where(yb < white - 1.0, w, 0.0)
                pos = w > 0
            ys.append(yb)
            ws.append(w)
            used.append(pos)
            if s is None:
                s, st, stt, sy, sty = (np.zeros(w.shape) for _ in range(5))
                cnt = np.zeros(w.shape, np.int16)
            s += w
            wt = w * t
            st += wt
            cnt += 1 if pos is None else pos
            if with_fit:
                sy += w * yb
                sty += wt * yb
            wt *= t
            stt += wt
        with np.errstate(invalid="ignore", divide="ignore"):
            d = s * stt - st * st
            ok = (cnt >= 2) & (d > 0)
            every = bool(ok.all())  # the usual band: a line for every pixel, nothing to set to NaN
            if with_fit:
                bb = (s * sty - st * sy) / d
                if not every:
                    bb = np.where(ok, bb, np.nan)
                beta[idx] = bb
                bi = (sy - bb * st) / s
                b[idx] = bi if every else np.where(ok, bi, np.nan)
                if n_times is not None:
                    n_times[idx] = cnt
            if not with_variance:
                return
            tbar = st / s
            sxx = d / s
            bv = np.zeros(s.shape)
            cv = np.zeros(s.shape)
            for (t, _y, _n, v), yb, w, pos in zip(obs, ys, ws, used, strict=True):
                a = w * (t - tbar)
                a /= sxx
                c = w / s
                c -= tbar * a
                vb = variance(yb, idx) if variance is not None else np.asarray(v[idx], np.float64)
                per = vb / w if pos is None else np.where(pos, vb / np.where(pos, w, 1.0), 0.0)
                a *= a
                a *= per
                bv += a
                c *= c
                c *= per
                cv += c
        beta_var[idx] = bv if every else np.where(ok, bv, np.nan)
        b_var[idx] = cv if every else np.where(ok, cv, np.nan)

    _run_bands(one, shape, jobs)
    return beta, beta_var, b, b_var, n_times


def _noise_model(stats: list[tuple[float, StackResult]], b: np.ndarray,
                 jobs: int | None = 1) -> tuple[np.ndarray, np.ndarray]:
    """Per-plane line ``variance = v0 + g · signal`` through the stacks' mean dark signal and variance.

    Returns v0 (DN²) and g (DN per electron), both shaped (C, 1, 1). Pixels more than 5x the
    median variance (hot, noisy) are left out of the plane means. The planes run in ``jobs`` threads.
    """
    c = b.shape[0]
    v0 = np.zeros((c, 1, 1))
    g = np.zeros((c, 1, 1))

    def plane(k: int) -> None:
        xs, ys = [], []
        b_ok = np.isfinite(b[k])
        for _t, st in stats:
            var = (st.variance_all if st.variance_all is not None else st.variance)[k]  # float32 as stacked
            ok = np.isfinite(var) & b_ok
            # hot and noisy pixels out: above 5x the median, or (quantised data below 1 DN of noise, whose
            # median variance is often 0) above 5x the mean; the means and the median in float64
            v = np.asarray(var[ok], np.float64)  # in raster order; _max_median_mean keeps that order
            thr = np.float64(5 * _max_median_mean(v))
            below = v < thr  # compared in float64, as ``var < thr`` promotes the float32 variances
            ok &= var < thr
            if not ok.any():
                raise CamcalError(f"the dark frames at {_t:g} s show no temporal noise at all",
                                  st.paths[0].parent if st.paths else None)
            # plane means over the kept pixels as masked float64 sums: no whole-plane float64 copy (48 MB at 24 MP)
            xs.append(float((np.sum(st.value[k], where=ok, dtype=np.float64)
                             - np.sum(b[k], where=ok, dtype=np.float64))
                            / np.count_nonzero(ok)))
            ys.append(float(np.mean(v, where=below)))  # the values of var[ok] below the cut
        if len(xs) >= 2 and np.ptp(xs) > 0:
            slope, icpt = np.polyfit(xs, ys, 1)
            g[k], v0[k] = max(slope, 0.0), max(icpt, 1e-6)
        else:
            v0[k] = max(ys[0], 1e-6)

    _run_planes(plane, c, jobs, b[0].size)
    return v0, g


def _max_median_mean(x: np.ndarray) -> float:
    """``max(median(x), mean(x))`` of a 1-D float64 array (``x`` is not modified).

    When at least ``n // 2 + 1`` values lie at or below the mean, both middle order statistics do, so the median
    is at most the mean and the maximum is the mean: one comparison instead of a selection (a skewed variance
    distribution, the usual case, takes this path). Otherwise :func:`numpy.median`. Exact either way.
    """
    mean = float(np.mean(x))
    if np.count_nonzero(x <= mean) >= x.size // 2 + 1:
        return mean
    return max(float(median(x)), mean)


def _run_planes(one: Callable[[int], object], c: int, jobs: int | None, plane_pixels: int) -> list:
    """``[one(k) for k in range(c)]`` in ``jobs`` threads (:func:`camcal.threads.thread_count`), in plane order."""
    return thread_map(one, range(c), thread_count(jobs, c, plane_pixels), "camcal-dark-plane")


def _channel_summary(b, b_var, beta, beta_var, var_t, defects, stacks, have_bias: bool, gain,
                     noise: TemporalNoise, names: tuple[str, ...], jobs: int | None = 1) -> dict:
    """Per-plane figures of the dark model (the planes in ``jobs`` threads)."""

    def plane(k: int) -> dict:
        good = defects[k] == 0
        # float32 maps: every mean and variance below in float64, and β's median and MAD of its values in float64
        bk, betak = b[k][good], np.asarray(beta[k][good], np.float64)
        med_beta, rs_beta = _robust(betak)
        if noise.quantised[k]:
            rn_var = float(noise.read_noise_dn[k]) ** 2
        elif have_bias:
            rn_var = float(np.mean(np.asarray(var_t[k][good], np.float64))) - QUANTISATION_VAR_DN2
        else:
            # EMVA 1288: temporal dark variance grows linearly with t; extrapolate its plane mean to t = 0
            ts = np.array([t for t, _ in stacks])
            vs = np.array([float(np.mean(np.asarray(s.variance_all[k][good], np.float64))) for _, s in stacks])
            rn_var = float(np.polyfit(ts, vs, 1)[1]) if ts.size >= 2 else float(vs[0])
            rn_var -= QUANTISATION_VAR_DN2
        var_bk = np.var(bk, dtype=np.float64)  # np.std(bk) is its square root
        dsnu_bias2 = float(var_bk) - float(np.mean(b_var[k][good], dtype=np.float64))
        if noise.quantised[k]:
            dsnu_bias2 = float(noise.dsnu_dn[k]) ** 2
        beta_var_k = beta_var[k][good]  # a copy: its square roots are taken in place for their median
        dsnu_beta2 = float(np.var(betak)) - float(np.mean(beta_var_k, dtype=np.float64))
        return {
            "bias_dn": float(np.mean(bk, dtype=np.float64)),  # the mean: a median of quantised levels sticks to half DN
            "bias_unc_dn": float(1.2533 * np.sqrt(var_bk) / np.sqrt(bk.size)),
            "dark_current_dn_per_s": med_beta,
            "dark_current_unc_dn_per_s": float(1.2533 * rs_beta / np.sqrt(betak.size)),
            "dark_current_pixel_unc_dn_per_s": float(median(np.sqrt(beta_var_k, out=beta_var_k))),
            "dark_current_mean_dn_per_s": float(np.mean(betak)),
            "read_noise_dn": float(np.sqrt(max(rn_var, 0.0))),
            "temporal_noise_dn": float(noise.temporal_noise_dn[k]),
            "dsnu_bias_dn": float(np.sqrt(max(dsnu_bias2, 0.0))),
            "dsnu_dark_current_dn_per_s": float(np.sqrt(max(dsnu_beta2, 0.0))),
            "gain_dn_per_e_from_dark": float(gain[k, 0, 0]),
            "hot_pixel_count": int(np.count_nonzero(defects[k] & HOT)),
            "dead_pixel_count": int(np.count_nonzero(defects[k] & DEAD)),
            "noisy_pixel_count": int(np.count_nonzero(defects[k] & NOISY)),
        }

    return dict(zip(names, _run_planes(plane, len(names), jobs, b[0].size), strict=True))


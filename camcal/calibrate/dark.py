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
- **bias only** (a measurement without darks): bias, read noise, DSNU, noisy pixels; dark current unknown.

The stage's two calls: :func:`camcal.calibrate.dark_frames.measure_dark` (the files: frames grouped by exposure
time and stacked) and :func:`fit_dark` (this module: pure, stacks in, model out); the temporal noise is
:mod:`camcal.calibrate.dark_noise`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from camcal.calibrate.dark_frames import DarkOptions, DarkStacks, same_iso
from camcal.calibrate.dark_noise import QUANTISATION_VAR_DN2, TemporalNoise, noise_model, run_planes, temporal_noise
from camcal.calibrate.robust import median, median_and_mad
from camcal.calibrate.stack import StackResult
from camcal.models.dark import DEAD, HOT, NOISY, DarkModel
from camcal.threads import thread_count, thread_map


def _robust(x: np.ndarray) -> tuple[float, float]:
    finite = np.isfinite(x)
    x = x if finite.all() else x[finite]  # not modified below: no copy when every value is finite
    if x.size == 0:
        return float("nan"), float("nan")
    return median_and_mad(x)  # np.median and scipy's normal-scaled MAD, by sampled selection


def fit_dark(stacks: DarkStacks, options: DarkOptions = DarkOptions(),  # noqa: B008
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
    iso = same_iso([s for _, s in stack_list] + ([bias_stack] if bias_stack is not None else []),
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
    noise_v0, noise_gain = noise_model(dark_stats, b, jobs)
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

    run_planes(hot, beta.shape[0], jobs, beta[0].size)
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

def _fit_bias_stack(st: StackResult, bias_folder: Path | None, options: DarkOptions) -> DarkModel:
    """The bias-only model of averaged bias frames (:func:`fit_dark` of a measurement without darks); pure."""
    hot_sigma, noisy_sigma, saturation_fraction = options.hot_sigma, options.noisy_sigma, options.saturation_fraction
    files = st.paths
    iso = same_iso([st], bias_folder)  # type: ignore[arg-type]
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

    return dict(zip(names, run_planes(plane, len(names), jobs, b[0].size), strict=True))


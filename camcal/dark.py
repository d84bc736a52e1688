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
  frames. β is in DN/s at the ISO of the frames.
- **read noise**: the temporal standard deviation in DN of the bias frames (without bias
  frames: of the shortest dark exposure, extrapolated per channel to t = 0 by a line
  through the mean temporal variance against t, EMVA 1288 §4.3 "from the variance"),
  minus the quantisation variance 1/12 DN² (EMVA 1288 eq. 4 σ_q² for integer data).
- **DSNU**: the spatial standard deviation of the bias map and of the β map over good
  pixels, with the temporal noise of the estimates removed (EMVA 1288 §4.5).
- **defects** (bit mask): 1 hot (β above the channel median by more than both
  ``hot_sigma`` robust standard deviations and ``(hot_factor - 1)`` medians), 2 dead
  (stuck: temporal sigma below ``dead_fraction`` of the channel median), 4 noisy
  (temporal sigma above the median by ``noisy_sigma`` robust standard deviations).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from camcal.errors import CamcalError
from camcal.frame import PLANES, Frame
from camcal.io import exposure_from_exif, folder_files
from camcal.stack import MAD_TO_SIGMA, METHODS, StackResult, combine_frames

HOT, DEAD, NOISY = 1, 2, 4
"""Bits of :attr:`DarkModel.defects`."""

QUANTISATION_VAR_DN2 = 1.0 / 12.0
"""Variance of rounding to integer DN (EMVA 1288 σ_q²), DN²."""

KIND = "dark"
_MAPS = ("bias", "dark_current", "dark_current_unc", "read_noise", "defects")


@dataclass(frozen=True, eq=False)
class DarkModel:
    """Dark model of one camera at one ISO (planes R, G1, G2, B, half resolution).

    Attributes
    ----------
    bias_dn : (4, h, w) float32
        Master bias in DN, black level included (the intercept at t = 0).
    dark_current_dn_per_s : (4, h, w) float32
        Dark current β in DN/s at :attr:`iso`.
    dark_current_unc_dn_per_s : (4, h, w) float32
        Standard uncertainty of β per pixel, DN/s.
    read_noise_dn : (4, h, w) float32
        Temporal standard deviation of the dark signal in DN (quantisation removed).
    defects : (4, h, w) uint8
        Bit mask: 1 hot, 2 dead (stuck), 4 noisy.
    iso : float
        ISO of the frames.
    cfa_pattern : str
    temperature_c : float or None
        Mean temperature of the dark frames, degC (``temperature_C`` column), when known.
    channels : dict
        Per-plane summary numbers (see :meth:`summary`).
    exposure_times_s : tuple of float
        Dark exposure times used, s.
    black_level_dn : tuple of float
        Black level per plane from the files, DN.
    white_level_dn : float
        Saturation level, DN.
    provenance : dict
        Files, folders and options.
    """

    bias_dn: np.ndarray
    dark_current_dn_per_s: np.ndarray
    dark_current_unc_dn_per_s: np.ndarray
    read_noise_dn: np.ndarray
    defects: np.ndarray
    iso: float
    cfa_pattern: str
    temperature_c: float | None
    channels: dict = field(default_factory=dict)
    exposure_times_s: tuple[float, ...] = ()
    black_level_dn: tuple[float, ...] = ()
    white_level_dn: float = float("nan")
    provenance: dict = field(default_factory=dict)

    def dark_frame_dn(self, exposure_s: float, iso: float | None = None) -> np.ndarray:
        """Expected dark frame ``bias + β·t`` (seed eq. 12 β term), (4, h, w) DN.

        β scales with the gain, so with ``iso`` it is multiplied by ``iso / self.iso``;
        the bias (black level) does not change with ISO.
        """
        if not np.isfinite(exposure_s) or exposure_s < 0:
            raise CamcalError(f"exposure time must be a non-negative number of seconds, got {exposure_s}")
        scale = 1.0 if iso is None else float(iso) / self.iso
        return (self.bias_dn + self.dark_current_dn_per_s * np.float32(exposure_s * scale)).astype(np.float32)

    def summary(self) -> dict:
        """JSON-ready summary: per-plane numbers and defect counts."""
        per = {key: {p: self.channels[p][key] for p in PLANES} for key in next(iter(self.channels.values()))}
        for key in ("hot_pixel_count", "dead_pixel_count", "noisy_pixel_count"):
            per[key.replace("_count", "_count_per_plane")] = per.pop(key)
        return {
            "iso": self.iso,
            "cfa_pattern": self.cfa_pattern,
            "temperature_c": self.temperature_c,
            "exposure_times_s": list(self.exposure_times_s),
            "plane_shape": list(self.bias_dn.shape[1:]),
            **per,
            "hot_pixel_count": int(np.count_nonzero(self.defects & HOT)),
            "dead_pixel_count": int(np.count_nonzero(self.defects & DEAD)),
            "noisy_pixel_count": int(np.count_nonzero(self.defects & NOISY)),
            "defect_fraction": float(np.count_nonzero(self.defects) / self.defects.size),
        }


# --------------------------------------------------------------------------------------------


def _exposure_time(path: Path, manifest: dict) -> float:
    """Exposure time from the manifest row, else from the file's EXIF header (no decode)."""
    row = manifest.get(path.name) or {}
    t = row.get("exposure_s")
    if t is None:
        t = exposure_from_exif(path).exposure_s
    if t is None:
        from camcal.errors import MissingMetadataError

        raise MissingMetadataError(path, "exposure_s")
    return float(t)


def _files(folder: Path) -> tuple[list[Path], dict]:
    return folder_files(folder)


def dark_frame_check(saturation_fraction: float = 0.01) -> Callable[[Frame], None]:
    """Per-frame check for bias/dark frames: RAW only, not saturated."""

    def check(frame: Frame) -> None:
        if frame.kind != "raw":
            raise CamcalError("bias and dark frames must be RAW files (the dark model works on CFA planes)",
                              frame.path)
        white = frame.white_level_dn
        frac = float(np.count_nonzero(frame.data >= white)) / frame.data.size
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
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan")
    med = float(np.median(x))
    return med, MAD_TO_SIGMA * float(np.median(np.abs(x - med)))


def fit_dark(
    dark_folder: str | Path,
    bias_folder: str | Path | None = None,
    *,
    method: str = "sigma_clip",
    sigma: float = 3.0,
    hot_sigma: float = 6.0,
    hot_factor: float = 5.0,
    noisy_sigma: float = 6.0,
    dead_fraction: float = 0.25,
    saturation_fraction: float = 0.01,
    bias_prior_frames: float = 1.0,
    jobs: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> DarkModel:
    """Fit the dark model from a folder of dark frames (and optionally bias frames).

    Parameters
    ----------
    dark_folder : folder of RAW dark frames at two or more exposure times (one is enough
        with bias frames), with an optional ``frames.csv`` (``exposure_s``, ``iso``,
        ``temperature_C``...).
    bias_folder : folder of RAW bias frames (shortest exposure, no light), optional.
    method : how each exposure group of darks is combined (:func:`camcal.stack.combine_frames`);
        bias frames are always averaged (``mean``) so their variance is the full temporal variance.
    sigma : sigma-clipping threshold.
    hot_sigma, hot_factor : hot if β > median + max(hot_sigma · robust σ_β, (hot_factor - 1) · median).
    noisy_sigma : noisy if temporal σ > median + noisy_sigma · robust spread of σ (and above the
        chi-square bound a normal pixel exceeds with probability 1e-6, for the number of frames).
    dead_fraction : dead (stuck) if temporal σ < dead_fraction · median σ (and below the 1e-6
        chi-square bound).
    saturation_fraction : a frame with more than this fraction of pixels at the white level is refused.
    bias_prior_frames : weight, in frames, of the black-level prior at t = 0 (no bias frames only).
    jobs : 1 or 2 (decode pool and band threads).
    progress : ``progress(done, total)`` over all frames.

    Raises
    ------
    CamcalError
        Non-RAW or saturated frames, frames of different sizes/patterns/ISO, a single dark
        exposure time without bias frames, missing exposure times.
    """
    if method not in METHODS:
        raise CamcalError(f"unknown combination method {method!r}; choose from {', '.join(METHODS)}")
    dark_folder = Path(dark_folder)
    files, manifest = _files(dark_folder)
    times = [_exposure_time(p, manifest) for p in files]
    groups: dict[float, list[Path]] = {}
    for p, t in zip(files, times, strict=True):
        groups.setdefault(float(f"{t:.6g}"), []).append(p)
    bias_files, bias_manifest = _files(Path(bias_folder)) if bias_folder is not None else ([], {})
    if bias_folder is None and len(groups) < 2:
        (t0,) = groups
        raise CamcalError(f"all {len(files)} dark frames have one exposure time ({t0:g} s); the dark-current fit "
                          "needs two or more exposure times, or bias frames (--bias)", dark_folder)
    total = len(files) + len(bias_files)
    done = [0]

    def sub_progress(offset: int) -> Callable[[int, int], None] | None:
        if progress is None:
            return None

        def cb(i: int, _n: int) -> None:
            progress(offset + i, total)

        return cb

    check = dark_frame_check(saturation_fraction)
    bias_stack = None
    if bias_files:
        bias_stack = combine_frames(bias_files, method="mean", manifest=bias_manifest, check=check, jobs=jobs,
                                    progress=sub_progress(0))
        done[0] = len(bias_files)
    stacks: list[tuple[float, StackResult]] = []
    for t in sorted(groups):
        st = combine_frames(groups[t], method=method, sigma=sigma, manifest=manifest, check=check, jobs=jobs,
                            progress=sub_progress(done[0]))
        done[0] += len(groups[t])
        stacks.append((t, st))
    ref = stacks[0][1]
    for st in [s for _, s in stacks] + ([bias_stack] if bias_stack is not None else []):
        if st.frame_shape != ref.frame_shape or st.cfa_pattern != ref.cfa_pattern:
            h, w = st.frame_shape
            h0, w0 = ref.frame_shape
            raise CamcalError(f"frame size {w}x{h} ({st.cfa_pattern}) differs from the first dark frame's "
                              f"{w0}x{h0} ({ref.cfa_pattern})", st.paths[0])
    iso = _same_iso([s for _, s in stacks] + ([bias_stack] if bias_stack is not None else []), dark_folder)

    black = np.asarray(ref.black_level_dn, np.float64)[:, None, None]
    white = ref.white_level_dn
    # observations (t, level, frames used, per-frame temporal variance)
    obs: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []
    if bias_stack is not None:
        tb = float(np.median([e.exposure_s or 0.0 for e in bias_stack.exposures]))
        obs.append((tb, bias_stack.value, bias_stack.count, bias_stack.variance))
    for t, st in stacks:
        obs.append((t, st.value, st.count, st.variance))
    # fill missing variances (single frames) with the channel median of the group
    filled = []
    for t, y, n, v in obs:
        v = np.asarray(v, np.float64)
        if not np.all(np.isfinite(v)):
            med = np.array([np.nanmedian(c) if np.any(np.isfinite(c)) else 0.0 for c in v])[:, None, None]
            v = np.where(np.isfinite(v), v, med)
        filled.append((t, np.asarray(y, np.float64), np.asarray(n, np.float64), v))
    if bias_stack is None:
        v0 = np.array([np.median(c) for c in filled[0][3]])[:, None, None]
        prior_n = np.full(ref.value.shape, bias_prior_frames, np.float64)
        filled.insert(0, (0.0, np.broadcast_to(black, ref.value.shape), prior_n,
                          np.broadcast_to(v0, ref.value.shape)))
    beta, _, b, _, n_times = _fit_lines(filled, white)
    # Per-pixel temporal variances from 4-16 frames are too noisy to propagate (a t-like tail), so the
    # uncertainties use a noise model per plane instead: var(level) = v0 + g · (level - bias), the
    # photon-transfer line of the dark signal (EMVA 1288 §4.3: dark current from mean and variance),
    # g the system gain in DN per electron, v0 the read-noise variance.
    dark_stats = [(t, st) for t, st in stacks] + ([(0.0, bias_stack)] if bias_stack is not None else [])
    noise_v0, noise_gain = _noise_model(dark_stats, b)
    modelled = []
    for t, y, n, _v in filled:
        signal = np.maximum(y - np.where(np.isfinite(b), b, black), 0.0)
        modelled.append((t, y, n, noise_v0 + noise_gain * signal))
    _, beta_var, _, b_var, _ = _fit_lines(modelled, white)

    # read noise: per-pixel temporal variance of the bias (or shortest dark), quantisation removed
    if bias_stack is not None:
        var_t = np.asarray(bias_stack.variance, np.float64)
    else:
        var_t = np.asarray(stacks[0][1].variance_all, np.float64)
    read_noise = np.sqrt(np.maximum(var_t - QUANTISATION_VAR_DN2, 0.0))

    # defects
    from scipy.stats import chi2

    defects = np.zeros(beta.shape, np.uint8)
    sigma_t = np.sqrt(var_t)
    dof = float(np.median((bias_stack or stacks[0][1]).count)) - 1.0
    # a normal pixel's sample sigma lies within these factors of the true one but for ~1e-6 of pixels
    lo_factor = float(np.sqrt(chi2.ppf(1e-6, dof) / dof)) if dof >= 1 else 0.0
    hi_factor = float(np.sqrt(chi2.isf(1e-6, dof) / dof)) if dof >= 1 else np.inf
    for k in range(beta.shape[0]):
        med_b, rs_b = _robust(beta[k])
        thresh = med_b + max(hot_sigma * rs_b, (hot_factor - 1.0) * abs(med_b))
        hot = ~np.isfinite(beta[k]) | (beta[k] > thresh)
        med_s, rs_s = _robust(sigma_t[k])
        noisy = sigma_t[k] > max(med_s + noisy_sigma * rs_s, hi_factor * med_s)
        dead = sigma_t[k] < min(dead_fraction, lo_factor) * med_s
        defects[k] = hot * HOT | dead * DEAD | noisy * NOISY
    # pixels without a fit (saturated in all but one group): β lower bound from saturation
    no_fit = ~np.isfinite(beta)
    if np.any(no_fit):
        t_min = min(t for t, _ in stacks)
        beta = np.where(no_fit, (white - np.where(np.isfinite(b), b, black)) / t_min, beta)
        b = np.where(np.isfinite(b), b, np.broadcast_to(black, b.shape))
        beta_var = np.where(no_fit, np.inf, beta_var)

    channels = _channel_summary(b, b_var, beta, beta_var, var_t, defects, stacks, bias_stack is not None,
                                noise_gain)
    temps = [e.temperature_c for _, s in stacks for e in s.exposures]
    temperature = float(np.mean(temps)) if temps and all(t is not None for t in temps) else None
    provenance = {
        "dark_folder": str(dark_folder),
        "bias_folder": None if bias_folder is None else str(bias_folder),
        "dark_files": [p.name for p in files],
        "bias_files": [p.name for p in bias_files],
        "frames_per_exposure": {f"{t:g}": len(groups[t]) for t in sorted(groups)},
        "temperature_range_c": [min(temps), max(temps)] if temperature is not None else None,
        "options": {"method": method, "sigma": sigma, "hot_sigma": hot_sigma, "hot_factor": hot_factor,
                    "noisy_sigma": noisy_sigma, "dead_fraction": dead_fraction,
                    "saturation_fraction": saturation_fraction, "bias_prior_frames": bias_prior_frames},
        "bias_source": "bias frames" if bias_stack is not None else "fit of dark frames, black level as prior",
        "read_noise_source": "bias frames" if bias_stack is not None
        else f"shortest dark ({stacks[0][0]:g} s), per-plane value extrapolated to t = 0",
    }
    return DarkModel(
        bias_dn=b.astype(np.float32),
        dark_current_dn_per_s=beta.astype(np.float32),
        dark_current_unc_dn_per_s=np.sqrt(beta_var).astype(np.float32),
        read_noise_dn=read_noise.astype(np.float32),
        defects=defects,
        iso=float(iso),
        cfa_pattern=str(ref.cfa_pattern),
        temperature_c=temperature,
        channels=channels,
        exposure_times_s=tuple(float(t) for t, _ in stacks),
        black_level_dn=tuple(float(x) for x in ref.black_level_dn),
        white_level_dn=float(white),
        provenance=provenance,
    )


def _fit_lines(obs, white: float):
    """Per-pixel weighted least squares of level = b + β·t (weights = frames used).

    ``obs`` is a list of ``(t_s, level_dn, n_frames, per_frame_variance_dn2)``; levels at or
    above ``white - 1`` (saturated) get zero weight. Returns β, var(β), b, var(b), and the
    number of exposure times with non-zero weight; β and b are NaN where fewer than two remain.
    Uncertainties propagate the temporal variances: var(β) = Σ a_k² σ_k²/n_k with
    a_k = n_k (t_k - t̄) / Σ n (t - t̄)² (linear least squares, e.g. Bevington & Robinson §6).
    """
    shape = obs[0][1].shape
    s = np.zeros(shape)
    st = np.zeros(shape)
    stt = np.zeros(shape)
    sy = np.zeros(shape)
    sty = np.zeros(shape)
    n_times = np.zeros(shape, np.int16)
    weights = []
    for t, y, n, _v in obs:
        w = np.where(y < white - 1.0, n, 0.0)
        weights.append(w)
        s += w
        st += w * t
        stt += w * t * t
        sy += w * y
        sty += w * t * y
        n_times += w > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        d = s * stt - st * st
        ok = (n_times >= 2) & (d > 0)
        beta = np.where(ok, (s * sty - st * sy) / d, np.nan)
        b = np.where(ok, (sy - beta * st) / s, np.nan)
        tbar = st / s
        sxx = d / s
        beta_var = np.zeros(shape)
        b_var = np.zeros(shape)
        for (t, _y, _n, v), w in zip(obs, weights, strict=True):
            a = w * (t - tbar) / sxx
            c = w / s - tbar * a
            per = np.where(w > 0, v / np.where(w > 0, w, 1.0), 0.0)
            beta_var += a * a * per
            b_var += c * c * per
    beta_var = np.where(ok, beta_var, np.nan)
    b_var = np.where(ok, b_var, np.nan)
    return beta, beta_var, b, b_var, n_times


def _noise_model(stats: list[tuple[float, StackResult]], b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-plane line ``variance = v0 + g · signal`` through the stacks' mean dark signal and variance.

    Returns v0 (DN²) and g (DN per electron), both shaped (C, 1, 1). Pixels more than 5x the
    median variance (hot, noisy) are left out of the plane means.
    """
    c = b.shape[0]
    v0 = np.zeros((c, 1, 1))
    g = np.zeros((c, 1, 1))
    for k in range(c):
        xs, ys = [], []
        for _t, st in stats:
            var = np.asarray(st.variance_all if st.variance_all is not None else st.variance, np.float64)[k]
            ok = np.isfinite(var) & np.isfinite(b[k])
            ok &= var < 5 * np.median(var[ok])
            if not ok.any():
                raise CamcalError(f"the dark frames at {_t:g} s show no temporal noise at all (the same file "
                                  "twice, or a copy?)", st.paths[0].parent if st.paths else None)
            xs.append(float(np.mean(np.asarray(st.value, np.float64)[k][ok] - b[k][ok])))
            ys.append(float(np.mean(var[ok])))
        if len(xs) >= 2 and np.ptp(xs) > 0:
            slope, icpt = np.polyfit(xs, ys, 1)
            g[k], v0[k] = max(slope, 0.0), max(icpt, 1e-6)
        else:
            v0[k] = max(ys[0], 1e-6)
    return v0, g


def _channel_summary(b, b_var, beta, beta_var, var_t, defects, stacks, have_bias: bool, gain) -> dict:
    out = {}
    for k, name in enumerate(PLANES):
        good = defects[k] == 0
        bk, betak = b[k][good], beta[k][good]
        med_beta, rs_beta = _robust(betak)
        if have_bias:
            rn_var = float(np.mean(var_t[k][good])) - QUANTISATION_VAR_DN2
        else:
            # EMVA 1288: temporal dark variance grows linearly with t; extrapolate its plane mean to t = 0
            ts = np.array([t for t, _ in stacks])
            vs = np.array([float(np.mean(np.asarray(s.variance_all, np.float64)[k][good])) for _, s in stacks])
            rn_var = float(np.polyfit(ts, vs, 1)[1]) if ts.size >= 2 else float(vs[0])
            rn_var -= QUANTISATION_VAR_DN2
        dsnu_bias2 = float(np.var(bk)) - float(np.mean(b_var[k][good]))
        dsnu_beta2 = float(np.var(betak)) - float(np.mean(beta_var[k][good]))
        out[name] = {
            "bias_dn": float(np.median(bk)),
            "bias_unc_dn": float(1.2533 * np.std(bk) / np.sqrt(bk.size)),
            "dark_current_dn_per_s": med_beta,
            "dark_current_unc_dn_per_s": float(1.2533 * rs_beta / np.sqrt(betak.size)),
            "dark_current_pixel_unc_dn_per_s": float(np.median(np.sqrt(beta_var[k][good]))),
            "dark_current_mean_dn_per_s": float(np.mean(betak)),
            "read_noise_dn": float(np.sqrt(max(rn_var, 0.0))),
            "dsnu_bias_dn": float(np.sqrt(max(dsnu_bias2, 0.0))),
            "dsnu_dark_current_dn_per_s": float(np.sqrt(max(dsnu_beta2, 0.0))),
            "gain_dn_per_e_from_dark": float(gain[k, 0, 0]),
            "hot_pixel_count": int(np.count_nonzero(defects[k] & HOT)),
            "dead_pixel_count": int(np.count_nonzero(defects[k] & DEAD)),
            "noisy_pixel_count": int(np.count_nonzero(defects[k] & NOISY)),
        }
    return out


def subtract_dark(planes: np.ndarray, model: DarkModel, exposure_s: float, iso: float | None = None) -> np.ndarray:
    """Remove the expected dark frame (bias + β·t) from (4, h, w) planes in DN; float32 result."""
    planes = np.asarray(planes)
    if planes.shape != model.bias_dn.shape:
        raise CamcalError(f"planes of shape {planes.shape} do not match the dark model's {model.bias_dn.shape}")
    return planes.astype(np.float32) - model.dark_frame_dn(exposure_s, iso)


def dark_to_parts(model: DarkModel) -> tuple[dict, dict[str, np.ndarray]]:
    """The JSON part and the named maps (``bias.R`` ...) of a model; used by files and profiles."""
    arrays = {"bias": model.bias_dn, "dark_current": model.dark_current_dn_per_s,
              "dark_current_unc": model.dark_current_unc_dn_per_s, "read_noise": model.read_noise_dn,
              "defects": model.defects.astype(np.float32)}
    maps = {f"{m}.{p}": np.where(np.isfinite(arrays[m][k]), arrays[m][k], np.float32(3.0e38))
            for m in _MAPS for k, p in enumerate(PLANES)}
    data = {
        "iso": model.iso, "cfa_pattern": model.cfa_pattern, "temperature_c": model.temperature_c,
        "exposure_times_s": list(model.exposure_times_s), "black_level_dn": list(model.black_level_dn),
        "white_level_dn": model.white_level_dn, "channels": model.channels, "summary": model.summary(),
        "provenance": model.provenance,
        "units": {"bias": "DN", "dark_current": "DN/s at iso", "dark_current_unc": "DN/s", "read_noise": "DN",
                  "defects": "bits: 1 hot, 2 dead, 4 noisy"},
    }
    return data, maps


def _check_dark_data(data: dict, where: str | Path | None) -> None:
    """Refuse a dark model's JSON part with values of the wrong type or out of range (one line)."""
    from camcal.frame import PATTERNS

    def number(key: str, *, positive: bool, optional: bool = False) -> None:
        v = data.get(key)
        if v is None and optional:
            return
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or (positive and v <= 0):
            raise CamcalError(f"malformed dark model: {key} must be a finite{' positive' if positive else ''} "
                              f"number, got {v!r}", where)

    if not isinstance(data, dict):
        raise CamcalError("malformed dark model: its data is not an object", where)
    number("iso", positive=True)
    number("white_level_dn", positive=True, optional=True)
    number("temperature_c", positive=False, optional=True)
    if data.get("cfa_pattern") not in PATTERNS:
        raise CamcalError(f"malformed dark model: cfa_pattern {data.get('cfa_pattern')!r} is not one of "
                          f"{', '.join(PATTERNS)}", where)
    for key in ("exposure_times_s", "black_level_dn"):
        v = data.get(key)
        if v is not None and (not isinstance(v, list) or not all(
                isinstance(t, int | float) and not isinstance(t, bool) and math.isfinite(t) for t in v)):
            raise CamcalError(f"malformed dark model: {key} must be a list of numbers", where)
    ch = data.get("channels")
    if not isinstance(ch, dict) or not all(isinstance(ch.get(p), dict) and ch[p] for p in PLANES) or len(
            {tuple(sorted(ch[p])) for p in PLANES}) != 1 or "hot_pixel_count" not in ch[PLANES[0]]:
        raise CamcalError(f"malformed dark model: channels must hold the same summary numbers for {', '.join(PLANES)}",
                          where)
    for p in PLANES:
        for key, v in ch[p].items():
            if v is not None and (isinstance(v, bool) or not isinstance(v, int | float)):
                raise CamcalError(f"malformed dark model: channels.{p}.{key} must be a number, got {v!r}", where)


def dark_from_parts(data: dict, maps: dict[str, np.ndarray], where: str | Path | None = None) -> DarkModel:
    """Inverse of :func:`dark_to_parts`; ``where`` names the file in errors."""
    missing = [f"{m}.{p}" for m in _MAPS for p in PLANES if f"{m}.{p}" not in maps]
    if missing:
        raise CamcalError(f"dark model lacks maps {', '.join(missing[:4])}", where)
    _check_dark_data(data, where)
    try:
        arr = {m: np.stack([maps[f"{m}.{p}"] for p in PLANES]).astype(np.float32) for m in _MAPS}
        arr["dark_current_unc"] = np.where(arr["dark_current_unc"] >= 3.0e38, np.inf, arr["dark_current_unc"])
        return DarkModel(
            bias_dn=arr["bias"], dark_current_dn_per_s=arr["dark_current"],
            dark_current_unc_dn_per_s=arr["dark_current_unc"], read_noise_dn=arr["read_noise"],
            defects=np.rint(arr["defects"]).astype(np.uint8), iso=float(data["iso"]),
            cfa_pattern=str(data["cfa_pattern"]),
            temperature_c=None if data.get("temperature_c") is None else float(data["temperature_c"]),
            channels=dict(data.get("channels") or {}),
            exposure_times_s=tuple(float(t) for t in data.get("exposure_times_s") or ()),
            black_level_dn=tuple(float(t) for t in data.get("black_level_dn") or ()),
            white_level_dn=float(data.get("white_level_dn") or float("nan")),
            provenance=dict(data.get("provenance") or {}),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise CamcalError(f"malformed dark model ({exc})", where) from None


def save_dark(model: DarkModel, path: str | Path) -> Path:
    """Write the model as ``path`` (JSON) + ``<stem>.maps.exr`` (maps ``bias.R`` ...), kind ``dark``."""
    from camcal.store import save_stage

    data, maps = dark_to_parts(model)
    return save_stage(path, KIND, data, maps)


def load_dark(path: str | Path) -> DarkModel:
    """Read a model written by :func:`save_dark`."""
    from camcal.store import load_stage

    data, maps = load_stage(path, KIND)
    return dark_from_parts(data, maps, path)

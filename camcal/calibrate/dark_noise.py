"""The temporal noise of the dark stage: read noise, the quantised-normal fit below 1 DN, noisy pixels, and the
per-plane photon-transfer line of the dark signal's variance (EMVA 1288 release 4.0 §4.3, eq. 4).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.special import ndtr
from scipy.stats import chi2

from camcal.calibrate.robust import median
from camcal.calibrate.stack import StackResult
from camcal.errors import CamcalError
from camcal.threads import thread_count, thread_map

QUANTISATION_VAR_DN2 = 1.0 / 12.0
"""Variance of rounding to integer DN (EMVA 1288 σ_q²), DN²."""


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

    run_planes(plane, c, jobs, var_t[0].size)
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



def noise_model(stats: list[tuple[float, StackResult]], b: np.ndarray,
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

    run_planes(plane, c, jobs, b[0].size)
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


def run_planes(one: Callable[[int], object], c: int, jobs: int | None, plane_pixels: int) -> list:
    """``[one(k) for k in range(c)]`` in ``jobs`` threads (:func:`camcal.threads.thread_count`), in plane order."""
    return thread_map(one, range(c), thread_count(jobs, c, plane_pixels), "camcal-dark-plane")



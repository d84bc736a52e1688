"""Per-pixel inversion of the closed-form models: ratio → optical depth → chlorophyll-a concentration.

Two exact routes share the closed form R(τ) = K e^(−sτ) I(mτ; μc) and its analytic derivative
(:class:`camcal.water.models.ClosedForm`):

- :func:`tau_newton`: a vectorised safeguarded Newton iteration on g(τ) = ln R(τ) − ln r (bracketed;
  a step leaving the bracket is replaced by bisection). R is monotone in τ, so the root is unique.
- :class:`TauTable`: for whole images. The inverse τ(δ), δ = ln R(0) − ln r, is tabulated by
  :func:`tau_newton` on nodes uniform in w = ln δ (δ from 1e-14 to the underflow limit), with the
  analytic slope dτ/dw = δ/(−d ln R/dτ); a pixel costs one log and a cubic Hermite evaluation.
  Interpolation error is below 1e-11 relative (tested); below δ = 1e-14 the first-order
  τ = δ/(−d ln R/dτ|₀) is exact to O(δ ln δ).

Pixels no concentration explains become NaN with a :class:`Reason` code, never an exception.
The radiance uncertainty propagates as σ_C = |dC/d ln r| σ_ln r, σ_ln r² = (σ_s/L_s)² + (σ_ref/L_ref)².
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from camcal.errors import CamcalError
from camcal.threads import run_bands
from camcal.water.models import ClosedForm, form_at
from camcal.water.units import mol_per_L_to_ug_per_L

#: Largest m·τ tabulated (E₃ underflows near 700).
MAX_PATH_TAU = 600.0
DELTA_MIN = 1e-14


class Reason(IntEnum):
    """Why a pixel has no concentration (0 = it has one)."""

    OK = 0
    NOT_FINITE = 1  # ratio (or an input radiance) is NaN or infinite
    NOT_POSITIVE = 2  # ratio ≤ 0: no light, or a bad black level
    ABOVE_CLEAR_WATER = 3  # ratio above the C = 0 value: brighter than clear water allows
    TOO_DARK = 4  # ratio below what the model can represent (optical depth beyond the table)
    BAD_REFERENCE = 5  # reference radiance ≤ 0 or not finite
    OUTSIDE_ROI = 6  # pixel outside the requested region
    BAD_DEPTH = 7  # depth below MIN_DEPTH_M (1 µm), or not finite


MIN_DEPTH_M = 1e-6
"""Smallest depth inverted, m: below it τ per unit concentration underflows and C overflows."""


def tau_newton(ratio, cf: ClosedForm, *, max_iter: int = 200, rtol: float = 1e-15):
    """Optical depth τ ≥ 0 with R(τ) = ratio, by safeguarded Newton on ln R; vectorised.

    Returns ``(tau, reason)``; τ is NaN where ``reason`` ≠ 0.
    """
    shape = np.shape(ratio)
    r = np.asarray(ratio, dtype=float).reshape(-1)
    tau = np.full(r.shape, np.nan)
    reason = np.zeros(r.shape, dtype=np.uint8)
    finite = np.isfinite(r)
    reason[~finite] = Reason.NOT_FINITE
    pos = finite & (r > 0)
    reason[finite & (r <= 0)] = Reason.NOT_POSITIVE
    r0 = cf.ratio_at_zero
    above = pos & (r > r0)
    reason[above] = Reason.ABOVE_CLEAR_WATER
    tau[pos & (r == r0)] = 0.0
    tau_max = MAX_PATH_TAU / (cf.path_factor + cf.view_factor)
    ln_rmin = float(np.log(cf.ratio(tau_max)))
    with np.errstate(divide="ignore"):
        lnr_all = np.log(np.where(pos, r, 1.0))
    dark = pos & ~above & (lnr_all < ln_rmin)
    reason[dark] = Reason.TOO_DARK
    work = np.flatnonzero(pos & (r < r0) & ~dark)
    if work.size:
        lnr = lnr_all[work]
        lo = np.zeros(work.size)
        hi = np.full(work.size, tau_max)
        x = np.clip((np.log(r0) - lnr) / cf.slope_at_zero, 0.0, tau_max)  # first-order start
        active = np.ones(work.size, dtype=bool)
        for _ in range(max_iter):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            xa = x[idx]
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                g = np.log(cf.ratio(xa)) - lnr[idx]
                dg = cf.dlog_ratio_dtau(xa)
            # g decreases in τ: g > 0 → root above x
            pos_g = g > 0
            lo[idx] = np.where(pos_g, xa, lo[idx])
            hi[idx] = np.where(pos_g, hi[idx], xa)
            with np.errstate(divide="ignore", invalid="ignore"):
                step = xa - g / dg
            bad = ~np.isfinite(step) | (step <= lo[idx]) | (step >= hi[idx])
            new = np.where(bad, 0.5 * (lo[idx] + hi[idx]), step)
            done = (np.abs(new - xa) <= rtol * np.maximum(new, 1e-300) + 1e-300) | (g == 0)
            x[idx] = np.where(g == 0, xa, new)
            active[idx[done]] = False
        tau[work] = x
    return tau.reshape(shape), reason.reshape(shape)


@dataclass(frozen=True)
class HermiteTable:
    """y(w) tabulated as a cubic Hermite spline on nodes uniform in w, for whole images: a value costs one index
    and one Horner cubic (:class:`TauTable` and :class:`camcal.water.band.BandInverse` each hold one).

    Cell j spans w0 + j·dw … w0 + (j + 1)·dw; on it y = c0 + u (c1 + u (c2 + u c3)), u ∈ [0, 1), the cubic
    Hermite interpolant of the values and slopes at its two nodes (de Boor 2001, *A Practical Guide to
    Splines*, ch. IV). Beyond the last cell, its cubic goes on.
    """

    w0: float
    inv_dw: float  # 1/dw, dw the nodes' spacing
    coef: np.ndarray  # (4, cells): c0 … c3 of each cell

    @classmethod
    def from_nodes(cls, w: np.ndarray, y: np.ndarray, dydw: np.ndarray) -> HermiteTable:
        """The table through the values ``y`` with slopes ``dydw`` at the uniform nodes ``w``."""
        dw = float(w[1] - w[0])
        m = dydw * dw  # dy/du on a unit cell
        y0, y1, m0, m1 = y[:-1], y[1:], m[:-1], m[1:]
        coef = np.stack([y0, m0, -3 * y0 - 2 * m0 + 3 * y1 - m1, 2 * y0 + m0 - 2 * y1 + m1])
        return cls(float(w[0]), 1.0 / dw, np.ascontiguousarray(coef))

    def evaluate(self, w: np.ndarray, with_slope: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """y at each ``w`` (float64 array, overwritten: it holds the position in the cell after), and dy/dw when
        ``with_slope`` (else None)."""
        t = w
        t -= self.w0
        t *= self.inv_dw
        j = t.astype(np.intp)
        np.minimum(j, self.coef.shape[1] - 1, out=j)
        t -= j  # u
        c = self.coef
        c3 = c[3].take(j)
        res = c[2].take(j)
        res += c3 * t
        der = None
        if with_slope:
            # dy/du = c1 + 2 c2 u + 3 c3 u²
            der = c[2].take(j) * 2.0
            der += 3.0 * c3 * t
            der *= t
            der += c[1].take(j)
            der *= self.inv_dw
        res *= t
        res += c[1].take(j)
        res *= t
        res += c[0].take(j)
        return res, der


#: Pixels per work unit of the image inversion (bounded memory; :func:`camcal.threads.thread_count` threads share them).
CHUNK = 1 << 20


class TauTable:
    """Tabulated inverse τ(ln R(0) − ln r) of one :class:`ClosedForm`, for whole images (see module doc)."""

    def __init__(self, cf: ClosedForm, nodes: int = 8192) -> None:
        self.cf = cf
        r0 = cf.ratio_at_zero
        tau_max = MAX_PATH_TAU / (cf.path_factor + cf.view_factor)
        with np.errstate(divide="ignore"):
            delta_max = float(np.log(r0) - np.log(cf.ratio(tau_max)))
        if not np.isfinite(delta_max):  # R(0) = 0, or R(τ_max) below the smallest float: no table to build
            raise CamcalError(f"the model's ratio R(τ) cannot be tabulated up to τ = {tau_max:g} (R(0) = {r0:g}, "
                              f"R(τ_max) = {float(cf.ratio(tau_max)):g}): is the disk's albedo 0 or absurdly small?")
        w = np.linspace(np.log(DELTA_MIN), np.log(delta_max), nodes)
        delta = np.exp(w)
        delta[-1] = delta_max
        tau, _ = tau_newton(r0 * np.exp(-delta), cf)
        tau[-1] = tau_max
        self._table = HermiteTable.from_nodes(w, tau, delta / (-cf.dlog_ratio_dtau(tau)))  # dτ/dw
        self.delta_max = delta_max
        self.slope0 = float(cf.slope_at_zero)  # −d ln R/dτ at τ = 0
        self.ln_r0 = float(np.log(r0))

    def tau(self, ratio, *, with_slope: bool = False):
        """τ for each ratio (any shape), its :class:`Reason`, and optionally dτ/d(−ln r).

        Returns ``(tau, reason)`` or ``(tau, reason, dtau_dlnr_neg)``.
        """
        r = np.asarray(ratio)
        flat = r.reshape(-1)
        tau = np.empty(flat.size)
        reason = np.empty(flat.size, dtype=np.uint8)
        slope = np.empty(flat.size) if with_slope else None

        def work(s: int) -> None:
            sl = slice(s, min(s + CHUNK, flat.size))
            self.tau_into(flat[sl], tau[sl], reason[sl], None if slope is None else slope[sl])

        run_bands(lambda start, _stop: work(start), flat.size, CHUNK)
        out = (tau.reshape(r.shape), reason.reshape(r.shape))
        return out + (slope.reshape(r.shape),) if with_slope else out

    def tau_into(self, r: np.ndarray, tau: np.ndarray, reason: np.ndarray, slope: np.ndarray | None) -> None:
        """Fill ``tau``, ``reason`` (and ``slope`` = dτ/d(−ln r)) for one chunk of ratios, in place."""
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = np.log(r, dtype=np.float64)
            np.subtract(self.ln_r0, delta, out=delta)
            inside = (delta >= DELTA_MIN) & (delta <= self.delta_max)
        all_inside = bool(inside.all())
        d = delta if all_inside else np.where(inside, delta, 1.0)
        res, der = self._table.evaluate(np.log(d), with_slope=slope is not None)
        tau[...] = res
        reason[...] = 0
        if slope is not None:
            der /= d  # dτ/d(−ln r) = (dτ/dw) / δ
            slope[...] = der
        if all_inside:
            return
        out = ~inside
        small = out & (delta >= 0) & (delta < DELTA_MIN)
        tau[small] = delta[small] / self.slope0
        if slope is not None:
            slope[small] = 1.0 / self.slope0
        out &= ~small
        rr = r[out]
        why = np.full(rr.shape, Reason.TOO_DARK, dtype=np.uint8)
        with np.errstate(invalid="ignore"):
            why[rr > np.exp(self.ln_r0)] = Reason.ABOVE_CLEAR_WATER
            why[rr <= 0] = Reason.NOT_POSITIVE
        why[~np.isfinite(rr)] = Reason.NOT_FINITE
        reason[out] = why
        tau[out] = np.nan
        if slope is not None:
            slope[out] = np.nan


@functools.lru_cache(maxsize=16)
def tau_table(cf: ClosedForm) -> TauTable:
    """A cached :class:`TauTable` for a closed form."""
    return TauTable(cf)


@dataclass(frozen=True)
class Inversion:
    """Concentration per pixel. NaN where ``reason`` ≠ 0 (see :class:`Reason`)."""

    c_mol_per_L: np.ndarray
    c_ug_per_L: np.ndarray
    sigma_ug_per_L: np.ndarray
    tau: np.ndarray
    reason: np.ndarray

    def summary(self) -> dict:
        """Counts per reason and robust statistics of the valid concentrations (µg/L)."""
        ok = self.reason == 0
        vals = self.c_ug_per_L[ok]
        counts = {Reason(int(k)).name.lower(): int(v) for k, v in zip(*np.unique(self.reason, return_counts=True),
                                                                       strict=True)}
        stats = {}
        if vals.size:
            stats = {"median_ug_per_L": float(np.median(vals)), "mean_ug_per_L": float(np.mean(vals)),
                     "p05_ug_per_L": float(np.percentile(vals, 5)), "p95_ug_per_L": float(np.percentile(vals, 95))}
        return {"pixels": int(self.reason.size), "valid": int(ok.sum()), "reasons": counts, **stats}


def _tau_by_table(r: np.ndarray, cf: ClosedForm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """τ, the reason codes and dτ/dln R of ratios ``r`` by the interpolated table (:func:`tau_table`)."""
    return tau_table(cf).tau(r, with_slope=True)


def _tau_by_newton(r: np.ndarray, cf: ClosedForm) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """τ, the reason codes and dτ/dln R of ratios ``r`` by Newton's method per pixel (:func:`tau_newton`)."""
    tau, reason = tau_newton(r.astype(float), cf)
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = 1.0 / -cf.dlog_ratio_dtau(np.where(np.isfinite(tau), tau, 0.0))
    return tau, reason, slope


TAU_METHODS = {"table": _tau_by_table, "newton": _tau_by_newton}
"""How :func:`invert_ratio` solves R(τ) = ratio: ``table`` (fast, for images) or ``newton`` (per pixel, the
reference)."""


def invert_ratio(ratio, model, depth_m, *, sigma_ln_ratio=None, method: str = "table") -> Inversion:
    """Chlorophyll-a from the ratio of disk radiance to reference radiance, per pixel.

    Parameters
    ----------
    ratio : array, measured L_disk/L_ref (any shape).
    model : :class:`~camcal.water.models.SeedModel`, :class:`~camcal.water.models.RefinedModel` (mean or exact
        transmittance) or :class:`~camcal.water.models.LampModel` (one depth).
    depth_m : disk depth, m (scalar or an array broadcastable to ``ratio``).
    sigma_ln_ratio : relative 1-σ uncertainty of the ratio (σ_r / r), scalar or array; None → NaN σ.
    method : 'table' (fast, for images) or 'newton' (per pixel, the reference).

    Returns
    -------
    :class:`Inversion` (arrays of the shape of ``ratio``).
    """
    r = np.asarray(ratio)
    scalar_depth = np.ndim(depth_m) == 0 and np.isfinite(depth_m) and float(depth_m) >= MIN_DEPTH_M
    if hasattr(model, "closed_form_at"):  # the geometry depends on the depth (LampModel)
        finite = np.asarray(depth_m, float)[np.isfinite(depth_m)]
        if finite.size and np.ptp(finite) > 0:
            raise CamcalError(f"the {model.name} model's geometry depends on the depth: invert one depth at a time")
        dep = float(finite.flat[0]) if finite.size and finite.flat[0] >= MIN_DEPTH_M else 1.0
        with np.errstate(all="ignore"):
            cf = form_at(model, dep)
        if not (np.isfinite(cf.ratio_at_zero) and cf.ratio_at_zero > 0 and np.isfinite(cf.slope_at_zero)):
            cf = form_at(model, 1.0)  # an absurd depth (the geometry overflows): every pixel BAD_DEPTH below
            depth_m = np.full(np.shape(depth_m), np.nan)
            scalar_depth = False
    else:
        cf = model.closed_form()
    if not (np.isfinite(cf.ratio_at_zero) and cf.ratio_at_zero > 0):  # e.g. albedo 0: no light comes back at all
        raise CamcalError(f"the {model.name} model sends no light back from the disk in clear water "
                          f"(R(0) = {cf.ratio_at_zero:g}; is its albedo 0?): there is nothing to invert")
    scalar_sigma = sigma_ln_ratio is None or np.ndim(sigma_ln_ratio) == 0
    if method == "table" and scalar_depth and scalar_sigma:
        return _finite_or_reason(_invert_table_scalar(r, model, cf, float(depth_m), sigma_ln_ratio))
    depth = np.broadcast_to(np.asarray(depth_m, dtype=float), r.shape)
    if method not in TAU_METHODS:
        raise ValueError(f"unknown method {method!r}; use {' or '.join(map(repr, TAU_METHODS))}")
    tau, reason, slope = TAU_METHODS[method](r, cf)
    reason = reason.copy()
    good_depth = np.isfinite(depth) & (depth >= MIN_DEPTH_M)
    reason[~good_depth & (reason == 0)] = Reason.BAD_DEPTH
    dd = np.where(good_depth, depth, 1.0)
    with np.errstate(over="ignore", invalid="ignore"):  # absurd depths overflow: TOO_DARK via _finite_or_reason
        per_c = model.tau(1.0, dd) - model.background_tau(dd)
        tau_bg = model.background_tau(dd)
    with np.errstate(invalid="ignore"):
        excess = tau - tau_bg
        clamp = (reason == 0) & (excess < 0) & (excess >= -1e-9 * np.maximum(tau_bg, 1e-300))
        excess = np.where(clamp, 0.0, excess)
        reason[(reason == 0) & (excess < 0)] = Reason.ABOVE_CLEAR_WATER
        ok = reason == 0
        c = np.where(ok, excess / per_c, np.nan)
        if sigma_ln_ratio is None:
            sigma = np.full(r.shape, np.nan)
        else:
            sigma = np.where(ok, np.abs(slope) * np.asarray(sigma_ln_ratio, dtype=float) / per_c, np.nan)
    return _finite_or_reason(Inversion(c, mol_per_L_to_ug_per_L(c), mol_per_L_to_ug_per_L(sigma),
                                       np.where(ok, tau, np.nan), reason))


def _finite_or_reason(inv: Inversion) -> Inversion:
    """A concentration that overflowed (extreme τ per unit C) becomes NaN with reason TOO_DARK, in place."""
    with np.errstate(invalid="ignore"):
        bad = (inv.reason == 0) & ~(np.isfinite(inv.c_mol_per_L) & np.isfinite(inv.c_ug_per_L))
    if bad.any():
        inv.reason[bad] = Reason.TOO_DARK
        for arr in (inv.c_mol_per_L, inv.c_ug_per_L, inv.sigma_ug_per_L, inv.tau):
            arr[bad] = np.nan
    return inv


def _invert_table_scalar(r: np.ndarray, model, cf: ClosedForm, depth_m: float, sigma_ln_ratio) -> Inversion:
    """The image fast path: one depth and one relative σ; chunked, on :func:`~camcal.threads.thread_count`
    threads, fused."""
    table = tau_table(cf)
    with np.errstate(over="ignore", invalid="ignore"):  # absurd depths overflow: TOO_DARK via _finite_or_reason
        tau_bg = float(model.background_tau(depth_m))
        per_c = float(model.tau(1.0, depth_m)) - tau_bg  # τ per (mol/L)
    to_ug = float(mol_per_L_to_ug_per_L(1.0))
    flat = r.reshape(-1)
    c = np.empty(flat.size)
    cug = np.empty(flat.size)
    sig = np.empty(flat.size)
    tau = np.empty(flat.size)
    reason = np.empty(flat.size, dtype=np.uint8)
    clamp = 1e-9 * max(tau_bg, 1e-300)  # table accuracy is ~3e-11 relative

    def work(s: int) -> None:
        sl = slice(s, min(s + CHUNK, flat.size))
        t, why, sp, cc = tau[sl], reason[sl], sig[sl], c[sl]
        table.tau_into(flat[sl], t, why, sp)
        np.subtract(t, tau_bg, out=cc)
        if tau_bg > 0:
            with np.errstate(invalid="ignore"):
                neg = cc < 0
            if neg.any():
                tiny = neg & (cc >= -clamp)
                cc[tiny] = 0.0
                hard = neg & ~tiny
                why[hard] = Reason.ABOVE_CLEAR_WATER
                cc[hard] = np.nan
                t[hard] = np.nan
                sp[hard] = np.nan
        cc *= 1.0 / per_c
        np.multiply(cc, to_ug, out=cug[sl])
        if sigma_ln_ratio is None:
            sp[...] = np.nan
        else:
            np.abs(sp, out=sp)
            sp *= float(sigma_ln_ratio) / per_c * to_ug

    run_bands(lambda start, _stop: work(start), flat.size, CHUNK)
    shape = r.shape
    return Inversion(c.reshape(shape), cug.reshape(shape), sig.reshape(shape), tau.reshape(shape),
                     reason.reshape(shape))


def invert_images(submerged, reference, model, depth_m, *, sigma_submerged=None, sigma_reference=None,
                  roi: tuple[int, int, int, int] | None = None, method: str = "table",
                  pixel_geometry=None) -> Inversion:
    """Chlorophyll-a map from a submerged-disk radiance image and a reference radiance image.

    ``model`` is a SeedModel/RefinedModel (narrowband: the images are radiances at one wavelength) or a
    :class:`camcal.water.band.BandModel` (band-aware: the images are one channel's band radiances or DN
    rates; ``depth_m`` must then be a scalar). ``reference`` may be an image or a scalar; σ arguments are
    1-σ radiance uncertainties in the same units (images or scalars). ``roi`` = (x0, y0, width, height) in
    pixels: pixels outside get NaN with reason OUTSIDE_ROI. ``pixel_geometry`` (a
    :class:`camcal.water.lampfield.PixelGeometry`, lamp model only): invert each pixel with its own lamp
    geometry instead of the disk centre's.
    """
    sub = np.asarray(submerged, dtype=np.float64)
    ref = np.broadcast_to(np.asarray(reference, dtype=np.float64), sub.shape)
    ref_bad = ~(np.isfinite(ref) & (ref > 0))
    with np.errstate(all="ignore"):  # overflowing ratios/σ become inf: reasons, never warnings on stderr
        ratio = np.where(ref_bad, np.nan, sub / np.where(ref_bad, 1.0, ref))
        sig = None
        if sigma_submerged is not None or sigma_reference is not None:
            rs = 0.0 if sigma_submerged is None else np.asarray(sigma_submerged, float) / sub
            rr = 0.0 if sigma_reference is None else np.asarray(sigma_reference, float) / ref
            sig = np.sqrt(np.square(rs) + np.square(rr))
    if pixel_geometry is not None:  # the lamp model, each pixel's own geometry
        inv = pixel_geometry.invert(ratio, model, float(depth_m), sigma_ln_ratio=sig)
    elif hasattr(model, "inverse"):  # a BandModel: its tabulated band inverse at this depth
        inv = model.inverse(float(depth_m)).concentration(ratio, sigma_ln_ratio=sig)
    else:
        inv = invert_ratio(ratio, model, depth_m, sigma_ln_ratio=sig, method=method)
    reason = inv.reason
    reason[ref_bad & np.isfinite(sub)] = Reason.BAD_REFERENCE
    if roi is not None:
        x0, y0, w, h = roi
        inside = np.zeros(sub.shape, dtype=bool)
        inside[max(y0, 0):y0 + h, max(x0, 0):x0 + w] = True
        reason[~inside] = Reason.OUTSIDE_ROI
    ok = reason == 0
    nan = np.nan
    return Inversion(np.where(ok, inv.c_mol_per_L, nan), np.where(ok, inv.c_ug_per_L, nan),
                     np.where(ok, inv.sigma_ug_per_L, nan), np.where(ok, inv.tau, nan), reason)

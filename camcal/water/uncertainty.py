"""Every input uncertainty carried to the concentration C (GUM first-order propagation, JCGM 100:2008 §5.1).

The measured ratio r is fixed; a model parameter p (depth, lamp height, lamp angle, ε, the channel's
c_R(λ)) is uncertain by σ_p. At fixed r the implicit function B(C; p) = r gives

    σ_C,p = |∂B/∂p| / |∂B/∂C| · σ_p,

with ∂B/∂p by a central difference (step ½σ_p) of the forward model and ∂B/∂C analytic (or central). For
c_R(λ), stored per wavelength with a standard uncertainty u_c(λ) in the profile, the band ratio
B = Σ c S R_λ Δλ / Σ c S Δλ gives (independent wavelengths)

    σ_B,c² = Σ_λ [S_λ Δλ (R_λ − B) u_c(λ) / Σ c S Δλ]²,    σ_C,c = σ_B,c / |∂B/∂C|.

The terms depend on C only (one depth, one geometry), so for images they are tabulated on a log grid of C
and interpolated per pixel (log-log). The ratio-noise term stays per pixel (:mod:`camcal.water.invert`).
The total is the root sum of squares (the inputs are independent). A Monte Carlo oracle in the tests checks the
first-order terms by sampling the same inputs and re-inverting (within 10 %).

References
----------
JCGM 100:2008, Evaluation of measurement data — Guide to the expression of uncertainty in measurement, §5.1.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import brentq

from camcal.water.band import bricaud_1998
from camcal.water.units import ug_per_L_to_mol_per_L

#: C grid of the tabulated terms, µg/L (log-spaced).
C_GRID_UG_PER_L = np.logspace(-3, 5, 161)


@dataclass(frozen=True)
class Uncertain:
    """A stated input: ``name`` (e.g. 'depth'), its value and 1-σ in ``unit``."""

    name: str
    value: float
    sigma: float
    unit: str


def term_sigma_c(forward: Callable[[float, np.ndarray], np.ndarray], param: Uncertain, c_ug_per_L,
                 db_dc) -> np.ndarray:
    """σ_C (µg/L) from one parameter: |∂B/∂p| σ_p / |∂B/∂C| at each C.

    forward(p, c) : the band or narrowband ratio at parameter value p and concentrations c (µg/L).
    db_dc : ∂B/∂C at ``c_ug_per_L`` (per µg/L) of the nominal model.
    """
    c = np.asarray(c_ug_per_L, float)
    h = 0.5 * param.sigma
    if not h > 0:
        return np.zeros_like(c)
    db_dp = (np.asarray(forward(param.value + h, c)) - np.asarray(forward(param.value - h, c))) / (2 * h)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(db_dp / np.asarray(db_dc, float)) * param.sigma


def interpolate_term(term_grid: np.ndarray, c_ug_per_L, grid: np.ndarray = C_GRID_UG_PER_L) -> np.ndarray:
    """A term tabulated on ``grid`` at per-pixel C (log-log; clamped at the grid's ends; NaN stays NaN)."""
    c = np.asarray(c_ug_per_L, float)
    t = np.asarray(term_grid, float)
    ok = t > 0
    if not ok.any():
        return np.where(np.isfinite(c), 0.0, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        lc = np.log(np.clip(c, grid[0], grid[-1]))
        out = np.exp(np.interp(lc, np.log(grid[ok]), np.log(t[ok])))
    return np.where(np.isfinite(c), out, np.nan)


def combine(terms: dict[str, np.ndarray]) -> np.ndarray:
    """Root sum of squares of the terms (NaN where any is NaN), accumulated in place."""
    arrays = [np.asarray(v, float) for v in terms.values()]
    shape = np.broadcast_shapes(*(a.shape for a in arrays))
    total = np.zeros(shape)
    for a in arrays:
        total += a * a
    return np.sqrt(total, out=total)


def dominant(terms: dict[str, np.ndarray]) -> dict:
    """Median of each term over the finite pixels and the name of the largest (JSON-ready)."""
    med = {}
    for k, v in terms.items():
        v = np.asarray(v, float)
        v = v[np.isfinite(v)]
        med[k] = float(np.median(v)) if v.size else None
    known = {k: v for k, v in med.items() if v is not None}
    return {"median_terms_ug_per_L": med, "dominant": max(known, key=known.get) if known else None}


def solve_c(forward_c: Callable[[np.ndarray], np.ndarray], ratio: float, c_hi_ug_per_L: float = 1e5) -> float:
    """C (µg/L) with forward_c(C) = ratio (monotone decreasing), by Brent's method on ln C; NaN if none."""
    def g(lnc: float) -> float:
        with np.errstate(divide="ignore"):
            return float(np.log(forward_c(np.array([np.exp(lnc)]))[0]) - np.log(ratio))

    lo, hi = np.log(1e-6), np.log(c_hi_ug_per_L)
    glo, ghi = g(lo), g(hi)
    if not (glo > 0 > ghi):
        return float("nan")
    return float(np.exp(brentq(g, lo, hi, xtol=1e-12, rtol=1e-12)))



def _is_band(model) -> bool:
    return hasattr(model, "spectral_ratio")


def model_ratio(model, c_ug_per_L, depth_m: float) -> np.ndarray:
    """The ratio of a band model (C in µg/L) or a narrowband model (converted to mol/L) at one depth."""
    if _is_band(model):
        return model.ratio(c_ug_per_L, depth_m)
    return model.ratio(ug_per_L_to_mol_per_L(c_ug_per_L), depth_m)


def _with(model, **changes):
    """``model`` with geometry fields changed (a band model's geometry, or the model itself)."""
    if _is_band(model):
        return replace(model, geometry=replace(model.geometry, **changes))
    return replace(model, **changes)


def _scaled_absorber(model, scale: float):
    if _is_band(model):
        chl = model.chlorophyll or bricaud_1998()
        return replace(model, chlorophyll=replace(chl, coefficient_m2_per_mg=chl.coefficient_m2_per_mg * scale))
    return replace(model, epsilon_L_per_mol_cm=model.epsilon_L_per_mol_cm * scale)


#: Inputs of the field model (sun and sky, :class:`camcal.water.field.FieldBandModel`): the sun's zenith angle
#: (degrees), the diffuse irradiance's relative scale (nominal 1) and the aerosol optical depth at 500 nm.
FIELD_INPUTS = ("sun_zenith", "diffuse_fraction", "aerosol")


def forward_for(model, depth_m: float, name: str) -> Callable[[float, np.ndarray], np.ndarray]:
    """forward(p, C) varying one input: 'depth' (m), 'lamp_height' (m), 'lamp_angle' (degrees), 'epsilon'
    (relative scale of ε or of the absorber spectrum, nominal 1), or for the field model 'sun_zenith' (degrees),
    'diffuse_fraction' (relative scale of the diffuse irradiance) and 'aerosol' (optical depth at 500 nm)."""
    if name == "depth":
        return lambda p, c: model_ratio(model, c, p)
    if name == "lamp_height":
        return lambda p, c: model_ratio(_with(model, height_m=float(p)), c, depth_m)
    if name == "lamp_angle":
        return lambda p, c: model_ratio(_with(model, lamp_angle_rad=float(np.radians(p))), c, depth_m)
    if name == "epsilon":
        return lambda p, c: model_ratio(_scaled_absorber(model, float(p)), c, depth_m)
    if name in FIELD_INPUTS and hasattr(model, "varied"):  # the field model (camcal.water.field)
        return lambda p, c: model_ratio(model.varied(name, float(p)), c, depth_m)
    raise ValueError(f"unknown uncertain input {name!r}")


def derivative_c(model, c_ug_per_L, depth_m: float) -> np.ndarray:
    """∂B/∂C per µg/L by a central difference in ln C (relative step 1e-5)."""
    c = np.asarray(c_ug_per_L, float)
    h = 1e-5
    return (model_ratio(model, c * (1 + h), depth_m) - model_ratio(model, c * (1 - h), depth_m)) / (2 * h * c)


def uncertainty_terms(model, depth_m: float, c_ug_per_L, inputs: list[Uncertain], *,
                      sensitivity_sigma=None, grid: np.ndarray = C_GRID_UG_PER_L) -> dict[str, np.ndarray]:
    """σ_C terms (µg/L) at ``c_ug_per_L`` (any shape, NaN kept) from each stated input and, for a band model
    with ``sensitivity_sigma`` (u_c(λ) on its grid), from c_R(λ): tabulated on ``grid``, interpolated log-log."""
    db = derivative_c(model, grid, depth_m)
    if sensitivity_sigma is None:
        sensitivity_sigma = getattr(model, "sensitivity_sigma", None)
    tables = {}
    for q in inputs:
        if q.sigma > 0:
            tables[q.name] = term_sigma_c(forward_for(model, depth_m, q.name), q, grid, db)
    if sensitivity_sigma is not None and _is_band(model):
        sb = model.ratio_sigma_from_sensitivity(grid, depth_m, sensitivity_sigma)
        with np.errstate(divide="ignore", invalid="ignore"):
            tables["sensitivity"] = np.abs(sb / db)
    return interpolate_terms(tables, c_ug_per_L, grid)


def interpolate_terms(tables: dict[str, np.ndarray], c_ug_per_L, grid: np.ndarray = C_GRID_UG_PER_L,
                      ) -> dict[str, np.ndarray]:
    """Several terms tabulated on a log-uniform ``grid`` at per-pixel C (log-log linear, clamped at the ends,
    NaN where C is NaN): cell index and weight computed once per pixel for all terms, in chunks of 2¹⁸
    pixels (bounded temporaries, as the inversion)."""
    c = np.asarray(c_ug_per_L, float)
    lg = np.log(grid)
    uniform = grid.size >= 2 and np.allclose(np.diff(lg), lg[1] - lg[0], rtol=1e-9, atol=0)
    logs = {}
    out = {}
    for name, t in tables.items():
        t = np.asarray(t, float)
        if uniform and np.all(np.isfinite(t) & (t > 0)):
            logs[name] = np.log(t)
        else:  # a term that vanishes somewhere: the general (slower) path
            out[name] = interpolate_term(t, c, grid)
    if not logs:
        return out
    flat = c.reshape(-1)
    res = {name: np.empty(flat.size) for name in logs}
    inv_step, lo, last = 1.0 / (lg[1] - lg[0]), lg[0], grid.size - 2
    for s in range(0, flat.size, 1 << 18):
        cc = flat[s:s + (1 << 18)]
        finite = np.isfinite(cc)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.log(np.clip(np.where(finite, cc, grid[0]), grid[0], grid[-1]))
        u -= lo
        u *= inv_step
        j = np.minimum(u.astype(np.intp), last)
        u -= j
        for name, lt in logs.items():
            v = lt.take(j)
            v += u * (lt.take(j + 1) - v)
            np.exp(v, out=v)
            v[~finite] = np.nan
            res[name][s:s + cc.size] = v
    out.update({name: v.reshape(c.shape) for name, v in res.items()})
    return out

def all_terms(inv, model, depth_m: float, inputs: list[Uncertain]) -> dict[str, np.ndarray]:
    """The σ_C terms (µg/L) of an :class:`camcal.water.invert.Inversion`: 'ratio' (its per-pixel ratio-noise
    σ, when one was given), each stated input, and 'sensitivity' (a band model's u_c(λ), when known)."""
    terms = {}
    if np.any(np.isfinite(inv.sigma_ug_per_L)):
        terms["ratio"] = inv.sigma_ug_per_L
    terms.update(uncertainty_terms(model, depth_m, inv.c_ug_per_L, inputs))
    return terms

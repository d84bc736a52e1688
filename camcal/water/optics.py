"""Surface optics of a flat air-water interface: Snell, Schlick (seed §1.1.1) and exact Fresnel.

All functions are vectorised over angle arrays (radians). Angles are measured from the surface
normal. ``n1`` is the refractive index of the medium the light comes from, ``n2`` of the one it enters.

References
----------
Born, M., Wolf, E. Principles of Optics (7th ed.), §1.5.2-1.5.3: the Fresnel equations.
Schlick, C. (1994). An inexpensive BRDF model for physically-based rendering. Computer Graphics Forum 13(3), 233-246.
"""

from __future__ import annotations

import functools

import numpy as np

#: Refractive index of water in the visible (seed §1.1.1).
N_WATER = 1.33
N_AIR = 1.0


def snell(theta_i_rad, n1: float = N_AIR, n2: float = N_WATER):
    """Refraction angle θt (rad) from n1 sin θi = n2 sin θt; NaN beyond total internal reflection."""
    s = n1 / n2 * np.sin(np.asarray(theta_i_rad, dtype=float))
    with np.errstate(invalid="ignore"):
        return np.where(np.abs(s) <= 1.0, np.arcsin(np.clip(s, -1.0, 1.0)), np.nan)


def critical_angle(n_dense: float = N_WATER, n_rare: float = N_AIR) -> float:
    """Critical angle (rad) for light going from the dense to the rare medium: arcsin(n_rare/n_dense)."""
    return float(np.arcsin(n_rare / n_dense))


def schlick_r0(n1: float = N_AIR, n2: float = N_WATER) -> float:
    """Normal-incidence reflectance ((n1-n2)/(n1+n2))² (0.0201 for air/water, n = 1.33)."""
    return ((n1 - n2) / (n1 + n2)) ** 2


def schlick_reflectance(theta_i_rad, n1: float = N_AIR, n2: float = N_WATER):
    """Schlick's approximation R = R0 + (1-R0)(1-cos θ)⁵ (seed §1.1.1).

    For light coming from the denser medium (n1 > n2) the formula must use the angle on the rarer side,
    otherwise it misses total internal reflection: here θ is replaced by the transmitted angle, and R = 1
    beyond the critical angle.
    """
    theta = np.asarray(theta_i_rad, dtype=float)
    r0 = schlick_r0(n1, n2)
    if n1 > n2:
        theta_t = snell(theta, n1, n2)
        cos = np.cos(np.where(np.isnan(theta_t), 0.0, theta_t))
        return np.where(np.isnan(theta_t), 1.0, r0 + (1.0 - r0) * (1.0 - cos) ** 5)
    return r0 + (1.0 - r0) * (1.0 - np.cos(theta)) ** 5


def fresnel_reflectance(theta_i_rad, n1: float = N_AIR, n2: float = N_WATER):
    """Exact Fresnel reflectance for unpolarised light, ½(Rs + Rp); 1 beyond total internal reflection.

    Air-side angles 40°/53°/80°/85° give 0.0242/0.0384/0.347/0.583 for n = 1.33 (physics notes).
    """
    theta = np.asarray(theta_i_rad, dtype=float)
    ci = np.cos(theta)
    s = n1 / n2 * np.sin(theta)
    tir = np.abs(s) >= 1.0
    ct = np.sqrt(np.clip(1.0 - s * s, 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = ((n1 * ci - n2 * ct) / (n1 * ci + n2 * ct)) ** 2
        rp = ((n1 * ct - n2 * ci) / (n1 * ct + n2 * ci)) ** 2
        r = 0.5 * (rs + rp)
    return np.where(tir, 1.0, np.nan_to_num(r, nan=1.0))


REFLECTANCE_METHODS = {"fresnel": fresnel_reflectance, "schlick": schlick_reflectance}
"""The surface reflectance R(θ_i, n1, n2) of each ``method``: Fresnel's unpolarised (exact) or Schlick's."""


def transmittance(theta_i_rad, n1: float = N_AIR, n2: float = N_WATER, method: str = "fresnel"):
    """T = 1 - R (seed §1.1.2) with R from ``method`` (:data:`REFLECTANCE_METHODS`)."""
    if method not in REFLECTANCE_METHODS:
        raise ValueError(f"unknown reflectance method {method!r}; use {' or '.join(map(repr, REFLECTANCE_METHODS))}")
    return 1.0 - REFLECTANCE_METHODS[method](theta_i_rad, n1, n2)


@functools.lru_cache(maxsize=8)
def gauss_legendre(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [-1, 1] (cached)."""
    return np.polynomial.legendre.leggauss(nodes)


@functools.lru_cache(maxsize=64)
def hemispheric_transmittance(theta_max_air_rad: float = np.pi / 2, n: float = N_WATER, method: str = "fresnel",
                              nodes: int = 96) -> float:
    """Cosine-weighted mean air→water transmittance of a uniform sky up to ``theta_max_air_rad``.

    T̄ = ∫ T(θ) cos θ sin θ dθ / ∫ cos θ sin θ dθ over air angles 0..θmax (0.934 for a full sky, n = 1.33).
    Gauss-Legendre quadrature in μ = cos θ.
    """
    x, w = gauss_legendre(nodes)
    mu_lo = np.cos(theta_max_air_rad)
    mu = 0.5 * (1 - mu_lo) * x + 0.5 * (1 + mu_lo)
    t = transmittance(np.arccos(mu), N_AIR, n, method)
    return float(np.sum(w * t * mu) / np.sum(w * mu))

"""ρ, the water surface's reflectance of the sky into the camera (the sky-glint factor of Rrs).

Above-water radiometry measures L_t = L_w + ρ L_sky, with L_sky the sky radiance in the direction that a flat
surface would reflect into the camera (the sky photo, taken at the water photo's angle from the zenith). ρ is:

- **flat surface**: the unpolarised Fresnel reflectance at the view angle, R(θv) (Born & Wolf §1.5;
  :func:`camcal.water.optics.fresnel_reflectance`): 0.0242 at 40° for n = 1.33.
- **wind-roughened surface** (:func:`rho_rough`): the average of Fresnel over the wave facets that the camera
  sees, their slopes Gaussian and isotropic with the Cox & Munk (1954) mean-square slope
  σ² = 0.003 + 0.00512 W (W the wind speed at 12.5 m, m s⁻¹). A facet of normal n, tilted by θn, reflects the
  camera's ray v to r = v − 2(v·n)n at the local incidence angle ω (cos ω = −v·n); its share of the pixel is its
  projected area, p(zx, zy) cos ω / (cos θn cos θv) (Cox & Munk 1954, eq. 2; Mobley 1994, §4.4). Rays that a
  facet sends back down into the water are not counted (they see water, not sky). For a uniform sky this is
  ρ = Σ w R(ω) / Σ w over the facets; the sum is a 2-D Gauss-Hermite quadrature over the slopes.

- **a sky of realistic shape** (:func:`rho_sky`, :func:`rho_sky_with_sigma`): the same facets, each carrying the
  radiance of the CIE standard general sky (CIE S 011/E:2003; Darula & Kittler 2002) in its reflected direction
  relative to the mirror direction's, for the sun's zenith and azimuth; σ from the clear/hazy sky types.

Uncertainty (:func:`rho_with_sigma`): the wind speed's own 1-σ (a finite difference of the model), and the
**sky's structure**: the model reflects a uniform sky, a real one brightens towards the horizon and has the sun
in it. Mobley (1999, Fig. 9 and Table 2) computes ρ with a Hydrolight sky of realistic radiance distribution: at
θv = 40° and 135° from the sun, 0.0256 (wind 0) to 0.028 (5 m s⁻¹), 0.029–0.035 at 10 m s⁻¹ depending on the sun;
HydroColor (Leeuw & Boss 2018) uses 0.028. The difference between those values and the uniform-sky model, about
5–10 % of ρ below 10 m s⁻¹, is taken as a relative 1-σ, ``sky_structure_rel`` (default 0.07). It is stated, not
measured: a camera cannot see the sky's full distribution from one photo.

References
----------
Cox, C., Munk, W. (1954). Measurement of the roughness of the sea surface from photographs of the sun's glitter.
J. Opt. Soc. Am. 44(11), 838-850.
Mobley, C. D. (1994). Light and Water: Radiative Transfer in Natural Waters, §4.4.
Mobley, C. D. (1999). Estimation of the remote-sensing reflectance from above-surface measurements.
Applied Optics 38(36), 7442-7455, doi:10.1364/AO.38.007442.
Darula, S., Kittler, R. (2002). CIE general sky standard defining luminance distributions. Proc. eSim 2002.
CIE S 011/E:2003 (ISO 15469:2004). Spatial distribution of daylight - CIE standard general sky.
Leeuw, T., Boss, E. (2018). The HydroColor app: above water measurements of remote sensing reflectance and
turbidity using a smartphone camera. Sensors 18(1), 256, doi:10.3390/s18010256.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from camcal.errors import CamcalError
from camcal.water.optics import N_WATER, fresnel_reflectance

#: ρ of HydroColor and of Mobley (1999) at 40° from nadir, 135° from the sun, wind 5 m s⁻¹.
RHO_HYDROCOLOR = 0.028
#: Relative 1-σ of ρ for the sky's radiance distribution (module docstring).
SKY_STRUCTURE_REL = 0.07
#: Gauss-Hermite nodes per slope axis of the facet average.
HERMITE_NODES = 48


def cox_munk_mss(wind_m_s: float) -> float:
    """Mean-square slope of the sea surface, σ² = 0.003 + 0.00512 W (Cox & Munk 1954, clean surface), W in m s⁻¹."""
    if not (np.isfinite(wind_m_s) and 0 <= wind_m_s <= 30):
        raise CamcalError(f"wind speed {wind_m_s!r} m/s: give 0-30 m/s")
    return 0.003 + 0.00512 * float(wind_m_s)


def rho_flat(view_deg: float, n: float = N_WATER) -> float:
    """Fresnel reflectance of a flat surface at the view angle from nadir (degrees): ρ for no wind."""
    return float(fresnel_reflectance(np.radians(view_deg), 1.0, n))


@functools.lru_cache(maxsize=256)
def rho_rough(view_deg: float, wind_m_s: float, n: float = N_WATER, nodes: int = HERMITE_NODES) -> float:
    """ρ of a uniform sky over a Cox-Munk surface (module docstring), view angle from nadir in degrees.

    W = 0 is Cox & Munk's calm sea (σ² = 0.003), 0.5 % above the flat surface's Fresnel reflectance at 40°.
    """
    if not 0 <= view_deg < 85:
        raise CamcalError(f"view angle {view_deg:g} deg from nadir: give 0-85 deg")
    s = np.sqrt(cox_munk_mss(wind_m_s) / 2.0)  # per axis (isotropic)
    x, w = np.polynomial.hermite_e.hermegauss(nodes)  # probabilists' Hermite: weight e^(−x²/2)
    zx, zy = np.meshgrid(s * x, s * x, indexing="ij")
    wxy = np.outer(w, w)
    t = np.radians(view_deg)
    v = np.array([np.sin(t), 0.0, -np.cos(t)])  # camera ray, travelling down to the water
    norm = np.sqrt(1.0 + zx ** 2 + zy ** 2)
    nx, ny, nz = -zx / norm, -zy / norm, 1.0 / norm  # facet normal (up)
    cos_w = -(v[0] * nx + v[1] * ny + v[2] * nz)
    rz = v[2] + 2.0 * cos_w * nz  # reflected ray's vertical component (up > 0: sees the sky)
    seen = (cos_w > 0) & (rz > 0)
    weight = wxy * np.where(seen, cos_w * norm, 0.0)  # projected area: cos ω / cos θn (cos θv is common)
    r = fresnel_reflectance(np.arccos(np.clip(cos_w, -1, 1)), 1.0, n)
    total = wxy * np.where(cos_w > 0, cos_w * norm, 0.0)
    return float(np.sum(weight * r) / np.sum(total))


@dataclass(frozen=True)
class Rho:
    """ρ with its 1-σ and the parts of it (dimensionless)."""

    value: float
    sigma: float
    terms: dict
    model: str
    view_deg: float
    wind_m_s: float | None

    def describe(self) -> dict:
        return {"rho": self.value, "sigma": self.sigma, "sigma_terms": dict(self.terms), "model": self.model,
                "view_deg": self.view_deg, "wind_m_s": self.wind_m_s}


def rho_with_sigma(view_deg: float, wind_m_s: float | None, wind_sigma_m_s: float = 1.0, *,
                   sky_structure_rel: float = SKY_STRUCTURE_REL, n: float = N_WATER) -> Rho:
    """ρ and its 1-σ: ``wind_m_s`` None is the flat surface (Fresnel, the sky-structure term only), else the
    Cox-Munk average with the wind's σ propagated by a central difference (module docstring)."""
    if wind_m_s is None:
        v = rho_flat(view_deg, n)
        terms = {"sky_structure": sky_structure_rel * v}
        model = "flat surface: Fresnel at the view angle"
    else:
        v = rho_rough(float(view_deg), float(wind_m_s), n)
        h = max(float(wind_sigma_m_s), 1e-3)
        lo, hi = max(wind_m_s - h, 0.0), min(wind_m_s + h, 30.0)
        d = (rho_rough(float(view_deg), hi, n) - rho_rough(float(view_deg), lo, n)) / (hi - lo)
        terms = {"wind": abs(d) * float(wind_sigma_m_s), "sky_structure": sky_structure_rel * v}
        model = "Cox & Munk (1954) facets, uniform sky, Fresnel per facet"
    return Rho(v, float(np.sqrt(sum(t * t for t in terms.values()))), terms, model, float(view_deg),
               None if wind_m_s is None else float(wind_m_s))


# --- ρ for a sky of realistic angular radiance distribution -------------------------------------------------------

#: CIE standard general sky (CIE S 011/E:2003, ISO 15469; Darula & Kittler 2002), the clear types:
#: (a, b) of the gradation φ(Z) = 1 + a e^(b/cos Z), (c, d, e) of the indicatrix
#: f(χ) = 1 + c [e^(dχ) − e^(dπ/2)] + e cos²χ.
CIE_SKY_TYPES = {
    11: (-1.0, -0.55, 10.0, -3.0, 0.45),  # white-blue sky with a distinct solar corona
    12: (-1.0, -0.32, 10.0, -3.0, 0.45),  # CIE standard clear sky, low luminance turbidity
    13: (-1.0, -0.32, 16.0, -3.0, 0.30),  # CIE standard clear sky, polluted atmosphere
    14: (-1.0, -0.15, 16.0, -3.0, 0.30),  # cloudless turbid sky with a broad solar corona
}
#: The nominal sky and the alternatives whose ρ spread is σ(ρ)'s sky-shape term.
CIE_NOMINAL = 12
CIE_ALTERNATIVES = (11, 13, 14)


def cie_sky_relative(cos_zenith, scattering_rad, sky_type: int = CIE_NOMINAL) -> np.ndarray:
    """φ(Z) f(χ) of the CIE standard general sky (relative radiance, any scale), Z from the zenith, χ from the sun."""
    a, b, c, d, e = CIE_SKY_TYPES[sky_type]
    cz = np.clip(np.asarray(cos_zenith, float), 1e-6, 1.0)
    chi = np.asarray(scattering_rad, float)
    return (1.0 + a * np.exp(b / cz)) * (1.0 + c * (np.exp(d * chi) - np.exp(d * np.pi / 2)) + e * np.cos(chi) ** 2)


@functools.lru_cache(maxsize=1024)
def rho_sky(view_deg: float, wind_m_s: float, sun_zenith_deg: float, relative_azimuth_deg: float,
            sky_type: int = CIE_NOMINAL, n: float = N_WATER, nodes: int = HERMITE_NODES) -> float:
    """ρ_eff = Σ w R(ω) L(r) / (Σ w · L(mirror)) over Cox-Munk facets (the weights of :func:`rho_rough`), with
    L the CIE standard general sky of ``sky_type`` for the sun at ``sun_zenith_deg`` and ``relative_azimuth_deg``
    from the view's azimuth (degrees). The sun's disk itself is not in the sky model: its mirror image is glint,
    screened out of the water photos. Mobley (1999) computes 0.028 at 40°, 135°, 5 m s⁻¹ with a Hydrolight sky."""
    if not 0 <= view_deg < 85:
        raise CamcalError(f"view angle {view_deg:g} deg from nadir: give 0-85 deg")
    if not 0 <= sun_zenith_deg < 90:
        raise CamcalError(f"sun zenith {sun_zenith_deg:g} deg: give 0-90 deg")
    s = np.sqrt(cox_munk_mss(wind_m_s) / 2.0)
    x, w = np.polynomial.hermite_e.hermegauss(nodes)
    zx, zy = np.meshgrid(s * x, s * x, indexing="ij")
    wxy = np.outer(w, w)
    t = np.radians(view_deg)
    v = np.array([np.sin(t), 0.0, -np.cos(t)])
    norm = np.sqrt(1.0 + zx ** 2 + zy ** 2)
    nx, ny, nz = -zx / norm, -zy / norm, 1.0 / norm
    cos_w = -(v[0] * nx + v[1] * ny + v[2] * nz)
    rx, ry, rz = v[0] + 2.0 * cos_w * nx, v[1] + 2.0 * cos_w * ny, v[2] + 2.0 * cos_w * nz
    zs, az = np.radians(sun_zenith_deg), np.radians(relative_azimuth_deg)
    sun = np.array([np.sin(zs) * np.cos(az), np.sin(zs) * np.sin(az), np.cos(zs)])
    chi = np.arccos(np.clip(rx * sun[0] + ry * sun[1] + rz * sun[2], -1.0, 1.0))
    seen = (cos_w > 0) & (rz > 0)
    area = wxy * np.where(cos_w > 0, cos_w * norm, 0.0)
    r = fresnel_reflectance(np.arccos(np.clip(cos_w, -1, 1)), 1.0, n)
    sky = np.where(seen, cie_sky_relative(rz, chi, sky_type), 0.0)
    mirror = cie_sky_relative(np.cos(t), np.arccos(np.clip(np.sin(t) * sun[0] + np.cos(t) * sun[2], -1, 1)),
                              sky_type)
    return float(np.sum(area * r * sky) / (np.sum(area) * mirror))


def rho_sky_with_sigma(view_deg: float, wind_m_s: float, wind_sigma_m_s: float, sun_zenith_deg: float,
                       relative_azimuth_deg: float, n: float = N_WATER) -> Rho:
    """ρ of :func:`rho_sky` for the CIE clear sky (type 12) and its 1-σ: the wind's (central difference) and the
    sky's shape, the largest departure of the other clear types (11 hazier gradation, 13 polluted, 14 turbid) from
    type 12."""
    args = (float(view_deg), float(sun_zenith_deg), float(relative_azimuth_deg))
    v = rho_sky(args[0], float(wind_m_s), args[1], args[2], CIE_NOMINAL, n)
    h = max(float(wind_sigma_m_s), 1e-3)
    lo, hi = max(wind_m_s - h, 0.0), min(wind_m_s + h, 30.0)
    d = (rho_sky(args[0], hi, args[1], args[2], CIE_NOMINAL, n)
         - rho_sky(args[0], lo, args[1], args[2], CIE_NOMINAL, n)) / (hi - lo)
    shape = max(abs(rho_sky(args[0], float(wind_m_s), args[1], args[2], k, n) - v) for k in CIE_ALTERNATIVES)
    terms = {"wind": abs(d) * float(wind_sigma_m_s), "sky_structure": shape}
    model = (f"Cox & Munk (1954) facets reflecting the CIE standard clear sky (type {CIE_NOMINAL}) for the sun at "
             f"{sun_zenith_deg:.1f} deg zenith, {relative_azimuth_deg:g} deg in azimuth; σ: wind and clear/hazy sky "
             "types 11, 13, 14")
    return Rho(v, float(np.sqrt(sum(t * t for t in terms.values()))), terms, model, float(view_deg), float(wind_m_s))

"""What the camera sees around and over a submerged Secchi disk: surface glare and water-leaving radiance.

A flat surface reflects the sky into the camera over the disk and the water alike; the water itself sends up
light scattered by its particles (and, in shallow water, by the bottom). In the band channel (radiances in the
profile's unit, W m⁻² sr⁻¹ nm⁻¹ or relative):

- **Glare**, modelled from the sky model and the view, not measured:
  G = R(θv) L_sky, with R the unpolarised Fresnel reflectance at the camera's view angle (Born & Wolf §1.5) and
  L_sky = f E_g/π the uniform sky of the field model (f the band's diffuse fraction, E_g the global
  irradiance). The reference photo measures E_g through the dry disk, L_ref = ρ_ref E_g/π, so
  G = R(θv) f L_ref/ρ_ref: no absolute scale is needed. 1-σ: the diffuse fraction's and ρ_ref's relative
  uncertainties in quadrature.
- **Water-leaving radiance** W = S − G, S the measured surround. Beyond the glare's uncertainty it is light from
  the water, which a clear, non-scattering lake does not send (the field model's assumption). The part of it
  that also lies over the disk comes from the column above it. For a homogeneous column that is optically deep
  around the disk, the radiance from the layer 0…d is the fraction
  F = 1 − exp(−a d (1 + 1/μv)) of the whole (single scattering; down and up attenuation taken as the band's
  absorption a, the vertical path down and the view's slant path μv = cos θv,w up; Mobley 1994 §5.9): the
  estimate over the disk is F W. Its 1-σ covers both physical bounds, none of it (the light comes from below
  the disk: the bottom, a deep layer) and all of it: a rectangular distribution of half-width
  max(F, 1 − F) W around F W, σ = max(F, 1 − F) W/√3.

The disk's signal is then D − G − F W; with W estimated as S − G that is D − (1 − F) G − F S, so the glare
enters σ with the weight (1 − F) and the surround's noise with F. A surround brighter than the glare by more
than twice its 1-σ is **not explained** by the model: the result carries a warning, and since neither the glare
model nor the column model can then be trusted, the light over the disk beyond the disk's own is known only to
lie between none and all of the surround, X in [0, S] (:meth:`SurroundBudget.unexplained_interval`), and the
sky may be brighter than the model's (up to the diffuse fraction whose glare would be the whole surround). C stays
the model's estimate; σ_C takes the unexplained term, a rectangular distribution whose half-width is the largest
|C(X; sky) − C| over those bounds (GUM 4.3.7; computed through the nonlinear inversion, not its slope):
:func:`camcal.water.secchi.unexplained_sigma`. A surround darker than the glare by more than that is also a
warning (the sky in the reflected direction is darker than the uniform sky, a polariser): the measured surround
is then the glare.

References
----------
Born, M., Wolf, E. Principles of Optics, §1.5. Mobley, C. D. (1994). Light and Water, §4.3 (the reflected sky),
§5.9 (the water-leaving radiance of a homogeneous column).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camcal.water.optics import N_WATER, fresnel_reflectance, snell

#: Albedo of the dry reference disk (a white Secchi disk) and its 1-σ: the sky radiance from the reference photo.
REFERENCE_ALBEDO = 0.85
REFERENCE_ALBEDO_SIGMA = 0.1
#: Surround − glare above this many 1-σ is water-leaving radiance the model does not explain.
EXPLAINED_SIGMAS = 2.0


def glare_radiance(reference_radiance: float, diffuse_fraction: float, *, view_angle_rad: float = 0.0,
                   n_water: float = N_WATER, reference_albedo: float = REFERENCE_ALBEDO) -> float:
    """G = R(θv) f L_ref/ρ_ref: the uniform sky reflected by the flat surface into the camera (module docstring),
    in the unit of ``reference_radiance``."""
    r = float(fresnel_reflectance(float(view_angle_rad), 1.0, n_water))
    return r * float(diffuse_fraction) * float(reference_radiance) / float(reference_albedo)


def column_fraction(absorption_per_m: float, depth_m: float, *, view_angle_rad: float = 0.0,
                    n_water: float = N_WATER) -> float:
    """F = 1 − exp(−a d (1 + 1/μv)): the share of a homogeneous, optically deep column's water-leaving radiance
    that comes from above depth d (module docstring); ``absorption_per_m`` the band's absorption a, m⁻¹."""
    mu_v = float(np.cos(snell(float(view_angle_rad), 1.0, n_water)))
    return float(1.0 - np.exp(-float(absorption_per_m) * float(depth_m) * (1.0 + 1.0 / mu_v)))


@dataclass(frozen=True)
class SurroundBudget:
    """The submerged photo's disk signal after glare and water-leaving radiance (units: the band radiance's).

    glare, glare_sigma : the modelled glare G and its 1-σ; surround, surround_se : the measured S and its
    standard error; water_leaving : W = S − G; column_fraction : F; over_disk, over_disk_sigma : F W and its
    1-σ; signal : D − G − F W; warning : None, or why the surround is not what the model explains.
    """

    glare: float
    glare_sigma: float
    surround: float
    surround_se: float
    water_leaving: float
    column_fraction: float
    over_disk: float
    over_disk_sigma: float
    signal: float
    warning: str | None

    @property
    def explained(self) -> bool:
        return self.warning is None

    def sigma_terms(self) -> dict[str, float]:
        """1-σ of the signal by source: 'glare' ((1 − F) σ_G), 'water_leaving' (the rectangular term) and
        'surround_noise' (F SE_S)."""
        f = self.column_fraction
        return {"glare": (1.0 - f) * self.glare_sigma, "water_leaving": self.over_disk_sigma,
                "surround_noise": f * self.surround_se}

    def unexplained_interval(self) -> tuple[float, float] | None:
        """(0, S) when the surround is brighter than the model explains, else None."""
        return (0.0, self.surround) if self.warning is not None and self.water_leaving > 0 else None

    def describe(self) -> dict:
        return {"glare_modelled": self.glare, "glare_sigma": self.glare_sigma, "surround_measured": self.surround,
                "surround_se": self.surround_se, "water_leaving": self.water_leaving,
                "column_fraction": self.column_fraction, "water_leaving_over_disk": self.over_disk,
                "water_leaving_over_disk_sigma": self.over_disk_sigma, "disk_signal": self.signal,
                "explained": self.explained}


def surround_budget(disk: float, surround: float, surround_se: float, glare: float, glare_sigma: float,
                    column: float, *, unit: str = "") -> SurroundBudget:
    """The disk's signal D − G − F W and the check of the surround against the glare (module docstring)."""
    w = surround - glare
    sigma_w = float(np.hypot(surround_se, glare_sigma))
    u = f" {unit}" if unit else ""
    warning = None
    g = glare
    if w > EXPLAINED_SIGMAS * sigma_w:
        warning = (f"the water around the disk ({surround:.3g}{u}) is {surround / glare:.1f}× the surface glare the "
                   f"sky model predicts ({glare:.3g} ± {glare_sigma:.2g}{u}): the rest ({w:.3g}{u}) is light from "
                   f"the water itself (particles, a bloom, the bottom); its part over the disk is estimated as "
                   f"{column:.0%} of it; σ_C carries the unexplained term (the light over the disk anywhere from "
                   "none to all of the surround)")
    elif w < -EXPLAINED_SIGMAS * sigma_w:
        warning = (f"the water around the disk ({surround:.3g}{u}) is darker than the surface glare the sky model "
                   f"predicts ({glare:.3g} ± {glare_sigma:.2g}{u}): the sky in the reflected direction is not the "
                   "model's uniform sky (a polariser, clouds); the measured surround is taken as the glare")
        g, glare_sigma = surround, max(glare_sigma, abs(w) / np.sqrt(3.0))
        w = 0.0
    w_pos = max(w, 0.0)
    over = column * w_pos
    over_sigma = max(column, 1.0 - column) * w_pos / np.sqrt(3.0)
    return SurroundBudget(g, float(glare_sigma), surround, surround_se, w, column, over, float(over_sigma),
                          disk - g - over, warning)

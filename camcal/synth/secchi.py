"""Secchi-disk scenes for the synthetic camera: a white disk above water and the same disk submerged.

The survey of the seed (§1, §5): photograph a Lambertian disk of albedo ρ in air (the reference) and the
same disk at depth d in water holding chlorophyll-a at concentration C, under the same daylight. Per
wavelength the submerged disk's radiance is the water model's ratio times the reference radiance,

    L_ref(λ) = ρ E(λ)/π,        L_sub(λ) = R_λ(τ_λ(C, d)) · L_ref(λ),
    τ_λ = [a_w(λ) + a_bg(λ) + a_chl(λ, C)] d,

with R_λ the ratio of the chosen geometry (:class:`camcal.water.models.RefinedModel` by default, or the
seed's eq. 10), a_w pure water (Pope & Fry 1997), a_chl the band model's chlorophyll spectrum (Bricaud
et al. 1998 by default).

R_λ is **rendered independently of the inversion** (``renderer="independent"``, the default): by direct
numerical integration over the sky's air-side zenith angles (composite Simpson, 4000 intervals), ray by
ray — each sky ray refracted by Snell, transmitted with its own exact Fresnel T(θ_air), absorbed along its
own slant path e^(−a(λ) d / cos θ_water), for every wavelength — then reflected by the disk and sent up along
the camera's view with T_up and e^(−a d/μv) (étendue: cos θ_a dΩ_a = n² cos θ_w dΩ_w, so the n² factors
cancel). For the seed's geometry it integrates eq. 10 itself over θ. The inversion's E₃ closed forms (with
the cosine-mean T̄) are not used, so tests that invert these scenes measure the approximation of the mean
transmittance. ``renderer="closed-form"`` keeps :meth:`camcal.water.band.BandModel.spectral_ratio`. E(λ) is CIE D65
(colour-science) scaled to a clear-sky global irradiance of 1.2 W m⁻² nm⁻¹ at 560 nm (typical of a high sun;
e.g. the ASTM G-173 global tilt spectrum is ≈ 1.5 W m⁻² nm⁻¹ near 560 nm). Each scene is a disk (centre,
radius configurable; anti-aliased edge) on a darker uniform background of albedo ``background_albedo``
(the deck around the reference; deep water around the submerged disk).

A camera channel i then records the DN rate ∫ c_i L dλ, so the predicted ratio of the two photos in channel i
is the band ratio B_i(C) of :class:`camcal.water.band.BandModel` with the reference radiance as illuminant;
:func:`secchi_scenes` returns it (for R, G, B) in its truth.

References
----------
Bricaud, A. et al. (1998). J. Geophys. Res. 103(C13), 31033-31044.
CIE 015:2018 Colorimetry (illuminant D65); colour-science ``colour.SDS_ILLUMINANTS["D65"]``.
Pope, R. M., Fry, E. S. (1997). Applied Optics 36(33), 8710-8723.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camcal.errors import CamcalError
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import Scene, SyntheticCamera
from camcal.units import CONCENTRATION
from camcal.water.band import BandModel, bricaud_1998
from camcal.water.models import RefinedModel, SeedModel
from camcal.water.optics import fresnel_reflectance, schlick_reflectance
from camcal.water.units import ug_per_L_to_mol_per_L

#: Clear-sky global horizontal spectral irradiance at 560 nm used to scale D65, W m⁻² nm⁻¹.
DAYLIGHT_IRRADIANCE_560_W_M2_NM = 1.2


def daylight_white_radiance(wavelengths_nm: np.ndarray = WAVELENGTHS_NM, *, illuminant: str = "D65",
                            irradiance_560_W_m2_nm: float = DAYLIGHT_IRRADIANCE_560_W_M2_NM) -> np.ndarray:
    """Spectral radiance of a perfect white Lambertian surface, L = E/π (W m⁻² sr⁻¹ nm⁻¹), E a CIE
    illuminant's relative spectrum (colour-science) scaled to ``irradiance_560_W_m2_nm`` at 560 nm."""
    import colour  # loads matplotlib: kept off paths that do not plot

    key = {k.lower(): k for k in colour.SDS_ILLUMINANTS}.get(str(illuminant).lower())
    if key is None:
        raise CamcalError(f"unknown illuminant {illuminant!r}; use a CIE illuminant name such as D65")
    sd = colour.SDS_ILLUMINANTS[key]
    wl = np.asarray(wavelengths_nm, float)
    rel = np.interp(wl, sd.wavelengths, sd.values)
    e = rel * irradiance_560_W_m2_nm / float(np.interp(560.0, sd.wavelengths, sd.values))
    return e / np.pi


def disk_weight(shape_hw: tuple[int, int], radius_px: float, centre_xy: tuple[float, float] | None = None,
                ) -> np.ndarray:
    """(H, W) fraction of each pixel covered by a disk (1 inside, 0 outside, a one-pixel linear ramp at the
    edge). ``centre_xy`` in full-resolution pixel coordinates (default: the image centre)."""
    h, w = shape_hw
    cx, cy = ((w - 1) / 2.0, (h - 1) / 2.0) if centre_xy is None else centre_xy
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    r = np.hypot(xx - cx, yy - cy)
    return np.clip(radius_px - r + 0.5, 0.0, 1.0)


#: Simpson intervals of the independent angular integration.
RENDER_INTERVALS = 4000


def independent_spectral_ratio(geometry, absorption_per_m: np.ndarray, depth_m: float,
                               intervals: int = RENDER_INTERVALS) -> np.ndarray:
    """Submerged-disk radiance over reference radiance per wavelength, by direct numerical integration over
    angles (see the module docstring); ``absorption_per_m`` a(λ) (m⁻¹) on any grid, returns the same shape.

    Refined geometry: R = (2/n²) T_up(θv) e^(−a d/μv) ∫_0^θmax T(θa) e^(−a d/cos θw(θa)) cos θa sin θa dθa,
    θw = arcsin(sin θa / n). Seed geometry (no surface): R = 2ρ ∫_0^θc e^(−2 a d/cos θ) cos θ sin θ dθ.
    """
    a = np.asarray(absorption_per_m, float)[..., None]
    m = intervals + (intervals % 2)
    simpson = np.ones(m + 1)
    simpson[1:-1:2], simpson[2:-1:2] = 4.0, 2.0
    if isinstance(geometry, SeedModel):
        th = np.linspace(0.0, geometry.cutoff_rad, m + 1)
        f = np.exp(-2.0 * a * depth_m / np.cos(th)) * np.cos(th) * np.sin(th)
        return 2.0 * geometry.albedo * np.sum(simpson * f, axis=-1) * (th[1] - th[0]) / 3.0
    n = geometry.n_water
    theta_max = min(geometry.sky_cutoff_rad, np.pi / 2)
    th = np.linspace(0.0, theta_max, m + 1)
    th_w = np.arcsin(np.sin(th) / n)
    t_down = 1.0 - fresnel_reflectance(th, 1.0, n) if geometry.reflectance == "fresnel" else \
        1.0 - _schlick(th, n)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        f = t_down * np.exp(-a * depth_m / np.cos(th_w)) * np.cos(th) * np.sin(th)
    integral = np.sum(simpson * f, axis=-1) * (th[1] - th[0]) / 3.0
    view_w = np.arcsin(np.sin(geometry.view_angle_rad) / n)
    t_up = 1.0 - float(fresnel_reflectance(view_w, n, 1.0)) if geometry.reflectance == "fresnel" else \
        1.0 - float(_schlick(view_w, n, up=True))
    return 2.0 * geometry.albedo / (n * n) * t_up * np.exp(-a[..., 0] * depth_m / np.cos(view_w)) * integral


def _schlick(theta, n, up: bool = False):
    return schlick_reflectance(theta, n, 1.0) if up else schlick_reflectance(theta, 1.0, n)


@dataclass(frozen=True)
class SecchiScenes:
    """The two scenes of a Secchi-disk survey and their ground truth.

    reference : the disk in air on its background; submerged : the disk at depth in water.
    weight : (H, W) disk coverage map (1 inside the disk).
    wavelengths_nm, reference_radiance, submerged_radiance : the disk's spectral radiances
        (W m⁻² sr⁻¹ nm⁻¹) in the two scenes.
    band_model : the :class:`camcal.water.band.BandModel` of the camera's true red channel used for the
        truth (its ``spectral_ratio`` rendered the submerged disk).
    truth : JSON-ready dict (see :func:`secchi_scenes`).
    """

    reference: Scene
    submerged: Scene
    weight: np.ndarray
    wavelengths_nm: np.ndarray
    reference_radiance: np.ndarray
    submerged_radiance: np.ndarray
    band_model: object
    truth: dict


GEOMETRIES = {"refined": RefinedModel, "seed": SeedModel}
"""The water models a synthetic Secchi scene can be rendered with, by name."""


def _geometry(model):
    """The water model ``model`` names (:data:`GEOMETRIES`), or the model itself."""
    if isinstance(model, str):
        if model not in GEOMETRIES:
            raise CamcalError(f"unknown water model {model!r}; use {' or '.join(GEOMETRIES)}")
        return GEOMETRIES[model]()
    if not hasattr(model, "closed_form"):
        raise CamcalError("water model must be 'refined', 'seed' or a SeedModel/RefinedModel")
    return model


def secchi_scenes(
    camera: SyntheticCamera,
    *,
    c_ug_per_L: float,
    depth_m: float,
    disk_albedo: float = 0.85,
    background_albedo: float = 0.05,
    white_radiance: np.ndarray | None = None,
    model="refined",
    chlorophyll=None,
    water_absorption_per_m=None,
    background_absorption_per_m=0.0,
    radius_fraction: float = 0.3,
    centre_xy: tuple[float, float] | None = None,
    renderer: str = "independent",
) -> SecchiScenes:
    """The reference and submerged Secchi-disk scenes for ``camera`` (see the module docstring).

    Parameters
    ----------
    camera : the synthetic camera (its sensor size gives the weight maps; its true c(λ) the predicted ratios).
    c_ug_per_L : chlorophyll-a concentration, µg/L (= mg m⁻³), ≥ 0.
    depth_m : depth of the submerged disk, m, > 0.
    disk_albedo, background_albedo : Lambertian albedos in (0, 1]; the background must be darker.
    white_radiance : radiance of a perfect white surface under the light, W m⁻² sr⁻¹ nm⁻¹ on
        :data:`camcal.models.spectra.WAVELENGTHS_NM` (default :func:`daylight_white_radiance`, D65).
    model : 'refined' (default), 'seed', or a SeedModel/RefinedModel (its geometry; albedo relative to the
        reference, so 1).
    chlorophyll, water_absorption_per_m, background_absorption_per_m : as
        :class:`camcal.water.band.BandModel` (defaults: Bricaud 1998; Pope & Fry water for the refined
        geometry, none for the seed's; no CDOM).
    radius_fraction : disk radius as a fraction of half the smaller sensor side.
    centre_xy : disk centre in full-resolution pixels (default: the image centre).
    renderer : 'independent' (default: numerical integration over angles, ray by ray) or 'closed-form' (the
        band model's E₃ closed forms, the inversion's own physics).

    Returns
    -------
    SecchiScenes, whose ``truth`` holds ``c_ug_per_L``, ``c_mol_per_L``, ``depth_m``, ``model``,
    ``predicted_band_ratio`` {R, G, B} (camera's true c(λ)), ``predicted_red_band_ratio``, the disk geometry
    and the light.
    """

    c = float(c_ug_per_L)
    d = float(depth_m)
    if not (np.isfinite(c) and c >= 0):
        raise CamcalError(f"chlorophyll-a concentration must be >= 0 {CONCENTRATION}, got {c_ug_per_L!r}")
    if not (np.isfinite(d) and d > 0):
        raise CamcalError(f"disk depth must be positive, got {depth_m!r} m")
    if not (0 < background_albedo < disk_albedo <= 1):
        raise CamcalError("albedos must satisfy 0 < background_albedo < disk_albedo <= 1")
    if not 0 < radius_fraction <= 1:
        raise CamcalError("radius_fraction must be in (0, 1]")
    wl = WAVELENGTHS_NM
    white = daylight_white_radiance(wl) if white_radiance is None else np.asarray(white_radiance, float)
    if white.shape != wl.shape or not np.all(np.isfinite(white)) or np.any(white < 0):
        raise CamcalError(f"white radiance must be {wl.size} finite non-negative values on the 380-780 nm grid")
    geometry = _geometry(model)
    p = camera.params
    radius_px = radius_fraction * 0.5 * min(p.width, p.height)
    weight = disk_weight((p.height, p.width), radius_px, centre_xy)
    l_ref = disk_albedo * white
    l_bg = background_albedo * white
    sens = camera.spectral_sensitivity()
    kw = dict(geometry=geometry, chlorophyll=chlorophyll, background_absorption_per_m=background_absorption_per_m,
              illuminant=l_ref / l_ref.max(), water_absorption_per_m=water_absorption_per_m)
    bands = {ch: BandModel(wl, sens[i], **kw) for i, ch in enumerate("RGB")}
    if renderer == "closed-form":
        r_lambda = bands["R"].spectral_ratio(c, d)
    elif renderer == "independent":
        chl = (chlorophyll or bricaud_1998()).on(wl)
        r_lambda = independent_spectral_ratio(geometry, bands["R"].absorption_background() + chl.absorption_per_m(c),
                                              d)
    else:
        raise CamcalError(f"unknown renderer {renderer!r}; use independent or closed-form")
    l_sub = r_lambda * l_ref
    reference = Scene(((weight, l_ref), (1.0 - weight, l_bg)), wl)
    submerged = Scene(((weight, l_sub), (1.0 - weight, l_bg)), wl)
    predicted = {ch: float(b.ratio(c, d)) for ch, b in bands.items()}
    rendered = {ch: float(np.sum(sens[i] * l_sub) / np.sum(sens[i] * l_ref)) for i, ch in enumerate("RGB")}
    cx, cy = ((p.width - 1) / 2.0, (p.height - 1) / 2.0) if centre_xy is None else centre_xy
    truth = {
        "c_ug_per_L": c,
        "c_mol_per_L": float(ug_per_L_to_mol_per_L(c)),
        "depth_m": d,
        "model": getattr(geometry, "name", type(geometry).__name__),
        "band_model": bands["R"].describe(),
        "predicted_band_ratio": predicted,
        "predicted_red_band_ratio": predicted["R"],
        "renderer": renderer,
        "rendered_band_ratio": rendered,
        "rendered_red_band_ratio": rendered["R"],
        "disk_albedo": float(disk_albedo),
        "background_albedo": float(background_albedo),
        "disk_centre_px": [float(cx), float(cy)],
        "disk_radius_px": float(radius_px),
        "light": "CIE D65, 1.2 W m⁻² nm⁻¹ at 560 nm" if white_radiance is None else "given",
        "reference_disk_radiance_560_W_m2_sr_nm": float(np.interp(560.0, wl, l_ref)),
    }
    return SecchiScenes(reference, submerged, weight, wl, l_ref, l_sub, bands["R"], truth)


def suggest_exposure_s(camera: SyntheticCamera, spectrum: np.ndarray, *, fill: float = 0.5,
                       iso: float | None = None, f_number: float | None = None,
                       wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> float:
    """Exposure time (s) that brings the brightest channel, on axis, for ``spectrum`` to ``fill`` of the
    smaller of the full well and the DN range above black (PRNU and noise stay below the clip for fill ≤ 0.8)."""
    p = camera.params
    iso = p.iso_base if iso is None else iso
    f_number = p.reference_f_number if f_number is None else f_number
    rate_e = float(np.max(camera.channel_rates_e(spectrum, f_number, wavelengths_nm)))
    if not rate_e > 0:
        raise CamcalError("the spectrum gives no signal in any channel")
    k = camera.dn_per_electron(iso)
    max_e = min(p.full_well_e, (p.white_dn - max(p.black_level_dn)) / k)
    return float(fill * max_e / rate_e)

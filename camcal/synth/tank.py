"""The seed's §4 experiment, synthesised: a disk in a tank of dyed water under a point lamp, photographed
submerged and dry, rendered by ray tracing **independently of the models that invert it**.

Geometry (metres; z up, the water surface at z = 0): the lamp at (0, 0, H); the disk's centre at
(X₀, 0, −d) with X₀ = H tan θa + d tan β(θa) (the lamp's ray to the disk centre leaves at air zenith angle
θa, as in :class:`camcal.water.models.LampModel`). The camera looks straight down (nadir; far away, so every
pixel's line of sight is vertical) at a field centred on the disk.

Rendering, per pixel (its own point P on the disk plane, not the disk centre's), ray by ray:

1. **Snell**: the entry point S on the surface is found on the vertical plane through the lamp and P by
   bisection of sin α = n sin β (the refracted ray from the lamp through S reaches P).
2. **Ray tube**: the forward map S ↦ P (vector Snell refraction of the ray lamp→S, propagated to z = −d) is
   differentiated numerically (central differences of traced rays); the irradiance on the horizontal disk
   per unit lamp intensity is E = T(α) (cos α / r²) / |det ∂P/∂S| e^(−a(λ) L), r = |S − lamp|, L = |P − S|.
3. **Fresnel**: T(α) = 1 − R(α), exact unpolarised Fresnel for the incidence angle of that ray; on the way up
   the vertical ray leaves with T(0)/n² (radiance across the interface) after e^(−a(λ) d).
4. **Absorption**: a(λ) = a_w(λ) (Pope & Fry 1997) + a_dye(λ, C), per wavelength (1 nm), per ray.
5. The dry disk (the empty tank, same place, same lamp): E = I (H + d)/R³ (inverse square, cosine).

The lamp emits I(λ) ∝ a 3200 K black body (``calibration_data/lamp_3200K.csv``). The disk is Lambertian
(albedo 0.85) on a dark bottom (0.05) at the same depth. The per-pixel spectra e^(−a(λ) L_p) are handed to the
synthetic camera as a few (weight map, spectrum) components — Lagrange interpolation in the path length on
Chebyshev nodes, exact to < 1e-10 — so :class:`camcal.synth.camera.SyntheticCamera` writes real DNGs.

None of this uses the closed forms of :mod:`camcal.water.models` (the ray tube is traced numerically, the
Jacobian not taken from dX/dθa): tests that invert these photos with :class:`LampModel` measure the model's
real approximations (disk-centre geometry, the analytic ray tube) as well as the noise.

The absorber defaults to :func:`blue_dye`, a **synthetic stand-in** for a blue food dye (a Gaussian band at
630 nm, 1.3e5 L mol⁻¹ cm⁻¹, σ 35 nm, M = 792.85 g/mol, shaped after Brilliant Blue FCF; not a measured spectrum).

References
----------
Born, M., Wolf, E. Principles of Optics, §1.5 (Fresnel); Mobley, C. D. (1994), Light and Water, §4.3 (n²).
Pope, R. M., Fry, E. S. (1997). Applied Optics 36(33), 8710-8723.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from camcal.errors import CamcalError
from camcal.io.atomic import atomic_write_text
from camcal.io.data import read_bundled_table
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import Scene, SyntheticCamera, save_truth
from camcal.synth.secchi import disk_weight, suggest_exposure_s
from camcal.units import CONCENTRATION
from camcal.water.band import ChlorophyllAbsorption, solvent_spectrum
from camcal.water.optics import N_WATER, fresnel_reflectance
from camcal.water.purewater import pure_water_absorption_per_m

#: The synthetic blue dye (a Gaussian stand-in shaped after Brilliant Blue FCF): peak, width, molar ε, M.
DYE_PEAK_NM = 630.0
DYE_SIGMA_NM = 35.0
DYE_PEAK_EPSILON_L_PER_MOL_CM = 1.3e5
DYE_MOLAR_MASS_G_PER_MOL = 792.85
#: Lamp radiant intensity at 560 nm, W sr⁻¹ nm⁻¹ (a few-hundred-watt halogen lamp), scaled by the 3200 K shape.
LAMP_INTENSITY_560_W_SR_NM = 0.5
#: Chebyshev nodes of the path-length interpolation of e^(−a(λ) L) (exact to < 1e-10 for a ΔL ≤ 3).
PATH_NODES = 12


def blue_dye(wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> ChlorophyllAbsorption:
    """The synthetic blue dye's absorption (linear, per µg/L): ε(λ) = ε_peak exp(−½((λ − 630)/35)²)/M."""
    wl = np.asarray(wavelengths_nm, float)
    eps_g = DYE_PEAK_EPSILON_L_PER_MOL_CM * np.exp(-0.5 * ((wl - DYE_PEAK_NM) / DYE_SIGMA_NM) ** 2)
    return solvent_spectrum(wl, eps_g / DYE_MOLAR_MASS_G_PER_MOL)


def write_dye_absorbance_csv(path: str | Path, *, concentration_mg_per_L: float = 5.0, path_length_cm: float = 1.0,
                             wavelengths_nm: np.ndarray = np.arange(380.0, 781.0, 2.0)) -> Path:
    """The dye as a spectrophotometer would report it: decadic absorbance of ``concentration_mg_per_L`` over
    ``path_length_cm``, a CSV for ``camcal water ... --absorber-csv`` (:func:`camcal.water.band.read_absorber_csv`)."""
    wl = np.asarray(wavelengths_nm, float)
    eps_g = DYE_PEAK_EPSILON_L_PER_MOL_CM * np.exp(-0.5 * ((wl - DYE_PEAK_NM) / DYE_SIGMA_NM) ** 2) / \
        DYE_MOLAR_MASS_G_PER_MOL
    a = eps_g * concentration_mg_per_L * 1e-3 * path_length_cm
    lines = ["# synthetic blue dye (Gaussian stand-in, camcal.synth.tank), decadic absorbance, blank subtracted",
             f"# concentration: {concentration_mg_per_L:g} mg/L", f"# path_length: {path_length_cm:g} cm",
             "wavelength_nm,absorbance"] + [f"{w:g},{v:.8g}" for w, v in zip(wl, a, strict=True)]
    path = Path(path)
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


def lamp_spectrum_W_sr_nm(wavelengths_nm: np.ndarray = WAVELENGTHS_NM,
                          intensity_560: float = LAMP_INTENSITY_560_W_SR_NM) -> np.ndarray:
    """Radiant intensity I(λ) of the lamp, W sr⁻¹ nm⁻¹: the shipped 3200 K shape scaled at 560 nm."""
    _, v = read_bundled_table("lamp_3200K.csv")
    rel = np.interp(np.asarray(wavelengths_nm, float), v[:, 0], v[:, 1])
    return rel * intensity_560 / float(np.interp(560.0, v[:, 0], v[:, 1]))


def _entry_distance(rho_m: np.ndarray, height_m: float, depth_m: float, n: float) -> np.ndarray:
    """Horizontal distance s of the surface entry point from the lamp's foot, for landing distance ρ:
    s/√(s² + H²) = n (ρ − s)/√((ρ − s)² + d²), by vectorised bisection (increasing in s on [0, ρ])."""
    lo = np.zeros_like(rho_m)
    hi = rho_m.copy()
    for _ in range(80):
        s = 0.5 * (lo + hi)
        f = s / np.hypot(s, height_m) - n * (rho_m - s) / np.hypot(rho_m - s, depth_m)
        lo = np.where(f < 0, s, lo)
        hi = np.where(f < 0, hi, s)
    return 0.5 * (lo + hi)


def _trace(sx, sy, height_m: float, depth_m: float, n: float):
    """Refract the lamp's ray through surface point (sx, sy) (vector Snell) and propagate it to z = −d.
    Returns the landing point (px, py), cos α (incidence), r = |S − lamp| and the in-water path length."""
    r = np.sqrt(sx * sx + sy * sy + height_m * height_m)
    vx, vy, vz = sx / r, sy / r, -height_m / r  # unit direction, going down
    cos_i = -vz
    eta = 1.0 / n
    cos_t = np.sqrt(1.0 - eta * eta * (1.0 - cos_i * cos_i))
    # t = η v + (η cos_i − cos_t) N, N = (0, 0, 1) the surface normal on the incident side
    tx, ty, tz = eta * vx, eta * vy, eta * vz + (eta * cos_i - cos_t)
    step = depth_m / -tz
    return sx + tx * step, sy + ty * step, cos_i, r, step * np.sqrt(tx * tx + ty * ty + tz * tz)


def lamp_irradiance_in_water(x_m, y_m, height_m: float, depth_m: float, n: float = N_WATER,
                             delta_m: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Per unit lamp intensity, the irradiance on the horizontal disk at (x, y, −d) **without absorption**,
    E = T(α) cos α / r² / |det ∂P/∂S| (m⁻²), and the in-water path length L (m) of the ray reaching it,
    by ray tracing (see the module docstring). Vectorised over points."""
    x = np.asarray(x_m, float)
    y = np.asarray(y_m, float)
    rho = np.hypot(x, y)
    s = _entry_distance(rho, height_m, depth_m, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        ux, uy = np.where(rho > 0, x / np.where(rho > 0, rho, 1), 1.0), np.where(rho > 0, y / np.where(rho > 0, rho, 1),
                                                                                  0.0)
    sx, sy = s * ux, s * uy
    _, _, cos_i, r, path = _trace(sx, sy, height_m, depth_m, n)
    pxa, pya = _trace(sx + delta_m, sy, height_m, depth_m, n)[:2]
    pxb, pyb = _trace(sx - delta_m, sy, height_m, depth_m, n)[:2]
    pxc, pyc = _trace(sx, sy + delta_m, height_m, depth_m, n)[:2]
    pxd, pyd = _trace(sx, sy - delta_m, height_m, depth_m, n)[:2]
    det = ((pxa - pxb) * (pyc - pyd) - (pya - pyb) * (pxc - pxd)) / (4 * delta_m * delta_m)
    t = 1.0 - fresnel_reflectance(np.arccos(np.clip(cos_i, -1, 1)), 1.0, n)
    return t * cos_i / (r * r) / np.abs(det), path


def lamp_irradiance_in_air(x_m, y_m, height_m: float, depth_m: float) -> np.ndarray:
    """Per unit lamp intensity, the irradiance on the horizontal disk at (x, y, −d) in the empty tank: (H+d)/R³."""
    hd = height_m + depth_m
    big_r = np.sqrt(np.asarray(x_m, float) ** 2 + np.asarray(y_m, float) ** 2 + hd * hd)
    return hd / big_r**3


def _lagrange_weights(values: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """(k, ...) Lagrange basis polynomials of ``nodes`` evaluated at ``values``."""
    out = np.ones((nodes.size,) + values.shape)
    for k in range(nodes.size):
        for j in range(nodes.size):
            if j != k:
                out[k] *= (values - nodes[j]) / (nodes[k] - nodes[j])
    return out


@dataclass(frozen=True)
class TankSetup:
    """The lamp and the tank. Lengths in m, angles in degrees (air zenith angle of the ray to the disk centre)."""

    lamp_height_m: float = 1.0  # above the water surface
    lamp_angle_deg: float = 20.0
    disk_radius_m: float = 0.10
    disk_albedo: float = 0.85
    background_albedo: float = 0.05
    n_water: float = N_WATER
    radius_fraction: float = 0.6  # disk radius over half the sensor's short side
    lamp_intensity_560_W_sr_nm: float = LAMP_INTENSITY_560_W_SR_NM

    def __post_init__(self) -> None:
        if not (0.01 <= self.lamp_height_m <= 100 and 0 <= self.lamp_angle_deg < 85):
            raise CamcalError("tank: lamp height must be 0.01-100 m and its angle 0-85 degrees")
        if not (0 < self.background_albedo < self.disk_albedo <= 1 and self.disk_radius_m > 0):
            raise CamcalError("tank: albedos must satisfy 0 < background < disk <= 1, disk radius > 0")


@dataclass(frozen=True)
class TankScenes:
    """Dry and submerged scenes of one (depth, concentration), their spectra at the disk centre, and truth."""

    dry: Scene
    submerged: Scene
    weight: np.ndarray
    dry_centre_radiance: np.ndarray
    submerged_centre_radiance: np.ndarray
    red_ratio_map: np.ndarray  # noise-free per-pixel R-channel ratio submerged/dry (full resolution)
    truth: dict = field(default_factory=dict)


def tank_scenes(camera: SyntheticCamera, *, c_ug_per_L: float, depth_m: float, setup: TankSetup | None = None,
                absorber: ChlorophyllAbsorption | None = None) -> TankScenes:
    """Render the dry and submerged tank photos' scenes (see the module docstring).

    Parameters
    ----------
    camera : the synthetic camera (its size sets the field; its true c_R the noise-free ratio map).
    c_ug_per_L : absorber (dye) concentration, µg/L (= mg m⁻³), ≥ 0.
    depth_m : depth of the disk below the surface, m, > 0.
    setup : the lamp and tank (default :class:`TankSetup`).
    absorber : the absorber's spectrum (default :func:`blue_dye`).
    """
    setup = setup or TankSetup()
    c, d = float(c_ug_per_L), float(depth_m)
    if not (np.isfinite(c) and c >= 0):
        raise CamcalError(f"tank: concentration must be >= 0 {CONCENTRATION}, got {c_ug_per_L!r}")
    if not (np.isfinite(d) and 0 < d <= 10):
        raise CamcalError(f"tank: depth must be in (0, 10] m, got {depth_m!r}")
    absorber = absorber or blue_dye()
    wl = WAVELENGTHS_NM
    p = camera.params
    h, w = p.height, p.width
    radius_px = setup.radius_fraction * 0.5 * min(w, h)
    m_per_px = setup.disk_radius_m / radius_px
    weight = disk_weight((h, w), radius_px)
    albedo = setup.disk_albedo * weight + setup.background_albedo * (1.0 - weight)
    n, hh, a = setup.n_water, setup.lamp_height_m, np.radians(setup.lamp_angle_deg)
    beta = np.arcsin(np.sin(a) / n)
    x0 = hh * np.tan(a) + d * np.tan(beta)
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    px = x0 + (xx - (w - 1) / 2.0) * m_per_px
    py = (yy - (h - 1) / 2.0) * m_per_px
    e_geo, path_down = lamp_irradiance_in_water(px, py, hh, d, n)
    e_air = lamp_irradiance_in_air(px, py, hh, d)
    t_up = 1.0 - float(fresnel_reflectance(0.0, n, 1.0))
    lamp = lamp_spectrum_W_sr_nm(wl, setup.lamp_intensity_560_W_sr_nm)
    a_lambda = pure_water_absorption_per_m(wl) + absorber.on(wl).absorption_per_m(c)
    total_path = path_down + d  # down along the ray, up vertically
    lo, hi = float(total_path.min()), float(total_path.max())
    k = np.arange(PATH_NODES)
    nodes = 0.5 * (lo + hi) + 0.5 * (hi - lo + 1e-12) * np.cos((2 * k + 1) * np.pi / (2 * PATH_NODES))
    basis = _lagrange_weights(total_path, nodes)
    amp_sub = albedo / np.pi * e_geo * t_up / (n * n)
    sub_components = tuple((amp_sub * basis[j], lamp * np.exp(-a_lambda * nodes[j])) for j in range(PATH_NODES))
    dry = Scene(((albedo / np.pi * e_air, lamp),), wl)
    submerged = Scene(sub_components, wl)
    # noise-free R-channel ratio per pixel (the camera's own band integral of each component)
    rate = {j: float(camera.channel_rates_e(s, p.reference_f_number)[0]) for j, (_, s) in enumerate(sub_components)}
    sub_r = sum(wgt * rate[j] for j, (wgt, _) in enumerate(sub_components))
    dry_r = albedo / np.pi * e_air * float(camera.channel_rates_e(lamp, p.reference_f_number)[0])
    ci, cj = (h - 1) / 2.0, (w - 1) / 2.0
    e_geo_c, path_c = lamp_irradiance_in_water(np.array([x0]), np.array([0.0]), hh, d, n)
    centre_dry = setup.disk_albedo / np.pi * float(lamp_irradiance_in_air(x0, 0.0, hh, d)) * lamp
    centre_sub = setup.disk_albedo / np.pi * float(e_geo_c[0]) * t_up / (n * n) * lamp * np.exp(
        -a_lambda * (float(path_c[0]) + d))
    truth = {"c_ug_per_L": c, "depth_m": d, "lamp_height_m": hh, "lamp_angle_deg": setup.lamp_angle_deg,
             "disk_radius_m": setup.disk_radius_m, "disk_albedo": setup.disk_albedo,
             "background_albedo": setup.background_albedo, "n_water": n, "metres_per_pixel": m_per_px,
             "disk_centre_px": [cj, ci], "disk_radius_px": radius_px,
             "disk_centre_from_lamp_foot_m": float(x0), "absorber": absorber.source or "synthetic blue dye",
             "lamp": "3200 K black body (calibration_data/lamp_3200K.csv), "
                     f"{setup.lamp_intensity_560_W_sr_nm:g} W sr⁻¹ nm⁻¹ at 560 nm",
             "renderer": "ray traced per pixel (numerical ray tube, Snell, Fresnel, absorption per wavelength)",
             "red_ratio_centre": float(np.sum(camera.spectral_sensitivity()[0] * centre_sub) /
                                       np.sum(camera.spectral_sensitivity()[0] * centre_dry))}
    return TankScenes(dry, submerged, weight, centre_dry, centre_sub, sub_r / dry_r, truth)


def write_tank_session(outdir: str | Path, camera: SyntheticCamera, *, depths_m, concentrations_ug_per_L,
                       setup: TankSetup | None = None, absorber: ChlorophyllAbsorption | None = None,
                       rng: np.random.Generator, fill: float = 0.5) -> dict:
    """Photograph the tank: per depth one dry DNG (the empty tank) and one submerged DNG per concentration.

    Files: ``dry_d{depth}m.dng``, ``sub_d{depth}m_c{C}ugL.dng`` and ``truth.json`` (every shot's exposure,
    depth, C and the render's truth). Each photo is exposed for ``fill`` of the well at the disk centre.
    Returns the truth dict (``shots``: list of {file, kind, depth_m, c_ug_per_L, exposure_s}).
    """
    setup = setup or TankSetup()
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    shots = []
    for d in depths_m:
        first = None
        for c in concentrations_ug_per_L:
            sc = tank_scenes(camera, c_ug_per_L=c, depth_m=d, setup=setup, absorber=absorber)
            if first is None:
                first = sc
                t = suggest_exposure_s(camera, sc.dry_centre_radiance, fill=fill)
                name = f"dry_d{d:g}m.dng"
                camera.write_dng(out / name, sc.dry, exposure_s=t, rng=rng)
                shots.append({"file": name, "kind": "dry", "depth_m": float(d), "c_ug_per_L": None, "exposure_s": t})
            t = suggest_exposure_s(camera, sc.submerged_centre_radiance, fill=fill)
            name = f"sub_d{d:g}m_c{c:g}ugL.dng"
            camera.write_dng(out / name, sc.submerged, exposure_s=t, rng=rng)
            shots.append({"file": name, "kind": "submerged", "depth_m": float(d), "c_ug_per_L": float(c),
                          "exposure_s": t, "red_ratio_centre": sc.truth["red_ratio_centre"]})
    truth = {"setup": {k: getattr(setup, k) for k in setup.__dataclass_fields__}, "shots": shots,
             "camera": camera.truth(), "absorber": (absorber or blue_dye()).source or "synthetic blue dye"}
    save_truth(out / "truth.json", truth)
    return truth

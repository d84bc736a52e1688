"""Sunlit Secchi-disk scenes: a white disk in a lake under the sun and a clear sky, rendered from first principles
**independently of the field model that inverts them** (:mod:`camcal.water.field`).

Light: the Bird & Riordan (1986) clear-sky model SPECTRL2 (:func:`pvlib.spectrum.spectrl2`, called here with
its own inputs): the direct normal irradiance DNI(λ) and the diffuse horizontal irradiance DHI(λ); the sky is
uniform, L_sky(λ) = DHI/π. Water: pure water a_w(λ) (Pope & Fry 1997) plus a pigment a_ph(λ, C) = A C^E
(Bricaud et al. 1998), both read from ``calibration_data`` and interpolated here.

Per wavelength (1 nm, 380-780 nm), ray by ray:

1. **Direct beam** at θs: refracted by Snell's law (sin θs = n sin β), transmitted with the exact unpolarised
   Fresnel T(θs) (Born & Wolf §1.5, written out below), absorbed along d/cos β. On the horizontal disk:
   E_dir,w = DNI cos θs T(θs) e^(−a d/cos β).
2. **Sky**, integrated numerically over the air-side zenith angle θa (composite Simpson, 2000 intervals; azimuth
   analytically, 2π): each sky ray refracted to θw, transmitted with its own T(θa), absorbed along d/cos θw;
   étendue (cos θa dΩa = n² cos θw dΩw) gives E_sky,w = 2π L_sky ∫ T(θa) e^(−a d/cos θw) cos θa sin θa dθa.
3. **Disk** (Lambertian, ρ), seen from the nadir camera after d upward and the surface: L = ρ (E_dir,w +
   E_sky,w)/π · T(0)/n² · e^(−a d).
4. **Surface**: the flat surface reflects the sky at the zenith over disk and water alike: L_refl = R(0) L_sky.
   The water around the disk is deep and does not scatter, so it sends up nothing else. An optional
   **glint** (the sun reflected by a wave facet: R(θs) DNI/Ω_sun, Ω_sun = 6.8e-5 sr) is a bright patch next to
   the disk; it saturates the sensor.
5. **Reference**: the same disk, dry and horizontal, under the same light: L = ρ (DNI cos θs + DHI)/π, on a
   deck of albedo 0.05.

The synthetic camera integrates these spectra over its c(λ) and writes real DNG and JPEG files with the capture
time. None of this calls :mod:`camcal.water` (no E₃ closed form, no Gauss-Legendre, no band model).

References
----------
Bird, R. E., Riordan, C. (1986). J. Climate Appl. Meteor. 25, 87-97. Born, M., Wolf, E. Principles of Optics,
§1.5. Bricaud, A. et al. (1998). J. Geophys. Res. 103(C13), 31033-31044. Pope, R. M., Fry, E. S. (1997).
Applied Optics 36(33), 8710-8723. Mobley, C. D. (1994). Light and Water, §4.3 (the n² law).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np
import pvlib

from camcal.errors import CamcalError
from camcal.io.data import read_bundled_table
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import Scene, SyntheticCamera, save_truth
from camcal.synth.exif import PlaceTime
from camcal.synth.secchi import disk_weight, suggest_exposure_s
from camcal.units import CONCENTRATION

#: Solid angle of the sun's disk, sr (0.265° angular radius).
SUN_SOLID_ANGLE_SR = 6.8e-5
#: Simpson intervals of the sky integral.
SKY_INTERVALS = 2000
#: Refractive index of the lake's water.
N_LAKE = 1.33


def _fresnel_r(cos_i, n1: float, n2: float):
    """Unpolarised Fresnel reflectance for incidence cosine ``cos_i`` from n1 into n2 (1 beyond the critical angle)."""
    cos_i = np.clip(np.asarray(cos_i, float), 0.0, 1.0)
    sin_t2 = (n1 / n2) ** 2 * (1.0 - cos_i**2)
    tir = sin_t2 >= 1.0
    cos_t = np.sqrt(np.clip(1.0 - sin_t2, 0.0, 1.0))
    rs = ((n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)) ** 2
    rp = ((n1 * cos_t - n2 * cos_i) / (n1 * cos_t + n2 * cos_i)) ** 2
    return np.where(tir, 1.0, 0.5 * (rs + rp))


@functools.lru_cache(maxsize=1)
def _tables():
    _, pf = read_bundled_table("water_absorption_pope_fry_1997.csv")
    hdr, br = read_bundled_table("chlorophyll_a_bricaud_1998.csv")
    return pf[:, 0], pf[:, 1], br[:, 0], br[:, hdr.index("A_ph_m2_per_mg")], br[:, hdr.index("E_ph")]


def lake_absorption_per_m(wavelengths_nm, c_ug_per_L: float) -> np.ndarray:
    """a(λ) = a_w(λ) + A(λ) C^E(λ), m⁻¹ (Pope & Fry water held at its ends; no pigment outside 400-700 nm)."""
    wl = np.asarray(wavelengths_nm, float)
    pw, pa, bw, ba, be = _tables()
    a_w = np.interp(wl, pw, pa)
    if c_ug_per_L <= 0:
        return a_w
    return a_w + np.interp(wl, bw, ba, left=0.0, right=0.0) * c_ug_per_L ** np.interp(wl, bw, be)


@dataclass(frozen=True)
class SunSky:
    """SPECTRL2 inputs of the rendered day (units in the names)."""

    sun_zenith_deg: float
    sun_azimuth_deg: float = 180.0
    aerosol_optical_depth_500nm: float = 0.1
    precipitable_water_cm: float = 1.42
    ozone_atm_cm: float = 0.344
    pressure_Pa: float = 101325.0
    day_of_year: int = 172

    def spectra(self, wavelengths_nm=WAVELENGTHS_NM) -> tuple[np.ndarray, np.ndarray]:
        """(DNI, DHI) in W m⁻² nm⁻¹ on ``wavelengths_nm`` (linear interpolation of SPECTRL2's grid)."""
        z = float(self.sun_zenith_deg)
        s = pvlib.spectrum.spectrl2(apparent_zenith=z, aoi=z, surface_tilt=0.0, ground_albedo=0.06,
                                    surface_pressure=self.pressure_Pa,
                                    relative_airmass=float(pvlib.atmosphere.get_relative_airmass(z)),
                                    precipitable_water=self.precipitable_water_cm, ozone=self.ozone_atm_cm,
                                    aerosol_turbidity_500nm=self.aerosol_optical_depth_500nm,
                                    dayofyear=int(self.day_of_year))
        wl = np.asarray(s["wavelength"], float)
        x = np.asarray(wavelengths_nm, float)
        return (np.interp(x, wl, np.asarray(s["dni"], float).reshape(-1)),
                np.interp(x, wl, np.asarray(s["dhi"], float).reshape(-1)))


def submerged_disk_radiance(sky: SunSky, c_ug_per_L: float, depth_m: float, albedo: float,
                            wavelengths_nm=WAVELENGTHS_NM, n: float = N_LAKE) -> np.ndarray:
    """Radiance of the submerged disk leaving the surface toward the nadir camera, W m⁻² sr⁻¹ nm⁻¹ (steps 1-3)."""
    wl = np.asarray(wavelengths_nm, float)
    dni, dhi = sky.spectra(wl)
    a = lake_absorption_per_m(wl, c_ug_per_L)
    zs = np.radians(sky.sun_zenith_deg)
    cos_b = np.sqrt(1.0 - (np.sin(zs) / n) ** 2)
    e_dir = dni * np.cos(zs) * (1.0 - _fresnel_r(np.cos(zs), 1.0, n)) * np.exp(-a * depth_m / cos_b)
    m = SKY_INTERVALS
    th = np.linspace(0.0, np.pi / 2, m + 1)
    w = np.ones(m + 1)
    w[1:-1:2], w[2:-1:2] = 4.0, 2.0
    w *= (th[1] - th[0]) / 3.0
    cos_w = np.sqrt(1.0 - (np.sin(th) / n) ** 2)
    g = (1.0 - _fresnel_r(np.cos(th), 1.0, n)) * np.cos(th) * np.sin(th)
    integral = np.exp(-a[:, None] * depth_m / cos_w[None, :]) @ (w * g)
    e_sky = 2.0 * np.pi * (dhi / np.pi) * integral
    t_up = 1.0 - float(_fresnel_r(1.0, n, 1.0))
    return albedo * (e_dir + e_sky) / np.pi * t_up / n**2 * np.exp(-a * depth_m)


def reflected_sky_radiance(sky: SunSky, wavelengths_nm=WAVELENGTHS_NM, n: float = N_LAKE) -> np.ndarray:
    """The zenith sky reflected by the flat surface into the nadir camera: R(0) DHI/π (step 4)."""
    _, dhi = sky.spectra(wavelengths_nm)
    return float(_fresnel_r(1.0, 1.0, n)) * dhi / np.pi


def reference_disk_radiance(sky: SunSky, albedo: float, wavelengths_nm=WAVELENGTHS_NM) -> np.ndarray:
    """The dry horizontal disk under the same light: ρ (DNI cos θs + DHI)/π (step 5)."""
    dni, dhi = sky.spectra(wavelengths_nm)
    return albedo * (dni * np.cos(np.radians(sky.sun_zenith_deg)) + dhi) / np.pi


@dataclass(frozen=True)
class SunlitScenes:
    """Reference and submerged scenes of one shot, their disk spectra and the truth (JSON-ready)."""

    reference: Scene
    submerged: Scene
    reference_radiance: np.ndarray
    submerged_radiance: np.ndarray
    reflected_radiance: np.ndarray
    truth: dict = field(default_factory=dict)


def sunlit_scenes(camera: SyntheticCamera, *, sky: SunSky, c_ug_per_L: float, depth_m: float,
                  disk_albedo: float = 0.85, deck_albedo: float = 0.05, radius_fraction: float = 0.45,
                  centre_xy: tuple[float, float] | None = None, glint_xy: tuple[float, float] | None = None,
                  glint_radius_px: float = 6.0) -> SunlitScenes:
    """Render one shot (module docstring). Pixel coordinates are the photo's (full resolution); the disk radius
    is ``radius_fraction`` of half the short side; ``glint_xy`` places a sun glint on the water."""
    c, d = float(c_ug_per_L), float(depth_m)
    if not (np.isfinite(c) and c >= 0 and np.isfinite(d) and 0 < d <= 20):
        raise CamcalError(f"sunlit scene: C must be >= 0 {CONCENTRATION} and the depth in (0, 20] m (got {c!r}, {d!r})")
    p = camera.params
    wl = WAVELENGTHS_NM
    radius_px = radius_fraction * 0.5 * min(p.width, p.height)
    cx, cy = ((p.width - 1) / 2.0, (p.height - 1) / 2.0) if centre_xy is None else centre_xy
    disk = disk_weight((p.height, p.width), radius_px, (cx, cy))
    l_ref = reference_disk_radiance(sky, disk_albedo, wl)
    l_deck = deck_albedo / disk_albedo * l_ref
    l_sub = submerged_disk_radiance(sky, c, d, disk_albedo, wl)
    l_refl = reflected_sky_radiance(sky, wl)
    components = [(disk, l_sub), (None, l_refl)]
    if glint_xy is not None:
        dni, _ = sky.spectra(wl)
        l_glint = float(_fresnel_r(np.cos(np.radians(sky.sun_zenith_deg)), 1.0, N_LAKE)) * dni / SUN_SOLID_ANGLE_SR
        components.append((disk_weight((p.height, p.width), glint_radius_px, glint_xy), l_glint))
    reference = Scene(((disk, l_ref), (1.0 - disk, l_deck)), wl)
    submerged = Scene(tuple(components), wl)
    sens = camera.spectral_sensitivity()
    truth = {"c_ug_per_L": c, "depth_m": d, "sun_zenith_deg": float(sky.sun_zenith_deg),
             "sun_azimuth_deg": float(sky.sun_azimuth_deg), "sky": {k: getattr(sky, k) for k in
                                                                      sky.__dataclass_fields__},
             "disk_albedo": disk_albedo, "disk_centre_px": [float(cx), float(cy)], "disk_radius_px": float(radius_px),
             "glint_px": None if glint_xy is None else [float(glint_xy[0]), float(glint_xy[1]), glint_radius_px],
             "rendered_band_ratio": {ch: float(np.sum(sens[i] * l_sub) / np.sum(sens[i] * l_ref))
                                     for i, ch in enumerate("RGB")},
             "reflected_over_reference": {ch: float(np.sum(sens[i] * l_refl) / np.sum(sens[i] * l_ref))
                                          for i, ch in enumerate("RGB")},
             "renderer": "camcal.synth.sunlit (SPECTRL2 sun and uniform sky, Simpson over the sky, Fresnel, "
                         "Pope & Fry water, Bricaud pigment)"}
    return SunlitScenes(reference, submerged, l_ref, l_sub, l_refl, truth)


def write_sunlit_pair(outdir: str | Path, camera: SyntheticCamera, scenes: SunlitScenes, *, stem: str,
                      rng: np.random.Generator, capture_time: datetime | None = None, fill: float = 0.5,
                      formats: tuple[str, ...] = ("dng",), write_reference: bool = True,
                      place: PlaceTime | None = None) -> dict:
    """Photograph one rendered shot: ``{stem}_ref.<ext>`` (unless ``write_reference`` is False) and
    ``{stem}_sub.<ext>`` for each of ``formats`` ('dng', 'jpg', 'heic'); each exposed for ``fill`` of the well
    on the disk; ``place`` writes the GPS position and time (:class:`camcal.synth.exif.PlaceTime`).
    Returns {kind: {ext: path}, 'exposure_s': {...}}."""
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    files: dict = {"exposure_s": {}}
    shots = [("sub", scenes.submerged, scenes.submerged_radiance + scenes.reflected_radiance)]
    if write_reference:
        shots.insert(0, ("ref", scenes.reference, scenes.reference_radiance))
    for kind, scene, spectrum in shots:
        t = suggest_exposure_s(camera, spectrum, fill=fill)
        files["exposure_s"][kind] = t
        for ext in formats:
            path = out / f"{stem}_{kind}.{ext}"
            kw = dict(exposure_s=t, rng=rng, capture_time=capture_time, place=place)
            if ext == "dng":
                camera.write_dng(path, scene, **kw)
            elif ext in ("jpg", "jpeg"):
                camera.write_jpeg(path, scene, **kw)
            elif ext == "heic":
                camera.write_heic(path, scene, **kw)
            else:
                raise CamcalError(f"unknown photo format {ext!r}; use dng, jpg or heic")
            files.setdefault(kind, {})[ext] = str(path)
    return files


def write_sunlit_survey(outdir: str | Path, camera: SyntheticCamera, *, sky: SunSky, depths_m, c_ug_per_L: float,
                        rng: np.random.Generator, formats: tuple[str, ...] = ("dng",),
                        capture_time: datetime | None = None, place: PlaceTime | None = None,
                        **scene_kwargs) -> dict:
    """One reference and one submerged photo per depth under one sky; ``truth.json`` beside them."""
    out = Path(outdir)
    shots = []
    for i, d in enumerate(depths_m):
        sc = sunlit_scenes(camera, sky=sky, c_ug_per_L=c_ug_per_L, depth_m=d, **scene_kwargs)
        files = write_sunlit_pair(out, camera, sc, stem=f"d{d:g}m", rng=rng, formats=formats,
                                  capture_time=capture_time, write_reference=i == 0, place=place)
        shots.append({"depth_m": float(d), "files": files, "truth": sc.truth})
    truth = {"c_ug_per_L": float(c_ug_per_L), "sky": {k: getattr(sky, k) for k in sky.__dataclass_fields__},
             "shots": shots, "camera": camera.truth()}
    save_truth(out / "truth.json", truth)
    return truth


def write_sunlit_photos(outdir: str | Path, camera: SyntheticCamera, *, chl: float, depths: str,
                        sun_zenith_deg: float, sun_azimuth_deg: float = 180.0, formats: str = "dng", seed: int = 1,
                        place: PlaceTime | None = None) -> list[Path]:
    """``camcal synth photo --scene secchi-sunlit``: parse the options' text and write
    :func:`write_sunlit_survey` into ``outdir`` (a folder); returns the files written (truth.json last)."""
    out = Path(outdir)
    if out.suffix.lower() in (".dng", ".jpg", ".jpeg", ".heic", ".heif") or (out.exists() and not out.is_dir()):
        raise CamcalError("--scene secchi-sunlit writes several photos: give a folder", out)
    try:
        ds = [float(t) for t in depths.replace("m", "").split(",") if t.strip()]
    except ValueError:
        raise CamcalError(f"--depths takes depths in m separated by commas (0.5,1), got {depths!r}") from None
    fmts = tuple(f.strip().lower() for f in formats.split(",") if f.strip())
    if not ds or not fmts or any(f not in ("dng", "jpg", "jpeg", "heic") for f in fmts):
        raise CamcalError(f"--format takes dng, jpg or heic separated by commas, got {formats!r}")
    if not 0 <= sun_zenith_deg < 89:
        raise CamcalError(f"--sun-zenith must be 0-89 deg, got {sun_zenith_deg:g}")
    sky = SunSky(float(sun_zenith_deg), float(sun_azimuth_deg))
    truth = write_sunlit_survey(out, camera, sky=sky, depths_m=ds, c_ug_per_L=float(chl),
                                rng=np.random.default_rng([seed, 45]), formats=fmts, place=place)
    files = [Path(p) for shot in truth["shots"] for kind in ("ref", "sub")
             for p in shot["files"].get(kind, {}).values()]
    return [*files, out / "truth.json"]

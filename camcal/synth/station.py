"""A water-colour station for the synthetic camera: photos of the water surface, the sky and a grey card.

The field protocol of above-water radiometry (Mobley 1999; HydroColor): the water at θv = 40° from nadir and 135°
in azimuth from the sun, the sky at 40° from the zenith in the mirror direction, a grey card level in the same
light. Each scene is spectral (1 nm, 380-780 nm), rendered here from its own physics, **independently of the
estimator** (:mod:`camcal.water.rrs`, :mod:`camcal.water.skyglint`): nothing of :mod:`camcal.water` is called.

- **Light**: SPECTRL2 (Bird & Riordan 1986, :class:`camcal.synth.sunlit.SunSky`) at the sun of the photos' place
  and time (pvlib's solar position): E_d = DNI cos θs + DHI. The sky's angular shape is the Perez, Seals &
  Michalsky (1993) all-weather luminance model for a clear sky (clearness bin 8, ε > 6.2, brightness
  Δ = ``PEREZ_DELTA``): L(ζ, γ) = L0 (1 + a e^(b/cos ζ)) (1 + c e^(dγ) + e cos²γ), ζ the zenith angle of the sky
  element, γ its angle to the sun, the coefficients x = x1 + x2 Z + Δ (x3 + x4 Z) of the model's table at the
  sun's zenith Z; L0 is fixed by ∫ L cos ζ dΩ = DHI over the hemisphere (numerically). The sky photos and every
  reflected ray carry this sky at their own direction and the sun of the station (the view points 135° in
  azimuth from the sun). Its shape is independent of the estimator's CIE sky.
- **Water** (a bio-optical model): a = a_w (Pope & Fry 1997) + a_ph(Chl) (Bricaud et al. 1998, A C^E) +
  a_CDOM(440) e^(−0.014 (λ−440)) + a_NAP(440) e^(−0.011 (λ−440)) (Babin et al. 2003); b_b = b_bw + b_bp with
  b_bw = 0.5 · 0.00288 (λ/500)^−4.32 (Morel 1974) and b_bp(λ) = b_bp(555) (555/λ)^η. The subsurface
  reflectance r_rs = g0 u + g1 u², u = b_b/(a + b_b), g0 = 0.089, g1 = 0.125 (Gordon et al. 1988), and above the
  surface Rrs = 0.52 r_rs / (1 − 1.7 r_rs) (Lee et al. 2002); L_w = Rrs E_d.
- **Surface**: wave facets with Cox & Munk (1954) isotropic Gaussian slopes (σ² = 0.003 + 0.00512 W) sampled by
  Monte Carlo (``FACETS`` facets, drawn in slope space, weighted by their projected area cos ω/cos θn); each
  reflects the camera's ray with its own exact Fresnel R(ω) into the sky direction it points at, whose radiance
  L(θr) it carries; rays sent down see no sky. The reflected radiance of a photo is ρ_eff L(θv) with
  ρ_eff = Σ w R(ω) L(θr)/L(θv) / Σ w: the sky photo at θv then holds exactly the radiance a flat-surface model
  multiplies by ρ. Each water photo sees its own waves: ρ_eff times (1 + ``WAVE_SCATTER`` N(0, 1)); each photo's
  sky brightness drifts by ``SKY_DRIFT`` N(0, 1).
- **Glint** (optional, in one water photo): sun glitter, facets that mirror the sun: sparse pixels (2 % of the
  frame) carrying R(θs) DNI/Ω_sun times a facet fraction, log-uniform in 10⁻⁶–5·10⁻²: most saturate, the rest
  are bright specks; and a haze of sub-pixel glitter over the whole photo, ``GLITTER_HAZE`` times the same
  radiance (a few % to tens of % of the water photo: what a wave field tilted towards the sun adds).
- **Card**: Lambertian, R_card(λ) (18 % flat by default) under E_d: L = R_card E_d/π.

Truth: Rrs per band of the camera's true c(λ), ∫ c_b L_w dλ / ∫ c_b E_d dλ (what a band measures), the spectrum,
ρ_eff, the sun and the files.

References
----------
Babin, M. et al. (2003). J. Geophys. Res. 108(C7), 3211. Bird, R. E., Riordan, C. (1986). J. Climate Appl.
Meteor. 25, 87-97. Bricaud, A. et al. (1998). J. Geophys. Res. 103(C13), 31033-31044. Cox, C., Munk, W. (1954).
J. Opt. Soc. Am. 44(11), 838-850. Gordon, H. R. et al. (1988). J. Geophys. Res. 93(D9), 10909-10924.
Lee, Z., Carder, K. L., Arnone, R. A. (2002). Applied Optics 41(27), 5755-5772. Morel, A. (1974). Optical
properties of pure water and pure sea water. In Optical Aspects of Oceanography, 1-24. Mobley, C. D. (1999).
Applied Optics 38(36), 7442-7455. Perez, R., Seals, R., Michalsky, J. (1993). All-weather model for sky luminance
distribution. Solar Energy 50(3), 235-245 (erratum 51(5), 423). Pope, R. M., Fry, E. S. (1997). Applied Optics
36(33), 8710-8723.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd
import pvlib

from camcal.errors import CamcalError
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import Scene, SyntheticCamera, save_truth
from camcal.synth.exif import PlaceTime
from camcal.synth.secchi import suggest_exposure_s
from camcal.synth.sunlit import N_LAKE, SUN_SOLID_ANGLE_SR, SunSky, _fresnel_r, lake_absorption_per_m

PEREZ_DELTA = 0.15
#: Perez et al. (1993) Table 1, clearness bin 8 (ε > 6.2): (x1, x2, x3, x4) of a, b, c, d, e.
PEREZ_CLEAR = {"a": (-1.0500, 0.0289, 0.4260, 0.3590), "b": (-0.3250, 0.1156, 0.7781, 0.0025),
               "c": (31.0625, -14.5000, -46.1148, 55.3750), "d": (-7.2312, 0.4050, 13.3500, 0.6234),
               "e": (1.5000, -0.6426, 1.8564, 0.5636)}
FACETS = 400_000
WAVE_SCATTER = 0.02
SKY_DRIFT = 0.01
VIEW_DEG = 40.0
RELATIVE_AZIMUTH_DEG = 135.0
GLITTER_HAZE = 2e-6


@dataclass(frozen=True)
class Water:
    """Bio-optical constituents: Chl (mg m⁻³), CDOM and NAP absorption at 440 nm (m⁻¹), b_bp(555) (m⁻¹), η."""

    chl_mg_m3: float
    cdom_440_per_m: float
    nap_440_per_m: float
    bbp_555_per_m: float
    bbp_slope: float


WATERS = {
    "clear": Water(0.3, 0.02, 0.0, 0.0012, 1.5),
    "green": Water(15.0, 0.25, 0.05, 0.006, 1.0),
    "turbid": Water(3.0, 0.5, 1.2, 0.15, 0.5),
}


def water_rrs(wavelengths_nm, water: Water) -> np.ndarray:
    """Rrs(λ) above the surface, sr⁻¹ (module docstring: Gordon et al. 1988, Lee et al. 2002)."""
    wl = np.asarray(wavelengths_nm, float)
    a = (lake_absorption_per_m(wl, water.chl_mg_m3) + water.cdom_440_per_m * np.exp(-0.014 * (wl - 440.0))
         + water.nap_440_per_m * np.exp(-0.011 * (wl - 440.0)))
    bb = 0.5 * 0.00288 * (wl / 500.0) ** -4.32 + water.bbp_555_per_m * (555.0 / wl) ** water.bbp_slope
    u = bb / (a + bb)
    r = 0.089 * u + 0.125 * u ** 2
    return 0.52 * r / (1.0 - 1.7 * r)


def _sun_direction(sun_zenith_deg: float) -> np.ndarray:
    """Unit vector to the sun in the station frame: x the camera's view azimuth, the sun 135° away from it."""
    z, phi = np.radians(sun_zenith_deg), np.radians(RELATIVE_AZIMUTH_DEG)
    return np.array([np.sin(z) * np.cos(phi), np.sin(z) * np.sin(phi), np.cos(z)])


def sky_shape(direction, sun_zenith_deg: float, delta: float = PEREZ_DELTA) -> np.ndarray:
    """L/L0 of the Perez et al. (1993) clear sky (module docstring) at unit vectors ``direction`` (3, ...)."""
    zs = np.radians(sun_zenith_deg)
    k = {n: x1 + x2 * zs + delta * (x3 + x4 * zs) for n, (x1, x2, x3, x4) in PEREZ_CLEAR.items()}
    d = np.asarray(direction, float)
    cz = np.clip(d[2], 1e-6, 1.0)
    s = _sun_direction(sun_zenith_deg).reshape((3,) + (1,) * (d.ndim - 1))
    gamma = np.arccos(np.clip(np.sum(d * s, axis=0), -1.0, 1.0))
    return (1.0 + k["a"] * np.exp(k["b"] / cz)) * (1.0 + k["c"] * np.exp(k["d"] * gamma)
                                                   + k["e"] * np.cos(gamma) ** 2)


def sky_irradiance_integral(sun_zenith_deg: float, steps: int = 720) -> float:
    """∫ (L/L0) cos ζ dΩ over the sky hemisphere (sr), midpoint rule in ζ and azimuth."""
    zeta = (np.arange(steps // 4) + 0.5) * (np.pi / 2) / (steps // 4)
    phi = (np.arange(steps) + 0.5) * 2 * np.pi / steps
    zz, pp = np.meshgrid(zeta, phi, indexing="ij")
    d = np.stack([np.sin(zz) * np.cos(pp), np.sin(zz) * np.sin(pp), np.cos(zz)])
    f = sky_shape(d, sun_zenith_deg) * np.cos(zz) * np.sin(zz)
    return float(f.sum() * (np.pi / 2 / zeta.size) * (2 * np.pi / steps))


def view_sky_direction(view_deg: float) -> np.ndarray:
    """The sky photo's direction: θv from the zenith, the mirror of the water view (azimuth 0 of the frame)."""
    t = np.radians(view_deg)
    return np.array([np.sin(t), 0.0, np.cos(t)])


def surface_reflectance(view_deg: float, wind_m_s: float, rng: np.random.Generator, facets: int = FACETS,
                        sun_zenith_deg: float = 40.0) -> float:
    """ρ_eff of the module docstring by Monte Carlo over Cox-Munk facets (sky radiance relative to L(θv))."""
    s = np.sqrt((0.003 + 0.00512 * wind_m_s) / 2.0)
    zx, zy = rng.normal(0.0, s, facets), rng.normal(0.0, s, facets)
    norm = np.sqrt(1 + zx * zx + zy * zy)
    n = np.stack([-zx / norm, -zy / norm, 1.0 / norm])
    t = np.radians(view_deg)
    v = np.array([np.sin(t), 0.0, -np.cos(t)])[:, None]
    cos_w = -np.sum(v * n, axis=0)
    r = v + 2 * cos_w * n
    front = cos_w > 0
    w = np.where(front, cos_w * norm, 0.0)
    up = front & (r[2] > 0)
    refl = np.where(up, _fresnel_r(cos_w, 1.0, N_LAKE) * sky_shape(r, sun_zenith_deg), 0.0)
    return float(np.sum(w * refl) / np.sum(w) / sky_shape(view_sky_direction(view_deg), sun_zenith_deg))


def station_sun(place: PlaceTime) -> tuple[float, float]:
    """(apparent zenith, azimuth) in degrees at the place and time (pvlib, NREL SPA)."""
    pos = pvlib.solarposition.get_solarposition(pd.DatetimeIndex([place.utc_aware]), place.latitude_deg,
                                                place.longitude_deg, altitude=place.altitude_m or 0.0)
    return float(pos["apparent_zenith"].iloc[0]), float(pos["azimuth"].iloc[0])


def write_station(outdir: str | Path, camera: SyntheticCamera, *, water: str | Water = "clear", place: PlaceTime,
                  wind_m_s: float = 5.0, n_water: int = 5, n_sky: int = 3, glint_photo: int | None = None,
                  card_wavelengths_nm=None, card_reflectance=None, rng: np.random.Generator | None = None,
                  aerosol_optical_depth_500nm: float = 0.1) -> dict:
    """Write ``water_1..n.dng``, ``sky_1..n.dng``, ``card.dng`` and ``truth.json`` into ``outdir``; returns the truth.

    ``glint_photo`` (1-based) adds sun glitter to that water photo; ``card_reflectance`` (on
    ``card_wavelengths_nm``) replaces the 18 % flat card."""
    wtype = WATERS.get(water) if isinstance(water, str) else water
    if wtype is None:
        raise CamcalError(f"unknown water {water!r}; choose {', '.join(WATERS)}")
    if not (0 <= wind_m_s <= 20 and n_water >= 1 and n_sky >= 1):
        raise CamcalError("station: wind 0-20 m/s, at least one water and one sky photo")
    if glint_photo is not None and not 1 <= glint_photo <= n_water:
        raise CamcalError(f"--glint-photo must be 1-{n_water}")
    rng = rng or np.random.default_rng(camera.params.seed + 4049)
    glint_rng = np.random.default_rng(int(rng.integers(2 ** 62)))  # drawn always: glint leaves the rest unchanged
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    zen, az = station_sun(place)
    if not zen < 85:
        raise CamcalError(f"the sun is {90 - zen:.1f} deg above the horizon at the station's time: too low")
    wl = WAVELENGTHS_NM
    sky = SunSky(zen, az, aerosol_optical_depth_500nm=aerosol_optical_depth_500nm,
                 day_of_year=int(place.utc_aware.timetuple().tm_yday))
    dni, dhi = sky.spectra(wl)
    ed = dni * np.cos(np.radians(zen)) + dhi
    l0 = dhi / sky_irradiance_integral(zen)
    l_sky_view = l0 * float(sky_shape(view_sky_direction(VIEW_DEG), zen))
    rrs = water_rrs(wl, wtype)
    lw = rrs * ed
    rho = surface_reflectance(VIEW_DEG, wind_m_s, rng, sun_zenith_deg=zen)
    card = np.full(wl.size, 0.18) if card_reflectance is None else np.interp(wl, card_wavelengths_nm,
                                                                               card_reflectance)
    sens = camera.spectral_sensitivity()
    files: dict = {"water": [], "sky": [], "card": []}
    photos = []

    def shoot(name: str, scene: Scene, spectrum: np.ndarray, kind: str, extra: dict) -> None:
        t = float(f"{suggest_exposure_s(camera, spectrum, fill=0.5):.3g}")
        path = camera.write_dng(out / name, scene, exposure_s=t, rng=rng, place=place)
        files[kind].append(str(path))
        photos.append({"file": name, "kind": kind, "exposure_s": t, **extra})

    reflected_sum = np.zeros(wl.size)
    kept = 0
    for i in range(1, n_water + 1):
        rho_i = rho * (1.0 + WAVE_SCATTER * rng.standard_normal())
        drift = 1.0 + SKY_DRIFT * rng.standard_normal()
        lt = lw + rho_i * drift * l_sky_view
        comps = [(None, lt)]
        extra = {"rho_eff": rho_i, "sky_drift": drift, "glint": i == glint_photo}
        if i == glint_photo:
            p = camera.params
            spots = glint_rng.random((p.height, p.width)) < 0.02
            fraction = 10.0 ** glint_rng.uniform(-6.0, np.log10(5e-2), (p.height, p.width))  # log-uniform
            weight = np.where(spots, fraction, 0.0)
            l_glint = float(_fresnel_r(np.cos(np.radians(zen)), 1.0, N_LAKE)) * dni / SUN_SOLID_ANGLE_SR
            comps += [(weight, l_glint), (None, GLITTER_HAZE * l_glint)]
        else:
            reflected_sum += rho_i * drift * l_sky_view
            kept += 1
        shoot(f"water_{i}.dng", Scene(tuple(comps), wl), lt, "water", extra)
    for j in range(1, n_sky + 1):
        drift = 1.0 + SKY_DRIFT * rng.standard_normal()
        shoot(f"sky_{j}.dng", Scene.uniform(l_sky_view * drift), l_sky_view * drift, "sky", {"sky_drift": drift})
    l_card = card * ed / np.pi
    shoot("card.dng", Scene.uniform(l_card), l_card, "card", {})

    def band(x):
        return {b: float(np.trapezoid(sens[k] * x, wl) / np.trapezoid(sens[k] * ed, wl)) for k, b in enumerate("RGB")}

    truth = {
        "renderer": "camcal.synth.station (SPECTRL2, Gordon/Lee Rrs(a, bb), Cox-Munk Monte Carlo surface, "
                    "Perez et al. 1993 clear sky)",
        "water": asdict(wtype) | {"name": water if isinstance(water, str) else "custom"},
        "rrs_per_sr": band(lw),
        "rrs_spectrum": {"wavelength_nm": wl[::5].tolist(), "rrs_per_sr": rrs[::5].tolist()},
        "reflected_over_ed_per_sr": band(reflected_sum / max(kept, 1)),
        "rho_eff": rho, "wind_m_s": wind_m_s, "view_deg": VIEW_DEG, "relative_azimuth_deg": RELATIVE_AZIMUTH_DEG,
        "sky_model": {"name": "Perez et al. (1993) clear sky, bin 8", "delta": PEREZ_DELTA},
        "sun_zenith_deg": zen, "sun_azimuth_deg": az,
        "utc": place.utc_aware.astimezone(UTC).isoformat(), "latitude_deg": place.latitude_deg,
        "longitude_deg": place.longitude_deg,
        "glint_photo": None if glint_photo is None else f"water_{glint_photo}.dng",
        "card": "18 % flat" if card_reflectance is None else "given spectrum", "photos": photos, "files": files,
        "camera": camera.truth(),
    }
    save_truth(out / "truth.json", truth)
    return truth


def place_at(utc: str | datetime, latitude_deg: float = 52.0, longitude_deg: float = 5.0) -> PlaceTime:
    """A :class:`PlaceTime` with GPS position and time (UTC clock) for a station."""
    when = datetime.fromisoformat(utc.replace("Z", "+00:00")) if isinstance(utc, str) else utc
    return PlaceTime(when, 0, latitude_deg, longitude_deg, 0.0)

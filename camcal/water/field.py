"""The field model: a Secchi disk in a sunlit lake, lit by the direct solar beam and the diffuse sky.

Geometry (flat surface, camera at nadir or at a view angle θv from nadir, disk horizontal at depth d):

- **Direct beam** at the sun's zenith angle θs: on a horizontal surface in air its irradiance is
  E_dir = DNI cos θs. Through the flat surface the beam keeps its horizontal footprint, loses the Fresnel
  reflectance R(θs) (unpolarised, Born & Wolf §1.5) and refracts to β (sin θs = n sin β); it reaches the disk
  after the slant path d/cos β: E_w,dir = T(θs) E_dir e^(−τ/cos β).
- **Diffuse sky** (uniform radiance L_sky = E_dif/π): the refined model (:class:`camcal.water.models.RefinedModel`,
  the refracted cone, Fresnel T(θ) inside the angular integral by default).
- **Up**: the disk (Lambertian, ρ) is seen along the view with T_up/n² (the n² law, Mobley 1994) and
  e^(−τ/μv).

The observable is the disk's radiance over that of the same disk in air under the same light (the reference
photo: the dry disk, horizontal, lit by the global irradiance E_g = E_dir + E_dif). Per wavelength, with the
diffuse fraction f(λ) = E_dif/E_g,

    R_λ(τ) = (1 − f) R_dir(τ) + f R_sky(τ),
    R_dir(τ) = ρ T(θs) T_up/n² e^(−τ (1/cos β + 1/μv)),
    R_sky(τ) = 2ρ T_up e^(−τ/μv) ∫_μw^1 T(μ) μ e^(−τ/μ) dμ      (refined model),

τ = (a_w + a_bg + a_chl(C)) d. ``--sky overcast`` is f = 1 (the refined model alone). The split E_dir/E_dif
is spectral: from the Bird & Riordan (1986) clear-sky model SPECTRL2 (:func:`pvlib.spectrum.spectrl2`) or from
measured spectra. The band-aware ratio integrates R_λ over the camera's c(λ) with the global irradiance as the
reference's spectrum (:class:`FieldBandModel`).

SPECTRL2 defaults (:class:`ClearSky`): aerosol optical depth at 500 nm 0.1 (a clear day), precipitable water
1.42 cm, ozone 0.344 atm-cm (the reference atmosphere of Bird & Riordan 1986 and ASTM G173), surface pressure
101 325 Pa (sea level), the day of the year 172 when no date is known (it only scales the extraterrestrial
irradiance, which cancels in the ratio).

References
----------
Bird, R. E., Riordan, C. (1986). Simple solar spectral model for direct and diffuse irradiance on horizontal
and tilted planes at the Earth's surface for cloudless atmospheres. J. Climate Appl. Meteor. 25, 87-97.
Born, M., Wolf, E. Principles of Optics, §1.5. Mobley, C. D. (1994). Light and Water, §4.3.
Holmgren, W. F., Hansen, C. W., Mikofski, M. A. (2018). pvlib python. J. Open Source Software 3(29), 884.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pvlib

from camcal.errors import CamcalError
from camcal.io.manifest import read_text_file
from camcal.water.band import BandModel, bricaud_1998
from camcal.water.models import ExactTransmittanceForm, ExponentialForm, RefinedModel
from camcal.water.optics import N_WATER, snell, transmittance

#: SPECTRL2 inputs when none are given (module docstring).
DEFAULT_AOD_500NM = 0.1
DEFAULT_PRECIPITABLE_WATER_CM = 1.42
DEFAULT_OZONE_ATM_CM = 0.344
DEFAULT_PRESSURE_PA = 101325.0
DEFAULT_DAY_OF_YEAR = 172
#: Gauss-Legendre nodes of the sky part's angular integral (:meth:`FieldGeometry.sky_form`).
SKY_NODES = 32


@dataclass(frozen=True)
class ClearSky:
    """A cloudless sky by SPECTRL2 (Bird & Riordan 1986, through pvlib) at the sun's zenith angle.

    sun_zenith_deg : degrees (0-89); aerosol_optical_depth_500nm : dimensionless;
    precipitable_water_cm : cm; ozone_atm_cm : atm-cm; pressure_Pa : Pa; day_of_year : 1-366.
    """

    sun_zenith_deg: float
    aerosol_optical_depth_500nm: float = DEFAULT_AOD_500NM
    precipitable_water_cm: float = DEFAULT_PRECIPITABLE_WATER_CM
    ozone_atm_cm: float = DEFAULT_OZONE_ATM_CM
    pressure_Pa: float = DEFAULT_PRESSURE_PA
    day_of_year: int = DEFAULT_DAY_OF_YEAR

    kind = "clear"

    def __post_init__(self) -> None:
        if not 0 <= self.sun_zenith_deg < 89:
            raise CamcalError(f"sun zenith angle {self.sun_zenith_deg:g} deg: the field model needs the sun above "
                              "the horizon (0-89 deg)")
        if not (0 <= self.aerosol_optical_depth_500nm < 5 and 0 <= self.precipitable_water_cm < 15
                and 0 < self.ozone_atm_cm < 1 and 3e4 < self.pressure_Pa < 1.2e5):
            raise CamcalError("SPECTRL2 inputs out of range: aerosol optical depth 0-5, precipitable water 0-15 cm, "
                              "ozone 0-1 atm-cm, pressure 30-120 kPa")

    @functools.cached_property
    def _spectra(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        z = float(self.sun_zenith_deg)
        am = float(pvlib.atmosphere.get_relative_airmass(z))
        s = pvlib.spectrum.spectrl2(apparent_zenith=z, aoi=z, surface_tilt=0.0, ground_albedo=0.06,
                                    surface_pressure=self.pressure_Pa, relative_airmass=am,
                                    precipitable_water=self.precipitable_water_cm, ozone=self.ozone_atm_cm,
                                    aerosol_turbidity_500nm=self.aerosol_optical_depth_500nm,
                                    dayofyear=int(self.day_of_year))
        wl = np.asarray(s["wavelength"], float)
        direct = np.asarray(s["dni"], float).reshape(-1) * np.cos(np.radians(z))
        diffuse = np.asarray(s["dhi"], float).reshape(-1)
        return wl, direct, diffuse

    def irradiance(self, wavelengths_nm) -> tuple[np.ndarray, np.ndarray]:
        """(E_dir, E_dif) on a horizontal surface, W m⁻² nm⁻¹, linearly interpolated on ``wavelengths_nm``."""
        wl, direct, diffuse = self._spectra
        x = np.asarray(wavelengths_nm, float)
        return np.interp(x, wl, direct), np.interp(x, wl, diffuse)

    def with_(self, **changes) -> ClearSky:
        return replace(self, **changes)

    def describe(self) -> dict:
        return {"sky": "clear (SPECTRL2, Bird & Riordan 1986, pvlib)", "sun_zenith_deg": self.sun_zenith_deg,
                "aerosol_optical_depth_500nm": self.aerosol_optical_depth_500nm,
                "precipitable_water_cm": self.precipitable_water_cm, "ozone_atm_cm": self.ozone_atm_cm,
                "pressure_Pa": self.pressure_Pa, "day_of_year": self.day_of_year}


@dataclass(frozen=True, eq=False)
class MeasuredSky:
    """Measured direct and diffuse horizontal spectral irradiance (W m⁻² nm⁻¹, any common scale).

    From a CSV with columns ``wavelength_nm``, ``direct_horizontal`` and ``diffuse_horizontal``
    (:func:`read_sky_csv`); outside its range the values are NaN (the band must lie inside).
    """

    sun_zenith_deg: float
    wavelengths_nm: np.ndarray
    direct_horizontal: np.ndarray
    diffuse_horizontal: np.ndarray
    source: str = ""

    kind = "measured"

    def irradiance(self, wavelengths_nm) -> tuple[np.ndarray, np.ndarray]:
        x = np.asarray(wavelengths_nm, float)
        return (np.interp(x, self.wavelengths_nm, self.direct_horizontal, left=np.nan, right=np.nan),
                np.interp(x, self.wavelengths_nm, self.diffuse_horizontal, left=np.nan, right=np.nan))

    def with_(self, **changes) -> MeasuredSky:
        if "aerosol_optical_depth_500nm" in changes:
            raise CamcalError("a measured sky has no aerosol parameter")
        return replace(self, **changes)

    def describe(self) -> dict:
        return {"sky": "measured", "source": self.source, "sun_zenith_deg": self.sun_zenith_deg}


@dataclass(frozen=True)
class OvercastSky:
    """Diffuse light only (f = 1): the refined model. The sun's position does not enter."""

    sun_zenith_deg: float = 0.0
    kind = "overcast"

    def irradiance(self, wavelengths_nm) -> tuple[np.ndarray, np.ndarray]:
        x = np.asarray(wavelengths_nm, float)
        return np.zeros_like(x), np.ones_like(x)

    def with_(self, **changes) -> OvercastSky:
        return self

    def describe(self) -> dict:
        return {"sky": "overcast (diffuse only)"}


def read_sky_csv(path: str | Path, sun_zenith_deg: float) -> MeasuredSky:
    """A measured sky: CSV with ``wavelength_nm``, ``direct_horizontal``, ``diffuse_horizontal`` (W m⁻² nm⁻¹ on a
    horizontal surface; any common scale); ``#`` lines are comments."""
    path = Path(path)
    text = read_text_file(path, "sky spectrum CSV")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    need = ("wavelength_nm", "direct_horizontal", "diffuse_horizontal")
    if any(n not in header for n in need):
        raise CamcalError(f"sky spectrum CSV needs columns {', '.join(need)} (header is {','.join(header)})", path)
    try:
        v = np.array([[float(c) for c in ln.split(",")] for ln in lines[1:]], dtype=float)
    except ValueError:
        raise CamcalError("sky spectrum CSV: a row is not numbers", path) from None
    if v.ndim != 2 or v.shape[0] < 2 or v.shape[1] != len(header) or not np.all(np.isfinite(v)):
        raise CamcalError("sky spectrum CSV needs at least two complete rows of finite numbers", path)
    wl, d, f = (v[:, header.index(n)] for n in need)
    if np.any(np.diff(wl) <= 0) or np.any(d < 0) or np.any(f < 0) or not np.any(f > 0):
        raise CamcalError("sky spectrum CSV: wavelengths must increase and irradiances be >= 0 (diffuse not all 0)",
                          path)
    return MeasuredSky(float(sun_zenith_deg), wl, d, f, str(path))


@dataclass(frozen=True)
class FieldGeometry:
    """The sun-and-sky geometry over a flat surface (see the module docstring).

    sun_zenith_rad : θs in air; albedo : ρ relative to the reference; n_water; view_angle_rad : camera's air-side
    view angle from nadir; reflectance : 'fresnel' or 'schlick'; transmittance : the sky part's 'exact' (T(θ)
    inside the integral, default) or 'mean' (T̄, E₃ closed form).
    """

    sun_zenith_rad: float = 0.0
    albedo: float = 1.0
    n_water: float = N_WATER
    view_angle_rad: float = 0.0
    reflectance: str = "fresnel"
    transmittance: str = "exact"

    name = "field"
    includes_water = True

    def sky_model(self) -> RefinedModel:
        return RefinedModel(albedo=self.albedo, n_water=self.n_water, view_angle_rad=self.view_angle_rad,
                            reflectance=self.reflectance, transmittance=self.transmittance)

    def refracted_sun_rad(self) -> float:
        """β, the in-water angle of the sun's beam (sin θs = n sin β)."""
        return float(snell(self.sun_zenith_rad, 1.0, self.n_water))

    def direct_form(self) -> ExponentialForm:
        """R_dir(τ) = ρ T(θs) T_up/n² e^(−τ(1/cos β + 1/μv))."""
        view_w = float(snell(self.view_angle_rad, 1.0, self.n_water))
        t_up = float(transmittance(view_w, self.n_water, 1.0, self.reflectance))
        t_down = float(transmittance(self.sun_zenith_rad, 1.0, self.n_water, self.reflectance))
        k = self.albedo * t_down * t_up / self.n_water ** 2
        return ExponentialForm(k, 1.0 / np.cos(self.refracted_sun_rad()) + 1.0 / np.cos(view_w))

    def sky_form(self):
        """R_sky(τ): the refined model's form; with T(θ) inside the integral on ``SKY_NODES`` Gauss-Legendre nodes
        (the refined model's 128 are for its 1e-7 round trip; 32 keep the band ratio within 1e-5 at a quarter
        of the cost, tested)."""
        f = self.sky_model().closed_form()
        if isinstance(f, ExactTransmittanceForm):
            f = replace(f, nodes=SKY_NODES)
        return f


@dataclass(frozen=True, eq=False)
class FieldBandModel(BandModel):
    """The band ratio of a camera channel under sun and sky: R_λ = (1 − f) R_dir + f R_sky integrated over
    c(λ) E_g(λ) (E_g the global horizontal irradiance, the reference's light). ``geometry`` is a
    :class:`FieldGeometry`, ``sky`` a :class:`ClearSky`, :class:`MeasuredSky` or :class:`OvercastSky` (its
    sun zenith overrides the geometry's). ``diffuse_scale`` multiplies the diffuse irradiance (an uncertainty
    knob: 1 nominal). Build with :func:`field_band_model`.
    """

    sky: object = field(default_factory=OvercastSky)
    diffuse_scale: float = 1.0

    @functools.cached_property
    def _light(self) -> tuple[np.ndarray, np.ndarray]:
        """(E_g shape normalised to max 1, diffuse fraction f) on the wavelength grid."""
        direct, diffuse = self.sky.irradiance(np.asarray(self.wavelengths_nm, float))
        diffuse = diffuse * self.diffuse_scale
        glob = direct + diffuse
        if np.any(~np.isfinite(glob)):
            raise CamcalError("the measured sky spectrum does not cover the channel's wavelengths")
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(glob > 0, diffuse / glob, 1.0)
        return glob / np.max(glob), f

    @functools.cached_property
    def _fparts(self):
        wl = np.asarray(self.wavelengths_nm, float)
        s, f = self._light
        w = np.clip(np.asarray(self.sensitivity, float) * s, 0.0, None) * np.gradient(wl)
        if not np.sum(w) > 0:
            raise CamcalError("channel sensitivity is zero everywhere on the grid")
        used = w > 1e-12 * w.max()
        chl = (self.chlorophyll or bricaud_1998()).on(wl[used])
        return w[used] / np.sum(w[used]), chl, self.absorption_background()[used], f[used]

    @property
    def _parts(self):  # the parent's methods that read _parts see the field weights
        return self._fparts[:3]

    def _geom(self) -> FieldGeometry:
        return replace(self.geometry, sun_zenith_rad=float(np.radians(self.sky.sun_zenith_deg)))

    def _mix(self, tau, f):
        """(R_λ, dR_λ/dτ) of the mixture, the sky integral evaluated once."""
        g = self._geom()
        d, s = g.direct_form(), g.sky_form()
        rd = d.ratio(tau)
        if isinstance(s, ExactTransmittanceForm):
            j, dj = s._j(tau)
            att = s.scale * np.exp(-s.view_factor * tau)
            rs, drs = att * j, att * (dj - s.view_factor * j)
        else:
            rs, drs = s.ratio(tau), s.ratio_derivative(tau)
        return (1 - f) * rd + f * rs, -(1 - f) * d.view_factor * rd + f * drs

    def spectral_ratio(self, c_ug_per_L, depth_m: float) -> np.ndarray:
        wl = np.asarray(self.wavelengths_nm, float)
        chl = (self.chlorophyll or bricaud_1998()).on(wl)
        tau = (self.absorption_background() + chl.absorption_per_m(c_ug_per_L)) * depth_m
        return self._mix(tau, self._light[1])[0]

    def ratio(self, c_ug_per_L, depth_m: float):
        w, chl, bg, f = self._fparts
        tau = (bg + chl.absorption_per_m(c_ug_per_L)) * depth_m
        return np.sum(w * self._mix(tau, f)[0], axis=-1)

    def ratio_derivative(self, c_ug_per_L, depth_m: float):
        return self.ratio_and_derivative(c_ug_per_L, depth_m)[1]

    def ratio_and_derivative(self, c_ug_per_L, depth_m: float):
        """(B(C), dB/dC) in one pass."""
        w, chl, bg, f = self._fparts
        tau = (bg + chl.absorption_per_m(c_ug_per_L)) * depth_m
        r, dr = self._mix(tau, f)
        return np.sum(w * r, axis=-1), np.sum(w * dr * depth_m * chl.derivative_per_m(c_ug_per_L), axis=-1)

    def _rebuilt(self, **changes) -> FieldBandModel:
        m = replace(self, **changes)
        return replace(m, illuminant=m._light[0])

    def varied(self, name: str, value: float) -> FieldBandModel:
        """The model with one uncertain input changed: 'sun_zenith' (degrees), 'diffuse_fraction' (relative
        scale of the diffuse irradiance, nominal 1), 'aerosol' (optical depth at 500 nm)."""
        if name == "sun_zenith":
            return self._rebuilt(sky=self.sky.with_(sun_zenith_deg=float(value)))
        if name == "diffuse_fraction":
            return self._rebuilt(diffuse_scale=float(value))
        if name == "aerosol":
            return self._rebuilt(sky=self.sky.with_(aerosol_optical_depth_500nm=max(float(value), 0.0)))
        raise ValueError(f"unknown field input {name!r}")

    def describe(self) -> dict:
        out = super().describe()
        s, f = self._light
        wl = np.asarray(self.wavelengths_nm, float)
        w = np.clip(np.asarray(self.sensitivity, float), 0, None) * s * np.gradient(wl)
        out.update({"geometry": "field (sun + sky, flat surface)", "light": self.sky.describe(),
                    "diffuse_fraction_in_band": float(np.sum(w * f) / np.sum(w)),
                    "sky_transmittance": self.geometry.transmittance})
        return out


def field_band_model(wavelengths_nm, sensitivity, *, sky, geometry: FieldGeometry | None = None, chlorophyll=None,
                     water_absorption_per_m=None, background_absorption_per_m=0.0,
                     sensitivity_sigma=None) -> FieldBandModel:
    """A :class:`FieldBandModel` of one channel c(λ) under ``sky`` (its illuminant the global irradiance)."""
    m = FieldBandModel(np.asarray(wavelengths_nm, float), np.asarray(sensitivity, float),
                       geometry=geometry or FieldGeometry(), chlorophyll=chlorophyll,
                       background_absorption_per_m=background_absorption_per_m,
                       water_absorption_per_m=water_absorption_per_m, sensitivity_sigma=sensitivity_sigma, sky=sky)
    return replace(m, illuminant=m._light[0])

"""A phone camera in the synthetic world: measured small-sensor curves, the camera, its sunlit scenes.

**Curves.** The spectral sensitivities are those of real phone-class sensors (Sony IMX219, OmniVision OV5647:
1.1-1.4 µm pixels, the sensors of phone camera modules and of the Raspberry Pi cameras), none of them in the
bundled 52-camera library, so an estimator whose basis was learnt from that library meets a new camera. The
shipped tables (``calibration_data/camera_curves/phone/``) are each manufacturer's published relative quantum
efficiency of the bare sensor with its Bayer filters, 400-700 nm. A phone module adds a UV-IR-cut filter in
front of the sensor; :func:`phone_sensitivities` models it as two logistic edges (a phone hot mirror passes half
at about 650 nm and falls from 90 % to 10 % within ~30 nm) and holds the sensor's QE outside 400-700 nm at its
end values (not measured there), so that the product falls smoothly to zero outside the pass band.

**Camera** (:class:`PhoneParams`, :class:`PhoneCamera`): the signal chain of
:class:`camcal.synth.camera.SyntheticCamera` (photon noise, read noise, dark current, PRNU, quantisation) with a
phone's numbers: 1.12 µm pixels, a full well of 4500 e⁻, 2 e⁻ read noise, 10-bit RAW, base ISO 50, a fixed f/1.8
lens, and the natural falloff of a wide lens, cos⁴θ with tan θ = (r / r_corner) tan θ_corner (θ_corner = 37.4°:
0.40 at the corners), represented within 1e-4 of the gain by the DNG radial polynomial the camera
uses (least squares in r², r⁴ … r¹⁰). The pinhole focal length follows from the same corner field angle, so the
chart's perspective and the falloff share one lens; every file's EXIF states it as a phone's does, FocalLength
(mm) and FocalLengthIn35mmFilm (21.63 mm / tan θ_corner, in whole mm: 28 mm at 37.4°). The RAW is a Bayer DNG
(``synth.dng``); the processed photo
is an 8-bit HEIC (``synth.heic``) made as a phone's pipeline does (:meth:`PhoneCamera.process`): black removed and
scaled, optional lens-shading correction, white-balance gains, a 3×3 colour matrix, a tone curve (sRGB, or a
filmic shoulder before sRGB), 2× nearest-neighbour up-sampling of the superpixel demosaic, 8-bit quantisation.

**Scenes**, lit by the clear-sky SPECTRL2 sun and sky of :class:`camcal.synth.sunlit.SunSky` at the photo's time
and place (solar position from pvlib's SPA):

- a horizontal X-Rite ColorChecker Classic (4×6 patches in a black card) on a grey ground, seen in perspective,
  L = ρ(λ)(DNI cos θs + DHI)/π, ρ a *measured* chart (colour-science's 'ColorChecker N Ohta' by default, which
  differs from the 'BabelColor Average' an estimator assumes by 0.5-5 % reflectance RMS per patch), each pixel's
  coverage of patch, card and ground from 4×4 sub-samples through the chart's homography;
- a uniform grey field under the same light;
- uniform photos of a diffuse surface (a relative flat);
- sunlit Secchi-disk photos, rendered by :func:`camcal.synth.sunlit.sunlit_scenes`.

None of this calls an estimator: the chart, grey and flat radiances are the reflectance times the light,
integrated over the camera's true c(λ) by the camera model.

References
----------
Bird, R. E., Riordan, C. (1986). J. Climate Appl. Meteor. 25, 87-97 (SPECTRL2). Reda, I., Andreas, A. (2004).
Solar Energy 76, 577-589 (SPA). Ohta, N. (1997), ColorChecker spectral reflectances (colour-science
``SDS_COLOURCHECKERS['ColorChecker N Ohta']``). McCamy, C. S., Marcus, H., Davidson, J. G. (1976). A colour-rendition
chart. J. Appl. Photogr. Eng. 2(3), 95-99 (the chart's layout). IEC 61966-2-1:1999 (sRGB).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas as pd
import pvlib
from skimage.transform import ProjectiveTransform

from camcal.errors import CamcalError
from camcal.frame import rgb_from_planes
from camcal.io.data import read_bundled_table
from camcal.models.falloff import HALF_DIAGONAL_35MM_MM
from camcal.models.spectra import WAVELENGTHS_NM
from camcal.synth.camera import Scene, SensorParams, SyntheticCamera, frame_rngs, save_truth, write_jpeg_file
from camcal.synth.exif import PlaceTime
from camcal.synth.heic import write_heic
from camcal.synth.secchi import suggest_exposure_s
from camcal.synth.sunlit import SunSky, reference_disk_radiance, sunlit_scenes, write_sunlit_pair
from camcal.synth.targets import grey_card_reflectance
from camcal.synth.tone import srgb_encode
from camcal.units import DN_PER_S, SPECTRAL_RADIANCE, SPECTRAL_SENSITIVITY

PHONE_SENSORS: dict[str, str] = {
    "imx219": "camera_curves/phone/imx219_qe_400_700_1.csv",
    "ov5647": "camera_curves/phone/ov5647_qe_400_700_1.csv",
}
"""Shipped phone-class sensor curves: key → file in ``calibration_data``."""

SENSOR_NAMES: dict[str, str] = {"imx219": "Sony IMX219", "ov5647": "OmniVision OV5647"}


@dataclass(frozen=True)
class PhoneCurves:
    """Relative spectral sensitivities of a phone camera (sensor × UV-IR-cut filter).

    ``r``, ``g``, ``b`` are dimensionless on ``wavelength_nm`` (nm), each peaking at 1;
    ``channel_peaks`` are the sensor's published peak QE of R, G, B relative to the largest
    (the ratio between channels that the per-channel normalisation removes).
    """

    sensor: str
    wavelength_nm: np.ndarray
    r: np.ndarray
    g: np.ndarray
    b: np.ndarray
    channel_peaks: tuple[float, float, float]
    uv_cut_nm: float | None
    ir_cut_nm: float | None
    source: str

    @property
    def rgb(self) -> np.ndarray:
        """(3, n) R, G, B."""
        return np.stack([self.r, self.g, self.b])


def cut_filter_transmittance(
    wavelengths_nm: np.ndarray, uv_cut_nm: float | None = 400.0, ir_cut_nm: float | None = 650.0,
    uv_width_nm: float = 5.0, ir_width_nm: float = 7.0,
) -> np.ndarray:
    """Transmittance (0..1) of a phone's UV-IR-cut filter: logistic edges, 0.5 at ``uv_cut_nm`` and ``ir_cut_nm``.

    T(λ) = 1/(1 + exp((λ_uv − λ)/w_uv)) · 1/(1 + exp((λ − λ_ir)/w_ir)); an edge of None is absent.
    With w_ir = 7 nm the IR edge falls from 90 % to 10 % over 31 nm (4.4 w), as phone hot mirrors do.
    """
    wl = np.asarray(wavelengths_nm, float)
    t = np.ones_like(wl)
    if uv_cut_nm is not None:
        t = t / (1.0 + np.exp((uv_cut_nm - wl) / uv_width_nm))
    if ir_cut_nm is not None:
        t = t / (1.0 + np.exp((wl - ir_cut_nm) / ir_width_nm))
    return t


def sensor_qe_table(sensor: str = "imx219") -> tuple[np.ndarray, np.ndarray]:
    """The shipped table of ``sensor``: wavelength (nm) and (3, n) relative QE of R, G, B (fraction, as published)."""
    if sensor not in PHONE_SENSORS:
        raise CamcalError(f"unknown phone sensor {sensor!r}; choose from {', '.join(PHONE_SENSORS)}")
    header, values = read_bundled_table(PHONE_SENSORS[sensor])
    if header != ["wavelength_nm", "red_qe", "green_qe", "blue_qe"]:
        raise CamcalError(f"shipped table {PHONE_SENSORS[sensor]} has unexpected columns {header}")
    return values[:, 0], np.clip(values[:, 1:].T / 100.0, 0.0, None)


def phone_sensitivities(
    sensor: str = "imx219",
    wavelengths_nm: np.ndarray = WAVELENGTHS_NM,
    *,
    uv_cut_nm: float | None = 400.0,
    ir_cut_nm: float | None = 650.0,
) -> PhoneCurves:
    """Measured phone-sensor curves through a modelled UV-IR-cut filter, on ``wavelengths_nm``.

    The sensor's QE (linear interpolation of the 1 nm table) is held at its end values outside
    400-700 nm and multiplied by :func:`cut_filter_transmittance`; each channel is then divided by
    its peak. With both edges None the result is the bare sensor, zero outside 400-700 nm.

    Parameters
    ----------
    sensor
        A key of :data:`PHONE_SENSORS` (``"imx219"``, ``"ov5647"``).
    wavelengths_nm
        Output grid, nm (default the camcal grid 380-780 nm / 1 nm).
    uv_cut_nm, ir_cut_nm
        Half-transmission wavelengths of the filter's edges, nm (None: that edge absent).
    """
    wl_tab, qe = sensor_qe_table(sensor)
    wl = np.asarray(wavelengths_nm, float)
    bare = uv_cut_nm is None and ir_cut_nm is None
    out = np.empty((3, wl.size))
    for i in range(3):
        if bare:
            out[i] = np.interp(wl, wl_tab, qe[i], left=0.0, right=0.0)
        else:
            out[i] = np.interp(wl, wl_tab, qe[i]) * cut_filter_transmittance(wl, uv_cut_nm, ir_cut_nm)
    peaks = out.max(axis=1)
    if np.any(peaks <= 0):
        raise CamcalError(f"phone sensor {sensor!r} has no response on the requested grid")
    rel = peaks / peaks.max()
    out = out / peaks[:, None]
    return PhoneCurves(
        sensor=sensor, wavelength_nm=wl, r=out[0], g=out[1], b=out[2],
        channel_peaks=(float(rel[0]), float(rel[1]), float(rel[2])),
        uv_cut_nm=uv_cut_nm, ir_cut_nm=ir_cut_nm,
        source=f"calibration_data/{PHONE_SENSORS[sensor]} ({SENSOR_NAMES[sensor]}, manufacturer's published QE)",
    )


# ---- the camera ---------------------------------------------------------------------------------------------

DEFAULT_COLOUR_MATRIX: tuple[tuple[float, float, float], ...] = (
    (1.62, -0.47, -0.15),
    (-0.24, 1.46, -0.22),
    (0.02, -0.51, 1.49),
)
"""Camera RGB (white-balanced) → output RGB of the synthetic phone's pipeline; each row sums to 1 (white stays
white). A matrix of the size phones use to reach sRGB primaries from a small sensor's broad filters."""


@dataclass(frozen=True)
class PhoneParams:
    """Parameters of the synthetic phone (the ground truth of its photos). Units in the names.

    Sizes are full-resolution mosaic pixels; a test image (600×400) is a phone sensor at reduced resolution
    with the pixel of the full sensor (the radiometry per pixel is that of a 1.12 µm pixel).
    """

    sensor: str = "imx219"
    """Key of :data:`PHONE_SENSORS`: the measured curves."""
    width: int = 600
    height: int = 400
    cfa_pattern: str = "BGGR"
    bit_depth: int = 10
    black_level_dn: float = 64.0
    white_level_dn: int = 1023
    gain_e_per_dn: float = 4.4
    """System gain at the base ISO, e⁻/DN (959 DN above black hold 4220 e⁻: the DN range clips before the well)."""
    iso_base: float = 50.0
    full_well_e: float = 4500.0
    read_noise_e: float = 2.0
    dark_current_e_per_s: float = 5.0
    prnu_sigma: float = 0.008
    pixel_pitch_um: float = 1.12
    f_number: float = 1.8
    """The fixed aperture, written to every file's EXIF."""
    lens_transmittance: float = 0.9
    qe_peak: float = 0.7
    """Peak QE of the most sensitive channel; the others by the sensor's published channel ratios."""
    uv_cut_nm: float | None = 400.0
    ir_cut_nm: float | None = 650.0
    corner_field_angle_deg: float = 37.4
    """Field angle at the image corner farthest from the optical centre: cos⁴ gives the corner gain (0.40)."""
    optical_centre: tuple[float, float] = (0.5, 0.5)
    """Optical centre (principal point) as fractions of width and height."""
    white_balance: tuple[float, float, float] | None = None
    """White-balance gains R, G, B of the processed photos, locked for every photo; None: the phone's daylight
    preset, the gains that make a white under CIE D55 neutral for this sensor (:meth:`PhoneCamera.wb_gains`)."""
    colour_matrix: tuple[tuple[float, float, float], ...] = DEFAULT_COLOUR_MATRIX
    tone: str = "srgb"
    """Tone curve of the processed photos: ``srgb`` (IEC 61966-2-1) or ``filmic`` (:func:`filmic_encode`)."""
    filmic_shoulder: float = 1.5
    lens_shading_correction: float = 0.0
    """Fraction (0..1) of the falloff the processed photos remove (g**-s); 0: none, as in the RAW."""
    heic_quality: int = 90
    heic_preset: str | None = "ultrafast"
    """x265 speed preset of the HEIC encoder (a phone's hardware encoder is fast too); None: libheif's default."""
    make: str = "camcal"
    model: str | None = None
    """EXIF model; None: ``Synthetic Phone <sensor>``."""
    serial: str = "SYNPHONE1"
    seed: int = 1

    def __post_init__(self) -> None:
        if self.sensor not in PHONE_SENSORS:
            raise CamcalError(f"unknown phone sensor {self.sensor!r}; choose from {', '.join(PHONE_SENSORS)}")
        if self.tone not in ("srgb", "filmic"):
            raise CamcalError(f"unknown phone tone curve {self.tone!r}; choose srgb or filmic")
        if not 0.0 <= self.lens_shading_correction <= 1.0:
            raise CamcalError("lens_shading_correction must be in [0, 1]")
        if not 0.0 < self.corner_field_angle_deg < 80.0:
            raise CamcalError("corner_field_angle_deg must be in (0, 80)")
        m = np.asarray(self.colour_matrix, float)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise CamcalError("colour_matrix must be a finite 3x3 matrix")

    @property
    def model_name(self) -> str:
        return self.model or f"Synthetic Phone {SENSOR_NAMES[self.sensor].split()[-1]}"

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


def cos4_falloff(r: np.ndarray, corner_field_angle_deg: float) -> np.ndarray:
    """Relative illumination cos⁴θ of a distortion-free lens, tan θ = r tan θ_corner, r = radius / corner radius."""
    t2 = np.tan(np.radians(corner_field_angle_deg)) ** 2
    return (1.0 + np.asarray(r, float) ** 2 * t2) ** -2


def cos4_radial_k(corner_field_angle_deg: float) -> tuple[float, float, float, float, float]:
    """DNG ``FixVignetteRadial`` k0..k4 of :func:`cos4_falloff`: least squares in r², …, r¹⁰ over 0 ≤ r ≤ 1,
    weighted by √r (pixels lie on rings of circumference ∝ r); within 1e-4 of the gain at 37.4°."""
    r = np.linspace(0.0, 1.0, 2001)
    g = cos4_falloff(r, corner_field_angle_deg)
    a = np.stack([r ** (2 * i) for i in range(1, 6)], axis=1)
    w = np.sqrt(r + 1e-3)
    k = np.linalg.lstsq(a * w[:, None], (g - 1.0) * w, rcond=None)[0]
    return tuple(float(v) for v in k)  # type: ignore[return-value]


def filmic_encode(x: np.ndarray, shoulder: float = 1.5) -> np.ndarray:
    """A phone-like filmic tone curve: the shoulder y = (1 + s) x / (1 + s x) (1 → 1, shadows lifted by 1 + s,
    highlights compressed; Reinhard et al. 2002, eq. 3 scaled to keep white) followed by the sRGB encoding."""
    x = np.clip(np.asarray(x, float), 0.0, 1.0)
    return srgb_encode((1.0 + shoulder) * x / (1.0 + shoulder * x))


class PhoneCamera(SyntheticCamera):
    """The synthetic phone: :class:`SyntheticCamera` with the phone's sensor, curves, lens and processing."""

    def __init__(self, phone: PhoneParams | None = None) -> None:
        self.phone = phone or PhoneParams()
        ph = self.phone
        curves = phone_sensitivities(ph.sensor, WAVELENGTHS_NM, uv_cut_nm=ph.uv_cut_nm, ir_cut_nm=ph.ir_cut_nm)
        self.curves = curves
        black = float(ph.black_level_dn)
        params = SensorParams(
            width=ph.width, height=ph.height, cfa_pattern=ph.cfa_pattern, bit_depth=ph.bit_depth,
            black_level_dn=(black, black, black, black), white_level_dn=ph.white_level_dn,
            gain_e_per_dn=ph.gain_e_per_dn, iso_base=ph.iso_base, read_noise_e=ph.read_noise_e,
            full_well_e=ph.full_well_e, dark_current_e_per_s=(ph.dark_current_e_per_s,) * 4,
            hot_pixel_fraction=1e-4, bias_pattern_dn=0.05, prnu_sigma=ph.prnu_sigma,
            vignetting_k=cos4_radial_k(ph.corner_field_angle_deg), optical_centre=ph.optical_centre,
            pixel_pitch_um=ph.pixel_pitch_um, focal_length_mm=None, lens_transmittance=ph.lens_transmittance,
            qe_peak=tuple(ph.qe_peak * c for c in curves.channel_peaks),  # type: ignore[arg-type]
            sensitivity=f"phone:{ph.sensor}", reference_iso=ph.iso_base, reference_f_number=ph.f_number,
            make=ph.make, model=ph.model_name, serial=ph.serial, seed=ph.seed,
        )
        super().__init__(params)
        self.params = dataclasses.replace(
            params, focal_length_mm=self.focal_length_px * ph.pixel_pitch_um * 1e-3,
            focal_length_35mm_mm=HALF_DIAGONAL_35MM_MM / float(np.tan(np.radians(ph.corner_field_angle_deg))))

    # ---- optics ----------------------------------------------------------------------------------------------
    @property
    def corner_radius_px(self) -> float:
        """Distance from the optical centre to the farthest image corner, full-resolution pixels."""
        p = self.params
        cx, cy = self.optical_centre_px
        return float(max(np.hypot(x - cx, y - cy) for x in (0, p.width - 1) for y in (0, p.height - 1)))

    @property
    def focal_length_px(self) -> float:
        """Pinhole focal length, pixels: the corner radius over tan θ_corner (the lens of the falloff)."""
        return self.corner_radius_px / float(np.tan(np.radians(self.phone.corner_field_angle_deg)))

    def falloff_at(self, x_px, y_px) -> np.ndarray:
        """The lens's cos⁴ relative illumination at full-resolution pixel positions (the model the radial
        polynomial of the RAW represents)."""
        cx, cy = self.optical_centre_px
        r = np.hypot(np.asarray(x_px, float) - cx, np.asarray(y_px, float) - cy) / self.corner_radius_px
        return cos4_falloff(r, self.phone.corner_field_angle_deg)

    def radial_gain_at(self, x_px, y_px) -> np.ndarray:
        """The relative illumination the camera applies (its DNG radial polynomial) at pixel positions."""
        cx, cy = self.optical_centre_px
        r2 = ((np.asarray(x_px, float) - cx) ** 2 + (np.asarray(y_px, float) - cy) ** 2) / self.corner_radius_px**2
        g = np.ones_like(r2)
        for i, k in enumerate(self.params.vignetting_k):
            g = g + k * r2 ** (i + 1)
        return g

    @cached_property
    def qe(self) -> np.ndarray:
        """(3, n) QE of R, G, B on :data:`WAVELENGTHS_NM`: the measured curves × the filter × the peak QE."""
        return self.curves.rgb * np.asarray(self.params.qe_peak)[:, None]

    # ---- processing ------------------------------------------------------------------------------------------
    @cached_property
    def wb_gains(self) -> tuple[float, float, float]:
        """White-balance gains R, G, B (G = 1) of the processed photos (:attr:`PhoneParams.white_balance`)."""
        if self.phone.white_balance is not None:
            return tuple(float(g) for g in self.phone.white_balance)  # type: ignore[return-value]
        import colour  # loads matplotlib: kept off paths that do not plot

        d55 = colour.SDS_ILLUMINANTS["D55"]
        e = np.interp(WAVELENGTHS_NM, d55.wavelengths, d55.values)
        rates = self.channel_rates_e(e, self.phone.f_number)
        return (float(rates[1] / rates[0]), 1.0, float(rates[1] / rates[2]))

    def process(self, planes_dn: np.ndarray) -> np.ndarray:
        """The phone's pipeline: (4, h, w) RAW planes → (H, W, 3) uint8 processed image (module docstring).

        x = (DN − black)/(white − black) (G the mean of G1, G2), clipped to [0, 1]; × g^−s (lens shading,
        s = :attr:`PhoneParams.lens_shading_correction`); × the white-balance gains, clipped; the colour matrix,
        clipped; the tone curve; 2× up-sampled; round(255 y).
        """
        lin = self.linear_rgb(planes_dn)
        s = self.phone.lens_shading_correction
        if s > 0:
            lin = lin * rgb_from_planes(self.vignetting_map) ** (-s)
        lin = np.clip(lin * np.asarray(self.wb_gains)[:, None, None], 0.0, 1.0)
        m = np.asarray(self.phone.colour_matrix, float)
        lin = np.clip(np.einsum("ij,jhw->ihw", m, lin), 0.0, 1.0)
        enc = srgb_encode(lin) if self.phone.tone == "srgb" else filmic_encode(lin, self.phone.filmic_shoulder)
        full = np.repeat(np.repeat(enc, 2, axis=1), 2, axis=2)
        return np.moveaxis(np.clip(np.rint(full * 255.0), 0, 255).astype(np.uint8), 0, -1)

    def encode_processed(self, linear_rgb: np.ndarray) -> np.ndarray:
        """The pipeline after the RAW for a linear camera RGB value (…, 3) in [0, 1] (no noise, no up-sampling):
        lens shading excluded, white balance, matrix, tone; returns the encoded value in [0, 1]."""
        lin = np.clip(np.asarray(linear_rgb, float) * np.asarray(self.wb_gains), 0.0, 1.0)
        lin = np.clip(lin @ np.asarray(self.phone.colour_matrix, float).T, 0.0, 1.0)
        return srgb_encode(lin) if self.phone.tone == "srgb" else filmic_encode(lin, self.phone.filmic_shoulder)

    def render_processed(self, scene: Scene, *, exposure_s: float, iso: float | None = None,
                         f_number: float | None = None, rng: np.random.Generator, **_ignored) -> np.ndarray:
        """Expose and process (:meth:`process`); the phone's own pipeline replaces the generic tone options."""
        planes = self.expose_planes(scene, exposure_s=exposure_s, iso=iso, f_number=self.phone.f_number, rng=rng)
        return self.process(planes)

    def write_dng(self, path, scene: Scene, *, exposure_s: float, iso: float | None = None, rng: np.random.Generator,
                  place: PlaceTime | None = None, f_number: float | None = None, **kwargs) -> Path:
        """A Bayer DNG (10-bit, FNumber = the fixed aperture); ``f_number`` other than the phone's is refused."""
        self._check_aperture(f_number)
        return super().write_dng(path, scene, exposure_s=exposure_s, iso=iso, f_number=self.phone.f_number, rng=rng,
                                 place=place, **kwargs)

    def write_heic(self, path, scene: Scene, *, exposure_s: float, iso: float | None = None,
                   rng: np.random.Generator, place: PlaceTime | None = None, capture_time=None,
                   f_number: float | None = None, **_ignored) -> Path:
        """An 8-bit HEIC of the phone's pipeline with the EXIF (exposure, f/1.8, ISO, time, GPS)."""
        self._check_aperture(f_number)
        iso = self.params.iso_base if iso is None else iso
        img = self.render_processed(scene, exposure_s=exposure_s, iso=iso, rng=rng)
        return write_heic(path, img, bits=8, quality=self.phone.heic_quality, preset=self.phone.heic_preset,
                          exposure_s=exposure_s,
                          f_number=self.phone.f_number, iso=iso, make=self.params.make, model=self.params.model,
                          capture_time=capture_time, place=place, focal_length_mm=self.params.focal_length_mm,
                          focal_length_35mm_mm=self.params.focal_length_35mm_mm)

    def write_jpeg(self, path, scene: Scene, *, exposure_s: float, iso: float | None = None,
                   rng: np.random.Generator, place: PlaceTime | None = None, capture_time=None,
                   f_number: float | None = None, **_ignored) -> Path:
        """A JPEG of the same pipeline (quality 95, 4:4:4), with the EXIF."""
        self._check_aperture(f_number)
        iso = self.params.iso_base if iso is None else iso
        img = self.render_processed(scene, exposure_s=exposure_s, iso=iso, rng=rng)
        return write_jpeg_file(path, img, exposure_s=exposure_s, f_number=self.phone.f_number, iso=iso,
                               make=self.params.make, model=self.params.model, quality=95,
                               capture_time=capture_time, place=place, focal_length_mm=self.params.focal_length_mm,
                               focal_length_35mm_mm=self.params.focal_length_35mm_mm)

    def _check_aperture(self, f_number: float | None) -> None:
        if f_number is not None and abs(float(f_number) - self.phone.f_number) > 1e-9:
            raise CamcalError(f"the phone's aperture is fixed at f/{self.phone.f_number:g}, not f/{f_number:g}")

    def truth(self, iso: float | None = None) -> dict:
        """:meth:`SyntheticCamera.truth` plus the phone: its parameters, curves, lens and processing."""
        t = super().truth(iso)
        t["phone"] = self.phone.to_json()
        t["curves"] = {"sensor": self.curves.sensor, "source": self.curves.source,
                       "uv_cut_nm": self.curves.uv_cut_nm, "ir_cut_nm": self.curves.ir_cut_nm,
                       "channel_peaks": list(self.curves.channel_peaks),
                       "filter": "logistic edges, widths 5 nm (UV) and 7 nm (IR); cut_filter_transmittance"}
        t["vignetting"]["model"] = (f"dng-radial: least-squares fit of cos^4 (corner field angle "
                                    f"{self.phone.corner_field_angle_deg:g} deg, cos4_radial_k)")
        t["vignetting"]["corner_radius_px"] = self.corner_radius_px
        t["lens"] = {"f_number": self.phone.f_number, "focal_length_px": self.focal_length_px,
                     "focal_length_mm": self.params.focal_length_mm,
                     "focal_length_35mm_mm": self.params.focal_length_35mm_mm,
                     "exif_focal_length_35mm_mm": int(round(self.params.focal_length_35mm_mm)),
                     "fixed_aperture": True}
        t["processing"] = {"white_balance": list(self.wb_gains),
                           "white_balance_source": "given" if self.phone.white_balance else "daylight preset (D55)",
                           "colour_matrix": [list(r) for r in self.phone.colour_matrix],
                           "tone": self.phone.tone, "filmic_shoulder": self.phone.filmic_shoulder,
                           "lens_shading_correction": self.phone.lens_shading_correction,
                           "demosaic": "superpixel (G = mean of G1, G2), 2x nearest-neighbour up-sampling",
                           "bits": 8, "heic_quality": self.phone.heic_quality,
                           "order": "black, scale to [0,1], clip, lens shading, white balance, clip, matrix, clip, "
                                    "tone, up-sample, 8-bit"}
        return t


# ---- the light ----------------------------------------------------------------------------------------------

DEFAULT_PLACE = PlaceTime(pd.Timestamp("2026-06-21T10:30:00Z").to_pydatetime(), utc_offset_min=120,
                          latitude_deg=46.45, longitude_deg=6.55, altitude_m=372.0)
"""Where and when the default phone photos are taken: Lake Geneva near local noon at the June solstice (the sun
~24° from the zenith)."""


def sun_sky_at(place: PlaceTime, *, aerosol_optical_depth_500nm: float = 0.1, precipitable_water_cm: float = 1.42,
               ozone_atm_cm: float = 0.344, pressure_Pa: float = 101325.0) -> SunSky:
    """The SPECTRL2 day of a photo: the apparent solar zenith and the azimuth at ``place`` (pvlib SPA, Reda &
    Andreas 2004), the day of the year of its UTC date, and the atmosphere given.

    Raises
    ------
    CamcalError
        No GPS position, or the sun lower than 80° from the zenith (SPECTRL2's clear-sky model is then poor).
    """
    if place.latitude_deg is None or place.longitude_deg is None:
        raise CamcalError("a sunlit phone photo needs a GPS position (latitude, longitude)")
    u = place.utc_aware
    pos = pvlib.solarposition.get_solarposition(pd.DatetimeIndex([pd.Timestamp(u)]), place.latitude_deg,
                                                place.longitude_deg, altitude=place.altitude_m or 0.0)
    zen = float(pos["apparent_zenith"].iloc[0])
    if not zen < 80.0:
        raise CamcalError(f"the sun stands {zen:.1f}° from the zenith at {u.isoformat()}: choose a time with the sun "
                          "higher than 10° above the horizon")
    return SunSky(sun_zenith_deg=zen, sun_azimuth_deg=float(pos["azimuth"].iloc[0]),
                  aerosol_optical_depth_500nm=aerosol_optical_depth_500nm, precipitable_water_cm=precipitable_water_cm,
                  ozone_atm_cm=ozone_atm_cm, pressure_Pa=pressure_Pa, day_of_year=int(u.timetuple().tm_yday))


def horizontal_irradiance(sky: SunSky, wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> np.ndarray:
    """Global irradiance on a horizontal surface, DNI cos θs + DHI, W m⁻² nm⁻¹ (SPECTRL2 via :class:`SunSky`)."""
    return np.pi * reference_disk_radiance(sky, 1.0, wavelengths_nm)


def sky_truth(sky: SunSky) -> dict:
    """The light of a set of photos, JSON-ready (SPECTRL2 inputs, and the horizontal irradiance on the grid)."""
    e = horizontal_irradiance(sky)
    return {"model": "SPECTRL2 (pvlib.spectrum.spectrl2): DNI cos(zenith) + DHI on a horizontal surface",
            **{k: getattr(sky, k) for k in sky.__dataclass_fields__},
            "wavelength_nm": WAVELENGTHS_NM.tolist(), "horizontal_irradiance_W_m2_nm": e.tolist()}


# ---- the colour chart ---------------------------------------------------------------------------------------

CHART_PATCHES = 24
CHART_ROWS, CHART_COLUMNS = 4, 6


@dataclass(frozen=True)
class ChartLayout:
    """An X-Rite ColorChecker Classic card, millimetres: 4×6 square patches in a black card.

    The swatch grid (6 × 39 + 5 × 7.5 by 4 × 39 + 3 × 7.5 mm: aspect 1.52) is centred on the card.
    """

    card_mm: tuple[float, float] = (279.4, 215.9)
    patch_mm: float = 39.0
    gap_mm: float = 7.5
    card_reflectance: float = 0.02
    """The black card around the patches (flat)."""

    @property
    def grid_mm(self) -> tuple[float, float]:
        return (CHART_COLUMNS * self.patch_mm + (CHART_COLUMNS - 1) * self.gap_mm,
                CHART_ROWS * self.patch_mm + (CHART_ROWS - 1) * self.gap_mm)

    @property
    def grid_origin_mm(self) -> tuple[float, float]:
        gw, gh = self.grid_mm
        return ((self.card_mm[0] - gw) / 2.0, (self.card_mm[1] - gh) / 2.0)

    def patch_corners_mm(self, index: int) -> np.ndarray:
        """(4, 2) corners TL, TR, BR, BL of patch ``index`` (row-major from the top-left), card coordinates."""
        r, c = divmod(index, CHART_COLUMNS)
        x0 = self.grid_origin_mm[0] + c * (self.patch_mm + self.gap_mm)
        y0 = self.grid_origin_mm[1] + r * (self.patch_mm + self.gap_mm)
        s = self.patch_mm
        return np.array([[x0, y0], [x0 + s, y0], [x0 + s, y0 + s], [x0, y0 + s]])

    def label(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """Label of card points: patch 0..23, 24 the black card, 25 outside the card (the ground)."""
        x, y = np.asarray(x_mm, float), np.asarray(y_mm, float)
        ox, oy = self.grid_origin_mm
        pitch = self.patch_mm + self.gap_mm
        cx, cy = (x - ox) / pitch, (y - oy) / pitch
        col, row = np.floor(cx), np.floor(cy)
        inside = ((0 <= col) & (col < CHART_COLUMNS) & (0 <= row) & (row < CHART_ROWS)
                  & ((cx - col) * pitch < self.patch_mm) & ((cy - row) * pitch < self.patch_mm))
        out = np.where((0 <= x) & (x < self.card_mm[0]) & (0 <= y) & (y < self.card_mm[1]), CHART_PATCHES,
                       CHART_PATCHES + 1)
        return np.where(inside, (row * CHART_COLUMNS + col).astype(int), out)


@dataclass(frozen=True)
class ChartPose:
    """Where the card lies in the photo: the pinhole camera of :class:`PhoneCamera` sees the card turned by
    ``tilt_deg`` about its horizontal axis (0: square to the camera; > 0: its top edge farther away, as a card
    lying on the ground looks from a standing photographer), ``yaw_deg`` about its vertical axis and
    ``roll_deg`` in the image plane, its centre at ``centre_fraction`` of the image, ``width_fraction`` of the
    image width across (at its centre line)."""

    tilt_deg: float = 20.0
    yaw_deg: float = 5.0
    roll_deg: float = 3.0
    centre_fraction: tuple[float, float] = (0.5, 0.48)
    width_fraction: float = 0.45


def _rotation(tilt_deg: float, yaw_deg: float, roll_deg: float) -> np.ndarray:
    a, b, c = np.radians([-tilt_deg, yaw_deg, roll_deg])  # tilt > 0: the card's top edge away from the camera
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


def chart_homography(camera: PhoneCamera, layout: ChartLayout = ChartLayout(),
                     pose: ChartPose = ChartPose()) -> ProjectiveTransform:
    """The projective map card millimetres → full-resolution image pixels (x right, y down; pixel centres at
    integers) of a flat card posed by ``pose`` in front of the camera's pinhole (focal length
    :attr:`PhoneCamera.focal_length_px`, principal point the optical centre)."""
    p = camera.params
    f = camera.focal_length_px
    cx, cy = camera.optical_centre_px
    w_mm, h_mm = layout.card_mm
    corners = np.array([[0, 0], [w_mm, 0], [w_mm, h_mm], [0, h_mm]], float)
    local = np.column_stack([corners - [w_mm / 2, h_mm / 2], np.zeros(4)])
    rot = _rotation(pose.tilt_deg, pose.yaw_deg, pose.roll_deg)
    u0, v0 = pose.centre_fraction[0] * (p.width - 1), pose.centre_fraction[1] * (p.height - 1)
    direction = np.array([(u0 - cx) / f, (v0 - cy) / f, 1.0])
    dist = f * w_mm / (pose.width_fraction * p.width)
    for _ in range(4):  # scale the distance until the card's middle spans width_fraction of the image
        pts = local @ rot.T + dist * direction
        img = np.column_stack([cx + f * pts[:, 0] / pts[:, 2], cy + f * pts[:, 1] / pts[:, 2]])
        span = 0.5 * (np.linalg.norm(img[1] - img[0]) + np.linalg.norm(img[2] - img[3]))
        dist *= span / (pose.width_fraction * p.width)
    pts = local @ rot.T + dist * direction
    img = np.column_stack([cx + f * pts[:, 0] / pts[:, 2], cy + f * pts[:, 1] / pts[:, 2]])
    tform = ProjectiveTransform.from_estimate(corners, img)
    if not tform:
        raise CamcalError("the chart pose gives no valid homography")
    if np.any(img[:, 0] < 0) or np.any(img[:, 0] > p.width - 1) or np.any(img[:, 1] < 0) or \
            np.any(img[:, 1] > p.height - 1):
        raise CamcalError("the chart pose puts part of the card outside the image")
    return tform


def chart_label_weights(camera: PhoneCamera, tform: ProjectiveTransform, layout: ChartLayout = ChartLayout(),
                        supersample: int = 4) -> np.ndarray:
    """(26, H, W) float32 coverage of every pixel by patch 0..23, the black card (24) and the ground (25),
    from ``supersample``² points per pixel mapped back to the card (they sum to 1 per pixel)."""
    p = camera.params
    n = int(supersample)
    nlab = CHART_PATCHES + 2
    off = (np.arange(n) + 0.5) / n - 0.5
    inv = np.linalg.inv(tform.params)
    out = np.zeros((p.height, p.width, nlab), np.float32)
    xs = (np.arange(p.width)[:, None] + off[None, :]).ravel()
    rows_per_block = max(1, 1_000_000 // (p.width * n * n))
    for y0 in range(0, p.height, rows_per_block):
        y1 = min(p.height, y0 + rows_per_block)
        ys = (np.arange(y0, y1)[:, None] + off[None, :]).ravel()
        gx, gy = np.meshgrid(xs, ys)
        q = inv @ np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
        lab = layout.label(q[0] / q[2], q[1] / q[2]).reshape(y1 - y0, n, p.width, n)
        pix = (np.arange(y1 - y0)[:, None, None, None] * p.width + np.arange(p.width)[None, None, :, None])
        counts = np.bincount((pix * nlab + lab).ravel(), minlength=(y1 - y0) * p.width * nlab)
        out[y0:y1] = counts.reshape(y1 - y0, p.width, nlab) / float(n * n)
    return np.ascontiguousarray(np.moveaxis(out, -1, 0))
    return out


def chart_reflectances(name: str = "ColorChecker N Ohta",
                       wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> tuple[list[str], np.ndarray]:
    """Patch names and (24, n) reflectances of a colour-science ColorChecker data set (``SDS_COLOURCHECKERS``),
    linearly interpolated onto ``wavelengths_nm`` and held at the data set's end values beyond its range."""
    import colour  # loads matplotlib: kept off paths that do not plot

    if name not in colour.SDS_COLOURCHECKERS:
        raise CamcalError(f"unknown colour-checker data set {name!r}; choose from "
                          f"{', '.join(colour.SDS_COLOURCHECKERS)}")
    sds = colour.SDS_COLOURCHECKERS[name]
    names = list(sds)
    if len(names) != CHART_PATCHES:
        raise CamcalError(f"colour-checker data set {name!r} has {len(names)} patches, not 24")
    wl = np.asarray(wavelengths_nm, float)
    return names, np.stack([np.interp(wl, sds[k].wavelengths, sds[k].values) for k in names])


@dataclass(frozen=True)
class ChartScene:
    """A sunlit chart photo's scene, its patch radiances (W m⁻² sr⁻¹ nm⁻¹, (24, n)) and the truth (JSON-ready)."""

    scene: Scene
    patch_radiance: np.ndarray
    white_radiance: np.ndarray
    truth: dict = field(default_factory=dict)


def chart_scene(camera: PhoneCamera, sky: SunSky, *, reflectance: str | np.ndarray = "ColorChecker N Ohta",
                layout: ChartLayout = ChartLayout(), pose: ChartPose = ChartPose(), ground_albedo: float = 0.25,
                supersample: int = 4) -> ChartScene:
    """A ColorChecker Classic lying in the sun on a grey ground (flat albedo ``ground_albedo``), seen in perspective.

    Every surface is Lambertian and horizontal: L = ρ(λ) (DNI cos θs + DHI)/π. The truth holds the card's and the
    swatch grid's corners in image pixels (TL, TR, BR, BL: top-left is the corner next to 'dark skin'), every
    patch's corners and centre, the cos⁴ gain there, and each channel's true DN rate at the reference setting
    (``∫ c_i L dλ`` on axis, DN s⁻¹; times the gain where the patch lies). ``reflectance`` is a colour-science
    data-set name or a (24, n) array on :data:`WAVELENGTHS_NM` (e.g. a chart perturbed within the published
    chart-to-chart spread); the truth then names it ``given``.
    """
    if isinstance(reflectance, str):
        names, rho = chart_reflectances(reflectance)
    else:
        names, _ = chart_reflectances("ColorChecker N Ohta")
        rho = np.asarray(reflectance, float)
        if rho.shape != (CHART_PATCHES, WAVELENGTHS_NM.size) or not np.all(np.isfinite(rho)) or \
                np.any(rho < 0) or np.any(rho > 1.5):
            raise CamcalError(f"chart reflectance must be 24 rows of {WAVELENGTHS_NM.size} values in [0, 1.5] on the "
                              "380-780 nm grid")
        reflectance = "given"
    tform = chart_homography(camera, layout, pose)
    weights = chart_label_weights(camera, tform, layout, supersample)
    white = horizontal_irradiance(sky) / np.pi
    patch_l = rho * white[None, :]
    comps = [(weights[k], patch_l[k]) for k in range(CHART_PATCHES)]
    comps.append((weights[CHART_PATCHES], layout.card_reflectance * white))
    comps.append((weights[CHART_PATCHES + 1], ground_albedo * white))
    scene = Scene(tuple(comps), WAVELENGTHS_NM)
    sens = camera.spectral_sensitivity()
    rate = np.trapezoid(sens[:, None, :] * patch_l[None, :, :], WAVELENGTHS_NM, axis=-1)  # (3, 24)
    w_mm, h_mm = layout.card_mm
    gx0, gy0 = layout.grid_origin_mm
    gw, gh = layout.grid_mm
    card_px = tform(np.array([[0, 0], [w_mm, 0], [w_mm, h_mm], [0, h_mm]], float))
    grid_px = tform(np.array([[gx0, gy0], [gx0 + gw, gy0], [gx0 + gw, gy0 + gh], [gx0, gy0 + gh]], float))
    patches = []
    for k in range(CHART_PATCHES):
        cmm = layout.patch_corners_mm(k)
        cpx = tform(cmm)
        centre = tform(cmm.mean(axis=0, keepdims=True))[0]
        gain = float(camera.radial_gain_at(centre[0], centre[1]))
        patches.append({"index": k, "name": names[k], "centre_px": centre.tolist(), "corners_px": cpx.tolist(),
                        "relative_illumination": gain,
                        "dn_rate_on_axis": {ch: float(rate[i, k]) for i, ch in enumerate("RGB")},
                        "band_radiance": {ch: float(rate[i, k] / np.trapezoid(sens[i], WAVELENGTHS_NM))
                                          for i, ch in enumerate("RGB")}})
    truth = {"chart": "X-Rite ColorChecker Classic (24 patches, 4x6, black card)",
             "reflectance": (f"colour-science SDS_COLOURCHECKERS[{reflectance!r}]" if reflectance != "given" else
                             "given (patch_reflectance)"), "reflectance_name": reflectance,
             "patch_reflectance": rho.tolist() if reflectance == "given" else None,
             "card_mm": list(layout.card_mm), "patch_mm": layout.patch_mm, "gap_mm": layout.gap_mm,
             "card_reflectance": layout.card_reflectance, "ground_albedo": ground_albedo,
             "pose": dataclasses.asdict(pose), "homography_card_mm_to_px": tform.params.tolist(),
             "pixel_convention": "full-resolution pixels, x right, y down, pixel centres at integers",
             "card_corners_px": card_px.tolist(), "grid_corners_px": grid_px.tolist(), "patches": patches,
             "dn_rate_units": f"{DN_PER_S} at the reference ISO and f-number, on axis (multiply by "
                              "relative_illumination for the patch's place)",
             "band_radiance_units": SPECTRAL_RADIANCE}
    return ChartScene(scene, patch_l, white, truth)


def grey_field_scene(camera: PhoneCamera, sky: SunSky, reflectance: np.ndarray | float | None = None
                     ) -> tuple[Scene, dict]:
    """A uniform horizontal grey field in the sun filling the frame: L = ρ(λ) (DNI cos θs + DHI)/π.

    ``reflectance`` on :data:`WAVELENGTHS_NM` (or one number); default the smooth grey card of
    :func:`camcal.synth.targets.grey_card_reflectance` (0.17 at 380 nm rising to 0.19 at 780 nm).
    Truth: the spectral radiance, each channel's DN rate on axis (``∫ c_i L dλ``) and band radiance
    (``∫ c_i L dλ / ∫ c_i dλ``, :mod:`camcal.units`) at the reference setting.
    """
    if reflectance is None:
        rho = grey_card_reflectance()
    else:
        rho = np.broadcast_to(np.asarray(reflectance, float), WAVELENGTHS_NM.shape).copy()
    radiance = rho * horizontal_irradiance(sky) / np.pi
    sens = camera.spectral_sensitivity()
    rate = np.trapezoid(sens * radiance[None, :], WAVELENGTHS_NM, axis=-1)
    truth = {"reflectance": rho.tolist(), "radiance_W_m2_sr_nm": radiance.tolist(),
             "dn_rate_on_axis": {ch: float(rate[i]) for i, ch in enumerate("RGB")},
             "band_radiance": {ch: float(rate[i] / np.trapezoid(sens[i], WAVELENGTHS_NM))
                               for i, ch in enumerate("RGB")},
             "band_radiance_units": SPECTRAL_RADIANCE,
             "dn_rate_units": f"{DN_PER_S} at the reference ISO and f-number, on axis"}
    return Scene.uniform(radiance), truth


def phone_exposure_s(camera: PhoneCamera, spectrum: np.ndarray, fill: float, iso: float | None = None) -> float:
    """A phone's exposure time for ``spectrum`` on axis at ``fill`` of the range: 1/N s with N whole (so the EXIF
    rational is the exposure used) below 1 s."""
    t = suggest_exposure_s(camera, spectrum, fill=fill, iso=iso)
    return 1.0 / round(1.0 / t) if t < 1.0 else float(round(t, 3))


# ---- a day's photos -----------------------------------------------------------------------------------------

def write_phone_photos(
    outdir: str | Path,
    camera: PhoneCamera | None = None,
    *,
    place: PlaceTime = DEFAULT_PLACE,
    sky: SunSky | None = None,
    chart_reflectance: str | np.ndarray = "ColorChecker N Ohta",
    chart_pose: ChartPose = ChartPose(),
    chart_evs: tuple[float, ...] = (0.0, -1.0),
    c_ug_per_L: float = 5.0,
    depths_m: tuple[float, ...] = (1.0, 2.0),
    n_flats: int = 3,
    formats: tuple[str, ...] = ("dng", "heic"),
    seed: int = 1,
    progress=None,
) -> dict:
    """Photograph a phone user's field day in the sun and write ``truth.json`` beside the photos.

    ``outdir`` receives ``chart/chart_ev<EV>.<ext>`` (the chart at each exposure offset ``chart_evs``, the white
    patch at 0.7 of the range on axis at EV 0), ``grey/grey.<ext>`` (the grey field, 0.5 of the range),
    ``flat/flat_<k>.<ext>`` (a uniform diffuse surface lit by the sky, 0.5 of the range; ``n_flats`` of them,
    none if 0) and ``secchi/d<depth>m_{ref,sub}.<ext>`` (:func:`camcal.synth.sunlit.write_sunlit_pair`: the dry
    reference disk once, the disk submerged at each depth in water holding ``c_ug_per_L`` µg/L chlorophyll-a),
    each in every format of ``formats`` ('dng', 'heic', 'jpg'), with the time, GPS and the fixed f/1.8 in the
    EXIF. ``sky`` defaults to :func:`sun_sky_at` ``place``. ``progress(done, total)`` is called per photo.
    Returns the truth written.
    """
    cam = camera or PhoneCamera()
    sky = sky or sun_sky_at(place)
    out = Path(outdir)
    bad = [f for f in formats if f not in ("dng", "heic", "jpg")]
    if bad or not formats:
        raise CamcalError(f"unknown photo format(s) {bad}; use dng, heic or jpg")
    if not (np.isfinite(c_ug_per_L) and c_ug_per_L >= 0) or not depths_m or \
            not all(np.isfinite(d) and 0 < d <= 20 for d in depths_m):
        raise CamcalError(f"Secchi photos need chlorophyll-a >= 0 and depths in (0, 20] m (got {c_ug_per_L!r}, "
                          f"{list(depths_m)!r})")
    if n_flats < 0 or not chart_evs:
        raise CamcalError("n_flats must be >= 0 and chart_evs hold at least one exposure offset")
    chart = chart_scene(cam, sky, reflectance=chart_reflectance, pose=chart_pose)  # refuses a bad chart first
    for sub in ("chart", "grey", "flat", "secchi"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    total = (len(chart_evs) + 1 + n_flats) * len(formats) + (1 + len(depths_m)) * len(formats)
    rngs = iter(frame_rngs(seed, total, 47))
    done = 0

    def shoot(path_stem: Path, scene: Scene, t: float) -> dict:
        nonlocal done
        files = {}
        for ext in formats:
            path = path_stem.with_suffix(f".{ext}")
            writer = {"dng": cam.write_dng, "heic": cam.write_heic, "jpg": cam.write_jpeg}[ext]
            writer(path, scene, exposure_s=t, rng=next(rngs), place=place)
            files[ext] = str(path.relative_to(out))
            done += 1
            if progress is not None:
                progress(done, total)
        return files

    white_index = chart.truth["patches"][18]
    t0 = phone_exposure_s(cam, chart.patch_radiance[18], 0.7)
    charts = []
    for ev in chart_evs:
        t = phone_exposure_s(cam, chart.patch_radiance[18], 0.7 * 2.0**ev)
        charts.append({"ev": ev, "exposure_s": t, "iso": cam.params.iso_base,
                       "files": shoot(out / "chart" / f"chart_ev{ev:+g}".replace("+", "p").replace("-", "m"),
                                      chart.scene, t)})
    grey_scene, grey_truth = grey_field_scene(cam, sky)
    tg = phone_exposure_s(cam, np.asarray(grey_truth["radiance_W_m2_sr_nm"]), 0.5)
    grey_truth.update(exposure_s=tg, iso=cam.params.iso_base, files=shoot(out / "grey" / "grey", grey_scene, tg))
    _, dhi = sky.spectra()
    flat_l = 0.5 * dhi / np.pi  # the sky through a diffuser of transmittance 0.5
    tf = phone_exposure_s(cam, flat_l, 0.5)
    flats = [{"exposure_s": tf, "files": shoot(out / "flat" / f"flat_{k:02d}", Scene.uniform(flat_l), tf)}
             for k in range(n_flats)]
    shots = []
    for i, d in enumerate(depths_m):
        sc = sunlit_scenes(cam, sky=sky, c_ug_per_L=c_ug_per_L, depth_m=d)
        rng = next(rngs)
        files = write_sunlit_pair(out / "secchi", cam, sc, stem=f"d{d:g}m", rng=rng, formats=formats,
                                  write_reference=i == 0, place=place)
        done += len(formats) * (2 if i == 0 else 1)
        if progress is not None:
            progress(min(done, total), total)
        rel = {k: ({e: str(Path(v).relative_to(out)) for e, v in val.items()} if k != "exposure_s" else val)
               for k, val in files.items()}
        shots.append({"depth_m": float(d), "files": rel, "truth": sc.truth})
    truth = {
        "generator": "camcal.synth.phone.write_phone_photos",
        "seed": seed,
        "place": {"utc": place.utc_aware.isoformat(), "utc_offset_min": place.utc_offset_min,
                  "latitude_deg": place.latitude_deg, "longitude_deg": place.longitude_deg,
                  "altitude_m": place.altitude_m},
        "sky": sky_truth(sky),
        "camera": cam.truth(),
        "chart": {**chart.truth, "shots": charts, "white_patch": white_index["name"], "exposure_ev0_s": t0},
        "grey": grey_truth,
        "flat": {"radiance": "0.5 DHI/pi (the sky through a diffuser)", "shots": flats},
        "secchi": {"c_ug_per_L": float(c_ug_per_L), "shots": shots},
        "units": {"spectral_sensitivity": SPECTRAL_SENSITIVITY, "radiance": SPECTRAL_RADIANCE},
    }
    save_truth(out / "truth.json", truth)
    return truth

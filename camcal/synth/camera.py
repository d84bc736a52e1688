"""The synthetic camera: a physically honest sensor model that writes real files.

Signal chain per pixel (all per CFA plane, at half resolution):

1. Photo-electron rate from the scene's spectral radiance L(λ) (W m⁻² sr⁻¹ nm⁻¹)::

       e_rate = A_pix · π / (4 N²) · τ · ∫ QE_i(λ) L(λ) λ / (h c) dλ        [e⁻ s⁻¹]

   (image-plane irradiance of a distant Lambertian scene through an f/N lens,
   A_pix the pixel area, τ the lens transmittance), times the vignetting
   g(x, y) (1 at the optical centre) and the PRNU map (mean 1).
2. Electrons collected: Poisson((e_rate + dark_rate) · t), clipped at the full well.
3. Read noise: Gaussian, σ_read electrons (input referred).
4. DN = electrons · (ISO / ISO_base) / K + black level (+ bias pattern), rounded,
   clipped to [0, white level]. K is the system gain in e⁻/DN at the base ISO.

So the DN rate per unit exposure ISO·t/N² is constant (seed §2.1), and the
spectral sensitivity at the reference setting (ISO_ref, N_ref) is::

       c_i(λ) = A_pix · π/(4 N_ref²) · τ · QE_i(λ) · λ/(h c) · ISO_ref/(ISO_base · K)
              [DN s⁻¹ per W m⁻² sr⁻¹ nm⁻¹, per nm]

with DN rate = ∫ c_i(λ) L(λ) dλ (seed §3.1, d = t ∫ c L dλ).

Vignetting follows the DNG ``FixVignetteRadial`` opcode model,
g(r) = 1 + k0 r² + k1 r⁴ + k2 r⁶ + k3 r⁸ + k4 r¹⁰, with r the distance from the
optical centre divided by the distance from it to the farthest image corner.
The k are the lens's natural falloff (cos⁴ and pupil distortion, the same at every
aperture); ``aperture_vignetting_k1`` adds mechanical vignetting (the lens barrel
clipping the oblique bundles), whose strength falls as the lens is stopped down:

    g(r, N) = g(r) + a(N) r⁴,   a(N) = a_ref · (N_a / N)²

with a_ref = ``aperture_vignetting_k1`` at N_a = ``aperture_vignetting_f_number``
(the clipped share of the bundle scales with the aperture's area, ∝ 1/N²). The
preset ``apertures`` (a_ref = −0.2 at f/2.8) has corner gains 0.42 at f/2.8 and
0.60 at f/8: 42 % more light in the corners at f/8, as on real lenses.
"""

from __future__ import annotations

import dataclasses
import json
import tempfile
from dataclasses import dataclass, field
from datetime import datetime
from functools import cached_property
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from camcal.errors import CamcalError
from camcal.frame import PATTERNS, PLANES, merge_planes, plane_offsets, rgb_from_planes, split_planes
from camcal.io.atomic import atomic_write_bytes, atomic_write_text
from camcal.models.spectra import WAVELENGTHS_NM, camera_sensitivities, photon_energy_j
from camcal.synth.dng import write_dng, write_linear_dng
from camcal.synth.exif import PlaceTime, encode_exif_app1
from camcal.synth.heic import write_heic
from camcal.synth.tone import apply_tone
from camcal.units import SPECTRAL_SENSITIVITY

LINEAR_FROM_PLANES: tuple[int, int, int] = (0, 1, 3)
"""Indices into :data:`camcal.frame.PLANES` of the R, G, B channels of a synthetic linear RAW: R, G1, B."""


@dataclass(frozen=True)
class SensorParams:
    """Parameters of a synthetic camera (the ground truth of every test).

    Sizes are full-resolution mosaic pixels; electrons are e-; DN are digital numbers.
    """

    width: int = 384
    height: int = 256
    cfa_pattern: str = "RGGB"
    bit_depth: int = 14
    black_level_dn: tuple[float, float, float, float] = (512.0, 512.0, 512.0, 512.0)
    """Black level per plane R, G1, G2, B, DN."""
    white_level_dn: int | None = None
    """Clipping level, DN (default 2**bit_depth - 1)."""
    gain_e_per_dn: float = 1.6
    """System gain at the base ISO, electrons per DN."""
    iso_base: float = 100.0
    read_noise_e: float = 3.0
    """Read noise, electrons RMS (input referred, ISO independent)."""
    full_well_e: float = 40000.0
    dark_current_e_per_s: tuple[float, float, float, float] = (2.0, 2.0, 2.0, 2.0)
    """Median dark current per plane, e⁻ s⁻¹."""
    dark_current_spread: float = 0.25
    """Log-normal sigma of the per-pixel dark current."""
    hot_pixel_fraction: float = 3e-4
    hot_pixel_factor: tuple[float, float] = (30.0, 300.0)
    """Hot pixels have this many times the median dark current (log-uniform)."""
    bias_pattern_dn: float = 0.5
    """RMS of the fixed per-pixel bias offset, DN (bias DSNU)."""
    prnu_sigma: float = 0.01
    """Relative RMS of the photo-response non-uniformity."""
    dead_pixel_fraction: float = 0.0
    """Fraction of pixels with no response to light (PRNU 0): dark frames look normal, flats do not."""
    offset_jitter_dn: float = 0.0
    """RMS of a frame-to-frame offset common to every pixel of a plane, DN (row/frame noise of real
    sensors, ~0.1 DN on the IMX296)."""
    vignetting_k: tuple[float, float, float, float, float] = (-0.30, -0.08, 0.0, 0.0, 0.0)
    """DNG radial vignetting coefficients k0..k4 (g(1) = 1 + sum k = corner gain)."""
    aperture_vignetting_k1: float = 0.0
    """Mechanical vignetting: r⁴ coefficient added at ``aperture_vignetting_f_number``, scaled by (N_a/N)² at
    f-number N (module docstring); 0: vignetting independent of the aperture."""
    aperture_vignetting_f_number: float = 2.8
    optical_centre: tuple[float, float] = (0.55, 0.48)
    """Optical centre as fractions of width and height."""
    pixel_pitch_um: float = 4.78
    focal_length_mm: float | None = None
    """Focal length written to the DNGs' FocalLength tag, mm (None: no tag)."""
    focal_length_35mm_mm: float | None = None
    """35 mm equivalent focal length written to the DNGs' FocalLengthIn35mmFilm tag, mm (None: no tag)."""
    lens_transmittance: float = 0.9
    qe_peak: tuple[float, float, float] = (0.35, 0.45, 0.38)
    """Peak quantum efficiency of R, G, B (the measured curves give the shape)."""
    sensitivity: str = "nikon-d5100"
    """Key of :data:`camcal.models.spectra.CAMERAS` or a colour-science camera name."""
    reference_iso: float = 100.0
    reference_f_number: float = 4.0
    make: str = "camcal"
    model: str = "Synthetic D5100"
    serial: str = "SYN0001"
    seed: int = 1

    def __post_init__(self) -> None:
        if self.cfa_pattern not in PATTERNS:
            raise CamcalError(f"unknown CFA pattern {self.cfa_pattern!r}")
        if self.width % 2 or self.height % 2 or self.width < 64 or self.height < 64:
            raise CamcalError("synthetic sensor size must be even and at least 64x64 (LibRaw's minimum)")
        if not 8 <= self.bit_depth <= 16:
            raise CamcalError("bit depth must be 8..16")

    @property
    def white_dn(self) -> int:
        return int(self.white_level_dn if self.white_level_dn is not None else 2**self.bit_depth - 1)

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


PRESETS: dict[str, SensorParams] = {
    "default": SensorParams(),
    # A 10-bit sensor with sub-DN read noise, learned from the Raspberry Pi Global Shutter camera's real
    # dark frames (Sony IMX296, 1456x1088, BGGR, black level 60, white 1023; ../shared/realdata/pi): read
    # noise 0.38-0.39 DN with the quantisation removed (0.45-0.48 DN as recorded), frame-to-frame offsets
    # of ~0.1 DN, a per-pixel bias spread of only ~0.02 DN (so the pixel means are NOT spread over whole
    # DN: the regime where var - 1/12 fails). Gain ~10 e⁻/DN (full well ~10 ke- over 963 DN).
    "imx296": SensorParams(
        width=1456, height=1088, cfa_pattern="BGGR", bit_depth=10, black_level_dn=(60.0, 60.0, 60.0, 60.0),
        white_level_dn=1023, gain_e_per_dn=10.0, read_noise_e=3.9, full_well_e=10000.0,
        dark_current_e_per_s=(3.0, 3.0, 3.0, 3.0), bias_pattern_dn=0.03, offset_jitter_dn=0.1,
        pixel_pitch_um=3.45, make="camcal", model="Synthetic IMX296", serial="SYN0296",
    ),
    # 0.3 % hot pixels that saturate at 30 s (the sweep's longest exposure in the blue) on the default
    # camera: 500-3000 x the median dark current of 2 e⁻ s⁻¹ at 1.6 e⁻/DN reaches the 15 871 DN range in
    # 8-48 s (the darks of 16 s and 32 s see them saturate too).
    "hot": SensorParams(hot_pixel_fraction=3e-3, hot_pixel_factor=(500.0, 3000.0), model="Synthetic D5100 hot"),
    # per-channel black levels and frame-to-frame offset jitter on the default camera
    "offsets": SensorParams(black_level_dn=(512.0, 510.0, 514.0, 508.0), offset_jitter_dn=0.1,
                            model="Synthetic D5100 offsets"),
    # mechanical vignetting that falls with the f-number (corner gain 0.42 at f/2.8, 0.60 at f/8); its sessions
    # hold flats at f/2.8 and f/8 (flat/f2.8/, flat/f8/) and the sweep at f/4 (camcal synth session)
    "apertures": SensorParams(aperture_vignetting_k1=-0.2, focal_length_mm=35.0, model="Synthetic D5100 apertures"),
}
"""Named synthetic cameras (``camcal synth session --preset NAME``, ``camcal demo --preset NAME``)."""


def preset(name: str, **overrides) -> SensorParams:
    """The :data:`PRESETS` entry ``name`` with ``overrides`` (e.g. a smaller ``width``/``height`` for tests).

    Raises
    ------
    CamcalError
        Unknown preset name.
    """
    if name not in PRESETS:
        raise CamcalError(f"unknown synthetic camera preset {name!r}; choose from {', '.join(PRESETS)}")
    return dataclasses.replace(PRESETS[name], **overrides)


@dataclass(frozen=True)
class Scene:
    """A scene: spectral radiance components, each uniform or weighted by a map.

    ``components`` is a list of ``(weight, spectrum)``: ``weight`` is None
    (uniform) or an (H, W) array of full-resolution weights; ``spectrum`` is the
    spectral radiance in W m⁻² sr⁻¹ nm⁻¹ on ``wavelengths_nm``.
    """

    components: tuple[tuple[np.ndarray | None, np.ndarray], ...]
    wavelengths_nm: np.ndarray = field(default_factory=lambda: WAVELENGTHS_NM)

    @staticmethod
    def uniform(spectrum: np.ndarray, wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> Scene:
        return Scene(((None, np.asarray(spectrum, float)),), wavelengths_nm)

    @staticmethod
    def dark() -> Scene:
        return Scene(())


class SyntheticCamera:
    """A camera with fixed-pattern maps drawn once from ``params.seed``.

    Methods return new arrays; the camera holds no mutable state besides caches.
    """

    def __init__(self, params: SensorParams | None = None) -> None:
        self.params = params or SensorParams()

    # ---- fixed pattern ------------------------------------------------------------
    @cached_property
    def _maps(self) -> dict[str, np.ndarray]:
        p = self.params
        rng = np.random.default_rng([p.seed, 7])
        h, w = p.height // 2, p.width // 2
        med = np.asarray(p.dark_current_e_per_s, float)[:, None, None]
        dark = med * np.exp(p.dark_current_spread * rng.standard_normal((4, h, w)) - 0.0)
        hot = rng.random((4, h, w)) < p.hot_pixel_fraction
        lo, hi = np.log(p.hot_pixel_factor[0]), np.log(p.hot_pixel_factor[1])
        factor = np.exp(rng.uniform(lo, hi, size=int(hot.sum())))
        dark[hot] = (med * np.ones((4, h, w)))[hot] * factor
        prnu = 1.0 + p.prnu_sigma * rng.standard_normal((4, h, w))
        bias = p.bias_pattern_dn * rng.standard_normal((4, h, w))
        dead = np.zeros((4, h, w), bool)
        if p.dead_pixel_fraction > 0:  # drawn from a stream of its own: the other maps stay as they were
            dead = np.random.default_rng([p.seed, 11]).random((4, h, w)) < p.dead_pixel_fraction
            prnu[dead] = 0.0
        return {"dark_e_per_s": dark, "hot": hot, "prnu": prnu, "bias_dn": bias, "dead": dead,
                "vignetting": self._vignetting(self.params.reference_f_number)}

    def vignetting_k_at(self, f_number: float | None) -> tuple[float, ...]:
        """The DNG radial coefficients k0..k4 of the relative illumination at f-number ``f_number`` (None: the
        reference f-number): the natural falloff plus the mechanical term (module docstring)."""
        p = self.params
        n = p.reference_f_number if f_number is None else float(f_number)
        k = list(p.vignetting_k)
        k[1] += p.aperture_vignetting_k1 * (p.aperture_vignetting_f_number / n) ** 2
        return tuple(k)

    def _vignetting(self, f_number: float | None) -> np.ndarray:
        p = self.params
        cx, cy = self.optical_centre_px
        yy, xx = np.mgrid[0 : p.height, 0 : p.width].astype(float)
        rmax = max(np.hypot(x - cx, y - cy) for x in (0, p.width - 1) for y in (0, p.height - 1))
        r2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / rmax**2
        g = np.ones_like(r2)
        for i, k in enumerate(self.vignetting_k_at(f_number)):
            g += k * r2 ** (i + 1)
        return split_planes(g, p.cfa_pattern, dtype=np.float64)

    def vignetting_map_at(self, f_number: float | None) -> np.ndarray:
        """(4, h, w) relative illumination per plane at f-number ``f_number``, 1 at the optical centre."""
        if not self.params.aperture_vignetting_k1 or f_number is None:
            return self.vignetting_map
        cache = self.__dict__.setdefault("_vignetting_cache", {})
        if f_number not in cache:
            cache[f_number] = self._vignetting(f_number)
        return cache[f_number]

    @property
    def optical_centre_px(self) -> tuple[float, float]:
        """Optical centre (x, y) in full-resolution pixel coordinates."""
        p = self.params
        return p.optical_centre[0] * (p.width - 1), p.optical_centre[1] * (p.height - 1)

    @property
    def dark_current_map_e_per_s(self) -> np.ndarray:
        return self._maps["dark_e_per_s"]

    @property
    def hot_pixel_mask(self) -> np.ndarray:
        return self._maps["hot"]

    @property
    def dead_pixel_mask(self) -> np.ndarray:
        """(4, h, w) pixels without response to light."""
        return self._maps["dead"]

    @property
    def prnu_map(self) -> np.ndarray:
        return self._maps["prnu"]

    @property
    def vignetting_map(self) -> np.ndarray:
        """(4, h, w) relative illumination per plane, 1 at the optical centre."""
        return self._maps["vignetting"]

    # ---- radiometry ----------------------------------------------------------------
    @cached_property
    def qe(self) -> np.ndarray:
        """(3, n) quantum efficiency of R, G, B on :data:`WAVELENGTHS_NM`."""
        rel = camera_sensitivities(self.params.sensitivity, WAVELENGTHS_NM)
        return rel * np.asarray(self.params.qe_peak)[:, None]

    def electron_response(self, f_number: float, wavelengths_nm: np.ndarray = WAVELENGTHS_NM) -> np.ndarray:
        """(3, n) electrons s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm, at f-number ``f_number``."""
        p = self.params
        area_m2 = (p.pixel_pitch_um * 1e-6) ** 2
        qe = self.qe if wavelengths_nm is WAVELENGTHS_NM else np.stack(
            [np.interp(wavelengths_nm, WAVELENGTHS_NM, q, left=0, right=0) for q in self.qe]
        )
        return area_m2 * np.pi / (4 * f_number**2) * p.lens_transmittance * qe / photon_energy_j(wavelengths_nm)

    def dn_per_electron(self, iso: float) -> float:
        return iso / (self.params.iso_base * self.params.gain_e_per_dn)

    def spectral_sensitivity(self, iso: float | None = None, f_number: float | None = None) -> np.ndarray:
        """True c_i(λ), (3, n): DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm, on-axis, at a setting.

        Defaults to the reference setting of the params.
        """
        p = self.params
        iso = p.reference_iso if iso is None else iso
        n = p.reference_f_number if f_number is None else f_number
        return self.electron_response(n) * self.dn_per_electron(iso)

    def channel_rates_e(self, spectrum: np.ndarray, f_number: float, wavelengths_nm=WAVELENGTHS_NM) -> np.ndarray:
        """On-axis electron rate per channel (R, G, B) for a spectrum, e⁻ s⁻¹."""
        resp = self.electron_response(f_number, wavelengths_nm)
        return np.trapezoid(resp * np.asarray(spectrum)[None, :], wavelengths_nm, axis=-1)

    # ---- exposure ------------------------------------------------------------------
    def _electron_rate_planes(self, scene: Scene, f_number: float) -> np.ndarray:
        p = self.params
        h, w = p.height // 2, p.width // 2
        rate = np.zeros((4, h, w))
        rgb_of_plane = [0, 1, 1, 2]
        for weight, spectrum in scene.components:
            rgb = self.channel_rates_e(spectrum, f_number, scene.wavelengths_nm)
            per_plane = np.array([rgb[i] for i in rgb_of_plane])[:, None, None]
            if weight is None:
                rate += per_plane
            else:
                weight = np.asarray(weight, float)
                if weight.shape != (p.height, p.width):
                    raise CamcalError(f"scene weight map has shape {weight.shape}, sensor is {(p.height, p.width)}")
                rate += per_plane * split_planes(weight, p.cfa_pattern, dtype=np.float64)
        return rate * self.vignetting_map_at(f_number) * self.prnu_map

    def expose_planes(
        self,
        scene: Scene,
        *,
        exposure_s: float,
        iso: float | None = None,
        f_number: float | None = None,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Simulate one exposure; returns (4, h, w) uint16 DN planes (R, G1, G2, B)."""
        p = self.params
        iso = p.iso_base if iso is None else iso
        f_number = p.reference_f_number if f_number is None else f_number
        mean_e = (self._electron_rate_planes(scene, f_number) + self.dark_current_map_e_per_s) * exposure_s
        electrons = rng.poisson(mean_e).astype(np.float64)
        np.minimum(electrons, p.full_well_e, out=electrons)
        electrons += p.read_noise_e * rng.standard_normal(electrons.shape)
        black = np.asarray(p.black_level_dn, float)[:, None, None]
        dn = electrons * self.dn_per_electron(iso) + black + self._maps["bias_dn"]
        if p.offset_jitter_dn > 0:  # one offset per plane and frame (drawn only then: other streams unchanged)
            dn += p.offset_jitter_dn * rng.standard_normal((dn.shape[0], 1, 1))
        return np.clip(np.rint(dn), 0, p.white_dn).astype(np.uint16)

    def expose(self, scene: Scene, **kwargs) -> np.ndarray:
        """Simulate one exposure; returns the (H, W) uint16 mosaic."""
        return merge_planes(self.expose_planes(scene, **kwargs), self.params.cfa_pattern)

    def linear_rgb(self, planes_dn: np.ndarray) -> np.ndarray:
        """In-camera processing, linear part: black removed, scaled to [0, 1], (3, h, w) RGB."""
        p = self.params
        black = np.asarray(p.black_level_dn, float)[:, None, None]
        x = (planes_dn.astype(np.float64) - black) / (p.white_dn - black)
        return np.clip(rgb_from_planes(x), 0.0, 1.0)

    # ---- files ---------------------------------------------------------------------
    def write_dng(
        self,
        path: str | Path,
        scene: Scene,
        *,
        exposure_s: float,
        iso: float | None = None,
        f_number: float | None = None,
        rng: np.random.Generator,
        capture_time: datetime | None = None,
        temperature_c: float | None = None,
        layout: str = "bayer",
        tag_f_number: bool = True,
        place: PlaceTime | None = None,
    ) -> Path:
        """Expose and write a real DNG file (decodable by LibRaw, Exif exposure tags).

        ``place`` (:class:`camcal.synth.exif.PlaceTime`): GPS position, GPS UTC time and
        OffsetTimeOriginal in the EXIF; DateTimeOriginal is then its local clock time.

        ``layout="linear"`` writes a LinearRaw DNG instead of the mosaic: the R, G1 and B planes of the
        same exposure as an (H/2, W/2, 3) R, G, B image (a superpixel demosaic taking G from G1), so
        that every channel's truth is that of its Bayer plane. ``tag_f_number=False`` writes no FNumber
        tag (a fixed-aperture camera); the exposure still uses ``f_number``.
        """
        p = self.params
        iso = p.iso_base if iso is None else iso
        f_number = p.reference_f_number if f_number is None else f_number
        if layout == "linear":
            planes = self.expose_planes(scene, exposure_s=exposure_s, iso=iso, f_number=f_number, rng=rng)
            return write_linear_dng(
                path, np.moveaxis(planes[list(LINEAR_FROM_PLANES)], 0, -1),
                black_level_dn=tuple(float(p.black_level_dn[k]) for k in LINEAR_FROM_PLANES),
                white_level_dn=p.white_dn, exposure_s=exposure_s, f_number=f_number if tag_f_number else None,
                iso=iso, make=p.make, model=p.model, serial=p.serial, capture_time=capture_time,
                temperature_c=temperature_c, place=place, focal_length_mm=p.focal_length_mm,
                focal_length_35mm_mm=p.focal_length_35mm_mm,
            )
        if layout != "bayer":
            raise ValueError(f"layout must be 'bayer' or 'linear', got {layout!r}")
        mosaic = self.expose(scene, exposure_s=exposure_s, iso=iso, f_number=f_number, rng=rng)
        return write_dng(
            path,
            mosaic,
            cfa_pattern=p.cfa_pattern,
            black_level_dn=self._black_by_position(),
            white_level_dn=p.white_dn,
            exposure_s=exposure_s,
            f_number=f_number if tag_f_number else None,
            iso=iso,
            make=p.make,
            model=p.model,
            serial=p.serial,
            capture_time=capture_time,
            temperature_c=temperature_c,
            place=place,
            focal_length_mm=p.focal_length_mm,
            focal_length_35mm_mm=p.focal_length_35mm_mm,
        )

    def black_by_position(self) -> tuple[float, float, float, float]:
        """Black level (DN) of each 2x2 mosaic position, row-major: what a DNG's BlackLevel tag holds."""
        return self._black_by_position()

    def _black_by_position(self) -> tuple[float, float, float, float]:
        off = plane_offsets(self.params.cfa_pattern)
        pos = [0.0] * 4
        for k, name in enumerate(PLANES):
            r, c = off[name]
            pos[2 * r + c] = self.params.black_level_dn[k]
        return tuple(pos)  # type: ignore[return-value]

    def render_processed(
        self,
        scene: Scene,
        *,
        exposure_s: float,
        iso: float,
        f_number: float,
        rng: np.random.Generator,
        tone: str = "srgb",
        gamma: float = 1 / 2.2,
        colour_matrix: np.ndarray | None = None,
        bits: int = 8,
    ) -> np.ndarray:
        """Expose and process as a camera does for a JPEG or HEIC: the (H, W, 3) image of ``bits`` bits.

        Processing: black removed and scaled to [0, 1] (:meth:`linear_rgb`),
        nearest-neighbour demosaic to full resolution, the 3x3 ``colour_matrix`` (camera RGB →
        output RGB, rows summing to 1 keep white; None: identity, no mixing) and a clip to [0, 1],
        tone curve ``tone`` (``"srgb"``: IEC 61966-2-1; ``"power"``: x**gamma), quantisation to
        ``bits`` bits (uint8 for 8, uint16 holding 0..2**bits − 1 otherwise).
        """
        planes = self.expose_planes(scene, exposure_s=exposure_s, iso=iso, f_number=f_number, rng=rng)
        lin = self.linear_rgb(planes)
        if colour_matrix is not None:
            m = np.asarray(colour_matrix, float)
            if m.shape != (3, 3) or not np.all(np.isfinite(m)):
                raise ValueError(f"colour_matrix must be a finite 3x3 array, got shape {m.shape}")
            lin = np.clip(np.einsum("ij,jhw->ihw", m, lin), 0.0, 1.0)
        full = np.repeat(np.repeat(lin, 2, axis=1), 2, axis=2)
        enc = apply_tone(full, tone, gamma)
        top = 2**bits - 1
        img = np.clip(np.rint(enc * top), 0, top).astype(np.uint8 if bits == 8 else np.uint16)
        return np.moveaxis(img, 0, -1)

    def write_jpeg(
        self,
        path: str | Path,
        scene: Scene,
        *,
        exposure_s: float,
        iso: float | None = None,
        f_number: float | None = None,
        rng: np.random.Generator,
        tone: str = "srgb",
        gamma: float = 1 / 2.2,
        quality: int = 97,
        capture_time: datetime | None = None,
        colour_matrix: np.ndarray | None = None,
        tag_f_number: bool = True,
        place: PlaceTime | None = None,
    ) -> Path:
        """Expose and write an 8-bit JPEG as a camera would: linear RGB, colour matrix, tone curve, EXIF.

        Processing as :meth:`render_processed` (8 bits), then JPEG at ``quality`` with 4:4:4 chroma.
        ``place``: GPS and time tags as in :meth:`write_dng`.
        """
        img, tags = self._processed_photo(scene, exposure_s, iso, f_number, rng, tone, gamma, colour_matrix, 8,
                                          tag_f_number, quality, capture_time, place)
        return write_jpeg_file(path, img, **tags)

    def write_heic(
        self,
        path: str | Path,
        scene: Scene,
        *,
        exposure_s: float,
        iso: float | None = None,
        f_number: float | None = None,
        rng: np.random.Generator,
        tone: str = "srgb",
        gamma: float = 1 / 2.2,
        quality: int = 97,
        bits: int = 8,
        capture_time: datetime | None = None,
        colour_matrix: np.ndarray | None = None,
        tag_f_number: bool = True,
        place: PlaceTime | None = None,
    ) -> Path:
        """Expose and write a HEIC (HEVC in HEIF) as a phone would, 8 or 10 bits, with EXIF.

        Processing as :meth:`render_processed`; encoded by pillow-heif (libheif, x265) at ``quality``
        with 4:4:4 chroma; ``place``: GPS and time tags as in :meth:`write_dng`.
        """
        img, tags = self._processed_photo(scene, exposure_s, iso, f_number, rng, tone, gamma, colour_matrix, bits,
                                          tag_f_number, quality, capture_time, place)
        return write_heic(path, img, bits=bits, **tags)

    def _processed_photo(self, scene: Scene, exposure_s: float, iso: float | None, f_number: float | None,
                         rng: np.random.Generator, tone: str, gamma: float, colour_matrix: np.ndarray | None,
                         bits: int, tag_f_number: bool, quality: int, capture_time: datetime | None,
                         place: PlaceTime | None) -> tuple[np.ndarray, dict]:
        """The image of :meth:`render_processed` (at the camera's base ISO and reference f-number unless
        given) and the EXIF and encoder arguments the JPEG and HEIC writers share."""
        p = self.params
        iso = p.iso_base if iso is None else iso
        f_number = p.reference_f_number if f_number is None else f_number
        img = self.render_processed(scene, exposure_s=exposure_s, iso=iso, f_number=f_number, rng=rng, tone=tone,
                                    gamma=gamma, colour_matrix=colour_matrix, bits=bits)
        tags = {"exposure_s": exposure_s, "f_number": f_number if tag_f_number else None, "iso": iso,
                "make": p.make, "model": p.model, "quality": quality, "capture_time": capture_time, "place": place}
        return img, tags

    def truth(self, iso: float | None = None) -> dict:
        """Ground truth of the fixed pattern and the radiometry, JSON-ready."""
        p = self.params
        iso = p.iso_base if iso is None else iso
        k = self.dn_per_electron(iso)
        dark_dn = self.dark_current_map_e_per_s * k
        hot = self.hot_pixel_mask
        cx, cy = self.optical_centre_px
        c_ref = self.spectral_sensitivity()
        return {
            "params": p.to_json(),
            "iso": iso,
            "planes": list(PLANES),
            "bias_dn": {
                n: float(p.black_level_dn[i] + np.mean(self._maps["bias_dn"][i])) for i, n in enumerate(PLANES)
            },
            "dark_current_dn_per_s": {n: float(np.median(dark_dn[i])) for i, n in enumerate(PLANES)},
            "read_noise_dn": {
                n: float(np.hypot(p.read_noise_e * k, 0.0)) for n in PLANES
            },
            "hot_pixels": [[int(c), int(y), int(x)] for c, y, x in zip(*np.nonzero(hot), strict=True)],
            "hot_pixel_count": int(hot.sum()),
            "dead_pixel_count": int(self.dead_pixel_mask.sum()),
            "offset_jitter_dn": p.offset_jitter_dn,
            "prnu_sigma": p.prnu_sigma,
            "vignetting": {
                "model": "dng-radial",
                "k": list(self.vignetting_k_at(None)),
                "k_natural": list(p.vignetting_k),
                "aperture_term": {"k1_at_f_number": p.aperture_vignetting_k1,
                                  "f_number": p.aperture_vignetting_f_number,
                                  "rule": "k1(N) = k1_natural + k1_at_f_number * (f_number / N)^2"},
                "centre_px": [cx, cy],
                "centre_half_px": {
                    n: [(cx - plane_offsets(p.cfa_pattern)[n][1]) / 2, (cy - plane_offsets(p.cfa_pattern)[n][0]) / 2]
                    for n in PLANES
                },
                "corner_gain": float(1 + sum(self.vignetting_k_at(None))),
            },
            "gain_e_per_dn_at_iso": 1.0 / k,
            "saturation_dn": float(min(p.white_dn, p.full_well_e * k + min(p.black_level_dn))),
            "spectral_sensitivity": {
                "wavelength_nm": WAVELENGTHS_NM.tolist(),
                "R": c_ref[0].tolist(),
                "G": c_ref[1].tolist(),
                "B": c_ref[2].tolist(),
                "units": SPECTRAL_SENSITIVITY,
                "reference_iso": p.reference_iso,
                "reference_f_number": p.reference_f_number,
            },
        }


def write_jpeg_file(
    path: str | Path,
    rgb8: np.ndarray,
    *,
    exposure_s: float | None,
    f_number: float | None,
    iso: float | None,
    make: str = "camcal",
    model: str = "Synthetic",
    quality: int = 97,
    capture_time: datetime | None = None,
    place: PlaceTime | None = None,
    focal_length_mm: float | None = None,
    focal_length_35mm_mm: float | None = None,
) -> Path:
    """Write an (H, W, 3) uint8 image as a JPEG with an Exif block, atomically.

    OpenImageIO encodes the pixels (4:4:4 chroma); camcal writes the Exif APP1
    segment itself so that exposure time and f-number are exact rationals.
    """
    h, w, _ = rgb8.shape
    spec = oiio.ImageSpec(w, h, 3, oiio.UINT8)
    spec.attribute("Compression", f"jpeg:{int(quality)}")
    spec.attribute("jpeg:subsampling", "4:4:4")
    with tempfile.TemporaryDirectory(prefix="camcal-jpeg-") as tdir:
        tmp = Path(tdir) / "pixels.jpg"
        out = oiio.ImageOutput.create(str(tmp))
        if out is None or not out.open(str(tmp), spec):
            raise CamcalError(f"cannot write JPEG: {oiio.geterror()}", path)
        out.write_image(np.ascontiguousarray(rgb8))
        out.close()
        data = tmp.read_bytes()
    app1 = encode_exif_app1(
        exposure_s=exposure_s, f_number=f_number, iso=iso, make=make, model=model, capture_time=capture_time,
        place=place, focal_length_mm=focal_length_mm, focal_length_35mm_mm=focal_length_35mm_mm,
    )
    return atomic_write_bytes(path, data[:2] + app1 + data[2:])


def frame_rngs(seed: int, n: int, stream: int) -> list[np.random.Generator]:
    """``n`` independent generators for frames of one stream (reproducible)."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence([seed, stream]).spawn(n)]


def save_truth(path: str | Path, truth: dict) -> Path:

    return atomic_write_text(path, json.dumps(truth, indent=1, sort_keys=True))


"""A calibration profile from photos of a colour chart: ``camcal chart`` (the file step around the pure core).

The photos
----------
Every photo is decoded by :func:`camcal.io.read.load_frame` (RAW and linear DNG through LibRaw, HEIC through
pillow-heif, JPEG/TIFF/PNG through OpenImageIO), the chart found (:mod:`camcal.chart.detect`) and its patches
sampled (:mod:`camcal.chart.patches`). A RAW photo and a processed photo of the same name stem are *twins*
(one shot written twice, as a phone writes DNG + HEIC).

RAW and linear DNG: the patch means (black level subtracted) are divided by the relative exposure
x = (ISO·t/N²)/(ISO_ref/N_ref²) (seed §2.1, :func:`camcal.models.exposure.frame_relative_exposure`) with the reference
setting (ISO_ref, N_ref) the photos' own (a phone's aperture is fixed): DN s⁻¹ at the reference setting, the
signals of absolute c(λ) (:func:`camcal.chart.recovery.recover_sensitivity`) when the light's scale is known.
Several photos are averaged patch by patch (inverse-variance). A photo whose exposure tags are unknown gives
the shape of c(λ) only (relative).

HEIC and JPEG (:mod:`camcal.chart.tone`): with RAW twins the tone curve and the 3x3 colour matrix are fitted on
all patches, and ``camcal apply`` reads a processed photo as RAW-equivalent signals through them (the profile's
c(λ) is the RAW one). Without RAW, the tone curve is fitted on the six neutral patches of every processed photo
(all exposures), the patches linearised and c(λ) of the processed channels recovered from them (the profile's
colour matrix is then the identity: its c(λ) already contains the camera's mixing; c may be negative, a mixed
channel is). The white balance is compared across the photos (:func:`camcal.chart.tone.white_balance_check`).

The light: the clear-sky global irradiance on the level chart (SPECTRL2, :func:`camcal.chart.light.
clear_sky_irradiance`) at the sun's zenith angle from the first photo's EXIF time and GPS (:mod:`camcal.io.sun`) or
``--sun``; a CIE illuminant by name (shape only: relative c); a CSV; or ``estimate`` (a CIE daylight fitted with
c(λ), :func:`camcal.chart.recovery.estimate_illuminant`).

Vignetting: a chart photo does not measure it. Photos of a uniform surface (``--flat``) give a relative flat
(:func:`camcal.calibrate.flat.fit_flat_planes`, 1 on the optical axis) that divides the patches (at each patch's centre)
and goes into the profile; without it the patches are read as they are (keep the chart near the image centre)
and the profile records that vignetting is not corrected.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from camcal import __version__
from camcal.calibrate.flat import fit_flat_planes, flats_optics
from camcal.chart.basis import DEFAULT_COMPONENTS, camera_basis
from camcal.chart.detect import NEUTRAL_PATCHES, ChartLocation, locate_chart
from camcal.chart.light import Irradiance, cie_illuminant, clear_sky_irradiance, read_irradiance_csv
from camcal.chart.patches import PatchSignals, sample_patches
from camcal.chart.recovery import (
    DEFAULT_REGULARISATION,
    RecoveredSensitivity,
    design_matrix,
    estimate_illuminant,
    recover_sensitivity,
)
from camcal.chart.targets import ChartReflectance, published_chart, read_chart_csv
from camcal.chart.tone import ToneFit, fit_tone_neutral, fit_tone_twins, white_balance_check
from camcal.errors import CamcalError
from camcal.frame import Frame
from camcal.io.hashing import sha256_file
from camcal.io.read import load_frame
from camcal.io.sun import SunPosition, parse_sun_option, sun_from_metadata
from camcal.models.exposure import frame_relative_exposure
from camcal.models.flat import FlatModel
from camcal.models.profile import CalibrationProfile, CameraIdentity, Provenance
from camcal.models.response import ChannelResponse, ColourMatrix, ResponseModel
from camcal.water.field import (
    DEFAULT_AOD_500NM,
    DEFAULT_OZONE_ATM_CM,
    DEFAULT_PRECIPITABLE_WATER_CM,
    DEFAULT_PRESSURE_PA,
)

RGB3 = ("R", "G", "B")


@functools.lru_cache(maxsize=4)
def _library_basis(ir_cut: tuple[float, float] | None = None):
    """The bundled library's camera basis (behind a known IR cut, nm and 1-σ nm, when given), built once per
    process (its leave-one-out prior takes seconds)."""
    return camera_basis(ir_cut=ir_cut)

#: Field angle of the image corner assumed for the uncorrected fall-off of a profile without flats, degrees (a
#: phone's main camera: 26 mm equivalent, 39.8° to the corner of a 3:2 frame; 38° for 4:3).
UNCORRECTED_CORNER_FIELD_DEG = 38.0
#: Variance given to a saturated patch so that the fit ignores it, relative to its signal².
LEFT_OUT_VARIANCE = 1e8


@dataclass(frozen=True)
class ChartOptions:
    """What ``camcal chart`` was asked (CLI options, in their units)."""

    chart_csv: Path | None = None
    corners: np.ndarray | None = None
    illuminant: str | None = None
    """None: the clear sky; ``"estimate"``; a CIE name (``D65``, ``D5000``, ``blackbody:3200``); or a CSV path."""
    illuminant_absolute: bool = True
    sun: str | None = None
    utc_offset: str | None = None
    aerosol_optical_depth_500nm: float = DEFAULT_AOD_500NM
    aerosol_sigma: float | None = None
    precipitable_water_cm: float = DEFAULT_PRECIPITABLE_WATER_CM
    ozone_atm_cm: float = DEFAULT_OZONE_ATM_CM
    pressure_Pa: float = DEFAULT_PRESSURE_PA
    flat: tuple[Path, ...] = ()
    n_components: int = DEFAULT_COMPONENTS
    regularisation: float = DEFAULT_REGULARISATION
    ir_cut: tuple[float, float] | None = None
    """The module's IR cut as (half-transmission wavelength, its 1-σ), nm, from its datasheet; None: unknown
    (the filter-shape prior of :mod:`camcal.chart.basis` spans 630-700 nm)."""

    def record(self) -> dict:
        return {"chart": None if self.chart_csv is None else Path(self.chart_csv).name,
                "corners": None if self.corners is None else np.asarray(self.corners).tolist(),
                "illuminant": self.illuminant if self.illuminant is None or not str(self.illuminant).lower()
                .endswith(".csv") else Path(self.illuminant).name,
                "sun": self.sun, "aerosol_optical_depth_500nm": self.aerosol_optical_depth_500nm,
                "precipitable_water_cm": self.precipitable_water_cm, "ozone_atm_cm": self.ozone_atm_cm,
                "pressure_Pa": self.pressure_Pa, "flat": [Path(p).name for p in self.flat],
                "n_components": self.n_components, "regularisation": self.regularisation,
                "ir_cut": None if self.ir_cut is None else {"cut_nm": self.ir_cut[0], "sigma_nm": self.ir_cut[1],
                                                            "source": "user (the module's datasheet)"}}


@dataclass(frozen=True, eq=False)
class ChartPhoto:
    """One chart photo: what it is, where the chart lies, its patches (the frame itself is not kept)."""

    path: Path
    kind: str
    layout: str
    shape: tuple[int, int]
    exposure: Any
    location: ChartLocation
    patches: PatchSignals
    sha256: str
    white_level_dn: float
    cfa_pattern: str | None = None

    def record(self, x_s: float | None) -> dict:
        e = self.exposure
        return {"file": self.path.name, "sha256": self.sha256, "kind": self.kind, "layout": self.layout,
                "exposure_s": e.exposure_s, "iso": e.iso, "f_number": e.f_number, "relative_exposure_s": x_s,
                "capture_time": e.capture_time, "chart": self.location.to_dict(),
                "saturated_patches": [int(k) + 1 for k in np.flatnonzero(self.patches.saturated)]}


@dataclass(frozen=True, eq=False)
class ChartResult:
    """The profile and what the summary shows."""

    profile: CalibrationProfile
    recovered: RecoveredSensitivity
    light: Irradiance
    photos: tuple[ChartPhoto, ...]
    tone: ToneFit | None
    warnings: tuple[str, ...]
    notes: tuple[str, ...]
    illuminant_estimate: dict | None = None
    white_balance: str | None = None


def read_chart_photo(path: Path, corners: np.ndarray | None = None) -> tuple[ChartPhoto, Frame]:
    """Decode one photo, find the chart and sample its patches."""
    frame = load_frame(path)
    loc = locate_chart(frame, corners)
    patches = sample_patches(frame, loc)
    return ChartPhoto(Path(path), frame.kind, str(frame.layout), frame.shape, frame.exposure, loc, patches,
                      sha256_file(path), float(frame.white_level_dn),
                      frame.cfa_pattern), frame


def _setting(photos: Sequence[ChartPhoto]) -> tuple[float | None, float | None]:
    """The photos' most common (ISO, f-number) where both are known; (None, None) when none states them."""
    seen = Counter((float(p.exposure.iso), float(p.exposure.f_number)) for p in photos
                   if p.exposure.iso and p.exposure.f_number and p.exposure.exposure_s)
    return seen.most_common(1)[0][0] if seen else (None, None)


def _relative_exposures(photos: Sequence[ChartPhoto], ref: tuple[float | None, float | None],
                        notes: list[str]) -> list[float] | None:
    """x per photo at the reference setting, or None when a photo's exposure is unknown (then c is relative)."""
    if ref[0] is None:
        notes.append("the photos state no exposure time, ISO and f-number (tags absent or zero): c(λ) is relative "
                     "(its shape only) and the photos are assumed equally exposed")
        return None
    return [frame_relative_exposure(p.exposure, ref[0], ref[1], p.path) for p in photos]


def _flat_gain_at(flat: FlatModel | None, photo: ChartPhoto) -> np.ndarray | None:
    """(24, C) the flat's gain at each patch centre (plane pixels), or None without a flat."""
    if flat is None:
        return None
    gain = flat.gain()
    step = 2 if photo.layout == "bayer" or photo.kind == "processed" else 1
    c = photo.patches.centre_px / step
    jj = np.clip(np.round(c[:, 0] - 0.5).astype(int), 0, gain.shape[2] - 1)
    ii = np.clip(np.round(c[:, 1] - 0.5).astype(int), 0, gain.shape[1] - 1)
    g = gain[:, ii, jj].T  # (24, C)
    if photo.patches.mean_dn.shape[1] == 3 and g.shape[1] == 4:
        g = np.column_stack([g[:, 0], 0.5 * (g[:, 1] + g[:, 2]), g[:, 3]])
    return g


def combine_signals(photos: Sequence[ChartPhoto], x_s: Sequence[float] | None, flat: FlatModel | None = None,
                    linear: Callable[[ChartPhoto], tuple[np.ndarray, np.ndarray]] | None = None
                    ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], np.ndarray]:
    """Per plane (24,) signals y (mean/x, flat-divided) and (24, 24) covariances, inverse-variance averaged over
    ``photos``; saturated patches get :data:`LEFT_OUT_VARIANCE`. Returns (signal, cov, usable (24,) bool).

    ``linear``: for processed photos, the linearised (24, 3) means and (24, 3, 3) covariances of a photo.
    """
    names = photos[0].patches.channels
    num = np.zeros((24, len(names)))
    den = np.zeros((24, len(names)))
    usable = np.zeros(24, bool)
    for j, p in enumerate(photos):
        mean, cov = (p.patches.mean_dn, p.patches.cov_dn2) if linear is None else linear(p)
        x = 1.0 if x_s is None else float(x_s[j])
        g = _flat_gain_at(flat, p)
        y = mean / x
        var = np.einsum("kcc->kc", cov) / x**2
        if g is not None:
            y, var = y / g, var / g**2
        ok = ~p.patches.saturated & np.all(np.isfinite(y), 1) & np.all(np.isfinite(var), 1)
        w = np.where(ok[:, None], 1.0 / np.maximum(var, 1e-300), 0.0)
        num += w * np.where(ok[:, None], y, 0.0)
        den += w
        usable |= ok
    if usable.sum() < 12:
        raise CamcalError(f"only {int(usable.sum())} of 24 patches are usable (not saturated) in any photo; expose "
                          "for the white patch (no channel at its white level) and shoot again", photos[0].path)
    signal, scov = {}, {}
    for i, c in enumerate(names):
        y = np.where(den[:, i] > 0, num[:, i] / np.maximum(den[:, i], 1e-300), 0.0)
        var = np.where(den[:, i] > 0, 1.0 / np.maximum(den[:, i], 1e-300), 0.0)
        big = LEFT_OUT_VARIANCE * max(float(np.nanmax(np.abs(y))), 1e-30) ** 2
        var = np.where(usable, np.maximum(var, 1e-12 * max(float(np.max(np.abs(y))), 1e-30) ** 2), big)
        y = np.where(usable, y, float(np.median(y[usable])))
        signal[c], scov[c] = y, np.diag(var)
    return signal, scov, usable


# ---- the light ---------------------------------------------------------------------------------------------------
def chart_sun(options: ChartOptions, photo: ChartPhoto) -> SunPosition:
    """The sun for the chart photo: ``--sun`` or the photo's EXIF time and GPS (:mod:`camcal.io.sun`)."""
    if options.sun is not None:
        return parse_sun_option(options.sun)
    try:
        return sun_from_metadata(photo.exposure, utc_offset=options.utc_offset, path=photo.path)
    except CamcalError as exc:
        raise CamcalError(f"{exc.message}; or name the light: --illuminant D65 (a CIE illuminant), --illuminant "
                          "FILE.csv (a measured spectrum) or --illuminant estimate", photo.path) from None


def make_light(options: ChartOptions, photo: ChartPhoto, wavelength_nm: np.ndarray) -> Irradiance | None:
    """The light on the chart (module docstring); None for ``estimate`` (fitted with c)."""
    ill = options.illuminant
    if ill is not None and str(ill).lower() == "estimate":
        return None
    if ill is not None and (str(ill).lower().endswith(".csv") or Path(ill).is_file()):
        return read_irradiance_csv(ill, absolute=options.illuminant_absolute, wavelength_nm=wavelength_nm)
    if ill is not None:
        return cie_illuminant(ill, wavelength_nm=wavelength_nm)
    sun = chart_sun(options, photo)
    doy = sun.utc.timetuple().tm_yday if sun.utc is not None else None
    kw = {} if options.aerosol_sigma is None else {"aerosol_sigma": options.aerosol_sigma}
    light = clear_sky_irradiance(sun.zenith_deg, aerosol_optical_depth_500nm=options.aerosol_optical_depth_500nm,
                                 precipitable_water_cm=options.precipitable_water_cm, ozone_atm_cm=options.ozone_atm_cm,
                                 pressure_Pa=options.pressure_Pa, day_of_year=doy, wavelength_nm=wavelength_nm, **kw)
    src = {**light.source, "sun": {"zenith_deg": sun.zenith_deg, "azimuth_deg": sun.azimuth_deg,
                                   "source": sun.source, "utc": None if sun.utc is None else sun.utc.isoformat()}}
    return dataclasses.replace(light, source=src)


# ---- processed photos --------------------------------------------------------------------------------------------
def _rgb_of_raw(p: ChartPhoto) -> tuple[np.ndarray, np.ndarray]:
    """(24, 3) R, mean G, B patch means of a RAW photo and (24, 3, 3) covariances."""
    m, c = p.patches.mean_dn, p.patches.cov_dn2
    if m.shape[1] == 3:
        return m, c
    t = np.array([[1, 0, 0, 0], [0, 0.5, 0.5, 0], [0, 0, 0, 1]], float)
    return m @ t.T, np.einsum("ij,kjl,ml->kim", t, c, t)


def _linearised(tone: ToneFit, p: ChartPhoto) -> tuple[np.ndarray, np.ndarray]:
    """(24, 3) linearised means and their (24, 3, 3) covariances (the patch covariance through the slope)."""
    m = p.patches.mean_dn
    lin = tone.linearise(m)
    s = tone.slope(m)
    cov = p.patches.cov_dn2 * (s[:, :, None] * s[:, None, :])
    return lin, cov


def _rho_eff(chart: ChartReflectance, light: Irradiance | None, c: dict[str, np.ndarray] | None) -> np.ndarray:
    """(24, 3) effective reflectance ∫ c ρ E / ∫ c E per channel (a flat c and flat E when unknown)."""
    wl = chart.wavelength_nm
    e = np.ones_like(wl) if light is None else light.on(wl).irradiance_w_m2_nm
    out = np.empty((24, 3))
    for i, ch in enumerate(RGB3):
        ci = np.ones_like(wl) if c is None else np.asarray(c[ch], float)
        w = ci * e
        out[:, i] = np.trapezoid(chart.reflectance * w, wl, axis=1) / np.trapezoid(w, wl)
    return out


def _processed_response(tone: ToneFit, matrix: ColourMatrix, photos: Sequence[ChartPhoto],
                        ref: tuple[float, float], x_s: Sequence[float] | None) -> ResponseModel:
    """The ``processed`` response a chart fit gives: the tone curve and the colour matrix apply reads."""
    w = tone.white_level_dn
    chans = {}
    vals = np.concatenate([p.patches.mean_dn[list(NEUTRAL_PATCHES)] for p in photos] or [np.empty((0, 3))])
    x_white = None
    if tone.gains is not None:
        x_white = [1.0 / max(float(g), 1e-300) for g in tone.gains]  # x·ρ̄ reaching white
    for i, ch in enumerate(RGB3):
        v = vals[:, i][np.isfinite(vals[:, i])]
        lo, hi = (float(v.min()), float(v.max())) if v.size else (math.nan, math.nan)
        gain = math.nan if x_white is None else w / x_white[i]
        chans[ch] = ChannelResponse(alpha=gain, alpha_unc=math.nan, gamma=1.0 / tone.exponent,
                                    gamma_unc=tone.exponent_unc / tone.exponent**2, beta=0.0, beta_unc=math.nan,
                                    linear_range_dn=(lo, hi), saturation_dn=w, linearity_error_pct=math.nan,
                                    pearson_r=math.nan)
    return ResponseModel("processed", chans, ref[0], ref[1], tone=tone.tone_record(RGB3, x_white),
                         white_level_dn=w, colour_matrix=matrix)


#: Iterations and over-relaxation of the colour-matrix estimate of processed-only photos (:func:`unmix_processed`).
UNMIX_ITERATIONS = 6
UNMIX_RELAXATION = 2.5


def unmix_processed(signal: dict[str, np.ndarray], scov: dict[str, np.ndarray], chart: ChartReflectance,
                    light: Irradiance, basis, options: ChartOptions
                    ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray], str]:
    """The colour matrix A of processed-only photos: j = A r with r = M c, c non-negative and camera-like.

    A processed channel mixes the sensor's (j = A r, white balance included); any invertible B gives another
    pair (A B⁻¹, B c), so the data alone cannot separate them: the basis's prior (curves shaped like measured
    cameras, c ≥ 0) does. Alternating least squares: c recovered from A⁻¹ j (:func:`recover_sensitivity`),
    then A fitted to j ≈ A (M c) (weighted by the signals' variances), over-relaxed by
    :data:`UNMIX_RELAXATION`; A's rows normalised to sum 1 (a neutral stays neutral: the diagonal scale
    ambiguity is given to c). Returns (A, the unmixed signals and their variances, a note).
    """
    j = np.column_stack([signal[c] for c in RGB3])
    v = np.column_stack([np.diag(scov[c]) for c in RGB3])
    m = design_matrix(chart, light)
    a = np.eye(3)

    def rows_to_one(x: np.ndarray) -> np.ndarray:
        return x @ np.diag(np.linalg.inv(x) @ np.ones(3))

    chi2 = math.nan
    for _ in range(UNMIX_ITERATIONS):
        ai = np.linalg.inv(a)
        y, vy = j @ ai.T, v @ (ai ** 2).T
        rec = recover_sensitivity({c: y[:, i] for i, c in enumerate(RGB3)},
                                  {c: vy[:, i] for i, c in enumerate(RGB3)}, chart, light, basis,
                                  n_components=options.n_components, regularisation=options.regularisation)
        chi2 = sum(rec.chi2.values())
        r = np.column_stack([m @ rec.values[c] for c in RGB3])
        w = 1.0 / np.sqrt(v)
        fit = np.vstack([np.linalg.lstsq(r * w[:, [i]], j[:, i] * w[:, i], rcond=None)[0] for i in range(3)])
        a = rows_to_one(a + UNMIX_RELAXATION * (rows_to_one(fit) - a))
    ai = np.linalg.inv(a)
    y, vy = j @ ai.T, v @ (ai ** 2).T
    note = ("colour matrix of the processed channels estimated from the chart (rows R, G, B: "
            + "; ".join(", ".join(f"{x:.3f}" for x in row) for row in a) + f"; χ² {chi2:.3g} over 72 values)")
    return a, {c: y[:, i] for i, c in enumerate(RGB3)}, {c: np.diag(vy[:, i]) for i, c in enumerate(RGB3)}, note


# ---- the flat ----------------------------------------------------------------------------------------------------
def flat_from_photos(paths: Sequence[Path], tone: ToneFit | None = None, progress=None) -> FlatModel:
    """A relative flat (vignetting, 1 on the optical axis) from photos of a uniform surface.

    RAW photos: black level subtracted; processed photos: linearised with ``tone`` and binned 2x2 (the planes a
    processed profile's apply divides). The photos are normalised by their medians and averaged; the radial model
    of :func:`camcal.calibrate.flat.fit_flat_planes` is fitted (no PRNU: a wall or a sky is not uniform pixel by pixel).
    """
    stack = None
    n = 0
    first = None
    exposures = []
    for path in paths:
        frame = load_frame(path)
        exposures.append(frame.exposure)
        if first is None:
            first = frame
        elif frame.shape != first.shape or frame.kind != first.kind:
            raise CamcalError(f"flat photos differ in size or kind from {first.path.name}", path)
        if frame.kind == "raw":
            planes = frame.planes(np.float32) - frame.black_vector().astype(np.float32)
            planes[frame.planes(np.float32) >= frame.white_level_dn] = np.nan
        else:
            if tone is None:
                raise CamcalError("processed flat photos need a tone curve: give the chart as HEIC/JPEG too", path)
            v = frame.planes(np.float32)
            lin = tone.linearise(v).astype(np.float32)
            lin[v >= frame.white_level_dn] = np.nan
            c, h, w = lin.shape
            planes = np.nanmean(lin[:, : h // 2 * 2, : w // 2 * 2].reshape(c, h // 2, 2, w // 2, 2), axis=(2, 4))
        med = np.nanmedian(planes.reshape(planes.shape[0], -1), axis=1)
        if np.any(~(med > 0)):
            raise CamcalError("flat photo has no signal above black in some channel", path)
        planes = planes / med[:, None, None]
        stack = planes if stack is None else stack + planes
        n += 1
        if progress:
            progress()
    if first is None:
        raise CamcalError("--flat: no photos given")
    mean = stack / n
    mask = ~np.isfinite(mean)
    mean = np.where(mask, np.float32(1.0), mean)
    channels = tuple(first.channel_names) if first.kind == "raw" else RGB3
    fm = fit_flat_planes(mean.astype(np.float32), channels=channels,
                         cfa_pattern=first.cfa_pattern if first.layout == "bayer" else None, model="radial",
                         mask=mask, with_prnu=False,
                         info={"n_frames": n, "files": [Path(p).name for p in paths],
                               "source": "photos of a uniform surface (camcal chart --flat)"})
    return fm.replace(optics=flats_optics(exposures, Path(paths[0]).parent))


# ---- the whole stage ---------------------------------------------------------------------------------------------
def _input(path: Path, stage: str, sha: str | None = None) -> dict:
    return {"stage": stage, "file": Path(path).name, "sha256": sha or sha256_file(path),
            "bytes": Path(path).stat().st_size}


def build_chart_profile(paths: Sequence[str | Path], options: ChartOptions = ChartOptions(),  # noqa: B008
                        progress: Callable[[str], None] | None = None) -> ChartResult:
    """Chart photos → :class:`camcal.models.profile.CalibrationProfile` with ``source: chart`` (module docstring)."""
    if not paths:
        raise CamcalError("give at least one photo of the colour chart")
    tick = progress or (lambda _msg: None)
    warnings: list[str] = []
    notes: list[str] = []
    photos: list[ChartPhoto] = []
    frames_shape: dict[Path, tuple[int, int]] = {}
    for p in paths:
        ph, frame = read_chart_photo(Path(p), options.corners)
        frames_shape[ph.path] = frame.shape
        photos.append(ph)
        tick(f"chart found in {ph.path.name} ({ph.location.method})")
        notes.extend(f"{ph.path.name}: {n}" for n in ph.patches.notes)
    raws = [p for p in photos if p.kind == "raw"]
    procs = [p for p in photos if p.kind == "processed"]
    if raws and len({(p.layout, p.shape) for p in raws}) > 1:
        raise CamcalError("the RAW chart photos differ in layout or size: give photos of one camera and mode")
    if procs and len({p.white_level_dn for p in procs}) > 1:
        raise CamcalError("the processed chart photos differ in bit depth: give HEICs or JPEGs, not both")
    chart = (published_chart() if options.chart_csv is None else read_chart_csv(options.chart_csv))
    basis = _library_basis(options.ir_cut)
    wl = basis.wavelength_nm
    chart = chart.on(wl)
    light = make_light(options, photos[0], wl)
    base_group = raws or procs
    ref = _setting(base_group)
    x_s = _relative_exposures(base_group, ref, notes)
    flat = None
    tone: ToneFit | None = None
    matrix: ColourMatrix | None = None
    twins: list[tuple[ChartPhoto, ChartPhoto]] = []
    if raws and procs:
        by_stem = {p.path.stem: p for p in raws}
        twins = [(by_stem[q.path.stem], q) for q in procs if q.path.stem in by_stem]
        if not twins:
            warnings.append("processed photos without a RAW twin of the same name are not used when RAW photos are "
                            "given (the RAW defines c(λ))")
    if raws:
        if options.flat:
            flat = flat_from_photos(options.flat)
        signal, scov, usable = combine_signals(raws, x_s, flat)
        nonneg = True
    else:
        # processed only: tone from the neutrals, iterated with the recovered c (the patches' effective reflectance)
        sem = [p.patches.sem_dn() for p in procs]
        xs = x_s if x_s is not None else [1.0] * len(procs)
        c_guess = None
        for _ in range(3 if options.flat else 2):
            gains = None if flat is None else [_flat_gain_at(flat, p) for p in procs]
            tone = fit_tone_neutral([p.patches.mean_dn for p in procs], sem, xs, _rho_eff(chart, light, c_guess),
                                    procs[0].white_level_dn, gains)
            if options.flat:  # the flat's shape depends on the tone curve that linearises it
                flat = flat_from_photos(options.flat, tone)
            signal, scov, usable = combine_signals(procs, x_s, flat, lambda p, t=tone: _linearised(t, p))
            if light is None:
                continue
            rec0 = recover_sensitivity(signal, scov, chart, light, basis, n_components=options.n_components,
                                       regularisation=options.regularisation, nonnegative=False)
            c_guess = rec0.values
        nonneg = True
        a = np.eye(3)
        if light is not None:
            a, signal, scov, mix_note = unmix_processed(signal, scov, chart, light, basis, options)
            notes.append(mix_note)
        resid = tuple(float(v) for v in np.zeros(3))
        matrix = ColourMatrix(a, np.zeros((3, 3)), (len(procs),) * 3, resid, tuple(p.path.name for p in procs))
        warnings.append("processed photos only: the profile reads processed photos taken with the same white balance "
                        "and style only; its colour matrix is estimated from the chart (channels unmixed into "
                        "camera-like curves), not measured; RAW (ProRAW/DNG) twins measure it")
    tick("patches measured")
    estimate = None
    if light is None:
        # both families fitted; the one of the larger evidence (smaller −2 log p) is kept
        fits = [estimate_illuminant(signal, scov, chart, basis, family=fam, n_components=options.n_components,
                                    regularisation=options.regularisation, nonnegative=nonneg)
                for fam in ("daylight", "blackbody")]
        est = min(fits, key=lambda f: float(np.min(f.profile_objective)))
        rec, light = est.recovered, est.light
        estimate = {"family": est.family, "parameter_K": est.parameter_K, "u_parameter_K": est.u_parameter_K,
                    "notes": list(est.notes),
                    "minus_2_log_evidence": {f.family: float(np.min(f.profile_objective)) for f in fits}}
        warnings.extend(est.notes)
    else:
        rec = recover_sensitivity(signal, scov, chart, light, basis, n_components=options.n_components,
                                  regularisation=options.regularisation, nonnegative=nonneg)
    tick("c(λ) recovered")
    absolute = rec.absolute and x_s is not None
    if rec.absolute and x_s is None:
        rec = dataclasses.replace(rec, absolute=False)
    spectral = rec.to_spectral_sensitivity(reference_iso=ref[0] if absolute else None,
                                           reference_f_number=ref[1] if absolute else None)
    wb_text = None
    if twins:
        tw_raw, tw_proc = zip(*twins, strict=True)
        raw_rgb = [_rgb_of_raw(r)[0] for r in tw_raw]
        use = [~(r.patches.saturated | q.patches.saturated) for r, q in twins]
        tone = fit_tone_twins([q.patches.mean_dn for q in tw_proc], [q.patches.sem_dn() for q in tw_proc], raw_rgb,
                              tw_proc[0].white_level_dn, use)
        notes.extend(tone.notes)
        m = tone.matrix * tone.white_level_dn
        mu = tone.matrix_unc * tone.white_level_dn
        resid = []
        for i in range(3):
            pred = np.concatenate([rr @ m[i] for rr in raw_rgb])
            lin = np.concatenate([tone.linearise(q.patches.mean_dn)[:, i] for q in tw_proc])
            ok = np.concatenate(use) & (lin > 0)
            resid.append(float(np.sqrt(np.mean(((lin - pred) / lin)[ok] ** 2))) if ok.any() else math.nan)
        matrix = ColourMatrix(m, mu, (len(twins),) * 3, tuple(resid), tuple(q.path.name for q in tw_proc))
        procs = list(tw_proc)
        if ref[0] is not None:  # the linear gain of the processed channels: lin / (x ρ̄) over the light neutrals
            rho = _rho_eff(chart, light, {c: spectral.rgb()[c] for c in RGB3})
            light4 = list(NEUTRAL_PATCHES[:4])
            g = [tone.linearise(q.patches.mean_dn)[light4] / (frame_relative_exposure(q.exposure, ref[0], ref[1],
                                                                                      q.path) * rho[light4])
                 for q in procs]
            tone = dataclasses.replace(tone, gains=np.nanmedian(np.concatenate(g), axis=0) / tone.white_level_dn)
    if procs and tone is not None:
        lin_neutral = [tone.linearise(p.patches.mean_dn)[list(NEUTRAL_PATCHES)] for p in procs]
        locked, wb_text = white_balance_check(lin_neutral, [p.path.name for p in procs])
        (notes if locked else warnings).append(wb_text)
    # the profile
    first = base_group[0]
    e = first.exposure
    h, w = frames_shape[first.path]
    if raws:
        cam = CameraIdentity(e.make, e.model, e.serial, first.cfa_pattern, w, h,
                             "linear" if first.layout == "linear" else "bayer")
    else:
        cam = CameraIdentity(e.make, e.model, e.serial, None, w, h, "processed")
    response = None
    if procs and tone is not None and matrix is not None:
        pref = _setting(procs)
        pref = pref if pref[0] is not None else (ref[0] or 100.0, ref[1] or 1.0)
        response = {"processed": _processed_response(tone, matrix, procs, ref if ref[0] else pref, x_s)}
    if flat is None:
        warnings.append("no flat photos (--flat): apply corrects no vignetting; radiance away from the image centre "
                        "is low by the lens's fall-off (a phone's corners: often 30-60 %)")
    records = [p.record(None if x_s is None or p not in base_group else x_s[base_group.index(p)]) for p in photos]
    processed_rec = None
    if tone is not None:
        processed_rec = {"tone": {"exponent": tone.exponent, "exponent_unc": tone.exponent_unc,
                                  "offset_a": tone.offset_a, "offset_a_unc": tone.offset_a_unc,
                                  "rms_dn": tone.rms_dn, "chi2_red": tone.chi2_red, "n_points": tone.n_points,
                                  "fitted_on": "RAW twins, all patches" if twins else "neutral patches"},
                         "colour_matrix": None if matrix is None else matrix.to_dict(),
                         "white_balance": wb_text}
    src = dict(spectral.source or {})
    src.update({"file": first.path.name, "sha256": first.sha256, "format": None, "photos": records})
    if processed_rec is not None:
        src["processed"] = processed_rec
    if estimate is not None:
        src["light"] = {**src.get("light", {}), "estimate": estimate}
    if flat is None:
        src["vignetting"] = {"corrected": False, "corner_field_deg": UNCORRECTED_CORNER_FIELD_DEG,
                             "model": "not measured (no --flat photos): apply corrects none and adds to each pixel's "
                                      "σ the cos⁴ fall-off of a lens whose corner lies at corner_field_deg, as a "
                                      "uniform bias between 0 and that loss (σ = loss/√3)"}
    src["notes"] = [*notes, *warnings]
    spectral = dataclasses.replace(spectral, source=src)
    inputs = [_input(p.path, "chart", p.sha256) for p in photos] + [_input(Path(f), "flat") for f in options.flat]
    if options.chart_csv is not None:
        inputs.append(_input(Path(options.chart_csv), "chart_reflectance"))
    if options.illuminant and Path(options.illuminant).is_file():
        inputs.append(_input(Path(options.illuminant), "illuminant"))
    created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    profile = CalibrationProfile(camera=cam, reference_iso=ref[0] if absolute else None,
                                 reference_f_number=ref[1] if absolute else None, flat=flat, response=response,
                                 spectral=spectral,
                                 provenance=Provenance(__version__, created, tuple(inputs),
                                                       {"chart": options.record()}))
    return ChartResult(profile, rec, light, tuple(photos), tone, tuple(warnings), tuple(notes), estimate, wb_text)

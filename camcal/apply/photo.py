"""Apply a calibration profile to one survey photo: radiance per channel and at one wavelength.

The pipeline (seed eq. 12 inverted, seed §2.1 and §3.1)
--------------------------------------------------------
RAW (CFA planes R, G1, G2, B in DN)::

    signal  = planes − (bias + β·t·ISO/ISO_dark)        dark model (or the file's black level)
    signal /= g_flat(x, y)                              flat field, 1 on the optical axis
    rate    = signal / x,   x = (ISO·t/N²)/(ISO_ref/N_ref²)   DN s⁻¹ at the reference setting
    R, G, B = R, (G1 + G2)/2, B
    L_i     = rate_i / ∫c_i dλ                          band radiance, W m⁻² sr⁻¹ nm⁻¹
    L(λ0)   = w · (R, G, B)                             narrowband or smooth estimator (camcal.apply.radiance)

Processed (JPEG/TIFF/PNG, 8 or 16 bit R, G, B)::

    lin     = response["processed"].linearise(values)   linear, 0..W scale, ∝ exposure
    DN_raw  = A⁻¹ · lin                                 the profile's colour matrix (camcal.calibrate.colour_matrix), or
            = lin · k_i,  k_i = a_raw,i / a_jpeg,i      without one: a gain per channel (same linearity series)
    2x2 mean → half resolution, then flat, exposure and radiance as for RAW (no dark subtraction:
    the camera already removed black).

Assumptions for processed files: the camera renders tone(A · RAW) with a fixed white balance and colour
matrix (the matrix A is fitted from RAW + JPEG twins of the sweep and the linearity series; without it
each JPEG channel is assumed to depend on one RAW channel only, true for a camera without a matrix and
for no real one), a per-channel tone curve, and no local tone mapping or noise reduction. JPEG results
are only valid with the white balance and picture style fixed as during calibration; RAW is the
radiometric format.

Resolution
----------
The output is **half resolution**, not demosaicked: one value per 2x2 CFA cell (R, mean of the two G,
B of that cell), so an (H, W) photo gives (H/2, W/2) maps. Processed files are binned 2x2 to the same
grid. Pixel (i, j) of the output covers photo pixels rows 2i..2i+1, columns 2j..2j+1.

Invalid pixels are NaN: defective pixels of the dark model (hot, dead, noisy; in G only when both G1
and G2 are defective), saturated pixels (RAW DN at the white level; processed values at the maximum).

Uncertainty (``L<λ>_unc``, one standard deviation)
-------------------------------------------------
Per-pixel noise variance in DN² of each RAW plane, EMVA 1288 linear model::

    var = σ_read² · (ISO/ISO_dark)² + K · (signal + β·t·ISO/ISO_dark),  K = K_dark · ISO/ISO_dark

with σ_read the dark model's per-pixel read noise and K the system gain in DN per electron from photon
transfer (the profile's ``emva1288`` section, EMVA 1288 release 4.0), else from the dark model's
photon-transfer line of the dark signal (``gain_dn_per_e_from_dark``); the read noise is assumed input
referred (constant in electrons), so it scales with ISO in DN. Without a dark model the noise term
is omitted (documented in the metadata ``notes``). For processed files the same model is evaluated at
the RAW-equivalent signal (the JPEG came from that sensor; quantisation and compression are ignored).
The variance is propagated through the flat, the exposure and the estimator's linear weights and
combined with the relative uncertainty of c(λ) (as :func:`camcal.apply.radiance.radiance_at` does) and,
when the PRNU map is not applied, the profile's PRNU (relative RMS per channel, a fixed-pattern
error of each pixel) and, for ``smooth``, the spectral-reconstruction error (the RMS error over the prior
spectra, :func:`camcal.apply.radiance.smooth_spread_rel`). ``narrowband`` has no such term: it is exact for light
confined near λ0 and meaningless for broadband light (the metadata's ``spectral_assumption`` says so).
``R_unc``, ``G_unc``, ``B_unc`` are the noise of each band (the c(λ) scale, common to every photo, is in
``band_scale_unc_rel``). Not included: flat-field model error, exposure-metadata error (ISO and f-number are
nominal values).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from camcal.apply.processed_unc import SystematicVariance, systematic_variance
from camcal.apply.radiance import RadianceModel, mono_model, radiance_at, radiance_model
from camcal.errors import CamcalError
from camcal.frame import PLANES, Frame, plane_offsets, rgb_from_planes
from camcal.io.read import open_image, read_pixels
from camcal.models.camera_id import Sensor, match, sensor_of, sensor_of_profile
from camcal.models.correct import Calibration, correct_planes, system_gain_dn_per_e
from camcal.models.exposure import frame_relative_exposure
from camcal.models.falloff import corner_field, relative_radius, uncorrected_sigma_rel
from camcal.models.flat import FlatChoice, choose_flat
from camcal.region import Region
from camcal.threads import default_threads, run_bands
from camcal.units import BAND_RADIANCE

BAND_UNITS = BAND_RADIANCE
#: Unit of every map written from a profile whose c(λ) is relative (only ratios of two such maps are physical).
RELATIVE_UNITS = "relative (c(λ) without an absolute scale: ratios only)"
#: Channel order of the interleaved output array (the L<λ0> names are filled in per plan).
OUTPUT_CHANNELS = ("R", "G", "B", "L", "L_unc", "R_unc", "G_unc", "B_unc")


SPECTRAL_ASSUMPTIONS = {
    "narrowband": "light confined near the wavelength (a line or an interference filter); on a broadband scene L is "
                  "the in-band radiance, not a spectral radiance, and its spectral error is unbounded",
    "smooth": "smooth spectrum (no lines); spectral_unc_rel is the RMS error over the priors",
    "trained": "a scene like the prior spectra (black bodies, daylight, reflectances under daylight); "
               "spectral_unc_rel is the leave-one-out RMS error over them",
}
"""What each L(λ0) estimator assumes of the scene (:mod:`camcal.apply.radiance`), written in the EXR's metadata."""


def next_step_for_c(profile) -> str:
    """What to do for a profile without a usable c(λ): the step that fits the profile at hand."""
    spectral = getattr(profile, "spectral", None)
    if spectral is None:
        if getattr(profile, "dark", None) is not None and getattr(profile, "flat", None) is None \
                and getattr(profile, "response", None) is None:
            return ("this bias/dark-only profile needs a monochromator sweep (SESSION/sweep/ with sweep.csv, then "
                    "camcal calibrate), or imported curves (camcal profile import-spectral CURVES --into PROFILE)")
        return ("add a monochromator sweep (SESSION/sweep/, camcal calibrate) or import curves "
                "(camcal profile import-spectral CURVES --into PROFILE --targets targets/ -o abs.camcal); without a "
                "lab, photograph a colour chart in the sun: camcal chart CHART.dng -o camera.camcal")
    source = (spectral.source or {}).get("kind") if isinstance(getattr(spectral, "source", None), dict) else None
    if source in ("imported", "library"):
        return ("set the absolute scale of the imported curves from reference targets: camcal profile "
                "import-spectral CURVES --into PROFILE --targets targets/ -o abs.camcal; or make the profile from "
                "a colour chart in the sun (camcal chart CHART.dng -o camera.camcal)")
    if source == "chart":
        return ("photograph the chart again with its exposure tags (time, ISO, f-number) under the sun or a measured "
                "light (camcal chart CHART.dng -o camera.camcal; --illuminant D65 or estimate give shape only)")
    return "calibrate the sweep with --sweep-mode absolute (it needs the reference detector's radiances)"


RESOLUTION_NOTE = "half resolution: one value per 2x2 CFA cell (R, mean of G1 and G2, B), not demosaicked"
LINEAR_RESOLUTION_NOTE = "full resolution: the linear RAW's own R, G, B planes (already demosaicked by its writer)"


def radiance_channel_name(wavelength_nm: float, in_band: bool = False) -> str:
    """``L663`` for the spectral radiance at 663 nm; ``L662.5`` for 662.5 nm; ``L663_inband`` for the in-band
    radiance (W m⁻² sr⁻¹) of ``narrowband`` without a filter width, which is not a spectral radiance."""
    return f"L{float(wavelength_nm):g}" + ("_inband" if in_band else "")


@dataclass(frozen=True, eq=False)
class RadianceImage:
    """Result of :func:`apply`: named half-resolution maps and metadata.

    Attributes
    ----------
    channels : dict
        ``R``, ``G``, ``B``: band radiance, W m⁻² sr⁻¹ nm⁻¹; ``L<λ>`` spectral radiance at λ
        (units in ``metadata["units"]``) and ``L<λ>_unc`` its standard uncertainty. float32 (h, w).
    metadata : dict
        units, wavelength_nm, estimator, profile_sha256, source_file, exposure, camera, notes...
    """

    channels: dict[str, np.ndarray]
    metadata: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return next(iter(self.channels.values())).shape  # type: ignore[return-value]


@dataclass(frozen=True, eq=False)
class ApplyPlan:
    """Everything of a profile that does not depend on the photo, computed once (batches reuse it).

    Attributes
    ----------
    profile : the CalibrationProfile.
    model : the radiance estimator's linear maps.
    flat_planes : (4, h, w) flat gain of the RAW planes, or None without a flat model.
    flat_rgb : (3, h, w) flat gain of R, G (mean of G1, G2), B, or None.
    options : the estimator options, for the metadata.
    """

    profile: object
    model: RadianceModel
    flat_planes: np.ndarray | None
    flat_rgb: np.ndarray | None
    options: dict
    prnu_rel: np.ndarray | None = None
    calibration: Calibration = Calibration()
    """The RAW planes' correction (:mod:`camcal.models.correct`): dark model, flat gain, defects."""
    rgb_calibration: Calibration = Calibration()
    """The flat division of processed photos' binned R, G, B (:mod:`camcal.models.correct`)."""
    flat_plans: dict = field(default_factory=dict)
    """Plans with the vignetting model of another f-number (:func:`plan_for_optics`), built once per model."""

    @property
    def relative(self) -> bool:
        """True when the profile's c(λ) is relative: every map is then relative radiance (ratios only)."""
        return getattr(self.profile.spectral, "mode", "absolute") != "absolute"


    @property
    def gain_dn_per_e(self) -> np.ndarray | None:
        """(4, 1, 1) system gain of the dark model at its ISO, DN per electron."""
        return self.calibration.noise_gain_dn_per_e


def prepare(
    profile,
    wavelength_nm: float = 663.0,
    estimator: str = "auto",
    *,
    filter_fwhm_nm: float | None = None,
    line_fwhm_nm: float | None = None,
    with_prnu: bool = False,
) -> ApplyPlan:
    """Precompute the photo-independent parts of :func:`apply` for ``profile``.

    Raises
    ------
    CamcalError
        The profile has no absolute spectral sensitivity, or the wavelength/estimator is invalid.
    """
    spectral = profile.spectral
    if spectral is None:
        raise CamcalError("the profile has no spectral sensitivity c(λ); radiance needs it: "
                          f"{next_step_for_c(profile)}")
    if profile.reference_iso is None or profile.reference_f_number is None:
        raise CamcalError("the profile holds no reference ISO and f-number (no stage of its calibration normalised "
                          "exposure); radiance needs them: calibrate again with --reference-iso and "
                          "--reference-f-number, or with 'iso' and 'f_number' in session.toml (imported curves: "
                          "camcal profile import-spectral --reference-iso and --reference-f-number)")
    slit = 0.0 if spectral.deconvolved else spectral.bandwidth_nm
    if getattr(spectral, "mono", False):  # one channel Y: band radiance, L(λ0) only through a narrowband filter
        model = mono_model(spectral.wavelength_nm, spectral.values["Y"], spectral.uncertainty["Y"],
                           float(wavelength_nm), estimator, filter_fwhm_nm=filter_fwhm_nm,
                           line_fwhm_nm=line_fwhm_nm, slit_fwhm_nm=slit)
    else:
        model = radiance_model(spectral.wavelength_nm, spectral.rgb(), spectral.rgb_uncertainty(),
                               float(wavelength_nm), estimator, filter_fwhm_nm=filter_fwhm_nm,
                               line_fwhm_nm=line_fwhm_nm, slit_fwhm_nm=slit)
    flat_planes, flat_rgb = _flat_maps(None if profile.flat is None else profile.flat.gain(with_prnu=with_prnu),
                                       profile)
    prnu_rel = None
    if profile.flat is not None and not with_prnu and profile.flat.prnu_rms:
        rms = [float(profile.flat.prnu_rms.get(c, 0.0) or 0.0) for c in profile.flat.channels]
        if len(rms) == 4:
            rms = [rms[0], 0.5 * math.hypot(rms[1], rms[2]), rms[3]]
        prnu_rel = np.array(rms, np.float32)[:, None, None]
    options = {"wavelength_nm": float(wavelength_nm), "estimator": estimator, "filter_fwhm_nm": filter_fwhm_nm,
               "line_fwhm_nm": line_fwhm_nm, "with_prnu": with_prnu}
    cal = Calibration.of(profile.dark, None, emva=getattr(profile, "emva", None))
    if flat_planes is not None:  # the gain evaluated above, not a second time (a worker's start-up)
        if not np.all(np.isfinite(flat_planes)) or np.any(flat_planes <= 0):
            raise CamcalError("the flat model's gain is not positive and finite everywhere")
        cal = replace(cal, flat_gain=flat_planes, inv_flat_gain=(1.0 / flat_planes).astype(np.float32))
    rgb_cal = _rgb_calibration(flat_rgb)
    return ApplyPlan(profile, model, flat_planes, flat_rgb, options, prnu_rel, cal, rgb_cal)


def _rgb_calibration(flat_rgb: np.ndarray | None) -> Calibration:
    """The calibration of binned R, G, B (processed photos): the flat gain only."""
    return Calibration(flat_gain=flat_rgb, inv_flat_gain=None if flat_rgb is None else 1.0 / flat_rgb)


def _flat_maps(gain: np.ndarray | None, profile) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(gain of the RAW planes, gain of binned R, G, B) of a flat gain map: (4, h, w) Bayer planes, (3, h, w)
    linear RAW planes, or (3, h, w) of a flat fitted on processed frames (then no RAW planes)."""
    if gain is None:
        return None, None
    flat_planes = np.asarray(gain, np.float32)
    if flat_planes.shape[0] == 4:
        return flat_planes, rgb_from_planes(flat_planes)
    if getattr(profile.camera, "layout", "bayer") in ("linear", "mono"):  # linear RAW R, G, B or mono Y planes
        return flat_planes, flat_planes
    return None, flat_planes  # a flat fitted on processed RGB frames


def plan_for_optics(plan: ApplyPlan, exposure, path: Path | None, notes: list[str],
                    strict: bool = False) -> tuple[ApplyPlan, FlatChoice | None]:
    """The plan with the vignetting model of the photo's f-number and focal length (:func:`camcal.models.flat.
    choose_flat`: the model measured at it, interpolated between two, or the nearest with a warning).

    The warning goes to ``notes``; with ``strict`` a photo whose setting the flats were not measured at is
    refused (one line). Plans of other f-numbers are built once and kept in ``plan.flat_plans``.
    """
    flat = getattr(plan.profile, "flat", None)
    if flat is None:
        return plan, None
    choice = choose_flat(flat, exposure.f_number, exposure.focal_length_mm)
    if choice.warning:
        if strict and choice.mismatch:
            raise CamcalError(f"{choice.warning}; refused by --strict (without it the photo is corrected with "
                              "this warning)", path)
        notes.append(choice.warning)
    if len(choice.parts) == 1 and choice.parts[0][0] is flat:
        return plan, choice
    other = plan.flat_plans.get(choice.key)
    if other is None:
        flat_planes, flat_rgb = _flat_maps(choice.gain(with_prnu=bool(plan.options.get("with_prnu"))), plan.profile)
        cal = plan.calibration
        if flat_planes is not None:
            cal = replace(cal, flat_gain=flat_planes, inv_flat_gain=(1.0 / flat_planes).astype(np.float32))
        rgb_cal = _rgb_calibration(flat_rgb)
        other = replace(plan, flat_planes=flat_planes, flat_rgb=flat_rgb, calibration=cal, rgb_calibration=rgb_cal)
        plan.flat_plans[choice.key] = other
    return other, choice


def check_camera(exposure, profile, path: Path | None, allow_other_camera: bool = False,
                 frame: Frame | None = None) -> list[str]:
    """Refuse a photo from another camera than the profile's; returns notes.

    One camera under two software names passes (:mod:`camcal.models.camera_id`: the make normalised, a writer's
    placeholder model such as PiDNG's with the same sensor geometry, CFA and layout), with a note.
    A photo without make/model metadata cannot be checked: a note says so.
    """
    cam = profile.camera
    make, model = exposure.make, exposure.model
    if not make and not model:
        return ["photo has no camera make/model metadata: camera not checked"]
    photo = Sensor(make, model)
    if frame is not None and frame.layout != "processed":  # a JPEG's size and levels are not the RAW's
        photo = replace(sensor_of(frame), make=make, model=model)
    same, note = match(photo, sensor_of_profile(cam))
    if same:
        return [note] if note else []
    msg = f"photo is from {make} {model}, the profile is for {cam.make} {cam.model}"
    if not allow_other_camera:
        raise CamcalError(f"{msg}; use a profile of this camera (or --allow-other-camera)", path)
    return [msg + " (allowed by --allow-other-camera)"]


def _bin2(x: np.ndarray) -> np.ndarray:
    """(C, H, W) -> (C, H//2, W//2) mean of 2x2 blocks (odd edges cropped)."""
    c, h, w = x.shape
    x = x[:, : h // 2 * 2, : w // 2 * 2]
    return x.reshape(c, h // 2, 2, w // 2, 2).mean(axis=(2, 4), dtype=np.float32)


def _noise_params(profile, iso: float) -> tuple[np.ndarray | None, np.ndarray | None, float]:
    """(read variance (4,h,w) DN², gain (4,1,1) DN/e⁻, ISO scale) at ``iso``, or Nones without a dark model."""
    dark = profile.dark
    if dark is None:
        return None, None, 1.0
    scale = float(iso) / dark.iso
    k = system_gain_dn_per_e(dark, getattr(profile, "emva", None))
    rn = dark.read_noise_dn.astype(np.float32) * np.float32(scale)
    return rn * rn, k * np.float32(scale), scale


#: Half-resolution rows per work unit of the RAW path: a band's temporaries stay in the CPU cache.
BAND_ROWS = 16


def _raw_check(frame: Frame, plan: ApplyPlan) -> None:
    """Refuse a photo whose layout or planes do not match the profile's (another camera, mode, crop or resolution)."""
    layout = getattr(plan.profile.camera, "layout", "bayer")
    if frame.layout != layout:
        raise CamcalError(f"is a {frame.layout} RAW file but the profile was measured on {layout} RAW frames; a "
                          "profile applies only to photos of its layout", frame.path)
    if frame.layout in ("linear", "mono"):
        shape = (3 if frame.layout == "linear" else 1, *frame.shape)
    else:
        shape = (4, frame.shape[0] // 2, frame.shape[1] // 2)
        if frame.shape[0] % 2 or frame.shape[1] % 2:
            raise CamcalError(f"a CFA mosaic must have even sides, got {frame.shape}", frame.path)
    dark = plan.profile.dark
    if dark is not None and shape != dark.bias_dn.shape:
        raise CamcalError(f"photo planes {shape[1:]} do not match the profile's dark model "
                          f"{dark.bias_dn.shape[1:]} (another camera, crop or resolution)", frame.path)
    if plan.flat_planes is not None and plan.flat_planes.shape != shape:
        raise CamcalError(f"photo planes {shape[1:]} do not match the profile's flat field "
                          f"{plan.flat_planes.shape[1:]} (another camera, crop or resolution)", frame.path)


def _raw_pixels(frame: Frame, plan: ApplyPlan, t: float, iso: float, inv_x: float, notes: list[str],
                threads: int) -> np.ndarray:
    """RAW mosaic -> interleaved (h, w, 8) float32 (:data:`OUTPUT_CHANNELS`): R, G, B band radiance, L(λ0), its
    uncertainty, and the 1-σ noise of R, G, B.

    The per-photo hot path of a batch. Each band of :data:`BAND_ROWS` half-resolution rows runs the
    whole chain (module docstring) on float32 buffers that stay in the cache, and writes its rows of
    the output; the bands run on ``threads`` threads.
    """
    _raw_check(frame, plan)
    model = plan.model
    cal = plan.calibration
    mosaic = frame.data
    linear = frame.layout == "linear"
    h, w = frame.shape if linear else (frame.shape[0] // 2, frame.shape[1] // 2)
    nplanes = 3 if linear else 4
    off = None if linear else plane_offsets(frame.cfa_pattern)
    white = float(frame.white_level_dn)
    black = frame.black_vector().ravel()
    if cal.dark is None:
        notes.append("no dark model: the file's black level was subtracted, dark current ignored; no noise map")
    elif not cal.dark_current_known:
        notes.append("the profile's dark current is unknown (bias-only calibration): the bias was subtracted, "
                     "dark current was not")
    band_k = [np.float32(inv_x / model.band_integral[i]) for i in range(3)]
    if not any(model.weights[i] != 0 for i in range(3)):
        raise CamcalError("the radiance estimator has no non-zero weight; the profile's c(λ) is unusable", frame.path)
    nan = np.float32(np.nan)
    out = np.empty((h, w, len(OUTPUT_CHANNELS)), np.float32)

    def work(r0: int, r1: int) -> None:
        n = r1 - r0
        planes = np.empty((nplanes, n, w), np.float32)
        if linear:
            for k in range(3):
                planes[k] = mosaic[r0:r1, :, k]
        else:
            for k, name in enumerate(PLANES):
                r, c = off[name]
                planes[k] = mosaic[2 * r0 + r: 2 * r1: 2, c::2]
        corr = correct_planes(planes, cal, exposure_s=t, iso=iso, white_level_dn=white, black_level_dn=black,
                              full_shape=(nplanes, h, w), window=(slice(r0, r1), slice(None)), variance=True,
                              channels=frame.channel_names, path=frame.path, inplace=True)
        planes, invalid, var = corr.signal_dn, corr.invalid, corr.variance_dn2
        np.copyto(planes, nan, where=invalid)
        if linear:  # R, G, B planes of their own: no greens to merge
            signal = (planes[0], planes[1], planes[2])
            if var is not None:
                var = [var[0], var[1], var[2]]
        else:
            # G: mean of the good greens (one defective green leaves the other)
            g = planes[1] + planes[2]
            g *= np.float32(0.5)
            np.copyto(g, planes[2], where=invalid[1])
            np.copyto(g, planes[1], where=invalid[2])
            signal = (planes[0], g, planes[3])
            if var is not None:
                vg = var[1] + var[2]
                vg *= np.float32(0.25)
                np.copyto(vg, var[2], where=invalid[1])
                np.copyto(vg, var[1], where=invalid[2])
                var = [var[0], vg, var[3]]
        if var is not None and plan.prnu_rel is not None:  # pixel response non-uniformity left uncorrected
            for i in range(3):
                var[i] += (plan.prnu_rel[i] * signal[i]) ** 2
        o = out[r0:r1]
        # L(λ0) and its 1-σ (noise ⊕ c(λ) ⊕ spectral reconstruction) by the one path, written into the output
        radiance_at(signal, var, model, inv_x, out=(o[..., 3], o[..., 4]))
        if var is None:  # no noise model: the common terms alone
            o[..., 5:] = nan
        for i in range(3):
            np.multiply(signal[i], band_k[i], out=o[..., i])
            if var is not None:
                np.sqrt(var[i], out=var[i])  # σ in place: var[i] is not used after this
                np.multiply(var[i], band_k[i], out=o[..., 5 + i])

    run_bands(work, h, BAND_ROWS, threads)
    return out


def _processed_signal(frame: Frame, plan: ApplyPlan, iso: float, notes: list[str]):
    """Processed RGB -> (RAW-equivalent signal (3,h,w) binned, variance or None, invalid (3,h,w))."""
    profile = plan.profile
    resp = profile.response or {}
    if "processed" not in resp or ("raw" not in resp and resp["processed"].colour_matrix is None):
        raise CamcalError("the profile has no response for processed photos (HEIC/JPEG): photograph a colour chart "
                          "with this camera in the same format and white balance and run camcal chart CHART.heic -o "
                          "phone.camcal, or calibrate a linearity series of RAW+JPEG pairs; or read the RAW file "
                          "(ProRAW/DNG) with a RAW profile", frame.path)
    rp, rr = resp["processed"], resp.get("raw")
    values = frame.planes(np.float32)
    # processed pixels per RAW plane pixel: 2 for a Bayer profile (half-resolution planes); for a linear-RAW
    # profile the ratio of the image to the planes (1 when the JPEG has the RAW's size)
    linear = getattr(profile.camera, "layout", "bayer") == "linear"
    plane_h = profile.camera.height if linear else profile.camera.height // 2
    f = 2 if not linear or not plane_h else max(1, values.shape[1] // plane_h)
    binf = _bin2 if f == 2 else (lambda a: np.asarray(a, np.float32))
    saturated = binf((values >= np.float32(frame.white_level_dn)).astype(np.float32)) > 0
    scale = rp.value_scale(frame.white_level_dn)
    if scale != 1.0:  # e.g. a 10-bit HEIC read against the response of the calibration's 8-bit JPEGs
        notes.append(f"processed file of white level {frame.white_level_dn:g} DN read against a response measured "
                     f"on files of white level {rp.white_level_dn:g} DN: values scaled by {scale:.6g}, assuming "
                     "the same tone curve at the other bit depth")
    lin = rp.linearise(values, white_level_dn=frame.white_level_dn).astype(np.float32)
    if rp.colour_matrix is not None:  # r = A⁻¹ j: the camera's channel mixing undone (camcal.calibrate.colour_matrix)
        signal = binf(rp.colour_matrix.to_raw(lin))
        to_signal = lambda g: binf(rp.colour_matrix.to_raw(g))  # noqa: E731
        notes.append("processed file: RAW-equivalent signal through the profile's colour matrix (fitted on the "
                     "sweep's JPEG twins); valid with the white balance and picture style of the calibration")
    else:
        k = []
        for ch in ("R", "G", "B"):
            raw_gain = (0.5 * (rr.linear_gain_dn_per_s("G1") + rr.linear_gain_dn_per_s("G2"))
                        if ch == "G" and "G1" in rr.channels else rr.linear_gain_dn_per_s(ch))
            k.append(raw_gain / rp.linear_gain_dn_per_s(ch))
        signal = binf(lin * np.array(k, np.float32)[:, None, None])
        to_signal = lambda g: binf(g * np.array(k, np.float32)[:, None, None])  # noqa: E731
        notes.append("processed file: no colour matrix in the profile, so one gain per channel: assumes the "
                     "camera does not mix its channels (true for the synthetic camera without a matrix, not for "
                     "real ones; calibrate with JPEG twins of the sweep)")
    var = None
    read_var, kg, scale = _noise_params(profile, iso)
    if read_var is not None:
        if read_var.shape[1:] != signal.shape[1:]:
            raise CamcalError(f"photo (half resolution {signal.shape[1:]}) does not match the profile's sensor "
                              f"{read_var.shape[1:]}", frame.path)
        if read_var.shape[0] == 3:  # linear RAW planes R, G, B
            var = read_var + kg * np.maximum(signal, 0)
        else:
            rv = np.stack([read_var[0], 0.25 * (read_var[1] + read_var[2]), read_var[3]])
            kk = rgb_from_planes(kg)
            var = rv + kk * np.maximum(signal, 0) * np.array([1.0, 0.5, 1.0], np.float32)[:, None, None]
    raw_signal = signal.copy()

    def systematic(inv_flat: np.ndarray | None) -> SystematicVariance | None:
        """The tone curve's and the colour matrix's variance (:mod:`camcal.apply.processed_unc`)."""
        return systematic_variance(values, rp, frame.white_level_dn, to_signal, raw_signal, inv_flat,
                                   plan.model.weights)

    return signal, var, saturated, systematic


def apply_prepared(frame: Frame, plan: ApplyPlan, *, allow_other_camera: bool = False,
                   threads: int | None = None, strict: bool = False) -> RadianceImage:
    """:func:`apply` with a precomputed :class:`ApplyPlan` (see :func:`prepare`).

    ``strict``: refuse a photo whose f-number or focal length the flats were not measured at
    (:func:`plan_for_optics`).

    ``threads``: threads of the RAW arithmetic (default :func:`default_threads`; a batch worker of a
    pool gets its share of the cores). The channels are views of one interleaved (h, w, 5) float32
    array, which :func:`camcal.io.exr.write_exr` writes without a copy.
    """
    profile = plan.profile
    path = frame.path
    notes = check_camera(frame.exposure, profile, path, allow_other_camera, frame)
    x = frame_relative_exposure(frame.exposure, profile.reference_iso, profile.reference_f_number, path)
    t = frame.exposure.require("exposure_s", path)
    iso = frame.exposure.require("iso", path)
    plan, choice = plan_for_optics(plan, frame.exposure, path, notes, strict)
    inv_x = 1.0 / x
    if frame.layout == "mono" or getattr(profile.spectral, "mono", False):
        return _mono_image(frame, plan, t, iso, inv_x, notes, choice)
    if frame.kind == "raw":
        pixels = _raw_pixels(frame, plan, t, iso, inv_x, notes, default_threads() if threads is None else threads)
    else:
        signal, var, saturated, systematic = _processed_signal(frame, plan, iso, notes)
        if plan.flat_rgb is not None:
            if plan.flat_rgb.shape != signal.shape:
                raise CamcalError(f"photo (half resolution {signal.shape[1:]}) does not match the profile's flat "
                                  f"field {plan.flat_rgb.shape[1:]} (another camera, crop or resolution)", path)
            # linearised, binned RGB: no dark, nothing clipped beyond ``saturated``; the flat division only
            signal = correct_planes(signal, plan.rgb_calibration, exposure_s=t, iso=iso, white_level_dn=np.inf,
                                    black_level_dn=np.zeros(3), channels=("R", "G", "B"), path=path,
                                    inplace=True).signal_dn
            if var is not None:
                var *= plan.rgb_calibration.inv_flat_gain ** 2
        signal[saturated] = np.nan
        if var is not None and plan.prnu_rel is not None:
            var += (plan.prnu_rel * signal) ** 2  # pixel response non-uniformity left uncorrected
        pixels = np.empty((*signal.shape[1:], len(OUTPUT_CHANNELS)), np.float32)
        for i in range(3):
            k = np.float32(inv_x / plan.model.band_integral[i])
            np.multiply(signal[i], k, out=pixels[..., i])
            pixels[..., 5 + i] = np.nan if var is None else np.sqrt(np.maximum(var[i], 0)) * k
        radiance_at(signal, var, plan.model, inv_x, out=(pixels[..., 3], pixels[..., 4]))
        sysvar = systematic(None if plan.flat_rgb is None else plan.rgb_calibration.inv_flat_gain)
        if sysvar is not None:
            _add_systematic_sigma(pixels, sysvar, plan, inv_x, saturated)
            notes.append("processed file: R_unc, G_unc, B_unc and the L uncertainty include the profile's "
                         + " and ".join({"tone": "tone-curve", "colour_matrix": "colour-matrix"}[t]
                                        for t in sysvar.terms)
                         + " uncertainty at each pixel's value (first order; camcal.apply.processed_unc)"
                         + ("" if var is not None else "; no noise model (the profile has no dark model), so "
                            "they hold these terms alone"))
    unflat = None
    if plan.flat_planes is None and plan.flat_rgb is None:
        notes.append("no flat model: vignetting not corrected")
        vig = (getattr(profile.spectral, "source", None) or {}).get("vignetting")
        if isinstance(vig, dict) and not vig.get("corrected", True):
            field = unflat_corner_field(frame.exposure, vig, path)
            _add_unflat_sigma(pixels, field["corner_field_deg"])
            notes.append("the profile's vignetting was not measured: R_unc, G_unc, B_unc and the L uncertainty "
                         f"include the cos⁴ fall-off of a corner at {field['corner_field_deg']:.3g}° "
                         f"({field['source']}) as a bias of 0 to that loss (0 at the centre; shoot flats for "
                         "camcal chart --flat to correct it)")
            unflat = field
    name = radiance_channel_name(plan.model.wavelength_nm, plan.model.in_band)
    names = [{"L": name, "L_unc": f"{name}_unc"}.get(c, c) for c in OUTPUT_CHANNELS]
    channels = {c: pixels[..., i] for i, c in enumerate(names)}
    e = frame.exposure
    relative = plan.relative
    if relative:
        notes.append("relative radiance: the profile's c(λ) has no absolute scale; only ratios of two such maps "
                     f"(camcal water invert) are physical; for absolute radiance: {next_step_for_c(profile)}")
    band_units = RELATIVE_UNITS if relative else BAND_UNITS
    l_units = RELATIVE_UNITS if relative else plan.model.units
    meta = {
        "units": {"R": band_units, "G": band_units, "B": band_units, name: l_units, f"{name}_unc": l_units,
                  "R_unc": band_units, "G_unc": band_units, "B_unc": band_units},
        "radiance_scale": "relative" if relative else "absolute",
        "uncertainty": {
            "R_unc, G_unc, B_unc": "1-σ noise of the band radiance (photon, read and dark noise, PRNU left "
                                   "uncorrected); the c(λ) scale uncertainty, common to every photo, is "
                                   "band_scale_unc_rel",
            f"{name}_unc": "1-σ: noise ⊕ c(λ) uncertainty ⊕ spectral reconstruction (spectral_unc_rel)",
        },
        "band_scale_unc_rel": [float(u / b) for u, b in zip(plan.model.band_unc, plan.model.band_integral,
                                                             strict=True)],
        "spectral_unc_rel": plan.model.spectral_unc_rel,
        "spectral_assumption": SPECTRAL_ASSUMPTIONS.get(plan.model.estimator, SPECTRAL_ASSUMPTIONS["trained"]),
        "estimator_summary": plan.model.describe(),
        "estimator_candidates": [list(c) for c in plan.model.candidates],
        "wavelength_nm": plan.model.wavelength_nm,
        "estimator": plan.model.estimator,
        "estimator_channel": plan.model.channel,
        "estimator_weights": [float(w) for w in plan.model.weights],
        "options": plan.options,
        "profile_sha256": profile.content_sha256,
        "source_file": str(path) if path is not None else None,
        "source_name": path.name if path is not None else None,
        "kind": frame.kind,
        "exposure": {"exposure_s": e.exposure_s, "iso": e.iso, "f_number": e.f_number,
                     "focal_length_mm": e.focal_length_mm,
                     "capture_time": e.capture_time, "utc_offset": e.utc_offset, "gps_time_utc": e.gps_time_utc,
                     "relative_exposure_s": x,
                     "reference_iso": profile.reference_iso, "reference_f_number": profile.reference_f_number},
        "camera": {"make": e.make, "model": e.model, "serial": e.serial},
        "place": {"latitude_deg": e.latitude_deg, "longitude_deg": e.longitude_deg, "altitude_m": e.altitude_m},
        "profile_camera": {"make": profile.camera.make, "model": profile.camera.model,
                           "serial": profile.camera.serial},
        "resolution": LINEAR_RESOLUTION_NOTE if frame.layout == "linear" else RESOLUTION_NOTE,
        "invalid": "NaN: defective (dark model) or saturated pixels",
        "optics": None if choice is None else choice.record(profile.flat),
        "uncorrected_vignetting": unflat,
        "notes": notes,
    }
    return RadianceImage(channels, meta)


def unflat_corner_field(exposure, vignetting: dict, path: Path | None) -> dict:
    """The corner field angle of the uncorrected fall-off of a photo (:mod:`camcal.models.falloff`): the photo's own
    EXIF FocalLengthIn35mmFilm; else the profile's (from its chart photos' EXIF); else the stated assumption."""
    own = corner_field(exposure, path.name if path is not None else None)
    if own["focal_length_35mm_mm"] is not None:
        return own
    deg = float(vignetting.get("corner_field_deg", own["corner_field_deg"]))
    if vignetting.get("focal_length_35mm_mm") is not None or abs(deg - own["corner_field_deg"]) > 1e-9:
        src = vignetting.get("corner_field_source") or "its corner_field_deg"
        return {"corner_field_deg": deg, "focal_length_35mm_mm": vignetting.get("focal_length_35mm_mm"),
                "source": f"the profile's, {src} (the photo holds no FocalLengthIn35mmFilm)"}
    return own


MONO_RESOLUTION_NOTE = "full resolution: the monochrome sensor's own pixels (no colour filter)"


def _mono_image(frame: Frame, plan: ApplyPlan, t: float, iso: float, inv_x: float, notes: list[str],
                choice: FlatChoice | None) -> RadianceImage:
    """A monochrome RAW frame -> ``Y`` (band radiance, :data:`BAND_UNITS`) and ``Y_unc``; with the narrowband
    estimator also ``L<λ0>`` and its σ (:func:`camcal.apply.radiance.mono_model`). Same chain as :func:`_raw_pixels`
    on the one plane: dark, flat, exposure, ``Y = rate / ∫c dλ``."""
    profile = plan.profile
    if frame.layout != "mono" or not getattr(profile.spectral, "mono", False):
        raise CamcalError(f"is a {frame.layout} {frame.kind} file but the profile's c(λ) is "
                          f"{'of a monochrome sensor (Y)' if getattr(profile.spectral, 'mono', False) else 'R, G, B'}"
                          "; a profile applies only to photos of its layout", frame.path)
    _raw_check(frame, plan)
    cal, model = plan.calibration, plan.model
    if cal.dark is None:
        notes.append("no dark model: the file's black level was subtracted, dark current ignored; no noise map")
    planes = np.asarray(frame.data, np.float32)[None].copy()
    corr = correct_planes(planes, cal, exposure_s=t, iso=iso, white_level_dn=float(frame.white_level_dn),
                          black_level_dn=frame.black_vector().ravel(), variance=True, channels=("Y",),
                          path=frame.path, inplace=True)
    signal, invalid, var = corr.signal_dn, corr.invalid, corr.variance_dn2
    signal[invalid] = np.nan
    if var is not None and plan.prnu_rel is not None:
        var = var + (plan.prnu_rel * signal) ** 2
    k = np.float32(inv_x / model.band_integral[0])
    y = (signal[0] * k).astype(np.float32)
    y_unc = np.full_like(y, np.nan) if var is None else (np.sqrt(np.maximum(var[0], 0)) * k).astype(np.float32)
    relative = plan.relative
    band_units = RELATIVE_UNITS if relative else BAND_UNITS
    channels = {"Y": y, "Y_unc": y_unc}
    units = {"Y": band_units, "Y_unc": band_units}
    if np.any(model.weights != 0):
        name = radiance_channel_name(model.wavelength_nm, model.in_band)
        lv, lu = radiance_at(signal, var, model, inv_x)
        channels |= {name: lv.astype(np.float32), f"{name}_unc": lu.astype(np.float32)}
        units |= {name: RELATIVE_UNITS if relative else model.units,
                  f"{name}_unc": RELATIVE_UNITS if relative else model.units}
    else:
        notes.append(f"monochrome sensor: one broad channel cannot reconstruct the spectral radiance at "
                     f"{model.wavelength_nm:g} nm, so only the band radiance Y is written (with a narrowband filter "
                     "in front of the lens: --estimator narrowband --filter-fwhm FWHM)")
    if plan.flat_planes is None:
        notes.append("no flat model: vignetting not corrected")
    e = frame.exposure
    meta = {
        "units": units,
        "radiance_scale": "relative" if relative else "absolute",
        "uncertainty": {"Y_unc": "1-σ noise of the band radiance (photon, read and dark noise, PRNU left "
                                 "uncorrected); the c(λ) scale uncertainty is band_scale_unc_rel"},
        "band_scale_unc_rel": [float(model.band_unc[0] / model.band_integral[0])],
        "band": "Y = rate / ∫c dλ: the c(λ)-weighted mean spectral radiance over the sensor's band",
        "wavelength_nm": model.wavelength_nm, "estimator": model.estimator, "estimator_channel": model.channel,
        "estimator_weights": [float(w) for w in model.weights], "options": plan.options,
        "profile_sha256": profile.content_sha256,
        "source_file": str(frame.path) if frame.path is not None else None,
        "source_name": frame.path.name if frame.path is not None else None, "kind": frame.kind,
        "exposure": {"exposure_s": e.exposure_s, "iso": e.iso, "f_number": e.f_number,
                     "focal_length_mm": e.focal_length_mm, "capture_time": e.capture_time,
                     "relative_exposure_s": 1.0 / inv_x, "reference_iso": profile.reference_iso,
                     "reference_f_number": profile.reference_f_number},
        "camera": {"make": e.make, "model": e.model, "serial": e.serial},
        "resolution": MONO_RESOLUTION_NOTE, "invalid": "NaN: defective (dark model) or saturated pixels",
        "optics": None if choice is None else choice.record(profile.flat), "notes": notes,
    }
    return RadianceImage(channels, meta)


def _add_systematic_sigma(pixels: np.ndarray, sysvar: SystematicVariance, plan: ApplyPlan, inv_x: float,
                          saturated: np.ndarray) -> None:
    """Add, in place, the tone curve's and colour matrix's σ (:mod:`camcal.apply.processed_unc`) to the uncertainty
    channels of ``pixels`` (h, w, 8): band i by its scale inv_x/∫c_i, L(λ0) by inv_x (the weights are in the
    weighted sum already). Channels without a noise figure (NaN) get these terms alone; saturated pixels stay NaN."""
    for i in range(3):
        term = np.sqrt(sysvar.band_dn2[i]) * np.float32(inv_x / plan.model.band_integral[i])
        old = pixels[..., 5 + i]
        pixels[..., 5 + i] = np.where(saturated[i], np.nan, np.hypot(np.nan_to_num(old), term))
    term = np.sqrt(sysvar.weighted_dn2) * np.float32(abs(inv_x))
    old = pixels[..., 4]
    pixels[..., 4] = np.where(np.isfinite(old), np.hypot(np.nan_to_num(old), term), old)


def _add_unflat_sigma(pixels: np.ndarray, corner_field_deg: float) -> None:
    """Add, in place, the uncorrected fall-off's σ to the uncertainty channels of ``pixels`` (h, w, 8).

    The cos⁴ fall-off of a lens whose image corner lies at ``corner_field_deg``, left uncorrected, as a uniform bias
    between 0 and the loss (:func:`camcal.models.falloff.uncorrected_sigma_rel`). Channels without a noise figure
    (NaN) get that term alone.
    """
    h, w = pixels.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    rel = uncorrected_sigma_rel(relative_radius(xx, yy, w, h).astype(np.float32), corner_field_deg).astype(np.float32)
    for value, unc in ((0, 5), (1, 6), (2, 7), (3, 4)):
        term = pixels[..., value] * rel
        old = pixels[..., unc]
        pixels[..., unc] = np.where(np.isfinite(old), np.hypot(np.nan_to_num(old), term), np.abs(term))


def apply(
    frame: Frame,
    profile,
    wavelength_nm: float = 663.0,
    estimator: str = "auto",
    *,
    filter_fwhm_nm: float | None = None,
    line_fwhm_nm: float | None = None,
    with_prnu: bool = False,
    allow_other_camera: bool = False,
    strict: bool = False,
) -> RadianceImage:
    """Radiance maps of one photo through a calibration profile (module docstring: the pipeline).

    Parameters
    ----------
    frame : a decoded photo (:func:`camcal.io.read.load_frame`), RAW or processed.
    profile : :class:`camcal.models.profile.CalibrationProfile` with an absolute spectral sensitivity.
    wavelength_nm : λ0 of the spectral-radiance map, nm (channel ``L<λ0>``).
    estimator : ``"auto"`` (the spectral estimator with the smallest reconstruction error for this c(λ)),
        ``"trained"``, ``"smooth"`` (smooth spectrum) or ``"narrowband"`` (light confined near λ0: an in-band
        radiance ``L<λ0>_inband`` unless ``filter_fwhm_nm``); see :mod:`camcal.apply.radiance`.
    filter_fwhm_nm : narrowband only: divide by this width to give W m⁻² sr⁻¹ nm⁻¹.
    line_fwhm_nm : narrowband only: FWHM of the light, for the slit correction of c(λ0).
    with_prnu : also divide by the profile's PRNU map.
    allow_other_camera : accept a photo whose make/model differs from the profile's.
    strict : refuse a photo whose f-number or focal length differs from the flats' (or cannot be checked).

    Returns
    -------
    RadianceImage with channels R, G, B (band radiance), L<λ0>, L<λ0>_unc at half resolution.

    Raises
    ------
    CamcalError
        Another camera, missing exposure metadata, size mismatch, a profile without c(λ) or
        (processed photos) without a JPEG response.
    """
    plan = prepare(profile, wavelength_nm, estimator, filter_fwhm_nm=filter_fwhm_nm, line_fwhm_nm=line_fwhm_nm,
                   with_prnu=with_prnu)
    return apply_prepared(frame, plan, allow_other_camera=allow_other_camera, strict=strict)


# ---- regions of interest ------------------------------------------------------------------------------------------
def roi_mask(shape_hw: tuple[int, int], roi: Region | None = None,
             mask: np.ndarray | None = None, where: str | Path | None = None, scale: int = 2) -> np.ndarray:
    """Boolean mask on the output grid (half resolution for Bayer photos: ``scale`` 2; linear RAW: 1).

    ``roi`` is a :class:`camcal.region.Region` in full-resolution photo pixels (rounded outward to whole
    output cells). ``mask`` is a 2-D array at the photo's full resolution (2x the output) or at the output
    resolution; non-zero marks the region; at full resolution a cell is in when at least half its pixels are.
    """
    h, w = shape_hw
    if mask is not None:
        m = np.asarray(mask, np.float32)
        if m.ndim == 3:
            m = m.max(axis=-1)
        if m.shape == (h, w):
            out = m > 0
        elif m.shape[0] // 2 == h and m.shape[1] // 2 == w:
            out = _bin2((m > 0).astype(np.float32)[None])[0] >= 0.5
        else:
            raise CamcalError(f"mask is {m.shape[1]}x{m.shape[0]}; expected the photo's size {2 * w}x{2 * h} "
                              f"or the output's {w}x{h}", where)
    elif roi is not None:
        out = np.zeros((h, w), bool)
        out[roi.window((h, w), scale, where)] = True
    else:
        raise CamcalError("give an ROI or a mask")
    if not out.any():
        raise CamcalError("the ROI/mask selects no pixels", where)
    return out


def read_mask(path: str | Path) -> np.ndarray:
    """A mask image (PNG/TIFF/JPEG, any channels) as a 2-D float array."""
    path = Path(path)
    if not path.is_file():
        raise CamcalError("no such mask file", path)
    with open_image(path, None, "a mask image") as (inp, spec):
        data = read_pixels(inp, spec, path, spec.nchannels, oiio.FLOAT)
    return np.asarray(data, np.float32).max(axis=-1)


def roi_statistics(channels: dict[str, np.ndarray], mask: np.ndarray) -> list[dict]:
    """Mean, median and standard deviation (ddof 1) per channel over the mask, NaN pixels excluded.

    Returns rows ``{"channel", "n", "mean", "median", "sigma"}``.
    """
    rows = []
    for name, arr in channels.items():
        v = np.asarray(arr, np.float64)[mask]
        v = v[np.isfinite(v)]
        n = int(v.size)
        rows.append({"channel": name, "n": n,
                     "mean": float(np.mean(v)) if n else float("nan"),
                     "median": float(np.median(v)) if n else float("nan"),
                     "sigma": float(np.std(v, ddof=1)) if n > 1 else float("nan")})
    return rows

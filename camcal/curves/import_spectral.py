"""Calibrating without a monochromator: relative c(λ) made absolute with photos of reference targets.

A camera's *relative* spectral sensitivity c_rel,i(λ) (measured elsewhere: SPECTACLE, an open data set,
a relative sweep) fixes the shape of each channel's curve; one photo of a target of known spectral
radiance L(λ) fixes its scale. With the seed's sensor model (seed §3.1, d = t ∫ c L dλ) and the
exposure normalisation of seed §2.1, the corrected DN rate of channel i on the target at the reference
setting (ISO_ref, N_ref), on axis, is

    rate_i = ∫ c_i(λ) L(λ) dλ = k_i ∫ c_rel,i(λ) L(λ) dλ = k_i P_i,

so k_i = rate_i / P_i, and c_i = k_i c_rel,i in DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm.

Targets: a lamp or sphere port read by a spectroradiometer (L(λ) given), or a diffuse reflectance
standard (grey card, Spectralon) of reflectance ρ(λ) under a measured irradiance E(λ), read as a
Lambertian surface: L = ρ E / π.

Uncertainty of one target j: u(rate) is the standard error of the region's mean (its spatial scatter
over √n: shot and read noise, and the PRNU, conservative); the target's stated uncertainty u_L(λ) is
taken as fully correlated over wavelength (a calibration scale error), u(P) = ∫ c_rel u_L dλ, combined
with a stated relative uncertainty of the whole spectrum if given. Then var_j = u(rate_j)² + (k P_j u_rel,j)².

Several targets: weighted least squares per channel, k = Σ w_j rate_j P_j / Σ w_j P_j², w_j = 1/var_j
(iterated, var depends on k), u(k) = (Σ w_j P_j²)^-½, and normalised residuals
z_j = (rate_j − k P_j)/√var_j. If the relative curves belong to this camera, every target gives the
same k up to noise: χ² = Σ z² over targets and planes follows χ² with 4(n − 1) degrees of freedom.
Curves of another camera leave target-dependent residuals (the ratio rate/P then depends on the
target's colour); a p-value below :data:`CONSISTENCY_P` is reported as "the curves do not belong to
this camera". The targets are treated as independent (one spectroradiometer's common scale error
would not average down: state it once with ``scale_unc_rel``).

Dark and flat correction of the photo follow ``camcal apply`` (dark model at the photo's exposure, else
the file's black level; division by the flat gain, 1 on the optical axis); that measurement is the one
function :func:`region_rate`.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats
from scipy.stats import median_abs_deviation

from camcal import __version__
from camcal.curves.files import FileFormat, as_absolute, read_numeric_table, read_spectral_file, resample
from camcal.curves.library import Match, find_camera, library_curves, with_layout
from camcal.errors import CamcalError
from camcal.frame import PLANES, Frame
from camcal.io.hashing import sha256_file
from camcal.io.manifest import exposure_overrides, read_manifest, safe_member
from camcal.io.read import load_frame, read_photo_metadata
from camcal.models.correct import Calibration, correct_frame
from camcal.models.dark import load_dark
from camcal.models.exposure import frame_relative_exposure
from camcal.models.flat import load_flat
from camcal.models.profile import SCHEMA_VERSION, CalibrationProfile, CameraIdentity, Provenance
from camcal.models.spectral import SpectralSensitivity, float_or_none
from camcal.region import DEFAULT_ROI_FRACTION, Region, central_roi

TARGETS_CSV = "targets.csv"
#: Below this χ² p-value the targets disagree beyond their noise: the curves do not fit this camera.
CONSISTENCY_P = 0.01
#: Largest fraction of a channel's ∫c_rel a target spectrum may leave uncovered.
MAX_UNCOVERED = 0.005


# ---- the one region measurement --------------------------------------------------------------------------
@dataclass(frozen=True)
class RegionRate:
    """Corrected DN rate of a photo's region per plane, at the reference setting.

    rate_dn_per_s : (C,) mean over the region, DN s⁻¹ at (ISO_ref, N_ref), on axis (flat applied).
    rate_unc_dn_per_s : (C,) standard error of that mean (spatial scatter / √n), DN s⁻¹.
    n_pixels : (C,) pixels used (saturated, defective and > 5 robust σ outliers left out).
    relative_exposure_s : x = (ISO·t/N²)/(ISO_ref/N_ref²), s.
    notes : what was (not) corrected.
    channels : the C planes: R, G1, G2, B (Bayer) or R, G, B (linear RAW).
    """

    rate_dn_per_s: np.ndarray
    rate_unc_dn_per_s: np.ndarray
    n_pixels: np.ndarray
    relative_exposure_s: float
    notes: tuple[str, ...] = ()
    channels: tuple[str, ...] = PLANES


def region_rate(frame: Frame, box: Region | tuple[int, int, int, int] | None, *, dark=None, flat=None,
                reference_iso: float, reference_f_number: float, min_pixels: int = 16) -> RegionRate:
    """Mean corrected DN rate per plane over ``box`` of a RAW photo (Bayer: R, G1, G2, B; linear RAW: R, G, B).

    As in ``camcal apply``, through the one correction path (:func:`camcal.models.correct.correct_frame`): planes −
    dark model at the photo's exposure and ISO (without a model the file's black level), divided by the flat
    gain, known defects and saturated pixels masked; then divided by the relative exposure x
    (:func:`camcal.models.exposure.frame_relative_exposure`, seed §2.1).

    Parameters
    ----------
    frame : a decoded RAW photo.
    box : a :class:`camcal.region.Region` in photo pixels (rounded outward to whole plane pixels), or
        (x0, y0, x1, y1), half-open, in half-resolution plane pixels; None: the central
        :data:`camcal.region.DEFAULT_ROI_FRACTION` of each side.
    dark, flat : camcal.models.dark.DarkModel, camcal.models.flat.FlatModel or None.
    """
    path = frame.path
    if frame.kind != "raw":
        raise CamcalError("is not a RAW file; a reference-target photo must be linear RAW data (shoot RAW: ProRAW/"
                          "DNG on a phone); for a HEIC/JPEG camera, photograph a colour chart in the sun and run "
                          "camcal chart CHART.heic -o phone.camcal", path)
    x = frame_relative_exposure(frame.exposure, reference_iso, reference_f_number, path)
    linear = frame.layout == "linear"
    shape_hw = tuple(frame.shape) if linear else (frame.shape[0] // 2, frame.shape[1] // 2)
    if isinstance(box, Region):
        ys, xs = box.window(shape_hw, 1 if linear else 2, path)
        box = (xs.start, ys.start, xs.stop, ys.stop)
    x0, y0, x1, y1 = central_roi(shape_hw, DEFAULT_ROI_FRACTION) if box is None else box
    if not (0 <= x0 < x1 <= shape_hw[1] and 0 <= y0 < y1 <= shape_hw[0]):
        raise CamcalError(f"region {box} (plane pixels) lies outside the {shape_hw[1]}x{shape_hw[0]} planes", path)
    notes = []
    if dark is None:
        notes.append("no dark model: the file's black level was subtracted, dark current ignored")
    if flat is None:
        notes.append("no flat model: the region's vignetting is not corrected (values refer to the region)")
    try:
        corr = correct_frame(frame, Calibration.of(dark, flat), window=(slice(y0, y1), slice(x0, x1)))
    except CamcalError as exc:
        raise CamcalError(exc.message, path) from None
    planes, bad = corr.signal_dn, corr.invalid
    y0, y1, x0, x1 = 0, planes.shape[1], 0, planes.shape[2]
    names = tuple(frame.channel_names)
    nc = planes.shape[0]
    rate = np.empty(nc)
    unc = np.empty(nc)
    npix = np.zeros(nc, int)
    for k in range(nc):
        v = planes[k, y0:y1, x0:x1][~bad[k, y0:y1, x0:x1]].astype(np.float64) / x
        if v.size:
            med = np.median(v)
            mad = median_abs_deviation(v, scale="normal")
            if mad > 0:
                v = v[np.abs(v - med) <= 5.0 * mad]
        if v.size < min_pixels:
            raise CamcalError(f"plane {names[k]}: only {v.size} usable pixels in the region (saturated or "
                              f"defective); need {min_pixels}", path)
        rate[k] = float(np.mean(v))
        unc[k] = float(np.std(v, ddof=1) / math.sqrt(v.size))
        npix[k] = v.size
    return RegionRate(rate, unc, npix, x, tuple(notes), names)


# ---- target spectra ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TargetSpectrum:
    """Known spectral radiance of a reference target.

    wavelength_nm : (m,) increasing, nm.
    radiance : (m,) W m⁻² sr⁻¹ nm⁻¹.
    radiance_unc : (m,) standard uncertainty, same unit, treated as fully correlated over λ (0: not stated).
    scale_unc_rel : a further relative standard uncertainty of the whole spectrum (0: none stated).
    description : how L was obtained (file names).
    files : ``{"file", "sha256", "bytes"}`` of the spectrum files.
    """

    name: str
    wavelength_nm: np.ndarray
    radiance: np.ndarray
    radiance_unc: np.ndarray
    scale_unc_rel: float = 0.0
    description: str = ""
    files: tuple[dict, ...] = ()


def _column_file(path: Path, what: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """wavelength_nm, value, standard uncertainty (zeros when absent) from a 2- or 3-column table."""
    _, data, _ = read_numeric_table(path)
    if data.shape[1] not in (2, 3):
        raise CamcalError(f"{what} file must have 2 or 3 columns (wavelength_nm, value[, uncertainty]), "
                          f"has {data.shape[1]}", path)
    order = np.argsort(data[:, 0])
    data = data[order]
    if np.any(np.diff(data[:, 0]) <= 0) or data.shape[0] < 2:
        raise CamcalError(f"{what} file needs at least 2 distinct, increasing wavelengths", path)
    if np.any(data[:, 1] < 0) or (data.shape[1] == 3 and np.any(data[:, 2] < 0)):
        raise CamcalError(f"{what} file holds a negative value", path)
    unc = data[:, 2] if data.shape[1] == 3 else np.zeros(data.shape[0])
    return data[:, 0], data[:, 1], unc


def _file_record(path: Path, stage: str, root: Path | None = None) -> dict:
    name = path.name if root is None else path.resolve().relative_to(root.resolve()).as_posix()
    return {"stage": stage, "file": name, "sha256": sha256_file(path), "bytes": path.stat().st_size}


def radiance_target(name: str, path: str | Path, scale_unc_rel: float = 0.0) -> TargetSpectrum:
    """A target whose spectral radiance was measured: file ``wavelength_nm, L [W m⁻² sr⁻¹ nm⁻¹][, u(L)]``."""
    path = Path(path)
    wl, L, u = _column_file(path, "radiance")
    return TargetSpectrum(name, wl, L, u, float(scale_unc_rel), f"radiance from {path.name}",
                          (_file_record(path, "reference_targets"),))


def reflectance_target(name: str, reflectance_path: str | Path, irradiance_path: str | Path,
                       scale_unc_rel: float = 0.0) -> TargetSpectrum:
    """A Lambertian reflectance standard under a measured irradiance: L = ρ(λ) E(λ) / π.

    Files: ``wavelength_nm, ρ (0..1)[, u(ρ)]`` and ``wavelength_nm, E [W m⁻² nm⁻¹][, u(E)]``; E is
    interpolated onto ρ's wavelengths (inside E's range). u(L)/L = √((u_ρ/ρ)² + (u_E/E)²).
    """
    rp, ip = Path(reflectance_path), Path(irradiance_path)
    wl, rho, u_rho = _column_file(rp, "reflectance")
    if np.any(rho > 1.5):
        raise CamcalError("reflectance above 1.5: give reflectance as a fraction (0..1), not percent", rp)
    wl_e, e, u_e = _column_file(ip, "irradiance")
    keep = (wl >= wl_e[0]) & (wl <= wl_e[-1])
    if keep.sum() < 2:
        raise CamcalError(f"the irradiance ({wl_e[0]:g}–{wl_e[-1]:g} nm) does not cover the reflectance's "
                          f"wavelengths", ip)
    wl, rho, u_rho = wl[keep], rho[keep], u_rho[keep]
    ee, uee = np.interp(wl, wl_e, e), np.interp(wl, wl_e, u_e)
    L = rho * ee / math.pi
    rel = np.hypot(np.divide(u_rho, rho, out=np.zeros_like(rho), where=rho > 0),
                   np.divide(uee, ee, out=np.zeros_like(ee), where=ee > 0))
    return TargetSpectrum(name, wl, L, L * rel, float(scale_unc_rel),
                          f"reflectance {rp.name} under irradiance {ip.name} (Lambertian, L = ρE/π)",
                          (_file_record(rp, "reference_targets"), _file_record(ip, "reference_targets")))


def predicted_rate(curves: SpectralSensitivity, target: TargetSpectrum) -> tuple[np.ndarray, np.ndarray]:
    """P_i = ∫ c_rel,i(λ) L(λ) dλ per plane (``curves.plane_names``) and its standard uncertainty (trapezoid
    on the curves' grid) from the target's spectrum.

    L is interpolated linearly onto the curves' wavelengths. Raises when the target's spectrum leaves
    more than :data:`MAX_UNCOVERED` of a channel's ∫c uncovered.
    """
    wl = curves.wavelength_nm
    inside = (wl >= target.wavelength_nm[0]) & (wl <= target.wavelength_nm[-1])
    L = np.where(inside, np.interp(wl, target.wavelength_nm, target.radiance), 0.0)
    uL = np.where(inside, np.interp(wl, target.wavelength_nm, target.radiance_unc), 0.0)
    names = curves.plane_names
    p = np.empty(len(names))
    u = np.empty(len(names))
    for k, plane in enumerate(names):
        c = np.clip(curves.values[plane], 0.0, None)
        total = np.trapezoid(c, wl)
        if total <= 0:
            raise CamcalError(f"the relative curve of plane {plane} has no positive value")
        covered = np.trapezoid(c * inside, wl)
        if 1.0 - covered / total > MAX_UNCOVERED:
            raise CamcalError(
                f"target {target.name!r}: its spectrum ({target.wavelength_nm[0]:g}–{target.wavelength_nm[-1]:g} nm) "
                f"leaves {100 * (1 - covered / total):.2g} % of plane {plane}'s sensitivity uncovered "
                f"(curves {wl[0]:g}–{wl[-1]:g} nm)")
        p[k] = np.trapezoid(c * L, wl)
        u[k] = math.hypot(np.trapezoid(c * uL, wl), p[k] * target.scale_unc_rel)
        if p[k] <= 0:
            raise CamcalError(f"target {target.name!r} gives no signal in plane {plane} (∫ c L dλ = 0)")
    return p, u


#: Correlation of a curve's uncertainty over wavelength: (weight, Gaussian length in nm) of two components,
#: ρ(Δλ) = Σ w exp(−Δλ²/(2ℓ²)). Fitted to the differences between independent measurements of one camera model
#: (the pairs of camcal.curves.borrowed, in units of f: autocorrelation 0.62 at 10–20 nm, 0.43 at 40 nm,
#: 0.28 at 60 nm, 0.12 at 80 nm, 0.03 at 100 nm; docs/spectral.md).
CURVE_CORRELATION = ((0.38, 5.0), (0.62, 50.0))


def curve_covariance(curves: SpectralSensitivity, targets: Sequence[TargetSpectrum],
                     correlation: tuple[tuple[float, float], ...] = CURVE_CORRELATION) -> np.ndarray:
    """Covariance of P_j = ∫ c_rel L_j dλ between targets caused by the curves' own u(c), (C, n, n).

    u(c)(λ) is taken as correlated over wavelength with ρ(Δλ) = Σ w exp(−Δλ²/(2ℓ²)) (:data:`CURVE_CORRELATION`):
    Cov(P_j, P_l) = Σ_λ Σ_λ' w_λ L_j(λ) u(λ) ρ(λ − λ') u(λ') L_l(λ') w_λ' (trapezoid weights w). The part of it
    common to all targets is absorbed by k; the colour-dependent rest goes into the χ².
    """
    wl = curves.wavelength_nm
    n = len(targets)
    names = curves.plane_names
    out = np.zeros((len(names), n, n))
    if wl.size < 2 or not any(np.any(curves.uncertainty[q] > 0) for q in names):
        return out
    w = np.zeros_like(wl)
    dw = np.diff(wl)
    w[:-1] += dw / 2
    w[1:] += dw / 2
    L = np.array([np.where((wl >= t.wavelength_nm[0]) & (wl <= t.wavelength_nm[-1]),
                           np.interp(wl, t.wavelength_nm, t.radiance), 0.0) for t in targets])  # (n, m)
    dl = wl[:, None] - wl[None, :]
    rho = sum(wt * np.exp(-0.5 * (dl / ell) ** 2) for wt, ell in correlation)
    for i, q in enumerate(names):
        a = L * (w * curves.uncertainty[q])[None, :]  # (n, m)
        out[i] = a @ rho @ a.T
    return out


# ---- observations and the fit --------------------------------------------------------------------------------
@dataclass(frozen=True)
class TargetObservation:
    """One target: its spectrum and the photos of it (with the region measured on each)."""

    target: TargetSpectrum
    photos: tuple[Path, ...]
    rates: tuple[RegionRate, ...]

    def rate(self) -> tuple[np.ndarray, np.ndarray]:
        """Inverse-variance mean over the photos, (4,) DN s⁻¹, and its standard error."""
        r = np.array([x.rate_dn_per_s for x in self.rates])
        u = np.array([x.rate_unc_dn_per_s for x in self.rates])
        w = 1.0 / np.maximum(u, 1e-300) ** 2
        return (w * r).sum(0) / w.sum(0), 1.0 / np.sqrt(w.sum(0))


@dataclass(frozen=True)
class AbsoluteScale:
    """Per-plane scale factors k (c = k · c_rel) and how well the targets agree.

    k, k_unc : dict plane -> DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm per unit of c_rel.
    targets : per target: name, photos, rate, predicted P, residual (rate/(kP) − 1) and z per plane.
    chi2, dof, p_value : χ² of the normalised residuals over targets and planes (None with one target).
    consistent : None with one target (nothing to compare), else p_value ≥ :data:`CONSISTENCY_P`.
    verdict : one sentence for people.
    """

    k: dict[str, float]
    k_unc: dict[str, float]
    targets: tuple[dict, ...]
    chi2: float | None
    dof: int
    p_value: float | None
    consistent: bool | None
    verdict: str
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict[str, Any]:
        return {"method": "reference_targets", "k": self.k, "k_unc": self.k_unc, "targets": list(self.targets),
                "chi2": self.chi2, "dof": self.dof, "p_value": self.p_value, "consistent": self.consistent,
                "verdict": self.verdict, "notes": list(self.notes)}


def fit_scale(curves: SpectralSensitivity, observations: Sequence[TargetObservation]) -> AbsoluteScale:
    """k per plane from one or more targets (module docstring: estimator, uncertainty, residuals)."""
    if not observations:
        raise CamcalError("no reference-target photos")
    names = curves.plane_names
    for ob in observations:
        for rr in ob.rates:
            if tuple(rr.channels) != tuple(names):
                raise CamcalError(f"the curves have planes {', '.join(names)}, the photos of target "
                                  f"{ob.target.name!r} {', '.join(rr.channels)}")
    n = len(observations)
    rates, urates, preds, upreds = [], [], [], []
    for ob in observations:
        r, ur = ob.rate()
        p, up = predicted_rate(curves, ob.target)
        rates.append(r), urates.append(ur), preds.append(p), upreds.append(up)
    r, ur, p, up = (np.array(a) for a in (rates, urates, preds, upreds))  # (n, C)
    rel_p = up / p
    k = (r * p).sum(0) / (p * p).sum(0)
    for _ in range(6):
        var = ur**2 + (k * p * rel_p) ** 2
        w = 1.0 / np.maximum(var, 1e-300)
        k = (w * r * p).sum(0) / (w * p * p).sum(0)
    var = ur**2 + (k * p * rel_p) ** 2
    w = 1.0 / np.maximum(var, 1e-300)
    u_k = 1.0 / np.sqrt((w * p * p).sum(0))
    cov_c = curve_covariance(curves, [ob.target for ob in observations])  # (C, n, n), the curves' own u(c)
    var_tot = var + (k**2) * np.einsum("ijj->ji", cov_c)
    z = (r - k * p) / np.sqrt(var_tot)
    resid = r / (k * p) - 1.0
    rows = []
    for j, ob in enumerate(observations):
        rows.append({"name": ob.target.name, "description": ob.target.description,
                     "photos": [q.name for q in ob.photos],
                     "rate_dn_per_s": dict(zip(names, r[j].tolist(), strict=True)),
                     "rate_unc_dn_per_s": dict(zip(names, ur[j].tolist(), strict=True)),
                     "predicted": dict(zip(names, p[j].tolist(), strict=True)),
                     "predicted_unc_rel": dict(zip(names, rel_p[j].tolist(), strict=True)),
                     "residual_rel": dict(zip(names, resid[j].tolist(), strict=True)),
                     "z": dict(zip(names, z[j].tolist(), strict=True))})
    kd = dict(zip(names, k.tolist(), strict=True))
    ud = dict(zip(names, u_k.tolist(), strict=True))
    if n == 1:
        rel = max(u_k / k)
        return AbsoluteScale(kd, ud, tuple(rows), None, 0, None, None,
                             f"one target: k set to ±{100 * rel:.2g} % (largest plane); a second target of another "
                             "colour would test whether the relative curves belong to this camera")
    chi2 = 0.0
    for i in range(len(names)):  # χ² with the full covariance: photo noise + the curves' u(c), correlated over λ
        res = r[:, i] - k[i] * p[:, i]
        chi2 += float(res @ np.linalg.solve(np.diag(var[:, i]) + k[i] ** 2 * cov_c[i], res))
    dof = len(names) * (n - 1)
    pv = float(stats.chi2.sf(chi2, dof))
    worst = float(np.max(np.abs(resid)))
    basis = "their noise and the curves' u(c)" if np.any(cov_c) else "their noise"
    if pv >= CONSISTENCY_P:
        verdict = (f"{n} targets agree within {basis} (χ²/dof = {chi2 / dof:.3g}, p = {pv:.2g}; largest "
                   f"residual {100 * worst:.2g} %): the relative curves fit this camera")
    else:
        verdict = (f"{n} targets disagree beyond {basis} (χ²/dof = {chi2 / dof:.3g}, p = {pv:.2g}; largest "
                   f"residual {100 * worst:.2g} %): the relative curves do not belong to this camera, or a "
                   "target's spectrum or the photos are wrong")
    return AbsoluteScale(kd, ud, tuple(rows), chi2, dof, pv, pv >= CONSISTENCY_P, verdict)


def scale_curves(curves: SpectralSensitivity, scale: AbsoluteScale, reference_iso: float,
                 reference_f_number: float) -> SpectralSensitivity:
    """Absolute c_i = k_i c_rel,i with u(c)² = (k u_rel)² + (c_rel u_k)² (u_k correlated over λ)."""
    names = curves.plane_names
    values = {p: scale.k[p] * curves.values[p] for p in names}
    unc = {p: np.hypot(scale.k[p] * curves.uncertainty[p], scale.k_unc[p] * curves.values[p]) for p in names}
    out = dataclasses.replace(curves, values=values, uncertainty=unc,
                              notes=(*curves.notes, *scale.notes, scale.verdict))
    return as_absolute(out, reference_iso, reference_f_number)


# ---- the targets manifest ------------------------------------------------------------------------------------
def _number(rec: dict, col: str, where: str, csv_path: Path, *, integer: bool = False) -> float | None:
    v = rec.get(col)
    if v is None:
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise CamcalError(f"{where}: column {col!r} has non-numeric value {v!r}", csv_path) from None
    if not math.isfinite(x) or x < 0 or (integer and x != int(x)):
        raise CamcalError(f"{where}: column {col!r} must be a non-negative {'integer' if integer else 'number'}, "
                          f"got {v!r}", csv_path)
    return x


def read_targets(targets_csv: str | Path) -> list[tuple[TargetSpectrum, list[tuple[Path, dict, tuple | None]]]]:
    """Read ``targets.csv``: one row per photo; rows naming the same target are photos of one target.

    Columns: ``file`` (photo, relative to the folder; required); ``radiance`` (spectrum file) **or**
    ``reflectance`` and ``irradiance`` (files); ``target`` (name; default the spectrum file's stem);
    ``scale_unc_rel`` (relative standard uncertainty of the spectrum, e.g. 0.02); ``roi_x, roi_y, roi_w,
    roi_h`` (full-resolution photo pixels; default the central 20 % of each side); ``exposure_s, iso,
    f_number`` override the photo's metadata. Every path must stay inside the folder.
    """
    csv_path = Path(targets_csv)
    if csv_path.is_dir():
        csv_path = csv_path / TARGETS_CSV
    rows = read_manifest(csv_path, required=("file",))
    if not rows:
        raise CamcalError("lists no photos", csv_path)
    folder = csv_path.parent
    groups: dict[str, tuple[TargetSpectrum, list]] = {}
    for i, (name, rec) in enumerate(rows.items(), start=1):
        where = f"{csv_path.name} row {i}"
        photo = safe_member(folder, name, csv_path)
        if not photo.is_file():
            raise CamcalError(f"{where}: lists {name!r}, which is not in the folder", csv_path)
        rad, refl, irr = rec.get("radiance"), rec.get("reflectance"), rec.get("irradiance")
        if rad and (refl or irr) or not rad and not (refl and irr):
            raise CamcalError(f"{where}: give either a radiance file or a reflectance and an irradiance file (no "
                              "measured irradiance? camcal chart models the clear-sky sunlight on a colour chart "
                              "from the photo's time and GPS)", csv_path)
        tname = str(rec.get("target") or Path(str(rad or refl)).stem)
        sunc = _number(rec, "scale_unc_rel", where, csv_path) or 0.0
        key = tname
        if key not in groups:
            if rad:
                spec = radiance_target(tname, safe_member(folder, str(rad), csv_path), sunc)
            else:
                spec = reflectance_target(tname, safe_member(folder, str(refl), csv_path),
                                          safe_member(folder, str(irr), csv_path), sunc)
            groups[key] = (spec, [])
        roi_vals = [_number(rec, c, where, csv_path, integer=True) for c in ("roi_x", "roi_y", "roi_w", "roi_h")]
        if any(v is not None for v in roi_vals) and not all(v is not None for v in roi_vals):
            raise CamcalError(f"{where}: give all of roi_x, roi_y, roi_w, roi_h or none", csv_path)
        try:
            roi = None if roi_vals[0] is None else Region(*(int(v) for v in roi_vals))  # type: ignore[misc]
        except CamcalError as exc:
            raise CamcalError(f"{where}: {exc.message}", csv_path) from None
        groups[key][1].append((photo, exposure_overrides(rec), roi))
    return list(groups.values())


def observe_targets(targets_csv: str | Path, *, dark=None, flat=None, reference_iso: float,
                    reference_f_number: float) -> list[TargetObservation]:
    """Decode every photo of ``targets.csv`` and measure its region with :func:`region_rate`."""
    out = []
    for spec, photos in read_targets(targets_csv):
        rates = []
        for path, overrides, roi in photos:
            frame = load_frame(path, overrides)
            rates.append(region_rate(frame, roi, dark=dark, flat=flat, reference_iso=reference_iso,
                                     reference_f_number=reference_f_number))
        out.append(TargetObservation(spec, tuple(p for p, _, _ in photos), tuple(rates)))
    return out


# ---- assembling a profile ------------------------------------------------------------------------------------
def _model(obj, loader):
    return loader(obj) if isinstance(obj, str | Path) else obj


def _first_photo(targets: str | Path) -> Frame:
    """The first photo of ``targets.csv`` (its camera's make, model and layout)."""
    groups = read_targets(targets)
    path, overrides, _ = groups[0][1][0]
    return load_frame(path, overrides)


def library_match(name: str, *, base: CalibrationProfile | None = None, targets: str | Path | None = None,
                  camera: CameraIdentity | None = None) -> Match:
    """The curve-library camera for ``name``: a model name, or ``"auto"``: the make and model of ``base``'s camera,
    else of the first target photo (its EXIF), else of ``camera``."""
    if name != "auto":
        return find_camera(name)
    for ident in (base.camera if base else None, camera):
        if ident is not None and ident.model:
            return find_camera(make=ident.make, model=ident.model)
    if targets is not None:
        e = _first_photo(targets).exposure
        if e.model:
            return find_camera(make=e.make, model=e.model)
    raise CamcalError("--camera auto: neither the profile nor the target photos name a camera model; give the model, "
                      "e.g. --camera \"Canon EOS 5D Mark III\"")


def _layout_of(base: CalibrationProfile | None, targets: str | Path | None, camera: CameraIdentity | None) -> str:
    if base is not None:
        return base.camera.layout
    if targets is not None:
        return "linear" if _first_photo(targets).layout == "linear" else "bayer"
    return camera.layout if camera is not None else "bayer"


def targets_setting(targets_csv: str | Path) -> tuple[float, float]:
    """The target photos' most common (ISO, f-number), from targets.csv and the photos' tags: never a default.

    Raises
    ------
    CamcalError
        No photo states both, naming the options that give them.
    """
    seen: Counter = Counter()
    for _, photos in read_targets(targets_csv):
        for path, overrides, _ in photos:
            e = read_photo_metadata(path)
            iso = overrides.get("iso") or e.iso
            n = overrides.get("f_number") or e.f_number
            if iso and n:
                seen[(float(iso), float(n))] += 1
    if not seen:
        raise CamcalError("the reference setting is unknown: the target photos state no ISO and f-number (no tag, "
                          "no iso and f_number columns in targets.csv); pass --reference-iso and "
                          "--reference-f-number", targets_csv)
    return seen.most_common(1)[0][0]


def import_spectral(
    curves_path: str | Path | None = None,
    *,
    fmt: FileFormat = "auto",
    base: CalibrationProfile | None = None,
    targets: str | Path | None = None,
    absolute: bool = False,
    reference_iso: float | None = None,
    reference_f_number: float | None = None,
    dark=None,
    flat=None,
    camera: CameraIdentity | None = None,
    library_camera: str | None = None,
) -> tuple[CalibrationProfile, AbsoluteScale | None]:
    """A profile whose spectral sensitivity comes from ``curves_path``, absolute through targets if given.

    Parameters
    ----------
    curves_path : SPECTACLE CSV or plain table (:func:`camcal.curves.files.read_spectral_file`); None with
        ``library_camera``.
    library_camera : a camera of the bundled curve library (:mod:`camcal.curves.library`), or ``"auto"`` (the make
        and model of ``base``, else of the target photos); its relative curves carry the borrowed-curve
        uncertainty (:mod:`camcal.curves.borrowed`) and the profile names the library entry as its source.
    base : an existing profile to put the curves into (dark, flat, response and camera kept; its spectral
        sensitivity replaced; the curves resampled to its wavelength grid when it has one).
    targets : ``targets.csv`` (or its folder) of reference-target photos: the curves are taken as relative
        and scaled by :func:`fit_scale`.
    absolute : without targets, the curves are already absolute at (reference_iso, reference_f_number)
        (a camcal export keeps its own setting in ``.meta.json``).
    reference_iso, reference_f_number : the reference setting; default the profile's (``base``), else the
        absolute curves' own, else unknown: relative curves need none, an absolute scale (targets,
        ``absolute``) then raises, naming the options.
    dark, flat : models (or files) for the target photos when ``base`` has none.
    camera : identity of a new profile; default from the first target photo.

    Returns
    -------
    (profile, scale or None). The profile is not saved.
    """
    library_record = None
    if library_camera is not None:
        if curves_path is not None:
            raise CamcalError("give a curve file or a library camera (--camera), not both")
        if absolute:
            raise CamcalError("the library's curves are relative: set their scale with reference targets")
        match = library_match(library_camera, base=base, targets=targets, camera=camera)
        curves, library_record, path = library_curves(match, _layout_of(base, targets, camera))
        used = "rawtoaces"
    elif curves_path is None:
        raise CamcalError("give a curve file or a library camera (--camera)")
    else:
        path = Path(curves_path)
        curves, used = read_spectral_file(path, fmt)
        curves = with_layout(curves, _layout_of(base, targets, camera))
    # the reference setting: given, the profile's, or the absolute curves' own; otherwise unknown (a relative
    # curve needs none), and asked for only where an absolute scale needs it
    ref_iso = reference_iso or (base.reference_iso if base else None) or (
        curves.reference_iso if curves.mode == "absolute" else None)
    ref_n = reference_f_number or (base.reference_f_number if base else None) or (
        curves.reference_f_number if curves.mode == "absolute" else None)
    if targets is not None and (ref_iso is None or ref_n is None):
        iso, n = targets_setting(targets)
        ref_iso, ref_n = ref_iso or iso, ref_n or n
    if absolute and (ref_iso is None or ref_n is None):
        raise CamcalError("--absolute curves are absolute at a reference setting, and none is known (no profile "
                          "or metadata gives it): pass --reference-iso and --reference-f-number")
    dark = _model(dark, load_dark) if dark is not None else (base.dark if base else None)
    flat = _model(flat, load_flat) if flat is not None else (base.flat if base else None)
    inputs = [_file_record(path, "spectral_import")]
    scale = None
    if targets is not None:
        obs = observe_targets(targets, dark=dark, flat=flat, reference_iso=ref_iso, reference_f_number=ref_n)
        scale = fit_scale(curves, obs)
        notes = sorted({n for ob in obs for r in ob.rates for n in r.notes})
        scale = dataclasses.replace(scale, notes=tuple(notes))
        curves = scale_curves(curves, scale, ref_iso, ref_n)
        tcsv = Path(targets) / TARGETS_CSV if Path(targets).is_dir() else Path(targets)
        root = tcsv.parent
        inputs.append(_file_record(tcsv, "reference_targets", root))
        for ob in obs:
            inputs.extend(dict(f) for f in ob.target.files)
            inputs.extend(_file_record(q, "reference_targets", root) for q in ob.photos)
        absolute_scale = scale.to_dict()
        if camera is None and base is None:
            first = load_frame(obs[0].photos[0])
            h, w = first.shape
            e = first.exposure
            camera = CameraIdentity(e.make, e.model, e.serial, first.cfa_pattern, w, h,
                                    "linear" if first.layout == "linear" else "bayer")
    elif absolute or curves.mode == "absolute":
        if curves.mode != "absolute":
            curves = as_absolute(curves, ref_iso, ref_n)
        elif (curves.reference_iso, curves.reference_f_number) != (ref_iso, ref_n):
            raise CamcalError(f"the curves are absolute at ISO {curves.reference_iso:g} f/{curves.reference_f_number:g}"
                              f", the profile's reference is ISO {ref_iso:g} f/{ref_n:g}", path)
        absolute_scale = {"method": "file", "description": f"absolute values as given in {path.name}"}
    else:
        absolute_scale = {"method": "none", "description": "relative curves: no absolute scale (apply needs one; "
                          "add reference-target photos)"}
    grid_notes: list[str] = []
    if base is not None and base.spectral is not None:
        curves, grid_notes = resample(curves, base.spectral.wavelength_nm)
    source = {"kind": "library" if library_record else "imported", "file": path.name, "sha256": inputs[0]["sha256"],
              "format": used, "absolute_scale": absolute_scale}
    if library_record:
        source["library"] = library_record
    if grid_notes:
        source["notes"] = grid_notes
    curves = dataclasses.replace(curves, source=source, reference_iso=float_or_none(ref_iso),
                                 reference_f_number=float_or_none(ref_n))
    options = {"spectral_import": {"file": path.name, "format": used, "camera": library_camera,
                                   "targets": None if targets is None
                                   else Path(targets).name, "absolute": bool(absolute),
                                   "reference_iso": ref_iso, "reference_f_number": ref_n}}
    created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    if base is not None:
        prov = Provenance(__version__, created, (*base.provenance.inputs, *inputs),
                          {**base.provenance.options, **options})
        if (base.reference_iso, base.reference_f_number) != (ref_iso, ref_n):
            raise CamcalError(f"the profile's reference setting is ISO {base.reference_iso:g} "
                              f"f/{base.reference_f_number:g}; import at that setting")
        profile = dataclasses.replace(base, spectral=curves, provenance=prov, content_sha256=None,
                                      schema_version=SCHEMA_VERSION)
    else:
        if camera is None:
            raise CamcalError("a new profile needs the camera's identity: give reference-target photos, an "
                              "existing profile, or the camera's make, model and size")
        profile = CalibrationProfile(camera=camera, reference_iso=float_or_none(ref_iso),
                                     reference_f_number=float_or_none(ref_n),
                                     dark=dark, flat=flat, spectral=curves,
                                     provenance=Provenance(__version__, created, tuple(inputs), options))
    return profile, scale

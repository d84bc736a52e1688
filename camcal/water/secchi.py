"""From photos of a Secchi disk to chlorophyll-a in one stage (``camcal secchi``).

1. **Apply** the calibration profile to every photo (:func:`camcal.apply.photo.apply_prepared`): band radiance R, G, B.
2. **Find the disk** in each (:func:`camcal.water.disk.find_disk`, or ``--roi``): the interior and, in the
   submerged photos, the surround water that measures the sky reflected by the surface.
3. **Glare and water-leaving radiance** (:mod:`camcal.water.surround`): the surface glare over the disk is
   modelled from the sky model and the view, G = R(θv) f L̄_ref/ρ_ref; the measured surround beyond it is the
   water's own light W, whose part over the disk F W (a homogeneous column) is subtracted with a 1-σ covering
   none to all of it. A surround the glare does not explain is a warning.
4. **Band-radiance ratio** r = (L̄_sub − G − F W)/L̄_ref of the band channel (R), with the photos' noise
   σ_ln r² = SE_sub²/(L̄_sub − G − F W)² + (SE_ref/L̄_ref)²; F depends on C (the band's absorption), so C and F
   are solved together by fixed-point iteration.
5. **Invert** with the field model (:class:`camcal.water.field.FieldBandModel`: sun and sky over a flat surface,
   SPECTRL2 or a measured sky, or ``overcast``) over the profile's c(λ).
6. σ_C: the ratio's noise, the glare, the water-leaving radiance over the disk, the surround's noise, the depth,
   the absorber's scale (ε), the sun's zenith angle, the diffuse fraction, the aerosol and the profile's c(λ)
   (:mod:`camcal.water.uncertainty`), root sum of squares, with the dominant term.

Several submerged photos (depths) give one C each and a combined C: the inverse-variance weighted mean, whose
σ keeps the independent terms (ratio, depth) independent and the shared ones (ε, sun, sky, c(λ)) fully
correlated (their weighted mean).
"""

from __future__ import annotations

import html
import json
import math
import warnings
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from camcal.apply.photo import RadianceImage, apply_prepared, prepare
from camcal.apply.provenance import check_made_by
from camcal.errors import CamcalError
from camcal.io.atomic import atomic_write_text
from camcal.io.exr import read_exr
from camcal.io.read import load_frame
from camcal.models.profile import load_profile
from camcal.region import Region
from camcal.report.plots import new_figure, write_png
from camcal.units import CONCENTRATION
from camcal.water.band import band_model_from_profile
from camcal.water.disk import DiskFit, disk_from_roi, find_disk, region_mean
from camcal.water.field import FieldBandModel, FieldGeometry
from camcal.water.invert import Reason
from camcal.water.surround import (
    REFERENCE_ALBEDO,
    REFERENCE_ALBEDO_SIGMA,
    SurroundBudget,
    column_fraction,
    glare_radiance,
    surround_budget,
)
from camcal.water.uncertainty import Uncertain, combine, solve_c, uncertainty_terms

#: Terms that differ from photo to photo (independent); the rest are shared by all photos of a survey.
INDEPENDENT_TERMS = ("ratio", "depth", "surround_noise")
#: Relative 1-σ of the uniform sky's radiance when the sky model states none (overcast).
DIFFUSE_SIGMA_DEFAULT = 0.2
#: The largest diffuse fraction a bright surround is taken to allow (all-diffuse is the overcast model).
MAX_DIFFUSE_FRACTION = 0.99
#: Fixed-point iterations of C and the column fraction F.
MAX_ITERATIONS = 30
#: Longest side of a photo on the page, pixels (block means of the radiance); the page's figure resolution.
PREVIEW_PX = 240
PREVIEW_DPI = 80


@dataclass
class Shot:
    """One photo's measurement (radiances in W m⁻² sr⁻¹ nm⁻¹, band channel)."""

    path: Path
    kind: str  # 'reference' or 'submerged'
    depth_m: float | None = None
    depth_sigma_m: float = 0.0
    fit: DiskFit | None = None
    channels: dict | None = None
    disk_radiance: float = float("nan")
    disk_se: float = float("nan")
    surround_radiance: float = 0.0
    surround_se: float = 0.0
    ratio: float = float("nan")
    sigma_ln_ratio: float = float("nan")
    c_ug_per_L: float = float("nan")
    sigma_ug_per_L: float = float("nan")
    terms: dict = field(default_factory=dict)
    reason: str = ""
    error: str | None = None
    notes: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    budget: SurroundBudget | None = None
    unit: str = ""
    scale: str = ""
    """'absolute' or 'relative' radiance (the profile's c(λ))."""
    image: str | None = None
    """The page's PNG of this photo (downsampled, written as the photo is done), or None without a page."""
    disk: dict | None = None
    """The located disk (:meth:`camcal.water.disk.DiskFit.describe`), kept when the full-size masks are dropped."""
    time_utc: str | None = None
    """Capture instant, ISO 8601: the GPS time, or the camera clock with its stated UTC offset; None if unknown."""
    latitude_deg: float | None = None
    longitude_deg: float | None = None


def photo_radiance(path: Path, plan, channel: str, profile_path, allow_other_camera: bool = False
                   ) -> tuple[dict, dict]:
    """(channels, metadata) of one photo: the profile applied to a photo, or an EXR of ``camcal apply`` read back
    (refused when another profile made it, :func:`camcal.apply.provenance.check_made_by`)."""
    if path.suffix.lower() == ".exr":
        chans, meta = read_exr(path, sorted({"G", channel}))
        check_made_by(meta, path, plan.profile, profile_path)
        return chans, meta
    img = apply_prepared(load_frame(path), plan, allow_other_camera=allow_other_camera)
    return img.channels, img.metadata


def capture_time_utc(exposure: dict) -> str | None:
    """The UTC instant of apply's ``exposure`` metadata: the GPS time, else the camera clock with its UTC offset;
    None when neither says (a time zone is never guessed)."""
    if exposure.get("gps_time_utc"):
        return str(exposure["gps_time_utc"])
    local, off = exposure.get("capture_time"), exposure.get("utc_offset")
    if local and off:
        try:
            return datetime.fromisoformat(f"{str(local)[:19]}{off}").astimezone(UTC).isoformat()
        except ValueError:
            return None
    return None


def block_mean(a: np.ndarray, factor: int) -> np.ndarray:
    """``a`` (2-D) averaged over ``factor`` × ``factor`` blocks (NaN ignored; an all-NaN block is NaN)."""
    if factor <= 1:
        return np.asarray(a, np.float32)
    h, w = (a.shape[0] // factor) * factor, (a.shape[1] // factor) * factor
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(np.asarray(a[:h, :w], np.float32).reshape(h // factor, factor, w // factor, factor),
                          axis=(1, 3))


def finish_photo(s: Shot, ref: Shot, model, channel: str, page_dir: Path | None, index: int) -> None:
    """The photo is done: draw its page image (downsampled to :data:`PREVIEW_PX`) when there is a page, then drop
    its full-size channels and masks, so a survey's memory does not grow with its photos."""
    if page_dir is not None and s.channels is not None and s.fit is not None:
        name = f"photo{index:03d}_{s.kind}.png"
        write_png(_shot_figure(s, ref, model, channel), page_dir / name, dpi=PREVIEW_DPI)
        s.image = name
    s.channels = None
    s.fit = None


def measure_photo(shot: Shot, plan, channel: str, roi: Region | None, surround: bool, profile_path=None,
                  allow_other_camera: bool = False) -> Shot:
    """Apply the profile (or read its EXR), find the disk and average the band channel over its interior (and
    surround)."""
    channels, metadata = photo_radiance(shot.path, plan, channel, profile_path, allow_other_camera)
    shot.scale = str(metadata.get("radiance_scale", ""))
    shot.time_utc = capture_time_utc(metadata.get("exposure") or {})
    place = metadata.get("place") or {}
    shot.latitude_deg, shot.longitude_deg = place.get("latitude_deg"), place.get("longitude_deg")
    img = RadianceImage(channels, metadata)
    scale = 2 if str(img.metadata.get("resolution", "")).startswith("half") else 1
    finder = img.channels["G"]
    if roi is not None:
        fit = disk_from_roi(finder, roi, scale=scale, where=shot.path)
    else:
        fit = find_disk(finder, scale=scale, where=shot.path)
    band = img.channels[channel]
    shot.fit, shot.channels = fit, {k: img.channels[k] for k in {"G", channel}}  # until the photo is done
    shot.disk = fit.describe()
    shot.notes += list(fit.notes) + list(img.metadata.get("notes", []))
    shot.disk_radiance, shot.disk_se, _ = region_mean(band, fit.interior)
    shot.unit = str(img.metadata.get("units", {}).get(channel, ""))
    if surround:
        if fit.surround.sum() < 20:
            raise CamcalError("too little water around the disk to measure the reflected sky (move the disk "
                              "away from the frame's edge or give --roi)", shot.path)
        shot.surround_radiance, shot.surround_se, _ = region_mean(band, fit.surround)
    return shot


def diffuse_fraction_in_band(model: FieldBandModel) -> float:
    """The band's diffuse fraction f = ∫ c E_g f dλ / ∫ c E_g dλ of the field model's light."""
    w, _, _, f = model._fparts
    return float(np.sum(w * f))


def band_absorption_per_m(model: FieldBandModel, c_ug_per_L: float) -> float:
    """The band-weighted absorption a = Σ w (a_w + a_bg + a_chl(C)), m⁻¹."""
    w, chl, bg, _ = model._fparts
    return float(np.sum(w * (bg + chl.absorption_per_m(c_ug_per_L))))


def sky_variants(model: FieldBandModel, f_max: float, nodes: int = 3) -> list[FieldBandModel]:
    """The model with its band's diffuse fraction from f (its own) to ``f_max`` (``nodes`` values, the ends
    included): a surround brighter than the modelled glare may be a sky brighter than the model's. The diffuse
    irradiance is scaled by k = f'(1 − f)/(f(1 − f')) so that the band's diffuse fraction becomes f'. Only the
    model itself when f_max ≤ f or the sky is already all diffuse."""
    f = diffuse_fraction_in_band(model)
    if not (0 < f < 1 and f_max > f + 1e-3) or model.sky.kind == "overcast":
        return [model]
    return [model, *(model.varied("diffuse_fraction", fp * (1 - f) / (f * (1 - fp)))
                     for fp in np.linspace(f, f_max, nodes)[1:])]


def unexplained_sigma(models: list[FieldBandModel], disk: float, reference: float, depth_m: float,
                      span: tuple[float, float], c_ug_per_L: float, nodes: int = 9) -> float:
    """The unexplained term: only bounds are known (the light X over the disk in ``span``, the sky among
    ``models``, :func:`sky_variants`), so a rectangular distribution (GUM 4.3.7) whose half-width is the largest
    deviation |C(X; sky) − C| over that range (``nodes`` values of X, ends included, each inverted exactly):
    σ = max |C(X; sky) − C|/√3. A value no C explains (X too large: a dark disk) counts as C = 2× the largest
    explained one, so σ stays finite and large."""
    xs = np.linspace(span[0], span[1], nodes)
    worst = 0.0
    for m in models:
        cs = np.array([invert_one(m, (disk - xx) / reference, depth_m)[0] for xx in xs])
        if not np.isfinite(cs).any():
            return float("inf")
        cs = np.where(np.isfinite(cs), cs, 2.0 * np.nanmax(cs))
        worst = max(worst, float(np.max(np.abs(cs - c_ug_per_L))))
    return worst / float(np.sqrt(3.0))


def solve_shot(s: Shot, ref: Shot, model: FieldBandModel, depth_m: float, depth_sigma_m: float, inputs: list,
               glare_rel_sigma: float, *, view_angle_rad: float = 0.0, n_water: float = 1.33) -> Shot:
    """C of one submerged photo with its glare and water-leaving budget (:mod:`camcal.water.surround`) and every
    σ_C term. C and the column fraction F(C) are solved together (fixed point from F = ½)."""
    glare = glare_radiance(ref.disk_radiance, diffuse_fraction_in_band(model), view_angle_rad=view_angle_rad,
                           n_water=n_water)
    col = 0.5
    c = float("nan")
    for _ in range(MAX_ITERATIONS):
        budget = surround_budget(s.disk_radiance, s.surround_radiance, s.surround_se, glare,
                                 glare_rel_sigma * glare, col, unit=s.unit)
        c_new, reason = invert_one(model, budget.signal / ref.disk_radiance, depth_m)
        if reason != "ok":
            c = c_new
            break
        new_col = column_fraction(band_absorption_per_m(model, c_new), depth_m, view_angle_rad=view_angle_rad,
                                  n_water=n_water)
        done = np.isfinite(c) and abs(c_new - c) <= 1e-6 * c_new and abs(new_col - col) < 1e-6
        c, col = c_new, new_col
        if done:
            break
    budget = surround_budget(s.disk_radiance, s.surround_radiance, s.surround_se, glare, glare_rel_sigma * glare,
                             col, unit=s.unit)
    s.budget = budget
    if budget.warning:
        s.warnings.append(budget.warning)
    sig = budget.signal
    s.ratio = sig / ref.disk_radiance
    s.sigma_ln_ratio = float(np.sqrt(s.disk_se ** 2 / sig ** 2 + (ref.disk_se / ref.disk_radiance) ** 2)) \
        if sig > 0 else float("nan")
    s.c_ug_per_L, s.reason = invert_one(model, s.ratio, depth_m)
    if s.reason != "ok":
        s.error = f"{s.path}: no concentration explains the ratio {s.ratio:.4g} ({s.reason})"
        return s
    b, db = model.ratio_and_derivative(np.array([s.c_ug_per_L]), depth_m)
    per_ln_ratio = float(b[0]) / abs(float(db[0]))  # σ_C per unit σ_ln r
    terms = {"ratio": np.array([s.sigma_ln_ratio * per_ln_ratio])}
    for k, v in budget.sigma_terms().items():
        if v > 0:
            terms[k] = np.array([v / sig * per_ln_ratio])
    span = budget.unexplained_interval()
    if span is not None:  # the surround model does not hold: X ~ U(0, S) over the disk, through the inversion
        terms.pop("glare", None)
        terms.pop("water_leaving", None)
        # ... and the sky may be brighter than the model's: up to the diffuse fraction whose glare is the surround
        f = diffuse_fraction_in_band(model)
        f_max = min(MAX_DIFFUSE_FRACTION, f * s.surround_radiance / glare) if glare > 0 else f
        variants = sky_variants(model, f_max)
        terms["unexplained_surround"] = np.array([unexplained_sigma(variants, s.disk_radiance, ref.disk_radiance,
                                                                    depth_m, span, s.c_ug_per_L)])
        if len(variants) > 1:
            s.warnings.append(f"the surround also allows a sky brighter than the model's: a diffuse fraction in the "
                              f"band up to {f_max:.0%} (the model's {f:.0%}), carried into σ_C")
    grid = s.c_ug_per_L * np.array([0.999, 1.0, 1.001])  # one C: a three-node log-uniform grid
    terms.update(uncertainty_terms(model, depth_m, np.array([s.c_ug_per_L]),
                                   [Uncertain("depth", depth_m, depth_sigma_m, "m"), *inputs], grid=grid))
    s.terms = {k: float(np.asarray(v).reshape(-1)[0]) for k, v in terms.items()}
    s.sigma_ug_per_L = float(combine({k: np.array(v) for k, v in s.terms.items()}))
    return s


@dataclass
class SecchiResult:
    reference: Shot
    submerged: list
    model: FieldBandModel
    c_ug_per_L: float
    sigma_ug_per_L: float
    terms: dict
    dominant: str | None
    meta: dict


def invert_one(model: FieldBandModel, ratio: float, depth_m: float) -> tuple[float, str]:
    """C (µg/L) of one band ratio at one depth by Brent's method on ln C (:func:`camcal.water.uncertainty.solve_c`),
    and the reason ('ok', or the :class:`camcal.water.invert.Reason` name when no C explains it)."""
    if not np.isfinite(ratio):
        return float("nan"), Reason.NOT_FINITE.name.lower()
    if ratio <= 0:
        return float("nan"), Reason.NOT_POSITIVE.name.lower()
    if ratio > float(model.ratio(0.0, depth_m)):
        return float("nan"), Reason.ABOVE_CLEAR_WATER.name.lower()
    c = solve_c(lambda cc: model.ratio(cc, depth_m), ratio)
    return (c, "ok") if np.isfinite(c) else (c, Reason.TOO_DARK.name.lower())


def _combined(shots: list[Shot]) -> tuple[float, float, dict]:
    ok = [s for s in shots if s.error is None and np.isfinite(s.c_ug_per_L) and s.sigma_ug_per_L > 0]
    if not ok:
        return float("nan"), float("nan"), {}
    w = np.array([1.0 / s.sigma_ug_per_L ** 2 for s in ok])
    w /= w.sum()
    c = float(np.sum(w * [s.c_ug_per_L for s in ok]))
    names = sorted({k for s in ok for k in s.terms})
    terms = {}
    for k in names:
        v = np.array([float(s.terms.get(k, 0.0)) for s in ok])
        terms[k] = float(np.sqrt(np.sum((w * v) ** 2))) if k in INDEPENDENT_TERMS else float(np.sum(w * v))
    return c, float(np.sqrt(sum(v * v for v in terms.values()))), terms


def run_secchi(profile_path: str | Path, reference: str | Path, submerged: list, depths: list[tuple[float, float]],
               *, sky, geometry: FieldGeometry, inputs: list[Uncertain], channel: str = "R", chlorophyll=None,
               background_absorption_per_m: float = 0.0, roi: Region | None = None,
               sun_zeniths_deg: list | None = None, progress=None, allow_other_camera: bool = False,
               page_dir: str | Path | None = None) -> SecchiResult:
    """The whole stage (module docstring). ``depths`` one (d, σ_d) in m per submerged photo; ``sky`` a
    ClearSky/MeasuredSky/OvercastSky; ``inputs`` the stated uncertainties other than depth and the ratio
    (names of :data:`camcal.water.uncertainty.FIELD_INPUTS` and 'epsilon'). Photos are RAW/JPEG/HEIC (the profile
    is applied) or radiance EXRs of ``camcal apply`` (refused when another profile made them). Per-photo failures
    are kept in the shot's ``error`` (the rest goes on); a bad reference stops the stage."""
    profile = load_profile(profile_path)
    plan = prepare(profile, estimator="narrowband")  # the band channels only: no spectral estimator to build
    base = band_model_from_profile(profile, channel, geometry=geometry.sky_model(), chlorophyll=chlorophyll,
                                   illuminant=None, background_absorption_per_m=background_absorption_per_m)
    model = FieldBandModel(base.wavelengths_nm, base.sensitivity, geometry=geometry, chlorophyll=chlorophyll,
                           background_absorption_per_m=background_absorption_per_m,
                           sensitivity_sigma=base.sensitivity_sigma, sky=sky)
    model = replace(model, illuminant=model._light[0])
    ref = measure_photo(Shot(Path(reference), "reference"), plan, channel, roi, surround=False,
                        profile_path=profile_path, allow_other_camera=allow_other_camera)
    diffuse_sigma = next((q.sigma for q in inputs if q.name == "diffuse_fraction"), DIFFUSE_SIGMA_DEFAULT)
    glare_rel_sigma = float(np.hypot(diffuse_sigma, REFERENCE_ALBEDO_SIGMA / REFERENCE_ALBEDO))
    if not (np.isfinite(ref.disk_radiance) and ref.disk_radiance > 0):
        raise CamcalError("the reference disk has no positive radiance", ref.path)
    page = None if page_dir is None else Path(page_dir)
    if page is not None:
        page.mkdir(parents=True, exist_ok=True)
    finish_photo(ref, ref, model, channel, page, 0)
    if progress:
        progress()
    shots = []
    models: dict[float, FieldBandModel] = {}
    zeniths = sun_zeniths_deg or [None] * len(submerged)
    base_model = model
    for path, (d, sd), zen in zip(submerged, depths, zeniths, strict=True):
        s = Shot(Path(path), "submerged", d, sd)
        model = base_model
        if zen is not None and sky.kind != "overcast":  # this photo's own sun (--sun auto)
            key = round(float(zen), 3)
            if key not in models:
                models[key] = base_model.varied("sun_zenith", key)
            model = models[key]
            inputs = [replace(q, value=key) if q.name == "sun_zenith" else q for q in inputs]
        try:
            measure_photo(s, plan, channel, roi, surround=True, profile_path=profile_path,
                          allow_other_camera=allow_other_camera)
            if s.scale and ref.scale and s.scale != ref.scale:
                raise CamcalError(f"holds {s.scale} radiance but the reference {ref.path.name} holds {ref.scale} "
                                  "radiance: a ratio needs both from one profile", s.path)
            s.unit = ref.unit
            solve_shot(s, ref, model, d, sd, inputs, glare_rel_sigma, view_angle_rad=geometry.view_angle_rad,
                       n_water=geometry.n_water)
        except CamcalError as exc:
            s.error = str(exc)
        finish_photo(s, ref, model, channel, page, len(shots) + 1)
        shots.append(s)
        if progress:
            progress()
    model = base_model
    c, sigma, terms = _combined(shots)
    dom = max(terms, key=terms.get) if terms else None
    meta = {"band_model": model.describe(), "stated_uncertainties": {q.name: {"value": q.value, "sigma": q.sigma,
                                                                             "unit": q.unit} for q in inputs}}
    return SecchiResult(ref, shots, model, c, sigma, terms, dom, meta)


def result_json(res: SecchiResult) -> dict:
    """JSON-ready summary (NaN → None)."""
    def num(v):
        return float(v) if v is not None and np.isfinite(v) else None

    def shot(s: Shot) -> dict:
        return {"file": str(s.path), "kind": s.kind, "depth_m": s.depth_m, "depth_sigma_m": s.depth_sigma_m,
                "disk": s.disk, "image": s.image, "time_utc": s.time_utc,
                "latitude_deg": s.latitude_deg, "longitude_deg": s.longitude_deg, "disk_radiance": num(s.disk_radiance),
                "disk_radiance_se": num(s.disk_se), "surround_radiance": num(s.surround_radiance),
                "ratio": num(s.ratio), "sigma_ln_ratio": num(s.sigma_ln_ratio), "c_ug_per_L": num(s.c_ug_per_L),
                "sigma_ug_per_L": num(s.sigma_ug_per_L), "sigma_terms_ug_per_L": {k: num(v) for k, v in
                                                                                  s.terms.items()},
                "dominant": max(s.terms, key=s.terms.get) if s.terms else None, "reason": s.reason or None,
                "error": s.error, "notes": s.notes, "warnings": s.warnings, "unit": s.unit,
                "surround_budget": None if s.budget is None else {k: num(v) if not isinstance(v, bool) else v
                                                                  for k, v in s.budget.describe().items()}}

    return {"c_ug_per_L": num(res.c_ug_per_L), "sigma_ug_per_L": num(res.sigma_ug_per_L),
            "sigma_terms_ug_per_L": {k: num(v) for k, v in res.terms.items()}, "dominant": res.dominant,
            "warnings": all_warnings(res), "unit_radiance": res.reference.unit, "unit_c": CONCENTRATION,
            "reference": shot(res.reference), "submerged": [shot(s) for s in res.submerged], **res.meta}


def all_warnings(res: SecchiResult) -> list[str]:
    """Every photo's warnings, each prefixed with its file name."""
    return [f"{s.path.name}: {w}" for s in [res.reference, *res.submerged] for w in s.warnings]


def _shot_figure(s: Shot, ref: Shot, model, channel: str):
    """The page image of one photo, from block means of its full-size maps: the photo (G band radiance) with the
    disk, interior, surround and glints; for a submerged photo also its per-pixel band ratio over the interior."""
    from matplotlib.patches import Circle  # lazy, as camcal.report.plots: matplotlib only when a page is drawn

    g = s.channels["G"]
    f = max(1, math.ceil(max(g.shape) / PREVIEW_PX))
    sub = s.kind == "submerged" and s.budget is not None and np.isfinite(s.c_ug_per_L)
    fig = new_figure(5.6 if sub else 3.4, 2.7)
    axes = fig.subplots(1, 2 if sub else 1, squeeze=False)[0]
    small = block_mean(g, f)
    finite = small[np.isfinite(small)]
    vmax = float(np.percentile(finite, 99.5)) if finite.size else 1.0
    ax = axes[0]
    ax.imshow(small, cmap="gray", vmin=0, vmax=vmax, interpolation="nearest")
    (cx, cy), r = s.fit.centre_px, s.fit.radius_px
    ax.add_patch(Circle(((cx - (f - 1) / 2) / f, (cy - (f - 1) / 2) / f), r / f, fill=False, color="tab:orange",
                        lw=1.0))
    for mask, colour in ((s.fit.interior, "tab:green"), (s.fit.surround if sub else None, "tab:blue"),
                         (s.fit.glint if s.fit.glint.any() else None, "tab:red")):
        if mask is not None:
            ax.contour(block_mean(mask.astype(np.float32), f), levels=[0.5], colors=colour, linewidths=0.7)
    ax.set_title("disk (orange), interior (green)" + (",\nsurround (blue)" if sub else ""), fontsize=9)
    if sub:
        b = s.budget
        ratio = block_mean(np.where(s.fit.interior, (s.channels[channel] - b.glare - b.over_disk)
                                    / ref.disk_radiance, np.nan), f)
        im = axes[1].imshow(ratio, cmap="viridis", interpolation="nearest")
        cb = fig.colorbar(im, ax=axes[1], shrink=0.8)
        cb.ax.tick_params(labelsize=8)
        cb.set_label("ratio (dimensionless)", fontsize=8)
        axes[1].set_title(f"band ratio per pixel ({channel}),\nmean {s.ratio:.4f}", fontsize=9)
    for a in axes:
        a.set_xticks([])
        a.set_yticks([])
    return fig


def _survey_figures(res: SecchiResult, out: Path) -> list[tuple[str, str]]:
    """C ± σ_C over the capture time (or the photo order when no photo holds a time) and, when photos hold GPS,
    their positions coloured by C; returns [(file, caption)]."""
    ok = [s for s in res.submerged if s.error is None and np.isfinite(s.c_ug_per_L)]
    figs: list[tuple[str, str]] = []
    if not ok:
        return figs
    fig = new_figure(6.0, 2.6)
    ax = fig.subplots()
    timed = [s for s in ok if s.time_utc]
    if timed:
        import matplotlib.dates as mdates

        x = [datetime.fromisoformat(s.time_utc) for s in timed]
        ax.errorbar(x, [s.c_ug_per_L for s in timed], yerr=[s.sigma_ug_per_L for s in timed], fmt="o", ms=4,
                    capsize=3)
        if max(x) - min(x) < timedelta(minutes=10):  # one instant: a readable hour around it
            ax.set_xlim(min(x) - timedelta(minutes=30), max(x) + timedelta(minutes=30))
        ax.xaxis.set_major_formatter(mdates.DateFormatter("%H:%M", tz=UTC))
        ax.set_xlabel("capture time (UTC)")
        caption = "C ± σ_C (1σ) of each submerged photo over its capture time (UTC)"
    else:
        ax.errorbar(range(1, len(ok) + 1), [s.c_ug_per_L for s in ok], yerr=[s.sigma_ug_per_L for s in ok], fmt="o",
                    ms=4, capsize=3)
        ax.set_xlabel("submerged photo (no capture time in the photos)")
        ax.set_xticks(range(1, len(ok) + 1))
        caption = "C ± σ_C (1σ) of each submerged photo, in order (the photos hold no capture time)"
    if np.isfinite(res.c_ug_per_L):
        ax.axhline(res.c_ug_per_L, color="0.4", lw=0.8, ls="--", label=f"combined {res.c_ug_per_L:.3g} "
                   f"{CONCENTRATION}")
        ax.legend(fontsize=7)
    ax.set_ylabel(f"chlorophyll-a ({CONCENTRATION})")
    ax.tick_params(labelsize=7)
    write_png(fig, out / "survey_time.png")
    figs.append(("survey_time.png", caption))
    placed = [s for s in ok if s.latitude_deg is not None and s.longitude_deg is not None]
    if placed:
        fig = new_figure(4.2, 3.4)
        ax = fig.subplots()
        sc = ax.scatter([s.longitude_deg for s in placed], [s.latitude_deg for s in placed],
                        c=[s.c_ug_per_L for s in placed], cmap="viridis", s=36)
        cb = fig.colorbar(sc, ax=ax)
        cb.set_label(f"C ({CONCENTRATION})", fontsize=7)
        ax.set_xlabel("longitude (° E)")
        ax.set_ylabel("latitude (° N)")
        ax.ticklabel_format(useOffset=False)
        lon = [s.longitude_deg for s in placed]
        lat = [s.latitude_deg for s in placed]
        if max(lon) - min(lon) < 1e-3 and max(lat) - min(lat) < 1e-3:  # one place: about ±100 m around it
            ax.set_xlim(min(lon) - 1e-3, max(lon) + 1e-3)
            ax.set_ylim(min(lat) - 1e-3, max(lat) + 1e-3)
        ax.tick_params(labelsize=7)
        write_png(fig, out / "survey_positions.png")
        figs.append(("survey_positions.png", "positions of the submerged photos (GPS, WGS-84), coloured by C"))
    return figs


PAGE_CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:0;background:#f4f6f8;color:#1d2630}
header{background:#12344d;color:#fff;padding:20px 32px}
header h1{margin:0 0 6px;font-size:24px;font-weight:600}
header p{margin:2px 0;opacity:.9;font-size:14px}
main{padding:20px 32px;max-width:1100px}
.result{font-size:30px;font-weight:700}
.warn{background:#fff4d6;border-left:4px solid #e0a000;padding:8px 12px;margin:8px 0;font-size:13px}
.err{background:#fde2e1;border-left:4px solid #c62828;padding:8px 12px;margin:8px 0;font-size:13px}
.grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(460px,1fr));gap:16px}
.card{background:#fff;border-radius:8px;box-shadow:0 1px 3px rgba(0,0,0,.12);padding:14px}
.card h3{margin:0 0 8px;font-size:15px;word-break:break-all}
.card img{width:100%;height:auto;border-radius:4px;background:#eee}
table.kv{border-collapse:collapse;width:100%;font-size:13px;margin-top:8px}
table.kv td{padding:3px 4px;border-bottom:1px solid #eef0f2}
table.kv td:first-child{color:#55606b;width:45%}
table.kv td:last-child{text-align:right;font-variant-numeric:tabular-nums}
.terms{font-size:12px;color:#55606b}
figure{margin:0}
figcaption{font-size:12px;color:#55606b;margin-top:4px}
.plots{display:flex;flex-wrap:wrap;gap:16px;margin:12px 0 24px}
.plots .card{flex:0 1 480px}
footer{font-size:12px;color:#6b7680;padding:12px 32px 24px}
"""


def _fmt(v, digits: int = 4, unit: str = "") -> str:
    if v is None or not np.isfinite(v):
        return "—"
    return f"{v:.{digits}g}" + (f" {unit}" if unit else "")


def _card(s: Shot, res: SecchiResult, title: str) -> str:
    e = html.escape
    unit = s.unit or res.reference.unit
    rows = [("kind", "reference (disk in air)" if s.kind == "reference" else "submerged")]
    if s.depth_m is not None:
        rows.append(("depth", f"{s.depth_m:g} m" + (f" ± {s.depth_sigma_m * 1000:g} mm" if s.depth_sigma_m else "")))
    if s.disk:
        cx, cy = s.disk["centre_photo_px"]
        rows.append(("disk", f"centre ({cx:.1f}, {cy:.1f}) px, radius {s.disk['radius_photo_px']:.1f} px"))
    rows.append(("disk radiance L", f"{_fmt(s.disk_radiance)} ± {_fmt(s.disk_se, 2)} {unit}"))
    if s.kind == "submerged":
        b = s.budget
        rows.append(("surround radiance", _fmt(s.surround_radiance, 4, unit)))
        if b is not None:
            rows.append(("surface glare (model)", f"{_fmt(b.glare, 3)} ± {_fmt(b.glare_sigma, 2)} {unit}"))
            rows.append(("water light over the disk", f"{_fmt(b.over_disk, 3)} ± {_fmt(b.over_disk_sigma, 2)} {unit}"))
        rows.append(("band ratio", f"{_fmt(s.ratio, 5)} (dimensionless)"))
        rows.append(("C ± σ_C (1σ)", f"<b>{_fmt(s.c_ug_per_L)} ± {_fmt(s.sigma_ug_per_L, 2)} {CONCENTRATION}</b>"))
    if s.time_utc:
        rows.append(("capture time", e(s.time_utc.replace("+00:00", " UTC"))))
    if s.latitude_deg is not None and s.longitude_deg is not None:
        rows.append(("position", f"{s.latitude_deg:.5f}° N, {s.longitude_deg:.5f}° E"))
    kv = "".join(f"<tr><td>{e(k)}</td><td>{v}</td></tr>" for k, v in rows)
    terms = ""
    if s.terms:
        parts = ", ".join(f"{e(k)} {v:.2g}" for k, v in sorted(s.terms.items(), key=lambda kv: -kv[1]))
        terms = f'<p class="terms">σ_C terms ({CONCENTRATION}, 1σ): {parts}</p>'
    img = f'<img src="{e(s.image)}" alt="{e(s.path.name)}">' if s.image else ""
    warns = "".join(f'<div class="warn">⚠ {e(w)}</div>' for w in s.warnings)
    err = f'<div class="err">failed: {e(s.error)}</div>' if s.error else ""
    notes = "".join(f'<p class="terms">note: {e(str(n))}</p>' for n in s.notes)
    return (f'<div class="card"><h3>{e(title)}</h3>{img}{err}{warns}<table class="kv">{kv}</table>'
            f"{terms}{notes}</div>")


def _light_text(meta: dict) -> str:
    light = (meta.get("band_model") or {}).get("light") or {}
    sky = str(light.get("sky", "?"))
    if "sun_zenith_deg" in light and "overcast" not in sky:
        sky += f", sun zenith {float(light['sun_zenith_deg']):.1f}°"
    if "aerosol_optical_depth_500nm" in light:
        sky += f", aerosol optical depth {float(light['aerosol_optical_depth_500nm']):g} at 500 nm"
    f = (meta.get("band_model") or {}).get("diffuse_fraction_in_band")
    if f is not None:
        sky += f", diffuse fraction in the band {float(f):.0%}"
    return sky


def write_diagnostics(res: SecchiResult, outdir: str | Path, channel: str = "R") -> Path:
    """The survey page ``index.html`` (one card per photo with its image, disk, ratio, C ± σ_C and warnings;
    C over time; positions where the photos hold GPS) and ``secchi.json``; returns the page's path. The photos'
    images were drawn as each photo was done (``run_secchi(page_dir=...)``)."""
    e = html.escape
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    plots = "".join(f'<div class="card"><figure><img src="{e(f)}" alt="{e(c)}"><figcaption>{e(c)}</figcaption>'
                    f"</figure></div>" for f, c in _survey_figures(res, out))
    warns = all_warnings(res)
    ok = np.isfinite(res.c_ug_per_L)
    result = (f"C = {res.c_ug_per_L:.4g} ± {res.sigma_ug_per_L:.2g} {CONCENTRATION} (1σ)" if ok
              else "no concentration")
    n_sub = len(res.submerged)
    head = (f"<header><h1>Secchi survey: chlorophyll-a</h1><p class='result'>{e(result)}</p>"
            f"<p>{n_sub} submerged photo{'s' if n_sub != 1 else ''} and one reference; dominant uncertainty: "
            f"{e(str(res.dominant))}; band channel {e(channel)}; radiance in {e(res.reference.unit or '?')}</p>"
            f"<p>light: {e(_light_text(res.meta))}</p></header>")
    banner = "".join(f'<div class="warn">⚠ {e(w)}</div>' for w in warns)
    every = [res.reference, *res.submerged]
    names = [s.path.name for s in every]  # a file name shared by photos of several folders gets its folder
    cards = "".join(_card(s, res, s.path.name if names.count(s.path.name) == 1 else f"{s.path.parent.name}/"
                          f"{s.path.name}") for s in every)
    page = ("<!doctype html><html lang='en'><head><meta charset='utf-8'><meta name='viewport' "
            "content='width=device-width, initial-scale=1'><title>camcal secchi: "
            f"{e(result)}</title><style>{PAGE_CSS}</style></head><body>{head}<main>{banner}"
            f"<h2>Survey</h2><div class='plots'>{plots}</div><h2>Photos</h2><div class='grid'>{cards}</div></main>"
            "<footer>camcal secchi: field model (sun and sky over a flat surface) over the profile's c(λ); glare and "
            "the water's own light as in docs/water.md; σ_C is one standard deviation (root sum of squares of its "
            "terms). Full numbers: secchi.json.</footer></body></html>")
    atomic_write_text(out / "secchi.json", json.dumps(result_json(res), indent=1, allow_nan=False,
                                                      ensure_ascii=False))
    return atomic_write_text(out / "index.html", page)

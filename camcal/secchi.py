"""From photos of a Secchi disk to chlorophyll-a in one stage (``camcal secchi``).

1. **Apply** the calibration profile to every photo (:func:`camcal.apply.apply_prepared`): band radiance R, G, B.
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
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from camcal.apply import apply_prepared, prepare
from camcal.atomic import atomic_write_text
from camcal.errors import CamcalError
from camcal.io import load_frame
from camcal.plots import new_figure, write_png
from camcal.profile import load_profile
from camcal.region import Region
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
#: Fixed-point iterations of C and the column fraction F.
MAX_ITERATIONS = 30


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
    preview: dict | None = None
    """Downsampled G and band-ratio images for the page (:func:`downsample`), made as each photo is done."""


def measure_photo(shot: Shot, plan, channel: str, roi: Region | None, surround: bool) -> Shot:
    """Apply the profile, find the disk and average the band channel over its interior (and surround)."""
    img = apply_prepared(load_frame(shot.path), plan)
    scale = 2 if str(img.metadata.get("resolution", "")).startswith("half") else 1
    finder = img.channels["G"]
    if roi is not None:
        fit = disk_from_roi(finder, roi, scale=scale, where=shot.path)
    else:
        fit = find_disk(finder, scale=scale, where=shot.path)
    band = img.channels[channel]
    shot.fit, shot.channels = fit, {k: img.channels[k] for k in {"G", channel}}  # for the diagnostic page
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


def unexplained_sigma(model: FieldBandModel, disk: float, reference: float, depth_m: float,
                      span: tuple[float, float], c_ug_per_L: float, nodes: int = 12) -> float:
    """RMS of C(X) − C for the light X over the disk uniform on ``span`` (Gauss-Legendre over X, each node
    inverted exactly); a node no C explains (X too large: a dark disk) counts as a zero-signal bound, C = 2×
    the largest explained C, so σ stays finite and large."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    lo, hi = span
    xs = lo + (x + 1.0) * 0.5 * (hi - lo)
    cs = np.array([invert_one(model, (disk - xx) / reference, depth_m)[0] for xx in xs])
    ok = np.isfinite(cs)
    if not ok.any():
        return float("inf")
    cs = np.where(ok, cs, 2.0 * np.nanmax(cs))
    return float(np.sqrt(np.sum(0.5 * w * (cs - c_ug_per_L) ** 2)))


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
        terms["unexplained_surround"] = np.array([unexplained_sigma(model, s.disk_radiance, ref.disk_radiance,
                                                                    depth_m, span, s.c_ug_per_L)])
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
               sun_zeniths_deg: list | None = None, progress=None) -> SecchiResult:
    """The whole stage (module docstring). ``depths`` one (d, σ_d) in m per submerged photo; ``sky`` a
    ClearSky/MeasuredSky/OvercastSky; ``inputs`` the stated uncertainties other than depth and the ratio
    (names of :data:`camcal.water.uncertainty.FIELD_INPUTS` and 'epsilon'). Per-photo failures are kept in the
    shot's ``error`` (the rest goes on); a bad reference stops the stage."""
    profile = load_profile(profile_path)
    plan = prepare(profile)
    base = band_model_from_profile(profile, channel, geometry=geometry.sky_model(), chlorophyll=chlorophyll,
                                   illuminant=None, background_absorption_per_m=background_absorption_per_m)
    model = FieldBandModel(base.wavelengths_nm, base.sensitivity, geometry=geometry, chlorophyll=chlorophyll,
                           background_absorption_per_m=background_absorption_per_m,
                           sensitivity_sigma=base.sensitivity_sigma, sky=sky)
    model = replace(model, illuminant=model._light[0])
    ref = measure_photo(Shot(Path(reference), "reference"), plan, channel, roi, surround=False)
    diffuse_sigma = next((q.sigma for q in inputs if q.name == "diffuse_fraction"), DIFFUSE_SIGMA_DEFAULT)
    glare_rel_sigma = float(np.hypot(diffuse_sigma, REFERENCE_ALBEDO_SIGMA / REFERENCE_ALBEDO))
    if progress:
        progress()
    if not (np.isfinite(ref.disk_radiance) and ref.disk_radiance > 0):
        raise CamcalError("the reference disk has no positive radiance", ref.path)
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
            measure_photo(s, plan, channel, roi, surround=True)
            s.unit = ref.unit
            solve_shot(s, ref, model, d, sd, inputs, glare_rel_sigma, view_angle_rad=geometry.view_angle_rad,
                       n_water=geometry.n_water)
        except CamcalError as exc:
            s.error = str(exc)
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
                "disk": s.fit.describe() if s.fit else None, "disk_radiance": num(s.disk_radiance),
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


def _shot_figure(s: Shot, res: SecchiResult, channel: str):
    from matplotlib.patches import Circle  # lazy, as camcal.plots: matplotlib only when a page is drawn

    sub = s.kind == "submerged" and s.fit is not None and np.isfinite(s.c_ug_per_L)
    fig = new_figure(11.0 if sub else 4.5, 3.6)
    axes = fig.subplots(1, 3 if sub else 1, squeeze=False)[0]
    g = s.channels["G"]
    finite = g[np.isfinite(g)]
    vmax = float(np.percentile(finite, 99.5)) if finite.size else 1.0
    ax = axes[0]
    ax.imshow(g, cmap="gray", vmin=0, vmax=vmax, interpolation="nearest")
    if s.fit is not None:
        (cx, cy), r = s.fit.centre_px, s.fit.radius_px
        ax.add_patch(Circle((cx, cy), r, fill=False, color="tab:orange", lw=1.2, label="disk"))
        ax.contour(s.fit.interior, levels=[0.5], colors="tab:green", linewidths=0.8)
        if s.kind == "submerged":
            ax.contour(s.fit.surround, levels=[0.5], colors="tab:blue", linewidths=0.8)
        if s.fit.glint.any():
            ax.contour(s.fit.glint, levels=[0.5], colors="tab:red", linewidths=0.8)
    ax.set_title(f"{s.path.name}: disk (orange), interior (green)" + (", surround (blue), glint (red)"
                                                                     if s.kind == "submerged" else ""), fontsize=7)
    if sub:
        ratio = np.where(s.fit.interior, (s.channels[channel] - s.budget.glare - s.budget.over_disk)
                         / res.reference.disk_radiance,
                         np.nan)
        im = axes[1].imshow(ratio, cmap="viridis", interpolation="nearest")
        fig.colorbar(im, ax=axes[1], shrink=0.8)
        axes[1].set_title(f"ratio per pixel ({channel}); mean {s.ratio:.4f}", fontsize=7)
        predicted = float(res.model.ratio(s.c_ug_per_L, s.depth_m))
        resid = (ratio - predicted) / predicted
        lim = float(np.nanpercentile(np.abs(resid), 99)) if np.isfinite(resid).any() else 1.0
        im = axes[2].imshow(resid, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
        fig.colorbar(im, ax=axes[2], shrink=0.8)
        axes[2].set_title(f"residual vs model at C = {s.c_ug_per_L:.3g} {CONCENTRATION} (relative)", fontsize=7)
    for a in axes:
        a.set_xticks([])
        a.set_yticks([])
    return fig


def write_diagnostics(res: SecchiResult, outdir: str | Path, channel: str = "R") -> Path:
    """A diagnostic page ``index.html`` with one PNG per photo (disk outlined, regions, ratio, residual) and
    ``secchi.json``; returns the page's path."""
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    rows, figs = [], []
    for i, s in enumerate([res.reference, *res.submerged]):
        if s.channels is not None:
            name = f"photo{i:02d}_{s.kind}.png"
            write_png(_shot_figure(s, res, channel), out / name)
            figs.append(f'<figure><img src="{name}" alt="{html.escape(s.path.name)}"><figcaption>'
                        f'{html.escape(s.path.name)}</figcaption></figure>')
        c = "" if not np.isfinite(s.c_ug_per_L) else f"{s.c_ug_per_L:.4g} ± {s.sigma_ug_per_L:.2g}"
        rows.append("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in (
            s.path.name, s.kind, "" if s.depth_m is None else f"{s.depth_m:g}",
            "" if not np.isfinite(s.ratio) else f"{s.ratio:.5f}", c,
            max(s.terms, key=s.terms.get) if s.terms else "", s.error or "; ".join(s.notes))) + "</tr>")
    head = (f"<h1>Secchi survey: C = {res.c_ug_per_L:.4g} ± {res.sigma_ug_per_L:.2g} {CONCENTRATION}</h1>"
            f"<p>dominant uncertainty: {html.escape(str(res.dominant))}; light: "
            f"{html.escape(json.dumps(res.meta['band_model'].get('light')))}</p>")
    table = ("<table border=1 cellpadding=3><tr><th>photo</th><th>kind</th><th>depth (m)</th><th>ratio</th>"
             f"<th>C ({CONCENTRATION})</th><th>dominant</th><th>notes</th></tr>" + "".join(rows) + "</table>")
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>camcal secchi</title></head><body>"
            + head + table + "".join(figs) + "</body></html>")
    atomic_write_text(out / "secchi.json", json.dumps(result_json(res), indent=1, allow_nan=False))
    return atomic_write_text(out / "index.html", page)

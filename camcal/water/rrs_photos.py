"""From photos of the water, the sky and a grey card to Rrs per band, turbidity and SPM (``camcal rrs``).

1. **Radiance**: every photo through the profile (:func:`camcal.apply.photo.apply_prepared`), or ``camcal apply``'s EXRs
   as they are; band radiance R, G, B over the photo's central region (:func:`camcal.water.rrs.region_stats`).
2. **Screen** the water photos for glint (:func:`camcal.water.rrs.screen_water`): the rejected ones are named.
3. **ρ** from the view angle and the wind (:func:`camcal.water.skyglint.rho_with_sigma`).
4. **Card** reflectance per band through the profile's c(λ) and the light (SPECTRL2 at the sun of the photos'
   EXIF, or flat when the sun is unknown).
5. **Rrs ± σ** per band with the dominant term (:func:`camcal.water.rrs.estimate_rrs`), the profile's σ(c)
   (:func:`camcal.water.rrs.profile_term`), the band ratios, and the products of the red band at its effective
   wavelength (:mod:`camcal.water.products`).
6. **Outputs**: a self-contained page (photos with their regions, Rrs bars with σ, the products), ``rrs.json``
   and ``station.csv``, one row that :func:`append_survey` merges into a survey table.
"""

from __future__ import annotations

import csv
import html
import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from camcal.apply.photo import apply_prepared, prepare
from camcal.errors import CamcalError
from camcal.io.atomic import atomic_write_text
from camcal.io.exr import read_exr
from camcal.io.manifest import read_text_file
from camcal.io.read import load_frame
from camcal.io.sun import SunPosition
from camcal.models.profile import load_profile
from camcal.report.plots import new_figure, write_png
from camcal.water.field import ClearSky
from camcal.water.products import (
    SPM_NECHAD_2010,
    TURBIDITY_DOGLIOTTI_2015,
    Product,
    effective_wavelength_nm,
    product,
)
from camcal.water.rrs import (
    BANDS,
    RrsResult,
    card_band_reflectance,
    estimate_rrs,
    profile_term,
    region_stats,
    screen_water,
)
from camcal.water.skyglint import rho_sky_with_sigma, rho_with_sigma


@dataclass
class Station:
    """One station's photos, result and products."""

    water: list
    sky: list
    card: list
    result: RrsResult
    products: dict
    effective_wavelength_nm: dict
    meta: dict = field(default_factory=dict)
    images: dict = field(default_factory=dict)  # name -> G channel (for the page)


def read_card_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A card's measured reflectance: CSV ``wavelength_nm, reflectance[, sigma]`` (fractions 0-1; ``#`` comments)."""
    path = Path(path)
    text = read_text_file(path, "card reflectance CSV")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    if header[:2] != ["wavelength_nm", "reflectance"]:
        raise CamcalError("card reflectance CSV needs columns wavelength_nm,reflectance[,sigma] "
                          f"(header is {','.join(header)})", path)
    try:
        v = np.array([[float(c) for c in ln.split(",")] for ln in lines[1:]], dtype=float)
    except ValueError:
        raise CamcalError("card reflectance CSV: a row is not numbers", path) from None
    if v.ndim != 2 or v.shape[0] < 2 or v.shape[1] != len(header) or not np.all(np.isfinite(v)):
        raise CamcalError("card reflectance CSV needs at least two complete rows of finite numbers", path)
    if np.any(np.diff(v[:, 0]) <= 0) or np.any(v[:, 1] <= 0) or np.any(v[:, 1] > 1.5):
        raise CamcalError("card reflectance CSV: wavelengths must increase and reflectances lie in (0, 1.5]", path)
    return v[:, 0], v[:, 1], (v[:, 2] if v.shape[1] > 2 else None)


def _radiance(path: Path, plan) -> tuple[dict, dict]:
    """(channels R, G, B, metadata) of a photo through the profile, or of an EXR of ``camcal apply`` made with the
    same profile (another profile's band radiance has another scale)."""
    if path.suffix.lower() == ".exr":
        ch, meta = read_exr(path, ["R", "G", "B"])
        made_with = meta.get("profile_sha256")
        if made_with is not None and made_with != plan.profile.content_sha256:
            raise CamcalError("this radiance EXR was made with another profile than --profile; apply the photos with "
                              "this profile or give that one", path)
        if meta.get("radiance_scale") == "relative":
            raise CamcalError("relative radiance (the profile had no absolute c(λ)): Rrs needs absolute band "
                              "radiance, or at least one profile for all photos; use the photos themselves", path)
        return ch, meta
    img = apply_prepared(load_frame(path), plan)
    return img.channels, img.metadata


def _meta(meta: dict) -> dict:
    e, p = meta.get("exposure") or {}, meta.get("place") or {}
    return {"capture_time": e.get("capture_time"), "gps_time_utc": e.get("gps_time_utc"),
            "utc_offset": e.get("utc_offset"), "latitude_deg": p.get("latitude_deg"),
            "longitude_deg": p.get("longitude_deg")}


def run_rrs(profile_path, water: list, sky: list, card: list, *, sun: SunPosition | None, view_deg: float = 40.0,
            relative_azimuth_deg: float | None = 135.0, wind_m_s: float | None = 5.0, wind_sigma_m_s: float = 2.0,
            card_csv: str | Path | None = None, sky_model: str = "cie", progress=None) -> Station:
    """The whole stage (module docstring). ``sun`` None: the light is taken flat (noted). ``sky_model`` 'cie': ρ
    reflects the CIE standard clear sky for the sun's position (:func:`camcal.water.skyglint.rho_sky_with_sigma`;
    needs the sun, the wind and the relative azimuth), 'uniform': a uniform sky."""
    profile = load_profile(profile_path)
    plan = prepare(profile)
    if plan.relative:
        raise CamcalError("the profile's c(λ) is relative: Rrs compares photos of different exposures and needs "
                          "absolute band radiance", Path(profile_path))
    sp = profile.spectral
    wl = np.asarray(sp.wavelength_nm, float)
    sens = {b: np.asarray(v, float) for b, v in sp.rgb().items()}
    try:
        sens_sigma = {b: np.asarray(v, float) for b, v in sp.rgb_uncertainty().items()}
    except (AttributeError, KeyError, TypeError):
        sens_sigma = None
    notes = []
    if sun is not None:
        direct, diffuse = ClearSky(float(sun.apparent_zenith_deg)).irradiance(wl)
        light = direct + diffuse
        light_text = f"SPECTRL2 global irradiance at the sun's zenith {sun.apparent_zenith_deg:.2f} deg"
    else:
        light = None
        light_text = "flat (the sun is unknown: no EXIF time and place, no --sun)"
        notes.append("the light's spectrum is taken flat: the card's band reflectance and the bands' effective "
                     "wavelengths assume it")
    stats: dict[str, list] = {"water": [], "sky": [], "card": []}
    images = {}
    for kind, paths in (("water", water), ("sky", sky), ("card", card)):
        for p in paths:
            p = Path(p)
            ch, meta = _radiance(p, plan)
            s = region_stats(ch, p.name, kind)
            s.meta = {"path": str(p), **_meta(meta)}
            stats[kind].append(s)
            images[p.name] = np.asarray(ch["G"], np.float32)
            if progress:
                progress()
    for kind in ("sky", "card"):
        for s in stats[kind]:
            if not all(np.isfinite(s.mean[b]) and s.mean[b] > 0 for b in BANDS):
                raise CamcalError(f"the {kind} photo's region has no positive radiance in every band",
                                  Path(s.meta["path"]))
            if s.saturated_fraction > 0.01:
                raise CamcalError(f"the {kind} photo is saturated over {100 * s.saturated_fraction:.1f} % of its "
                                  "region: shoot it again with a shorter exposure", Path(s.meta["path"]))
    kept = screen_water(stats["water"])
    if not kept:
        raise CamcalError("every water photo was rejected: " + "; ".join(f"{s.name}: {s.rejected}"
                                                                         for s in stats["water"]))
    if sky_model == "cie" and sun is not None and wind_m_s is not None and relative_azimuth_deg is not None:
        rho = rho_sky_with_sigma(view_deg, wind_m_s, wind_sigma_m_s, float(sun.apparent_zenith_deg),
                                 relative_azimuth_deg)
    else:
        if sky_model == "cie":
            notes.append("ρ for a uniform sky: the CIE sky needs the sun's position, the wind and the azimuth")
        rho = rho_with_sigma(view_deg, wind_m_s, wind_sigma_m_s)
    if card_csv is not None:
        cwl, cr, cs = read_card_csv(card_csv)
    else:
        cwl = cr = cs = None
    card_r = card_band_reflectance(wl, sens, light, cwl, cr, cs)
    first = estimate_rrs(kept, stats["sky"], stats["card"], rho, card_r)
    prof = profile_term(first.rrs, wl, sens, sens_sigma, light, cwl, cr)
    result = estimate_rrs(kept, stats["sky"], stats["card"], rho, card_r, prof)
    eff = {b: effective_wavelength_nm(wl, sens[b], light) for b in BANDS}
    products = {alg.quantity: product(alg, result.rrs["R"], result.sigma["R"], eff["R"])
                for alg in (TURBIDITY_DOGLIOTTI_2015, SPM_NECHAD_2010)}
    where = (stats["card"] + kept)[0].meta
    meta = {"profile": str(profile_path), "profile_sha256": profile.content_sha256, "view_deg": view_deg,
            "relative_azimuth_deg": relative_azimuth_deg, "wind_m_s": wind_m_s, "wind_sigma_m_s": wind_sigma_m_s,
            "sun": None if sun is None else sun.to_dict(), "light": light_text, "card": str(card_csv or "18 % flat"),
            "time_utc": None if sun is None or sun.utc is None else sun.utc.isoformat(),
            "latitude_deg": where.get("latitude_deg"), "longitude_deg": where.get("longitude_deg"), "notes": notes}
    if relative_azimuth_deg is not None and abs(relative_azimuth_deg - 135.0) > 30:
        notes.append(f"relative azimuth {relative_azimuth_deg:g} deg from the sun: ρ's model is for a sky without "
                     "the sun's glitter; the protocol's 135 deg keeps it out of the view")
    return Station(stats["water"], stats["sky"], stats["card"], result, products, eff, meta, images)


def _clean(v):
    """NaN and infinities to None, numpy scalars to Python, recursively."""
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if isinstance(v, float | np.floating):
        return float(v) if np.isfinite(v) else None
    if isinstance(v, np.integer | np.bool_):
        return v.item()
    return v


def station_json(st: Station) -> dict:
    """JSON-ready summary (NaN as null)."""
    return _clean({"rrs": st.result.describe(), "products": {k: p.describe() for k, p in st.products.items()},
            "effective_wavelength_nm": st.effective_wavelength_nm,
            "photos": [p.describe() for p in st.water + st.sky + st.card],
            "rejected": [{"file": p.name, "reason": p.rejected} for p in st.water if p.rejected], **st.meta})


#: Columns of a station row (the survey table's header).
CSV_COLUMNS = (["station", "time_utc", "latitude_deg", "longitude_deg", "sun_zenith_deg", "wind_m_s"]
               + [f"{q}_{b}" for b in BANDS for q in ("Rrs", "sigma_Rrs")] + ["dominant_R", "dominant_G", "dominant_B"]
               + ["B_over_G", "sigma_B_over_G", "G_over_R", "sigma_G_over_R", "turbidity_FNU", "sigma_turbidity_FNU",
                  "turbidity_valid", "SPM_g_m3", "sigma_SPM_g_m3", "SPM_valid", "red_effective_wavelength_nm",
                  "water_photos_kept", "water_photos_rejected"])


def station_row(st: Station, name: str) -> dict:
    """The station's CSV row (:data:`CSV_COLUMNS`; Rrs in sr⁻¹)."""
    r = st.result
    t, s = st.products["turbidity"], st.products["SPM"]
    row = {"station": name, "time_utc": st.meta.get("time_utc") or "", "latitude_deg": st.meta.get("latitude_deg"),
           "longitude_deg": st.meta.get("longitude_deg"),
           "sun_zenith_deg": (st.meta.get("sun") or {}).get("apparent_zenith_deg"), "wind_m_s": st.meta["wind_m_s"]}
    for b in BANDS:
        row[f"Rrs_{b}"], row[f"sigma_Rrs_{b}"], row[f"dominant_{b}"] = r.rrs[b], r.sigma[b], r.dominant[b]
    row["B_over_G"], row["sigma_B_over_G"] = r.ratios["B/G"]
    row["G_over_R"], row["sigma_G_over_R"] = r.ratios["G/R"]
    row.update({"turbidity_FNU": t.value, "sigma_turbidity_FNU": t.sigma, "turbidity_valid": t.valid,
                "SPM_g_m3": s.value, "sigma_SPM_g_m3": s.sigma, "SPM_valid": s.valid,
                "red_effective_wavelength_nm": st.effective_wavelength_nm["R"],
                "water_photos_kept": sum(p.rejected is None for p in st.water),
                "water_photos_rejected": " ".join(p.name for p in st.water if p.rejected)})
    return {k: ("" if row[k] is None else (f"{row[k]:.6g}" if isinstance(row[k], float) else row[k]))
            for k in CSV_COLUMNS}


def _csv_text(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def append_survey(path: str | Path, row: dict) -> Path:
    """Add (or replace, by station name) a station's row in the survey table at ``path`` (created if absent)."""
    path = Path(path)
    rows = []
    if path.exists():
        text = read_text_file(path, "survey CSV")
        reader = csv.DictReader(io.StringIO(text))
        if tuple(reader.fieldnames or ()) != tuple(CSV_COLUMNS):
            raise CamcalError("not a camcal rrs survey table (its header differs)", path)
        rows = [r for r in reader if r["station"] != row["station"]]
    return atomic_write_text(path, _csv_text([*rows, row]))


def _photo_figure(st: Station):
    from matplotlib import colormaps  # lazy: matplotlib only when a page is drawn
    from matplotlib.patches import Rectangle


    photos = st.water + st.sky + st.card
    cols = min(len(photos), 5)
    rows = -(-len(photos) // cols)
    fig = new_figure(2.4 * cols, 1.9 * rows)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[len(photos):]:
        ax.set_axis_off()
    for ax, p in zip(axes, photos, strict=False):
        g = st.images[p.name]
        finite = g[np.isfinite(g)]
        top = 2.0 * float(np.median(finite)) if finite.size and np.median(finite) > 0 else 1.0
        cmap = colormaps["gray"].with_extremes(bad="magenta")  # saturated or defective pixels
        ax.imshow(g, cmap=cmap, vmin=0.0, vmax=top,  # 0 to twice the median: uniform water is mid-grey
                  interpolation="nearest")
        y0, y1, x0, x1 = p.region
        colour = "tab:red" if p.rejected else "tab:green"
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, color=colour, lw=1.2))
        ax.set_title(f"{p.name}" + (" (rejected)" if p.rejected else ""), fontsize=6, color=colour)
        ax.set_xticks([])
        ax.set_yticks([])
    return fig


def _rrs_figure(st: Station):
    fig = new_figure(4.8, 3.0)
    ax = fig.subplots()
    r = st.result
    order = sorted(BANDS, key=st.effective_wavelength_nm.get)
    x = [st.effective_wavelength_nm[b] for b in order]
    colours = {"R": "tab:red", "G": "tab:green", "B": "tab:blue"}
    ax.bar(x, [r.rrs[b] for b in order], width=25, yerr=[2 * r.sigma[b] for b in order], capsize=4,
           color=[colours[b] for b in order], alpha=0.75, label="camcal Rrs ± 2σ")
    ax.plot(x, [r.hydrocolor[b] for b in order], "kx", label="HydroColor method (ρ = 0.028)")
    ax.set_xlabel("band effective wavelength (nm)")
    ax.set_ylabel("Rrs (sr⁻¹)")
    ax.legend(fontsize=7)
    return fig


_STYLE = ("body{font-family:system-ui,sans-serif;margin:2em auto;max-width:60em;color:#222}"
          "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:.25em .6em;"
          "text-align:right}th{background:#f3f3f3}td.l,th.l{text-align:left}.bad{color:#b00}.ok{color:#070}"
          "img{max-width:100%}h1{font-size:1.4em}h2{font-size:1.1em;margin-top:1.6em}")


def write_page(st: Station, outdir: str | Path, name: str = "station") -> Path:
    """``index.html`` (self-contained style), its PNGs, ``rrs.json`` and ``station.csv`` in ``outdir``."""
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    write_png(_photo_figure(st), out / "photos.png")
    write_png(_rrs_figure(st), out / "rrs.png")
    r = st.result
    esc = html.escape
    rows = "".join(
        f"<tr><td class=l>{b}</td><td>{st.effective_wavelength_nm[b]:.1f}</td><td>{r.rrs[b]:.5f}</td>"
        f"<td>{r.sigma[b]:.2g}</td><td class=l>{esc(r.dominant[b])}</td><td>{r.hydrocolor[b]:.5f}</td></tr>"
        for b in BANDS)
    ratios = "".join(f"<tr><td class=l>{k}</td><td>{v:.4f}</td><td>{s:.2g}</td></tr>" for k, (v, s) in
                     r.ratios.items())

    def prow(p: Product) -> str:
        cls = "ok" if p.valid else "bad"
        return (f"<tr><td class=l>{esc(p.quantity)}</td><td>{p.value:.4g} ± {p.sigma:.2g} {esc(p.unit)}</td>"
                f"<td class=l>{esc(p.algorithm)} at {p.wavelength_nm:.0f} nm (A = {p.a:.4g}, C = {p.c:.4g})</td>"
                f"<td class='l {cls}'>{esc(p.validity)}</td></tr>")

    photos = "".join(
        f"<tr><td class=l>{esc(p.name)}</td><td class=l>{p.kind}</td>"
        + "".join(f"<td>{p.mean[b]:.4g}</td>" for b in BANDS)
        + f"<td class='l {'bad' if p.rejected else 'ok'}'>{esc(p.rejected or 'kept')}</td></tr>"
        for p in st.water + st.sky + st.card)
    terms = "".join("<tr><td class=l>" + esc(k) + "</td>" + "".join(f"<td>{r.terms[b][k]:.2g}</td>" for b in BANDS)
                    + "</tr>" for k in r.terms["R"])
    m = st.meta
    page = (f"<!doctype html><html><head><meta charset='utf-8'><title>camcal rrs: {esc(name)}</title>"
            f"<style>{_STYLE}</style></head><body><h1>Water colour at {esc(name)}</h1>"
            f"<p>time {esc(str(m.get('time_utc')))}, position {esc(str(m.get('latitude_deg')))}, "
            f"{esc(str(m.get('longitude_deg')))}; view {m['view_deg']:g}° from nadir; wind {esc(str(m['wind_m_s']))} "
            f"m/s; ρ = {r.rho.value:.4f} ± {r.rho.sigma:.4f} ({esc(r.rho.model)}); light: {esc(m['light'])}; "
            f"card: {esc(m['card'])}</p>"
            "<h2>Rrs per band (sr⁻¹)</h2><table><tr><th class=l>band</th><th>λ_eff (nm)</th><th>Rrs</th><th>σ</th>"
            f"<th class=l>dominant σ term</th><th>HydroColor method</th></tr>{rows}</table>"
            "<img src='rrs.png' alt='Rrs bars with 2σ'>"
            f"<h2>Band ratios</h2><table><tr><th class=l>ratio</th><th>value</th><th>σ</th></tr>{ratios}</table>"
            "<h2>Products (red band)</h2><table><tr><th class=l>quantity</th><th>value</th><th class=l>algorithm</th>"
            f"<th class=l>validity</th></tr>{prow(st.products['turbidity'])}{prow(st.products['SPM'])}</table>"
            f"<h2>σ terms (sr⁻¹)</h2><table><tr><th class=l>term</th><th>R</th><th>G</th><th>B</th></tr>{terms}"
            "</table><h2>Photos</h2><img src='photos.png' alt='photos with their regions'>"
            "<table><tr><th class=l>photo</th><th class=l>kind</th><th>L_R</th><th>L_G</th><th>L_B</th>"
            f"<th class=l>screening</th></tr>{photos}</table>"
            + "".join(f"<p>note: {esc(n)}</p>" for n in m.get("notes", [])) + "</body></html>")
    atomic_write_text(out / "rrs.json", json.dumps(station_json(st), indent=1, allow_nan=False, default=str))
    atomic_write_text(out / "station.csv", _csv_text([station_row(st, name)]))
    return atomic_write_text(out / "index.html", page)

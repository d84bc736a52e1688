"""The calibration report: one self-contained HTML page for a :class:`camcal.models.profile.CalibrationProfile`.

The page has no external resources: CSS is inline and every plot is a figure of :mod:`camcal.report.plots`
encoded as PNG (matplotlib's Agg renderer, no pyplot, no backend change) and embedded as a
``data:image/png;base64`` URI, so it can be mailed, archived next to the profile, or opened offline.
Sections, in pipeline order:

* **Dark current** (seed eq. 12, β term; EMVA 1288 §8): histogram of the per-pixel dark current
  β (DN s⁻¹ at the dark frames' ISO) per CFA plane with the hot pixels drawn separately, and a map
  of β with the hot pixels circled.
* **Vignetting** (DNG ``OpcodeList3`` WarpRectilinear/FixVignetteRadial model
  g = 1 + k0 r² + k1 r⁴ + k2 r⁶ + k3 r⁸ + k4 r¹⁰): relative illumination g against the normalised
  radius r per plane, and a gain map with the optical centres.
* **Response** (seed eq. 12, g = α·x^γ + β): the measured ROI means (``ResponseModel.points``),
  filled when used by the fit and hollow when excluded (saturated or compressed), with the fit,
  and the relative residuals; one figure per kind (RAW, processed/JPEG).
* **Spectral sensitivity** c(λ) (seed §3.1): R, G (mean of G1 and G2), B with ±1 standard
  uncertainty bands, and G1 against G2.
* **EMVA 1288 summary** (release 4.0): the standard's data-sheet figures per plane, in its order
  (:func:`camcal.models.emva.sheet_rows`): system gain K from photon transfer, temporal dark noise, absolute
  sensitivity threshold, saturation capacity, SNR_max, dynamic range, linearity error, dark current,
  DSNU and PRNU with their uncertainties, the noise left in the flat map.
* Tables of the numbers of the JSON contract (:func:`camcal.models.profile.contract`), the contract itself,
  and the provenance (camcal version, creation date, input files, options, content hash).

A stage that was not calibrated gets a short "not calibrated" note instead of its section.
:func:`render_report` is pure (the same profile gives the same bytes); :func:`write_report`
writes the page atomically.
"""

from __future__ import annotations

import base64
import html
import json
import math
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from camcal import __version__
from camcal.errors import CamcalError
from camcal.frame import PLANES
from camcal.io.atomic import atomic_write_text
from camcal.models.emva import STANDARD, sheet_rows
from camcal.models.profile import contract, flats_optics_text
from camcal.models.spectral import describe_origin
from camcal.report.plots import dark_figure, flat_figure, png_bytes, response_figure, spectral_figure
from camcal.units import DN_PER_S

STAGE_TITLES = {"dark": "Dark current", "flat": "Vignetting (flat field)", "response": "Response curves",
                "spectral_sensitivity": "Spectral sensitivity c(λ)"}

CSS = """
body{font-family:-apple-system,"Segoe UI",Helvetica,Arial,sans-serif;margin:0;background:#f4f5f7;color:#1d1f23}
main{max-width:1120px;margin:0 auto;padding:16px 24px 48px;background:#fff}
h1{font-size:1.6em;margin:.4em 0 .1em}h2{font-size:1.25em;border-bottom:2px solid #dde1e6;padding-bottom:4px;
margin-top:1.8em}h3{font-size:1.05em;margin:1.2em 0 .4em}
.sub{color:#5a6270;margin:0 0 1em}
.bad{color:#b3261e;font-weight:600}
nav a{margin-right:14px;color:#1f5fa8;text-decoration:none}
table{border-collapse:collapse;margin:.5em 0 1em;font-size:.9em}
th,td{border:1px solid #d6dae0;padding:3px 9px;text-align:right;vertical-align:top}
th{background:#eef1f5}td.l,th.l{text-align:left}
figure{margin:.6em 0 1.2em}figure img{max-width:100%;height:auto;border:1px solid #e3e6ea}
figcaption{font-size:.85em;color:#4a5260;margin-top:4px}
.missing{background:#fff6e0;border-left:4px solid #f0a500;padding:8px 12px;color:#5c4400}
.stages span{display:inline-block;padding:2px 9px;margin:0 6px 4px 0;border-radius:10px;font-size:.85em}
.ok{background:#dff3e4;color:#14532d}.no{background:#fde8e8;color:#7f1d1d}
details{margin:.6em 0}summary{cursor:pointer;color:#1f5fa8}
pre{background:#f6f8fa;padding:10px;overflow:auto;font-size:.8em;max-height:480px}
code{font-size:.9em}
"""


# ---------------------------------------------------------------------------------------------
# small helpers
# ---------------------------------------------------------------------------------------------
def _esc(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _num(value: Any, digits: int = 5) -> str:
    """A number for a table cell (``—`` for missing or non-finite)."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "—" if not math.isfinite(value) else f"{value:.{digits}g}"
    if isinstance(value, list | tuple) and all(isinstance(v, int | float) for v in value):
        return "(" + ", ".join(_num(v, digits) for v in value) + ")"
    return _esc(value)


def _table(header: Sequence[str], rows: Iterable[Sequence[Any]], left: int = 1) -> str:
    """An HTML table; the first ``left`` columns are left-aligned text, the others formatted numbers."""
    out = ["<table><thead><tr>"]
    out += [f'<th class="l">{_esc(h)}</th>' if i < left else f"<th>{_esc(h)}</th>" for i, h in enumerate(header)]
    out.append("</tr></thead><tbody>")
    for row in rows:
        cells = [f'<td class="l">{_esc(v)}</td>' if i < left else f"<td>{_num(v)}</td>" for i, v in enumerate(row)]
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _channel_rows(spec: Sequence[tuple[str, str, dict | None]], channels: Sequence[str]) -> list[list[Any]]:
    return [[name, unit, *((vals or {}).get(c) for c in channels)] for name, unit, vals in spec]


def _img(png: bytes, alt: str, caption: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{_esc(alt)}">'
            f"<figcaption>{caption}</figcaption></figure>")


_SESSION_FOLDER = {"dark": "bias/ and dark/", "flat": "flat/", "response": "linearity/",
                   "spectral_sensitivity": "sweep/"}


_SESSION_STAGES = {"dark": ("bias", "dark"), "flat": ("flat",), "response": ("linearity",),
                   "spectral_sensitivity": ("sweep",)}


def _missing(key: str, profile=None) -> str:
    why = [r for r in (profile.provenance.not_calibrated if profile is not None else ())
           if r.get("stage") in _SESSION_STAGES[key]]
    if why:
        return (f'<section id="{key}"><h2>{_esc(STAGE_TITLES[key])}</h2>'
                + "".join(f'<p class="missing">not calibrated: the {_esc(r["stage"])} stage had too few usable '
                          f"frames: {_esc(r['reason'])}</p>" for r in why) + "</section>")
    return (f'<section id="{key}"><h2>{_esc(STAGE_TITLES[key])}</h2>'
            f'<p class="missing">not calibrated: this profile has no {_esc(STAGE_TITLES[key].lower())} stage. '
            f"<code>camcal calibrate</code> adds it when the session has {_esc(_SESSION_FOLDER[key])} "
            f"folder{'s' if key == 'dark' else ''}.</p></section>")


# ---------------------------------------------------------------------------------------------
# sections
# ---------------------------------------------------------------------------------------------
_RGB = ("R", "G", "B", "G1", "G2")


def _dark_section(profile, c: dict) -> str:
    d = c["dark"]
    rows = _channel_rows([
        ("bias", "DN", d["bias_dn"]),
        ("dark current β", DN_PER_S, d["dark_current_dn_per_s"]),
        ("β uncertainty", DN_PER_S, d["dark_current_unc_dn_per_s"]),
        ("read noise", "DN", d["read_noise_dn"]),
        ("DSNU of bias", "DN", d["dsnu_bias_dn"]),
        ("DSNU of β", DN_PER_S, d["dsnu_dark_current_dn_per_s"]),
    ], _RGB)
    defects = _table(["defects", "count"], [["hot", d["hot_pixel_count"]], ["dead", d["dead_pixel_count"]],
                                             ["noisy", d["noisy_pixel_count"]]])
    t = d.get("temperature_c")
    sub = (f'<p class="sub">ISO {_num(d["iso"])}, '
           f"{'temperature ' + _num(t) + ' °C' if t is not None else 'temperature unknown'}; "
           f"dark exposures {_num(list(profile.dark.exposure_times_s))} s.</p>")
    fig = _img(png_bytes(dark_figure(profile.dark)), "dark current histogram and map",
               "Left: histogram of β per plane (log counts; the β axis is linear up to the dotted line and "
               "logarithmic beyond it), hot pixels in orange. Right: β map, hot pixels circled. "
               "β is the slope of the dark signal with exposure time (seed eq. 12, β term).")
    return (f'<section id="dark"><h2>{STAGE_TITLES["dark"]}</h2>{sub}{fig}'
            + _table(["quantity", "unit", *_RGB], rows, left=2) + defects + "</section>")


def _flat_section(profile, c: dict) -> str:
    f = c["flat"]
    rows = _channel_rows([("corner gain", "", f["corner_gain"]), ("residual RMS", "rel.", f["residual_rms"]),
                          ("PRNU RMS", "rel.", f["prnu_rms"])], _RGB)
    centre = [[ch, x, y] for ch, (x, y) in f["centre_full_px"].items()]
    k = [[ch, *vals] for ch, vals in profile.flat.k.items()]
    nk = max((len(v) for v in profile.flat.k.values()), default=0)
    fig = _img(png_bytes(flat_figure(profile.flat)), "vignetting: gain against radius and gain map",
               "Left: relative illumination g against normalised radius per plane (curves: the fitted model; "
               "dots: the model over the plane). Right: gain map with the optical centres.")
    return (f'<section id="flat"><h2>{STAGE_TITLES["flat"]}</h2>'
            f'<p class="sub">model {_esc(f["model"])}; gain = 1 at the optical centre; flats at '
            f'{_esc(flats_optics_text(f))}.</p>{fig}'
            + _table(["quantity", "unit", *_RGB], rows, left=2)
            + "<h3>Optical centre (full-resolution px) and DNG radial coefficients</h3>"
            + _table(["plane", "x", "y"], centre)
            + (_table(["plane", *(f"k{i}" for i in range(nk))], k) if nk else "")
            + "</section>")


def _response_section(profile, c: dict) -> str:
    parts = [f'<section id="response"><h2>{STAGE_TITLES["response"]}</h2>'
             '<p class="sub">Seed eq. 12, g = α·x^γ + β, x = ISO·t/N² relative to the reference setting '
             "(seconds at the reference ISO and f-number).</p>"]
    order = [k for k in ("raw", "processed") if k in profile.response]
    order += [k for k in profile.response if k not in order]
    for kind in order:
        model = profile.response[kind]
        label = "RAW" if kind == "raw" else "JPEG / processed" if kind == "processed" else kind
        parts.append(f"<h3>{_esc(label)}</h3>")
        parts.append(_img(png_bytes(response_figure(model)), f"response curves {kind}",
                          "Left: ROI means (filled: used by the fit; hollow: excluded) and the fit. "
                          "Right: residuals relative to g − β."))
        rows = []
        for name, ch in model.channels.items():
            rate = model.linear_gain_dn_per_s(name) if (kind == "raw" or model.tone) else float("nan")
            rows.append([name, ch.gamma, ch.gamma_unc, ch.alpha, ch.alpha_unc, ch.beta, ch.beta_unc,
                         ch.linearity_error_pct, f"{ch.pearson_r:.7f}", rate, ch.saturation_dn])
        parts.append(_table(["channel", "γ", "u(γ)", "α [DN s^-γ]", "u(α)", "β [DN]", "u(β)", "LE [%]", "r",
                             f"linear gain [{DN_PER_S}]", "saturation [DN]"], rows))
        sat_rows = [[name, ch.saturation_dn, ch.saturation_exposure_s if math.isfinite(ch.saturation_exposure_s)
                     else "not reached", f"{_num(ch.linear_range_dn[0])} – {_num(ch.linear_range_dn[1])}",
                     f"{_num(ch.fitted_exposure_s[0])} – {_num(ch.fitted_exposure_s[1])}"]
                    for name, ch in model.channels.items()]
        parts.append("<h4>Saturation and fitted range</h4>"
                     + _table(["channel", "saturation level [DN]", "reached at exposure [s]", "fitted range [DN]",
                               "fitted exposures [s]"], sat_rows)
                     + '<p class="sub">Frames at or past saturation end the linear range and are not fitted '
                       "(EMVA 1288 saturation point); exposures are relative, in s at the reference setting."
                     + (f" Saturated frames: {_esc(', '.join(model.saturated_files()))}."
                        if model.saturated_files() else "") + "</p>")
        parts.append(f'<p class="sub">dark subtracted: {"yes" if model.dark_subtracted else "no"}; '
                     f"white level {_num(model.white_level_dn)} DN.</p>")
        cm = getattr(model, "colour_matrix", None)
        if cm is not None:
            rows = [[out, *(f"{cm.matrix[i, j]:.5g} ± {cm.matrix_unc[i, j]:.2g}" for j in range(3)), cm.n_frames[i],
                     100 * cm.residual_rms_rel[i]] for i, out in enumerate(("JPEG R", "JPEG G", "JPEG B"))]
            parts.append("<h4>Colour matrix</h4>" + _table(
                ["linearised", "× RAW R", "× RAW G", "× RAW B", "frames", "residual RMS [%]"], rows, left=4)
                + f'<p class="sub">Linearised JPEG = A · RAW (above the black level), fitted on the JPEG twins in '
                f'{_esc(", ".join(Path(f).name for f in cm.sources))}; apply uses A⁻¹.</p>')
        elif kind == "processed":
            parts.append('<p class="sub">No colour matrix (no JPEG twins in the sweep): JPEGs are read with one gain '
                         "per channel, which assumes the camera does not mix its channels.</p>")
    return "".join(parts) + "</section>"


def _spectral_section(profile, c: dict) -> str:
    s = c["spectral_sensitivity"]
    spec = profile.spectral
    peak, eff = s["peak_wavelength_nm"], s["effective_wavelength_nm"]
    planes, bands = (("Y",), ("Y",)) if spec.mono else (_RGB, ("R", "G", "B"))  # a monochrome sensor: Y alone
    summary = _table(["quantity", "unit", *planes], _channel_rows(
        [("peak λ", "nm", peak), ("effective λ", "nm", eff)], planes), left=2)
    values = spec.channels()
    rows = [[f"{wl:g}", *(values[ch][i] if ch in values else None for ch in planes),  # linear RAW: no G1, G2
             *(s[f"{ch}_unc"][i] for ch in bands)]
            for i, wl in enumerate(s["wavelength_nm"])]
    full = ("<details><summary>c(λ) values ("
            f"{len(rows)} wavelengths)</summary>"
            + _table(["λ [nm]", *planes, *(f"u({b})" for b in bands)], rows) + "</details>")
    band = "unknown" if spec.bandwidth_nm is None else f"{spec.bandwidth_nm:g} nm"
    notes = "".join(f"<li>{_esc(n)}</li>" for n in spec.notes)
    fig = _img(png_bytes(spectral_figure(spec)), "spectral sensitivity with uncertainty bands",
               "Left: c(λ) of R, G (mean of G1 and G2) and B with ±1 standard-uncertainty bands, and below "
               "the standard uncertainty u(λ). Right: the two green planes, and their difference with its "
               "±1 σ band.")
    return (f'<section id="spectral_sensitivity"><h2>{STAGE_TITLES["spectral_sensitivity"]}</h2>'
            f'<p class="sub">{_esc(s["mode"])}, units: <code>{_esc(s["units"])}</code>; slit bandwidth {band}; '
            f'{"deconvolved" if spec.deconvolved else "slit-weighted (not deconvolved)"}.</p>'
            f"{_spectral_source_html(s['source'])}{fig}{summary}{full}"
            + (f"<p>Notes:</p><ul>{notes}</ul>" if notes else "") + "</section>")


def _spectral_source_html(src: dict) -> str:
    """Where c(λ) came from and how its absolute scale was set; the reference targets' residuals."""
    where, how = describe_origin(src)
    a = src.get("absolute_scale") or {}
    warn = a.get("consistent") is False
    out = (f'<p id="spectral-source"><b>Source:</b> {_esc(where)}.<br><b>Absolute scale:</b> '
           + (f'<span class="bad">{_esc(how)}</span>' if warn else _esc(how)) + ".</p>")
    if a.get("method") == "reference_targets":
        rows = [[t["name"], ", ".join(t.get("photos") or []),
                 *(f"{100 * t['residual_rel'][p]:+.3g} % (z {t['z'][p]:+.2g})" for p in PLANES)]
                for t in a.get("targets") or []]
        ks = [["k", "", *(f"{a['k'][p]:.6g} ± {a['k_unc'][p]:.2g}" for p in PLANES)]]
        out += ("<p>c<sub>i</sub> = k<sub>i</sub> · c<sub>rel,i</sub> with k<sub>i</sub> = rate<sub>i</sub> / "
                "∫ c<sub>rel,i</sub> L dλ (least squares over the targets); residual = rate / (k P) − 1, z in "
                "units of its standard uncertainty.</p>"
                + _table(["target", "photos", *PLANES], ks + rows, left=2))
    return out


def _emva_section(profile) -> str:
    """The EMVA 1288 summary sheet: operating point, then the figures per plane in the standard's order."""
    sheet = profile.emva
    planes = list(sheet.channels)
    sp = sheet.spatial
    point = [["standard", STANDARD], ["ISO", f"{sheet.iso:g}"]]
    for row in sheet.photon_transfer:
        point.append([f"photon transfer, ISO {row['iso']:g}", f"{row.get('pairs', 0)} frame pairs of the "
                      "linearity series, K fitted up to 70 % of saturation"])
    if sp.get("dsnu_frames"):
        point.append(["DSNU", f"average of {sp['dsnu_frames']} dark frames at {sp['dsnu_exposure_s']:g} s, "
                      "temporal noise / L removed (eq. 36)"])
    if sp.get("prnu_frames"):
        point.append(["PRNU", f"PRNU_1288: the plain average of {sp['prnu_frames']} flats, vignetting included, "
                      "temporal noise / L removed (eq. 36); camcal's PRNU about the vignetting model apart"])
    rows = [[name if i == 0 or name != prev else "", q, unit, *(vals.get(p) for p in planes)]
            for i, ((name, q, unit, vals), prev) in enumerate(zip(sheet_rows(sheet),
                                                                  [None, *(r[0] for r in sheet_rows(sheet))],
                                                                  strict=False))]
    qe = ""
    if sheet.quantum_efficiency:
        q = sheet.quantum_efficiency
        wl = q["wavelength_nm"]
        step = max(1, len(wl) // 12)
        qrows = [[f"{wl[i]:g}", *(None if q["values"].get(p) is None or q["values"][p][i] is None
                                  else 100 * q["values"][p][i] for p in planes)] for i in range(0, len(wl), step)]
        qe = (f"<h3>Quantum efficiency η(λ) (lens included; pixel pitch {q['pixel_pitch_um']:g} µm)</h3>"
              + _table(["λ (nm)", *[f"{p} (%)" for p in planes]], qrows))
    notes = "".join(f"<li>{_esc(n)}</li>" for n in sheet.notes)
    return ('<section id="emva1288"><h2>EMVA 1288 summary</h2>'
            '<p class="sub">Figures as EMVA Standard 1288 release 4.0 defines them (docs/dark.md, docs/flat.md); '
            "K from the mean–variance line of the linearity series' frame pairs.</p>"
            + _table(["operating point", "value"], point, left=2)
            + _table(["section", "quantity", "unit", *planes], rows, left=3) + qe
            + (f"<p>Notes:</p><ul>{notes}</ul>" if notes else "") + "</section>")


def _provenance_section(profile, c: dict) -> str:
    p = profile.provenance
    by_stage = Counter(str(i.get("stage", "?")) if isinstance(i, dict) else "?" for i in p.inputs)
    rows = [["camcal version (profile)", p.camcal_version], ["camcal version (report)", __version__],
            ["created (UTC)", p.created_utc or "unknown"], ["schema version", profile.schema_version],
            ["content SHA-256", profile.content_sha256 or "not saved"],
            ["input files", f"{len(p.inputs)}" + (" (" + ", ".join(f"{k}: {v}" for k, v in by_stage.items()) + ")"
                                                  if by_stage else "")]]
    opts = [[k, v if isinstance(v, str) else json.dumps(v, default=str)] for k, v in sorted(p.options.items())]
    inputs = [[i.get("stage", ""), i.get("file", ""), i.get("sha256", ""), i.get("bytes", "")]
              if isinstance(i, dict) else ["", str(i), "", ""] for i in p.inputs]
    left_out = [[r.get("stage", ""), r.get("file", ""), r.get("reason", "")] for r in p.left_out]
    not_cal = [[r.get("stage", ""), r.get("reason", "")] for r in p.not_calibrated]
    return ('<section id="provenance"><h2>Provenance</h2>'
            + _table(["item", "value"], rows, left=2)
            + (f'<h3 id="left-out">Frames left out ({len(left_out)})</h3>'
               + _table(["stage", "file", "reason"], left_out, left=3) if left_out else
               '<h3 id="left-out">Frames left out</h3><p>none: every frame of the session was used.</p>')
            + ("<h3>Stages not calibrated</h3>" + _table(["stage", "reason"], not_cal, left=2) if not_cal else "")
            + "<h3>Options</h3>" + (_table(["option", "value"], opts, left=2) if opts else "<p>none recorded</p>")
            + (f"<details><summary>input files ({len(inputs)})</summary>"
               + _table(["stage", "file", "SHA-256", "bytes"], inputs, left=3) + "</details>" if inputs else "")
            + "<details><summary>JSON contract (<code>camcal profile show --json</code>)</summary><pre>"
            + _esc(json.dumps(c, indent=2, allow_nan=False, default=str)) + "</pre></details></section>")


_SECTIONS = (("dark", "dark", _dark_section), ("flat", "flat", _flat_section),
             ("response", "response", _response_section),
             ("spectral_sensitivity", "spectral", _spectral_section))


def render_report(profile, progress: Callable[[str, int, int], None] | None = None) -> str:
    """The self-contained HTML report of a profile.

    Parameters
    ----------
    profile : camcal.models.profile.CalibrationProfile
    progress : optional callback ``(section, done, total)`` called as each section is rendered.

    Returns
    -------
    str
        A complete HTML5 document: inline CSS, plots as base64 PNG ``data:`` URIs, no scripts and no
        external resources. Pure: the same profile gives the same text (no "generated at" time).
    """

    c = contract(profile)
    cam = c["camera"]
    stages = profile.stages()
    title = f"camcal calibration report — {cam['make'] or '?'} {cam['model'] or '?'}"
    bias_only = profile.dark is not None and getattr(profile.dark, "dark_current_dn_per_s", 0) is None

    def state(k: str, done: bool) -> tuple[str, str]:
        if k == "dark" and done and bias_only:  # bias and read noise measured, the dark current is not
            return "no", "bias only; dark current not calibrated"
        return ("ok", "calibrated") if done else ("no", "not calibrated")

    badges = "".join(f'<span class="{state(k, done)[0]}">{_esc(STAGE_TITLES[k])}: {_esc(state(k, done)[1])}</span>'
                     for k, done in stages.items())
    head_rows = [["make", cam["make"] or "unknown"], ["model", cam["model"] or "unknown"],
                 ["serial", cam["serial"] or "unknown"], ["CFA pattern", cam["cfa_pattern"] or "none"],
                 ["image size", f"{cam['width']} × {cam['height']} px"],
                 ["reference setting", f"ISO {profile.reference_iso:g}, f/{profile.reference_f_number:g}"
                  if profile.reference_iso is not None and profile.reference_f_number is not None
                  else "none (no stage normalised exposure)"],
                 ["content SHA-256", profile.content_sha256 or "not saved"]]
    body = [f"<h1>{_esc(title)}</h1>",
            f'<p class="sub">profile created {_esc(c["provenance"]["created_utc"] or "at an unknown time")} '
            f"with camcal {_esc(c['provenance']['camcal_version'])}; report by camcal {_esc(__version__)}.</p>",
            "<nav>" + "".join(f'<a href="#{k}">{_esc(STAGE_TITLES[k])}</a>' for k in stages)
            + ('<a href="#emva1288">EMVA 1288</a>' if getattr(profile, "emva", None) is not None else "")
            + '<a href="#provenance">Provenance</a></nav>',
            f'<div class="stages">{badges}</div>',
            _table(["camera", "value"], head_rows, left=2)]
    total = len(_SECTIONS) + 1
    for done, (key, attr, section) in enumerate(_SECTIONS):
        if progress is not None:
            progress(STAGE_TITLES[key], done, total)
        present = getattr(profile, attr) is not None and (key != "response" or bool(profile.response))
        body.append(section(profile, c) if present else _missing(key, profile))
    if getattr(profile, "emva", None) is not None:
        body.append(_emva_section(profile))
    if progress is not None:
        progress("provenance", total - 1, total)
    body.append(_provenance_section(profile, c))
    if progress is not None:
        progress("done", total, total)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<meta name=\"generator\" content=\"camcal {_esc(__version__)}\">"
            f"<title>{_esc(title)}</title><style>{CSS}</style></head>\n<body><main>\n"
            + "\n".join(body) + "\n</main></body></html>\n")


def write_report(profile, path: str | Path, progress: Callable[[str, int, int], None] | None = None) -> Path:
    """Render :func:`render_report` and write it to ``path`` atomically (UTF-8); returns the path.

    Raises
    ------
    CamcalError
        When ``path`` is a folder or cannot be written (one line naming the path).
    """
    path = Path(path)
    if path.is_dir():
        raise CamcalError("is a folder; give the report file name, e.g. report.html", path)
    text = render_report(profile, progress=progress)
    try:
        return atomic_write_text(path, text)
    except OSError as exc:
        raise CamcalError(f"cannot write the report: {exc.strerror or exc}", path) from None

"""The EMVA 1288 data sheet of a measurement: the ``emva1288`` JSON section and one self-contained HTML page.

:func:`sheet_from_figures` puts the figures of :func:`camcal.calibrate.emva_standard.evaluate` into an
:class:`camcal.models.emva.EmvaSheet` (the layout of a profile's ``emva1288`` section, one channel per plane:
``Y`` for a monochrome sensor). :func:`render_sheet` lays the page out like the standard's summary sheet
(release 4.0 "Linear" §9: operating point, then sensitivity, noise, saturation, dynamic range, linearity, dark
current and non-uniformity, each with its uncertainty) followed by its plots (:mod:`camcal.emva1288.plots`),
encoded as PNG and embedded as ``data:`` URIs (no external resource). Pure: the same inputs give the same page.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Callable, Sequence

from camcal import __version__
from camcal.calibrate.emva_standard import StandardFigures
from camcal.emva1288 import plots as ep
from camcal.models.emva import STANDARD, EmvaSheet
from camcal.report.plots import png_bytes
from camcal.units import DN, DN_PER_ELECTRON, DN_PER_S, ELECTRONS, ELECTRONS_PER_DN, ELECTRONS_PER_S

MONOCHROME = "Y"
"""The name of the one channel of a monochrome sensor."""

CSS = """
body{font-family:-apple-system,"Segoe UI",Helvetica,Arial,sans-serif;margin:0;background:#f4f5f7;color:#1d1f23}
main{max-width:1120px;margin:0 auto;padding:16px 24px 48px;background:#fff}
h1{font-size:1.6em;margin:.4em 0 .1em}h2{font-size:1.25em;border-bottom:2px solid #dde1e6;padding-bottom:4px;
margin-top:1.6em}.sub{color:#5a6270;margin:0 0 1em}
table{border-collapse:collapse;margin:.5em 0 1em;font-size:.85em}
th,td{border:1px solid #d6dae0;padding:2px 8px;text-align:right;vertical-align:top}
th{background:#eef1f5}td.l,th.l{text-align:left}td.sec{background:#f7f8fa;font-weight:600;text-align:left}
.grid{display:grid;grid-template-columns:1fr 1fr;gap:8px}.wide{grid-column:1 / span 2}
figure{margin:.6em 0 1.2em}figure img{max-width:100%;height:auto;border:1px solid #e3e6ea}
figcaption{font-size:.85em;color:#4a5260;margin-top:4px}
"""

#: The summary rows in the standard's order: (section, quantity, symbol, key, uncertainty key, unit).
SUMMARY_ROWS: tuple[tuple[str, str, str, str, str | None, str], ...] = (
    ("sensitivity", "quantum efficiency", "η", "quantum_efficiency_pct", "quantum_efficiency_unc_pct", "%"),
    ("sensitivity", "overall system gain", "K", "K_dn_per_e", "K_unc_dn_per_e", DN_PER_ELECTRON),
    ("sensitivity", "inverse system gain", "1/K", "inverse_K_e_per_dn", None, ELECTRONS_PER_DN),
    ("noise", "temporal dark noise", "σ_d", "read_noise_e", "read_noise_unc_e", ELECTRONS),
    ("noise", "temporal dark noise", "σ_y.dark", "dark_noise_dn", None, DN),
    ("noise", "temporal dark noise, quantisation removed", "σ_d·K", "read_noise_dn", None, DN),
    ("saturation", "signal-to-noise ratio", "SNR_max", "snr_max", "snr_max_unc", ""),
    ("saturation", "signal-to-noise ratio", "SNR_max", "snr_max_db", None, "dB"),
    ("saturation", "signal-to-noise ratio", "SNR_max", "snr_max_bits", None, "bit"),
    ("saturation", "absolute sensitivity threshold", "μ_p.min", "threshold_photons", None, "photons"),
    ("saturation", "absolute sensitivity threshold", "μ_e.min", "threshold_e", None, ELECTRONS),
    ("saturation", "saturation capacity", "μ_p.sat", "saturation_photons", None, "photons"),
    ("saturation", "saturation capacity", "μ_e.sat", "saturation_e", "saturation_unc_e", ELECTRONS),
    ("saturation", "saturation signal above dark", "μ_y.sat − μ_y.dark", "saturation_dn", None, DN),
    ("saturation", "dynamic range", "DR", "dynamic_range", None, ""),
    ("saturation", "dynamic range", "DR", "dynamic_range_db", None, "dB"),
    ("linearity", "linearity error, minimum", "LE_min", "linearity_error_min_pct", None, "%"),
    ("linearity", "linearity error, maximum", "LE_max", "linearity_error_max_pct", None, "%"),
    ("linearity", "linearity error (release 3.0)", "LE", "linearity_error_pct", None, "%"),
    ("dark current", "dark current, from the mean", "μ_I", "dark_current_e_per_s", None, ELECTRONS_PER_S),
    ("dark current", "dark current, from the mean", "μ_I", "dark_current_dn_per_s", None, DN_PER_S),
    ("dark current", "dark current, from the variance", "μ_I.var", "dark_current_from_variance_e_per_s", None,
     ELECTRONS_PER_S),
    ("non-uniformity", "DSNU₁₂₈₈, total", "DSNU₁₂₈₈", "dsnu_e", None, ELECTRONS),
    ("non-uniformity", "DSNU₁₂₈₈, total", "s_y.dark", "dsnu_dn", "dsnu_unc_dn", DN),
    ("non-uniformity", "DSNU₁₂₈₈, row part", "DSNU_row", "dsnu_row_e", None, ELECTRONS),
    ("non-uniformity", "DSNU₁₂₈₈, column part", "DSNU_col", "dsnu_col_e", None, ELECTRONS),
    ("non-uniformity", "DSNU₁₂₈₈, pixel part", "DSNU_pixel", "dsnu_pixel_e", None, ELECTRONS),
    ("non-uniformity", "PRNU₁₂₈₈, total", "PRNU₁₂₈₈", "prnu_pct", "prnu_unc_pct", "%"),
    ("non-uniformity", "PRNU₁₂₈₈, row part", "PRNU_row", "prnu_row_pct", None, "%"),
    ("non-uniformity", "PRNU₁₂₈₈, column part", "PRNU_col", "prnu_col_pct", None, "%"),
    ("non-uniformity", "PRNU₁₂₈₈, pixel part", "PRNU_pixel", "prnu_pixel_pct", None, "%"),
)


def sheet_from_figures(result: StandardFigures, *, operating_point: dict, channel: str = MONOCHROME,
                       iso: float | None = None, notes: Sequence[str] = ()) -> EmvaSheet:
    """The :class:`EmvaSheet` of one channel's figures (``operating_point`` goes to its ``spatial`` record)."""
    f = dict(result.figures)
    f["K_source"] = "photon transfer (EMVA 1288 pairs)"
    ptc = {"iso": iso, "pairs": int(f.get("ptc_points") or 0), "channels": {channel: {
        "K_dn_per_e": f.get("K_dn_per_e"), "K_unc_dn_per_e": f.get("K_unc_dn_per_e"),
        "fit_range_dn": [0.0, f.get("ptc_fit_max_dn")], "n_fit": int(f.get("ptc_fit_points") or 0),
        "dark_variance_dn2": None if f.get("dark_noise_dn") is None else f["dark_noise_dn"] ** 2,
        "intercept_fitted": False, "saturation_dn": f.get("saturation_dn"),
        "saturation_exposure_s": f.get("saturation_exposure_s")}}}
    qe = None
    return EmvaSheet(iso, {channel: f}, (ptc,), dict(operating_point), qe, (*result.notes, *notes))


def _esc(v) -> str:
    return html.escape(str(v), quote=True)


def _fmt(v, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    if isinstance(v, int | float):
        return f"{v:.{digits}g}"
    return _esc(v)


def _img(png: bytes, alt: str, caption: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{_esc(alt)}">'
            f"<figcaption>{_esc(caption)}</figcaption></figure>")


def summary_table(figures: dict) -> str:
    """The summary table (HTML) of one channel's figures, in :data:`SUMMARY_ROWS` order."""
    out = ['<table><thead><tr><th class="l">quantity</th><th class="l">symbol</th><th>value</th>'
           '<th>uncertainty</th><th class="l">unit</th></tr></thead><tbody>']
    section = None
    for sec, name, sym, key, ukey, unit in SUMMARY_ROWS:
        if sec != section:
            out.append(f'<tr><td class="sec" colspan="5">{_esc(sec)}</td></tr>')
            section = sec
        u = figures.get(ukey) if ukey else None
        out.append(f'<tr><td class="l">{_esc(name)}</td><td class="l">{_esc(sym)}</td><td>{_fmt(figures.get(key))}'
                   f'</td><td>{"" if ukey is None else _fmt(u, 2)}</td><td class="l">{_esc(unit)}</td></tr>')
    out.append("</tbody></table>")
    return "".join(out)


def render_sheet(sheet: EmvaSheet, result: StandardFigures, title: str,
                 progress: Callable[[str, int, int], None] | None = None) -> str:
    """The data sheet page (HTML text) of a one-channel sheet and the curves of ``result``."""
    f = next(iter(sheet.channels.values()))
    c = result.curves
    plots: list[tuple[str, Callable, str]] = [
        ("photon transfer", lambda: ep.photon_transfer_figure(c, f),
         "Temporal variance against mean signal, dark values removed; K is the slope of the filled points "
         "(up to 70 % of saturation)."),
        ("SNR", lambda: ep.snr_figure(c, f), "Signal-to-noise ratio against irradiation, with the linear model."),
        ("linearity", lambda: ep.linearity_figure(c, f),
         "Mean signal against irradiation and its relative deviation from the linearity fit (5–95 % of "
         "saturation)."),
    ]
    if "dsnu_spectrogram_h" in c:
        plots.append(("DSNU spectrogram", lambda: ep.spectrogram_figure(c, f, "dsnu"),
                      "Spectrograms of the averaged dark image, DN; dashed: the temporal noise left in the average."))
    if "prnu_spectrogram_h" in c:
        plots.append(("PRNU spectrogram", lambda: ep.spectrogram_figure(c, f, "prnu"),
                      "Spectrograms of the averaged bright image minus dark, % of its mean."))
    if "dsnu_image_dn" in c:
        plots.append(("histograms", lambda: ep.histogram_figure(c, f),
                      "Histograms of the averaged dark image (DN) and of the 5×5 high-pass-filtered PRNU image (%)."))
    plots.append(("dark current", lambda: ep.dark_current_figure(c, f),
                  "Dark pairs' mean and variance against exposure time, with their lines (dark current)."))
    figs = []
    for i, (name, make, caption) in enumerate(plots):
        if progress is not None:
            progress("plots", i, len(plots))
        cls = "" if i < 2 else ' class="wide"'
        figs.append(f"<div{cls}>{_img(png_bytes(make()), name, caption)}</div>")
    point = "".join(f'<tr><td class="l">{_esc(k)}</td><td class="l">{_fmt(v, 6)}</td></tr>'
                    for k, v in sheet.spatial.items())
    notes = "".join(f"<li>{_esc(n)}</li>" for n in sheet.notes)
    return ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>EMVA 1288 data sheet: {_esc(title)}</title><style>{CSS}</style></head><body><main>"
            f"<h1>EMVA 1288 data sheet</h1><p class=\"sub\">{_esc(title)} · figures as {_esc(STANDARD)} defines "
            f"them · camcal {_esc(__version__)}</p>"
            '<section id="summary"><h2>Summary</h2><div class="grid"><div>'
            f"<table><thead><tr><th class=\"l\">operating point</th><th class=\"l\">value</th></tr></thead>"
            f"<tbody>{point}</tbody></table></div><div>{summary_table(f)}</div></div></section>"
            f'<section id="plots"><h2>Plots</h2><div class="grid">{"".join(figs)}</div></section>'
            + (f'<section id="notes"><h2>Notes</h2><ul>{notes}</ul></section>' if notes else "")
            + "</main></body></html>\n")

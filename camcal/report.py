"""The calibration report: one self-contained HTML page for a :class:`camcal.profile.CalibrationProfile`.

The page has no external resources: CSS is inline and every plot is a PNG rendered by matplotlib's
Agg backend and embedded as a ``data:image/png;base64`` URI, so it can be mailed, archived next to
the profile, or opened offline. Sections, in pipeline order:

* **Dark current** (seed eq. 12, β term; EMVA 1288 §8): histogram of the per-pixel dark current
  β (DN s^-1 at the dark frames' ISO) per CFA plane with the hot pixels drawn separately, and a map
  of β with the hot pixels circled.
* **Vignetting** (DNG ``OpcodeList3`` WarpRectilinear/FixVignetteRadial model
  g = 1 + k0 r² + k1 r⁴ + k2 r⁶ + k3 r⁸ + k4 r¹⁰): relative illumination g against the normalised
  radius r per plane, and a gain map with the optical centres.
* **Response** (seed eq. 12, g = α·x^γ + β): the measured ROI means (``ResponseModel.points``),
  filled when used by the fit and hollow when excluded (saturated or compressed), with the fit,
  and the relative residuals; one figure per kind (RAW, processed/JPEG).
* **Spectral sensitivity** c(λ) (seed §3.1): R, G (mean of G1 and G2), B with ±1 standard
  uncertainty bands, and G1 against G2.
* Tables of the numbers of the JSON contract (:func:`camcal.profile.contract`), the contract itself,
  and the provenance (camcal version, creation date, input files, options, content hash).

A stage that was not calibrated gets a short "not calibrated" note instead of its section.
:func:`render_report` is pure (the same profile gives the same bytes); :func:`write_report`
writes the page atomically.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from camcal import __version__
from camcal.atomic import atomic_write_text
from camcal.errors import CamcalError
from camcal.frame import PLANES
from camcal.spectral import describe_origin

COLOURS = {"R": "#d62728", "G": "#2ca02c", "G1": "#2ca02c", "G2": "#17632a", "B": "#1f77b4"}
"""Plot colour per channel."""

HOT_COLOUR = "#ff7f0e"
"""Colour of hot pixels in the dark plots."""

DPI = 100
"""Resolution of the embedded PNGs (dots per inch of the matplotlib figure size)."""

MAX_MAP_PX = 600
"""Maps wider or taller than this (plane pixels) are block-averaged for display."""

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


def _figure_png(fig) -> bytes:
    """PNG bytes of a matplotlib figure (no timestamp metadata, so the output is reproducible)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return buf.getvalue()


def _img(png: bytes, alt: str, caption: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{_esc(alt)}">'
            f"<figcaption>{caption}</figcaption></figure>")


def _new_figure(width_in: float, height_in: float):
    """A matplotlib Figure on the Agg canvas (no pyplot state, thread-safe, no display needed)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _display_map(a: np.ndarray) -> tuple[np.ndarray, int]:
    """Block-mean ``a`` (2-D) down to at most :data:`MAX_MAP_PX` per side; returns (map, factor)."""
    h, w = a.shape
    f = max(1, math.ceil(max(h, w) / MAX_MAP_PX))
    if f == 1:
        return a, 1
    hh, ww = h // f, w // f
    return np.nanmean(a[: hh * f, : ww * f].reshape(hh, f, ww, f), axis=(1, 3)), f


_SESSION_FOLDER = {"dark": "bias/ and dark/", "flat": "flat/", "response": "linearity/",
                   "spectral_sensitivity": "sweep/"}


def _missing(key: str) -> str:
    return (f'<section id="{key}"><h2>{_esc(STAGE_TITLES[key])}</h2>'
            f'<p class="missing">not calibrated: this profile has no {_esc(STAGE_TITLES[key].lower())} stage. '
            f"<code>camcal calibrate</code> adds it when the session has {_esc(_SESSION_FOLDER[key])} "
            f"folder{'s' if key == 'dark' else ''}.</p></section>")


# ---------------------------------------------------------------------------------------------
# plots
# ---------------------------------------------------------------------------------------------
def _dark_bins(normal: np.ndarray, everything: np.ndarray) -> tuple[np.ndarray, float | None]:
    """Histogram bins for β: linear over the bulk of the pixels, logarithmic out to the hottest pixel.

    Returns (bin edges, symlog linear threshold or None when one linear scale suffices). The bulk is
    the 0.05–99.95 percentile range of the non-hot pixels; hot pixels are often 10–1000 × the median.
    """
    lo_b, hi_b = (np.percentile(normal, [0.05, 99.95]) if normal.size else (0.0, 1.0))
    lo = float(min(lo_b, everything.min())) if everything.size else float(lo_b)
    hi = float(everything.max()) if everything.size else float(hi_b)
    span = max(float(hi_b - lo_b), 1e-12)
    lo_edge = min(lo, float(lo_b) - 0.1 * span)
    lin_hi = float(hi_b) + 0.1 * span
    thresh = max(abs(lin_hi), abs(lo_edge), 1e-12)
    if hi <= 3.0 * thresh:
        return np.linspace(lo_edge, max(hi, lin_hi), 120), None
    linear = np.linspace(lo_edge, thresh, 100)
    # logarithmic bins whose first width matches the linear ones (no jump in counts per bin at the joint)
    ratio = 1.0 + (linear[1] - linear[0]) / thresh
    n_log = int(min(400, max(10, math.ceil(math.log(hi * 1.001 / thresh) / math.log(ratio)))))
    logpart = np.geomspace(thresh, hi * 1.001, n_log + 1)[1:]
    return np.concatenate([linear, logpart]), thresh


def plot_dark(dark) -> bytes:
    """Histogram of β per plane (hot pixels separately) and a β map with hot pixels circled; PNG bytes.

    Parameters
    ----------
    dark : camcal.dark.DarkModel
        β = ``dark_current_dn_per_s`` (4, h, w) in DN s^-1; hot pixels are bit 1 of ``defects``.
    """
    from matplotlib.colors import Normalize

    from camcal.dark import HOT

    beta = np.asarray(dark.dark_current_dn_per_s, np.float64)
    hot = (np.asarray(dark.defects) & HOT) != 0
    fig = _new_figure(11.0, 4.4)
    ax1, ax2 = fig.subplots(1, 2, width_ratios=[1.05, 1.0])
    finite = beta[np.isfinite(beta)]
    normal = beta[np.isfinite(beta) & ~hot]
    bins, linthresh = _dark_bins(normal if normal.size else finite, finite)
    styles = {"R": "-", "G1": "-", "G2": "--", "B": "-."}
    for i, name in enumerate(PLANES[: beta.shape[0]]):
        vals = beta[i][np.isfinite(beta[i]) & ~hot[i]]
        counts, _ = np.histogram(vals, bins=bins)
        ax1.stairs(np.where(counts > 0, counts, np.nan), bins, lw=1.3, ls=styles.get(name, "-"),
                   color=COLOURS.get(name, "k"), label=f"{name} (median {np.median(vals):.3g})" if vals.size else name)
    hot_vals = beta[hot & np.isfinite(beta)]
    if hot_vals.size:
        counts, _ = np.histogram(hot_vals, bins=bins)
        ax1.stairs(counts, bins, fill=True, color=HOT_COLOUR, alpha=0.85,
                   label=f"hot pixels ({hot_vals.size}, all planes)")
        # a rug along the bottom: a handful of hot pixels in narrow bins would be hard to see
        ax1.plot(hot_vals, np.full(hot_vals.size, 0.04), "|", ms=14, mew=1.2, color=HOT_COLOUR,
                 transform=ax1.get_xaxis_transform())
    if linthresh is not None:
        ax1.set_xscale("symlog", linthresh=linthresh, linscale=2.0)
        ax1.axvline(linthresh, color="0.6", lw=0.8, ls=":")
    ax1.set_yscale("log")
    ax1.set_xlabel(f"dark current β [DN/s at ISO {dark.iso:g}]")
    ax1.set_ylabel("pixels per bin")
    ax1.set_title("β per pixel and plane")
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=8)
    mean_map = np.nanmean(beta, axis=0)
    shown, factor = _display_map(mean_map)
    good = mean_map[np.isfinite(mean_map) & ~hot.any(axis=0)]
    vmin, vmax = np.percentile(good, [1, 99]) if good.size else (0.0, 1.0)
    im = ax2.imshow(shown, cmap="magma", norm=Normalize(float(vmin), float(max(vmax, vmin + 1e-9))),
                    interpolation="nearest", extent=(-0.5, mean_map.shape[1] - 0.5, mean_map.shape[0] - 0.5, -0.5))
    _, ys, xs = np.nonzero(hot)
    if xs.size:
        size = 42 if xs.size <= 100 else 12 if xs.size <= 1000 else 3
        ax2.scatter(xs, ys, s=size, facecolors="none", edgecolors="#00e5ff", linewidths=1.0 if size > 3 else 0.6,
                    label=f"hot pixel ({xs.size})")
        ax2.legend(fontsize=8, loc="upper right")
    ax2.set_title("β map, mean of the planes" + (f" ({factor}×{factor} blocks)" if factor > 1 else "")
                  + ", colours 1–99 %")
    ax2.set_xlabel("x [plane px]")
    ax2.set_ylabel("y [plane px]")
    fig.colorbar(im, ax=ax2, shrink=0.85, label="β [DN/s]")
    return _figure_png(fig)


def plot_flat(flat) -> bytes:
    """Relative illumination against radius per plane and a gain map with optical centres; PNG bytes.

    Parameters
    ----------
    flat : camcal.flat.FlatModel
        The radial model g(r) = 1 + Σ k_i r^(2i+2) (r normalised to the farthest corner) is drawn
        as a curve; with a 2-D model the binned median of the active gain map is drawn instead.
    """
    from camcal.flat import radial_gain

    gain = flat.gain()
    geom = flat.geometry
    h, w = flat.shape
    stride = max(1, math.ceil(math.sqrt(h * w / 4000)))  # ~4000 samples per plane for the cloud
    yy, xx = np.mgrid[0:h:stride, 0:w:stride].astype(np.float64)
    fig = _new_figure(11.0, 4.4)
    ax1, ax2 = fig.subplots(1, 2, width_ratios=[1.05, 1.0])
    r_grid = np.linspace(0.0, 1.0, 200)
    corner = flat.corner_gain()
    for i, name in enumerate(flat.channels):
        col = COLOURS.get(name, "k")
        cx, cy = flat.centre_px[name]
        r = np.sqrt(geom.r2(name, xx, yy, cx, cy)).ravel()
        g = gain[i, ::stride, ::stride].ravel()
        # a cloud of the active model over the plane (subsampled), then its curve
        ax1.plot(r, g, ".", ms=1.5, color=col, alpha=0.15)
        if flat.kind == "radial":
            ax1.plot(r_grid, radial_gain(r_grid**2, flat.k[name]), color=col, lw=1.6,
                     label=f"{name} (corner {corner[name]:.3f})")
        else:
            edges = np.linspace(0.0, max(float(r.max()), 1e-9), 41)
            idx = np.clip(np.digitize(r, edges) - 1, 0, 39)
            med = np.array([np.median(g[idx == k]) if np.any(idx == k) else np.nan for k in range(40)])
            ax1.plot(0.5 * (edges[1:] + edges[:-1]), med, color=col, lw=1.6,
                     label=f"{name} (corner {corner[name]:.3f})")
    ax1.set_xlabel("r (distance from optical centre / distance to farthest corner)")
    ax1.set_ylabel("relative illumination g (1 at optical centre)")
    ax1.set_title(f"vignetting, {flat.kind} model")
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=8)
    gi = flat.channels.index("G1") if "G1" in flat.channels else (1 if len(flat.channels) > 1 else 0)
    shown, factor = _display_map(gain[gi].astype(np.float64))
    im = ax2.imshow(shown, cmap="viridis", interpolation="nearest", extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    for name in flat.channels:
        cx, cy = flat.centre_px[name]
        ax2.plot(cx, cy, "+", color=COLOURS.get(name, "w"), ms=12, mew=1.6, label=f"centre {name}")
    ax2.legend(fontsize=7, loc="lower right")
    ax2.set_title(f"gain map, plane {flat.channels[gi]}; + optical centres")
    ax2.set_xlabel("x [plane px]")
    ax2.set_ylabel("y [plane px]")
    fig.colorbar(im, ax=ax2, shrink=0.85, label="g")
    return _figure_png(fig)


def plot_response(model) -> bytes:
    """Measured points and the eq. 12 fit per channel (log–log), and relative residuals; PNG bytes.

    Parameters
    ----------
    model : camcal.response.ResponseModel
        ``points[ch]`` holds ``x_s`` (relative exposure, s at the reference setting), ``mean_dn`` and
        ``used``; the fit is ``g = α x^γ + β`` (seed eq. 12).
    """
    fig = _new_figure(11.0, 4.6)
    ax1, ax2 = fig.subplots(1, 2, width_ratios=[1.15, 1.0])
    any_points = False
    fitted_residuals: list[np.ndarray] = []
    for name, ch in model.channels.items():
        col = COLOURS.get(name, "k")
        pts = model.points.get(name) or {}
        x = np.asarray(pts.get("x_s", []), float)
        g = np.asarray(pts.get("mean_dn", []), float)
        used = np.asarray(pts.get("used", [True] * len(x)), bool)
        if not len(x):
            continue
        any_points = True
        ok = x > 0
        xx = np.geomspace(x[ok].min(), x[ok].max(), 200) if ok.any() else x
        label = f"{name}: γ={ch.gamma:.4f}, β={ch.beta:.4g} DN"
        ax1.plot(xx * 1e3, ch.predict(xx), "-", color=col, lw=1.2, alpha=0.8, label=label)
        ax1.plot(x[used] * 1e3, g[used], "o", color=col, ms=4)
        ax1.plot(x[~used] * 1e3, g[~used], "o", mfc="none", color=col, ms=6)
        pred = ch.predict(x)
        signal = pred - ch.beta
        rel = 100.0 * (g - pred) / np.where(np.abs(signal) > 0, signal, np.nan)
        ax2.plot(x[used] * 1e3, rel[used], "o-", color=col, ms=3, lw=0.8, label=name)
        fitted_residuals.append(rel[used])
        ax2.plot(x[~used] * 1e3, rel[~used], "o", mfc="none", color=col, ms=5)
        ax1.axhline(ch.saturation_dn, color=col, ls=":", lw=0.8)
    if any_points:
        ax1.set_xscale("log")
        ax1.set_yscale("log")
        ax2.set_xscale("log")
    ax1.plot([], [], "o", mfc="none", color="0.4", label="excluded (saturated/compressed)")
    ax1.set_xlabel(f"relative exposure x [ms at ISO {model.reference_iso:g}, f/{model.reference_f_number:g}]")
    ax1.set_ylabel("ROI mean g [DN]")
    ax1.set_title(f"{model.kind}: data and fit g = α·x^γ + β (dotted: saturation)")
    ax1.grid(alpha=0.3, which="both")
    ax1.legend(fontsize=7, loc="upper left")
    ax2.axhline(0.0, color="0.5", lw=0.8)
    finite = np.concatenate(fitted_residuals) if fitted_residuals else np.array([])
    finite = finite[np.isfinite(finite)]
    lim = max(1.0, 1.3 * float(np.max(np.abs(finite)))) if finite.size else 1.0
    ax2.set_ylim(-lim, lim)
    ax2.set_xlabel("relative exposure x [ms]")
    ax2.set_ylabel("residual [% of g − β]")
    ax2.set_title("residuals (hollow: excluded, may be off scale)")
    ax2.grid(alpha=0.3, which="both")
    ax2.legend(fontsize=8)
    return _figure_png(fig)


def plot_spectral(spec) -> bytes:
    """c(λ) for R, G, B with ±1 σ bands and G1 against G2, each above its uncertainty panel; PNG bytes.

    Parameters
    ----------
    spec : camcal.spectral.SpectralSensitivity
        Values and standard uncertainties per plane (seed §3.1); G is the mean of G1 and G2 and
        u(G) = ½·√(u(G1)² + u(G2)²).

    Notes
    -----
    Typical uncertainties are below 1 % of the peak, too thin to see as bands at full scale, so the
    lower panels show u(λ) itself (left) and G2 − G1 with its ±1 σ band (right: the greens agree where
    the band covers 0).
    """
    wl = np.asarray(spec.wavelength_nm, float)
    rgb, unc = spec.rgb(), spec.rgb_uncertainty()
    fig = _new_figure(11.0, 5.8)
    (ax1, ax2), (ax3, ax4) = fig.subplots(2, 2, sharex=True, height_ratios=[2.6, 1.0])
    for name in ("R", "G", "B"):
        v, u = np.asarray(rgb[name], float), np.asarray(unc[name], float)
        ax1.fill_between(wl, v - u, v + u, color=COLOURS[name], alpha=0.3, lw=0)
        ax1.plot(wl, v, "-", color=COLOURS[name], lw=1.4, marker=".", ms=3, label=name)
        ax3.plot(wl, u, "-", color=COLOURS[name], lw=1.2, label=f"u({name})")
    # linear RAW has one green plane: the lower-right comparison of the two greens is then empty (G − G)
    gk1, gk2 = ("G1", "G2") if "G1" in spec.values else ("G", "G")
    g1, g2 = np.asarray(spec.values[gk1], float), np.asarray(spec.values[gk2], float)
    u1, u2 = np.asarray(spec.uncertainty[gk1], float), np.asarray(spec.uncertainty[gk2], float)
    for name, v, u in (("G1", g1, u1), ("G2", g2, u2)):
        ax2.fill_between(wl, v - u, v + u, color=COLOURS[name], alpha=0.3, lw=0)
        ax2.plot(wl, v, "-" if name == "G1" else "--", color=COLOURS[name], lw=1.3, label=name)
    diff, u_diff = g2 - g1, np.hypot(u1, u2)
    ax4.fill_between(wl, diff - u_diff, diff + u_diff, color=COLOURS["G2"], alpha=0.3, lw=0, label="±1 σ")
    ax4.plot(wl, diff, "-", color=COLOURS["G2"], lw=1.2, label="G2 − G1")
    ax4.axhline(0.0, color="0.5", lw=0.8)
    unit = "rel." if spec.mode == "relative" else "DN s⁻¹ per W m⁻² sr⁻¹ nm⁻¹"
    ax1.set_title("c(λ): R, G (mean of G1, G2), B; bands ±1 σ")
    ax2.set_title("the two green planes G1, G2 (±1 σ)")
    ax1.set_ylabel(f"c(λ) [{unit}]", fontsize=8)
    ax2.set_ylabel(f"c(λ) [{unit}]", fontsize=8)
    ax3.set_ylabel("u(λ)", fontsize=8)
    ax4.set_ylabel("G2 − G1", fontsize=8)
    for ax in (ax1, ax2, ax3, ax4):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncols=3 if ax in (ax3, ax4) else 1)
    for ax in (ax3, ax4):
        ax.set_xlabel("wavelength λ [nm]")
    return _figure_png(fig)


# ---------------------------------------------------------------------------------------------
# sections
# ---------------------------------------------------------------------------------------------
_RGB = ("R", "G", "B", "G1", "G2")


def _dark_section(profile, c: dict) -> str:
    d = c["dark"]
    rows = _channel_rows([
        ("bias", "DN", d["bias_dn"]),
        ("dark current β", "DN/s", d["dark_current_dn_per_s"]),
        ("β uncertainty", "DN/s", d["dark_current_unc_dn_per_s"]),
        ("read noise", "DN", d["read_noise_dn"]),
        ("DSNU of bias", "DN", d["dsnu_bias_dn"]),
        ("DSNU of β", "DN/s", d["dsnu_dark_current_dn_per_s"]),
    ], _RGB)
    defects = _table(["defects", "count"], [["hot", d["hot_pixel_count"]], ["dead", d["dead_pixel_count"]],
                                             ["noisy", d["noisy_pixel_count"]]])
    t = d.get("temperature_c")
    sub = (f'<p class="sub">ISO {_num(d["iso"])}, '
           f"{'temperature ' + _num(t) + ' °C' if t is not None else 'temperature unknown'}; "
           f"dark exposures {_num(list(profile.dark.exposure_times_s))} s.</p>")
    fig = _img(plot_dark(profile.dark), "dark current histogram and map",
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
    fig = _img(plot_flat(profile.flat), "vignetting: gain against radius and gain map",
               "Left: relative illumination g against normalised radius per plane (curves: the fitted model; "
               "dots: the model over the plane). Right: gain map with the optical centres.")
    return (f'<section id="flat"><h2>{STAGE_TITLES["flat"]}</h2>'
            f'<p class="sub">model {_esc(f["model"])}; gain = 1 at the optical centre.</p>{fig}'
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
        parts.append(_img(plot_response(model), f"response curves {kind}",
                          "Left: ROI means (filled: used by the fit; hollow: excluded) and the fit. "
                          "Right: residuals relative to g − β."))
        rows = []
        for name, ch in model.channels.items():
            rate = model.linear_gain_dn_per_s(name) if (kind == "raw" or model.tone) else float("nan")
            rows.append([name, ch.gamma, ch.gamma_unc, ch.alpha, ch.alpha_unc, ch.beta, ch.beta_unc,
                         ch.linearity_error_pct, f"{ch.pearson_r:.7f}", rate, ch.saturation_dn])
        parts.append(_table(["channel", "γ", "u(γ)", "α [DN s^-γ]", "u(α)", "β [DN]", "u(β)", "LE [%]", "r",
                             "linear gain [DN/s]", "saturation [DN]"], rows))
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
    summary = _table(["quantity", "unit", *_RGB], _channel_rows(
        [("peak λ", "nm", peak), ("effective λ", "nm", eff)], _RGB), left=2)
    values = spec.channels()
    rows = [[f"{wl:g}", *(values[ch][i] if ch in values else None for ch in _RGB),  # linear RAW: no G1, G2
             *(s[f"{ch}_unc"][i] for ch in ("R", "G", "B"))]
            for i, wl in enumerate(s["wavelength_nm"])]
    full = ("<details><summary>c(λ) values ("
            f"{len(rows)} wavelengths)</summary>"
            + _table(["λ [nm]", *_RGB, "u(R)", "u(G)", "u(B)"], rows) + "</details>")
    band = "unknown" if spec.bandwidth_nm is None else f"{spec.bandwidth_nm:g} nm"
    notes = "".join(f"<li>{_esc(n)}</li>" for n in spec.notes)
    fig = _img(plot_spectral(spec), "spectral sensitivity with uncertainty bands",
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
    return ('<section id="provenance"><h2>Provenance</h2>'
            + _table(["item", "value"], rows, left=2)
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
    profile : camcal.profile.CalibrationProfile
    progress : optional callback ``(section, done, total)`` called as each section is rendered.

    Returns
    -------
    str
        A complete HTML5 document: inline CSS, plots as base64 PNG ``data:`` URIs, no scripts and no
        external resources. Pure: the same profile gives the same text (no "generated at" time).
    """
    from camcal.profile import contract

    c = contract(profile)
    cam = c["camera"]
    stages = profile.stages()
    title = f"camcal calibration report — {cam['make'] or '?'} {cam['model'] or '?'}"
    badges = "".join(f'<span class="{"ok" if done else "no"}">{_esc(STAGE_TITLES[k])}: '
                     f'{"calibrated" if done else "not calibrated"}</span>' for k, done in stages.items())
    head_rows = [["make", cam["make"] or "unknown"], ["model", cam["model"] or "unknown"],
                 ["serial", cam["serial"] or "unknown"], ["CFA pattern", cam["cfa_pattern"] or "none"],
                 ["image size", f"{cam['width']} × {cam['height']} px"],
                 ["reference setting", f"ISO {profile.reference_iso:g}, f/{profile.reference_f_number:g}"],
                 ["content SHA-256", profile.content_sha256 or "not saved"]]
    body = [f"<h1>{_esc(title)}</h1>",
            f'<p class="sub">profile created {_esc(c["provenance"]["created_utc"] or "at an unknown time")} '
            f"with camcal {_esc(c['provenance']['camcal_version'])}; report by camcal {_esc(__version__)}.</p>",
            "<nav>" + "".join(f'<a href="#{k}">{_esc(STAGE_TITLES[k])}</a>' for k in stages)
            + '<a href="#provenance">Provenance</a></nav>',
            f'<div class="stages">{badges}</div>',
            _table(["camera", "value"], head_rows, left=2)]
    total = len(_SECTIONS) + 1
    for done, (key, attr, section) in enumerate(_SECTIONS):
        if progress is not None:
            progress(STAGE_TITLES[key], done, total)
        present = getattr(profile, attr) is not None and (key != "response" or bool(profile.response))
        body.append(section(profile, c) if present else _missing(key))
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

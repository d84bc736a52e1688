"""Figures of a calibration: matplotlib :class:`~matplotlib.figure.Figure` objects with one colour table.

Every function returns a new ``Figure`` built with ``matplotlib.figure.Figure`` directly: no pyplot
state, no backend change (the backend is never set), safe in threads and in a user's
notebook. The callers decide what to do with it:

* the HTML report (:mod:`camcal.report.page`) encodes it with :func:`png_bytes`;
* the stage commands (``camcal flat``, ``camcal linearity``, ``camcal sweep``) write it with
  :func:`write_png` (atomically);
* in a notebook, ``display(fig)`` (or the figure as the last expression of a cell) shows it once
  matplotlib's inline support is on (``%matplotlib inline``).

Figures, in pipeline order:

* :func:`dark_figure` — dark current β (seed eq. 12, β term; EMVA 1288 §8): histogram per plane with
  the hot pixels apart, and a map with the hot pixels circled;
* :func:`flat_figure` — vignetting, DNG ``FixVignetteRadial`` g = 1 + k0 r² + … + k4 r¹⁰ against the
  normalised radius per plane (optionally over the master flat's block means), and the gain map;
* :func:`response_figure` — seed eq. 12, g = α·x^γ + β: measured ROI means and the fit, and the
  relative residuals;
* :func:`spectral_figure` — c(λ) (seed §3.1) of R, G, B and of G1, G2 with their standard
  uncertainties (optionally over a known truth);
* :func:`seed_ratio_figure` — the seed §5 curves of ``camcal water simulate`` (eq. 10 beside eq. 11).

Colours: :data:`COLOURS` is the one table for the planes (R, G1, G2, B) and the RGB channels
(R, G, B); :data:`LINESTYLES` tells G2 from G1 where both are drawn.

matplotlib is imported when a figure is built, not when this module is imported: ``camcal``'s
start-up must not pay for it and most commands never draw.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from camcal.frame import PLANES
from camcal.io.atomic import atomic_write_bytes
from camcal.models.blocks import auto_downsample, block_mean
from camcal.models.dark import HOT, DarkModel
from camcal.models.flat import FlatModel, radial_gain
from camcal.models.response import ResponseModel
from camcal.models.spectral import SpectralSensitivity
from camcal.units import DN, DN_PER_S, SPECTRAL_RADIANCE

if TYPE_CHECKING:
    from matplotlib.figure import Figure

COLOURS: dict[str, str] = {"R": "#d62728", "G1": "#2ca02c", "G2": "#17632a", "G": "#2ca02c", "B": "#1f77b4"}
"""Plot colour per plane (R, G1, G2, B) and RGB channel (R, G, B; G is the mean of G1 and G2)."""

LINESTYLES: dict[str, str] = {"R": "-", "G1": "-", "G2": "--", "G": "-", "B": "-"}
"""Line style per plane or channel: G2 dashed, so that it stays apart from G1 where they overlap."""

HOT_COLOUR = "#ff7f0e"
"""Colour of hot pixels in the dark figure."""

DPI = 100
"""Resolution of the PNGs, dots per inch of the figure size (an 11 in wide figure is 1100 px)."""

MAX_MAP_PX = 600
"""Maps wider or taller than this (plane pixels) are block-averaged for display."""


def colour(name: str) -> str:
    """The colour of a plane or channel (:data:`COLOURS`); black for any other name."""
    return COLOURS.get(name, "k")


# ---------------------------------------------------------------------------------------------
# figures and PNGs
# ---------------------------------------------------------------------------------------------
def new_figure(width_in: float, height_in: float) -> Figure:
    """An empty ``Figure`` of ``width_in`` × ``height_in`` inches, constrained layout, no pyplot state."""
    # lazy: importing matplotlib costs ~0.2 s of start-up, paid only when a figure is drawn (RESULTS.md)
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), layout="constrained")


def png_bytes(fig: Figure, dpi: float = DPI) -> bytes:
    """PNG bytes of ``fig`` (Agg renderer; no timestamp or software metadata, so reproducible)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    return buf.getvalue()


def write_png(fig: Figure, path: str | Path, dpi: float = DPI) -> Path:
    """Write ``fig`` as a PNG to ``path`` atomically (temp file, then rename); returns the path."""
    return atomic_write_bytes(path, png_bytes(fig, dpi))


def _display_map(a: np.ndarray) -> tuple[np.ndarray, int]:
    """Block-mean ``a`` (2-D) down to at most :data:`MAX_MAP_PX` per side; returns (map, factor)."""
    h, w = a.shape
    f = max(1, math.ceil(max(h, w) / MAX_MAP_PX))
    if f == 1:
        return a, 1
    hh, ww = h // f, w // f
    return np.nanmean(a[: hh * f, : ww * f].reshape(hh, f, ww, f), axis=(1, 3)), f


# ---------------------------------------------------------------------------------------------
# dark
# ---------------------------------------------------------------------------------------------
def _dark_bins(normal: np.ndarray, everything: np.ndarray) -> tuple[np.ndarray, float | None]:
    """Histogram bins: linear over the bulk of the pixels, logarithmic out to the largest value.

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


def dark_figure(dark: DarkModel) -> Figure:
    """Histogram of the dark current β per plane (hot pixels apart) and a β map with hot pixels circled.

    Parameters
    ----------
    dark : camcal.models.dark.DarkModel
        β = ``dark_current_dn_per_s`` (4, h, w) in DN s⁻¹ at ``dark.iso`` (seed eq. 12, β term);
        hot pixels are bit 1 of ``defects``. A bias-only model (β None) shows the bias in DN instead.

    Returns
    -------
    Figure
        Two axes: the histogram (one step line per plane, labelled with its median; the hot pixels
        as one filled histogram and a rug) and the map of the mean over the planes.
    """
    from matplotlib.colors import Normalize  # lazy with matplotlib itself (see new_figure)

    has_beta = dark.dark_current_dn_per_s is not None
    values = np.asarray(dark.dark_current_dn_per_s if has_beta else dark.bias_dn, np.float64)
    symbol, unit = ("β", DN_PER_S) if has_beta else ("bias", DN)
    what = f"dark current β [{DN_PER_S} at ISO {dark.iso:g}]" if has_beta else "bias [DN] (no dark current: bias only)"
    hot = (np.asarray(dark.defects) & HOT) != 0
    fig = new_figure(11.0, 4.4)
    ax1, ax2 = fig.subplots(1, 2, width_ratios=[1.05, 1.0])
    finite = values[np.isfinite(values)]
    normal = values[np.isfinite(values) & ~hot]
    bins, linthresh = _dark_bins(normal if normal.size else finite, finite)
    for i, name in enumerate(PLANES[: values.shape[0]]):
        vals = values[i][np.isfinite(values[i]) & ~hot[i]]
        counts, _ = np.histogram(vals, bins=bins)
        ax1.stairs(np.where(counts > 0, counts, np.nan), bins, lw=1.3, ls=LINESTYLES[name], color=colour(name),
                   label=f"{name} (median {np.median(vals):.3g})" if vals.size else name)
    hot_vals = values[hot & np.isfinite(values)]
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
    ax1.set_xlabel(what)
    ax1.set_ylabel("pixels per bin")
    ax1.set_title(f"{symbol} per pixel and plane")
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=8)
    with np.errstate(all="ignore"):
        mean_map = np.nanmean(values, axis=0)
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
    ax2.set_title(f"{symbol} map, mean of the planes" + (f" ({factor}×{factor} blocks)" if factor > 1 else "")
                  + ", colours 1–99 %")
    ax2.set_xlabel("x [plane px]")
    ax2.set_ylabel("y [plane px]")
    fig.colorbar(im, ax=ax2, shrink=0.85, label=f"{symbol} [{unit}]")
    return fig


# ---------------------------------------------------------------------------------------------
# flat
# ---------------------------------------------------------------------------------------------
def flat_figure(flat: FlatModel, master: np.ndarray | None = None) -> Figure:
    """Relative illumination g against the normalised radius per plane, and a gain map with optical centres.

    Parameters
    ----------
    flat : camcal.models.flat.FlatModel
        The radial model g(r) = 1 + Σ k_i r^(2i+2) (r normalised to the farthest corner, DNG
        ``FixVignetteRadial``) is drawn as a curve; with a 2-D model the binned median of the active
        gain map over the radius is drawn instead.
    master : (C, h, w) array, optional
        The master flat (any scale, :class:`camcal.calibrate.flat.MasterFlat` ``value``). When given, its block
        means (about 48 blocks along the long side), divided by its level at the optical centre, are
        drawn as dots: the data the model was fitted to. Without it the dots are the active model
        over the plane (subsampled), which shows how far a 2-D model departs from a radial one.

    Returns
    -------
    Figure
        Left axes: per plane one line (the curve, labelled ``"<plane> (corner <gain>)"``) and one
        dotted series. Right axes: the gain map of G1 and a ``+`` per plane at its optical centre.
    """
    gain = flat.gain()
    geom = flat.geometry
    h, w = flat.shape
    fig = new_figure(11.0, 4.4)
    ax1, ax2 = fig.subplots(1, 2, width_ratios=[1.05, 1.0])
    r_grid = np.linspace(0.0, 1.0, 200)
    corner = flat.corner_gain()
    stride = max(1, math.ceil(math.sqrt(h * w / 4000)))  # ~4000 samples of the model per plane
    yy, xx = np.mgrid[0:h:stride, 0:w:stride].astype(np.float64)
    for i, name in enumerate(flat.channels):
        col = colour(name)
        cx, cy = flat.centre_px[name]
        r = np.sqrt(geom.r2(name, xx, yy, cx, cy)).ravel()
        g = gain[i, ::stride, ::stride].ravel()
        if master is None:
            ax1.plot(r, g, ".", ms=1.5, color=col, alpha=0.15)
        else:
            plane = np.asarray(master[i], np.float64)
            block, bx, by = block_mean(plane, auto_downsample((h, w), 48))
            # the master is on any scale: divide by its level at the optical centre
            scale = float(np.nanmedian(plane / np.maximum(gain[i], 1e-6)))
            ax1.plot(np.sqrt(geom.r2(name, bx, by, cx, cy)).ravel(), block.ravel() / scale, ".", ms=2,
                     color=col, alpha=0.35)
        label = f"{name} (corner {corner[name]:.3f})"
        if flat.kind == "radial":
            ax1.plot(r_grid, radial_gain(r_grid**2, flat.k[name]), color=col, lw=1.6, ls=LINESTYLES.get(name, "-"),
                     label=label)
        else:
            edges = np.linspace(0.0, max(float(r.max()), 1e-9), 41)
            idx = np.clip(np.digitize(r, edges) - 1, 0, 39)
            med = np.array([np.median(g[idx == k]) if np.any(idx == k) else np.nan for k in range(40)])
            ax1.plot(0.5 * (edges[1:] + edges[:-1]), med, color=col, lw=1.6, ls=LINESTYLES.get(name, "-"),
                     label=label)
    ax1.set_xlabel("r (distance from optical centre / distance to farthest corner)")
    ax1.set_ylabel("relative illumination g (1 at optical centre)")
    ax1.set_title(f"vignetting, {flat.kind} model" + ("; dots: master flat" if master is not None else ""))
    ax1.grid(alpha=0.3)
    ax1.legend(fontsize=8)
    gi = flat.channels.index("G1") if "G1" in flat.channels else (1 if len(flat.channels) > 1 else 0)
    shown, _ = _display_map(gain[gi].astype(np.float64))
    im = ax2.imshow(shown, cmap="viridis", interpolation="nearest", extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    for name in flat.channels:
        cx, cy = flat.centre_px[name]
        ax2.plot(cx, cy, "+", color=colour(name), ms=12, mew=1.6, label=f"centre {name}")
    ax2.legend(fontsize=7, loc="lower right")
    ax2.set_title(f"gain map, plane {flat.channels[gi]}; + optical centres")
    ax2.set_xlabel("x [plane px]")
    ax2.set_ylabel("y [plane px]")
    fig.colorbar(im, ax=ax2, shrink=0.85, label="g")
    return fig


# ---------------------------------------------------------------------------------------------
# response
# ---------------------------------------------------------------------------------------------
def response_figure(model: ResponseModel, title: str | None = None) -> Figure:
    """Measured points and the seed eq. 12 fit per channel (log–log), and the relative residuals.

    Parameters
    ----------
    model : camcal.models.response.ResponseModel
        ``points[ch]`` holds ``x_s`` (relative exposure, s at the reference setting), ``mean_dn`` and
        ``used``; the fit is ``g = α x^γ + β`` (seed eq. 12).
    title : optional figure title (e.g. the camera); the axes keep their own titles.

    Returns
    -------
    Figure
        Left axes: per channel with points the fitted curve (labelled ``"<ch>: γ=…"``), the used points
        (filled), the excluded points (hollow: saturated or compressed) and the saturation level
        (dotted). Right axes: residuals in % of g − β per channel.
    """
    fig = new_figure(11.0, 4.6)
    ax1, ax2 = fig.subplots(1, 2, width_ratios=[1.15, 1.0])
    any_points = False
    fitted_residuals: list[np.ndarray] = []
    for name, ch in model.channels.items():
        col = colour(name)
        pts = model.points.get(name) or {}
        x = np.asarray(pts.get("x_s", []), float)
        g = np.asarray(pts.get("mean_dn", []), float)
        used = np.asarray(pts.get("used", [True] * len(x)), bool)
        if not len(x) or len(g) != len(x) or len(used) != len(x):  # none, or not one series (an edited profile)
            continue
        any_points = True
        ok = x > 0
        xx = np.geomspace(x[ok].min(), x[ok].max(), 200) if ok.any() else x
        label = f"{name}: γ={ch.gamma:.4f}, β={ch.beta:.4g} DN"
        ax1.plot(xx * 1e3, ch.predict(xx), ls=LINESTYLES.get(name, "-"), color=col, lw=1.2, alpha=0.8, label=label)
        ax1.plot(x[used] * 1e3, g[used], "o", color=col, ms=4)
        ax1.plot(x[~used] * 1e3, g[~used], "o", mfc="none", color=col, ms=6)
        pred = ch.predict(x)
        signal = pred - ch.beta
        with np.errstate(all="ignore"):
            rel = 100.0 * (g - pred) / np.where(np.abs(signal) > 0, signal, np.nan)
        ax2.plot(x[used] * 1e3, rel[used], "o", ls=LINESTYLES.get(name, "-"), color=col, ms=3, lw=0.8, label=name)
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
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


# ---------------------------------------------------------------------------------------------
# spectral
# ---------------------------------------------------------------------------------------------
def spectral_figure(spec: SpectralSensitivity, truth: dict[str, np.ndarray] | None = None,
                    truth_wavelength_nm: np.ndarray | None = None, title: str | None = None) -> Figure:
    """c(λ) of R, G, B with ±1 σ bands and of G1, G2 with their difference, each above an uncertainty panel.

    Parameters
    ----------
    spec : camcal.models.spectral.SpectralSensitivity
        Values and standard uncertainties per plane (seed §3.1); G is the mean of G1 and G2 and
        u(G) = ½·√(u(G1)² + u(G2)²).
    truth : optional known curves, same units as ``spec``: keys R, G, B are drawn over the left panel,
        G1, G2 over the right one (thin black-edged lines in the channel's colour, labelled ``"<k> truth"``).
    truth_wavelength_nm : wavelengths of ``truth`` (nm); required with ``truth``.
    title : optional figure title.

    Returns
    -------
    Figure
        Four axes: c(λ) of R, G, B (top left), of G1 and G2 (top right), u(λ) of R, G, B (bottom
        left), G2 − G1 with its ±1 σ band (bottom right).

    Notes
    -----
    Typical uncertainties are below 1 % of the peak, too thin to see as bands at full scale, so the
    lower panels show u(λ) itself (left) and G2 − G1 with its ±1 σ band (right: the greens agree where
    the band covers 0).
    """
    if truth is not None and truth_wavelength_nm is None:
        raise ValueError("truth needs truth_wavelength_nm")
    wl = np.asarray(spec.wavelength_nm, float)
    if spec.mono:
        return _mono_spectral_figure(spec, wl, truth, truth_wavelength_nm, title)
    rgb, unc = spec.rgb(), spec.rgb_uncertainty()
    fig = new_figure(11.0, 5.8)
    (ax1, ax2), (ax3, ax4) = fig.subplots(2, 2, sharex=True, height_ratios=[2.6, 1.0])
    for name in ("R", "G", "B"):
        v, u = np.asarray(rgb[name], float), np.asarray(unc[name], float)
        ax1.fill_between(wl, v - u, v + u, color=colour(name), alpha=0.3, lw=0)
        ax1.plot(wl, v, LINESTYLES[name], color=colour(name), lw=1.4, marker=".", ms=3, label=name)
        ax3.plot(wl, u, LINESTYLES[name], color=colour(name), lw=1.2, label=f"u({name})")
    # linear RAW has one green plane: the comparison of the two greens is then G against itself (0)
    gk1, gk2 = ("G1", "G2") if "G1" in spec.values else ("G", "G")
    g1, g2 = np.asarray(spec.values[gk1], float), np.asarray(spec.values[gk2], float)
    u1, u2 = np.asarray(spec.uncertainty[gk1], float), np.asarray(spec.uncertainty[gk2], float)
    for name, v, u in (("G1", g1, u1), ("G2", g2, u2)):
        ax2.fill_between(wl, v - u, v + u, color=colour(name), alpha=0.3, lw=0)
        ax2.plot(wl, v, LINESTYLES[name], color=colour(name), lw=1.3, label=name)
    diff, u_diff = g2 - g1, np.hypot(u1, u2)
    ax4.fill_between(wl, diff - u_diff, diff + u_diff, color=colour("G2"), alpha=0.3, lw=0, label="±1 σ")
    ax4.plot(wl, diff, "-", color=colour("G2"), lw=1.2, label="G2 − G1")
    ax4.axhline(0.0, color="0.5", lw=0.8)
    if truth is not None:
        twl = np.asarray(truth_wavelength_nm, float)
        for name, v in truth.items():
            ax = ax2 if name in ("G1", "G2") else ax1
            ax.plot(twl, np.asarray(v, float), ":", color=colour(name), lw=1.6, label=f"{name} truth")
        if wl.size > 1:  # the truth may span more than the measurement (the x axis is shared by all four axes)
            ax1.set_xlim(wl[0], wl[-1])
    unit = "rel." if spec.mode == "relative" else f"{DN_PER_S} per {SPECTRAL_RADIANCE}"
    ax1.set_title("c(λ): R, G (mean of G1, G2), B; bands ±1 σ"
                  + (", deconvolved" if spec.deconvolved else ""))
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
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def _mono_spectral_figure(spec, wl: np.ndarray, truth, truth_wavelength_nm, title: str | None) -> Figure:
    """c(λ) of a monochrome sensor's one channel ``Y`` with its ±1 σ band (top) and u(λ) (bottom)."""
    v, u = np.asarray(spec.values["Y"], float), np.asarray(spec.uncertainty["Y"], float)
    fig = new_figure(7.0, 5.0)
    ax1, ax3 = fig.subplots(2, 1, sharex=True, height_ratios=[2.6, 1.0])
    ax1.fill_between(wl, v - u, v + u, color="0.5", alpha=0.3, lw=0)
    ax1.plot(wl, v, "-", color="0.15", lw=1.4, marker=".", ms=3, label="Y")
    ax3.plot(wl, u, "-", color="0.15", lw=1.2, label="u(Y)")
    if truth is not None and "Y" in truth:
        ax1.plot(np.asarray(truth_wavelength_nm, float), np.asarray(truth["Y"], float), ":", color="0.15", lw=1.6,
                 label="Y truth")
    unit = "rel." if spec.mode == "relative" else f"{DN_PER_S} per {SPECTRAL_RADIANCE}"
    ax1.set_title("c(λ) of the monochrome channel Y; band ±1 σ" + (", deconvolved" if spec.deconvolved else ""))
    ax1.set_ylabel(f"c(λ) [{unit}]", fontsize=8)
    ax3.set_ylabel("u(λ)", fontsize=8)
    ax3.set_xlabel("wavelength λ [nm]")
    for ax in (ax1, ax3):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


# ---------------------------------------------------------------------------------------------
# water: seed §5
# ---------------------------------------------------------------------------------------------
def seed_ratio_figure(table: np.ndarray, name: str) -> Figure:
    """One seed §5 curve: L_i/L_s at 663 nm, the exact eq. 10 beside the first-order eq. 11 (log axis).

    Parameters
    ----------
    table : (n, 4) or (n, 5) array from :func:`camcal.water.simulate.seed_section5_tables`: columns x, exact
        ratio (eq. 10, E₃ closed form), first-order ratio (eq. 11), relative error of eq. 11 and, when
        present, the second-order ratio of the seed's appendix (k, q) (drawn where positive).
    name : ``"depth"`` (x in m, drawn in cm, C = 1e-7 mol/L) or ``"concentration"`` (x in mol/L, d = 20 cm).

    Returns
    -------
    Figure
        One axes with lines labelled ``"exact (eq. 10, E₃ closed form)"``, ``"first order (eq. 11)"`` and,
        with a fifth column, ``"second order (appendix k, q)"``.
    """
    if name not in ("depth", "concentration"):
        raise ValueError(f"name must be depth or concentration, got {name!r}")
    t = np.asarray(table, float)
    fig = new_figure(6.0, 4.0)
    ax = fig.subplots()
    x = t[:, 0] * (100.0 if name == "depth" else 1.0)
    ax.semilogy(x, t[:, 1], label="exact (eq. 10, E₃ closed form)")
    ax.semilogy(x, t[:, 2], "--", label="first order (eq. 11)")
    if t.shape[1] > 4:
        ax.semilogy(x, np.where(t[:, 4] > 0, t[:, 4], np.nan), ":", label="second order (appendix k, q)")
    ax.set_xlabel("depth (cm)" if name == "depth" else "C (mol/L)")
    ax.set_ylabel("L_i / L_s at 663 nm")
    ax.set_title("C = 1e-7 mol/L" if name == "depth" else "d = 20 cm")
    ax.grid(alpha=0.3)
    ax.legend()
    return fig

"""The plots of an EMVA 1288 data sheet (release 4.0 "Linear" §9, the figures a sensor's data sheet is read by).

Each function takes the ``curves`` and ``figures`` of :class:`camcal.calibrate.emva_standard.StandardFigures` and
returns a new matplotlib ``Figure`` (built with :func:`camcal.report.plots.new_figure`: no pyplot state, no backend
change):

* :func:`photon_transfer_figure` — σ²_y − σ²_y.dark against μ_y − μ_y.dark, the fitted points, the line of slope
  K and the saturation point;
* :func:`snr_figure` — SNR against the irradiance (photons per pixel, or exposure time), the linear model's
  SNR (eq. 15) and the ideal √μ_p;
* :func:`linearity_figure` — μ_y − μ_y.dark against the irradiance with the relative-deviation fit, and the
  deviation δ in %;
* :func:`dark_current_figure` — μ_y.dark and σ²_y.dark against exposure time with their lines;
* :func:`spectrogram_figure` — horizontal and vertical spectrograms of the DSNU (DN) or PRNU (%) image with the
  temporal noise left in the average;
* :func:`histogram_figure` — the DSNU image and the high-pass-filtered PRNU image as log-count histograms.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from camcal.calibrate.emva import QUANTISATION_VAR_DN2
from camcal.report.plots import new_figure
from camcal.units import DN, DN_PER_ELECTRON, ELECTRONS_PER_S

if TYPE_CHECKING:
    from matplotlib.figure import Figure

POINT = "#1f77b4"
"""Colour of measured points (the one channel of a monochrome sensor)."""
FIT = "#d62728"
"""Colour of fitted lines and models."""
OUT = "#9aa4b1"
"""Colour of points left out of a fit."""


def _xlabel(figures: dict) -> str:
    return "irradiation μ_p (photons/pixel)" if figures.get("quantum_efficiency_pct") else "exposure time t (s)"


def photon_transfer_figure(curves: dict, figures: dict) -> Figure:
    """Photon transfer: the temporal variance against the mean, both with the dark values removed."""
    fig = new_figure(5.4, 3.8)
    ax = fig.add_subplot()
    x, v, fit = curves["signal_dn"], curves["variance_dn2"], curves["fit_mask"]
    ax.plot(x[fit], v[fit], "o", color=POINT, ms=4, label="fitted")
    ax.plot(x[~fit], v[~fit], "o", mfc="none", color=OUT, ms=4, label="not fitted")
    k = figures["K_dn_per_e"]
    top = figures.get("ptc_fit_max_dn") or float(np.nanmax(x))
    xx = np.array([0.0, top])
    ax.plot(xx, k * xx, "-", color=FIT, label=f"K = {k:.4g} ± {figures['K_unc_dn_per_e']:.2g} {DN_PER_ELECTRON}")
    i = int(figures["saturation_index"])
    ax.plot([x[i]], [v[i]], "s", mfc="none", mec="k", ms=9, label="saturation")
    ax.set_xlabel(f"μ_y − μ_y.dark ({DN})")
    ax.set_ylabel(f"σ²_y − σ²_y.dark ({DN}²)")
    ax.set_title("photon transfer")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def snr_figure(curves: dict, figures: dict) -> Figure:
    """SNR against the irradiance, measured and from the linear camera model (release 3.0 eq. 15)."""
    fig = new_figure(5.4, 3.8)
    ax = fig.add_subplot()
    x = curves["x"]
    sig = curves["signal_dn"]
    snr = sig / np.sqrt(np.maximum(curves["total_variance_dn2"], 1e-12))
    good = (x > 0) & (sig > 0) & (np.arange(x.size) <= int(figures["saturation_index"]))
    ax.loglog(x[good], snr[good], "o", color=POINT, ms=4, label="measured")
    k = figures["K_dn_per_e"]
    sd_e = (figures.get("read_noise_e") or 0.0)
    eta = (figures.get("quantum_efficiency_pct") or 0.0) / 100.0
    xx = np.geomspace(max(float(np.min(x[good])) / 3, 1e-30), float(np.max(x)) * 1.2, 200)
    if eta > 0:
        mu_e = eta * xx
        ax.loglog(xx, np.sqrt(xx), ":", color="k", label="ideal √μ_p")
    else:
        r = figures.get("responsivity_dn_per_s") or 1.0
        mu_e = r * xx / k
    model = mu_e / np.sqrt(sd_e**2 + QUANTISATION_VAR_DN2 / k**2 + mu_e)
    sat_x = figures.get("saturation_photons") or figures.get("saturation_exposure_s")
    keep = xx <= (sat_x or np.inf)
    ax.loglog(xx[keep], model[keep], "-", color=FIT, label="linear model")
    ax.axhline(1.0, color="k", lw=0.6)
    ax.set_xlabel(_xlabel(figures))
    ax.set_ylabel("SNR")
    ax.set_title(f"SNR (SNR_max = {figures['snr_max']:.4g})")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return fig


def linearity_figure(curves: dict, figures: dict) -> Figure:
    """The signal against the irradiance and its relative deviation from the linearity fit."""
    fig = new_figure(10.0, 3.2)
    ax, bx = fig.subplots(1, 2)
    x, y, dev = curves["x"], curves["signal_dn"], curves["linearity_deviation_pct"]
    ax.plot(x, y, "o", color=POINT, ms=4)
    ax.set_xlabel(_xlabel(figures))
    ax.set_ylabel(f"μ_y − μ_y.dark ({DN})")
    ax.set_title("response")
    ax.grid(alpha=0.3)
    sat = figures.get("saturation_dn")
    if sat:
        ok = np.isfinite(dev) & (y >= 0.05 * sat) & (y <= 0.95 * sat)
        bx.plot(x[ok], dev[ok], "o-", color=POINT, ms=4)
        bx.plot(x[~ok & np.isfinite(dev)], dev[~ok & np.isfinite(dev)], "o", mfc="none", color=OUT, ms=4)
        bx.set_ylim(*(np.array([-1.5, 1.5]) * max(abs(figures.get("linearity_error_min_pct") or 1.0),
                                                  abs(figures.get("linearity_error_max_pct") or 1.0), 0.2)))
    bx.axhline(0, color="k", lw=0.6)
    bx.set_xlabel(_xlabel(figures))
    bx.set_ylabel("deviation δ (%)")
    le = (figures.get("linearity_error_min_pct"), figures.get("linearity_error_max_pct"))
    bx.set_title("linearity" + ("" if None in le else f": LE {le[0]:.2f} … {le[1]:.2f} %"))
    bx.grid(alpha=0.3)
    return fig


def dark_current_figure(curves: dict, figures: dict) -> Figure:
    """Mean and temporal variance of the dark pairs against exposure time."""
    fig = new_figure(10.0, 3.2)
    ax, bx = fig.subplots(1, 2)
    t, m, v = curves["dark_exposure_s"], curves["dark_mean_dn"], curves["dark_variance_dn2"]
    for axis, y, lab in ((ax, m, f"μ_y.dark ({DN})"), (bx, v, f"σ²_y.dark ({DN}²)")):
        axis.plot(t * 1e3, y, "o", color=POINT, ms=4)
        if np.unique(t).size > 2:
            a, b = np.polyfit(t, y, 1)
            axis.plot(t * 1e3, a * t + b, "-", color=FIT)
        axis.set_xlabel("exposure time (ms)")
        axis.set_ylabel(lab)
        axis.grid(alpha=0.3)
    dc = figures.get("dark_current_e_per_s")
    ax.set_title("dark signal" + ("" if dc is None else f": {dc:.3g} {ELECTRONS_PER_S}"))
    bx.set_title("dark temporal variance")
    return fig


def spectrogram_figure(curves: dict, figures: dict, kind: str) -> Figure:
    """Horizontal and vertical spectrograms of the ``kind`` ("dsnu": DN, "prnu": %) image."""
    fig = new_figure(10.0, 3.2)
    axes = fig.subplots(1, 2)
    unit = DN if kind == "dsnu" else "%"
    floor = figures.get(f"{kind}_temporal_floor_{'dn' if kind == 'dsnu' else 'pct'}")
    level = figures.get("dsnu_dn") if kind == "dsnu" else figures.get("prnu_pct")
    for axis, key, name in zip(axes, ("h", "v"), ("horizontal", "vertical"), strict=True):
        f, amp = curves[f"{kind}_spectrogram_{key}"]
        axis.semilogy(f[1:], np.maximum(amp[1:], 1e-6), "-", color=POINT, lw=0.7)
        if floor:
            axis.axhline(floor, color=OUT, ls="--", lw=1, label="temporal noise / √L")
        if level:
            axis.axhline(level, color=FIT, lw=1, label=("DSNU₁₂₈₈" if kind == "dsnu" else "PRNU₁₂₈₈"))
        axis.set_xlabel("spatial frequency (cycles/pixel)")
        axis.set_ylabel(f"standard deviation ({unit})")
        axis.set_title(f"{kind.upper()} spectrogram, {name}")
        axis.grid(alpha=0.3, which="both")
        axis.legend(fontsize=8)
    return fig


def histogram_figure(curves: dict, figures: dict) -> Figure:
    """Log-count histograms of the DSNU image (DN about its mean) and the high-pass-filtered PRNU image (%)."""
    fig = new_figure(10.0, 3.2)
    axes = fig.subplots(1, 2)
    for axis, key, unit, title in ((axes[0], "dsnu_image_dn", DN, "DSNU histogram"),
                                   (axes[1], "prnu_highpass_pct", "%", "PRNU histogram (5×5 high-pass)")):
        a = curves.get(key)
        if a is None:
            axis.set_axis_off()
            continue
        a = np.asarray(a, float).ravel()
        lo, hi = float(np.min(a)), float(np.max(a))
        bins = 128 if hi > lo else 1
        counts, edges = np.histogram(a, bins=bins)
        centres = 0.5 * (edges[1:] + edges[:-1])
        axis.semilogy(centres, np.maximum(counts, 0.5), drawstyle="steps-mid", color=POINT)
        s = float(np.std(a))
        if s > 0:
            g = a.size * (edges[1] - edges[0]) / (s * math.sqrt(2 * math.pi)) * np.exp(-0.5 * (centres / s) ** 2)
            axis.semilogy(centres, np.maximum(g, 0.5), "--", color=FIT, label="normal, same σ")
            axis.legend(fontsize=8)
        axis.set_ylim(0.5, None)
        axis.set_xlabel(f"deviation from the mean ({unit})")
        axis.set_ylabel("pixels")
        axis.set_title(title)
        axis.grid(alpha=0.3)
    return fig

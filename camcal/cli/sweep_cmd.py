"""``camcal sweep``: spectral sensitivity c(λ) per channel from a monochromator sweep (seed §3.1)."""

from __future__ import annotations

import dataclasses
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import typer
from rich.table import Table

from camcal.calibrate.session import resolve_exposure
from camcal.calibrate.sweep import SweepOptions, fit_sweep, measure_sweep, read_sweep
from camcal.cli.common import console, err_console, fraction, plot_path, print_json, progress
from camcal.curves.files import write_spectacle_csv
from camcal.curves.library import with_layout
from camcal.curves.published_sweeps import sweep_means_sensitivity
from camcal.errors import CamcalError
from camcal.io.manifest import session_defaults_for
from camcal.region import Region
from camcal.report.plots import spectral_figure, write_png
from camcal.units import SPECTRAL_SENSITIVITY


def _means(means: Path, responsivity: Path | None, reduction: str, output: Path, as_json: bool) -> None:
    if reduction not in ("camcal", "publisher"):
        raise CamcalError(f"--reduction must be camcal or publisher, got {reduction!r}")
    sens, red, readings = sweep_means_sensitivity(means, responsivity, reduction)  # type: ignore[arg-type]
    sens = with_layout(dataclasses.replace(sens, source={
        "kind": "sweep_means", "file": means.name, "sha256": readings.files[0]["sha256"], "format": "sweep_means",
        "absolute_scale": {"method": "none", "description": "relative: the reference detector's responsivity is "
                           "relative"}, "notes": [f"{f['file']} {f['sha256']}" for f in readings.files]}), "bayer")
    write_spectacle_csv(sens, output)
    png_path = output.with_suffix(".png")
    write_png(spectral_figure(sens), png_path)
    summary = sens.summary()
    if as_json:
        print_json({**summary, "output": str(output), "png": str(png_path), "reduction": reduction,
                    "peak_response": {k: float(v.max()) for k, v in red.response.items()},
                    "peak_relative": {k: float(np.nanmax(v)) for k, v in sens.values.items()}})
        return
    # what the CSV holds: every channel divided by the largest value of any channel (that one peaks at 1)
    table = Table(title=f"spectral sensitivity from sweep means ({reduction} reduction; relative: divided by the "
                        "largest channel's peak)")
    for col in ("channel", "peak λ (nm)", "peak (largest = 1)", "u at peak (%)", "λ_eff (nm)"):
        table.add_column(col)
    for ch, v in sens.values.items():
        v = np.asarray(v, float)
        k = int(np.nanargmax(v))
        u = np.asarray(sens.uncertainty[ch], float)
        table.add_row(ch, f"{sens.wavelength_nm[k]:g}", f"{v[k]:.4f}", f"{100 * u[k] / v[k]:.2g}",
                      f"{summary['effective_wavelength_nm'].get(ch, summary['effective_wavelength_nm']['G']):.1f}")
    console.print(table)
    console.print(f"wrote {output} (+ {output.stem}.meta.json) and {png_path}")


def _frames_setting(folder: Path, rows) -> tuple[float, float]:
    """The sweep frames' most common (ISO, f-number), from sweep.csv, the tags and session.toml: never a default.

    Raises
    ------
    CamcalError
        When a value is unknown, saying what to add.
    """
    defaults = session_defaults_for(folder)
    seen: Counter = Counter()
    for row in rows:
        ref = resolve_exposure(row.path, row.overrides, defaults, "sweep.csv")
        seen[(ref.iso, ref.f_number)] += 1
    (iso, n), _ = seen.most_common(1)[0]
    for value, what, column, option in ((iso, "ISO", "iso", "--reference-iso"),
                                        (n, "f-number", "f_number", "--reference-f-number")):
        if value is None:
            raise CamcalError(f"the reference {what} is unknown: the sweep frames hold none (no tag, no {column} "
                              f"column in sweep.csv, no session.toml); add one or pass {option}", folder)
    return float(iso), float(n)


def register(app: typer.Typer) -> None:
    @app.command("sweep")
    def sweep_cmd(
        sweep: Path | None = typer.Argument(None, help="Sweep folder holding the frames and sweep.csv (omit with "
                                            "--means)."),
        output: Path = typer.Option(..., "-o", "--output", help="Output CSV (SPECTACLE layout); metadata goes to "
                                    "<stem>.meta.json beside it."),
        dark: Path | None = typer.Option(None, "--dark", help="Dark model (camcal dark -o dark.json)."),
        flat: Path | None = typer.Option(None, "--flat", help="Flat model (camcal flat -o flat.json)."),
        mode: str = typer.Option("absolute", "--sweep-mode", help=f"absolute ({SPECTRAL_SENSITIVITY}) or "
                                 "relative (divided by the largest value of any channel: that channel peaks at 1)."),
        roi: str | None = typer.Option(None, "--roi", help="Region x,y,w,h in photo pixels at full resolution "
                                       "(rounded outward to whole plane pixels)."),
        roi_fraction: float | None = typer.Option(None, "--roi-fraction", parser=fraction, help="('20%' or 0.2) "
                                                  "A centred region covering this fraction of each side "
                                                  "(default 0.2: 4 % of the area)."),
        deconvolve: bool = typer.Option(False, help="Remove the monochromator slit function (needs bandwidth_nm)."),
        slit: str = typer.Option("gaussian", help="Slit function shape for --deconvolve: gaussian or triangular."),
        reference_iso: float | None = typer.Option(None, help="Reference ISO of the absolute result (default: the "
                                                   "sweep frames' most common ISO)."),
        reference_f_number: float | None = typer.Option(None, help="Reference f-number of the absolute result "
                                                        "(default: the sweep frames' most common f-number)."),
        plot: bool = typer.Option(True, "--plot/--no-plot", help="Write the plot of c(λ) to <output stem>.png."),
        jobs: int = typer.Option(2, "--jobs", "-j", min=1, help="CPU cores to use (decoding threads)."),
        as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
        means: Path | None = typer.Option(None, "--means", help="A sweep measured elsewhere, as per-step channel "
                                          "means: a CSV wavelength_nm,state,R,G,B,reference (docs/spectral.md) or "
                                          "an open-data <name>_info.txt with _camera.dat and _diode.dat beside it."),
        responsivity: Path | None = typer.Option(None, "--responsivity", help="With --means: the reference "
                                                 "detector's responsivity, wavelength_nm,responsivity (default for "
                                                 "an info.txt: the file its line 4 names, beside it)."),
        reduction: str = typer.Option("camcal", "--reduction", help="With --means: camcal (dark = mean of the "
                                      "darks around each lit reading) or publisher (dark before, clipped at 0)."),
    ) -> None:
        """Measure c(λ) for R, G1, G2, B and write a SPECTACLE CSV and a PNG plot."""

        if output.suffix.lower() != ".csv":
            raise CamcalError("output must be a .csv file", output)
        if (sweep is None) == (means is None):
            raise CamcalError("give a sweep folder or --means FILE, one of them")
        if means is not None:
            _means(means, responsivity, reduction, output, as_json)
            return
        if mode not in ("absolute", "relative"):
            raise CamcalError(f"--sweep-mode must be absolute or relative, got {mode!r}")
        if roi is not None and roi_fraction is not None:
            raise CamcalError("give --roi or --roi-fraction, not both")
        region: Region | float | None = Region.parse(roi) if roi is not None else roi_fraction
        rows = read_sweep(sweep)
        total = len(rows)
        if reference_iso is None or reference_f_number is None:
            iso, n = _frames_setting(sweep, rows)
            reference_iso = iso if reference_iso is None else reference_iso
            reference_f_number = n if reference_f_number is None else reference_f_number
        with warnings.catch_warnings(record=True) as caught, progress() as bar:
            warnings.simplefilter("always")
            task = bar.add_task("sweep frames", total=total)
            options = SweepOptions(roi=region, mode=mode, deconvolve=deconvolve, slit=slit,  # type: ignore[arg-type]
                                   reference_iso=reference_iso, reference_f_number=reference_f_number)  # type: ignore[arg-type]
            measured = measure_sweep(sweep, rows, options, dark=dark, flat=flat, jobs=jobs,
                                     progress=lambda done, n: bar.update(task, completed=done))
            result = fit_sweep(measured, options)
        for msg in dict.fromkeys(" ".join(str(w.message).split()) for w in caught):
            err_console.print(f"camcal: warning: {msg}", soft_wrap=True, markup=False, highlight=False)
        write_spectacle_csv(result, output)
        png_path = plot_path(plot, output.with_suffix(".png"))
        if png_path is not None:
            write_png(spectral_figure(result), png_path)
        summary = result.summary()
        if as_json:
            print_json({**summary, "output": str(output), "png": str(png_path)})
            return
        table = Table(title=f"spectral sensitivity ({result.mode}, {result.units})")
        for col in ("channel", "peak λ (nm)", "peak value", "λ_eff (nm)", "bandwidth (nm)"):
            table.add_column(col)
        chans = result.channels()
        for ch in ("R", "G1", "G2", "B", "G"):
            table.add_row(ch, f"{summary['peak_wavelength_nm'][ch]:g}", f"{float(chans[ch].max()):.5g}",
                          f"{summary['effective_wavelength_nm'][ch]:.1f}",
                          f"{summary['effective_bandwidth_nm'][ch]:.1f}")
        console.print(table)
        console.print(f"wrote {output} (+ {output.stem}.meta.json)" + (f" and {png_path}" if png_path else ""))

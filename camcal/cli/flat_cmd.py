"""``camcal flat SESSION/flat [--dark dark.json] -o flat.json``: vignetting, optical centre and PRNU."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from camcal.calibrate.flat import FlatOptions, fit_flat, measure_flat
from camcal.cli.common import console, plot_path, print_json, progress
from camcal.errors import CamcalError
from camcal.models.dark import as_dark_model
from camcal.models.flat import save_flat
from camcal.models.profile import flats_optics_text
from camcal.report.plots import flat_figure, write_png


def register(app: typer.Typer) -> None:
    @app.command("flat")
    def flat_cmd(
        folder: Path = typer.Argument(..., help="Folder of RAW flat-field frames (with an optional frames.csv)."),
        output: Path = typer.Option(..., "-o", "--output",
                                    help="Flat model JSON to write (maps go to <stem>.maps.exr)."),
        dark: Path | None = typer.Option(None, "--dark", help="Dark model JSON from `camcal dark`; without it only "
                                         "the files' black level is subtracted."),
        plot: bool = typer.Option(True, "--plot/--no-plot", help="Write the falloff plot to <stem>.falloff.png."),
        model: str = typer.Option("radial", "--vignetting-model", help="radial (DNG radial, fitted centre) or 2d "
                                  "(Legendre)."),
        downsample: int | None = typer.Option(None, "--downsample", min=1,
                                              help="Block size of the fit in photo pixels, whole CFA cells (even for "
                                              "a Bayer sensor; default ~64 blocks across)."),
        terms: int = typer.Option(3, "--terms", min=1, max=5, help="Radial coefficients k0.. to fit (1-5)."),
        degree: int = typer.Option(4, "--degree", min=1, max=12, help="Total degree of the 2-D model."),
        no_prnu: bool = typer.Option(False, "--no-prnu", help="Do not compute the PRNU map."),
        method: str = typer.Option("sigma_clip", "--method", help="Combine: mean, median or sigma_clip."),
        sigma: float = typer.Option(3.0, "--sigma", help="Clipping threshold (sigma_clip)."),
        jobs: int = typer.Option(1, "--jobs", "-j", min=1, max=2, help="CPU cores to use (decoding processes; at "
                                 "most 2)."),
        as_json: bool = typer.Option(False, "--json", help="Print the model summary as JSON."),
    ) -> None:
        """Fit a per-channel vignetting model (DNG radial, optical centre free) and PRNU from flat fields."""
        if output.suffix.lower() != ".json":
            raise CamcalError("the flat model output must be a .json file", output)

        with progress() as bar:
            task = bar.add_task("flat frames", total=None)

            def tick(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total)

            options = FlatOptions(model, downsample, terms, degree, not no_prnu, method, sigma)
            dark_model = as_dark_model(dark)
            master = measure_flat(folder, dark_model, options, jobs=jobs, progress=tick)
            fm = fit_flat(master, dark_model, options)
        path = save_flat(fm, output)
        png_path = plot_path(plot, output.with_name(output.stem + ".falloff.png"))
        if png_path is not None:
            png_path = write_png(flat_figure(fm, master=master.value), png_path)
        summary = fm.summary()
        if as_json:
            print_json({**summary, "output": str(path), "png": str(png_path)})
            return
        table = Table(title=f"flat model ({summary['model']}, {summary['info'].get('n_frames')} frames)",
                      title_justify="left")
        for col in ("plane", "centre x,y (plane px)", "corner gain", "residual RMS", "PRNU RMS", "level (DN)"):
            table.add_column(col)
        for c in fm.channels:
            cx, cy = fm.centre_px[c]
            prnu = fm.prnu_rms.get(c)
            table.add_row(c, f"{cx:.2f}, {cy:.2f}", f"{summary['corner_gain'][c]:.4f}",
                          f"{100 * fm.residual_rms[c]:.3f} %", "—" if prnu is None else f"{100 * prnu:.3f} %",
                          f"{fm.level_dn.get(c, float('nan')):.1f}")
        console.print(table)
        console.print(f"flats at {flats_optics_text(summary)}", soft_wrap=True, markup=False, highlight=False)
        console.print(f"wrote {path}" + (f" and {png_path}" if png_path else ""))

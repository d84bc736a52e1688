"""``camcal sweep``: spectral sensitivity c(λ) per channel from a monochromator sweep (seed §3.1)."""

from __future__ import annotations

import warnings
from pathlib import Path

import typer
from rich.table import Table

from camcal.cli.common import console, err_console, print_json, progress
from camcal.errors import CamcalError
from camcal.plots import spectral_figure, write_png
from camcal.region import Region
from camcal.spectral import measure_sweep, read_sweep
from camcal.spectral_files import write_spectacle_csv


def register(app: typer.Typer) -> None:
    @app.command("sweep")
    def sweep_cmd(
        sweep: Path = typer.Argument(..., help="Sweep folder holding the frames and sweep.csv."),
        output: Path = typer.Option(..., "-o", "--output", help="Output CSV (SPECTACLE layout); metadata goes to "
                                    "<stem>.meta.json beside it."),
        dark: Path | None = typer.Option(None, "--dark", help="Dark model (camcal dark -o dark.json)."),
        flat: Path | None = typer.Option(None, "--flat", help="Flat model (camcal flat -o flat.json)."),
        mode: str = typer.Option("absolute", help="absolute (DN s^-1 per W m^-2 sr^-1 at the reference setting) "
                                 "or relative (peak 1)."),
        roi: str | None = typer.Option(None, "--roi", help="Region x,y,w,h in photo pixels at full resolution "
                                       "(rounded outward to whole plane pixels)."),
        roi_fraction: float | None = typer.Option(None, "--roi-fraction", help="A centred region covering this "
                                                  "fraction of each side (default 0.2: 4 % of the area)."),
        deconvolve: bool = typer.Option(False, help="Remove the monochromator slit function (needs bandwidth_nm)."),
        slit: str = typer.Option("gaussian", help="Slit function shape for --deconvolve: gaussian or triangular."),
        reference_iso: float = typer.Option(100.0, help="Reference ISO of the absolute result."),
        reference_f_number: float = typer.Option(4.0, help="Reference f-number of the absolute result."),
        png: Path | None = typer.Option(None, help="Plot of c(λ) (default <output stem>.png)."),
        jobs: int = typer.Option(2, help="Decoding threads."),
        as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
    ) -> None:
        """Measure c(λ) for R, G1, G2, B and write a SPECTACLE CSV and a PNG plot."""

        if output.suffix.lower() != ".csv":
            raise CamcalError("output must be a .csv file", output)
        if mode not in ("absolute", "relative"):
            raise CamcalError(f"--mode must be absolute or relative, got {mode!r}")
        if roi is not None and roi_fraction is not None:
            raise CamcalError("give --roi or --roi-fraction, not both")
        region: Region | float | None = Region.parse(roi) if roi is not None else roi_fraction
        total = len(read_sweep(sweep))
        with warnings.catch_warnings(record=True) as caught, progress() as bar:
            warnings.simplefilter("always")
            task = bar.add_task("sweep frames", total=total)
            result = measure_sweep(
                sweep, dark=dark, flat=flat, roi=region, mode=mode, deconvolve=deconvolve,  # type: ignore[arg-type]
                slit=slit, reference_iso=reference_iso, reference_f_number=reference_f_number,  # type: ignore[arg-type]
                jobs=jobs, progress=lambda done, n: bar.update(task, completed=done),
            )
        for msg in dict.fromkeys(" ".join(str(w.message).split()) for w in caught):
            err_console.print(f"camcal: warning: {msg}", soft_wrap=True, markup=False, highlight=False)
        write_spectacle_csv(result, output)
        png_path = png or output.with_suffix(".png")
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
        console.print(f"wrote {output} (+ {output.stem}.meta.json) and {png_path}")

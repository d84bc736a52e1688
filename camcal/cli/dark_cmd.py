"""``camcal dark [SESSION/dark] [--bias SESSION/bias] -o dark.json``; ``--bias`` alone is a bias-only calibration."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from camcal.calibrate.dark import fit_dark
from camcal.calibrate.dark_frames import DarkOptions, measure_dark
from camcal.cli.common import console, print_json, progress
from camcal.errors import CamcalError
from camcal.frame import PLANES
from camcal.models.dark import save_dark
from camcal.units import DN, DN_PER_S


def _num(value, fmt: str) -> str:
    """A table cell: the value, or "—" for a quantity the frames did not measure (None; the line under the
    table says "not calibrated")."""
    return "—" if value is None else format(value, fmt)


def register(app: typer.Typer) -> None:
    @app.command("dark")
    def dark_cmd(
        dark: Path | None = typer.Argument(None, help="Folder of RAW dark frames (two or more exposure times, or "
                                           "one with --bias); leave it out with --bias for a bias-only model."),
        bias: Path | None = typer.Option(None, "--bias", help="Folder of RAW bias frames (alone: a bias-only "
                                         "calibration: bias, read noise, noisy pixels; dark current unknown)."),
        output: Path = typer.Option(..., "-o", "--output", help="Output dark model (.json, maps beside it)."),
        method: str = typer.Option("sigma_clip", "--method", help="Combination of darks: mean, median, sigma_clip."),
        sigma: float = typer.Option(3.0, "--sigma", help="Sigma-clipping threshold."),
        jobs: int = typer.Option(2, "--jobs", "-j", help="CPU cores to use (decoding threads; "
                                                         "capped at the usable cores)."),
        as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON instead of a table."),
    ) -> None:
        """Fit bias, read noise, dark current and defects from bias and dark frames (or bias frames alone)."""
        if dark is None and bias is None:
            raise CamcalError("give a folder of dark frames, --bias FOLDER of bias frames, or both")
        with progress() as bar:
            task = bar.add_task("dark frames", total=None)

            def cb(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total)

            options = DarkOptions(method, sigma)
            model = fit_dark(measure_dark(dark, bias, options, jobs=jobs, progress=cb), options)
        save_dark(model, output)
        summary = model.summary()
        if as_json:
            print_json(summary)
            return
        temp = "—" if model.temperature_c is None else f"{model.temperature_c:.1f} °C"
        table = Table(title=f"Dark model → {output}  (ISO {model.iso:g}, {model.cfa_pattern}, {temp}, "
                            f"t = {', '.join(f'{t:g}' for t in model.exposure_times_s)} s)", title_justify="left")
        table.add_column("plane")
        for col in ("bias", "β", "±β", "σ read", "DSNU", "DSNU β", "hot", "dead", "noisy"):
            table.add_column(col, justify="right")
        for p in PLANES:
            c = model.channels[p]
            table.add_row(p, f"{c['bias_dn']:.2f}", _num(c.get("dark_current_dn_per_s"), ".4g"),
                          _num(c.get("dark_current_unc_dn_per_s"), ".1g"), f"{c['read_noise_dn']:.3f}",
                          f"{c['dsnu_bias_dn']:.3f}", _num(c.get("dsnu_dark_current_dn_per_s"), ".3g"),
                          str(c["hot_pixel_count"]), str(c["dead_pixel_count"]), str(c["noisy_pixel_count"]))
        console.print(table)
        console.print(f"bias, read noise (σ read) and bias DSNU in {DN}; dark current β and its DSNU in {DN_PER_S} "
                      f"at ISO {model.iso:g}")
        if not model.exposure_times_s or model.channels[PLANES[0]].get("dark_current_dn_per_s") is None:
            console.print("dark current β: not calibrated (bias frames only; apply subtracts the bias and says so)")
        console.print(f"defective pixels: {100 * summary['defect_fraction']:.3f} %  →  {output}")

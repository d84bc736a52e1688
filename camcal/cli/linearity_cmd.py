"""``camcal linearity FOLDER -o response.json``: fit seed eq. 12 per channel, RAW and JPEG, with a PNG per kind."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from camcal.calibrate.response import ResponseOptions, fit_response, measure_response
from camcal.cli.common import console, fraction, print_json, progress
from camcal.errors import CamcalError
from camcal.io.store import to_jsonable
from camcal.models.dark import load_dark
from camcal.models.response import save_response
from camcal.region import Region
from camcal.report.plots import response_figure, write_png


def register(app: typer.Typer) -> None:
    @app.command("linearity")
    def linearity_cmd(
        folder: Path = typer.Argument(..., help="Exposure series of a constant source (SESSION/linearity)."),
        out: Path = typer.Option(..., "-o", "--output", help="Response file to write (.json)."),
        roi: str | None = typer.Option(None, "--roi", help="Region x,y,w,h in photo pixels at full resolution "
                                       "(rounded outward to whole plane pixels)."),
        roi_fraction: float | None = typer.Option(None, "--roi-fraction", parser=fraction, help="('32%' or 0.32) "
                                                  "A centred region covering this fraction of each side "
                                                  "(default 0.316: 10 % of the area)."),
        dark: Path | None = typer.Option(None, "--dark", help="Dark model (camcal dark -o ...) to subtract from RAW."),
        reference_iso: float | None = typer.Option(
            None, "--reference-iso", help="Reference ISO (default: most common)."
        ),
        reference_f_number: float | None = typer.Option(
            None, "--reference-f-number", help="Reference f-number (default: most common)."
        ),
        plot: bool = typer.Option(True, "--plot/--no-plot", help="Write <out stem>.<kind>.png with data and fit."),
        as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON instead of a table."),
    ) -> None:
        """Fit g = α·x^γ + β (seed eq. 12) per channel; report linear range, saturation, EMVA 1288 LE, Pearson r."""

        if roi is not None and roi_fraction is not None:
            raise CamcalError("give --roi or --roi-fraction, not both")
        region = Region.parse(roi) if roi is not None else roi_fraction
        dark_model = load_dark(dark) if dark is not None else None
        with progress() as bar:
            task = bar.add_task("reading frames", total=None)

            def tick(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total)

            options = ResponseOptions(roi=region, reference_iso=reference_iso, reference_f_number=reference_f_number)
            models = fit_response(measure_response(folder, options, dark=dark_model, progress=tick))
        save_response(models, out)
        plots = []
        if plot:
            for kind, model in models.items():
                plots.append(str(write_png(response_figure(model), out.with_name(f"{out.stem}.{kind}.png"))))
        if as_json:
            print_json(to_jsonable(
                {"output": str(out), "plots": plots, "models": {k: m.summary() for k, m in models.items()}}
            ))
            return
        for kind, model in models.items():
            ref = f"ISO {model.reference_iso:g}, f/{model.reference_f_number:g}"
            table = Table(title=f"{kind} response (x: s at {ref})", title_justify="left")
            for col in ("channel", "α", "γ", "β [DN]", "linear range [DN]", "saturation [DN]", "LE [%]", "r"):
                table.add_column(col, justify="right")
            for name, ch in model.channels.items():
                table.add_row(
                    name, f"{ch.alpha:.5g} ± {ch.alpha_unc:.2g}", f"{ch.gamma:.4f} ± {ch.gamma_unc:.2g}",
                    f"{ch.beta:.2f} ± {ch.beta_unc:.2g}", f"{ch.linear_range_dn[0]:.1f} – {ch.linear_range_dn[1]:.1f}",
                    f"{ch.saturation_dn:g}", f"{ch.linearity_error_pct:.3f}", f"{ch.pearson_r:.5f}",
                )
            console.print(table)
            if model.tone:
                for name, t in model.tone["channels"].items():
                    console.print(f"  {name}: sRGB-form exponent {t['srgb']['exponent']:.4f}, inverse uses "
                                  f"{t['use']}, linearised spread {t['linearised_ratio_spread_pct']:.2f} %")
        console.print(f"wrote {out}" + (f" and {', '.join(plots)}" if plots else ""))

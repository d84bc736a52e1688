"""``camcal demo``: the whole pipeline on embedded, synthetic data."""

from __future__ import annotations

from pathlib import Path

import typer

from camcal.demo.lab import run_demo
from camcal.demo.phone import run_phone_demo
from camcal.errors import CamcalError


def register(app: typer.Typer) -> None:
    @app.command("demo")
    def demo_cmd(
        out: Path = typer.Option(Path("camcal-demo"), "-o", "--output", help="Folder for the demo's files."),
        preset_name: str = typer.Option("default", "--preset",
                                         help="Synthetic camera: default, imx296, hot or offsets "
                                              "(`camcal synth session --help`)."),
        layout: str = typer.Option("bayer", "--layout",
                                   help="RAW layout of every synthetic file: bayer (CFA mosaics) or linear "
                                        "(LinearRaw DNGs with R, G, B planes, as converters and phones write)."),
        phone: bool = typer.Option(False, "--phone", help="The phone route instead: a colour chart in the sun (camcal "
                                   "chart) to a profile, then the grey field (apply) and the Secchi disk (secchi) "
                                   "from DNG and HEIC."),
    ) -> int:
        """Synthesise a calibration session and Secchi-disk photos, run every stage, print truth vs recovered."""
        if phone:
            return 0 if run_phone_demo(out)["ok"] else 1

        if layout not in ("bayer", "linear"):
            raise CamcalError(f"unknown layout {layout!r}; choose bayer or linear")
        return 0 if run_demo(out, preset_name=preset_name, layout=layout)["ok"] else 1

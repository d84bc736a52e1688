"""``camcal demo``: the whole pipeline on embedded, synthetic data."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("demo")
    def demo_cmd(
        out: Path = typer.Option(Path("camcal-demo"), "--out", help="Folder for the demo's files."),
    ) -> None:
        """Synthesise a calibration session and survey photos, run every stage, print truth vs recovered."""
        from camcal.demo import run_demo

        run_demo(out)

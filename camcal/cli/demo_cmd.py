"""``camcal demo``: the whole pipeline on embedded, synthetic data."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("demo")
    def demo_cmd(
        out: Path = typer.Option(Path("camcal-demo"), "--out", help="Folder for the demo's files."),
    ) -> int:
        """Synthesise a calibration session and Secchi-disk photos, run every stage, print truth vs recovered."""
        from camcal.demo import run_demo

        return 0 if run_demo(out)["ok"] else 1

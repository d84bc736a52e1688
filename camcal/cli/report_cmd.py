"""``camcal report PROFILE -o report.html``: a self-contained HTML report of a calibration profile."""

from __future__ import annotations

from pathlib import Path

import typer

from camcal.cli.common import console, progress
from camcal.models.profile import load_profile
from camcal.report.page import write_report


def register(app: typer.Typer) -> None:
    @app.command("report")
    def report_cmd(
        profile: Path = typer.Argument(..., help="Profile file (.camcal)."),
        output: Path | None = typer.Option(None, "-o", "--output",
                                           help="HTML file to write (default: PROFILE with the suffix .html)."),
    ) -> None:
        """Write a self-contained HTML report (plots embedded, no external resources) of a profile."""

        out = output if output is not None else profile.with_suffix(".html")
        loaded = load_profile(profile)
        with progress() as bar:
            task = bar.add_task("report", total=None)

            def tick(section: str, done: int, total: int) -> None:
                bar.update(task, description=f"report: {section}", completed=done, total=total)

            write_report(loaded, out, progress=tick)
        missing = [k for k, done in loaded.stages().items() if not done]
        note = f"; not calibrated: {', '.join(missing)}" if missing else ""
        console.print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB){note}")

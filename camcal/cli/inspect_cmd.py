"""``camcal inspect FILE... [--json]``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from camcal.cli.common import console, print_json
from camcal.inspect import describe


def register(app: typer.Typer) -> None:
    @app.command("inspect")
    def inspect_cmd(
        files: list[Path] = typer.Argument(..., help="RAW, JPEG, TIFF or PNG files."),
        as_json: bool = typer.Option(False, "--json", help="Print machine-readable JSON (a list, one object a file)."),
    ) -> None:
        """Show CFA pattern, black/white levels, size and exposure metadata of image files."""
        infos = [describe(f) for f in files]
        if as_json:
            print_json(infos)
            return
        for info in infos:
            table = Table(title=str(info["file"]), show_header=False, title_justify="left")
            for key, value in info.items():
                if key != "file":
                    table.add_row(key, "—" if value is None else str(value))
            console.print(table)

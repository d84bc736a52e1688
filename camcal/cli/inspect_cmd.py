"""``camcal inspect FILE... [--json]``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from camcal.cli.common import console, err_console, print_json
from camcal.frame import TRACKED
from camcal.inspect import describe, describe_many

_UNITS = {"exposure_s": " s", "exposure_value_s": " s", "white_level_dn": " DN"}


def _cell(key: str, info: dict) -> str:
    value = info[key]
    if key in TRACKED:
        src = info["sources"][key]
        return "unknown" if value is None else f"{value}{_UNITS.get(key, '')}  ({src})"
    if value is None:
        return "—"
    if key == "notes":
        return "; ".join(value) if value else "—"
    return f"{value}{_UNITS.get(key, '')}"


def register(app: typer.Typer) -> None:
    @app.command("inspect")
    def inspect_cmd(
        files: list[Path] = typer.Argument(..., help="RAW, JPEG, TIFF or PNG files."),
        as_json: bool = typer.Option(False, "--json", help="Print machine-readable JSON (a list, one object a file)."),
    ) -> None:
        """Show layout, CFA pattern, black/white levels, size and exposure metadata (value and source) of images.

        Every readable file is reported; unreadable ones are listed (exit code 1 when some failed,
        2 when the only file given cannot be read).
        """
        # one file: its error is the command's (exit 2); several: every readable one is reported
        entries, failures = ([describe(files[0])], []) if len(files) == 1 else describe_many(files)
        if as_json:
            print_json(entries)
        else:
            for info in entries:
                if info.get("error"):
                    continue
                table = Table(title=str(info["file"]), show_header=False, title_justify="left")
                for key in info:
                    if key not in ("file", "sources", "error"):
                        table.add_row(key, _cell(key, info))
                console.print(table)
            if failures:
                console.print(f"{len(entries) - len(failures)} of {len(entries)} files read; "
                              f"{len(failures)} could not be read (listed on stderr)")
        for f in failures:
            err_console.print(f"camcal: failed: {f['error']}", markup=False, highlight=False, soft_wrap=True)
        if failures:
            raise typer.Exit(1)

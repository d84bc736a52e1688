"""``camcal inspect FILE... [--json]``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from camcal.cli.common import console, err_console, print_json
from camcal.frame import PLACE_TIME, TRACKED
from camcal.inspect import SUN_KEYS, describe, describe_many
from camcal.sun import parse_sun_option

_UNITS = {"exposure_s": " s", "focal_length_mm": " mm", "exposure_value_s": " s", "white_level_dn": " DN",
          "latitude_deg": "°", "longitude_deg": "°", "altitude_m": " m", "zenith_deg": "°", "azimuth_deg": "°",
          "apparent_zenith_deg": "°"}


def _sun_rows(sun: dict) -> list[tuple[str, str]]:
    if sun.get("source") is None:
        return [(f"sun.{k}", "unknown") for k in SUN_KEYS[:2]] + [("sun.source", f"— ({sun.get('reason')})")]
    return [(f"sun.{k}", f"{sun[k]:.3f}{_UNITS[k]}" if k != "source" else str(sun[k])) for k in SUN_KEYS]


def _cell(key: str, info: dict) -> str:
    value = info[key]
    if key == "capture_time_utc":
        return "unknown" if value is None else f"{value}  ({info['time_source']})"
    if key in TRACKED or key in PLACE_TIME:
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
        files: list[Path] = typer.Argument(..., help="RAW, JPEG, HEIC/HEIF, TIFF or PNG files."),
        as_json: bool = typer.Option(False, "--json", help="Print machine-readable JSON (a list, one object a file)."),
        sun_text: str | None = typer.Option(None, "--sun", metavar="ZENITH,AZIMUTH",
                                            help="The sun's zenith angle and azimuth (degrees, azimuth clockwise "
                                                 "from north), replacing the one computed from the photos' "
                                                 "capture time and GPS position."),
    ) -> None:
        """Show layout, CFA pattern, black/white levels, size, exposure metadata (value and source), capture
        time (local, offset, UTC and its source), GPS position and the sun's position of images.

        Every readable file is reported; unreadable ones are listed (exit code 1 when some failed,
        2 when the only file given cannot be read).
        """
        sun = parse_sun_option(sun_text) if sun_text is not None else None
        # one file: its error is the command's (exit 2); several: every readable one is reported
        entries, failures = ([describe(files[0], sun)], []) if len(files) == 1 else describe_many(files, sun)
        if as_json:
            print_json(entries)
        else:
            for info in entries:
                if info.get("error"):
                    continue
                table = Table(title=str(info["file"]), show_header=False, title_justify="left")
                for key in info:
                    if key == "sun":
                        for row in _sun_rows(info["sun"]):
                            table.add_row(*row)
                    elif key not in ("file", "sources", "error", "time_source"):
                        table.add_row(key, _cell(key, info))
                console.print(table)
            if failures:
                console.print(f"{len(entries) - len(failures)} of {len(entries)} files read; "
                              f"{len(failures)} could not be read (listed on stderr)")
        for f in failures:
            err_console.print(f"camcal: failed: {f['error']}", markup=False, highlight=False, soft_wrap=True)
        if failures:
            raise typer.Exit(1)

"""``camcal inspect FILE... [--json]``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from camcal.calibrate.inspect import SUN_KEYS, describe, describe_many
from camcal.cli.common import console, err_console, print_json
from camcal.frame import PLACE_TIME, TRACKED
from camcal.io.sun import parse_sun_option

_UNITS = {"exposure_s": " s", "focal_length_mm": " mm", "exposure_value_s": " s", "white_level_dn": " DN",
          "latitude_deg": "°", "longitude_deg": "°", "altitude_m": " m", "zenith_deg": "°", "azimuth_deg": "°",
          "apparent_zenith_deg": "°"}


def _sun_rows(sun: dict) -> list[tuple[str, str]]:
    if sun.get("source") is None:
        return [(f"sun.{k}", "unknown") for k in SUN_KEYS[:2]] + [("sun.source", f"— ({sun.get('reason')})")]
    return [(f"sun.{k}", f"{sun[k]:.3f}{_UNITS[k]}" if k != "source" else str(sun[k])) for k in SUN_KEYS]


def _g(value, digits: int = 6) -> str:
    """A number with at most ``digits`` significant digits (integers as they are)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return str(value)
    return str(value) if isinstance(value, int) else f"{value:.{digits}g}"


def _levels(levels) -> str:
    if isinstance(levels, dict):
        vals = {_g(v) for v in levels.values()}
        return f"{vals.pop()} DN (every plane)" if len(vals) == 1 else ", ".join(f"{k} {_g(v)}" for k, v in
                                                                                  levels.items()) + " DN"
    return "unknown" if levels is None else f"{_g(levels)} DN"


def _src(info: dict, key: str) -> str:
    src = info["sources"].get(key)
    return f"  ({src})" if src else ""


def _summary_rows(info: dict) -> list[tuple[str, str]]:
    """What a user needs of a photo, one row each, sensible digits (``--all`` for every field)."""
    def known(key, fmt):
        v = info.get(key)
        return "unknown" if v is None else fmt(v) + _src(info, key)

    cam = " ".join(str(v) for v in (info.get("make"), info.get("model")) if v) or "unknown"
    if info.get("serial"):
        cam += f" (serial {info['serial']})"
    layout = f"{info.get('kind')} {info.get('format')}, {info.get('width')} × {info.get('height')} px"
    if info.get("cfa_pattern"):
        layout += f", {info.get('layout')} {info['cfa_pattern']}"
    if info.get("bit_depth"):
        layout += f", {info['bit_depth']} bit"
    if info.get("icc_profile"):
        layout += f", colour profile {info['icc_profile']}"
    rows = [("file type", layout), ("camera", cam),
            ("black / white level", f"{_levels(info.get('black_level_dn'))} / {_levels(info.get('white_level_dn'))}"),
            ("exposure time", known("exposure_s", lambda v: f"{_g(v, 4)} s")),
            ("f-number", known("f_number", lambda v: f"f/{_g(v, 3)}")),
            ("ISO", known("iso", lambda v: _g(v, 5))),
            ("focal length", known("focal_length_mm", lambda v: f"{_g(v, 4)} mm")),
            ("capture time (camera clock)", known("capture_time", str)),
            ("capture time (UTC)", "unknown" if info.get("capture_time_utc") is None
             else f"{info['capture_time_utc']}  ({info.get('time_source')})")]
    lat, lon = info.get("latitude_deg"), info.get("longitude_deg")
    if lat is None or lon is None:
        rows.append(("GPS position", "unknown"))
    else:
        alt = info.get("altitude_m")
        rows.append(("GPS position", f"{lat:.5f}° N, {lon:.5f}° E" + ("" if alt is None else f", {alt:.1f} m")
                     + _src(info, "latitude_deg")))
    sun = info.get("sun") or {}
    if sun.get("source") is None:
        rows.append(("sun", f"unknown ({sun.get('reason')})"))
    else:
        rows.append(("sun", f"zenith {sun['zenith_deg']:.2f}°, azimuth {sun['azimuth_deg']:.2f}°  ({sun['source']})"))
    if info.get("saturated_pct") is not None:
        rows.append(("saturated pixels", f"{_g(info['saturated_pct'], 3)} %"
                     + (f": {info['saturated']}" if info.get("saturated") else "")))
    if info.get("notes"):
        rows.append(("notes", "; ".join(info["notes"])))
    return rows


def _cell(key: str, info: dict) -> str:
    value = info[key]
    if isinstance(value, float):
        value = _g(value)
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
        show_all: bool = typer.Option(False, "--all", help="Show every field (default: what a user needs)."),
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
                if not show_all:
                    for row in _summary_rows(info):
                        table.add_row(*row)
                    console.print(table)
                    continue
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

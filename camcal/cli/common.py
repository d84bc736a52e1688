"""Helpers shared by CLI modules: console, progress bars (from :mod:`camcal.terminal`), JSON output."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from camcal.terminal import console, err_console, progress, track

__all__ = ["console", "err_console", "plot_path", "print_json", "progress", "track"]


def print_json(obj: object) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, sort_keys=False, allow_nan=False, default=str) + "\n")


def plot_path(png: Path | None, plot: bool, default: Path) -> Path | None:
    """Where to write a command's plot: ``default`` with ``--plot`` (the default), None with ``--no-plot``.

    The old ``--png PATH`` still names the file for one release, with a deprecation line.
    """
    if png is not None:
        print(f"camcal: deprecated: --png PATH is now --plot/--no-plot (the plot goes to {default.name}); "
              "--png is removed in camcal 0.3", file=sys.stderr)
        return png if plot else None
    return default if plot else None

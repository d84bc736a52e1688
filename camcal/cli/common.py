"""Helpers shared by CLI modules: console, progress bars (from :mod:`camcal.terminal`), JSON output."""

from __future__ import annotations

import json
import sys

from camcal.terminal import console, err_console, progress, track

__all__ = ["console", "err_console", "print_json", "progress", "track"]


def print_json(obj: object) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, sort_keys=False, allow_nan=False, default=str) + "\n")

"""Helpers shared by CLI modules: console, progress bars (from :mod:`camcal.io.terminal`), JSON output."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from camcal.errors import CamcalError
from camcal.io.terminal import console, err_console, progress, track

__all__ = ["console", "err_console", "fraction", "one_output", "plot_path", "print_json", "progress", "track"]


def print_json(obj: object) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, sort_keys=False, allow_nan=False, default=str, ensure_ascii=False)
                     + "\n")


def plot_path(plot: bool, default: Path) -> Path | None:
    """Where to write a command's plot: ``default`` with ``--plot`` (the default), None with ``--no-plot``."""
    return default if plot else None


def one_output(positional: Path | None, option: Path | None, what: str) -> Path:
    """The output path given as the command's argument or as ``-o/--output`` (one of them, not both)."""
    if positional is not None and option is not None and positional != option:
        raise CamcalError(f"give {what} once: as the argument or as -o/--output, not both")
    out = option if option is not None else positional
    if out is None:
        raise CamcalError(f"give {what}: -o/--output PATH")
    return out


def fraction(text: str | float | None) -> float | None:
    """A relative amount as '3%' or as the fraction '0.03' (None stays None); for ``parser=`` of an option."""
    if text is None or isinstance(text, float):
        return text
    t = str(text).strip()
    try:
        value = float(t[:-1]) / 100.0 if t.endswith("%") else float(t)
    except ValueError:
        raise CamcalError(f"cannot read {text!r}: give a percentage (3%) or a fraction (0.03)") from None
    return value

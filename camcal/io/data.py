"""Access to the reference tables in the ``calibration_data`` package."""

from __future__ import annotations

import io
from importlib import resources

import numpy as np

from camcal.errors import CamcalError


def data_text(name: str) -> str:
    """Text of a file shipped in ``calibration_data``."""
    try:
        return resources.files("calibration_data").joinpath(name).read_text(encoding="utf-8")
    except (FileNotFoundError, ModuleNotFoundError):
        raise CamcalError(f"shipped data file {name!r} not found (broken install?)") from None


def read_bundled_table(name: str) -> tuple[list[str], np.ndarray]:
    """A shipped CSV as (column names, float array (rows, columns)); ``#`` lines are comments."""
    lines = [ln for ln in data_text(name).splitlines() if ln.strip() and not ln.startswith("#")]
    header = [h.strip() for h in lines[0].split(",")]
    values = np.loadtxt(io.StringIO("\n".join(lines[1:])), delimiter=",", ndmin=2)
    return header, values

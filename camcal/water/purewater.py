"""Pure-water absorption a_w(λ): Pope & Fry (1997), 380–727.5 nm in 2.5 nm steps.

The table ships as ``calibration_data/water_absorption_pope_fry_1997.csv`` (m⁻¹, natural log; source and the
two repository copies it was checked against are in the file's header). Between nodes a_w is interpolated
linearly; outside the table it is held at the end value (the red channel of a camera with an IR-cut filter
sees little beyond 727.5 nm, where a_w keeps rising: holding the end value under-states it there).

References
----------
Pope, R. M., Fry, E. S. (1997). Absorption spectrum (380–700 nm) of pure water. II. Integrating cavity
measurements. Applied Optics 36(33), 8710–8723, doi:10.1364/AO.36.008710.
"""

from __future__ import annotations

import functools

import numpy as np

from camcal.io.data import read_bundled_table

POPE_FRY_FILE = "water_absorption_pope_fry_1997.csv"


@functools.lru_cache(maxsize=1)
def pope_fry_1997() -> tuple[np.ndarray, np.ndarray]:
    """The table as (wavelength_nm, a_w_per_m) arrays (read-only copies)."""

    header, v = read_bundled_table(POPE_FRY_FILE)
    wl = v[:, header.index("wavelength_nm")].copy()
    a = v[:, header.index("a_w_per_m")].copy()
    wl.flags.writeable = False
    a.flags.writeable = False
    return wl, a


def pure_water_absorption_per_m(wavelength_nm):
    """a_w(λ) in m⁻¹ (natural log) at ``wavelength_nm`` (any shape): Pope & Fry (1997), linear interpolation,
    end values held outside 380–727.5 nm."""
    wl, a = pope_fry_1997()
    return np.interp(np.asarray(wavelength_nm, dtype=float), wl, a)

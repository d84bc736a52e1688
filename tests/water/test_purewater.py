"""Tests of :mod:`camcal.water.purewater`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

import numpy as np
import pytest

from camcal.water.purewater import pure_water_absorption_per_m


@pytest.mark.formula
def test_pure_water_absorption_is_pope_and_fry():
    """Pope & Fry (1997), table 3: a_w = 0.00635, 0.0204, 0.2224, 0.410, 0.624 m⁻¹ at 440, 500, 600, 660, 700 nm;
    linear between the 2.5 nm nodes (662.5 nm: 0.429 m⁻¹) and the end values held outside 380-727.5 nm."""
    got = pure_water_absorption_per_m(np.array([440.0, 500.0, 600.0, 660.0, 700.0]))
    np.testing.assert_allclose(got, [0.00635, 0.0204, 0.2224, 0.410, 0.624], rtol=1e-9)
    mid = float(pure_water_absorption_per_m(661.25))
    assert mid == pytest.approx(0.5 * (0.410 + float(pure_water_absorption_per_m(662.5))), rel=1e-12)
    assert float(pure_water_absorption_per_m(300.0)) == float(pure_water_absorption_per_m(380.0))

"""Tests of :mod:`camcal.water.units`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

import numpy as np
import pytest

from camcal.water.units import (
    parse_concentration_mol_per_L,
    parse_epsilon_L_per_mol_cm,
    parse_length_m,
    specific_absorption_m2_per_mg,
)


@pytest.mark.formula
def test_unit_strings_are_converted_with_the_molar_mass_and_si_prefixes():
    """The water module's unit strings against conversions written out: SI prefixes (µ = 1e-6, n = 1e-9, c = 1e-2,
    m = 1e-3), the molar mass of chlorophyll-a (893.5 g/mol, C55H72MgN4O5) and the bare-number defaults (mol/L,
    L/mol/cm, metres)."""
    m = 893.5  # g/mol, written out (IUPAC standard atomic weights: 55·12.011 + 72·1.008 + 24.305 + 4·14.007 + 5·15.999)
    assert parse_concentration_mol_per_L("2e-7") == pytest.approx(2e-7, rel=1e-15)
    assert parse_concentration_mol_per_L("2e-7mol/L") == pytest.approx(2e-7, rel=1e-15)
    assert parse_concentration_mol_per_L("3umol/L") == pytest.approx(3e-6, rel=1e-15)
    assert parse_concentration_mol_per_L("40 nmol/l") == pytest.approx(40e-9, rel=1e-15)
    assert parse_concentration_mol_per_L("0.17870g/L") == pytest.approx(0.1787 / m, rel=1e-15)
    assert parse_concentration_mol_per_L("89ug/L") == pytest.approx(89e-6 / m, rel=1e-15)
    assert parse_epsilon_L_per_mol_cm("78628") == pytest.approx(78628.0, rel=1e-15)
    assert parse_epsilon_L_per_mol_cm("78628L/mol/cm") == pytest.approx(78628.0, rel=1e-15)
    assert parse_epsilon_L_per_mol_cm("88L/g/cm") == pytest.approx(88.0 * m, rel=1e-15)
    assert parse_epsilon_L_per_mol_cm("0.088L/mg/cm") == pytest.approx(88.0 * m, rel=1e-12)
    assert parse_length_m("0.3") == pytest.approx(0.3, rel=1e-15)
    assert parse_length_m("20cm") == pytest.approx(0.2, rel=1e-15)
    assert parse_length_m("250mm") == pytest.approx(0.25, rel=1e-15)
    # a* (natural log, m² mg⁻¹) of a decadic ε in L g⁻¹ cm⁻¹: 1 L = 1e-3 m³, 1 g = 1e3 mg, 1 cm = 1e-2 m
    assert specific_absorption_m2_per_mg(88.0) == pytest.approx(np.log(10) * 88.0 * 1e-3 / (1e3 * 1e-2), rel=1e-12)

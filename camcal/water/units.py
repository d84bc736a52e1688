"""Units of the water module (seed §1.3, corrected; see docs/water.md).

The seed's units are inconsistent: its ε = 0.088 "cm⁻¹/g" for chlorophyll-a at 663 nm is, numerically,
a decadic specific absorption coefficient in L mg⁻¹ cm⁻¹ (= 88 L g⁻¹ cm⁻¹; compare Porra et al. 1989:
85.96 L g⁻¹ cm⁻¹ at 663.6 nm in 80 % acetone, and Jeffrey & Humphrey 1975: 87.65 L g⁻¹ cm⁻¹ at 664 nm in
90 % acetone). Internally camcal uses

- concentration C in mol/L (the seed's unit), reported also in µg/L (= mg m⁻³);
- ε decadic, in L mol⁻¹ cm⁻¹;
- depth in metres;
- optical depth τ = ln(10) ε C d (natural, one way, vertical; d in cm inside that product).

References
----------
Porra, R. J., Thompson, W. A., Kriedemann, P. E. (1989). Biochim. Biophys. Acta 975, 384-394.
Jeffrey, S. W., Humphrey, G. F. (1975). Biochem. Physiol. Pflanzen 167, 191-194.
"""

from __future__ import annotations

import math
import re

import numpy as np

from camcal.errors import CamcalError

#: Molar mass of chlorophyll-a, C55H72MgN4O5, g/mol.
CHLA_MOLAR_MASS_G_PER_MOL = 893.5
#: The seed's ε (0.088, read as L mg⁻¹ cm⁻¹), in L g⁻¹ cm⁻¹.
EPSILON_SEED_L_PER_G_CM = 88.0
#: Named ε presets in L g⁻¹ cm⁻¹ at the red peak (in solvent).
EPSILON_PRESETS_L_PER_G_CM = {
    "seed": EPSILON_SEED_L_PER_G_CM,  # seed §1.4, units corrected
    "porra1989": 85.96,  # Porra et al. 1989, 80 % acetone, 663.6 nm
    "jeffrey-humphrey1975": 87.65,  # Jeffrey & Humphrey 1975, 90 % acetone, 664 nm
}
LN10 = math.log(10.0)


def epsilon_L_per_mol_cm(epsilon_L_per_g_cm: float) -> float:
    """Specific (L g⁻¹ cm⁻¹) to molar (L mol⁻¹ cm⁻¹) decadic absorption coefficient of chlorophyll-a."""
    return float(epsilon_L_per_g_cm) * CHLA_MOLAR_MASS_G_PER_MOL


def epsilon_L_per_g_cm(epsilon_L_per_mol_cm_: float) -> float:
    """Molar (L mol⁻¹ cm⁻¹) to specific (L g⁻¹ cm⁻¹) decadic absorption coefficient of chlorophyll-a."""
    return float(epsilon_L_per_mol_cm_) / CHLA_MOLAR_MASS_G_PER_MOL


#: The seed's ε in L mol⁻¹ cm⁻¹ (88 L g⁻¹ cm⁻¹ × 893.5 g/mol = 78 628).
EPSILON_SEED_L_PER_MOL_CM = epsilon_L_per_mol_cm(EPSILON_SEED_L_PER_G_CM)


def mol_per_L_to_ug_per_L(c_mol_per_L):
    """Chlorophyll-a concentration mol/L → µg/L (= mg m⁻³)."""
    return np.asarray(c_mol_per_L, dtype=float) * CHLA_MOLAR_MASS_G_PER_MOL * 1e6


def ug_per_L_to_mol_per_L(c_ug_per_L):
    """Chlorophyll-a concentration µg/L (= mg m⁻³) → mol/L."""
    return np.asarray(c_ug_per_L, dtype=float) / (CHLA_MOLAR_MASS_G_PER_MOL * 1e6)


def specific_absorption_m2_per_mg(epsilon_L_per_g_cm_: float) -> float:
    """Natural-log chlorophyll-specific absorption a* (m² mg⁻¹) from decadic ε (L g⁻¹ cm⁻¹): a* = 2.303e-4 ε."""
    return LN10 * 1e-4 * float(epsilon_L_per_g_cm_)


_NUM = r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*"
_LENGTH = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
_CONC = {"mol/l": 1.0, "m": 1.0, "umol/l": 1e-6, "nmol/l": 1e-9,
         "ug/l": None, "µg/l": None, "mg/m3": None, "mg/m^3": None, "g/l": "g"}
_EPS = {"l/mol/cm": "mol", "lmol-1cm-1": "mol", "l/g/cm": "g", "lg-1cm-1": "g", "l/mg/cm": "mg", "lmg-1cm-1": "mg"}


_EXAMPLE = {"depth": "'0.2m'", "concentration": "'89ug/L'", "epsilon": "'88L/g/cm'"}


def _split(text: str, what: str) -> tuple[float, str]:
    m = re.fullmatch(_NUM + r"([^\s]*)\s*", str(text))
    if not m:
        raise CamcalError(f"cannot read {what} {text!r}: expected a number with a unit, "
                          f"e.g. {_EXAMPLE.get(what, repr('0.2m'))}")
    value = float(m.group(1))
    if not math.isfinite(value):  # '1e400' overflows to inf
        raise CamcalError(f"{what} {text!r} is out of range (not a finite number)")
    return value, m.group(2).strip().lower().replace(" ", "")


def parse_length_m(text: str, default_unit: str = "m") -> float:
    """'0.2m', '20cm', '200mm' or a bare number (in ``default_unit``) → metres."""
    value, unit = _split(text, "depth")
    unit = unit or default_unit
    if unit not in _LENGTH:
        raise CamcalError(f"unknown length unit {unit!r} in {text!r}; use m, cm or mm")
    return value * _LENGTH[unit]


def parse_concentration_mol_per_L(text: str) -> float:
    """'1e-7mol/L', '89ug/L', '89mg/m3', '0.1umol/L' (bare number: mol/L) → mol/L."""
    value, unit = _split(text, "concentration")
    unit = unit or "mol/l"
    if unit not in _CONC:
        raise CamcalError(f"unknown concentration unit {unit!r} in {text!r}; use mol/L, umol/L, ug/L or mg/m3")
    factor = _CONC[unit]
    if factor is None:
        return float(ug_per_L_to_mol_per_L(value))
    if factor == "g":
        return value / CHLA_MOLAR_MASS_G_PER_MOL
    return value * factor


def parse_epsilon_L_per_mol_cm(text: str) -> float:
    """ε as '78628L/mol/cm', '88L/g/cm', '0.088L/mg/cm' or a preset name → L mol⁻¹ cm⁻¹."""
    key = str(text).strip().lower()
    if key in EPSILON_PRESETS_L_PER_G_CM:
        return epsilon_L_per_mol_cm(EPSILON_PRESETS_L_PER_G_CM[key])
    value, unit = _split(text, "epsilon")
    unit = unit or "l/mol/cm"
    if unit not in _EPS:
        raise CamcalError(
            f"unknown epsilon unit {unit!r} in {text!r}; use L/mol/cm, L/g/cm, L/mg/cm or a preset "
            f"({', '.join(EPSILON_PRESETS_L_PER_G_CM)})"
        )
    kind = _EPS[unit]
    if kind == "mol":
        return value
    if kind == "g":
        return epsilon_L_per_mol_cm(value)
    return epsilon_L_per_mol_cm(value * 1e3)

"""One unit string per quantity (issue 30 item 8): camcal writes each unit from the table in camcal.units.

Two checks over every module of camcal/: no other spelling of those units anywhere (code, docstrings,
comments), and no unit string written as a literal in code outside camcal.units (docstrings may name units).
Each check is shown to fail on a line that breaks it.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from camcal import units

ROOT = Path(__file__).resolve().parents[1]

#: Spellings of the table's units that camcal does not write (ASCII exponents, slashes, another order).
OTHER_SPELLINGS = {
    "radiance": re.compile(r"W ?m\^?-2|W ?/ ?m\^?2|W m\*\*-2|W ?/ ?\(m|sr\^?-1\b|nm\^?-1\b|\^-[12]\b"),
    "DN rate": re.compile(r"DN ?/ ?s\b|DN/sec|DN s-1\b"),
    "electrons": re.compile(r"(?<![\w.])e(?:-|\^-)(?=[\s/)\]]|$)|DN/e-"),
    "concentration": re.compile(r"\bug/L\b|µg/l\b|µg L⁻¹|\bug L\b"),
}
#: Typed input the parsers accept and name in their messages (ASCII, for a keyboard), not units camcal writes.
INPUT_SPELLINGS = {"camcal/water/units.py": ("ug/L", "µg/l"), "camcal/water/band.py": ("ug/L", "µg/l"),
                   "camcal/cli/water_cmd.py": ("'89ug/L'",)}

#: The table's strings a literal in code may not hold (it takes them from camcal.units).
TABLE = (units.IN_BAND_RADIANCE, units.DN_PER_S, units.ELECTRONS, units.CONCENTRATION)


def _modules():
    for p in sorted((ROOT / "camcal").rglob("*.py")):
        yield str(p.relative_to(ROOT)), p.read_text()


def other_spellings(rel: str, text: str) -> list[str]:
    found = []
    for n, line in enumerate(text.splitlines(), 1):
        for allowed in INPUT_SPELLINGS.get(rel, ()):
            line = line.replace(allowed, "")
        found += [f"{rel}:{n}: {what}: {line.strip()[:100]}" for what, rx in OTHER_SPELLINGS.items()
                  if rx.search(line)]
    return found


def literal_units(rel: str, text: str) -> list[str]:
    """Unit strings of the table in string literals of code (docstrings excluded)."""
    tree = ast.parse(text)
    docs = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant)}
    return [f"{rel}:{n.lineno}: {n.value[:100]!r}" for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs
            and any(u in n.value for u in TABLE)]


def test_no_other_spelling_of_a_unit_in_camcal():
    found = [f for rel, text in _modules() if rel != "camcal/units.py" for f in other_spellings(rel, text)]
    assert found == []


def test_unit_strings_come_from_the_table():
    found = [f for rel, text in _modules() if rel != "camcal/units.py" for f in literal_units(rel, text)]
    assert found == []


@pytest.mark.parametrize("line", ['units = "W m^-2 sr^-1 nm^-1"', "# 3 DN/s at ISO 100", 'msg = "K in DN/e-"',
                                  "print(f'{c} ug/L')", "x = 'W/m2/sr/nm'", "gain: 1.6 e- per DN"])
def test_the_spelling_check_sees_another_spelling(line):
    assert other_spellings("camcal/x.py", line)


def test_the_spelling_check_lets_numbers_and_input_spellings_pass():
    assert other_spellings("camcal/x.py", "tol = 1e-6; x = a ** -1; y = 2.5e-2") == []
    assert other_spellings("camcal/cli/water_cmd.py", "help=\"e.g. '89ug/L'\"") == []


def test_the_table_check_sees_a_literal_and_not_a_docstring():
    src = 'def f():\n    """β in DN s⁻¹."""\n    return "β [DN s⁻¹]"\n'
    assert literal_units("camcal/x.py", src) == ["camcal/x.py:3: 'β [DN s⁻¹]'"]


def test_the_conventions_doc_shows_the_table():
    doc = (ROOT / "docs" / "conventions.md").read_text()
    for u in (units.DN, units.DN_PER_S, units.ELECTRONS, units.SPECTRAL_RADIANCE, units.IN_BAND_RADIANCE,
              units.SPECTRAL_SENSITIVITY, units.CONCENTRATION):
        assert u in doc, u

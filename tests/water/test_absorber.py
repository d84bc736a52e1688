"""Dyes and other absorbers from a CSV: ε per gram, ε per mole, or a spectrophotometer's absorbance."""

from __future__ import annotations

import json

import numpy as np
import pytest

from camcal.errors import CamcalError
from camcal.water.band import read_absorber_csv
from tests.conftest import assert_one_line_error, run_cli

WL = np.arange(400.0, 781.0, 5.0)
MOLAR_MASS = 792.85  # g/mol, as for Brilliant Blue FCF (E133)
# a Gaussian stand-in for a blue food dye: peak 630 nm, 1.3e5 L mol⁻¹ cm⁻¹, σ 35 nm (not a measured spectrum)
EPS_MOL = 1.3e5 * np.exp(-0.5 * ((WL - 630.0) / 35.0) ** 2)


def _write(path, header, column, comments=()):
    rows = "\n".join(f"{w:g},{v:.12g}" for w, v in zip(WL, column, strict=True))
    path.write_text("".join(f"# {c}\n" for c in comments) + f"wavelength_nm,{header}\n{rows}\n")
    return path


def test_three_forms_agree(tmp_path):
    eps_g = EPS_MOL / MOLAR_MASS
    a = read_absorber_csv(_write(tmp_path / "g.csv", "epsilon_L_per_g_cm", eps_g))
    b = read_absorber_csv(_write(tmp_path / "mol.csv", "epsilon_L_per_mol_cm", EPS_MOL,
                                 [f"molar_mass_g_per_mol: {MOLAR_MASS}"]))
    # a spectrophotometer: 5 mg/L in a 10 mm cuvette → A = ε_g · 0.005 g/L · 1 cm (peak ≈ 0.82)
    absorbance = eps_g * 0.005 * 1.0
    c = read_absorber_csv(_write(tmp_path / "abs.csv", "absorbance", absorbance,
                                 ["concentration: 5 mg/L", "path_length = 10 mm", "instrument: any"]))
    d = read_absorber_csv(_write(tmp_path / "absm.csv", "absorbance", EPS_MOL * 1e-6,
                                 ["concentration: 1 umol/L", f"molar_mass_g_per_mol: {MOLAR_MASS}",
                                  "path_length: 1 cm"]))
    for x in (b, c, d):
        np.testing.assert_allclose(x.coefficient_m2_per_mg, a.coefficient_m2_per_mg, rtol=1e-9)
        assert np.all(x.exponent == 1.0)
    # a = 2.303e-4 ε[L g⁻¹ cm⁻¹] C[µg/L]: at the peak, 1 mg/m³ of dye absorbs 0.0378 m⁻¹
    assert float(a.absorption_per_m(1.0)[np.argmin(np.abs(WL - 630))]) == pytest.approx(
        np.log(10) * 1e-4 * 1.3e5 / MOLAR_MASS, rel=1e-9)
    assert "absorbance of 5 mg/l over 10 mm" in c.source


@pytest.mark.parametrize("header,comments,fragment", [
    ("epsilon_L_per_mol_cm", [], "molar_mass_g_per_mol"),
    ("absorbance", ["concentration: 5 mg/L"], "path_length"),
    ("absorbance", ["concentration: 5 furlongs", "path_length: 1 cm"], "concentration unit"),
    ("absorbance", ["concentration: 1 umol/L", "path_length: 1 cm"], "molar_mass_g_per_mol"),
    ("absorbance", ["concentration: -5 mg/L", "path_length: 1 cm"], "positive number"),
    ("transmittance", [], "absorbance"),
])
def test_bad_absorber_csv(tmp_path, header, comments, fragment):
    with pytest.raises(CamcalError, match=fragment):
        read_absorber_csv(_write(tmp_path / "x.csv", header, EPS_MOL * 1e-5, comments))


def test_dye_round_trip_through_the_cli(profile_path, tmp_path):
    """A user's dye in the band-aware lamp model: C → ratio → C through the CLI (µg/L of dye)."""
    csv = _write(tmp_path / "dye.csv", "absorbance", EPS_MOL / MOLAR_MASS * 0.005,
                 ["concentration: 5 mg/L", "path_length: 1 cm"])
    lamp = ["--water-model", "lamp", "--lamp-height", "1m", "--lamp-angle", "15", "--profile", profile_path,
            "--absorber-csv", csv]
    proc = run_cli("water", "forward", "--json", "--concentration", "50ug/L,500ug/L", "--depth", "0.3m", *lamp)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["band_model"]["chlorophyll"].startswith(str(csv)) and out["illuminant"] == "lamp"
    r = out["ratio"][0]
    assert r[1] < r[0]
    proc = run_cli("water", "invert", "--json", "--ratio", ",".join(map(repr, r)), "--depth", "0.3m", *lamp)
    assert proc.returncode == 0, proc.stderr
    np.testing.assert_allclose(json.loads(proc.stdout)["c_ug_per_L"], [50.0, 500.0], rtol=1e-6)
    assert_one_line_error(run_cli("water", "invert", "--json", "--ratio", "0.3", "--depth", "0.3m", *lamp[:-1],
                                  tmp_path / "none.csv"), "none.csv")

"""One table of unit strings: how camcal writes the unit of each quantity for a reader.

CLI help and summaries, reports, ``camcal profile show``, EXR headers and the ``units`` fields of stage and
profile files take their unit text from here, so that one quantity is written one way everywhere
(docs/conventions.md#units shows the same table). ``tests/test_units.py`` fails when
camcal/ spells one of these units another way (``W m^-2``, ``DN/s``, ``e-``, ``ug/L`` ...), or writes one of
them as a literal outside this module.

Radiance has two meanings, kept apart by name:

- **spectral radiance** L(λ), per nm: :data:`SPECTRAL_RADIANCE`;
- **band radiance** of a channel, L_i = rate_i / ∫c_i dλ, the c_i-weighted mean spectral radiance over the
  channel's band (``apply``'s R, G, B): also per nm, :data:`BAND_RADIANCE`;
- **in-band radiance**, spectral radiance integrated over a band (a monochromator's reference detector, the
  ``narrowband`` estimator without a filter width): not per nm, :data:`IN_BAND_RADIANCE`.

Water-chemistry units (ε, concentration in mol/L, the parsers of typed values) are in
:mod:`camcal.water.units`, which writes a concentration with :data:`CONCENTRATION`.
"""

from __future__ import annotations

DN = "DN"
"""Pixel values: digital numbers."""
DN_PER_S = "DN s⁻¹"
"""DN rates and dark current β."""
ELECTRONS = "e⁻"
"""Charge: electrons."""
ELECTRONS_PER_S = f"{ELECTRONS} s⁻¹"
"""Electron rates (dark current in electrons)."""
DN_PER_ELECTRON = f"{DN}/{ELECTRONS}"
"""System gain K."""
ELECTRONS_PER_DN = f"{ELECTRONS}/{DN}"
"""Inverse system gain 1/K."""
SPECTRAL_RADIANCE = "W m⁻² sr⁻¹ nm⁻¹"
"""Spectral radiance L(λ)."""
BAND_RADIANCE = SPECTRAL_RADIANCE
"""Band radiance of a channel: the c_i-weighted mean spectral radiance over its band (per nm)."""
IN_BAND_RADIANCE = "W m⁻² sr⁻¹"
"""Radiance integrated over a band (not per nm)."""
SPECTRAL_SENSITIVITY = f"{DN_PER_S} per ({SPECTRAL_RADIANCE}) per nm at the reference ISO and f-number, on axis"
"""An absolute spectral sensitivity c(λ)."""
RELATIVE = "relative"
"""A relative c(λ) (peak 1) and what is computed from it: only ratios are physical."""
CONCENTRATION = "µg/L"
"""Chlorophyll-a concentration (= mg m⁻³)."""

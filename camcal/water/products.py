"""Water-quality products from Rrs: turbidity (FNU), suspended particulate matter (SPM, g m⁻³), band ratios.

Both single-band algorithms share the semi-analytical form of Nechad et al. (2010, eq. 8),

    X = A ρw / (1 − ρw / C),        ρw = π Rrs  (water-leaving reflectance, dimensionless),

- **turbidity** (FNU): Dogliotti et al. (2015), red band, A = 228.1 FNU, C = 0.1641 at 645 nm (the coefficients
  of Nechad et al. 2009 at MODIS 645 nm). Dogliotti's red algorithm holds for ρw(645) ≤ 0.05; above 0.07 they use
  the NIR band (859 nm), which a camera's red channel cannot give.
- **SPM** (g m⁻³): Nechad et al. (2010), A = 355.85 g m⁻³, C = 0.1728 at 665 nm (their MERIS band 7 calibration).

A camera's red band is centred elsewhere (about 600 nm for a Bayer sensor). At the band's **effective wavelength**
λ_eff = ∫ λ c(λ) E(λ) dλ / ∫ c(λ) E(λ) dλ (c the profile's sensitivity, E the light) the coefficients are moved by
Nechad et al. (2010)'s own derivation, A ∝ a_nw(λ)/b*_bp(λ): in the red the non-water absorption is small beside
pure water's, so A(λ) = A(λ0) a_w(λ)/a_w(λ0) with a_w of Pope & Fry (1997) and b*_bp held flat over the shift;
C is held. That move is an approximation: its relative 1-σ is stated as ``COEFFICIENT_TRANSFER_REL`` per 50 nm of
shift (Nechad et al. 2010, Fig. 4, show A rising by about a factor a_w between 620 and 700 nm with a scatter of
10-20 % about it). σ of a product is its Rrs part (σ(Rrs) propagated through dX/dρw = A/(1 − ρw/C)²) and the
coefficients' part, kept apart.

Validity: ρw ≤ 0 gives no product; turbidity flags ρw > 0.05 (beyond Dogliotti's red branch); both flag
ρw > C/2, where the algorithm loses sensitivity (dX/dρw has grown fourfold) and approaches its asymptote at C.

References
----------
Dogliotti, A. I., Ruddick, K. G., Nechad, B., Doxaran, D., Knaeps, E. (2015). A single algorithm to retrieve
turbidity from remotely-sensed data in all coastal and estuarine waters. Remote Sens. Environ. 156, 157-168.
Nechad, B., Ruddick, K. G., Neukermans, G. (2009). Calibration and validation of a generic multisensor algorithm
for mapping of turbidity in coastal waters. Proc. SPIE 7473, 74730H.
Nechad, B., Ruddick, K. G., Park, Y. (2010). Calibration and validation of a generic multisensor algorithm for
mapping of total suspended matter in turbid waters. Remote Sens. Environ. 114, 854-866.
Pope, R. M., Fry, E. S. (1997). Applied Optics 36(33), 8710-8723.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camcal.water.purewater import pure_water_absorption_per_m

#: Relative 1-σ of A per 50 nm between the band's effective wavelength and the algorithm's (module docstring).
COEFFICIENT_TRANSFER_REL = 0.1


@dataclass(frozen=True)
class Algorithm:
    """X = A ρw/(1 − ρw/C) at ``wavelength_nm`` (A in ``unit``, C dimensionless)."""

    name: str
    quantity: str
    unit: str
    a: float
    c: float
    wavelength_nm: float
    reference: str
    rho_w_max: float | None = None


TURBIDITY_DOGLIOTTI_2015 = Algorithm("Dogliotti et al. 2015 (red)", "turbidity", "FNU", 228.1, 0.1641, 645.0,
                                     "Remote Sens. Environ. 156, 157-168", rho_w_max=0.05)
SPM_NECHAD_2010 = Algorithm("Nechad et al. 2010", "SPM", "g m⁻³", 355.85, 0.1728, 665.0,
                            "Remote Sens. Environ. 114, 854-866")


def effective_wavelength_nm(wavelengths_nm, sensitivity, light=None) -> float:
    """λ_eff = ∫ λ c E dλ / ∫ c E dλ (E flat when ``light`` is None), nm."""
    wl = np.asarray(wavelengths_nm, float)
    w = np.clip(np.asarray(sensitivity, float), 0, None) * (1.0 if light is None else np.asarray(light, float))
    return float(np.trapezoid(wl * w, wl) / np.trapezoid(w, wl))


def at_wavelength(alg: Algorithm, wavelength_nm: float) -> tuple[Algorithm, float]:
    """The algorithm with A moved to ``wavelength_nm`` (module docstring), and A's relative 1-σ of the move."""
    k = float(pure_water_absorption_per_m(wavelength_nm) / pure_water_absorption_per_m(alg.wavelength_nm))
    rel = COEFFICIENT_TRANSFER_REL * abs(float(wavelength_nm) - alg.wavelength_nm) / 50.0
    moved = Algorithm(alg.name, alg.quantity, alg.unit, alg.a * k, alg.c, float(wavelength_nm), alg.reference,
                      alg.rho_w_max)
    return moved, rel


def apply_algorithm(alg: Algorithm, rrs_sr, sigma_rrs_sr=0.0):
    """(X, σ of X from σ(Rrs), dX/dRrs) for Rrs in sr⁻¹; X is NaN where ρw ≤ 0 or ρw ≥ C."""
    rho_w = np.pi * np.asarray(rrs_sr, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where((rho_w > 0) & (rho_w < alg.c), alg.a * rho_w / (1.0 - rho_w / alg.c), np.nan)
        dx = np.pi * alg.a / (1.0 - rho_w / alg.c) ** 2
    return x, np.abs(dx) * np.asarray(sigma_rrs_sr, float), dx


@dataclass(frozen=True)
class Product:
    """One product of one station: value, its σ (Rrs part and coefficients part) and its validity."""

    quantity: str
    unit: str
    value: float
    sigma: float
    sigma_rrs: float
    sigma_coefficients: float
    algorithm: str
    wavelength_nm: float
    a: float
    c: float
    valid: bool
    validity: str

    def describe(self) -> dict:
        def num(v):
            return float(v) if np.isfinite(v) else None

        return {"quantity": self.quantity, "unit": self.unit, "value": num(self.value), "sigma": num(self.sigma),
                "sigma_from_rrs": num(self.sigma_rrs), "sigma_from_coefficients": num(self.sigma_coefficients),
                "algorithm": self.algorithm, "effective_wavelength_nm": self.wavelength_nm, "A": self.a, "C": self.c,
                "valid": self.valid, "validity": self.validity}


def product(alg: Algorithm, rrs_red_sr: float, sigma_rrs_sr: float, band_wavelength_nm: float) -> Product:
    """One product from the red band's Rrs ± σ at its effective wavelength (module docstring)."""
    moved, rel = at_wavelength(alg, band_wavelength_nm)
    x, sx, _ = apply_algorithm(moved, rrs_red_sr, sigma_rrs_sr)
    x, sx = float(x), float(sx)
    rho_w = np.pi * rrs_red_sr
    notes = []
    if not rho_w > 0:
        notes.append("Rrs ≤ 0: no product")
    elif rho_w >= moved.c:
        notes.append(f"ρw = {rho_w:.3g} ≥ C = {moved.c:.3g}: beyond the algorithm's asymptote")
    else:
        if moved.rho_w_max is not None and rho_w > moved.rho_w_max:
            notes.append(f"ρw = {rho_w:.3g} > {moved.rho_w_max:g}: beyond the red branch (the NIR one is needed)")
        if rho_w > moved.c / 2:
            notes.append(f"ρw = {rho_w:.3g} > C/2: the algorithm is losing sensitivity")
    sc = abs(x) * rel if np.isfinite(x) else float("nan")
    valid = np.isfinite(x) and not notes
    return Product(alg.quantity, alg.unit, x, float(np.hypot(sx, sc)), sx, sc, alg.name, float(band_wavelength_nm),
                   moved.a, moved.c, bool(valid), "; ".join(notes) or "within the algorithm's range")


def band_ratio(num_rrs: float, num_rel_indep: float, den_rrs: float, den_rel_indep: float,
               shared_rel: dict | None = None) -> tuple[float, float]:
    """(r, σ_r) of Rrs_num/Rrs_den: independent relative σ of each band in quadrature, and shared terms given as
    {name: (δ_num/Rrs_num, δ_den/Rrs_den)} (signed relative shifts of one common cause) as their difference."""
    r = num_rrs / den_rrs
    var = num_rel_indep ** 2 + den_rel_indep ** 2
    for a, b in (shared_rel or {}).values():
        var += (a - b) ** 2
    return float(r), float(abs(r) * np.sqrt(var))

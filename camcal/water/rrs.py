"""Remote-sensing reflectance per camera band from photos of the water, the sky and a grey card, with σ.

The above-water method (Mobley 1999; HydroColor, Leeuw & Boss 2018), band by band (b = R, G, B):

    Rrs_b = (L_t,b − ρ L_sky,b) / (π L_card,b / R_card,b)          (sr⁻¹)

L are the band radiances of ``camcal apply`` (∫ c_b L dλ / ∫ c_b dλ, W m⁻² sr⁻¹ nm⁻¹) averaged over each photo's
central region: L_t the water surface (about 40° from nadir, 135° from the sun), L_sky the sky at the same angle
from the zenith, L_card a grey card level in the same light. π L_card/R_card is the downwelling irradiance E_d
seen through the band, so Rrs_b = ∫ c_b L_w dλ / ∫ c_b E_d dλ when R_card,b is the card's reflectance weighted by
c_b(λ) E_d(λ) (:func:`card_band_reflectance`). ρ is :mod:`camcal.water.skyglint`.

**Glint screening** (:func:`screen_water`): sun glitter and whitecaps only ever brighten a water photo. A photo is
left out, and named with its reason, when (1) more than ``SATURATED_MAX`` of its region is saturated, (2) more
than ``BRIGHT_MAX`` of its region's pixels lie above the region's median by more than ``PIXEL_K`` robust standard
deviations (1.4826 MAD) — the sparkle of glitter —, or (3) with three photos or more, its mean lies above the
median of the photos' means by more than ``PHOTO_K`` robust deviations of those means (floored by the photos'
own standard errors and by ``PHOTO_FLOOR_REL`` of the median, the waves' own spread), in any band.

**Uncertainty** (:func:`estimate_rrs`), 1-σ per band from the partial derivatives of the equation:

- ``water_photos``: the larger of the region means' noise (their standard errors) and the scatter of the kept
  water photos' means (waves) over √n;
- ``sky_photos``: the sky photos' noise; ``sky_variability``: the scatter of the sky photos' means over √n (one
  sky photo: a stated ``SKY_VARIABILITY_REL`` of L_sky, since one photo cannot show it);
- ``card_photo``: the card photos' noise; ``card_reflectance``: the card's stated σ (2 % of 18 % by default);
- ``rho``: σ(ρ) of :func:`camcal.water.skyglint.rho_with_sigma` (wind and sky structure);
- ``profile``: the profile's σ(c(λ)): the band's weighting of Rrs(λ) and of the card moved by c ± σ
  (:func:`profile_term`).

Shared terms (ρ, card reflectance, profile, sky variability) move every band together and largely cancel in
band ratios; the photo noise terms are independent per band. The dominant term is named per band.

References
----------
Mobley, C. D. (1999). Applied Optics 38(36), 7442-7455. Leeuw, T., Boss, E. (2018). Sensors 18(1), 256.
Burggraaff, O. et al. (2022). Accuracy and reproducibility of above-water radiometry with calibrated smartphone
cameras using RAW data. Frontiers in Remote Sensing 3, 940096.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from camcal.water.products import band_ratio
from camcal.water.skyglint import RHO_HYDROCOLOR, Rho

BANDS = ("R", "G", "B")
#: Grey card: 18 % flat, its stated 1-σ (absolute, reflectance units).
CARD_REFLECTANCE = 0.18
CARD_REFLECTANCE_SIGMA = 0.0036
#: Glint screening thresholds (module docstring).
SATURATED_MAX = 0.002
BRIGHT_MAX = 0.005
PIXEL_K = 6.0
PHOTO_K = 4.0
#: Floor of the between-photo scale, relative to the median: waves move a photo's reflected sky by a few %.
PHOTO_FLOOR_REL = 0.015
#: Relative 1-σ of the sky between photos when only one sky photo is given.
SKY_VARIABILITY_REL = 0.03
#: Central fraction of each photo's side used as its region.
REGION_FRACTION = 0.5


@dataclass
class PhotoStats:
    """One photo's region statistics per band (W m⁻² sr⁻¹ nm⁻¹) and its screening outcome."""

    name: str
    kind: str  # 'water', 'sky' or 'card'
    mean: dict
    se: dict
    n_pixels: int
    saturated_fraction: float
    bright_fraction: float
    rejected: str | None = None
    region: tuple = ()  # (y0, y1, x0, x1) in the radiance map's pixels
    meta: dict = field(default_factory=dict)

    def describe(self) -> dict:
        return {"file": self.name, "kind": self.kind, "mean": dict(self.mean), "se": dict(self.se),
                "n_pixels": self.n_pixels, "saturated_fraction": self.saturated_fraction,
                "bright_fraction": self.bright_fraction, "rejected": self.rejected, "region_px": list(self.region),
                **self.meta}


def central_region(shape_hw: tuple[int, int], fraction: float = REGION_FRACTION) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1) of the centred box covering ``fraction`` of each side."""
    h, w = shape_hw
    dy, dx = int(round(h * (1 - fraction) / 2)), int(round(w * (1 - fraction) / 2))
    return dy, h - dy, dx, w - dx


def region_stats(channels: dict, name: str, kind: str, region: tuple[int, int, int, int] | None = None) -> PhotoStats:
    """Mean, standard error, saturated (NaN) fraction and bright-outlier fraction of R, G, B over ``region``
    (default :func:`central_region`). NaN pixels are apply's saturated or defective ones."""
    shape = np.asarray(channels["G"]).shape
    y0, y1, x0, x1 = region or central_region(shape)
    mean, se = {}, {}
    sat = bright = 0.0
    n = 0
    for b in BANDS:
        v = np.asarray(channels[b], float)[y0:y1, x0:x1].ravel()
        ok = np.isfinite(v)
        sat = max(sat, 1.0 - ok.mean())
        v = v[ok]
        n = v.size
        if n < 2:
            mean[b], se[b] = float("nan"), float("nan")
            continue
        med = float(np.median(v))
        mad = 1.4826 * float(np.median(np.abs(v - med)))
        if mad > 0:
            bright = max(bright, float(np.mean(v > med + PIXEL_K * mad)))
        mean[b], se[b] = float(v.mean()), float(v.std(ddof=1) / np.sqrt(n))
    return PhotoStats(name, kind, mean, se, int(n), float(sat), float(bright), None, (y0, y1, x0, x1))


def screen_water(photos: list[PhotoStats]) -> list[PhotoStats]:
    """Mark glinted water photos (module docstring) in place; returns the kept ones."""
    for p in photos:
        if p.saturated_fraction > SATURATED_MAX:
            p.rejected = (f"sun glint or whitecaps: {100 * p.saturated_fraction:.2g} % of the region saturated "
                          f"(limit {100 * SATURATED_MAX:g} %)")
        elif p.bright_fraction > BRIGHT_MAX:
            p.rejected = (f"sun glint: {100 * p.bright_fraction:.2g} % of the region's pixels are bright outliers "
                          f"(> median + {PIXEL_K:g} robust σ; limit {100 * BRIGHT_MAX:g} %)")
        elif not all(np.isfinite(p.mean[b]) for b in BANDS):
            p.rejected = "no valid pixels in the region"
    kept = [p for p in photos if p.rejected is None]
    if len(kept) >= 3:
        for b in BANDS:
            m = np.array([p.mean[b] for p in kept])
            med = float(np.median(m))
            scale = max(1.4826 * float(np.median(np.abs(m - med))), 3.0 * float(np.median([p.se[b] for p in kept])),
                        PHOTO_FLOOR_REL * abs(med))
            for p, v in zip(kept, m, strict=True):
                z = (v - med) / scale
                if p.rejected is None and z > PHOTO_K:
                    p.rejected = (f"brighter than the other water photos in {b} by {z:.1f} robust σ (limit "
                                  f"{PHOTO_K:g}): glint or a whitecap")
    return [p for p in photos if p.rejected is None]


def combine(photos: list[PhotoStats], scatter: bool = True) -> tuple[dict, dict, dict]:
    """(mean, noise σ of the mean, scatter σ of the mean) per band over the photos (scatter NaN for one photo)."""
    mean, noise, spread = {}, {}, {}
    n = len(photos)
    for b in BANDS:
        m = np.array([p.mean[b] for p in photos])
        s = np.array([p.se[b] for p in photos])
        mean[b] = float(m.mean())
        noise[b] = float(np.sqrt(np.sum(s ** 2)) / n)
        spread[b] = float(m.std(ddof=1) / np.sqrt(n)) if (scatter and n >= 2) else float("nan")
    return mean, noise, spread


def card_band_reflectance(wavelengths_nm, sensitivity: dict, light, card_wavelengths_nm=None, card_reflectance=None,
                          card_sigma=None) -> dict:
    """{band: (R_card,b, σ)}: the card's reflectance weighted by c_b(λ) E(λ) (E ``light`` on ``wavelengths_nm`` or
    None for flat). ``card_reflectance`` None is 18 % flat with σ 0.0036; a measured spectrum is interpolated
    (end values held) with its σ (array or scalar, default 2 % of the value)."""
    wl = np.asarray(wavelengths_nm, float)
    if card_reflectance is None:
        return {b: (CARD_REFLECTANCE, CARD_REFLECTANCE_SIGMA) for b in BANDS}
    r = np.interp(wl, card_wavelengths_nm, card_reflectance)
    s = 0.02 * r if card_sigma is None else np.interp(wl, card_wavelengths_nm, np.broadcast_to(
        np.asarray(card_sigma, float), np.shape(card_reflectance)))
    e = np.ones_like(wl) if light is None else np.asarray(light, float)
    out = {}
    for b in BANDS:
        w = np.clip(np.asarray(sensitivity[b], float), 0, None) * e
        out[b] = (float(np.trapezoid(w * r, wl) / np.trapezoid(w, wl)),
                  float(np.trapezoid(w * s, wl) / np.trapezoid(w, wl)))  # σ fully correlated over λ
    return out


def profile_term(rrs: dict, wavelengths_nm, sensitivity: dict, sensitivity_sigma: dict | None, light,
                 card_wavelengths_nm=None, card_reflectance=None) -> dict:
    """{band: 1-σ of Rrs_b} from the profile's σ(c): Rrs(λ) taken piecewise linear through the bands' Rrs at their
    effective wavelengths; the band weights c_b ± σ_b move the band's mean of Rrs(λ) E(λ) over E(λ) and the card's
    band reflectance; half the difference is the term."""
    wl = np.asarray(wavelengths_nm, float)
    if sensitivity_sigma is None:
        return {b: 0.0 for b in BANDS}
    e = np.ones_like(wl) if light is None else np.asarray(light, float)
    eff = {b: float(np.trapezoid(wl * np.clip(sensitivity[b], 0, None) * e, wl)
                    / np.trapezoid(np.clip(sensitivity[b], 0, None) * e, wl)) for b in BANDS}
    order = sorted(BANDS, key=eff.get)
    spec = np.interp(wl, [eff[b] for b in order], [rrs[b] for b in order])
    card = np.ones_like(wl) if card_reflectance is None else np.interp(wl, card_wavelengths_nm, card_reflectance)

    def band(c):
        w = np.clip(c, 0, None) * e
        m = np.trapezoid(w * spec, wl) / np.trapezoid(w, wl)
        k = np.trapezoid(w * card, wl) / np.trapezoid(w, wl)
        return m / k

    out = {}
    for b in BANDS:
        c, s = np.asarray(sensitivity[b], float), np.asarray(sensitivity_sigma.get(b, 0.0), float)
        base = band(c)
        scale = rrs[b] / base if base else 0.0  # the card factor cancels at the nominal c
        out[b] = float(abs(band(c + s) - band(c - s)) / 2.0 * scale)
    return out


@dataclass
class RrsResult:
    """Rrs per band (sr⁻¹) with σ, its terms and dominant term, band ratios, and the inputs used."""

    rrs: dict
    sigma: dict
    terms: dict
    dominant: dict
    ratios: dict
    lt: dict
    lsky: dict
    lcard: dict
    card: dict
    rho: Rho
    hydrocolor: dict

    def describe(self) -> dict:
        return {"rrs_per_sr": dict(self.rrs), "sigma_per_sr": dict(self.sigma), "sigma_terms_per_sr": {
            b: dict(t) for b, t in self.terms.items()}, "dominant": dict(self.dominant),
            "ratios": {k: {"value": v, "sigma": s} for k, (v, s) in self.ratios.items()},
            "L_water": dict(self.lt), "L_sky": dict(self.lsky), "L_card": dict(self.lcard),
            "card_reflectance": {b: {"value": v, "sigma": s} for b, (v, s) in self.card.items()},
            "rho": self.rho.describe(), "hydrocolor_rrs_per_sr": dict(self.hydrocolor)}


def hydrocolor_rrs(lt: dict, lsky: dict, lcard: dict, rho: float = RHO_HYDROCOLOR,
                   card: float = CARD_REFLECTANCE) -> dict:
    """HydroColor's estimate (Leeuw & Boss 2018): ρ = 0.028 fixed, an 18 % card, no σ."""
    return {b: float((lt[b] - rho * lsky[b]) * card / (np.pi * lcard[b])) for b in BANDS}


def estimate_rrs(water: list[PhotoStats], sky: list[PhotoStats], card: list[PhotoStats], rho: Rho,
                 card_reflectance: dict, profile_sigma: dict | None = None) -> RrsResult:
    """Rrs ± σ per band from the kept water photos, the sky and card photos (module docstring).

    ``card_reflectance`` {band: (R, σ)} (:func:`card_band_reflectance`); ``profile_sigma`` {band: σ of Rrs} from
    :func:`profile_term` (None: computed by the caller afterwards, 0 here)."""
    lt, lt_noise, lt_spread = combine(water)
    ls, ls_noise, ls_spread = combine(sky)
    lc, lc_noise, _ = combine(card, scatter=False)
    rrs, sigma, terms, dom = {}, {}, {}, {}
    for b in BANDS:
        rc, src = card_reflectance[b]
        ed = np.pi * lc[b] / rc  # downwelling irradiance through the band, W m⁻² nm⁻¹
        r = (lt[b] - rho.value * ls[b]) / ed
        sky_var = ls_spread[b] if np.isfinite(ls_spread[b]) else SKY_VARIABILITY_REL * ls[b]
        water_sig = max(lt_noise[b], lt_spread[b]) if np.isfinite(lt_spread[b]) else lt_noise[b]
        t = {"water_photos": water_sig / ed,
             "sky_photos": rho.value * ls_noise[b] / ed,
             "sky_variability": rho.value * sky_var / ed,
             "card_photo": abs(r) * lc_noise[b] / lc[b],
             "card_reflectance": abs(r) * src / rc,
             "rho": rho.sigma * ls[b] / ed,
             "profile": 0.0 if profile_sigma is None else float(profile_sigma[b])}
        rrs[b], terms[b] = float(r), {k: float(v) for k, v in t.items()}
        sigma[b] = float(np.sqrt(sum(v * v for v in t.values())))
        dom[b] = max(t, key=t.get)
    ratios = band_ratios(rrs, terms, ls, card_reflectance, rho, lc)
    return RrsResult(rrs, sigma, terms, dom, ratios, lt, ls, lc, card_reflectance, rho, hydrocolor_rrs(lt, ls, lc))


#: Terms shared by all bands (one cause moves every band), the rest independent per band.
SHARED_TERMS = ("rho", "card_reflectance", "sky_variability")


def band_ratios(rrs: dict, terms: dict, ls: dict, card: dict, rho: Rho, lc: dict) -> dict:
    """{'B/G': (r, σ), 'G/R': (r, σ)}: independent terms in quadrature, shared ones as signed shifts (a larger ρ
    lowers every band by σ_ρ L_sky/E_d; a brighter card reflectance raises every band's Rrs by the same fraction;
    a brighter sky photo lowers every band)."""
    def rel(b, k):
        return terms[b][k] / rrs[b] if rrs[b] else np.inf

    out = {}
    for num, den in (("B", "G"), ("G", "R")):
        indep_n = np.sqrt(sum(rel(num, k) ** 2 for k in terms[num] if k not in SHARED_TERMS))
        indep_d = np.sqrt(sum(rel(den, k) ** 2 for k in terms[den] if k not in SHARED_TERMS))
        shared = {"rho": (-rel(num, "rho"), -rel(den, "rho")),
                  "card_reflectance": (rel(num, "card_reflectance"), rel(den, "card_reflectance")),
                  "sky_variability": (-rel(num, "sky_variability"), -rel(den, "sky_variability"))}
        out[f"{num}/{den}"] = band_ratio(rrs[num], indep_n, rrs[den], indep_d, shared)
    return out

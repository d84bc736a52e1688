"""Helpers shared by the formula tests of several modules: spectra, files and records built by hand."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.special import gammainccinv, ndtri

from camcal.calibrate.stack import StackResult
from camcal.frame import PLANES, Exposure
from camcal.models.dark import DarkModel
from camcal.models.flat import FlatModel
from camcal.models.response import (
    ChannelResponse,
)
from camcal.models.spectral import RELATIVE_UNITS, SpectralSensitivity
from camcal.water.band import bricaud_1998
from camcal.water.models import SeedModel
from camcal.water.purewater import pure_water_absorption_per_m


def _gauss(wl, mu, s, a=1.0):
    return a * np.exp(-0.5 * ((np.asarray(wl, float) - mu) / s) ** 2)


FIELD_WL = np.arange(520.0, 761.0, 4.0)


FIELD_C = _gauss(FIELD_WL, 640.0, 22.0)  # a red channel, negligible at the grid's ends


def _field_truth(sky_wl, direct, diffuse, sun_deg, geom, c, d, *, chl=None, a_scale=1.0, water=None,
                 background=0.0):
    """B = Σ c E_g R dλ / Σ c E_g dλ (trapezoid rule) with R = (1 − f) R_dir + f R_sky, E_g = E_dir + E_dif,
    f = E_dif / E_g; R_dir and R_sky from the geometry's closed forms at the sun's angle; τ = (a_w + a_bg +
    s A C^E) d with A, E of ``chl`` (Bricaud et al. 1998 by default) and a_w of Pope & Fry (1997) by default."""
    e_dir, e_dif = np.interp(FIELD_WL, sky_wl, direct), np.interp(FIELD_WL, sky_wl, diffuse)
    glob = e_dir + e_dif
    f = e_dif / glob
    chl = chl or bricaud_1998()
    a = np.interp(FIELD_WL, chl.wavelengths_nm, chl.coefficient_m2_per_mg, left=0.0, right=0.0)
    a_w = pure_water_absorption_per_m(FIELD_WL) if water is None else water
    tau = (a_w + background + a_scale * a * c ** np.interp(FIELD_WL, chl.wavelengths_nm, chl.exponent)) * d
    g = replace(geom, sun_zenith_rad=np.radians(sun_deg))
    r = (1 - f) * g.direct_form().ratio(tau) + f * g.sky_form().ratio(tau)
    return np.trapezoid(FIELD_C * glob * r, FIELD_WL) / np.trapezoid(FIELD_C * glob, FIELD_WL)


_BAND_WL = np.arange(400.0, 701.0, 10.0)


def _band_profile(zero_blue=False):
    """A profile holding only c(λ): R rises from exactly 1 % of its peak at 500 nm (0 below, and 0 at 490 nm) to
    its peak 0.5 at 600 nm; G1, G2 and B are Gaussians; each plane has its own uncertainty."""
    from camcal.models.profile import CalibrationProfile, CameraIdentity, Provenance

    wl = _BAND_WL
    values = {"R": np.interp(wl, [490.0, 500.0, 600.0, 700.0], [0.0, 0.005, 0.5, 0.15]),
              "G1": _gauss(wl, 540.0, 30.0, 0.9), "G2": _gauss(wl, 550.0, 30.0, 0.8),
              "B": np.zeros_like(wl) if zero_blue else _gauss(wl, 460.0, 25.0, 0.7)}
    unc = {p: 0.01 * (k + 1) + 0.03 * v for k, (p, v) in enumerate(values.items())}
    s = SpectralSensitivity(wl, values, unc, RELATIVE_UNITS, "relative")
    return CalibrationProfile(CameraIdentity("m", "x", None, "RGGB", 96, 64), 100.0, 4.0, spectral=s,
                              provenance=Provenance("test", "2026-01-01T00:00:00Z"))


def _json_round_trip(obj):
    import json

    return json.loads(json.dumps(obj))


def _vignetting(k, centre, shape):
    """The DNG radial gain 1 + k0 r² + k1 r⁴ of one plane without a mosaic, r normalised to the farthest corner."""
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    cx, cy = centre
    rmax2 = max((x - cx) ** 2 + (y - cy) ** 2 for x in (0.0, w - 1.0) for y in (0.0, h - 1.0))
    r2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / rmax2
    return 1.0 + k[0] * r2 + k[1] * r2**2


def _aperture_series():
    """Radial models (planes R, G on 3 x 4, no mosaic) at f/2.8, f/5.6 and f/11 (35 mm), their hand-computed gains
    and one shared PRNU map; the f/5.6 model is the primary one, holding the others (given out of order)."""
    from camcal.models.flat import Optics

    ks = {2.8: {"R": (-0.5, 0.1), "G": (-0.42, 0.07)}, 5.6: {"R": (-0.3, 0.05), "G": (-0.26, 0.03)},
          11.0: {"R": (-0.12, 0.02), "G": (-0.1, 0.01)}}
    centre = {"R": (1.0, 1.0), "G": (2.0, 0.5)}
    prnu = (1.0 + 0.01 * np.arange(24).reshape(2, 3, 4)).astype(np.float32)

    def model(n, **kw):
        return FlatModel(channels=("R", "G"), centre_px=centre, k={c: (*ks[n][c], 0.0, 0.0, 0.0) for c in "RG"},
                         model_2d=None, prnu=prnu, residual_rms={c: 0.001 for c in "RG"}, shape=(3, 4),
                         info={"n_terms": 2}, optics=Optics(n, "tag", 35.0, "tag"), **kw)

    m28, m11 = model(2.8), model(11.0)
    primary = model(5.6, apertures=(m11, m28))
    gains = {n: np.stack([_vignetting(ks[n][c], centre[c], (3, 4)) for c in "RG"]) for n in ks}
    return primary, m28, m11, gains, prnu


def _dark_model(bias, beta, iso):
    z = np.zeros(bias.shape, np.float32)
    return DarkModel(bias_dn=bias, dark_current_dn_per_s=beta, dark_current_unc_dn_per_s=z, read_noise_dn=z + 2,
                     defects=np.zeros(bias.shape, np.uint8), iso=iso, cfa_pattern="RGGB", temperature_c=None)


NOISE_METHOD = "per-pixel temporal variance minus the quantisation variance 1/12 DN² (EMVA 1288 eq. 4)"


def _read_noise_stack(var, count, frames=(), n_paths=None, level=60.0):
    """A read-noise stack of per-pixel temporal variance ``var`` (C, h, w) over ``count`` frames a pixel, keeping
    ``frames`` (its first frames' planes), written by ``n_paths`` files (``count`` by default; no file is read), at
    ``level`` DN (a number or a (C, h, w) map: the stack's value)."""
    var = np.asarray(var, np.float32)
    level = np.broadcast_to(np.asarray(level, np.float32), var.shape).copy()
    n = int(count) if n_paths is None else n_paths
    e = Exposure(exposure_s=1e-4, iso=100.0)
    return StackResult(value=level, mean=level, variance=var, count=np.full(var.shape, count, np.int16),
                       n_frames=n, method="mean", exposures=(e,) * n,
                       paths=tuple(Path(f"b{i}.dng") for i in range(n)), channel_names=PLANES, cfa_pattern="RGGB",
                       black_level_dn=(60.0,) * 4, white_level_dn=1023.0,
                       frame_shape=(2 * var.shape[1], 2 * var.shape[2]), variance_all=var,
                       kept_planes=tuple(np.asarray(f, np.float32) for f in frames))


def _noisy_bound(dof, noisy_sigma):
    """The noisy-pixel bound on var/v̂: the chi-square upper 1e-6 quantile over dof, here from the inverse
    regularised upper incomplete gamma function (χ²_ν quantile = 2·Q⁻¹(ν/2, p)), or 1 + noisy_sigma·√(2/dof)."""
    return max(2.0 * gammainccinv(dof / 2.0, 1e-6) / dof, 1.0 + noisy_sigma * np.sqrt(2.0 / dof))


def _map_of_variance(var):
    """√(var − 1/12 DN²), 0 below the quantisation variance, NaN where var is NaN (EMVA 1288 eq. 4)."""
    return np.sqrt(np.clip(np.asarray(var, np.float64) - 1.0 / 12.0, 0.0, None))


def _channel(alpha=1.0, gamma=1.0, beta=0.0, offset=float("nan"), rate=float("nan")):
    return ChannelResponse(alpha=alpha, alpha_unc=0.0, gamma=gamma, gamma_unc=0.0, beta=beta, beta_unc=0.0,
                           linear_range_dn=(0.0, 1.0), saturation_dn=4095.0, linearity_error_pct=0.0,
                           pearson_r=1.0, rate_dn_per_s=rate, offset_dn=offset)


BAND_WL = np.arange(520.0, 761.0, 4.0)


BAND_C = _gauss(BAND_WL, 640.0, 22.0)  # a red channel, negligible at the grid's ends


def _bricaud_per_m(c_ug_per_L):
    """a_chl = A(λ) C^E(λ) on BAND_WL from the Bricaud et al. (1998) table (400-700 nm; no absorption beyond)."""
    chl = bricaud_1998()
    a = np.interp(BAND_WL, chl.wavelengths_nm, chl.coefficient_m2_per_mg, right=0.0)
    return a * c_ug_per_L ** np.interp(BAND_WL, chl.wavelengths_nm, chl.exponent)


INV_WL = np.arange(600.0, 701.0, 2.0)


INV_C = np.sin(np.pi * (INV_WL - 600.0) / 100.0) ** 2  # exactly zero at both ends: trapezoid = the model's weights


def _inv_forward(c_ug_per_L, depth_m=0.5, bg=0.1):
    """B(C) of the seed's geometry over INV_C, written out: the trapezoid rule over the Bricaud table (A C^E, on
    the table's own 2 nm grid here) with the seed's per-wavelength closed form R(τ), τ = (a_bg + A C^E) d."""
    chl = bricaud_1998()
    a = np.interp(INV_WL, chl.wavelengths_nm, chl.coefficient_m2_per_mg)
    e = np.interp(INV_WL, chl.wavelengths_nm, chl.exponent)
    form = SeedModel().closed_form()
    out = []
    for cv in np.atleast_1d(np.asarray(c_ug_per_L, float)):
        r = form.ratio((bg + a * cv**e) * depth_m)
        out.append(np.trapezoid(INV_C * r, INV_WL) / np.trapezoid(INV_C, INV_WL))
    return np.array(out)


def _inv_sigma(c, sigma_ln_ratio, depth_m=0.5):
    """σ_C = σ_ln r / |d ln B/dC|, the derivative by central differences (h = 1e-4 C) of the forward model."""
    h = 1e-4 * c
    dln = (np.log(_inv_forward(c + h, depth_m)) - np.log(_inv_forward(c - h, depth_m))) / (2 * h)
    return sigma_ln_ratio / np.abs(dln)


N_WATER = 1.33


def fresnel_t_from_air(theta_air_rad: float, n: float = N_WATER) -> float:
    """Unpolarised power transmittance of a flat air→water surface at air-side angle θa.

    From the amplitude transmission coefficients t_s = 2 cos θi / (cos θi + n cos θt),
    t_p = 2 cos θi / (n cos θi + cos θt) and the power factor n cos θt / cos θi (not from 1 − R).
    By reciprocity (Stokes relations) it is also the water→air transmittance along the refracted ray.
    """
    ci = np.cos(theta_air_rad)
    ct = np.sqrt(1.0 - (np.sin(theta_air_rad) / n) ** 2)
    k = n * ct / ci
    ts = 2 * ci / (ci + n * ct)
    tp = 2 * ci / (n * ci + ct)
    return float(0.5 * k * (ts * ts + tp * tp))


def schlick_t_from_air(theta_air_rad: float, n: float = N_WATER) -> float:
    """1 − Schlick's R at the air-side angle (either direction, Schlick 1994)."""
    r0 = ((n - 1) / (n + 1)) ** 2
    return float(1 - (r0 + (1 - r0) * (1 - np.cos(theta_air_rad)) ** 5))


def _stack(level: np.ndarray, t_s: float, white: float, black: float, n: int = 8, var_dn2: float = 4.0):
    """A combined stack of ``n`` dark frames at exposure ``t_s`` with exact per-pixel levels (no file)."""
    level = np.asarray(level, np.float32)
    var = np.full(level.shape, var_dn2, np.float32)
    e = Exposure(exposure_s=t_s, iso=100.0)
    return StackResult(value=level, mean=level, variance=var, count=np.full(level.shape, n, np.int16), n_frames=n,
                       method="mean", exposures=(e,) * n, paths=tuple(Path(f"d{t_s:g}_{i}.dng") for i in range(n)),
                       channel_names=PLANES, cfa_pattern="RGGB", black_level_dn=(black,) * 4, white_level_dn=white,
                       frame_shape=(2 * level.shape[1], 2 * level.shape[2]), variance_all=var)


#: σ of a normal distribution over its median absolute deviation: 1/Φ⁻¹(3/4) (scipy's ``scale="normal"``).
NORMAL_PER_MAD = 1.0 / float(ndtri(0.75))


def _dark_group(level, var, t_s, n, *, black=(1000.0,) * 4, white=4095.0, cfa="RGGB", iso=100.0,
                temps=None, exposure_s="t") -> StackResult:
    """A combined stack of ``n`` frames at ``t_s`` with exact per-pixel levels and temporal variances (no file).

    ``temps``: the frames' sensor temperatures (one per frame, or None); ``exposure_s=None`` gives frames whose
    exposure time is not known (as bias frames may be)."""
    level = np.asarray(level, np.float32)
    var = np.asarray(var, np.float32)
    temps = [None] * n if temps is None else list(temps)
    es = tuple(Exposure(exposure_s=t_s if exposure_s == "t" else exposure_s, iso=iso, temperature_c=tc)
               for tc in temps)
    return StackResult(value=level, mean=level, variance=var.copy(), count=np.full(level.shape, n, np.int16),
                       n_frames=n, method="mean", exposures=es,
                       paths=tuple(Path(f"d{t_s:g}_{i}.dng") for i in range(n)), channel_names=PLANES,
                       cfa_pattern=cfa, black_level_dn=tuple(black), white_level_dn=white,
                       frame_shape=(2 * level.shape[1], 2 * level.shape[2]), variance_all=var)



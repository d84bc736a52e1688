"""The water column's own radiance above a submerged disk (seed §1.7, "back scattering"), from the same Rrs.

The Secchi model (:mod:`camcal.water.field`) lets the disk alone send light up: it leaves out the light that the
water between the surface and the disk scatters back. Over optically deep water that light is the water-leaving
radiance L_w = Rrs E_d that ``camcal rrs`` measures. Over a disk at depth d only the layer above the disk scatters,
and the shallow-water model of Maritorena, Morel & Gentili (1994, eq. 9) gives the layer's share:

    L_column(d) = Rrs E_d [1 − e^(−(K_d + k_u) d)],

K_d the diffuse attenuation of the downwelling light and k_u that of the upwelling light scattered by the column.
With the inherent optical properties of the band, K_d ≈ (a + b_b)/μ_d (Gordon 1989, μ_d = cos β of the refracted
sun) and k_u = 1.03 (1 + 2.4 u)^0.5 (a + b_b), u = b_b/(a + b_b) (Lee et al. 1998, eq. 5, the column's
upwelling). u follows from Rrs itself by inverting r_rs = g0 u + g1 u², r_rs = Rrs/(0.52 + 1.7 Rrs) (Gordon et al.
1988; Lee et al. 2002), so the band's Rrs and a + b_b are enough (:func:`column_radiance`). The disk's own term of
``secchi`` is unchanged; the submerged photo sees L_disk + L_column, so a Secchi inversion that wants the column
out subtracts :func:`column_radiance` from the disk's radiance (or, in ratio form, Rrs E_d/L_ref × the bracket).
This is not yet wired into ``camcal secchi``.

References
----------
Maritorena, S., Morel, A., Gentili, B. (1994). Diffuse reflectance of oceanic shallow waters: influence of water
depth and bottom albedo. Limnol. Oceanogr. 39(7), 1689-1703.
Lee, Z., Carder, K. L., Mobley, C. D., Steward, R. G., Patch, J. S. (1998). Hyperspectral remote sensing for
shallow waters. I. A semianalytical model. Applied Optics 37(27), 6329-6338.
Gordon, H. R. (1989). Can the Lambert-Beer law be applied to the diffuse attenuation coefficient of ocean water?
Limnol. Oceanogr. 34(8), 1389-1409. Gordon, H. R. et al. (1988). J. Geophys. Res. 93(D9), 10909-10924.
Lee, Z., Carder, K. L., Arnone, R. A. (2002). Applied Optics 41(27), 5755-5772.
"""

from __future__ import annotations

import numpy as np

from camcal.water.optics import N_WATER, snell

G0, G1 = 0.089, 0.125


def subsurface_rrs(rrs_sr):
    """r_rs below the surface from Rrs above it: r_rs = Rrs/(0.52 + 1.7 Rrs) (Lee et al. 2002), sr⁻¹."""
    rrs = np.asarray(rrs_sr, float)
    return rrs / (0.52 + 1.7 * rrs)


def u_from_rrs(rrs_sr):
    """u = b_b/(a + b_b) from Rrs: the positive root of g1 u² + g0 u − r_rs = 0 (Gordon et al. 1988)."""
    r = subsurface_rrs(rrs_sr)
    return (-G0 + np.sqrt(G0 * G0 + 4 * G1 * r)) / (2 * G1)


def column_radiance(rrs_sr, ed_W_m2_nm, depth_m, kappa_per_m, sun_zenith_deg: float = 0.0, n: float = N_WATER):
    """L_column (W m⁻² sr⁻¹ nm⁻¹) of the water above a disk at ``depth_m`` (module docstring).

    ``rrs_sr`` the band's Rrs (sr⁻¹, from ``camcal rrs``), ``ed_W_m2_nm`` the downwelling irradiance through the
    band (π L_card/R_card), ``kappa_per_m`` = a + b_b of the band (m⁻¹). Depth 0 gives 0, deep water Rrs E_d.
    """
    u = u_from_rrs(rrs_sr)
    kappa = np.asarray(kappa_per_m, float)
    mu_d = np.cos(snell(np.radians(sun_zenith_deg), 1.0, n))
    k_d = kappa / mu_d
    k_u = 1.03 * np.sqrt(1.0 + 2.4 * u) * kappa
    return np.asarray(rrs_sr, float) * np.asarray(ed_W_m2_nm, float) * (1.0 - np.exp(-(k_d + k_u)
                                                                                       * np.asarray(depth_m, float)))

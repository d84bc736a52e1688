"""The tone curve and colour matrix of processed chart photos (HEIC, JPEG), and the white-balance check.

A phone renders v_i = W · T(j_i / W) with j = A · r: the sensor's linear signals r (R, G, B) mixed by a
colour matrix A (white balance included), then a tone curve T, W the file's white level (seed eq. 12's
processed case). camcal describes T with the sRGB form of free exponent p and offset a (IEC 61966-2-1's
shape, :func:`camcal.models.response.srgb_form_encode`): T(L) = (1 + a) L^p − a above a linear toe. That is
the form ``camcal apply`` inverts (:meth:`camcal.models.response.ResponseModel.linearise`).

Two fits:

- **Neutral patches only** (:func:`fit_tone_neutral`; HEIC/JPEG without RAW twins). For the six neutral
  patches the linear signal is j_{k,i} = G_i · x · ρ̄_{k,i}: a gain G_i per channel, the photo's relative
  exposure x (seed §2.1) and the patch's effective reflectance ρ̄_{k,i} = ∫ c_i ρ_k E dλ / ∫ c_i E dλ (the
  neutrals are nearly flat, so ρ̄ depends on c only weakly: the caller iterates with the recovered c).
  Least squares in v over every neutral patch of every photo (all exposures given enter), weighted by the
  patch means' standard errors; p, a shared, G_i per channel. The linearised processed channels then are
  the camera's channels: c(λ) of the processed channels is recovered from them (no colour matrix: the
  profile's matrix is the identity).
- **RAW twins** (:func:`fit_tone_twins`; a DNG and a HEIC of each chart shot): j = A · r with r the RAW
  patches' means (R, mean G, B; DN above black at the same exposure), so p, a and the 3x3 A are fitted
  together over all 24 patches; apply then turns a HEIC into RAW-equivalent signals (A⁻¹ j) and uses the
  RAW c(λ).

Uncertainty: the parameters' covariance from the Jacobian (scaled by the reduced χ² when above 1: the form's
own misfit enters). White balance: the linearised neutrals' R/G and B/G of each photo are compared
(:func:`white_balance_check`); a change beyond :data:`WB_TOLERANCE` and the noise is reported.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import isotonic_regression, least_squares

from camcal.chart.detect import NEUTRAL_PATCHES
from camcal.errors import CamcalError
from camcal.models.response import SRGB_OFFSET_A, srgb_form_decode, srgb_form_encode, srgb_form_toe

#: Relative change of a neutral patch's R/G or B/G between photos beyond which the white balance moved.
WB_TOLERANCE = 0.02
#: Processed values above this fraction of white are near the shoulder or clipped and are not fitted.
MAX_FRACTION_OF_WHITE = 0.97


@dataclass(frozen=True)
class ToneFit:
    """The fitted sRGB-form tone curve (shared by R, G, B), the channel mixing, and their uncertainties.

    exponent, exponent_unc, offset_a, offset_a_unc : the form's p and a (dimensionless).
    white_level_dn : W of the files, DN.
    gains : (3,) G_i of the neutral fit (linear fraction of white per unit x·ρ̄), or None for twins.
    matrix, matrix_unc : (3, 3) A of the twin fit (processed j from RAW r, both relative to W), or None.
    rms_dn : RMS residual of the fit, DN. chi2_red : reduced χ². n_points : values fitted.
    """

    exponent: float
    exponent_unc: float
    offset_a: float
    offset_a_unc: float
    white_level_dn: float
    gains: np.ndarray | None
    matrix: np.ndarray | None
    matrix_unc: np.ndarray | None
    rms_dn: float
    chi2_red: float
    n_points: int
    notes: tuple[str, ...] = field(default_factory=tuple)
    table_v_dn: np.ndarray | None = None
    """Twins only: knots of a monotone tone table (file DN), which replaces the sRGB form where the form misfits."""
    table_linear_dn: np.ndarray | None = None
    """The table's linear values at the knots, DN on the 0..W scale."""
    table_rms_dn: float = float("nan")
    exponent_offset_cov: np.ndarray | None = None
    """(2, 2) covariance of (exponent, offset_a) of the fit (what apply propagates,
    :mod:`camcal.models.processed_unc`)."""
    table_linear_dn_unc: np.ndarray | None = None
    """Standard error of the table's linear value at each knot, linear DN (0 at the origin)."""

    def linearise(self, v_dn: np.ndarray) -> np.ndarray:
        """File DN → linear DN on the 0..W scale (what ``camcal apply`` computes)."""
        v = np.asarray(v_dn, float)
        if self.table_v_dn is not None:
            vk, lk = self.table_v_dn, self.table_linear_dn
            slope = (lk[-1] - lk[-2]) / (vk[-1] - vk[-2])
            return np.where(v > vk[-1], lk[-1] + slope * (v - vk[-1]), np.maximum(np.interp(v, vk, lk), 0.0))
        return self.white_level_dn * srgb_form_decode(v / self.white_level_dn, self.exponent, self.offset_a)

    def slope(self, v_dn: np.ndarray) -> np.ndarray:
        """d(linear DN)/d(file DN) at ``v_dn`` (numerical, for propagating the patches' noise)."""
        v = np.asarray(v_dn, float)
        h = 0.5
        return (self.linearise(v + h) - self.linearise(np.maximum(v - h, 0.0))) / (v + h - np.maximum(v - h, 0.0))

    def tone_record(self, channels: Sequence[str] = ("R", "G", "B"), x_white_s: Sequence[float] | None = None) -> dict:
        """The profile's ``response.processed.tone`` object (camcal/schemas/profile-1.schema.json)."""
        lb, s = srgb_form_toe(self.exponent, self.offset_a)
        out = {}
        for i, ch in enumerate(channels):
            xw = None if x_white_s is None else float(x_white_s[i])
            out[ch] = {"use": "srgb" if self.table_v_dn is None else "table",
                       "srgb": {"form": "srgb", "exponent": self.exponent, "exponent_unc": self.exponent_unc,
                                "offset_a": self.offset_a, "offset_a_unc": self.offset_a_unc,
                                "exponent_offset_covariance": None if self.exponent_offset_cov is None else
                                self.exponent_offset_cov.tolist(), "x_white_s": xw, "toe_linear": lb,
                                "toe_slope": s, "chi2_red": self.chi2_red, "rms_dn": self.rms_dn},
                       "eq12_rms_dn": None, "x_white_s": xw,
                       "linear_gain_dn_per_s": None if xw is None else self.white_level_dn / xw}
            if self.table_v_dn is not None:
                out[ch]["table"] = {"v_dn": [float(x) for x in self.table_v_dn],
                                    "linear_dn": [float(x) for x in self.table_linear_dn],
                                    "rms_dn": self.table_rms_dn}
                if self.table_linear_dn_unc is not None:
                    out[ch]["table"]["linear_dn_unc"] = [float(x) for x in self.table_linear_dn_unc]
        return {"form": "srgb form with free exponent and offset (IEC 61966-2-1 shape), fitted on a colour chart's "
                        + ("patches with RAW twins" if self.matrix is not None else "six neutral patches"),
                "channels": out}


def _encode(lin: np.ndarray, p: float, a: float) -> np.ndarray:
    return srgb_form_encode(np.clip(lin, 0.0, 4.0), p, a)


def _covariance(res) -> np.ndarray:
    j = res.jac
    dof = max(res.fun.size - j.shape[1], 1)
    chi2_red = float(res.fun @ res.fun) / dof
    try:
        cov = np.linalg.pinv(j.T @ j)
    except np.linalg.LinAlgError:
        cov = np.full((j.shape[1], j.shape[1]), np.nan)
    return cov * max(chi2_red, 1.0)


def fit_tone_neutral(values_dn: Sequence[np.ndarray], sem_dn: Sequence[np.ndarray], x_s: Sequence[float],
                     rho_eff: np.ndarray, white_level_dn: float,
                     patch_gain: Sequence[np.ndarray] | None = None) -> ToneFit:
    """The tone curve from the neutral patches of one or more processed photos (module docstring).

    values_dn, sem_dn : per photo (24, 3) patch means and their standard errors, file DN.
    x_s : per photo relative exposure, s (any common scale: only ratios between photos matter).
    rho_eff : (24, 3) effective reflectance of each patch per channel (only the neutrals are used).
    patch_gain : per photo (24, 3) relative illumination (the flat's gain) at each patch, which multiplies the
        linear signal before the tone curve; None: 1 (no flat: the neutrals' own fall-off biases the curve).
    """
    w = float(white_level_dn)
    rows = []
    gains = patch_gain if patch_gain is not None else [np.ones((24, 3))] * len(values_dn)
    for v, u, x, g in zip(values_dn, sem_dn, x_s, gains, strict=True):
        for k in NEUTRAL_PATCHES:
            for i in range(3):
                if np.isfinite(v[k, i]) and 0.005 * w < v[k, i] < MAX_FRACTION_OF_WHITE * w:
                    rows.append((i, x * rho_eff[k, i] * g[k, i], v[k, i], max(u[k, i], 0.5)))
    if len(rows) < 8:
        raise CamcalError(f"only {len(rows)} neutral-patch values between black and white: the tone curve needs the "
                          "six grey patches exposed below clipping (expose for the white patch)")
    ch = np.array([r[0] for r in rows], int)
    s = np.array([r[1] for r in rows])
    v = np.array([r[2] for r in rows])
    u = np.array([r[3] for r in rows])
    g0 = np.array([np.median(srgb_form_decode(v[ch == i] / w, 1 / 2.4) / s[ch == i]) if np.any(ch == i) else 1.0
                   for i in range(3)])

    def resid(q):
        p, a, lg = q[0], q[1], q[2:]
        return (w * _encode(np.exp(lg)[ch] * s, p, a) - v) / u

    q0 = np.r_[1 / 2.4, SRGB_OFFSET_A, np.log(np.maximum(g0, 1e-9))]
    res = least_squares(resid, q0, bounds=([0.15, 0.0, -30, -30, -30], [1.0, 0.5, 30, 30, 30]), x_scale="jac")
    cov = _covariance(res)
    rms = float(np.sqrt(np.mean((res.fun * u) ** 2)))
    dof = max(res.fun.size - res.x.size, 1)
    notes = []
    if len({round(x, 12) for x in x_s}) == 1 and len(values_dn) > 1:
        notes.append("every photo has the same exposure: the tone curve rests on the six grey patches alone")
    return ToneFit(float(res.x[0]), float(np.sqrt(max(cov[0, 0], 0.0))), float(res.x[1]),
                   float(np.sqrt(max(cov[1, 1], 0.0))), w, np.exp(res.x[2:]), None, None, rms,
                   float(res.fun @ res.fun) / dof, int(v.size), tuple(notes), exponent_offset_cov=cov[:2, :2].copy())


def fit_tone_twins(values_dn: Sequence[np.ndarray], sem_dn: Sequence[np.ndarray], raw_rgb_dn: Sequence[np.ndarray],
                   white_level_dn: float, usable: Sequence[np.ndarray] | None = None) -> ToneFit:
    """Tone curve and colour matrix A from processed photos and their RAW twins (module docstring).

    values_dn, sem_dn : per photo (24, 3) processed patch means and standard errors, file DN.
    raw_rgb_dn : per photo (24, 3) RAW patch means R, mean G, B, DN above black (same shot).
    usable : per photo (24,) bool, patches to fit (not saturated in either file).
    """
    w = float(white_level_dn)
    vs, us, rs = [], [], []
    for j, (v, u, r) in enumerate(zip(values_dn, sem_dn, raw_rgb_dn, strict=True)):
        ok = np.all(np.isfinite(v), 1) & np.all(np.isfinite(r), 1)
        if usable is not None:
            ok &= np.asarray(usable[j], bool)
        vs.append(v[ok]), us.append(u[ok]), rs.append(r[ok])
    v, u, r = np.concatenate(vs), np.concatenate(us), np.concatenate(rs)
    if v.shape[0] < 8:
        raise CamcalError(f"only {v.shape[0]} patches usable in both the RAW and the processed photos; the colour "
                          "matrix needs at least 8")
    good = (v > 0.005 * w) & (v < MAX_FRACTION_OF_WHITE * w)
    rscale = float(np.max(r))
    rn = r / rscale
    # start: the sRGB form, A from linearised values by least squares
    lin0 = srgb_form_decode(v / w, 1 / 2.4)
    a0 = np.linalg.lstsq(rn, lin0, rcond=None)[0].T

    def resid(q):
        p, a, m = q[0], q[1], q[2:].reshape(3, 3)
        pred = w * _encode(rn @ m.T, p, a)
        return ((pred - v) / np.maximum(u, 0.5))[good]

    q0 = np.r_[1 / 2.4, SRGB_OFFSET_A, a0.ravel()]
    lo = np.r_[0.15, 0.0, np.full(9, -np.inf)]
    hi = np.r_[1.0, 0.5, np.full(9, np.inf)]
    res = least_squares(resid, q0, bounds=(lo, hi), x_scale="jac")
    cov = _covariance(res)
    m = res.x[2:].reshape(3, 3) / rscale  # j/W = m · r (r in DN above black)
    m_unc = np.sqrt(np.maximum(np.diag(cov)[2:], 0.0)).reshape(3, 3) / rscale
    dof = max(res.fun.size - res.x.size, 1)
    rms = float(np.sqrt(np.mean((res.fun * np.maximum(u, 0.5)[good]) ** 2)))
    fit = ToneFit(float(res.x[0]), float(np.sqrt(max(cov[0, 0], 0.0))), float(res.x[1]),
                  float(np.sqrt(max(cov[1, 1], 0.0))), w, None, m, m_unc, rms, float(res.fun @ res.fun) / dof,
                  int(good.sum()), exponent_offset_cov=cov[:2, :2].copy())
    if good.sum() >= TABLE_MIN_POINTS:
        fit = _with_table(fit, v, r, good)
    return fit


#: Fewest processed values (patches × channels × photos) for a tone table instead of the sRGB form alone.
TABLE_MIN_POINTS = 48
#: Knots of the tone table (quantiles of the fitted values).
TABLE_KNOTS = 12


def _with_table(fit: ToneFit, v: np.ndarray, r: np.ndarray, good: np.ndarray) -> ToneFit:
    """A monotone tone table from the twins: alternately, the isotonic regression of the predicted linear value
    A r on the file value v (:func:`scipy.optimize.isotonic_regression`), binned into :data:`TABLE_KNOTS` knots,
    and A refitted by least squares on the table's linearised values. Kept only when it fits better than the sRGB
    form (the table's RMS in DN, v against the table's inverse at A r)."""
    w = fit.white_level_dn
    m = fit.matrix.copy()
    best = None
    for _ in range(3):
        pred = w * (r @ m.T)  # linear DN the matrix predicts
        vv, pp = v[good], pred[good]
        order = np.argsort(vv)
        vv, pp = vv[order], pp[order]
        iso = isotonic_regression(pp).x
        edges = np.quantile(vv, np.linspace(0, 1, TABLE_KNOTS + 1))
        vk, lk = [0.0], [0.0]
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            sel = (vv >= a) & (vv <= b)
            if sel.any():
                vk.append(float(np.median(vv[sel])))
                lk.append(float(np.median(iso[sel])))
        vk.append(float(vv[-1]))  # the brightest value fitted ends the table (apply extends its last slope)
        lk.append(float(iso[-1]))
        vk, lk = np.array(vk), np.maximum.accumulate(np.array(lk))
        keep = np.r_[True, np.diff(vk) > 1e-6]
        vk, lk = vk[keep], lk[keep]
        if vk.size < 4:
            return fit
        table = dataclasses.replace(fit, table_v_dn=vk, table_linear_dn=lk, matrix=m)
        lin = table.linearise(v)
        m = np.vstack([np.linalg.lstsq(r[good[:, i]], lin[good[:, i], i], rcond=None)[0] for i in range(3)]) / w
        x = w * (r @ m.T)
        top = (vk[-1] - vk[-2]) / max(lk[-1] - lk[-2], 1e-12)
        v_back = np.where(x > lk[-1], vk[-1] + top * (x - lk[-1]), np.interp(x, lk, vk))
        rms = float(np.sqrt(np.mean((v_back - v)[good] ** 2)))
        if best is None or rms < best.table_rms_dn:
            best = dataclasses.replace(table, matrix=m, table_rms_dn=rms)
    if best is None or not best.table_rms_dn < fit.rms_dn:
        return fit
    best = dataclasses.replace(best, table_linear_dn_unc=_knot_unc(best, v, r, good))
    return dataclasses.replace(best, notes=(*fit.notes, f"tone table ({best.table_v_dn.size} knots, RMS "
                                                        f"{best.table_rms_dn:.3g} DN) replaces the sRGB form (RMS "
                                                        f"{fit.rms_dn:.3g} DN)"))


def _knot_unc(table: ToneFit, v: np.ndarray, r: np.ndarray, good: np.ndarray) -> np.ndarray:
    """Standard error of each knot's linear value: the residuals (table(v) − W A r) of the fitted values nearest the
    knot (between the midpoints to its neighbours), √(π/2)·s/√n (the standard error of a median of normal data);
    the origin is fixed (0), a knot with fewer than 3 values takes the residuals' overall standard deviation."""
    w = table.white_level_dn
    resid = (table.linearise(v) - w * (r @ table.matrix.T))[good]
    vv = v[good]
    vk = table.table_v_dn
    mid = np.r_[-np.inf, 0.5 * (vk[1:] + vk[:-1]), np.inf]
    overall = float(np.std(resid, ddof=1)) if resid.size > 1 else 0.0
    out = np.zeros(vk.size)
    for k in range(1, vk.size):
        sel = (vv > mid[k]) & (vv <= mid[k + 1])
        n = int(sel.sum())
        out[k] = np.sqrt(np.pi / 2) * (float(np.std(resid[sel], ddof=1)) / np.sqrt(n) if n >= 3 else overall)
    return out


def white_balance_check(linear_neutrals: Sequence[np.ndarray], names: Sequence[str],
                        sem: Sequence[np.ndarray] | None = None) -> tuple[bool, str]:
    """Whether the linearised neutral patches keep one R/G and B/G over the photos: (locked, sentence).

    linear_neutrals : per photo (6, 3) linearised neutral-patch means (white first).
    """
    if len(linear_neutrals) < 2:
        return True, ("one photo: white balance not compared; it must stay locked (fixed, not auto) for every photo "
                      "this profile reads, or the processed colours change")
    ratios = []
    for n in linear_neutrals:
        light = n[:4]  # the four lightest grey patches
        ratios.append(np.array([np.nanmedian(light[:, 0] / light[:, 1]), np.nanmedian(light[:, 2] / light[:, 1])]))
    ratios = np.array(ratios)
    dev = ratios / ratios[0] - 1.0  # against the first photo
    worst = int(np.argmax(np.abs(dev).max(1)))
    if np.abs(dev).max() > WB_TOLERANCE:
        return False, (f"white balance changed between the photos: {names[worst]} has R/G {100 * dev[worst, 0]:+.1f} %"
                       f", B/G {100 * dev[worst, 1]:+.1f} % against {names[0]}'s neutral patches (tolerance "
                       f"{100 * WB_TOLERANCE:g} %); lock the white balance (a fixed preset, not auto) and shoot again")
    return True, (f"white balance locked across {len(linear_neutrals)} photos (neutral R/G, B/G within "
                  f"{100 * np.abs(dev).max():.2g} %)")

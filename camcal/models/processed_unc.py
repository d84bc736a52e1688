"""The uncertainty a processed photo's (HEIC, JPEG) tone curve and colour matrix give its linearised values.

A processed value v is read as linear DN through the inverse tone curve, lin = T⁻¹(v; θ), and as RAW-equivalent
signals through the colour matrix, r = A⁻¹ lin (:mod:`camcal.models.response`). θ and A are fitted (on a colour
chart, :mod:`camcal.chart.tone`) and carry a covariance; to first order (the law of propagation of uncertainty,
JCGM 100:2008 (GUM) §5.1.2, eq. 10 and 13) the error they give r at one pixel is

    δr = A⁻¹ (∂T⁻¹/∂θ) δθ − A⁻¹ δA r,

so u²(r_i) = g_iᵀ Σ_θ g_i + Σ_mn (A⁻¹)_im² r_n² u²(A_mn), g_i = Σ_m (A⁻¹)_im ∂T⁻¹_m/∂θ. The derivative of the
inverse tone curve is taken per pixel value: a value near white is nearly fixed by the curve's end (T⁻¹(W) = W),
a dark value moves most with the exponent.

The tone record (``response.processed.tone.channels[c]``) states what is known:

- ``srgb`` with ``exponent_offset_covariance`` (the 2x2 covariance of the exponent p and the offset a, written by
  ``camcal chart``): ∂T⁻¹/∂(p, a) by central differences of :func:`camcal.models.response.srgb_form_decode`
  (its linear toe included). A record holding only ``exponent_unc`` (a lab profile's, fitted with the white
  exposure whose covariance it does not keep) gives no term: the correlation it would need is not stated.
- ``table`` with ``linear_dn_unc`` (the standard error of each knot's linear value): ∂T⁻¹/∂ℓ_k are the weights of
  the linear interpolation (and of the extension past the last knot), the knots independent.

When every channel holds the same record (camcal chart fits one curve for R, G and B), θ is one set of parameters
shared by the channels (their errors are fully correlated); otherwise each channel has its own. The colour matrix's
entries are independent, u(A_mn) its ``matrix_unc``. Correlations between the tone curve and the matrix (fitted
together from RAW twins) are not kept.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from camcal.models.response import srgb_form_decode

#: Steps of the central differences of the sRGB form's inverse in p and a (dimensionless).
STEP_EXPONENT = 1e-4
STEP_OFFSET = 1e-4


@dataclass(frozen=True)
class ParameterBlock:
    """Parameters of the linearisation with a joint covariance.

    covariance : (K, K) covariance of the K parameters θ_q.
    lut : (K, 3, L) ∂lin/∂θ_q of the R, G, B channels at every file level 0..L−1 (linear DN on the response's
        scale per unit θ_q): a processed file holds integers, so a pixel's gradient is ``lut[q, c, value]``.
    """

    covariance: np.ndarray
    lut: np.ndarray

    def gradient(self, q: int, values: np.ndarray) -> np.ndarray:
        """(3, ...) ∂lin/∂θ_q at integer file values (3, ...), float32."""
        v = np.asarray(values)
        return np.stack([np.take(self.lut[q, c], v[c]) for c in range(3)]).astype(np.float32)


def _srgb_cov(rec: dict) -> np.ndarray | None:
    """The (2, 2) covariance of (p, a) of an ``srgb`` record, or None when the record does not state it."""
    cov = (rec.get("srgb") or {}).get("exponent_offset_covariance")
    if cov is None:
        return None
    c = np.asarray(cov, float)
    if c.shape != (2, 2) or not np.all(np.isfinite(c)):
        return None
    return 0.5 * (c + c.T)


def _table_unc(rec: dict) -> np.ndarray | None:
    t = rec.get("table") or {}
    u = t.get("linear_dn_unc")
    if u is None or len(u) != len(t.get("v_dn") or ()):
        return None
    u = np.asarray(u, float)
    return u if np.all(np.isfinite(u)) and np.all(u >= 0) else None


def _curve_key(rec: dict) -> tuple:
    """What defines a channel's inverse curve and its uncertainty (not its gain): equal keys, one shared curve."""
    if rec.get("use") == "srgb":
        s = rec.get("srgb") or {}
        return ("srgb", s.get("exponent"), s.get("offset_a"), str(s.get("exponent_offset_covariance")))
    t = rec.get("table") or {}
    return (rec.get("use"), str(t.get("v_dn")), str(t.get("linear_dn")), str(t.get("linear_dn_unc")))


def srgb_gradients(v_dn: np.ndarray, exponent: float, offset_a: float, white_dn: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """∂lin/∂p and ∂lin/∂a of lin = W · srgb_form_decode(v/W; p, a) at file values ``v_dn`` (linear DN per unit),
    by central differences (the linear toe included)."""
    x = np.asarray(v_dn, float) / white_dn
    hp, ha = STEP_EXPONENT, STEP_OFFSET
    dp = (srgb_form_decode(x, exponent + hp, offset_a) - srgb_form_decode(x, exponent - hp, offset_a)) / (2 * hp)
    lo = max(offset_a - ha, 0.0)
    da = (srgb_form_decode(x, exponent, offset_a + ha) - srgb_form_decode(x, exponent, lo)) / (offset_a + ha - lo)
    return white_dn * dp, white_dn * da


def table_weights(v_dn: np.ndarray, knots_v_dn: np.ndarray) -> np.ndarray:
    """(n_knots, ...) ∂lin/∂ℓ_k of the tone table's inverse at ``v_dn``: the linear-interpolation weights between the
    knots, and past the last knot the extension by the last two knots' slope (as
    :meth:`camcal.models.response.ResponseModel.linearise` reads the table)."""
    v = np.asarray(v_dn, float)
    vk = np.asarray(knots_v_dn, float)
    n = vk.size
    beyond = v > vk[-1]
    t = np.where(beyond, (v - vk[-1]) / (vk[-1] - vk[-2]), 0.0)
    out = np.empty((n, *v.shape))
    for k in range(n):
        e = np.zeros(n)
        e[k] = 1.0
        out[k] = np.where(beyond, 0.0, np.interp(v, vk, e))
    out[-1] = np.where(beyond, 1.0 + t, out[-1])
    out[-2] = np.where(beyond, -t, out[-2])
    return out


def tone_blocks(tone: dict, white_dn: float, n_levels: int, value_scale: float = 1.0,
                channels: Sequence[str] = ("R", "G", "B")) -> list[ParameterBlock]:
    """The tone curve's parameter blocks over the file levels 0..``n_levels``−1 (module docstring); a file level v
    is read as v·``value_scale`` on the response's scale (:meth:`camcal.models.response.ResponseModel.value_scale`).

    Empty when no channel's record states the covariance of its curve (nothing known to propagate).
    """
    recs = [tone["channels"][c] for c in channels]
    levels = np.arange(int(n_levels), dtype=float) * float(value_scale)
    shared = all(_curve_key(r) == _curve_key(recs[0]) for r in recs[1:])
    groups = [list(range(len(channels)))] if shared else [[i] for i in range(len(channels))]
    blocks = []
    for idx in groups:
        rec = recs[idx[0]]
        if rec.get("use") == "srgb" and (cov := _srgb_cov(rec)) is not None:
            gp, ga = srgb_gradients(levels, float(rec["srgb"]["exponent"]), float(rec["srgb"]["offset_a"]), white_dn)
            lut = np.zeros((2, 3, levels.size))
            lut[0, idx], lut[1, idx] = gp, ga
            blocks.append(ParameterBlock(cov, lut))
        elif rec.get("use") == "table" and (unc := _table_unc(rec)) is not None:
            keep = np.flatnonzero(unc > 0)
            w = table_weights(levels, rec["table"]["v_dn"])[keep]
            lut = np.zeros((keep.size, 3, levels.size))
            lut[:, idx] = w[:, None, :]
            blocks.append(ParameterBlock(np.diag(unc[keep] ** 2), lut))
    return blocks


def matrix_gradients(matrix: np.ndarray, matrix_unc: np.ndarray, raw_signal: np.ndarray
                     ) -> Iterator[tuple[float, np.ndarray]]:
    """(u²(A_mn), ∂r/∂A_mn) of the colour matrix's entries at RAW-equivalent signals ``raw_signal`` (3, ...):
    ∂r/∂A_mn = −(A⁻¹)[:, m] r_n; entries of zero uncertainty are skipped."""
    u = np.asarray(matrix_unc, float)
    inv = np.linalg.inv(np.asarray(matrix, float))
    r = np.asarray(raw_signal)
    shape = (3,) + (1,) * (r.ndim - 1)
    for m in range(3):
        for n in range(3):
            if u[m, n] > 0:
                yield float(u[m, n] ** 2), (-inv[:, m]).reshape(shape).astype(r.dtype) * r[n][None]


def quadratic_form(covariance: np.ndarray, gradients: Sequence[np.ndarray]) -> np.ndarray:
    """Σ_qq' g_q Σ_qq' g_q' elementwise (the first-order variance, GUM eq. 13), through Σ's eigenvectors."""
    w, v = np.linalg.eigh(np.asarray(covariance, float))
    out = np.zeros_like(gradients[0])
    for j in range(w.size):
        if w[j] > 0:
            z = sum(v[q, j] * gradients[q] for q in range(len(gradients)))
            out += np.asarray(w[j], out.dtype) * z * z
    return out

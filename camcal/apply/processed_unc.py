"""The per-pixel variance a processed photo's tone curve and colour matrix add to its RAW-equivalent signals.

The model is :mod:`camcal.models.processed_unc` (first-order propagation, GUM §5.1.2); this module evaluates it on
a photo's pixels the way :mod:`camcal.apply.photo` reads them: the gradient of the linearised values (one lookup per
file level), through the colour matrix's inverse (or the per-channel gains), binned 2x2, divided by the flat. The
variance of the radiance estimator's weighted sum Σ_i w_i s_i is formed from the same gradients, so the errors'
correlation between channels (one tone curve, one matrix) is kept for L(λ0).

Memory: one parameter's gradient at a time (a tone table's knots, the matrix's entries); the sRGB form's two
parameters together.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from camcal.models.processed_unc import matrix_gradients, quadratic_form, tone_blocks


@dataclass(frozen=True)
class SystematicVariance:
    """Variances of the binned, flat-divided RAW-equivalent signals (DN², (3, h, w)) and of the estimator's weighted
    sum Σ_i w_i s_i (DN², (h, w)); ``terms``: which parts entered (``tone``, ``colour_matrix``)."""

    band_dn2: np.ndarray
    weighted_dn2: np.ndarray
    terms: tuple[str, ...]


def systematic_variance(values: np.ndarray, response, file_white_dn: float, to_signal: Callable[[np.ndarray],
                        np.ndarray], raw_signal: np.ndarray, inv_flat: np.ndarray | None,
                        weights: np.ndarray) -> SystematicVariance | None:
    """The tone curve's and the colour matrix's variance at every output pixel (module docstring).

    values : (3, H, W) the file's integer values. response : the profile's processed
    :class:`camcal.models.response.ResponseModel`. to_signal : linear gradient (3, H, W) → binned RAW-equivalent
    gradient (3, h, w) (A⁻¹ or the gains, then the 2x2 bin). raw_signal : (3, h, w) the binned RAW-equivalent
    signal before the flat. inv_flat : (3, h, w) 1/flat or None. weights : (3,) the estimator's w_i.
    None when the profile states neither uncertainty.
    """
    w = np.asarray(weights, np.float32)[:, None, None]
    band = np.zeros(raw_signal.shape, np.float32)
    comb = np.zeros(raw_signal.shape[1:], np.float32)
    terms = []

    def finish(g: np.ndarray) -> np.ndarray:
        return g if inv_flat is None else g * inv_flat

    tone = response.tone
    if tone is not None:
        n_levels = int(round(float(file_white_dn))) + 1
        v = np.clip(np.asarray(values), 0, n_levels - 1).astype(np.intp)
        for block in tone_blocks(tone, float(response.white_level_dn), n_levels,
                                 response.value_scale(file_white_dn)):
            cov = block.covariance
            if np.count_nonzero(cov - np.diag(np.diag(cov))) == 0:
                for q, s2 in enumerate(np.diag(cov)):
                    g = finish(to_signal(block.gradient(q, v)))
                    band += np.float32(s2) * g * g
                    c = np.sum(g * w, axis=0)
                    comb += np.float32(s2) * c * c
            else:
                grads = [finish(to_signal(block.gradient(q, v))) for q in range(cov.shape[0])]
                band += quadratic_form(cov, grads)
                comb += quadratic_form(cov, [np.sum(g * w, axis=0) for g in grads])
            terms.append("tone")
    cm = response.colour_matrix
    if cm is not None and np.any(np.asarray(cm.matrix_unc) > 0):
        for s2, g in matrix_gradients(cm.matrix, cm.matrix_unc, raw_signal):
            g = finish(g)
            band += np.float32(s2) * g * g
            c = np.sum(g * w, axis=0)
            comb += np.float32(s2) * c * c
        terms.append("colour_matrix")
    if not terms:
        return None
    return SystematicVariance(band, comb, tuple(dict.fromkeys(terms)))

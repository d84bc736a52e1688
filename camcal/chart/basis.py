"""A low-dimensional basis of camera spectral sensitivities, learnt from the bundled curve library.

Jiang et al. (2013) found that the R, G and B sensitivities of 28 cameras each lie close to a space of two or
three principal components. Here, per channel, the library's curves (each normalised to a peak of 1, as Jiang
does) are decomposed by :func:`colour.recovery.PCA_Jiang2013` (an eigen-decomposition of the uncentred second
moment Σ_j c_j c_jᵀ): c(λ) ≈ Σ_k w_k φ_k(λ).

The Bayesian reading of that PCA, used by :mod:`camcal.chart.recovery`: the library is a sample of the
population of cameras, so a new camera's normalised curve is a priori

    c ~ N(μ, Σ),   μ = Φ w̄,   Σ = Φ Cov(w) Φᵀ + Σ_trunc,

w̄ and Cov(w) the mean and covariance of the library's coefficients on the first K components Φ, and Σ_trunc
the second moment of what K components miss for a camera the basis was not learnt from: the leave-one-camera-out
residuals r_j = c_j − Φ_(−j) Φ_(−j)ᵀ c_j (each camera projected onto the basis of the other cameras). Its
diagonal is the basis (truncation) error per wavelength.

References
----------
Jiang, J., Liu, D., Gu, J., Süsstrunk, S. (2013). What is the space of spectral sensitivity functions for digital
color cameras? IEEE Workshop on Applications of Computer Vision (WACV), 168-179.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from camcal.chart.targets import GRID_NM
from camcal.curve_library import COLLECTION, library_folder, list_cameras, read_curve_json
from camcal.errors import CamcalError

CHANNELS = ("R", "G", "B")
#: Components kept when not stated (a 24-patch chart constrains few more per channel).
DEFAULT_COMPONENTS = 8


@dataclass(frozen=True, eq=False)
class CameraBasis:
    """Training curves and their per-channel principal components.

    Attributes
    ----------
    wavelength_nm : ndarray (n,)
        nm.
    cameras : tuple of str
        Names of the training cameras.
    curves : ndarray (N, 3, n)
        Training curves R, G, B, each normalised to a peak of 1 (relative, dimensionless).
    components : ndarray (3, n, M)
        Per channel the eigenvectors φ_k (columns, unit norm) of :func:`colour.recovery.PCA_Jiang2013`,
        by decreasing eigenvalue.
    eigenvalues : ndarray (3, M)
    loo_residuals : dict
        K -> (N, 3, n) leave-one-camera-out residuals of each training camera on K components (filled lazily).
    source : dict
        Library, collection, excluded cameras.
    """

    wavelength_nm: np.ndarray
    cameras: tuple[str, ...]
    curves: np.ndarray
    components: np.ndarray
    eigenvalues: np.ndarray
    source: dict[str, Any] = field(default_factory=dict)
    loo_residuals: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def max_components(self) -> int:
        return int(self.components.shape[2])

    def phi(self, channel: int, k: int) -> np.ndarray:
        """(n, k) the first ``k`` components of ``channel`` (0 R, 1 G, 2 B)."""
        if not 1 <= k <= self.max_components:
            raise CamcalError(f"the basis has 1-{self.max_components} components, not {k}")
        return self.components[channel][:, :k]

    def project(self, curve: np.ndarray, channel: int, k: int) -> np.ndarray:
        """The best (least-squares) approximation of ``curve`` (n,) by ``k`` components of ``channel``."""
        p = self.phi(channel, k)
        return p @ (p.T @ np.asarray(curve, float))

    def residuals(self, k: int) -> np.ndarray:
        """(N, 3, n) leave-one-camera-out residuals on ``k`` components (module docstring)."""
        if k not in self.loo_residuals:
            out = np.empty_like(self.curves)
            for j in range(len(self.cameras)):
                keep = np.arange(len(self.cameras)) != j
                comps = _uncentred_components(self.curves[keep], k)
                for ch in range(3):
                    p = comps[ch]
                    out[j, ch] = self.curves[j, ch] - p @ (p.T @ self.curves[j, ch])
            self.loo_residuals[k] = out
        return self.loo_residuals[k]

    def truncation_variance(self, k: int) -> np.ndarray:
        """(3, n) mean square leave-one-out residual per wavelength: the basis error of a new camera's curve
        (normalised to peak 1) on ``k`` components, variance."""
        return np.mean(self.residuals(k) ** 2, axis=0)

    def prior(self, channel: int, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(μ (n,), Σ_basis (n, n), Σ_trunc (n, n)) of a new camera's normalised curve (module docstring)."""
        p = self.phi(channel, k)
        w = self.curves[:, channel] @ p
        mu = p @ w.mean(axis=0)
        cov_w = np.atleast_2d(np.cov(w, rowvar=False))
        r = self.residuals(k)[:, channel]
        return mu, p @ cov_w @ p.T, r.T @ r / r.shape[0]


def _uncentred_components(curves: np.ndarray, k: int) -> np.ndarray:
    """(3, n, k) the leading eigenvectors of Σ_j c_j c_jᵀ per channel: the arithmetic of
    :func:`colour.recovery.PCA_Jiang2013` on curves already normalised to peak 1, without building colour-science
    objects (the leave-one-out loop calls it once per camera; equality is tested)."""
    out = []
    for ch in range(curves.shape[1]):
        a = curves[:, ch]
        _, v = np.linalg.eigh(a.T @ a)
        out.append(v[:, ::-1][:, :k])
    return np.array(out)


def _pca(curves: np.ndarray, k: int | None, wl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel (components (3, n, k), eigenvalues (3, k)) by :func:`colour.recovery.PCA_Jiang2013`."""
    import colour  # loads matplotlib: kept off paths that do not need it
    from colour.recovery import PCA_Jiang2013

    msds = {str(i): colour.MultiSpectralDistributions(c.T, wl, labels=list(CHANNELS)) for i, c in enumerate(curves)}
    v, w = PCA_Jiang2013(msds, k, additional_data=True)
    return np.array(v), np.array(w)


@functools.cache
def _library(exclude: tuple[str, ...], grid: tuple[float, ...]) -> tuple[tuple[str, ...], np.ndarray]:
    wl = np.asarray(grid, float)
    names, curves = [], []
    for cam in list_cameras():
        if cam.name in exclude or cam.file in exclude:
            continue
        main = read_curve_json(library_folder() / cam.file)["spectral_data"]["data"]["main"]
        x = np.array([float(key) for key in main])
        v = np.array([main[key] for key in main], float)[np.argsort(x)]
        x = np.sort(x)
        rgb = np.array([np.interp(wl, x, v[:, i], left=0.0, right=0.0) for i in range(3)])
        if not (np.all(np.isfinite(rgb)) and np.all(rgb.max(axis=1) > 0)):
            raise CamcalError(f"library curves of {cam.name} are not finite and positive", cam.file)
        names.append(cam.name)
        curves.append(rgb / rgb.max(axis=1, keepdims=True))
    return tuple(names), np.array(curves)


def normalise(curves: np.ndarray) -> np.ndarray:
    """(3, n) curves, each channel divided by its peak."""
    c = np.asarray(curves, float)
    return c / np.max(c, axis=-1, keepdims=True)


def camera_basis(exclude=(), *, wavelength_nm=GRID_NM, extra: dict[str, np.ndarray] | None = None) -> CameraBasis:
    """The basis of the bundled library's cameras (:mod:`camcal.curve_library`), less ``exclude`` (names such as
    ``"Nikon D5100"`` or file names), plus ``extra`` curves ({name: (3, n) R, G, B on ``wavelength_nm``})."""
    wl = np.asarray(wavelength_nm, float)
    exclude = tuple(str(e) for e in exclude)
    names, curves = _library(exclude, tuple(float(x) for x in wl))
    known = {c.name for c in list_cameras()} | {c.file for c in list_cameras()}
    unknown = [e for e in exclude if e not in known]
    if unknown:
        raise CamcalError(f"cannot exclude {unknown[0]!r}: not a camera of the curve library")
    if extra:
        names = names + tuple(extra)
        curves = np.concatenate([curves, np.array([normalise(v) for v in extra.values()])])
    src = {"collection": COLLECTION, "excluded": list(exclude), "extra": list(extra or {})}
    return basis_from_curves(curves, names, wl, src)


def basis_from_curves(curves: np.ndarray, names: tuple[str, ...], wavelength_nm, source: dict | None = None
                      ) -> CameraBasis:
    """A basis of (N, 3, n) training curves (each channel normalised here to peak 1) named ``names``."""
    curves = np.array([normalise(c) for c in np.asarray(curves, float)])
    if len(names) < 3 or curves.shape[0] != len(names):
        raise CamcalError("a camera basis needs at least three training cameras, one name each")
    wl = np.asarray(wavelength_nm, float)
    comps, eig = _pca(curves, None, wl)
    src = {**(source or {}), "kind": "camera_basis", "n_cameras": len(names),
           "method": "PCA_Jiang2013 (colour.recovery), per channel, curves normalised to peak 1"}
    return CameraBasis(wl, tuple(names), curves, comps, eig, src)


def leave_one_out_table(basis: CameraBasis, k: int = DEFAULT_COMPONENTS) -> list[dict[str, Any]]:
    """Per training camera and channel, the RMS (over the grid) of the leave-one-camera-out residual on ``k``
    components, % of the channel's peak: the basis's own error for a camera it was not learnt from."""
    r = basis.residuals(k)
    return [{"camera": name, "channel": ch, "k": k,
             "rms_pct_of_peak": float(100.0 * np.sqrt(np.mean(r[j, i] ** 2)))}
            for j, name in enumerate(basis.cameras) for i, ch in enumerate(CHANNELS)]


def projection_floor(basis: CameraBasis, curves: np.ndarray, k: int = DEFAULT_COMPONENTS) -> dict[str, float]:
    """RMS % of peak of the best projection of a camera's (3, n) R, G, B curves onto ``k`` components per
    channel: no chart recovery in that basis can do better."""
    c = normalise(curves)
    return {ch: float(100.0 * np.sqrt(np.mean((c[i] - basis.project(c[i], i, k)) ** 2)))
            for i, ch in enumerate(CHANNELS)}

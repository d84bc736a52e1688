"""A low-dimensional basis of camera spectral sensitivities, learnt from the bundled curve library.

Jiang et al. (2013) found that the R, G and B sensitivities of 28 cameras each lie close to a space of two or
three principal components. Here, per channel, the library's curves (each normalised to a peak of 1, as Jiang
does) are decomposed by :func:`colour.recovery.PCA_Jiang2013` (an eigen-decomposition of the uncentred second
moment Σ_j c_j c_jᵀ): c(λ) ≈ Σ_k w_k φ_k(λ).

The Bayesian reading of that PCA, used by :mod:`camcal.chart.recovery`: the library is a sample of the
population of cameras, so a new camera's normalised curve is a priori

    c ~ N(μ, Σ),   μ = Φ w̄,   Σ = Φ Cov(w) Φᵀ + Σ_trunc (+ Σ_lab),

w̄ and Cov(w) the mean and covariance of the library's coefficients on the first K components Φ, and Σ_trunc
the second moment of what K components miss for a camera the basis was not learnt from: the leave-one-camera-out
residuals r_j = c_j − Φ_(−j) Φ_(−j)ᵀ c_j (each camera projected onto the basis of the other cameras). Its
diagonal is the basis (truncation) error per wavelength. Σ_lab (:func:`lab_covariance`) adds that the library's
curves are measurements of one lab: independent labs' curves of one camera model differ by 1-7 % of the peak.

The filter-shape prior (:func:`with_filter_variants`, on by default). A camera's curve is its sensor's
response times its cut filter's transmittance; phone modules cut the infrared earlier (about 650 nm) than the
library's DSLRs (680-700 nm). Each library camera is therefore also taken behind an extra IR-cut edge (630, 650,
670 nm) and UV-cut edge (405, 415 nm); leave-one-out leaves a camera out with all its variants.

References
----------
Jiang, J., Liu, D., Gu, J., Süsstrunk, S. (2013). What is the space of spectral sensitivity functions for digital
color cameras? IEEE Workshop on Applications of Computer Vision (WACV), 168-179.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import special

from camcal.chart.targets import GRID_NM
from camcal.curves.borrowed import shipped_borrowed_uncertainty
from camcal.curves.import_spectral import CURVE_CORRELATION
from camcal.curves.library import COLLECTION, library_folder, list_cameras, read_curve_json
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
        """(N, 3, n) leave-one-camera-out residuals on ``k`` components (module docstring); a camera is left out
        with its filter variants (:func:`with_filter_variants`)."""
        if k not in self.loo_residuals:
            base = [n.split(" × ")[0] for n in self.cameras]
            out = np.empty_like(self.curves)
            comps_of: dict[str, np.ndarray] = {}
            for j in range(len(self.cameras)):
                if base[j] not in comps_of:
                    keep = np.array([b != base[j] for b in base])
                    comps_of[base[j]] = _uncentred_components(self.curves[keep], k)
                comps = comps_of[base[j]]
                for ch in range(3):
                    p = comps[ch]
                    out[j, ch] = self.curves[j, ch] - p @ (p.T @ self.curves[j, ch])
            self.loo_residuals[k] = out
        return self.loo_residuals[k]

    def truncation_variance(self, k: int) -> np.ndarray:
        """(3, n) mean square leave-one-out residual per wavelength: the basis error of a new camera's curve
        (normalised to peak 1) on ``k`` components, variance."""
        return np.mean(self.residuals(k) ** 2, axis=0)

    def prior(self, channel: int, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(μ (n,), Σ_basis, Σ_trunc, Σ_lab (n, n)) of a new camera's normalised curve (module docstring)."""
        p = self.phi(channel, k)
        w = self.curves[:, channel] @ p
        mu = p @ w.mean(axis=0)
        cov_w = np.atleast_2d(np.cov(w, rowvar=False))
        r = self.residuals(k)[:, channel]
        return mu, p @ cov_w @ p.T, r.T @ r / r.shape[0], lab_covariance(self.wavelength_nm, CHANNELS[channel])


def lab_covariance(wavelength_nm, channel: str) -> np.ndarray:
    """(n, n) Σ_lab = f(λ) f(λ') ρ(λ − λ'): how far a measured curve lies from the camera's true curve, as a
    fraction of the peak (f: the borrowed-curve table of :mod:`camcal.curves.borrowed`, independent
    measurements of one model by different labs; ρ: their correlation over wavelength,
    :data:`camcal.curves.import_spectral.CURVE_CORRELATION`)."""
    wl = np.asarray(wavelength_nm, float)
    f = shipped_borrowed_uncertainty().at(wl)[channel]
    d = wl[:, None] - wl[None, :]
    rho = sum(w * np.exp(-d ** 2 / (2 * ell ** 2)) for w, ell in CURVE_CORRELATION)
    return f[:, None] * f[None, :] * rho


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


#: Extra cut-off edges of the filter-shape prior: IR-cut half-transmission wavelengths, UV-cut ones, and the
#: edges' Gaussian width (nm). Phone modules cut the infrared earlier than DSLRs (about 650 nm against 680-700 nm).
FILTER_IR_CUTS_NM = (630.0, 650.0, 670.0)
FILTER_UV_CUTS_NM = (405.0, 415.0)
FILTER_EDGE_SIGMA_NM = 8.0


def filter_edge(wavelength_nm, cut_nm: float, kind: str, sigma_nm: float = FILTER_EDGE_SIGMA_NM) -> np.ndarray:
    """Transmittance of an interference cut filter's edge: an error-function step, 0.5 at ``cut_nm``
    (``kind`` ``"ir"`` passes below it, ``"uv"`` above)."""
    x = (np.asarray(wavelength_nm, float) - cut_nm) / (sigma_nm * math.sqrt(2.0))
    return 0.5 * special.erfc(x if kind == "ir" else -x)


def with_filter_variants(names: tuple[str, ...], curves: np.ndarray, wavelength_nm, *,
                         ir_cuts_nm: tuple[float, ...] = FILTER_IR_CUTS_NM,
                         uv_cuts_nm: tuple[float, ...] = FILTER_UV_CUTS_NM,
                         keep_bare: bool = True) -> tuple[tuple[str, ...], np.ndarray]:
    """The filter-shape prior: every training camera also behind each extra IR-cut edge (``ir_cuts_nm``) and
    each UV-cut edge (``uv_cuts_nm``): the same sensor in a module with another cut filter.

    ``keep_bare`` False (a known IR cut, :func:`ir_cut_nodes`) leaves out the cameras without an extra IR edge
    and takes the UV edges on each IR variant instead of on the bare cameras."""
    ir = [(curves * filter_edge(wavelength_nm, cut, "ir"), [f"{n} × IR-cut {cut:g} nm" for n in names])
          for cut in ir_cuts_nm]
    sets = [(curves, list(names)), *ir] if keep_bare else ir
    uv_of = sets[:1] if keep_bare else ir
    out, labels = [c for c, _ in sets], [lab for _, ls in sets for lab in ls]
    for cut in uv_cuts_nm:
        for c, ls in uv_of:
            out.append(c * filter_edge(wavelength_nm, cut, "uv"))
            labels += [f"{lab} × UV-cut {cut:g} nm" for lab in ls]
    return tuple(labels), np.concatenate(out)


def ir_cut_nodes(cut_nm: float, sigma_nm: float) -> tuple[float, ...]:
    """IR-cut edges that stand for a cut known as ``cut_nm`` ± ``sigma_nm`` (a module's datasheet): the three
    points c + σ·{−√1.5, 0, +√1.5}, equally weighted, whose spread is σ (their variance is exactly σ²)."""
    if not (math.isfinite(cut_nm) and 550.0 <= cut_nm <= 760.0):
        raise CamcalError(f"an IR cut at {cut_nm:g} nm is outside 550-760 nm")
    if not (math.isfinite(sigma_nm) and 0.0 <= sigma_nm <= 50.0):
        raise CamcalError(f"the IR cut's uncertainty {sigma_nm:g} nm is outside 0-50 nm")
    h = math.sqrt(1.5) * sigma_nm
    return (cut_nm,) if sigma_nm == 0.0 else (cut_nm - h, cut_nm, cut_nm + h)


def camera_basis(exclude=(), *, wavelength_nm=GRID_NM, extra: dict[str, np.ndarray] | None = None,
                 filter_variants: bool = True, ir_cut: tuple[float, float] | None = None) -> CameraBasis:
    """The basis of the bundled library's cameras (:mod:`camcal.curves.library`), less ``exclude`` (names such as
    ``"Nikon D5100"`` or file names), plus ``extra`` curves ({name: (3, n) R, G, B on ``wavelength_nm``}), with
    the filter-shape prior (:func:`with_filter_variants`) unless ``filter_variants`` is False.

    ``ir_cut`` (nm, 1-σ nm): the module's IR cut is known (its datasheet's half-transmission wavelength): every
    training camera is taken behind that edge (:func:`ir_cut_nodes`) and none without it, so the prior is the
    library's cameras as the module's filter makes them. A chart cannot measure the edge beyond about 640 nm
    (docs/spectral.md); this is how a user who knows it says so."""
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
    n_measured = len(names)
    ir_cuts = FILTER_IR_CUTS_NM if ir_cut is None else ir_cut_nodes(*ir_cut)
    if filter_variants or ir_cut is not None:
        names, curves = with_filter_variants(names, curves, wl, ir_cuts_nm=ir_cuts, keep_bare=ir_cut is None)
    variants = filter_variants or ir_cut is not None
    src = {"collection": COLLECTION, "excluded": list(exclude), "extra": list(extra or {}),
           "n_measured_cameras": n_measured,
           "filter_variants": {"ir_cuts_nm": list(ir_cuts), "uv_cuts_nm": list(FILTER_UV_CUTS_NM),
                               "edge_sigma_nm": FILTER_EDGE_SIGMA_NM, "bare_included": ir_cut is None}
           if variants else None,
           "ir_cut": None if ir_cut is None else {"cut_nm": float(ir_cut[0]), "sigma_nm": float(ir_cut[1]),
                                                   "source": "user (the module's datasheet)"}}
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
    """Per measured training camera and channel, the RMS (over the grid) of the leave-one-camera-out residual on
    ``k`` components (the camera left out with its filter variants), % of the channel's peak: the basis's own
    error for a camera it was not learnt from."""
    r = basis.residuals(k)
    return [{"camera": name, "channel": ch, "k": k,
             "rms_pct_of_peak": float(100.0 * np.sqrt(np.mean(r[j, i] ** 2)))}
            for j, name in enumerate(basis.cameras) if " × " not in name for i, ch in enumerate(CHANNELS)]


def projection_floor(basis: CameraBasis, curves: np.ndarray, k: int = DEFAULT_COMPONENTS) -> dict[str, float]:
    """RMS % of peak of the best projection of a camera's (3, n) R, G, B curves onto ``k`` components per
    channel: no chart recovery in that basis can do better."""
    c = normalise(curves)
    return {ch: float(100.0 * np.sqrt(np.mean((c[i] - basis.project(c[i], i, k)) ** 2)))
            for i, ch in enumerate(CHANNELS)}

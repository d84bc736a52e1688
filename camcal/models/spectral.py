"""The spectral sensitivity c(λ) of a camera and its serialisation.

Measured by :mod:`camcal.calibrate.sweep` (the stored convention, finite bandwidth, is described there), imported by
:mod:`camcal.curves.files`, or taken from the curve library.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from scipy.interpolate import CubicSpline

from camcal.errors import CamcalError
from camcal.frame import MONO, PLANES, RGB
from camcal.io.store import to_jsonable
from camcal.models.spectra import FWHM_TO_SIGMA
from camcal.units import RELATIVE, SPECTRAL_SENSITIVITY

DEFAULT_REFERENCE_ISO = 100.0


DEFAULT_REFERENCE_F_NUMBER = 4.0


ABSOLUTE_UNITS = SPECTRAL_SENSITIVITY


RELATIVE_UNITS = RELATIVE


@dataclass(frozen=True)
class SpectralSensitivity:
    """Spectral sensitivity per CFA plane.

    Attributes
    ----------
    wavelength_nm : ndarray (n,)
        Monochromator settings, nm, increasing.
    values : dict
        c(λ) per plane ``R, G1, G2, B``: slit-weighted (``deconvolved`` False) or
        deconvolved. Units in :attr:`units`.
    uncertainty : dict
        Standard uncertainty per plane, same units (temporal noise and reference
        detector; for deconvolved values propagated through the linear estimator,
        regularisation bias excluded).
    units : str
        ``"relative"`` or :data:`ABSOLUTE_UNITS`.
    mode : {"relative", "absolute"}
    reference_iso, reference_f_number : float or None
        Setting the DN rates are normalised to; None when unknown, which only relative curves may be (a
        relative curve needs no exposure setting; its absolute scale, when set, refers to one).
    bandwidth_nm : float or None
        Median slit FWHM, nm, when known.
    deconvolved : bool
    n_frames : dict
        Frames used per wavelength (key: wavelength as text), informational.
    notes : tuple of str
        Warnings raised while measuring (skipped frames...).
    source : dict or None
        Where the curves came from and how their absolute scale was set
        (:mod:`camcal.curves.files`, :mod:`camcal.curves.import_spectral`): ``kind``
        ``sweep`` | ``imported`` | ``reference_targets``, the source ``file`` and
        its ``sha256``, ``absolute_scale``. None: measured by :func:`camcal.calibrate.sweep.measure_sweep`
        (profiles written before the field existed).
    """

    wavelength_nm: np.ndarray
    values: dict[str, np.ndarray]
    uncertainty: dict[str, np.ndarray]
    units: str
    mode: Literal["relative", "absolute"]
    reference_iso: float | None = None
    reference_f_number: float | None = None
    bandwidth_nm: float | None = None
    deconvolved: bool = False
    n_frames: dict[str, int] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    source: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        wl = np.asarray(self.wavelength_nm, float)
        if wl.ndim != 1 or wl.size == 0 or np.any(np.diff(wl) <= 0):
            raise CamcalError("spectral sensitivity wavelengths must be a non-empty increasing 1-D array")
        for d in (self.values, self.uncertainty):
            if set(d) not in (set(PLANES), set(RGB), set(MONO)) or any(np.shape(v) != wl.shape for v in d.values()):
                raise CamcalError(f"spectral sensitivity needs planes {PLANES} (Bayer), {RGB} (linear RAW) or {MONO} "
                                  f"(monochrome) of {wl.size} values each")
        if set(self.values) != set(self.uncertainty):
            raise CamcalError("spectral sensitivity values and uncertainties name different planes")

    @property
    def plane_names(self) -> tuple[str, ...]:
        """:data:`camcal.frame.PLANES` (Bayer sensors), :data:`camcal.frame.RGB` (linear RAW) or
        :data:`camcal.frame.MONO` (a monochrome sensor)."""
        return PLANES if "G1" in self.values else MONO if "Y" in self.values else RGB

    @property
    def mono(self) -> bool:
        """True for the one channel ``Y`` of a monochrome sensor (no R, G, B views)."""
        return "Y" in self.values

    # ---- views ---------------------------------------------------------------------
    def rgb(self) -> dict[str, np.ndarray]:
        """R, G (mean of G1 and G2 on a Bayer sensor), B."""
        v = self.values
        if "Y" in v:  # a monochrome sensor: its one channel
            return {"Y": v["Y"]}
        if "G1" not in v:
            return {"R": v["R"], "G": v["G"], "B": v["B"]}
        return {"R": v["R"], "G": 0.5 * (v["G1"] + v["G2"]), "B": v["B"]}

    def rgb_uncertainty(self) -> dict[str, np.ndarray]:
        """Standard uncertainty of :meth:`rgb` (G1 and G2 treated as independent)."""
        u = self.uncertainty
        if "Y" in u:
            return {"Y": u["Y"]}
        if "G1" not in u:
            return {"R": u["R"], "G": u["G"], "B": u["B"]}
        return {"R": u["R"], "G": 0.5 * np.hypot(u["G1"], u["G2"]), "B": u["B"]}

    def channels(self) -> dict[str, np.ndarray]:
        """Planes and RGB together: R, G1, G2, B, G (R, G, B for linear RAW; Y for a monochrome sensor)."""
        if self.mono:
            return dict(self.values)
        return {**self.values, "G": self.rgb()["G"]}


    def origin(self) -> dict[str, Any]:
        """:attr:`source`, or for curves without one (measured by :func:`measure_sweep`) the sweep's record."""
        if self.source:
            return self.source
        absolute = self.mode == "absolute"
        return {"kind": "sweep", "file": None, "sha256": None,
                "absolute_scale": {"method": "sweep" if absolute else "none",
                                   "description": "monochromator sweep with a reference detector (camcal sweep)"
                                   if absolute else "relative: no absolute scale"}}

    # ---- derived figures -----------------------------------------------------------
    def peak_wavelength_nm(self) -> dict[str, float]:
        """Wavelength of the largest sample per channel (exact to the sampling), nm."""
        return {k: float(self.wavelength_nm[int(np.argmax(v))]) for k, v in self.channels().items()}

    def effective_wavelength_nm(self) -> dict[str, float]:
        """Centroid λ_eff = ∫ λ c dλ / ∫ c dλ per channel, nm (negative noise clipped to 0)."""
        wl = self.wavelength_nm
        out = {}
        for k, v in self.channels().items():
            c = np.clip(v, 0.0, None)
            area = np.trapezoid(c, wl)
            out[k] = float(np.trapezoid(wl * c, wl) / area) if area > 0 else float("nan")
        return out

    def effective_bandwidth_nm(self) -> dict[str, float]:
        """Equivalent width ∫ c dλ / max c per channel, nm (the width of a box of the same area and peak)."""
        wl = self.wavelength_nm
        out = {}
        for k, v in self.channels().items():
            c = np.clip(v, 0.0, None)
            out[k] = float(np.trapezoid(c, wl) / c.max()) if c.max() > 0 else float("nan")
        return out

    def slit_bias(self) -> dict[str, np.ndarray]:
        """Second-order estimate of (c ⊛ φ − c) per plane, same units: (σ²/2)·c'' (Gaussian slit).

        c'' is that of the not-a-knot cubic spline through the nodes (:class:`scipy.interpolate.CubicSpline`).

        Zero when deconvolved or when the bandwidth is unknown.
        """
        if self.deconvolved or not self.bandwidth_nm or self.wavelength_nm.size < 4:
            return {p: np.zeros_like(self.wavelength_nm) for p in self.plane_names}
        sigma2 = (self.bandwidth_nm * FWHM_TO_SIGMA) ** 2
        return {p: 0.5 * sigma2 * CubicSpline(self.wavelength_nm, v)(self.wavelength_nm, 2)
                for p, v in self.values.items()}

    def summary(self) -> dict[str, Any]:
        """JSON-ready overview: setting, range, peaks, effective wavelengths and bandwidths, slit bias."""
        peak = max(float(np.max(v)) for v in self.values.values())
        bias = self.slit_bias()
        return {
            "mode": self.mode,
            "units": self.units,
            "reference_iso": self.reference_iso,
            "reference_f_number": self.reference_f_number,
            "bandwidth_nm": self.bandwidth_nm,
            "deconvolved": self.deconvolved,
            "n_wavelengths": int(self.wavelength_nm.size),
            "wavelength_range_nm": [float(self.wavelength_nm[0]), float(self.wavelength_nm[-1])],
            "peak_value": peak,
            "peak_wavelength_nm": self.peak_wavelength_nm(),
            "effective_wavelength_nm": self.effective_wavelength_nm(),
            "effective_bandwidth_nm": self.effective_bandwidth_nm(),
            "max_relative_uncertainty_at_peak": {
                p: float(self.uncertainty[p][int(np.argmax(self.values[p]))] / max(np.max(self.values[p]), 1e-300))
                for p in self.plane_names
            },
            "slit_bias_rms_of_peak": {p: float(np.sqrt(np.mean(bias[p] ** 2)) / peak) for p in self.plane_names},
            "notes": list(self.notes),
        }


def describe_origin(src: dict[str, Any]) -> tuple[str, str]:
    """(where c(λ) came from, how its absolute scale was set) from :meth:`SpectralSensitivity.origin`."""
    if src.get("kind") == "sweep":
        where = "monochromator sweep (camcal sweep / calibrate)"
    elif src.get("kind") == "library":
        lib = src.get("library") or {}
        where = (f"curve library: {lib.get('name')} ({lib.get('file')}, {lib.get('collection')}; measured by "
                 f"{lib.get('creator') or 'unknown'}, {lib.get('license')}), matched from {lib.get('matched')}")
    elif src.get("kind") == "chart":
        photos = src.get("photos") or []
        light = src.get("light") or {}
        where = (f"a colour chart ({len(photos)} photo{'s' if len(photos) != 1 else ''}: "
                 f"{', '.join(str(p.get('file')) for p in photos[:4])}) under {light.get('model') or light.get('kind')}"
                 f"; basis of {((src.get('basis') or {}).get('n_cameras'))} library cameras")
    else:
        where = (f"imported from {src.get('file')} ({src.get('format')} format, SHA-256 "
                 f"{str(src.get('sha256'))[:12]}…)")
    a = src.get("absolute_scale") or {}
    if a.get("method") == "reference_targets":
        n = len(a.get("targets") or [])
        how = f"reference targets ({n} target{'s' if n != 1 else ''}): {a.get('verdict', '')}"
    else:
        how = str(a.get("description") or a.get("method"))
    return where, how


def to_relative(s: SpectralSensitivity) -> SpectralSensitivity:
    """Divide values and uncertainties by the largest value over all planes (mode ``relative``)."""
    peak = max(float(np.max(v)) for v in s.values.values())
    if not peak > 0:
        raise CamcalError("spectral sensitivity has no positive value; cannot normalise")
    return _replace(s, values={p: v / peak for p, v in s.values.items()},
                    uncertainty={p: u / peak for p, u in s.uncertainty.items()}, units=RELATIVE_UNITS,
                    mode="relative")


def _replace(s: SpectralSensitivity, **kw) -> SpectralSensitivity:
    return dataclasses.replace(s, **kw)


def spectral_to_dict(s: SpectralSensitivity) -> dict[str, Any]:
    """Everything of ``s``, JSON-ready (lists of floats); inverse of :func:`spectral_from_dict`."""
    return to_jsonable({
        "wavelength_nm": s.wavelength_nm, "values": {p: s.values[p] for p in s.plane_names},
        "uncertainty": {p: s.uncertainty[p] for p in s.plane_names}, "units": s.units, "mode": s.mode,
        "reference_iso": s.reference_iso, "reference_f_number": s.reference_f_number,
        "bandwidth_nm": s.bandwidth_nm, "deconvolved": s.deconvolved, "n_frames": s.n_frames,
        "notes": list(s.notes), "summary": s.summary(),
        **({"source": s.source} if s.source is not None else {}),
    })


def _planes_of(values: dict) -> tuple[str, ...]:
    """The plane names a stored curve set uses: R, G1, G2, B (Bayer) or R, G, B (linear RAW)."""
    return PLANES if "G1" in values else MONO if "Y" in values else RGB


def float_or_none(v: Any) -> float | None:
    """``None`` stays unknown; anything else becomes a float."""
    return None if v is None else float(v)


def spectral_from_dict(d: dict[str, Any]) -> SpectralSensitivity:
    """Rebuild a :class:`SpectralSensitivity` from :func:`spectral_to_dict` output."""
    try:
        return SpectralSensitivity(
            wavelength_nm=np.asarray(d["wavelength_nm"], float),
            values={p: np.asarray(d["values"][p], float) for p in _planes_of(d["values"])},
            uncertainty={p: np.asarray(d["uncertainty"][p], float) for p in _planes_of(d["values"])},
            units=str(d["units"]), mode="absolute" if d["mode"] == "absolute" else "relative",
            reference_iso=float_or_none(d.get("reference_iso")),
            reference_f_number=float_or_none(d.get("reference_f_number")),
            bandwidth_nm=None if d.get("bandwidth_nm") is None else float(d["bandwidth_nm"]),
            deconvolved=bool(d.get("deconvolved", False)), n_frames=dict(d.get("n_frames") or {}),
            notes=tuple(str(n) for n in d.get("notes") or ()),
            source=dict(d["source"]) if isinstance(d.get("source"), dict) else None,
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise CamcalError(f"malformed spectral sensitivity ({type(exc).__name__}: {exc})") from None

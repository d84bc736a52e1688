"""The dark model of one camera (bias, dark current, read noise, defects) and its files.

Fitted by :mod:`camcal.calibrate.dark`; read by profiles, the correction path, plots and reports without loading the
fitting code. See :mod:`camcal.calibrate.dark` for the measurement (EMVA 1288 §4.3, §4.5).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from camcal.errors import CamcalError
from camcal.frame import MONO, PLANES, RGB
from camcal.io.store import load_stage, save_stage
from camcal.units import DN, DN_PER_S

HOT, DEAD, NOISY = 1, 2, 4
"""Bits of :attr:`DarkModel.defects`."""


KIND = "dark"


_MAPS = ("bias", "dark_current", "dark_current_unc", "read_noise", "defects")


@dataclass(frozen=True, eq=False)
class DarkModel:
    """Dark model of one camera at one ISO (planes R, G1, G2, B, half resolution).

    Attributes
    ----------
    bias_dn : (4, h, w) float32
        Master bias in DN, black level included (the intercept at t = 0).
    dark_current_dn_per_s : (4, h, w) float32, or None
        Dark current β in DN s⁻¹ at :attr:`iso`; None when unknown (a bias-only calibration).
    dark_current_unc_dn_per_s : (4, h, w) float32, or None
        Standard uncertainty of β per pixel, DN s⁻¹.
    read_noise_dn : (4, h, w) float32
        Temporal standard deviation of the dark signal in DN with the quantisation removed (below 1 DN
        of noise: the plane's value from :func:`camcal.calibrate.dark.quantised_noise_fit`, see
        :func:`camcal.calibrate.dark.temporal_noise`).
    defects : (4, h, w) uint8
        Bit mask: 1 hot (dark current), 2 dead (no response in the flats, set by ``camcal calibrate``
        from :func:`camcal.models.flat.dead_pixels`), 4 noisy (temporal variance far above the model).
    iso : float
        ISO of the frames.
    cfa_pattern : str or None
        CFA pattern of Bayer frames; None for linear RAW (planes R, G, B at full resolution).
    temperature_c : float or None
        Mean temperature of the dark frames, degC (``temperature_C`` column), when known.
    channels : dict
        Per-plane summary numbers (see :meth:`summary`).
    exposure_times_s : tuple of float
        Dark exposure times used, s.
    black_level_dn : tuple of float
        Black level per plane from the files, DN.
    white_level_dn : float
        Saturation level, DN.
    provenance : dict
        Files, folders and options.
    """

    bias_dn: np.ndarray
    dark_current_dn_per_s: np.ndarray | None
    dark_current_unc_dn_per_s: np.ndarray | None
    read_noise_dn: np.ndarray
    defects: np.ndarray
    iso: float
    cfa_pattern: str | None
    temperature_c: float | None
    channels: dict = field(default_factory=dict)
    exposure_times_s: tuple[float, ...] = ()
    black_level_dn: tuple[float, ...] = ()
    white_level_dn: float = float("nan")
    provenance: dict = field(default_factory=dict)

    def dark_frame_dn(self, exposure_s: float, iso: float | None = None,
                      window: tuple[slice, slice] | None = None) -> np.ndarray:
        """Expected dark frame ``bias + β·t·iso/self.iso`` (seed eq. 12 β term), (C, h, w) DN, float32.

        β scales with the gain, so with ``iso`` it is multiplied by ``iso / self.iso``;
        the bias (black level) does not change with ISO. A bias-only model (β unknown) gives its bias.
        ``window`` (rows, columns of each plane, plane pixels) evaluates that part only.
        """
        bias, dark_signal = self.dark_frame_parts_dn(exposure_s, iso, window)
        out = np.array(bias, np.float32)
        if dark_signal is not None:
            out += dark_signal
        return out

    def dark_frame_parts_dn(self, exposure_s: float, iso: float | None = None,
                            window: tuple[slice, slice] | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """The two parts of :meth:`dark_frame_dn`: the bias (a read-only view of :attr:`bias_dn` on ``window``)
        and the dark signal ``β·t·iso/self.iso`` in DN, float32, or None when β is unknown (bias-only model)."""
        if not np.isfinite(exposure_s) or exposure_s < 0:
            raise CamcalError(f"exposure time must be a non-negative number of seconds, got {exposure_s}")
        rows, cols = window if window is not None else (slice(None), slice(None))
        dark_signal = None
        if self.dark_current_dn_per_s is not None:
            dark_signal = self.dark_current_dn_per_s[:, rows, cols] * np.float32(exposure_s * self.iso_scale(iso))
        return self.bias_dn[:, rows, cols], dark_signal

    def iso_scale(self, iso: float | None) -> float:
        """k = ``iso / self.iso`` (1 when ``iso`` is None): the factor by which the dark current and the
        noise in DN grow with the gain (EMVA 1288 release 4.0, eq. 6, with the gain in DN per electron ∝ ISO)."""
        return 1.0 if iso is None else float(iso) / float(self.iso)

    def noise_variance_dn2(self, signal_dn: np.ndarray, dark_signal_dn: np.ndarray, gain_dn_per_e: np.ndarray,
                           iso: float | None = None, window: tuple[slice, slice] | None = None) -> np.ndarray:
        """Temporal noise variance of a frame's dark-subtracted signal, DN², float32 (C, h, w).

        EMVA 1288 release 4.0 linear camera model (eq. 6): ``σ² = σ_read²·k² + K·k·max(s + β·t·k, 0)``,
        with ``s`` the signal above dark (``signal_dn``, before the flat division) and β·t·k the dark signal
        (``dark_signal_dn``, from :meth:`dark_frame_parts_dn`; both carry shot noise), ``σ_read`` the
        read-noise map (:attr:`read_noise_dn`), K ``gain_dn_per_e`` (C, 1, 1) the system gain in DN per
        electron at :attr:`iso` and k :meth:`iso_scale`; all on ``window`` (plane pixels).
        """
        rows, cols = window if window is not None else (slice(None), slice(None))
        k = self.iso_scale(iso)
        var = dark_signal_dn + signal_dn
        np.maximum(var, 0, out=var)
        var *= gain_dn_per_e * np.float32(k)
        rn = self.read_noise_dn[:, rows, cols]
        read_var = rn * rn
        read_var *= np.float32(k * k)
        var += read_var
        return var

    @property
    def plane_names(self) -> tuple[str, ...]:
        """:data:`camcal.frame.PLANES` for Bayer frames, :data:`camcal.frame.RGB` for linear RAW,
        :data:`camcal.frame.MONO` for a monochrome sensor."""
        return {4: PLANES, 1: MONO}.get(self.bias_dn.shape[0], RGB)

    @property
    def layout(self) -> str:
        """``"bayer"``, ``"linear"`` or ``"mono"`` (the frames the model was measured on)."""
        return {4: "bayer", 1: "mono"}.get(self.bias_dn.shape[0], "linear")

    def summary(self) -> dict:
        """JSON-ready summary: per-plane numbers and defect counts."""
        per = {key: {p: self.channels[p][key] for p in self.plane_names}
               for key in next(iter(self.channels.values()))}
        for key in ("hot_pixel_count", "dead_pixel_count", "noisy_pixel_count"):
            per[key.replace("_count", "_count_per_plane")] = per.pop(key)
        return {
            "iso": self.iso,
            "cfa_pattern": self.cfa_pattern,
            "layout": self.layout,
            "temperature_c": self.temperature_c,
            "exposure_times_s": list(self.exposure_times_s),
            "plane_shape": list(self.bias_dn.shape[1:]),
            **per,
            "hot_pixel_count": int(np.count_nonzero(self.defects & HOT)),
            "dead_pixel_count": int(np.count_nonzero(self.defects & DEAD)),
            "noisy_pixel_count": int(np.count_nonzero(self.defects & NOISY)),
            "defect_fraction": float(np.count_nonzero(self.defects) / self.defects.size),
        }


def with_dead_pixels(model: DarkModel, dead: np.ndarray, source: str) -> DarkModel:
    """A new model whose defect map also marks ``dead`` (C, h, w) pixels as DEAD, counts updated.

    Dead pixels are found by their response (:func:`camcal.models.flat.dead_pixels`); ``source`` says where.
    """
    dead = np.asarray(dead, bool)
    if dead.shape != model.defects.shape:
        raise CamcalError(f"dead-pixel map {dead.shape} does not match the dark model's {model.defects.shape}")
    defects = model.defects | (dead * DEAD).astype(np.uint8)
    channels = {p: {**c, "dead_pixel_count": int(np.count_nonzero(defects[k] & DEAD))}
                for k, (p, c) in enumerate(model.channels.items())}
    prov = {**model.provenance, "dead_pixels": source}
    return dataclasses.replace(model, defects=defects, channels=channels, provenance=prov)


def _finite_or_big(plane: np.ndarray) -> np.ndarray:
    """``plane`` with its non-finite values (a β of unknown uncertainty: inf) stored as 3e38; the plane itself
    (no copy) when every value is finite, the usual case."""
    finite = np.isfinite(plane)
    return plane if finite.all() else np.where(finite, plane, np.float32(3.0e38))


def dark_to_parts(model: DarkModel) -> tuple[dict, dict[str, np.ndarray]]:
    """The JSON part and the named maps (``bias.R`` ...) of a model; used by files and profiles."""
    arrays = {"bias": model.bias_dn, "dark_current": model.dark_current_dn_per_s,
              "dark_current_unc": model.dark_current_unc_dn_per_s, "read_noise": model.read_noise_dn,
              "defects": model.defects.astype(np.float32)}
    maps = {f"{m}.{p}": _finite_or_big(arrays[m][k])
            for m in _MAPS if arrays[m] is not None for k, p in enumerate(model.plane_names)}
    data = {
        "iso": model.iso, "cfa_pattern": model.cfa_pattern, "layout": model.layout,
        "temperature_c": model.temperature_c,
        "exposure_times_s": list(model.exposure_times_s), "black_level_dn": list(model.black_level_dn),
        "white_level_dn": model.white_level_dn, "channels": model.channels, "summary": model.summary(),
        "dark_current_known": model.dark_current_dn_per_s is not None,
        "provenance": model.provenance,
        "units": {"bias": DN, "dark_current": f"{DN_PER_S} at iso", "dark_current_unc": DN_PER_S, "read_noise": DN,
                  "defects": "bits: 1 hot, 2 dead, 4 noisy"},
    }
    return data, maps


def dark_from_parts(data: dict, maps: dict[str, np.ndarray], where: str | Path | None = None) -> DarkModel:
    """Inverse of :func:`dark_to_parts`; ``where`` names the file in errors."""
    known = not (isinstance(data, dict) and data.get("dark_current_known") is False)
    names = _MAPS if known else tuple(m for m in _MAPS if not m.startswith("dark_current"))
    layout = data.get("layout") if isinstance(data, dict) else None
    planes = RGB if layout == "linear" else MONO if layout == "mono" else PLANES
    missing = [f"{m}.{p}" for m in names for p in planes if f"{m}.{p}" not in maps]
    if missing:
        raise CamcalError(f"dark model lacks maps {', '.join(missing[:4])}", where)
    try:
        arr: dict[str, np.ndarray | None] = {
            m: np.stack([maps[f"{m}.{p}"] for p in planes]).astype(np.float32) for m in names}
        if known:
            arr["dark_current_unc"] = np.where(arr["dark_current_unc"] >= 3.0e38, np.inf, arr["dark_current_unc"])
        else:
            arr["dark_current"] = arr["dark_current_unc"] = None
        return DarkModel(
            bias_dn=arr["bias"], dark_current_dn_per_s=arr["dark_current"],
            dark_current_unc_dn_per_s=arr["dark_current_unc"], read_noise_dn=arr["read_noise"],
            defects=np.rint(arr["defects"]).astype(np.uint8), iso=float(data["iso"]),
            cfa_pattern=None if data.get("cfa_pattern") is None else str(data["cfa_pattern"]),
            temperature_c=None if data.get("temperature_c") is None else float(data["temperature_c"]),
            channels=dict(data.get("channels") or {}),
            exposure_times_s=tuple(float(t) for t in data.get("exposure_times_s") or ()),
            black_level_dn=tuple(float(t) for t in data.get("black_level_dn") or ()),
            white_level_dn=float(data.get("white_level_dn") or float("nan")),
            provenance=dict(data.get("provenance") or {}),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise CamcalError(f"malformed dark model ({exc})", where) from None


def save_dark(model: DarkModel, path: str | Path) -> Path:
    """Write the model as ``path`` (JSON) + ``<stem>.maps.exr`` (maps ``bias.R`` ...), kind ``dark``."""
    data, maps = dark_to_parts(model)
    return save_stage(path, KIND, data, maps)


def load_dark(path: str | Path) -> DarkModel:
    """Read a model written by :func:`save_dark` (the one dark-model loader)."""
    data, maps = load_stage(path, KIND)
    return dark_from_parts(data, maps, path)


def as_dark_model(dark: DarkModel | str | Path | None) -> DarkModel | None:
    """A dark model given as itself, as a path (read by :func:`load_dark`) or None."""
    if dark is None or isinstance(dark, DarkModel):
        return dark
    if isinstance(dark, str | Path):
        return load_dark(dark)
    return dark  # any object with the DarkModel interface (dark_frame_dn...), e.g. in tests

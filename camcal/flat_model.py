"""The flat-field model (DNG ``FixVignetteRadial`` vignetting, optional 2-D Legendre series, PRNU) and its files.

Fitted by :mod:`camcal.flat`, which describes the model and its normalisation (g = 1 at the optical centre).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.polynomial import legendre

from camcal.errors import CamcalError
from camcal.frame import plane_offsets
from camcal.store import load_stage, save_stage

N_RADIAL = 5
"""Number of DNG radial coefficients k0..k4."""


@dataclass(frozen=True)
class PlaneGeometry:
    """Where plane pixels sit on the full-resolution sensor.

    Attributes
    ----------
    scale : int
        Mosaic pixels per plane pixel (2 for CFA planes, 1 for full-resolution channels).
    offsets : dict
        ``{channel: (row, column)}`` offset of each plane within the CFA cell, mosaic pixels.
    full_shape : (int, int)
        Full-resolution (H, W) in mosaic pixels.
    """

    scale: int
    offsets: dict[str, tuple[int, int]]
    full_shape: tuple[int, int]

    @staticmethod
    def for_planes(channels: tuple[str, ...], shape: tuple[int, int], cfa_pattern: str | None) -> PlaneGeometry:
        h, w = shape
        if cfa_pattern is None:
            return PlaneGeometry(1, {c: (0, 0) for c in channels}, (h, w))
        off = plane_offsets(cfa_pattern)
        return PlaneGeometry(2, {c: off[c] for c in channels}, (2 * h, 2 * w))

    def to_full(self, channel: str, x: np.ndarray | float, y: np.ndarray | float):
        """Plane pixel coordinates -> full-resolution mosaic coordinates (x, y)."""
        oy, ox = self.offsets[channel]
        return self.scale * np.asarray(x, float) + ox, self.scale * np.asarray(y, float) + oy

    def rmax_full(self, channel: str, cx: float, cy: float) -> float:
        """Distance (mosaic px) from the plane's optical centre to the farthest image corner."""
        fx, fy = self.to_full(channel, cx, cy)
        hh, ww = self.full_shape
        return float(max(np.hypot(x - fx, y - fy) for x in (0.0, ww - 1.0) for y in (0.0, hh - 1.0)))

    def r2(self, channel: str, x: np.ndarray, y: np.ndarray, cx: float, cy: float) -> np.ndarray:
        """Squared normalised radius r² of plane pixels (x, y) for the centre (cx, cy) in plane px."""
        s = self.scale
        rmax = self.rmax_full(channel, cx, cy)
        return ((s * (x - cx)) ** 2 + (s * (y - cy)) ** 2) / rmax**2


def radial_gain(r2: np.ndarray, k: tuple[float, ...] | np.ndarray) -> np.ndarray:
    """DNG radial model g = 1 + k0 r² + k1 r⁴ + ... (Horner), r² given."""
    g = np.zeros(np.shape(r2), dtype=np.float64)
    for kk in reversed(tuple(k)):
        g += kk
        g *= r2
    g += 1.0
    return g


def _legendre_uv(geom: PlaneGeometry, channel: str, x: np.ndarray, y: np.ndarray):
    """Plane pixels -> (u, v) in [-1, 1] across the full-resolution image."""
    fx, fy = geom.to_full(channel, x, y)
    hh, ww = geom.full_shape
    return 2.0 * fx / (ww - 1.0) - 1.0, 2.0 * fy / (hh - 1.0) - 1.0


@dataclass(frozen=True)
class FlatModel:
    """A fitted flat field.

    Attributes
    ----------
    channels : tuple of str
        Plane names, ``("R", "G1", "G2", "B")`` for RAW.
    centre_px : dict
        Fitted optical centre (x, y) per plane, in plane pixels (half resolution for RAW).
    k : dict
        DNG radial coefficients k0..k4 per plane (r normalised to the farthest corner, measured in
        full-resolution pixels; see the module docstring).
    model_2d : dict or None
        Optional smooth 2-D model: ``{"kind": "legendre2d", "degree": n, "coefficients": {ch: (n+1)x(n+1)},
        "scale": {ch: s}}``, g(u, v) = s · Σ c_ij P_i(u) P_j(v), u, v in [-1, 1] across the full-resolution image.
        When present, :meth:`gain` uses it instead of the radial model.
    prnu : ndarray or None
        (C, h, w) pixel-level residual master/(A·g), mean 1 per plane (dimensionless).
    residual_rms : dict
        Relative RMS of the downsampled master about the active smooth model, per plane.
    shape : (int, int)
        (h, w) of each plane.
    cfa_pattern : str or None
        CFA pattern of the frames (None: channels already at full resolution).
    level_dn : dict
        Fitted on-axis level A per plane of the master flat, DN above dark (mean over frames).
    prnu_rms : dict
        Estimated PRNU (relative RMS of P, the temporal noise of the master removed), per plane.
    info : dict
        Provenance: frames used, downsample factor, combine method, dark model.
    """

    channels: tuple[str, ...]
    centre_px: dict[str, tuple[float, float]]
    k: dict[str, tuple[float, ...]]
    model_2d: dict | None
    prnu: np.ndarray | None
    residual_rms: dict[str, float]
    shape: tuple[int, int]
    cfa_pattern: str | None = None
    level_dn: dict[str, float] = field(default_factory=dict)
    prnu_rms: dict[str, float] = field(default_factory=dict)
    info: dict = field(default_factory=dict)

    @property
    def geometry(self) -> PlaneGeometry:
        return PlaneGeometry.for_planes(self.channels, self.shape, self.cfa_pattern)

    @property
    def kind(self) -> str:
        return "2d" if self.model_2d else "radial"

    def radial_gain(self) -> np.ndarray:
        """(C, h, w) DNG radial model per plane, 1 at each plane's optical centre."""
        h, w = self.shape
        yy, xx = np.arange(h, dtype=np.float64)[:, None], np.arange(w, dtype=np.float64)[None, :]  # broadcast
        geom = self.geometry
        out = np.empty((len(self.channels), h, w), np.float32)
        for i, c in enumerate(self.channels):
            cx, cy = self.centre_px[c]
            out[i] = radial_gain(geom.r2(c, xx, yy, cx, cy), self.k[c])
        return out

    def gain(self, with_prnu: bool = False) -> np.ndarray:
        """(C, h, w) relative illumination, 1 at the optical centre (times the PRNU map when asked).

        The 2-D model is used when present, else the DNG radial model.
        """
        if self.model_2d:
            h, w = self.shape
            yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
            out = np.empty((len(self.channels), h, w), np.float32)
            for i, c in enumerate(self.channels):
                out[i] = _eval_2d(self.model_2d, self.geometry, c, xx, yy)
        else:
            out = self.radial_gain()
        if with_prnu:
            if self.prnu is None:
                raise CamcalError("this flat model has no PRNU map (fitted without it)")
            out = out * self.prnu.astype(np.float32)
        return out

    def corner_gain(self) -> dict[str, float]:
        """Smallest gain at the four plane corners, per plane."""
        g = self.gain()
        return {c: float(min(g[i, 0, 0], g[i, 0, -1], g[i, -1, 0], g[i, -1, -1])) for i, c in enumerate(self.channels)}

    def centre_full_px(self) -> dict[str, tuple[float, float]]:
        """Optical centre per plane in full-resolution mosaic pixels (x, y)."""
        geom = self.geometry
        return {c: tuple(float(v) for v in geom.to_full(c, *self.centre_px[c])) for c in self.channels}

    def summary(self) -> dict:
        """JSON-ready summary (no maps)."""
        return {
            "model": self.kind,
            "channels": list(self.channels),
            "shape": list(self.shape),
            "cfa_pattern": self.cfa_pattern,
            "normalisation": "gain = 1 at the optical centre (radiance refers to on-axis sensitivity)",
            "centre_px": {c: list(v) for c, v in self.centre_px.items()},
            "centre_full_px": {c: list(v) for c, v in self.centre_full_px().items()},
            "k": {c: list(v) for c, v in self.k.items()},
            "corner_gain": self.corner_gain(),
            "residual_rms": dict(self.residual_rms),
            "level_dn": dict(self.level_dn),
            "prnu_rms": dict(self.prnu_rms),
            "has_prnu": self.prnu is not None,
            "info": dict(self.info),
        }


def _eval_2d(model_2d: dict, geom: PlaneGeometry, channel: str, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    u, v = _legendre_uv(geom, channel, x, y)
    coef = np.asarray(model_2d["coefficients"][channel], float)
    return float(model_2d["scale"][channel]) * legendre.legval2d(u, v, coef)


#: A pixel is dead when its flat-field response is below this fraction of the smooth model's.
DEAD_RESPONSE = 0.5


def dead_pixels(model: FlatModel, threshold: float = DEAD_RESPONSE) -> np.ndarray:
    """(C, h, w) bool: pixels whose response to the flat light is below ``threshold`` of the model's.

    The response is the PRNU map (master flat / (level · vignetting), mean 1 per plane): a dead pixel
    answers light with (almost) nothing, whatever its dark level. This, not a zero temporal variance
    in dark frames, is what makes a pixel dead (below 1 DN of read noise most good pixels read the same
    value in every dark frame). Empty without a PRNU map.
    """
    if model.prnu is None:
        return np.zeros((len(model.channels), *model.shape), bool)
    return np.asarray(model.prnu) < threshold


def flat_to_parts(model: FlatModel) -> tuple[dict, dict[str, np.ndarray]]:
    """The JSON part and the named maps (``gain.R``, ``prnu.R`` ...) of a model; used by files and profiles."""
    data = model.summary()
    data["model_2d"] = model.model_2d
    gain = model.gain()
    maps = {f"gain.{c}": gain[i] for i, c in enumerate(model.channels)}
    if model.prnu is not None:
        maps.update({f"prnu.{c}": model.prnu[i] for i, c in enumerate(model.channels)})
    return data, maps


def flat_from_parts(data: dict, maps: dict[str, np.ndarray], where: str | Path | None = None) -> FlatModel:
    """Inverse of :func:`flat_to_parts`; ``where`` names the file in errors."""
    try:
        channels = tuple(data["channels"])
        shape = (int(data["shape"][0]), int(data["shape"][1]))
        centre = {c: (float(data["centre_px"][c][0]), float(data["centre_px"][c][1])) for c in channels}
        k = {c: tuple(float(v) for v in data["k"][c]) for c in channels}
        rms = {c: float(data["residual_rms"][c]) for c in channels}
        prnu = None
        if data.get("has_prnu"):
            prnu = np.stack([np.asarray(maps[f"prnu.{c}"], np.float32) for c in channels])
            if prnu.shape[1:] != shape:
                raise ValueError("PRNU maps do not match the recorded shape")
        model = FlatModel(
            channels=channels, centre_px=centre, k=k, model_2d=data.get("model_2d"), prnu=prnu, residual_rms=rms,
            shape=shape, cfa_pattern=data.get("cfa_pattern"),
            level_dn={c: float(v) for c, v in (data.get("level_dn") or {}).items()},
            prnu_rms={c: float(v) for c, v in (data.get("prnu_rms") or {}).items()},
            info=dict(data.get("info") or {}),
        )
        # probe the model at the plane corners: a decodable but unusable model fails here, not later
        h, w = shape
        yy, xx = np.array([[0.0, 0.0], [h - 1.0, h - 1.0]]), np.array([[0.0, w - 1.0], [0.0, w - 1.0]])
        geom = model.geometry
        for c in channels:
            g = (_eval_2d(model.model_2d, geom, c, xx, yy) if model.model_2d
                 else radial_gain(geom.r2(c, xx, yy, *centre[c]), k[c]))
            if not np.all(np.isfinite(g)):
                raise ValueError(f"the vignetting model of {c} is not finite at the corners")
        return model
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
        raise CamcalError(f"not a valid camcal flat file ({type(exc).__name__}: {exc})", where) from None


def save_flat(model: FlatModel, path: str | Path) -> Path:
    """Write ``path`` (JSON) and ``<stem>.maps.exr`` with ``gain.<ch>`` and ``prnu.<ch>`` maps."""
    data, maps = flat_to_parts(model)
    return save_stage(path, "flat", data, maps)


def load_flat(path: str | Path) -> FlatModel:
    """Read a flat model written by :func:`save_flat`."""
    data, maps = load_stage(path, "flat")
    return flat_from_parts(data, maps, path)


def as_flat_model(flat: FlatModel | str | Path | None) -> FlatModel | None:
    """A flat model given as itself, as a path (read by :func:`load_flat`) or None."""
    if isinstance(flat, str | Path):
        return load_flat(flat)
    return flat

"""The flat-field model (DNG ``FixVignetteRadial`` vignetting, optional 2-D Legendre series, PRNU) and its files.

Fitted by :mod:`camcal.calibrate.flat`, which describes the model and its normalisation (g = 1 at the optical centre).

Optics: a model records the f-number and focal length of its flats (:class:`Optics`, each value with its
source; unknown stays None). Vignetting changes with the aperture (mechanical vignetting falls as the lens is
stopped down: tens of percent at the corners between f/2.8 and f/8 on real lenses), so a model may carry
models fitted at other f-numbers (:attr:`FlatModel.apertures`), and :func:`choose_flat` picks the one of a
photo's f-number:

- a model measured at the photo's f-number (within 3 %): used as it is;
- between two measured f-numbers whose models have the same form (same kind, planes, shape, number of radial
  terms or 2-D degree): ln g interpolated linearly in 1/N² (the relative aperture area, on which the amount of
  light clipped by the lens barrel depends), pixel by pixel; its uncertainty is stated as the largest
  difference at the corners from interpolating linearly in ln N instead (two rules that agree at the measured
  f-numbers and differ only in how the falloff changes between them);
- otherwise (outside the measured range, models of different forms, one model only): the nearest measured
  f-number (in 1/N²), with a warning saying by how much the corners may then differ.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.polynomial import legendre

from camcal.errors import CamcalError
from camcal.frame import plane_offsets
from camcal.io.store import load_stage, save_stage

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
    """DNG radial model g = 1 + k0 r² + k1 r⁴ + ... (Horner), r² given.

    Trailing zero coefficients (k3 = k4 = 0 of a three-term fit) are skipped: with a finite r² their Horner
    steps leave exactly 0, so the values are those of the full sum."""
    k = tuple(k)
    top = max((i for i, kk in enumerate(k) if kk != 0), default=-1)
    g = np.zeros(np.shape(r2), dtype=np.float64)
    if top >= 0 and np.all(np.isfinite(r2)):
        k = k[:top + 1]
    for kk in reversed(k):
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
class Optics:
    """The lens setting of a model's flats; a value nothing gave is None (unknown), never a default.

    Attributes
    ----------
    f_number : the flats' f-number N (dimensionless).
    f_number_source : where it came from: ``tag``, ``libraw``, ``frames.csv``, ``session`` (``session.toml``),
        ``folder flat/f8/`` (the sub-folder's name); several joined by ``+``.
    focal_length_mm : the lens's focal length, mm.
    focal_length_source : as ``f_number_source``.
    """

    f_number: float | None = None
    f_number_source: str | None = None
    focal_length_mm: float | None = None
    focal_length_source: str | None = None

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @staticmethod
    def from_dict(d: dict | None) -> Optics:
        d = d or {}

        def num(k):
            return None if d.get(k) is None else float(d[k])

        return Optics(num("f_number"), d.get("f_number_source"), num("focal_length_mm"), d.get("focal_length_source"))

    def label(self) -> str:
        """``f/2.8, 50 mm``; ``f/?`` for an unknown f-number."""
        n = "f/?" if self.f_number is None else f"f/{self.f_number:g}"
        return n if self.focal_length_mm is None else f"{n}, {self.focal_length_mm:g} mm"


_MODEL_FIELDS = frozenset({"channels", "centre_px", "k", "model_2d", "shape", "cfa_pattern"})
"""The fields of :class:`FlatModel` its gain depends on."""


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
    optics : Optics
        f-number and focal length of the flats (each with its source; unknown: None).
    apertures : tuple of FlatModel
        Models fitted on flats at other f-numbers (same camera and geometry), by f-number; their PRNU map is this
        model's (a property of the pixels, not of the lens). Empty for flats of one f-number.
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
    optics: Optics = Optics()  # noqa: RUF009 - frozen, so one shared default is safe
    apertures: tuple[FlatModel, ...] = ()

    def models(self) -> tuple[FlatModel, ...]:
        """This model and those at other f-numbers, by f-number (unknown last)."""
        return tuple(sorted((self, *self.apertures),
                            key=lambda m: (m.optics.f_number is None, m.optics.f_number or 0.0)))

    def f_numbers(self) -> list[float | None]:
        """The f-numbers of the flats, by value (None: unknown)."""
        return [m.optics.f_number for m in self.models()]

    def replace(self, **changes) -> FlatModel:
        """:func:`dataclasses.replace`, keeping the gain evaluated already (:meth:`with_gain`) when ``changes``
        leave the model itself (its planes, centres, coefficients) as it is."""
        new = dataclasses.replace(self, **changes)
        gain = self.__dict__.get("_gain")
        if gain is not None and not changes.keys() & _MODEL_FIELDS:
            object.__setattr__(new, "_gain", gain)
        return new

    def with_gain(self, gain: np.ndarray) -> FlatModel:
        """This model holding ``gain``, its own :meth:`gain` (no PRNU) as evaluated by the caller: :meth:`gain`
        returns it (read-only) instead of evaluating the model again. A calibration evaluates the model once, in
        its fit, and passes it on to the sweep's correction and the profile's maps. A model loaded from a file
        holds no gain: each use evaluates it (no whole-frame map kept beside the caller's)."""
        gain = np.asarray(gain, np.float32)
        if gain.shape != (len(self.channels), *self.shape):
            raise ValueError(f"a gain of shape {gain.shape} for a model of {len(self.channels)} x {self.shape}")
        gain = gain.view()
        gain.setflags(write=False)
        new = dataclasses.replace(self)
        object.__setattr__(new, "_gain", gain)
        return new

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_gain"}  # the gain is evaluated again, not copied

    def corner_values(self) -> np.ndarray:
        """(C, 4) gain at the four plane corners of each plane (the model only, no PRNU), without a full map."""
        h, w = self.shape
        yy, xx = np.array([0.0, 0.0, h - 1.0, h - 1.0]), np.array([0.0, w - 1.0, 0.0, w - 1.0])
        geom = self.geometry
        return np.stack([_eval_2d(self.model_2d, geom, c, xx, yy) if self.model_2d
                         else radial_gain(geom.r2(c, xx, yy, *self.centre_px[c]), self.k[c]) for c in self.channels])

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

        The 2-D model is used when present, else the DNG radial model. A model holding its gain
        (:meth:`with_gain`) returns it, read-only, without evaluating it again.
        """
        held = self.__dict__.get("_gain")
        if held is not None:
            out = held
        elif self.model_2d:
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
        """Smallest gain at the four plane corners, per plane (the values of :meth:`gain`'s float32 map, the
        model evaluated at the corners only)."""
        g = self.corner_values().astype(np.float32)
        return {c: float(min(g[i])) for i, c in enumerate(self.channels)}

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
            "optics": self.optics.to_dict(),
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
    if model.apertures:  # parametric models only: their PRNU is this model's map, their gain is evaluated on load
        data["apertures"] = [{**m.summary(), "model_2d": m.model_2d, "has_prnu": False} for m in model.apertures]
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
            optics=Optics.from_dict(data.get("optics")),
        )
        if data.get("apertures"):
            others = tuple(dataclasses.replace(flat_from_parts({**d, "has_prnu": False}, {}, where), prnu=prnu)
                           for d in data["apertures"])
            if any(o.shape != shape or o.channels != channels for o in others):
                raise ValueError("a model of another f-number has other planes or another shape")
            model = dataclasses.replace(model, apertures=others)
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


#: Focal lengths within 1 % are one setting (a prime lens, a zoom at the same mark).
FOCAL_TOLERANCE = 0.01
#: Two f-numbers within 3 % are one setting: cameras write nominal values (2.8) or exact ones (2√2 = 2.83).
F_NUMBER_TOLERANCE = 0.03


def same_f_number(a: float | None, b: float | None) -> bool:
    """True when ``a`` and ``b`` are one f-number (within :data:`F_NUMBER_TOLERANCE`); False when either is None."""
    return a is not None and b is not None and abs(a - b) <= F_NUMBER_TOLERANCE * min(a, b)


def same_form(a: FlatModel, b: FlatModel) -> bool:
    """True when two models may be interpolated: same kind, planes, shape, CFA, radial terms or 2-D degree."""
    if (a.kind, a.channels, a.shape, a.cfa_pattern) != (b.kind, b.channels, b.shape, b.cfa_pattern):
        return False
    if a.kind == "2d":
        return a.model_2d.get("degree") == b.model_2d.get("degree")  # type: ignore[union-attr]
    return a.info.get("n_terms") == b.info.get("n_terms")


def _u(n: float) -> float:
    """The interpolation variable of the vignetting: 1/N² (the relative aperture area)."""
    return 1.0 / (n * n)


@dataclass(frozen=True)
class FlatChoice:
    """The vignetting model for one photo (:func:`choose_flat`).

    Attributes
    ----------
    how : ``measured`` (a model at the photo's f-number), ``interpolated`` (between two), ``nearest`` (the
        nearest measured f-number), ``unchecked`` (the flats' or the photo's f-number unknown).
    parts : ((model, weight), ...): ln g = Σ weight · ln g_model (one part of weight 1 unless interpolated).
    photo_f_number, photo_focal_length_mm : the photo's setting (None: unknown).
    corner_difference_rel : how much the corrected corners may be off, |g_true / g_model − 1| (the largest over
        planes and corners): the interpolation's uncertainty, the extrapolated change beyond the measured range,
        1/g_corner − 1 for a photo stopped down from flats of one f-number (the true gain lies between the flats'
        and 1), the flats' corner falloff for another focal length; None when measured, or when nothing bounds it
        (a photo at a wider aperture than flats of one f-number).
    mismatch : the photo's f-number or focal length is not one the flats were measured at (``--strict`` refuses).
    warning : one line for the user (None when the model was measured at the photo's setting).
    """

    how: str
    parts: tuple[tuple[FlatModel, float], ...]
    photo_f_number: float | None
    photo_focal_length_mm: float | None
    corner_difference_rel: float | None
    mismatch: bool
    warning: str | None

    @property
    def key(self) -> tuple:
        """Identifies the gain map (for caching)."""
        return tuple((m.optics.f_number, round(w, 9)) for m, w in self.parts)

    def gain(self, with_prnu: bool = False) -> np.ndarray:
        """(C, h, w) float32 gain: the chosen model's, or exp(Σ w ln g) of the interpolated ones (PRNU: the
        primary model's map, shared by every f-number)."""
        if len(self.parts) == 1:
            return np.asarray(self.parts[0][0].gain(with_prnu=with_prnu), np.float32)
        log_g = sum(w * np.log(m.gain().astype(np.float64)) for m, w in self.parts)
        g = np.exp(log_g)
        if with_prnu:
            prnu = self.parts[0][0].prnu
            if prnu is None:
                raise CamcalError("this flat model has no PRNU map (fitted without it)")
            g = g * prnu
        return g.astype(np.float32)

    def describe(self) -> str:
        """``f/8 model (measured)``, ``f/2.8 and f/8 models (ln g interpolated in 1/N²)`` ..."""
        names = " and ".join(m.optics.label() for m, _ in self.parts)
        how = {"measured": "measured at the photo's f-number", "interpolated": "ln g interpolated linearly in 1/N²",
               "nearest": "the nearest measured f-number", "unchecked": "f-number not checked"}[self.how]
        return f"{names} ({how})"

    def record(self, flat: FlatModel) -> dict:
        """JSON-ready record for the output's metadata."""
        return {"photo_f_number": self.photo_f_number, "photo_focal_length_mm": self.photo_focal_length_mm,
                "flat_f_numbers": flat.f_numbers(),
                "flat_focal_length_mm": [m.optics.focal_length_mm for m in flat.models()],
                "vignetting_model": self.describe(), "how": self.how,
                "weights": [[m.optics.f_number, w] for m, w in self.parts],
                "corner_difference_rel": self.corner_difference_rel, "warning": self.warning,
                "mismatch": self.mismatch,
                "rule": "ln g linear in 1/N² between measured f-numbers of models of the same form; outside: "
                        "the nearest (docs/flat.md)"}


def _corner_ratio(log_a: np.ndarray, log_b: np.ndarray) -> float:
    """Largest |exp(a − b) − 1| over planes and corners."""
    return float(np.max(np.abs(np.expm1(log_a - log_b))))


def choose_flat(flat: FlatModel, f_number: float | None, focal_length_mm: float | None = None) -> FlatChoice:
    """The vignetting model of a photo taken at ``f_number`` and ``focal_length_mm`` (module docstring: the rule).

    Parameters
    ----------
    flat : the profile's flat model (with its models at other f-numbers, :attr:`FlatModel.apertures`).
    f_number : the photo's f-number N; None when unknown.
    focal_length_mm : the photo's focal length, mm; None when unknown.
    """
    models = [m for m in flat.models() if m.optics.f_number is not None]
    notes: list[str] = []
    mismatch = False
    diff: float | None = None
    n_txt = "f/?" if f_number is None else f"f/{f_number:g}"
    if not models or f_number is None:
        how, parts = "unchecked", ((flat, 1.0),)
        mismatch = True
        notes.append("the flats' f-number is unknown: the vignetting of this f/{} photo is not checked (record "
                     "f_number in the flats' frames.csv or session.toml)".format("?" if f_number is None else
                                                                                f"{f_number:g}")
                     if not models else "the photo's f-number is unknown: the vignetting model (flats at "
                     f"{', '.join(m.optics.label() for m in models)}) is not checked")
    else:
        at = [m for m in models if same_f_number(m.optics.f_number, f_number)]
        u = _u(f_number)
        lo = [m for m in models if m.optics.f_number < f_number]  # wider apertures (larger 1/N²)
        hi = [m for m in models if m.optics.f_number > f_number]
        if at:
            how, parts = "measured", ((at[0], 1.0),)
        elif lo and hi and same_form(lo[-1], hi[0]):
            a, b = lo[-1], hi[0]
            ua, ub = _u(a.optics.f_number), _u(b.optics.f_number)
            wa = (u - ub) / (ua - ub)
            how, parts = "interpolated", ((a, wa), (b, 1.0 - wa))
            la, lb = np.log(a.corner_values()), np.log(b.corner_values())
            na, nb = a.optics.f_number, b.optics.f_number
            wl = (np.log(nb) - np.log(f_number)) / (np.log(nb) - np.log(na))
            diff = _corner_ratio(wa * la + (1 - wa) * lb, wl * la + (1 - wl) * lb)
            mismatch = True
            notes.append(f"{n_txt} photo between the flats' {a.optics.label()} and {b.optics.label()}: vignetting "
                         f"interpolated (ln g linear in 1/N²); corners uncertain by up to ±{100 * diff:.2g} % (the "
                         "difference from interpolating in ln N)")
        else:
            near = min(models, key=lambda m: abs(_u(m.optics.f_number) - u))
            how, parts = "nearest", ((near, 1.0),)
            mismatch = True
            side = [m for m in models if m is not near and same_form(m, near)]
            if side:  # extrapolate the change between the two nearest models to the photo's f-number
                other = min(side, key=lambda m: abs(_u(m.optics.f_number) - _u(near.optics.f_number)))
                ln, lo_ = np.log(near.corner_values()), np.log(other.corner_values())
                slope = (ln - lo_) / (_u(near.optics.f_number) - _u(other.optics.f_number))
                diff = _corner_ratio(ln + slope * (u - _u(near.optics.f_number)), ln)
                why = (f"about {100 * diff:.2g} %, extrapolating the change from {other.optics.label()} to "
                       f"{near.optics.label()}")
            else:
                g_corner = float(np.min(near.corner_values()))
                if f_number > near.optics.f_number:  # stopped down: the true gain lies between the flats' and 1
                    diff = 1.0 / g_corner - 1.0
                    why = (f"up to +{100 * diff:.3g} % (stopping down reduces the flats' corner falloff of "
                           f"{100 * (1 - g_corner):.2g} %, so the corners are over-corrected by at most 1/g - 1)")
                else:  # opened up: more vignetting than the flats', by an amount one model cannot bound
                    diff = None
                    why = (f"an amount one flat cannot bound (a wider aperture vignettes more than the flats' "
                           f"{100 * (1 - g_corner):.2g} % corner falloff: the corners are under-corrected, by tens "
                           "of percent between f/2.8 and f/8 on real lenses)")
            span = (f"outside the flats' {models[0].optics.label()} – {models[-1].optics.label()}"
                    if len(models) > 1 else f"flats at {near.optics.label()} only")
            notes.append(f"{n_txt} photo, {span}: the {near.optics.label()} vignetting model is used; the corners "
                         f"may differ by {why}")
    focal = [m.optics.focal_length_mm for m, _ in parts if m.optics.focal_length_mm is not None]
    if focal and focal_length_mm is not None and any(
            abs(f - focal_length_mm) > FOCAL_TOLERANCE * min(f, focal_length_mm) for f in focal):
        mismatch = True
        falloff = float(1.0 - min(float(np.min(m.corner_values())) for m, _ in parts))
        diff = max(diff or 0.0, falloff)
        notes.append(f"focal length {focal_length_mm:g} mm, the flats' {focal[0]:g} mm: vignetting changes with "
                     f"the focal length, the corners may differ by as much as the flats' corner falloff, "
                     f"{100 * falloff:.2g} %")
    return FlatChoice(how, parts, f_number, focal_length_mm, diff, mismatch, "; ".join(notes) or None)


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

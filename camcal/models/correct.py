"""The one correction path: raw planes → signal above dark, its variance and a per-pixel invalid mask.

Every stage that reads light frames (flat, linearity, sweep, colour) and ``apply`` corrects a frame
here and nowhere else (one correction path). For planes ``d`` in DN of a frame taken with exposure time t at
ISO S, with the calibration known so far:

1. **dark**: ``s = d − (bias + β·t·S/S_dark)`` — the dark model's expected dark frame (seed eq. 12,
   the offset term β_i of RAW data is the bias plus the dark signal, physics notes); without a dark
   model the file's black level per plane is subtracted (dark current then stays in the signal);
   a dark model whose dark current is unknown (bias-only calibration) subtracts its bias only.
2. **flat**: ``s / g`` with g the flat-field gain (1 at the optical centre, :mod:`camcal.calibrate.flat`).
3. **variance** (optional): ``var = σ_read²·k² + K·k·max(s + β·t·k, 0)``, divided by g²
   (EMVA 1288 release 4.0, linear camera model, eq. 6; s + dark signal = d − bias;
   k = S/S_dark, K the system gain in DN per electron from photon transfer or the dark frames'
   photon-transfer line), evaluated by the dark model itself
   (:meth:`camcal.models.dark.DarkModel.noise_variance_dn2`).
4. **invalid mask**: known defects (dark model: hot, dead, noisy; flat: dead), pixels at or above
   the white level (saturated or clipped), and raw values at 0 when the black level is above 0
   (clipped below). Saturation is counted outside known defects: a hot pixel the dark model knows
   never makes a frame "saturated" — it is masked.

Exposure normalisation (ISO·t/N², seed §2.1) stays in :mod:`camcal.models.exposure`; the callers divide the
corrected signal by the relative exposure when they need a rate.

Statistics of a stage use the valid pixels only; :func:`require_valid` refuses a frame only when
too few valid pixels are left in a channel, and says why.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from camcal.errors import CamcalError
from camcal.frame import PLANES, Frame, split_planes
from camcal.models.dark import DarkModel

Window = tuple[slice, slice]
"""Rows and columns of a plane, plane pixels (half resolution for CFA mosaics)."""


@runtime_checkable
class DarkFrameModel(Protocol):
    """What the correction path needs of a dark model.

    ``dark_frame_dn(exposure_s, iso)`` returns the complete expected dark frame in DN (black level
    included) as (C, h, w) planes, as an (H, W) mosaic, or as a dict of planes. :class:`camcal.models.dark.DarkModel`
    implements it on a window too, and gives the noise variance (``noise_variance_dn2``); another model is
    evaluated whole and cropped, and gives no variance.
    """

    def dark_frame_dn(self, exposure_s: float, iso: float) -> Any: ...


@dataclass(frozen=True, eq=False)
class Calibration:
    """The calibration known so far, as the correction path uses it.

    Attributes
    ----------
    dark : a :class:`camcal.models.dark.DarkModel` (or any :class:`DarkFrameModel`), or None: subtract the
        file's black level only.
    flat_gain : (C, h, w) float32 flat-field gain (1 at the optical centre), or None.
    defects : (C, h, w) bool, True for known defective pixels, or None.
    inv_flat_gain : 1 / ``flat_gain`` (float32), computed once.
    noise_gain_dn_per_e : (C, 1, 1) float32 system gain K of the dark model at its ISO, DN per electron
        (the slope of its photon-transfer line), or None.
    dark_frames : None, or a dict in which the whole-frame dark frames are kept by (exposure, ISO) and reused
        (:meth:`remembering_dark_frames`): for a stack of frames of one exposure, such as the flats, the dark frame
        is computed once instead of once per frame. Not for a batch of photos of many exposures (a frame each).
    """

    dark: Any = None
    flat_gain: np.ndarray | None = None
    defects: np.ndarray | None = None
    inv_flat_gain: np.ndarray | None = None
    noise_gain_dn_per_e: np.ndarray | None = None
    dark_frames: dict | None = None

    def remembering_dark_frames(self) -> Calibration:
        """This calibration, keeping each whole-frame dark frame it computes for the next frame of the same
        exposure time and ISO (the same values, computed once)."""
        return replace(self, dark_frames={})

    @staticmethod
    def of(dark: Any = None, flat: Any = None, *, with_prnu: bool = False, emva: Any = None) -> Calibration:
        """Build from a dark model and a :class:`camcal.models.flat.FlatModel` (either may be None); the system gain
        of the noise model is :func:`system_gain_dn_per_e` (``emva``: the profile's EMVA 1288 sheet)."""
        gain = None
        if flat is not None:
            gain = np.asarray(flat.gain(with_prnu=with_prnu), np.float32)
            if not np.all(np.isfinite(gain)) or np.any(gain <= 0):
                raise CamcalError("the flat model's gain is not positive and finite everywhere")
        defects = None
        d = getattr(dark, "defects", None)
        if d is not None:
            defects = np.asarray(d) != 0
        k = system_gain_dn_per_e(dark, emva)
        inv = None if gain is None else (1.0 / gain).astype(np.float32)
        return Calibration(dark=dark, flat_gain=gain, defects=defects, inv_flat_gain=inv, noise_gain_dn_per_e=k)

    @property
    def dark_current_known(self) -> bool:
        """False for a bias-only dark model (dark current unknown)."""
        return self.dark is None or getattr(self.dark, "dark_current_dn_per_s", True) is not None


@dataclass(frozen=True, eq=False)
class Corrected:
    """One frame (or a window of it) through the correction path.

    Attributes
    ----------
    signal_dn : (C, h, w) float32, DN above dark, divided by the flat gain (the signal the pixel
        would give at the optical centre); not yet normalised by the exposure.
    variance_dn2 : (C, h, w) float32 noise variance of ``signal_dn`` in DN², or None (not asked for,
        or no dark model to take the noise model from).
    invalid : (C, h, w) bool, True where the pixel cannot be trusted (known defect, saturated,
        clipped).
    saturated : (C, h, w) bool, saturated or clipped pixels that are not known defects.
    defective : (C, h, w) bool, known defects.
    clipped : (C, h, w) bool, every pixel at or above the white level (or clipped at 0), defects included.
    channels : plane names.
    """

    signal_dn: np.ndarray
    variance_dn2: np.ndarray | None
    invalid: np.ndarray
    saturated: np.ndarray
    defective: np.ndarray
    clipped: np.ndarray
    channels: tuple[str, ...]

    def valid_fraction(self) -> np.ndarray:
        """(C,) fraction of valid pixels per channel."""
        return 1.0 - self.invalid.reshape(self.invalid.shape[0], -1).mean(axis=1)

    def saturated_fraction(self) -> np.ndarray:
        """(C,) fraction of pixels saturated outside known defects, per channel."""
        return self.saturated.reshape(self.saturated.shape[0], -1).mean(axis=1)

    def mean_dn(self) -> np.ndarray:
        """(C,) mean of the valid pixels per channel, DN (NaN for a channel without valid pixels)."""
        out = np.full(self.signal_dn.shape[0], np.nan)
        for k in range(out.size):
            ok = ~self.invalid[k]
            if ok.any():
                out[k] = float(np.mean(self.signal_dn[k], where=ok, dtype=np.float64))
        return out

    def masked(self, fill: float = np.nan) -> np.ndarray:
        """``signal_dn`` with invalid pixels set to ``fill`` (a new array)."""
        out = self.signal_dn.copy()
        out[self.invalid] = fill
        return out


def _window_of(a: np.ndarray, window: Window | None) -> np.ndarray:
    return a if window is None else a[:, window[0], window[1]]


def _check_dark_planes(dark: DarkModel, shape: tuple[int, ...], path: Path | None) -> None:
    if tuple(dark.bias_dn.shape) != tuple(shape):
        raise CamcalError(f"the frame's planes {tuple(shape)} do not match the dark model's "
                          f"{tuple(dark.bias_dn.shape)} (another camera, crop or resolution)", path)


def dark_frame(dark: Any, exposure_s: float, iso: float | None, shape: tuple[int, int, int],
               window: Window | None = None, channels: tuple[str, ...] = PLANES,
               cfa_pattern: str | None = None, path: Path | None = None) -> np.ndarray:
    """The dark model's expected dark frame on ``window``: bias + β·t·ISO/ISO_dark, DN, float32.

    ``shape`` is the full (C, h, w) plane shape of the frame. A :class:`camcal.models.dark.DarkModel`
    evaluates itself on the window only (:meth:`~camcal.models.dark.DarkModel.dark_frame_dn`); any other
    :class:`DarkFrameModel` is evaluated whole and cropped.
    """
    if isinstance(dark, DarkModel):
        _check_dark_planes(dark, shape, path)
        try:
            return dark.dark_frame_dn(exposure_s, iso, window)
        except CamcalError as exc:
            raise CamcalError(exc.message, path) from None
    try:
        d = dark.dark_frame_dn(exposure_s, iso)
    except CamcalError:
        raise
    except Exception as exc:  # a third-party model: report, do not crash
        raise CamcalError(f"the dark model failed for t = {exposure_s} s, ISO {iso}: {exc}", path) from None
    if isinstance(d, dict):
        d = np.stack([np.asarray(d[n], np.float64) for n in channels])
    d = np.asarray(d, np.float64)
    if d.ndim == 0:
        d = np.full(shape, float(d))
    elif d.ndim == 2 and cfa_pattern is not None and d.shape == (2 * shape[1], 2 * shape[2]):
        d = split_planes(d, cfa_pattern, dtype=np.float64)
    if d.shape != tuple(shape):
        raise CamcalError(f"the dark model's frame has shape {d.shape}, this frame's planes are {tuple(shape)}",
                          path)
    return np.ascontiguousarray(_window_of(d, window), np.float32)


def _dark_frame_of(calibration: Calibration, exposure_s: float, iso: float | None, shape: tuple[int, int, int],
                   window: Window | None, channels: tuple[str, ...], cfa_pattern: str | None,
                   path: Path | None) -> np.ndarray:
    """:func:`dark_frame` of ``calibration.dark``, taken from and kept in ``calibration.dark_frames`` when it is a
    dict and the whole frame is corrected (the kept array is never written to)."""
    memo = calibration.dark_frames
    if memo is None or window is not None:
        return dark_frame(calibration.dark, exposure_s, iso, shape, window, channels, cfa_pattern, path)
    key = (float(exposure_s), None if iso is None else float(iso), tuple(shape), tuple(channels), cfa_pattern)
    frame = memo.get(key)
    if frame is None:  # two threads may both compute it: the same values
        frame = dark_frame(calibration.dark, exposure_s, iso, shape, window, channels, cfa_pattern, path)
        frame.flags.writeable = False
        memo[key] = frame
    return frame


def correct_planes(
    planes: np.ndarray,
    calibration: Calibration,
    *,
    exposure_s: float | None,
    iso: float | None,
    white_level_dn: float,
    black_level_dn: np.ndarray,
    full_shape: tuple[int, int, int] | None = None,
    window: Window | None = None,
    variance: bool = False,
    channels: tuple[str, ...] = PLANES,
    cfa_pattern: str | None = None,
    path: Path | None = None,
    inplace: bool = False,
) -> Corrected:
    """Correct (C, h, w) planes in DN (module docstring): dark, flat, variance, invalid mask.

    Parameters
    ----------
    planes : (C, h, w) raw planes in DN (a window of the frame's planes when ``window`` is given).
    calibration : the dark model, flat gain and defects known so far.
    exposure_s, iso : the frame's exposure time (s) and ISO; the exposure time is needed with a
        dark model whose dark current is known.
    white_level_dn : saturation level of the file, DN.
    black_level_dn : (C,) black level per plane from the file, DN (used without a dark model).
    full_shape : (C, h, w) of the whole frame's planes (default: the shape of ``planes``).
    window : the rows and columns of the frame's planes that ``planes`` holds.
    variance : also compute the noise variance (needs a :class:`~camcal.models.dark.DarkModel` with a known
        dark current and a system gain, else None).
    inplace : float32 ``planes`` may be overwritten with the result (the hot path of ``apply``).

    Returns
    -------
    Corrected
    """
    planes = np.asarray(planes)
    shape = tuple(full_shape) if full_shape is not None else planes.shape
    white = np.float32(white_level_dn)
    raw_bad = planes >= white
    black = np.asarray(black_level_dn, np.float32).reshape(-1, 1, 1)
    if np.any(black > 0):
        raw_bad |= planes <= 0
    signal = planes if (inplace and planes.dtype == np.float32) else planes.astype(np.float32)
    dark = calibration.dark
    var = None
    if dark is not None:
        beta = getattr(dark, "dark_current_dn_per_s", True)
        if beta is not None and exposure_s is None:
            raise CamcalError("dark correction needs the exposure time, which the file does not give", path)
        t = 0.0 if exposure_s is None else float(exposure_s)
        if (variance and isinstance(dark, DarkModel) and beta is not None
                and calibration.noise_gain_dn_per_e is not None):
            # the dark frame in its two parts: the dark signal is shot noise too
            _check_dark_planes(dark, shape, path)
            try:
                bias, dark_signal = dark.dark_frame_parts_dn(t, iso, window)
            except CamcalError as exc:
                raise CamcalError(exc.message, path) from None
            signal -= bias
            signal -= dark_signal
            var = dark.noise_variance_dn2(signal, dark_signal, calibration.noise_gain_dn_per_e, iso, window)
        else:
            signal -= _dark_frame_of(calibration, t, iso, shape, window, channels, cfa_pattern, path)
    else:
        signal -= black
    if calibration.flat_gain is not None:
        g = calibration.inv_flat_gain if calibration.inv_flat_gain is not None else 1.0 / calibration.flat_gain
        if tuple(g.shape) != tuple(shape):
            raise CamcalError(f"the frame's planes {tuple(shape)} do not match: the flat model is for {tuple(g.shape)} "
                              f"(another camera, crop or resolution)", path)
        inv = _window_of(g, window)
        signal *= inv
        if var is not None:
            var *= inv
            var *= inv
    if calibration.defects is not None:
        if tuple(calibration.defects.shape) != tuple(shape):
            raise CamcalError(f"the frame's planes {tuple(shape)} do not match the defect map's "
                              f"{tuple(calibration.defects.shape)}", path)
        defective = np.array(_window_of(calibration.defects, window), bool)
    else:
        defective = np.zeros(signal.shape, bool)
    saturated = raw_bad & ~defective
    invalid = raw_bad | defective
    return Corrected(signal, var, invalid, saturated, defective, raw_bad, tuple(channels))


def system_gain_dn_per_e(dark: Any, emva: Any = None) -> np.ndarray | None:
    """(C, 1, 1) float32 system gain K of the noise model at the dark model's ISO, DN/e⁻, or None without a
    dark model.

    Per plane: K from photon transfer (the profile's EMVA 1288 sheet, :class:`camcal.models.emva.EmvaSheet`, scaled
    from its ISO to the dark model's) where known, else the dark model's photon-transfer line of the dark
    signal (``gain_dn_per_e_from_dark``, weak when the dark current is small), else 0 (no shot-noise term).
    """
    if getattr(dark, "read_noise_dn", None) is None or not callable(getattr(dark, "summary", None)):
        return None
    gains = dark.summary().get("gain_dn_per_e_from_dark") or {}
    names = getattr(dark, "plane_names", PLANES)
    k = [float(gains.get(p, 0.0) or 0.0) for p in names]
    if emva is not None:
        scale = float(dark.iso) / float(emva.iso)
        for i, p in enumerate(names):
            g = emva.gain_dn_per_e(p)
            if g is not None and np.isfinite(g) and g > 0:
                k[i] = float(g) * scale
    return np.array(k, np.float32)[:, None, None]


def correct_frame(frame: Frame, calibration: Calibration, *, window: Window | None = None,
                  variance: bool = False) -> Corrected:
    """:func:`correct_planes` on a RAW :class:`camcal.frame.Frame` (its planes, exposure and levels)."""
    planes = frame.planes(np.float32)
    full = planes.shape
    if window is not None:
        planes = np.ascontiguousarray(planes[:, window[0], window[1]])
    return correct_planes(
        planes, calibration, exposure_s=frame.exposure.exposure_s, iso=frame.exposure.iso,
        white_level_dn=float(frame.white_level_dn), black_level_dn=frame.black_vector().ravel(),
        full_shape=full, window=window, variance=variance, channels=frame.channel_names,
        cfa_pattern=frame.cfa_pattern, path=frame.path, inplace=True,
    )


def require_valid(corrected: Corrected, path: Path | None, *, min_valid_fraction: float = 0.5,
                  what: str = "frame", region: str = "") -> None:
    """Refuse a frame only when too few valid pixels are left in some channel; the message says why.

    Raises
    ------
    CamcalError
        Naming the channel, the valid fraction and its cause (saturated outside known defects,
        or known defects).
    """
    valid = corrected.valid_fraction()
    k = int(np.argmin(valid))
    if valid[k] >= min_valid_fraction:
        return
    n = corrected.invalid[k].size
    sat = 100.0 * np.count_nonzero(corrected.saturated[k]) / n
    dfc = 100.0 * np.count_nonzero(corrected.defective[k]) / n
    where = f" of the {region}" if region else ""
    if sat >= dfc:
        why = f"{sat:.3g} %{where} saturated outside known defects; shorten the exposure"
    else:
        why = f"{dfc:.3g} %{where} are known defects (masked)"
    raise CamcalError(f"{what} has only {100 * valid[k]:.3g} % valid pixels in channel {corrected.channels[k]} "
                      f"(need {100 * min_valid_fraction:g} %): {why}", path)

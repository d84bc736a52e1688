"""The response model of seed eq. 12 (per channel, per kind of file), the JPEG colour matrix, and their files.

Fitted by :mod:`camcal.calibrate.response` (exposure series) and
:mod:`camcal.calibrate.colour_matrix` (the colour matrix from JPEG twins of a sweep); applied by
:mod:`camcal.apply.photo`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from camcal.errors import CamcalError
from camcal.frame import PLANES
from camcal.io.store import save_stage


@dataclass(frozen=True)
class ColourMatrix:
    """``j = matrix @ r``: linearised processed (R, G, B) from RAW (R, G, B) DN above the black level.

    Attributes
    ----------
    matrix : (3, 3) float; rows: processed R, G, B; columns: RAW R, G (mean of G1, G2), B.
    matrix_unc : (3, 3) standard uncertainties of the entries (from the fit residuals).
    n_frames : per processed channel, the sweep frames used.
    residual_rms_rel : per processed channel, RMS of (j − A r)/j over the frames used.
    sources : the folders whose twins were used.
    """

    matrix: np.ndarray
    matrix_unc: np.ndarray
    n_frames: tuple[int, int, int]
    residual_rms_rel: tuple[float, float, float]
    sources: tuple[str, ...]

    @property
    def inverse(self) -> np.ndarray:
        return np.linalg.inv(self.matrix)

    def to_raw(self, lin: np.ndarray) -> np.ndarray:
        """(3, ...) linearised processed values -> (3, ...) RAW-equivalent R, G, B (DN above the black level)."""
        inv = self.inverse.astype(np.float32)
        return np.einsum("ij,j...->i...", inv, np.asarray(lin, np.float32)).astype(np.float32)

    def to_dict(self) -> dict:
        return {"matrix": self.matrix.tolist(), "matrix_unc": self.matrix_unc.tolist(),
                "n_frames": list(self.n_frames), "residual_rms_rel": list(self.residual_rms_rel),
                "sources": [Path(f).name for f in self.sources],
                "equation": "linearised processed (R,G,B) = matrix @ RAW (R, (G1+G2)/2, B) DN above the black level"}

    @staticmethod
    def from_dict(d: dict) -> ColourMatrix:
        try:
            m = np.asarray(d["matrix"], float)
            u = np.asarray(d.get("matrix_unc", np.zeros((3, 3))), float)
            if m.shape != (3, 3) or u.shape != (3, 3) or not (np.all(np.isfinite(m)) and np.all(np.isfinite(u))):
                raise ValueError("matrix and matrix_unc must be finite 3x3 arrays")
            if abs(np.linalg.det(m)) < 1e-12 * max(1.0, float(np.abs(m).max())) ** 3:
                raise ValueError("the colour matrix is singular")
            n = tuple(int(v) for v in d.get("n_frames", (0, 0, 0)))
            r = tuple(float(v) for v in d.get("residual_rms_rel", (np.nan,) * 3))
            w = tuple(str(v) for v in d.get("sources", ()))
            if len(n) != 3 or len(r) != 3:
                raise ValueError("n_frames and residual_rms_rel need 3 values")
        except (KeyError, TypeError, ValueError) as exc:
            raise CamcalError(f"malformed colour matrix ({exc})") from None
        return ColourMatrix(m, u, n, r, w)  # type: ignore[arg-type]



RESPONSE_KIND = "response"
"""Stage kind in the JSON written by :func:`save_response`."""


@dataclass(frozen=True)
class ChannelResponse:
    """One channel of seed eq. 12: g = alpha · x**gamma + beta.

    Attributes
    ----------
    alpha, alpha_unc : float
        Gain α and its standard uncertainty, DN s^-γ (x in s at the reference setting).
        For RAW (γ ≈ 1) this is the DN rate, DN s⁻¹.
    gamma, gamma_unc : float
        Exponent γ (dimensionless).
    beta, beta_unc : float
        Offset β in DN: black level + dark signal for RAW without a dark model,
        ≈ 0 after dark subtraction; ≈ 0 (power law) or −0.055·W (sRGB) for JPEG.
    linear_range_dn : (float, float)
        Lowest and highest ROI mean (DN, as fitted) of the points the fit used:
        the range over which eq. 12 describes the channel (unsaturated, uncompressed).
    saturation_dn : float
        Clipping level in DN: the largest ROI value seen when frames saturated,
        else the file's white level.
    linearity_error_pct : float
        EMVA 1288 linearity error of g − β against x, percent (module docstring).
    pearson_r : float
        Pearson correlation of g with x over the fitted points.
    rate_dn_per_s, rate_dn_per_s_unc, offset_dn : float
        RAW only (NaN otherwise): the straight-line fit g = rate·x + offset (γ fixed to 1) over
        the same points. Because x is in seconds (~1e-5 s), α = A·x0^-γ moves by −ln(x0)·Δγ ≈ 10·Δγ
        relative when γ moves, so the DN rate of a linear sensor is this constrained fit's slope,
        not α; :meth:`ResponseModel.linearise` and ``linear_gain_dn_per_s`` use it.
    """

    alpha: float
    alpha_unc: float
    gamma: float
    gamma_unc: float
    beta: float
    beta_unc: float
    linear_range_dn: tuple[float, float]
    saturation_dn: float
    linearity_error_pct: float
    pearson_r: float
    rate_dn_per_s: float = float("nan")
    rate_dn_per_s_unc: float = float("nan")
    offset_dn: float = float("nan")
    saturation_exposure_s: float = float("nan")
    """Relative exposure (s at the reference setting) of the first frame saturated in this channel: where the
    series reached :attr:`saturation_dn`; NaN when no frame saturated
    (:class:`camcal.calibrate.response.Saturation`)."""
    fitted_exposure_s: tuple[float, float] = (float("nan"), float("nan"))
    """Lowest and highest relative exposure (s at the reference setting) of the points the fit used."""

    def predict(self, x_s: np.ndarray | float) -> np.ndarray:
        """g(x) of eq. 12 for relative exposure ``x_s`` (s)."""
        return self.alpha * np.power(np.asarray(x_s, float), self.gamma) + self.beta


@dataclass(frozen=True)
class ResponseModel:
    """The response of every channel of one kind of file.

    Attributes
    ----------
    kind : "raw" or "processed" (JPEG/TIFF/PNG)
    channels : {name: ChannelResponse}; raw: R, G1, G2, B; processed: R, G, B
    reference_iso, reference_f_number : the setting x refers to
    tone : processed only: per channel the fitted sRGB-form transfer function with
        free exponent, the chosen inverse (``"srgb"`` or ``"eq12"``) and the linear
        gain (DN s⁻¹) of the linearised values; None for raw.
    white_level_dn : the files' white level, DN
    dark_subtracted : whether a dark model was subtracted before the fit (raw)
    points : per channel the measured series (x_s, mean_dn, sem_dn, used, saturated, files)
    """

    kind: str
    channels: dict[str, ChannelResponse]
    reference_iso: float
    reference_f_number: float
    tone: dict | None = None
    white_level_dn: float = float("nan")
    dark_subtracted: bool = False
    roi: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 1.0)
    points: dict = field(default_factory=dict)
    colour_matrix: ColourMatrix | None = None
    """Processed only: how the camera mixes RAW R, G, B into the linearised processed channels
    (:mod:`camcal.calibrate.colour_matrix`, fitted from the sweep's JPEG twins); None when not measured."""

    # -- use -----------------------------------------------------------------------------------------------------
    def linear_gain_dn_per_s(self, channel: str) -> float:
        """The constant ratio ``linearise(g) / x`` of a channel, DN s⁻¹ at the reference setting.

        RAW: the slope of the γ = 1 fit (α when absent). Processed: W / x_w, the linear DN rate of the
        de-toned values (W the white level, x_w the exposure reaching white).
        """
        if self.kind == "raw":
            ch = self.channels[channel]
            return float(ch.rate_dn_per_s if math.isfinite(ch.rate_dn_per_s) else ch.alpha)
        return float(self.tone["channels"][channel]["linear_gain_dn_per_s"])  # type: ignore[index]

    def value_scale(self, file_white_dn: float | None) -> float:
        """Processed only: the factor that brings a file's values onto the scale this response was fitted on.

        A processed response is fitted on the calibration's files (8-bit JPEGs: white 255 DN); a photo of
        another bit depth from the same camera (a 10-bit HEIC: white 1023 DN) holds the same tone-encoded
        fraction v/W, so its values are multiplied by W_response / W_file, assuming the camera applies the
        same tone curve at both depths. 1 for RAW, when the white levels agree, or when one is unknown.
        """
        if self.kind != "processed" or file_white_dn is None:
            return 1.0
        w_file, w_resp = float(file_white_dn), float(self.white_level_dn)
        if not (math.isfinite(w_file) and math.isfinite(w_resp)) or w_file <= 0 or w_resp <= 0:
            return 1.0
        ratio = w_resp / w_file
        return 1.0 if abs(ratio - 1.0) < 1e-9 else ratio

    def linearise(self, values: np.ndarray, channel_axis: int = 0, *,
                  white_level_dn: float | None = None) -> np.ndarray:
        """Pixel values -> linear signal proportional to exposure.

        Parameters
        ----------
        values : array with the channels along ``channel_axis`` (4 for raw in R, G1, G2, B order,
            3 for processed in R, G, B order), DN as in the files.
        channel_axis : axis holding the channels.
        white_level_dn : processed only: the white level of the file the values come from, when it may differ
            from the response's (:meth:`value_scale`); None: the values are on the response's scale.

        Returns
        -------
        float64 array of the same shape.
        RAW: ``values − offset`` (DN above the offset of the γ = 1 fit, ≈ β; when the model was fitted
        after dark subtraction, subtract the dark frame first). The RAW γ is a
        diagnostic: the sensor is linear and its value is within 0.5 % of 1.
        Processed: the inverse of the chosen tone curve, in linear DN on the file's
        scale (0…W): ``W · x / x_w``, so that ``result / x`` is the constant
        :meth:`linear_gain_dn_per_s`. Values below the curve's offset map to 0.
        """
        v = np.asarray(values, dtype=np.float64)
        scale = self.value_scale(white_level_dn)
        if scale != 1.0:
            v = v * scale
        names = list(self.channels)
        v = np.moveaxis(v, channel_axis, 0)
        if v.shape[0] != len(names):
            raise CamcalError(
                f"{self.kind} response has {len(names)} channels ({', '.join(names)}); "
                f"values have {v.shape[0]} along axis {channel_axis}"
            )
        out = np.empty_like(v)
        for k, name in enumerate(names):
            ch = self.channels[name]
            if self.kind == "raw":
                out[k] = v[k] - (ch.offset_dn if math.isfinite(ch.offset_dn) else ch.beta)
            else:
                out[k] = _detone(v[k], ch, self.tone["channels"][name], self.white_level_dn)  # type: ignore[index]
        return np.moveaxis(out, 0, channel_axis)

    def saturated_files(self) -> list[str]:
        """Files of the series at or past saturation in any channel: they end the linear range and are not fitted
        (from :attr:`points`; [] when none saturated or the points were not kept)."""
        out: dict[str, None] = {}
        for pts in self.points.values():
            if not isinstance(pts, dict):  # points are diagnostics: a profile may carry none for a channel
                continue
            for name, sat in zip(pts.get("files") or (), pts.get("saturated") or (), strict=False):
                if sat:
                    out[str(name)] = None
        return sorted(out)

    def summary(self) -> dict:
        """JSON-ready summary: per channel α, γ, β with uncertainties, ranges, LE, r; tone fit."""
        chans = {}
        for name, ch in self.channels.items():
            rec = asdict(ch)
            rec["linear_range_dn"] = list(ch.linear_range_dn)
            rec["fitted_exposure_s"] = list(ch.fitted_exposure_s)
            rec["linear_pearson_r_ok"] = bool(ch.pearson_r >= 0.98)
            chans[name] = rec
        out = {
            "kind": self.kind,
            "equation": "g = alpha * x**gamma + beta (seed eq. 12), x = ISO*t/N^2 relative to the reference, s",
            "reference_iso": self.reference_iso,
            "reference_f_number": self.reference_f_number,
            "white_level_dn": self.white_level_dn,
            "dark_subtracted": self.dark_subtracted,
            "channels": chans,
        }
        if self.tone is not None:
            out["tone"] = self.tone
        if self.colour_matrix is not None:
            out["colour_matrix"] = self.colour_matrix.to_dict()
        return out

    def to_dict(self) -> dict:
        """Everything, JSON-ready (see :func:`save_response`)."""
        d = self.summary()
        d["roi"] = list(self.roi)
        d["points"] = self.points
        return d

    @staticmethod
    def from_dict(d: dict) -> ResponseModel:
        """Inverse of :meth:`to_dict`."""

        def num(v) -> float:
            return float("nan") if v is None else float(v)

        try:
            channels = {}
            for name, rec in d["channels"].items():
                channels[name] = ChannelResponse(
                    alpha=num(rec["alpha"]), alpha_unc=num(rec["alpha_unc"]), gamma=num(rec["gamma"]),
                    gamma_unc=num(rec["gamma_unc"]), beta=num(rec["beta"]), beta_unc=num(rec["beta_unc"]),
                    linear_range_dn=(num(rec["linear_range_dn"][0]), num(rec["linear_range_dn"][1])),
                    saturation_dn=num(rec["saturation_dn"]), linearity_error_pct=num(rec["linearity_error_pct"]),
                    pearson_r=num(rec["pearson_r"]), rate_dn_per_s=num(rec.get("rate_dn_per_s")),
                    rate_dn_per_s_unc=num(rec.get("rate_dn_per_s_unc")), offset_dn=num(rec.get("offset_dn")),
                    saturation_exposure_s=num(rec.get("saturation_exposure_s")),
                    fitted_exposure_s=tuple(num(v) for v in rec.get("fitted_exposure_s") or (None, None)),
                )
            expected = {"raw": (set(PLANES), {"R", "G", "B"}, {"Y"}),
                        "processed": ({"R", "G", "B"},)}.get(str(d["kind"]))
            if expected is None or set(channels) not in expected:
                raise ValueError(f"kind {d['kind']!r} with channels {sorted(channels)}; expected raw R, G1, G2, B "
                                 "(or R, G, B for linear RAW, Y for a monochrome sensor) or processed R, G, B")
            return ResponseModel(
                kind=str(d["kind"]), channels=channels, reference_iso=num(d["reference_iso"]),
                reference_f_number=num(d["reference_f_number"]), tone=d.get("tone"),
                white_level_dn=num(d.get("white_level_dn")), dark_subtracted=bool(d.get("dark_subtracted", False)),
                roi=tuple(d.get("roi", (0.0, 1.0, 0.0, 1.0))), points=d.get("points") or {},
                colour_matrix=None if d.get("colour_matrix") is None else ColourMatrix.from_dict(d["colour_matrix"]),
            )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise CamcalError(f"malformed response model ({type(exc).__name__}: {exc})") from None


def save_response(models: dict[str, ResponseModel] | ResponseModel, path: str | Path) -> Path:
    """Write response models as a camcal stage file (kind ``response``, JSON only)."""
    if isinstance(models, ResponseModel):
        models = {models.kind: models}
    return save_stage(path, RESPONSE_KIND, {"models": {k: m.to_dict() for k, m in models.items()}})



SRGB_OFFSET_A = 0.055
"""Offset a of the sRGB transfer-function form (IEC 61966-2-1)."""


def srgb_form_toe(p: float, a: float = SRGB_OFFSET_A) -> tuple[float, float]:
    """Toe of the sRGB form with exponent p: the line V = s·L from the origin tangent to (1 + a) L^p − a.

    Returns (L_b, s): the linear value where the toe meets the curve and its slope.
    For p = 1/2.4 this gives L_b = 0.00304, s = 12.92 (IEC 61966-2-1: 0.0031308, 12.92).
    """
    lb = (a / ((1 + a) * (1 - p))) ** (1 / p) if p < 1 else 0.0
    s = (1 + a) * p * lb ** (p - 1) if lb > 0 else 1.0
    return float(lb), float(s)


def srgb_form_encode(lin: np.ndarray, p: float, a: float = SRGB_OFFSET_A) -> np.ndarray:
    """Linear L (1 at white) -> encoded V with the sRGB form, exponent p."""
    lb, s = srgb_form_toe(p, a)
    lin = np.asarray(lin, float)
    return np.where(lin <= lb, s * lin, (1 + a) * np.power(np.maximum(lin, lb), p) - a)


def srgb_form_decode(v: np.ndarray, p: float, a: float = SRGB_OFFSET_A) -> np.ndarray:
    """Inverse of :func:`srgb_form_encode`; values below 0 map to 0."""
    lb, s = srgb_form_toe(p, a)
    v = np.maximum(np.asarray(v, float), 0.0)
    return np.where(v <= s * lb, v / s, np.power((v + a) / (1 + a), 1.0 / p))


def _detone(v: np.ndarray, ch: ChannelResponse, tone: dict, white_dn: float) -> np.ndarray:
    """Processed value -> linear DN on the 0..W scale (W·x/x_w)."""
    if tone["use"] == "table":  # a monotone table (camcal chart): linear between the knots, held at the ends' slope
        t = tone["table"]
        vk, lk = np.asarray(t["v_dn"], float), np.asarray(t["linear_dn"], float)
        if vk.size < 2 or np.any(np.diff(vk) <= 0) or np.any(np.diff(lk) < 0):
            raise CamcalError("malformed tone table: v_dn must increase and linear_dn must not decrease")
        slope = (lk[-1] - lk[-2]) / (vk[-1] - vk[-2])
        out = np.interp(v, vk, lk)
        return np.where(v > vk[-1], lk[-1] + slope * (v - vk[-1]), np.maximum(out, 0.0))
    if tone["use"] == "srgb":
        return white_dn * srgb_form_decode(v / white_dn, tone["srgb"]["exponent"], tone["srgb"]["offset_a"])
    num = np.maximum(v - ch.beta, 0.0)
    return white_dn * np.power(num / (white_dn - ch.beta), 1.0 / ch.gamma)

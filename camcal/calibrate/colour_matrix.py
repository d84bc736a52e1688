"""The JPEG colour matrix: how a camera mixes its RAW channels into processed R, G, B.

A camera renders a JPEG as ``tone(M · WB · raw)``: white balance (a gain per channel), a 3x3 colour
matrix M that mixes the channels, then a tone curve per channel. :mod:`camcal.calibrate.response` inverts the
tone curve of each processed channel (``linearise``), which leaves ``j = A · r``: the linearised
processed values j are a fixed linear map A of the RAW signals r = (R, (G1 + G2)/2, B) above the
black level (the camera removes its black level, not the dark current), as
long as the white balance and picture style stay fixed. A grey exposure series cannot separate the
columns of A (one chromaticity); a monochromator sweep can: every wavelength is a different
chromaticity. With a JPEG twin of each sweep frame (same exposure, ``<stem>.jpg``), A is fitted by
least squares, one row per processed channel, over the wavelengths where that channel is neither
clipped nor near black.

Applying a profile to a JPEG then takes the RAW-equivalent signal as ``r = A⁻¹ · j`` (see
:mod:`camcal.apply.photo`) instead of one gain per channel — which is only right when M is the identity
(per-channel white balance alone). Without a fitted matrix apply falls back to the per-channel gains
and says so in the notes.

Reference: the camera pipeline model of Ramanath et al. (2005), "Color image processing pipeline",
IEEE Signal Processing Magazine 22(1), 34–43; seed eq. 12 for the per-channel response.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camcal.calibrate.session import StageFrames, folder_of
from camcal.errors import CamcalError
from camcal.io.folders import list_frames
from camcal.io.kinds import is_raw_path
from camcal.io.read import load_frame
from camcal.models.correct import Calibration, correct_frame
from camcal.models.response import ColourMatrix
from camcal.region import DEFAULT_ROI_FRACTION, central_roi

#: A JPEG channel of a sweep frame is used when fewer than this fraction of its ROI pixels are clipped
#: (0 or the white level) ...
MAX_CLIPPED_FRACTION = 0.01
#: ... and its linearised ROI mean is above this fraction of the white level (8-bit quantisation).
MIN_LEVEL_FRACTION = 0.02


def twin_pairs(folder: str | Path | StageFrames) -> list[tuple[Path, Path]]:
    """The RAW frames of ``folder`` (a path, or the session index's :class:`camcal.calibrate.session.StageFrames`) that
    have a processed twin (``<stem>.jpg`` or ``.jpeg``, else ``.heic`` or ``.heif``), sorted by name."""
    pairs = []
    for path in (folder.paths if isinstance(folder, StageFrames) else list_frames(folder)):
        if not is_raw_path(path):
            continue
        for suffix in (".jpg", ".jpeg", ".JPG", ".JPEG", ".heic", ".HEIC", ".heif", ".HEIF"):
            twin = path.with_suffix(suffix)
            if twin.is_file():
                pairs.append((path, twin))
                break
    return pairs


@dataclass(frozen=True)
class TwinMeasurement:
    """The central box of each RAW frame and its processed twin (:func:`measure_colour_matrix`).

    Attributes
    ----------
    raw_rgb_dn : (N, 3) RAW means above the file's black level, DN (the two greens averaged).
    linearised_dn : (N, 3) linearised processed means (``processed.linearise``), DN of the response model.
    usable : (N, 3) bool, neither channel clipped nor too dark.
    where : the first folder (named in errors); sources : every folder (recorded).
    """

    raw_rgb_dn: np.ndarray
    linearised_dn: np.ndarray
    usable: np.ndarray
    where: Path | None = None
    sources: tuple[str, ...] = ()


def measure_colour_matrix(folders: Sequence[str | Path | StageFrames], processed, *,
                          roi_fraction: float = DEFAULT_ROI_FRACTION) -> TwinMeasurement | None:
    """The file step of the colour matrix: every RAW frame of ``folders`` with a processed twin, both decoded once
    and their central box measured (:func:`measure_twins`); None when no folder has twins.

    Parameters
    ----------
    folders : folders holding RAW + JPEG twins of the same exposure: the sweep (many chromaticities,
        but with a negative matrix coefficient a monochromatic line clips the other channels to 0) and
        the linearity series (one broadband chromaticity with every channel well exposed, which pins
        the combination a daylight scene needs). Exposures are not needed: A relates the two files of
        one exposure.
    processed : the processed :class:`camcal.models.response.ResponseModel` (its ``linearise``).
    roi_fraction : central box, fraction of each side.

    Raises
    ------
    CamcalError
        A twin that is not a processed image of the same size.
    """
    pairs = [p for f in folders for p in twin_pairs(f)]
    if not pairs:
        return None
    r, j, ok = measure_twins(pairs, processed, roi_fraction=roi_fraction)
    return TwinMeasurement(r, j, ok, folder_of(folders[0]), tuple(str(folder_of(f)) for f in folders))


def fit_colour_matrix(measured: TwinMeasurement, *, min_frames: int = 6) -> ColourMatrix:
    """The fit of the colour matrix A (module docstring), pure: :func:`colour_matrix_from_twins` of a
    :class:`TwinMeasurement`; ``min_frames``: usable frames each processed channel needs.

    Raises
    ------
    CamcalError
        Too few usable frames, or a singular matrix.
    """
    return colour_matrix_from_twins(measured.raw_rgb_dn, measured.linearised_dn, measured.usable,
                                    min_frames=min_frames, where=measured.where, sources=measured.sources)


def measure_twins(pairs: Sequence[tuple[Path, Path]], processed, *,
                  roi_fraction: float = DEFAULT_ROI_FRACTION) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The file step of the colour matrix: decode each RAW frame and its JPEG twin once and measure the
    central box.

    Returns
    -------
    raw_rgb : (N, 3) RAW means above the file's black level, DN (the two greens averaged).
    jpeg_lin : (N, 3) linearised JPEG means (``processed.linearise``), DN of the response model.
    usable : (N, 3) bool, neither channel clipped nor too dark.
    """
    r_rows, j_rows, ok_rows = [], [], []
    white = float(processed.white_level_dn)
    for path, twin in pairs:
        raw = load_frame(path)
        jpg = load_frame(twin)
        hw = (raw.shape[0] // 2, raw.shape[1] // 2) if raw.layout == "bayer" else raw.shape
        f = jpg.shape[0] // hw[0] if hw[0] else 0  # JPEG pixels per plane pixel: 2 (Bayer), 1 or 2 (linear)
        if jpg.kind == "raw" or f not in (1, 2) or jpg.shape != (f * hw[0], f * hw[1]) or (
                raw.layout == "bayer" and f != 2):
            raise CamcalError(f"is not a processed twin of {path.name} (a JPEG of the same size)", twin)
        x0, y0, x1, y1 = central_roi(hw, roi_fraction)
        # above the file's black level, not the dark model: the camera renders its JPEG from the RAW data
        # minus its black level, dark current included (long sweep exposures: it matters); clipped pixels
        # masked (camcal.models.correct)
        corr = correct_frame(raw, Calibration(), window=(slice(y0, y1), slice(x0, x1)))
        raw_clipped = float(corr.saturated_fraction().max())
        m = dict(zip(raw.channel_names, corr.mean_dn(), strict=True))
        if "G1" in m:
            m["G"] = 0.5 * (m["G1"] + m["G2"])
        r_rows.append([m["R"], m["G"], m["B"]])
        vals = jpg.planes(np.float32)[:, f * y0: f * y1, f * x0: f * x1]
        clipped = np.mean((vals <= 0) | (vals >= jpg.white_level_dn), axis=(1, 2))
        lin = processed.linearise(vals, white_level_dn=jpg.white_level_dn)
        j = np.mean(lin, axis=(1, 2), dtype=np.float64)
        j_rows.append(j)
        ok_rows.append((clipped < MAX_CLIPPED_FRACTION) & (j > MIN_LEVEL_FRACTION * white)
                       & (raw_clipped < MAX_CLIPPED_FRACTION))
    return np.asarray(r_rows), np.asarray(j_rows), np.asarray(ok_rows)


def colour_matrix_from_twins(r: np.ndarray, j: np.ndarray, ok: np.ndarray, *, min_frames: int = 6,
                             where: str | Path | None = None, sources: tuple[str, ...] = ()) -> ColourMatrix:
    """Fit the colour matrix A (module docstring) to twin measurements (:func:`measure_twins`); pure.

    Each processed channel is a weighted least-squares combination of the RAW R, G, B means over its usable
    frames (relative residuals); ``where`` names the folder in errors, ``sources`` are recorded.
    """
    matrix = np.empty((3, 3))
    unc = np.empty((3, 3))
    n_used, rms = [], []
    for i, name in enumerate(("R", "G", "B")):
        use = ok[:, i]
        n = int(use.sum())
        if n < max(min_frames, 4):
            raise CamcalError(f"only {n} sweep frames have a usable JPEG {name} channel (neither clipped nor "
                              f"below {100 * MIN_LEVEL_FRACTION:g} % of white); the colour matrix needs "
                              f"{max(min_frames, 4)}", where)
        x, y = r[use], j[use, i]
        w = 1.0 / np.maximum(np.abs(y), 1e-12)  # relative residuals: every wavelength counts alike
        xw, yw = x * w[:, None], y * w
        coef, *_ = np.linalg.lstsq(xw, yw, rcond=None)
        res = yw - xw @ coef
        dof = max(n - 3, 1)
        s2 = float(res @ res) / dof
        cov = s2 * np.linalg.pinv(xw.T @ xw)
        matrix[i], unc[i] = coef, np.sqrt(np.maximum(np.diag(cov), 0))
        n_used.append(n)
        rms.append(float(np.sqrt(np.mean(res**2))))
    if abs(np.linalg.det(matrix)) < 1e-12 * float(np.abs(matrix).max()) ** 3:
        raise CamcalError("the fitted colour matrix is singular (the JPEG twins hold too few colours)", where)
    return ColourMatrix(matrix, unc, tuple(n_used), tuple(rms), sources)  # type: ignore[arg-type]

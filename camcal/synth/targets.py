"""Synthetic reference targets: photos of known smooth spectra, with their spectrum files and targets.csv.

A target fills the frame with one smooth spectral radiance L(λ) (W m⁻² sr⁻¹ nm⁻¹); the synthetic
camera (:class:`camcal.synth.camera.SyntheticCamera`) photographs it with all its noise (shot, read,
dark current, PRNU, vignetting), so a photo's corrected DN rate on axis is ∫ c_i L dλ with the camera's
true c_i (seed §3.1). The spectrum file is what a spectroradiometer would report, written exactly
(``stated_unc_rel`` goes into ``targets.csv`` as ``scale_unc_rel``).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from camcal.io.atomic import atomic_write_text
from camcal.models.spectra import WAVELENGTHS_NM, planck_radiance
from camcal.synth.camera import Scene, SyntheticCamera, frame_rngs
from camcal.synth.session import exposure_for_level


def smooth_target_spectra(level_w_m2_sr_nm: float = 0.05) -> dict[str, np.ndarray]:
    """Three smooth spectra of different colour on :data:`WAVELENGTHS_NM`, W m⁻² sr⁻¹ nm⁻¹.

    ``lamp_2856K``: a tungsten lamp (Planck, CIE illuminant A temperature), reddish;
    ``sky_9000K``: a bluish black body (a daylight-lit port); ``green_filtered``: a 4000 K lamp through a
    broad green-blue filter (transmittance 0.15 + 0.85·exp(−((λ−510)/70)²)). Each is scaled to
    ``level_w_m2_sr_nm`` at 555 nm.
    """
    wl = WAVELENGTHS_NM

    def at555(s: np.ndarray) -> np.ndarray:
        return level_w_m2_sr_nm * s / np.interp(555.0, wl, s)

    filt = 0.15 + 0.85 * np.exp(-(((wl - 510.0) / 70.0) ** 2))
    return {"lamp_2856K": at555(planck_radiance(2856.0)), "sky_9000K": at555(planck_radiance(9000.0)),
            "green_filtered": at555(planck_radiance(4000.0) * filt)}


def grey_card_reflectance() -> np.ndarray:
    """A smooth, slightly rising grey-card reflectance on :data:`WAVELENGTHS_NM` (0.17 at 380 nm, 0.19 at 780 nm)."""
    return 0.17 + 0.02 * (WAVELENGTHS_NM - WAVELENGTHS_NM[0]) / (WAVELENGTHS_NM[-1] - WAVELENGTHS_NM[0])


def _table(header: list[str], cols: list[np.ndarray]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for row in np.column_stack(cols):
        w.writerow([f"{row[0]:g}", *(repr(float(v)) for v in row[1:])])
    return buf.getvalue()


def write_target_photos(
    folder: str | Path,
    camera: SyntheticCamera,
    spectra: dict[str, np.ndarray],
    *,
    n_photos: int = 1,
    level: float = 0.4,
    iso: float | None = None,
    f_number: float | None = None,
    stated_unc_rel: float = 0.002,
    seed: int = 18,
    reflectance: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
    layout: str = "bayer",
) -> Path:
    """Photograph each target (real DNGs) and write its spectrum file and ``targets.csv``; returns the CSV.

    Parameters
    ----------
    spectra : name -> spectral radiance on :data:`WAVELENGTHS_NM` (a spectroradiometer-read target):
        written as ``<name>.csv`` with columns ``wavelength_nm,radiance_W_m2_sr_nm``.
    reflectance : name -> (reflectance ρ, irradiance E in W m⁻² nm⁻¹) on :data:`WAVELENGTHS_NM`: a
        Lambertian standard (L = ρE/π), written as ``<name>_reflectance.csv`` and ``<name>_irradiance.csv``.
    n_photos : photos per target.
    level : brightest channel's level on axis, fraction of full scale.
    stated_unc_rel : the relative uncertainty the "spectroradiometer" states (column ``scale_unc_rel``).
    layout : ``"bayer"`` (CFA DNGs) or ``"linear"`` (LinearRaw DNGs of R, G1, B: a linear-RAW camera).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    p = camera.params
    iso = p.iso_base if iso is None else iso
    n = p.reference_f_number if f_number is None else f_number
    items: list[tuple[str, np.ndarray, dict[str, str]]] = []
    for name, spec in spectra.items():
        atomic_write_text(folder / f"{name}.csv", _table(["wavelength_nm", "radiance_W_m2_sr_nm"],
                                                           [WAVELENGTHS_NM, np.asarray(spec, float)]))
        items.append((name, np.asarray(spec, float), {"radiance": f"{name}.csv"}))
    for name, (rho, irr) in (reflectance or {}).items():
        atomic_write_text(folder / f"{name}_reflectance.csv", _table(["wavelength_nm", "reflectance"],
                                                                      [WAVELENGTHS_NM, rho]))
        atomic_write_text(folder / f"{name}_irradiance.csv", _table(["wavelength_nm", "irradiance_W_m2_nm"],
                                                                     [WAVELENGTHS_NM, irr]))
        items.append((name, np.asarray(rho, float) * np.asarray(irr, float) / np.pi,
                      {"reflectance": f"{name}_reflectance.csv", "irradiance": f"{name}_irradiance.csv"}))
    rngs = iter(frame_rngs(seed, n_photos * len(items), 18))
    rows = []
    for name, radiance, files in items:
        t = float(f"{exposure_for_level(camera, radiance, level, iso, n):.4g}")
        for k in range(n_photos):
            photo = f"{name}_{k:02d}.dng"
            camera.write_dng(folder / photo, Scene.uniform(radiance), exposure_s=t, iso=iso, f_number=n,
                             rng=next(rngs), layout=layout)
            rows.append({"file": photo, "target": name, "radiance": files.get("radiance", ""),
                         "reflectance": files.get("reflectance", ""), "irradiance": files.get("irradiance", ""),
                         "scale_unc_rel": stated_unc_rel})
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return atomic_write_text(folder / "targets.csv", buf.getvalue())

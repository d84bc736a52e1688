"""The EMVA 1288 summary sheet of a calibration (the ``emva1288`` section of a profile) and its rows.

Built by :func:`camcal.calibrate.emva.build_sheet`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from camcal.units import DN, DN_PER_ELECTRON, DN_PER_S, ELECTRONS, ELECTRONS_PER_DN, ELECTRONS_PER_S

STANDARD = "EMVA 1288 release 4.0 (Linear)"


#: Per-channel keys every sheet has (null when not measurable from the session's frames).
SHEET_KEYS = ("K_dn_per_e", "read_noise_dn", "dsnu_dn", "prnu_pct", "saturation_dn", "saturation_e", "snr_max",
              "dynamic_range_db", "linearity_error_pct")


@dataclass(frozen=True)
class EmvaSheet:
    """EMVA 1288 summary of one camera at the dark model's ISO (the ``emva1288`` section of a profile).

    Attributes
    ----------
    iso : ISO of the figures (that of the dark frames); None when unknown (a descriptor's measurement).
    channels : per plane, the figures (:data:`SHEET_KEYS` and more: uncertainties, electrons, sources), numbers or
        None when the session lacks the frames to measure them.
    photon_transfer : per ISO of the linearity series, per plane: K, its uncertainty and the fit range.
    spatial : how the spatial figures were measured (exposure, frames, noise left in the flat map).
    quantum_efficiency : ``{"pixel_pitch_um", "wavelength_nm", "values": {plane: [...]}}`` or None.
    notes : what is missing and why, which fallback was used.
    """

    iso: float | None
    channels: dict[str, dict]
    photon_transfer: tuple[dict, ...] = ()
    spatial: dict = field(default_factory=dict)
    quantum_efficiency: dict | None = None
    notes: tuple[str, ...] = ()

    def gain_dn_per_e(self, channel: str) -> float | None:
        """K of ``channel`` at :attr:`iso`, DN/e⁻, or None."""
        return (self.channels.get(channel) or {}).get("K_dn_per_e")

    def to_dict(self) -> dict:
        return {"standard": STANDARD, "iso": None if self.iso is None else float(self.iso), "channels": self.channels,
                "photon_transfer": list(self.photon_transfer), "spatial": self.spatial,
                "quantum_efficiency": self.quantum_efficiency, "notes": list(self.notes)}

    @staticmethod
    def from_dict(d: dict) -> EmvaSheet:
        iso = d.get("iso")
        return EmvaSheet(iso=None if iso is None else float(iso),
                         channels={c: dict(v) for c, v in d["channels"].items()},
                         photon_transfer=tuple(d.get("photon_transfer") or ()), spatial=dict(d.get("spatial") or {}),
                         quantum_efficiency=d.get("quantum_efficiency"), notes=tuple(d.get("notes") or ()))


def sheet_rows(sheet: EmvaSheet) -> list[tuple[str, str, str, dict[str, float | None]]]:
    """The rows of an EMVA 1288 summary sheet, in the standard's order: (section, quantity, unit, per plane).

    Used by ``camcal profile show --emva`` and the HTML report; values are None where unknown.
    """
    ch = sheet.channels

    def col(key: str, scale: float = 1.0) -> dict[str, float | None]:
        return {c: (None if v.get(key) is None else float(v[key]) * scale) for c, v in ch.items()}

    def inv(key: str) -> dict[str, float | None]:
        return {c: (None if not v.get(key) else 1.0 / float(v[key])) for c, v in ch.items()}

    rows = [
        ("sensitivity", "overall system gain K", DN_PER_ELECTRON, col("K_dn_per_e")),
        ("sensitivity", "uncertainty of K", DN_PER_ELECTRON, col("K_unc_dn_per_e")),
        ("sensitivity", "1/K", ELECTRONS_PER_DN, inv("K_dn_per_e")),
        ("sensitivity", "temporal dark noise σ_y.dark", DN, col("dark_noise_dn")),
        ("sensitivity", "read noise σ_d·K (quantisation removed)", DN, col("read_noise_dn")),
        ("sensitivity", "read noise σ_d", ELECTRONS, col("read_noise_e")),
        ("sensitivity", "camcal: read noise, quantised-normal fit (not EMVA 1288)", DN, col("read_noise_quantised_dn")),
        ("sensitivity", "absolute sensitivity threshold μ_e.min", ELECTRONS, col("threshold_e")),
        ("sensitivity", "saturation capacity μ_y.sat", DN, col("saturation_dn")),
        ("sensitivity", "saturation capacity μ_e.sat", ELECTRONS, col("saturation_e")),
        ("sensitivity", "SNR_max", "", col("snr_max")),
        ("sensitivity", "SNR_max", "dB", col("snr_max_db")),
        ("sensitivity", "dynamic range DR", "dB", col("dynamic_range_db")),
        ("linearity", "linearity error LE", "%", col("linearity_error_pct")),
        ("linearity", "LE min", "%", col("linearity_error_min_pct")),
        ("linearity", "LE max", "%", col("linearity_error_max_pct")),
        ("dark current", "dark current", DN_PER_S, col("dark_current_dn_per_s")),
        ("dark current", "dark current", ELECTRONS_PER_S, col("dark_current_e_per_s")),
        ("nonuniformity", "DSNU_1288", DN, col("dsnu_dn")),
        ("nonuniformity", "uncertainty of DSNU", DN, col("dsnu_unc_dn")),
        ("nonuniformity", "DSNU_1288", ELECTRONS, col("dsnu_e")),
        ("nonuniformity", "PRNU_1288 (total)", "%", col("prnu_pct")),
        ("nonuniformity", "uncertainty of PRNU_1288", "%", col("prnu_unc_pct")),
        ("nonuniformity", "PRNU_1288, row part", "%", col("prnu_row_pct")),
        ("nonuniformity", "PRNU_1288, column part", "%", col("prnu_col_pct")),
        ("nonuniformity", "PRNU_1288, pixel part", "%", col("prnu_pixel_pct")),
        ("nonuniformity", "camcal: PRNU about the vignetting model (not EMVA 1288)", "%", col("prnu_devignetted_pct")),
        ("nonuniformity", "uncertainty of camcal's PRNU", "%", col("prnu_devignetted_unc_pct")),
        ("nonuniformity", "noise left in the flat map", "%", col("flat_map_noise_pct")),
        ("nonuniformity", "flats for map noise < PRNU", "frames", col("flats_for_noise_below_prnu")),
    ]
    return rows

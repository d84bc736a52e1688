"""The calibration profile: every stage of one camera's calibration in one validated file.

A profile file (``.camcal``) is a ZIP container (:mod:`camcal.io.container`) with
``profile.json`` — human-readable, validated against
``camcal/schemas/profile-1.schema.json`` on every load — and ``maps.exr`` with
the per-pixel maps (dark: ``dark.bias.R`` ...; flat: ``flat.gain.R`` ...).
Content and maps are protected by SHA-256 hashes; loading refuses unknown
major schema versions, corrupted files and hash mismatches. The format is
documented in ``docs/profile-format.md``.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np

from camcal import __version__
from camcal.errors import CamcalError
from camcal.frame import PLANES, RGB
from camcal.io.container import read_container, write_container
from camcal.io.store import to_jsonable
from camcal.models.dark import DarkModel, dark_from_parts, dark_to_parts
from camcal.models.emva import SHEET_KEYS, EmvaSheet
from camcal.models.flat import FlatModel, flat_from_parts, flat_to_parts
from camcal.models.response import ResponseModel
from camcal.models.spectral import SpectralSensitivity, float_or_none, spectral_from_dict, spectral_to_dict

FORMAT = "camcal-profile"
SCHEMA_VERSION = "1.9"  # 1.1: optional response.processed.colour_matrix; 1.2: optional spectral_sensitivity.source;
# 1.3: camera.layout, dark.layout, dark.dark_current_known, dark channels temporal_noise_dn, R, G, B planes (linear RAW)
# 1.4: optional emva1288 section (EMVA 1288 summary: K from photon transfer, DSNU, PRNU, saturation, SNR, DR, LE)
# 1.5: provenance.left_out and provenance.not_calibrated; reference iso / f_number may be null (no stage
# normalised exposure); response channels saturation_exposure_s and fitted_exposure_s
# 1.6: spectral_sensitivity.source kinds "library" and "sweep_means" and source.library (the curve-library entry)
# 1.7: flat.optics (the flats' f-number and focal length with their sources) and flat.apertures (models fitted at
# other f-numbers); a 1.6 profile loads with the flats' optics unknown
# 1.8: spectral_sensitivity.reference_iso / reference_f_number may be null (relative curves of unknown setting)
# 1.9: spectral_sensitivity.source kind "chart" (camcal chart: c(λ) from a colour chart) with its chart, light,
# basis, photos and processed records; absolute_scale method "chart"
SUPPORTED_MAJOR = 1


@dataclass(frozen=True)
class CameraIdentity:
    """Which camera a profile belongs to. Width and height are full-resolution pixels."""

    make: str | None
    model: str | None
    serial: str | None
    cfa_pattern: str | None
    width: int
    height: int
    layout: str = "bayer"
    """``"bayer"`` (CFA mosaic), ``"linear"`` (linear multi-channel RAW) or ``"processed"``: the frames the
    profile was measured on; it is applied only to photos of the same layout."""


@dataclass(frozen=True)
class Provenance:
    """Where a profile came from: camcal version, UTC creation time, input files with SHA-256, options."""

    camcal_version: str
    created_utc: str
    inputs: tuple[dict, ...] = ()
    options: dict = field(default_factory=dict)
    left_out: tuple[dict, ...] = ()
    """Frames the calibration did not use: ``{"file": "stage/name", "stage", "reason"}``
    (:mod:`camcal.calibrate.screen`)."""
    not_calibrated: tuple[dict, ...] = ()
    """Stages present in the session but not calibrated: ``{"stage", "reason"}`` (too few usable frames)."""


@dataclass(frozen=True, eq=False)
class CalibrationProfile:
    """One camera's calibration.

    Attributes
    ----------
    camera : CameraIdentity
    reference_iso, reference_f_number : float or None
        The reference setting every DN rate is normalised to (seed §2.1); None when unknown and no stage
        normalised exposure (a bias/dark/flat-only profile: apply then refuses it).
    dark : camcal.models.dark.DarkModel or None
    flat : camcal.models.flat.FlatModel or None
    response : dict of camcal.models.response.ResponseModel, keyed ``raw`` / ``processed``, or None
    spectral : camcal.models.spectral.SpectralSensitivity or None
        Absolute c(λ) in DN s⁻¹ per (W m⁻² sr⁻¹ nm⁻¹) per nm at the reference setting, on axis.
    emva : camcal.models.emva.EmvaSheet or None
        The EMVA 1288 summary (system gain K from photon transfer, DSNU, PRNU, saturation, SNR_max, dynamic
        range, linearity error); the noise model uses its K (:meth:`camcal.models.correct.Calibration.of`).
    provenance : Provenance
    schema_version : str
    content_sha256 : str or None
        The integrity hash of the file it was loaded from or saved to.
    """

    camera: CameraIdentity
    reference_iso: float | None
    reference_f_number: float | None
    dark: DarkModel | None = None
    flat: FlatModel | None = None
    response: dict[str, ResponseModel] | None = None
    spectral: SpectralSensitivity | None = None
    emva: EmvaSheet | None = None
    provenance: Provenance = field(default_factory=lambda: Provenance(__version__, ""))
    schema_version: str = SCHEMA_VERSION
    content_sha256: str | None = None

    def stages(self) -> dict[str, bool]:
        return {"dark": self.dark is not None, "flat": self.flat is not None,
                "response": bool(self.response), "spectral_sensitivity": self.spectral is not None}


# ---- stage codecs: model <-> (JSON part, maps) ------------------------------------------------------------
def _stage_to_parts(name: str, model) -> tuple[dict, dict[str, np.ndarray]]:
    if name == "dark":
        return dark_to_parts(model)
    if name == "flat":
        return flat_to_parts(model)
    if name == "response":
        return {k: m.to_dict() for k, m in model.items()}, {}
    if name == "spectral_sensitivity":
        return spectral_to_dict(model), {}
    raise ValueError(name)


def _stage_from_parts(name: str, data: dict, maps: dict[str, np.ndarray], where: Path):
    try:
        if name == "dark":
            return dark_from_parts(data, maps, where)
        if name == "flat":
            return flat_from_parts(data, maps, where)
        if name == "response":
            return {k: ResponseModel.from_dict(v) for k, v in data.items()}
        if name == "spectral_sensitivity":
            return spectral_from_dict(data)
    except CamcalError as exc:
        raise CamcalError(f"{name} section: {exc.message}", where) from None
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:  # schema-valid but undecodable
        raise CamcalError(f"{name} section is malformed ({type(exc).__name__}: {exc})", where) from None
    raise ValueError(name)


_STAGE_ATTR = {"dark": "dark", "flat": "flat", "response": "response", "spectral_sensitivity": "spectral"}


def profile_to_document(profile: CalibrationProfile) -> tuple[dict, dict[str, np.ndarray]]:
    """The JSON document (without integrity) and the prefixed maps of a profile."""
    doc: dict[str, Any] = {
        "format": FORMAT,
        "schema_version": profile.schema_version,
        "camera": dataclasses.asdict(profile.camera),
        "reference": {"iso": float_or_none(profile.reference_iso),
                      "f_number": float_or_none(profile.reference_f_number)},
    }
    maps: dict[str, np.ndarray] = {}
    names: dict[str, list[str]] = {}
    for key, attr in _STAGE_ATTR.items():
        model = getattr(profile, attr)
        if model is None or (key == "response" and not model):
            doc[key] = None
            continue
        data, stage_maps = _stage_to_parts(key, model)
        doc[key] = to_jsonable(data)
        if stage_maps:
            names[key] = [f"{key}.{m}" for m in stage_maps]
            maps.update({f"{key}.{m}": np.asarray(a, np.float32) for m, a in stage_maps.items()})
    doc["emva1288"] = None if profile.emva is None else to_jsonable(profile.emva.to_dict())
    p = profile.provenance
    prov = {"camcal_version": p.camcal_version, "created_utc": p.created_utc, "inputs": list(p.inputs),
            "options": p.options}
    if p.left_out:
        prov["left_out"] = [dict(r) for r in p.left_out]
    if p.not_calibrated:
        prov["not_calibrated"] = [dict(r) for r in p.not_calibrated]
    doc["provenance"] = to_jsonable(prov)
    doc["maps"] = names
    return doc, maps


@functools.lru_cache(maxsize=1)
def _schema() -> dict:
    """The JSON Schema of major version 1 (strict inside every section: see its ``$comment``)."""
    text = resources.files("camcal").joinpath("schemas/profile-1.schema.json").read_text(encoding="utf-8")
    return json.loads(text)


def _minor(version: object) -> int:
    """The minor number of a ``MAJOR.MINOR`` version; -1 when it has none."""
    parts = str(version).split(".")
    return int(parts[1]) if len(parts) == 2 and parts[1].isdigit() else -1


def check_version(doc: dict, where: str | Path) -> None:
    """Refuse documents that are not camcal profiles or have an unknown major schema version."""
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise CamcalError("not a camcal profile (format marker missing)", where)
    version = doc.get("schema_version")
    if not isinstance(version, str) or not version.split(".")[0].isdigit():
        raise CamcalError(f"profile has an invalid schema_version {version!r}", where)
    major = int(version.split(".")[0])
    if major != SUPPORTED_MAJOR:
        raise CamcalError(
            f"profile schema version {version} is not supported (this camcal {__version__} reads {SUPPORTED_MAJOR}.x); "
            "use a matching camcal version", where)


def validate_document(doc: dict, where: str | Path) -> None:
    """Validate ``doc`` against the JSON Schema; one line naming the first offending field."""
    check_version(doc, where)
    validator = jsonschema.Draft202012Validator(_schema())
    errors = sorted(validator.iter_errors(doc), key=lambda e: [str(p) for p in e.absolute_path])
    if errors:
        err = errors[0]
        while err.validator == "oneOf" and err.context:  # the branch that nearly fits (e.g. Bayer or linear planes)
            branches: dict[int, list] = {}
            for sub in err.context:
                branches.setdefault(int(sub.schema_path[0]), []).append(sub)
            err = min(branches.values(), key=len)[0]
        loc = "/".join(str(p) for p in err.absolute_path)
        unknown: list[str] = []
        if err.validator == "additionalProperties" and isinstance(err.instance, dict):
            known = set(err.schema.get("properties", {}))
            unknown = sorted(str(k) for k in err.instance if k not in known)
        elif "propertyNames" in err.schema_path:  # a per-channel object with a key that is not a channel
            unknown = [str(err.instance)]
        if unknown:
            keys = ", ".join(f"{loc + '/' if loc else ''}{k}" for k in unknown[:3])
            version = doc.get("schema_version")
            why = (f"schema {version} is newer than this camcal {__version__} reads ({SCHEMA_VERSION}); "
                   "use a newer camcal" if _minor(version) > _minor(SCHEMA_VERSION) else
                   f"schema {version} has only the keys of docs/profile-format.md")
            raise CamcalError(f"profile has unknown key{'s' if len(unknown) > 1 else ''} {keys} ({why})", where)
        raise CamcalError(f"profile does not follow the schema at {loc or '(top level)'}: "
                          f"{' '.join(err.message.split())[:160]}", where)
    spec = doc.get("spectral_sensitivity")
    if spec:
        n = len(spec["wavelength_nm"])
        for part in ("values", "uncertainty"):
            for plane in (PLANES if "G1" in spec[part] else ("Y",) if "Y" in spec[part] else RGB):
                if len(spec[part][plane]) != n:
                    raise CamcalError(f"spectral_sensitivity.{part}.{plane} has {len(spec[part][plane])} values, "
                                      f"wavelength_nm has {n}", where)


def profile_from_document(doc: dict, maps: dict[str, np.ndarray], where: str | Path, *,
                          skip_map_stages: bool = False) -> CalibrationProfile:
    """Rebuild a profile from a validated document and its maps (``skip_map_stages``: stages with maps → None)."""
    where = Path(where)
    validate_document(doc, where)
    stages: dict[str, Any] = {}
    for key, attr in _STAGE_ATTR.items():
        data = doc[key]
        if data is None:
            stages[attr] = None
            continue
        wanted = doc["maps"].get(key, [])
        if wanted and skip_map_stages:
            stages[attr] = None
            continue
        missing = [m for m in wanted if m not in maps]
        if missing:
            raise CamcalError(f"profile lacks maps {missing[:3]}", where)
        stage_maps = {m[len(key) + 1:]: maps[m] for m in wanted}
        stages[attr] = _stage_from_parts(key, data, stage_maps, where)
    cam = doc["camera"]
    prov = doc["provenance"]
    emva = None
    if doc.get("emva1288"):
        try:
            emva = EmvaSheet.from_dict(doc["emva1288"])
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise CamcalError(f"emva1288 section is malformed ({type(exc).__name__}: {exc})", where) from None
    return CalibrationProfile(
        camera=CameraIdentity(cam["make"], cam["model"], cam["serial"], cam["cfa_pattern"], int(cam["width"]),
                              int(cam["height"]), str(cam.get("layout") or "bayer")),
        reference_iso=float_or_none(doc["reference"]["iso"]),
        reference_f_number=float_or_none(doc["reference"]["f_number"]),
        provenance=Provenance(prov["camcal_version"], prov["created_utc"], tuple(prov["inputs"]),
                              dict(prov["options"]), tuple(prov.get("left_out", ())),
                              tuple(prov.get("not_calibrated", ()))),
        schema_version=doc["schema_version"],
        content_sha256=doc.get("integrity", {}).get("content_sha256"),
        emva=emva,
        **stages,
    )


def save_profile(profile: CalibrationProfile, path: str | Path) -> CalibrationProfile:
    """Write ``profile`` to ``path`` (atomically); returns it with ``content_sha256`` set.

    The document is validated against the schema before anything is written; the written file is read back
    and both of its hashes verified (the maps are not decoded again: they were encoded from arrays in hand).
    """
    doc, maps = profile_to_document(profile)
    validate_document({**doc, "integrity": {"algorithm": "sha256", "content_sha256": "0" * 64,
                                            "maps_sha256": None}}, path)
    write_container(path, doc, maps)
    written, _ = read_container(path, decode_maps=False)
    return dataclasses.replace(profile, content_sha256=written["integrity"]["content_sha256"])


def load_profile(path: str | Path, *, with_maps: bool = True) -> CalibrationProfile:
    """Read, verify (hashes, schema, version) and rebuild a profile.

    ``with_maps=False`` verifies everything the same way but does not decode the per-pixel maps; the
    stages that hold maps (dark, flat) are then None. A batch runner uses it to check the camera and
    the options before sending the work to processes that each load the whole profile.
    """
    doc, maps = read_container(path, decode_maps=with_maps)
    return profile_from_document(doc, maps, path, skip_map_stages=not with_maps)


# ---- the JSON contract -------------------------------------------------------------------------------------
def _rgb(per_plane: dict | None) -> dict | None:
    """{R, G1, G2, B} -> {R, G, B, G1, G2} with G the mean of G1 and G2 ({Y} of a monochrome sensor as it is)."""
    if not per_plane:
        return None
    if set(per_plane) == {"Y"}:  # a monochrome sensor: its one channel
        return {"Y": per_plane["Y"]}
    if "G1" not in per_plane:  # linear RAW: R, G, B planes
        return {"R": per_plane.get("R"), "G": per_plane.get("G"), "B": per_plane.get("B"), "G1": None, "G2": None}
    out = {"R": per_plane.get("R"), "B": per_plane.get("B"), "G1": per_plane.get("G1"), "G2": per_plane.get("G2")}
    g1, g2 = per_plane.get("G1"), per_plane.get("G2")
    out["G"] = None if g1 is None or g2 is None else 0.5 * (float(g1) + float(g2))
    return {k: out[k] for k in ("R", "G", "B", "G1", "G2")}


def _finite(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x


def flats_optics_text(flat: dict) -> str:
    """The flats' f-numbers and focal length of a contract's ``flat`` object, each with its source:
    ``f/2.8 (frames.csv), f/8 (frames.csv); 35 mm (tag); one vignetting model per f-number``."""
    parts = []
    for a in flat.get("apertures") or [{"optics": flat.get("optics") or {}}]:
        o = a["optics"]
        parts.append("an unknown f-number" if o.get("f_number") is None
                     else f"f/{o['f_number']:g} ({o['f_number_source']})")
    o = flat.get("optics") or {}
    focal = ("focal length unknown" if o.get("focal_length_mm") is None
             else f"{o['focal_length_mm']:g} mm ({o['focal_length_source']})")
    many = "; one vignetting model per f-number (apply picks the photo's)" if len(parts) > 1 else ""
    return f"{', '.join(parts)}; {focal}{many}"


def contract(profile: CalibrationProfile) -> dict:
    """The stable JSON object of ``camcal profile show --json`` (see docs/profile-format.md).

    A stage that was not calibrated is ``null``. G is the mean of G1 and G2.
    """
    out: dict[str, Any] = {
        "schema_version": profile.schema_version,
        "content_sha256": profile.content_sha256,
        "camera": dataclasses.asdict(profile.camera),
        "reference": {"iso": profile.reference_iso, "f_number": profile.reference_f_number},
    }
    if profile.dark is not None:
        s = profile.dark.summary()
        out["dark"] = {
            "iso": s["iso"],
            "temperature_c": s.get("temperature_c"),
            "bias_dn": _rgb(s.get("bias_dn")),
            "dark_current_dn_per_s": _rgb(s.get("dark_current_dn_per_s")),
            "dark_current_unc_dn_per_s": _rgb(s.get("dark_current_unc_dn_per_s")),
            "read_noise_dn": _rgb(s.get("read_noise_dn")),
            "temporal_noise_dn": _rgb(s.get("temporal_noise_dn")),
            "dark_current_known": profile.dark.dark_current_dn_per_s is not None,
            "dsnu_bias_dn": _rgb(s.get("dsnu_bias_dn")),
            "dsnu_dark_current_dn_per_s": _rgb(s.get("dsnu_dark_current_dn_per_s")),
            "hot_pixel_count": s["hot_pixel_count"],
            "dead_pixel_count": s.get("dead_pixel_count"),
            "noisy_pixel_count": s.get("noisy_pixel_count"),
        }
    else:
        out["dark"] = None
    if profile.flat is not None:
        s = profile.flat.summary()
        out["flat"] = {"model": s["model"], "centre_full_px": s["centre_full_px"],
                       "corner_gain": _rgb(s["corner_gain"]), "residual_rms": _rgb(s["residual_rms"]),
                       "prnu_rms": _rgb(s.get("prnu_rms")), "optics": s["optics"],
                       "f_numbers": profile.flat.f_numbers(),
                       "apertures": [{"optics": m.optics.to_dict(), "model": m.kind,
                                      "corner_gain": _rgb(m.corner_gain())} for m in profile.flat.models()]}
    else:
        out["flat"] = None
    if profile.response:
        primary = profile.response.get("raw") or next(iter(profile.response.values()))

        def per(model, attr):
            ch = model.channels
            if "G1" in ch:
                return _rgb({p: _finite(getattr(ch[p], attr)) for p in PLANES})
            return {c: _finite(getattr(ch[c], attr)) for c in (("Y",) if "Y" in ch else ("R", "G", "B"))}

        out["response"] = {"kind": primary.kind, "gamma": per(primary, "gamma"), "alpha": per(primary, "alpha"),
                           "beta": per(primary, "beta"),
                           "models": {k: {"gamma": per(m, "gamma"), "alpha": per(m, "alpha"), "beta": per(m, "beta"),
                                          "linearity_error_pct": per(m, "linearity_error_pct"),
                                          "saturation_dn": per(m, "saturation_dn"),
                                          "saturation_exposure_s": per(m, "saturation_exposure_s"),
                                          "fitted_range_dn": {c: [_finite(v) for v in ch.linear_range_dn]
                                                              for c, ch in m.channels.items()},
                                          "fitted_exposure_s": {c: [_finite(v) for v in ch.fitted_exposure_s]
                                                                for c, ch in m.channels.items()},
                                          "saturated_files": m.saturated_files()}
                                      for k, m in profile.response.items()}}
    else:
        out["response"] = None
    if profile.spectral is not None:
        s = profile.spectral
        rgb, unc = s.rgb(), s.rgb_uncertainty()
        out["spectral_sensitivity"] = {
            "wavelength_nm": [float(v) for v in s.wavelength_nm],
            **{c: [float(v) for v in rgb[c]] for c in rgb},  # R, G, B; Y for a monochrome sensor
            **{f"{c}_unc": [float(v) for v in unc[c]] for c in rgb},
            "units": s.units,
            "mode": s.mode,
            "peak_wavelength_nm": s.peak_wavelength_nm(),
            "effective_wavelength_nm": s.effective_wavelength_nm(),
            "source": s.origin(),
        }
    else:
        out["spectral_sensitivity"] = None
    if profile.emva is not None:  # per plane, as in the profile file (planes R, G1, G2, B or R, G, B)
        out["emva1288"] = {"iso": profile.emva.iso,
                           "channels": {c: {k: v.get(k) for k in SHEET_KEYS} | {"K_source": v.get("K_source")}
                                        for c, v in profile.emva.channels.items()}}
    else:
        out["emva1288"] = None
    p = profile.provenance
    out["provenance"] = {"camcal_version": p.camcal_version, "created_utc": p.created_utc, "n_inputs": len(p.inputs),
                         "options": p.options, "left_out": [dict(r) for r in p.left_out],
                         "not_calibrated": [dict(r) for r in p.not_calibrated]}
    return to_jsonable(out)


def _flatten(obj, prefix: str = "") -> dict[str, Any]:
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    if isinstance(obj, list) and obj and all(isinstance(v, int | float) for v in obj):
        return {prefix: obj}
    return {prefix: obj}


def diff_profiles(a: CalibrationProfile, b: CalibrationProfile, rel_tol: float = 0.0) -> list[dict]:
    """Differences between two profiles' contracts: ``[{key, a, b, rel_change}]`` (numbers compared relatively)."""
    fa, fb = _flatten(contract(a)), _flatten(contract(b))
    rows = []
    for key in sorted(set(fa) | set(fb)):
        if key in ("content_sha256", "provenance.created_utc"):
            continue
        va, vb = fa.get(key), fb.get(key)
        if isinstance(va, list) and isinstance(vb, list) and len(va) == len(vb) and va and isinstance(va[0], float):
            x, y = np.asarray(va, float), np.asarray(vb, float)
            scale = max(float(np.max(np.abs(x))), 1e-300)
            rel = float(np.max(np.abs(x - y)) / scale)
            if rel > rel_tol:
                rows.append({"key": key, "a": f"{len(va)} values", "b": f"{len(vb)} values", "rel_change": rel})
            continue
        if isinstance(va, int | float) and isinstance(vb, int | float) and not isinstance(va, bool):
            rel = abs(vb - va) / max(abs(va), 1e-300) if va != vb else 0.0
            if rel > rel_tol:
                rows.append({"key": key, "a": va, "b": vb, "rel_change": rel})
        elif va != vb:
            rows.append({"key": key, "a": va, "b": vb, "rel_change": None})
    return rows

"""The bundled camera-curve library: measured relative c(λ) of 52 camera models, found by make and model.

The curves are the ACES project's ``AcademySoftwareFoundation/rawtoaces-data`` (Apache-2.0,
``data/camera/*_380_780_5.json``; copied unchanged into ``calibration_data/camera_curves/rawtoaces/`` with
the licence and the publisher's ``aliases.json``): relative R, G, B from 380 to 780 nm every 5 nm, make and
model in a JSON header. Every file is read with a bound (:data:`camcal.io.limits.MAX_CURVE_JSON_BYTES`, the JSON
nesting depth) and validated against ``camcal/schemas/camera-curves-rawtoaces.schema.json`` before use.

Names. Cameras spell themselves in many ways; :func:`find_camera` accepts

- a full name, ``"Canon EOS 5D Mark III"``, with any case, spaces, underscores or hyphens
  (``"Canon_EOS_5D_Mark_III"``, ``"canon eos-5d mark iii"``);
- EXIF's make and model, ``("Canon", "Canon EOS 5D Mark III")`` or ``("NIKON CORPORATION", "NIKON D5100")``:
  the make's corporate suffix is dropped and a model that repeats the make is taken without it;
- a model alone when only one make has it (``"D5100"``, ``"ILCE-7M3"``);
- the publisher's aliases (``"EOS Rebel T3i"`` is the EOS 600D; a different model with the same sensor is
  matched too, and the match says so).

An unknown name is refused in one line naming the closest models (:mod:`difflib`).

The curves carry no uncertainty of their own; used on another unit of the model they carry the
borrowed-curve uncertainty (:mod:`camcal.curves.borrowed`).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import json
import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np

from camcal.curves.borrowed import TABLE as BORROWED_TABLE
from camcal.curves.borrowed import shipped_table_sha256, with_borrowed_uncertainty
from camcal.errors import CamcalError
from camcal.frame import PLANES, RGB
from camcal.io.hashing import sha256_file
from camcal.io.limits import MAX_CURVE_JSON_BYTES, check_json_depth
from camcal.io.manifest import read_text_file
from camcal.models.spectral import RELATIVE_UNITS, SpectralSensitivity

#: Where the library lives inside the ``calibration_data`` package.
LIBRARY_FOLDER = "camera_curves/rawtoaces"
#: The collection the files were copied from (repository @ commit).
COLLECTION = "AcademySoftwareFoundation/rawtoaces-data @ e9b8503cf8a0641f40e5345d9757bde60c15f423"
FILE_SUFFIX = "_380_780_5.json"
ALIASES_FILE = "aliases.json"
_CORPORATE = re.compile(r"\b(corporation|corp|company|co|ltd|limited|inc|gmbh|ag|imaging|optical|camera)\b\.?")


def _key(text: str) -> str:
    """Letters and digits only, lower case: ``"Canon_EOS-5D Mark III"`` -> ``"canoneos5dmarkiii"``."""
    return re.sub(r"[^0-9a-z]", "", str(text).lower())


def make_key(make: str) -> str:
    """A make without its corporate suffix: ``"NIKON CORPORATION"`` -> ``"nikon"``."""
    return _key(_CORPORATE.sub(" ", str(make).lower().replace("_", " ")))


@dataclass(frozen=True)
class LibraryCamera:
    """One camera of the library (the header of its file)."""

    make: str
    model: str
    file: str
    creator: str | None
    equipment: str | None
    license: str

    @property
    def name(self) -> str:
        return f"{self.make} {self.model}"

    @property
    def make_key(self) -> str:
        return make_key(self.make)

    @property
    def model_key(self) -> str:
        return _key(self.model)


@dataclass(frozen=True)
class Match:
    """The library camera a name resolved to, and how (``exact``, ``model``, ``alias: …``)."""

    camera: LibraryCamera
    query: str
    how: str


def library_folder() -> Path:
    """The folder of the bundled library files."""
    return Path(str(resources.files("calibration_data").joinpath(LIBRARY_FOLDER)))


@functools.cache
def _schema_validator() -> jsonschema.Draft202012Validator:
    text = resources.files("camcal").joinpath("schemas/camera-curves-rawtoaces.schema.json").read_text("utf-8")
    return jsonschema.Draft202012Validator(json.loads(text))


def read_curve_json(path: str | Path) -> dict[str, Any]:
    """A library file, read with a bound and validated (one line naming the file and the problem)."""
    path = Path(path)
    text = read_text_file(path, "camera-curve file", MAX_CURVE_JSON_BYTES, max_line_bytes=None)
    check_json_depth(text.encode("utf-8"), path, "camera-curve file")
    try:
        doc = json.loads(text)
    except ValueError as exc:
        raise CamcalError(f"not a camera-curve file (invalid JSON: {' '.join(str(exc).split())[:100]})",
                          path) from None
    errors = sorted(_schema_validator().iter_errors(doc), key=lambda e: [str(p) for p in e.absolute_path])
    if errors:
        err = errors[0]
        loc = "/".join(str(p) for p in err.absolute_path) or "(top level)"
        raise CamcalError(f"camera-curve file does not follow its schema at {loc}: "
                          f"{' '.join(err.message.split())[:160]}", path)
    return doc


def _camera_of(doc: dict[str, Any], path: Path) -> LibraryCamera:
    h = doc["header"]
    return LibraryCamera(h["manufacturer"].strip(), h["model"].strip(), path.name, h.get("document_creator"),
                         h.get("measurement_equipment"), h["license"])


@functools.cache
def _catalogue(folder: str) -> tuple[LibraryCamera, ...]:
    files = sorted(Path(folder).glob("*" + FILE_SUFFIX))
    if not files:
        raise CamcalError("holds no camera-curve files (*_380_780_5.json)", folder)
    return tuple(_camera_of(read_curve_json(f), f) for f in files)


def list_cameras(search: str | None = None, folder: str | Path | None = None) -> list[LibraryCamera]:
    """The library's cameras (sorted by make and model); ``search`` keeps those whose name contains it
    (case, spaces, underscores and hyphens ignored)."""
    cams = sorted(_catalogue(str(folder or library_folder())), key=lambda c: (c.make.lower(), c.model.lower()))
    if search:
        k = _key(search)
        cams = [c for c in cams if k in _key(c.name)]
    return cams


@functools.cache
def _aliases(folder: str) -> tuple[dict[str, str], dict[tuple[str, str], tuple[str, str, str]]]:
    """(make key -> make, (make key, model key) -> (make, model, comment)) from the publisher's aliases.json."""
    path = Path(folder) / ALIASES_FILE
    if not path.is_file():
        return {}, {}
    text = read_text_file(path, "camera-curve aliases", MAX_CURVE_JSON_BYTES, max_line_bytes=None)
    check_json_depth(text.encode("utf-8"), path, "camera-curve aliases")
    try:
        cam = json.loads(text)["data"]["camera"]
        makes = {make_key(k): str(v) for k, v in cam.get("make", {}).items()}
        models = {(make_key(mk), _key(alias)): (str(e["make"]), str(e["model"]), str(e.get("comments") or ""))
                  for mk, table in cam.get("model", {}).items() for alias, e in table.items()}
    except (ValueError, KeyError, TypeError, AttributeError):
        raise CamcalError("camera-curve aliases are malformed", path) from None
    return makes, models


def _resolve(mk: str | None, mdk: str, cams: list[LibraryCamera], folder: str, query: str) -> Match | None:
    make_alias, model_alias = _aliases(folder)
    if mk is not None and mk in make_alias:
        mk = make_key(make_alias[mk])
    if mk is not None and mdk.startswith(mk) and len(mdk) > len(mk):  # EXIF's "Canon EOS …", "NIKON D5100"
        mdk = mdk[len(mk):]
    for c in cams:
        if (mk is None or c.make_key == mk) and c.model_key == mdk:
            return Match(c, query, "exact" if mk is not None else "model")
    for (amk, amd), (make, model, comment) in model_alias.items():
        if (mk is None or amk == mk) and amd == mdk:
            for c in cams:
                if c.make_key == make_key(make) and c.model_key == _key(model):
                    return Match(c, query, f"alias: {query} is listed by the library as {c.name} ({comment})")
    return None


#: What a user whose camera has no curves in the library can do (every step exists).
NO_CURVES_NEXT_STEP = ("photograph a colour chart (X-Rite ColorChecker) in the sun and run camcal chart PHOTO -o "
                       "camera.camcal (c(λ) from the chart), or import a measured curve file (camcal profile "
                       "import-spectral CURVES.csv; see camcal curves list for the library)")


def find_camera(name: str | None = None, *, make: str | None = None, model: str | None = None,
                folder: str | Path | None = None) -> Match:
    """The library camera named ``name`` (a full name or a model) or by EXIF ``make`` and ``model``.

    Raises
    ------
    CamcalError
        One line naming the closest models of the library when nothing matches.
    """
    folder = str(folder or library_folder())
    cams = list_cameras(folder=folder)
    if name is None and not model:
        raise CamcalError("no camera model to look up (the profile and the photos name none; give --camera)")
    query = name if name is not None else (model if make and model and _key(model).startswith(make_key(make))
                                           else " ".join(x for x in (make, model) if x))
    found = None
    if name is None:
        found = _resolve(make_key(make) if make else None, _key(model or ""), cams, folder, query)
    else:
        k = _key(name)
        makes = sorted({c.make_key for c in cams} | set(_aliases(folder)[0]), key=len, reverse=True)
        for mk in makes:  # "Canon EOS 5D Mark III", "Canon_Canon EOS 5D Mark III" (make repeated)
            if k.startswith(mk) and len(k) > len(mk):
                rest = k[len(mk):]
                while rest.startswith(mk) and len(rest) > len(mk):
                    rest = rest[len(mk):]
                found = _resolve(mk, rest, cams, folder, query)
                if found:
                    break
        if found is None:  # a model alone, when one make has it
            hits = [c for c in cams if c.model_key == k]
            found = Match(hits[0], query, "model") if len(hits) == 1 else _resolve(None, k, cams, folder, query)
    if found is None:
        # closest models only of the same make: another make's camera is no substitute (a phone for a DSLR)
        mk = make_key(make) if make else next((m for m in sorted({c.make_key for c in cams}, key=len, reverse=True)
                                               if _key(query).startswith(m)), None)
        names = [c.name for c in cams if mk is not None and c.make_key == mk]
        close = difflib.get_close_matches(query, names, n=4, cutoff=0.5) or \
            difflib.get_close_matches(query.lower(), [n.lower() for n in names], n=4, cutoff=0.3)
        close = [next(n for n in names if n.lower() == c.lower()) for c in close]
        hint = f"; closest: {', '.join(close)}" if close else ""
        raise CamcalError(f"camera {query!r} is not in the curve library ({len(cams)} cameras){hint}; "
                          f"{NO_CURVES_NEXT_STEP}")
    return found


def library_curves(match: Match, layout: str = "bayer", *, folder: str | Path | None = None
                   ) -> tuple[SpectralSensitivity, dict[str, Any], Path]:
    """The relative curves of a library camera with the borrowed-curve uncertainty, its source record and file.

    ``layout`` ``"bayer"`` gives planes R, G1, G2, B (the file's one G for both greens), ``"linear"`` R, G, B.
    The record (``spectral_sensitivity.source.library`` of a profile) names the entry, its file's SHA-256,
    the collection, the measurement's creator and equipment, the licence and how the name matched.
    """
    path = Path(str(folder or library_folder())) / match.camera.file
    doc = read_curve_json(path)
    main = doc["spectral_data"]["data"]["main"]
    wl = np.array([float(k) for k in main])
    order = np.argsort(wl)
    wl = wl[order]
    if np.any(np.diff(wl) <= 0):
        raise CamcalError("camera-curve file lists a wavelength twice", path)
    vals = np.array([main[k] for k in main], float)[order]
    if not np.all(np.isfinite(vals)):
        raise CamcalError("camera-curve file holds a non-finite value", path)
    rgb = {ch: vals[:, i] for i, ch in enumerate(RGB)}
    planes = RGB if layout == "linear" else PLANES
    values = {p: rgb["G" if p in ("G1", "G2") else p].copy() for p in planes}
    notes = [f"curves of the library's {match.camera.name} (measured on another unit of the model)"]
    if match.how.startswith("alias"):
        notes.append(match.how)
    if layout != "linear":
        notes.append("one green curve in the library: used for both G1 and G2")
    curves = SpectralSensitivity(wavelength_nm=wl, values=values,
                                 uncertainty={p: np.zeros_like(wl) for p in planes}, units=RELATIVE_UNITS,
                                 mode="relative", notes=tuple(notes))
    curves = with_borrowed_uncertainty(curves)
    record = {"name": match.camera.name, "make": match.camera.make, "model": match.camera.model,
              "file": match.camera.file, "sha256": sha256_file(path), "collection": COLLECTION,
              "creator": match.camera.creator, "equipment": match.camera.equipment,
              "license": match.camera.license, "matched": f"{match.query!r} ({match.how})",
              "borrowed_uncertainty": {"table": BORROWED_TABLE, "sha256": shipped_table_sha256(),
                                       "description": "standard uncertainty of a model's curve used on another "
                                       "unit, fraction of each channel's peak (docs/spectral.md)"}}
    return curves, record, path


def with_layout(curves: SpectralSensitivity, layout: str) -> SpectralSensitivity:
    """Bayer planes (R, G1, G2, B) for ``"bayer"``, R, G, B for ``"linear"`` (G = the mean of G1 and G2)."""
    if layout == "linear" and "G1" in curves.values:
        rgb, urgb = curves.rgb(), curves.rgb_uncertainty()
        return dataclasses.replace(curves, values=rgb, uncertainty=urgb)
    if layout != "linear" and "G1" not in curves.values:
        v, u = curves.values, curves.uncertainty
        return dataclasses.replace(curves, values={"R": v["R"], "G1": v["G"], "G2": v["G"], "B": v["B"]},
                                   uncertainty={"R": u["R"], "G1": u["G"], "G2": u["G"], "B": u["B"]})
    return curves

"""A plain description of image files: what ``camcal inspect`` prints."""

from __future__ import annotations

from pathlib import Path

from camcal.calibrate.session import STAGES, index_session
from camcal.errors import CamcalError
from camcal.frame import PLACE_TIME, TRACKED
from camcal.io.folders import folder_manifest
from camcal.io.manifest import exposure_overrides
from camcal.io.read import load_frame, saturated_fraction
from camcal.io.sun import SunPosition, photo_time_utc, sun_from_metadata

SUN_KEYS = ("zenith_deg", "azimuth_deg", "apparent_zenith_deg", "source")
"""Keys of the ``sun`` object of :func:`describe` (and rows ``sun.<key>`` of the table)."""


def describe_sun(exposure, path, sun: SunPosition | None = None) -> dict[str, object]:
    """The ``sun`` object of :func:`describe`: ``sun`` when given (``--sun``), else from the photo's metadata;
    with unknown angles (null) and a ``reason`` when the photo cannot place it."""
    if sun is None:
        try:
            sun = sun_from_metadata(exposure, path=None)
        except CamcalError as exc:
            return {**dict.fromkeys(SUN_KEYS), "reason": exc.message}
    d = sun.to_dict()
    return {k: d[k] for k in (*SUN_KEYS, "utc")} | {"reason": None}


def describe(path: str | Path, sun: SunPosition | None = None) -> dict[str, object]:
    """Decode ``path`` and return its layout and exposure metadata as a JSON-ready dict.

    Keys: file, kind (raw/processed), layout (bayer/linear/processed), format, width, height,
    channels (plane names), cfa_pattern, black_level_dn (per plane), white_level_dn, bit_depth,
    icc_profile (processed images: the embedded profile's description), exposure_s, f_number, iso,
    exposure_value_s (ISO·t/N², s), make, model, serial, capture_time (the camera clock, no zone),
    utc_offset (``+HH:MM``), capture_time_utc, time_source (:func:`camcal.io.sun.photo_time_utc`),
    latitude_deg, longitude_deg, altitude_m (GPS), sun (``zenith_deg``, ``azimuth_deg``,
    ``apparent_zenith_deg``, ``source``, ``utc``, ``reason`` when unknown), saturated_pct (percent of the
    values at or above the white level), saturated (a note when a quarter of them or more are: "fully
    saturated" or the percentage; null otherwise), sources (where each of exposure_s, f_number, iso,
    capture_time, utc_offset, gps_time_utc, latitude_deg, longitude_deg, altitude_m came from: ``tag``,
    ``libraw``, ``frames.csv``, ``session``; null when unknown), notes (disagreements between readers, values
    set aside, a GPS date that disagrees with the local date), error (null).

    An unknown value is null (None): never a library's placeholder. The file's values are read the way
    ``calibrate`` and ``apply`` read them (:func:`manifest_row`): a stage folder of a session through the
    session index (its ``frames.csv`` or ``sweep.csv`` row, marked ``frames.csv``), any other folder through
    its own ``frames.csv``; session defaults (``session.toml`` beside the file or in its parent folder)
    apply, marked ``session``.
    ``sun`` (``--sun ZENITH,AZIMUTH``) replaces the sun computed from the photo.
    """
    overrides, index_note = manifest_row(Path(path))
    f = load_frame(path, overrides)
    e = f.exposure
    h, w = f.shape
    sat = 100.0 * saturated_fraction(f)
    ev = e.iso * e.exposure_s / e.f_number**2 if (e.iso and e.exposure_s and e.f_number) else None
    when = photo_time_utc(e)
    bits = int(f.white_level_dn).bit_length() if f.kind == "processed" else None
    return {
        "file": str(path),
        "kind": f.kind,
        "layout": f.layout,
        "format": Path(path).suffix.lower().lstrip("."),
        "width": w,
        "height": h,
        "channels": list(f.channel_names),
        "cfa_pattern": f.cfa_pattern,
        "black_level_dn": f.black_level_dn,
        "white_level_dn": f.white_level_dn,
        "bit_depth": bits,
        "icc_profile": f.icc_profile,
        "exposure_s": e.exposure_s,
        "f_number": e.f_number,
        "focal_length_mm": e.focal_length_mm,
        "iso": e.iso,
        "exposure_value_s": ev,
        "make": e.make,
        "model": e.model,
        "serial": e.serial,
        "capture_time": e.capture_time,
        "utc_offset": e.utc_offset,
        "capture_time_utc": None if when.utc is None else when.utc.isoformat(),
        "time_source": when.source,
        "latitude_deg": e.latitude_deg,
        "longitude_deg": e.longitude_deg,
        "altitude_m": e.altitude_m,
        "sun": describe_sun(e, path, sun),
        "saturated_pct": round(sat, 3),
        "saturated": ("fully saturated: every value at the white level" if sat >= 100.0 else
                      f"{min(sat, 99.99):.4g} % of the values at the white level" if sat >= 25.0 else None),
        "sources": {name: e.source(name) for name in (*TRACKED, *PLACE_TIME)},
        "notes": (list(e.notes) + [n for n in when.notes if not n.startswith("no ")]
                  + ([index_note] if index_note else [])),
        "error": None,
    }


def manifest_row(path: Path) -> tuple[dict[str, float | None], str | None]:
    """The manifest overrides ``calibrate`` or ``apply`` would give ``path``, and a note when it could not say.

    In a session's stage folder (``SESSION/dark/x.dng``): the row the session index resolves for the file
    (:func:`camcal.calibrate.session.index_session`, as ``calibrate`` reads it). In any other folder: the folder's own
    ``frames.csv`` row (as ``apply`` reads a folder of photos).
    """
    folder = path.parent
    if folder.name in STAGES:
        try:
            index = index_session(folder.parent)
        except CamcalError as exc:  # the file is still described, with the reason its session is not read
            return exposure_overrides(folder_manifest(folder).get(path.name)), f"session index: {exc}"
        stage = index.stage(folder.name)
        if stage is not None:
            for ref in stage.frames:
                if ref.path.name == path.name:
                    return dict(ref.overrides), None
            return {}, None
    return exposure_overrides(folder_manifest(folder).get(path.name)), None


def describe_many(paths: list[str | Path], sun: SunPosition | None = None
                  ) -> tuple[list[dict[str, object]], list[dict[str, str]]]:
    """:func:`describe` every file; one that cannot be read does not stop the others.

    Returns
    -------
    (entries, failures): ``entries`` in the order given, a failed file as ``{"file", "error"}``
    (the one-line reason); ``failures`` those failed entries alone.
    """
    entries: list[dict[str, object]] = []
    failures: list[dict[str, str]] = []
    for p in paths:
        try:
            entries.append(describe(p, sun))
        except CamcalError as exc:
            failures.append({"file": str(p), "error": str(exc)})
            entries.append(failures[-1])  # type: ignore[arg-type]
    return entries, failures

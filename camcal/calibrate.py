"""``camcal calibrate``: run every stage whose folder exists, in order, into one profile.

Order: dark (with bias/ when present) → flat (dark-corrected) → linearity
(dark-corrected) → sweep (dark- and flat-corrected). Every input file is
hashed (SHA-256) into the profile's provenance.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

from camcal import __version__
from camcal.dark import fit_dark, with_dead_pixels
from camcal.errors import CamcalError
from camcal.flat import DEAD_RESPONSE, dead_pixels, fit_flat
from camcal.hashing import sha256_file
from camcal.io import IMAGE_EXTENSIONS, folder_manifest, list_frames, load_frame
from camcal.manifest import SESSION_DEFAULTS, read_manifest
from camcal.profile import CalibrationProfile, CameraIdentity, Provenance

STAGES = ("bias", "dark", "flat", "linearity", "sweep")

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class CalibrateOptions:
    """Options of :func:`calibrate_session` (recorded in the profile's provenance).

    ``reference_iso`` / ``reference_f_number``: the reference setting; by default
    the setting of the sweep frames (where the absolute calibration is measured),
    else the most common one of the linearity series, else of the darks (flats, bias).
    Never defaulted silently: when unknown, calibration stops saying what to add.
    """

    reference_iso: float | None = None
    reference_f_number: float | None = None
    dark_method: str = "sigma_clip"
    flat_model: str = "radial"
    sweep_mode: str = "absolute"
    deconvolve: bool = False
    jobs: int = 2


def present_stages(session: str | Path) -> list[str]:
    """Stage folders of ``session`` that hold at least one image file."""
    session = Path(session)
    if not session.is_dir():
        raise CamcalError("is not a session folder", session)
    out = []
    for s in STAGES:
        d = session / s
        if d.is_dir() and any(p.suffix.lower() in IMAGE_EXTENSIONS for p in d.iterdir()):
            out.append(s)
    return out


def _inputs(session: Path, stages: list[str]) -> list[dict]:
    rows = []
    for s in stages:
        d = session / s
        for p in sorted(d.iterdir()):
            if p.is_file() and not p.name.startswith(".") and (
                p.suffix.lower() in IMAGE_EXTENSIONS or p.suffix.lower() == ".csv"
            ):
                rows.append({"stage": s, "file": f"{s}/{p.name}", "sha256": sha256_file(p), "bytes": p.stat().st_size})
    return rows


def camera_identity(session: Path, stages: list[str]) -> CameraIdentity:
    """Identity from the first RAW frame of the session (else the first frame); all stages must agree."""
    seen: dict[str, CameraIdentity] = {}
    for s in stages:
        frames = list_frames(session / s)
        raw = [p for p in frames if p.suffix.lower() not in (".jpg", ".jpeg", ".png", ".tif", ".tiff")]
        f = load_frame((raw or frames)[0])
        h, w = f.shape
        seen[s] = CameraIdentity(f.exposure.make, f.exposure.model, f.exposure.serial, f.cfa_pattern, w, h, f.layout)
    models = {(c.make, c.model) for c in seen.values() if c.model}
    if len(models) > 1:
        raise CamcalError(f"frames from different cameras in one session: {sorted(models)}", session)
    layouts = {c.layout for c in seen.values() if c.layout != "processed"}
    if len(layouts) > 1:
        raise CamcalError(f"RAW frames of different layouts in one session: {sorted(layouts)} (one camera mode per "
                          "session)", session)
    raw_ids = [c for c in seen.values() if c.layout != "processed"]
    return (raw_ids or list(seen.values()))[0]


_REFERENCE_HINT = {
    "iso": ("ISO", "iso = N", "iso", "--reference-iso"),
    "f_number": ("f-number", "f_number = N", "f_number", "--reference-f-number"),
}


def _reference(session: Path, stages: list[str], opts: CalibrateOptions) -> tuple[float, float, list[str]]:
    """The reference setting (ISO_ref, N_ref): the options', else the most common setting of the first stage
    present of sweep, linearity, dark, flat, bias (frames.csv / sweep.csv and session.toml applied).

    Never defaulted: a value no frame, manifest or session default gives stops calibration with one line
    saying what to add. Returns (ISO_ref, N_ref, notes): a note says when a value came from ``session.toml``
    or from LibRaw alone rather than from a tag or a manifest.
    """
    iso, n = opts.reference_iso, opts.reference_f_number
    if iso and n:
        return float(iso), float(n), []
    for s in ("sweep", "linearity", "dark", "flat", "bias"):
        if s not in stages:
            continue
        manifest = folder_manifest(session / s) if (session / s / "frames.csv").exists() else {}
        csv_name = "frames.csv"
        if s == "sweep" and (session / s / "sweep.csv").exists():
            manifest = read_manifest(session / s / "sweep.csv", required=("file",))
            csv_name = "sweep.csv"
        settings: Counter = Counter()
        origin: dict[tuple, tuple[str | None, str | None]] = {}
        for p in list_frames(session / s)[:64]:
            row = manifest.get(p.name, {})
            f = load_frame(p)
            key = (row.get("iso") or f.exposure.iso, row.get("f_number") or f.exposure.f_number)
            settings[key] += 1
            origin.setdefault(key, (csv_name if row.get("iso") else f.exposure.source("iso"),
                                    csv_name if row.get("f_number") else f.exposure.source("f_number")))
        (fi, fn), _ = settings.most_common(1)[0]
        iso, n = iso or fi, n or fn
        for key, value in (("iso", iso), ("f_number", n)):
            if not value:
                what, toml, col, opt = _REFERENCE_HINT[key]
                raise CamcalError(
                    f"the reference {what} is unknown: the {s}/ frames hold no {what} (no tag, no {col} column); "
                    f"add '{toml}' to {SESSION_DEFAULTS} at the session root (one value for the whole camera), "
                    f"an {col} column to {s}/{csv_name}, or pass {opt}", session)
        notes = [f"reference {what} {value:g} from {SESSION_DEFAULTS if src == 'session' else 'LibRaw alone (no tag)'}"
                 for what, value, src, given in (("ISO", iso, origin[(fi, fn)][0], opts.reference_iso),
                                                 ("f-number", n, origin[(fi, fn)][1], opts.reference_f_number))
                 if not given and src in ("session", "libraw")]
        return float(iso), float(n), notes
    raise CamcalError("no stage folder to take the reference setting from; pass --reference-iso and "
                      "--reference-f-number", session)


def calibrate_session(
    session: str | Path, options: CalibrateOptions | None = None, progress: Progress | None = None
) -> tuple[CalibrationProfile, list[str]]:
    """Calibrate every stage present in ``session``; returns the profile and notes (skipped stages...).

    ``progress(stage, done, total)`` is called as frames are processed.
    """
    session = Path(session)
    opts = options or CalibrateOptions()
    stages = present_stages(session)
    if not stages:
        raise CamcalError("holds none of bias/ dark/ flat/ linearity/ sweep/ with image files", session)
    camera = camera_identity(session, stages)
    ref_iso, ref_n, notes = _reference(session, stages, opts)

    def cb(stage: str):
        return (lambda done, total: progress(stage, done, total)) if progress else None

    dark = flat = spectral = None
    response = None
    if "dark" in stages:
        dark = fit_dark(session / "dark", session / "bias" if "bias" in stages else None, method=opts.dark_method,
                        jobs=opts.jobs, progress=cb("dark"))
    elif "bias" in stages:
        dark = fit_dark(None, session / "bias", jobs=opts.jobs, progress=cb("bias"))
        notes.append("bias/ without dark/: bias, read noise and noisy pixels calibrated; dark current unknown "
                     "(apply subtracts the bias only; add dark frames at two exposure times to measure it)")
    if "flat" in stages:
        flat = fit_flat(session / "flat", dark, model=opts.flat_model, jobs=opts.jobs, progress=cb("flat"))
        dead = dead_pixels(flat)
        if dark is not None:
            dark = with_dead_pixels(dark, dead, f"flat response below {DEAD_RESPONSE:g} of the model")
        elif dead.any():
            notes.append(f"{int(dead.sum())} dead pixels in the flats are not kept: without a dark model the "
                         "profile has no defect map")
    if "linearity" in stages:
        from camcal.response import fit_response

        response = fit_response(session / "linearity", dark=dark, reference_iso=ref_iso, reference_f_number=ref_n,
                                progress=cb("linearity"))
    if "sweep" in stages:
        from camcal.spectral import measure_sweep

        spectral = measure_sweep(session / "sweep", dark=dark, flat=flat, mode=opts.sweep_mode,
                                 deconvolve=opts.deconvolve, reference_iso=ref_iso, reference_f_number=ref_n,
                                 jobs=opts.jobs, progress=cb("sweep"))
        if flat is None:
            notes.append("sweep without a flat model: c(λ) refers to the region of interest, not the optical axis")
        if response is not None and "processed" in response:
            from dataclasses import replace

            from camcal.colour import fit_colour_matrix, twin_pairs

            if twin_pairs(session / "sweep"):  # the sweep's colours; the series adds a broadband one
                cm = fit_colour_matrix([session / "sweep", session / "linearity"], response["processed"])
                response = {**response, "processed": replace(response["processed"], colour_matrix=cm)}
            else:
                notes.append("JPEG response without a colour matrix (the sweep has no JPEG twins): JPEG radiance "
                             "assumes the camera does not mix its channels")
    provenance = Provenance(
        camcal_version=__version__,
        created_utc=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        inputs=tuple(_inputs(session, stages)),
        options={**asdict(opts), "session": session.name, "stages": stages},
    )
    profile = CalibrationProfile(camera=camera, reference_iso=ref_iso, reference_f_number=ref_n, dark=dark,
                                 flat=flat, response=response, spectral=spectral, provenance=provenance)
    return profile, notes

"""``camcal calibrate``: run every stage whose folder exists, in order, into one profile.

Order: dark (with bias/ when present) → flat (dark-corrected) → linearity
(dark-corrected) → sweep (dark- and flat-corrected). Every input file is
hashed (SHA-256) into the profile's provenance.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from camcal import __version__
from camcal.camera_id import Sensor, match, preferred, sensor_of
from camcal.colour import fit_colour_matrix, twin_pairs
from camcal.dark import DarkOptions, fit_dark_stacks, stack_darks, with_dead_pixels
from camcal.emva import build_sheet
from camcal.errors import CamcalError
from camcal.flat import DEAD_RESPONSE, FlatOptions, dead_pixels, fit_master, flat_prnu, master_flat
from camcal.hashing import sha256_file
from camcal.io import load_frame
from camcal.manifest import SESSION_DEFAULTS, session_camera_facts
from camcal.profile import CalibrationProfile, CameraIdentity, Provenance
from camcal.response import fit_series_set, measure_series
from camcal.session import STAGES, SessionIndex, index_session, present_stages
from camcal.spectral import SweepOptions, measure_sweep_settings, read_sweep, sensitivity_from_settings, sweep_rows

__all__ = ["STAGES", "CalibrateOptions", "calibrate_session", "camera_identity", "present_stages"]

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class CalibrateOptions:
    """Options of :func:`calibrate_session` (recorded in the profile's provenance).

    ``reference_iso`` / ``reference_f_number``: the reference setting; by default
    the setting of the sweep frames (where the absolute calibration is measured),
    else the most common one of the linearity series, else of the darks (flats, bias).
    Never defaulted silently: when unknown, calibration stops saying what to add.

    ``jobs``: decoding threads; None chooses them (:func:`camcal.threads.thread_count`: the usable cores, at most
    4, and one thread for frames under 0.25 megapixels, where a pool costs more than it gains).
    """

    reference_iso: float | None = None
    reference_f_number: float | None = None
    dark_method: str = "sigma_clip"
    flat_model: str = "radial"
    sweep_mode: str = "absolute"
    deconvolve: bool = False
    jobs: int | None = None


def _inputs(index: SessionIndex) -> list[dict]:
    """Provenance rows (stage, file, SHA-256, bytes) of every input file the session index found."""
    return [{"stage": s, "file": f"{s}/{p.name}", "sha256": sha256_file(p), "bytes": p.stat().st_size}
            for s in index.stages for p in index.inputs.get(s, ())]


def camera_identity(session: str | Path | SessionIndex, stages: list[str] | None = None) -> CameraIdentity:
    """Identity from the first RAW frame of the session (else the first frame); all stages must agree.

    ``session`` is a :class:`camcal.session.SessionIndex` (or a folder, indexed here); ``stages`` limits the
    stages looked at (default: all present).
    """
    index = session if isinstance(session, SessionIndex) else index_session(session)
    seen: dict[str, CameraIdentity] = {}
    sensors: dict[str, Sensor] = {}
    for s in stages if stages is not None else index.stages:
        frames = index.frames[s].paths
        raw = [p for p in frames if p.suffix.lower() not in (".jpg", ".jpeg", ".png", ".tif", ".tiff")]
        f = load_frame((raw or frames)[0])
        h, w = f.shape
        seen[s] = CameraIdentity(f.exposure.make, f.exposure.model, f.exposure.serial, f.cfa_pattern, w, h, f.layout)
        sensors[s] = sensor_of(f)
    named = {s: c for s, c in sensors.items() if c.model}
    for s, c in named.items():  # every stage against every other (camcal.camera_id: software names forgiven)
        for t, d in named.items():
            if s < t and not match(c, d)[0]:
                raise CamcalError(f"frames from different cameras in one session: {s}/ is {c.label}, {t}/ is "
                                  f"{d.label}", index.root)
    if named:
        best = preferred(list(named.values()))
        stage = next(s for s, c in named.items() if c is best)
        seen = {stage: seen[stage], **seen}
    layouts = {c.layout for c in seen.values() if c.layout != "processed"}
    if len(layouts) > 1:
        raise CamcalError(f"RAW frames of different layouts in one session: {sorted(layouts)} (one camera mode per "
                          "session)", index.root)
    raw_ids = [c for c in seen.values() if c.layout != "processed"]
    return (raw_ids or list(seen.values()))[0]


_REFERENCE_HINT = {
    "iso": ("ISO", "iso = N", "iso", "--reference-iso"),
    "f_number": ("f-number", "f_number = N", "f_number", "--reference-f-number"),
}


def _reference(index: SessionIndex, opts: CalibrateOptions) -> tuple[float, float, list[str]]:
    """The reference setting (ISO_ref, N_ref): the options', else the most common setting of the first stage
    present of sweep, linearity, dark, flat, bias (frames.csv / sweep.csv and session.toml applied).

    Never defaulted: a value no frame, manifest or session default gives stops calibration with one line
    saying what to add. Returns (ISO_ref, N_ref, notes): a note says when a value came from ``session.toml``
    or from LibRaw alone rather than from a tag or a manifest.
    """
    iso, n = opts.reference_iso, opts.reference_f_number
    if iso and n:
        return float(iso), float(n), []
    session = index.root
    for s in ("sweep", "linearity", "dark", "flat", "bias"):
        if s not in index.stages:
            continue
        manifest, csv_name = index.manifest_of(s)
        settings: Counter = Counter()
        origin: dict[tuple, tuple[str | None, str | None]] = {}
        for ref in index.frames[s].frames[:64]:
            p = ref.path
            row = manifest.get(p.name, {})
            if ref.iso is not None and ref.f_number is not None:  # manifest, tag or session.toml: no decode
                exp_iso, exp_n, src_iso, src_n = ref.iso, ref.f_number, ref.iso_source, ref.f_number_source
            else:  # only LibRaw (a maker header) can tell: decode
                e = load_frame(p).exposure
                exp_iso, exp_n, src_iso, src_n = e.iso, e.f_number, e.source("iso"), e.source("f_number")
            key = (row.get("iso") or exp_iso, row.get("f_number") or exp_n)
            settings[key] += 1
            origin.setdefault(key, (csv_name if row.get("iso") else src_iso,
                                    csv_name if row.get("f_number") else src_n))
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


def _flat_mask(master, dark):
    """Pixels left out of the flat's PRNU: masked in every frame, and the dark model's defects."""
    mask = ~np.isfinite(master.value)
    if dark is not None and dark.defects.shape == mask.shape:
        mask |= dark.defects != 0
    return mask


def calibrate_session(
    session: str | Path, options: CalibrateOptions | None = None, progress: Progress | None = None
) -> tuple[CalibrationProfile, list[str]]:
    """Calibrate every stage present in ``session``; returns the profile and notes (skipped stages...).

    The session is read once (:func:`camcal.session.index_session`: stage folders, manifests, session
    defaults); every stage receives its frames from that index. ``progress(stage, done, total)`` is called
    as frames are processed.
    """
    opts = options or CalibrateOptions()
    index = index_session(session)
    session = index.root
    stages = list(index.stages)
    camera = camera_identity(index)
    ref_iso, ref_n, notes = _reference(index, opts)

    def cb(stage: str):
        return (lambda done, total: progress(stage, done, total)) if progress else None

    dark = flat = spectral = None
    response = None
    dark_stacks = master = prnu = pairs = None
    bias_frames = index.stage("bias")
    if "dark" in stages:
        dark_opts = DarkOptions(method=opts.dark_method)
        dark_stacks = stack_darks(index.frames["dark"], bias_frames, dark_opts, jobs=opts.jobs, progress=cb("dark"))
        dark = fit_dark_stacks(dark_stacks, dark_opts)
    elif bias_frames is not None:
        dark_stacks = stack_darks(None, bias_frames, jobs=opts.jobs, progress=cb("bias"))
        dark = fit_dark_stacks(dark_stacks)
        notes.append("bias/ without dark/: bias, read noise and noisy pixels calibrated; dark current unknown "
                     "(apply subtracts the bias only; add dark frames at two exposure times to measure it)")
    if "flat" in stages:
        flat_opts = FlatOptions(model=opts.flat_model)
        master = master_flat(index.frames["flat"], dark, method=flat_opts.method, sigma=flat_opts.sigma,
                             checks=flat_opts.checks, jobs=opts.jobs, progress=cb("flat"))
        flat = fit_master(master, dark, **flat_opts.fit_kwargs())
        if master.mean_all is not None:
            prnu = flat_prnu(master, flat, _flat_mask(master, dark))
        dead = dead_pixels(flat)
        if dark is not None:
            dark = with_dead_pixels(dark, dead, f"flat response below {DEAD_RESPONSE:g} of the model")
        elif dead.any():
            notes.append(f"{int(dead.sum())} dead pixels in the flats are not kept: without a dark model the "
                         "profile has no defect map")
    if "linearity" in stages:
        series = measure_series(index.frames["linearity"], dark=dark, reference_iso=ref_iso,
                                reference_f_number=ref_n, progress=cb("linearity"))
        pairs = series["raw"].pairs if "raw" in series else None
        response = fit_series_set(series)
    if "sweep" in stages:
        sweep = index.frames["sweep"]
        rows = sweep_rows(sweep.folder, index.sweep_manifest) if index.sweep_manifest is not None else None
        sweep_opts = SweepOptions(mode=opts.sweep_mode, deconvolve=opts.deconvolve,  # type: ignore[arg-type]
                                  reference_iso=ref_iso, reference_f_number=ref_n)
        sweep_opts.check()
        measured = measure_sweep_settings(sweep.folder, rows if rows is not None else read_sweep(sweep.folder),
                                          dark=dark, flat=flat, options=sweep_opts, jobs=opts.jobs,
                                          progress=cb("sweep"))
        spectral = sensitivity_from_settings(measured, sweep_opts)
        if flat is None:
            notes.append("sweep without a flat model: c(λ) refers to the region of interest, not the optical axis")
        if response is not None and "processed" in response:
            if twin_pairs(sweep):  # the sweep's colours; the series adds a broadband one
                cm = fit_colour_matrix([sweep, index.frames["linearity"]], response["processed"])
                response = {**response, "processed": replace(response["processed"], colour_matrix=cm)}
            else:
                notes.append("JPEG response without a colour matrix (the sweep has no JPEG twins): JPEG radiance "
                             "assumes the camera does not mix its channels")
    emva = None
    if dark is not None or pairs is not None or prnu is not None:
        channels = dark.plane_names if dark is not None else (flat.channels if flat is not None else
                                                              tuple(series["raw"].channels))
        emva = build_sheet(channels=tuple(channels), iso=dark.iso if dark is not None else ref_iso,
                           dark_stacks=dark_stacks, dark=dark, master_flat=master, flat_prnu=prnu, pairs=pairs,
                           spectral=spectral, pixel_pitch_um=session_camera_facts(session / stages[0]).get(
                               "pixel_pitch_um"))
    provenance = Provenance(
        camcal_version=__version__,
        created_utc=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        inputs=tuple(_inputs(index)),
        options={**asdict(opts), "session": session.name, "stages": stages},
    )
    profile = CalibrationProfile(camera=camera, reference_iso=ref_iso, reference_f_number=ref_n, dark=dark,
                                 flat=flat, response=response, spectral=spectral, emva=emva,
                                 provenance=provenance)
    return profile, notes

"""Batches of survey photos through a profile: a process pool, or a dask.distributed cluster.

Behaviour
---------
- One EXR per photo, ``OUTDIR/<photo name>.exr`` (``IMG_1.dng`` -> ``IMG_1.dng.exr``, so a RAW and its
  JPEG twin do not collide), written atomically (temporary file + rename): a failed or interrupted photo
  leaves no file under its final name.
- **Resumable**: a photo whose EXR exists, made with the same profile (content hash), wavelength,
  estimator, precision and compression (read from the EXR header, no pixels), is skipped without being
  decoded. An EXR made with other settings is redone.
- A failing photo (damaged file, missing metadata, another camera) does not stop the batch; its
  one-line error is listed in the report (``apply_report.csv``) and the exit code is 1.
- A photo whose f-number or focal length differs from the flats' gets a warning (its EXR's ``optics`` and
  ``notes``, the report's ``warning`` column, the summary); ``strict`` refuses it (a failure, exit code 1).
- With a region of interest the mean, median and standard deviation of every channel are written
  to ``roi_stats.csv`` (skipped photos: read back from their EXR).
- ``progress(done, total, result)`` is called in the caller's process as photos finish.

Workers load the profile from its path once per process, when they start (the pool's initializer), not
per photo (a dask cluster needs the profile, the photos and the output folder on a shared file system).

**Workers die with their parent.** A local pool's workers exit when the process that started them is gone,
however it went (SIGKILL, an out-of-memory killer, a scheduler): on Linux the kernel sends them SIGKILL
(``prctl(PR_SET_PDEATHSIG)``), elsewhere a thread of each worker polls its parent's process id. A write
cut short this way leaves a temporary ``.part`` file; the rerun removes those of writers that no longer
run (:func:`camcal.io.atomic.clear_stale`) and redoes the photos without a current EXR.
"""

from __future__ import annotations

import csv
import ctypes
import io
import math
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from camcal.apply.photo import (
    LINEAR_RESOLUTION_NOTE,
    MONO_RESOLUTION_NOTE,
    apply_prepared,
    check_camera,
    prepare,
    read_mask,
    roi_mask,
    roi_statistics,
)
from camcal.errors import CamcalError
from camcal.io.allocator import use_frame_allocator
from camcal.io.atomic import atomic_write_text, clear_stale, remove_pending
from camcal.io.exr import read_exr, read_exr_header, write_exr
from camcal.io.folders import folder_manifest, list_frames
from camcal.io.kinds import is_raw_path
from camcal.io.manifest import exposure_overrides
from camcal.io.read import exposure_from_exif, load_frame
from camcal.models.camera_id import Sensor, could_match, sensor_of_profile
from camcal.models.profile import load_profile
from camcal.region import Region
from camcal.threads import default_threads, usable_cores

REPORT_CSV = "apply_report.csv"
ROI_CSV = "roi_stats.csv"
STATUSES = ("done", "skipped", "failed")


@dataclass(frozen=True)
class BatchOptions:
    """Per-photo options (see :func:`camcal.apply.photo.apply`) and the region for statistics.

    ``roi`` is a :class:`camcal.region.Region` (photo pixels); ``mask_path`` a mask image (either one, or neither).
    """

    wavelength_nm: float = 663.0
    estimator: str = "auto"
    filter_fwhm_nm: float | None = None
    line_fwhm_nm: float | None = None
    with_prnu: bool = False
    allow_other_camera: bool = False
    roi: Region | None = None
    mask_path: str | None = None
    precision: str = "float"
    """EXR pixel type (:data:`camcal.io.exr.PRECISIONS`): ``float``, ``half`` or ``mixed`` (1σ channels in half)."""
    compression: str = "none"
    """EXR compression (:data:`camcal.io.exr.COMPRESSIONS`); the default is measured in docs/apply.md."""
    threads: int | None = None  # threads of one photo's arithmetic; None: the batch runner's share of the cores
    strict: bool = False
    """Refuse a photo whose f-number or focal length the flats were not measured at (:func:`camcal.apply.photo.
    plan_for_optics`); the rest of the batch goes on."""


@dataclass(frozen=True)
class PhotoResult:
    """Outcome of one photo: status ``done`` / ``skipped`` / ``failed``, the error line, ROI rows."""

    source: str
    output: str
    status: str
    error: str | None = None
    seconds: float = 0.0
    stats: tuple[dict, ...] = ()
    warning: str | None = None
    """The optics warning of the photo (its f-number or focal length differs from the flats'), from its EXR."""


@dataclass(frozen=True)
class BatchReport:
    results: tuple[PhotoResult, ...]
    outdir: str
    report_csv: str
    roi_csv: str | None = None
    counts: dict = field(default_factory=dict)
    estimator: str = ""
    """One line: the L<λ0> estimator, its unit and its spectral-reconstruction term (:meth:`RadianceModel.describe`)."""

    @property
    def failed(self) -> list[PhotoResult]:
        return [r for r in self.results if r.status == "failed"]

    @property
    def exit_code(self) -> int:
        """0 when every photo has its EXR, 1 when any failed."""
        return 1 if self.failed else 0


def output_path(photo: str | Path, outdir: str | Path) -> Path:
    """``OUTDIR/<photo file name>.exr``."""
    return Path(outdir) / f"{Path(photo).name}.exr"


# ---- per process state ---------------------------------------------------------------------------------------------
_PLANS: dict[tuple, object] = {}


def _plan(profile_path: str, options: BatchOptions, *, with_maps: bool = True):
    """The profile's ApplyPlan, loaded once per process and per (file, mtime, options).

    ``with_maps=False``: a plan of the profile without its per-pixel maps (identity and options
    checked, no dark or flat), not cached — for the runner when workers do the photos.
    """
    p = Path(profile_path)
    try:
        st = p.stat()
    except OSError:
        raise CamcalError("no such profile file", p) from None
    key = (str(p.resolve()), st.st_mtime_ns, st.st_size, options.wavelength_nm, options.estimator,
           options.filter_fwhm_nm, options.line_fwhm_nm, options.with_prnu)
    plan = _PLANS.get(key) if with_maps else None
    if plan is None:

        profile = load_profile(p, with_maps=with_maps)
        try:
            plan = prepare(profile, options.wavelength_nm, options.estimator, filter_fwhm_nm=options.filter_fwhm_nm,
                           line_fwhm_nm=options.line_fwhm_nm, with_prnu=options.with_prnu)
        except CamcalError as exc:  # e.g. "the profile has no spectral sensitivity": name the profile file
            if exc.path is not None:
                raise
            raise CamcalError(exc.message, p) from None
        if with_maps:
            _PLANS.clear()
            _PLANS[key] = plan
    return plan


PR_SET_PDEATHSIG = 1
"""``prctl`` option (linux/prctl.h): the signal a process receives when the thread that made it exits."""
PARENT_POLL_S = 0.5
"""Seconds between two looks at the parent's process id (the fallback where there is no parent-death signal)."""


def die_with_parent(parent_pid: int) -> str:
    """Make this process exit when ``parent_pid``, its parent, is gone; returns how (``"pdeathsig"``/``"poll"``).

    On Linux ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (the kernel kills this process when its parent dies); a
    watcher thread polling :func:`os.getppid` every :data:`PARENT_POLL_S` s is started in every case, as the
    portable fallback and to catch a parent that died before the signal was set (re-parented at once).
    """
    how = "poll"
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)  # the C library is loaded in every CPython process
            if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0:
                how = "pdeathsig"
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:  # the parent died before the signal was set
        _orphaned()
    threading.Thread(target=_watch_parent, args=(parent_pid,), name="camcal-parent-watch", daemon=True).start()
    return how


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    _orphaned()


def _orphaned() -> None:
    remove_pending()  # this worker's half-written files
    os._exit(1)


def _worker_init(parent_pid: int, profile_path: str, options: BatchOptions) -> None:
    """A pool worker's start: die with the parent, then load the profile once (shared by all its photos).

    A profile that fails to load here is left to fail per photo (one clear line each), not to break the pool.
    """
    die_with_parent(parent_pid)
    use_frame_allocator()
    try:
        _plan(profile_path, options)
    except Exception:  # noqa: BLE001 - reported by process_photo for every photo
        pass


def exr_header(path: Path) -> dict | None:
    """camcal attributes of an EXR header (no pixels), or None when it cannot be read (:func:`read_exr_header`)."""
    try:
        return read_exr_header(path)
    except CamcalError:
        return None


def _is_current(out: Path, profile_sha256: str | None, options: BatchOptions) -> bool:
    if not out.is_file():
        return False
    meta = exr_header(out)
    if not meta:
        return False
    wl = meta.get("wavelength_nm")
    asked = (meta.get("options") or {}).get("estimator", meta.get("estimator"))  # 'auto' and what it chose
    return (meta.get("profile_sha256") == profile_sha256 and asked == options.estimator
            and isinstance(wl, int | float) and math.isclose(float(wl), options.wavelength_nm)
            and (meta.get("options") or {}).get("filter_fwhm_nm") == options.filter_fwhm_nm
            and _precision_of(meta) == options.precision
            and meta.get("exr_compression") == options.compression
            and not (options.strict and (meta.get("optics") or {}).get("mismatch")))


def _precision_of(meta: dict) -> str:
    """The ``precision`` an EXR was written with, from its header: a ``mixed`` request whose 1σ values did not fit
    half (``uncertainty_precision`` "float (...)") is a ``mixed`` file with float32 pixels."""
    pixel_type = meta.get("exr_pixel_type")
    if pixel_type == "float" and str(meta.get("uncertainty_precision") or "").startswith("float"):
        return "mixed"
    return str(pixel_type)


_MASKS: dict[tuple, object] = {}


def _load_mask(options: BatchOptions):
    """The mask image of ``options``, read once per process and per (file, mtime, size), not once per photo."""
    if options.mask_path is None:
        return None
    p = Path(options.mask_path)
    try:
        st = p.stat()
    except OSError:
        return read_mask(p)  # reports the missing file
    key = (str(p.resolve()), st.st_mtime_ns, st.st_size)
    if key not in _MASKS:
        _MASKS.clear()
        _MASKS[key] = read_mask(p)
    return _MASKS[key]


def _stats(channels: dict, options: BatchOptions, mask_image, where: Path, meta: dict | None) -> tuple[dict, ...]:
    """ROI statistics of one output; ``meta`` its metadata (a linear RAW's output is at full resolution)."""
    if options.roi is None and options.mask_path is None:
        return ()

    shape = next(iter(channels.values())).shape
    scale = 1 if (meta or {}).get("resolution") in (LINEAR_RESOLUTION_NOTE, MONO_RESOLUTION_NOTE) else 2
    m = roi_mask(shape, options.roi, mask_image, where, scale=scale)
    units = (meta or {}).get("units") or {}
    rows = roi_statistics({k: channels[k] for k in sorted(channels, key=_channel_order)}, m)
    return tuple({**row, "unit": str(units.get(row["channel"], ""))} for row in rows)


def _channel_order(name: str) -> tuple:
    """One row order for a fresh result and one read back from its EXR: R, G, B, L<λ>, L<λ>_unc, R_unc, G_unc, B_unc."""
    rgb = {"R": 0, "G": 1, "B": 2}
    base = name.removesuffix("_unc")
    return (name.endswith("_unc") and base in rgb, rgb.get(base, 3), name.endswith("_unc"), name)


def exr_datetime(capture_time: str | None) -> str:
    """The EXR ``DateTime`` of an output: the photo's capture time (``YYYY:MM:DD HH:MM:SS``).

    Deterministic, so the same photo gives a byte-identical EXR wherever and whenever it is processed.
    """
    if capture_time and len(capture_time) >= 19 and capture_time[10] in "T ":
        return f"{capture_time[:10].replace('-', ':')} {capture_time[11:19]}"
    return "1970:01:01 00:00:00"


def process_photo(photo: str, profile_path: str, outdir: str, options: BatchOptions) -> PhotoResult:
    """Apply the profile to one photo and write its EXR; never raises (failures are a result).

    Skips the photo when its EXR is current (:func:`_is_current`).
    """
    return process_photos([photo], profile_path, outdir, options)[0]


def process_photos(photos: Sequence[str], profile_path: str, outdir: str, options: BatchOptions,
                   done: Callable[[PhotoResult], None] | None = None) -> list[PhotoResult]:
    """:func:`process_photo` for several photos in a row, photo k's EXR written while photo k+1 is decoded.

    The write runs in one background thread (OpenImageIO releases the GIL while it compresses and writes; LibRaw
    while it decodes), at most one write in flight: photo k+1 is decoded and corrected while k is written, then
    waits for that write before its own starts, so at most two photos' images are held whatever the number of
    photos. Each photo's result is known, and given to ``done``, when its EXR is renamed into place; a photo
    that fails does not stop the others.
    """
    results: list[PhotoResult] = []
    writing: tuple[Future, PhotoResult, float] | None = None

    def finish(r: PhotoResult) -> None:
        results.append(r)
        if done is not None:
            done(r)

    def settle() -> None:
        nonlocal writing
        if writing is not None:
            fut, pending, t0 = writing
            writing = None
            finish(_written(fut, pending, t0))

    with ThreadPoolExecutor(1, thread_name_prefix="camcal-write") as writer:
        for photo in photos:
            t0 = time.perf_counter()
            step = _compute_photo(photo, profile_path, outdir, options, t0)
            settle()  # photo k's write ends before photo k+1's starts: one write in flight
            if isinstance(step, PhotoResult):
                finish(step)
                continue
            image, pending, capture_time = step
            fut = writer.submit(write_exr, pending.output, image.channels, image.metadata,
                                precision=options.precision, compression=options.compression,
                                datetime=exr_datetime(capture_time))
            writing = (fut, pending, t0)
            del image, step
        settle()
    return results


def _compute_photo(photo: str, profile_path: str, outdir: str, options: BatchOptions, t0: float):
    """Decode and correct one photo: ``(image, result if written, capture time)``, or its final result."""
    src = Path(photo)
    out = output_path(src, outdir)
    try:
        plan = _plan(profile_path, options)
        mask_image = _load_mask(options)
        if _is_current(out, plan.profile.content_sha256, options):
            return _skipped(src, out, options, mask_image, t0)

        manifest = folder_manifest(src.parent) if (src.parent / "frames.csv").is_file() else {}
        frame = load_frame(src, exposure_overrides(manifest.get(src.name)))
        image = apply_prepared(frame, plan, allow_other_camera=options.allow_other_camera, threads=options.threads,
                               strict=options.strict)
        stats = _stats(image.channels, options, mask_image, src, image.metadata)
        return (image, PhotoResult(str(src), str(out), "done", None, 0.0, stats,
                                   (image.metadata.get("optics") or {}).get("warning")),
                frame.exposure.capture_time)
    except Exception as exc:  # a batch reports every failure and goes on
        return _failure(src, out, exc, t0)


def _written(fut: Future, pending: PhotoResult, t0: float) -> PhotoResult:
    """The result of a photo started at ``t0`` once its write ended."""
    try:
        fut.result()
    except Exception as exc:  # a batch reports every failure and goes on
        return _failure(Path(pending.source), Path(pending.output), exc, t0)
    return replace(pending, seconds=time.perf_counter() - t0)


def _failure(src: Path, out: Path, exc: BaseException, t0: float) -> PhotoResult:
    """A failed photo's result: its one-line error."""
    if isinstance(exc, CamcalError):
        error = str(exc)
    elif isinstance(exc, MemoryError):
        error = f"{src}: out of memory"
    else:
        msg = " ".join(f"{type(exc).__name__}: {exc}".split())
        error = f"{src}: internal error: {msg}"
    return PhotoResult(str(src), str(out), "failed", error, time.perf_counter() - t0)


def _skipped(src: Path, out: Path, options: BatchOptions, mask_image, t0: float) -> PhotoResult:
    """A photo whose EXR is current: nothing is computed; ROI statistics are read back from the EXR."""
    stats = ()
    if options.roi is not None or options.mask_path is not None:
        channels, meta = read_exr(out)
        stats = _stats(channels, options, mask_image, src, meta)
    else:
        meta = exr_header(out)
    return PhotoResult(str(src), str(out), "skipped", None, time.perf_counter() - t0, stats,
                       ((meta or {}).get("optics") or {}).get("warning"))


def _skip_current(photo: str, outdir: str, options: BatchOptions, mask_image) -> PhotoResult:
    """:func:`_skipped` for the runner, which already checked the header (no profile load here)."""
    t0 = time.perf_counter()
    src = Path(photo)
    out = output_path(src, outdir)
    try:
        return _skipped(src, out, options, mask_image, t0)
    except Exception as exc:  # a batch reports every failure and goes on
        return _failure(src, out, exc, t0)


# ---- the runner ------------------------------------------------------------------------------------------------------
def expand_photos(items: Sequence[str | Path]) -> list[Path]:
    """Files as given; folders expanded to their image files (not recursive). Duplicated output names refused."""

    photos: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            photos.extend(list_frames(p))
        else:
            photos.append(p)
    seen: dict[str, Path] = {}
    for p in photos:
        if p.name in seen and seen[p.name].resolve() != p.resolve():
            raise CamcalError(f"two photos share the file name {p.name} ({seen[p.name]} and {p}); their outputs "
                              "would collide: run them into different output folders", p)
        seen[p.name] = p
    unique = list({str(p.resolve()): p for p in photos}.values())
    if not unique:
        raise CamcalError("no photos given")
    return unique


def preflight(profile_path: str | Path, photos: Sequence[Path], options: BatchOptions, *, with_maps: bool = True):
    """Load the profile and refuse the batch (CamcalError, exit 2) when a photo's EXIF names another camera.

    Only the EXIF header is read (photos that cannot be read are left to fail in the batch).
    ``with_maps=False`` when workers do the photos: the maps are verified by hash, not decoded here.
    """

    default_threads()  # a bad CAMCAL_THREADS refuses the batch here, not every photo
    plan = _plan(str(profile_path), options, with_maps=with_maps)
    mask = _load_mask(options) if options.roi is None and options.mask_path is not None else None
    cam = plan.profile.camera
    if (options.roi is not None or mask is not None) and cam.width and cam.height and photos:

        # RAW photos of the profile's camera have its sensor size: a region that does not fit it is a
        # bad option of the whole batch (exit 2, naming the mask), not a failure of every photo
        if all(is_raw_path(Path(p)) for p in photos):
            linear = getattr(cam, "layout", "bayer") == "linear"
            roi_mask((cam.height, cam.width) if linear else (cam.height // 2, cam.width // 2),
                     options.roi if mask is None else None, mask, options.mask_path if mask is not None else "--roi",
                     scale=1 if linear else 2)
    if not options.allow_other_camera:
        for p in photos:
            try:
                exp = exposure_from_exif(p)
            except Exception:  # noqa: BLE001 - unreadable files fail later, per photo
                continue
            if exp.make or exp.model:
                if could_match(Sensor(exp.make, exp.model), sensor_of_profile(plan.profile.camera)):
                    continue  # one camera, perhaps under a writer's name: the photo's own check decides
            check_camera(exp, plan.profile, p, False)
    return plan


def _earlier_rows(path: Path, header: list[str]) -> str:
    """The data rows of an earlier report with the same header (text, each line ending in a newline), else ''."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return ""
    first, _, rest = text.partition("\n")
    return rest if first.strip() == ",".join(header) and rest.strip() else ""


def _write_reports(outdir: Path, results: list[PhotoResult], options: BatchOptions) -> tuple[Path, Path | None]:

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    header = ["file", "status", "output", "seconds", "error", "warning"]
    w.writerow(header)
    earlier = _earlier_rows(outdir / REPORT_CSV, header)
    if earlier:  # a rerun into the same folder appends: the earlier runs' rows stay
        buf.write(earlier)
    for r in results:
        w.writerow([r.source, r.status, r.output if r.status != "failed" else "", f"{r.seconds:.3f}", r.error or "",
                    r.warning or ""])
    report = atomic_write_text(outdir / REPORT_CSV, buf.getvalue())
    roi_csv = None
    if options.roi is not None or options.mask_path is not None:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        region = (f"roi {options.roi}" if options.roi is not None
                  else f"mask {options.mask_path}")
        w.writerow(["file", "channel", "n", "mean", "median", "sigma", "unit", "region"])
        for r in results:
            for row in r.stats:
                w.writerow([Path(r.source).name, row["channel"], row["n"], repr(row["mean"]), repr(row["median"]),
                            repr(row["sigma"]), row.get("unit", ""), region])
        roi_csv = atomic_write_text(outdir / ROI_CSV, buf.getvalue())
    return report, roi_csv


def run_batch(
    profile_path: str | Path,
    photos: Sequence[str | Path],
    outdir: str | Path,
    options: BatchOptions | None = None,
    *,
    jobs: int | None = 1,
    scheduler: str | object | None = None,
    progress: Callable[[int, int, PhotoResult], None] | None = None,
) -> BatchReport:
    """Apply a profile to many photos (module docstring: outputs, resuming, failures).

    Parameters
    ----------
    profile_path : the ``.camcal`` profile.
    photos : photo files and/or folders.
    outdir : output folder (created).
    options : :class:`BatchOptions`.
    jobs : worker processes for the local pool (1: in this process; None: the usable cores).
    scheduler : a dask.distributed scheduler address (``tcp://host:8786``), or a ``Client`` /
        ``LocalCluster`` object; None uses the local process pool.
    progress : ``progress(done, total, result)``.

    Raises
    ------
    CamcalError
        Unreadable profile, photos of another camera (without ``allow_other_camera``), colliding names,
        a bad ROI/mask. Per-photo failures are reported, not raised.
    """
    options = options or BatchOptions()
    jobs = usable_cores() if jobs is None else jobs
    outdir = Path(outdir)
    paths = expand_photos(photos)
    if progress is not None:  # the total is known before the profile is loaded
        progress(0, len(paths), None)
    plan = preflight(profile_path, paths, options, with_maps=scheduler is None and jobs <= 1)
    outdir.mkdir(parents=True, exist_ok=True)
    profile_path = str(Path(profile_path).resolve())
    # absolute, not resolved: a photo reached through a symbolic link keeps its folder's frames.csv and
    # session.toml (the folder the user named), not those beside the link's target
    args = [(os.path.abspath(p), profile_path, str(outdir.resolve()), options) for p in paths]
    total = len(args)
    results: dict[str, PhotoResult] = {}

    def done(r: PhotoResult) -> None:
        results[r.source] = r
        if progress is not None:
            progress(len(results), total, r)

    # outputs already written with this profile and these options: skipped here, no worker started
    todo = []
    mask_image = _load_mask(options) if options.mask_path is not None else None
    leftovers = any(outdir.glob(".*.part*"))  # one listing of the folder, not one per photo
    for a in args:
        if leftovers:
            clear_stale(output_path(a[0], a[2]))  # temporary files of a killed earlier run
        if _is_current(output_path(a[0], a[2]), plan.profile.content_sha256, options):
            done(_skip_current(a[0], a[2], options, mask_image))  # the header (and pixels for ROI statistics)
        else:
            todo.append(a)
    if not todo:
        pass
    elif scheduler is not None:  # a dask worker runs as many photos at once as it has threads
        _run_dask(_with_threads(todo, 1), scheduler, done)
    elif jobs <= 1 or len(todo) == 1:
        process_photos([a[0] for a in todo], *todo[0][1:], done=done)
    else:
        workers = min(jobs, len(todo))

        _run_pool(_with_threads(todo, max(1, default_threads() // workers)), workers, done)
    ordered = [results[a[0]] for a in args]
    report, roi_csv = _write_reports(outdir, ordered, options)
    counts = {s: sum(r.status == s for r in ordered) for s in STATUSES}
    return BatchReport(tuple(ordered), str(outdir), str(report), None if roi_csv is None else str(roi_csv), counts,
                       plan.model.describe())


def _with_threads(args: list[tuple], threads: int) -> list[tuple]:
    """``args`` with the photo-arithmetic threads set, unless the options already say."""
    return [(*a[:3], a[3] if a[3].threads is not None else replace(a[3], threads=threads)) for a in args]


CHUNK_PHOTOS = 4
"""Photos per pool task at most: within a task each write overlaps the next photo's decode
(:func:`process_photos`); small enough that the workers finish together and progress moves."""


def _chunks(args: list[tuple], workers: int) -> list[list[tuple]]:
    """``args`` cut into tasks of up to :data:`CHUNK_PHOTOS` photos, at least two tasks per worker when possible."""
    size = max(1, min(CHUNK_PHOTOS, len(args) // (2 * workers)))
    return [args[i:i + size] for i in range(0, len(args), size)]


def _process_chunk(args: list[tuple]) -> list[PhotoResult]:
    """A pool task: :func:`process_photos` over photos that share the profile, output folder and options."""
    return process_photos([a[0] for a in args], *args[0][1:])


def _run_pool(args: list[tuple], jobs: int, done: Callable[[PhotoResult], None]) -> None:
    ctx = multiprocessing.get_context("spawn")  # no fork of a process holding threads (progress bar, OIIO)
    workers = min(jobs, len(args))
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                             initargs=(os.getpid(), args[0][1], args[0][3])) as pool:
        futures = {pool.submit(_process_chunk, chunk): chunk for chunk in _chunks(args, workers)}
        for fut in as_completed(futures):
            try:
                results = fut.result()
            except BrokenProcessPool:
                results = [PhotoResult(a[0], str(output_path(a[0], a[2])), "failed",
                                       f"{a[0]}: worker process died (out of memory?)") for a in futures[fut]]
            for r in results:
                done(r)


def _run_dask(args: list[tuple], scheduler, done: Callable[[PhotoResult], None]) -> None:
    try:
        from dask.distributed import Client, as_completed  # optional dependency (dask), ~0.7 s at import
    except ImportError:
        raise CamcalError("--dask-scheduler needs dask.distributed (pip install 'dask[distributed]')") from None
    own = False
    if isinstance(scheduler, str):
        try:
            client = Client(scheduler, timeout="60s")
        except (OSError, TimeoutError) as exc:
            raise CamcalError(f"cannot connect to the dask scheduler {scheduler}: {exc}") from None
        own = True
    elif hasattr(scheduler, "submit"):
        client = scheduler
    else:
        client = Client(scheduler)
        own = True
    try:
        futures = [client.submit(process_photo, *a, pure=False) for a in args]
        index = {f.key: a for f, a in zip(futures, args, strict=True)}
        for fut in as_completed(futures):
            a = index[fut.key]
            try:
                done(fut.result())
            except Exception as exc:  # noqa: BLE001 - a lost worker is a failed photo, not a failed batch
                done(PhotoResult(a[0], str(output_path(a[0], a[2])), "failed",
                                 f"{a[0]}: dask task failed: {type(exc).__name__}: {exc}"))
    finally:
        if own:
            client.close()


def report_rows(report: BatchReport) -> list[dict]:
    """JSON-ready rows of a report."""
    return [{k: v for k, v in asdict(r).items() if k != "stats"} for r in report.results]

"""The EMVA 1288 descriptor file (the standard's exchange format) and the frames it lists: a thin adapter.

A descriptor (release 3.0 and 4.0 use the same lines) is text, ``#`` starts a comment::

    v 3.0                      release of the standard the measurement follows
    n 12 640 480               bits per pixel, width, height
    b 40000.0 120.0            bright step: exposure time (ns), mean photons per pixel
    i images\\b_000_snap_001.png  the step's images (two: a temporal pair; more: the spatial stack)
    d 40000.0                  dark step: exposure time (ns)

Paths are relative to the descriptor's folder, written with ``\\`` or ``/``; a path that leaves that folder
(absolute, or through ``..``) is refused. Sizes are bounded before anything is read
(:data:`camcal.io.limits.MAX_EMVA_IMAGES`, :data:`camcal.io.limits.MAX_EMVA_STEPS`, the pixel limit). The frames are
read with :func:`camcal.io.read.read_monochrome`, two at a time for the pairs and one at a time into running sums for
the spatial stacks (:class:`camcal.calibrate.emva_standard.StackAccumulator`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from camcal.calibrate.emva_standard import SpatialStack, StackAccumulator, TemporalSeries, pair_moments
from camcal.errors import CamcalError
from camcal.io.limits import MAX_EMVA_IMAGES, MAX_EMVA_STEPS, max_pixels
from camcal.io.manifest import read_text_file
from camcal.io.read import read_monochrome

RELEASES = ("3.0", "3.1", "4.0")
"""Releases of the standard whose descriptor camcal reads."""

NS_PER_S = 1e9


@dataclass(frozen=True)
class Step:
    """One ``b`` or ``d`` line: exposure time (s), photons per pixel (0 for dark) and its images' paths."""

    exposure_s: float
    photons: float
    images: tuple[Path, ...]
    line: int

    @property
    def dark(self) -> bool:
        return self.photons == 0.0


@dataclass(frozen=True)
class Descriptor:
    """A parsed descriptor: release, bit depth, frame size and steps (in file order)."""

    path: Path
    release: str
    bits: int
    width: int
    height: int
    steps: tuple[Step, ...]

    @property
    def temporal(self) -> tuple[Step, ...]:
        """Steps of exactly two images (the photon-transfer pairs)."""
        return tuple(s for s in self.steps if len(s.images) == 2)

    @property
    def spatial(self) -> tuple[Step, ...]:
        """Steps of more than two images (the spatial stacks)."""
        return tuple(s for s in self.steps if len(s.images) > 2)


def _number(text: str, path: Path, line: int, what: str) -> float:
    try:
        v = float(text.replace(",", "."))
    except ValueError:
        raise CamcalError(f"line {line}: {what} {text!r} is not a number", path) from None
    if not math.isfinite(v) or v < 0:
        raise CamcalError(f"line {line}: {what} {text!r} is not a finite value ≥ 0", path)
    return v


def _image_path(text: str, folder: Path, path: Path, line: int) -> Path:
    rel = PurePosixPath(text.replace("\\", "/"))
    if rel.is_absolute() or (rel.parts and rel.parts[0].endswith(":")) or text.startswith(("\\", "/")):
        raise CamcalError(f"line {line}: image path {text!r} is absolute; paths must be relative to the "
                          "descriptor's folder", path)
    full = (folder / Path(*rel.parts)).resolve()
    if not full.is_relative_to(folder.resolve()):
        raise CamcalError(f"line {line}: image path {text!r} leaves the descriptor's folder; refused", path)
    return full


def parse_descriptor(text: str, path: str | Path) -> Descriptor:
    """Parse the text of a descriptor file at ``path`` (used for the folder of its images and in messages)."""
    path = Path(path)
    folder = path.parent
    release = None
    fmt: tuple[int, int, int] | None = None
    steps: list[Step] = []
    current: tuple[float, float, int] | None = None
    images: list[Path] = []
    n_images = 0

    def close() -> None:
        if current is not None:
            if len(images) < 2:
                raise CamcalError(f"line {current[2]}: a step needs two or more images, it has {len(images)}", path)
            steps.append(Step(current[0], current[1], tuple(images), current[2]))

    for no, raw in enumerate(text.splitlines(), 1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split(maxsplit=1) if s[:1] == "i" else s.split()
        key = parts[0]
        if key == "v":
            if len(parts) != 2 or parts[1] not in RELEASES:
                raise CamcalError(f"line {no}: release {' '.join(parts[1:])!r}; camcal reads descriptors of "
                                  f"release {', '.join(RELEASES)}", path)
            release = parts[1]
        elif key == "n":
            if len(parts) != 4 or fmt is not None:
                raise CamcalError(f"line {no}: expected one line 'n bits width height'", path)
            try:
                bits, w, h = (int(p) for p in parts[1:])
            except ValueError:
                raise CamcalError(f"line {no}: 'n bits width height' needs integers", path) from None
            if not 1 <= bits <= 16:
                raise CamcalError(f"line {no}: {bits} bits per pixel; camcal reads 1 to 16", path)
            if w <= 0 or h <= 0 or w * h > max_pixels():
                raise CamcalError(f"line {no}: {w}x{h} pixels is empty or above the limit of {max_pixels()}", path)
            fmt = (bits, w, h)
        elif key in ("b", "d"):
            want = 3 if key == "b" else 2
            if len(parts) != want:
                raise CamcalError(f"line {no}: expected '{'b exposure_ns photons' if key == 'b' else 'd exposure_ns'}'",
                                  path)
            close()
            images = []
            t = _number(parts[1], path, no, "exposure time") / NS_PER_S
            p = _number(parts[2], path, no, "photon count") if key == "b" else 0.0
            if key == "b" and p == 0.0:
                raise CamcalError(f"line {no}: a bright step with 0 photons", path)
            current = (t, p, no)
            if len(steps) >= MAX_EMVA_STEPS:
                raise CamcalError(f"more than {MAX_EMVA_STEPS} steps; refused", path)
        elif key == "i":
            if current is None:
                raise CamcalError(f"line {no}: an image before any 'b' or 'd' step", path)
            if len(parts) != 2:
                raise CamcalError(f"line {no}: expected 'i path'", path)
            n_images += 1
            if n_images > MAX_EMVA_IMAGES:
                raise CamcalError(f"more than {MAX_EMVA_IMAGES} images; refused", path)
            images.append(_image_path(parts[1].strip(), folder, path, no))
        else:
            raise CamcalError(f"line {no}: unknown line {s[:40]!r} (expected v, n, b, d or i)", path)
    close()
    if release is None:
        raise CamcalError("no 'v' line: the release of the standard is unknown", path)
    if fmt is None:
        raise CamcalError("no 'n bits width height' line", path)
    if not steps:
        raise CamcalError("lists no step", path)
    return Descriptor(path, release, fmt[0], fmt[1], fmt[2], tuple(steps))


def read_descriptor(path: str | Path) -> Descriptor:
    """Read and parse a descriptor file (bounded read, :func:`camcal.io.manifest.read_text_file`)."""
    return parse_descriptor(read_text_file(path, "EMVA 1288 descriptor"), path)


@dataclass(frozen=True)
class Measurement:
    """The moments of a descriptor's frames: the photon-transfer series and the spatial stacks (or None)."""

    descriptor: Descriptor
    series: TemporalSeries
    bright: SpatialStack | None
    dark: SpatialStack | None
    notes: tuple[str, ...] = ()


def _frame(path: Path, d: Descriptor) -> np.ndarray:
    a = read_monochrome(path)
    if a.shape != (d.height, d.width):
        raise CamcalError(f"is {a.shape[1]}x{a.shape[0]}, the descriptor says {d.width}x{d.height}", path)
    if int(a.max()) >= 2**d.bits:
        raise CamcalError(f"holds {int(a.max())}, above the descriptor's {d.bits}-bit range", path)
    return a


def load_measurement(d: Descriptor, progress: Callable[[int, int], None] | None = None) -> Measurement:
    """Read every frame ``d`` lists into its moments (one pair or one stack frame in memory at a time)."""
    total = sum(len(s.images) for s in d.steps)
    done = 0

    def tick(n: int) -> None:
        nonlocal done
        done += n
        if progress is not None:
            progress(done, total)

    darks: dict[float, tuple[float, float, float]] = {}
    bright: list[tuple[float, float, float, float, float]] = []
    for s in d.temporal:
        m, v, u = pair_moments(_frame(s.images[0], d), _frame(s.images[1], d))
        tick(2)
        if s.dark:
            if s.exposure_s in darks:
                raise CamcalError(f"line {s.line}: a second dark pair at {s.exposure_s * NS_PER_S:g} ns", d.path)
            darks[s.exposure_s] = (m, v, u)
        else:
            bright.append((s.exposure_s, s.photons, m, v, u))
    missing = sorted({t for t, *_ in bright if t not in darks})
    if missing:
        raise CamcalError(f"no dark pair at exposure time {missing[0] * NS_PER_S:g} ns (the standard needs one "
                          "per exposure time)", d.path)
    if len(bright) < 2:
        raise CamcalError("fewer than two bright pairs: no photon transfer", d.path)
    td = np.array(sorted(darks))
    series = TemporalSeries(
        exposure_s=np.array([b[0] for b in bright]), photons=np.array([b[1] for b in bright]),
        mean_dn=np.array([b[2] for b in bright]), variance_dn2=np.array([b[3] for b in bright]),
        dark_mean_dn=np.array([darks[b[0]][0] for b in bright]),
        dark_variance_dn2=np.array([darks[b[0]][1] for b in bright]),
        dark_exposure_s=td, dark_series_mean_dn=np.array([darks[t][0] for t in td]),
        dark_series_variance_dn2=np.array([darks[t][1] for t in td]),
        variance_unc_dn2=np.array([b[4] for b in bright]),
        dark_variance_unc_dn2=np.array([darks[b[0]][2] for b in bright]),
    )
    notes: list[str] = []
    stacks: dict[bool, SpatialStack] = {}
    sp = d.spatial
    exposures = {s.exposure_s for s in sp}
    if len(exposures) > 1:
        raise CamcalError("spatial stacks at more than one exposure time; the standard takes one", d.path)
    for s in sp:
        if s.dark in stacks:
            raise CamcalError(f"line {s.line}: a second {'dark' if s.dark else 'bright'} spatial stack", d.path)
        acc = StackAccumulator()
        for img in s.images:
            acc.add(_frame(img, d))
            tick(1)
        stacks[s.dark] = acc.result(s.exposure_s, float("nan") if s.dark else s.photons)
    if not sp:
        notes.append("no spatial stacks (steps of more than two images): DSNU₁₂₈₈ and PRNU₁₂₈₈ unknown")
    return Measurement(d, series, stacks.get(False), stacks.get(True), tuple(notes))

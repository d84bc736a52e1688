"""Camera identity across software names: when two files come from one camera.

Files of one camera do not always name it the same way. The make is spelled differently by different
writers ("RaspberryPi", "Raspberry Pi"), and some writers put their own name in the model tag: PiDNG
writes ``PiDNG / PiCamera2`` where picamera2 writes the sensor, ``imx296``. Two descriptions are one camera
when

- their makes normalise to the same name (case, spaces and punctuation ignored), and
- their models normalise to the same name, or one of them is a writer's placeholder
  (:data:`WRITER_PLACEHOLDERS`) and the sensor agrees: the same geometry, CFA pattern, layout and, where
  both are known, black and white levels.

Anything else is a real conflict. A file with neither make nor model cannot be checked (the caller says so).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

#: Model tags that name the software that wrote the file, not the camera (normalised, see :func:`normalise`).
WRITER_PLACEHOLDERS = ("pidng", "picamera")


def normalise(name: str | None) -> str:
    """Lower case, letters and digits only: ``"Raspberry Pi"`` and ``"RaspberryPi"`` give ``"raspberrypi"``."""
    return re.sub(r"[^0-9a-z]", "", str(name or "").lower())


def is_placeholder(model: str | None) -> bool:
    """True when a model tag names the writing software (PiDNG's ``PiDNG / PiCamera2``), not the camera."""
    m = normalise(model)
    return any(p in m for p in WRITER_PLACEHOLDERS)


@dataclass(frozen=True)
class Sensor:
    """What a file says about its sensor: make and model tags, full-resolution size, CFA, layout, levels (DN)."""

    make: str | None
    model: str | None
    width: int | None = None
    height: int | None = None
    cfa_pattern: str | None = None
    layout: str | None = None
    black_level_dn: tuple[float, ...] | None = None
    white_level_dn: float | None = None

    @property
    def label(self) -> str:
        return " ".join(str(v) for v in (self.make, self.model) if v) or "an unnamed camera"


def _same_sensor(a: Sensor, b: Sensor) -> bool:
    """Geometry, CFA and layout equal; levels equal where both are known."""
    for x, y in ((a.width, b.width), (a.height, b.height), (a.cfa_pattern, b.cfa_pattern), (a.layout, b.layout)):
        if x is None or y is None or x != y:
            return False
    if a.black_level_dn is not None and b.black_level_dn is not None:
        if tuple(round(float(v), 3) for v in a.black_level_dn) != tuple(round(float(v), 3) for v in b.black_level_dn):
            return False
    if a.white_level_dn is not None and b.white_level_dn is not None:
        if round(float(a.white_level_dn), 3) != round(float(b.white_level_dn), 3):
            return False
    return True


def match(a: Sensor, b: Sensor) -> tuple[bool, str | None]:
    """(one camera?, a note when they are one camera under different names, else None).

    Same make and model (normalised): one camera, no note. Same make, one model a writer's placeholder,
    same sensor: one camera, with a note naming both spellings. Anything else: not one camera.
    """
    if normalise(a.make) != normalise(b.make):
        return False, None
    if normalise(a.model) == normalise(b.model):
        if (a.make, a.model) != (b.make, b.model):
            return True, f"{a.label} and {b.label}: one camera (names differ only in spelling)"
        return True, None
    if (is_placeholder(a.model) or is_placeholder(b.model)) and _same_sensor(a, b):
        return True, (f"{a.label} and {b.label}: one camera (the model tag names the writing software; the sensor "
                      "geometry, CFA and levels agree)")
    return False, None


def preferred(sensors: list[Sensor]) -> Sensor:
    """The description to record for one camera: the first whose model is not a writer's placeholder."""
    return next((s for s in sensors if s.model and not is_placeholder(s.model)), sensors[0])


def sensor_of(frame) -> Sensor:
    """The :class:`Sensor` of a decoded :class:`camcal.frame.Frame` (tags, size, CFA, layout, levels)."""
    h, w = frame.shape[:2]
    black = tuple(float(v) for v in frame.black_vector().ravel())
    white = getattr(frame, "white_level_dn", None)
    return Sensor(frame.exposure.make, frame.exposure.model, int(w), int(h), frame.cfa_pattern, frame.layout, black,
                  None if white is None else float(white))


def sensor_of_profile(camera) -> Sensor:
    """The :class:`Sensor` a profile's :class:`camcal.models.profile.CameraIdentity` records (no levels)."""
    return Sensor(camera.make, camera.model, camera.width, camera.height, camera.cfa_pattern,
                  getattr(camera, "layout", None))


def could_match(a: Sensor, b: Sensor) -> bool:
    """True when the tags alone do not rule out one camera (the sensor decides; see :func:`match`)."""
    if normalise(a.make) != normalise(b.make):
        return False
    return normalise(a.model) == normalise(b.model) or is_placeholder(a.model) or is_placeholder(b.model)

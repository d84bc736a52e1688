"""The one exception type for problems a user can fix.

Every :class:`CamcalError` renders as a single line that names the file (when
there is one) and the problem; the CLI prints it to stderr and exits with code 2.
"""

from __future__ import annotations

from pathlib import Path


class CamcalError(Exception):
    """A user-facing error: bad input, missing metadata, an impossible request.

    Parameters
    ----------
    message : str
        What is wrong, and where possible how to fix it.
    path : str or Path, optional
        The file or folder concerned; it leads the rendered line.
    """

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        self.message = " ".join(str(message).split())  # one line, always
        self.path = None if path is None else Path(path)
        super().__init__(self.__str__())

    def __str__(self) -> str:
        return f"{self.path}: {self.message}" if self.path is not None else self.message


class MissingMetadataError(CamcalError):
    """A stage needs an exposure value the file and the manifest do not give."""

    def __init__(self, path: str | Path, field: str) -> None:
        super().__init__(
            f"missing {field}: not in the file's metadata; add a '{field}' column for this file "
            f"to frames.csv in its folder (columns: file,exposure_s,iso,f_number), or, when every frame "
            f"shares it (a fixed lens), '{field} = N' to session.toml in the folder or its parent",
            path,
        )
        self.field = field


class TooFewFrames(CamcalError):
    """A stage has fewer usable frames (or exposures, or wavelengths) than its fit needs.

    ``camcal calibrate`` leaves such a stage out of the profile and goes on with the others (exit code 1);
    with ``--strict``, or when a stage runs on its own, it is an error like any other.

    Parameters
    ----------
    stage : the stage (``bias``, ``dark``, ``flat``, ``linearity``, ``sweep``).
    what : what is counted, plural (``"distinct exposures"``, ``"wavelengths"``).
    needed, remaining : how many the fit needs and how many are usable.
    detail : what was left out, or why, appended to the message.
    """

    def __init__(self, stage: str, what: str, needed: int, remaining: int, detail: str = "",
                 path: str | Path | None = None) -> None:
        self.stage, self.what, self.needed, self.remaining = stage, what, int(needed), int(remaining)
        tail = f" ({detail})" if detail else ""
        super().__init__(f"the {stage} stage needs at least {needed} usable {what}, {remaining} remain{tail}", path)


class FrameLeftOut(UserWarning):
    """A stage left a frame out and goes on without it (``camcal calibrate`` lists these in its summary table
    and the profile's ``provenance.left_out`` rather than as warnings)."""

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

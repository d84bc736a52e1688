"""Old option spellings, kept for one release: each is rewritten to its new name with one deprecation line.

The CLI vocabulary (docs/cli.md): ``-o/--output`` for every output path, ``--jobs`` = CPU cores to use,
option names that say which model they choose (``--water-model``, ``--vignetting-model``, ``--camera``),
``--sweep-mode``, ``--plot/--no-plot``. :data:`DEPRECATED` maps a command path (its words, e.g.
``("water", "invert")``) to ``{old option: new option}``; :func:`rewrite` applies it to an argument list
before the app parses it, so the commands themselves know only the new names.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

#: The release after which the old spellings are removed.
REMOVED_IN = "0.3"

_WATER = {"--model": "--water-model", "--out": "--output"}

#: Command path → {old spelling: new spelling}.
DEPRECATED: dict[tuple[str, ...], dict[str, str]] = {
    ("water", "invert"): _WATER,
    ("water", "forward"): _WATER,
    ("water", "simulate"): {"--out": "--output"},
    ("linearity",): {"--out": "--output"},
    ("demo",): {"--out": "--output"},
    ("flat",): {"--model": "--vignetting-model"},
    ("sweep",): {"--mode": "--sweep-mode"},
    ("calibrate",): {"--flat-model": "--vignetting-model"},
    ("profile", "import-spectral"): {"--model": "--camera-model"},
}


def _command_path(argv: Sequence[str]) -> tuple[str, ...]:
    """The leading words of ``argv`` up to the first option (the command and sub-command, perhaps an argument)."""
    words: list[str] = []
    for a in argv:
        if a.startswith("-"):
            break
        words.append(a)
    return tuple(words)


def table_for(argv: Sequence[str]) -> dict[str, str]:
    """The deprecated spellings of the command ``argv`` runs (longest matching command path)."""
    path = _command_path(argv)
    best: tuple[str, ...] = ()
    for key in DEPRECATED:
        if path[: len(key)] == key and len(key) > len(best):
            best = key
    return DEPRECATED.get(best, {})


def rewrite(argv: Sequence[str], warn=None) -> list[str]:
    """``argv`` with every deprecated option spelling replaced by its new name; one line per old spelling used.

    ``--old=value`` becomes ``--new=value``. Arguments after ``--`` are left alone.
    """
    table = table_for(argv)
    if not table:
        return list(argv)
    warn = warn or (lambda line: print(line, file=sys.stderr))
    out: list[str] = []
    seen: set[str] = set()
    rest = False
    for a in argv:
        if rest or a == "--":
            rest = True
            out.append(a)
            continue
        name, eq, value = a.partition("=")
        if name in table:
            new = table[name]
            if name not in seen:
                seen.add(name)
                warn(f"camcal: deprecated: {name} is now {new} ({name} is removed in camcal {REMOVED_IN})")
            out.append(new + eq + value)
        else:
            out.append(a)
    return out

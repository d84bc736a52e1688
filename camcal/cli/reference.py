"""``docs/cli.md``: every command and option, generated from the Typer app, and the naming rules it keeps.

Regenerate with ``python -m camcal.cli.reference > docs/cli.md``; ``tests/cli/test_reference.py`` checks the
file is current and that every command (including ones added later) follows :data:`RULES`.
"""

from __future__ import annotations

import sys

import typer

from camcal.cli import app, register_commands

#: The CLI vocabulary, as the test enforces it.
RULES = (
    "every output path is `-o/--output` (and `-o` is never anything else)",
    "`--jobs` (`-j`) is the number of CPU cores to use, whatever the worker kind; its help starts with "
    "\"CPU cores to use\"",
    "an option that picks a model names which one: `--water-model`, `--vignetting-model`, `--camera` "
    "(no bare `--model`)",
    "the sweep's units are `--sweep-mode` (no bare `--mode`)",
    "plots are `--plot/--no-plot` (no visible `--png`)",
    "every pixel option (`--roi`, `*-px`) is in photo pixels at full resolution, and its help says so",
    "percentages are accepted as `3%` or the fraction `0.03`",
)


def commands() -> list[tuple[str, object]]:
    """(full command name, click command) of every leaf command of the app, in help order."""
    register_commands()
    root = typer.main.get_command(app)
    out: list[tuple[str, object]] = []

    def walk(prefix: str, cmd) -> None:
        if hasattr(cmd, "list_commands"):
            for name in cmd.list_commands(None):
                walk(f"{prefix} {name}".strip(), cmd.get_command(None, name))
        else:
            out.append((prefix, cmd))

    walk("", root)
    return out


def options(cmd) -> list[dict]:
    """The visible parameters of ``cmd``: names, kind, default, help."""
    rows = []
    for p in cmd.params:
        if getattr(p, "hidden", False):
            continue
        kind = "argument" if p.param_type_name == "argument" else "option"
        names = list(p.opts) + [f"{s}" for s in getattr(p, "secondary_opts", [])]
        default = p.default
        if callable(default) or default is None or kind == "argument":
            default = ""
        rows.append({"names": names, "kind": kind, "required": bool(p.required),
                     "default": str(default), "help": " ".join((getattr(p, "help", None) or "").split()),
                     "metavar": p.name or ""})
    return rows


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def render() -> str:
    """The Markdown of docs/cli.md."""
    lines = ["# Command-line reference", "",
             "Generated from the app by `python -m camcal.cli.reference > docs/cli.md`; "
             "`tests/cli/test_reference.py` keeps it current. Do not edit by hand.", "",
             "## Naming rules", ""]
    lines += [f"- {r}" for r in RULES]
    lines.append("")
    for name, cmd in commands():
        lines += [f"## `camcal {name}`", "", _cell(" ".join((cmd.help or "").split("\n\n")[0].split())), "",
                  "| argument / option | default | meaning |", "|---|---|---|"]
        for o in options(cmd):
            label = (o["metavar"].upper() if o["kind"] == "argument" else " / ".join(o["names"]))
            default = "required" if o["required"] else o["default"]
            lines.append(f"| `{_cell(label)}` | {_cell(default)} | {_cell(o['help'])} |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover - a maintenance script
    sys.stdout.write(render())

"""The ``camcal`` command line: a thin layer that parses arguments and calls the library.

Each command group lives in its own module exposing ``register(app)``; :data:`COMMAND_MODULES` lists them
all, explicitly. A run imports only the module of the command it runs (:func:`register_commands`): importing
every command module costs ~0.35 s at start-up (benchmarks/RESULTS.md, "Start-up"), most of it scipy and
the stage modules a ``--version`` or an ``inspect`` never uses. ``--help`` and an unknown command load them
all. A command module that fails to import is an error, never a silently missing command.
:func:`main` turns every user error into one line on stderr and exit code 2.
"""

from __future__ import annotations

import importlib
import sys
import warnings
from collections.abc import Sequence

import typer

try:  # typer >= 0.20 vendors click as ``typer._click``; older versions raise click's own
    from typer._click.exceptions import ClickException
except ImportError:  # pragma: no cover - depends on the installed typer
    from click.exceptions import ClickException

from camcal import __version__
from camcal.errors import CamcalError
from camcal.io.allocator import use_frame_allocator
from camcal.io.atomic import remove_pending

app = typer.Typer(
    name="camcal",
    help="Turn a consumer camera into a calibrated radiometer for water-quality science.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

#: Commands (``camcal NAME``) in help order; each is implemented by ``camcal.cli.NAME_cmd.register(app)``.
COMMAND_MODULES = (
    "demo", "inspect", "synth", "dark", "flat", "linearity", "sweep", "calibrate", "chart", "profile", "curves",
    "report", "apply", "water", "secchi", "rrs", "emva",
)


def _version(value: bool) -> None:
    if value:
        typer.echo(f"camcal {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Show the version."),
) -> None:
    """camcal: camera calibration for radiometry (see README.md)."""


def register_commands(names: Sequence[str] = COMMAND_MODULES) -> None:
    """Import the command modules ``names`` (default all) and register their commands on :data:`app`, once each.

    An import error propagates: a command that cannot load is a defect, not an absent command.
    """
    for name in COMMAND_MODULES:  # help order, whatever the order asked
        if name in names and name not in _registered():
            importlib.import_module(f"camcal.cli.{name}_cmd").register(app)


def _registered() -> set[str]:
    """Names of the commands and command groups on :data:`app` (the app itself is the record)."""
    return {c.name for c in app.registered_commands} | {g.name for g in app.registered_groups}


def commands_for(argv: Sequence[str]) -> tuple[str, ...]:
    """The command modules a run with arguments ``argv`` needs.

    The first argument that is not an option names the command (the root takes only ``--version`` and
    ``--help``, neither with a value): that command's module alone. ``--version`` with no command needs none;
    anything else (``--help``, no arguments, an unknown command) needs all, so help lists every command and an
    unknown name gets its suggestions.
    """
    words = [a for a in argv if not a.startswith("-")]
    if words:
        return (words[0],) if words[0] in COMMAND_MODULES else COMMAND_MODULES
    if "--version" in argv and "--help" not in argv:
        return ()
    return COMMAND_MODULES


def _usage_error_type() -> type[Exception]:
    """Typer >= 0.20 vendors click as ``typer._click``; older versions raise click's own."""
    return ClickException


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit code (0 ok, 1 partial failure, 2 user error, 3 internal error)."""

    try:
        return _main(argv)
    finally:  # an interrupt in a window no ``except`` covers must not leave a .part file behind
        remove_pending()


def _main(argv: list[str] | None) -> int:
    usage_error = _usage_error_type()
    # floating-point warnings (an empty slice, 0/0 in a masked pixel) are handled where they arise (NaN with a
    # reason, a refused frame); the user sees results and one-line errors, never numpy's warnings
    warnings.filterwarnings("ignore", category=RuntimeWarning)
    use_frame_allocator()  # frame-sized buffers reused, not faulted in again for every frame
    try:
        args = sys.argv[1:] if argv is None else [str(a) for a in argv]
        register_commands(commands_for(args))
        result = app(args=args, prog_name="camcal", standalone_mode=False)
    except typer.Exit as exc:
        return int(exc.exit_code or 0)
    except typer.Abort:
        print("camcal: interrupted", file=sys.stderr)
        return 130
    except usage_error as exc:  # type: ignore[misc]
        print(f"camcal: error: {exc.format_message()} (see camcal --help)", file=sys.stderr)
        return 2
    except CamcalError as exc:
        print(f"camcal: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("camcal: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except OSError as exc:  # writing an output: a directory in the way, no space, no permission
        where = exc.filename2 or exc.filename
        print(f"camcal: error: {where + ': ' if where else ''}{exc.strerror or ' '.join(str(exc).split())}",
              file=sys.stderr)
        return 2
    except Exception as exc:  # the promise: never a traceback
        print(f"camcal: internal error: {type(exc).__name__}: {' '.join(str(exc).split())} (please report)",
              file=sys.stderr)
        return 3
    if result == 130:  # click turns Ctrl-C into Exit(130) and, not standalone, returns the code silently
        print("camcal: interrupted", file=sys.stderr)
    return int(result) if isinstance(result, int) else 0


def run() -> None:
    """Console-script entry point."""
    sys.exit(main())

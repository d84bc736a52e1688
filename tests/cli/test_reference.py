"""docs/cli.md is current, and every command (including ones added later) follows the CLI vocabulary."""

from __future__ import annotations

from pathlib import Path

import pytest

from camcal.cli.reference import commands, render

try:  # typer >= 0.20 vendors click
    from typer._click.core import Context
except ImportError:  # pragma: no cover - depends on the installed typer
    from click import Context

ROOT = Path(__file__).resolve().parents[2]
COMMANDS = commands()


def test_cli_md_is_current():
    assert (ROOT / "docs" / "cli.md").read_text() == render(), (
        "docs/cli.md is out of date: python -m camcal.cli.reference > docs/cli.md")


def test_cli_md_lists_every_option():
    text = (ROOT / "docs" / "cli.md").read_text()
    for name, cmd in COMMANDS:
        assert f"## `camcal {name}`" in text
        for p in cmd.params:
            if p.param_type_name == "option" and not p.hidden:
                assert p.opts[0] in text, (name, p.opts)


@pytest.mark.parametrize(("name", "cmd"), COMMANDS, ids=[n for n, _ in COMMANDS])
def test_naming_rules(name, cmd):
    opts = [p for p in cmd.params if p.param_type_name == "option" and not p.hidden]
    for p in opts:
        names = set(p.opts) | set(p.secondary_opts)
        help_text = " ".join((p.help or "").split())
        # every output path is -o/--output, and -o is never anything else
        assert not names & {"--out", "--outdir", "--output-dir"}, (name, names)
        assert ("-o" in names) == ("--output" in names), (name, names)
        # --jobs: one unit everywhere
        if "--jobs" in names:
            assert help_text.startswith("CPU cores to use"), (name, help_text)
        # option names that say which model; --sweep-mode; --plot/--no-plot
        assert not names & {"--model", "--mode", "--flat-model", "--png"}, (name, names)
        if any("plot" in n for n in names):
            assert names == {"--plot", "--no-plot"}, (name, names)
        # every pixel option in photo pixels
        if names & {"--roi"} or any(n.endswith("-px") for n in names):
            assert "photo pixels" in help_text, (name, names, help_text)
        # percentages as 3% or 0.03
        if any(n.endswith(("-fraction", "-tol", "-unc")) or n == "--relative-sigma" for n in names):
            ctx = Context(cmd)
            a, b = p.process_value(ctx, "3%"), p.process_value(ctx, "0.03")
            if isinstance(a, float):
                assert a == pytest.approx(b) == pytest.approx(0.03), (name, names)
            else:  # parsed later by the command (with ± and units): the help says so
                assert "%" in help_text, (name, names)

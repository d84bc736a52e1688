import json
import re
from pathlib import Path

import pytest

from camcal import __version__
from tests.conftest import assert_one_line_error, run_cli

ROOT = Path(__file__).resolve().parents[2]


def test_version():
    proc = run_cli("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"camcal {__version__}"


def test_inspect_dng_and_jpeg_json(session_dir):
    dng = session_dir / "linearity" / "lin_005.dng"
    jpg = session_dir / "linearity" / "lin_005.jpg"
    proc = run_cli("inspect", "--json", dng, jpg)
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info[0]["kind"] == "raw" and info[0]["cfa_pattern"] == "RGGB"
    assert info[0]["black_level_dn"] == {"R": 512.0, "G1": 512.0, "G2": 512.0, "B": 512.0}
    assert info[0]["white_level_dn"] == 16383 and info[0]["iso"] == 100 and info[0]["f_number"] == 4
    truth = json.loads((session_dir / "truth.json").read_text())
    assert info[0]["exposure_s"] == pytest.approx(truth["linearity"]["exposure_s"][5], rel=1e-6)
    assert info[1]["kind"] == "processed" and info[1]["width"] == 384 and info[1]["height"] == 256
    assert info[1]["exposure_s"] == pytest.approx(info[0]["exposure_s"], rel=1e-6)


def test_inspect_human_output(session_dir):
    proc = run_cli("inspect", session_dir / "bias" / "bias_000.dng")
    assert proc.returncode == 0 and "RGGB" in proc.stdout and "16383" in proc.stdout


@pytest.mark.parametrize("kind", ["empty", "truncated", "text", "directory", "missing"])
def test_inspect_bad_input_one_line_exit_2(tmp_path, session_dir, kind):
    p = tmp_path / "bad.dng"
    if kind == "empty":
        p.write_bytes(b"")
    elif kind == "truncated":
        p.write_bytes((session_dir / "bias" / "bias_000.dng").read_bytes()[:4000])
    elif kind == "text":
        p.write_text("hello\n" * 100)
    elif kind == "directory":
        p.mkdir()
    proc = run_cli("inspect", p)
    assert_one_line_error(proc, "bad.dng")


def test_unknown_option_is_one_line():
    assert_one_line_error(run_cli("inspect", "--bogus"), "--bogus")


def test_synth_session_cli(tmp_path):
    proc = run_cli("synth", "session", tmp_path / "S", "--pattern", "BGGR", "--bits", "12", "--width", "128",
                   "--height", "96", "--stages", "bias,flat")
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in (tmp_path / "S").iterdir()) == ["bias", "flat", "truth.json"]
    info = json.loads(run_cli("inspect", "--json", tmp_path / "S" / "flat" / "flat_000.dng").stdout)[0]
    assert info["cfa_pattern"] == "BGGR" and info["white_level_dn"] == 4095


def test_readme_test_command_is_what_ci_runs():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    cmd = re.search(r"```(?:bash|sh)\n# test\n(.+?)\n```", readme, re.S).group(1).strip()
    assert cmd in ci


def _python(code: str):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)


def test_every_command_is_registered():
    """Registration is an explicit list: each listed module registers its command, and nothing is skipped."""
    code = (
        "import typer.main\n"
        "from camcal.cli import COMMAND_MODULES, app, register_commands\n"
        "register_commands()\n"
        "print(' '.join(sorted(typer.main.get_command(app).commands)))\n"
    )
    proc = _python(code)
    assert proc.returncode == 0, proc.stderr[-3000:]
    from camcal.cli import COMMAND_MODULES

    assert proc.stdout.split() == sorted(COMMAND_MODULES)
    assert sorted(p.stem[: -len("_cmd")] for p in (ROOT / "camcal" / "cli").glob("*_cmd.py")) == sorted(COMMAND_MODULES)


def test_a_command_module_that_fails_to_import_is_an_error():
    code = (
        "import sys\n"
        "sys.modules['camcal.cli.water_cmd'] = None  # importing it now raises ImportError\n"
        "from camcal.cli import main\n"
        "sys.exit(main(['water', '--help']))\n"
    )
    proc = _python(code)
    assert proc.returncode == 3, (proc.stdout, proc.stderr)
    assert "camcal.cli.water_cmd" in proc.stderr and "Traceback" not in proc.stderr


def test_start_up_imports_only_the_command_it_runs():
    """`--version` loads no command module; a command loads its own; the library never imports the CLI."""
    code = (
        "import sys\n"
        "from camcal.cli import main\n"
        "assert main(['--version']) == 0\n"
        "loaded = sorted(m for m in sys.modules if m.startswith('camcal.cli.') and m.endswith('_cmd'))\n"
        "assert loaded == [], loaded\n"
        "heavy = [m for m in ('colour', 'matplotlib', 'dask', 'OpenImageIO') if m in sys.modules]\n"
        "assert heavy == [], heavy\n"
        "main(['inspect', '--help'])\n"
        "loaded = sorted(m for m in sys.modules if m.startswith('camcal.cli.') and m.endswith('_cmd'))\n"
        "assert loaded == ['camcal.cli.inspect_cmd'], loaded\n"
        "import camcal.demo.lab\n"
        "print('ok')\n"
    )
    proc = _python(code)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-3000:]
    proc = _python("import sys, camcal.demo.lab, camcal.apply.photo, camcal.apply.batch, camcal.water.invert\n"
                   "assert not any(m == 'camcal.cli' or m.startswith('camcal.cli.') for m in sys.modules)\n")
    assert proc.returncode == 0, proc.stderr[-3000:]


def test_inspect_shows_what_a_user_needs_with_sensible_digits(session_dir):
    """By default one row per thing a user needs (no 15-digit floats, no raw dicts); --all shows every field."""
    p = session_dir / "bias" / "bias_000.dng"
    short = run_cli("inspect", p).stdout
    full = run_cli("inspect", p, "--all").stdout
    assert "exposure time" in short and "black / white level" in short and "{'R'" not in short
    assert short.count("\n") < full.count("\n")
    assert "exposure_value_s" in full and "exposure_value_s" not in short
    for line in short.splitlines() + full.splitlines():  # at most 6 significant digits in any number
        for token in line.replace("(", " ").replace(")", " ").split():
            digits = token.rstrip("s°%,").replace(".", "").lstrip("0")
            assert not (digits.isdigit() and len(digits) > 10), line

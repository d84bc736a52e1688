"""Structure rules of issue 17 that a test can check: imports where a reader expects them, the library never
imports the CLI, one ``--roi`` parser."""

from __future__ import annotations

import ast
import functools
import json
import re
import subprocess
import sys
import tomllib
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest

from camcal.errors import CamcalError
from camcal.region import Region, pixels_per_output_cell

ROOT = Path(__file__).resolve().parents[1]

# The only imports allowed inside a function: packages that must stay off the paths that do not plot or do not
# distribute (test_a_calibrate_run_loads_no_plotting_or_distribution). matplotlib draws figures; dask runs a batch on
# a cluster; colour-science imports matplotlib itself (its package __init__ imports colour.plotting), so it follows
# matplotlib's rule, and so does colour-checker-detection (it imports colour-science). astropy reads FITS frames
# only and costs 0.7 s to import. Everything else, camcal's own modules and every other library, is imported at the
# top.
IMPORTED_WHERE_USED = {"matplotlib", "dask", "colour", "colour_checker_detection", "astropy"}


def _imports_inside_functions(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import inside a function of ``path`` that is not in :data:`IMPORTED_WHERE_USED`
    (a comment on the line does not excuse it)."""
    found = []
    for fn in ast.walk(ast.parse(path.read_text())):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.ImportFrom):
                mods = [("." * node.level) + (node.module or "")]
            elif isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            else:
                continue
            found += [(node.lineno, m) for m in mods if m.split(".")[0] not in IMPORTED_WHERE_USED]
    return found


def test_modules_import_at_the_top():
    offenders = {}
    for p in sorted((ROOT / "camcal").rglob("*.py")):
        local = _imports_inside_functions(p)
        if local:
            offenders[str(p.relative_to(ROOT))] = local
    assert offenders == {}


def test_the_import_check_sees_an_import_inside_a_function(tmp_path):
    """The check above finds a lazy import of a library or of camcal, comment or not, and lets matplotlib pass."""
    src = tmp_path / "m.py"
    src.write_text("def f():\n    import rawpy  # lazy\n    from camcal import io\n"
                   "    from matplotlib.figure import Figure\n")
    assert _imports_inside_functions(src) == [(2, "rawpy"), (3, "camcal")]


def test_the_library_never_imports_the_cli():
    pattern = re.compile(r"^\s*(from camcal\.cli\b|import camcal\.cli\b)", re.M)
    offenders = [str(p.relative_to(ROOT)) for p in (ROOT / "camcal").rglob("*.py")
                 if p.parent.name != "cli" and p.name != "__main__.py" and pattern.search(p.read_text())]
    assert offenders == []


def test_every_roi_option_is_read_by_region_parse():
    """Every command module with a ``--roi`` option parses it with :meth:`Region.parse` and has no parser of its own."""
    cli = ROOT / "camcal" / "cli"
    with_roi = sorted(p.name for p in cli.glob("*_cmd.py") if '"--roi"' in p.read_text())
    assert with_roi == ["apply_cmd.py", "linearity_cmd.py", "secchi_cmd.py", "sweep_cmd.py", "water_cmd.py"]
    for name in with_roi:
        text = (cli / name).read_text()
        assert "Region.parse(" in text, name
        assert not re.search(r"def _(parse_)?roi\b", text), name


@pytest.mark.parametrize("text", ["1,2,3", "0,0,0,5", "-1,0,4,4", "1.5,0,4,4", ",,,", "0.1", "a,b,c,d"])
def test_region_parse_refuses_other_forms(text):
    with pytest.raises(CamcalError, match="x,y,w,h"):
        Region.parse(text)


def test_photo_pixels_to_an_output_grid():
    """apply's notes say the grid: half resolution for Bayer photos (2 photo pixels per cell), full for linear."""
    assert pixels_per_output_cell("half resolution: one value per 2x2 CFA cell") == 2
    assert pixels_per_output_cell("full resolution: the linear RAW's own R, G, B planes") == 1
    assert pixels_per_output_cell(None) is None and pixels_per_output_cell("something else") is None
    # rounded outward: photo pixels 3..8 cover half-resolution cells 1..3 (cells 1, 2, 3)
    assert Region(3, 3, 5, 5).window((10, 10), 2) == (slice(1, 4), slice(1, 4))


def test_a_calibrate_run_loads_no_plotting_or_distribution(session_dir, tmp_path):
    """calibrate neither plots nor distributes, so it loads neither matplotlib nor dask (its fits
    call scipy, which it may load). The session is the full synthetic one (every stage, JPEG twins and the
    colour matrix)."""
    code = ("import json, sys\n"
            "from camcal.cli import run\n"
            "sys.argv = ['camcal', 'calibrate', sys.argv[1], '-o', sys.argv[2]]\n"
            "try:\n"
            "    run()\n"
            "except SystemExit as e:\n"
            "    assert not e.code, e.code\n"
            "heavy = ('matplotlib', 'dask')\n"
            "print('LOADED', json.dumps(sorted({m.split('.')[0] for m in sys.modules} & set(heavy))))\n")
    proc = subprocess.run([sys.executable, "-c", code, str(session_dir), str(tmp_path / "p.camcal")],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "p.camcal").is_file()
    assert json.loads(proc.stdout.rsplit("LOADED", 1)[1]) == []


@functools.cache
def _third_party_imports() -> set[str]:
    """Top-level names of every module imported anywhere in camcal/ (at the top or inside a function)."""
    names: set[str] = set()
    for path in (ROOT / "camcal").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names.update(a.name.split(".")[0] for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names


@functools.cache
def _distributions() -> dict[str, list[str]]:
    return packages_distributions()


def _runtime_dependencies() -> list[str]:
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    return [re.split(r"[<>=!~\[; ]", d, maxsplit=1)[0] for d in deps]


@pytest.mark.parametrize("dist", _runtime_dependencies())
def test_every_declared_dependency_is_imported_by_camcal(dist):
    """Issue 25: a runtime dependency in pyproject.toml is one the package imports (its import name from the
    installed distribution's metadata, e.g. colour-science -> colour, scikit-image -> skimage)."""
    import_names = {m for m, dists in _distributions().items()
                    if dist.lower().replace("_", "-") in {x.lower().replace("_", "-") for x in dists}}
    assert import_names, f"{dist} is declared but not installed"
    imported = bool(import_names & _third_party_imports())
    assert imported, f"{dist} is declared in pyproject.toml but camcal/ never imports {sorted(import_names)}"


def _declared_distributions() -> set[str]:
    """Runtime dependencies and every extra of pyproject.toml, normalised (PEP 503)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    specs = list(project["dependencies"]) + [d for extra in project["optional-dependencies"].values() for d in extra]
    return {re.split(r"[<>=!~\[; ]", d, maxsplit=1)[0].lower().replace("_", "-") for d in specs}


def test_every_third_party_import_of_camcal_is_declared():
    """Issue 25: what camcal/ imports is declared in pyproject.toml, not merely present because another
    dependency pulls it in (Pillow under pillow-heif, pandas under pvlib, click under typer)."""
    declared = _declared_distributions()
    missing = []
    for name in sorted(_third_party_imports() - set(sys.stdlib_module_names) - {"camcal"}):
        dists = {d.lower().replace("_", "-") for d in _distributions().get(name, [])}
        if not dists & declared:
            missing.append(f"{name} (from {sorted(dists) or 'no installed distribution'})")
    assert not missing, f"imported by camcal/ but not declared in pyproject.toml: {missing}"


# the fitting code of each stage; a model module (camcal.<stage>_model) holds what the stage's results are
FITTING_MODULES = ("camcal.dark", "camcal.flat", "camcal.response", "camcal.spectral", "camcal.colour_matrix",
                   "camcal.emva", "camcal.calibrate", "camcal.stack", "camcal.sweep_means")
MODEL_MODULES = ("dark_model", "flat_model", "response_model", "spectral_model", "emva_model", "blocks")


def test_reading_and_applying_a_profile_loads_no_fitting_code():
    """Issue 25 item 4: a profile, and what reads or applies it, needs the stages' models, never their fits
    (one interpreter for the four, so the check costs one start-up)."""
    readers = ("camcal.profile", "camcal.apply", "camcal.water", "camcal.report")
    code = (f"import json, sys, {', '.join(readers)}\n"
            "print('LOADED', json.dumps(sorted(m for m in sys.modules if m.startswith('camcal.'))))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    loaded = set(json.loads(proc.stdout.rsplit("LOADED", 1)[1]))
    assert set(readers) <= loaded
    assert sorted(loaded & set(FITTING_MODULES)) == []


@pytest.mark.parametrize("name", MODEL_MODULES)
def test_model_modules_import_no_stage(name):
    """A model module sits below every stage: it imports no fitting module (nor another stage's model through
    one)."""
    tree = ast.parse((ROOT / "camcal" / f"{name}.py").read_text())
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert sorted(imported & set(FITTING_MODULES)) == []

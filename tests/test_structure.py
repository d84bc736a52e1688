"""Structure rules that a test can check: the layers as folders, imports where a reader expects them, the library never
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


# --- layers: one sub-package per layer (generated; keep the two marker lines) ---
# camcal/ is one sub-package per layer; its top-level modules are the core types (CORE), the entry points and the
# demo. LAYERS says which layers a module of each layer may import ("core" is the core modules and the camcal
# package itself); a layer not listed here (a new sub-package) fails test_every_sub_package_is_a_layer until it
# has a row. demo runs every layer (it may import anything but the CLI); the CLI may import anything.
CORE = {"errors", "frame", "region", "threads", "units"}
TOP_LEVEL = {"__init__", "__main__", "errors", "frame", "region", "threads", "units"}
MAX_TOP_LEVEL_MODULES = 8
LAYERS = {
    "core": set(),
    "io": {"core"},
    "models": {"core", "io"},
    "calibrate": {"core", "io", "models"},
    "curves": {"core", "io", "models"},
    "apply": {"core", "io", "models"},
    "report": {"core", "io", "models"},
    "water": {"apply", "core", "io", "models", "report"},
    "synth": {"core", "io", "models", "water"},
    "emva1288": {"calibrate", "core", "io", "models", "report"},
    "chart": {"calibrate", "core", "curves", "io", "models", "water"},
}
# What synth, the source of ground truth, may take from the layers it imports: its own writers, the core types,
# reference spectra and water's optical constants and column models; never a stage, correct or the profile.
SYNTH_NEVER_LAYERS = ("calibrate", "curves", "apply", "report")
SYNTH_NEVER_MODULES = ("camcal.models.correct", "camcal.models.profile")


def _layer_of_file(path: Path) -> str:
    rel = path.relative_to(ROOT / "camcal")
    if len(rel.parts) > 1:
        return rel.parts[0]
    return "core" if rel.stem in CORE or rel.stem == "__init__" else rel.stem


def _sub_packages() -> set[str]:
    return {p.parent.name for p in (ROOT / "camcal").glob("*/__init__.py")}


def _camcal_imports(path: Path) -> set[str]:
    """camcal modules ``path`` imports; ``from camcal import x`` counts as ``camcal.x`` when x is a module."""
    names = set()
    modules = _sub_packages() | {p.stem for p in (ROOT / "camcal").glob("*.py")}
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names if a.name.split(".")[0] == "camcal"}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "camcal":
            if node.module == "camcal":
                names |= {f"camcal.{a.name}" if a.name in modules else "camcal" for a in node.names}
            else:
                names.add(node.module)
    return names


def _layer_of_import(name: str) -> str:
    parts = name.split(".")
    if len(parts) == 1:
        return "core"
    return parts[1] if parts[1] in _sub_packages() else ("core" if parts[1] in CORE else parts[1])


def test_camcal_holds_few_modules_beside_its_sub_packages():
    top = sorted(p.stem for p in (ROOT / "camcal").glob("*.py"))
    assert len(top) <= MAX_TOP_LEVEL_MODULES, top
    assert set(top) <= TOP_LEVEL, sorted(set(top) - TOP_LEVEL)


def test_every_sub_package_is_a_layer():
    assert sorted(_sub_packages() - set(LAYERS) - {"cli", "demo"}) == []


@pytest.mark.parametrize("layer", sorted(LAYERS))
def test_each_layer_imports_only_the_layers_below_it(layer):
    """``models/`` never imports ``calibrate/``; ``apply/``, ``report/`` and ``water/`` read a profile through
    ``models/`` only; ``io/`` imports the core modules only; nothing in the library imports the CLI."""
    offenders = []
    for path in sorted((ROOT / "camcal").rglob("*.py")):
        if _layer_of_file(path) != layer:
            continue
        for name in sorted(_camcal_imports(path)):
            target = _layer_of_import(name)
            if target not in LAYERS[layer] | {layer}:
                offenders.append(f"{path.relative_to(ROOT)}: {name}")
    assert offenders == []


def test_demo_and_entry_points_only_sit_above_the_layers():
    demo = sorted((ROOT / "camcal" / "demo").glob("*.py"))
    assert demo, "camcal/demo/ holds the demo's modules"
    for path in demo:
        assert not any(_layer_of_import(n) == "cli" for n in _camcal_imports(path)), path


def test_the_layer_check_sees_an_upward_import(tmp_path, monkeypatch):
    """The check above finds models/ importing calibrate/ in a planted module (it can fail)."""
    planted = tmp_path / "camcal" / "models"
    planted.mkdir(parents=True)
    (planted / "x.py").write_text("from camcal.calibrate.dark import fit_dark\nfrom camcal import errors\n")
    monkeypatch.setitem(globals(), "ROOT", tmp_path)
    assert _layer_of_file(planted / "x.py") == "models"
    assert {_layer_of_import(n) for n in _camcal_imports(planted / "x.py")} == {"calibrate", "core"}


def test_synth_takes_no_stage_correction_or_profile():
    offenders = []
    for path in sorted((ROOT / "camcal" / "synth").rglob("*.py")):
        offenders += [f"{path.name}: {n}" for n in sorted(_camcal_imports(path))
                      if _layer_of_import(n) in SYNTH_NEVER_LAYERS or n in SYNTH_NEVER_MODULES]
    assert offenders == []


def test_reading_and_applying_a_profile_loads_no_fitting_code():
    """A profile, and what reads or applies it, needs the stages' models, never their measurement or fit, nor
    curves/ (one interpreter for all, so the check costs one start-up)."""
    readers = ("camcal.models.profile", "camcal.apply.photo", "camcal.apply.batch", "camcal.water",
               "camcal.report.page")
    code = (f"import json, sys, {', '.join(readers)}\n"
            "print('LOADED', json.dumps(sorted(m for m in sys.modules if m.startswith('camcal.'))))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    loaded = set(json.loads(proc.stdout.rsplit("LOADED", 1)[1]))
    assert set(readers) <= loaded
    assert sorted(m for m in loaded if m.split(".")[1] in {"calibrate", "curves"}) == []


@pytest.mark.parametrize("path", sorted((ROOT / "camcal" / "models").glob("*.py")), ids=lambda p: p.name)
def test_model_modules_import_no_stage(path):
    """A model module sits below every stage: ``models/`` never imports ``calibrate/``."""
    assert sorted(n for n in _camcal_imports(path) if _layer_of_import(n) == "calibrate") == []
# --- end of the layer rules ---

"""Docs that run: every shell command of README.md, the user guide and the stage docs, on synthetic data.

Each ``camcal`` command of a ```bash block is run through the real CLI (in process, :func:`camcal.cli.main`)
in one working folder, in the order of the pages, with the documents' placeholders mapped onto the files of
``camcal demo`` (its session, profile, survey photos and their radiance EXRs): a renamed option, a changed
default or an example that no longer gives its stated result fails here instead of misleading a reader.
Stated results are checked where the docs state one (:data:`STATED`); the chlorophyll examples must give
C within 3 % of the demo's truth (60 µg/L). A command that cannot run on synthetic data is listed in
:data:`NOT_RUN` with the reason; an example neither run nor listed fails the test.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from camcal.cli import main
from camcal.io.exr import read_exr

ROOT = Path(__file__).resolve().parents[1]
#: The pages whose examples are run, in this order (later pages use files earlier ones wrote: dark.json...).
PAGES = ("README.md", "docs/user-guide.md", "docs/dark.md", "docs/flat.md", "docs/response.md", "docs/spectral.md",
         "docs/apply.md", "docs/water.md", "docs/report.md")
#: The demo's truth (camcal.demo.lab.CHL_UG_PER_L) and the stated tolerance of the chlorophyll examples.
CHL_TRUTH_UG_PER_L = 60.0
CHL_TOLERANCE = 0.03

#: The real camera files beside the checkout (../shared/realdata; absent on some machines: then the examples that
#: name one of them are not run, as the other real-data tests are skipped).
REALDATA = Path(__file__).resolve().parents[1].parent / "shared" / "realdata"

#: Placeholder → what it names in the working folder (whole words; applied in this order).
PLACEHOLDERS = (
    (r"radiance/(sub|submerged)\.dng\.exr", "radiance/disk_submerged.dng.exr"),
    (r"radiance/(ref|reference)\.dng\.exr", "radiance/disk_reference.dng.exr"),
    (r"\bA\.exr", "radiance/disk_submerged.dng.exr"),
    (r"\bB\.exr", "radiance/disk_reference.dng.exr"),
    (r"\b(camera|cam|P|old)\.camcal\b", "cam.camcal"),
    (r"\bphoto\.dng\b", "survey/disk_reference.dng"),
    (r"\bIMG_0001\.dng\b", "survey/disk_reference.dng"),
    (r"\bIMG_0002\.dng\b", "survey/disk_submerged.dng"),
    (r"(?<![\w/])photos/", "survey/"),
    (r"--roi x,y,w,h", "--roi 172,108,40,40"),
    (r"--sigma-channel S\b", "--sigma-channel L663_unc"),
    (r"-o DIR\b", "-o sim"),
    (r"\bold\.jpg\b", "survey/disk_reference.dng"),
    (r"\bIMG_2682\.HEIC\b", str(REALDATA / "heic" / "iphone7_IMG_2682.heic")),
)

#: Examples that are not run, by a fragment of the command, with the reason.
NOT_RUN = {
    "camcal demo": "the session fixture runs the README's demo command itself",
    "phone.camcal": "needs photos of a colour chart and a phone's survey (tests/chart/test_profile_build.py runs the "
    "phone chapter's commands on camcal synth phone's photos)",
    "camcal chart": "needs photos of a colour chart (tests/chart/test_profile_build.py and tests/chart/test_detect.py)",
    "import-spectral": "needs photos of reference targets of known radiance "
    "(tests/curves/test_import_spectral.py runs it)",
    "--dask-scheduler": "needs a Dask cluster",
    "--model lamp --lamp-height 1m±1cm --lamp-angle 20±0.5 --profile": "needs photos of a lamp-lit tank and a dye "
    "spectrum (notebook 04 runs it on synthetic photos)",
    "--water-model lamp --lamp-height 1m±1cm --lamp-angle 20±0.5 --profile": "needs photos of a lamp-lit tank and "
    "a dye spectrum (notebook 04 runs it on synthetic photos)",
    "camcal water invert ...": "an elided synopsis, not a command",
    "cam_abs.camcal": "shows the profile the import-spectral example writes",
    "camcal secchi": "needs sunlit photos of a Secchi disk with their time and GPS (tests/water/test_field.py runs "
    "camcal secchi end to end on rendered scenes, from DNG, JPEG and HEIC)",
    "--means": "needs a sweep published as channel means (tests/curves/test_published_sweeps.py runs it on the open "
    "sweeps of ../shared/realdata/sweeps)",
}


def _optional(text: str) -> str:
    """``[--json]`` → ``--json``; ``[a | b]`` → ``a``; an option value ``seed|refined`` → ``seed``."""
    text = re.sub(r"\[([^\]]*)\]", lambda m: m.group(1).split(" | ")[0], text)
    return re.sub(r"(?<=\s)([\w.-]+)(\|[\w.-]+)+", r"\1", text)


def shell_commands(page: str) -> list[tuple[int, str]]:
    """(line number, command) of every ``camcal`` command in the page's ```bash/```sh blocks."""
    out: list[tuple[int, str]] = []
    lines = (ROOT / page).read_text().splitlines()
    block = None
    pending, start = "", 0
    for i, line in enumerate(lines, 1):
        fence = re.match(r"^```(\w*)", line)
        if fence:
            block = None if block is not None else fence.group(1)
            continue
        if block not in ("bash", "sh", "shell"):
            continue
        if not pending:
            start = i
        code = re.sub(r"\s#\s.*$", "", line).rstrip()
        if code.endswith("\\"):
            pending += code[:-1] + " "
            continue
        full, pending = (pending + code).strip(), ""
        for part in full.split("&&"):
            if part.strip().startswith("camcal "):
                out.append((start, " ".join(part.split())))
    return out


def all_commands() -> list[tuple[str, int, str]]:
    return [(page, n, cmd) for page in PAGES for n, cmd in shell_commands(page)]


def _argv(cmd: str) -> list[str]:
    text = _optional(cmd)
    for pattern, repl in PLACEHOLDERS:
        text = re.sub(pattern, repl, text)
    return text.split()[1:]


def _parse_only(argv: list[str]) -> None:
    """Parse ``argv`` with the app's own parser (options, types, choices) without running the command."""
    import typer

    from camcal.cli import app, register_commands

    register_commands()
    cmd = typer.main.get_command(app)
    args = list(argv)
    name = "camcal"
    while hasattr(cmd, "get_command"):  # a group: descend to the command the words name
        name, args = args[0], args[1:]
        sub = cmd.get_command(None, name)
        assert sub is not None, f"no command {name!r}"
        cmd = sub
    cmd.make_context(name, list(args))  # parses and checks every option, runs nothing


@pytest.fixture(scope="session")
def workdir(tmp_path_factory, demo_run):
    """The README's own demo command run once; the working folder holds its files under the docs' names.

    The run is the ``demo_run`` fixture's (``camcal demo -o DIR`` by the real CLI, shared with tests/demo/test_demo.py):
    the README's command must be exactly that one, with only the output folder's name in place of DIR."""
    work = tmp_path_factory.mktemp("docs")
    (demo_cmd,) = [c for p, _, c in all_commands() if p == "README.md" and c.startswith("camcal demo")]
    argv = demo_cmd.split()[1:]
    demo, proc = demo_run
    assert argv[:-1] == proc.args[1:-1], (demo_cmd, proc.args)
    assert proc.returncode == 0, (demo_cmd, proc.stderr)
    (work / "SESSION").symlink_to(demo / "session")
    shutil.copy(demo / "camera.camcal", work / "cam.camcal")
    (work / "survey").symlink_to(demo / "survey")
    shutil.copytree(demo / "radiance", work / "radiance")
    # a mask over the disk (photo pixels) for the --mask example
    import OpenImageIO as oiio

    mask = np.zeros((256, 384, 1), np.uint8)
    mask[108:148, 172:212] = 255
    out = oiio.ImageOutput.create(str(work / "disk.png"))
    out.open(str(work / "disk.png"), oiio.ImageSpec(384, 256, 1, oiio.UINT8))
    out.write_image(mask)
    out.close()
    return work


def _chl(work: Path, out: str) -> dict:
    _, meta = read_exr(work / out, ["chl_ug_per_L"])
    return meta["summary"]


def test_every_example_is_run_or_listed():
    cmds = all_commands()
    assert len(cmds) > 30  # the pages hold examples: the extraction itself works
    assert any("--roi 172,108,40,40" in c for _, _, c in cmds)


def test_docs_commands_run(workdir, monkeypatch, capsys):
    monkeypatch.chdir(workdir)
    calibrated = False  # after one full calibration (~20 s each), the others go through the option parser only
    failures = []
    for page, line, cmd in all_commands():
        if any(key in cmd for key in NOT_RUN):
            continue
        argv = _argv(cmd)
        if not REALDATA.is_dir() and any(arg.startswith(str(REALDATA)) for arg in argv):
            continue  # names a real camera file, and ../shared/realdata is absent here
        if cmd.startswith("camcal calibrate") and calibrated:
            try:
                _parse_only(argv)
            except Exception as exc:  # noqa: BLE001 - reported with the page and line
                failures.append(f"{page}:{line}: {cmd}\n    {type(exc).__name__}: {exc}")
            continue
        code = main(argv)
        err = capsys.readouterr().err
        if code != 0:
            failures.append(f"{page}:{line}: {cmd}\n    exit {code}: {err.strip()}")
            continue
        calibrated |= cmd.startswith("camcal calibrate")
        # stated results
        if cmd.startswith("camcal water invert --submerged") and "--profile" in cmd and "chl.exr" in cmd:
            s = _chl(workdir, "chl.exr")
            c = s["median_ug_per_L"]
            if abs(c / CHL_TRUTH_UG_PER_L - 1) > CHL_TOLERANCE:
                failures.append(f"{page}:{line}: {cmd}\n    C = {c:.2f} µg/L, truth {CHL_TRUTH_UG_PER_L} ± 3 %")
            if "--roi 172,108,40,40" in cmd and s["valid"] != 399:  # the guide: 399 of the region's 400
                failures.append(f"{page}:{line}: {cmd}\n    {s['valid']} valid pixels, the guide says 399")
        if cmd.startswith("camcal apply") and "--roi" in cmd:
            assert (workdir / argv[argv.index("-o") + 1] / "roi_stats.csv").is_file()
    assert not failures, "\n".join(failures)

"""The end-to-end demo on synthetic data (grows with each pipeline stage)."""

from __future__ import annotations

import json
from pathlib import Path

from rich.table import Table

from camcal.cli.common import console, progress
from camcal.inspect import describe
from camcal.synth.camera import SensorParams, SyntheticCamera
from camcal.synth.session import SessionPlan, write_session


def run_demo(out: str | Path) -> dict:
    """Synthesise a session into ``out``/session and report what it holds. Returns a summary dict."""
    out = Path(out)
    cam = SyntheticCamera(SensorParams())
    with progress() as bar:
        tasks: dict[str, int] = {}

        def tick(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(f"synthesise {stage}", total=total)
            bar.update(tasks[stage], completed=done)

        session = write_session(out / "session", cam, SessionPlan(), progress=tick)
    truth = json.loads((session / "truth.json").read_text())
    table = Table(title="camcal demo: synthetic session")
    for col in ("stage", "file", "pattern", "exposure s", "ISO", "f/N", "black DN", "white DN"):
        table.add_column(col)
    for stage in ("bias", "dark", "flat", "linearity", "sweep"):
        files = sorted((session / stage).glob("*.dng"))
        if not files:
            continue
        info = describe(files[0])
        table.add_row(stage, files[0].name, str(info["cfa_pattern"]), f"{info['exposure_s']:.4g}", f"{info['iso']:g}",
                      f"{info['f_number']:g}", f"{info['black_level_dn']['R']:g}", f"{info['white_level_dn']:g}")
    console.print(table)
    console.print(
        f"truth: bias {truth['bias_dn']['R']:.1f} DN, dark current {truth['dark_current_dn_per_s']['R']:.3f} DN/s, "
        f"read noise {truth['read_noise_dn']['R']:.2f} DN, {truth['hot_pixel_count']} hot pixels"
    )
    return {"session": str(session), "truth": truth}

"""``camcal calibrate SESSION -o PROFILE``."""

from __future__ import annotations

import warnings
from pathlib import Path

import typer

from camcal.calibrate.run import CalibrateOptions, calibrate_session
from camcal.cli.common import console, err_console, progress
from camcal.cli.profile_cmd import print_contract
from camcal.errors import FrameLeftOut
from camcal.models.profile import contract, save_profile


def register(app: typer.Typer) -> None:
    @app.command("calibrate")
    def calibrate_cmd(
        session: Path = typer.Argument(..., help="Session folder with any of bias/ dark/ flat/ linearity/ sweep/."),
        output: Path = typer.Option(..., "-o", "--output", help="Profile file to write (.camcal)."),
        reference_iso: float | None = typer.Option(None, help="Reference ISO (default: the sweep's)."),
        reference_f_number: float | None = typer.Option(None, help="Reference f-number (default: the sweep's)."),
        flat_model: str = typer.Option("radial", "--vignetting-model", help="Vignetting model: radial or 2d."),
        sweep_mode: str = typer.Option("absolute", help="c(λ) units: absolute or relative."),
        deconvolve: bool = typer.Option(False, help="Deconvolve the monochromator slit from c(λ)."),
        jobs: int | None = typer.Option(None, "--jobs", "-j", min=1,
                                        help="CPU cores to use (decoding threads; capped at the usable cores; "
                                        "default: automatic)."),
        strict: bool = typer.Option(False, "--strict",
                                    help="All or nothing: any frame that cannot be used, or any stage with too few "
                                         "usable frames, refuses the session (exit 2, nothing written)."),
    ) -> None:
        """Run every calibration stage whose folder exists and write one profile.

        Frames that cannot be used (unreadable, copies, another camera or size, saturated beyond use, no light)
        are left out and listed with their reason; a stage with too few usable frames is not calibrated, the
        profile is written without it and the exit code is 1. --strict refuses such a session instead.
        """
        opts = CalibrateOptions(reference_iso=reference_iso, reference_f_number=reference_f_number,
                                flat_model=flat_model, sweep_mode=sweep_mode, deconvolve=deconvolve, jobs=jobs,
                                strict=strict)
        with warnings.catch_warnings(record=True) as caught, progress() as bar:
            warnings.simplefilter("always")
            tasks: dict[str, int] = {}

            def tick(stage: str, done: int, total: int) -> None:
                if stage not in tasks:
                    tasks[stage] = bar.add_task(stage, total=total)
                bar.update(tasks[stage], completed=done, total=total)

            profile, notes = calibrate_session(session, opts, progress=tick)
        profile = save_profile(profile, output)
        # stage warnings (e.g. the sweep's) and notes, one line each, without repeats
        # (left-out frames are in the summary's table, not repeated as warnings)
        messages = [" ".join(str(w.message).split()) for w in caught
                    if issubclass(w.category, UserWarning) and not issubclass(w.category, FrameLeftOut)]
        for msg in dict.fromkeys([*notes, *messages]):
            err_console.print(f"camcal: warning: {msg}", soft_wrap=True, markup=False, highlight=False)
        print_contract(contract(profile), title=f"profile → {output}")
        console.print(f"wrote {output} (sha256 {profile.content_sha256[:16]}…)")
        prov = profile.provenance
        for rec in prov.not_calibrated:
            err_console.print(f"camcal: failed: stage {rec['stage']} not calibrated: {rec['reason']}",
                              soft_wrap=True, markup=False, highlight=False)
        if prov.left_out:
            err_console.print(f"camcal: warning: {len(prov.left_out)} frame(s) left out (listed above; --strict "
                              "refuses such a session)", soft_wrap=True, markup=False, highlight=False)
        if prov.not_calibrated:
            raise typer.Exit(1)

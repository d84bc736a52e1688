"""``camcal apply PROFILE PHOTO... -o OUTDIR``: radiance EXRs from survey photos."""

from __future__ import annotations

from pathlib import Path

import typer

from camcal.apply.batch import BatchOptions, report_rows, run_batch
from camcal.cli.common import console, err_console, print_json, progress
from camcal.errors import CamcalError
from camcal.io.exr import COMPRESSIONS, PRECISIONS
from camcal.region import Region
from camcal.units import IN_BAND_RADIANCE


def register(app: typer.Typer) -> None:
    @app.command("apply")
    def apply_cmd(
        profile: Path = typer.Argument(..., help="Calibration profile (.camcal)."),
        photos: list[Path] = typer.Argument(..., help="Photos (RAW or JPEG) and/or folders of photos."),
        outdir: Path = typer.Option(..., "-o", "--output", help="Output folder: one <photo>.exr per photo."),
        wavelength: float = typer.Option(663.0, "--wavelength", help="λ0 of the L<λ0> map, nm."),
        estimator: str = typer.Option("auto", "--estimator", help="auto (default: the spectral estimator with the "
                                      "smallest reconstruction error for the profile's c(λ)), trained, smooth, or "
                                      "narrowband (light confined near λ0: the in-band radiance L<λ0>_inband, "
                                      f"{IN_BAND_RADIANCE}, unless --filter-fwhm); docs/apply.md."),
        filter_fwhm: float | None = typer.Option(None, "--filter-fwhm",
                                                 help="narrowband: filter width, nm; L<λ0> then per nm."),
        line_fwhm: float | None = typer.Option(None, "--line-fwhm",
                                               help="narrowband: width of the light, nm (slit correction of c)."),
        jobs: int | None = typer.Option(None, "--jobs", "-j",
                                        help="CPU cores to use (one worker process each); default: the usable cores."),
        dask_scheduler: str | None = typer.Option(None, "--dask-scheduler",
                                                  help="Run on a dask.distributed cluster (tcp://host:8786)."),
        roi: str | None = typer.Option(None, "--roi", help="Region x,y,w,h in photo pixels at full resolution "
                                       "(rounded outward to the output grid): statistics to roi_stats.csv."),
        mask: Path | None = typer.Option(None, "--mask", help="Mask image (non-zero = in): statistics."),
        allow_other_camera: bool = typer.Option(False, "--allow-other-camera",
                                                help="Accept photos of another camera model than the profile's."),
        precision: str = typer.Option(BatchOptions.precision, "--precision",
                                      help="EXR pixels: float (32-bit, default), half (16-bit; docs/apply.md "
                                      "says when it is enough) or mixed (the 1σ channels in half when their "
                                      "values fit it)."),
        compression: str = typer.Option(BatchOptions.compression, "--compression",
                                        help="EXR compression: none (default: lossless, the fastest), zip, zips, "
                                        "piz, pxr24, b44, dwaa, dwab, zstd or rle; measured in docs/apply.md "
                                        "(pxr24, b44 and dwaa/dwab are lossy)."),
        strict: bool = typer.Option(False, "--strict",
                                    help="Refuse photos whose f-number or focal length the flats were not measured "
                                         "at (or cannot be checked); the rest of the batch goes on."),
        json_out: bool = typer.Option(False, "--json", help="Print the report as JSON."),
    ) -> None:
        """Apply a profile to photos: band radiance R, G, B and L<λ> with its uncertainty, as OpenEXR.

        Exit code 0 when every photo has its EXR, 1 when some failed (listed), 2 on bad input.
        """

        if roi is not None and mask is not None:
            raise CamcalError("give --roi or --mask, not both")
        if precision not in PRECISIONS:
            raise CamcalError(f"--precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
        if compression not in COMPRESSIONS:
            raise CamcalError(f"--compression must be one of {', '.join(COMPRESSIONS)}, got {compression!r}")
        if jobs is not None and jobs < 1:
            raise CamcalError("--jobs must be at least 1")
        opts = BatchOptions(wavelength_nm=wavelength, estimator=estimator, filter_fwhm_nm=filter_fwhm,
                            line_fwhm_nm=line_fwhm, allow_other_camera=allow_other_camera,
                            roi=Region.parse(roi) if roi is not None else None,
                            mask_path=None if mask is None else str(mask), precision=precision, compression=compression,
                            strict=strict)
        with progress() as bar:
            task = bar.add_task("apply (loading the profile)", total=None)

            def tick(done: int, total: int, _result) -> None:
                bar.update(task, completed=done, total=total, description="apply")

            report = run_batch(profile, photos, outdir, opts, jobs=jobs, scheduler=dask_scheduler, progress=tick)
        if json_out:

            print_json({"counts": report.counts, "report_csv": report.report_csv, "roi_csv": report.roi_csv,
                        "estimator": report.estimator, "photos": report_rows(report)})
        else:
            c = report.counts
            console.print(f"{c['done']} written, {c['skipped']} already done (skipped), {c['failed']} failed "
                          f"→ {report.outdir} (report {Path(report.report_csv).name}"
                          f"{', ' + Path(report.roi_csv).name if report.roi_csv else ''})", soft_wrap=True)
            console.print(report.estimator, soft_wrap=True, markup=False, highlight=False)
        for r in report.results:
            if r.warning and r.status != "failed":
                err_console.print(f"camcal: warning: {Path(r.source).name}: {r.warning}", markup=False,
                                  highlight=False, soft_wrap=True)
        for r in report.failed:
            err_console.print(f"camcal: failed: {r.error}", markup=False, highlight=False, soft_wrap=True)
        if report.exit_code:
            raise typer.Exit(report.exit_code)

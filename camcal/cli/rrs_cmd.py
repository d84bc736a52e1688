"""``camcal rrs``: photos of the water, the sky and a grey card to Rrs per band, turbidity and SPM, with σ."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from camcal.cli.common import console, print_json, progress
from camcal.errors import CamcalError
from camcal.io.sun import parse_sun_option, photo_sun
from camcal.water.rrs import BANDS
from camcal.water.rrs_photos import append_survey, run_rrs, station_json, station_row, write_page


def register(app: typer.Typer) -> None:
    @app.command("rrs")
    def rrs_cmd(
        profile: Path = typer.Option(..., "--profile", help="Calibration profile (.camcal) of the camera."),
        water: list[Path] = typer.Option(..., "--water", help="Photo (or apply's EXR) of the water surface, about "
                                         "40 deg from nadir and 135 deg from the sun; repeat for several (glint "
                                         "screening needs three or more)."),
        sky: list[Path] = typer.Option(..., "--sky", help="Photo of the sky at the same angle from the zenith; "
                                       "repeat for several."),
        card: list[Path] = typer.Option(..., "--card", help="Photo of the grey card, level, in the same light."),
        out: Path = typer.Option(None, "-o", "--output", help="Folder for the page (index.html, PNGs, rrs.json, "
                                 "station.csv)."),
        as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
        wind: float = typer.Option(5.0, "--wind", help="Wind speed, m/s (0: Cox & Munk's calm sea)."),
        wind_unc: float = typer.Option(2.0, "--wind-sigma", help="1-σ of the wind speed, m/s."),
        view_deg: float = typer.Option(40.0, "--view-deg", help="The water photo's angle from nadir, degrees."),
        azimuth_deg: float = typer.Option(135.0, "--azimuth-deg", help="The water photo's azimuth from the sun, "
                                          "degrees (recorded; the protocol's 135 keeps glitter out)."),
        card_reflectance: Path = typer.Option(None, "--card-reflectance", help="The card's measured reflectance: "
                                              "CSV wavelength_nm,reflectance[,sigma] (default 18 % flat ± 0.36 %)."),
        sky_model: str = typer.Option("cie", "--sky-model", help="ρ's sky: cie (the CIE standard "
                                      "clear sky for the sun's position; needs the sun; the default) or uniform."),
        sun: str = typer.Option("auto", "--sun", help="auto (the card photo's EXIF time and GPS position) or "
                                "ZENITH,AZIMUTH in degrees."),
        utc_offset: str = typer.Option(None, help="--sun auto: the camera clock's offset from UTC, +HH:MM."),
        station: str = typer.Option(None, "--station", help="The station's name in the CSV (default: the output "
                                    "folder's name)."),
        survey: Path = typer.Option(None, "--survey", help="A survey table (CSV) to add this station's row to "
                                    "(created if absent; a row of the same station is replaced)."),
    ) -> None:
        """Remote-sensing reflectance Rrs per band (sr⁻¹) from photos of the water, the sky and a grey card, with
        its σ and dominant term; turbidity (FNU) and SPM (g m⁻³) from the red band; band ratios."""
        if not (0 <= wind <= 30 and 0 <= wind_unc <= 30 and 0 <= view_deg < 85):
            raise CamcalError("--wind and --wind-sigma must be 0-30 m/s, --view-deg 0-85")
        if sky_model not in ("uniform", "cie"):
            raise CamcalError(f"--sky-model {sky_model!r}: choose uniform or cie")
        note = None
        if sun.strip().lower() == "auto":
            try:
                position = photo_sun(card[0], utc_offset=utc_offset)
            except CamcalError as exc:
                position, note = None, f"sun unknown ({exc}); the light is taken flat"
        else:
            position = parse_sun_option(sun)
        name = station or (out.name if out is not None else card[0].parent.name)
        with progress() as bar:
            task = bar.add_task("rrs", total=len(water) + len(sky) + len(card))
            st = run_rrs(profile, list(water), list(sky), list(card), sun=position, view_deg=view_deg,
                         relative_azimuth_deg=azimuth_deg, wind_m_s=wind, wind_sigma_m_s=wind_unc,
                         card_csv=card_reflectance, sky_model=sky_model, progress=lambda: bar.advance(task))
        if note:
            st.meta["notes"].insert(0, note)
        page = write_page(st, out, name) if out is not None else None
        if survey is not None:
            append_survey(survey, station_row(st, name))
        r = st.result
        if as_json:
            print_json({**station_json(st), "station": name, "page": None if page is None else str(page)})
            return
        for p in st.water:
            if p.rejected:
                console.print(f"{p.name}: left out: {p.rejected}", markup=False)
        table = Table(title=f"Rrs at {name} (ρ = {r.rho.value:.4f} ± {r.rho.sigma:.4f})", title_justify="left")
        for col in ("band", "λ_eff (nm)", "Rrs (sr⁻¹)", "σ (sr⁻¹)", "dominant σ term", "HydroColor method"):
            table.add_column(col, justify="left" if col in ("band", "dominant σ term") else "right")
        for b in BANDS:
            table.add_row(b, f"{st.effective_wavelength_nm[b]:.1f}", f"{r.rrs[b]:.5f}", f"{r.sigma[b]:.2g}",
                          r.dominant[b], f"{r.hydrocolor[b]:.5f}")
        console.print(table)
        for k, (v, s) in r.ratios.items():
            console.print(f"{k} = {v:.4f} ± {s:.2g}", markup=False)
        for p in st.products.values():
            console.print(f"{p.quantity} = {p.value:.4g} ± {p.sigma:.2g} {p.unit} ({p.algorithm} at "
                          f"{p.wavelength_nm:.0f} nm; {p.validity})", markup=False)
        for n in st.meta["notes"]:
            console.print(f"note: {n}", markup=False)
        if page is not None:
            console.print(f"wrote {page}", markup=False)

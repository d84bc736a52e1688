"""``camcal curves list``: the bundled camera-curve library (camcal.curves.library)."""

from __future__ import annotations

import typer
from rich.table import Table

from camcal.cli.common import console, err_console, print_json
from camcal.curves.library import COLLECTION, NO_CURVES_NEXT_STEP, list_cameras


def register(app: typer.Typer) -> None:
    grp = typer.Typer(help="The bundled library of measured camera spectral sensitivities.", no_args_is_help=True)
    app.add_typer(grp, name="curves")

    @grp.command("list")
    def list_cmd(
        search: str | None = typer.Option(None, "--search", help="Keep cameras whose make and model contain this "
                                          "text (case, spaces, underscores and hyphens ignored)."),
        as_json: bool = typer.Option(False, "--json", help="Print the list as JSON."),
    ) -> None:
        """List the library's cameras (use a name with profile import-spectral --camera)."""
        cams = list_cameras(search)
        if not cams and search is not None:  # a search that finds nothing is a failed look-up: exit 1
            if as_json:
                print_json([])
            err_console.print(f"no camera in the library matches {search!r}; {NO_CURVES_NEXT_STEP}",
                              soft_wrap=True, markup=False, highlight=False)
            raise typer.Exit(1)
        if as_json:
            print_json([{"name": c.name, "make": c.make, "model": c.model, "file": c.file, "creator": c.creator,
                         "equipment": c.equipment, "license": c.license} for c in cams])
            return
        if not cams:
            console.print(f"no camera in the library matches {search!r}")
            return
        table = Table("camera", "measured by", "file", title=f"{len(cams)} cameras ({COLLECTION})",
                      title_justify="left")
        for c in cams:
            table.add_row(c.name, " / ".join(x for x in (c.creator, c.equipment) if x) or "—", c.file)
        console.print(table)

"""Seed §5 reproduced: ratio against depth (10-50 cm at 1e-7 mol/L) and against concentration
(1e-7…5e-7 mol/L at 20 cm), θc = π/2.1, ρ = 1; the exact eq. 10 beside the first-order eq. 11 and the
appendix's second-order (k, q) model; and the inversions (eq. 11, the appendix as written, its algebra
corrected, its (k, q) model solved exactly) against the exact one over the seed's ranges."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from camcal.io.atomic import atomic_write_text
from camcal.report.plots import seed_ratio_figure, write_png
from camcal.water.models import SeedModel


def seed_section5_tables(model: SeedModel | None = None, points: int = 81) -> dict[str, np.ndarray]:
    """The two §5 curves as arrays: columns (x, exact eq. 10, first-order eq. 11, relative error of eq. 11)."""
    model = model or SeedModel()
    depth_m = np.linspace(0.10, 0.50, points)
    conc = np.linspace(1e-7, 5e-7, points)
    out = {}
    for name, x, c, d in (("depth", depth_m, 1e-7, depth_m), ("concentration", conc, conc, 0.20)):
        exact = model.ratio(c, d)
        first = model.ratio_first_order(c, d)
        second = model.ratio_second_order(c, d)
        out[name] = np.column_stack([x, exact, first, first / exact - 1.0, second])
    return out


#: The seed's ranges for the comparison table: depth, cm, and concentration, mol/L (§5; 1e-8 added).
APPENDIX_DEPTHS_CM = (10, 20, 30, 50)
APPENDIX_CONCENTRATIONS_MOL_PER_L = (1e-8, 1e-7, 2e-7, 3e-7, 5e-7)


def appendix_comparison(model: SeedModel | None = None) -> list[dict]:
    """Each (d, C) of the seed's ranges: the exact eq. 10 ratio and the C read from it by eq. 11, by the
    appendix's last line as written, by its algebra corrected (same linearisation) and by its (k, q) model
    solved exactly; the relative errors against the true C, and the (k, q) model's own forward error."""
    model = model or SeedModel()
    rows = []
    for d_cm in APPENDIX_DEPTHS_CM:
        d = d_cm / 100.0
        k, q = model.appendix_k_q(d)
        for c in APPENDIX_CONCENTRATIONS_MOL_PER_L:
            r = float(model.ratio(c, d))
            reads = {"eq11": float(model.invert_first_order(r, d)),
                     "appendix_as_written": float(model.invert_appendix_as_written(r, d)),
                     "appendix_corrected": float(model.invert_appendix_corrected(r, d)),
                     "second_order_exact": float(model.invert_second_order(r, d))}
            rows.append({"depth_cm": d_cm, "c_mol_per_L": c, "ratio_exact": r, "k": k, "q_per_mol_per_L": float(q),
                         "second_order_ratio_error": float(model.ratio_second_order(c, d)) / r - 1.0,
                         **{f"c_{n}": v for n, v in reads.items()},
                         **{f"error_{n}": v / c - 1.0 for n, v in reads.items()}})
    return rows


def appendix_markdown(rows: list[dict]) -> str:
    """The comparison as a Markdown table (relative errors of C; the as-written value in mol/L)."""
    lines = ["| d | C (mol/L) | eq. 11 | appendix as written (C read, mol/L) | appendix, algebra corrected | "
             "(k, q) model solved exactly | (k, q) model's ratio error |", "|---|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['depth_cm']} cm | {r['c_mol_per_L']:.0e} | {100 * r['error_eq11']:+.1f} % | "
                     f"{r['c_appendix_as_written']:.3g} | {100 * r['error_appendix_corrected']:+.1f} % | "
                     f"{100 * r['error_second_order_exact']:+.1f} % | {100 * r['second_order_ratio_error']:+.1f} % |")
    return "\n".join(lines) + "\n"


def simulate_seed_section5(outdir: str | Path, model: SeedModel | None = None) -> list[Path]:
    """Write ``ratio_vs_depth.csv``, ``ratio_vs_concentration.csv`` and a PNG of each
    (:func:`camcal.report.plots.seed_ratio_figure`), and the appendix comparison (CSV and Markdown)."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    tables = seed_section5_tables(model)
    written = []
    heads = {"depth": "depth_m", "concentration": "c_mol_per_L"}
    for name, t in tables.items():
        lines = [f"# seed §5: theta_c = pi/2.1, albedo 1, epsilon {SeedModel().epsilon_L_per_mol_cm:.1f} L/mol/cm",
                 f"{heads[name]},ratio_exact_eq10,ratio_first_order_eq11,relative_error_eq11,"
                 "ratio_second_order_appendix"]
        lines += [",".join(f"{v:.10g}" for v in row) for row in t]
        csv = outdir / f"ratio_vs_{name}.csv"
        atomic_write_text(csv, "\n".join(lines) + "\n")
        png = write_png(seed_ratio_figure(t, name), outdir / f"ratio_vs_{name}.png")
        written += [csv, png]
    rows = appendix_comparison(model)
    cols = list(rows[0])
    lines = ["# seed appendix 6.1: C read from the exact eq. 10 ratio by eq. 11, the appendix's last line as written, "
             "its algebra corrected and its (k, q) model solved exactly (theta_0 = 0); errors relative to the true C",
             ",".join(cols)] + [",".join(f"{r[c]:.10g}" for c in cols) for r in rows]
    csv = outdir / "appendix_comparison.csv"
    atomic_write_text(csv, "\n".join(lines) + "\n")
    md = outdir / "appendix_comparison.md"
    atomic_write_text(md, appendix_markdown(rows))
    written += [csv, md]
    return written

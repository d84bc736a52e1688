"""Seed §5 reproduced: ratio against depth (10-50 cm at 1e-7 mol/L) and against concentration
(1e-7…5e-7 mol/L at 20 cm), θc = π/2.1, ρ = 1; the exact eq. 10 beside the first-order eq. 11."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from camcal.atomic import atomic_path, atomic_write_text
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
        out[name] = np.column_stack([x, exact, first, first / exact - 1.0])
    return out


def simulate_seed_section5(outdir: str | Path, model: SeedModel | None = None) -> list[Path]:
    """Write ``ratio_vs_depth.csv``, ``ratio_vs_concentration.csv`` and a PNG of each (matplotlib, Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    tables = seed_section5_tables(model)
    written = []
    heads = {"depth": "depth_m", "concentration": "c_mol_per_L"}
    for name, t in tables.items():
        lines = [f"# seed §5: theta_c = pi/2.1, albedo 1, epsilon {SeedModel().epsilon_L_per_mol_cm:.1f} L/mol/cm",
                 f"{heads[name]},ratio_exact_eq10,ratio_first_order_eq11,relative_error_eq11"]
        lines += [",".join(f"{v:.10g}" for v in row) for row in t]
        csv = outdir / f"ratio_vs_{name}.csv"
        atomic_write_text(csv, "\n".join(lines) + "\n")
        fig, ax = plt.subplots(figsize=(6, 4))
        x = t[:, 0] * (100 if name == "depth" else 1)
        ax.semilogy(x, t[:, 1], label="exact (eq. 10, E₃ closed form)")
        ax.semilogy(x, t[:, 2], "--", label="first order (eq. 11)")
        ax.set_xlabel("depth (cm)" if name == "depth" else "C (mol/L)")
        ax.set_ylabel("L_i / L_s at 663 nm")
        ax.set_title("1e-7 mol/L" if name == "depth" else "d = 20 cm")
        ax.legend()
        fig.tight_layout()
        png = outdir / f"ratio_vs_{name}.png"
        with atomic_path(png) as tmp:
            fig.savefig(tmp, format="png", dpi=100)
        plt.close(fig)
        written += [csv, png]
    return written

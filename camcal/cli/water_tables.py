"""Rich tables of ``camcal water`` for people (``--json`` prints the same content as JSON)."""

from __future__ import annotations

import math

from rich.table import Table

from camcal.units import CONCENTRATION


def _num(v, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    return f"{float(v):.{digits}g}"


def forward_table(doc: dict) -> Table:
    """Predicted ratio L_sub/L_ref: one row per depth, one column per concentration."""
    t = Table(title=f"predicted ratio L_sub/L_ref ({doc.get('model')} model, {doc.get('inversion')})",
              title_justify="left")
    t.add_column("depth (m)", justify="right")
    for c in doc["c_ug_per_L"]:
        t.add_column(f"C = {_num(c)} {CONCENTRATION}", justify="right")
    for d, row in zip(doc["depth_m"], doc["ratio"], strict=True):
        t.add_row(_num(d), *[_num(v, 5) for v in row])
    return t


def ratio_table(doc: dict) -> Table:
    """``invert --ratio``: C ± σ_C per ratio, the dominant term and the reason."""
    t = Table(title=f"chlorophyll-a from ratios ({doc.get('model')} model, {doc.get('inversion')}, depth "
                    f"{_num(doc.get('depth_m'))} m)", title_justify="left")
    for col in ("ratio", f"C ({CONCENTRATION})", f"σ_C ({CONCENTRATION})", "largest σ term", "reason"):
        t.add_column(col, justify="left" if col in ("largest σ term", "reason") else "right")
    terms = doc.get("sigma_terms_ug_per_L") or {}
    for i, r in enumerate(doc["ratio"]):
        each = {k: v[i] for k, v in terms.items() if v[i] is not None}
        big = max(each, key=each.get) if each else "—"
        t.add_row(_num(r, 5), _num(doc["c_ug_per_L"][i]), _num(doc["sigma_ug_per_L"][i], 2), big, doc["reason"][i])
    return t


def summary_table(summary: dict) -> Table:
    """``invert`` of images: pixel counts, the distribution of C and the σ_C terms."""
    t = Table(title="chlorophyll-a per pixel", title_justify="left", show_header=False)
    t.add_column("quantity")
    t.add_column("value", justify="right")
    t.add_row("pixels (valid / all)", f"{summary.get('valid')} / {summary.get('pixels')}")
    reasons = {k: v for k, v in (summary.get("reasons") or {}).items() if k != "ok" and v}
    if reasons:
        t.add_row("left out", ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in reasons.items()))
    t.add_row(f"median C ({CONCENTRATION})", _num(summary.get("median_ug_per_L")))
    t.add_row(f"mean C ({CONCENTRATION})", _num(summary.get("mean_ug_per_L")))
    t.add_row(f"5–95 % of pixels ({CONCENTRATION})",
              f"{_num(summary.get('p05_ug_per_L'))} – {_num(summary.get('p95_ug_per_L'))}")
    unc = summary.get("uncertainty") or {}
    for k, v in (unc.get("median_terms_ug_per_L") or {}).items():
        t.add_row(f"σ_C term {k} (median, {CONCENTRATION})", _num(v, 2))
    if unc.get("dominant"):
        t.add_row("dominant σ term", str(unc["dominant"]))
    if unc.get("not_stated"):
        t.add_row("not stated (no σ)", ", ".join(unc["not_stated"]))
    if unc.get("note"):
        t.add_row("note", unc["note"])
    return t

"""Write a bench run: ``report.md``, one CSV per table, one PNG per plot and ``summary.md`` (the
README-ready condensed tables), into a folder.

Plots use matplotlib's object API (``Figure`` + ``FigureCanvasAgg``): no pyplot, no global state.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bentray.engine.bench.common import Plot, Section, Table, fmt

__all__ = ["write_csv", "draw_plot", "markdown_table", "write_report", "summary_markdown"]

# README-ready condensed tables: table name -> (heading, columns, row filter)
SUMMARY: list[tuple[str, str, list[str], Any]] = [
    (
        "speedup",
        "Time to reach a target error (A-LD / A-LU / V-IM / V-SM), analytic vs the best baseline",
        [
            "case",
            "target",
            "analytic_setting",
            "analytic_time_s",
            "best_exact",
            "best_exact_time_s",
            "speedup_vs_exact",
            "best_mesh",
            "best_mesh_time_s",
            "speedup_vs_mesh",
        ],
        lambda r: r["target"] in (1e-3, 1e-4, 1e-5),
    ),
    (
        "stalls",
        "Where the baselines stop converging",
        ["case", "family", "best_error", "best_setting", "finest_error"],
        lambda r: r["stalls"] is True and not str(r["family"]).startswith("analytic"),
    ),
    (
        "fig3_convergence",
        "Fig. 3: worst relative position / arc-length error against the closed forms",
        ["profile", "curve", "epsilon", "layers", "position_error_max", "arc_length_error_max"],
        None,
    ),
    (
        "table2_same_quality",
        "Table 2: cost at the same quality",
        [
            "case",
            "target",
            "config",
            "reached",
            "setting",
            "cells",
            "segments_per_path",
            "error_max",
            "trace_time_s",
            "time_vs_parabolic_adaptive",
        ],
        None,
    ),
    (
        "table3_breakdown",
        "Table 3: time breakdown",
        [
            "scene",
            "curve",
            "cells",
            "rays",
            "segments",
            "total_s",
            "setup_pct",
            "face_intersections_pct",
            "advance_pct",
            "other_pct",
            "ns_per_segment",
            "note",
        ],
        None,
    ),
    (
        "fig8_scaling",
        "Fig. 8: scaling",
        [
            "study",
            "variant",
            "x_value",
            "cells",
            "surfaces",
            "crossings_per_ray",
            "us_per_ray",
            "ns_per_crossing",
            "note",
        ],
        None,
    ),
    (
        "throughput",
        "Throughput",
        [
            "scene",
            "cells",
            "rays",
            "threads",
            "trace_time_s",
            "crossings_per_ray",
            "crossings_per_s_per_core",
            "rays_per_s",
            "note",
        ],
        None,
    ),
    (
        "extreme_cases",
        "Stiff and extreme cases",
        ["case", "method", "media", "rays", "error_max", "trace_time_s", "lost", "below_ground", "status", "note"],
        None,
    ),
]

# Tables with more rows than this are only linked from report.md (the CSV has them all).
MAX_INLINE_ROWS = 60


def write_csv(table: Table, path: Path) -> Path:
    """Write ``table`` as CSV (header = columns; floats in repr precision)."""
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(table.columns)
        for row in table.rows:
            w.writerow([_csv_cell(row.get(c, "")) for c in table.columns])
    return path


def _csv_cell(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, dict):
        return "; ".join(f"{k} {x}" for k, x in v.items())
    return v


def markdown_table(table: Table, columns: Sequence[str] | None = None) -> str:
    """A markdown table of ``table`` (all columns unless ``columns`` names a subset)."""
    cols = list(columns) if columns is not None else table.columns
    lines = ["| " + " | ".join(cols) + " |", "|" + " --- |" * len(cols)]
    for row in table.rows:
        lines.append("| " + " | ".join(fmt(row.get(c, "")).replace("|", "/") for c in cols) + " |")
    return "\n".join(lines)


def draw_plot(plot: Plot, path: Path) -> Path:
    """Draw ``plot`` (panels side by side, two per row) into a PNG at ``path``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = max(1, len(plot.panels))
    ncols = 1 if n == 1 else 2
    nrows = math.ceil(n / ncols)
    fig = Figure(figsize=(6.0 * ncols, 4.2 * nrows), dpi=100)
    FigureCanvasAgg(fig)
    fig.suptitle(plot.title)
    for i, panel in enumerate(plot.panels):
        ax = fig.add_subplot(nrows, ncols, i + 1)
        for s in panel.get("series", []):
            pts = [(x, y) for x, y in zip(s.x, s.y, strict=True) if _plottable(x, y, panel)]
            if not pts:
                continue
            ax.plot(
                [p[0] for p in pts],
                [p[1] for p in pts],
                marker=s.marker,
                linestyle=s.linestyle,
                label=s.label,
                markersize=4,
            )
        if panel.get("xlog"):
            ax.set_xscale("log")
        if panel.get("ylog"):
            ax.set_yscale("log")
        if panel.get("hline") is not None:
            ax.axhline(panel["hline"], color="grey", linewidth=0.8, linestyle=":")
        ax.set_title(panel.get("title", ""))
        ax.set_xlabel(panel.get("xlabel", ""))
        ax.set_ylabel(panel.get("ylabel", ""))
        ax.grid(True, which="both", linewidth=0.3)
        if panel.get("series"):
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    return path


def _plottable(x: Any, y: Any, panel: dict[str, Any]) -> bool:
    try:
        xf, yf = float(x), float(y)
    except (TypeError, ValueError):
        return False
    if not (math.isfinite(xf) and math.isfinite(yf)):
        return False
    return not ((panel.get("xlog") and xf <= 0) or (panel.get("ylog") and yf <= 0))


def summary_markdown(sections: Sequence[Section], machine: dict[str, Any], *, quick: bool) -> str:
    """README-ready condensed tables of a bench run (the sections' key columns and rows)."""
    tables = {t.name: t for sec in sections for t in sec.tables}
    lines = [
        f"Measured by `bentray bench{' --quick' if quick else ''}` on {machine.get('cpu')} "
        f"({machine.get('cores')} cores; comparative timings on 1 numba thread), {machine.get('date_utc')} UTC; "
        f"numpy {machine.get('numpy')}, numba {machine.get('numba')}.",
        "",
    ]
    for sec in sections:
        for para in sec.text:
            if para.startswith("**"):
                lines += [para, ""]
    for name, heading, cols, keep in SUMMARY:
        if name not in tables:
            continue
        sub = Table(name, heading, cols, [r for r in tables[name].rows if keep is None or keep(r)])
        if sub.rows:
            lines += [f"**{heading}**", "", markdown_table(sub), ""]
    return "\n".join(lines)


def write_report(
    out_dir: Path, sections: Sequence[Section], machine: dict[str, Any], *, quick: bool, command: str, wall_s: float
) -> Path:
    """Write every section's tables (CSV), plots (PNG) and ``report.md``; returns the report path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = [
        "# bentray bench" + (" (quick)" if quick else ""),
        "",
        f"Command: `{command}`; total wall time {wall_s:.1f} s.",
        "",
        "| machine | |",
        "| --- | --- |",
    ]
    lines += [f"| {k} | {v} |" for k, v in machine.items()]
    lines += [
        "",
        "Timings are wall-clock seconds of warm runs (Numba compiled first), the best of N repeats; "
        "the machine may be shared, so small differences are noise.",
        "",
    ]
    lines.append("Sections: " + ", ".join(f"[{s.title}](#{s.key})" for s in sections))
    lines.append("")
    for sec in sections:
        lines += [f'<a id="{sec.key}"></a>', f"## {sec.title}", "", f"_{sec.status}; {sec.wall_s:.1f} s_", ""]
        for para in sec.text:
            lines += [para, ""]
        for table in sec.tables:
            csv_path = write_csv(table, out_dir / f"{table.name}.csv")
            lines += [f"**{table.title}** (`{csv_path.name}`)", ""]
            if len(table.rows) <= MAX_INLINE_ROWS:
                lines += [markdown_table(table), ""]
            else:
                lines += [f"{len(table.rows)} rows: see the CSV.", ""]
        for plot in sec.plots:
            png = draw_plot(plot, out_dir / f"{plot.name}.png")
            lines += [f"![{plot.title}]({png.name})", ""]
    (out_dir / "summary.md").write_text(summary_markdown(sections, machine, quick=quick), encoding="utf-8")
    path = out_dir / "report.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path

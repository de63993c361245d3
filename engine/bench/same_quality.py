"""Table 2: what each curve / mesh combination costs to reach the same quality.

For a target worst relative position error (1e-4; also 1e-5 in the full run) on A-LD (and A-LU in the full
run), each configuration's mesh is refined step by step (coarse to fine) until the target is met:

- parabolic + adaptive mesh: slabs by the curvature rule, delta 1e-4, 3e-5, 1e-5, ... (the default rule);
- parabolic + adaptive mesh, paper's rule: slabs by the gradient rule, epsilon 1e-3, 3e-4, ... (full run);
- circular + adaptive mesh (curvature rule on c; full run);
- n-linear + adaptive mesh: the curvature rule on n; plane exits by bisection (docs/physics.md §4);
- n-linear + bisection, uniform layers: Cao et al.'s setting (equal layers, catenary, bisection);
- parabolic + uniform layers: the parabolic curve without the adaptive mesh.
Uniform layer counts double from 1,024. The row reported per target is the first (coarsest) mesh that
meets it: cells, segments per path (cell steps per ray), trace time (best of the warm runs) and error.
Errors against DOP853 at rtol 1e-13 (baselines_probe.reference_positions).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from bentray.engine.bench.baselines_probe import CASES, StratifiedCase, reference_positions
from bentray.engine.bench.common import Plot, Section, Series, Table, best_time, fmt, on_timing_threads
from bentray.engine.constants import CURVE_QUANTITY
from bentray.engine.media import build_media
from bentray.engine.mesh.slabs import build_slab_mesh, locate_in_slabs
from bentray.engine.tracer import trace
from bentray.scenes.schema import Solver

__all__ = ["CONFIGS", "run"]

# name -> (curve, mesh kind); mesh kind: "curvature" | "gradient" | "uniform"
CONFIGS: dict[str, tuple[str, str]] = {
    "parabolic + adaptive mesh": ("parabolic", "curvature"),
    "parabolic + adaptive mesh (paper's gradient rule)": ("parabolic", "gradient"),
    "circular + adaptive mesh": ("circular", "curvature"),
    "n-linear + adaptive mesh": ("n_linear", "curvature"),
    "n-linear + bisection, uniform layers (Cao et al.)": ("n_linear", "uniform"),
    "parabolic + uniform layers": ("parabolic", "uniform"),
}
QUICK_CONFIGS = (
    "parabolic + adaptive mesh",
    "n-linear + adaptive mesh",
    "n-linear + bisection, uniform layers (Cao et al.)",
    "parabolic + uniform layers",
)
MAX_UNIFORM_LAYERS = 2**17
SEARCH_COLUMNS = ["case", "config", "setting", "cells", "segments_per_path", "error_max", "trace_time_s", "lost"]
COLUMNS = [
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
]


def _settings(kind: str) -> Iterator[float]:
    if kind == "uniform":
        n = 1024
        while n <= MAX_UNIFORM_LAYERS:
            yield float(n)
            n *= 2
        return
    start, stop = (1e-4, 1e-11) if kind == "curvature" else (1e-3, 1e-9)
    k = 0
    while True:
        v = start * 10.0 ** (-k / 2.0)  # half decades
        if v < stop:
            return
        yield float(f"{v:.0e}")
        k += 1


def _mesh(case: StratifiedCase, profile: Any, curve: str, kind: str, setting: float) -> tuple[Any, Any, str]:
    lo = np.asarray(case.domain_min, float)
    hi = np.asarray(case.domain_max, float)
    if kind == "uniform":
        z = np.linspace(lo[2], hi[2], int(setting) + 1)
        q = CURVE_QUANTITY[curve]

        def m_of_z(zz: np.ndarray) -> np.ndarray:
            zz = np.atleast_1d(zz)
            return profile.quantity(q, np.column_stack([np.zeros_like(zz), np.zeros_like(zz), zz]))

        mesh = build_slab_mesh(lo, hi, z, m_of_z)
        return mesh, (lambda xyz: locate_in_slabs(z, xyz)), f"{int(setting):,} layers"
    if kind == "gradient":
        solver = Solver(curve=curve, sizing="gradient", epsilon=setting)
        label = f"eps={setting:g}"
    else:
        solver = Solver(curve=curve, delta=setting)
        label = f"delta={setting:g}"
    med = build_media(profile, curve, solver, lo, hi)
    return med.mesh, med.locate, label


def _search(
    case: StratifiedCase, config: str, count: int, ref: np.ndarray, finest_target: float, min_total_s: float
) -> list[dict[str, Any]]:
    curve, kind = CONFIGS[config]
    profile = case.profile()
    origins, dirs = case.fan(count)
    rows = []
    for setting in _settings(kind):
        mesh, locate, label = _mesh(case, profile, curve, kind, setting)
        cells = locate(origins)

        def run(mesh: Any = mesh, cells: np.ndarray = cells) -> Any:
            return trace(
                mesh,
                curve,
                case.c_ref,
                origins,
                dirs,
                cells,
                max_time_s=case.t_end,
                max_reflections=case.max_reflections,
            )

        trace(mesh, curve, case.c_ref, origins[:1], dirs[:1], cells[:1], max_time_s=1e-3, max_reflections=1)
        elapsed, res = best_time(run, 1, min_total_s)
        err = float(np.max(np.linalg.norm(res.position - ref, axis=1)) / case.norm_m)
        rows.append(
            {
                "case": case.key,
                "config": config,
                "setting": label,
                "cells": mesh.n_cells,
                "segments_per_path": float(res.steps.mean()),
                "error_max": err,
                "trace_time_s": elapsed,
                "lost": res.status_counts()["lost"],
            }
        )
        if err <= finest_target:
            break
    return rows


@on_timing_threads
def run(quick: bool) -> Section:
    """Quick: A-LD, 13 rays, target 1e-4, four configurations; full: A-LD and A-LU, 91 rays, 1e-4 and 1e-5."""
    count = 13 if quick else 91
    targets = (1e-4,) if quick else (1e-4, 1e-5)
    cases = ("A-LD",) if quick else ("A-LD", "A-LU")
    configs = QUICK_CONFIGS if quick else tuple(CONFIGS)
    search = Table("table2_search", "Table 2: every mesh tried (coarse to fine)", SEARCH_COLUMNS)
    table = Table("table2_same_quality", "Table 2: cost at the same quality", COLUMNS)
    for key in cases:
        case = CASES[key]
        _, dirs = case.fan(count)
        ref = reference_positions(dirs, case=case)
        found: dict[str, list[dict[str, Any]]] = {}
        for config in configs:
            found[config] = _search(case, config, count, ref, min(targets), 0.05 if quick else 0.3)
            for r in found[config]:
                search.add(**r)
        for target in targets:
            base_time = math.nan
            for config in configs:
                hit = next((r for r in found[config] if r["error_max"] <= target), None)
                r = hit if hit is not None else found[config][-1]
                if config == "parabolic + adaptive mesh" and hit is not None:
                    base_time = r["trace_time_s"]
                table.add(
                    case=key,
                    target=target,
                    config=config,
                    reached=hit is not None,
                    setting=r["setting"],
                    cells=r["cells"],
                    segments_per_path=r["segments_per_path"],
                    error_max=r["error_max"],
                    trace_time_s=r["trace_time_s"],
                    time_vs_parabolic_adaptive=r["trace_time_s"] / base_time if hit is not None else math.nan,
                )
    sec = Section("same_quality", "Same-quality comparison (Table 2)")
    sec.text.append(
        f"{count} rays, elevations -45..45 degrees, source 1.5 m, 10 s. For each target the coarsest mesh of each "
        "configuration that reaches it (meshes refined by half decades of delta / epsilon, or doubling uniform "
        "layer counts up to 131,072). `segments per path` = cell steps per ray. `reached = False` rows show the "
        "finest mesh tried. Trace time: best of the warm runs (more tries for short runs); mesh build excluded."
    )
    for r in table.rows:
        if r["config"].startswith("n-linear + adaptive") and r["reached"]:
            par = next(
                p
                for p in table.rows
                if p["case"] == r["case"] and p["target"] == r["target"] and p["config"] == "parabolic + adaptive mesh"
            )
            sec.text.append(
                f"{r['case']} at {r['target']:g}: n-linear + adaptive mesh {fmt(r['segments_per_path'])} segments per "
                f"path vs parabolic {fmt(par['segments_per_path'])}, {fmt(r['time_vs_parabolic_adaptive'])}x the "
                "parabolic time (its plane exits are found by bisection)."
            )
    sec.tables += [table, search]
    panels = []
    for key in cases:
        series = []
        for config in configs:
            rs = [r for r in search.rows if r["case"] == key and r["config"] == config]
            series.append(Series(config, [r["trace_time_s"] for r in rs], [r["error_max"] for r in rs]))
        panels.append(
            {
                "title": key,
                "xlabel": "trace time (s)",
                "ylabel": "worst relative position error",
                "xlog": True,
                "ylog": True,
                "series": series,
                "hline": min(targets),
            }
        )
    sec.plots.append(Plot("table2_same_quality", "Error against time per curve / mesh configuration", panels))
    return sec

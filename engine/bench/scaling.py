"""Fig. 8: trace time against media gradient magnitude, cell count and surface count.

(a) gradient magnitude: the log profile c = 340 + b ln(z + 1) with b scaled (A-LD is b = 1 m/s), each on
    its default slab mesh (curvature rule, delta 1e-8), the A-LD fan (source 1.5 m, -45..45 degrees, 10 s);
(b) cell count: A-LD on slab meshes from delta 1e-5 to 1e-10, same fan; in the full run also the
    desert scene's terrain mesh at three horizontal spacings (rays over the sphere, 10 s, 3 reflections);
(c) surface count: the christmas village with 0, 10, 20 and 40 of its buildings (each adds wall and roof
    faces; the horizontal spacing is fixed, so the cell count changes only near the new footprints).
Every time is a warm trace (best of the runs); scene rows are skipped with the reason when the terrain
mesh builder fails.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import numpy as np

from bentray.engine.bench.baselines_probe import CASES, StratifiedCase
from bentray.engine.bench.common import Plot, Section, Series, Table, best_time, on_timing_threads
from bentray.engine.bench.scene_meshes import SceneUnavailable, build_scene_mesh
from bentray.engine.media import build_media
from bentray.engine.tracer import trace
from bentray.scenes.schema import Solver

__all__ = ["run"]

COLUMNS = [
    "study",
    "variant",
    "x_value",
    "cells",
    "surfaces",
    "rays",
    "crossings_per_ray",
    "reflections_per_ray",
    "trace_time_s",
    "us_per_ray",
    "ns_per_crossing",
    "lost",
    "note",
]


def _time(
    mesh: Any,
    origins: np.ndarray,
    dirs: np.ndarray,
    cells: np.ndarray,
    t_end: float,
    max_refl: int,
    repeats: int,
    min_total_s: float,
) -> tuple[float, Any]:
    trace(mesh, "parabolic", 340.0, origins[:1], dirs[:1], cells[:1], max_time_s=1e-3, max_reflections=1)
    return best_time(
        lambda: trace(mesh, "parabolic", 340.0, origins, dirs, cells, max_time_s=t_end, max_reflections=max_refl),
        repeats,
        min_total_s,
    )


def _row(
    table: Table,
    study: str,
    variant: str,
    x: float,
    mesh: Any,
    res: Any,
    elapsed: float,
    surfaces: int | str = "",
    note: str = "",
) -> None:
    n = res.n_rays
    crossings = float(res.crossings.sum())
    table.add(
        study=study,
        variant=variant,
        x_value=x,
        cells=mesh.n_cells,
        surfaces=surfaces,
        rays=n,
        crossings_per_ray=crossings / n,
        reflections_per_ray=float(res.reflections.mean()),
        trace_time_s=elapsed,
        us_per_ray=1e6 * elapsed / n,
        ns_per_crossing=1e9 * elapsed / max(crossings, 1.0),
        lost=res.status_counts()["lost"],
        note=note,
    )


class _Budget(NamedTuple):
    """Sizes and timing of one run: fan_rays (A-LD geometry), scene_rays (over the sphere), best of
    ``repeats`` runs (more while they add up to ``min_total`` s), and whether it is the quick run."""

    fan_rays: int
    scene_rays: int
    repeats: int
    min_total: float
    quick: bool


def _gradient_rows(table: Table, bud: _Budget) -> None:
    """(a) gradient magnitude: the log profile with b scaled, each on its default slab mesh, the A-LD fan."""
    base = CASES["A-LD"]
    for b in (0.5, 1.0, 4.0) if bud.quick else (0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0):
        case = StratifiedCase(
            f"b={b:g}", "log", {"c0": 340.0, "b": b, "z_g": 1.0}, base.t_end, base.domain_min, base.domain_max
        )
        med = build_media(case.profile(), "parabolic", Solver(), np.array(case.domain_min), np.array(case.domain_max))
        o, d = case.fan(bud.fan_rays)
        elapsed, res = _time(med.mesh, o, d, med.locate(o), case.t_end, 50, bud.repeats, bud.min_total)
        _row(
            table,
            "gradient",
            "log profile, default slab mesh",
            abs(b) / 1.0,
            med.mesh,
            res,
            elapsed,
            note=f"dc/dz at the ground = {b:g} 1/s",
        )


def _cell_rows(table: Table, bud: _Budget) -> None:
    """(b) cell count: A-LD on slab meshes from delta 1e-5 to 1e-10; in the full run also the desert
    scene's terrain mesh at three horizontal spacings (metres)."""
    base = CASES["A-LD"]
    o, d = base.fan(bud.fan_rays)
    for delta in (1e-6, 1e-8, 1e-10) if bud.quick else (1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10):
        med = build_media(
            base.profile(), "parabolic", Solver(delta=delta), np.array(base.domain_min), np.array(base.domain_max)
        )
        elapsed, res = _time(med.mesh, o, d, med.locate(o), base.t_end, 50, bud.repeats, bud.min_total)
        _row(table, "cells", "A-LD slabs", float(med.mesh.n_cells), med.mesh, res, elapsed, note=f"delta={delta:g}")
    if bud.quick:
        return
    for spacing in (62.5, 31.25, 20.0):
        try:
            sc = build_scene_mesh("desert", bud.scene_rays, horizontal_spacing_m=spacing)
        except SceneUnavailable as exc:
            table.add(study="cells", variant="desert terrain mesh", note=f"skipped: {exc}")
            continue
        elapsed, res = _time(sc.mesh, sc.origins, sc.directions, sc.start_cells, 10.0, 3, bud.repeats, bud.min_total)
        _row(
            table,
            "cells",
            "desert terrain mesh",
            float(sc.mesh.n_cells),
            sc.mesh,
            res,
            elapsed,
            surfaces=sc.surfaces,
            note=f"horizontal spacing {spacing:g} m",
        )


def _surface_rows(table: Table, bud: _Budget) -> None:
    """(c) surface count: the christmas village with 0 to 40 of its buildings (fixed horizontal spacing);
    a scene that cannot be built becomes a skipped row."""
    try:
        from bentray.scenes.library.registry import get_builtin

        village = get_builtin("christmas", "medium").surfaces
        for k in (0, 40) if bud.quick else (0, 10, 20, 40):
            surf = dataclasses.replace(village, footprints=list(village.footprints[:k]))
            try:
                sc = build_scene_mesh("christmas", bud.scene_rays, surfaces=surf)
            except SceneUnavailable as exc:
                table.add(study="surfaces", variant=f"christmas, {k} buildings", note=f"skipped: {exc}")
                continue
            elapsed, res = _time(
                sc.mesh, sc.origins, sc.directions, sc.start_cells, 10.0, 3, bud.repeats, bud.min_total
            )
            _row(
                table,
                "surfaces",
                f"christmas, {k} buildings",
                float(sc.surfaces),
                sc.mesh,
                res,
                elapsed,
                surfaces=sc.surfaces,
            )
    except Exception as exc:  # noqa: BLE001 - the scene library itself failed: report, do not abort the bench
        table.add(study="surfaces", variant="christmas", note=f"skipped: {type(exc).__name__}: {exc}")


def _scaling_plot(table: Table) -> Plot:
    """Log-log panels per study: us per ray and ns per crossing against the study's x value."""
    panels = []
    for study, xlabel in (
        ("gradient", "ground gradient |dc/dz| (1/s)"),
        ("cells", "cells"),
        ("surfaces", "reflecting surface triangles (ground + walls + roofs)"),
    ):
        series = []
        for variant in dict.fromkeys(r["variant"] for r in table.rows if r["study"] == study):
            rs = [r for r in table.rows if r["study"] == study and r["variant"] == variant and r["trace_time_s"] != ""]
            if rs:
                series.append(
                    Series(f"{variant}: us per ray", [r["x_value"] for r in rs], [r["us_per_ray"] for r in rs])
                )
                series.append(
                    Series(
                        f"{variant}: ns per crossing",
                        [r["x_value"] for r in rs],
                        [r["ns_per_crossing"] for r in rs],
                        marker="x",
                        linestyle="--",
                    )
                )
        panels.append(
            {"title": study, "xlabel": xlabel, "ylabel": "time", "xlog": True, "ylog": True, "series": series}
        )
    return Plot("fig8_scaling", "Trace time against gradient, cell count and surface count", panels)


@on_timing_threads
def run(quick: bool) -> Section:
    """Quick: fewer variants, 31-ray fans, 300-ray scenes, one run each; full: 91-ray fans, 2,000-ray scenes."""
    repeats, min_total = (1, 0.05) if quick else (3, 0.3)
    bud = _Budget(31 if quick else 91, 300 if quick else 2000, repeats, min_total, quick)
    table = Table("fig8_scaling", "Fig. 8: trace time against gradient, cells and surfaces", COLUMNS)
    _gradient_rows(table, bud)
    _cell_rows(table, bud)
    _surface_rows(table, bud)
    sec = Section("scaling", "Scaling (Fig. 8)")
    sec.text.append(
        f"Fans of {bud.fan_rays} rays (A-LD geometry) and {bud.scene_rays} rays over the sphere for scenes; best of "
        f"{repeats} warm run(s). `ns_per_crossing` = trace time / cell crossings: near-constant means the cost "
        "is the number of cells a ray crosses, whatever the gradient or the surface count. Larger gradients cost "
        "more only through the finer mesh the sizing rule builds for them and the extra reflections."
    )
    sec.tables.append(table)
    sec.plots.append(_scaling_plot(table))
    return sec

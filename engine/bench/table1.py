"""Table 1: the built-in scenes run end to end as jobs (the paper's Table 1 layout).

Each scene's ready-made job (scenes/library/jobs.py: its default profile, its wind where it has one, the
first source, 100 elevations x 100 azimuths = 10,000 rays over -45..45 degrees and all azimuths, 10 s, at
most 3 reflections) goes through ``run_job`` exactly as ``bentray run`` would run it. The table gives the
surfaces (triangles of the ground, walls and roofs in the mesh), the media points and cells, the mesh
build and trace times, and the rays by status: the "zero lost rays" claim of the README is this table's
``lost`` column. Quick: medium resolution only, 2,500 rays; full: medium and high, 10,000 rays.
The first job pays the Numba compilation when the cache is cold: its compile_s column says how much (the
trace_s column leaves it out).
"""

from __future__ import annotations

import time

from bentray.engine.bench.common import Section, Table
from bentray.scenes.library.registry import BUILTIN_SCENES

__all__ = ["run", "COLUMNS"]

COLUMNS = [
    "scene",
    "resolution",
    "surface_triangles",
    "buildings",
    "media_points",
    "cells",
    "layers",
    "representation",
    "mesh_build_s",
    "rays",
    "trace_s",
    "compile_s",
    "crossings_per_ray",
    "reflections_per_ray",
    "time_limit",
    "reflection_limit",
    "exited",
    "step_limit",
    "lost",
]


def run(quick: bool) -> Section:
    from bentray.engine.run import run_job
    from bentray.scenes.library.jobs import builtin_job

    section = Section("table1", "Built-in scenes end to end (Table 1)")
    table = Table("table1", "Built-in scenes: 3 reflections, 10 s, rays from the first source", COLUMNS)
    side = 50 if quick else 100
    resolutions = ("medium",) if quick else ("medium", "high")
    for resolution in resolutions:
        for name in BUILTIN_SCENES:
            t0 = time.perf_counter()
            outcome = run_job(
                builtin_job(
                    name, resolution=resolution, elevations=side, azimuths=side, max_time_s=10.0, max_reflections=3
                )
            )
            rep = outcome.report
            mesh = rep["mesh"]
            rays = rep["rays"]
            status = rays["by_status"]
            n = rays["total"]
            table.add(
                scene=name,
                resolution=resolution,
                surface_triangles=mesh.get("surface_triangles") or 2,
                buildings=mesh.get("buildings", 0),
                media_points=mesh.get("points"),
                cells=mesh.get("cells"),
                layers=mesh.get("layers"),
                representation=rep["representation"],
                mesh_build_s=rep["timings_s"]["mesh"],
                rays=n,
                trace_s=rep["timings_s"]["trace"] - rep["compile_s"].get("trace", 0.0),
                compile_s=rep["compile_s"]["total"],
                crossings_per_ray=rays["tet_crossings_total"] / n,
                reflections_per_ray=rays["reflections_total"] / n,
                time_limit=status["time_limit"],
                reflection_limit=status["reflection_limit"],
                exited=status["exited"],
                step_limit=status["step_limit"],
                lost=status["lost"],
            )
            section.text.append(f"{name} ({resolution}): {time.perf_counter() - t0:.1f} s wall")
    section.tables.append(table)
    section.text.insert(
        0,
        "Flat ground has 2 surface triangles' worth of ground (one slab face); its media are "
        "slabs, not a 3D mesh (the job needs none). `trace_s` is the trace without Numba compilation; "
        "`compile_s` is the job's compilation (report.json compile_s.total: non-zero for the first jobs of a "
        "cold cache, 0 once `bentray warmup` has run).",
    )
    return section

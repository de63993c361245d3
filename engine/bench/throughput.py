"""Throughput: cell crossings per second (per core) and rays per second, on the medium desert scene.

The desert scene's terrain mesh (scene_meshes.build_scene_mesh: native 31.25 m horizontal spacing,
terrain-following layers), rays spread evenly over the sphere from its source (2 m above the centre),
10 s, at most 3 reflections (the paper's Desert(m) run: 10K rays, 179 cells per ray, 3 reflections,
219 ms, about 8M crossings per second on one 3.2 GHz core in 2016). Timed with 1 numba thread and with
all of them (the thread count is restored afterwards); best of the warm runs. The A-LD slab mesh (delta
1e-8, the same sphere of rays from 1.5 m) is measured too, so the section has numbers when the terrain
mesh builder is unavailable.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

from bentray.engine.bench.breakdown import _stratified_scene
from bentray.engine.bench.common import Section, Table, best_time
from bentray.engine.bench.scene_meshes import SceneMesh, SceneUnavailable, build_scene_mesh
from bentray.engine.tracer import trace

__all__ = ["run", "measure"]

COLUMNS = [
    "scene",
    "cells",
    "rays",
    "threads",
    "trace_time_s",
    "crossings_per_ray",
    "reflections_per_ray",
    "crossings_per_s",
    "crossings_per_s_per_core",
    "rays_per_s",
    "lost",
    "note",
]


def measure(sc: SceneMesh, threads: int, repeats: int, min_total_s: float) -> dict[str, Any]:
    """Warm best-of trace time of ``sc``'s rays with ``threads`` numba threads, and the derived rates."""
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        kw: dict[str, Any] = {"max_time_s": 10.0, "max_reflections": 3}
        trace(sc.mesh, "parabolic", 340.0, sc.origins[:1], sc.directions[:1], sc.start_cells[:1], **kw)
        elapsed, res = best_time(
            lambda: trace(sc.mesh, "parabolic", 340.0, sc.origins, sc.directions, sc.start_cells, **kw),
            repeats,
            min_total_s,
        )
    finally:
        numba.set_num_threads(before)
    crossings = float(res.crossings.sum())
    n = res.n_rays
    return {
        "scene": sc.name,
        "cells": sc.mesh.n_cells,
        "rays": n,
        "threads": threads,
        "trace_time_s": elapsed,
        "crossings_per_ray": crossings / n,
        "reflections_per_ray": float(res.reflections.mean()),
        "crossings_per_s": crossings / elapsed,
        "crossings_per_s_per_core": crossings / elapsed / threads,
        "rays_per_s": n / elapsed,
        "lost": res.status_counts()["lost"],
    }


def run(quick: bool, scene_cache: dict[str, Any] | None = None) -> Section:
    """Quick: 1,000 rays, one run; full: 10,000 rays, best of 5+. ``scene_cache`` as in breakdown.run."""
    count = 1000 if quick else 10_000
    repeats, min_total = (1, 0.0) if quick else (5, 1.0)
    cache = scene_cache if scene_cache is not None else {}
    table = Table("throughput", "Throughput", COLUMNS)
    key = f"desert/{count}"
    if key not in cache:
        try:
            cache[key] = build_scene_mesh("desert", count)
        except SceneUnavailable as exc:
            cache[key] = exc
    scenes: list[Any] = [cache[key], _stratified_scene(count)]
    all_threads = numba.get_num_threads()
    for sc in scenes:
        if isinstance(sc, SceneUnavailable):
            table.add(scene="desert", rays=count, note=f"skipped: {sc}")
            continue
        for threads in sorted({1, all_threads}):
            table.add(**measure(sc, threads, repeats, min_total), note=f"mesh build {sc.build_s:.1f} s")
    sec = Section("throughput", "Throughput")
    sec.text.append(
        f"{count} rays over the sphere, 10 s, at most 3 reflections, parabolic curve; best of {repeats} warm run(s). "
        "Paper reference (one 3.2 GHz core, 2016): Desert(m) 10K rays, 179 cells per ray, 219 ms, ~8M crossings "
        "per second. docs/physics.md §9 records 7M/s per core for a naive Numba traversal on random-point "
        "Delaunay tets."
    )
    desert = [r for r in table.rows if r["scene"] == "desert" and r["threads"] != ""]
    if desert:
        one = next(r for r in desert if r["threads"] == 1)
        per_ray = np.mean([r["crossings_per_ray"] for r in desert])
        sec.text.append(
            f"**Desert (medium): {one['crossings_per_s_per_core'] / 1e6:.2f}M crossings per second on "
            f"one core, {one['rays_per_s']:,.0f} rays per second; {per_ray:.0f} cells per ray.**"
        )
    sec.tables.append(table)
    return sec

"""Appendix C: surfaces embedded in the media mesh (the default) against surfaces linked to the cells they overlap.

For ``desert`` and ``christmas`` at medium and high resolution (the surface triangle count roughly doubles):

- embedded: scene_meshes.build_scene_mesh (terrain-following conforming tets at the terrain's own spacing;
  ground, walls and roofs are mesh faces), traced by tracer.trace;
- linked: experimental/linked_mesh.py build_linked_mesh: the same layer levels (curvature rule, delta 1e-3, absolute z)
  over flat ground at the lowest surface point, horizontal spacing fixed at the scene's *medium* terrain
  spacing for both resolutions (the media mesh does not see the surfaces), the scene's triangles linked to
  the cells they overlap; traced by linked_media.trace_linked.

Same rays for both: ``count`` directions over the sphere from the scene's source, 10 s, at most 3
reflections, parabolic curve, 1 numba thread, best of the warm runs. Construction times exclude Numba
compilation (``_warm_up`` compiles the builders' kernels on tiny inputs first).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from bentray.engine.bench.common import Section, Table, best_time, on_timing_threads
from bentray.engine.bench.scene_meshes import (
    VERTICAL_D_MIN_M,
    VERTICAL_DELTA,
    SceneMesh,
    SceneUnavailable,
    _native_spacing,
    build_scene_mesh,
)
from bentray.engine.tracer import trace

__all__ = ["run", "COLUMNS"]

COLUMNS = [
    "scene",
    "resolution",
    "method",
    "surface_triangles",
    "cells",
    "air_cells",
    "mesh_build_s",
    "link_build_s",
    "build_total_s",
    "tris_per_cell_mean",
    "tris_per_cell_max",
    "rays",
    "trace_time_s",
    "crossings_per_ray",
    "surface_tests_per_ray",
    "reflections_per_ray",
    "lost",
    "note",
]
SCENES = ("desert", "christmas")
KW: dict[str, Any] = {"max_time_s": 10.0, "max_reflections": 3}


def _linked(name: str, resolution: str, sc: SceneMesh) -> tuple[Any, float]:
    from bentray.engine.experimental.linked_mesh import build_linked_mesh, locate_in_linked_mesh
    from bentray.engine.mesh.sizing import curvature_layers
    from bentray.scenes.library.registry import get_builtin
    from bentray.scenes.profile_models import profile_from_spec

    scene = get_builtin(name, resolution)
    profile = profile_from_spec(scene.profile)
    lo = np.asarray(scene.domain_min, float)
    hi = np.asarray(scene.domain_max, float)
    centre = 0.5 * (lo + hi)

    def m_at_z(z: np.ndarray) -> np.ndarray:
        z = np.atleast_1d(np.asarray(z, float))
        return profile.quantity("n2", np.column_stack([np.full(len(z), centre[0]), np.full(len(z), centre[1]), z]))

    z_levels = curvature_layers(
        lo[2], hi[2], m_at_z, delta=VERTICAL_DELTA, d_min=VERTICAL_D_MIN_M, d_max=float(hi[2] - lo[2])
    )
    medium = get_builtin(name, "medium").surfaces
    spacing = _native_spacing(medium, lo, hi)
    lm = build_linked_mesh(
        scene.surfaces, lo, hi, lambda p: profile.quantity("n2", p), horizontal_spacing=spacing, z_levels=z_levels
    )
    cell = locate_in_linked_mesh(lm, sc.origins[:1])
    if cell[0] < 0:
        raise SceneUnavailable(f"{name}: the source is not in an air cell of the linked mesh")
    return lm, int(cell[0])


@on_timing_threads
def _rows(name: str, resolution: str, count: int, repeats: int, min_total: float) -> list[dict[str, Any]]:
    from bentray.engine.experimental.linked_media import trace_linked

    sc = build_scene_mesh(name, count, resolution=resolution)
    n = count
    trace(sc.mesh, "parabolic", 340.0, sc.origins[:1], sc.directions[:1], sc.start_cells[:1], **KW)
    t_emb, res = best_time(
        lambda: trace(sc.mesh, "parabolic", 340.0, sc.origins, sc.directions, sc.start_cells, **KW), repeats, min_total
    )
    nb = sc.stats.get("n_boundary_faces", {})
    emb = {
        "scene": name,
        "resolution": resolution,
        "method": "embedded",
        "surface_triangles": sc.surfaces,
        "cells": sc.mesh.n_cells,
        "air_cells": sc.mesh.n_cells,
        "mesh_build_s": sc.build_s,
        "link_build_s": 0.0,
        "build_total_s": sc.build_s,
        "rays": n,
        "trace_time_s": t_emb,
        "crossings_per_ray": float(res.crossings.mean()),
        "surface_tests_per_ray": 0.0,
        "reflections_per_ray": float(res.reflections.mean()),
        "lost": res.status_counts()["lost"],
        "note": f"ground {nb.get('ground', 0)}, walls {nb.get('walls', 0)}, roofs {nb.get('roofs', 0)} mesh faces",
    }
    t0 = time.perf_counter()
    lm, cell = _linked(name, resolution, sc)
    wall = time.perf_counter() - t0
    starts = np.full(n, cell, dtype=np.int64)
    tests = np.zeros(n, dtype=np.int64)
    trace_linked(lm, "parabolic", 340.0, sc.origins[:1], sc.directions[:1], starts[:1], **KW)
    t_lnk, rl = best_time(
        lambda: trace_linked(lm, "parabolic", 340.0, sc.origins, sc.directions, starts, surface_tests=tests, **KW),
        repeats,
        min_total,
    )
    st = lm.stats
    lnk = {
        "scene": name,
        "resolution": resolution,
        "method": "linked",
        "surface_triangles": st["triangles"],
        "cells": st["cells"],
        "air_cells": st["air_cells"],
        "mesh_build_s": st["mesh_s"],
        "link_build_s": st["link_s"] + st["solid_s"] + st["surfaces_s"],
        "build_total_s": wall,
        "tris_per_cell_mean": st["tris_per_cell_mean"],
        "tris_per_cell_max": st["tris_per_cell_max"],
        "rays": n,
        "trace_time_s": t_lnk,
        "crossings_per_ray": float(rl.crossings.mean()),
        "surface_tests_per_ray": float(tests.mean()),
        "reflections_per_ray": float(rl.reflections.mean()),
        "lost": rl.status_counts()["lost"],
        "note": f"{st['layers']} layers, h {st['horizontal_spacing_m']:.3g} m; linked cells {st['linked_cells']:,}, "
        f"{st['tris_per_cell_mean_linked']:.2f} tris each; candidates {st['candidate_pairs']:,} "
        f"({st['link_candidates_s']:.2f} s), exact test {st['link_exact_s']:.2f} s, solid cells "
        f"{st['solid_s']:.2f} s",
    }
    return [emb, lnk]


def _warm_up() -> None:
    """Compile the mesh builders' and the overlap test's Numba kernels on tiny inputs (not timed)."""
    from bentray.engine.experimental.linked_mesh import link_cells

    tet = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]])
    link_cells(tet, np.array([[[0.1, 0.1, 0.1], [2, 0, 0], [0, 2, 0]]]))
    try:
        build_scene_mesh("flat", 1)
    except SceneUnavailable:
        pass


def run(quick: bool) -> Section:
    """Quick: medium resolution only, 300 rays, one run; full: medium and high, 2,000 rays, best of 3+."""
    _warm_up()
    count = 300 if quick else 2000
    repeats, min_total = (1, 0.0) if quick else (3, 1.0)
    resolutions = ("medium",) if quick else ("medium", "high")
    table = Table("appendix_c_linked", "Appendix C: embedded vs linked surfaces", COLUMNS)
    for name in SCENES:
        for res in resolutions:
            try:
                for row in _rows(name, res, count, repeats, min_total):
                    table.add(**row)
            except SceneUnavailable as exc:
                table.add(scene=name, resolution=res, note=f"skipped: {exc}")
    sec = Section("linked_surfaces", "Appendix C: embedded vs linked surfaces")
    sec.text.append(
        f"{count} rays over the sphere from each scene's source, 10 s, at most 3 reflections, parabolic, 1 thread; "
        "embedded = terrain-following conforming tets (surfaces are mesh faces, horizontal spacing = the terrain's); "
        "linked = flat layered tets over the lowest surface point at the medium terrain spacing for both "
        "resolutions, with the surface triangles linked to the cells they overlap (exact separating-axis test). "
        "Build times: mesh_build_s is the media mesh, link_build_s the surface triangles, link table and solid-cell "
        "marking; the linked mesh's cells include those below the ground (solid, never entered)."
    )
    sec.tables.append(table)
    return sec

"""Media of a scene with closed obstacle meshes over flat ground (representation ``tetwild``).

``build_obstacle_media`` has the call shape of ``media.build_terrain_media`` and builds the fTetWild mesh
of engine/mesh/tetwild.py: the air box above the flat ground z = domain_min z minus
``surfaces.obstacles``. Scenes with terrain or footprints are refused here (ValueError): the
terrain-following mesh handles those, and neither builder handles both yet.

Sizing: one ideal edge length for the whole domain (fTetWild's uniform sizing), ``solver.d_max_m`` if
given, otherwise extent * DEFAULT_TET_D_MAX_FRACTION / 4 (the terrain mesh's default horizontal
spacing), and never more than OBSTACLE_EDGE_FRACTION of the smallest obstacle's bounding-box extent so
every obstacle is resolved. fTetWild's envelope is DEFAULT_EPSILON (its relative epsilon; it is not the
paper's sizing epsilon of ``solver.epsilon``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bentray.engine.constants import CURVE_QUANTITY
from bentray.engine.media import DEFAULT_TET_D_MAX_FRACTION, Media, tet_geometry
from bentray.engine.mesh.tets import approximation_error
from bentray.engine.mesh.tetwild import DEFAULT_EPSILON, build_obstacle_tet_mesh, locate_in_obstacle_mesh
from bentray.engine.profiles import Profile
from bentray.engine.surfaces import SceneSurfaces

# An obstacle's smallest bounding-box extent spans at least 1 / OBSTACLE_EDGE_FRACTION ideal edges.
OBSTACLE_EDGE_FRACTION = 0.25
# Eq. 14 is evaluated on an EQ14_GRID^3 grid over the domain (points inside obstacles count as outside).
EQ14_GRID = 20


def build_obstacle_media(
    profile: Profile,
    curve: str,
    solver: Any,
    domain_min: np.ndarray,
    domain_max: np.ndarray,
    surfaces: SceneSurfaces,
    *,
    top: str = "open",
    quantity_fn: Callable[[np.ndarray], np.ndarray] | None = None,
) -> Media:
    """The fTetWild mesh of the air above flat ground (z = domain_min z) minus the closed obstacles.

    profile, curve, solver : as ``build_terrain_media`` (the traced quantity of ``curve`` at the mesh
        vertices; ``solver.d_max_m`` caps the edge length; ``solver.gradient`` picks the gradient).
    domain_min, domain_max : (3,) metres, world frame, z up.
    surfaces : flat ground (terrain None), no footprints, at least one obstacle; every obstacle's faces
        and the ground get material 0 (SceneSurfaces carries no per-obstacle material yet).
    top : "open" or "reflect".
    quantity_fn : accepted for the call shape of ``build_terrain_media``; the uniform edge length does
        not depend on the medium, so it is not used.
    Stats: cells, points, obstacle_faces, surface_deviation_m (max distance of the obstacle faces'
    vertices from the input obstacle surfaces), edge_length_m, build_time_s, Eq. 14 error, and the
    builder's own stats.
    """
    del quantity_fn  # documented above: no medium-dependent sizing in this builder
    lo = np.asarray(domain_min, float)
    hi = np.asarray(domain_max, float)
    if surfaces.terrain is not None or surfaces.footprints:
        raise ValueError("closed obstacle meshes are supported over flat ground without footprints only")
    if not surfaces.obstacles:
        raise ValueError("no obstacles: use build_media or build_terrain_media")
    quantity = CURVE_QUANTITY[curve]
    t0 = time.perf_counter()
    extent = float(np.max(hi - lo))
    edge = extent * DEFAULT_TET_D_MAX_FRACTION / 4.0
    if solver.d_max_m is not None:
        edge = min(edge, float(solver.d_max_m))
    smallest = min(float(np.ptp(np.asarray(v, float), axis=0).min()) for v, _ in surfaces.obstacles)
    edge = min(edge, OBSTACLE_EDGE_FRACTION * smallest) if smallest > 0 else edge

    def quantity_at(p: np.ndarray) -> np.ndarray:
        return profile.quantity(quantity, p)

    tet = build_obstacle_tet_mesh(lo, hi, float(lo[2]), surfaces.obstacles, quantity_at=quantity_at,
                                  edge_length=edge, epsilon=DEFAULT_EPSILON, top=top,
                                  gradient_method=solver.gradient,
                                  materials=surfaces.obstacle_materials or None)  # fmt: skip
    mesh = tet.cells
    stats = dict(tet.stats)
    stats.update({
        "cells": int(mesh.n_cells),
        "points": int(len(tet.points)),
        "obstacles": len(surfaces.obstacles),
        "obstacle_faces": int(stats["n_boundary_faces"]["obstacle"]),
        "surface_deviation_m": stats["surface_deviation_m"]["max"],
        "min_cell_size_m": float(mesh.size.min()),
        "median_cell_size_m": float(np.median(mesh.size)),
        "max_cell_size_m": float(mesh.size.max()),
    })  # fmt: skip
    stats["build_time_s"] = time.perf_counter() - t0
    axes = [np.linspace(lo[i], hi[i], EQ14_GRID) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    stats["approximation_error_eq14"] = approximation_error(tet, grid, quantity_at(grid))
    return Media(
        representation="tetwild",
        reason=f"scene has {len(surfaces.obstacles)} closed obstacle meshes over flat ground: fTetWild "
        "tetrahedra of the box minus the obstacles (ground and box planes exact, obstacle faces within "
        f"{stats['surface_deviation_m']:.3g} m of the input)",
        quantity=quantity,
        mesh=mesh,
        locate=lambda xyz: locate_in_obstacle_mesh(tet, xyz),
        geometry=lambda: tet_geometry(tet.points, tet.tets, mesh, quantity),
        stats=stats,
    )

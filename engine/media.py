"""Choose and build the media representation a job needs (and nothing more).

- homogeneous profile                      -> ``uniform``: one box cell, straight rays, no mesh build
- stratified profile (c depends on z only) -> ``slabs``: horizontal layers graded by the sizing rule
- anything else (hot spot, fluctuations, 3D grids) -> ``tets``: Algorithm 2 + Delaunay tetrahedra
- a scene with terrain or buildings -> ``terrain``: the terrain-following conforming mesh
  (engine/mesh/terrain.py) whose ground, walls and roofs are reflecting faces with their materials

``solver.representation`` may force one (a benchmark of tets on a stratified profile, say); forcing
``uniform`` or ``slabs`` on a profile that varies horizontally is refused, because it would silently
trace a different medium.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bentray.engine.constants import CURVE_QUANTITY
from bentray.engine.errors import JobInputError
from bentray.engine.mesh.cells import CellMesh, locate_points
from bentray.engine.mesh.sizing import (
    curvature_layers,
    gradient_layers,
    relative_error_1d,
    sizing_grid_spacing,
)
from bentray.engine.mesh.slabs import build_slab_mesh, locate_in_slabs, slab_geometry
from bentray.engine.profiles import Profile
from bentray.engine.result import MeshGeometry
from bentray.engine.surfaces import HeightGrid, SceneSurfaces, TriangleSurface
from bentray.engine.wind import sizing_quantity, wind_is_stratified

Wind = tuple[int, np.ndarray]

# Defaults chosen by measurement (README, "Accuracy against cost"): on A-LD (log profile, b = +1,
# 91 rays, 10 s) delta = 1e-8 gives ~2,300 layers and 1.4e-6 relative position error; 1e-6 gives
# 231 layers and 2e-5. Slabs are cheap, so the default buys the accuracy.
DEFAULT_SLAB_DELTA = 1e-8
# Smallest layer: 10 micrometres resolves z_g = 0.01 m log profiles at the default delta.
DEFAULT_SLAB_D_MIN = 1e-5
# 3D meshes pay per point in all three directions: a looser default and bounded spacings.
DEFAULT_TET_DELTA = 1e-4
DEFAULT_TET_D_MIN_FRACTION = 1.0 / 200.0  # of the largest domain extent
DEFAULT_TET_D_MAX_FRACTION = 1.0 / 8.0


@dataclass
class Media:
    """A built media representation and what the report says about it."""

    representation: str
    reason: str
    quantity: str
    mesh: CellMesh
    locate: Callable[[np.ndarray], np.ndarray]
    geometry: Callable[[], MeshGeometry]
    stats: dict[str, Any] = field(default_factory=dict)


def choose_representation(profile: Profile, requested: str, wind: Wind | None = None) -> tuple[str, str]:
    """(representation, reason) for a profile, an optional wind and the job's ``solver.representation``.

    A log wind over flat ground varies with z only (slabs carry it; the kernel adds u . e per ray); the
    ridge wind varies in x too (tets). ``uniform`` is exact only in still air: one cell cannot carry the
    wind's gradient.
    """
    windy = wind is not None
    horizontal = not profile.stratified or (wind is not None and not wind_is_stratified(int(wind[0])))
    still_air = profile.kind == "homogeneous" and not windy
    if requested != "auto":
        if requested in ("uniform", "slabs") and horizontal:
            what = f"profile kind {profile.kind!r}" if not profile.stratified else "the ridge wind"
            raise JobInputError(
                f"solver.representation: {requested!r} needs a stratified medium, but {what} "
                "varies horizontally; use 'tets' or 'auto'"
            )
        if requested == "uniform" and not still_air:
            what = "with wind" if windy else f"for profile {profile.kind!r}"
            raise JobInputError(
                f"solver.representation: 'uniform' is only exact for a homogeneous profile in still air, not {what}"
            )
        return requested, "requested by solver.representation"
    if still_air:
        return "uniform", "homogeneous medium: one cell, straight rays, no media mesh"
    if not horizontal:
        extra = " (the log wind adds u . e per ray in the kernel)" if windy else ""
        return "slabs", f"stratified medium over flat ground: horizontal layers, no 3D mesh{extra}"
    if profile.stratified:
        return "tets", "the ridge wind varies in x and z: adaptive tetrahedral mesh sized on the downwind medium"
    return "tets", f"profile {profile.kind!r} varies in 3D: adaptive tetrahedral mesh (Algorithm 2 + Delaunay)"


def _sizing_params(solver: Any, representation: str, extent: float) -> tuple[str, float, float, float]:
    rule = solver.effective_sizing
    if rule == "gradient":
        tol = solver.epsilon if solver.epsilon is not None else 1e-3
    elif representation == "tets":
        tol = solver.delta if solver.delta is not None else DEFAULT_TET_DELTA
    else:
        tol = solver.delta if solver.delta is not None else DEFAULT_SLAB_DELTA
    if representation == "tets":
        d_min = solver.d_min_m if solver.d_min_m is not None else extent * DEFAULT_TET_D_MIN_FRACTION
        d_max = solver.d_max_m if solver.d_max_m is not None else extent * DEFAULT_TET_D_MAX_FRACTION
    else:
        d_min = solver.d_min_m if solver.d_min_m is not None else DEFAULT_SLAB_D_MIN
        d_max = solver.d_max_m if solver.d_max_m is not None else extent
    if d_min > d_max:
        raise JobInputError(f"solver.d_min_m ({d_min}) is larger than solver.d_max_m ({d_max})")
    return rule, float(tol), float(d_min), float(d_max)


def _n_from_quantity(quantity: str) -> Callable[[np.ndarray], np.ndarray]:
    if quantity == "n2":
        return np.sqrt
    if quantity == "c":
        return lambda m: 340.0 / m  # c_ref cancels in the relative error of Eq. 14
    return lambda m: m


@dataclass(frozen=True)
class _MediaRequest:
    """What ``build_media`` resolved for one job, handed to the representation builders.

    profile : the medium; quantity : the traced quantity ("n2", "c" or "n"); solver : the job's Solver;
    lo, hi : (3,) float64 domain corners, metres, world frame; representation, reason : from
    ``choose_representation``; ground, top : boundary tags ("reflect" / "open"); extent : largest domain
    side, metres; t0 : perf_counter at the start of the build (build_time_s counts from it);
    size_q, size_n : the downwind effective medium's quantity and n, xyz (N, 3) -> (N,), used for sizing
    with wind (None: size on the profile itself).
    """

    profile: Profile
    quantity: str
    solver: Any
    lo: np.ndarray
    hi: np.ndarray
    representation: str
    reason: str
    ground: str
    top: str
    extent: float
    t0: float
    size_q: Callable[[np.ndarray], np.ndarray] | None = None
    size_n: Callable[[np.ndarray], np.ndarray] | None = None


def build_media(
    profile: Profile,
    curve: str,
    solver: Any,
    domain_min: np.ndarray,
    domain_max: np.ndarray,
    *,
    ground: str = "reflect",
    top: str = "open",
    wind: Wind | None = None,
) -> Media:
    """Build the representation the job needs for the traced quantity of ``curve``.

    wind : (code, params) of engine.wind, or None. The mesh carries the profile alone (the kernel adds
    u . e per ray); its sizing uses the downwind effective medium c + |u| (docs/physics.md §6).
    """
    lo = np.asarray(domain_min, float)
    hi = np.asarray(domain_max, float)
    quantity = CURVE_QUANTITY[curve]
    representation, reason = choose_representation(profile, solver.representation, wind)
    size_q = sizing_quantity(profile.sound_speed, profile.c_ref, wind, quantity) if wind is not None else None
    size_n = sizing_quantity(profile.sound_speed, profile.c_ref, wind, "n") if wind is not None else None
    extent = float(np.max(hi - lo))
    t0 = time.perf_counter()
    req = _MediaRequest(profile, quantity, solver, lo, hi, representation, reason, ground, top, extent, t0,
                        size_q, size_n)  # fmt: skip
    if representation in ("uniform", "slabs"):
        return _build_layers(req)
    return _build_tets(req)


def _column_points(centre: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Points (N, 3) metres on the vertical through ``centre`` (x, y) at heights z (N,) (a scalar is one)."""
    z = np.atleast_1d(np.asarray(z, float))
    return np.column_stack([np.full(len(z), centre[0]), np.full(len(z), centre[1]), z])


def _layer_levels(req: _MediaRequest, m_at_z: Callable[[np.ndarray], np.ndarray], stats: dict[str, Any]) -> np.ndarray:
    """Slab interfaces z (L + 1,) metres from lo z to hi z: two for ``uniform``, else the curvature rule on
    the (sizing) quantity or the gradient rule on n along the domain's central column; records the
    sizing rule and its parameters in ``stats``."""
    lo, hi = req.lo, req.hi
    if req.representation == "uniform":
        return np.array([lo[2], hi[2]])
    centre = 0.5 * (lo + hi)
    rule, tol, d_min, d_max = _sizing_params(req.solver, "slabs", hi[2] - lo[2])
    if rule == "gradient":
        size_n = req.size_n

        def n_at_z(z: np.ndarray) -> np.ndarray:
            col = _column_points(centre, z)
            return size_n(col) if size_n is not None else req.profile.quantity("n", col)

        z_levels = gradient_layers(lo[2], hi[2], n_at_z, epsilon=tol, d_min=d_min, d_max=d_max)
    else:
        size_q = req.size_q

        def size_m_at_z(z: np.ndarray) -> np.ndarray:
            return size_q(_column_points(centre, z)) if size_q is not None else m_at_z(z)

        z_levels = curvature_layers(lo[2], hi[2], size_m_at_z, delta=tol, d_min=d_min, d_max=d_max)
    stats.update({"sizing_rule": rule, "tolerance": tol, "d_min_m": d_min, "d_max_m": d_max})
    return z_levels


def _build_layers(req: _MediaRequest) -> Media:
    """``uniform`` (one box cell) or ``slabs`` (horizontal layers graded by the sizing rule): the profile
    sampled on the domain's central column, metres; stats with the cell sizes and, for slabs, Eq. 14."""
    lo, hi, quantity = req.lo, req.hi, req.quantity
    centre = 0.5 * (lo + hi)

    def m_at_z(z: np.ndarray) -> np.ndarray:
        return req.profile.quantity(quantity, _column_points(centre, z))

    stats: dict[str, Any] = {}
    z_levels = _layer_levels(req, m_at_z, stats)
    mesh = build_slab_mesh(lo, hi, z_levels, m_at_z, ground=req.ground, top=req.top)
    thickness = np.diff(z_levels)
    stats.update(
        {
            "cells": int(len(thickness)),
            "points": int(4 * len(z_levels)),
            "layers": int(len(thickness)),
            "min_cell_size_m": float(thickness.min()),
            "median_cell_size_m": float(np.median(thickness)),
            "max_cell_size_m": float(thickness.max()),
            "build_time_s": time.perf_counter() - req.t0,
        }
    )
    if req.representation == "slabs":
        stats["approximation_error_eq14"] = relative_error_1d(z_levels, m_at_z, _n_from_quantity(quantity))
    return Media(
        representation=req.representation,
        reason=req.reason,
        quantity=quantity,
        mesh=mesh,
        locate=lambda xyz: locate_in_slabs(z_levels, xyz),
        geometry=lambda: slab_geometry(lo, hi, mesh, z_levels, quantity),
        stats=stats,
    )


def _build_tets(req: _MediaRequest) -> Media:
    """``tets``: the sizing grid d(x) (metres), FCC resampling (Algorithm 2) and the Delaunay CellMesh;
    stats with the tet mesh's own report, the cell sizes and Eq. 14 on a 40^3 grid."""
    from bentray.engine.mesh.fcc import fcc_resample
    from bentray.engine.mesh.tets import approximation_error, build_tet_mesh

    profile, quantity, solver, lo, hi = req.profile, req.quantity, req.solver, req.lo, req.hi
    rule, tol, d_min, d_max = _sizing_params(solver, "tets", req.extent)

    def quantity_at(p: np.ndarray) -> np.ndarray:
        return profile.quantity(quantity, p)

    grid_step = None
    native = getattr(profile, "spacing", None)  # gridded input: size it from its own samples
    if native is not None and np.ndim(native) == 1 and len(native) == 3:
        grid_step = float(np.min(native))
    spacing = sizing_grid_spacing(
        req.size_q if req.size_q is not None else quantity_at,
        req.size_n if req.size_n is not None else (lambda p: profile.quantity("n", p)),
        lo,
        hi,
        rule=rule,
        tolerance=tol,
        d_min=d_min,
        d_max=d_max,
        grid_step=grid_step,
    )
    points = fcc_resample(lo, hi, spacing, d_min=d_min, d_max=d_max)
    tet = build_tet_mesh(
        lo,
        hi,
        points,
        quantity_at,
        spacing=spacing,
        ground=req.ground,
        top=req.top,
        gradient_method=solver.gradient,
    )
    stats = dict(tet.stats)
    stats.update({"sizing_rule": rule, "tolerance": tol, "d_min_m": d_min, "d_max_m": d_max})
    stats.update(_cell_size_stats(tet.cells, len(tet.points)))  # the same headline keys as the slab report
    stats["build_time_s"] = time.perf_counter() - req.t0
    # Eq. 14 on an input grid of about 40^3 points spanning the domain
    axes = [np.linspace(lo[i], hi[i], 40) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    stats["approximation_error_eq14"] = approximation_error(tet, grid, quantity_at(grid))
    mesh = tet.cells
    return Media(
        representation=req.representation,
        reason=req.reason,
        quantity=quantity,
        mesh=mesh,
        locate=lambda xyz: locate_points(mesh, xyz),
        geometry=lambda: tet_geometry(tet.points, tet.tets, mesh, quantity),
        stats=stats,
    )


def _cell_size_stats(mesh: CellMesh, n_points: int) -> dict[str, Any]:
    """Headline keys of a tet mesh report: cells, points and the cell size (longest edge, metres)
    min / median / max."""
    return {
        "cells": int(mesh.n_cells),
        "points": int(n_points),
        "min_cell_size_m": float(mesh.size.min()),
        "median_cell_size_m": float(np.median(mesh.size)),
        "max_cell_size_m": float(mesh.size.max()),
    }


def tet_geometry(points: np.ndarray, tets: np.ndarray, mesh: CellMesh, quantity: str) -> MeshGeometry:
    """mesh.vtu content of a tetrahedral media mesh: the traced quantity and its gradient per cell."""
    return MeshGeometry(
        points=points,
        connectivity=tets,
        cell_type="tetra",
        cell_data={quantity: mesh.media_ref.copy(), f"grad_{quantity}": mesh.gradient.copy()},
    )


def _native_spacing(surfaces: SceneSurfaces) -> float | None:
    """Sample spacing of the terrain input (metres), or None (flat ground / triangle terrain)."""
    terrain = surfaces.terrain
    if isinstance(terrain, HeightGrid) and len(terrain.x) > 1 and len(terrain.y) > 1:
        return float(min(np.min(np.diff(terrain.x)), np.min(np.diff(terrain.y))))
    if isinstance(terrain, TriangleSurface):
        tri = terrain.vertices[terrain.triangles]
        edges = np.linalg.norm(tri[:, [1, 2, 0], :2] - tri[:, :, :2], axis=2)
        return float(np.median(edges))
    return None


def _terrain_sigma_levels(
    profile: Profile,
    quantity: str,
    solver: Any,
    lo: np.ndarray,
    hi: np.ndarray,
    sizing: tuple[str, float, float],
    quantity_fn: Callable[[np.ndarray], np.ndarray] | None,
) -> np.ndarray:
    """Terrain-following sigma levels (L + 1,) in [0, 1]: the slab rule (sizing = (rule, tolerance,
    d_max metres)) on the domain's central column of the stratified part of the medium (a fluctuating
    profile's base; quantity_fn overrides it), thinnest layer solver.d_min_m (default 1 cm), mapped by
    sigma = (z - lo z) / (hi z - lo z). The gradient rule sizes on n of the profile itself."""
    rule, tol, d_max = sizing
    # Layers follow the stratified part of the medium (a fluctuating profile's base): the fluctuations'
    # own scale is resolved horizontally by the terrain spacing, not by hundreds of global layers.
    column = getattr(profile, "base", profile)
    sizing_q = quantity_fn or (lambda p: column.quantity(quantity, p))
    centre = 0.5 * (lo + hi)
    z_lo = lo[2]

    def m_at_z(z: np.ndarray) -> np.ndarray:
        return sizing_q(_column_points(centre, z))

    v_min = solver.d_min_m if solver.d_min_m is not None else DEFAULT_SLAB_D_MIN * 1e3  # 1 cm
    if rule == "gradient":
        z_levels = gradient_layers(
            z_lo,
            hi[2],
            lambda z: profile.quantity("n", _column_points(centre, z)),
            epsilon=tol,
            d_min=v_min,
            d_max=d_max,
        )
    else:
        z_levels = curvature_layers(z_lo, hi[2], m_at_z, delta=tol, d_min=v_min, d_max=d_max)
    sigma = (z_levels - z_lo) / (hi[2] - z_lo)
    sigma[0], sigma[-1] = 0.0, 1.0
    return sigma


def _terrain_horizontal_spacing(surfaces: SceneSurfaces, solver: Any, extent: float) -> float:
    """Horizontal spacing (metres): the terrain's own sample spacing, else extent x
    DEFAULT_TET_D_MAX_FRACTION / 4; capped by solver.d_max_m."""
    native = _native_spacing(surfaces)
    horizontal: float = native if native is not None else extent * DEFAULT_TET_D_MAX_FRACTION / 4.0
    if solver.d_max_m is not None:
        horizontal = min(horizontal, solver.d_max_m)
    return horizontal


def _surface_triangles(stats: dict[str, Any]) -> int | None:
    """Reflecting surface triangles of a terrain mesh report: ground + walls + roofs faces (None without
    n_boundary_faces)."""
    faces = stats.get("n_boundary_faces")
    if not isinstance(faces, dict):
        return None
    return int(faces.get("ground", 0) + faces.get("walls", 0) + faces.get("roofs", 0))


def _terrain_reason(surfaces: SceneSurfaces) -> str:
    """The report's reason line for the terrain representation."""
    ground = "terrain" if surfaces.terrain is not None else "flat ground"
    buildings = f" and {len(surfaces.footprints)} buildings" if surfaces.footprints else ""
    return (
        f"scene has {ground}{buildings}: "
        "terrain-following conforming tetrahedra (ground, walls and roofs are mesh faces)"
    )


def build_terrain_media(
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
    """The conforming terrain-following mesh of a scene with terrain and/or buildings.

    Vertical layers: the curvature (or gradient) rule of the slabs applied to the stratified part of the
    profile at the domain centre, with the tets tolerance (default delta 1e-4), mapped to
    terrain-following sigma levels. Horizontal spacing: the terrain's own sample spacing (the surface is
    kept exactly), or ``solver.d_max_m`` if smaller. quantity_fn overrides the traced quantity used for
    the layers (wind: the downwind effective medium).
    """
    from bentray.engine.mesh.terrain import build_terrain_mesh, locate_in_terrain_mesh, terrain_index

    lo = np.asarray(domain_min, float)
    hi = np.asarray(domain_max, float)
    quantity = CURVE_QUANTITY[curve]
    extent = float(np.max(hi - lo))
    t0 = time.perf_counter()
    rule, tol, d_min, d_max = _sizing_params(solver, "tets", extent)

    def quantity_at(p: np.ndarray) -> np.ndarray:
        return profile.quantity(quantity, p)

    sigma = _terrain_sigma_levels(profile, quantity, solver, lo, hi, (rule, tol, d_max), quantity_fn)
    horizontal = _terrain_horizontal_spacing(surfaces, solver, extent)
    tet = build_terrain_mesh(
        surfaces,
        lo,
        hi,
        quantity_at,
        horizontal_spacing=horizontal,
        layer_levels=sigma,
        top=top,
        gradient_method=solver.gradient,
    )
    index = terrain_index(tet)
    mesh = tet.cells
    stats = dict(tet.stats)
    sizes = _cell_size_stats(mesh, len(tet.points))
    stats.update(
        {
            "sizing_rule": rule,
            "tolerance": tol,
            "horizontal_spacing_m": horizontal,
            "cells": sizes.pop("cells"),
            "points": sizes.pop("points"),
            "layers": int(len(sigma) - 1),
            **sizes,
            "surface_triangles": _surface_triangles(stats),
            "buildings": len(surfaces.footprints),
            "build_time_s": time.perf_counter() - t0,  # the whole media build (s), as every representation reports
            "mesh_build_time_s": stats.get("build_time_s"),  # the mesh builder's split (triangulation, tables, ...)
        }
    )
    return Media(
        representation="terrain",
        reason=_terrain_reason(surfaces),
        quantity=quantity,
        mesh=mesh,
        locate=lambda xyz: locate_in_terrain_mesh(tet, xyz, index),
        geometry=lambda: tet_geometry(tet.points, tet.tets, mesh, quantity),
        stats=stats,
    )

"""Tetrahedral media mesh of a box above flat ground minus closed obstacle meshes, by fTetWild (pytetwild).

``build_obstacle_tet_mesh`` is the builder for obstacles that are not extrusions of a footprint (those
go through the terrain-following mesh, terrain.py, which keeps its input surfaces exactly):

1. Input surface: the air box [lo_x, hi_x] x [lo_y, hi_y] x [ground_z, hi_z] (12 triangles, outward) plus
   every obstacle with its triangles reversed (inward). fTetWild keeps the tets whose generalised
   winding number is above 1/2, i.e. the box minus the obstacles; obstacles may cross the ground (the
   part below ground_z is cut off) and may overlap each other.
2. pytetwild 0.4.2 (MPL-2.0) runs inside a temporary working directory (it writes
   ``__tracked_surface.stl`` into the current directory) under a process-wide lock, because the
   working directory is global to the process. ``vtk_ordering=True``; the orientation is checked anyway
   and every negative tet is flipped.
3. fTetWild keeps none of the input triangles: its boundary lies within its envelope
   eps_abs = epsilon * (bounding-box diagonal of the input surface). Boundary faces with all three
   vertices within ``snap_tol`` (default SNAP_ENVELOPES * eps_abs) of a box plane are tagged with that
   plane and their vertices are moved exactly onto it (the ground reflection is then exact); slivers
   whose 4 vertices land on one plane are dropped, and the mesh is rejected if snapping flattens or
   inverts any other tet. The remaining boundary faces are obstacle faces;
   each must lie within ``snap_tol`` of the input obstacle surface (the measured deviation is in
   ``stats``). fTetWild re-triangulates even where it keeps the input vertices (edge flips make chords:
   0.035-0.039 m on an 8 m icosphere at envelope 0.078 m), so the deviation is probed at the faces'
   vertices, edge midpoints and centroids.
4. Traversal tables with the helpers of the terrain mesh (prisms.face_vertices, match_faces,
   face_planes: bit-identical shared planes of opposite sign), cells in Morton order (tets.py).
   Tags: ground BOUNDARY_REFLECT (``ground_material``), obstacle faces BOUNDARY_REFLECT (the material of
   the nearest obstacle), sides BOUNDARY_OPEN, top open or reflecting.
5. Media exactly as terrain.py: vertex values m_v = quantity_at(points), reference point = centroid,
   media_ref = mean of the 4 vertex values, gradient by least squares on the face neighbours (Green-Gauss
   fallback) or each cell's own P1 gradient.

Not supported here: terrain (the ground is the flat plane z = ground_z) and footprints.
"""

from __future__ import annotations

import os
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from bentray.engine.constants import BOUNDARY_OPEN, BOUNDARY_REFLECT
from bentray.engine.errors import MeshBuildError
from bentray.engine.mesh.cells import locate_points
from bentray.engine.mesh.gradients import tet_cell_mesh
from bentray.engine.mesh.prisms import face_planes, face_vertices, match_faces
from bentray.engine.mesh.surface_checks import basic_mesh_problem, closed_mesh_problem
from bentray.engine.mesh.tets import (
    DEGENERATE_VOL_REL,
    GRADIENT_METHODS,
    TetMesh,
    _morton_order,
    locate_tets,
)

# fTetWild's envelope: its output boundary lies within epsilon * (input bounding-box diagonal) of the
# input surface. Measured on a 60 x 40 x 30 m box with an 8 m sphere (edge 4 m, 1 thread): epsilon 1e-3
# builds in 2.2 s, 3e-4 in 11 s, 1e-4 in 113-145 s; the default buys build time, the snap makes the
# box planes exact whatever epsilon is.
DEFAULT_EPSILON = 1e-3
# Box-plane classification and snap tolerance, in envelopes: a boundary vertex of a box-plane face lies
# within one envelope of the plane (measured <= 0.5 envelope), so 2 envelopes never miss one, while an
# obstacle must stay farther than that from the sides and the top (checked).
SNAP_ENVELOPES = 2.0

_TETWILD_LOCK = threading.Lock()

# The 12 outward triangles of a box whose 8 corners are numbered i = x + 2 y + 4 z (bits).
_BOX_TRIANGLES = np.array([
    [0, 2, 3], [0, 3, 1],  # z = lo (normal -z)
    [4, 5, 7], [4, 7, 6],  # z = hi (+z)
    [0, 1, 5], [0, 5, 4],  # y = lo (-y)
    [2, 6, 7], [2, 7, 3],  # y = hi (+y)
    [0, 4, 6], [0, 6, 2],  # x = lo (-x)
    [1, 3, 7], [1, 7, 5],  # x = hi (+x)
], dtype=np.int64)  # fmt: skip


def _box_surface(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = np.array([[hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2]]
                        for i in range(8)])  # fmt: skip
    return corners, _BOX_TRIANGLES.copy()


def _run_tetwild(vertices: np.ndarray, faces: np.ndarray, edge_length: float, epsilon: float,
                 num_threads: int, optimize: bool) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """pytetwild in a temporary working directory (it writes __tracked_surface.stl into the cwd)."""
    import pytetwild  # optional dependency (MPL-2.0), imported only when this builder runs

    with _TETWILD_LOCK, tempfile.TemporaryDirectory(prefix="bentray-tetwild-") as tmp:
        cwd = os.getcwd()
        os.chdir(tmp)
        try:
            pts, tets = pytetwild.tetrahedralize(  # type: ignore[attr-defined]  # not in its __all__
                np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces, dtype=np.int32),
                edge_length_abs=float(edge_length), epsilon=float(epsilon), num_threads=int(num_threads),
                optimize=optimize, vtk_ordering=True, quiet=True,
            )  # fmt: skip
        finally:
            os.chdir(cwd)
    return np.asarray(pts, dtype=np.float64), np.asarray(tets, dtype=np.int64)


def surface_distance(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact distance (N,) metres from each point (N, 3) to a triangle soup (F, 3, 3) and the nearest
    triangle id (N,).

    trimesh's point-triangle closest point on candidate pairs: a triangle farther than
    |p - centroid| - R (R its circumradius about the centroid) cannot beat the triangle with the nearest
    centroid, so only triangles whose centroid lies within d0 + R_max are tried.
    """
    from trimesh.triangles import closest_point

    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    cen = tri.mean(axis=1)
    r_max = float(np.linalg.norm(tri - cen[:, None, :], axis=2).max())
    tree = cKDTree(cen)
    _, near = tree.query(points, k=1)
    d0 = np.linalg.norm(closest_point(tri[near], points) - points, axis=1)
    cand = tree.query_ball_point(points, d0 + r_max + 1e-12)
    counts = np.array([len(c) for c in cand], dtype=np.int64)
    pi = np.repeat(np.arange(len(points)), counts)
    ti = np.concatenate([np.asarray(c, dtype=np.int64) for c in cand]) if len(cand) else np.empty(0, np.int64)
    dist = np.linalg.norm(closest_point(tri[ti], points[pi]) - points[pi], axis=1)
    order = np.lexsort((dist, pi))
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return dist[order][first], ti[order][first]


def _check_obstacles(obstacles: Sequence[tuple[np.ndarray, np.ndarray]], lo: np.ndarray, hi: np.ndarray,
                     ground_z: float) -> list[tuple[np.ndarray, np.ndarray]]:  # fmt: skip
    out = []
    for i, (v, f) in enumerate(obstacles):
        v = np.asarray(v, dtype=np.float64)
        f = np.asarray(f, dtype=np.int64)
        problem = basic_mesh_problem(v, f) or closed_mesh_problem(v, f)
        if problem:
            raise ValueError(f"obstacle {i}: {problem}")
        if not np.all((v[:, :2] > lo[:2]) & (v[:, :2] < hi[:2])) or not np.all(v[:, 2] < hi[2]):
            raise ValueError(f"obstacle {i}: vertices must lie strictly inside the domain's xy box and below its top")
        if not np.any(v[:, 2] > ground_z):
            raise ValueError(f"obstacle {i}: lies entirely below the ground z = {ground_z:g}")
        out.append((v, f))
    return out


class _AirBox(NamedTuple):
    """The checked inputs: lo, hi (3,) metres; ground height gz (m); obstacles [(vertices (V, 3) m, faces
    (F, 3) int64)]; mats (n_obstacles,) int64 material per obstacle; planes_def: the 6 box planes as
    (axis, value) (ground z = gz, x lo, x hi, y lo, y hi, top)."""

    lo: np.ndarray
    hi: np.ndarray
    gz: float
    obs: list[tuple[np.ndarray, np.ndarray]]
    mats: np.ndarray
    planes_def: list[tuple[int, float]]


class _ObstacleFaces(NamedTuple):
    """The boundary faces (nb of them) after the snap: cell bc (nb,), face slot bf (nb,), vertex ids fv
    (nb, 3) and the masks is_ground, is_side, is_top, is_obst (nb,) (obstacle = on no box plane)."""

    bc: np.ndarray
    bf: np.ndarray
    fv: np.ndarray
    is_ground: np.ndarray
    is_side: np.ndarray
    is_top: np.ndarray
    is_obst: np.ndarray


def _check_air_box(domain_min, domain_max, ground_z: float, obstacles: Sequence[tuple[np.ndarray, np.ndarray]],
                   materials: Sequence[int] | None, top: str, gradient_method: str, edge_length: float,
                   epsilon: float) -> _AirBox:  # fmt: skip
    """Validate the arguments of ``build_obstacle_tet_mesh`` (ValueError naming the first bad one)."""
    lo = np.asarray(domain_min, dtype=np.float64).reshape(3)
    hi = np.asarray(domain_max, dtype=np.float64).reshape(3)
    gz = float(ground_z)
    if not np.all(hi > lo):
        raise ValueError(f"domain_max {hi} must exceed domain_min {lo} on every axis")
    if not (lo[2] <= gz < hi[2]):
        raise ValueError(f"ground_z = {gz:g} must lie in [domain_min z, domain_max z)")
    if top not in ("open", "reflect"):
        raise ValueError(f"top must be 'open' or 'reflect', got {top!r}")
    if gradient_method not in GRADIENT_METHODS:
        raise ValueError(f"gradient_method must be one of {GRADIENT_METHODS}, got {gradient_method!r}")
    if not (np.isfinite(edge_length) and edge_length > 0):
        raise ValueError("edge_length must be positive")
    if not (0.0 < epsilon < 1.0):
        raise ValueError("epsilon must be in (0, 1)")
    obs = _check_obstacles(obstacles, lo, hi, gz)
    if not obs:
        raise ValueError("no obstacles: use the terrain-following or box builders")
    mats = np.zeros(len(obs), dtype=np.int64) if materials is None else np.asarray(materials, dtype=np.int64)
    if mats.shape != (len(obs),):
        raise ValueError(f"materials must have one entry per obstacle ({len(obs)})")
    planes_def = [(2, gz), (0, lo[0]), (0, hi[0]), (1, lo[1]), (1, hi[1]), (2, hi[2])]  # ground, 4 sides, top
    return _AirBox(lo, hi, gz, obs, mats, planes_def)


def _air_surface(box: _AirBox) -> tuple[np.ndarray, np.ndarray]:
    """fTetWild's input: the air box [lo_x, hi_x] x [lo_y, hi_y] x [gz, hi_z] (outward triangles) and every
    obstacle reversed (a hole in the air volume). Returns vertices (V, 3) metres and triangles (F, 3)."""
    bv, bf = _box_surface(np.array([box.lo[0], box.lo[1], box.gz]), box.hi)
    verts, faces = [bv], [bf]
    offset = len(bv)
    for v, f in box.obs:
        verts.append(v)
        faces.append(f[:, ::-1] + offset)  # reversed: obstacles are holes in the air volume
        offset += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def _check_clearance(box: _AirBox, tol: float) -> None:
    """ValueError when an obstacle comes within the snap tolerance ``tol`` (m) of the sides or the top."""
    lo, hi = box.lo, box.hi
    for i, (v, _) in enumerate(box.obs):
        gap = min(float((v[:, :2] - lo[:2]).min()), float((hi[:2] - v[:, :2]).min()), float(hi[2] - v[:, 2].max()))
        if gap <= tol:
            raise ValueError(f"obstacle {i}: {gap:.3g} m from the domain sides / top, not more than the snap "
                             f"tolerance {tol:.3g} m; enlarge the domain or lower epsilon")  # fmt: skip


def _compact(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop the points (P, 3) no tet (T, 4) uses and renumber the tets; MeshBuildError without tets."""
    if len(tets) == 0:
        raise MeshBuildError("fTetWild returned no tetrahedra")
    used = np.unique(tets)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return np.ascontiguousarray(points[used]), remap[tets]


def _snap_to_box_planes(points: np.ndarray, tets: np.ndarray, planes_def: list[tuple[int, float]],
                        tol: float) -> float:  # fmt: skip
    """Move the vertices of every boundary face lying within ``tol`` (m) of a box plane exactly onto it
    (``points`` (P, 3) is modified in place); returns the largest move, metres."""
    faces_all = face_vertices(tets)
    nbrs, _ = match_faces(faces_all, len(points), len(points))
    bc, bf_ = np.nonzero(nbrs < 0)
    fv = faces_all[bc, bf_]  # (nb, 3)
    dist = np.stack([np.abs(points[fv, ax] - val).max(axis=1) for ax, val in planes_def], axis=1)  # (nb, 6)
    which = np.where(dist.min(axis=1) <= tol, dist.argmin(axis=1), -1)
    snap_max = 0.0
    for k, (ax, val) in enumerate(planes_def):
        vid = np.unique(fv[which == k])
        if len(vid):
            snap_max = max(snap_max, float(np.abs(points[vid, ax] - val).max()))
            points[vid, ax] = val
    return snap_max


def _drop_slivers_and_orient(points: np.ndarray, tets: np.ndarray, planes_def: list[tuple[int, float]],
                             snap_max: float) -> tuple[np.ndarray, int]:  # fmt: skip
    """Remove the tets whose 4 vertices all lie on one box plane after the snap (no volume: as tets.py
    drops qhull's hull slivers; their other faces become boundary faces on that plane), flip the negative
    ones (swap vertices 0 and 1); MeshBuildError if any is flat. Returns (tets (T, 4), slivers removed)."""
    on_plane = np.zeros(len(tets), dtype=bool)
    for ax, val in planes_def:
        on_plane |= np.all(points[tets, ax] == val, axis=1)
    n_slivers = int(on_plane.sum())
    tets = tets[~on_plane]
    p = points[tets]
    vol6 = np.linalg.det(p[:, 1:, :] - p[:, :1, :])
    neg = vol6 < 0
    tets[neg, 0], tets[neg, 1] = tets[neg, 1], tets[neg, 0].copy()
    pairs = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])
    longest = np.linalg.norm(p[:, pairs[:, 0]] - p[:, pairs[:, 1]], axis=2).max(axis=1)
    flat = np.abs(vol6) <= DEGENERATE_VOL_REL * longest**3
    if np.any(flat):
        raise MeshBuildError(f"{int(flat.sum())} flat tets after fTetWild and the box-plane snap "
                             f"(snap moved vertices up to {snap_max:.3g} m); lower epsilon")  # fmt: skip
    return tets, n_slivers


def _boundary_faces(points: np.ndarray, faces_all: np.ndarray, nbrs: np.ndarray,
                    planes_def: list[tuple[int, float]]) -> _ObstacleFaces:  # fmt: skip
    """Classify the boundary faces (nbrs < 0) by the box plane holding all 3 vertices (exact after the
    snap); faces on none are obstacle faces."""
    bc, bf_ = np.nonzero(nbrs < 0)
    fv = faces_all[bc, bf_]
    on = np.stack([np.all(points[fv, ax] == val, axis=1) for ax, val in planes_def], axis=1)  # exact after snap
    is_ground, is_side, is_top = on[:, 0], np.any(on[:, 1:5], axis=1), on[:, 5]
    is_obst = ~(is_ground | is_side | is_top)
    return _ObstacleFaces(bc, bf_, fv, is_ground, is_side, is_top, is_obst)


def _surface_deviation(points: np.ndarray, bfaces: _ObstacleFaces, tri_all: np.ndarray,
                       tol: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Distances (m) of the obstacle faces from the input obstacle triangles tri_all (F, 3, 3): at their
    vertices (dev_v), and at the vertices, edge midpoints and centroids (dev: fTetWild's edge flips cut
    chords). MeshBuildError when one exceeds ``tol`` (m). Returns (dev, dev_v)."""
    fv, is_obst = bfaces.fv, bfaces.is_obst
    ov = np.unique(fv[is_obst])
    dev_v = surface_distance(points[ov], tri_all)[0] if len(ov) else np.zeros(0)
    ot = points[fv[is_obst]]  # (no, 3, 3)
    probes = np.concatenate([0.5 * (ot + np.roll(ot, 1, axis=1)), ot.mean(axis=1, keepdims=True)], axis=1)
    dev = np.concatenate([dev_v, surface_distance(probes.reshape(-1, 3), tri_all)[0] if len(ot) else []])
    if len(dev) and dev.max() > tol:
        raise MeshBuildError(f"a boundary face is neither on a box plane nor within {tol:.3g} m of an obstacle "
                             f"(vertex {dev.max():.3g} m away); lower epsilon")  # fmt: skip
    return dev, dev_v


def _tags_and_materials(
    points: np.ndarray,
    nbrs: np.ndarray,
    bfaces: _ObstacleFaces,
    box: _AirBox,
    tri_all: np.ndarray,
    top: str,
    ground_material: int,
) -> tuple[np.ndarray, np.ndarray]:
    """neighbours (T, 4) with boundary tags (ground and obstacles BOUNDARY_REFLECT, top as asked, sides
    BOUNDARY_OPEN) and face_material (T, 4): ground_material on the ground, on an obstacle face the
    material of the obstacle owning the input triangle nearest its centroid."""
    bc, bf_, is_ground, is_obst = bfaces.bc, bfaces.bf, bfaces.is_ground, bfaces.is_obst
    neighbours = nbrs.copy()
    top_tag = np.where(bfaces.is_top & (top == "reflect"), BOUNDARY_REFLECT, BOUNDARY_OPEN)
    neighbours[bc, bf_] = np.where(is_ground | is_obst, BOUNDARY_REFLECT, top_tag)
    face_material = np.zeros(nbrs.shape, dtype=np.int64)
    face_material[bc[is_ground], bf_[is_ground]] = int(ground_material)
    oi = np.flatnonzero(is_obst)
    if len(oi):
        tri_owner = np.repeat(np.arange(len(box.obs)), [len(f) for _, f in box.obs])
        near_tri = surface_distance(points[bfaces.fv[oi]].mean(axis=1), tri_all)[1]
        face_material[bc[oi], bf_[oi]] = box.mats[tri_owner[near_tri]]
    return neighbours, face_material


class _Snap(NamedTuple):
    """fTetWild's envelope eps_abs (m), the snap tolerance (m), the largest snap move (m) and the number of
    box-plane slivers removed."""

    envelope: float
    tol: float
    snap_max: float
    n_slivers: int


class _Tables(NamedTuple):
    """Traversal tables of the air mesh: tets (T, 4) in Morton order, neighbour_face nbf (T, 4), outward
    planes (T, 4, 4), face_planes' quality dict qual, the classified boundary faces, the obstacle-surface
    deviations dev / dev_v (m), neighbours (T, 4) with boundary tags and face_material (T, 4)."""

    tets: np.ndarray
    nbf: np.ndarray
    planes: np.ndarray
    qual: dict
    bfaces: _ObstacleFaces
    dev: np.ndarray
    dev_v: np.ndarray
    neighbours: np.ndarray
    face_material: np.ndarray


def _air_tets(box: _AirBox, edge_length: float, epsilon: float, snap_tol: float | None, num_threads: int,
              optimize: bool) -> tuple[np.ndarray, np.ndarray, float, float]:  # fmt: skip
    """fTetWild on the air surface: points (P, 3) m, tets (T, 4), the envelope eps_abs = epsilon x input
    bounding-box diagonal (m) and the snap tolerance (m: snap_tol, default SNAP_ENVELOPES envelopes)."""
    in_v, in_f = _air_surface(box)
    envelope = float(epsilon * np.linalg.norm(in_v.max(axis=0) - in_v.min(axis=0)))
    tol = SNAP_ENVELOPES * envelope if snap_tol is None else float(snap_tol)
    _check_clearance(box, tol)
    points, tets = _run_tetwild(in_v, in_f, edge_length, epsilon, num_threads, optimize)
    return points, tets, envelope, tol


def _air_tables(points: np.ndarray, tets: np.ndarray, box: _AirBox, tol: float, top: str,
                ground_material: int) -> _Tables:  # fmt: skip
    """Morton order (tets.py), neighbours and shared planes (prisms.py helpers), boundary classification,
    the obstacle-surface deviation check and the boundary tags; MeshBuildError on flat tets."""
    tets = np.ascontiguousarray(tets[_morton_order(points[tets].mean(axis=1), box.lo, box.hi)])
    faces_all = face_vertices(tets)
    nbrs, nbf = match_faces(faces_all, len(points), len(points))
    planes, qual = face_planes(points, tets, faces_all, nbrs, nbf)
    vol, longest = qual["volume"], qual["longest_edge"]
    if np.any(6.0 * vol <= DEGENERATE_VOL_REL * longest**3):
        raise MeshBuildError(f"{int((6.0 * vol <= DEGENERATE_VOL_REL * longest**3).sum())} flat or inverted tets")
    bfaces = _boundary_faces(points, faces_all, nbrs, box.planes_def)
    tri_all = np.concatenate([v[f] for v, f in box.obs])
    dev, dev_v = _surface_deviation(points, bfaces, tri_all, tol)
    neighbours, face_material = _tags_and_materials(points, nbrs, bfaces, box, tri_all, top, ground_material)
    return _Tables(tets, nbf, planes, qual, bfaces, dev, dev_v, neighbours, face_material)


def _air_stats(points: np.ndarray, box: _AirBox, snap: _Snap, tab: _Tables, edge_length: float, epsilon: float,
               gradient_method: str, n_fallback: int, times: list[float]) -> dict:  # fmt: skip
    """The ``stats`` of ``build_obstacle_tet_mesh`` (times: perf_counter at start, after fTetWild, after
    the tables, after the gradients)."""
    t0, t1, t2, t3 = times
    dev, dev_v, bfaces, neighbours = tab.dev, tab.dev_v, tab.bfaces, tab.neighbours
    return {
        "n_points": int(len(points)),
        "n_cells": int(len(tab.tets)),
        "n_obstacles": len(box.obs),
        "n_degenerate": 0,
        "edge_length_m": float(edge_length),
        "epsilon": float(epsilon),
        "envelope_m": snap.envelope,
        "snap_tol_m": snap.tol,
        "snap_max_m": snap.snap_max,
        "n_plane_slivers_removed": snap.n_slivers,
        "surface_deviation_m": {
            "max": float(dev.max()) if len(dev) else 0.0,
            "median": float(np.median(dev)) if len(dev) else 0.0,
            "max_at_vertices": float(dev_v.max()) if len(dev_v) else 0.0,
        },  # fmt: skip
        **tab.qual["summary"],
        "n_boundary_faces": {
            "ground": int(bfaces.is_ground.sum()),
            "obstacle": int(bfaces.is_obst.sum()),
            "sides": int(bfaces.is_side.sum()),
            "top": int(bfaces.is_top.sum()),
            "reflect": int((neighbours == BOUNDARY_REFLECT).sum()),
            "open": int((neighbours == BOUNDARY_OPEN).sum()),
        },
        "gradient_method": gradient_method,
        "n_lsq_fallback": n_fallback,
        "build_time_s": {
            "tetwild": t1 - t0,
            "tables": t2 - t1,
            "gradients": t3 - t2,
            "total": time.perf_counter() - t0,
        },
    }


def build_obstacle_tet_mesh(
    domain_min,
    domain_max,
    ground_z: float,
    obstacles: Sequence[tuple[np.ndarray, np.ndarray]],
    *,
    quantity_at: Callable[[np.ndarray], np.ndarray],
    edge_length: float,
    epsilon: float = DEFAULT_EPSILON,
    materials: Sequence[int] | None = None,
    ground_material: int = 0,
    top: str = "open",
    gradient_method: str = "lsq",
    snap_tol: float | None = None,
    num_threads: int = 1,
    optimize: bool = True,
) -> TetMesh:
    """Tetrahedral CellMesh of the air: the box above the flat ground z = ground_z minus closed obstacles.

    Parameters
    ----------
    domain_min, domain_max : (3,) metres, world frame, z up; the mesh spans x, y of the box and
        z from ground_z to domain_max z.
    ground_z : flat ground height, metres, domain_min z <= ground_z < domain_max z.
    obstacles : list of (vertices (V, 3) float64 metres, faces (F, 3) int64): closed, outward oriented,
        not self-intersecting (checked as engine.mesh.surface_checks), strictly inside the box's xy extent and
        below its top by more than snap_tol; they may reach below the ground.
    quantity_at : callable, xyz (N, 3) float64 metres -> traced quantity m (N,) (n^2, c or n).
    edge_length : fTetWild's ideal edge length, metres.
    epsilon : fTetWild's envelope, relative to the input bounding-box diagonal (dimensionless).
    materials : material index of each obstacle's faces (default 0 = rigid); ground_material likewise.
    top : "open" or "reflect" (tag of the faces on z = domain_max z); sides are always BOUNDARY_OPEN.
    gradient_method : "lsq", "lsq_unweighted" or "green_gauss" (as tets.build_tet_mesh).
    snap_tol : box-plane classification / snap tolerance, metres (default SNAP_ENVELOPES envelopes).
    num_threads : fTetWild threads (0: all cores). Even one thread does not give the same mesh twice: eight builds
        of the same box obstacle (tests/mesh/test_tetwild_obstacles.py) gave 7,422 to 8,845 tets.
    optimize : fTetWild's quality optimisation (off is faster and gives worse tets).

    Returns
    -------
    TetMesh, tets positively oriented, cells in Morton order. ``stats`` holds n_points, n_cells,
    n_boundary_faces (ground, obstacle, sides, top, reflect, open), edge_length_m, epsilon,
    envelope_m (eps_abs), snap_tol_m, snap_max_m (largest vertex move onto a box plane),
    surface_deviation_m (max and median distance of the obstacle faces' vertices from the input
    obstacle surface, probed at the obstacle faces' vertices, edge midpoints and centroids; and at the
    vertices alone), the face_planes quality summary, n_lsq_fallback and build_time_s.

    Raises
    ------
    ValueError on bad arguments or obstacles; MeshBuildError when fTetWild's output fails the checks.
    """
    t0 = time.perf_counter()
    box = _check_air_box(domain_min, domain_max, ground_z, obstacles, materials, top, gradient_method, edge_length,
                         epsilon)  # fmt: skip
    points, tets, envelope, tol = _air_tets(box, edge_length, epsilon, snap_tol, num_threads, optimize)
    t1 = time.perf_counter()
    points, tets = _compact(points, tets)
    snap_max = _snap_to_box_planes(points, tets, box.planes_def, tol)
    tets, n_slivers = _drop_slivers_and_orient(points, tets, box.planes_def, snap_max)
    tab = _air_tables(points, tets, box, tol, top, ground_material)
    t2 = time.perf_counter()
    cells, vertex_values, n_fallback = tet_cell_mesh(points, tab.tets, tab.planes, tab.neighbours, tab.nbf,
                                                     tab.qual["longest_edge"], tab.face_material, quantity_at,
                                                     gradient_method)  # fmt: skip
    t3 = time.perf_counter()
    snap = _Snap(envelope, tol, snap_max, n_slivers)
    stats = _air_stats(points, box, snap, tab, edge_length, epsilon, gradient_method, n_fallback, [t0, t1, t2, t3])
    return TetMesh(cells=cells, points=points, tets=tab.tets, stats=stats, vertex_values=vertex_values)


def locate_in_obstacle_mesh(tet_mesh: TetMesh, xyz: np.ndarray) -> np.ndarray:
    """Cell id (N,) int64 containing each point of ``xyz`` (N, 3) metres, or -1 outside the air volume.

    tets.locate_tets (visibility walk; it stops at boundary faces, so a point behind an obstacle may be
    missed), then brute force (cells.locate_points) for the points it did not find: exact, O(cells)
    per missed point (sources, not receiver grids).
    """
    xyz = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
    cell, _ = locate_tets(tet_mesh, xyz)
    miss = np.flatnonzero(cell < 0)
    if len(miss):
        cell[miss] = locate_points(tet_mesh.cells, xyz[miss])
    return cell

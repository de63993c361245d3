"""Appendix C alternative: surfaces *linked* to the media cells they overlap, instead of embedded in the mesh.

The default scene mesh (terrain.py) conforms to the terrain, walls and roofs: they are reflecting boundary
faces. Here the media mesh ignores the surfaces (the paper's Sec. 5.2 second option, after [17]):

1. Media mesh: the same terrain-following prism/tet builder (terrain.py) over *flat* ground at the lowest
   surface point (minus a small margin), with the caller's horizontal spacing and absolute layer levels.
   It does not conform to any surface, so the surface tessellation cannot change it.
2. Surface triangles (``surface_triangles``): the terrain (two per HeightGrid square, a TriangleSurface's
   own triangles, or two for flat ground), every footprint's walls (two per polygon edge, from below the
   terrain to the roof, so they seal against it) and roof (ear clipping, k - 2). Footprints are validated
   and their roof heights found exactly as terrain.py does (``base_z`` None: lowest terrain sample under the
   polygon). Each triangle's plane normal points *into the solid* (down for ground and roofs, inward for
   walls), so a ray reaches a surface where the plane's signed distance crosses zero upward, exactly as it
   leaves a cell through a face (kernels/roots.py).
3. Link table (``link_cells``): candidate (cell, triangle) pairs from padded bounding boxes
   (engine.mesh.boxes.box_pairs), then an exact separating-axis test in Numba (23 axes: the triangle normal,
   4 tet face normals, 18 edge-edge cross products) padded by LINK_TOL_REL x cell size, so touching pairs
   are linked (conservative). CSR: ``link_offsets`` (n_cells + 1), ``link_tris``.
4. Solid cells: a cell with no links lies entirely on one side of every surface; it is solid when its
   centroid is below the terrain or inside a footprint under its roof. Faces of air cells leading into
   solid cells, and the flat bottom, get the tag BOUNDARY_SOLID: a ray crossing one leaked through a
   surface and ends as lost (never silently).

World frame, metres, z up; float64 everywhere.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, NamedTuple

import numba as nb
import numpy as np

from bentray.engine.constants import BOUNDARY_REFLECT, NJIT_FLAGS, PARALLEL_FLAGS
from bentray.engine.mesh.boxes import box_pairs
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.mesh.terrain import (
    _check_footprints,
    _terrain,
    build_terrain_mesh,
    locate_in_terrain_mesh,
    terrain_index,
)
from bentray.engine.mesh.tets import TetMesh
from bentray.engine.mesh.triangulate2d import TriangleLocator, checked_spacing_2d, points_in_polygon
from bentray.engine.surfaces import HeightGrid, SceneSurfaces, TriangleSurface

__all__ = [
    "BOUNDARY_SOLID",
    "KIND_GROUND",
    "KIND_WALL",
    "KIND_ROOF",
    "SurfaceTriangles",
    "LinkedMesh",
    "surface_triangles",
    "link_cells",
    "tet_triangle_overlap",
    "build_linked_mesh",
    "locate_in_linked_mesh",
]

# Boundary tag (CellMesh.neighbours) of a face leading into a solid cell (below the terrain, inside a
# building) or through the flat bottom: crossing it means the ray leaked through a linked surface.
BOUNDARY_SOLID = -3
KIND_GROUND, KIND_WALL, KIND_ROOF = 0, 1, 2
# Separating-axis slack, relative to the cell's longest edge: a pair separated by less than 1e-9 of the
# cell size counts as overlapping (touching pairs are linked; conservative). 1e-9 of a 30 m cell is 30 nm,
# far above rounding of km-scale coordinates (~1e-13 m) and far below any geometry that matters.
LINK_TOL_REL = 1e-9
# Edge-edge axes shorter than this (relative to |e1| |e2|) come from (nearly) parallel edges: skipped,
# the face normals already cover those directions.
PARALLEL_AXIS_REL = 1e-12
# Flat bottom of the media mesh sits this fraction of the domain height below the lowest surface point, so
# no surface vertex lies on a mesh face (the media below the domain bottom is clamped to its value there).
BOTTOM_MARGIN_REL = 1e-3
# Cells per bounding-box candidate search (engine.mesh.boxes.box_pairs caps candidates at 20M per call).
LINK_CHUNK = 250_000


class SurfaceTriangles(NamedTuple):
    """Surface triangles of a scene.

    vertices : (T, 3, 3) float64 metres, world frame. normal : (T, 3) unit, pointing into the solid.
    material : (T,) int64 index into SceneSurfaces.materials. kind : (T,) int8 (KIND_GROUND/WALL/ROOF).
    """

    vertices: np.ndarray
    normal: np.ndarray
    material: np.ndarray
    kind: np.ndarray

    @property
    def n(self) -> int:
        return int(self.vertices.shape[0])


class LinkedMesh(NamedTuple):
    """An unconstrained media mesh plus the surface triangles linked to the cells they overlap.

    cells : CellMesh (tets, K = 4); faces into solid cells and the flat bottom are BOUNDARY_SOLID.
    tet : the TetMesh the cells came from (points, tets; for location and overlap tests).
    triangles : SurfaceTriangles. link_offsets : (n_cells + 1,) int64; link_tris : (L,) int64 -- the
    triangles overlapping cell c are ``link_tris[link_offsets[c]:link_offsets[c + 1]]``.
    tri_plane : (T, 4) float64 (n, h) with n . x = h on the triangle, n into the solid.
    tri_origin : (T, 3) float64 vertex 0. tri_dual : (T, 2, 3) float64 vectors a1, a2 with barycentric
    u = (x - v0) . a1, v = (x - v0) . a2 (of x's projection on the plane along n).
    solid : (n_cells,) bool. stats : counts and build times (``build_linked_mesh``).
    """

    cells: CellMesh
    tet: TetMesh
    triangles: SurfaceTriangles
    link_offsets: np.ndarray
    link_tris: np.ndarray
    tri_plane: np.ndarray
    tri_origin: np.ndarray
    tri_dual: np.ndarray
    solid: np.ndarray
    stats: dict[str, Any]

    def kernel_links(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(link_offsets, link_tris, tri_plane, tri_origin, tri_dual) as the traversal kernel takes them."""
        return self.link_offsets, self.link_tris, self.tri_plane, self.tri_origin, self.tri_dual


# ---------------------------------------------------------------------------------------------------
# Surface triangles
# ---------------------------------------------------------------------------------------------------
def _ear_clip(poly: np.ndarray) -> np.ndarray:
    """(k - 2, 3) vertex ids triangulating a simple counter-clockwise polygon (k, 2) by ear clipping."""
    idx = list(range(len(poly)))
    out = []

    def cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
        return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))

    guard = 0
    while len(idx) > 3 and guard < 10 * len(poly) ** 2:
        guard += 1
        n = len(idx)
        for k in range(n):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % n]
            a, b, c = poly[i0], poly[i1], poly[i2]
            if cross(a, b, c) <= 0.0:
                continue  # reflex (or flat) corner: not an ear
            others = [j for j in idx if j not in (i0, i1, i2)]
            p = poly[others]
            inside = ((b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0]) >= 0) & (
                (c[0] - b[0]) * (p[:, 1] - b[1]) - (c[1] - b[1]) * (p[:, 0] - b[0]) >= 0) & (
                (a[0] - c[0]) * (p[:, 1] - c[1]) - (a[1] - c[1]) * (p[:, 0] - c[0]) >= 0)  # fmt: skip
            if inside.any():
                continue
            out.append((i0, i1, i2))
            idx.pop(k)
            break
        else:
            raise ValueError("ear clipping failed: polygon is not simple and counter-clockwise")
    out.append(tuple(idx))
    return np.asarray(out, dtype=np.int64)


def _grid_triangles(grid: HeightGrid, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles per HeightGrid square overlapping the box (diagonal (i, j)-(i+1, j+1)); materials."""
    x, y, z = (np.asarray(a, dtype=np.float64) for a in (grid.x, grid.y, grid.z))
    i = np.flatnonzero((x[1:] > lo[0]) & (x[:-1] < hi[0]))
    j = np.flatnonzero((y[1:] > lo[1]) & (y[:-1] < hi[1]))
    jj, ii = (a.ravel() for a in np.meshgrid(j, i, indexing="ij"))

    def node(dj: int, di: int) -> np.ndarray:
        return np.column_stack([x[ii + di], y[jj + dj], z[jj + dj, ii + di]])

    p00, p10, p11, p01 = node(0, 0), node(0, 1), node(1, 1), node(1, 0)
    tris = np.concatenate([np.stack([p00, p10, p11], axis=1), np.stack([p00, p11, p01], axis=1)])
    mat = (np.full(len(ii), int(grid.default_material), dtype=np.int64) if grid.material is None
           else np.asarray(grid.material, dtype=np.int64)[jj, ii])  # fmt: skip
    return tris, np.concatenate([mat, mat])


def _terrain_triangles(surfaces: SceneSurfaces, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = surfaces.terrain
    if t is None:
        c = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        p = np.column_stack([c, np.full(4, lo[2])])
        return np.stack([p[[0, 1, 2]], p[[0, 2, 3]]]), np.zeros(2, dtype=np.int64)
    if isinstance(t, HeightGrid):
        return _grid_triangles(t, lo, hi)
    if isinstance(t, TriangleSurface):
        v = np.asarray(t.vertices, dtype=np.float64)
        tri = np.asarray(t.triangles, dtype=np.int64)
        p = v[tri]
        keep = np.all((p[:, :, :2].max(axis=1) > lo[:2]) & (p[:, :, :2].min(axis=1) < hi[:2]), axis=1)
        mat = (np.full(len(tri), int(t.default_material), dtype=np.int64) if t.material is None
               else np.asarray(t.material, dtype=np.int64))  # fmt: skip
        return p[keep], mat[keep]
    raise ValueError(f"unsupported terrain type {type(t).__name__}")


def surface_triangles(surfaces: SceneSurfaces, domain_min, domain_max) -> SurfaceTriangles:
    """Terrain, wall and roof triangles of ``surfaces`` over the domain box (see the module docstring).

    Raises ValueError for invalid terrain or footprints (the checks of terrain.py) and for obstacles.
    """
    lo = np.asarray(domain_min, dtype=np.float64).reshape(3)
    hi = np.asarray(domain_max, dtype=np.float64).reshape(3)
    if surfaces.obstacles:
        raise ValueError("closed obstacle meshes are not supported by the linked surfaces")
    ground, gmat = _terrain_triangles(surfaces, lo, hi)
    parts, mats, kinds = [ground], [gmat], [np.full(len(ground), KIND_GROUND, dtype=np.int8)]
    polys = _check_footprints(list(surfaces.footprints), lo, hi)
    if polys:
        # heights and samples exactly as terrain.py (base_z None: lowest terrain sample under the polygon)
        terrain = _terrain(surfaces.terrain, lo, hi, checked_spacing_2d(float(np.max(hi - lo))))
        g_lo, g_hi = ground[:, :, :2].min(axis=1), ground[:, :, :2].max(axis=1)
        for fp, poly in zip(surfaces.footprints, polys, strict=True):
            if fp.base_z is None:
                s_in = terrain.samples_in(poly)
                base = float(terrain.height(np.concatenate([poly, s_in]) if len(s_in) else poly).min())
            else:
                base = float(fp.base_z)
            roof = base + float(fp.height_m)
            # walls reach down to the lowest terrain vertex near the footprint: sealed against the ground
            near = np.all((g_hi >= poly.min(axis=0)) & (g_lo <= poly.max(axis=0)), axis=1)
            bottom = min(base, float(ground[near][:, :, 2].min())) if near.any() else base
            if not roof < hi[2]:
                raise ValueError(f"footprint {fp.name}: roof z = {roof:g} must be below domain_max z")
            q = np.roll(poly, -1, axis=0)
            a, b = np.column_stack([poly, np.full(len(poly), bottom)]), np.column_stack([q, np.full(len(q), bottom)])
            a2, b2 = a.copy(), b.copy()
            a2[:, 2] = roof
            b2[:, 2] = roof
            walls = np.concatenate([np.stack([a, b, b2], axis=1), np.stack([a, b2, a2], axis=1)])
            roof_tris = np.column_stack([poly, np.full(len(poly), roof)])[_ear_clip(poly)]
            parts += [walls, roof_tris]
            mats += [np.full(len(walls) + len(roof_tris), int(fp.material), dtype=np.int64)]
            kinds += [np.full(len(walls), KIND_WALL, dtype=np.int8), np.full(len(roof_tris), KIND_ROOF, dtype=np.int8)]
    verts = np.ascontiguousarray(np.concatenate(parts))
    kind = np.concatenate(kinds)
    n = np.cross(verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0])
    n /= np.linalg.norm(n, axis=1)[:, None]
    # into the solid: down for ground and roofs; for walls, toward the polygon's inside (CCW: left of the edge)
    wall = kind == KIND_WALL
    edge = verts[:, 1] - verts[:, 0]
    inward = np.column_stack([-edge[:, 1], edge[:, 0], np.zeros(len(edge))])
    flip = np.where(wall, np.einsum("ij,ij->i", n, inward) < 0.0, n[:, 2] > 0.0)
    n[flip] *= -1.0
    return SurfaceTriangles(verts, np.ascontiguousarray(n), np.concatenate(mats), kind)


def triangle_tables(tri: SurfaceTriangles) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kernel tables (tri_plane (T, 4), tri_origin (T, 3), tri_dual (T, 2, 3)); see LinkedMesh."""
    v0 = tri.vertices[:, 0]
    e1, e2 = tri.vertices[:, 1] - v0, tri.vertices[:, 2] - v0
    nn = np.cross(e1, e2)
    n2 = np.einsum("ij,ij->i", nn, nn)[:, None]
    dual = np.stack([np.cross(e2, nn) / n2, np.cross(nn, e1) / n2], axis=1)
    plane = np.column_stack([tri.normal, np.einsum("ij,ij->i", tri.normal, v0)])
    return np.ascontiguousarray(plane), np.ascontiguousarray(v0), np.ascontiguousarray(dual)


# ---------------------------------------------------------------------------------------------------
# Link table: exact tet / triangle overlap (separating axes)
# ---------------------------------------------------------------------------------------------------
@nb.njit(**NJIT_FLAGS)
def _separated(tv, sv, ax, ay, az, pad) -> bool:
    """True when the tet tv (4, 3) and the triangle sv (3, 3) are apart by more than pad along the axis."""
    norm = np.sqrt(ax * ax + ay * ay + az * az)
    lo1 = np.inf
    hi1 = -np.inf
    for i in range(4):
        p = tv[i, 0] * ax + tv[i, 1] * ay + tv[i, 2] * az
        lo1 = min(lo1, p)
        hi1 = max(hi1, p)
    lo2 = np.inf
    hi2 = -np.inf
    for i in range(3):
        p = sv[i, 0] * ax + sv[i, 1] * ay + sv[i, 2] * az
        lo2 = min(lo2, p)
        hi2 = max(hi2, p)
    gap = pad * norm
    return hi1 < lo2 - gap or hi2 < lo1 - gap


@nb.njit(**NJIT_FLAGS)
def tet_triangle_overlap(tv, sv, pad: float) -> bool:
    """Exact overlap of a tetrahedron tv (4, 3) and a triangle sv (3, 3), closed sets padded by ``pad`` m.

    Separating-axis theorem for two convex polytopes: they are disjoint iff some axis among the triangle
    normal, the tet's face normals and the cross products of their edges separates their projections.
    """
    e1 = sv[1] - sv[0]
    e2 = sv[2] - sv[0]
    n = np.cross(e1, e2)
    if _separated(tv, sv, n[0], n[1], n[2], pad):
        return False
    for f in range(4):  # face opposite vertex f
        a = tv[(f + 1) % 4]
        b = tv[(f + 2) % 4]
        c = tv[(f + 3) % 4]
        m = np.cross(b - a, c - a)
        if _separated(tv, sv, m[0], m[1], m[2], pad):
            return False
    for i in range(3):
        for j in range(i + 1, 4):
            te = tv[j] - tv[i]
            lt = np.sqrt(te[0] * te[0] + te[1] * te[1] + te[2] * te[2])
            for k in range(3):
                se = sv[(k + 1) % 3] - sv[k]
                ls = np.sqrt(se[0] * se[0] + se[1] * se[1] + se[2] * se[2])
                m = np.cross(te, se)
                if np.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]) <= PARALLEL_AXIS_REL * lt * ls:
                    continue
                if _separated(tv, sv, m[0], m[1], m[2], pad):
                    return False
    return True


@nb.njit(**PARALLEL_FLAGS)
def _overlap_pairs(cell_v, tri_v, ci, ti, pad, out):
    for k in nb.prange(ci.shape[0]):
        out[k] = tet_triangle_overlap(cell_v[ci[k]], tri_v[ti[k]], pad[ci[k]])


def link_cells(
    cell_vertices: np.ndarray, tri_vertices: np.ndarray, *, tol_rel: float = LINK_TOL_REL
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """CSR link table of the triangles overlapping each tetrahedral cell.

    cell_vertices : (C, 4, 3) float64 metres; tri_vertices : (T, 3, 3) float64 metres.
    tol_rel : overlap slack relative to each cell's longest edge (see LINK_TOL_REL).
    Returns (offsets (C + 1,) int64, tris (L,) int64 sorted per cell, stats: candidates, links, times).
    """
    cv = np.ascontiguousarray(cell_vertices, dtype=np.float64)
    tv = np.ascontiguousarray(tri_vertices, dtype=np.float64)
    t0 = time.perf_counter()
    clo, chi, tlo, thi = cv.min(axis=1), cv.max(axis=1), tv.min(axis=1), tv.max(axis=1)
    parts = []
    for start in range(0, len(cv), LINK_CHUNK):  # chunks keep box_pairs under its candidate limit
        a, b = box_pairs(clo[start : start + LINK_CHUNK], chi[start : start + LINK_CHUNK], tlo, thi)
        parts.append((a + start, b))
    ci = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, dtype=np.int64)
    ti = np.concatenate([p[1] for p in parts]) if parts else np.zeros(0, dtype=np.int64)
    t1 = time.perf_counter()
    edges = cv[:, [0, 0, 0, 1, 1, 2]] - cv[:, [1, 2, 3, 2, 3, 3]]
    pad = tol_rel * np.sqrt(np.einsum("ijk,ijk->ij", edges, edges).max(axis=1))
    ok = np.zeros(len(ci), dtype=np.bool_)
    if len(ci):
        _overlap_pairs(cv, tv, ci.astype(np.int64), ti.astype(np.int64), pad, ok)
    ci, ti = ci[ok], ti[ok]
    order = np.lexsort((ti, ci))
    ci, ti = ci[order], ti[order]
    offsets = np.zeros(len(cv) + 1, dtype=np.int64)
    np.cumsum(np.bincount(ci, minlength=len(cv)), out=offsets[1:])
    stats = {
        "candidate_pairs": int(len(ok)),
        "links": int(len(ti)),
        "candidates_s": t1 - t0,
        "exact_s": time.perf_counter() - t1,
    }
    return offsets, np.ascontiguousarray(ti, dtype=np.int64), stats


# ---------------------------------------------------------------------------------------------------
# Builder
# ---------------------------------------------------------------------------------------------------
def _solid_cells(centroids: np.ndarray, linked: np.ndarray, tri: SurfaceTriangles,
                 footprints: list[tuple[np.ndarray, float]]) -> np.ndarray:  # fmt: skip
    """Unlinked cells whose centroid is below the terrain triangles or inside a building under its roof."""
    cand = np.flatnonzero(~linked)
    solid = np.zeros(len(centroids), dtype=bool)
    if len(cand) == 0:
        return solid
    g = tri.vertices[tri.kind == KIND_GROUND]
    loc = TriangleLocator(g[:, :, :2].reshape(-1, 2), np.arange(3 * len(g)).reshape(-1, 3))
    t, w = loc.locate(centroids[cand, :2])
    height = np.where(t >= 0, np.einsum("ni,ni->n", w, g[np.maximum(t, 0), :, 2]), -np.inf)
    below = centroids[cand, 2] < height
    for poly, roof in footprints:
        below |= points_in_polygon(centroids[cand, :2], poly) & (centroids[cand, 2] < roof)
    solid[cand[below]] = True
    return solid


def build_linked_mesh(
    surfaces: SceneSurfaces,
    domain_min,
    domain_max,
    quantity_at: Callable[[np.ndarray], np.ndarray],
    *,
    horizontal_spacing: float,
    z_levels: np.ndarray,
    top: str = "open",
    gradient_method: str = "lsq",
) -> LinkedMesh:
    """Unconstrained layered media mesh with the scene's surface triangles linked to the cells they overlap.

    surfaces : terrain / footprints / materials (as build_terrain_mesh; obstacles unsupported).
    domain_min, domain_max : (3,) metres. quantity_at : xyz (N, 3) -> traced quantity (N,); evaluated with z
    clamped to >= domain_min z (the mesh bottom may sit slightly below it).
    horizontal_spacing : 2D triangle edge length of the media mesh (metres; independent of the surfaces).
    z_levels : absolute layer boundaries (metres, increasing, last = domain_max z); those above the mesh
    bottom (lowest surface point minus BOTTOM_MARGIN_REL x height) are kept, the bottom is prepended.
    top : "open" or "reflect".

    stats : cells, solid_cells, air_cells, triangles (ground / walls / roofs), links, linked_cells,
    tris_per_cell_mean (over air cells), tris_per_cell_mean_linked, tris_per_cell_max, candidate_pairs and
    build times in seconds: mesh_s, surfaces_s, link_s (candidates + exact test), solid_s, total_s.
    """
    t0 = time.perf_counter()
    lo = np.asarray(domain_min, dtype=np.float64).reshape(3)
    hi = np.asarray(domain_max, dtype=np.float64).reshape(3)
    tri = surface_triangles(surfaces, lo, hi)
    t1 = time.perf_counter()
    bottom = float(tri.vertices[:, :, 2].min()) - BOTTOM_MARGIN_REL * float(hi[2] - lo[2])
    z = np.asarray(z_levels, dtype=np.float64).reshape(-1)
    if len(z) < 2 or np.any(np.diff(z) <= 0) or z[-1] != hi[2]:
        raise ValueError("z_levels must increase strictly and end at domain_max z")
    z = np.concatenate([[bottom], z[z > bottom + 1e-6 * (hi[2] - bottom)]])
    if z[-1] != hi[2]:
        z = np.append(z, hi[2])
    sigma = (z - bottom) / (hi[2] - bottom)
    sigma[0], sigma[-1] = 0.0, 1.0
    z_floor = lo[2]

    def clamped(p: np.ndarray) -> np.ndarray:
        q = np.array(p, dtype=np.float64, copy=True)
        q[:, 2] = np.maximum(q[:, 2], z_floor)
        return quantity_at(q)

    box_lo = np.array([lo[0], lo[1], bottom])
    tet = build_terrain_mesh(
        SceneSurfaces(),
        box_lo,
        hi,
        clamped,
        horizontal_spacing=float(horizontal_spacing),
        layer_levels=sigma,
        top=top,
        gradient_method=gradient_method,
    )
    t2 = time.perf_counter()
    cell_v = tet.points[tet.tets]
    offsets, link_tris, link_stats = link_cells(cell_v, tri.vertices)
    t3 = time.perf_counter()
    counts = np.diff(offsets)
    fps = [(np.asarray(fp.polygon, float), float(r["roof_z"]))
           for fp, r in zip(surfaces.footprints, _roofs(tri, surfaces), strict=True)]  # fmt: skip
    solid = _solid_cells(tet.cells.ref_point, counts > 0, tri, fps)
    cells = tet.cells
    nbrs = cells.neighbours.copy()
    into_solid = (nbrs >= 0) & solid[np.maximum(nbrs, 0)]
    # the flat bottom of the layered mesh (build_terrain_mesh tags it as reflecting ground)
    bottom_face = (nbrs == BOUNDARY_REFLECT) & (cells.planes[:, :, 2] < -0.5)
    nbrs[into_solid | bottom_face] = BOUNDARY_SOLID
    cells = cells._replace(neighbours=nbrs)
    t4 = time.perf_counter()
    plane, origin, dual = triangle_tables(tri)
    air = ~solid
    stats = {
        "cells": int(cells.n_cells),
        "solid_cells": int(solid.sum()),
        "air_cells": int(air.sum()),
        "layers": int(len(sigma) - 1),
        "bottom_z": bottom,
        "horizontal_spacing_m": float(horizontal_spacing),
        "triangles": tri.n,
        "ground_triangles": int((tri.kind == KIND_GROUND).sum()),
        "wall_triangles": int((tri.kind == KIND_WALL).sum()),
        "roof_triangles": int((tri.kind == KIND_ROOF).sum()),
        "links": int(len(link_tris)),
        "linked_cells": int((counts > 0).sum()),
        "tris_per_cell_mean": float(counts[air].mean()) if air.any() else 0.0,
        "tris_per_cell_mean_linked": float(counts[counts > 0].mean()) if (counts > 0).any() else 0.0,
        "tris_per_cell_max": int(counts.max()) if len(counts) else 0,
        "candidate_pairs": link_stats["candidate_pairs"],
        "mesh_s": t2 - t1,
        "surfaces_s": t1 - t0,
        "link_s": t3 - t2,
        "link_candidates_s": link_stats["candidates_s"],
        "link_exact_s": link_stats["exact_s"],
        "solid_s": t4 - t3,
        "total_s": time.perf_counter() - t0,
    }
    return LinkedMesh(cells, tet, tri, offsets, link_tris, plane, origin, dual, solid, stats)


def _roofs(tri: SurfaceTriangles, surfaces: SceneSurfaces) -> list[dict[str, float]]:
    """Roof z of each footprint, read back from its roof triangles (in footprint order)."""
    roofs = tri.vertices[tri.kind == KIND_ROOF][:, 0, 2]
    counts = [len(fp.polygon) - 2 for fp in surfaces.footprints]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int) if counts else []
    return [{"roof_z": float(roofs[s])} for s in starts]


def locate_in_linked_mesh(lm: LinkedMesh, xyz: np.ndarray) -> np.ndarray:
    """Cell id (N,) int64 of each point (N, 3) metres; -1 outside the box or in a solid cell.

    A point in an air cell may still be under the terrain or inside a building within a linked cell:
    callers place sources above the ground (as for the embedded mesh).
    """
    cell = locate_in_terrain_mesh(lm.tet, xyz, terrain_index(lm.tet))
    return np.where((cell >= 0) & ~lm.solid[np.maximum(cell, 0)], cell, -1)

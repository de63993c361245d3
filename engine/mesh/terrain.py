"""Terrain-following conforming tetrahedral media mesh: terrain, buildings and barriers as mesh boundaries.

``build_terrain_mesh`` turns ``SceneSurfaces`` (engine/surfaces.py) into a CellMesh whose ground, walls
and roofs are reflecting boundary faces (BOUNDARY_REFLECT, material index in ``face_material``):

1. 2D point set over the domain's xy box (triangulate2d.py): box sides, footprint vertices and edge
   samples, terrain samples thinned to the horizontal spacing d(x, y) and a graded hexagonal lattice; a
   conforming Delaunay triangulation in which every footprint edge is a union of triangle edges.
2. Ground height at every 2D vertex: bilinear in a HeightGrid, barycentric in a TriangleSurface,
   domain_min z without terrain. Mesh vertices lie on the input surface exactly (up to rounding); ground
   faces are the planar triangles between them (exact for planar terrain).
3. Terrain-following layers (prisms.py): sigma levels graded by the vertical sizing, one level pinned to
   each roof over its footprint's columns. Each triangular prism between two levels is split into 3 tets
   with a consistent diagonal rule; prisms inside a footprint below its roof are removed.
4. Face hash for neighbours, planes from sorted vertex ids, boundary tags: ground (level-0 faces) and
   building faces (between a kept and a removed prism) BOUNDARY_REFLECT with the terrain / building
   material; box sides BOUNDARY_OPEN; the top open or reflecting. Prisms in Morton order.
5. Media exactly as tets.py: vertex values m_v = quantity_at(points), per-cell reference = centroid,
   media_ref = mean of the 4 vertex values, gradient by least squares on the face neighbours (Green-Gauss
   fallback) or each cell's own P1 gradient.

Buildings. A footprint is a vertical prism standing on the terrain: roof height R = base_z + height_m
(base_z default: the lowest terrain height under the polygon, over the input terrain samples inside it
and the 2D mesh vertices on or inside it). The terrain is *not* flattened under a footprint: the mesh
keeps the exact terrain heights at the footprint's vertices and pins the roof as a level of their
columns (prisms.py), so the roof is flat, the walls are vertical (they span from the terrain up to R)
and the ground outside stays exactly on the input surface. The terrain must stay below R under the
footprint (ValueError otherwise). Footprints must be simple, pairwise disjoint and strictly inside the
domain's xy box. Closed obstacle meshes (``SceneSurfaces.obstacles``) are not supported here.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from bentray.engine.constants import BOUNDARY_OPEN, BOUNDARY_REFLECT
from bentray.engine.errors import MeshBuildError
from bentray.engine.mesh.bilinear_kernel import bilinear_heights
from bentray.engine.mesh.fcc import separated_from
from bentray.engine.mesh.gradients import tet_cell_mesh
from bentray.engine.mesh.prisms import (
    check_sigma_levels,
    column_levels,
    face_planes,
    face_vertices,
    match_faces,
    morton_prism_order,
    prism_tets,
    roof_levels,
    sigma_levels,
)
from bentray.engine.mesh.tets import DEGENERATE_VOL_REL, GRADIENT_METHODS, TetMesh
from bentray.engine.mesh.triangulate2d import (
    SEGMENT_SEPARATION,
    SIDE_CLEARANCE,
    TriangleLocator,
    box_side_samples,
    checked_spacing_2d,
    conforming_delaunay,
    footprint_samples,
    greedy_thin,
    hex_fill,
    in_diametral_disks,
    points_in_polygon,
    segments_intersect,
    stride_thin_grid,
)
from bentray.engine.surfaces import Footprint, HeightGrid, SceneSurfaces, TriangleSurface

# A point counts as inside a cell when no face plane is violated by more than LOCATE_TOL_REL * cell size
# (as cells.locate_points): far above plane rounding, far below any cell.
LOCATE_TOL_REL = 1e-9


# ---------------------------------------------------------------------------------------------------
# Terrain
# ---------------------------------------------------------------------------------------------------
class _Terrain(NamedTuple):
    height: Callable[[np.ndarray], np.ndarray]  # xy (N, 2) -> z (N,)
    material: Callable[[np.ndarray], np.ndarray]  # xy (N, 2) -> material index (N,)
    samples: np.ndarray  # (M, 2) input samples inside the box, thinned to the spacing (grid nodes, TIN vertices)
    samples_in: Callable[[np.ndarray], np.ndarray]  # polygon (k, 2) -> every input sample (M, 2) inside it


def _bilinear(grid: HeightGrid, xy: np.ndarray) -> np.ndarray:
    """Ground height (m) of a height grid at points xy (N, 2) m: bilinear in the cell that holds each point (the edge
    cells extrapolate beyond the grid). Compiled (mesh/bilinear_kernel.py): the terrain is sampled one point at a
    time by the diffraction stage's columns, where numpy's per-call overhead made this 55 us a call."""
    pts = np.ascontiguousarray(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
    return bilinear_heights(grid.x, grid.y, grid.z, pts)


def _terrain(surface: HeightGrid | TriangleSurface | None, lo: np.ndarray, hi: np.ndarray,
             spacing_fn: Callable) -> _Terrain:  # fmt: skip
    def inside_polygon(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
        p = p[np.all((p >= poly.min(axis=0)) & (p <= poly.max(axis=0)), axis=1)]
        return p[points_in_polygon(p, poly)]

    if surface is None:
        return _Terrain(lambda xy: np.full(len(xy), lo[2]), lambda xy: np.zeros(len(xy), dtype=np.int64),
                        np.empty((0, 2)), lambda poly: np.empty((0, 2)))  # fmt: skip
    if isinstance(surface, HeightGrid):
        x, y, z = (np.ascontiguousarray(a, dtype=np.float64) for a in (surface.x, surface.y, surface.z))
        if x.ndim != 1 or y.ndim != 1 or len(x) < 2 or len(y) < 2 or z.shape != (len(y), len(x)):
            raise ValueError("HeightGrid needs x (nx >= 2), y (ny >= 2) and z of shape (ny, nx)")
        if np.any(np.diff(x) <= 0) or np.any(np.diff(y) <= 0) or not np.all(np.isfinite(z)):
            raise ValueError("HeightGrid x and y must increase strictly and z be finite")
        if x[0] > lo[0] or x[-1] < hi[0] or y[0] > lo[1] or y[-1] < hi[1]:
            raise ValueError("the HeightGrid must cover the domain's xy box")
        grid = HeightGrid(x, y, z, surface.material, surface.default_material)

        def nodes_in(poly: np.ndarray) -> np.ndarray:
            bx = x[(x >= poly[:, 0].min()) & (x <= poly[:, 0].max())]
            by = y[(y >= poly[:, 1].min()) & (y <= poly[:, 1].max())]
            gx, gy = np.meshgrid(bx, by)
            return inside_polygon(np.column_stack([gx.ravel(), gy.ravel()]), poly)

        mat = None if surface.material is None else np.asarray(surface.material, dtype=np.int64)
        if mat is not None and mat.shape != (len(y) - 1, len(x) - 1):
            raise ValueError("HeightGrid.material must have shape (ny - 1, nx - 1)")

        def material(xy: np.ndarray) -> np.ndarray:
            if mat is None:
                return np.full(len(xy), int(surface.default_material), dtype=np.int64)
            i = np.clip(np.searchsorted(x, xy[:, 0], side="right") - 1, 0, len(x) - 2)
            j = np.clip(np.searchsorted(y, xy[:, 1], side="right") - 1, 0, len(y) - 2)
            return mat[j, i]

        xs, ys = x[(x > lo[0]) & (x < hi[0])], y[(y > lo[1]) & (y < hi[1])]
        nodes = stride_thin_grid(xs, ys, spacing_fn) if len(xs) > 1 and len(ys) > 1 else np.empty((0, 2))
        return _Terrain(lambda xy: _bilinear(grid, xy), material, nodes, nodes_in)
    if isinstance(surface, TriangleSurface):
        v = np.asarray(surface.vertices, dtype=np.float64)
        tri = np.asarray(surface.triangles, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or tri.ndim != 2 or tri.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise ValueError("TriangleSurface needs vertices (V, 3) finite and triangles (T, 3)")
        loc = TriangleLocator(v[:, :2], tri)
        tmat = (np.full(len(tri), int(surface.default_material), dtype=np.int64) if surface.material is None
                else np.asarray(surface.material, dtype=np.int64))  # fmt: skip

        def height(xy: np.ndarray) -> np.ndarray:
            t, w = loc.locate(xy)
            if np.any(t < 0):
                raise ValueError(f"{int((t < 0).sum())} mesh points are not over the TriangleSurface")
            return np.einsum("ni,ni->n", w, v[tri[t], 2])

        def material(xy: np.ndarray) -> np.ndarray:
            t, _ = loc.locate(xy)
            return tmat[np.maximum(t, 0)]

        cand = v[np.all((v[:, :2] > lo[:2]) & (v[:, :2] < hi[:2]), axis=1), :2]
        cand = cand[greedy_thin(cand, spacing_fn(cand))] if len(cand) else cand
        return _Terrain(height, material, cand, lambda poly: inside_polygon(v[:, :2], poly))
    raise ValueError(f"unsupported terrain type {type(surface).__name__}")


def terrain_height_function(
    surface: HeightGrid | TriangleSurface | None, lo: np.ndarray, hi: np.ndarray
) -> Callable[[np.ndarray], np.ndarray]:
    """Ground height z (metres) at plan points xy (N, 2) as the mesh sees it (bilinear grid, TIN, or
    flat at lo z), clamped to the domain's xy box."""
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    spacing = float(np.max(hi[:2] - lo[:2]))
    height = _terrain(surface, lo, hi, lambda xy: np.full(len(xy), spacing)).height

    def ground(xy: np.ndarray) -> np.ndarray:
        return height(np.clip(np.asarray(xy, dtype=np.float64), lo[:2], hi[:2]))

    return ground


def _check_footprints(footprints: list[Footprint], lo: np.ndarray, hi: np.ndarray) -> list[np.ndarray]:
    """Validate footprints (simple, disjoint, strictly inside the box, positive height); return polygons."""
    polys = []
    for f, fp in enumerate(footprints):
        name = fp.name or f"#{f}"
        p = np.asarray(fp.polygon, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 3 or not np.all(np.isfinite(p)):
            raise ValueError(f"footprint {name}: polygon must be (k >= 3, 2) finite")
        if not (np.isfinite(fp.height_m) and fp.height_m > 0):
            raise ValueError(f"footprint {name}: height_m must be positive")
        if not np.all((p > lo[:2]) & (p < hi[:2])):
            raise ValueError(f"footprint {name}: polygon must lie strictly inside the domain's xy box")
        q = np.roll(p, -1, axis=0)
        if np.any(np.all(p == q, axis=1)):
            raise ValueError(f"footprint {name}: repeated consecutive vertex")
        hit = segments_intersect(p, q, p, q)
        k = len(p)
        idx = np.arange(k)
        hit[idx, idx] = False
        hit[idx, (idx + 1) % k] = False
        hit[(idx + 1) % k, idx] = False
        if hit.any():
            raise ValueError(f"footprint {name}: polygon is not simple (edges cross or touch)")
        for h in fp.holes:  # courtyards: validated upstream (shapely); here only their form and containment
            h = np.asarray(h, dtype=np.float64)
            if h.ndim != 2 or h.shape[1] != 2 or len(h) < 3 or not np.all(np.isfinite(h)):
                raise ValueError(f"footprint {name}: each hole must be (k >= 3, 2) finite")
            if not np.all(points_in_polygon(h, p)):
                raise ValueError(f"footprint {name}: a hole is not inside the polygon")
        polys.append(p)
    boxes = np.array([[p[:, 0].min(), p[:, 1].min(), p[:, 0].max(), p[:, 1].max()] for p in polys]).reshape(-1, 4)
    over = ((boxes[:, None, 0] <= boxes[None, :, 2]) & (boxes[None, :, 0] <= boxes[:, None, 2])
            & (boxes[:, None, 1] <= boxes[None, :, 3]) & (boxes[None, :, 1] <= boxes[:, None, 3]))  # fmt: skip
    for a, b in zip(*np.nonzero(np.triu(over, 1)), strict=True):
        pa, pb = polys[a], polys[b]
        crossing = segments_intersect(pa, np.roll(pa, -1, axis=0), pb, np.roll(pb, -1, axis=0)).any()
        a_in_b = _in_footprint(pa[:1], pb, footprints[b].holes)[0]
        if crossing or a_in_b or _in_footprint(pb[:1], pa, footprints[a].holes)[0]:
            raise ValueError(f"footprints {footprints[a].name or a} and {footprints[b].name or b} overlap")
    return polys


def _in_footprint(p: np.ndarray, poly: np.ndarray, holes: list[np.ndarray]) -> np.ndarray:
    """Mask of points p (N, 2) inside the polygon and outside its holes (even-odd over all rings)."""
    inside = points_in_polygon(p, poly)
    for h in holes:
        inside &= ~points_in_polygon(p, np.asarray(h, dtype=np.float64))
    return inside


# ---------------------------------------------------------------------------------------------------
# Builder
# ---------------------------------------------------------------------------------------------------
class _Plan2D(NamedTuple):
    """The conforming 2D triangulation: xy (n2, 2) metres, tris (m, 3) int64, constraint segments segs
    (S, 2) int64 and their footprint seg_owner (S,), and the triangulation report (recovery rounds, split
    points, smallest angles, n_terrain_samples, n_lattice)."""

    xy: np.ndarray
    tris: np.ndarray
    segs: np.ndarray
    seg_owner: np.ndarray
    report: dict


class _Columns(NamedTuple):
    """Footprint membership, ground and levels of the 2D vertices.

    vertex_fp (n2,), tri_fp (m,) int64: footprint of each vertex / triangle (-1 outside); cen (m, 2)
    triangle centroids, metres; ground (n2,) terrain height, metres; base_z, roof_z (n_footprints,)
    metres; s (L + 1,) sigma levels; roof_k (n_footprints,) level pinned to each roof; points
    (n_layers + 1) n2 x 3, metres, layer-major (point k n2 + v is vertex v at level k).
    """

    vertex_fp: np.ndarray
    tri_fp: np.ndarray
    cen: np.ndarray
    ground: np.ndarray
    base_z: np.ndarray
    roof_z: np.ndarray
    s: np.ndarray
    roof_k: np.ndarray
    points: np.ndarray


class _PrismTables(NamedTuple):
    """keep (m, L) bool: prism kept (False inside a building below its roof); tets (T, 4) int64 (3 per
    prism, Morton order of the prisms); faces (T, 4, 3) sorted vertex ids of face i; nbrs, nbf (T, 4)
    neighbour cell (-1: boundary) and its face index; planes (T, 4, 4); face_planes' quality dict qual."""

    keep: np.ndarray
    tets: np.ndarray
    faces: np.ndarray
    nbrs: np.ndarray
    nbf: np.ndarray
    planes: np.ndarray
    qual: dict


class _TerrainBoundary(NamedTuple):
    """neighbours (T, 4) with boundary tags, face_material (T, 4) and the n_boundary_faces counts."""

    neighbours: np.ndarray
    face_material: np.ndarray
    counts: dict


def _check_terrain_arguments(surfaces: SceneSurfaces, domain_min, domain_max, top: str, gradient_method: str,
                             layer_levels, vertical_spacing) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(lo, hi) (3,) float64 metres; ValueError on an empty box, a bad top / gradient method, not exactly
    one of layer_levels / vertical_spacing, or closed obstacle meshes (not supported here)."""
    lo = np.asarray(domain_min, dtype=np.float64).reshape(3)
    hi = np.asarray(domain_max, dtype=np.float64).reshape(3)
    if not np.all(hi > lo):
        raise ValueError(f"domain_max {hi} must exceed domain_min {lo} on every axis")
    if top not in ("open", "reflect"):
        raise ValueError(f"top must be 'open' or 'reflect', got {top!r}")
    if gradient_method not in GRADIENT_METHODS:
        raise ValueError(f"gradient_method must be one of {GRADIENT_METHODS}, got {gradient_method!r}")
    if (layer_levels is None) == (vertical_spacing is None):
        raise ValueError("give exactly one of layer_levels and vertical_spacing")
    if surfaces.obstacles:
        raise ValueError("closed obstacle meshes are not supported by the terrain-following mesh")
    return lo, hi


def _triangulate(surfaces: SceneSurfaces, polys: list[np.ndarray], terrain: _Terrain, lo: np.ndarray,
                 hi: np.ndarray, spacing_fn: Callable, max_points_2d: int) -> _Plan2D:  # fmt: skip
    """Step 1: box side samples and footprint rings (outer and holes) as constraints, then the terrain
    samples and a hexagonal lattice kept clear of the sides, of the constraints (SEGMENT_SEPARATION d)
    and of each other, and outside the segments' diametral disks; their conforming Delaunay
    triangulation (the box sides and every footprint edge are unions of triangle edges)."""
    ring = box_side_samples(lo[:2], hi[:2], spacing_fn)
    rings = [r for fp, poly in zip(surfaces.footprints, polys, strict=True) for r in [poly, *fp.holes]]
    ring_fp = np.array([f for f, fp in enumerate(surfaces.footprints) for _ in range(1 + len(fp.holes))], np.int64)
    fp_pts, fp_segs, fp_owner = footprint_samples([np.asarray(r, dtype=np.float64) for r in rings], spacing_fn)
    fp_owner = ring_fp[fp_owner] if len(fp_owner) else fp_owner  # ring index -> footprint index
    segs = fp_segs + len(ring)
    constraint = np.concatenate([ring, fp_pts])

    def keep_free(p: np.ndarray, others: list[tuple[np.ndarray, float]]) -> np.ndarray:
        if len(p) == 0:
            return p
        d = spacing_fn(p)
        clear = np.minimum((p - lo[:2]).min(axis=1), (hi[:2] - p).min(axis=1)) >= SIDE_CLEARANCE * d
        p, d = p[clear], d[clear]
        for q, factor in others:
            if len(q) and len(p):
                ok = separated_from(p, factor * d, q, factor * spacing_fn(q))
                p, d = p[ok], d[ok]
        return p[~in_diametral_disks(p, constraint, segs)]

    tsamp = keep_free(terrain.samples, [(fp_pts, SEGMENT_SEPARATION)])
    lattice = keep_free(hex_fill(lo[:2], hi[:2], spacing_fn, ring, max_points_2d),
                        [(fp_pts, SEGMENT_SEPARATION), (tsamp, 1.0)])  # fmt: skip
    pts0 = np.concatenate([constraint, tsamp, lattice])
    required = np.column_stack([np.arange(len(ring)), np.roll(np.arange(len(ring)), -1)])
    xy, tris, segs, seg_owner, tri_report = conforming_delaunay(pts0, segs, fp_owner[fp_segs[:, 0]], required)
    report = {**tri_report, "n_terrain_samples": int(len(tsamp)), "n_lattice": int(len(lattice))}
    return _Plan2D(xy, tris, segs, seg_owner, report)


def _footprint_membership(plan: _Plan2D, polys: list[np.ndarray],
                          footprints: list[Footprint]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Footprint of every 2D vertex (n2,) and triangle (m,) (-1 outside; a triangle by its centroid, a
    vertex by its constraint segments and the triangles inside), and the centroids (m, 2) metres."""
    xy, tris = plan.xy, plan.tris
    vertex_fp = np.full(len(xy), -1, dtype=np.int64)
    vertex_fp[plan.segs.ravel()] = np.repeat(plan.seg_owner, 2)
    tri_fp = np.full(len(tris), -1, dtype=np.int64)
    cen = xy[tris].mean(axis=1)
    for f, poly in enumerate(polys):
        cand = np.flatnonzero(np.all((cen >= poly.min(axis=0)) & (cen <= poly.max(axis=0)), axis=1))
        tri_fp[cand[_in_footprint(cen[cand], poly, footprints[f].holes)]] = f
    inside_tris = np.flatnonzero(tri_fp >= 0)
    vertex_fp[tris[inside_tris].ravel()] = np.repeat(tri_fp[inside_tris], 3)
    return vertex_fp, tri_fp, cen


def _roof_heights(footprints: list[Footprint], polys: list[np.ndarray], terrain: _Terrain, ground: np.ndarray,
                  vertex_fp: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(base_z, roof_z) (n_footprints,) metres: base_z given, or the lowest terrain height under the
    footprint (its 2D vertices and the input samples inside it); roof_z = base_z + height_m. ValueError
    when a roof is not above the terrain under it or not below domain_max z."""
    roof_z = np.empty(len(polys))
    base_z = np.empty(len(polys))
    for f, (fp, poly) in enumerate(zip(footprints, polys, strict=True)):
        g_f = ground[vertex_fp == f]
        if fp.base_z is None:
            s_in = terrain.samples_in(poly)
            s_in = s_in[_in_footprint(s_in, poly, fp.holes)] if fp.holes and len(s_in) else s_in
            base_z[f] = float(np.concatenate([g_f, terrain.height(s_in) if len(s_in) else []]).min())
        else:
            base_z[f] = float(fp.base_z)
        roof_z[f] = base_z[f] + float(fp.height_m)
        if not (roof_z[f] < hi[2]) or not np.all(g_f < roof_z[f]):
            raise ValueError(f"footprint {fp.name or f}: roof z = {roof_z[f]:g} must be above the terrain under "
                             f"it (max {g_f.max():g}) and below domain_max z")  # fmt: skip
    return base_z, roof_z


def _columns(surfaces: SceneSurfaces, polys: list[np.ndarray], terrain: _Terrain, plan: _Plan2D, lo: np.ndarray,
             hi: np.ndarray, layer_levels, vertical_spacing) -> _Columns:  # fmt: skip
    """Steps 2-3: footprint membership, ground heights (ValueError unless in [lo z, hi z)), roofs, sigma
    levels (given, or from the vertical spacing on the tallest column) with one level pinned to each
    roof, and the layer-major 3D points."""
    xy = plan.xy
    vertex_fp, tri_fp, cen = _footprint_membership(plan, polys, list(surfaces.footprints))
    ground = terrain.height(xy)
    if not np.all(np.isfinite(ground)) or ground.min() < lo[2] or ground.max() >= hi[2]:
        raise ValueError("the terrain must lie in [domain_min z, domain_max z) over the domain")
    base_z, roof_z = _roof_heights(list(surfaces.footprints), polys, terrain, ground, vertex_fp, hi)
    if layer_levels is not None:
        s = check_sigma_levels(layer_levels)
    else:
        assert vertical_spacing is not None  # exactly one of the two (checked by the caller)
        s = sigma_levels(float(hi[2] - ground.min()), vertical_spacing)
    roof_k = roof_levels(s, ground, float(hi[2]), vertex_fp, roof_z)
    z = column_levels(ground, s, float(hi[2]), vertex_fp, roof_z, roof_k)
    layered = np.empty((len(s), len(xy), 3))
    layered[:, :, :2] = xy[None]
    layered[:, :, 2] = z
    return _Columns(vertex_fp, tri_fp, cen, ground, base_z, roof_z, s, roof_k, layered.reshape(-1, 3))


def _prism_tables(plan: _Plan2D, col: _Columns, lo: np.ndarray, hi: np.ndarray) -> _PrismTables:
    """Steps 3-4: the kept prisms in Morton order, 3 tets each (consistent diagonals), face hash
    neighbours and shared planes; MeshBuildError on flat tets."""
    xy, tris = plan.xy, plan.tris
    n2, m, n_layers = len(xy), len(tris), len(col.s) - 1
    keep = np.ones((m, n_layers), dtype=bool)
    inside_tris = np.flatnonzero(col.tri_fp >= 0)
    if len(inside_tris):
        keep[inside_tris] = np.arange(n_layers)[None, :] >= col.roof_k[col.tri_fp[inside_tris]][:, None]
    p_tri, p_layer = np.nonzero(keep)
    width = float(np.sqrt(np.prod(hi[:2] - lo[:2]) / max(m, 1)))
    order = morton_prism_order(col.cen[p_tri], p_layer, width)
    p_tri, p_layer = p_tri[order], p_layer[order]
    tri_sorted = np.sort(tris, axis=1)
    ps = xy[tri_sorted]
    ccw = ((ps[:, 1, 0] - ps[:, 0, 0]) * (ps[:, 2, 1] - ps[:, 0, 1])
           - (ps[:, 1, 1] - ps[:, 0, 1]) * (ps[:, 2, 0] - ps[:, 0, 0])) > 0  # fmt: skip
    tets = prism_tets(tri_sorted, ccw, n2, p_tri, p_layer)
    faces = face_vertices(tets)
    nbrs, nbf = match_faces(faces, n2, len(col.points))
    planes, qual = face_planes(col.points, tets, faces, nbrs, nbf)
    vol, longest = qual["volume"], qual["longest_edge"]
    if np.any(6.0 * vol <= DEGENERATE_VOL_REL * longest**3):
        raise MeshBuildError(f"{int((6.0 * vol <= DEGENERATE_VOL_REL * longest**3).sum())} flat tets")
    return _PrismTables(keep, tets, faces, nbrs, nbf, planes, qual)


def _ground_materials(surfaces: SceneSurfaces, terrain: _Terrain, ground_xy: np.ndarray) -> np.ndarray:
    """Material (k,) of ground faces with centroids ground_xy (k, 2) metres: the terrain's material, then
    the ground zones (later zones win)."""
    ground_mat = terrain.material(ground_xy)
    for zone in surfaces.ground_zones:  # later zones win; each face takes the zone under its centroid
        ground_mat[_in_footprint(ground_xy, np.asarray(zone.polygon, np.float64), zone.holes)] = zone.material
    return ground_mat


def _terrain_boundary(surfaces: SceneSurfaces, terrain: _Terrain, plan: _Plan2D, col: _Columns,
                      tab: _PrismTables, lo: np.ndarray, hi: np.ndarray, top: str) -> _TerrainBoundary:  # fmt: skip
    """Step 4, boundary tags: ground (level-0 faces) and building faces (all vertices of one footprint)
    BOUNDARY_REFLECT with the ground / footprint material, box sides BOUNDARY_OPEN, the top as asked;
    MeshBuildError for a boundary face that is none of these."""
    xy, n2, n_layers, vertex_fp = plan.xy, len(plan.xy), len(col.s) - 1, col.vertex_fp
    bc, bf = np.nonzero(tab.nbrs < 0)
    fv = tab.faces[bc, bf]
    lay, v2 = fv // n2, fv % n2
    is_ground = np.all(lay == 0, axis=1)
    is_top = np.all(lay == n_layers, axis=1)
    is_side = np.zeros(len(bc), dtype=bool)
    for ax in (0, 1):
        for val in (lo[ax], hi[ax]):
            is_side |= np.all(xy[v2, ax] == val, axis=1)
    owner = vertex_fp[v2[:, 0]]
    is_bldg = ~(is_ground | is_top | is_side)
    if np.any(is_bldg & ((owner < 0) | np.any(vertex_fp[v2] != owner[:, None], axis=1))):
        raise MeshBuildError("a boundary face is neither ground, top, side nor a building face")
    is_roof = is_bldg & np.all(lay == lay[:, :1], axis=1)
    neighbours = tab.nbrs.copy()
    neighbours[bc, bf] = np.where(is_ground | is_bldg, BOUNDARY_REFLECT,
                                  np.where(is_top & (top == "reflect"), BOUNDARY_REFLECT, BOUNDARY_OPEN))  # fmt: skip
    face_material = np.zeros((len(tab.tets), 4), dtype=np.int64)
    gi = np.flatnonzero(is_ground)
    face_material[bc[gi], bf[gi]] = _ground_materials(surfaces, terrain, xy[v2[gi]].mean(axis=1))
    bi = np.flatnonzero(is_bldg)
    fp_mat = np.array([fp.material for fp in surfaces.footprints], dtype=np.int64)
    face_material[bc[bi], bf[bi]] = fp_mat[owner[bi]] if len(bi) else 0
    counts = {
        "ground": int(is_ground.sum()),
        "walls": int((is_bldg & ~is_roof).sum()),
        "roofs": int(is_roof.sum()),
        "top": int(is_top.sum()),
        "sides": int(is_side.sum()),
        "reflect": int((neighbours == BOUNDARY_REFLECT).sum()),
        "open": int((neighbours == BOUNDARY_OPEN).sum()),
    }
    return _TerrainBoundary(neighbours, face_material, counts)


def _terrain_stats(
    surfaces: SceneSurfaces,
    plan: _Plan2D,
    col: _Columns,
    tab: _PrismTables,
    bnd: _TerrainBoundary,
    gradient_method: str,
    n_fallback: int,
    times: list[float],
) -> dict:
    """The ``stats`` of ``build_terrain_mesh`` (times: perf_counter at start, after the 2D
    triangulation, after the tables, after the gradients)."""
    t0, t1, t2, t3 = times
    used = np.zeros(len(col.points), dtype=bool)
    used[tab.tets.ravel()] = True
    return {
        "n_vertices_2d": int(len(plan.xy)),
        "n_triangles_2d": int(len(plan.tris)),
        "n_layers": int(len(col.s) - 1),
        "n_points": int(len(col.points)),
        "n_unused_points": int((~used).sum()),
        "n_cells": int(len(tab.tets)),
        "n_cells_removed": int(3 * (tab.keep.size - tab.keep.sum())),
        "n_degenerate": 0,
        "sigma_levels": col.s.tolist(),
        "triangulation": plan.report,
        "roofs": [
            {
                "name": fp.name,
                "base_z": float(col.base_z[f]),
                "roof_z": float(col.roof_z[f]),
                "level": int(col.roof_k[f]),
            }
            for f, fp in enumerate(surfaces.footprints)
        ],  # fmt: skip
        **tab.qual["summary"],
        "n_boundary_faces": bnd.counts,
        "gradient_method": gradient_method,
        "n_lsq_fallback": n_fallback,
        "build_time_s": {
            "triangulation_2d": t1 - t0,
            "tables": t2 - t1,
            "gradients": t3 - t2,
            "total": time.perf_counter() - t0,
        },  # fmt: skip
    }


def build_terrain_mesh(
    surfaces: SceneSurfaces,
    domain_min,
    domain_max,
    quantity_at: Callable[[np.ndarray], np.ndarray],
    *,
    horizontal_spacing: Callable[[np.ndarray], np.ndarray] | float,
    layer_levels: np.ndarray | None = None,
    vertical_spacing: Callable[[np.ndarray], np.ndarray] | float | None = None,
    top: str = "open",
    gradient_method: str = "lsq",
    max_points_2d: int = 2_000_000,
) -> TetMesh:
    """Terrain-following conforming tetrahedral CellMesh of the domain above the terrain minus buildings.

    Parameters
    ----------
    surfaces : terrain (HeightGrid, TriangleSurface or None = flat ground at domain_min z), footprints and
        materials. The terrain must cover the domain's xy box and lie in [domain_min z, domain_max z).
    domain_min, domain_max : (3,) metres, world frame, z up. The top of the mesh is z = domain_max z.
    quantity_at : callable, xyz (N, 3) float64 metres -> traced quantity m (N,) (n^2, c or n).
    horizontal_spacing : target triangle edge length d (metres): a constant or a callable xy (N, 2) -> (N,),
        evaluated at ground level (the sizing field of docs/physics.md §6).
    layer_levels : sigma levels (L + 1,), 0 = s_0 < ... < s_L = 1: z_k = g + s_k (H - g) (prisms.py).
    vertical_spacing : alternatively the layer thickness dz (metres), a constant or a callable of the
        height above ground zeta (M,) -> (M,) on the tallest column (lowest ground); levels follow it.
        Exactly one of layer_levels / vertical_spacing must be given.
    top : "open" or "reflect" (tag of the faces on z = domain_max z); sides are always BOUNDARY_OPEN.
    gradient_method : "lsq", "lsq_unweighted" or "green_gauss" (as tets.build_tet_mesh).
    max_points_2d : raise ValueError if the horizontal spacing asks for more 2D points than this.

    Returns
    -------
    TetMesh with K = 4 faces per cell (face i opposite vertex i), tets positively oriented; the 3 tets of
    a prism are consecutive cells. ``points`` (P, 3) are layer-major: point k * n2 + v is 2D vertex v at
    level k (points inside buildings below the roof are unused). ``stats`` holds n_vertices_2d,
    n_triangles_2d, n_layers, n_points, n_unused_points, n_cells, n_cells_removed (inside buildings),
    sigma_levels, triangulation (recovery rounds, split points, smallest 2D angles), roofs (per footprint:
    base_z, roof_z, level), volume_min_m3, volume_total_m3, min_dihedral_deg, aspect, longest_edge_m,
    n_boundary_faces (ground, walls, roofs, top, sides, reflect, open), n_lsq_fallback and build_time_s.

    Raises
    ------
    ValueError on bad arguments; MeshBuildError when the build fails its own checks.
    """
    t0 = time.perf_counter()
    lo, hi = _check_terrain_arguments(surfaces, domain_min, domain_max, top, gradient_method, layer_levels,
                                      vertical_spacing)  # fmt: skip
    spacing_fn = checked_spacing_2d(horizontal_spacing)
    polys = _check_footprints(list(surfaces.footprints), lo, hi)
    terrain = _terrain(surfaces.terrain, lo, hi, spacing_fn)
    plan = _triangulate(surfaces, polys, terrain, lo, hi, spacing_fn, max_points_2d)
    t1 = time.perf_counter()
    col = _columns(surfaces, polys, terrain, plan, lo, hi, layer_levels, vertical_spacing)
    tab = _prism_tables(plan, col, lo, hi)
    bnd = _terrain_boundary(surfaces, terrain, plan, col, tab, lo, hi, top)
    t2 = time.perf_counter()
    cells, vertex_values, n_fallback = tet_cell_mesh(col.points, tab.tets, tab.planes, bnd.neighbours, tab.nbf,
                                                     tab.qual["longest_edge"], bnd.face_material, quantity_at,
                                                     gradient_method)  # fmt: skip
    t3 = time.perf_counter()
    stats = _terrain_stats(surfaces, plan, col, tab, bnd, gradient_method, n_fallback, [t0, t1, t2, t3])
    return TetMesh(cells=cells, points=col.points, tets=tab.tets, stats=stats, vertex_values=vertex_values)


# ---------------------------------------------------------------------------------------------------
# Location
# ---------------------------------------------------------------------------------------------------
class TerrainIndex(NamedTuple):
    """Point-location tables of a terrain mesh (``terrain_index``).

    locator : TriangleLocator over the 2D triangulation; triangles : (m, 3) int64 2D vertex ids;
    levels : (L + 1, n2) float64 column heights, metres; prism_cells : (m, L, 3) int64 cell ids of the
    prism over triangle t between levels k and k + 1 (-1 where removed inside a building).
    """

    locator: TriangleLocator
    triangles: np.ndarray
    levels: np.ndarray
    prism_cells: np.ndarray


def terrain_index(tet_mesh: TetMesh) -> TerrainIndex:
    """Rebuild the column structure of a ``build_terrain_mesh`` result from its tets (vectorised)."""
    n2 = int(tet_mesh.stats["n_vertices_2d"])
    n_layers = int(tet_mesh.stats["n_layers"])
    first = tet_mesh.tets[::3]  # the 3 tets of a prism are consecutive cells: one per prism suffices
    srt = np.sort(first % n2, axis=1)  # each tet has exactly one vertical edge: one repeated 2D id
    mid = np.where(srt[:, 1] != srt[:, 0], srt[:, 1], srt[:, 2])
    if float(n2) ** 3 < 2.0**62:
        key = (srt[:, 0] * n2 + mid) * n2 + srt[:, 3]
        ukey, tri_id = np.unique(key, return_inverse=True)
        triangles = np.column_stack([ukey // (n2 * n2), (ukey // n2) % n2, ukey % n2])
    else:
        triangles, tri_id = np.unique(np.column_stack([srt[:, 0], mid, srt[:, 3]]), axis=0, return_inverse=True)
    layer = first.min(axis=1) // n2
    prism_cells = np.full((len(triangles), n_layers, 3), -1, dtype=np.int64)
    base = 3 * np.arange(len(first))
    for k in range(3):
        prism_cells[tri_id.reshape(-1), layer, k] = base + k
    xy = tet_mesh.points[:n2, :2]
    levels = tet_mesh.points[:, 2].reshape(n_layers + 1, n2)
    return TerrainIndex(TriangleLocator(xy, triangles), triangles, levels, prism_cells)


def locate_in_terrain_mesh(tet_mesh: TetMesh, xyz: np.ndarray, index: TerrainIndex | None = None) -> np.ndarray:
    """Cell id (N,) int64 containing each point of ``xyz`` (N, 3) metres, or -1 when outside the domain,
    below the ground or inside a building.

    2D location in the triangulation, then a bisection over the column's levels (the level surface over a
    triangle is the plane through its 3 vertices: barycentric interpolation is exact), then the one of the
    prism's 3 tets with the smallest plane violation (<= LOCATE_TOL_REL * cell size). Pass ``index``
    (``terrain_index``) to reuse the tables across calls.
    """
    idx = terrain_index(tet_mesh) if index is None else index
    xyz = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
    n = len(xyz)
    out = np.full(n, -1, dtype=np.int64)
    tri, bary = idx.locator.locate(xyz[:, :2])
    ok = np.flatnonzero(tri >= 0)
    if len(ok) == 0:
        return out
    tv = idx.triangles[tri[ok]]
    w = bary[ok]
    z = xyz[ok, 2]

    def level(k: np.ndarray) -> np.ndarray:
        return np.einsum("ni,ni->n", w, idx.levels[k[:, None], tv])

    n_layers = idx.levels.shape[0] - 1
    k_lo = np.zeros(len(ok), dtype=np.int64)
    k_hi = np.full(len(ok), n_layers, dtype=np.int64)
    while np.any(k_hi - k_lo > 1):
        k_mid = (k_lo + k_hi) // 2
        up = z >= level(k_mid)
        k_lo = np.where(up, k_mid, k_lo)
        k_hi = np.where(up, k_hi, k_mid)
    cand = idx.prism_cells[tri[ok], k_lo]  # (n_ok, 3)
    cm = tet_mesh.cells
    c = np.maximum(cand, 0)
    pl = cm.planes[c]  # (n_ok, 3, 4, 4)
    viol = (np.einsum("nckj,nj->nck", pl[..., :3], xyz[ok]) - pl[..., 3]).max(axis=2)
    viol = np.where(cand >= 0, viol, np.inf)
    best = viol.argmin(axis=1)
    rows = np.arange(len(ok))
    good = viol[rows, best] <= LOCATE_TOL_REL * np.maximum(1.0, cm.size[c[rows, best]])
    out[ok[good]] = cand[rows, best][good]
    return out

"""Checks of triangle meshes read from files: terrain height fields and closed obstacles.

Every function returns a reason string (None = fine) rather than raising, so the caller can name the
file or the job field. Vertices (V, 3) float64 metres, faces (F, 3) int64, world frame, z up.

What is checked (and what is not):
- basic: finite coordinates, indices in range, no repeated index in a face, no zero-area triangle;
- height field (terrain): no two vertices over the same (x, y); no vertical triangle (zero plan area);
  no edge shared by more than two triangles; no fold over a shared edge; in plan view no proper crossing
  of two edges and no vertex, edge midpoint or centroid strictly inside another triangle (bucketed on a
  uniform grid, near-linear). Together these find every overlap of two triangles except contrived
  touching configurations in which all of those probe points lie exactly on the other's boundary.
- closed obstacle: every edge in exactly two faces (watertight and edge-manifold), each edge traversed
  once in each direction (consistent orientation), every connected shell with positive signed volume
  (outward normals), and no two faces that share no vertex intersecting (separating-axis test, 17 axes
  including the coplanar ones, on candidate pairs from a bounding-box grid). Not checked: faces sharing
  exactly one vertex that also cross elsewhere, vertex-manifoldness (two shells touching at a vertex),
  and one closed shell nested inside another.
"""

from __future__ import annotations

import numpy as np

# the closed-surface checks live engine-side (engine.mesh.tetwild uses them): re-exported here
from bentray.engine.mesh.surface_checks import (
    DEGENERATE_AREA_REL,
    basic_mesh_problem,
    closed_mesh_problem,
    triangles_intersect,
)
from bentray.engine.mesh.surface_checks import directed_edges as _edges
from bentray.engine.mesh.surface_checks import format_point as _fmt
from bentray.engine.mesh.surface_checks import mesh_scale as _scale
from bentray.engine.mesh.surface_checks import unique_pairs as _unique_pairs
from bentray.scenes.geometry import GEOMETRY_REL_TOL, box_pairs, locate_points_2d, segments_cross

__all__ = [
    "DEGENERATE_AREA_REL",
    "merge_duplicate_vertices",
    "basic_mesh_problem",
    "height_field_problem",
    "closed_mesh_problem",
    "orient_ccw_from_above",
    "triangles_intersect",
]


def merge_duplicate_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Conversion: merge vertices with bit-identical coordinates (STL stores each triangle's corners
    separately) and drop unreferenced ones; order of first use is kept."""
    used = np.unique(faces.ravel())
    vertices = vertices[used]
    remap = np.full(max(int(faces.max(initial=-1)) + 1, 1), -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    faces = remap[faces]
    _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return vertices[first[order]], rank[inverse.ravel()][faces]


def _plan_area2(tri: np.ndarray) -> np.ndarray:
    """Twice the signed plan-view area of (T, 3, >=2) triangles (> 0: counter-clockwise from above)."""
    e1, e2 = tri[:, 1, :2] - tri[:, 0, :2], tri[:, 2, :2] - tri[:, 0, :2]
    area2: np.ndarray = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    return area2


def orient_ccw_from_above(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Conversion: a copy of faces with every triangle counter-clockwise seen from above (+z)."""
    flip = _plan_area2(vertices[faces]) < 0
    out = faces.copy()
    out[flip] = out[flip][:, ::-1]
    return out


def height_field_problem(vertices: np.ndarray, faces: np.ndarray) -> str | None:
    """Why the mesh is not a terrain height field (at most one surface point above each (x, y)), or None.
    Run :func:`basic_mesh_problem` first; faces in any orientation."""
    scale = _scale(vertices)
    tol = GEOMETRY_REL_TOL * scale
    xy = vertices[:, :2]
    _, first, inverse = np.unique(xy, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    if first.size < xy.shape[0]:
        dup = int(np.argmax(first[inverse] != np.arange(xy.shape[0])))
        other = int(first[inverse[dup]])
        return (
            f"vertices {other} {_fmt(vertices[other])} and {dup} {_fmt(vertices[dup])} lie on one vertical "
            "line: not a height field"
        )
    tri = vertices[faces]
    area2 = _plan_area2(tri)
    edge_len = np.linalg.norm(tri[:, [1, 2, 0], :2] - tri[:, :, :2], axis=2).max(axis=1)
    vertical = np.abs(area2) <= tol * edge_len
    if np.any(vertical):
        i = int(np.argmax(vertical))
        return f"triangle {i} is vertical (zero area seen from above): not a height field"
    faces = orient_ccw_from_above(vertices, faces)
    directed, owner = _edges(faces)
    undirected = np.sort(directed, axis=1)
    keys, idx, counts = _unique_pairs(undirected)
    if np.any(counts > 2):
        e = keys[int(np.argmax(counts > 2))]
        return f"the edge between vertices {e[0]} and {e[1]} is shared by {int(counts.max())} triangles"
    # both triangles counter-clockwise from above: on opposite sides of a shared edge they traverse it in
    # opposite directions; the same direction twice means one folds back over the other
    _, d_idx, d_counts = _unique_pairs(directed)
    folded = d_counts[d_idx] > 1
    if np.any(folded):
        e = int(np.argmax(folded))
        pair = owner[(idx == idx[e])]
        return (
            f"triangles {pair[0]} and {pair[1]} fold over their shared edge near {_fmt(vertices[directed[e, 0]])}: "
            "not a height field"
        )
    tri_xy = vertices[faces][:, :, :2]
    # probe points strictly inside another triangle: vertices, edge midpoints, centroids
    edge_v = keys
    probes = np.concatenate([xy, 0.5 * (xy[edge_v[:, 0]] + xy[edge_v[:, 1]]), tri_xy.mean(axis=1)])
    ip, it, _ = locate_points_2d(probes, tri_xy, strict=True, tol=tol)
    n_v, n_e = xy.shape[0], edge_v.shape[0]
    is_own_centroid = (ip >= n_v + n_e) & (ip - n_v - n_e == it)
    ip, it = ip[~is_own_centroid], it[~is_own_centroid]
    if ip.size:
        p, t = int(ip[0]), int(it[0])
        what = "vertex" if p < n_v else ("an edge midpoint" if p < n_v + n_e else "the centroid of a triangle")
        return (
            f"triangle {t} overlaps another part of the surface seen from above ({what} at {_fmt(probes[p])} "
            "lies inside it): not a height field"
        )
    a, b = xy[edge_v[:, 0]], xy[edge_v[:, 1]]
    ia, ib = box_pairs(np.minimum(a, b), np.maximum(a, b))
    share = np.any(edge_v[ia][:, :, None] == edge_v[ib][:, None, :], axis=(1, 2))
    ia, ib = ia[~share], ib[~share]
    cross = segments_cross(a[ia], b[ia], a[ib], b[ib], tol, touching=False)
    if np.any(cross):
        n = int(np.argmax(cross))
        return (
            f"edges {_fmt(a[ia[n]])}-{_fmt(b[ia[n]])} and {_fmt(a[ib[n]])}-{_fmt(b[ib[n]])} cross seen from above: "
            "not a height field"
        )
    return None

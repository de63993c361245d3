"""Plain-numpy geometry for checking scene meshes: box-overlap candidate pairs, plan-view point location in
triangles, terrain height lookup and segment crossings.

Polygon predicates (validity, overlap, point in polygon) are shapely's: see :mod:`bentray.scenes.gis_geometry`.

No I/O and no exceptions of our own: functions return arrays or a reason string (``None`` = fine); the
readers in :mod:`bentray.scenes.terrain_io` and :mod:`bentray.scenes.scene_models` turn reasons into
errors naming the file or job field. World frame, metres, z up; plan view means the xy projection.
"""

from __future__ import annotations

import numpy as np

from bentray.engine.surfaces import HeightGrid, TriangleSurface

__all__ = [
    "GEOMETRY_REL_TOL",
    "MAX_BOX_COORDINATE",
    "MAX_CANDIDATE_PAIRS",
    "CandidateLimitError",
    "box_pairs",
    "locate_points_2d",
    "terrain_height_at",
    "terrain_xy_bounds",
    "segments_cross",
]

# The bucketed box-overlap search and its constants live in the engine (engine/mesh must not import the
# scene layer); the scene checks use the same function.
from bentray.engine.mesh.boxes import (  # noqa: E402
    GEOMETRY_REL_TOL,
    MAX_BOX_COORDINATE,
    MAX_CANDIDATE_PAIRS,
    CandidateLimitError,
    box_pairs,
)


def _cross2(ax, ay, bx, by):
    return ax * by - ay * bx


def locate_points_2d(
    points_xy: np.ndarray, tri_xy: np.ndarray, *, strict: bool = False, tol: float | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All (point, triangle) pairs with the point inside the triangle in plan view.

    points_xy : (N, 2) float64; tri_xy : (T, 3, 2) float64 (any orientation, non-degenerate).
    strict : True keeps only points at least ``tol`` inside every edge (interior); False keeps points
    within ``tol`` outside too (closed triangles). tol defaults to GEOMETRY_REL_TOL x the scene size.
    Returns (point ids, triangle ids, barycentric weights (P, 3)), pairs sorted by point id.
    """
    if points_xy.shape[0] == 0 or tri_xy.shape[0] == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    if tol is None:
        span = np.ptp(np.concatenate([points_xy, tri_xy.reshape(-1, 2)]), axis=0).max()
        tol = GEOMETRY_REL_TOL * max(float(span), 1.0)
    ip, it = box_pairs(points_xy, points_xy, tri_xy.min(axis=1), tri_xy.max(axis=1))
    p = points_xy[ip]
    t = tri_xy[it]
    area2 = _cross2(t[:, 1, 0] - t[:, 0, 0], t[:, 1, 1] - t[:, 0, 1], t[:, 2, 0] - t[:, 0, 0], t[:, 2, 1] - t[:, 0, 1])
    sign = np.where(area2 < 0, -1.0, 1.0)
    dists = []
    for k in range(3):
        a, b = t[:, k], t[:, (k + 1) % 3]
        edge_len = np.hypot(b[:, 0] - a[:, 0], b[:, 1] - a[:, 1])
        side = sign * _cross2(b[:, 0] - a[:, 0], b[:, 1] - a[:, 1], p[:, 0] - a[:, 0], p[:, 1] - a[:, 1])
        dists.append(side / np.where(edge_len > 0, edge_len, 1.0))  # signed distance inside edge k
    d = np.stack(dists, axis=1)
    inside = np.all(d >= tol, axis=1) if strict else np.all(d >= -tol, axis=1)
    ip, it, d, t = ip[inside], it[inside], d[inside], t[inside]
    # barycentric weights: weight of vertex k is proportional to the distance to the opposite edge
    edge_len = np.stack(
        [np.hypot(*(t[:, (k + 1) % 3] - t[:, k]).T) for k in range(3)], axis=1
    )  # edge k runs from vertex k to k+1; it is opposite vertex k+2
    w = np.stack([d[:, 1] * edge_len[:, 1], d[:, 2] * edge_len[:, 2], d[:, 0] * edge_len[:, 0]], axis=1)
    total = w.sum(axis=1, keepdims=True)
    bary = w / np.where(total != 0, total, 1.0)
    order = np.argsort(ip, kind="stable")
    return ip[order], it[order], bary[order]


def terrain_xy_bounds(terrain: HeightGrid | TriangleSurface) -> tuple[np.ndarray, np.ndarray]:
    """Plan-view bounding box ((2,) min, (2,) max) of a terrain, metres."""
    if isinstance(terrain, HeightGrid):
        return np.array([terrain.x[0], terrain.y[0]]), np.array([terrain.x[-1], terrain.y[-1]])
    v = terrain.vertices[:, :2]
    return v.min(axis=0), v.max(axis=0)


def terrain_height_at(terrain: HeightGrid | TriangleSurface, xy: np.ndarray) -> np.ndarray:
    """Ground height (N,) float64 at plan positions xy (N, 2): bilinear on a HeightGrid, linear inside the
    triangles of a TriangleSurface; NaN where the terrain does not cover the point."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    out = np.full(xy.shape[0], np.nan)
    if isinstance(terrain, HeightGrid):
        from bentray.engine.mesh.bilinear_kernel import bilinear_heights  # numba, only when a grid is sampled

        x, y, z = (np.ascontiguousarray(a, dtype=np.float64) for a in (terrain.x, terrain.y, terrain.z))
        ok = (xy[:, 0] >= x[0]) & (xy[:, 0] <= x[-1]) & (xy[:, 1] >= y[0]) & (xy[:, 1] <= y[-1])
        out[ok] = bilinear_heights(x, y, z, np.ascontiguousarray(xy[ok]))  # the terrain mesh's own lookup
        return out
    tri = terrain.triangles
    ip, it, bary = locate_points_2d(xy, terrain.vertices[tri][:, :, :2])
    first = np.unique(ip, return_index=True)[1]
    ip, it, bary = ip[first], it[first], bary[first]
    out[ip] = np.einsum("pk,pk->p", bary, terrain.vertices[tri[it], 2])
    return out


def segments_cross(
    a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, tol: float, *, touching: bool
) -> np.ndarray:
    """Vectorised segment test for segments a-b and c-d ((N, 2) each).

    touching=False: proper crossings only (each segment strictly straddles the other's line by more than
    tol). touching=True: also contacts within tol (an endpoint on the other segment, collinear overlap).
    """

    def side(p, q, r):  # signed distance of r from line p->q
        length = np.hypot(q[:, 0] - p[:, 0], q[:, 1] - p[:, 1])
        return _cross2(q[:, 0] - p[:, 0], q[:, 1] - p[:, 1], r[:, 0] - p[:, 0], r[:, 1] - p[:, 1]) / np.where(
            length > 0, length, 1.0
        )

    d1, d2, d3, d4 = side(a, b, c), side(a, b, d), side(c, d, a), side(c, d, b)
    proper = (((d1 > tol) & (d2 < -tol)) | ((d1 < -tol) & (d2 > tol))) & (
        ((d3 > tol) & (d4 < -tol)) | ((d3 < -tol) & (d4 > tol))
    )
    if not touching:
        return proper

    def on_segment(p, q, r, dist):  # r within tol of segment p-q
        t_len2 = np.sum((q - p) ** 2, axis=1)
        t = np.sum((r - p) * (q - p), axis=1) / np.where(t_len2 > 0, t_len2, 1.0)
        slack = tol / np.sqrt(np.where(t_len2 > 0, t_len2, 1.0))
        return (np.abs(dist) <= tol) & (t >= -slack) & (t <= 1 + slack)

    return (
        proper | on_segment(a, b, c, d1) | on_segment(a, b, d, d2) | on_segment(c, d, a, d3) | on_segment(c, d, b, d4)
    )

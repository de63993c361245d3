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

# Orientation and containment tests treat anything within GEOMETRY_REL_TOL x (scene size) of a line or
# plane as "on" it: 1e-9 of a 2 km scene is 2 micrometres, far below any survey accuracy and far above
# float64 rounding of coordinates (~1e-13 m at km scale), so touching is never mistaken for crossing.
GEOMETRY_REL_TOL = 1e-9
# Candidate pairs the bucketed overlap search may generate before giving up (about 16 bytes each plus
# temporaries: 20M pairs ~ 1 GB). A well-formed input yields a few pairs per element.
MAX_CANDIDATE_PAIRS = 20_000_000
# Grid cells per axis of the bucketing grid (keys stay inside int64 in 3D).
_MAX_CELLS_PER_AXIS = 1 << 16
# Box coordinates beyond this are refused: differences and squares of coordinates up to 1e150 stay finite
# (a 1e308 coordinate made the extent overflow to inf and the cell-size loop spin on NaN forever).
MAX_BOX_COORDINATE = 1e150


class CandidateLimitError(ValueError):
    """The overlap search would need more than MAX_CANDIDATE_PAIRS candidate pairs."""


def _registrations(lo: np.ndarray, hi: np.ndarray, origin: np.ndarray, h: float, dims: np.ndarray):
    """Cell keys of every grid cell each box touches: (box ids, keys), both int64."""
    i0 = np.clip(np.floor((lo - origin) / h).astype(np.int64), 0, dims - 1)
    i1 = np.clip(np.floor((hi - origin) / h).astype(np.int64), 0, dims - 1)
    span = i1 - i0 + 1
    counts = np.prod(span, axis=1)
    total = int(counts.sum())
    box = np.repeat(np.arange(lo.shape[0], dtype=np.int64), counts)
    local = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    key = np.zeros(total, dtype=np.int64)
    stride = 1
    for axis in range(lo.shape[1]):
        s = span[box, axis]
        key += (i0[box, axis] + local % s) * stride
        local //= s
        stride *= int(dims[axis])
    return box, key


def box_pairs(
    lo_a: np.ndarray, hi_a: np.ndarray, lo_b: np.ndarray | None = None, hi_b: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs of axis-aligned boxes that overlap (closed boxes, padded by GEOMETRY_REL_TOL).

    lo_a, hi_a : (Na, d) float64, d = 2 or 3; lo_b, hi_b : (Nb, d) or None for a self-join.
    Returns (ia, ib) int64 arrays, unique pairs; for a self-join only ia < ib.
    Uniform-grid bucketing (cell size about the median box size): near-linear for well-shaped inputs.
    Raises CandidateLimitError beyond MAX_CANDIDATE_PAIRS and ValueError for a coordinate that is not finite
    or beyond MAX_BOX_COORDINATE in magnitude.
    """
    self_join = lo_b is None or hi_b is None
    if self_join:
        lo_b, hi_b = lo_a, hi_a
    assert lo_b is not None and hi_b is not None
    for arr in (lo_a, hi_a, lo_b, hi_b):
        if arr.size and not (np.all(np.isfinite(arr)) and np.abs(arr).max() <= MAX_BOX_COORDINATE):
            raise ValueError(f"box coordinates must be finite and at most {MAX_BOX_COORDINATE:g} in magnitude")
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if lo_a.shape[0] == 0 or lo_b.shape[0] == 0:
        return empty
    origin = np.minimum(lo_a.min(axis=0), lo_b.min(axis=0))
    top = np.maximum(hi_a.max(axis=0), hi_b.max(axis=0))
    extent = float(np.max(top - origin))
    pad = GEOMETRY_REL_TOL * max(extent, 1.0)
    lo_a, hi_a, lo_b, hi_b = lo_a - pad, hi_a + pad, lo_b - pad, hi_b + pad
    n_boxes = lo_a.shape[0] + lo_b.shape[0]
    h = max(
        float(np.median((hi_a - lo_a).max(axis=1))),
        float(np.median((hi_b - lo_b).max(axis=1))),
        (extent + 2 * pad) / _MAX_CELLS_PER_AXIS,
        1e-300,
    )
    grid_origin = origin - pad
    for _ in range(4096):  # h doubles each round: finite inputs break out long before h overflows
        dims = np.floor((top + pad - grid_origin) / h).astype(np.int64) + 1
        span_a = np.prod(np.floor((hi_a - lo_a) / h) + 2, axis=1).sum()
        span_b = np.prod(np.floor((hi_b - lo_b) / h) + 2, axis=1).sum()
        if span_a + span_b <= 16 * n_boxes + 64:
            break
        h *= 2.0  # a few huge boxes would otherwise register in very many cells
    else:
        raise ValueError("box_pairs: no cell size fits the boxes (non-finite extent)")
    box_a, key_a = _registrations(lo_a, hi_a, grid_origin, h, dims)
    box_b, key_b = _registrations(lo_b, hi_b, grid_origin, h, dims)
    order_b = np.argsort(key_b, kind="stable")
    key_b, box_b = key_b[order_b], box_b[order_b]
    start = np.searchsorted(key_b, key_a, side="left")
    stop = np.searchsorted(key_b, key_a, side="right")
    n_pairs = stop - start
    total = int(n_pairs.sum())
    if total > MAX_CANDIDATE_PAIRS:
        raise CandidateLimitError(f"the overlap search needs {total:,} candidate pairs (limit {MAX_CANDIDATE_PAIRS:,})")
    ia = np.repeat(box_a, n_pairs)
    cell = np.repeat(key_a, n_pairs)
    offset = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(n_pairs) - n_pairs, n_pairs)
    ib = box_b[np.repeat(start, n_pairs) + offset]
    keep = ia < ib if self_join else np.ones(ia.shape, dtype=bool)
    ia, ib, cell = ia[keep], ib[keep], cell[keep]
    overlap = np.all((lo_a[ia] <= hi_b[ib]) & (lo_b[ib] <= hi_a[ia]), axis=1)
    ia, ib, cell = ia[overlap], ib[overlap], cell[overlap]
    # report each pair once: in the cell holding the lower corner of the boxes' intersection
    corner = np.clip(np.floor((np.maximum(lo_a[ia], lo_b[ib]) - grid_origin) / h).astype(np.int64), 0, dims - 1)
    strides = np.concatenate([[1], np.cumprod(dims[:-1])]).astype(np.int64)
    once = corner @ strides == cell
    code = np.sort(ia[once] * np.int64(lo_b.shape[0]) + ib[once])
    return code // lo_b.shape[0], code % lo_b.shape[0]


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
        x, y, z = terrain.x, terrain.y, terrain.z
        ok = (xy[:, 0] >= x[0]) & (xy[:, 0] <= x[-1]) & (xy[:, 1] >= y[0]) & (xy[:, 1] <= y[-1])
        px, py = xy[ok, 0], xy[ok, 1]
        j = np.clip(np.searchsorted(x, px, side="right") - 1, 0, x.size - 2)
        i = np.clip(np.searchsorted(y, py, side="right") - 1, 0, y.size - 2)
        u = (px - x[j]) / (x[j + 1] - x[j])
        v = (py - y[i]) / (y[i + 1] - y[i])
        out[ok] = (
            (1 - u) * (1 - v) * z[i, j]
            + u * (1 - v) * z[i, j + 1]
            + (1 - u) * v * z[i + 1, j]
            + u * v * z[i + 1, j + 1]
        )
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

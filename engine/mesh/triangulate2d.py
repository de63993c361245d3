"""2D point set and conforming Delaunay triangulation for the terrain-following mesh (terrain.py).

The horizontal plane of the domain box is sampled with graded spacing d(x, y) (docs/physics.md §6):

* *constraint points*, never moved or dropped: the 4 box corners, graded samples along the 4 box sides,
  every footprint vertex and graded samples along every footprint edge;
* *terrain points*: the input terrain samples (height-grid nodes or triangle vertices), thinned to d;
* *lattice points*: a graded hexagonal lattice (``fcc.grow_lattice`` in 2D) filling the rest.

Footprint edges must be unions of triangle edges. ``scipy.spatial.Delaunay`` is not constrained, so the
edges are recovered by splitting (a conforming Delaunay triangulation):

1. every free (terrain or lattice) point inside the closed diametral disk of a footprint sub-segment is
   removed. A segment whose closed diametral disk holds no vertex but its two end points has an empty
   circle through its end points, so it is an edge of *every* Delaunay triangulation (Gabriel edge);
2. the triangulation is built and every sub-segment looked up among its edges; each missing one (its disk
   is encroached by a constraint point of another segment, or rounding hit a cocircular tie) is split at
   its midpoint, and the loop repeats until every sub-segment is present (checked, never assumed).

Termination at acute polygon corners uses concentric shells (Ruppert): the first sample on both edges
at a polygon vertex is placed at the same distance r from it, so midpoint splits keep the two sub-segments
next to the vertex at equal lengths r / 2^k; equal-length segments meeting at any angle do not encroach
each other. Parallel close edges (thin barriers) stop splitting once sub-segments are about twice as
short as the gap.

All coordinates are float64 metres, world frame (x, y).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from bentray.engine.errors import MeshBuildError
from bentray.engine.mesh.fcc import HEX_DENSITY, estimate_point_count, grow_lattice, hex_directions

# Free points closer than SEGMENT_SEPARATION * min(d_i, d_j) to a footprint constraint point are dropped
# (the rule tets.BOUNDARY_SEPARATION applies to box-face samples): closer ones would make needle triangles
# with the (unrelated) edge samples; farther gaps stay below ~1.6 d.
SEGMENT_SEPARATION = 0.6
# Free points closer than SIDE_CLEARANCE * d to a box side are dropped (tets.BOUNDARY_CLEARANCE).
SIDE_CLEARANCE = 0.3
# Diametral disks are enlarged by this relative margin when removing free points, so that a point on the
# circle up to rounding counts as encroaching (closed disk): cocircular ties must not decide an edge.
DISK_MARGIN = 1e-9
# Splitting rounds allowed for edge recovery. Each round halves every missing sub-segment; 64 rounds
# would shrink a 1 km segment below 1e-16 m, so hitting the cap means a genuinely bad input.
MAX_RECOVERY_ROUNDS = 64
# A triangle with twice its area <= DEGENERATE_AREA_REL * (longest edge)^2 is flat (rounding-level).
DEGENERATE_AREA_REL = 1e-12
# Barycentric slack for 2D point location (relative): ~1e3 ulps of coordinates at km scale.
BARY_TOL = 1e-10
# Height-grid nodes are thinned by power-of-two strides whose node spacing may exceed d by up to this factor:
# a grid step just under d / 2 (e.g. 20.2 m for d = 40 m) would otherwise keep every node (4x the points).
STRIDE_SLACK = 1.05
# Relative slack of the greedy thinning rule (as fcc.SEPARATION_RTOL).
SEPARATION_RTOL = 1e-6


# ---------------------------------------------------------------------------------------------------
# Sampling helpers
# ---------------------------------------------------------------------------------------------------
def checked_spacing_2d(spacing: Callable[[np.ndarray], np.ndarray] | float) -> Callable[[np.ndarray], np.ndarray]:
    """Wrap a spacing (callable xy (N, 2) -> d (N,) metres, or a constant) into a validated callable."""
    if not callable(spacing):
        value = float(spacing)
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"horizontal_spacing must be finite and positive, got {spacing!r}")
        return lambda xy: np.full(len(xy), value)

    def fn(xy: np.ndarray) -> np.ndarray:
        d = np.asarray(spacing(np.ascontiguousarray(xy[:, :2], dtype=np.float64)), dtype=np.float64).reshape(-1)
        if d.shape[0] != len(xy) or not np.all(np.isfinite(d) & (d > 0)):
            raise ValueError("horizontal_spacing must return one finite positive value per point")
        return d

    return fn


def graded_interior(a: np.ndarray, b: np.ndarray, spacing_fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Points strictly inside segment a-b (2D) with gaps following d: equal steps of N(t) = int ds / d."""
    length = float(np.hypot(*(b - a)))
    t = np.linspace(0.0, length, 257)
    d = spacing_fn(a + t[:, None] / length * (b - a))
    need = int(min(200_001, 8 * length / d.min()))
    if need > len(t):
        t = np.linspace(0.0, length, need)
        d = spacing_fn(a + t[:, None] / length * (b - a))
    inv = 1.0 / d
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(t))])
    n = max(1, int(round(cum[-1])))
    s = np.interp(np.arange(1, n) * cum[-1] / n, cum, t)
    return a + s[:, None] / length * (b - a)


def box_side_samples(lo: np.ndarray, hi: np.ndarray, spacing_fn: Callable) -> np.ndarray:
    """The box boundary as a counter-clockwise ring (B, 2): each corner followed by graded samples along
    its side, every sample exactly on its side; consecutive ring points are the side sub-segments."""
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    out = []
    for i in range(4):
        s = graded_interior(corners[i], corners[(i + 1) % 4], spacing_fn)
        axis = 1 if i % 2 == 0 else 0  # sides 0 and 2 are y = const, sides 1 and 3 are x = const
        s[:, axis] = corners[i, axis]  # exactly on the side (interpolation may round)
        out += [corners[i : i + 1], s]
    return np.concatenate(out)


def footprint_samples(polygons: list[np.ndarray], spacing_fn: Callable) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constraint points and sub-segments of the footprint edges.

    The first sample on both edges at a polygon vertex is at the same distance r = min(d(v), L/3 of both
    incident edges) from it (concentric shells, see the module docstring); between those, graded samples.

    Returns points (P, 2), segments (S, 2) int64 indices into points (consecutive along each edge) and the
    footprint index of each point (P,) int64.
    """
    pts: list[np.ndarray] = []
    segs: list[np.ndarray] = []
    owner: list[np.ndarray] = []
    base = 0
    for f, poly in enumerate(polygons):
        k = len(poly)
        nxt = np.roll(poly, -1, axis=0)
        length = np.hypot(*(nxt - poly).T)
        r = np.minimum(spacing_fn(poly), np.minimum(length, np.roll(length, 1)) / 3.0)
        chain = []
        for i in range(k):
            a, b = poly[i], nxt[i]
            u = (b - a) / length[i]
            pa, pb = a + r[i] * u, b - r[(i + 1) % k] * u
            chain.append(np.concatenate([a[None], pa[None], graded_interior(pa, pb, spacing_fn), pb[None]]))
        ring = np.concatenate(chain)
        ids = base + np.arange(len(ring))
        pts.append(ring)
        segs.append(np.column_stack([ids, np.roll(ids, -1)]))
        owner.append(np.full(len(ring), f, dtype=np.int64))
        base += len(ring)
    if not pts:
        return np.empty((0, 2)), np.empty((0, 2), dtype=np.int64), np.empty(0, dtype=np.int64)
    return np.concatenate(pts), np.concatenate(segs).astype(np.int64), np.concatenate(owner)


def stride_thin_grid(x: np.ndarray, y: np.ndarray, spacing_fn: Callable) -> np.ndarray:
    """Height-grid nodes (N, 2) thinned to the spacing by power-of-two index strides.

    A node (i, j) is kept when i and j are multiples of s, the largest power of two with
    s * (grid step) <= STRIDE_SLACK * d (s >= 1): strides nest, so a graded spacing gives a quadtree-like
    subgrid whose kept nodes are exact grid nodes (where the grid is coarser than d every node is kept and
    the lattice densifies between them).
    """
    gx, gy = np.meshgrid(x, y)
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    ii_grid, jj_grid = np.meshgrid(np.arange(len(x)), np.arange(len(y)))
    ii, jj = ii_grid.ravel(), jj_grid.ravel()
    dx = np.diff(x)
    dy = np.diff(y)
    step = np.maximum(dx[np.minimum(ii, len(dx) - 1)], dy[np.minimum(jj, len(dy) - 1)])
    ratio = STRIDE_SLACK * spacing_fn(xy) / step
    s = (2 ** np.floor(np.log2(np.maximum(ratio, 1.0)))).astype(np.int64)
    keep = (ii % s == 0) & (jj % s == 0)
    return xy[keep]


def greedy_thin(p: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Mask of the sequential greedy thinning in index order: keep p_i unless an earlier kept p_j lies
    closer than (1 - SEPARATION_RTOL) * min(d_i, d_j). Vectorised in rounds (a point is decided once every
    earlier conflicting point is)."""
    m = len(p)
    if m <= 1:
        return np.ones(m, dtype=bool)
    pairs = cKDTree(p).query_pairs(r=float(d.max()), output_type="ndarray")
    if len(pairs) == 0:
        return np.ones(m, dtype=bool)
    a, b = pairs.min(axis=1), pairs.max(axis=1)
    dist = np.hypot(*(p[a] - p[b]).T)
    close = dist < (1.0 - SEPARATION_RTOL) * np.minimum(d[a], d[b])
    a, b = a[close], b[close]
    state = np.zeros(m, dtype=np.int8)  # 0 undecided, 1 kept, -1 dropped
    while np.any(state == 0):
        und = state == 0
        blocked = np.zeros(m, dtype=bool)
        blocked[b[und[a] & und[b]]] = True
        new = und & ~blocked
        state[new] = 1
        rej = b[new[a]]
        state[rej[state[rej] == 0]] = -1
    return state == 1


def hex_fill(lo: np.ndarray, hi: np.ndarray, spacing_fn: Callable, fixed: np.ndarray, max_points: int) -> np.ndarray:
    """Graded hexagonal lattice over the box grown from its centre, avoiding the ``fixed`` points (2D)."""
    lo3 = np.array([lo[0], lo[1], 0.0])
    hi3 = np.array([hi[0], hi[1], 0.0])

    def fn3(p: np.ndarray) -> np.ndarray:
        return spacing_fn(p[:, :2])

    est = estimate_point_count(lo3, hi3, fn3, HEX_DENSITY)
    if est > max_points:
        raise ValueError(f"the horizontal spacing asks for about {est:,.0f} 2D points (> {max_points:,})")
    fixed3 = np.column_stack([fixed, np.zeros(len(fixed))])
    pts, _ = grow_lattice(lo3, hi3, fn3, hex_directions(2), 0.5 * (lo3 + hi3), fixed_points=fixed3,
                          fixed_spacing=spacing_fn(fixed), max_points=max_points)  # fmt: skip
    return pts[:, :2].copy()


def in_diametral_disks(p: np.ndarray, seg_pts: np.ndarray, segs: np.ndarray) -> np.ndarray:
    """Mask of points p (N, 2) inside (or on, up to DISK_MARGIN) the diametral disk of any segment."""
    if len(segs) == 0 or len(p) == 0:
        return np.zeros(len(p), dtype=bool)
    a, b = seg_pts[segs[:, 0]], seg_pts[segs[:, 1]]
    mid = 0.5 * (a + b)
    rad = 0.5 * np.hypot(*(b - a).T) * (1.0 + DISK_MARGIN)
    hits = cKDTree(p).query_ball_point(mid, rad, return_sorted=False)
    out = np.zeros(len(p), dtype=bool)
    flat = [i for h in hits for i in h]
    out[np.asarray(flat, dtype=np.int64)] = True
    return out


# ---------------------------------------------------------------------------------------------------
# Conforming Delaunay
# ---------------------------------------------------------------------------------------------------
def _edge_keys(tris: np.ndarray, n: int) -> np.ndarray:
    e = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    e.sort(axis=1)
    return np.unique(e[:, 0] * n + e[:, 1])


def conforming_delaunay(
    points: np.ndarray, segments: np.ndarray, seg_owner: np.ndarray, required: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
    """Delaunay triangulation of ``points`` in which every segment is a union of triangle edges.

    points : (P, 2) float64; segments : (S, 2) int64 point ids (split at midpoints where missing; the new
    points are appended); seg_owner : (S,) int64 label carried to the split halves; required : (R, 2)
    int64 edges that must be present as they are (box sides: hull edges, always Delaunay), checked only.

    Returns points (P', 2), triangles (T, 3) int64 counter-clockwise, segments (S', 2), seg_owner (S',) and
    a report {rounds, n_split_points, min_angle_deg}. Raises MeshBuildError when recovery does not converge,
    qhull drops points or a triangle is flat.
    """
    pts = np.asarray(points, dtype=np.float64)
    segs = np.asarray(segments, dtype=np.int64).reshape(-1, 2)
    owner = np.asarray(seg_owner, dtype=np.int64)
    n0 = len(pts)
    rounds = 0
    while True:
        rounds += 1
        if rounds > MAX_RECOVERY_ROUNDS:
            raise MeshBuildError(f"footprint edges not recovered after {MAX_RECOVERY_ROUNDS} splitting rounds")
        tri = Delaunay(pts)
        if len(tri.coplanar):
            raise MeshBuildError(f"qhull left {len(tri.coplanar)} 2D points out of the triangulation")
        tris = tri.simplices.astype(np.int64)
        edges = _edge_keys(tris, len(pts))
        s = np.sort(segs, axis=1)
        missing = ~np.isin(s[:, 0] * len(pts) + s[:, 1], edges)
        if not missing.any():
            break
        mid = 0.5 * (pts[segs[missing, 0]] + pts[segs[missing, 1]])
        new_ids = len(pts) + np.arange(len(mid))
        pts = np.concatenate([pts, mid])
        first = np.column_stack([segs[missing, 0], new_ids])
        second = np.column_stack([new_ids, segs[missing, 1]])
        segs = np.concatenate([segs[~missing], first, second])
        owner = np.concatenate([owner[~missing], owner[missing], owner[missing]])
    req = np.sort(np.asarray(required, dtype=np.int64).reshape(-1, 2), axis=1)
    if len(req) and not np.all(np.isin(req[:, 0] * len(pts) + req[:, 1], edges)):
        raise MeshBuildError("box side segments are missing from the 2D triangulation")
    p = pts[tris]
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area2 = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    cw = area2 < 0
    tris[cw, 1], tris[cw, 2] = tris[cw, 2], tris[cw, 1].copy()
    area2 = np.abs(area2)
    lens = np.stack([np.hypot(*(p[:, (i + 1) % 3] - p[:, i]).T) for i in range(3)], axis=1)
    if np.any(area2 <= DEGENERATE_AREA_REL * lens.max(axis=1) ** 2):
        raise MeshBuildError("the 2D triangulation has flat triangles")
    # smallest angle of each triangle: sin(angle opposite the shortest edge) = 2A / (product of the other two)
    srt = np.sort(lens, axis=1)
    min_angle = np.degrees(np.arcsin(np.clip(area2 / (srt[:, 1] * srt[:, 2]), 0.0, 1.0)))
    report = {"rounds": rounds, "n_split_points": len(pts) - n0, "min_angle_deg": float(min_angle.min()),
              "median_min_angle_deg": float(np.median(min_angle))}  # fmt: skip
    return pts, tris, segs, owner, report


# ---------------------------------------------------------------------------------------------------
# Polygons and point location
# ---------------------------------------------------------------------------------------------------
def points_in_polygon(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Crossing-number test: mask of points p (N, 2) strictly inside the simple polygon (k, 2).

    Points exactly on the boundary may go either way; callers only test points well inside or outside.
    """
    inside = np.zeros(len(p), dtype=bool)
    px, py = p[:, 0], p[:, 1]
    for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        cross = (a[1] > py) != (b[1] > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xint = a[0] + (py - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
        inside ^= cross & (px < xint)
    return inside


def _orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    return np.sign(
        (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
    )


def segments_intersect(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """(n, m) mask: segment i of (a0, a1) touches or crosses segment j of (b0, b1) (closed segments)."""
    A0, A1 = a0[:, None, :], a1[:, None, :]
    B0, B1 = b0[None, :, :], b1[None, :, :]
    o1, o2 = _orient(A0, A1, B0), _orient(A0, A1, B1)
    o3, o4 = _orient(B0, B1, A0), _orient(B0, B1, A1)
    proper = (o1 * o2 <= 0) & (o3 * o4 <= 0)
    # all four collinear: intersect only when the projections overlap
    col = (o1 == 0) & (o2 == 0)
    lo_a, hi_a = np.minimum(A0, A1), np.maximum(A0, A1)
    lo_b, hi_b = np.minimum(B0, B1), np.maximum(B0, B1)
    overlap = np.all((lo_a <= hi_b) & (lo_b <= hi_a), axis=-1)
    return np.where(col, overlap, proper)


class TriangleLocator:
    """2D point location in an arbitrary triangle set (bucket grid over the triangles' bounding boxes).

    xy : (V, 2) float64 metres; triangles : (T, 3) int64. Vectorised numpy: no Python loop over points.
    """

    def __init__(self, xy: np.ndarray, triangles: np.ndarray) -> None:
        self.xy = np.ascontiguousarray(xy, dtype=np.float64)
        self.tris = np.ascontiguousarray(triangles, dtype=np.int64)
        p = self.xy[self.tris]
        tlo, thi = p.min(axis=1), p.max(axis=1)
        self.lo = tlo.min(axis=0)
        ext = np.maximum(thi.max(axis=0) - self.lo, 1e-300)
        n = max(1, len(self.tris))
        cell = float(np.sqrt(ext[0] * ext[1] / n)) or float(ext.max())
        self.shape = np.maximum(1, np.minimum(np.ceil(ext / cell), 4096)).astype(np.int64)
        self.cell = ext / self.shape
        i0 = self._bucket_ij(tlo)
        i1 = self._bucket_ij(thi)
        nx = i1[:, 0] - i0[:, 0] + 1
        ny = i1[:, 1] - i0[:, 1] + 1
        count = nx * ny
        tri = np.repeat(np.arange(len(self.tris)), count)
        local = np.arange(len(tri)) - np.repeat(np.cumsum(count) - count, count)
        bi = i0[tri, 0] + local // ny[tri]
        bj = i0[tri, 1] + local % ny[tri]
        bucket = bi * self.shape[1] + bj
        order = np.argsort(bucket, kind="stable")
        self.cand = tri[order]
        self.start = np.searchsorted(bucket[order], np.arange(self.shape[0] * self.shape[1] + 1))

    def _bucket_ij(self, q: np.ndarray) -> np.ndarray:
        ij = np.floor((q - self.lo) / self.cell).astype(np.int64)
        return np.clip(ij, 0, self.shape - 1)

    def locate(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Triangle containing each point q (N, 2) (-1 if none) and its barycentric weights (N, 3).

        A point on a shared edge gets the candidate with the largest smallest weight.
        """
        q = np.ascontiguousarray(np.asarray(q, dtype=np.float64).reshape(-1, 2))
        n = len(q)
        ij = self._bucket_ij(q)
        b = ij[:, 0] * self.shape[1] + ij[:, 1]
        s0, s1 = self.start[b], self.start[b + 1]
        cnt = s1 - s0
        qi = np.repeat(np.arange(n), cnt)
        ci = self.cand[np.repeat(s0, cnt) + np.arange(len(qi)) - np.repeat(np.cumsum(cnt) - cnt, cnt)]
        p = self.xy[self.tris[ci]]
        e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        r = q[qi] - p[:, 0]
        l1 = (r[:, 0] * e2[:, 1] - r[:, 1] * e2[:, 0]) / det
        l2 = (e1[:, 0] * r[:, 1] - e1[:, 1] * r[:, 0]) / det
        lam = np.column_stack([1.0 - l1 - l2, l1, l2])
        score = lam.min(axis=1)
        order = np.lexsort((-score, qi))
        first = np.ones(len(order), dtype=bool)
        first[1:] = qi[order[1:]] != qi[order[:-1]]
        best = order[first]
        tri = np.full(n, -1, dtype=np.int64)
        bary = np.zeros((n, 3))
        ok = score[best] >= -BARY_TOL
        tri[qi[best[ok]]] = ci[best[ok]]
        bary[qi[best[ok]]] = lam[best[ok]]
        return tri, bary

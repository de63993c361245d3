"""Algorithm 2 of the paper: resample the domain with a face-centred-cubic (FCC) lattice of graded spacing.

A lattice is grown breadth-first from the domain centre. A popped site is kept when it lies in the box
and no kept sample is too close; every kept site pushes its 12 FCC neighbours at its spacing d(x)
(docs/physics.md §6; here the mean of the two end spacings, see ``_children``).
The FIFO queue is processed one BFS level at a time, fully vectorised:

1. the level's candidates (children of the previous level, in parent-then-direction order) are
   box-filtered and de-duplicated (coincident sites reached from several parents, first one wins);
2. they are tested against all kept samples with k-d trees (a logarithmic forest of cKDTrees, so each
   kept point is re-indexed only O(log N) times);
3. conflicts *inside* the level are resolved by the greedy maximal independent set in FIFO order,
   computed in rounds (a candidate is accepted once every earlier conflicting candidate is decided).

Steps 1-3 give what the sequential per-point FIFO queue gives (up to merging sites closer than
DEDUPE_REL * d, which conflict anyway), so the result is deterministic; there is no randomness.

Separation rule: a site x_i is rejected when a kept sample x_j satisfies
``|x_i - x_j| < (1 - SEPARATION_RTOL) * min(d(x_i), d(x_j))``. With constant d this is the paper's
"no kept sample within radius d". With graded d the ``min`` matters: a child pushed at its parent's
spacing d_p into a coarser region (d(child) > d_p) would otherwise always find its parent inside its own
radius, and the lattice could never grow towards coarse regions. Nearest-neighbour distances are thus at
least the smaller of the two local spacings.

Density (measured): constant d gives the exact FCC lattice, sqrt(2) / d^3 points per unit volume. Where d
varies, branches of the lattice grown at slightly different spacings become incommensurate and reject
each other, and the packing degrades towards a random sequential one: about 0.6 of sqrt(2) / d^3 in a
2 km x 2 km x 500 m box with d = 10 m -> 100 m over the height (91k points against 156k), nearly the same
(0.56) for a gentle 5 % per spacing grading. The effective spacing is then ~1.2 d; the sizing tolerance,
not d itself, is what callers should tune.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

# Relative slack of the separation test. Lattice neighbours sit at exactly d from their parent; after
# ~1e3 additions a coordinate carries ~1e-13 relative rounding, so a 1e-6 slack accepts true lattice
# neighbours and still rejects every genuinely closer site.
SEPARATION_RTOL = 1e-6
# Candidates reached from several parents coincide up to rounding (~1e-13 d); quantising positions to
# 1e-6 of the local spacing merges them before the (more expensive) tree tests. Sites closer than this
# would conflict anyway, so merging never changes the result beyond keeping the first one.
DEDUPE_REL = 1e-6
# Neighbours fetched per k-d tree query. Kept samples are separated by >= min(d_i, d_j), so a ball of
# radius d holds about 12 (kissing number) in a smoothly graded lattice; queries that come back full
# are re-checked exactly with query_ball_point.
KNN = 16
# Sample count used to estimate the output size (integral of the lattice density) before growing.
ESTIMATE_SAMPLES = 32_768

# The 12 nearest neighbours of an FCC lattice with nearest-neighbour distance 1, in a fixed order.
FCC_DIRECTIONS = (
    np.array(
        [
            [1, 1, 0], [1, -1, 0], [-1, 1, 0], [-1, -1, 0],
            [1, 0, 1], [1, 0, -1], [-1, 0, 1], [-1, 0, -1],
            [0, 1, 1], [0, 1, -1], [0, -1, 1], [0, -1, -1],
        ],
        dtype=np.float64,
    )
    / np.sqrt(2.0)
)  # fmt: skip

# Lattice density (points per unit volume / area / length) of the FCC, hexagonal and 1D lattices with
# nearest-neighbour distance 1.
FCC_DENSITY = np.sqrt(2.0)
HEX_DENSITY = 2.0 / np.sqrt(3.0)


def hex_directions(axis: int) -> np.ndarray:
    """The 6 unit vectors of a hexagonal lattice in the plane normal to ``axis`` (exact 0 along it)."""
    u, v = [a for a in range(3) if a != axis]
    ang = np.arange(6) * (np.pi / 3.0)
    dirs = np.zeros((6, 3))
    dirs[:, u] = np.cos(ang)
    dirs[:, v] = np.sin(ang)
    return dirs


def clamped_spacing(
    spacing: Callable[[np.ndarray], np.ndarray], d_min: float, d_max: float
) -> Callable[[np.ndarray], np.ndarray]:
    """Wrap ``spacing`` so it returns float64 (N,) values clamped to [d_min, d_max]; NaN raises."""

    def fn(xyz: np.ndarray) -> np.ndarray:
        d = np.asarray(spacing(xyz), dtype=np.float64).reshape(-1)
        if d.shape[0] != xyz.shape[0]:
            raise ValueError(f"spacing returned {d.shape[0]} values for {xyz.shape[0]} points")
        if np.any(np.isnan(d)):
            raise ValueError("spacing returned NaN")
        return np.clip(d, d_min, d_max)

    return fn


def estimate_point_count(lo: np.ndarray, hi: np.ndarray, spacing_fn: Callable, density: float) -> float:
    """Integral of ``density / d^k`` over the box (k = number of axes with non-zero extent).

    Midpoint rule on a grid of ~ESTIMATE_SAMPLES cells, proportioned to the box extents.
    """
    ext = hi - lo
    free = ext > 0
    k = int(free.sum())
    if k == 0:
        return 1.0
    per = (ESTIMATE_SAMPLES / np.prod(ext[free] / ext[free].max())) ** (1.0 / k)
    counts = np.where(free, np.maximum(1, np.round(per * ext / ext.max())), 1).astype(int)
    axes = [lo[a] + (np.arange(counts[a]) + 0.5) * ext[a] / counts[a] if free[a] else np.array([lo[a]])
            for a in range(3)]  # fmt: skip
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    d = spacing_fn(grid)
    return float(density * np.mean(d ** (-k)) * np.prod(ext[free]))


class _Forest:
    """Kept samples as a logarithmic forest of cKDTrees (Bentley-Saxe): sizes shrink geometrically."""

    def __init__(self) -> None:
        self.pts: list[np.ndarray] = []
        self.d: list[np.ndarray] = []
        self.trees: list[cKDTree] = []

    def add(self, pts: np.ndarray, d: np.ndarray) -> None:
        if len(pts) == 0:
            return
        self.pts.append(pts)
        self.d.append(d)
        self.trees.append(None)
        while len(self.pts) >= 2 and len(self.pts[-1]) >= len(self.pts[-2]):
            p, dd = self.pts.pop(), self.d.pop()
            self.trees.pop()
            self.pts[-1] = np.concatenate([self.pts[-1], p])
            self.d[-1] = np.concatenate([self.d[-1], dd])
        self.trees[-1] = cKDTree(self.pts[-1], balanced_tree=False, compact_nodes=False)

    def clear_of(self, c: np.ndarray, dc: np.ndarray) -> np.ndarray:
        """Mask of candidates with no kept sample closer than (1 - rtol) * min(d_c, d_j)."""
        ok = np.ones(len(c), dtype=bool)
        # Cheap pass first: the nearest kept point rejects the many candidates that coincide with (or
        # are pushed back onto) existing samples.
        for k in (1, KNN):
            for tree, dk in zip(self.trees, self.d, strict=True):
                idx = np.flatnonzero(ok)
                if len(idx) == 0:
                    return ok
                viol, full = _conflicts(tree, dk, c[idx], dc[idx], k)
                ok[idx[viol]] = False
                if k == KNN:
                    for i in idx[full & ~viol]:
                        ok[i] = not _ball_conflict(tree, dk, c[i], dc[i])
        return ok


def separated_from(points: np.ndarray, d: np.ndarray, others: np.ndarray, others_d: np.ndarray) -> np.ndarray:
    """Mask of ``points`` with no sample of ``others`` closer than (1 - SEPARATION_RTOL) * min(d_i, d_j).

    points (N, 3), d (N,), others (M, 3), others_d (M,): metres. Vectorised k-d tree test (exact).
    """
    forest = _Forest()
    forest.add(np.asarray(others, dtype=np.float64), np.asarray(others_d, dtype=np.float64))
    if not forest.trees or len(points) == 0:
        return np.ones(len(points), dtype=bool)
    return forest.clear_of(np.asarray(points, dtype=np.float64), np.asarray(d, dtype=np.float64))


def _conflicts(tree: cKDTree, dt: np.ndarray, c: np.ndarray, dc: np.ndarray, k: int):
    """(violates, came_back_full) for candidates c against one tree, using the k nearest."""
    k = min(k, tree.n)
    r = (1.0 - SEPARATION_RTOL) * dc
    dist, idx = tree.query(c, k=k, distance_upper_bound=float(r.max()))
    if k == 1:
        dist, idx = dist[:, None], idx[:, None]
    found = idx < tree.n
    dj = dt[np.where(found, idx, 0)]
    viol = np.any(found & (dist < (1.0 - SEPARATION_RTOL) * np.minimum(dc[:, None], dj)), axis=1)
    full = found[:, -1] & (dist[:, -1] < r) & (k < tree.n)
    return viol, full


def _ball_conflict(tree: cKDTree, dt: np.ndarray, x: np.ndarray, d: float) -> bool:
    j = np.asarray(tree.query_ball_point(x, (1.0 - SEPARATION_RTOL) * d), dtype=np.int64)
    if len(j) == 0:
        return False
    dist = np.linalg.norm(tree.data[j] - x, axis=1)
    return bool(np.any(dist < (1.0 - SEPARATION_RTOL) * np.minimum(d, dt[j])))


def _dedupe_first(c: np.ndarray, q: float, lo: np.ndarray) -> np.ndarray:
    """Indices (ascending) of the first candidate of every group of positions equal after quantising."""
    if len(c) <= 1:
        return np.arange(len(c))
    key = np.floor((c - lo) / q + 0.5).astype(np.int64)
    order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))  # stable: group's first = smallest index
    ks = key[order]
    first = np.ones(len(c), dtype=bool)
    first[1:] = np.any(ks[1:] != ks[:-1], axis=1)
    return np.sort(order[first])


def _greedy_in_batch(c: np.ndarray, dc: np.ndarray) -> np.ndarray:
    """Accept mask equal to processing the candidates one by one in index order (greedy MIS)."""
    m = len(c)
    if m <= 1:
        return np.ones(m, dtype=bool)
    tree = cKDTree(c, balanced_tree=False, compact_nodes=False)
    k = min(KNN + 1, m)  # +1: the candidate itself comes back at distance 0
    r = (1.0 - SEPARATION_RTOL) * dc
    dist, idx = tree.query(c, k=k, distance_upper_bound=float(r.max()))
    found = idx < m
    jj = np.where(found, idx, 0)
    ii = np.broadcast_to(np.arange(m)[:, None], idx.shape)
    conflict = found & (jj != ii) & (dist < (1.0 - SEPARATION_RTOL) * np.minimum(dc[:, None], dc[jj]))
    src, dst = ii[conflict], jj[conflict]
    full = np.flatnonzero(found[:, -1] & (dist[:, -1] < r) & (k < m))
    if len(full):
        extra_s, extra_d = [], []
        for i in full:
            j = np.asarray(tree.query_ball_point(c[i], r[i]), dtype=np.int64)
            j = j[j != i]
            dd = np.linalg.norm(c[j] - c[i], axis=1)
            j = j[dd < (1.0 - SEPARATION_RTOL) * np.minimum(dc[i], dc[j])]
            extra_s.append(np.full(len(j), i))
            extra_d.append(j)
        src = np.concatenate([src, *extra_s])
        dst = np.concatenate([dst, *extra_d])
    # Symmetrise and keep each directed edge once.
    a = np.concatenate([src, dst])
    b = np.concatenate([dst, src])
    if len(a) == 0:
        return np.ones(m, dtype=bool)
    e = np.unique(a * m + b)
    a, b = e // m, e % m
    state = np.zeros(m, dtype=np.int8)  # 0 undecided, 1 accepted, -1 rejected
    while True:
        und = state == 0
        if not und.any():
            break
        live = und[a] & und[b]
        blocked = np.zeros(m, dtype=bool)
        blocked[a[live & (b < a)]] = True  # an earlier candidate is still undecided
        new = und & ~blocked
        state[new] = 1
        hit = new[a]
        rej = b[hit]
        state[rej[state[rej] == 0]] = -1
    return state == 1


def _children(
    p: np.ndarray,
    dp: np.ndarray,
    directions: np.ndarray,
    spacing_fn: Callable,
    lo: np.ndarray,
    hi: np.ndarray,
) -> np.ndarray:
    """The lattice neighbours of kept sites ``p``: at distance s = (d_p + d(p + e d_p)) / 2 along e.

    Spacing the edge by the mean of its two end spacings (one fixed-point step of s = mean(d_p, d_child))
    makes edge lengths follow d at the edge midpoint, so graded regions get their target density
    sqrt(2) / d^3 instead of lagging one step behind (pushing at d_p alone under-samples a region
    where d shrinks by about (1 + |grad d|)^3). For |grad d| < 1 the child stays at least
    min(d_p, d_child) from its parent, so the separation test never rejects it because of the parent.
    """
    n, k = len(p), len(directions)
    tent = p[:, None, :] + dp[:, None, None] * directions[None, :, :]
    d_tent = spacing_fn(np.clip(tent.reshape(-1, 3), lo, hi)).reshape(n, k)
    s = 0.5 * (dp[:, None] + d_tent)
    return (p[:, None, :] + s[:, :, None] * directions[None, :, :]).reshape(-1, 3)


def grow_lattice(
    lo: np.ndarray,
    hi: np.ndarray,
    spacing_fn: Callable[[np.ndarray], np.ndarray],
    directions: np.ndarray,
    start: np.ndarray,
    *,
    fixed_points: np.ndarray | None = None,
    fixed_spacing: np.ndarray | None = None,
    max_points: int = 2_000_000,
) -> tuple[np.ndarray, np.ndarray]:
    """Grow a lattice with neighbour ``directions`` (unit rows) from ``start`` inside [lo, hi].

    ``spacing_fn`` must already be clamped. ``fixed_points`` (with ``fixed_spacing``) act as samples
    kept beforehand (they are obstacles, not returned). A box axis with lo == hi is a flat box (face
    sampling): directions must then be exactly 0 along that axis. Returns (points (P, 3), d (P,)).
    """
    ext = hi - lo
    tol = 1e-12 * max(float(np.abs(np.concatenate([lo, hi])).max()), float(ext.max()), 1.0)
    forest = _Forest()
    if fixed_points is not None and len(fixed_points):
        forest.add(np.asarray(fixed_points, float), np.asarray(fixed_spacing, float))
    kept_p: list[np.ndarray] = []
    kept_d: list[np.ndarray] = []
    n_kept = 0
    cand = np.asarray(start, dtype=np.float64).reshape(1, 3)
    q = DEDUPE_REL * float(spacing_fn(cand)[0])
    while len(cand):
        inside = np.all((cand >= lo - tol) & (cand <= hi + tol), axis=1)
        cand = np.clip(cand[inside], lo, hi)
        cand = cand[_dedupe_first(cand, q, lo)]
        if len(cand) == 0:
            break
        dc = spacing_fn(cand)
        ok = forest.clear_of(cand, dc)
        cand, dc = cand[ok], dc[ok]
        acc = _greedy_in_batch(cand, dc)
        cand, dc = cand[acc], dc[acc]
        if len(cand) == 0:
            break
        forest.add(cand, dc)
        kept_p.append(cand)
        kept_d.append(dc)
        n_kept += len(cand)
        if n_kept > max_points:
            raise ValueError(
                f"lattice growth exceeded max_points={max_points} (still growing); "
                "use a larger epsilon / d_min or raise max_points"
            )
        q = DEDUPE_REL * float(dc.min())
        cand = _children(cand, dc, directions, spacing_fn, lo, hi)
    if not kept_p:
        return np.empty((0, 3)), np.empty(0)
    return np.concatenate(kept_p), np.concatenate(kept_d)


def fcc_resample(
    domain_min,
    domain_max,
    spacing: Callable[[np.ndarray], np.ndarray],
    *,
    d_min: float,
    d_max: float,
    max_points: int = 2_000_000,
) -> np.ndarray:
    """Algorithm 2: FCC sample points with graded spacing d(x) in the box [domain_min, domain_max].

    Parameters
    ----------
    domain_min, domain_max : (3,) metres, world frame; the box must have positive extent on every axis.
    spacing : callable, xyz (N, 3) float64 metres -> target spacing d(x) (N,) metres; clamped here to
        [d_min, d_max].
    d_min, d_max : metres, 0 < d_min <= d_max.
    max_points : raise ValueError instead of growing more samples than this (checked up front with the
        integral of the FCC density sqrt(2) / d^3, and again while growing).

    Returns
    -------
    points : (P, 3) float64, metres, in BFS order from the domain centre. Kept samples are at least
        ``(1 - SEPARATION_RTOL) * min(d_i, d_j)`` apart; constant d gives an exact FCC lattice of density
        sqrt(2) / d^3. Deterministic.
    """
    lo = np.asarray(domain_min, dtype=np.float64).reshape(3)
    hi = np.asarray(domain_max, dtype=np.float64).reshape(3)
    if not np.all(hi > lo):
        raise ValueError(f"domain_max {hi} must exceed domain_min {lo} on every axis")
    if not (np.isfinite(d_min) and np.isfinite(d_max) and 0 < d_min <= d_max):
        raise ValueError(f"need 0 < d_min <= d_max, got d_min={d_min}, d_max={d_max}")
    fn = clamped_spacing(spacing, float(d_min), float(d_max))
    est = estimate_point_count(lo, hi, fn, FCC_DENSITY)
    if est > max_points:
        raise ValueError(
            f"FCC resampling would produce about {est:,.0f} points (> max_points={max_points:,}); "
            "use a larger epsilon or d_min, or raise max_points"
        )
    pts, _ = grow_lattice(lo, hi, fn, FCC_DIRECTIONS, 0.5 * (lo + hi), max_points=max_points)
    return pts

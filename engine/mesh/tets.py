"""Delaunay tetrahedralisation of a box domain into a CellMesh (paper Sec. 5.1-5.3, docs/physics.md §6).

``build_tet_mesh`` takes interior samples (e.g. from ``fcc.fcc_resample``), adds boundary samples on the
12 box edges (1D graded) and the 6 faces (hexagonal lattice grown on the face, Algorithm 2 in 2D), runs
``scipy.spatial.Delaunay`` and builds the traversal tables:

* face i of a tet is opposite its vertex i; ``neighbours[c, i]`` is the cell across it or a boundary
  tag; ``neighbour_face[c, i]`` is the index of the same face in that neighbour;
* every face plane is computed once from its sorted vertex ids (a < b < c):
  ``n = normalize((p_b - p_a) x (p_c - p_a))``, ``h = n . p_a``, then negated per cell to point
  outward, so the two cells of a shared face hold bit-identical planes of opposite sign;
* cells are reordered along a Morton (Z-order) curve of their centroids for memory locality.

Per-cell media (the traced quantity m): vertex values m_v = quantity(points); reference point = centroid;
media_ref = mean of the 4 vertex values (the P1 value at the centroid); gradient by least squares on
the face neighbours (``gradients.lsq_gradients``) or the cell's own P1 gradient (``green_gauss``).

``size`` (the characteristic cell length that scales geometric tolerances) is the longest edge: it
bounds the cell diameter, so ``ON_FACE_REL * size`` is relative to the largest coordinate difference
inside the cell.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from bentray.engine.constants import BOUNDARY_OPEN, BOUNDARY_REFLECT
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.mesh.fcc import grow_lattice, hex_directions, separated_from
from bentray.engine.mesh.gradients import green_gauss_gradients, lsq_gradients

# Interior points get a seeded random displacement of JITTER_REL * d per coordinate (boundary points
# the same, inside their face plane or along their edge): FCC and hexagonal lattices are full of
# cospherical / cocircular point sets, for which the Delaunay tetrahedralisation is not unique and qhull
# returns flat tets. 1e-3 d lifts the degeneracy by ~1e-3 d, nine orders above rounding, and moves the
# media samples by a negligible fraction of a cell.
JITTER_REL = 1e-3
# Interior points closer than BOUNDARY_CLEARANCE * d to a box face, or closer than
# BOUNDARY_SEPARATION * min(d_i, d_j) to a boundary sample j, are dropped: otherwise they form
# needle/sliver tets with the (unrelated) face lattice.
BOUNDARY_CLEARANCE = 0.3
BOUNDARY_SEPARATION = 0.6
# A tet with |6 V| <= DEGENERATE_VOL_REL * (longest edge)^3 is flat. After jitter the flattest legitimate
# tets are ~JITTER_REL thin; anything below 1e-12 is a qhull degeneracy and the mesh is rejected.
DEGENERATE_VOL_REL = 1e-12
# Barycentric slack for point location: a point within 1e-10 (relative) of a face belongs to either cell;
# far above the ~1e-13 rounding of barycentric coordinates at km-scale coordinates.
BARY_TOL = 1e-10
MAX_WALK_STEPS = 10_000
# qhull options. The 6 box faces carry thousands of exactly coplanar samples; with the default
# facet-merging options ("Qbb Qc Qz Q12") qhull spends minutes merging those coplanar hull facets
# (20 s for 10k face samples, 160 s for 20k). "QJ" joggles the input by ~1e-11 of the box size
# instead (1.2 s for the same input): the jitter above keeps interior tets 1e-3 d away from degeneracy,
# so joggling never flips them; the only casualties are flat slivers of 4 samples of one box face on
# the hull, which are removed. The joggle is qhull's seeded pseudo-random one: deterministic.
QHULL_OPTIONS = "QJ Qbb"

GRADIENT_METHODS = ("lsq", "lsq_unweighted", "green_gauss")

_BOX_EDGES = [(ax, lo_other) for ax in range(3) for lo_other in range(4)]


class TetMesh(NamedTuple):
    """A tetrahedral media mesh and its build report.

    cells : CellMesh with K = 4 faces per cell (face i opposite vertex i of ``tets``).
    points : (P, 3) float64, metres, world frame (boundary samples first, then interior samples).
    tets : (T, 4) int64 vertex ids, positively oriented, in the same (Morton) order as ``cells``.
    stats : dict, see ``build_tet_mesh``.
    vertex_values : (P,) float64, the traced quantity m at ``points`` (for barycentric interpolation).
    """

    cells: CellMesh
    points: np.ndarray
    tets: np.ndarray
    stats: dict
    vertex_values: np.ndarray


# ---------------------------------------------------------------------------------------------------
# Boundary sampling
# ---------------------------------------------------------------------------------------------------
def _edge_samples(a: np.ndarray, b: np.ndarray, spacing_fn: Callable) -> np.ndarray:
    """Points strictly inside segment a-b whose gaps follow d: equal steps of N(t) = int_0^t ds / d."""
    length = float(np.linalg.norm(b - a))
    n_fine = 257
    for _ in range(2):
        t = np.linspace(0.0, length, n_fine)
        d = spacing_fn(a + t[:, None] / length * (b - a))
        need = int(min(200_001, max(257, 8 * length / d.min())))
        if need <= n_fine:
            break
        n_fine = need
    inv = 1.0 / d
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(t))])
    n = max(1, int(round(cum[-1])))
    s = np.interp(np.arange(1, n) * cum[-1] / n, cum, t)
    return a + s[:, None] / length * (b - a)


def _boundary_samples(lo, hi, spacing_fn, rng):
    """Corners, edge and face samples (each exactly on its box planes, jittered within them).

    Returns points (B, 3) and their spacing d (B,).
    """
    corners = np.array([[hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2]]
                        for i in range(8)])  # fmt: skip
    pts = [corners]
    # 12 edges: along axis ax, the other two coordinates at lo/hi.
    edge_pts = []
    for ax in range(3):
        u, v = [k for k in range(3) if k != ax]
        for cu in (lo[u], hi[u]):
            for cv in (lo[v], hi[v]):
                a = np.empty(3)
                a[ax], a[u], a[v] = lo[ax], cu, cv
                b = a.copy()
                b[ax] = hi[ax]
                e = _edge_samples(a, b, spacing_fn)
                if len(e):
                    d = spacing_fn(e)
                    e[:, ax] += rng.uniform(-1, 1, len(e)) * JITTER_REL * d
                    e[:, ax] = np.clip(e[:, ax], lo[ax], hi[ax])
                    edge_pts.append(e)
    edges = np.concatenate(edge_pts) if edge_pts else np.empty((0, 3))
    pts.append(edges)
    fixed = np.concatenate([corners, edges])
    fixed_d = spacing_fn(fixed)
    for ax in range(3):
        u, v = [k for k in range(3) if k != ax]
        for side in (lo[ax], hi[ax]):
            flo, fhi = lo.copy(), hi.copy()
            flo[ax] = fhi[ax] = side
            on_face = fixed[:, ax] == side
            f, d = grow_lattice(flo, fhi, spacing_fn, hex_directions(ax), 0.5 * (flo + fhi),
                                fixed_points=fixed[on_face], fixed_spacing=fixed_d[on_face],
                                max_points=50_000_000)  # fmt: skip
            if len(f) == 0:
                continue
            margin = np.minimum.reduce([f[:, u] - lo[u], hi[u] - f[:, u], f[:, v] - lo[v], hi[v] - f[:, v]])
            keep = margin >= BOUNDARY_CLEARANCE * d
            f, d = f[keep], d[keep]
            for k in (u, v):
                f[:, k] += rng.uniform(-1, 1, len(f)) * JITTER_REL * d
                f[:, k] = np.clip(f[:, k], lo[k], hi[k])
            pts.append(f)
    out = np.concatenate(pts)
    return out, spacing_fn(out)


def _nn_spacing(interior: np.ndarray, default: float) -> Callable[[np.ndarray], np.ndarray]:
    """d(x) = nearest-neighbour distance of the interior sample nearest to x (FCC: equals d)."""
    if len(interior) < 2:
        return lambda x: np.full(len(x), default)
    tree = cKDTree(interior)
    nn = tree.query(interior, k=2)[0][:, 1]

    def fn(x: np.ndarray) -> np.ndarray:
        return nn[tree.query(x, k=1)[1]]

    return fn


def _checked_spacing(spacing: Callable) -> Callable[[np.ndarray], np.ndarray]:
    def fn(x: np.ndarray) -> np.ndarray:
        d = np.asarray(spacing(x), dtype=np.float64).reshape(-1)
        if d.shape[0] != len(x) or not np.all(np.isfinite(d) & (d > 0)):
            raise ValueError("spacing must return finite positive values, one per point")
        return d

    return fn


# ---------------------------------------------------------------------------------------------------
# Tables
# ---------------------------------------------------------------------------------------------------
def _morton_order(xyz: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Permutation sorting points along a 63-bit Morton (Z-order) curve of the box."""
    scale = (2**21 - 1) / np.maximum(hi - lo, 1e-300)
    q = np.clip((xyz - lo) * scale, 0, 2**21 - 1).astype(np.uint64)

    def spread(v: np.ndarray) -> np.ndarray:
        v = v & np.uint64(0x1FFFFF)
        v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
        v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
        v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
        v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
        v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
        return v

    code = spread(q[:, 0]) | (spread(q[:, 1]) << np.uint64(1)) | (spread(q[:, 2]) << np.uint64(2))
    return np.argsort(code, kind="stable")


def _face_planes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T, 4, 4) outward planes; shared faces bit-identical with opposite sign."""
    t = len(tets)
    faces = np.empty((t, 4, 3), dtype=np.int64)
    for i in range(4):
        faces[:, i, :] = np.delete(tets, i, axis=1)
    faces.sort(axis=2)
    pa, pb, pc = (points[faces[:, :, k]] for k in range(3))
    u = pb - pa
    v = pc - pa
    # Explicit component arithmetic (no reductions) so that every face gives the same bits in both cells.
    nx = u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1]
    ny = u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2]
    nz = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    nx, ny, nz = nx / norm, ny / norm, nz / norm
    h = nx * pa[..., 0] + ny * pa[..., 1] + nz * pa[..., 2]
    planes = np.stack([nx, ny, nz, h], axis=-1)
    opp = points[tets]  # (T, 4, 3): vertex i is opposite face i
    side = nx * opp[..., 0] + ny * opp[..., 1] + nz * opp[..., 2] - h
    planes[side > 0] *= -1.0
    return planes


def _circumradius(p: np.ndarray) -> np.ndarray:
    e = p[:, 1:, :] - p[:, :1, :]
    rhs = 0.5 * np.einsum("nij,nij->ni", e, e)
    c = np.linalg.solve(e, rhs[:, :, None])[:, :, 0]
    return np.linalg.norm(c, axis=1)


def _summary(x: np.ndarray, pct=(50,)) -> dict:
    out = {"min": float(x.min()), "max": float(x.max())}
    for p in pct:
        out["median" if p == 50 else f"p{p}"] = float(np.percentile(x, p))
    return out


# ---------------------------------------------------------------------------------------------------
# Builder
# ---------------------------------------------------------------------------------------------------
_EDGE_PAIRS = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])


class _Samples(NamedTuple):
    """The Delaunay input: points (P, 3) metres (boundary samples first, then the kept interior samples),
    the boundary count B, the kept interior count and the number of interior samples dropped."""

    points: np.ndarray
    n_boundary: int
    n_interior: int
    n_dropped: int


class _Tets(NamedTuple):
    """Positively oriented tets in Morton order and their geometry.

    tets : (T, 4) int64 vertex ids; nbrs : (T, 4) int64 cell across face i (-1: hull face); vol6 : (T,)
    |6 V| m^3; edge_len : (T, 6) edge lengths, metres (pairs of _EDGE_PAIRS of the unoriented tet);
    longest : (T,) longest edge, metres; n_face_slivers : zero-volume hull slivers removed.
    """

    tets: np.ndarray
    nbrs: np.ndarray
    vol6: np.ndarray
    edge_len: np.ndarray
    longest: np.ndarray
    n_face_slivers: int


class _BoxFaces(NamedTuple):
    """Boundary faces (nb = their count) and their tags: neighbours (T, 4) int64 with the hull faces
    tagged; on_ground, on_top (nb,) bool masks; tags (nb,) int64 BOUNDARY_REFLECT / BOUNDARY_OPEN."""

    neighbours: np.ndarray
    on_ground: np.ndarray
    on_top: np.ndarray
    tags: np.ndarray


def _check_box_arguments(domain_min, domain_max, ground: str, top: str,
                         gradient_method: str) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(lo, hi) (3,) float64 metres of the box; ValueError on an empty box or an unknown tag / method."""
    lo = np.asarray(domain_min, dtype=np.float64).reshape(3)
    hi = np.asarray(domain_max, dtype=np.float64).reshape(3)
    if not np.all(hi > lo):
        raise ValueError(f"domain_max {hi} must exceed domain_min {lo} on every axis")
    for name, val in (("ground", ground), ("top", top)):
        if val not in ("reflect", "open"):
            raise ValueError(f"{name} must be 'reflect' or 'open', got {val!r}")
    if gradient_method not in GRADIENT_METHODS:
        raise ValueError(f"gradient_method must be one of {GRADIENT_METHODS}, got {gradient_method!r}")
    return lo, hi


def _resample(lo: np.ndarray, hi: np.ndarray, interior: np.ndarray, spacing: Callable | None,
              rng: np.random.Generator) -> _Samples:  # fmt: skip
    """Boundary samples of the box plus the interior samples (N, 3) m that are strictly inside, clear of
    the faces (BOUNDARY_CLEARANCE d) and of the boundary samples (BOUNDARY_SEPARATION d), jittered by
    JITTER_REL d. ``spacing`` d (metres) defaults to the interior nearest-neighbour distance."""
    interior = interior[np.all((interior > lo) & (interior < hi), axis=1)]
    if spacing is not None:
        spacing_fn = _checked_spacing(spacing)
    else:
        spacing_fn = _nn_spacing(interior, default=float((hi - lo).min()))
    bpts, bd = _boundary_samples(lo, hi, spacing_fn, rng)
    n_in0 = len(interior)
    if len(interior):
        di = spacing_fn(interior)
        clearance = np.minimum((interior - lo).min(axis=1), (hi - interior).min(axis=1))
        keep = clearance >= BOUNDARY_CLEARANCE * di
        interior, di = interior[keep], di[keep]
    if len(interior):
        keep = separated_from(interior, BOUNDARY_SEPARATION * di, bpts, BOUNDARY_SEPARATION * bd)
        interior, di = interior[keep], di[keep]
        interior = interior + rng.uniform(-1, 1, interior.shape) * (JITTER_REL * di)[:, None]
    points = np.ascontiguousarray(np.concatenate([bpts, interior]))
    return _Samples(points, len(bpts), len(interior), n_in0 - len(interior))


def _delaunay(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """qhull's tets (T, 4) and neighbours (T, 4) (-1: hull face) of ``points`` (P, 3), minus the
    zero-volume slivers that joggling leaves on the box faces (4 samples of one face; their neighbours'
    faces on that plane become hull faces), and the number of slivers removed."""
    tri = Delaunay(points, qhull_options=QHULL_OPTIONS)
    tets = tri.simplices.astype(np.int64)
    nbrs = tri.neighbors.astype(np.int64)
    on_plane = np.zeros(len(tets), dtype=bool)
    tp = points[tets]
    for ax in range(3):
        for val in (lo[ax], hi[ax]):
            on_plane |= np.all(tp[:, :, ax] == val, axis=1)
    n_face_slivers = int(on_plane.sum())
    if n_face_slivers:
        keep_idx = np.flatnonzero(~on_plane)
        remap = np.full(len(tets), -1, dtype=np.int64)
        remap[keep_idx] = np.arange(len(keep_idx))
        tets, nbrs = tets[keep_idx], nbrs[keep_idx]
        nbrs = np.where(nbrs >= 0, remap[np.maximum(nbrs, 0)], -1)
    return tets, nbrs, n_face_slivers


def _orient_and_order(points: np.ndarray, tets: np.ndarray, nbrs: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                      n_face_slivers: int) -> _Tets:  # fmt: skip
    """Flip negative tets (swap vertices 0 and 1 with their faces), reject flat ones (ValueError) and
    sort the cells along a Morton curve of their centroids (neighbour ids renumbered)."""
    p = points[tets]
    e = p[:, 1:, :] - p[:, :1, :]
    vol6 = np.linalg.det(e)
    neg = vol6 < 0
    tets[neg, 0], tets[neg, 1] = tets[neg, 1], tets[neg, 0].copy()
    nbrs[neg, 0], nbrs[neg, 1] = nbrs[neg, 1], nbrs[neg, 0].copy()
    vol6 = np.abs(vol6)
    edge_len = np.linalg.norm(p[:, _EDGE_PAIRS[:, 0]] - p[:, _EDGE_PAIRS[:, 1]], axis=2)  # (T, 6)
    longest = edge_len.max(axis=1)
    flat = vol6 <= DEGENERATE_VOL_REL * longest**3
    if np.any(flat):
        raise ValueError(
            f"Delaunay returned {int(flat.sum())} flat tets (|6V| <= {DEGENERATE_VOL_REL:g} * edge^3) "
            "despite the jitter; the input points are degenerate (duplicates or exactly cospherical)"
        )
    order = _morton_order(p.mean(axis=1), lo, hi)
    inv = np.empty_like(order)
    inv[order] = np.arange(len(order))
    tets = np.ascontiguousarray(tets[order])
    nbrs = nbrs[order]
    nbrs = np.where(nbrs >= 0, inv[np.maximum(nbrs, 0)], -1)
    return _Tets(tets, nbrs, vol6[order], edge_len[order], longest[order], n_face_slivers)


def _neighbour_faces(nbrs: np.ndarray) -> np.ndarray:
    """neighbour_face (T, 4) int64: the index of face i of cell c in the cell across it (-1 on the hull);
    ValueError if the neighbour table is not symmetric."""
    nbf = np.full(nbrs.shape, -1, dtype=np.int64)
    ci, fi = np.nonzero(nbrs >= 0)
    match = nbrs[nbrs[ci, fi]] == ci[:, None]
    if not np.all(match.sum(axis=1) == 1):
        raise ValueError("Delaunay neighbour table is not symmetric")
    nbf[ci, fi] = match.argmax(axis=1)
    return nbf


def _box_faces(points: np.ndarray, tets: np.ndarray, nbrs: np.ndarray, lo: np.ndarray, hi: np.ndarray,
               ground: str, top: str) -> _BoxFaces:  # fmt: skip
    """Tag the hull faces by the box plane holding all three of their vertices (exact: boundary samples
    are never moved off their planes): ground / top as asked, sides BOUNDARY_OPEN; ValueError if a hull
    face is on no box plane."""
    neighbours = nbrs.copy()
    bc, bf = np.nonzero(nbrs < 0)
    fv = np.stack([tets[bc, (bf + k) % 4] for k in (1, 2, 3)], axis=1)  # the face's 3 vertices
    fp = points[fv]  # (nb, 3, 3)
    on_ground = np.all(fp[:, :, 2] == lo[2], axis=1)
    on_top = np.all(fp[:, :, 2] == hi[2], axis=1)
    on_side = np.zeros(len(bc), dtype=bool)
    for ax in (0, 1):
        on_side |= np.all(fp[:, :, ax] == lo[ax], axis=1) | np.all(fp[:, :, ax] == hi[ax], axis=1)
    if not np.all(on_ground | on_top | on_side):
        raise ValueError(f"{int((~(on_ground | on_top | on_side)).sum())} hull faces are not on the box")
    tag_ground = BOUNDARY_REFLECT if ground == "reflect" else BOUNDARY_OPEN
    tag_top = BOUNDARY_REFLECT if top == "reflect" else BOUNDARY_OPEN
    tags = np.where(on_ground, tag_ground, np.where(on_top, tag_top, BOUNDARY_OPEN))
    neighbours[bc, bf] = tags
    return _BoxFaces(neighbours, on_ground, on_top, tags)


def _box_cells(
    points: np.ndarray,
    tt: _Tets,
    planes: np.ndarray,
    faces: _BoxFaces,
    nbf: np.ndarray,
    quantity: Callable[[np.ndarray], np.ndarray],
    gradient_method: str,
) -> tuple[CellMesh, np.ndarray, int]:
    """The CellMesh of the tets (outward face planes (T, 4, 4)) with the traced quantity m: vertex
    values m_v = quantity(points) (P,), reference point = centroid, media_ref = mean of the 4 vertex
    values, gradient (T, 3) per metre by least squares on the face neighbours (Green-Gauss fallback) or
    Green-Gauss alone. Returns (cells, vertex values, number of least-squares fallbacks); ValueError on
    non-finite values."""
    tets = tt.tets
    t = len(tets)
    vertex_values = np.asarray(quantity(points), dtype=np.float64).reshape(-1)
    if vertex_values.shape != (len(points),) or not np.all(np.isfinite(vertex_values)):
        raise ValueError("quantity must return one finite value per point")
    centroids = points[tets].mean(axis=1)
    media_ref = vertex_values[tets].mean(axis=1)
    gg = green_gauss_gradients(points, tets, vertex_values)
    if gradient_method == "green_gauss":
        grad, fallback = gg, np.ones(t, dtype=bool)
    else:
        grad, fallback = lsq_gradients(centroids, media_ref, faces.neighbours, weighted=gradient_method == "lsq",
                                       fallback=gg)  # fmt: skip
    cells = CellMesh(
        planes=np.ascontiguousarray(planes),
        neighbours=np.ascontiguousarray(faces.neighbours),
        neighbour_face=nbf,
        media_ref=np.ascontiguousarray(media_ref),
        ref_point=np.ascontiguousarray(centroids),
        gradient=np.ascontiguousarray(grad),
        size=np.ascontiguousarray(tt.longest),
        face_material=np.zeros((t, 4), dtype=np.int64),
    )
    return cells, vertex_values, int(fallback.sum()) if gradient_method != "green_gauss" else 0


def _tet_quality(points: np.ndarray, tt: _Tets) -> dict:
    """Counts and quality summaries of the mesh (the stats keys of ``build_tet_mesh`` on geometry)."""
    tets = tt.tets
    used = np.zeros(len(points), dtype=bool)
    used[tets.ravel()] = True
    radius_edge = _circumradius(points[tets]) / tt.edge_len.min(axis=1)
    flat_edges = np.sort(tets[:, _EDGE_PAIRS], axis=2).reshape(-1, 2)
    uniq = np.unique(flat_edges[:, 0] * len(points) + flat_edges[:, 1])
    ulen = np.linalg.norm(points[uniq // len(points)] - points[uniq % len(points)], axis=1)
    return {
        "n_points": int(used.sum()),
        "n_unused_points": int((~used).sum()),
        "n_cells": int(len(tets)),
        "n_degenerate": 0,
        "n_face_slivers_removed": tt.n_face_slivers,
        "edge_length": _summary(ulen),
        "size": _summary(tt.longest),
        "radius_edge": _summary(radius_edge, pct=(50, 99)),
        "volume_total": float(tt.vol6.sum() / 6.0),
    }


def build_tet_mesh(
    domain_min,
    domain_max,
    interior_points: np.ndarray,
    quantity: Callable[[np.ndarray], np.ndarray],
    *,
    spacing: Callable[[np.ndarray], np.ndarray] | None = None,
    ground: str = "reflect",
    top: str = "open",
    gradient_method: str = "lsq",
    seed: int = 0,
) -> TetMesh:
    """Delaunay tetrahedral CellMesh of the box [domain_min, domain_max].

    Parameters
    ----------
    domain_min, domain_max : (3,) metres, world frame; z is up, the ground is z = domain_min[2].
    interior_points : (N, 3) float64, metres: interior samples (e.g. ``fcc_resample``). Points within
        BOUNDARY_CLEARANCE * d of a box face or BOUNDARY_SEPARATION * d of a boundary sample are dropped.
    quantity : callable, xyz (N, 3) -> exact traced quantity m (N,) (n^2, c or n).
    spacing : callable xyz (N, 3) -> d (N,) metres for the boundary samples; default: the
        nearest-neighbour distance of the closest interior sample.
    ground, top : "reflect" or "open": tag of the faces on z = domain_min[2] / z = domain_max[2]
        (BOUNDARY_REFLECT / BOUNDARY_OPEN). The four sides are always BOUNDARY_OPEN.
    gradient_method : "lsq" (inverse-distance weighted least squares, Eq. 11-13, with Green-Gauss
        fallback), "lsq_unweighted" or "green_gauss" (each cell's own P1 gradient).
    seed : seeds the jitter (deterministic output for a given seed).

    Returns
    -------
    TetMesh. ``stats`` holds n_points, n_boundary_points, n_interior_points, n_interior_dropped,
    n_unused_points, n_cells, n_degenerate (always 0: flat tets raise), edge_length and size
    (longest edge) min/median/max in metres, radius_edge (circumradius / shortest edge) min/median/p99/max,
    n_boundary_faces by place and tag, n_lsq_fallback and build_time_s split into
    resample / delaunay / tables / gradients (+ total).

    Raises
    ------
    ValueError on bad arguments or when qhull returns flat tets or a hull that is not the box.
    """
    t0 = time.perf_counter()
    lo, hi = _check_box_arguments(domain_min, domain_max, ground, top, gradient_method)
    interior = np.asarray(interior_points, dtype=np.float64).reshape(-1, 3)
    samples = _resample(lo, hi, interior, spacing, np.random.default_rng(seed))
    points = samples.points
    t1 = time.perf_counter()
    tets, nbrs, n_face_slivers = _delaunay(points, lo, hi)
    t2 = time.perf_counter()
    tt = _orient_and_order(points, tets, nbrs, lo, hi, n_face_slivers)
    planes = _face_planes(points, tt.tets)
    nbf = _neighbour_faces(tt.nbrs)
    faces = _box_faces(points, tt.tets, tt.nbrs, lo, hi, ground, top)
    t3 = time.perf_counter()
    cells, vertex_values, n_fallback = _box_cells(points, tt, planes, faces, nbf, quantity, gradient_method)
    t4 = time.perf_counter()
    quality = _tet_quality(points, tt)
    stats = {
        "n_points": quality.pop("n_points"),
        "n_boundary_points": int(samples.n_boundary),
        "n_interior_points": int(samples.n_interior),
        "n_interior_dropped": int(samples.n_dropped),
        **quality,
        "n_boundary_faces": {
            "ground": int(faces.on_ground.sum()),
            "top": int(faces.on_top.sum()),
            "sides": int((~faces.on_ground & ~faces.on_top).sum()),
            "reflect": int((faces.tags == BOUNDARY_REFLECT).sum()),
            "open": int((faces.tags == BOUNDARY_OPEN).sum()),
        },
        "gradient_method": gradient_method,
        "n_lsq_fallback": n_fallback,
        "build_time_s": {
            "resample": t1 - t0,
            "delaunay": t2 - t1,
            "tables": t3 - t2,
            "gradients": t4 - t3,
            "total": time.perf_counter() - t0,
        },
    }
    return TetMesh(cells=cells, points=points, tets=tt.tets, stats=stats, vertex_values=vertex_values)


# ---------------------------------------------------------------------------------------------------
# Location and approximation error
# ---------------------------------------------------------------------------------------------------
def _barycentric(points: np.ndarray, tets: np.ndarray, cell: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    p = points[tets[cell]]
    e = (p[:, 1:, :] - p[:, :1, :]).transpose(0, 2, 1)  # columns p_i - p_0
    lam = np.linalg.solve(e, (xyz - p[:, 0, :])[:, :, None])[:, :, 0]
    return np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)


def locate_tets(tet_mesh: TetMesh, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cell containing each point (N, 3) and its barycentric coordinates (N, 4), or -1 outside.

    Vectorised visibility walk: start in the cell with the nearest centroid, step across the face with
    the most negative barycentric coordinate (it separates the point from the cell) until all are
    >= -BARY_TOL; reaching a boundary face means the point is outside the (convex) box. Delaunay
    meshes never cycle; points still walking after MAX_WALK_STEPS are reported as outside (-1).
    """
    xyz = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
    n = len(xyz)
    cells = tet_mesh.cells
    cell = cKDTree(cells.ref_point).query(xyz, k=1)[1].astype(np.int64)
    out = np.full(n, -1, dtype=np.int64)
    bary = np.zeros((n, 4))
    active = np.arange(n)
    for _ in range(MAX_WALK_STEPS):
        if len(active) == 0:
            break
        c = cell[active]
        lam = _barycentric(tet_mesh.points, tet_mesh.tets, c, xyz[active])
        k = lam.argmin(axis=1)
        done = lam[np.arange(len(active)), k] >= -BARY_TOL
        out[active[done]] = c[done]
        bary[active[done]] = lam[done]
        nxt = cells.neighbours[c, k]
        go = ~done & (nxt >= 0)
        cell[active[go]] = nxt[go]
        active = active[go]
    return out, bary


def approximation_error(tet_mesh: TetMesh, grid_points: np.ndarray, exact_values: np.ndarray) -> dict:
    """Paper Eq. 14: relative 2-norm error ||m_G - m~_G|| / ||m_G|| on the input grid points.

    Two approximations m~: ``barycentric`` (P1 interpolation of the vertex values) and ``cell_linear``
    (each cell's linear model media_ref + gradient . (x - ref_point), what the tracer uses). Points
    outside the mesh are ignored and counted. Returns rel_error_*, max_abs_error_*, n_inside, n_outside.
    """
    g = np.atleast_2d(np.asarray(grid_points, dtype=np.float64))
    m = np.asarray(exact_values, dtype=np.float64).reshape(-1)
    if len(m) != len(g):
        raise ValueError("grid_points and exact_values must have the same length")
    cell, bary = locate_tets(tet_mesh, g)
    ok = cell >= 0
    c = cell[ok]
    m_in = m[ok]
    m_bary = np.einsum("ni,ni->n", bary[ok], tet_mesh.vertex_values[tet_mesh.tets[c]])
    cm = tet_mesh.cells
    m_lin = cm.media_ref[c] + np.einsum("ni,ni->n", g[ok] - cm.ref_point[c], cm.gradient[c])
    norm = float(np.linalg.norm(m_in))

    def rel(approx: np.ndarray) -> float:
        err = float(np.linalg.norm(m_in - approx))
        return err / norm if norm > 0 else (0.0 if err == 0 else float("inf"))

    return {
        "rel_error_barycentric": rel(m_bary),
        "rel_error_cell_linear": rel(m_lin),
        "max_abs_error_barycentric": float(np.abs(m_in - m_bary).max()) if len(c) else 0.0,
        "max_abs_error_cell_linear": float(np.abs(m_in - m_lin).max()) if len(c) else 0.0,
        "n_inside": int(ok.sum()),
        "n_outside": int((~ok).sum()),
    }

"""Terrain-following layers, the prism-to-tetrahedron split and the face tables (terrain.py).

Layers. Every 2D vertex v carries a column of L + 1 heights z_k(v), k = 0..L, from sigma levels
0 = s_0 < s_1 < ... < s_L = 1:

    z_k(v) = g(v) + s_k (H - g(v))          g the ground height, H the flat top (domain_max z)

so layers follow the terrain near the ground and flatten toward the top (z_0 = g and z_L = H exactly).
In the columns of a footprint's vertices (on its boundary or inside it) one level k_f is pinned to the
roof height R and the others are re-spaced linearly below and above it:

    z_k = g + (s_k / s_kf) (R - g)  for k <= k_f,     z_k = R + (s_k - s_kf) / (1 - s_kf) (H - R)  for k >= k_f

(k_f: the level whose sigma is nearest the footprint's mean (R - g) / (H - g)). Every column stays strictly
increasing whenever g < R < H, so the number of layers does not grow with the number of buildings, the
roof is one flat level over the footprint and the walls (columns over footprint edges) are vertical.

Prisms. The prism over 2D triangle (a, b, c) (sorted vertex ids a < b < c) between levels k and k + 1 is
split into (A, B, C, A'), (B, C, A', B'), (C, A', B', C') (X = level-k point of x, X' = level k + 1). Each
quad side (x, y), x < y, gets the diagonal x'-y (top of the lower id to the bottom of the higher id) from
both prisms that share it, so neighbouring prisms share faces exactly. Each tet contains one vertical
edge, so its volume is exactly h * A2D / 3 (h that edge's length, A2D the triangle's area): positive
whenever the columns increase, whatever the terrain shear.

Points are stored layer by layer: point k * n2 + v is 2D vertex v at level k.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba as nb
import numpy as np

from bentray.engine.constants import NJIT_FLAGS, PARALLEL_FLAGS
from bentray.engine.errors import MeshBuildError

# Fine sample count for integrating 1 / dz(zeta) when turning a vertical spacing rule into levels
# (linear and geometric grids together resolve both uniform and millimetre-graded spacings).
LEVEL_SAMPLES = 4097


# ---------------------------------------------------------------------------------------------------
# Levels
# ---------------------------------------------------------------------------------------------------
def sigma_levels(height: float, vertical_spacing: Callable[[np.ndarray], np.ndarray] | float) -> np.ndarray:
    """Sigma levels s (L + 1,) from a spacing rule dz(zeta) (metres; zeta = height above ground, metres,
    on the column of height ``height``): equal steps of N(zeta) = int dzeta / dz, rounded to an integer."""
    if not callable(vertical_spacing):
        dz = float(vertical_spacing)
        if not (np.isfinite(dz) and dz > 0):
            raise ValueError(f"vertical_spacing must be finite and positive, got {vertical_spacing!r}")
        n = max(1, int(round(height / dz)))
        return np.linspace(0.0, 1.0, n + 1)
    grid = np.unique(np.concatenate([np.linspace(0.0, height, LEVEL_SAMPLES),
                                     np.geomspace(1e-9 * height, height, LEVEL_SAMPLES)]))  # fmt: skip
    d = np.asarray(vertical_spacing(grid), dtype=np.float64).reshape(-1)
    if d.shape != grid.shape or not np.all(np.isfinite(d) & (d > 0)):
        raise ValueError("vertical_spacing must return one finite positive value per height")
    inv = 1.0 / d
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(grid))])
    n = max(1, int(round(cum[-1])))
    zeta = np.interp(np.arange(n + 1) * cum[-1] / n, cum, grid)
    s = zeta / height
    s[0], s[-1] = 0.0, 1.0
    return check_sigma_levels(s)


def check_sigma_levels(levels: np.ndarray) -> np.ndarray:
    """Validate sigma levels: 1D, strictly increasing, from exactly 0 to exactly 1."""
    s = np.asarray(levels, dtype=np.float64).reshape(-1)
    if len(s) < 2 or s[0] != 0.0 or s[-1] != 1.0 or np.any(np.diff(s) <= 0):
        raise ValueError("layer_levels must increase strictly from 0 to 1 (sigma fractions of the column)")
    return s


def roof_levels(s: np.ndarray, ground: np.ndarray, top_z: float, vertex_fp: np.ndarray,
                roof_z: np.ndarray) -> np.ndarray:  # fmt: skip
    """Level index k_f in [1, L - 1] pinned to each footprint's roof (nearest mean sigma of the roof)."""
    n_fp = len(roof_z)
    if n_fp == 0:
        return np.empty(0, dtype=np.int64)
    if len(s) < 3:
        raise ValueError("footprints need at least 2 layers (one below and one above each roof)")
    on = vertex_fp >= 0
    g = ground[on]
    frac = (roof_z[vertex_fp[on]] - g) / (top_z - g)
    mean = np.bincount(vertex_fp[on], weights=frac, minlength=n_fp) / np.bincount(vertex_fp[on], minlength=n_fp)
    inner = s[1:-1]
    return 1 + np.abs(inner[None, :] - mean[:, None]).argmin(axis=1)


def column_levels(ground: np.ndarray, s: np.ndarray, top_z: float, vertex_fp: np.ndarray, roof_z: np.ndarray,
                  roof_k: np.ndarray) -> np.ndarray:  # fmt: skip
    """Heights z_k(v) (L + 1, n2) of every column (module docstring); raises if a column is not increasing."""
    z = ground[None, :] + s[:, None] * (top_z - ground)[None, :]
    on = np.flatnonzero(vertex_fp >= 0)
    if len(on):
        g = ground[on]
        roof = roof_z[vertex_fp[on]]
        k = roof_k[vertex_fp[on]]
        sk = s[k]
        below = g + (s[:, None] / sk) * (roof - g)
        above = roof + ((s[:, None] - sk) / (1.0 - sk)) * (top_z - roof)
        zon = np.where(np.arange(len(s))[:, None] <= k, below, above)
        zon[k, np.arange(len(on))] = roof
        z[:, on] = zon
    z[0] = ground
    z[-1] = top_z
    if not np.all(np.diff(z, axis=0) > 0):
        raise MeshBuildError("a terrain column is not strictly increasing (roof at or below the ground?)")
    return z


# ---------------------------------------------------------------------------------------------------
# Prisms and tets
# ---------------------------------------------------------------------------------------------------
def _spread(v: np.ndarray) -> np.ndarray:
    v = v & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def morton_prism_order(centroid_xy: np.ndarray, layer: np.ndarray, cell_width: float) -> np.ndarray:
    """Permutation of prisms along a 63-bit Morton curve of (x / w, y / w, layer), w a typical triangle width:
    all three axes counted in cells, so neighbouring prisms are near each other in memory."""
    q = np.empty((len(layer), 3))
    q[:, :2] = (centroid_xy - centroid_xy.min(axis=0)) / cell_width
    q[:, 2] = layer
    q = np.clip(np.round(q), 0, 2**21 - 1).astype(np.uint64)
    code = _spread(q[:, 0]) | (_spread(q[:, 1]) << np.uint64(1)) | (_spread(q[:, 2]) << np.uint64(2))
    return np.argsort(code, kind="stable")


def prism_tets(tris_sorted: np.ndarray, ccw: np.ndarray, n2: int, prism_tri: np.ndarray,
               prism_layer: np.ndarray) -> np.ndarray:  # fmt: skip
    """Tets (3 n_prisms, 4) int64 of the listed prisms (the 3 of a prism consecutive; module docstring).

    ccw : (m,) bool, whether the sorted triangle (a, b, c) is counter-clockwise seen from above. All three
    tets have the orientation of (a, b, c) (the vertical edge is upward); where it is clockwise the first two
    vertices are swapped, so every tet is positively oriented.
    """
    a, b, c = (tris_sorted[prism_tri, i] + prism_layer * n2 for i in range(3))
    a1, b1, c1 = a + n2, b + n2, c + n2
    t = np.empty((len(prism_tri), 3, 4), dtype=np.int64)
    t[:, 0] = np.column_stack([a, b, c, a1])
    t[:, 1] = np.column_stack([b, c, a1, b1])
    t[:, 2] = np.column_stack([c, a1, b1, c1])
    cw = ~ccw[prism_tri]
    t[cw, :, 0], t[cw, :, 1] = t[cw, :, 1], t[cw, :, 0].copy()
    return t.reshape(-1, 4)


@nb.njit(**NJIT_FLAGS)
def _sorted_faces(tets, faces):  # pragma: no cover - compiled
    for t in range(tets.shape[0]):
        for f in range(4):
            k = 0
            for j in range(4):
                if j != f:
                    faces[t, f, k] = tets[t, j]
                    k += 1
            a, b, c = faces[t, f, 0], faces[t, f, 1], faces[t, f, 2]
            if a > b:
                a, b = b, a
            if b > c:
                b, c = c, b
            if a > b:
                a, b = b, a
            faces[t, f, 0], faces[t, f, 1], faces[t, f, 2] = a, b, c


def face_vertices(tets: np.ndarray) -> np.ndarray:
    """(T, 4, 3) sorted vertex ids of face i (opposite vertex i) of every tet."""
    faces = np.empty((len(tets), 4, 3), dtype=np.int64)
    _sorted_faces(np.ascontiguousarray(tets, dtype=np.int64), faces)
    return faces


# Buckets of faces sharing their lowest vertex are paired by comparing all pairs up to this size (about 20
# faces in a terrain mesh); larger ones (a vertex with a large fan) by a numpy sort of their faces.
PAIR_SCAN_MAX = 64


@nb.njit(**NJIT_FLAGS)
def _pair_faces(f, n_points, nb_out, nf_out, scan_max, deferred):  # pragma: no cover - compiled
    """Pair the sorted faces f (F, 3) bucketed by their lowest vertex (counting sort); faces of buckets
    larger than scan_max are only marked in ``deferred``. Returns the number of faces that found a second
    partner (0 unless a face is shared by more than two cells)."""
    start = np.zeros(n_points + 1, dtype=np.int64)
    for i in range(f.shape[0]):
        start[f[i, 0] + 1] += 1
    for v in range(n_points):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    face = np.empty(f.shape[0], dtype=np.int64)  # bucketed: face id and its key (b, c) as b n_points + c
    key = np.empty(f.shape[0], dtype=np.int64)
    for i in range(f.shape[0]):
        p = fill[f[i, 0]]
        face[p], key[p] = i, f[i, 1] * n_points + f[i, 2]
        fill[f[i, 0]] += 1
    extra = 0
    for v in range(n_points):
        lo, hi = start[v], start[v + 1]
        if hi - lo > scan_max:
            for p in range(lo, hi):
                deferred[face[p]] = True
            continue
        for p in range(lo, hi):
            for q in range(p + 1, hi):  # the first later copy; a third copy finds q already paired
                if key[q] == key[p]:
                    i, j = face[p], face[q]
                    extra += 1 if nb_out[i] >= 0 or nb_out[j] >= 0 else 0
                    nb_out[i], nf_out[i] = j // 4, j % 4
                    nb_out[j], nf_out[j] = i // 4, i % 4
                    break
    return extra


def _pair_sorted(f: np.ndarray, ids: np.ndarray, nb: np.ndarray, nf: np.ndarray) -> bool:
    """Pair the faces ``ids`` (flat ids into f (F, 3)) among themselves by a lexicographic sort; False
    if a face is shared by more than two cells."""
    s = ids[np.lexsort((f[ids, 2], f[ids, 1], f[ids, 0]))]
    same = np.all(f[s[1:]] == f[s[:-1]], axis=1)
    i = np.flatnonzero(same)
    s1, s2 = s[i], s[i + 1]
    nb[s1], nf[s1] = s2 // 4, s2 % 4
    nb[s2], nf[s2] = s1 // 4, s1 % 4
    return not np.any(same[1:] & same[:-1])


def match_faces(faces: np.ndarray, n2: int, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Face hash: (neighbours, neighbour_face), both (T, 4) int64, -1 where a face has no partner.

    faces : (T, 4, 3) sorted vertex ids (face_vertices), ids < n_points; n2 (the 2D vertex count) is kept
    for the callers. The faces are bucketed by their lowest vertex and paired within a bucket (compiled;
    buckets over PAIR_SCAN_MAX faces by a numpy sort); the pairing is unique, so the tables are those of a
    sort on the whole face. Raises MeshBuildError if a face is shared by more than two cells.
    """
    if n_points >= 2**31:
        raise ValueError("match_faces: face keys b n_points + c need n_points < 2**31")
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    nb = np.full(len(f), -1, dtype=np.int64)
    nf = np.full(len(f), -1, dtype=np.int64)
    deferred = np.zeros(len(f), dtype=bool)
    extra = _pair_faces(f, int(n_points), nb, nf, PAIR_SCAN_MAX, deferred)
    if extra or (deferred.any() and not _pair_sorted(f, np.flatnonzero(deferred), nb, nf)):
        raise MeshBuildError("a face is shared by more than two cells")
    return nb.reshape(-1, 4), nf.reshape(-1, 4)


@nb.njit(**PARALLEL_FLAGS)
def _planes_quality(points, tets, faces, planes, vol, longest, dihedral, aspect):  # pragma: no cover - compiled
    for t in nb.prange(tets.shape[0]):
        amax = -math.inf  # largest face area, m^2
        for f in range(4):
            pa = points[faces[t, f, 0]]
            pb = points[faces[t, f, 1]]
            pc = points[faces[t, f, 2]]
            ux, uy, uz = pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]
            vx, vy, vz = pc[0] - pa[0], pc[1] - pa[1], pc[2] - pa[2]
            nx = uy * vz - uz * vy
            ny = uz * vx - ux * vz
            nz = ux * vy - uy * vx
            norm = math.sqrt(nx * nx + ny * ny + nz * nz)
            nx, ny, nz = nx / norm, ny / norm, nz / norm
            h = nx * pa[0] + ny * pa[1] + nz * pa[2]
            po = points[tets[t, f]]
            sign = -1.0 if nx * po[0] + ny * po[1] + nz * po[2] - h > 0.0 else 1.0
            planes[t, f, 0] = sign * nx
            planes[t, f, 1] = sign * ny
            planes[t, f, 2] = sign * nz
            planes[t, f, 3] = sign * h
            amax = max(amax, 0.5 * norm)
        v0, v1, v2, v3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        e00, e01, e02 = points[v1, 0] - points[v0, 0], points[v1, 1] - points[v0, 1], points[v1, 2] - points[v0, 2]
        e10, e11, e12 = points[v2, 0] - points[v0, 0], points[v2, 1] - points[v0, 1], points[v2, 2] - points[v0, 2]
        e20, e21, e22 = points[v3, 0] - points[v0, 0], points[v3, 1] - points[v0, 1], points[v3, 2] - points[v0, 2]
        vol[t] = (e00 * (e11 * e22 - e12 * e21) - e01 * (e10 * e22 - e12 * e20) + e02 * (e10 * e21 - e11 * e20)) / 6.0
        lmax = 0.0
        cmax = -math.inf  # the smallest dihedral angle is acos of the largest cosine (acos decreases)
        for i in range(4):
            for j in range(i + 1, 4):
                pi = points[tets[t, i]]
                pj = points[tets[t, j]]
                d = math.sqrt((pi[0] - pj[0]) ** 2 + (pi[1] - pj[1]) ** 2 + (pi[2] - pj[2]) ** 2)
                lmax = max(lmax, d)
                c = -(planes[t, i, 0] * planes[t, j, 0] + planes[t, i, 1] * planes[t, j, 1]
                      + planes[t, i, 2] * planes[t, j, 2])  # fmt: skip
                cmax = max(cmax, c)
        longest[t] = lmax
        dihedral[t] = min(180.0, math.degrees(math.acos(min(1.0, max(-1.0, cmax)))))
        aspect[t] = lmax / (3.0 * vol[t] / amax)  # longest edge / shortest altitude


@nb.njit(**NJIT_FLAGS)
def _count_unpaired_planes(planes, neighbours, neighbour_face):  # pragma: no cover - compiled
    bad = 0  # each shared face once, from its lower cell (negation is exact: the test is symmetric)
    for t in range(planes.shape[0]):
        for f in range(4):
            o = neighbours[t, f]
            if o > t:
                g = neighbour_face[t, f]
                for i in range(4):
                    if planes[o, g, i] != -planes[t, f, i]:
                        bad += 1
    return bad


def face_planes(points: np.ndarray, tets: np.ndarray, faces: np.ndarray, neighbours: np.ndarray,
                neighbour_face: np.ndarray) -> tuple[np.ndarray, dict]:  # fmt: skip
    """Outward planes (T, 4, 4) and a quality report.

    Every face plane is computed from its sorted vertex ids (n = normalize((p_b - p_a) x (p_c - p_a)),
    h = n . p_a; the same operations in both cells of a shared face, so the same bits), then negated per
    cell where the opposite vertex lies on its positive side: shared faces hold bit-identical planes of
    opposite sign (checked). The report holds volume (T,) (exact determinant / 6, m^3), longest_edge (T,)
    metres and a JSON-able ``summary``: volume min and total, smallest dihedral angle (degrees) min / p1 /
    median, aspect (longest edge / shortest altitude) median / p99 / max, longest edge min / median / max.
    """
    t = len(tets)
    planes = np.empty((t, 4, 4))
    vol = np.empty(t)
    longest = np.empty(t)
    dihedral = np.empty(t)
    aspect = np.empty(t)
    _planes_quality(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(tets, dtype=np.int64),
                    faces, planes, vol, longest, dihedral, aspect)  # fmt: skip
    if _count_unpaired_planes(planes, neighbours, neighbour_face):
        raise MeshBuildError("a shared face does not hold opposite planes in its two cells (flat tet?)")
    summary = {
        "volume_min_m3": float(vol.min()),
        "volume_total_m3": float(vol.sum()),
        "min_dihedral_deg": {
            "min": float(dihedral.min()),
            "p1": float(np.percentile(dihedral, 1)),
            "median": float(np.median(dihedral)),
        },  # fmt: skip
        "aspect": {
            "median": float(np.median(aspect)),
            "p99": float(np.percentile(aspect, 99)),
            "max": float(aspect.max()),
        },  # fmt: skip
        "longest_edge_m": {
            "min": float(longest.min()),
            "median": float(np.median(longest)),
            "max": float(longest.max()),
        },  # fmt: skip
    }
    return planes, {"volume": vol, "longest_edge": longest, "summary": summary}

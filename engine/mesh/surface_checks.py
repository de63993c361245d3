"""Checks of closed triangle surfaces (obstacle meshes) before they are tetrahedralised.

Every function returns a reason string (None = fine) rather than raising, so the caller can name the
file or the job field. Vertices (V, 3) float64 metres, faces (F, 3) int64, world frame, z up.

Checked: finite coordinates, indices in range, no repeated index in a face, no zero-area triangle
(:func:`basic_mesh_problem`); every edge in exactly two faces (watertight and edge-manifold), each edge
traversed once in each direction (consistent orientation), every connected shell with positive signed
volume (outward normals), and no two faces that share no vertex intersecting (separating-axis test, 17
axes including the coplanar ones, on candidate pairs from a bounding-box grid) (:func:`closed_mesh_problem`).
Not checked: faces sharing exactly one vertex that also cross elsewhere, vertex-manifoldness (two shells
touching at a vertex), and one closed shell nested inside another. The terrain height-field checks live
with the scene readers (``scenes.mesh_checks``), which re-export these.
"""

from __future__ import annotations

import numpy as np

from bentray.engine.mesh.boxes import GEOMETRY_REL_TOL, CandidateLimitError, box_pairs

__all__ = [
    "DEGENERATE_AREA_REL",
    "basic_mesh_problem",
    "closed_mesh_problem",
    "directed_edges",
    "format_point",
    "mesh_scale",
    "triangles_intersect",
    "unique_pairs",
]

# A triangle whose area is below DEGENERATE_AREA_REL x (bounding-box diagonal)^2 is degenerate: 1e-12 of
# a 2 km scene is 4 cm^2 (a sliver no mesh builder can use), while any real facet is many orders larger.
DEGENERATE_AREA_REL = 1e-12


def mesh_scale(vertices: np.ndarray) -> float:
    return max(float(np.linalg.norm(np.ptp(vertices, axis=0))), float(np.abs(vertices).max()), 1.0)


def format_point(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:g}" for v in p) + ")"


def basic_mesh_problem(vertices: np.ndarray, faces: np.ndarray) -> str | None:
    """Finite coordinates, valid indices, no repeated index, no zero-area triangle."""
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        return f"expected (V, 3) vertices and (F, 3) triangles, got {vertices.shape} and {faces.shape}"
    if faces.shape[0] == 0:
        return "the file contains no triangles"
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if np.any(bad):
        return f"{int(bad.sum())} vertices have NaN or infinite coordinates (first: vertex {int(np.argmax(bad))})"
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        return f"triangle indices must be in [0, {vertices.shape[0] - 1}]"
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    if np.any(repeated):
        i = int(np.argmax(repeated))
        return f"{int(repeated.sum())} triangles use the same vertex twice (first: triangle {i})"
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    tiny = area <= DEGENERATE_AREA_REL * mesh_scale(vertices) ** 2
    if np.any(tiny):
        i = int(np.argmax(tiny))
        return (
            f"{int(tiny.sum())} degenerate (zero-area) triangles (first: triangle {i} with corners "
            f"{format_point(tri[i, 0])}, {format_point(tri[i, 1])}, {format_point(tri[i, 2])})"
        )
    return None


def unique_pairs(pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """np.unique(pairs, axis=0, return_inverse=True, return_counts=True) for (N, 2) non-negative int64,
    through one int64 code per row (several times faster than the row-wise unique)."""
    n = np.int64(pairs.max(initial=0) + 1)
    codes, inverse, counts = np.unique(pairs[:, 0] * n + pairs[:, 1], return_inverse=True, return_counts=True)
    return np.column_stack([codes // n, codes % n]), inverse.ravel(), counts


def directed_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directed edges (3F, 2) in face order (edge k of face f at row 3 f + k) and the owning face ids."""
    directed = np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2)
    return directed, np.repeat(np.arange(faces.shape[0]), 3)


def triangles_intersect(t1: np.ndarray, t2: np.ndarray, tol: float) -> np.ndarray:
    """Separating-axis test for (P, 3, 3) triangle pairs: True where the triangles share interior points.
    Touching (an overlap thinner than tol on some axis) counts as separated, except along the common
    normal of coplanar triangles, where both projections are points. Axes: both normals, the 9 edge
    cross products and the 6 in-plane edge normals (needed for coplanar pairs)."""
    e1 = np.roll(t1, -1, axis=1) - t1
    e2 = np.roll(t2, -1, axis=1) - t2
    n1 = np.cross(e1[:, 0], e1[:, 1])
    n2 = np.cross(e2[:, 0], e2[:, 1])
    axes = [n1[:, None], n2[:, None]]
    axes.append(np.cross(e1[:, :, None, :], e2[:, None, :, :]).reshape(-1, 9, 3))
    axes.append(np.cross(n1[:, None, :], e1))
    axes.append(np.cross(n2[:, None, :], e2))
    ax = np.concatenate(axes, axis=1)  # (P, 17, 3)
    norm = np.linalg.norm(ax, axis=2)
    p1 = np.einsum("pad,pvd->pav", ax, t1)
    p2 = np.einsum("pad,pvd->pav", ax, t2)
    gap = np.maximum(p2.min(axis=2) - p1.max(axis=2), p1.min(axis=2) - p2.max(axis=2))
    longest = max(float(np.abs(e1).max(initial=0.0)), float(np.abs(e2).max(initial=0.0)), 1e-300)
    usable = norm > 1e-12 * longest**2  # parallel edges give a zero axis: no information
    slack = tol * norm
    # both projections a single point (an axis along the common normal of coplanar triangles): only a real
    # gap separates; otherwise an overlap thinner than tol is a touch and counts as separated
    both_flat = (np.ptp(p1, axis=2) <= slack) & (np.ptp(p2, axis=2) <= slack)
    separated = usable & ((gap > slack) | ((gap >= -slack) & ~both_flat))
    return ~np.any(separated, axis=1)


def closed_mesh_problem(vertices: np.ndarray, faces: np.ndarray) -> str | None:
    """Why the mesh is not a closed, consistently outward-oriented, non-self-intersecting surface, or None.
    Run :func:`basic_mesh_problem` first."""
    directed, owner = directed_edges(faces)
    undirected = np.sort(directed, axis=1)
    keys, idx, counts = unique_pairs(undirected)
    if np.any(counts == 1):
        e = keys[int(np.argmax(counts == 1))]
        return (
            f"not watertight: {int(np.sum(counts == 1))} edges belong to a single triangle (first: the edge "
            f"{format_point(vertices[e[0]])}-{format_point(vertices[e[1]])})"
        )
    if np.any(counts > 2):
        e = keys[int(np.argmax(counts > 2))]
        return (
            f"not manifold: {int(np.sum(counts > 2))} edges are shared by more than two triangles (first: the "
            f"edge {format_point(vertices[e[0]])}-{format_point(vertices[e[1]])}, "
            f"in {int(counts[np.argmax(counts > 2)])})"
        )
    _, d_idx, d_counts = unique_pairs(directed)
    same_way = d_counts[d_idx] > 1
    if np.any(same_way):
        e = int(np.argmax(same_way))
        pair = owner[idx == idx[e]]
        return (
            f"inconsistently oriented: triangles {pair[0]} and {pair[1]} run through their shared edge in the "
            "same direction (their normals disagree)"
        )
    # shells: connected components over shared edges; each must enclose a positive volume. scipy.sparse.csgraph
    # loads here: the job schema imports this module, and most jobs have no closed mesh to check
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pair_rows = np.argsort(idx, kind="stable").reshape(-1, 2)  # each edge appears exactly twice
    fa, fb = owner[pair_rows[:, 0]], owner[pair_rows[:, 1]]
    n_faces = faces.shape[0]
    graph = coo_matrix((np.ones(fa.size), (fa, fb)), shape=(n_faces, n_faces))
    n_shells, shell = connected_components(graph, directed=False)
    tri = vertices[faces]
    centre = vertices.mean(axis=0)
    six_vol = np.einsum("fd,fd->f", tri[:, 0] - centre, np.cross(tri[:, 1] - centre, tri[:, 2] - centre))
    volume = np.bincount(shell, weights=six_vol, minlength=n_shells) / 6.0
    scale = mesh_scale(vertices)
    if np.any(volume <= DEGENERATE_AREA_REL * scale**3):
        s = int(np.argmin(volume))
        return (
            f"shell {s} (of {n_shells}) has signed volume {volume[s]:.6g} m^3: its triangles must be ordered "
            "counter-clockwise seen from outside (outward normals)"
        )
    tol = GEOMETRY_REL_TOL * scale
    try:
        i, j = box_pairs(tri.min(axis=1), tri.max(axis=1))
    except CandidateLimitError as exc:
        return f"too many overlapping triangles to check: {exc}"
    share = np.any(faces[i][:, :, None] == faces[j][:, None, :], axis=(1, 2))
    i, j = i[~share], j[~share]
    hit = np.zeros(i.shape, dtype=bool)
    for lo in range(0, i.size, 200_000):  # bounded temporaries (17 axes x 3 vertices per pair)
        hit[lo : lo + 200_000] = triangles_intersect(tri[i[lo : lo + 200_000]], tri[j[lo : lo + 200_000]], tol)
    if np.any(hit):
        n = int(np.argmax(hit))
        near = format_point(tri[i[n]].mean(axis=0))
        return f"self-intersecting: triangles {int(i[n])} and {int(j[n])} intersect (near {near})"
    return None

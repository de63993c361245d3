"""The batched-numpy per-cell Hessian that engine/mesh/hessian.py computed until 2026-12-05 (evening): the oracle of
its compiled pass (engine/mesh/hessian_kernel.py; tests/mesh/test_hessian_kernel.py). Same formulas, numpy's
batched solve for the vertices, einsum for the sums; 18 s on the consultant example's 1.76 million tetrahedra."""

from __future__ import annotations

from itertools import combinations

import numpy as np

from bentray.engine.constants import FACE_UNUSED
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.mesh.hessian import packed_hessians


def cell_vertices(mesh: CellMesh) -> tuple[np.ndarray, np.ndarray]:
    """The vertices of each convex cell: the points where three of its face planes meet inside every other
    face. Returns (points (n, V, 3) m, valid (n, V) bool), V = C(K, 3) candidate slots (a tet: 4 valid of
    4, a slab box: 8 of 20)."""
    planes = mesh.planes
    n, k = planes.shape[0], planes.shape[1]
    used = mesh.neighbours != FACE_UNUSED
    triples = list(combinations(range(k), 3))
    pts = np.full((n, len(triples), 3), np.nan)
    valid = np.zeros((n, len(triples)), dtype=bool)
    scale = np.maximum(1.0, np.max(np.abs(planes[:, :, 3]), axis=1))
    for slot, (a, b, c) in enumerate(triples):
        mat = planes[:, [a, b, c], :3]
        det = np.linalg.det(mat)
        ok = used[:, a] & used[:, b] & used[:, c] & (np.abs(det) > 1e-12)
        if not ok.any():
            continue
        idx = np.nonzero(ok)[0]
        p = np.linalg.solve(mat[idx], planes[idx][:, [a, b, c], 3][..., None])[..., 0]
        dist = np.einsum("nkj,nj->nk", planes[idx, :, :3], p) - planes[idx, :, 3]
        inside = np.all((dist <= 1e-9 * scale[idx, None]) | ~used[idx], axis=1)
        pts[idx[inside], slot] = p[inside]
        valid[idx[inside], slot] = True
    if not np.all(valid.any(axis=1)):
        raise ValueError("cell_vertices: a cell has no vertex (its face planes do not bound it)")
    return pts, valid


def face_areas(mesh: CellMesh, pts: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(n, K) area of each face (m^2; 0 for unused slots): the convex polygon of the cell's vertices on
    the face plane, ordered by angle about their mean and fanned into triangles."""
    planes = mesh.planes
    n, k = planes.shape[0], planes.shape[1]
    scale = np.maximum(1.0, np.max(np.abs(planes[:, :, 3]), axis=1))
    areas = np.zeros((n, k))
    filled = np.where(valid[..., None], pts, 0.0)
    for f in range(k):
        m = planes[:, f, :3]
        on = valid & (np.abs(np.einsum("nvj,nj->nv", filled, m) - planes[:, f, 3][:, None]) <= 1e-9 * scale[:, None])
        on &= (mesh.neighbours[:, f] != FACE_UNUSED)[:, None]
        cnt = on.sum(axis=1)
        centre = np.einsum("nvj,nv->nj", filled, on) / np.maximum(cnt, 1)[:, None]
        # an in-plane frame (u, w) per face
        helper = np.where(np.abs(m[:, 0:1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
        u = np.cross(m, helper)
        u /= np.linalg.norm(u, axis=1)[:, None]
        w = np.cross(m, u)
        rel = filled - centre[:, None, :]
        ang = np.arctan2(np.einsum("nvj,nj->nv", rel, w), np.einsum("nvj,nj->nv", rel, u))
        ang = np.where(on, ang, np.inf)
        order = np.argsort(ang, axis=1)
        ordered = np.take_along_axis(rel, order[..., None], axis=1)
        on_sorted = np.take_along_axis(on, order, axis=1)
        nxt = np.roll(ordered, -1, axis=1)
        # close the polygon: the last valid vertex pairs with the first
        last = np.maximum(cnt - 1, 0)
        rows = np.arange(n)
        nxt[rows, last] = ordered[:, 0]
        cross = np.cross(ordered, nxt)
        tri = 0.5 * np.abs(np.einsum("nvj,nj->nv", cross, m)) * on_sorted
        areas[:, f] = np.where(cnt >= 3, tri.sum(axis=1), 0.0)
    return areas


def cell_hessians_numpy(mesh: CellMesh) -> np.ndarray:
    """(n_cells, 9) per-cell Hessian of the traced quantity (module docstring), per m^2."""
    pts, valid = cell_vertices(mesh)
    cnt = valid.sum(axis=1)
    centre = np.einsum("nvj,nv->nj", np.where(valid[..., None], pts, 0.0), valid) / cnt[:, None]
    areas = face_areas(mesh, pts, valid)
    planes = mesh.planes
    used = mesh.neighbours != FACE_UNUSED
    dist = np.abs(planes[:, :, 3] - np.einsum("nkj,nj->nk", planes[:, :, :3], centre))
    volume = np.sum(np.where(used, areas * dist, 0.0), axis=1) / 3.0
    nb = mesh.neighbours
    inner = nb >= 0
    safe = np.where(inner, nb, 0)
    dg = (mesh.gradient[safe] - mesh.gradient[:, None, :]) * inner[..., None]  # (n, K, 3)
    m = planes[:, :, :3]
    weight = np.where(inner, areas / (volume[:, None] + volume[safe]), 0.0)  # (n, K) per m
    half = np.einsum("nk,nki,nkj->nij", weight, dg, m)  # sum_f w_f dg_f n_f^T, without (n, K, 3, 3) arrays
    m_all = np.einsum("nk,nki,nkj->nij", np.where(used, areas, 0.0), m, m)
    m_inner = np.einsum("nk,nki,nkj->nij", np.where(inner, areas, 0.0), m, m)
    edge = ~np.all(inner | ~used, axis=1)
    # the boundary scaling and the packing were never batched-numpy-only: the engine's own (the oracle checks the
    # face sums the compiled pass feeds it)
    return packed_hessians(half, m_all, m_inner, edge, centre)

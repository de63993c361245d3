"""Per-cell gradients of the traced quantity m on a tetrahedral mesh (paper Sec. 5.3, Eq. 11-13).

Two estimators, both exact for a linear field m = a + g . x (up to rounding):

* ``lsq_gradients``: least squares on the centroids of the (up to 4) face neighbours,
  ``(x_k - x_0)^T grad m = m_k - m_0``, optionally weighted by inverse centroid distance (Eq. 13). The
  centroid values must be the P1 value at the centroid (mean of the 4 vertex values) so that a linear
  field is reproduced exactly.
* ``green_gauss_gradients``: the exact gradient of the P1 interpolant of the tet's own vertex values
  (Green-Gauss over the 4 faces equals it for a tetrahedron), used as the fallback where the least
  squares system is under-determined or ill-conditioned, and as ``gradient_method="green_gauss"``.

``lsq_gradients`` is vectorised numpy (batched 3x3 solves) and is the reference; ``lsq_gradients_compiled``
gives the same bits from one compiled pass per cell (lsq_kernel.py: the normal equations and a closed-form
eigenvalue test, LAPACK only for the few cells near the threshold) and is what ``cell_media`` uses.
"""

from __future__ import annotations

import numpy as np

from bentray.engine.mesh.lsq_kernel import (
    LSQ_ACCEPT,
    LSQ_UNDECIDED,
    cell_centroids,
    green_gauss_systems,
    lsq_systems,
)

# Least squares is used only where the normal matrix A = sum_k w_k^2 (x_k - x_0)(x_k - x_0)^T has
# lambda_min / lambda_max >= LSQ_RCOND_MIN. With inverse-distance weights the rows are unit vectors, so
# the ratio measures how well the neighbour directions span 3D: 1e-3 means the worst direction is
# sampled with ~3% (sqrt(1e-3)) of the spread of the best one. Below that the O(h^2) curvature residual
# of a non-linear field (and rounding, for a linear one) is amplified by > ~30x along the poorly
# sampled direction, while the cell's own P1 gradient is always well defined: fall back to it.
# Well-shaped cells with 3 or 4 neighbours are typically at 0.1-0.5.
LSQ_RCOND_MIN = 1e-3


def green_gauss_gradients(points: np.ndarray, tets: np.ndarray, vertex_values: np.ndarray) -> np.ndarray:
    """Exact gradient of the linear (P1) interpolant of ``vertex_values`` on each tet.

    points : (P, 3) float64, metres. tets : (T, 4) int64 vertex ids (any orientation, non-degenerate).
    vertex_values : (P,) float64. Returns (T, 3) float64, units of m per metre.
    """
    points = np.asarray(points, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    vv = np.asarray(vertex_values, dtype=np.float64)
    p = points[tets]  # (T, 4, 3)
    e = p[:, 1:, :] - p[:, :1, :]  # (T, 3, 3): rows p_i - p_0
    dm = vv[tets[:, 1:]] - vv[tets[:, :1]]  # (T, 3)
    return np.linalg.solve(e, dm[:, :, None])[:, :, 0]


def lsq_gradients(
    centroids: np.ndarray,
    centroid_values: np.ndarray,
    neighbours: np.ndarray,
    weighted: bool = True,
    *,
    fallback: np.ndarray | None = None,
    rcond_min: float = LSQ_RCOND_MIN,
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares cell gradients from the face neighbours' centroids (Eq. 11-13).

    Parameters
    ----------
    centroids : (n, 3) float64, metres (the cells' reference points).
    centroid_values : (n,) float64, m at the centroids (P1 value: mean of the 4 vertex values).
    neighbours : (n, K) int64, neighbour cell ids; negative entries (boundary tags, padding) are ignored.
    weighted : weight each equation by 1 / |x_k - x_0| (the paper's optional W, Eq. 13).
    fallback : optional (n, 3) gradients copied into the cells where least squares is not used (fewer
        than 3 neighbours or lambda_min / lambda_max < rcond_min); NaN there when not given.

    Returns
    -------
    grads : (n, 3) float64, m per metre.
    used_fallback : (n,) bool, True where the least-squares system was rejected.
    """
    x0 = np.asarray(centroids, dtype=np.float64)
    m0 = np.asarray(centroid_values, dtype=np.float64)
    nb = np.asarray(neighbours, dtype=np.int64)
    valid = nb >= 0
    j = np.where(valid, nb, 0)
    dx = x0[j] - x0[:, None, :]  # (n, K, 3)
    dm = m0[j] - m0[:, None]  # (n, K)
    dist = np.linalg.norm(dx, axis=2)
    valid &= dist > 0
    if weighted:
        w = np.where(valid, 1.0 / np.where(valid, dist, 1.0), 0.0)
    else:
        w = valid.astype(np.float64)
    rows = dx * w[:, :, None]
    rhs = dm * w
    a = np.einsum("nki,nkj->nij", rows, rows)
    b = np.einsum("nki,nk->ni", rows, rhs)
    enough = valid.sum(axis=1) >= 3
    lam = np.linalg.eigvalsh(a)  # ascending, (n, 3)
    good = enough & (lam[:, 2] > 0) & (lam[:, 0] >= rcond_min * lam[:, 2])
    return _solve_accepted(a, b, good, fallback)


def _solve_accepted(
    a: np.ndarray, b: np.ndarray, good: np.ndarray, fallback: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Gradients (n, 3) of the accepted cells from their normal equations a (n, 3, 3), b (n, 3) (LAPACK gesv),
    ``fallback`` (or NaN) elsewhere; and the rejected mask (n,). Shared by both least-squares paths."""
    grads = np.full((len(good), 3), np.nan)
    if np.any(good):
        grads[good] = np.linalg.solve(a[good], b[good][:, :, None])[:, :, 0]
    used_fallback = ~good
    if fallback is not None and np.any(used_fallback):
        grads[used_fallback] = np.asarray(fallback, dtype=np.float64)[used_fallback]
    return grads, used_fallback


def lsq_gradients_compiled(
    centroids: np.ndarray,
    centroid_values: np.ndarray,
    neighbours: np.ndarray,
    weighted: bool = True,
    *,
    fallback: np.ndarray | None = None,
    rcond_min: float = LSQ_RCOND_MIN,
) -> tuple[np.ndarray, np.ndarray]:
    """``lsq_gradients`` (same arguments, shapes, units and bits) from the compiled normal equations.

    A and b come from ``lsq_kernel.lsq_systems`` (bit-identical to the einsums); the accept decision is
    the closed-form one, or LAPACK's eigvalsh as in ``lsq_gradients`` for the cells the kernel leaves
    undecided (near the threshold), so the decisions are the same; the solves are the same LAPACK gesv.
    """
    x0 = np.asarray(centroids, dtype=np.float64)
    a, b, status = lsq_systems(x0, centroid_values, neighbours, weighted, rcond_min)
    good = status == LSQ_ACCEPT
    undecided = np.flatnonzero(status == LSQ_UNDECIDED)
    if len(undecided):
        lam = np.linalg.eigvalsh(a[undecided])  # ascending, (u, 3)
        good[undecided] = (lam[:, 2] > 0) & (lam[:, 0] >= rcond_min * lam[:, 2])
    return _solve_accepted(a, b, good, fallback)


def cell_media(
    points: np.ndarray, tets: np.ndarray, neighbours: np.ndarray, quantity_at, gradient_method: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Per-cell linear media of a tetrahedral mesh from the traced quantity at its vertices.

    points (P, 3) metres; tets (T, 4); neighbours (T, 4) (negative: boundary); quantity_at: xyz (N, 3)
    -> (N,). Returns (vertex values (P,), media_ref (T,) = P1 value at the centroid, centroids (T, 3),
    gradient (T, 3), number of cells on the Green-Gauss fallback). gradient_method: "lsq", "lsq_unweighted" or
    "green_gauss"; the Green-Gauss fallback is computed only for the cells that need it.
    """
    vertex_values = np.asarray(quantity_at(points), dtype=np.float64).reshape(-1)
    if vertex_values.shape != (len(points),) or not np.all(np.isfinite(vertex_values)):
        raise ValueError("quantity_at must return one finite value per point")
    centroids, media_ref = cell_centroids(points, tets, vertex_values)  # the numpy means' bits
    if gradient_method == "green_gauss":
        all_cells = np.arange(len(tets))
        return vertex_values, media_ref, centroids, _green_gauss_cells(points, tets, all_cells, vertex_values), 0
    grad, fallback = lsq_gradients_compiled(centroids, media_ref, neighbours, weighted=gradient_method == "lsq")
    cells = np.flatnonzero(fallback)
    if len(cells):
        grad[cells] = _green_gauss_cells(points, tets, cells, vertex_values)
    return vertex_values, media_ref, centroids, grad, int(fallback.sum())


def _green_gauss_cells(
    points: np.ndarray, tets: np.ndarray, cells: np.ndarray, vertex_values: np.ndarray
) -> np.ndarray:
    """``green_gauss_gradients(points, tets[cells], vertex_values)`` (n, 3), bit for bit: the same systems
    from one compiled gather, the same LAPACK solves."""
    e, dm = green_gauss_systems(points, tets, cells, vertex_values)
    return np.linalg.solve(e, dm[:, :, None])[:, :, 0]


def tet_cell_mesh(
    points: np.ndarray,
    tets: np.ndarray,
    planes: np.ndarray,
    neighbours: np.ndarray,
    neighbour_face: np.ndarray,
    longest: np.ndarray,
    face_material: np.ndarray,
    quantity_at,
    gradient_method: str,
):
    """The kernels' CellMesh of a tetrahedral mesh whose geometry and boundary tags are built: per-cell
    linear media from :func:`cell_media`. Returns (CellMesh, vertex values (P,), Green-Gauss fallbacks)."""
    from bentray.engine.mesh.cells import CellMesh

    vertex_values, media_ref, centroids, grad, n_fallback = cell_media(
        points, tets, neighbours, quantity_at, gradient_method
    )
    cells = CellMesh(
        planes=np.ascontiguousarray(planes),
        neighbours=np.ascontiguousarray(neighbours),
        neighbour_face=np.ascontiguousarray(neighbour_face),
        media_ref=np.ascontiguousarray(media_ref),
        ref_point=np.ascontiguousarray(centroids),
        gradient=np.ascontiguousarray(grad),
        size=np.ascontiguousarray(longest),
        face_material=face_material,
    )
    return cells, vertex_values, n_fallback

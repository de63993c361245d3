"""A smooth second derivative of the mesh's traced quantity, per cell, for the beams' paraxial state.

The media mesh is piecewise linear: inside a cell m (n^2 for the parabolic curve) has the constant gradient
``mesh.gradient[c]`` and no curvature; all of the medium's curvature sits in the gradient jumps at faces.
The exact paraxial derivatives of that mesh turn those jumps into kicks ``(g_old - g_new)/2 d sigma`` with
``d sigma = -(m.X)/(m.p)``, which grow without bound as a crossing turns tangential (docs/physics.md §11,
"Smooth-medium paraxial state"): a ray whose turning point sits just above a face and its neighbour just
below it get very different tubes. The medium the mesh approximates has no such jumps; its curvature is
smooth. Beams therefore propagate the paraxial state through a medium whose Hessian is constant per cell
and spreads each face's jump over the two cells it separates. The Hessian of a piecewise-linear m, as a
distribution, is a sum over faces of ``sym(dg_f n_f^T) delta_f`` (dg_f = g[nb] - g[c] across face f, n_f
its unit normal out of c, delta_f the surface delta); its integral over space is
``sum_f A_f sym(dg_f n_f^T)``. Giving each face's share to c and nb in proportion to their volumes,

    H_c = sum over inner faces f of c:  A_f sym(dg_f n_f^T) / (V_c + V_nb),

conserves that integral exactly: a steep ray crossing many cells gets, to first order in the cell size,
the same total as the sum of the exact kicks. On slabs (A_f / V = 1 / h) this is
``H_zz = (H_below + H_above) / 2`` with ``H_face = dg / ((h_c + h_nb) / 2)``: the jump over the distance
between layer middles. A cell on the domain's boundary lacks the faces beyond it: its H is scaled by
``C = M_inner^+ M_all`` (M = sum of A_f n_f n_f^T over its inner / all faces), so a ground slab gets the
full H_zz of the face above it (directions the inner faces cover with less than 1/4 of their largest
``M_inner`` eigenvalue are left out of C, not amplified). The ray itself still follows the mesh's exact curves.

Returned as (n_cells, 9) float64: (H_xx, H_yy, H_zz, H_xy, H_xz, H_yz) per metre^2 and the centroid (m), the
point where the smooth medium's gradient is the cell's own (its gradient elsewhere: g + H (x - centroid)).
"""

from __future__ import annotations

import numpy as np

from bentray.engine.constants import FACE_UNUSED
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.mesh.hessian_kernel import cell_geometry

_CACHE: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # id(mesh.gradient) -> (that array, its Hessians)
_CACHE_SIZE = 4


def cell_hessians(mesh: CellMesh) -> np.ndarray:
    """(n_cells, 9) per-cell Hessian of the traced quantity (module docstring), per m^2.

    The vertices, face areas, volumes and sums over faces come from one compiled pass per cell
    (mesh/hessian_kernel.py; the batched-numpy formulas it replaced are its test oracle,
    tests/reference/hessian_numpy.py); the boundary cells' scaling is LAPACK's pseudo-inverse here."""
    centre, areas, volume, half, m_all, m_inner, ok = cell_geometry(
        np.ascontiguousarray(mesh.planes, dtype=np.float64),
        np.ascontiguousarray(mesh.neighbours),
        np.ascontiguousarray(mesh.gradient, dtype=np.float64),
    )
    if not ok.all():
        raise ValueError("cell_hessians: a cell has no vertex (its face planes do not bound it)")
    nb = mesh.neighbours
    edge = ~np.all((nb >= 0) | (nb == FACE_UNUSED), axis=1)
    return packed_hessians(half, m_all, m_inner, edge, centre)


def packed_hessians(
    half: np.ndarray, m_all: np.ndarray, m_inner: np.ndarray, edge: np.ndarray, centre: np.ndarray
) -> np.ndarray:
    """(n, 9) rows [Hxx, Hyy, Hzz, Hxy, Hxz, Hyz, cx, cy, cz] from the face sums of each cell.

    half (n, 3, 3): sum_f w_f dg_f n_f^T (symmetrised here); m_all, m_inner (n, 3, 3): sum of A_f n_f n_f^T over
    all used / the inner faces; edge (n,) bool: cells with a boundary face; centre (n, 3) m. Boundary cells miss
    the share of the faces they lack (a ground slab would get half its H_zz): they are scaled by
    C = M_inner^+ M_all (identity inside), directions the inner faces cover poorly dropped (rcond 0.25)."""
    h = 0.5 * (half + np.swapaxes(half, 1, 2))
    if edge.any():
        c = np.linalg.pinv(m_inner[edge], rcond=0.25) @ m_all[edge]
        he = h[edge]
        h[edge] = 0.5 * (he @ c + np.swapaxes(c, 1, 2) @ he)
    return np.ascontiguousarray(
        np.column_stack([h[:, 0, 0], h[:, 1, 1], h[:, 2, 2], h[:, 0, 1], h[:, 0, 2], h[:, 1, 2], centre])
    )


def hessian_of(mesh: CellMesh) -> np.ndarray:
    """:func:`cell_hessians` of ``mesh``, computed once per mesh (kept for the last few meshes traced)."""
    key = id(mesh.gradient)
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is mesh.gradient:
        return hit[1]
    if len(_CACHE) >= _CACHE_SIZE:
        _CACHE.pop(next(iter(_CACHE)))
    out = cell_hessians(mesh)
    _CACHE[key] = (mesh.gradient, out)
    return out

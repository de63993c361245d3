"""CellMesh: the one representation every traversal kernel walks.

A media mesh is a set of convex cells with planar faces: a single box (homogeneous medium), a stack
of horizontal slabs (stratified medium over flat ground) or Delaunay tetrahedra (3D media). Inside a
cell the traced quantity ``m`` (n^2, c or n, depending on the curve) is linear:

    m(x) = media_ref[i] + gradient[i] . (x - ref_point[i])

All arrays are float64/int64, C-contiguous, world frame, metres.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bentray.engine.constants import BOUNDARY_OPEN, BOUNDARY_REFLECT, FACE_UNUSED


class CellMesh(NamedTuple):
    """Struct-of-arrays media mesh consumed by the kernels (passed to them as is: numba takes a NamedTuple
    of arrays as one argument and reads its fields by name).

    planes : (n_cells, K, 4) float64
        Face planes ``(mx, my, mz, h)``: outward unit normal m and offset h; the cell is
        ``m . x <= h`` for all its faces. Shared faces hold the identical plane with opposite sign in
        the two cells (computed once from the sorted vertex ids), so both sides agree bit for bit.
    neighbours : (n_cells, K) int64
        Cell across each face, or a boundary tag (``BOUNDARY_OPEN``, ``BOUNDARY_REFLECT``), or
        ``FACE_UNUSED`` for padding slots.
    neighbour_face : (n_cells, K) int64
        Index of the same face in the neighbour's face list (the entry face there); -1 at boundaries.
    media_ref : (n_cells,) float64
        Traced quantity m at ``ref_point`` (n^2 dimensionless, c in m/s, or n dimensionless).
    ref_point : (n_cells, 3) float64, metres.
    gradient : (n_cells, 3) float64
        grad m (per metre).
    size : (n_cells,) float64, metres
        Characteristic cell length used to scale geometric tolerances.
    face_material : (n_cells, K) int64
        Material index of reflecting faces (0 = rigid); unused elsewhere.
    """

    planes: np.ndarray
    neighbours: np.ndarray
    neighbour_face: np.ndarray
    media_ref: np.ndarray
    ref_point: np.ndarray
    gradient: np.ndarray
    size: np.ndarray
    face_material: np.ndarray

    @property
    def n_cells(self) -> int:
        return int(self.planes.shape[0])

    def media_at(self, cell: int, xyz: np.ndarray) -> np.ndarray:
        """Traced quantity m of cell ``cell`` evaluated at ``xyz`` (N, 3): the cell's linear model."""
        return self.media_ref[cell] + (np.asarray(xyz, float) - self.ref_point[cell]) @ self.gradient[cell]


def validate_cell_mesh(mesh: CellMesh) -> None:
    """Check shapes, dtypes and the neighbour / neighbour_face symmetry; raise ValueError if broken."""
    n, k = mesh.neighbours.shape
    if mesh.planes.shape != (n, k, 4):
        raise ValueError(f"planes shape {mesh.planes.shape} does not match neighbours {(n, k)}")
    for name in ("neighbour_face", "face_material"):
        if getattr(mesh, name).shape != (n, k):
            raise ValueError(f"{name} shape {getattr(mesh, name).shape} != {(n, k)}")
    if mesh.media_ref.shape != (n,) or mesh.size.shape != (n,):
        raise ValueError("media_ref and size must be (n_cells,)")
    if mesh.ref_point.shape != (n, 3) or mesh.gradient.shape != (n, 3):
        raise ValueError("ref_point and gradient must be (n_cells, 3)")
    nb = mesh.neighbours
    inner = nb >= 0
    if np.any(nb[inner] >= n):
        raise ValueError("neighbour index out of range")
    allowed = np.isin(nb[~inner], [BOUNDARY_OPEN, BOUNDARY_REFLECT, FACE_UNUSED])
    if not np.all(allowed):
        raise ValueError("unknown boundary tag in neighbours")
    ci, fi = np.nonzero(inner)
    nj = nb[ci, fi]
    nf = mesh.neighbour_face[ci, fi]
    if np.any(nf < 0) or np.any(nf >= k):
        raise ValueError("neighbour_face out of range for an interior face")
    if not np.array_equal(nb[nj, nf], ci):
        raise ValueError("neighbour table is not symmetric")
    if not np.allclose(mesh.planes[nj, nf], -mesh.planes[ci, fi], rtol=0.0, atol=0.0):
        raise ValueError("shared faces must hold the identical plane with opposite sign")


def locate_points(mesh: CellMesh, xyz: np.ndarray) -> np.ndarray:
    """Cell id containing each point of ``xyz`` (N, 3), or -1 when outside every cell.

    Brute force over cells (vectorised): used once per source, not per ray. A point on a shared face
    or edge gets the cell with the smallest maximum plane violation; ties are harmless because the
    kernels treat a start point on a face consistently.
    """
    xyz = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
    out = np.full(len(xyz), -1, dtype=np.int64)
    used = mesh.neighbours != FACE_UNUSED
    normals = mesh.planes[:, :, :3]
    offsets = mesh.planes[:, :, 3]
    for i, p in enumerate(xyz):
        dist = normals @ p - offsets  # (n_cells, K)
        dist = np.where(used, dist, -np.inf)
        worst = dist.max(axis=1)
        best = int(np.argmin(worst))
        if worst[best] <= 1e-9 * max(1.0, float(mesh.size[best])):
            out[i] = best
    return out

"""Stratified media over flat ground: horizontal layers (slabs) instead of a 3D mesh.

When c depends on z only and the ground is flat, the exact media restricted to a column is 1D, so
the cells are slabs spanning the whole domain box horizontally: each has 6 planes (bottom, top and
the four open sides). The traced quantity m is interpolated linearly in z between layer boundaries
(continuous, exact at the boundaries), so a profile that is linear in m needs a single layer and is
represented exactly. A homogeneous medium is the one-slab case.

Layer boundaries come from a sizing rule (sizing.py); m is sampled exactly at them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from bentray.engine.constants import BOUNDARY_OPEN, BOUNDARY_REFLECT
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.result import MeshGeometry

# Face order of a slab cell.
FACE_BOTTOM, FACE_TOP, FACE_XMIN, FACE_XMAX, FACE_YMIN, FACE_YMAX = range(6)


def build_slab_mesh(
    domain_min: np.ndarray,
    domain_max: np.ndarray,
    z_levels: np.ndarray,
    m_at_z: Callable[[np.ndarray], np.ndarray],
    *,
    ground: str = "reflect",
    top: str = "open",
) -> CellMesh:
    """Slab CellMesh from increasing layer boundaries ``z_levels`` (first = ground, last = top).

    m_at_z : vectorised m(z) (traced quantity along a vertical line), z in metres.
    """
    lo = np.asarray(domain_min, dtype=np.float64)
    hi = np.asarray(domain_max, dtype=np.float64)
    z = np.asarray(z_levels, dtype=np.float64)
    if z.ndim != 1 or len(z) < 2 or np.any(np.diff(z) <= 0.0):
        raise ValueError("z_levels must be strictly increasing with at least 2 values")
    if z[0] != lo[2] or z[-1] != hi[2]:
        raise ValueError("z_levels must start at the domain bottom and end at its top")
    m = np.asarray(m_at_z(z), dtype=np.float64)
    if not np.all(np.isfinite(m)):
        raise ValueError("media values are not finite at some layer boundaries")
    n = len(z) - 1
    planes = np.zeros((n, 6, 4))
    planes[:, FACE_BOTTOM] = [0.0, 0.0, -1.0, 0.0]
    planes[:, FACE_BOTTOM, 3] = -z[:-1]
    planes[:, FACE_TOP] = [0.0, 0.0, 1.0, 0.0]
    planes[:, FACE_TOP, 3] = z[1:]
    planes[:, FACE_XMIN] = [-1.0, 0.0, 0.0, -lo[0]]
    planes[:, FACE_XMAX] = [1.0, 0.0, 0.0, hi[0]]
    planes[:, FACE_YMIN] = [0.0, -1.0, 0.0, -lo[1]]
    planes[:, FACE_YMAX] = [0.0, 1.0, 0.0, hi[1]]
    ids = np.arange(n, dtype=np.int64)
    neighbours = np.full((n, 6), BOUNDARY_OPEN, dtype=np.int64)
    neighbour_face = np.full((n, 6), -1, dtype=np.int64)
    neighbours[:, FACE_BOTTOM] = ids - 1
    neighbours[:, FACE_TOP] = ids + 1
    neighbour_face[:, FACE_BOTTOM] = FACE_TOP
    neighbour_face[:, FACE_TOP] = FACE_BOTTOM
    neighbours[0, FACE_BOTTOM] = BOUNDARY_REFLECT if ground == "reflect" else BOUNDARY_OPEN
    neighbour_face[0, FACE_BOTTOM] = -1
    neighbours[-1, FACE_TOP] = BOUNDARY_REFLECT if top == "reflect" else BOUNDARY_OPEN
    neighbour_face[-1, FACE_TOP] = -1
    centre = 0.5 * (lo + hi)
    ref_point = np.repeat(centre[None, :], n, axis=0)
    ref_point[:, 2] = z[:-1]
    gradient = np.zeros((n, 3))
    gradient[:, 2] = np.diff(m) / np.diff(z)
    # Geometric tolerances scale with the layer thickness (the distances a ray resolves there),
    # not with the km-wide horizontal extent.
    size = np.diff(z).copy()
    return CellMesh(
        planes=planes,
        neighbours=neighbours,
        neighbour_face=neighbour_face,
        media_ref=m[:-1].copy(),
        ref_point=ref_point,
        gradient=gradient,
        size=size,
        face_material=np.zeros((n, 6), dtype=np.int64),
    )


def locate_in_slabs(z_levels: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Slab index of each point (binary search in z); -1 outside the vertical range."""
    z = np.asarray(z_levels)
    pts = np.atleast_2d(xyz)
    idx = np.searchsorted(z, pts[:, 2], side="right") - 1
    idx = np.where((pts[:, 2] >= z[0]) & (pts[:, 2] <= z[-1]), np.clip(idx, 0, len(z) - 2), -1)
    return idx.astype(np.int64)


def slab_geometry(
    domain_min: np.ndarray, domain_max: np.ndarray, mesh: CellMesh, z_levels: np.ndarray, quantity: str
) -> MeshGeometry:
    """Hexahedra (VTK ordering) for mesh.vtu, with the traced quantity and its gradient per cell."""
    lo = np.asarray(domain_min, float)
    hi = np.asarray(domain_max, float)
    z = np.asarray(z_levels, float)
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    pts = np.concatenate([np.column_stack([corners, np.full(4, zi)]) for zi in z])
    n = len(z) - 1
    base = 4 * np.arange(n)[:, None]
    conn = np.concatenate([base + np.arange(4), base + 4 + np.arange(4)], axis=1).astype(np.int64)
    mid = 0.5 * (z[:-1] + z[1:])
    m_mid = mesh.media_ref + mesh.gradient[:, 2] * (mid - z[:-1])
    return MeshGeometry(
        points=pts,
        connectivity=conn,
        cell_type="hexahedron",
        cell_data={quantity: m_mid, f"grad_{quantity}": mesh.gradient.copy(), "thickness_m": np.diff(z)},
    )

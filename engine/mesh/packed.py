"""Packed per-cell records for the lean traversal: everything the walk reads on entering a cell in one row.

The CellMesh keeps its fields in seven arrays (planes, neighbours, neighbour_face, media_ref, ref_point,
gradient, size), so entering a cell touches 8-10 cache lines spread over seven places in memory. The lean
kernel (kernels/lean.py) reads instead one float64 row per cell, 64-byte aligned, with the fields at fixed
offsets for K faces:

==========  ==================  =============================================================
offset      length              field
==========  ==================  =============================================================
0           4 K                 planes, face by face: (mx, my, mz, h)
4K          3                   gradient of the traced quantity (per metre)
4K + 3      3                   ref_point (m)
4K + 6      1                   media_ref
4K + 7      1                   size (m)
4K + 8      K                   neighbours (cell index or boundary tag, stored exactly as float64)
5K + 8      K                   neighbour_face (stored exactly as float64)
==========  ==================  =============================================================

padded to a multiple of 8 doubles: tetrahedra (K = 4) take 32 doubles, 256 B, 4 cache lines; slab cells
(K = 6) 48 doubles, 6 lines. The values are copies of the mesh's (integers below 2^53 are exact in float64),
so a kernel reading them does the same arithmetic on the same numbers as one reading the mesh's arrays.
"""

from __future__ import annotations

import weakref
from typing import NamedTuple

import numpy as np

from bentray.engine.mesh.cells import CellMesh

__all__ = ["PackedCells", "pack_cells", "packed_cells"]

CACHE_LINE = 64  # bytes


class PackedCells(NamedTuple):
    """Packed records (module docstring). rec : (n_cells, width) float64, rows 64-byte aligned; k_faces : K."""

    rec: np.ndarray
    k_faces: int


def record_width(k_faces: int) -> int:
    """Doubles per record for K faces: 6 K + 8 rounded up to a whole number of cache lines."""
    per_line = CACHE_LINE // 8
    return -(-(6 * k_faces + 8) // per_line) * per_line


def _aligned_empty(rows: int, width: int) -> np.ndarray:
    """A (rows, width) float64 array whose first byte sits on a cache-line boundary (so does every row when
    width is a multiple of 8)."""
    raw = np.empty(rows * width + CACHE_LINE // 8, dtype=np.float64)
    skip = (-raw.ctypes.data % CACHE_LINE) // 8
    return raw[skip : skip + rows * width].reshape(rows, width)


def pack_cells(mesh: CellMesh) -> PackedCells:
    """Build the packed records of ``mesh`` (module docstring for the layout)."""
    n, k = mesh.planes.shape[0], mesh.planes.shape[1]
    if np.abs(mesh.neighbours).max(initial=0) >= 2**53:
        raise ValueError("neighbour indices beyond 2^53 cannot be packed exactly into float64 records")
    width = record_width(k)
    rec = _aligned_empty(n, width)
    rec[:, : 4 * k] = mesh.planes.reshape(n, 4 * k)
    rec[:, 4 * k : 4 * k + 3] = mesh.gradient
    rec[:, 4 * k + 3 : 4 * k + 6] = mesh.ref_point
    rec[:, 4 * k + 6] = mesh.media_ref
    rec[:, 4 * k + 7] = mesh.size
    rec[:, 4 * k + 8 : 5 * k + 8] = mesh.neighbours
    rec[:, 5 * k + 8 : 6 * k + 8] = mesh.neighbour_face
    rec[:, 6 * k + 8 :] = 0.0
    return PackedCells(rec, k)


# One packed copy per live mesh (keyed by its planes array, which the records copy): a job traces the same
# mesh many times (bench rounds, conditions, batches) and packing a 760k-cell mesh takes a few tenths of a
# second. An entry is dropped as soon as its planes array is freed (weakref.finalize), so a worker keeps no
# records of a finished job's mesh (they are 256 B per tetrahedron, about 0.9x the mesh itself).
_CACHE: dict[int, tuple[weakref.ref[np.ndarray], PackedCells]] = {}


def packed_cells(mesh: CellMesh) -> PackedCells:
    """The packed records of ``mesh``, built once per mesh and reused while the mesh lives."""
    key = id(mesh.planes)
    hit = _CACHE.get(key)
    if hit is not None and hit[0]() is mesh.planes:
        return hit[1]
    packed = pack_cells(mesh)
    _CACHE[key] = (weakref.ref(mesh.planes), packed)
    weakref.finalize(mesh.planes, _CACHE.pop, key, None)
    return packed

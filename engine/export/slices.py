"""Horizontal 2D maps from a 3D field (nx, ny, nz): a z index, or a height above the ground per column.

Levels in dB; NaN marks nodes the field did not reach (or outside the grid). Local frame, metres.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["slice_at_z", "slice_above_ground"]


def slice_at_z(values: ArrayLike, origin_z: float, spacing_z: float, z: float) -> tuple[NDArray[np.float64], float]:
    """(nx, ny) levels on the grid's z level nearest ``z`` (metres) and that level's z.
    Raises ValueError when z is more than half a spacing outside the grid."""
    v = np.asarray(values, dtype=np.float64)
    nz = v.shape[2]
    k = int(np.floor((z - origin_z) / spacing_z + 0.5))
    if not 0 <= k < nz:
        top = origin_z + (nz - 1) * spacing_z
        raise ValueError(f"z = {z:g} m is outside the field grid (z {origin_z:g} to {top:g} m)")
    return np.ascontiguousarray(v[:, :, k]), float(origin_z + k * spacing_z)


def slice_above_ground(
    values: ArrayLike, origin_z: float, spacing_z: float, ground_z: ArrayLike, height: float
) -> NDArray[np.float64]:
    """(nx, ny) levels at ``ground_z[i, j] + height`` in each column, linear in *energy* (10^(L/10)) between
    the two z nodes around it (a point on a node takes that node's level exactly). NaN where that height is
    outside the grid or either node is NaN. values (nx, ny, nz) dB; ground_z (nx, ny) metres, or a scalar."""
    v = np.asarray(values, dtype=np.float64)
    nx, ny, nz = v.shape
    target = np.broadcast_to(np.asarray(ground_z, dtype=np.float64), (nx, ny)) + float(height)
    t = (target - origin_z) / spacing_z
    k0 = np.floor(t).astype(np.int64)
    frac = t - k0
    on_top = (k0 == nz - 1) & (frac == 0.0)  # exactly on the top node
    k0 = np.where(on_top, nz - 2, k0)
    frac = np.where(on_top, 1.0, frac)
    inside = (k0 >= 0) & (k0 < nz - 1) & np.isfinite(t)
    kc = np.clip(k0, 0, max(nz - 2, 0))
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    if nz == 1:
        return np.where(t == 0.0, v[:, :, 0], np.nan)
    lo, hi = v[ii, jj, kc], v[ii, jj, kc + 1]
    e = (1.0 - frac) * np.power(10.0, lo / 10.0) + frac * np.power(10.0, hi / 10.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        level = 10.0 * np.log10(e)
    level = np.where(frac == 0.0, lo, np.where(frac == 1.0, hi, level))
    return np.where(inside, level, np.nan)

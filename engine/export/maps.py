"""The 2D map an export writes: one level array of a FieldGrid sliced at a z level or a height above ground.

Returns the map (nx, ny) dB and where it lies in the CRS: node (0, 0) at ``xy0`` (the grid's local origin
plus the frame's offset), spacing ``dxy``. Ground heights for ``height`` come from a callable on *CRS*
plan coordinates (e.g. :func:`bentray.scenes.geometry.terrain_height_at` of the scene's terrain file) or a
constant.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bentray.engine.export.field_grid import FieldGrid
from bentray.engine.export.slices import slice_above_ground, slice_at_z

__all__ = ["LevelMap", "level_map", "node_xy_crs"]


@dataclass
class LevelMap:
    """level (nx, ny) dB; xy0 (2,) CRS metres of node (0, 0); dxy (2,) metres; description for metadata;
    crs_wkt of the frame (None: local metres)."""

    level: NDArray[np.float64]
    xy0: NDArray[np.float64]
    dxy: NDArray[np.float64]
    description: str
    crs_wkt: str | None


def node_xy_crs(grid: FieldGrid) -> NDArray[np.float64]:
    """(nx, ny, 2) CRS plan coordinates of the grid's columns."""
    off = np.asarray(grid.frame.origin, dtype=np.float64)
    gx, gy = np.meshgrid(grid.axis(0) + off[0], grid.axis(1) + off[1], indexing="ij")
    return np.stack([gx, gy], axis=-1)


def level_map(
    grid: FieldGrid,
    array: str = "spl_a",
    *,
    z: float | None = None,
    height: float | None = None,
    ground: float | Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
) -> LevelMap:
    """Exactly one of ``z`` (absolute metres: the nearest grid level) and ``height`` (metres above
    ``ground``: a constant z or a callable CRS xy (N, 2) -> ground z (N,); energy-linear between levels)."""
    if (z is None) == (height is None):
        raise ValueError("give exactly one of z (a grid level) and height (above the ground)")
    values = grid.level(array)
    xy0 = np.asarray(grid.origin[:2], dtype=np.float64) + np.asarray(grid.frame.origin, dtype=np.float64)
    dxy = np.asarray(grid.spacing[:2], dtype=np.float64)
    if z is not None:
        level, z_used = slice_at_z(values, float(grid.origin[2]), float(grid.spacing[2]), z)
        return LevelMap(level, xy0, dxy, f"{array} at z = {z_used:g} m", grid.frame.crs_wkt)
    assert height is not None
    if ground is None:
        raise ValueError("a height above the ground needs the ground: a constant z or the scene's terrain")
    if callable(ground):
        xy = node_xy_crs(grid).reshape(-1, 2)
        gz = np.asarray(ground(xy), dtype=np.float64).reshape(grid.shape[:2])
        if np.any(np.isnan(gz)):
            raise ValueError(f"the terrain does not cover {int(np.isnan(gz).sum())} columns of the field grid")
    else:
        gz = np.full(grid.shape[:2], float(ground))
    level = slice_above_ground(values, float(grid.origin[2]), float(grid.spacing[2]), gz, height)
    return LevelMap(level, xy0, dxy, f"{array} at {height:g} m above the ground", grid.frame.crs_wkt)

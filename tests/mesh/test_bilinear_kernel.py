"""engine/mesh/bilinear_kernel.py: the compiled height-grid interpolation gives the numpy formula's heights bit for bit.

Oracle: the numpy formula the terrain used until 2026-12-05 (below, unchanged). Points inside the grid, on its
lines and nodes, outside it (the edge cells extrapolate), and not finite; uneven grid spacing.
"""

from __future__ import annotations

import numpy as np

import bentray  # noqa: F401
from bentray.engine.mesh.bilinear_kernel import bilinear_heights
from bentray.engine.mesh.terrain import _bilinear
from bentray.engine.surfaces import HeightGrid


def _numpy_bilinear(x: np.ndarray, y: np.ndarray, z: np.ndarray, xy: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(x, xy[:, 0], side="right") - 1, 0, len(x) - 2)
    j = np.clip(np.searchsorted(y, xy[:, 1], side="right") - 1, 0, len(y) - 2)
    tx = (xy[:, 0] - x[i]) / (x[i + 1] - x[i])
    ty = (xy[:, 1] - y[j]) / (y[j + 1] - y[j])
    return ((1.0 - tx) * (1.0 - ty) * z[j, i] + tx * (1.0 - ty) * z[j, i + 1]
            + (1.0 - tx) * ty * z[j + 1, i] + tx * ty * z[j + 1, i + 1])  # fmt: skip


def test_heights_equal_the_numpy_formula_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.uniform(0.5, 30.0, 41)) - 300.0
    y = np.cumsum(rng.uniform(0.5, 30.0, 23)) - 200.0
    z = rng.normal(0.0, 20.0, (y.size, x.size))
    inside = np.column_stack([rng.uniform(x[0], x[-1], 5000), rng.uniform(y[0], y[-1], 5000)])
    outside = np.column_stack([rng.uniform(x[0] - 500, x[-1] + 500, 2000), rng.uniform(y[0] - 500, y[-1] + 500, 2000)])
    nodes = np.column_stack([np.repeat(x, 3)[:60], np.tile(y, 6)[:60]])
    odd = np.array([[np.nan, 0.0], [0.0, np.nan], [np.inf, 0.0], [x[-1], y[-1]], [x[0], y[0]]])
    xy = np.concatenate([inside, outside, nodes, odd])
    got = bilinear_heights(x, y, z, xy)
    with np.errstate(invalid="ignore"):  # the infinite point: inf - inf in the oracle
        want = _numpy_bilinear(x, y, z, xy)
    assert np.array_equal(got, want, equal_nan=True)
    # through the terrain's own entry point, with a list of points and a single point
    grid = HeightGrid(x, y, z, None, 0)
    assert np.array_equal(_bilinear(grid, xy[:10].tolist()), want[:10])
    assert np.array_equal(_bilinear(grid, xy[3]), want[3:4])

"""Numba kernel of terrain screening's crest search over a height grid (:mod:`.terrain`).

Per straight path source -> point: the profile sample with the largest Fresnel parameter
``nu = h sqrt(d / (d1 d2))`` on the given samples t0 (fractions of the path), then twice on 33 samples
between the best one's neighbours; the height is the terrain mesh's (bilinear on the grid, the point
clamped to the domain's xy box first), the arithmetic is that of :func:`.terrain.main_crests`'s numpy
version in the same order (bit-identical results, tests/diffraction/test_terrain_batch.py). Self-contained:
the kernel calls no function from another module (numba's cache would not notice a change there).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from bentray.engine.constants import NJIT_FLAGS, PARALLEL_FLAGS

__all__ = ["CrestPaths", "GridTerrain", "crest_search"]

REFINE_SAMPLES = 33  # samples of each refinement between the best sample's neighbours


class GridTerrain(NamedTuple):
    """A height grid as the mesh sees it: x (nx,), y (ny,) strictly increasing (m), z (ny, nx) heights
    (m), box (4,) = x_min, y_min, x_max, y_max of the domain (points are clamped to it first)."""

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    box: np.ndarray


class CrestPaths(NamedTuple):
    """Straight paths from one source: src (3,), dxy (N, 2) plan offsets point - source, dz (N,) height
    differences, d (N,) lengths (m)."""

    src: np.ndarray
    dxy: np.ndarray
    dz: np.ndarray
    d: np.ndarray


@nb.njit(**NJIT_FLAGS)
def _right(a: np.ndarray, v: float) -> int:
    """np.searchsorted(a, v, side="right")."""
    lo = 0
    hi = a.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] <= v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@nb.njit(**NJIT_FLAGS)
def _height(g: GridTerrain, px: float, py: float) -> float:
    """Bilinear height at (px, py) clamped to the box (engine/mesh/terrain.py's _bilinear, same order)."""
    px = min(max(px, g.box[0]), g.box[2])
    py = min(max(py, g.box[1]), g.box[3])
    x, y, z = g.x, g.y, g.z
    i = min(max(_right(x, px) - 1, 0), x.shape[0] - 2)
    j = min(max(_right(y, py) - 1, 0), y.shape[0] - 2)
    tx = (px - x[i]) / (x[i + 1] - x[i])
    ty = (py - y[j]) / (y[j + 1] - y[j])
    return ((1.0 - tx) * (1.0 - ty) * z[j, i] + tx * (1.0 - ty) * z[j, i + 1]
            + (1.0 - tx) * ty * z[j + 1, i] + tx * ty * z[j + 1, i + 1])  # fmt: skip


@nb.njit(**NJIT_FLAGS)
def _sample_t(t0: np.ndarray, k: int, refine: bool, lo: float, hi: float, step: float) -> float:
    """Sample k: t0[k], or np.linspace(lo, hi, REFINE_SAMPLES)[k] with numpy's arithmetic."""
    if not refine:
        return t0[k]
    if k == REFINE_SAMPLES - 1:
        return hi
    if step == 0.0:
        return (float(k) / (REFINE_SAMPLES - 1)) * (hi - lo) + lo
    return float(k) * step + lo


@nb.njit(**PARALLEL_FLAGS)
def crest_search(g: GridTerrain, paths: CrestPaths, t0: np.ndarray, crest: np.ndarray, excess: np.ndarray) -> None:
    """crest[p] (N, 3): the main crest of path p (module docstring); excess[p] its height above the straight
    path (m). t0 (S,) the first samples (fractions in (0, 1))."""
    sx, sy, sz = paths.src[0], paths.src[1], paths.src[2]
    for p in nb.prange(paths.d.shape[0]):
        dx, dy, dz, d = paths.dxy[p, 0], paths.dxy[p, 1], paths.dz[p], paths.d[p]
        lo = 0.0
        hi = 0.0
        step = 0.0
        for it in range(3):
            refine = it > 0
            m = REFINE_SAMPLES if refine else t0.shape[0]
            best = -np.inf
            jb = 0
            seen_nan = False
            for k in range(m):  # np.argmax: the first maximum, or the first NaN
                t = _sample_t(t0, k, refine, lo, hi, step)
                z_line = sz + t * dz
                e = _height(g, sx + t * dx, sy + t * dy) - z_line
                nu = e * math.sqrt(d / (t * d * (1.0 - t) * d))
                if math.isnan(nu):
                    if not seen_nan:
                        seen_nan = True
                        jb = k
                elif not seen_nan and nu > best:
                    best = nu
                    jb = k
            t = _sample_t(t0, jb, refine, lo, hi, step)
            px, py = sx + t * dx, sy + t * dy
            z_line = sz + t * dz
            e = _height(g, px, py) - z_line
            crest[p, 0] = px
            crest[p, 1] = py
            crest[p, 2] = z_line + e
            excess[p] = e
            t_lo = _sample_t(t0, max(jb - 1, 0), refine, lo, hi, step)
            t_hi = _sample_t(t0, min(jb + 1, m - 1), refine, lo, hi, step)
            lo, hi = t_lo, t_hi
            step = (hi - lo) / (REFINE_SAMPLES - 1)

"""Terrain screening in batches (engine/diffraction/terrain.py, a batch of edges per call) against the
per-point loop it replaced (kept here as the reference: one crest search and one single-edge
:func:`edge_paths` call per point). Same levels to 1e-9 dB and the same screened points, with straight and
curved legs (a linear-c fit of a refracting, wind-like effective sound speed), over a terrain with two
ridges of different heights, a vertical path and open paths."""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine.diffraction.legs import circular_legs, fit_linear_c
from bentray.engine.diffraction.paths import GroundSide, edge_paths
from bentray.engine.diffraction.terrain import screen_pressure
from bentray.engine.diffraction.wedge import Edge

F = np.array([125.0, 250.0, 500.0, 1000.0])
C0 = 340.0
SRC = np.array([-300.0, 5.0, 2.0])


def _terrain(xy: np.ndarray) -> np.ndarray:
    xy = np.asarray(xy, float)
    x, y = xy[:, 0], xy[:, 1]
    return 25.0 * np.exp(-(((x - 0.0) / 60.0) ** 2)) + 12.0 * np.exp(-(((x - 250.0) / 30.0) ** 2)) * (1 + 0.002 * y)


def _curved(a: np.ndarray, b: np.ndarray):
    def c_eff(p: np.ndarray, e: np.ndarray) -> np.ndarray:
        return 340.0 - 0.03 * p[:, 2] + 1.2 * np.log1p(np.abs(p[:, 2]) / 0.1) * e[:, 0] / 10.0

    ca, g = fit_linear_c(c_eff, a, b)
    return circular_legs(a, b, ca, g)


def _loop(height, src, pts, f_hz, c_ref, sigma, legs, samples=256):
    """The per-point implementation that terrain.py had before the batches (2026-12-02)."""
    n_f, n = len(f_hz), pts.shape[0]
    energy = np.zeros((n_f, n))
    p = np.zeros((n_f, n), complex)
    screened = np.zeros(n, bool)
    t = np.linspace(0.0, 1.0, samples + 2)[1:-1]
    src_ground = GroundSide(float(height(src[None, :2])[0]), sigma)
    for i, rec in enumerate(pts):
        dxy = rec[:2] - src[:2]
        horizontal = float(np.hypot(*dxy))
        if horizontal <= 0.0:
            continue
        d = float(np.linalg.norm(rec - src))
        tt = t
        for _ in range(3):
            xy = src[:2] + tt[:, None] * dxy
            z_line = src[2] + tt * (rec[2] - src[2])
            excess = np.asarray(height(xy), float) - z_line
            nu = excess * np.sqrt(d / (tt * d * (1.0 - tt) * d))
            j = int(np.argmax(nu))
            lo, hi = tt[max(j - 1, 0)], tt[min(j + 1, tt.size - 1)]
            best = (xy[j].copy(), float(z_line[j] + excess[j]), float(excess[j]))
            tt = np.linspace(lo, hi, 33)
        if not best[2] > 0.0:
            continue
        screened[i] = True
        u = dxy / horizontal
        crest = np.array([best[0][0], best[0][1], best[1]])
        edge = Edge(crest, np.array([-u[1], u[0], 0.0]), np.array([0.0, 0.0, -1.0]), 2.0)
        rec_ground = GroundSide(float(height(rec[None, :2])[0]), sigma)
        parts = edge_paths(edge, src, rec[None, :], f_hz, c_ref, src_ground, rec_ground, legs, geometric=True)
        energy[:, i] = (np.abs(parts[:, :, 0]) ** 2).sum(axis=0)
        p[:, i] = parts[:, :, 0].sum(axis=0)
    return energy, p, screened


def _points() -> np.ndarray:
    rng = np.random.default_rng(7)
    n = 90
    pts = np.column_stack([rng.uniform(-250, 600, n), rng.uniform(-80, 80, n), rng.uniform(0.5, 60, n)])
    pts[:, 2] += _terrain(pts[:, :2])
    pts[0] = [SRC[0], SRC[1], 40.0]  # vertical path: not screened
    pts[1] = [-200.0, 5.0, 10.0]  # before the first ridge: open
    return pts


@pytest.mark.parametrize("legs", [None, _curved], ids=["straight", "curved"])
@pytest.mark.parametrize("sigma", [2e5, None], ids=["grass", "rigid"])
def test_batches_equal_the_per_point_loop(legs, sigma) -> None:
    pts = _points()
    e0, p0, s0 = _loop(_terrain, SRC, pts, F, C0, sigma, legs)
    e1, p1, s1 = screen_pressure(_terrain, SRC, pts, F, C0, sigma, legs)
    assert np.array_equal(s0, s1) and 20 < s0.sum() < len(pts) - 5 and not s0[0] and not s0[1]
    on = s0
    assert np.all(e1[:, ~on] == 0.0) and np.all(p1[:, ~on] == 0.0)
    db = np.abs(10 * np.log10(e1[:, on] / e0[:, on]))
    db_p = np.abs(10 * np.log10(np.abs(p1[:, on]) ** 2 / np.abs(p0[:, on]) ** 2))
    print(f"\n max |dB| energy {db.max():.2e}, coherent {db_p.max():.2e}")
    assert db.max() < 1e-9 and db_p.max() < 1e-9
    assert np.abs(p1 - p0).max() <= 1e-9 * np.abs(p0).max()


def test_numba_crest_search_equals_numpy_on_a_height_grid() -> None:
    """The Numba crest search (engine/diffraction/crests.py) on a HeightGrid against the numpy search with
    the mesh's own height function (terrain_height_function: clamped bilinear): bit-identical crests."""
    from bentray.engine.diffraction.crests import GridTerrain
    from bentray.engine.diffraction.terrain import main_crests
    from bentray.engine.mesh.terrain import terrain_height_function
    from bentray.engine.surfaces import HeightGrid

    gx = np.linspace(-400.0, 700.0, 111)
    gy = np.linspace(-120.0, 120.0, 25)
    xx, yy = np.meshgrid(gx, gy)
    grid = HeightGrid(gx, gy, _terrain(np.column_stack([xx.ravel(), yy.ravel()])).reshape(xx.shape))
    lo, hi = np.array([-390.0, -100.0, 0.0]), np.array([690.0, 100.0, 300.0])
    height = terrain_height_function(grid, lo, hi)
    pts = _points()
    pts[2] = [800.0, 150.0, 30.0]  # outside the box: heights clamped
    pts[3] = SRC  # the source itself: 0 / 0 (NaN) in nu
    gt = GridTerrain(gx, gy, grid.z, np.array([lo[0], lo[1], hi[0], hi[1]]))
    c0, e0 = main_crests(height, SRC, pts, 256)
    c1, e1 = main_crests(height, SRC, pts, 256, gt)
    assert np.array_equal(np.isnan(e0), np.isnan(e1)) and np.isnan(e0[3])
    ok = np.isfinite(e0)
    assert np.array_equal(e0[ok], e1[ok]) and np.array_equal(c0[ok], c1[ok])
    assert 20 < np.count_nonzero(e0[ok] > 0) < ok.sum()

"""Terrain screening: a level for the points that neither the beams nor the building/barrier diffraction
reach, behind hills (the diffraction stage does not use terrain crests as edges).

Per (source, point) with no level: the terrain profile along the vertical plane through both is sampled
(``TERRAIN_SCREEN_SAMPLES`` points); the main obstruction is the sample with the largest
frequency-independent Fresnel parameter ``nu = h sqrt(d / (d1 d2))`` (h the terrain's height above the
straight source-point line there, d1, d2 the distances to the ends; Deygout's main-edge rule, as
ISO 9613-2 and the engineering methods choose the screening edge). There the hill is replaced by a thin
rigid screen (a half-plane) across the path, horizontal, up to the crest height, and the level is the UTD
four-path model of :func:`bentray.engine.diffraction.paths.edge_paths` (source and receiver images in the
local ground under each end, curved legs in refracting air), the combinations added as energies in
incoherent maps and as pressures in coherent ones. Only the main edge is used (no second crest), and the
crest's rounding is not modelled: a thin screen diffracts more than a rounded hill, so behind broad hills
the level is an upper estimate. Points already carrying a level are untouched, so nothing is counted
twice.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bentray.engine.acoustics.weighting import a_weighting_db
from bentray.engine.diffraction.crests import CrestPaths, GridTerrain, crest_search
from bentray.engine.diffraction.paths import GroundSide, LegModel, edge_paths
from bentray.engine.diffraction.wedge import Edge
from bentray.engine.field_sources import COMBINATION, DIFFRACTED, NONE, Contribution, combine

__all__ = ["TERRAIN_SCREEN_SAMPLES", "main_crests", "screen_pressure", "stage_terrain_screening"]

TERRAIN_SCREEN_SAMPLES = 256  # profile samples per path (4 m on 1 km), the best refined twice 16x finer


SCREEN_CHUNK = 2048  # points per batch (the crest search holds chunk x samples profile points)


def _rows_linspace(lo: np.ndarray, hi: np.ndarray, num: int) -> np.ndarray:
    """(N, num): np.linspace(lo[i], hi[i], num) per row, with numpy's scalar arithmetic (same bits)."""
    div = num - 1
    step = (hi - lo) / div
    y = np.arange(num, dtype=float)[None, :] * step[:, None]
    zero = step == 0
    if np.any(zero):
        y[zero] = (np.arange(num, dtype=float)[None, :] / div) * (hi - lo)[zero, None]
    y += lo[:, None]
    y[:, -1] = hi
    return y


def main_crests(
    height: Callable[[np.ndarray], np.ndarray],
    src: np.ndarray,
    pts: np.ndarray,
    samples: int,
    grid: GridTerrain | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(crest (N, 3), excess (N,)): per straight path src (3,) -> pts (N, 3) the profile sample with the
    largest Fresnel parameter nu (module docstring), found on ``samples`` samples and refined twice on 33
    between its neighbours; excess is its height above the straight line (m; NaN for a vertical path).

    grid: the terrain as a height grid (the same heights as ``height``): the search then runs in the
    Numba kernel :func:`.crests.crest_search` (parallel over the paths, bit-identical); else in numpy."""
    n = pts.shape[0]
    dxy = pts[:, :2] - src[:2]
    dz = pts[:, 2] - src[2]
    d = np.linalg.norm(pts - src, axis=1)
    t0 = np.linspace(0.0, 1.0, samples + 2)[1:-1]
    if grid is not None:
        crest = np.empty((n, 3))
        best = np.empty(n)
        crest_search(grid, CrestPaths(src, np.ascontiguousarray(dxy), dz, d), t0, crest, best)
        return crest, np.where(np.hypot(dxy[:, 0], dxy[:, 1]) > 0.0, best, np.nan)
    rows = np.arange(n)
    tt = np.broadcast_to(t0, (n, samples))
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(3):  # the sampled maximum, then twice refined between its neighbours
            xy = src[:2] + tt[:, :, None] * dxy[:, None, :]
            z_line = src[2] + tt * dz[:, None]
            excess = np.asarray(height(xy.reshape(-1, 2)), float).reshape(tt.shape) - z_line
            nu = excess * np.sqrt(d[:, None] / (tt * d[:, None] * (1.0 - tt) * d[:, None]))
            j = np.argmax(nu, axis=1)
            lo = tt[rows, np.maximum(j - 1, 0)]
            hi = tt[rows, np.minimum(j + 1, tt.shape[1] - 1)]
            crest = np.column_stack([xy[rows, j], z_line[rows, j] + excess[rows, j]])
            best = excess[rows, j]
            tt = _rows_linspace(lo, hi, 33)
    best = np.where(np.hypot(dxy[:, 0], dxy[:, 1]) > 0.0, best, np.nan)
    return crest, best


def screen_pressure(
    height: Callable[[np.ndarray], np.ndarray],
    src: np.ndarray,
    pts: np.ndarray,
    f_hz: np.ndarray,
    c_ref: float,
    flow_resistivity: float | None,
    legs: LegModel | None = None,
    samples: int = TERRAIN_SCREEN_SAMPLES,
    grid: GridTerrain | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(energy (F, N) |p|^2 re 1 m summed over the four combinations, p (F, N) complex coherent sum,
    screened (N,) bool: a crest obstructs the straight path) for points pts (N, 3) from src (3,).

    height(xy (M, 2)) -> (M,) ground height, metres, world frame; f_hz (F,); c_ref m/s; grid: the same
    terrain as a height grid (the crest search in Numba, :func:`main_crests`). Points go in batches of
    SCREEN_CHUNK: the crest search and the four paths over each point's own crest (a batch of edges) are
    whole-array operations."""
    src = np.asarray(src, float)
    pts = np.atleast_2d(np.asarray(pts, float))
    f_hz = np.atleast_1d(np.asarray(f_hz, float))
    n_f, n = len(f_hz), pts.shape[0]
    energy = np.zeros((n_f, n))
    p = np.zeros((n_f, n), complex)
    screened = np.zeros(n, bool)
    src_ground = GroundSide(float(height(src[None, :2])[0]), flow_resistivity)
    for a in range(0, n, SCREEN_CHUNK):
        chunk = pts[a : a + SCREEN_CHUNK]
        crest, excess = main_crests(height, src, chunk, samples, grid)
        on = excess > 0.0
        if not np.any(on):
            continue
        idx = a + np.nonzero(on)[0]
        screened[idx] = True
        rec = chunk[on]
        dxy = rec[:, :2] - src[:2]
        horizontal = np.hypot(dxy[:, 0], dxy[:, 1])
        u = dxy / horizontal[:, None]
        m = rec.shape[0]
        edge = Edge(
            crest[on], np.column_stack([-u[:, 1], u[:, 0], np.zeros(m)]), np.tile([0.0, 0.0, -1.0], (m, 1)), 2.0
        )
        rec_ground = GroundSide(np.asarray(height(rec[:, :2]), float), flow_resistivity)
        parts = edge_paths(edge, src, rec, f_hz, c_ref, src_ground, rec_ground, legs, geometric=True)
        energy[:, idx] = (np.abs(parts) ** 2).sum(axis=0)
        p[:, idx] = parts.sum(axis=0)
    return energy, p, screened


def grid_terrain(job: Any, surfaces: Any) -> GridTerrain | None:
    """The scene's terrain as a GridTerrain when it is a height grid (the heights of
    engine/mesh/terrain.py's terrain_height_function), else None (a TIN: the crest search stays numpy)."""
    from bentray.engine.surfaces import HeightGrid

    terrain = getattr(surfaces, "terrain", None)
    if not isinstance(terrain, HeightGrid):
        return None
    lo = np.asarray(job.scene.box.min, float)
    hi = np.asarray(job.scene.box.max, float)
    x, y, z = (np.ascontiguousarray(np.asarray(a, float)) for a in (terrain.x, terrain.y, terrain.z))
    return GridTerrain(x, y, z, np.array([lo[0], lo[1], hi[0], hi[1]]))


def _sources_sum(
    job: Any, setup: Any, pts: np.ndarray, f_hz: np.ndarray, c_ref: float, height: Any, sigma: float | None,
    legs: LegModel, coherent: bool, grid: GridTerrain | None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray]:  # fmt: skip
    n_f, n = len(f_hz), pts.shape[0]
    rel = np.zeros((n_f, n))
    powered = np.zeros((n_f, n)) if setup.powers is not None else None
    p_sum = np.zeros((n_f, n), complex) if coherent else None
    screened = np.zeros(n, bool)
    for s, source in enumerate(job.sources):
        src = np.asarray(source.position, float)
        e, p, scr = screen_pressure(height, src, pts, f_hz, c_ref, sigma, legs, grid=grid)
        r = np.abs(p) ** 2 if coherent else e
        rel += r
        if powered is not None:
            powered += r * (np.asarray(setup.powers[s], float)[:, None] / (4.0 * np.pi))
        if p_sum is not None:
            p_sum += p
        screened |= scr
    return rel, powered, p_sum, screened


def _fill_receivers(
    job: Any,
    setup: Any,
    receivers: Any,
    c_ref: float,
    height: Any,
    sigma: float | None,
    legs: LegModel,
    grid: GridTerrain | None,
) -> int:
    """The same for receivers.csv rows without a level (field_source 0); returns how many were filled."""
    from bentray.engine.field_sources import combine_receiver_rows

    rows = receivers.rows
    todo = np.array([i for i, r in enumerate(rows) if r.get("field_source", NONE) == NONE], int)
    if todo.size == 0:
        return 0
    f_hz = np.asarray(receivers.stats["frequencies_hz"], float)
    labels = [c[len("tl_inc_") : -2] for c in receivers.columns if c.startswith("tl_inc_")]
    pts = np.asarray(setup.receivers_xyz, float)[todo]
    conts = []
    filled = np.zeros(len(rows), bool)
    for coherent in (True, False):
        rel_t, pow_t, _, screened = _sources_sum(job, setup, pts, f_hz, c_ref, height, sigma, legs, coherent, grid)
        rel = np.zeros((len(f_hz), len(rows)))
        rel[:, todo] = rel_t
        weight = np.zeros_like(rel)
        weight[:, todo[screened]] = 1.0
        powered = None
        if pow_t is not None:
            powered = np.zeros_like(rel)
            powered[:, todo] = pow_t
        conts.append(Contribution(DIFFRACTED, rel, weight, powered=powered))
        filled[todo[screened & (rel_t.max(axis=0) > 0)]] = True
    old = [r.get("field_source", NONE) for r in rows]
    combine_receiver_rows(rows, labels, np.asarray(a_weighting_db(f_hz), float), [conts[0]], [conts[1]])
    for i, r in enumerate(rows):
        r["field_source"] = DIFFRACTED if filled[i] else int(old[i])
    return int(filled.sum())


def stage_terrain_screening(
    job: Any, profile: Any, wind: Any, surfaces: Any, setup: Any, field_arrays: Any, receivers: Any, log: Any
) -> dict[str, Any] | None:
    """Fill the points without a level behind terrain crests (module docstring), in place; returns the
    report's ``terrain_screening`` section (None when skipped; the reason is in log.stages)."""
    from bentray.engine.diffraction.stage import _field_points, _ground, _leg_model

    if surfaces is None or surfaces.terrain is None:
        log.stages["terrain_screening"] = "skipped: no terrain (flat ground shadows nothing)"
        return None
    if field_arrays is None or "field_source" not in field_arrays.arrays:
        log.stages["terrain_screening"] = "skipped: no beam field with per-point source codes"
        return None
    t0 = time.perf_counter()
    height, sigma = _ground(job, surfaces)
    c_ref = float(profile.c_ref)
    legs, legs_how = _leg_model(profile, wind, c_ref)
    spec = job.field
    labels = list(spec.labels)
    f_hz = np.asarray(spec.frequencies_hz, float)
    code = np.asarray(field_arrays.arrays["field_source"]).reshape(-1).copy()
    solid = np.asarray(field_arrays.arrays["inside_solid"], bool).reshape(-1)
    tl = np.stack([np.asarray(field_arrays.arrays[f"tl_{lab}hz"], float).reshape(-1) for lab in labels])
    missing = ~np.isfinite(tl) & ~solid[None, :]  # (F, V): bands without a level at points in the air
    todo = np.flatnonzero(missing.any(axis=0))
    out: dict[str, Any] = {"points_without_level": int(todo.size), "legs": legs_how}
    if todo.size == 0:
        log.stages["terrain_screening"] = "skipped: every point in the air already has a level"
        return None
    coherent = spec.mode != "incoherent"
    pts = _field_points(job, field_arrays, height)[todo]
    grid = grid_terrain(job, surfaces)
    rel_t, pow_t, p_t, screened = _sources_sum(job, setup, pts, f_hz, c_ref, height, sigma, legs, coherent, grid)
    n_f, n_all = len(f_hz), code.size
    rel = np.zeros((n_f, n_all))
    rel[:, todo] = rel_t
    weight = np.zeros((n_f, n_all))
    weight[:, todo[screened]] = missing[:, todo[screened]]  # only the bands that had no level
    powered = None
    if pow_t is not None:
        powered = np.zeros((n_f, n_all))
        powered[:, todo] = pow_t
    # levels only (p=None): a coherent map's p_re/p_im keep the beam/diffraction pressures, and the
    # levels merged earlier as energies are not recomputed from |p|^2
    contrib = Contribution(DIFFRACTED, rel, weight, powered=powered)
    combine(field_arrays.arrays, labels, np.asarray(a_weighting_db(f_hz), float), [contrib], coherent, solid)
    filled = todo[screened & (rel_t.max(axis=0) > 0)]
    partial = missing[:, filled].all(axis=0)  # every band came from the screen, else it is a combination
    code[filled] = np.where(partial | (code[filled] == NONE), DIFFRACTED, COMBINATION)
    field_arrays.arrays["field_source"] = code.reshape(field_arrays.grid.shape)
    if receivers is not None and setup.receivers_xyz is not None:
        out["receivers_filled"] = _fill_receivers(job, setup, receivers, c_ref, height, sigma, legs, grid)
    out["points_filled"] = int(filled.size)
    out["points_still_without_level"] = int(todo.size - filled.size)
    out["seconds"] = time.perf_counter() - t0
    log.timings["terrain_screening"] = out["seconds"]
    log.stages["terrain_screening"] = (
        f"ran: {filled.size} of {todo.size} points without a level filled by a thin screen at the main terrain "
        f"crest of each path (UTD, four paths, legs {legs_how})"
    )
    return out

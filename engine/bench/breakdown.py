"""Table 3: where the trace time goes (curve set-up, face intersections, the rest), per scene and curve.

Method (variants, not instrumentation: timers inside the kernel would cost more than what they measure):
1. a recording walk (the traversal loop of kernels/traverse.py without nudging, paths or field; a ray
   that finds no exit just stops) stores the state at every cell entry: cell, entry point, tangent,
   entry face;
2. four replay kernels run over those entries in parallel, each doing one more phase than the last:
   ``load`` (read the entry: the memory streaming every replay pays), ``setup`` (+ the cell's media at
   the entry point and curves.setup), ``+ exit`` (+ curves.find_exit over the cell's faces: closed-form
   quadratics for the parabolic and circular curves, bisection for n-linear), ``+ advance`` (+ the
   travel time and the curve's end state, curves.time_at / evaluate);
3. the real tracer (engine/tracer.py) on the same rays gives the total.
Set-up = t(setup) - t(load); face intersections = t(+exit) - t(setup); advance = t(+advance) - t(+exit);
other (walking to the neighbour, reflections, bookkeeping, memory stalls of the real loop) = total -
(t(+advance) - t(load)).
Each time is the best of the warm runs. The replays touch the cells in the same order as the rays do,
so their memory behaviour is close to the real loop's but not identical: the split is an estimate, the
total is measured.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numba as nb
import numpy as np

from bentray.engine.bench.common import Section, Table, best_time, fmt, on_timing_threads
from bentray.engine.bench.scene_meshes import SCENE_NAMES, SceneMesh, SceneUnavailable
from bentray.engine.constants import (
    BOUNDARY_REFLECT,
    CURVE_CODES,
    NJIT_FLAGS,
    ON_FACE_REL,
    PARALLEL_FLAGS,
)
from bentray.engine.kernels import curves
from bentray.engine.kernels.llvm_inline import njit_inline
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.tracer import trace

__all__ = ["record_entries", "phase_times", "run"]

COLUMNS = [
    "scene",
    "curve",
    "cells",
    "rays",
    "segments",
    "total_s",
    "setup_s",
    "face_intersections_s",
    "advance_s",
    "other_s",
    "setup_pct",
    "face_intersections_pct",
    "advance_pct",
    "other_pct",
    "ns_per_segment",
    "note",
]


@nb.njit(**NJIT_FLAGS)
def _media_at(media_ref, ref_point, gradient, cell, x):
    return (
        media_ref[cell]
        + gradient[cell, 0] * (x[0] - ref_point[cell, 0])
        + gradient[cell, 1] * (x[1] - ref_point[cell, 1])
        + gradient[cell, 2] * (x[2] - ref_point[cell, 2])
    )


class Entries(NamedTuple):
    """Cell-entry records, flattened: cell (E,) int64, entry face (E,) int64 (-1: none), entry point x
    (E, 3) m, unit tangent d (E, 3)."""

    cell: np.ndarray
    face: np.ndarray
    x: np.ndarray
    d: np.ndarray


class WalkParams(NamedTuple):
    """The recording walk's limits: curve (CURVE_* code), c_ref (m/s), max_time (s), max_reflections, cap
    (entries stored per ray at most)."""

    curve: int
    c_ref: float
    max_time: float
    max_reflections: int
    cap: int


@njit_inline
def _mirror(planes, cell, face, d):
    """d (3,) reflected specularly off face ``face`` of ``cell`` and renormalised, in place."""
    dot = d[0] * planes[cell, face, 0] + d[1] * planes[cell, face, 1] + d[2] * planes[cell, face, 2]
    nrm = 0.0
    for j in range(3):
        d[j] -= 2.0 * dot * planes[cell, face, j]
        nrm += d[j] * d[j]
    for j in range(3):
        d[j] /= math.sqrt(nrm)


@nb.njit(**NJIT_FLAGS)
def _record_ray(mesh, wp, x, d, cell, ent, first):
    """Walk one ray from x, d (3,) in ``cell`` (x, d overwritten), storing each cell entry into ``ent``
    from slot ``first`` on (at most wp.cap); stops where it finds no exit, at max_time, at an open face or
    past max_reflections. Returns the number of entries stored. (Called, not inlined: inlined into the
    prange loop of _record the stores into ent.d came out as zeros.)"""
    planes, neighbours, gradient, size = mesh.planes, mesh.neighbours, mesh.gradient, mesh.size
    xn = np.empty(3)
    dn = np.empty(3)
    cs = np.zeros(curves.CS_SIZE)
    entry = -1
    t = 0.0
    refl = 0
    k = 0
    while cell >= 0 and k < wp.cap:
        e = first + k
        ent.cell[e] = cell
        ent.face[e] = entry
        for j in range(3):
            ent.x[e, j] = x[j]
            ent.d[e, j] = d[j]
        k += 1
        m0 = _media_at(mesh.media_ref, mesh.ref_point, gradient, cell, x)
        if not curves.setup(wp.curve, m0, gradient[cell], d, cs):
            break
        face, param = curves.find_exit(
            wp.curve, cs, x, d, planes[cell], neighbours[cell], entry, ON_FACE_REL * size[cell], size[cell]
        )
        if face < 0:
            break
        dt = curves.time_at(wp.curve, cs, param, wp.c_ref)
        if t + dt >= wp.max_time:
            break
        curves.evaluate(wp.curve, cs, x, d, param, xn, dn)
        t += dt
        for j in range(3):
            x[j] = xn[j]
            d[j] = dn[j]
        nxt = neighbours[cell, face]
        if nxt >= 0:
            entry = mesh.neighbour_face[cell, face]
            cell = nxt
        elif nxt == BOUNDARY_REFLECT and refl < wp.max_reflections:
            _mirror(planes, cell, face, d)
            refl += 1
            entry = face
        else:
            break
    return k


@nb.njit(**PARALLEL_FLAGS)
def _record(mesh, wp, origins, directions, start_cells, ent, counts):
    """Entry states of every ray's cells (mesh: CellMesh; wp: WalkParams), ray i in slots
    [i cap, (i + 1) cap) of ``ent`` (Entries); counts[i] = entries stored."""
    for k in nb.prange(origins.shape[0]):
        i = np.int64(k)  # one signature of _record_ray: the prange index is uint64 in the parallel body
        x = origins[i].copy()
        d = directions[i] / math.sqrt(directions[i, 0] ** 2 + directions[i, 1] ** 2 + directions[i, 2] ** 2)
        counts[i] = _record_ray(mesh, wp, x, d, start_cells[i], ent, i * wp.cap)


@nb.njit(**PARALLEL_FLAGS)
def _replay(phase, mesh, curve, c_ref, ent, out):
    """Replay the entries ``ent`` (Entries) on ``mesh`` (CellMesh) up to ``phase``: -1 reads the entry only;
    0: + media and setup; 1: + find_exit; 2: + time_at and evaluate. out[e] keeps each result alive (no
    dead-code elimination)."""
    planes, neighbours, gradient, size = mesh.planes, mesh.neighbours, mesh.gradient, mesh.size
    n = ent.cell.shape[0]
    n_chunks = 64
    for ch in nb.prange(n_chunks):
        cs = np.zeros(curves.CS_SIZE)
        xn = np.empty(3)
        dn = np.empty(3)
        for e in range(ch * n // n_chunks, (ch + 1) * n // n_chunks):
            cell = ent.cell[e]
            x = ent.x[e]
            d = ent.d[e]
            if phase < 0:
                out[e] = x[0] + d[2] + cell + ent.face[e]
                continue
            m0 = _media_at(mesh.media_ref, mesh.ref_point, gradient, cell, x)
            ok = curves.setup(curve, m0, gradient[cell], d, cs)
            acc = cs[0] + cs[3] + cs[6]
            if ok and phase >= 1:
                face, param = curves.find_exit(
                    curve, cs, x, d, planes[cell], neighbours[cell], ent.face[e], ON_FACE_REL * size[cell], size[cell]
                )
                if face >= 0:
                    acc += param + face
                if phase >= 2 and face >= 0:
                    acc += curves.time_at(curve, cs, param, c_ref)
                    acc += curves.evaluate(curve, cs, x, d, param, xn, dn) + xn[0] + dn[2]
            out[e] = acc


def record_entries(
    mesh: CellMesh,
    curve: str,
    c_ref: float,
    origins: np.ndarray,
    directions: np.ndarray,
    start_cells: np.ndarray,
    *,
    max_time_s: float,
    max_reflections: int,
    cap: int = 100_000,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cell-entry states of the rays, flattened in ray order: cell (E,) int64, entry face (E,) int64,
    entry point (E, 3) m, unit tangent (E, 3). At most ``cap`` entries per ray."""
    n = len(origins)
    ent = Entries(np.zeros(n * cap, dtype=np.int64), np.zeros(n * cap, dtype=np.int64), np.zeros((n * cap, 3)),
                  np.zeros((n * cap, 3)))  # fmt: skip
    counts = np.zeros(n, dtype=np.int64)
    wp = WalkParams(CURVE_CODES[curve], float(c_ref), float(max_time_s), int(max_reflections), int(cap))
    _record(
        mesh,
        wp,
        np.ascontiguousarray(origins, dtype=np.float64),
        np.ascontiguousarray(directions, dtype=np.float64),
        np.ascontiguousarray(start_cells, dtype=np.int64),
        ent,
        counts,
    )
    keep = (np.arange(cap)[None, :] < counts[:, None]).reshape(-1)
    return ent.cell[keep], ent.face[keep], ent.x[keep], ent.d[keep]


def phase_times(
    mesh: CellMesh,
    curve: str,
    c_ref: float,
    origins: np.ndarray,
    directions: np.ndarray,
    start_cells: np.ndarray,
    *,
    max_time_s: float,
    max_reflections: int,
    repeats: int = 3,
    min_total_s: float = 0.3,
) -> dict[str, Any]:
    """Total trace time and its split (module docstring), seconds, best of ``repeats`` warm runs each."""
    kw: dict[str, Any] = {"max_time_s": max_time_s, "max_reflections": max_reflections}
    trace(mesh, curve, c_ref, origins[:1], directions[:1], start_cells[:1], **kw)  # compile
    total, res = best_time(
        lambda: trace(mesh, curve, c_ref, origins, directions, start_cells, **kw), repeats, min_total_s
    )
    cap = int(res.steps.max()) + 2  # the recording walk never takes more steps than the real one (+ a margin)
    ent = record_entries(mesh, curve, c_ref, origins, directions, start_cells, cap=cap, **kw)
    entries = Entries(*ent)
    out = np.empty(len(ent[0]))
    code = CURVE_CODES[curve]
    phases = []
    for phase in (-1, 0, 1, 2):

        def go(phase: int = phase) -> None:
            _replay(phase, mesh, code, float(c_ref), entries, out)

        go()  # compile / warm
        phases.append(best_time(go, repeats, min_total_s)[0])
    if not np.all(np.isfinite(out)):
        raise FloatingPointError("replay produced non-finite values")
    load, setup, exit_, advance = phases
    return {
        "total_s": total,
        "load_s": load,
        "setup_s": setup - load,
        "face_intersections_s": exit_ - setup,
        "advance_s": advance - exit_,
        "other_s": total - (advance - load),
        "segments": int(res.steps.sum()),
        "recorded_entries": int(len(ent[0])),
        "status": res.status_counts(),
    }


def _stratified_scene(count: int) -> SceneMesh:
    """The A-LD slab mesh (delta 1e-8) with an even fan over the sphere from (0, 0, 1.5): always available."""
    from bentray.engine.bench.baselines_probe import CASES
    from bentray.engine.bench.common import sphere_directions
    from bentray.engine.media import build_media
    from bentray.scenes.schema import Solver

    case = CASES["A-LD"]
    med = build_media(case.profile(), "parabolic", Solver(), np.array(case.domain_min), np.array(case.domain_max))
    src = np.asarray([case.source], float)
    return SceneMesh(
        "A-LD slabs",
        med.mesh,
        np.repeat(src, count, axis=0),
        sphere_directions(count),
        np.repeat(med.locate(src), count),
        float(med.stats["build_time_s"]),
        dict(med.stats),
    )


@on_timing_threads
def run(quick: bool, scene_cache: dict[str, Any] | None = None) -> Section:
    """Quick: A-LD slabs (200 rays) + desert (1,000 rays), one timed run each; full: A-LD slabs (1,000 rays) +
    every built-in scene (10,000 rays), best of 2+. ``scene_cache`` (key -> SceneMesh or SceneUnavailable)
    shares scene meshes with the other sections."""
    repeats, min_total = (1, 0.0) if quick else (2, 0.5)
    table = Table("table3_breakdown", "Table 3: time breakdown per scene and curve", COLUMNS)
    for sc in _scenes(quick, scene_cache if scene_cache is not None else {}):
        if isinstance(sc, tuple):
            for curve in ("parabolic", "n_linear"):
                table.add(scene=sc[0], curve=curve, note=f"skipped: {sc[1]}")
            continue
        for curve in ("parabolic", "n_linear"):
            _add_row(table, sc, curve, repeats, min_total)
    sec = Section("breakdown", "Time breakdown (Table 3)")
    sec.text.append(
        "Rays spread evenly over the sphere from the scene's first source (A-LD slabs: from 1.5 m), 10 s, at most "
        f"3 reflections; best of {repeats} warm run(s) (more for short runs in the full bench), {_threads()} numba "
        "threads. Phases timed by replaying the "
        "recorded cell entries with one more phase each time (module docstring of engine/bench/breakdown.py): "
        "set-up = media + curve constants; face intersections = exit search over the cell's faces (for n-linear "
        "this is the bisection); advance = travel time + end state; other = the rest of the real loop (walk to "
        "the neighbour, reflections, bookkeeping, memory). The split is an estimate (replays differ from the "
        "real loop in memory behaviour; a negative `other` means the replay cost more than its share), the total "
        "is measured."
    )
    nl = [r for r in table.rows if r["curve"] == "n_linear" and r["total_s"] != ""]
    for r in nl:
        par = next(p for p in table.rows if p["scene"] == r["scene"] and p["curve"] == "parabolic")
        sec.text.append(
            f"{r['scene']}: n-linear bisection {fmt(r['face_intersections_s'])} s "
            f"({fmt(r['face_intersections_pct'])} % of its time) vs parabolic quadratics "
            f"{fmt(par['face_intersections_s'])} s; total {fmt(r['total_s'] / par['total_s'])}x."
        )
    sec.tables.append(table)
    return sec


def _scenes(quick: bool, cache: dict[str, Any]) -> list[SceneMesh | tuple[str, str]]:
    """The A-LD slabs and the built-in scenes of run() (quick: desert only), built once into ``cache``; a
    scene that cannot be built is (name, reason)."""
    from bentray.engine.bench.scene_meshes import build_scene_mesh

    count = 1000 if quick else 10_000
    scenes: list[SceneMesh | tuple[str, str]] = [_stratified_scene(count // 5 if quick else count // 10)]
    for name in ("desert",) if quick else SCENE_NAMES:
        key = f"{name}/{count}"
        if key not in cache:
            try:
                cache[key] = build_scene_mesh(name, count)
            except SceneUnavailable as exc:
                cache[key] = exc
        item = cache[key]
        scenes.append((name, str(item)) if isinstance(item, SceneUnavailable) else item)
    return scenes


def _add_row(table: Table, sc: SceneMesh, curve: str, repeats: int, min_total: float) -> None:
    """Time one scene with one curve (phase_times: 10 s, 3 reflections) and add its row to ``table``."""
    mesh = sc.mesh if curve == "parabolic" else _requantify(sc, curve)
    p = phase_times(
        mesh,
        curve,
        340.0,
        sc.origins,
        sc.directions,
        sc.start_cells,
        max_time_s=10.0,
        max_reflections=3,
        repeats=repeats,
        min_total_s=min_total,
    )
    tot = p["total_s"]
    pct = {k: 100.0 * p[f"{k}_s"] / tot for k in ("setup", "face_intersections", "advance", "other")}
    table.add(
        scene=sc.name,
        curve=curve,
        cells=mesh.n_cells,
        rays=len(sc.origins),
        segments=p["segments"],
        total_s=tot,
        setup_s=p["setup_s"],
        face_intersections_s=p["face_intersections_s"],
        advance_s=p["advance_s"],
        other_s=p["other_s"],
        setup_pct=pct["setup"],
        face_intersections_pct=pct["face_intersections"],
        advance_pct=pct["advance"],
        other_pct=pct["other"],
        ns_per_segment=1e9 * tot / max(p["segments"], 1),
        note=f"lost {p['status']['lost']}",
    )


def _threads() -> int:
    return int(nb.get_num_threads())


def _requantify(sc: SceneMesh, curve: str) -> CellMesh:
    """The parabolic mesh's cells with media in the quantity of ``curve`` (n = sqrt(n^2), c = c_ref/n):
    same geometry, per-cell linear model of the new quantity by the chain rule at the reference point."""
    mesh = sc.mesh
    n = np.sqrt(mesh.media_ref)
    grad_n = mesh.gradient / (2.0 * n)[:, None]
    if curve == "n_linear":
        return mesh._replace(media_ref=n.copy(), gradient=grad_n)
    c = 340.0 / n
    return mesh._replace(media_ref=c, gradient=(-340.0 / (n * n))[:, None] * grad_n)

"""Measurement: media-mesh build time against cell count for the tets and terrain meshers (the fit of
``bentray.scenes.cost.MESH_SECONDS_PER_CELL``).

    python -m bentray.engine.bench.mesh_time [--repeat 1] [--quick]

Builds the media mesh of small jobs through the engine's own stages (``stage_profile``, ``stage_scene``,
``stage_mesh``), nothing traced: tets (a hot-spot profile, ``solver.representation`` "tets",
``d_min_m = d_max_m`` = d so the cell count follows V / d^3) and terrain (the builtin ridge with
``solver.d_max_m`` setting the horizontal spacing, and christmas with its 40 buildings). A first
unmeasured build compiles/warms every path. Prints one line per build (mesher, cells, seconds, seconds
per cell, and the cost model's estimate of the same build) and the least-squares fit ``t = a + b x
cells`` per mesher. A measurement script, not a test: numbers depend on the machine.
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import numpy as np


def _tets_job(side: float, d: float) -> dict[str, Any]:
    return {
        "name": f"tets-{side:g}-{d:g}",
        "scene": {"domain": {"min": [0, 0, 0], "max": [side, side, 0.5 * side]}, "ground": {"kind": "flat"}},
        "profile": {"kind": "hot_spot", "center": [0.5 * side, 0.5 * side, 10.0], "t_s": 330.0, "d0": 50.0},
        "sources": [{"position": [0.5 * side, 0.5 * side, 2.0]}],
        "rays": {"elevation_deg": {"min": -10, "max": 10, "count": 3}, "max_time_s": 1.0, "max_reflections": 1},
        "solver": {"representation": "tets", "d_min_m": d, "d_max_m": d},
        "outputs": ["report"],
    }


def _terrain_job(d_max: float | None, builtin: str = "ridge") -> dict[str, Any]:
    # d_min_m 0.01: the terrain mesher's default smallest layer (1 cm), stated so that d_max_m may be small
    solver: dict[str, Any] = {} if d_max is None else {"d_max_m": d_max, "d_min_m": 0.01}
    from bentray.scenes.library.registry import get_builtin

    source = [float(v) for v in get_builtin(builtin, "medium").sources[0]]
    return {
        "name": f"{builtin}-{d_max}",
        "scene": {"builtin": builtin, "resolution": "medium"},
        "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 0.1},
        "sources": [{"position": source}],
        "rays": {"elevation_deg": {"min": -10, "max": 10, "count": 3}, "max_time_s": 1.0, "max_reflections": 1},
        "solver": solver,
        "outputs": ["report"],
    }


def build_once(spec: dict[str, Any]) -> tuple[str, int, float, int]:
    """(representation, cells, seconds of profile + scene + mesh, points) of one job's media build."""
    from bentray.engine.stages import StageLog, stage_mesh, stage_profile, stage_profile_heights, stage_scene
    from bentray.scenes.schema import Job

    job = Job.model_validate(spec)
    log = StageLog()
    t0 = time.perf_counter()
    profile, wind = stage_profile(job, None, log)
    surfaces = stage_scene(job, None, log)
    profile = stage_profile_heights(job, profile, surfaces, log)
    media = stage_mesh(job, profile, surfaces, wind, log)
    seconds = time.perf_counter() - t0
    return media.representation, int(media.mesh.n_cells), seconds, int(media.stats.get("points", 0))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="media-mesh build time against cell count")
    parser.add_argument("--repeat", type=int, default=1, help="builds per size (the fastest is kept)")
    parser.add_argument("--quick", action="store_true", help="two sizes per mesher (a smoke run)")
    parser.add_argument("--only", choices=("tets", "terrain"), default=None, help="one mesher only")
    args = parser.parse_args(argv)
    from bentray.scenes.cost import estimate_mesh
    from bentray.scenes.schema import Job

    tets = [(400.0, d) for d in (40.0, 25.0, 16.0, 11.0, 8.0)]
    terrain: list[float | None] = [None, 20.0, 14.0, 10.0]
    if args.quick:
        tets, terrain = tets[:2], terrain[:2]
    if args.only == "tets":
        terrain = []
    elif args.only == "terrain":
        tets = []
    build_once(_tets_job(200.0, 50.0))  # warm: imports, numba compilation
    build_once(_terrain_job(None))
    rows: dict[str, list[tuple[int, float]]] = {"tets": [], "terrain": []}
    specs = [_tets_job(s, d) for s, d in tets] + [_terrain_job(d) for d in terrain]
    if terrain and not args.quick:
        specs.append(_terrain_job(None, "christmas"))  # 40 buildings: walls and roofs in the mesh
    for spec in specs:
        best = None
        for _ in range(max(args.repeat, 1)):
            rep, cells, secs, points = build_once(spec)
            best = secs if best is None else min(best, secs)
        assert best is not None
        rows.setdefault(rep, []).append((cells, best))
        est = estimate_mesh(Job.model_validate(spec))  # the cost model's estimate of the same build
        print(
            f"{rep:8s} {spec['name']:16s} cells {cells:>10,d} (points {points:>9,d})  {best:8.2f} s  "
            f"{1e6 * best / cells:6.2f} us/cell; estimate {est.cells:>12,.0f} cells {est.seconds:8.2f} s"
        )
    print(f"machine: {os.cpu_count()} CPUs; numba threads {os.environ.get('NUMBA_NUM_THREADS', 'default')}")
    for rep, data in rows.items():
        if len(data) < 2:
            continue
        x = np.array([c for c, _ in data], float)
        y = np.array([t for _, t in data], float)
        b, a = np.polyfit(x, y, 1)
        through0 = float(np.sum(x * y) / np.sum(x * x))
        print(
            f"fit {rep}: t = {a:.3f} s + {1e6 * b:.2f} us x cells; through 0: {1e6 * through0:.2f} us/cell; "
            f"max per-cell {1e6 * float(np.max(y / x)):.2f} us"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

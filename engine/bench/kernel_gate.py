"""Kernel refactor gate: final ray states and field buffers of a fixed set of traces, saved for comparison.

A refactor of the traversal kernels must leave every number bit-identical. Run this module with the
Python of the base commit and with that of the refactor, then compare (``np.array_equal`` on every array):

    OLD/.venv/bin/python -m bentray.engine.bench.kernel_gate save old.npz
    NEW/.venv/bin/python -m bentray.engine.bench.kernel_gate save new.npz
    python -m bentray.engine.bench.kernel_gate compare old.npz new.npz
    python -m bentray.engine.bench.kernel_gate timing OLD/.venv/bin/python NEW/.venv/bin/python [rounds]

The numerical baselines have their own case set (every method, mesh and exact media; run as a script so that
each interpreter imports its own bentray, the base commit may lack this command):

    OLD/.venv/bin/python NEW/engine/bench/kernel_gate.py save_baselines old_b.npz
    NEW/.venv/bin/python NEW/engine/bench/kernel_gate.py save_baselines new_b.npz
    python -m bentray.engine.bench.kernel_gate compare old_b.npz new_b.npz

Cases: the A-LD fan (log profile b = +1, slab mesh, 91 elevations -45..45 deg), a sphere of rays on the same
mesh, the medium desert terrain mesh (1,500 rays over the sphere), each without field, with an incoherent
and a coherent field (soft ground material on every reflecting face, a random ground table), with path
recording, and with a log wind (slabs) and a ridge wind (desert terrain). Saved per case: the trace's
position, direction, time, length, status, reflections, crossings, nudges, steps, path arrays, and the
field buffers (every accumulator array). ``timing`` alternates the two interpreters (subprocesses) over
``rounds`` rounds, each timing the desert sphere best of 3 warm runs, and prints best-of-rounds crossings
per second and their ratio (new / old). ``save_baselines``: trace_numerical with euler, euler_adaptive, rk4
and dopri5 (with and without renormalisation) over the A-LD slab mesh and the exact A-LD profile (a fan of 16
rays, paths recorded), saving the trace, the restarts, rejected steps and evaluations.
"""

from __future__ import annotations

import subprocess
import sys
import time
from typing import Any

import numpy as np

BOUNDARY_REFLECT = -2
_scenes_cache: dict = {}


def _buffers(mode: str, n: int, lo: np.ndarray, hi: np.ndarray, n_slots: int):
    from bentray.engine.field_buffers import FieldBuffers, FieldGrid

    rng = np.random.default_rng(7)
    shape = (24, 3, 20)
    spacing = (hi - lo) / np.array(shape)
    grid = FieldGrid(origin=lo + 0.5 * spacing, spacing=spacing, shape=shape)
    n_f = 2 if mode == "incoherent" else 1
    weights = rng.uniform(0.5, 1.5, (n, n_f))
    q2tab = rng.uniform(0.3, 1.0, (2, 2, 8, 8))
    q2ax = np.array([np.log(1e-3), 1.0, 0.0, 1.2, 1e-3])
    alpha = np.array([1e-4, 3e-3])[:n_f]
    band_of = np.arange(n_f, dtype=np.int64)
    return FieldBuffers(mode, grid, weights, alpha, band_of, q2tab, q2ax, 7.0, n_slots, n_groups=4)


def _soft(mesh):
    mat = np.where(mesh.neighbours == BOUNDARY_REFLECT, 1, 0).astype(np.int64)
    return mesh._replace(face_material=mat)


def _scenes(n_desert: int = 1500):
    from bentray.engine.bench.breakdown import _stratified_scene
    from bentray.engine.bench.scene_meshes import build_scene_mesh

    ald = _stratified_scene(400)
    from bentray.engine.bench.baselines_probe import CASES

    o, d = CASES["A-LD"].fan(91)
    fan = (ald.mesh, o, d, np.repeat(ald.start_cells[:1], len(o)))
    sphere = (ald.mesh, ald.origins, ald.directions, ald.start_cells)
    des = build_scene_mesh("desert", n_desert)
    desert = (des.mesh, des.origins, des.directions, des.start_cells)
    return {"ald_fan": fan, "ald_sphere": sphere, "desert": desert}


def _winds():
    from bentray.engine.wind import wind_spec
    from bentray.scenes.library.ridge import RIDGE_WIND

    log = wind_spec("log", {"u_star": 0.4, "z_g": 0.1, "direction_deg": 30.0})
    return {"ald_fan": log, "ald_sphere": log, "desert": wind_spec("ridge", RIDGE_WIND)}


def _store(out: dict, key: str, res, buf) -> None:
    for name in ("position", "direction", "time_s", "length_m", "status", "reflections", "crossings"):
        out[f"{key}/{name}"] = getattr(res, name)
    out[f"{key}/nudges"] = res.nudges
    out[f"{key}/steps"] = res.steps
    if res.paths is not None:
        for name in ("offsets", "points", "time_s", "length_m"):
            out[f"{key}/path_{name}"] = getattr(res.paths, name)
    if res.reflection_cos is not None:
        out[f"{key}/refl_cos"] = res.reflection_cos
        out[f"{key}/refl_mat"] = res.reflection_material
    if buf is not None:
        for name in ("energy", "hits", "c_energy", "c_perp2", "c_time", "c_length", "c_ray"):
            out[f"{key}/fld_{name}"] = getattr(buf, name)


def save(path: str) -> None:
    """Trace every case and save the arrays to ``path`` (.npz)."""
    from bentray.engine.tracer import trace

    out: dict[str, Any] = {}
    winds = _winds()
    _scenes_cache.update(_scenes())
    for name, (mesh, o, d, cells) in _scenes_cache.items():
        mesh = _soft(mesh)
        lo = mesh.ref_point.min(axis=0)
        hi = mesh.ref_point.max(axis=0)
        mid = 0.5 * (lo + hi)
        lo, hi = np.minimum(lo, mid - 50.0), np.maximum(hi, mid + 50.0)  # slabs: all ref points at y = 0
        kw: dict[str, Any] = {"max_time_s": 10.0, "max_reflections": 30}
        for wind_name, wind in (("still", None), ("wind", winds[name])):
            key = f"{name}/{wind_name}"
            t0 = time.perf_counter()
            _store(out, f"{key}/plain", trace(mesh, "parabolic", 340.0, o, d, cells, wind=wind, **kw), None)
            for mode in ("incoherent", "coherent"):
                buf = _buffers(mode, len(o), lo, hi, 3)
                res = trace(mesh, "parabolic", 340.0, o, d, cells, wind=wind, field=buf, **kw)
                _store(out, f"{key}/{mode}", res, buf)
            n_p = min(len(o), 200)
            res = trace(mesh, "parabolic", 340.0, o[:n_p], d[:n_p], cells[:n_p], wind=wind, path_samples=50, **kw)
            _store(out, f"{key}/paths", res, None)
            print(f"{key}: {time.perf_counter() - t0:.1f} s, crossings {int(res.crossings.sum())}", flush=True)
    # the other two curve kinds on the same geometry (media requantified as bench/breakdown.py does)
    from bentray.engine.bench.breakdown import _requantify
    from bentray.engine.bench.scene_meshes import SceneMesh

    for name in ("ald_fan", "desert"):
        mesh, o, d, cells = _scenes_cache[name]
        for curve in ("n_linear", "circular"):
            cm = _soft(_requantify(SceneMesh(name, mesh, o, d, cells, 0.0), curve))
            kw = {"max_time_s": 10.0, "max_reflections": 30}
            key = f"{name}/{curve}"
            _store(out, f"{key}/wind", trace(cm, curve, 340.0, o, d, cells, wind=winds[name], **kw), None)
            buf = _buffers("incoherent", len(o), cm.ref_point.min(axis=0) - 50.0, cm.ref_point.max(axis=0) + 50.0, 3)
            _store(out, f"{key}/incoherent", trace(cm, curve, 340.0, o, d, cells, field=buf, **kw), buf)
            print(f"{key}: done", flush=True)
    # the numerical baselines share the out_state / out_counts columns: rk4 and dopri5 on the A-LD slab mesh
    from bentray.engine.baselines.trace_numerical import trace_numerical

    mesh, o, d, cells = _scenes_cache["ald_fan"]
    for method in ("rk4", "dopri5"):
        stats: dict[str, np.ndarray] = {}
        res, restarts = trace_numerical(
            method, "mesh", mesh=mesh, origins=o[::6], directions=d[::6], start_cells=cells[::6], max_time_s=3.0,
            step_m=2.0, tolerance=1e-7, path_samples=20, domain_min=np.array([-50.0, -50.0, 0.0]),
            domain_max=np.array([4000.0, 50.0, 2600.0]), stats=stats,
        )  # fmt: skip
        _store(out, f"baseline/{method}", res, None)
        out[f"baseline/{method}/restarts"] = restarts
        out[f"baseline/{method}/rejected"] = stats["rejected"]
        out[f"baseline/{method}/evaluations"] = stats["evaluations"]
    np.savez(path, **out)
    print(f"saved {len(out)} arrays to {path}")


def save_baselines(path: str) -> None:
    """Trace the numerical-baseline cases (module docstring) and save the arrays to ``path`` (.npz)."""
    from bentray.engine.baselines.exact_media import exact_media_spec
    from bentray.engine.baselines.trace_numerical import trace_numerical
    from bentray.engine.bench.baselines_probe import CASES
    from bentray.engine.bench.breakdown import _stratified_scene

    case = CASES["A-LD"]
    ald = _stratified_scene(4)
    o, d = case.fan(16)
    common: dict[str, Any] = {
        "origins": o,
        "directions": d,
        "max_time_s": 4.0,
        "max_reflections": 20,
        "path_samples": 30,
        "domain_min": np.asarray(case.domain_min, float),
        "domain_max": np.asarray(case.domain_max, float),
    }
    media_kw: dict[str, dict[str, Any]] = {
        "mesh": {"mesh": ald.mesh, "start_cells": np.repeat(ald.start_cells[:1], len(o))},
        "exact": {"exact_spec": exact_media_spec(case.profile())},
    }
    out: dict[str, Any] = {}
    for media, mkw in media_kw.items():
        for method in ("euler", "euler_adaptive", "rk4", "dopri5"):
            for renorm in (False, True):
                fixed = method in ("euler", "rk4")
                setting: dict[str, Any] = {"step_m": 5.0} if fixed else {"step_m": 2.0, "tolerance": 1e-6}
                stats: dict[str, np.ndarray] = {}
                res, restarts = trace_numerical(
                    method, media, renormalize=renorm, stats=stats, **setting, **mkw, **common
                )
                key = f"baseline/{media}/{method}/{'renorm' if renorm else 'plain'}"
                _store(out, key, res, None)
                out[f"{key}/restarts"] = restarts
                out[f"{key}/rejected"] = stats["rejected"]
                out[f"{key}/evaluations"] = stats["evaluations"]
                print(f"{key}: steps {int(np.asarray(res.steps).sum())}, restarts {int(restarts.sum())}", flush=True)
    np.savez(path, **out)
    print(f"saved {len(out)} arrays to {path}")


def compare(path_a: str, path_b: str) -> bool:
    """Print every array that differs (np.array_equal, NaN == NaN); True when all are identical."""
    a, b = np.load(path_a), np.load(path_b)
    keys = sorted(set(a.files) | set(b.files))
    bad = 0
    for k in keys:
        if k not in a.files or k not in b.files:
            print(f"MISSING {k}")
            bad += 1
        elif not np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"):
            print(f"DIFFERS {k}")
            bad += 1
    print(f"{len(keys) - bad} of {len(keys)} arrays bit-identical")
    return bad == 0


def _time_once() -> None:
    from bentray.engine.bench.scene_meshes import build_scene_mesh
    from bentray.engine.tracer import trace

    sc = build_scene_mesh("desert", 2000)
    kw: dict[str, Any] = {"max_time_s": 10.0, "max_reflections": 3}
    trace(sc.mesh, "parabolic", 340.0, sc.origins, sc.directions, sc.start_cells, **kw)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        res = trace(sc.mesh, "parabolic", 340.0, sc.origins, sc.directions, sc.start_cells, **kw)
        best = min(best, time.perf_counter() - t0)
    print(f"CROSSINGS_PER_S {res.crossings.sum() / best:.6e}")


def timing(old_python: str, new_python: str, rounds: int = 3) -> None:
    best = {old_python: 0.0, new_python: 0.0}
    for r in range(rounds):
        for py in (old_python, new_python) if r % 2 == 0 else (new_python, old_python):
            # run as a script: each interpreter imports its own bentray (the base commit lacks this module)
            cmd = [py, __file__, "time_once"]
            txt = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
            rate = float(txt.split("CROSSINGS_PER_S")[1].split()[0])
            print(f"round {r} {py}: {rate / 1e6:.2f}M crossings/s", flush=True)
            best[py] = max(best[py], rate)
    print(
        f"best old {best[old_python] / 1e6:.2f}M/s, new {best[new_python] / 1e6:.2f}M/s, "
        f"ratio new/old {best[new_python] / best[old_python]:.3f}"
    )


if __name__ == "__main__":
    cmd = sys.argv[1]
    if cmd == "save":
        save(sys.argv[2])
    elif cmd == "save_baselines":
        save_baselines(sys.argv[2])
    elif cmd == "compare":
        sys.exit(0 if compare(sys.argv[2], sys.argv[3]) else 1)
    elif cmd == "timing":
        timing(sys.argv[2], sys.argv[3], int(sys.argv[4]) if len(sys.argv) > 4 else 3)
    elif cmd == "time_once":
        _time_once()
    else:
        raise SystemExit(f"unknown command {cmd!r}")

"""Throughput: cell crossings per second (per core) and ns per crossing, generic and lean kernels, against
the machine's own limits measured in the same run.

The desert scene's terrain mesh (scene_meshes.build_scene_mesh: native 31.25 m horizontal spacing,
terrain-following layers), rays spread evenly over the sphere from its source (2 m above the centre),
10 s, at most 3 reflections (the paper's Desert(m) run: 10K rays, 179 cells per ray, 3 reflections,
219 ms, about 8M crossings per second on one 3.2 GHz core in 2016, 122 ns per crossing). The A-LD slab
mesh (delta 1e-8, the same sphere of rays from 1.5 m) is measured too, so the section has numbers when the
terrain mesh builder is unavailable.

Kernels (tracer.trace): ``generic`` (traverse.trace_rays, what every trace with a field, paths, wind or
paraxial state runs) and ``lean`` (kernels/lean.py, the plain parabolic trace on packed cell records;
bit-identical final states) with one ray in flight and no prefetch (``lean 1 lane``), and as the tracer
runs it: tracer.LEAN_LANES rays in flight, each next record prefetched for meshes larger than
tracer.LEAN_CACHED_BYTES of records (the desert) and not for smaller ones (the slabs). ``generic + wind``:
the generic kernel with a wind (the ridge wind of the built-in ridge scene over the desert, a log-law wind
over the slabs): the wind's cost per crossing is its time less the generic kernel's, in the same run. With
1 numba thread and with all of them (restored afterwards).
Timing: ``rounds`` interleaved rounds (every kernel once per round, in turn, so that a change in the
machine's load hits all alike), each the best of ``repeats`` warm runs; a kernel's time is its best over
rounds; the ratios compare times of the same run. The load average is printed beside the numbers.

The machine (bench/machine.py, same run): single-core triad bandwidth and operation costs, and from them a
memory bound (the cache lines one cell's records span, at that bandwidth) and an arithmetic bound (the
parabolic crossing's operation counts at those costs) per crossing, both printed against the measured ns
per crossing.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

import numba
import numpy as np

from bentray.engine.bench.breakdown import _stratified_scene
from bentray.engine.bench.common import Section, Table
from bentray.engine.bench.machine import crossing_bounds, measure_machine
from bentray.engine.bench.scene_meshes import SceneMesh, SceneUnavailable, build_scene_mesh
from bentray.engine.compile_time import compile_timer
from bentray.engine.result import TraceResult
from bentray.engine.tracer import LEAN_LANES, trace, trace_lean

__all__ = ["run", "measure_kernels", "scene_wind", "KERNELS", "WIND_KERNEL"]

COLUMNS = [
    "scene",
    "cells",
    "rays",
    "threads",
    "kernel",
    "trace_time_s",
    "crossings_per_ray",
    "reflections_per_ray",
    "crossings_per_s",
    "crossings_per_s_per_core",
    "ns_per_crossing_per_core",
    "speedup_vs_generic",
    "x_memory_bound",
    "x_arithmetic_bound",
    "rays_per_s",
    "compile_s",
    "lost",
    "note",
]
MACHINE_COLUMNS = ["quantity", "value", "unit"]
LEAN_DEFAULT = f"lean {LEAN_LANES} lanes"
WIND_KERNEL = "generic + wind"
KERNELS = ("generic", "lean 1 lane", LEAN_DEFAULT, WIND_KERNEL)
ISSUE_WIND_NS = 286.0  # the wind's cost per crossing (generic kernel, desert) when issue 18 was filed
PAPER_NS = 122.0  # the paper's Desert(m): 219 ms for 10K rays x 179 cells on one 3.2 GHz core (2016)


def scene_wind(scene: str) -> Any:
    """The wind of the ``generic + wind`` row (kernel form): the built-in ridge scene's over the desert, a
    log-law wind (u* 0.4 m/s, z_g 0.1 m, blowing 30 degrees from x) over the slabs."""
    from bentray.engine.wind import wind_spec

    if scene == "desert":
        from bentray.scenes.library.ridge import RIDGE_WIND

        return wind_spec("ridge", RIDGE_WIND)
    return wind_spec("log", {"u_star": 0.4, "z_g": 0.1, "direction_deg": 30.0})


def _runner(sc: SceneMesh, kernel: str) -> Callable[[], TraceResult]:
    kw: dict[str, Any] = {"max_time_s": 10.0, "max_reflections": 3}
    args = (sc.mesh, 340.0, sc.origins, sc.directions, sc.start_cells)
    if kernel == "generic":
        return lambda: trace(sc.mesh, "parabolic", 340.0, *args[2:], kernel="generic", **kw)
    if kernel == WIND_KERNEL:
        wind = scene_wind(sc.name)
        return lambda: trace(sc.mesh, "parabolic", 340.0, *args[2:], kernel="generic", wind=wind, **kw)
    if kernel == "lean 1 lane":
        return lambda: trace_lean(*args, prefetch=0, lanes=1, **kw)
    return lambda: trace_lean(*args, **kw)  # the tracer's defaults: LEAN_LANES lanes, prefetch by size


def measure_kernels(
    sc: SceneMesh, threads: int, rounds: int, repeats: int, compiled: dict[str, float] | None = None
) -> dict[str, tuple[float, TraceResult]]:
    """Best warm time (s) and the result of each kernel in KERNELS on ``sc`` with ``threads`` numba threads,
    over ``rounds`` interleaved rounds of ``repeats`` runs each (module docstring). ``compiled`` (if given)
    gets each kernel's Numba compilation seconds in its first call (engine.compile_time; 0 on a warm cache)."""
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    runners = {k: _runner(sc, k) for k in KERNELS}
    best: dict[str, float] = dict.fromkeys(KERNELS, float("inf"))
    results: dict[str, TraceResult] = {}
    try:
        for k, go in runners.items():  # compile / load and warm each once
            with compile_timer() as ct:
                results[k] = go()
            if compiled is not None:
                compiled[k] = compiled.get(k, 0.0) + ct.seconds
        for _ in range(max(1, rounds)):
            for k, go in runners.items():
                for _ in range(max(1, repeats)):
                    t0 = time.perf_counter()
                    results[k] = go()
                    best[k] = min(best[k], time.perf_counter() - t0)
    finally:
        numba.set_num_threads(before)
    return {k: (best[k], results[k]) for k in KERNELS}


def _machine_table(costs: dict[str, float], bounds: dict[str, dict[str, float]]) -> Table:
    table = Table("throughput_machine", "The machine, same run (one core)", MACHINE_COLUMNS)
    table.add(quantity="triad bandwidth", value=costs["triad_gb_s"], unit="GB/s")
    for name, label in (("flop_s", "multiply or add"), ("sqrt_s", "sqrt"), ("div_s", "division"), ("log1p_s", "log1p")):
        table.add(quantity=f"{label} (independent chains)", value=costs[name] * 1e9, unit="ns")
    for scene, b in bounds.items():
        table.add(quantity=f"{scene}: cache lines per cell", value=b["lines_per_cell"], unit="lines")
        table.add(quantity=f"{scene}: memory bound per crossing", value=b["memory_ns"], unit="ns")
        table.add(quantity=f"{scene}: cache lines per packed record (lean)", value=b["packed_lines"], unit="lines")
        table.add(quantity=f"{scene}: memory bound per crossing, packed", value=b["packed_memory_ns"], unit="ns")
        table.add(quantity=f"{scene}: arithmetic bound per crossing", value=b["arithmetic_ns"], unit="ns")
    return table


def run(quick: bool, scene_cache: dict[str, Any] | None = None) -> Section:
    """Quick: 1,000 rays, 1 round of 1 run; full: 10,000 rays, 3 rounds of 3. ``scene_cache`` as in
    breakdown.run."""
    count = 1000 if quick else 10_000
    rounds, repeats = (1, 1) if quick else (3, 3)
    cache = scene_cache if scene_cache is not None else {}
    table = Table("throughput", "Throughput", COLUMNS)
    key = f"desert/{count}"
    if key not in cache:
        try:
            cache[key] = build_scene_mesh("desert", count)
        except SceneUnavailable as exc:
            cache[key] = exc
    scenes: list[Any] = [cache[key], _stratified_scene(count)]
    load_before = os.getloadavg()
    costs = measure_machine(repeats=2 if quick else 5)
    bounds = {sc.name: crossing_bounds(sc.mesh, costs) for sc in scenes if not isinstance(sc, SceneUnavailable)}
    all_threads = numba.get_num_threads()
    for sc in scenes:
        if isinstance(sc, SceneUnavailable):
            table.add(scene="desert", rays=count, note=f"skipped: {sc}")
            continue
        b = bounds[sc.name]
        for threads in sorted({1, all_threads}):
            compiled: dict[str, float] = {}
            timed = measure_kernels(sc, threads, rounds, repeats, compiled)
            t_generic = timed["generic"][0]
            for kernel, (elapsed, res) in timed.items():
                crossings = float(res.crossings.sum())
                n = res.n_rays
                ns = elapsed * threads / crossings * 1e9 if crossings else float("nan")
                table.add(
                    scene=sc.name,
                    cells=sc.mesh.n_cells,
                    rays=n,
                    threads=threads,
                    kernel=kernel,
                    trace_time_s=elapsed,
                    crossings_per_ray=crossings / n,
                    reflections_per_ray=float(res.reflections.mean()),
                    crossings_per_s=crossings / elapsed,
                    crossings_per_s_per_core=crossings / elapsed / threads,
                    ns_per_crossing_per_core=ns,
                    speedup_vs_generic=t_generic / elapsed,
                    x_memory_bound=ns / b["memory_ns" if kernel.startswith("generic") else "packed_memory_ns"],
                    x_arithmetic_bound=ns / b["arithmetic_ns"],
                    rays_per_s=n / elapsed,
                    compile_s=compiled[kernel],
                    lost=res.status_counts()["lost"],
                    note=f"mesh build {sc.build_s:.1f} s",
                )
    load_after = os.getloadavg()
    sec = Section("throughput", "Throughput")
    sec.text.append(
        f"{count} rays over the sphere, 10 s, at most 3 reflections, parabolic curve; {rounds} interleaved round(s) "
        f"of {repeats} warm run(s) per kernel, best taken. Load average (1 min) {load_before[0]:.1f} before, "
        f"{load_after[0]:.1f} after: on a shared machine compare the ratios of one run, not absolute times. "
        f"`lean 1 lane`: kernels/lean.py with one ray in flight, no prefetch; `{LEAN_DEFAULT}`: the tracer's "
        f"default, {LEAN_LANES} rays in flight per thread, each next cell record prefetched where the records "
        f"do not fit in cache (the desert, not the slabs); bit-identical final states. "
        f"Paper reference (one 3.2 GHz core, 2016): Desert(m) 10K rays, 179 cells per ray, "
        f"219 ms, ~8M crossings per second, {PAPER_NS:.0f} ns per crossing."
    )
    sec.text.append(
        f"The machine (one core, same run): triad {costs['triad_gb_s']:.1f} GB/s; multiply or add "
        f"{costs['flop_s'] * 1e9:.2f} ns, sqrt {costs['sqrt_s'] * 1e9:.2f} ns, division {costs['div_s'] * 1e9:.2f} ns, "
        f"log1p {costs['log1p_s'] * 1e9:.1f} ns (independent chains). Per crossing: memory bound = the cache lines "
        "of one cell's records at that bandwidth (every cell from memory), arithmetic bound = 235 flops, 9 sqrt, "
        "10 divisions at those costs (the generic crossing's operations, one at a time; the lean kernel does its "
        "face search and advance as 4-wide vectors, so it can go below this bound; its memory bound counts its "
        "packed record's lines); `x_memory_bound` / `x_arithmetic_bound` = measured ns per crossing over each."
    )
    one = [r for r in table.rows if r["threads"] == 1 and r["kernel"]]
    for scene in dict.fromkeys(r["scene"] for r in one):
        rows = {r["kernel"]: r for r in one if r["scene"] == scene}
        gen, one_lane, lean = rows.get("generic"), rows.get("lean 1 lane"), rows.get(LEAN_DEFAULT)
        if gen is None or lean is None or one_lane is None:
            continue
        if one_lane["ns_per_crossing_per_core"] < lean["ns_per_crossing_per_core"]:
            lean = one_lane  # the faster of the two (the tracer picks by the records' size)
        b = bounds[scene]
        sec.text.append(
            f"**{scene}, one core: generic {gen['ns_per_crossing_per_core']:.0f} ns per crossing "
            f"({gen['crossings_per_s_per_core'] / 1e6:.1f}M/s), lean 1 lane {one_lane['ns_per_crossing_per_core']:.0f} "
            f"ns, {LEAN_DEFAULT} {rows[LEAN_DEFAULT]['ns_per_crossing_per_core']:.0f} ns; best lean "
            f"{lean['crossings_per_s_per_core'] / 1e6:.1f}M/s, {lean['speedup_vs_generic']:.2f}x the generic; bounds: "
            f"memory {b['memory_ns']:.0f} ns ({b['lines_per_cell']:.1f} lines per cell; packed "
            f"{b['packed_memory_ns']:.0f} ns, {b['packed_lines']:.0f} lines), arithmetic "
            f"{b['arithmetic_ns']:.0f} ns; "
            f"best lean = {lean['x_memory_bound']:.1f}x the memory bound, {lean['x_arithmetic_bound']:.1f}x the "
            f"arithmetic bound; paper {PAPER_NS:.0f} ns / best lean = "
            f"{PAPER_NS / lean['ns_per_crossing_per_core']:.2f}x; "
            f"{np.mean([r['crossings_per_ray'] for r in rows.values() if r['kernel'] != WIND_KERNEL]):.0f} "
            "cells per ray.**"
        )
        windy = rows.get(WIND_KERNEL)
        if windy is not None:
            extra = windy["ns_per_crossing_per_core"] - gen["ns_per_crossing_per_core"]
            sec.text.append(
                f"{scene}, one core, generic kernel with {'the ridge' if scene == 'desert' else 'a log-law'} wind: "
                f"{windy['ns_per_crossing_per_core']:.0f} ns per crossing, the wind {extra:.0f} ns of it"
                + (f" ({ISSUE_WIND_NS:.0f} ns when issue 18 was filed)." if scene == "desert" else ".")
            )
    sec.tables.append(table)
    sec.tables.append(_machine_table(costs, bounds))
    return sec

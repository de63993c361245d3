"""``bentray bench --only gpu``: the CUDA traversal against the CPU kernels, rays and crossings per second.

Cases: the medium desert scene's terrain mesh (scene_meshes.build_scene_mesh) and the A-LD slab mesh
(breakdown._stratified_scene), rays spread evenly over the sphere from the scene's source, 10 s, at most 3
reflections, parabolic curve (the throughput section's setting). Per case, in one run: the CPU kernels with all
numba threads (warm, best of the repeats) and the CUDA kernel (engine/gpu), whose first call's mesh copy and
kernel compile are reported apart from the warm launches (rays copied in, kernel, states copied back). Rates:
rays / kernel time and crossings / kernel time; ``end_to_end`` adds the per-call ray transfers. The CUDA
states are compared with the CPU ones (statuses equal, largest end-point difference relative to the path).

The field case (table ``gpu_field``): the A-LD slab mesh with a beam field (incoherent, octave bands 63 Hz -
8 kHz, a 120 x 5 x 7 grid up to 3 km, the mesh's rigid ground) from a regular launch grid (elevation x
azimuth), traced with
beams on the CPU (all numba threads, per-thread slots) and on the GPU (atomics into one accumulator,
engine/gpu/beam_device.py): rays per second and beam deposits (point contributions) per second, the largest
relative difference of the collapsed energies and whether the hit counts agree.

Without a CUDA device (numba-cuda missing, no driver, or only the simulator) the section says so and is
skipped; nothing is built and the command exits with status 0.
"""

from __future__ import annotations

import time
from typing import Any

import numba
import numpy as np

from bentray.engine.bench.common import Section, Table, best_time
from bentray.engine.gpu import device as gpu_device

__all__ = ["COLUMNS", "FIELD_COLUMNS", "run"]

COLUMNS = [
    "scene",
    "cells",
    "rays",
    "device",
    "mesh_transfer_s",
    "compile_s",
    "rays_transfer_s",
    "kernel_s",
    "copy_back_s",
    "trace_time_s",
    "crossings_per_ray",
    "rays_per_s",
    "crossings_per_s",
    "end_to_end_rays_per_s",
    "speedup",
    "status_equal",
    "max_end_diff_rel",
    "note",
]
_KW: dict[str, Any] = {"max_time_s": 10.0, "max_reflections": 3}
FIELD_COLUMNS = [
    "scene",
    "rays",
    "points",
    "bands",
    "device",
    "compile_s",
    "rays_transfer_s",
    "kernel_s",
    "copy_back_s",
    "trace_time_s",
    "rays_per_s",
    "deposits_per_s",
    "speedup",
    "hits_equal",
    "energy_max_rel",
    "note",
]


def _field_case(count: int) -> dict[str, Any]:
    """The A-LD slabs with a beam-field template and a launch grid of about ``count`` rays (see the docstring)."""
    from bentray.engine import beam_field
    from bentray.engine.bench.baselines_probe import CASES
    from bentray.engine.media import build_media
    from bentray.scenes.field_models import FieldSpec
    from bentray.scenes.schema import Solver

    case = CASES["A-LD"]
    profile = case.profile()
    med = build_media(profile, "parabolic", Solver(), np.array(case.domain_min), np.array(case.domain_max))
    n_az = max(int(round(np.sqrt(count / 20.0))), 1)
    n_el = max(count // n_az, 2)
    el = np.linspace(-20.0, 20.0, n_el)
    az = np.linspace(-10.0, 10.0, n_az) if n_az > 1 else np.zeros(1)
    e_grid, a_grid = np.meshgrid(np.radians(el), np.radians(az), indexing="ij")
    e, a = e_grid.ravel(), a_grid.ravel()
    d = np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    src = np.asarray([case.source], float)
    n = d.shape[0]
    spec = FieldSpec(origin=(25.0, -40.0, 1.5), spacing=(25.0, 20.0, 5.0), shape=(120, 5, 7), mode="incoherent")
    n_mat = int(med.mesh.face_material.max()) + 1
    template = beam_field.prepare(
        spec,
        elevation_deg=el,
        azimuth_deg=az,
        n_rays=n,
        source_index=np.zeros(n, np.int64),
        source_powers_w=None,
        materials=[200_000.0] * n_mat,
        max_reflections=_KW["max_reflections"],
        c_ref=float(profile.c_ref),
        ground_sound_speed=340.0,
        n_face_materials=n_mat,
    )
    return {
        "name": "A-LD slabs, beams",
        "mesh": med.mesh,
        "c_ref": float(profile.c_ref),
        "origins": np.repeat(src, n, axis=0),
        "directions": d,
        "start_cells": np.repeat(med.locate(src), n),
        "template": template,
        "points": spec.shape[0] * spec.shape[1] * spec.shape[2],
        "bands": len(spec.frequencies_hz),
    }


def _field_rows(fc: dict[str, Any], repeats: int, min_total: float, device_name: str) -> list[dict[str, Any]]:
    """The CPU and GPU rows of the field case (warm: each path is called once before it is timed)."""
    from bentray.engine.gpu.tracer import trace_cuda
    from bentray.engine.tracer import trace

    tpl = fc["template"]
    args = (fc["mesh"], "parabolic", fc["c_ref"], fc["origins"], fc["directions"], fc["start_cells"])
    n = fc["origins"].shape[0]

    def cpu() -> Any:
        buf = tpl.like(tpl.weights)
        trace(*args, field=buf, **_KW)
        return buf.collapse()

    cpu()
    cpu_s, cpu_buf = best_time(cpu, repeats, min_total)
    base = {"scene": fc["name"], "rays": n, "points": fc["points"], "bands": fc["bands"]}
    hits = float(cpu_buf.collapsed.hits.sum())
    rows = [
        {
            **base,
            "device": f"cpu ({numba.get_num_threads()} threads)",
            "kernel_s": cpu_s,
            "trace_time_s": cpu_s,
            "rays_per_s": n / cpu_s,
            "deposits_per_s": hits / cpu_s,
        }
    ]
    t0 = time.perf_counter()
    first_buf = tpl.like(tpl.weights, n_slots=1)
    _, first = trace_cuda(*args, beams=first_buf, **_KW)
    first_wall = time.perf_counter() - t0
    best: dict[str, float] | None = None
    gpu_buf = None
    for _ in range(max(repeats, 1)):
        buf = tpl.like(tpl.weights, n_slots=1)
        _, tim = trace_cuda(*args, beams=buf, **_KW)
        if best is None or tim["kernel"] < best["kernel"]:
            best, gpu_buf = tim, buf
    assert best is not None and gpu_buf is not None
    gpu_buf.collapse()
    a, b = cpu_buf.collapsed, gpu_buf.collapsed
    both = (a.energy > 0) | (b.energy > 0)
    rel = np.abs(a.energy - b.energy)[both] / np.maximum(np.abs(a.energy), np.abs(b.energy))[both]
    per_call = best["rays_transfer"] + best["kernel"] + best["copy_back"]
    rows.append(
        {
            **base,
            "device": device_name,
            "compile_s": first["compile"],
            "rays_transfer_s": best["rays_transfer"],
            "kernel_s": best["kernel"],
            "copy_back_s": best["copy_back"],
            "trace_time_s": per_call,
            "rays_per_s": n / best["kernel"],
            "deposits_per_s": float(b.hits.sum()) / best["kernel"],
            "speedup": cpu_s / per_call,
            "hits_equal": bool(np.array_equal(a.hits, b.hits)),
            "energy_max_rel": float(rel.max()) if rel.size else 0.0,
            "note": f"first call {first_wall:.2f} s (mesh copy, compile, launch)",
        }
    )
    return rows


def _cpu_row(sc: Any, repeats: int, min_total: float) -> tuple[dict[str, Any], Any]:
    from bentray.engine.tracer import trace

    trace(sc.mesh, "parabolic", 340.0, sc.origins[:1], sc.directions[:1], sc.start_cells[:1], **_KW)
    elapsed, res = best_time(
        lambda: trace(sc.mesh, "parabolic", 340.0, sc.origins, sc.directions, sc.start_cells, **_KW),
        repeats,
        min_total,
    )
    crossings = float(res.crossings.sum())
    n = res.n_rays
    row = {
        "scene": sc.name,
        "cells": sc.mesh.n_cells,
        "rays": n,
        "device": f"cpu ({numba.get_num_threads()} threads)",
        "trace_time_s": elapsed,
        "kernel_s": elapsed,
        "crossings_per_ray": crossings / n,
        "rays_per_s": n / elapsed,
        "crossings_per_s": crossings / elapsed,
        "end_to_end_rays_per_s": n / elapsed,
    }
    return row, res


def _gpu_row(sc: Any, cpu_row: dict[str, Any], cpu_res: Any, repeats: int, device_name: str) -> dict[str, Any]:
    from bentray.engine.gpu.tracer import trace_cuda

    args = (sc.mesh, "parabolic", 340.0, sc.origins, sc.directions, sc.start_cells)
    t0 = time.perf_counter()
    _, first = trace_cuda(*args, **_KW)  # mesh copy + compile + a first launch
    first_wall = time.perf_counter() - t0
    best: dict[str, float] | None = None
    res = None
    for _ in range(max(repeats, 1)):
        res, tim = trace_cuda(*args, **_KW)
        if best is None or tim["kernel"] < best["kernel"]:
            best = tim
    assert best is not None and res is not None
    crossings = float(res.crossings.sum())
    n = res.n_rays
    per_call = best["rays_transfer"] + best["kernel"] + best["copy_back"]
    scale = np.maximum(cpu_res.length_m, 1.0)
    diff = np.max(np.abs(res.position - cpu_res.position), axis=1) / scale
    return {
        "scene": sc.name,
        "cells": sc.mesh.n_cells,
        "rays": n,
        "device": device_name,
        "mesh_transfer_s": first["mesh_transfer"],
        "compile_s": first["compile"],
        "rays_transfer_s": best["rays_transfer"],
        "kernel_s": best["kernel"],
        "copy_back_s": best["copy_back"],
        "trace_time_s": per_call,
        "crossings_per_ray": crossings / n,
        "rays_per_s": n / best["kernel"],
        "crossings_per_s": crossings / best["kernel"],
        "end_to_end_rays_per_s": n / per_call,
        "speedup": cpu_row["trace_time_s"] / per_call,
        "status_equal": float(np.mean(res.status == cpu_res.status)),
        "max_end_diff_rel": float(np.max(diff)) if n else 0.0,
        "note": f"first call {first_wall:.2f} s (mesh copy, compile, launch)",
    }


def _scenes(count: int, cache: dict[str, Any]) -> list[Any]:
    from bentray.engine.bench.breakdown import _stratified_scene
    from bentray.engine.bench.scene_meshes import SceneUnavailable, build_scene_mesh

    key = f"desert/{count}"
    if key not in cache:
        try:
            cache[key] = build_scene_mesh("desert", count)
        except SceneUnavailable as exc:
            cache[key] = exc
    return [cache[key], _stratified_scene(count)]


def run(quick: bool, scene_cache: dict[str, Any] | None = None) -> Section:
    """Quick: 20,000 rays per case, one warm run; full: 200,000 rays, best of 3. Skipped without a device."""
    sec = Section("gpu", "CUDA traversal against the CPU kernels")
    usable, why = gpu_device.cuda_status()
    if not usable or gpu_device.simulator_enabled():
        reason = why if not usable else "only numba's CUDA simulator is on (not a device)"
        sec.status = f"skipped: {reason}"
        sec.text.append(
            f"No CUDA device here ({reason}): no GPU numbers. On a machine with one (and `pip install "
            "'bentray[gpu]'`), `bentray bench --only gpu` measures the desert and A-LD cases on the CPU and the GPU."
        )
        return sec
    count = 20_000 if quick else 200_000
    repeats, min_total = (1, 0.0) if quick else (3, 1.0)
    table = Table("gpu", "CUDA traversal against the CPU kernels", COLUMNS)
    for sc in _scenes(count, scene_cache if scene_cache is not None else {}):
        if isinstance(sc, Exception):
            table.add(scene="desert", rays=count, note=f"skipped: {sc}")
            continue
        cpu_row, cpu_res = _cpu_row(sc, repeats, min_total)
        table.add(**cpu_row, note=f"mesh build {sc.build_s:.1f} s")
        table.add(**_gpu_row(sc, cpu_row, cpu_res, repeats, why))
    sec.text.append(
        f"{count:,} rays over the sphere, 10 s, at most 3 reflections, parabolic curve; {why}. Rates use the "
        "kernel time; end_to_end adds the per-call ray transfers; the first call's mesh copy and compile are apart."
    )
    sec.tables.append(table)
    n_field = 2_000 if quick else 20_000
    ftable = Table("gpu_field", "Beam field on the CPU and on the CUDA device (A-LD slabs)", FIELD_COLUMNS)
    for row in _field_rows(_field_case(n_field), repeats, min_total, why):
        ftable.add(**row)
    sec.text.append(
        f"Field: {n_field:,} rays (a launch grid, elevation -20..20 deg, azimuth -10..10 deg) with beams onto a "
        "120 x 5 x 7 grid, 8 octave bands, incoherent, rigid ground; CPU per-thread slots against GPU atomics into "
        "one accumulator (the sum order differs: energy_max_rel is that rounding, plus FMA / libdevice on a "
        "device); deposits = beam contributions to points."
    )
    sec.tables.append(ftable)
    return sec

"""Orchestration: Job -> profile -> media representation -> launch fan -> kernels -> JobOutcome.

Plain Python; the per-ray work happens in the Numba kernels. Each stage is timed; the report says
which stages ran and why the others did not.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numba
import numpy as np

import bentray
from bentray.engine import field as field_stage
from bentray.engine.errors import JobInputError
from bentray.engine.media import build_media, build_terrain_media
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.result import JobOutcome, TraceResult
from bentray.engine.surfaces import SceneSurfaces
from bentray.engine.tracer import trace
from bentray.scenes.library.registry import get_builtin
from bentray.scenes.profile_models import profile_from_spec
from bentray.scenes.scene_models import check_points_above_ground, surfaces_from_specs
from bentray.scenes.schema import Job


def launch_fan(job: Job) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Origins (n,3), unit directions (n,3), source index, elevation and azimuth (degrees) of every ray.

    Order: source-major, then elevation, then azimuth. Elevation is above the horizontal, azimuth
    counter-clockwise from +x: d = (cos el cos az, cos el sin az, sin el).
    """
    el = np.asarray(job.rays.elevation_deg.values(), float)
    az = np.asarray(job.rays.azimuth_deg.values(), float)
    el_g, az_g = np.meshgrid(el, az, indexing="ij")
    el_f = el_g.reshape(-1)
    az_f = az_g.reshape(-1)
    er = np.radians(el_f)
    ar = np.radians(az_f)
    dirs = np.column_stack([np.cos(er) * np.cos(ar), np.cos(er) * np.sin(ar), np.sin(er)])
    n_src = len(job.sources)
    per = len(el_f)
    origins = np.repeat(np.array([s.position for s in job.sources], float), per, axis=0)
    return (
        origins,
        np.tile(dirs, (n_src, 1)),
        np.repeat(np.arange(n_src, dtype=np.int64), per),
        np.tile(el_f, n_src),
        np.tile(az_f, n_src),
    )


def load_surfaces(job: Job, base_dir: Path | None = None) -> SceneSurfaces | None:
    """The scene's terrain, buildings and materials (None: flat ground only, no constrained meshing)."""
    scene = job.scene
    if scene.builtin is not None:
        if not scene.has_surfaces:
            return None
        return get_builtin(scene.builtin, scene.resolution).surfaces
    if scene.terrain is None and scene.buildings is None:
        return None
    return surfaces_from_specs(scene.terrain, scene.buildings, scene.materials, base_dir, scene.box, prefix="scene")


def _describe_surfaces(surfaces: SceneSurfaces) -> str:
    terrain = type(surfaces.terrain).__name__ if surfaces.terrain is not None else "flat ground"
    return f"{terrain}, {len(surfaces.footprints)} buildings, {len(surfaces.materials)} materials"


def _wants_paths(job: Job) -> bool:
    if job.rays.record_paths is not None:
        return bool(job.rays.record_paths)
    return "rays" in job.outputs or "paths" in job.outputs


def run_job(job: Job, base_dir: Path | None = None) -> JobOutcome:
    """Run a validated job in this process and return everything it produced (nothing is written)."""
    timings: dict[str, float] = {}
    stages: dict[str, str] = {}

    t0 = time.perf_counter()
    profile = profile_from_spec(job.profile, base_dir=str(base_dir) if base_dir is not None else None)
    timings["profile"] = time.perf_counter() - t0
    stages["profile"] = f"ran: {profile.kind}"

    domain = job.scene.box
    lo = np.asarray(domain.min, float)
    hi = np.asarray(domain.max, float)
    t0 = time.perf_counter()
    surfaces = load_surfaces(job, base_dir)
    timings["scene"] = time.perf_counter() - t0
    stages["scene"] = (f"ran: {_describe_surfaces(surfaces)}" if surfaces is not None
                       else "skipped: flat ground, no terrain or buildings (no constrained meshing)")
    t0 = time.perf_counter()
    if surfaces is not None:
        media = build_terrain_media(profile, job.solver.curve, job.solver, lo, hi, surfaces, top=job.scene.top.kind)
    else:
        media = build_media(profile, job.solver.curve, job.solver, lo, hi, ground="reflect",
                            top=job.scene.top.kind)
    timings["mesh"] = time.perf_counter() - t0
    stages["mesh"] = f"ran: {media.representation} ({media.reason})"

    origins, dirs, src_idx, el, az = launch_fan(job)
    t0 = time.perf_counter()
    src_pos = np.array([s.position for s in job.sources], float)
    if surfaces is not None:
        check_points_above_ground(surfaces, src_pos, [f"sources.{i}.position" for i in range(len(src_pos))],
                                  flat_ground_z=float(lo[2]) if surfaces.terrain is None else None)
    src_cells = media.locate(src_pos)
    bad = np.nonzero(src_cells < 0)[0]
    if bad.size:
        i = int(bad[0])
        raise JobInputError(f"sources.{i}.position: {list(src_pos[i])} is not inside the media mesh")
    start_cells = src_cells[src_idx]
    timings["locate"] = time.perf_counter() - t0

    record = _wants_paths(job)
    mesh = media.mesh
    buffers = None
    powers = None
    if job.field is not None:
        t0 = time.perf_counter()
        materials = _materials(job, surfaces)
        mesh, buffers, powers = _prepare_field(job, profile, mesh, src_idx, materials)
        timings["field_setup"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    result: TraceResult = trace(
        mesh, job.solver.curve, profile.c_ref, origins, dirs, start_cells,
        max_time_s=job.rays.max_time_s, max_reflections=job.rays.max_reflections,
        max_steps=job.rays.max_steps, path_samples=job.solver.path_samples if record else 0,
        field=buffers,
    )
    timings["trace"] = time.perf_counter() - t0
    stages["trace"] = f"ran: {job.solver.curve} curve, {result.n_rays} rays" + (
        " (field accumulated along the curves)" if buffers is not None else "")
    stages["paths"] = "ran: sampled on the true curves" if record else "skipped: no 'rays' or 'paths' output"
    result.source = src_idx
    result.elevation_deg = el
    result.azimuth_deg = az
    field_arrays = None
    if job.field is not None and buffers is not None:
        t0 = time.perf_counter()
        grid_points = buffers.grid.points()
        field_arrays = field_stage.finalize(job.field, buffers, profile.sound_speed(grid_points), result, powers,
                                            materials)
        field_arrays.preview = {
            "source_xyz": list(job.sources[0].position),
            "receiver_z": float(lo[2] + job.field.receiver_height_m),
            "title": f"{job.name}: {profile.kind} profile, {result.n_rays} rays",
        }
        field_arrays.stats["fan_spacing"] = field_stage.fan_spacing_advice(
            job.field, np.array([src.position for src in job.sources]), job.rays.elevation_deg.values(),
            job.rays.azimuth_deg.values())
        timings["field_finalize"] = time.perf_counter() - t0
        stages["field"] = (f"ran: {job.field.mode}, {buffers.grid.n_points} points, "
                           f"{len(job.field.frequencies_hz)} bands")
    else:
        stages["field"] = "skipped: no field requested"

    geometry = None
    if "mesh" in job.outputs:
        t0 = time.perf_counter()
        geometry = media.geometry()
        timings["mesh_geometry"] = time.perf_counter() - t0
        stages["mesh_output"] = "ran"
    else:
        stages["mesh_output"] = "skipped: 'mesh' not in outputs"

    report = build_report(job, profile.describe(), media.representation, media.reason, media.stats,
                          result, timings, stages)
    if field_arrays is not None:
        report["field"] = field_arrays.stats
    return JobOutcome(trace=result, mesh_geometry=geometry, report=report, field=field_arrays)


def _materials(job: Job, surfaces: SceneSurfaces | None) -> list[float | None]:
    """Flow resistivity per face material index (None = rigid): the scene's table, or flat ground's."""
    if surfaces is not None:
        return [m.flow_resistivity for m in surfaces.materials]
    return [None, job.scene.ground.flow_resistivity]


def _prepare_field(job: Job, profile, mesh: CellMesh, src_idx: np.ndarray, materials: list[float | None]):
    """Ground material on the mesh, per-ray launch weights, source powers (W) and the accumulators."""
    spec = job.field
    assert spec is not None
    if job.scene.ground.flow_resistivity is not None and not job.scene.has_surfaces:
        mesh = field_stage.tag_ground_material(mesh, float(job.scene.box.min[2]), field_stage.GROUND_MATERIAL)
    per_source = field_stage.launch_solid_angles(job.rays.elevation_deg.values(), job.rays.azimuth_deg.values())
    weights = np.tile(per_source, len(job.sources))
    lo = job.scene.box.min
    ground_point = np.array([[job.sources[0].position[0], job.sources[0].position[1], lo[2]]])
    powers = None
    if job.sources[0].power_db is not None:
        powers = np.array([[field_stage.W_REF * 10.0 ** (src.power_db[b] / 10.0) for b in spec.labels]
                           for src in job.sources])
    buffers = field_stage.prepare(spec, ray_weights=weights, source_index=src_idx, source_powers_w=powers,
                                  materials=materials, max_reflections=job.rays.max_reflections,
                                  ground_sound_speed=float(profile.sound_speed(ground_point)[0]))
    return mesh, buffers, powers


def build_report(job: Job, profile_desc: dict[str, Any], representation: str, reason: str,
                 mesh_stats: dict[str, Any], result: TraceResult, timings: dict[str, float],
                 stages: dict[str, str]) -> dict[str, Any]:
    """The JSON report: stages, timings, mesh stats, rays by status, crossings."""
    crossings = int(result.crossings.sum())
    steps = int(result.steps.sum()) if result.steps is not None else None
    trace_s = timings.get("trace", 0.0)
    return {
        "name": job.name,
        "bentray_version": bentray.__version__,
        "profile": profile_desc,
        "solver": job.solver.model_dump(mode="json"),
        "representation": representation,
        "representation_reason": reason,
        "stages": stages,
        "timings_s": timings,
        "mesh": mesh_stats,
        "rays": {
            "total": result.n_rays,
            "by_status": result.status_counts(),
            "reflections_total": int(result.reflections.sum()),
            "tet_crossings_total": crossings,
            "crossings_per_ray_mean": crossings / max(result.n_rays, 1),
            "segments_total": steps,
            "nudges_total": int(result.nudges.sum()),
            "rays_nudged": int(np.count_nonzero(result.nudges)),
        },
        "throughput": {
            "crossings_per_s": crossings / trace_s if trace_s > 0 else None,
            "rays_per_s": result.n_rays / trace_s if trace_s > 0 else None,
            "note": "trace time includes Numba compilation on a cold cache",
        },
        "machine": {"numba_threads": int(numba.get_num_threads()), "cpu_count": os.cpu_count()},
    }

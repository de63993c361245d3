"""Orchestration: Job -> profile -> media representation -> launch fan -> kernels -> JobOutcome.

Plain Python; the per-ray work happens in the Numba kernels. Each stage is timed; the report says
which stages ran and why the others did not.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numba
import numpy as np

import bentray
from bentray.engine import field as field_stage
from bentray.engine.constants import CURVE_QUANTITY
from bentray.engine.errors import JobInputError
from bentray.engine.field_buffers import FieldBuffers
from bentray.engine.ground_profile import AboveGround
from bentray.engine.media import build_media, build_terrain_media
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.result import JobOutcome, TraceResult, concat_traces
from bentray.engine.surfaces import SceneSurfaces
from bentray.engine.tracer import trace
from bentray.engine.wind import sizing_quantity
from bentray.scenes.library.registry import get_builtin
from bentray.scenes.profile_models import profile_from_spec
from bentray.scenes.scene_models import check_points_above_ground, surfaces_from_specs
from bentray.scenes.schema import Job
from bentray.scenes.wind_models import wind_from_spec


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
    """Record sampled paths? See :func:`bentray.scenes.cost.records_paths` (by default only for 'paths',
    or for 'rays' up to DEFAULT_PATH_RAYS rays)."""
    from bentray.scenes.cost import records_paths

    return records_paths(job)


@dataclass
class TracePlan:
    """Everything a ray batch needs, as plain arrays (picklable: sent once to scale-out workers).

    origins, directions : (n, 3) float64, metres / unit vectors, world frame; start_cells : (n,) int64.
    field : accumulator template (zero-size weights are taken per batch from ``field_weights``) or None.
    baseline : None for the analytic curves, else the numerical method's keyword arguments.
    """

    mesh: CellMesh
    curve: str
    c_ref: float
    wind: tuple[int, np.ndarray] | None
    origins: np.ndarray
    directions: np.ndarray
    start_cells: np.ndarray
    max_time_s: float
    max_reflections: int
    max_steps: int
    path_samples: int
    field: FieldBuffers | None = None
    field_weights: np.ndarray | None = None
    baseline: dict[str, Any] | None = None
    source: np.ndarray | None = None  # (n,) int64 source index per ray (source-major); None: one source

    @property
    def n_rays(self) -> int:
        return int(self.origins.shape[0])

    def batches(self, batch_rays: int) -> list[tuple[int, int]]:
        """Consecutive [start, stop) ray ranges: per source, then blocks of at most ``batch_rays`` rays
        of its launch fan (a range never straddles two sources; rays are source-major)."""
        n = self.n_rays
        size = max(int(batch_rays), 1)
        if self.source is None or n == 0:
            return [(a, min(a + size, n)) for a in range(0, n, size)] or [(0, 0)]
        cuts = np.concatenate([[0], np.nonzero(np.diff(self.source))[0] + 1, [n]]).tolist()
        spans = zip(cuts[:-1], cuts[1:], strict=True)
        return [(a, min(a + size, hi)) for lo, hi in spans for a in range(lo, hi, size)]


@dataclass
class BatchResult:
    """One batch's rays (in order) and its collapsed partial field; restarts for the baselines."""

    start: int
    stop: int
    trace: TraceResult
    field: FieldBuffers | None = None
    restarts: np.ndarray | None = None
    seconds: float = 0.0


def trace_batch(plan: TracePlan, start: int, stop: int) -> BatchResult:
    """Trace rays ``start:stop`` of the plan (in this process, numba threads) and collapse its field."""
    t0 = time.perf_counter()
    sl = slice(start, stop)
    restarts = None
    buffers = None
    if plan.baseline is not None:
        from bentray.engine.baselines.trace_numerical import trace_numerical

        result, restarts = trace_numerical(
            plan.baseline["method"],
            plan.baseline["media"],
            mesh=plan.mesh,
            quantity=plan.baseline["quantity"],
            exact_spec=plan.baseline["exact_spec"],
            c_ref=plan.c_ref,
            origins=plan.origins[sl],
            directions=plan.directions[sl],
            start_cells=plan.start_cells[sl],
            max_time_s=plan.max_time_s,
            max_reflections=plan.max_reflections,
            max_steps=plan.max_steps,
            step_m=plan.baseline["step_m"],
            tolerance=plan.baseline["tolerance"],
            path_samples=plan.path_samples,
            domain_min=plan.baseline["domain_min"],
            domain_max=plan.baseline["domain_max"],
            ground_z=plan.baseline["ground_z"],
            top=plan.baseline["top"],
        )
    else:
        if plan.field is not None:
            assert plan.field_weights is not None
            buffers = plan.field.like(plan.field_weights[sl])
        result = trace(
            plan.mesh,
            plan.curve,
            plan.c_ref,
            plan.origins[sl],
            plan.directions[sl],
            plan.start_cells[sl],
            max_time_s=plan.max_time_s,
            max_reflections=plan.max_reflections,
            max_steps=plan.max_steps,
            path_samples=plan.path_samples,
            field=buffers,
            wind=plan.wind,
        )
        if buffers is not None:
            buffers.collapse(ray_offset=start)
    return BatchResult(start, stop, result, buffers, restarts, time.perf_counter() - t0)


def combine_batches(parts: list[BatchResult]) -> tuple[TraceResult, FieldBuffers | None, np.ndarray | None]:
    """Rays concatenated in order, partial fields summed in batch order (the same order on any executor)."""
    parts = sorted(parts, key=lambda b: b.start)
    trace_result = concat_traces([b.trace for b in parts])
    field_sum = None
    if parts[0].field is not None:
        field_sum = parts[0].field
        for b in parts[1:]:
            if b.field is not None:  # None: already summed, in batch order, into an earlier one (dask_executor)
                field_sum.add(b.field)
    restarts = None
    if parts[0].restarts is not None:
        restarts = np.concatenate([b.restarts for b in parts if b.restarts is not None])
    return trace_result, field_sum, restarts


class InOrderSum:
    """Sums batch partial fields in batch order as the batches arrive, so the client holds only the
    out-of-order window instead of every partial field (a 1e6-point, 8-band grid is 72 MB per batch).

    The first batch keeps the running sum; each later batch's field is added into it when all earlier
    batches are in, then dropped (``field = None``): ``combine_batches`` gives the same bits as summing
    every partial field at the end.
    """

    def __init__(self, ranges: list[tuple[int, int]]) -> None:
        self._order = sorted(a for a, _ in ranges)
        self._next = 0
        self._pending: dict[int, BatchResult] = {}
        self._head: BatchResult | None = None

    def push(self, part: BatchResult) -> None:
        if part.field is None:
            return
        self._pending[part.start] = part
        while self._next < len(self._order) and self._order[self._next] in self._pending:
            ready = self._pending.pop(self._order[self._next])
            self._next += 1
            if self._head is None:
                self._head = ready
            else:
                assert self._head.field is not None and ready.field is not None
                self._head.field.add(ready.field)
                ready.field = None


ProgressFn = Callable[[str, float], None]


class LocalExecutor:
    """Runs the batches one after another in this process (each batch uses every numba thread)."""

    name = "local"

    def run_batches(
        self, plan: TracePlan, ranges: list[tuple[int, int]], on_batch: Callable[[BatchResult], None] | None = None
    ) -> list[BatchResult]:
        """Trace the ranges in order; each batch's partial field is added into the first one at once
        (the same order, hence the same bits, as summing them all at the end), so one is held at a time."""
        out = []
        fold = InOrderSum(ranges)
        for a, b in ranges:
            part = trace_batch(plan, a, b)
            fold.push(part)
            out.append(part)
            if on_batch is not None:
                on_batch(part)
        return out

    def describe(self) -> str:
        return f"local process, {numba.get_num_threads()} numba threads"


def default_executor() -> Any:
    """The executor selected by configuration: ``BENTRAY_DASK_SCHEDULER`` (scale-out) or local."""
    address = os.environ.get("BENTRAY_DASK_SCHEDULER", "").strip()
    if address:
        from bentray.engine.dask_executor import DaskExecutor  # optional dependency

        return DaskExecutor(address)
    return LocalExecutor()


def run_job(
    job: Job, base_dir: Path | None = None, *, progress: ProgressFn | None = None, executor: Any = None
) -> JobOutcome:
    """Run a validated job and return everything it produced (nothing is written).

    progress(stage, fraction) is called at each stage and after each ray batch (fraction of the whole
    job, 0..1). executor: an object with ``run_batches(plan, ranges, on_batch)`` (default: local, or
    Dask when ``BENTRAY_DASK_SCHEDULER`` is set).
    """
    report_progress: ProgressFn = progress or (lambda stage, fraction: None)
    timings: dict[str, float] = {}
    stages: dict[str, str] = {}
    solver = job.solver
    report_progress("profile", 0.0)

    t0 = time.perf_counter()
    profile = profile_from_spec(job.profile, base_dir=str(base_dir) if base_dir is not None else None)
    timings["profile"] = time.perf_counter() - t0
    stages["profile"] = f"ran: {profile.kind}"
    wind = wind_from_spec(job.wind) if job.wind is not None else None
    stages["wind"] = (
        f"ran: {job.wind.kind} wind, effective sound speed c + u . e per ray azimuth"
        if job.wind is not None
        else "skipped: no wind (no wind arrays)"
    )

    domain = job.scene.box
    lo = np.asarray(domain.min, float)
    hi = np.asarray(domain.max, float)
    report_progress("scene", 0.02)
    t0 = time.perf_counter()
    surfaces = load_surfaces(job, base_dir)
    timings["scene"] = time.perf_counter() - t0
    stages["scene"] = (
        f"ran: {_describe_surfaces(surfaces)}"
        if surfaces is not None
        else "skipped: flat ground, no terrain or buildings (no constrained meshing)"
    )
    profile = _profile_heights(job, profile, surfaces, lo, hi)
    stages["profile"] += f", heights {job.scene.profile_heights.replace('_', ' ')}"
    report_progress("mesh", 0.05)
    t0 = time.perf_counter()
    mesh_curve = solver.mesh_curve
    if solver.is_baseline and solver.media == "exact":
        # the closed-form profile is integrated directly: the mesh only locates nothing; one box cell
        media = build_media(
            profile,
            mesh_curve,
            solver.model_copy(update={"representation": "uniform"}) if profile.kind == "homogeneous" else solver,
            lo,
            hi,
            ground="reflect",
            top=job.scene.top.kind,
        )
    elif surfaces is not None and surfaces.obstacles:
        from bentray.engine.media_obstacles import build_obstacle_media  # pytetwild (optional)

        media = build_obstacle_media(profile, mesh_curve, solver, lo, hi, surfaces, top=job.scene.top.kind)
    elif surfaces is not None:
        qfn = sizing_quantity(profile.sound_speed, profile.c_ref, wind, CURVE_QUANTITY[mesh_curve]) if wind else None
        media = build_terrain_media(
            profile, mesh_curve, solver, lo, hi, surfaces, top=job.scene.top.kind, quantity_fn=qfn
        )
    else:
        media = build_media(profile, mesh_curve, solver, lo, hi, ground="reflect", top=job.scene.top.kind, wind=wind)
    timings["mesh"] = time.perf_counter() - t0
    stages["mesh"] = f"ran: {media.representation} ({media.reason})"

    origins, dirs, src_idx, el, az = launch_fan(job)
    t0 = time.perf_counter()
    src_pos = np.array([s.position for s in job.sources], float)
    if surfaces is not None:
        check_points_above_ground(
            surfaces,
            src_pos,
            [f"sources.{i}.position" for i in range(len(src_pos))],
            flat_ground_z=float(lo[2]) if surfaces.terrain is None else None,
        )
    src_cells = media.locate(src_pos)
    bad = np.nonzero(src_cells < 0)[0]
    if bad.size:
        i = int(bad[0])
        raise JobInputError(f"sources.{i}.position: {list(src_pos[i])} is not inside the media mesh")
    start_cells = src_cells[src_idx]
    timings["locate"] = time.perf_counter() - t0

    record = _wants_paths(job)
    mesh = media.mesh
    template = None
    powers = None
    materials: list[float | None] = []
    if job.field is not None:
        t0 = time.perf_counter()
        materials = _materials(job, surfaces)
        mesh, template, powers = _prepare_field(job, profile, mesh, src_idx, materials)
        timings["field_setup"] = time.perf_counter() - t0
    plan = TracePlan(
        mesh=mesh,
        curve=mesh_curve,
        c_ref=float(profile.c_ref),
        wind=wind,
        origins=origins,
        directions=dirs,
        start_cells=start_cells,
        max_time_s=job.rays.max_time_s,
        max_reflections=job.rays.max_reflections,
        max_steps=job.rays.max_steps,
        path_samples=solver.path_samples if record else 0,
        field=template,
        field_weights=template.weights if template is not None else None,
        baseline=_baseline_args(job, profile, lo, hi) if solver.is_baseline else None,
        source=src_idx,
    )

    runner = executor if executor is not None else default_executor()
    ranges = plan.batches(solver.batch_rays)
    done = [0]

    def on_batch(part: BatchResult) -> None:
        done[0] += part.stop - part.start
        report_progress("trace", min(0.1 + 0.8 * done[0] / max(plan.n_rays, 1), 0.9))

    report_progress("trace", 0.1)
    t0 = time.perf_counter()
    parts = runner.run_batches(plan, ranges, on_batch)
    result, buffers, restarts = combine_batches(parts)
    timings["trace"] = time.perf_counter() - t0
    how = (
        f"numerical baseline {solver.curve} on {solver.media or 'mesh'} media"
        if solver.is_baseline
        else f"{solver.curve} curve"
    )
    stages["trace"] = f"ran: {how}, {result.n_rays} rays in {len(ranges)} batch(es) on {runner.describe()}" + (
        " (field accumulated along the curves)" if template else ""
    )
    stages["paths"] = "ran: sampled on the true curves" if record else "skipped: no 'rays' or 'paths' output"
    result.source = src_idx
    result.elevation_deg = el
    result.azimuth_deg = az
    report_progress("field", 0.9)
    field_arrays = None
    if job.field is not None and buffers is not None:
        t0 = time.perf_counter()
        grid_points = buffers.grid.points()
        field_arrays = field_stage.finalize(
            job.field, buffers, profile.sound_speed(grid_points), result, powers, materials
        )
        field_arrays.preview = {
            "source_xyz": list(job.sources[0].position),
            "receiver_z": float(lo[2] + job.field.receiver_height_m),
            "title": f"{job.name}: {profile.kind} profile, {result.n_rays} rays",
        }
        if surfaces is not None and surfaces.terrain is not None:
            from bentray.engine.mesh.terrain import terrain_height_function

            g = buffers.grid
            gx = g.origin[0] + g.spacing[0] * np.arange(g.shape[0])
            gy = g.origin[1] + g.spacing[1] * np.arange(g.shape[1])
            xy = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
            field_arrays.preview["ground_z"] = terrain_height_function(surfaces.terrain, lo, hi)(xy).reshape(
                g.shape[0], g.shape[1]
            )
            field_arrays.preview["receiver_height_m"] = float(job.field.receiver_height_m)
        field_arrays.stats["fan_spacing"] = field_stage.fan_spacing_advice(
            job.field,
            np.array([src.position for src in job.sources]),
            job.rays.elevation_deg.values(),
            job.rays.azimuth_deg.values(),
        )
        timings["field_finalize"] = time.perf_counter() - t0
        stages["field"] = (
            f"ran: {job.field.mode}, {buffers.grid.n_points} points, {len(job.field.frequencies_hz)} bands"
        )
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

    report = build_report(
        job, profile.describe(), media.representation, media.reason, media.stats, result, timings, stages
    )
    report["batches"] = {"count": len(ranges), "batch_rays": solver.batch_rays, "executor": runner.name}
    if job.wind is not None:
        report["wind"] = job.wind.model_dump(mode="json")
    if restarts is not None:
        report["rays"]["restarts_total"] = int(restarts.sum())
    if field_arrays is not None:
        report["field"] = field_arrays.stats
    report_progress("done", 1.0)
    return JobOutcome(trace=result, mesh_geometry=geometry, report=report, field=field_arrays)


def _profile_heights(job: Job, profile, surfaces: SceneSurfaces | None, lo: np.ndarray, hi: np.ndarray):
    """The profile measured from the ground (scene.profile_heights = "above_ground", the default) or in
    world z. Nothing changes over flat ground at z = 0 or for a homogeneous medium."""
    if job.scene.profile_heights == "absolute" or profile.kind == "homogeneous":
        return profile
    if surfaces is None or surfaces.terrain is None:
        if float(lo[2]) == 0.0:
            return profile
        ground_z = float(lo[2])
        return AboveGround(profile, lambda xy: np.full(len(xy), ground_z), flat=True)
    from bentray.engine.mesh.terrain import terrain_height_function

    return AboveGround(profile, terrain_height_function(surfaces.terrain, lo, hi), flat=False)


def _baseline_args(job: Job, profile, lo: np.ndarray, hi: np.ndarray) -> dict[str, Any]:
    """Keyword arguments of engine.baselines.trace_numerical for the job's solver."""
    from bentray.engine.baselines.exact_media import exact_media_spec

    solver = job.solver
    media = solver.media or "mesh"
    if media == "exact" and isinstance(profile, AboveGround):
        raise JobInputError(
            "solver.media: 'exact' integrates the closed-form profile in world z, but the domain "
            f"bottom is at z = {lo[2]:g} m and scene.profile_heights is 'above_ground'; "
            "set scene.profile_heights to 'absolute' or put the ground at z = 0"
        )
    exact = exact_media_spec(profile) if media == "exact" else None
    adaptive = solver.curve in ("euler_adaptive", "dopri5")
    return {
        "method": solver.curve,
        "media": media,
        "quantity": CURVE_QUANTITY[solver.mesh_curve],
        "exact_spec": exact,
        # defaults: 1 m fixed steps (the GPU paper's order of magnitude); adaptive: 1e-8 m local error
        "step_m": solver.step_m if solver.step_m is not None else 1.0,
        "tolerance": solver.tolerance if solver.tolerance is not None else (1e-8 if adaptive else 1e-8),
        "domain_min": lo,
        "domain_max": hi,
        "ground_z": float(lo[2]),
        "top": job.scene.top.kind,
    }


def _materials(job: Job, surfaces: SceneSurfaces | None) -> list[float | None]:
    """Flow resistivity per face material index (None = rigid): the scene's table, or flat ground's."""
    if surfaces is not None:
        return [m.flow_resistivity for m in surfaces.materials]
    return [None, job.scene.ground.flow_resistivity]


def _prepare_field(job: Job, profile, mesh: CellMesh, src_idx: np.ndarray, materials: list[float | None]):
    """Ground material on the mesh, source powers (W) and the accumulator template (per-ray launch weights,
    tables; no slots: each batch allocates its own)."""
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
        powers = np.array(
            [[field_stage.W_REF * 10.0 ** (src.power_db[b] / 10.0) for b in spec.labels] for src in job.sources]
        )
    buffers = field_stage.prepare(
        spec,
        ray_weights=weights,
        source_index=src_idx,
        source_powers_w=powers,
        materials=materials,
        max_reflections=job.rays.max_reflections,
        ground_sound_speed=float(profile.sound_speed(ground_point)[0]),
        n_slots=0,
    )
    return mesh, buffers, powers


def build_report(
    job: Job,
    profile_desc: dict[str, Any],
    representation: str,
    reason: str,
    mesh_stats: dict[str, Any],
    result: TraceResult,
    timings: dict[str, float],
    stages: dict[str, str],
) -> dict[str, Any]:
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

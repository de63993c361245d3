"""The stages of a job, one function each, called in order by :func:`bentray.engine.run.run_job`.

Each stage records its wall time and what it did ("ran: ...") or why it did not ("skipped: ...") in
a :class:`StageLog`; the report carries both.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bentray.engine import beam_field
from bentray.engine import field as field_stage
from bentray.engine.compile_time import CompileTime, compile_timer
from bentray.engine.constants import BOUNDARY_REFLECT, CURVE_QUANTITY
from bentray.engine.eigenray_stage import ArrivalTable, eigenray_decision, run_eigenrays
from bentray.engine.errors import JobInputError
from bentray.engine.executors import Executor
from bentray.engine.field_buffers import FieldBuffers
from bentray.engine.ground_profile import AboveGround
from bentray.engine.media import Media, Wind, build_media, build_terrain_media
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.mesh.hessian import hessian_of
from bentray.engine.profiles import Profile
from bentray.engine.result import MeshGeometry, TraceResult
from bentray.engine.surfaces import SceneSurfaces
from bentray.engine.trace_plan import BaselineSpec, TracePlan
from bentray.engine.wind import sizing_quantity
from bentray.scenes.directivity_models import ray_amplitudes
from bentray.scenes.profile_models import profile_from_spec
from bentray.scenes.scene_models import check_points_above_ground, scene_surfaces
from bentray.scenes.schema import Job
from bentray.scenes.wind_models import wind_from_spec

ProgressFn = Callable[[str, float], None]

__all__ = [
    "FieldSetup",
    "LaunchFan",
    "ProgressFn",
    "StageLog",
    "Traced",
    "baseline_spec",
    "build_plan",
    "launch_fan",
    "load_surfaces",
    "stage_field",
    "stage_eigenrays",
    "stage_field_setup",
    "stage_locate",
    "stage_mesh",
    "stage_mesh_output",
    "stage_profile",
    "stage_profile_heights",
    "stage_scene",
    "stage_trace",
]


@dataclass
class StageLog:
    """Seconds per timed stage and one line per stage, in the order the stages ran."""

    timings: dict[str, float] = field(default_factory=dict)
    stages: dict[str, str] = field(default_factory=dict)
    compile_s: dict[str, float] = field(default_factory=dict)  # Numba compilation inside each stage (s)
    compiled_functions: int = 0

    def copy(self) -> StageLog:
        """An independent log holding everything recorded so far (a run continues from its prepared stages)."""
        return StageLog(dict(self.timings), dict(self.stages), dict(self.compile_s), self.compiled_functions)

    @contextmanager
    def timed(self, name: str) -> Iterator[None]:
        """Time the ``with`` body as ``timings[name]`` (seconds, compilation included) and the Numba
        compilation inside it as ``compile_s[name]`` (engine.compile_time; stages that compiled nothing
        are left out)."""
        t0 = time.perf_counter()
        with compile_timer() as ct:
            yield
        self.timings[name] = time.perf_counter() - t0
        self._add_compile(name, ct)

    @contextmanager
    def compiling(self, name: str) -> Iterator[None]:
        """Only the Numba compilation inside the ``with`` body, as ``compile_s[name]``: for stages that time
        themselves (diffraction, terrain screening, the wave and shadow stages set ``timings`` from their own
        clocks). A compile outside the stage's own clock still counts in its time: ``timings[name]`` becomes at
        least the wall time of the ``with`` body when anything compiled."""
        t0 = time.perf_counter()
        with compile_timer() as ct:
            yield
        if ct.functions:
            self.timings[name] = max(self.timings.get(name, 0.0), time.perf_counter() - t0)
        self._add_compile(name, ct)

    def _add_compile(self, name: str, ct: CompileTime) -> None:
        if ct.functions:
            self.compile_s[name] = self.compile_s.get(name, 0.0) + ct.seconds
            self.compiled_functions += ct.functions


class LaunchFan(NamedTuple):
    """Every ray of the job, source-major, then elevation, then azimuth.

    origins (n, 3) metres and directions (n, 3) unit vectors, world frame; source (n,) int64 source index;
    elevation_deg, azimuth_deg (n,) launch angles in degrees.
    """

    origins: np.ndarray
    directions: np.ndarray
    source: np.ndarray
    elevation_deg: np.ndarray
    azimuth_deg: np.ndarray


class FieldSetup(NamedTuple):
    """The field stage's preparation: the mesh with ground materials, the accumulator template (None: no
    field), source powers (n_sources, n_bands) W (None: unit power) and flow resistivity per material."""

    mesh: CellMesh
    template: FieldBuffers | beam_field.BeamBuffers | None
    powers: np.ndarray | None
    materials: list[float | None]
    receivers_xyz: np.ndarray | None = None  # (P, 3) m, the job's receivers with heights resolved


@dataclass
class Traced:
    """The trace stage's output: rays, the summed field accumulators, baseline restarts, batch count."""

    result: TraceResult
    buffers: FieldBuffers | None
    restarts: np.ndarray | None
    n_batches: int


def launch_fan(job: Job) -> LaunchFan:
    """Origins, unit directions, source index, elevation and azimuth (degrees) of every ray.

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
    return LaunchFan(
        origins,
        np.tile(dirs, (n_src, 1)),
        np.repeat(np.arange(n_src, dtype=np.int64), per),
        np.tile(el_f, n_src),
        np.tile(az_f, n_src),
    )


def load_surfaces(job: Job, base_dir: Path | None = None) -> SceneSurfaces | None:
    """The scene's terrain, buildings and materials (None: flat ground only, no constrained meshing)."""
    return scene_surfaces(job.scene, base_dir)


def _domain(job: Job) -> tuple[np.ndarray, np.ndarray]:
    box = job.scene.box
    return np.asarray(box.min, float), np.asarray(box.max, float)


# --- stages, in the order run_job calls them ------------------------------------------------------
def stage_profile(job: Job, base_dir: Path | None, log: StageLog) -> tuple[Profile, Wind | None]:
    """The sound-speed profile (as a law of world z; see :func:`stage_profile_heights`) and the wind."""
    with log.timed("profile"):
        profile = profile_from_spec(job.profile, base_dir=str(base_dir) if base_dir is not None else None)
    log.stages["profile"] = f"ran: {profile.kind}"
    wind = wind_from_spec(job.wind) if job.wind is not None else None
    log.stages["wind"] = (
        f"ran: {job.wind.kind} wind, effective sound speed c + u . e per ray azimuth"
        if job.wind is not None
        else "skipped: no wind (no wind arrays)"
    )
    return profile, wind


def stage_scene(job: Job, base_dir: Path | None, log: StageLog) -> SceneSurfaces | None:
    """The scene's surfaces (terrain, buildings, obstacles, materials), None for flat ground only."""
    with log.timed("scene"):
        surfaces = load_surfaces(job, base_dir)
    log.stages["scene"] = (
        f"ran: {_describe_surfaces(surfaces)}"
        if surfaces is not None
        else "skipped: flat ground, no terrain or buildings (no constrained meshing)"
    )
    return surfaces


def _describe_surfaces(surfaces: SceneSurfaces) -> str:
    terrain = type(surfaces.terrain).__name__ if surfaces.terrain is not None else "flat ground"
    return f"{terrain}, {len(surfaces.footprints)} buildings, {len(surfaces.materials)} materials"


def stage_profile_heights(job: Job, profile: Profile, surfaces: SceneSurfaces | None, log: StageLog) -> Profile:
    """The profile measured from the ground (scene.profile_heights = "above_ground", the default) or in
    world z. Nothing changes over flat ground at z = 0 or for a homogeneous medium."""
    log.stages["profile"] += f", heights {job.scene.profile_heights.replace('_', ' ')}"
    lo, hi = _domain(job)
    if job.scene.profile_heights == "absolute" or profile.kind == "homogeneous":
        return profile
    if surfaces is None or surfaces.terrain is None:
        if float(lo[2]) == 0.0:
            return profile
        ground_z = float(lo[2])
        return AboveGround(profile, lambda xy: np.full(len(xy), ground_z), flat=True)
    from bentray.engine.mesh.terrain import terrain_height_function

    return AboveGround(profile, terrain_height_function(surfaces.terrain, lo, hi), flat=False)


def stage_mesh(job: Job, profile: Profile, surfaces: SceneSurfaces | None, wind: Wind | None, log: StageLog) -> Media:
    """The media representation: one box cell (baselines on exact media), an obstacle mesh (fTetWild), a
    terrain-following mesh, or the flat-ground slabs / tetrahedra."""
    solver = job.solver
    lo, hi = _domain(job)
    mesh_curve = solver.mesh_curve
    top = job.scene.top.kind
    with log.timed("mesh"):
        if solver.is_baseline and solver.media == "exact":
            # the closed-form profile is integrated directly: the mesh only locates nothing; one box cell
            uniform = solver.model_copy(update={"representation": "uniform"})
            media = build_media(
                profile,
                mesh_curve,
                uniform if profile.kind == "homogeneous" else solver,
                lo,
                hi,
                ground="reflect",
                top=top,
            )
        elif surfaces is not None and surfaces.obstacles:
            from bentray.engine.media_obstacles import build_obstacle_media  # pytetwild (optional)

            media = build_obstacle_media(profile, mesh_curve, solver, lo, hi, surfaces, top=top)
        elif surfaces is not None:
            quantity = CURVE_QUANTITY[mesh_curve]
            qfn = sizing_quantity(profile.sound_speed, profile.c_ref, wind, quantity) if wind else None
            media = build_terrain_media(profile, mesh_curve, solver, lo, hi, surfaces, top=top, quantity_fn=qfn)
        else:
            media = build_media(profile, mesh_curve, solver, lo, hi, ground="reflect", top=top, wind=wind)
    log.stages["mesh"] = f"ran: {media.representation} ({media.reason})"
    return media


def stage_locate(
    job: Job, media: Media, surfaces: SceneSurfaces | None, source_index: np.ndarray, log: StageLog
) -> np.ndarray:
    """(n,) int64 start cell of every ray; raises JobInputError naming a source below the ground or
    outside the media mesh."""
    lo, _ = _domain(job)
    with log.timed("locate"):
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
        start_cells = src_cells[source_index]
    return start_cells


def _materials(job: Job, surfaces: SceneSurfaces | None) -> list[float | None]:
    """Flow resistivity per face material index (None = rigid): the scene's table, or flat ground's."""
    if surfaces is not None:
        return [m.flow_resistivity for m in surfaces.materials]
    return [None, job.scene.ground.flow_resistivity]


def resolve_receivers(job: Job, surfaces: SceneSurfaces | None) -> np.ndarray:
    """(P, 3) receiver points (m): absolute positions as given, ``xy`` + ``height_above_ground_m`` on the
    terrain (or the flat ground at the domain bottom). Every point must be above the ground and outside
    buildings (SceneSpecError naming ``receivers.<i>.position``)."""
    lo, hi = _domain(job)
    xyz = np.zeros((len(job.receivers), 3))
    rel = []
    for i, rec in enumerate(job.receivers):
        if rec.position is not None:
            xyz[i] = rec.position
        else:
            xyz[i, :2] = rec.horizontal
            rel.append(i)
    if rel:
        idx = np.asarray(rel)
        if surfaces is not None and surfaces.terrain is not None:
            from bentray.engine.mesh.terrain import terrain_height_function

            ground = np.asarray(terrain_height_function(surfaces.terrain, lo, hi)(xyz[idx, :2]), float)
        else:
            ground = np.full(idx.size, float(lo[2]))
        heights = np.array([job.receivers[i].height_above_ground_m or 0.0 for i in rel])
        xyz[idx, 2] = ground + np.maximum(heights, 1e-6)
    names = [f"receivers.{i}.position" if r.position is not None else f"receivers.{i}.xy" for i, r in
             enumerate(job.receivers)]  # fmt: skip
    if surfaces is not None:
        check_points_above_ground(
            surfaces, xyz, names, flat_ground_z=float(lo[2]) if surfaces.terrain is None else None
        )
    bad = np.nonzero(~((xyz[:, 2] > lo[2]) & (xyz[:, 2] < hi[2])))[0]
    if bad.size:
        i = int(bad[0])
        raise JobInputError(f"{names[i]}: the receiver at z = {xyz[i, 2]:g} m is outside the domain's z range")
    return xyz


def _grid_columns(job: Job) -> tuple[np.ndarray, np.ndarray]:
    """x, y (nx * ny,) of the field grid's columns, i-major (the grid's point order)."""
    spec = job.field
    assert spec is not None
    gx = spec.origin[0] + spec.spacing[0] * np.arange(spec.shape[0])
    gy = spec.origin[1] + spec.spacing[1] * np.arange(spec.shape[1])
    x, y = np.meshgrid(gx, gy, indexing="ij")
    return x.reshape(-1), y.reshape(-1)


def _grid_ground_z(job: Job, surfaces: SceneSurfaces | None) -> np.ndarray:
    """(nx, ny) ground height (m) under each column of the field grid: the terrain, else the flat ground."""
    spec = job.field
    assert spec is not None
    lo, hi = _domain(job)
    nx, ny = spec.shape[0], spec.shape[1]
    if surfaces is None or surfaces.terrain is None:
        return np.full((nx, ny), float(lo[2]))
    from bentray.engine.mesh.terrain import terrain_height_function

    x, y = _grid_columns(job)
    return np.asarray(terrain_height_function(surfaces.terrain, lo, hi)(np.stack([x, y], axis=1)), float).reshape(
        nx, ny
    )


def _grid_ground_planes(job: Job, surfaces: SceneSurfaces | None) -> np.ndarray:
    """(nx, ny, 4) the ground's tangent plane under each column of the field grid: unit normal (up) and offset d
    (n.x = d), from central differences of the terrain height 1 m either side (flat ground: z = domain floor)."""
    spec = job.field
    assert spec is not None
    lo, hi = _domain(job)
    nx, ny = spec.shape[0], spec.shape[1]
    x, y = _grid_columns(job)
    if surfaces is None or surfaces.terrain is None:
        z = np.full(x.shape, float(lo[2]))
        sx = sy = np.zeros(x.shape)
    else:
        from bentray.engine.mesh.terrain import terrain_height_function

        height = terrain_height_function(surfaces.terrain, lo, hi)

        def at(px: np.ndarray, py: np.ndarray) -> np.ndarray:
            return np.asarray(height(np.stack([px, py], axis=1)), float)

        z = at(x, y)
        sx = (at(x + 1.0, y) - at(x - 1.0, y)) / 2.0
        sy = (at(x, y + 1.0) - at(x, y - 1.0)) / 2.0
    n = np.stack([-sx, -sy, np.ones_like(sx)], axis=1)
    n /= np.linalg.norm(n, axis=1)[:, None]
    d = n[:, 0] * x + n[:, 1] * y + n[:, 2] * z
    return np.concatenate([n, d[:, None]], axis=1).reshape(nx, ny, 4)


def stage_field_setup(
    job: Job,
    profile: Profile,
    mesh: CellMesh,
    surfaces: SceneSurfaces | None,
    source_index: np.ndarray,
    log: StageLog,
) -> FieldSetup:
    """Ground material on the mesh, source powers (W) and the accumulator template (per-ray launch weights,
    tables; no slots: each batch allocates its own). Without a field: the mesh as it is, nothing else."""
    spec = job.field
    if spec is None and not job.receivers:
        return FieldSetup(mesh, None, None, [])
    with log.timed("field_setup"):
        materials = _materials(job, surfaces)
        if job.scene.ground.flow_resistivity is not None and not job.scene.has_surfaces:
            mesh = field_stage.tag_ground_material(mesh, float(job.scene.box.min[2]), field_stage.GROUND_MATERIAL)
        lo = job.scene.box.min
        ground_point = np.array([[job.sources[0].position[0], job.sources[0].position[1], lo[2]]])
        powers = None
        receiver_bands = None
        if spec is None and job.sources[0].power_db is not None:
            receiver_bands = sorted(float(b) for b in job.sources[0].power_db)
        labels = spec.labels if spec is not None else beam_field.receiver_settings(receiver_bands).labels
        if job.sources[0].power_db is not None:
            powers = np.array(
                [[field_stage.W_REF * 10.0 ** (src.power_db[b] / 10.0) for b in labels] for src in job.sources]
            )
        receivers_xyz = resolve_receivers(job, surfaces) if job.receivers else None
        if spec is None or spec.method == "beams":
            beam_template = beam_field.prepare(
                spec,
                elevation_deg=np.asarray(job.rays.elevation_deg.values(), float),
                azimuth_deg=np.asarray(job.rays.azimuth_deg.values(), float),
                n_rays=len(source_index),
                source_index=source_index,
                source_powers_w=powers,
                materials=materials,
                max_reflections=job.rays.max_reflections,
                c_ref=float(profile.c_ref),
                ground_sound_speed=float(profile.sound_speed(ground_point)[0]),
                n_face_materials=int(mesh.face_material.max()) + 1 if mesh.face_material.size else 1,
                ground_z=_grid_ground_z(job, surfaces) if spec is not None and spec.heights == "above_ground" else None,
                ground_planes=_grid_ground_planes(job, surfaces) if beam_field.widens_incoherent_beams(spec) else None,
                receivers_xyz=receivers_xyz,
                receiver_bands=receiver_bands,
            )
            if job.wind is None and job.solver.curve == "parabolic":
                # the beams' smooth medium (docs/physics.md §11), once per job: it travels with every batch
                beam_template.tables = beam_template.tables._replace(hessian=hessian_of(mesh))
            return FieldSetup(mesh, beam_template, powers, materials, receivers_xyz)
        # voxels: each ray carries the power of its launch solid angle (a 3D fan)
        per_source = field_stage.launch_solid_angles(job.rays.elevation_deg.values(), job.rays.azimuth_deg.values())
        weights = np.tile(per_source, len(job.sources))
        buffers = field_stage.prepare(
            spec,
            ray_weights=weights,
            source_index=source_index,
            source_powers_w=powers,
            materials=materials,
            max_reflections=job.rays.max_reflections,
            ground_sound_speed=float(profile.sound_speed(ground_point)[0]),
            n_slots=0,
        )
    return FieldSetup(mesh, buffers, powers, materials)


def baseline_spec(job: Job, profile: Profile) -> BaselineSpec:
    """The numerical baseline's settings for the job's solver (defaults filled in)."""
    from bentray.engine.baselines.exact_media import exact_media_spec

    solver = job.solver
    lo, hi = _domain(job)
    media = solver.media or "mesh"
    if media == "exact" and isinstance(profile, AboveGround):
        raise JobInputError(
            "solver.media: 'exact' integrates the closed-form profile in world z, but the domain "
            f"bottom is at z = {lo[2]:g} m and scene.profile_heights is 'above_ground'; "
            "set scene.profile_heights to 'absolute' or put the ground at z = 0"
        )
    return BaselineSpec(
        method=solver.curve,
        media=media,
        quantity=CURVE_QUANTITY[solver.mesh_curve],
        exact_spec=exact_media_spec(profile) if media == "exact" else None,
        # defaults: 1 m fixed steps (the GPU paper's order of magnitude); 1e-8 m local error
        step_m=solver.step_m if solver.step_m is not None else 1.0,
        tolerance=solver.tolerance if solver.tolerance is not None else 1e-8,
        domain_min=lo,
        domain_max=hi,
        ground_z=float(lo[2]),
        top=job.scene.top.kind,
    )


def _wants_paths(job: Job) -> bool:
    """Record sampled paths? See :func:`bentray.scenes.cost.records_paths` (by default only for 'paths',
    or for 'rays' up to DEFAULT_PATH_RAYS rays)."""
    from bentray.scenes.cost import records_paths

    return records_paths(job)


def build_plan(
    job: Job, profile: Profile, wind: Wind | None, fan: LaunchFan, start_cells: np.ndarray, setup: FieldSetup
) -> TracePlan:
    """The trace plan: the mesh, the curve, every ray and what to accumulate along it."""
    solver = job.solver
    return TracePlan(
        mesh=setup.mesh,
        curve=solver.mesh_curve,
        c_ref=float(profile.c_ref),
        wind=wind,
        origins=fan.origins,
        directions=fan.directions,
        start_cells=start_cells,
        max_time_s=job.rays.max_time_s,
        max_reflections=job.rays.max_reflections,
        max_steps=job.rays.max_steps,
        path_samples=solver.path_samples if _wants_paths(job) else 0,
        field=setup.template,
        field_weights=setup.template.weights if setup.template is not None else None,
        baseline=baseline_spec(job, profile) if solver.is_baseline else None,
        source=fan.source,
        ray_amplitudes=_ray_amplitudes(job, fan, setup),
        device=solver.device,
    )


def _ray_amplitudes(job: Job, fan: LaunchFan, setup: FieldSetup) -> np.ndarray | None:
    """(n, F) pressure-amplitude factors of the sources' directivity toward each ray's launch direction
    (scenes/directivity_models.py), for beam fields; None when every source is omnidirectional."""
    template = setup.template
    if not isinstance(template, beam_field.BeamBuffers) or all(s.directivity is None for s in job.sources):
        return None
    settings = template.settings or job.field
    labels = list(settings.labels) if settings is not None else []
    out = np.ones((fan.directions.shape[0], len(labels)))
    for s, src in enumerate(job.sources):
        rows = fan.source == s
        out[rows] = ray_amplitudes(src.directivity, labels, fan.directions[rows])
    return out


def stage_trace(
    job: Job, plan: TracePlan, fan: LaunchFan, executor: Executor, progress: ProgressFn, log: StageLog
) -> Traced:
    """Trace the plan's batches on ``executor`` (progress 0.1 .. 0.9 as batches finish) and combine them."""
    from bentray.engine.batches import BatchResult, combine_batches

    solver = job.solver
    # a beam field is normalised per source (docs/physics.md §11), so each source's fan is one batch
    beams_on = isinstance(plan.field, beam_field.BeamBuffers)
    ranges = plan.batches(plan.n_rays if beams_on else solver.batch_rays)
    done = [0]

    def on_batch(part: BatchResult) -> None:
        done[0] += part.stop - part.start
        progress("trace", min(0.1 + 0.8 * done[0] / max(plan.n_rays, 1), 0.9))

    progress("trace", 0.1)
    with log.timed("trace"):
        parts = executor.run_batches(plan, ranges, on_batch)
        result, buffers, restarts = combine_batches(parts)
    how = (
        f"numerical baseline {solver.curve} on {solver.media or 'mesh'} media"
        if solver.is_baseline
        else f"{solver.curve} curve"
    )
    log.stages["trace"] = f"ran: {how}, {result.n_rays} rays in {len(ranges)} batch(es) on {executor.describe()}" + (
        " (field accumulated along the curves)" if plan.field else ""
    )
    log.stages["paths"] = (
        "ran: sampled on the true curves" if _wants_paths(job) else "skipped: no 'rays' or 'paths' output"
    )
    result.source = fan.source
    result.elevation_deg = fan.elevation_deg
    result.azimuth_deg = fan.azimuth_deg
    return Traced(result, buffers, restarts, len(ranges))


def stage_field(
    job: Job,
    profile: Profile,
    surfaces: SceneSurfaces | None,
    traced: Traced,
    setup: FieldSetup,
    log: StageLog,
) -> field_stage.FieldArrays | None:
    """Levels on the field grid from the summed accumulators, the preview's extras and fan-spacing advice."""
    spec = job.field
    buffers = traced.buffers
    if spec is None or buffers is None or (isinstance(buffers, beam_field.BeamBuffers) and buffers.grid is None):
        log.stages["field"] = "skipped: no field requested"
        return None
    lo, hi = _domain(job)
    result = traced.result
    with log.timed("field_finalize"):
        if isinstance(buffers, beam_field.BeamBuffers):
            field_arrays = beam_field.finalize(spec, buffers)
        else:
            grid_points = buffers.grid.points()
            field_arrays = field_stage.finalize(
                spec, buffers, profile.sound_speed(grid_points), result, setup.powers, setup.materials
            )
        above = spec.heights == "above_ground"
        field_arrays.preview = {
            "source_xyz": list(job.sources[0].position),
            "receiver_z": float((0.0 if above else lo[2]) + spec.receiver_height_m),
            "title": f"{job.name}: {profile.kind} profile, {result.n_rays} rays"
            + (" (heights above the ground)" if above else ""),
        }
        if above:
            field_arrays.field_data["grid"] = (
                "point (i,j,k) at x, y = origin + (i,j)*spacing and at origin_z + k*spacing_z metres ABOVE THE "
                "GROUND under it (terrain-following map); NaN: no beam reached the point"
            )
        if surfaces is not None and surfaces.terrain is not None and not above:
            from bentray.engine.mesh.terrain import terrain_height_function

            g = buffers.grid
            gx = g.origin[0] + g.spacing[0] * np.arange(g.shape[0])
            gy = g.origin[1] + g.spacing[1] * np.arange(g.shape[1])
            xy = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
            field_arrays.preview["ground_z"] = terrain_height_function(surfaces.terrain, lo, hi)(xy).reshape(
                g.shape[0], g.shape[1]
            )
            field_arrays.preview["receiver_height_m"] = float(spec.receiver_height_m)
        if surfaces is not None and surfaces.footprints:
            field_arrays.preview["footprints"] = [np.asarray(fp.polygon, float) for fp in surfaces.footprints]
        field_arrays.stats["fan_spacing"] = field_stage.fan_spacing_advice(
            spec,
            np.array([src.position for src in job.sources]),
            job.rays.elevation_deg.values(),
            job.rays.azimuth_deg.values(),
        )
    how = "paraxial beams" if isinstance(buffers, beam_field.BeamBuffers) else "voxel ray density"
    log.stages["field"] = f"ran: {spec.mode} ({how}), {buffers.grid.n_points} points, {len(spec.frequencies_hz)} bands"
    return field_arrays


def stage_receivers(job: Job, traced: Traced, setup: FieldSetup, log: StageLog) -> beam_field.ReceiverTable | None:
    """Receiver levels (receivers.csv) from the beam accumulators at the job's receiver points."""
    buffers = traced.buffers
    if not job.receivers or not isinstance(buffers, beam_field.BeamBuffers) or setup.receivers_xyz is None:
        log.stages["receivers"] = "skipped: no receivers in the job"
        return None
    with log.timed("receivers"):
        table = beam_field.finalize_receivers(job.field, buffers, [r.id for r in job.receivers], setup.receivers_xyz)
    log.stages["receivers"] = (
        f"ran: {len(job.receivers)} receivers, coherent and incoherent levels from the beams "
        f"({table.stats['without_beams']} reached by no beam)"
    )
    return table


def reflecting_walls(job: Job, surfaces: SceneSurfaces | None) -> np.ndarray:
    """(W, 6) outer walls [x0, y0, x1, y1, z_lo, z_hi] of the scene's buildings (m, local frame), outside
    on the right of x0 -> x1 (footprints are counter-clockwise); barriers are not in the mesh (they do not
    reflect) and courtyard walls are left out."""
    from bentray.scenes.scene_models import footprint_bases

    if surfaces is None or not surfaces.footprints:
        return np.zeros((0, 6))
    z0 = float(job.scene.box.min[2])
    bases = footprint_bases(surfaces.terrain, surfaces.footprints, z0)
    rows = []
    for fp, base in zip(surfaces.footprints, bases, strict=True):
        ring = np.asarray(fp.polygon, float)
        for a, b in zip(ring, np.roll(ring, -1, axis=0), strict=True):
            rows.append([a[0], a[1], b[0], b[1], float(base), float(base) + float(fp.height_m)])
    return np.asarray(rows, float).reshape(-1, 6)


def stage_eigenrays(
    job: Job,
    profile: Profile,
    wind: Wind | None,
    setup: FieldSetup,
    start_cells: np.ndarray,
    fan: LaunchFan,
    log: StageLog,
    surfaces: SceneSurfaces | None = None,
) -> ArrivalTable | None:
    """Eigenrays at the job's receivers (arrivals.csv): see :mod:`bentray.engine.eigenray_stage`; the
    buildings' outer walls of ``surfaces`` are searched for wall reflections."""
    why_not = eigenray_decision(job)
    if why_not is not None or setup.receivers_xyz is None:
        log.stages["eigenrays"] = why_not or "skipped: no receivers in the job"
        return None
    from bentray.engine.eigenrays import RayModel  # only a job with receivers loads the search

    template = setup.template
    tables = template.tables if isinstance(template, beam_field.BeamBuffers) else None
    settings = template.settings if isinstance(template, beam_field.BeamBuffers) else None
    freqs = np.asarray(settings.frequencies_hz if settings is not None else [], float)
    walls = reflecting_walls(job, surfaces)
    models = []
    for s, src in enumerate(job.sources):
        first = int(np.nonzero(fan.source == s)[0][0])
        models.append(
            RayModel(
                mesh=setup.mesh,
                curve=job.solver.mesh_curve,
                c_ref=float(profile.c_ref),
                origin=np.asarray(src.position, float),
                start_cell=int(start_cells[first]),
                max_reflections=job.rays.max_reflections,
                max_steps=job.rays.max_steps,
                wind=wind,
                tables=tables,
                frequencies_hz=freqs,
                walls=walls,
            )
        )
    with log.timed("eigenrays"):
        table = run_eigenrays(job, models, setup.receivers_xyz, freqs)
    st = table.stats
    log.stages["eigenrays"] = (
        f"ran: {st['arrivals']} arrivals at {st['receivers']} receivers from {st['sources']} sources "
        f"({len(st['not_converged'])} receivers with brackets that did not converge; {st['method']})"
    )
    return table


def stage_mesh_output(
    job: Job, media: Media, log: StageLog, surfaces: SceneSurfaces | None = None
) -> MeshGeometry | None:
    """The media mesh's geometry for ``mesh.vtu`` when 'mesh' is in the outputs."""
    if "mesh" not in job.outputs:
        log.stages["mesh_output"] = "skipped: 'mesh' not in outputs"
        return None
    with log.timed("mesh_geometry"):
        geometry = media.geometry()
        _tag_reflecting_materials(geometry, media.mesh, job, surfaces)
    log.stages["mesh_output"] = "ran"
    return geometry


def _tag_reflecting_materials(geometry: MeshGeometry, mesh: CellMesh, job: Job, surfaces: SceneSurfaces | None) -> None:
    """Cell array ``reflecting_material``: the material index of the cell's reflecting (ground, wall, roof)
    face, -1 for cells without one (the largest index where a cell has several), and its legend. Only
    where mesh.vtu's cells are the media cells one to one."""
    if geometry.connectivity.shape[0] != mesh.neighbours.shape[0]:
        return
    reflect = mesh.neighbours == BOUNDARY_REFLECT
    geometry.cell_data["reflecting_material"] = np.where(reflect, mesh.face_material, -1).max(axis=1).astype(np.int32)
    names = [m.name for m in surfaces.materials] if surfaces is not None else ["the flat ground (scene.ground)"]
    geometry.field_data["reflecting_material_legend"] = "-1 no reflecting face, " + ", ".join(
        f"{i} {name}" for i, name in enumerate(names)
    )

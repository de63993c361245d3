"""Orchestration: Job -> profile -> scene -> media mesh -> launch fan -> ray batches -> field -> JobOutcome.

Plain Python, one call per stage (:mod:`bentray.engine.stages`); the per-ray work happens in the Numba
kernels, on the executor the caller passes (:mod:`bentray.engine.executors`; the engine reads no
configuration). Each stage is timed; the report (:mod:`bentray.engine.report`) says which stages ran and
why the others did not.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from bentray.engine import stages
from bentray.engine.diffraction.stage import stage_diffraction
from bentray.engine.diffraction.terrain import stage_terrain_screening
from bentray.engine.eigenray_stage import merge_into_receivers
from bentray.engine.executors import Executor, LocalExecutor
from bentray.engine.media import Media, Wind
from bentray.engine.profiles import Profile
from bentray.engine.report import build_report
from bentray.engine.result import JobOutcome
from bentray.engine.shadow_stage import stage_refractive_shadow
from bentray.engine.stages import ProgressFn, StageLog
from bentray.engine.surfaces import SceneSurfaces
from bentray.engine.wave_stage import stage_wave_field
from bentray.scenes.crs import LocalFrame
from bentray.scenes.gis_frame import localise_job
from bentray.scenes.scene_models import resolve_source_heights
from bentray.scenes.schema import Job

__all__ = ["Prepared", "ProgressFn", "prepare_medium", "prepare_scene", "run_job", "run_prepared"]


def _no_progress(stage: str, fraction: float) -> None:
    return None


def _band_labels(job: Job, setup: stages.FieldSetup) -> list[str]:
    """The receivers' band labels (those of receivers.csv): the field's, or the receiver defaults."""
    template = setup.template
    settings = getattr(template, "settings", None) or job.field
    return list(settings.labels) if settings is not None else []


@dataclass
class Prepared:
    """What a job's propagation needs before its sources are traced: the job in the local frame (source
    heights resolved), its frame, profile, wind, surfaces, media mesh and the preparation's stage log.
    :mod:`bentray.engine.conditions` builds one per condition (reusing the scene, and the mesh where the
    medium is the same) and runs each emission group of sources on it."""

    job: Job
    frame: LocalFrame
    profile: Profile
    wind: Wind | None
    surfaces: SceneSurfaces | None
    media: Media
    log: StageLog


def prepare_scene(job: Job, base_dir: Path | None, log: StageLog) -> tuple[Job, LocalFrame, SceneSurfaces | None]:
    """The job in the local frame with its source heights resolved, the frame, and the scene's surfaces."""
    job, frame = localise_job(job)  # scene.crs: CRS coordinates -> the local frame (identity otherwise)
    surfaces = stages.stage_scene(job, base_dir, log)
    return resolve_source_heights(job, surfaces), frame, surfaces


def prepare_medium(
    job: Job, base_dir: Path | None, surfaces: SceneSurfaces | None, log: StageLog, progress: ProgressFn
) -> tuple[Profile, Wind | None, Media]:
    """The job's profile (measured from the ground where the scene says so), wind and media mesh."""
    progress("profile", 0.0)
    profile, wind = stages.stage_profile(job, base_dir, log)
    profile = stages.stage_profile_heights(job, profile, surfaces, log)
    progress("mesh", 0.05)
    return profile, wind, stages.stage_mesh(job, profile, surfaces, wind, log)


def run_job(
    job: Job,
    base_dir: Path | None = None,
    *,
    progress: ProgressFn | None = None,
    executor: Executor | None = None,
) -> JobOutcome:
    """Run a validated job and return everything it produced (nothing is written).

    base_dir : where the job's relative file paths (terrain, grids, tables) are resolved.
    progress(stage, fraction) is called at each stage and after each ray batch (fraction of the whole
    job, 0..1). executor : runs the ray batches (default: :class:`LocalExecutor`, this process; callers
    that scale out pass e.g. ``executors.make_executor(dask_address)``). A job with ``conditions`` runs
    once per condition and emission group (:func:`bentray.engine.conditions.run_conditions`).
    """
    report_progress = progress or _no_progress
    runner = executor if executor is not None else LocalExecutor()
    if job.conditions:
        from bentray.engine.conditions import run_conditions

        return run_conditions(job, base_dir, progress=report_progress, executor=runner)
    log = StageLog()
    report_progress("scene", 0.0)
    job, frame, surfaces = prepare_scene(job, base_dir, log)
    profile, wind, media = prepare_medium(job, base_dir, surfaces, log, report_progress)
    return run_prepared(Prepared(job, frame, profile, wind, surfaces, media, log), progress=report_progress,
                        executor=runner)  # fmt: skip


def run_prepared(prepared: Prepared, *, progress: ProgressFn, executor: Executor) -> JobOutcome:
    """Trace the sources of a prepared job and build its field, receivers, eigenrays and report."""
    job, profile, wind, surfaces, media = (
        prepared.job,
        prepared.profile,
        prepared.wind,
        prepared.surfaces,
        prepared.media,
    )
    report_progress, runner = progress, executor
    log = prepared.log.copy()  # the scene and mesh stages' timings and compilation carry on
    fan = stages.launch_fan(job)
    start_cells = stages.stage_locate(job, media, surfaces, fan.source, log)
    setup = stages.stage_field_setup(job, profile, media.mesh, surfaces, fan.source, log)
    plan = stages.build_plan(job, profile, wind, fan, start_cells, setup)
    traced = stages.stage_trace(job, plan, fan, runner, report_progress, log)
    report_progress("field", 0.9)
    field_arrays = stages.stage_field(job, profile, surfaces, traced, setup, log)
    receivers = stages.stage_receivers(job, traced, setup, log)
    report_progress("diffraction", 0.92)
    with log.compiling("diffraction"):
        diffraction = stage_diffraction(job, profile, wind, surfaces, setup, field_arrays, receivers, log)
    with log.compiling("terrain_screening"):
        terrain = stage_terrain_screening(job, profile, wind, surfaces, setup, field_arrays, receivers, log)
    with log.compiling("wave_field"):
        wave = stage_wave_field(job, profile, wind, surfaces, setup, field_arrays, receivers, log)
    wave_bands = [f"{f:g}" for f in wave["bands_hz"]] if wave is not None else []
    with log.compiling("refractive_shadow"):
        shadow = stage_refractive_shadow(
            job, profile, wind, surfaces, setup, field_arrays, receivers, log, field_done_labels=wave_bands
        )
    report_progress("eigenrays", 0.93)
    arrivals = stages.stage_eigenrays(job, profile, wind, setup, start_cells, fan, log, surfaces)
    if receivers is not None and arrivals is not None:
        merge_into_receivers(receivers, arrivals, list(_band_labels(job, setup)))
    geometry = stages.stage_mesh_output(job, media, log, surfaces)
    report = build_report(
        job,
        profile_desc=profile.describe(),
        media=media,
        result=traced.result,
        timings=log.timings,
        compile_s=log.compile_s,
        compiled_functions=log.compiled_functions,
        stages=log.stages,
        batches={"count": traced.n_batches, "batch_rays": job.solver.batch_rays, "executor": runner.name},
        restarts=traced.restarts,
        field_stats=field_arrays.stats if field_arrays is not None else None,
    )
    if receivers is not None:
        report["receivers"] = receivers.stats
    if arrivals is not None:
        report["eigenrays"] = arrivals.stats
    if diffraction is not None:
        report["diffraction"] = diffraction
    if terrain is not None:
        report["terrain_screening"] = terrain
    if wave is not None:
        report["wave_field"] = wave
    if shadow is not None:
        report["refractive_shadow"] = shadow
    frame = prepared.frame
    if frame.crs_wkt is not None:
        report["georeference"] = frame.as_dict()  # bentray export places the outputs back in the CRS
    report_progress("done", 1.0)
    return JobOutcome(
        trace=traced.result,
        mesh_geometry=geometry,
        report=report,
        field=field_arrays,
        receivers=receivers,
        arrivals=arrivals,
    )

"""``bentray render``: a job's camera shoots one ray per pixel through the job's media mesh.

The media mesh is built exactly as ``bentray run`` builds it (engine/stages.py: profile, scene, heights above
the ground, mesh); the camera rays then go through the same analytic traversal (engine/tracer.py, or the CUDA
kernel with ``solver.device``) with ``max_reflections = 0``, so each ray stops where it first meets a reflecting
face (ground, terrain, building: status reflection_limit, at the hit point) or leaves the domain (exited), or
runs out of ``rays.max_time_s`` (time_limit). Light is traced like sound: the mirage profiles define
``c = c_ref / n`` (engine/profiles.py), so the ray paths depend on n only. The job's ``sources`` and launch fan
are not used; ``rays.max_time_s`` and ``rays.max_steps`` bound each camera ray.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bentray.engine import stages
from bentray.engine.constants import STATUS_EXITED, STATUS_LOST, STATUS_REFLECTION_LIMIT, STATUS_STEP_LIMIT
from bentray.engine.errors import JobInputError
from bentray.engine.render.camera import pixel_directions
from bentray.engine.render.shade import LOST_RGB, shade_sky, shade_surface, surface_materials, surface_normals
from bentray.scenes.scene_models import check_points_above_ground, resolve_source_heights
from bentray.scenes.schema import Job

__all__ = ["RENDER_BATCH_RAYS", "RenderOutcome", "render_job", "write_png"]

RENDER_BATCH_RAYS = 65_536  # camera rays per trace call (bounds the per-call arrays to ~15 MB)
_TOP_TOL_M = 1e-6  # hits this close to a reflecting domain top count as sky


@dataclass
class RenderOutcome:
    """A rendered image and what each pixel saw.

    rgb : (H, W, 3) float64 linear RGB in [0, 1], row 0 at the top. hit : (H, W) bool, the ray met a surface
    (ground, terrain, building). position, direction : (H, W, 3) final ray states (m, unit). status : (H, W)
    int8 constants.STATUS_*. stats : counts, timings (s) and the mesh's description.
    """

    rgb: np.ndarray
    hit: np.ndarray
    position: np.ndarray
    direction: np.ndarray
    status: np.ndarray
    stats: dict[str, Any] = field(default_factory=dict)


def _trace_camera(
    job: Job, media: Any, c_ref: float, wind: Any, origins: np.ndarray, dirs: np.ndarray, cell: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """Final position, direction and status of every camera ray, traced in batches of RENDER_BATCH_RAYS."""
    from bentray.engine.gpu.dispatch import trace_final_states

    n = len(dirs)
    pos = np.empty((n, 3))
    direction = np.empty((n, 3))
    status = np.empty(n, np.int8)
    info: dict[str, Any] = {}
    for a in range(0, n, RENDER_BATCH_RAYS):
        b = min(a + RENDER_BATCH_RAYS, n)
        res, info = trace_final_states(
            media.mesh,
            job.solver.mesh_curve,
            c_ref,
            origins[a:b],
            dirs[a:b],
            np.full(b - a, cell, np.int64),
            max_time_s=job.rays.max_time_s,
            max_reflections=0,
            max_steps=job.rays.max_steps,
            wind=wind,
            device=job.solver.device,
            n_job_rays=n,
        )
        pos[a:b], direction[a:b], status[a:b] = res.position, res.direction, res.status
    return pos, direction, status, info


def render_job(job: Job, base_dir: Path | None = None) -> RenderOutcome:
    """Render ``job.camera`` through the job's media mesh (nothing is written).

    Raises JobInputError naming ``camera`` when the job has none, when the camera is not inside the media
    mesh or not above the ground, or when the job uses ``scene.crs`` (render works in the local frame).
    """
    import time

    camera = job.camera
    if camera is None:
        raise JobInputError("camera: the job has no camera (bentray render needs one; see README 'Rendering')")
    if job.scene.crs is not None:
        raise JobInputError("scene.crs: bentray render works in the job's local frame; remove scene.crs")
    if job.solver.is_baseline:
        raise JobInputError(f"solver.curve: render traces the analytic curves, not the baseline {job.solver.curve!r}")
    t0 = time.perf_counter()
    log = stages.StageLog()
    profile, wind = stages.stage_profile(job, base_dir, log)
    surfaces = stages.stage_scene(job, base_dir, log)
    job = resolve_source_heights(job, surfaces)
    profile = stages.stage_profile_heights(job, profile, surfaces, log)
    media = stages.stage_mesh(job, profile, surfaces, wind, log)
    box = job.scene.box
    lo, hi = np.asarray(box.min, float), np.asarray(box.max, float)
    position = np.asarray(camera.position, float)
    if surfaces is not None:
        check_points_above_ground(
            surfaces,
            position[None],
            ["camera.position"],
            flat_ground_z=float(lo[2]) if surfaces.terrain is None else None,
        )
    elif not position[2] > lo[2]:
        raise JobInputError(f"camera.position: z={position[2]:g} m is not above the ground (z={lo[2]:g} m)")
    if not (np.all(position > lo) and np.all(position < hi)):
        raise JobInputError(
            f"camera.position: {position.tolist()} is not strictly inside the domain "
            f"[{', '.join(f'{v:g}' for v in lo)}] to [{', '.join(f'{v:g}' for v in hi)}]"
        )
    cell = int(media.locate(position[None])[0])
    if cell < 0:
        raise JobInputError(f"camera.position: {position.tolist()} is not inside the media mesh")
    dirs = pixel_directions(camera)
    origins = np.broadcast_to(position, dirs.shape)
    t1 = time.perf_counter()
    pos, d, status, info = _trace_camera(job, media, float(profile.c_ref), wind, origins, dirs, cell)
    t2 = time.perf_counter()
    hit = (status == STATUS_REFLECTION_LIMIT) & (pos[:, 2] < hi[2] - _TOP_TOL_M)
    lost = (status == STATUS_LOST) | (status == STATUS_STEP_LIMIT)
    sun = np.asarray(camera.sun.direction())
    rgb = shade_sky(d, sun)
    if np.any(hit):
        hp = pos[hit]
        ground = _ground_z(surfaces, lo, hi, hp)
        normals = surface_normals(hp, surfaces, lo, hi, ground)
        material = surface_materials(hp, surfaces, ground)
        rgb[hit] = shade_surface(hp, normals, material, sun, (float(lo[2]), float(lo[2] + 0.25 * (hi[2] - lo[2]))))
    rgb[lost] = LOST_RGB
    h, w = camera.height, camera.width
    stats = {
        "pixels": int(h * w),
        "surface": int(hit.sum()),
        "sky": int((~hit & ~lost).sum()),
        "exited": int((status == STATUS_EXITED).sum()),
        "lost": int(lost.sum()),
        "mesh": media.representation,
        "mesh_cells": int(media.mesh.n_cells),
        "stages": dict(log.stages),
        "timings_s": {**log.timings, "setup": t1 - t0, "trace": t2 - t1, "shade": time.perf_counter() - t2},
        **info,
    }
    return RenderOutcome(
        rgb=rgb.reshape(h, w, 3),
        hit=hit.reshape(h, w),
        position=pos.reshape(h, w, 3),
        direction=d.reshape(h, w, 3),
        status=status.reshape(h, w),
        stats=stats,
    )


def _ground_z(surfaces: Any, lo: np.ndarray, hi: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Ground height (m) under each point: the terrain as the mesh sees it, else the domain bottom."""
    if surfaces is None or surfaces.terrain is None:
        return np.full(len(points), float(lo[2]))
    from bentray.engine.mesh.terrain import terrain_height_function

    return terrain_height_function(surfaces.terrain, lo, hi)(points[:, :2])


def write_png(outcome: RenderOutcome, path: Path) -> Path:
    """Write the image as an 8-bit sRGB PNG (linear RGB gamma-encoded with 1/2.2); returns the path."""
    import matplotlib.image

    srgb = np.clip(outcome.rgb, 0.0, 1.0) ** (1.0 / 2.2)
    path.parent.mkdir(parents=True, exist_ok=True)
    matplotlib.image.imsave(path, (srgb * 255.0 + 0.5).astype(np.uint8))
    return path

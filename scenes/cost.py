"""A cost model of a validated job, evaluated before any work starts (the service's 422, the CLI's exit 2).

Every estimate is an upper-bound style count from the job alone (no mesh is built), in bytes or in
elementary operations, with the formula stated where it is computed:

- ``paths_bytes``: recorded ray paths, ``rays x path_samples x PATH_SAMPLE_BYTES`` (measured: 20,000
  rays x 400 samples held 828 MB, i.e. 103.5 B per sample with the result arrays and the VTK copy).
- ``field_bytes``: the field accumulators, one set per thread plus the collapsed total and one batch's
  partial. Voxels: ``(threads + 2) x points x (bands + 1) x 8 B`` incoherent; coherent mode keeps 5
  records of 8 B per arrival group (at most 8) and point. Beams (the default method): per point,
  3 x (reflection groups, at most 4) KMAH groups x bands x (2 coherent + 1 incoherent arrays) x 8 B.
- ``rays_bytes``: the per-ray final state, ``rays x RAY_STATE_BYTES``.
- ``field_deposits``: field samples. Voxels: ``rays x crossings x (grid diagonal + 2 x largest cell) /
  h`` where h = sample_fraction x smallest field spacing (segments are cut into pieces of length h where
  they pass the grid). Beams: ``crossings x (4 x points x sources + 8 x rays x (grid diagonal + 2 x
  largest cell) / chord)`` (the beams of a fan tile space; a stencil per chord).
  crossings = min(max_reflections + 1, 1 + c_max max_time_s / smallest domain extent): each reflection
  can bring the ray back through the grid.
- ``ray_steps``: ``rays x max_steps`` is a bound nobody reaches, so the work estimate of the trace is
  ``rays x crossings x cells per crossing`` with cells per crossing = domain diagonal / (largest extent
  / 200) (the tets default smallest cell; adaptive sizings make few cells where the medium is smooth, so
  ``solver.d_min_m`` does not enter), capped by ``max_steps``.

:func:`cost_problems` compares them with :class:`CostLimits` and returns one ``field.path: reason``
line per exceeded budget, with the estimate and the limit in the text.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

__all__ = [
    "DEFAULT_PATH_RAYS",
    "CostEstimate",
    "CostLimits",
    "cost_problems",
    "estimate_cost",
    "machine_memory_bytes",
    "records_paths",
]

PATH_SAMPLE_BYTES = 104  # measured, see the module docstring
RAY_STATE_BYTES = 200  # final position, direction, time, length, status, indices, launch angles
DEFAULT_PATH_RAYS = 2_000  # paths are recorded by default only up to this many rays (~83 MB at 400 samples)
_C_MAX_M_S = 1000.0  # the media check's upper sound speed (scenes.media_checks.C_MAX_M_S)


def records_paths(job: Any) -> bool:
    """Whether the job records sampled ray paths: ``rays.record_paths`` if given; else when 'paths' is
    an output, or 'rays' is and the job has at most :data:`DEFAULT_PATH_RAYS` rays."""
    if job.rays.record_paths is not None:
        return bool(job.rays.record_paths)
    if "paths" in job.outputs:
        return True
    return "rays" in job.outputs and job.n_rays <= DEFAULT_PATH_RAYS


def machine_memory_bytes() -> int:
    """Physical memory of this machine in bytes (0 when unknown)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 0


@dataclass(frozen=True)
class CostLimits:
    """Budgets of one job. memory_bytes: all estimated arrays together; field_deposits and ray_steps:
    elementary operations (about 1e8 per core-second each)."""

    memory_bytes: int = 8 * 2**30
    field_deposits: float = 2e10
    ray_steps: float = 5e10
    threads: int = os.cpu_count() or 1


@dataclass(frozen=True)
class CostEstimate:
    paths_bytes: int
    field_bytes: int
    rays_bytes: int
    field_deposits: float
    ray_steps: float

    @property
    def memory_bytes(self) -> int:
        return self.paths_bytes + self.field_bytes + self.rays_bytes


def estimate_cost(job: Any, threads: int) -> CostEstimate:
    """The estimates of the module docstring for a validated job, ``threads`` numba threads."""
    n_rays = int(job.n_rays)
    box = job.scene.box
    extent = [float(b - a) for a, b in zip(box.min, box.max, strict=True)]
    diagonal = math.sqrt(sum(e * e for e in extent))
    crossings = min(job.rays.max_reflections + 1, 1.0 + _C_MAX_M_S * job.rays.max_time_s / max(min(extent), 1e-9))
    paths = n_rays * job.solver.path_samples * PATH_SAMPLE_BYTES if records_paths(job) else 0
    field_bytes = 0
    deposits = 0.0
    spec = job.field
    if spec is not None:
        n_points = spec.n_points
        n_bands = len(spec.frequencies_hz)
        method = getattr(spec, "method", "voxels")
        grid_diag = math.sqrt(sum(((n - 1) * s) ** 2 for n, s in zip(spec.shape, spec.spacing, strict=True)))
        cell = job.solver.d_max_m if job.solver.d_max_m is not None else max(extent)
        near_grid = grid_diag + 2.0 * min(cell, diagonal)  # path length of one crossing near the grid
        if method == "beams":
            # engine/beam_field.py: per slot, (reflection groups <= 4) x (KMAH 3) x bands x points x 8 B for
            # each of the coherent (2 arrays) and incoherent (1) sums, plus two per-point arrays
            groups = 3 * (min(job.rays.max_reflections, 3) + 1)
            arrays = {"coherent": 2, "incoherent": 1}.get(spec.mode, 3)
            field_bytes = (threads + 2) * n_points * (groups * n_bands * arrays + groups + 1) * 8
            chord = spec.chord_m if spec.chord_m is not None else min(max(2.0 * min(spec.spacing), 1.0), 10.0)
            # each chord deposits into the points its beam owns: on average a few per point of the grid
            # and crossing for every source (the beams of a fan tile space), plus a stencil per chord
            deposits = crossings * (4.0 * n_points * len(job.sources) + 8.0 * n_rays * near_grid / chord)
        else:
            if spec.mode == "coherent":
                groups = min(job.rays.max_reflections, 7) + 1
                field_bytes = (threads + 2) * n_points * (groups * 5 + 1) * 8
            else:
                powered = sum(1 for s in job.sources if s.power_db is not None)
                acc = n_bands * (2 if powered > 1 else 1)
                field_bytes = (threads + 2) * n_points * (acc + 1) * 8
            h = spec.sample_fraction * min(spec.spacing)
            deposits = n_rays * crossings * near_grid / h
    d_min = max(extent) / 200.0
    steps = n_rays * min(float(job.rays.max_steps), crossings * max(diagonal / d_min, 1.0))
    return CostEstimate(paths, int(field_bytes), n_rays * RAY_STATE_BYTES, float(deposits), float(steps))


def _gb(n: float) -> str:
    return f"{n / 2**30:.3g} GiB"


def cost_problems(job: Any, limits: CostLimits) -> list[str]:
    """``field.path: reason`` lines for every budget of ``limits`` the job's estimate exceeds."""
    est = estimate_cost(job, limits.threads)
    lines: list[str] = []
    if est.memory_bytes > limits.memory_bytes:
        parts = {"paths": est.paths_bytes, "field": est.field_bytes, "rays": est.rays_bytes}
        biggest = max(parts, key=lambda k: parts[k])
        field = {"paths": "rays.record_paths", "field": "field.shape", "rays": "rays"}[biggest]
        hint = {
            "paths": "set rays.record_paths to false, or lower solver.path_samples or the ray count",
            "field": "use fewer field points or bands (split the map into tiles)",
            "rays": "use fewer rays",
        }[biggest]
        lines.append(
            f"{field}: the job needs an estimated {_gb(est.memory_bytes)} of memory (paths {_gb(est.paths_bytes)}, "
            f"field {_gb(est.field_bytes)} for {limits.threads} threads, rays {_gb(est.rays_bytes)}); the limit "
            f"is {_gb(limits.memory_bytes)}: {hint}"
        )
    if est.field_deposits > limits.field_deposits:
        lines.append(
            f"field.spacing: an estimated {est.field_deposits:.3g} field samples (rays x grid crossings x path "
            f"length near the grid / (sample_fraction x smallest spacing)); the limit is "
            f"{limits.field_deposits:.3g}: use a coarser spacing, a larger field.sample_fraction or fewer rays"
        )
    if est.ray_steps > limits.ray_steps:
        lines.append(
            f"rays: an estimated {est.ray_steps:.3g} cell crossings (rays x domain crossings x diagonal / smallest "
            f"cell); the limit is {limits.ray_steps:.3g}: use fewer rays, fewer reflections, a shorter "
            "max_time_s or a larger solver.d_min_m"
        )
    return lines

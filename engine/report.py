"""The job report (``report.json``): stages, timings, mesh stats, rays by status, batches, field stats."""

from __future__ import annotations

import os
from typing import Any

import numba
import numpy as np

import bentray
from bentray.engine.media import Media
from bentray.engine.result import TraceResult
from bentray.scenes.schema import Job

__all__ = ["build_report"]


def build_report(
    job: Job,
    *,
    profile_desc: dict[str, Any],
    media: Media,
    result: TraceResult,
    timings: dict[str, float],
    stages: dict[str, str],
    batches: dict[str, Any],
    restarts: np.ndarray | None = None,
    field_stats: dict[str, Any] | None = None,
    compile_s: dict[str, float] | None = None,
    compiled_functions: int = 0,
) -> dict[str, Any]:
    """The JSON report of a finished job.

    timings : seconds per stage; stages : "ran: ..." / "skipped: why" per stage; batches : count,
    batch_rays and executor name; restarts : (n,) int64 restarts per ray of a numerical baseline (None:
    analytic curves); field_stats : the field stage's stats (None: no field); compile_s : Numba compilation
    seconds inside each stage (engine.compile_time; part of that stage's timings_s), compiled_functions :
    how many signatures were compiled. ``compile_s`` in the report has every compiling stage and ``total``
    (0 on a warm cache); the throughput figures use the trace time without compilation.
    """
    crossings = int(result.crossings.sum())
    steps = int(result.steps.sum()) if result.steps is not None else None
    compiled = {k: float(v) for k, v in (compile_s or {}).items()}
    trace_s = timings.get("trace", 0.0) - compiled.get("trace", 0.0)
    report: dict[str, Any] = {
        "name": job.name,
        "bentray_version": bentray.__version__,
        "profile": profile_desc,
        "solver": job.solver.model_dump(mode="json"),
        "representation": media.representation,
        "representation_reason": media.reason,
        "stages": stages,
        "timings_s": timings,
        "compile_s": {**compiled, "total": sum(compiled.values())},
        "compiled_functions": int(compiled_functions),
        "mesh": media.stats,
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
            "note": "trace time without Numba compilation (compile_s.trace)",
        },
        "machine": {"numba_threads": int(numba.get_num_threads()), "cpu_count": os.cpu_count()},
        "batches": batches,
    }
    if job.wind is not None:
        report["wind"] = job.wind.model_dump(mode="json")
    if restarts is not None:
        report["rays"]["restarts_total"] = int(restarts.sum())
    if field_stats is not None:
        report["field"] = field_stats
    return report

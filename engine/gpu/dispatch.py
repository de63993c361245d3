"""Final ray states on the device ``solver.device`` picks: the CPU tracer or the CUDA kernel.

Only final states (position, direction, time, length, counts, first-reflection material) come back from the
device; fields, path samples and paraxial states stay on the CPU path (engine/tracer.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bentray.engine.gpu.device import resolve_device
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.result import TraceResult
from bentray.engine.tracer import trace

__all__ = ["trace_final_states"]


def trace_final_states(
    mesh: CellMesh,
    curve: str,
    c_ref: float,
    origins: np.ndarray,
    directions: np.ndarray,
    start_cells: np.ndarray,
    *,
    max_time_s: float,
    max_reflections: int,
    max_steps: int,
    wind: tuple[int, np.ndarray] | None,
    device: str = "cpu",
    n_job_rays: int | None = None,
) -> tuple[TraceResult, dict[str, Any]]:
    """(TraceResult with reflection_cos / reflection_material of the first reflection, info) on the device
    ``device`` ("cpu" | "cuda" | "auto"; auto decides on ``n_job_rays``, default the number of rays given).
    info: ``device`` (the one used) and ``device_reason``."""
    n = int(np.asarray(origins).reshape(-1, 3).shape[0])
    used, reason = resolve_device(device, n if n_job_rays is None else int(n_job_rays))
    info: dict[str, Any] = {"device": used, "device_reason": reason}
    if used == "cuda":
        from bentray.engine.gpu.tracer import trace_cuda

        res, timings = trace_cuda(
            mesh,
            curve,
            c_ref,
            origins,
            directions,
            start_cells,
            max_time_s=max_time_s,
            max_reflections=max_reflections,
            max_steps=max_steps,
            wind=wind,
        )
        info["device_timings_s"] = timings
        return res, info
    res = trace(
        mesh,
        curve,
        c_ref,
        origins,
        directions,
        start_cells,
        max_time_s=max_time_s,
        max_reflections=max_reflections,
        max_steps=max_steps,
        wind=wind,
        record_reflections=True,
    )
    return res, info

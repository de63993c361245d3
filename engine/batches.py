"""Ray batches: trace one [start, stop) range of a plan, and combine batches in batch order.

A batch is a pure function of (plan, start, stop), so any executor may run, retry or reorder them;
partial fields are always summed in batch order (:class:`InOrderSum`, :func:`combine_batches`), the same
order on every executor.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from bentray.engine.beam_field import BeamBuffers
from bentray.engine.field_buffers import FieldBuffers
from bentray.engine.result import TraceResult, concat_traces
from bentray.engine.trace_plan import TracePlan
from bentray.engine.tracer import trace

__all__ = ["BatchResult", "InOrderSum", "combine_batches", "trace_batch"]


@dataclass
class BatchResult:
    """One batch's rays (in order) and its collapsed partial field; restarts for the baselines.

    start, stop : the ray range; seconds : wall time of the batch where it ran.
    """

    start: int
    stop: int
    trace: TraceResult
    field: FieldBuffers | BeamBuffers | None = None
    restarts: np.ndarray | None = None
    seconds: float = 0.0


def trace_batch(plan: TracePlan, start: int, stop: int) -> BatchResult:
    """Trace rays ``start:stop`` of the plan (in this process, numba threads) and collapse its field."""
    t0 = time.perf_counter()
    sl = slice(start, stop)
    restarts = None
    buffers: FieldBuffers | BeamBuffers | None = None
    if plan.baseline is not None:
        from bentray.engine.baselines.trace_numerical import trace_numerical

        spec = plan.baseline
        result, restarts = trace_numerical(
            spec.method,
            spec.media,
            mesh=plan.mesh,
            quantity=spec.quantity,
            exact_spec=spec.exact_spec,
            c_ref=plan.c_ref,
            origins=plan.origins[sl],
            directions=plan.directions[sl],
            start_cells=plan.start_cells[sl],
            max_time_s=plan.max_time_s,
            max_reflections=plan.max_reflections,
            max_steps=plan.max_steps,
            step_m=spec.step_m,
            tolerance=spec.tolerance,
            path_samples=plan.path_samples,
            domain_min=spec.domain_min,
            domain_max=spec.domain_max,
            ground_z=spec.ground_z,
            top=spec.top,
        )
    elif _on_cuda(plan):
        from bentray.engine.gpu.tracer import trace_cuda  # numba-cuda: final ray states and beam fields

        beam_buf: BeamBuffers | None = None
        if plan.field is not None:  # a beam field (_on_cuda refuses voxel fields): one device accumulator
            assert plan.field_weights is not None and isinstance(plan.field, BeamBuffers)
            beam_buf = plan.field.like(plan.field_weights[sl], n_slots=1)
            if plan.ray_amplitudes is not None:
                beam_buf.ray_amp = plan.ray_amplitudes[sl]
        result, _ = trace_cuda(
            plan.mesh,
            plan.curve,
            plan.c_ref,
            plan.origins[sl],
            plan.directions[sl],
            plan.start_cells[sl],
            max_time_s=plan.max_time_s,
            max_reflections=plan.max_reflections,
            max_steps=plan.max_steps,
            wind=plan.wind,
            beams=beam_buf,
        )
        if beam_buf is None:
            result.reflection_cos = result.reflection_material = None  # as the CPU path without a field
        else:
            buffers = beam_buf.collapse(ray_offset=start)
    else:
        if plan.field is not None:
            assert plan.field_weights is not None
            buffers = plan.field.like(plan.field_weights[sl])
            if plan.ray_amplitudes is not None and isinstance(buffers, BeamBuffers):
                buffers.ray_amp = plan.ray_amplitudes[sl]
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


def _on_cuda(plan: TracePlan) -> bool:
    """True when the plan's analytic rays go to the CUDA kernel (solver.device cuda, or auto on a device for a
    large job). The device computes final ray states and beam fields (field grids and receivers: BeamBuffers);
    a job with a voxel field or recorded paths stays on the CPU under auto and is an error naming solver.device
    under cuda."""
    if plan.device == "cpu":
        return False
    from bentray.engine.errors import JobInputError
    from bentray.engine.gpu.device import resolve_device

    voxel = plan.field is not None and not isinstance(plan.field, BeamBuffers)
    needs_cpu = voxel or plan.path_samples > 0
    if needs_cpu and plan.device == "cuda":
        raise JobInputError(
            "solver.device: 'cuda' traces final ray states and beam fields only; this job accumulates a voxel "
            "field or records ray paths (use 'cpu' or 'auto', or drop the 'paths' output)"
        )
    return not needs_cpu and resolve_device(plan.device, plan.n_rays)[0] == "cuda"


def combine_batches(
    parts: list[BatchResult],
) -> tuple[TraceResult, FieldBuffers | BeamBuffers | None, np.ndarray | None]:
    """Rays concatenated in order, partial fields summed in batch order (the same order on any executor)."""
    parts = sorted(parts, key=lambda b: b.start)
    trace_result = concat_traces([b.trace for b in parts])
    field_sum = None
    if parts[0].field is not None:
        field_sum = parts[0].field
        for b in parts[1:]:
            if b.field is not None:  # None: already summed, in batch order, into an earlier one (InOrderSum)
                field_sum.add(b.field)  # type: ignore[arg-type]  # batches of one job share one kind
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
        """Take one finished batch (any order); fold every batch that is now next in order."""
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
                self._head.field.add(ready.field)  # type: ignore[arg-type]  # one kind per job
                ready.field = None

"""Executors: who runs a plan's ray batches. The local one here; Dask in :mod:`bentray.engine.dask_executor`.

The engine never reads configuration: the caller (``bentray run`` / ``bentray sweep``, the service worker
from its settings) picks the executor, e.g. with :func:`make_executor` and a Dask scheduler address.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numba

from bentray.engine.batches import BatchResult, InOrderSum, trace_batch
from bentray.engine.trace_plan import TracePlan

__all__ = ["BatchCallback", "Executor", "LocalExecutor", "make_executor"]

BatchCallback = Callable[[BatchResult], None]


@runtime_checkable
class Executor(Protocol):
    """Runs ray batches of a plan. ``name`` goes into the report (``batches.executor``)."""

    name: str

    def run_batches(
        self, plan: TracePlan, ranges: list[tuple[int, int]], on_batch: BatchCallback | None = None
    ) -> list[BatchResult]:
        """Trace every [start, stop) range of ``plan``; return the BatchResults (any order: ``combine_batches``
        sorts them), partial fields folded in batch order (:class:`~bentray.engine.batches.InOrderSum`).
        ``on_batch`` sees each batch as it finishes."""
        ...

    def describe(self) -> str:
        """Where the batches run, in words (for the report's trace stage)."""
        ...


class LocalExecutor:
    """Runs the batches one after another in this process (each batch uses every numba thread)."""

    name = "local"

    def run_batches(
        self, plan: TracePlan, ranges: list[tuple[int, int]], on_batch: BatchCallback | None = None
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


def make_executor(dask_address: str | None = None) -> Executor:
    """The Dask executor for a scheduler address (``tcp://host:8786``), else the local one.

    A blank address means local. Dask is an optional dependency (``pip install 'bentray[dask]'``).
    """
    address = (dask_address or "").strip()
    if address:
        from bentray.engine.dask_executor import DaskExecutor  # optional dependency

        return DaskExecutor(address)
    return LocalExecutor()

"""Scale-out on Dask distributed: one task per ray batch, the trace plan scattered once.

Selected by the caller: ``--dask ADDR`` or ``BENTRAY_DASK_SCHEDULER=tcp://host:8786`` (read by ``bentray run``,
``bentray sweep`` and the service settings, never by the engine; ``executors.make_executor``); without
either the local executor runs the batches in-process.

How a job runs here: the client (``bentray run`` or the service worker) builds the profile, scene and
media mesh once and packs them into a :class:`~bentray.engine.trace_plan.TracePlan`; :meth:`DaskExecutor.run_batches`
scatters the plan to every worker (``broadcast=True``: one copy per worker, never rebuilt or re-sent per
batch) and submits one ``trace_batch`` task per ray range (``TracePlan.batches``: per source, then
blocks of ``solver.batch_rays`` launch directions). Each finished batch is reported through ``on_batch``
(progress per batch). ``batches.combine_batches`` then sums the partial fields in batch order, the same order
as a local run.

Failures: a task whose worker dies is rescheduled by the scheduler on another worker; a task that raises
is retried ``retries`` times (default 2). Both are safe because a batch is a pure function of the plan
and its range. The scattered plan survives as long as one worker holding a copy survives.

Determinism: rays are bit-for-bit those of a local run. Partial fields are summed in batch order on
every executor. Inside a batch the field is accumulated in one slot per numba thread and the slots are
summed in slot order, so with equal thread counts (and batch size) the field is bit-for-bit a local
run's; with other thread counts or batch sizes it agrees to 1e-12 relative: the tolerance asserted by
tests/scale/test_dask.py (measured on the test job: energies, levels and hits <= 3e-15, the complex
pressure <= 3e-15 of |p|; a real or imaginary part near zero alone differs by up to 5e-13 of itself,
so p_re / p_im are compared relative to |p|).

Cores: a worker with ``nthreads`` T runs up to T batches at once, each calling parallel numba kernels. Each
task therefore sets its numba thread count (thread-local in numba) to ``max(1, budget // T)`` where
budget is ``BENTRAY_WORKER_NUMBA_THREADS`` if set, else ``NUMBA_NUM_THREADS`` (default: the core count).
Several worker processes on one machine share its cores: set ``NUMBA_NUM_THREADS`` (or
``BENTRAY_WORKER_NUMBA_THREADS``) to cores / processes in their environment. Recommended: one worker
process per machine with ``--nthreads 1`` (each batch then uses every core through numba).
"""

from __future__ import annotations

import os
import threading
import uuid
from collections.abc import Callable
from typing import Any

import numba
import numpy as np

from bentray.engine.batches import BatchResult, InOrderSum, trace_batch
from bentray.engine.trace_plan import TracePlan

try:  # optional dependency: pip install "bentray[dask]"
    from distributed import Client, as_completed, get_worker
except ImportError as exc:  # pragma: no cover - exercised only without the extra
    raise ImportError("Dask scale-out needs the 'dask' extra: pip install 'bentray[dask]'") from exc

__all__ = [
    "DEFAULT_RETRIES",
    "DaskExecutor",
    "InOrderSum",
    "aligned_arrays",
    "connect",
    "disconnect",
    "on_worker",
    "task_numba_threads",
]

# A batch is a pure function of (plan, start, stop): retrying it is always safe. Two retries cover a
# transient failure plus one more; a worker that dies mid-task is rescheduled by the scheduler anyway
# (distributed.scheduler.allowed-failures, default 3), independently of this count.
DEFAULT_RETRIES = 2
# Seconds to wait for a scheduler when connecting by address (a typo should fail, not hang).
CONNECT_TIMEOUT_S = 30.0

_CLIENTS: dict[str, Client] = {}  # one connection per scheduler address in this process
_CLIENTS_LOCK = threading.Lock()


def connect(address: str) -> Client:
    """A client connected to the scheduler at ``address`` (e.g. ``tcp://host:8786``), reused per process."""
    with _CLIENTS_LOCK:
        client = _CLIENTS.get(address)
        if client is None or client.status not in ("running", "connecting"):
            client = Client(address, set_as_default=False, timeout=CONNECT_TIMEOUT_S)
            _CLIENTS[address] = client
        return client


def disconnect(address: str | None = None) -> None:
    """Close the cached connection to ``address`` (None: every cached connection)."""
    with _CLIENTS_LOCK:
        for key in [address] if address is not None else list(_CLIENTS):
            client = _CLIENTS.pop(key, None)
            if client is not None:
                client.close()


def task_numba_threads(worker_nthreads: int, budget: int | None = None) -> int:
    """Numba threads for one task on a worker running ``worker_nthreads`` tasks at once.

    budget: the cores this worker may use (default ``BENTRAY_WORKER_NUMBA_THREADS``, else numba's
    ``NUMBA_NUM_THREADS``); the result is at least 1 and at most ``NUMBA_NUM_THREADS``.
    """
    limit = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # set at import
    if budget is None:
        budget = int(os.environ.get("BENTRAY_WORKER_NUMBA_THREADS", "0") or 0) or limit
    return max(1, min(limit, int(budget) // max(int(worker_nthreads), 1)))


def on_worker(fn: Callable[..., Any], *args: Any, numba_threads: int | None = None, **kwargs: Any) -> Any:
    """Run ``fn(*args, **kwargs)`` in a Dask task after fixing this thread's numba thread count.

    numba_threads: explicit count, else :func:`task_numba_threads` of the worker's ``nthreads``.
    """
    if numba_threads is None:
        try:
            worker = get_worker()
            nthreads = int(getattr(worker, "nthreads", 0) or worker.state.nthreads)
        except ValueError:  # not inside a worker (e.g. a synchronous scheduler): use this process's threads
            nthreads = 1
        numba_threads = task_numba_threads(nthreads)
    limit = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # set at import
    numba.set_num_threads(min(int(numba_threads), limit))
    return fn(*args, **kwargs)


def aligned_arrays(obj: Any, _depth: int = 0) -> Any:
    """``obj`` with every unaligned numpy array replaced by an aligned copy (dataclasses, objects and dicts
    updated in place; tuples and NamedTuples rebuilt); returns the (possibly new) object.

    Why: Dask delivers arrays as views into its message frames, sometimes at an offset that is not a
    multiple of 8 (seen: the mesh's ``planes``). numba types an unaligned array as another type and compiles
    every kernel again for it (a minute per worker process, cached then), and unaligned loads are slower.
    """
    if isinstance(obj, np.ndarray):
        return obj if obj.flags.aligned else obj.copy()
    if _depth > 4 or obj is None or isinstance(obj, (str, bytes, int, float, bool)):
        return obj
    if isinstance(obj, tuple):
        items = [aligned_arrays(v, _depth + 1) for v in obj]
        if all(a is b for a, b in zip(items, obj, strict=True)):
            return obj
        return type(obj)(*items) if hasattr(obj, "_fields") else tuple(items)
    if isinstance(obj, list):
        obj[:] = [aligned_arrays(v, _depth + 1) for v in obj]
        return obj
    if isinstance(obj, dict):
        for key, value in obj.items():
            new = aligned_arrays(value, _depth + 1)
            if new is not value:
                obj[key] = new
        return obj
    if hasattr(obj, "__dict__"):
        for key, value in vars(obj).items():
            new = aligned_arrays(value, _depth + 1)
            if new is not value:
                setattr(obj, key, new)
    return obj


def _batch_task(plan: TracePlan, start: int, stop: int) -> BatchResult:
    """One Dask task: trace rays ``start:stop`` of the (scattered) plan, arrays realigned first."""
    return trace_batch(aligned_arrays(plan), start, stop)


class DaskExecutor:
    """Runs a job's ray batches as Dask tasks (the ``run_batches``/``describe`` interface of LocalExecutor).

    address_or_client: a scheduler address (``tcp://host:8786``; connection reused per process, see
    :func:`connect`) or a ``distributed.Client``. retries: re-runs of a batch whose task raised.
    numba_threads: numba threads per task (default: derived from the worker, see the module docstring).
    """

    name = "dask"

    def __init__(
        self, address_or_client: str | Client, *, retries: int = DEFAULT_RETRIES, numba_threads: int | None = None
    ) -> None:
        if isinstance(address_or_client, Client):
            self._client: Client | None = address_or_client
            scheduler = address_or_client.scheduler
            assert scheduler is not None, "the Dask client is not connected to a scheduler"
            self.address = str(scheduler.address)
        else:
            self._client = None
            self.address = str(address_or_client)
        self.retries = int(retries)
        self.numba_threads = numba_threads

    @property
    def client(self) -> Client:
        if self._client is None:
            self._client = connect(self.address)
        return self._client

    def run_batches(
        self, plan: TracePlan, ranges: list[tuple[int, int]], on_batch: Callable[[BatchResult], None] | None = None
    ) -> list[BatchResult]:
        """Scatter ``plan`` to every worker once, trace each [start, stop) range as one task and return the
        BatchResults in completion order (``combine_batches`` sorts them); ``on_batch`` sees each as it
        finishes. Partial fields are summed in batch order as they arrive (:class:`InOrderSum`)."""
        client = self.client
        tag = uuid.uuid4().hex[:12]
        plan_future = client.scatter(plan, broadcast=True, hash=False)
        futures = [
            client.submit(
                on_worker,
                _batch_task,
                plan_future,
                a,
                b,
                numba_threads=self.numba_threads,
                key=f"bentray-batch-{tag}-{a}-{b}",
                retries=self.retries,
                pure=False,
            )
            for a, b in ranges
        ]
        out: list[BatchResult] = []
        fold = InOrderSum(ranges)
        try:
            for future, part in as_completed(futures, loop=client.loop, with_results=True):
                future.release()  # the result is here now: let the worker free it
                part = aligned_arrays(part)  # the field stage's kernels run on these arrays here
                out.append(part)
                fold.push(part)
                if on_batch is not None:
                    on_batch(part)
        finally:
            if len(out) < len(futures):
                client.cancel(futures)
            del futures
            plan_future.release()
        return out

    def describe(self) -> str:
        info = self.client.scheduler_info()
        workers = info.get("workers", {})
        threads = sum(int(w.get("nthreads", 0)) for w in workers.values())
        return f"Dask scheduler {self.address}, {len(workers)} worker(s), {threads} thread(s)"

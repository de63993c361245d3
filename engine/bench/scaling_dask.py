"""Dask scale-out: strong scaling (1 vs 2 worker processes) and the cost of one ray batch.

    python -m bentray.engine.bench.scaling_dask --out DIR [--quick]

Workload: the field test job scaled up: log profile (A-LD, b = 1), flat absorbing ground, one source at
2 m, a fan of elevation x azimuth rays, 1 s, 4 reflections, an incoherent field on two grids: "small"
(25 x 5 x 3 points, the partial field is 6 kB) and "map" (150 x 50 x 5 points, 37,500 points x 2
bands: a 0.9 MB partial field per batch: every batch allocates, collapses and ships it back).

The trace plan is built once (by run_job through a capturing executor), then each timing is
``executor.run_batches(plan, plan.batches(B))`` + ``combine_batches``: exactly the part batching
changes (for Dask it includes scattering the plan). Each is the best of ``repeats`` warm runs.

- Strong scaling: the same job with batch size ``SCALING_BATCH`` on: local 1 / 2 numba threads,
  LocalCluster 1 worker x 1 thread, 2 workers x 1 thread (tasks on 1 numba thread each).
- Overhead per batch: the first 1000 rays in 1 to 200 batches (5 to 1000 rays each); the time is fitted as
  T(B) = T0 + n_batches(B) * overhead (least squares): the slope is the cost of one more batch.
  Locally (1 numba thread) and on the 2-worker cluster (there the slope is the wall-clock cost of one more
  batch with two workers sharing the tasks).
"""

from __future__ import annotations

import argparse
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np

from bentray.engine.batches import BatchResult, combine_batches
from bentray.engine.bench.common import Section, Table
from bentray.engine.executors import LocalExecutor
from bentray.engine.run import run_job
from bentray.engine.trace_plan import TracePlan
from bentray.scenes.schema import Job

__all__ = ["run", "main"]

SCALING_BATCH = 500  # rays per batch for the strong-scaling rows (enough batches to balance 2 workers)
OVERHEAD_RAYS = 1000  # rays traced in the overhead rows, split into 1 to 200 batches
GRIDS = {"small": ([10, -20, 1], [10, 10, 2], [25, 5, 3]), "map": ([0, -50, 1], [2, 2, 2], [150, 50, 5])}


def _job(grid: str, elevations: int, azimuths: int) -> Job:
    origin, spacing, shape = GRIDS[grid]
    return Job.model_validate(
        {
            "name": f"scaling-dask-{grid}",
            "scene": {
                "domain": {"min": [-20, -60, 0], "max": [300, 60, 120]},
                "ground": {"kind": "flat", "flow_resistivity": 200.0},
            },
            "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
            "sources": [{"position": [0.0, 0.0, 2.0]}],
            "rays": {
                "elevation_deg": {"min": -30, "max": 30, "count": elevations},
                "azimuth_deg": {"min": -20, "max": 20, "count": azimuths},
                "max_time_s": 1.0,
                "max_reflections": 4,
            },
            "field": {
                "origin": origin,
                "spacing": spacing,
                "shape": shape,
                "frequencies_hz": [125, 1000],
                "mode": "incoherent",
            },
            "outputs": ["field", "report"],
        }
    )


class _Captured(Exception):
    """Raised by the capturing executor once it holds the plan (the job stops there)."""


class _Capture(LocalExecutor):
    """An executor that keeps the plan run_job hands it and stops the job (to time batchings of it)."""

    plan: TracePlan | None = None

    def run_batches(
        self, plan: TracePlan, ranges: list[tuple[int, int]], on_batch: Callable[[BatchResult], None] | None = None
    ) -> list[BatchResult]:
        self.plan = plan
        raise _Captured


def build_plan(grid: str, elevations: int, azimuths: int) -> TracePlan:
    """The TracePlan of the benchmark job (profile, mesh, fan and field template built by run_job)."""
    capture = _Capture()
    try:
        run_job(_job(grid, elevations, azimuths), executor=capture)
    except _Captured:
        pass
    assert capture.plan is not None
    return capture.plan


def time_batches(executor: Any, plan: TracePlan, batch_rays: int, repeats: int, n_rays: int | None = None) -> float:
    """Best wall time (s) of run_batches + combine_batches over ``repeats`` runs, on the first ``n_rays``
    rays (default all) in ranges of ``batch_rays``."""
    ranges = plan.batches(batch_rays)
    if n_rays is not None:
        ranges = [(a, min(a + batch_rays, n_rays)) for a in range(0, n_rays, batch_rays)]
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        combine_batches(executor.run_batches(plan, ranges))
        best = min(best, time.perf_counter() - t0)
    return float(best)


def _overhead_rows(
    table: Any, executor: Any, label: str, grid: str, plan: TracePlan, sizes: list[int], repeats: int
) -> float:
    """Time OVERHEAD_RAYS rays in batches of each size, add the rows to ``table``; the fitted s per batch."""
    times = [time_batches(executor, plan, b, repeats, OVERHEAD_RAYS) for b in sizes]
    counts = [-(-OVERHEAD_RAYS // b) for b in sizes]
    t0, slope = _fit_overhead(counts, times)
    for b, n, t in zip(sizes, counts, times, strict=True):
        table.add(
            grid=grid,
            executor=label,
            batch_rays=b,
            batches=n,
            trace_s=t,
            ms_per_batch_fit=1e3 * slope,
            us_per_ray_fit=1e6 * t0 / OVERHEAD_RAYS,
        )
    return slope


def _fit_overhead(n_batches: list[int], seconds: list[float]) -> tuple[float, float]:
    """Least-squares T = T0 + n * overhead: (T0, overhead) in seconds."""
    a = np.column_stack([np.ones(len(n_batches)), np.asarray(n_batches, float)])
    (t0, slope), *_ = np.linalg.lstsq(a, np.asarray(seconds, float), rcond=None)
    return float(t0), float(slope)


def _local_rows(plans: dict[str, TracePlan], scaling: Table, overhead: Table, sizes: list[int], repeats: int,
                say: Callable[[str], None]) -> dict[str, float]:  # fmt: skip
    """Strong-scaling rows on the local executor (1 and 2 numba threads) and its per-batch overhead rows
    (1 thread); returns the 1-thread time (s) of each grid, the speed-up baseline."""
    n_rays = plans["small"].n_rays
    local = LocalExecutor()
    base: dict[str, float] = {}
    for grid, plan in plans.items():
        for threads in (1, 2):
            limit = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # set at import
            numba.set_num_threads(min(threads, limit))
            t = time_batches(local, plan, SCALING_BATCH, repeats)
            base.setdefault(grid, t)
            scaling.add(grid=grid, executor="local", workers=1, numba_threads=threads, trace_s=t,
                        speedup=base[grid] / t, rays_per_s=n_rays / t)  # fmt: skip
            say(f"{grid}: local {threads} thread(s) {t:.3f} s")
        numba.set_num_threads(1)
        slope = _overhead_rows(overhead, local, "local, 1 thread", grid, plan, sizes, repeats)
        say(f"{grid}: local overhead {1e3 * slope:.2f} ms/batch")
    return base


def _dask_rows(plans: dict[str, TracePlan], scaling: Table, overhead: Table, sizes: list[int], repeats: int,
               base: dict[str, float], say: Callable[[str], None]) -> None:  # fmt: skip
    """Strong-scaling rows on a LocalCluster of 1 and 2 worker processes (1 thread each) and, on 2
    workers, the per-batch overhead rows."""
    from distributed import Client, LocalCluster

    from bentray.engine.dask_executor import DaskExecutor

    n_rays = plans["small"].n_rays
    for workers in (1, 2):
        with (
            LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.ERROR,
            ) as cluster,
            Client(cluster, set_as_default=False) as client,
        ):
            executor = DaskExecutor(client, numba_threads=1)
            for grid, plan in plans.items():
                time_batches(executor, plan, SCALING_BATCH, 1)  # warm: workers import and load the kernels
                t = time_batches(executor, plan, SCALING_BATCH, repeats)
                scaling.add(grid=grid, executor="dask LocalCluster", workers=workers, numba_threads=1, trace_s=t,
                            speedup=base[grid] / t, rays_per_s=n_rays / t)  # fmt: skip
                say(f"{grid}: dask {workers} worker(s) {t:.3f} s")
                if workers == 2:
                    slope = _overhead_rows(overhead, executor, "dask, 2 workers", grid, plan, sizes, repeats)
                    say(f"{grid}: dask overhead {1e3 * slope:.2f} ms/batch")


def run(quick: bool = False, progress: Callable[[str], None] | None = None) -> Section:
    """The section (module docstring): quick 41 x 41 rays, 1 repeat; full 61 x 61 rays, best of 2."""
    import distributed  # noqa: F401  # the dask extra: fail before any timing when it is missing

    say = progress or (lambda line: None)
    el, az = (41, 41) if quick else (61, 61)
    repeats = 1 if quick else 2
    # overhead: the first OVERHEAD_RAYS rays in 1 .. 200 batches (small batches make the per-batch cost visible)
    counts_all = (100, 20, 4, 1) if quick else (200, 100, 40, 10, 1)
    sizes = [OVERHEAD_RAYS // n for n in counts_all]
    numba.set_num_threads(1)
    plans = {grid: build_plan(grid, el, az) for grid in GRIDS}
    n_rays = plans["small"].n_rays
    for plan in plans.values():
        time_batches(LocalExecutor(), plan, n_rays, 1)  # warm: compile or load the kernels
    say(f"plans built: {n_rays} rays")
    scaling = Table(
        "scaling_dask",
        f"Strong scaling, {n_rays} rays in batches of {SCALING_BATCH}",
        ["grid", "executor", "workers", "numba_threads", "trace_s", "speedup", "rays_per_s"],
    )
    overhead = Table(
        "batch_overhead",
        f"{OVERHEAD_RAYS} rays in 1 to {max(counts_all)} batches; "
        "ms_per_batch_fit = slope of T over the batch count, us_per_ray_fit = intercept / rays",
        ["grid", "executor", "batch_rays", "batches", "trace_s", "ms_per_batch_fit", "us_per_ray_fit"],
    )
    base = _local_rows(plans, scaling, overhead, sizes, repeats, say)
    _dask_rows(plans, scaling, overhead, sizes, repeats, base, say)
    section = Section(
        "scaling_dask", "Dask scale-out: strong scaling and overhead per batch", tables=[scaling, overhead]
    )
    section.text.append(f"{n_rays} rays; best of {repeats}; speedup against local on 1 numba thread.")
    return section


def _markdown(table: Table) -> str:
    def cell(v: Any) -> str:
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    lines = [f"**{table.title}**", "", "| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    lines += ["| " + " | ".join(cell(r[c]) for c in table.columns) + " |" for r in table.rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    import csv

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="folder for scaling_dask.md and the CSV tables")
    parser.add_argument("--quick", action="store_true", help="fewer rays and one repeat")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    section = run(args.quick, progress=lambda line: print("  " + line, flush=True))
    text = [f"# {section.title}", "", *section.text, ""]
    for table in section.tables:
        with open(out / f"{table.name}.csv", "w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=table.columns)
            writer.writeheader()
            writer.writerows(table.rows)
        text += [_markdown(table), ""]
    (out / "scaling_dask.md").write_text("\n".join(text), encoding="utf-8")
    print("\n".join(text))
    print(f"wrote {out} in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

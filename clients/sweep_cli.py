"""``bentray sweep``: one job per value of a parameter (a dotted path into the job JSON).

    bentray sweep JOB.json --param profile.b --values -1,-0.5,0,0.5,1 --out DIR [--dask ADDR]

Each value gives a copy of the job with that field set (``profile.b``, ``sources.0.position.2``:
list items by index; a missing last key is added), validated before anything runs (a bad value exits
with status 2 naming the field). Outputs of each job go to ``DIR/<param>=<value>/`` (the job's own
``outputs``), and ``DIR/sweep.csv`` has one row per value: rays by status, trace and wall seconds and,
for field jobs, the energy mean (``10 lg mean 10^(L/10)``; for a transmission loss ``-10 lg mean
10^(-TL/10)``) over the grid's finite points of ``spl_a`` (else the transmission loss band nearest 1 kHz,
as in preview.png), with a column ``field_mean_over`` naming those points. Each job's name gets the swept
value (``town_profile.b_-0.5``), so every preview.png has its own title.

Executors. Without Dask (no ``--dask`` and no ``BENTRAY_DASK_SCHEDULER``) the jobs run one after
another in this process. With Dask each value is ONE Dask task that runs the whole job (profile, mesh,
trace, field) on a worker with the local executor; the outcomes come back to this process, which writes
them. Sweeps differ in their media (e.g. ``profile.b`` changes the mesh), so every job builds its own mesh
anyway; building it on the worker parallelises the mesh builds too, and jobs of a sweep run concurrently
over the cluster. A single huge job is better run with ``bentray run --dask`` (its batches fan out).
Files named in the job (terrain, buildings, grid profiles) must be readable at the same path on workers.
"""

from __future__ import annotations

import argparse
import copy
import csv
import json
import math
import re
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# A value becomes part of a directory name: keep it to a portable, non-hidden file name.
_LABEL_RE = re.compile(r"^[A-Za-z0-9+_-][A-Za-z0-9.+_-]{0,63}$")
_PARAM_RE = re.compile(r"^[A-Za-z0-9_]+(\.[A-Za-z0-9_]+)*$")


class SweepError(ValueError):
    """A sweep that cannot run as asked (bad --param path or --values); exit status 2."""


@dataclass
class SweepRow:
    """One value's summary line of sweep.csv."""

    label: str
    value: Any
    out_dir: Path
    rays: dict[str, int]
    trace_s: float
    wall_s: float
    field_array: str
    field_mean: float
    field_mean_over: str = ""


def parse_values(text: str) -> list[tuple[str, Any]]:
    """``"-1,-0.5,0,on"`` -> [(label, value)]: each comma-separated item parsed as JSON, else a string."""
    items = [t.strip() for t in text.split(",")]
    if not items or any(not t for t in items):
        raise SweepError(f"--values: expected a comma-separated list, got {text!r}")
    out = []
    for item in items:
        if not _LABEL_RE.match(item):
            raise SweepError(f"--values: {item!r} cannot name an output directory (letters, digits, .+-_)")
        try:
            value = json.loads(item)
        except json.JSONDecodeError:
            value = item
        if isinstance(value, float) and not math.isfinite(value):
            raise SweepError(f"--values: {item!r} is not finite")
        out.append((item, value))
    if len({label for label, _ in out}) != len(out):
        raise SweepError(f"--values: duplicate values in {text!r}")
    return out


def set_dotted(spec: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """A deep copy of ``spec`` with ``path`` (``a.b.0.c``) set to ``value``; list items by index."""
    if not _PARAM_RE.match(path):
        raise SweepError(f"--param: {path!r} is not a dotted path like profile.b")
    out = copy.deepcopy(spec)
    node: Any = out
    parts = path.split(".")
    for depth, key in enumerate(parts):
        last = depth == len(parts) - 1
        where = ".".join(parts[: depth + 1])
        if isinstance(node, list):
            if not key.isdigit() or int(key) >= len(node):
                raise SweepError(f"--param {path}: {where} is not an item of a {len(node)}-item list")
            if last:
                node[int(key)] = value
            else:
                node = node[int(key)]
        elif isinstance(node, dict):
            if last:
                node[key] = value
            else:
                node = node.setdefault(key, {})
        else:
            raise SweepError(f"--param {path}: {'.'.join(parts[:depth])} is a value, not an object or list")
    return out


def energy_mean_db(values: Any, *, loss: bool = False) -> tuple[float, int]:
    """(energy mean in dB, number of finite values) of a level array: ``10 lg(mean 10^(L/10))``; for a loss
    (TL, dB re the 1 m free field, larger is quieter) ``-10 lg(mean 10^(-TL/10))``. NaN / inf values (no
    beam reached the point, inside a solid) are left out; (nan, 0) when none is finite."""
    import numpy as np

    arr = np.asarray(values, dtype=np.float64)
    finite = arr[np.isfinite(arr)]
    if not finite.size:
        return math.nan, 0
    sign = -1.0 if loss else 1.0
    top = float(finite.max() if not loss else finite.min())  # factored out: no overflow at 300+ dB
    mean = float(np.mean(10.0 ** (sign * (finite - top) / 10.0)))
    return top + sign * 10.0 * math.log10(mean), int(finite.size)


def field_summary(outcome: Any) -> tuple[str, float, str]:
    """(array name, energy mean in dB, over which points) of the preview array; ("", nan, "") without a field."""
    import numpy as np

    if outcome.field is None:
        return "", math.nan, ""
    name, _ = outcome.field.preview_array()
    arr = np.asarray(outcome.field.arrays[name], float)
    mean, n = energy_mean_db(arr, loss=name.startswith("tl_"))
    return name, mean, f"energy mean over the {n} of {arr.size} grid points with a finite {name}"


def _job_name(spec: dict[str, Any], param: str, label: str) -> str:
    """The job's name with the swept value (the preview title of each job names its value)."""
    import re

    name = f"{spec.get('name', 'job')}_{param}_{label}"
    return re.sub(r"[^A-Za-z0-9._-]", "_", name)[:100]


def _run_one(spec: dict[str, Any], base_dir: str | None) -> Any:
    """Validate and run one job with the local executor (in this process or on a Dask worker)."""
    from bentray.engine.executors import LocalExecutor
    from bentray.engine.run import run_job
    from bentray.scenes.schema import Job

    t0 = time.perf_counter()
    outcome = run_job(Job.model_validate(spec), Path(base_dir) if base_dir else None, executor=LocalExecutor())
    outcome.report.setdefault("timings_s", {})["job_wall"] = time.perf_counter() - t0
    return outcome


def run_sweep(
    job_path: Path,
    param: str,
    values: list[tuple[str, Any]],
    out_dir: Path,
    *,
    dask: str | None = None,
    progress: Callable[[str], None] | None = None,
) -> list[SweepRow]:
    """Run the sweep, write every job's outputs and ``out_dir/sweep.csv``; rows in ``values`` order.

    dask: scheduler address (or a ``distributed.Client``); None runs the jobs here one after another.
    """
    from pydantic import ValidationError

    from bentray.engine.writers import write_outcome
    from bentray.scenes.schema import Job, format_validation_error, load_job

    say = progress or (lambda line: None)
    load_job(job_path)  # the base job must be valid on its own (errors name the field)
    base = json.loads(job_path.read_text(encoding="utf-8"))  # the raw JSON: only what the user wrote
    specs = []
    for label, value in values:
        spec = set_dotted(base, param, value)
        spec["name"] = _job_name(spec, param, label)
        try:
            job = Job.model_validate(spec)
        except ValidationError as exc:
            raise SweepError(f"{param}={label}: invalid job:\n{format_validation_error(exc)}") from None
        specs.append((label, value, spec, [str(o) for o in job.outputs]))
    base_dir = str(job_path.absolute().parent)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows: dict[str, SweepRow] = {}

    def finish(i: int, outcome: Any) -> None:
        label, value, _, outputs = specs[i]
        target = out_dir / f"{param}={label}"
        write_outcome(outcome, outputs, target)
        name, mean, over = field_summary(outcome)
        timings = outcome.report.get("timings_s", {})
        rows[label] = SweepRow(
            label,
            value,
            target,
            outcome.trace.status_counts(),
            float(timings.get("trace", 0.0)),
            float(timings.get("job_wall", 0.0)),
            name,
            mean,
            over,
        )
        say(f"{param}={label}: {outcome.trace.n_rays} rays, trace {rows[label].trace_s:.2f} s -> {target}")

    if dask is None:
        for i, (_, _, spec, _) in enumerate(specs):
            finish(i, _run_one(spec, base_dir))
    else:
        from distributed import as_completed

        from bentray.engine.dask_executor import DEFAULT_RETRIES, DaskExecutor, aligned_arrays, on_worker

        client = DaskExecutor(dask).client
        tag = uuid.uuid4().hex[:12]
        futures = [
            client.submit(
                on_worker, _run_one, spec, base_dir, key=f"bentray-sweep-{tag}-{i}", retries=DEFAULT_RETRIES, pure=False
            )
            for i, (_, _, spec, _) in enumerate(specs)
        ]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            completed = as_completed(futures, loop=client.loop, with_results=True)  # type: ignore[no-untyped-call]
            for fut, outcome in completed:
                fut.release()
                finish(index[fut.key], aligned_arrays(outcome))
        finally:
            client.cancel([f for f in futures if not f.done()])  # type: ignore[no-untyped-call]
    ordered = [rows[label] for label, *_ in specs]
    write_sweep_csv(param, ordered, out_dir / "sweep.csv")
    return ordered


def write_sweep_csv(param: str, rows: list[SweepRow], path: Path) -> None:
    """sweep.csv: param, value, dir, rays_total, rays_<status>..., trace_s, wall_s, field_array, field_mean_db
    (the energy mean of the preview array, :func:`energy_mean_db`), field_mean_over (which points)."""
    statuses = list(rows[0].rays) if rows else []
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "param",
                "value",
                "dir",
                "rays_total",
                *[f"rays_{s}" for s in statuses],
                "trace_s",
                "wall_s",
                "field_array",
                "field_mean_db",
                "field_mean_over",
            ]
        )
        for r in rows:
            w.writerow(
                [
                    param,
                    r.label,
                    r.out_dir.name,
                    sum(r.rays.values()),
                    *[r.rays.get(s, 0) for s in statuses],
                    f"{r.trace_s:.6f}",
                    f"{r.wall_s:.6f}",
                    r.field_array,
                    "" if math.isnan(r.field_mean) else f"{r.field_mean:.6f}",
                    r.field_mean_over,
                ]
            )


def cmd_sweep(args: argparse.Namespace) -> int:
    from bentray.clients.cli import CommandError, _load, dask_address

    job_path = Path(args.job)
    _load(job_path)  # unreadable or invalid base job: exit 2 with the field errors
    out_dir = Path(args.out)
    if out_dir.exists() and not out_dir.is_dir():
        raise CommandError(f"--out {out_dir} exists and is not a directory", code=2)
    dask = dask_address(args.dask)
    t0 = time.perf_counter()
    try:
        rows = run_sweep(
            job_path,
            args.param,
            parse_values(args.values),
            out_dir,
            dask=dask,
            progress=lambda line: print("  " + line, flush=True),
        )
    except SweepError as exc:
        raise CommandError(str(exc), code=2) from None
    where = f"Dask scheduler {dask}" if dask else "this process"
    print(
        f"sweep {args.param}: {len(rows)} jobs on {where} in {time.perf_counter() - t0:.2f} s; "
        f"wrote {out_dir / 'sweep.csv'}"
    )
    return 0


def add_sweep(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "sweep",
        help="run one job per value of a parameter; write DIR/<param>=<value>/ and sweep.csv",
        description="Run a job once per value of one parameter (a dotted path into the job JSON).",
    )
    # values such as "-1,-0.5,0" start with '-': accept them as values, not as unknown options
    p._negative_number_matcher = re.compile(r"^-\.?\d")
    p.add_argument("job", help="job file (JSON)")
    p.add_argument("--param", required=True, help="dotted path into the job JSON, e.g. profile.b")
    p.add_argument("--values", required=True, help="comma-separated values (JSON each), e.g. -1,-0.5,0,0.5,1")
    p.add_argument("--out", required=True, help="output directory: <param>=<value>/ per job, sweep.csv")
    p.add_argument(
        "--dask",
        metavar="ADDR",
        default=None,
        help="Dask scheduler (tcp://host:8786): one task per value (default: BENTRAY_DASK_SCHEDULER, "
        "else this process)",
    )
    p.set_defaults(func=cmd_sweep)

"""``bentray warmup``: compile the kernels once, before the first real job needs them.

    bentray warmup [JOB.json ...] [--no-builtin] [--threads N]

Runs miniature copies of the packaged example jobs (scenes/examples/*.json, the README's first command
among them), of every built-in scene's ready-made job (scenes/library/jobs.py, medium resolution, with
its wind) and of any JOB files given: at most 3 x 3 rays, a field grid of at most 4 x 4 x 4 points, the
same settings otherwise. Numba specialises kernels by argument types, not sizes, so a miniature compiles
exactly what the full job later loads from the cache (``NUMBA_CACHE_DIR``, keyed by the engine's source;
bentray/__init__.py). Nothing is written but the cache. The docker image runs this at build time.

Prints one line per job (wall time, compilation measured by engine.compile_time) and the totals; a
second run prints about zero compilation. Exit status 2 for an unreadable or invalid job file.
"""

from __future__ import annotations

import argparse
import json
import time
from importlib import resources
from pathlib import Path
from typing import Any

__all__ = ["add_warmup", "cmd_warmup", "miniature", "warmup_specs"]

MAX_COUNT = 3  # rays per launch-angle axis in a miniature
MAX_FIELD_POINTS = 4  # field grid points per axis in a miniature


def miniature(spec: dict[str, Any]) -> dict[str, Any]:
    """A copy of job JSON ``spec`` with at most MAX_COUNT elevations and azimuths, a field grid of at most
    MAX_FIELD_POINTS per axis over the same extent (first and last points kept), outputs kept; the same types
    reach every kernel."""
    out: dict[str, Any] = json.loads(json.dumps(spec))
    rays = out.get("rays") or {}
    for axis in ("elevation_deg", "azimuth_deg"):
        if isinstance(rays.get(axis), dict) and "count" in rays[axis]:
            rays[axis]["count"] = min(int(rays[axis]["count"]), MAX_COUNT)
    fld = out.get("field")
    if isinstance(fld, dict) and "shape" in fld:
        full = [int(n) for n in fld["shape"]]
        fld["shape"] = [min(n, MAX_FIELD_POINTS) for n in full]
        spacing = fld.get("spacing")
        if isinstance(spacing, list) and len(spacing) == len(full):
            # the same extent, fewer points: the stages that decide from where the grid lies (the refractive
            # shadow's azimuth bins) decide as for the full job, instead of running (and compiling) for a small one
            fld["spacing"] = [
                float(h) * (n - 1) / (m - 1) if n > m > 1 else h
                for h, n, m in zip(spacing, full, fld["shape"], strict=True)
            ]
    out["name"] = f"warmup-{out.get('name', 'job')}"
    return out


def warmup_specs(extra: list[Path], builtin: bool) -> list[tuple[str, dict[str, Any], Path | None]]:
    """(label, miniature job JSON, base folder for relative paths) of every job to warm."""
    from bentray.scenes.library.jobs import builtin_job_spec
    from bentray.scenes.library.registry import BUILTIN_SCENES
    from bentray.scenes.schema import JobFileError

    specs: list[tuple[str, dict[str, Any], Path | None]] = []
    if builtin:
        examples = resources.files("bentray.scenes") / "examples"
        for entry in sorted(examples.iterdir(), key=lambda e: e.name):
            if entry.name.endswith(".json"):
                base = Path(str(entry)).parent
                specs.append((f"example {entry.name}", miniature(json.loads(entry.read_text())), base))
        for name in BUILTIN_SCENES:
            specs.append((f"scene {name}", miniature(builtin_job_spec(name, resolution="medium")), None))
    for path in extra:
        try:
            spec = json.loads(Path(path).read_text())
        except (OSError, ValueError) as exc:
            raise JobFileError(f"{path}: cannot read the job: {exc}") from None
        specs.append((str(path), miniature(spec), Path(path).absolute().parent))
    return specs


def cmd_warmup(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from bentray.clients.cli import CommandError, _set_threads
    from bentray.engine.compile_time import compile_timer
    from bentray.engine.run import run_job
    from bentray.scenes.schema import Job, JobFileError, format_validation_error

    if args.threads is not None:
        _set_threads(args.threads)
    try:
        specs = warmup_specs([Path(p) for p in args.jobs], builtin=not args.no_builtin)
        jobs = [(label, Job.model_validate(spec), base) for label, spec, base in specs]
    except JobFileError as exc:
        raise CommandError(str(exc), code=2) from None
    except ValidationError as exc:
        raise CommandError(f"invalid job:\n{format_validation_error(exc)}", code=2) from None
    import os

    print(f"warmup: {len(jobs)} miniature job(s); numba cache {os.environ.get('NUMBA_CACHE_DIR', '(default)')}")
    t_all = time.perf_counter()
    with compile_timer() as total:
        for label, job, base in jobs:
            t0 = time.perf_counter()
            with compile_timer() as ct:
                run_job(job, base)
            print(
                f"  {label}: {time.perf_counter() - t0:.1f} s, compiled {ct.functions} function(s) in "
                f"{ct.seconds:.1f} s",
                flush=True,
            )
    print(
        f"warmup: {time.perf_counter() - t_all:.1f} s, of which Numba compilation {total.seconds:.1f} s "
        f"({total.functions} function(s))"
    )
    return 0


def add_warmup(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from bentray.clients.cli import _positive_int

    p = sub.add_parser(
        "warmup",
        help="compile the kernels the examples, the built-in scenes and given jobs use (fills the cache)",
        description="Compile every kernel the packaged examples, the built-in scenes' jobs and the given job "
        "files use, by running miniature copies of them (nothing is written but the numba cache).",
    )
    p.add_argument("jobs", nargs="*", metavar="JOB", help="extra job files to warm (JSON)")
    p.add_argument("--no-builtin", action="store_true", help="only the given job files")
    p.add_argument("--threads", type=_positive_int, default=None, help="numba threads (default: all)")
    p.set_defaults(func=cmd_warmup)

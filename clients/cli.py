"""The ``bentray`` command line.

    bentray run JOB.json --out DIR [--threads N] [--dask ADDR] [--check]
    bentray sweep JOB.json --param PATH --values V1,V2,... --out DIR [--dask ADDR]
    bentray bench --out DIR [--quick] [--only NAME ...]
    bentray scenes [--resolution medium|high] [--json] [--job NAME]
    bentray warmup [JOB.json ...] [--no-builtin]

Exit status: 0 success; 2 invalid command line or job file (unreadable, invalid JSON, schema errors,
scene, medium or cost-model problems and any input error the engine finds, printed one
``field.path: reason`` per line on stderr); 1 any other error during the run (one line on stderr;
``--traceback`` shows the full traceback instead); 143 SIGTERM (temporary folders removed).

Subcommands register themselves in :data:`COMMANDS` (more to come: scenes, bench, serve, submit).
Heavy imports (the engine, numba, pyvista) happen inside the command that needs them.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import bentray
from bentray.engine.errors import BentrayError

if TYPE_CHECKING:
    from bentray.engine.preview_process import PreviewWorker
    from bentray.engine.result import JobOutcome
    from bentray.scenes.schema import Job

# Errors reported as one line with exit status 1: bentray's own (engine/errors.py) and the usual
# input/resource failures. Anything else is a bug and keeps its traceback.
_PREVIEW_GLANCE_BYTES = 1_000_000  # larger job files are not read twice to start the preview process early
_RUN_ERRORS: tuple[type[BaseException], ...] = (
    BentrayError,
    ValueError,
    OSError,
    RuntimeError,
    MemoryError,
    OverflowError,
    ArithmeticError,
)


class Terminated(BaseException):
    """SIGTERM: unwinds like Ctrl-C so that staging folders beside --out are removed (exit 143)."""


def _on_sigterm(signum: int, frame: object) -> None:
    raise Terminated()


DASK_SCHEDULER_ENV = "BENTRAY_DASK_SCHEDULER"  # default of --dask (bentray run, bentray sweep)


def dask_address(flag: str | None) -> str | None:
    """The Dask scheduler for ``--dask``: the flag, else ``BENTRAY_DASK_SCHEDULER``, else None (this process)."""
    import os

    return (flag or "").strip() or os.environ.get(DASK_SCHEDULER_ENV, "").strip() or None


class _LazyChoices:
    """argparse ``choices`` read on first use (checking a value, printing help or an error), so that building
    the parser for ``bentray run`` does not import the bench or the scene library."""

    def __init__(self, load: Callable[[], Sequence[str]]) -> None:
        self._load = load
        self._names: tuple[str, ...] | None = None

    def _get(self) -> tuple[str, ...]:
        if self._names is None:
            self._names = tuple(self._load())
        return self._names

    def __contains__(self, item: object) -> bool:
        return item in self._get()

    def __iter__(self) -> Iterator[str]:
        return iter(self._get())

    def __len__(self) -> int:
        return len(self._get())


class CommandError(Exception):
    """A user-facing failure of a command: printed as one line, exit status ``code``."""

    def __init__(self, message: str, code: int = 1) -> None:
        super().__init__(message)
        self.code = code


# ---------------------------------------------------------------------------------------------
# bentray run
# ---------------------------------------------------------------------------------------------
def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _set_threads(n: int) -> None:
    import numba

    available = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # set at import
    if n > available:
        raise CommandError(f"--threads {n} exceeds the {available} threads numba can use", code=2)
    numba.set_num_threads(n)


def _load(job_path: Path) -> Job:
    from pydantic import ValidationError

    from bentray.scenes.schema import JobFileError, format_validation_error, load_job

    try:
        return load_job(job_path)
    except JobFileError as exc:
        raise CommandError(str(exc), code=2) from None
    except ValidationError as exc:
        raise CommandError(
            f"{job_path}: invalid job ({exc.error_count()} error(s)):\n{format_validation_error(exc)}", code=2
        ) from None


def _summary(job: Job, outcome: JobOutcome, written: list[Path], wall_s: float, write_s: float = 0.0) -> str:
    trace = outcome.trace
    lines = [f"job {job.name}: {trace.n_rays} rays in {wall_s:.2f} s"]
    counts = {name: n for name, n in trace.status_counts().items() if n}
    lines.append("  rays by status: " + (", ".join(f"{k} {v}" for k, v in counts.items()) or "none"))
    timings = outcome.report.get("timings_s") or {}
    if timings:
        parts = []
        for stage, seconds in timings.items():
            try:
                parts.append(f"{stage} {float(seconds):.3f}")
            except (TypeError, ValueError):
                parts.append(f"{stage} {seconds}")
        lines.append("  timings (s): " + ", ".join(parts))
    compiled = outcome.report.get("compile_s") or {}
    if compiled.get("total"):
        stages = ", ".join(f"{k} {float(v):.1f}" for k, v in compiled.items() if k != "total")
        lines.append(f"  of which Numba compilation (s): {float(compiled['total']):.1f} ({stages}; once per install)")
    sizes = [f"{p} ({p.stat().st_size / 1e6:.1f} MB)" if p.is_file() else str(p) for p in written]
    lines.append(f"  wrote in {write_s:.2f} s: " + (", ".join(sizes) or "nothing"))
    return "\n".join(lines)


def _check(job: Job, job_path: Path) -> None:
    """The checks the service runs at submit (scene, sources, medium, cost model with this machine's
    memory): one ``field.path: reason`` line each, exit status 2."""
    import numba

    from bentray.scenes.cost import CostLimits, cost_problems, machine_memory_bytes
    from bentray.scenes.job_checks import scene_problems

    machine = machine_memory_bytes()
    limits = CostLimits(
        memory_bytes=int(0.8 * machine) if machine > 0 else CostLimits().memory_bytes,
        threads=int(numba.get_num_threads()),
    )
    base = job_path.absolute().parent
    lines = scene_problems(job, base) + cost_problems(job, limits, base)
    if lines:
        raise CommandError(f"{job_path}: invalid job ({len(lines)} error(s)):\n" + "\n".join(lines), code=2)


def _start_preview(job_path: Path) -> PreviewWorker | None:
    """Start preview.png's drawing process (engine/preview_process.py) when the job file lists 'field' in
    its outputs: a glance at the JSON before validation, so the child imports matplotlib on the idle core
    while this process validates the job and builds the mesh. A file that is not such JSON starts
    nothing (validation reports it); a job that turns out invalid just stops the child."""
    from bentray.engine.preview_process import PreviewWorker

    try:
        if job_path.stat().st_size > _PREVIEW_GLANCE_BYTES:
            return None
        data = json.loads(job_path.read_bytes())
    except (OSError, ValueError, RecursionError):
        return None
    outputs = data.get("outputs") if isinstance(data, dict) else None
    if isinstance(outputs, list) and "field" in outputs:
        return PreviewWorker.start()
    return None


def cmd_run(args: argparse.Namespace) -> int:
    job_path = Path(args.job)
    preview = None if args.check else _start_preview(job_path)
    try:
        return _run(args, job_path, preview)
    finally:
        if preview is not None:
            preview.close()


def _run(args: argparse.Namespace, job_path: Path, preview: PreviewWorker | None) -> int:
    job = _load(job_path)
    out_dir = Path(args.out)
    if out_dir.exists() and not out_dir.is_dir():
        raise CommandError(f"--out {out_dir} exists and is not a directory", code=2)
    if args.threads is not None:
        _set_threads(args.threads)
    _check(job, job_path)
    if args.check:
        print(f"{job_path}: valid job ({job.n_rays:,} rays)")
        return 0

    from bentray.clients.progress import RunProgress
    from bentray.engine.errors import JobInputError
    from bentray.engine.executors import make_executor
    from bentray.engine.run import run_job
    from bentray.engine.writers import write_outcome

    executor = make_executor(dask_address(args.dask))
    t0 = time.perf_counter()
    progress = RunProgress(job.n_rays)  # stages and a ray bar on a terminal; nothing when piped
    try:
        outcome = run_job(job, job_path.absolute().parent, executor=executor, progress=progress)
    except JobInputError as exc:  # the job cannot run as asked: its lines name the field
        raise CommandError(f"{job_path}: invalid job:\n{exc}", code=2) from None
    finally:
        progress.close()
    t_write = time.perf_counter()
    written = write_outcome(outcome, list(job.outputs), out_dir, preview_worker=preview)
    write_s = time.perf_counter() - t_write
    print(_summary(job, outcome, written, time.perf_counter() - t0, write_s))
    return 0


def _add_run(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("run", help="trace one job file and write its outputs", description="Trace one job.")
    p.add_argument("job", help="job file (JSON, see scenes/examples/)")
    p.add_argument("--out", required=True, help="output directory (created; files replaced all-or-nothing)")
    p.add_argument("--threads", type=_positive_int, default=None, help="numba threads (default: all)")
    p.add_argument(
        "--check",
        action="store_true",
        help="validate only (schema, scene, medium, cost model; the service's submit checks) and exit",
    )
    p.add_argument(
        "--dask",
        metavar="ADDR",
        default=None,
        help="run the ray batches on this Dask scheduler, e.g. tcp://host:8786 "
        "(default: BENTRAY_DASK_SCHEDULER, else this process)",
    )
    p.set_defaults(func=cmd_run)


# ---------------------------------------------------------------------------------------------
# bentray bench
# ---------------------------------------------------------------------------------------------
def cmd_bench(args: argparse.Namespace) -> int:
    out_dir = Path(args.out)
    if out_dir.exists() and not out_dir.is_dir():
        raise CommandError(f"--out {out_dir} exists and is not a directory", code=2)

    from bentray.engine.bench.runner import run_bench_sections

    t0 = time.perf_counter()
    outcome = run_bench_sections(
        out_dir, quick=args.quick, only=args.only, progress=lambda line: print("  " + line, flush=True)
    )
    print(f"bench: wrote {outcome.report} in {time.perf_counter() - t0:.1f} s")
    if outcome.failed:
        raise CommandError(f"section(s) failed: {', '.join(outcome.failed)} (see {outcome.report})")
    return 0


def _bench_sections() -> list[str]:
    from bentray.engine.bench.runner import SECTIONS

    return list(SECTIONS)


def _add_bench(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "bench",
        help="benchmark accuracy and speed; write report.md, CSVs and PNGs",
        description="Run the benchmark sections and write report.md, CSV tables and PNG plots.",
    )
    p.add_argument("--out", required=True, help="output directory (created; files in it are replaced)")
    p.add_argument("--quick", action="store_true", help="smoke run: fewer rays, settings and repeats (~2 min)")
    p.add_argument(
        "--only",
        nargs="+",
        choices=_LazyChoices(_bench_sections),
        metavar="NAME",
        help="run only these sections: %(choices)s",
    )
    p.set_defaults(func=cmd_bench)


# ---------------------------------------------------------------------------------------------
# bentray scenes
# ---------------------------------------------------------------------------------------------
def cmd_scenes(args: argparse.Namespace) -> int:
    import json

    from bentray.scenes.library.registry import scene_table

    if args.job is not None:
        from bentray.scenes.library.jobs import builtin_job_spec

        try:
            spec = builtin_job_spec(args.job, resolution=args.resolution)
        except ValueError as exc:
            raise CommandError(str(exc), code=2) from None
        print(json.dumps(spec, indent=1))
        return 0
    rows = scene_table(args.resolution)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    cols = ["name", "domain_m", "triangles", "buildings", "sources", "profile"]
    width = {c: max(len(c), *(len(str(r[c])) for r in rows)) for c in cols}
    print("  ".join(c.ljust(width[c]) for c in cols))
    for r in rows:
        print("  ".join(str(r[c]).ljust(width[c]) for c in cols))
    print()
    for r in rows:
        print(f"{r['name']}: {r['description']}")
    return 0


def _builtin_scene_names() -> list[str]:
    from bentray.scenes.library.registry import BUILTIN_SCENES

    return list(BUILTIN_SCENES)


def _add_scenes(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from bentray.scenes.library.common import RESOLUTIONS  # the registry (every scene module) loads on use

    p = sub.add_parser(
        "scenes",
        help="list the built-in scenes with their stats",
        description="List the built-in scenes (scene.builtin) with their size, surface "
        "triangles, buildings, sources and default profile.",
    )
    p.add_argument("--resolution", choices=list(RESOLUTIONS), default="medium")
    p.add_argument("--json", action="store_true", help="print the table as JSON")
    p.add_argument(
        "--job",
        choices=_LazyChoices(_builtin_scene_names),
        metavar="NAME",
        help="print a ready-to-run job file for this scene (10,000 rays, 3 reflections) instead",
    )
    p.set_defaults(func=cmd_scenes)


# Each entry adds one subcommand parser (with set_defaults(func=handler)).
COMMANDS: list[Callable[[argparse._SubParsersAction[argparse.ArgumentParser]], None]] = [
    _add_run,
    _add_bench,
    _add_scenes,
]


def _add_sweep(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from bentray.clients.sweep_cli import add_sweep  # bentray sweep (one job per parameter value)

    add_sweep(sub)


COMMANDS.append(_add_sweep)


def _add_service_verbs(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from bentray.clients.service_cli import SERVICE_COMMANDS  # serve, submit, status, fetch, cancel

    for add in SERVICE_COMMANDS:
        add(sub)


COMMANDS.append(_add_service_verbs)


def _add_export(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from bentray.clients.export_cli import add_export  # bentray export (GeoTIFF, isophones, facades, ...)

    add_export(sub)


COMMANDS.append(_add_export)


def _add_lden(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from bentray.clients.lden_cli import add_lden  # bentray lden (period levels and Lden of conditions)

    add_lden(sub)


COMMANDS.append(_add_lden)


def _add_warmup(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from bentray.clients.warmup_cli import add_warmup  # bentray warmup (fill the numba cache)

    add_warmup(sub)


COMMANDS.append(_add_warmup)


def _add_render(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from bentray.clients.render_cli import add_render  # bentray render (a camera through the media mesh)

    add_render(sub)


COMMANDS.append(_add_render)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="bentray", description="Outdoor-acoustics curved-ray engine.")
    parser.add_argument("--version", action="version", version=f"bentray {bentray.__version__}")
    parser.add_argument("--traceback", action="store_true", help="show full tracebacks on errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for add in COMMANDS:
        add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help(sys.stderr)
        return 2
    import signal

    try:
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread: leave signals alone
        previous = None
    try:
        return int(args.func(args) or 0)
    except Terminated:
        print(f"bentray {args.command}: terminated", file=sys.stderr)
        return 143
    except RecursionError as exc:
        if args.traceback:
            raise
        print(f"bentray {args.command}: error: input nests too deeply ({exc})", file=sys.stderr)
        return 2
    except CommandError as exc:
        if args.traceback:
            raise
        print(f"bentray {args.command}: error: {exc}", file=sys.stderr)
        return exc.code
    except _RUN_ERRORS as exc:
        if args.traceback:
            raise
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"bentray {args.command}: error: {type(exc).__name__}: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"bentray {args.command}: interrupted", file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())

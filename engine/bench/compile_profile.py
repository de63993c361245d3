"""Where a first run's Numba compilation goes: per function, and LLVM's part of it.

    python -m bentray.engine.bench.compile_profile [JOB.json] [--top 30]

Runs the miniature of JOB (``bentray warmup``'s: the same kernels and types, a few rays; default the README's
job, scenes/examples/ridge-wind-map.json) in a child process whose ``NUMBA_CACHE_DIR`` is a new empty folder,
so every kernel the job needs compiles, and prints:

- the total wall time and the number of dispatcher compilations (one per function and signature);
- LLVM's part: function passes, module passes (on a function's module with its callees linked in), machine
  code and cache writes, timed around Numba's own CPUCodeLibrary methods (private API: a Numba upgrade may
  rename them; the per-function table below uses the public ``numba:compile`` events only);
- per function: the wall time inside its ``numba:compile`` event less its callees' (self) and with them
  (inclusive), its nesting depth, and the functions compiled for more than one signature.

Measured with it: docs/physics.md §9, "Where a first run's compilation goes". The numbers move by several
seconds from run to run on a shared machine; compare runs in the same minutes.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["CompileProfile", "FunctionCompile", "format_profile", "main", "profile_compilation"]

README_JOB = Path(__file__).resolve().parents[2] / "scenes" / "examples" / "ridge-wind-map.json"
LLVM_STEPS = ("function passes", "module passes", "machine code", "cache writes")


@dataclass
class FunctionCompile:
    """One dispatcher compilation: name (module.qualname), inclusive and self wall seconds, depth (0: compiled
    from Python, 1: by a depth-0 function's typing, ...)."""

    name: str
    inclusive_s: float
    self_s: float
    depth: int


@dataclass
class CompileProfile:
    """functions : every compilation in the order they ended; llvm_s : seconds per LLVM_STEPS entry; wall_s."""

    functions: list[FunctionCompile] = field(default_factory=list)
    llvm_s: dict[str, float] = field(default_factory=lambda: dict.fromkeys(LLVM_STEPS, 0.0))
    wall_s: float = 0.0


def _name(dispatcher: Any) -> str:
    fn = getattr(dispatcher, "py_func", None)
    if fn is None:
        return str(dispatcher)
    return f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', '?')}"


@contextmanager
def _llvm_timers(into: dict[str, float]) -> Iterator[None]:
    """Add the wall time of Numba's LLVM steps into ``into`` (keys LLVM_STEPS) while the block runs."""
    from numba.core import codegen

    targets = [
        (codegen.CPUCodeLibrary, "_optimize_functions", "function passes"),
        (codegen.CPUCodeLibrary, "_optimize_final_module", "module passes"),
        (codegen.JITCodeLibrary, "_finalize_specific", "machine code"),
        (codegen.CPUCodeLibrary, "serialize_using_object_code", "cache writes"),
    ]
    saved = []
    for cls, attr, key in targets:
        original = getattr(cls, attr, None)
        if original is None:  # a Numba that renamed it: that step is reported as 0
            continue

        def timed(self: Any, *args: Any, _original: Callable[..., Any] = original, _key: str = key, **kw: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return _original(self, *args, **kw)
            finally:
                into[_key] += time.perf_counter() - t0

        saved.append((cls, attr, original))
        setattr(cls, attr, timed)
    try:
        yield
    finally:
        for cls, attr, original in saved:
            setattr(cls, attr, original)


def profile_compilation(work: Callable[[], Any]) -> CompileProfile:
    """Run ``work()`` in this process and profile the Numba compilations it triggers (only those: functions
    already in the on-disk cache load without a compile event). Compilations on other threads are nested as
    they come (Numba compiles under one global lock, so they do not overlap)."""
    from numba.core import event

    prof = CompileProfile()
    stack: list[list[Any]] = []  # [dispatcher, start, callees' inclusive seconds]
    lock = threading.Lock()

    class _Listener(event.Listener):
        def on_start(self, ev: Any) -> None:
            data = ev.data if isinstance(ev.data, dict) else {}
            with lock:
                stack.append([data.get("dispatcher"), time.perf_counter(), 0.0])

        def on_end(self, ev: Any) -> None:
            with lock:
                dispatcher, t0, callees = stack.pop()
                inclusive = time.perf_counter() - t0
                if stack:
                    stack[-1][2] += inclusive
                prof.functions.append(FunctionCompile(_name(dispatcher), inclusive, inclusive - callees, len(stack)))

    t0 = time.perf_counter()
    with _llvm_timers(prof.llvm_s), event.install_listener("numba:compile", _Listener()):
        work()
    prof.wall_s = time.perf_counter() - t0
    return prof


def format_profile(prof: CompileProfile, top: int = 30) -> str:
    """The profile as text: totals, LLVM's steps, the ``top`` functions by self time, repeated signatures."""
    compiled = sum(f.inclusive_s for f in prof.functions if f.depth == 0)
    llvm = sum(prof.llvm_s.values())
    lines = [
        f"wall {prof.wall_s:.1f} s, of which compiling {compiled:.1f} s: {len(prof.functions)} compilations",
        f"LLVM {llvm:.1f} s: " + ", ".join(f"{k} {v:.2f} s" for k, v in prof.llvm_s.items()),
        f"Numba's own (bytecode, typing, lowering, the rest) ~{compiled - llvm:.1f} s",
        "",
        f"{'self s':>8} {'incl s':>8} depth  function",
    ]
    for f in sorted(prof.functions, key=lambda f: -f.self_s)[:top]:
        lines.append(f"{f.self_s:8.2f} {f.inclusive_s:8.2f} {f.depth:5d}  {f.name}")
    repeats: dict[str, list[float]] = defaultdict(list)
    for f in prof.functions:
        repeats[f.name].append(f.self_s)
    multi = {k: v for k, v in repeats.items() if len(v) > 1}
    if multi:
        lines += ["", "compiled for more than one signature (count, self s):"]
        for name, times in sorted(multi.items(), key=lambda kv: -sum(kv[1])):
            lines.append(f"  {len(times)} x {sum(times):6.2f}  {name}")
    return "\n".join(lines)


def _child(job_path: Path, top: int) -> None:
    """In the child (empty NUMBA_CACHE_DIR set by the parent): profile the miniature of the job and print it."""
    from bentray.clients.warmup_cli import miniature
    from bentray.engine.run import run_job
    from bentray.scenes.schema import Job

    job = Job.model_validate(miniature(json.loads(job_path.read_text())))
    prof = profile_compilation(lambda: run_job(job, job_path.parent))
    print(format_profile(prof, top), flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("job", nargs="?", type=Path, default=README_JOB)
    parser.add_argument("--top", type=int, default=30, help="functions to list by self time")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if not args.job.is_file():
        print(f"compile_profile: job: no such file: {args.job}", file=sys.stderr)
        return 2
    if args.child:
        _child(args.job, args.top)
        return 0
    with tempfile.TemporaryDirectory(prefix="bentray-compile-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        cmd = [sys.executable, "-m", "bentray.engine.bench.compile_profile", str(args.job), "--top", str(args.top)]
        print(f"compile_profile: {args.job} (miniature), empty numba cache {cache}", flush=True)
        return subprocess.run([*cmd, "--child"], env=env, check=False).returncode


if __name__ == "__main__":
    raise SystemExit(main())

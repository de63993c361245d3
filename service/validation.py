"""Submit-time validation in a separate process, under a time limit (the API's threads never run it).

Validating a job is CPU work whose cost depends on the input (pydantic over a large body, polygon
checks, reading an uploaded terrain, sampling the medium): it runs in a long-lived helper process
(multiprocessing ``spawn``) that the API thread waits on for at most ``Settings.validation_seconds``.
A helper that overruns is killed (SIGKILL) and replaced; the request is answered 422 with the limit in
the text. A new helper imports the validation modules first and says when it is ready (up to
:data:`HELPER_START_S`, its own allowance): the time limit is the validation's, never the helper's
start-up (a cold helper on a loaded machine took over 10 s to import them). Two stages, each one round trip:

1. :func:`check_job_text`: the job JSON -> schema, server limits and the cost model -> the job's name
   and the files it names (the API then places those files in the job's inputs folder);
2. :func:`check_job_scene`: uploaded files read as their kind, then the scene checks of
   :func:`bentray.scenes.job_checks.scene_problems` (overlaps, sources below the ground, the medium),
   and the mesh-time estimate of a job whose profile or terrain is a file (stage 1 could not read it).

Results are plain dicts (``{"ok": bool, "lines": [...], "code": str, ...}``), never exceptions.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

__all__ = ["JobLimits", "ValidationBusy", "ValidationPool", "ValidationTimeout", "check_job_scene", "check_job_text"]


HELPER_START_S = 120.0  # a new helper's imports: waited for apart from the validation time limit
_READY = "ready"
# validated once by a new helper before it says it is ready (first calls import and build lazily)
_WARM_JOB = (
    '{"name": "warm", "scene": {"domain": {"min": [0, 0, 0], "max": [100, 100, 50]}}, '
    '"profile": {"kind": "log"}, "sources": [{"position": [50, 50, 2]}], '
    '"rays": {"elevation_deg": {"min": -5, "max": 5, "count": 3}, "max_time_s": 0.5, "max_reflections": 1}}'
)


class ValidationTimeout(Exception):
    """The validation helper did not answer within the time limit (it was killed)."""


class ValidationBusy(Exception):
    """Every validation helper stayed busy for the waiting allowance (the server is overloaded)."""


@dataclass(frozen=True)
class JobLimits:
    """The server limits a job is checked against (from :class:`bentray.service.settings.Settings`)."""

    max_rays: int
    max_field_points: int
    max_memory_bytes: int
    max_field_deposits: float
    max_ray_steps: float
    threads: int
    max_mesh_seconds: float = 600.0  # bentray.scenes.cost.DEFAULT_MESH_SECONDS


# ---------------------------------------------------------------------------------------------
# The stages (run in the helper; importable and callable in-process too)
# ---------------------------------------------------------------------------------------------
def _error(lines: list[str], code: str) -> dict[str, Any]:
    return {"ok": False, "lines": lines, "code": code}


def _file_refs(value: Any, loc: tuple[str | int, ...] = ()) -> list[tuple[str, str]]:
    """(field path, name) of every input file a job names (``file`` / ``path`` keys, any depth)."""
    out: list[tuple[str, str]] = []
    stack: list[tuple[Any, tuple[str | int, ...]]] = [(value, loc)]
    while stack:
        item, where = stack.pop()
        if isinstance(item, dict):
            for key, sub in reversed(list(item.items())):
                if key in ("file", "path") and isinstance(sub, str):
                    out.append((".".join(str(p) for p in (*where, key)), sub))
                else:
                    stack.append((sub, (*where, key)))
        elif isinstance(item, list):
            stack.extend((sub, (*where, i)) for i, sub in reversed(list(enumerate(item))))
    return out


def check_job_text(text: str, limits: JobLimits) -> dict[str, Any]:
    """Stage 1: parse and validate; ``{"ok": True, "name", "refs": [(field, name)], "n_rays", "mesh_known"}``
    or an error. ``mesh_known`` False: the mesh-time estimate needs the job's files (stage 2 makes it)."""
    from pydantic import ValidationError

    from bentray.scenes.cost import CostLimits, cost_problems, estimate_mesh
    from bentray.scenes.schema import JobFileError, format_validation_error, parse_job_text

    try:
        job = parse_job_text(text, origin="job")
    except ValidationError as exc:
        return _error(format_validation_error(exc).splitlines(), "invalid_job")
    except JobFileError as exc:
        line = " ".join(str(exc).split())
        return _error([line if line.startswith("job: ") else f"job: {line}"], "invalid_json")
    lines: list[str] = []
    if job.n_rays > limits.max_rays:
        lines.append(
            f"rays: {job.n_rays:,} rays (sources x elevations x azimuths) exceed this server's limit "
            f"of {limits.max_rays:,} rays per job"
        )
    if job.field is not None and job.field.n_points > limits.max_field_points:
        lines.append(
            f"field.shape: {job.field.n_points:,} field points exceed this server's limit of "
            f"{limits.max_field_points:,}"
        )
    if not lines:
        lines = cost_problems(
            job,
            CostLimits(
                memory_bytes=limits.max_memory_bytes,
                field_deposits=limits.max_field_deposits,
                ray_steps=limits.max_ray_steps,
                threads=limits.threads,
                mesh_seconds=limits.max_mesh_seconds,
            ),
        )
    if lines:
        return _error(lines, "over_limit")
    refs = _file_refs(job.model_dump(mode="json", exclude_none=True))
    known = estimate_mesh(job).known
    return {"ok": True, "name": job.name, "refs": refs, "n_rays": job.n_rays, "mesh_known": known}


def check_job_scene(
    text: str, inputs: str, uploads: list[tuple[str, str, str]], mesh_seconds: float | None = None
) -> dict[str, Any]:
    """Stage 2: each uploaded (field, name, kind) read as its kind, then the scene checks with files
    in ``inputs``, then (``mesh_seconds`` given) the mesh-time estimate with those files;
    ``{"ok": True}`` or an error (``invalid_file`` / ``invalid_job`` / ``over_limit``)."""
    from bentray.scenes.cost import CostLimits, mesh_problems
    from bentray.scenes.job_checks import scene_problems
    from bentray.scenes.schema import parse_job_text
    from bentray.service.uploads import check_upload

    lines: list[str] = []
    for field, name, kind in uploads:
        try:
            check_upload(Path(inputs) / name, kind)  # type: ignore[arg-type]
        except ValueError as exc:
            lines.append(f"{field}: {name}: {exc}")
    if lines:
        return _error(lines, "invalid_file")
    job = parse_job_text(text, origin="job")
    problems = scene_problems(job, inputs)
    problems = [_strip_folder(line, inputs) for line in problems]
    if problems:
        return _error(problems, "invalid_job")
    if mesh_seconds is not None:
        over = mesh_problems(job, CostLimits(mesh_seconds=mesh_seconds), inputs)
        if over:
            return _error([_strip_folder(line, inputs) for line in over], "over_limit")
    return {"ok": True}


def check_upload_file(path: str, kind: str) -> dict[str, Any]:
    """An asset upload read as ``kind``: ``{"ok": True, "kind": accepted kind}`` or an ``invalid_file`` error."""
    from bentray.service.uploads import check_upload

    try:
        return {"ok": True, "kind": check_upload(Path(path), kind)}  # type: ignore[arg-type]
    except ValueError as exc:
        return _error([f"file: {Path(path).name}: {exc}"], "invalid_file")
    except RecursionError:
        return _error([f"file: {Path(path).name}: the file nests too deeply"], "invalid_file")


def _strip_folder(line: str, folder: str) -> str:
    """No server-side path in an answer: readers prefix messages with the file's path."""
    return line.replace(str(Path(folder)) + "/", "")


_STAGES: dict[str, Callable[..., dict[str, Any]]] = {
    "text": check_job_text,
    "scene": check_job_scene,
    "upload": check_upload_file,
}


def _serve(conn: Connection) -> None:
    """Helper-process loop: (stage, args) in, result dict out; every failure is an answer."""
    import os

    with contextlib.suppress(OSError):
        os.nice(5)
    with contextlib.suppress(Exception):  # the imports and first calls of the stages, before any time limit
        import bentray.scenes.job_checks  # noqa: F401
        import bentray.service.uploads  # noqa: F401

        warm = JobLimits(2_000_000, 5_000_000, 2**33, 2e10, 5e10, 1)
        check_job_text(_WARM_JOB, warm)
        check_job_scene(_WARM_JOB, os.getcwd(), [], 600.0)
    try:
        conn.send(_READY)
    except (OSError, ValueError):
        return
    while True:
        try:
            stage, args = conn.recv()
        except (EOFError, OSError):
            return
        try:
            result = _STAGES[stage](*args)
        except RecursionError:
            result = _error(["job: the job nests too deeply"], "invalid_job")
        except Exception as exc:  # a bug or an unexpected reader failure: still an answer, never a hang
            why = " ".join(str(exc).split())[:500]
            result = _error([f"job: cannot validate the job ({type(exc).__name__}: {why})"], "invalid_job")
        try:
            conn.send(result)
        except (OSError, ValueError):
            return


# ---------------------------------------------------------------------------------------------
# The pool
# ---------------------------------------------------------------------------------------------
class _Helper:
    def __init__(self, ctx: Any) -> None:
        parent, child = ctx.Pipe()
        self.conn: Connection = parent
        self.process: BaseProcess = ctx.Process(target=_serve, args=(child,), name="bentray-validate", daemon=True)
        self.process.start()
        child.close()
        self.ready = False  # True once the helper said it finished its imports

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for the helper's ready message; False if it did not come."""
        if not self.ready:
            if not self.conn.poll(timeout_s):
                return False
            self.ready = self.conn.recv() == _READY
        return self.ready

    def kill(self) -> None:
        with contextlib.suppress(Exception):
            self.process.kill()
            self.process.join(2.0)
        with contextlib.suppress(Exception):
            self.conn.close()


class ValidationPool:
    """``size`` helper processes; :meth:`run` sends one stage to an idle one and waits ``timeout_s``."""

    def __init__(self, timeout_s: float, size: int = 2) -> None:
        self.timeout_s = float(timeout_s)
        self._ctx = multiprocessing.get_context("spawn")
        self._idle: list[_Helper] = []
        self._count = 0
        self._size = max(int(size), 1)
        self._cond = threading.Condition()
        self._closed = False

    def start(self) -> None:
        """Start one helper now (its imports take a second) so the first request does not wait for it."""
        with self._cond:
            if not self._closed and self._count == 0:
                self._idle.append(_Helper(self._ctx))
                self._count += 1

    def _take(self, deadline: float) -> _Helper:
        with self._cond:
            while True:
                if self._closed:
                    raise RuntimeError("the validation pool is closed")
                if self._idle:
                    return self._idle.pop()
                if self._count < self._size:
                    self._count += 1
                    break
                left = deadline - time.monotonic()
                if left <= 0:
                    raise ValidationBusy("every validation helper is busy")
                self._cond.wait(left)
        try:
            return _Helper(self._ctx)
        except BaseException:
            with self._cond:
                self._count -= 1
                self._cond.notify()
            raise

    def _give_back(self, helper: _Helper | None) -> None:
        with self._cond:
            if helper is not None and not self._closed:
                self._idle.append(helper)
            else:
                self._count -= 1
                if helper is not None:
                    helper.kill()
            self._cond.notify()

    def run(self, stage: str, *args: Any) -> dict[str, Any]:
        """The stage's result dict; :class:`ValidationTimeout` when no answer came within the limit."""
        deadline = time.monotonic() + self.timeout_s
        helper = self._take(deadline + self.timeout_s)  # waiting for a free helper has its own allowance
        deadline = max(deadline, time.monotonic() + 0.5 * self.timeout_s)
        try:
            if not helper.ready:  # a new helper: its start-up has its own allowance, then the limit runs
                if not helper.wait_ready(HELPER_START_S):
                    helper.kill()
                    self._give_back(None)
                    raise ValidationBusy(f"a validation helper did not start within {HELPER_START_S:g} s")
                deadline = time.monotonic() + self.timeout_s
            helper.conn.send((stage, args))
            if not helper.conn.poll(max(deadline - time.monotonic(), 0.0)):
                raise ValidationTimeout(f"validation took longer than {self.timeout_s:g} s")
            result: dict[str, Any] = helper.conn.recv()
        except ValidationTimeout:
            helper.kill()
            self._give_back(None)
            raise
        except (EOFError, OSError, BrokenPipeError) as exc:  # the helper died (out of memory?)
            helper.kill()
            self._give_back(None)
            return _error(
                [f"job: the validation process stopped ({type(exc).__name__}); the job is refused"], "invalid_job"
            )
        self._give_back(helper)
        return result

    def close(self) -> None:
        with self._cond:
            self._closed = True
            idle, self._idle = self._idle, []
            self._count -= len(idle)
            self._cond.notify_all()
        for helper in idle:
            helper.kill()

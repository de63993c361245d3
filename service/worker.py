"""Job processes and the supervisor that starts, watches, cancels and recovers them.

Each attempt of a job runs in its own child *process* (multiprocessing ``spawn`` context: the engine
holds the CPU and numba's threads, so never a thread of the API). The child parses the stored job
JSON, calls :func:`bentray.engine.run.run_job` (ray batches local, or on Dask when the settings name a
scheduler: ``BENTRAY_DASK_SCHEDULER``) with a progress callback that writes stage and
fraction to the store, and writes the result files with ``write_outcome``. Cancel = terminate that
child (SIGTERM, then SIGKILL after :data:`TERMINATE_GRACE_S`).

The :class:`Supervisor` loop runs in ``bentray serve`` (a thread, ``--workers N`` children at most) or
alone (``python -m bentray.service worker``, e.g. a separate container on the same data volume). It:
- claims queued jobs while fewer than N children run;
- notices cancel requests, the per-attempt run-time limit and children that died without finishing
  (exit code / signal): such a job is queued again once, then failed with the reason;
- on start and every few seconds, recovers ``running`` jobs of supervisors that are gone (a server
  killed mid-job): queued again once, then failed with the reason;
- deletes finished jobs and assets older than the retention time.
Children die with their supervisor (Linux ``PR_SET_PDEATHSIG`` plus a parent watch thread), so a
killed server never leaves an orphan writing results for an attempt that was already recovered.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import shutil
import signal
import socket
import sys
import threading
import time
import traceback
import uuid
from dataclasses import dataclass
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

from bentray.service.layout import DataLayout
from bentray.service.settings import Settings
from bentray.service.store import JobRecord, JobStatus, JobStore

__all__ = ["Supervisor", "run_attempt"]

log = logging.getLogger("bentray.service")

TERMINATE_GRACE_S = 2.0  # SIGTERM -> SIGKILL delay when cancelling a child
HEARTBEAT_S = 1.0  # supervisor heartbeat period
STALE_SUPERVISOR_S = 15.0  # a supervisor silent this long is gone (other hosts; same host checks its pid)
RECOVERY_PERIOD_S = 2.0  # how often orphaned running jobs are looked for
CLEANUP_PERIOD_S = 60.0  # how often expired jobs and assets are deleted (at most half the retention time)
PROGRESS_PERIOD_S = 0.25  # a child writes progress at most this often (plus every stage change)
_ERROR_TEXT_CHARS = 4000  # a job's error text is cut to this length


# ---------------------------------------------------------------------------------------------
# The child process
# ---------------------------------------------------------------------------------------------
def _die_with_parent(parent_pid: int) -> None:
    """Exit when the supervisor process goes away (SIGKILL of the server included)."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent_pid:  # died before prctl took effect
        os._exit(1)

    def watch() -> None:  # portable fallback; runs whenever the engine releases the GIL
        while True:
            time.sleep(0.5)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


class Terminated(BaseException):
    """SIGTERM in a job process (not an Exception: the attempt is not recorded as failed)."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise Terminated(f"signal {signum}")


def remove_staging(job_dir: Path) -> int:
    """Remove the writers' staging folders (``.results.*.tmp``) in a job folder; how many were removed."""
    count = 0
    for tmp in job_dir.glob(".results.*.tmp"):
        shutil.rmtree(tmp, ignore_errors=True)
        count += 1
    return count


def _error_text(exc: BaseException) -> str:
    message = " ".join(str(exc).split()) or type(exc).__name__
    return f"{type(exc).__name__}: {message}"[:_ERROR_TEXT_CHARS]


def _float_timings(report: dict[str, Any]) -> dict[str, float]:
    out = {}
    for stage, seconds in (report.get("timings_s") or {}).items():
        with contextlib.suppress(TypeError, ValueError):
            out[str(stage)] = float(seconds)
    return out


def run_attempt(
    db_path: str,
    job_id: str,
    attempt: int,
    inputs: str,
    results: str,
    threads: int,
    nice: int,
    parent_pid: int,
    dask_scheduler: str | None = None,
) -> None:
    """Child-process entry: run one attempt of a job and record its outcome in the store.

    Expected failures (bentray's typed errors, bad inputs, I/O) end the job ``failed`` with their text;
    anything else too, with the last traceback line. Writes are guarded by ``attempt``.
    """
    _die_with_parent(parent_pid)
    # SIGTERM (cancel, server stop) unwinds like an exception, so staging folders are removed on the way out
    signal.signal(signal.SIGTERM, _raise_terminated)
    if nice:
        with contextlib.suppress(OSError):
            os.nice(nice)
    store = JobStore(db_path)
    record = store.get(job_id)
    if record is None or record.status is not JobStatus.RUNNING or record.attempts != attempt:
        return
    last_time = [0.0]
    last_stage = [""]

    def progress(stage: str, fraction: float) -> None:
        now = time.monotonic()
        if stage != last_stage[0] or now - last_time[0] >= PROGRESS_PERIOD_S:
            last_time[0], last_stage[0] = now, stage
            store.set_progress(job_id, attempt, stage, 0.98 * fraction)  # the last 2 %: writing files

    preview = None  # preview.png's drawing process (engine/preview_process.py), for jobs with a field
    try:
        import inspect

        import numba

        from bentray.engine.executors import make_executor
        from bentray.engine.preview_process import PreviewWorker
        from bentray.engine.run import run_job
        from bentray.engine.writers import write_outcome
        from bentray.scenes.schema import parse_job_text

        available = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
        numba.set_num_threads(max(1, min(threads, available)))
        job = parse_job_text(record.job_json, origin=f"job {job_id}")
        if "field" in job.outputs:  # it loads matplotlib while the job runs (it inherits the nice level)
            preview = PreviewWorker.start()
        kwargs: dict[str, Any] = {"executor": make_executor(dask_scheduler)}
        if "progress" in inspect.signature(run_job).parameters:
            kwargs["progress"] = progress
        outcome = run_job(job, Path(inputs), **kwargs)
        store.set_progress(job_id, attempt, "writing", 0.98)
        remove_staging(Path(results).parent)  # an earlier attempt killed while writing
        written = write_outcome(outcome, list(job.outputs), Path(results), preview_worker=preview)
        store.finish(
            job_id,
            attempt,
            JobStatus.SUCCEEDED,
            files=[p.name for p in written],
            timings=_float_timings(outcome.report),
        )
    except Exception as exc:  # every failure ends the job with its reason; the process exits cleanly
        log.debug("job %s failed:\n%s", job_id, traceback.format_exc())
        store.finish(job_id, attempt, JobStatus.FAILED, error=_error_text(exc))
    finally:
        if preview is not None:  # a job that failed or was cancelled before its outputs: stop the child
            preview.close()
        remove_staging(Path(results).parent)
        store.close()


# ---------------------------------------------------------------------------------------------
# The supervisor
# ---------------------------------------------------------------------------------------------
@dataclass
class _Active:
    record: JobRecord
    process: BaseProcess
    started: float


def _exit_reason(exitcode: int | None) -> str:
    if exitcode is not None and exitcode < 0:
        try:
            name = signal.Signals(-exitcode).name
        except ValueError:
            name = f"signal {-exitcode}"
        return f"the job process was killed by {name}" + (" (out of memory?)" if name == "SIGKILL" else "")
    return f"the job process exited with code {exitcode} without recording a result"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class Supervisor:
    """Starts and watches job processes; see the module docstring. ``start()`` runs it in a thread."""

    def __init__(self, settings: Settings, store: JobStore | None = None) -> None:
        self.settings = settings
        self.layout = DataLayout(settings.data_dir)
        self.store = store or JobStore(settings.db_path)
        self.id = uuid.uuid4().hex
        self.host = socket.gethostname()
        self._ctx = multiprocessing.get_context("spawn")
        self._active: dict[str, _Active] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._threads_per_job = settings.threads_per_job
        self._next_heartbeat = 0.0
        self._next_recovery = 0.0
        self._next_cleanup = 0.0

    # -- life cycle ----------------------------------------------------------------------------
    def start(self) -> None:
        """Register, recover orphaned jobs and run the loop in a daemon thread."""
        self.store.register_supervisor(self.id, self.host, os.getpid())
        self.recover_orphans()
        self.remove_stale_staging()
        self._thread = threading.Thread(target=self._run_thread, name="bentray-supervisor", daemon=True)
        self._thread.start()

    def run_forever(self) -> None:
        """Run the loop in this thread until SIGTERM/SIGINT (standalone worker)."""
        self.store.register_supervisor(self.id, self.host, os.getpid())
        self.recover_orphans()
        self.remove_stale_staging()
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda *_: self._stop.set())
        try:
            self._loop()
        finally:
            self._shutdown()

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the loop; running children are terminated and their jobs queued again (no attempt used)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run_thread(self) -> None:
        try:
            self._loop()
        except Exception:  # keep a record; the health endpoint reports the dead supervisor
            log.exception("supervisor loop crashed")
        finally:
            self._shutdown()

    def _loop(self) -> None:
        while not self._stop.is_set():
            self.tick()
            self._stop.wait(self.settings.poll_seconds)

    def _shutdown(self) -> None:
        for job_id, active in list(self._active.items()):
            self._terminate(active.process)
            self.store.release(job_id, active.record.attempts)
            self._active.pop(job_id, None)
        with contextlib.suppress(Exception):
            self.store.unregister_supervisor(self.id)
        self.store.close()

    # -- one iteration -------------------------------------------------------------------------
    def tick(self) -> None:
        now = time.time()
        if now >= self._next_heartbeat:
            self.store.heartbeat(self.id)
            self._next_heartbeat = now + HEARTBEAT_S
        if now >= self._next_recovery:
            self.recover_orphans()
            self._next_recovery = now + RECOVERY_PERIOD_S
        if now >= self._next_cleanup:
            self.cleanup()
            self._next_cleanup = now + min(CLEANUP_PERIOD_S, 0.5 * 86400.0 * self.settings.retention_days)
        self._watch_children()
        while len(self._active) < self.settings.workers and not self._stop.is_set():
            record = self.store.claim_next(self.id)
            if record is None:
                break
            self._spawn(record)

    def _spawn(self, record: JobRecord) -> None:
        inputs = self.layout.inputs(record.id)
        results = self.layout.results(record.id)
        inputs.mkdir(parents=True, exist_ok=True)
        args = (
            str(self.store.path),
            record.id,
            record.attempts,
            str(inputs),
            str(results),
            self._threads_per_job,
            self.settings.worker_nice,
            os.getpid(),
            self.settings.dask_scheduler,
        )
        process = self._ctx.Process(target=run_attempt, args=args, name=f"bentray-job-{record.id[:8]}", daemon=False)
        process.start()
        self.store.set_pid(record.id, record.attempts, process.pid)
        self._active[record.id] = _Active(record, process, time.monotonic())
        log.info("job %s attempt %d started (pid %s)", record.id, record.attempts, process.pid)

    def _terminate(self, process: BaseProcess) -> None:
        if process.is_alive():
            process.terminate()
            process.join(TERMINATE_GRACE_S)
            if process.is_alive():
                process.kill()
        process.join(TERMINATE_GRACE_S)

    def _watch_children(self) -> None:
        for job_id, active in list(self._active.items()):
            attempt = active.record.attempts
            current = self.store.get(job_id)
            if current is None or current.attempts != attempt or current.status is not JobStatus.RUNNING:
                exiting = (
                    current is not None
                    and current.attempts == attempt
                    and current.finished
                    and current.finished_at is not None
                    and time.time() - current.finished_at < 10.0
                )
                if exiting and active.process.is_alive():
                    continue  # the child recorded its result and is closing down
                self._terminate(active.process)
                self._active.pop(job_id)
                continue
            if current.cancel_requested:
                self._terminate(active.process)
                self.store.finish(job_id, attempt, JobStatus.CANCELLED)
                self._active.pop(job_id)
                log.info("job %s cancelled", job_id)
            elif time.monotonic() - active.started > self.settings.max_job_seconds:
                self._terminate(active.process)
                self.store.finish(
                    job_id,
                    attempt,
                    JobStatus.FAILED,
                    error=f"the job ran longer than this server's limit of "
                    f"{self.settings.max_job_seconds:g} s and was stopped",
                )
                self._active.pop(job_id)
            elif not active.process.is_alive():
                active.process.join()
                new = self.store.requeue_or_fail(
                    job_id, attempt, _exit_reason(active.process.exitcode), self.settings.max_attempts
                )
                remove_staging(self.layout.job_dir(job_id))  # no process of this job runs now
                log.warning(
                    "job %s attempt %d: process died (exit %s) -> %s", job_id, attempt, active.process.exitcode, new
                )
                self._active.pop(job_id)

    def _supervisor_gone(self, sup: dict[str, Any], now: float) -> bool:
        if sup["id"] == self.id:
            return False
        if sup["host"] == self.host and (sup["pid"] == os.getpid() or not _pid_alive(sup["pid"])):
            return True
        return bool(now - sup["heartbeat"] > STALE_SUPERVISOR_S)

    def recover_orphans(self) -> None:
        """Queue again (once) or fail the running jobs of supervisors that are gone."""
        now = time.time()
        sups = {s["id"]: s for s in self.store.supervisors()}
        gone = {sid for sid, s in sups.items() if self._supervisor_gone(s, now)}
        for record in self.store.running_of_other_supervisors(self.id):
            if record.supervisor is None or record.supervisor in gone or record.supervisor not in sups:
                new = self.store.requeue_or_fail(
                    record.id,
                    record.attempts,
                    "the server stopped while the job was running",
                    self.settings.max_attempts,
                )
                log.warning("job %s: orphaned attempt %d recovered -> %s", record.id, record.attempts, new)
        for sid in gone:
            self.store.unregister_supervisor(sid)

    def remove_stale_staging(self) -> int:
        """Remove result staging folders of jobs that are not running (left by a kill during the write)."""
        count = 0
        for job_dir in (self.settings.data_dir / "jobs").glob("*"):
            if not any(job_dir.glob(".results.*.tmp")):
                continue
            record = self.store.get(job_dir.name)
            if record is None or record.status is not JobStatus.RUNNING:
                count += remove_staging(job_dir)
        return count

    def cleanup(self) -> None:
        """Delete finished jobs (rows and files) and assets older than the retention time."""
        before = time.time() - self.settings.retention_days * 86400.0
        for record in self.store.expired(before):
            self.layout.remove_job_files(record.id)
            self.store.delete(record.id)
        for asset in self.store.expired_assets(before):
            with contextlib.suppress(OSError, ValueError):
                self.layout.asset_path(asset.owner, asset.name).unlink(missing_ok=True)
            self.store.delete_asset(asset.owner, asset.name)

"""The persistent job store: one SQLite database in WAL mode under ``BENTRAY_DATA_DIR``.

Queue semantics (every transition is one SQL transaction, so API, supervisor and job processes
can share the file safely):

    queued --claim--> running --finish--> succeeded | failed | cancelled
    queued --cancel--> cancelled
    running --worker died / server stopped--> queued (attempts < max_attempts) or failed (with reason)

``attempts`` counts how often a job was claimed. Writes from a job process name the attempt they
belong to, so a process of an abandoned attempt can never overwrite a newer one. Supervisors (the
loops that start job processes) register with a heartbeat; running jobs of a supervisor that is gone
are recovered by the next one (see :meth:`JobStore.recover_orphans`).

Owners are hashes of API keys (:func:`bentray.service.settings.owner_of_key`), never keys. Job
payloads are the job JSON text (never pickle). Times are Unix seconds (float, UTC).
"""

from __future__ import annotations

import builtins
import enum
import json
import sqlite3
import threading
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["FINISHED", "AssetRecord", "JobRecord", "JobStatus", "JobStore", "QueueFull", "new_job_id"]

_BUSY_TIMEOUT_S = 30.0  # writers wait this long for the database lock (transactions are milliseconds)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    owner TEXT NOT NULL,
    name TEXT NOT NULL,
    status TEXT NOT NULL,
    stage TEXT NOT NULL DEFAULT '',
    progress REAL NOT NULL DEFAULT 0,
    created_at REAL NOT NULL,
    started_at REAL,
    finished_at REAL,
    updated_at REAL NOT NULL,
    error TEXT,
    attempts INTEGER NOT NULL DEFAULT 0,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    supervisor TEXT,
    worker_pid INTEGER,
    job_json TEXT NOT NULL,
    files TEXT NOT NULL DEFAULT '[]',
    timings TEXT NOT NULL DEFAULT '{}'
);
CREATE INDEX IF NOT EXISTS jobs_status ON jobs (status);
CREATE INDEX IF NOT EXISTS jobs_owner ON jobs (owner);
CREATE TABLE IF NOT EXISTS supervisors (
    id TEXT PRIMARY KEY,
    host TEXT NOT NULL,
    pid INTEGER NOT NULL,
    started_at REAL NOT NULL,
    heartbeat REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS assets (
    owner TEXT NOT NULL,
    name TEXT NOT NULL,
    size INTEGER NOT NULL,
    sha256 TEXT NOT NULL,
    kind TEXT NOT NULL,
    created_at REAL NOT NULL,
    PRIMARY KEY (owner, name)
);
"""


class JobStatus(enum.StrEnum):
    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"


FINISHED = (JobStatus.SUCCEEDED, JobStatus.FAILED, JobStatus.CANCELLED)


class QueueFull(Exception):
    """``max_queue`` jobs are already queued."""


def new_job_id() -> str:
    """32 lowercase hex characters (uuid4): safe as a folder name and unguessable."""
    return uuid.uuid4().hex


@dataclass(frozen=True)
class JobRecord:
    """One row of ``jobs``; ``files`` are the result file names, ``timings`` stage -> seconds."""

    id: str
    owner: str
    name: str
    status: JobStatus
    stage: str
    progress: float
    created_at: float
    started_at: float | None
    finished_at: float | None
    updated_at: float
    error: str | None
    attempts: int
    cancel_requested: bool
    supervisor: str | None
    worker_pid: int | None
    job_json: str
    files: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)

    @classmethod
    def from_row(cls, row: sqlite3.Row) -> JobRecord:
        data: dict[str, Any] = dict(row)
        data["status"] = JobStatus(data["status"])
        data["cancel_requested"] = bool(data["cancel_requested"])
        data["files"] = json.loads(data["files"])
        data["timings"] = json.loads(data["timings"])
        return cls(**data)

    @property
    def finished(self) -> bool:
        return self.status in FINISHED


@dataclass(frozen=True)
class AssetRecord:
    owner: str
    name: str
    size: int
    sha256: str
    kind: str
    created_at: float


class JobStore:
    """Thread-safe access to the store (one connection per thread; every method is one transaction)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._local = threading.local()
        self._connection().executescript(_SCHEMA)  # executescript commits by itself

    # -- connections ---------------------------------------------------------------------------
    def _connection(self) -> sqlite3.Connection:
        con = getattr(self._local, "con", None)
        if con is None:
            con = sqlite3.connect(self.path, timeout=_BUSY_TIMEOUT_S, isolation_level=None)
            con.row_factory = sqlite3.Row
            con.execute("PRAGMA journal_mode=WAL")
            con.execute("PRAGMA synchronous=NORMAL")  # WAL + NORMAL: durable across process crashes
            con.execute("PRAGMA foreign_keys=ON")
            self._local.con = con
        return con

    @contextmanager
    def _tx(self, immediate: bool = True) -> Iterator[sqlite3.Connection]:
        con = self._connection()
        con.execute("BEGIN IMMEDIATE" if immediate else "BEGIN")
        try:
            yield con
        except BaseException:
            con.execute("ROLLBACK")
            raise
        con.execute("COMMIT")

    def close(self) -> None:
        con = getattr(self._local, "con", None)
        if con is not None:
            con.close()
            self._local.con = None

    # -- jobs ----------------------------------------------------------------------------------
    def create_job(self, job_id: str, owner: str, name: str, job_json: str, max_queue: int) -> JobRecord:
        """Insert a queued job; raises :class:`QueueFull` when ``max_queue`` jobs are queued already."""
        now = time.time()
        with self._tx() as con:
            (queued,) = con.execute("SELECT COUNT(*) FROM jobs WHERE status = 'queued'").fetchone()
            if queued >= max_queue:
                raise QueueFull(f"{queued} jobs are queued; the limit is {max_queue}")
            con.execute(
                "INSERT INTO jobs (id, owner, name, status, stage, created_at, updated_at, job_json) "
                "VALUES (?, ?, ?, 'queued', 'queued', ?, ?, ?)",
                (job_id, owner, name, now, now, job_json),
            )
        record = self.get(job_id)
        assert record is not None
        return record

    def get(self, job_id: str, owner: str | None = None) -> JobRecord | None:
        """The job, or None when unknown or (with ``owner``) owned by someone else."""
        con = self._connection()
        if owner is None:
            row = con.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        else:
            row = con.execute("SELECT * FROM jobs WHERE id = ? AND owner = ?", (job_id, owner)).fetchone()
        return JobRecord.from_row(row) if row is not None else None

    def list(
        self, owner: str | None = None, status: JobStatus | None = None, limit: int = 1000
    ) -> builtins.list[JobRecord]:
        """Jobs, newest first, optionally of one owner and/or one status."""
        where, args = [], []
        if owner is not None:
            where.append("owner = ?")
            args.append(owner)
        if status is not None:
            where.append("status = ?")
            args.append(status.value)
        sql = "SELECT * FROM jobs" + (" WHERE " + " AND ".join(where) if where else "")
        rows = self._connection().execute(sql + " ORDER BY rowid DESC LIMIT ?", (*args, limit)).fetchall()
        return [JobRecord.from_row(r) for r in rows]

    def counts(self) -> dict[str, int]:
        rows = self._connection().execute("SELECT status, COUNT(*) FROM jobs GROUP BY status").fetchall()
        out = {s.value: 0 for s in JobStatus}
        out.update({r[0]: int(r[1]) for r in rows})
        return out

    def claim_next(self, supervisor: str) -> JobRecord | None:
        """Atomically move the oldest queued job to running (attempts + 1); None if none is queued."""
        now = time.time()
        with self._tx() as con:
            row = con.execute("SELECT id FROM jobs WHERE status = 'queued' ORDER BY rowid LIMIT 1").fetchone()
            if row is None:
                return None
            con.execute(
                "UPDATE jobs SET status = 'running', attempts = attempts + 1, started_at = ?, updated_at = ?, "
                "stage = 'starting', progress = 0, error = NULL, supervisor = ?, worker_pid = NULL WHERE id = ?",
                (now, now, supervisor, row["id"]),
            )
        return self.get(row["id"])

    def set_pid(self, job_id: str, attempt: int, pid: int | None) -> None:
        with self._tx() as con:
            con.execute(
                "UPDATE jobs SET worker_pid = ? WHERE id = ? AND attempts = ? AND status = 'running'",
                (pid, job_id, attempt),
            )

    def set_progress(self, job_id: str, attempt: int, stage: str, progress: float) -> bool:
        """Record the stage and the overall fraction (clipped to 0..1); False if the attempt is stale."""
        fraction = min(max(float(progress), 0.0), 1.0)
        with self._tx() as con:
            cur = con.execute(
                "UPDATE jobs SET stage = ?, progress = ?, updated_at = ? "
                "WHERE id = ? AND attempts = ? AND status = 'running'",
                (stage, fraction, time.time(), job_id, attempt),
            )
            return cur.rowcount == 1

    def finish(
        self,
        job_id: str,
        attempt: int | None,
        status: JobStatus,
        error: str | None = None,
        files: builtins.list[str] | None = None,
        timings: dict[str, float] | None = None,
    ) -> bool:
        """Move a running job (of this attempt, if given) to a finished status; False if it was not running."""
        assert status in FINISHED
        now = time.time()
        sql = (
            "UPDATE jobs SET status = ?, error = ?, finished_at = ?, updated_at = ?, worker_pid = NULL, "
            "stage = ?, progress = CASE WHEN ? = 'succeeded' THEN 1.0 ELSE progress END"
        )
        args: builtins.list[Any] = [status.value, error, now, now, status.value, status.value]
        if files is not None:
            sql += ", files = ?"
            args.append(json.dumps(files))
        if timings is not None:
            sql += ", timings = ?"
            args.append(json.dumps(timings))
        sql += " WHERE id = ? AND status = 'running'"
        args.append(job_id)
        if attempt is not None:
            sql += " AND attempts = ?"
            args.append(attempt)
        with self._tx() as con:
            return con.execute(sql, args).rowcount == 1

    def requeue_or_fail(self, job_id: str, attempt: int, reason: str, max_attempts: int) -> JobStatus | None:
        """A running attempt was lost: queue the job again if attempts remain, else fail it with ``reason``.

        Returns the new status, or None when the job was no longer running that attempt.
        """
        now = time.time()
        with self._tx() as con:
            row = con.execute(
                "SELECT attempts, cancel_requested FROM jobs WHERE id = ? AND status = 'running' AND attempts = ?",
                (job_id, attempt),
            ).fetchone()
            if row is None:
                return None
            if row["cancel_requested"]:
                new, error = JobStatus.CANCELLED, None
            elif row["attempts"] < max_attempts:
                new, error = JobStatus.QUEUED, f"attempt {attempt} lost: {reason}; queued again"
            else:
                new, error = JobStatus.FAILED, f"{reason} (attempt {attempt} of {max_attempts}; not retried)"
            finished = None if new is JobStatus.QUEUED else now
            con.execute(
                "UPDATE jobs SET status = ?, error = ?, stage = ?, finished_at = ?, updated_at = ?, "
                "worker_pid = NULL, supervisor = NULL WHERE id = ?",
                (new.value, error, new.value, finished, now, job_id),
            )
            return new

    def release(self, job_id: str, attempt: int) -> bool:
        """Give a running attempt back to the queue without using it up (graceful server shutdown)."""
        with self._tx() as con:
            cur = con.execute(
                "UPDATE jobs SET status = CASE WHEN cancel_requested THEN 'cancelled' ELSE 'queued' END, "
                "stage = CASE WHEN cancel_requested THEN 'cancelled' ELSE 'queued' END, "
                "attempts = attempts - 1, worker_pid = NULL, supervisor = NULL, updated_at = ?, "
                "finished_at = CASE WHEN cancel_requested THEN ? ELSE NULL END "
                "WHERE id = ? AND status = 'running' AND attempts = ?",
                (time.time(), time.time(), job_id, attempt),
            )
            return cur.rowcount == 1

    def request_cancel(self, job_id: str) -> JobRecord | None:
        """Cancel a queued job at once; flag a running one (its supervisor ends the process)."""
        now = time.time()
        with self._tx() as con:
            con.execute(
                "UPDATE jobs SET status = 'cancelled', stage = 'cancelled', finished_at = ?, updated_at = ? "
                "WHERE id = ? AND status = 'queued'",
                (now, now, job_id),
            )
            con.execute(
                "UPDATE jobs SET cancel_requested = 1, updated_at = ? WHERE id = ? AND status = 'running'",
                (now, job_id),
            )
        return self.get(job_id)

    def delete(self, job_id: str) -> bool:
        with self._tx() as con:
            return con.execute("DELETE FROM jobs WHERE id = ?", (job_id,)).rowcount == 1

    def expired(self, before: float) -> builtins.list[JobRecord]:
        """Finished jobs whose ``finished_at`` is older than ``before``."""
        rows = (
            self._connection()
            .execute(
                "SELECT * FROM jobs WHERE status IN ('succeeded', 'failed', 'cancelled') AND finished_at < ?", (before,)
            )
            .fetchall()
        )
        return [JobRecord.from_row(r) for r in rows]

    # -- supervisors ---------------------------------------------------------------------------
    def register_supervisor(self, supervisor: str, host: str, pid: int) -> None:
        now = time.time()
        with self._tx() as con:
            con.execute(
                "INSERT OR REPLACE INTO supervisors (id, host, pid, started_at, heartbeat) VALUES (?, ?, ?, ?, ?)",
                (supervisor, host, pid, now, now),
            )

    def heartbeat(self, supervisor: str) -> None:
        with self._tx() as con:
            con.execute("UPDATE supervisors SET heartbeat = ? WHERE id = ?", (time.time(), supervisor))

    def unregister_supervisor(self, supervisor: str) -> None:
        with self._tx() as con:
            con.execute("DELETE FROM supervisors WHERE id = ?", (supervisor,))

    def supervisors(self) -> builtins.list[dict[str, Any]]:
        return [dict(r) for r in self._connection().execute("SELECT * FROM supervisors").fetchall()]

    def running_of_other_supervisors(self, supervisor: str) -> builtins.list[JobRecord]:
        rows = (
            self._connection()
            .execute(
                "SELECT * FROM jobs WHERE status = 'running' AND (supervisor IS NULL OR supervisor != ?)", (supervisor,)
            )
            .fetchall()
        )
        return [JobRecord.from_row(r) for r in rows]

    # -- assets --------------------------------------------------------------------------------
    def put_asset(self, owner: str, name: str, size: int, sha256: str, kind: str) -> AssetRecord:
        now = time.time()
        with self._tx() as con:
            con.execute(
                "INSERT OR REPLACE INTO assets (owner, name, size, sha256, kind, created_at) VALUES (?, ?, ?, ?, ?, ?)",
                (owner, name, size, sha256, kind, now),
            )
        return AssetRecord(owner, name, size, sha256, kind, now)

    def get_asset(self, owner: str, name: str) -> AssetRecord | None:
        row = self._connection().execute("SELECT * FROM assets WHERE owner = ? AND name = ?", (owner, name)).fetchone()
        return AssetRecord(**dict(row)) if row is not None else None

    def list_assets(self, owner: str) -> builtins.list[AssetRecord]:
        rows = self._connection().execute("SELECT * FROM assets WHERE owner = ? ORDER BY name", (owner,)).fetchall()
        return [AssetRecord(**dict(r)) for r in rows]

    def delete_asset(self, owner: str, name: str) -> bool:
        with self._tx() as con:
            return con.execute("DELETE FROM assets WHERE owner = ? AND name = ?", (owner, name)).rowcount == 1

    def expired_assets(self, before: float) -> builtins.list[AssetRecord]:
        rows = self._connection().execute("SELECT * FROM assets WHERE created_at < ?", (before,)).fetchall()
        return [AssetRecord(**dict(r)) for r in rows]

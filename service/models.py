"""Public API models (pydantic v2): what the service returns and the Python client reads.

Times are Unix seconds (UTC); ``progress`` is the overall fraction 0..1 of the current attempt.
The request body of ``POST /v1/jobs`` is the job itself (:class:`bentray.scenes.schema.Job`).
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict

__all__ = ["AssetInfo", "ErrorBody", "Health", "JobInfo", "JobList", "JobState", "SceneInfo"]

JobState = str  # one of queued, running, succeeded, failed, cancelled (bentray.service.store.JobStatus)


class _Model(BaseModel):
    model_config = ConfigDict(extra="ignore")  # clients tolerate fields added by newer servers


class JobInfo(_Model):
    id: str
    name: str
    status: JobState
    stage: str
    progress: float
    created_at: float
    started_at: float | None = None
    finished_at: float | None = None
    error: str | None = None
    attempts: int = 0
    cancel_requested: bool = False
    results: list[str] = []
    timings_s: dict[str, float] = {}
    links: dict[str, str] = {}

    @property
    def finished(self) -> bool:
        return self.status in ("succeeded", "failed", "cancelled")


class JobList(_Model):
    jobs: list[JobInfo]


class AssetInfo(_Model):
    name: str
    kind: str
    size: int
    sha256: str
    created_at: float


class SceneInfo(_Model):
    name: str
    resolution: str
    domain_m: str
    triangles: int
    buildings: int
    sources: int
    profile: str
    description: str


class Health(_Model):
    status: str
    version: str
    workers: int
    supervisor: str
    auth: str


class ErrorBody(_Model):
    error: str
    detail: str
    errors: list[dict[str, Any]] = []

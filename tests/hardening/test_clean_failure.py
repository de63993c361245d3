"""Issue 15: validation that cannot hang (a helper process under a time limit) and temporary folders
removed on every exit path and on restart."""

from __future__ import annotations

import json
import os
import time

import pytest

from bentray.service.validation import JobLimits, ValidationPool, ValidationTimeout
from tests.hardening.conftest import base_job

LIMITS = JobLimits(
    max_rays=2_000_000,
    max_field_points=5_000_000,
    max_memory_bytes=2**33,
    max_field_deposits=2e10,
    max_ray_steps=5e10,
    threads=2,
)


def test_validation_over_its_time_limit_is_killed_and_the_pool_recovers():
    pool = ValidationPool(timeout_s=30.0, size=1)
    try:
        text = json.dumps(base_job())
        assert pool.run("text", text, LIMITS)["ok"]  # warm: the helper's imports are done
        helper = pool._idle[0]
        pool.timeout_s = 1e-4  # a 100,000-row table takes tens of ms: the helper is killed, the request refused
        big = base_job()
        big["profile"] = {"kind": "table", "z": list(range(100_000)), "c": [340.0] * 100_000}
        t0 = time.perf_counter()
        with pytest.raises(ValidationTimeout, match="validation took longer than 0.0001 s"):
            pool.run("text", json.dumps(big), LIMITS)
        assert time.perf_counter() - t0 < 10.0  # the kill waits up to 2 s for the helper to go
        helper.process.join(10.0)
        assert not helper.process.is_alive()
        pool.timeout_s = 60.0
        result = pool.run("text", "{", LIMITS)  # a fresh helper answers
        assert result == {
            "ok": False,
            "lines": ["job: invalid JSON at line 1, column 2: Expecting property name enclosed in double quotes"],
            "code": "invalid_json",
        }
    finally:
        pool.close()


def test_result_staging_left_by_a_killed_attempt_is_removed(tmp_path):
    from bentray.service.settings import Settings
    from bentray.service.store import JobStatus, JobStore
    from bentray.service.worker import Supervisor, remove_staging

    settings = Settings(data_dir=tmp_path, workers=1)
    store = JobStore(settings.db_path)
    job_ids = ["a" * 32, "b" * 32]
    for job_id in job_ids:
        store.create_job(job_id, "local", job_id[:4], json.dumps(base_job()), 10)
        staging = tmp_path / "jobs" / job_id / ".results.x1y2.tmp"
        staging.mkdir(parents=True)
        (staging / "rays.csv").write_text("half")
    running = store.claim_next("someone-else")  # job a is running elsewhere: its staging stays
    assert running is not None and running.id == job_ids[0] and running.status is JobStatus.RUNNING
    sup = Supervisor(settings, store)
    assert sup.remove_stale_staging() == 1
    assert (tmp_path / "jobs" / job_ids[0] / ".results.x1y2.tmp").exists()
    assert not (tmp_path / "jobs" / job_ids[1] / ".results.x1y2.tmp").exists()
    assert remove_staging(tmp_path / "jobs" / job_ids[0]) == 1  # what the next attempt does before writing
    store.close()


def test_stale_uploads_and_orphan_job_folders_are_removed_at_start(tmp_path):
    from bentray.service.app import STALE_SUBMIT_S, remove_stale_files
    from bentray.service.deps import Services
    from bentray.service.settings import Settings

    services = Services.create(Settings(data_dir=tmp_path), start_workers=False)
    upload = tmp_path / "assets" / "local" / ".upload.abc123"
    upload.mkdir(parents=True)
    (upload / "hill.asc").write_text("partial")
    orphan = tmp_path / "jobs" / ("c" * 32)
    (orphan / "upload").mkdir(parents=True)
    fresh = tmp_path / "jobs" / ("d" * 32)
    fresh.mkdir(parents=True)
    old = time.time() - 2 * STALE_SUBMIT_S
    os.utime(orphan, (old, old))
    assert remove_stale_files(services) == 2
    assert not upload.exists() and not orphan.exists() and fresh.exists()  # a submit may be under way
    services.validator.close()
    services.store.close()


def test_busy_validation_helpers_answer_busy_not_a_hang():
    from bentray.service.validation import ValidationBusy

    pool = ValidationPool(timeout_s=0.2, size=1)
    try:
        pool.start()
        held = pool._take(time.monotonic() + 1.0)  # another request holds the only helper
        t0 = time.perf_counter()
        with pytest.raises(ValidationBusy):  # the routes answer it as 429 with Retry-After
            pool.run("text", "{}", LIMITS)
        assert time.perf_counter() - t0 < 2.0
        pool._give_back(held)
    finally:
        pool.close()


def test_a_cold_helper_start_is_not_counted_in_the_time_limit():
    """A new helper's imports took over 10 s on a loaded machine (30 concurrent submits answered 422
    validation_timeout); the limit is the validation's own, the start-up has its own allowance."""
    pool = ValidationPool(timeout_s=0.5, size=1)  # well below the helper's import time
    try:
        result = pool.run("text", json.dumps(base_job()), LIMITS)
        assert result["ok"], result
        assert pool._idle and pool._idle[0].ready
    finally:
        pool.close()

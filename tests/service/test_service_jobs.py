"""Job life cycle over real HTTP: submit -> poll -> download (identical to a local run), the CLI verbs,
cancel of a running job, and recovery after the server is SIGKILLed mid-job."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from bentray.clients.cli import main
from bentray.engine.run import run_job
from bentray.engine.writers import write_outcome
from bentray.scenes.schema import parse_job_text
from bentray.service.store import JobStore
from tests.service.conftest import ServerProcess, finished, tiny_field_job, tiny_job, wait_for

# report.json keys that measure this run (seconds, rates, threads) rather than describe its result
VOLATILE_REPORT_KEYS = {
    "timings_s",
    "compile_s",
    "compiled_functions",
    "throughput",
    "build_time_s",
    "mesh_build_time_s",
    "machine",
}
JSON = {"Content-Type": "application/json"}
VOLATILE_STAGES = {"trace"}  # "... on local process, N numba threads"


def _stable_report(report: dict) -> dict:
    out = {}
    for key, value in report.items():
        if key in VOLATILE_REPORT_KEYS:
            continue
        if key == "stages":
            value = {k: v for k, v in value.items() if k not in VOLATILE_STAGES}
        out[key] = _stable_report(value) if isinstance(value, dict) else value
    return out


def _pid_gone(pid: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        try:  # a child of this test process would linger as a zombie; job processes are not ours
            if Path(f"/proc/{pid}/stat").read_text().split(") ")[-1].startswith("Z"):
                return True
        except OSError:
            return True
        time.sleep(0.1)
    return False


@pytest.fixture(scope="module")
def server(tmp_path_factory, warm_kernels):
    srv = ServerProcess(tmp_path_factory.mktemp("svc") / "data", workers=1).start()
    yield srv
    srv.stop()


def _local_run(job: dict, tmp_path: Path) -> tuple[str, Path]:
    """(the job's JSON text, the folder of its outputs written by a local run here)."""
    text = json.dumps(job)
    local = tmp_path / "local"
    write_outcome(run_job(parse_job_text(text), tmp_path), job["outputs"], local)
    return text, local


def test_full_job_cycle_matches_local_run(server, tmp_path):
    text, local = _local_run(tiny_job(31, name="cycle"), tmp_path)

    with server.client() as http:
        r = http.post("/v1/jobs", content=text, headers={"Content-Type": "application/json"})
        assert r.status_code == 202, r.text
        info = r.json()
        job_id = info["id"]
        assert info["status"] == "queued" and r.headers["location"] == f"/v1/jobs/{job_id}"
        seen_progress = []
        info = wait_for(http, job_id, lambda i: seen_progress.append(i["progress"]) or finished(i))
        assert info["status"] == "succeeded", info
        assert info["progress"] == 1.0 and info["attempts"] == 1 and info["error"] is None
        assert all(0.0 <= p <= 1.0 for p in seen_progress) and seen_progress == sorted(seen_progress)
        assert sorted(info["results"]) == ["mesh.vtu", "rays.csv", "rays.vtp", "report.json"]
        assert info["timings_s"]["trace"] >= 0.0 and info["started_at"] <= info["finished_at"]
        assert [j["id"] for j in http.get("/v1/jobs").json()["jobs"]].count(job_id) == 1

        types = {"rays.csv": "text/csv", "report.json": "application/json", "rays.vtp": "application/vnd.vtk"}
        for name in ("rays.csv", "rays.vtp", "mesh.vtu", "report.json"):
            r = http.get(info["links"][name])
            assert r.status_code == 200
            assert r.headers["content-type"].startswith(types.get(name, "application/vnd.vtk"))
            assert f'filename="{name}"' in r.headers["content-disposition"]
            local_bytes = (local / name).read_bytes()
            if name == "report.json":
                assert _stable_report(r.json()) == _stable_report(json.loads(local_bytes))
            else:
                assert r.content == local_bytes, f"{name} differs from the local run"
        assert http.get(f"/v1/jobs/{job_id}/results/field.vti").status_code == 404  # not produced

        # delete a finished job: record and files go
        assert http.delete(f"/v1/jobs/{job_id}").status_code == 204
        assert http.get(f"/v1/jobs/{job_id}").status_code == 404
        assert not (server.data_dir / "jobs" / job_id).exists()


def test_field_job_results_match_local_run(server, tmp_path):
    """A job with a field: the job process draws preview.png in its own child (engine/preview_process.py);
    field.vti and preview.png are byte for byte the local run's (drawn in-process), and no preview process
    outlives the job."""
    text, local = _local_run(tiny_field_job("field-cycle"), tmp_path)
    with server.client() as http:
        info = wait_for(http, http.post("/v1/jobs", content=text, headers=JSON).json()["id"], finished)
        assert info["status"] == "succeeded", info
        assert sorted(info["results"]) == ["field.vti", "preview.png", "report.json"]
        for name in ("field.vti", "preview.png"):
            got = http.get(info["links"][name])
            assert got.status_code == 200 and got.content == (local / name).read_bytes(), name
    children = [line for line in _process_table() if "bentray.engine.preview_process" in line]
    assert children == [], children
    assert "drawn in this process" not in server.log.read_text()  # the child drew it (no fallback warning)


def _process_table() -> list[str]:
    """Command lines of the processes this user can see (Linux /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                out.append((d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"))
            except OSError:
                continue
    return out


def test_cli_submit_wait_out_status_fetch(server, tmp_path, capsys):
    job_file = tmp_path / "cli.json"
    job_file.write_text(json.dumps(tiny_job(21, name="cli")))
    out = tmp_path / "out"
    assert main(["submit", str(job_file), "--wait", "--out", str(out), "--quiet", "--url", server.url]) == 0
    local = tmp_path / "local"
    assert main(["run", str(job_file), "--out", str(local)]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in local.iterdir())
    assert (out / "rays.csv").read_bytes() == (local / "rays.csv").read_bytes()
    assert (out / "rays.vtp").read_bytes() == (local / "rays.vtp").read_bytes()
    job_id = capsys.readouterr().err.split("submitted ")[1].split()[0]
    assert main(["status", job_id, "--url", server.url]) == 0
    assert "succeeded" in capsys.readouterr().out
    assert main(["fetch", job_id, "--out", str(tmp_path / "again"), "--name", "rays.csv", "--url", server.url]) == 0
    assert (tmp_path / "again" / "rays.csv").read_bytes() == (local / "rays.csv").read_bytes()
    bad = tmp_path / "bad.json"
    bad.write_text(
        json.dumps(
            {
                **tiny_job(),
                "rays": {"elevation_deg": {"min": 0, "max": 0, "count": 0}, "max_time_s": 1, "max_reflections": 0},
            }
        )
    )
    assert main(["submit", str(bad), "--url", server.url]) == 2
    assert "rays.elevation_deg.count: Input should be greater than or equal to 1" in capsys.readouterr().err


def test_cancel_running_job_stops_its_process(server):
    store = JobStore(server.data_dir / "jobs.sqlite3")
    with server.client() as http:
        # about a minute of tracing on one core: it must be stopped, not finish
        job_id = http.post("/v1/jobs", json=tiny_job(300_000, name="long", batch_rays=5_000)).json()["id"]
        wait_for(http, job_id, lambda i: i["status"] == "running" and i["stage"] == "trace")
        pid = store.get(job_id).worker_pid
        assert pid is not None
        t0 = time.monotonic()
        r = http.delete(f"/v1/jobs/{job_id}")
        assert r.status_code in (200, 202) and r.json()["cancel_requested"]
        info = wait_for(http, job_id, finished, timeout_s=10.0)
        elapsed = time.monotonic() - t0
        assert info["status"] == "cancelled" and elapsed < 10.0
        assert _pid_gone(pid, 5.0), "the job process is still alive after cancel"
        assert http.get(f"/v1/jobs/{job_id}/results/rays.csv").status_code == 409
    store.close()


def test_dead_job_process_is_retried_once_then_failed_with_reason(server):
    store = JobStore(server.data_dir / "jobs.sqlite3")
    with server.client() as http:
        job_id = http.post("/v1/jobs", json=tiny_job(300_000, name="doomed", batch_rays=5_000)).json()["id"]
        for attempt in (1, 2):
            wait_for(http, job_id, lambda i, n=attempt: i["attempts"] == n and i["stage"] == "trace")
            os.kill(store.get(job_id).worker_pid, signal.SIGKILL)  # the process dies; the server lives
        info = wait_for(http, job_id, finished, timeout_s=15.0)
        assert info["status"] == "failed" and info["attempts"] == 2
        assert "killed by SIGKILL" in info["error"] and "not retried" in info["error"]
    store.close()


@pytest.mark.slow  # 30 s warm; the dead-job-process retry and cancel tests stay fast
def test_restart_after_sigkill_recovers_jobs(tmp_path, warm_kernels):
    data = tmp_path / "data"
    srv = ServerProcess(data, workers=1).start()
    store = JobStore(data / "jobs.sqlite3")
    try:
        with srv.client() as http:
            done = http.post("/v1/jobs", json=tiny_job(11, name="done")).json()["id"]
            assert wait_for(http, done, finished)["status"] == "succeeded"
            long_id = http.post("/v1/jobs", json=tiny_job(12_000, name="mid", batch_rays=1_000)).json()["id"]
            queued = http.post("/v1/jobs", json=tiny_job(11, name="queued")).json()["id"]
            wait_for(http, long_id, lambda i: i["status"] == "running" and i["stage"] == "trace")
            pid = store.get(long_id).worker_pid
        srv.kill()
        assert _pid_gone(pid, 5.0), "the job process outlived its killed server"
        assert store.get(long_id).status.value == "running"  # nobody recorded anything yet
        srv.start()
        with srv.client() as http:
            info = wait_for(http, long_id, finished, timeout_s=120.0)
            assert info["status"] == "succeeded" or (info["status"] == "failed" and info["error"]), info
            assert info["attempts"] == 2
            assert wait_for(http, queued, finished)["status"] == "succeeded"
            r = http.get(f"/v1/jobs/{done}/results/rays.csv")  # a finished result survives the restart
            assert r.status_code == 200 and r.text.startswith("ray,source,")
    finally:
        store.close()
        srv.stop()


def test_run_time_limit_and_retention(tmp_path, warm_kernels):
    retention_s = 3.0
    env = {"BENTRAY_MAX_JOB_SECONDS": "1.5", "BENTRAY_RETENTION_DAYS": str(retention_s / 86400.0)}
    srv = ServerProcess(tmp_path / "data", workers=1, env=env).start()
    try:
        with srv.client() as http:
            job_id = http.post("/v1/jobs", json=tiny_job(300_000, name="slow", batch_rays=5_000)).json()["id"]
            info = wait_for(http, job_id, finished, timeout_s=60.0)
            assert info["status"] == "failed"
            assert info["error"] == "the job ran longer than this server's limit of 1.5 s and was stopped"
            assert (srv.data_dir / "jobs" / job_id).exists()
            # finished jobs older than the retention time are deleted with their files
            wait_for(http, job_id, lambda i: i.get("error") == "not_found", timeout_s=4 * retention_s)
            assert not (srv.data_dir / "jobs" / job_id).exists()
    finally:
        srv.stop()

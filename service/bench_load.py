"""Load check: concurrent jobs from two API keys, and ``GET /v1/health`` latency while they run.

    python -m bentray.service.bench_load [--jobs-per-key 15] [--rays 91] [--workers 2]

Starts ``python -m bentray.service serve`` on a free loopback port with two API keys, a temporary
data folder and ``--workers`` job processes; submits ``2 x --jobs-per-key`` small A-LD fan jobs at
once (one thread per job, httpx), polls them to completion and checks that

- every job succeeded;
- each key sees exactly its own jobs (``GET /v1/jobs``), gets 404 for every job of the other key
  (status and results), and each job's ``report.json`` carries the name it was submitted with;

while one more thread sends sequential ``GET /v1/health`` requests (one keep-alive connection, 10 ms
apart) from the first submit until the last job finished, and prints their p50 / p99 / max latency
(client side, wall clock). Exit status 0 when every check passed. A measurement script, not a test
(``tests/service/test_load.py`` runs :func:`run_load` small).
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import httpx
import numpy as np

KEYS = ("bench-key-alpha-0123456789", "bench-key-bravo-0123456789")


def small_job(name: str, rays: int = 91) -> dict[str, Any]:
    """The README's A-LD fan with ``rays`` elevations (the health bench's job), report only (no large
    files)."""
    from bentray.service.bench_health import _job

    job = _job(rays, name)
    job["outputs"] = ["report"]
    return job


@dataclass
class LoadResult:
    """What :func:`run_load` saw. ``problems``: one line per failed check (empty: all passed)."""

    jobs: int
    succeeded: int
    wall_s: float
    health_ms: np.ndarray
    problems: list[str] = field(default_factory=list)
    statuses: dict[str, int] = field(default_factory=dict)

    def summary(self) -> str:
        ms = self.health_ms
        health = (
            f"GET /v1/health x {len(ms)} during the run: p50 {np.percentile(ms, 50):.2f} ms, "
            f"p99 {np.percentile(ms, 99):.2f} ms, max {ms.max():.2f} ms"
            if len(ms)
            else "no health samples"
        )
        checks = "all checks passed" if not self.problems else f"{len(self.problems)} failed checks"
        done = f"{self.succeeded}/{self.jobs} jobs succeeded in {self.wall_s:.1f} s ({self.statuses})"
        return f"{done}; {health}; {checks}"


def _health_loop(url: str, stop: threading.Event, out: list[float], errors: list[str]) -> None:
    with httpx.Client(base_url=url, timeout=10.0) as http:
        while not stop.is_set():
            t0 = time.perf_counter()
            try:
                r = http.get("/v1/health")
                dt = time.perf_counter() - t0
                if r.status_code != 200:
                    errors.append(f"health: status {r.status_code}")
                out.append(dt)
            except httpx.HTTPError as exc:
                errors.append(f"health: {type(exc).__name__}: {exc}")
            stop.wait(0.01)


def run_load(
    url: str, keys: tuple[str, str], jobs_per_key: int, rays: int = 91, timeout_s: float = 600.0
) -> LoadResult:
    """Submit ``jobs_per_key`` jobs per key at once to the server at ``url``, wait, check (module docstring)."""
    clients = [httpx.Client(base_url=url, headers={"Authorization": f"Bearer {k}"}, timeout=60.0) for k in keys]
    problems: list[str] = []
    times: list[float] = []
    stop = threading.Event()
    sampler = threading.Thread(target=_health_loop, args=(url, stop, times, problems), daemon=True)
    plan = [(k, f"load-k{k}-j{j}") for j in range(jobs_per_key) for k in range(len(keys))]

    def submit(item: tuple[int, str]) -> tuple[int, str, str | None, str]:
        k, name = item
        with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {keys[k]}"}, timeout=120.0) as http:
            r = http.post("/v1/jobs", json=small_job(name, rays))
        if r.status_code == 202:
            return k, name, str(r.json()["id"]), ""
        return k, name, None, f"{r.status_code} {r.text[:300]}"

    t0 = time.perf_counter()
    sampler.start()
    try:
        with ThreadPoolExecutor(max_workers=len(plan)) as pool:
            submitted = list(pool.map(submit, plan))
        ids: dict[str, tuple[int, str]] = {}
        for k, name, job_id, why in submitted:
            if job_id is None:
                problems.append(f"{name}: submit answered {why}")
            else:
                ids[job_id] = (k, name)
        info: dict[str, dict[str, Any]] = {}
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for k, http in enumerate(clients):
                for item in http.get("/v1/jobs", params={"limit": 1000}).json()["jobs"]:
                    info[item["id"]] = item | {"_seen_by": k}
            if all(info.get(i, {}).get("status") in ("succeeded", "failed", "cancelled") for i in ids):
                break
            time.sleep(0.5)
        else:
            problems.append(f"jobs not finished within {timeout_s:g} s")
        wall = time.perf_counter() - t0
    finally:
        stop.set()
        sampler.join(15)
    statuses: dict[str, int] = {}
    for job_id, (k, name) in ids.items():
        item = info.get(job_id, {})
        status = str(item.get("status", "missing"))
        statuses[status] = statuses.get(status, 0) + 1
        if status != "succeeded":
            problems.append(f"{name}: {status} {item.get('error') or ''}".strip())
        if item and item["_seen_by"] != k:
            problems.append(f"{name}: listed for key {item['_seen_by']}, submitted with key {k}")
    # cross-key access: each key sees its own jobs only, the other key's are 404 (status and results)
    for k, http in enumerate(clients):
        own = {i for i, (kk, _) in ids.items() if kk == k}
        listed = {item["id"] for item in http.get("/v1/jobs", params={"limit": 1000}).json()["jobs"]}
        if listed != own:
            problems.append(f"key {k}: lists {len(listed)} jobs, submitted {len(own)} (or other ids)")
        for job_id, (kk, name) in ids.items():
            got = http.get(f"/v1/jobs/{job_id}")
            report = http.get(f"/v1/jobs/{job_id}/results/report.json")
            if kk == k:
                if got.status_code != 200 or got.json()["name"] != name:
                    problems.append(f"key {k}: own job {name}: {got.status_code}")
                elif report.status_code != 200 or report.json().get("name") != name:
                    problems.append(f"key {k}: own job {name}: report.json {report.status_code}")
            elif got.status_code != 404 or report.status_code != 404:
                problems.append(f"key {k}: other key's job {name}: {got.status_code} / {report.status_code}, not 404")
    for http in clients:
        http.close()
    return LoadResult(
        jobs=len(plan),
        succeeded=statuses.get("succeeded", 0),
        wall_s=wall,
        health_ms=1e3 * np.asarray(times, float),
        problems=problems,
        statuses=statuses,
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="concurrent jobs from two keys; health latency while they run")
    parser.add_argument("--jobs-per-key", type=int, default=15)
    parser.add_argument("--rays", type=int, default=91, help="elevations of each A-LD fan job")
    parser.add_argument("--workers", type=int, default=2, help="job processes of the server")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds for all jobs to finish")
    args = parser.parse_args(argv)
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory(prefix="bentray-load-") as data:
        env = {k: v for k, v in os.environ.items() if not k.startswith("BENTRAY_")}
        env["BENTRAY_API_KEYS"] = ",".join(KEYS)
        cmd = [sys.executable, "-m", "bentray.service", "serve", "--host", "127.0.0.1", "--port", str(port)]
        cmd += ["--workers", str(args.workers), "--data-dir", data, "--log-level", "warning"]
        proc = subprocess.Popen(cmd, env=env)
        try:
            for _ in range(600):
                try:
                    if httpx.get(url + "/v1/health", timeout=1.0).status_code == 200:
                        break
                except httpx.TransportError:
                    pass
                time.sleep(0.1)
            result = run_load(url, KEYS, args.jobs_per_key, args.rays, args.timeout)
        finally:
            proc.terminate()
            proc.wait(30)
    print(
        f"{time.strftime('%Y-%m-%d', time.gmtime())}, {os.cpu_count()} CPUs, --workers {args.workers}, "
        f"{args.jobs_per_key} jobs x 2 keys of {args.rays} rays: {result.summary()}"
    )
    for line in result.problems:
        print("  " + line)
    return 0 if not result.problems else 1


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: ``GET /v1/health`` latency while two jobs run (the issue asks for p99 < 50 ms).

    python -m bentray.service.bench_health [--requests 2000] [--rays 400000]

Starts ``python -m bentray.service serve --workers 2`` on a free local port with a temporary data
folder, submits two long A-LD fan jobs, waits until both are tracing, then sends ``--requests``
sequential health requests over one keep-alive connection and prints p50 / p99 / max latency (client
side, wall clock) and whether both jobs were still running at the end. The jobs are then cancelled
and the server stopped. A measurement script, not a test: numbers depend on the machine.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

_EXAMPLE = Path(__file__).resolve().parents[1] / "scenes" / "examples" / "a-ld-fan.json"


def _job(rays: int, name: str) -> dict[str, Any]:
    job = json.loads(_EXAMPLE.read_text()) if _EXAMPLE.is_file() else None
    if job is None:  # installed without the examples folder: the same job inline
        job = {
            "scene": {"domain": {"min": [-50, -50, 0], "max": [4000, 50, 2600]}, "ground": {"kind": "flat"}},
            "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
            "sources": [{"position": [0, 0, 1.5]}],
            "rays": {"elevation_deg": {"min": -45, "max": 45, "count": 91}, "max_time_s": 10.0, "max_reflections": 50},
            "solver": {"curve": "parabolic", "epsilon": 0.001},
            "outputs": ["rays", "report"],
        }
    job["name"] = name
    job["rays"]["elevation_deg"]["count"] = rays
    job["solver"]["batch_rays"] = 5000
    return job


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="GET /v1/health latency while two jobs run")
    parser.add_argument("--requests", type=int, default=2000)
    parser.add_argument("--rays", type=int, default=400_000, help="rays per job (long enough to outlast the test)")
    args = parser.parse_args(argv)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory(prefix="bentray-bench-") as data:
        env = {k: v for k, v in os.environ.items() if not k.startswith("BENTRAY_")}
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "bentray.service",
                "serve",
                "--port",
                str(port),
                "--workers",
                "2",
                "--data-dir",
                data,
                "--log-level",
                "warning",
            ],
            env=env,
        )
        try:
            with httpx.Client(base_url=url, timeout=10.0) as http:
                for _ in range(600):
                    try:
                        http.get("/v1/health")
                        break
                    except httpx.TransportError:
                        time.sleep(0.1)
                ids = [http.post("/v1/jobs", json=_job(args.rays, f"bench-{i}")).json()["id"] for i in range(2)]
                deadline = time.monotonic() + 300
                while time.monotonic() < deadline:
                    states = [http.get(f"/v1/jobs/{i}").json() for i in ids]
                    if all(s["status"] == "running" and s["stage"] == "trace" for s in states):
                        break
                    time.sleep(0.2)
                else:
                    print("the jobs did not start tracing within 300 s", file=sys.stderr)
                    return 1
                times = np.empty(args.requests)
                for k in range(args.requests):
                    t0 = time.perf_counter()
                    r = http.get("/v1/health")
                    times[k] = time.perf_counter() - t0
                    assert r.status_code == 200
                still = [http.get(f"/v1/jobs/{i}").json()["status"] for i in ids]
                for i in ids:
                    http.delete(f"/v1/jobs/{i}")
            ms = 1e3 * times
            print(
                f"GET /v1/health x {args.requests} while 2 jobs ran ({os.cpu_count()} CPUs): "
                f"p50 {np.percentile(ms, 50):.2f} ms, p99 {np.percentile(ms, 99):.2f} ms, max {ms.max():.2f} ms; "
                f"jobs at the end: {', '.join(still)}"
            )
            return 0 if np.percentile(ms, 99) < 50.0 else 1
        finally:
            proc.terminate()
            proc.wait(30)


if __name__ == "__main__":
    sys.exit(main())

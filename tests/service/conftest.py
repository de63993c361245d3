"""A real uvicorn server in a subprocess on 127.0.0.1 (a free port), driven over HTTP with httpx."""

from __future__ import annotations

import copy
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "scenes" / "examples" / "a-ld-fan.json"
START_TIMEOUT_S = 60.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def tiny_job(rays: int = 31, name: str = "tiny", batch_rays: int | None = None) -> dict:
    """The README's A-LD fan with ``rays`` elevations (about 5,000 rays/s on one core once compiled)."""
    job = copy.deepcopy(json.loads(EXAMPLE.read_text()))
    job["name"] = name
    job["rays"]["elevation_deg"]["count"] = rays
    if batch_rays is not None:
        job["solver"]["batch_rays"] = batch_rays
    return job


def tiny_field_job(name: str = "tiny-field") -> dict:
    """:func:`tiny_job` with a small level map (a vertical x-z section, 250 Hz and 1 kHz, 100 dB): field.vti
    and preview.png."""
    job = tiny_job(31, name)
    job["rays"]["azimuth_deg"] = {"min": -2.0, "max": 2.0, "count": 3}
    job["sources"][0]["power_db"] = {"250": 100.0, "1000": 100.0}
    job["field"] = {"origin": [20.0, 0.0, 1.0], "spacing": [40.0, 1.0, 5.0], "shape": [12, 1, 6],
                    "frequencies_hz": [250.0, 1000.0]}  # fmt: skip
    job["outputs"] = ["field", "report"]
    return job


class ServerProcess:
    """``python -m bentray.service serve`` on a free port with a given data folder and environment."""

    def __init__(self, data_dir: Path, workers: int = 1, env: dict[str, str] | None = None) -> None:
        self.data_dir = data_dir
        self.workers = workers
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("BENTRAY_")}
        self.env.update(env or {})
        self.proc: subprocess.Popen | None = None
        self.port = 0
        self.log = data_dir.parent / f"{data_dir.name}-server.log"

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> ServerProcess:
        self.port = free_port()
        cmd = [
            sys.executable,
            "-m",
            "bentray.service",
            "serve",
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--workers",
            str(self.workers),
            "--data-dir",
            str(self.data_dir),
            "--log-level",
            "warning",
        ]
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(cmd, env=self.env, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.log.read_text()}")
            try:
                if httpx.get(self.url + "/v1/health", timeout=1.0).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        self.stop()
        raise RuntimeError(f"server did not answer within {START_TIMEOUT_S} s:\n{self.log.read_text()}")

    def kill(self) -> None:
        """SIGKILL the server process (no shutdown code runs)."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)

    def client(self, key: str | None = None) -> httpx.Client:
        headers = {"Authorization": f"Bearer {key}"} if key else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=30.0)


def wait_for(client: httpx.Client, job_id: str, until, timeout_s: float = 90.0, poll_s: float = 0.1) -> dict:
    """Poll GET /v1/jobs/{id} until ``until(info)`` is true; fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    info: dict = {}
    while time.monotonic() < deadline:
        info = client.get(f"/v1/jobs/{job_id}").json()
        if until(info):
            return info
        time.sleep(poll_s)
    raise AssertionError(f"job {job_id} did not reach the expected state in {timeout_s} s: {info}")


def finished(info: dict) -> bool:
    return info["status"] in ("succeeded", "failed", "cancelled")


@pytest.fixture(scope="session")
def warm_kernels() -> None:
    """Compile the engine's kernels once in this process (job processes then load them from the cache)."""
    from bentray.engine.run import run_job
    from bentray.scenes.schema import Job

    run_job(Job.model_validate(tiny_job(5)), None)
    run_job(Job.model_validate(tiny_field_job()), None)

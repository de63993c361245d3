"""The README's load check, small: concurrent jobs from two keys all succeed, no key sees another's.

The full run (30 jobs, health p99) is ``python -m bentray.service.bench_load``; this test asserts the
outcome only, never a timing.
"""

from __future__ import annotations

from bentray.service.bench_load import KEYS, run_load

from .conftest import ServerProcess


def test_concurrent_jobs_from_two_keys_all_succeed(tmp_path, warm_kernels):
    env = {"BENTRAY_API_KEYS": ",".join(KEYS)}
    srv = ServerProcess(tmp_path / "data", workers=2, env=env).start()
    try:
        result = run_load(srv.url, KEYS, jobs_per_key=3, rays=11, timeout_s=300.0)
    finally:
        srv.stop()
    assert result.problems == []
    assert result.jobs == 6 and result.succeeded == 6
    assert len(result.health_ms) > 0  # health answered (200) throughout; its latency is not asserted

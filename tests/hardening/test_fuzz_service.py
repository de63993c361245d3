"""Fuzzing as a test (issue 15): schemathesis drives the live server over loopback (127.0.0.1 only, a
server with ``--workers 0``: queued jobs never run) from its own OpenAPI document and asserts that no
answer is a 5xx and every answer matches the documented status codes, content types, headers and
schemas. The default run is bounded in examples per operation and in wall time (<= ~60 s on 2 cores);
``-m slow`` runs ten times the examples.
"""

from __future__ import annotations

import time

import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, settings
from schemathesis import checks as st_checks

from tests.service.conftest import ServerProcess

EXAMPLES = 12  # per operation and media type (7 operations, 2 body media types for POST /v1/jobs)
SLOW_FACTOR = 10
BUDGET_S = 60.0
CHECKS = [
    st_checks.not_a_server_error,
    st_checks.status_code_conformance,
    st_checks.content_type_conformance,
    st_checks.response_headers_conformance,
    st_checks.response_schema_conformance,
]
COUNTS = {"calls": 0, "by_status": {}}


@pytest.fixture(scope="module")
def fuzz_server(tmp_path_factory):
    env = {"BENTRAY_MAX_UPLOAD_BYTES": "65536", "BENTRAY_MAX_QUEUE": "20", "BENTRAY_VALIDATION_SECONDS": "5"}
    srv = ServerProcess(tmp_path_factory.mktemp("fuzz") / "data", workers=0, env=env).start()
    assert srv.url.startswith("http://127.0.0.1:")
    yield srv
    srv.stop()
    print(f"\nfuzz: {COUNTS['calls']} calls, by status {dict(sorted(COUNTS['by_status'].items()))}")


def _config(coverage: bool) -> schemathesis.Config:
    # the coverage phase (every boundary of every field of the job schema) is ~1,500 calls: slow run only
    return schemathesis.Config.from_dict(
        {"phases": {"coverage": {"enabled": coverage}, "stateful": {"enabled": False}}}
    )


@pytest.fixture(scope="module")
def api_schema(fuzz_server):
    return schemathesis.openapi.from_url(fuzz_server.url + "/openapi.json", config=_config(coverage=False))


@pytest.fixture(scope="module")
def api_schema_full(fuzz_server):
    return schemathesis.openapi.from_url(fuzz_server.url + "/openapi.json", config=_config(coverage=True))


schema = schemathesis.pytest.from_fixture("api_schema")
schema_full = schemathesis.pytest.from_fixture("api_schema_full")
_START: dict[str, float] = {}


def _fuzz(case, fuzz_server, budget_s: float) -> None:
    start = _START.setdefault("t", time.monotonic())
    if time.monotonic() - start > budget_s:
        return  # the module's wall-time budget is spent: later examples pass untested (counted below)
    response = case.call_and_validate(base_url=fuzz_server.url, checks=CHECKS, timeout=30)
    COUNTS["calls"] += 1
    COUNTS["by_status"][response.status_code] = COUNTS["by_status"].get(response.status_code, 0) + 1


_SETTINGS = {
    "deadline": None,
    "suppress_health_check": list(HealthCheck),
    "phases": [Phase.explicit, Phase.generate],  # no shrinking: a failure is reported as found
    "derandomize": True,
}


@schema.parametrize()
@settings(max_examples=EXAMPLES, **_SETTINGS)
def test_fuzz_api(case, fuzz_server):
    _fuzz(case, fuzz_server, BUDGET_S)


@pytest.mark.slow
@schema_full.parametrize()
@settings(max_examples=EXAMPLES * SLOW_FACTOR, **_SETTINGS)
def test_fuzz_api_10x(case, fuzz_server):
    _fuzz(case, fuzz_server, SLOW_FACTOR * BUDGET_S)

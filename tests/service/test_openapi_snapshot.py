"""The OpenAPI schema is a contract with the Python client and with scripted users: a change to a route
or to the job schema must show up here as a diff of tests/service/reference/openapi.json.

Regenerate (and review the diff) with:
    python -c "from tests.service.test_openapi_snapshot import current; import json, sys; \
json.dump(current(), sys.stdout, indent=1, sort_keys=True)" > tests/service/reference/openapi.json
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

SNAPSHOT = Path(__file__).resolve().parent / "reference" / "openapi.json"


def current() -> dict:
    """The app's OpenAPI document (no workers started, nothing written outside a temporary folder)."""
    import tempfile

    from bentray.service.app import create_app
    from bentray.service.settings import Settings

    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(Settings(data_dir=Path(tmp)), start_workers=False)
        return json.loads(json.dumps(app.openapi()))


def test_openapi_matches_the_snapshot():
    if not SNAPSHOT.exists():
        pytest.fail(f"missing {SNAPSHOT}: generate it as the module docstring says and review it")
    expected = json.loads(SNAPSHOT.read_text())
    got = current()
    assert sorted(got["paths"]) == sorted(expected["paths"]), "routes changed"
    assert got == expected, "the OpenAPI schema changed: regenerate the snapshot and review the diff"

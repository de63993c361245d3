"""Issue 15, the service over real HTTP (127.0.0.1, --workers 0): what answered 500, hung or was accepted
and then failed in the worker now answers a 422 (or 400) in the service's error model, at once."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from tests.hardening.conftest import HILL, base_job, below_terrain_job, field_job, huge_footprint_job, overlapping_job
from tests.service.conftest import ServerProcess

ERROR_KEYS = {"error", "detail"}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    env = {"BENTRAY_MAX_JOB_MEMORY_BYTES": str(2**29)}
    srv = ServerProcess(tmp_path_factory.mktemp("harden") / "data", workers=0, env=env).start()
    with srv.client() as http:  # the validation helper's imports happen before the timed requests
        http.post("/v1/jobs", content=b"{}", headers={"content-type": "application/json"})
    yield srv
    srv.stop()


def _post(http, job) -> tuple[int, dict, float]:
    body = job if isinstance(job, bytes) else json.dumps(job).encode()
    t0 = time.perf_counter()
    r = http.post("/v1/jobs", content=body, headers={"content-type": "application/json"})
    return r.status_code, r.json(), time.perf_counter() - t0


def test_huge_footprint_answers_422_within_a_second(server):
    with server.client() as http:
        status, body, seconds = _post(http, huge_footprint_job())
    assert status == 422 and seconds < 1.0, (status, seconds)
    assert body["errors"][0]["field"] == "scene.buildings.footprints.0.polygon.0.0"


@pytest.mark.parametrize(
    "text, start",
    [
        (b"[" * 10_000 + b"]" * 10_000, "job: the JSON nests deeper than 64 levels"),
        (b'{"name": ' + b"9" * 5000 + b"}", "job: an integer of 5,000 digits"),
    ],
    ids=["deep", "huge-int"],
)
def test_unparseable_bodies_answer_422_not_500(server, text, start):
    with server.client() as http:
        status, body, _ = _post(http, text)
    assert status == 422 and body["error"] == "invalid_json" and body["detail"].startswith(start)


def test_deep_geojson_upload_answers_422(server):
    deep = b'{"type": "FeatureCollection", "features": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
    with server.client() as http:
        r = http.post("/v1/assets", files={"file": ("deep.geojson", deep)})
    assert r.status_code == 422 and set(r.json()) >= ERROR_KEYS, r.text
    assert r.json()["errors"][0]["field"] == "file"


def test_wrapping_field_shape_answers_422(server):
    with server.client() as http:
        status, body, _ = _post(http, field_job(1.0, (2**32, 2**32, 1)))
    assert status == 422 and {e["field"] for e in body["errors"]} == {"field.shape.0", "field.shape.1"}


def test_cost_model_refuses_with_the_estimate_and_the_limit(server):
    job = base_job()
    job["rays"]["elevation_deg"]["count"] = 20_000
    job["rays"]["record_paths"] = True
    with server.client() as http:
        status, body, _ = _post(http, job)
        assert status == 422 and body["error"] == "over_limit"
        assert body["errors"][0]["field"] == "rays.record_paths"
        assert (
            "estimated 0.779 GiB of memory (paths 0.775 GiB" in body["detail"]
            and "the limit is 0.5 GiB" in body["detail"]
        )
        job["rays"]["record_paths"] = False  # the same rays without paths fit
        status, body, _ = _post(http, job)
        assert status == 202, body
        status, body, _ = _post(http, field_job(1e-6))
        assert status == 422 and body["errors"][0]["field"] == "field.spacing"


def test_unphysical_media_and_bad_scenes_are_refused_at_submit(server):
    with server.client() as http:
        job = base_job()
        job["profile"]["b"] = -1e6
        status, body, _ = _post(http, job)
        assert status == 422 and body["errors"][0]["field"] == "profile.b"
        status, body, _ = _post(http, overlapping_job())
        assert status == 422 and "overlaps" in body["detail"]
        assert http.post("/v1/assets", files={"file": ("hill.asc", HILL.read_bytes())}).status_code == 201
        status, body, _ = _post(http, below_terrain_job())
        assert status == 422 and body["errors"][0]["field"] == "sources.0.position", body
        assert str(server.data_dir) not in body["detail"]


def test_grid_with_nan_is_refused_at_submit(server, tmp_path):
    c = np.full((3, 3, 3), 340.0)
    c[1, 1, 1] = np.nan
    np.savez(tmp_path / "grid.npz", c=c, origin=np.zeros(3), spacing=np.full(3, 50.0))
    job = base_job()
    job["scene"]["domain"] = {"min": [0, 0, 0], "max": [100, 100, 100]}
    job["sources"] = [{"position": [50, 50, 10]}]
    job["profile"] = {"kind": "grid", "path": "grid.npz"}
    with server.client() as http:
        r = http.post(
            "/v1/jobs",
            files=[
                ("job", ("job.json", json.dumps(job).encode())),
                ("files", ("grid.npz", (tmp_path / "grid.npz").read_bytes())),
            ],
        )
    assert r.status_code == 422 and r.json()["errors"][0]["field"] == "profile.path", r.text


def test_multipart_errors_use_the_error_model(server):
    with server.client() as http:
        r = http.post(
            "/v1/assets", content=b"--x\r\nnot a part", headers={"content-type": "multipart/form-data; boundary=x"}
        )
        assert r.status_code in (400, 422) and set(r.json()) >= ERROR_KEYS, r.text
        r = http.post("/v1/jobs", content=b"garbage", headers={"content-type": "multipart/form-data"})
        assert r.status_code == 400 and r.json()["error"] == "bad_request", r.text
        r = http.get("/v1/nothing-here")
        assert r.status_code == 404 and r.json()["error"] == "not_found"


def test_openapi_documents_every_error_with_the_error_model(server):
    with server.client() as http:
        doc = http.get("/openapi.json").json()
    assert "HTTPValidationError" not in doc["components"]["schemas"]
    expected = {
        ("post", "/v1/jobs"): {"400", "401", "411", "413", "415", "422", "429"},
        ("post", "/v1/assets"): {"400", "401", "411", "413", "415", "422"},
        ("get", "/v1/jobs/{job_id}/results/{name}"): {"401", "404", "409", "422"},
        ("get", "/v1/jobs/{job_id}"): {"401", "404", "422"},
    }
    for (method, path), codes in expected.items():
        responses = doc["paths"][path][method]["responses"]
        assert codes <= set(responses), (method, path, sorted(responses))
        for code in codes:
            schema = responses[code]["content"]["application/json"]["schema"]
            assert schema == {"$ref": "#/components/schemas/ErrorBody"}, (path, code)
    assert "Retry-After" in doc["paths"]["/v1/jobs"]["post"]["responses"]["429"]["headers"]

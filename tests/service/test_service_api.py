"""API checks over real HTTP that need no job to run (servers with --workers 0): API keys, malformed and
invalid jobs, server limits, uploads (size, content), path traversal, queue full, OpenAPI."""

from __future__ import annotations

import json

import httpx
import pytest
from pydantic import ValidationError

from bentray.scenes.schema import format_validation_error, parse_job_text
from tests.service.conftest import REPO, ServerProcess, tiny_job

KEY_A = "alice-0123456789abcdef"
KEY_B = "bob-0123456789abcdef00"
UPLOAD_LIMIT = 65_536
HILL = REPO / "scenes" / "examples" / "hill.asc"
# a closed tetrahedron with outward normals (a valid obstacle mesh)
TETRA_OBJ = "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


@pytest.fixture(scope="module")
def keyed(tmp_path_factory):
    env = {
        "BENTRAY_API_KEYS": f"{KEY_A},{KEY_B}",
        "BENTRAY_MAX_UPLOAD_BYTES": str(UPLOAD_LIMIT),
        "BENTRAY_MAX_RAYS": "100000",
        "BENTRAY_MAX_FIELD_POINTS": "1000",
    }
    srv = ServerProcess(tmp_path_factory.mktemp("keyed") / "data", workers=0, env=env).start()
    yield srv
    srv.stop()


def _files_outside(root, data_dir) -> list[str]:
    """Every file under ``root`` except those under the data folder and the server log."""
    return sorted(
        str(p.relative_to(root))
        for p in root.rglob("*")
        if p.is_file() and data_dir not in p.parents and not p.name.endswith("-server.log")
    )


def test_two_keys_cannot_see_each_other(keyed):
    with keyed.client(KEY_A) as a, keyed.client(KEY_B) as b, keyed.client() as anonymous:
        r = a.post("/v1/jobs", json=tiny_job(name="alice"))
        assert r.status_code == 202
        job_id = r.json()["id"]
        assert a.get(f"/v1/jobs/{job_id}").json()["name"] == "alice"
        for method, url in (
            ("GET", f"/v1/jobs/{job_id}"),
            ("DELETE", f"/v1/jobs/{job_id}"),
            ("GET", f"/v1/jobs/{job_id}/results/rays.csv"),
        ):
            r = b.request(method, url)
            assert r.status_code == 404, (method, url, r.text)
            assert r.json()["detail"] == f"no job {job_id!r}"  # the same answer as for an unknown id
        assert job_id not in [j["id"] for j in b.get("/v1/jobs").json()["jobs"]]
        assert job_id in [j["id"] for j in a.get("/v1/jobs").json()["jobs"]]
        assert a.get(f"/v1/jobs/{job_id}").json()["status"] == "queued"  # B's DELETE did nothing
        r = anonymous.get("/v1/jobs")
        assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
        with keyed.client("not-a-key-0123456789") as stranger:
            assert stranger.get(f"/v1/jobs/{job_id}").status_code == 401
        assert anonymous.get("/v1/health").status_code == 200  # health needs no key
        # assets are per key too: B's job cannot name A's asset
        assert a.post("/v1/assets", files={"file": ("hill.asc", HILL.read_bytes())}).status_code == 201
        job = tiny_job(name="bob")
        job["scene"] = {"domain": {"min": [-500, -500, 0], "max": [500, 500, 300]}, "terrain": {"file": "hill.asc"}}
        job["sources"] = [{"position": [0, 0, 40]}]
        assert a.post("/v1/jobs", json=job).status_code == 202
        r = b.post("/v1/jobs", json=job)
        assert r.status_code == 422 and r.json()["errors"][0]["field"] == "scene.terrain.file"
        assert [x["name"] for x in b.get("/v1/assets").json()] == []


def test_malformed_json_and_schema_violations(keyed):
    with keyed.client(KEY_A) as a:
        r = a.post("/v1/jobs", content=b'{"name": "x",', headers={"Content-Type": "application/json"})
        assert r.status_code == 422
        assert r.json()["error"] == "invalid_json" and r.json()["detail"].startswith("job: invalid JSON at line 1")
        r = a.post("/v1/jobs", content=b"\xff\xfe", headers={"Content-Type": "application/json"})
        assert r.status_code == 422 and "not UTF-8" in r.json()["detail"]
        r = a.post("/v1/jobs", content=b"{}", headers={"Content-Type": "text/plain"})
        assert r.status_code == 415
        bad = tiny_job()
        bad["rays"]["elevation_deg"]["count"] = 0
        bad["solver"]["curvature"] = "yes"
        bad["sources"][0]["position"] = [0, 0, -5]
        text = json.dumps(bad)
        with pytest.raises(ValidationError) as exc:
            parse_job_text(text)
        expected = format_validation_error(exc.value)
        r = a.post("/v1/jobs", content=text, headers={"Content-Type": "application/json"})
        assert r.status_code == 422
        assert r.json()["detail"] == expected  # the same lines as `bentray run` prints
        fields = [e["field"] for e in r.json()["errors"]]
        assert "rays.elevation_deg.count" in fields and "solver.curvature" in fields
        # server limits (configuration), reported like schema errors
        r = a.post("/v1/jobs", json=tiny_job(200_000))
        assert r.status_code == 422
        assert r.json()["detail"].startswith("rays: 200,000 rays") and "100,000" in r.json()["detail"]
        assert a.get("/v1/jobs/not-an-id").status_code == 404


def test_uploads_size_and_content(keyed):
    with keyed.client(KEY_A) as a:
        r = a.post("/v1/assets", files={"file": ("hill.asc", HILL.read_bytes())})
        assert r.status_code == 201 and r.json()["kind"] == "terrain" and r.json()["size"] == HILL.stat().st_size
        r = a.post("/v1/assets", files={"file": ("tetra.obj", TETRA_OBJ.encode())})
        assert r.status_code == 201 and r.json()["kind"] == "obstacle"
        # too large: one file over the limit (checked while streaming), a body far over it (Content-Length)
        r = a.post("/v1/assets", files={"file": ("big.asc", b"1 " * UPLOAD_LIMIT)})
        assert r.status_code == 413 and r.json()["error"] == "too_large"
        r = a.post("/v1/assets", files={"file": ("huge.asc", b"0" * (UPLOAD_LIMIT + 2 * 2**20))})
        assert r.status_code == 413
        # not a mesh, not a terrain
        r = a.post("/v1/assets", files={"file": ("junk.stl", b"hello, this is not a mesh\n")})
        assert r.status_code == 422 and r.json()["error"] == "invalid_file"
        assert r.json()["detail"].startswith("file: junk.stl: ")
        assert "STL" in r.json()["detail"] or "triangles" in r.json()["detail"]
        r = a.post("/v1/assets", files={"file": ("junk.asc", b"ncols 2\nnrows oops\n")})
        assert r.status_code == 422 and "junk.asc" in r.json()["detail"]
        r = a.post("/v1/assets", files={"file": ("notes.txt", b"hello")})
        assert r.status_code == 422 and "kind" in r.json()["detail"]
        names = [x["name"] for x in a.get("/v1/assets").json()]
        assert "junk.stl" not in names and "big.asc" not in names and "tetra.obj" in names
        # a job with its file as a multipart part; the file lands in the job's own inputs folder
        job = tiny_job(name="with-terrain")
        job["scene"] = {"domain": {"min": [-500, -500, 0], "max": [500, 500, 300]}, "terrain": {"file": "mine.asc"}}
        job["sources"] = [{"position": [0, 0, 40]}]
        r = a.post(
            "/v1/jobs",
            files=[("job", ("job.json", json.dumps(job).encode())), ("files", ("mine.asc", HILL.read_bytes()))],
        )
        assert r.status_code == 202, r.text
        inputs = keyed.data_dir / "jobs" / r.json()["id"] / "inputs"
        assert (inputs / "mine.asc").read_bytes() == HILL.read_bytes()
        r = a.post(
            "/v1/jobs", files=[("job", ("job.json", json.dumps(job).encode())), ("files", ("mine.asc", b"not a grid"))]
        )
        assert r.status_code == 422 and r.json()["errors"][0]["field"] == "scene.terrain.file"


def test_path_traversal_is_rejected(keyed):
    root = keyed.data_dir.parent
    before = _files_outside(root, keyed.data_dir)
    with keyed.client(KEY_A) as a:
        for name in ("../evil.asc", "../../evil.asc", "/tmp/evil.asc", "..", ".hidden.asc", "a/../../b.asc"):
            r = a.post("/v1/assets", files={"file": (name, HILL.read_bytes())})
            assert r.status_code == 422, (name, r.text)
            r = a.post("/v1/assets", files={"file": ("ok.asc", HILL.read_bytes())}, data={"name": name})
            assert r.status_code == 422, (name, r.text)
            assert r.json()["errors"][0]["field"] == "name"
        for name in ("../../etc/passwd", "/etc/passwd", "..\\x.asc", "sub/hill.asc"):
            job = tiny_job()
            job["scene"] = {"domain": {"min": [-500, -500, 0], "max": [500, 500, 300]}, "terrain": {"file": name}}
            job["sources"] = [{"position": [0, 0, 40]}]
            r = a.post("/v1/jobs", json=job)
            assert r.status_code == 422, (name, r.text)
            assert r.json()["errors"][0]["field"].startswith("scene.terrain")  # the schema or the service
        r = a.post(
            "/v1/jobs",
            files=[("job", ("job.json", json.dumps(tiny_job()).encode())), ("files", ("../up.asc", HILL.read_bytes()))],
        )
        assert r.status_code == 422 and r.json()["errors"][0]["field"] == "files"
        job_id = a.post("/v1/jobs", json=tiny_job()).json()["id"]
        for name in ("..%2F..%2Fjobs.sqlite3", "..%2Fresults", "%2E%2E", "report.json%00"):
            r = a.get(f"/v1/jobs/{job_id}/results/{name}")
            assert r.status_code in (404, 409), (name, r.status_code)
            assert r.status_code == 404 or name == "report.json"
        for url in ("/v1/jobs/..%2F..%2Fjobs.sqlite3", "/v1/assets/..%2Fx.asc"):
            assert a.request("DELETE" if "assets" in url else "GET", url).status_code == 404
    assert _files_outside(root, keyed.data_dir) == before
    assert not any(p.name in ("evil.asc", "up.asc", "b.asc") for p in root.rglob("*"))


def test_queue_full_answers_429(tmp_path):
    env = {"BENTRAY_MAX_QUEUE": "2", "BENTRAY_RETRY_AFTER_SECONDS": "7"}
    srv = ServerProcess(tmp_path / "data", workers=0, env=env).start()
    try:
        with srv.client() as http:
            ids = [http.post("/v1/jobs", json=tiny_job(name=f"q{i}")).json()["id"] for i in range(2)]
            r = http.post("/v1/jobs", json=tiny_job(name="q2"))
            assert r.status_code == 429 and r.json()["error"] == "queue_full"
            assert r.headers["retry-after"] == "7"  # issue 15: a 429 says when to retry
            from bentray.clients.client import BentrayClient, ServiceError

            job_file = tmp_path / "q.json"
            job_file.write_text(json.dumps(tiny_job(name="qc")))
            with BentrayClient(srv.url) as client, pytest.raises(ServiceError) as info:
                client.submit(job_file)
            assert info.value.status == 429 and info.value.retry_after_s == 7.0
            assert len(http.get("/v1/jobs").json()["jobs"]) == 2
            # cancelling a queued job frees a place at once
            r = http.delete(f"/v1/jobs/{ids[0]}")
            assert r.status_code == 200 and r.json()["status"] == "cancelled"
            assert http.post("/v1/jobs", json=tiny_job(name="q3")).status_code == 202
    finally:
        srv.stop()


def test_scenes_health_and_openapi(keyed):
    with keyed.client(KEY_A) as a:
        health = a.get("/v1/health").json()
        assert health["status"] == "ok" and health["auth"] == "api-keys" and health["supervisor"] == "external"
        scenes = a.get("/v1/scenes").json()
        assert {"flat", "ridge"} <= {s["name"] for s in scenes}
        spec = a.get("/openapi.json").json()
        assert {
            "/v1/jobs",
            "/v1/jobs/{job_id}",
            "/v1/jobs/{job_id}/results/{name}",
            "/v1/assets",
            "/v1/scenes",
            "/v1/health",
        } <= set(spec["paths"])
        assert "Job" in spec["components"]["schemas"]
        assert a.get("/docs").status_code == 200


def test_no_key_server_refuses_public_bind(tmp_path):
    import subprocess
    import sys

    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "bentray.service",
            "serve",
            "--host",
            "0.0.0.0",
            "--port",
            "1",
            "--data-dir",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        env={k: v for k, v in __import__("os").environ.items() if not k.startswith("BENTRAY_")},
    )
    assert r.returncode == 2 and "binds 127.0.0.1 only" in r.stderr
    with pytest.raises(httpx.TransportError):
        httpx.get("http://127.0.0.1:1/v1/health", timeout=1.0)

"""Issue 15, the cost model's mesh-time estimate (scenes/cost.py): it grows with the cells a job asks
for, it is close to a real build, and a job over ``BENTRAY_MAX_MESH_SECONDS`` is refused with a 422
(service) or exit 2 (``bentray run``) naming the field, the estimate and the limit."""

from __future__ import annotations

import json

import pytest

from bentray.clients.cli import main
from bentray.engine.bench.mesh_time import _terrain_job, _tets_job, build_once
from bentray.scenes.cost import CostLimits, cost_problems, estimate_mesh
from bentray.scenes.schema import Job
from bentray.service.settings import Settings, SettingsError
from tests.hardening.conftest import HILL, base_job
from tests.service.conftest import ServerProcess


def _job(spec: dict) -> Job:
    return Job.model_validate(spec)


def _hill_job(d_max: float) -> dict:
    """hill.asc (5-40 m high) under a 1 km box, a source well above it, horizontal spacing d_max."""
    job = base_job()
    job["scene"] = {"domain": {"min": [-500, -500, 0], "max": [500, 500, 300]}, "terrain": {"file": "hill.asc"}}
    job["sources"] = [{"position": [0, 0, 80.0]}]
    job["solver"] = {"d_max_m": d_max, "d_min_m": 0.01}
    return job


def test_mesh_estimate_grows_with_the_cells_asked_for():
    tets = [estimate_mesh(_job(_tets_job(400.0, d))) for d in (40.0, 25.0, 16.0, 8.0)]
    assert all(e.mesher == "tets" and e.known for e in tets)
    assert all(a.cells < b.cells and a.seconds < b.seconds for a, b in zip(tets, tets[1:], strict=False))
    assert estimate_mesh(_job(_tets_job(800.0, 16.0))).cells > tets[2].cells  # a larger box at the same d
    terrain = [estimate_mesh(_job(_terrain_job(d))) for d in (None, 20.0, 14.0, 10.0)]
    assert all(e.mesher == "terrain" and e.known for e in terrain)
    assert all(a.cells < b.cells and a.seconds < b.seconds for a, b in zip(terrain, terrain[1:], strict=False))
    slabs = estimate_mesh(_job(base_job()))  # a stratified profile over flat ground: no 3D mesh
    assert slabs.mesher == "none" and slabs.seconds == 0.0
    hill = _job(_hill_job(5.0))
    assert not estimate_mesh(hill).known  # the terrain file is not at hand
    assert estimate_mesh(hill, HILL.parent).known and estimate_mesh(hill, HILL.parent).mesher == "terrain"


def test_mesh_estimate_is_close_to_a_real_build():
    spec = _tets_job(400.0, 25.0)
    rep, cells, _, _ = build_once(spec)
    est = estimate_mesh(_job(spec))
    assert rep == "tets" and 0.7 < est.cells / cells < 1.4, (est, cells)


def test_mesh_budget_in_cost_problems():
    limits = CostLimits(mesh_seconds=2.0)
    lines = cost_problems(_job(_tets_job(400.0, 8.0)), limits)
    assert len(lines) == 1 and lines[0].startswith("solver.d_min_m: the tets mesh needs an estimated ")
    assert " s to build at " in lines[0] and "the limit is 2 s" in lines[0]
    assert cost_problems(_job(_tets_job(400.0, 40.0)), limits) == []
    assert cost_problems(_job(_tets_job(400.0, 8.0)), CostLimits()) == []  # the default budget (600 s)


def test_mesh_budget_setting():
    assert Settings.from_env({"BENTRAY_MAX_MESH_SECONDS": "5"}).max_mesh_seconds == 5.0
    with pytest.raises(SettingsError, match="BENTRAY_MAX_MESH_SECONDS"):
        Settings.from_env({"BENTRAY_MAX_MESH_SECONDS": "-1"})


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    env = {"BENTRAY_MAX_MESH_SECONDS": "2"}
    srv = ServerProcess(tmp_path_factory.mktemp("mesh-budget") / "data", workers=0, env=env).start()
    yield srv
    srv.stop()


def test_mesh_budget_refusal_through_the_api(server):
    with server.client() as http:
        r = http.post("/v1/jobs", json=_tets_job(400.0, 8.0))
        body = r.json()
        assert r.status_code == 422 and body["error"] == "over_limit", r.text
        assert body["errors"][0]["field"] == "solver.d_min_m"
        assert "the tets mesh needs an estimated" in body["detail"] and "the limit is 2 s" in body["detail"]
        assert http.post("/v1/jobs", json=_tets_job(400.0, 40.0)).status_code == 202
        # a terrain file: estimated in the second stage, once the file is uploaded with the job
        r = http.post(
            "/v1/jobs",
            files=[
                ("job", ("job.json", json.dumps(_hill_job(2.0)).encode())),
                ("files", ("hill.asc", HILL.read_bytes())),
            ],
        )
        body = r.json()
        assert r.status_code == 422 and body["error"] == "over_limit", r.text
        assert body["errors"][0]["field"] == "solver.d_max_m" and "the terrain mesh needs" in body["detail"]
        assert str(server.data_dir) not in body["detail"]


def test_mesh_budget_refusal_through_the_cli(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("BENTRAY_MAX_MESH_SECONDS", "2")
    path = tmp_path / "job.json"
    path.write_text(json.dumps(_tets_job(400.0, 8.0)))
    rc = main(["run", str(path), "--out", str(tmp_path / "out"), "--check"])
    err = capsys.readouterr().err
    assert rc == 2 and "solver.d_min_m: the tets mesh needs an estimated" in err and "the limit is 2 s" in err
    path.write_text(json.dumps(_tets_job(400.0, 40.0)))
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--check"]) == 0

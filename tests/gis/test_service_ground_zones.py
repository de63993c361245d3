"""The service accepts ground-zone GeoJSON as the CLI does: as an asset (kind ground_zones) and uploaded
with a job (the field scene.ground_zones.file gives the kind), read with the engine's zone reader."""

from __future__ import annotations

import json

import pytest

from tests.service.conftest import ServerProcess, tiny_job

pytest.importorskip("httpx")
pytest.importorskip("shapely")
KEY = "zones-0123456789abcdef"


def _zones(ring) -> bytes:
    feats = [{"type": "Feature", "properties": {"G": 1.0, "name": "grass"},
              "geometry": {"type": "Polygon", "coordinates": [ring]}}]  # fmt: skip
    return json.dumps({"type": "FeatureCollection", "features": feats}).encode()


GOOD = _zones([[-400, -400], [400, -400], [400, 400], [-400, 400], [-400, -400]])
BOWTIE = _zones([[0, 0], [10, 10], [10, 0], [0, 10], [0, 0]])


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = ServerProcess(tmp_path_factory.mktemp("zones") / "data", workers=0, env={"BENTRAY_API_KEYS": KEY}).start()
    yield srv
    srv.stop()


def _job(name: str) -> dict:
    job = tiny_job(name=name)
    job["scene"] = {
        "domain": {"min": [-500, -500, 0], "max": [500, 500, 300]},
        "ground_zones": {"file": "zones.geojson"},
    }
    job["sources"] = [{"position": [0, 0, 40]}]
    return job


def test_ground_zone_asset_and_job_upload(server):
    with server.client(KEY) as c:
        r = c.post("/v1/assets", files={"file": ("zones.geojson", GOOD)}, data={"kind": "ground_zones"})
        assert r.status_code == 201, r.text
        assert r.json()["kind"] == "ground_zones"
        r = c.post("/v1/assets", files={"file": ("bad.geojson", BOWTIE)}, data={"kind": "ground_zones"})
        assert r.status_code == 422 and "features.0" in r.text and "Self-intersection" in r.text, r.text
        # a job naming the asset
        r = c.post("/v1/jobs", json=_job("zones-asset"))
        assert r.status_code == 202, r.text
        # a job uploading the zones with it: checked as ground zones (not as buildings, which need heights)
        files = [("job", (None, json.dumps(_job("zones-upload")))), ("files", ("zones.geojson", GOOD))]
        r = c.post("/v1/jobs", files=files)
        assert r.status_code == 202, r.text
        files = [("job", (None, json.dumps(_job("zones-bad")))), ("files", ("zones.geojson", BOWTIE))]
        r = c.post("/v1/jobs", files=files)
        assert r.status_code == 422 and "scene.ground_zones.file" in r.text and "Self-intersection" in r.text, r.text

"""A job in UTM coordinates (scene.crs): localised to metres near zero, run, and exported back into the CRS.

The same scene given in local metres (no CRS) must give the same field bit for bit (a pure translation of
every input by the local origin), and `bentray export` must place the GeoTIFF at the UTM coordinates."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from bentray.clients.cli import main
from bentray.engine.run import run_job
from bentray.engine.writers import write_outcome
from bentray.scenes.gis_frame import localise_job
from bentray.scenes.schema import Job

rasterio = pytest.importorskip("rasterio")

X0, Y0 = 500_000.0, 5_400_000.0  # the local origin the scene's lower-left corner (500 120, 5 400 080) rounds to

LOCAL = {
    "name": "utm",
    "scene": {
        "domain": {"min": [120, 80, 0], "max": [420, 280, 60]},
        "buildings": {"footprints": [{"polygon": [[260, 150], [300, 150], [300, 190], [260, 190]], "levels": 3}]},
    },
    "profile": {"kind": "homogeneous"},
    "sources": [{"position": [180, 170], "height_above_ground_m": 2.0, "power_db": {"500": 100.0}}],
    "rays": {
        "elevation_deg": {"min": -30, "max": 30, "count": 13},
        "azimuth_deg": {"min": -60, "max": 60, "count": 25},
        "max_time_s": 2.0,
        "max_reflections": 2,
    },  # fmt: skip
    "field": {"origin": [130, 90, 0.5], "spacing": [10, 10, 2], "shape": [28, 18, 5], "frequencies_hz": [500]},
    "outputs": ["field", "report"],
}


def _utm(data):
    out = copy.deepcopy(data)
    out["scene"]["crs"] = "EPSG:32632"
    d = out["scene"]["domain"]
    d["min"][:2] = [d["min"][0] + X0, d["min"][1] + Y0]
    d["max"][:2] = [d["max"][0] + X0, d["max"][1] + Y0]
    for fp in out["scene"]["buildings"]["footprints"]:
        fp["polygon"] = [[x + X0, y + Y0] for x, y in fp["polygon"]]
    for s in out["sources"]:
        s["position"] = [s["position"][0] + X0, s["position"][1] + Y0, *s["position"][2:]]
    out["field"]["origin"] = [out["field"]["origin"][0] + X0, out["field"]["origin"][1] + Y0, out["field"]["origin"][2]]
    return out


def test_localise_job_shifts_by_the_rounded_corner():
    job, frame = localise_job(Job.model_validate(_utm(LOCAL)))
    assert frame.origin == (X0, Y0) and frame.crs_wkt and "32N" in frame.crs_wkt
    assert job.scene.domain.min == (120.0, 80.0, 0.0) and job.sources[0].position == (180.0, 170.0)
    assert job.field.origin == (130.0, 90.0, 0.5) and job.scene.local_origin == (X0, Y0)
    same, identity = localise_job(Job.model_validate(LOCAL))
    assert identity.crs_wkt is None and same.scene.domain.min == (120, 80, 0)
    with pytest.raises(ValueError, match="scene.crs"):
        Job.model_validate({**LOCAL, "scene": {**LOCAL["scene"], "crs": 4326}})


def test_utm_job_matches_the_local_job_and_exports_into_the_crs(tmp_path):
    local = run_job(Job.model_validate(LOCAL))
    utm = run_job(Job.model_validate(_utm(LOCAL)))
    assert utm.report["georeference"]["local_origin"] == [X0, Y0]
    for name, arr in local.field.arrays.items():
        np.testing.assert_array_equal(utm.field.arrays[name], arr)
    write_outcome(utm, ["field", "report"], tmp_path / "r")
    assert json.loads((tmp_path / "r" / "report.json").read_text())["georeference"]["crs"].startswith("PROJCRS")
    assert main(["export", str(tmp_path / "r"), "--format", "geotiff", "--z", "4.5", "--array", "spl_a"]) == 0
    with rasterio.open(tmp_path / "r" / "export" / "map_spl_a.tif") as src:
        assert src.crs.to_epsg() == 32632
        x, y = src.transform @ (0.5, src.height - 0.5)  # centre of the south-west cell = node (0, 0)
        assert (x, y) == pytest.approx((X0 + 130.0, Y0 + 90.0), abs=1e-6)

"""``scene.buildings.barriers`` / ``barriers_file``: accepted input, and bad input refused naming the field
(pydantic errors through the CLI's formatter; domain checks as SceneSpecError; the service answers 422
with the same text)."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from bentray.scenes.scene_models import SceneSpecError, scene_surfaces
from bentray.scenes.schema import Job, format_validation_error
from bentray.scenes.terrain_io import SceneFileError

BASE: dict[str, Any] = {
    "name": "barrier",
    "scene": {
        "domain": {"min": [-50, -50, 0], "max": [200, 50, 60]},
        "ground": {"kind": "flat", "flow_resistivity": 2e5},
        "buildings": {"barriers": [{"polyline": [[0, -20], [0, 0], [2, 20]], "height_m": 4, "name": "wall"}]},
    },
    "profile": {"kind": "homogeneous"},
    "sources": [{"position": [-5, 0, 0.5]}],
    "rays": {
        "elevation_deg": {"min": -45, "max": 45, "count": 11},
        "azimuth_deg": {"min": 0, "max": 0, "count": 1},
        "max_time_s": 1,
        "max_reflections": 3,
    },
    "outputs": ["report"],
}


def _error(job: dict[str, Any], base_dir: Path | None = None) -> str:
    try:
        scene_surfaces(Job.model_validate(job).scene, base_dir)
    except ValidationError as exc:
        return format_validation_error(exc)
    except (SceneSpecError, SceneFileError) as exc:
        return str(exc)
    raise AssertionError("accepted")


def test_inline_barrier_read() -> None:
    surf = scene_surfaces(Job.model_validate(BASE).scene, None)
    assert surf is not None and len(surf.barriers) == 1
    b = surf.barriers[0]
    assert b.height_m == 4.0 and b.base_z == 0.0 and b.polyline.shape == (3, 2) and b.name == "wall"
    assert surf.footprints == []


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"height_m": 0}, "scene.buildings.barriers.0.height_m: Input should be greater than 0"),
        ({"height_m": -2}, "scene.buildings.barriers.0.height_m: Input should be greater than 0"),
        (
            {"polyline": [[0, 0], [10, 10], [10, 0], [0, 10]]},
            "scene.buildings.barriers.0: polyline: the polyline intersects itself at (5, 5)",
        ),
        ({"polyline": [[0, 0], [0, 0], [5, 5]]}, "scene.buildings.barriers.0: polyline: segment 0 has zero length"),
        ({"polyline": [[0, 0]]}, "scene.buildings.barriers.0.polyline: List should have at least 2 items"),
        ({"polyline": [[0, 0], [300, 0]]}, "scene.buildings.barriers.0 ('wall'): vertex (300, 0) is outside"),
        ({"height_m": 70}, "scene.buildings.barriers.0 ('wall'): the top at z = 70 m is not below the domain top"),
    ],
)
def test_bad_barrier_refused_with_field(change: dict[str, Any], expected: str) -> None:
    job = copy.deepcopy(BASE)
    job["scene"]["buildings"]["barriers"][0].update(change)
    assert _error(job).startswith(expected)


def test_geojson_barriers(tmp_path: Path) -> None:
    fc = {
        "type": "FeatureCollection",
        "features": [
            {"type": "Feature", "properties": {"height": 3.5, "name": "A"},
             "geometry": {"type": "LineString", "coordinates": [[10, -10], [10, 10]]}},
            {"type": "Feature", "properties": {"height": 2},
             "geometry": {"type": "MultiLineString", "coordinates": [[[20, 0], [30, 0]], [[20, 5], [30, 5]]]}},
        ],
    }  # fmt: skip
    (tmp_path / "walls.geojson").write_text(json.dumps(fc))
    job = copy.deepcopy(BASE)
    job["scene"]["buildings"] = {"barriers_file": "walls.geojson"}
    surf = scene_surfaces(Job.model_validate(job).scene, tmp_path)
    assert surf is not None and [b.height_m for b in surf.barriers] == [3.5, 2.0, 2.0]
    fc["features"][0]["properties"]["height"] = 0
    (tmp_path / "walls.geojson").write_text(json.dumps(fc))
    err = _error(job, tmp_path)
    assert err.startswith("scene.buildings.barriers_file: features.0:") and "greater than 0" in err
    fc["features"][0]["properties"]["height"] = 3
    fc["features"][0]["geometry"]["coordinates"] = [[10, -10], [10, 900]]
    (tmp_path / "walls.geojson").write_text(json.dumps(fc))
    assert _error(job, tmp_path).startswith("scene.buildings.barriers_file: 'A': vertex (10, 900) is outside")

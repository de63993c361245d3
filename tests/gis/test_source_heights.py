"""Sources by height above the ground: validated (exactly one of absolute z / height) and resolved against
the terrain (bilinear on a height grid) or the flat ground."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from bentray.engine.surfaces import HeightGrid, SceneSurfaces
from bentray.scenes.scene_models import SceneSpecError, resolve_source_heights
from bentray.scenes.schema import Job

BASE = {
    "name": "h",
    "scene": {"domain": {"min": [0, 0, 0], "max": [100, 100, 50]}},
    "profile": {"kind": "homogeneous"},
    "rays": {"elevation_deg": {"min": -10, "max": 10, "count": 3}, "max_time_s": 1.0, "max_reflections": 2},
}


def _job(*sources):
    return Job.model_validate({**BASE, "sources": list(sources)})


def test_exactly_one_of_z_and_height():
    with pytest.raises(ValidationError, match="exactly one"):
        _job({"position": [10, 10, 2], "height_above_ground_m": 1.5})
    with pytest.raises(ValidationError, match="exactly one"):
        _job({"position": [10, 10]})
    with pytest.raises(ValidationError, match="greater than 0"):
        _job({"position": [10, 10], "height_above_ground_m": 0})
    with pytest.raises(ValidationError, match="not strictly inside the domain"):
        _job({"position": [150, 10], "height_above_ground_m": 1})


def test_resolved_against_terrain_and_flat_ground():
    job = _job({"position": [10, 10, 2]}, {"position": [30.5, 42.25], "height_above_ground_m": 4.0})
    flat = resolve_source_heights(job, None)
    assert flat.sources[0].position == (10, 10, 2) and flat.sources[1].position == (30.5, 42.25, 4.0)
    x = np.linspace(-10, 110, 13)
    gx, gy = np.meshgrid(x, x)
    grid = HeightGrid(x, x, 5.0 + 0.1 * gx - 0.05 * gy)  # a plane: bilinear is exact
    out = resolve_source_heights(job, SceneSurfaces(terrain=grid))
    assert out.sources[1].position[2] == pytest.approx(5.0 + 3.05 - 2.1125 + 4.0, abs=1e-12)
    assert out.sources[0] is job.sources[0] and resolve_source_heights(out, None) is out
    small = HeightGrid(np.array([0.0, 20.0]), np.array([0.0, 20.0]), np.zeros((2, 2)))
    with pytest.raises(SceneSpecError, match=r"sources\.1\.position: \(30.5, 42.25\) is outside the terrain"):
        resolve_source_heights(job, SceneSurfaces(terrain=small))

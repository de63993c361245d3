"""A building with a courtyard (GeoJSON hole) and a MultiPolygon meshed by the terrain-following mesher:
the air volume is exact, the courtyard is air, the solid ring is not, and a ray fan inside the courtyard
reflects off the courtyard wall as the mirror image (sound is blocked)."""

from __future__ import annotations

import json

import bentray  # noqa: F401  # isort: skip
import numpy as np
import pytest

from bentray.engine.constants import STATUS_REFLECTION_LIMIT
from bentray.engine.mesh.terrain import build_terrain_mesh, locate_in_terrain_mesh
from bentray.engine.surfaces import SceneSurfaces
from bentray.engine.tracer import trace
from bentray.scenes.terrain_io import read_footprints_geojson

LO = np.array([0.0, 0.0, 0.0])
HI = np.array([200.0, 160.0, 60.0])
ROOF = 15.0


def _rect(x, y, w, h):
    return [[x, y], [x + w, y], [x + w, y + h], [x, y + h], [x, y]]


@pytest.fixture(scope="module")
def courtyard_mesh(tmp_path_factory):
    path = tmp_path_factory.mktemp("yard") / "b.geojson"
    features = [
        {"type": "Feature", "properties": {"height": ROOF},
         "geometry": {"type": "Polygon", "coordinates": [_rect(40, 40, 80, 80), _rect(60, 60, 40, 40)]}},
        {"type": "Feature", "properties": {"height": 6.0},
         "geometry": {"type": "MultiPolygon", "coordinates": [[_rect(150, 20, 20, 20)], [_rect(150, 100, 20, 20)]]}},
    ]  # fmt: skip
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    fps = read_footprints_geojson(path)
    assert len(fps) == 3 and len(fps[0].holes) == 1
    tm = build_terrain_mesh(SceneSurfaces(footprints=fps), LO, HI, lambda p: np.ones(len(p)),
                            horizontal_spacing=8.0, vertical_spacing=3.0)  # fmt: skip
    return tm


def test_volume_is_box_minus_solids(courtyard_mesh):
    tm = courtyard_mesh
    solid = (80 * 80 - 40 * 40) * ROOF + 2 * 20 * 20 * 6.0
    p = tm.points[tm.tets]
    volume = np.sum(np.linalg.det(p[:, 1:] - p[:, :1])) / 6.0
    assert volume == pytest.approx(np.prod(HI - LO) - solid, rel=1e-12)
    assert [r["roof_z"] for r in tm.stats["roofs"]] == [ROOF, 6.0, 6.0]


def test_courtyard_is_air_and_the_ring_is_solid(courtyard_mesh):
    pts = np.array([[80.0, 80.0, 5.0], [50.0, 80.0, 5.0], [80.0, 110.0, 5.0], [50.0, 80.0, ROOF + 2.0]])
    cells = locate_in_terrain_mesh(courtyard_mesh, pts)
    assert cells[0] >= 0 and cells[3] >= 0  # courtyard air, above the roof
    assert cells[1] < 0 and cells[2] < 0  # inside the solid ring


def test_rays_reflect_off_the_courtyard_wall(courtyard_mesh):
    src = np.array([80.0, 80.0, 5.0])
    el, az = np.meshgrid(np.radians(np.linspace(-5, 5, 5)), np.radians(np.linspace(-30, 30, 7)))
    d = np.column_stack([np.cos(el.ravel()) * np.cos(az.ravel()), np.cos(el.ravel()) * np.sin(az.ravel()),
                         np.sin(el.ravel())])  # fmt: skip
    orig = np.tile(src, (len(d), 1))
    cells = locate_in_terrain_mesh(courtyard_mesh, orig)
    r = trace(courtyard_mesh.cells, "parabolic", 340.0, orig, d, cells, max_time_s=5.0, max_reflections=0)
    assert np.all(r.status == STATUS_REFLECTION_LIMIT)
    u = (100.0 - src[0]) / d[:, 0]  # the courtyard's east wall x = 100
    np.testing.assert_allclose(r.position, src + u[:, None] * d, rtol=0, atol=1e-9 * 200)

"""Footprints on shapely: UTM coordinates, holes, MultiPolygons, building:levels, validity reasons with the
feature index, non-finite / huge coordinates refused quickly, overlaps via STRtree."""

from __future__ import annotations

import json
import time
from types import SimpleNamespace

import numpy as np
import pytest

from bentray.scenes.geometry import box_pairs
from bentray.scenes.gis_geometry import footprint_polygon, polygon_from_rings
from bentray.scenes.scene_models import BuildingsSpec, FootprintSpec, SceneSpecError, surfaces_from_specs
from bentray.scenes.terrain_io import SceneFileError, read_footprints_geojson

X0, Y0 = 500_000.0, 5_400_000.0  # UTM zone 32N easting / northing, metres


def _write(path, features):
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    return path


def _feature(geometry, **props):
    return {"type": "Feature", "properties": props, "geometry": geometry}


def _rect(x, y, w, h):
    return [[x, y], [x + w, y], [x + w, y + h], [x, y + h], [x, y]]


def test_utm_building_is_accepted_with_its_area(tmp_path):
    path = _write(
        tmp_path / "b.geojson", [_feature({"type": "Polygon", "coordinates": [_rect(X0, Y0, 60, 30)]}, height=9)]
    )
    (fp,) = read_footprints_geojson(path)
    assert footprint_polygon(fp).area == pytest.approx(1800.0, rel=1e-12)
    # inline too, and through the domain checks of a UTM-placed domain
    spec = BuildingsSpec(footprints=[FootprintSpec(polygon=_rect(X0, Y0, 60, 30)[:-1], height_m=9)])
    domain = SimpleNamespace(min=(X0 - 100, Y0 - 100, 0.0), max=(X0 + 200, Y0 + 200, 100.0))
    surfaces = surfaces_from_specs(None, spec, [], tmp_path, domain)
    assert footprint_polygon(surfaces.footprints[0]).area == pytest.approx(1800.0, rel=1e-12)


def test_thin_barrier_far_from_the_origin_is_not_zero_area():
    poly, problem = polygon_from_rings(_rect(X0, Y0, 300.0, 0.2)[:-1])
    assert problem is None and poly.area == pytest.approx(60.0, rel=1e-9)
    _, problem = polygon_from_rings([[X0, Y0], [X0 + 5, Y0], [X0 + 10, Y0]])
    assert "zero area" in problem


def test_invalid_polygon_names_the_feature_and_shapely_reason(tmp_path):
    good = _feature({"type": "Polygon", "coordinates": [_rect(0, 0, 5, 5)]}, height=5)
    bow = _feature({"type": "Polygon", "coordinates": [[[20, 0], [30, 10], [30, 0], [20, 10], [20, 0]]]}, height=5)
    path = _write(tmp_path / "b.geojson", [good] * 7 + [bow])
    with pytest.raises(SceneFileError, match=r"b\.geojson: features\.7: Self-intersection at \(25, 5\)"):
        read_footprints_geojson(path)


def test_holes_multipolygons_and_levels(tmp_path):
    courtyard = {"type": "Polygon", "coordinates": [_rect(0, 0, 40, 40), _rect(10, 10, 20, 20)]}
    two = {"type": "MultiPolygon", "coordinates": [[_rect(100, 0, 10, 10)], [_rect(120, 0, 10, 10)]]}
    path = _write(
        tmp_path / "b.geojson",
        [
            _feature(courtyard, **{"building:levels": 4}),
            _feature(two, height="7.5 m", name="pair"),
        ],
    )
    fps = read_footprints_geojson(path, storey_height_m=3.0)
    assert [fp.name for fp in fps] == ["feature 0", "pair part 0", "pair part 1"]
    assert fps[0].height_m == 12.0 and fps[1].height_m == 7.5
    assert len(fps[0].holes) == 1 and footprint_polygon(fps[0]).area == pytest.approx(1600 - 400, rel=1e-12)
    ring = fps[0].holes[0]  # holes clockwise, exterior counter-clockwise, not closed
    assert len(ring) == 4 and polygon_from_rings(ring)[0].exterior.is_ccw
    x, y = ring[:, 0], ring[:, 1]
    assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) < 0


@pytest.mark.parametrize(
    ("geometry", "reason"),
    [
        ({"type": "Polygon", "coordinates": [_rect(0, 0, 40, 40), _rect(50, 10, 5, 5)]}, "Hole lies outside shell"),
        (
            {"type": "MultiPolygon", "coordinates": [[_rect(0, 0, 10, 10)], [_rect(5, 5, 10, 10)]]},
            "MultiPolygon parts 0 and 1 overlap",
        ),
        (
            {"type": "Polygon", "coordinates": [[[0, 0], [1e308, 0], [1e308, 1e308], [0, 0]]]},
            r"coordinate 1e\+308 m exceeds 1e\+09 m",
        ),
    ],
)
def test_geometry_errors(tmp_path, geometry, reason):
    path = _write(tmp_path / "b.geojson", [_feature(geometry, height=5)])
    t0 = time.perf_counter()
    with pytest.raises(SceneFileError, match=reason):
        read_footprints_geojson(path)
    assert time.perf_counter() - t0 < 2.0


def test_levels_or_height_exactly_one():
    with pytest.raises(ValueError, match="exactly one of height_m"):
        FootprintSpec(polygon=_rect(0, 0, 5, 5)[:-1], height_m=5, levels=2)
    spec = BuildingsSpec(footprints=[FootprintSpec(polygon=_rect(0, 0, 5, 5)[:-1], levels=3)], storey_height_m=2.5)
    assert spec.footprints[0].height(spec.storey_height_m) == 7.5


def test_box_pairs_refuses_huge_coordinates_quickly():
    lo = np.array([[-1e308, 0.0], [1e308, 1e308]])
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match="finite and at most"):
        box_pairs(lo, lo + 1)
    with pytest.raises(ValueError, match="finite"):
        box_pairs(np.array([[np.nan, 0.0]]), np.array([[1.0, 1.0]]))
    assert time.perf_counter() - t0 < 1.0


def test_overlapping_footprints_in_utm_are_reported(tmp_path):
    spec = BuildingsSpec(
        footprints=[
            FootprintSpec(polygon=_rect(X0, Y0, 20, 20)[:-1], height_m=5, name="a"),
            FootprintSpec(polygon=_rect(X0 + 20, Y0, 20, 20)[:-1], height_m=5, name="touching"),
            FootprintSpec(polygon=_rect(X0 + 10, Y0 + 10, 20, 20)[:-1], height_m=5, name="over"),
        ]
    )
    domain = SimpleNamespace(min=(X0 - 100, Y0 - 100, 0.0), max=(X0 + 200, Y0 + 200, 100.0))
    with pytest.raises(SceneSpecError) as info:
        surfaces_from_specs(None, spec, [], tmp_path, domain)
    lines = str(info.value).splitlines()
    assert len(lines) == 2 and all("overlaps" in line and "'over'" in line for line in lines)

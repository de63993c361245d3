"""Scene-surface job models: validation messages, surfaces_from_specs (files + inline footprints -> SceneSurfaces)
with every cross-check naming its job field, and the above-ground / inside-building test for points."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from pydantic import ValidationError

from bentray.engine.surfaces import Footprint, HeightGrid, SceneSurfaces, TriangleSurface
from bentray.scenes.scene_models import (
    BuildingsSpec,
    FootprintSpec,
    MaterialSpec,
    SceneSpecError,
    TerrainSpec,
    check_points_above_ground,
    footprint_base_z,
    surfaces_from_specs,
)
from bentray.scenes.terrain_io import SceneFileError

EXAMPLES = Path(__file__).resolve().parents[2] / "scenes" / "examples"
DOMAIN = SimpleNamespace(min=(-500.0, -500.0, 0.0), max=(500.0, 500.0, 300.0))


def _invalid(model, data: dict, reason: str) -> None:
    with pytest.raises(ValidationError) as info:
        model.model_validate(data)
    assert reason in str(info.value), str(info.value)


@pytest.mark.parametrize(
    ("model", "data", "reason"),
    [
        (TerrainSpec, {"file": "t.npy"}, "a .npy terrain holds heights only: give origin"),
        (TerrainSpec, {"file": "t.asc", "origin": [0, 0]}, "origin only apply to .npy terrain"),
        (TerrainSpec, {"file": "t.tif"}, "cannot tell the terrain format from 't.tif'"),
        (TerrainSpec, {"file": "t.npy", "origin": [0, 0], "spacing": [1, 0]}, "spacing must be > 0"),
        (TerrainSpec, {"file": "t.asc", "origin": [0, float("nan")]}, "finite number"),
        (TerrainSpec, {"file": "t.asc", "colour": "green"}, "Extra inputs are not permitted"),
        (FootprintSpec, {"polygon": [[0, 0], [1, 1], [1, 0], [0, 1]], "height_m": 5}, "Self-intersection at (0.5"),
        (FootprintSpec, {"polygon": [[0, 0], [1, 1]], "height_m": 5}, "at least 3 items"),
        (FootprintSpec, {"polygon": [[0, 0], [1, 0], [0, 1]], "height_m": 1000}, "less than 1000"),
        (MaterialSpec, {"name": "rigid", "flow_resistivity": None}, "'rigid' is built in"),
        (MaterialSpec, {"name": "grass", "flow_resistivity": 0}, "greater than 0"),
        (MaterialSpec, {"name": "grass"}, "Field required"),
        (BuildingsSpec, {}, "give a GeoJSON file, footprints or obstacles"),
        (BuildingsSpec, {"file": "b.shp"}, "buildings file must be GeoJSON"),
    ],
)
def test_model_validation_messages(model, data, reason):
    _invalid(model, data, reason)


def test_valid_models():
    assert TerrainSpec(file="ground.dat", format="asc").effective_format == "asc"
    assert TerrainSpec(file="h.NPY", origin=(0, 0), spacing=(1, 2)).effective_format == "npy"
    assert FootprintSpec(polygon=[(0, 0), (0, 1), (1, 1), (1, 0), (0, 0)], height_m=3).polygon[0] == (0, 0)


def _specs(**buildings):
    terrain = TerrainSpec(file="hill.asc", material="grass")
    materials = [MaterialSpec(name="grass", flow_resistivity=2e5), MaterialSpec(name="brick", flow_resistivity=None)]
    return terrain, BuildingsSpec(file="buildings.geojson", **buildings), materials


def test_surfaces_from_example_files():
    terrain, buildings, materials = _specs(
        footprints=[
            FootprintSpec(polygon=[(100, 100), (100, 120), (130, 120), (130, 100)], height_m=8, material="brick")
        ]
    )
    surfaces = surfaces_from_specs(terrain, buildings, materials, EXAMPLES, DOMAIN)
    assert isinstance(surfaces.terrain, HeightGrid) and surfaces.terrain.default_material == 1
    assert [m.name for m in surfaces.materials] == ["rigid", "grass", "brick"]
    assert [fp.name for fp in surfaces.footprints] == ["barn", "farmhouse", "noise barrier", "footprint 0"]
    inline = surfaces.footprints[3]
    assert inline.material == 2 and inline.height_m == 8.0
    np.testing.assert_array_equal(inline.polygon, [[130, 100], [130, 120], [100, 120], [100, 100]])  # made CCW


def _spec_error(exc_type, terrain, buildings, materials, reason: str, domain=DOMAIN, base_dir=EXAMPLES) -> str:
    with pytest.raises(exc_type) as info:
        surfaces_from_specs(terrain, buildings, materials, base_dir, domain)
    assert reason in str(info.value), str(info.value)
    return str(info.value)


def test_terrain_must_cover_the_domain_and_stay_inside_it():
    terrain, _, materials = _specs()
    wide = SimpleNamespace(min=(-600.0, -500.0, 0.0), max=(500.0, 500.0, 300.0))
    _spec_error(
        SceneSpecError,
        terrain,
        None,
        materials,
        "scene.terrain.file: the terrain covers x -500..500, y -500..500 m "
        "but the domain's xy box is x -600..500, y -500..500 m",
        domain=wide,
    )
    low = SimpleNamespace(min=(-500.0, -500.0, 0.0), max=(500.0, 500.0, 20.0))
    _spec_error(SceneSpecError, terrain, None, materials, "scene.terrain.file: the terrain reaches z = 35", domain=low)
    high = SimpleNamespace(min=(-500.0, -500.0, 6.0), max=(500.0, 500.0, 300.0))
    _spec_error(SceneSpecError, terrain, None, materials, "below the domain bottom (min z = 6 m)", domain=high)


def test_file_errors_are_prefixed_with_the_field(tmp_path):
    _, _, materials = _specs()
    text = _spec_error(SceneFileError, TerrainSpec(file="missing.asc"), None, materials, "scene.terrain.file: ")
    assert text.endswith("missing.asc: file not found")
    (tmp_path / "b.geojson").write_text(
        json.dumps(
            {
                "type": "FeatureCollection",
                "features": [
                    {
                        "type": "Feature",
                        "properties": {"height": 5, "material": "glass"},
                        "geometry": {"type": "Polygon", "coordinates": [[[0, 0], [5, 0], [0, 5]]]},
                    }
                ],
            }
        )
    )
    _spec_error(
        SceneFileError, None, BuildingsSpec(file="b.geojson"), materials, "scene.buildings.file: ", base_dir=tmp_path
    )
    _spec_error(
        SceneFileError,
        None,
        BuildingsSpec(file="b.geojson"),
        materials,
        "features.0: material 'glass' is not defined in scene.materials (defined: rigid, grass, brick)",
        base_dir=tmp_path,
    )


def test_material_references():
    terrain, buildings, materials = _specs()
    _spec_error(
        SceneSpecError,
        TerrainSpec(file="hill.asc", material="sand"),
        None,
        materials,
        "scene.terrain.material: material 'sand' is not defined (rigid, grass, brick)",
    )
    inline = BuildingsSpec(footprints=[FootprintSpec(polygon=[(0, 0), (5, 0), (0, 5)], height_m=3, material="wood")])
    _spec_error(SceneSpecError, None, inline, materials, "scene.buildings.footprints.0.material: material 'wood'")
    twice = [*materials, MaterialSpec(name="grass", flow_resistivity=1e5)]
    _spec_error(SceneSpecError, terrain, None, twice, "scene.materials.2.name: duplicate material name 'grass'")


def test_buildings_outside_overlapping_or_too_tall():
    terrain, _, materials = _specs()
    outside = FootprintSpec(polygon=[(480, 0), (520, 0), (520, 20)], height_m=5, name="shed")
    _spec_error(
        SceneSpecError,
        terrain,
        BuildingsSpec(footprints=[outside]),
        materials,
        "scene.buildings.footprints.0 ('shed'): vertex (520, 0) is outside the domain's xy box",
    )
    on_barn = FootprintSpec(polygon=[(-200, 150), (-150, 150), (-150, 170)], height_m=5)
    _spec_error(
        SceneSpecError,
        terrain,
        BuildingsSpec(file="buildings.geojson", footprints=[on_barn]),
        materials,
        "scene.buildings.file: 'barn' overlaps scene.buildings.footprints.0",
    )
    beside = FootprintSpec(polygon=[(-185, 150), (-150, 150), (-150, 170), (-185, 170)], height_m=5)  # shares a wall
    surfaces_from_specs(
        terrain, BuildingsSpec(file="buildings.geojson", footprints=[beside]), materials, EXAMPLES, DOMAIN
    )
    tower = FootprintSpec(polygon=[(0, 0), (10, 0), (0, 10)], height_m=290)
    _spec_error(
        SceneSpecError,
        terrain,
        BuildingsSpec(footprints=[tower]),
        materials,
        "scene.buildings.footprints.0: the roof at z = 3",
    )


def test_obstacle_outside_domain(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    box = trimesh.creation.box(extents=(10, 10, 10))
    box.apply_translation((495, 0, 50))
    box.export(tmp_path / "box.stl")
    spec = BuildingsSpec(obstacles=[{"file": "box.stl"}])
    _spec_error(
        SceneSpecError,
        None,
        spec,
        [],
        "scene.buildings.obstacles.0.file: 4 vertices lie outside the domain",
        base_dir=tmp_path,
    )


def test_triangle_terrain_with_a_hole(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    g = np.linspace(-500, 500, 11)
    xx, yy = np.meshgrid(g, g)
    v = np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, 2.0)])
    quads = [(i * 11 + j, i * 11 + j + 1, (i + 1) * 11 + j + 1, (i + 1) * 11 + j) for i in range(10) for j in range(10)]
    faces = [f for k, (a, b, c, d) in enumerate(quads) if k != 55 for f in ((a, b, c), (a, c, d))]  # one missing
    trimesh.Trimesh(v, np.array(faces), process=False).export(tmp_path / "holey.ply")
    _spec_error(
        SceneSpecError,
        TerrainSpec(file="holey.ply"),
        None,
        [],
        "scene.terrain.file: the terrain mesh has a hole over the domain",
        base_dir=tmp_path,
    )


def test_footprint_base_is_lowest_terrain_under_polygon():
    x, y = np.linspace(0, 100, 11), np.linspace(0, 50, 6)
    xx, yy = np.meshgrid(x, y)
    grid = HeightGrid(x=x, y=y, z=0.1 * xx - 0.05 * yy + 3.0)  # a plane: bilinear reproduces it exactly
    poly = np.array([[12.0, 7.0], [41.0, 9.0], [33.0, 44.0]])
    base = footprint_base_z(grid, Footprint(poly, 5.0), flat_z=0.0)
    assert base == pytest.approx(min(0.1 * px - 0.05 * py + 3.0 for px, py in poly), abs=1e-12)
    assert footprint_base_z(grid, Footprint(poly, 5.0, base_z=-1.5), flat_z=0.0) == -1.5
    assert footprint_base_z(None, Footprint(poly, 5.0), flat_z=2.0) == 2.0


def test_points_above_ground_inside_buildings_and_obstacles():
    terrain, buildings, materials = _specs()
    surfaces = surfaces_from_specs(terrain, buildings, materials, EXAMPLES, DOMAIN)
    ground = surfaces.terrain.z[10, 10]  # the node at x = 0, y = 0
    barn = surfaces.footprints[0]
    barn_base = footprint_base_z(surfaces.terrain, barn, 0.0)
    points = [
        (0, 0, ground + 1.5),
        (0, 0, ground - 3.2),
        (-200, 150, barn_base + 4),
        (-200, 150, barn_base + 9.5),
        (600, 0, 10),
    ]
    names = [f"sources.{i}.position" for i in range(len(points))]
    with pytest.raises(SceneSpecError) as info:
        check_points_above_ground(surfaces, points, names)
    lines = str(info.value).splitlines()
    assert (
        lines[0]
        == f"sources.1.position: (0, 0, {ground - 3.2:g}) is 3.2 m below the ground (ground at z = {ground:g} m)"
    )
    assert (
        lines[1].startswith("sources.2.position: (-200, 150, ")
        and "is inside building 'barn' (roof at z = " in lines[1]
    )
    assert lines[2] == "sources.4.position: (600, 0, 10) is outside the terrain's xy extent"
    assert len(lines) == 3
    check_points_above_ground(surfaces, points[:1], names[:1])  # no error
    flat = SceneSurfaces()
    with pytest.raises(
        SceneSpecError, match=r"receivers.0: \(1, 2, -1\) is 1 m below the ground \(ground at z = 0 m\)"
    ):
        check_points_above_ground(flat, [(1, 2, -1)], ["receivers.0"], flat_ground_z=0.0)
    with pytest.raises(SceneSpecError, match="is on the ground"):
        check_points_above_ground(flat, [(1, 2, 0)], ["receivers.0"], flat_ground_z=0.0)
    check_points_above_ground(flat, [(1, 2, -1)], ["receivers.0"])  # no flat ground given: no ground test


def test_point_inside_obstacle():
    trimesh = pytest.importorskip("trimesh")
    box = trimesh.creation.box(extents=(10, 10, 10))
    box.apply_translation((0, 0, 20))
    surfaces = SceneSurfaces(obstacles=[(np.asarray(box.vertices), np.asarray(box.faces))])
    pts = [(0, 0, 20), (4.9, -4.9, 24.9), (0, 0, 25.1), (6, 0, 20)]
    with pytest.raises(SceneSpecError) as info:
        check_points_above_ground(surfaces, pts, ["a", "b", "c", "d"], flat_ground_z=0.0)
    assert str(info.value).splitlines() == [
        "a: (0, 0, 20) is inside obstacle 0",
        "b: (4.9, -4.9, 24.9) is inside obstacle 0",
    ]
    with pytest.raises(ValueError, match="2 points but 1 names"):
        check_points_above_ground(surfaces, pts[:2], ["a"])


def test_triangle_terrain_ground_lookup():
    v = np.array([[-1.0, -1, 0], [1, -1, 2], [1, 1, 4], [-1, 1, 2]])
    surface = TriangleSurface(vertices=v, triangles=np.array([[0, 1, 2], [0, 2, 3]]))
    # the plane z = x + y + 2 through all four corners
    with pytest.raises(SceneSpecError, match=r"p: \(0.5, 0.25, 2\) is 0.75 m below the ground"):
        check_points_above_ground(SceneSurfaces(terrain=surface), [(0.5, 0.25, 2.0)], ["p"])

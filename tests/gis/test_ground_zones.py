"""Ground zones: the CNOSSOS G -> flow resistivity mapping at its table points, zones read from GeoJSON and
inline, and every ground face of the terrain mesh carrying the material of the zone under its centroid."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from bentray.engine.constants import BOUNDARY_REFLECT
from bentray.engine.mesh.terrain import build_terrain_mesh
from bentray.engine.surfaces import HeightGrid
from bentray.scenes.ground_zones import GroundZonesSpec, flow_resistivity_from_g
from bentray.scenes.scene_models import MaterialSpec, SceneSpecError, TerrainSpec, surfaces_from_specs

shapely = pytest.importorskip("shapely")


def test_g_mapping_hits_the_cnossos_classes():
    for g, sigma in [(0.0, 2e7), (0.3, 2e6), (0.7, 5e5), (1.0, 2e5)]:
        assert flow_resistivity_from_g(g) == pytest.approx(sigma, rel=1e-12)
    # log-linear between points: G = 0.15 is the geometric mean of 2e7 and 2e6
    assert flow_resistivity_from_g(0.15) == pytest.approx(math.sqrt(2e7 * 2e6), rel=1e-12)
    values = [flow_resistivity_from_g(g) for g in np.linspace(0, 1, 21)]
    assert all(b < a for a, b in zip(values, values[1:], strict=False))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        flow_resistivity_from_g(1.2)


def _rect(x, y, w, h):
    return [[x, y], [x + w, y], [x + w, y + h], [x, y + h]]


def test_ground_faces_take_their_zone_material(tmp_path):
    zones_file = tmp_path / "zones.geojson"
    feats = [
        {"type": "Feature", "properties": {"G": 1.0, "name": "meadow"},
         "geometry": {"type": "Polygon", "coordinates": [_rect(0, 0, 100, 160) + [[0, 0]]]}},
        {"type": "Feature", "properties": {"material": "water"},
         "geometry": {"type": "Polygon", "coordinates": [_rect(120, 20, 60, 60) + [[120, 20]],
                                                         _rect(140, 40, 20, 20) + [[140, 40]]]}},
    ]  # fmt: skip
    zones_file.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    spec = GroundZonesSpec(
        file="zones.geojson",
        zones=[{"polygon": _rect(50, 100, 30, 30), "flow_resistivity": 2e4}],  # painted over the meadow
    )
    np.save(tmp_path / "t.npy", np.zeros((12, 12)))
    terrain = TerrainSpec(file="t.npy", origin=(-10, -10), spacing=(20, 20), material="asphalt")
    materials = [MaterialSpec(name="asphalt", flow_resistivity=2e7), MaterialSpec(name="water", flow_resistivity=None)]
    domain = SimpleNamespace(min=(0.0, 0.0, -1.0), max=(200.0, 160.0, 40.0))
    surfaces = surfaces_from_specs(terrain, None, materials, tmp_path, domain, ground_zones=spec)
    table = {m.name: (i, m.flow_resistivity) for i, m in enumerate(surfaces.materials)}
    sigma = {i: s for i, s in table.values()}
    assert len(surfaces.ground_zones) == 3 and isinstance(surfaces.terrain, HeightGrid)
    tm = build_terrain_mesh(surfaces, domain.min, domain.max, lambda p: np.ones(len(p)),
                            horizontal_spacing=6.0, vertical_spacing=8.0)  # fmt: skip
    cells = tm.cells
    c, f = np.nonzero(cells.neighbours == BOUNDARY_REFLECT)
    fv = tm.points[tm.tets[c]]  # (n, 4, 3)
    mask = np.ones((len(c), 4), dtype=bool)
    mask[np.arange(len(c)), f] = False  # face f is opposite vertex f
    tri = fv[mask].reshape(len(c), 3, 3)
    ground = np.all(np.abs(tri[:, :, 2]) < 1e-9, axis=1)  # the flat terrain at z = 0
    cen = tri[ground].mean(axis=1)[:, :2]
    mat = cells.face_material[c[ground], f[ground]]

    def expect(p):
        if shapely.Polygon(_rect(50, 100, 30, 30)).intersects(shapely.Point(p)):
            return 2e4
        yard = shapely.Polygon(_rect(120, 20, 60, 60), [_rect(140, 40, 20, 20)])
        if yard.intersects(shapely.Point(p)):
            return None  # water: the material's (rigid) flow resistivity
        if shapely.Polygon(_rect(0, 0, 100, 160)).intersects(shapely.Point(p)):
            return flow_resistivity_from_g(1.0)  # G = 1 (2e5 up to rounding)
        return 2e7  # the terrain's asphalt

    # a centroid exactly on a zone edge may take either side (the crossing test is ambiguous there): skip those
    rects = [(50, 100, 30, 30), (120, 20, 60, 60), (140, 40, 20, 20), (0, 0, 100, 160)]
    edges = shapely.union_all([shapely.Polygon(_rect(*r)).boundary for r in rects])
    clear = ~shapely.dwithin(edges, shapely.points(cen), 1e-9)
    assert np.count_nonzero(~clear) < 0.1 * len(cen)
    got = [sigma[int(m)] for m in mat[clear]]
    want = [expect(p) for p in cen[clear]]
    bad = [(cen[clear][k], got[k], want[k]) for k in range(len(got)) if got[k] != want[k]]
    assert len(cen) > 500 and not bad, bad[:5]
    assert set(got) == {2e4, None, flow_resistivity_from_g(1.0), 2e7}


def test_zone_errors(tmp_path):
    with pytest.raises(ValueError, match="exactly one of flow_resistivity"):
        GroundZonesSpec(zones=[{"polygon": _rect(0, 0, 5, 5), "G": 0.5, "flow_resistivity": 1e5}])
    with pytest.raises(ValueError, match="Self-intersection"):
        GroundZonesSpec(zones=[{"polygon": [[0, 0], [5, 5], [5, 0], [0, 5]], "G": 0.5}])
    spec = GroundZonesSpec(zones=[{"polygon": _rect(0, 0, 5, 5), "material": "moss"}])
    domain = SimpleNamespace(min=(0.0, 0.0, 0.0), max=(10.0, 10.0, 10.0))
    with pytest.raises(SceneSpecError, match=r"scene.ground_zones: zones.0: material 'moss' is not defined"):
        surfaces_from_specs(None, None, [], tmp_path, domain, ground_zones=spec)


def test_zone_errors_are_found_at_submit(tmp_path):
    """The submit-time scene checks (service and ``bentray run --check``) read the ground zones as the job
    will: an undefined zone material is a ``scene.ground_zones`` problem before any worker runs."""
    from bentray.scenes.job_checks import scene_problems
    from bentray.scenes.schema import Job

    job = Job.model_validate(
        {
            "name": "zones",
            "scene": {
                "domain": {"min": [0, 0, 0], "max": [10, 10, 10]},
                "ground": {"kind": "flat"},
                "ground_zones": {"zones": [{"polygon": _rect(0, 0, 5, 5), "material": "moss"}]},
            },
            "profile": {"kind": "homogeneous", "c0": 340.0},
            "sources": [{"position": [5.0, 5.0, 2.0]}],
            "rays": {"elevation_deg": {"min": -5, "max": 5, "count": 3}, "max_time_s": 0.1, "max_reflections": 2},
            "outputs": ["report"],
        }
    )
    problems = scene_problems(job, tmp_path)
    assert any("scene.ground_zones" in p and "moss" in p for p in problems), problems

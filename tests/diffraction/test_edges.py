"""Scene edges (engine/diffraction/edges.py): wedge frames of barriers, roof edges and corners (air in
0 <= phi <= n pi, the solid beyond), terrain crests past the threshold, and the submit-time check that
the service answers with 422 (scenes/job_checks.scene_problems) naming a barrier outside the domain."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from bentray.engine.constants import TERRAIN_CREST_MIN_DEG
from bentray.engine.diffraction.edges import EDGE_CORNER, EDGE_ROOF, scene_edges, terrain_crests
from bentray.engine.diffraction.wedge import cylindrical
from bentray.engine.surfaces import Barrier, Footprint, HeightGrid, SceneSurfaces
from bentray.scenes.job_checks import scene_problems
from bentray.scenes.schema import Job
from tests.diffraction.test_barrier_input import BASE

SURF = SceneSurfaces(
    footprints=[Footprint(np.array([[0, 0], [20, 0], [20, 10], [0, 10.0]]), 8.0)],
    barriers=[Barrier(np.array([[-10, -20], [-10, 20.0]]), 4.0, 0.0, "wall")],
)


def test_building_and_barrier_wedges() -> None:
    edges = scene_edges(SURF, [0.0])
    barrier, building = edges.obstacles
    assert len(barrier.edges) == 3 and barrier.edges[0].n == 2.0
    assert building.kinds.count(EDGE_ROOF) == 4 and building.kinds.count(EDGE_CORNER) == 4
    assert sorted(building.roof_pairs) == [(0, 2), (1, 3)] and len(building.corner_pairs) == 4
    inside, above, outside = np.array([[10, 5, 4.0]]), np.array([[10, 5, 30.0]]), np.array([[-5, -5, 1.0]])
    for edge in building.edges:
        assert edge.n == pytest.approx(1.5)
        assert cylindrical(edge, inside)[1][0] > edge.n * np.pi  # the solid
    for edge, kind in zip(building.edges, building.kinds, strict=True):
        if kind == EDGE_ROOF:
            assert cylindrical(edge, above)[1][0] < edge.n * np.pi
    assert cylindrical(building.edges[4], outside)[1][0] < 1.5 * np.pi  # the corner at (0, 0) sees it
    assert edges.walls.shape == (5, 6) and list(edges.owner) == [0, 1, 1, 1, 1]


def test_terrain_crests_threshold() -> None:
    """A ridge whose slopes turn by 2 x 6 = 12 degrees is a crest at the 10-degree threshold, one that turns
    by 8 degrees is not; the crest wedge has n = (pi + bend) / pi with the ground as the solid."""
    x = np.linspace(-50, 50, 21)
    y = np.linspace(-10, 10, 3)
    for slope_deg, expected in ((6.0, True), (4.0, False)):
        z = np.tan(np.radians(slope_deg)) * (50 - np.abs(x))[None, :] * np.ones((3, 1))
        crests = terrain_crests(HeightGrid(x, y, z))
        assert bool(crests) is expected, slope_deg
        if crests:
            bend = np.radians(2 * slope_deg)
            assert crests[0].n == pytest.approx((np.pi + bend) / np.pi)
            assert np.allclose([c.point[0] for c in crests], 0.0)
            _, phi, _ = cylindrical(crests[0], np.array([[0.0, 0.0, 80.0], [0.0, 0.0, -10.0]]))
            assert phi[0] < crests[0].n * np.pi < phi[1]
    assert TERRAIN_CREST_MIN_DEG == 10.0


def test_submit_check_names_the_barrier() -> None:
    job = copy.deepcopy(BASE)
    job["scene"]["buildings"]["barriers"][0]["polyline"] = [[0, 0], [500, 0]]
    problems = scene_problems(Job.model_validate(job), None)
    assert any(p.startswith("scene.buildings.barriers.0 ('wall'): vertex (500, 0) is outside") for p in problems)

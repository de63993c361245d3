"""A job with a closed obstacle mesh (not an extrusion): meshed by fTetWild, traced end to end.

Reference: homogeneous air, a 10 m cube just above the ground 20 m in front of the source; rays aimed
at its front face come back with the mirror direction (d_x -> -d_x) and at the mirror time; none is lost
and none ends inside the cube.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from bentray.engine.run import run_job
from bentray.scenes.schema import Job

trimesh = pytest.importorskip("trimesh")
pytest.importorskip("pytetwild")


@pytest.mark.slow  # fTetWild + a field job: 9 s warm (tests/mesh/test_tetwild_obstacles.py keeps obstacles fast)
def test_closed_obstacle_job_reflects_and_loses_nothing(tmp_path):
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    box.apply_translation((25.0, 0.0, 5.5))  # front face at x = 20, 0.5 m above the ground (strictly inside)
    box.export(tmp_path / "cube.stl")
    job = Job.model_validate(
        {
            "name": "cube",
            "scene": {
                "domain": {"min": [-10, -20, 0], "max": [40, 20, 20]},
                "buildings": {"obstacles": [{"file": "cube.stl"}]},
            },
            "profile": {"kind": "homogeneous", "c0": 340.0},
            "sources": [{"position": [0.0, 0.0, 4.0]}],
            "rays": {
                "elevation_deg": {"min": -5, "max": 5, "count": 5},
                "azimuth_deg": {"min": -10, "max": 10, "count": 5},
                "max_time_s": 0.1,
                "max_reflections": 1,
            },
            "solver": {"d_max_m": 3.0},
        }
    )
    cwd_before = set(os.listdir("."))
    outcome = run_job(job, tmp_path)
    assert set(os.listdir(".")) == cwd_before  # fTetWild's __tracked_surface.stl stays in a temporary folder
    tr = outcome.trace
    assert outcome.report["representation"] == "tetwild"
    assert tr.status_counts()["lost"] == 0
    # every ray hits the front face once (elevations within +-5 deg, azimuths within +-10 deg: the face
    # spans |y| <= 5 m and 0.5 <= z <= 10.5 m at x = 20) and travels back toward the source: after
    # 0.1 s (34 m) the mirror image predicts x = 40 - 34 cos(el) cos(az), y and z as unfolded
    assert np.all(tr.reflections == 1) and np.all(tr.status == 1)  # time_limit
    el = np.radians(tr.elevation_deg)
    az = np.radians(tr.azimuth_deg)
    unfolded = 34.0 * np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    mirror = np.column_stack([40.0 - unfolded[:, 0], unfolded[:, 1], 4.0 + unfolded[:, 2]])
    # fTetWild re-triangulates the face into triangles of about the ideal edge length L, each within the
    # measured deviation dev of the plane: the hit point moves by up to dev (2 dev after the mirror) and a
    # triangle can tilt by up to 2 dev / L, which over the 14 m back moves the ray by 14 * 2 dev / L. The
    # mesh differs from run to run (fTetWild is not reproducible), so the bound is the per-triangle one
    # (an earlier whole-face bound, dev / 5, was too tight in principle; the test failed once in a full-suite
    # run, assertion not captured, and passed in the 18 runs after it).
    dev = outcome.report["mesh"]["surface_deviation_m"]
    edge = outcome.report["mesh"]["edge_length_m"]
    assert dev < 0.1 and 0 < edge <= 3.0
    np.testing.assert_allclose(
        tr.position,
        mirror,
        atol=2 * dev + 14.0 * 2 * dev / edge + 1e-9,
        err_msg=f"surface deviation {dev} m, edge length {edge} m",
    )


@pytest.mark.slow  # fTetWild + a field job: 19 s warm
def test_obstacle_material_reaches_the_obstacle_faces(tmp_path):
    from pydantic import ValidationError

    from bentray.engine.constants import BOUNDARY_REFLECT
    from bentray.engine.media_obstacles import build_obstacle_media
    from bentray.engine.profiles import Homogeneous
    from bentray.scenes.scene_models import surfaces_from_specs

    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    box.apply_translation((25.0, 0.0, 5.5))
    box.export(tmp_path / "cube.stl")
    scene = {
        "domain": {"min": [-10, -20, 0], "max": [40, 20, 20]},
        "materials": [{"name": "hedge", "flow_resistivity": 50000}],
        "buildings": {"obstacles": [{"file": "cube.stl", "material": "hedge"}]},
    }
    base = {
        "name": "cube",
        "profile": {"kind": "homogeneous"},
        "sources": [{"position": [0.0, 0.0, 4.0]}],
        "rays": {"elevation_deg": {"min": 0, "max": 0, "count": 1}, "max_time_s": 0.1, "max_reflections": 1},
    }
    job = Job.model_validate({**base, "scene": scene})
    surfaces = surfaces_from_specs(
        job.scene.terrain, job.scene.buildings, job.scene.materials, tmp_path, job.scene.box, prefix="scene"
    )
    assert surfaces.obstacle_materials == [1]  # 0 is rigid, 1 the first scene material
    media = build_obstacle_media(Homogeneous(), "parabolic", job.solver, [-10, -20, 0], [40, 20, 20], surfaces)
    m = media.mesh
    reflecting = m.neighbours == BOUNDARY_REFLECT
    mats = set(np.unique(m.face_material[reflecting]).tolist())
    assert mats == {0, 1}  # the ground stays rigid, the cube's faces carry the hedge
    bad = {**scene, "buildings": {"obstacles": [{"file": "cube.stl", "material": "glass"}]}}
    with pytest.raises(ValidationError, match="'glass' is not defined"):
        Job.model_validate({**base, "scene": bad})

"""The built-in scenes run end to end as jobs: 10,000 rays, 3 reflections, zero lost rays (issue 3's
must-show; the README's Table 1 comes from the same jobs through ``bentray bench --only table1``)."""

from __future__ import annotations

import pytest

from bentray.engine.errors import JobInputError
from bentray.engine.run import run_job
from bentray.scenes.library.jobs import builtin_job, builtin_job_spec
from bentray.scenes.library.registry import BUILTIN_SCENES, get_builtin
from bentray.scenes.schema import Job


@pytest.mark.parametrize("name", list(BUILTIN_SCENES))
def test_builtin_scene_runs_10k_rays_with_zero_lost(name):
    outcome = run_job(builtin_job(name, elevations=100, azimuths=100, max_time_s=10.0, max_reflections=3))
    rays = outcome.report["rays"]
    assert rays["total"] == 10_000
    assert rays["by_status"]["lost"] == 0
    assert rays["by_status"]["step_limit"] == 0
    assert rays["by_status"]["running"] == 0
    assert sum(rays["by_status"].values()) == 10_000
    mesh = outcome.report["mesh"]
    assert mesh["cells"] > 0 and mesh["points"] > 0
    if name != "flat":
        assert outcome.report["representation"] == "terrain"
        scene = get_builtin(name)
        # every terrain triangle is a mesh boundary face (walls and roofs come on top)
        assert mesh["surface_triangles"] >= scene.stats["surface_triangles"] - scene.stats.get("roof_triangles", 0)


def test_sources_inside_the_ground_are_refused_with_the_field_name():
    spec = builtin_job_spec("ridge", elevations=2, azimuths=2)
    spec["sources"] = [{"position": [0.0, 0.0, 20.0]}]  # the ridge crest is 40 m high at x = 0
    with pytest.raises(JobInputError, match=r"sources\.0\.position"):
        run_job(Job.model_validate(spec))

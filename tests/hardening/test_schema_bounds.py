"""Issue 15: bounds in the job schema, the one JSON reader, the cost model and the medium checks.

Each test is an input of the probe that hung, crashed with a 500 or was traced as a success before.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from pydantic import ValidationError

from bentray.scenes.cost import DEFAULT_PATH_RAYS, CostLimits, cost_problems, estimate_cost, records_paths
from bentray.scenes.job_checks import scene_problems
from bentray.scenes.media_checks import C_MAX_M_S, C_MIN_M_S, media_problems
from bentray.scenes.schema import JobFileError, format_validation_error, parse_job_text
from tests.hardening.conftest import (
    HILL,
    TETRA_OBJ,
    base_job,
    below_terrain_job,
    field_job,
    huge_footprint_job,
    overlapping_job,
)


def _lines(data: dict | str) -> list[str]:
    text = data if isinstance(data, str) else json.dumps(data)
    with pytest.raises((ValidationError, JobFileError)) as info:
        parse_job_text(text, origin="job")
    exc = info.value
    return format_validation_error(exc).splitlines() if isinstance(exc, ValidationError) else [str(exc)]


def test_huge_footprint_is_refused_by_the_schema_within_a_second():
    t0 = time.perf_counter()
    lines = _lines(huge_footprint_job())
    assert time.perf_counter() - t0 < 1.0
    assert lines[0].startswith("scene.buildings.footprints.0.polygon.0.0: Input should be less than or equal to")


@pytest.mark.parametrize(
    "text, expected",
    [
        ("[" * 10_000 + "]" * 10_000, "job: the JSON nests deeper than 64 levels"),
        ('{"name": ' + "9" * 5000 + "}", "job: an integer of 5,000 digits"),
        ('{"a": ' + "[" * 80 + "]" * 80 + "}", "job: the JSON nests deeper than 64 levels"),
    ],
    ids=["deep", "huge-int", "deep-inside"],
)
def test_json_reader_refuses_deep_nesting_and_huge_integers(text, expected):
    assert _lines(text)[0].startswith(expected)


def test_nul_in_a_file_name_is_a_field_error(job):
    job["scene"]["terrain"] = {"file": "hill\u0000.asc"}
    assert any(line.startswith("scene.terrain.file: ") and "control characters" in line for line in _lines(job))


@pytest.mark.parametrize("shape", [[2**32, 2**32, 1], [2**62, 4, 1], [10**30, 1, 1]])
def test_field_shape_cannot_wrap_or_overflow(shape):
    lines = _lines(field_job(1.0, shape))
    assert lines and all(line.startswith("field.shape") for line in lines)


@pytest.mark.parametrize(
    "path, value, field",
    [
        (("solver", "path_samples"), 10**9, "solver.path_samples"),
        (("solver", "delta"), 1e-300, "solver.delta"),
        (("solver", "d_min_m"), 1e-300, "solver.d_min_m"),
        (("rays", "max_steps"), 10**15, "rays.max_steps"),
        (("sources", 0, "position"), [0, 0, 1e300], "sources.0.position.2"),
        (("scene", "domain", "min"), [-1e12, -50, 0], "scene.domain.min.0"),
    ],
)
def test_size_like_parameters_are_bounded(path, value, field):
    job = base_job()
    target = job
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    if path[0] == "solver":
        job["solver"].pop("epsilon", None)
    assert any(line.startswith(field) for line in _lines(job)), _lines(job)


def test_fluctuating_modes_and_nesting_are_bounded(job):
    job["profile"] = {"kind": "fluctuating", "n_modes": 10**7}
    assert _lines(job)[0].startswith("profile.fluctuating.n_modes")
    nested: dict = {"kind": "log"}
    for _ in range(6):
        nested = {"kind": "fluctuating", "base": nested}
    job["profile"] = nested
    assert any("nest" in line for line in _lines(job))


# ---------------------------------------------------------------------------------------------
# Cost model
# ---------------------------------------------------------------------------------------------
def test_tiny_field_spacing_is_refused_by_the_work_budget():
    job = parse_job_text(json.dumps(field_job(1e-6)))
    lines = cost_problems(job, CostLimits())
    assert len(lines) == 1 and lines[0].startswith("field.spacing: an estimated")
    assert "the limit is 2e+10" in lines[0]
    assert not cost_problems(parse_job_text(json.dumps(field_job(10.0))), CostLimits())


def test_recorded_paths_are_in_the_memory_estimate(job):
    job["rays"]["elevation_deg"]["count"] = 20_000
    job["rays"]["record_paths"] = True
    parsed = parse_job_text(json.dumps(job))
    est = estimate_cost(parsed, threads=2)
    assert 0.8e9 < est.paths_bytes < 0.9e9  # measured 828 MB for these 20k rays x 400 samples
    lines = cost_problems(parsed, CostLimits(memory_bytes=2**29))
    assert lines and lines[0].startswith("rays.record_paths: the job needs an estimated 0.")
    assert "the limit is 0.5 GiB" in lines[0]


def test_paths_are_recorded_by_default_only_for_small_jobs(job):
    assert records_paths(parse_job_text(json.dumps(job)))  # 91 rays
    job["rays"]["elevation_deg"]["count"] = DEFAULT_PATH_RAYS + 1
    assert not records_paths(parse_job_text(json.dumps(job)))
    job["outputs"] = ["paths", "report"]
    assert records_paths(parse_job_text(json.dumps(job)))
    job["outputs"] = ["rays"]
    job["rays"]["record_paths"] = True
    assert records_paths(parse_job_text(json.dumps(job)))


# ---------------------------------------------------------------------------------------------
# The medium
# ---------------------------------------------------------------------------------------------
def test_negative_log_profile_is_refused_naming_b(job):
    job["profile"]["b"] = -1e6
    lines = media_problems(parse_job_text(json.dumps(job)))
    assert len(lines) == 1 and lines[0].startswith("profile.b: the log profile's sound speed is -")


def test_absurd_linear_c0_is_refused(job):
    job["profile"] = {"kind": "linear_c", "c0": 1e308, "alpha": 0.1}
    assert _lines(job)[0].startswith("profile.linear_c.c0: Input should be less than or equal to")
    job["profile"]["c0"] = 5000.0  # within the schema, not air
    lines = media_problems(parse_job_text(json.dumps(job)))
    assert lines and lines[0].startswith("profile.c0: ")


def test_checkerboard_grid_is_refused_and_smooth_grid_passes(job):
    job["scene"]["domain"] = {"min": [0, 0, 0], "max": [100, 100, 100]}
    job["sources"] = [{"position": [50, 50, 10]}]
    ii, jj, kk = np.meshgrid(np.arange(5), np.arange(5), np.arange(5), indexing="ij")
    checker = np.where((ii + jj + kk) % 2 == 0, 340.0, 3400.0)
    job["profile"] = {"kind": "grid", "origin": [0, 0, 0], "spacing": [25, 25, 25], "c": checker.tolist()}
    lines = media_problems(parse_job_text(json.dumps(job)))
    assert lines and lines[0].startswith("profile.c: 62 of 125 grid nodes have a sound speed outside")
    job["profile"]["c"] = (340.0 + 0.1 * kk).tolist()
    assert media_problems(parse_job_text(json.dumps(job))) == []
    job["profile"]["c"] = np.where((ii + jj + kk) % 2 == 0, 100.0, 1000.0).tolist()  # each node in range
    lines = media_problems(parse_job_text(json.dumps(job)))
    assert lines and lines[0].startswith("profile.c: the grid's sound speed ranges from 100 to 1000 m/s")


def test_grid_file_with_nan_or_negative_speed_is_a_scene_problem(tmp_path, job):
    job["scene"]["domain"] = {"min": [0, 0, 0], "max": [100, 100, 100]}
    job["sources"] = [{"position": [50, 50, 10]}]
    for bad in (np.nan, -340.0):
        c = np.full((3, 3, 3), 340.0)
        c[1, 1, 1] = bad
        np.savez(tmp_path / "grid.npz", c=c, origin=np.zeros(3), spacing=np.full(3, 50.0))
        job["profile"] = {"kind": "grid", "path": "grid.npz"}
        lines = scene_problems(parse_job_text(json.dumps(job)), tmp_path)
        assert len(lines) == 1 and lines[0].startswith("profile.path: "), lines


def test_strong_wind_is_refused(job):
    job["wind"] = {"kind": "log", "u_star": 5.0, "z_g": 0.01, "direction_deg": 0}
    lines = media_problems(parse_job_text(json.dumps(job)))
    assert lines and lines[0].startswith("wind.u_star: the wind speed reaches")
    job["wind"]["u_star"] = 0.5
    assert media_problems(parse_job_text(json.dumps(job))) == []


def test_range_admits_every_example_and_builtin_job():
    from bentray.scenes.library.jobs import builtin_job_spec
    from bentray.scenes.library.registry import BUILTIN_SCENES
    from bentray.scenes.schema import Job, load_job
    from tests.hardening.conftest import REPO

    assert C_MIN_M_S < 331.0 < C_MAX_M_S
    for path in sorted((REPO / "scenes" / "examples").glob("*.json")):
        if path.name.endswith("geojson") or "features" in path.read_text()[:200]:
            continue
        assert media_problems(load_job(path), path.parent) == [], path.name
    for name in BUILTIN_SCENES:
        assert media_problems(Job.model_validate(builtin_job_spec(name))) == [], name


# ---------------------------------------------------------------------------------------------
# Scene checks (before: accepted, then failed in the worker)
# ---------------------------------------------------------------------------------------------
def test_overlapping_footprints_are_a_scene_problem():
    lines = scene_problems(parse_job_text(json.dumps(overlapping_job())), None)
    assert lines == [
        "scene.buildings.footprints.0 overlaps scene.buildings.footprints.1; footprints may touch but not overlap"
    ]


def test_source_below_the_terrain_is_a_scene_problem(tmp_path):
    (tmp_path / "hill.asc").write_bytes(HILL.read_bytes())
    lines = scene_problems(parse_job_text(json.dumps(below_terrain_job())), tmp_path)
    assert (
        len(lines) == 1 and lines[0].startswith("sources.0.position: (0, 0, 1) is ") and "below the ground" in lines[0]
    )


def test_geojson_with_huge_coordinates_is_refused_before_geometry(tmp_path, job):
    ring = [[1e308, 0], [-1e308, 0], [0, 1e308], [1e308, 0]]
    feature = {"type": "Feature", "properties": {"height": 5}, "geometry": {"type": "Polygon", "coordinates": [ring]}}
    (tmp_path / "b.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    job["scene"]["buildings"] = {"file": "b.geojson"}
    t0 = time.perf_counter()
    lines = scene_problems(parse_job_text(json.dumps(job)), tmp_path)
    assert time.perf_counter() - t0 < 1.0
    assert len(lines) == 1 and lines[0].startswith("scene.buildings.file: coordinate 1e+308 is not within")


def test_obstacle_standing_on_the_flat_ground_is_inside_the_domain(tmp_path):
    from bentray.scenes.scene_models import BuildingsSpec, surfaces_from_specs
    from bentray.scenes.schema import Domain

    (tmp_path / "tetra.obj").write_text(TETRA_OBJ)
    domain = Domain(min=(-50, -50, 0), max=(50, 50, 50))
    surfaces = surfaces_from_specs(None, BuildingsSpec(obstacles=[{"file": "tetra.obj"}]), [], tmp_path, domain)
    assert len(surfaces.obstacles) == 1
    below = Domain(min=(-50, -50, 1), max=(50, 50, 50))  # base below the domain bottom: still refused
    with pytest.raises(ValueError, match="outside the domain"):
        surfaces_from_specs(None, BuildingsSpec(obstacles=[{"file": "tetra.obj"}]), [], tmp_path, below)

"""Job schema: the example loads; every invalid case names its field in the formatted message."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from bentray.scenes.schema import (
    MAX_TOTAL_RAYS,
    AngleRange,
    Job,
    JobFileError,
    Solver,
    format_validation_error,
    load_job,
    parse_job_text,
)

EXAMPLE = Path(__file__).resolve().parents[2] / "scenes" / "examples" / "a-ld-fan.json"


@pytest.fixture
def example() -> dict:
    return json.loads(EXAMPLE.read_text())


def _errors(data: dict) -> str:
    with pytest.raises(ValidationError) as info:
        Job.model_validate(data)
    return format_validation_error(info.value)


def test_example_loads():
    job = load_job(EXAMPLE)
    assert job.name == "a-ld-fan"
    assert job.scene.domain.min == (-50.0, -50.0, 0.0)
    assert job.scene.domain.max == (4000.0, 50.0, 2600.0)
    assert job.scene.ground.kind == "flat" and job.scene.ground.flow_resistivity is None
    assert job.scene.top.kind == "open"
    assert job.profile.kind == "log" and job.profile.c0 == 340.0
    assert job.sources[0].position == (0.0, 0.0, 1.5)
    np.testing.assert_array_equal(job.rays.elevation_deg.values(), np.arange(-45.0, 46.0))
    np.testing.assert_array_equal(job.rays.azimuth_deg.values(), [0.0])
    assert job.rays.max_time_s == 10.0 and job.rays.max_reflections == 50
    assert job.rays.max_steps == 10_000_000 and job.rays.record_paths is None
    assert job.n_rays == 91
    assert job.solver.curve == "parabolic" and job.solver.epsilon == 0.001
    assert job.outputs == ["rays", "mesh", "report"]


def test_epsilon_without_sizing_means_gradient_rule():
    solver = load_job(EXAMPLE).solver
    assert solver.sizing == "curvature"  # the field is never rewritten
    assert solver.effective_sizing == "gradient"
    assert Solver().effective_sizing == "curvature"
    assert Solver(sizing="gradient", epsilon=0.01).effective_sizing == "gradient"
    assert Solver(delta=0.01).effective_sizing == "curvature"
    # a dump states the effective rule, so it reloads with the same meaning
    dumped = solver.model_dump(mode="json")
    assert dumped["sizing"] == "gradient"
    assert Solver.model_validate(dumped).effective_sizing == "gradient"


def test_defaults(example):
    del example["solver"], example["outputs"], example["rays"]["azimuth_deg"]
    job = Job.model_validate(example)
    assert job.outputs == ["rays", "report"]
    assert job.solver == Solver()
    assert job.solver.path_samples == 400 and job.solver.gradient == "lsq"
    assert job.rays.azimuth_deg == AngleRange(min=0, max=0, count=1)


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (
            lambda d: d["rays"]["elevation_deg"].update(count=-1),
            "rays.elevation_deg.count: Input should be greater than or equal to 1",
        ),
        (lambda d: d["scene"]["domain"].update(min=[5000, -50, 0]), "scene.domain.max.0: "),
        (lambda d: d["scene"]["domain"].update(max=[4000, 50, 2.0e6]), "scene.domain.max.2: "),
        (lambda d: d["scene"]["domain"].update(max=[4000, 50, 0.0005]), "scene.domain.max.2: "),
        (lambda d: d["sources"][0].update(position=[0, 0, -1.0]), "sources.0.position: "),
        (lambda d: d["sources"][0].update(position=[0, 0, 0.0]), "sources.0.position: "),
        (lambda d: d["sources"].append({"position": [0, 60, 1.5]}), "sources.1.position: "),
        (lambda d: d["profile"].update(kind="wavy"), "profile: "),
        (lambda d: d.update(colour="red"), "colour: Extra inputs are not permitted"),
        (lambda d: d["rays"].update(colour="red"), "rays.colour: Extra inputs are not permitted"),
        (
            lambda d: d["rays"]["elevation_deg"].update(max=95),
            "rays.elevation_deg.max: Input should be less than or equal to 90",
        ),
        (lambda d: d["rays"]["azimuth_deg"].update(max=10), "rays.azimuth_deg.max: count is 1"),
        (lambda d: d["rays"]["elevation_deg"].update(min=45, max=-45), "rays.elevation_deg.max: "),
        (lambda d: d["rays"].update(max_time_s=0), "rays.max_time_s: Input should be greater than 0"),
        (lambda d: d["rays"].update(max_time_s=4000), "rays.max_time_s: "),
        (lambda d: d["rays"].update(max_reflections=-1), "rays.max_reflections: "),
        (lambda d: d["rays"]["elevation_deg"].update(count=MAX_TOTAL_RAYS + 1), "rays: "),
        (lambda d: d["solver"].update(sizing="curvature"), "solver.epsilon: "),
        (lambda d: d["solver"].update(delta=0.01), "solver.delta: "),
        (lambda d: d["solver"].update(d_min_m=10, d_max_m=1), "solver.d_max_m: "),
        (lambda d: d["solver"].update(path_samples=1), "solver.path_samples: "),
        (lambda d: d["solver"].update(curve="spline"), "solver.curve: "),
        (lambda d: d["scene"]["ground"].update(flow_resistivity=0), "scene.ground.flow_resistivity: "),
        (lambda d: d["scene"].update(builtin="canyon"), "scene.builtin: unknown builtin scene 'canyon'"),
        (lambda d: d.update(name="a b"), "name: "),
        (lambda d: d.update(name=""), "name: "),
        (lambda d: d.update(sources=[]), "sources: "),
        (lambda d: d.update(outputs=["video"]), "outputs.0: "),
    ],
)
def test_invalid_field_is_named(example, mutate, expected):
    mutate(example)
    assert expected in _errors(example)


def test_total_ray_limit_message(example):
    example["sources"] = [{"position": [0, 0, 1.5]}] * 2000
    example["rays"]["azimuth_deg"] = {"min": 0, "max": 350, "count": 100}
    message = _errors(example)
    assert "rays: 2000 sources x 91 elevations x 100 azimuths = 18,200,000 rays" in message
    assert "10,000,000" in message


def test_one_line_per_error(example):
    example["rays"]["elevation_deg"]["count"] = 0
    example["rays"]["max_time_s"] = -1
    lines = _errors(example).splitlines()
    assert lines == [
        "rays.elevation_deg.count: Input should be greater than or equal to 1",
        "rays.max_time_s: Input should be greater than 0",
    ]


def test_validation_never_mutates_input(example):
    before = copy.deepcopy(example)
    Job.model_validate(example)
    assert example == before


def test_invalid_json_names_line_and_column(tmp_path):
    path = tmp_path / "job.json"
    path.write_text('{"name": "x",\n  "scene": ,\n}')
    with pytest.raises(JobFileError, match=r"line 2, column 12"):
        load_job(path)


def test_duplicate_key_and_nan_rejected():
    with pytest.raises(JobFileError, match="duplicate key 'name'"):
        parse_job_text('{"name": "a", "name": "b"}')
    with pytest.raises(JobFileError, match="NaN"):
        parse_job_text('{"x": NaN}')


def test_missing_file(tmp_path):
    with pytest.raises(JobFileError, match="cannot read job file"):
        load_job(tmp_path / "nope.json")

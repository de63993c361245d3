"""The refractive-shadow stage in the job cost estimate (scenes/cost.py): one wavenumber integral per source, band and
(with wind) 5-degree azimuth bin, 0 where the job rules upward refraction out, 'auto' above the stage's own
limit counted as skipped, and a budget line naming field.refractive_shadow when 'on' is too expensive."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from bentray.engine.acoustics.wavenumber import ffp_cells
from bentray.engine.shadow_stage import SHADOW_AUTO_MAX_SOLVES
from bentray.scenes.cost import SHADOW_SECONDS_PER_CELL, CostLimits, cost_problems, estimate_cost
from bentray.scenes.schema import Job

BANDS = [63, 125, 250, 500, 1000, 2000, 4000, 8000]
BASE = {
    "name": "shadow-cost",
    "scene": {"domain": {"min": [-500, -500, 0], "max": [500, 500, 200]}},
    "profile": {"kind": "log", "c0": 340.0, "b": -1.0, "z_g": 1.0},
    "sources": [{"position": [0.0, 0.0, 2.0]}],
    "rays": {"elevation_deg": {"min": -30, "max": 30, "count": 31}, "max_time_s": 2.0, "max_reflections": 2},
    "field": {"origin": [-400, -400, 1.5], "spacing": [20, 20, 1], "shape": [41, 41, 1], "frequencies_hz": [500]},
    "outputs": ["field", "report"],
}


def _job(**changes) -> Job:
    spec = copy.deepcopy(BASE)
    for path, value in changes.items():
        node = spec
        keys = path.split("__")
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value
    return Job.model_validate(spec)


@pytest.mark.parametrize(
    ("profile", "solves"),
    [({"kind": "log", "b": -1.0}, 1), ({"kind": "log", "b": 1.0}, 0), ({"kind": "homogeneous"}, 0),
     ({"kind": "linear_c", "alpha": -0.1}, 1), ({"kind": "linear_c", "alpha": 0.1}, 0)],
)  # fmt: skip
def test_solves_only_where_upward_refraction_is_possible(profile, solves):
    est = estimate_cost(_job(profile=profile), threads=2)
    assert est.shadow_solves == solves
    r_max = float(np.hypot(400.0, 400.0)) + 10.0  # the map's corner from the source
    cells = ffp_cells(500.0, 340.0, 2.0, r_max, 0.25 * r_max + 20.0)
    assert est.shadow_seconds == pytest.approx(solves * cells * SHADOW_SECONDS_PER_CELL)


def test_bands_sources_and_wind_bins_multiply():
    assert estimate_cost(_job(field__frequencies_hz=[125, 500, 1000]), 2).shadow_solves == 3
    wind = {"kind": "log", "u_star": 0.5, "z_g": 0.1, "direction_deg": 0.0}
    # the source inside the map: every one of the 72 bins; 'on' so that 'auto' does not skip
    on = estimate_cost(_job(wind=wind, profile={"kind": "homogeneous"}, field__refractive_shadow="on"), 2)
    assert on.shadow_solves == 72
    # a map east of the source spans atan(400/100) .. : fewer bins
    east = _job(wind=wind, profile={"kind": "homogeneous"}, field__refractive_shadow="on",
                field__origin=[100, -100, 1.5], field__shape=[11, 11, 1])  # fmt: skip
    n = estimate_cost(east, 2).shadow_solves
    assert 10 < n < 72  # -45 .. +45 degrees: 19 bins
    assert n == 19


def test_auto_over_its_limit_and_off_cost_nothing():
    bands = BANDS + [16000]  # 9 bands
    two = [{"position": [0.0, 0.0, 2.0]}, {"position": [10.0, 0.0, 2.0]}]  # 18 solves > 16
    est = estimate_cost(_job(field__frequencies_hz=bands[:9], sources=two), 2)
    assert 2 * 9 > SHADOW_AUTO_MAX_SOLVES and est.shadow_solves == 0
    assert estimate_cost(_job(field__refractive_shadow="off"), 2).shadow_solves == 0


def test_an_expensive_on_stage_is_refused_naming_the_field():
    wind = {"kind": "log", "u_star": 0.5, "z_g": 0.1, "direction_deg": 0.0}
    job = _job(wind=wind, profile={"kind": "homogeneous"}, field__refractive_shadow="on",
               field__frequencies_hz=[500, 1000, 2000])  # fmt: skip
    lines = cost_problems(job, CostLimits())
    assert any(line.startswith("field.refractive_shadow: ") and "216 wavenumber integrals" in line for line in lines)
    assert not any(line.startswith("field.refractive_shadow") for line in cost_problems(_job(), CostLimits()))


def test_auto_skips_an_expensive_stage_and_the_stage_says_so():
    from bentray.engine.run import run_job
    from bentray.scenes.cost import SHADOW_AUTO_MAX_SECONDS, shadow_cost

    spec = {
        "name": "auto-seconds",
        "scene": {"domain": {"min": [-20, -20, 0], "max": [3000, 20, 100]}},
        "profile": {"kind": "log", "c0": 340.0, "b": -1.0, "z_g": 1.0},
        "sources": [{"position": [0.0, 0.0, 2.0]}],
        "rays": {"elevation_deg": {"min": -10, "max": 10, "count": 21}, "max_time_s": 0.5, "max_reflections": 1},
        "field": {"origin": [2900, 0, 1.5], "spacing": [10, 1, 1], "shape": [2, 1, 1], "frequencies_hz": [4000]},
        "outputs": ["field", "report"],
    }
    job = Job.model_validate(spec)
    assert shadow_cost(job, apply_auto=False)[1] > SHADOW_AUTO_MAX_SECONDS  # 4 kHz to 2.9 km
    assert shadow_cost(job) == (0, 0.0)
    assert (
        "s (~ f^2 x range x height per integral) is over the 'auto' limit"
        in run_job(job).report["stages"]["refractive_shadow"]
    )

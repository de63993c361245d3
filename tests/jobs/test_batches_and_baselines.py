"""Ray batches (the unit of progress and of scale-out) and the numerical baselines selected in jobs.

Batching must not change results: every ray is traced independently (bitwise identical rays) and the
field partials are summed in batch order (identical up to the reordering of a floating-point sum:
asserted to 1e-12 relative). The baselines through ``solver.curve`` are checked against the analytic
tracer on the same stratified profile (an independent integration of the same ray equations).
"""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from bentray.engine.run import run_job
from bentray.scenes.schema import Job


def _field_job(mode: str, **solver) -> Job:
    return Job.model_validate(
        {
            "name": "batches",
            "scene": {
                "domain": {"min": [-20, -60, 0], "max": [300, 60, 120]},
                "ground": {"kind": "flat", "flow_resistivity": 200.0},
            },
            "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
            "sources": [{"position": [0.0, 0.0, 2.0]}],
            "rays": {
                "elevation_deg": {"min": -30, "max": 30, "count": 31},
                "azimuth_deg": {"min": -20, "max": 20, "count": 21},
                "max_time_s": 1.0,
                "max_reflections": 4,
            },
            "solver": solver,
            "field": {
                "origin": [10, -20, 1],
                "spacing": [10, 10, 2],
                "shape": [25, 5, 3],
                "frequencies_hz": [125, 1000],
                "mode": mode,
                "method": "voxels",  # the voxel accumulator (beams: one batch per source)
            },
            "outputs": ["rays", "field", "report"],
        }
    )


@pytest.mark.parametrize("mode", ["incoherent", "coherent"])
def test_batched_run_matches_one_batch(mode):
    whole = run_job(_field_job(mode))
    stages: list[tuple[str, float]] = []
    batched = run_job(_field_job(mode, batch_rays=100), progress=lambda s, f: stages.append((s, f)))
    assert whole.report["batches"]["count"] == 1
    assert batched.report["batches"]["count"] == 7  # 651 rays in batches of 100
    for name in ("position", "direction", "time_s", "length_m", "reflections", "status", "crossings"):
        np.testing.assert_array_equal(getattr(whole.trace, name), getattr(batched.trace, name))
    for key, arr in whole.field.arrays.items():
        other = batched.field.arrays[key]
        finite = np.isfinite(arr)
        np.testing.assert_array_equal(finite, np.isfinite(other))
        np.testing.assert_allclose(other[finite], arr[finite], rtol=1e-12, atol=1e-12, err_msg=key)
    # progress: one report per batch during the trace, monotone, ending at 1
    fractions = [f for _, f in stages]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    assert sum(1 for s, _ in stages if s == "trace") == 1 + 7


def _baseline_job(curve: str, **solver) -> Job:
    return Job.model_validate(
        {
            "name": "baseline",
            "scene": {"domain": {"min": [-50, -50, 0], "max": [2000, 50, 800]}},
            "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
            "sources": [{"position": [0.0, 0.0, 1.5]}],
            "rays": {"elevation_deg": {"min": -10, "max": 10, "count": 9}, "max_time_s": 3.0, "max_reflections": 20},
            "solver": {"curve": curve, **solver},
            "outputs": ["rays", "report"],
        }
    )


@pytest.mark.parametrize(
    "curve, solver",
    [
        ("rk4", {"step_m": 0.5, "media": "exact"}),
        ("dopri5", {"tolerance": 1e-9, "media": "exact"}),
        ("dopri5", {"tolerance": 1e-9, "media": "mesh"}),
    ],
)
def test_baselines_in_jobs_agree_with_the_analytic_tracer(curve, solver):
    analytic = run_job(_baseline_job("parabolic", delta=1e-8)).trace
    outcome = run_job(_baseline_job(curve, **solver))
    numeric = outcome.trace
    assert numeric.status_counts()["lost"] == 0
    np.testing.assert_array_equal(numeric.reflections, analytic.reflections)
    # 1 km path, closed-form log profile; the analytic tracer meets 1e-6 relative at delta 1e-8, the
    # baselines at these steps 1e-5 (bench: baselines_probe): 1e-4 relative of the path is a safe bound
    err = np.linalg.norm(numeric.position - analytic.position, axis=1)
    assert err.max() < 1e-4 * 1020.0
    assert outcome.report["rays"]["restarts_total"] > 0
    assert curve in outcome.report["stages"]["trace"]


@pytest.mark.parametrize(
    "solver, field",
    [
        ({"curve": "rk4", "tolerance": 1e-6}, "tolerance"),
        ({"curve": "parabolic", "step_m": 1.0}, "step_m"),
        ({"curve": "parabolic", "media": "exact"}, "media"),
    ],
)
def test_baseline_settings_are_checked(solver, field):
    with pytest.raises(ValidationError) as err:
        _baseline_job(**solver)
    assert f"solver.{field}" in str(err.value) or field in str(err.value)


def test_baselines_refuse_wind():
    spec = _baseline_job("rk4").model_dump(mode="json")
    spec["wind"] = {"kind": "log", "u_star": 0.5, "z_g": 0.1, "direction_deg": 0.0}
    with pytest.raises(ValidationError, match="without wind"):
        Job.model_validate(spec)

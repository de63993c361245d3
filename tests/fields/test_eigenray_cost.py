"""The eigenray search in the cost model (scenes/cost.py, ``eigenray_steps``): the estimate bounds the rays
the search really traces, and a budget it exceeds is refused naming ``eigenrays.enabled``.

Oracle: the rays counted by wrapping ``engine.eigenrays._trace_to`` (every fan and probe call goes through
it) while the eigenray stage runs, converted to crossings with the same per-ray crossing count as the
estimate. Measured (this file's cases, 2 receivers at 200 and 900 m): homogeneous 807 rays per pair,
linear c (downward, 8 reflections allowed) about 1,480 per pair; the estimate allows 721 + 200 x 9 = 2,521.
"""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine import eigenrays
from bentray.engine.run import run_job
from bentray.scenes.cost import CostLimits, cost_problems, estimate_cost
from bentray.scenes.schema import Job


def _job(profile: dict, max_reflections: int, receivers: int = 2, enabled: str = "on") -> Job:
    xs = np.linspace(200.0, 900.0, receivers)
    return Job.model_validate(
        {
            "name": "eig-cost",
            "scene": {"domain": {"min": [-20, -50, 0], "max": [1020, 50, 300]}, "ground": {"kind": "flat"}},
            "profile": profile,
            "sources": [{"position": [0.0, 0.0, 2.0]}],
            "rays": {
                "elevation_deg": {"min": -30, "max": 30, "count": 61},
                "azimuth_deg": {"min": 0, "max": 0, "count": 1},
                "max_time_s": 3.2,
                "max_reflections": max_reflections,
            },
            "receivers": [{"id": f"r{i}", "position": [float(x), 0.0, 1.5]} for i, x in enumerate(xs)],
            "eigenrays": {"enabled": enabled},
            "outputs": ["report"],
        }
    )


@pytest.mark.parametrize(
    "profile, max_reflections",
    [({"kind": "homogeneous", "c0": 340.0}, 3), ({"kind": "linear_c", "c0": 340.0, "alpha": 0.1}, 8)],
    ids=["homogeneous", "linear-down"],
)
def test_estimate_bounds_the_rays_traced(monkeypatch, profile, max_reflections):
    traced = {"rays": 0}
    original = eigenrays._trace_to

    def counting(model, gammas, time_s, **kw):
        traced["rays"] += int(np.asarray(gammas).shape[0])
        return original(model, gammas, time_s, **kw)

    monkeypatch.setattr(eigenrays, "_trace_to", counting)
    job = _job(profile, max_reflections)
    with_eig = estimate_cost(job, threads=2)
    without = estimate_cost(_job(profile, max_reflections, enabled="off"), threads=2)
    assert without.eigenray_steps == 0.0
    out = run_job(job)
    assert out.arrivals is not None and out.arrivals.stats["arrivals"] >= 2
    # crossings per ray of the estimate: the fan's own estimate divided by its ray count
    per_ray = without.ray_steps / job.n_rays
    traced_steps = traced["rays"] * per_ray
    assert traced["rays"] > 2 * job.eigenrays.elevations  # the count saw the search
    assert traced_steps <= with_eig.eigenray_steps <= 10.0 * traced_steps


def test_eigenray_budget_is_refused_with_the_field():
    job = _job({"kind": "homogeneous", "c0": 340.0}, 3, receivers=50)
    est = estimate_cost(job, threads=2)
    lines = cost_problems(job, CostLimits(ray_steps=est.eigenray_steps / 2))
    eig = [ln for ln in lines if ln.startswith("eigenrays.enabled:")]
    assert len(eig) == 1 and "source-receiver pairs" in eig[0] and "set eigenrays.enabled to 'off'" in eig[0]
    assert not [ln for ln in cost_problems(job, CostLimits()) if ln.startswith("eigenrays")]

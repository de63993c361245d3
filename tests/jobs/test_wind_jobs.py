"""Wind in jobs: the ``wind`` key reaches the mesh choice, the sizing and the kernel.

Reference: the A-UW / A-DW ridge (docs/physics.md §7). Over the symmetric ridge in still air the
rays of a source at x = -800 m shooting along +x and its mirror image at x = +800 m shooting along -x are
mirror images (to rounding); with the wind blowing toward +x the downwind fan bends toward the ground
(more ground reflections, lower rays) and the upwind fan bends away (fewer, higher).
"""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine.errors import JobInputError
from bentray.engine.run import run_job
from bentray.scenes.library.registry import get_builtin
from bentray.scenes.library.ridge import RIDGE_WIND
from bentray.scenes.schema import Job

RIDGE = get_builtin("ridge", "medium")


def _ridge_job(wind: dict | None, azimuth: float, x: float) -> Job:
    spec = {
        "name": "ridge-wind",
        "scene": {"builtin": "ridge"},
        "profile": RIDGE.profile,
        "sources": [{"position": [x, 0.0, 4.35]}],
        "rays": {
            "elevation_deg": {"min": -1, "max": 8, "count": 37},
            "azimuth_deg": {"min": azimuth, "max": azimuth, "count": 1},
            "max_time_s": 5.0,
            "max_reflections": 50,
        },
        "outputs": ["rays", "report"],
    }
    if wind is not None:
        spec["wind"] = wind
    return Job.model_validate(spec)


@pytest.fixture(scope="module")
def ridge_runs():
    return {
        (wind, side): run_job(_ridge_job(RIDGE_WIND if wind else None, az, x))
        for wind in (False, True)
        for side, az, x in (("down", 0.0, -800.0), ("up", 180.0, 800.0))
    }


def test_still_air_fans_are_mirror_images(ridge_runs):
    a, b = ridge_runs[(False, "down")].trace, ridge_runs[(False, "up")].trace
    np.testing.assert_array_equal(a.reflections, b.reflections)
    # x mirrored, z equal. The prism split's diagonal rule is not mirror-symmetric, so the two fans see
    # differently cut cells and per-cell gradients (the profile follows the terrain, so the medium varies
    # along the slopes): measured 3.5e-3 m (2e-6 of the 1.7 km path); allow 1e-5.
    np.testing.assert_allclose(a.position[:, 0], -b.position[:, 0], rtol=0, atol=1e-5 * 1700)
    np.testing.assert_allclose(a.position[:, 2], b.position[:, 2], rtol=0, atol=1e-5 * 1700)


def test_downwind_bends_toward_the_ground_upwind_away(ridge_runs):
    still = ridge_runs[(False, "down")].trace
    down = ridge_runs[(True, "down")].trace
    up = ridge_runs[(True, "up")].trace
    assert down.reflections.sum() > 3 * still.reflections.sum()
    assert up.reflections.sum() < still.reflections.sum()
    # rays launched above 2 degrees end higher upwind than in still air (downwind ones bounce, so their
    # final height says little)
    el = np.linspace(-1, 8, 37)
    upper = el > 2.0
    assert np.all(up.position[upper, 2] > still.position[upper, 2])
    for run in (ridge_runs[(True, "down")], ridge_runs[(True, "up")]):
        assert run.report["stages"]["wind"].startswith("ran: ridge")
        assert run.report["representation"] == "terrain"
        assert run.trace.status_counts()["lost"] == 0


def _flat_job(**extra) -> Job:
    spec = {
        "name": "log-wind",
        "scene": {"domain": {"min": [-10, -2000, 0], "max": [2000, 2000, 500]}},
        "profile": {"kind": "homogeneous", "c0": 340.0},
        "sources": [{"position": [0.0, 0.0, 2.0]}],
        "rays": {"elevation_deg": {"min": 1, "max": 5, "count": 5}, "max_time_s": 3.0, "max_reflections": 20},
    }
    spec.update(extra)
    return Job.model_validate(spec)


def test_log_wind_over_flat_ground_uses_slabs_and_still_air_uses_one_cell():
    still = run_job(_flat_job())
    assert still.report["representation"] == "uniform"
    assert still.report["stages"]["wind"].startswith("skipped")
    assert "wind" not in still.report
    windy = run_job(_flat_job(wind={"kind": "log", "u_star": 0.6, "z_g": 0.1, "direction_deg": 0.0}))
    assert windy.report["representation"] == "slabs"
    assert windy.report["wind"]["kind"] == "log"
    # homogeneous c plus a downwind log wind: rays launched upward come back down (reflect)
    assert windy.trace.reflections.sum() > still.trace.reflections.sum()


def test_uniform_representation_is_refused_with_wind():
    job = _flat_job(
        wind={"kind": "log", "u_star": 0.6, "z_g": 0.1, "direction_deg": 0.0}, solver={"representation": "uniform"}
    )
    with pytest.raises(JobInputError, match="still air"):
        run_job(job)

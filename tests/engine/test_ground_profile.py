"""Profiles measured from the ground (scene.profile_heights, default "above_ground").

References: over flat ground at z = 10 m the traced fan equals the fan over ground at z = 0 shifted up by
10 m (same layers up to rounding); over terrain the sound speed at a height dz above the ground equals the
base law at dz (exact, the wrapper only shifts z).
"""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine.ground_profile import AboveGround
from bentray.engine.profiles import Log
from bentray.engine.run import run_job
from bentray.scenes.schema import Job


def _fan(z0: float, heights: str) -> Job:
    return Job.model_validate(
        {
            "name": "shifted",
            "scene": {"domain": {"min": [-50, -50, z0], "max": [2000, 50, z0 + 800]}, "profile_heights": heights},
            "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
            "sources": [{"position": [0.0, 0.0, z0 + 1.5]}],
            "rays": {"elevation_deg": {"min": -20, "max": 20, "count": 21}, "max_time_s": 4.0, "max_reflections": 30},
        }
    )


def test_flat_ground_above_zero_traces_the_same_fan_shifted():
    ref = run_job(_fan(0.0, "above_ground")).trace
    lifted = run_job(_fan(10.0, "above_ground"))
    np.testing.assert_array_equal(lifted.trace.reflections, ref.reflections)
    shifted = lifted.trace.position - np.array([0.0, 0.0, 10.0])
    # 1e-9 of the 1.36 km path: the slab boundaries are the same levels plus 10 m (rounding only)
    assert np.abs(shifted - ref.position).max() < 1e-9 * 1360
    assert "heights above ground" in lifted.report["stages"]["profile"]
    assert lifted.report["representation"] == "slabs"


def test_absolute_heights_keep_world_z():
    absolute = run_job(_fan(10.0, "absolute")).trace
    ref = run_job(_fan(0.0, "above_ground")).trace
    # the log law evaluated at z + 10 m is a different medium: the fans must differ
    assert np.abs(absolute.position[:, 2] - 10.0 - ref.position[:, 2]).max() > 1.0


def test_above_ground_shifts_by_the_terrain_height():
    base = Log(c0=340.0, b=1.0, z_g=1.0)
    slope = lambda xy: 0.1 * xy[:, 0] + 5.0  # noqa: E731  ground z = 5 + 0.1 x
    prof = AboveGround(base, slope, flat=False)
    xy = np.array([[0.0, 0.0], [100.0, 3.0], [-40.0, 7.0]])
    dz = np.array([0.0, 2.5, 40.0])
    pts = np.column_stack([xy, slope(xy) + dz])
    expected = base.sound_speed(np.column_stack([xy, dz]))
    np.testing.assert_allclose(prof.sound_speed(pts), expected, rtol=1e-15)
    # below the ground (inside a building footprint, never traced): the ground value, not NaN
    below = np.column_stack([xy, slope(xy) - 3.0])
    np.testing.assert_allclose(prof.sound_speed(below), base.sound_speed(np.column_stack([xy, np.zeros(3)])))
    assert not prof.stratified and prof.kind == "log"
    # the gradient carries the slope: d c / d x = -0.1 d c / d z at the ground plus nothing else
    g = prof.sound_speed_gradient(np.array([[100.0, 3.0, float(slope(xy[1:2])[0]) + 10.0]]))[0]
    gz = base.sound_speed_gradient(np.array([[100.0, 3.0, 10.0]]))[0, 2]
    np.testing.assert_allclose(g, [-0.1 * gz, 0.0, gz], rtol=1e-5, atol=1e-9)


def test_exact_baseline_media_refuse_a_shifted_profile():
    spec = _fan(10.0, "above_ground").model_dump(mode="json")
    spec["solver"] = {"curve": "rk4", "media": "exact", "step_m": 1.0}
    from bentray.engine.errors import JobInputError

    with pytest.raises(JobInputError, match="profile_heights"):
        run_job(Job.model_validate(spec))


def test_a_vertical_column_looks_its_ground_up_once_with_the_same_heights():
    """Thousands of heights above one (x, y) (the shadow stages' columns): one ground lookup, and the same
    speeds bit for bit as the lookup per point (oracle: a ground function that cannot be broadcast wrongly,
    called point by point); points at different (x, y), or a NaN coordinate, keep the per-point lookup."""
    calls = []

    def ground(xy):
        calls.append(len(xy))
        return 3.0 + 0.1 * np.sin(xy[:, 0]) * np.cos(0.3 * xy[:, 1])

    prof = AboveGround(Log(c0=340.0, b=-1.0, z_g=1.0), ground, flat=False)
    z = np.linspace(-5.0, 400.0, 4096)
    col = np.column_stack([np.full(z.size, 123.4), np.full(z.size, -56.7), z])
    got = prof.sound_speed(col)
    assert calls == [1]
    base = Log(c0=340.0, b=-1.0, z_g=1.0)
    g0 = float(ground(np.array([[123.4, -56.7]]))[0])
    per_point = np.concatenate([base.sound_speed(np.array([[123.4, -56.7, max(zi - g0, 0.0)]])) for zi in z])
    np.testing.assert_array_equal(got, per_point)
    calls.clear()
    scattered = col.copy()
    scattered[7, 0] += 1.0
    prof.sound_speed(scattered)
    with_nan = col.copy()
    with_nan[:, 0] = np.nan  # nan == nan is False: no column, the lookup per point (nan levels as before)
    assert np.all(np.isnan(prof.sound_speed(with_nan)))
    assert calls == [col.shape[0], col.shape[0]]

"""Every profile kind runs through the job path with the representation it needs and loses no ray.

The 3D kinds (hot spot, fluctuating, grid) go through Algorithm 2 + Delaunay; their accuracy against
DOP853 is checked on the hot spot, where the error must fall as the sizing tolerance falls.
"""

from __future__ import annotations

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine.profiles import HotSpot
from bentray.engine.run import run_job
from bentray.scenes.schema import Job
from tests.reference.ray_ode import integrate_ray

SMALL = {"min": [-100, -100, 0], "max": [100, 100, 80]}


def _job(profile, solver=None, domain=SMALL, t_end=0.5, source=(-80.0, 3.0, 2.0)):
    return Job.model_validate(
        {
            "name": "profiles",
            "scene": {"domain": domain},
            "profile": profile,
            "sources": [{"position": list(source)}],
            "rays": {
                "elevation_deg": {"min": -20, "max": 30, "count": 11},
                "azimuth_deg": {"min": -10, "max": 10, "count": 3},
                "max_time_s": t_end,
                "max_reflections": 20,
            },
            "solver": solver or {},
            "outputs": ["report"],
        }
    )


def _grid_file(tmp_path):
    x = np.linspace(-100, 100, 11)
    y = np.linspace(-100, 100, 11)
    z = np.linspace(0, 80, 9)
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    c = 340.0 + 0.05 * Z + 2.0 * np.exp(-((X - 20) ** 2 + Y**2) / 800.0)
    path = tmp_path / "c.npz"
    np.savez(path, c=c, origin=[-100, -100, 0], spacing=[20, 20, 10])
    return path


@pytest.mark.parametrize(
    ("profile", "representation"),
    [
        ({"kind": "homogeneous"}, "uniform"),
        ({"kind": "linear_n"}, "slabs"),
        ({"kind": "linear_n2"}, "slabs"),
        ({"kind": "log", "b": -1.0}, "slabs"),
        ({"kind": "table", "z": [0, 5, 30, 80], "c": [343, 341, 340, 339.5]}, "slabs"),
        ({"kind": "hot_spot", "center": [0, 0, 10], "t_s": 320, "d0": 30}, "tets"),
        ({"kind": "fluctuating", "base": {"kind": "log", "b": 1.0}, "rms": 0.3, "k_min": 0.03, "k_max": 0.08}, "tets"),
        ({"kind": "grid", "path": "GRID"}, "tets"),
    ],
)
def test_profile_kind_runs(tmp_path, profile, representation):
    if profile.get("path") == "GRID":
        profile = {"kind": "grid", "path": str(_grid_file(tmp_path))}
    solver = {"delta": 1e-3} if profile["kind"] == "fluctuating" else None
    outcome = run_job(_job(profile, solver))
    report = outcome.report
    assert report["representation"] == representation
    assert report["rays"]["by_status"]["lost"] == 0
    assert report["rays"]["by_status"]["step_limit"] == 0
    assert np.all(np.isfinite(outcome.trace.position))
    if representation == "tets":
        mesh = report["mesh"]
        for key in (
            "points",
            "cells",
            "min_cell_size_m",
            "median_cell_size_m",
            "radius_edge",
            "build_time_s",
            "approximation_error_eq14",
        ):
            assert key in mesh
        assert mesh["approximation_error_eq14"]["rel_error_cell_linear"] < 1e-2


@pytest.mark.slow  # 10 s warm; the hot spot still runs in test_profile_kind_runs
def test_hot_spot_error_falls_with_delta():
    profile = {"kind": "hot_spot", "center": [0, 0, 10], "t_s": 320, "d0": 30}
    hs = HotSpot(center=(0, 0, 10), t_s=320, d0=30)
    t_end = 0.4  # 136 m: every ray stays inside the 200 x 200 x 80 m box
    errors = []
    ref = None
    for delta in (1e-3, 1e-4):
        outcome = run_job(_job(profile, {"delta": delta}, t_end=t_end))
        if ref is None:
            el = np.radians(outcome.trace.elevation_deg)
            az = np.radians(outcome.trace.azimuth_deg)
            d = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            ref = np.array(
                [
                    integrate_ray(
                        lambda x: float(hs.quantity("n", x[None, :])[0]),
                        lambda x: hs.refractive_index_gradient(x[None, :])[0],
                        np.array([-80.0, 3.0, 2.0]),
                        di,
                        t_end,
                    ).position
                    for di in d
                ]
            )
        assert outcome.report["rays"]["by_status"]["time_limit"] == outcome.trace.n_rays
        errors.append(float(np.max(np.linalg.norm(outcome.trace.position - ref, axis=1)) / (340.0 * t_end)))
    assert errors[1] < errors[0] / 3.0, errors
    assert errors[1] < 5e-3, errors

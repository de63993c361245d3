"""Stratified profiles through the whole job path (schema -> slabs -> kernels) against DOP853.

Relative position error |x - x_ref| / (c0 t) after 10 s, source 1.5 m, elevations -45..45 degrees:
- with the default solver settings it is below 1e-4 on A-LD and A-LU (issue 2), for every curve;
- it falls as the sizing tolerance (delta, or the paper's epsilon) falls;
- no ray is lost.
"""

from __future__ import annotations

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine.run import run_job
from bentray.scenes.schema import Job
from tests.reference.ray_ode import integrate_ray, log_profile, mirage_profile

REF_STRIDE = 3  # reference rays: every 3rd of the 91 (31 rays) keeps the suite fast


def _job(profile: dict, solver: dict | None = None, t_end: float = 10.0, count: int = 91, hi_x: float = 4000.0):
    return Job.model_validate(
        {
            "name": "accuracy",
            "scene": {"domain": {"min": [-50, -50, 0], "max": [hi_x, 50, 2600]}, "ground": {"kind": "flat"}},
            "profile": profile,
            "sources": [{"position": [0, 0, 1.5]}],
            "rays": {
                "elevation_deg": {"min": -45, "max": 45, "count": count},
                "max_time_s": t_end,
                "max_reflections": 50,
            },
            "solver": solver or {},
            "outputs": ["report"],
        }
    )


_REFERENCE_CACHE: dict[tuple, np.ndarray] = {}


def _reference(kind: str, b: float, t_end: float = 10.0) -> np.ndarray:
    key = (kind, b, t_end)
    if key not in _REFERENCE_CACHE:
        n_of, g_of = log_profile(b=b) if kind == "log" else mirage_profile(kind)
        el = np.radians(np.linspace(-45, 45, 91))[::REF_STRIDE]
        d = np.column_stack([np.cos(el), np.zeros_like(el), np.sin(el)])
        _REFERENCE_CACHE[key] = np.array(
            [integrate_ray(n_of, g_of, np.array([0, 0, 1.5]), di, t_end).position for di in d]
        )
    return _REFERENCE_CACHE[key]


def _error(outcome, ref: np.ndarray, t_end: float = 10.0) -> float:
    pos = outcome.trace.position[::REF_STRIDE]
    return float(np.max(np.linalg.norm(pos - ref, axis=1)) / (340.0 * t_end))


@pytest.mark.parametrize("b", [1.0, -1.0], ids=["A-LD", "A-LU"])
@pytest.mark.parametrize("curve", ["parabolic", "circular", "n_linear"])
def test_default_settings_meet_1e4(b, curve):
    outcome = run_job(_job({"kind": "log", "c0": 340.0, "b": b, "z_g": 1.0}, {"curve": curve}))
    counts = outcome.trace.status_counts()
    assert counts["lost"] == 0 and counts["step_limit"] == 0
    assert counts["time_limit"] == 91
    assert outcome.report["representation"] == "slabs"
    err = _error(outcome, _reference("log", b))
    assert err < 1e-4, f"{curve} b={b}: {err:.2e}"


@pytest.mark.parametrize("b", [1.0, -1.0], ids=["A-LD", "A-LU"])
def test_error_falls_with_delta(b):
    errors = []
    for delta in (1e-5, 1e-7, 1e-9):
        outcome = run_job(_job({"kind": "log", "b": b}, {"delta": delta}))
        errors.append(_error(outcome, _reference("log", b)))
    assert errors[0] > errors[1] > errors[2], errors
    assert errors[2] < errors[0] / 30.0, errors


def test_error_falls_with_paper_epsilon():
    errors = []
    for eps in (1e-2, 1e-3, 1e-4):
        outcome = run_job(_job({"kind": "log", "b": 1.0}, {"epsilon": eps}))
        assert outcome.report["mesh"]["sizing_rule"] == "gradient"
        errors.append(_error(outcome, _reference("log", 1.0)))
    assert errors[0] > errors[1] > errors[2], errors


@pytest.mark.parametrize("kind", ["mirage_inferior", "mirage_superior"])
def test_mirage_profiles(kind):
    """Visual validation profiles (V-IM, V-SM), traced over 100 m of range (0.3 s at 340 m/s)."""
    t_end = 0.3
    outcome = run_job(_job({"kind": kind}, t_end=t_end, hi_x=200.0))
    assert outcome.trace.status_counts()["lost"] == 0
    err = _error(outcome, _reference(kind.split("_")[1], 0.0, t_end), t_end)
    assert err < 1e-4, f"{kind}: {err:.2e}"

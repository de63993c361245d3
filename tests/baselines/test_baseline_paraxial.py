"""Variational equations of the numerical baselines (docs/physics.md §10, "Numerical baselines").

Oracle 1: the baseline itself. Each method's carried launch-angle derivatives (X_k, P_k) must be the
derivative of what that method computes: the same ray launched 1e-6 and 5e-7 rad away in elevation and
azimuth, on both sides, differentiated on the exit plane (Richardson, truncation O(h^4)). Rays whose
neighbours took a different number of accepted steps or reflections (another step sequence: the map
is not smooth there) are left out; the test asserts that most are compared. Exact media (the closed-form
A-LD log profile, smooth), ground reflections.

Oracle 2 (the other way round): DOPRI5 on the exact profile as the reference for the analytic tracer's
smooth-medium paraxial state (what beams carry) on fine slab meshes of the same profile: it converges with
the mesh (stated below as measured).
"""

from __future__ import annotations

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine.baselines.exact_media import exact_media_spec
from bentray.engine.baselines.trace_numerical import trace_numerical
from bentray.engine.constants import STATUS_EXITED
from bentray.engine.media import build_media
from bentray.engine.tracer import trace
from bentray.scenes.profile_models import profile_from_spec
from bentray.scenes.schema import Job

H = 1e-6
LO = np.array([-20.0, -200.0, 0.0])
HI = np.array([600.0, 200.0, 150.0])
SRC = np.array([0.0, 0.0, 2.0])
LOG_DOWN = {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0}
FAN_EL = np.array([-4.0, -2.0, 0.5, 2.0, 4.0, 8.0])
FAN_AZ = np.array([0.0, 7.0, -11.0, 3.0, -30.0, 15.0])
STEP_M = {"euler": 0.5, "euler_adaptive": 2.0, "rk4": 2.0, "dopri5": 5.0}
TOLERANCE = {"euler": 1e-10, "euler_adaptive": 1e-6, "rk4": 1e-10, "dopri5": 1e-10}  # adaptive: local error


def _fan(el_deg: np.ndarray, az_deg: np.ndarray) -> tuple[np.ndarray, int]:
    el0 = np.radians(el_deg)
    az0 = np.radians(az_deg)
    steps = [H, -H, H / 2, -H / 2]
    els = np.concatenate([el0] + [el0 + h for h in steps] + [el0] * 4)
    azs = np.concatenate([az0] + [az0] * 4 + [az0 + h for h in steps])
    dirs = np.column_stack([np.cos(els) * np.cos(azs), np.cos(els) * np.sin(azs), np.sin(els)])
    return dirs, el0.size


def _errors(res, n: int, same: np.ndarray) -> tuple[float, float]:
    par = res.paraxial
    p_vec = res.direction * par[:, 12:13]
    blocks = [slice(k * n, (k + 1) * n) for k in range(9)]

    def richardson(values: np.ndarray, first: int) -> np.ndarray:
        d_h = (values[blocks[first]] - values[blocks[first + 1]]) / (2 * H)
        d_h2 = (values[blocks[first + 2]] - values[blocks[first + 3]]) / H
        return (4.0 * d_h2 - d_h) / 3.0

    wx = wp = 0.0
    for k, first in enumerate((1, 5)):
        x_k = par[blocks[0], 3 * k : 3 * k + 3]
        p_k = par[blocks[0], 6 + 3 * k : 9 + 3 * k]
        scale_x = np.maximum(np.linalg.norm(x_k, axis=1), 0.1 * res.length_m[blocks[0]])
        ex = np.linalg.norm(richardson(res.position, first) - x_k, axis=1) / scale_x
        ep = np.linalg.norm(richardson(p_vec, first) - p_k, axis=1) / np.maximum(np.linalg.norm(p_k, axis=1), 1e-2)
        wx = max(wx, float(np.max(ex[same], initial=0.0)))
        wp = max(wp, float(np.max(ep[same], initial=0.0)))
    return wx, wp


def _baseline(method: str, dirs: np.ndarray, **kw):
    profile = profile_from_spec(Job.model_validate(_spec()).profile)
    res, _ = trace_numerical(
        method,
        "exact",
        exact_spec=exact_media_spec(profile),
        c_ref=profile.c_ref,
        origins=np.repeat(SRC[None], dirs.shape[0], axis=0),
        directions=dirs,
        max_time_s=30.0,
        max_reflections=20,
        step_m=STEP_M[method],
        tolerance=TOLERANCE[method],
        domain_min=LO,
        domain_max=HI,
        paraxial=True,
        **kw,
    )
    return res


def _spec() -> dict:
    return {
        "name": "baseline-paraxial",
        "scene": {"domain": {"min": LO.tolist(), "max": HI.tolist()}, "ground": {"kind": "flat"}},
        "profile": LOG_DOWN,
        "sources": [{"position": SRC.tolist()}],
        "rays": {"elevation_deg": {"min": -5, "max": 5, "count": 3}, "max_time_s": 30.0, "max_reflections": 20},
        "solver": {"curve": "parabolic", "representation": "slabs"},
        "outputs": ["report"],
    }


@pytest.mark.parametrize("method", ["euler", "euler_adaptive", "rk4", "dopri5"])
@pytest.mark.parametrize("renormalize", [False, True])
def test_baseline_variational_derivatives_match_the_baseline_itself(method, renormalize):
    """Each method's variational derivatives against central differences of that method's own launches."""
    dirs, n = _fan(FAN_EL, FAN_AZ)
    res = _baseline(method, dirs, renormalize=renormalize)
    blocks = [slice(k * n, (k + 1) * n) for k in range(9)]
    same = res.status[blocks[0]] == STATUS_EXITED
    for b in blocks[1:]:
        same &= (res.steps[b] == res.steps[blocks[0]]) & (res.reflections[b] == res.reflections[blocks[0]])
        same &= res.status[b] == STATUS_EXITED
    wx, wp = _errors(res, n, same)
    out = {"compared": int(same.sum()), "reflections": int(res.reflections[blocks[0]][same].sum()), "x": wx, "p": wp}
    print(method, renormalize, out)
    if method == "euler_adaptive":
        # step doubling changes its step sequence between neighbouring launches on most rays (another map
        # branch): measured, one ray of six keeps the same accepted steps
        assert out["compared"] >= 1, out
    else:
        assert out["compared"] >= 4, out
        assert out["reflections"] >= 4, out
    assert max(wx, wp) < 1e-6, out


def _analytic_perp(epsilon: float, paraxial: bool | str) -> tuple[np.ndarray, np.ndarray]:
    """|X_el,perp| and reflections of the fan's base rays, analytic tracer on a slab mesh of the profile."""
    job = Job.model_validate(
        {**_spec(), "solver": {"curve": "parabolic", "representation": "slabs", "epsilon": epsilon}}
    )
    profile = profile_from_spec(job.profile)
    media = build_media(profile, "parabolic", job.solver, LO, HI, ground="reflect", top=job.scene.top.kind)
    dirs, n = _fan(FAN_EL, FAN_AZ)
    cells = media.locate(SRC[None])
    res = trace(
        media.mesh,
        "parabolic",
        profile.c_ref,
        np.repeat(SRC[None], n, axis=0),
        dirs[:n],
        np.full(n, cells[0]),
        max_time_s=30.0,
        max_reflections=20,
        paraxial=paraxial,
    )
    assert np.all(res.status == STATUS_EXITED)
    return _perp(res, 0), res.reflections


def _perp(res, k: int) -> np.ndarray:
    x = res.paraxial[:, 3 * k : 3 * k + 3]
    x = x - np.sum(x * res.direction, axis=1)[:, None] * res.direction
    return np.linalg.norm(x, axis=1)


def test_smooth_medium_derivatives_converge_to_dopri5_on_the_exact_profile():
    """The analytic tracer's paraxial state in the smooth medium (paraxial="smooth", what beams carry:
    mesh/hessian.py) on slab meshes of the profile converges to DOPRI5's variational derivatives on the
    exact profile. The exact derivatives of the piecewise-linear mesh do not (docs/physics.md §11): measured
    |X_el,perp| of the el -4 ray (2 reflections; DOPRI5 979.66, an independent scipy DOP853 979.66): exact
    mesh 852 / 893 / 1051 / 975 at epsilon 1e-5 / 1e-6 / 1e-7 / 1e-8, smooth medium 1006 / 983.1 / 979.78 /
    979.64. Smooth medium, worst relative difference over the 6 rays: 0.107 at 1e-6 (607 layers), 0.016 at
    1e-7 (1,917 layers; the el 0.5 ray near a caustic, |X| = 7.4), rays away from caustics 5.5e-4."""
    num = _baseline("dopri5", _fan(FAN_EL, FAN_AZ)[0][: FAN_EL.size])
    assert np.all(num.status == STATUS_EXITED)
    ref = _perp(num, 0)
    worst = {}
    for eps in (1e-6, 1e-7):
        xa, refl = _analytic_perp(eps, "smooth")
        np.testing.assert_array_equal(refl, num.reflections)
        rel = np.abs(xa - ref) / ref
        worst[eps] = float(rel.max())
        far = ref > 100.0  # away from caustics
        print(eps, np.round(xa, 3), rel.round(5))
    assert num.reflections.sum() >= 12
    assert worst[1e-7] < 0.03, worst
    assert worst[1e-7] < worst[1e-6] / 3.0, worst  # converges with the mesh
    assert float(rel[far].max()) < 2e-3, rel

"""Variational equations of the numerical baselines (docs/physics.md §10, "Numerical baselines").

Oracle 1: the baseline itself. Each method's carried launch-angle derivatives (X_k, P_k) must be the
derivative of what that method computes: the same ray launched 1e-6 and 5e-7 rad away in elevation and
azimuth, on both sides, differentiated on the exit plane (Richardson, truncation O(h^4)). Rays whose
neighbours took a different number of accepted steps or reflections (another step sequence: the map
is not smooth there) are left out; the test asserts that most are compared. Exact media (the closed-form
A-LD log profile, smooth), ground reflections.

Oracle 2: the analytic tracer's exact derivatives (engine/kernels/paraxial.py) on a fine slab mesh of the
same profile: agreement to the mesh's own discretisation of the medium (stated below as measured).
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


@pytest.mark.slow  # 260 s on 2 cores (a fine slab mesh and DOPRI5 at tight tolerance)
@pytest.mark.xfail(
    strict=True,
    reason="open: measured 2.3 relative difference of |X_perp| between DOPRI5 on the exact profile and the "
    "analytic tracer on a 1e-5 slab mesh (6 rays; each agrees with its own central differences). Positions converge "
    "with the mesh (0.05 m at epsilon 1e-5, 1e-3 m at 1e-7) but the mesh's |X_el,perp| does not converge to DOPRI5's "
    "on rays with ground reflections (el -4: 852, 893, 1051 at 1e-5, 1e-6, 1e-7 vs 980); az agrees to 1e-15",
)
def test_baseline_variational_derivatives_match_the_analytic_ones():
    """DOPRI5 on the exact profile against the analytic parabolic tracer's exact derivatives on a fine slab
    mesh (the mesh's piecewise-linear n^2 differs from the profile: agreement to that discretisation)."""
    job = Job.model_validate({**_spec(), "solver": {"curve": "parabolic", "representation": "slabs", "epsilon": 1e-5}})
    profile = profile_from_spec(job.profile)
    media = build_media(profile, "parabolic", job.solver, LO, HI, ground="reflect", top=job.scene.top.kind)
    dirs, n = _fan(FAN_EL, FAN_AZ)
    dirs = dirs[:n]
    cells = media.locate(SRC[None])
    ana = trace(
        media.mesh,
        "parabolic",
        profile.c_ref,
        np.repeat(SRC[None], n, axis=0),
        dirs,
        np.full(n, cells[0]),
        max_time_s=30.0,
        max_reflections=20,
        paraxial=True,
    )
    num = _baseline("dopri5", dirs)
    ok = (ana.status == STATUS_EXITED) & (num.status == STATUS_EXITED) & (ana.reflections == num.reflections)
    # both on the same exit plane: compare the transverse spreading |X_k,perp| and the tube J
    worst = 0.0
    for res in (ana, num):
        assert res.paraxial is not None
    t = ana.direction
    for k in range(2):
        xa = ana.paraxial[:, 3 * k : 3 * k + 3]
        xn = num.paraxial[:, 3 * k : 3 * k + 3]
        xa = xa - np.sum(xa * t, axis=1)[:, None] * t
        xn = xn - np.sum(xn * num.direction, axis=1)[:, None] * num.direction
        rel = np.abs(np.linalg.norm(xa, axis=1) - np.linalg.norm(xn, axis=1)) / np.linalg.norm(xn, axis=1)
        worst = max(worst, float(np.max(rel[ok], initial=0.0)))
    print("analytic vs dopri5", int(ok.sum()), worst)
    assert ok.sum() >= 4
    assert worst < 1e-2, worst

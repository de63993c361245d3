"""Property-based checks of kernel invariants through the public tracer (engine/tracer.py ``trace``).

- An exited ray's end point lies on the domain face it left through (the open sides and top of a
  Delaunay tet mesh), within ON_FACE_TOL of the domain size.
- Travel time and arc length never decrease along a recorded path; in a homogeneous medium
  ``length = c t`` at every sample (docs/physics.md §2, travel time and arc length).
- Reciprocity (time reversal): a ray traced for t from S to P and relaunched from P along its reversed
  end tangent for the same t comes back to S, in a homogeneous medium over reflecting ground and in a
  linear-c medium (circular curve, docs/physics.md §3); in linear c its travel time also matches the
  closed form between two points, t = acosh(1 + g^2 R^2 / (2 c_S c_P)) / g (independent of the kernel's).

Examples are bounded (a few dozen per property); the meshes are built once per module.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bentray  # noqa: F401
from bentray.engine.constants import STATUS_EXITED, STATUS_TIME_LIMIT
from bentray.engine.mesh.cells import locate_points
from bentray.engine.mesh.fcc import fcc_resample
from bentray.engine.mesh.slabs import build_slab_mesh, locate_in_slabs
from bentray.engine.mesh.tets import build_tet_mesh
from bentray.engine.tracer import trace

LO = np.array([0.0, 0.0, 0.0])
HI = np.array([200.0, 160.0, 120.0])
C_REF = 340.0
SIZE = float(np.linalg.norm(HI - LO))
ON_FACE_TOL = 1e-9 * SIZE  # stated tolerance: an exit point is on its face plane to 1e-9 of the domain
RETURN_TOL = 1e-8  # time reversal: back at the source to 1e-8 of the path length
PROPS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)


@pytest.fixture(scope="module")
def homogeneous_tets():
    d = 20.0
    pts = fcc_resample(LO, HI, lambda x: np.full(len(x), d), d_min=d, d_max=d)
    return build_tet_mesh(LO, HI, pts, lambda x: np.ones(len(x)), spacing=lambda x: np.full(len(x), d)).cells


def _unit(theta: float, phi: float) -> np.ndarray:
    return np.array([math.cos(theta) * math.cos(phi), math.cos(theta) * math.sin(phi), math.sin(theta)])


points = st.tuples(*(st.floats(0.05, 0.95) for _ in range(3))).map(lambda f: LO + np.array(f) * (HI - LO))
directions = st.tuples(st.floats(-1.5, 1.5), st.floats(-math.pi, math.pi)).map(lambda a: _unit(*a))


@PROPS
@given(origin=points, direction=directions)
def test_an_exited_ray_ends_on_the_face_plane_it_left_through(homogeneous_tets, origin, direction):
    start = locate_points(homogeneous_tets, origin[None, :])
    r = trace(homogeneous_tets, "parabolic", C_REF, origin[None], direction[None], start, max_time_s=10.0,
              max_reflections=4)  # fmt: skip
    assert r.status[0] == STATUS_EXITED  # 10 s is 3.4 km: every ray leaves through an open face
    p = r.position[0]
    # open faces: the four sides and the top (the ground z = 0 reflects)
    gaps = np.abs(np.array([p[0] - LO[0], HI[0] - p[0], p[1] - LO[1], HI[1] - p[1], HI[2] - p[2]]))
    assert gaps.min() <= ON_FACE_TOL, f"end point {p} is {gaps.min():.3g} m from every open face"
    assert np.all(p >= LO - ON_FACE_TOL) and np.all(p <= HI + ON_FACE_TOL)


@PROPS
@given(origin=points, direction=directions, curved=st.booleans())
def test_time_and_arc_length_increase_along_recorded_paths(homogeneous_tets, origin, direction, curved):
    if curved:  # n^2 = 1 + 0.01 z in one slab: parabolas, with ground reflections
        z = np.array([LO[2], HI[2]])
        mesh = build_slab_mesh(LO, HI, z, lambda zz: 1.0 + 0.01 * zz)
        start = locate_in_slabs(z, origin[None, :])
    else:
        mesh = homogeneous_tets
        start = locate_points(mesh, origin[None, :])
    r = trace(mesh, "parabolic", C_REF, origin[None], direction[None], start, max_time_s=1.0, max_reflections=6,
              path_samples=40)  # fmt: skip
    assert r.paths is not None
    t = r.paths.time_s[r.paths.offsets[0] : r.paths.offsets[1]]
    s = r.paths.length_m[r.paths.offsets[0] : r.paths.offsets[1]]
    assert len(t) >= 2
    assert np.all(np.diff(t) >= 0.0) and np.all(np.diff(s) >= 0.0)
    assert t[-1] == pytest.approx(r.time_s[0], abs=1e-12) and s[-1] == pytest.approx(r.length_m[0], rel=1e-12)
    if not curved:
        np.testing.assert_allclose(s, C_REF * t, rtol=1e-12, atol=1e-9)


def _round_trip(mesh, locate, curve, origin, direction, t):
    out = trace(mesh, curve, C_REF, origin[None], direction[None], locate(origin[None, :]), max_time_s=t,
                max_reflections=10)  # fmt: skip
    if out.status[0] != STATUS_TIME_LIMIT:
        return out, None
    p, back_dir = out.position[0], -out.direction[0]
    back = trace(mesh, curve, C_REF, p[None], back_dir[None], locate(p[None, :]), max_time_s=t, max_reflections=10)
    return out, back


@PROPS
@given(origin=points, direction=directions, t=st.floats(0.05, 0.5))
def test_time_reversal_in_a_homogeneous_medium_over_reflecting_ground(homogeneous_tets, origin, direction, t):
    out, back = _round_trip(homogeneous_tets, lambda x: locate_points(homogeneous_tets, x), "parabolic", origin,
                            direction, t)  # fmt: skip
    if back is None:  # left the domain first: nothing to reverse
        assert out.status[0] == STATUS_EXITED
        return
    assert back.status[0] == STATUS_TIME_LIMIT
    assert back.reflections[0] == out.reflections[0]
    assert np.linalg.norm(back.position[0] - origin) <= RETURN_TOL * C_REF * t
    if out.reflections[0] == 0:  # straight line: t = |P - S| / c both ways
        assert np.linalg.norm(out.position[0] - origin) == pytest.approx(C_REF * t, rel=1e-12)


G = 0.5  # c = 300 + G z (m/s): strong enough to bend a 150 m ray visibly


@PROPS
@given(origin=points, direction=directions, t=st.floats(0.05, 0.4))
def test_linear_c_reciprocity_and_the_two_point_travel_time(origin, direction, t):
    z = np.array([LO[2], HI[2]])
    mesh = build_slab_mesh(LO, HI, z, lambda zz: 300.0 + G * zz)
    locate = lambda x: locate_in_slabs(z, x)  # noqa: E731
    out, back = _round_trip(mesh, locate, "circular", origin, direction, t)
    if back is None:
        assert out.status[0] == STATUS_EXITED
        return
    assert back.status[0] == STATUS_TIME_LIMIT
    assert np.linalg.norm(back.position[0] - origin) <= RETURN_TOL * 300.0 * t
    if out.reflections[0] == 0:
        p = out.position[0]
        c_s, c_p = 300.0 + G * origin[2], 300.0 + G * p[2]
        r2 = float(np.sum((p - origin) ** 2))
        closed = math.acosh(1.0 + G * G * r2 / (2.0 * c_s * c_p)) / G
        assert closed == pytest.approx(t, rel=1e-9)

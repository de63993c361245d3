"""Every boundary case of docs/physics.md §5, each against a closed form or an exact invariant.

Ray end states: time_limit (exactly at max_time, solved inside the last segment), reflection_limit,
exited (open face), step_limit, lost (never silent: counted, nudges recorded).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine.constants import (
    BOUNDARY_OPEN,
    FACE_UNUSED,
    MAX_NUDGES_IN_A_ROW,
    STATUS_EXITED,
    STATUS_LOST,
    STATUS_REFLECTION_LIMIT,
    STATUS_STEP_LIMIT,
    STATUS_TIME_LIMIT,
)
from bentray.engine.kernels.traverse import _walk
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.mesh.slabs import build_slab_mesh, locate_in_slabs
from bentray.engine.tracer import trace

LO = np.array([-100.0, -100.0, 0.0])
HI = np.array([1000.0, 100.0, 500.0])
C_REF = 340.0


def _run(z, m_of_z, origin, direction, curve="parabolic", top="open", **kw):
    mesh = build_slab_mesh(LO, HI, np.asarray(z, float), m_of_z, top=top)
    o = np.atleast_2d(np.asarray(origin, float))
    d = np.atleast_2d(np.asarray(direction, float))
    d = d / np.linalg.norm(d, axis=1)[:, None]
    kw.setdefault("max_time_s", 1.0)
    kw.setdefault("max_reflections", 10)
    return trace(mesh, curve, C_REF, o, d, locate_in_slabs(np.asarray(z, float), o), **kw)


def homogeneous(z):
    return np.ones_like(z)


@pytest.mark.parametrize("curve", ["parabolic", "circular", "n_linear"])
def test_time_limit_is_exact_inside_a_segment(curve):
    m = (lambda z: np.full_like(z, 340.0)) if curve == "circular" else homogeneous
    r = _run([0, 500], m, [0, 0, 10], [1, 0, 0], curve=curve, max_time_s=0.5)
    assert r.status[0] == STATUS_TIME_LIMIT
    assert r.time_s[0] == 0.5
    np.testing.assert_allclose(r.position[0], [170.0, 0.0, 10.0], rtol=0, atol=1e-12)
    assert r.length_m[0] == pytest.approx(170.0, rel=1e-15)


def test_time_limit_inside_a_curved_segment_matches_closed_form():
    """n^2 = 1 + a z: the parabola reached at exactly t = T, sigma from the cubic (brentq here)."""
    from scipy.optimize import brentq

    a = 0.004
    x0 = np.array([0.0, 0.0, 20.0])
    d0 = np.array([0.8, 0.0, 0.6])
    r = _run([0, 500], lambda z: 1 + a * z, x0, d0, max_time_s=0.7)
    n0 = math.sqrt(1 + a * x0[2])
    p0 = n0 * d0
    g = np.array([0, 0, a])
    sig = brentq(lambda s: (n0**2 * s + g @ p0 * s**2 / 2 + g @ g * s**3 / 12) / C_REF - 0.7, 0, 1e4, xtol=1e-15)
    np.testing.assert_allclose(r.position[0], x0 + p0 * sig + g * sig**2 / 4, rtol=1e-13)


def test_ground_reflection_is_specular_and_counted():
    r = _run([0, 500], homogeneous, [0, 0, 10], [1, 0, -1], max_time_s=0.1)
    assert r.reflections[0] == 1
    # straight ray: mirror image source at z = -10
    t = 0.1
    image = np.array([0, 0, -10.0]) + C_REF * t * np.array([1, 0, 1]) / math.sqrt(2)
    np.testing.assert_allclose(r.position[0], image, atol=1e-11)
    np.testing.assert_allclose(r.direction[0], np.array([1, 0, 1]) / math.sqrt(2), atol=1e-15)


def test_reflection_limit_stops_on_the_ground():
    r = _run([0, 500], homogeneous, [0, 0, 10], [1, 0, -1], max_reflections=0)
    assert r.status[0] == STATUS_REFLECTION_LIMIT
    assert r.reflections[0] == 0
    np.testing.assert_allclose(r.position[0], [10.0, 0.0, 0.0], atol=1e-12)


def test_reflecting_top_is_a_lid():
    r = _run([0, 500], homogeneous, [0, 0, 10], [0, 0, 1], top="reflect", max_time_s=2.0)
    # up 490 m, down 500 m (ground), up 10 m ... 680 m in 2 s: 490 + 190 -> at z = 310 going down
    assert r.reflections[0] == 1
    np.testing.assert_allclose(r.position[0], [0, 0, 500 - (680 - 490)], atol=1e-10)


def test_open_side_exits_on_the_boundary():
    r = _run([0, 500], homogeneous, [0, 0, 10], [1, 0, 0], max_time_s=10.0)
    assert r.status[0] == STATUS_EXITED
    np.testing.assert_allclose(r.position[0], [1000.0, 0.0, 10.0], atol=1e-12)
    assert r.time_s[0] == pytest.approx(1000.0 / C_REF, rel=1e-15)


def test_step_cap_is_reported():
    z = np.linspace(0, 500, 101)
    r = _run(z, homogeneous, [0, 0, 2.5], [0, 0, 1], max_steps=5)
    assert r.status[0] == STATUS_STEP_LIMIT


def test_ray_leaving_through_its_entry_face():
    """n^2 decreasing upward bends rays down: a shallow ray enters the upper slab and turns back down
    inside it, leaving through the face it came in by (the non-zero root of the entry face)."""
    a = -0.002
    x0 = np.array([0.0, 0.0, 1.0])
    d0 = np.array([math.cos(0.05), 0.0, math.sin(0.05)])
    two = _run([0, 2, 500], lambda z: 1 + a * z, x0, d0, max_time_s=0.5)
    one = _run([0, 500], lambda z: 1 + a * z, x0, d0, max_time_s=0.5)
    assert two.crossings[0] >= 2  # up into the top slab, back down through the same face
    assert two.reflections[0] == one.reflections[0] == 1
    np.testing.assert_allclose(two.position[0], one.position[0], atol=1e-10)


@pytest.mark.parametrize("curve", ["parabolic", "circular", "n_linear"])
@pytest.mark.parametrize("direction", [[0, 0, 1], [0, 0, -1]], ids=["up", "down"])
def test_ray_along_the_gradient(curve, direction):
    """Vertical rays in a linear profile stay on the vertical line; travel time is exact."""
    m = {"parabolic": lambda z: 1 + 0.01 * z, "circular": lambda z: 340 + 0.1 * z, "n_linear": lambda z: 1 + 0.002 * z}[
        curve
    ]
    z = np.linspace(0, 500, 11)
    r = _run(z, m, [0, 0, 100], direction, curve=curve, max_time_s=0.2)
    assert r.status[0] == STATUS_TIME_LIMIT
    assert r.position[0][0] == pytest.approx(0.0, abs=1e-9) and r.position[0][1] == 0.0
    assert r.nudges[0] == 0 and not np.any(np.isnan(r.position))


def test_grazing_launch_at_the_ground_under_upward_refraction():
    """Source a micrometre above the ground, elevations around 0, strongly upward-refracting."""
    a = 0.01
    el = np.radians(np.linspace(-1e-3, 1e-3, 21))
    d = np.column_stack([np.cos(el), np.zeros_like(el), np.sin(el)])
    z = np.concatenate([[0.0], np.geomspace(1e-6, 500, 200)])
    mesh = build_slab_mesh(LO, HI, z, lambda zz: 1 + a * zz)
    o = np.tile([0, 0, 1e-6], (21, 1))
    r = trace(mesh, "parabolic", C_REF, o, d, locate_in_slabs(z, o), max_time_s=1.0, max_reflections=10)
    assert np.all(r.status == STATUS_TIME_LIMIT)
    assert np.all(np.isfinite(r.position)) and np.all(r.position[:, 2] > 0)


@pytest.mark.parametrize("factor", [100.0, 1e4])
def test_huge_gradients_lose_no_ray(factor):
    z = np.linspace(0, 500, 51)
    el = np.radians(np.linspace(-45, 45, 31))
    d = np.column_stack([np.cos(el), np.zeros_like(el), np.sin(el)])
    o = np.tile([0, 0, 10], (31, 1))
    for curve, m in [
        ("parabolic", lambda zz: 1 + 0.01 * factor * zz),
        ("circular", lambda zz: 340 + 0.1 * factor * zz),
    ]:
        mesh = build_slab_mesh(LO, HI, z, m)
        r = trace(mesh, curve, C_REF, o, d, locate_in_slabs(z, o), max_time_s=1.0, max_reflections=10_000)
        assert not np.any(r.status == STATUS_LOST), curve
        assert np.all(np.isfinite(r.position))


def test_a_ray_with_no_exit_is_nudged_counted_and_reported_lost():
    """One cell with a single face behind the ray: no exit exists; the ray must end as lost after
    MAX_NUDGES_IN_A_ROW nudges, not loop or vanish."""
    k = 4
    planes = np.zeros((1, k, 4))
    planes[0, 0] = [-1.0, 0.0, 0.0, 0.0]  # x >= 0
    neighbours = np.full((1, k), FACE_UNUSED, dtype=np.int64)
    neighbours[0, 0] = BOUNDARY_OPEN
    mesh = CellMesh(
        planes=planes,
        neighbours=neighbours,
        neighbour_face=np.full((1, k), -1, dtype=np.int64),
        media_ref=np.ones(1),
        ref_point=np.zeros((1, 3)),
        gradient=np.zeros((1, 3)),
        size=np.ones(1),
        face_material=np.zeros((1, k), dtype=np.int64),
    )
    r = trace(
        mesh,
        "parabolic",
        C_REF,
        np.array([[1.0, 0, 0]]),
        np.array([[1.0, 0, 0]]),
        np.array([0]),
        max_time_s=1.0,
        max_reflections=1,
    )
    assert r.status[0] == STATUS_LOST
    assert r.nudges[0] == MAX_NUDGES_IN_A_ROW + 1


def test_walk_relocates_across_cells_and_boundaries():
    z = np.array([0.0, 1.0, 2.0, 500.0])
    mesh = build_slab_mesh(LO, HI, z, homogeneous)
    x = np.array([0.0, 0.0, 2.5])
    cell, outcome = _walk(mesh.planes, mesh.neighbours, 0, x)
    assert (cell, outcome) == (2, 0)
    x = np.array([0.0, 0.0, -1e-9])
    cell, outcome = _walk(mesh.planes, mesh.neighbours, 1, x)
    assert (cell, outcome) == (0, 2) and x[2] == 0.0  # projected back onto the ground
    x = np.array([2000.0, 0.0, 0.5])
    assert _walk(mesh.planes, mesh.neighbours, 0, x)[1] == 1  # beyond the open side


def test_zero_gradient_all_curves_are_straight():
    for curve, m in [
        ("parabolic", homogeneous),
        ("circular", lambda z: np.full_like(z, 340.0)),
        ("n_linear", homogeneous),
    ]:
        r = _run(np.linspace(0, 500, 7), m, [0, 0, 50], [0.6, 0.0, 0.8], curve=curve, max_time_s=0.5)
        np.testing.assert_allclose(r.position[0], [0.6 * 170, 0, 50 + 0.8 * 170], atol=1e-10)

"""Curved legs of diffracted paths (closed-form circular rays of a linear-c fit) against independent ray
shooting (scipy solve_ivp on the ray equations) and tests/reference/linear_c.py's quadrature."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bentray.engine.diffraction.legs import circular_legs, fit_linear_c, straight_legs
from bentray.engine.diffraction.paths import edge_paths
from bentray.engine.diffraction.wedge import Edge
from tests.reference import linear_c as lc

C0 = 340.0
A = np.array([[0.0, 0.0, 2.0], [10.0, 5.0, 0.5], [0.0, 0.0, 30.0], [3.0, 1.0, 4.0]])
B = np.array([[500.0, 30.0, 8.0], [-200.0, 40.0, 60.0], [800.0, 0.0, 1.0], [40.0, 0.0, 4.0]])


def _shoot(a: np.ndarray, t0: np.ndarray, length: float, g: float) -> tuple[np.ndarray, float, np.ndarray]:
    """Integrate dx/ds = T, dT/ds = -(grad c - (grad c . T) T) / c, dt/ds = 1/c over arc length s."""

    def rhs(_s: float, y: np.ndarray) -> np.ndarray:
        t = y[3:6]
        c = C0 + g * y[2]
        grad = np.array([0.0, 0.0, g])
        return np.concatenate([t, -(grad - (grad @ t) * t) / c, [1.0 / c]])

    sol = solve_ivp(rhs, (0.0, length), np.concatenate([a, t0, [0.0]]), rtol=1e-11, atol=1e-11, method="DOP853")
    y = sol.y[:, -1]
    return y[:3], float(y[6]), y[3:6]


@pytest.mark.parametrize("g", [0.1, -0.05])
def test_circular_legs_against_ray_shooting(g: float) -> None:
    """Shooting along the closed-form start tangent for the closed-form arc length lands on B (< 1e-6 of
    the leg), with the closed-form travel time (< 1e-9 relative) and end tangent (< 1e-7)."""
    legs = circular_legs(A, B, C0 + g * A[:, 2], np.full(len(A), g))
    for i in range(len(A)):
        end, t, tang = _shoot(A[i], legs.t_start[i], float(legs.length[i]), g)
        chord = np.linalg.norm(B[i] - A[i])
        assert np.linalg.norm(end - B[i]) < 1e-6 * chord
        assert t == pytest.approx(legs.time[i], rel=1e-9)
        assert t == pytest.approx(lc.travel_time_quadrature(A[i], B[i], C0, g), rel=1e-9)
        assert np.linalg.norm(tang - legs.t_end[i]) < 1e-7
        assert legs.length[i] > chord  # an arc is longer than its chord


def test_fit_and_straight_limit() -> None:
    """The fit recovers a linear profile exactly; g -> 0 gives the straight legs."""
    ca, g = fit_linear_c(lambda p, e: C0 + 0.07 * p[:, 2] + 2.0 * e[:, 0], A, B)  # wind 2 m/s along +x
    e_x = (B - A)[:, 0] / np.hypot(*(B - A)[:, :2].T)
    assert g == pytest.approx(np.full(len(A), 0.07), abs=1e-12)
    assert ca == pytest.approx(C0 + 0.07 * A[:, 2] + 2.0 * e_x, abs=1e-9)
    s = straight_legs(A, B, C0)
    c = circular_legs(A, B, np.full(len(A), C0), np.full(len(A), 1e-14))
    assert c.length == pytest.approx(s.length, rel=1e-12) and c.time == pytest.approx(s.time, rel=1e-12)


def test_refraction_changes_the_barrier_attenuation() -> None:
    """A 4 m screen, source 0.5 m high 5 m before it, receiver 200 m behind at 1.5 m (no ground): downward
    refraction (c = 340 + 0.1 z) shortens the path over the edge relative to the direct ray, so the
    diffracted level rises (measured +0.3 dB); upward refraction lowers it (-0.3 dB). The diffracted leg
    times are the closed-form arcs."""
    edge = Edge(np.array([0.0, 0.0, 4.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0]), 2.0)
    src, rec = np.array([-5.0, 0.0, 0.5]), np.array([[200.0, 0.0, 1.5]])
    f = np.array([500.0, 1000.0])
    levels = {}
    for g in (-0.1, 0.0, 0.1):

        def legs(a: np.ndarray, b: np.ndarray, g: float = g):
            return circular_legs(a, b, C0 + g * np.atleast_2d(a)[:, 2], np.full(np.atleast_2d(a).shape[0], g))

        p = edge_paths(edge, src, rec, f, C0, None, None, legs=legs)[0]
        levels[g] = 20 * np.log10(np.abs(p[:, 0]))
    print("\n diffracted level, g = -0.1 / 0 / +0.1:", {k: np.round(v, 2) for k, v in levels.items()})
    assert np.all(levels[0.1] > levels[0.0] + 0.2) and np.all(levels[-0.1] < levels[0.0] - 0.2)

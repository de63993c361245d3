"""Curve primitives against independent references: scipy quadrature and direct evaluation.

Tolerances: closed forms are exact, so agreement is required to ~1e-12 relative (quadrature at
epsrel 1e-13); root selection must match numpy's polynomial roots to 1e-12.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

import bentray  # noqa: F401  (environment defaults before numba)
from bentray.engine.kernels import circular, nlinear, parabolic
from bentray.engine.kernels.roots import face_exit_parameter, upcrossing_root

RNG = np.random.default_rng(1234)


# ---------------------------------------------------------------------------------------------
# quadratic up-crossing
# ---------------------------------------------------------------------------------------------


def _reference_upcrossing(a, b, c):
    roots = np.roots([a, b, c]) if a != 0 else (np.array([-c / b]) if b != 0 else np.array([]))
    best = math.inf
    for r in roots:
        if abs(r.imag) > 0:
            continue
        r = r.real
        if 2 * a * r + b > 0:
            best = r
    return best


@pytest.mark.parametrize("seed", range(5))
def test_upcrossing_matches_numpy_roots(seed):
    rng = np.random.default_rng(seed)
    for _ in range(400):
        a, b, c = rng.normal(size=3) * 10.0 ** rng.uniform(-6, 3, size=3)
        got = upcrossing_root(a, b, c)
        ref = _reference_upcrossing(a, b, c)
        if math.isinf(ref):
            assert math.isinf(got)
        else:
            assert got == pytest.approx(ref, rel=1e-9, abs=1e-12 * max(1.0, abs(ref)))


def test_upcrossing_linear_limit_and_tangent():
    assert upcrossing_root(0.0, 2.0, -4.0) == 2.0
    assert math.isinf(upcrossing_root(0.0, -2.0, 4.0))  # only a downward crossing
    assert math.isinf(upcrossing_root(1.0, -2.0, 1.0))  # tangent contact is not a crossing
    # tiny curvature: tends to the straight-line root without cancellation
    assert upcrossing_root(1e-30, 1.0, -3.0) == pytest.approx(3.0, rel=1e-15)


def test_entry_face_uses_nonzero_root_only():
    # entering (b < 0) and curving back (a > 0): exits through the entry face at -b/a
    assert face_exit_parameter(0.5, -1.0, 1e-9, True, 1e-12) == pytest.approx(2.0, rel=1e-15)
    # entering and curving away: never leaves through the entry face
    assert math.isinf(face_exit_parameter(-0.5, -1.0, 0.0, True, 1e-12))
    # grazing (b >= 0) at the entry face: no zero-length exit back out
    assert math.isinf(face_exit_parameter(0.5, 0.0, 0.0, True, 1e-12))


def test_point_on_face_moving_out_exits_immediately():
    # rounding put the point 1e-15 beyond the plane; moving outward: exit at parameter 0
    assert face_exit_parameter(0.1, 1.0, 1e-15, False, 1e-12) == 0.0
    # same point moving inward: no exit through this face
    assert math.isinf(face_exit_parameter(-0.1, -1.0, 1e-15, False, 1e-12))


# ---------------------------------------------------------------------------------------------
# parabolic curve
# ---------------------------------------------------------------------------------------------


def _quad_arc(p0, g, sigma):
    return quad(lambda u: np.linalg.norm(p0 + 0.5 * g * u), 0.0, sigma, epsabs=0.0, epsrel=1e-13, limit=200)[0]


PARABOLIC_CASES = [
    ("zero gradient", np.array([1.0, 0.0, 0.0]), np.zeros(3), 10.0),
    ("tiny gradient", np.array([0.6, 0.0, 0.8]), np.array([0.0, 0.0, 1e-14]), 100.0),
    ("paper n2-linear", np.array([0.7, 0.1, -0.7]), np.array([0.0, 0.0, 0.01]), 200.0),
    ("along gradient", np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.3]), 5.0),
    ("against gradient", np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 0.05]), 5.0),
    ("nearly against gradient", np.array([1e-7, 0.0, -1.0]), np.array([0.0, 0.0, 0.05]), 30.0),
    ("huge gradient", np.array([0.3, 0.4, 0.866]), np.array([3.0, -2.0, 50.0]), 0.3),
    ("grazing", np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -0.02]), 50.0),
]


@pytest.mark.parametrize(("label", "d0", "g", "sigma"), PARABOLIC_CASES, ids=[c[0] for c in PARABOLIC_CASES])
def test_parabolic_arc_length_matches_quadrature(label, d0, g, sigma):
    p0 = 1.02 * d0 / np.linalg.norm(d0)
    got = parabolic.arc_length(p0, g, sigma)
    ref = _quad_arc(p0, g, sigma)
    assert got == pytest.approx(ref, rel=1e-12)


def _mp_arc(p0, g, sigma):
    import mpmath as mp

    def speed(u):
        return mp.sqrt(sum((mp.mpf(p0[k]) + mp.mpf(g[k]) / 2 * u) ** 2 for k in range(3)))

    with mp.workdps(40):
        return mp.quad(speed, [0, sigma])


@pytest.mark.parametrize("e", [1e-6, 1.8e-4, 2e-4, 3.6e-3, 3.7e-3, 1.5e-2, 1.6e-2, 5e-2])
def test_parabolic_arc_length_by_quadrature_within_its_bound(e):
    """arc_length's Gauss-Legendre tiers (2, 3, 4 points up to half-turning ratios 1.9e-4, 3.66e-3, 1.57e-2,
    truncation <= 2.1e-16 relative by docs/physics.md section 2) and the closed form beyond, at the tier edges,
    against 40-digit mpmath quadrature: within 1e-15 relative (the bound plus a few ulps of rounding), for
    random directions, gradients from 1e-6 to 0.1 per metre and p0 (anti)parallel or normal to g."""
    import mpmath as mp

    rng = np.random.default_rng(7)
    worst = 0.0
    for i in range(40):
        g = rng.normal(size=3) * 10 ** rng.uniform(-6, -1)
        special = (g, -g, np.cross(g, [0.3, 0.1, 1.0]))  # along, against and normal to the gradient
        d = special[(i // 4) % 3] if i % 4 == 0 else rng.normal(size=3)
        p0 = (0.9 + 0.2 * rng.random()) * d / np.linalg.norm(d)
        sigma = 2 * e * np.linalg.norm(p0) / (np.linalg.norm(g) / 2)  # half-turning ratio ~e
        ref = _mp_arc(p0, g, sigma)
        worst = max(worst, float(abs(mp.mpf(parabolic.arc_length(p0, g, sigma)) - ref) / ref))
    assert worst <= 1e-15


def test_parabolic_time_is_integral_of_n2_over_cref():
    p0 = 1.01 * np.array([0.6, 0.0, 0.8])
    g = np.array([0.001, 0.0, 0.01])
    sigma = 123.0
    ref = quad(lambda u: np.dot(p0 + 0.5 * g * u, p0 + 0.5 * g * u) / 340.0, 0, sigma, epsrel=1e-14)[0]
    got = parabolic.travel_time(p0 @ p0, g @ p0, g @ g, sigma, 340.0)
    assert got == pytest.approx(ref, rel=1e-13)
    back = parabolic.sigma_at_time(p0 @ p0, g @ p0, g @ g, got, 2 * sigma, 340.0)
    assert back == pytest.approx(sigma, rel=1e-13)


def test_parabolic_state_solves_ray_ode():
    """x(sigma), p(sigma) against DOP853 of dx/dsigma = p, dp/dsigma = g/2 (n^2 linear)."""
    n0sq = 1.0
    g = np.array([0.0, 0.002, 0.01])
    x0 = np.array([1.0, 2.0, 3.0])
    d0 = np.array([0.8, 0.0, 0.6])
    p0 = math.sqrt(n0sq) * d0
    sol = solve_ivp(
        lambda s, y: np.concatenate([y[3:], 0.5 * g]),
        (0, 400.0),
        np.concatenate([x0, p0]),
        method="DOP853",
        rtol=1e-13,
        atol=1e-13,
    )
    x = np.empty(3)
    t = np.empty(3)
    parabolic.state_at(x0, p0, g, 400.0, x, t)
    np.testing.assert_allclose(x, sol.y[:3, -1], rtol=1e-11)
    np.testing.assert_allclose(t, sol.y[3:, -1] / np.linalg.norm(sol.y[3:, -1]), rtol=1e-11, atol=1e-13)


# ---------------------------------------------------------------------------------------------
# circular curve
# ---------------------------------------------------------------------------------------------


CIRCULAR_CASES = [
    ("paper c-linear", np.array([0.0, 0.0, 0.1]), np.array([0.8, 0.0, 0.6])),
    ("oblique gradient", np.array([0.03, -0.02, 0.1]), np.array([0.6, 0.64, 0.48])),
    ("along gradient", np.array([0.0, 0.0, 0.5]), np.array([0.0, 0.0, 1.0])),
    ("against gradient", np.array([0.0, 0.0, 0.5]), np.array([0.0, 0.0, -1.0])),
    ("zero gradient", np.zeros(3), np.array([0.0, 1.0, 0.0])),
    ("huge gradient", np.array([0.0, 0.0, 40.0]), np.array([1.0, 0.0, 0.0])),
]


@pytest.mark.parametrize(("label", "G", "d0"), CIRCULAR_CASES, ids=[c[0] for c in CIRCULAR_CASES])
def test_circular_curve_solves_ray_ode(label, G, d0):
    """Position, tangent, arc length and travel time against DOP853 of the ray equations in c-linear media."""
    c0 = 340.0
    x0 = np.array([0.0, 0.0, 10.0])
    k = np.zeros(3)
    kappa2, gnorm, w = circular.setup(c0, G, d0, k)
    u = 0.6 / math.sqrt(kappa2) if kappa2 > 0 else 50.0  # psi ~ 62 degrees of arc
    x = np.empty(3)
    t = np.empty(3)
    circular.state_at(x0, d0, k, kappa2, u, x, t)
    s_end = circular.arc_length(kappa2, u)

    def c_of(xx):
        return c0 + G @ (xx - x0)

    # arc-length parametrised ray equations for n = c0/c: d/ds(n T) = grad n
    def rhs(_s, y):
        xx, tt = y[:3], y[3:6]
        c = c_of(xx)
        grad_ln_n = -G / c
        return np.concatenate([tt, grad_ln_n - (grad_ln_n @ tt) * tt, [1.0 / c]])

    sol = solve_ivp(rhs, (0.0, s_end), np.concatenate([x0, d0, [0.0]]), method="DOP853", rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(x, sol.y[:3, -1], rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(t, sol.y[3:6, -1], atol=1e-10)
    assert circular.travel_time(c0, gnorm, w, u) == pytest.approx(sol.y[6, -1], rel=1e-10)
    # closed-form inverse of the time equation
    assert circular.u_at_time(c0, gnorm, w, circular.travel_time(c0, gnorm, w, u)) == pytest.approx(u, rel=1e-12)


def test_circular_plane_equation_gives_points_on_plane():
    c0 = 340.0
    G = np.array([0.01, 0.0, 0.1])
    d0 = np.array([0.6, 0.0, 0.8])
    x0 = np.array([5.0, 1.0, 2.0])
    k = np.zeros(3)
    kappa2, _, _ = circular.setup(c0, G, d0, k)
    for m, h in [((0.0, 0.0, 1.0), 300.0), ((1.0, 0.0, 0.0), 250.0), ((0.6, 0.0, 0.8), 100.0)]:
        a, b, c = circular.plane_coefficients(m[0], m[1], m[2], h, x0, d0, k, kappa2)
        u = face_exit_parameter(a, b, c, False, 1e-12)
        assert math.isfinite(u) and u > 0
        x = np.empty(3)
        t = np.empty(3)
        circular.state_at(x0, d0, k, kappa2, u, x, t)
        assert np.dot(m, x) == pytest.approx(h, rel=1e-12)


# ---------------------------------------------------------------------------------------------
# n-linear curve (comparison method)
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("d0", [np.array([0.8, 0.0, 0.6]), np.array([0.6, 0.48, -0.64]), np.array([1.0, 0.0, 0.0])])
def test_nlinear_catenary_solves_ray_ode(d0):
    n0 = 1.0
    g = np.array([0.0, 0.0, 0.02])
    x0 = np.zeros(3)
    er = np.empty(3)
    ez = np.empty(3)
    straight, alpha, xi, u0, _ = nlinear.setup(n0, g, d0, er, ez)
    assert not straight
    r = 40.0
    x = np.empty(3)
    t = np.empty(3)
    nlinear.state_at(x0, er, ez, alpha, xi, u0, r, x, t)
    s_end = nlinear.arc_length(alpha, xi, u0, r)

    def rhs(_s, y):
        xx, pp = y[:3], y[3:6]
        n = n0 + g @ (xx - x0)
        return np.concatenate([pp / n, g, [n / 340.0]])

    sol = solve_ivp(rhs, (0.0, s_end), np.concatenate([x0, n0 * d0, [0.0]]), method="DOP853", rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(x, sol.y[:3, -1], rtol=1e-10, atol=1e-10)
    p = sol.y[3:6, -1]
    np.testing.assert_allclose(t, p / np.linalg.norm(p), atol=1e-10)
    assert nlinear.travel_time(alpha, xi, u0, r, 340.0) == pytest.approx(sol.y[6, -1], rel=1e-10)


def test_nlinear_bisection_finds_plane_crossing():
    n0 = 1.0
    g = np.array([0.0, 0.0, 0.02])
    d0 = np.array([0.8, 0.0, -0.6])  # heads down, curves up: crosses z = -5 then would come back
    x0 = np.zeros(3)
    er = np.empty(3)
    ez = np.empty(3)
    _, alpha, xi, u0, _ = nlinear.setup(n0, g, d0, er, ez)
    cs = np.concatenate([er, ez, [alpha, xi, u0]])  # the curve record face_exit reads (curves.setup layout)
    r = nlinear.face_exit((0.0, 0.0, -1.0, 5.0), x0, cs, False, 1e-12, 10.0)
    x = np.empty(3)
    t = np.empty(3)
    nlinear.state_at(x0, er, ez, alpha, xi, u0, r, x, t)
    assert x[2] == pytest.approx(-5.0, abs=1e-12)
    assert t[2] < 0  # still descending: it is the first (outgoing) crossing

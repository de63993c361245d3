"""Exact-profile traversal: when the mesh represents the medium exactly, the traced rays must agree
with independent references to 1e-9 of the path length c0 t (after 10 s, with ground reflections).

- linear_n2 with the parabolic curve, linear_c with the circular curve, linear_n with the n-linear
  curve: each is linear in the quantity its curve needs, so one slab represents it exactly.
- references: scipy DOP853 at rtol 1e-12 (tests/reference/ray_ode.py), and for linear_c the
  textbook circle geometry (Snell invariant, centre on the plane c = 0), written out here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine.constants import STATUS_TIME_LIMIT
from bentray.engine.mesh.slabs import build_slab_mesh, locate_in_slabs
from bentray.engine.tracer import trace
from tests.reference.ray_ode import integrate_ray

LO = np.array([-50.0, -50.0, 0.0])
HI = np.array([4000.0, 50.0, 2600.0])
SOURCE = np.array([0.0, 0.0, 1.5])
T_END = 10.0
C_REF = 340.0
TOL = 1e-9  # relative to the path length c0 t


def _fan(count=91):
    el = np.radians(np.linspace(-45.0, 45.0, count))
    d = np.column_stack([np.cos(el), np.zeros_like(el), np.sin(el)])
    return np.tile(SOURCE, (count, 1)), d


def _trace_one_slab(m_of_z, curve, **kw):
    z = np.array([LO[2], HI[2]])
    mesh = build_slab_mesh(LO, HI, z, m_of_z)
    o, d = _fan()
    return trace(mesh, curve, C_REF, o, d, locate_in_slabs(z, o), max_time_s=T_END, max_reflections=50, **kw), d


CASES = {
    # name: (curve, m(z), n(x), grad n(x))
    "linear_n2/parabolic": (
        "parabolic",
        lambda z: 1.0 + 0.01 * z,
        lambda x: math.sqrt(1.0 + 0.01 * x[2]),
        lambda x: np.array([0.0, 0.0, 0.005 / math.sqrt(1.0 + 0.01 * x[2])]),
    ),
    "linear_c/circular": (
        "circular",
        lambda z: 340.0 + 0.1 * z,
        lambda x: C_REF / (340.0 + 0.1 * x[2]),
        lambda x: np.array([0.0, 0.0, -C_REF * 0.1 / (340.0 + 0.1 * x[2]) ** 2]),
    ),
    "linear_n/n_linear": (
        "n_linear",
        lambda z: 1.0 + 0.02 * z,
        lambda x: 1.0 + 0.02 * x[2],
        lambda x: np.array([0.0, 0.0, 0.02]),
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_exact_profiles_match_dop853(name):
    curve, m_of_z, n_of, grad_n_of = CASES[name]
    result, d = _trace_one_slab(m_of_z, curve)
    assert np.all(result.status == STATUS_TIME_LIMIT)
    assert np.all(result.time_s == T_END)
    worst = 0.0
    for i in range(0, 91, 6):
        ref = integrate_ray(n_of, grad_n_of, SOURCE, d[i], T_END, c_ref=C_REF)
        err = np.linalg.norm(result.position[i] - ref.position) / (340.0 * T_END)
        worst = max(worst, err)
        assert result.reflections[i] == ref.reflections
        assert result.length_m[i] == pytest.approx(ref.length_m, rel=TOL)
        np.testing.assert_allclose(result.direction[i], ref.direction, atol=1e-8)
    assert worst < TOL, f"{name}: worst relative position error {worst:.2e}"


def _circle_reference(c0, alpha, x0, elevation, t_end):
    """Closed-form ray in c = c0 + alpha z (alpha > 0) over a reflecting ground z = 0.

    The ray is an arc of a circle centred on the plane c = 0 (z_c = -c0/alpha) with radius
    R = c(z0) / (alpha cos(elevation)). With beta the angle on that circle (the local elevation),
    t = (gd^-1(beta0) - gd^-1(beta)) / alpha, gd^-1 = asinh(tan).
    """
    z_c = -c0 / alpha
    beta = elevation
    r_pos = 0.0
    R = (c0 + alpha * x0[2]) / (alpha * math.cos(beta))
    r_c = r_pos + R * math.sin(beta)
    t_left = t_end
    reflections = 0
    while True:
        beta_hit = -math.acos(-z_c / R)  # where the circle meets z = 0, descending
        t_hit = (math.asinh(math.tan(beta)) - math.asinh(math.tan(beta_hit))) / alpha
        if t_hit >= t_left:
            beta_end = math.atan(math.sinh(math.asinh(math.tan(beta)) - alpha * t_left))
            r = r_c - R * math.sin(beta_end)
            z = z_c + R * math.cos(beta_end)
            return np.array([r, 0.0, z]), reflections
        t_left -= t_hit
        r_hit = r_c - R * math.sin(beta_hit)
        beta = -beta_hit
        r_c = r_hit + R * math.sin(beta)
        reflections += 1


def test_linear_c_circular_matches_circle_geometry():
    curve, m_of_z, _, _ = CASES["linear_c/circular"]
    result, d = _trace_one_slab(m_of_z, curve)
    el = np.radians(np.linspace(-45.0, 45.0, 91))
    for i in range(91):
        ref, refl = _circle_reference(340.0, 0.1, SOURCE, el[i], T_END)
        err = np.linalg.norm(result.position[i] - ref) / (340.0 * T_END)
        assert err < TOL, f"ray {i}: {err:.2e}"
        assert result.reflections[i] == refl


@pytest.mark.parametrize("layers", [7, 60])
def test_exact_profile_is_exact_on_many_slabs(layers):
    """Splitting an exactly-linear medium into many slabs must not change the ray (walk is exact)."""
    curve, m_of_z, _, _ = CASES["linear_n2/parabolic"]
    one, _ = _trace_one_slab(m_of_z, curve)
    z = np.concatenate([[0.0], np.geomspace(0.01, HI[2], layers)])
    mesh = build_slab_mesh(LO, HI, z, m_of_z)
    o, d = _fan()
    many = trace(mesh, curve, C_REF, o, d, locate_in_slabs(z, o), max_time_s=T_END, max_reflections=50)
    np.testing.assert_allclose(many.position, one.position, rtol=0, atol=TOL * 340.0 * T_END)
    assert many.crossings.sum() > 91  # it really walked through layers
    assert many.nudges.sum() == 0

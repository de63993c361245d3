"""Self-checks of the creeping-wave residue series (engine/acoustics/creeping.py) and its oracle check
against the GFPE (tests/reference/gfpe.py) in the medium where the closed form is exact (linear k^2).

Checked: roots (relative residual <= 1e-9; the rigid limit gives the zeros of Ai' exactly, a very hard
impedance tends to them, a very soft one to the zeros of Ai), convergence with the number of terms
(60 vs 120 modes: <= 0.01 dB at shadow points), the limiting ray against the closed forms of linear c
(circle) and linear k^2 (parabola), the Numerov residue series of a sampled profile against the closed
form (kappa to 1e-6 relative, levels to 0.05 dB), and the closed form against the GFPE for
c = 340 / sqrt(1 + a z), a = 2 * 0.1 / 340 1/m, source 2 m, receiver 1.5 m, 150 m - 1 km (measured:
<= 0.08 dB rigid and grass at 100 Hz).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ai_zeros

from bentray.engine.acoustics import creeping
from bentray.engine.acoustics.creeping import (
    creeping_modes,
    creeping_pressure,
    fit_linear_k2,
    limiting_ray,
    profile_modes,
    profile_pressure,
)
from bentray.engine.acoustics.ground import delany_bazley_impedance
from tests.reference.gfpe import gfpe_tl

C0, A = 340.0, 2.0 * 0.1 / 340.0
ZS, ZR = 2.0, 1.5
GRASS = 200_000.0
RANGES = np.array([150.0, 200.0, 300.0, 500.0, 700.0, 1000.0])


def k2_linear(z):
    return C0 / np.sqrt(1.0 + A * np.asarray(z, float))


def _tl(modes, r=RANGES, zr=ZR):
    return -20.0 * np.log10(np.abs(creeping_pressure(modes, ZS, r, np.full(np.size(r), zr))))


@pytest.mark.parametrize("f", [100.0, 500.0, 2000.0])
@pytest.mark.parametrize("sigma", [None, GRASS, 20_000.0])
def test_roots_solve_the_boundary_condition(f, sigma):
    z = None if sigma is None else complex(delany_bazley_impedance(f, sigma))
    modes = creeping_modes(f, A, C0, z, 60)
    assert modes.residual <= 1e-9
    assert np.all(modes.kappa.imag > 0)  # every mode decays with range
    assert np.all(np.diff(modes.kappa.imag) > 0)  # ordered, higher modes decay faster


def test_rigid_limit_and_the_hard_and_soft_impedance_limits():
    _, ap, _, _ = ai_zeros(20)
    a_soft = ai_zeros(20)[0]
    rigid = creeping_modes(300.0, A, C0, None, 20)
    assert np.array_equal(rigid.zeta, ap.astype(complex))
    hard = creeping_modes(300.0, A, C0, 1e7 * (1 + 1j), 20)
    assert np.max(np.abs(hard.zeta - ap)) < 1e-5
    soft = creeping_modes(300.0, A, C0, 1e-6 * (1 + 1j), 20)  # |q| >> 1: continued from the zeros of Ai
    assert abs(soft.q) > 1 and np.max(np.abs(soft.zeta - a_soft)) < 1e-4


@pytest.mark.parametrize("f", [100.0, 500.0])
def test_series_converges_with_the_number_of_terms(f):
    z = complex(delany_bazley_impedance(f, GRASS))
    r = np.array([230.0, 300.0, 600.0, 1000.0])  # shadow boundary at 217.6 m
    d = np.abs(_tl(creeping_modes(f, A, C0, z, 60), r) - _tl(creeping_modes(f, A, C0, z, 120), r))
    assert d.max() <= 0.01, d


def test_limiting_ray_matches_the_closed_forms():
    h = np.array([0.5, 1.5, 2.0, 10.0, 50.0])
    lin_c = limiting_ray(lambda z: 340.0 - 0.1 * np.asarray(z, float), 100.0, 512)
    radius = 340.0 / 0.1  # grazing ray of linear c: a circle of radius c0 / |g|
    np.testing.assert_allclose(lin_c.x_of_h(h), np.sqrt(2 * radius * h - h * h), rtol=1e-6)
    lin_k2 = limiting_ray(k2_linear, 100.0, 512)
    np.testing.assert_allclose(lin_k2.x_of_h(h), 2.0 * np.sqrt(h / A), rtol=1e-6)
    np.testing.assert_allclose(fit_linear_k2(lin_k2, ZS, h), A, rtol=1e-6)
    assert lin_c.upward and lin_k2.upward
    assert not limiting_ray(lambda z: 340.0 + np.log(np.asarray(z, float) + 1.0), 100.0, 64).upward


_NO_GRAZE = {
    "log b = +1": lambda z: 340.0 + np.log1p(np.asarray(z, float)),
    "homogeneous": lambda z: np.full(np.shape(z), 340.0),
    "linear increase": lambda z: 340.0 + 0.05 * np.asarray(z, float),
    "decrease then increase above 5 m": lambda z: 340.0 + 0.01 * (np.asarray(z, float) - 5.0) ** 2 - 0.25,
}


@pytest.mark.parametrize("profile", list(_NO_GRAZE))
def test_limiting_ray_without_a_grazing_ray_is_the_full_table(profile):
    """Where c does not drop below its ground value just above the ground, limiting_ray stops after the first
    interval's nodes; oracle: the full quadrature over every node (_ray_span), which it must equal (x = 0 at
    the ground, nan above: the ray turns back at once). The last profile drops first, so it gets the full
    table (a grazing ray up to ~10 m), checked against the same oracle."""
    c_of_h = _NO_GRAZE[profile]
    calls = []

    def counted(h):
        calls.append(np.size(h))
        return c_of_h(h)

    ray = limiting_ray(counted, 400.0, 512)
    edges = np.linspace(0.0, np.sqrt(400.0 - ray.h_g), 513)
    mid, half = 0.5 * (edges[1:] + edges[:-1]), 0.5 * np.diff(edges)
    u = (mid[:, None] + half[:, None] * creeping._GL_X[None, :]).ravel()
    full = creeping._ray_span(c_of_h(ray.h_g + u * u), u, half, ray.c_ground)
    np.testing.assert_array_equal(ray.x, full)
    np.testing.assert_array_equal(ray.h, ray.h_g + edges * edges)
    if profile.startswith("decrease"):
        assert ray.h_g == 0.0 and np.isfinite(ray.x[1]) and not ray.upward
        assert max(calls) == u.size
    else:
        assert ray.x[0] == 0.0 and np.all(np.isnan(ray.x[1:])) and not ray.upward
        assert max(calls) == 401 and sum(calls) == 401 + 8  # the probes, then the first interval's 8 nodes


def _bisect_one_at_a_time(c_of_h, lo: float, hi: float, below: float) -> float:
    """The flat layer's top as limiting_ray found it until 2026-12-05: one halving per evaluation, 60 of them."""
    for _ in range(60):
        half_way = 0.5 * (lo + hi)
        if float(np.asarray(c_of_h(np.array([half_way])), float)[0]) < below:
            hi = half_way
        else:
            lo = half_way
    return lo


@pytest.mark.parametrize("top", [0.1, 1.0, 2.7, 13.3333, 99.9])
def test_flat_layer_top_is_the_one_at_a_time_bisection(top):
    """A column whose c stays at its ground value up to ``top`` (a plane below the terrain there, or the log-law
    wind below z_g): limiting_ray bisects for that top six halvings per call; oracle: one halving per call. The
    same h_g bit for bit (and the same table), in 10 calls instead of 60."""

    def c_of_h(h):
        return 340.0 - 0.05 * np.maximum(np.asarray(h, float) - top, 0.0)

    calls = []

    def counted(h):
        calls.append(np.size(h))
        return c_of_h(h)

    ray = limiting_ray(counted, 400.0, 512)
    probe = np.concatenate([[0.0], np.geomspace(1e-4, 400.0, 400)])
    cp = c_of_h(probe)
    first = int(np.flatnonzero(cp < cp[0] * (1.0 - 1e-12))[0])
    want = _bisect_one_at_a_time(c_of_h, float(probe[first - 1]), float(probe[first]), cp[0] * (1.0 - 1e-12))
    assert ray.h_g == want
    # c must drop by 1e-12 of c_ground to count as below it: 340e-12 m/s at 0.05 1/s, 6.8e-9 m above the top
    assert 0.0 <= ray.h_g - top <= 7e-9 and ray.upward
    assert len(calls) == 1 + 10 + 1  # the probes, 10 bisection calls of up to 63 midpoints, the quadrature


@pytest.mark.parametrize("f", [100.0, pytest.param(500.0, marks=pytest.mark.slow)])
def test_numerov_series_reproduces_the_closed_form(f):
    z = complex(delany_bazley_impedance(f, GRASS))
    closed = creeping_modes(f, A, C0, z, 12)
    k0 = 2 * np.pi * f / C0
    delta = 1.0188 / (k0 * k0 * A) ** (1 / 3)
    num = profile_modes(f, k2_linear, z, 8 * delta, 0.9 * A, 12, 401)  # continued from another medium
    n = min(6, num.kappa.size)
    np.testing.assert_allclose(num.kappa[:n], closed.kappa[:n], rtol=1e-6)
    tl_num = -20 * np.log10(np.abs(profile_pressure(num, ZS, RANGES, np.full(RANGES.size, ZR))))
    assert np.max(np.abs(tl_num - _tl(closed))) <= 0.05


@pytest.mark.parametrize("sigma", [None, GRASS])
def test_closed_form_matches_the_gfpe_in_linear_k2(sigma):
    f = 100.0
    z = None if sigma is None else complex(delany_bazley_impedance(f, sigma))
    ref = gfpe_tl(k2_linear, f, ZS, RANGES, np.array([ZR]), flow_resistivity=sigma)[:, 0]
    d = np.abs(_tl(creeping_modes(f, A, C0, z, 60)) - ref)
    assert d.max() <= 0.2, d

"""Checks of the image-source oracle by itself (closed forms, boundary condition, the exact integral)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.reference import image_source as im

SIGMA = 2.0e5  # Pa s/m^2, grass


def test_delany_bazley_closed_form() -> None:
    # f / sigma = 1 (f = 200 Hz, sigma = 200 kPa s/m^2): Z = 1 + 9.08 + 11.9 i exactly
    assert im.delany_bazley(200.0, 2.0e5) == pytest.approx(10.08 + 11.9j, rel=1e-12)
    z = im.delany_bazley(np.array([50.0, 500.0, 5000.0]), SIGMA)
    assert np.all(z.real > 1.0) and np.all(z.imag > 0.0)
    assert np.all(np.diff(np.abs(z)) < 0.0)  # softer (closer to rho c) at higher frequency


def test_free_field_normalisation_and_rigid_limit() -> None:
    # direct term exp(i k r)/r (|p| = 1 at 1 m) plus a rigid image of modulus 1/R2
    k = 2 * np.pi * 500.0 / 340.0
    r = np.array([1.0, 10.0])
    p = im.pressure(500.0, 1000.0, r, [1000.0])[:, 0]
    assert np.abs(p - np.exp(1j * k * r) / r) == pytest.approx(1 / np.hypot(r, 2000.0), rel=1e-12)
    # rigid ground: Q = 1, and a huge flow resistivity tends to it at normal-ish incidence
    q = im.spherical_wave_coefficient(9.24, 10.0, 0.9, complex(im.delany_bazley(500.0, 1e12)))
    assert abs(q - 1.0) < 1e-3
    # grazing incidence far away over finite impedance: Q -> R_p -> -1
    q = im.spherical_wave_coefficient(9.24, 1e7, 1e-6, complex(im.delany_bazley(500.0, SIGMA)))
    assert abs(q + 1.0) < 0.05


@pytest.mark.parametrize("f_hz", [100.0, 500.0, 1000.0])
def test_spherical_wave_q_matches_exact_integral(f_hz: float) -> None:
    """Weyl-van der Pol Q against the exact complex-image integral: measured max 0.016 dB, 0.34 %."""
    r = np.array([5.0, 10.0, 50.0, 200.0, 1000.0])
    z = np.array([0.5, 1.0, 2.0, 4.0])
    pe = im.exact_pressure(f_hz, 2.0, r, z, SIGMA)
    pq = im.pressure(f_hz, 2.0, r, z, SIGMA)
    assert np.max(np.abs(20 * np.log10(np.abs(pq) / np.abs(pe)))) < 0.05
    assert np.max(np.abs(pq - pe) / np.abs(pe)) < 0.01


def test_exact_integral_satisfies_impedance_boundary_condition() -> None:
    """dp/dz + i (k/Z) p = 0 at z = 0 (centred difference across a thin layer) and Helmholtz above."""
    f, zs, c0 = 300.0, 1.5, 340.0
    k = 2 * np.pi * f / c0
    zg = complex(im.delany_bazley(f, SIGMA))
    h = 1e-3
    r = np.array([3.0, 30.0, 300.0])
    p = im.exact_pressure(f, zs, r, [0.0, h, 2 * h], SIGMA)
    dpdz = (-3 * p[:, 0] + 4 * p[:, 1] - p[:, 2]) / (2 * h)
    resid = np.abs(dpdz + 1j * k / zg * p[:, 0]) / np.abs(k * p[:, 0])
    assert np.all(resid < 1e-4)
    # the rigid image field does not satisfy it (the check can fail)
    pr = im.pressure(f, zs, r, [0.0, h, 2 * h])
    dr_ = (-3 * pr[:, 0] + 4 * pr[:, 1] - pr[:, 2]) / (2 * h)
    assert np.all(np.abs(dr_ + 1j * k / zg * pr[:, 0]) / np.abs(k * pr[:, 0]) > 1e-2)
    # axisymmetric Helmholtz p_rr + p_r / r + p_zz + k^2 p = 0 at (r, z) = (30, 2), 5-point stencil
    d = 0.005
    rr = np.array([30.0 - d, 30.0, 30.0 + d])
    pp = im.exact_pressure(f, zs, rr, [2.0 - d, 2.0, 2.0 + d], SIGMA)
    lap = (pp[0, 1] - 2 * pp[1, 1] + pp[2, 1]) / d**2 + (pp[2, 1] - pp[0, 1]) / (2 * d * 30.0)
    lap += (pp[1, 0] - 2 * pp[1, 1] + pp[1, 2]) / d**2
    assert abs(lap + k**2 * pp[1, 1]) / abs(k**2 * pp[1, 1]) < 2e-4


def test_reciprocity_and_incoherent_sum() -> None:
    f = 250.0
    a = im.pressure(f, 2.0, [80.0], [5.0], SIGMA)
    b = im.pressure(f, 5.0, [80.0], [2.0], SIGMA)
    assert a == pytest.approx(b, rel=1e-12)
    ti = im.incoherent_tl(f, 2.0, [80.0], [5.0])
    assert ti[0, 0] == pytest.approx(-10 * np.log10(1 / (80**2 + 9) + 1 / (80**2 + 49)), abs=1e-12)


def test_line_source_far_field() -> None:
    """(i/4) [H0(k R1) + H0(k R2)] against the large-argument form (i/4) sqrt(2/(pi k R)) exp(i (k R - pi/4))."""
    k = 2 * np.pi * 200.0 / 340.0
    p = im.line_source_pressure(200.0, 10.0, [300.0], [2.0])[0, 0]
    r1, r2 = np.hypot(300.0, 8.0), np.hypot(300.0, 12.0)
    asym = sum(0.25j * np.sqrt(2 / (np.pi * k * x)) * np.exp(1j * (k * x - np.pi / 4)) for x in (r1, r2))
    assert abs(p - asym) / abs(asym) < 1e-3

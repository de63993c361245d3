"""Checks of the Airy normal-mode oracle by itself (the modes, their norm, the weak-gradient limit)."""

from __future__ import annotations

import numpy as np
from scipy.special import airy

from tests.reference import image_source as im
from tests.reference import normal_modes as nm


def test_modes_are_orthonormal_and_complete() -> None:
    """The closed-form norms match quadrature (rel 1e-6), and projecting a Gaussian (15 m high, 5 m wide)
    on the first 400 modes gives it back (max error measured 5e-5)."""
    k0 = 2 * np.pi * 100.0 / 340.0
    a = 1e-3
    g = (k0**2 * a) ** (1 / 3)
    ap, ai_ap = nm._ai_prime_zeros(400)
    norm = -ap * ai_ap**2 / g
    z = np.linspace(0.0, 150.0, 15001)
    dz = z[1] - z[0]
    phi = airy(g * z[:, None] + ap[None, :8])[0]
    num = (phi**2).sum(axis=0) * dz - 0.5 * dz * phi[0] ** 2  # trapezoid; the modes vanish at 150 m
    assert np.allclose(num, norm[:8], rtol=1e-6)
    z = np.linspace(0.0, 45.0, 1801)
    dz = z[1] - z[0]
    phi = airy(g * z[:, None] + ap[None, :])[0]
    f = np.exp(-(((z - 15.0) / 5.0) ** 2))
    w = np.full(z.size, dz)
    w[0] = w[-1] = 0.5 * dz
    coef = (phi * (f * w)[:, None]).sum(axis=0) / norm
    err = np.max(np.abs(phi @ coef - f))
    print(f"\n mode completeness: max error {err:.2e}")
    assert err < 1e-4
    # rigid ground: every mode has zero slope at z = 0
    assert np.allclose(airy(ap)[1], 0.0, atol=1e-9)


def test_weak_gradient_tends_to_image_source() -> None:
    """a = 1e-5 1/m (c rises 0.17 cm/s per m): within 0.05 dB of the rigid image source up to 200 m
    (measured 0.03 dB; 0.065 dB at 300 m, the refraction itself), i.e. p -> exp(i k R)/R."""
    r = np.array([50.0, 100.0, 150.0, 200.0])
    z = np.array([1.0, 2.0, 4.0])
    pm = nm.pressure(100.0, 1e-5, 2.0, r, z)
    ph = im.pressure(100.0, 2.0, r, z)
    d = np.abs(20 * np.log10(np.abs(pm) / np.abs(ph)))
    print(f"\n a=1e-5 vs image source: max {d.max():.3f} dB")
    assert d.max() < 0.05


def test_downward_refraction_raises_levels() -> None:
    """a = 1e-3 1/m at 100 Hz: at 1 km the trapped field is ~10 dB above the homogeneous one."""
    r = np.array([1000.0])
    z = np.array([1.0, 2.0, 4.0])
    pm = nm.pressure(100.0, 1e-3, 2.0, r, z)
    ph = im.pressure(100.0, 2.0, r, z)
    assert np.all(20 * np.log10(np.abs(pm) / np.abs(ph)) > 5.0)


def test_impedance_modes_tend_to_exact_image_integral() -> None:
    """Grass (200 kPa s/m^2), 100 Hz, a = 1e-4 1/m: within 0.05 dB of the exact complex-image integral
    at 30-50 m (measured 0.035 dB; the refraction itself adds 0.1 dB by 100 m)."""
    r = np.array([30.0, 50.0])
    z = np.array([1.0, 2.0, 4.0])
    pm = nm.pressure(100.0, 1e-4, 2.0, r, z, flow_resistivity=2e5)
    ph = im.exact_pressure(100.0, 2.0, r, z, 2e5)
    d = np.abs(20 * np.log10(np.abs(pm) / np.abs(ph)))
    print(f"\n impedance modes a=1e-4 vs exact image integral: max {d.max():.3f} dB")
    assert d.max() < 0.05


def test_impedance_roots() -> None:
    """The continued roots solve g Ai' + i beta Ai = 0 and stay distinct; the first one has turned into
    the surface wave (bound to the ground: far from the rigid zero -1.02)."""
    k0 = 2 * np.pi * 100.0 / 340.0
    g = (k0**2 * 3e-4) ** (1 / 3)
    beta = k0 / complex(im.delany_bazley(100.0, 2e5))
    ap, _ = nm._ai_prime_zeros(300)
    zeta = nm._impedance_roots(ap, g, beta)
    ai, aip, _, _ = airy(zeta)
    assert np.max(np.abs(g * aip + 1j * beta * ai)) < 1e-10
    assert abs(zeta[0] - ap[0]) > 0.5 and np.all(np.abs(zeta[50:] - ap[50:]) < 0.1)

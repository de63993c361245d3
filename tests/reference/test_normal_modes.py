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

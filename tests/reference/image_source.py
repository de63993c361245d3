"""Independent reference: a point source over flat ground in homogeneous air (image source).

Shares no code with the engine. Time factor exp(-i w t); outgoing waves exp(+i k R).

Geometry: source S = (0, z_s), receiver R = (r, z_r) (horizontal range r >= 0, heights above the flat
ground z = 0), image source S' = (0, -z_s); R1 = |S R|, R2 = |S' R|, cos(theta) = (z_s + z_r) / R2
(theta the angle of incidence from the ground normal).

Pressure, normalised so that the free field is 1 at 1 m (so ``tl = -20 log10 |p|`` is the transmission
loss re 1 m free field):

    p = exp(i k R1) / R1 + Q exp(i k R2) / R2,

Q = 1 for rigid ground, otherwise the spherical-wave reflection coefficient (Weyl-van der Pol, as in
Salomons 2001, App. D): Q = R_p + (1 - R_p) F(w), R_p = (Z cos th - 1) / (Z cos th + 1),
F(w) = 1 + i sqrt(pi) w wofz(w), w = sqrt(i k R2 / 2) (1/Z + cos th), Z the normalised Delany-Bazley
impedance (Re Z > 1, Im Z > 0 in this time convention).

``exact_pressure`` evaluates instead the exact integral for a locally reacting plane (a line of image
sources at complex heights, Thomasson 1976 / Attenborough's form), used to check Q:

    p = exp(i k R1)/R1 + exp(i k R2)/R2 - 2 beta int_0^inf exp(-beta q) f(z_s + z_r + i q) dq,
    f(u) = exp(i k sqrt(r^2 + u^2)) / sqrt(r^2 + u^2), beta = k / Z,

which satisfies dp/dz + i beta p = 0 at z = 0 (derivation: integrate by parts along the image line).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import quad_vec
from scipy.special import hankel1, wofz

C0_DEFAULT = 340.0


def delany_bazley(frequency_hz: ArrayLike, flow_resistivity: ArrayLike) -> np.ndarray:
    """Normalised Delany-Bazley impedance Z (exp(-i w t): Im Z > 0); sigma in Pa s/m^2, f in Hz."""
    f = np.asarray(frequency_hz, float)
    sigma = np.asarray(flow_resistivity, float)
    if np.any(f <= 0) or np.any(sigma <= 0):
        raise ValueError("frequency_hz and flow_resistivity must be > 0")
    x = f / (sigma * 1e-3)
    return (1.0 + 9.08 * x**-0.75) + 1j * (11.9 * x**-0.73)


def plane_wave_coefficient(z: complex | np.ndarray, cos_theta: ArrayLike) -> np.ndarray:
    """R_p = (Z cos th - 1) / (Z cos th + 1); Z = inf (rigid) gives 1."""
    ct = np.asarray(cos_theta, float)
    if np.all(np.isinf(z)):
        return np.ones_like(ct, dtype=complex)
    return (z * ct - 1.0) / (z * ct + 1.0)


def spherical_wave_coefficient(k: float, r2: ArrayLike, cos_theta: ArrayLike, z: complex | None) -> np.ndarray:
    """Q = R_p + (1 - R_p) F(w) (see module docstring); z None means rigid (Q = 1)."""
    r2 = np.asarray(r2, float)
    ct = np.asarray(cos_theta, float)
    if z is None:
        return np.ones(np.broadcast(r2, ct).shape, complex)
    rp = plane_wave_coefficient(z, ct)
    w = np.sqrt(0.5j * k * r2) * (1.0 / z + ct)
    f = 1.0 + 1j * np.sqrt(np.pi) * w * wofz(w)
    return rp + (1.0 - rp) * f


def _geometry(zs: float, ranges_m: ArrayLike, zr_m: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r = np.asarray(ranges_m, float)[:, None]
    zr = np.asarray(zr_m, float)[None, :]
    if zs <= 0 or np.any(zr < 0) or np.any(r < 0):
        raise ValueError("zs must be > 0, ranges and receiver heights >= 0")
    r1 = np.hypot(r, zr - zs)
    r2 = np.hypot(r, zr + zs)
    return r1, r2, (zr + zs) / r2


def _impedance(f_hz: float, flow_resistivity: float | None) -> complex | None:
    return None if flow_resistivity is None else complex(delany_bazley(f_hz, flow_resistivity))


def pressure(
    f_hz: float,
    zs: float,
    ranges_m: ArrayLike,
    zr_m: ArrayLike,
    flow_resistivity: float | None = None,
    c0: float = C0_DEFAULT,
) -> np.ndarray:
    """Complex pressure re 1 m free field, shape (len(ranges_m), len(zr_m)); sigma None = rigid."""
    k = 2.0 * np.pi * f_hz / c0
    r1, r2, ct = _geometry(zs, ranges_m, zr_m)
    q = spherical_wave_coefficient(k, r2, ct, _impedance(f_hz, flow_resistivity))
    return np.exp(1j * k * r1) / r1 + q * np.exp(1j * k * r2) / r2


def tl(
    f_hz: float,
    zs: float,
    ranges_m: ArrayLike,
    zr_m: ArrayLike,
    flow_resistivity: float | None = None,
    c0: float = C0_DEFAULT,
) -> np.ndarray:
    """Transmission loss -20 log10 |p| in dB re 1 m free field, shape (len(ranges_m), len(zr_m))."""
    return -20.0 * np.log10(np.abs(pressure(f_hz, zs, ranges_m, zr_m, flow_resistivity, c0)))


def incoherent_tl(
    f_hz: float,
    zs: float,
    ranges_m: ArrayLike,
    zr_m: ArrayLike,
    flow_resistivity: float | None = None,
    c0: float = C0_DEFAULT,
) -> np.ndarray:
    """Incoherent sum -10 log10(1/R1^2 + |Q|^2/R2^2), dB re 1 m, shape (len(ranges_m), len(zr_m))."""
    k = 2.0 * np.pi * f_hz / c0
    r1, r2, ct = _geometry(zs, ranges_m, zr_m)
    q = spherical_wave_coefficient(k, r2, ct, _impedance(f_hz, flow_resistivity))
    return -10.0 * np.log10(1.0 / r1**2 + np.abs(q) ** 2 / r2**2)


def exact_pressure(
    f_hz: float,
    zs: float,
    ranges_m: ArrayLike,
    zr_m: ArrayLike,
    flow_resistivity: float,
    c0: float = C0_DEFAULT,
    epsrel: float = 1e-10,
) -> np.ndarray:
    """Exact pressure over a locally reacting plane (complex image line), re 1 m free field.

    Shape (len(ranges_m), len(zr_m)); needs Re(1/Z) > 0 (true for Delany-Bazley).
    """
    k = 2.0 * np.pi * f_hz / c0
    z = complex(delany_bazley(f_hz, flow_resistivity))
    beta = k / z
    r1, r2, _ = _geometry(zs, ranges_m, zr_m)
    r = np.broadcast_to(np.asarray(ranges_m, float)[:, None], r1.shape)
    u = np.broadcast_to(zs + np.asarray(zr_m, float)[None, :], r1.shape)

    def integrand(q: float) -> np.ndarray:
        d = np.sqrt(r**2 + (u + 1j * q) ** 2)  # Im(arg) = 2 u q >= 0: principal branch is continuous
        return np.exp(-beta * q) * np.exp(1j * k * d) / d

    # scale q by the decay length 1/Re(beta) so that the quadrature sees an O(1) interval
    scale = 1.0 / beta.real
    val, _err = quad_vec(lambda t: integrand(t * scale) * scale, 0.0, np.inf, epsrel=epsrel, epsabs=1e-14)
    return np.exp(1j * k * r1) / r1 + np.exp(1j * k * r2) / r2 - 2.0 * beta * val


def line_source_pressure(
    f_hz: float,
    zs: float,
    ranges_m: ArrayLike,
    zr_m: ArrayLike,
    c0: float = C0_DEFAULT,
) -> np.ndarray:
    """2D line source over rigid ground: (i/4) [H0(k R1) + H0(k R2)] (exp(-i w t)), shape (nr, nz)."""
    k = 2.0 * np.pi * f_hz / c0
    r1, r2, _ = _geometry(zs, ranges_m, zr_m)
    return 0.25j * (hankel1(0, k * r1) + hankel1(0, k * r2))

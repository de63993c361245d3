"""Independent reference: exact normal modes (Airy functions) for a linear-k^2 downward-refracting
atmosphere over rigid or impedance ground, a point source. Shares no code with the engine or the GFPE.

Medium: k(z)^2 = k0^2 (1 - a z) (a > 0, i.e. c(z) = c0 / sqrt(1 - a z), sound speed increasing with
height: downward refraction; valid for z < 1/a), rigid ground at z = 0. Time factor exp(-i w t).
Modes of d^2 phi/dz^2 + (k(z)^2 - kappa^2) phi = 0 with phi'(0) = 0, phi -> 0 as z -> inf:

    phi_n(z) = Ai(g z + a'_n),  g = (k0^2 a)^(1/3),  kappa_n^2 = k0^2 + a'_n g^2,

a'_n < 0 the zeros of Ai'; norm int_0^inf phi_n^2 dz = -a'_n Ai(a'_n)^2 / g. Over impedance ground
(dphi/dz + i beta phi = 0, beta = k0 / Z) a'_n becomes the complex root zeta_n of g Ai'(zeta) + i beta Ai(zeta)
= 0, followed by Newton continuation from the rigid zeros (beta scaled from 0 to 1 in 40 steps; the first
root becomes the surface wave), norm (Ai'(zeta_n)^2 - zeta_n Ai(zeta_n)^2) / g (bilinear, no conjugate).
The spectrum is discrete and complete (every wave turns back down), so the field is the mode sum

    p(r, z) = 4 pi G = i pi sum_n phi_n(z_s) phi_n(z) H0^(1)(kappa_n r) / N_n

(G the Green's function of the Helmholtz operator, -delta source): p ~ exp(i k R)/R near the source, so
|p| is re 1 m free field. Modes with kappa_n^2 <= 0 (evanescent in range) are left out; at r >> lambda
they are negligible. Cost: the number of modes grows as k0 / sqrt(a) (~1,000 at 100 Hz, a = 3e-4); the
impedance continuation is practical to ~250 Hz at a = 3e-4 (at 500 Hz the high complex roots overflow Airy
and the call raises RuntimeError).
"""

from __future__ import annotations

from functools import cache

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import ai_zeros, airy, hankel1

from tests.reference.image_source import delany_bazley


@cache
def _ai_prime_zeros(n: int) -> tuple[np.ndarray, np.ndarray]:
    _, ap, ai_at_ap, _ = ai_zeros(n)  # zeros a'_n of Ai', and Ai(a'_n)
    return ap, ai_at_ap


def profile_c(c0: float, a: float):  # noqa: ANN201 - a callable c(z)
    """c(z) = c0 / sqrt(1 - a z), m/s (the medium of ``pressure``)."""
    return lambda z: c0 / np.sqrt(1.0 - a * np.asarray(z, float))


def _impedance_roots(ap: np.ndarray, g: float, beta: complex, steps: int = 40) -> np.ndarray:
    """Roots of g Ai'(zeta) + i beta Ai(zeta) = 0 continued from the zeros ap of Ai' (Newton)."""
    zeta = ap.astype(complex)
    for s in np.linspace(0.0, 1.0, steps + 1)[1:]:
        b = s * beta
        for _ in range(30):
            ai, aip, _, _ = airy(zeta)
            dz = (g * aip + 1j * b * ai) / (g * zeta * ai + 1j * b * aip)
            zeta = zeta - dz
            if np.all(np.abs(dz) < 1e-12 * (1.0 + np.abs(zeta))):
                break
    ai, aip, _, _ = airy(zeta)
    resid = np.abs(g * aip + 1j * beta * ai) / (g * np.abs(aip) + np.abs(beta * ai) + 1e-300)
    if resid.max() > 1e-8 or np.min(np.abs(np.diff(np.sort_complex(zeta)))) < 1e-6:
        raise RuntimeError("impedance mode continuation failed (residual or merged roots)")
    return zeta


def pressure(
    f_hz: float,
    a: float,
    zs: float,
    ranges_m: ArrayLike,
    zr_m: ArrayLike,
    c0: float = 340.0,
    taper_deg: tuple[float, float] | None = (40.0, 60.0),
    flow_resistivity: float | None = None,
) -> np.ndarray:
    """Complex pressure re 1 m free field (c0 at the ground), shape (len(ranges_m), len(zr_m)).

    ``a`` in 1/m (> 0); heights well below 1/a; ``flow_resistivity`` (Pa s/m^2, Delany-Bazley) or None
    for rigid ground. ``taper_deg`` = (t1, t2): the modes whose ground
    elevation angle acos(kappa_n / k0) exceeds t1 are weighted down by cos^2 to 0 at t2 (None: all
    modes). In this medium every ray returns to the ground, the near-vertical ones after climbing to
    z ~ 1/a where c -> inf, a short range 2 sin(2 th)/a away (~ -25 dB at 1 km for a = 1e-4): an
    artefact of the unbounded profile that an absorbing-top model (the GFPE) cannot and should not
    reproduce. Low-angle arrivals are built from modes near kappa = k0 and are unaffected.
    """
    if a <= 0:
        raise ValueError("a must be > 0 (downward refraction: all modes trapped)")
    k0 = 2.0 * np.pi * f_hz / c0
    g = (k0**2 * a) ** (1.0 / 3.0)
    n_est = int(1.2 * (2.0 / (3.0 * np.pi)) * (k0**2 / g**2) ** 1.5) + 50
    ap, aip = _ai_prime_zeros(n_est)
    if (k0**2 + ap * g**2 > 0.0).all():
        raise RuntimeError("mode table too short")
    ap, aip = ap[k0**2 + ap * g**2 > -(g**2) * 50.0], aip[k0**2 + ap * g**2 > -(g**2) * 50.0]
    if flow_resistivity is None:
        zeta = ap
        weight = g / (-ap * aip**2)  # 1 / norm
    else:
        beta = k0 / complex(delany_bazley(f_hz, flow_resistivity))
        zeta = _impedance_roots(ap, g, beta)
        ai, aip_, _, _ = airy(zeta)
        weight = g / (aip_**2 - zeta * ai**2)
    kap = np.sqrt(k0**2 + zeta * g**2 + 0j)
    kap = np.where(kap.imag < 0, -kap, kap)
    keep = kap.real > 1e-9 * k0
    zeta, kap, weight = zeta[keep], kap[keep], weight[keep]
    if taper_deg is not None:
        th = np.degrees(np.arccos(np.clip(kap.real / k0, -1.0, 1.0)))
        t1, t2 = taper_deg
        weight = weight * np.where(
            th <= t1, 1.0, np.where(th >= t2, 0.0, np.cos(0.5 * np.pi * (th - t1) / (t2 - t1)) ** 2)
        )
    phi_s = airy(g * zs + zeta)[0]
    phi_r = airy(g * np.asarray(zr_m, float)[:, None] + zeta[None, :])[0]  # (nz, n)
    h = hankel1(0, np.outer(np.asarray(ranges_m, float), kap))  # (nr, n)
    return 1j * np.pi * (h * (phi_s * weight)[None, :]) @ phi_r.T

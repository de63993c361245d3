"""Independent reference: exact normal modes (Airy functions) for a linear-k^2 downward-refracting
atmosphere over rigid ground, a point source. Shares no code with the engine or the GFPE.

Medium: k(z)^2 = k0^2 (1 - a z) (a > 0, i.e. c(z) = c0 / sqrt(1 - a z), sound speed increasing with
height: downward refraction; valid for z < 1/a), rigid ground at z = 0. Time factor exp(-i w t).
Modes of d^2 phi/dz^2 + (k(z)^2 - kappa^2) phi = 0 with phi'(0) = 0, phi -> 0 as z -> inf:

    phi_n(z) = Ai(g z + a'_n),  g = (k0^2 a)^(1/3),  kappa_n^2 = k0^2 + a'_n g^2,

a'_n < 0 the zeros of Ai'; norm int_0^inf phi_n^2 dz = -a'_n Ai(a'_n)^2 / g. The spectrum is discrete and
complete (every wave turns back down), so the field is the mode sum

    p(r, z) = 4 pi G = i pi sum_n phi_n(z_s) phi_n(z) H0^(1)(kappa_n r) / N_n

(G the Green's function of the Helmholtz operator, -delta source): p ~ exp(i k R)/R near the source, so
|p| is re 1 m free field. Modes with kappa_n^2 <= 0 (evanescent in range) are left out; at r >> lambda
they are negligible.
"""

from __future__ import annotations

from functools import cache

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import ai_zeros, airy, hankel1


@cache
def _ai_prime_zeros(n: int) -> tuple[np.ndarray, np.ndarray]:
    _, ap, ai_at_ap, _ = ai_zeros(n)  # zeros a'_n of Ai', and Ai(a'_n)
    return ap, ai_at_ap


def profile_c(c0: float, a: float):  # noqa: ANN201 - a callable c(z)
    """c(z) = c0 / sqrt(1 - a z), m/s (the medium of ``pressure``)."""
    return lambda z: c0 / np.sqrt(1.0 - a * np.asarray(z, float))


def pressure(
    f_hz: float,
    a: float,
    zs: float,
    ranges_m: ArrayLike,
    zr_m: ArrayLike,
    c0: float = 340.0,
    taper_deg: tuple[float, float] | None = (40.0, 60.0),
) -> np.ndarray:
    """Complex pressure re 1 m free field (c0 at the ground), shape (len(ranges_m), len(zr_m)).

    ``a`` in 1/m (> 0); heights well below 1/a. ``taper_deg`` = (t1, t2): the modes whose ground
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
    kap2 = k0**2 + ap * g**2
    keep = kap2 > 0.0
    if keep.all():
        raise RuntimeError("mode table too short")
    ap, aip, kap = ap[keep], aip[keep], np.sqrt(kap2[keep])
    weight = g / (-ap * aip**2)  # 1 / norm
    if taper_deg is not None:
        th = np.degrees(np.arccos(np.clip(kap / k0, -1.0, 1.0)))
        t1, t2 = taper_deg
        weight = weight * np.where(
            th <= t1, 1.0, np.where(th >= t2, 0.0, np.cos(0.5 * np.pi * (th - t1) / (t2 - t1)) ** 2)
        )
    phi_s = airy(g * zs + ap)[0]
    phi_r = airy(g * np.asarray(zr_m, float)[:, None] + ap[None, :])[0]  # (nz, n)
    h = hankel1(0, np.outer(np.asarray(ranges_m, float), kap))  # (nr, n)
    return 1j * np.pi * (h * (phi_s * weight)[None, :]) @ phi_r.T

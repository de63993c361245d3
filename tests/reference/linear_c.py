"""Closed-form rays in a linear sound-speed profile c(z) = c0 + g z (an oracle for eigenray tests).

Every ray is an arc of a circle whose centre lies on the line c = 0 (z_c = -c0 / g); between two points
there is exactly one such arc, and its travel time is (docs/physics.md §3)

    t(a, b) = arccosh(1 + g^2 |a - b|^2 / (2 c(a) c(b))) / |g|.

:func:`travel_time_quadrature` integrates ds / c along the explicit arc instead (scipy.integrate.quad):
the self-check of the closed form. :func:`reflected_times` finds the one-reflection arrivals off flat
ground at z = 0 by Fermat's principle: the stationary points of t(s, b) + t(b, r) over the ground point
b on the source-receiver line (each leg the unique arc; for g > 0 the arcs bow upwards and stay above the
ground).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import quad
from scipy.optimize import brentq


def speed(z: float, c0: float, g: float) -> float:
    return c0 + g * z


def travel_time(a: np.ndarray, b: np.ndarray, c0: float, g: float) -> float:
    """Closed-form travel time (s) between points a and b (3,), metres."""
    d2 = float(np.sum((np.asarray(a, float) - np.asarray(b, float)) ** 2))
    if g == 0.0:
        return math.sqrt(d2) / c0
    eps = g * g * d2 / (2.0 * speed(a[2], c0, g) * speed(b[2], c0, g))
    # arccosh(1 + eps) without the cancellation of forming 1 + eps (eps ~ 1e-8 for weak gradients)
    return math.log1p(eps + math.sqrt(eps * (2.0 + eps))) / abs(g)


def travel_time_quadrature(a: np.ndarray, b: np.ndarray, c0: float, g: float) -> float:
    """The same time by quadrature of ds / c along the circle through a and b centred on z = -c0 / g."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    length = math.hypot(b[0] - a[0], b[1] - a[1])
    zc = -c0 / g
    xc = (length**2 + (b[2] - zc) ** 2 - (a[2] - zc) ** 2) / (2.0 * length)  # a at x = 0, b at x = length
    radius = math.hypot(xc, a[2] - zc)
    phi_a = math.atan2(a[2] - zc, 0.0 - xc)
    phi_b = math.atan2(b[2] - zc, length - xc)

    def integrand(phi: float) -> float:
        z = zc + radius * math.sin(phi)
        return radius / speed(z, c0, g)

    value, _ = quad(integrand, min(phi_a, phi_b), max(phi_a, phi_b), epsabs=0.0, epsrel=1e-13, limit=200)
    return value


def reflected_times(src: np.ndarray, rec: np.ndarray, c0: float, g: float, n_scan: int = 4001) -> list[float]:
    """Travel times (s) of the one-reflection arrivals off the ground z = 0, sorted (Fermat: dT/du = 0)."""
    src = np.asarray(src, float)
    rec = np.asarray(rec, float)

    def point(u: float) -> np.ndarray:
        p = src + u * (rec - src)
        return np.array([p[0], p[1], 0.0])

    def total(u: float) -> float:
        b = point(u)
        return travel_time(src, b, c0, g) + travel_time(b, rec, c0, g)

    h = 1e-7

    def slope(u: float) -> float:
        return (total(u + h) - total(u - h)) / (2.0 * h)

    us = np.linspace(1e-5, 1.0 - 1e-5, n_scan)
    ds = np.array([slope(u) for u in us])
    roots = [brentq(slope, us[i], us[i + 1], xtol=1e-15) for i in np.nonzero(np.sign(ds[:-1]) != np.sign(ds[1:]))[0]]
    return sorted(total(u) for u in roots)

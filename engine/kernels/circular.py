"""Circular ray curve: constant G = grad(c) inside a cell (physics.md section 3).

The curve is parametrised by the half-angle variable ``u = tan(psi/2) / kappa`` (psi = kappa s the
turning angle, kappa = |G_perp| / c0), which makes every expression rational and finite at
kappa = 0 (straight rays, rays along the gradient):

    x(u) = x0 + (2u d0 + 2u^2 k) / (1 + kappa^2 u^2)           k = -G_perp / c0, |k| = kappa
    T(u) = ((1 - kappa^2 u^2) d0 + 2u k) / (1 + kappa^2 u^2)
    s(u) = 2 atan(kappa u) / kappa
    t(u) = y ln(1 + |G| y) / (|G| y),  y = 2u / (c0 - w u),  w = |G| - G.d0 >= 0

t(u) is the closed form (F(psi - theta0) - F(-theta0)) / |G| of physics.md, F = asinh(tan), rewritten
(tan half-angle substitution, partial fractions) so that it neither divides by |G| nor by kappa; its
inverse is closed form too: u = c0 E / (2 + w E), E = (exp(|G| t) - 1) / |G|.

A plane m.x = h gives ``(D kappa^2 + 2 m.k) u^2 + 2 (m.d0) u + D = 0`` (D = m.x0 - h), the u-form of
the tan-half-angle equation of physics.md: it is a positive multiple of the signed distance, so the
up-crossing logic of ``roots.py`` applies unchanged. u in [0, inf) covers psi in [0, pi).
"""

from __future__ import annotations

import math

import numba as nb

from bentray.engine.constants import NJIT_FLAGS
from bentray.engine.kernels.roots import atan_over_x, expm1_over_x, log1p_over_x


@nb.njit(**NJIT_FLAGS)
def setup(c0: float, G, d0, k_out):
    """Curve constants for a cell: writes k = -G_perp/c0 into k_out; returns (kappa^2, |G|, w)."""
    gt = G[0] * d0[0] + G[1] * d0[1] + G[2] * d0[2]
    gpx = G[0] - gt * d0[0]
    gpy = G[1] - gt * d0[1]
    gpz = G[2] - gt * d0[2]
    k_out[0] = -gpx / c0
    k_out[1] = -gpy / c0
    k_out[2] = -gpz / c0
    kappa2 = k_out[0] * k_out[0] + k_out[1] * k_out[1] + k_out[2] * k_out[2]
    gnorm = math.sqrt(G[0] * G[0] + G[1] * G[1] + G[2] * G[2])
    gperp2 = gpx * gpx + gpy * gpy + gpz * gpz
    if gt >= 0.0:
        denom = gnorm + gt
        w = gperp2 / denom if denom > 0.0 else 0.0  # |G| - gt without cancellation
    else:
        w = gnorm - gt
    return kappa2, gnorm, w


@nb.njit(**NJIT_FLAGS)
def plane_coefficients(mx, my, mz, h, x0, d0, k, kappa2):
    """Coefficients (A, B, C) of the u-form plane equation (a positive multiple of m.x(u) - h)."""
    d = mx * x0[0] + my * x0[1] + mz * x0[2] - h
    a = d * kappa2 + 2.0 * (mx * k[0] + my * k[1] + mz * k[2])
    b = 2.0 * (mx * d0[0] + my * d0[1] + mz * d0[2])
    return a, b, d


@nb.njit(**NJIT_FLAGS)
def travel_time(c0: float, gnorm: float, w: float, u: float) -> float:
    """Exact travel time (s) to parameter u; +inf where c would reach 0 (u >= c0 / w)."""
    den = c0 - w * u
    if den <= 0.0:
        return math.inf
    y = 2.0 * u / den
    return y * log1p_over_x(gnorm * y)


@nb.njit(**NJIT_FLAGS)
def u_at_time(c0: float, gnorm: float, w: float, dt: float) -> float:
    """Closed-form inverse of ``travel_time``: the u reached after travel time dt."""
    e = dt * expm1_over_x(gnorm * dt)
    return c0 * e / (2.0 + w * e)


@nb.njit(**NJIT_FLAGS)
def arc_length(kappa2: float, u: float) -> float:
    """Arc length (m) to parameter u: 2 atan(kappa u) / kappa."""
    kappa = math.sqrt(kappa2)
    return 2.0 * u * atan_over_x(kappa * u)


@nb.njit(**NJIT_FLAGS)
def state_at(x0, d0, k, kappa2: float, u: float, x_out, t_out) -> None:
    """Position x(u) and unit tangent T(u) written into x_out, t_out (3,)."""
    ku2 = kappa2 * u * u
    inv = 1.0 / (1.0 + ku2)
    for i in range(3):
        x_out[i] = x0[i] + (2.0 * u * d0[i] + 2.0 * u * u * k[i]) * inv
        t_out[i] = ((1.0 - ku2) * d0[i] + 2.0 * u * k[i]) * inv
    norm = math.sqrt(t_out[0] * t_out[0] + t_out[1] * t_out[1] + t_out[2] * t_out[2])
    for i in range(3):
        t_out[i] /= norm

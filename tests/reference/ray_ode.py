"""Independent reference: the ray equations integrated by scipy's DOP853 at rtol 1e-12.

This is the oracle the engine is checked against; it shares no code with the engine. State
(x, p) with p = n T, integrated in travel time t (dx/dt = c_ref p / n^2, dp/dt = c_ref grad n / n).
The flat ground z = 0 reflects specularly (event with direction -1, p_z -> -p_z, restart).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp


@dataclass
class RefState:
    position: np.ndarray
    direction: np.ndarray
    reflections: int
    length_m: float


def integrate_ray(
    n_of: Callable[[np.ndarray], float],
    grad_n_of: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    d0: np.ndarray,
    t_end: float,
    *,
    c_ref: float = 340.0,
    rtol: float = 1e-12,
    max_reflections: int = 10_000,
) -> RefState:
    """Final state at travel time t_end, with specular ground reflections at z = 0."""
    x = np.asarray(x0, float)
    d = np.asarray(d0, float) / np.linalg.norm(d0)
    p = n_of(x) * d
    t = 0.0
    length = 0.0
    reflections = 0

    def rhs(_t, y):
        xx = y[:3]
        pp = y[3:6]
        n = n_of(xx)
        return np.concatenate([c_ref * pp / n**2, c_ref * grad_n_of(xx) / n, [c_ref / n]])

    def ground(_t, y):
        return y[2]

    ground.terminal = True
    ground.direction = -1
    while True:
        y0 = np.concatenate([x, p, [length]])
        sol = solve_ivp(
            rhs, (t, t_end), y0, method="DOP853", rtol=rtol, atol=1e-12 * max(1.0, np.abs(x).max()), events=ground
        )
        y = sol.y[:, -1]
        x, p, length = y[:3].copy(), y[3:6].copy(), y[6]
        t = sol.t[-1]
        if sol.status == 1 and sol.t_events[0].size:
            x[2] = 0.0
            p[2] = -p[2]
            reflections += 1
            if reflections > max_reflections:
                break
            continue
        break
    return RefState(position=x, direction=p / np.linalg.norm(p), reflections=reflections, length_m=length)


# --- profiles written out independently of bentray.engine.profiles ---------------------------------


def log_profile(c0: float = 340.0, b: float = 1.0, z_g: float = 1.0, c_ref: float = 340.0):
    """n and grad n of c(z) = c0 + b ln(z/z_g + 1)."""

    def n_of(x):
        return c_ref / (c0 + b * np.log(max(x[2], 0.0) / z_g + 1.0))

    def grad_n_of(x):
        z = max(x[2], 0.0)
        c = c0 + b * np.log(z / z_g + 1.0)
        return np.array([0.0, 0.0, -c_ref * b / ((z + z_g) * c * c)])

    return n_of, grad_n_of


def mirage_profile(kind: str, mu0: float = 1.000233, mu1: float = 0.4584, beta: float = 2.303):
    """Inferior (n^2 = mu0^2 + mu1^2 (1 - e^{-beta z})) or superior (n^2 = mu0^2 + mu1^2 e^{-beta z})."""
    sign = 1.0 if kind == "inferior" else -1.0

    def n2(z):
        return mu0**2 + mu1**2 * ((1.0 - np.exp(-beta * z)) if sign > 0 else np.exp(-beta * z))

    def n_of(x):
        return np.sqrt(n2(max(x[2], 0.0)))

    def grad_n_of(x):
        z = max(x[2], 0.0)
        dn2 = sign * mu1**2 * beta * np.exp(-beta * z)
        return np.array([0.0, 0.0, dn2 / (2.0 * np.sqrt(n2(z)))])

    return n_of, grad_n_of

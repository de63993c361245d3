"""Explicit one-step integrators of the ray equations (Euler, step-doubling Euler, RK4, Dormand-Prince 5(4)).

Ray ODE (physics.md section 1), ``d/ds (n dx/ds) = grad n``, ``dt/ds = n / c_ref``, written in the
parameter sigma with ``d sigma = ds / n`` and ``p = n dx/ds`` (the analytic parabolic curve's
parameter, physics.md section 2). State ``y`` (NY = 8,) float64:

    y[0:3] x (m)   y[3:6] p (dimensionless, |p| = n)   y[6] t (s)   y[7] s (m, arc length)

    dx/dsigma = p,   dp/dsigma = n grad n = grad(n^2) / 2,   dt/dsigma = n^2 / c_ref,   ds/dsigma = n

Why sigma rather than arc length: the right-hand side is polynomial in p (no division by n or |p|,
no renormalisation needed for the equations to make sense), and it is the form in which the
parabolic primitive is exact: for constant grad(n^2) the solution is polynomial (x quadratic, t cubic
in sigma), so RK4 and DOPRI5 reproduce it to rounding, a built-in check. Arc length is carried as
a state component, so ``s`` is integrated to the method's order too. sigma is approximately the arc
length divided by n (n ~ 1 in air), so steps given in metres are converted with ``h = step_m / n``.

Media are selected by an integer (Numba first-class functions do not cache): a ``media`` tuple
``(kind, exact_code, exact_params, planes, neighbours, media_ref, ref_point, gradient, quantity,
c_ref)`` built by :func:`make_media`; kind ``MEDIA_EXACT`` evaluates the closed-form profile
(exact_media.n_and_grad), ``MEDIA_MESH`` the CellMesh's linear model of the cell found by walking
from ``cell`` (mesh_media.mesh_n_and_grad).

Every stepper takes ``k1 = f(y0)`` precomputed (so a restarted step costs no new evaluation at its
start) and returns False when the media was unphysical (n <= 0) or non-finite at a stage.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from bentray.engine.baselines.exact_media import n_and_grad
from bentray.engine.baselines.mesh_media import QUANTITY_CODES, mesh_n_and_grad
from bentray.engine.constants import NJIT_FLAGS
from bentray.engine.mesh.cells import CellMesh

__all__ = [
    "NY",
    "MEDIA_EXACT",
    "MEDIA_MESH",
    "METHOD_EULER",
    "METHOD_EULER_ADAPTIVE",
    "METHOD_RK4",
    "METHOD_DOPRI5",
    "METHOD_CODES",
    "make_media",
    "media_n",
    "rhs",
    "euler_step",
    "euler_doubling_step",
    "rk4_step",
    "dopri5_step",
    "advance",
    "error_norm",
]

NY = 8  # state size: x(3), p(3), t, s

MEDIA_EXACT = 0
MEDIA_MESH = 1

METHOD_EULER = 0  # fixed step, order 1 (the paper's polygonal rays)
METHOD_EULER_ADAPTIVE = 1  # step doubling (paper Sec. 4.2): two half steps accepted, order 1
METHOD_RK4 = 2  # classical Runge-Kutta, fixed step, order 4
METHOD_DOPRI5 = 3  # Dormand-Prince 5(4), adaptive, local extrapolation, FSAL
METHOD_CODES = {"euler": METHOD_EULER, "euler_adaptive": METHOD_EULER_ADAPTIVE, "rk4": METHOD_RK4,
                "dopri5": METHOD_DOPRI5}
# Work rows each stepper needs (see advance): dopri5 uses k2..k6 and a stage state.
WORK_ROWS = 6

# Dormand-Prince 5(4) tableau (Dormand & Prince 1980; Hairer, Norsett & Wanner, Table II.5.2).
A21 = 1.0 / 5.0
A31, A32 = 3.0 / 40.0, 9.0 / 40.0
A41, A42, A43 = 44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0
A51, A52, A53, A54 = 19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0
A61, A62, A63, A64, A65 = 9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0
B1, B3, B4, B5, B6 = 35.0 / 384.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0
# Error coefficients: 5th-order weights minus the embedded 4th-order ones (b - b_hat).
E1, E3, E4, E5, E6, E7 = (71.0 / 57600.0, -71.0 / 16695.0, 71.0 / 1920.0, -17253.0 / 339200.0, 22.0 / 525.0,
                          -1.0 / 40.0)


def make_media(
    media: str,
    *,
    exact_spec: tuple[int, np.ndarray] | None = None,
    mesh: CellMesh | None = None,
    quantity: str = "n2",
    c_ref: float = 340.0,
) -> tuple:
    """The ``media`` tuple the kernels dispatch on.

    media : "exact" (needs ``exact_spec`` from exact_media.exact_media_spec) or "mesh" (needs ``mesh``
    and the traced ``quantity`` "n2", "c" or "n"). Unused slots hold 1-element dummies so that both
    kinds share one compiled signature.
    """
    dummy3 = np.zeros((1, 1, 4))
    dummy_nb = np.full((1, 1), -9, dtype=np.int64)
    if media == "exact":
        if exact_spec is None:
            raise ValueError("media='exact' needs exact_spec = exact_media_spec(profile)")
        code, params = exact_spec
        params = np.ascontiguousarray(params, dtype=np.float64)
        if params[0] != c_ref:
            raise ValueError(f"c_ref {c_ref} differs from the profile's c_ref {params[0]}")
        return (MEDIA_EXACT, int(code), params, dummy3, dummy_nb, np.zeros(1), np.zeros((1, 3)),
                np.zeros((1, 3)), 0, float(c_ref))
    if media == "mesh":
        if mesh is None:
            raise ValueError("media='mesh' needs a CellMesh")
        if quantity not in QUANTITY_CODES:
            raise ValueError(f"quantity must be one of {sorted(QUANTITY_CODES)}, got {quantity!r}")
        f8 = np.float64
        return (
            MEDIA_MESH, -1, np.zeros(1),
            np.ascontiguousarray(mesh.planes, dtype=f8), np.ascontiguousarray(mesh.neighbours, dtype=np.int64),
            np.ascontiguousarray(mesh.media_ref, dtype=f8), np.ascontiguousarray(mesh.ref_point, dtype=f8),
            np.ascontiguousarray(mesh.gradient, dtype=f8), int(QUANTITY_CODES[quantity]), float(c_ref),
        )
    raise ValueError(f"media must be 'exact' or 'mesh', got {media!r}")


@nb.njit(**NJIT_FLAGS)
def media_n(media, cell, x, out_grad):
    """n at ``x`` (3,) m and grad n into ``out_grad`` (3,) 1/m, dispatched on ``media[0]``."""
    if media[0] == MEDIA_EXACT:
        return n_and_grad(media[1], media[2], x, out_grad)
    n, _ = mesh_n_and_grad(media[3], media[4], media[5], media[6], media[7], media[8], media[9], cell, x, out_grad)
    return n


@nb.njit(**NJIT_FLAGS)
def rhs(media, cell, y, out):
    """out (NY,) = dy/dsigma at state y (NY,). False when n <= 0 or anything is non-finite."""
    g = np.empty(3)
    n = media_n(media, cell, y, g)
    out[0] = y[3]
    out[1] = y[4]
    out[2] = y[5]
    out[3] = n * g[0]
    out[4] = n * g[1]
    out[5] = n * g[2]
    out[6] = n * n / media[9]
    out[7] = n
    return n > 0.0 and math.isfinite(n) and math.isfinite(g[0] + g[1] + g[2])


@nb.njit(**NJIT_FLAGS)
def euler_step(y0, k1, h, y1):
    """Explicit Euler: y1 = y0 + h k1 (no evaluation; the paper's Eq. 2)."""
    for i in range(NY):
        y1[i] = y0[i] + h * k1[i]


@nb.njit(**NJIT_FLAGS)
def euler_doubling_step(media, cell, y0, k1, h, y1, yerr, work):
    """Two Euler half steps into y1; yerr = y1 - (one full Euler step): the step-doubling estimate.

    work : (>= 2, NY) scratch. One new evaluation (at the midpoint).
    """
    hh = 0.5 * h
    ym = work[0]
    km = work[1]
    for i in range(NY):
        ym[i] = y0[i] + hh * k1[i]
    ok = rhs(media, cell, ym, km)
    for i in range(NY):
        y1[i] = ym[i] + hh * km[i]
        yerr[i] = y1[i] - (y0[i] + h * k1[i])
    return ok


@nb.njit(**NJIT_FLAGS)
def rk4_step(media, cell, y0, k1, h, y1, work):
    """Classical RK4 step into y1. work : (>= 4, NY) scratch. Three new evaluations."""
    k2 = work[0]
    k3 = work[1]
    k4 = work[2]
    yt = work[3]
    for i in range(NY):
        yt[i] = y0[i] + 0.5 * h * k1[i]
    ok = rhs(media, cell, yt, k2)
    for i in range(NY):
        yt[i] = y0[i] + 0.5 * h * k2[i]
    ok = rhs(media, cell, yt, k3) and ok
    for i in range(NY):
        yt[i] = y0[i] + h * k3[i]
    ok = rhs(media, cell, yt, k4) and ok
    for i in range(NY):
        y1[i] = y0[i] + h * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) / 6.0
    return ok


@nb.njit(**NJIT_FLAGS)
def dopri5_step(media, cell, y0, k1, h, y1, k7, yerr, work):
    """Dormand-Prince 5(4) step: 5th-order y1 (local extrapolation), k7 = f(y1) (FSAL: the next step's
    k1) and the embedded error estimate yerr = y1 - y1_hat (4th order). work : (>= 6, NY) scratch.
    Six new evaluations per step."""
    k2 = work[0]
    k3 = work[1]
    k4 = work[2]
    k5 = work[3]
    k6 = work[4]
    yt = work[5]
    for i in range(NY):
        yt[i] = y0[i] + h * A21 * k1[i]
    ok = rhs(media, cell, yt, k2)
    for i in range(NY):
        yt[i] = y0[i] + h * (A31 * k1[i] + A32 * k2[i])
    ok = rhs(media, cell, yt, k3) and ok
    for i in range(NY):
        yt[i] = y0[i] + h * (A41 * k1[i] + A42 * k2[i] + A43 * k3[i])
    ok = rhs(media, cell, yt, k4) and ok
    for i in range(NY):
        yt[i] = y0[i] + h * (A51 * k1[i] + A52 * k2[i] + A53 * k3[i] + A54 * k4[i])
    ok = rhs(media, cell, yt, k5) and ok
    for i in range(NY):
        yt[i] = y0[i] + h * (A61 * k1[i] + A62 * k2[i] + A63 * k3[i] + A64 * k4[i] + A65 * k5[i])
    ok = rhs(media, cell, yt, k6) and ok
    for i in range(NY):
        y1[i] = y0[i] + h * (B1 * k1[i] + B3 * k3[i] + B4 * k4[i] + B5 * k5[i] + B6 * k6[i])
    ok = rhs(media, cell, y1, k7) and ok
    for i in range(NY):
        yerr[i] = h * (E1 * k1[i] + E3 * k3[i] + E4 * k4[i] + E5 * k5[i] + E6 * k6[i] + E7 * k7[i])
    return ok


@nb.njit(**NJIT_FLAGS)
def advance(method, media, cell, y0, k1, h, y1, knew, yerr, work):
    """One step of ``method`` (METHOD_*) from y0 with step h (sigma units) into y1.

    Returns (ok, has_knew): has_knew when ``knew`` already holds f(y1) (DOPRI5's FSAL stage); yerr
    holds the error estimate of the adaptive methods (zeros for the fixed-step ones). This is the
    accepted-step map: a step restarted with a reduced length (boundary or time limit) calls it again.
    """
    if method == METHOD_EULER:
        euler_step(y0, k1, h, y1)
        for i in range(NY):
            yerr[i] = 0.0
        return True, False
    if method == METHOD_EULER_ADAPTIVE:
        return euler_doubling_step(media, cell, y0, k1, h, y1, yerr, work), False
    if method == METHOD_RK4:
        for i in range(NY):
            yerr[i] = 0.0
        return rk4_step(media, cell, y0, k1, h, y1, work), False
    return dopri5_step(media, cell, y0, k1, h, y1, knew, yerr, work), True


@nb.njit(**NJIT_FLAGS)
def error_norm(yerr, tol):
    """max_i |yerr_i| / tol over position (m) and p (dimensionless): <= 1 accepts the step.

    The tolerance is an absolute local error per step, in metres for x and in units of n for p
    (n ~ 1 in air); t and s are quadratures of the same path and are not controlled separately.
    """
    e = 0.0
    for i in range(6):
        a = abs(yerr[i])
        if not (a == a):  # NaN: reject
            return math.inf
        if a > e:
            e = a
    return e / tol

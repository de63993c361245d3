"""One interface over the three curve kinds, so the traversal loop is written once.

Per cell, a curve is set up from the entry point x0, unit tangent d0, the cell's traced quantity
m0 = m(x0) and its constant gradient g. Its constants live in a small float64 work array ``cs``:

- parabolic (m = n^2): cs[0:3] p0 = n0 d0, cs[3:6] g, cs[6] n0^2, cs[7] g.p0, cs[8] |g|^2
- circular  (m = c):   cs[0:3] k = -G_perp/c0, cs[3] kappa^2, cs[4] |G|, cs[5] w, cs[6] c0
- n-linear  (m = n):   cs[0:3] e_r, cs[3:6] e_z, cs[6] alpha, cs[7] xi, cs[8] u0, cs[9] straight,
                       cs[10] n0, cs[11] g.d0 (straight mode)

The curve parameter ("param") is sigma, u or r (s in straight n-linear mode); it starts at 0 in the
cell and only grows. Functions return travel time and arc length increments from param 0.
"""

from __future__ import annotations

import math

import numba as nb

from bentray.engine.constants import CURVE_CIRCULAR, CURVE_PARABOLIC, FACE_UNUSED, NJIT_FLAGS
from bentray.engine.kernels import circular, nlinear, parabolic
from bentray.engine.kernels.llvm_inline import njit_inline
from bentray.engine.kernels.roots import NO_ROOT, face_exit_parameter

CS_SIZE = 16


@nb.njit(**NJIT_FLAGS)
def slowness(curve: int, m: float, c_ref: float) -> float:
    """1/c (s/m) from the traced quantity m (n^2, c or n) of the curve kind."""
    if curve == CURVE_PARABOLIC:
        return math.sqrt(m) / c_ref
    if curve == CURVE_CIRCULAR:
        return 1.0 / m
    return m / c_ref


@njit_inline
def setup(curve: int, m0: float, g, d0, cs) -> bool:
    """Fill ``cs`` for the cell; False when the media value is unphysical (n^2, c or n <= 0)."""
    if not (m0 > 0.0) or not math.isfinite(m0):
        return False
    if curve == CURVE_PARABOLIC:
        n0 = math.sqrt(m0)
        for i in range(3):
            cs[i] = n0 * d0[i]
            cs[3 + i] = g[i]
        cs[6] = m0
        cs[7] = g[0] * cs[0] + g[1] * cs[1] + g[2] * cs[2]
        cs[8] = g[0] * g[0] + g[1] * g[1] + g[2] * g[2]
        return True
    if curve == CURVE_CIRCULAR:
        kappa2, gnorm, w = circular.setup(m0, g, d0, cs[0:3])
        cs[3] = kappa2
        cs[4] = gnorm
        cs[5] = w
        cs[6] = m0
        return True
    straight, alpha, xi, u0, gd = nlinear.setup(m0, g, d0, cs[0:3], cs[3:6])
    cs[6] = alpha
    cs[7] = xi
    cs[8] = u0
    cs[9] = 1.0 if straight else 0.0
    cs[10] = m0
    cs[11] = gd
    return True


@njit_inline
def find_exit(curve: int, cs, x0, d0, planes, neighbours, entry: int, on_face_tol: float, size: float):
    """(face index, param) of the first exit among the cell's face planes; (-1, inf) if none.

    planes : (K, 4) of the cell, neighbours : (K,) (FACE_UNUSED slots are skipped).
    """
    best = NO_ROOT
    best_face = -1
    for f in range(planes.shape[0]):
        if neighbours[f] == FACE_UNUSED:
            continue
        mx = planes[f, 0]
        my = planes[f, 1]
        mz = planes[f, 2]
        h = planes[f, 3]
        is_entry = f == entry
        if curve == CURVE_PARABOLIC:
            a, b, c = parabolic.plane_coefficients(mx, my, mz, h, x0, cs[0:3], cs[3:6])
            r = face_exit_parameter(a, b, c, is_entry, on_face_tol)
        elif curve == CURVE_CIRCULAR:
            a, b, c = circular.plane_coefficients(mx, my, mz, h, x0, d0, cs[0:3], cs[3])
            r = face_exit_parameter(a, b, c, is_entry, on_face_tol)
        elif cs[9] != 0.0:  # straight n-linear
            c = mx * x0[0] + my * x0[1] + mz * x0[2] - h
            b = mx * d0[0] + my * d0[1] + mz * d0[2]
            r = face_exit_parameter(0.0, b, c, is_entry, on_face_tol)
        else:
            r = nlinear.face_exit((mx, my, mz, h), x0, cs, is_entry, on_face_tol, size)
        if r < best:
            best = r
            best_face = f
    return best_face, best


@njit_inline
def time_at(curve: int, cs, param: float, c_ref: float) -> float:
    """Travel time (s) from param 0 to ``param``."""
    if curve == CURVE_PARABOLIC:
        return parabolic.travel_time(cs[6], cs[7], cs[8], param, c_ref)
    if curve == CURVE_CIRCULAR:
        # circular t is in seconds directly (c in m/s); c_ref plays no role
        return circular.travel_time(cs[6], cs[4], cs[5], param)
    if cs[9] != 0.0:
        return nlinear.straight_time(cs[10], cs[11], param, c_ref)
    return nlinear.travel_time(cs[6], cs[7], cs[8], param, c_ref)


@nb.njit(**NJIT_FLAGS)
def param_at_time(curve: int, cs, dt: float, param_hi: float, c_ref: float) -> float:
    """The param reached after travel time dt (dt <= time_at(param_hi))."""
    if curve == CURVE_PARABOLIC:
        return parabolic.sigma_at_time(cs[6], cs[7], cs[8], dt, param_hi, c_ref)
    if curve == CURVE_CIRCULAR:
        u = circular.u_at_time(cs[6], cs[4], cs[5], dt)
        return u if u < param_hi else param_hi
    if cs[9] != 0.0:
        s = nlinear.straight_s_at_time(cs[10], cs[11], dt, c_ref)
        return s if s < param_hi else param_hi
    return nlinear.r_at_time(cs[6], cs[7], cs[8], dt, param_hi, c_ref)


@njit_inline
def evaluate(curve: int, cs, x0, d0, param: float, x_out, t_out) -> float:
    """Write x(param), T(param) into x_out, t_out; return the arc length (m) from param 0."""
    if curve == CURVE_PARABOLIC:
        parabolic.state_at(x0, cs[0:3], cs[3:6], param, x_out, t_out)
        return parabolic.arc_length(cs[0:3], cs[3:6], param)
    if curve == CURVE_CIRCULAR:
        circular.state_at(x0, d0, cs[0:3], cs[3], param, x_out, t_out)
        return circular.arc_length(cs[3], param)
    if cs[9] != 0.0:
        for i in range(3):
            x_out[i] = x0[i] + param * d0[i]
            t_out[i] = d0[i]
        return param
    nlinear.state_at(x0, cs[0:3], cs[3:6], cs[6], cs[7], cs[8], param, x_out, t_out)
    return nlinear.arc_length(cs[6], cs[7], cs[8], param)


@nb.njit(**NJIT_FLAGS)
def evaluate_call(curve: int, cs, x0, d0, param: float, x_out, t_out) -> float:
    """:func:`evaluate` as a called function, for call sites off the per-crossing path (path samples, the last
    segment of a ray). evaluate is inlined wherever it is called, and each inlined copy (with its arc length and
    the three curve kinds) is optimised and emitted again (under Numba's IR inlining, until 2026-12-05, also
    typed again: 5 copies cost ~8 s of the first run's compilation)."""
    return evaluate(curve, cs, x0, d0, param, x_out, t_out)


@nb.njit(**NJIT_FLAGS)
def interior_step(curve: int, cs) -> float:
    """Param of a within-cell step when no face is reached (circular: a quarter turn), else inf."""
    if curve == CURVE_CIRCULAR and cs[3] > 0.0:
        return 1.0 / math.sqrt(cs[3])
    return NO_ROOT

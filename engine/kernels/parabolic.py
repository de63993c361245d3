"""Parabolic ray curve: constant g = grad(n^2) inside a cell (physics.md section 2).

Parameter sigma with d sigma = ds / n and p = n dx/ds (|p| = n):

    p(sigma) = p0 + (g/2) sigma,   x(sigma) = x0 + p0 sigma + (g/4) sigma^2
    t(sigma) = (n0^2 sigma + (g.p0) sigma^2 / 2 + |g|^2 sigma^3 / 12) / c_ref

sigma grows monotonically (n > 0), so there is no turning-point singularity: grazing rays and rays
along the gradient need no special case. Arc length is the closed-form integral of |p(sigma)|,
rearranged so that it stays accurate as |g| -> 0 and as p0 becomes parallel to g (see
``arc_length``). All arrays are float64 (3,) in the world frame, metres.
"""

from __future__ import annotations

import math

from bentray.engine.constants import TIME_SOLVE_ITERS
from bentray.engine.kernels.llvm_inline import njit_inline
from bentray.engine.kernels.roots import log1p_over_x


@njit_inline
def plane_coefficients(mx, my, mz, h, x0, p0, g):
    """Coefficients (A, B, C) of ``m.x(sigma) - h = A sigma^2 + B sigma + C``."""
    a = 0.25 * (mx * g[0] + my * g[1] + mz * g[2])
    b = mx * p0[0] + my * p0[1] + mz * p0[2]
    c = mx * x0[0] + my * x0[1] + mz * x0[2] - h
    return a, b, c


@njit_inline
def travel_time(n0sq: float, gp0: float, gg: float, sigma: float, c_ref: float) -> float:
    """Exact travel time (s) after parameter sigma (the cubic of physics.md section 2)."""
    return sigma * (n0sq + sigma * (0.5 * gp0 + sigma * gg / 12.0)) / c_ref


@njit_inline
def sigma_at_time(n0sq: float, gp0: float, gg: float, dt: float, sigma_hi: float, c_ref: float) -> float:
    """Solve t(sigma) = dt on [0, sigma_hi] (t is strictly increasing: dt/dsigma = n^2 / c_ref).

    Newton steps safeguarded by the bracket; converges to a few ulps.
    """
    lo = 0.0
    hi = sigma_hi
    t_hi = travel_time(n0sq, gp0, gg, hi, c_ref)
    s = hi * dt / t_hi if t_hi > 0.0 else 0.0
    for _ in range(TIME_SOLVE_ITERS):
        f = travel_time(n0sq, gp0, gg, s, c_ref) - dt
        if f > 0.0:
            hi = s
        else:
            lo = s
        deriv = (n0sq + s * (gp0 + s * gg / 4.0)) / c_ref
        step = f / deriv if deriv > 0.0 else 0.0
        s_new = s - step
        if not (lo < s_new < hi):
            s_new = 0.5 * (lo + hi)
        if abs(s_new - s) <= 4e-16 * abs(s_new) or hi - lo <= 4e-16 * hi:
            return s_new
        s = s_new
    return s


@njit_inline
def _plus_part(y: float, p: float, hh: float) -> float:
    """y + sqrt(y^2 + h^2) (= y + p) without cancellation when y < 0."""
    if y >= 0.0:
        return y + p
    return hh / (p - y)


@njit_inline
def arc_length_closed(p0, g, sigma: float) -> float:
    """Closed-form arc length of the parabolic segment, integral_0^sigma |p0 + (g/2) u| du (metres).

    With v = g/2, w = |v|, Y = p.v/w (component along v) and h = |p0 x v|/w (constant normal part):
    s = [Y1 P1 - Y0 P0 + h^2 ln((Y1 + P1)/(Y0 + P0))] / (2 w). Both terms are rewritten without the
    1/w factor (differences of P and of Y + P taken analytically), so the result is accurate to a
    few ulps for any |g| including 0 and for p0 (anti)parallel to g.
    """
    p0x, p0y, p0z = p0[0], p0[1], p0[2]
    big_p0 = math.sqrt(p0x * p0x + p0y * p0y + p0z * p0z)
    vx, vy, vz = 0.5 * g[0], 0.5 * g[1], 0.5 * g[2]
    w = math.sqrt(vx * vx + vy * vy + vz * vz)
    if w == 0.0 or sigma == 0.0:
        return big_p0 * sigma
    ux, uy, uz = vx / w, vy / w, vz / w
    y0 = p0x * ux + p0y * uy + p0z * uz
    cx = p0y * uz - p0z * uy
    cy = p0z * ux - p0x * uz
    cz = p0x * uy - p0y * ux
    hh = cx * cx + cy * cy + cz * cz  # h^2
    p1x, p1y, p1z = p0x + vx * sigma, p0y + vy * sigma, p0z + vz * sigma
    big_p1 = math.sqrt(p1x * p1x + p1y * p1y + p1z * p1z)
    y1 = y0 + w * sigma
    psum = big_p1 + big_p0
    if psum == 0.0:
        return 0.0
    term1 = 0.5 * sigma * (big_p1 + y0 * (y1 + y0) / psum)
    a0 = _plus_part(y0, big_p0, hh)
    a1 = _plus_part(y1, big_p1, hh)
    if hh == 0.0 or a0 == 0.0:
        return term1
    k = (a1 + a0) / psum
    hh_over_a0 = (big_p0 - y0) if y0 < 0.0 else hh / a0
    z = w * sigma * k / a0
    term2 = 0.5 * sigma * k * hh_over_a0 * log1p_over_x(z)
    return term1 + term2


# Gauss-Legendre arc length (arc_length). With e = w sigma / (2 |p_mid|) the half-turning ratio of the segment
# (w = |g| / 2, p_mid = p at the segment's middle), the N-point rule's truncation error is at most
# 4 |binom(1/2, 2N)| e^(2N) / (1 - e)^2 relative (docs/physics.md section 2, "Arc length by quadrature"). The
# rule with N points is used up to the e where that bound is 2e-16: 1.9e-4 (N = 2), 3.66e-3 (N = 3),
# 1.57e-2 (N = 4; 2.1e-16 with the (1 - e)^2); the closed form beyond. ARC_Q* = 0.999 (e / (1 + e))^2 is
# compared with (w sigma / 2)^2 / |p0|^2 (|p_mid| >= |p0| - w sigma / 2).
ARC_E2, ARC_E3, ARC_E4 = 1.9e-4, 3.66e-3, 1.57e-2
ARC_Q2 = 0.999 * (ARC_E2 / (1.0 + ARC_E2)) ** 2
ARC_Q3 = 0.999 * (ARC_E3 / (1.0 + ARC_E3)) ** 2
ARC_Q4 = 0.999 * (ARC_E4 / (1.0 + ARC_E4)) ** 2
GL2_T = 0.57735026918962576451  # nodes on [-1, 1] (positive half) and weights
GL3_T, GL3_W0, GL3_W1 = 0.77459666924148337704, 8.0 / 9.0, 5.0 / 9.0
GL4_T0, GL4_T1 = 0.33998104358485626480, 0.86113631159405257522
GL4_W0, GL4_W1 = 0.65214515486254614263, 0.34785484513745385737


@njit_inline
def _speed(p0, g, u: float) -> float:
    """|p(u)| = |p0 + (g/2) u|."""
    px = p0[0] + 0.5 * g[0] * u
    py = p0[1] + 0.5 * g[1] * u
    pz = p0[2] + 0.5 * g[2] * u
    return math.sqrt(px * px + py * py + pz * pz)


@njit_inline
def arc_length(p0, g, sigma: float) -> float:
    """Arc length of the parabolic segment, integral_0^sigma |p0 + (g/2) u| du (metres).

    |p| is the norm of a linear function of u; in t = 2u/sigma - 1 it is |p_mid| sqrt((1 + alpha t)(1 + conj
    alpha t)) with |alpha| = e = w sigma / (2 |p_mid|) (w = |g|/2), so its Taylor coefficients fall like e^k
    and the N-point Gauss-Legendre rule errs by at most 4 |binom(1/2, 2N)| e^(2N) / (1 - e)^2 relative.
    Depending on e: 2, 3 or 4 points (truncation <= 2e-16 relative), else the closed form
    (arc_length_closed). The test on e uses |p_mid| >= |p0| - w sigma / 2 and squares only: 2-4 square
    roots in all instead of the closed form's 3 square roots, 7 divisions and a log1p. Derivation and
    check against mpmath: docs/physics.md section 2; tests/engine/test_curve_kernels.py.
    """
    mm = p0[0] * p0[0] + p0[1] * p0[1] + p0[2] * p0[2]
    q = 0.0625 * (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) * sigma * sigma  # (w sigma / 2)^2
    h = 0.5 * sigma
    if q <= ARC_Q2 * mm:
        r = GL2_T * h
        return h * (_speed(p0, g, h - r) + _speed(p0, g, h + r))
    if q <= ARC_Q3 * mm:
        r = GL3_T * h
        return h * (GL3_W1 * (_speed(p0, g, h - r) + _speed(p0, g, h + r)) + GL3_W0 * _speed(p0, g, h))
    if q <= ARC_Q4 * mm:
        r0 = GL4_T0 * h
        r1 = GL4_T1 * h
        inner = _speed(p0, g, h - r0) + _speed(p0, g, h + r0)
        outer = _speed(p0, g, h - r1) + _speed(p0, g, h + r1)
        return h * (GL4_W0 * inner + GL4_W1 * outer)
    return arc_length_closed(p0, g, sigma)


@njit_inline
def state_at(x0, p0, g, sigma: float, x_out, t_out) -> None:
    """Position x(sigma) and unit tangent T(sigma) written into x_out, t_out (3,)."""
    px = p0[0] + 0.5 * g[0] * sigma
    py = p0[1] + 0.5 * g[1] * sigma
    pz = p0[2] + 0.5 * g[2] * sigma
    x_out[0] = x0[0] + sigma * (p0[0] + 0.25 * g[0] * sigma)
    x_out[1] = x0[1] + sigma * (p0[1] + 0.25 * g[1] * sigma)
    x_out[2] = x0[2] + sigma * (p0[2] + 0.25 * g[2] * sigma)
    norm = math.sqrt(px * px + py * py + pz * pz)
    t_out[0] = px / norm
    t_out[1] = py / norm
    t_out[2] = pz / norm

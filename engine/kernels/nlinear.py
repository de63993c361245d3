"""n-linear ray curve (Cao et al.; the paper's comparison method): constant grad(n) in a cell.

physics.md section 4. With alpha = |grad n|, axis e_z = grad n / alpha, e_r the unit part of d0 normal
to e_z, xi = n0 cos(theta0), u0 = asinh(tan theta0) and U(r) = alpha r / xi + u0, the ray is a
catenary in the ray plane, parametrised by the distance r along e_r:

    z(r) = (2 xi / alpha) sinh((U + u0)/2) sinh(alpha r / (2 xi))        (height along e_z)
    s(r) = (2 xi / alpha) cosh((U + u0)/2) sinh(alpha r / (2 xi))        (arc length)
    t(r) = xi / (2 c_ref) * (r + cosh(U + u0) (xi / alpha) sinh(alpha r / xi))
    T(r) = (e_r + sinh(U) e_z) / cosh(U)

(the product forms of the textbook expressions; they have finite limits as alpha -> 0). Plane
intersections have no closed form: bisection on m.x(r) - h, as the comparison method does; that cost
is what the benchmark's time breakdown measures. Rays (nearly) along e_z, and alpha = 0, are straight
lines with n linear along them.
"""

from __future__ import annotations

import math

import numba as nb

from bentray.engine.constants import NJIT_FLAGS, NLINEAR_BISECTION_ITERS, NLINEAR_MAX_DOUBLINGS, NLINEAR_STRAIGHT_COS
from bentray.engine.kernels.roots import NO_ROOT, face_exit_parameter, sinh_over_x


@nb.njit(**NJIT_FLAGS)
def setup(n0: float, g, d0, er_out, ez_out):
    """Curve constants. Writes e_r, e_z; returns (straight, alpha, xi, u0, g_along_d0).

    straight = True means: x(s) = x0 + s d0, n(s) = n0 + (g.d0) s, parameter is s.
    """
    alpha = math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    gd = g[0] * d0[0] + g[1] * d0[1] + g[2] * d0[2]
    if alpha == 0.0:
        for i in range(3):
            ez_out[i] = 0.0
            er_out[i] = d0[i]
        return True, 0.0, n0, 0.0, gd
    for i in range(3):
        ez_out[i] = g[i] / alpha
    sin0 = gd / alpha
    rx = d0[0] - sin0 * ez_out[0]
    ry = d0[1] - sin0 * ez_out[1]
    rz = d0[2] - sin0 * ez_out[2]
    cos0 = math.sqrt(rx * rx + ry * ry + rz * rz)
    if cos0 < NLINEAR_STRAIGHT_COS:
        for i in range(3):
            er_out[i] = d0[i]
        return True, alpha, n0, 0.0, gd
    er_out[0] = rx / cos0
    er_out[1] = ry / cos0
    er_out[2] = rz / cos0
    return False, alpha, n0 * cos0, math.asinh(sin0 / cos0), gd


@nb.njit(**NJIT_FLAGS)
def height(alpha: float, xi: float, u0: float, r: float) -> float:
    """z(r): displacement along e_z (m)."""
    half = 0.5 * alpha * r / xi
    return math.sinh(u0 + half) * r * sinh_over_x(half)


@nb.njit(**NJIT_FLAGS)
def arc_length(alpha: float, xi: float, u0: float, r: float) -> float:
    """s(r): arc length (m)."""
    half = 0.5 * alpha * r / xi
    return math.cosh(u0 + half) * r * sinh_over_x(half)


@nb.njit(**NJIT_FLAGS)
def travel_time(alpha: float, xi: float, u0: float, r: float, c_ref: float) -> float:
    """t(r): travel time (s)."""
    full = alpha * r / xi
    return 0.5 * xi / c_ref * (r + math.cosh(full + 2.0 * u0) * r * sinh_over_x(full))


@nb.njit(**NJIT_FLAGS)
def _plane_value(c: float, a: float, b: float, alpha: float, xi: float, u0: float, r: float) -> float:
    return c + a * r + b * height(alpha, xi, u0, r)


@nb.njit(**NJIT_FLAGS)
def _bisect(c, a, b, alpha, xi, u0, lo, hi):
    """Root of the plane function on [lo, hi] with f(lo) <= 0 < f(hi)."""
    for _ in range(NLINEAR_BISECTION_ITERS):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        if _plane_value(c, a, b, alpha, xi, u0, mid) > 0.0:
            hi = mid
        else:
            lo = mid
    return hi


@nb.njit(**NJIT_FLAGS)
def face_exit(plane, x0, cs, is_entry, on_face_tol, size):
    """Exit parameter r through one face plane (bisection), or +inf. Up-crossings only.

    plane : (mx, my, mz, h) outward unit normal and offset (a tuple of floats); x0 : (3,) start (m);
    cs : the curve record of curves.setup (er = cs[0:3], ez = cs[3:6], alpha, xi, u0 = cs[6], cs[7], cs[8]);
    is_entry : the face the ray entered through; on_face_tol : m; size : cell size (m, bracket step).
    """
    mx, my, mz, h = plane
    alpha = cs[6]
    xi = cs[7]
    u0 = cs[8]
    c = mx * x0[0] + my * x0[1] + mz * x0[2] - h
    if is_entry:
        c = 0.0
    a = mx * cs[0] + my * cs[1] + mz * cs[2]
    b = mx * cs[3] + my * cs[4] + mz * cs[5]
    if b == 0.0:
        return face_exit_parameter(0.0, a, c, is_entry, on_face_tol)
    slope0 = a + b * math.sinh(u0)  # f'(0)
    if c > -on_face_tol and slope0 > 0.0:
        # already on/beyond the plane and moving out: immediate exit, except through the entry face
        return NO_ROOT if is_entry else 0.0
    # r* where f' = 0 (extremum of f): sinh(U*) = -a / b
    r_star = (math.asinh(-a / b) - u0) * xi / alpha
    if b > 0.0:  # convex: decreasing until r*, then increasing without bound
        lo = r_star if r_star > 0.0 else 0.0
        if _plane_value(c, a, b, alpha, xi, u0, lo) > 0.0:
            return NO_ROOT
        step = size if size > 0.0 else 1.0
        hi = lo + step
        for _ in range(NLINEAR_MAX_DOUBLINGS):
            if _plane_value(c, a, b, alpha, xi, u0, hi) > 0.0:
                return _bisect(c, a, b, alpha, xi, u0, lo, hi)
            step *= 2.0
            hi = lo + step
        return NO_ROOT
    # concave: increasing until r*, then decreasing: an up-crossing only inside (0, r*)
    if r_star <= 0.0:
        return NO_ROOT
    if _plane_value(c, a, b, alpha, xi, u0, r_star) <= 0.0:
        return NO_ROOT
    return _bisect(c, a, b, alpha, xi, u0, 0.0, r_star)


@nb.njit(**NJIT_FLAGS)
def r_at_time(alpha, xi, u0, dt, r_hi, c_ref):
    """Solve t(r) = dt on [0, r_hi] by bisection (t increasing in r)."""
    lo = 0.0
    hi = r_hi
    for _ in range(NLINEAR_BISECTION_ITERS + 20):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        if travel_time(alpha, xi, u0, mid, c_ref) > dt:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


@nb.njit(**NJIT_FLAGS)
def state_at(x0, er, ez, alpha, xi, u0, r, x_out, t_out) -> None:
    """Position x(r) and unit tangent T(r) written into x_out, t_out (3,)."""
    z = height(alpha, xi, u0, r)
    big_u = alpha * r / xi + u0
    sh = math.sinh(big_u)
    ch = math.cosh(big_u)
    for i in range(3):
        x_out[i] = x0[i] + r * er[i] + z * ez[i]
        t_out[i] = (er[i] + sh * ez[i]) / ch


# ----- straight mode (alpha == 0 or ray along the gradient): parameter s, n(s) = n0 + gd s ---------


@nb.njit(**NJIT_FLAGS)
def straight_time(n0: float, gd: float, s: float, c_ref: float) -> float:
    return s * (n0 + 0.5 * gd * s) / c_ref


@nb.njit(**NJIT_FLAGS)
def straight_s_at_time(n0: float, gd: float, dt: float, c_ref: float) -> float:
    """Stable root of n0 s + gd s^2 / 2 = dt c_ref."""
    rhs = dt * c_ref
    disc = n0 * n0 + 2.0 * gd * rhs
    if disc < 0.0:
        disc = 0.0
    return 2.0 * rhs / (n0 + math.sqrt(disc))

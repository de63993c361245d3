"""Root helpers shared by the curve kernels: stable quadratic up-crossings and small special functions.

A face plane ``m . x = h`` seen along a curve parameter ``u >= 0`` gives a signed distance
``f(u) = A u^2 + B u + C`` (parabolic: u = sigma; circular: u = tan(psi/2)/kappa, up to a positive
factor). The cell is ``f <= 0``. The ray leaves through that face where f crosses zero *upward*
(f' > 0). A quadratic has at most one upward crossing, and with the stable formula
``q = -(B + sign(B) sqrt(B^2 - 4AC)) / 2`` it is always ``C / q`` when ``B >= 0`` and ``q / A`` when
``B < 0`` (the two roots' derivatives are ``-sign(B) sqrt(disc)`` and ``+sign(B) sqrt(disc)``).
No case split on the sign of A, no cancellation, and A -> 0 tends smoothly to the linear root -C/B.
"""

from __future__ import annotations

import math

from bentray.engine.kernels.llvm_inline import njit_inline

NO_ROOT = math.inf


@njit_inline
def upcrossing_root(a: float, b: float, c: float) -> float:
    """Parameter of the unique upward zero crossing of ``a u^2 + b u + c`` (any sign), or +inf.

    Tangent contacts (disc == 0) are not crossings and return +inf. A linear f (a == 0: a plane parallel
    to the gradient, e.g. every side face of a horizontal slab) skips the square root: there -c / b is bit
    for bit what the formula below gives (sqrt(b * b) == |b| exactly while b * b is a normal float).
    """
    if a == 0.0 and math.isfinite(c) and abs(b) < 1e150:
        if b > 1e-150:
            return c / -b
        if b < -1e-150:
            return NO_ROOT
    disc = b * b - 4.0 * a * c
    if disc <= 0.0:
        return NO_ROOT
    sq = math.sqrt(disc)
    if b >= 0.0:
        q = -0.5 * (b + sq)
        return c / q  # q < 0 strictly because sq > 0
    q = -0.5 * (b - sq)
    if a == 0.0:
        return NO_ROOT  # linear with b < 0: only a downward crossing
    return q / a


@njit_inline
def face_exit_parameter(a: float, b: float, c: float, is_entry: bool, on_face_tol: float) -> float:
    """Exit parameter through one face, or +inf when the curve does not leave through it.

    - entry face (``c`` is exactly 0 there): only a strictly positive up-crossing counts; a ray that
      grazes back out through the face it came in by is handled by the non-zero root.
    - other faces: a positive up-crossing counts; a point already on or beyond the plane
      (``c > -on_face_tol``) that moves outward (``b > 0``) exits at once (parameter 0). This is the
      rounding case at edges and vertices, and it keeps the walk going instead of losing the ray. So does
      a point on the plane moving exactly along it (``b == 0``) and curving outward (``a > 0``).
    """
    if is_entry:
        c = 0.0
    r = upcrossing_root(a, b, c)
    if 0.0 < r < NO_ROOT:
        return r
    if (not is_entry) and c > -on_face_tol and (b > 0.0 or (b == 0.0 and a > 0.0)):
        return 0.0  # moving out, or tangent and curving out (a grazing ray on the ground): exit at once
    return NO_ROOT


@njit_inline
def log1p_over_x(z: float) -> float:
    """log(1 + z) / z, exact limit 1 at z = 0 (z > -1)."""
    if abs(z) < 1e-4:
        return 1.0 - z / 2.0 + z * z / 3.0 - z * z * z / 4.0
    return math.log1p(z) / z


@njit_inline
def expm1_over_x(z: float) -> float:
    """(exp(z) - 1) / z, exact limit 1 at z = 0."""
    if abs(z) < 1e-4:
        return 1.0 + z / 2.0 + z * z / 6.0 + z * z * z / 24.0
    return math.expm1(z) / z


@njit_inline
def atan_over_x(z: float) -> float:
    """atan(z) / z, exact limit 1 at z = 0."""
    if abs(z) < 1e-4:
        z2 = z * z
        return 1.0 - z2 / 3.0 + z2 * z2 / 5.0
    return math.atan(z) / z


@njit_inline
def sinh_over_x(z: float) -> float:
    """sinh(z) / z, exact limit 1 at z = 0."""
    if abs(z) < 1e-4:
        z2 = z * z
        return 1.0 + z2 / 6.0 + z2 * z2 / 120.0
    return math.sinh(z) / z

"""Numba kernels of edge diffraction: Fresnel integrals and the uniform (UTD) rigid-wedge coefficient.

Time factor exp(-i w t) throughout (waves carry exp(+i k s)). Everything here is self-contained: the
kernels call no function from another module (numba's cache would not notice a change there).

Fresnel integrals C(x), S(x) (pi/2 normalisation, C(x) = int_0^x cos(pi t^2/2) dt) by the power series
for |x| <= 1.5 and the continued fraction of the complementary error function beyond (Numerical
Recipes, ``frenel``; relative accuracy ~1e-15). The auxiliary functions f, g (Abramowitz and Stegun
7.3.5-6: 1/2 - C = g cos X - f sin X, 1/2 - S = f cos X + g sin X, X = pi x^2/2) come straight from the
continued fraction for large x (no cancellation): g + i f = (1 + i)/2 (1 - i) x h.

UTD transition function (Kouyoumjian and Pathak 1974, conjugated for exp(-i w t)):

    F(X) = -2 i sqrt(X) exp(-i X) int_{sqrt X}^inf exp(i t^2) dt = sqrt(2 pi X) (f(u) - i g(u)),  u = sqrt(2X/pi),

F(0) = 0, F -> 1 for X >> 1. Rigid (acoustically hard, Neumann) wedge of exterior angle n pi (n = 2: thin
half-plane; n = 3/2: a 90-degree building corner seen from outside), angles phi (receiver) and phi'
(source) measured from face 0 through the air, 0 <= phi, phi' <= n pi:

    D = -exp(i pi/4) / (2 n sqrt(2 pi k) sin b0) * sum_{beta in (phi - phi', phi + phi')} sum_{+-}
        cot((pi +- beta) / (2 n)) F(k L a+-(beta)),   a+-(beta) = 2 cos^2((2 n pi N+- - beta) / 2),

N+- the integers nearest to (beta +- pi) / (2 n pi); b0 the angle between the incident ray and the edge;
L the distance parameter (s s' sin^2 b0 / (s + s') for a point source). Where a cotangent is singular (a
shadow or reflection boundary, |eps| < EPS_BOUNDARY) its product with F takes the limit
n sqrt(2 pi k L) sgn(eps) exp(-i pi/4), sgn = 0 within EPS_ON_BOUNDARY: the diffracted field is then -/+
half the geometric wave it replaces, which is what makes geometric + diffracted continuous.

Line of sight: :func:`walls_blocking` tests straight segments source -> point against vertical walls
(building walls, barriers). A segment between two points outside a vertical prism that passes through
it crosses at least one of its walls (it cannot enter and leave through the flat roof alone), so walls
suffice for buildings too.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

_EPS = 1e-16
_FPMIN = 1e-300
_XMIN = 1.5  # series below, continued fraction above (Numerical Recipes)
_MAXIT = 200
# aux_fg's asymptotic series from here on: its smallest term (m ~ pi x^2 / 4) is below 1e-17 relative
# for x >= 6, the sum's accuracy is then ~1e-16 (tests/diffraction/test_fresnel_fast.py)
_X_ASYMPTOTIC = 6.0
EPS_BOUNDARY = 1e-10  # rad: a cotangent argument this close to its pole uses the analytic limit
# rad: this close to a boundary the point is ON it (sgn = 0: the geometric wave counts half); the same
# tolerance as the geometric field's (wedge.py), so the two halves always meet
EPS_ON_BOUNDARY = 1e-12


@nb.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def fresnel_cs(x: float) -> tuple[float, float]:
    """(C(x), S(x)), odd in x."""
    ax = abs(x)
    if ax < 1e-150:
        return x, 0.0
    if ax <= _XMIN:
        sm = 0.0
        sums = 0.0
        sumc = ax
        sign = 1.0
        fact = 0.5 * math.pi * ax * ax
        odd = True
        term = ax
        n = 3
        for k in range(1, _MAXIT):
            term *= fact / k
            sm += sign * term / n
            test = abs(sm) * _EPS
            if odd:
                sign = -sign
                sums = sm
                sm = sumc
            else:
                sumc = sm
                sm = sums
            if term < test:
                break
            odd = not odd
            n += 2
        c, s = sumc, sums
    elif ax >= _X_ASYMPTOTIC:
        f, g = _aux_fg_asymptotic(ax)
        big_x = 0.5 * math.pi * ax * ax
        cx, sx = math.cos(big_x), math.sin(big_x)
        c, s = 0.5 + f * sx - g * cx, 0.5 - f * cx - g * sx
    else:
        h = _cf(ax)
        pix2 = math.pi * ax * ax
        cs = complex(0.5, 0.5) * (1.0 - complex(math.cos(0.5 * pix2), math.sin(0.5 * pix2)) * h)
        c, s = cs.real, cs.imag
    if x < 0.0:
        return -c, -s
    return c, s


@nb.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def _cf(ax: float) -> complex:
    """(1 - i) x h of the erfc continued fraction (Numerical Recipes), x > 1.5."""
    pix2 = math.pi * ax * ax
    b = complex(1.0, -pix2)
    cc = complex(1.0 / _FPMIN, 0.0)
    d = 1.0 / b
    h = d
    n = -1
    for _ in range(2, _MAXIT):
        n += 2
        a = -float(n * (n + 1))
        b += 4.0
        d = 1.0 / (a * d + b)
        cc = b + a / cc
        dl = cc * d
        h *= dl
        if abs(dl.real - 1.0) + abs(dl.imag) < _EPS:
            break
    return complex(ax, -ax) * h


@nb.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def _aux_fg_asymptotic(x: float) -> tuple[float, float]:
    """(f(x), g(x)) from their asymptotic series (Abramowitz and Stegun 7.3.27-28), z = pi x^2:
    f ~ 1/(pi x) sum_m (-1)^m (4m-1)!! / z^2m,  g ~ 1/(pi^2 x^3) sum_m (-1)^m (4m+1)!! / z^2m,
    summed while the terms fall below 1e-17 of the first (x >= _X_ASYMPTOTIC: there the smallest term is
    below 1e-17, so the truncation error is too)."""
    z2 = (math.pi * x * x) ** 2
    tf = 1.0
    tg = 1.0
    sf = 1.0
    sg = 1.0
    for m in range(1, _MAXIT):
        tf *= -((4.0 * m - 3.0) * (4.0 * m - 1.0)) / z2
        tg *= -((4.0 * m - 1.0) * (4.0 * m + 1.0)) / z2
        sf += tf
        sg += tg
        if abs(tg) < 1e-17:
            break
    return sf / (math.pi * x), sg / (math.pi * math.pi * x * x * x)


@nb.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def aux_fg(x: float) -> tuple[float, float]:
    """Auxiliary Fresnel functions (f(x), g(x)) for x >= 0 (f(0) = g(0) = 1/2): the asymptotic series
    beyond _X_ASYMPTOTIC (few real terms, ~10x faster than the continued fraction, same to ~1e-16
    relative), the continued fraction beyond _XMIN, the series below."""
    if x >= _X_ASYMPTOTIC:
        return _aux_fg_asymptotic(x)
    if x > _XMIN:
        q = complex(0.5, 0.5) * _cf(x)  # g + i f
        return q.imag, q.real
    c, s = fresnel_cs(x)
    big_x = 0.5 * math.pi * x * x
    q = complex(math.cos(big_x), -math.sin(big_x)) * complex(0.5 - c, 0.5 - s)  # g + i f
    return q.imag, q.real


@nb.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def transition(big_x: float) -> complex:
    """UTD transition function F(X), X >= 0 (module docstring)."""
    if big_x <= 0.0:
        return 0j
    u = math.sqrt(2.0 * big_x / math.pi)
    f, g = aux_fg(u)
    return math.sqrt(2.0 * math.pi * big_x) * complex(f, -g)


@nb.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def _cot_f(n: float, beta: float, sgn: float, kl: float) -> complex:
    """cot((pi + sgn beta) / (2 n)) F(k L a^sgn(beta)), with the analytic limit at the pole."""
    big_n = math.floor((beta + sgn * math.pi) / (2.0 * n * math.pi) + 0.5)
    eps = math.pi + sgn * beta - sgn * 2.0 * n * math.pi * big_n  # zero on the boundary
    if abs(eps) < EPS_BOUNDARY:
        s = 0.0 if abs(eps) <= EPS_ON_BOUNDARY else math.copysign(1.0, eps)
        return n * math.sqrt(2.0 * math.pi * kl) * s * complex(math.sqrt(0.5), -math.sqrt(0.5))
    a = 2.0 * math.cos(0.5 * (2.0 * n * math.pi * big_n - beta)) ** 2
    return transition(kl * a) / math.tan((math.pi + sgn * beta) / (2.0 * n))


@nb.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def wedge_coefficient(n: float, phi: float, phip: float, k: float, dist_l: float, sin_b0: float) -> complex:
    """UTD coefficient D of a rigid wedge (exterior angle n pi), module docstring; units m^(1/2)."""
    kl = k * dist_l
    bm = phi - phip
    bp = phi + phip
    tot = _cot_f(n, bm, 1.0, kl) + _cot_f(n, bm, -1.0, kl) + _cot_f(n, bp, 1.0, kl) + _cot_f(n, bp, -1.0, kl)
    pre = -complex(math.sqrt(0.5), math.sqrt(0.5)) / (2.0 * n * math.sqrt(2.0 * math.pi * k) * sin_b0)
    return pre * tot


@nb.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def wedge_coefficients(
    n: np.ndarray,
    phi: np.ndarray,
    phip: np.ndarray,
    dist_l: np.ndarray,
    sin_b0: np.ndarray,
    k: np.ndarray,
    out: np.ndarray,
) -> None:
    """out[f, i] = D(n[i], phi[i], phip[i], k[f], dist_l[i], sin_b0[i]); arrays (N,), k (F,), out (F, N)."""
    for i in range(n.shape[0]):
        for f in range(k.shape[0]):
            out[f, i] = wedge_coefficient(n[i], phi[i], phip[i], k[f], dist_l[i], sin_b0[i])


@nb.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def fresnel_segment(u1: np.ndarray, u2: np.ndarray, out: np.ndarray) -> None:
    """out[i] = (C(u2) - C(u1) + i (S(u2) - S(u1))) / (1 + i): the share of a stationary-phase integral
    int exp(i pi u^2 / 2) du carried by [u1, u2] (1 for the whole line, 1/2 for a half line)."""
    for i in range(u1.shape[0]):
        c1, s1 = fresnel_cs(u1[i])
        c2, s2 = fresnel_cs(u2[i])
        out[i] = complex(c2 - c1, s2 - s1) / complex(1.0, 1.0)


@nb.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
def walls_blocking(src: np.ndarray, pts: np.ndarray, walls: np.ndarray, owner: np.ndarray, out: np.ndarray) -> None:
    """out[p, o] = 1 where the segment src (3,) -> pts[p] (P, 3) crosses a wall of owner o, else unchanged.

    walls (W, 6): x1, y1, x2, y2, z_bottom, z_top of vertical rectangles (m); owner (W,) int64 obstacle index
    into out's columns (P, O) uint8. Crossings within 1e-9 of a segment end (a point on a facade) do not
    count."""
    for p in range(pts.shape[0]):
        dx = pts[p, 0] - src[0]
        dy = pts[p, 1] - src[1]
        dz = pts[p, 2] - src[2]
        for w in range(walls.shape[0]):
            o = owner[w]
            if out[p, o]:
                continue
            ex = walls[w, 2] - walls[w, 0]
            ey = walls[w, 3] - walls[w, 1]
            den = dx * ey - dy * ex
            if den == 0.0:
                continue
            qx = walls[w, 0] - src[0]
            qy = walls[w, 1] - src[1]
            t = (qx * ey - qy * ex) / den  # along the segment
            u = (qx * dy - qy * dx) / den  # along the wall
            if t <= 1e-9 or t >= 1.0 - 1e-9 or u < 0.0 or u > 1.0:
                continue
            z = src[2] + t * dz
            if walls[w, 4] <= z <= walls[w, 5]:
                out[p, o] = 1

"""Analytic wind fields and the effective sound speed per ray azimuth (docs/physics.md §7).

Wind enters the traversal through the standard effective-sound-speed approximation

    c_eff(x) = c(x) + u(x) . e,      e = the ray's horizontal launch azimuth (unit, fixed for the whole path)

so a wind is a horizontal vector field u(x) (m/s, world frame). It is evaluated analytically in the kernel
(engine/kernels/traverse.py: the value at each cell's entry point, the exact gradient at the middle of the
ray's straight chord through the cell), never stored per cell: a job without wind has no wind array
anywhere (code ``WIND_NONE`` and an empty parameter array).

Kinds (``direction_deg`` is the direction the wind blows TOWARD, counter-clockwise from +x, so
``u = |u| (cos dir, sin dir, 0)``; a ray launched along +x with direction_deg = 0 travels downwind):

- ``log``: log law over flat ground, ``|u|(dz) = (u*/K) ln(dz/z_g)`` for dz > z_g, K = 0.41, with
  ``dz = z - ground_z`` the height above the ground plane. At and below dz = z_g the speed is 0: the log
  law itself reaches 0 at z_g, so |u| is continuous (its z-derivative jumps at z_g, a kink the mesh sizing
  resolves with thin layers).
- ``ridge``: the A-UW / A-DW field over the 2D ridge ``h(X) = H L^2 / (X^2 + L^2)``, X = x - crest_x, axis
  along y: ``|u| = (u*/K) ln(dz/z_g) + du(X, dz)`` with dz = z - ground_z - h(X) the height above the ridge
  surface and the linear potential-flow speed-up ``du = u_ref H L ((dz + L)^2 - X^2) / (X^2 + (dz + L)^2)^2``
  (du = u_ref H/L at the crest), u_ref = (u*/K) ln(z_ref/z_g) the log-law speed at the reference height
  z_ref. Below dz = z_g the speed falls linearly to 0 at the surface, ``|u| = du(X, z_g) dz / z_g``
  (continuous at z_g, where the log term is 0), and is 0 at and below the surface (dz <= 0). The speed-up is
  the solution for flow across the ridge (direction_deg 0 or 180); other directions use the same magnitude
  field along their own direction (an approximation, stated here rather than refused). The vertical
  component of the potential flow is ignored: it has no part in u . e for a horizontal e.

Parameter array layout (float64): [0] u*/K (m/s), [1] z_g (m), [2] cos dir, [3] sin dir, [4] ground_z (m);
ridge adds [5] H (m), [6] L (m), [7] crest_x (m), [8] u_ref (m/s), [9] z_ref (m).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numba as nb
import numpy as np

from bentray.engine.constants import CURVE_CIRCULAR, CURVE_PARABOLIC, NJIT_FLAGS
from bentray.engine.kernels.llvm_inline import njit_inline

__all__ = [
    "KARMAN",
    "WIND_NONE",
    "WIND_LOG",
    "WIND_RIDGE",
    "WIND_CODES",
    "MAX_U_STAR",
    "DEFAULT_Z_REF_M",
    "no_wind",
    "wind_spec",
    "check_wind",
    "wind_is_stratified",
    "wind_speed",
    "wind_along",
    "max_wind_speed",
    "effective_sound_speed",
    "sizing_quantity",
    "wind_at",
    "effective_quantity",
    "effective_value",
    "wind_value",
    "wind_values",
]

KARMAN = 0.41  # von Karman constant of the log law (docs/physics.md §7)
WIND_NONE = 0
WIND_LOG = 1
WIND_RIDGE = 2
WIND_CODES = {"log": WIND_LOG, "ridge": WIND_RIDGE}
_N_PARAMS = {WIND_NONE: 0, WIND_LOG: 5, WIND_RIDGE: 10}
# Largest friction velocity accepted: u* = 5 m/s is already a storm (u(10 m) ~ 55 m/s at z_g = 0.1 m);
# beyond it c_eff = c +- |u| leaves the regime where the effective-speed approximation means anything.
MAX_U_STAR = 5.0
DEFAULT_Z_REF_M = 10.0  # reference height of u_ref for the ridge speed-up (the usual 10 m anemometer height)


# ---------------------------------------------------------------------------------------------
# Builders (plain Python; validate, never mutate)
# ---------------------------------------------------------------------------------------------
def no_wind() -> tuple[int, np.ndarray]:
    """(WIND_NONE, empty float64 array): the kernel arguments of a job without wind."""
    return WIND_NONE, np.zeros(0)


def _number(params: Mapping[str, Any], key: str, default: float | None = None) -> float:
    if key not in params:
        if default is None:
            raise ValueError(f"wind: missing parameter {key!r}")
        return float(default)
    value = float(params[key])
    if not math.isfinite(value):
        raise ValueError(f"wind: {key} must be finite, got {value!r}")
    return value


def _cos_sin_deg(angle_deg: float) -> tuple[float, float]:
    """cos and sin of an angle in degrees, exact at multiples of 90 (a crosswind then has u . e = 0 exactly)."""
    r = angle_deg % 360.0
    exact = {0.0: (1.0, 0.0), 90.0: (0.0, 1.0), 180.0: (-1.0, 0.0), 270.0: (0.0, -1.0)}
    if r in exact:
        return exact[r]
    a = math.radians(r)
    return math.cos(a), math.sin(a)


def wind_spec(kind: str, params: Mapping[str, Any]) -> tuple[int, np.ndarray]:
    """Kernel form (code, params float64 array) of a wind field.

    kind : "log" or "ridge". params (SI units): u_star (m/s, 0 < u_star <= MAX_U_STAR), z_g (m, > 0),
    direction_deg (blowing toward, counter-clockwise from +x), ground_z_m (m, default 0); ridge adds
    height_m H (>= 0), half_width_m L (> 0), crest_x_m (default 0) and z_ref_m (> z_g, default 10 m).
    Unknown keys raise ValueError (a misspelt key must not silently fall back to a default).
    """
    if kind not in WIND_CODES:
        raise ValueError(f"wind: unknown kind {kind!r}; expected one of {sorted(WIND_CODES)}")
    allowed = {"u_star", "z_g", "direction_deg", "ground_z_m"}
    if kind == "ridge":
        allowed |= {"height_m", "half_width_m", "crest_x_m", "z_ref_m"}
    unknown = sorted(set(params) - allowed - {"kind"})
    if unknown:
        raise ValueError(f"wind ({kind}): unknown parameter(s) {', '.join(unknown)}")
    u_star = _number(params, "u_star")
    z_g = _number(params, "z_g")
    cos_dir, sin_dir = _cos_sin_deg(_number(params, "direction_deg"))
    ground_z = _number(params, "ground_z_m", 0.0)
    if not (0.0 < u_star <= MAX_U_STAR):
        raise ValueError(f"wind: u_star must be in (0, {MAX_U_STAR}] m/s, got {u_star}")
    if not (z_g > 0.0):
        raise ValueError(f"wind: z_g must be > 0 m, got {z_g}")
    head = [u_star / KARMAN, z_g, cos_dir, sin_dir, ground_z]
    if kind == "log":
        return WIND_LOG, np.array(head, dtype=np.float64)
    height = _number(params, "height_m")
    half_width = _number(params, "half_width_m")
    crest_x = _number(params, "crest_x_m", 0.0)
    z_ref = _number(params, "z_ref_m", DEFAULT_Z_REF_M)
    if not (height >= 0.0):
        raise ValueError(f"wind: height_m must be >= 0 m, got {height}")
    if not (half_width > 0.0):
        raise ValueError(f"wind: half_width_m must be > 0 m, got {half_width}")
    if not (z_ref > z_g):
        raise ValueError(f"wind: z_ref_m ({z_ref}) must be above z_g ({z_g})")
    u_ref = u_star / KARMAN * math.log(z_ref / z_g)
    return WIND_RIDGE, np.array(head + [height, half_width, crest_x, u_ref, z_ref], dtype=np.float64)


def check_wind(wind: tuple[int, np.ndarray] | None) -> tuple[int, np.ndarray]:
    """Validated kernel arguments (code, C-contiguous float64 params); None -> no_wind()."""
    if wind is None:
        return no_wind()
    code, params = wind
    code = int(code)
    if code not in _N_PARAMS:
        raise ValueError(f"wind: unknown code {code}")
    arr = np.ascontiguousarray(params, dtype=np.float64).reshape(-1)
    if arr.shape[0] != _N_PARAMS[code]:
        raise ValueError(f"wind code {code} needs {_N_PARAMS[code]} parameters, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError("wind parameters must be finite")
    return code, arr


def wind_is_stratified(code: int) -> bool:
    """True when |u| depends on z only (no wind, or the log law over flat ground): slabs can carry it."""
    return int(code) in (WIND_NONE, WIND_LOG)


# ---------------------------------------------------------------------------------------------
# numpy versions (sizing, reports, tests); independent of the njit code below
# ---------------------------------------------------------------------------------------------
def _speed_up_np(params: np.ndarray, xx: np.ndarray, dz: np.ndarray) -> np.ndarray:
    height, half_width, u_ref = params[5], params[6], params[8]
    p2 = (dz + half_width) ** 2
    x2 = xx * xx
    return u_ref * height * half_width * (p2 - x2) / (x2 + p2) ** 2


def wind_speed(code: int, params: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """|u| (m/s) at points ``xyz`` (N, 3) metres, world frame -> (N,) float64 (0 for WIND_NONE)."""
    pts = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
    code = int(code)
    if code == WIND_NONE:
        return np.zeros(len(pts))
    a, z_g, ground_z = params[0], params[1], params[4]
    if code == WIND_LOG:
        dz = pts[:, 2] - ground_z
        return np.where(dz > z_g, a * np.log(np.maximum(dz, z_g) / z_g), 0.0)
    height, half_width, crest_x = params[5], params[6], params[7]
    xx = pts[:, 0] - crest_x
    dz = pts[:, 2] - ground_z - height * half_width**2 / (xx * xx + half_width**2)
    above = a * np.log(np.maximum(dz, z_g) / z_g) + _speed_up_np(params, xx, np.maximum(dz, z_g))
    ramp = _speed_up_np(params, xx, np.full_like(dz, z_g)) * np.clip(dz, 0.0, None) / z_g
    return np.where(dz > z_g, above, ramp)


def wind_along(code: int, params: np.ndarray, xyz: np.ndarray, e: np.ndarray) -> np.ndarray:
    """u(x) . e (m/s) at points (N, 3); e (3,) or (N, 3) horizontal unit azimuths (z part ignored)."""
    ev = np.asarray(e, dtype=np.float64)
    speed = wind_speed(code, params, xyz)
    if int(code) == WIND_NONE:
        return speed
    return speed * (params[2] * ev[..., 0] + params[3] * ev[..., 1])


def max_wind_speed(code: int, params: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """The worst-azimuth wind term max_e u(x) . e = |u(x)| (m/s) at points (N, 3): the downwind ray's."""
    return np.abs(wind_speed(code, params, xyz))


def effective_sound_speed(c: np.ndarray, code: int, params: np.ndarray, xyz: np.ndarray, e: np.ndarray) -> np.ndarray:
    """c_eff = c + u . e (m/s) for sound speeds ``c`` (N,) at points ``xyz`` (N, 3) and azimuths e."""
    return np.asarray(c, dtype=np.float64) + wind_along(code, params, xyz, e)


def sizing_quantity(
    sound_speed: Callable[[np.ndarray], np.ndarray], c_ref: float, wind: tuple[int, np.ndarray] | None, quantity: str
) -> Callable[[np.ndarray], np.ndarray]:
    """Traced quantity of the downwind effective medium c + |u(x)| at points (N, 3), for mesh sizing.

    The downwind ray sees the whole wind speed, so its medium carries the largest wind gradient and
    curvature (docs/physics.md §6: size on the worst case over azimuth). quantity : "c", "n" (c_ref/c)
    or "n2". Without wind the callable returns the profile's own quantity.
    """
    code, params = check_wind(wind)
    if quantity not in ("c", "n", "n2"):
        raise ValueError(f"unknown traced quantity {quantity!r}")

    def m_of(xyz: np.ndarray) -> np.ndarray:
        pts = np.atleast_2d(np.asarray(xyz, dtype=np.float64))
        c = np.asarray(sound_speed(pts), dtype=np.float64) + max_wind_speed(code, params, pts)
        if quantity == "c":
            return c
        n = c_ref / c
        return n if quantity == "n" else n * n

    return m_of


# ---------------------------------------------------------------------------------------------
# njit: value and exact gradient at one point (kernel side)
# ---------------------------------------------------------------------------------------------
@njit_inline
def _speed_up(params, xx, dz):
    """(du, d du/dX, d du/d dz) of the ridge speed-up at X = xx, height dz above the surface."""
    k = params[8] * params[5] * params[6]
    p = dz + params[6]
    p2 = p * p
    x2 = xx * xx
    s = x2 + p2
    s3 = s * s * s
    du = k * (p2 - x2) / (s * s)
    d_x = -2.0 * k * xx * (3.0 * p2 - x2) / s3
    d_p = 2.0 * k * p * (3.0 * x2 - p2) / s3
    return du, d_x, d_p


@njit_inline
def _ridge_surface(params, x0):
    """The ridge's surface at world x0: (X = x0 - crest x, h(X) = H L^2 / (X^2 + L^2), h'(X), h''(X)) in metres
    above the ridge's base (H height_m, L half_width_m)."""
    height = params[5]
    half_width = params[6]
    xx = x0 - params[7]
    l2 = half_width * half_width
    den = xx * xx + l2
    h = height * l2 / den
    h1 = -2.0 * height * l2 * xx / (den * den)
    h2 = 2.0 * height * l2 * (3.0 * xx * xx - l2) / (den * den * den)
    return xx, h, h1, h2


@njit_inline
def speed_at(code, params, x):
    """(|u|, d|u|/dx, d|u|/dz) at point x (m; 3-tuple or (3,) array) for a wind code other than WIND_NONE; |u| does
    not depend on y. :func:`along_from_speed` turns one evaluation into the value along any azimuth (the traversal
    evaluates it once per point, for the ray's azimuth and its turn)."""
    a = params[0]
    z_g = params[1]
    if code == WIND_LOG:
        dz = x[2] - params[4]
        if dz > z_g:
            return a * math.log(dz / z_g), 0.0, a / dz
        return 0.0, 0.0, 0.0
    xx, h, dh_dx, _ = _ridge_surface(params, x[0])
    dz = x[2] - params[4] - h
    if dz > z_g:
        du, d_x, d_p = _speed_up(params, xx, dz)
        u = a * math.log(dz / z_g) + du
        d_dz = a / dz + d_p
    elif dz > 0.0:
        du, d_x, d_p = _speed_up(params, xx, z_g)
        r = dz / z_g
        u = du * r
        d_x = d_x * r
        d_dz = du / z_g
    else:
        return 0.0, 0.0, 0.0
    # dz depends on x through the surface: d|u|/dx = d/dX|dz - h'(X) d/d dz
    return u, d_x - dh_dx * d_dz, d_dz


@nb.njit(**NJIT_FLAGS)
def _speed_up_second(params, xx, dz):
    """Second derivatives (d2/dX2, d2/dX dp, d2/dp2) of the ridge speed-up du = k (p^2 - X^2) / (X^2 + p^2)^2,
    p = dz + half_width: du = k Re(zeta^-2) with zeta = p + i X (harmonic), so d2/dp2 = k Re(6 zeta^-4) =
    -d2/dX2 and d2/dX dp = -k Im(6 zeta^-4)."""
    k = params[8] * params[5] * params[6]
    zeta = complex(dz + params[6], xx)
    z2 = zeta * zeta
    f2 = 6.0 / (z2 * z2)
    return -k * f2.real, -k * f2.imag, k * f2.real


@nb.njit(**NJIT_FLAGS)
def speed_hessian(code, params, x):
    """|u| and its exact first and second derivatives at point x (3,): the tuple (|u|, d/dx, d/dz, d2/dx2,
    d2/dx dz, d2/dz2) (|u| does not depend on y; a tuple, not an array, so that the paraxial kernels' hot
    loop makes no array views). The branches are speed_at's: the log law above z_g, the ridge's speed-up
    growing linearly in height below z_g, calm at and below the surface. Over the ridge the height above the
    surface is dz = z - z0 - h(X): d/dx = d/dX - h' d/d dz, and d2/dx2 = U_XX - 2 h' U_Xdz + h'^2 U_dzdz -
    h'' U_dz."""
    a = params[0]
    z_g = params[1]
    if code == WIND_LOG:
        dz = x[2] - params[4]
        if dz > z_g:
            return a * math.log(dz / z_g), 0.0, a / dz, 0.0, 0.0, -a / (dz * dz)
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if code != WIND_RIDGE:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    xx, h, h1, h2 = _ridge_surface(params, x[0])
    dz = x[2] - params[4] - h
    if dz > z_g:
        du, u_x, u_p = _speed_up(params, xx, dz)
        u_xx, u_xp, u_pp = _speed_up_second(params, xx, dz)
        u = a * math.log(dz / z_g) + du
        u_z = a / dz + u_p
        u_xz = u_xp
        u_zz = -a / (dz * dz) + u_pp
    elif dz > 0.0:
        du, u_x0, u_p = _speed_up(params, xx, z_g)
        u_xx, u_xp, u_pp = _speed_up_second(params, xx, z_g)
        r = dz / z_g  # the speed-up at z_g, scaled linearly down to the surface
        u = du * r
        u_x = u_x0 * r
        u_xx = u_xx * r
        u_z = du / z_g
        u_xz = u_x0 / z_g
        u_zz = 0.0
    else:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return (
        u,
        u_x - h1 * u_z,
        u_z,
        u_xx - 2.0 * h1 * u_xz + h1 * h1 * u_zz - h2 * u_z,
        u_xz - h1 * u_zz,
        u_zz,
    )


WIND_PARAM_SIZE = 10  # the longest parameter array (ridge); wind_values pads shorter ones with zeros


@nb.njit(**NJIT_FLAGS)
def wind_values(params):
    """The wind's parameter array as a WIND_PARAM_SIZE-tuple of floats (zeros beyond its length): the traversal
    binds it once per ray and passes values, not the array every thread shares, to the per-crossing calls
    (each call on an array takes an atomic reference on it)."""
    p = np.zeros(WIND_PARAM_SIZE)
    for i in range(min(params.shape[0], WIND_PARAM_SIZE)):
        p[i] = params[i]
    return (p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8], p[9])


@njit_inline
def along_from_speed(params, speed, e):
    """(w, dw/dx, dw/dy, dw/dz) of :func:`wind_value` from the speed at the point, speed = :func:`speed_at`'s
    (|u|, d|u|/dx, d|u|/dz), for the horizontal unit azimuth e: the same arithmetic, bit for bit."""
    cos_a = params[2] * e[0] + params[3] * e[1]  # cos of the angle between the wind and e
    return cos_a * speed[0], cos_a * speed[1], 0.0, cos_a * speed[2]


@njit_inline
def wind_value(code, params, x, e):
    """(w, dw/dx, dw/dy, dw/dz): w = u(x) . e (m/s) at point x (m) for the horizontal unit azimuth e, and its
    exact gradient (1/s). x, e : 3-tuples or (3,) arrays; params : the wind's parameters (array, or the tuple of
    :func:`wind_values`). code WIND_NONE gives zeros."""
    if code == WIND_NONE:
        return 0.0, 0.0, 0.0, 0.0
    return along_from_speed(params, speed_at(code, params, x), e)


@nb.njit(**NJIT_FLAGS)
def wind_at(code, params, x, e, out_grad):
    """w = u(x) . e (m/s) at point x (3,) metres for the horizontal unit azimuth e (3,).

    Writes grad w (3,) (1/s, exact) into out_grad. code WIND_NONE gives 0 and a zero gradient.
    """
    w, g0, g1, g2 = wind_value(code, params, x, e)
    out_grad[0] = g0
    out_grad[1] = g1
    out_grad[2] = g2
    return w


@njit_inline
def effective_value(curve, c_ref, m, g, code, params, x, e):
    """:func:`effective_quantity` from values: (m_eff, state, g_eff x, y, z, w, grad w x, y, z).

    g, x, e : 3-tuples or (3,) arrays; params : array or :func:`wind_values` tuple. state 1: m_eff and g_eff
    computed (the medium's own m and g where the wind and its gradient are exactly 0); 0: m not positive,
    returned as is, nothing else computed (the other entries 0); -1: c_eff not positive, m_eff = -1.0, the wind
    and its gradient computed but no g_eff. The same arithmetic as effective_quantity, bit for bit."""
    if not (m > 0.0):
        return m, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return _effective(curve, c_ref, m, g, wind_value(code, params, x, e))


@njit_inline
def effective_value_at(curve, c_ref, m, g, params, speed, e):
    """:func:`effective_value` with the wind's speed at the point already evaluated (speed = :func:`speed_at`'s,
    code not WIND_NONE): the same tuple, bit for bit."""
    if not (m > 0.0):
        return m, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return _effective(curve, c_ref, m, g, along_from_speed(params, speed, e))


@njit_inline
def _effective(curve, c_ref, m, g, wv):
    """effective_value's arithmetic for m > 0 and the wind's (w, grad w) = wv at the point."""
    if curve == CURVE_PARABOLIC:
        c = c_ref / math.sqrt(m)
        dc = -0.5 * c / m  # dc/dm
    elif curve == CURVE_CIRCULAR:
        c = m
        dc = 1.0
    else:
        c = c_ref / m
        dc = -c / m
    w, wg0, wg1, wg2 = wv
    if w == 0.0 and wg0 == 0.0 and wg1 == 0.0 and wg2 == 0.0:
        # no wind here (crosswind ray, below z_g): the medium itself, bit for bit (no round trip through c)
        return m, 1, g[0], g[1], g[2], w, wg0, wg1, wg2
    c_eff = c + w
    if not (c_eff > 0.0):
        return -1.0, -1, 0.0, 0.0, 0.0, w, wg0, wg1, wg2
    if curve == CURVE_PARABOLIC:
        m_eff = (c_ref / c_eff) * (c_ref / c_eff)
        dm = -2.0 * m_eff / c_eff  # dm/dc at c_eff
    elif curve == CURVE_CIRCULAR:
        m_eff = c_eff
        dm = 1.0
    else:
        m_eff = c_ref / c_eff
        dm = -m_eff / c_eff
    return m_eff, 1, dm * (dc * g[0] + wg0), dm * (dc * g[1] + wg1), dm * (dc * g[2] + wg2), w, wg0, wg1, wg2


@nb.njit(**NJIT_FLAGS)
def effective_quantity(curve, c_ref, m, g, code, params, x, e, w_grad, g_out):
    """Traced quantity of the effective medium c + u . e at x, and its gradient into g_out (3,).

    m, g : the cell's traced quantity at x and its gradient (n^2 for the parabolic curve, c for the
    circular one, n = c_ref/c for n-linear). Converts to c and grad c, adds w = u(x).e and grad w, and
    converts back. Where m is not positive it is returned as is, and where c_eff is not positive -1.0 is
    returned: both unphysical, the curve setup refuses them (the ray ends as lost); g_out is then left as it
    was. Where the wind term and its gradient are exactly 0, m and g are returned unchanged (bit for bit).
    w_grad : (3,) receives grad w (untouched where m is not positive). The arithmetic is :func:`effective_value`'s.
    """
    m_eff, state, g0, g1, g2, _, wg0, wg1, wg2 = effective_value(curve, c_ref, m, g, code, params, x, e)
    if state == 0:
        return m_eff
    w_grad[0] = wg0
    w_grad[1] = wg1
    w_grad[2] = wg2
    if state == 1:
        g_out[0] = g0
        g_out[1] = g1
        g_out[2] = g2
    return m_eff

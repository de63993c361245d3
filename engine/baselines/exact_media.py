"""The analytic media profiles evaluated directly in Numba, for the numerical ray integrators.

The analytic tracer samples a profile into a mesh; the numerical baselines can instead evaluate the
closed-form profile at every integration stage (``media='exact'``), so their error is the integrator's
alone. A profile is flattened once, in Python, into an integer code and a float64 parameter vector;
the kernel :func:`n_and_grad` evaluates the refractive index ``n = c_ref / c`` (dimensionless) and its
world-frame gradient (1/m) at one point (metres). The formulas, clamps and subgradients are those of
``engine/profiles.py`` (checked there against the Profile methods at rtol 1e-12).

Parameter layout (``params[0]`` is always ``c_ref`` in m/s):

================  ======================================================================
homogeneous       c_ref, c0
linear_c          c_ref, c0, alpha              c = c0 + alpha z
linear_n          c_ref, n0, alpha              n = n0 + alpha z
linear_n2         c_ref, n0, alpha              n^2 = n0^2 + alpha z
log               c_ref, c0, b, z_g, smooth     c = c0 + b ln(max(z, 0)/z_g + 1)
mirage_inferior   c_ref, mu0, mu1, beta         n^2 = mu0^2 + mu1^2 (1 - exp(-beta z))
mirage_superior   c_ref, mu0, mu1, beta         n^2 = mu0^2 + mu1^2 exp(-beta z)
hot_spot          c_ref, xs, ys, zs, t_s, d0, dT, smooth   T = T_std(z) + dT exp(-d/d0), dT = t_s - T_std(zs)
================  ======================================================================

Below the ground (z < 0). The log and hot-spot profiles clamp z at 0 (Profile semantics: constant
below ground), which puts a jump in grad n at z = 0. No ray goes below the ground, but the
intermediate stages of a Runge-Kutta step that lands on it do, and a gradient jump there costs the
method its order at every reflection (measured on A-LD, RK4: a 6e-5 relative position error floor that
did not fall with the step, instead of 4th order). With ``smooth_below_ground=True`` (the default; the
``smooth`` flag above) the kernel continues these two profiles smoothly below z = 0: the log profile by
its own formula down to z = -z_g/2 and linearly (C1) below that, the standard atmosphere by its
troposphere line. Above the ground nothing changes; with ``smooth_below_ground=False`` the kernel
reproduces the Profile methods everywhere.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from bentray.engine.constants import NJIT_FLAGS
from bentray.engine.kernels.llvm_inline import njit_inline
from bentray.engine.profiles import (
    GAMMA_AIR,
    LAPSE_RATE_K_PER_M,
    R_AIR,
    T_SEA_LEVEL_K,
    TROPOPAUSE_M,
    Homogeneous,
    HotSpot,
    LinearC,
    LinearN,
    LinearN2,
    Log,
    MirageInferior,
    MirageSuperior,
    Profile,
    standard_temperature,
)

__all__ = [
    "EXACT_HOMOGENEOUS",
    "EXACT_LINEAR_C",
    "EXACT_LINEAR_N",
    "EXACT_LINEAR_N2",
    "EXACT_LOG",
    "EXACT_MIRAGE_INFERIOR",
    "EXACT_MIRAGE_SUPERIOR",
    "EXACT_HOT_SPOT",
    "exact_media_spec",
    "n_and_grad",
]

LN2 = math.log(2.0)

EXACT_HOMOGENEOUS = 0
EXACT_LINEAR_C = 1
EXACT_LINEAR_N = 2
EXACT_LINEAR_N2 = 3
EXACT_LOG = 4
EXACT_MIRAGE_INFERIOR = 5
EXACT_MIRAGE_SUPERIOR = 6
EXACT_HOT_SPOT = 7

# Exact classes only: a user subclass may override the formulas, so it is not assumed to share them.
_CODES: dict[type, int] = {
    Homogeneous: EXACT_HOMOGENEOUS,
    LinearC: EXACT_LINEAR_C,
    LinearN: EXACT_LINEAR_N,
    LinearN2: EXACT_LINEAR_N2,
    Log: EXACT_LOG,
    MirageInferior: EXACT_MIRAGE_INFERIOR,
    MirageSuperior: EXACT_MIRAGE_SUPERIOR,
    HotSpot: EXACT_HOT_SPOT,
}


def exact_media_spec(profile: Profile, smooth_below_ground: bool = True) -> tuple[int, np.ndarray]:
    """(code, params) of an analytic profile for :func:`n_and_grad`.

    params : (k,) float64, C-contiguous; layout in the module docstring. ``smooth_below_ground``: continue
    the log and hot-spot profiles smoothly below z = 0 instead of clamping (module docstring). Raises
    ValueError for the profiles without a closed form here (table, grid, fluctuating) or any other class.
    """
    code = _CODES.get(type(profile))
    if code is None:
        raise ValueError(
            f"profile kind {getattr(profile, 'kind', type(profile).__name__)!r} has no closed form for the "
            "numerical baselines (exact media: homogeneous, linear_c, linear_n, linear_n2, log, "
            "mirage_inferior, mirage_superior, hot_spot); use solver.media = 'mesh'"
        )
    cr = profile.c_ref
    if code == EXACT_HOMOGENEOUS:
        vals = [cr, profile.c0]
    elif code == EXACT_LINEAR_C:
        vals = [cr, profile.c0, profile.alpha]
    elif code in (EXACT_LINEAR_N, EXACT_LINEAR_N2):
        vals = [cr, profile.n0, profile.alpha]
    elif code == EXACT_LOG:
        vals = [cr, profile.c0, profile.b, profile.z_g, float(smooth_below_ground)]
    elif code in (EXACT_MIRAGE_INFERIOR, EXACT_MIRAGE_SUPERIOR):
        vals = [cr, profile.mu0, profile.mu1, profile.beta]
    else:
        ctr = profile.center
        d_t = profile.t_s - float(standard_temperature(ctr[2]))
        vals = [cr, ctr[0], ctr[1], ctr[2], profile.t_s, profile.d0, d_t, float(smooth_below_ground)]
    return code, np.ascontiguousarray(vals, dtype=np.float64)


@njit_inline
def _from_c(c_ref, c, gcx, gcy, gcz, out, k):
    """n = c_ref / c and grad n = -c_ref / c^2 grad c into out[k:k+3]."""
    f = -c_ref / (c * c)
    out[k] = f * gcx
    out[k + 1] = f * gcy
    out[k + 2] = f * gcz
    return c_ref / c


@njit_inline
def _from_n2(m, gmz, out, k):
    """n = sqrt(n^2) and grad n = grad(n^2) / (2 n) into out[k:k+3], gradient along z only."""
    n = math.sqrt(m)
    out[k] = 0.0
    out[k + 1] = 0.0
    out[k + 2] = gmz / (2.0 * n)
    return n


@nb.njit(**NJIT_FLAGS)
def n_and_grad(code, params, x, out_grad):
    """Refractive index n (dimensionless) at ``x`` (3,) metres; writes grad n (1/m) into ``out_grad`` (3,).

    ``code, params`` from :func:`exact_media_spec`. Unphysical media (c <= 0, n^2 < 0) give n <= 0 or
    NaN, which the caller turns into the ``lost`` status. An unknown code returns NaN.
    """
    return n_and_grad_at(code, params, x, out_grad, 0)


@njit_inline
def n_and_grad_at(code, params, x, out, k):
    """:func:`n_and_grad` writing grad n into ``out[k:k+3]`` (no array view: the integrators' hot path)."""
    cr = params[0]
    z = x[2]
    if code == EXACT_HOMOGENEOUS:
        out[k] = 0.0
        out[k + 1] = 0.0
        out[k + 2] = 0.0
        return cr / params[1]
    if code == EXACT_LINEAR_C:
        return _from_c(cr, params[1] + params[2] * z, 0.0, 0.0, params[2], out, k)
    if code == EXACT_LINEAR_N:
        out[k] = 0.0
        out[k + 1] = 0.0
        out[k + 2] = params[2]
        return params[1] + params[2] * z
    if code == EXACT_LINEAR_N2:
        return _from_n2(params[1] * params[1] + params[2] * z, params[2], out, k)
    if code == EXACT_LOG:
        c0 = params[1]
        b = params[2]
        z_g = params[3]
        if z >= 0.0 or (params[4] != 0.0 and z > -0.5 * z_g):
            return _from_c(cr, c0 + b * math.log1p(z / z_g), 0.0, 0.0, b / (z + z_g), out, k)
        if params[4] != 0.0:  # C1 linear continuation below z = -z_g / 2
            return _from_c(cr, c0 - b * LN2 + (2.0 * b / z_g) * (z + 0.5 * z_g), 0.0, 0.0, 2.0 * b / z_g, out, k)
        return _from_c(cr, c0, 0.0, 0.0, 0.0, out, k)
    if code == EXACT_MIRAGE_INFERIOR or code == EXACT_MIRAGE_SUPERIOR:
        mu0 = params[1]
        mu1 = params[2]
        beta = params[3]
        e = math.exp(-beta * z)
        if code == EXACT_MIRAGE_INFERIOR:
            return _from_n2(mu0 * mu0 + mu1 * mu1 * -math.expm1(-beta * z), mu1 * mu1 * beta * e, out, k)
        return _from_n2(mu0 * mu0 + mu1 * mu1 * e, -mu1 * mu1 * beta * e, out, k)
    if code == EXACT_HOT_SPOT:
        rx = x[0] - params[1]
        ry = x[1] - params[2]
        rz = z - params[3]
        d0 = params[5]
        d_t = params[6]
        d = math.sqrt(rx * rx + ry * ry + rz * rz)
        e = math.exp(-d / d0)
        coef = -d_t * e / (d0 * d) if d > 0.0 else 0.0  # the cone tip gets the zero subgradient
        smooth = params[7] != 0.0
        zc = min(z if smooth else max(z, 0.0), TROPOPAUSE_M)
        t = T_SEA_LEVEL_K + LAPSE_RATE_K_PER_M * zc + d_t * e
        lapse = LAPSE_RATE_K_PER_M if ((smooth or z >= 0.0) and z <= TROPOPAUSE_M) else 0.0
        c = math.sqrt(GAMMA_AIR * R_AIR * t)
        q = GAMMA_AIR * R_AIR / (2.0 * c)  # grad c = q grad T
        return _from_c(cr, c, q * coef * rx, q * coef * ry, q * (coef * rz + lapse), out, k)
    out[k] = math.nan
    out[k + 1] = math.nan
    out[k + 2] = math.nan
    return math.nan

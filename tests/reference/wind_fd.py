"""Oracle for the wind's paraxial terms: the effective medium's derivatives by central differences.

This is the engine's former kernels/paraxial.wind_terms (until 2026-12), kept beside the tests that use it:
d m0/dgamma_k and d g/dgamma_k of the effective medium c + u.e (wind.effective_quantity) by central
differences along the same directions as the closed form (paraxial.wind_terms), with the relative step
WIND_FD_REL of the cell size. Its own error is the O(h^2) truncation and the rounding of the difference, about
1e-7 relative (at 1e-5 the rounding put 1e-6 relative noise on P_k along T in 2 mm slabs).
"""

from __future__ import annotations

import math

import numba as nb

from bentray.engine.constants import NJIT_FLAGS
from bentray.engine.kernels.paraxial import chord_face
from bentray.engine.wind import effective_quantity

WIND_FD_REL = 1e-4
FD_FLAGS = {**NJIT_FLAGS, "cache": False}  # test-only: compiled per session, not into the engine's cache


@nb.njit(**FD_FLAGS)
def _eff_diff(curve, c_ref, code, params, m_base, g_cell, y, dy, e, de, h, work):
    """Central difference along (dy, de) of the effective medium (wind.effective_quantity): returns
    d m and writes d g into work[0:3]. work : (15,) scratch."""
    gdy = g_cell[0] * dy[0] + g_cell[1] * dy[1] + g_cell[2] * dy[2]
    yp = work[3:6]
    ep = work[6:9]
    gm = work[9:12]
    wg = work[12:15]
    for i in range(3):
        yp[i] = y[i] + h * dy[i]
        ep[i] = e[i] + h * de[i]
    mp = effective_quantity(curve, c_ref, m_base + h * gdy, g_cell, code, params, yp, ep, wg, work[0:3])
    for i in range(3):
        yp[i] = y[i] - h * dy[i]
        ep[i] = e[i] - h * de[i]
    mm = effective_quantity(curve, c_ref, m_base - h * gdy, g_cell, code, params, yp, ep, wg, gm)
    for i in range(3):
        work[i] = (work[i] - gm[i]) / (2.0 * h)
    return (mp - mm) / (2.0 * h)


@nb.njit(**FD_FLAGS)
def wind_terms(curve, c_ref, wind, cell_model, x, d, par, seg, work):
    """The segment record with wind (after tangent_derivs): d m0/dgamma_k and d g/dgamma_k of the effective
    medium the traversal sets the segment up with (its value at x, its gradient at the chord middle).

    wind : (code, params, e) the ray's wind and unit horizontal launch azimuth e (de/d az = (-e_y, e_x, 0),
    de/d el = 0); cell_model : (m_cell_x, g_cell, planes, neighbours, cell_size, mid_ok, x_mid) the cell's own
    traced quantity at x and gradient, its face planes, and the chord middle (mid_ok False: the gradient was
    taken at x). The chord middle x + (L/2) d moves with X_k, D_k and the chord length L to the first face f
    ahead: dL = -(m_f.X_k + L m_f.D_k)/(m_f.d). The wind model's own derivatives are central differences
    along these directions (step WIND_FD_REL of the cell size; at 1e-5 their rounding put 1e-6 relative
    noise on P_k along T in 2 mm slabs: docs/physics.md §10).
    work : (21,) scratch.
    """
    code, params, e = wind
    m_x, g_cell, planes, neighbours, cell_size, mid_ok, x_mid = cell_model
    best, bf = chord_face(planes, neighbours, x, d) if mid_ok else (math.inf, -1)
    m_mid = m_x + g_cell[0] * (x_mid[0] - x[0]) + g_cell[1] * (x_mid[1] - x[1]) + g_cell[2] * (x_mid[2] - x[2])
    de = work[15:18]
    dxm = work[18:21]
    for k in range(2):
        o = 3 * k
        xk = par[o : o + 3]
        if k == 0:
            de[0] = 0.0
            de[1] = 0.0
        else:
            de[0] = -e[1]
            de[1] = e[0]
        de[2] = 0.0
        xn = math.sqrt(xk[0] * xk[0] + xk[1] * xk[1] + xk[2] * xk[2])
        h = WIND_FD_REL * cell_size / max(xn, cell_size) if cell_size > 0.0 else WIND_FD_REL
        dm0 = _eff_diff(curve, c_ref, code, params, m_x, g_cell, x, xk, e, de, h, work)
        seg[6 + k] = dm0
        if mid_ok and bf >= 0:
            md = planes[bf, 0] * d[0] + planes[bf, 1] * d[1] + planes[bf, 2] * d[2]
            if best > 0.0:
                mxk = planes[bf, 0] * xk[0] + planes[bf, 1] * xk[1] + planes[bf, 2] * xk[2]
                mdk = planes[bf, 0] * seg[o] + planes[bf, 1] * seg[o + 1] + planes[bf, 2] * seg[o + 2]
                dlen = -(mxk + best * mdk) / md
                half = 0.5 * best
            else:
                dlen = 0.0
                half = 0.0
            for i in range(3):
                dxm[i] = xk[i] + 0.5 * dlen * d[i] + half * seg[o + i]
            xn = math.sqrt(dxm[0] * dxm[0] + dxm[1] * dxm[1] + dxm[2] * dxm[2])
            h = WIND_FD_REL * cell_size / max(xn, cell_size) if cell_size > 0.0 else WIND_FD_REL
            _eff_diff(curve, c_ref, code, params, m_mid, g_cell, x_mid, dxm, e, de, h, work)
        for i in range(3):
            seg[8 + o + i] = work[i]
    seg[16] = 1.0

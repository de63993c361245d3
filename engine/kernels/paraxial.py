"""Paraxial rays for the parabolic curve: exact launch-angle derivatives of what the tracer computes.

State ``par`` (12,) float64: ``X_1 = par[0:3]``, ``X_2 = par[3:6]`` (dx/dgamma_k, metres per radian) and
``P_1 = par[6:9]``, ``P_2 = par[9:12]`` (dp/dgamma_k, p = n T, per radian), gamma = (elevation,
azimuth). Inside one cell the parabolic map ``x(sigma) = x0 + p0 sigma + g sigma^2 / 4``,
``p(sigma) = p0 + g sigma / 2`` is affine in (x0, p0), so (docs/physics.md §10):

- launch from a point source: ``X_k = 0``, ``P_k = n0 dd0/dgamma_k``;
- inside a cell at fixed sigma: ``X_k(sigma) = X_k + P_k sigma``, ``P_k`` constant;
- leaving through a face (plane m.x = h) at sigma_f, the neighbouring ray meets the face
  ``d sigma_k = -(m.X_k)/(m.p)`` later; the derivatives *on the face* are
  ``X_k += p d sigma_k``, ``P_k += (g/2) d sigma_k`` (:func:`onto_face`);
- every segment starts by re-evaluating n at the entry point with the (new) cell's model and keeping
  the direction: ``p' = n'(x) p / |p|``; its derivative is
  ``P_k' = (g'.X_k)/(2 n') d + (n'/|p|) (P_k - d (d.P_k))`` (:func:`restart`); where n^2 is continuous
  this is the identity, and it is exact for the piecewise-linear media the mesh carries;
- specular reflection with R = I - 2 m m^T: ``X_k -> R X_k`` (X_k lies in the plane after
  :func:`onto_face`), ``P_k -> R P_k``.

*Smooth medium* (beams without wind, and ``trace(paraxial="smooth")``; docs/physics.md §11): the
derivatives of the C1 medium whose Hessian H is constant per cell (engine/mesh/hessian.py) instead of the
mesh's own: ``dX/dsigma = P``, ``dP/dsigma = H X / 2`` along the cell's curve (:func:`smooth_advance`), no
projection onto inner faces and no restart (the medium has no faces), and at a boundary (reflection, exit)
:func:`onto_face` with the smooth gradient at the face point (:func:`smooth_gradient`).

With wind the per-cell gradient is taken at the middle of the chord through the cell, which depends on
the entry state; that dependence is not differentiated (first order in the cell size), nor are the
rare slide and nudge moves (counted in the ray's nudges).

Circular and n-linear curves (docs/physics.md §10, "Other curves"): their segments are set up from the
entry point and the *unit* tangent, so between segments ``par`` keeps the same (X, P) form and each
segment works on ``D_k = dT/dgamma_k`` instead: :func:`tangent_derivs` (P -> D at the segment start, with
the |p| the previous segment ended with), :func:`along_curve` (X_k, D_k at a fixed curve parameter: the
derivative of the closed-form curve with respect to its start state, through the cell's setup constants;
and the curve's rates d x/d param, d T/d param), :func:`onto_face_rates` (the face projection with those
rates) and :func:`to_p` (D -> P at the end, P_k = (grad n . X_k) T + n D_k with the cell's own model).
The restart in a new cell needs no extra term there: the new cell's model enters through the setup.
"""

from __future__ import annotations

import math

import numba as nb

from bentray.engine.constants import CURVE_CIRCULAR, CURVE_PARABOLIC, FACE_UNUSED, NJIT_FLAGS
from bentray.engine.kernels.llvm_inline import njit_inline
from bentray.engine.kernels.nlinear import arc_length as _nl_arc
from bentray.engine.kernels.nlinear import height as _nl_height
from bentray.engine.wind import effective_value, speed_hessian, wind_value

PAR_SIZE = 12
# per-segment record ``seg`` (SEG_SIZE,): D_k at the start [0:6], d m0/dgamma_k [6:8] (m0 the traced quantity
# the segment starts from), d g/dgamma_k [8:14] (g its gradient), d m0 - g.X_k [14:16], wind terms on [16]
SEG_SIZE = 17


@njit_inline
def launch(par, d, n0):
    """Point-source launch: X = 0, P_k = n0 dd/dgamma_k for d = (cos el cos az, cos el sin az, sin el).

    d : (3,) unit launch direction (elevation and azimuth are recovered from it).
    """
    ch = math.sqrt(d[0] * d[0] + d[1] * d[1])  # cos el
    if ch > 0.0:
        ca = d[0] / ch
        sa = d[1] / ch
    else:
        ca = 1.0
        sa = 0.0
    se = d[2]
    for i in range(6):
        par[i] = 0.0
    # d/d el = (-sin el cos az, -sin el sin az, cos el);  d/d az = (-cos el sin az, cos el cos az, 0)
    par[6] = -n0 * se * ca
    par[7] = -n0 * se * sa
    par[8] = n0 * ch
    par[9] = -n0 * ch * sa
    par[10] = n0 * ch * ca
    par[11] = 0.0


@njit_inline
def advance(par, sigma):
    """X_k += P_k sigma (in place): the derivatives at parameter sigma of the current cell's curve."""
    for i in range(3):
        par[i] += par[6 + i] * sigma
        par[3 + i] += par[9 + i] * sigma


@njit_inline
def advanced_copy(par, sigma, out):
    """out = the derivatives at parameter sigma (par unchanged)."""
    for i in range(3):
        out[i] = par[i] + par[6 + i] * sigma
        out[3 + i] = par[3 + i] + par[9 + i] * sigma
        out[6 + i] = par[6 + i]
        out[9 + i] = par[9 + i]


@njit_inline
def onto_face(par, plane, p, g, max_dsig):
    """Derivatives on the face plane (m, h) reached with slowness vector p: see the module docstring.

    max_dsig : bound on |d sigma_k| (inf: exact). A ray that crosses a face between two cells nearly
    tangentially has |m.p| -> 0 and d sigma_k -> inf: the exact derivative of the piecewise-linear medium
    there is a kick (g_old - g_new)/2 d sigma_k that a continuous medium does not have; on terrain-following
    tets it flips tubes (spurious caustics, speckled maps). The traversal passes inf (exact) except when the
    state feeds beams and the face is slanted (constants.BEAM_KICK_BOUND_NZ): then cell size / n (the ridge
    map's point noise 1.7 -> 0.16 dB). trace(paraxial=True) without beams always gets the exact derivatives.
    Beams without wind (the smooth medium, :func:`smooth_advance`) call this only at boundaries (reflections,
    exits), with the smooth gradient at the face point.
    """
    mp = plane[0] * p[0] + plane[1] * p[1] + plane[2] * p[2]
    if mp == 0.0:
        return
    for k in range(2):
        o = 3 * k
        mx = plane[0] * par[o] + plane[1] * par[o + 1] + plane[2] * par[o + 2]
        dsig = -mx / mp
        if dsig > max_dsig:
            dsig = max_dsig
        elif dsig < -max_dsig:
            dsig = -max_dsig
        for i in range(3):
            par[o + i] += p[i] * dsig
            par[6 + o + i] += 0.5 * g[i] * dsig


@njit_inline
def hessian_kick(par, hess, cell, coef):
    """P_k += coef H X_k (in place), H the symmetric Hessian of n^2 in row ``cell`` of hess (n_cells, 9):
    (xx, yy, zz, xy, xz, yz), per m^2. Half a step of dP/dsigma = H X / 2 is coef = sigma / 4 (the beams'
    paraxial state in the smooth medium, kick-drift-kick around :func:`advance`; docs/physics.md §11)."""
    hxx = hess[cell, 0]
    hyy = hess[cell, 1]
    hzz = hess[cell, 2]
    hxy = hess[cell, 3]
    hxz = hess[cell, 4]
    hyz = hess[cell, 5]
    for k in range(2):
        o = 3 * k
        x0 = par[o]
        x1 = par[o + 1]
        x2 = par[o + 2]
        par[6 + o] += coef * (hxx * x0 + hxy * x1 + hxz * x2)
        par[7 + o] += coef * (hxy * x0 + hyy * x1 + hyz * x2)
        par[8 + o] += coef * (hxz * x0 + hyz * x1 + hzz * x2)


@njit_inline
def smooth_gradient(hess, cell, g, x, out):
    """out = g + H (x - c): the smooth medium's gradient at x in ``cell`` (g the cell's gradient, which the
    smooth medium has at the cell's centroid c = hess[cell, 6:9])."""
    d0 = x[0] - hess[cell, 6]
    d1 = x[1] - hess[cell, 7]
    d2 = x[2] - hess[cell, 8]
    out[0] = g[0] + hess[cell, 0] * d0 + hess[cell, 3] * d1 + hess[cell, 4] * d2
    out[1] = g[1] + hess[cell, 3] * d0 + hess[cell, 1] * d1 + hess[cell, 5] * d2
    out[2] = g[2] + hess[cell, 4] * d0 + hess[cell, 5] * d1 + hess[cell, 2] * d2


SMOOTH_STEP = 0.02  # largest sigma sqrt(|H|/2) of one kick-drift-kick substep of smooth_advance


@nb.njit(**NJIT_FLAGS)
def smooth_advance(par, hess, cell, sigma):
    """X_k, P_k after sigma along the cell's curve in the smooth medium, dX/dsigma = P, dP/dsigma = H X / 2 with
    the cell's constant Hessian (row ``cell`` of hess): kick-drift-kick substeps of sigma sqrt(|H|_F / 2) at
    most SMOOTH_STEP (one substep in most cells; more for grazing chords through strongly curved layers),
    each second-order accurate; the local error of a substep is O((sigma sqrt(|H|/2))^3). In place."""
    h2 = 0.0
    for j in range(6):  # the Hessian's components; [6:9] is the centroid
        w = 2.0 if j >= 3 else 1.0
        h2 += w * hess[cell, j] * hess[cell, j]
    rate = math.sqrt(0.5 * math.sqrt(h2))
    n_sub = 1
    if rate > 0.0:
        n_sub = min(100000, 1 + int(abs(sigma) * rate / SMOOTH_STEP))
    step = sigma / n_sub
    for _ in range(n_sub):
        hessian_kick(par, hess, cell, 0.25 * step)
        advance(par, step)
        hessian_kick(par, hess, cell, 0.25 * step)


@njit_inline
def restart(par, d, p_norm, n_new, g_new):
    """Derivatives of the restart ``p' = n_new(x) d`` with d = p/|p| (p_norm = |p| before, n_new after)."""
    if not (p_norm > 0.0 and n_new > 0.0):
        return
    scale = n_new / p_norm
    for k in range(2):
        o = 3 * k
        gx = g_new[0] * par[o] + g_new[1] * par[o + 1] + g_new[2] * par[o + 2]
        dp = d[0] * par[6 + o] + d[1] * par[7 + o] + d[2] * par[8 + o]
        along = 0.5 * gx / n_new
        for i in range(3):
            par[6 + o + i] = along * d[i] + scale * (par[6 + o + i] - d[i] * dp)


@njit_inline
def reflect(par, m):
    """Specular reflection of the derivatives off the plane with unit normal m (after onto_face)."""
    for k in range(4):
        o = 3 * k
        dot = m[0] * par[o] + m[1] * par[o + 1] + m[2] * par[o + 2]
        for i in range(3):
            par[o + i] -= 2.0 * dot * m[i]


# ----- circular and n-linear curves, and the wind: the segment record (docs/physics.md §10, "Other curves") -----


@njit_inline
def refractive_index(curve, m, c_ref):
    """n = c_ref / c from the traced quantity m of a circular (m = c) or n-linear (m = n) curve."""
    if curve == CURVE_CIRCULAR:
        return c_ref / m
    return m


@njit_inline
def tangent_derivs(par, d, p_norm, seg):
    """seg[0:6] = D_k = dT/dgamma_k = (P_k - d (d.P_k)) / |p| at a segment start (d the unit tangent)."""
    for k in range(2):
        o = 3 * k
        dp = d[0] * par[6 + o] + d[1] * par[7 + o] + d[2] * par[8 + o]
        for i in range(3):
            seg[o + i] = (par[6 + o + i] - d[i] * dp) / p_norm


@njit_inline
def plain_terms(par, g, seg):
    """The segment record without wind: d m0 = g.X_k (the cell's linear model), d g = 0."""
    for k in range(2):
        o = 3 * k
        seg[6 + k] = g[0] * par[o] + g[1] * par[o + 1] + g[2] * par[o + 2]
        seg[14 + k] = 0.0
    for i in range(6):
        seg[8 + i] = 0.0
    seg[16] = 0.0


@njit_inline
def chord_face(planes, neighbours, x, d):
    """The straight chord from x along d to the first face ahead: (length L in metres, face index), or
    (inf, -1) when no face is ahead. planes (K, 4), neighbours (K,) of one cell."""
    best = math.inf
    bf = -1
    for f in range(planes.shape[0]):
        if neighbours[f] == FACE_UNUSED:
            continue
        md = planes[f, 0] * d[0] + planes[f, 1] * d[1] + planes[f, 2] * d[2]
        if md > 0.0:
            dist = (planes[f, 3] - planes[f, 0] * x[0] - planes[f, 1] * x[1] - planes[f, 2] * x[2]) / md
            if dist < best:
                best = dist
                bf = f
    return best, bf


@nb.njit(**NJIT_FLAGS)
def _conversion(curve, c_ref, m):
    """The traced quantity m > 0 as a sound speed: (c, dc/dm, d2c/dm2) (m = n^2 = (c_ref/c)^2 parabolic, c
    circular, n = c_ref/c n-linear)."""
    if curve == CURVE_PARABOLIC:
        c = c_ref / math.sqrt(m)
        return c, -0.5 * c / m, 0.75 * c / (m * m)
    if curve == CURVE_CIRCULAR:
        return m, 1.0, 0.0
    c = c_ref / m
    return c, -c / m, 2.0 * c / (m * m)


@nb.njit(**NJIT_FLAGS)
def _eff_point(curve, c_ref, wind, m_c, y):
    """What the effective medium's first-order change at y needs, once per point (_eff_variation takes it to
    each step): (state, cos_a, c', c'', M'(c_eff), M''(c_eff), su) with state 1 (wind here), 0 (no wind: the
    medium's own), -1 (m or c_eff not positive) and su the wind speed and its derivatives
    (wind.speed_hessian). Tuples throughout: the segment loop makes no array views here."""
    code, params, e = wind
    su = speed_hessian(code, params, y)
    cos_a = params[2] * e[0] + params[3] * e[1]
    if not (m_c > 0.0):
        return -1, cos_a, 0.0, 0.0, 0.0, 0.0, su
    if cos_a * su[0] == 0.0 and cos_a * su[1] == 0.0 and cos_a * su[2] == 0.0:
        return 0, cos_a, 0.0, 0.0, 0.0, 0.0, su
    c, dc, ddc = _conversion(curve, c_ref, m_c)
    c_eff = c + cos_a * su[0]
    if not (c_eff > 0.0):
        return -1, cos_a, 0.0, 0.0, 0.0, 0.0, su
    if curve == CURVE_PARABOLIC:
        m_eff = (c_ref / c_eff) * (c_ref / c_eff)
        return 1, cos_a, dc, ddc, -2.0 * m_eff / c_eff, 6.0 * m_eff / (c_eff * c_eff), su
    if curve == CURVE_CIRCULAR:
        return 1, cos_a, dc, ddc, 1.0, 0.0, su
    m_eff = c_ref / c_eff
    return 1, cos_a, dc, ddc, -m_eff / c_eff, 2.0 * m_eff / (c_eff * c_eff), su


@nb.njit(**NJIT_FLAGS)
def _eff_variation(point, g_cell, dy, cos_d):
    """First-order change of the effective medium (wind.effective_quantity: c_eff = c(m) + u(y).e, converted
    back) at a point for the step (dy, de) of position and azimuth, in closed form: (d m_eff, d g_eff x, y,
    z). point : _eff_point's; g_cell : (3,); dy : 3-tuple; cos_d = wind direction . de.

    With c = C(m), w = u.e = cos_a |u| and grad w = cos_a grad|u| (cos_a = wind direction . e):
    d c_eff = C' (g.dy) + grad w.dy + |u| cos_d; d m_eff = M'(c_eff) d c_eff;
    d g_eff = M''(c_eff) d c_eff (C' g + grad w) + M'(c_eff) (C'' (g.dy) g + cos_a H|u| dy + cos_d grad|u|),
    H|u| the exact Hessian of the wind speed. Where the wind and its gradient vanish the medium is its own
    (effective_quantity returns it unchanged): d m = g.dy, d g = 0. Where m or c_eff is not positive (refused
    by the curve setup) both are 0."""
    state, cos_a, dc, ddc, dm, ddm, su = point
    g0, g1, g2 = g_cell[0], g_cell[1], g_cell[2]
    gdy = g0 * dy[0] + g1 * dy[1] + g2 * dy[2]
    if state < 0:
        return 0.0, 0.0, 0.0, 0.0
    if state == 0:
        return gdy, 0.0, 0.0, 0.0
    wx = cos_a * su[1]
    wz = cos_a * su[2]
    dce = dc * gdy + wx * dy[0] + wz * dy[2] + su[0] * cos_d
    # d grad w = cos_a H|u| dy + cos_d grad|u| (|u| does not depend on y)
    dwx = cos_a * (su[3] * dy[0] + su[4] * dy[2]) + cos_d * su[1]
    dwz = cos_a * (su[4] * dy[0] + su[5] * dy[2]) + cos_d * su[2]
    dgx = ddm * dce * (dc * g0 + wx) + dm * (ddc * gdy * g0 + dwx)
    dgy = ddm * dce * (dc * g1) + dm * (ddc * gdy * g1)
    dgz = ddm * dce * (dc * g2 + wz) + dm * (ddc * gdy * g2 + dwz)
    return dm * dce, dgx, dgy, dgz


@nb.njit(**NJIT_FLAGS)
def wind_terms(curve, c_ref, wind, cell_model, x, d, par, seg):
    """The segment record with wind (after tangent_derivs): d m0/dgamma_k and d g/dgamma_k of the effective
    medium the traversal sets the segment up with (its value at x, its gradient at the chord middle), in
    closed form (_eff_variation: the wind speed's exact Hessian).

    wind : (code, params, e) the ray's wind and unit horizontal launch azimuth e (de/d az = (-e_y, e_x, 0),
    de/d el = 0); cell_model : (m_cell_x, g_cell, planes, neighbours, cell_size, mid_ok, x_mid) the cell's own
    traced quantity at x and gradient, its face planes, and the chord middle (mid_ok False: the gradient was
    taken at x). The chord middle x + (L/2) d moves with X_k, D_k and the chord length L to the first face f
    ahead: dL = -(m_f.X_k + L m_f.D_k)/(m_f.d). Until 2026-12 these derivatives were central differences
    (four effective-medium evaluations per launch angle); they remain the test oracle
    (tests/reference/wind_fd.py), which this agrees with to their truncation (docs/physics.md §10). The wind
    speed and its Hessian are evaluated once at x and once at the chord middle for both launch angles, and
    the loop makes no array views (each costs two atomic reference-count updates). cell_model's cell_size
    serves only the oracle's step.
    """
    code, params, e = wind
    m_x, g_cell, planes, neighbours, cell_size, mid_ok, x_mid = cell_model
    best, bf = chord_face(planes, neighbours, x, d) if mid_ok else (math.inf, -1)
    m_mid = m_x + g_cell[0] * (x_mid[0] - x[0]) + g_cell[1] * (x_mid[1] - x[1]) + g_cell[2] * (x_mid[2] - x[2])
    at_x = _eff_point(curve, c_ref, wind, m_x, x)
    use_mid = mid_ok and bf >= 0
    at_mid = _eff_point(curve, c_ref, wind, m_mid, x_mid) if use_mid else at_x
    for k in range(2):
        o = 3 * k
        xk = (par[o], par[o + 1], par[o + 2])
        # de/d el = 0; de/d az = (-e_y, e_x, 0): wind direction . de
        cos_d = 0.0 if k == 0 else -params[2] * e[1] + params[3] * e[0]
        dm0, dgx, dgy, dgz = _eff_variation(at_x, g_cell, xk, cos_d)
        seg[6 + k] = dm0
        if use_mid:
            md = planes[bf, 0] * d[0] + planes[bf, 1] * d[1] + planes[bf, 2] * d[2]
            if best > 0.0:
                mxk = planes[bf, 0] * xk[0] + planes[bf, 1] * xk[1] + planes[bf, 2] * xk[2]
                mdk = planes[bf, 0] * seg[o] + planes[bf, 1] * seg[o + 1] + planes[bf, 2] * seg[o + 2]
                dlen = -(mxk + best * mdk) / md
                half = 0.5 * best
            else:
                dlen = 0.0
                half = 0.0
            dxm = (
                xk[0] + 0.5 * dlen * d[0] + half * seg[o],
                xk[1] + 0.5 * dlen * d[1] + half * seg[o + 1],
                xk[2] + 0.5 * dlen * d[2] + half * seg[o + 2],
            )
            _, dgx, dgy, dgz = _eff_variation(at_mid, g_cell, dxm, cos_d)
        seg[8 + o] = dgx
        seg[9 + o] = dgy
        seg[10 + o] = dgz
    seg[16] = 1.0


@nb.njit(**NJIT_FLAGS)
def beam_wind_terms(curve, c_ref, wind, m_raw, g_cell, x, par, seg):
    """The segment record with wind for beams (after tangent_derivs): d m0/dgamma_k in closed form and d g = 0.

    Beams take each cell's wind gradient as fixed (:func:`drop_gradient_terms`), so of :func:`wind_terms` only
    d m0 is left: the derivative of the effective medium's m at x along X_k, with the launch azimuth's turn of
    e for k = 2. With w = u(x).e and c_eff = c + w, ``d m0 = g_eff(x).X_k + (dm/dc)(c_eff) u(x).de_k``
    (g_eff: wind.effective_value's gradient at x with the cell's linear model; u.de = wind_value along de,
    linear in e). wind_terms gets the same by central differences (relative step WIND_FD_REL): one effective
    medium and one wind evaluation here instead of four. wind : (code, params, e), params an array or the tuple
    of wind.wind_values; m_raw, g_cell : the cell's traced quantity at x and its gradient. Values, not work
    arrays. The device kernel calls this; the CPU traversal, which has the effective medium at x already, calls
    :func:`beam_wind_record` with it (the same arithmetic). Called only where the segment was set up, so the
    effective medium at x exists (state 1).
    """
    code, params, e = wind
    xv = (x[0], x[1], x[2])
    eff = effective_value(curve, c_ref, m_raw, (g_cell[0], g_cell[1], g_cell[2]), code, params, xv, (e[0], e[1], e[2]))
    u_de = wind_value(code, params, xv, (-e[1], e[0], 0.0))[0]
    beam_wind_record(curve, c_ref, eff, u_de, par, seg)


@nb.njit(**NJIT_FLAGS)
def beam_wind_record(curve, c_ref, eff, u_de, par, seg):
    """:func:`beam_wind_terms` from the effective medium at x, eff = wind.effective_value's tuple there (state 1),
    and u_de = u(x).de, the wind along the launch azimuth's turn de = (-e_y, e_x, 0) (m/s)."""
    m_eff, _, g0, g1, g2, _, _, _, _ = eff
    if curve == CURVE_CIRCULAR:
        dm = 1.0
    elif curve == CURVE_PARABOLIC:
        c_eff = c_ref / math.sqrt(m_eff) if m_eff > 0.0 else 0.0
        dm = -2.0 * m_eff / c_eff if c_eff > 0.0 else 0.0
    else:
        c_eff = c_ref / m_eff if m_eff > 0.0 else 0.0
        dm = -m_eff / c_eff if c_eff > 0.0 else 0.0
    for k in range(2):
        o = 3 * k
        seg[6 + k] = g0 * par[o] + g1 * par[o + 1] + g2 * par[o + 2]
    seg[7] += dm * u_de
    for i in range(6):
        seg[8 + i] = 0.0
    seg[16] = 1.0


@njit_inline
def finish_terms(par, g, seg):
    """seg[14:16] = d m0 - g.X_k with g the gradient the segment is set up with (after wind_terms)."""
    for k in range(2):
        o = 3 * k
        seg[14 + k] = seg[6 + k] - (g[0] * par[o] + g[1] * par[o + 1] + g[2] * par[o + 2])


@njit_inline
def drop_gradient_terms(seg):
    """Beams with wind: zero d g/dgamma_k (seg[8:14]), keep d m0 (after finish_terms; docs/physics.md §11).

    The exact derivative of the chord-middle gradient makes the paraxial state of the per-cell model grow
    exponentially near the ground in a log-law layer (|X_el| 1e6-1e9 m/rad after 1 km on the ridge map, where
    the continuous medium's rays give 10-1,700 m/rad): beams take each cell's gradient as fixed, as they do
    without wind. trace(paraxial=True) without beams keeps the exact terms."""
    for i in range(6):
        seg[8 + i] = 0.0


@njit_inline
def restart_dm(par, d, p_norm, n_new, seg):
    """restart with the segment record's d m0 (d n^2) in place of g.X_k: the parabolic restart with wind."""
    if not (p_norm > 0.0 and n_new > 0.0):
        return
    scale = n_new / p_norm
    for k in range(2):
        o = 3 * k
        dp = d[0] * par[6 + o] + d[1] * par[7 + o] + d[2] * par[8 + o]
        along = 0.5 * seg[6 + k] / n_new
        for i in range(3):
            par[6 + o + i] = along * d[i] + scale * (par[6 + o + i] - d[i] * dp)


@njit_inline
def advance_dg(par, seg, sigma):
    """The parabolic segment's d g/dgamma_k terms (wind): X_k += dg_k sigma^2/4, P_k += dg_k sigma/2."""
    q = 0.25 * sigma * sigma
    for k in range(2):
        o = 3 * k
        for i in range(3):
            par[o + i] += seg[8 + o + i] * q
            par[6 + o + i] += seg[8 + o + i] * 0.5 * sigma


@nb.njit(**NJIT_FLAGS)
def _along_circular(cs, d0, g, seg, par, u, rates):
    """along_curve for the circular arc x(u) = x0 + (2u d0 + 2u^2 k)/q, q = 1 + kappa^2 u^2 (§3)."""
    c0 = cs[6]
    ka2 = cs[3]
    uu = u * u
    inv = 1.0 / (1.0 + ka2 * uu)
    dq_du = 2.0 * ka2 * u
    gt = g[0] * d0[0] + g[1] * d0[1] + g[2] * d0[2]
    tn = 0.0
    for i in range(3):
        rates[3 + i] = ((1.0 - ka2 * uu) * d0[i] + 2.0 * u * cs[i]) * inv  # T(u) for now
        tn += rates[3 + i] * rates[3 + i]
    tn = math.sqrt(tn)
    t0 = rates[3] / tn
    t1 = rates[4] / tn
    t2 = rates[5] / tn
    for i in range(3):
        nx = 2.0 * u * d0[i] + 2.0 * uu * cs[i]
        nt = (1.0 - ka2 * uu) * d0[i] + 2.0 * u * cs[i]
        rates[i] = (2.0 * d0[i] + 4.0 * u * cs[i]) * inv - nx * dq_du * inv * inv
        rates[3 + i] = (-2.0 * ka2 * u * d0[i] + 2.0 * cs[i]) * inv - nt * dq_du * inv * inv
    tt = (t0 * rates[3] + t1 * rates[4] + t2 * rates[5]) / tn
    rates[3] = rates[3] / tn - tt * t0
    rates[4] = rates[4] / tn - tt * t1
    rates[5] = rates[5] / tn - tt * t2
    for k in range(2):
        o = 3 * k
        x0v = (par[o], par[o + 1], par[o + 2])
        dc0 = seg[6 + k]
        dgv = (seg[8 + o], seg[9 + o], seg[10 + o])
        dgt = g[0] * seg[o] + g[1] * seg[o + 1] + g[2] * seg[o + 2] + dgv[0] * d0[0] + dgv[1] * d0[1] + dgv[2] * d0[2]
        # k = -(G - (G.d0) d0)/c0: dk = ((dG.d0 + G.D0) d0 + (G.d0) D0 - dG - k dc0)/c0
        dk = (
            (dgt * d0[0] + gt * seg[o] - dgv[0] - cs[0] * dc0) / c0,
            (dgt * d0[1] + gt * seg[o + 1] - dgv[1] - cs[1] * dc0) / c0,
            (dgt * d0[2] + gt * seg[o + 2] - dgv[2] - cs[2] * dc0) / c0,
        )
        dka2 = 2.0 * (cs[0] * dk[0] + cs[1] * dk[1] + cs[2] * dk[2])
        dq = uu * dka2
        for i in range(3):
            nx = 2.0 * u * d0[i] + 2.0 * uu * cs[i]
            nt = (1.0 - ka2 * uu) * d0[i] + 2.0 * u * cs[i]
            par[o + i] = x0v[i] + (2.0 * u * seg[o + i] + 2.0 * uu * dk[i]) * inv - nx * dq * inv * inv
            par[6 + o + i] = (
                (1.0 - ka2 * uu) * seg[o + i] - uu * dka2 * d0[i] + 2.0 * u * dk[i]
            ) * inv - nt * dq * inv * inv
        dn = (t0 * par[6 + o] + t1 * par[7 + o] + t2 * par[8 + o]) / tn
        par[6 + o] = par[6 + o] / tn - dn * t0
        par[7 + o] = par[7 + o] / tn - dn * t1
        par[8 + o] = par[8 + o] / tn - dn * t2
    return math.sqrt(rates[0] * rates[0] + rates[1] * rates[1] + rates[2] * rates[2])


@nb.njit(**NJIT_FLAGS)
def _along_nlinear(cs, d0, seg, par, r, rates):
    """along_curve for the n-linear catenary x(r) = x0 + r e_r + z(r) e_z (§4), or its straight mode."""
    if cs[9] != 0.0:  # straight: x = x0 + s d0, T = d0
        for k in range(2):
            o = 3 * k
            for i in range(3):
                par[o + i] += r * seg[o + i]
                par[6 + o + i] = seg[o + i]
        for i in range(3):
            rates[i] = d0[i]
            rates[3 + i] = 0.0
        return 1.0
    alpha = cs[6]
    xi = cs[7]
    u0 = cs[8]
    n0 = cs[10]
    z = _nl_height(alpha, xi, u0, r)
    s = _nl_arc(alpha, xi, u0, r)
    big_u = alpha * r / xi + u0
    sh = math.sinh(big_u)
    ch = math.cosh(big_u)
    ch0 = math.cosh(u0)
    sin0 = cs[3] * d0[0] + cs[4] * d0[1] + cs[5] * d0[2]
    rx = d0[0] - sin0 * cs[3]
    ry = d0[1] - sin0 * cs[4]
    rz = d0[2] - sin0 * cs[5]
    cos0 = math.sqrt(rx * rx + ry * ry + rz * rz)
    du_dr = alpha / xi
    for i in range(3):
        ti = (cs[i] + sh * cs[3 + i]) / ch
        rates[i] = cs[i] + sh * cs[3 + i]
        rates[3 + i] = du_dr * (cs[3 + i] * ch - ti * sh) / ch
    for k in range(2):
        o = 3 * k
        dn0 = seg[6 + k]
        # the axis e_z = g/alpha moves with d g (wind): d alpha = e_z.dg, d e_z = (dg - e_z d alpha)/alpha
        dal = cs[3] * seg[8 + o] + cs[4] * seg[9 + o] + cs[5] * seg[10 + o]
        dez = (
            (seg[8 + o] - cs[3] * dal) / alpha,
            (seg[9 + o] - cs[4] * dal) / alpha,
            (seg[10 + o] - cs[5] * dal) / alpha,
        )
        dsin0 = (
            cs[3] * seg[o] + cs[4] * seg[o + 1] + cs[5] * seg[o + 2] + dez[0] * d0[0] + dez[1] * d0[1] + dez[2] * d0[2]
        )
        drx = seg[o] - dsin0 * cs[3] - sin0 * dez[0]
        dry = seg[o + 1] - dsin0 * cs[4] - sin0 * dez[1]
        drz = seg[o + 2] - dsin0 * cs[5] - sin0 * dez[2]
        dcos0 = cs[0] * drx + cs[1] * dry + cs[2] * drz
        der = ((drx - cs[0] * dcos0) / cos0, (dry - cs[1] * dcos0) / cos0, (drz - cs[2] * dcos0) / cos0)
        dxi = dn0 * cos0 + n0 * dcos0
        du0 = (dsin0 * cos0 - sin0 * dcos0) / (cos0 * cos0) / ch0
        # z depends on alpha and xi through beta = alpha/xi: beta dz/dbeta = r sinh U - z
        dz = s * du0 + (r * sh - z) * (dal / alpha - dxi / xi)
        dbu = du0 + r * (dal - du_dr * dxi) / xi
        for i in range(3):
            ti = (cs[i] + sh * cs[3 + i]) / ch
            par[o + i] += r * der[i] + dz * cs[3 + i] + z * dez[i]
            par[6 + o + i] = (der[i] + sh * dez[i] + dbu * (cs[3 + i] * ch - ti * sh)) / ch
    return math.sqrt(rates[0] * rates[0] + rates[1] * rates[1] + rates[2] * rates[2])


@nb.njit(**NJIT_FLAGS)
def along_curve(curve, cs, x0, d0, g, seg, par, param, rates):
    """X_k, D_k at the curve parameter ``param`` of a circular or n-linear segment, in place.

    cs : the segment's curve constants (curves.setup from x0, d0, the cell's m0 and gradient g); seg : the
    segment record (D_k at the start, d m0, d g: tangent_derivs and plain_terms or wind_terms);
    par : (12,) X_k(0) in par[0:6] on entry; on return par[0:6] = X_k(param), par[6:12] = D_k(param) (the
    D form: call to_p before anything else reads par). rates : (6,) written, d x/d param and d T/d param
    at param. Returns |d x/d param|. The derivative of the closed-form curve (§3, §4) through its setup
    constants: exact to rounding (docs/physics.md §10).
    """
    if curve == CURVE_CIRCULAR:
        return _along_circular(cs, d0, g, seg, par, param, rates)
    return _along_nlinear(cs, d0, seg, par, param, rates)


@njit_inline
def onto_face_rates(par, plane, rates, max_dparam):
    """onto_face for the D form: the neighbouring ray meets the face d param_k = -(m.X_k)/(m.x') later,
    X_k += x' d param_k, D_k += T' d param_k (rates = x', T'); max_dparam as onto_face's bound."""
    mr = plane[0] * rates[0] + plane[1] * rates[1] + plane[2] * rates[2]
    if mr == 0.0:
        return
    for k in range(2):
        o = 3 * k
        mx = plane[0] * par[o] + plane[1] * par[o + 1] + plane[2] * par[o + 2]
        dpar = -mx / mr
        if dpar > max_dparam:
            dpar = max_dparam
        elif dpar < -max_dparam:
            dpar = -max_dparam
        for i in range(3):
            par[o + i] += rates[i] * dpar
            par[6 + o + i] += rates[3 + i] * dpar


@njit_inline
def to_p(curve, c_ref, cs, g, x0, xe, te, par, seg):
    """D form -> P form in place at the point xe (tangent te) of the segment from x0: P_k = dn_k te + n D_k
    with n = n(m), m = m0 + g.(xe - x0) the segment's own linear model and d m_k = (d m0 - g.X_k(0)) +
    dg_k.(xe - x0) + g.X_k (the first two terms vanish without wind); returns n."""
    m0 = cs[6] if curve == CURVE_CIRCULAR else cs[10]
    m = m0 + g[0] * (xe[0] - x0[0]) + g[1] * (xe[1] - x0[1]) + g[2] * (xe[2] - x0[2])
    if curve == CURVE_CIRCULAR:
        n = c_ref / m
        f = -n / m
    else:
        n = m
        f = 1.0
    for k in range(2):
        o = 3 * k
        dm = g[0] * par[o] + g[1] * par[o + 1] + g[2] * par[o + 2]
        if seg[16] != 0.0:
            dm += seg[14 + k]
            for i in range(3):
                dm += seg[8 + o + i] * (xe[i] - x0[i])
        gx = f * dm
        for i in range(3):
            par[6 + o + i] = gx * te[i] + n * par[6 + o + i]
    return n

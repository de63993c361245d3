"""Field accumulation along the true ray curves (physics.md section 8), called from the traversal.

Every traced segment (one analytic curve inside one cell) is cut into sub-intervals of at most
``h_sample`` metres of arc, uniform in the curve parameter. The exact travel time of each
sub-interval (closed form, ``curves.time_at``) is deposited into the voxel that contains the curve
point at the sub-interval's middle parameter, so the time a ray spends in the grid is conserved exactly
and only its split between neighbouring voxels carries a sampling error of order h_sample.

Grid: point i, j, k sits at ``origin + (i, j, k) * spacing``; its voxel is the box of size ``spacing``
centred on it. Flat voxel index ``v = (i * ny + j) * nz + k`` (C order of an (nx, ny, nz) array).

Incoherent accumulation (per band f): ``E[f, v] += w_f * dt * exp(-a_f s) * G_f(s)`` with ray weight
w_f (W, launch solid angle / 4 pi times the source power), a_f the energy absorption coefficient (1/m,
ISO 9613-1), s the arc length from the source and G_f the product over the ray's reflections so far of
the ground energy coefficient |Q_f(cos theta_j, s)|^2 (spherical-wave, looked up in a table). Coherent
bookkeeping (per arrival group = reflection count): geometric energy ``w dt`` and the nearest sample to
the grid point, whose travel time and arc length are carried to the grid point along the local tangent.

Accumulators are per thread slot (``acc``): no shared writes; the wrapper sums the slots.
"""

from __future__ import annotations

import math

import numba as nb

from bentray.engine.acoustics.ground import q2_lookup
from bentray.engine.constants import NJIT_FLAGS
from bentray.engine.kernels import curves

# fgeo layout (float64): grid origin (3), 1/spacing (3), h_sample (arc metres per sub-interval)
FGEO_SIZE = 7
# Ground-factor refresh: |Q(s)|^2 depends on s through sqrt(k s); re-evaluated when s has changed
# by more than this fraction since the last evaluation. Measured: a 2 % change of R2 moves |Q|^2 by
# up to 0.047 at grazing incidence, so 0.5 % keeps it near 0.01 (0.05 dB); rays that met only rigid
# faces never evaluate the table.
Q_REFRESH_REL = 0.005
FIELD_OFF = 0
FIELD_INCOHERENT = 1
FIELD_COHERENT = 2


@nb.njit(**NJIT_FLAGS)
def ground_factors(q2tab, q2ax, band_of, refl_cos, refl_mat, n_refl, s, gq):
    """gq[f] = product over recorded reflections of |Q_band_of[f]|^2 at path length s.

    q2tab, q2ax : acoustics.ground.build_q2_table's table and grid (rigid materials hold exactly 1).
    """
    n_rec = min(n_refl, refl_cos.shape[0])
    for f in range(gq.shape[0]):
        g = 1.0
        for j in range(n_rec):
            g *= q2_lookup(q2tab, q2ax, refl_mat[j], band_of[f], refl_cos[j], s)
        gq[f] = g


@nb.njit(**NJIT_FLAGS)
def _voxel(fgeo, fshape, x):
    """Flat voxel index of point x, or -1 outside the grid's voxels."""
    i = int(math.floor((x[0] - fgeo[0]) * fgeo[3] + 0.5))
    if i < 0 or i >= fshape[0]:
        return -1
    j = int(math.floor((x[1] - fgeo[1]) * fgeo[4] + 0.5))
    if j < 0 or j >= fshape[1]:
        return -1
    k = int(math.floor((x[2] - fgeo[2]) * fgeo[5] + 0.5))
    if k < 0 or k >= fshape[2]:
        return -1
    return (i * fshape[1] + j) * fshape[2] + k


@nb.njit(**NJIT_FLAGS)
def _misses_grid(fgeo, fshape, xa, xb, reach):
    """True if a curve of arc length <= 2*reach from xa to xb cannot touch the grid's voxels.

    Every point of such a curve is within ``reach`` of xa or of xb (triangle inequality along the arc).
    """
    for a in range(3):
        half = 0.5 / fgeo[3 + a]
        g_lo = fgeo[a] - half
        g_hi = fgeo[a] + (fshape[a] - 1) / fgeo[3 + a] + half
        lo = min(xa[a], xb[a]) - reach
        hi = max(xa[a], xb[a]) + reach
        if hi < g_lo or lo > g_hi:
            return True
    return False


@nb.njit(**NJIT_FLAGS)
def deposit_segment(
    curve, cs, x0, d0, x1, param_end, t0, s0, seg_s, c_ref, m0, grad_m,
    mode, fgeo, fshape, weights, alpha, band_of, q2tab, q2ax,
    refl_cos, refl_mat, n_refl, gq, gq_state, last_vox, ray_id, acc,
    energy, hits, c_energy, c_perp2, c_time, c_length, c_ray, xs, ts,
):
    """Deposit one segment (param 0 .. param_end from x0 to x1, arc length seg_s) into the grid.

    weights : (n_f,) ray power per accumulated band (W); alpha : (n_f,) energy absorption (1/m);
    band_of : (n_f,) physical band index of each accumulated band (for the ground table);
    gq : (n_f,) current ground factors; gq_state : (1,) arc length they were evaluated at, 0 while the
    ray has met only rigid faces (gq = 1, nothing to evaluate), -1 after a soft reflection (re-evaluate);
    last_vox : (1,) voxel of the ray's previous sample (for ray_hits: a ray counts once per entry).
    energy : (n_acc, n_f, n_vox); hits : (n_acc, n_vox); c_* : (n_acc, n_group, n_vox) coherent records.
    m0, grad_m : the cell's traced quantity at x0 and its gradient (for the local slowness).
    """
    if seg_s <= 0.0 or param_end <= 0.0:
        return
    if _misses_grid(fgeo, fshape, x0, x1, 0.5 * seg_s):
        last_vox[0] = -1
        return
    n_sub = int(seg_s / fgeo[6]) + 1
    n_f = energy.shape[1]
    t_prev = 0.0
    for j in range(n_sub):
        p_b = param_end * (j + 1) / n_sub
        p_mid = param_end * (j + 0.5) / n_sub
        t_b = curves.time_at(curve, cs, p_b, c_ref)
        dt = t_b - t_prev
        t_prev = t_b
        ds_mid = curves.evaluate(curve, cs, x0, d0, p_mid, xs, ts)
        v = _voxel(fgeo, fshape, xs)
        if v < 0:
            last_vox[0] = -1
            continue
        if v != last_vox[0]:
            hits[acc, v] += 1.0
            last_vox[0] = v
        if not (dt > 0.0):
            continue
        s_mid = s0 + ds_mid
        if mode == FIELD_INCOHERENT:
            if gq_state[0] != 0.0 and abs(s_mid - gq_state[0]) > Q_REFRESH_REL * gq_state[0]:
                ground_factors(q2tab, q2ax, band_of, refl_cos, refl_mat, n_refl, s_mid, gq)
                gq_state[0] = s_mid
            for f in range(n_f):
                energy[acc, f, v] += weights[f] * dt * math.exp(-alpha[f] * s_mid) * gq[f]
        else:
            g = min(n_refl, c_energy.shape[1] - 1)
            c_energy[acc, g, v] += weights[0] * dt
            # nearest approach to the grid point: carry time and length along the local tangent
            nz = fshape[2]
            ny = fshape[1]
            k = v % nz
            jj = (v // nz) % ny
            ii = v // (nz * ny)
            qx = fgeo[0] + ii / fgeo[3] - xs[0]
            qy = fgeo[1] + jj / fgeo[4] - xs[1]
            qz = fgeo[2] + k / fgeo[5] - xs[2]
            along = qx * ts[0] + qy * ts[1] + qz * ts[2]
            perp2 = qx * qx + qy * qy + qz * qz - along * along
            if perp2 < c_perp2[acc, g, v]:
                m = m0 + grad_m[0] * (xs[0] - x0[0]) + grad_m[1] * (xs[1] - x0[1]) + grad_m[2] * (xs[2] - x0[2])
                slowness = curves.slowness(curve, m, c_ref)
                t_mid = t0 + curves.time_at(curve, cs, p_mid, c_ref)
                c_perp2[acc, g, v] = perp2
                c_time[acc, g, v] = t_mid + along * slowness
                c_length[acc, g, v] = s_mid + along
                c_ray[acc, g, v] = ray_id


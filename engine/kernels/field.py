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
# Ground factors: |Q(s)|^2 depends on s through sqrt(k s). They are evaluated at an anchor s_a and
# at s_a (1 + Q_SPAN_REL) and interpolated linearly in ln s in between (the table itself is bilinear in
# ln R2 with nodes 3.3 % apart, so this reproduces it closely); a sample outside the span moves the
# anchor. Measured: a 2 % change of R2 moves |Q|^2 by up to 0.047 at grazing incidence, so holding
# it constant over the span would not do. Rays that met only rigid faces never evaluate the table.
Q_SPAN_REL = 0.02
# Per-ray field state ``fst``: [0] pending time (s) and [1] pending arc (m) of short segments not yet
# deposited, [2] ground-factor anchor s_a (0: only rigid reflections so far, -1: stale after a soft one).
FST_SIZE = 3
FIELD_OFF = 0
FIELD_INCOHERENT = 1
FIELD_COHERENT = 2


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
def _ground_factor(f, s, q2tab, q2ax, band_of, refl_cos, refl_mat, n_refl, gq, fst):
    """Product of |Q|^2 over the ray's reflections in accumulated band f at arc length s."""
    if fst[2] == 0.0:
        return 1.0
    if f == 0 and (fst[2] < 0.0 or s < fst[2] or s > fst[2] * (1.0 + Q_SPAN_REL)):
        span = math.log1p(Q_SPAN_REL)
        for b in range(gq.shape[1]):
            g_a = 1.0
            g_b = 1.0
            for j in range(min(n_refl, refl_cos.shape[0])):
                g_a *= q2_lookup(q2tab, q2ax, refl_mat[j], band_of[b], refl_cos[j], s)
                g_b *= q2_lookup(q2tab, q2ax, refl_mat[j], band_of[b], refl_cos[j], s * (1.0 + Q_SPAN_REL))
            gq[0, b] = g_a
            gq[1, b] = (g_b - g_a) / span
        fst[2] = s
    return gq[0, f] + gq[1, f] * math.log(s / fst[2])


@nb.njit(**NJIT_FLAGS)
def _deposit_point(
    v,
    x,
    tangent,
    t_pt,
    s_pt,
    dt,
    slowness,
    mode,
    fgeo,
    fshape,
    weights,
    alpha,
    band_of,
    q2tab,
    q2ax,
    refl_cos,
    refl_mat,
    n_refl,
    gq,
    fst,
    ray_id,
    acc,
    energy,
    c_energy,
    c_perp2,
    c_time,
    c_length,
    c_ray,
):
    """Deposit time dt spent around point x (voxel v, arc length s_pt, travel time t_pt)."""
    if mode == FIELD_INCOHERENT:
        for f in range(energy.shape[1]):
            g = _ground_factor(f, s_pt, q2tab, q2ax, band_of, refl_cos, refl_mat, n_refl, gq, fst)
            energy[acc, f, v] += weights[f] * dt * math.exp(-alpha[f] * s_pt) * g
        return
    grp = min(n_refl, c_energy.shape[1] - 1)
    c_energy[acc, grp, v] += weights[0] * dt
    # nearest approach to the grid point: carry time and length along the local tangent
    nz = fshape[2]
    ny = fshape[1]
    qx = fgeo[0] + (v // (nz * ny)) / fgeo[3] - x[0]
    qy = fgeo[1] + ((v // nz) % ny) / fgeo[4] - x[1]
    qz = fgeo[2] + (v % nz) / fgeo[5] - x[2]
    along = qx * tangent[0] + qy * tangent[1] + qz * tangent[2]
    perp2 = qx * qx + qy * qy + qz * qz - along * along
    if perp2 < c_perp2[acc, grp, v]:
        c_perp2[acc, grp, v] = perp2
        c_time[acc, grp, v] = t_pt + along * slowness
        c_length[acc, grp, v] = s_pt + along
        c_ray[acc, grp, v] = ray_id


@nb.njit(**NJIT_FLAGS)
def flush_pending(
    x,
    tangent,
    t_end,
    s_end,
    slowness,
    mode,
    fgeo,
    fshape,
    weights,
    alpha,
    band_of,
    q2tab,
    q2ax,
    refl_cos,
    refl_mat,
    n_refl,
    gq,
    fst,
    last_vox,
    ray_id,
    acc,
    energy,
    hits,
    c_energy,
    c_perp2,
    c_time,
    c_length,
    c_ray,
):
    """Deposit the pending time of short segments that ended at x (time t_end, arc s_end)."""
    if fst[0] > 0.0:
        v = _voxel(fgeo, fshape, x)
        if v >= 0:
            if v != last_vox[0]:
                hits[acc, v] += 1.0
                last_vox[0] = v
            _deposit_point(
                v,
                x,
                tangent,
                t_end,
                s_end - 0.5 * fst[1],
                fst[0],
                slowness,
                mode,
                fgeo,
                fshape,
                weights,
                alpha,
                band_of,
                q2tab,
                q2ax,
                refl_cos,
                refl_mat,
                n_refl,
                gq,
                fst,
                ray_id,
                acc,
                energy,
                c_energy,
                c_perp2,
                c_time,
                c_length,
                c_ray,
            )
        else:
            last_vox[0] = -1
    fst[0] = 0.0
    fst[1] = 0.0


@nb.njit(**NJIT_FLAGS)
def deposit_segment(
    curve,
    cs,
    x0,
    d0,
    x1,
    param_end,
    t0,
    s0,
    seg_t,
    seg_s,
    c_ref,
    m0,
    grad_m,
    mode,
    fgeo,
    fshape,
    weights,
    alpha,
    band_of,
    q2tab,
    q2ax,
    refl_cos,
    refl_mat,
    n_refl,
    gq,
    fst,
    last_vox,
    ray_id,
    acc,
    energy,
    hits,
    c_energy,
    c_perp2,
    c_time,
    c_length,
    c_ray,
    xs,
    ts,
):
    """Deposit one segment (param 0 .. param_end from x0 to x1: time seg_t, arc length seg_s).

    Segments shorter than the sample length (thin layers, edge walks) are not evaluated: their time is
    added to the pending time, deposited as one sample once a sample length has gathered or a longer
    segment starts (at the point where the pending path ended). Longer segments are cut into
    sub-intervals of at most h_sample, uniform in the curve parameter; each deposits its exact travel
    time at its middle point.

    weights : (n_f,) ray power per accumulated band (W); alpha : (n_f,) energy absorption (1/m);
    band_of : (n_f,) physical band index of each accumulated band (for the ground table);
    gq : (2, n_f) ground factors at the anchor and their slope in ln s; fst : (FST_SIZE,) per-ray state;
    last_vox : (1,) voxel of the ray's previous sample (for ray_hits: a ray counts once per entry).
    energy : (n_acc, n_f, n_vox); hits : (n_acc, n_vox); c_* : (n_acc, n_group, n_vox) coherent records.
    m0, grad_m : the cell's traced quantity at x0 and its gradient (for the local slowness).
    """
    if seg_s <= 0.0 or param_end <= 0.0:
        return
    h = fgeo[6]
    if fst[1] + seg_s < h:
        fst[0] += seg_t
        fst[1] += seg_s
        return
    slowness0 = curves.slowness(curve, m0, c_ref)
    flush_pending(
        x0,
        d0,
        t0,
        s0,
        slowness0,
        mode,
        fgeo,
        fshape,
        weights,
        alpha,
        band_of,
        q2tab,
        q2ax,
        refl_cos,
        refl_mat,
        n_refl,
        gq,
        fst,
        last_vox,
        ray_id,
        acc,
        energy,
        hits,
        c_energy,
        c_perp2,
        c_time,
        c_length,
        c_ray,
    )
    if _misses_grid(fgeo, fshape, x0, x1, 0.5 * seg_s):
        last_vox[0] = -1
        return
    n_sub = int(seg_s / h) + 1
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
        slowness = 0.0
        t_mid = 0.0
        if mode != FIELD_INCOHERENT:
            m = m0 + grad_m[0] * (xs[0] - x0[0]) + grad_m[1] * (xs[1] - x0[1]) + grad_m[2] * (xs[2] - x0[2])
            slowness = curves.slowness(curve, m, c_ref)
            t_mid = t0 + curves.time_at(curve, cs, p_mid, c_ref)
        _deposit_point(
            v,
            xs,
            ts,
            t_mid,
            s0 + ds_mid,
            dt,
            slowness,
            mode,
            fgeo,
            fshape,
            weights,
            alpha,
            band_of,
            q2tab,
            q2ax,
            refl_cos,
            refl_mat,
            n_refl,
            gq,
            fst,
            ray_id,
            acc,
            energy,
            c_energy,
            c_perp2,
            c_time,
            c_length,
            c_ray,
        )

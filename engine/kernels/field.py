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

Kernel contract: the shared accumulators travel as one :class:`FieldAcc` (built by
field_buffers.FieldBuffers.kernel_tuple), each ray's own part (band powers, reflection record, ground
factors, pending time, scratch) as one :class:`RayField`, and a segment's span as one :class:`Segment`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

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


class FieldAcc(NamedTuple):
    """Shared field accumulators and tables (one per trace call; arrays written in place).

    mode : FIELD_OFF, FIELD_INCOHERENT or FIELD_COHERENT; fgeo : (FGEO_SIZE,) grid origin, 1/spacing, h_sample;
    fshape : (3,) int64 grid shape; alpha : (n_f,) energy absorption (1/m); band_of : (n_f,) physical band
    of each accumulated band; q2tab, q2ax : ground table |Q|^2 and its axes (acoustics.ground.q2_lookup);
    energy : (n_acc, n_f, n_vox); hits : (n_acc, n_vox); c_energy, c_perp2, c_time, c_length, c_ray :
    (n_acc, n_group, n_vox) coherent records (nearest sample per group).
    """

    mode: int
    fgeo: np.ndarray
    fshape: np.ndarray
    alpha: np.ndarray
    band_of: np.ndarray
    q2tab: np.ndarray
    q2ax: np.ndarray
    energy: np.ndarray
    hits: np.ndarray
    c_energy: np.ndarray
    c_perp2: np.ndarray
    c_time: np.ndarray
    c_length: np.ndarray
    c_ray: np.ndarray


class RayField(NamedTuple):
    """One ray's part of the field bookkeeping (arrays written in place by this ray only).

    weights : (n_f,) ray power per accumulated band (W); refl_cos, refl_mat : (R,) incidence cosine and
    face material of its first R reflections; gq : (2, n_f) ground factors at the anchor and their slope in
    ln s; fst : (FST_SIZE,) pending time, pending arc, ground anchor; last_vox : (1,) voxel of the previous
    sample (ray_hits count a ray once per entry); xs, ts : (3,) scratch; ray_id : the ray's index (coherent
    records); acc : its accumulator slot.
    """

    weights: np.ndarray
    refl_cos: np.ndarray
    refl_mat: np.ndarray
    gq: np.ndarray
    fst: np.ndarray
    last_vox: np.ndarray
    xs: np.ndarray
    ts: np.ndarray
    ray_id: int
    acc: int


class Segment(NamedTuple):
    """A segment's span: curve parameter 0 .. param_end, starting at travel time t0 (s) and arc s0 (m),
    lasting seg_t seconds and seg_s metres of arc."""

    param_end: float
    t0: float
    s0: float
    seg_t: float
    seg_s: float


@nb.njit(**NJIT_FLAGS)
def new_ray_field(weights, refl_cos, refl_mat, ray_id, acc):
    """Fresh per-ray field state for ray ``ray_id`` in accumulator slot ``acc``."""
    return RayField(
        weights,
        refl_cos,
        refl_mat,
        np.zeros((2, weights.shape[0])),
        np.zeros(FST_SIZE),
        np.full(1, -1, dtype=np.int64),
        np.empty(3),
        np.empty(3),
        ray_id,
        acc,
    )


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
def _ground_factor(fld, rf, n_refl, f, s):
    """Product of |Q|^2 over the ray's first n_refl reflections in accumulated band f at arc length s."""
    fst = rf.fst
    gq = rf.gq
    if fst[2] == 0.0:
        return 1.0
    if f == 0 and (fst[2] < 0.0 or s < fst[2] or s > fst[2] * (1.0 + Q_SPAN_REL)):
        span = math.log1p(Q_SPAN_REL)
        for b in range(gq.shape[1]):
            g_a = 1.0
            g_b = 1.0
            for j in range(min(n_refl, rf.refl_cos.shape[0])):
                g_a *= q2_lookup(fld.q2tab, fld.q2ax, rf.refl_mat[j], fld.band_of[b], rf.refl_cos[j], s)
                g_b *= q2_lookup(
                    fld.q2tab, fld.q2ax, rf.refl_mat[j], fld.band_of[b], rf.refl_cos[j], s * (1.0 + Q_SPAN_REL)
                )
            gq[0, b] = g_a
            gq[1, b] = (g_b - g_a) / span
        fst[2] = s
    return gq[0, f] + gq[1, f] * math.log(s / fst[2])


@nb.njit(**NJIT_FLAGS)
def _deposit_point(fld, rf, n_refl, v, x, tangent, t_pt, s_pt, dt, slowness):
    """Deposit time dt spent around point x (voxel v, arc length s_pt, travel time t_pt)."""
    acc = rf.acc
    if fld.mode == FIELD_INCOHERENT:
        energy = fld.energy
        for f in range(energy.shape[1]):
            g = _ground_factor(fld, rf, n_refl, f, s_pt)
            energy[acc, f, v] += rf.weights[f] * dt * math.exp(-fld.alpha[f] * s_pt) * g
        return
    grp = min(n_refl, fld.c_energy.shape[1] - 1)
    fld.c_energy[acc, grp, v] += rf.weights[0] * dt
    # nearest approach to the grid point: carry time and length along the local tangent
    fgeo = fld.fgeo
    nz = fld.fshape[2]
    ny = fld.fshape[1]
    qx = fgeo[0] + (v // (nz * ny)) / fgeo[3] - x[0]
    qy = fgeo[1] + ((v // nz) % ny) / fgeo[4] - x[1]
    qz = fgeo[2] + (v % nz) / fgeo[5] - x[2]
    along = qx * tangent[0] + qy * tangent[1] + qz * tangent[2]
    perp2 = qx * qx + qy * qy + qz * qz - along * along
    if perp2 < fld.c_perp2[acc, grp, v]:
        fld.c_perp2[acc, grp, v] = perp2
        fld.c_time[acc, grp, v] = t_pt + along * slowness
        fld.c_length[acc, grp, v] = s_pt + along
        fld.c_ray[acc, grp, v] = rf.ray_id


@nb.njit(**NJIT_FLAGS)
def flush_pending(fld, rf, n_refl, x, tangent, t_end, s_end, slowness):
    """Deposit the pending time of short segments that ended at x (time t_end, arc s_end).

    n_refl : reflections so far; slowness : 1/c at x (s/m, for the coherent nearest-approach time).
    """
    fst = rf.fst
    last_vox = rf.last_vox
    if fst[0] > 0.0:
        v = _voxel(fld.fgeo, fld.fshape, x)
        if v >= 0:
            if v != last_vox[0]:
                fld.hits[rf.acc, v] += 1.0
                last_vox[0] = v
            _deposit_point(fld, rf, n_refl, v, x, tangent, t_end, s_end - 0.5 * fst[1], fst[0], slowness)
        else:
            last_vox[0] = -1
    fst[0] = 0.0
    fst[1] = 0.0


@nb.njit(**NJIT_FLAGS)
def deposit_segment(fld, rf, n_refl, curve, c_ref, cs, x0, d0, x1, m0, grad_m, seg):
    """Deposit one segment (param 0 .. seg.param_end from x0 to x1: time seg.seg_t, arc length seg.seg_s).

    Segments shorter than the sample length (thin layers, edge walks) are not evaluated: their time is
    added to the pending time, deposited as one sample once a sample length has gathered or a longer
    segment starts (at the point where the pending path ended). Longer segments are cut into
    sub-intervals of at most h_sample, uniform in the curve parameter; each deposits its exact travel
    time at its middle point.

    fld : FieldAcc; rf : RayField; n_refl : the ray's reflections so far; curve, c_ref, cs : the segment's
    curve kind, reference speed (m/s) and constants (curves.setup); x0, d0 : start point and unit tangent;
    x1 : end point; m0, grad_m : the cell's traced quantity at x0 and its gradient (for the local
    slowness); seg : Segment (parameter span, start time and arc, duration and arc length).
    """
    param_end = seg.param_end
    seg_s = seg.seg_s
    if seg_s <= 0.0 or param_end <= 0.0:
        return
    fst = rf.fst
    fgeo = fld.fgeo
    h = fgeo[6]
    if fst[1] + seg_s < h:
        fst[0] += seg.seg_t
        fst[1] += seg_s
        return
    slowness0 = curves.slowness(curve, m0, c_ref)
    flush_pending(fld, rf, n_refl, x0, d0, seg.t0, seg.s0, slowness0)
    last_vox = rf.last_vox
    if _misses_grid(fgeo, fld.fshape, x0, x1, 0.5 * seg_s):
        last_vox[0] = -1
        return
    xs = rf.xs
    ts = rf.ts
    n_sub = int(seg_s / h) + 1
    t_prev = 0.0
    for j in range(n_sub):
        p_b = param_end * (j + 1) / n_sub
        p_mid = param_end * (j + 0.5) / n_sub
        t_b = curves.time_at(curve, cs, p_b, c_ref)
        dt = t_b - t_prev
        t_prev = t_b
        ds_mid = curves.evaluate(curve, cs, x0, d0, p_mid, xs, ts)
        v = _voxel(fgeo, fld.fshape, xs)
        if v < 0:
            last_vox[0] = -1
            continue
        if v != last_vox[0]:
            fld.hits[rf.acc, v] += 1.0
            last_vox[0] = v
        if not (dt > 0.0):
            continue
        slowness = 0.0
        t_mid = 0.0
        if fld.mode != FIELD_INCOHERENT:
            m = m0 + grad_m[0] * (xs[0] - x0[0]) + grad_m[1] * (xs[1] - x0[1]) + grad_m[2] * (xs[2] - x0[2])
            slowness = curves.slowness(curve, m, c_ref)
            t_mid = seg.t0 + curves.time_at(curve, cs, p_mid, c_ref)
        _deposit_point(fld, rf, n_refl, v, xs, ts, t_mid, seg.s0 + ds_mid, dt, slowness)

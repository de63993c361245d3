"""Beam fields: geometric (hat) beams around paraxial rays, summed onto field points (docs/physics.md §11).

Every ray carries, besides its position ``x``, unit tangent ``T``, travel time ``t`` and arc length
``s``, the paraxial derivatives of its state with respect to its two launch angles ``gamma = (el, az)``:
``X_k = dx/dgamma_k`` and ``P_k = dp/dgamma_k`` (``p = n T``, ``n = c_ref / c``; engine/kernels/paraxial.py).
The traversal cuts each ray into straight *chords* between samples ``a`` and ``b`` (a few metres apart,
and at every reflection and at the end) and calls :func:`deposit_chord` for each.

For a field point ``r`` the chord owns ``r`` when ``(r - x_a).T_a >= 0 > (r - x_b).T_b``: consecutive
chords share their end planes, so along one ray every point has at most one foot. At the foot
(``u = d_a / (d_a - d_b)``, all sample quantities interpolated linearly in u) the transverse offset
``q = r - x_f`` is expressed in launch angles by solving ``X_perp dgamma = q_perp`` (2x2, in the
orthonormal transverse basis built from X_1 and X_2); the hat weight is
``w = (1 - |dgamma_1| / Dgamma_1)(1 - |dgamma_2| / Dgamma_2)`` (zero outside one launch step), so the
four rays around a point's launch angles share it with weights summing to one. The ray's intensity
there follows from its own tube: ``I / I_1m = cos(el_0) / J`` with ``J = |X_1,perp x X_2,perp|``
(``I_1m`` the free-field intensity at 1 m), and its travel time to ``r`` from the eikonal to second
order: ``tau = t_f + (q.T) / c_f + q_perp.(P_1 dgamma_1 + P_2 dgamma_2) / (2 c_ref)`` (the wavefront
curvature ``P X^-1`` without forming it).

Near a caustic ``J -> 0``: each transverse width ``|X_k,perp| Dgamma_k`` is floored at ``w_min`` (the
amplitude then stays finite and the beam keeps a width). Arrivals are kept apart in groups (reflection
count, caustic count): per group the accumulator holds ``sum w A exp(i w tau)`` (or ``sum w I``) and
``sum w``; the finaliser divides by ``max(sum w, W_FLOOR)``, which removes the partition-of-unity
deficit where a group's neighbouring rays have already reflected (near the ground at grazing angles),
and fades the field to zero within one beam width of a fan edge or a geometric shadow boundary.

Accumulators are per thread slot (``slot``): no shared writes; the wrapper sums the slots in order. Each point's
beam is computed by :func:`point_beam` (pure, values in and out: the chord's samples and the grid's constants are
bound once per chord as tuples of values) and added with ``+=`` into the slot by :func:`deposit_chord`;
:func:`point_beam_terms` writes the same terms into a work array for the receivers' path and the CUDA kernel,
which adds them into one accumulator with atomics (engine/gpu/beam_device.py). A chord's candidate points are
the columns of its box, narrowed to the indices between its end planes (:func:`_slab_k_range`,
:func:`_image_k_range`). Nothing a kernel calls here allocates (the work arrays live in :class:`BeamRay`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from bentray.engine.acoustics.ground import _table_cell, q_at_cell
from bentray.engine.constants import NJIT_FLAGS, NJIT_NO_NRT
from bentray.engine.kernels.llvm_inline import njit_inline

# Sample record layout (float64): position, unit tangent, time, arc, X1, X2, P1, P2, slowness 1/c,
# sign of det[X1, X2, T] at the sample (caustic detection), the ray's reflection count there and whether the
# sample's per-band amplitude (BeamRay.amp_last / amp_cur) has been computed (1.0) or not yet (0.0): amplitudes
# are computed when a chord first deposits (:func:`chord_amplitudes`), most samples never need them.
S_X = 0
S_T = 3
S_TIME = 6
S_ARC = 7
S_X1 = 8
S_X2 = 11
S_P1 = 14
S_P2 = 17
S_SLOW = 20
S_JSIGN = 21
S_NREFL = 22
S_AMP = 23
SAMPLE_SIZE = 24

BEAM_OFF = 0
BEAM_COHERENT = 1
BEAM_INCOHERENT = 2
BEAM_SEMICOHERENT = 3
BEAM_MODES = {"coherent": BEAM_COHERENT, "incoherent": BEAM_INCOHERENT, "semicoherent": BEAM_SEMICOHERENT}

# Caustic-count classes kept apart (0, 1, >= 2 caustics): two branches of one reflection count that meet
# at a point are separated by a fold, so they differ in their caustic count.
N_KMAH = 3
# Divide each group's sum by max(sum of hat weights, W_FLOOR): a point with at least half of a full
# partition of unity is normalised; below that the field fades linearly (fan edges, shadow boundaries).
W_FLOOR = 0.5
# The caustic floor of a beam's width is at most this fraction of the width of an unfocused tube at the
# same arc length (arc * Dgamma): it acts where a tube has collapsed, not near the source.
FLOOR_ARC_REL = 0.25
# At most this many tube widths in one Fresnel-widened hat (a collapsed tube at a caustic keeps a finite count).
MAX_WIDEN = 1e6


class BeamGrid(NamedTuple):
    """Field points and the beam constants of a job (read only in kernels).

    origin, spacing : (3,) float64, metres, world frame; point (i, j, k) is at
        ``origin + (i, j, k) * spacing + (0, 0, z_offset[i, j])``.
    shape : (3,) int64; z_offset : (nx, ny) float64 m (zeros; terrain height for maps above the ground).
    omega : (n_f,) angular frequencies, rad/s; c_ref : m/s (n = c_ref / c).
    dgamma : (2,) launch steps (elevation, azimuth) in rad; w_min : smallest beam half-width, m.
    n_refl : number of reflection-count groups (the last one holds all higher counts).
    mode : BEAM_COHERENT | BEAM_INCOHERENT | BEAM_SEMICOHERENT.
    fresnel_k : m; the incoherent map's width floor is ``sqrt(fresnel_k * arc)`` (``fresnel_k = lambda / pi``,
        lambda of the highest band: the intensity half-width of the narrowest Gaussian beam that can reach arc
        length ``arc``; 0: off, the tube's own width).
    fresnel_cap : (2,) rad; that floor along launch axis k is at most ``arc * fresnel_cap[k]``, a quarter of the
        fan's extent along k (a narrow fan, such as a vertical fan a few degrees wide, is then not all edge).
    mirror : (nx, ny, 4) the ground's tangent plane under each column, unit normal n (up) and offset d
        (``n.x = d``): each point's mirror image through it is evaluated too, which returns the kernel mass a
        floored beam spreads below the ground (the reflection method of kernel estimates; docs/physics.md §11);
        (0, 0, 4): none. The planes' normals point up (n_z >= 0): an image then lies no higher than its point.
    z_top : m, the highest grid point (origin z + max z_offset + (nz - 1) spacing z; inf: unknown): a chord whose
        beams stay above it can reach no point and, with upward normals, no image (:func:`chord_far`).
    """

    origin: np.ndarray
    spacing: np.ndarray
    shape: np.ndarray
    z_offset: np.ndarray
    omega: np.ndarray
    c_ref: float
    dgamma: np.ndarray
    w_min: float
    n_refl: int
    mode: int
    fresnel_k: float
    fresnel_cap: np.ndarray
    mirror: np.ndarray
    z_top: float


class BeamAcc(NamedTuple):
    """Per-slot accumulators; V = number of field points, G = n_refl * N_KMAH groups, F bands.

    s_re, s_im : (slots, G, F, V) sum of w A exp(i omega tau) (size 0 in incoherent mode).
    energy : (slots, G, F, V) sum of w I / I_1m (size 0 in coherent mode).
    weight : (slots, G, V) sum of hat weights w.
    hits : (slots, V) number of beam contributions (diagnostics: a point no beam reached has 0).
    near_amp : (slots, G, F, V) sum of h |A|^2 with h the hat of each ray's own tube (Fresnel-widened incoherent
        maps only, else size 0): the amplitude factors (reflections, absorption) of the rays nearest the point.
    near_w : (slots, 2, G, V) [0] sum of those tube hats h, [1] sum of w I / I_1m (the spreading alone, widened);
        size 0 with near_amp. The finaliser forms ``(sum w I) (sum h |A|^2) / (sum h)``: the widened beams smooth
        the spreading, which is what the rays get wrong where they no longer bound tubes, but not the amplitude
        factors, which vary fast near a soft ground (docs/physics.md §11).
    """

    s_re: np.ndarray
    s_im: np.ndarray
    energy: np.ndarray
    weight: np.ndarray
    hits: np.ndarray
    near_amp: np.ndarray
    near_w: np.ndarray


class BeamPoints(NamedTuple):
    """Receiver points for beam levels, binned for the chord search.

    xyz : (P, 3) metres, world frame; bin_origin : (3,) lower corner of bin (0, 0, 0); bin_size : edge (m);
    bin_shape : (3,) int64; bin_start : (n_bins + 1,) int64 CSR offsets into bin_items (P,) int64; a point
    lies in bin floor((x - bin_origin) / bin_size) (clipped to the bin grid).
    """

    xyz: np.ndarray
    bin_origin: np.ndarray
    bin_size: float
    bin_shape: np.ndarray
    bin_start: np.ndarray
    bin_items: np.ndarray


def group_index(n_refl_groups: int, reflections: int, kmah: int) -> int:
    """Plain-Python mirror of the kernels' group numbering (tests and the finaliser)."""
    return min(reflections, n_refl_groups - 1) * N_KMAH + min(kmah, N_KMAH - 1)


@njit_inline
def chord_group(n_refl_groups, reflections, kmah):
    return min(reflections, n_refl_groups - 1) * N_KMAH + min(kmah, N_KMAH - 1)


@njit_inline
def _transverse_basis(x1, x2, t, dg1, dg2, w_min, arc, w_fres, cap1, cap2):
    """Orthonormal transverse basis e1, e2 and the triangular map of dgamma into it.

    x1, x2 : X_1, X_2, t : unit tangent (3-tuples or (3,) arrays). Returns (a11, a12, a22, a11c, a22c, e1, e2)
    with e1, e2 3-tuples (values, not a work array: array views in this per-point function cost reference
    counting): ``X_perp dgamma = (a11 dg1 + a12 dg2) e1 + a22 dg2 e2``. a11c and a22c are
    floored so that a_kk * Dgamma_k >= min(w_min, FLOOR_ARC_REL * arc * Dgamma_k) (the caustic floor); a11 and
    a22 are those floored again at min(w_fres, arc * cap_k) / Dgamma_k (w_fres: the incoherent map's Fresnel
    floor, m, 0 off; cap_k its cap, rad: BeamGrid.fresnel_k and fresnel_cap); without it a_kk = a_kkc.
    """
    a1 = x1[0] * t[0] + x1[1] * t[1] + x1[2] * t[2]
    u0 = x1[0] - a1 * t[0]
    u1 = x1[1] - a1 * t[1]
    u2 = x1[2] - a1 * t[2]
    a2 = x2[0] * t[0] + x2[1] * t[1] + x2[2] * t[2]
    v0 = x2[0] - a2 * t[0]
    v1 = x2[1] - a2 * t[1]
    v2 = x2[2] - a2 * t[2]
    nu = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    if nu > 0.0:
        e0, e1_, e2_ = u0 / nu, u1 / nu, u2 / nu
    else:
        # X1 has no transverse part (a point caustic of the elevation family): any direction normal to
        # T and, if possible, to X2
        nv = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        if nv > 0.0:
            # e1 = (X2p x T) / |X2p|
            e0 = (v1 * t[2] - v2 * t[1]) / nv
            e1_ = (v2 * t[0] - v0 * t[2]) / nv
            e2_ = (v0 * t[1] - v1 * t[0]) / nv
        else:
            # any unit vector normal to T
            if abs(t[2]) < 0.9:
                e0, e1_, e2_ = -t[1], t[0], 0.0
            else:
                e0, e1_, e2_ = 0.0, -t[2], t[1]
            ne = math.sqrt(e0 * e0 + e1_ * e1_ + e2_ * e2_)
            e0, e1_, e2_ = e0 / ne, e1_ / ne, e2_ / ne
    # e2 = T x e1 (right-handed transverse basis)
    f0 = t[1] * e2_ - t[2] * e1_
    f1 = t[2] * e0 - t[0] * e2_
    f2 = t[0] * e1_ - t[1] * e0
    a11 = nu
    a12 = v0 * e0 + v1 * e1_ + v2 * e2_
    a22 = v0 * f0 + v1 * f1 + v2 * f2
    sgn = 1.0 if a22 >= 0.0 else -1.0
    a22 = abs(a22)
    # floors: w_min, but never more than FLOOR_ARC_REL of the width an unfocused tube would have at this
    # arc length (about arc * dgamma): near the source the tube is legitimately thin, at a caustic it is not
    floor1 = min(w_min, FLOOR_ARC_REL * arc * dg1)
    floor2 = min(w_min, FLOOR_ARC_REL * arc * dg2)
    if a11 * dg1 < floor1:
        a11 = floor1 / dg1
    if a22 * dg2 < floor2:
        a22 = floor2 / dg2
    if a11 <= 0.0:
        a11 = 1e-300
    if a22 <= 0.0:
        a22 = 1e-300
    a11c = a11
    a22c = a22
    if w_fres > 0.0:
        wide1 = min(w_fres, arc * cap1)
        wide2 = min(w_fres, arc * cap2)
        # widened by a whole number of tube widths: a hat of half-width m neighbour spacings sampled at the
        # neighbours sums to m exactly only for integer m (m = 1.25 would give 1.4, +0.5 dB)
        if a11 * dg1 < wide1:
            a11 *= min(math.ceil(wide1 / (a11 * dg1)), MAX_WIDEN)
        if a22 * dg2 < wide2:
            a22 *= min(math.ceil(wide2 / (a22 * dg2)), MAX_WIDEN)
    return a11, a12, a22, a11c, a22c, (e0, e1_, e2_), (sgn * f0, sgn * f1, sgn * f2)


@nb.njit(**NJIT_FLAGS)
def signed_tube(sample):
    """det[X1, X2, T] of a sample record: its sign flips where the ray passes a caustic. (Values, not slices:
    three slices per sample cost six atomic reference-count updates.)"""
    x1 = (sample[S_X1], sample[S_X1 + 1], sample[S_X1 + 2])
    x2 = (sample[S_X2], sample[S_X2 + 1], sample[S_X2 + 2])
    t = (sample[S_T], sample[S_T + 1], sample[S_T + 2])
    return (
        x1[0] * (x2[1] * t[2] - x2[2] * t[1])
        - x1[1] * (x2[0] * t[2] - x2[2] * t[0])
        + x1[2] * (x2[0] * t[1] - x2[1] * t[0])
    )


@nb.njit(**NJIT_FLAGS)
def _half_width(sample, dg1, dg2, w_min):
    """Upper bound (m) of |q_perp|, a point's transverse offset from its foot, for the beams of a sample's tube
    before Fresnel widening: ``max(|X1| dg1, w_min) + sqrt(|X2|^2 dg2^2 + w_min^2)``.

    In point_beam's basis q_perp = g1 a11 e1 + g2 (a12 e1 + a22 e2) with |g_k| < dg_k, so |q_perp| <= a11 dg1 +
    sqrt(a12^2 + a22^2) dg2. a11 dg1 is |X1_perp| dg1 or its floor (<= w_min). a12^2 + a22^2 = |X2_perp|^2, but the
    floor raises a22 alone: a sheared tube (X2 nearly along X1, a22 small) floored to w_min reaches
    sqrt(a12^2 dg2^2 + w_min^2), up to sqrt(2) times max(|X2| dg2, w_min), the bound used until 2026-12-05, which
    the search box then missed owned points by (tests/fields/test_candidate_pruning.py). docs/physics.md §11."""
    n1 = 0.0
    n2 = 0.0
    for i in range(3):
        n1 += sample[S_X1 + i] * sample[S_X1 + i]
        n2 += sample[S_X2 + i] * sample[S_X2 + i]
    return max(math.sqrt(n1) * dg1, w_min) + math.sqrt(n2 * dg2 * dg2 + w_min * w_min)


@nb.njit(**NJIT_FLAGS)
def _foot_offset_bound(sa, sb):
    """Upper bound (m) of a point's offset along the tangent from its foot on the straight chord from sa to sb.

    The foot is (1 - u) x_a + u x_b with u where the point's distances to the two end planes (normals t_a, t_b)
    interpolate to 0, so q.T(u) = u (1 - u) (x_b - x_a).(t_b - t_a) with T(u) = (1 - u) t_a + u t_b; for unit
    tangents |T(u)| >= |t_a + t_b| / 2, hence |q.T / |T|| <= |x_b - x_a| |t_b - t_a| / (2 |t_a + t_b|): micrometres
    to millimetres for the chords of a few metres that turn by milliradians. |t_a + t_b| is taken at least 1: a
    chord turning by more than 120 degrees (which the sampling never makes) gets |x_b - x_a| |t_b - t_a| / 2."""
    d2 = 0.0
    dt2 = 0.0
    st2 = 0.0
    for i in range(3):
        d = sb[S_X + i] - sa[S_X + i]
        dt = sb[S_T + i] - sa[S_T + i]
        st = sb[S_T + i] + sa[S_T + i]
        d2 += d * d
        dt2 += dt * dt
        st2 += st * st
    return math.sqrt(d2 * dt2) / (2.0 * max(math.sqrt(st2), 1.0))


@njit_inline
def _reach_bound(sa, sb, dg1, dg2, w_min):
    """An upper bound of :func:`chord_reach` before the Fresnel widening, without square roots (the 1-norm of a
    vector bounds its 2-norm, a + w_min bounds sqrt(a^2 + w_min^2), and |dx|_1 |dt|_1 / 2 bounds
    :func:`_foot_offset_bound`; 0.1 % and 1 nm of margin cover the rounding): the quick test, taken for every chord
    sample, that skips the exact reach of a chord far from every point."""
    a1 = abs(sa[S_X1]) + abs(sa[S_X1 + 1]) + abs(sa[S_X1 + 2])
    a2 = abs(sa[S_X2]) + abs(sa[S_X2 + 1]) + abs(sa[S_X2 + 2])
    b1 = abs(sb[S_X1]) + abs(sb[S_X1 + 1]) + abs(sb[S_X1 + 2])
    b2 = abs(sb[S_X2]) + abs(sb[S_X2 + 1]) + abs(sb[S_X2 + 2])
    r = max(max(a1 * dg1, w_min) + a2 * dg2 + w_min, max(b1 * dg1, w_min) + b2 * dg2 + w_min)
    dx1 = abs(sb[S_X] - sa[S_X]) + abs(sb[S_X + 1] - sa[S_X + 1]) + abs(sb[S_X + 2] - sa[S_X + 2])
    dt1 = abs(sb[S_T] - sa[S_T]) + abs(sb[S_T + 1] - sa[S_T + 1]) + abs(sb[S_T + 2] - sa[S_T + 2])
    return 1.001 * (r + 0.5 * dx1 * dt1) + 1e-9


@njit_inline
def chord_widening(grid, sa, sb):
    """How much (m) the Fresnel floor can widen a beam of the chord from sa to sb along each transverse axis: the
    floor at the chord's larger arc length (the widened hat is at most one tube width more); 0 without it."""
    if grid.fresnel_k > 0.0:
        return math.sqrt(grid.fresnel_k * max(sa[S_ARC], sb[S_ARC]))
    return 0.0


@njit_inline
def mirror_point(grid, i, j, px, py, pz, reach, out):
    """The image of point (px, py, pz) of column (i, j) through the ground's tangent plane there, into out (3,);
    False when the grid has no mirror planes or the point is farther than ``reach`` above the plane (the image is
    then at least 2 reach from every chord above the ground) or below it."""
    if grid.mirror.shape[0] == 0:
        return False
    n0 = grid.mirror[i, j, 0]
    n1 = grid.mirror[i, j, 1]
    n2 = grid.mirror[i, j, 2]
    h = n0 * px + n1 * py + n2 * pz - grid.mirror[i, j, 3]
    if h < 0.0 or h > reach:
        return False
    out[0] = px - 2.0 * h * n0
    out[1] = py - 2.0 * h * n1
    out[2] = pz - 2.0 * h * n2
    return True


@njit_inline
def _misses(lo, hi, origin, spacing, n):
    """True when no grid coordinate origin + i spacing (0 <= i < n) lies in [lo, hi] (the span tested
    without the integer conversion of :func:`_index_range`)."""
    return hi < origin or lo > origin + (n - 1) * spacing


@njit_inline
def chord_far(grid, sa, sb):
    """True when the chord from sa to sb cannot reach the grid's columns (chord_box's first test) or stays, with
    its beams' reach, above the grid's highest point (BeamGrid.z_top; no point there, and no image: an image
    lies no higher than its point): checked before :func:`deposit_chord` is called, so that chords that miss the
    grid pay neither the call nor the reference counts of its tuple of arrays."""
    bound = _reach_bound(sa, sb, grid.dgamma[0], grid.dgamma[1], grid.w_min) + 2.0 * chord_widening(grid, sa, sb)
    if min(sa[S_X + 2], sb[S_X + 2]) - bound > grid.z_top:
        return True
    return _misses(
        min(sa[S_X], sb[S_X]) - bound, max(sa[S_X], sb[S_X]) + bound, grid.origin[0], grid.spacing[0], grid.shape[0]
    ) or _misses(
        min(sa[S_X + 1], sb[S_X + 1]) - bound,
        max(sa[S_X + 1], sb[S_X + 1]) + bound,
        grid.origin[1],
        grid.spacing[1],
        grid.shape[1],
    )


@njit_inline
def _index_range(lo, hi, origin, spacing, n):
    """Grid indices [i0, i1] whose coordinate lies in [lo, hi] (empty when i0 > i1)."""
    i0 = int(math.ceil((lo - origin) / spacing))
    i1 = int(math.floor((hi - origin) / spacing))
    if i0 < 0:
        i0 = 0
    if i1 > n - 1:
        i1 = n - 1
    return i0, i1


@njit_inline
def _turn(re, im, kmah):
    """(re + i im) * (-i)^kmah: the phase lost at each caustic (exp(-i w t) convention)."""
    k = kmah % 4
    if k == 0:
        return re, im
    if k == 1:
        return im, -re
    if k == 2:
        return -re, -im
    return -im, re


# What point_beam_terms writes into its ``terms`` array (the beam of one chord at one point, before it is
# accumulated): hat weight, intensity factor I / I_1m, foot interpolation u, travel time tau (s) and amplitude
# w sqrt(I / I_1m) (tau and amplitude only in the coherent modes).
PB_W = 0
PB_REL_I = 1
PB_U = 2
PB_TAU = 3
PB_AMP = 4
PB_NEAR = 5  # the hat of the ray's own tube at the point (h1 h2 of the unwidened tube; = w without widening)
PB_SIZE = 6
POINT_SCRATCH = 15  # offset of the mirrored point in BeamRay.work (its first 15 slots held point_beam_terms'
# basis, X1, X2 and tangent until 2026-12-04, now values; the offset is kept for the device kernel's scratch rows)
# BeamRay.work holds POINT_SCRATCH + 3: the last three hold a mirrored point (deposit_chord's ground images)
WORK_SIZE = POINT_SCRATCH + 3


@njit_inline
def sample_values(s):
    """The SAMPLE_SIZE floats of a sample record as a tuple (read once per chord: the per-point code then indexes
    a tuple of values, which costs no reference counting, instead of an array bound in a loop)."""
    # fmt: off
    return (s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8], s[9], s[10], s[11],
            s[12], s[13], s[14], s[15], s[16], s[17], s[18], s[19], s[20], s[21], s[22], s[23])
    # fmt: on


@njit_inline
def grid_values(grid):
    """The scalars of a BeamGrid that a point's beam needs, as a tuple (read once per chord):
    (dgamma_el, dgamma_az, w_min, fresnel_k, fresnel_cap_el, fresnel_cap_az, c_ref, mode)."""
    return (
        grid.dgamma[0],
        grid.dgamma[1],
        grid.w_min,
        grid.fresnel_k,
        grid.fresnel_cap[0],
        grid.fresnel_cap[1],
        grid.c_ref,
        grid.mode,
    )


# Relative and absolute-rounding margins of :func:`outside_hat` (its bounds are exact in real arithmetic; both sides
# carry rounding of ~1e-16 relative to their terms' magnitudes) and the smallest |X1_perp|^2 / |X1|^2 it trusts
# (below it the basis takes another branch; the test then rejects nothing).
HAT_TEST_REL = 1e-9
HAT_TEST_MIN_PERP = 1e-6


@njit_inline
def outside_hat(t, q, x1, x2, dg1, dg2, w_min, w_fres):
    """True only when the point's transverse offset lies outside the chord's (floored, Fresnel-widened) hat at the
    foot, so :func:`point_beam` would give it zero weight: a necessary condition of ownership tested without the
    transverse basis (no normalisation, no floors rounded up to whole tube widths): most candidates of a chord's
    search box are rejected here, before the basis is built (docs/physics.md §11, "Candidate points").

    t : the interpolated tangent (3-tuple, not normalised); q : point minus foot; x1, x2 : X_1, X_2 at the foot;
    w_fres : the Fresnel floor at the foot (m, 0 off). With ``Y_perp = Y - (Y.t) t / |t|^2``, ``nu = |X1_perp|`` and
    the basis of :func:`_transverse_basis` (e1 = X1_perp / nu, a11 = nu, a12 = X2_perp.e1): ownership needs
    ``|g1| < dg1`` and ``|g2| < dg2``, hence
    ``|c1| = |a11w g1 + a12 g2| < a11w dg1 + |a12| dg2`` and ``|c2| < a22w dg2``, where the floored and widened
    ``a_kkw dg_k <= max(a_kk dg_k, w_min) + w_fres`` (the floor is at most w_min; widening by a whole number of tube
    widths adds less than one tube width to a width below w_fres). Times nu (and |t| nu for c2 = det(t, X1, q) /
    (|t| nu), a22 = |det(t, X1, X2)| / (|t| nu)) the tests need two square roots and no division by a small number.
    Every bound is widened by HAT_TEST_REL relative to its terms' magnitudes, so rounding cannot reject an owned
    point; a nearly point caustic (|X1_perp|^2 < HAT_TEST_MIN_PERP |X1|^2) rejects nothing."""
    tt = (t[0] * t[0] + t[1] * t[1]) + t[2] * t[2]
    x1t = x1[0] * t[0] + x1[1] * t[1] + x1[2] * t[2]
    x11 = x1[0] * x1[0] + x1[1] * x1[1] + x1[2] * x1[2]
    n1sq = x11 - x1t * x1t / tt
    if not n1sq > HAT_TEST_MIN_PERP * x11:
        return False
    eps = HAT_TEST_REL
    n1_hi = n1sq + eps * x11
    nu_hi = math.sqrt(n1_hi)
    qt = q[0] * t[0] + q[1] * t[1] + q[2] * t[2]
    qx1 = q[0] * x1[0] + q[1] * x1[1] + q[2] * x1[2]
    x2t = x2[0] * t[0] + x2[1] * t[1] + x2[2] * t[2]
    x21 = x2[0] * x1[0] + x2[1] * x1[1] + x2[2] * x1[2]
    c1 = qx1 - qt * x1t / tt
    c1_tol = eps * (abs(qx1) + abs(qt * x1t) / tt)
    a12_hi = abs(x21 - x2t * x1t / tt) + eps * (abs(x21) + abs(x2t * x1t) / tt)
    rhs1 = max(n1_hi * dg1, w_min * nu_hi) + w_fres * nu_hi + a12_hi * dg2
    if abs(c1) - c1_tol > (1.0 + eps) * rhs1:
        return True
    # c2 and a22 from triple products with t x X1
    m0 = t[1] * x1[2] - t[2] * x1[1]
    m1 = t[2] * x1[0] - t[0] * x1[2]
    m2 = t[0] * x1[1] - t[1] * x1[0]
    dq = m0 * q[0] + m1 * q[1] + m2 * q[2]
    dx = m0 * x2[0] + m1 * x2[1] + m2 * x2[2]
    # rounding of the triple products: bounded by eps times the same sums of absolute products
    a0 = abs(t[1] * x1[2]) + abs(t[2] * x1[1])
    a1 = abs(t[2] * x1[0]) + abs(t[0] * x1[2])
    a2 = abs(t[0] * x1[1]) + abs(t[1] * x1[0])
    dq_tol = eps * (a0 * abs(q[0]) + a1 * abs(q[1]) + a2 * abs(q[2]))
    dx_hi = abs(dx) + eps * (a0 * abs(x2[0]) + a1 * abs(x2[1]) + a2 * abs(x2[2]))
    tn_nu_hi = math.sqrt(tt * n1_hi) * (1.0 + eps)
    rhs2 = max(dx_hi * dg2, w_min * tn_nu_hi) + w_fres * tn_nu_hi
    return abs(dq) - dq_tol > (1.0 + eps) * rhs2


# point_beam's answer for a point the chord does not own
_NO_BEAM = (False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit_inline
def point_beam(ta, tb, gc, launch_cos, px, py, pz):
    """The beam of the chord from sample ``ta`` to ``tb`` at point (px, py, pz), nothing accumulated.

    ta, tb : sample records as tuples (:func:`sample_values`); gc : :func:`grid_values`; launch_cos : cos of
    the launch elevation. Returns (owned, w, rel_i, u, tau, amp, near): whether the chord owns the point with a
    non-zero hat weight, then the PB_* terms (tau, amp only in the coherent modes, else 0). Values only: this runs
    for every candidate point of a chord, and arrays bound here would cost reference counting per point.
    """
    da = (px - ta[S_X]) * ta[S_T] + (py - ta[S_X + 1]) * ta[S_T + 1] + (pz - ta[S_X + 2]) * ta[S_T + 2]
    if da < 0.0:
        return _NO_BEAM
    db = (px - tb[S_X]) * tb[S_T] + (py - tb[S_X + 1]) * tb[S_T + 1] + (pz - tb[S_X + 2]) * tb[S_T + 2]
    if db >= 0.0:
        return _NO_BEAM
    dg1 = gc[0]
    dg2 = gc[1]
    u = da / (da - db)
    v_ = 1.0 - u
    t0 = v_ * ta[S_T] + u * tb[S_T]
    t1 = v_ * ta[S_T + 1] + u * tb[S_T + 1]
    t2 = v_ * ta[S_T + 2] + u * tb[S_T + 2]
    q0 = px - (v_ * ta[S_X] + u * tb[S_X])
    q1 = py - (v_ * ta[S_X + 1] + u * tb[S_X + 1])
    q2 = pz - (v_ * ta[S_X + 2] + u * tb[S_X + 2])
    x1 = (v_ * ta[S_X1] + u * tb[S_X1], v_ * ta[S_X1 + 1] + u * tb[S_X1 + 1], v_ * ta[S_X1 + 2] + u * tb[S_X1 + 2])
    x2 = (v_ * ta[S_X2] + u * tb[S_X2], v_ * ta[S_X2 + 1] + u * tb[S_X2 + 1], v_ * ta[S_X2 + 2] + u * tb[S_X2 + 2])
    arc = v_ * ta[S_ARC] + u * tb[S_ARC]
    w_fres = math.sqrt(gc[3] * arc) if gc[3] > 0.0 else 0.0
    if outside_hat((t0, t1, t2), (q0, q1, q2), x1, x2, dg1, dg2, gc[2], w_fres):
        return _NO_BEAM
    tn = math.sqrt(((0.0 + t0 * t0) + t1 * t1) + t2 * t2)
    tf = (t0 / tn, t1 / tn, t2 / tn)
    a11, a12, a22, a11c, a22c, e1, e2 = _transverse_basis(x1, x2, tf, dg1, dg2, gc[2], arc, w_fres, gc[4], gc[5])
    qa = q0 * tf[0] + q1 * tf[1] + q2 * tf[2]
    qp0 = q0 - qa * tf[0]
    qp1 = q1 - qa * tf[1]
    qp2 = q2 - qa * tf[2]
    c1 = qp0 * e1[0] + qp1 * e1[1] + qp2 * e1[2]
    c2 = qp0 * e2[0] + qp1 * e2[1] + qp2 * e2[2]
    g2 = c2 / a22
    g1 = (c1 - a12 * g2) / a11
    h1 = 1.0 - abs(g1) / dg1
    if h1 <= 0.0:
        return _NO_BEAM
    h2 = 1.0 - abs(g2) / dg2
    if h2 <= 0.0:
        return _NO_BEAM
    # w: the hat's share of a partition of unity, h1 h2 (a11c a22c) / (a11 a22) for a hat widened by the Fresnel
    # floor (h1 h2 without it); rel_i: the tube's intensity. Then w rel_i = h1 h2 launch_cos / (a11 a22) spreads
    # the ray's energy over the widened footprint while sum w still measures how fully rays cover the point.
    w = h1 * h2
    near = w
    if w_fres > 0.0:
        w *= (a11c / a11) * (a22c / a22)
        g2c = c2 / a22c
        g1c = (c1 - a12 * g2c) / a11c
        near = max(1.0 - abs(g1c) / dg1, 0.0) * max(1.0 - abs(g2c) / dg2, 0.0)
    rel_i = launch_cos / (a11c * a22c)
    tau = 0.0
    amp = 0.0
    if gc[7] != BEAM_INCOHERENT:
        # travel time to the point: foot time, along-tangent offset, wavefront curvature
        pd_0 = (v_ * ta[S_P1] + u * tb[S_P1]) * g1 + (v_ * ta[S_P2] + u * tb[S_P2]) * g2
        pd_1 = (v_ * ta[S_P1 + 1] + u * tb[S_P1 + 1]) * g1 + (v_ * ta[S_P2 + 1] + u * tb[S_P2 + 1]) * g2
        pd_2 = (v_ * ta[S_P1 + 2] + u * tb[S_P1 + 2]) * g1 + (v_ * ta[S_P2 + 2] + u * tb[S_P2 + 2]) * g2
        pd0 = ((0.0 + qp0 * pd_0) + qp1 * pd_1) + qp2 * pd_2
        tau = v_ * ta[S_TIME] + u * tb[S_TIME] + qa * (v_ * ta[S_SLOW] + u * tb[S_SLOW]) + 0.5 * pd0 / gc[6]
        amp = w * math.sqrt(rel_i)
    return True, w, rel_i, u, tau, amp, near


@njit_inline
def point_beam_terms(grid, chord, px, py, pz, terms):
    """:func:`point_beam` of ``chord`` (see :func:`deposit_chord`) at point (px, py, pz), written into ``terms``
    (PB_*); False if the chord does not own the point or its hat weight is zero. terms : (PB_SIZE,) out array
    (caller-provided: no allocation, so the device kernel calls this too)."""
    return write_terms(
        terms, point_beam(sample_values(chord[0]), sample_values(chord[1]), grid_values(grid), chord[6], px, py, pz)
    )


@njit_inline
def write_terms(terms, beam):
    """:func:`point_beam`'s answer ``beam`` into the work array ``terms`` (PB_*) when the chord owns the point;
    returns whether it does (terms untouched otherwise)."""
    owned, w, rel_i, u, tau, amp, near = beam
    if not owned:
        return False
    terms[PB_W] = w
    terms[PB_REL_I] = rel_i
    terms[PB_U] = u
    terms[PB_TAU] = tau
    terms[PB_AMP] = amp
    terms[PB_NEAR] = near
    return True


@njit_inline
def band_energy(a_re, a_im, b_re, b_im, u, w, rel_i):
    """One band's incoherent term ``w I / I_1m |A|^2`` of a point's beam: A interpolated at the foot (u) between
    the chord's amplitudes (a_re + i a_im at sample a, b_re + i b_im at b); w, rel_i from point_beam_terms.
    Scalars only (no array taken from a tuple per band: that costs reference counting in the hot loop)."""
    v_ = 1.0 - u
    re = v_ * a_re + u * b_re
    im = v_ * a_im + u * b_im
    return w * rel_i * (re * re + im * im)


@njit_inline
def band_coherent(a_re, a_im, b_re, b_im, u, kmah, omega, tau, amp):
    """One band's coherent term ``w sqrt(I / I_1m) A (-i)^kmah exp(i omega tau)`` (re, im) of a point's beam
    (omega: the band's angular frequency; tau, amp from point_beam_terms). Scalars only."""
    v_ = 1.0 - u
    re, im = _turn(v_ * a_re + u * b_re, v_ * a_im + u * b_im, kmah)
    ph = omega * tau
    cph = math.cos(ph)
    sph = math.sin(ph)
    return amp * (re * cph - im * sph), amp * (re * sph + im * cph)


@njit_inline
def _accumulate(grid, acc, slot, amp_a, amp_b, group, kmah, v, terms):
    """Add a point's beam (``terms``) to point v of accumulator slot ``slot`` (the CPU's per-slot ``+=``;
    the device kernel adds the same terms with atomics, engine/gpu/beam_device.py)."""
    w = terms[PB_W]
    u = terms[PB_U]
    acc.weight[slot, group, v] += w
    acc.hits[slot, v] += 1.0
    n_f = grid.omega.shape[0]
    if grid.mode != BEAM_COHERENT:
        rel_i = terms[PB_REL_I]
        for f in range(n_f):
            acc.energy[slot, group, f, v] += band_energy(
                amp_a[0, f], amp_a[1, f], amp_b[0, f], amp_b[1, f], u, w, rel_i
            )
        if acc.near_w.shape[0] > 0:
            near = terms[PB_NEAR]
            acc.near_w[slot, 0, group, v] += near
            acc.near_w[slot, 1, group, v] += w * rel_i
            if near > 0.0:
                for f in range(n_f):
                    acc.near_amp[slot, group, f, v] += band_energy(
                        amp_a[0, f], amp_a[1, f], amp_b[0, f], amp_b[1, f], u, near, 1.0
                    )
    if grid.mode != BEAM_INCOHERENT:
        tau = terms[PB_TAU]
        amp = terms[PB_AMP]
        for f in range(n_f):
            re, im = band_coherent(amp_a[0, f], amp_a[1, f], amp_b[0, f], amp_b[1, f], u, kmah, grid.omega[f], tau, amp)
            acc.s_re[slot, group, f, v] += re
            acc.s_im[slot, group, f, v] += im


@njit_inline
def _point_beam(grid, acc, slot, chord, px, py, pz, v, scratch, terms):
    """The beam of ``chord`` at point (px, py, pz) accumulated into point v of ``acc``; False if it does not own
    the point or its hat weight is zero. scratch, terms : work arrays of :func:`point_beam_terms`."""
    if not point_beam_terms(grid, chord, px, py, pz, terms):
        return False
    chord_amplitudes(chord)
    _accumulate(grid, acc, slot, chord[2], chord[3], chord[4], chord[5], v, terms)
    return True


@nb.njit(**NJIT_FLAGS)
def chord_reach(grid, sa, sb):
    """Upper bound (m) of |P - foot| for every point P the chord from sample sa to sb owns (the search box's
    margin): the tube's transverse reach at either sample (|X_k| at the foot is at most its larger value at the
    ends), twice the Fresnel widening and the along-tangent offset of a curved chord, widened by 1e-9 relative and
    1 nm for rounding (docs/physics.md §11, "The search box")."""
    tube = max(_half_width(sa, grid.dgamma[0], grid.dgamma[1], grid.w_min),
               _half_width(sb, grid.dgamma[0], grid.dgamma[1], grid.w_min))  # fmt: skip
    reach = tube + 2.0 * chord_widening(grid, sa, sb) + _foot_offset_bound(sa, sb)
    return reach * (1.0 + 1e-9) + 1e-9


@nb.njit(**NJIT_FLAGS)
def chord_box(grid, sa, sb):
    """Grid columns a chord may reach: (i0, i1, j0, j1, z_lo, z_hi), index ranges in x and y (inclusive,
    empty when i0 > i1) and the height range (m) whose points are searched in each column. A chord whose
    bounding box, widened by a bound of its reach, misses the grid's columns returns an empty range at once."""
    nx = grid.shape[0]
    ny = grid.shape[1]
    bound = _reach_bound(sa, sb, grid.dgamma[0], grid.dgamma[1], grid.w_min) + 2.0 * chord_widening(grid, sa, sb)
    if _misses(
        min(sa[S_X], sb[S_X]) - bound, max(sa[S_X], sb[S_X]) + bound, grid.origin[0], grid.spacing[0], nx
    ) or _misses(
        min(sa[S_X + 1], sb[S_X + 1]) - bound,
        max(sa[S_X + 1], sb[S_X + 1]) + bound,
        grid.origin[1],
        grid.spacing[1],
        ny,
    ):
        return 1, 0, 1, 0, 0.0, -1.0
    reach = chord_reach(grid, sa, sb)
    i0, i1 = _index_range(
        min(sa[S_X], sb[S_X]) - reach, max(sa[S_X], sb[S_X]) + reach, grid.origin[0], grid.spacing[0], nx
    )
    j0, j1 = _index_range(
        min(sa[S_X + 1], sb[S_X + 1]) - reach,
        max(sa[S_X + 1], sb[S_X + 1]) + reach,
        grid.origin[1],
        grid.spacing[1],
        ny,
    )
    z_lo = min(sa[S_X + 2], sb[S_X + 2]) - reach
    z_hi = max(sa[S_X + 2], sb[S_X + 2]) + reach
    return i0, i1, j0, j1, z_lo, z_hi


# Plane-distance margin (m) of the chords' candidate ranges: a candidate is dropped only where its distance to an end
# plane is past the plane by more than this; point_beam's own test rounds by ~1e-13 m on km domains.
SLAB_TOL_M = 1e-6


@njit_inline
def _floor_in(t, lo, hi):
    """floor(t) as a float, t first clamped to [lo - 2, hi + 2] (finite; +-inf allowed): the candidate ranges
    need the bound only within their index range, and the clamp keeps inf out of the integer rounding (math.floor,
    which the CUDA target has: numpy's ufuncs it has not)."""
    return float(math.floor(min(max(t, lo - 2.0), hi + 2.0)))


@njit_inline
def _ceil_in(t, lo, hi):
    """ceil(t) as a float, t clamped as in :func:`_floor_in`."""
    return float(math.ceil(min(max(t, lo - 2.0), hi + 2.0)))


@njit_inline
def _plane_k_range(a0, ak, b0, bk, k0, k1):
    """The part of the index range [k0, k1] of candidates r_k = r_0 + k step that may lie between a chord's end
    planes, given a0 = (r_0 - x_a).T_a, ak = step.T_a, b0 = (r_0 - x_b).T_b, bk = step.T_b (both distances linear
    in k); (1, 0) when empty. Conservative: an index is dropped only where its near-plane distance is below
    -SLAB_TOL_M or its far-plane distance at least +SLAB_TOL_M, with one index of slack each way; non-finite
    input prunes nothing (point_beam decides)."""
    if not (math.isfinite(a0) and math.isfinite(b0) and math.isfinite(ak) and math.isfinite(bk)):
        return k0, k1
    tol = SLAB_TOL_M
    lo = float(k0)
    hi = float(k1)
    # a0 + ak k >= -tol (each bound clamped to [lo - 2, hi + 2] before rounding: an overflow to +-inf stays finite)
    if ak > 0.0:
        lo = max(lo, _floor_in((-tol - a0) / ak, lo, hi) - 1.0)
    elif ak < 0.0:
        hi = min(hi, _ceil_in((-tol - a0) / ak, lo, hi) + 1.0)
    elif a0 < -tol:
        return 1, 0
    # b0 + bk k < tol
    if bk > 0.0:
        hi = min(hi, _ceil_in((tol - b0) / bk, lo, hi) + 1.0)
    elif bk < 0.0:
        lo = max(lo, _floor_in((tol - b0) / bk, lo, hi) - 1.0)
    elif b0 >= tol:
        return 1, 0
    if not (lo <= hi):
        return 1, 0
    return int(lo), int(hi)


@njit_inline
def _slab_k_range(ta, tb, r0, step, k0, k1):
    """:func:`_plane_k_range` of the candidates r0 + k step (3-tuples, m) for the chord from ta to tb (tuples of
    :func:`sample_values`)."""
    a0 = (r0[0] - ta[S_X]) * ta[S_T] + (r0[1] - ta[S_X + 1]) * ta[S_T + 1] + (r0[2] - ta[S_X + 2]) * ta[S_T + 2]
    b0 = (r0[0] - tb[S_X]) * tb[S_T] + (r0[1] - tb[S_X + 1]) * tb[S_T + 1] + (r0[2] - tb[S_X + 2]) * tb[S_T + 2]
    ak = step[0] * ta[S_T] + step[1] * ta[S_T + 1] + step[2] * ta[S_T + 2]
    bk = step[0] * tb[S_T] + step[1] * tb[S_T + 1] + step[2] * tb[S_T + 2]
    return _plane_k_range(a0, ak, b0, bk, k0, k1)


@njit_inline
def _image_k_range(ta, tb, px, py, zo, dz, nz, m, reach, z_band):
    """Indices k of the column's points (px, py, zo + k dz) whose ground images can be deposited: those at most
    ``reach`` above the mirror plane m = (n, d) (h = n.r - d in [0, reach]) and whose image can lie in the height
    band z_band = (z_lo, z_hi) of the chord's box and between the chord's end planes; (1, 0) when none;
    (0, nz - 1) (no pruning) where the plane is too steep to invert (n_z dz below 1e-9 m). The images are linear
    in k: r_k - 2 h_k n with h_k = h_0 + n_z dz k. Conservative, as :func:`_plane_k_range` (one index of slack
    on the reach as well)."""
    hk = m[2] * dz
    if not (hk > 1e-9):
        return 0, nz - 1
    h0 = m[0] * px + m[1] * py + m[2] * zo - m[3]
    if not math.isfinite(h0):
        return 0, nz - 1
    top = float(nz - 1)
    lo = max(0.0, _ceil_in(-h0 / hk, 0.0, top) - 1.0)
    hi = min(top, _floor_in((reach - h0) / hk, 0.0, top) + 1.0)
    if not (lo <= hi):
        return 1, 0
    r0 = (px - 2.0 * h0 * m[0], py - 2.0 * h0 * m[1], zo - 2.0 * h0 * m[2])
    step = (-2.0 * hk * m[0], -2.0 * hk * m[1], dz - 2.0 * hk * m[2])
    # the image's height in [z_lo, z_hi]: r0_z - z_lo + step_z k >= 0 and r0_z - z_hi + step_z k <= 0
    k0, k1 = _plane_k_range(r0[2] - z_band[0], step[2], r0[2] - z_band[1], step[2], int(lo), int(hi))
    if k0 > k1:
        return 1, 0
    return _slab_k_range(ta, tb, r0, step, k0, k1)


# Margin (m) of :func:`_images_stay_out`: a ring column is skipped only when its images stay this much short of the box.
# The box's reach (chord_reach) already holds a curved chord's along-tangent offset (_foot_offset_bound); the margin
# is slack for rounding.
RING_TOL_M = 1e-3


@njit_inline
def _images_stay_out(px, py, box_xy, m0, m1, reach):
    """True when no image of column (px, py) can lie in the chord's box of columns box_xy = (x_lo, x_hi, y_lo,
    y_hi) (m): an image r - 2 h n with 0 <= h <= reach moves sideways by at most 2 reach |n_xy| (n_xy = (m0, m1),
    the mirror plane's horizontal normal), and the column is farther than that from the box. :func:`deposit_chord`
    searches one column around the box for images (a tilted ground moves them sideways); on flat ground, and on
    gentle slopes for most columns, none of them can arrive, and the column is skipped before its index range."""
    dx = max(box_xy[0] - px, px - box_xy[1], 0.0)
    dy = max(box_xy[2] - py, py - box_xy[3], 0.0)
    shift = 2.0 * reach * math.sqrt(m0 * m0 + m1 * m1)
    return shift + RING_TOL_M < math.sqrt(dx * dx + dy * dy)


@nb.njit(**NJIT_NO_NRT)
def deposit_chord(grid, acc, slot, chord, scratch, terms):
    """Add the beam of the chord from sample ``sa`` to sample ``sb`` to every grid point it owns, and, where the
    grid has mirror planes (BeamGrid.mirror), its beam at the ground images of the points near the ground to the
    points themselves: the kernel mass a floored beam spreads below the ground comes back (docs/physics.md §11).

    chord : tuple (sa, sb, amp_a, amp_b, group, kmah, launch_cos, tabs, refl_cos, refl_mat, amp0): sa, sb
    (SAMPLE_SIZE,) sample records; amp_a, amp_b (2, F) complex amplitude factor per band at the two samples
    (reflection coefficients, absorption; re in row 0, im in row 1), filled on the chord's first deposit from
    tabs, refl_cos, refl_mat and amp0 (:func:`chord_amplitudes`); group, the arrival group of the chord; kmah,
    caustics passed (the amplitude turns by (-i)^kmah, time factor exp(-i w t)); launch_cos, cos(launch
    elevation) (I / I_1m = launch_cos / J). scratch, terms : unused (the device kernel's work arrays).
    Returns the number of contributions added.

    Search: the chord's box of columns (:func:`chord_box`; for images one column wider each way, since an image
    moves sideways by 2 h sin(slope)); in each column the points between the chord's end planes
    (:func:`_slab_k_range`), then the column's images (points at most the chord's reach above the ground plane,
    whose image lies in the box's height range). Per column the points come first, then the images: each point
    receives its direct term before its image's, as when all points preceded all images.

    Everything a point needs is bound once per chord (the samples and grid constants as tuples of values, the
    accumulator arrays as locals): the per-point code binds no array, so it costs no reference counting; the
    kernel itself is compiled without it (NJIT_NO_NRT: it allocates nothing and keeps no array past the call,
    and counting the ~30 arrays of its arguments cost 8 % of the deposits, docs/physics.md §9).
    """
    sa = chord[0]
    sb = chord[1]
    i0, i1, j0, j1, z_lo, z_hi = chord_box(grid, sa, sb)
    if i0 > i1 or j0 > j1:
        return 0
    ta = sample_values(sa)
    tb = sample_values(sb)
    gc = grid_values(grid)
    launch_cos = chord[6]
    group = chord[4]
    kmah = chord[5]
    amp_a = chord[2]
    amp_b = chord[3]
    mode = grid.mode
    omega = grid.omega
    n_f = omega.shape[0]
    z_offset = grid.z_offset
    mirror = grid.mirror
    ox = grid.origin[0]
    oy = grid.origin[1]
    oz = grid.origin[2]
    sx = grid.spacing[0]
    sy = grid.spacing[1]
    dz = grid.spacing[2]
    nx = grid.shape[0]
    ny = grid.shape[1]
    nz = grid.shape[2]
    weight = acc.weight
    hits = acc.hits
    energy = acc.energy
    near_w = acc.near_w
    near_amp = acc.near_amp
    s_re = acc.s_re
    s_im = acc.s_im
    has_near = near_w.shape[0] > 0
    mirrored = mirror.shape[0] > 0
    reach = 0.5 * (z_hi - z_lo)  # at least the chord's transverse reach
    ci0, ci1, cj0, cj1 = i0, i1, j0, j1
    box_xy = (0.0, 0.0, 0.0, 0.0)
    if mirrored:
        ci0, ci1, cj0, cj1 = max(i0 - 1, 0), min(i1 + 1, nx - 1), max(j0 - 1, 0), min(j1 + 1, ny - 1)
        r_box = z_hi - max(sa[S_X + 2], sb[S_X + 2])  # chord_box's reach
        box_xy = (
            min(sa[S_X], sb[S_X]) - r_box,
            max(sa[S_X], sb[S_X]) + r_box,
            min(sa[S_X + 1], sb[S_X + 1]) - r_box,
            max(sa[S_X + 1], sb[S_X + 1]) + r_box,
        )
    amps_ready = False
    count = 0
    for i in range(ci0, ci1 + 1):
        px = ox + i * sx
        for j in range(cj0, cj1 + 1):
            py = oy + j * sy
            zo = oz + z_offset[i, j]
            k0, k1 = 1, 0
            if i0 <= i <= i1 and j0 <= j <= j1:
                k0, k1 = _index_range(z_lo, z_hi, zo, dz, nz)
                if k0 <= k1:
                    k0, k1 = _slab_k_range(ta, tb, (px, py, zo), (0.0, 0.0, dz), k0, k1)
            m0 = m1 = m2 = m3 = 0.0
            n0, n1 = 1, 0  # the images' index range
            if mirrored:
                m0 = mirror[i, j, 0]
                m1 = mirror[i, j, 1]
                if k0 > k1 and _images_stay_out(px, py, box_xy, m0, m1, reach):
                    continue  # a column of the ring around the box whose images cannot move into it
                m2 = mirror[i, j, 2]
                m3 = mirror[i, j, 3]
                n0, n1 = _image_k_range(ta, tb, px, py, zo, dz, nz, (m0, m1, m2, m3), reach, (z_lo, z_hi))
            # the column's candidates: points k0..k1 (image False), then images n0..n1 (image True), each image
            # tested as beams.mirror_point does (its index range only skips images that cannot be deposited)
            image = k0 > k1
            k = n0 if image else k0
            while True:
                if image:
                    if k > n1:
                        break
                    pz = zo + k * dz
                    h = m0 * px + m1 * py + m2 * pz - m3  # beams.mirror_point
                    if h < 0.0 or h > reach:
                        if pz > zo + 2.0 * reach + dz:
                            break
                        k += 1
                        continue
                    qx = px - 2.0 * h * m0
                    qy = py - 2.0 * h * m1
                    qz = pz - 2.0 * h * m2
                    if qz < z_lo or qz > z_hi:
                        k += 1
                        continue
                else:
                    qx = px
                    qy = py
                    qz = zo + k * dz
                v = (i * ny + j) * nz + k
                if not image and k == k1:
                    image = True
                    k = n0
                else:
                    k += 1
                owned, w, rel_i, u, tau, amp, near = point_beam(ta, tb, gc, launch_cos, qx, qy, qz)
                if not owned:
                    continue
                if not amps_ready:
                    chord_amplitudes(chord)
                    amps_ready = True
                count += 1
                # beams._accumulate, with the arrays bound above
                weight[slot, group, v] += w
                hits[slot, v] += 1.0
                if mode != BEAM_COHERENT:
                    for f in range(n_f):
                        energy[slot, group, f, v] += band_energy(
                            amp_a[0, f], amp_a[1, f], amp_b[0, f], amp_b[1, f], u, w, rel_i
                        )
                    if has_near:
                        near_w[slot, 0, group, v] += near
                        near_w[slot, 1, group, v] += w * rel_i
                        if near > 0.0:
                            for f in range(n_f):
                                near_amp[slot, group, f, v] += band_energy(
                                    amp_a[0, f], amp_a[1, f], amp_b[0, f], amp_b[1, f], u, near, 1.0
                                )
                if mode != BEAM_INCOHERENT:
                    for f in range(n_f):
                        re, im = band_coherent(
                            amp_a[0, f], amp_a[1, f], amp_b[0, f], amp_b[1, f], u, kmah, omega[f], tau, amp
                        )
                        s_re[slot, group, f, v] += re
                        s_im[slot, group, f, v] += im
    return count


@nb.njit(**NJIT_FLAGS)
def points_box(grid, pts, sa, sb):
    """Receiver bins a chord may reach: (i0, i1, j0, j1, k0, k1), inclusive bin index ranges."""
    reach = chord_reach(grid, sa, sb)
    i0, i1 = _index_range(
        min(sa[S_X], sb[S_X]) - reach - pts.bin_size,
        max(sa[S_X], sb[S_X]) + reach,
        pts.bin_origin[0],
        pts.bin_size,
        pts.bin_shape[0],
    )
    j0, j1 = _index_range(
        min(sa[S_X + 1], sb[S_X + 1]) - reach - pts.bin_size,
        max(sa[S_X + 1], sb[S_X + 1]) + reach,
        pts.bin_origin[1],
        pts.bin_size,
        pts.bin_shape[1],
    )
    k0, k1 = _index_range(
        min(sa[S_X + 2], sb[S_X + 2]) - reach - pts.bin_size,
        max(sa[S_X + 2], sb[S_X + 2]) + reach,
        pts.bin_origin[2],
        pts.bin_size,
        pts.bin_shape[2],
    )
    return i0, i1, j0, j1, k0, k1


@nb.njit(**NJIT_NO_NRT)
def deposit_points(grid, acc, pts, slot, chord, scratch, terms):
    """The same for a list of receiver points (BeamPoints: binned on a coarse regular grid)."""
    if pts.xyz.shape[0] == 0:
        return 0
    i0, i1, j0, j1, k0, k1 = points_box(grid, pts, chord[0], chord[1])
    count = 0
    ny = pts.bin_shape[1]
    nz = pts.bin_shape[2]
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            for k in range(k0, k1 + 1):
                b = (i * ny + j) * nz + k
                for e in range(pts.bin_start[b], pts.bin_start[b + 1]):
                    v = pts.bin_items[e]
                    if _point_beam(
                        grid, acc, slot, chord, pts.xyz[v, 0], pts.xyz[v, 1], pts.xyz[v, 2], v, scratch, terms
                    ):
                        count += 1
    return count


class BeamTables(NamedTuple):
    """Per-band tables the per-ray amplitude needs.

    q_table, q_grid : complex spherical-wave coefficient per (material, band) (acoustics.ground.build_q_table;
        materials beyond the table are refused when the job is prepared); alpha : (F,) energy absorption
        coefficient, 1/m (amplitude factor exp(-alpha s / 2)); chord_m : largest chord length, m.
    hessian : (n_cells, 9) the mesh's smooth Hessian of n^2 per cell and its centroid (mesh/hessian.py: the
        beams' paraxial state in the smooth medium, docs/physics.md §11), or (0, 9): the exact kicks of the
        piecewise-linear mesh.
    """

    q_table: np.ndarray
    q_grid: np.ndarray
    alpha: np.ndarray
    chord_m: float
    hessian: np.ndarray


class BeamRay(NamedTuple):
    """Per-ray scratch of the beam field: the last sample and the one being built, with amplitudes.

    last, cur : (SAMPLE_SIZE,); amp_last, amp_cur : (2, F); amp0 : (F,) the ray's own amplitude factor
    (the source's directivity toward its launch direction; ones for an omnidirectional source); ist : (3,) int64 =
    [has a last sample, caustics passed (kmah), sign of the last non-zero det[X1, X2, T] (+1/-1/0)];
    work : (POINT_SCRATCH,), terms : (PB_SIZE,) the work arrays of :func:`point_beam_terms` (allocated once per
    ray here, not per chord).
    """

    last: np.ndarray
    cur: np.ndarray
    amp_last: np.ndarray
    amp_cur: np.ndarray
    ist: np.ndarray
    amp0: np.ndarray
    work: np.ndarray
    terms: np.ndarray


@nb.njit(**NJIT_FLAGS)
def new_ray(n_f):
    return BeamRay(
        np.zeros(SAMPLE_SIZE),
        np.zeros(SAMPLE_SIZE),
        np.zeros((2, n_f)),
        np.zeros((2, n_f)),
        np.zeros(3, np.int64),
        np.ones(n_f),
        np.zeros(WORK_SIZE),
        np.zeros(PB_SIZE),
    )


@nb.njit(**NJIT_FLAGS)
def _amplitude(tabs, arc, n_refl, refl_cos, refl_mat, out):
    """Per-band amplitude factor at arc length ``arc``: product of Q over the ray's reflections times
    exp(-alpha s / 2) (no caustic phase: see deposit_chord's kmah). Each reflection's table cell
    (two logarithms) is found once for all bands; the products are formed in the same order as one
    ``q_lookup`` per band and reflection would (the same numbers)."""
    n_f = out.shape[1]
    for f in range(n_f):
        out[0, f] = math.exp(-0.5 * tabs.alpha[f] * arc)
        out[1, f] = 0.0
    n_cos = tabs.q_table.shape[2]
    n_r = tabs.q_table.shape[3]
    for j in range(min(n_refl, refl_cos.shape[0])):
        mat = refl_mat[j]
        if mat <= 0:
            continue
        ci, tu, cj, tr = _table_cell(tabs.q_grid, n_cos, n_r, refl_cos[j], arc)
        for f in range(n_f):
            qr, qi = q_at_cell(tabs.q_table, mat, f, ci, tu, cj, tr)
            re = out[0, f]
            im = out[1, f]
            out[0, f] = re * qr - im * qi
            out[1, f] = re * qi + im * qr


@nb.njit(**NJIT_FLAGS)
def _sample_amplitude(tabs, sample, amp, refl_cos, refl_mat, amp0):
    """The per-band amplitude (2, F) of a sample record into ``amp``, unless already there (sample[S_AMP]):
    Q of the sample's reflections (its S_NREFL; the ray's reflection arrays only grow), absorption to its
    arc length, the source's directivity amp0 (x 1.0 exactly when omnidirectional)."""
    if sample[S_AMP] != 0.0:
        return
    _amplitude(tabs, sample[S_ARC], int(sample[S_NREFL]), refl_cos, refl_mat, amp)
    for f in range(amp0.shape[0]):
        amp[0, f] *= amp0[f]
        amp[1, f] *= amp0[f]
    sample[S_AMP] = 1.0


@njit_inline
def chord_amplitudes(chord):
    """Fill the amplitudes of both samples of a chord (deposit_chord's tuple) where not yet computed: called
    before a chord's first term is accumulated, so a chord that reaches no point costs no amplitude."""
    # the test first, inline: once both are computed (nearly every point of a chord) no call and none of the
    # reference counts of its six array arguments
    if chord[0][S_AMP] == 0.0:
        _sample_amplitude(chord[7], chord[0], chord[2], chord[8], chord[9], chord[10])
    if chord[1][S_AMP] == 0.0:
        _sample_amplitude(chord[7], chord[1], chord[3], chord[8], chord[9], chord[10])


class Beam(NamedTuple):
    """The beam field of a trace call: the grid (BeamGrid, BeamAcc), the per-band tables, and the receiver
    points (p_grid holds their constants, in BEAM_SEMICOHERENT mode so that both coherent and incoherent
    levels can be formed; p_acc their accumulators; pts their positions)."""

    grid: BeamGrid
    acc: BeamAcc
    tabs: BeamTables
    p_grid: BeamGrid
    p_acc: BeamAcc
    pts: BeamPoints


@njit_inline
def sample_record(ray, x, tangent, time, arc, slow, par, n_refl, start_new):
    """First half of :func:`ray_sample`: fill ``ray.cur`` (caustic count; amplitudes later, on demand:
    :func:`chord_amplitudes`); True when the chord ``ray.last`` -> ``ray.cur`` is to be deposited (the caller
    deposits it, then calls :func:`sample_shift`). n_refl : the ray's reflections so far. Inlined: a call would
    take a reference on each of the ray's arrays, for every sample."""
    cur = ray.cur
    for i in range(3):
        cur[S_X + i] = x[i]
        cur[S_T + i] = tangent[i]
    cur[S_TIME] = time
    cur[S_ARC] = arc
    for i in range(6):
        cur[S_X1 + i] = par[i]
        cur[S_P1 + i] = par[6 + i]
    cur[S_SLOW] = slow
    det = signed_tube(cur)
    sign = 1 if det > 0.0 else (-1 if det < 0.0 else 0)
    if sign != 0:
        # a reflection mirrors the tube (det changes sign without a caustic): a new chord only resets the
        # reference sign
        if ray.ist[2] != 0 and sign != ray.ist[2] and not start_new:
            ray.ist[1] += 1
        ray.ist[2] = sign
    cur[S_JSIGN] = sign
    cur[S_NREFL] = n_refl
    cur[S_AMP] = 0.0  # the amplitudes follow when a chord ending or starting here deposits (chord_amplitudes)
    return ray.ist[0] != 0 and not start_new


@njit_inline
def sample_shift(ray):
    """Second half of :func:`ray_sample`: the current sample becomes the last one."""
    for i in range(SAMPLE_SIZE):
        ray.last[i] = ray.cur[i]
    n_copy = ray.amp_cur.shape[1] if ray.cur[S_AMP] != 0.0 else 0  # amplitudes not computed: nothing to move
    for f in range(n_copy):
        ray.amp_last[0, f] = ray.amp_cur[0, f]
        ray.amp_last[1, f] = ray.amp_cur[1, f]
    ray.ist[0] = 1


@njit_inline
def ray_chord(ray, group, kmah, launch_cos, tabs, refl):
    """The chord tuple of :func:`deposit_chord` for a ray's last chord (``ray.last`` -> ``ray.cur``, BeamRay):
    group, kmah, launch_cos as there; tabs the BeamTables; refl the reflections tuple of :func:`ray_sample`."""
    return (ray.last, ray.cur, ray.amp_last, ray.amp_cur, group, kmah, launch_cos, tabs, refl[1], refl[2], ray.amp0)


@njit_inline
def deposit_sample(beam, slot, ray, refl, grid_near):
    """Deposit the chord ``ray.last`` -> ``ray.cur`` onto the grid (when ``grid_near``: not :func:`chord_far`) and
    the receiver points. refl : as in :func:`ray_sample`. Returns the number of contributions added. Runs only for
    a chord that may reach something. Inlined into ray_sample (its one caller): as a call it passed the whole Beam
    (about 40 arrays, each a struct of 7-13 words) by value, which cost 0.13 of the reduced README job's 0.9 CPU-s
    of deposits (docs/physics.md §9); deposit_chord, which gets only the grid, the slot's accumulators and the
    chord, stays a call."""
    n_refl = refl[0]
    launch_cos = refl[3]
    kmah = ray.ist[1]
    reached = 0
    if grid_near:
        grid = beam.grid
        group = chord_group(grid.n_refl, n_refl, kmah)
        chord = ray_chord(ray, group, kmah, launch_cos, beam.tabs, refl)
        reached = deposit_chord(grid, beam.acc, slot, chord, ray.work, ray.terms)
    if beam.pts.xyz.shape[0] > 0:
        group = chord_group(beam.p_grid.n_refl, n_refl, kmah)
        chord = ray_chord(ray, group, kmah, launch_cos, beam.tabs, refl)
        reached += deposit_points(beam.p_grid, beam.p_acc, beam.pts, slot, chord, ray.work, ray.terms)
    return reached


@njit_inline
def ray_sample(beam, slot, ray, x, tangent, time, arc, slow, par, refl, start_new):
    """Record a sample of the ray and deposit the chord from the previous one (unless start_new).

    x, tangent : (3,) position (m) and unit tangent; time (s), arc (m), slow = 1/c (s/m) there;
    par : (12,) paraxial derivatives (engine/kernels/paraxial.py); refl : tuple (n_refl, refl_cos,
    refl_mat, launch_cos): reflections so far, their incidence cosines and materials, and cos(launch
    elevation). start_new: the sample starts a new chord (launch, or the outgoing side of a reflection).
    Returns the number of points reached.

    Inlined where the traversal samples (about once per chord length of every ray): the sample itself and the
    test whether its chord can reach the grid bind no array in a call; :func:`deposit_sample` (a call that takes
    a reference on each of the beam's arrays) runs only for chords that can reach the grid (one in ten on the
    README job) or when there are receiver points.
    """
    reached = 0
    if sample_record(ray, x, tangent, time, arc, slow, par, refl[0], start_new):
        grid_near = beam.grid.mode != BEAM_OFF and not chord_far(beam.grid, ray.last, ray.cur)
        if grid_near or beam.pts.xyz.shape[0] > 0:
            reached = deposit_sample(beam, slot, ray, refl, grid_near)
    sample_shift(ray)
    return reached


@nb.njit(**NJIT_FLAGS)
def ray_sample_call(beam, slot, ray, x, tangent, time, arc, slow, par, refl, start_new):
    """:func:`ray_sample` as a called function, for the samples taken once per ray (the launch, the end of the
    last segment, the end). Each inlined copy of ray_sample is optimised and emitted again by LLVM (under
    Numba's IR inlining, until 2026-12-05, also typed again: ~1 s each); the per-crossing, per-reflection and
    in-segment samples stay inlined."""
    return ray_sample(beam, slot, ray, x, tangent, time, arc, slow, par, refl, start_new)

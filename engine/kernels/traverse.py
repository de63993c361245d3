"""Algorithm 1 of the paper: analytic ray curves walked cell by cell, parallel over rays.

Per cell: build the curve from the cell's linear media model at the entry point, take the first
exit among the face planes (closed form, or bisection for n-linear), then step into the neighbour
across the exit face, reflect specularly off a reflecting face (T' = T - 2 (T.m) m), or stop at an
open face. A ray stops at exactly ``max_time`` (time equation solved inside the last segment), at a
reflecting face after ``max_reflections`` reflections, at an open face, after ``max_steps`` steps,
or as lost (unphysical media, no consistent exit after nudging, non-finite state). The end state is
an integer status; the Python wrapper turns it into counts (constants.STATUS_NAMES).

Robustness (physics.md section 5): the entry face uses the exact zero constant term; points on or
beyond a face moving outward exit at once (edges and vertices are walked through with zero-length
steps); a ray that finds no exit, or that makes too many zero-length steps in a row, is nudged along
its tangent by NUDGE_REL x cell size and re-located by walking. Nudges are counted per ray.

Optional path recording samples points on the true curves at about every ``dt_sample`` seconds
(interior samples of long segments are evaluated on the curve, not interpolated), plus every
reflection and the end point, into a fixed per-ray slice of the output buffers.

Optional wind (engine/wind.py): each ray sees the effective medium c + u(x) . e with e its horizontal
launch azimuth; the wind's value at each entry point and its exact gradient at the middle of the straight
chord through the cell are added to the cell's model (no per-cell wind arrays).

Kernel contract (structs, not long argument lists): ``trace_rays(mesh, prm, fld, paths, rays, n_slots)``
with mesh a mesh.cells.CellMesh, prm a :class:`RayParams`, fld a field.FieldAcc, paths a
:class:`PathBuffers` and rays a :class:`Rays` (per-ray inputs and the out_state / out_counts outputs,
columns constants.STATE_* / COUNT_*). Tolerances live in engine/constants.py. The steps are plain njit functions, not
``inline="always"``: numba's IR inlining of a function taking these structs, with early returns, keeps a
reference-count update per struct member per call (measured: 40x slower than the plain call, which LLVM
inlines and prunes). One ray's life, in order:

- :func:`_new_ray` builds its :class:`Ray` (state arrays and scratch; per-ray extra state goes here);
- :func:`_step` per segment: :func:`_cell_medium` (the cell's model at x, wind, slide gradient), the
  curve set-up and first exit, then one of :func:`_resolve_stall` (nudge or slide), :func:`_finish_at_time`
  (hook: segment to max_time) or :func:`_advance` (hook: segment to the exit) followed by
  :func:`_cross_face` (hook: into the neighbour), :func:`_reflect` (hook: specular reflection) or the exit;
- :func:`_finish` (hook: the end) deposits the pending field time and writes the outputs.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from bentray.engine.constants import (
    BOUNDARY_OPEN,
    BOUNDARY_REFLECT,
    COUNT_CROSSINGS,
    COUNT_NUDGES,
    COUNT_REFLECTIONS,
    COUNT_SAMPLES,
    COUNT_SIZE,
    COUNT_STATUS,
    COUNT_STEPS,
    FACE_UNUSED,
    GRAZE_COS,
    MAX_NUDGES_IN_A_ROW,
    MAX_WALK,
    MAX_ZERO_STEPS,
    NJIT_FLAGS,
    NUDGE_REL,
    ON_FACE_REL,
    PARALLEL_FLAGS,
    PINGPONG_SLIDE,
    SLIDE_COS,
    SLIDE_DIST_REL,
    STATE_D,
    STATE_LENGTH,
    STATE_TIME,
    STATE_X,
    STATUS_EXITED,
    STATUS_LOST,
    STATUS_REFLECTION_LIMIT,
    STATUS_RUNNING,
    STATUS_STEP_LIMIT,
    STATUS_TIME_LIMIT,
    TINY_STEP_REL,
)
from bentray.engine.kernels import beams, curves, field, paraxial
from bentray.engine.wind import WIND_NONE, effective_quantity

# ---------------------------------------------------------------------------------------------
# Per-ray state (Ray.ns int64, Ray.fs float64). ns[0:COUNT_SIZE] has the out_counts layout
# (constants.COUNT_*: status, reflections, crossings, nudges, steps, samples) and is copied there at the end.
# ---------------------------------------------------------------------------------------------
NS_CELL = COUNT_SIZE  # current cell (-1: the start point is not in the mesh)
NS_ENTRY = COUNT_SIZE + 1  # face of the current cell the ray entered through (-1: none; excluded from the exit)
NS_NUDGE_RUN = COUNT_SIZE + 2  # nudges in a row without a step of positive length
NS_ZERO_RUN = COUNT_SIZE + 3  # zero-length / tiny steps in a row
NS_SLIDE_FACE = COUNT_SIZE + 4  # face the next segment slides along (-1: none)
NS_PREV_CELL = COUNT_SIZE + 5  # cell before the last crossing (ping-pong detection)
NS_PP_RUN = COUNT_SIZE + 6  # crossings back and forth across one face in a row, moving along it
NS_WIND = COUNT_SIZE + 7  # this ray's wind code (WIND_NONE for a vertical launch: no azimuth)
NS_SIZE = COUNT_SIZE + 8
FS_TIME = 0  # travel time (s)
FS_LENGTH = 1  # arc length (m)
FS_T_LAST = 2  # time of the last recorded path sample (s)
FS_SIZE = 3
# final paraxial state written per ray when asked (Rays.out_par): X_el, X_az, P_el, P_az, |p|
PAR_OUT_SIZE = paraxial.PAR_SIZE + 1


class RayParams(NamedTuple):
    """What every ray of one trace call shares (built by tracer.trace).

    curve : CURVE_* code; c_ref : reference speed (m/s); wind_code, wind_params : analytic wind
    (engine/wind.py; WIND_NONE and an empty array: none); max_time : s; max_reflections; max_steps;
    record : path recording on; dt_sample : path sample interval (s).
    """

    curve: int
    c_ref: float
    wind_code: int
    wind_params: np.ndarray
    max_time: float
    max_reflections: int
    max_steps: int
    record: bool
    dt_sample: float


class PathBuffers(NamedTuple):
    """Path sample buffers: ray i owns rows [i * cap, (i + 1) * cap) of pts (m, (N, 3)), t (s), s (m)."""

    pts: np.ndarray
    t: np.ndarray
    s: np.ndarray
    cap: int


class Rays(NamedTuple):
    """Per-ray inputs and outputs, row i for ray i.

    origins, directions : (n, 3) m / any length; start_cells : (n,) int64 (-1: not in the mesh -> lost);
    f_weights : (n, n_f) band powers (n_f may be 0 without field); refl_cos, refl_mat : (n, R) first R
    reflections' incidence cosine and face material (written); out_state : (n, STATE_SIZE) float64,
    out_counts : (n, COUNT_SIZE) int64 (written; columns constants.STATE_* / COUNT_*);
    out_par : (n, PAR_OUT_SIZE) final paraxial state (written), or (0, PAR_OUT_SIZE): not asked for.
    """

    origins: np.ndarray
    directions: np.ndarray
    start_cells: np.ndarray
    f_weights: np.ndarray
    refl_cos: np.ndarray
    refl_mat: np.ndarray
    out_state: np.ndarray
    out_counts: np.ndarray
    out_par: np.ndarray


class RayBeam(NamedTuple):
    """One ray's paraxial state and beam samples (docs/physics.md §10-11).

    par : (12,) X_el, X_az, P_el, P_az; par_tmp : (12,) scratch; p_end : (3,) slowness vector p = n T at
    the end of the current segment; samples : beams.BeamRay; bf : (2,) [|p| = n at the ray's point, cos of
    the launch elevation]; bn : (2,) int [paraxial state on, beam deposits on].
    """

    par: np.ndarray
    par_tmp: np.ndarray
    p_end: np.ndarray
    samples: beams.BeamRay
    bf: np.ndarray
    bn: np.ndarray


class Ray(NamedTuple):
    """One ray in flight: its state (arrays changed in place) and scratch, built by :func:`_new_ray`.

    x, d : (3,) position (m) and unit tangent; fs : (FS_SIZE,) float state; ns : (NS_SIZE,) int state;
    e_wind : (3,) unit horizontal launch azimuth (wind); g : (3,) the gradient the current cell's curve
    is set up with; cs : (curves.CS_SIZE,) curve constants; xn, dn : (3,) segment end; the rest scratch;
    path_base : first path row of this ray; rf : its field.RayField.
    Per-ray extra state (e.g. paraxial derivatives) belongs here: add arrays, fill them in _new_ray.
    """

    x: np.ndarray
    d: np.ndarray
    fs: np.ndarray
    ns: np.ndarray
    e_wind: np.ndarray
    g: np.ndarray
    cs: np.ndarray
    xn: np.ndarray
    dn: np.ndarray
    xs: np.ndarray
    ts: np.ndarray
    g_slide: np.ndarray
    w_grad: np.ndarray
    g_eff: np.ndarray
    g_tmp: np.ndarray
    x_mid: np.ndarray
    path_base: int
    rf: field.RayField
    bm: RayBeam


# ---------------------------------------------------------------------------------------------
# Geometry and media helpers
# ---------------------------------------------------------------------------------------------
@nb.njit(**NJIT_FLAGS)
def _media_at(mesh, cell, x):
    """The cell's traced quantity m at x (its linear model)."""
    ref_point = mesh.ref_point
    gradient = mesh.gradient
    return (
        mesh.media_ref[cell]
        + gradient[cell, 0] * (x[0] - ref_point[cell, 0])
        + gradient[cell, 1] * (x[1] - ref_point[cell, 1])
        + gradient[cell, 2] * (x[2] - ref_point[cell, 2])
    )


@nb.njit(**NJIT_FLAGS)
def _slowness_at(mesh, prm, ray, cell, x):
    """1/c (s/m) of the medium the ray sees at x: the cell's model, plus the wind along e when on."""
    m = _media_at(mesh, cell, x)
    wind = ray.ns[NS_WIND]
    if wind != WIND_NONE:
        m = effective_quantity(
            prm.curve, prm.c_ref, m, mesh.gradient[cell], wind, prm.wind_params, x, ray.e_wind, ray.w_grad, ray.g_tmp
        )
    return curves.slowness(prm.curve, m, prm.c_ref)


@nb.njit(**NJIT_FLAGS)
def _chord_middle(planes, neighbours, x, d, out):
    """Middle of the straight chord from x along d to the cell's boundary, into out (3,); False if none.

    The cell is convex, so the middle lies inside it: the wind gradient sampled there is the cell's
    secant slope along the ray to second order (the entry point's own gradient is only first order).
    """
    best = math.inf
    for f in range(planes.shape[0]):
        if neighbours[f] == FACE_UNUSED:
            continue
        md = planes[f, 0] * d[0] + planes[f, 1] * d[1] + planes[f, 2] * d[2]
        if md > 0.0:
            dist = (planes[f, 3] - planes[f, 0] * x[0] - planes[f, 1] * x[1] - planes[f, 2] * x[2]) / md
            if dist < best:
                best = dist
    if not (best < math.inf):
        return False
    if best < 0.0:
        best = 0.0
    for i in range(3):
        out[i] = x[i] + 0.5 * best * d[i]
    return True


@nb.njit(**NJIT_FLAGS)
def _tangent_face(planes, neighbours, x, d, cell_size):
    """Face of one cell that x lies on and d moves along (the most tangent one), or -1."""
    best = -1
    best_cos = SLIDE_COS
    for f in range(planes.shape[0]):
        if neighbours[f] == FACE_UNUSED:
            continue
        dist = planes[f, 0] * x[0] + planes[f, 1] * x[1] + planes[f, 2] * x[2] - planes[f, 3]
        if abs(dist) > SLIDE_DIST_REL * cell_size:
            continue
        c = abs(planes[f, 0] * d[0] + planes[f, 1] * d[1] + planes[f, 2] * d[2])
        if c <= best_cos:
            best_cos = c
            best = f
    return best


@nb.njit(**NJIT_FLAGS)
def _walk(planes, neighbours, cell, x):
    """Re-locate x by walking from ``cell`` toward the most violated face.

    Returns (cell, outcome): outcome 0 = inside, 1 = beyond an open boundary, 2 = beyond a
    reflecting boundary (x is then projected back onto that plane), 3 = walk did not converge.
    """
    for _ in range(MAX_WALK):
        worst = 0.0
        worst_face = -1
        for f in range(planes.shape[1]):
            if neighbours[cell, f] == FACE_UNUSED:
                continue
            d = planes[cell, f, 0] * x[0] + planes[cell, f, 1] * x[1] + planes[cell, f, 2] * x[2]
            d -= planes[cell, f, 3]
            if d > worst:
                worst = d
                worst_face = f
        if worst_face < 0:
            return cell, 0
        nxt = neighbours[cell, worst_face]
        if nxt >= 0:
            cell = nxt
            continue
        if nxt == BOUNDARY_OPEN:
            return cell, 1
        for i in range(3):
            x[i] -= worst * planes[cell, worst_face, i]
        return cell, 2
    return cell, 3


@nb.njit(**NJIT_FLAGS)
def _nudge(planes, neighbours, cell, x, d, eta):
    """Move x by eta metres along d and re-locate it by walking: (cell, status) with status RUNNING,
    EXITED (beyond an open boundary) or LOST (the walk did not converge)."""
    for i in range(3):
        x[i] += eta * d[i]
    cell, outcome = _walk(planes, neighbours, cell, x)
    if outcome == 1:
        return cell, STATUS_EXITED
    if outcome == 3:
        return cell, STATUS_LOST
    return cell, STATUS_RUNNING


@nb.njit(**NJIT_FLAGS)
def _onto_face(plane, x, d, move_x):
    """Project d (renormalised) and, if move_x, x onto the plane (m, h): the start of a slide."""
    dm = d[0] * plane[0] + d[1] * plane[1] + d[2] * plane[2]
    dist = plane[0] * x[0] + plane[1] * x[1] + plane[2] * x[2] - plane[3]
    for i in range(3):
        if move_x:
            x[i] -= dist * plane[i]
        d[i] -= dm * plane[i]
    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    for i in range(3):
        d[i] /= norm


# ---------------------------------------------------------------------------------------------
# Path recording and field deposit of one ray
# ---------------------------------------------------------------------------------------------
@nb.njit(**NJIT_FLAGS)
def _emit(paths, ray, x, t, s):
    """Record the path sample (x, t, s) if the ray's slice has room."""
    ns = ray.ns
    count = ns[COUNT_SAMPLES]
    if count < paths.cap:
        k = ray.path_base + count
        paths.pts[k, 0] = x[0]
        paths.pts[k, 1] = x[1]
        paths.pts[k, 2] = x[2]
        paths.t[k] = t
        paths.s[k] = s
        ns[COUNT_SAMPLES] = count + 1


@nb.njit(**NJIT_FLAGS)
def _emit_segment(prm, paths, ray, param_end, t_end):
    """Interior samples of the segment from the ray's x, d (set up in ray.cs) to param_end (time t_end),
    evaluated on the curve, when it spans more than dt_sample."""
    t0 = ray.fs[FS_TIME]
    s0 = ray.fs[FS_LENGTH]
    n_int = int((t_end - t0) / prm.dt_sample)
    if n_int > 2 * paths.cap:
        n_int = 2 * paths.cap
    for j in range(1, n_int + 1):
        prm_j = param_end * j / (n_int + 1)
        ds = curves.evaluate(prm.curve, ray.cs, ray.x, ray.d, prm_j, ray.xs, ray.ts)
        tt = t0 + curves.time_at(prm.curve, ray.cs, prm_j, prm.c_ref)
        _emit(paths, ray, ray.xs, tt, s0 + ds)
        ray.fs[FS_T_LAST] = tt


@nb.njit(**NJIT_FLAGS)
def _deposit(prm, fld, ray, m0, param_end, seg_t, seg_s):
    """Field deposit of the segment from the ray's x, d to ray.xn (no-op without field)."""
    if fld.mode != field.FIELD_OFF:
        seg = field.Segment(param_end, ray.fs[FS_TIME], ray.fs[FS_LENGTH], seg_t, seg_s)
        field.deposit_segment(
            fld, ray.rf, ray.ns[COUNT_REFLECTIONS], prm.curve, prm.c_ref, ray.cs, ray.x, ray.d, ray.xn, m0, ray.g, seg
        )


@nb.njit(**NJIT_FLAGS)
def _flush(mesh, prm, fld, ray, cell):
    """Deposit the ray's pending field time at its current point (before a reflection, at the end)."""
    slowness = _slowness_at(mesh, prm, ray, cell, ray.x)
    fs = ray.fs
    field.flush_pending(fld, ray.rf, ray.ns[COUNT_REFLECTIONS], ray.x, ray.d, fs[FS_TIME], fs[FS_LENGTH], slowness)


# ---------------------------------------------------------------------------------------------
# One ray's life: launch, then steps (cell medium, exit, stall / finish at time / advance, then cross,
# reflect or exit) until it stops, then finish. The four places per-ray extra state is updated:
# _advance and _finish_at_time (a segment inside a cell), _cross_face, _reflect, _finish.
# ---------------------------------------------------------------------------------------------
@nb.njit(**NJIT_FLAGS)
def _new_ray(prm, paths, rays, i, acc, beam):
    """Ray i at its launch: unit tangent, start cell, wind azimuth, empty counters, its field state."""
    x = rays.origins[i].copy()
    d = rays.directions[i].copy()
    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    for k in range(3):
        d[k] /= norm
    ns = np.zeros(NS_SIZE, dtype=np.int64)
    ns[COUNT_STATUS] = STATUS_RUNNING
    ns[NS_CELL] = rays.start_cells[i]
    ns[NS_ENTRY] = -1
    ns[NS_SLIDE_FACE] = -1
    ns[NS_PREV_CELL] = -1
    ns[NS_WIND] = WIND_NONE
    # wind: the ray's horizontal launch azimuth e (the effective-sound-speed approximation keeps it for
    # the whole path); a vertical launch has no azimuth and sees no wind (u . e = 0 for every horizontal u)
    e_wind = np.zeros(3)
    if prm.wind_code != WIND_NONE:
        horizontal = math.sqrt(d[0] * d[0] + d[1] * d[1])
        if horizontal > 0.0:
            e_wind[0] = d[0] / horizontal
            e_wind[1] = d[1] / horizontal
            ns[NS_WIND] = prm.wind_code
    rf = field.new_ray_field(rays.f_weights[i], rays.refl_cos[i], rays.refl_mat[i], i, acc)
    deposit_on = beam.grid.mode != beams.BEAM_OFF or beam.pts.xyz.shape[0] > 0
    want_par = rays.out_par.shape[0] > 0
    bm = RayBeam(
        np.zeros(paraxial.PAR_SIZE),
        np.zeros(paraxial.PAR_SIZE),
        np.zeros(3),
        beams.new_ray(beam.grid.omega.shape[0]),
        np.array([1.0, math.sqrt(d[0] * d[0] + d[1] * d[1])]),
        np.array([1 if (deposit_on or want_par) else 0, 1 if deposit_on else 0], dtype=np.int64),
    )
    e3 = np.empty
    return Ray(
        x, d, np.zeros(FS_SIZE), ns, e_wind, e3(3), np.zeros(curves.CS_SIZE), e3(3), e3(3), e3(3), e3(3), e3(3),
        e3(3), e3(3), e3(3), e3(3), i * paths.cap, rf, bm,
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------
# Paraxial state and beam samples (docs/physics.md §10-11; parabolic curve): the hooks below are no-ops
# unless ray.bm.bn[0] (paraxial on) / ray.bm.bn[1] (beam deposits on).
# ---------------------------------------------------------------------------------------------
@nb.njit(**NJIT_FLAGS)
def _beam_sample(prm, beam, ray, x, d, t, s, par, start_new):
    """Record a beam sample at x (tangent d, time t, arc s) and deposit the chord that ends there."""
    bm = ray.bm
    beams.ray_sample(
        beam, ray.rf.acc, bm.samples, x, d, t, s, bm.bf[0] / prm.c_ref, par, ray.ns[COUNT_REFLECTIONS],
        ray.rf.refl_cos, ray.rf.refl_mat, bm.bf[1], start_new,
    )  # fmt: skip


@nb.njit(**NJIT_FLAGS)
def _beam_launch(mesh, prm, beam, ray):
    """Point-source launch derivatives, from n of the start cell's model (with the wind) at the source."""
    bm = ray.bm
    cell = ray.ns[NS_CELL]
    if bm.bn[0] == 0 or cell < 0:
        bm.bn[0] = 0
        bm.bn[1] = 0
        return
    m = _media_at(mesh, cell, ray.x)
    if ray.ns[NS_WIND] != WIND_NONE:
        m = effective_quantity(
            prm.curve, prm.c_ref, m, mesh.gradient[cell], prm.wind_code, prm.wind_params, ray.x, ray.e_wind,
            ray.w_grad, ray.g_eff,
        )  # fmt: skip
    if not (m > 0.0):
        bm.bn[0] = 0
        bm.bn[1] = 0
        return
    bm.bf[0] = math.sqrt(m)
    paraxial.launch(bm.par, ray.d, bm.bf[0])
    if bm.bn[1]:
        _beam_sample(prm, beam, ray, ray.x, ray.d, 0.0, 0.0, bm.par, True)


@nb.njit(**NJIT_FLAGS)
def _p_at(cs, sigma, p_out):
    """Slowness vector p(sigma) = p0 + g sigma / 2 of the parabolic segment into p_out; returns |p| = n."""
    nn = 0.0
    for i in range(3):
        p_out[i] = cs[i] + 0.5 * cs[3 + i] * sigma
        nn += p_out[i] * p_out[i]
    return math.sqrt(nn)


@nb.njit(**NJIT_FLAGS)
def _beam_along(prm, beam, ray, param, ds):
    """A segment from the ray's x, d to param (arc ds): beam samples inside it when it is longer than the
    chord length, then the paraxial state and p carried to its end (ray.x, ray.fs not yet moved)."""
    bm = ray.bm
    if bm.bn[1] and ds > beam.tabs.chord_m:
        n_int = int(ds / beam.tabs.chord_m)
        t0 = ray.fs[FS_TIME]
        s0 = ray.fs[FS_LENGTH]
        for j in range(1, n_int + 1):
            prm_j = param * j / (n_int + 1)
            ds_j = curves.evaluate(prm.curve, ray.cs, ray.x, ray.d, prm_j, ray.xs, ray.ts)
            t_j = t0 + curves.time_at(prm.curve, ray.cs, prm_j, prm.c_ref)
            paraxial.advanced_copy(bm.par, prm_j, bm.par_tmp)
            n_j = _p_at(ray.cs, prm_j, bm.p_end)
            n_keep = bm.bf[0]
            bm.bf[0] = n_j
            _beam_sample(prm, beam, ray, ray.xs, ray.ts, t_j, s0 + ds_j, bm.par_tmp, False)
            bm.bf[0] = n_keep
    paraxial.advance(bm.par, param)
    bm.bf[0] = _p_at(ray.cs, param, bm.p_end)


@nb.njit(**NJIT_FLAGS)
def _beam_exit(mesh, prm, beam, ray, cell, face):
    """The segment ended on ``face``: derivatives on the face; a sample there when the ray reflects or
    leaves, or when the last sample is a chord length behind."""
    bm = ray.bm
    paraxial.onto_face(bm.par, mesh.planes[cell, face], bm.p_end, ray.g)
    if bm.bn[1]:
        fs = ray.fs
        if mesh.neighbours[cell, face] < 0 or fs[FS_LENGTH] - bm.samples.last[beams.S_ARC] >= beam.tabs.chord_m:
            _beam_sample(prm, beam, ray, ray.x, ray.d, fs[FS_TIME], fs[FS_LENGTH], bm.par, False)


@nb.njit(**NJIT_FLAGS)
def _beam_reflect(mesh, prm, beam, ray, cell, face):
    """After a specular reflection: reflected derivatives and a new chord from the reflection point."""
    bm = ray.bm
    paraxial.reflect(bm.par, mesh.planes[cell, face])
    if bm.bn[1]:
        _beam_sample(prm, beam, ray, ray.x, ray.d, ray.fs[FS_TIME], ray.fs[FS_LENGTH], bm.par, True)


@nb.njit(**NJIT_FLAGS)
def _beam_finish(prm, beam, ray, out_par):
    """The last chord, and the final paraxial state when asked for."""
    bm = ray.bm
    fs = ray.fs
    if bm.bn[1] and fs[FS_LENGTH] > bm.samples.last[beams.S_ARC]:
        _beam_sample(prm, beam, ray, ray.x, ray.d, fs[FS_TIME], fs[FS_LENGTH], bm.par, False)
    if out_par.shape[0] > 0:
        for i in range(paraxial.PAR_SIZE):
            out_par[i] = bm.par[i]
        out_par[paraxial.PAR_SIZE] = bm.bf[0] if bm.bn[0] else math.nan


@nb.njit(**NJIT_FLAGS)
def _slide_gradient(mesh, ray, cell, face, wind_on):
    """ray.g for a slide along ``face``: the mean gradient of its two sides without the normal part."""
    g = ray.g
    g_slide = ray.g_slide
    plane = mesh.planes[cell, face]
    nb_cell = mesh.neighbours[cell, face]
    for i in range(3):
        g_slide[i] = g[i]
        if nb_cell >= 0 and not wind_on:
            g_slide[i] = 0.5 * (g[i] + mesh.gradient[nb_cell, i])
    gm = g_slide[0] * plane[0] + g_slide[1] * plane[1] + g_slide[2] * plane[2]
    for i in range(3):
        g[i] = g_slide[i] - gm * plane[i]


@nb.njit(**NJIT_FLAGS)
def _cell_medium(mesh, prm, ray, cell):
    """The traced quantity m0 at x and (into ray.g) the gradient the cell's curve is set up with;
    returns (m0, the face excluded from the exit search).

    With wind, m0 and g become the effective medium's quantity (exact, at x) and its gradient at the
    middle of the straight chord through the cell: the entry point's own gradient would make the per-cell
    model first-order accurate (measured on a log-law wind, errors fell only 3x per 3x thinner layers, and
    10x with the chord middle). The curve, its exit, time_at (which then integrates 1/c_eff: the travel
    time in the moving medium), the nudge slowness and the field deposit all use them.
    """
    x = ray.x
    g = ray.g
    ns = ray.ns
    m0 = _media_at(mesh, cell, x)
    for i in range(3):  # copied, not viewed: a view per step costs two atomic reference-count updates
        g[i] = mesh.gradient[cell, i]
    wind_on = ns[NS_WIND] != WIND_NONE
    if wind_on:
        curve, c_ref, code, wp = prm.curve, prm.c_ref, prm.wind_code, prm.wind_params
        m0 = effective_quantity(curve, c_ref, m0, g, code, wp, x, ray.e_wind, ray.w_grad, ray.g_eff)
        if _chord_middle(mesh.planes[cell], mesh.neighbours[cell], x, ray.d, ray.x_mid):
            m_mid = _media_at(mesh, cell, ray.x_mid)
            effective_quantity(curve, c_ref, m_mid, g, code, wp, ray.x_mid, ray.e_wind, ray.w_grad, ray.g_eff)
        for i in range(3):
            g[i] = ray.g_eff[i]
    exclude = ns[NS_ENTRY]
    slide_face = ns[NS_SLIDE_FACE]
    if slide_face >= 0:
        _slide_gradient(mesh, ray, cell, slide_face, wind_on)
        exclude = slide_face
        ns[NS_SLIDE_FACE] = -1
    return m0, exclude


@nb.njit(**NJIT_FLAGS)
def _resolve_stall(mesh, prm, ray, cell, m0):
    """No consistent exit (rounding at an edge or vertex) or too many zero-length steps: slide along a
    face the ray lies on and moves along, else nudge it NUDGE_REL x cell size along d and re-locate it."""
    ns = ray.ns
    ns[COUNT_NUDGES] += 1
    ns[NS_NUDGE_RUN] += 1
    ns[NS_ZERO_RUN] = 0
    if ns[NS_NUDGE_RUN] > MAX_NUDGES_IN_A_ROW:
        ns[COUNT_STATUS] = STATUS_LOST
        return
    tf = _tangent_face(mesh.planes[cell], mesh.neighbours[cell], ray.x, ray.d, mesh.size[cell])
    if tf >= 0:
        _onto_face(mesh.planes[cell, tf], ray.x, ray.d, True)
        ns[NS_SLIDE_FACE] = tf
        return
    eta = NUDGE_REL * mesh.size[cell]
    ray.fs[FS_TIME] += eta * curves.slowness(prm.curve, m0, prm.c_ref)
    ray.fs[FS_LENGTH] += eta
    cell, status = _nudge(mesh.planes, mesh.neighbours, cell, ray.x, ray.d, eta)
    ns[NS_CELL] = cell
    ns[COUNT_STATUS] = status
    ns[NS_ENTRY] = -1


@nb.njit(**NJIT_FLAGS)
def _finish_at_time(prm, fld, paths, ray, m0, param, beam):
    """The segment reaches max_time before its exit at ``param``: end the ray on the curve at max_time."""
    fs = ray.fs
    t = fs[FS_TIME]
    param_end = curves.param_at_time(prm.curve, ray.cs, prm.max_time - t, param, prm.c_ref)
    ds = curves.evaluate(prm.curve, ray.cs, ray.x, ray.d, param_end, ray.xn, ray.dn)
    if ray.bm.bn[0]:
        _beam_along(prm, beam, ray, param_end, ds)
    _deposit(prm, fld, ray, m0, param_end, prm.max_time - t, ds)
    if prm.record and prm.max_time - t > prm.dt_sample:
        _emit_segment(prm, paths, ray, param_end, prm.max_time)
    for i in range(3):
        ray.x[i] = ray.xn[i]
        ray.d[i] = ray.dn[i]
    fs[FS_TIME] = prm.max_time
    fs[FS_LENGTH] += ds
    ray.ns[COUNT_STATUS] = STATUS_TIME_LIMIT


@nb.njit(**NJIT_FLAGS)
def _advance(prm, fld, paths, ray, m0, param, dt, cell_size, beam):
    """Move the ray along its curve to the exit at ``param`` (travel time dt): field deposit, path samples."""
    ns = ray.ns
    fs = ray.fs
    x = ray.x
    ds = curves.evaluate(prm.curve, ray.cs, x, ray.d, param, ray.xn, ray.dn)
    if ds > TINY_STEP_REL * cell_size:
        ns[NS_ZERO_RUN] = 0
    elif param != 0.0:
        ns[NS_ZERO_RUN] += 1
    if ray.bm.bn[0]:
        _beam_along(prm, beam, ray, param, ds)
    _deposit(prm, fld, ray, m0, param, dt, ds)
    if prm.record and dt > prm.dt_sample:
        _emit_segment(prm, paths, ray, param, fs[FS_TIME] + dt)
    for i in range(3):
        x[i] = ray.xn[i]
        ray.d[i] = ray.dn[i]
    fs[FS_TIME] += dt
    fs[FS_LENGTH] += ds
    if not (math.isfinite(x[0]) and math.isfinite(x[1]) and math.isfinite(x[2])):
        ns[COUNT_STATUS] = STATUS_LOST
        return
    if prm.record and fs[FS_TIME] - fs[FS_T_LAST] >= prm.dt_sample:
        _emit(paths, ray, x, fs[FS_TIME], fs[FS_LENGTH])
        fs[FS_T_LAST] = fs[FS_TIME]
    if param > 0.0:
        ns[NS_NUDGE_RUN] = 0


@nb.njit(**NJIT_FLAGS)
def _cross_face(mesh, ray, cell, face, nxt):
    """Step into neighbour ``nxt`` across ``face``, or slide along the face after PINGPONG_SLIDE
    crossings back and forth across it while moving along it (a zero-width channel of the medium)."""
    ns = ray.ns
    d = ray.d
    plane = mesh.planes[cell, face]
    dm = d[0] * plane[0] + d[1] * plane[1] + d[2] * plane[2]
    if nxt == ns[NS_PREV_CELL] and abs(dm) <= SLIDE_COS:
        ns[NS_PP_RUN] += 1
    else:
        ns[NS_PP_RUN] = 0
    if ns[NS_PP_RUN] >= PINGPONG_SLIDE:
        _onto_face(plane, ray.x, d, False)
        ns[NS_SLIDE_FACE] = face
        ns[NS_PP_RUN] = 0
        ns[COUNT_NUDGES] += 1
        return
    ns[NS_PREV_CELL] = cell
    ns[NS_ENTRY] = mesh.neighbour_face[cell, face]
    ns[NS_CELL] = nxt
    ns[COUNT_CROSSINGS] += 1


@nb.njit(**NJIT_FLAGS)
def _reflect(mesh, prm, fld, paths, ray, cell, face, param, beam):
    """Specular reflection off reflecting ``face`` (T' = T - 2 (T.m) m), or the reflection limit, or a
    slide along the face when the ray sits on it tangentially (|d . m| <= GRAZE_COS at a zero step)."""
    ns = ray.ns
    d = ray.d
    fs = ray.fs
    plane = mesh.planes[cell, face]
    dot = d[0] * plane[0] + d[1] * plane[1] + d[2] * plane[2]
    if param == 0.0 and abs(dot) <= GRAZE_COS:
        # on the boundary, moving along it and curving into it: the limit of vanishing bounces is
        # creeping along the surface; slide (no reflection: the direction would not change)
        ns[NS_SLIDE_FACE] = face
        ns[NS_ENTRY] = -1
        return
    reflections = ns[COUNT_REFLECTIONS]
    if reflections >= prm.max_reflections:
        ns[COUNT_STATUS] = STATUS_REFLECTION_LIMIT
        return
    material = mesh.face_material[cell, face]
    if fld.mode != field.FIELD_OFF:  # time gathered before the reflection belongs to the incoming ray
        _flush(mesh, prm, fld, ray, cell)
        if material > 0:
            ray.rf.fst[2] = -1.0  # a soft reflection: re-evaluate the ground factors
    if reflections < ray.rf.refl_cos.shape[0]:
        ray.rf.refl_cos[reflections] = abs(dot)
        ray.rf.refl_mat[reflections] = material
    for i in range(3):
        d[i] -= 2.0 * dot * plane[i]
    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    for i in range(3):
        d[i] /= norm
    ns[COUNT_REFLECTIONS] = reflections + 1
    ns[NS_ENTRY] = face
    if ray.bm.bn[0]:
        _beam_reflect(mesh, prm, beam, ray, cell, face)
    if prm.record and fs[FS_TIME] > fs[FS_T_LAST]:
        _emit(paths, ray, ray.x, fs[FS_TIME], fs[FS_LENGTH])
        fs[FS_T_LAST] = fs[FS_TIME]


@nb.njit(**NJIT_FLAGS)
def _step(mesh, prm, fld, paths, ray, beam):
    """One segment: the cell's curve from x, its first exit, then stall, time limit or advance + exit."""
    ns = ray.ns
    if ns[COUNT_STEPS] >= prm.max_steps:
        ns[COUNT_STATUS] = STATUS_STEP_LIMIT
        return
    ns[COUNT_STEPS] += 1
    cell = ns[NS_CELL]
    m0, exclude = _cell_medium(mesh, prm, ray, cell)
    if not curves.setup(prm.curve, m0, ray.g, ray.d, ray.cs):
        ns[COUNT_STATUS] = STATUS_LOST
        return
    if ray.bm.bn[0]:  # the segment restarts from this cell's model at x: p' = n'(x) d
        n_new = math.sqrt(m0)
        paraxial.restart(ray.bm.par, ray.d, ray.bm.bf[0], n_new, ray.g)
        ray.bm.bf[0] = n_new
    cell_size = mesh.size[cell]
    planes = mesh.planes[cell]
    face, param = curves.find_exit(
        prm.curve, ray.cs, ray.x, ray.d, planes, mesh.neighbours[cell], exclude, ON_FACE_REL * cell_size, cell_size
    )
    if face < 0:
        param = curves.interior_step(prm.curve, ray.cs)  # circular: a quarter turn inside the cell
    if param == 0.0:
        ns[NS_ZERO_RUN] += 1
    if (face < 0 and not math.isfinite(param)) or ns[NS_ZERO_RUN] > MAX_ZERO_STEPS:
        _resolve_stall(mesh, prm, ray, cell, m0)
        return
    dt = curves.time_at(prm.curve, ray.cs, param, prm.c_ref)
    if not (dt >= 0.0):
        ns[COUNT_STATUS] = STATUS_LOST
        return
    if ray.fs[FS_TIME] + dt >= prm.max_time:
        _finish_at_time(prm, fld, paths, ray, m0, param, beam)
        if ray.bm.bn[1]:
            _beam_sample(prm, beam, ray, ray.x, ray.d, ray.fs[FS_TIME], ray.fs[FS_LENGTH], ray.bm.par, False)
        return
    _advance(prm, fld, paths, ray, m0, param, dt, cell_size, beam)
    if ns[COUNT_STATUS] != STATUS_RUNNING:
        return
    if face < 0:
        ns[NS_ENTRY] = -1  # within-cell step (circular quarter turn): same cell, no entry face
        return
    if ray.bm.bn[0]:
        _beam_exit(mesh, prm, beam, ray, cell, face)
    nxt = mesh.neighbours[cell, face]
    if nxt >= 0:
        _cross_face(mesh, ray, cell, face, nxt)
    elif nxt == BOUNDARY_REFLECT:
        _reflect(mesh, prm, fld, paths, ray, cell, face, param, beam)
    else:
        ns[COUNT_STATUS] = STATUS_EXITED


@nb.njit(**NJIT_FLAGS)
def _finish(mesh, prm, fld, paths, ray, out_state, out_counts, beam, out_par):
    """The ray has stopped: deposit its pending field time, record the end point, write its outputs."""
    ns = ray.ns
    fs = ray.fs
    cell = ns[NS_CELL]
    if fld.mode != field.FIELD_OFF and cell >= 0:
        _flush(mesh, prm, fld, ray, cell)
    if prm.record and (ns[COUNT_SAMPLES] == 0 or fs[FS_TIME] > fs[FS_T_LAST]):
        _emit(paths, ray, ray.x, fs[FS_TIME], fs[FS_LENGTH])
    if ray.bm.bn[0] or out_par.shape[0] > 0:
        _beam_finish(prm, beam, ray, out_par)
    for i in range(3):
        out_state[STATE_X + i] = ray.x[i]
        out_state[STATE_D + i] = ray.d[i]
    out_state[STATE_TIME] = fs[FS_TIME]
    out_state[STATE_LENGTH] = fs[FS_LENGTH]
    for k in range(COUNT_SIZE):
        out_counts[k] = ns[k]


@nb.njit(**NJIT_FLAGS)
def trace_one(mesh, prm, fld, paths, rays, i, acc, beam):
    """Trace ray i (rays.origins[i], rays.directions[i] from rays.start_cells[i]) to its end state.

    mesh : CellMesh; prm : RayParams; fld : field.FieldAcc (mode FIELD_OFF: no accumulation), written in
    accumulator slot ``acc``; paths : PathBuffers (ray i's slice); rays : Rays (row i read and written).
    """
    ray = _new_ray(prm, paths, rays, i, acc, beam)
    if prm.record:
        _emit(paths, ray, ray.x, 0.0, 0.0)
    if ray.ns[NS_CELL] < 0:
        ray.ns[COUNT_STATUS] = STATUS_LOST
    _beam_launch(mesh, prm, beam, ray)
    while ray.ns[COUNT_STATUS] == STATUS_RUNNING:
        _step(mesh, prm, fld, paths, ray, beam)
    out_par = rays.out_par[i] if rays.out_par.shape[0] > 0 else rays.out_par.reshape(-1)
    _finish(mesh, prm, fld, paths, ray, rays.out_state[i], rays.out_counts[i], beam, out_par)


@nb.njit(**PARALLEL_FLAGS)
def trace_rays(mesh, prm, fld, paths, rays, n_slots, b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts):
    """Trace all rays in parallel (prange over ``n_slots`` accumulator slots, rays interleaved).

    Ray i owns row i of every ``rays`` array and the path slice ``[i * paths.cap, (i + 1) * paths.cap)``;
    field accumulator slot ``i % n_slots`` is only written by the one thread running that slot. For a
    fixed n_slots the results are deterministic. b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts : the beam
    field and the receiver points (beams.Beam; BEAM_OFF in b_grid.mode and no points: none; passed apart
    because a parallel kernel does not take nested structs).
    """
    n = rays.origins.shape[0]
    for slot in nb.prange(n_slots):
        for i in range(slot, n, n_slots):
            trace_one(mesh, prm, fld, paths, rays, i, slot, beams.Beam(b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts))

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
columns constants.STATE_* / COUNT_*); the ray's own field state is one field.RayField. Tolerances live in
engine/constants.py. One ray's life (trace_one) reads as its steps: ``_launch`` (wind azimuth, paraxial
launch), ``_walk_cells`` (per cell: the medium, with wind ``_wind_medium``; a slide ``_slide_gradient``; the
curve and its first exit; a stall ``_resolve_stall``; the last segment ``_finish_at_max_time``; the segment
inside the cell with ``_segment_hooks``; the crossing into the neighbour; ``_reflect``) and ``_write_out``.
The steps are ``inline="always"`` (numba inlines them before typing, so the loop compiles as one function:
the same machine code as one long loop, no call and no reference counting per step; an earlier split into
called functions over a per-ray state struct measured 2.3-2.8x slower). Per-ray state: the work arrays of
:class:`RayWork`, the fixed per-ray context :class:`RayCtx` (its counters are the ray's out_counts row,
updated in place), and the hot scalars (cell, t, s, entry, stall counters) as locals of ``_walk_cells``.
The places where per-ray extra state (paraxial derivatives, beam deposit) is updated are marked ``HOOK
(a)`` (after each segment inside a cell, also the last one at max_time), ``HOOK (b)`` (face crossing into
a neighbour), ``HOOK (c)`` (specular reflection) and ``HOOK (d)`` (the end).
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
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.wind import WIND_NONE, effective_quantity


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


# final paraxial state written per ray when asked (Rays.out_par): X_el, X_az, P_el, P_az, |p|
PAR_OUT_SIZE = paraxial.PAR_SIZE + 1


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


class RayWork(NamedTuple):
    """One ray's work arrays (float64; (3,) unless noted), allocated once per ray (_new_work).

    x, d : position (m) and unit tangent; xn, dn : the end of the current segment; xs, ts : a point and
    tangent on the curve (samples); cs : (curves.CS_SIZE,) the current cell's curve; g : the gradient the
    curve is set up with; g_slide : its scratch while sliding; x_mid : the middle of the straight chord
    (wind); e_wind : the horizontal launch azimuth (zeros without wind); w_grad, g_eff, g_tmp : wind
    scratch; par, par_tmp : (paraxial.PAR_SIZE,) paraxial derivatives and a copy advanced inside a
    segment; p_end : the slowness vector at a segment's end; f : (2,) [F_T_LAST: time of the last path
    sample (s), F_P_NORM: |p| = n at x (1.0 until the paraxial launch)].
    """

    x: np.ndarray
    d: np.ndarray
    xn: np.ndarray
    dn: np.ndarray
    xs: np.ndarray
    ts: np.ndarray
    cs: np.ndarray
    g: np.ndarray
    g_slide: np.ndarray
    x_mid: np.ndarray
    e_wind: np.ndarray
    w_grad: np.ndarray
    g_eff: np.ndarray
    g_tmp: np.ndarray
    par: np.ndarray
    par_tmp: np.ndarray
    p_end: np.ndarray
    f: np.ndarray


F_T_LAST = 0
F_P_NORM = 1


class RayCtx(NamedTuple):
    """What one ray fixes at its launch (_launch).

    i : its row in Rays; acc : its accumulator slot; base : first row of its path slice; wind : the WIND_*
    code it sees (WIND_NONE without wind or for a vertical launch); f_on : field accumulation on; par_on :
    paraxial state carried; deposit_on : beam samples taken; rf : field.RayField; bray : beams.BeamRay;
    cnt : (COUNT_SIZE,) int64, its out_counts row (reflections, crossings, nudges, steps, samples counted
    in place; the status written at the end).
    """

    i: int
    acc: int
    base: int
    wind: int
    f_on: bool
    par_on: bool
    deposit_on: bool
    rf: field.RayField
    bray: beams.BeamRay
    cnt: np.ndarray


class Job(NamedTuple):
    """What every step of every ray of one trace call reads: the mesh (CellMesh), prm (RayParams), the field
    accumulators (field.FieldAcc), the path buffers (PathBuffers) and the beam field (beams.Beam)."""

    mesh: CellMesh
    prm: RayParams
    fld: field.FieldAcc
    paths: PathBuffers
    beam: beams.Beam


@nb.njit(**NJIT_FLAGS)
def _media_at(media_ref, ref_point, gradient, cell, x):
    return (
        media_ref[cell]
        + gradient[cell, 0] * (x[0] - ref_point[cell, 0])
        + gradient[cell, 1] * (x[1] - ref_point[cell, 1])
        + gradient[cell, 2] * (x[2] - ref_point[cell, 2])
    )


@nb.njit(inline="always", **NJIT_FLAGS)
def _slowness_at(mesh, prm, w, cell, wind):
    """1/c (s/m) of the medium the ray sees at w.x: the cell's model, plus the wind along w.e_wind when on."""
    m = _media_at(mesh.media_ref, mesh.ref_point, mesh.gradient, cell, w.x)
    if wind != WIND_NONE:
        m = effective_quantity(prm.curve, prm.c_ref, m, mesh.gradient[cell], wind, prm.wind_params, w.x, w.e_wind,
                               w.w_grad, w.g_tmp)  # fmt: skip
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


@nb.njit(**NJIT_FLAGS)
def _emit(paths, cnt, base, x, t, s):
    """Path sample (x (3,) m, t s, s m) into row base + cnt[COUNT_SAMPLES] of paths, while the slice has room."""
    count = cnt[COUNT_SAMPLES]
    if count < paths.cap:
        k = base + count
        paths.pts[k, 0] = x[0]
        paths.pts[k, 1] = x[1]
        paths.pts[k, 2] = x[2]
        paths.t[k] = t
        paths.s[k] = s
        cnt[COUNT_SAMPLES] = count + 1


@nb.njit(inline="always", **NJIT_FLAGS)
def _emit_segment(prm, paths, ray, w, param_end, t0, s0, t_end):
    """Interior samples of a segment from time t0 (s), arc s0 (m) to t_end spanning more than dt_sample
    (evaluated on the curve w.cs from w.x, w.d at parameters j param_end / (n + 1)); w.f[F_T_LAST] follows."""
    n_int = int((t_end - t0) / prm.dt_sample)
    if n_int > 2 * paths.cap:
        n_int = 2 * paths.cap
    for j in range(1, n_int + 1):
        pj = param_end * j / (n_int + 1)
        ds = curves.evaluate(prm.curve, w.cs, w.x, w.d, pj, w.xs, w.ts)
        tt = t0 + curves.time_at(prm.curve, w.cs, pj, prm.c_ref)
        _emit(paths, ray.cnt, ray.base, w.xs, tt, s0 + ds)
        w.f[F_T_LAST] = tt


@nb.njit(**NJIT_FLAGS)
def _p_at(cs, sigma, p_out):
    """Slowness vector p(sigma) = p0 + g sigma / 2 of the parabolic segment into p_out; returns |p| = n."""
    nn = 0.0
    for i in range(3):
        p_out[i] = cs[i] + 0.5 * cs[3 + i] * sigma
        nn += p_out[i] * p_out[i]
    return math.sqrt(nn)


@nb.njit(inline="always", **NJIT_FLAGS)
def _beam_segment(prm, beam, ray, w, param, t, s, ds):
    """Beam samples inside a segment (parameter 0 .. param from time t, arc s; ds m long) longer than the
    chord length: on the curve, uniform in sigma (w.xs, w.ts, w.par_tmp, w.p_end are overwritten)."""
    chord = beam.tabs.chord_m
    if ds <= chord:
        return
    n_int = int(ds / chord)
    for j in range(1, n_int + 1):
        pj = param * j / (n_int + 1)
        dsj = curves.evaluate(prm.curve, w.cs, w.x, w.d, pj, w.xs, w.ts)
        tj = t + curves.time_at(prm.curve, w.cs, pj, prm.c_ref)
        paraxial.advanced_copy(w.par, pj, w.par_tmp)
        nj = _p_at(w.cs, pj, w.p_end)
        beams.ray_sample(beam, ray.acc, ray.bray, w.xs, w.ts, tj, s + dsj, nj / prm.c_ref, w.par_tmp,
                         ray.cnt[COUNT_REFLECTIONS], False)  # fmt: skip


@nb.njit(inline="always", **NJIT_FLAGS)
def _new_work(x0, d0):
    """Fresh RayWork starting at x0 (3,) m along d0 (3,) (normalised here)."""
    x = x0.copy()
    d = d0.copy()
    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    for k in range(3):
        d[k] /= norm
    e = np.empty(3)  # (a name per scratch array would not read better: RayWork names them)
    return RayWork(x, d, np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.zeros(curves.CS_SIZE), np.empty(3),
                   np.empty(3), np.empty(3), np.zeros(3), np.empty(3), np.empty(3), e, np.zeros(paraxial.PAR_SIZE),
                   np.zeros(paraxial.PAR_SIZE), np.zeros(3), np.array([0.0, 1.0]))  # fmt: skip


@nb.njit(inline="always", **NJIT_FLAGS)
def _ray_wind(prm, w):
    """The wind code this ray sees, with its horizontal launch azimuth e into w.e_wind (the effective-sound-
    speed approximation keeps e for the whole path); a vertical launch has no azimuth and sees no wind
    (u . e = 0 for every horizontal u): WIND_NONE."""
    if prm.wind_code == WIND_NONE:
        return WIND_NONE
    d = w.d
    horizontal = math.sqrt(d[0] * d[0] + d[1] * d[1])
    if not (horizontal > 0.0):
        return WIND_NONE
    w.e_wind[0] = d[0] / horizontal
    w.e_wind[1] = d[1] / horizontal
    return prm.wind_code


@nb.njit(inline="always", **NJIT_FLAGS)
def _launch(mesh, prm, fld, beam, rays, i, acc, cap, w):
    """RayCtx of ray i (accumulator slot acc, path slice from row i * cap), with w (RayWork from _new_work) set
    up: wind azimuth, the paraxial launch and the beam's first sample (docs/physics.md §10-11) when asked for
    and physical; the ray's counters (rays.out_counts[i]) zeroed."""
    cell = rays.start_cells[i]
    wind = _ray_wind(prm, w)
    cnt = rays.out_counts[i]
    for k in range(cnt.shape[0]):
        cnt[k] = 0
    rf = field.new_ray_field(rays.f_weights[i], rays.refl_cos[i], rays.refl_mat[i], i, acc)
    launch_cos = math.sqrt(w.d[0] * w.d[0] + w.d[1] * w.d[1])
    bray = beams.new_ray(beam.grid.omega.shape[0], rays.refl_cos[i], rays.refl_mat[i], launch_cos)
    deposit_on = beam.grid.mode != beams.BEAM_OFF or beam.pts.xyz.shape[0] > 0
    par_on = (deposit_on or rays.out_par.shape[0] > 0) and cell >= 0
    if par_on:
        m_start = _media_at(mesh.media_ref, mesh.ref_point, mesh.gradient, cell, w.x)
        if wind != WIND_NONE:
            m_start = effective_quantity(prm.curve, prm.c_ref, m_start, mesh.gradient[cell], wind, prm.wind_params,
                                         w.x, w.e_wind, w.w_grad, w.g_eff)  # fmt: skip
        if m_start > 0.0:
            w.f[F_P_NORM] = math.sqrt(m_start)
            paraxial.launch(w.par, w.d, w.f[F_P_NORM])
            if deposit_on:
                beams.ray_sample(beam, acc, bray, w.x, w.d, 0.0, 0.0, w.f[F_P_NORM] / prm.c_ref, w.par, 0, True)
        else:
            par_on = False
    return RayCtx(i, acc, i * cap, wind, fld.mode != field.FIELD_OFF, par_on, deposit_on and par_on,
                  rf, bray, cnt)  # fmt: skip


@nb.njit(inline="always", **NJIT_FLAGS)
def _wind_medium(mesh, prm, w, cell, wind, m0):
    """The effective medium c + u . e in cell ``cell`` at w.x: returns its traced quantity (exact, at x) and
    sets w.g to its gradient at the middle of the straight chord through the cell (w.g holds the cell's own
    gradient on entry). The entry point's own gradient would make the per-cell model first-order accurate;
    measured on a log-law wind, errors fell only 3x per 3x thinner layers, and 10x with the chord middle.
    The curve, its exit, time_at (which then integrates 1/c_eff: the travel time in the moving medium), the
    nudge slowness and the field deposit all use them."""
    m0 = effective_quantity(prm.curve, prm.c_ref, m0, w.g, wind, prm.wind_params, w.x, w.e_wind, w.w_grad, w.g_eff)
    if _chord_middle(mesh.planes[cell], mesh.neighbours[cell], w.x, w.d, w.x_mid):
        m_mid = _media_at(mesh.media_ref, mesh.ref_point, mesh.gradient, cell, w.x_mid)
        effective_quantity(prm.curve, prm.c_ref, m_mid, w.g, wind, prm.wind_params, w.x_mid, w.e_wind, w.w_grad,
                           w.g_eff)  # fmt: skip
    for k in range(3):
        w.g[k] = w.g_eff[k]
    return m0


@nb.njit(inline="always", **NJIT_FLAGS)
def _slide_gradient(mesh, w, cell, face, wind_on):
    """Sliding along ``face``: w.g becomes the mean gradient of the two sides (without wind; with wind the
    cell's own) without its normal part, so the curve stays in the face plane."""
    planes = mesh.planes
    g = w.g
    g_slide = w.g_slide
    nb_cell = mesh.neighbours[cell, face]
    for k in range(3):
        g_slide[k] = g[k]
        if nb_cell >= 0 and not wind_on:
            g_slide[k] = 0.5 * (g[k] + mesh.gradient[nb_cell, k])
    gm = g_slide[0] * planes[cell, face, 0] + g_slide[1] * planes[cell, face, 1] + g_slide[2] * planes[cell, face, 2]
    for k in range(3):
        g[k] = g_slide[k] - gm * planes[cell, face, k]


@nb.njit(inline="always", **NJIT_FLAGS)
def _cell_medium(mesh, prm, w, cell, wind, entry, slide_face):
    """The traced quantity at w.x (returned) and the gradient w.g of the curve in ``cell``: the cell's model,
    with wind the effective medium, and sliding along ``slide_face`` (>= 0) its in-plane part. Returns
    (m0, the face the exit search excludes: the slide face, else the entry face)."""
    gradient = mesh.gradient
    m0 = _media_at(mesh.media_ref, mesh.ref_point, gradient, cell, w.x)
    for k in range(3):  # copied, not viewed: a view per step costs two atomic reference-count updates
        w.g[k] = gradient[cell, k]
    if wind != WIND_NONE:
        m0 = _wind_medium(mesh, prm, w, cell, wind, m0)
    if slide_face >= 0:
        _slide_gradient(mesh, w, cell, slide_face, wind != WIND_NONE)
        return m0, slide_face
    return m0, entry


@nb.njit(inline="always", **NJIT_FLAGS)
def _restart_paraxial(w, m0):
    """The segment restarts from the cell's model at x: p' = n'(x) d (docs/physics.md §10); w.f[F_P_NORM]
    becomes n'(x) = sqrt(m0)."""
    n_new = math.sqrt(m0)
    paraxial.restart(w.par, w.d, w.f[F_P_NORM], n_new, w.g)
    w.f[F_P_NORM] = n_new


@nb.njit(inline="always", **NJIT_FLAGS)
def _cross_face(mesh, w, cnt, cell, face, entry, prev_cell, pp_run):
    """Into the neighbour across ``face`` of ``cell`` (a crossing counted in cnt), unless the ray has zig-
    zagged across this face PINGPONG_SLIDE times in a row while moving along it: then it slides along the
    face in the current cell (counted as a nudge). Returns (cell, entry, prev_cell, pp_run, slide_face)."""
    planes = mesh.planes
    d = w.d
    nxt = mesh.neighbours[cell, face]
    dm = d[0] * planes[cell, face, 0] + d[1] * planes[cell, face, 1] + d[2] * planes[cell, face, 2]
    pp_run = pp_run + 1 if nxt == prev_cell and abs(dm) <= SLIDE_COS else 0
    if pp_run >= PINGPONG_SLIDE:
        _onto_face(planes[cell, face], w.x, d, False)
        cnt[COUNT_NUDGES] += 1
        return cell, entry, prev_cell, 0, face
    cnt[COUNT_CROSSINGS] += 1
    return nxt, mesh.neighbour_face[cell, face], cell, pp_run, -1


@nb.njit(inline="always", **NJIT_FLAGS)
def _resolve_stall(mesh, prm, w, cnt, cell, m0, entry, t, s, nudge_run):
    """No consistent exit (rounding at an edge or vertex, or too many zero-length steps): slide along the
    face x lies on and d moves along, else nudge x by NUDGE_REL x cell size along d and re-locate it.

    Counts a nudge; more than MAX_NUDGES_IN_A_ROW in a row: lost. Returns (cell, status, slide_face, entry,
    t, s, nudge_run) with t (s), s (m) advanced by the nudge.
    """
    cnt[COUNT_NUDGES] += 1
    nudge_run += 1
    if nudge_run > MAX_NUDGES_IN_A_ROW:
        return cell, STATUS_LOST, -1, entry, t, s, nudge_run
    tf = _tangent_face(mesh.planes[cell], mesh.neighbours[cell], w.x, w.d, mesh.size[cell])
    if tf >= 0:
        _onto_face(mesh.planes[cell, tf], w.x, w.d, True)
        return cell, STATUS_RUNNING, tf, entry, t, s, nudge_run
    eta = NUDGE_REL * mesh.size[cell]
    t += eta * curves.slowness(prm.curve, m0, prm.c_ref)
    s += eta
    cell, status = _nudge(mesh.planes, mesh.neighbours, cell, w.x, w.d, eta)
    return cell, status, -1, -1, t, s, nudge_run


@nb.njit(inline="always", **NJIT_FLAGS)
def _paraxial_segment(prm, beam, ray, w, param, t, s, ds):
    """HOOK (a), paraxial: the beam samples inside the segment, then the derivatives and |p| at its end."""
    if ray.deposit_on:
        _beam_segment(prm, beam, ray, w, param, t, s, ds)
    paraxial.advance(w.par, param)
    w.f[F_P_NORM] = _p_at(w.cs, param, w.p_end)


@nb.njit(inline="always", **NJIT_FLAGS)
def _segment_hooks(job, ray, w, cell, face, param, t, s, dt, ds, m0):
    """HOOK (a): a segment inside the cell (parameter 0 .. param, from time t, arc s; dt s, ds m long,
    ending at w.xn, w.dn on ``face``, -1 for a within-cell step): paraxial derivatives and beam samples,
    field deposit and path samples, before x moves on."""
    prm = job.prm
    n_refl = ray.cnt[COUNT_REFLECTIONS]
    if ray.par_on:  # derivatives at the segment's end, on its face
        _paraxial_segment(prm, job.beam, ray, w, param, t, s, ds)
        if face >= 0:
            paraxial.onto_face(w.par, job.mesh.planes[cell, face], w.p_end, w.g, math.inf)
            chord_done = s + ds - ray.bray.last[beams.S_ARC] >= job.beam.tabs.chord_m
            if ray.deposit_on and (job.mesh.neighbours[cell, face] < 0 or chord_done):
                beams.ray_sample(job.beam, ray.acc, ray.bray, w.xn, w.dn, t + dt, s + ds, w.f[F_P_NORM] / prm.c_ref,
                                 w.par, n_refl, False)  # fmt: skip
    if ray.f_on:
        seg = field.Segment(param, t, s, dt, ds)
        field.deposit_segment(job.fld, ray.rf, n_refl, prm.curve, prm.c_ref, w.cs, w.x, w.d, w.xn, m0, w.g, seg)
    if prm.record and dt > prm.dt_sample:
        _emit_segment(prm, job.paths, ray, w, param, t, s, t + dt)


@nb.njit(inline="always", **NJIT_FLAGS)
def _finish_at_max_time(job, ray, w, param, t, s, m0):
    """The last segment, to exactly max_time (the time equation solved inside it), with its HOOK (a):
    x, d move to its end; returns the arc length there (m)."""
    prm = job.prm
    max_time = prm.max_time
    n_refl = ray.cnt[COUNT_REFLECTIONS]
    param_end = curves.param_at_time(prm.curve, w.cs, max_time - t, param, prm.c_ref)
    ds = curves.evaluate(prm.curve, w.cs, w.x, w.d, param_end, w.xn, w.dn)
    if ray.par_on:
        _paraxial_segment(prm, job.beam, ray, w, param_end, t, s, ds)
        if ray.deposit_on:
            beams.ray_sample(job.beam, ray.acc, ray.bray, w.xn, w.dn, max_time, s + ds, w.f[F_P_NORM] / prm.c_ref,
                             w.par, n_refl, False)  # fmt: skip
    if ray.f_on:
        seg = field.Segment(param_end, t, s, max_time - t, ds)
        field.deposit_segment(job.fld, ray.rf, n_refl, prm.curve, prm.c_ref, w.cs, w.x, w.d, w.xn, m0, w.g, seg)
    if prm.record and max_time - t > prm.dt_sample:
        _emit_segment(prm, job.paths, ray, w, param_end, t, s, max_time)
    for k in range(3):
        w.x[k] = w.xn[k]
        w.d[k] = w.dn[k]
    return s + ds


@nb.njit(inline="always", **NJIT_FLAGS)
def _reflect(job, ray, w, cell, face, param, t, s, entry):
    """At a reflecting ``face`` of ``cell`` (x on it): specular reflection T' = T - 2 (T.m) m with its
    HOOK (c), or a slide when the ray sits on the face tangent to it and curving into it, or the end at
    max_reflections. Returns (status, entry, slide_face)."""
    mesh = job.mesh
    prm = job.prm
    planes = mesh.planes
    d = w.d
    cnt = ray.cnt
    dot = d[0] * planes[cell, face, 0] + d[1] * planes[cell, face, 1] + d[2] * planes[cell, face, 2]
    if param == 0.0 and abs(dot) <= GRAZE_COS:
        # on the boundary, moving along it and curving into it: the limit of vanishing bounces is creeping
        # along the surface; slide (no reflection: the direction would not change)
        return STATUS_RUNNING, -1, face
    n_refl = cnt[COUNT_REFLECTIONS]
    if n_refl >= prm.max_reflections:
        return STATUS_REFLECTION_LIMIT, entry, -1
    if ray.f_on:  # time gathered before the reflection belongs to the incoming ray
        field.flush_pending(job.fld, ray.rf, n_refl, w.x, d, t, s, _slowness_at(mesh, prm, w, cell, ray.wind))
        if mesh.face_material[cell, face] > 0:
            ray.rf.fst[2] = -1.0  # a soft reflection: re-evaluate the ground factors
    refl_cos = ray.rf.refl_cos
    if n_refl < refl_cos.shape[0]:
        refl_cos[n_refl] = abs(dot)
        ray.rf.refl_mat[n_refl] = mesh.face_material[cell, face]
    for k in range(3):
        d[k] -= 2.0 * dot * planes[cell, face, k]
    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    for k in range(3):
        d[k] /= norm
    cnt[COUNT_REFLECTIONS] = n_refl + 1  # HOOK (c): specular reflection done (d reflected)
    if ray.par_on:
        paraxial.reflect(w.par, planes[cell, face])
        if ray.deposit_on:
            beams.ray_sample(job.beam, ray.acc, ray.bray, w.x, d, t, s, w.f[F_P_NORM] / prm.c_ref, w.par, n_refl + 1,
                             True)  # fmt: skip
    if prm.record and t > w.f[F_T_LAST]:
        _emit(job.paths, cnt, ray.base, w.x, t, s)
        w.f[F_T_LAST] = t
    return STATUS_RUNNING, face, -1


@nb.njit(inline="always", **NJIT_FLAGS)
def _walk_cells(job, ray, w, cell):
    """The per-cell loop of Algorithm 1 from ``cell`` (x, d in w; counters in ray.cnt) until the ray stops;
    returns (cell, status, t, s). Per step: medium, curve, first exit (a stall: slide or nudge), the segment
    (to max_time, or to its end: HOOK (a)), then the neighbour (HOOK (b)), a reflection (HOOK (c)) or exit."""
    mesh = job.mesh
    prm = job.prm
    planes, neighbours, size = mesh.planes, mesh.neighbours, mesh.size
    x, d, xn, dn, cs = w.x, w.d, w.xn, w.dn, w.cs
    curve, c_ref, max_time, dt_sample, record = prm.curve, prm.c_ref, prm.max_time, prm.dt_sample, prm.record
    cnt = ray.cnt
    hooks_on = ray.par_on or ray.f_on or record
    t = 0.0
    s = 0.0
    entry = slide_face = prev_cell = -1
    zero_run = nudge_run = pp_run = 0
    status = STATUS_RUNNING if cell >= 0 else STATUS_LOST
    while status == STATUS_RUNNING:
        if cnt[COUNT_STEPS] >= prm.max_steps:
            status = STATUS_STEP_LIMIT
            break
        cnt[COUNT_STEPS] += 1
        m0, exclude = _cell_medium(mesh, prm, w, cell, ray.wind, entry, slide_face)
        slide_face = -1
        if not curves.setup(curve, m0, w.g, d, cs):
            status = STATUS_LOST
            break
        if ray.par_on:  # the segment restarts from this cell's model at x: p' = n'(x) d (docs/physics.md §10)
            _restart_paraxial(w, m0)
        cell_size = size[cell]
        tol = ON_FACE_REL * cell_size
        face, param = curves.find_exit(curve, cs, x, d, planes[cell], neighbours[cell], exclude, tol, cell_size)
        if face < 0:
            param = curves.interior_step(curve, cs)  # circular: a quarter turn inside the cell
        if param == 0.0:
            zero_run += 1
        if (face < 0 and not math.isfinite(param)) or zero_run > MAX_ZERO_STEPS:
            cell, status, slide_face, entry, t, s, nudge_run = _resolve_stall(mesh, prm, w, cnt, cell, m0, entry, t,
                                                                              s, nudge_run)  # fmt: skip
            zero_run = 0
            continue
        dt = curves.time_at(curve, cs, param, c_ref)
        if not (dt >= 0.0):
            status = STATUS_LOST
            break
        if t + dt >= max_time:
            s = _finish_at_max_time(job, ray, w, param, t, s, m0)
            t = max_time
            status = STATUS_TIME_LIMIT
            break
        ds = curves.evaluate(curve, cs, x, d, param, xn, dn)
        if ds > TINY_STEP_REL * cell_size:
            zero_run = 0
        elif param != 0.0:
            zero_run += 1
        if hooks_on:
            _segment_hooks(job, ray, w, cell, face, param, t, s, dt, ds, m0)
        for k in range(3):
            x[k] = xn[k]
            d[k] = dn[k]
        t += dt
        s += ds
        if not (math.isfinite(x[0]) and math.isfinite(x[1]) and math.isfinite(x[2])):
            status = STATUS_LOST
            break
        if record and t - w.f[F_T_LAST] >= dt_sample:
            _emit(job.paths, cnt, ray.base, x, t, s)
            w.f[F_T_LAST] = t
        if param > 0.0:
            nudge_run = 0
        if face < 0:
            entry = -1  # within-cell step (circular quarter turn): same cell, no entry face
            continue
        nxt = neighbours[cell, face]
        if nxt >= 0:  # HOOK (b): crossed into the neighbour cell (or sliding along a face it zig-zags across)
            cell, entry, prev_cell, pp_run, slide_face = _cross_face(mesh, w, cnt, cell, face, entry, prev_cell, pp_run)
        elif nxt == BOUNDARY_REFLECT:
            status, entry, slide_face = _reflect(job, ray, w, cell, face, param, t, s, entry)
        else:
            status = STATUS_EXITED
    return cell, status, t, s


@nb.njit(inline="always", **NJIT_FLAGS)
def _write_out(job, ray, w, rays, cell, status, t, s):
    """HOOK (d): the ray has stopped (status set) at w.x, w.d, time t (s), arc s (m) in ``cell``: the pending
    field time, the last path sample and beam chord, and the final state into row ray.i of ``rays``."""
    prm = job.prm
    cnt = ray.cnt
    n_refl = cnt[COUNT_REFLECTIONS]
    if ray.f_on and cell >= 0:
        field.flush_pending(job.fld, ray.rf, n_refl, w.x, w.d, t, s, _slowness_at(job.mesh, prm, w, cell, ray.wind))
    if prm.record and (cnt[COUNT_SAMPLES] == 0 or t > w.f[F_T_LAST]):
        _emit(job.paths, cnt, ray.base, w.x, t, s)
    if ray.deposit_on and s > ray.bray.last[beams.S_ARC]:  # the last chord
        beams.ray_sample(job.beam, ray.acc, ray.bray, w.x, w.d, t, s, w.f[F_P_NORM] / prm.c_ref, w.par, n_refl,
                         False)  # fmt: skip
    if rays.out_par.shape[0] > 0:
        out_par = rays.out_par[ray.i]
        for k in range(paraxial.PAR_SIZE):
            out_par[k] = w.par[k]
        out_par[paraxial.PAR_SIZE] = w.f[F_P_NORM] if ray.par_on else math.nan
    out_state = rays.out_state[ray.i]
    for k in range(3):
        out_state[STATE_X + k] = w.x[k]
        out_state[STATE_D + k] = w.d[k]
    out_state[STATE_TIME] = t
    out_state[STATE_LENGTH] = s
    cnt[COUNT_STATUS] = status


@nb.njit(**NJIT_FLAGS)
def trace_one(mesh, prm, fld, paths, rays, i, acc, beam):
    """Trace ray i (rays.origins[i], rays.directions[i] from rays.start_cells[i]) to its end state.

    mesh : CellMesh; prm : RayParams; fld : field.FieldAcc (mode FIELD_OFF: no accumulation), written in
    accumulator slot ``acc``; paths : PathBuffers (ray i's slice); rays : Rays (row i read and written:
    out_state, out_counts, refl_cos, refl_mat, out_par). With wind, each cell's curve is set up from the
    effective medium c + u.e: its value at the entry point x, its gradient at the middle of the straight
    chord from x along d through the cell (exact analytic derivatives there); e = the unit horizontal part
    of the launch direction, fixed for the whole path. beam : beams.Beam (beam field and receiver points;
    the paraxial state of docs/physics.md §10 is carried when beams are on or rays.out_par is asked for).
    """
    w = _new_work(rays.origins[i], rays.directions[i])
    ray = _launch(mesh, prm, fld, beam, rays, i, acc, paths.cap, w)
    job = Job(mesh, prm, fld, paths, beam)
    if prm.record:
        _emit(paths, ray.cnt, ray.base, w.x, 0.0, 0.0)
    cell, status, t, s = _walk_cells(job, ray, w, rays.start_cells[i])
    _write_out(job, ray, w, rays, cell, status, t, s)


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

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

Kernel contract (structs, not long argument lists): ``trace_rays(mesh, prm, fld, paths, rays, n_slots, beam)``
with mesh a mesh.cells.CellMesh, prm a :class:`RayParams`, fld a field.FieldAcc, paths a
:class:`PathBuffers` and rays a :class:`Rays` (per-ray inputs and the out_state / out_counts outputs,
columns constants.STATE_* / COUNT_*); the ray's own field state is one field.RayField. Tolerances live in
engine/constants.py. The per-ray loop of trace_slots is kept as one function with its state in local
scalars: a split into step functions over a per-ray state struct (arrays) was bit-identical but measured
2.3-2.8x slower (crossings per second, desert scene), so only the rare events are helpers. The places
where per-ray extra state (paraxial derivatives, beam deposit) is updated are marked ``HOOK (a)`` (after
each segment inside a cell, also the last one at max_time), ``HOOK (b)`` (face crossing into a neighbour),
``HOOK (c)`` (specular reflection) and ``HOOK (d)`` (the end).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numba as nb
import numpy as np

from bentray.engine.constants import (
    BEAM_KICK_BOUND_NZ,
    BOUNDARY_OPEN,
    BOUNDARY_REFLECT,
    COUNT_CROSSINGS,
    COUNT_NUDGES,
    COUNT_REFLECTIONS,
    COUNT_SAMPLES,
    COUNT_STATUS,
    COUNT_STEPS,
    CURVE_PARABOLIC,
    FACE_UNUSED,
    GRAZE_COS,
    MAX_NUDGES_IN_A_ROW,
    MAX_WALK,
    MAX_ZERO_STEPS,
    NJIT_FLAGS,
    NUDGE_REL,
    ON_FACE_REL,
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
from bentray.engine.kernels.borrow import borrow, held_until_here
from bentray.engine.kernels.face_roots4 import exit_of_cell_planes, exit_of_tet_planes
from bentray.engine.kernels.llvm_inline import njit_inline
from bentray.engine.wind import (
    WIND_NONE,
    along_from_speed,
    effective_quantity,
    effective_value,
    effective_value_at,
    speed_at,
    wind_values,
)


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
    f_weights : (n, n_f) band powers of a voxel field (n_f may be 0 without field), or with beams the
        per-ray amplitude factors of the source's directivity (n, F; (n, 0) for omnidirectional sources);
    refl_cos, refl_mat : (n, R) first R reflections' incidence cosine and face material (written);
    out_state : (n, STATE_SIZE) float64, out_counts : (n, COUNT_SIZE) int64 (written; constants.STATE_*, COUNT_*);
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


@njit_inline
def _media_at(media_ref, ref_point, gradient, cell, x):
    return (
        media_ref[cell]
        + gradient[cell, 0] * (x[0] - ref_point[cell, 0])
        + gradient[cell, 1] * (x[1] - ref_point[cell, 1])
        + gradient[cell, 2] * (x[2] - ref_point[cell, 2])
    )


@nb.njit(**NJIT_FLAGS)
def _slowness_at(curve, c_ref, media_ref, ref_point, gradient, cell, x, wind_code, wind_params, e, w_grad, g_eff):
    """1/c (s/m) of the medium the ray sees at x: the cell's model, plus the wind along e when on."""
    m = _media_at(media_ref, ref_point, gradient, cell, x)
    if wind_code != WIND_NONE:
        # values, as the per-crossing calls pass them: the wind's helpers compile for tuples only
        g = (gradient[cell, 0], gradient[cell, 1], gradient[cell, 2])
        xv = (x[0], x[1], x[2])
        ev = (e[0], e[1], e[2])
        m = effective_quantity(curve, c_ref, m, g, wind_code, wind_values(wind_params), xv, ev, w_grad, g_eff)
    return curves.slowness(curve, m, c_ref)


@njit_inline
def _effective_into(eff, g_eff):
    """wind.effective_value's answer ``eff``: its gradient into g_eff (3,) where effective_quantity would write it
    (state 1; g_eff keeps what it held otherwise); returns the effective traced quantity."""
    m_eff, state, ge0, ge1, ge2, _, _, _, _ = eff
    if state == 1:
        g_eff[0] = ge0
        g_eff[1] = ge1
        g_eff[2] = ge2
    return m_eff


@njit_inline
def _chord_middle(planes, neighbours, x, d, out):
    """Middle of the straight chord from x along d to the cell's boundary, into out (3,); False if none.

    The cell is convex, so the middle lies inside it: the wind gradient sampled there is the cell's
    secant slope along the ray to second order (the entry point's own gradient is only first order).
    """
    best, _ = paraxial.chord_face(planes, neighbours, x, d)
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
def _emit(path_pts, path_t, path_s, base, cap, count, x, t, s):
    if count < cap:
        k = base + count
        path_pts[k, 0] = x[0]
        path_pts[k, 1] = x[1]
        path_pts[k, 2] = x[2]
        path_t[k] = t
        path_s[k] = s
        return count + 1
    return count


@nb.njit(**NJIT_FLAGS)
def _emit_segment(prm, paths, cs, x0, d0, param_end, span, base, count, xs, ts):
    """Interior samples of a segment spanning more than dt_sample (evaluated on the curve).

    prm : RayParams (curve, c_ref, dt_sample); paths : PathBuffers; span : (t0, s0, t_end, t_last) the
    segment's start time (s) and arc (m), its end time and the last sample's time. Returns (count, t_last).
    """
    t0, s0, t_end, t_last = span
    n_int = int((t_end - t0) / prm.dt_sample)
    if n_int > 2 * paths.cap:
        n_int = 2 * paths.cap
    for j in range(1, n_int + 1):
        sig = param_end * j / (n_int + 1)
        ds = curves.evaluate_call(prm.curve, cs, x0, d0, sig, xs, ts)
        tt = t0 + curves.time_at(prm.curve, cs, sig, prm.c_ref)
        count = _emit(paths.pts, paths.t, paths.s, base, paths.cap, count, xs, tt, s0 + ds)
        t_last = tt
    return count, t_last


@nb.njit(**NJIT_FLAGS)
def _p_at(cs, sigma, p_out):
    """Slowness vector p(sigma) = p0 + g sigma / 2 of the parabolic segment into p_out; returns |p| = n."""
    nn = 0.0
    for i in range(3):
        p_out[i] = cs[i] + 0.5 * cs[3 + i] * sigma
        nn += p_out[i] * p_out[i]
    return math.sqrt(nn)


@nb.njit(**NJIT_FLAGS)
def _beam_segment(beam, slot, bray, prm, cs, x, d, seg, par, scratch, refl):
    """Beam samples inside a segment longer than the chord length (on the curve, uniform in sigma).

    prm : RayParams (curve, c_ref); seg : (param, t, s, ds, cell) the segment's end parameter, start time (s),
    start arc (m), length (m) and, for beams in the smooth medium (paraxial.smooth_advance), the cell (else
    -1); scratch : (par_tmp, p_tmp, xs, ts, seg, rates, g) work arrays (seg: the
    segment record of kernels/paraxial.py, g: the segment's gradient); refl : the ray's reflections tuple
    of beams.ray_sample.
    """
    param, t, s, ds, smooth_cell = seg
    par_tmp, p_tmp, xs, ts, seg, rates, g = scratch
    chord = beam.tabs.chord_m
    if ds <= chord:
        return
    n_int = int(ds / chord)
    for j in range(1, n_int + 1):
        sig = param * j / (n_int + 1)
        dsj = curves.evaluate(prm.curve, cs, x, d, sig, xs, ts)
        tj = t + curves.time_at(prm.curve, cs, sig, prm.c_ref)
        if smooth_cell >= 0:
            for q in range(paraxial.PAR_SIZE):
                par_tmp[q] = par[q]
            paraxial.smooth_advance(par_tmp, beam.tabs.hessian, smooth_cell, sig)
            nj = _p_at(cs, sig, p_tmp)
        elif prm.curve == CURVE_PARABOLIC:
            paraxial.advanced_copy(par, sig, par_tmp)
            if seg[16] != 0.0:
                paraxial.advance_dg(par_tmp, seg, sig)
            nj = _p_at(cs, sig, p_tmp)
        else:
            for q in range(paraxial.PAR_SIZE):
                par_tmp[q] = par[q]
            paraxial.along_curve(prm.curve, cs, x, d, g, seg, par_tmp, sig, rates)
            nj = paraxial.to_p(prm.curve, prm.c_ref, cs, g, x, xs, ts, par_tmp, seg)
        beams.ray_sample(beam, slot, bray, xs, ts, tj, s + dsj, nj / prm.c_ref, par_tmp, refl, np.bool_(False))


@nb.njit(**NJIT_FLAGS)
def trace_slots(mesh, prm, fld, paths, rays, slots, beam):
    """Trace the rays of accumulator slots ``slots[0] <= acc < slots[1]`` (of ``slots[2]``) to their end states.

    Slot ``acc`` holds rays acc, acc + n_slots, ... (interleaved, so every slot gets a like mix of directions);
    ray i is traced from rays.origins[i], rays.directions[i] in rays.start_cells[i]. One call runs on one
    thread (the kernel releases the GIL; :func:`trace_rays` runs disjoint slot ranges on a thread pool), and
    only it writes slot acc's accumulators, so for a fixed n_slots the results do not depend on the threads.
    Why this shape (measured on the README job's miniature from an empty cache, and on its reduced copy,
    181 x 61 rays, one thread; docs/physics.md §9):
    - the loop over rays lives here, not in a caller: a caller links this kernel's machine code into its own
      and LLVM optimises and emits all of it again (a prange caller did that about four times over, through
      its gufunc: 17-20 s of the first run's ~120 s of compilation);
    - the inputs are borrowed (kernels/borrow.py): without that, every array taken out of the structs in the
      hot paths was reference counted with atomics (a prange gufunc's arguments are not), and the beam trace
      ran 15 % slower than under the prange caller; borrowed, it runs 9-12 % faster than that;
    - the samples taken once per ray call beams.ray_sample_call and the last segment curves.evaluate_call
      instead of inlined copies (each inlined copy is optimised and emitted again by LLVM; until 2026-12-05,
      when Numba inlined them, also typed again).

    mesh : CellMesh; prm : RayParams; fld : field.FieldAcc (mode FIELD_OFF: no accumulation), written in
    accumulator slot ``acc``; paths : PathBuffers (ray i's slice); rays : Rays (row i read and written:
    out_state, out_counts, refl_cos, refl_mat). With wind, each cell's curve is set up from the effective
    medium c + u.e: its value at the entry point x, its gradient at the middle of the straight chord from
    x along d through the cell (exact analytic derivatives there); e = the unit horizontal part of the
    launch direction, fixed for the whole path. beam : beams.Beam (beam field and receiver points; the
    paraxial state of docs/physics.md §10 is carried when beams are on or rays.out_par is asked for).
    slots : (first, end, n_slots) int.
    """
    # the inputs' arrays without reference counting (kernels/borrow.py; the caller holds them for the call)
    mesh = borrow(mesh)
    prm = borrow(prm)
    fld = borrow(fld)
    paths = borrow(paths)
    rays = borrow(rays)
    beam = borrow(beam)
    planes = mesh.planes
    neighbours = mesh.neighbours
    neighbour_face = mesh.neighbour_face
    media_ref = mesh.media_ref
    ref_point = mesh.ref_point
    gradient = mesh.gradient
    size = mesh.size
    face_material = mesh.face_material
    curve = prm.curve
    c_ref = prm.c_ref
    wind_code = prm.wind_code
    wind_params = prm.wind_params
    max_time = prm.max_time
    max_reflections = prm.max_reflections
    max_steps = prm.max_steps
    record = prm.record
    dt_sample = prm.dt_sample
    path_pts = paths.pts
    path_t = paths.t
    path_s = paths.s
    path_cap = paths.cap
    n_rays = rays.origins.shape[0]
    first_slot, end_slot, n_slots = slots
    for acc in range(first_slot, end_slot):
        for i_ray in range(acc, n_rays, n_slots):
            path_base = i_ray * path_cap
            x_start = rays.origins[i_ray]
            d_start = rays.directions[i_ray]
            cell_start = rays.start_cells[i_ray]
            refl_cos = rays.refl_cos[i_ray]
            refl_mat = rays.refl_mat[i_ray]
            out_state = rays.out_state[i_ray]
            out_counts = rays.out_counts[i_ray]
            rf = field.new_ray_field(rays.f_weights[i_ray], refl_cos, refl_mat, i_ray, acc)
            f_on = fld.mode != field.FIELD_OFF
            fst = rf.fst
            # the ray's work arrays, used through borrowed views: the per-crossing and per-sample calls they go to
            # count no references (docs/physics.md §9); ``owned`` holds them to the ray's end (held_until_here)
            owned = (
                x_start.copy(),  # x
                d_start.copy(),  # d
                np.zeros(3),  # e_wind
                np.empty(3),  # w_grad
                np.empty(3),  # g_eff
                np.empty(3),  # g_tmp
                np.empty(3),  # x_mid
                np.empty(3),  # xn
                np.empty(3),  # dn
                np.empty(3),  # xs
                np.empty(3),  # ts
                np.zeros(curves.CS_SIZE),  # cs
                np.zeros(paraxial.PAR_SIZE),  # par
                np.zeros(paraxial.PAR_SIZE),  # par_tmp
                np.zeros(3),  # p_end
                np.zeros(paraxial.SEG_SIZE),  # seg
                np.zeros(6),  # rates
                np.zeros(3),  # g_nb
                np.empty(3),  # g_slide
                np.empty(3),  # g: the gradient the current cell's curve is set up with
            )
            x, d, e_wind, w_grad, g_eff, g_tmp, x_mid, xn, dn, xs, ts, cs = borrow(owned[:12])
            par, par_tmp, p_end, seg, rates, g_nb, g_slide, g = borrow(owned[12:])
            norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            for i in range(3):
                d[i] /= norm
            # wind: the ray's horizontal launch azimuth e (the effective-sound-speed approximation keeps it for
            # the whole path); a vertical launch has no azimuth and sees no wind (u . e = 0 for every horizontal u)
            ray_wind = WIND_NONE
            if wind_code != WIND_NONE:
                horizontal = math.sqrt(d[0] * d[0] + d[1] * d[1])
                if horizontal > 0.0:
                    e_wind[0] = d[0] / horizontal
                    e_wind[1] = d[1] / horizontal
                    ray_wind = wind_code
            wind_on = ray_wind != WIND_NONE
            # the wind's parameters and the ray's azimuth as values for the per-crossing calls (wind.wind_values)
            wp = wind_values(wind_params)
            ew = (e_wind[0], e_wind[1], e_wind[2])
            t = 0.0
            s = 0.0
            cell = cell_start
            # paraxial state and beam samples (docs/physics.md §10-11); seg: the segment record (circular,
            # n-linear, wind)
            parabolic = curve == CURVE_PARABOLIC
            tets = planes.shape[1] == 4
            cells8 = 4 < planes.shape[1] <= 8  # slab boxes and prisms: two groups of four faces
            want_par = rays.out_par.shape[0] > 0
            deposit_on = beam.grid.mode != beams.BEAM_OFF or beam.pts.xyz.shape[0] > 0
            par_on = (deposit_on or want_par) and cell_start >= 0
            mid_ok = False
            m_raw = 0.0
            # the beam ray used through a borrowed view (no reference counts per chord sample); bray_held keeps its
            # arrays to the ray's end
            bray_held = beams.new_ray(beam.grid.omega.shape[0])
            bray = borrow(bray_held)
            if deposit_on and rays.f_weights.shape[1] == bray.amp0.shape[0]:  # beams: f_weights = directivity factors
                for f in range(bray.amp0.shape[0]):
                    bray.amp0[f] = rays.f_weights[i_ray, f]
            launch_cos = math.sqrt(d[0] * d[0] + d[1] * d[1])
            # callee arguments typed int64 / bool, not Literal[int](0) / Literal[bool]: a literal first type (or a
            # True at one call site, False at another) compiles each callee, ray_sample above all, once more
            reflections = np.int64(0)
            yes = np.bool_(True)
            no = np.bool_(False)
            p_norm = 1.0
            if par_on:
                m_start = _media_at(media_ref, ref_point, gradient, cell, x)
                if wind_on:
                    g_start = (gradient[cell, 0], gradient[cell, 1], gradient[cell, 2])
                    m_start = effective_quantity(
                        curve, c_ref, m_start, g_start, ray_wind, wp, (x[0], x[1], x[2]), ew, w_grad, g_eff
                    )
                if m_start > 0.0:
                    p_norm = math.sqrt(m_start) if parabolic else paraxial.refractive_index(curve, m_start, c_ref)
                    paraxial.launch(par, d, p_norm)
                    if deposit_on:
                        beams.ray_sample_call(
                            beam,
                            acc,
                            bray,
                            x,
                            d,
                            0.0,
                            0.0,
                            p_norm / c_ref,
                            par,
                            (reflections, refl_cos, refl_mat, launch_cos),
                            yes,
                        )
                else:
                    par_on = False
            deposit_on = deposit_on and par_on
            # the smooth medium (mesh/hessian.py; beams, or trace(paraxial="smooth")): per-cell Hessians, no face kicks
            hess = beam.tabs.hessian
            chord_m = beam.tabs.chord_m  # beam samples at least this far apart (m)
            smooth = par_on and parabolic and not wind_on and hess.shape[0] == planes.shape[0]
            entry = -1
            crossings = 0
            nudges = 0
            nudge_run = 0
            zero_run = 0
            slide_face = -1
            prev_cell = -1
            pp_run = 0
            steps = 0
            status = STATUS_RUNNING
            count = np.int64(0)
            t_last = 0.0
            if record:
                count = _emit(path_pts, path_t, path_s, path_base, path_cap, count, x, t, s)
            if cell < 0:
                status = STATUS_LOST
            while status == STATUS_RUNNING:
                if steps >= max_steps:
                    status = STATUS_STEP_LIMIT
                    break
                steps += 1
                m0 = _media_at(media_ref, ref_point, gradient, cell, x)
                for i in range(3):  # copied, not viewed: a view per step costs two atomic reference-count updates
                    g[i] = gradient[cell, i]
                if wind_on:
                    # m0, g become the effective medium's traced quantity (exact, at x) and its gradient (at the
                    # middle of the straight chord through the cell: the entry point's own gradient would make the
                    # per-cell model first-order accurate; measured on a log-law wind, errors fell only 3x per 3x
                    # thinner layers, and 10x with the chord middle). The curve, its exit, time_at (which then
                    # integrates 1/c_eff: the travel time in the moving medium), the nudge slowness and the field
                    # deposit all use them. Without wind nothing here changes.
                    # (wind.effective_value on values: wp, ew and 3-tuples, no array in the calls; g_eff is written
                    # only where effective_quantity would write it, state 1)
                    m_raw = m0
                    g_cell = (g[0], g[1], g[2])
                    x_now = (x[0], x[1], x[2])
                    # the wind's speed at x, evaluated once: the effective medium here and the beams' segment
                    # record (paraxial.beam_wind_record) both take it (wind.effective_value's arithmetic)
                    su_x = speed_at(wind_code, wp, x_now)
                    eff_x = effective_value_at(curve, c_ref, m0, g_cell, wp, su_x, ew)
                    m0 = _effective_into(eff_x, g_eff)
                    mid_ok = _chord_middle(planes[cell], neighbours[cell], x, d, x_mid)
                    if mid_ok:
                        m_mid = _media_at(media_ref, ref_point, gradient, cell, x_mid)
                        _effective_into(
                            effective_value(
                                curve, c_ref, m_mid, g_cell, wind_code, wp, (x_mid[0], x_mid[1], x_mid[2]), ew
                            ),
                            g_eff,
                        )
                    for i in range(3):
                        g[i] = g_eff[i]
                # int64, never Literal[int](-1) (entry starts as -1): a literal first type would compile the exit
                # search's callee once more
                exclude = np.int64(entry)
                if slide_face >= 0:
                    # slide along the face: the mean gradient of the two sides without its normal part
                    nb_cell = neighbours[cell, slide_face]
                    for i in range(3):
                        g_slide[i] = g[i]
                        if nb_cell >= 0 and not wind_on:
                            g_slide[i] = 0.5 * (g[i] + gradient[nb_cell, i])
                    gm = (
                        g_slide[0] * planes[cell, slide_face, 0]
                        + g_slide[1] * planes[cell, slide_face, 1]
                        + g_slide[2] * planes[cell, slide_face, 2]
                    )
                    for i in range(3):
                        g[i] = g_slide[i] - gm * planes[cell, slide_face, i]
                    exclude = np.int64(slide_face)
                    slide_face = -1
                if not curves.setup(curve, m0, g, d, cs):
                    status = STATUS_LOST
                    break
                if par_on and wind_on:  # the effective medium's derivatives (docs/physics.md §10, wind)
                    paraxial.tangent_derivs(par, d, p_norm, seg)
                    if deposit_on:  # beams drop the gradient terms: d m0 alone, in closed form
                        u_de = along_from_speed(wp, su_x, (-ew[1], ew[0], 0.0))[0]  # the wind along the azimuth's turn
                        paraxial.beam_wind_record(curve, c_ref, eff_x, u_de, par, seg)
                    else:
                        paraxial.wind_terms(
                            curve,
                            c_ref,
                            (ray_wind, wp, ew),
                            (m_raw, gradient[cell], planes[cell], neighbours[cell], size[cell], mid_ok, x_mid),
                            x,
                            d,
                            par,
                            seg,
                        )
                    paraxial.finish_terms(par, g, seg)
                    if deposit_on:  # beams: each cell's wind gradient taken as fixed (docs/physics.md §11)
                        paraxial.drop_gradient_terms(seg)
                if par_on and parabolic:  # the segment restarts from this cell's model at x: p' = n'(x) d (§10)
                    n_new = math.sqrt(m0)
                    if wind_on:
                        paraxial.restart_dm(par, d, p_norm, n_new, seg)
                    elif not smooth:  # smooth medium: n^2 and the constraint 2 p.P = grad n^2 . X carry on as they are
                        paraxial.restart(par, d, p_norm, n_new, g)
                    p_norm = n_new
                elif par_on:  # circular / n-linear: the segment starts from (x, d); its D_k (docs/physics.md §10)
                    if not wind_on:
                        paraxial.tangent_derivs(par, d, p_norm, seg)
                        paraxial.plain_terms(par, g, seg)
                cell_size = size[cell]
                if parabolic and tets:  # the faces four at once (kernels/face_roots4.py): find_exit's bits
                    param, face = exit_of_tet_planes(
                        planes[cell], neighbours[cell], cs[3], cs[4], cs[5], cs[0], cs[1], cs[2], x[0], x[1], x[2],
                        exclude, ON_FACE_REL * cell_size,
                    )  # fmt: skip
                elif parabolic and cells8:
                    param, face = exit_of_cell_planes(
                        planes[cell], neighbours[cell], cs[3], cs[4], cs[5], cs[0], cs[1], cs[2], x[0], x[1], x[2],
                        exclude, ON_FACE_REL * cell_size,
                    )  # fmt: skip
                else:
                    face, param = curves.find_exit(
                        curve, cs, x, d, planes[cell], neighbours[cell], exclude, ON_FACE_REL * cell_size, cell_size
                    )
                if face < 0:
                    param = curves.interior_step(curve, cs)  # circular: a quarter turn inside the cell
                if param == 0.0:
                    zero_run += 1
                if (face < 0 and not math.isfinite(param)) or zero_run > MAX_ZERO_STEPS:
                    # rounding at an edge or vertex left no consistent exit: nudge and re-locate
                    nudges += 1
                    nudge_run += 1
                    zero_run = 0
                    if nudge_run > MAX_NUDGES_IN_A_ROW:
                        status = STATUS_LOST
                        break
                    tf = _tangent_face(planes[cell], neighbours[cell], x, d, size[cell])
                    if tf >= 0:
                        _onto_face(planes[cell, tf], x, d, yes)
                        slide_face = tf
                        continue
                    eta = NUDGE_REL * cell_size
                    t += eta * curves.slowness(curve, m0, c_ref)
                    s += eta
                    cell, status = _nudge(planes, neighbours, cell, x, d, eta)
                    entry = -1
                    continue
                dt = curves.time_at(curve, cs, param, c_ref)
                if not (dt >= 0.0):
                    status = STATUS_LOST
                    break
                if t + dt >= max_time:
                    param_end = curves.param_at_time(curve, cs, max_time - t, param, c_ref)
                    ds = curves.evaluate_call(curve, cs, x, d, param_end, xn, dn)
                    if par_on:  # HOOK (a), paraxial: the last segment, to max_time
                        if deposit_on and ds > chord_m:  # a call binds ~60 arrays: only for segments that need samples
                            _beam_segment(
                                beam,
                                acc,
                                bray,
                                prm,
                                cs,
                                x,
                                d,
                                (param_end, t, s, ds, cell if smooth else np.int64(-1)),
                                par,
                                (par_tmp, p_end, xs, ts, seg, rates, g),
                                (reflections, refl_cos, refl_mat, launch_cos),
                            )
                        if smooth:
                            paraxial.smooth_advance(par, hess, cell, param_end)
                            p_norm = _p_at(cs, param_end, p_end)
                        elif parabolic:
                            paraxial.advance(par, param_end)
                            if wind_on:
                                paraxial.advance_dg(par, seg, param_end)
                            p_norm = _p_at(cs, param_end, p_end)
                        else:
                            paraxial.along_curve(curve, cs, x, d, g, seg, par, param_end, rates)
                            p_norm = paraxial.to_p(curve, c_ref, cs, g, x, xn, dn, par, seg)
                        if deposit_on:
                            beams.ray_sample_call(
                                beam,
                                acc,
                                bray,
                                xn,
                                dn,
                                max_time,
                                s + ds,
                                p_norm / c_ref,
                                par,
                                (reflections, refl_cos, refl_mat, launch_cos),
                                no,
                            )
                    if f_on:
                        field.deposit_segment(
                            fld,
                            rf,
                            reflections,
                            curve,
                            c_ref,
                            cs,
                            x,
                            d,
                            xn,
                            m0,
                            g,
                            field.Segment(param_end, t, s, max_time - t, ds),
                        )
                    if record and max_time - t > dt_sample:
                        count, t_last = _emit_segment(
                            prm, paths, cs, x, d, param_end, (t, s, max_time, t_last), path_base, count, xs, ts
                        )
                    for i in range(3):
                        x[i] = xn[i]
                        d[i] = dn[i]
                    t = max_time
                    s += ds
                    status = STATUS_TIME_LIMIT  # HOOK (a): the last segment, to max_time
                    break
                ds = curves.evaluate(curve, cs, x, d, param, xn, dn)
                if ds > TINY_STEP_REL * cell_size:
                    zero_run = 0
                elif param != 0.0:
                    zero_run += 1
                if par_on:  # HOOK (a), paraxial: samples inside the segment, derivatives at its end (on its face)
                    if deposit_on and ds > chord_m:  # (as above)
                        _beam_segment(
                            beam,
                            acc,
                            bray,
                            prm,
                            cs,
                            x,
                            d,
                            (param, t, s, ds, cell if smooth else np.int64(-1)),
                            par,
                            (par_tmp, p_end, xs, ts, seg, rates, g),
                            (reflections, refl_cos, refl_mat, launch_cos),
                        )
                    if smooth:
                        paraxial.smooth_advance(par, hess, cell, param)
                        p_norm = _p_at(cs, param, p_end)
                        x_rate = p_norm
                    elif parabolic:
                        paraxial.advance(par, param)
                        if wind_on:
                            paraxial.advance_dg(par, seg, param)
                        p_norm = _p_at(cs, param, p_end)
                        x_rate = p_norm
                    else:
                        x_rate = paraxial.along_curve(curve, cs, x, d, g, seg, par, param, rates)
                    if face >= 0:
                        # exact derivatives, unless the state feeds beams and the face is slanted: then the kick of a
                        # near-tangential crossing is bounded (constants.BEAM_KICK_BOUND_NZ; docs/physics.md §11)
                        slanted = abs(planes[cell, face, 2]) < BEAM_KICK_BOUND_NZ
                        bound = cell_size / x_rate if deposit_on and slanted else math.inf
                        if smooth and neighbours[cell, face] >= 0:
                            pass  # the smooth medium has no face here: X_k stay at fixed sigma (mesh/hessian.py)
                        elif smooth:
                            # a boundary (reflection, exit): onto it with the smooth medium's gradient at the face point
                            paraxial.smooth_gradient(hess, cell, g, xn, g_nb)
                            paraxial.onto_face(par, planes[cell, face], p_end, g_nb, bound)
                        elif parabolic:
                            paraxial.onto_face(par, planes[cell, face], p_end, g, bound)
                        else:
                            paraxial.onto_face_rates(par, planes[cell, face], rates, bound)
                    if not parabolic:
                        p_norm = paraxial.to_p(curve, c_ref, cs, g, x, xn, dn, par, seg)
                    if face >= 0:
                        if deposit_on and (neighbours[cell, face] < 0 or s + ds - bray.last[beams.S_ARC] >= chord_m):
                            beams.ray_sample(
                                beam,
                                acc,
                                bray,
                                xn,
                                dn,
                                t + dt,
                                s + ds,
                                p_norm / c_ref,
                                par,
                                (reflections, refl_cos, refl_mat, launch_cos),
                                no,
                            )
                if f_on:
                    field.deposit_segment(
                        fld, rf, reflections, curve, c_ref, cs, x, d, xn, m0, g, field.Segment(param, t, s, dt, ds)
                    )
                if record:
                    if dt > dt_sample:
                        count, t_last = _emit_segment(
                            prm, paths, cs, x, d, param, (t, s, t + dt, t_last), path_base, count, xs, ts
                        )
                for i in range(3):
                    x[i] = xn[i]
                    d[i] = dn[i]
                t += dt
                s += ds
                if not (math.isfinite(x[0]) and math.isfinite(x[1]) and math.isfinite(x[2])):
                    status = STATUS_LOST
                    break
                if record and t - t_last >= dt_sample:
                    count = _emit(path_pts, path_t, path_s, path_base, path_cap, count, x, t, s)
                    t_last = t
                if param > 0.0:
                    nudge_run = 0
                # HOOK (a): a segment inside the cell ended here (x, d, t, s updated; cell not yet changed)
                if face < 0:
                    entry = -1  # within-cell step (circular quarter turn): same cell, no entry face
                    continue
                nxt = neighbours[cell, face]
                if nxt >= 0:
                    dm = d[0] * planes[cell, face, 0] + d[1] * planes[cell, face, 1] + d[2] * planes[cell, face, 2]
                    if nxt == prev_cell and abs(dm) <= SLIDE_COS:
                        pp_run += 1
                    else:
                        pp_run = 0
                    if pp_run >= PINGPONG_SLIDE:
                        # zig-zagging across this face: slide along it in the current cell
                        _onto_face(planes[cell, face], x, d, no)
                        slide_face = face
                        pp_run = 0
                        nudges += 1
                        continue
                    prev_cell = cell
                    entry = neighbour_face[cell, face]
                    cell = nxt
                    crossings += 1  # HOOK (b): crossed into the neighbour cell
                elif nxt == BOUNDARY_REFLECT:
                    dot = d[0] * planes[cell, face, 0] + d[1] * planes[cell, face, 1] + d[2] * planes[cell, face, 2]
                    if param == 0.0 and abs(dot) <= GRAZE_COS:
                        # on the boundary, moving along it and curving into it: the limit of vanishing bounces
                        # is creeping along the surface; slide (no reflection: the direction would not change)
                        slide_face = face
                        entry = -1
                        continue
                    if reflections >= max_reflections:
                        status = STATUS_REFLECTION_LIMIT
                        break
                    if f_on:  # time gathered before the reflection belongs to the incoming ray
                        field.flush_pending(
                            fld,
                            rf,
                            reflections,
                            x,
                            d,
                            t,
                            s,
                            _slowness_at(
                                curve,
                                c_ref,
                                media_ref,
                                ref_point,
                                gradient,
                                cell,
                                x,
                                ray_wind,
                                wind_params,
                                e_wind,
                                w_grad,
                                g_tmp,
                            ),
                        )
                        if face_material[cell, face] > 0:
                            fst[2] = -1.0  # a soft reflection: re-evaluate the ground factors
                    if reflections < refl_cos.shape[0]:
                        refl_cos[reflections] = abs(dot)
                        refl_mat[reflections] = face_material[cell, face]
                    for i in range(3):
                        d[i] -= 2.0 * dot * planes[cell, face, i]
                    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
                    for i in range(3):
                        d[i] /= norm
                    reflections += 1
                    entry = face  # HOOK (c): specular reflection done (d reflected)
                    if par_on:
                        paraxial.reflect(par, planes[cell, face])
                        if deposit_on:
                            beams.ray_sample(
                                beam,
                                acc,
                                bray,
                                x,
                                d,
                                t,
                                s,
                                p_norm / c_ref,
                                par,
                                (reflections, refl_cos, refl_mat, launch_cos),
                                yes,
                            )
                    if record and t > t_last:
                        count = _emit(path_pts, path_t, path_s, path_base, path_cap, count, x, t, s)
                        t_last = t
                else:
                    status = STATUS_EXITED
                    break
            # HOOK (d): the ray has stopped (status set)
            if f_on and cell >= 0:
                field.flush_pending(
                    fld,
                    rf,
                    reflections,
                    x,
                    d,
                    t,
                    s,
                    _slowness_at(
                        curve,
                        c_ref,
                        media_ref,
                        ref_point,
                        gradient,
                        cell,
                        x,
                        ray_wind,
                        wind_params,
                        e_wind,
                        w_grad,
                        g_tmp,
                    ),
                )
            if record and (count == 0 or t > t_last):
                count = _emit(path_pts, path_t, path_s, path_base, path_cap, count, x, t, s)
            if deposit_on and s > bray.last[beams.S_ARC]:  # HOOK (d), paraxial: the last chord
                beams.ray_sample_call(
                    beam, acc, bray, x, d, t, s, p_norm / c_ref, par, (reflections, refl_cos, refl_mat, launch_cos), no
                )
            if want_par:
                out_par = rays.out_par[i_ray]
                for k in range(paraxial.PAR_SIZE):
                    out_par[k] = par[k]
                out_par[paraxial.PAR_SIZE] = p_norm if par_on else math.nan
            for k in range(3):
                out_state[STATE_X + k] = x[k]
                out_state[STATE_D + k] = d[k]
            out_state[STATE_TIME] = t
            out_state[STATE_LENGTH] = s
            out_counts[COUNT_STATUS] = status
            out_counts[COUNT_REFLECTIONS] = reflections
            out_counts[COUNT_CROSSINGS] = crossings
            out_counts[COUNT_NUDGES] = nudges
            out_counts[COUNT_STEPS] = steps
            out_counts[COUNT_SAMPLES] = count
            # the owners of the borrowed work arrays and beam ray are released here, after the views' last use
            held_until_here(bray_held)
            held_until_here(owned)


def trace_rays(mesh, prm, fld, paths, rays, n_slots: int, beam: beams.Beam) -> None:
    """Trace all rays: ``n_slots`` accumulator slots (rays interleaved, :func:`trace_slots`) split into
    contiguous ranges, one per thread of a pool of ``numba.get_num_threads()`` (at most n_slots) threads.

    Ray i owns row i of every ``rays`` array and the path slice ``[i * paths.cap, (i + 1) * paths.cap)``;
    field accumulator slot ``i % n_slots`` is written only by the thread running that slot. For a fixed
    n_slots the results are deterministic. beam : beams.Beam (the beam field and the receiver points;
    BEAM_OFF in beam.grid.mode and no points: none). Python threads, not a prange: a parallel numba caller
    would compile and link the whole kernel once more (see trace_slots).
    """
    n_slots = int(n_slots)
    threads = max(1, min(n_slots, int(nb.get_num_threads())))
    bounds = [n_slots * k // threads for k in range(threads + 1)]
    spans = [(bounds[k], bounds[k + 1], n_slots) for k in range(threads) if bounds[k + 1] > bounds[k]]
    if len(spans) <= 1:
        trace_slots(mesh, prm, fld, paths, rays, (0, n_slots, n_slots), beam)
        return
    with ThreadPoolExecutor(max_workers=len(spans)) as pool:
        for done in [pool.submit(trace_slots, mesh, prm, fld, paths, rays, span, beam) for span in spans]:
            done.result()

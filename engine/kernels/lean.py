"""A lean traversal for the common plain trace: parabolic curve, no wind, no field, no paths, no paraxial state.

The generic kernel (traverse.trace_slots) serves every curve kind, field, beam, path recording and wind
with one loop and runtime switches; a job that needs none of them still pays for the switches, the
runtime curve dispatch, the per-cell array views (two atomic reference-count updates each) and the
compile time of all of it. This module is the same walk (Algorithm 1, physics.md section 5) written
for that one case, and written for the memory system:

- the same arithmetic in the same order on the same numbers (parabolic.plane_coefficients written out,
  roots.face_exit_parameter, parabolic.travel_time / sigma_at_time / state_at / arc_length, and the
  generic kernel's own rare-event helpers for nudges, slides and walks), so the final ray states are
  bit-identical to the generic kernel's (tests/engine/test_lean_traversal.py);
- faces that cannot be exits are skipped before their root is taken: with A <= 0 and B <= 0 the face
  polynomial A u^2 + B u + C has no upward crossing for u > 0 and face_exit_parameter returns +inf for
  every C (also the on-face and tangent cases), so skipping them changes no result;
- a tetrahedron's four faces are searched at once as 4-wide vectors (kernels/face_roots4.py: every branch of
  the face loop a lane-wise select, the same bits): the loop's branches change outcome from ray to ray, and
  with several rays in flight they were mispredicted often (desert, 8 lanes: 95 -> 68 ns per crossing);
  cells with other face counts keep the loop (``_exit_search``);
- each cell is one packed, 64-byte aligned record (mesh/packed.py: planes, gradient, reference point and
  value, size, neighbours and neighbour faces; 4 cache lines for a tetrahedron) instead of reads from seven
  arrays (8-10 lines); the rare events read the mesh's own arrays;
- interleaved lanes: a ray learns its next cell only at the end of each step, so a single ray waits for
  every new cell's record from memory (a terrain mesh of 760k cells is 195 MB of records, and most cells
  are new to the ray that enters them). The kernel keeps ``lanes`` rays in flight and steps them in turn;
  once a ray's exit face is known its next record is prefetched (``prefetch`` 1), and the other lanes'
  steps run while it arrives. Prefetches only move data into the cache (they never fault and change no
  value), and each lane's arithmetic is that of one ray alone, so any number of lanes gives the same bits;
- stages across the lanes: one ray's step is a chain (record -> n -> p -> face roots -> position -> next
  record: three square roots and two divisions in series) that the processor can only wait on, so a round
  takes each stage of the common step (an interior crossing) for every lane before the next stage, and the
  lanes' independent chains overlap; a lane whose step is not the common one runs the whole step
  (``_lane_step``) from the same state (desert, 8 lanes: 68 -> 60 ns per crossing);
- the advance stage (travel time, new position and tangent, arc length: six square roots and five divisions
  per lane) for four lanes at once as 4-wide vectors (kernels/lane_advance4.py, the same bits), with both
  quadrature rules taken and the lane's chosen by a select: the choice between the 2- and 3-point rules
  was a coin toss on the desert (54 % / 46 %) and mispredicted as a branch (60 -> 50 ns per crossing).

Rays run in contiguous blocks (neighbouring launch directions share a thread and their cells' cache
lines), one serial kernel call per block on Python threads (the kernel releases the GIL; tracer.trace_lean),
so no parallel (prange) lowering is compiled. The outputs are the generic kernel's out_state / out_counts
columns (constants.STATE_* / COUNT_*); COUNT_SAMPLES is 0 (no path recording).
"""

from __future__ import annotations

import math
from typing import Any

import numba as nb
import numpy as np
from llvmlite import ir  # type: ignore[import-untyped]
from numba.core import cgutils, types
from numba.core.extending import intrinsic

from bentray.engine.constants import (
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
    MAX_ZERO_STEPS,
    NJIT_FLAGS,
    NUDGE_REL,
    ON_FACE_REL,
    PINGPONG_SLIDE,
    SLIDE_COS,
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
from bentray.engine.kernels import parabolic
from bentray.engine.kernels.atomics import fetch_add
from bentray.engine.kernels.face_roots4 import exit_of_cell8, exit_of_tet
from bentray.engine.kernels.lane_advance4 import advance4
from bentray.engine.kernels.llvm_inline import njit_inline
from bentray.engine.kernels.roots import NO_ROOT, face_exit_parameter
from bentray.engine.kernels.traverse import _nudge, _onto_face, _tangent_face

__all__ = ["trace_block_lanes"]

# The parabolic helpers: the generic kernel's own (kernels/llvm_inline.py: compiled once, inlined by LLVM), so
# the same arithmetic. Until 2026-12-05 they were numba-IR inlined there, and this kernel compiled plain
# copies of them: IR inlining at its four call sites and in the prefetch helpers cost ~80 s of compilation
# under load against 22 s.
_travel_time = parabolic.travel_time
_sigma_at_time = parabolic.sigma_at_time
_state_at = parabolic.state_at
_arc_length = parabolic.arc_length
_face_exit_parameter = face_exit_parameter


def _prefetch_intrinsic(typingctx, arr, row, byte_offset):
    """Prefetch (read, high locality) the cache line at byte ``byte_offset`` of row ``row`` of ``arr``
    (LLVM's llvm.prefetch; no fault for any address, no value changed)."""
    if not isinstance(arr, types.Array):
        return None
    sig = types.void(arr, row, byte_offset)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        zero = context.get_constant(types.intp, 0)
        idx = [args[1]] + [zero] * (aryty.ndim - 1)
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, idx, wraparound=False, boundscheck=False)
        i8p = builder.bitcast(ptr, ir.IntType(8).as_pointer())
        addr = builder.gep(i8p, [args[2]])
        i32 = ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p.type, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0")
        builder.call(fn, [addr, ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


_prefetch: Any = intrinsic(_prefetch_intrinsic)


@njit_inline
def _exit_search(rec, cell, k_faces, o_nb, g, p0, x, exclude, on_face_tol):
    """(parameter, face) of the exit from row ``cell`` of ``rec`` face by face (cells of any face count K):
    unused faces and faces with A <= 0 and B <= 0 skipped, roots.face_exit_parameter for the rest, the
    smallest parameter wins (the first face on a tie); (+inf, -1) when no face is an exit. g, p0, x : (3,)
    tuples or arrays (grad n^2 per metre, p = n T at the start, position m)."""
    param = NO_ROOT
    face = -1
    for f in range(k_faces):
        if rec[cell, o_nb + f] == FACE_UNUSED:
            continue
        mx = rec[cell, 4 * f]
        my = rec[cell, 4 * f + 1]
        mz = rec[cell, 4 * f + 2]
        a = 0.25 * (mx * g[0] + my * g[1] + mz * g[2])
        b = mx * p0[0] + my * p0[1] + mz * p0[2]
        if a <= 0.0 and b <= 0.0:
            continue
        c = mx * x[0] + my * x[1] + mz * x[2] - rec[cell, 4 * f + 3]
        r = _face_exit_parameter(a, b, c, f == exclude, on_face_tol)
        if r < param:
            param = r
            face = f
    return param, face


@njit_inline
def _exit_any(rec, k_faces, o_nb, cell, g, p0, x, exclude, on_face_tol):
    """(parameter, face) of the exit from row ``cell``: a tetrahedron's four faces as one vector pass, cells of 5
    to 8 faces as two (kernels/face_roots4.py), others face by face (_exit_search); the same bits in each."""
    if k_faces == 4:
        return exit_of_tet(
            rec, cell, g[0], g[1], g[2], p0[0], p0[1], p0[2], x[0], x[1], x[2], exclude, on_face_tol, o_nb
        )
    if k_faces <= 8:
        return exit_of_cell8(
            rec, cell, g[0], g[1], g[2], p0[0], p0[1], p0[2], x[0], x[1], x[2], exclude, on_face_tol, o_nb, k_faces
        )
    return _exit_search(rec, cell, k_faces, o_nb, g, p0, x, exclude, on_face_tol)


@nb.njit(**NJIT_FLAGS)
def _prefetch_row(arr, row, row_bytes):
    """Every cache line of row ``row`` of ``arr`` (row_bytes long). A tetrahedron's packed record (256 bytes,
    64-byte aligned: mesh/packed.py) is exactly four lines, four prefetches with no loop (desert, 8 lanes: 2.5 ns
    per crossing less than the loop); other rows need not be line-aligned, so their last byte's line is
    prefetched too."""
    if row_bytes == 256:
        _prefetch(arr, row, 0)
        _prefetch(arr, row, 64)
        _prefetch(arr, row, 128)
        _prefetch(arr, row, 192)
        return
    off = 0
    while off < row_bytes:
        _prefetch(arr, row, off)
        off += 64
    _prefetch(arr, row, row_bytes - 1)


# Lane state columns (trace_block_lanes): float64 per lane
_F_X = 0  # position (3)
_F_D = 3  # unit tangent (3)
_F_T = 6  # travel time
_F_S = 7  # arc length
_F_SIZE = 8
# int64 per lane
_I_RAY = 0  # ray index, -1: lane idle
_I_CELL = 1
_I_ENTRY = 2
_I_REFL = 3
_I_CROSS = 4
_I_NUDGES = 5
_I_NUDGE_RUN = 6
_I_ZERO_RUN = 7
_I_SLIDE = 8
_I_PREV = 9
_I_PP = 10
_I_STEPS = 11
_I_STATUS = 12
_I_SIZE = 13


@nb.njit(**NJIT_FLAGS)
def _lane_start(ray, x_start, d_start, cell, fs, ist):
    """Load ray ``ray`` into one lane's state rows fs (_F_SIZE,), ist (_I_SIZE,) as the generic walk starts it
    (unit direction, zero time and length, no entry face; lost at once without a start cell)."""
    norm = math.sqrt(d_start[0] * d_start[0] + d_start[1] * d_start[1] + d_start[2] * d_start[2])
    for i in range(3):
        fs[_F_X + i] = x_start[i]
        fs[_F_D + i] = d_start[i] / norm
    fs[_F_T] = 0.0
    fs[_F_S] = 0.0
    ist[:] = 0
    ist[_I_RAY] = ray
    ist[_I_CELL] = cell
    ist[_I_ENTRY] = -1
    ist[_I_SLIDE] = -1
    ist[_I_PREV] = -1
    ist[_I_STATUS] = STATUS_RUNNING if cell >= 0 else STATUS_LOST


@nb.njit(**NJIT_FLAGS)
def _lane_finish(fs, ist, state, counts):
    """Write one lane's final state into its ray's output rows."""
    for k in range(3):
        state[STATE_X + k] = fs[_F_X + k]
        state[STATE_D + k] = fs[_F_D + k]
    state[STATE_TIME] = fs[_F_T]
    state[STATE_LENGTH] = fs[_F_S]
    counts[COUNT_STATUS] = ist[_I_STATUS]
    counts[COUNT_REFLECTIONS] = ist[_I_REFL]
    counts[COUNT_CROSSINGS] = ist[_I_CROSS]
    counts[COUNT_NUDGES] = ist[_I_NUDGES]
    counts[COUNT_STEPS] = ist[_I_STEPS]
    counts[COUNT_SAMPLES] = 0


@nb.njit(**NJIT_FLAGS)
def _lane_take(lane, next_ray, end, queue, rays_in, rays_out, fst, ist):
    """Load the next ray that starts inside the mesh into ``lane`` (rays starting outside it are written out
    as lost at once); returns the thread's new chunk [next_ray, end), end -1 once the queue is empty (the lane
    is then left idle, ray -1).
    next_ray, end : this thread's current chunk of neighbouring rays; queue : (taken, hi, chunk), the rays shared
    by every thread: taken (1,) int64, the next ray not yet handed out (atomics.fetch_add moves it by ``chunk``),
    up to hi (excluded). rays_in : (origins, directions, cells); rays_out : (out_state, out_counts)."""
    taken, hi, chunk = queue
    origins, directions, cells = rays_in
    out_state, out_counts = rays_out
    ist[lane, _I_RAY] = -1
    while True:
        if next_ray >= end:
            next_ray = fetch_add(taken, chunk)
            if next_ray >= hi:
                return hi, -1  # the queue is empty: end -1 tells the caller not to ask again
            end = min(next_ray + chunk, hi)
        ray = next_ray
        next_ray += 1
        _lane_start(ray, origins[ray], directions[ray], cells[ray], fst[lane], ist[lane])
        if ist[lane, _I_STATUS] == STATUS_RUNNING:
            return next_ray, end
        _lane_finish(fst[lane], ist[lane], out_state[ray], out_counts[ray])
        ist[lane, _I_RAY] = -1


@njit_inline
def _step_start(rec, o_g, o_r, o_m, o_s, cell, x0, x1, x2, d0, d1, d2):
    """A step's start in ``cell`` at x = (x0, x1, x2) with unit tangent (d0, d1, d2): (m0 = n^2, g = grad n^2,
    p0 = n T, g.p0, |g|^2, the cell's size), for the common step and _lane_step alike (n is nan where m0 < 0:
    both check m0 before using anything else)."""
    m0 = (
        rec[cell, o_m]
        + rec[cell, o_g] * (x0 - rec[cell, o_r])
        + rec[cell, o_g + 1] * (x1 - rec[cell, o_r + 1])
        + rec[cell, o_g + 2] * (x2 - rec[cell, o_r + 2])
    )
    g0 = rec[cell, o_g]
    g1 = rec[cell, o_g + 1]
    g2 = rec[cell, o_g + 2]
    n0 = math.sqrt(m0)
    p0 = (n0 * d0, n0 * d1, n0 * d2)
    gp0 = g0 * p0[0] + g1 * p0[1] + g2 * p0[2]
    gg = g0 * g0 + g1 * g1 + g2 * g2
    return m0, (g0, g1, g2), p0, gp0, gg, rec[cell, o_s]


@nb.njit(**NJIT_FLAGS)
def _lane_step(rec, geo, planes, neighbours, c_ref, limits, fst, ist, lane, x, d, xn, dn):
    """One whole step of the walk for ``lane`` (its state rows fst[lane], ist[lane], updated; the status in
    ist[lane, _I_STATUS]): the generic walk's loop body with every rare event (nudges, slides, reflections,
    limits). x, d, xn, dn : (3,) work arrays. geo : (k_faces and the record's field offsets, record bytes)."""
    max_time, max_reflections, max_steps, prefetch, lanes = limits
    k_faces, o_g, o_r, o_m, o_s, o_nb, o_nf, rec_bytes = geo
    # ---- load the lane
    for i in range(3):
        x[i] = fst[lane, _F_X + i]
        d[i] = fst[lane, _F_D + i]
    t = fst[lane, _F_T]
    s = fst[lane, _F_S]
    cell = ist[lane, _I_CELL]
    entry = ist[lane, _I_ENTRY]
    reflections = ist[lane, _I_REFL]
    crossings = ist[lane, _I_CROSS]
    nudges = ist[lane, _I_NUDGES]
    nudge_run = ist[lane, _I_NUDGE_RUN]
    zero_run = ist[lane, _I_ZERO_RUN]
    slide_face = ist[lane, _I_SLIDE]
    prev_cell = ist[lane, _I_PREV]
    pp_run = ist[lane, _I_PP]
    steps = ist[lane, _I_STEPS]
    status = STATUS_RUNNING
    # ---- one step of the walk's loop (its 'break': status set here; its 'continue': the step ends)
    while True:
        if steps >= max_steps:
            status = STATUS_STEP_LIMIT
            break
        steps += 1
        m0, g, p0, gp0, gg, cell_size = _step_start(rec, o_g, o_r, o_m, o_s, cell, x[0], x[1], x[2], d[0], d[1], d[2])
        exclude = entry
        if slide_face >= 0:  # the mean gradient of the two cells, less its normal part (g.p0 and |g|^2 again)
            g0, g1, g2 = g
            nb_cell = int(rec[cell, o_nb + slide_face])
            if nb_cell >= 0:
                g0 = 0.5 * (g0 + rec[nb_cell, o_g])
                g1 = 0.5 * (g1 + rec[nb_cell, o_g + 1])
                g2 = 0.5 * (g2 + rec[nb_cell, o_g + 2])
            pf = 4 * slide_face
            gm = g0 * rec[cell, pf] + g1 * rec[cell, pf + 1] + g2 * rec[cell, pf + 2]
            g0 = g0 - gm * rec[cell, pf]
            g1 = g1 - gm * rec[cell, pf + 1]
            g2 = g2 - gm * rec[cell, pf + 2]
            exclude = slide_face
            slide_face = -1
            g = (g0, g1, g2)
            gp0 = g0 * p0[0] + g1 * p0[1] + g2 * p0[2]
            gg = g0 * g0 + g1 * g1 + g2 * g2
        if not (m0 > 0.0) or not math.isfinite(m0):
            status = STATUS_LOST
            break
        on_face_tol = ON_FACE_REL * cell_size
        param, face = _exit_any(rec, k_faces, o_nb, cell, g, p0, x, exclude, on_face_tol)
        nxt = -1
        if face >= 0:
            nxt = int(rec[cell, o_nb + face])
            if prefetch > 0 and nxt >= 0:
                _prefetch_row(rec, nxt, rec_bytes)
        if param == 0.0:
            zero_run += 1
        if (face < 0 and not math.isfinite(param)) or zero_run > MAX_ZERO_STEPS:
            nudges += 1
            nudge_run += 1
            zero_run = 0
            if nudge_run > MAX_NUDGES_IN_A_ROW:
                status = STATUS_LOST
                break
            tf = _tangent_face(planes[cell], neighbours[cell], x, d, cell_size)
            if tf >= 0:
                _onto_face(planes[cell, tf], x, d, True)
                slide_face = tf
                break
            eta = NUDGE_REL * cell_size
            t += eta * (math.sqrt(m0) / c_ref)
            s += eta
            cell, status = _nudge(planes, neighbours, cell, x, d, eta)
            entry = -1
            break
        dt = _travel_time(m0, gp0, gg, param, c_ref)
        if not (dt >= 0.0):
            status = STATUS_LOST
            break
        if t + dt >= max_time:
            param_end = _sigma_at_time(m0, gp0, gg, max_time - t, param, c_ref)
            _state_at(x, p0, g, param_end, xn, dn)
            ds = _arc_length(p0, g, param_end)
            for i in range(3):
                x[i] = xn[i]
                d[i] = dn[i]
            t = max_time
            s += ds
            status = STATUS_TIME_LIMIT
            break
        _state_at(x, p0, g, param, xn, dn)
        ds = _arc_length(p0, g, param)
        if ds > TINY_STEP_REL * cell_size:
            zero_run = 0
        elif param != 0.0:
            zero_run += 1
        for i in range(3):
            x[i] = xn[i]
            d[i] = dn[i]
        t += dt
        s += ds
        if not (math.isfinite(x[0]) and math.isfinite(x[1]) and math.isfinite(x[2])):
            status = STATUS_LOST
            break
        if param > 0.0:
            nudge_run = 0
        if nxt >= 0:
            pf = 4 * face
            dm = d[0] * rec[cell, pf] + d[1] * rec[cell, pf + 1] + d[2] * rec[cell, pf + 2]
            if nxt == prev_cell and abs(dm) <= SLIDE_COS:
                pp_run += 1
            else:
                pp_run = 0
            if pp_run >= PINGPONG_SLIDE:
                _onto_face(planes[cell, face], x, d, False)
                slide_face = face
                pp_run = 0
                nudges += 1
                break
            prev_cell = cell
            entry = int(rec[cell, o_nf + face])
            cell = nxt
            crossings += 1
        elif nxt == BOUNDARY_REFLECT:
            pf = 4 * face
            dot = d[0] * rec[cell, pf] + d[1] * rec[cell, pf + 1] + d[2] * rec[cell, pf + 2]
            if param == 0.0 and abs(dot) <= GRAZE_COS:
                slide_face = face
                entry = -1
                break
            if reflections >= max_reflections:
                status = STATUS_REFLECTION_LIMIT
                break
            for i in range(3):
                d[i] -= 2.0 * dot * rec[cell, pf + i]
            norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            for i in range(3):
                d[i] /= norm
            reflections += 1
            entry = face
        else:
            status = STATUS_EXITED
        break
    # ---- store the lane; a finished ray is written out and the lane takes the next one
    for i in range(3):
        fst[lane, _F_X + i] = x[i]
        fst[lane, _F_D + i] = d[i]
    fst[lane, _F_T] = t
    fst[lane, _F_S] = s
    ist[lane, _I_CELL] = cell
    ist[lane, _I_ENTRY] = entry
    ist[lane, _I_REFL] = reflections
    ist[lane, _I_CROSS] = crossings
    ist[lane, _I_NUDGES] = nudges
    ist[lane, _I_NUDGE_RUN] = nudge_run
    ist[lane, _I_ZERO_RUN] = zero_run
    ist[lane, _I_SLIDE] = slide_face
    ist[lane, _I_PREV] = prev_cell
    ist[lane, _I_PP] = pp_run
    ist[lane, _I_STEPS] = steps
    ist[lane, _I_STATUS] = status


@njit_inline
def _step_exit(rec, k_faces, o_nb, cell, g, p0, x, entry, cell_size):
    """(parameter, face, next cell) of the exit from ``cell``, as _lane_step finds it (no slide pending: the
    entry face is the excluded one); with no exit (face -1) the next cell is read at face 0 and not used."""
    param, face = _exit_any(rec, k_faces, o_nb, cell, g, p0, x, entry, ON_FACE_REL * cell_size)
    nxt = int(rec[cell, o_nb + max(face, 0)])
    return param, face, nxt


@njit_inline
def _fast_lane(fst, ist, lane, x):
    """Start the lane's common step: its position copied into x (3,); returns (common, cell, entry), common
    False for an idle lane (its cell read as 0) and for a step that starts with a slide pending or with the
    zero-step run at its limit (both handled by _lane_step)."""
    for i in range(3):
        x[i] = fst[lane, _F_X + i]
    ok = ist[lane, _I_RAY] >= 0 and ist[lane, _I_SLIDE] < 0 and ist[lane, _I_ZERO_RUN] <= MAX_ZERO_STEPS
    return ok, ist[lane, _I_CELL] if ok else 0, ist[lane, _I_ENTRY]


@nb.njit(**NJIT_FLAGS)
def trace_block_lanes(packed, mesh, c_ref, limits, origins, directions, cells, out_state, out_counts, queue):
    """Trace the rays of ``queue`` in ``lanes`` interleaved lanes on packed cell records (mesh/packed.py).

    The generic walk (traverse.trace_slots) for the plain parabolic trace, one segment step of each lane's ray
    per round. A ray knows its next cell only at the end of a step, so one ray alone waits for every new cell's
    record; with several lanes, a ray's next record is prefetched (``prefetch`` > 0) as soon as its exit face is
    known and arrives while the other lanes compute. A round takes the lanes stage by stage: every lane's step
    start (n, p, the gradient terms), then every lane's exit search, then the travel times and new states,
    then the arc lengths, then each lane's checks. A stage's lanes are independent, so the processor
    overlaps them (one lane's step is a chain of three square roots and two divisions that it otherwise waits
    on). That is the common step: an interior crossing with a positive parameter inside the time limit. Any
    other outcome (the ray leaves, reflects, stops, stalls on a face, slides, or starts the step with a slide
    pending) throws the lane's stage values away and runs the whole step for it (``_lane_step``), from the
    same state. Both are the generic walk's arithmetic on the same numbers (the records are exact copies),
    so the final states are bit-identical to the generic kernel's for any number of lanes. The rare events
    (nudges, slides, walks) read the mesh's own arrays.

    Lanes whose rays ended take the next ones at the end of the round, so the lanes stay full to the queue's
    end. Threads that run this kernel on one queue share its rays: each takes ``chunk`` neighbouring rays at a
    time (an atomic counter, kernels/atomics.py), and no thread's lanes drain before the last rays are handed
    out. Blocks of 256 rays, one kernel call each, drained their lanes at every block's end: with both cores
    busy 51.0 ns per crossing and core on the slabs and 49.7 ns on the desert, against 48.8 and 47.9 ns with the
    shared queue and 48.3 and 47.8 ns on one core (2026-12-05, one process, 5 rounds of 3).

    packed : PackedCells; mesh : CellMesh; c_ref : m/s; limits : (max_time s, max_reflections, max_steps,
    prefetch 0 | 1, lanes >= 1). origins, directions (n, 3), cells (n,), out_state (n, STATE_SIZE),
    out_counts (n, COUNT_SIZE): inputs, and the generic kernel's output columns (constants.STATE_* / COUNT_*).
    queue : (taken (1,) int64, hi, chunk): rays taken[0] .. hi - 1 are traced (taken[0] is moved past hi).
    """
    max_time, max_reflections, max_steps, prefetch, lanes = limits
    rec = packed.rec
    k_faces = packed.k_faces
    o_g = 4 * k_faces
    o_r = o_g + 3
    o_m = o_g + 6
    o_s = o_g + 7
    o_nb = o_g + 8
    o_nf = o_nb + k_faces
    rec_bytes = 8 * rec.shape[1]
    geo = (k_faces, o_g, o_r, o_m, o_s, o_nb, o_nf, rec_bytes)
    planes = mesh.planes
    neighbours = mesh.neighbours
    taken, hi, chunk = queue
    n_lanes = max(1, min(lanes, hi - taken[0]))  # sizes the lane arrays only (another thread may take rays too)
    fst = np.empty((n_lanes, _F_SIZE))
    ist = np.full((n_lanes, _I_SIZE), -1, dtype=np.int64)
    x = np.empty(3)
    d = np.empty(3)
    xn = np.empty(3)
    dn = np.empty(3)
    # the lanes' common-step values, stage to stage: position, new position and tangent (n_lanes, 3); lf columns
    # m0, g (3), p0 (3), g.p0, |g|^2, cell size, parameter, dt; li columns fast, cell, face, next cell
    lx = np.empty((n_lanes, 3))
    lxn = np.empty((n_lanes, 3))
    ldn = np.empty((n_lanes, 3))
    lf = np.empty((n_lanes, 12))
    li = np.empty((n_lanes, 4), dtype=np.int64)
    lds = np.empty(n_lanes)
    next_ray = 0
    end = 0  # this thread's chunk [next_ray, end): empty until the first take
    busy = 0
    rays_in = (origins, directions, cells)
    rays_out = (out_state, out_counts)
    for lane in range(n_lanes):  # fill the lanes
        next_ray, end = _lane_take(lane, next_ray, end, queue, rays_in, rays_out, fst, ist)
        busy += ist[lane, _I_RAY] >= 0
    idle = n_lanes - busy
    while busy > 0:
        for k in range(n_lanes):
            ok, cell, entry = _fast_lane(fst, ist, k, lx[k])
            ok = ok and ist[k, _I_STEPS] < max_steps
            m0, g, p0, gp0, gg, sz = _step_start(
                rec,
                o_g,
                o_r,
                o_m,
                o_s,
                cell,
                lx[k, 0],
                lx[k, 1],
                lx[k, 2],
                fst[k, _F_D],
                fst[k, _F_D + 1],
                fst[k, _F_D + 2],
            )
            param, face, nxt = _step_exit(rec, k_faces, o_nb, cell, g, p0, (lx[k, 0], lx[k, 1], lx[k, 2]), entry, sz)
            if prefetch > 0:
                _prefetch_row(rec, max(nxt, 0), rec_bytes)
            lf[k, 0] = m0
            lf[k, 1] = g[0]
            lf[k, 2] = g[1]
            lf[k, 3] = g[2]
            lf[k, 4] = p0[0]
            lf[k, 5] = p0[1]
            lf[k, 6] = p0[2]
            lf[k, 7] = gp0
            lf[k, 8] = gg
            lf[k, 9] = sz
            lf[k, 10] = param
            li[k, 0] = ok
            li[k, 1] = cell
            li[k, 2] = face
            li[k, 3] = nxt
        first = 0
        while first + 4 <= n_lanes:  # four lanes at a time as vectors (kernels/lane_advance4.py, the same bits)
            rare = advance4(lf, lx, lxn, ldn, lds, first, c_ref)
            if rare != 0:  # a segment beyond the 3-point rule's range: its length by the scalar helper
                for j in range(4):
                    if (rare >> j) & 1:
                        k = first + j
                        lds[k] = _arc_length((lf[k, 4], lf[k, 5], lf[k, 6]), (lf[k, 1], lf[k, 2], lf[k, 3]), lf[k, 10])
            first += 4
        for k in range(first, n_lanes):
            g = (lf[k, 1], lf[k, 2], lf[k, 3])
            p0 = (lf[k, 4], lf[k, 5], lf[k, 6])
            param = lf[k, 10]
            lf[k, 11] = _travel_time(lf[k, 0], lf[k, 7], lf[k, 8], param, c_ref)
            _state_at(lx[k], p0, g, param, lxn[k], ldn[k])
            lds[k] = _arc_length(p0, g, param)
        for k in range(n_lanes):
            lane = k
            m0 = lf[k, 0]
            param = lf[k, 10]
            dt = lf[k, 11]
            ds = lds[k]
            sz = lf[k, 9]
            ok = li[k, 0] != 0
            cell = li[k, 1]
            face = li[k, 2]
            nxt = li[k, 3]
            xn_ = lxn[k]
            dn_ = ldn[k]
            t = fst[lane, _F_T]
            ok = ok and m0 > 0.0 and math.isfinite(m0) and face >= 0 and param > 0.0 and dt >= 0.0
            ok = ok and t + dt < max_time and ds > TINY_STEP_REL * sz and nxt >= 0
            ok = ok and math.isfinite(xn_[0]) and math.isfinite(xn_[1]) and math.isfinite(xn_[2])
            if ok:
                pp = 0
                if nxt == ist[lane, _I_PREV]:  # back into the cell it came from: grazing along the face?
                    pf = 4 * face
                    dm = dn_[0] * rec[cell, pf] + dn_[1] * rec[cell, pf + 1] + dn_[2] * rec[cell, pf + 2]
                    if abs(dm) <= SLIDE_COS:
                        pp = ist[lane, _I_PP] + 1
                ok = pp < PINGPONG_SLIDE
            if ok:
                for i in range(3):
                    fst[lane, _F_X + i] = xn_[i]
                    fst[lane, _F_D + i] = dn_[i]
                fst[lane, _F_T] = t + dt
                fst[lane, _F_S] = fst[lane, _F_S] + ds
                ist[lane, _I_STEPS] += 1
                ist[lane, _I_ZERO_RUN] = 0
                ist[lane, _I_NUDGE_RUN] = 0
                ist[lane, _I_PP] = pp
                ist[lane, _I_PREV] = cell
                ist[lane, _I_ENTRY] = int(rec[cell, o_nf + face])
                ist[lane, _I_CELL] = nxt
                ist[lane, _I_CROSS] += 1
                continue
            ray = ist[lane, _I_RAY]
            if ray < 0:
                continue
            _lane_step(rec, geo, planes, neighbours, c_ref, limits, fst, ist, lane, x, d, xn, dn)
            if ist[lane, _I_STATUS] == STATUS_RUNNING:
                continue
            _lane_finish(fst[lane], ist[lane], out_state[ray], out_counts[ray])
            ist[lane, _I_RAY] = -1
            busy -= 1
            idle += 1
        if idle > 0 and end >= 0:  # lanes whose rays ended take the next ones (the chunk's, then the queue's)
            for lane in range(n_lanes):
                if ist[lane, _I_RAY] < 0 and end >= 0:
                    next_ray, end = _lane_take(lane, next_ray, end, queue, rays_in, rays_out, fst, ist)
                    if ist[lane, _I_RAY] >= 0:
                        busy += 1
                        idle -= 1

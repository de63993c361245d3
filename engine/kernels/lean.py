"""A lean traversal for the common plain trace: parabolic curve, no wind, no field, no paths, no paraxial state.

The generic kernel (traverse.trace_one) serves every curve kind, field, beam, path recording and wind
with one loop and runtime switches; a job that needs none of them still pays for the switches, the
runtime curve dispatch, the per-cell array views (two atomic reference-count updates each) and the
compile time of all of it. This module is the same walk (Algorithm 1, physics.md section 5) written
for that one case:

- the same arithmetic in the same order on the same mesh arrays (parabolic.plane_coefficients written
  out, roots.face_exit_parameter, parabolic.travel_time / sigma_at_time / state_at / arc_length, and the
  generic kernel's own rare-event helpers for nudges, slides and walks), so the final ray states are
  bit-identical to the generic kernel's (tests/engine/test_lean_traversal.py);
- faces that cannot be exits are skipped before their root is taken: with A <= 0 and B <= 0 the face
  polynomial A u^2 + B u + C has no upward crossing for u > 0 and face_exit_parameter returns +inf for
  every C (also the on-face and tangent cases), so skipping them changes no result;
- the cell walk reads the mesh arrays by index, never through per-cell views;
- memory prefetch (``prefetch`` > 0): once a cell's exit face is known, the next cell's records (planes,
  neighbours, neighbour faces, media, gradient, reference point, size) are prefetched while the segment's
  time and arc length are computed; ``prefetch`` 2 also prefetches the planes and gradients of all of a
  cell's neighbours when the ray enters it. Prefetches only move data into the cache (they never fault
  and change no value).

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
from bentray.engine.kernels.roots import NO_ROOT, face_exit_parameter
from bentray.engine.kernels.traverse import _nudge, _onto_face, _tangent_face

__all__ = ["trace_block_lean", "trace_one_lean"]

# The parabolic helpers compiled as plain (called, not IR-inlined) functions: the very same Python code as
# the generic kernel's, so the same arithmetic, but numba's IR inlining (inline="always") of their four
# call sites and of the prefetch helpers made this kernel compile in about 80 s under load against 22 s
# (LLVM still inlines the small ones at machine-code level).
_travel_time = nb.njit(**NJIT_FLAGS)(parabolic.travel_time.py_func)
_sigma_at_time = nb.njit(**NJIT_FLAGS)(parabolic.sigma_at_time.py_func)
_state_at = nb.njit(**NJIT_FLAGS)(parabolic.state_at.py_func)
_arc_length = nb.njit(**NJIT_FLAGS)(parabolic.arc_length.py_func)
_face_exit_parameter = nb.njit(**NJIT_FLAGS)(face_exit_parameter.py_func)


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


@nb.njit(**NJIT_FLAGS)
def _prefetch_row(arr, row, row_bytes):
    """Every cache line of row ``row`` of ``arr`` (row_bytes long; rows need not be line-aligned)."""
    off = 0
    while off < row_bytes:
        _prefetch(arr, row, off)
        off += 64
    _prefetch(arr, row, row_bytes - 1)


@nb.njit(**NJIT_FLAGS)
def _prefetch_cell(mesh, cell, k_faces):
    """The records the walk reads on entering ``cell``."""
    _prefetch_row(mesh.planes, cell, 32 * k_faces)
    _prefetch_row(mesh.neighbours, cell, 8 * k_faces)
    _prefetch_row(mesh.gradient, cell, 24)
    _prefetch_row(mesh.ref_point, cell, 24)
    _prefetch(mesh.media_ref, cell, 0)
    _prefetch(mesh.size, cell, 0)


@nb.njit(**NJIT_FLAGS)
def trace_one_lean(mesh, c_ref, limits, x_start, d_start, cell, state, counts):
    """Trace one ray (parabolic, no wind/field/paths) from x_start along d_start in ``cell`` (-1: lost).

    mesh : CellMesh; c_ref : reference speed (m/s); limits : (max_time s, max_reflections, max_steps,
    prefetch 0 | 1 | 2 (module docstring)). x_start, d_start : (3,) m / any length. Writes state
    (STATE_SIZE,) and counts (COUNT_SIZE,).
    """
    max_time, max_reflections, max_steps, prefetch = limits
    planes = mesh.planes
    neighbours = mesh.neighbours
    neighbour_face = mesh.neighbour_face
    media_ref = mesh.media_ref
    ref_point = mesh.ref_point
    gradient = mesh.gradient
    size = mesh.size
    k_faces = planes.shape[1]
    x = x_start.copy()
    d = d_start.copy()
    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    for i in range(3):
        d[i] /= norm
    xn = np.empty(3)
    dn = np.empty(3)
    t = 0.0
    s = 0.0
    entry = -1
    reflections = 0
    crossings = 0
    nudges = 0
    nudge_run = 0
    zero_run = 0
    slide_face = -1
    prev_cell = -1
    pp_run = 0
    steps = 0
    status = STATUS_RUNNING
    if cell < 0:
        status = STATUS_LOST
    while status == STATUS_RUNNING:
        if steps >= max_steps:
            status = STATUS_STEP_LIMIT
            break
        steps += 1
        m0 = (
            media_ref[cell]
            + gradient[cell, 0] * (x[0] - ref_point[cell, 0])
            + gradient[cell, 1] * (x[1] - ref_point[cell, 1])
            + gradient[cell, 2] * (x[2] - ref_point[cell, 2])
        )
        g0 = gradient[cell, 0]
        g1 = gradient[cell, 1]
        g2 = gradient[cell, 2]
        exclude = entry
        if slide_face >= 0:
            # slide along the face: the mean gradient of the two sides without its normal part
            nb_cell = neighbours[cell, slide_face]
            if nb_cell >= 0:
                g0 = 0.5 * (g0 + gradient[nb_cell, 0])
                g1 = 0.5 * (g1 + gradient[nb_cell, 1])
                g2 = 0.5 * (g2 + gradient[nb_cell, 2])
            gm = g0 * planes[cell, slide_face, 0] + g1 * planes[cell, slide_face, 1] + g2 * planes[cell, slide_face, 2]
            g0 = g0 - gm * planes[cell, slide_face, 0]
            g1 = g1 - gm * planes[cell, slide_face, 1]
            g2 = g2 - gm * planes[cell, slide_face, 2]
            exclude = slide_face
            slide_face = -1
        if not (m0 > 0.0) or not math.isfinite(m0):
            status = STATUS_LOST
            break
        n0 = math.sqrt(m0)
        p0 = (n0 * d[0], n0 * d[1], n0 * d[2])
        g = (g0, g1, g2)
        gp0 = g0 * p0[0] + g1 * p0[1] + g2 * p0[2]
        gg = g0 * g0 + g1 * g1 + g2 * g2
        cell_size = size[cell]
        on_face_tol = ON_FACE_REL * cell_size
        param = NO_ROOT
        face = -1
        for f in range(k_faces):
            if neighbours[cell, f] == FACE_UNUSED:
                continue
            mx = planes[cell, f, 0]
            my = planes[cell, f, 1]
            mz = planes[cell, f, 2]
            a = 0.25 * (mx * g0 + my * g1 + mz * g2)
            b = mx * p0[0] + my * p0[1] + mz * p0[2]
            if a <= 0.0 and b <= 0.0:
                continue  # no upward crossing for u > 0 whatever C is: face_exit_parameter would give +inf
            c = mx * x[0] + my * x[1] + mz * x[2] - planes[cell, f, 3]
            r = _face_exit_parameter(a, b, c, f == exclude, on_face_tol)
            if r < param:
                param = r
                face = f
        if prefetch > 0 and face >= 0:
            nxt = neighbours[cell, face]
            if nxt >= 0:
                _prefetch_cell(mesh, nxt, k_faces)
                _prefetch_row(neighbour_face, cell, 8 * k_faces)
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
                _onto_face(planes[cell, tf], x, d, True)
                slide_face = tf
                continue
            eta = NUDGE_REL * cell_size
            t += eta * (math.sqrt(m0) / c_ref)
            s += eta
            cell, status = _nudge(planes, neighbours, cell, x, d, eta)
            entry = -1
            continue
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
        nxt = neighbours[cell, face]
        if nxt >= 0:
            dm = d[0] * planes[cell, face, 0] + d[1] * planes[cell, face, 1] + d[2] * planes[cell, face, 2]
            if nxt == prev_cell and abs(dm) <= SLIDE_COS:
                pp_run += 1
            else:
                pp_run = 0
            if pp_run >= PINGPONG_SLIDE:
                # zig-zagging across this face: slide along it in the current cell
                _onto_face(planes[cell, face], x, d, False)
                slide_face = face
                pp_run = 0
                nudges += 1
                continue
            prev_cell = cell
            entry = neighbour_face[cell, face]
            cell = nxt
            crossings += 1
            if prefetch > 1:
                for f in range(k_faces):
                    nb_next = neighbours[cell, f]
                    if nb_next >= 0 and f != entry:
                        _prefetch_row(planes, nb_next, 32 * k_faces)
                        _prefetch_row(gradient, nb_next, 24)
        elif nxt == BOUNDARY_REFLECT:
            dot = d[0] * planes[cell, face, 0] + d[1] * planes[cell, face, 1] + d[2] * planes[cell, face, 2]
            if param == 0.0 and abs(dot) <= GRAZE_COS:
                # on the boundary, moving along it and curving into it: creep along the surface (slide)
                slide_face = face
                entry = -1
                continue
            if reflections >= max_reflections:
                status = STATUS_REFLECTION_LIMIT
                break
            for i in range(3):
                d[i] -= 2.0 * dot * planes[cell, face, i]
            norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            for i in range(3):
                d[i] /= norm
            reflections += 1
            entry = face
        else:
            status = STATUS_EXITED
            break
    for k in range(3):
        state[STATE_X + k] = x[k]
        state[STATE_D + k] = d[k]
    state[STATE_TIME] = t
    state[STATE_LENGTH] = s
    counts[COUNT_STATUS] = status
    counts[COUNT_REFLECTIONS] = reflections
    counts[COUNT_CROSSINGS] = crossings
    counts[COUNT_NUDGES] = nudges
    counts[COUNT_STEPS] = steps
    counts[COUNT_SAMPLES] = 0  # no path samples


@nb.njit(**NJIT_FLAGS)
def trace_block_lean(mesh, c_ref, limits, origins, directions, cells, out_state, out_counts, lo, hi):
    """Trace rays lo..hi-1 with :func:`trace_one_lean` (one thread; the wrapper runs contiguous blocks on
    several threads, the GIL released). origins, directions : (n, 3) float64; cells : (n,) int64;
    out_state (n, STATE_SIZE) float64 and out_counts (n, COUNT_SIZE) int64 are written, row i for ray i."""
    for i in range(lo, hi):
        trace_one_lean(mesh, c_ref, limits, origins[i], directions[i], cells[i], out_state[i], out_counts[i])

"""The analytic traversal as a CUDA kernel (numba-cuda): one thread per ray, final ray states and beam fields.

Shared steps, not a forked traversal. numba-cuda compiles a CPU-jitted (nopython) dispatcher that a CUDA
kernel calls as a CUDA device function from the same Python source
(numba.cuda.target.CUDATypingContext.resolve_value_type wraps its ``py_func`` in a CUDADispatcher with
``device=True``; numba-cuda's own tests call such functions from kernels).
So this kernel calls the CPU traversal's named steps themselves: the curve interface
(kernels/curves.py: setup, find_exit, time_at, param_at_time, evaluate, interior_step, slowness, and through
them parabolic.py, circular.py, nlinear.py, roots.py), the cell model and robustness steps of
kernels/traverse.py (_media_at, _chord_middle, _tangent_face, _walk, _nudge, _onto_face) and the wind
(wind.effective_quantity). What is written here is only the per-ray loop of ``traverse.trace_slots`` that ties
them together, with its paraxial and beam hooks (kernels/paraxial.py: launch, restart, advance, onto_face,
reflect; the beam samples of engine/gpu/beam_device.py, which calls kernels/beams.py's steps and accumulates
with atomics) and without its voxel-field and path-recording hooks (``trace_slots`` itself allocates numpy
arrays, which a CUDA kernel cannot: its scratch arrays become ``cuda.local.array`` here, the per-band beam
amplitudes rows of a global beam_device.BeamScratch). The loop is statement for statement trace_slots', so the
same rays take the same steps and deposit the same chords.

Kernel contract as on the CPU: ``trace_rays_cuda[blocks, threads](mesh, prm, rays, b_grid, b_acc, b_tabs,
p_grid, p_acc, b_pts, b_scr)`` with mesh a mesh.cells.CellMesh of device arrays, prm a traverse.RayParams, rays
a traverse.Rays (out_state, out_counts, refl_cos, refl_mat written; f_weights: the beams' per-ray directivity
factors (n, F) or (n, 0); out_par unused), then the beam field as traverse.trace_rays takes it (beams.BeamGrid,
BeamAcc, BeamTables for the grid, the same for the receiver points with beams.BeamPoints; beam_field.no_beam_args
for none: mode BEAM_OFF, no points) and b_scr a beam_device.BeamScratch with one row per thread. Ray i is thread
i. The ray states share nothing between threads, so they do not depend on the launch configuration or on the
order threads run in; the beam accumulators (slot 0 only) are shared and summed with atomics, in no defined order
(beam_device.py's docstring).

Determinism against the CPU: under numba's CUDA simulator the steps run as the same CPU code, so the states
are bit-identical (tests/gpu). On a device, NVVM contracts a * b + c into fused multiply-adds (numba-cuda
enables FMA even with fastmath off) and libdevice's log1p / atan / expm1 / sqrt may differ from the CPU's by
an ulp; the states then agree to rounding (the device tests allow 1e-9 of the path length, the size of the
traversal's own tolerances) rather than bit for bit.
"""

from __future__ import annotations

import math
from typing import Any

import numba as nb
from numba import cuda as _cuda

from bentray.engine.constants import (
    BEAM_KICK_BOUND_NZ,
    BOUNDARY_REFLECT,
    COUNT_CROSSINGS,
    COUNT_NUDGES,
    COUNT_REFLECTIONS,
    COUNT_SAMPLES,
    COUNT_STATUS,
    COUNT_STEPS,
    GRAZE_COS,
    MAX_NUDGES_IN_A_ROW,
    MAX_ZERO_STEPS,
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
from bentray.engine.gpu.beam_device import beam_segment_device, ray_sample_device
from bentray.engine.kernels import beams, curves, paraxial
from bentray.engine.kernels.traverse import _chord_middle, _media_at, _nudge, _onto_face, _p_at, _tangent_face
from bentray.engine.wind import WIND_NONE, effective_quantity

__all__ = ["THREADS_PER_BLOCK", "trace_rays_cuda"]

cuda: Any = _cuda  # numba.cuda's grid / local are injected at run time (no type information)

_CS_SIZE = curves.CS_SIZE  # module constants: cuda.local.array needs a compile-time literal size
_PAR_SIZE = paraxial.PAR_SIZE
_SEG_SIZE = paraxial.SEG_SIZE
_SAMPLE_SIZE = beams.SAMPLE_SIZE
_WORK_SIZE = beams.WORK_SIZE
_PB_SIZE = beams.PB_SIZE
_S_ARC = beams.S_ARC
THREADS_PER_BLOCK = 128  # rays per block: the loop is register-heavy, small blocks keep occupancy up


@cuda.jit
def trace_rays_cuda(mesh, prm, rays, b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts, b_scr):  # noqa: C901
    """Trace ray ``cuda.grid(1)`` of ``rays`` through ``mesh`` to its end state, depositing its beams (see the
    module docstring; trace_slots' per-ray loop, kept as one function as on the CPU)."""
    i_ray = cuda.grid(1)
    if i_ray >= rays.origins.shape[0]:
        return
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
    refl_cos = rays.refl_cos[i_ray]
    refl_mat = rays.refl_mat[i_ray]
    out_state = rays.out_state[i_ray]
    out_counts = rays.out_counts[i_ray]
    x = cuda.local.array(3, nb.float64)
    d = cuda.local.array(3, nb.float64)
    for i in range(3):
        x[i] = rays.origins[i_ray, i]
        d[i] = rays.directions[i_ray, i]
    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    for i in range(3):
        d[i] /= norm
    e_wind = cuda.local.array(3, nb.float64)
    w_grad = cuda.local.array(3, nb.float64)
    g_eff = cuda.local.array(3, nb.float64)
    x_mid = cuda.local.array(3, nb.float64)
    for i in range(3):
        e_wind[i] = 0.0
    ray_wind = WIND_NONE
    if wind_code != WIND_NONE:
        horizontal = math.sqrt(d[0] * d[0] + d[1] * d[1])
        if horizontal > 0.0:
            e_wind[0] = d[0] / horizontal
            e_wind[1] = d[1] / horizontal
            ray_wind = wind_code
    wind_on = ray_wind != WIND_NONE
    xn = cuda.local.array(3, nb.float64)
    dn = cuda.local.array(3, nb.float64)
    cs = cuda.local.array(_CS_SIZE, nb.float64)
    for i in range(_CS_SIZE):
        cs[i] = 0.0
    g_slide = cuda.local.array(3, nb.float64)
    g = cuda.local.array(3, nb.float64)
    t = 0.0
    s = 0.0
    cell = rays.start_cells[i_ray]
    # paraxial state and beam samples (docs/physics.md §10-11; parabolic curve), as in trace_slots
    beam = beams.Beam(b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts)
    deposit_on = b_grid.mode != beams.BEAM_OFF or b_pts.xyz.shape[0] > 0
    par_on = deposit_on and cell >= 0
    par = cuda.local.array(_PAR_SIZE, nb.float64)
    par_tmp = cuda.local.array(_PAR_SIZE, nb.float64)
    seg = cuda.local.array(_SEG_SIZE, nb.float64)  # the segment record with wind (paraxial.beam_wind_terms)
    for i in range(_SEG_SIZE):
        seg[i] = 0.0
    for i in range(_PAR_SIZE):
        par[i] = 0.0
        par_tmp[i] = 0.0
    p_end = cuda.local.array(3, nb.float64)
    xs = cuda.local.array(3, nb.float64)
    ts = cuda.local.array(3, nb.float64)
    for i in range(3):
        p_end[i] = 0.0
    s_last = cuda.local.array(_SAMPLE_SIZE, nb.float64)
    s_cur = cuda.local.array(_SAMPLE_SIZE, nb.float64)
    for i in range(_SAMPLE_SIZE):
        s_last[i] = 0.0
        s_cur[i] = 0.0
    ist = cuda.local.array(3, nb.int64)
    for i in range(3):
        ist[i] = 0
    amp_last = b_scr.amp_last[i_ray]
    amp_cur = b_scr.amp_cur[i_ray]
    amp0 = b_scr.amp0[i_ray]
    n_bands = amp0.shape[0]
    for f in range(n_bands):
        amp_last[0, f] = 0.0
        amp_last[1, f] = 0.0
        amp_cur[0, f] = 0.0
        amp_cur[1, f] = 0.0
        amp0[f] = 1.0
    bray = beams.BeamRay(
        s_last,
        s_cur,
        amp_last,
        amp_cur,
        ist,
        amp0,
        cuda.local.array(_WORK_SIZE, nb.float64),
        cuda.local.array(_PB_SIZE, nb.float64),
    )
    if deposit_on and rays.f_weights.shape[1] == n_bands:  # beams: f_weights = directivity factors
        for f in range(n_bands):
            amp0[f] = rays.f_weights[i_ray, f]
    launch_cos = math.sqrt(d[0] * d[0] + d[1] * d[1])
    p_norm = 1.0
    if par_on:
        m_start = _media_at(media_ref, ref_point, gradient, cell, x)
        if wind_on:
            m_start = effective_quantity(
                curve, c_ref, m_start, gradient[cell], ray_wind, wind_params, x, e_wind, w_grad, g_eff
            )
        if m_start > 0.0:
            p_norm = math.sqrt(m_start)
            paraxial.launch(par, d, p_norm)
            if deposit_on:
                ray_sample_device(
                    beam, bray, x, d, 0.0, 0.0, p_norm / c_ref, par, (0, refl_cos, refl_mat, launch_cos), True
                )
        else:
            par_on = False
    deposit_on = deposit_on and par_on
    # beams in the smooth medium (mesh/hessian.py), as on the CPU: per-cell Hessians, no face kicks
    hess = b_tabs.hessian
    smooth = deposit_on and not wind_on and hess.shape[0] == planes.shape[0]
    g_nb = cuda.local.array(3, nb.float64)
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
        m0 = _media_at(media_ref, ref_point, gradient, cell, x)
        m_raw = m0
        for i in range(3):
            g[i] = gradient[cell, i]
        if wind_on:
            m0 = effective_quantity(curve, c_ref, m0, g, wind_code, wind_params, x, e_wind, w_grad, g_eff)
            if _chord_middle(planes[cell], neighbours[cell], x, d, x_mid):
                effective_quantity(
                    curve,
                    c_ref,
                    _media_at(media_ref, ref_point, gradient, cell, x_mid),
                    g,
                    wind_code,
                    wind_params,
                    x_mid,
                    e_wind,
                    w_grad,
                    g_eff,
                )
            for i in range(3):
                g[i] = g_eff[i]
        exclude = entry
        if slide_face >= 0:
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
            exclude = slide_face
            slide_face = -1
        if not curves.setup(curve, m0, g, d, cs):
            status = STATUS_LOST
            break
        if par_on and wind_on:  # beams with wind: d m0 in closed form, each cell's gradient fixed (trace_slots)
            paraxial.tangent_derivs(par, d, p_norm, seg)
            paraxial.beam_wind_terms(curve, c_ref, (ray_wind, wind_params, e_wind), m_raw, gradient[cell], x, par,
                                     seg)  # fmt: skip
            paraxial.finish_terms(par, g, seg)
            paraxial.drop_gradient_terms(seg)
        if par_on:  # the segment restarts from this cell's model at x: p' = n'(x) d (docs/physics.md §10)
            n_new = math.sqrt(m0)
            if wind_on:
                paraxial.restart_dm(par, d, p_norm, n_new, seg)
            elif not smooth:  # smooth medium: the state carries on as it is (traverse.trace_slots)
                paraxial.restart(par, d, p_norm, n_new, g)
            p_norm = n_new
        cell_size = size[cell]
        face, param = curves.find_exit(
            curve, cs, x, d, planes[cell], neighbours[cell], exclude, ON_FACE_REL * cell_size, cell_size
        )
        if face < 0:
            param = curves.interior_step(curve, cs)
        if param == 0.0:
            zero_run += 1
        if (face < 0 and not math.isfinite(param)) or zero_run > MAX_ZERO_STEPS:
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
            ds = curves.evaluate(curve, cs, x, d, param_end, xn, dn)
            if par_on:  # HOOK (a), paraxial: the last segment, to max_time
                if deposit_on:
                    beam_segment_device(
                        beam,
                        bray,
                        prm,
                        cs,
                        x,
                        d,
                        (param_end, t, s, ds, cell if smooth else -1),
                        par,
                        (par_tmp, p_end, xs, ts),
                        (reflections, refl_cos, refl_mat, launch_cos),
                    )
                if smooth:
                    paraxial.smooth_advance(par, hess, cell, param_end)
                else:
                    paraxial.advance(par, param_end)
                p_norm = _p_at(cs, param_end, p_end)
                if deposit_on:
                    ray_sample_device(
                        beam,
                        bray,
                        xn,
                        dn,
                        max_time,
                        s + ds,
                        p_norm / c_ref,
                        par,
                        (reflections, refl_cos, refl_mat, launch_cos),
                        False,
                    )
            for i in range(3):
                x[i] = xn[i]
                d[i] = dn[i]
            t = max_time
            s += ds
            status = STATUS_TIME_LIMIT
            break
        ds = curves.evaluate(curve, cs, x, d, param, xn, dn)
        if ds > TINY_STEP_REL * cell_size:
            zero_run = 0
        elif param != 0.0:
            zero_run += 1
        if par_on:  # HOOK (a), paraxial: samples inside the segment, derivatives at its end (on its face)
            if deposit_on:
                beam_segment_device(
                    beam,
                    bray,
                    prm,
                    cs,
                    x,
                    d,
                    (param, t, s, ds, cell if smooth else -1),
                    par,
                    (par_tmp, p_end, xs, ts),
                    (reflections, refl_cos, refl_mat, launch_cos),
                )
            if smooth:
                paraxial.smooth_advance(par, hess, cell, param)
            else:
                paraxial.advance(par, param)
            p_norm = _p_at(cs, param, p_end)
            if face >= 0:
                # exact derivatives, unless the face is slanted: then the kick of a near-tangential crossing is
                # bounded (constants.BEAM_KICK_BOUND_NZ; docs/physics.md §11); par_on implies deposit_on here
                slanted = abs(planes[cell, face, 2]) < BEAM_KICK_BOUND_NZ
                bound = cell_size / p_norm if deposit_on and slanted else math.inf
                if smooth and neighbours[cell, face] >= 0:
                    pass  # the smooth medium has no face here
                elif smooth:  # a boundary: with the smooth medium's gradient at the face point
                    paraxial.smooth_gradient(hess, cell, g, xn, g_nb)
                    paraxial.onto_face(par, planes[cell, face], p_end, g_nb, bound)
                else:
                    paraxial.onto_face(par, planes[cell, face], p_end, g, bound)
                if deposit_on and (neighbours[cell, face] < 0 or s + ds - bray.last[_S_ARC] >= b_tabs.chord_m):
                    ray_sample_device(
                        beam,
                        bray,
                        xn,
                        dn,
                        t + dt,
                        s + ds,
                        p_norm / c_ref,
                        par,
                        (reflections, refl_cos, refl_mat, launch_cos),
                        False,
                    )
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
        if face < 0:
            entry = -1
            continue
        nxt = neighbours[cell, face]
        if nxt >= 0:
            dm = d[0] * planes[cell, face, 0] + d[1] * planes[cell, face, 1] + d[2] * planes[cell, face, 2]
            if nxt == prev_cell and abs(dm) <= SLIDE_COS:
                pp_run += 1
            else:
                pp_run = 0
            if pp_run >= PINGPONG_SLIDE:
                _onto_face(planes[cell, face], x, d, False)
                slide_face = face
                pp_run = 0
                nudges += 1
                continue
            prev_cell = cell
            entry = neighbour_face[cell, face]
            cell = nxt
            crossings += 1
        elif nxt == BOUNDARY_REFLECT:
            dot = d[0] * planes[cell, face, 0] + d[1] * planes[cell, face, 1] + d[2] * planes[cell, face, 2]
            if param == 0.0 and abs(dot) <= GRAZE_COS:
                slide_face = face
                entry = -1
                continue
            if reflections >= max_reflections:
                status = STATUS_REFLECTION_LIMIT
                break
            if reflections < refl_cos.shape[0]:
                refl_cos[reflections] = abs(dot)
                refl_mat[reflections] = face_material[cell, face]
            for i in range(3):
                d[i] -= 2.0 * dot * planes[cell, face, i]
            norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            for i in range(3):
                d[i] /= norm
            reflections += 1
            entry = face
            if par_on:
                paraxial.reflect(par, planes[cell, face])
                if deposit_on:
                    ray_sample_device(
                        beam,
                        bray,
                        x,
                        d,
                        t,
                        s,
                        p_norm / c_ref,
                        par,
                        (reflections, refl_cos, refl_mat, launch_cos),
                        True,
                    )
        else:
            status = STATUS_EXITED
            break
    if deposit_on and s > bray.last[_S_ARC]:  # HOOK (d), paraxial: the last chord
        ray_sample_device(
            beam, bray, x, d, t, s, p_norm / c_ref, par, (reflections, refl_cos, refl_mat, launch_cos), False
        )
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
    out_counts[COUNT_SAMPLES] = 0

"""The analytic traversal as a CUDA kernel (numba-cuda): one thread per ray, final ray states.

Shared steps, not a forked traversal. numba-cuda compiles a CPU-jitted (nopython) dispatcher that a CUDA
kernel calls as a CUDA device function from the same Python source
(numba.cuda.target.CUDATypingContext.resolve_value_type wraps its ``py_func`` in a CUDADispatcher with
``device=True``; numba-cuda's own tests call such functions from kernels).
So this kernel calls the CPU traversal's named steps themselves: the curve interface
(kernels/curves.py: setup, find_exit, time_at, param_at_time, evaluate, interior_step, slowness, and through
them parabolic.py, circular.py, nlinear.py, roots.py), the cell model and robustness steps of
kernels/traverse.py (_media_at, _chord_middle, _tangent_face, _walk, _nudge, _onto_face) and the wind
(wind.effective_quantity). What is written here is only the per-ray loop of ``traverse.trace_one`` that ties
them together, without its field, beam, paraxial and path-recording hooks (``trace_one`` itself allocates
numpy arrays, which a CUDA kernel cannot: its scratch arrays become ``cuda.local.array`` here). The loop is
statement for statement trace_one's, so the same rays take the same steps.

Kernel contract as on the CPU: ``trace_rays_cuda[blocks, threads](mesh, prm, rays)`` with mesh a
mesh.cells.CellMesh of device arrays, prm a traverse.RayParams, rays a traverse.Rays (out_state, out_counts,
refl_cos, refl_mat written; f_weights and out_par unused). Ray i is thread i; nothing is shared between
threads, so the ray states do not depend on the launch configuration or on the order threads run in.

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
from bentray.engine.kernels import curves
from bentray.engine.kernels.traverse import _chord_middle, _media_at, _nudge, _onto_face, _tangent_face
from bentray.engine.wind import WIND_NONE, effective_quantity

__all__ = ["THREADS_PER_BLOCK", "trace_rays_cuda"]

cuda: Any = _cuda  # numba.cuda's grid / local are injected at run time (no type information)

_CS_SIZE = curves.CS_SIZE  # a module constant: cuda.local.array needs a compile-time literal size
THREADS_PER_BLOCK = 128  # rays per block: the loop is register-heavy, small blocks keep occupancy up


@cuda.jit
def trace_rays_cuda(mesh, prm, rays):  # noqa: C901 (trace_one's loop, kept as one function as on the CPU)
    """Trace ray ``cuda.grid(1)`` of ``rays`` through ``mesh`` to its end state (see the module docstring)."""
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
        else:
            status = STATUS_EXITED
            break
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

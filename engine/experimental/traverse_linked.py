"""Traversal with surfaces linked to cells (paper Appendix C; mesh: experimental/linked_mesh.py). FROZEN.

A fork of the main loop (kernels/traverse.py) as it stood before the kernel-contract refactor, with the
helpers it used copied in below: it lacks the main loop's slide, ping-pong and graze fixes and no job can
select it; kept only for the Appendix C bench table (bench/linked_surfaces.py). Do not extend it.


Per cell, as kernels/traverse.py: the curve from the cell's linear media model, its first exit among the
face planes (curves.find_exit). Then every triangle linked to the cell is tested the same way: its plane
(normal into the solid) seen along the curve is the quadratic of roots.py, and the ray reaches it at the
plane's first upward zero crossing (air to solid). A crossing at or before the face exit is accepted when
the point lies in the triangle: barycentric u, v >= -BARY_TOL and u + v <= 1 + BARY_TOL. The nearest one
wins (ties with the face exit go to the surface); the ray reflects specularly with the triangle's normal
(T' = T - 2 (T.m) m) and goes on in the same cell.

Right after a reflection the ray sits on the triangle's plane moving away from it (b < 0); the stable
up-crossing root then returns only a later genuine return to the plane (a curved ray can come back to a
large flat triangle), never the start point, so no "last triangle" exclusion is needed. A point within the
on-face tolerance of a plane moving into it is a hit at parameter 0 (a concave corner's second reflection).

Supported: paths (samples on the true curves), reflections (surfaces and a reflecting top), travel time,
arc length, crossings, nudges and the status codes of trace_slots. Not supported (not needed for the
Appendix C comparison): field accumulation and wind. A ray crossing a BOUNDARY_SOLID face leaked through a
surface and ends as STATUS_LOST.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from bentray.engine.constants import (
    BOUNDARY_OPEN,
    BOUNDARY_REFLECT,
    FACE_UNUSED,
    MAX_NUDGES_IN_A_ROW,
    MAX_WALK,
    MAX_ZERO_STEPS,
    NJIT_FLAGS,
    NUDGE_REL,
    ON_FACE_REL,
    PARALLEL_FLAGS,
    STATUS_EXITED,
    STATUS_LOST,
    STATUS_REFLECTION_LIMIT,
    STATUS_RUNNING,
    STATUS_STEP_LIMIT,
    STATUS_TIME_LIMIT,
)
from bentray.engine.kernels import curves


# --- helpers of kernels/traverse.py at the fork (frozen copies) ---
@nb.njit(**NJIT_FLAGS)
def _media_at(media_ref, ref_point, gradient, cell, x):
    return (
        media_ref[cell]
        + gradient[cell, 0] * (x[0] - ref_point[cell, 0])
        + gradient[cell, 1] * (x[1] - ref_point[cell, 1])
        + gradient[cell, 2] * (x[2] - ref_point[cell, 2])
    )


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
def _emit_segment(
    curve,
    cs,
    x0,
    d0,
    param_end,
    t0,
    s0,
    t_end,
    c_ref,
    t_last,
    dt_sample,
    path_pts,
    path_t,
    path_s,
    base,
    cap,
    count,
    xs,
    ts,
):
    """Interior samples of a segment spanning more than dt_sample (evaluated on the curve)."""
    n_int = int((t_end - t0) / dt_sample)
    if n_int > 2 * cap:
        n_int = 2 * cap
    for j in range(1, n_int + 1):
        prm = param_end * j / (n_int + 1)
        ds = curves.evaluate(curve, cs, x0, d0, prm, xs, ts)
        tt = t0 + curves.time_at(curve, cs, prm, c_ref)
        count = _emit(path_pts, path_t, path_s, base, cap, count, xs, tt, s0 + ds)
        t_last = tt
    return count, t_last


# Barycentric slack of the point-in-triangle test (relative to the triangle's edges): 1e-9 of a 30 m
# triangle is 30 nm. A ray through a shared edge is accepted by both triangles (no leak through the
# crack); the price is a hit up to that distance beyond a convex edge, far below any media error.
BARY_TOL = 1e-9


@nb.njit(**NJIT_FLAGS)
def _surface_hit(curve, cs, x, d, tri_plane, tri_origin, tri_dual, j, best, tol, size, one_nb, xs, ts):
    """Parameter where the curve first reaches triangle j (air to solid) if it is < best, else +inf."""
    _, r = curves.find_exit(curve, cs, x, d, tri_plane[j : j + 1], one_nb, -1, tol, size)
    if not (r <= best) or not math.isfinite(r):
        return math.inf
    if r == 0.0:
        # an immediate hit only for a point on the plane (not one deep on the solid side of its extension)
        c = tri_plane[j, 0] * x[0] + tri_plane[j, 1] * x[1] + tri_plane[j, 2] * x[2] - tri_plane[j, 3]
        if c > tol:
            return math.inf
        for i in range(3):
            xs[i] = x[i]
    else:
        curves.evaluate(curve, cs, x, d, r, xs, ts)
    px = xs[0] - tri_origin[j, 0]
    py = xs[1] - tri_origin[j, 1]
    pz = xs[2] - tri_origin[j, 2]
    u = px * tri_dual[j, 0, 0] + py * tri_dual[j, 0, 1] + pz * tri_dual[j, 0, 2]
    v = px * tri_dual[j, 1, 0] + py * tri_dual[j, 1, 1] + pz * tri_dual[j, 1, 2]
    if u >= -BARY_TOL and v >= -BARY_TOL and u + v <= 1.0 + BARY_TOL:
        return r
    return math.inf


@nb.njit(**NJIT_FLAGS)
def trace_linked_one(
    planes,
    neighbours,
    neighbour_face,
    media_ref,
    ref_point,
    gradient,
    size,
    link_offsets,
    link_tris,
    tri_plane,
    tri_origin,
    tri_dual,
    curve,
    c_ref,
    x_start,
    d_start,
    cell_start,
    max_time,
    max_reflections,
    max_steps,
    record,
    dt_sample,
    path_pts,
    path_t,
    path_s,
    path_base,
    path_cap,
    out_state,
    out_counts,
):
    """Trace one ray. out_state (8,): x, y, z, dx, dy, dz, time_s, length_m.

    out_counts (7,): status, reflections, crossings, nudges, steps, path samples, surface tests.
    """
    x = x_start.copy()
    d = d_start.copy()
    norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    for i in range(3):
        d[i] /= norm
    xn = np.empty(3)
    dn = np.empty(3)
    xs = np.empty(3)
    ts = np.empty(3)
    one_nb = np.zeros(1, dtype=np.int64)
    cs = np.zeros(curves.CS_SIZE)
    t = 0.0
    s = 0.0
    cell = cell_start
    entry = -1
    reflections = 0
    crossings = 0
    nudges = 0
    nudge_run = 0
    zero_run = 0
    steps = 0
    tests = 0
    count = 0
    t_last = 0.0
    status = STATUS_RUNNING
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
        if not curves.setup(curve, m0, gradient[cell], d, cs):
            status = STATUS_LOST
            break
        cell_size = size[cell]
        tol = ON_FACE_REL * cell_size
        face, param = curves.find_exit(curve, cs, x, d, planes[cell], neighbours[cell], entry, tol, cell_size)
        if face < 0:
            param = curves.interior_step(curve, cs)
        hit = -1
        for k in range(link_offsets[cell], link_offsets[cell + 1]):
            j = link_tris[k]
            tests += 1
            r = _surface_hit(curve, cs, x, d, tri_plane, tri_origin, tri_dual, j, param, tol, cell_size, one_nb, xs, ts)
            if r <= param:
                param = r
                hit = j
        if param == 0.0:
            zero_run += 1
        else:
            zero_run = 0
        if (hit < 0 and face < 0 and not math.isfinite(param)) or zero_run > MAX_ZERO_STEPS:
            nudges += 1
            nudge_run += 1
            zero_run = 0
            if nudge_run > MAX_NUDGES_IN_A_ROW:
                status = STATUS_LOST
                break
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
            if record and max_time - t > dt_sample:
                count, t_last = _emit_segment(
                    curve,
                    cs,
                    x,
                    d,
                    param_end,
                    t,
                    s,
                    max_time,
                    c_ref,
                    t_last,
                    dt_sample,
                    path_pts,
                    path_t,
                    path_s,
                    path_base,
                    path_cap,
                    count,
                    xs,
                    ts,
                )
            for i in range(3):
                x[i] = xn[i]
                d[i] = dn[i]
            t = max_time
            s += ds
            status = STATUS_TIME_LIMIT
            break
        ds = curves.evaluate(curve, cs, x, d, param, xn, dn)
        if record and dt > dt_sample:
            count, t_last = _emit_segment(
                curve,
                cs,
                x,
                d,
                param,
                t,
                s,
                t + dt,
                c_ref,
                t_last,
                dt_sample,
                path_pts,
                path_t,
                path_s,
                path_base,
                path_cap,
                count,
                xs,
                ts,
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
        if hit >= 0:
            mx, my, mz = tri_plane[hit, 0], tri_plane[hit, 1], tri_plane[hit, 2]
        elif face < 0:
            entry = -1  # within-cell step (circular quarter turn)
            continue
        else:
            nxt = neighbours[cell, face]
            if nxt >= 0:
                entry = neighbour_face[cell, face]
                cell = nxt
                crossings += 1
                continue
            if nxt == BOUNDARY_OPEN:
                status = STATUS_EXITED
                break
            if nxt != BOUNDARY_REFLECT:
                status = STATUS_LOST  # BOUNDARY_SOLID: leaked through a surface
                break
            mx, my, mz = planes[cell, face, 0], planes[cell, face, 1], planes[cell, face, 2]
        # specular reflection off the surface triangle or the reflecting top
        if reflections >= max_reflections:
            status = STATUS_REFLECTION_LIMIT
            break
        dot = d[0] * mx + d[1] * my + d[2] * mz
        d[0] -= 2.0 * dot * mx
        d[1] -= 2.0 * dot * my
        d[2] -= 2.0 * dot * mz
        norm = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        for i in range(3):
            d[i] /= norm
        reflections += 1
        entry = face if hit < 0 else -1
        if record and t > t_last:
            count = _emit(path_pts, path_t, path_s, path_base, path_cap, count, x, t, s)
            t_last = t
    if record and (count == 0 or t > t_last):
        count = _emit(path_pts, path_t, path_s, path_base, path_cap, count, x, t, s)
    for i in range(3):
        out_state[i] = x[i]
        out_state[3 + i] = d[i]
    out_state[6] = t
    out_state[7] = s
    out_counts[0] = status
    out_counts[1] = reflections
    out_counts[2] = crossings
    out_counts[3] = nudges
    out_counts[4] = steps
    out_counts[5] = count
    out_counts[6] = tests


@nb.njit(**PARALLEL_FLAGS)
def trace_linked_rays(
    planes,
    neighbours,
    neighbour_face,
    media_ref,
    ref_point,
    gradient,
    size,
    link_offsets,
    link_tris,
    tri_plane,
    tri_origin,
    tri_dual,
    curve,
    c_ref,
    origins,
    directions,
    start_cells,
    max_time,
    max_reflections,
    max_steps,
    record,
    dt_sample,
    path_cap,
    path_pts,
    path_t,
    path_s,
    out_state,
    out_counts,
):
    """All rays in parallel (prange over rays); ray i owns its rows and path slice [i cap, (i + 1) cap)."""
    for k in nb.prange(origins.shape[0]):
        i = np.int64(k)  # one signature of trace_linked_one: the prange index is uint64 in the parallel body
        trace_linked_one(
            planes,
            neighbours,
            neighbour_face,
            media_ref,
            ref_point,
            gradient,
            size,
            link_offsets,
            link_tris,
            tri_plane,
            tri_origin,
            tri_dual,
            curve,
            c_ref,
            origins[i],
            directions[i],
            start_cells[i],
            max_time,
            max_reflections,
            max_steps,
            record,
            dt_sample,
            path_pts,
            path_t,
            path_s,
            i * path_cap,
            path_cap,
            out_state[i],
            out_counts[i],
        )

"""Numerical ray integration with the analytic tracer's boundaries, end states and outputs.

The baseline family of the paper's comparison (Weiskopf et al., papers/002: polygonal rays from a
numerical ODE solver, step-doubling adaptive steps, early ray termination), on the same scenes as the
analytic tracer: ``euler`` (fixed step), ``euler_adaptive`` (step doubling), ``rk4`` (fixed step) and
``dopri5`` (Dormand-Prince 5(4), adaptive), integrating the ray ODE in sigma (integrators.py), over
exact closed-form media or a CellMesh's per-cell linear media. Parallel over rays (prange).

Boundaries: the flat ground ``z = ground_z`` reflects specularly, the domain sides are open, the top
``z = domain_max[2]`` is open or reflecting; with mesh media the CellMesh's boundary faces also count
(``BOUNDARY_REFLECT`` reflects with the face's plane normal, ``BOUNDARY_OPEN`` exits). A boundary is
detected when a step ends beyond it (a step that leaves and re-enters within itself is not seen: keep
steps short against the ray's curvature). The crossing is first located on the step's chord (Euler,
whose x and t are linear in the step) or on its cubic Hermite dense output (x, p at both ends: no
new evaluation), then the step is RESTARTED from its start with that reduced length (counted: the
paper's Table 3) and refined by Newton / secant iterations on the restarted step (safeguarded inside
the bracket) until the ray lands within ``LAND_REL (1 + |x|)`` metres of the plane; the point is
snapped onto the plane and the direction reflected (``p' = p - 2 (p.m) m``). Straight rays land with
one restart, curved ones typically with 2-4. The time limit is a boundary in t: the last step is
restarted so that the ray stops at exactly ``max_time_s``. A ray sitting on a boundary whose step
still ends beyond it (curving out of a plane it grazes) is searched for an interior re-entry by
halving; if there is none it *slides*: the end point is projected onto the plane and the outward part
of p reflected (one reflection).

End states as in the analytic tracer: time_limit, reflection_limit, exited, step_limit (``max_steps``
accepted steps), lost (n <= 0, non-finite state, step size underflow, or a mesh walk that did not
converge). ``p`` is not renormalised to ``|p| = n(x)`` after a step unless ``renormalize=True``
(the paper's baselines do not; the effect is measured in bench/baselines_probe.py).

Paraxial state (``paraxial=True``; docs/physics.md §10, "Numerical baselines"): the launch-angle
derivatives V = (X_el, X_az, P_el, P_az) start as the analytic tracer's (X = 0, P = n0 dd0/dgamma) and
follow each accepted step by integrators.var_step (the step's own tableau and stages on the variational
equations); a landing on a boundary plane projects them onto it (the neighbouring ray's landing step is
dh = -(m.X)/(m.x_h) longer, x_h, p_h the step map's rates in its length: X += x_h dh, P += p_h dh), a
reflection mirrors them, and
renormalisation is differentiated. Euler's and RK4's fixed step length h = step_m / n(x) is differentiated too
(dh = -h grad n.X / n).
Not differentiated: the adaptive step-size choice, slides along grazed planes. The result's ``paraxial``
column layout is the analytic tracer's (n, 13), its last column |p|.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from bentray.engine.baselines.integrators import (
    EVALS_PER_STEP,
    EVENT_PLANE,
    EVENT_TIME,
    MAX_STAGES,
    MEDIA_MESH,
    METHOD_CODES,
    METHOD_EULER,
    METHOD_RK4,
    NV,
    NY,
    advance,
    controlled_step,
    first_guess,
    land,
    make_media,
    media_n,
    new_step_work,
    plane_g,
    rhs,
    var_step,
)
from bentray.engine.baselines.mesh_media import WALK_FAILED, walk
from bentray.engine.constants import (
    BOUNDARY_OPEN,
    BOUNDARY_REFLECT,
    COUNT_CROSSINGS,
    COUNT_REFLECTIONS,
    COUNT_STATUS,
    NJIT_FLAGS,
    PARALLEL_FLAGS,
    STATE_D,
    STATE_LENGTH,
    STATE_SIZE,
    STATE_TIME,
    STATE_X,
    STATUS_EXITED,
    STATUS_LOST,
    STATUS_REFLECTION_LIMIT,
    STATUS_RUNNING,
    STATUS_STEP_LIMIT,
    STATUS_TIME_LIMIT,
)
from bentray.engine.kernels.llvm_inline import njit_inline
from bentray.engine.kernels.paraxial import launch as paraxial_launch
from bentray.engine.kernels.paraxial import reflect as paraxial_reflect
from bentray.engine.kernels.traverse import PAR_OUT_SIZE, PathBuffers
from bentray.engine.mesh.cells import CellMesh, locate_points
from bentray.engine.result import TraceResult, gather_paths, kernel_trace_result
from bentray.engine.tracer import path_capacity

__all__ = ["trace_numerical", "NUMERICAL_METHODS"]

NUMERICAL_METHODS = tuple(METHOD_CODES)

# A ray has landed on a plane when |m.x - h| <= LAND_REL (1 + max|x_i|) metres: ~200 ulps of a
# coordinate, so regula falsi reaches it in a few restarts, and 3e-10 m at km range, far below any
# integrator error measured here (the snap onto the plane moves the point by at most this).
LAND_REL = 1e-13
# ... and on the time limit when |t - max_time| <= TIME_LAND_REL max(1, max_time) seconds (then t is
# set to max_time exactly).
TIME_LAND_REL = 1e-14
# Halvings of a step tried to find an interior point back inside a plane the ray starts on.
MAX_GRAZE_HALVINGS = 8
# A landing that reveals an earlier crossing of another boundary is re-targeted at most this often.
MAX_RETARGETS = 8

EVENT_NONE = 0

# out_counts columns after the three shared with the analytic tracer (constants.COUNT_STATUS ..
# COUNT_CROSSINGS): the integrators' own counters.
NCOUNT_STEPS = 3  # accepted steps
NCOUNT_RESTARTS = 4  # steps restarted to land on a boundary or the time limit
NCOUNT_REJECTED = 5  # steps rejected by the adaptive control
NCOUNT_EVALS = 6  # right-hand-side evaluations
NCOUNT_SAMPLES = 7  # path samples recorded
NCOUNT_SIZE = 8


@nb.njit(**NJIT_FLAGS)
def _detect(y0, y1, bplanes, btags, media, cell, max_time, eps_x, eps_t, evp, grz):
    """Earliest boundary event of the step y0 -> y1, ordered by chord fraction.

    Planes the ray sits on at y0 while not moving outward (g0 >= -eps, p.m <= 0) are not events but
    "grazing departures": the most violated one is copied into ``grz`` (4,) with its tag returned.
    Returns (kind, tag, frac, g0, g1, grz_tag, walk_ok); a plane event's plane is copied into evp (4,).
    """
    best = 2.0
    kind = EVENT_NONE
    tag = 0
    bg0 = 0.0
    bg1 = 0.0
    grz_tag = 0
    grz_g = eps_x
    g1t = y1[6] - max_time
    if g1t > eps_t:
        g0t = y0[6] - max_time
        best = -g0t / (g1t - g0t) if g0t < 0.0 else 0.0
        kind = EVENT_TIME
        bg0 = g0t
        bg1 = g1t
    n_planes = bplanes.shape[0]
    walk_ok = True
    extra = 0
    face = -1
    cell1 = cell
    if media[0] == MEDIA_MESH:
        cell1, face, _ = walk(media[3], media[4], cell, y1, eps_x)
        walk_ok = face != WALK_FAILED
        if face >= 0:
            extra = 1
    for j in range(n_planes + extra):
        pl = bplanes[j] if j < n_planes else media[3][cell1, face]
        g1 = plane_g(pl, y1)
        if not (g1 > eps_x):
            continue
        g0 = plane_g(pl, y0)
        pm = pl[0] * y0[3] + pl[1] * y0[4] + pl[2] * y0[5]
        jtag = btags[j] if j < n_planes else media[4][cell1, face]
        if g0 >= -eps_x and pm <= 0.0:
            if g1 > grz_g:
                grz_g = g1
                grz_tag = jtag
                for i in range(4):
                    grz[i] = pl[i]
            continue
        f = -g0 / (g1 - g0) if g0 < 0.0 else 0.0
        if f < best:
            best = f
            kind = EVENT_PLANE
            tag = jtag
            bg0 = g0
            bg1 = g1
            for i in range(4):
                evp[i] = pl[i]
    return kind, tag, best, bg0, bg1, grz_tag, walk_ok


class NumParams(NamedTuple):
    """What every ray of one trace_numerical call shares: method (METHOD_CODES value), max_time (s),
    max_reflections, max_steps (accepted steps), step_m (m of arc: fixed step, or the first adaptive one),
    tol (absolute local error per step), renormalize (|p| = n after each step), record (path samples on),
    dt_sample (s between path samples)."""

    method: int
    max_time: float
    max_reflections: int
    max_steps: int
    step_m: float
    tol: float
    renormalize: bool
    record: bool
    dt_sample: float
    paraxial: bool


class Bounds(NamedTuple):
    """The explicit boundary planes (n_b, 4) ``(m, h)`` (inside: m.x <= h) and their tags (n_b,) int64
    (BOUNDARY_OPEN / BOUNDARY_REFLECT): :func:`boundary_planes`."""

    planes: np.ndarray
    tags: np.ndarray


class NumRays(NamedTuple):
    """Per-ray inputs and outputs, row i for ray i: origins, directions (n, 3) m / any non-zero length;
    start_cells (n,) int64 (mesh media; -1: lost); out_state (n, STATE_SIZE) float64 and out_counts
    (n, NCOUNT_SIZE) int64 (written; columns constants.STATE_* and COUNT_STATUS .. COUNT_CROSSINGS, NCOUNT_*);
    out_par (n, PAR_OUT_SIZE) the final paraxial state (written when NumParams.paraxial; else (0, PAR_OUT_SIZE))."""

    origins: np.ndarray
    directions: np.ndarray
    start_cells: np.ndarray
    out_state: np.ndarray
    out_counts: np.ndarray
    out_par: np.ndarray


@nb.njit(**NJIT_FLAGS)
def _emit(paths, cnt, base, y):
    """Path sample of state y (x, t, s) into row base + cnt[NCOUNT_SAMPLES] of paths, while there is room."""
    count = cnt[NCOUNT_SAMPLES]
    if count < paths.cap:
        k = base + count
        paths.pts[k, 0] = y[0]
        paths.pts[k, 1] = y[1]
        paths.pts[k, 2] = y[2]
        paths.t[k] = y[6]
        paths.s[k] = y[7]
        cnt[NCOUNT_SAMPLES] = count + 1


@nb.njit(**NJIT_FLAGS)
def _emit_interior(paths, cnt, base, sw, h, dt_sample):
    """Samples inside a step sw.y0 -> sw.y1 (length h in sigma) longer than dt_sample: cubic Hermite in
    sigma (x, t, s and their sigma-derivatives sw.k1, sw.knew at both ends), evenly spaced in sigma like
    the analytic tracer's (sw.ys is overwritten)."""
    y0, k0, y1, k1, ys = sw.y0, sw.k1, sw.y1, sw.knew, sw.ys
    n_int = int((y1[6] - y0[6]) / dt_sample)
    if n_int > 2 * paths.cap:
        n_int = 2 * paths.cap
    for j in range(1, n_int + 1):
        u = j / (n_int + 1)
        h00 = (1.0 + 2.0 * u) * (1.0 - u) * (1.0 - u)
        h10 = u * (1.0 - u) * (1.0 - u)
        h01 = u * u * (3.0 - 2.0 * u)
        h11 = u * u * (u - 1.0)
        for i in (0, 1, 2, 6, 7):
            ys[i] = h00 * y0[i] + h10 * h * k0[i] + h01 * y1[i] + h11 * h * k1[i]
        _emit(paths, cnt, base, ys)


@nb.njit(**NJIT_FLAGS)
def _reflect(pl, y, k, reflections, max_reflections):
    """Specular reflection p' = p - 2 (p.m) m off plane ``pl`` (k[0:3] = p kept in step).

    Returns (status, reflections): REFLECTION_LIMIT (no reflection; the ray stops on the face) when
    ``max_reflections`` were already made.
    """
    if reflections >= max_reflections:
        return STATUS_REFLECTION_LIMIT, reflections
    pm = pl[0] * y[3] + pl[1] * y[4] + pl[2] * y[5]
    if pm > 0.0:
        for i in range(3):
            y[3 + i] -= 2.0 * pm * pl[i]
            k[i] = y[3 + i]
    return STATUS_RUNNING, reflections + 1


@nb.njit(**NJIT_FLAGS)
def _finite(y):
    for i in range(NY):
        if not math.isfinite(y[i]):
            return False
    return True


@njit_inline
def _land_events(prm, media, bounds, cell, sw, h, eps_x, eps_t, ev, ok):
    """Land the step sw.y0 -> sw.y1 (length h) on its earliest event ``ev = (kind, tag, g0, g1)`` (plane in
    sw.evp), by restarts; an earlier crossing of another boundary that the landing reveals re-targets it
    (at most MAX_RETARGETS times). Returns (ok, has_knew, h_end, ev_kind, ev_tag, moved, restarts)."""
    kind, tag, g0, g1 = ev
    y0, y1, evp = sw.y0, sw.y1, sw.evp
    ev_kind = EVENT_NONE
    ev_tag = 0
    h_end = h
    moved = False
    has = True
    restarts = 0
    for _ in range(MAX_RETARGETS + 1):
        if kind == EVENT_NONE or not ok:
            break
        hk = first_guess(prm.method, kind, evp, y0, y1, h_end, g0, g1, media[9])
        eps = eps_t if kind == EVENT_TIME else eps_x
        bracket = (0.0, min(g0, 0.0), h_end, g1)
        h_end, ok, has, nr = land(prm.method, media, cell, sw, bracket, hk, kind, evp, prm.max_time, eps)
        restarts += nr
        ev_kind = kind
        ev_tag = tag
        if kind == EVENT_TIME:
            y1[6] = prm.max_time
        else:
            gg = plane_g(evp, y1)
            for i in range(3):
                y1[i] -= gg * evp[i]
            moved = True
        # an earlier crossing of another boundary revealed by the landing re-targets it
        kind, tag, _frac, g0, g1, _grz_tag, walk_ok = _detect(
            y0, y1, bounds.planes, bounds.tags, media, cell, prm.max_time, eps_x, eps_t, evp, sw.ys
        )
        ok = ok and walk_ok
    return ok, has, h_end, ev_kind, ev_tag, moved, restarts


@njit_inline
def _leave_grazed(prm, media, cell, sw, h_end, g_end, eps_x, grz_tag, ev_kind, ev_tag):
    """The step (length h_end, ending g_end > eps_x beyond the plane sw.grz the ray sits on) left a grazed
    plane: find an interior re-entry by halving and land on it, else take the step and slide along the
    plane (its end projected onto it). Returns (ok, has_knew, h_end, ev_kind, ev_tag, slide_tag, restarts)."""
    y0, k1, y1, grz, evp = sw.y0, sw.k1, sw.y1, sw.grz, sw.evp
    method = prm.method
    restarts = 0
    slide_tag = 0
    hk = h_end
    glo = 0.0
    found = False
    for _ in range(MAX_GRAZE_HALVINGS):
        hk *= 0.5
        ok, has = advance(method, media, cell, y0, k1, hk, y1, sw.knew, sw.yerr, sw.work)
        restarts += 1
        glo = plane_g(grz, y1)
        if not ok or glo < -eps_x:
            found = ok
            break
    if found:
        h_guess = hk + (h_end - hk) * (-glo) / (g_end - glo)
        h_end, ok, has, nr = land(method, media, cell, sw, (hk, glo, h_end, g_end), h_guess, EVENT_PLANE, grz,
                                  prm.max_time, eps_x)  # fmt: skip
        ev_kind = EVENT_PLANE
        ev_tag = grz_tag
        for i in range(4):
            evp[i] = grz[i]
    else:
        ok, has = advance(method, media, cell, y0, k1, h_end, y1, sw.knew, sw.yerr, sw.work)
        nr = 1
        slide_tag = grz_tag
        if ev_kind == EVENT_TIME:  # re-apply the landing's snap to the re-taken step
            y1[6] = prm.max_time
        elif ev_kind == EVENT_PLANE:
            gg = plane_g(evp, y1)
            for i in range(3):
                y1[i] -= gg * evp[i]
    restarts += nr
    gg = plane_g(grz, y1)
    for i in range(3):
        y1[i] -= gg * grz[i]
    return ok, has, h_end, ev_kind, ev_tag, slide_tag, restarts


@nb.njit(**NJIT_FLAGS)
def _resolve_events(prm, media, bounds, cell, sw, h, eps_x, eps_t):
    """Shorten the step sw.y0 -> sw.y1 (length h) to the earliest boundary or time event, by restarts.

    On return sw.y1 is the final end state (on the event's plane / at max_time, or the untouched step).
    Returns (ok, has_knew, h_end, ev_kind, ev_tag, slide_tag, moved, restarts): ``sw.evp`` holds the
    event's plane, ``sw.grz`` a grazed plane the ray slid along (slide_tag != 0), ``moved`` whether x was
    snapped or projected (so f(y1) must be re-evaluated).
    """
    kind, tag, _, g0, g1, grz_tag, ok = _detect(
        sw.y0, sw.y1, bounds.planes, bounds.tags, media, cell, prm.max_time, eps_x, eps_t, sw.evp, sw.grz
    )
    ok, has, h_end, ev_kind, ev_tag, moved, restarts = _land_events(
        prm, media, bounds, cell, sw, h, eps_x, eps_t, (kind, tag, g0, g1), ok
    )
    slide_tag = 0
    g_end = plane_g(sw.grz, sw.y1)
    if ok and grz_tag != 0 and g_end > eps_x:
        ok, has, h_end, ev_kind, ev_tag, slide_tag, nr = _leave_grazed(
            prm, media, cell, sw, h_end, g_end, eps_x, grz_tag, ev_kind, ev_tag
        )
        restarts += nr
        moved = True
    return ok, has, h_end, ev_kind, ev_tag, slide_tag, moved, restarts


@njit_inline
def _launch(media, bounds, sw, cnt, x_start, d_start, cell):
    """Initial state y0 = (x, n d / |d|, 0, 0) and f(y0) into sw.k1 (one evaluation counted in cnt).

    Returns (status, n0, |d|): LOST when n is not positive / finite there, d is zero, f fails or the
    origin lies outside a boundary plane.
    """
    y0 = sw.y0
    nrm = math.sqrt(d_start[0] ** 2 + d_start[1] ** 2 + d_start[2] ** 2)
    for i in range(3):
        y0[i] = x_start[i]
    n0 = math.nan
    if media[0] != MEDIA_MESH or cell >= 0:
        n0 = media_n(media, cell, y0, sw.ys)
    if not (n0 > 0.0 and math.isfinite(n0) and nrm > 0.0):
        return STATUS_LOST, n0, nrm
    status = STATUS_RUNNING
    for i in range(3):
        y0[3 + i] = n0 * d_start[i] / nrm
    eps0 = LAND_REL * (1.0 + max(abs(y0[0]), abs(y0[1]), abs(y0[2])))
    for j in range(bounds.planes.shape[0]):
        if plane_g(bounds.planes[j], y0) > eps0:
            status = STATUS_LOST  # origin outside the domain
    if not rhs(media, cell, y0, sw.k1):
        status = STATUS_LOST
    cnt[NCOUNT_EVALS] += 1
    return status, n0, nrm


@njit_inline
def _apply_events(prm, sw, cnt, ev_kind, ev_tag, slide_tag, eps_t):
    """The accepted step's events at sw.y0: time limit, exit through an open plane, reflection (counted in
    cnt), a slide along a grazed plane (an open one exits, a reflecting one reflects the outward part of p).
    Returns the status."""
    y0, k1, evp, grz = sw.y0, sw.k1, sw.evp, sw.grz
    status = STATUS_RUNNING
    reflections = cnt[COUNT_REFLECTIONS]
    if ev_kind == EVENT_TIME or y0[6] >= prm.max_time - eps_t:
        y0[6] = prm.max_time
        status = STATUS_TIME_LIMIT
    elif ev_kind == EVENT_PLANE and ev_tag == BOUNDARY_OPEN:
        status = STATUS_EXITED
    elif ev_kind == EVENT_PLANE:
        status, reflections = _reflect(evp, y0, k1, reflections, prm.max_reflections)
    if status == STATUS_RUNNING and slide_tag == BOUNDARY_OPEN:
        status = STATUS_EXITED
    elif status == STATUS_RUNNING and slide_tag == BOUNDARY_REFLECT:
        if grz[0] * y0[3] + grz[1] * y0[4] + grz[2] * y0[5] > 0.0:
            status, reflections = _reflect(grz, y0, k1, reflections, prm.max_reflections)
    cnt[COUNT_REFLECTIONS] = reflections
    return status


@njit_inline
def _step(media, bounds, prm, paths, sw, cnt, base, cell, h_next, t_last, eps_t, vw):
    """One accepted step from sw.y0 (trial length h_next) with its events, path samples (ray's slice from
    row ``base``) and the mesh walk; counters in cnt. vw : the variational arrays (v0, v1, work), advanced
    when prm.paraxial. Returns (status, cell, h_next, t_last)."""
    y0, y1, k1, knew = sw.y0, sw.y1, sw.k1, sw.knew
    n_per = EVALS_PER_STEP[prm.method]
    ok, has, h, h_next, rej = controlled_step(
        prm.method, media, cell, y0, k1, h_next, prm.step_m, prm.tol, y1, knew, sw.yerr, sw.work
    )
    cnt[NCOUNT_REJECTED] += rej
    cnt[NCOUNT_EVALS] += (rej + 1) * n_per
    if not ok:
        return STATUS_LOST, cell, h_next, t_last
    cnt[NCOUNT_STEPS] += 1
    eps_x = LAND_REL * (1.0 + max(abs(y1[0]), abs(y1[1]), abs(y1[2])))
    # fast path: nothing crossed (the common step) -> no event machinery (mesh faces need the walk)
    crossed = media[0] == MEDIA_MESH or y1[6] - prm.max_time > eps_t
    bplanes = bounds.planes
    for j in range(bplanes.shape[0]):
        g1 = bplanes[j, 0] * y1[0] + bplanes[j, 1] * y1[1] + bplanes[j, 2] * y1[2] - bplanes[j, 3]
        crossed = crossed or g1 > eps_x
    ev_kind = EVENT_NONE
    ev_tag = 0
    slide_tag = 0
    moved = False
    h_end = h
    if crossed:
        ok, has2, h_end, ev_kind, ev_tag, slide_tag, moved, nr = _resolve_events(
            prm, media, bounds, cell, sw, h, eps_x, eps_t
        )
        cnt[NCOUNT_RESTARTS] += nr
        cnt[NCOUNT_EVALS] += nr * n_per
        if nr > 0:
            has = has2
    if not (ok and _finite(y1)):
        return STATUS_LOST, cell, h_next, t_last
    # ---- accept: f(y1), path samples, cell, then the events ----
    if moved or not has:
        if not rhs(media, cell, y1, knew):
            return STATUS_LOST, cell, h_next, t_last
        cnt[NCOUNT_EVALS] += 1
    if prm.record and y1[6] - y0[6] > prm.dt_sample:
        _emit_interior(paths, cnt, base, sw, h_end, prm.dt_sample)
    v0, v1, vwork, vrate = vw
    if prm.paraxial:
        landed = ev_kind == EVENT_PLANE
        # a fixed-step method's length h = step_m / n(x0) moves with the launch too (an adaptive one's
        # controller is not differentiated); a landing's length is set by its plane instead
        fixed = (prm.method == METHOD_EULER or prm.method == METHOD_RK4) and ev_kind == EVENT_NONE
        with_rate = landed or fixed
        var_step(prm.method, media, cell, y0, h_end, sw.work, v0, v1, vwork, vrate if with_rate else vrate[:0])
        if landed:
            _var_onto_plane(v1, sw.evp, vrate)
        elif fixed:
            _var_fixed_length(v0, v1, k1, h_end, vrate)
        for i in range(NV):
            v0[i] = v1[i]
    for i in range(NY):
        k1[i] = knew[i]
        y0[i] = y1[i]
    if media[0] == MEDIA_MESH:
        cell, face, mv = walk(media[3], media[4], cell, y0, eps_x)
        cnt[COUNT_CROSSINGS] += mv
        if face == WALK_FAILED:
            return STATUS_LOST, cell, h_next, t_last
    if prm.record and y0[6] - t_last >= prm.dt_sample:
        _emit(paths, cnt, base, y0)
        t_last = y0[6]
    refl_before = cnt[COUNT_REFLECTIONS]
    status = _apply_events(prm, sw, cnt, ev_kind, ev_tag, slide_tag, eps_t)
    if prm.paraxial and cnt[COUNT_REFLECTIONS] > refl_before:
        paraxial_reflect(v0, sw.evp if ev_kind == EVENT_PLANE and ev_tag == BOUNDARY_REFLECT else sw.grz)
    if prm.record and cnt[COUNT_REFLECTIONS] > refl_before and y0[6] > t_last:
        _emit(paths, cnt, base, y0)
        t_last = y0[6]
    if prm.renormalize and status == STATUS_RUNNING:
        pn = math.sqrt(y0[3] ** 2 + y0[4] ** 2 + y0[5] ** 2)
        if prm.paraxial:
            _var_renormalize(v0, y0, k1, pn)
        for i in range(3):
            y0[3 + i] *= k1[7] / pn
            k1[i] = y0[3 + i]
    return status, cell, h_next, t_last


@njit_inline
def _var_onto_plane(v, pl, f1):
    """The derivatives on the plane pl the step landed on: dsigma_k = -(m.X_k)/(m.x'), X_k += x' dsigma_k,
    P_k += p' dsigma_k with (x', p') = f1[0:6] the step map's rates in its length (var_step)."""
    mr = pl[0] * f1[0] + pl[1] * f1[1] + pl[2] * f1[2]
    if mr == 0.0:
        return
    for k in range(2):
        o = 3 * k
        ds = -(pl[0] * v[o] + pl[1] * v[o + 1] + pl[2] * v[o + 2]) / mr
        for i in range(3):
            v[o + i] += f1[i] * ds
            v[6 + o + i] += f1[3 + i] * ds


@njit_inline
def _var_fixed_length(v0, v1, f0, h, rate):
    """The fixed step length h = step_m / n(x0) of Euler and RK4 moves with the launch: dh_k = -h (grad n .
    X_k(0)) / n = -h (f0[3:6] . X_k(0)) / n^2 (f0 = f(y0): f0[3:6] = n grad n, f0[7] = n); v1 += rate dh_k."""
    n2 = f0[7] * f0[7]
    for k in range(2):
        o = 3 * k
        dh = -h * (f0[3] * v0[o] + f0[4] * v0[o + 1] + f0[5] * v0[o + 2]) / n2
        for i in range(3):
            v1[o + i] += rate[i] * dh
            v1[6 + o + i] += rate[3 + i] * dh


@njit_inline
def _var_renormalize(v, y, f, pn):
    """Derivative of p' = n(x) p/|p| (pn = |p|, f = f(y): f[3:6] = n grad n, f[7] = n):
    P_k' = (grad n . X_k) p/|p| + (n/|p|) (P_k - p^ (p^.P_k))."""
    n = f[7]
    for k in range(2):
        o = 3 * k
        gx = (f[3] * v[o] + f[4] * v[o + 1] + f[5] * v[o + 2]) / n
        pp = (y[3] * v[6 + o] + y[4] * v[7 + o] + y[5] * v[8 + o]) / pn
        for i in range(3):
            v[6 + o + i] = gx * y[3 + i] / pn + (n / pn) * (v[6 + o + i] - pp * y[3 + i] / pn)


@njit_inline
def _own_inputs(media, bounds):
    """Per-ray copies of the small shared inputs: every call that passes an array touches its reference
    count (an atomic add), and two threads hitting the same shared counters serialise each other."""
    bounds = Bounds(bounds.planes.copy(), bounds.tags.copy())
    if media[0] != MEDIA_MESH:  # exact media: the parameters and the 1-element mesh placeholders
        media = (
            media[0],
            media[1],
            media[2].copy(),
            media[3].copy(),
            media[4].copy(),
            media[5].copy(),
            media[6].copy(),
            media[7].copy(),
            media[8],
            media[9],
        )
    return media, bounds


@nb.njit(**NJIT_FLAGS)
def trace_one(media, bounds, prm, paths, rays, i):
    """Integrate ray i of ``rays`` (NumRays) from its start to its end state.

    media : the integrators.make_media tuple; bounds : Bounds; prm : NumParams; paths : traverse.PathBuffers
    (ray i's slice from row i * paths.cap). Writes rays.out_state[i] (columns constants.STATE_*: x, d,
    time_s, length_m) and rays.out_counts[i] (NCOUNT_SIZE,): status, reflections, cell crossings
    (constants.COUNT_STATUS, _REFLECTIONS, _CROSSINGS, shared with the analytic tracer), then NCOUNT_STEPS
    (accepted steps), NCOUNT_RESTARTS, NCOUNT_REJECTED (rejected steps), NCOUNT_EVALS (right-hand-side
    evaluations), NCOUNT_SAMPLES (path samples).
    """
    media, bounds = _own_inputs(media, bounds)
    sw = new_step_work()
    y0 = sw.y0
    cnt = rays.out_counts[i]
    for k in range(cnt.shape[0]):
        cnt[k] = 0
    base = i * paths.cap
    cell = rays.start_cells[i]
    d_start = rays.directions[i]
    eps_t = TIME_LAND_REL * max(1.0, prm.max_time)
    status, n0, nrm = _launch(media, bounds, sw, cnt, rays.origins[i], d_start, cell)
    vw = (np.zeros(NV), np.zeros(NV), np.zeros((2 * MAX_STAGES + 4, NV)), np.zeros(6))
    if prm.paraxial and status == STATUS_RUNNING:
        d_unit = np.empty(3)
        for k in range(3):
            d_unit[k] = d_start[k] / nrm
        paraxial_launch(vw[0], d_unit, n0)
    if prm.record:
        _emit(paths, cnt, base, y0)
    t_last = 0.0
    h_next = prm.step_m / n0 if n0 > 0.0 else 0.0
    while status == STATUS_RUNNING:
        if cnt[NCOUNT_STEPS] >= prm.max_steps:
            status = STATUS_STEP_LIMIT
            break
        status, cell, h_next, t_last = _step(media, bounds, prm, paths, sw, cnt, base, cell, h_next, t_last, eps_t, vw)
    if prm.record and (cnt[NCOUNT_SAMPLES] == 0 or y0[6] > t_last):
        _emit(paths, cnt, base, y0)
    out_state = rays.out_state[i]
    pn = math.sqrt(y0[3] ** 2 + y0[4] ** 2 + y0[5] ** 2)
    for k in range(3):
        out_state[STATE_X + k] = y0[k]
        out_state[STATE_D + k] = y0[3 + k] / pn if pn > 0.0 else d_start[k] / nrm
    out_state[STATE_TIME] = y0[6]
    out_state[STATE_LENGTH] = y0[7]
    cnt[COUNT_STATUS] = status
    if prm.paraxial:
        out_par = rays.out_par[i]
        for k in range(NV):
            out_par[k] = vw[0][k]
        out_par[NV] = pn


@nb.njit(**PARALLEL_FLAGS)
def trace_rays_numerical(media, bounds, prm, paths, rays):
    """All rays in parallel (prange); ray i owns rays.out_state[i], rays.out_counts[i] and the path slice
    ``[i * paths.cap, (i + 1) * paths.cap)``: no shared writes, deterministic results. media : the
    integrators.make_media tuple; bounds : Bounds; prm : NumParams; paths : traverse.PathBuffers;
    rays : NumRays."""
    for i in nb.prange(rays.origins.shape[0]):
        trace_one(media, bounds, prm, paths, rays, np.int64(i))  # one signature (the prange index is uint64 too)


def boundary_planes(
    domain_min: np.ndarray, domain_max: np.ndarray, ground_z: float, top: str
) -> tuple[np.ndarray, np.ndarray]:
    """Explicit boundary planes ``(m, h)`` (inside: m.x <= h) and their tags, (6, 4) float64 / (6,) int64.

    Ground z = ground_z (reflecting), top z = domain_max[2] (open or reflecting), four open sides.
    """
    lo = np.asarray(domain_min, dtype=np.float64).reshape(3)
    hi = np.asarray(domain_max, dtype=np.float64).reshape(3)
    if top not in ("open", "reflect"):
        raise ValueError(f"top must be 'open' or 'reflect', got {top!r}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        raise ValueError(f"domain_min {lo.tolist()} must be finite and below domain_max {hi.tolist()}")
    if not (math.isfinite(ground_z) and ground_z < hi[2]):
        raise ValueError(f"ground_z {ground_z} must be finite and below the top {hi[2]}")
    planes = np.array(
        [
            [0.0, 0.0, -1.0, -ground_z],
            [0.0, 0.0, 1.0, hi[2]],
            [-1.0, 0.0, 0.0, -lo[0]],
            [1.0, 0.0, 0.0, hi[0]],
            [0.0, -1.0, 0.0, -lo[1]],
            [0.0, 1.0, 0.0, hi[1]],
        ]
    )
    tags = np.array(
        [BOUNDARY_REFLECT, BOUNDARY_REFLECT if top == "reflect" else BOUNDARY_OPEN] + [BOUNDARY_OPEN] * 4,
        dtype=np.int64,
    )
    return planes, tags


def trace_numerical(
    method: str,
    media: str,
    *,
    mesh: CellMesh | None = None,
    quantity: str = "n2",
    exact_spec: tuple[int, np.ndarray] | None = None,
    c_ref: float = 340.0,
    origins: np.ndarray,
    directions: np.ndarray,
    start_cells: np.ndarray | None = None,
    max_time_s: float,
    max_reflections: int = 50,
    max_steps: int = 10_000_000,
    step_m: float = 1.0,
    tolerance: float = 1e-8,
    path_samples: int = 0,
    domain_min: np.ndarray,
    domain_max: np.ndarray,
    ground_z: float = 0.0,
    top: str = "open",
    renormalize: bool = False,
    stats: dict[str, np.ndarray] | None = None,
    paraxial: bool = False,
) -> tuple[TraceResult, np.ndarray]:
    """Trace rays by numerical integration of the ray ODE; returns ``(TraceResult, restarts)``.

    method : "euler" | "rk4" (fixed steps of about ``step_m`` metres of arc: h = step_m / n(x) in
        sigma) or "euler_adaptive" | "dopri5" (adaptive; ``step_m`` is the first step, ``tolerance``
        the absolute local error per step, metres for x and units of n for p).
    media : "exact" (closed-form profile, ``exact_spec = exact_media.exact_media_spec(profile)``) or
        "mesh" (the CellMesh's linear model of the traced ``quantity`` "n2" | "c" | "n").
    origins, directions : (n, 3) float64, metres / any non-zero length, world frame.
    start_cells : (n,) int64 cells containing the origins (mesh media; located when None; -1 -> lost).
    domain_min, domain_max : (3,) metres: open sides, top at domain_max[2]; the ground is z = ground_z.
    path_samples : samples per ray (0: none), as engine.tracer.trace (Hermite-interpolated inside long steps).
    stats : if a dict is given it receives (n,) int64 arrays "rejected" (rejected trial steps) and
        "evaluations" (right-hand-side evaluations).
    paraxial : also integrate the variational equations (module docstring): TraceResult.paraxial (n, 13)
        X_el, X_az, P_el, P_az and |p| (p the integrated state, not renormalised unless ``renormalize``).
    Returns the TraceResult (launch angles NaN, ``crossings`` = mesh cells crossed, ``nudges`` = 0,
    ``steps`` = accepted steps) and ``restarts`` (n,) int64: steps re-taken with a reduced length to
    land on a boundary or on the time limit.
    """
    if method not in METHOD_CODES:
        raise ValueError(f"unknown method {method!r}; expected one of {sorted(METHOD_CODES)}")
    med = make_media(media, exact_spec=exact_spec, mesh=mesh, quantity=quantity, c_ref=float(c_ref))
    origins, directions, start_cells = _ray_inputs(media, mesh, origins, directions, start_cells)
    _check_limits(max_time_s, step_m, tolerance, max_reflections, max_steps, path_samples)
    n = origins.shape[0]
    bplanes, btags = boundary_planes(domain_min, domain_max, float(ground_z), top)
    record = path_samples > 0
    cap = path_capacity(path_samples, max_reflections) if record else 1
    n_slots = n * cap if record else 1
    paths = PathBuffers(np.zeros((n_slots, 3)), np.zeros(n_slots), np.zeros(n_slots), cap)
    out_counts = np.zeros((n, NCOUNT_SIZE), dtype=np.int64)
    out_par = np.full((n if paraxial else 0, PAR_OUT_SIZE), np.nan)
    rays = NumRays(origins, directions, start_cells, np.zeros((n, STATE_SIZE)), out_counts, out_par)
    prm = NumParams(
        METHOD_CODES[method],
        float(max_time_s),
        int(max_reflections),
        int(max_steps),
        float(step_m),
        float(tolerance),
        bool(renormalize),
        record,
        float(max_time_s) / max(path_samples, 1),
        bool(paraxial),
    )
    trace_rays_numerical(med, Bounds(bplanes, btags), prm, paths, rays)
    gathered = gather_paths(paths.pts, paths.t, paths.s, out_counts[:, NCOUNT_SAMPLES], cap) if record else None
    if stats is not None:
        stats["rejected"] = out_counts[:, NCOUNT_REJECTED].copy()
        stats["evaluations"] = out_counts[:, NCOUNT_EVALS].copy()
    result = kernel_trace_result(
        rays.out_state,
        status=out_counts[:, COUNT_STATUS],
        reflections=out_counts[:, COUNT_REFLECTIONS],
        crossings=out_counts[:, COUNT_CROSSINGS],
        nudges=np.zeros(n, dtype=np.int64),
        steps=out_counts[:, NCOUNT_STEPS],
        paths=gathered,
        paraxial=out_par if paraxial else None,
    )
    return result, out_counts[:, NCOUNT_RESTARTS].copy()


def _ray_inputs(
    media: str, mesh: CellMesh | None, origins: np.ndarray, directions: np.ndarray, start_cells: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """origins, directions as C-contiguous (n, 3) float64 and start_cells (n,) int64 (mesh media: located
    when None; exact media: zeros); ValueError when the lengths differ."""
    origins = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    n = origins.shape[0]
    if directions.shape[0] != n:
        raise ValueError("origins and directions must have the same length")
    if start_cells is None:
        if media == "mesh":
            assert mesh is not None  # make_media refused media="mesh" without a mesh
            uniq, inv = np.unique(origins, axis=0, return_inverse=True)
            start_cells = locate_points(mesh, uniq)[inv.reshape(-1)]
        else:
            start_cells = np.zeros(n, dtype=np.int64)
    start_cells = np.ascontiguousarray(start_cells, dtype=np.int64).reshape(-1)
    if start_cells.shape[0] != n:
        raise ValueError("start_cells must have one entry per ray")
    return origins, directions, start_cells


def _check_limits(
    max_time_s: float, step_m: float, tolerance: float, max_reflections: int, max_steps: int, path_samples: int
) -> None:
    """ValueError unless the time limit and step are positive and finite, the tolerance positive and the
    counts in range."""
    if not (max_time_s > 0.0 and math.isfinite(max_time_s)):
        raise ValueError("max_time_s must be positive and finite")
    if not (step_m > 0.0 and math.isfinite(step_m)):
        raise ValueError("step_m must be positive and finite")
    if not (tolerance > 0.0):
        raise ValueError("tolerance must be positive")
    if max_reflections < 0 or max_steps < 1 or path_samples < 0:
        raise ValueError("max_reflections and path_samples must be >= 0, max_steps >= 1")

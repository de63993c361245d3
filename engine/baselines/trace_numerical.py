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
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from bentray.engine.baselines.integrators import (
    EVALS_PER_STEP,
    EVENT_PLANE,
    EVENT_TIME,
    MEDIA_MESH,
    METHOD_CODES,
    NY,
    WORK_ROWS,
    advance,
    controlled_step,
    first_guess,
    land,
    make_media,
    media_n,
    plane_g,
    rhs,
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


@nb.njit(**NJIT_FLAGS)
def _emit(path_pts, path_t, path_s, base, cap, count, y):
    if count < cap:
        k = base + count
        path_pts[k, 0] = y[0]
        path_pts[k, 1] = y[1]
        path_pts[k, 2] = y[2]
        path_t[k] = y[6]
        path_s[k] = y[7]
        return count + 1
    return count


@nb.njit(**NJIT_FLAGS)
def _emit_interior(y0, k0, y1, k1, h, dt_sample, path_pts, path_t, path_s, base, cap, count, ys):
    """Samples inside a step longer than dt_sample: cubic Hermite in sigma (x, t, s and their
    sigma-derivatives at both ends), evenly spaced in sigma like the analytic tracer's."""
    n_int = int((y1[6] - y0[6]) / dt_sample)
    if n_int > 2 * cap:
        n_int = 2 * cap
    for j in range(1, n_int + 1):
        u = j / (n_int + 1)
        h00 = (1.0 + 2.0 * u) * (1.0 - u) * (1.0 - u)
        h10 = u * (1.0 - u) * (1.0 - u)
        h01 = u * u * (3.0 - 2.0 * u)
        h11 = u * u * (u - 1.0)
        for i in (0, 1, 2, 6, 7):
            ys[i] = h00 * y0[i] + h10 * h * k0[i] + h01 * y1[i] + h11 * h * k1[i]
        count = _emit(path_pts, path_t, path_s, base, cap, count, ys)
    return count


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


@nb.njit(**NJIT_FLAGS)
def _resolve_events(
    method, media, bplanes, btags, cell, y0, k1, h, max_time, eps_x, eps_t, y1, knew, yerr, work, evp, grz, scratch
):
    """Shorten the step y0 -> y1 (length h) to the earliest boundary or time event, by restarts.

    On return y1 is the final end state (on the event's plane / at max_time, or the untouched step).
    Returns (ok, has_knew, h_end, ev_kind, ev_tag, slide_tag, moved, restarts): ``evp`` holds the
    event's plane, ``grz`` a grazed plane the ray slid along (slide_tag != 0), ``moved`` whether x was
    snapped or projected (so f(y1) must be re-evaluated).
    """
    kind, tag, f, g0, g1, grz_tag, ok = _detect(y0, y1, bplanes, btags, media, cell, max_time, eps_x, eps_t, evp, grz)
    ev_kind = EVENT_NONE
    ev_tag = 0
    h_end = h
    moved = False
    has = True
    restarts = 0
    for _ in range(MAX_RETARGETS + 1):
        if kind == EVENT_NONE or not ok:
            break
        hk = first_guess(method, kind, evp, y0, y1, h_end, g0, g1, media[9])
        h_end, ok, has, nr = land(
            method,
            media,
            cell,
            y0,
            k1,
            0.0,
            min(g0, 0.0),
            h_end,
            g1,
            hk,
            kind,
            evp,
            max_time,
            eps_t if kind == EVENT_TIME else eps_x,
            y1,
            knew,
            yerr,
            work,
        )
        restarts += nr
        ev_kind = kind
        ev_tag = tag
        if kind == EVENT_TIME:
            y1[6] = max_time
        else:
            gg = plane_g(evp, y1)
            for i in range(3):
                y1[i] -= gg * evp[i]
            moved = True
        # an earlier crossing of another boundary revealed by the landing re-targets it
        kind, tag, f, g0, g1, _, walk_ok = _detect(
            y0, y1, bplanes, btags, media, cell, max_time, eps_x, eps_t, evp, scratch
        )
        ok = ok and walk_ok
    slide_tag = 0
    g_end = plane_g(grz, y1)
    if ok and grz_tag != 0 and g_end > eps_x:
        # the ray left a plane it sits on: find an interior re-entry by halving, else slide along it
        hk = h_end
        glo = 0.0
        found = False
        for _ in range(MAX_GRAZE_HALVINGS):
            hk *= 0.5
            ok, has = advance(method, media, cell, y0, k1, hk, y1, knew, yerr, work)
            restarts += 1
            glo = plane_g(grz, y1)
            if not ok or glo < -eps_x:
                found = ok
                break
        if found:
            h_end, ok, has, nr = land(
                method,
                media,
                cell,
                y0,
                k1,
                hk,
                glo,
                h_end,
                g_end,
                hk + (h_end - hk) * (-glo) / (g_end - glo),
                EVENT_PLANE,
                grz,
                max_time,
                eps_x,
                y1,
                knew,
                yerr,
                work,
            )
            ev_kind = EVENT_PLANE
            ev_tag = grz_tag
            for i in range(4):
                evp[i] = grz[i]
        else:
            ok, has = advance(method, media, cell, y0, k1, h_end, y1, knew, yerr, work)
            nr = 1
            slide_tag = grz_tag
            if ev_kind == EVENT_TIME:  # re-apply the landing's snap to the re-taken step
                y1[6] = max_time
            elif ev_kind == EVENT_PLANE:
                gg = plane_g(evp, y1)
                for i in range(3):
                    y1[i] -= gg * evp[i]
        restarts += nr
        gg = plane_g(grz, y1)
        for i in range(3):
            y1[i] -= gg * grz[i]
        moved = True
    return ok, has, h_end, ev_kind, ev_tag, slide_tag, moved, restarts


@nb.njit(**NJIT_FLAGS)
def trace_one(
    method,
    media,
    bplanes,
    btags,
    x_start,
    d_start,
    cell_start,
    max_time,
    max_reflections,
    max_steps,
    step_m,
    tol,
    renormalize,
    record,
    dt_sample,
    path_pts,
    path_t,
    path_s,
    base,
    cap,
    out_state,
    out_counts,
):
    """Integrate one ray. out_state (STATE_SIZE,): columns constants.STATE_* (x, d, time_s, length_m).

    out_counts (NCOUNT_SIZE,): status, reflections, cell crossings (constants.COUNT_STATUS, _REFLECTIONS,
    _CROSSINGS, shared with the analytic tracer), then NCOUNT_STEPS (accepted steps), NCOUNT_RESTARTS,
    NCOUNT_REJECTED (rejected steps), NCOUNT_EVALS (right-hand-side evaluations), NCOUNT_SAMPLES (path samples).
    """
    # Small shared inputs are copied per ray: every call that passes an array touches its reference
    # count (an atomic add), and two threads hitting the same shared counters serialise each other.
    bplanes = bplanes.copy()
    btags = btags.copy()
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
    y0 = np.zeros(NY)
    y1 = np.zeros(NY)
    k1 = np.zeros(NY)
    knew = np.zeros(NY)
    yerr = np.zeros(NY)
    ys = np.zeros(NY)
    work = np.zeros((WORK_ROWS, NY))
    evp = np.zeros(4)
    grz = np.zeros(4)
    status = STATUS_RUNNING
    reflections = 0
    crossings = 0
    steps = 0
    restarts = 0
    rejected = 0
    evals = 0
    count = 0
    cell = cell_start
    nrm = math.sqrt(d_start[0] ** 2 + d_start[1] ** 2 + d_start[2] ** 2)
    for i in range(3):
        y0[i] = x_start[i]
    eps_t = TIME_LAND_REL * max(1.0, max_time)
    n0 = math.nan
    if media[0] != MEDIA_MESH or cell >= 0:
        n0 = media_n(media, cell, y0, ys)
    if not (n0 > 0.0 and math.isfinite(n0) and nrm > 0.0):
        status = STATUS_LOST
    else:
        for i in range(3):
            y0[3 + i] = n0 * d_start[i] / nrm
        eps0 = LAND_REL * (1.0 + max(abs(y0[0]), abs(y0[1]), abs(y0[2])))
        for j in range(bplanes.shape[0]):
            if plane_g(bplanes[j], y0) > eps0:
                status = STATUS_LOST  # origin outside the domain
        if not rhs(media, cell, y0, k1):
            status = STATUS_LOST
        evals += 1
    if record:
        count = _emit(path_pts, path_t, path_s, base, cap, count, y0)
    t_last = 0.0
    h_next = step_m / n0 if n0 > 0.0 else 0.0
    n_per = EVALS_PER_STEP[method]
    while status == STATUS_RUNNING:
        if steps >= max_steps:
            status = STATUS_STEP_LIMIT
            break
        ok, has, h, h_next, rej = controlled_step(
            method, media, cell, y0, k1, h_next, step_m, tol, y1, knew, yerr, work
        )
        rejected += rej
        evals += (rej + 1) * n_per
        if not ok:
            status = STATUS_LOST
            break
        steps += 1
        eps_x = LAND_REL * (1.0 + max(abs(y1[0]), abs(y1[1]), abs(y1[2])))
        # fast path: nothing crossed (the common step) -> no event machinery (mesh faces need the walk)
        crossed = media[0] == MEDIA_MESH or y1[6] - max_time > eps_t
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
                method,
                media,
                bplanes,
                btags,
                cell,
                y0,
                k1,
                h,
                max_time,
                eps_x,
                eps_t,
                y1,
                knew,
                yerr,
                work,
                evp,
                grz,
                ys,
            )
            restarts += nr
            evals += nr * n_per
            if nr > 0:
                has = has2
        if not (ok and _finite(y1)):
            status = STATUS_LOST
            break
        # ---- accept: f(y1), path samples, cell, then the events ----
        if moved or not has:
            if not rhs(media, cell, y1, knew):
                status = STATUS_LOST
                break
            evals += 1
        if record and y1[6] - y0[6] > dt_sample:
            count = _emit_interior(y0, k1, y1, knew, h_end, dt_sample, path_pts, path_t, path_s, base, cap, count, ys)
        for i in range(NY):
            k1[i] = knew[i]
            y0[i] = y1[i]
        if media[0] == MEDIA_MESH:
            cell, face, mv = walk(media[3], media[4], cell, y0, eps_x)
            crossings += mv
            if face == WALK_FAILED:
                status = STATUS_LOST
                break
        if record and y0[6] - t_last >= dt_sample:
            count = _emit(path_pts, path_t, path_s, base, cap, count, y0)
            t_last = y0[6]
        refl_before = reflections
        if ev_kind == EVENT_TIME or y0[6] >= max_time - eps_t:
            y0[6] = max_time
            status = STATUS_TIME_LIMIT
        elif ev_kind == EVENT_PLANE and ev_tag == BOUNDARY_OPEN:
            status = STATUS_EXITED
        elif ev_kind == EVENT_PLANE:
            status, reflections = _reflect(evp, y0, k1, reflections, max_reflections)
        if status == STATUS_RUNNING and slide_tag == BOUNDARY_OPEN:
            status = STATUS_EXITED
        elif status == STATUS_RUNNING and slide_tag == BOUNDARY_REFLECT:
            if grz[0] * y0[3] + grz[1] * y0[4] + grz[2] * y0[5] > 0.0:
                status, reflections = _reflect(grz, y0, k1, reflections, max_reflections)
        if record and reflections > refl_before and y0[6] > t_last:
            count = _emit(path_pts, path_t, path_s, base, cap, count, y0)
            t_last = y0[6]
        if renormalize and status == STATUS_RUNNING:
            pn = math.sqrt(y0[3] ** 2 + y0[4] ** 2 + y0[5] ** 2)
            for i in range(3):
                y0[3 + i] *= k1[7] / pn
                k1[i] = y0[3 + i]
    if record and (count == 0 or y0[6] > t_last):
        count = _emit(path_pts, path_t, path_s, base, cap, count, y0)
    pn = math.sqrt(y0[3] ** 2 + y0[4] ** 2 + y0[5] ** 2)
    for i in range(3):
        out_state[STATE_X + i] = y0[i]
        out_state[STATE_D + i] = y0[3 + i] / pn if pn > 0.0 else d_start[i] / nrm
    out_state[STATE_TIME] = y0[6]
    out_state[STATE_LENGTH] = y0[7]
    out_counts[COUNT_STATUS] = status
    out_counts[COUNT_REFLECTIONS] = reflections
    out_counts[COUNT_CROSSINGS] = crossings
    out_counts[NCOUNT_STEPS] = steps
    out_counts[NCOUNT_RESTARTS] = restarts
    out_counts[NCOUNT_REJECTED] = rejected
    out_counts[NCOUNT_EVALS] = evals
    out_counts[NCOUNT_SAMPLES] = count


@nb.njit(**PARALLEL_FLAGS)
def trace_rays_numerical(
    method,
    media,
    bplanes,
    btags,
    origins,
    directions,
    start_cells,
    max_time,
    max_reflections,
    max_steps,
    step_m,
    tol,
    renormalize,
    record,
    dt_sample,
    path_cap,
    path_pts,
    path_t,
    path_s,
    out_state,
    out_counts,
):
    """All rays in parallel (prange); ray i owns out_state[i], out_counts[i] and the path slice
    ``[i * path_cap, (i + 1) * path_cap)``: no shared writes, deterministic results."""
    for i in nb.prange(origins.shape[0]):
        trace_one(
            method,
            media,
            bplanes,
            btags,
            origins[i],
            directions[i],
            start_cells[i],
            max_time,
            max_reflections,
            max_steps,
            step_m,
            tol,
            renormalize,
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
    Returns the TraceResult (launch angles NaN, ``crossings`` = mesh cells crossed, ``nudges`` = 0,
    ``steps`` = accepted steps) and ``restarts`` (n,) int64: steps re-taken with a reduced length to
    land on a boundary or on the time limit.
    """
    if method not in METHOD_CODES:
        raise ValueError(f"unknown method {method!r}; expected one of {sorted(METHOD_CODES)}")
    med = make_media(media, exact_spec=exact_spec, mesh=mesh, quantity=quantity, c_ref=float(c_ref))
    origins = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    n = origins.shape[0]
    if directions.shape[0] != n:
        raise ValueError("origins and directions must have the same length")
    if start_cells is None:
        if media == "mesh":
            uniq, inv = np.unique(origins, axis=0, return_inverse=True)
            start_cells = locate_points(mesh, uniq)[inv.reshape(-1)]
        else:
            start_cells = np.zeros(n, dtype=np.int64)
    start_cells = np.ascontiguousarray(start_cells, dtype=np.int64).reshape(-1)
    if start_cells.shape[0] != n:
        raise ValueError("start_cells must have one entry per ray")
    if not (max_time_s > 0.0 and math.isfinite(max_time_s)):
        raise ValueError("max_time_s must be positive and finite")
    if not (step_m > 0.0 and math.isfinite(step_m)):
        raise ValueError("step_m must be positive and finite")
    if not (tolerance > 0.0):
        raise ValueError("tolerance must be positive")
    if max_reflections < 0 or max_steps < 1 or path_samples < 0:
        raise ValueError("max_reflections and path_samples must be >= 0, max_steps >= 1")
    bplanes, btags = boundary_planes(domain_min, domain_max, float(ground_z), top)
    record = path_samples > 0
    cap = path_capacity(path_samples, max_reflections) if record else 1
    n_slots = n * cap if record else 1
    path_pts = np.zeros((n_slots, 3))
    path_t = np.zeros(n_slots)
    path_s = np.zeros(n_slots)
    out_state = np.zeros((n, STATE_SIZE))
    out_counts = np.zeros((n, NCOUNT_SIZE), dtype=np.int64)
    trace_rays_numerical(
        METHOD_CODES[method],
        med,
        bplanes,
        btags,
        origins,
        directions,
        start_cells,
        float(max_time_s),
        int(max_reflections),
        int(max_steps),
        float(step_m),
        float(tolerance),
        bool(renormalize),
        record,
        float(max_time_s) / max(path_samples, 1),
        cap,
        path_pts,
        path_t,
        path_s,
        out_state,
        out_counts,
    )
    paths = gather_paths(path_pts, path_t, path_s, out_counts[:, NCOUNT_SAMPLES], cap) if record else None
    if stats is not None:
        stats["rejected"] = out_counts[:, NCOUNT_REJECTED].copy()
        stats["evaluations"] = out_counts[:, NCOUNT_EVALS].copy()
    result = kernel_trace_result(
        out_state,
        status=out_counts[:, COUNT_STATUS],
        reflections=out_counts[:, COUNT_REFLECTIONS],
        crossings=out_counts[:, COUNT_CROSSINGS],
        nudges=np.zeros(n, dtype=np.int64),
        steps=out_counts[:, NCOUNT_STEPS],
        paths=paths,
    )
    return result, out_counts[:, NCOUNT_RESTARTS].copy()

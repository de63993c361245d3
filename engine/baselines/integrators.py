"""Explicit one-step integrators of the ray equations (Euler, step-doubling Euler, RK4, Dormand-Prince 5(4)).

Ray ODE (docs/physics.md §1), ``d/ds (n dx/ds) = grad n``, ``dt/ds = n / c_ref``, written in the
parameter sigma with ``d sigma = ds / n`` and ``p = n dx/ds`` (the analytic parabolic curve's
parameter, docs/physics.md §2). State ``y`` (NY = 8,) float64:

    y[0:3] x (m)   y[3:6] p (dimensionless, |p| = n)   y[6] t (s)   y[7] s (m, arc length)

    dx/dsigma = p,   dp/dsigma = n grad n = grad(n^2) / 2,   dt/dsigma = n^2 / c_ref,   ds/dsigma = n

Why sigma rather than arc length: the right-hand side is polynomial in p (no division by n or |p|,
no renormalisation needed for the equations to make sense), and it is the form in which the
parabolic primitive is exact: for constant grad(n^2) the solution is polynomial (x quadratic, t cubic
in sigma), so RK4 and DOPRI5 reproduce it to rounding, a built-in check. Arc length is carried as
a state component, so ``s`` is integrated to the method's order too. sigma is approximately the arc
length divided by n (n ~ 1 in air), so steps given in metres are converted with ``h = step_m / n``.

Media are selected by an integer (Numba first-class functions do not cache): a ``media`` tuple
``(kind, exact_code, exact_params, planes, neighbours, media_ref, ref_point, gradient, quantity,
c_ref)`` built by :func:`make_media`; kind ``MEDIA_EXACT`` evaluates the closed-form profile
(exact_media.n_and_grad), ``MEDIA_MESH`` the CellMesh's linear model of the cell found by walking
from ``cell`` (mesh_media.mesh_n_and_grad).

Variational equations (docs/physics.md §10, "Numerical baselines"): with ``paraxial`` on, each accepted
step also advances the launch-angle derivatives ``V = (X_el, X_az, P_el, P_az)`` (NV = 12,) of the
state by the same tableau and the same stages applied to ``X' = P``, ``P' = J(x) X``, J = grad(n grad n)
(:func:`var_step`): Runge-Kutta discretisation and differentiation commute, so this is the exact
derivative of the fixed-length step's map. :func:`media_jac` gives J(x) X: for mesh media from the cell's
linear model in closed form, for exact media by a central difference of the exact n grad n along X.

Every stepper takes ``k1 = f(y0)`` precomputed (so a restarted step costs no new evaluation at its
start) and returns False when the media was unphysical (n <= 0) or non-finite at a stage. Also here:
the step-size controller (``controlled_step``) and event landing by restarted steps (``land``), which
trace_numerical uses for boundaries and the time limit.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from bentray.engine.baselines.exact_media import n_and_grad_at
from bentray.engine.baselines.mesh_media import QUANTITY_C as QUANTITY_CODES_C
from bentray.engine.baselines.mesh_media import QUANTITY_CODES, mesh_n_and_grad_at
from bentray.engine.baselines.mesh_media import QUANTITY_N as QUANTITY_CODES_N
from bentray.engine.constants import NJIT_FLAGS
from bentray.engine.kernels.llvm_inline import njit_inline
from bentray.engine.mesh.cells import CellMesh

__all__ = [
    "NY",
    "WORK_ROWS",
    "STAGES",
    "EVALS_PER_STEP",
    "EVENT_PLANE",
    "EVENT_TIME",
    "MEDIA_EXACT",
    "MEDIA_MESH",
    "METHOD_EULER",
    "METHOD_EULER_ADAPTIVE",
    "METHOD_RK4",
    "METHOD_DOPRI5",
    "METHOD_CODES",
    "make_media",
    "media_n",
    "rhs",
    "rk_step",
    "euler_step",
    "euler_doubling_step",
    "rk4_step",
    "dopri5_step",
    "advance",
    "error_norm",
    "controlled_step",
    "plane_g",
    "event_g",
    "event_rate",
    "first_guess",
    "land",
    "NV",
    "media_jac",
    "var_step",
]

NY = 8  # state size: x(3), p(3), t, s
NV = 12  # variational state: X_el, X_az (m/rad), P_el, P_az (1/rad)
VAR_FD_M = 1e-5  # metres: step of media_jac's central difference on exact media

MEDIA_EXACT = 0
MEDIA_MESH = 1

METHOD_EULER = 0  # fixed step, order 1 (the paper's polygonal rays)
METHOD_EULER_ADAPTIVE = 1  # step doubling (paper Sec. 4.2): two half steps accepted, order 1
METHOD_RK4 = 2  # classical Runge-Kutta, fixed step, order 4
METHOD_DOPRI5 = 3  # Dormand-Prince 5(4), adaptive, local extrapolation, FSAL
METHOD_CODES = {
    "euler": METHOD_EULER,
    "euler_adaptive": METHOD_EULER_ADAPTIVE,
    "rk4": METHOD_RK4,
    "dopri5": METHOD_DOPRI5,
}

# All four methods are explicit Runge-Kutta tableaux stepped by one loop (rk_step), so the media code
# has one call site in the steppers instead of one per stage and method. Rows: METHOD_*; STAGES[m]
# stages; A[m] (7, 7) stage coefficients, B[m] (7,) weights, E[m] (7,) error weights (b - b_hat; zero
# for the fixed-step methods).
#
# Inlining (kernels/llvm_inline.py's njit_inline since 2026-12-05, Numba IR inlining before; the figures below
# are from then): every call that passes arrays pays atomic reference-count
# updates per array, which dominated the step cost. The media evaluation and rhs are inlined (an A-LD
# right-hand side went from 260 to 105 ns), and so are advance and controlled_step, which have one hot
# call site (an Euler step of the tracer: 480 -> 350 ns CPU; +2 s of compilation). rk_step is not:
# inlining it into its four call sites gained another 30 % but doubled the cold compile (24 -> 52 s CPU).
# Made njit_inline on 2026-12-05 (evening) it gained nothing: Dormand-Prince on A-LD at 1e-4 took 5.75-5.77 ms
# against 5.74-5.79 ms as a call (the probe of README's A-LD row), so it stays a call.
MAX_STAGES = 7
STAGES = np.array([1, 2, 4, 7], dtype=np.int64)
# New right-hand-side evaluations per step (k1 = f(y0) is given; DOPRI5's 7th stage is f(y1), FSAL).
EVALS_PER_STEP = STAGES - 1
WORK_ROWS = MAX_STAGES + 1  # the stages K and one stage state
A = np.zeros((4, MAX_STAGES, MAX_STAGES))
B = np.zeros((4, MAX_STAGES))
E = np.zeros((4, MAX_STAGES))
B[METHOD_EULER, 0] = 1.0
# Step doubling as a tableau: two Euler half steps (y0 + h/2 k1 + h/2 k2), error against one full step.
A[METHOD_EULER_ADAPTIVE, 1, 0] = 0.5
B[METHOD_EULER_ADAPTIVE, :2] = [0.5, 0.5]
E[METHOD_EULER_ADAPTIVE, :2] = [-0.5, 0.5]
A[METHOD_RK4, 1, 0] = 0.5
A[METHOD_RK4, 2, 1] = 0.5
A[METHOD_RK4, 3, 2] = 1.0
B[METHOD_RK4, :4] = [1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0]
# Dormand-Prince 5(4) (Dormand & Prince 1980; Hairer, Norsett & Wanner I, Table II.5.2).
A[METHOD_DOPRI5, 1, :1] = [1.0 / 5.0]
A[METHOD_DOPRI5, 2, :2] = [3.0 / 40.0, 9.0 / 40.0]
A[METHOD_DOPRI5, 3, :3] = [44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0]
A[METHOD_DOPRI5, 4, :4] = [19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0]
A[METHOD_DOPRI5, 5, :5] = [9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0]
A[METHOD_DOPRI5, 6, :6] = [35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0]
B[METHOD_DOPRI5, :6] = A[METHOD_DOPRI5, 6, :6]
E[METHOD_DOPRI5, :] = [
    71.0 / 57600.0,
    0.0,
    -71.0 / 16695.0,
    71.0 / 1920.0,
    -17253.0 / 339200.0,
    22.0 / 525.0,
    -1.0 / 40.0,
]

# Step-size control. DOPRI5 (Hairer, Norsett & Wanner I, II.4): h_new = h min(FAC_MAX, max(FAC_MIN,
# SAFETY err^(-1/5))), no growth right after a rejection. Step doubling (paper Sec. 4.2): halve and
# retry above the tolerance, double after a step whose error is below DOUBLING_GROW_BELOW of it
# (Euler's local error grows 4x when h doubles), keep h in between.
SAFETY = 0.9
FAC_MIN = 0.2
FAC_MAX = 5.0
DOUBLING_GROW_BELOW = 0.25
# Consecutive rejected trial steps before giving up (h shrinks by >= 2 each time): the ray is lost.
MAX_REJECTS_IN_A_ROW = 200
# Restarts per event landing (Newton/secant converge superlinearly: 1-4 in practice; the bisection
# safeguard shrinks any bracket below float64 resolution within 60).
MAX_LAND_ITERS = 60

EVENT_PLANE = 1  # g(y) = m.x - h for a plane (m, h)
EVENT_TIME = 2  # g(y) = t - t_end


def make_media(
    media: str,
    *,
    exact_spec: tuple[int, np.ndarray] | None = None,
    mesh: CellMesh | None = None,
    quantity: str = "n2",
    c_ref: float = 340.0,
) -> tuple:
    """The ``media`` tuple the kernels dispatch on.

    media : "exact" (needs ``exact_spec`` from exact_media.exact_media_spec) or "mesh" (needs ``mesh``
    and the traced ``quantity`` "n2", "c" or "n"). Unused slots hold 1-element dummies so that both
    kinds share one compiled signature.
    """
    dummy3 = np.zeros((1, 1, 4))
    dummy_nb = np.full((1, 1), -9, dtype=np.int64)
    if media == "exact":
        if exact_spec is None:
            raise ValueError("media='exact' needs exact_spec = exact_media_spec(profile)")
        code, params = exact_spec
        params = np.ascontiguousarray(params, dtype=np.float64)
        if params[0] != c_ref:
            raise ValueError(f"c_ref {c_ref} differs from the profile's c_ref {params[0]}")
        return (
            MEDIA_EXACT,
            int(code),
            params,
            dummy3,
            dummy_nb,
            np.zeros(1),
            np.zeros((1, 3)),
            np.zeros((1, 3)),
            0,
            float(c_ref),
        )
    if media == "mesh":
        if mesh is None:
            raise ValueError("media='mesh' needs a CellMesh")
        if quantity not in QUANTITY_CODES:
            raise ValueError(f"quantity must be one of {sorted(QUANTITY_CODES)}, got {quantity!r}")
        f8 = np.float64
        return (
            MEDIA_MESH,
            -1,
            np.zeros(1),
            np.ascontiguousarray(mesh.planes, dtype=f8),
            np.ascontiguousarray(mesh.neighbours, dtype=np.int64),
            np.ascontiguousarray(mesh.media_ref, dtype=f8),
            np.ascontiguousarray(mesh.ref_point, dtype=f8),
            np.ascontiguousarray(mesh.gradient, dtype=f8),
            int(QUANTITY_CODES[quantity]),
            float(c_ref),
        )
    raise ValueError(f"media must be 'exact' or 'mesh', got {media!r}")


@nb.njit(**NJIT_FLAGS)
def media_n(media, cell, x, out_grad):
    """n at ``x`` (3,) m and grad n into ``out_grad`` (3,) 1/m, dispatched on ``media[0]``."""
    return media_n_at(media, cell, x, out_grad, 0)


@njit_inline
def media_n_at(media, cell, x, out, k):
    """:func:`media_n` writing grad n into ``out[k:k+3]``."""
    if media[0] == MEDIA_EXACT:
        return n_and_grad_at(media[1], media[2], x, out, k)
    n, _ = mesh_n_and_grad_at(media[3], media[4], media[5], media[6], media[7], media[8], media[9], cell, x, out, k)
    return n


@njit_inline
def rhs(media, cell, y, out):
    """out (NY,) = dy/dsigma at state y (NY,). False when n <= 0 or anything is non-finite."""
    n = media_n_at(media, cell, y, out, 3)  # grad n lands in out[3:6]
    ok = n > 0.0 and math.isfinite(n) and math.isfinite(out[3] + out[4] + out[5])
    out[0] = y[3]
    out[1] = y[4]
    out[2] = y[5]
    out[3] *= n
    out[4] *= n
    out[5] *= n
    out[6] = n * n / media[9]
    out[7] = n
    return ok


@nb.njit(**NJIT_FLAGS)
def rk_step(method, media, cell, y0, k1, h, y1, yerr, work):
    """One explicit Runge-Kutta step of tableau ``method`` from y0 (k1 = f(y0) given) into y1.

    work : (WORK_ROWS, NY) scratch; on return work[s] holds stage s (work[STAGES-1] = f(y1) for DOPRI5).
    yerr = h sum_j E_j k_j (zeros for the fixed-step tableaux). False when a stage saw unphysical media.
    """
    n_st = STAGES[method]
    yt = work[MAX_STAGES]
    ok = True
    for i in range(NY):
        work[0, i] = k1[i]
    for st in range(1, n_st):
        for i in range(NY):
            acc = 0.0
            for j in range(st):
                acc += A[method, st, j] * work[j, i]
            yt[i] = y0[i] + h * acc
        ok = rhs(media, cell, yt, work[st]) and ok
    for i in range(NY):
        acc = 0.0
        err = 0.0
        for j in range(n_st):
            acc += B[method, j] * work[j, i]
            err += E[method, j] * work[j, i]
        y1[i] = y0[i] + h * acc
        yerr[i] = h * err
    return ok


@nb.njit(**NJIT_FLAGS)
def euler_step(y0, k1, h, y1):
    """Explicit Euler, y1 = y0 + h k1 (the paper's Eq. 2); no evaluation."""
    for i in range(NY):
        y1[i] = y0[i] + h * k1[i]


@nb.njit(**NJIT_FLAGS)
def euler_doubling_step(media, cell, y0, k1, h, y1, yerr, work):
    """Two Euler half steps into y1; yerr = y1 - (one full Euler step), the step-doubling error estimate."""
    return rk_step(METHOD_EULER_ADAPTIVE, media, cell, y0, k1, h, y1, yerr, work)


@nb.njit(**NJIT_FLAGS)
def rk4_step(media, cell, y0, k1, h, y1, work):
    """Classical RK4 step into y1 (three new evaluations)."""
    return rk_step(METHOD_RK4, media, cell, y0, k1, h, y1, work[MAX_STAGES - 1], work)


@nb.njit(**NJIT_FLAGS)
def dopri5_step(media, cell, y0, k1, h, y1, k7, yerr, work):
    """Dormand-Prince 5(4) step: 5th-order y1 (local extrapolation), k7 = f(y1) (FSAL: the next step's
    k1) and the embedded error estimate yerr = y1 - y1_hat (4th order). Six new evaluations."""
    ok = rk_step(METHOD_DOPRI5, media, cell, y0, k1, h, y1, yerr, work)
    for i in range(NY):
        k7[i] = work[6, i]
    return ok


@njit_inline
def advance(method, media, cell, y0, k1, h, y1, knew, yerr, work):
    """The accepted-step map of ``method``: one step from y0 with step h (sigma units) into y1.

    Returns (ok, has_knew): has_knew when ``knew`` holds f(y1) (DOPRI5's FSAL stage). A step restarted
    with a reduced length (boundary or time limit) calls this again.
    """
    ok = rk_step(method, media, cell, y0, k1, h, y1, yerr, work)
    if method == METHOD_DOPRI5:
        for i in range(NY):
            knew[i] = work[6, i]
        return ok, True
    return ok, False


@nb.njit(**NJIT_FLAGS)
def error_norm(yerr, tol):
    """max_i |yerr_i| / tol over position (m) and p (dimensionless): <= 1 accepts the step.

    The tolerance is an absolute local error per step, in metres for x and in units of n for p
    (n ~ 1 in air); t and s are quadratures of the same path and are not controlled separately.
    """
    e = 0.0
    for i in range(6):
        a = abs(yerr[i])
        if not (a == a):  # NaN: reject
            return math.inf
        if a > e:
            e = a
    return e / tol


@njit_inline
def controlled_step(method, media, cell, y0, k1, h, step_m, tol, y1, knew, yerr, work):
    """The accepted step from y0 into y1: fixed (h = step_m / n(y0), about step_m metres of arc) for
    Euler and RK4, error-controlled from the trial step h for step doubling and DOPRI5.

    Returns (ok, has_knew, h_used, h_next, rejected).
    """
    fixed = method == METHOD_EULER or method == METHOD_RK4
    if fixed:
        h = step_m / k1[7]
    rejected = 0
    while True:
        ok, has = advance(method, media, cell, y0, k1, h, y1, knew, yerr, work)
        if fixed:
            return ok, has, h, h, rejected
        err = error_norm(yerr, tol) if ok else math.inf
        if err <= 1.0:
            if method == METHOD_EULER_ADAPTIVE:
                return True, has, h, (2.0 * h if err < DOUBLING_GROW_BELOW else h), rejected
            fac = FAC_MAX if err == 0.0 else min(FAC_MAX, max(FAC_MIN, SAFETY * err**-0.2))
            return True, has, h, h * (min(fac, 1.0) if rejected > 0 else fac), rejected
        rejected += 1
        if rejected > MAX_REJECTS_IN_A_ROW:
            return False, has, h, h, rejected
        if method == METHOD_EULER_ADAPTIVE:
            h *= 0.5
        else:
            h *= FAC_MIN if not (err < math.inf) else max(FAC_MIN, SAFETY * err**-0.2)


@nb.njit(**NJIT_FLAGS)
def plane_g(pl, y):
    """Signed distance m.x - h (m) of the state's position to plane ``pl`` = (mx, my, mz, h)."""
    return pl[0] * y[0] + pl[1] * y[1] + pl[2] * y[2] - pl[3]


@nb.njit(**NJIT_FLAGS)
def event_g(kind, pl, t_end, y):
    """Event function: plane_g for EVENT_PLANE, t - t_end (s) for EVENT_TIME."""
    if kind == EVENT_TIME:
        return y[6] - t_end
    return plane_g(pl, y)


@nb.njit(**NJIT_FLAGS)
def event_rate(kind, pl, y, c_ref):
    """dg/dsigma along the ray: m.p for a plane, n^2 / c_ref ~ |p|^2 / c_ref for the time."""
    if kind == EVENT_TIME:
        return (y[3] * y[3] + y[4] * y[4] + y[5] * y[5]) / c_ref
    return pl[0] * y[3] + pl[1] * y[4] + pl[2] * y[5]


@nb.njit(**NJIT_FLAGS)
def first_guess(method, kind, pl, y0, y1, h, g0, g1, c_ref):
    """First guess in [0, h] for the event crossing of the step y0 -> y1 (g0 <= 0 < g1): the chord for
    Euler (its x and t are linear in h), otherwise the root of the cubic Hermite dense output of g
    (values and sigma-rates at both ends: no new evaluation)."""
    if g0 >= 0.0:
        return 0.0
    f = -g0 / (g1 - g0)
    if method == METHOD_EULER:
        return f * h
    d0 = h * event_rate(kind, pl, y0, c_ref)
    d1 = h * event_rate(kind, pl, y1, c_ref)
    lo = 0.0
    hi = 1.0
    u = f
    for _ in range(50):  # safeguarded Newton on the cubic
        u2 = u * u
        u3 = u2 * u
        gu = (2 * u3 - 3 * u2 + 1) * g0 + (u3 - 2 * u2 + u) * d0 + (3 * u2 - 2 * u3) * g1 + (u3 - u2) * d1
        du = (6 * u2 - 6 * u) * g0 + (3 * u2 - 4 * u + 1) * d0 + (6 * u - 6 * u2) * g1 + (3 * u2 - 2 * u) * d1
        if gu > 0.0:
            hi = u
        else:
            lo = u
        nxt = u - gu / du
        if not (nxt > lo and nxt < hi):
            nxt = 0.5 * (lo + hi)
        if abs(nxt - u) <= 1e-15:
            return nxt * h
        u = nxt
    return u * h


class StepWork(NamedTuple):
    """One ray's integration arrays (float64, (NY,) unless noted), allocated once per ray.

    y0, k1 : the state and f(y0); y1, knew, yerr : a step's end state, f(y1) (when known) and error
    estimate; work : (WORK_ROWS, NY) the stages; ys : (NY,) scratch (samples, gradients); evp, grz : (4,)
    the plane (m, h) of the step's event and of a plane the ray grazes (baselines/trace_numerical.py).
    """

    y0: np.ndarray
    k1: np.ndarray
    y1: np.ndarray
    knew: np.ndarray
    yerr: np.ndarray
    work: np.ndarray
    ys: np.ndarray
    evp: np.ndarray
    grz: np.ndarray


@nb.njit(**NJIT_FLAGS)
def new_step_work():
    """Zeroed StepWork."""
    return StepWork(np.zeros(NY), np.zeros(NY), np.zeros(NY), np.zeros(NY), np.zeros(NY), np.zeros((WORK_ROWS, NY)),
                    np.zeros(NY), np.zeros(4), np.zeros(4))  # fmt: skip


@nb.njit(**NJIT_FLAGS)
def land(method, media, cell, sw, bracket, hk, kind, pl, t_end, eps):
    """Restart the step from sw.y0 (f = sw.k1) with reduced lengths until |g(advance(y0, h))| <= eps.

    One Newton step with the event rate at the landed state as derivative, then secant steps through
    the last two restarts; regula falsi / bisection inside the bracket ``(lo, glo, hi, ghi)``,
    ``g(lo) = glo <= 0 < ghi = g(hi)``, whenever a step leaves it. ``hk`` is the first guess; kind, pl,
    t_end : the event (EVENT_PLANE with plane pl (4,), or EVENT_TIME at t_end s). Leaves sw.y1 =
    advance(y0, h) (sw.knew, sw.yerr, sw.work its by-products). Returns (h, ok, has_knew, restarts).
    """
    lo, glo, hi, ghi = bracket
    y1 = sw.y1
    restarts = 0
    ok = True
    has = False
    h_prev = math.nan
    g_prev = math.nan
    for _ in range(MAX_LAND_ITERS):
        ok, has = advance(method, media, cell, sw.y0, sw.k1, hk, y1, sw.knew, sw.yerr, sw.work)
        restarts += 1
        if not ok:
            break
        g = event_g(kind, pl, t_end, y1)
        if abs(g) <= eps:
            break
        if g > 0.0:
            hi = hk
            ghi = g
        else:
            lo = hk
            glo = g
        rate = event_rate(kind, pl, y1, media[9]) if restarts == 1 else (g - g_prev) / (hk - h_prev)
        h_prev = hk
        g_prev = g
        nxt = hk - g / rate
        if not (nxt > lo and nxt < hi):
            nxt = lo + (hi - lo) * (-glo) / (ghi - glo)
            if not (nxt > lo and nxt < hi):
                nxt = 0.5 * (lo + hi)
        if nxt == hk:
            break
        hk = nxt
    return hk, ok, has, restarts


@nb.njit(**NJIT_FLAGS)
def media_jac(media, cell, x, v, out, k, scratch):
    """out[k:k+3] = J(x) v with J = grad(n grad n) (1/m^2), the x-Jacobian of dp/dsigma, at x along v (3,).

    Mesh media, in the cell containing x (traced quantity m linear with gradient g): n^2 -> J = 0,
    n -> J = g g^T, c -> J = 3 c_ref^2 g g^T / m^4 (n grad n = -c_ref^2 g / m^3). Exact media: central
    difference of the exact n grad n at x +- e v/|v|, e = VAR_FD_M (truncation (e/L)^2 for a profile
    varying over L metres: 1e-10 at L = 1 m). scratch : (6,).
    """
    vn = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if vn == 0.0:
        out[k] = 0.0
        out[k + 1] = 0.0
        out[k + 2] = 0.0
        return
    if media[0] == MEDIA_MESH:
        _, c = mesh_n_and_grad_at(media[3], media[4], media[5], media[6], media[7], media[8], media[9], cell, x,
                                  scratch, 0)  # fmt: skip
        q = media[8]
        gx = media[7][c, 0]
        gy = media[7][c, 1]
        gz = media[7][c, 2]
        f = 0.0
        if q == QUANTITY_CODES_N:
            f = 1.0
        elif q == QUANTITY_CODES_C:
            m = media[5][c] + gx * (x[0] - media[6][c, 0]) + gy * (x[1] - media[6][c, 1]) + gz * (x[2] - media[6][c, 2])
            f = 3.0 * media[9] * media[9] / (m * m * m * m)
        gv = f * (gx * v[0] + gy * v[1] + gz * v[2])
        out[k] = gv * gx
        out[k + 1] = gv * gy
        out[k + 2] = gv * gz
        return
    e = VAR_FD_M / vn
    xp = scratch[3:6]
    for i in range(3):
        xp[i] = x[i] + e * v[i]
    n_p = n_and_grad_at(media[1], media[2], xp, scratch, 0)
    fx = n_p * scratch[0]
    fy = n_p * scratch[1]
    fz = n_p * scratch[2]
    for i in range(3):
        xp[i] = x[i] - e * v[i]
    n_m = n_and_grad_at(media[1], media[2], xp, scratch, 0)
    out[k] = (fx - n_m * scratch[0]) / (2.0 * e)
    out[k + 1] = (fy - n_m * scratch[1]) / (2.0 * e)
    out[k + 2] = (fz - n_m * scratch[2]) / (2.0 * e)


@nb.njit(**NJIT_FLAGS)
def var_step(method, media, cell, y0, h, work, v0, v1, vw, rate):
    """v1 (NV,) = the derivative of the step map y0 -> y1 (length h, stages k_j in work rows 0.. as the
    accepted rk_step left them) applied to v0: the same tableau on X' = P, P' = J(x) X at the step's own
    stage positions (recomputed from work bit for bit as rk_step formed them). DOPRI5's FSAL stage
    (weight 0) is skipped. rate : (6,) or (0,): when given, also d(x1, p1)/dh, the step map's rate in its
    length (a landing's length moves with the launch: dh = -(m.X1)/(m.rate_x)); it is f(y1) only to the
    method's order. vw : (2 MAX_STAGES + 4, NV) scratch."""
    n_st = STAGES[method]
    ys = vw[MAX_STAGES]
    vs = vw[MAX_STAGES + 1]
    scratch = vw[MAX_STAGES + 2]
    yd = vw[2 * MAX_STAGES + 3]
    with_rate = rate.shape[0] == 6
    for st in range(n_st):
        if st == n_st - 1 and B[method, st] == 0.0:
            break
        for i in range(3):
            acc = 0.0
            for j in range(st):
                acc += A[method, st, j] * work[j, i]
            ys[i] = y0[i] + h * acc
        for i in range(NV):
            acc = 0.0
            for j in range(st):
                acc += A[method, st, j] * vw[j, i]
            vs[i] = v0[i] + h * acc
        row = vw[st]
        for kk in range(2):
            o = 3 * kk
            for i in range(3):
                row[o + i] = vs[6 + o + i]
            media_jac(media, cell, ys, vs[o : o + 3], row, 6 + o, scratch)
        if with_rate:  # d Y_st/dh = sum_j a_j (k_j + h dk_j/dh), dk_st/dh = J_f(Y_st) dY_st/dh
            for i in range(6):
                acc = 0.0
                for j in range(st):
                    acc += A[method, st, j] * (work[j, i] + h * vw[MAX_STAGES + 3 + j, i])
                yd[i] = acc
            rd = vw[MAX_STAGES + 3 + st]
            for i in range(3):
                rd[i] = yd[3 + i]
            media_jac(media, cell, ys, yd[0:3], rd, 3, scratch)
    for i in range(NV):
        acc = 0.0
        for j in range(n_st):
            if B[method, j] != 0.0:
                acc += B[method, j] * vw[j, i]
        v1[i] = v0[i] + h * acc
    if with_rate:
        for i in range(6):
            acc = 0.0
            for j in range(n_st):
                if B[method, j] != 0.0:
                    acc += B[method, j] * (work[j, i] + h * vw[MAX_STAGES + 3 + j, i])
            rate[i] = acc

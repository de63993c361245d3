"""Eigenrays: the rays from a source that pass exactly through a receiver (docs/physics.md §12).

Search, per (source, receiver):

1. **Bracket** in a vertical launch fan in the receiver's azimuth ``az0`` (elevations over
   ``(-90, 90)`` deg): each ray's sampled path gives the height ``z(R)`` and time where it first reaches
   the receiver's horizontal range ``R``; the exact probe of the ray at that time gives its reflection
   count ``k``. Consecutive elevations with the same ``k`` between which ``z(R) - z_r`` changes sign
   bracket one arrival (direct, ground-reflected, each branch of a refracted multipath).
   **Wall reflections** (arrivals out of that vertical plane): for every reflecting vertical wall
   (``RayModel.walls``, the buildings' outer walls) with the source and the receiver in front of it, the
   receiver's mirror image ``r'`` in the wall's plane gives the azimuth and the *unfolded* range ``R'`` of
   the wall-reflected arrivals (a vertical wall mirrors the horizontal path and keeps its length). If
   the straight horizontal line from the source to ``r'`` crosses the wall segment (the horizontal path
   of a stratified medium without wind is straight; ``WALL_MARGIN`` of the wall's length allowed for
   wind), a second fan is traced at that azimuth, and each ray's height is read where its horizontal arc
   length (not its projected distance) first reaches ``R'``; only crossings nearer to ``r`` than to ``r'``
   count (rays that passed over or beside the wall go on toward the image). Its sign changes bracket
   the arrivals with one wall reflection (and any ground reflections), refined as below. Arrivals
   with two or more wall reflections are not searched.
2. **Refine** each bracket by Newton in the launch angles ``gamma = (el, az)``: probe the ray at time
   ``t`` (the kernels' exact state at a given travel time), split the miss ``r - x(t)`` into its part
   along the tangent (which moves ``t`` by ``along / c``) and across it, and solve
   ``X_perp dgamma = q_perp`` (3x2 least squares) with the ray's own Jacobian: the paraxial derivatives
   ``X_k = dx/dgamma_k`` of every analytic curve (engine/kernels/paraxial.py; central differences of
   launches, ``h = 1e-6`` rad, remain as ``probe(..., central=True)`` for comparison). A step that makes the
   miss larger is halved (at most 8 times); a step that changes the reflection count is refused the same
   way. Converged when ``|r - x| <= tolerance_m``.
3. **Describe** the arrival: exact travel time (``t + along / c`` at the last probe), arc length,
   reflections, caustics passed (sign changes of ``det[X_1, X_2, T]`` sampled along the converged ray,
   a reflection's mirror flip discounted; X_k here in the smooth medium, ``probe(..., smooth=True)``, as the
   beams carry them: docs/physics.md §11), the tube's spreading ``sqrt(cos el0 / J)`` (J = |X_1,perp x
   X_2,perp|, re the free field at 1 m, the same as the beam field's) and per band the complex amplitude
   ``A = spreading * prod Q(cos th_j, s) * exp(-alpha s / 2) * (-i)^caustics`` (the pressure re 1 m free
   field is ``A exp(i omega t)``; e^{-i omega t} time convention as the beam field).

Nothing is dropped silently: brackets that do not converge are returned as failures with the reason,
and the caller reports them per receiver.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import NamedTuple

import numba
import numpy as np

from bentray.engine.constants import STATUS_TIME_LIMIT
from bentray.engine.kernels.beams import BeamTables
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.tracer import trace

__all__ = [
    "Arrival",
    "EigenraySearch",
    "EigenrayFailure",
    "RayModel",
    "SearchSettings",
    "find_eigenrays",
    "launch_direction",
]

FD_STEP_RAD = 1e-6  # central-difference step of the launch angles (probe(..., central=True))
MAX_HALVINGS = 8  # step halvings per Newton iteration before a bracket is given up
DUPLICATE_RAD = 1e-7  # two converged launches closer than this (and with the same reflections) are one ray
CAUSTIC_SAMPLE_M = 5.0  # spacing (m of arc) of the det[X1, X2, T] samples that count caustics
MAX_CAUSTIC_SAMPLES = 400
SUBDIVISIONS = 8  # sub-intervals of a bracket interval that straddles a branch boundary
MAX_DEPTH = 4  # such splits in a row (8^4: a 0.25 deg fan step resolved to 6e-5 deg)
WALL_MARGIN = 0.05  # a wall's bracket fan runs where the source-image line crosses the wall within 5 % of its length


@dataclass(frozen=True)
class RayModel:
    """What probing one ray of one source needs.

    mesh : the media mesh (with ground materials); curve : "parabolic" | "circular" | "n_linear";
    c_ref : reference speed (m/s); wind : (code, params) or None; origin : (3,) source position (m, world
    frame); start_cell : the cell that contains it; max_reflections, max_steps : the job's ray limits.
    tables : per-band ground table and absorption (None: spreading only, no per-band amplitudes);
    frequencies_hz : (F,) the bands of ``tables``. walls : (W, 6) reflecting vertical walls [x0, y0, x1,
    y1, z_lo, z_hi] (m, world frame), each with its outside on the right of x0 -> x1 (a counter-clockwise
    footprint's edges); searched for single wall reflections (module docstring). Empty: none.
    """

    mesh: CellMesh
    curve: str
    c_ref: float
    origin: np.ndarray
    start_cell: int
    max_reflections: int
    max_steps: int = 10_000_000
    wind: tuple[int, np.ndarray] | None = None
    tables: BeamTables | None = None
    frequencies_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    walls: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))


@dataclass(frozen=True)
class SearchSettings:
    """Bracket fan size, convergence tolerance (m of miss distance) and Newton iteration cap."""

    elevations: int = 721
    tolerance_m: float = 1e-8
    max_iterations: int = 40
    path_samples: int = 400


class Probe(NamedTuple):
    """One ray at travel time t: position x (3,) m, unit tangent (3,), time s, arc m, reflections, status,
    X (3, 2) dx/dgamma (m/rad), slowness 1/c (s/m), reflection cosines and materials (R,)."""

    x: np.ndarray
    tangent: np.ndarray
    time: float
    arc: float
    reflections: int
    status: int
    X: np.ndarray
    slowness: float
    refl_cos: np.ndarray
    refl_mat: np.ndarray


@dataclass
class Arrival:
    """One eigenray of a (source, receiver) pair.

    time_s, length_m : travel time and arc length to the receiver; elevation_deg, azimuth_deg : launch
    angles; reflections; caustics passed; spreading : |p| re the free field at 1 m from the tube alone;
    amplitude : (F,) complex per band (spreading, reflections, absorption, caustic phase; the pressure re
    1 m is amplitude * exp(i omega time_s)); miss_m : final |r - x|; iterations : Newton iterations.
    """

    time_s: float
    length_m: float
    elevation_deg: float
    azimuth_deg: float
    reflections: int
    caustics: int
    spreading: float
    amplitude: np.ndarray
    miss_m: float
    iterations: int


@dataclass
class EigenrayFailure:
    """A bracket that did not converge: its launch elevation (deg), reflections and the reason."""

    elevation_deg: float
    reflections: int
    reason: str


@dataclass
class EigenraySearch:
    """All arrivals found for one (source, receiver), sorted by time, and the brackets that failed."""

    arrivals: list[Arrival]
    failures: list[EigenrayFailure]
    brackets: int


def launch_direction(el: float, az: float) -> np.ndarray:
    """Unit launch direction (3,) for elevation el and azimuth az (rad): (cos el cos az, cos el sin az, sin el)."""
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def _trace_to(model: RayModel, gammas: np.ndarray, time_s: float, *, paraxial: bool | str, path_samples: int = 0):
    n = gammas.shape[0]
    dirs = np.array([launch_direction(g[0], g[1]) for g in gammas]).reshape(n, 3)
    return trace(
        model.mesh,
        model.curve,
        model.c_ref,
        np.repeat(model.origin[None, :], n, axis=0),
        dirs,
        np.full(n, model.start_cell, np.int64),
        max_time_s=float(time_s),
        max_reflections=model.max_reflections,
        max_steps=model.max_steps,
        path_samples=path_samples,
        wind=model.wind,
        paraxial=paraxial,
        record_reflections=True,
    )


def probe(model: RayModel, gamma: np.ndarray, time_s: float, *, central: bool = False, smooth: bool = False) -> Probe:
    """The ray launched at gamma = (el, az) (rad) at travel time ``time_s``, with its launch Jacobian: the
    paraxial derivatives (exact), or with ``central`` central differences of 5 launches (h = FD_STEP_RAD).
    smooth : the derivatives in the smooth medium instead (trace(paraxial="smooth"), what beams carry: the
    arrival's spreading and caustics; Newton keeps the mesh's exact Jacobian)."""
    if not central:
        res = _trace_to(model, np.asarray(gamma, float)[None, :], time_s, paraxial="smooth" if smooth else True)
        assert res.paraxial is not None
        par = res.paraxial[0]
        X = np.column_stack([par[0:3], par[3:6]])
        slowness = float(par[12]) / model.c_ref
        i = 0
    else:
        h = FD_STEP_RAD
        g = np.asarray(gamma, float)
        gs = np.array([g, g + (h, 0.0), g - (h, 0.0), g + (0.0, h), g - (0.0, h)])
        res = _trace_to(model, gs, time_s, paraxial=False)
        p = res.position
        X = np.column_stack([(p[1] - p[2]) / (2 * h), (p[3] - p[4]) / (2 * h)])
        slowness = float(res.time_s[0] / res.length_m[0]) if res.length_m[0] > 0 else 1.0 / model.c_ref
        i = 0
    assert res.reflection_cos is not None and res.reflection_material is not None
    return Probe(
        x=res.position[i].copy(),
        tangent=res.direction[i] / np.linalg.norm(res.direction[i]),
        time=float(res.time_s[i]),
        arc=float(res.length_m[i]),
        reflections=int(res.reflections[i]),
        status=int(res.status[i]),
        X=X,
        slowness=slowness,
        refl_cos=res.reflection_cos[i].copy(),
        refl_mat=res.reflection_material[i].copy(),
    )


@contextmanager
def _one_thread() -> Iterator[None]:
    """Run single-ray probes on one numba thread: waking the pool for one ray cost 5-6 ms per call on a
    busy 2-core machine (0.9 ms on one thread)."""
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def _miss(pr: Probe, r: np.ndarray) -> tuple[np.ndarray, float]:
    """(q_perp (3,), along) of the receiver r relative to the probe: r - x = along T + q_perp."""
    q = r - pr.x
    along = float(q @ pr.tangent)
    return q - along * pr.tangent, along


def _newton_step(pr: Probe, q_perp: np.ndarray) -> np.ndarray:
    """Launch-angle correction (2,) solving X_perp dgamma = q_perp in the least-squares sense."""
    t = pr.tangent
    x_perp = pr.X - np.outer(t, t @ pr.X)
    step, *_ = np.linalg.lstsq(x_perp, q_perp, rcond=None)
    return np.asarray(step, float)


def _refine(model: RayModel, r: np.ndarray, gamma0: np.ndarray, t0: float, k: int, st: SearchSettings):
    """Newton from (gamma0, t0) on arrivals with k reflections: (gamma, probe, iterations) or a reason."""
    gamma = np.asarray(gamma0, float).copy()
    t = float(t0)
    pr = probe(model, gamma, t)
    if pr.reflections != k or pr.status != STATUS_TIME_LIMIT:
        return f"the bracket's ray does not reach the receiver with {k} reflections"
    q, along = _miss(pr, r)
    err = math.hypot(float(np.linalg.norm(q)), along)
    for it in range(1, st.max_iterations + 1):
        if err <= st.tolerance_m:
            return gamma, pr, it - 1
        try:
            step = _newton_step(pr, q)
        except np.linalg.LinAlgError:
            return "singular launch Jacobian (receiver on a caustic?)"
        dt = along * pr.slowness
        scale = 1.0
        for _ in range(MAX_HALVINGS + 1):
            g_new = gamma + scale * step
            t_new = t + dt
            cand = probe(model, g_new, t_new) if t_new > 0 else None
            if cand is not None and cand.reflections == k and cand.status == STATUS_TIME_LIMIT:
                q_new, along_new = _miss(cand, r)
                err_new = math.hypot(float(np.linalg.norm(q_new)), along_new)
                if err_new < err or err_new <= st.tolerance_m:
                    gamma, t, pr, q, along, err = g_new, t_new, cand, q_new, along_new, err_new
                    break
            scale *= 0.5
        else:
            return f"Newton stalled at a miss of {err:.3g} m"
    if err <= st.tolerance_m:
        return gamma, pr, st.max_iterations
    return f"no convergence in {st.max_iterations} iterations (miss {err:.3g} m)"


def _caustics(model: RayModel, gamma: np.ndarray, pr: Probe) -> int:
    """Caustics passed before the probe: sign changes of det[X1, X2, T] at samples along the ray, each
    reflection's mirror flip (a sign change without a caustic) discounted."""
    n = int(min(max(math.ceil(pr.arc / CAUSTIC_SAMPLE_M), 16), MAX_CAUSTIC_SAMPLES))
    count = 0
    prev_sign = 0
    prev_k = 0
    for j in range(1, n + 1):
        sample = pr if j == n else probe(model, gamma, pr.time * j / n, smooth=True)
        det = float(np.linalg.det(np.column_stack([sample.X[:, 0], sample.X[:, 1], sample.tangent])))
        sign = 1 if det > 0 else (-1 if det < 0 else 0)
        if sign == 0:
            continue
        if prev_sign != 0:
            expected = prev_sign * (-1) ** (sample.reflections - prev_k)
            if sign != expected:
                count += 1
        prev_sign, prev_k = sign, sample.reflections
    return count


def _amplitudes(model: RayModel, pr: Probe, spreading: float, caustics: int) -> np.ndarray:
    """(F,) complex amplitude per band: spreading x reflection coefficients x absorption x (-i)^caustics."""
    from bentray.engine.acoustics.ground import q_lookup

    tabs = model.tables
    n_f = model.frequencies_hz.shape[0]
    if tabs is None or n_f == 0:
        return np.zeros(0, complex)
    out = np.empty(n_f, complex)
    turn = (-1j) ** (caustics % 4)
    n_refl = min(pr.reflections, pr.refl_cos.shape[0])
    for f in range(n_f):
        a = complex(math.exp(-0.5 * tabs.alpha[f] * pr.arc))
        for j in range(n_refl):
            mat = int(pr.refl_mat[j])
            if mat <= 0:
                continue
            qr, qi = q_lookup(tabs.q_table, tabs.q_grid, mat, f, float(pr.refl_cos[j]), pr.arc)
            a *= complex(qr, qi)
        out[f] = spreading * a * turn
    return out


def _describe(model: RayModel, r: np.ndarray, gamma: np.ndarray, pr: Probe, iterations: int) -> Arrival:
    q, along = _miss(pr, r)
    # the tube in the smooth medium (docs/physics.md §11): the mesh's own derivatives jump where the ray
    # turns near a layer face; the converged ray, time and reflections are the same
    pr = probe(model, gamma, pr.time, smooth=True)
    t = pr.tangent
    x_perp = pr.X - np.outer(t, t @ pr.X)
    jac = float(np.linalg.norm(np.cross(x_perp[:, 0], x_perp[:, 1])))
    spreading = math.sqrt(math.cos(gamma[0]) / jac) if jac > 0 else math.inf
    caustics = _caustics(model, gamma, pr)
    return Arrival(
        time_s=pr.time + along * pr.slowness,
        length_m=pr.arc + along,
        elevation_deg=math.degrees(gamma[0]),
        azimuth_deg=math.degrees(gamma[1]),
        reflections=pr.reflections,
        caustics=caustics,
        spreading=spreading,
        amplitude=_amplitudes(model, pr, spreading, caustics),
        miss_m=math.hypot(float(np.linalg.norm(q)), along),
        iterations=iterations,
    )


class _Bracket(NamedTuple):
    gamma: np.ndarray  # (2,) rad, interpolated start
    time: float
    reflections: int


class _Target(NamedTuple):
    """Where a fan's rays are read: at horizontal range ``rng`` along ``h0`` (projected distance), or, with
    ``image`` (3,) set, where their horizontal arc length first reaches ``rng`` and only if nearer to the
    receiver ``r`` than to its wall image."""

    r: np.ndarray
    rng: float
    h0: np.ndarray
    image: np.ndarray | None = None


def _range_crossings(res, origin: np.ndarray, target: _Target):
    """Per fan ray: (f = z(R) - z_r, time at R) at the first sampled crossing of the range R (NaN: none)."""
    paths = res.paths
    n = res.position.shape[0]
    f = np.full(n, np.nan)
    t_cross = np.full(n, np.nan)
    rng = target.rng
    for i in range(n):
        a, b = int(paths.offsets[i]), int(paths.offsets[i + 1])
        pts = paths.points[a:b]
        if pts.shape[0] < 2:
            continue
        if target.image is None:
            rho = (pts[:, :2] - origin[:2]) @ target.h0
        else:
            steps = np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))
            rho = np.concatenate([[0.0], np.cumsum(steps)])
        up = np.nonzero((rho[:-1] < rng) & (rho[1:] >= rng))[0]
        if up.size == 0:
            continue
        j = int(up[0])
        u = (rng - rho[j]) / (rho[j + 1] - rho[j])
        if target.image is not None:
            xy = pts[j, :2] + u * (pts[j + 1, :2] - pts[j, :2])
            if np.hypot(*(xy - target.r[:2])) >= np.hypot(*(xy - target.image[:2])):
                continue
        f[i] = pts[j, 2] + u * (pts[j + 1, 2] - pts[j, 2]) - float(target.r[2])
        t_cross[i] = paths.time_s[a + j] + u * (paths.time_s[a + j + 1] - paths.time_s[a + j])
    return f, t_cross


class _Fan(NamedTuple):
    """A vertical fan at azimuth az: elevations (rad), f = z(R) - z_r (m; NaN: R not reached), times (s)."""

    el: np.ndarray
    f: np.ndarray
    t: np.ndarray


def _trace_fan(model: RayModel, els: np.ndarray, az: float, target: _Target, st: SearchSettings, max_time_s: float):
    gammas = np.column_stack([els, np.full(els.size, az)])
    res = _trace_to(model, gammas, max_time_s, paraxial=False, path_samples=st.path_samples)
    f, t_cross = _range_crossings(res, model.origin, target)
    return _Fan(els, f, t_cross)


def _direct_target(model: RayModel, r: np.ndarray) -> _Target:
    d = r - model.origin
    rng = math.hypot(float(d[0]), float(d[1]))
    return _Target(r, rng, d[:2] / rng)


def wall_images(origin: np.ndarray, r: np.ndarray, walls: np.ndarray) -> list[np.ndarray]:
    """Mirror images (3,) of receiver ``r`` in the walls (W, 6) that can reflect toward it: source and
    receiver in front of the wall (on its outside), and the horizontal source-image line crossing the wall
    segment within WALL_MARGIN of its length (module docstring)."""
    images = []
    for x0, y0, x1, y1, _, _ in np.asarray(walls, float).reshape(-1, 6):
        dx, dy = x1 - x0, y1 - y0
        length = math.hypot(dx, dy)
        if length <= 0.0:
            continue
        nx, ny = dy / length, -dx / length  # outward normal (outside on the right of x0 -> x1)
        ds = (origin[0] - x0) * nx + (origin[1] - y0) * ny
        dr = (r[0] - x0) * nx + (r[1] - y0) * ny
        if ds <= 0.0 or dr <= 0.0:
            continue
        img = np.array([r[0] - 2.0 * dr * nx, r[1] - 2.0 * dr * ny, r[2]])
        # the source-image line meets the wall's line at fraction ds / (ds + dr) of its length
        u = ds / (ds + dr)
        hit = origin[:2] + u * (img[:2] - origin[:2])
        along = ((hit[0] - x0) * dx + (hit[1] - y0) * dy) / (length * length)
        if -WALL_MARGIN <= along <= 1.0 + WALL_MARGIN:
            images.append(img)
    return images


def _reflections_at(model: RayModel, fan: _Fan, az: float, idx: np.ndarray) -> dict[int, int]:
    """Reflection count of fan rays idx at their range-crossing time (one probe each, one thread)."""
    with _one_thread():
        return {int(i): probe(model, np.array([fan.el[i], az]), float(fan.t[i])).reflections for i in idx}


def _sign_changes(fan: _Fan) -> np.ndarray:
    ok = np.isfinite(fan.f)
    return np.nonzero(ok[:-1] & ok[1:] & (np.sign(fan.f[:-1]) != np.sign(fan.f[1:])))[0]


def _resolve(model, target: _Target, fan: _Fan, az, st, max_time_s, depth, out: list, failures: list) -> None:
    """Brackets from the sign changes of ``fan``; an interval whose ends differ in reflection count
    holds a branch boundary next to the root (a ray grazing the ground there): it is split into
    SUBDIVISIONS sub-intervals, at most MAX_DEPTH times (then it is reported, not dropped)."""
    cand = _sign_changes(fan)
    if cand.size == 0:
        return
    k = _reflections_at(model, fan, az, np.unique(np.concatenate([cand, cand + 1])))
    for j in cand:
        j = int(j)
        if k[j] == k[j + 1]:
            u = fan.f[j] / (fan.f[j] - fan.f[j + 1])
            el = fan.el[j] + u * (fan.el[j + 1] - fan.el[j])
            t = fan.t[j] + u * (fan.t[j + 1] - fan.t[j])
            out.append(_Bracket(np.array([el, az]), float(t), k[j]))
        elif depth < MAX_DEPTH:
            sub = np.linspace(fan.el[j], fan.el[j + 1], SUBDIVISIONS + 1)
            sub_fan = _trace_fan(model, sub, az, target, st, max_time_s)
            _resolve(model, target, sub_fan, az, st, max_time_s, depth + 1, out, failures)
        else:
            failures.append(
                EigenrayFailure(
                    math.degrees(float(fan.el[j])),
                    min(k[j], k[j + 1]),
                    f"a branch boundary ({k[j]} / {k[j + 1]} reflections) stays within "
                    f"{math.degrees(float(fan.el[j + 1] - fan.el[j])):.2g} deg of a root",
                )
            )


def _brackets(
    model: RayModel, r: np.ndarray, st: SearchSettings, max_time_s: float
) -> tuple[list[_Bracket], list[EigenrayFailure]] | str:
    d = r - model.origin
    if math.hypot(float(d[0]), float(d[1])) < 1e-6:
        return "the receiver is directly above or below the source (the bracket needs a horizontal offset)"
    half = 0.5 * math.pi * (1.0 - 1.0 / st.elevations)
    els = np.linspace(-half, half, st.elevations)
    targets = [_direct_target(model, r)]
    for img in wall_images(model.origin, r, model.walls):
        di = img - model.origin
        rng = math.hypot(float(di[0]), float(di[1]))
        targets.append(_Target(r, rng, di[:2] / rng, img))
    out: list[_Bracket] = []
    failures: list[EigenrayFailure] = []
    for target in targets:
        az = math.atan2(float(target.h0[1]), float(target.h0[0]))
        fan = _trace_fan(model, els, az, target, st, max_time_s)
        _resolve(model, target, fan, az, st, max_time_s, 0, out, failures)
    return out, failures


def find_eigenrays(
    model: RayModel, receiver: np.ndarray, max_time_s: float, settings: SearchSettings | None = None
) -> EigenraySearch:
    """Every eigenray from ``model``'s source to ``receiver`` (3,) m found in the vertical bracket fans (the
    receiver's azimuth, and each reflecting wall's image of it).

    max_time_s : the longest travel time searched (the job's rays.max_time_s).
    """
    st = settings or SearchSettings()
    r = np.asarray(receiver, float).reshape(3)
    found = _brackets(model, r, st, max_time_s)
    if isinstance(found, str):
        return EigenraySearch([], [EigenrayFailure(math.nan, -1, found)], 0)
    brackets, failures = found
    arrivals: list[Arrival] = []
    seen: list[tuple[np.ndarray, int]] = []
    with _one_thread():
        _refine_all(model, r, brackets, st, arrivals, failures, seen)
    arrivals.sort(key=lambda a: a.time_s)
    return EigenraySearch(arrivals, failures, len(brackets))


def _refine_all(model, r, brackets, st, arrivals, failures, seen) -> None:
    for b in brackets:
        got = _refine(model, r, b.gamma, b.time, b.reflections, st)
        if isinstance(got, str):
            failures.append(EigenrayFailure(math.degrees(float(b.gamma[0])), b.reflections, got))
            continue
        gamma, pr, iterations = got
        if any(kk == pr.reflections and float(np.max(np.abs(gg - gamma))) < DUPLICATE_RAD for gg, kk in seen):
            continue
        seen.append((gamma, pr.reflections))
        arrivals.append(_describe(model, r, gamma, pr, iterations))

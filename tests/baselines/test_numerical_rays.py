"""Numerical ray-integration baselines (engine/baselines) against independent references.

- media: the Numba closed forms against the Profile methods (rtol 1e-12); the mesh evaluation against
  the CellMesh's linear model; single steps against the exact parabola of a constant grad(n^2);
- homogeneous air: straight rays and mirror images (every method, exact and mesh media) to 1e-9;
- linear_c: the textbook circle (closed form below); log (A-LD): scipy DOP853 at rtol 1e-12
  (tests/reference/ray_ode.py): observed orders of Euler (~1) and RK4 (~4) as the step halves, and
  DOPRI5 error falling with its tolerance;
- mesh media: the same rays as the analytic tracer on the same slab / tet mesh (same media);
- every ray ends with a status: limits, lost, zero and 100x gradients, grazing launches.
Relative errors are |x - x_ref| / (c0 t) after t = 10 s unless stated.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine.baselines.exact_media import exact_media_spec, n_and_grad
from bentray.engine.baselines.integrators import METHOD_DOPRI5, METHOD_RK4, NY, WORK_ROWS, make_media, rhs, rk_step
from bentray.engine.baselines.mesh_media import WALK_INSIDE, mesh_n_and_grad, walk
from bentray.engine.baselines.trace_numerical import NUMERICAL_METHODS, trace_numerical
from bentray.engine.constants import (
    STATUS_EXITED,
    STATUS_LOST,
    STATUS_NAMES,
    STATUS_REFLECTION_LIMIT,
    STATUS_STEP_LIMIT,
    STATUS_TIME_LIMIT,
)
from bentray.engine.media import build_media
from bentray.engine.mesh.cells import locate_points
from bentray.engine.mesh.fcc import fcc_resample
from bentray.engine.mesh.slabs import FACE_BOTTOM, build_slab_mesh, locate_in_slabs
from bentray.engine.mesh.tets import build_tet_mesh
from bentray.engine.profiles import (
    Fluctuating,
    Grid,
    Homogeneous,
    HotSpot,
    LinearC,
    LinearN,
    LinearN2,
    Log,
    MirageInferior,
    MirageSuperior,
    Table,
)
from bentray.engine.tracer import trace
from bentray.scenes.schema import Solver
from tests.reference.ray_ode import integrate_ray, log_profile

LO = np.array([-50.0, -50.0, 0.0])
HI = np.array([4000.0, 50.0, 2600.0])
SOURCE = np.array([0.0, 0.0, 1.5])
T_END = 10.0
C_REF = 340.0
PATH = 340.0 * T_END  # the relative errors are divided by this (c0 t)
# A-LD comparison rays: the near-horizontal ray trapped in the ground duct (36 reflections) is left out
# of the order tests: the DOP853 oracle itself scatters by 1e-4 m there between rtol 1e-11 and 1e-13.
ELEVATIONS = np.array([-45.0, -30.0, -15.0, -7.5, 7.5, 15.0, 30.0, 45.0])


def _fan(elevations_deg, source=SOURCE):
    el = np.radians(np.asarray(elevations_deg, float))
    d = np.column_stack([np.cos(el), np.zeros_like(el), np.sin(el)])
    return np.tile(source, (len(el), 1)), d


def _run(method, profile, elevations=ELEVATIONS, source=SOURCE, **kw):
    o, d = _fan(elevations, source)
    kw.setdefault("max_time_s", T_END)
    kw.setdefault("max_reflections", 50)
    kw.setdefault("domain_min", LO)
    kw.setdefault("domain_max", HI)
    return trace_numerical(
        method, "exact", exact_spec=exact_media_spec(profile), c_ref=profile.c_ref, origins=o, directions=d, **kw
    )


def _order(errors, ratio=2.0):
    return [math.log(a / b) / math.log(ratio) for a, b in zip(errors[:-1], errors[1:], strict=True)]


# ------------------------------------------------------------------------------------------------
# media
# ------------------------------------------------------------------------------------------------
ANALYTIC = [
    Homogeneous(c0=331.0),
    LinearC(c0=335.0, alpha=0.3),
    LinearN(n0=1.1, alpha=0.02),
    LinearN2(n0=1.05, alpha=0.01),
    Log(c0=338.0, b=-2.0, z_g=0.3),
    MirageInferior(),
    MirageSuperior(),
    HotSpot(center=(20.0, -10.0, 15.0), t_s=340.0, d0=30.0),
]


def _points(rng, n, z_min):
    return np.column_stack([rng.uniform(-200, 200, n), rng.uniform(-200, 200, n), rng.uniform(z_min, 300.0, n)])


def _eval_exact(spec, pts):
    code, params = spec
    n = np.empty(len(pts))
    g = np.empty((len(pts), 3))
    for i, p in enumerate(pts):
        n[i] = n_and_grad(code, params, p, g[i])
    return n, g


@pytest.mark.parametrize("profile", ANALYTIC, ids=lambda p: p.kind)
def test_exact_media_match_the_profile_methods(profile):
    rng = np.random.default_rng(1)
    above = _points(rng, 300, 0.0)
    above[:5, 2] = [0.0, 1e-9, 0.5, 10.999e3, 15.0]  # ground, just above, hot-spot centre height
    above[5] = [20.0, -10.0, 15.0]  # the hot-spot centre itself (zero subgradient of the cone)
    below = _points(rng, 100, 0.0)
    below[:, 2] = rng.uniform(-0.2, 0.0, 100)  # just below ground (mirages turn unphysical further down)
    cases = [
        (exact_media_spec(profile, smooth_below_ground=False), np.vstack([above, below])),
        (exact_media_spec(profile), above),
    ]  # the smooth continuation only differs below ground
    for spec, pts in cases:
        n, g = _eval_exact(spec, pts)
        np.testing.assert_allclose(n, profile.quantity("n", pts), rtol=1e-12, atol=0)
        g_ref = profile.refractive_index_gradient(pts)
        np.testing.assert_allclose(g, g_ref, rtol=1e-12, atol=1e-12 * np.abs(g_ref).max())


@pytest.mark.parametrize("profile", [Log(b=1.0, z_g=0.4), HotSpot(center=(0.0, 0.0, 5.0))], ids=lambda p: p.kind)
def test_smooth_continuation_below_ground_is_c1(profile):
    """n and grad n continuous across z = 0 (and across z = -z_g/2 for the log profile's linear tail)."""
    spec = exact_media_spec(profile)
    levels = [0.0] + ([-0.5 * profile.z_g] if profile.kind == "log" else [])
    eps = 1e-7
    for z in levels:
        pts = np.array([[3.0, 1.0, z - eps], [3.0, 1.0, z + eps]])
        n, g = _eval_exact(spec, pts)
        assert abs(n[1] - n[0] - eps * (g[0, 2] + g[1, 2])) < 1e-15  # continuous, slope = gradient
        assert np.all(np.abs(g[1] - g[0]) < 1e-5 * np.abs(g).max())  # a gradient without a jump
    # the Profile (clamped below ground) has a jump in grad n at z = 0 for these kinds: that is why
    gz = profile.refractive_index_gradient(np.array([[3.0, 1.0, -eps], [3.0, 1.0, eps]]))[:, 2]
    assert abs(gz[1] - gz[0]) > 1e-3 * abs(gz[1])


def test_sampled_profiles_are_refused():
    z = np.linspace(0, 100, 5)
    grid = Grid([0, 0, 0], [10, 10, 10], c=np.full((2, 2, 2), 340.0))
    for profile in (Table(z, c=340 + 0.1 * z), grid, Fluctuating(Log())):
        with pytest.raises(ValueError, match="solver.media = 'mesh'"):
            exact_media_spec(profile)


@pytest.mark.parametrize("quantity", ["n2", "c", "n"])
def test_mesh_media_walk_to_the_cell_and_evaluate_its_linear_model(quantity):
    z = np.concatenate([[0.0], np.geomspace(0.01, 500.0, 40)])
    m_of_z = {
        "n2": lambda zz: 1.0 + 0.004 * np.sqrt(zz),
        "c": lambda zz: 340.0 + 2.0 * np.log1p(zz),
        "n": lambda zz: 1.0 + 1e-3 * np.log1p(zz),
    }[quantity]
    mesh = build_slab_mesh(LO, np.array([4000.0, 50.0, 500.0]), z, m_of_z)
    med = make_media("mesh", mesh=mesh, quantity=quantity, c_ref=C_REF)
    rng = np.random.default_rng(2)
    pts = np.column_stack([rng.uniform(-40, 3900, 200), rng.uniform(-40, 40, 200), rng.uniform(0, 499, 200)])
    cells = locate_in_slabs(z, pts)
    g = np.empty(3)
    for p, c in zip(pts, cells, strict=True):
        found, face, _ = walk(mesh.planes, mesh.neighbours, 0, p, 0.0)
        assert face == WALK_INSIDE and found == c
        n, cell = mesh_n_and_grad(*med[3:10], 17, p, g)
        m = mesh.media_at(c, p[None])[0]
        gm = mesh.gradient[c]
        n_ref, dn = {"n2": (math.sqrt(m), 1 / (2 * math.sqrt(m))), "c": (C_REF / m, -C_REF / m**2), "n": (m, 1.0)}[
            quantity
        ]
        assert cell == c
        assert n == pytest.approx(n_ref, rel=1e-14)
        np.testing.assert_allclose(g, dn * gm, rtol=1e-14, atol=1e-300)
    # below the ground the walk stops at the bottom cell's ground face (the tracer's boundary event)
    cell, face, _ = walk(mesh.planes, mesh.neighbours, 30, np.array([0.0, 0.0, -1.0]), 0.0)
    assert (cell, face) == (0, FACE_BOTTOM)


@pytest.mark.parametrize("method", [METHOD_RK4, METHOD_DOPRI5], ids=["rk4", "dopri5"])
def test_one_step_is_exact_for_constant_grad_n2(method):
    """n^2 = n0^2 + a z: x(sigma) = x0 + p0 sigma + g sigma^2/4, t = (n0^2 s + g.p0 s^2/2 + |g|^2 s^3/12)/c_ref
    (docs/physics.md §2) is polynomial, so RK4 and DOPRI5 reproduce it to rounding in one long step."""
    profile = LinearN2(n0=1.0, alpha=0.01)
    med = make_media("exact", exact_spec=exact_media_spec(profile), c_ref=C_REF)
    x0 = np.array([1.0, 2.0, 30.0])
    d0 = np.array([0.6, 0.0, 0.8])
    n0 = math.sqrt(1.0 + 0.01 * 30.0)
    y0 = np.concatenate([x0, n0 * d0, [0.0, 0.0]])
    k1 = np.empty(NY)
    assert rhs(med, 0, y0, k1)
    y1 = np.empty(NY)
    yerr = np.empty(NY)
    work = np.empty((WORK_ROWS, NY))
    sig = 80.0
    assert rk_step(method, med, 0, y0, k1, sig, y1, yerr, work)
    g = np.array([0.0, 0.0, 0.01])
    p0 = n0 * d0
    np.testing.assert_allclose(y1[:3], x0 + p0 * sig + g * sig**2 / 4, rtol=1e-14, atol=1e-12)
    np.testing.assert_allclose(y1[3:6], p0 + g * sig / 2, rtol=1e-14, atol=1e-14)
    t_ref = (n0**2 * sig + g @ p0 * sig**2 / 2 + g @ g * sig**3 / 12) / C_REF
    assert y1[6] == pytest.approx(t_ref, rel=1e-14)


# ------------------------------------------------------------------------------------------------
# homogeneous air: straight rays and image sources
# ------------------------------------------------------------------------------------------------
def _mirror(source, direction, distance):
    """Straight ray unfolded by mirroring in the ground z = 0: end position and reflection count."""
    p = source + distance * direction
    if p[2] < 0:
        return p * np.array([1.0, 1.0, -1.0]), 1
    return p, 0


@pytest.mark.parametrize("media", ["exact", "mesh"])
@pytest.mark.parametrize("method", NUMERICAL_METHODS)
def test_straight_rays_and_ground_images_for_every_method(method, media):
    c0 = 330.0  # n = 340/330 != 1: exercises the sigma scaling
    profile = Homogeneous(c0=c0)
    el = np.linspace(-45.0, 45.0, 19)
    o, d = _fan(el)
    if media == "exact":
        kw = {"exact_spec": exact_media_spec(profile)}
    else:
        kw = {
            "mesh": build_slab_mesh(LO, HI, np.array([0.0, 100.0, 2600.0]), lambda z: np.full_like(z, c0)),
            "quantity": "c",
        }
    r, restarts = trace_numerical(
        method,
        media,
        origins=o,
        directions=d,
        max_time_s=T_END,
        step_m=7.0,
        tolerance=1e-9,
        domain_min=LO,
        domain_max=HI,
        **kw,
    )
    assert np.all(r.status == STATUS_TIME_LIMIT)
    assert np.all(r.time_s == T_END)
    for i in range(len(el)):
        ref, refl = _mirror(SOURCE, d[i], c0 * T_END)
        assert np.linalg.norm(r.position[i] - ref) / (c0 * T_END) < 1e-9, (i, r.position[i], ref)
        assert r.reflections[i] == refl
    np.testing.assert_allclose(r.length_m, c0 * T_END, rtol=1e-12)
    # straight rays land with at most one restart per event (time limit + each reflection; none when a
    # step happens to end on the event)
    assert np.all(restarts <= 1 + r.reflections) and np.all(restarts >= r.reflections)


def test_reflecting_top_open_sides_and_limits():
    profile = Homogeneous()
    up = trace_numerical(
        "rk4",
        "exact",
        exact_spec=exact_media_spec(profile),
        origins=[[0, 0, 10.0]],
        directions=[[0, 0, 1.0]],
        max_time_s=2.0,
        step_m=3.0,
        domain_min=[-100, -100, 0],
        domain_max=[1000, 100, 500],
        top="reflect",
    )[0]
    # up 490 m, down 500 m, up 10 m ... 680 m in 2 s: 490 + 190 -> z = 310 going down, one reflection
    np.testing.assert_allclose(up.position[0], [0, 0, 310.0], atol=1e-9)
    assert up.reflections[0] == 1 and up.status[0] == STATUS_TIME_LIMIT
    np.testing.assert_allclose(up.direction[0], [0, 0, -1.0], atol=1e-15)
    side = trace_numerical(
        "dopri5",
        "exact",
        exact_spec=exact_media_spec(profile),
        origins=[[0, 0, 10.0]],
        directions=[[1.0, 0, 0]],
        max_time_s=10.0,
        domain_min=[-100, -100, 0],
        domain_max=[1000, 100, 500],
    )[0]
    assert side.status[0] == STATUS_EXITED
    np.testing.assert_allclose(side.position[0], [1000.0, 0.0, 10.0], atol=1e-9)
    assert side.time_s[0] == pytest.approx(1000.0 / 340.0, rel=1e-12)
    kw = {
        "exact_spec": exact_media_spec(profile),
        "origins": [[0, 0, 10.0]],
        "directions": [[1.0, 0, -1.0]],
        "max_time_s": 1.0,
        "domain_min": LO,
        "domain_max": HI,
    }
    stop = trace_numerical("euler", "exact", max_reflections=0, **kw)[0]
    assert stop.status[0] == STATUS_REFLECTION_LIMIT and stop.reflections[0] == 0
    np.testing.assert_allclose(stop.position[0], [10.0, 0.0, 0.0], atol=1e-12)  # stops on the ground
    capped = trace_numerical("euler", "exact", max_steps=5, step_m=1.0, **kw)[0]
    assert capped.status[0] == STATUS_STEP_LIMIT and capped.steps[0] == 5


# ------------------------------------------------------------------------------------------------
# orders of accuracy
# ------------------------------------------------------------------------------------------------
def _circle_reference(c0, alpha, x0, elevation, t_end):
    """Closed-form ray in c = c0 + alpha z (alpha > 0) over a reflecting ground z = 0: an arc of the circle
    centred on the plane c = 0 with radius R = c(z0) / (alpha cos(elevation)); with beta the local
    elevation, t = (gd^-1(beta0) - gd^-1(beta)) / alpha, gd^-1 = asinh(tan)."""
    z_c = -c0 / alpha
    beta = elevation
    big_r = (c0 + alpha * x0[2]) / (alpha * math.cos(beta))
    r_c = big_r * math.sin(beta)
    t_left = t_end
    while True:
        beta_hit = -math.acos(-z_c / big_r)  # where the circle meets z = 0, descending
        t_hit = (math.asinh(math.tan(beta)) - math.asinh(math.tan(beta_hit))) / alpha
        if t_hit >= t_left:
            beta_end = math.atan(math.sinh(math.asinh(math.tan(beta)) - alpha * t_left))
            return np.array([r_c - big_r * math.sin(beta_end), 0.0, z_c + big_r * math.cos(beta_end)])
        t_left -= t_hit
        r_hit = r_c - big_r * math.sin(beta_hit)
        beta = -beta_hit
        r_c = r_hit + big_r * math.sin(beta)


@pytest.fixture(scope="module")
def circle_refs():
    return np.array([_circle_reference(340.0, 0.1, SOURCE, math.radians(e), T_END) for e in ELEVATIONS])


@pytest.fixture(scope="module")
def ald_refs():
    n_of, g_of = log_profile(b=1.0)
    _, d = _fan(ELEVATIONS)
    return np.array([integrate_ray(n_of, g_of, SOURCE, di, T_END).position for di in d])


CASES = {  # profile, reference fixture, Euler steps, RK4 steps (metres)
    "linear_c": (LinearC(), "circle_refs", (4.0, 2.0, 1.0), (100.0, 50.0, 25.0)),
    "A-LD": (Log(b=1.0), "ald_refs", (1.0, 0.5, 0.25), (1.0, 0.5, 0.25)),
}


@pytest.mark.parametrize("case", list(CASES))
def test_fixed_step_orders(case, request):
    profile, ref_name, euler_steps, rk4_steps = CASES[case]
    ref = request.getfixturevalue(ref_name)
    for method, steps, band in (("euler", euler_steps, (0.8, 1.4)), ("rk4", rk4_steps, (3.5, 4.5))):
        errors = []
        for h in steps:
            r, _ = _run(method, profile, step_m=h)
            assert np.all(r.status == STATUS_TIME_LIMIT)
            errors.append(np.max(np.linalg.norm(r.position - ref, axis=1)) / PATH)
        orders = _order(errors)
        assert all(band[0] < q < band[1] for q in orders), (method, errors, orders)
    assert errors[-1] < 1e-8  # RK4 at the finest step


@pytest.mark.parametrize("case", list(CASES))
def test_dopri5_error_tracks_its_tolerance(case, request):
    """Tolerance = local error per step (m): the global error falls ~tol^(0.75..1) and stays within
    [0.1, 3000] tolerances (metres) over the 3.4 km path."""
    profile, ref_name, _, _ = CASES[case]
    ref = request.getfixturevalue(ref_name)
    tols = (1e-6, 1e-8, 1e-10)
    errors = []
    for tol in tols:
        r, _ = _run("dopri5", profile, tolerance=tol)
        assert np.all(r.status == STATUS_TIME_LIMIT)
        errors.append(np.max(np.linalg.norm(r.position - ref, axis=1)))
    slopes = _order(errors, ratio=100.0)
    assert all(0.6 < q < 1.3 for q in slopes), (errors, slopes)
    assert all(0.1 * t < e < 3000 * t for e, t in zip(errors, tols, strict=True)), errors


def test_step_doubling_euler_converges_with_its_tolerance(circle_refs):
    errors = [
        np.max(np.linalg.norm(_run("euler_adaptive", LinearC(), tolerance=tol)[0].position - circle_refs, axis=1))
        / PATH
        for tol in (1e-4, 1e-6)
    ]
    # local error ~h^2 controlled per step: the global error falls ~tol^(1/2)
    assert 0.35 < _order(errors, ratio=100.0)[0] < 0.65, errors


# ------------------------------------------------------------------------------------------------
# mesh media: the same media as the analytic tracer
# ------------------------------------------------------------------------------------------------
def test_mesh_media_agree_with_the_analytic_tracer_on_slabs():
    media = build_media(Log(b=1.0), "parabolic", Solver(delta=1e-6), LO, HI)
    o, d = _fan(ELEVATIONS)
    cells = media.locate(o)
    ref = trace(media.mesh, "parabolic", C_REF, o, d, cells, max_time_s=T_END, max_reflections=50)
    errors = []
    for tol in (1e-10, 1e-12):
        r, _ = trace_numerical(
            "dopri5",
            "mesh",
            mesh=media.mesh,
            quantity=media.quantity,
            origins=o,
            directions=d,
            start_cells=cells,
            max_time_s=T_END,
            tolerance=tol,
            domain_min=LO,
            domain_max=HI,
        )
        assert np.array_equal(r.reflections, ref.reflections) and np.all(r.status == STATUS_TIME_LIMIT)
        assert np.array_equal(r.crossings, ref.crossings)  # the walk crosses the same slabs
        errors.append(np.max(np.linalg.norm(r.position - ref.position, axis=1)) / PATH)
    # the piecewise-linear media has a gradient jump at every face: DOPRI5 converges ~tol there
    assert errors[1] < 2e-8 and errors[1] < errors[0] / 30, errors


def test_mesh_boundary_faces_and_exact_linear_tets():
    """A linear n^2 on Delaunay tets: the mesh is exact, RK4 is exact for it, so RK4 with 20 m steps must
    reproduce the analytic parabolic traversal; the explicit ground and box are moved away so that only
    the mesh's own faces reflect (ground) and exit (sides, top)."""
    lo, hi, d = np.array([0.0, 0.0, 0.0]), np.array([200.0, 160.0, 120.0]), 18.0
    pts = fcc_resample(lo, hi, lambda x: np.full(len(x), d), d_min=d, d_max=d)
    tm = build_tet_mesh(lo, hi, pts, lambda x: 1.0 + 0.01 * x[:, 2], spacing=lambda x: np.full(len(x), d))
    el, az = np.meshgrid(np.radians(np.linspace(-60, 60, 7)), np.radians(np.linspace(-80, 80, 5)))
    dirs = np.column_stack(
        [np.cos(el.ravel()) * np.cos(az.ravel()), np.cos(el.ravel()) * np.sin(az.ravel()), np.sin(el.ravel())]
    )
    o = np.tile([60.0, 70.0, 30.0], (len(dirs), 1))
    cells = locate_points(tm.cells, o)
    ref = trace(tm.cells, "parabolic", C_REF, o, dirs, cells, max_time_s=0.5, max_reflections=10)
    r, _ = trace_numerical(
        "rk4",
        "mesh",
        mesh=tm.cells,
        quantity="n2",
        origins=o,
        directions=dirs,
        max_time_s=0.5,
        step_m=20.0,
        domain_min=lo - 1000,
        domain_max=hi + 1000,
        ground_z=-500.0,
    )
    assert set(np.unique(r.status)) == {STATUS_TIME_LIMIT, STATUS_EXITED}
    np.testing.assert_array_equal(r.status, ref.status)
    np.testing.assert_array_equal(r.reflections, ref.reflections)
    assert r.reflections.sum() > 5
    np.testing.assert_allclose(r.position, ref.position, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r.time_s, ref.time_s, rtol=1e-13)


# ------------------------------------------------------------------------------------------------
# every ray ends with a status
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", NUMERICAL_METHODS)
def test_zero_and_100x_gradients(method):
    el = np.linspace(-45.0, 45.0, 15)
    src = np.array([0.0, 0.0, 10.0])
    tol = 1e-5 if method == "euler_adaptive" else 1e-10
    for profile in (Homogeneous(), LinearC(alpha=10.0), Log(b=100.0)):
        r, _ = _run(method, profile, el, src, max_time_s=1.0, max_reflections=10_000, step_m=0.25, tolerance=tol)
        assert np.all(r.status == STATUS_TIME_LIMIT), profile.kind
        assert np.all(np.isfinite(r.position)) and np.all(r.position[:, 2] >= 0.0)
        if profile.kind == "linear_c" and method in ("rk4", "dopri5"):  # 100x: circles of ~34 m radius
            ref = np.array([_circle_reference(340.0, 10.0, src, math.radians(e), 1.0) for e in el])
            assert np.max(np.linalg.norm(r.position - ref, axis=1)) / 340.0 < 1e-6
            assert r.reflections.max() >= 5


@pytest.mark.parametrize("method", NUMERICAL_METHODS)
def test_grazing_launch_on_the_ground(method):
    """Sources on the ground, elevations 0 and +-1e-3 degrees. Upward refraction (A-LU) lifts them off;
    downward refraction (A-LD) presses them onto the ground (sliding or many tiny bounces): any end
    state, but finite, never below ground, never lost."""
    el = np.array([-1e-3, 0.0, 1e-3])
    tol = 1e-6 if method == "euler_adaptive" else 1e-9
    for b in (-1.0, 1.0):
        r, _ = _run(method, Log(b=b), el, np.zeros(3), max_reflections=100, step_m=1.0, tolerance=tol)
        assert np.all(np.isfinite(r.position)) and np.all(r.position[:, 2] >= 0.0)
        assert not np.any(r.status == STATUS_LOST)
        if b < 0:
            assert np.all(r.status == STATUS_TIME_LIMIT) and np.all(r.position[:, 2] > 100.0)
        else:
            assert set(np.unique(r.status)) <= {STATUS_TIME_LIMIT, STATUS_REFLECTION_LIMIT}


def test_lost_rays_are_reported():
    # c = 340 - z is negative above 340 m: a source there is unphysical
    r, _ = _run("rk4", LinearC(alpha=-1.0), [0.0, 10.0], np.array([0.0, 0.0, 400.0]))
    assert np.all(r.status == STATUS_LOST) and np.all(np.isfinite(r.position))
    # fixed 1 m steps up toward the c = 0 plane (never reached in finite time) overshoot into c < 0:
    # lost (n <= 0 at a stage), with a finite last state, not NaN
    r, _ = _run("rk4", LinearC(alpha=-1.0), [90.0], np.array([0.0, 0.0, 300.0]), step_m=1.0)
    assert r.status[0] == STATUS_LOST and np.all(np.isfinite(r.position)) and 330.0 < r.position[0, 2] < 340.0
    # mesh media: a start cell of -1 (origin outside the mesh), and an origin outside the domain
    mesh = build_slab_mesh(LO, HI, np.array([0.0, 2600.0]), lambda z: np.ones_like(z))
    r, _ = trace_numerical(
        "euler",
        "mesh",
        mesh=mesh,
        origins=[[0, 0, 1.0], [0, 0, 1.0]],
        directions=[[1, 0, 0], [1, 0, 0]],
        start_cells=[-1, 0],
        max_time_s=1.0,
        domain_min=LO,
        domain_max=HI,
    )
    assert list(r.status) == [STATUS_LOST, STATUS_TIME_LIMIT]
    r, _ = _run("euler", Homogeneous(), [0.0], np.array([0.0, 0.0, -1.0]))
    assert r.status[0] == STATUS_LOST
    assert set(STATUS_NAMES) >= set(np.unique(r.status))


def test_paths_follow_the_rays():
    r, _ = _run("dopri5", Homogeneous(), [-30.0, 20.0], path_samples=40, tolerance=1e-9)
    paths = r.paths
    assert paths is not None and paths.offsets[0] == 0 and paths.offsets[-1] == len(paths.points)
    for i, e in enumerate([-30.0, 20.0]):
        sl = slice(paths.offsets[i], paths.offsets[i + 1])
        pts, t = paths.points[sl], paths.time_s[sl]
        assert len(pts) >= 40 and np.all(np.diff(t) > 0) and t[-1] == T_END
        np.testing.assert_allclose(pts[0], SOURCE, atol=0)
        np.testing.assert_allclose(pts[-1], r.position[i], atol=0)
        np.testing.assert_allclose(paths.length_m[sl], 340.0 * t, rtol=1e-12, atol=1e-9)
        d = np.array([math.cos(math.radians(e)), 0.0, math.sin(math.radians(e))])
        unfolded = np.array([_mirror(SOURCE, d, 340.0 * tt)[0] for tt in t])
        np.testing.assert_allclose(pts, unfolded, atol=1e-9)  # Hermite samples lie on the straight ray
        assert (e < 0) == np.any(pts[:, 2] == 0.0)  # the reflection point is a sample


def test_input_errors():
    spec = exact_media_spec(Homogeneous())
    base = {"origins": [SOURCE], "directions": [[1, 0, 0]], "max_time_s": 1.0, "domain_min": LO, "domain_max": HI}
    with pytest.raises(ValueError, match="unknown method"):
        trace_numerical("rk45", "exact", exact_spec=spec, **base)
    with pytest.raises(ValueError, match="media must be"):
        trace_numerical("rk4", "grid", exact_spec=spec, **base)
    with pytest.raises(ValueError, match="exact_spec"):
        trace_numerical("rk4", "exact", **base)
    with pytest.raises(ValueError, match="c_ref"):
        trace_numerical("rk4", "exact", exact_spec=spec, c_ref=343.0, **base)
    with pytest.raises(ValueError, match="top"):
        trace_numerical("rk4", "exact", exact_spec=spec, top="lid", **base)

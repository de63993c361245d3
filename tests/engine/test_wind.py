"""Wind through the effective sound speed c_eff = c + u(x) . e (engine/wind.py, the kernel seam).

References, all independent of the engine's wind code:
- the log law and the ridge speed-up written out again here (scalar Python) with hand-derived derivatives;
- central finite differences of the kernel's own values for its exact gradients;
- scipy DOP853 at rtol 1e-12 (tests/reference/ray_ode.py) on the effective medium for each ray azimuth.
Tolerances are stated where used; positions are compared relative to the path length c0 T.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

import bentray  # noqa: F401
from bentray.engine.constants import (
    BOUNDARY_OPEN,
    BOUNDARY_REFLECT,
    CURVE_CODES,
    STATUS_LOST,
    STATUS_REFLECTION_LIMIT,
    STATUS_TIME_LIMIT,
)
from bentray.engine.field_buffers import FieldBuffers, FieldGrid
from bentray.engine.mesh.cells import CellMesh, validate_cell_mesh
from bentray.engine.mesh.sizing import curvature_layers
from bentray.engine.mesh.slabs import build_slab_mesh, locate_in_slabs
from bentray.engine.tracer import trace
from bentray.engine.wind import (
    WIND_LOG,
    WIND_NONE,
    WIND_RIDGE,
    effective_quantity,
    effective_value,
    max_wind_speed,
    no_wind,
    sizing_quantity,
    wind_along,
    wind_at,
    wind_spec,
    wind_values,
)
from bentray.scenes.library.ridge import RIDGE_WIND
from bentray.scenes.wind_models import WIND_SPEC_ADAPTER, RidgeWindSpec, wind_from_spec
from tests.reference.ray_ode import integrate_ray

K = 0.41
C0 = 340.0
C_REF = 340.0
U_STAR = 0.5
Z_G = 0.1
H, L = 40.0, 200.0  # the library ridge
A = U_STAR / K
U_REF = A * math.log(10.0 / Z_G)  # log-law speed at the default reference height, 10 m
LOG = {"u_star": U_STAR, "z_g": Z_G, "direction_deg": 0.0}
RIDGE = {**LOG, "height_m": H, "half_width_m": L}


# --- the wind written out independently (scalar), with hand-derived derivatives ---------------------
def _log_speed(dz: float) -> tuple[float, float]:
    """(|u|, d|u|/dz) of the log law: (u*/K) ln(dz/z_g) above z_g, 0 below."""
    return (A * math.log(dz / Z_G), A / dz) if dz > Z_G else (0.0, 0.0)


def _ridge_speed(x: float, z: float) -> tuple[float, float, float]:
    """(|u|, d|u|/dx, d|u|/dz) of log law + speed-up over h(x) = H L^2/(x^2 + L^2), linear ramp below z_g."""
    h = H * L * L / (x * x + L * L)
    hx = -2.0 * H * L * L * x / (x * x + L * L) ** 2
    dz = z - h

    def du(zz: float) -> tuple[float, float, float]:  # value, d/dx at fixed height, d/d(height)
        p = zz + L
        q = x * x + p * p
        return (
            U_REF * H * L * (p * p - x * x) / q**2,
            U_REF * H * L * (-2.0 * x * q - 4.0 * x * (p * p - x * x)) / q**3,
            U_REF * H * L * (2.0 * p * q - 4.0 * p * (p * p - x * x)) / q**3,
        )

    if dz > Z_G:
        s, sx, sz = du(dz)
        u, ud = A * math.log(dz / Z_G) + s, A / dz + sz
        return u, sx - hx * ud, ud
    if dz > 0.0:
        s, sx, _ = du(Z_G)
        return s * dz / Z_G, sx * dz / Z_G - hx * s / Z_G, s / Z_G
    return 0.0, 0.0, 0.0


def _oracle_log(cos_angle: float):
    """n = c_ref / (c0 + |u| cos) and grad n for the log-law wind seen along an azimuth."""

    def n_of(p):
        return C_REF / (C0 + cos_angle * _log_speed(p[2])[0])

    def grad_n_of(p):
        u, uz = _log_speed(p[2])
        c = C0 + cos_angle * u
        return np.array([0.0, 0.0, -C_REF * cos_angle * uz / (c * c)])

    return n_of, grad_n_of


def _oracle_ridge(cos_angle: float):
    def n_of(p):
        return C_REF / (C0 + cos_angle * _ridge_speed(p[0], p[2])[0])

    def grad_n_of(p):
        u, ux, uz = _ridge_speed(p[0], p[2])
        c = C0 + cos_angle * u
        return -C_REF * cos_angle * np.array([ux, 0.0, uz]) / (c * c)

    return n_of, grad_n_of


# --- builders and field values ---------------------------------------------------------------------
def test_wind_spec_layout_and_validation():
    code, p = wind_spec("ridge", RIDGE)
    assert code == WIND_RIDGE and p.dtype == np.float64 and p.shape == (10,)
    np.testing.assert_allclose(p[[0, 1, 5, 6, 8, 9]], [A, Z_G, H, L, U_REF, 10.0], rtol=1e-15)
    code, p = wind_spec("log", {**LOG, "direction_deg": 90.0})
    assert code == WIND_LOG and p[2] == 0.0 and p[3] == 1.0  # cardinal directions are exact
    assert no_wind()[0] == WIND_NONE and no_wind()[1].shape == (0,)
    for kind, params, match in [
        ("gust", LOG, "unknown kind"),
        ("log", {**LOG, "u_star": 0.0}, "u_star"),
        ("log", {**LOG, "u_star": 6.0}, "u_star"),
        ("log", {**LOG, "z_g": -1.0}, "z_g"),
        ("log", {**LOG, "height_m": 1.0}, "unknown parameter"),
        ("log", {"u_star": 0.5, "z_g": 0.1}, "direction_deg"),
        ("ridge", {**RIDGE, "z_ref_m": 0.05}, "z_ref_m"),
        ("ridge", {**RIDGE, "half_width_m": 0.0}, "half_width_m"),
        ("log", {**LOG, "direction_deg": math.nan}, "finite"),
    ]:
        with pytest.raises(ValueError, match=match):
            wind_spec(kind, params)


def test_schema_models_match_builders():
    assert np.array_equal(wind_from_spec(RIDGE_WIND)[1], wind_spec("ridge", RIDGE)[1])
    spec = WIND_SPEC_ADAPTER.validate_python({**LOG, "kind": "log", "direction_deg": 30.0})
    assert np.array_equal(wind_from_spec(spec)[1], wind_spec("log", {**LOG, "direction_deg": 30.0})[1])
    assert isinstance(WIND_SPEC_ADAPTER.validate_python(RIDGE_WIND), RidgeWindSpec)
    for bad in [
        {**LOG, "kind": "log", "extra": 1},
        {**LOG, "kind": "log", "u_star": float("nan")},
        {**LOG, "kind": "log", "u_star": 5.5},
        {**RIDGE, "kind": "ridge", "z_ref_m": 0.1},
        {"kind": "log", "u_star": 0.5, "z_g": 0.1},
    ]:
        with pytest.raises(ValidationError):
            WIND_SPEC_ADAPTER.validate_python(bad)


def test_crest_speed_up_and_log_law_values():
    code, p = wind_spec("ridge", RIDGE)
    # crest, just above the surface: du -> u_ref H / L (docs/physics.md §7), plus the log term
    dz = 1e-6 + Z_G
    u = wind_speed_at(code, p, 0.0, H + dz)
    assert u == pytest.approx(A * math.log(dz / Z_G) + U_REF * H * L / (dz + L) ** 2, rel=1e-13)
    # ... the speed-up there is u_ref H/L (1 - 2 dz/L + O(dz^2)): the crest value of the formula
    assert u - A * math.log(dz / Z_G) == pytest.approx(U_REF * H / L, rel=2.0 * dz / L)
    assert u - A * math.log(dz / Z_G) < U_REF * H / L
    # at x = +-L the speed-up changes sign at the surface: ((dz + L)^2 - L^2) is ~ 2 L dz
    hl = H / 2.0
    for z in (hl + 5.0, hl + 50.0):
        d = z - hl
        ref = A * math.log(d / Z_G) + U_REF * H * L * ((d + L) ** 2 - L**2) / (L**2 + (d + L) ** 2) ** 2
        assert wind_speed_at(code, p, L, z) == pytest.approx(ref, rel=1e-13)
    # the log law over flat ground, with its ground offset
    code, p = wind_spec("log", {**LOG, "ground_z_m": 3.0})
    assert wind_speed_at(code, p, 123.0, 13.0) == pytest.approx(A * math.log(10.0 / Z_G), rel=1e-14)
    assert wind_speed_at(code, p, 0.0, 3.05) == 0.0 and wind_speed_at(code, p, 0.0, 1.0) == 0.0  # at or below z_g


def wind_speed_at(code: int, p: np.ndarray, x: float, z: float) -> float:
    """|u| through the kernel function (e along the wind)."""
    return wind_at(code, p, np.array([x, 0.0, z]), np.array([p[2], p[3], 0.0]), np.empty(3))


def _points(rng: np.random.Generator, n: int) -> np.ndarray:
    x = rng.uniform(-3.0 * L, 3.0 * L, n)
    h = H * L * L / (x * x + L * L)
    dz = np.concatenate([rng.uniform(0.005, 0.095, n // 4), 10.0 ** rng.uniform(-0.9, 2.5, n - n // 4)])
    return np.column_stack([x, rng.uniform(-50.0, 50.0, n), h + dz])


@pytest.mark.parametrize("kind", ["log", "ridge"])
def test_kernel_values_and_gradients(kind):
    """Values vs the scalar re-implementation and vs the numpy version (1e-12); exact gradients vs central
    differences (step 1e-6 m, error ~ u''' h^2 + rounding: 1e-6 relative to |grad| + 1e-7 1/s)."""
    rng = np.random.default_rng(7)
    az = 0.7
    e = np.array([math.cos(az), math.sin(az), 0.0])
    code, p = wind_spec(kind, {**(LOG if kind == "log" else RIDGE), "direction_deg": 20.0})
    cos_a = math.cos(az - math.radians(20.0))
    pts = _points(rng, 400)
    if kind == "log":
        pts[:, 2] -= H * L * L / (pts[:, 0] ** 2 + L * L)  # heights above flat ground
    g = np.empty(3)
    numpy_w = wind_along(code, p, pts, e)
    for i, x in enumerate(pts):
        w = wind_at(code, p, x, e, g)
        ref = _log_speed(x[2]) if kind == "log" else _ridge_speed(x[0], x[2])
        u_ref, grad_ref = ref[0], ([0.0, ref[1]] if kind == "log" else list(ref[1:]))
        assert w == pytest.approx(cos_a * u_ref, rel=1e-12, abs=1e-13)
        assert numpy_w[i] == pytest.approx(w, rel=1e-12, abs=1e-13)
        np.testing.assert_allclose(g[[0, 2]], cos_a * np.array(grad_ref), rtol=1e-10, atol=1e-12)
        assert g[1] == 0.0
        fd = np.empty(3)
        step = 1e-6
        for a in range(3):
            xp, xm = x.copy(), x.copy()
            xp[a] += step
            xm[a] -= step
            fd[a] = (wind_at(code, p, xp, e, np.empty(3)) - wind_at(code, p, xm, e, np.empty(3))) / (2 * step)
        np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-7)
    assert np.all(max_wind_speed(code, p, pts) >= np.abs(numpy_w) - 1e-12)


@pytest.mark.parametrize("curve", list(CURVE_CODES))
def test_effective_quantity_conversions(curve):
    """m_eff = q(c + w) with q the curve's quantity, and its gradient vs central differences of the
    composite medium c(x) = linear + wind (the cell's model plus the wind at x)."""
    code, p = wind_spec("ridge", {**RIDGE, "direction_deg": 180.0})
    e = np.array([-0.6, 0.8, 0.0])
    gc = np.array([0.01, -0.02, 0.05])  # grad c of the cell (1/s)
    q = {"parabolic": lambda c: (C_REF / c) ** 2, "circular": lambda c: c, "n_linear": lambda c: C_REF / c}[curve]
    dq_dc = {
        "parabolic": lambda c: -2.0 * C_REF**2 / c**3,
        "circular": lambda c: 1.0,
        "n_linear": lambda c: -C_REF / c**2,
    }[curve]

    def m_eff(x):
        c = 330.0 + gc @ x
        return q(c + wind_along(code, p, x[None, :], e)[0])

    c_code = CURVE_CODES[curve]
    for x in (np.array([30.0, 5.0, 45.0]), np.array([-250.0, 1.0, 60.0]), np.array([10.0, 0.0, 39.97])):
        c = 330.0 + gc @ x
        step = 1e-5
        g_out = np.empty(3)
        m = effective_quantity(c_code, C_REF, q(c), dq_dc(c) * gc, code, p, x, e, np.empty(3), g_out)
        assert m == pytest.approx(m_eff(x), rel=1e-13)
        fd = np.array([(m_eff(x + step * u) - m_eff(x - step * u)) / (2 * step) for u in np.eye(3)])
        np.testing.assert_allclose(g_out, fd, rtol=1e-6, atol=1e-9 * abs(m))
    # c_eff <= 0 (a 400 m/s headwind on 340 m/s air) is refused: the ray would end as lost
    fast = wind_spec("log", {"u_star": 5.0, "z_g": 1e-30, "direction_deg": 0.0})
    m = effective_quantity(
        c_code,
        C_REF,
        q(340.0),
        np.zeros(3),
        *fast,
        np.array([0.0, 0.0, 100.0]),
        np.array([-1.0, 0.0, 0.0]),
        np.empty(3),
        np.empty(3),
    )
    assert not m > 0.0


STORM = np.array([400.0, 1e-30, 1.0, 0.0, -1.0])  # log-law parameters of a 400 m/s wind: c_eff <= 0 upwind


@pytest.mark.parametrize("curve", list(CURVE_CODES))
@pytest.mark.parametrize("kind", ["none", "log", "ridge", "storm"])
def test_effective_value_on_tuples_is_effective_quantity(curve, kind):
    """The traversal's per-crossing form (wind.effective_value on wind.wind_values' tuple and 3-tuples) gives
    effective_quantity's numbers bit for bit, and computes g_eff exactly where effective_quantity writes it:
    not for m <= 0 (returned as is) nor for c_eff <= 0 (-1.0)."""
    if kind == "none":
        code, p = no_wind()
    elif kind == "storm":
        code, p = WIND_LOG, STORM
    else:
        code, p = wind_spec(kind, {**(RIDGE if kind == "ridge" else LOG), "direction_deg": 30.0})
    wp = wind_values(p)
    assert len(wp) == 10 and list(wp[: p.size]) == list(p) and not any(wp[p.size :])
    c_code = CURVE_CODES[curve]
    rng = np.random.default_rng(5)
    states = set()
    for _ in range(300):
        x = rng.uniform([-600.0, -50.0, -1.0], [600.0, 50.0, 120.0])
        az = rng.uniform(0.0, 2.0 * math.pi)
        e = np.array([math.cos(az), math.sin(az), 0.0])
        g = rng.normal(0.0, 0.01, 3)
        m = float(rng.choice([rng.uniform(0.5, 1.5), 0.0, -0.2]))
        w_grad = np.full(3, 7.0)  # a sentinel: what effective_quantity leaves untouched keeps it
        g_out = np.full(3, 7.0)
        m_ref = effective_quantity(c_code, C_REF, m, g, code, p, x, e, w_grad, g_out)
        m_val, state, g0, g1, g2, _, wg0, wg1, wg2 = effective_value(
            c_code, C_REF, m, (g[0], g[1], g[2]), code, wp, (x[0], x[1], x[2]), (e[0], e[1], e[2])
        )
        states.add(state)
        assert m_val == m_ref
        assert (state == 1) == (not np.array_equal(g_out, np.full(3, 7.0)))
        if state == 1:
            assert [g0, g1, g2] == list(g_out)
        if state != 0:
            assert [wg0, wg1, wg2] == list(w_grad)
        else:
            assert np.array_equal(w_grad, np.full(3, 7.0))
    assert {0, 1} <= states and (kind != "storm" or -1 in states)


def test_sizing_quantity_is_the_downwind_medium():
    code, p = wind_spec("log", {**LOG, "direction_deg": 123.0})
    pts = np.column_stack([np.zeros(5), np.zeros(5), [0.05, 0.5, 2.0, 20.0, 200.0]])
    speed = np.array([_log_speed(z)[0] for z in pts[:, 2]])
    for quantity, q in [("c", lambda c: c), ("n", lambda c: C_REF / c), ("n2", lambda c: (C_REF / c) ** 2)]:
        m = sizing_quantity(lambda x: np.full(len(x), C0), C_REF, (code, p), quantity)(pts)
        np.testing.assert_allclose(m, q(C0 + speed), rtol=1e-14)
    m = sizing_quantity(lambda x: np.full(len(x), C0), C_REF, None, "n2")(pts)
    np.testing.assert_array_equal(m, np.ones(5))


# --- log-law wind over flat ground: slabs sized on the downwind medium vs DOP853 ---------------------
LO = np.array([-2000.0, -2000.0, 0.0])
HI = np.array([2000.0, 2000.0, 2000.0])
SOURCE = np.array([0.0, 0.0, 1.5])
T_END = 5.0
ELEVATIONS = np.radians([-10.0, -2.0, 0.0, 2.0, 10.0])
LOG_TOL = 1e-5  # measured (delta 1e-8): parabolic 5e-7, circular 1.7e-6, n_linear 2.1e-6
_REF: dict = {}


def _slab_mesh(curve: str, wind, delta: float = 1e-8):
    quantity = {"parabolic": "n2", "circular": "c", "n_linear": "n"}[curve]
    m_q = sizing_quantity(lambda x: np.full(len(x), C0), C_REF, wind, quantity)
    z = curvature_layers(
        LO[2], HI[2], lambda zz: m_q(np.column_stack([0 * zz, 0 * zz, zz])), delta=delta, d_min=1e-5, d_max=HI[2]
    )
    base = C0 if quantity == "c" else 1.0  # homogeneous air: the mesh carries c alone
    return build_slab_mesh(LO, HI, z, lambda zz: np.full(len(zz), base)), z


def _fan(azimuth_deg: float) -> tuple[np.ndarray, np.ndarray]:
    az = math.radians(azimuth_deg)
    ca, sa = {0.0: (1.0, 0.0), 180.0: (-1.0, 0.0), 90.0: (0.0, 1.0)}.get(azimuth_deg, (math.cos(az), math.sin(az)))
    d = np.column_stack([np.cos(ELEVATIONS) * ca, np.cos(ELEVATIONS) * sa, np.sin(ELEVATIONS)])
    return np.tile(SOURCE, (len(d), 1)), d


def _log_reference(azimuth_deg: float) -> list:
    if azimuth_deg not in _REF:
        n_of, g_of = _oracle_log(math.cos(math.radians(azimuth_deg)))
        _, d = _fan(azimuth_deg)
        _REF[azimuth_deg] = [integrate_ray(n_of, g_of, SOURCE, di, T_END, c_ref=C_REF) for di in d]
    return _REF[azimuth_deg]


@pytest.mark.parametrize("curve", list(CURVE_CODES))
def test_log_wind_downwind_upwind_oblique_match_dop853(curve):
    """c_eff(z) = c0 + (u*/K) ln(z/z_g) cos(angle): downwind (0), upwind (180) and oblique (30 degrees)."""
    wind = wind_spec("log", LOG)
    mesh, z = _slab_mesh(curve, wind)
    ends = {}
    for azimuth in (0.0, 180.0, 30.0):
        o, d = _fan(azimuth)
        r = trace(mesh, curve, C_REF, o, d, locate_in_slabs(z, o), max_time_s=T_END, max_reflections=50, wind=wind)
        assert np.all(r.status == STATUS_TIME_LIMIT)
        for i, ref in enumerate(_log_reference(azimuth)):
            assert r.reflections[i] == ref.reflections
            err = np.linalg.norm(r.position[i] - ref.position) / (C0 * T_END)
            assert err < LOG_TOL, f"{curve} azimuth {azimuth} ray {i}: {err:.2e}"
        ends[azimuth] = r.position[:, 2]
    # wind increasing with height: downwind rays refract down (ducted near the ground), upwind rays up
    straight = SOURCE[2] + C0 * T_END * np.sin(ELEVATIONS[3:])
    assert np.all(ends[0.0][3:] < straight - 50.0) and np.all(ends[180.0][3:] > straight + 5.0)


def test_crosswind_and_windless_regions_equal_no_wind_bit_for_bit():
    """A ray across the wind (u . e = 0) and a wind that is 0 in the whole domain (z_g above its top)
    give exactly the no-wind result; so do wind=None and the explicit no_wind() arguments."""
    base, z = _slab_mesh("parabolic", None, delta=1e-6)
    o, d = _fan(0.0)
    d = np.vstack([d, [0.0, 0.0, 1.0]])  # a vertical ray has no azimuth: no wind
    o = np.vstack([o, SOURCE])
    cells = locate_in_slabs(z, o)
    kw = {"max_time_s": T_END, "max_reflections": 50, "path_samples": 40}
    ref = trace(base, "parabolic", C_REF, o, d, cells, **kw)
    for wind in (
        no_wind(),
        wind_spec("log", {**LOG, "direction_deg": 90.0}),
        wind_spec("ridge", {**RIDGE, "direction_deg": -90.0}),
        wind_spec("log", {**LOG, "z_g": 5000.0}),
    ):
        r = trace(base, "parabolic", C_REF, o, d, cells, wind=wind, **kw)
        for name in ("position", "direction", "time_s", "length_m", "reflections", "status", "crossings", "steps"):
            assert np.array_equal(getattr(r, name), getattr(ref, name)), name
        assert np.array_equal(r.paths.points, ref.paths.points) and np.array_equal(r.paths.time_s, ref.paths.time_s)
    # ... while the same wind along the rays changes them
    r = trace(base, "parabolic", C_REF, o, d, cells, wind=wind_spec("log", LOG), **kw)
    assert not np.array_equal(r.position[:-1], ref.position[:-1])
    assert np.array_equal(r.position[-1], ref.position[-1])


def test_field_energy_conserved_with_wind():
    """Incoherent deposit with wind: every segment deposits its exact travel time, so a grid holding
    the whole paths receives sum_i w_i T (relative 1e-12)."""
    wind = wind_spec("log", LOG)
    mesh, z = _slab_mesh("parabolic", wind, delta=1e-6)
    o, d = _fan(30.0)
    grid = FieldGrid(origin=np.array([-10.0, -10.0, 0.0]), spacing=np.array([10.0, 10.0, 5.0]), shape=(45, 30, 41))
    weights = np.linspace(1.0, 2.0, len(d))[:, None]
    buf = FieldBuffers(
        "incoherent",
        grid,
        weights,
        np.zeros(1),
        np.zeros(1, np.int64),
        np.ones((1, 1, 2, 2)),
        np.array([0.0, 1.0, 0.0, 1.0]),
        2.0,
        n_slots=2,
    )
    r = trace(
        mesh, "parabolic", C_REF, o, d, locate_in_slabs(z, o), max_time_s=1.0, max_reflections=50, field=buf, wind=wind
    )
    assert np.all(r.status == STATUS_TIME_LIMIT) and r.reflections.sum() >= 2
    assert buf.reduce().energy.sum() == pytest.approx(weights.sum() * 1.0, rel=1e-12)


# --- ridge: log law + speed-up, traced through a box grid over flat ground, vs DOP853 -----------------
def _box_grid(xs: np.ndarray, zs: np.ndarray, y_lo: float, y_hi: float, m_const: float) -> CellMesh:
    """Boxes spanning y (face order: bottom, top, x-, x+, y-, y+), reflecting ground, open elsewhere."""
    nx, nz = len(xs) - 1, len(zs) - 1
    n = nx * nz
    i, k = np.divmod(np.arange(n), nz)  # cell id i * nz + k
    one, zero = np.ones(n), np.zeros(n)
    planes = np.zeros((n, 6, 4))
    planes[:, 0] = np.column_stack([zero, zero, -one, -zs[k]])
    planes[:, 1] = np.column_stack([zero, zero, one, zs[k + 1]])
    planes[:, 2] = np.column_stack([-one, zero, zero, -xs[i]])
    planes[:, 3] = np.column_stack([one, zero, zero, xs[i + 1]])
    planes[:, 4] = [0.0, -1.0, 0.0, -y_lo]
    planes[:, 5] = [0.0, 1.0, 0.0, y_hi]
    ids = np.arange(n)
    nb = np.full((n, 6), BOUNDARY_OPEN, dtype=np.int64)
    nf = np.full((n, 6), -1, dtype=np.int64)
    for f, ok, other, back in [
        (0, k > 0, ids - 1, 1),
        (1, k < nz - 1, ids + 1, 0),
        (2, i > 0, ids - nz, 3),
        (3, i < nx - 1, ids + nz, 2),
    ]:
        nb[:, f] = np.where(ok, other, BOUNDARY_OPEN)
        nf[:, f] = np.where(ok, back, -1)
    nb[k == 0, 0] = BOUNDARY_REFLECT
    return CellMesh(
        planes=planes,
        neighbours=nb,
        neighbour_face=nf,
        media_ref=np.full(n, m_const),
        ref_point=np.column_stack([xs[i], zero, zs[k]]),
        gradient=np.zeros((n, 3)),
        size=np.minimum(np.diff(xs)[i], np.diff(zs)[k]),
        face_material=np.zeros((n, 6), np.int64),
    )


RIDGE_SOURCE = np.array([0.0, 0.0, 50.0])  # above the crest (h = 40 m), rays leave both ways
RIDGE_T = 2.5
RIDGE_TOL = 2e-5  # measured on 5 m x 1 m boxes: 6e-6 (10 m x 2 m: 2.3e-5, 2.5 m x 0.5 m: 1.3e-6)
LANDING_TOL_M = 4.0  # measured 2.1 m: set by the 0.1 m ramp below z_g, which 1 m boxes do not resolve


def test_ridge_downwind_bends_down_upwind_bends_up_vs_dop853():
    xs = np.arange(-900.0, 900.0 + 2.5, 5.0)
    zs = np.arange(0.0, 200.0 + 0.5, 1.0)
    mesh = _box_grid(xs, zs, -50.0, 50.0, 1.0)
    validate_cell_mesh(mesh)
    wind = wind_spec("ridge", RIDGE)
    start = int(np.searchsorted(xs, 0.0, side="right") - 1) * (len(zs) - 1) + int(RIDGE_SOURCE[2])
    up = np.radians([1.0, 2.0, 3.0])  # these stay above the surface layer
    down = np.radians([-2.0, -1.0, 0.0])  # these reach the ground downwind
    z_end = {}
    for sign in (1.0, -1.0):  # downwind (+x), upwind (-x)
        d = np.column_stack([sign * np.cos(up), 0 * up, np.sin(up)])
        o = np.tile(RIDGE_SOURCE, (len(d), 1))
        cells = np.full(len(d), start)
        r = trace(mesh, "parabolic", C_REF, o, d, cells, max_time_s=RIDGE_T, max_reflections=5, wind=wind)
        n_of, g_of = _oracle_ridge(sign)
        assert np.all(r.status == STATUS_TIME_LIMIT) and np.all(r.reflections == 0)
        for i in range(len(d)):
            ref = integrate_ray(n_of, g_of, RIDGE_SOURCE, d[i], RIDGE_T, c_ref=C_REF)
            assert ref.reflections == 0
            err = np.linalg.norm(r.position[i] - ref.position) / (C0 * RIDGE_T)
            assert err < RIDGE_TOL, f"sign {sign} ray {i}: {err:.2e}"
        z_end[sign] = r.position[:, 2]
        if sign > 0:  # downwind, launched slightly down or level: the ground, where no-wind rays are far off
            d = np.column_stack([np.cos(down), 0 * down, np.sin(down)])
            r = trace(mesh, "parabolic", C_REF, o, d, cells, max_time_s=RIDGE_T, max_reflections=0, wind=wind)
            assert np.all(r.status == STATUS_REFLECTION_LIMIT)  # stopped at its first ground hit
            for i in range(len(d)):
                ref = integrate_ray(n_of, g_of, RIDGE_SOURCE, d[i], RIDGE_T, c_ref=C_REF, max_reflections=0)
                assert abs(r.position[i, 0] - ref.position[0]) < LANDING_TOL_M
                assert ref.position[2] == 0.0 and ref.reflections == 1
                # without wind the same ray would still be in the air: straight, it lands beyond c0 T
                assert RIDGE_SOURCE[2] / max(-math.tan(down[i]), 1e-300) > C0 * RIDGE_T
    straight = RIDGE_SOURCE[2] + C0 * RIDGE_T * np.sin(up)
    assert np.all(z_end[1.0] < straight - 30.0) and np.all(z_end[-1.0] > straight + 20.0)


def test_unphysical_effective_medium_loses_the_ray():
    """A headwind faster than sound (c_eff <= 0) is refused per cell: the ray ends as lost, not NaN."""
    mesh, z = _slab_mesh("parabolic", None, delta=1e-6)
    o, d = _fan(180.0)
    wind = (WIND_LOG, np.array([1e3, Z_G, 1.0, 0.0, 0.0]))  # past the builder's u* bound, on purpose
    r = trace(
        mesh, "parabolic", C_REF, o[:1], d[3:4], locate_in_slabs(z, o[:1]), max_time_s=1.0, max_reflections=5, wind=wind
    )
    assert r.status[0] == STATUS_LOST and np.all(np.isfinite(r.position))

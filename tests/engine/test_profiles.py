"""Media profiles (engine/profiles.py) and their job-file models (scenes/profile_models.py).

References are independent of the code under test: central finite differences computed here, closed
forms evaluated by hand, and the paper's parameter values from docs/physics.md §7.
"""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest
from pydantic import ValidationError

from bentray.engine import profiles as P
from bentray.scenes import profile_models as M

RNG = np.random.default_rng(12345)
# Points above ground, away from the hot-spot centre (0, 0, 10): x, y in [-80, 80] m, z in [0.5, 60] m.
POINTS = np.column_stack([RNG.uniform(-80, 80, 200), RNG.uniform(-80, 80, 200), RNG.uniform(0.5, 60, 200)])
FD_H = 1e-4  # m, step of the test's own central differences


def central_difference(f, pts: np.ndarray, h: float = FD_H) -> np.ndarray:
    """Reference gradient: (f(x + h e_i) - f(x - h e_i)) / 2h for each axis i; (N, 3)."""
    cols = []
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        cols.append((f(pts + e) - f(pts - e)) / (2 * h))
    return np.stack(cols, axis=1)


def _grid_profile() -> P.Grid:
    rng = np.random.default_rng(7)
    c = rng.uniform(330.0, 350.0, (6, 5, 7))
    return P.Grid(origin=(-90.0, -90.0, 0.0), spacing=(36.0, 45.0, 10.0), c=c)


PROFILE_FACTORIES = {
    "homogeneous": lambda: P.Homogeneous(c0=343.0),
    "linear_c": lambda: P.LinearC(),
    "linear_n": lambda: P.LinearN(),
    "linear_n2": lambda: P.LinearN2(),
    "log_ld": lambda: P.Log(b=1.0),
    "log_lu": lambda: P.Log(b=-1.0),
    "mirage_inferior": lambda: P.MirageInferior(),
    "mirage_superior": lambda: P.MirageSuperior(),
    "hot_spot": lambda: P.HotSpot(),
    "fluctuating": lambda: P.Fluctuating(P.Log(b=-1.0), rms=1.0, seed=3),
    "fluctuating_vk": lambda: P.Fluctuating(P.HotSpot(), spectrum="von_karman", seed=4),
    "table_pchip": lambda: P.Table(z=[0, 5, 12, 30, 70], c=[340, 341.5, 341.0, 343, 345]),
    "table_linear": lambda: P.Table(z=[0, 5, 12, 30, 70], c=[340, 341.5, 341.0, 343, 345], interpolation="linear"),
    "grid": _grid_profile,
}


# ---------------------------------------------------------------------------------------------
# Gradients against central differences
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(PROFILE_FACTORIES))
@pytest.mark.parametrize("quantity", ["c", "n", "n2"])
def test_gradient_matches_central_difference(name: str, quantity: str) -> None:
    prof = PROFILE_FACTORIES[name]()
    pts = POINTS
    if name == "table_linear":  # keep the FD stencil inside one linear segment
        z_nodes = np.array([0, 5, 12, 30, 70])
        pts = pts[np.min(np.abs(pts[:, 2, None] - z_nodes), axis=1) > 10 * FD_H]
    if name == "grid":  # keep the FD stencil inside one trilinear cell
        u = (pts - prof.origin) / prof.spacing
        pts = pts[np.all(np.abs(u - np.round(u)) * prof.spacing > 10 * FD_H, axis=1)]
    assert len(pts) > 100
    analytic = prof.quantity_gradient(quantity, pts)
    reference = central_difference(lambda x: prof.quantity(quantity, x), pts)
    q_max = np.max(np.abs(prof.quantity(quantity, pts)))
    # rtol 1e-6 of the largest gradient component, plus the FD rounding floor (~eps |q| / h).
    tol = 1e-6 * np.max(np.abs(reference)) + 1e-11 * q_max / FD_H
    assert np.max(np.abs(analytic - reference)) <= tol
    if quantity == "c":
        np.testing.assert_array_equal(prof.sound_speed_gradient(pts), analytic)
    if quantity == "n":
        np.testing.assert_array_equal(prof.refractive_index_gradient(pts), analytic)


def test_chain_rule_between_quantities() -> None:
    prof = P.Fluctuating(P.Log(), seed=1)
    c = prof.sound_speed(POINTS)
    gc = prof.sound_speed_gradient(POINTS)
    n = prof.quantity("n", POINTS)
    np.testing.assert_allclose(n, 340.0 / c, rtol=1e-15)
    np.testing.assert_allclose(prof.quantity("n2", POINTS), n * n, rtol=1e-15)
    np.testing.assert_allclose(prof.quantity_gradient("n", POINTS), -340.0 / c[:, None] ** 2 * gc, rtol=1e-13)


def test_finite_difference_fallback_for_subclass_without_gradient() -> None:
    class Wavy(P.Profile):
        kind = "wavy"

        def _m(self, p: np.ndarray) -> np.ndarray:
            return 340.0 + np.sin(p[:, 0]) + 0.5 * np.cos(2 * p[:, 1]) + 0.1 * p[:, 2]

    prof = Wavy()
    exact = np.column_stack([np.cos(POINTS[:, 0]), -np.sin(2 * POINTS[:, 1]), np.full(len(POINTS), 0.1)])
    np.testing.assert_allclose(prof.sound_speed_gradient(POINTS), exact, rtol=0, atol=1e-7)


# ---------------------------------------------------------------------------------------------
# Closed-form values
# ---------------------------------------------------------------------------------------------
def test_log_profile_known_values() -> None:
    prof = P.Log(c0=340.0, b=1.0, z_g=1.0)
    z = np.array([0.0, 1.0, math.e - 1.0, 9.0, 99.0])
    pts = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    expected = 340.0 + np.array([0.0, math.log(2.0), 1.0, math.log(10.0), math.log(100.0)])
    np.testing.assert_allclose(prof.sound_speed(pts), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(prof.sound_speed_gradient(pts)[:, 2], 1.0 / (z + 1.0), rtol=1e-14)
    up = P.Log(b=-1.0, z_g=2.0)
    assert up.sound_speed([5.0, -3.0, 2.0]) == pytest.approx(340.0 - math.log(2.0), abs=1e-12)
    # below ground (rounding only): clamped, finite
    below = prof.sound_speed([[0.0, 0.0, -1e-9], [0.0, 0.0, -5.0]])
    np.testing.assert_array_equal(below, [340.0, 340.0])
    np.testing.assert_array_equal(prof.sound_speed_gradient([0.0, 0.0, -5.0]), [0.0, 0.0, 0.0])


def test_linear_profiles_definitions() -> None:
    z = np.linspace(0.0, 100.0, 101)
    pts = np.column_stack([z * 3.0, -z, z])
    np.testing.assert_allclose(P.LinearC().sound_speed(pts), 340.0 + 0.1 * z, rtol=1e-15)
    np.testing.assert_allclose(P.LinearN().quantity("n", pts), 1.0 + 0.02 * z, rtol=1e-15)
    np.testing.assert_allclose(P.LinearN().sound_speed(pts), 340.0 / (1.0 + 0.02 * z), rtol=1e-15)
    n2 = P.LinearN2().quantity("n2", pts)
    np.testing.assert_array_equal(n2, 1.0 + 0.01 * z)  # native quantity: exactly as defined
    assert np.max(np.abs(np.diff(n2, 2))) < 1e-15  # exactly linear up to rounding
    np.testing.assert_allclose(P.LinearN2().sound_speed(pts), 340.0 / np.sqrt(1.0 + 0.01 * z), rtol=1e-15)


def test_mirage_profiles() -> None:
    z = np.array([0.0, 0.3, 1.0, 4.0])
    pts = np.column_stack([np.zeros(4), np.zeros(4), z])
    mu0, mu1, beta = 1.000233, 0.4584, 2.303
    inf_n2 = mu0**2 + mu1**2 * (1.0 - np.exp(-beta * z))
    sup_n2 = mu0**2 + mu1**2 * np.exp(-beta * z)
    np.testing.assert_allclose(P.MirageInferior().quantity("n2", pts), inf_n2, rtol=1e-15)
    np.testing.assert_allclose(P.MirageSuperior().quantity("n2", pts), sup_n2, rtol=1e-15)
    np.testing.assert_allclose(P.MirageInferior().sound_speed(pts), 340.0 / np.sqrt(inf_n2), rtol=1e-15)


def test_hot_spot_temperature() -> None:
    hs = P.HotSpot(center=(20.0, -5.0, 30.0), t_s=350.0, d0=40.0)
    assert hs.temperature([20.0, -5.0, 30.0]) == pytest.approx(350.0, abs=1e-9)
    c_centre = math.sqrt(1.4 * 287.05 * 350.0)
    assert hs.sound_speed([20.0, -5.0, 30.0]) == pytest.approx(c_centre, abs=1e-9)
    far = np.array([[20.0 + 8000.0, -5.0, 100.0], [20.0, 9000.0, 0.0]])
    t_std = 288.15 - 0.0065 * far[:, 2]
    np.testing.assert_allclose(hs.temperature(far), t_std, rtol=0, atol=1e-9)
    # decays towards T_std monotonically with distance
    d = np.array([0.0, 10.0, 40.0, 200.0, 1000.0])
    excess = hs.temperature(np.column_stack([20.0 + d, np.full(5, -5.0), np.full(5, 30.0)])) - (288.15 - 0.0065 * 30.0)
    np.testing.assert_allclose(excess, (350.0 - (288.15 - 0.0065 * 30.0)) * np.exp(-d / 40.0), rtol=1e-12, atol=1e-12)
    # the standard atmosphere is clamped to [0, 11000] m
    np.testing.assert_allclose(
        P.standard_temperature([-10.0, 0.0, 11000.0, 20000.0]), [288.15, 288.15, 216.65, 216.65], rtol=1e-15
    )
    assert not hs.stratified


# ---------------------------------------------------------------------------------------------
# Table
# ---------------------------------------------------------------------------------------------
def test_table_temperature_conversion() -> None:
    expected = math.sqrt(1.4 * 287.05 * 288.15)  # 340.2923 m/s with docs/physics.md §7's R = 287.05
    tk = P.Table(z=[0.0, 100.0], temperature_k=[288.15, 288.15])
    tc = P.Table(z=[0.0, 100.0], temperature_c=[15.0, 15.0])
    for prof in (tk, tc):
        c = prof.sound_speed([0.0, 0.0, 50.0])
        assert c == pytest.approx(expected, abs=1e-9)
        assert abs(c - 340.2923) < 1e-3
        # ISA quotes 340.294 m/s with R = 287.053; the difference is the R digits only.
        assert abs(c - 340.294) < 2e-3


@pytest.mark.parametrize("interpolation", ["pchip", "linear"])
def test_table_reproduces_nodes_and_extrapolates_constant(interpolation: str) -> None:
    z = np.array([0.0, 2.0, 10.0, 25.0, 80.0])
    c = np.array([338.0, 339.5, 341.0, 340.2, 343.0])
    prof = P.Table(z=z, c=c, interpolation=interpolation)
    nodes = np.column_stack([np.ones(5), np.ones(5), z])
    np.testing.assert_allclose(prof.sound_speed(nodes), c, rtol=0, atol=1e-12)
    outside = np.array([[0.0, 0.0, -3.0], [0.0, 0.0, 500.0]])
    np.testing.assert_array_equal(prof.sound_speed(outside), [338.0, 343.0])
    np.testing.assert_array_equal(prof.sound_speed_gradient(outside), np.zeros((2, 3)))
    assert prof.stratified
    if interpolation == "linear":
        assert prof.sound_speed([0.0, 0.0, 6.0]) == pytest.approx(340.25, abs=1e-12)


def test_table_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="strictly increasing"):
        P.Table(z=[0.0, 1.0, 1.0], c=[340, 341, 342])
    with pytest.raises(ValueError, match="exactly one"):
        P.Table(z=[0.0, 1.0], c=[340, 341], temperature_k=[290, 291])
    with pytest.raises(ValueError, match="at least 2"):
        P.Table(z=[0.0], c=[340])
    with pytest.raises(ValueError, match="c must be > 0"):
        P.Table(z=[0.0, 1.0], c=[340, -1])


# ---------------------------------------------------------------------------------------------
# Grid
# ---------------------------------------------------------------------------------------------
def _linear_grid_data() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    origin = np.array([-10.0, 5.0, 0.0])
    spacing = np.array([2.5, 4.0, 1.5])
    coef = np.array([0.03, -0.02, 0.1])
    ii, jj, kk = np.meshgrid(np.arange(5), np.arange(4), np.arange(6), indexing="ij")
    nodes = origin + np.stack([ii, jj, kk], axis=-1) * spacing
    c = 340.0 + nodes @ coef
    return origin, spacing, coef, c


def test_grid_trilinear_reproduces_linear_field() -> None:
    origin, spacing, coef, c = _linear_grid_data()
    grid = P.Grid(origin, spacing, c)
    rng = np.random.default_rng(2)
    hi = origin + spacing * (np.array(c.shape) - 1)
    pts = rng.uniform(origin, hi, (2000, 3))
    pts = np.vstack([pts, origin, hi])  # the box corners too
    np.testing.assert_allclose(grid.sound_speed(pts), 340.0 + pts @ coef, rtol=1e-12)
    np.testing.assert_allclose(grid.sound_speed_gradient(pts), np.broadcast_to(coef, pts.shape), rtol=1e-12)
    # outside: clamped onto the box, gradient 0 along the clamped axis
    out = np.array([[origin[0] - 7.0, origin[1] + 1.0, origin[2] + 1.0]])
    inside = np.array([[origin[0], origin[1] + 1.0, origin[2] + 1.0]])
    np.testing.assert_allclose(grid.sound_speed(out), grid.sound_speed(inside), rtol=1e-15)
    np.testing.assert_allclose(grid.sound_speed_gradient(out), [[0.0, coef[1], coef[2]]], rtol=1e-12)
    assert not grid.stratified


def test_grid_loads_npz_and_vti(tmp_path) -> None:
    pyvista = pytest.importorskip("pyvista")
    origin, spacing, coef, c = _linear_grid_data()
    ref = P.Grid(origin, spacing, c)
    pts = np.random.default_rng(3).uniform(origin, origin + spacing * 3, (50, 3))

    npz = tmp_path / "media.npz"
    np.savez(npz, c=c, origin=origin, spacing=spacing)
    g1 = P.Grid.from_file(npz)
    np.testing.assert_array_equal(g1.sound_speed(pts), ref.sound_speed(pts))

    npz_t = tmp_path / "media_t.npz"
    t = np.full(c.shape, 288.15)
    np.savez(npz_t, temperature_k=t, origin=origin, spacing=spacing)
    assert P.Grid.from_file(npz_t).sound_speed([0.0, 6.0, 1.0]) == pytest.approx(
        math.sqrt(1.4 * 287.05 * 288.15), abs=1e-9
    )

    for name in ("c", "sound_speed"):
        img = pyvista.ImageData(dimensions=c.shape, spacing=tuple(spacing), origin=tuple(origin))
        img.point_data[name] = c.ravel(order="F")
        vti = tmp_path / f"media_{name}.vti"
        img.save(vti)
        g2 = P.Grid.from_file(vti)
        assert g2.shape == c.shape
        np.testing.assert_allclose(g2.sound_speed(pts), ref.sound_speed(pts), rtol=1e-14)
        assert g2.describe()["path"] == str(vti)


def test_grid_validation_messages(tmp_path) -> None:
    origin, spacing, _, c = _linear_grid_data()
    bad = tmp_path / "nokey.npz"
    np.savez(bad, c=c, origin=origin)
    with pytest.raises(ValueError, match="missing key 'spacing'"):
        P.Grid.from_file(bad)
    with pytest.raises(ValueError, match="spacing must be > 0"):
        P.Grid(origin, [1.0, 0.0, 1.0], c)
    c_nan = c.copy()
    c_nan[1, 1, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        P.Grid(origin, spacing, c_nan)
    with pytest.raises(ValueError, match="> 0 everywhere"):
        P.Grid(origin, spacing, -c)
    with pytest.raises(ValueError, match="at least 2 points"):
        P.Grid(origin, spacing, c[:1])
    with pytest.raises(ValueError, match="shape"):
        P.Grid(origin, spacing, c[:, :, 0])
    with pytest.raises(ValueError, match=r"\.npz or \.vti"):
        P.Grid.from_file(tmp_path / "media.csv")
    with pytest.raises(ValueError, match="not found"):
        P.Grid.from_file(tmp_path / "absent.npz")


# ---------------------------------------------------------------------------------------------
# Fluctuations
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("spectrum", ["gaussian", "flat", "von_karman"])
def test_fluctuation_rms(spectrum: str) -> None:
    rms = 0.7
    prof = P.Fluctuating(P.Homogeneous(), rms=rms, spectrum=spectrum, seed=11)
    assert 0.5 * np.sum(prof.amplitudes**2) == pytest.approx(rms**2, rel=1e-12)
    kmag = np.linalg.norm(prof.wavevectors, axis=1)
    assert np.all((kmag >= prof.k_min) & (kmag <= prof.k_max))
    pts = np.random.default_rng(99).uniform(-3000.0, 3000.0, (200_000, 3))
    c_flu = prof.fluctuation(pts)
    assert np.sqrt(np.mean(c_flu**2)) == pytest.approx(rms, rel=0.05)
    np.testing.assert_allclose(prof.sound_speed(pts[:100]), 340.0 + c_flu[:100], rtol=1e-15)
    assert not prof.stratified


def test_fluctuation_determinism_and_seed() -> None:
    a = P.Fluctuating(P.Log(), seed=5)
    b = P.Fluctuating(P.Log(), seed=5)
    c = P.Fluctuating(P.Log(), seed=6)
    np.testing.assert_array_equal(a.sound_speed(POINTS), b.sound_speed(POINTS))
    np.testing.assert_array_equal(a.sound_speed_gradient(POINTS), b.sound_speed_gradient(POINTS))
    assert np.max(np.abs(a.fluctuation(POINTS) - c.fluctuation(POINTS))) > 0.1
    assert not np.array_equal(a.phases, c.phases)


def test_fluctuation_zero_rms_is_base() -> None:
    prof = P.Fluctuating(P.Log(b=-1.0), rms=0.0)
    np.testing.assert_array_equal(prof.sound_speed(POINTS), P.Log(b=-1.0).sound_speed(POINTS))


# ---------------------------------------------------------------------------------------------
# API details
# ---------------------------------------------------------------------------------------------
def test_shapes_and_effective_speed() -> None:
    prof = P.HotSpot()
    assert prof.sound_speed([1.0, 2.0, 3.0]).shape == ()
    assert prof.sound_speed(np.zeros((2, 4, 3))).shape == (2, 4)
    assert prof.quantity_gradient("n2", np.zeros((2, 4, 3))).shape == (2, 4, 3)
    np.testing.assert_array_equal(
        prof.effective_sound_speed(POINTS, azimuth_unit=np.array([1.0, 0.0, 0.0])), prof.sound_speed(POINTS)
    )
    with pytest.raises(ValueError, match="shape"):
        prof.sound_speed(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="unknown quantity"):
        prof.quantity("k", POINTS)


def test_build_profile_factory() -> None:
    prof = P.build_profile("fluctuating", base={"kind": "log", "b": -1.0}, rms=0.3, seed=2)
    assert isinstance(prof, P.Fluctuating) and isinstance(prof.base, P.Log) and prof.base.b == -1.0
    assert P.build_profile("hot_spot").describe()["t_s"] == 330.0
    with pytest.raises(ValueError, match="unknown profile kind"):
        P.build_profile("cubic")
    with pytest.raises(ValueError, match="unknown parameter"):
        P.build_profile("log", c1=3.0)
    assert set(P.PROFILE_KINDS) == {
        "homogeneous",
        "linear_c",
        "linear_n",
        "linear_n2",
        "log",
        "mirage_inferior",
        "mirage_superior",
        "hot_spot",
        "fluctuating",
        "table",
        "grid",
    }


@pytest.mark.parametrize("name", sorted(PROFILE_FACTORIES))
def test_describe_is_json_serializable(name: str) -> None:
    import json

    d = PROFILE_FACTORIES[name]().describe()
    assert json.loads(json.dumps(d)) == d
    assert d["kind"] in P.PROFILE_KINDS


# ---------------------------------------------------------------------------------------------
# Pydantic models
# ---------------------------------------------------------------------------------------------
def test_spec_defaults_are_paper_values() -> None:
    assert (M.LinearCSpec().c0, M.LinearCSpec().alpha) == (340.0, 0.1)
    assert (M.LinearNSpec().n0, M.LinearNSpec().alpha) == (1.0, 0.02)
    assert (M.LinearN2Spec().n0, M.LinearN2Spec().alpha) == (1.0, 0.01)
    assert (M.LogSpec().c0, M.LogSpec().b, M.LogSpec().z_g) == (340.0, 1.0, 1.0)
    for spec in (M.MirageInferiorSpec(), M.MirageSuperiorSpec()):
        assert (spec.mu0, spec.mu1, spec.beta) == (1.000233, 0.4584, 2.303)
    assert M.HomogeneousSpec().c0 == 340.0


@pytest.mark.parametrize(
    "spec_cls, engine_cls",
    [
        (M.HomogeneousSpec, P.Homogeneous),
        (M.LinearCSpec, P.LinearC),
        (M.LinearNSpec, P.LinearN),
        (M.LinearN2Spec, P.LinearN2),
        (M.LogSpec, P.Log),
        (M.MirageInferiorSpec, P.MirageInferior),
        (M.MirageSuperiorSpec, P.MirageSuperior),
        (M.HotSpotSpec, P.HotSpot),
        (M.FluctuatingSpec, P.Fluctuating),
    ],
)
def test_spec_defaults_match_engine_defaults(spec_cls, engine_cls) -> None:
    spec = spec_cls()
    for pname, param in inspect.signature(engine_cls.__init__).parameters.items():
        if pname in ("self", "base") or param.default is inspect.Parameter.empty:
            continue
        value = getattr(spec, pname)
        assert tuple(np.atleast_1d(value)) == tuple(np.atleast_1d(param.default)), pname


def test_profile_from_spec_round_trip() -> None:
    adapter = M.PROFILE_SPEC_ADAPTER
    spec = adapter.validate_python({"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0})
    prof = M.profile_from_spec(spec)
    assert isinstance(prof, P.Log)
    assert prof.describe() == P.Log().describe()
    fl = M.profile_from_spec(
        {"kind": "fluctuating", "base": {"kind": "log", "b": -1.0}, "rms": 0.4, "spectrum": "flat", "seed": 9}
    )
    ref = P.Fluctuating(P.Log(b=-1.0), rms=0.4, spectrum="flat", seed=9)
    np.testing.assert_array_equal(fl.sound_speed(POINTS), ref.sound_speed(POINTS))
    tab = M.profile_from_spec({"kind": "table", "z": [0, 10], "temperature_c": [15, 10]})
    assert isinstance(tab, P.Table) and tab.source == "temperature_c"
    dumped = spec.model_dump()
    assert adapter.validate_python(dumped) == spec


def test_profile_from_spec_grid_paths(tmp_path) -> None:
    origin, spacing, _, c = _linear_grid_data()
    (tmp_path / "media").mkdir()
    np.savez(tmp_path / "media" / "g.npz", c=c, origin=origin, spacing=spacing)
    spec = M.PROFILE_SPEC_ADAPTER.validate_python({"kind": "grid", "path": "media/g.npz"})
    prof = M.profile_from_spec(spec, base_dir=tmp_path)
    assert isinstance(prof, P.Grid) and prof.shape == c.shape
    nested = {"kind": "fluctuating", "base": {"kind": "grid", "path": "media/g.npz"}}
    assert isinstance(M.profile_from_spec(nested, base_dir=tmp_path).base, P.Grid)
    inline = M.profile_from_spec({"kind": "grid", "origin": [0, 0, 0], "spacing": [1, 1, 1], "c": c.tolist()})
    np.testing.assert_array_equal(inline.c, c)


@pytest.mark.parametrize(
    "data, field",
    [
        ({"kind": "log", "z_g": 0.0}, "z_g"),
        ({"kind": "log", "c0": -340.0}, "c0"),
        ({"kind": "linear_c", "alpha": float("inf")}, "alpha"),
        ({"kind": "log", "zg": 1.0}, "zg"),
        ({"kind": "fluctuating", "rms": -0.1}, "rms"),
        ({"kind": "fluctuating", "k_min": 1.0, "k_max": 0.5}, "k_min"),
        ({"kind": "fluctuating", "spectrum": "pink"}, "spectrum"),
        ({"kind": "fluctuating", "base": {"kind": "log", "c0": float("nan")}}, "c0"),
        ({"kind": "hot_spot", "d0": 0.0}, "d0"),
        ({"kind": "table", "z": [0.0, 5.0, 5.0], "c": [340, 341, 342]}, "z"),
        ({"kind": "table", "z": [0.0, 5.0], "c": [340, 341, 342]}, "c"),
        ({"kind": "table", "z": [0.0, 5.0], "c": [340, -1]}, "c"),
        ({"kind": "table", "z": [0.0, 5.0]}, "temperature_k"),
        ({"kind": "grid", "path": "media.csv"}, "path"),
        (
            {"kind": "grid", "origin": [0, 0, 0], "spacing": [1, -1, 1], "c": [[[340, 340]] * 2] * 2},
            "spacing",
        ),
        ({"kind": "grid", "origin": [0, 0, 0], "spacing": [1, 1, 1], "c": [[[340]]]}, "c"),
        ({"kind": "cubic"}, "kind"),
    ],
)
def test_spec_rejects_bad_input_naming_the_field(data: dict, field: str) -> None:
    with pytest.raises(ValidationError) as info:
        M.PROFILE_SPEC_ADAPTER.validate_python(data)
    assert field in str(info.value)


def test_spec_validators_do_not_mutate() -> None:
    data = {"kind": "table", "z": [0, 5.5, 9], "c": [340, 341, 339.5], "interpolation": "linear"}
    spec = M.PROFILE_SPEC_ADAPTER.validate_python(data)
    assert spec.z == [0.0, 5.5, 9.0] and spec.c == [340.0, 341.0, 339.5]
    assert spec.model_dump(exclude_none=True) == {**data, "z": [0.0, 5.5, 9.0], "c_ref": 340.0}

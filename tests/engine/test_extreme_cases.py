"""Stiff and extreme cases (engine/bench/extreme.py builds the media and rays) against independent references.

References (none shared with the engine or the bench): scipy DOP853 at rtol 1e-12 in travel time
(tests/reference/ray_ode.py), the vertical-ray integral t = int dz / c(z) (scipy quad) and mirror images
of straight rays, all written out here. Errors are |x - x_ref| / (c0 t) at the end time.

The analytic tracer: no lost ray, no NaN, no ray below the ground, and an error bound per case (each about
10x above the measured error, so a regression of an order of magnitude fails). The numerical baselines
(dopri5, rk4 on the exact profile; dopri5 on the mesh media for tet cases): every ray ends with a status
(none left "running"), finite end states.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

import bentray  # noqa: F401
from bentray.engine.bench.extreme import ALPHA_N2, build_case, trace_case
from bentray.engine.constants import STATUS_LOST, STATUS_NAMES, STATUS_RUNNING, STATUS_TIME_LIMIT
from tests.reference.ray_ode import integrate_ray, log_profile

C0 = 340.0


def _dop853(case, n_of, grad_n_of, rows) -> np.ndarray:
    return np.array(
        [integrate_ray(n_of, grad_n_of, case.origins[i], case.directions[i], case.max_time_s).position for i in rows]
    )


def _error(result, ref: np.ndarray, rows, t_end: float) -> float:
    return float(np.max(np.linalg.norm(result.position[rows] - ref, axis=1)) / (C0 * t_end))


def _check_analytic(case):
    res, _ = trace_case(case, "analytic", "mesh")
    assert res.status_counts()["lost"] == 0, res.status_counts()
    assert np.all(np.isfinite(res.position)) and np.all(np.isfinite(res.time_s))
    assert np.all(res.position[:, 2] >= -1e-9), res.position
    return res


def _check_baselines(case):
    runs = [("dopri5", "exact"), ("rk4", "exact")] + ([("dopri5", "mesh")] if case.mesh_media_baselines else [])
    for method, media in runs:
        res, _ = trace_case(case, method, media)
        assert not np.any(res.status == STATUS_RUNNING), (method, media)
        assert set(np.unique(res.status).tolist()) <= set(STATUS_NAMES), (method, media)
        assert np.all(np.isfinite(res.position)), (method, media)


# ------------------------------------------------------------------------------------------------
# sources on the ground
# ------------------------------------------------------------------------------------------------
def test_grazing_launch_upward_refraction_lifts_off():
    """A-LU, source on the ground, elevations 0 and 1e-3 degrees: both rays lift off (DOP853 to 1e-6,
    measured 7.9e-8)."""
    case = build_case("grazing_alu", quick=True)
    res = _check_analytic(case)
    assert np.all(res.status == STATUS_TIME_LIMIT)
    ref = _dop853(case, *log_profile(b=-1.0), [0, 1])
    assert _error(res, ref, [0, 1], case.max_time_s) < 1e-6
    assert np.all(res.position[:, 2] > 100.0)  # well off the ground after 10 s
    _check_baselines(case)


def test_grazing_launch_downward_refraction_bounces_stay_above_ground():
    """A-LD, elevation 1e-3 degrees from the ground: ever smaller bounces (reflection limit), never lost,
    never below the ground."""
    case = build_case("grazing_ald", quick=True)
    res, _ = trace_case(case, "analytic", "mesh")
    assert res.status[1] != STATUS_LOST and np.all(np.isfinite(res.position[1]))
    assert res.position[1, 2] >= -1e-9
    assert res.reflections[1] > 100
    _check_baselines(case)


def test_grazing_launch_downward_refraction_creeps_along_the_ground():
    """A-LD, elevation exactly 0 on the ground: the limit of vanishing bounces creeps along the ground at
    c(0): x = c0 t, z = 0 (the baselines slide there: checked to 1e-5)."""
    case = build_case("grazing_ald", quick=True)
    for method, media in (("analytic", "mesh"), ("dopri5", "exact")):
        res, _ = trace_case(case, method, media)
        assert res.status[0] != STATUS_LOST and np.all(np.isfinite(res.position[0]))
        assert res.position[0, 2] >= -1e-9, (method, res.position[0])
        assert abs(res.position[0, 0] - C0 * case.max_time_s) / (C0 * case.max_time_s) < 1e-5, method


# ------------------------------------------------------------------------------------------------
# special directions and gradients
# ------------------------------------------------------------------------------------------------
def _vertical_height(z0: float, up: bool, t_end: float, b: float = 1.0, z_g: float = 1.0) -> float:
    def c(z: float) -> float:
        return C0 + b * math.log(z / z_g + 1.0)

    def t_between(a: float, z: float) -> float:
        return quad(lambda zz: 1.0 / c(zz), a, z, epsabs=0.0, epsrel=1e-13)[0]

    if up:
        return brentq(lambda z: t_between(z0, z) - t_end, z0, z0 + 2 * C0 * t_end, xtol=1e-12)
    t_left = t_end - t_between(0.0, z0)  # down to the ground, then up again
    return brentq(lambda z: t_between(0.0, z) - t_left, 0.0, 2 * C0 * t_end, xtol=1e-12)


def test_rays_along_the_gradient_stay_vertical():
    """Vertical rays up and down (reflected) in A-LD against t = int dz / c(z): 2e-8 (measured 2.9e-9)."""
    case = build_case("along_gradient", quick=True)
    res = _check_analytic(case)
    assert np.all(res.status == STATUS_TIME_LIMIT) and np.all(res.nudges == 0)
    ref = np.array([[0.0, 0.0, _vertical_height(1.5, up, case.max_time_s)] for up in (True, False)])
    assert np.all(res.position[:, :2] == 0.0)
    assert _error(res, ref, [0, 1], case.max_time_s) < 2e-8
    assert res.reflections.tolist() == [0, 1]
    _check_baselines(case)


def test_zero_gradient_rays_are_straight_with_mirror_images():
    """Homogeneous air in one box cell: straight lines and ground mirror images to 1e-12."""
    case = build_case("zero_gradient", quick=True)
    res = _check_analytic(case)
    ref = case.origins + C0 * case.max_time_s * case.directions
    ref[:, 2] = np.abs(ref[:, 2])
    rows = list(range(len(ref)))
    assert _error(res, ref, rows, case.max_time_s) < 1e-12
    _check_baselines(case)


def test_gradients_100x_the_paper():
    """A-LD with b = 100 m/s (100x), 1 s: many reflections, DOP853 to 5e-6 (measured 4.5e-7)."""
    case = build_case("gradient_100x", quick=True)
    res = _check_analytic(case)
    assert np.all(res.status == STATUS_TIME_LIMIT) and res.reflections.max() >= 3
    rows = [0, 3, 6]
    ref = _dop853(case, *log_profile(b=100.0), rows)
    assert _error(res, ref, rows, case.max_time_s) < 5e-6
    _check_baselines(case)


def test_log_profile_with_a_1cm_roughness_length():
    """A-LD with z_g = 0.01 m (dc/dz = 100 1/s at the ground): DOP853 to 1e-6 (measured 1.0e-7)."""
    case = build_case("log_zg_0.01", quick=True)
    res = _check_analytic(case)
    assert np.all(res.status == STATUS_TIME_LIMIT)
    rows = [0, 3, 6]
    ref = _dop853(case, *log_profile(b=1.0, z_g=0.01), rows)
    assert _error(res, ref, rows, case.max_time_s) < 1e-6
    _check_baselines(case)


def test_ten_km_domain():
    """A-LD over 10 km (30 s, domain 10 km x 8 km): DOP853 to 5e-8 (measured 3.5e-9)."""
    case = build_case("domain_10km", quick=True)
    res = _check_analytic(case)
    assert np.all(res.status == STATUS_TIME_LIMIT)
    rows = [0, 2, 4]
    ref = _dop853(case, *log_profile(b=1.0), rows)
    assert _error(res, ref, rows, case.max_time_s) < 5e-8
    _check_baselines(case)


# ------------------------------------------------------------------------------------------------
# awkward mesh positions and cells (n^2 = 1 + alpha z: exact in every tet for the parabolic curve)
# ------------------------------------------------------------------------------------------------
def _n2_linear():
    def n_of(x):
        return math.sqrt(1.0 + ALPHA_N2 * x[2])

    def grad_n_of(x):
        return np.array([0.0, 0.0, ALPHA_N2 / (2.0 * math.sqrt(1.0 + ALPHA_N2 * x[2]))])

    return n_of, grad_n_of


@pytest.mark.parametrize("key", ["source_on_vertex", "source_on_edge", "source_on_face", "sliver_cells"])
def test_awkward_sources_and_sliver_cells(key):
    """Sources exactly on a vertex / edge midpoint / face centroid of a Delaunay mesh, and a sliver-filled
    mesh: every ray of a sphere fan reaches the time limit, matching DOP853 to 1e-10 (measured 3e-13)."""
    case = build_case(key, quick=True)
    if key == "sliver_cells":
        assert case.stats["min_dihedral_deg"] < 1.0  # the mesh really has slivers
    assert np.all(case.start_cells >= 0)
    res = _check_analytic(case)
    assert np.all(res.status == STATUS_TIME_LIMIT)
    rows = [0, 4, 7, 10, 13]
    ref = _dop853(case, *_n2_linear(), rows)
    assert _error(res, ref, rows, case.max_time_s) < 1e-10
    _check_baselines(case)


def test_vertex_edge_face_sources_are_where_they_claim():
    """The vertex source is a mesh vertex, the edge source the midpoint of an edge, the face source the
    centroid of a face (so the cases above exercise what they name)."""
    from bentray.engine.bench.extreme import _fcc_mesh, _vertex_edge_face

    tet = _fcc_mesh()
    where = _vertex_edge_face(tet)
    p = tet.points
    assert np.min(np.linalg.norm(p - where["vertex"], axis=1)) == 0.0
    k = int(np.argmin(np.linalg.norm(p - where["vertex"], axis=1)))
    cells = tet.tets[np.any(tet.tets == k, axis=1)]
    mids = [(p[k] + p[v]) / 2 for c in cells for v in c if v != k]
    assert min(np.linalg.norm(m - where["edge"]) for m in mids) < 1e-12
    cents = [(p[k] + p[a] + p[b]) / 3 for c in cells for a in c for b in c if k not in (a, b) and a < b]
    assert min(np.linalg.norm(m - where["face"]) for m in cents) < 1e-12

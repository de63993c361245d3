"""FCC resampling (Algorithm 2), Delaunay CellMesh construction, cell gradients and Eq. 14 errors."""

from __future__ import annotations

import bentray  # noqa: F401  # isort: skip  (sets OPENBLAS_NUM_THREADS before numpy / scipy load)
import numpy as np
import pytest
from scipy.spatial import cKDTree

from bentray.engine.constants import BOUNDARY_OPEN, BOUNDARY_REFLECT
from bentray.engine.mesh.cells import locate_points, validate_cell_mesh
from bentray.engine.mesh.fcc import SEPARATION_RTOL, fcc_resample
from bentray.engine.mesh.gradients import green_gauss_gradients, lsq_gradients
from bentray.engine.mesh.tets import approximation_error, build_tet_mesh, locate_tets

LO = np.array([0.0, 0.0, 0.0])
HI = np.array([100.0, 80.0, 60.0])
D = 10.0
G = np.array([0.3, -0.2, 0.5])


def const(d):
    return lambda x: np.full(len(x), d)


def linear_m(x):
    return 2.0 + x @ G


def random_points_in_cells(tm, rng, per_cell=2):
    """Random barycentric points inside every cell: (cell ids, xyz)."""
    n = tm.cells.n_cells
    cells = np.repeat(np.arange(n), per_cell)
    w = rng.dirichlet(np.ones(4), size=len(cells))
    xyz = np.einsum("ni,nij->nj", w, tm.points[tm.tets[cells]])
    return cells, xyz


@pytest.fixture(scope="module")
def interior():
    return fcc_resample(LO, HI, const(D), d_min=1.0, d_max=100.0)


@pytest.fixture(scope="module")
def mesh_lsq(interior):
    return build_tet_mesh(LO, HI, interior, linear_m, spacing=const(D), gradient_method="lsq")


@pytest.fixture(scope="module")
def mesh_gg(interior):
    return build_tet_mesh(LO, HI, interior, linear_m, spacing=const(D), gradient_method="green_gauss")


# ---------------------------------------------------------------------------------------------------
# fcc_resample
# ---------------------------------------------------------------------------------------------------
def test_fcc_constant_spacing_separation_and_density():
    d = 5.0
    p = fcc_resample(LO, HI, const(d), d_min=1.0, d_max=100.0)
    assert np.all((p >= LO) & (p <= HI))
    nn = cKDTree(p).query(p, k=2)[0][:, 1]
    assert nn.min() >= d * (1 - 1e-12)  # exact lattice: only rounding below d
    assert np.median(nn) == pytest.approx(d, rel=1e-12)
    expected = np.sqrt(2.0) * np.prod(HI - LO) / d**3
    assert abs(len(p) / expected - 1) < 0.15


def test_fcc_graded_spacing_denser_where_small_and_separated():
    def spacing(x):
        return 3.0 + 0.1 * x[:, 2]

    p = fcc_resample(LO, HI, spacing, d_min=3.0, d_max=100.0)
    low = np.sum(p[:, 2] < 30.0)
    high = np.sum(p[:, 2] >= 30.0)
    assert low > 2 * high
    d = spacing(p)
    pairs = cKDTree(p).query_pairs(r=d.max(), output_type="ndarray")
    dist = np.linalg.norm(p[pairs[:, 0]] - p[pairs[:, 1]], axis=1)
    assert np.all(dist >= (1 - SEPARATION_RTOL) * np.minimum(d[pairs[:, 0]], d[pairs[:, 1]]))
    # Clamping: a spacing below d_min is raised to d_min.
    q = fcc_resample(LO, HI, lambda x: np.full(len(x), 0.01), d_min=8.0, d_max=100.0)
    assert cKDTree(q).query(q, k=2)[0][:, 1].min() >= 8.0 * (1 - 1e-12)


def test_fcc_deterministic():
    def spacing(x):
        return 4.0 + 0.05 * np.abs(x[:, 0] - 30.0)

    a = fcc_resample(LO, HI, spacing, d_min=4.0, d_max=20.0)
    b = fcc_resample(LO, HI, spacing, d_min=4.0, d_max=20.0)
    assert np.array_equal(a, b)


def test_fcc_max_points_and_bad_arguments():
    with pytest.raises(ValueError, match="max_points"):
        fcc_resample(LO, HI, const(1.0), d_min=1.0, d_max=10.0, max_points=10_000)
    with pytest.raises(ValueError):
        fcc_resample(LO, HI, const(5.0), d_min=0.0, d_max=10.0)
    with pytest.raises(ValueError):
        fcc_resample(HI, LO, const(5.0), d_min=1.0, d_max=10.0)


# ---------------------------------------------------------------------------------------------------
# build_tet_mesh: topology and geometry
# ---------------------------------------------------------------------------------------------------
def test_mesh_valid_and_fills_box(mesh_lsq):
    tm = mesh_lsq
    validate_cell_mesh(tm.cells)
    assert tm.tets.dtype == np.int64 and tm.tets.shape == (tm.cells.n_cells, 4)
    p = tm.points[tm.tets]
    vol = np.linalg.det(p[:, 1:] - p[:, :1]) / 6.0
    assert np.all(vol > 0)
    assert vol.sum() == pytest.approx(np.prod(HI - LO), rel=1e-9)
    st = tm.stats
    assert st["n_cells"] == tm.cells.n_cells and st["n_degenerate"] == 0 and st["n_unused_points"] == 0
    assert 0.6 < st["radius_edge"]["min"] <= st["radius_edge"]["median"] <= st["radius_edge"]["max"] < 3.0
    assert set(st["build_time_s"]) >= {"resample", "delaunay", "tables", "gradients"}
    # size is the longest edge
    e = np.linalg.norm(p[:, :, None, :] - p[:, None, :, :], axis=-1).max(axis=(1, 2))
    np.testing.assert_array_equal(tm.cells.size, e)


def test_planes_faces_and_neighbours(mesh_lsq):
    tm = mesh_lsq
    c = tm.cells
    n = c.n_cells
    p = tm.points[tm.tets]  # (n, 4, 3)
    nrm, h = c.planes[:, :, :3], c.planes[:, :, 3]
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=2), 1.0, rtol=0, atol=1e-15)
    s = np.einsum("nfk,nvk->nfv", nrm, p) - h[:, :, None]  # signed distance of vertex v to face f
    tol = 1e-12 * c.size[:, None]
    for f in range(4):
        others = [v for v in range(4) if v != f]
        assert np.all(np.abs(s[:, f, others]) <= tol)  # face f passes through the other 3 vertices
        assert np.all(s[:, f, f] < -1e-6 * c.size)  # opposite vertex strictly inside: outward normal
    ci, fi = np.nonzero(c.neighbours >= 0)
    nj, nf = c.neighbours[ci, fi], c.neighbour_face[ci, fi]
    for a, fa, b, fb in zip(ci[:200], fi[:200], nj[:200], nf[:200], strict=True):
        assert set(np.delete(tm.tets[a], fa)) == set(np.delete(tm.tets[b], fb))
    # Morton order: consecutive cells are near each other (much nearer than a random pair).
    step = np.linalg.norm(np.diff(c.ref_point, axis=0), axis=1)
    rnd = np.linalg.norm(c.ref_point - c.ref_point[np.random.default_rng(1).permutation(n)], axis=1)
    assert np.median(step) < 0.2 * np.median(rnd)


@pytest.mark.parametrize(("ground", "top"), [("reflect", "open"), ("open", "reflect")])
def test_boundary_faces_on_box_with_tags(interior, ground, top):
    tm = build_tet_mesh(LO, HI, interior, linear_m, spacing=const(D), ground=ground, top=top, seed=3)
    c = tm.cells
    bc, bf = np.nonzero(c.neighbours < 0)
    assert np.all(c.neighbour_face[bc, bf] == -1)
    pl = c.planes[bc, bf]
    tag = c.neighbours[bc, bf]
    axis = np.argmax(np.abs(pl[:, :3]), axis=1)
    # boundary normals are exactly axis-aligned unit vectors and h is exactly the box coordinate
    assert np.all(np.abs(pl[np.arange(len(pl)), axis]) == 1.0)
    assert np.count_nonzero(pl[:, :3]) == len(pl)
    sign = pl[np.arange(len(pl)), axis]
    box = np.where(sign > 0, HI[axis], -LO[axis])
    np.testing.assert_array_equal(pl[:, 3], box)
    fv = np.stack([tm.tets[bc, (bf + k) % 4] for k in (1, 2, 3)], axis=1)
    coord = tm.points[fv][np.arange(len(bc)), :, axis]
    np.testing.assert_array_equal(coord, np.broadcast_to(np.where(sign > 0, HI[axis], LO[axis])[:, None],
                                                         coord.shape))  # fmt: skip
    is_ground = (axis == 2) & (sign < 0)
    is_top = (axis == 2) & (sign > 0)
    want = {"reflect": BOUNDARY_REFLECT, "open": BOUNDARY_OPEN}
    assert np.all(tag[is_ground] == want[ground])
    assert np.all(tag[is_top] == want[top])
    assert np.all(tag[~is_ground & ~is_top] == BOUNDARY_OPEN)
    # every box face is fully covered by boundary triangles
    area = 0.5 * np.linalg.norm(
        np.cross(tm.points[fv[:, 1]] - tm.points[fv[:, 0]], tm.points[fv[:, 2]] - tm.points[fv[:, 0]]), axis=1
    )
    ext = HI - LO
    assert area[is_ground].sum() == pytest.approx(ext[0] * ext[1], rel=1e-12)
    assert area[~is_ground & ~is_top].sum() == pytest.approx(2 * ext[2] * (ext[0] + ext[1]), rel=1e-12)


def test_build_deterministic_and_default_spacing(interior, mesh_lsq):
    again = build_tet_mesh(LO, HI, interior, linear_m, spacing=const(D), gradient_method="lsq")
    np.testing.assert_array_equal(again.tets, mesh_lsq.tets)
    np.testing.assert_array_equal(again.cells.planes, mesh_lsq.cells.planes)
    nn = build_tet_mesh(LO, HI, interior, linear_m)  # boundary spacing from interior nearest neighbours
    validate_cell_mesh(nn.cells)
    assert 0.7 * mesh_lsq.stats["n_boundary_points"] < nn.stats["n_boundary_points"]
    assert nn.stats["n_boundary_points"] < 1.3 * mesh_lsq.stats["n_boundary_points"]


def test_build_rejects_bad_arguments(interior):
    with pytest.raises(ValueError, match="ground"):
        build_tet_mesh(LO, HI, interior, linear_m, ground="absorb")
    with pytest.raises(ValueError, match="gradient_method"):
        build_tet_mesh(LO, HI, interior, linear_m, gradient_method="fd")
    with pytest.raises(ValueError, match="quantity"):
        build_tet_mesh(LO, HI, interior, lambda x: np.full(len(x), np.nan))


# ---------------------------------------------------------------------------------------------------
# Media: gradients, media_at, approximation error
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("which", ["mesh_lsq", "mesh_gg"])
def test_linear_field_reproduced(which, request):
    tm = request.getfixturevalue(which)
    c = tm.cells
    np.testing.assert_allclose(c.gradient, np.broadcast_to(G, c.gradient.shape), rtol=0, atol=1e-9)
    np.testing.assert_allclose(c.media_ref, linear_m(c.ref_point), rtol=0, atol=1e-12)
    rng = np.random.default_rng(7)
    cells, xyz = random_points_in_cells(tm, rng)
    model = c.media_ref[cells] + np.einsum("ni,ni->n", xyz - c.ref_point[cells], c.gradient[cells])
    np.testing.assert_allclose(model, linear_m(xyz), rtol=0, atol=1e-9)
    for k in rng.integers(0, c.n_cells, 5):
        sel = cells == k
        np.testing.assert_allclose(c.media_at(int(k), xyz[sel]), linear_m(xyz[sel]), rtol=0, atol=1e-9)
    grid = np.stack(np.meshgrid(*[np.linspace(LO[i], HI[i], 9) for i in range(3)], indexing="ij"), -1)
    grid = grid.reshape(-1, 3)
    err = approximation_error(tm, grid, linear_m(grid))
    assert err["n_outside"] == 0 and err["n_inside"] == len(grid)
    assert err["rel_error_barycentric"] < 1e-14
    assert err["rel_error_cell_linear"] < 1e-14


def test_approximation_error_decreases_with_spacing():
    def m(x):
        return np.exp(-x[:, 2] / 20.0)

    rng = np.random.default_rng(11)
    grid = LO + rng.random((3000, 3)) * (HI - LO)
    outside = np.array([[-1.0, 5.0, 5.0], [5.0, 5.0, 61.0]])
    errs = []
    for d in (16.0, 8.0):
        pts = fcc_resample(LO, HI, const(d), d_min=1.0, d_max=100.0)
        tm = build_tet_mesh(LO, HI, pts, m, spacing=const(d))
        e = approximation_error(tm, np.concatenate([grid, outside]), m(np.concatenate([grid, outside])))
        assert e["n_outside"] == 2 and e["n_inside"] == len(grid)
        errs.append(e)
    # P1 interpolation is second order: halving d divides the error by ~4 (measured 0.24, 0.24).
    for key in ("rel_error_barycentric", "rel_error_cell_linear"):
        assert 0 < errs[1][key] < 0.35 * errs[0][key]


def test_lsq_fallback_and_green_gauss():
    # Two tets sharing a face: each has one neighbour, so least squares must fall back.
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float)
    tets = np.array([[0, 1, 2, 3], [4, 1, 2, 3]])
    vals = linear_m(pts)
    gg = green_gauss_gradients(pts, tets, vals)
    np.testing.assert_allclose(gg, np.broadcast_to(G, (2, 3)), atol=1e-14)
    cen = pts[tets].mean(axis=1)
    nb = np.array([[1, -1, -1, -1], [0, -1, -1, -1]])
    g, fb = lsq_gradients(cen, vals[tets].mean(axis=1), nb)
    assert fb.all() and np.isnan(g).all()
    g, fb = lsq_gradients(cen, vals[tets].mean(axis=1), nb, fallback=gg)
    np.testing.assert_array_equal(g, gg)


# ---------------------------------------------------------------------------------------------------
# Point location
# ---------------------------------------------------------------------------------------------------
def test_locate_points_finds_containing_cell(mesh_lsq):
    tm = mesh_lsq
    c = tm.cells
    rng = np.random.default_rng(5)
    xyz = LO + rng.random((150, 3)) * (HI - LO)
    found = locate_points(c, xyz)
    assert np.all(found >= 0)
    viol = np.einsum("nfk,nk->nf", c.planes[found, :, :3], xyz) - c.planes[found, :, 3]
    assert np.all(viol.max(axis=1) <= 1e-9 * c.size[found])
    walk, bary = locate_tets(tm, xyz)
    np.testing.assert_array_equal(walk, found)
    assert np.all(bary >= -1e-10)
    np.testing.assert_allclose(np.einsum("ni,nij->nj", bary, tm.points[tm.tets[walk]]), xyz, atol=1e-9)
    out, _ = locate_tets(tm, np.array([[50.0, 40.0, -0.5], [101.0, 40.0, 30.0]]))
    assert np.all(out == -1)

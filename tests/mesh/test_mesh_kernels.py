"""Compiled mesh kernels against their numpy oracles (engine/mesh/lsq_kernel.py, gradients.py, prisms.py).

References: the numpy formulas they replace, written out here (means, normal-equation einsums, LAPACK
eigvalsh decisions, a lexicographic sort for the face pairing, numpy dihedral angles and volumes),
``gradients.lsq_gradients`` itself, scipy's Delaunay neighbours and a linear field's exact gradient.
"""

from __future__ import annotations

import bentray  # noqa: F401  # isort: skip  (sets OPENBLAS_NUM_THREADS before numpy / scipy load)
import numpy as np
import pytest
from scipy.spatial import Delaunay

from bentray.engine.errors import MeshBuildError
from bentray.engine.mesh import prisms
from bentray.engine.mesh.gradients import (
    LSQ_RCOND_MIN,
    cell_media,
    green_gauss_gradients,
    lsq_gradients,
    lsq_gradients_compiled,
)
from bentray.engine.mesh.lsq_kernel import (
    EIG_MARGIN,
    LSQ_ACCEPT,
    LSQ_REJECT,
    LSQ_UNDECIDED,
    _sym3_extreme_eigenvalues,
    cell_centroids,
    lsq_systems,
)
from bentray.engine.mesh.prisms import face_planes, face_vertices, match_faces

G = np.array([0.3, -0.2, 0.5])


@pytest.fixture(scope="module")
def random_mesh():
    """Delaunay tets of jittered random points in a 100 x 80 x 60 m box (irregular cells, many
    ill-conditioned least-squares systems), with scipy's neighbours (-1 on the hull)."""
    rng = np.random.default_rng(7)
    pts = rng.random((3000, 3)) * np.array([100.0, 80.0, 60.0])
    tri = Delaunay(pts)
    return pts, tri.simplices.astype(np.int64), tri.neighbors.astype(np.int64)


def oracle_normal_equations(x0, m0, nb, weighted):
    """``lsq_gradients``' A (n, 3, 3) and b (n, 3), and its count of usable neighbours (n,)."""
    valid = nb >= 0
    j = np.where(valid, nb, 0)
    dx = x0[j] - x0[:, None, :]
    dm = m0[j] - m0[:, None]
    dist = np.linalg.norm(dx, axis=2)
    valid &= dist > 0
    w = np.where(valid, 1.0 / np.where(valid, dist, 1.0), 0.0) if weighted else valid.astype(np.float64)
    rows = dx * w[:, :, None]
    return np.einsum("nki,nkj->nij", rows, rows), np.einsum("nki,nk->ni", rows, dm * w), valid.sum(axis=1)


def test_centroids_are_the_numpy_means_bit_for_bit(random_mesh):
    pts, tets, _ = random_mesh
    vals = np.exp(-pts[:, 2] / 20.0) + np.sin(pts[:, 0] / 7.0)
    cen, ref = cell_centroids(pts, tets, vals)
    np.testing.assert_array_equal(cen, pts[tets].mean(axis=1))
    np.testing.assert_array_equal(ref, vals[tets].mean(axis=1))


@pytest.mark.parametrize("weighted", [True, False])
def test_normal_equations_and_decisions_match_numpy(random_mesh, weighted):
    pts, tets, nb = random_mesh
    vals = np.exp(-pts[:, 2] / 20.0) + np.sin(pts[:, 0] / 7.0)
    cen, ref = pts[tets].mean(axis=1), vals[tets].mean(axis=1)
    a, b, status = lsq_systems(cen, ref, nb, weighted, LSQ_RCOND_MIN)
    a0, b0, count = oracle_normal_equations(cen, ref, nb, weighted)
    np.testing.assert_array_equal(a, a0)
    np.testing.assert_array_equal(b, b0)
    lam = np.linalg.eigvalsh(a0)
    good = (count >= 3) & (lam[:, 2] > 0) & (lam[:, 0] >= LSQ_RCOND_MIN * lam[:, 2])
    decided = status != LSQ_UNDECIDED
    np.testing.assert_array_equal(status[decided] == LSQ_ACCEPT, good[decided])
    assert np.all(status[count < 3] == LSQ_REJECT)
    # both outcomes occur (fallbacks: mostly hull cells), and only cells near the threshold are undecided
    assert good.sum() > 0.5 * len(good) and (~good).sum() > 100
    ratio = lam[:, 0] / lam[:, 2]
    assert np.all(np.abs(ratio[~decided] - LSQ_RCOND_MIN) <= 2 * EIG_MARGIN)


@pytest.mark.parametrize("method", ["lsq", "lsq_unweighted"])
def test_compiled_gradients_are_lsq_gradients_bit_for_bit(random_mesh, method):
    pts, tets, nb = random_mesh
    vals = np.exp(-pts[:, 2] / 20.0) + np.sin(pts[:, 0] / 7.0)
    cen, ref = pts[tets].mean(axis=1), vals[tets].mean(axis=1)
    fallback = np.full((len(tets), 3), 7.0)
    g0, fb0 = lsq_gradients(cen, ref, nb, weighted=method == "lsq", fallback=fallback)
    g1, fb1 = lsq_gradients_compiled(cen, ref, nb, weighted=method == "lsq", fallback=fallback)
    np.testing.assert_array_equal(fb1, fb0)
    np.testing.assert_array_equal(g1, g0)
    _, _, _, g2, n_fb = cell_media(pts, tets, nb, lambda p: np.exp(-p[:, 2] / 20.0) + np.sin(p[:, 0] / 7.0), method)
    assert n_fb == fb0.sum()
    np.testing.assert_array_equal(g2[~fb0], g0[~fb0])
    np.testing.assert_array_equal(g2[fb0], green_gauss_gradients(pts, tets[fb0], vals))


def test_green_gauss_cells_are_green_gauss_gradients_bit_for_bit(random_mesh):
    pts, tets, nb = random_mesh
    vals = np.exp(-pts[:, 2] / 20.0) + np.sin(pts[:, 0] / 7.0)
    _, _, _, g, n_fb = cell_media(pts, tets, nb, lambda p: np.exp(-p[:, 2] / 20.0) + np.sin(p[:, 0] / 7.0),
                                  "green_gauss")  # fmt: skip
    assert n_fb == 0
    np.testing.assert_array_equal(g, green_gauss_gradients(pts, tets, vals))


def test_compiled_gradients_are_exact_on_a_linear_field(random_mesh):
    pts, tets, nb = random_mesh
    _, ref, cen, grad, n_fb = cell_media(pts, tets, nb, lambda p: 2.0 + p @ G, "lsq")
    _, fb = lsq_gradients_compiled(cen, ref, nb)
    assert n_fb == fb.sum() > 0
    np.testing.assert_allclose(ref, 2.0 + cen @ G, rtol=0, atol=1e-13 * np.abs(ref).max())
    # least squares (lambda_min / lambda_max >= 1e-3): 1e-12 relative; the Green-Gauss fallback cells
    # include random Delaunay's slivers, whose own P1 gradient carries ~1e-11 of rounding
    err = np.linalg.norm(grad - G, axis=1) / np.linalg.norm(G)
    assert err[~fb].max() <= 1e-12 and err[fb].max() <= 1e-9, (err[~fb].max(), err[fb].max())


def test_undecided_cells_near_the_threshold_take_lapacks_decision():
    # Cell 0 at the origin, neighbours along x, y and (0, cos t, sin t): lambda_min / lambda_max sweeps
    # through LSQ_RCOND_MIN as t shrinks; every cell's decision must be eigvalsh's.
    t = np.linspace(0.02, 0.12, 4001)
    n = len(t)
    cen = np.zeros((4 * n, 3))
    cen[1::4, 0] = 1.0
    cen[2::4, 1] = 2.0
    cen[3::4, 1], cen[3::4, 2] = 1.5 * np.cos(t), 1.5 * np.sin(t)
    nb = np.full((4 * n, 4), -1, dtype=np.int64)
    nb[0::4, :3] = np.arange(4 * n).reshape(n, 4)[:, 1:]
    vals = np.arange(4 * n, dtype=np.float64)
    a, _, status = lsq_systems(cen, vals, nb, True, LSQ_RCOND_MIN)
    lam = np.linalg.eigvalsh(a[0::4])
    good = lam[:, 0] >= LSQ_RCOND_MIN * lam[:, 2]
    assert 0 < good.sum() < n and np.any(status[0::4] == LSQ_UNDECIDED)
    _, fb = lsq_gradients_compiled(cen, vals, nb)
    np.testing.assert_array_equal(~fb[0::4], good)


def test_decisions_on_flattened_stars_spanning_the_threshold():
    # 20000 cells, each at the origin of its own star of 4 neighbours whose directions are squashed
    # toward a plane (z scaled by 10^-3..10^0, sometimes also y): lambda_min / lambda_max spans the
    # threshold; invariant tests, closed form and LAPACK hand-over must all agree with eigvalsh.
    rng = np.random.default_rng(5)
    n = 20000
    d = rng.standard_normal((n, 4, 3))
    d[:, :, 2] *= 10.0 ** rng.uniform(-3, 0, (n, 1))
    d[: n // 4, :, 1] *= 10.0 ** rng.uniform(-2, 0, (n // 4, 1))
    cen = np.zeros((5 * n, 3))
    cen.reshape(n, 5, 3)[:, 1:] = d * rng.uniform(0.5, 20.0, (n, 4, 1))
    nb = np.full((5 * n, 4), -1, dtype=np.int64)
    nb[0::5] = np.arange(5 * n).reshape(n, 5)[:, 1:]
    vals = rng.standard_normal(5 * n)
    for weighted in (True, False):
        a, _, status = lsq_systems(cen, vals, nb, weighted, LSQ_RCOND_MIN)
        lam = np.linalg.eigvalsh(a[0::5])
        good = lam[:, 0] >= LSQ_RCOND_MIN * lam[:, 2]
        st = status[0::5]
        assert 0.2 < good.mean() < 0.8 and (st == LSQ_UNDECIDED).mean() < 0.01
        decided = st != LSQ_UNDECIDED
        np.testing.assert_array_equal(st[decided] == LSQ_ACCEPT, good[decided])
        _, fb = lsq_gradients_compiled(cen, vals, nb, weighted)
        np.testing.assert_array_equal(~fb[0::5], good)


def test_closed_form_eigenvalues_are_within_a_hundredth_of_the_margin():
    # random PSD matrices, and near-repeated eigenvalues (acos loses half the digits there)
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.standard_normal((3000, 3, 3)))
    lam = rng.random((3000, 3)) * 4.0
    lam[1000:2000, 1] = lam[1000:2000, 0] * (1 + 1e-9 * rng.standard_normal(1000))
    lam[2000:, 1] = lam[2000:, 2] * (1 + 1e-9 * rng.standard_normal(1000))
    lam[::7, 0] = 1e-3 * lam[::7].max(axis=1)
    a = np.einsum("nij,nj,nkj->nik", q, lam, q)
    a = 0.5 * (a + a.transpose(0, 2, 1))
    ref = np.linalg.eigvalsh(a)
    got = np.array([_sym3_extreme_eigenvalues(m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2]) for m in a])
    err = np.abs(got - ref[:, [0, 2]]).max(axis=1) / ref[:, 2]
    assert err.max() <= EIG_MARGIN / 100, err.max()


def oracle_pairs(faces):
    """Neighbour and neighbour-face tables (T, 4) from a lexicographic sort of the sorted faces."""
    f = faces.reshape(-1, 3)
    order = np.lexsort((f[:, 2], f[:, 1], f[:, 0]))
    same = np.flatnonzero(np.all(f[order][1:] == f[order][:-1], axis=1))
    nb = np.full(len(f), -1)
    nf = np.full(len(f), -1)
    s1, s2 = order[same], order[same + 1]
    nb[s1], nf[s1], nb[s2], nf[s2] = s2 // 4, s2 % 4, s1 // 4, s1 % 4
    return nb.reshape(-1, 4), nf.reshape(-1, 4)


def test_match_faces_pairs_faces_as_a_sort_does(random_mesh, monkeypatch):
    pts, tets, nb_scipy = random_mesh
    faces = face_vertices(tets)
    nb, nf = match_faces(faces, 1, len(pts))
    nb0, nf0 = oracle_pairs(faces)
    np.testing.assert_array_equal(nb, nb0)
    np.testing.assert_array_equal(nf, nf0)
    np.testing.assert_array_equal(nb, nb_scipy)  # scipy's neighbour i is opposite vertex i, as here
    with pytest.raises(MeshBuildError, match="more than two cells"):
        match_faces(face_vertices(np.vstack([tets, tets[:1]])), 1, len(pts))
    # large buckets (a vertex's fan) are paired by a sort: force it for every bucket
    monkeypatch.setattr(prisms, "PAIR_SCAN_MAX", 0)
    nb1, nf1 = match_faces(faces, 1, len(pts))
    np.testing.assert_array_equal(nb1, nb0)
    np.testing.assert_array_equal(nf1, nf0)
    with pytest.raises(MeshBuildError, match="more than two cells"):
        match_faces(face_vertices(np.vstack([tets, tets[:1]])), 1, len(pts))


def test_face_planes_quality_against_numpy(random_mesh):
    pts, tets, _ = random_mesh
    tets = tets.copy()
    p = pts[tets]
    flip = np.linalg.det(p[:, 1:] - p[:, :1]) < 0
    tets[flip, :2] = tets[flip, 1::-1]  # positively oriented
    faces = face_vertices(tets)
    nb, nf = match_faces(faces, 1, len(pts))
    planes, qual = face_planes(pts, tets, faces, nb, nf)
    p = pts[tets]
    np.testing.assert_allclose(qual["volume"], np.linalg.det(p[:, 1:] - p[:, :1]) / 6.0, rtol=1e-12)
    i, j = np.triu_indices(4, 1)
    cos = -np.einsum("tpk,tpk->tp", planes[:, i, :3], planes[:, j, :3])
    dihedral = np.degrees(np.arccos(np.clip(cos, -1, 1))).min(axis=1)
    assert qual["summary"]["min_dihedral_deg"]["min"] == pytest.approx(dihedral.min(), rel=1e-12)
    assert qual["summary"]["min_dihedral_deg"]["median"] == pytest.approx(np.median(dihedral), rel=1e-12)
    longest = np.linalg.norm(p[:, i] - p[:, j], axis=2).max(axis=1)
    np.testing.assert_array_equal(qual["longest_edge"], longest)
    fp = pts[faces]  # (T, 4, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(fp[:, :, 1] - fp[:, :, 0], fp[:, :, 2] - fp[:, :, 0]), axis=2)
    aspect = longest / (3.0 * np.abs(np.linalg.det(p[:, 1:] - p[:, :1])) / 6.0 / area.max(axis=1))
    for key, value in (("median", np.median(aspect)), ("p99", np.percentile(aspect, 99)), ("max", aspect.max())):
        assert qual["summary"]["aspect"][key] == pytest.approx(value, rel=1e-9)
    # a shared face whose two planes are not exact opposites is caught, whichever of its cells is changed
    assert prisms._count_unpaired_planes(planes, nb, nf) == 0
    cell = np.arange(len(tets))[:, None]
    for t, f in (np.argwhere(nb > cell)[0], np.argwhere((nb >= 0) & (nb < cell))[0]):
        bad = planes.copy()
        bad[t, f, 3] = np.nextafter(bad[t, f, 3], np.inf)
        assert prisms._count_unpaired_planes(bad, nb, nf) > 0

"""The vectorised exit search of a tetrahedron (engine/kernels/face_roots4.py) against the scalar face loops.

Oracles: curves.find_exit (the generic kernel's loop, parabolic curve; no skip) for exit_of_tet_planes and
exit_of_cell_planes, and
lean._exit_search, the face-by-face loop (roots.face_exit_parameter per face, faces with A <= 0 and
B <= 0 and unused faces skipped, the smallest parameter first on ties) that the lean kernel ran for every
cell before and still runs for cells that are not tetrahedra. ``exit_of_tet`` must return the same
parameter *bit for bit* and the same face for every input: random tetrahedra with points inside, on faces
and outside, every entry face, unused faces, and coefficients set to the special values where the scalar
code branches (+-0, nan, +-inf, subnormal and huge numbers), plus a hypothesis search over single cases.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bentray.engine.constants import CURVE_PARABOLIC, FACE_UNUSED
from bentray.engine.kernels import curves
from bentray.engine.kernels.face_roots4 import exit_of_cell8, exit_of_cell_planes, exit_of_tet, exit_of_tet_planes
from bentray.engine.kernels.lean import _exit_search
from bentray.engine.mesh.packed import record_width

K = 4
O_NB = 4 * K + 8
WIDTH = record_width(K)
SPECIAL = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 5e-324, -2.2e-308, 1e-160, 1e150, -1e300, 1.0, -1.0])


@nb.njit(cache=False)
def _both(rec, g, p0, x, entry, tol, out_p, out_f):
    """Per case i: the vector search (columns 0) and the scalar loop (columns 1) on row i of rec."""
    for i in range(rec.shape[0]):
        pv, fv = exit_of_tet(
            rec,
            i,
            g[i, 0],
            g[i, 1],
            g[i, 2],
            p0[i, 0],
            p0[i, 1],
            p0[i, 2],
            x[i, 0],
            x[i, 1],
            x[i, 2],
            entry[i],
            tol[i],
            O_NB,
        )
        gi = (g[i, 0], g[i, 1], g[i, 2])
        pi = (p0[i, 0], p0[i, 1], p0[i, 2])
        xi = (x[i, 0], x[i, 1], x[i, 2])
        ps, fs = _exit_search(rec, i, K, O_NB, gi, pi, xi, entry[i], tol[i])
        out_p[i, 0], out_p[i, 1] = pv, ps
        out_f[i, 0], out_f[i, 1] = fv, fs


def _generic_pair(search):
    """An njit helper: ``search`` (exit_of_tet_planes or exit_of_cell_planes, column 0) and curves.find_exit (column
    1) on cell i's planes (n, K, 4) and neighbours (n, K)."""

    @nb.njit(cache=False)
    def both(planes, neighbours, g, p0, x, entry, tol, out_p, out_f):
        cs = np.zeros(12)
        d = np.zeros(3)
        for i in range(planes.shape[0]):
            pv, fv = search(
                planes[i], neighbours[i], g[i, 0], g[i, 1], g[i, 2], p0[i, 0], p0[i, 1], p0[i, 2], x[i, 0], x[i, 1],
                x[i, 2], entry[i], tol[i],
            )  # fmt: skip
            cs[0:3] = p0[i]
            cs[3:6] = g[i]
            fs, ps = curves.find_exit(CURVE_PARABOLIC, cs, x[i], d, planes[i], neighbours[i], entry[i], tol[i], 1.0)
            out_p[i, 0], out_p[i, 1] = pv, ps
            out_f[i, 0], out_f[i, 1] = fv, fs

    return both


_both_generic = _generic_pair(exit_of_tet_planes)
_both_generic8 = _generic_pair(exit_of_cell_planes)


def _records(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """n packed tetrahedron records (planes outward, unit normals; neighbours 0..3) and their vertices."""
    rec = np.zeros((n, WIDTH))
    verts = rng.normal(size=(n, 4, 3)) * rng.choice([1e-3, 1.0, 30.0], size=(n, 1, 1))
    centroid = verts.mean(axis=1)
    for f in range(K):
        others = np.delete(verts, f, axis=1)
        m = np.cross(others[:, 1] - others[:, 0], others[:, 2] - others[:, 0])
        m /= np.linalg.norm(m, axis=1)[:, None]
        h = np.einsum("ij,ij->i", m, others[:, 0])
        flip = np.einsum("ij,ij->i", m, centroid) > h
        m[flip] *= -1.0
        h[flip] *= -1.0
        rec[:, 4 * f : 4 * f + 3] = m
        rec[:, 4 * f + 3] = h
        rec[:, O_NB + f] = f
    return rec, verts


def _compare(rec, g, p0, x, entry, tol) -> tuple[np.ndarray, np.ndarray]:
    """Both searches against their scalar loops on the same cases; returns the scalar (parameter, face)."""
    n = rec.shape[0]
    entry = entry.astype(np.int64)
    planes = np.ascontiguousarray(rec[:, :16].reshape(n, 4, 4))
    neighbours = np.ascontiguousarray(rec[:, O_NB : O_NB + K].astype(np.int64))
    pairs = (
        ("exit_of_tet", _both, (np.ascontiguousarray(rec),)),
        ("exit_of_tet_planes", _both_generic, (planes, neighbours)),
    )
    for name, kernel, args in pairs:
        out_p = np.empty((n, 2))
        out_f = np.empty((n, 2), dtype=np.int64)
        kernel(*args, g, p0, x, entry, tol, out_p, out_f)
        _assert_same(out_p, out_f, name)
    return out_p[:, 1], out_f[:, 1]


def _assert_same(out_p: np.ndarray, out_f: np.ndarray, name: str) -> None:
    n = out_p.shape[0]
    same_p = (out_p[:, 0] == out_p[:, 1]) | (np.isnan(out_p[:, 0]) & np.isnan(out_p[:, 1]))
    same_sign = np.signbit(out_p[:, 0]) == np.signbit(out_p[:, 1])
    bad = ~(same_p & same_sign & (out_f[:, 0] == out_f[:, 1]))
    assert not bad.any(), (
        f"{name}: {int(bad.sum())} of {n} cases differ; first: vector {out_p[bad][0, 0]!r} face "
        f"{out_f[bad][0, 0]}, scalar {out_p[bad][0, 1]!r} face {out_f[bad][0, 1]}"
    )


def test_random_tets_points_inside_on_faces_and_outside() -> None:
    rng = np.random.default_rng(7)
    n = 40_000
    rec, verts = _records(n, rng)
    w = rng.dirichlet(np.ones(4), size=n)
    kind = rng.integers(0, 4, size=n)
    w[kind == 1, rng.integers(0, 4, size=int((kind == 1).sum()))] = 0.0  # on a face (up to rounding)
    w /= w.sum(axis=1)[:, None]
    x = np.einsum("ij,ijk->ik", w, verts)
    x[kind == 2] += rng.normal(size=(int((kind == 2).sum()), 3))  # outside
    x[kind == 3] = verts[np.arange(n), rng.integers(0, 4, size=n)][kind == 3]  # on a vertex
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    n0 = rng.uniform(0.9, 1.1, size=n)
    p0 = d * n0[:, None]
    g = rng.normal(size=(n, 3)) * rng.choice([0.0, 1e-6, 1e-3, 1.0, 1e3], size=(n, 1))
    g[rng.random(n) < 0.1, :2] = 0.0  # vertical gradients: faces parallel to it give A = 0
    entry = rng.integers(-1, 4, size=n)
    tol = 1e-9 * rng.choice([0.0, 1.0, 30.0], size=n)
    param, face = _compare(rec, g, p0, x, entry, tol)
    assert (face >= 0).mean() > 0.6 and (param == 0.0).any() and np.isinf(param).any()  # the cases were varied


def test_special_values_and_unused_faces() -> None:
    rng = np.random.default_rng(11)
    n = 60_000
    rec, verts = _records(n, rng)
    x = verts.mean(axis=1) + rng.normal(size=(n, 3)) * 0.1
    p0 = rng.normal(size=(n, 3))
    g = rng.normal(size=(n, 3))
    entry = rng.integers(-1, 4, size=n)
    tol = rng.choice([0.0, 1e-9, 1e-3], size=n)
    # set random coefficients to the values where the scalar code branches
    for arr in (rec[:, :16], x, p0, g):
        hit = rng.random(arr.shape) < 0.12
        arr[hit] = rng.choice(SPECIAL, size=int(hit.sum()))
    # exactly tangent and exactly on-face cases: B = 0 (p0 in the face plane), C = 0 (x on the plane)
    sel = rng.random(n) < 0.2
    f = rng.integers(0, 4, size=n)
    m = np.stack([rec[np.arange(n), 4 * f + k] for k in range(3)], axis=1)
    with np.errstate(all="ignore"):  # the special values make nan and inf products, as intended
        p0[sel] = np.cross(m[sel], rng.normal(size=(int(sel.sum()), 3)))
    unused = rng.random((n, K)) < 0.1
    rec[:, O_NB : O_NB + K][unused] = FACE_UNUSED
    _compare(rec, g, p0, x, entry, tol)


_finite_or_special = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from([float(v) for v in SPECIAL]),
    st.floats(-10.0, 10.0),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    planes=st.lists(_finite_or_special, min_size=16, max_size=16),
    vec=st.lists(_finite_or_special, min_size=9, max_size=9),
    entry=st.integers(-1, 3),
    tol=st.sampled_from([0.0, 1e-12, 1e-3, math.inf]),
    unused=st.lists(st.booleans(), min_size=4, max_size=4),
)
def test_any_coefficients(planes, vec, entry, tol, unused) -> None:
    rec = np.zeros((1, WIDTH))
    rec[0, :16] = planes
    rec[0, O_NB : O_NB + K] = [FACE_UNUSED if u else f for f, u in enumerate(unused)]
    v = np.array(vec).reshape(3, 3)
    _compare(rec, v[0:1].copy(), v[1:2].copy(), v[2:3].copy(), np.array([entry]), np.array([tol]))


@pytest.mark.parametrize("entry", [-1, 0, 2])
def test_a_tet_by_hand(entry: int) -> None:
    """The unit corner tet, a ray along +x from inside, no gradient: it leaves through the slanted face
    x + y + z = 1 at sigma = (1 - 0.3) / |p| (the oracle-free check that both agree on a known answer)."""
    rec = np.zeros((1, WIDTH))
    s3 = 1.0 / math.sqrt(3.0)
    planes = [(-1.0, 0.0, 0.0, 0.0), (0.0, -1.0, 0.0, 0.0), (0.0, 0.0, -1.0, 0.0), (s3, s3, s3, s3)]
    for f, (mx, my, mz, h) in enumerate(planes):
        rec[0, 4 * f : 4 * f + 4] = (mx, my, mz, h)
        rec[0, O_NB + f] = f
    x = np.array([[0.1, 0.1, 0.1]])
    p0 = np.array([[1.0, 0.0, 0.0]])
    param, face = _compare(rec, np.zeros((1, 3)), p0, x, np.array([entry]), np.array([1e-12]))
    assert face[0] == 3
    assert param[0] == pytest.approx(0.7, rel=1e-14)


@nb.njit(cache=False)
def _both8(rec, k_faces, g, p0, x, entry, tol, out_p, out_f):
    """exit_of_cell8 (column 0) and the scalar loop (column 1) on rows of K-face records (4 < K <= 8)."""
    o_nb = 4 * k_faces + 8
    for i in range(rec.shape[0]):
        pv, fv = exit_of_cell8(
            rec, i, g[i, 0], g[i, 1], g[i, 2], p0[i, 0], p0[i, 1], p0[i, 2], x[i, 0], x[i, 1], x[i, 2], entry[i],
            tol[i], o_nb, k_faces,
        )  # fmt: skip
        gi = (g[i, 0], g[i, 1], g[i, 2])
        pi = (p0[i, 0], p0[i, 1], p0[i, 2])
        xi = (x[i, 0], x[i, 1], x[i, 2])
        ps, fs = _exit_search(rec, i, k_faces, o_nb, gi, pi, xi, entry[i], tol[i])
        out_p[i, 0], out_p[i, 1] = pv, ps
        out_f[i, 0], out_f[i, 1] = fv, fs


@pytest.mark.parametrize("k_faces", [5, 6, 7, 8])
def test_cells_of_five_to_eight_faces(k_faces: int) -> None:
    """Two groups of four faces, the faces beyond K masked (their rows and slots hold the record's other fields,
    here random numbers), the second group taken only where strictly smaller; random and special values, ties
    between faces (equal planes), unused faces, every entry face."""
    rng = np.random.default_rng(k_faces)
    n = 20_000
    width = record_width(k_faces)
    o_nb = 4 * k_faces + 8
    rec = rng.normal(size=(n, width))
    m = rng.normal(size=(n, k_faces, 3))
    m /= np.linalg.norm(m, axis=2)[:, :, None]
    rec[:, : 4 * k_faces : 4], rec[:, 1 : 4 * k_faces : 4], rec[:, 2 : 4 * k_faces : 4] = (
        m[..., 0],
        m[..., 1],
        m[..., 2],
    )
    rec[:, 3 : 4 * k_faces : 4] = rng.uniform(0.1, 2.0, size=(n, k_faces))
    dup = rng.random(n) < 0.1  # a face repeated later: a tie the first must win
    rec[dup, 4 * (k_faces - 1) : 4 * k_faces] = rec[dup, 0:4]
    rec[:, o_nb : o_nb + k_faces] = np.arange(k_faces)
    rec[:, o_nb : o_nb + k_faces][rng.random((n, k_faces)) < 0.1] = FACE_UNUSED
    x = rng.normal(size=(n, 3)) * 0.3
    p0 = rng.normal(size=(n, 3))
    g = rng.normal(size=(n, 3)) * rng.choice([0.0, 1e-3, 1.0], size=(n, 1))
    g[rng.random(n) < 0.3, :2] = 0.0
    for arr in (rec[:, : 4 * k_faces], x, p0, g):
        hit = rng.random(arr.shape) < 0.03
        arr[hit] = rng.choice(SPECIAL, size=int(hit.sum()))
    entry = rng.integers(-1, k_faces, size=n).astype(np.int64)
    tol = rng.choice([0.0, 1e-9, 1e-3], size=n)
    out_p = np.empty((n, 2))
    out_f = np.empty((n, 2), dtype=np.int64)
    _both8(np.ascontiguousarray(rec), k_faces, g, p0, x, entry, tol, out_p, out_f)
    _assert_same(out_p, out_f, f"exit_of_cell8 K={k_faces}")
    assert (out_f[:, 1] >= 4).any() and (out_f[:, 1] < 4).any() and (out_f[:, 1] == -1).any()


def test_strided_planes_in_the_generic_form() -> None:
    """A mesh built from slices gives the generic kernel strided per-cell views: exit_of_tet_planes gathers them
    one by one and must still equal curves.find_exit."""
    rng = np.random.default_rng(13)
    n = 5_000
    rec, verts = _records(n, rng)
    wide = np.zeros((n, 4, 8))
    wide[:, :, :4] = rec[:, :16].reshape(n, 4, 4)
    planes = wide[:, :, :4]  # (n, 4, 4) with a row stride of 8 doubles: not C-contiguous
    assert not planes.flags.c_contiguous
    neighbours = np.ascontiguousarray(rec[:, O_NB : O_NB + K].astype(np.int64))
    x = verts.mean(axis=1) + rng.normal(size=(n, 3)) * 0.05
    p0 = rng.normal(size=(n, 3))
    g = rng.normal(size=(n, 3))
    entry = rng.integers(-1, 4, size=n).astype(np.int64)
    tol = np.full(n, 1e-9)
    out_p = np.empty((n, 2))
    out_f = np.empty((n, 2), dtype=np.int64)
    _both_generic(planes, neighbours, g, p0, x, entry, tol, out_p, out_f)
    _assert_same(out_p, out_f, "exit_of_tet_planes, strided")
    assert (out_f[:, 1] >= 0).mean() > 0.5


@pytest.mark.parametrize("k_faces", [5, 6, 7, 8])
@pytest.mark.parametrize("strided", [False, True])
def test_generic_cells_of_five_to_eight_faces(k_faces: int, strided: bool) -> None:
    """The generic kernel's per-cell (K, 4) views for slab boxes and prisms: two groups of four faces, the rows past
    K read at K - 1 and masked (the last cell's view ends the array: nothing beyond it may decide), against
    curves.find_exit on random and special values, ties (a face repeated later), unused faces, every entry face,
    C-contiguous and strided views."""
    rng = np.random.default_rng(100 + k_faces + 10 * strided)
    n = 20_000
    m = rng.normal(size=(n, k_faces, 3))
    m /= np.linalg.norm(m, axis=2)[:, :, None]
    planes = np.empty((n, k_faces, 4))
    planes[..., :3] = m
    planes[..., 3] = rng.uniform(0.1, 2.0, size=(n, k_faces))
    dup = rng.random(n) < 0.1  # a face repeated later: a tie the first must win
    planes[dup, k_faces - 1] = planes[dup, 0]
    neighbours = np.tile(np.arange(k_faces, dtype=np.int64), (n, 1))
    neighbours[rng.random((n, k_faces)) < 0.1] = FACE_UNUSED
    x = rng.normal(size=(n, 3)) * 0.3
    p0 = rng.normal(size=(n, 3))
    g = rng.normal(size=(n, 3)) * rng.choice([0.0, 1e-3, 1.0], size=(n, 1))
    g[rng.random(n) < 0.3, :2] = 0.0
    for arr in (planes, x, p0, g):
        hit = rng.random(arr.shape) < 0.03
        arr[hit] = rng.choice(SPECIAL, size=int(hit.sum()))
    if strided:
        wide = np.full((n, k_faces, 8), np.nan)
        wide[:, :, :4] = planes
        planes = wide[:, :, :4]
        assert not planes.flags.c_contiguous
    entry = rng.integers(-1, k_faces, size=n).astype(np.int64)
    tol = rng.choice([0.0, 1e-9, 1e-3], size=n)
    out_p = np.empty((n, 2))
    out_f = np.empty((n, 2), dtype=np.int64)
    _both_generic8(planes, neighbours, g, p0, x, entry, tol, out_p, out_f)
    _assert_same(out_p, out_f, f"exit_of_cell_planes K={k_faces} strided={strided}")
    assert (out_f[:, 1] >= 4).any() and (out_f[:, 1] < 4).any() and (out_f[:, 1] == -1).any()

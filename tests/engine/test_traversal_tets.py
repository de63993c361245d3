"""Traversal through Delaunay tetrahedra: exactness where the mesh is exact, and robustness at
vertices, edges and faces (the rounding cases of docs/physics.md §5).

References: straight lines and the mirror-image source (homogeneous medium, flat ground), and the
single-slab trace of an exactly linear medium (itself checked against DOP853 to 1e-9 elsewhere).
"""

from __future__ import annotations

import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine.constants import STATUS_LOST, STATUS_TIME_LIMIT
from bentray.engine.mesh.cells import locate_points, validate_cell_mesh
from bentray.engine.mesh.fcc import fcc_resample
from bentray.engine.mesh.slabs import build_slab_mesh
from bentray.engine.mesh.tets import build_tet_mesh
from bentray.engine.tracer import trace

LO = np.array([0.0, 0.0, 0.0])
HI = np.array([200.0, 160.0, 120.0])
C_REF = 340.0


def _tet_mesh(quantity, d=18.0):
    pts = fcc_resample(LO, HI, lambda x: np.full(len(x), d), d_min=d, d_max=d)
    return build_tet_mesh(LO, HI, pts, quantity, spacing=lambda x: np.full(len(x), d))


@pytest.fixture(scope="module")
def homogeneous_tets():
    tm = _tet_mesh(lambda x: np.ones(len(x)))
    validate_cell_mesh(tm.cells)
    return tm


def _image_source_position(src, direction, t):
    """Straight ray in homogeneous air (c = C_REF) over the ground z = 0: unfold by mirroring."""
    p = src + C_REF * t * direction
    reflections = 0
    if p[2] < 0:
        p = p * np.array([1, 1, -1])
        reflections = 1
    return p, reflections


def _fan(n_el=13, n_az=9):
    el, az = np.meshgrid(np.radians(np.linspace(-60, 60, n_el)), np.radians(np.linspace(-80, 80, n_az)))
    el, az = el.ravel(), az.ravel()
    return np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


@pytest.mark.parametrize("where", ["vertex", "edge", "face", "interior"])
def test_straight_rays_from_vertices_edges_and_faces(homogeneous_tets, where):
    tm = homogeneous_tets
    pts, tets = tm.points, tm.tets
    inner = np.all((pts > LO + 30) & (pts < HI - 30), axis=1)
    cell = int(np.nonzero(np.all(inner[tets], axis=1))[0][0])
    v = pts[tets[cell]]
    src = {"vertex": v[0], "edge": 0.5 * (v[0] + v[1]), "face": (v[0] + v[1] + v[2]) / 3.0, "interior": v.mean(axis=0)}[
        where
    ]
    d = _fan()
    # also aim exactly at other mesh vertices (rays through vertices and along edges)
    targets = pts[np.all(tets[cell][:, None] != np.arange(len(pts))[None, :], axis=0)][:40]
    aim = targets - src
    d = np.concatenate([d, aim / np.linalg.norm(aim, axis=1)[:, None]])
    start = locate_points(tm.cells, src[None, :])[0]
    assert start >= 0
    t_end = 0.2  # 68 m: stays inside the box, some rays reflect off the ground
    r = trace(
        tm.cells,
        "parabolic",
        C_REF,
        np.tile(src, (len(d), 1)),
        d,
        np.full(len(d), start),
        max_time_s=t_end,
        max_reflections=5,
    )
    assert not np.any(r.status == STATUS_LOST)
    inside = r.status == STATUS_TIME_LIMIT
    assert inside.sum() > 0.5 * len(d)
    for i in np.nonzero(inside)[0]:
        ref, refl = _image_source_position(src, d[i], t_end)
        np.testing.assert_allclose(r.position[i], ref, atol=1e-9 * C_REF * t_end)
        assert r.reflections[i] == refl


def test_exactly_linear_medium_is_exact_on_tets():
    """n^2 = 1 + a.x (oblique gradient): LSQ and Green-Gauss both reproduce it exactly, so the tet
    trace equals the closed-form parabola (one slab cannot represent an oblique gradient, so the
    reference is the parabola evaluated directly with the same ground reflection)."""
    a = np.array([0.001, -0.0005, 0.004])

    def m(x):
        return 1.0 + x @ a

    tm = _tet_mesh(m)
    np.testing.assert_allclose(tm.cells.gradient, np.tile(a, (tm.cells.n_cells, 1)), rtol=0, atol=1e-12)
    src = np.array([60.0, 80.0, 30.0])
    d = _fan(9, 7)
    start = locate_points(tm.cells, src[None, :])[0]
    r = trace(
        tm.cells,
        "parabolic",
        C_REF,
        np.tile(src, (len(d), 1)),
        d,
        np.full(len(d), start),
        max_time_s=0.15,
        max_reflections=5,
    )
    assert not np.any(r.status == STATUS_LOST)
    # reference: a single huge box cell holding the same linear medium (no internal faces at all)
    from bentray.engine.mesh.cells import CellMesh

    box = build_slab_mesh(LO, HI, np.array([LO[2], HI[2]]), lambda z: np.ones_like(z))
    box = CellMesh(
        box.planes,
        box.neighbours,
        box.neighbour_face,
        np.array([m(np.zeros(3))]),
        np.zeros((1, 3)),
        a[None, :].copy(),
        box.size,
        box.face_material,
    )
    ref = trace(
        box,
        "parabolic",
        C_REF,
        np.tile(src, (len(d), 1)),
        d,
        np.zeros(len(d), dtype=np.int64),
        max_time_s=0.15,
        max_reflections=5,
    )
    same = ref.status == r.status
    assert same.all()
    np.testing.assert_allclose(r.position, ref.position, atol=1e-9 * C_REF * 0.15)
    np.testing.assert_allclose(r.length_m, ref.length_m, rtol=1e-9)
    assert np.array_equal(r.reflections, ref.reflections)
    assert r.crossings.sum() > 5 * len(d)  # the rays really walked through many tets

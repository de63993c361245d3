"""Surfaces linked to the cells they overlap (paper Appendix C): engine/experimental/linked_mesh.py,
engine/experimental/traverse_linked.py, engine/experimental/linked_media.py.

References: mirror images of straight rays over a tilted plane and off a box building (homogeneous
medium), the embedded (terrain-following) traversal on the same surface with a medium both meshes
represent exactly, and a linear-programming overlap test (scipy's HiGHS) for the link table.
"""

from __future__ import annotations

import bentray  # noqa: F401  # isort: skip  (sets OPENBLAS_NUM_THREADS before numpy / scipy load)
import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial import Delaunay

from bentray.engine.constants import BOUNDARY_REFLECT, STATUS_EXITED, STATUS_REFLECTION_LIMIT
from bentray.engine.experimental.linked_media import trace_linked
from bentray.engine.experimental.linked_mesh import (
    KIND_GROUND,
    KIND_ROOF,
    KIND_WALL,
    build_linked_mesh,
    link_cells,
    locate_in_linked_mesh,
)
from bentray.engine.media import build_terrain_media
from bentray.engine.mesh.terrain import build_terrain_mesh, locate_in_terrain_mesh
from bentray.engine.surfaces import Footprint, HeightGrid, SceneSurfaces, TriangleSurface
from bentray.engine.tracer import trace
from bentray.scenes.profile_models import profile_from_spec
from bentray.scenes.schema import Solver
from tests.mesh.test_terrain_mesh import (
    A0,
    AX,
    AY,
    BOX,
    BOX_HEIGHT,
    C_REF,
    HI,
    LO,
    W,
    _box_exit,
    _fan,
    _hit,
    plane,
    plane_grid,
)

M_GROUND = np.array([-AX, -AY, 1.0]) / np.linalg.norm([-AX, -AY, 1.0])
H_GROUND = A0 * M_GROUND[2]  # the tilted plane is M_GROUND . x = H_GROUND


def ones(p):
    return np.ones(len(p))


def _linked(surfaces, **kw):
    args = {"horizontal_spacing": 20.0, "z_levels": np.linspace(LO[2], HI[2], 16)}
    args.update(kw)
    return build_linked_mesh(surfaces, LO, HI, ones, **args)


@pytest.fixture(scope="module")
def plane_meshes():
    """Both representations of the tilted plane in a homogeneous medium (c = C_REF: straight rays)."""
    surfaces = SceneSurfaces(terrain=plane_grid())
    profile = profile_from_spec({"kind": "homogeneous", "c0": C_REF})
    embedded = build_terrain_media(profile, "parabolic", Solver(d_max_m=20.0), LO, HI, surfaces)
    return {"embedded": embedded, "linked": _linked(surfaces)}


def _run(meshes, method, src, d, max_reflections):
    orig = np.tile(src, (len(d), 1))
    kw = {"max_time_s": 20.0, "max_reflections": max_reflections}
    if method == "embedded":
        media = meshes["embedded"]
        cells = media.locate(orig)
        assert np.all(cells >= 0)
        return trace(media.mesh, "parabolic", C_REF, orig, d, cells, **kw)
    lm = meshes["linked"] if isinstance(meshes, dict) else meshes
    cells = locate_in_linked_mesh(lm, orig)
    assert np.all(cells >= 0)
    return trace_linked(lm, "parabolic", C_REF, orig, d, cells, **kw)


def test_terrain_media_reports_the_whole_build_and_the_mesh_split(plane_meshes):
    """build_terrain_media's build_time_s is the whole build (a number, as every representation reports it); the
    mesh builder's split stays beside it (until 2026-12-05 the total overwrote the split)."""
    stats = plane_meshes["embedded"].stats
    split = stats["mesh_build_time_s"]
    assert isinstance(stats["build_time_s"], float)
    assert set(split) >= {"triangulation_2d", "tables", "gradients", "total"}
    assert 0.0 < split["total"] <= stats["build_time_s"]


# ---------------------------------------------------------------------------------------------------
# (1) mirror images: the linked traversal, and the embedded one built through build_terrain_media
# (tests/mesh/test_terrain_mesh.py checks the embedded mesh from build_terrain_mesh the same way)
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["embedded", "linked"])
def test_ray_fan_reflects_off_the_tilted_plane_as_the_mirror_image(plane_meshes, method):
    src = np.array([200.0, 150.0, plane(200.0, 150.0) + 30.0])
    d = _fan(np.linspace(-75, -15, 13), np.arange(0, 360, 15))
    u = _hit(src, d, M_GROUND, H_GROUND)
    hit = src + u[:, None] * d
    inside = np.all((hit[:, :2] > LO[:2] + 1) & (hit[:, :2] < HI[:2] - 1), axis=1)
    d, u, hit = d[inside], u[inside], hit[inside]
    assert len(d) > 200
    r0 = _run(plane_meshes, method, src, d, 0)
    assert np.all(r0.status == STATUS_REFLECTION_LIMIT)
    np.testing.assert_allclose(r0.position, hit, rtol=0, atol=1e-9 * W)
    d_ref = d - 2 * (d @ M_GROUND)[:, None] * M_GROUND
    u2 = _box_exit(hit, d_ref)
    r1 = _run(plane_meshes, method, src, d, 1)
    assert np.all(r1.status == STATUS_EXITED) and np.all(r1.reflections == 1)
    np.testing.assert_allclose(r1.direction, d_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r1.position, hit + u2[:, None] * d_ref, rtol=0, atol=1e-9 * W)
    np.testing.assert_allclose(r1.length_m, u + u2, rtol=1e-9)
    np.testing.assert_allclose(r1.time_s, (u + u2) / C_REF, rtol=1e-9)
    assert r1.crossings.sum() > 10 * len(d)


def test_linked_fans_reflect_off_a_wall_and_a_roof():
    lm = _linked(SceneSurfaces(terrain=plane_grid(), footprints=[Footprint(BOX, BOX_HEIGHT, material=1)]))
    kinds = np.bincount(lm.triangles.kind, minlength=3)
    assert kinds[KIND_WALL] == 8 and kinds[KIND_ROOF] == 2 and kinds[KIND_GROUND] == 160
    roof = float(lm.triangles.vertices[lm.triangles.kind == KIND_ROOF][0, 0, 2])
    # roof = lowest terrain under the box + height, as terrain.py (a plane's lowest point is a corner)
    assert roof == pytest.approx(plane(BOX[:, 0], BOX[:, 1]).min() + BOX_HEIGHT, abs=1e-9)
    # wall x = 150 seen from the west, then down onto the tilted ground
    src = np.array([100.0, 130.0, plane(100.0, 130.0) + 10.0])
    d = _fan(np.linspace(-12, -2, 11), np.linspace(-25, 25, 11))
    m_wall = np.array([-1.0, 0.0, 0.0])
    hit = src + _hit(src, d, m_wall, -150.0)[:, None] * d
    ok = (hit[:, 1] > 101) & (hit[:, 1] < 159) & (hit[:, 2] < roof - 1) & (hit[:, 2] > plane(150.0, hit[:, 1]) + 1)
    d, hit = d[ok], hit[ok]
    d_ref = d - 2 * (d @ m_wall)[:, None] * m_wall
    u2 = _hit(hit, d_ref, M_GROUND, H_GROUND)
    ground_hit = hit + np.where(np.isfinite(u2), u2, 0.0)[:, None] * d_ref
    ok = np.isfinite(u2) & np.all((ground_hit[:, :2] > LO[:2] + 1) & (ground_hit[:, :2] < HI[:2] - 1), axis=1)
    d, hit, d_ref, ground_hit = d[ok], hit[ok], d_ref[ok], ground_hit[ok]
    assert len(d) >= 30
    r0 = _run(lm, "linked", src, d, 0)
    assert np.all(r0.status == STATUS_REFLECTION_LIMIT)
    np.testing.assert_allclose(r0.position, hit, rtol=0, atol=1e-9 * W)
    r1 = _run(lm, "linked", src, d, 1)
    assert np.all(r1.status == STATUS_REFLECTION_LIMIT) and np.all(r1.reflections == 1)
    np.testing.assert_allclose(r1.direction, d_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r1.position, ground_hit, rtol=0, atol=1e-9 * W)
    # roof from above; the reflected rays leave through the open top or sides
    src = np.array([190.0, 130.0, roof + 25.0])
    d = _fan(np.linspace(-85, -50, 8), np.arange(0, 360, 30))
    hit = src + _hit(src, d, np.array([0.0, 0.0, 1.0]), roof)[:, None] * d
    assert np.all((hit[:, :2] > BOX.min(axis=0)) & (hit[:, :2] < BOX.max(axis=0)))
    d_ref = d * np.array([1.0, 1.0, -1.0])
    r1 = _run(lm, "linked", src, d, 1)
    assert np.all(r1.status == STATUS_EXITED) and np.all(r1.reflections == 1)
    np.testing.assert_allclose(r1.direction, d_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r1.position, hit + _box_exit(hit, d_ref)[:, None] * d_ref, rtol=0, atol=1e-9 * W)


# ---------------------------------------------------------------------------------------------------
# (2) a stratified medium over hills: linked and embedded agree on the first ground hits
# ---------------------------------------------------------------------------------------------------
def hills(x, y):
    """Builtin-like rolling terrain (desert / christmas style): 4-14 m, a slight tilt and two mounds."""
    return (4.0 + 0.01 * x + 6.0 * np.exp(-((x - 250) ** 2 + (y - 120) ** 2) / (2 * 60.0**2))
            + 3.0 * np.exp(-((x - 90) ** 2 + (y - 220) ** 2) / (2 * 40.0**2)))  # fmt: skip


def test_linked_and_embedded_agree_on_ground_hits_in_a_stratified_medium():
    """n^2 = 1 + 0.002 z (the n^2-linear profile at a fifth of the paper's gradient: curved parabolic rays).

    Tolerance 1e-9 of the path length: both meshes carry n^2 *exactly* (it is linear, and a per-cell
    linear model with least-squares gradients reproduces a linear field to rounding), and the linked
    surface is the embedded mesh's own ground triangles, so the two traversals trace the same parabolas
    to the same planes through different cells (terrain-following vs flat layers, 14 m vs 10 m columns).
    Only rounding separates them; a media-approximation difference (e.g. the log profile on delta 1e-4
    layers: 1.6 % of the path here) would fail it, and so would the straight-ray hits (checked below).
    """
    x = np.linspace(-5.0, 405.0, 42)
    y = np.linspace(-5.0, 305.0, 32)
    gx, gy = np.meshgrid(x, y)
    profile = profile_from_spec({"kind": "linear_n2", "n0": 1.0, "alpha": 0.002})
    q = lambda p: profile.quantity("n2", p)  # noqa: E731
    tm = build_terrain_mesh(SceneSurfaces(terrain=HeightGrid(x, y, hills(gx, gy))), LO, HI, q,
                            horizontal_spacing=10.0, layer_levels=np.linspace(0.0, 1.0, 16))  # fmt: skip
    n2 = tm.stats["n_vertices_2d"]
    bc, bf = np.nonzero(tm.cells.neighbours == BOUNDARY_REFLECT)
    opposite = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])  # face i is opposite vertex i
    faces = np.take_along_axis(tm.tets[bc], opposite[bf], axis=1)
    faces = faces[np.all(faces < n2, axis=1)]  # ground (level 0) faces
    tin = TriangleSurface(tm.points[:n2].copy(), faces)
    lm = build_linked_mesh(SceneSurfaces(terrain=tin), LO, HI, q, horizontal_spacing=14.0,
                           z_levels=np.arange(0.0, 151.0, 10.0))  # fmt: skip
    src = np.array([200.0, 150.0, hills(200.0, 150.0) + 5.0])
    d = _fan(np.linspace(-25, -3, 12), np.arange(0, 360, 30))
    orig = np.tile(src, (len(d), 1))
    kw = {"max_time_s": 5.0, "max_reflections": 0}
    emb = trace(tm.cells, "parabolic", C_REF, orig, d, locate_in_terrain_mesh(tm, orig), **kw)
    tests = np.zeros(len(d), dtype=np.int64)
    lnk = trace_linked(lm, "parabolic", C_REF, orig, d, locate_in_linked_mesh(lm, orig), surface_tests=tests, **kw)
    # n grows with z: the shallow rays bend up and leave through the top or sides; both must agree on which
    np.testing.assert_array_equal(lnk.status, emb.status)
    hits = emb.status == STATUS_REFLECTION_LIMIT
    assert hits.sum() >= 80 and np.all(hits | (emb.status == STATUS_EXITED))
    length = emb.length_m[hits]
    assert length.min() > 10.0 and length.max() > 80.0
    np.testing.assert_array_less(np.linalg.norm(lnk.position - emb.position, axis=1), 1e-9 * emb.length_m)
    np.testing.assert_allclose(lnk.direction, emb.direction, rtol=0, atol=1e-9)
    np.testing.assert_allclose(lnk.length_m, emb.length_m, rtol=1e-9)
    np.testing.assert_allclose(lnk.time_s, emb.time_s, rtol=1e-9)
    assert np.all(tests > 0) and lnk.crossings.sum() > 5 * len(d)  # many cells, several per ray
    # the rays are curved: straight lines land decimetres to metres away (same TIN), far outside the tolerance
    flat = build_linked_mesh(SceneSurfaces(terrain=tin), LO, HI, ones, horizontal_spacing=14.0,
                             z_levels=np.arange(0.0, 151.0, 10.0))  # fmt: skip
    lin = trace_linked(flat, "parabolic", C_REF, orig, d, locate_in_linked_mesh(flat, orig), **kw)
    straight_gap = np.linalg.norm(lin.position[hits] - emb.position[hits], axis=1)
    assert np.all(straight_gap > 1e-3 * length)  # 10 cm to 6 m: a million times the tolerance


# ---------------------------------------------------------------------------------------------------
# (3) the link table against a brute-force overlap test
# ---------------------------------------------------------------------------------------------------
def _lp_overlap(tet: np.ndarray, tri: np.ndarray) -> bool:
    """Is there a point in both? Feasibility of sum l_i P_i = sum m_j T_j, l, m >= 0, sum l = sum m = 1."""
    a_eq = np.zeros((5, 7))
    a_eq[:3, :4] = tet.T
    a_eq[:3, 4:] = -tri.T
    a_eq[3, :4] = 1.0
    a_eq[4, 4:] = 1.0
    res = linprog(np.zeros(7), A_eq=a_eq, b_eq=[0, 0, 0, 1, 1], bounds=[(0, None)] * 7, method="highs")
    return res.status == 0


@pytest.mark.slow  # brute-force LP per pair: 11 s warm
def test_link_table_matches_brute_force_overlap():
    rng = np.random.default_rng(11)
    pts = rng.uniform(0.0, 1.0, (40, 3))
    tets = Delaunay(pts).simplices
    cell_v = pts[tets]
    centre = rng.uniform(-0.1, 1.1, (25, 3))
    scale = rng.uniform(0.05, 0.6, 25)
    tri_v = centre[:, None, :] + scale[:, None, None] * rng.uniform(-1.0, 1.0, (25, 3, 3))
    offsets, linked, stats = link_cells(cell_v, tri_v)
    got = {(c, int(t)) for c in range(len(cell_v)) for t in linked[offsets[c] : offsets[c + 1]]}
    want = {(c, t) for c in range(len(cell_v)) for t in range(len(tri_v)) if _lp_overlap(cell_v[c], tri_v[t])}
    assert 50 < len(want) < 0.9 * len(cell_v) * len(tri_v)  # a real mix of overlapping and disjoint pairs
    assert got == want
    assert stats["links"] == len(want) and stats["candidate_pairs"] >= len(want)
    assert np.all(np.diff(offsets) >= 0) and offsets[-1] == len(linked)

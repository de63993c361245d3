"""Terrain-following conforming tet mesh (engine/mesh/terrain.py, prisms.py, triangulate2d.py).

References: closed-form volumes of a box above a tilted plane minus a box building, the input surfaces
themselves (plane, scipy's bilinear RegularGridInterpolator, footprint polygons), brute-force point
location (cells.locate_points), scipy's Delaunay.find_simplex, the closed-form levels of a linear
spacing rule, and mirror-image reflection of straight rays in a homogeneous medium.
"""

from __future__ import annotations

import time

import bentray  # noqa: F401  # isort: skip  (sets OPENBLAS_NUM_THREADS before numpy / scipy load)
import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial import Delaunay

from bentray.engine.constants import (
    BOUNDARY_OPEN,
    BOUNDARY_REFLECT,
    STATUS_EXITED,
    STATUS_REFLECTION_LIMIT,
)
from bentray.engine.mesh.cells import locate_points, validate_cell_mesh
from bentray.engine.mesh.prisms import sigma_levels
from bentray.engine.mesh.terrain import build_terrain_mesh, locate_in_terrain_mesh, terrain_index
from bentray.engine.mesh.triangulate2d import SEPARATION_RTOL, TriangleLocator, greedy_thin
from bentray.engine.surfaces import Footprint, HeightGrid, SceneSurfaces, TriangleSurface
from bentray.engine.tracer import trace

LO = np.array([0.0, 0.0, 0.0])
HI = np.array([400.0, 300.0, 150.0])
W, D, H = HI - LO
A0, AX, AY = 10.0, 0.05, -0.03  # tilted plane z = A0 + AX x + AY y (ground between 1 and 30 m)
C_REF = 340.0
BOX = np.array([[150.0, 100.0], [230.0, 100.0], [230.0, 160.0], [150.0, 160.0]])
BOX_HEIGHT = 20.0


def plane(x, y):
    return A0 + AX * x + AY * y


def plane_grid(n_x=11, n_y=9):
    x = np.linspace(LO[0] - 5, HI[0] + 5, n_x)
    y = np.linspace(LO[1] - 5, HI[1] + 5, n_y)
    gx, gy = np.meshgrid(x, y)
    return HeightGrid(x, y, plane(gx, gy), default_material=2)


def ones(p):
    return np.ones(len(p))


def build(surfaces, **kw):
    args = {"horizontal_spacing": 20.0, "vertical_spacing": lambda z: 2.0 + 0.1 * z}
    args.update(kw)
    return build_terrain_mesh(surfaces, LO, HI, ones, **args)


@pytest.fixture(scope="module")
def plane_mesh():
    return build(SceneSurfaces(terrain=plane_grid()))


@pytest.fixture(scope="module")
def building_mesh():
    return build(SceneSurfaces(terrain=plane_grid(), footprints=[Footprint(BOX, BOX_HEIGHT, material=1, name="box")]))


@pytest.fixture(scope="module")
def tin_mesh():
    rng = np.random.default_rng(3)
    xy = rng.uniform([-10, -10], [410, 310], (300, 2))
    xy = np.vstack([xy, [[-10, -10], [410, -10], [410, 310], [-10, 310]]])
    tin = TriangleSurface(np.column_stack([xy, plane(xy[:, 0], xy[:, 1])]), Delaunay(xy).simplices)
    fps = [
        Footprint(np.array([[50.0, 50], [150, 60], [50, 67]]), 10, name="acute 10 deg"),
        Footprint(np.array([[200.0, 50], [300, 50], [300, 50.5], [200, 50.5]]), 6, name="barrier 0.5 m"),
        Footprint(np.array([[200.0, 100], [260, 100], [260, 140], [200, 140]]), 15, name="b1"),
        Footprint(np.array([[260.5, 121.3], [300, 105], [300, 135]]), 10, name="wedge 0.5 m from b1"),
        Footprint(
            np.array(
                [[100.0, 200], [200, 200], [200, 260], [180, 260], [180, 210], [120, 210], [120, 260], [100, 260]]
            ),
            12,
            name="U",
        ),  # fmt: skip
        Footprint(np.array([[300.0, 200], [340, 230], [300, 260.0], [320, 230]]), 8, name="arrow"),
    ]
    surf = SceneSurfaces(terrain=tin, footprints=fps)
    return surf, build(surf, horizontal_spacing=lambda q: 10.0 + 0.05 * q[:, 0], vertical_spacing=3.0)


def face_ids(tm):
    """(T, 4, 3) sorted vertex ids of face i (opposite vertex i), computed independently."""
    f = np.stack([np.delete(tm.tets, i, axis=1) for i in range(4)], axis=1)
    return np.sort(f, axis=2)


def boundary_faces(tm, tag):
    c, f = np.nonzero(tm.cells.neighbours == tag)
    return c, f, tm.points[face_ids(tm)[c, f]]


def dist_to_segment(p, a, b):
    t = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * (b - a)), axis=-1)


# ---------------------------------------------------------------------------------------------------
# Validity and volume
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["plane_mesh", "building_mesh", "tin_mesh"])
def test_mesh_is_valid_and_faces_pair_up(name, request):
    tm = request.getfixturevalue(name)
    tm = tm[1] if name == "tin_mesh" else tm
    validate_cell_mesh(tm.cells)
    fids = face_ids(tm)
    keys, counts = np.unique(fids.reshape(-1, 3), axis=0, return_counts=True)
    assert counts.max() == 2
    inner = tm.cells.neighbours >= 0
    assert 2 * int(np.sum(counts == 2)) == int(inner.sum())
    c, f = np.nonzero(inner)
    nb, nf = tm.cells.neighbours[c, f], tm.cells.neighbour_face[c, f]
    np.testing.assert_array_equal(fids[nb, nf], fids[c, f])  # same vertex triple on both sides
    np.testing.assert_array_equal(tm.cells.planes[nb, nf], -tm.cells.planes[c, f])
    p = tm.points[tm.tets]
    vol = np.linalg.det(p[:, 1:] - p[:, :1]) / 6.0
    assert vol.min() > 0
    assert tm.stats["volume_min_m3"] == pytest.approx(vol.min(), rel=1e-9)
    assert tm.stats["min_dihedral_deg"]["min"] > 0
    # every cell vertex is inside all its face planes (outward orientation)
    dist = np.einsum("nfi,nvi->nfv", tm.cells.planes[..., :3], p) - tm.cells.planes[..., 3][..., None]
    assert dist.max() <= 1e-9 * tm.cells.size.max()


def test_total_volume_is_box_above_plane_minus_building(plane_mesh, building_mesh):
    above = W * D * H - (A0 * W * D + AX * W**2 * D / 2 + AY * W * D**2 / 2)
    assert plane_mesh.stats["volume_total_m3"] == pytest.approx(above, rel=1e-12)
    roof = building_mesh.stats["roofs"][0]["roof_z"]
    corners = plane(BOX[:, 0], BOX[:, 1])
    assert roof == pytest.approx(corners.min() + BOX_HEIGHT, rel=1e-14)  # base_z default: lowest terrain
    area = 80.0 * 60.0
    exact = above - area * (roof - plane(190.0, 130.0))  # terrain linear: its mean is the centre value
    p = building_mesh.points[building_mesh.tets]
    assert np.sum(np.linalg.det(p[:, 1:] - p[:, :1])) / 6.0 == pytest.approx(exact, rel=1e-12)


def test_tin_volume_and_ground_on_plane(tin_mesh):
    surf, tm = tin_mesh
    above = W * D * H - (A0 * W * D + AX * W**2 * D / 2 + AY * W * D**2 / 2)
    removed = 0.0
    for fp, roof in zip(surf.footprints, tm.stats["roofs"], strict=True):
        q = fp.polygon
        qn = np.roll(q, -1, axis=0)
        cross = q[:, 0] * qn[:, 1] - qn[:, 0] * q[:, 1]
        area = cross.sum() / 2
        cen = ((q + qn) * cross[:, None]).sum(axis=0) / (6 * area)
        removed += abs(area) * (roof["roof_z"] - plane(*cen))
    assert tm.stats["volume_total_m3"] == pytest.approx(above - removed, rel=1e-10)
    _, _, fp = boundary_faces(tm, BOUNDARY_REFLECT)
    ground = np.all(np.abs(fp[..., 2] - plane(fp[..., 0], fp[..., 1])) <= 1e-9 * H, axis=1)
    assert ground.sum() == tm.stats["n_boundary_faces"]["ground"]


# ---------------------------------------------------------------------------------------------------
# Conformity
# ---------------------------------------------------------------------------------------------------
def test_ground_faces_lie_on_the_tilted_plane(plane_mesh):
    c, f, fp = boundary_faces(plane_mesh, BOUNDARY_REFLECT)
    assert len(c) == plane_mesh.stats["n_boundary_faces"]["ground"] > 0
    np.testing.assert_allclose(fp[..., 2], plane(fp[..., 0], fp[..., 1]), rtol=0, atol=1e-9)
    m = np.array([AX, AY, -1.0]) / np.linalg.norm([AX, AY, -1.0])  # outward of the air cells: into the ground
    np.testing.assert_allclose(plane_mesh.cells.planes[c, f, :3], np.tile(m, (len(c), 1)), rtol=0, atol=1e-12)
    assert np.all(plane_mesh.cells.face_material[c, f] == 2)
    # the ground is covered: face areas sum to the area of the plane over the box
    area = 0.5 * np.linalg.norm(np.cross(fp[:, 1] - fp[:, 0], fp[:, 2] - fp[:, 0]), axis=1).sum()
    assert area == pytest.approx(W * D * np.sqrt(1 + AX**2 + AY**2), rel=1e-12)
    _, _, top = boundary_faces(plane_mesh, BOUNDARY_OPEN)
    assert np.sum(np.all(top[..., 2] == HI[2], axis=1)) == plane_mesh.stats["n_boundary_faces"]["top"]


def test_reflecting_top_and_explicit_base_z():
    fp = Footprint(BOX, 12.0, base_z=30.0, material=3)
    tm = build(SceneSurfaces(terrain=plane_grid(), footprints=[fp]), top="reflect")
    assert tm.stats["roofs"][0]["roof_z"] == 42.0
    c, f, pts = boundary_faces(tm, BOUNDARY_REFLECT)
    top = np.all(pts[..., 2] == HI[2], axis=1)
    assert top.sum() == tm.stats["n_boundary_faces"]["top"] > 0
    np.testing.assert_array_equal(tm.cells.planes[c[top], f[top], :3], np.tile([0.0, 0.0, 1.0], (top.sum(), 1)))
    roof = np.all(pts[..., 2] == 42.0, axis=1)
    assert roof.sum() == tm.stats["n_boundary_faces"]["roofs"] > 0
    assert np.all(tm.cells.face_material[c[roof], f[roof]] == 3)
    _, _, side = boundary_faces(tm, BOUNDARY_OPEN)  # only the four sides stay open
    on_side = [np.all(side[..., ax] == val, axis=1) for ax in (0, 1) for val in (LO[ax], HI[ax])]
    assert len(side) == tm.stats["n_boundary_faces"]["sides"] and np.all(np.any(on_side, axis=0))


def test_bilinear_grid_vertices_lie_on_the_surface():
    rng = np.random.default_rng(7)
    x = np.linspace(-5, 405, 15)
    y = np.sort(np.concatenate([[-5.0, 305.0], rng.uniform(0, 300, 10)]))  # irregular rows
    z = 5.0 + rng.uniform(0, 20, (len(y), len(x)))
    tm = build(SceneSurfaces(terrain=HeightGrid(x, y, z)), horizontal_spacing=lambda q: 8.0 + 0.05 * q[:, 0])
    validate_cell_mesh(tm.cells)
    n2 = tm.stats["n_vertices_2d"]
    ref = RegularGridInterpolator((y, x), z, method="linear")(tm.points[:n2, [1, 0]])
    np.testing.assert_allclose(tm.points[:n2, 2], ref, rtol=0, atol=1e-12 * np.abs(z).max())
    # grid nodes inside the box that were kept are exact mesh vertices
    gx, gy = np.meshgrid(x, y)
    nodes = {(a, b) for a, b in zip(gx.ravel(), gy.ravel(), strict=True)}
    hit = [i for i, (a, b) in enumerate(tm.points[:n2, :2]) if (a, b) in nodes]
    assert len(hit) == tm.stats["triangulation"]["n_terrain_samples"] > 0
    np.testing.assert_array_equal(tm.points[hit, 2], [z[np.searchsorted(y, b), np.searchsorted(x, a)]
                                                      for a, b in tm.points[hit, :2]])  # fmt: skip


def test_walls_and_roof_lie_on_the_building(building_mesh):
    tm = building_mesh
    roof = tm.stats["roofs"][0]["roof_z"]
    c, f, fp = boundary_faces(tm, BOUNDARY_REFLECT)
    n = tm.cells.planes[c, f, :3]
    on_ground = np.all(np.abs(fp[..., 2] - plane(fp[..., 0], fp[..., 1])) <= 1e-9, axis=1)
    is_roof = np.all(fp[..., 2] == roof, axis=1)
    edges = list(zip(BOX, np.roll(BOX, -1, axis=0), strict=True))
    on_edge = [np.all(dist_to_segment(fp[..., :2], a, b) <= 1e-9, axis=1) for a, b in edges]
    is_wall = np.any(on_edge, axis=0) & (n[:, 2] == 0.0)
    assert np.all(on_ground.astype(int) + is_roof + is_wall == 1)  # each reflecting face is exactly one kind
    assert np.all(tm.cells.face_material[c[is_roof | is_wall], f[is_roof | is_wall]] == 1)
    # roof: horizontal, facing down (out of the air cell above), inside the footprint, covering its area
    np.testing.assert_array_equal(n[is_roof], np.tile([0.0, 0.0, -1.0], (is_roof.sum(), 1)))
    assert np.all((fp[is_roof][..., :2] >= BOX.min(axis=0)) & (fp[is_roof][..., :2] <= BOX.max(axis=0)))

    def areas(p):
        return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)

    assert areas(fp[is_roof]).sum() == pytest.approx(80.0 * 60.0, rel=1e-12)
    # walls: vertical, normal pointing into the building, each edge covered from the terrain to the roof
    for (a, b), e in zip(edges, on_edge, strict=True):
        sel = e & is_wall
        out = np.array([b[1] - a[1], a[0] - b[0]]) / np.linalg.norm(b - a)  # outward normal of the CCW box
        np.testing.assert_allclose(n[sel, :2], np.tile(-out, (sel.sum(), 1)), rtol=0, atol=1e-12)
        mid = 0.5 * (a + b)
        expect = np.linalg.norm(b - a) * (roof - plane(*mid))
        assert areas(fp[sel]).sum() == pytest.approx(expect, rel=1e-12)


def _edge_cover(xy, tris, poly):
    """Total length of the 2D triangulation edges lying on each polygon edge, and the edge lengths."""
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    e = np.unique(e, axis=0)
    got, want = [], []
    for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
        on = np.all(dist_to_segment(xy[e], a, b) <= 1e-9, axis=1)
        got.append(np.linalg.norm(xy[e[on, 0]] - xy[e[on, 1]], axis=1).sum())
        want.append(np.linalg.norm(b - a))
    return np.array(got), np.array(want)


def test_footprint_edges_are_unions_of_triangle_edges(tin_mesh):
    surf, tm = tin_mesh
    idx = terrain_index(tm)
    xy = tm.points[: tm.stats["n_vertices_2d"], :2]
    for fp in surf.footprints:
        got, want = _edge_cover(xy, idx.triangles, fp.polygon)
        np.testing.assert_allclose(got, want, rtol=1e-12, err_msg=fp.name)
    assert tm.stats["triangulation"]["n_split_points"] >= 1  # the wedge tip forces a split of b1's wall
    # roofs are layer levels over every footprint column
    n2 = tm.stats["n_vertices_2d"]
    for fp, r in zip(surf.footprints, tm.stats["roofs"], strict=True):
        on = np.min([dist_to_segment(xy, a, b) for a, b in zip(fp.polygon, np.roll(fp.polygon, -1, 0),
                                                               strict=True)], axis=0) <= 1e-9  # fmt: skip
        assert np.all(tm.points[r["level"] * n2 + np.flatnonzero(on), 2] == r["roof_z"])


# ---------------------------------------------------------------------------------------------------
# Media, levels, location helpers
# ---------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["lsq", "green_gauss"])
def test_linear_media_is_exact_per_cell(method):
    g = np.array([1e-3, -2e-3, 5e-3])
    tm = build_terrain_mesh(SceneSurfaces(terrain=plane_grid(), footprints=[Footprint(BOX, BOX_HEIGHT)]), LO, HI,
                            lambda p: 1.0 + p @ g, horizontal_spacing=30.0, vertical_spacing=10.0,
                            gradient_method=method)  # fmt: skip
    np.testing.assert_allclose(tm.cells.gradient, np.tile(g, (tm.cells.n_cells, 1)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(tm.cells.media_ref, 1.0 + tm.cells.ref_point @ g, rtol=1e-13)


def test_sigma_levels_follow_a_linear_spacing_rule():
    a, b, height = 0.5, 0.2, 300.0  # dz = a + b zeta: N(zeta) = ln(1 + b zeta / a) / b
    s = sigma_levels(height, lambda z: a + b * z)
    n_tot = np.log(1 + b * height / a) / b
    n = int(round(n_tot))
    expect = a / b * (np.exp(b * np.arange(n + 1) * n_tot / n) - 1) / height
    assert len(s) == n + 1
    np.testing.assert_allclose(s, expect, rtol=1e-5, atol=0)  # trapezoid of 1/dz, linear inversion: ~2e-6
    np.testing.assert_allclose(sigma_levels(height, 30.0), np.linspace(0, 1, 11), rtol=0, atol=0)


def test_triangle_locator_matches_scipy_find_simplex():
    rng = np.random.default_rng(11)
    xy = rng.uniform(0, 100, (400, 2))
    tri = Delaunay(xy)
    q = rng.uniform(-10, 110, (5000, 2))
    got, bary = TriangleLocator(xy, tri.simplices).locate(q)
    np.testing.assert_array_equal(got, tri.find_simplex(q))
    ok = got >= 0
    np.testing.assert_allclose(np.einsum("ni,nij->nj", bary[ok], xy[tri.simplices[got[ok]]]), q[ok], atol=1e-10)


def test_greedy_thinning_is_separated_and_maximal():
    rng = np.random.default_rng(5)
    p = rng.uniform(0, 50, (600, 2))
    d = 2.0 + 0.05 * p[:, 0]
    keep = greedy_thin(p, d)
    dist = np.linalg.norm(p[:, None] - p[None], axis=2)
    lim = (1 - SEPARATION_RTOL) * np.minimum(d[:, None], d[None])
    conflict = (dist < lim) & ~np.eye(len(p), dtype=bool)
    assert not np.any(conflict[np.ix_(keep, keep)])
    for i in np.flatnonzero(~keep):  # sequential greedy: an earlier kept point blocks every dropped one
        assert np.any(conflict[i, :i] & keep[:i])


def test_locate_matches_brute_force(building_mesh):
    rng = np.random.default_rng(2)
    q = rng.uniform(LO - 10, HI + 10, (400, 3))
    q[:100, :2] = rng.uniform(BOX.min(axis=0), BOX.max(axis=0), (100, 2))  # many in and over the building
    got = locate_in_terrain_mesh(building_mesh, q)
    np.testing.assert_array_equal(got, locate_points(building_mesh.cells, q))
    roof = building_mesh.stats["roofs"][0]["roof_z"]
    assert np.all(got[:100][q[:100, 2] < roof] == -1)
    assert np.all(got[q[:, 2] < plane(q[:, 0], q[:, 1])] == -1)
    assert np.sum(got >= 0) > 150


# ---------------------------------------------------------------------------------------------------
# Reflections (homogeneous medium: straight rays, mirror images)
# ---------------------------------------------------------------------------------------------------
def _fan(el_deg, az_deg):
    el, az = np.meshgrid(np.radians(el_deg), np.radians(az_deg))
    el, az = el.ravel(), az.ravel()
    return np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def _hit(x, d, m, h):
    """Parameter u >= 0 where x + u d meets the plane m . x = h (inf if never)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (h - x @ m) / (d @ m)
    return np.where(u > 1e-12, u, np.inf)


def _box_exit(x, d):
    u = np.full(len(x), np.inf)
    for ax, val in [(0, LO[0]), (0, HI[0]), (1, LO[1]), (1, HI[1]), (2, HI[2])]:
        m = np.eye(3)[ax]
        u = np.minimum(u, _hit(x, d, m, val))
    return u


def _trace(tm, src, d, max_reflections):
    orig = np.tile(src, (len(d), 1))
    cells = locate_in_terrain_mesh(tm, orig)
    assert np.all(cells >= 0)
    return trace(tm.cells, "parabolic", C_REF, orig, d, cells, max_time_s=20.0, max_reflections=max_reflections)


def test_ray_fan_reflects_off_the_tilted_terrain_as_the_mirror_image(plane_mesh):
    m = np.array([-AX, -AY, 1.0]) / np.linalg.norm([-AX, -AY, 1.0])
    h = A0 * m[2]  # the plane is m . x = h
    src = np.array([200.0, 150.0, plane(200.0, 150.0) + 30.0])
    d = _fan(np.linspace(-75, -15, 13), np.arange(0, 360, 15))
    u = _hit(src, d, m, h)
    hit = src + u[:, None] * d
    inside = np.all((hit[:, :2] > LO[:2] + 1) & (hit[:, :2] < HI[:2] - 1), axis=1)
    d, u, hit = d[inside], u[inside], hit[inside]
    assert len(d) > 200
    r0 = _trace(plane_mesh, src, d, 0)
    assert np.all(r0.status == STATUS_REFLECTION_LIMIT)
    np.testing.assert_allclose(r0.position, hit, rtol=0, atol=1e-9 * W)
    d_ref = d - 2 * (d @ m)[:, None] * m
    u2 = _box_exit(hit, d_ref)
    r1 = _trace(plane_mesh, src, d, 1)
    assert np.all(r1.status == STATUS_EXITED) and np.all(r1.reflections == 1)
    np.testing.assert_allclose(r1.direction, d_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r1.position, hit + u2[:, None] * d_ref, rtol=0, atol=1e-9 * W)
    np.testing.assert_allclose(r1.length_m, u + u2, rtol=1e-9)
    assert r1.crossings.sum() > 10 * len(d)


def test_ray_fans_reflect_off_a_wall_and_a_roof(building_mesh):
    tm = building_mesh
    roof = tm.stats["roofs"][0]["roof_z"]
    m_ground = np.array([-AX, -AY, 1.0]) / np.linalg.norm([-AX, -AY, 1.0])
    h_ground = A0 * m_ground[2]
    # wall x = 150 (normal -x), seen from the west, below the roof; the reflected rays come down on the terrain
    src = np.array([100.0, 130.0, plane(100.0, 130.0) + 10.0])
    d = _fan(np.linspace(-12, -2, 11), np.linspace(-25, 25, 11))  # all toward +x
    m_wall = np.array([-1.0, 0.0, 0.0])
    u = _hit(src, d, m_wall, -150.0)
    assert np.all(np.isfinite(u))
    hit = src + u[:, None] * d
    ok = (hit[:, 1] > 101) & (hit[:, 1] < 159) & (hit[:, 2] < roof - 1) & (hit[:, 2] > plane(150.0, hit[:, 1]) + 1)
    d, hit = d[ok], hit[ok]
    d_ref = d - 2 * (d @ m_wall)[:, None] * m_wall
    u2 = _hit(hit, d_ref, m_ground, h_ground)
    ground_hit = hit + np.where(np.isfinite(u2), u2, 0.0)[:, None] * d_ref
    ok = np.isfinite(u2) & np.all((ground_hit[:, :2] > LO[:2] + 1) & (ground_hit[:, :2] < HI[:2] - 1), axis=1)
    d, hit, d_ref, ground_hit = d[ok], hit[ok], d_ref[ok], ground_hit[ok]
    assert len(d) >= 30
    r0 = _trace(tm, src, d, 0)
    assert np.all(r0.status == STATUS_REFLECTION_LIMIT)
    np.testing.assert_allclose(r0.position, hit, rtol=0, atol=1e-9 * W)
    r1 = _trace(tm, src, d, 1)
    assert np.all(r1.status == STATUS_REFLECTION_LIMIT) and np.all(r1.reflections == 1)
    np.testing.assert_allclose(r1.direction, d_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r1.position, ground_hit, rtol=0, atol=1e-9 * W)
    # roof z = roof, seen from above; the reflected rays leave through the open top or sides
    src = np.array([190.0, 130.0, roof + 25.0])
    d = _fan(np.linspace(-85, -50, 8), np.arange(0, 360, 30))
    m_roof = np.array([0.0, 0.0, 1.0])
    u = _hit(src, d, m_roof, roof)
    hit = src + u[:, None] * d
    assert np.all((hit[:, :2] > BOX.min(axis=0)) & (hit[:, :2] < BOX.max(axis=0)))
    d_ref = d * np.array([1.0, 1.0, -1.0])
    r1 = _trace(tm, src, d, 1)
    assert np.all(r1.status == STATUS_EXITED) and np.all(r1.reflections == 1)
    np.testing.assert_allclose(r1.direction, d_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(r1.position, hit + _box_exit(hit, d_ref)[:, None] * d_ref, rtol=0, atol=1e-9 * W)


# ---------------------------------------------------------------------------------------------------
# Scale and errors
# ---------------------------------------------------------------------------------------------------
def test_100x100_grid_over_2km_builds_quickly():
    x = np.linspace(0.0, 2000.0, 100)
    gx, gy = np.meshgrid(x, x)
    z = 50 + 30 * np.sin(gx / 300) * np.cos(gy / 400) + 0.01 * gx
    fps = [Footprint(np.array([[500.0, 500], [560, 500], [560, 540], [500, 540]]), 15.0)]
    t0 = time.perf_counter()
    tm = build_terrain_mesh(SceneSurfaces(terrain=HeightGrid(x, x, z), footprints=fps), [0, 0, 0], [2000, 2000, 400],
                            ones, horizontal_spacing=40.0, vertical_spacing=lambda s: 2.0 + 0.15 * s)  # fmt: skip
    elapsed = time.perf_counter() - t0
    print(f"\n100x100 grid, d = 40 m: {tm.stats['n_cells']:,} cells, {tm.stats['n_layers']} layers, "
          f"{elapsed:.2f} s ({tm.stats['build_time_s']})")  # fmt: skip
    validate_cell_mesh(tm.cells)
    assert tm.stats["n_cells"] > 100_000
    assert tm.stats["n_boundary_faces"]["ground"] > 0 and tm.stats["n_boundary_faces"]["roofs"] > 0


def test_bad_inputs_raise():
    grid = plane_grid()
    box = Footprint(BOX, BOX_HEIGHT)
    with pytest.raises(ValueError, match="overlap"):
        build(SceneSurfaces(terrain=grid, footprints=[box, Footprint(BOX + 10.0, 5.0)]))
    with pytest.raises(ValueError, match="strictly inside"):
        build(SceneSurfaces(terrain=grid, footprints=[Footprint(BOX + 200.0, 5.0)]))
    with pytest.raises(ValueError, match="not simple"):
        build(SceneSurfaces(terrain=grid, footprints=[Footprint(BOX[[0, 2, 1, 3]], 5.0)]))
    with pytest.raises(ValueError, match="roof"):
        build(SceneSurfaces(terrain=grid, footprints=[Footprint(BOX, 2.0, base_z=0.0)]))  # roof below terrain
    with pytest.raises(ValueError, match="cover"):
        build(SceneSurfaces(terrain=HeightGrid(grid.x[:5], grid.y, grid.z[:, :5])))
    with pytest.raises(ValueError, match="exactly one"):
        build_terrain_mesh(SceneSurfaces(), LO, HI, ones, horizontal_spacing=20.0)
    with pytest.raises(ValueError, match="obstacle"):
        build(SceneSurfaces(obstacles=[(np.zeros((4, 3)), np.zeros((4, 3), dtype=np.int64))]))
    with pytest.raises(ValueError, match="at least 2 layers"):  # no level between ground and top for a roof
        build(SceneSurfaces(terrain=grid, footprints=[box]), vertical_spacing=None, layer_levels=[0.0, 1.0])

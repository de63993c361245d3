"""Scene input readers: every format round-trips through a temporary file, and every error names the file
and the reason (with the line for text formats). Geometry helpers are checked against brute-force or
scipy references."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import LinearNDInterpolator, RegularGridInterpolator
from scipy.spatial import Delaunay

from bentray.engine.errors import JobInputError
from bentray.engine.surfaces import HeightGrid, TriangleSurface
from bentray.scenes import terrain_io
from bentray.scenes.geometry import box_pairs, locate_points_2d, terrain_height_at
from bentray.scenes.gis_geometry import overlapping_pairs, polygon_from_rings
from bentray.scenes.mesh_checks import triangles_intersect
from bentray.scenes.terrain_io import (
    SceneFileError,
    read_esri_ascii,
    read_footprints_geojson,
    read_height_npy,
    read_height_npz,
    read_obstacle_mesh,
    read_terrain,
    read_terrain_mesh,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "scenes" / "examples"


def _raises(func, *args, match: str, **kwargs) -> str:
    with pytest.raises(SceneFileError) as info:
        func(*args, **kwargs)
    text = str(info.value)
    assert match in text, text
    return text


# ---------------------------------------------------------------------------------------------
# ESRI ASCII grid
# ---------------------------------------------------------------------------------------------
def _write_asc(path: Path, z_north_first: np.ndarray, header: dict[str, object]) -> Path:
    lines = [f"{k} {v}" for k, v in header.items()]
    lines += [" ".join(repr(float(v)) for v in row) for row in z_north_first]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("anchor", ["corner", "center"])
def test_asc_round_trip(tmp_path, anchor):
    rng = np.random.default_rng(1)
    z_south_first = rng.uniform(-5, 50, (4, 6))  # (ny, nx), row 0 is the southern row
    header = {"ncols": 6, "nrows": 4, f"xll{anchor}": 100.0, f"YLL{anchor.upper()}": -20.0, "cellsize": 2.5}
    grid = read_esri_ascii(_write_asc(tmp_path / "g.asc", z_south_first[::-1], header))
    shift = 1.25 if anchor == "corner" else 0.0  # corner: the values sit at the cell centres
    np.testing.assert_array_equal(grid.x, 100.0 + shift + 2.5 * np.arange(6))
    np.testing.assert_array_equal(grid.y, -20.0 + shift + 2.5 * np.arange(4))
    np.testing.assert_array_equal(grid.z, z_south_first)
    assert isinstance(grid, HeightGrid) and grid.z.flags.c_contiguous


def test_asc_dx_dy_header(tmp_path):
    header = {"ncols": 2, "nrows": 2, "xllcenter": 0, "yllcenter": 0, "dx": 1.0, "dy": 3.0}
    grid = read_esri_ascii(_write_asc(tmp_path / "g.asc", np.array([[1.0, 2.0], [3.0, 4.0]]), header))
    np.testing.assert_array_equal(grid.y, [0.0, 3.0])
    np.testing.assert_array_equal(grid.z, [[3.0, 4.0], [1.0, 2.0]])


def test_example_asc_reads():
    grid = read_esri_ascii(EXAMPLES / "hill.asc")
    assert grid.z.shape == (21, 21) and grid.x[0] == -500.0 and grid.y[-1] == 500.0
    assert EXAMPLES.joinpath("hill.asc").stat().st_size < 50_000


_HEADER = "ncols 3\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 10\nNODATA_value -9999\n"


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("nrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3 4\n", "header lacks ncols"),
        (
            "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\nfoo 3\n1 2\n3 4\n",
            "line 6: unknown header key 'foo'",
        ),
        ("ncols 2.5\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3 4\n", "ncols must be a positive integer"),
        (
            "ncols 2\nnrows 2\nxllcorner 0\nxllcenter 0\nyllcorner 0\ncellsize 1\n",
            "exactly one of xllcorner and xllcenter",
        ),
        ("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 0\n1 2\n3 4\n", "cell size must be a positive number"),
        ("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\n1 2\n3 4\n", "header lacks cellsize"),
        ("ncols 2\nnrows 2\nncols 2\n", "line 3: duplicate header key 'ncols'"),
        ("ncols 2\nnrows 2\nxllcorner abc\n", "line 3: xllcorner value 'abc' is not a number"),
        (_HEADER + "1 2 3\n4 5\n", "line 8: data row 2 has 2 values; ncols is 3"),
        (_HEADER + "1 2 3\n4 x 6\n", "line 8, value 2: 'x' is not a number"),
        (_HEADER + "1 2 3\n4 5 6\n7 8 9\n", "line 9: more data rows than nrows = 2"),
        (_HEADER + "1 2 3\n", "only 1 data rows; nrows is 2"),
        ("ncols 1\nnrows 5\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n2\n3\n4\n5\n", "at least 2 x 2 samples"),
        ("ncols 6000\nnrows 6000\nxllcorner 0\nyllcorner 0\ncellsize 1\n", "36,000,000 height samples; the limit"),
    ],
)
def test_asc_errors(tmp_path, text, reason):
    path = tmp_path / "bad.asc"
    path.write_text(text)
    message = _raises(read_esri_ascii, path, match=reason)
    assert message.startswith(str(path) + ": ")


def test_asc_missing_heights_name_count_and_first_location(tmp_path):
    path = tmp_path / "holes.asc"
    path.write_text(_HEADER + "1 2 3\n4 -9999 nan\n")
    _raises(
        read_esri_ascii,
        path,
        match="2 heights are missing (NaN, infinite or NODATA); the first at line 8, column 2 (x=15, y=5)",
    )


def test_file_level_errors(tmp_path, monkeypatch):
    _raises(read_esri_ascii, tmp_path / "nope.asc", match="nope.asc: file not found")
    _raises(read_esri_ascii, tmp_path, match="not a regular file")
    path = tmp_path / "big.asc"
    path.write_text(_HEADER + "1 2 3\n4 5 6\n")
    monkeypatch.setattr(terrain_io, "MAX_FILE_BYTES", 16)
    _raises(read_esri_ascii, path, match="big.asc: file is 0 MiB; the limit is 0 MiB")
    assert issubclass(SceneFileError, JobInputError) and issubclass(SceneFileError, ValueError)


# ---------------------------------------------------------------------------------------------
# .npy / .npz
# ---------------------------------------------------------------------------------------------
def test_npy_and_npz_round_trip(tmp_path):
    z = np.arange(12.0).reshape(3, 4)
    np.save(tmp_path / "h.npy", z)
    grid = read_height_npy(tmp_path / "h.npy", origin=(10.0, 20.0), spacing=(2.0, 5.0))
    np.testing.assert_array_equal(grid.x, [10, 12, 14, 16])
    np.testing.assert_array_equal(grid.y, [20, 25, 30])
    np.testing.assert_array_equal(grid.z, z)
    np.savez(tmp_path / "a.npz", z=z, origin=[10.0, 20.0], spacing=[2.0, 5.0])
    same = read_terrain(tmp_path / "a.npz")
    assert isinstance(same, HeightGrid)
    np.testing.assert_array_equal(same.x, grid.x)
    np.testing.assert_array_equal(same.y, grid.y)
    x, y = np.array([0.0, 1.0, 3.0, 7.0]), np.array([-1.0, 0.0, 2.0])
    np.savez(tmp_path / "b.npz", x=x, y=y, z=z)
    axes = read_height_npz(tmp_path / "b.npz")
    np.testing.assert_array_equal(axes.x, x)
    np.testing.assert_array_equal(axes.z, z)


def test_npy_npz_errors(tmp_path):
    np.save(tmp_path / "flat.npy", np.zeros(5))
    _raises(read_height_npy, tmp_path / "flat.npy", (0, 0), (1, 1), match="must be a 2D array (ny, nx), got shape (5,)")
    np.save(tmp_path / "obj.npy", np.array([[{}, {}], [{}, {}]], dtype=object))
    _raises(read_height_npy, tmp_path / "obj.npy", (0, 0), (1, 1), match="obj.npy: not a readable .npy array")
    z = np.ones((3, 3))
    z[1, 2] = np.nan
    np.save(tmp_path / "nan.npy", z)
    _raises(
        read_height_npy,
        tmp_path / "nan.npy",
        (0, 0),
        (1, 1),
        match="1 heights are missing (NaN, infinite or NODATA); the first at the array[1, 2]",
    )
    np.save(tmp_path / "ok.npy", np.ones((3, 3)))
    _raises(read_height_npy, tmp_path / "ok.npy", (0, 0), (1, -1), match="spacing must be 2 positive numbers")
    _raises(read_terrain, tmp_path / "ok.npy", match="origin and spacing must be given")
    np.savez(tmp_path / "k.npz", z=np.ones((3, 3)), origin=[0, 0])
    _raises(read_height_npz, tmp_path / "k.npz", match="expected keys z, origin, spacing or x, y, z; found origin, z")
    np.savez(tmp_path / "dec.npz", x=[0.0, 2.0, 1.0], y=[0.0, 1.0, 2.0], z=np.ones((3, 3)))
    _raises(read_height_npz, tmp_path / "dec.npz", match="x must be finite and strictly increasing")
    np.savez(tmp_path / "shape.npz", x=[0.0, 1.0], y=[0.0, 1.0, 2.0], z=np.ones((3, 3)))
    _raises(read_height_npz, tmp_path / "shape.npz", match="x must have shape (3,) to match z of shape (3, 3)")
    np.savez(tmp_path / "a.npz", z=np.ones((3, 3)), origin=[0, 0], spacing=[1, 1])
    _raises(read_terrain, tmp_path / "a.npz", origin=(0, 0), spacing=(1, 1), match="only for .npy terrain")
    _raises(read_terrain, tmp_path / "a.tif", match="unknown terrain format 'tif'")
    # sizes are read from the headers: a 35 kB compressed archive must not inflate to 36 MB first
    np.savez_compressed(tmp_path / "bomb.npz", z=np.zeros((6000, 6000), np.uint8), origin=[0, 0], spacing=[1, 1])
    _raises(read_height_npz, tmp_path / "bomb.npz", match="z has shape (6000, 6000): more than 25,000,000 values")


# ---------------------------------------------------------------------------------------------
# Triangle meshes (trimesh)
# ---------------------------------------------------------------------------------------------
def _terrain_mesh(n: int = 9) -> tuple[np.ndarray, np.ndarray]:
    g = np.linspace(0.0, 80.0, n)
    xx, yy = np.meshgrid(g, g)
    # jitter interior points by multiples of 1/64 m (exact in float32): a unique Delaunay triangulation
    jitter = np.round(np.random.default_rng(n).uniform(-2.0, 2.0, (2, n - 2, n - 2)) * 64) / 64
    xx[1:-1, 1:-1] += jitter[0]
    yy[1:-1, 1:-1] += jitter[1]
    z = np.round(3.0 * np.sin(xx.ravel() / 15.0) + 0.01 * yy.ravel(), 6)  # exact in OBJ's 8-decimal text
    v = np.column_stack([xx.ravel(), yy.ravel(), z])
    return v, Delaunay(v[:, :2]).simplices.astype(np.int64)


def _export(tmp_path: Path, name: str, v: np.ndarray, f: np.ndarray) -> Path:
    trimesh = pytest.importorskip("trimesh")
    path = tmp_path / name
    trimesh.Trimesh(v, f, process=False).export(path)
    return path


@pytest.mark.parametrize("ext", ["obj", "stl", "ply"])
def test_terrain_mesh_round_trip(tmp_path, ext):
    v, f = _terrain_mesh()
    f_mixed = f.copy()
    f_mixed[::3] = f_mixed[::3, ::-1]  # mixed winding in the file; the reader orients every triangle
    surface = read_terrain(_export(tmp_path, f"t.{ext}", v, f_mixed))
    assert isinstance(surface, TriangleSurface)
    assert surface.vertices.shape == v.shape  # STL's per-corner copies merged back
    assert surface.triangles.shape == f.shape
    tri = surface.vertices[surface.triangles]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    assert np.all(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0)  # counter-clockwise from above
    # the same surface: heights at random points agree with scipy's linear interpolation of the input
    stored = surface.vertices[np.lexsort(surface.vertices.T[::-1])]  # the reader may reorder vertices
    np.testing.assert_allclose(stored, v[np.lexsort(v.T[::-1])], rtol=1e-7, atol=1e-6)  # STL: float32
    # the same surface: heights at random points agree with scipy's linear interpolation on its own
    # Delaunay triangulation of the vertices read back (the grid's xy are exact in float32)
    probe = np.random.default_rng(2).uniform(0.5, 79.5, (200, 2))
    reference = LinearNDInterpolator(surface.vertices[:, :2], surface.vertices[:, 2])(probe)
    np.testing.assert_allclose(terrain_height_at(surface, probe), reference, rtol=0, atol=1e-12)


def _stacked_sheet(v, f):
    v2 = v.copy()
    v2[:, 2] += 5.0
    v2[:, 0] += 0.3
    return np.vstack([v, v2]), np.vstack([f, f + len(v)])


def _fold(v, f):
    v = v.copy()
    centre = 40  # interior vertex: push it past its neighbours so its fan folds over
    v[centre, 0] += 25.0
    return v, f


@pytest.mark.parametrize(
    ("mutate", "reason"),
    [
        (_stacked_sheet, "overlaps another part of the surface seen from above"),
        (_fold, "not a height field"),
        (
            lambda v, f: (np.vstack([v, v[:1] + [0, 0, 7.0]]), np.vstack([f, [[len(v), 1, 9]]])),
            "lie on one vertical line",
        ),
        (
            lambda v, f: (np.vstack([v, [[0, -5, 0], [10, -5, 0], [5, -5, 3]]]), np.vstack([f, [[81, 82, 83]]])),
            "is vertical",
        ),
        (lambda v, f: (v, np.vstack([f, f[:1]])), "shared by 3 triangles"),
    ],
)
def test_terrain_mesh_not_height_field(tmp_path, mutate, reason):
    v, f = mutate(*_terrain_mesh())
    path = _export(tmp_path, "bad.ply", v, f)
    _raises(read_terrain_mesh, path, match=reason)
    _raises(read_terrain_mesh, path, match="bad.ply: terrain mesh: ")


def test_mesh_basic_errors(tmp_path):
    v, f = _terrain_mesh(4)
    v_nan = v.copy()
    v_nan[3, 2] = np.nan
    _raises(
        read_terrain_mesh,
        _export(tmp_path, "nan.ply", v_nan, f),
        match="1 vertices have NaN or infinite coordinates (first: vertex 3)",
    )
    v_deg = np.vstack([v, [[1.0, 1.0, 0.0], [2.0, 2.0, 0.0], [3.0, 3.0, 0.0]]])
    f_deg = np.vstack([f, [[len(v), len(v) + 1, len(v) + 2]]])
    _raises(read_terrain_mesh, _export(tmp_path, "deg.ply", v_deg, f_deg), match="1 degenerate (zero-area) triangles")
    (tmp_path / "junk.obj").write_text("hello\n")
    _raises(read_terrain_mesh, tmp_path / "junk.obj", match="junk.obj: no triangles found")
    (tmp_path / "t.off").write_text("OFF\n")
    _raises(read_terrain_mesh, tmp_path / "t.off", match="unsupported mesh format 'off'")


def _box(lo=(0.0, 0.0, 0.0), hi=(2.0, 3.0, 4.0)) -> tuple[np.ndarray, np.ndarray]:
    trimesh = pytest.importorskip("trimesh")
    lo, hi = np.asarray(lo), np.asarray(hi)
    m = trimesh.creation.box(extents=hi - lo)
    return np.asarray(m.vertices) + (lo + hi) / 2, np.asarray(m.faces, dtype=np.int64)


@pytest.mark.parametrize("ext", ["obj", "stl", "ply"])
def test_obstacle_round_trip(tmp_path, ext):
    trimesh = pytest.importorskip("trimesh")
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=3.0)
    v1, f1 = np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)
    v2, f2 = _box((10, 0, 0), (12, 3, 4))  # a second, separate shell in the same file
    v, f = np.vstack([v1, v2]), np.vstack([f1, f2 + len(v1)])
    verts, faces = read_obstacle_mesh(_export(tmp_path, f"o.{ext}", v, f))
    assert verts.shape == v.shape and faces.shape == f.shape
    # same solid: the divergence-theorem volume equals trimesh's
    tri = verts[faces]
    volume = np.einsum("fd,fd->", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    np.testing.assert_allclose(volume, sphere.volume + 24.0, rtol=1e-6)  # STL stores float32


def _two_tets_sharing_an_edge():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [0, -1, 0], [0, 0, -1]], dtype=float)
    tet = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    other = np.array([[0, 1, 4], [0, 5, 1], [0, 4, 5], [1, 5, 4]])  # shares edge 0-1 only
    return v, np.vstack([tet, other])


@pytest.mark.parametrize(
    ("make", "reason"),
    [
        (lambda: (_box()[0], _box()[1][1:]), "not watertight: 3 edges belong to a single triangle"),
        (lambda: (_box()[0], _box()[1][:, ::-1]), "has signed volume -24 m^3"),
        (lambda: (_box()[0], np.vstack([_box()[1][:1, ::-1], _box()[1][1:]])), "inconsistently oriented"),
        (_two_tets_sharing_an_edge, "not manifold: 1 edges are shared by more than two triangles"),
        (
            lambda: (np.vstack([_box()[0], _box((1, 1, 1), (3, 4, 5))[0]]), np.vstack([_box()[1], _box()[1] + 8])),
            "self-intersecting: triangles",
        ),
    ],
)
def test_obstacle_errors(tmp_path, make, reason):
    v, f = make()
    path = _export(tmp_path, "obstacle.ply", v, f)
    _raises(read_obstacle_mesh, path, match=reason)
    _raises(read_obstacle_mesh, path, match="obstacle.ply: obstacle mesh: ")


def test_triangles_intersect_cases():
    t = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    cases = {
        "piercing": (np.array([[0.2, 0.2, -1], [0.3, 0.2, 1], [0.2, 0.3, 1]]), True),
        "above": (t + [0, 0, 0.5], False),
        "coplanar overlap": (t + [0.2, 0.2, 0], True),
        "coplanar apart": (t + [2, 0, 0], False),
        "touching at an edge": (np.array([[1.0, 0, 0], [0, 1, 0], [1, 1, 0]]), False),
        "crossing edge": (np.array([[0.25, -1, 0.0], [0.25, 1, 0.0], [0.25, 0, 1]]) + [0, 0, -0.5], True),
    }
    for name, (other, expected) in cases.items():
        got = triangles_intersect(t[None], other[None], tol=1e-9)[0]
        assert got == expected, name


# ---------------------------------------------------------------------------------------------
# GeoJSON footprints
# ---------------------------------------------------------------------------------------------
def _feature(coords, **props):
    return {"type": "Feature", "properties": props, "geometry": {"type": "Polygon", "coordinates": coords}}


def _write_geojson(path: Path, features) -> Path:
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    return path


def test_geojson_round_trip(tmp_path):
    clockwise = [[0, 0], [0, 10], [20, 10], [20, 10], [20, 0], [0, 0]]  # closed, a repeated vertex
    path = _write_geojson(
        tmp_path / "b.geojson",
        [
            _feature([clockwise], height=12.5, name="town hall", material="brick", base_z=3.0),
            _feature([[[30, 0, 1.0], [40, 0, 1.0], [35, 8, 1.0]]], height=4),
        ],
    )
    fps = read_footprints_geojson(path, {"rigid": 0, "brick": 1})
    assert [fp.name for fp in fps] == ["town hall", "feature 1"]
    ccw = np.array([[0, 0], [20, 0], [20, 10], [0, 10]])  # the same ring, counter-clockwise, not closed
    start = int(np.flatnonzero(np.all(ccw == fps[0].polygon[0], axis=1))[0])
    np.testing.assert_array_equal(fps[0].polygon, np.roll(ccw, -start, axis=0))
    assert fps[0].height_m == 12.5 and fps[0].base_z == 3.0 and fps[0].material == 1
    np.testing.assert_array_equal(fps[1].polygon, [[30, 0], [40, 0], [35, 8]])
    assert fps[1].base_z is None and fps[1].material == 0
    assert len(read_footprints_geojson(EXAMPLES / "buildings.geojson")) == 3


_SQUARE = [[[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]]]


@pytest.mark.parametrize(
    ("features", "reason"),
    [
        (
            [_feature(_SQUARE + [[[2, 2], [14, 2], [4, 4], [2, 2]]], height=5)],
            "features.0: Self-intersection at (10, 2.8",
        ),
        (
            [{"type": "Feature", "properties": {"height": 5}, "geometry": {"type": "MultiPolygon", "coordinates": []}}],
            "MultiPolygon coordinates must be a non-empty list",
        ),
        (
            [{"type": "Feature", "properties": {}, "geometry": {"type": "Point", "coordinates": [0, 0]}}],
            "geometry must be a Polygon or MultiPolygon, got 'Point'",
        ),
        (
            [_feature([[[0, 0], [10, 10], [10, 0], [0, 10], [0, 0]]], height=5, name="bow")],
            "features.0 ('bow'): Self-intersection at (5, 5)",
        ),
        ([_feature([[[0, 0], [10, 0], [0, 0], [10, 0]]], height=5)], "at least 3 distinct vertices, got 2"),
        ([_feature([[[0, 0], [5, 0], [10, 0]]], height=5)], "zero area"),
        ([_feature(_SQUARE)], 'give a "height" property (metres) or "building:levels"'),
        ([_feature(_SQUARE, height=True)], "got True"),
        ([_feature(_SQUARE, height=0)], "height 0 m must be > 0 and < 1000 m"),
        ([_feature(_SQUARE, height=1000)], "height 1000 m must be > 0 and < 1000 m"),
        ([_feature(_SQUARE, height=5, base_z="low")], '"base_z" must be a number (metres) or null'),
        (
            [_feature(_SQUARE, height=5), _feature(_SQUARE, height=5, material="glass")],
            "features.1: material 'glass' is not defined",
        ),
        ([_feature([[[0, 0], [10, "a"], [0, 10]]], height=5)], "list of [x, y] positions with finite numbers"),
    ],
)
def test_geojson_feature_errors(tmp_path, features, reason):
    path = _write_geojson(tmp_path / "bad.geojson", features)
    message = _raises(read_footprints_geojson, path, match=reason)
    assert message.startswith(f"{path}: ")


def test_geojson_document_errors(tmp_path):
    path = tmp_path / "x.geojson"
    path.write_text('{"type": "FeatureCollection",\n "features": [}')
    _raises(read_footprints_geojson, path, match="x.geojson: invalid JSON at line 2, column 15")
    path.write_text('{"type": "FeatureCollection", "features": [NaN]}')
    _raises(read_footprints_geojson, path, match="NaN is not allowed")
    path.write_text('{"type": "Feature"}')
    _raises(read_footprints_geojson, path, match='expected a GeoJSON object with "type": "FeatureCollection"')


# ---------------------------------------------------------------------------------------------
# Geometry helpers against brute force / scipy
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dim", [2, 3])
def test_box_pairs_matches_brute_force(dim):
    rng = np.random.default_rng(dim)
    lo = rng.uniform(0, 100, (300, dim))
    hi = lo + rng.uniform(0, 8, (300, dim)) ** 2 / 8  # a spread of sizes
    hi[:5] = lo[:5] + 60.0  # a few large boxes
    hi[5] = lo[5]  # a point
    ia, ib = box_pairs(lo, hi)
    ours = set(zip(ia.tolist(), ib.tolist(), strict=True))
    overlap = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)
    brute = {(i, j) for i, j in zip(*np.nonzero(np.triu(overlap, 1)), strict=True)}
    assert ours == brute
    pa, pb = box_pairs(lo[:50], hi[:50], lo[50:], hi[50:])
    brute_ab = {(i, j) for i, j in zip(*np.nonzero(overlap[:50, 50:]), strict=True)}
    assert set(zip(pa.tolist(), pb.tolist(), strict=True)) == brute_ab


def test_height_grid_lookup_matches_scipy_bilinear():
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.uniform(1, 5, 12))
    y = np.cumsum(rng.uniform(1, 5, 9))
    grid = HeightGrid(x=x, y=y, z=rng.uniform(0, 30, (9, 12)))
    probe = np.column_stack([rng.uniform(x[0], x[-1], 500), rng.uniform(y[0], y[-1], 500)])
    reference = RegularGridInterpolator((y, x), grid.z, method="linear")(probe[:, ::-1])
    np.testing.assert_allclose(terrain_height_at(grid, probe), reference, rtol=1e-13, atol=1e-12)
    assert np.all(np.isnan(terrain_height_at(grid, [[x[0] - 1, y[0]], [x[0], y[-1] + 1e-9]])))


def test_locate_points_barycentric():
    tri = np.array([[[0.0, 0.0], [4.0, 0.0], [0.0, 2.0]]])
    pts = np.array([[1.0, 0.5], [3.0, 1.0], [0.0, 0.0]])
    ip, it, bary = locate_points_2d(pts, tri)
    assert ip.tolist() == [0, 2] and it.tolist() == [0, 0]  # (3, 1) is outside; a vertex counts (closed)
    np.testing.assert_allclose(bary @ tri[0], pts[[0, 2]], atol=1e-12)
    assert locate_points_2d(pts, tri, strict=True)[0].tolist() == [0]


def test_polygon_checks():
    assert polygon_from_rings([[0, 0], [4, 0], [4, 3], [0, 3]])[1] is None
    assert "Self-intersection at (8, 0)" in polygon_from_rings([[0, 0], [4, 0], [8, 0], [4, 0.0], [4, 3]])[1]
    touching = [[0, 0], [4, 0], [4, 4], [2, 0], [0, 4.0]]  # vertex 3 touches edge 0
    assert "Ring Self-intersection at (2, 0)" in polygon_from_rings(touching)[1]

    def square(dx, dy, size=4.0):
        return polygon_from_rings([[dx, dy], [dx + size, dy], [dx + size, dy + size], [dx, dy + size]])[0]

    assert overlapping_pairs([square(0, 0), square(3, 3)]) == [(0, 1)]
    assert overlapping_pairs([square(0, 0), square(4, 0)]) == []  # shared wall
    assert overlapping_pairs([square(0, 0), square(4, 4)]) == []  # common corner
    assert overlapping_pairs([square(0, 0), square(0, 0)]) == [(0, 1)]  # identical
    assert overlapping_pairs([square(0, 0), square(1, 1, 1.0)]) == [(0, 1)]  # contained
    cross_a = np.array([[-5, -1], [5, -1], [5, 1], [-5, 1.0]])
    plus = [polygon_from_rings(cross_a)[0], polygon_from_rings(cross_a[:, ::-1])[0]]
    assert overlapping_pairs(plus) == [(0, 1)]  # a plus sign: no vertex inside the other

"""Field writers: .vti point order round-tripped through pyvista, atomic writes, PNG preview slices."""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

import matplotlib
import matplotlib.image
import numpy as np
import pytest
import pyvista as pv

from bentray.engine.field_output import (
    nearest_index,
    preview_slice_indices,
    write_field_vti,
    write_preview_png,
)

ORIGIN = (1.0, -2.0, 0.5)
SPACING = (0.5, 2.0, 3.0)
SHAPE = (4, 3, 2)


def _asymmetric() -> np.ndarray:
    i, j, k = np.meshgrid(*(np.arange(n) for n in SHAPE), indexing="ij")
    return 100.0 * i + 10.0 * j + k + 0.25  # every node distinct, no symmetry between axes


def test_vti_point_order_round_trip(tmp_path: Path) -> None:
    values = _asymmetric()
    vec = np.stack([values, -values, 2 * values], axis=-1)
    path = write_field_vti(
        tmp_path / "field.vti",
        ORIGIN,
        SPACING,
        SHAPE,
        {"spl_db": values, "vec": vec, "ids": np.arange(24, dtype=np.int32).reshape(SHAPE)},
        {"spl_units": "dB re 20 uPa", "time_convention": "exp(-i w t)", "frequency_hz": 500.0,
         "bands_hz": [63.0, 125.0], "frames": ["world", "metres", "z up"]},
    )  # fmt: skip
    grid = pv.read(path)
    assert tuple(grid.dimensions) == SHAPE
    np.testing.assert_allclose(grid.origin, ORIGIN)
    np.testing.assert_allclose(grid.spacing, SPACING)
    pts = np.asarray(grid.points)
    ijk = np.rint((pts - ORIGIN) / SPACING).astype(int)
    np.testing.assert_allclose(pts, ORIGIN + ijk * SPACING, atol=1e-12)
    got = np.asarray(grid.point_data["spl_db"])
    assert got.dtype == np.float64
    # value at (i, j, k) lands at the point origin + (i dx, j dy, k dz)
    np.testing.assert_array_equal(got, values[ijk[:, 0], ijk[:, 1], ijk[:, 2]])
    np.testing.assert_array_equal(np.asarray(grid.point_data["vec"]), vec[ijk[:, 0], ijk[:, 1], ijk[:, 2]])
    ids = np.asarray(grid.point_data["ids"])
    assert ids.dtype == np.int32
    # VTK order: x fastest, then y, then z
    np.testing.assert_array_equal(ids, np.arange(24).reshape(SHAPE)[ijk[:, 0], ijk[:, 1], ijk[:, 2]])
    np.testing.assert_array_equal(ijk[:5], [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [0, 1, 0]])
    fd = grid.field_data
    assert str(fd["spl_units"][0]) == "dB re 20 uPa"
    assert str(fd["time_convention"][0]) == "exp(-i w t)"
    assert float(fd["frequency_hz"][0]) == 500.0
    np.testing.assert_array_equal(fd["bands_hz"], [63.0, 125.0])
    assert [str(x) for x in fd["frames"]] == ["world", "metres", "z up"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["field.vti"]  # no temporary file left


def test_vti_failed_write_leaves_previous_file(tmp_path: Path) -> None:
    path = write_field_vti(tmp_path / "f.vti", ORIGIN, SPACING, SHAPE, {"a": _asymmetric()})
    before = path.read_bytes()
    with pytest.raises(ValueError, match="shape"):
        write_field_vti(path, ORIGIN, SPACING, SHAPE, {"a": np.zeros((3, 4, 2))})
    with pytest.raises(ValueError, match="field data"):
        write_field_vti(path, ORIGIN, SPACING, SHAPE, {"a": _asymmetric()}, {"bad": [[1.0, 2.0]]})
    with pytest.raises(ValueError, match="spacing"):
        write_field_vti(path, ORIGIN, (1.0, 0.0, 1.0), SHAPE, {"a": _asymmetric()})
    with pytest.raises(ValueError, match="shape"):
        write_field_vti(path, ORIGIN, SPACING, (4, 3, 0), {"a": np.zeros((4, 3, 0))})
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.vti"]


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_files_get_the_modes_open_would_give(tmp_path: Path, umask: int) -> None:
    """field.vti and preview.png are written through a temporary file: it must get 0o666 less the umask, as
    a file opened directly (report.json) does, not mkstemp's 0o600."""
    old = os.umask(umask)
    try:
        vti = write_field_vti(tmp_path / "f.vti", ORIGIN, SPACING, SHAPE, {"a": _asymmetric()})
        png = write_preview_png(tmp_path / "p.png", ORIGIN, SPACING, SHAPE, _asymmetric(), source_xyz=ORIGIN,
                                receiver_z=0.5)  # fmt: skip
        with (tmp_path / "plain.json").open("w") as fh:
            fh.write("{}")
    finally:
        os.umask(old)
    want = 0o666 & ~umask
    assert stat.S_IMODE((tmp_path / "plain.json").stat().st_mode) == want
    assert stat.S_IMODE(vti.stat().st_mode) == want
    assert stat.S_IMODE(png.stat().st_mode) == want
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.vti", "p.png", "plain.json"]  # no temporary left


def test_nearest_index() -> None:
    assert nearest_index(0.0, 1.0, 10, 3.4) == 3
    assert nearest_index(0.0, 1.0, 10, 3.6) == 4
    assert nearest_index(0.0, 1.0, 10, 3.5) == 3  # tie goes to the lower node
    assert nearest_index(0.0, 1.0, 10, -7.0) == 0  # clamped
    assert nearest_index(0.0, 1.0, 10, 99.0) == 9
    assert nearest_index(5.0, 2.5, 1, 100.0) == 0  # one-node axis
    assert nearest_index(-10.0, 0.1, 201, 0.0) == 100
    with pytest.raises(ValueError):
        nearest_index(0.0, 0.0, 3, 1.0)


def test_preview_slice_indices() -> None:
    origin, spacing, shape = (-50.0, -20.0, 0.0), (5.0, 4.0, 0.5), (21, 11, 9)
    # receiver at 1.6 m -> z nodes 0, 0.5, 1.0, 1.5, 2.0: nearest is 1.5 (k = 3); source y = 3.1 -> nodes
    # -20 + 4 j: 4.0 is j = 6 (|0.9|) against 0.0 at j = 5 (|3.1|)
    assert preview_slice_indices(origin, spacing, shape, (0.0, 3.1, 2.0), 1.6) == (3, 6)
    assert preview_slice_indices(origin, spacing, shape, (0.0, -100.0, 2.0), 100.0) == (8, 0)
    assert preview_slice_indices(origin, spacing, (21, 1, 1), (0.0, 3.1, 2.0), 1.6) == (0, 0)


def _png_shape(path: Path) -> tuple[int, ...]:
    img = matplotlib.image.imread(path)
    assert img.ndim == 3 and img.shape[2] in (3, 4)
    return img.shape


def test_preview_png_panels_and_degenerate_grids(tmp_path: Path) -> None:
    backend = matplotlib.get_backend()
    had_pyplot = "matplotlib.pyplot" in sys.modules
    rng = np.random.default_rng(3)
    full = 60.0 + rng.normal(size=(21, 11, 9))
    full[3, 4, :] = np.nan
    full[5, :, 2] = -np.inf
    p = write_preview_png(tmp_path / "full.png", (-50, -20, 0), (5, 4, 0.5), full.shape, full,
                          source_xyz=(0, 0, 2), receiver_z=1.5, title="t", label="SPL (dB)")  # fmt: skip
    assert _png_shape(p)[:2] == (450, 1200)  # two panels of 600 x 450 px
    line = 50.0 - 20 * np.log10(np.linspace(1, 200, 201)).reshape(201, 1, 1)
    line[10] = np.nan
    p = write_preview_png(tmp_path / "line.png", (0, 0, 1.5), (1, 1, 1), (201, 1, 1), line,
                          source_xyz=(0, 0, 2), receiver_z=1.5)  # fmt: skip
    assert _png_shape(p)[:2] == (450, 600)  # one line panel
    plane = rng.normal(size=(30, 1, 12))  # a vertical x-z section: one panel (the x-y slice is its row)
    p = write_preview_png(tmp_path / "xz.png", (0, 0, 0), (1, 1, 1), plane.shape, plane,
                          source_xyz=(0, 0, 2), receiver_z=1.5)  # fmt: skip
    assert _png_shape(p)[:2] == (450, 600)
    horiz = rng.normal(size=(30, 20, 1))
    p = write_preview_png(tmp_path / "xy.png", (0, 0, 0), (1, 1, 1), horiz.shape, horiz,
                          source_xyz=(0, 0, 2), receiver_z=1.5)  # fmt: skip
    assert _png_shape(p)[:2] == (450, 600)
    empty = np.full((5, 4, 3), np.nan)
    p = write_preview_png(tmp_path / "nan.png", (0, 0, 0), (1, 1, 1), empty.shape, empty,
                          source_xyz=(0, 0, 0), receiver_z=0.0)  # fmt: skip
    assert _png_shape(p)[:2] == (450, 1200)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["full.png", "line.png", "nan.png", "xy.png", "xz.png"]
    assert matplotlib.get_backend() == backend
    assert ("matplotlib.pyplot" in sys.modules) == had_pyplot
    with pytest.raises(ValueError, match="values"):
        write_preview_png(tmp_path / "bad.png", (0, 0, 0), (1, 1, 1), (5, 4, 3), np.zeros((5, 4)),
                          source_xyz=(0, 0, 0), receiver_z=0.0)  # fmt: skip
    assert not (tmp_path / "bad.png").exists()


def test_terrain_following_slice_picks_the_node_above_the_ground(tmp_path):
    from bentray.engine.field_output import terrain_following_slice, write_preview_png

    # values = the node's own z, so the slice must return ground + height rounded to the grid
    origin, spacing, shape = np.array([0.0, 0.0, 1.0]), np.array([10.0, 10.0, 2.0]), (4, 3, 20)
    z = origin[2] + spacing[2] * np.arange(shape[2])
    values = np.broadcast_to(z, shape).copy()
    ground = np.array([[0.0, 3.0, 10.0], [20.0, 33.0, 50.0], [1.0, 1.0, 1.0], [7.9, 8.1, 36.0]])
    got = terrain_following_slice(values, origin, spacing, ground, 4.0)
    want = origin[2] + spacing[2] * np.rint((ground + 4.0 - origin[2]) / spacing[2])
    want[want > z[-1]] = np.nan  # beyond the top node: blank
    np.testing.assert_array_equal(got, want)
    out = write_preview_png(
        tmp_path / "p.png",
        origin,
        spacing,
        shape,
        values,
        source_xyz=[5, 5, 3],
        receiver_z=5.0,
        ground_z=ground,
        receiver_height=4.0,
    )
    assert out.stat().st_size > 0

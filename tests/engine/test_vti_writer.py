"""write_image_data writes the file pyvista wrote (ImageData.save(binary=True, compression="lz4")) byte for
byte: every point-array dtype (booleans with pyvista's record of them), vectors first or not, string,
string-list and numeric field data; and pyvista reads the booleans back as booleans."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bentray.engine.field_output import _field_value, _vtk_order
from bentray.engine.vti_writer import write_image_data

pv = pytest.importorskip("pyvista")

SHAPE = (4, 3, 2)
ORIGIN, SPACING = (1.0, -2.0, 0.5), (0.5, 1.0, 2.0)


def _arrays(first_vector: bool) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(5)
    arrays = {
        "f64": rng.normal(size=SHAPE),
        "f32": rng.normal(size=SHAPE).astype(np.float32),
        "i64": rng.integers(-9, 9, size=SHAPE),
        "flag": rng.normal(size=SHAPE) > 0,
        "u8": rng.integers(0, 9, size=SHAPE).astype(np.uint8),
        "nan": np.where(rng.normal(size=SHAPE) > 0, np.nan, 1.0),
    }
    vec = {"vec": rng.normal(size=SHAPE + (3,))}
    return {**vec, **arrays} if first_vector else {**arrays, **vec}


FIELD_DATA = {"units": "dB", "f": 3.5, "i": 2, "names": ["a", "bb"], "nums": [1.0, 2.5], "np": np.float32(1.5)}


def _pyvista_file(path: Path, arrays: dict[str, np.ndarray]) -> Path:
    grid = pv.ImageData(dimensions=SHAPE, spacing=SPACING, origin=ORIGIN)
    for name, values in arrays.items():
        grid.point_data[name] = _vtk_order(name, values, SHAPE)
    for name, value in FIELD_DATA.items():
        grid.field_data[name] = _field_value(name, value)
    grid.save(str(path), binary=True, compression="lz4")
    return path


@pytest.mark.parametrize("first_vector", [False, True])
def test_same_bytes_as_pyvista(tmp_path: Path, first_vector: bool) -> None:
    arrays = _arrays(first_vector)
    ours = tmp_path / "ours.vti"
    points = {name: _vtk_order(name, values, SHAPE) for name, values in arrays.items()}
    write_image_data(ours, SHAPE, SPACING, ORIGIN, points, {k: _field_value(k, v) for k, v in FIELD_DATA.items()})
    assert ours.read_bytes() == _pyvista_file(tmp_path / "pyvista.vti", arrays).read_bytes()
    grid = pv.read(ours)
    assert grid.point_data["flag"].dtype == np.bool_
    np.testing.assert_array_equal(grid.point_data["flag"], _vtk_order("flag", arrays["flag"], SHAPE))
    np.testing.assert_array_equal(grid.point_data["vec"], _vtk_order("vec", arrays["vec"], SHAPE))

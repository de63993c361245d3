"""field.vti carries the scene CRS (WKT and EPSG code) and the local origin as field data."""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine.export.field_grid import read_field_vti
from bentray.engine.field_output import write_field_vti
from bentray.scenes.crs import LocalFrame, parse_crs

pytest.importorskip("pyproj")


def test_vti_field_data_round_trip(tmp_path):
    import pyvista as pv

    frame = LocalFrame(origin=(500_000.0, 5_400_000.0), crs_wkt=parse_crs(32632).to_wkt())
    fd = {"spl_units": "dB re 1e-12 W/m^2", **frame.vti_field_data()}
    write_field_vti(tmp_path / "field.vti", (0, 0, 0), (1, 1, 1), (3, 2, 1), {"spl_a": np.ones((3, 2, 1))}, fd)
    grid = pv.read(tmp_path / "field.vti")
    assert int(np.asarray(grid.field_data["crs_epsg"]).ravel()[0]) == 32632
    np.testing.assert_array_equal(np.asarray(grid.field_data["local_origin_m"]).ravel(), [500_000.0, 5_400_000.0])
    assert "x_crs = x + local_origin_m[0]" in str(np.asarray(grid.field_data["georeference"]).ravel()[0])
    back = read_field_vti(tmp_path / "field.vti").frame
    assert back.origin == frame.origin and parse_crs(back.crs_wkt) == parse_crs(frame.crs_wkt)
    assert LocalFrame().vti_field_data() == {}  # no CRS: nothing added

"""bentray export on a synthetic field.vti: rasters read back by rasterio with the right CRS, transform and
values; isophone band areas against the exact area of a field linear in x; exposure counts; slices and
point levels exact for fields whose energy is linear (trilinear) in the coordinates."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bentray.clients.cli import main
from bentray.engine.export.facades import levels_at_points
from bentray.engine.export.isophones import isophone_bands
from bentray.engine.export.slices import slice_above_ground, slice_at_z
from bentray.engine.field_output import write_field_vti

rasterio = pytest.importorskip("rasterio")
shapely = pytest.importorskip("shapely")

ORIGIN = np.array([10.0, 20.0, 0.0])  # local frame
SPACING = np.array([5.0, 5.0, 2.0])
SHAPE = (41, 21, 6)  # x 10..210, y 20..120, z 0..10
X0, Y0 = 500_000.0, 5_400_000.0


def _axes():
    return [ORIGIN[d] + SPACING[d] * np.arange(SHAPE[d]) for d in range(3)]


def _field(tmp_path):
    x, y, z = np.meshgrid(*_axes(), indexing="ij")
    spl_a = 90.0 - 0.25 * (x - ORIGIN[0]) + 0.0 * y + 0.1 * z  # 90 dB at x = 10 falling to 40 dB at x = 210
    spl_a[0, 0, :] = np.nan  # one unreached column
    energy = 1.0 + 0.5 * x + 0.25 * y + 2.0 * z  # trilinear energy: interpolation is exact
    out = tmp_path / "result"
    write_field_vti(out / "field.vti", ORIGIN, SPACING, SHAPE, {"spl_a": spl_a, "spl_e": 10 * np.log10(energy)})
    return out, spl_a, energy


def test_geotiff_and_ascii_read_back_with_crs_and_transform(tmp_path):
    result, spl_a, _ = _field(tmp_path)
    args = [
        "export",
        str(result),
        "--format",
        "geotiff,asc",
        "--z",
        "4.4",
        "--crs",
        "32632",
        "--origin",
        str(X0),
        str(Y0),
    ]
    assert main(args) == 0
    k = 2  # z = 4.4 -> nearest level z = 4
    for name in ("map_spl_a.tif", "map_spl_a.asc"):
        with rasterio.open(result / "export" / name) as src:
            assert src.crs.to_epsg() == 32632, name
            band = src.read(1, masked=True)
            assert band.shape == (SHAPE[1], SHAPE[0])
            for i, j in [(0, 1), (7, 3), (40, 20), (13, 0)]:
                row, col = SHAPE[1] - 1 - j, i
                xc, yc = src.transform @ (col + 0.5, row + 0.5)  # cell centre
                assert xc == pytest.approx(X0 + ORIGIN[0] + i * SPACING[0], abs=1e-6), name
                assert yc == pytest.approx(Y0 + ORIGIN[1] + j * SPACING[1], abs=1e-6), name
                assert float(band[row, col]) == pytest.approx(spl_a[i, j, k], abs=1e-4), name  # float32 / %.6f
            assert band.mask[SHAPE[1] - 1, 0]  # the NaN column is NODATA
    assert (result / "export" / "map_spl_a.prj").read_text().startswith("PROJCS[")


def test_isophone_band_areas_are_exact_for_a_linear_field(tmp_path):
    result, spl_a, _ = _field(tmp_path)
    assert main(["export", str(result), "--format", "isophones,exposure", "--z", "0", "--levels", "45,50,60"]) == 0
    data = json.loads((result / "export" / "isophones_spl_a.geojson").read_text())
    assert "crs" not in data  # no georeference given: local metres
    areas = {f["properties"]["label"]: shapely.geometry.shape(f["geometry"]).area for f in data["features"]}
    # L = 90 - 0.25 (x - 10) on x 10..210: L in [45, 50) for x in (170, 190], [50, 60) for (130, 170],
    # >= 60 for x <= 130 (the NaN node at x = 10, y = 20: contourpy's corner mask drops half its cell, 12.5 m^2)
    height = 100.0
    assert areas["45-50 dB"] == pytest.approx(20.0 * height, rel=1e-9)
    assert areas["50-60 dB"] == pytest.approx(40.0 * height, rel=1e-9)
    assert areas[">= 60 dB"] == pytest.approx(120.0 * height - 12.5, rel=1e-9)
    exposure = json.loads((result / "export" / "exposure.json").read_text())
    classes = exposure["area"]["classes"]
    lv = spl_a[:, :, 0]
    cell = 25.0
    for c, (lo, hi) in zip(classes, [(45, 50), (50, 60), (60, math.inf)], strict=True):
        assert c["area_m2"] == cell * int(np.count_nonzero((lv >= lo) & (lv < hi)))
    assert exposure["area"]["no_level_m2"] == cell
    assert exposure["area"]["below_m2"] == cell * int(np.count_nonzero(lv < 45))


def test_slices_and_point_levels_are_exact_for_linear_energy(tmp_path):
    x, y, z = _axes()
    gx, gy, gz = np.meshgrid(x, y, z, indexing="ij")
    energy = 1.0 + 0.5 * gx + 0.25 * gy + 2.0 * gz
    level = 10 * np.log10(energy)
    ground = 0.3 + 0.01 * gx[:, :, 0]  # a ground below the top, sloping
    h = 3.7
    got = slice_above_ground(level, ORIGIN[2], SPACING[2], ground, h)
    want = 10 * np.log10(1.0 + 0.5 * gx[:, :, 0] + 0.25 * gy[:, :, 0] + 2.0 * (ground + h))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert np.all(np.isnan(slice_above_ground(level, ORIGIN[2], SPACING[2], ground, 20.0)))
    sl, zk = slice_at_z(level, ORIGIN[2], SPACING[2], 5.1)
    assert zk == 6.0 and np.array_equal(sl, level[:, :, 3])
    rng = np.random.default_rng(1)
    p = np.column_stack([rng.uniform(10, 210, 50), rng.uniform(20, 120, 50), rng.uniform(0, 10, 50)])
    want_p = 10 * np.log10(1.0 + 0.5 * p[:, 0] + 0.25 * p[:, 1] + 2.0 * p[:, 2])
    np.testing.assert_allclose(levels_at_points(level, ORIGIN, SPACING, p), want_p, rtol=0, atol=1e-12)
    assert np.isnan(levels_at_points(level, ORIGIN, SPACING, [[0.0, 50.0, 2.0]]))[0]


def test_facades_and_building_exposure(tmp_path):
    result, spl_a, _ = _field(tmp_path)
    b = tmp_path / "b.geojson"
    ring = [[X0 + 100, Y0 + 50], [X0 + 120, Y0 + 50], [X0 + 120, Y0 + 60], [X0 + 100, Y0 + 60], [X0 + 100, Y0 + 50]]
    feature = {"type": "Feature", "properties": {"height": 7.0}, "geometry": {"type": "Polygon", "coordinates": [ring]}}
    b.write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    args = ["export", str(result), "--format", "facades,exposure", "--height", "4", "--ground-z", "0",
            "--buildings", str(b), "--crs", "EPSG:32632", "--origin", str(X0), str(Y0)]  # fmt: skip
    assert main(args) == 0
    data = json.loads((result / "export" / "facades.geojson").read_text())
    assert data["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32632"
    pts = np.array([f["geometry"]["coordinates"] for f in data["features"]])
    assert len(pts) == 2 * (4 + 4 + 2 + 2)  # 20 m walls: 4 pieces, 10 m walls: 2; storeys at 1.5 and 4.5 m
    poly = shapely.geometry.Polygon(ring)
    np.testing.assert_allclose(shapely.distance(poly, shapely.points(pts[:, :2])), 2.0, rtol=0, atol=1e-9)
    # the field is linear in dB along x only and trilinear interpolation is in energy: check against it
    local = pts - [X0, Y0, 0.0]
    want = levels_at_points(spl_a, ORIGIN, SPACING, local)
    got = np.array([f["properties"]["spl_a"] for f in data["features"]])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    csv_rows = (result / "export" / "facades.csv").read_text().splitlines()
    assert csv_rows[0] == "id,x,y,z,building,storey,spl_a" and len(csv_rows) == len(pts) + 1
    exposure = json.loads((result / "export" / "exposure.json").read_text())
    top = float(np.max(want))
    counted = [c for c in exposure["buildings"]["classes"] if c["buildings"]]
    assert len(counted) == 1 and counted[0]["level_min"] <= top < (counted[0]["level_max"] or math.inf)


def test_export_errors(tmp_path, capsys):
    result, _, _ = _field(tmp_path)
    assert main(["export", str(result), "--format", "geotiff", "--z", "4", "--array", "spl_x"]) == 1
    assert "--array 'spl_x': field.vti has spl_a, spl_e" in capsys.readouterr().err
    assert main(["export", str(result), "--format", "geotiff", "--z", "4", "--crs", "4326"]) == 1
    assert "is not projected" in capsys.readouterr().err
    assert main(["export", str(result), "--format", "geotiff", "--z", "50"]) == 1
    assert "outside the field grid" in capsys.readouterr().err
    assert main(["export", str(result), "--format", "geotiff", "--height", "2"]) == 1
    assert "needs the ground" in capsys.readouterr().err


def test_isophone_bands_keep_holes():
    x = np.arange(21.0)
    gx, gy = np.meshgrid(x, x, indexing="ij")
    peak = 70.0 - np.hypot(gx - 10, gy - 10)  # a cone: rings of level
    feats = isophone_bands(peak, [0.0, 0.0], [1.0, 1.0], [60.0, 65.0])
    ring = next(f for f in feats if f["properties"]["label"] == "60-65 dB")
    geom = shapely.geometry.shape(ring["geometry"])
    assert geom.is_valid and len(geom.geoms[0].interiors) == 1
    # the annulus 5 < r <= 10 of a cone sampled on a 1 m grid: area pi (100 - 25) within 1 %
    assert geom.area == pytest.approx(math.pi * 75.0, rel=0.01)


def test_receiver_points_levels(tmp_path):
    result, _, energy = _field(tmp_path)
    pts = tmp_path / "r.geojson"

    def point(props, coords):
        return {"type": "Feature", "properties": props, "geometry": {"type": "Point", "coordinates": coords}}

    feats = [point({"id": "a"}, [X0 + 33.0, Y0 + 41.5, 3.3]), point({"name": "b"}, [X0 + 150.0, Y0 + 77.0])]
    pts.write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    args = ["export", str(result), "--format", "receivers", "--receivers", str(pts), "--array", "spl_e",
            "--height", "1.5", "--ground-z", "2.0", "--crs", "32632", "--origin", str(X0), str(Y0)]  # fmt: skip
    assert main(args) == 0
    data = json.loads((result / "export" / "receivers.geojson").read_text())
    got = {f["properties"]["id"]: f["properties"]["spl_e"] for f in data["features"]}
    # spl_e = 10 lg(1 + 0.5 x + 0.25 y + 2 z) in the local frame: trilinear in energy is exact
    assert got["a"] == pytest.approx(10 * math.log10(1 + 0.5 * 33.0 + 0.25 * 41.5 + 2 * 3.3), abs=1e-9)
    assert got["b"] == pytest.approx(10 * math.log10(1 + 0.5 * 150.0 + 0.25 * 77.0 + 2 * 3.5), abs=1e-9)
    assert data["features"][1]["geometry"]["coordinates"] == [X0 + 150.0, Y0 + 77.0, 3.5]
    rows = (result / "export" / "receivers.csv").read_text().splitlines()
    assert rows[0] == "id,x,y,z,spl_e" and rows[1].startswith("a,500033.000,5400041.500,3.300,")

"""The consultant's case of issue 14, small: GIS inputs in EPSG:25832 coordinates as given (no shift by
hand) -> two conditions -> GeoTIFF / ASCII rasters, isophones, facade levels and Lden.

Inputs written as a GIS user has them: a DEM as ESRI ASCII grid (a 0.02 slope, 10 m cells), buildings as
GeoJSON (``height`` and ``building:levels``), grass (G = 1) and asphalt (G = 0) zones as GeoJSON, a point
source 1.5 m above the ground and a road LineString (65 dB re 1 pW/m per band, 0.5 m above the ground)
discretised by the ISO 9613-2 rule into point sources whose heights the job resolves on the DEM. Two
conditions: homogeneous and downward refracting (log profile b = +1), CNOSSOS-like favourable shares
0.5 / 0.75 / 1.0 (day / evening / night). Everything goes through ``bentray run``, ``bentray export``
and ``bentray lden``; a few thousand rays per job.
"""

from __future__ import annotations

import csv
import json
import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from bentray.clients.cli import main
from bentray.scenes.gis_sources import read_line_sources_geojson

rasterio = pytest.importorskip("rasterio")
shapely = pytest.importorskip("shapely")

X0, Y0 = 691_000.0, 5_334_000.0  # DEM lower-left corner (EPSG:25832, ETRS89 / UTM 32N)
NX, NY, DX = 29, 19, 10.0  # field columns at X0 + 10 .. X0 + 290, Y0 + 10 .. Y0 + 190
FAVOURABLE = (0.5, 0.75, 1.0)  # day, evening, night
BANDS = {"500": 95.0, "1000": 95.0}


def _rect(x, y, w, h):
    return [[[X0 + x, Y0 + y], [X0 + x + w, Y0 + y], [X0 + x + w, Y0 + y + h], [X0 + x, Y0 + y + h], [X0 + x, Y0 + y]]]


def _fc(features):
    return {"type": "FeatureCollection", "features": features}


def _feature(geometry_type, coordinates, **props):
    return {"type": "Feature", "properties": props, "geometry": {"type": geometry_type, "coordinates": coordinates}}


def _write_inputs(d: Path) -> None:
    ncols, nrows, cell = 31, 21, 10.0
    xc = X0 + (np.arange(ncols) + 0.5) * cell
    z = 500.0 + 0.02 * (xc - X0)  # rising eastwards, 500.1 .. 506.1 m
    rows = "\n".join(" ".join(f"{v:.3f}" for v in z) for _ in range(nrows))
    header = f"ncols {ncols}\nnrows {nrows}\nxllcorner {X0:.1f}\nyllcorner {Y0:.1f}\ncellsize {cell:g}\n"
    (d / "dem.asc").write_text(header + "NODATA_value -9999\n" + rows + "\n")
    buildings = [
        _feature("Polygon", _rect(150, 80, 30, 30), height=9.0, name="A"),
        _feature("Polygon", _rect(200, 130, 30, 20), **{"building:levels": 2, "name": "B"}),
    ]
    (d / "buildings.geojson").write_text(json.dumps(_fc(buildings)))
    zones = [
        _feature("Polygon", _rect(0, 0, 310, 210), G=1.0, name="grass"),
        _feature("Polygon", _rect(0, 30, 310, 20), G=0.0, name="asphalt"),  # the road, painted over the grass
    ]
    (d / "zones.geojson").write_text(json.dumps(_fc(zones)))
    road = _feature(
        "LineString", [[X0 + 20, Y0 + 40], [X0 + 280, Y0 + 40]],
        power_db_per_m={"500": 65.0, "1000": 65.0}, height_above_ground_m=0.5, name="road",
    )  # fmt: skip
    (d / "road.geojson").write_text(json.dumps(_fc([road])))


def _job(d: Path, profile: dict, name: str) -> dict:
    gx, gy = np.meshgrid(X0 + 10 + DX * np.arange(NX), Y0 + 10 + DX * np.arange(NY), indexing="ij")
    receivers = np.column_stack([gx.ravel(), gy.ravel()])  # the map's columns, in the CRS
    road = read_line_sources_geojson(d / "road.geojson", receivers, min_piece_m=40.0)
    return {
        "name": name,
        "scene": {
            "crs": "EPSG:25832",
            "domain": {"min": [X0 + 5, Y0 + 5, 495.0], "max": [X0 + 305, Y0 + 205, 560.0]},
            "terrain": {"file": "dem.asc", "material": "grass"},
            "materials": [{"name": "grass", "flow_resistivity": 200_000.0}],
            "buildings": {"file": "buildings.geojson"},
            "ground_zones": {"file": "zones.geojson"},
        },
        "profile": profile,
        "sources": [
            {"position": [X0 + 80, Y0 + 120], "height_above_ground_m": 1.5, "power_db": BANDS, "name": "plant"},
            *(p.as_job_source() for p in road),
        ],
        "rays": {
            "elevation_deg": {"min": -40, "max": 40, "count": 17},
            "azimuth_deg": {"min": -180, "max": 165, "count": 24},
            "max_time_s": 1.5,
            "max_reflections": 2,
        },
        "field": {
            "origin": [X0 + 10, Y0 + 10, 502.0],
            "spacing": [DX, DX, 2.0],
            "shape": [NX, NY, 7],
            "frequencies_hz": [500.0, 1000.0],
        },
        "outputs": ["field", "report"],
    }


@cache
def _study(base: str) -> Path:
    d = Path(base)
    _write_inputs(d)
    conditions = {"homogeneous": {"kind": "homogeneous"}, "favourable": {"kind": "log", "b": 1.0}}
    for name, profile in conditions.items():
        (d / f"{name}.json").write_text(json.dumps(_job(d, profile, name)))
        assert main(["run", str(d / f"{name}.json"), "--out", str(d / name)]) == 0
        args = ["export", str(d / name), "--format", "geotiff,asc,isophones,facades,exposure", "--height", "4",
                "--terrain", str(d / "dem.asc"), "--buildings", str(d / "buildings.geojson")]  # fmt: skip
        assert main(args) == 0
    p = FAVOURABLE
    args = ["lden", "--condition", str(d / "favourable"), *(str(v) for v in p),
            "--condition", str(d / "homogeneous"), *(str(1 - v) for v in p), "--height", "4",
            "--terrain", str(d / "dem.asc"), "--buildings", str(d / "buildings.geojson"),
            "--format", "geotiff,asc,isophones", "--out", str(d / "lden")]  # fmt: skip
    assert main(args) == 0
    return d


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    return _study(str(tmp_path_factory.mktemp("consultant")))


def test_the_job_ran_in_the_local_frame_and_reports_the_crs(study):
    report = json.loads((study / "homogeneous" / "report.json").read_text())
    assert report["georeference"]["local_origin"] == [X0, Y0]
    assert "25832" in report["georeference"]["crs"] or "ETRS89 / UTM zone 32N" in report["georeference"]["crs"]


def test_rasters_read_back_with_crs_transform_and_levels(study):
    for cond in ("homogeneous", "favourable"):
        for name in ("map_spl_a.tif", "map_spl_a.asc"):
            with rasterio.open(study / cond / "export" / name) as src:
                assert src.crs.to_epsg() == 25832, (cond, name)
                assert (src.width, src.height) == (NX, NY)
                x, y = src.transform @ (0.5, src.height - 0.5)  # south-west cell centre = node (0, 0)
                assert (x, y) == pytest.approx((X0 + 10, Y0 + 10), abs=1e-6)
                assert src.transform.a == DX and src.transform.e == -DX
                band = src.read(1, masked=True)
                # near the road (row of y = Y0 + 40) the map is loud, and everything reached is plausible
                assert band.count() > 0.9 * NX * NY, (cond, name)
                assert 25.0 < float(band.min()) and float(band.max()) < 110.0, (cond, name)


def test_isophones_facades_and_exposure(study):
    iso = json.loads((study / "homogeneous" / "export" / "isophones_spl_a.geojson").read_text())
    assert iso["features"] and "25832" in json.dumps(iso["crs"])
    for f in iso["features"]:
        geom = shapely.geometry.shape(f["geometry"])
        assert geom.is_valid and X0 < geom.bounds[0] and geom.bounds[3] < Y0 + 210
    with (study / "homogeneous" / "export" / "facades.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert {r["building"] for r in rows} == {"0", "1"} and {r["storey"] for r in rows} == {"0", "1", "2"}
    levels = [float(r["spl_a"]) for r in rows if r["spl_a"]]
    assert len(levels) > 0.8 * len(rows) and 25 < min(levels) and max(levels) < 110
    exposure = json.loads((study / "homogeneous" / "export" / "exposure.json").read_text())
    assert sum(c["buildings"] for c in exposure["buildings"]["classes"]) == 2


def _read(path: Path) -> np.ma.MaskedArray:
    with rasterio.open(path) as src:
        return src.read(1, masked=True).astype(np.float64)


def test_lden_is_the_hand_computation_from_the_two_condition_maps(study):
    fav, hom = (
        _read(study / "favourable" / "export" / "map_spl_a.tif"),
        _read(study / "homogeneous" / "export" / "map_spl_a.tif"),
    )
    periods = [10 * np.log10(p * 10 ** (fav / 10) + (1 - p) * 10 ** (hom / 10)) for p in FAVOURABLE]
    hand = 10 * np.log10((12 * 10 ** (periods[0] / 10) + 4 * 10 ** ((periods[1] + 5) / 10)
                          + 8 * 10 ** ((periods[2] + 10) / 10)) / 24)  # fmt: skip
    for name, ref in [("lday", periods[0]), ("levening", periods[1]), ("lnight", periods[2]), ("lden", hand)]:
        got = _read(study / "lden" / f"map_{name}.tif")
        both = ~got.mask & ~np.ma.getmaskarray(ref)
        assert both.sum() > 0.9 * NX * NY
        np.testing.assert_allclose(got[both], np.ma.getdata(ref)[both], rtol=0, atol=1e-4)  # float32 rasters
        with rasterio.open(study / "lden" / f"map_{name}.asc") as src:
            assert src.crs.to_epsg() == 25832
    # Lden of one condition alone is that map + 10 lg((12 + 4 10^0.5 + 8 10^1) / 24); the mix lies between
    shift = 10 * math.log10((12 + 4 * 10**0.5 + 8 * 10**1.0) / 24)
    got = _read(study / "lden" / "map_lden.tif")
    assert np.all(got >= np.minimum(fav, hom) + shift - 1e-4) and np.all(got <= np.maximum(fav, hom) + shift + 1e-4)
    with (study / "lden" / "facades_lden.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert {"lday", "levening", "lnight", "lden"} <= set(rows[0]) and len(rows) > 10
    assert json.loads((study / "lden" / "isophones_lden.geojson").read_text())["features"]


def test_field_vti_carries_the_crs_and_local_origin(study):
    import pyvista as pv

    from bentray.engine.export.field_grid import read_field_vti

    grid = pv.read(study / "homogeneous" / "field.vti")
    assert int(np.asarray(grid.field_data["crs_epsg"]).ravel()[0]) == 25832
    wkt = grid.field_data["crs_wkt"]
    assert str(wkt if isinstance(wkt, str) else np.asarray(wkt).ravel()[0]).startswith("PROJCRS")
    np.testing.assert_array_equal(np.asarray(grid.field_data["local_origin_m"]).ravel(), [X0, Y0])
    # without report.json the exports still find the georeference in the file
    frame = read_field_vti(study / "homogeneous" / "field.vti").frame
    assert frame.origin == (X0, Y0) and frame.crs_wkt is not None

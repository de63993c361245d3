"""Facade receivers, line-source discretisation, CRS parsing / local frame, and the missing-extra error."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bentray.engine.surfaces import Footprint
from bentray.scenes import gis_deps
from bentray.scenes.crs import CrsError, LocalFrame, choose_local_origin, parse_crs
from bentray.scenes.gis_sources import discretise_line, total_power_db

shapely = pytest.importorskip("shapely")
from bentray.engine.export.facades import facade_receivers  # noqa: E402


def _fp(x, y, w, h, height=7.0, holes=()):
    return Footprint(np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]], float), height, 0.0, holes=list(holes))


def test_facade_receivers_count_distance_heights_and_ids():
    rec = facade_receivers([_fp(0, 0, 20, 10)], spacing=5.0, distance=2.0, storey_height=3.0, first_height=1.5)
    assert len(rec.points) == 2 * (4 + 2 + 4 + 2)
    poly = shapely.Polygon([(0, 0), (20, 0), (20, 10), (0, 10)])
    d = shapely.distance(poly, shapely.points(rec.points[:, :2]))
    np.testing.assert_allclose(d, 2.0, rtol=0, atol=1e-12)
    assert sorted(set(rec.points[:, 2])) == [1.5, 4.5] and set(rec.storey.tolist()) == {0, 1}
    assert len(set(rec.ids)) == len(rec.ids) and np.all(rec.building == 0)
    # each receiver is in front of the middle of its wall piece: the foot of the normal is on the wall
    foot = rec.points[:, :2] - 2.0 * rec.normal
    np.testing.assert_allclose(shapely.distance(poly.boundary, shapely.points(foot)), 0.0, atol=1e-12)


def test_shared_walls_have_no_receivers_and_courtyards_do():
    hole = np.array([[10.0, 10.0], [10.0, 30.0], [30.0, 30.0], [30.0, 10.0]])  # clockwise
    a = _fp(0, 0, 40, 40, height=4.0, holes=[hole])
    b = _fp(40, 0, 20, 40, height=4.0)  # shares the wall x = 40 with a
    rec = facade_receivers([a, b], spacing=10.0, first_height=1.5)
    xy = rec.points[:, :2]
    assert not np.any(np.isclose(xy[:, 0], 42.0) & (rec.building == 0))  # nothing in front of the shared wall
    assert not np.any(np.isclose(xy[:, 0], 38.0) & (rec.building == 1))
    in_yard = np.all((xy > 10) & (xy < 30), axis=1)
    assert np.count_nonzero(in_yard) == 4 * 2  # 20 m courtyard walls, 10 m pieces, one storey
    both = shapely.union(shapely.Polygon(a.polygon, [hole]), shapely.Polygon(b.polygon))
    assert not np.any(shapely.intersects_xy(both, xy[:, 0], xy[:, 1]))


def test_line_source_power_is_conserved_and_pieces_obey_the_distance_rule():
    line = np.array([[0.0, 0.0, 0.5], [300.0, 0.0, 0.5], [300.0, 200.0, 0.5]])
    receivers = np.array([[150.0, 10.0, 1.5], [290.0, 100.0, 4.0]])
    pieces = discretise_line(line, {"500": 60.0, "1000": 57.0}, receivers, min_piece_m=0.5, max_piece_m=50.0)
    lengths = np.array([p.length_m for p in pieces])
    assert lengths.sum() == pytest.approx(500.0, rel=1e-12)
    # energy sum of the pieces = L_W' + 10 lg(total length), per band (1e-9 dB)
    assert total_power_db(pieces, "500") == pytest.approx(60.0 + 10 * math.log10(500.0), abs=1e-9)
    assert total_power_db(pieces, "1000") == pytest.approx(57.0 + 10 * math.log10(500.0), abs=1e-9)
    pos = np.array([p.position for p in pieces])
    dist = np.min(np.linalg.norm(pos[:, None, :] - receivers[None], axis=2), axis=1)
    assert np.all((lengths <= 0.5 * dist + 1e-9) | (lengths <= 0.5 + 1e-9))
    assert np.all(lengths <= 50.0 + 1e-9)
    assert lengths.min() < 5.0 and lengths.max() == 37.5  # short near the receivers; 300 m / 8 far away
    assert pieces[0].as_job_source()["power_db"]["500"] == pytest.approx(60.0 + 10 * math.log10(lengths[0]))


def test_line_source_heights_and_errors():
    flat = discretise_line([[0, 0], [10, 0]], {"A": 70.0}, [[5, 100, 2]], height_above_ground_m=0.5,
                           ground=lambda xy: 3.0 + 0.1 * xy[:, 0])  # fmt: skip
    for p in flat:
        assert p.position[2] == pytest.approx(3.0 + 0.1 * p.position[0] + 0.5, abs=1e-12)
    with pytest.raises(ValueError, match="exactly one"):
        discretise_line([[0, 0, 1], [10, 0, 1]], {"A": 70.0}, [], height_above_ground_m=0.5, ground=lambda xy: xy[:, 0])
    with pytest.raises(ValueError, match="at least 2 finite"):
        discretise_line([[0, 0, 1]], {"A": 70.0}, [])


def test_crs_parsing_and_local_frame():
    crs = parse_crs(32632)
    assert crs.to_epsg() == 32632 and parse_crs("EPSG:32632") == crs and parse_crs(crs.to_wkt()) == crs
    with pytest.raises(CrsError, match="is not projected"):
        parse_crs(4326)
    with pytest.raises(CrsError, match="unknown CRS"):
        parse_crs("EPSG:999999")
    with pytest.raises(CrsError, match="metres"):
        parse_crs(2227)  # California zone 3, US survey feet
    assert choose_local_origin([500_123.4, 5_401_999.9]) == (500_000.0, 5_401_000.0)
    assert choose_local_origin([-50.0, 20.0]) == (0.0, 0.0)
    frame = LocalFrame.from_scene(32632, [500_123.4, 5_401_999.9])
    p = np.array([[500_200.0, 5_402_000.5, 7.0]])
    np.testing.assert_array_equal(frame.to_crs(frame.to_local(p)), p)
    np.testing.assert_array_equal(frame.to_local(p), [[200.0, 1000.5, 7.0]])
    assert LocalFrame.from_dict(frame.as_dict()) == frame


def test_missing_extra_names_it(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def fake(name, *args, **kwargs):
        if name.split(".")[0] == "rasterio":
            raise ImportError("No module named 'rasterio'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake)
    monkeypatch.delitem(__import__("sys").modules, "rasterio", raising=False)
    with pytest.raises(
        gis_deps.GisDependencyError,
        match=r"GeoTIFF export needs the 'rasterio' package of the 'gis' extra: pip install 'bentray\[gis\]'",
    ):
        gis_deps.require("rasterio", "GeoTIFF export")


def test_line_pieces_without_ground_leave_the_height_to_the_job():
    pieces = discretise_line([[0, 0], [40, 0]], {"A": 70.0}, [[20, 30]], height_above_ground_m=0.5, min_piece_m=5.0)
    src = pieces[0].as_job_source()
    assert len(src["position"]) == 2 and src["height_above_ground_m"] == 0.5
    from bentray.scenes.schema import Source

    assert Source.model_validate(src).height_above_ground_m == 0.5
    with pytest.raises(ValueError, match="must be > 0"):
        discretise_line([[0, 0], [40, 0]], {"A": 70.0}, [], height_above_ground_m=0.0)


def test_localise_job_shifts_receivers():
    from bentray.scenes.gis_frame import localise_job
    from bentray.scenes.schema import Job

    job = Job.model_validate(
        {
            "name": "r",
            "scene": {"crs": 32632, "domain": {"min": [500_100, 5_400_100, 0], "max": [500_400, 5_400_300, 50]}},
            "profile": {"kind": "homogeneous"},
            "sources": [{"position": [500_150, 5_400_150, 2.0]}],
            "rays": {"elevation_deg": {"min": -10, "max": 10, "count": 3}, "max_time_s": 1.0, "max_reflections": 1},
            "receivers": [
                {"id": "a", "position": [500_200, 5_400_200, 4.0]},
                {"id": "b", "xy": [500_300, 5_400_250], "height_above_ground_m": 4.0},
            ],
        }
    )
    local, frame = localise_job(job)
    assert frame.origin == (500_000.0, 5_400_000.0)
    assert local.receivers[0].position == (200.0, 200.0, 4.0) and local.receivers[1].xy == (300.0, 250.0)

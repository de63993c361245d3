"""Output writers: exact round trips through csv / pyvista, and all-or-nothing job outputs."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import pyvista as pv

from bentray.engine import writers
from bentray.engine.constants import STATUS_EXITED, STATUS_LOST, STATUS_NAMES, STATUS_TIME_LIMIT
from bentray.engine.result import JobOutcome, MeshGeometry, RayPaths, TraceResult
from bentray.engine.writers import (
    write_mesh_vtu,
    write_outcome,
    write_rays_csv,
    write_rays_vtp,
    write_report_json,
)

HEADER = "ray,source,elevation_deg,azimuth_deg,x,y,z,dx,dy,dz,time_s,length_m,reflections,status"


def _trace(with_paths: bool = True) -> TraceResult:
    rng = np.random.default_rng(7)
    n = 3
    counts = [2, 5, 3]
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    m = int(offsets[-1])
    paths = RayPaths(
        offsets=offsets,
        points=rng.normal(size=(m, 3)) * 1000.0,
        time_s=rng.random(m) / 3.0,
        length_m=rng.random(m) * 1e4,
    )
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return TraceResult(
        source=np.array([0, 0, 1], dtype=np.int64),
        elevation_deg=np.array([-45.0, 0.1, 1.0 / 3.0]),
        azimuth_deg=np.array([0.0, -0.0, 359.99999999999994]),
        position=rng.normal(size=(n, 3)) * 1e3,
        direction=direction,
        time_s=np.array([10.0, 2.0 / 3.0, 1e-300]),
        length_m=np.array([3400.0000000000005, np.pi, 5e-324]),
        reflections=np.array([0, 7, 50], dtype=np.int64),
        status=np.array([STATUS_TIME_LIMIT, STATUS_EXITED, STATUS_LOST], dtype=np.int8),
        crossings=np.array([10, 20, 30], dtype=np.int64),
        nudges=np.zeros(n, dtype=np.int64),
        paths=paths if with_paths else None,
    )


def _mesh() -> MeshGeometry:
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=np.float64) * 0.1
    return MeshGeometry(
        points=points,
        connectivity=np.array([[0, 1, 2, 3], [1, 2, 3, 4]], dtype=np.int64),
        cell_type="tetra",
        cell_data={
            "n2": np.array([1.0 / 3.0, 0.9999999999999999]),
            "grad_n2": np.array([[0.0, 0.0, -1e-5], [1e-7, 2e-7, -3e-5]]),
            "level": np.array([3, 4], dtype=np.int32),
        },
    )


def _outcome(with_paths: bool = True, with_mesh: bool = True) -> JobOutcome:
    report = {
        "job": "tiny",
        "n_rays": np.int64(3),
        "timings_s": {"mesh": np.float64(0.25), "trace": 1.5},
        "status_counts": {"exited": 1},
        "max_error": np.array([1.0, 2.5]),
        "nan_value": float("nan"),
    }
    return JobOutcome(trace=_trace(with_paths), mesh_geometry=_mesh() if with_mesh else None, report=report)


def test_rays_csv_round_trip(tmp_path):
    trace = _trace()
    path = write_rays_csv(trace, tmp_path / "rays.csv")
    text = path.read_text()
    assert text.splitlines()[0] == HEADER
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == trace.n_rays
    for i, row in enumerate(rows):
        assert int(row["ray"]) == i
        assert int(row["source"]) == trace.source[i]
        assert float(row["elevation_deg"]) == trace.elevation_deg[i]
        assert float(row["azimuth_deg"]) == trace.azimuth_deg[i]
        assert [float(row[k]) for k in "xyz"] == trace.position[i].tolist()
        assert [float(row[k]) for k in ("dx", "dy", "dz")] == trace.direction[i].tolist()
        assert float(row["time_s"]) == trace.time_s[i]
        assert float(row["length_m"]) == trace.length_m[i]
        assert int(row["reflections"]) == trace.reflections[i]
        assert row["status"] == STATUS_NAMES[int(trace.status[i])]
    assert [r["status"] for r in rows] == ["time_limit", "exited", "lost"]
    assert rows[1]["azimuth_deg"] == "-0.0"


def test_rays_csv_rejects_unknown_status(tmp_path):
    trace = _trace()
    trace.status[0] = 42
    with pytest.raises(ValueError, match="unknown codes"):
        write_rays_csv(trace, tmp_path / "rays.csv")
    assert list(tmp_path.iterdir()) == []


def test_rays_vtp_round_trip(tmp_path):
    trace = _trace()
    path = write_rays_vtp(trace, tmp_path / "rays.vtp")
    poly = pv.read(path)
    assert poly.n_cells == 3
    np.testing.assert_array_equal(poly.points, trace.paths.points)
    assert poly.points.dtype == np.float64
    np.testing.assert_array_equal(poly["time_s"], trace.paths.time_s)
    np.testing.assert_array_equal(poly["length_m"], trace.paths.length_m)
    np.testing.assert_array_equal(poly.cell_data["ray"], [0, 1, 2])
    np.testing.assert_array_equal(poly.cell_data["status"], trace.status.astype(int))
    np.testing.assert_array_equal(poly.cell_data["source"], trace.source)
    # one polyline per ray, with exactly that ray's points in order
    lines = poly.lines
    pos, ray = 0, 0
    while pos < lines.size:
        k = lines[pos]
        start, stop = trace.paths.offsets[ray], trace.paths.offsets[ray + 1]
        np.testing.assert_array_equal(lines[pos + 1 : pos + 1 + k], np.arange(start, stop))
        pos += k + 1
        ray += 1
    assert ray == 3


def test_rays_vtp_skips_rays_without_samples(tmp_path):
    trace = _trace()
    p = trace.paths
    keep = np.r_[0:2, 7:10]  # ray 1 (points 2..6) dropped
    trace.paths = RayPaths(np.array([0, 2, 2, 5]), p.points[keep], p.time_s[keep], p.length_m[keep])
    poly = pv.read(write_rays_vtp(trace, tmp_path / "rays.vtp"))
    np.testing.assert_array_equal(poly.cell_data["ray"], [0, 2])
    np.testing.assert_array_equal(poly.cell_data["status"], trace.status[[0, 2]])


def test_rays_vtp_needs_paths(tmp_path):
    with pytest.raises(ValueError, match="no sampled paths"):
        write_rays_vtp(_trace(with_paths=False), tmp_path / "rays.vtp")


def test_mesh_vtu_round_trip(tmp_path):
    geometry = _mesh()
    grid = pv.read(write_mesh_vtu(geometry, tmp_path / "mesh.vtu"))
    assert isinstance(grid, pv.UnstructuredGrid)
    np.testing.assert_array_equal(grid.points, geometry.points)
    np.testing.assert_array_equal(grid.celltypes, [pv.CellType.TETRA] * 2)
    np.testing.assert_array_equal(grid.cells, [4, 0, 1, 2, 3, 4, 1, 2, 3, 4])
    for name, values in geometry.cell_data.items():
        np.testing.assert_array_equal(grid.cell_data[name], values)
        assert grid.cell_data[name].shape == values.shape
        assert grid.cell_data[name].dtype == values.dtype


def test_mesh_vtu_hexahedron(tmp_path):
    corners = np.array(
        [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float
    )
    geometry = MeshGeometry(corners, np.arange(8)[None, :], "hexahedron", {"c": np.array([340.5])})
    grid = pv.read(write_mesh_vtu(geometry, tmp_path / "mesh.vtu"))
    np.testing.assert_array_equal(grid.celltypes, [pv.CellType.HEXAHEDRON])
    np.testing.assert_array_equal(grid.cell_data["c"], [340.5])


def test_report_json(tmp_path):
    report = _outcome().report
    text = write_report_json(report, tmp_path / "report.json").read_text()
    data = json.loads(text)
    assert list(data) == list(report)  # key order kept
    assert data["n_rays"] == 3 and data["timings_s"] == {"mesh": 0.25, "trace": 1.5}
    assert data["max_error"] == [1.0, 2.5]
    assert data["nan_value"] is None
    assert text.startswith('{\n  "job": "tiny"')


def test_write_outcome_all_files(tmp_path):
    out = tmp_path / "out"
    written = write_outcome(_outcome(), ["rays", "mesh", "report"], out)
    names = ["rays.csv", "rays.vtp", "mesh.vtu", "report.json"]
    assert written == [out / n for n in names]
    assert sorted(p.name for p in out.iterdir()) == sorted(names)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # staging directory removed


def test_write_outcome_selection(tmp_path):
    out = tmp_path / "out"
    written = write_outcome(_outcome(with_paths=False, with_mesh=False), ["rays", "mesh", "report"], out)
    assert [p.name for p in written] == ["rays.csv", "report.json"]
    written = write_outcome(_outcome(), ["paths"], out)
    assert [p.name for p in written] == ["rays.vtp"]
    # files of the earlier run that this run did not write are removed
    assert sorted(p.name for p in out.iterdir()) == ["rays.vtp"]
    with pytest.raises(ValueError, match="no sampled paths"):
        write_outcome(_outcome(with_paths=False), ["paths"], out)
    with pytest.raises(ValueError, match="unknown outputs"):
        write_outcome(_outcome(), ["video"], out)


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    def boom(trace, path):
        path.write_text("partial")
        raise RuntimeError("disk full")

    monkeypatch.setattr(writers, "write_rays_vtp", boom)
    out = tmp_path / "out"
    with pytest.raises(RuntimeError, match="disk full"):
        write_outcome(_outcome(), ["rays", "mesh", "report"], out)
    assert list(tmp_path.iterdir()) == []  # neither out/ nor a staging directory

    out.mkdir()
    (out / "keep.txt").write_text("x")
    with pytest.raises(RuntimeError, match="disk full"):
        write_outcome(_outcome(), ["rays", "report"], out)
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]

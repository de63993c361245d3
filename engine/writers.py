"""Writers for a job's output files: rays.csv, rays.vtp, mesh.vtu, report.json.

Every file is first written inside a temporary directory created next to its destination and moved
into place with ``os.replace`` only after it was written completely, so a failed write never leaves
a partial file. :func:`write_outcome` stages *all* requested files this way and moves them into the
output directory only when every one of them succeeded.

pyvista is imported lazily (only the VTK writers need it).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np

from bentray.engine.constants import STATUS_NAMES
from bentray.engine.preview_process import PreviewRequest, PreviewWorker
from bentray.engine.result import JobOutcome, MeshGeometry, RayPaths, TraceResult

__all__ = [
    "OUTPUT_FILES",
    "RAYS_CSV_COLUMNS",
    "write_mesh_vtu",
    "write_outcome",
    "write_rays_csv",
    "write_rays_vtp",
    "write_report_json",
]

RAYS_CSV_COLUMNS = (
    "ray",
    "source",
    "elevation_deg",
    "azimuth_deg",
    "x",
    "y",
    "z",
    "dx",
    "dy",
    "dz",
    "time_s",
    "length_m",
    "reflections",
    "status",
)
# Every file name write_outcome may produce (stale ones from an earlier run are removed).
OUTPUT_FILES = (
    "rays.csv",
    "rays.vtp",
    "mesh.vtu",
    "field.vti",
    "preview.png",
    "receivers.csv",
    "arrivals.csv",
    "report.json",
)
_KNOWN_OUTPUTS = ("rays", "paths", "mesh", "report", "field")
_CSV_CHUNK_ROWS = 65_536
# VTK XML compression, chosen by write + read time (issue 18; README job's files, load average about 7, best of
# 3 interleaved rounds; zlib / none / lz4): mesh.vtu 8.3 + 3.0 s, 16 MB / 3.7 + 5.3 s, 48 MB / 2.5 + 3.3 s,
# 26 MB; a rays.vtp of 2,000 rays x 400 samples 16.3 + 7.5 s, 41 MB / 3.7 + 6.9 s, 51 MB / 4.8 + 7.0 s, 47 MB.
VTU_COMPRESSION: Final = "lz4"
VTP_COMPRESSION: Final = None
_VTK_CELL_TYPES = {"tetra": (10, 4), "hexahedron": (12, 8)}  # name -> (VTK cell type id, points per cell)


@contextlib.contextmanager
def _staged_file(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path with the same file name next to ``path``; move it into place on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp_dir = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        tmp_path = tmp_dir / path.name
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        shutil.rmtree(tmp_dir, ignore_errors=True)


# ---------------------------------------------------------------------------------------------
# rays.csv
# ---------------------------------------------------------------------------------------------
def _check_trace(trace: TraceResult) -> None:
    n = trace.n_rays
    shapes = {
        "source": (n,),
        "elevation_deg": (n,),
        "azimuth_deg": (n,),
        "position": (n, 3),
        "direction": (n, 3),
        "time_s": (n,),
        "length_m": (n,),
        "reflections": (n,),
    }
    for name, shape in shapes.items():
        actual = np.shape(getattr(trace, name))
        if actual != shape:
            raise ValueError(f"TraceResult.{name} has shape {actual}, expected {shape} for {n} rays")
    unknown = np.setdiff1d(np.unique(trace.status), np.fromiter(STATUS_NAMES, dtype=np.int64))
    if unknown.size:
        raise ValueError(f"TraceResult.status has unknown codes {unknown.tolist()}; known: {STATUS_NAMES}")


def _float_strings(values: np.ndarray) -> list[str]:
    # repr of a Python float is the shortest string that round-trips exactly (float(s) == value).
    return list(map(repr, np.asarray(values, dtype=np.float64).tolist()))


def _int_strings(values: np.ndarray) -> list[str]:
    return list(map(str, np.asarray(values, dtype=np.int64).tolist()))


def write_rays_csv(trace: TraceResult, path: str | Path) -> Path:
    """One row per ray with columns :data:`RAYS_CSV_COLUMNS`; floats at full precision (round-trip
    exactly through ``float()``), ``status`` as its name from ``STATUS_NAMES``. Returns ``path``."""
    _check_trace(trace)
    path = Path(path)
    n = trace.n_rays
    status_lookup = np.empty(max(STATUS_NAMES) + 1, dtype=object)
    for code, name in STATUS_NAMES.items():
        status_lookup[code] = name
    with _staged_file(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        fh.write(",".join(RAYS_CSV_COLUMNS) + "\n")
        for start in range(0, n, _CSV_CHUNK_ROWS):
            sl = slice(start, min(start + _CSV_CHUNK_ROWS, n))
            columns = [
                _int_strings(np.arange(sl.start, sl.stop)),
                _int_strings(trace.source[sl]),
                _float_strings(trace.elevation_deg[sl]),
                _float_strings(trace.azimuth_deg[sl]),
                *(_float_strings(trace.position[sl, k]) for k in range(3)),
                *(_float_strings(trace.direction[sl, k]) for k in range(3)),
                _float_strings(trace.time_s[sl]),
                _float_strings(trace.length_m[sl]),
                _int_strings(trace.reflections[sl]),
                status_lookup[np.asarray(trace.status[sl], dtype=np.int64)].tolist(),
            ]
            fh.write("\n".join(map(",".join, zip(*columns, strict=True))) + "\n")
    return path


# ---------------------------------------------------------------------------------------------
# rays.vtp
# ---------------------------------------------------------------------------------------------
def _check_paths(paths: RayPaths, n_rays: int) -> np.ndarray:
    offsets = np.asarray(paths.offsets, dtype=np.int64)
    m = int(np.shape(paths.points)[0]) if np.ndim(paths.points) == 2 else -1
    if np.shape(paths.points) != (m, 3):
        raise ValueError(f"RayPaths.points has shape {np.shape(paths.points)}, expected (M, 3)")
    if offsets.shape != (n_rays + 1,):
        raise ValueError(f"RayPaths.offsets has shape {offsets.shape}, expected ({n_rays + 1},)")
    if offsets[0] != 0 or offsets[-1] != m or np.any(np.diff(offsets) < 0):
        raise ValueError(
            f"RayPaths.offsets must rise from 0 to the number of points ({m}); got {offsets[0]} .. {offsets[-1]}"
        )
    for name in ("time_s", "length_m"):
        if np.shape(getattr(paths, name)) != (m,):
            raise ValueError(f"RayPaths.{name} has shape {np.shape(getattr(paths, name))}, expected ({m},)")
    return offsets


def write_rays_vtp(trace: TraceResult, path: str | Path) -> Path:
    """One polyline per ray from ``trace.paths`` (rays without samples are left out; the ``ray`` cell
    array names each line's ray). Point data ``time_s``, ``length_m``; cell data ``ray``, ``source``,
    ``status`` (int). Returns ``path``."""
    import pyvista as pv

    if trace.paths is None:
        raise ValueError("trace has no sampled paths (enable rays.record_paths or request output 'paths')")
    paths = trace.paths
    offsets = _check_paths(paths, trace.n_rays)
    counts = np.diff(offsets)
    rays = np.flatnonzero(counts > 0)
    # VTK's legacy cell layout: [n0, p0, p1, ..., n1, q0, ...]
    lines = np.empty(rays.size + int(counts.sum()), dtype=np.int64)
    head = np.arange(rays.size) + offsets[rays]  # where each line's count goes
    lines[head] = counts[rays]
    is_point = np.ones(lines.size, dtype=bool)
    is_point[head] = False
    lines[is_point] = np.arange(offsets[-1], dtype=np.int64)

    poly = pv.PolyData()
    poly.points = np.ascontiguousarray(paths.points, dtype=np.float64)
    poly.lines = lines
    poly.point_data["time_s"] = np.ascontiguousarray(paths.time_s, dtype=np.float64)
    poly.point_data["length_m"] = np.ascontiguousarray(paths.length_m, dtype=np.float64)
    poly.cell_data["ray"] = rays.astype(np.int64)
    poly.cell_data["source"] = np.asarray(trace.source, dtype=np.int64)[rays]
    poly.cell_data["status"] = np.asarray(trace.status, dtype=np.int32)[rays]
    poly.field_data["status_legend"] = [", ".join(f"{code} {name}" for code, name in sorted(STATUS_NAMES.items()))]
    path = Path(path)
    with _staged_file(path) as tmp:
        poly.save(tmp, compression=VTP_COMPRESSION)
    return path


# ---------------------------------------------------------------------------------------------
# mesh.vtu
# ---------------------------------------------------------------------------------------------
def write_mesh_vtu(geometry: MeshGeometry, path: str | Path) -> Path:
    """Tetra or hexahedron cells with ``geometry.cell_data`` as cell arrays (vectors as (C, 3))."""
    import pyvista as pv

    if geometry.cell_type not in _VTK_CELL_TYPES:
        raise ValueError(f"unknown cell_type {geometry.cell_type!r}; expected one of {list(_VTK_CELL_TYPES)}")
    vtk_type, k = _VTK_CELL_TYPES[geometry.cell_type]
    points = np.ascontiguousarray(geometry.points, dtype=np.float64)
    conn = np.asarray(geometry.connectivity, dtype=np.int64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"MeshGeometry.points has shape {points.shape}, expected (P, 3)")
    if conn.ndim != 2 or conn.shape[1] != k:
        raise ValueError(f"MeshGeometry.connectivity has shape {conn.shape}, expected (C, {k}) for {vtk_type}")
    if conn.size and (conn.min() < 0 or conn.max() >= points.shape[0]):
        raise ValueError(f"MeshGeometry.connectivity refers to points outside 0..{points.shape[0] - 1}")
    n_cells = conn.shape[0]
    cells = np.hstack([np.full((n_cells, 1), k, dtype=np.int64), conn]).ravel()
    grid = pv.UnstructuredGrid(cells, np.full(n_cells, vtk_type, dtype=np.uint8), points)
    for name, values in geometry.cell_data.items():
        values = np.asarray(values)
        if values.shape[0] != n_cells:
            raise ValueError(f"cell_data[{name!r}] has {values.shape[0]} rows for {n_cells} cells")
        grid.cell_data[name] = np.ascontiguousarray(values)
    for name, text in geometry.field_data.items():
        grid.field_data[name] = [str(text)]
    path = Path(path)
    with _staged_file(path) as tmp:
        grid.save(tmp, compression=VTU_COMPRESSION)
    return path


# ---------------------------------------------------------------------------------------------
# report.json
# ---------------------------------------------------------------------------------------------
def _jsonable(obj: Any, where: str = "report") -> Any:
    """Plain-JSON copy: numpy scalars/arrays to Python, tuples to lists, paths to strings.

    Non-finite floats (NaN, inf) become null so the file stays strict JSON (readable by any client).
    """
    if isinstance(obj, dict):
        out = {}
        for key, value in obj.items():
            if isinstance(key, np.generic):
                key = key.item()
            if isinstance(key, bool) or not isinstance(key, str | int):
                raise TypeError(f"{where}: key {key!r} of type {type(key).__name__} is not a string or integer")
            out[str(key)] = _jsonable(value, f"{where}.{key}")
        return out
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist(), where)
    if isinstance(obj, np.generic):
        return _jsonable(obj.item(), where)
    if isinstance(obj, list | tuple):
        return [_jsonable(value, f"{where}[{i}]") for i, value in enumerate(obj)]
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if obj is None or isinstance(obj, str | int | bool):
        return obj
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"{where}: value of type {type(obj).__name__} is not JSON-serialisable")


def write_report_json(report: dict, path: str | Path) -> Path:
    """JSON with keys in their given order, indent 2; numpy values converted (see :func:`_jsonable`)."""
    text = json.dumps(_jsonable(report), indent=2, sort_keys=False, allow_nan=False) + "\n"
    path = Path(path)
    with _staged_file(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


# ---------------------------------------------------------------------------------------------
# All outputs of a job
# ---------------------------------------------------------------------------------------------
def _mesh_geometry(outcome: JobOutcome) -> MeshGeometry:
    if outcome.mesh_geometry is None:
        raise ValueError("'mesh' output requested but the job produced no mesh geometry")
    return outcome.mesh_geometry


def _write_field(outcome: JobOutcome, path: Path) -> None:
    from bentray.engine.field_output import write_field_vti

    fa = outcome.field
    assert fa is not None
    field_data = dict(fa.field_data)
    geo = outcome.report.get("georeference")
    if isinstance(geo, dict):  # a scene in a CRS: the WKT, EPSG code and local origin travel with the grid
        from bentray.scenes.crs import LocalFrame

        field_data.update(LocalFrame.from_dict(geo).vti_field_data())
    write_field_vti(path, fa.grid.origin, fa.grid.spacing, fa.grid.shape, fa.arrays, field_data)


def _preview_request(outcome: JobOutcome, path: Path) -> PreviewRequest:
    """(path, args, kwargs) of ``write_preview_png`` for the job's field (drawn here or in a child process)."""
    fa = outcome.field
    assert fa is not None
    name, label = fa.preview_array()
    args = (fa.grid.origin, fa.grid.spacing, fa.grid.shape, fa.arrays[name])
    kwargs = {
        "source_xyz": fa.preview["source_xyz"],
        "receiver_z": fa.preview["receiver_z"],
        "title": fa.preview["title"],
        "label": label,
        "ground_z": fa.preview.get("ground_z"),
        "receiver_height": fa.preview.get("receiver_height_m"),
        "classes": name.startswith("spl"),  # levels: DIN 18005 classes; transmission loss: a continuous scale
        "footprints": fa.preview.get("footprints", ()),  # plan rings (local metres) when the field stage gives them
    }
    return path, args, kwargs


def _write_preview(outcome: JobOutcome, path: Path) -> None:
    from bentray.engine.field_output import write_preview_png

    png, args, kwargs = _preview_request(outcome, path)
    write_preview_png(png, *args, **kwargs)


def write_receivers_csv(table: Any, path: str | Path) -> Path:
    """receivers.csv (engine.beam_field.ReceiverTable, levels in dB) or arrivals.csv
    (engine.eigenray_stage.ArrivalTable): ``table.columns`` and one dict per row; floats to 6 digits
    (arrival times are written by the table at full precision)."""
    import csv

    path = Path(path)
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=table.columns)
        writer.writeheader()
        for row in table.rows:
            writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    return path


def _planned_files(outcome: JobOutcome, outputs: Sequence[str]) -> list[str]:
    unknown = [name for name in outputs if name not in _KNOWN_OUTPUTS]
    if unknown:
        raise ValueError(f"unknown outputs {unknown}; known: {list(_KNOWN_OUTPUTS)}")
    files: list[str] = []
    if "rays" in outputs:
        files.append("rays.csv")
        if outcome.trace.paths is not None:
            files.append("rays.vtp")
    if "paths" in outputs:
        if outcome.trace.paths is None:
            raise ValueError("output 'paths' was requested but the trace has no sampled paths")
        if "rays.vtp" not in files:
            files.append("rays.vtp")
    if "mesh" in outputs and outcome.mesh_geometry is not None:
        files.append("mesh.vtu")
    if "field" in outputs:
        if outcome.field is None:
            raise ValueError("output 'field' was requested but the job produced no field")
        files.extend(["field.vti", "preview.png"])
    if outcome.receivers is not None:
        files.append("receivers.csv")  # receivers are listed in the job: their levels are its output
    if outcome.arrivals is not None:
        files.append("arrivals.csv")  # the eigenrays at those receivers
    if "report" in outputs:
        files.append("report.json")
    return files


def _warn_preview_fallback(worker: PreviewWorker) -> None:
    warnings.warn(f"preview.png drawn in this process: {worker.fallback_reason}", RuntimeWarning, stacklevel=3)


def write_outcome(
    outcome: JobOutcome,
    outputs: Sequence[str],
    out_dir: str | Path,
    preview_worker: PreviewWorker | None = None,
) -> list[Path]:
    """Write the requested outputs into ``out_dir``; all files or none.

    "rays" -> rays.csv (and rays.vtp when ``trace.paths`` is present), "paths" -> rays.vtp (an error
    without paths), "mesh" -> mesh.vtu when ``outcome.mesh_geometry`` is not None, "report" ->
    report.json. Files are staged in a temporary directory next to ``out_dir`` and moved in only when
    all were written; on any failure ``out_dir`` is left as it was (not even created). After success,
    output files of an earlier run that this run did not produce (names in :data:`OUTPUT_FILES`) are
    removed so the directory never mixes two runs. Returns the written paths in writing order.

    ``preview_worker`` (:class:`bentray.engine.preview_process.PreviewWorker`, started when the job began):
    preview.png is drawn there while the other files are written here; if the child fails for any reason
    of its own the preview is drawn here instead, with the same arguments (same file, same errors). The
    worker is closed on return.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise NotADirectoryError(f"output path {out_dir} exists and is not a directory")
    files = _planned_files(outcome, outputs)
    writers = {
        "rays.csv": lambda p: write_rays_csv(outcome.trace, p),
        "rays.vtp": lambda p: write_rays_vtp(outcome.trace, p),
        "mesh.vtu": lambda p: write_mesh_vtu(_mesh_geometry(outcome), p),
        "report.json": lambda p: write_report_json(outcome.report, p),
        "field.vti": lambda p: _write_field(outcome, p),
        "preview.png": lambda p: _write_preview(outcome, p),
        "receivers.csv": lambda p: write_receivers_csv(outcome.receivers, p),
        "arrivals.csv": lambda p: write_receivers_csv(outcome.arrivals, p),
    }
    parent = out_dir.absolute().parent
    parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", suffix=".tmp", dir=parent))
    try:
        child = None  # the worker drawing preview.png, once it accepted the request
        if preview_worker is not None and "preview.png" in files:  # first, so it draws while we write
            request = _preview_request(outcome, staging / "preview.png")
            if preview_worker.submit(staging / ".preview-request.pkl", request):
                child = preview_worker
            else:
                _warn_preview_fallback(preview_worker)
        for name in files:
            if name == "preview.png" and child is not None:
                continue
            writers[name](staging / name)
        if child is not None and not child.wait():
            _warn_preview_fallback(child)
            writers["preview.png"](staging / "preview.png")
        out_dir.mkdir(exist_ok=True)
        written = []
        for name in files:
            os.replace(staging / name, out_dir / name)
            written.append(out_dir / name)
    finally:
        if preview_worker is not None:
            preview_worker.close()
        shutil.rmtree(staging, ignore_errors=True)
    for name in OUTPUT_FILES:
        if name not in files:
            (out_dir / name).unlink(missing_ok=True)
    return written

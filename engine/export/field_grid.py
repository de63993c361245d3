"""A finished field as numpy arrays: ``field.vti`` point arrays plus the georeference of ``report.json``.

Grid convention (as :mod:`bentray.engine.field_output`): node (i, j, k) of shape (nx, ny, nz) lies at
``origin + (i dx, j dy, k dz)`` in the engine's local frame (metres, z up); arrays are (nx, ny, nz)
indexed [i, j, k]. The georeference (``report.json`` key ``georeference``: ``{"crs": WKT, "local_origin":
[x0, y0]}``, see :class:`bentray.scenes.crs.LocalFrame`) maps local x, y to CRS x, y by adding (x0, y0).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bentray.scenes.crs import LocalFrame

__all__ = ["FieldGrid", "read_field_vti", "read_result"]


@dataclass
class FieldGrid:
    """Point arrays (name -> (nx, ny, nz) float64) of a regular grid with its local-frame origin and spacing
    (3,) metres, and the frame mapping local x, y to the CRS."""

    arrays: dict[str, NDArray[np.float64]]
    origin: NDArray[np.float64]
    spacing: NDArray[np.float64]
    frame: LocalFrame = field(default_factory=LocalFrame)

    @property
    def shape(self) -> tuple[int, int, int]:
        first = next(iter(self.arrays.values()))
        return (int(first.shape[0]), int(first.shape[1]), int(first.shape[2]))

    def axis(self, d: int) -> NDArray[np.float64]:
        """Node coordinates along axis d (0, 1, 2) in the local frame, metres."""
        return np.asarray(self.origin[d] + self.spacing[d] * np.arange(self.shape[d]), dtype=np.float64)

    def level(self, name: str) -> NDArray[np.float64]:
        """The array ``name`` (e.g. ``spl_a``, ``spl_1000``); KeyError lists the arrays there are."""
        if name not in self.arrays:
            raise KeyError(f"no point array {name!r} in the field; there are: {', '.join(sorted(self.arrays))}")
        return self.arrays[name]


def read_field_vti(path: str | Path, frame: LocalFrame | None = None) -> FieldGrid:
    """Read the scalar point arrays of a ``field.vti`` (VTK stores x fastest; returned [i, j, k]); the frame
    is ``frame`` when given, else the georeference in the file's field data (``crs_wkt``,
    ``local_origin_m``), else local metres."""
    import pyvista as pv

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file not found")
    grid = pv.read(path)
    dims = tuple(int(n) for n in grid.dimensions)
    arrays: dict[str, NDArray[np.float64]] = {}
    for name in grid.point_data.keys():
        values = np.asarray(grid.point_data[name], dtype=np.float64)
        if values.ndim != 1:
            continue  # vector arrays (components) are not levels
        arrays[name] = np.ascontiguousarray(values.reshape(dims[::-1]).transpose(2, 1, 0))
    if not arrays:
        raise ValueError(f"{path}: no scalar point arrays")
    if frame is None:  # the georeference field.vti carries (a CRS job), else local metres
        frame = LocalFrame.from_vti_field_data(grid.field_data)
    return FieldGrid(
        arrays=arrays,
        origin=np.asarray(grid.origin, dtype=np.float64),
        spacing=np.asarray(grid.spacing, dtype=np.float64),
        frame=frame or LocalFrame(),
    )


def read_result(result_dir: str | Path, frame: LocalFrame | None = None) -> tuple[FieldGrid, dict[str, Any]]:
    """``RESULT_DIR/field.vti`` and ``RESULT_DIR/report.json`` (if present). The frame is ``frame`` when given,
    else ``report["georeference"]`` when present, else local metres without CRS."""
    result_dir = Path(result_dir)
    report: dict[str, Any] = {}
    report_path = result_dir / "report.json"
    if report_path.is_file():
        report = json.loads(report_path.read_text(encoding="utf-8"))
    if frame is None and isinstance(report.get("georeference"), dict):
        frame = LocalFrame.from_dict(report["georeference"])
    return read_field_vti(result_dir / "field.vti", frame), report

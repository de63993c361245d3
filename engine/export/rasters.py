"""2D level maps as rasters: GeoTIFF (rasterio) and ESRI ASCII grid with a ``.prj`` (WKT1 ESRI).

Map convention: ``level`` (nx, ny) holds the level at node (i, j) = (x0 + i dx, y0 + j dy) in CRS
coordinates (the local frame shifted by the frame's origin). Each node is the *centre* of a raster cell:
row 0 is the northern row (j = ny - 1), so the affine transform is
``Affine(dx, 0, x0 - dx / 2, 0, -dy, y0 + (ny - 1/2) dy)`` and the ASCII header uses ``xllcenter`` /
``yllcenter``. NaN is written as NODATA (-9999).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bentray.scenes.gis_deps import require

__all__ = ["NODATA", "raster_rows", "raster_transform", "write_geotiff", "write_esri_ascii"]

NODATA = -9999.0


def raster_rows(level: ArrayLike) -> NDArray[np.float64]:
    """(ny, nx) raster rows, north first, NaN -> NODATA, from a map (nx, ny) indexed [i, j]."""
    v = np.asarray(level, dtype=np.float64)
    if v.ndim != 2:
        raise ValueError(f"a map is (nx, ny), got shape {v.shape}")
    rows = np.ascontiguousarray(v.T[::-1])
    return np.where(np.isfinite(rows), rows, NODATA)


def raster_transform(xy0: ArrayLike, dxy: ArrayLike, ny: int) -> Any:
    """rasterio Affine of a node-centred map: node (0, 0) at CRS ``xy0``, spacing ``dxy`` (2,) metres."""
    transform = require("rasterio.transform", "GeoTIFF export")
    x0, y0 = (float(v) for v in np.asarray(xy0, dtype=np.float64).reshape(2))
    dx, dy = (float(v) for v in np.asarray(dxy, dtype=np.float64).reshape(2))
    # the Affine itself, not from_origin (which multiplies Affines and warns under newer affine releases)
    return transform.Affine(dx, 0.0, x0 - 0.5 * dx, 0.0, -dy, y0 + (ny - 0.5) * dy)


def write_geotiff(
    path: str | Path, level: ArrayLike, xy0: ArrayLike, dxy: ArrayLike, crs_wkt: str | None, *, band_name: str = ""
) -> Path:
    """One-band float32 GeoTIFF of a map (nx, ny) with the CRS (None: no CRS recorded) and NODATA -9999."""
    rasterio = require("rasterio", "GeoTIFF export")
    rows = raster_rows(level)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    profile = {
        "driver": "GTiff",
        "height": rows.shape[0],
        "width": rows.shape[1],
        "count": 1,
        "dtype": "float32",
        "nodata": NODATA,
        "transform": raster_transform(xy0, dxy, rows.shape[0]),
        "crs": rasterio.crs.CRS.from_wkt(crs_wkt) if crs_wkt else None,
    }
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(rows.astype(np.float32), 1)
        if band_name:
            dst.set_band_description(1, band_name)
    return path


def write_esri_ascii(path: str | Path, level: ArrayLike, xy0: ArrayLike, dxy: ArrayLike, crs_wkt: str | None) -> Path:
    """ESRI ASCII grid (square cells only: ESRI's ``cellsize``) and, with a CRS, ``<stem>.prj`` in WKT1 ESRI."""
    rows = raster_rows(level)
    dx, dy = (float(v) for v in np.asarray(dxy, dtype=np.float64).reshape(2))
    if not np.isclose(dx, dy, rtol=1e-12, atol=0.0):
        raise ValueError(f"an ESRI ASCII grid has square cells; the field spacing is {dx:g} x {dy:g} m (use GeoTIFF)")
    x0, y0 = (float(v) for v in np.asarray(xy0, dtype=np.float64).reshape(2))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ny, nx = rows.shape
    header = (
        f"ncols {nx}\nnrows {ny}\nxllcenter {x0:.17g}\nyllcenter {y0:.17g}\ncellsize {dx:.17g}\n"
        f"NODATA_value {NODATA:g}\n"
    )
    body = "\n".join(" ".join(f"{v:.6f}" for v in row) for row in rows)
    path.write_text(header + body + "\n", encoding="ascii")
    if crs_wkt:
        pyproj = require("pyproj", "ESRI ASCII .prj")
        wkt = pyproj.CRS.from_wkt(crs_wkt).to_wkt(pyproj.enums.WktVersion.WKT1_ESRI)
        path.with_suffix(".prj").write_text(wkt, encoding="ascii")
    return path

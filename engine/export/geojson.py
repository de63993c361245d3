"""GeoJSON FeatureCollections in the scene's projected CRS.

RFC 7946 GeoJSON is WGS84 longitude/latitude; noise maps live in a projected CRS, so these files keep the
projected coordinates and name the CRS in the (pre-RFC, GDAL/QGIS-read) ``crs`` member,
``{"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32632"}}``, when it has an EPSG code;
``bentray:crs_wkt`` always carries the full WKT.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bentray.scenes.gis_deps import require

__all__ = ["feature_collection", "write_geojson"]


def feature_collection(features: list[dict[str, Any]], crs_wkt: str | None) -> dict[str, Any]:
    """A FeatureCollection dict with the CRS members (none when crs_wkt is None)."""
    out: dict[str, Any] = {"type": "FeatureCollection"}
    if crs_wkt:
        pyproj = require("pyproj", "GeoJSON export with a CRS")
        epsg = pyproj.CRS.from_wkt(crs_wkt).to_epsg()
        if epsg is not None:
            out["crs"] = {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{epsg}"}}
        out["bentray:crs_wkt"] = crs_wkt
    out["features"] = features
    return out


def write_geojson(path: str | Path, features: list[dict[str, Any]], crs_wkt: str | None) -> Path:
    """Write the FeatureCollection (compact JSON, NaN refused)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(feature_collection(features, crs_wkt), allow_nan=False, separators=(",", ":"))
    path.write_text(text + "\n", encoding="utf-8")
    return path

"""Area sources (car parks, industrial yards as GeoJSON Polygons with a power per square metre) -> point sources.

Discretisation rule (ISO 9613-2:1996 clause 4, as for line sources in :mod:`bentray.scenes.gis_sources`:
an extended source may be replaced by a point source at its centre when the distance to the receiver
exceeds twice the source's largest dimension): a quadtree of square cells over the polygon's bounds (the
root is the square of side max(width, height) on the lower-left corner). A cell of side ``s`` is split into
four while

* ``s > max_piece_m``, or
* its largest dimension, the diagonal ``sqrt(2) s``, exceeds half the distance from the cell's centre to
  the *nearest* receiver and ``s > min_piece_m``,

and never below ``min_piece_m`` (no infinite refinement for a receiver on the area). Cells that do not
meet the polygon are dropped. Each kept cell's intersection with the polygon (shapely, holes excluded) is
cut into its polygonal parts; each part of area ``a`` becomes a point source at its centroid (at
``point_on_surface`` when the centroid falls outside the part: an L-shaped or holed piece) with sound
power ``L_W = L_W'' + 10 lg(a / 1 m^2)`` per band. The parts' areas are scaled by A / sum(a) (a relative
correction below 1e-9, checked) so the pieces' powers sum to the area's, ``L_W'' + 10 lg(A)``, to
rounding.

Heights, as for line sources: a piece's z is the polygon's z (3D coordinates: the least-squares plane
through all vertices, which must lie within 0.01 m of it) or ``height_above_ground_m`` (GeoJSON property or
argument) above ``ground(xy)``. Without ``ground`` a piece keeps ``height_above_ground_m`` and its job
source is ``{"position": [x, y], "height_above_ground_m": h}``: the job resolves it on the scene's terrain.

Distances of the rule are 3D when the polygon has 3D coordinates and the receivers are 3D; in plan
otherwise (a lower bound: finer pieces). The quadtree works in the polygon's own frame (shifted to its
lower-left corner), so UTM-sized coordinates lose no area precision.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from bentray.scenes.gis_geometry import geometry_from_geojson, shapely_module
from bentray.scenes.gis_sources import PointSource

__all__ = ["AreaPiece", "discretise_area", "read_area_sources_geojson", "PLANE_TOL_M"]

# 3D polygon vertices must lie within this of their least-squares plane (metres).
PLANE_TOL_M = 0.01
# Quadtree depth cap: 2^-40 of the root side is far below any min_piece_m of a real area.
_MAX_DEPTH = 40
# Sum of the clipped pieces' areas vs the polygon's area: anything beyond rounding is a bug.
_AREA_CHECK_REL = 1e-9


@dataclass
class AreaPiece(PointSource):
    """One piece of an area source: a :class:`PointSource` (``line`` is the feature index, ``length_m``
    the side of the quadtree cell) with ``area_m2``, the area of the piece (cell clipped to the polygon)."""

    area_m2: float = math.nan


def _plane(points: NDArray[np.float64], name: str) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """z(xy) of the least-squares plane through (n, 3) vertices; ValueError if a vertex is off it."""
    centre = points.mean(axis=0)
    q = points - centre
    design = np.column_stack([q[:, 0], q[:, 1], np.ones(len(q))])
    coef, *_ = np.linalg.lstsq(design, q[:, 2], rcond=None)
    off = float(np.abs(design @ coef - q[:, 2]).max())
    if off > PLANE_TOL_M:
        raise ValueError(f"{name}: 3D polygon vertices are not planar ({off:.3g} m off their plane)")

    def z(xy: NDArray[np.float64]) -> NDArray[np.float64]:
        d = np.asarray(xy, dtype=np.float64) - centre[:2]
        return np.asarray(centre[2] + coef[2] + d[:, 0] * coef[0] + d[:, 1] * coef[1], dtype=np.float64)

    return z


def _vertices(geom: Any) -> NDArray[np.float64]:
    shapely = shapely_module("area sources")
    return np.asarray(shapely.get_coordinates(geom, include_z=True), dtype=np.float64)


def discretise_area(
    polygon: Any,
    power_db_per_m2: Mapping[str, float],
    receivers: ArrayLike,
    *,
    min_piece_m: float = 1.0,
    max_piece_m: float = 100.0,
    height_above_ground_m: float | None = None,
    ground: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
    area: int = 0,
    name: str = "area",
) -> list[AreaPiece]:
    """Point sources of one area: a shapely Polygon / MultiPolygon (holes allowed, plan metres; 3D
    coordinates give the height) by the quadtree rule of the module docstring.

    receivers : (R, 3) or (R, 2) receiver positions; power_db_per_m2 : dB re 1 pW/m^2 per band label;
    height_above_ground_m with ``ground`` (callable xy (N, 2) -> z (N,); without it the job resolves the
    height), or z from 3D coordinates (exactly one). 0 < min_piece_m <= max_piece_m. ``area`` (feature
    index) and ``name`` label the pieces (``name k``).
    """
    shapely = shapely_module("area sources")
    if not isinstance(polygon, shapely.Polygon | shapely.MultiPolygon) or polygon.is_empty:
        raise ValueError(f"{name}: an area source needs a non-empty Polygon or MultiPolygon")
    reason = str(shapely.is_valid_reason(polygon))
    if reason != "Valid Geometry":
        raise ValueError(f"{name}: invalid polygon: {reason}")
    if not (0 < min_piece_m <= max_piece_m and math.isfinite(max_piece_m)):
        raise ValueError(f"need 0 < min_piece_m <= max_piece_m, got {min_piece_m!r}, {max_piece_m!r}")
    verts = _vertices(polygon)
    has_z = bool(np.all(np.isfinite(verts[:, 2])))
    if not np.all(np.isfinite(verts[:, :2])):
        raise ValueError(f"{name}: a vertex coordinate is not a finite number")
    if (height_above_ground_m is None) == (not has_z):
        raise ValueError(f"{name}: give either 3D coordinates or height_above_ground_m (exactly one)")
    if height_above_ground_m is not None and not (math.isfinite(height_above_ground_m) and height_above_ground_m > 0):
        raise ValueError(f"{name}: height_above_ground_m must be > 0, got {height_above_ground_m!r}")
    if not power_db_per_m2 or not all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in power_db_per_m2.values()
    ):
        raise ValueError(f"{name}: power_db_per_m2 must map band labels to finite dB values")
    plane = _plane(verts, name) if has_z else None

    # the polygon's own frame: lower-left corner of its bounds at the origin
    x0, y0, x1, y1 = (float(v) for v in polygon.bounds)
    local = shapely.transform(polygon, lambda c: c - np.array([x0, y0]))
    total = float(local.area)
    extent = max(x1 - x0, y1 - y0)
    if not total > 1e-9 * extent**2:
        raise ValueError(f"{name}: the polygon has zero area ({total:.3g} m^2 for an extent of {extent:.3g} m)")
    shapely.prepare(local)

    r = np.asarray(receivers, dtype=np.float64)
    r = r.reshape(-1, r.shape[-1]) if r.size else np.zeros((0, 3))
    dims = 3 if r.shape[1] == 3 and plane is not None else 2
    tree = cKDTree(r[:, :dims] - np.array([x0, y0, 0.0][:dims])) if len(r) else None

    def nearest(c: NDArray[np.float64]) -> NDArray[np.float64]:
        if tree is None:
            return np.full(len(c), math.inf)
        q = c
        if dims == 3:
            assert plane is not None
            q = np.column_stack([c, plane(c + np.array([x0, y0]))])
        return np.asarray(tree.query(q)[0], dtype=np.float64)

    kept: list[tuple[Any, float]] = []  # (local piece polygon, cell side)
    side = extent
    centres = np.array([[0.5 * side, 0.5 * side]])
    for depth in range(_MAX_DEPTH + 1):
        if len(centres) == 0:
            break
        h = 0.5 * side
        boxes = shapely.box(centres[:, 0] - h, centres[:, 1] - h, centres[:, 0] + h, centres[:, 1] + h)
        hit = shapely.intersects(local, boxes)
        centres, boxes = centres[hit], boxes[hit]
        rule = math.sqrt(2.0) * side > 0.5 * nearest(centres)
        split = (side > max_piece_m) | (rule & (side > min_piece_m))
        split &= (0.5 * side >= min_piece_m * (1 - 1e-12)) & (depth < _MAX_DEPTH)
        kept += [(g, side) for g in shapely.intersection(local, boxes[~split])]
        c = centres[split]
        q = 0.25 * side
        centres = np.concatenate([c + [-q, -q], c + [q, -q], c + [-q, q], c + [q, q]])
        side = 0.5 * side

    pieces: list[tuple[Any, float]] = []
    for geom, s in kept:
        for part in shapely.get_parts(geom):
            if part.geom_type == "Polygon" and part.area > 0.0:
                pieces.append((part, s))
    areas = np.array([p.area for p, _ in pieces])
    if abs(areas.sum() - total) > _AREA_CHECK_REL * total:
        raise AssertionError(f"{name}: area pieces sum to {areas.sum()!r} m^2, the polygon is {total!r} m^2")
    areas *= total / areas.sum()

    out: list[AreaPiece] = []
    offset = np.array([x0, y0])
    for (part, s), a in zip(pieces, areas, strict=True):
        point = shapely.centroid(part)
        if not shapely.covers(part, point):
            point = shapely.point_on_surface(part)
        xy = np.array([[point.x, point.y]]) + offset
        if plane is not None:
            z = float(plane(xy)[0])
        else:
            assert height_above_ground_m is not None
            z = (math.nan if ground is None else float(np.asarray(ground(xy))[0])) + height_above_ground_m
        power = {k: float(v) + 10.0 * math.log10(float(a)) for k, v in power_db_per_m2.items()}
        pos = (float(xy[0, 0]), float(xy[0, 1]), z)
        out.append(AreaPiece(pos, power, s, area, f"{name} {len(out)}", height_above_ground_m, float(a)))
    return out


def read_area_sources_geojson(
    path: str | Path,
    receivers: ArrayLike,
    *,
    ground: Callable[[NDArray[np.float64]], NDArray[np.float64]] | None = None,
    min_piece_m: float = 1.0,
    max_piece_m: float = 100.0,
) -> list[AreaPiece]:
    """GeoJSON FeatureCollection of Polygon / MultiPolygon features (holes allowed) with
    ``power_db_per_m2`` (an object: band label -> dB re 1 pW/m^2) and ``height_above_ground_m`` (or 3D
    coordinates) -> point sources. Errors are ValueError naming ``features.<i>`` and the reason (shapely's
    for an invalid polygon, e.g. ``Self-intersection at (5, 5)``)."""
    shapely = shapely_module("area sources")
    path = Path(path)
    data = json.loads(path.read_text(encoding="utf-8"))
    features = data.get("features") if isinstance(data, dict) else None
    if not isinstance(features, list):
        raise ValueError(f"{path}: expected a GeoJSON FeatureCollection")
    out: list[AreaPiece] = []
    for i, feature in enumerate(features):
        label = f"{path}: features.{i}"
        geom = feature.get("geometry") if isinstance(feature, dict) else None
        props = (feature.get("properties") if isinstance(feature, dict) else None) or {}
        power = props.get("power_db_per_m2")
        if not isinstance(power, dict) or not power:
            raise ValueError(f"{label}: power_db_per_m2 must be an object of band label -> dB re 1 pW/m^2")
        for band, value in power.items():
            if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value):
                raise ValueError(f"{label}: power_db_per_m2[{band!r}] must be a finite number, got {value!r}")
            if value < 0:
                raise ValueError(
                    f"{label}: power_db_per_m2[{band!r}] is negative ({value!r} dB re 1 pW/m^2): a sign or unit "
                    "mistake (a level per square metre, not a total power or an attenuation)"
                )
        parts, problem = geometry_from_geojson(geom)
        if problem:
            raise ValueError(f"{label}: {problem}")
        assert isinstance(geom, dict) and parts is not None
        # geometry_from_geojson checks in plan; the height comes from the raw coordinates (z kept)
        polygon = shapely.geometry.shape(geom)
        height = props.get("height_above_ground_m")
        if height is not None and (not isinstance(height, int | float) or isinstance(height, bool)):
            raise ValueError(f"{label}: height_above_ground_m must be a number, got {height!r}")
        try:
            out += discretise_area(
                polygon, power, receivers, min_piece_m=min_piece_m, max_piece_m=max_piece_m,
                height_above_ground_m=None if height is None else float(height), ground=ground, area=i,
                name=str(props.get("name", f"features.{i}")),
            )  # fmt: skip
        except ValueError as exc:
            reason = str(exc).removeprefix(f"features.{i}: ")  # an unnamed feature's pieces are named so
            raise ValueError(f"{label}: {reason}") from None
    return out

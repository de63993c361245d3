"""Plan-view polygons of a scene (footprints, barriers, ground zones) as shapely geometries.

Conversions between the GeoJSON / job-file coordinate lists, shapely Polygons and the engine's
:class:`bentray.engine.surfaces.Footprint` (exterior ring counter-clockwise, holes clockwise, rings not
closed), validity with shapely's reason, and the predicates the scene checks need (overlap, point in
polygon). Coordinates are plan-view x, y in metres of the scene's frame (a projected CRS or local metres).

Tolerances are relative to the polygon's own *extent* (not to the size of its coordinates): a 60 m x 30 m
building at UTM northing 5.4e6 m is a 1800 m^2 polygon whatever its offset from the CRS origin.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from bentray.engine.surfaces import Footprint
from bentray.scenes.gis_deps import require

if TYPE_CHECKING:
    from shapely.geometry import MultiPolygon, Polygon

__all__ = [
    "AREA_REL_TOL",
    "OVERLAP_REL_TOL",
    "MAX_ABS_COORDINATE_M",
    "shapely_module",
    "polygon_from_rings",
    "polygon_problem",
    "polygon_parts",
    "footprint_polygon",
    "footprint_from_polygon",
    "overlapping_pairs",
    "points_in_polygon",
    "geometry_from_geojson",
]

# A polygon whose area is below AREA_REL_TOL x (its extent)^2 has zero area in practice: for a 100 m building
# that is 1e-5 m^2 (a sliver 1e-7 m wide), far below survey accuracy, far above float64 rounding of the
# shoelace sum after shifting to the polygon's own corner (~1e-16 x extent^2).
AREA_REL_TOL = 1e-9
# Two footprints overlap when their interiors share more than OVERLAP_REL_TOL x the smaller area: shared walls
# digitised twice (coordinates equal to ~1e-9 m) touch, they do not overlap.
OVERLAP_REL_TOL = 1e-9
# Plan coordinates beyond 1e9 m (more than twenty Earth circumferences) are a unit or CRS mistake; the bound
# keeps every difference, square and area finite (no overflow to inf, no NaN predicates).
MAX_ABS_COORDINATE_M = 1e9

_REASON = re.compile(r"^(?P<what>[^\[]+)\[(?P<x>\S+) (?P<y>\S+)\]$")


def shapely_module(purpose: str = "building footprints and ground zones") -> Any:
    """The shapely module (raises GisDependencyError naming the ``gis`` extra if it is missing)."""
    return require("shapely", purpose)


def _ring(coords: Any) -> np.ndarray:
    """(k, 2) float64 of a ring: a third coordinate dropped, consecutive duplicates and the closing vertex
    removed (conversions, not checks)."""
    ring = np.asarray(coords, dtype=np.float64)
    if ring.ndim != 2 or ring.shape[0] == 0 or ring.shape[1] < 2:
        return np.zeros((0, 2))
    ring = ring[:, :2]
    keep = np.ones(ring.shape[0], dtype=bool)
    keep[1:] = np.any(ring[1:] != ring[:-1], axis=1)
    ring = ring[keep]
    while ring.shape[0] > 1 and np.array_equal(ring[0], ring[-1]):
        ring = ring[:-1]
    return ring


def _signed_area(ring: np.ndarray) -> float:
    """Shoelace area (m^2, > 0 counter-clockwise) of an unclosed ring, after shifting to its first vertex."""
    local = ring - ring[0]
    return 0.5 * float(np.dot(local[:, 0], np.roll(local[:, 1], -1)) - np.dot(np.roll(local[:, 0], -1), local[:, 1]))


def _oriented(ring: np.ndarray, *, ccw: bool) -> np.ndarray:
    """The unclosed ring reversed (``ring[::-1]``) when its orientation is not the one asked for."""
    return ring[::-1].copy() if (_signed_area(ring) > 0) != ccw else ring


def _coordinate_problem(rings: Sequence[np.ndarray]) -> str | None:
    for r, ring in enumerate(rings):
        what = "the exterior ring" if r == 0 else f"hole {r - 1}"
        if not np.all(np.isfinite(ring)):
            return f"{what}: a vertex coordinate is not a finite number"
        if ring.size and np.abs(ring).max() > MAX_ABS_COORDINATE_M:
            return (
                f"{what}: coordinate {np.abs(ring).max():.3g} m exceeds {MAX_ABS_COORDINATE_M:g} m "
                "(plan coordinates are metres of a projected CRS; check the units and scene.crs)"
            )
        n_distinct = np.unique(ring, axis=0).shape[0] if ring.size else 0
        if n_distinct < 3:
            return f"{what}: a ring needs at least 3 distinct vertices, got {n_distinct}"
    return None


def polygon_from_rings(exterior: Any, holes: Sequence[Any] = ()) -> tuple[Polygon | None, str | None]:
    """A shapely Polygon from coordinate lists (exterior [[x, y], ...], holes likewise), or the reason it
    cannot be one. Returns (polygon, None) or (None, reason); the polygon is oriented (exterior
    counter-clockwise, holes clockwise) and checked with :func:`polygon_problem`."""
    shapely = shapely_module()
    rings = [_ring(exterior)] + [_ring(h) for h in holes]
    problem = _coordinate_problem(rings)
    if problem:
        return None, problem
    oriented = [_oriented(r, ccw=(k == 0)) for k, r in enumerate(rings)]
    poly = shapely.Polygon(oriented[0], oriented[1:])
    problem = polygon_problem(poly)
    return (None, problem) if problem else (poly, None)


def polygon_problem(poly: Polygon) -> str | None:
    """Why ``poly`` is not a usable footprint / zone polygon, or None.

    Checks, in order: finite coordinates within MAX_ABS_COORDINATE_M; non-zero area relative to its extent
    (AREA_REL_TOL); shapely validity (``is_valid_reason``, e.g. ``Self-intersection at (5, 0)``, ``Ring
    Self-intersection``, ``Hole lies outside shell``, ``Interior is disconnected``).
    """
    shapely = shapely_module()
    coords = [np.asarray(poly.exterior.coords)[:, :2]] + [np.asarray(r.coords)[:, :2] for r in poly.interiors]
    problem = _coordinate_problem(coords)
    if problem:
        return problem
    ext = coords[0]
    extent = float(np.ptp(ext, axis=0).max())
    # shifted to the first vertex: rounding ~1e-16 extent^2 whatever the size of the coordinates
    flat = shapely.oriented_envelope(shapely.Polygon(ext - ext[0])).area
    if flat <= AREA_REL_TOL * extent**2:
        return f"the polygon has zero area: its vertices are collinear (extent {extent:.3g} m)"
    reason = str(shapely.is_valid_reason(poly))
    if reason == "Valid Geometry":
        area = abs(_signed_area(ext[:-1]))
        if area <= AREA_REL_TOL * extent**2:
            return f"the polygon has zero area ({area:.3g} m^2 for an extent of {extent:.3g} m)"
        return None
    match = _REASON.match(reason)
    if match:
        x, y = float(match["x"]), float(match["y"])
        return f"{match['what'].strip()} at ({x:.10g}, {y:.10g})"
    return reason


def polygon_parts(geom: Polygon | MultiPolygon) -> list[Polygon]:
    """The polygons of a Polygon (itself) or a MultiPolygon (its parts, in order)."""
    return list(geom.geoms) if geom.geom_type == "MultiPolygon" else [geom]


def geometry_from_geojson(geometry: Any) -> tuple[list[Polygon] | None, str | None]:
    """GeoJSON ``Polygon`` or ``MultiPolygon`` geometry object -> (list of valid Polygons, None) or
    (None, reason). Each part is checked with :func:`polygon_from_rings`; a MultiPolygon whose parts
    overlap is refused (GeoJSON requires them disjoint)."""
    kind = geometry.get("type") if isinstance(geometry, dict) else None
    if kind not in ("Polygon", "MultiPolygon"):
        return None, f"geometry must be a Polygon or MultiPolygon, got {kind!r}"
    coords = geometry.get("coordinates")
    parts = [coords] if kind == "Polygon" else coords
    if not isinstance(parts, list) or not parts:
        return None, f"{kind} coordinates must be a non-empty list"
    out = []
    for p, rings in enumerate(parts):
        where = "" if kind == "Polygon" else f"part {p}: "
        if not isinstance(rings, list) or not rings:
            return None, f"{where}a polygon is a non-empty list of rings"
        for r, ring in enumerate(rings):
            if not isinstance(ring, list) or not all(
                isinstance(q, list) and len(q) in (2, 3) and all(_is_number(c) for c in q) for q in ring
            ):
                return None, f"{where}ring {r} must be a list of [x, y] positions with finite numbers"
        poly, problem = polygon_from_rings(rings[0], rings[1:])
        if problem:
            return None, f"{where}{problem}"
        assert poly is not None
        out.append(poly)
    pairs = overlapping_pairs(out)
    if pairs:
        i, j = pairs[0]
        return None, f"MultiPolygon parts {i} and {j} overlap"
    return out, None


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and bool(np.isfinite(value))


def footprint_polygon(fp: Footprint) -> Polygon:
    """The shapely Polygon of an engine Footprint (exterior and holes)."""
    shapely = shapely_module()
    return shapely.Polygon(fp.polygon, [np.asarray(h) for h in fp.holes])


def footprint_from_polygon(
    poly: Polygon, height_m: float, base_z: float | None = None, material: int = 0, name: str = ""
) -> Footprint:
    """Engine Footprint from a valid shapely Polygon: exterior (k, 2) counter-clockwise and holes (h, 2)
    clockwise, rings not closed, metres."""
    exterior = _oriented(np.asarray(poly.exterior.coords, dtype=np.float64)[:-1, :2].copy(), ccw=True)
    holes = [_oriented(np.asarray(r.coords, dtype=np.float64)[:-1, :2].copy(), ccw=False) for r in poly.interiors]
    return Footprint(polygon=exterior, height_m=height_m, base_z=base_z, material=material, name=name, holes=holes)


def overlapping_pairs(polys: Sequence[Polygon]) -> list[tuple[int, int]]:
    """Index pairs (i < j) of polygons whose interiors overlap by more than OVERLAP_REL_TOL x the smaller
    area (STRtree candidates, then the exact intersection area). Touching walls and corners do not count."""
    shapely = shapely_module()
    if len(polys) < 2:
        return []
    geoms = np.array(polys, dtype=object)
    tree = shapely.STRtree(geoms)
    a, b = tree.query(geoms, predicate="intersects")
    keep = a < b
    a, b = a[keep], b[keep]
    if a.size == 0:
        return []
    inter = shapely.area(shapely.intersection(geoms[a], geoms[b]))
    smaller = np.minimum(shapely.area(geoms[a]), shapely.area(geoms[b]))
    hit = inter > OVERLAP_REL_TOL * smaller
    return sorted(zip(a[hit].tolist(), b[hit].tolist(), strict=True))


def points_in_polygon(poly: Polygon, xy: np.ndarray, *, margin: float = 0.0) -> np.ndarray:
    """(N,) bool: points xy (N, 2) metres inside ``poly`` (holes excluded). margin > 0: at least ``margin``
    inside the boundary; margin < 0: up to ``-margin`` outside counts too; 0: the closed polygon."""
    shapely = shapely_module()
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if p.shape[0] == 0:
        return np.zeros(0, dtype=bool)
    if margin == 0.0:
        return np.asarray(shapely.intersects_xy(poly, p[:, 0], p[:, 1]), dtype=bool)
    points = shapely.points(p)
    if margin < 0:
        return np.asarray(shapely.dwithin(poly, points, -margin), dtype=bool)
    inside = np.asarray(shapely.contains_xy(poly, p[:, 0], p[:, 1]), dtype=bool)
    far = ~np.asarray(shapely.dwithin(poly.boundary, points, margin), dtype=bool)
    out: np.ndarray = inside & far
    return out

"""Thin noise barriers: ``scene.buildings.barriers`` (inline polylines with a height) and
``scene.buildings.barriers_file`` (a GeoJSON FeatureCollection of LineString / MultiLineString features
with a ``height`` property in metres and an optional ``base_z`` and ``name``).

A barrier is a vertical screen of zero thickness along its polyline, from its base (``base_z``, default
the lowest ground under the polyline) to ``height_m`` above it. Barriers diffract (engine/diffraction:
the diffraction stage tests the line of sight against them and adds the paths over their top edges);
they are not part of the media mesh, so the beams pass through them and the diffraction stage replaces
the beam field in their shadow (docs/physics.md, "Edge diffraction").

Checks: at least two vertices, no zero-length segment, a simple polyline (shapely ``is_simple``: no
self-intersection), ``0 < height_m < MAX_BUILDING_HEIGHT_M``; the domain checks (vertices strictly
inside the xy box, the top below the domain top) run in :func:`barriers_from_specs`, each naming the
job field (``scene.buildings.barriers.2: ...``).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from bentray.engine.surfaces import Barrier
from bentray.scenes.bounds import Coord, Vec2
from bentray.scenes.gis_geometry import shapely_module
from bentray.scenes.terrain_io import MAX_BUILDING_HEIGHT_M, MAX_FOOTPRINTS, MAX_POLYGON_VERTICES, SceneFileError

__all__ = ["BarrierSpec", "barriers_from_specs", "polyline_problem", "read_barriers_geojson"]


class BarrierSpec(BaseModel):
    """An inline barrier: ``polyline`` [[x, y], ...] metres, ``height_m`` above ``base_z`` (default: the
    lowest ground under the polyline), an optional ``name``."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    polyline: list[Vec2] = Field(min_length=2, max_length=MAX_POLYGON_VERTICES)
    height_m: float = Field(gt=0, lt=MAX_BUILDING_HEIGHT_M)
    base_z: Coord | None = None
    name: str | None = Field(default=None, max_length=100)

    @model_validator(mode="after")
    def _simple(self) -> BarrierSpec:
        problem = polyline_problem(np.asarray(self.polyline, float))
        if problem:
            raise ValueError(f"polyline: {problem}")
        return self


def polyline_problem(xy: np.ndarray) -> str | None:
    """Why the polyline (k, 2) cannot be a barrier, or None: fewer than two vertices, a zero-length
    segment, or a self-intersection (shapely)."""
    if xy.ndim != 2 or xy.shape[0] < 2 or xy.shape[1] != 2:
        return "a barrier needs at least two [x, y] vertices"
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    if np.any(seg <= 0.0):
        i = int(np.argmin(seg))
        return f"segment {i} has zero length (vertices {i} and {i + 1} coincide)"
    shapely = shapely_module()
    line = shapely.LineString(xy)
    if not line.is_simple:
        inter = shapely.unary_union(line)  # noded: a self-crossing shows up as a vertex of degree > 2
        pts = [tuple(p) for g in getattr(inter, "geoms", [inter]) for p in np.asarray(g.coords)]
        counts: dict[tuple[float, float], int] = {}
        for p in pts:
            counts[p] = counts.get(p, 0) + 1
        where = next((p for p, n in counts.items() if n > 2), None) or next(
            (p for p, n in counts.items() if n > 1), None
        )
        at = f" at ({where[0]:g}, {where[1]:g})" if where is not None else ""
        return f"the polyline intersects itself{at}"
    return None


def read_barriers_geojson(path: str | Path) -> list[BarrierSpec]:
    """GeoJSON FeatureCollection of LineString / MultiLineString features -> BarrierSpecs (properties:
    ``height`` or ``height_m`` metres, optional ``base_z``, ``name``); SceneFileError naming the feature."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise SceneFileError(f"cannot read {path.name}: {exc}") from None
    if (
        not isinstance(data, dict)
        or data.get("type") != "FeatureCollection"
        or not isinstance(data.get("features"), list)
    ):
        raise SceneFileError('expected a GeoJSON object with "type": "FeatureCollection" and a "features" list')
    if len(data["features"]) > MAX_FOOTPRINTS:
        raise SceneFileError(f"{len(data['features']):,} features; the limit is {MAX_FOOTPRINTS:,}")
    out = []
    for i, feat in enumerate(data["features"]):
        geom = (feat or {}).get("geometry") or {}
        props = (feat or {}).get("properties") or {}
        kind = geom.get("type")
        if kind not in ("LineString", "MultiLineString"):
            raise SceneFileError(f"features.{i}: a barrier is a LineString or MultiLineString, not {kind!r}")
        lines = [geom.get("coordinates")] if kind == "LineString" else list(geom.get("coordinates") or [])
        height = props.get("height_m", props.get("height"))
        for j, coords in enumerate(lines):
            try:
                xy = [(float(c[0]), float(c[1])) for c in (coords or [])]
                spec = BarrierSpec(
                    polyline=xy,
                    height_m=float(height) if height is not None else 0.0,
                    base_z=props.get("base_z"),
                    name=str(props.get("name", f"barrier {i}")) + (f" part {j}" if len(lines) > 1 else ""),
                )
            except (TypeError, ValueError, IndexError) as exc:
                msg = str(exc).splitlines()
                why = "; ".join(m.strip() for m in msg[1:] if m.strip()) if len(msg) > 1 else str(exc)
                raise SceneFileError(f"features.{i}: {why}") from None
            out.append(spec)
    return out


def barriers_from_specs(
    specs: list[BarrierSpec],
    labels: list[str],
    dmin: np.ndarray,
    dmax: np.ndarray,
    ground_z: Callable[[np.ndarray], np.ndarray],
    offset: tuple[float, float] | None = None,
) -> tuple[list[Barrier], list[str]]:
    """Engine barriers and the problems (one line each, starting with the label): a vertex outside the
    domain's xy box, a base below the domain bottom or a top at or above the domain top.

    ground_z : callable (M, 2) -> (M,) ground height (m) for the default base (the lowest ground under the
    polyline's vertices and segment midpoints); offset : subtracted from plan coordinates (CRS scenes)."""
    barriers: list[Barrier] = []
    problems: list[str] = []
    for spec, label in zip(specs, labels, strict=True):
        xy = np.asarray(spec.polyline, float)
        if offset:
            xy = xy - np.asarray(offset, float)
        outside = ~np.all((xy > dmin[:2]) & (xy < dmax[:2]), axis=1)
        if np.any(outside):
            v = xy[int(np.argmax(outside))]
            problems.append(
                f"{label}: vertex ({v[0]:g}, {v[1]:g}) is outside the domain's xy box "
                f"x {dmin[0]:g}..{dmax[0]:g}, y {dmin[1]:g}..{dmax[1]:g} m"
            )
            continue
        if spec.base_z is not None:
            base = float(spec.base_z)
        else:
            probe = np.vstack([xy, 0.5 * (xy[1:] + xy[:-1])])
            base = float(np.min(np.asarray(ground_z(probe), dtype=np.float64)))
        if base < dmin[2]:
            problems.append(f"{label}: base_z = {base:g} m is below the domain bottom (min z = {dmin[2]:g} m)")
            continue
        if base + spec.height_m >= dmax[2]:
            problems.append(
                f"{label}: the top at z = {base + spec.height_m:g} m is not below the domain top "
                f"(max z = {dmax[2]:g} m)"
            )
            continue
        barriers.append(Barrier(xy, float(spec.height_m), base, spec.name or label))
    return barriers, problems

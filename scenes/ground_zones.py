"""Ground zones: plan-view polygons of ground with their own acoustic impedance (grass, asphalt, water).

A zone gives exactly one of ``flow_resistivity`` (Pa s/m^2, the Delany-Bazley parameter of
:class:`bentray.scenes.scene_models.MaterialSpec`), ``G`` (the CNOSSOS-EU ground factor, 0 hard .. 1
porous) or ``material`` (a name from ``scene.materials``). Zones come inline or from a GeoJSON file of
Polygon / MultiPolygon features (properties as above, optional ``name``), validated like footprints
(shapely). Where zones overlap, the later zone wins (zones are painted in order); outside every zone the
ground keeps the terrain's material. Each ground face of the mesh takes the zone under its centroid (the
mesh does not follow zone edges: the boundary is resolved to the horizontal spacing).

G -> flow resistivity (CNOSSOS-EU, Commission Directive (EU) 2015/996, Annex, Table 2.5.a: ground classes
with their representative flow resistivity and G): G = 0 -> 20,000 kPa s/m^2 (class G, hard: asphalt,
concrete), G = 0.3 -> 2,000 kPa s/m^2 (class F, compacted dense ground: gravel road, parking lot),
G = 0.7 -> 500 kPa s/m^2 (class E, compacted field, lawns), G = 1 -> 200 kPa s/m^2 (class D, normal
uncompacted ground: pasture, grass). Between these points sigma is interpolated linearly in lg(sigma).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from bentray.engine.surfaces import GroundZone
from bentray.scenes.gis_geometry import geometry_from_geojson, polygon_from_rings

__all__ = [
    "G_TABLE",
    "flow_resistivity_from_g",
    "GroundZoneSpec",
    "GroundZonesSpec",
    "ZoneMaterial",
    "read_ground_zones_geojson",
    "ground_zones_from_spec",
]

# (G, flow resistivity in Pa s/m^2) of CNOSSOS-EU Table 2.5.a classes G, F, E, D (see the module docstring)
G_TABLE: tuple[tuple[float, float], ...] = ((0.0, 2.0e7), (0.3, 2.0e6), (0.7, 5.0e5), (1.0, 2.0e5))
MAX_ZONES = 10_000


def flow_resistivity_from_g(g: float) -> float:
    """Flow resistivity (Pa s/m^2) of ground factor G in [0, 1]: log-linear through G_TABLE."""
    if not (math.isfinite(g) and 0.0 <= g <= 1.0):
        raise ValueError(f"G must be in [0, 1], got {g!r}")
    gs = [p[0] for p in G_TABLE]
    lg = [math.log10(p[1]) for p in G_TABLE]
    return float(10.0 ** np.interp(g, gs, lg))


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class _ZoneAcoustics(_Model):
    flow_resistivity: float | None = Field(default=None, gt=0)
    G: float | None = Field(default=None, ge=0, le=1)
    material: str | None = None

    @model_validator(mode="after")
    def _one(self) -> _ZoneAcoustics:
        given = [k for k in ("flow_resistivity", "G", "material") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of flow_resistivity (Pa s/m^2), G (0..1) and material; got {given}")
        return self


class GroundZoneSpec(_ZoneAcoustics):
    """An inline zone: ``polygon`` [[x, y], ...] with optional ``holes``, and its acoustics."""

    polygon: list[tuple[float, float]] = Field(min_length=3, max_length=100_000)
    holes: list[list[tuple[float, float]]] = Field(default_factory=list, max_length=1000)
    name: str | None = Field(default=None, max_length=100)

    @model_validator(mode="after")
    def _valid(self) -> GroundZoneSpec:
        _, problem = polygon_from_rings(self.polygon, self.holes)
        if problem:
            raise ValueError(problem)
        return self


class GroundZonesSpec(_Model):
    """``scene.ground_zones``: a GeoJSON ``file`` and/or inline ``zones`` (file zones first)."""

    file: str | None = Field(default=None, min_length=1)
    zones: list[GroundZoneSpec] = Field(default_factory=list, max_length=MAX_ZONES)

    @model_validator(mode="after")
    def _something(self) -> GroundZonesSpec:
        if self.file is None and not self.zones:
            raise ValueError("give a GeoJSON file or zones (or leave ground_zones out)")
        return self


class ZoneMaterial:
    """Material table builder: zone acoustics -> material index (new materials appended, deduplicated)."""

    def __init__(self, names: dict[str, int], n_materials: int) -> None:
        self.names = dict(names)
        self.new: list[tuple[str, float]] = []  # (name, flow resistivity) to append to the table
        self._by_sigma: dict[float, int] = {}
        self._next = n_materials

    def index(self, acoustics: _ZoneAcoustics, where: str) -> int:
        if acoustics.material is not None:
            if acoustics.material not in self.names:
                raise ValueError(f"{where}: material {acoustics.material!r} is not defined ({', '.join(self.names)})")
            return self.names[acoustics.material]
        sigma = (
            float(acoustics.flow_resistivity)
            if acoustics.flow_resistivity is not None
            else flow_resistivity_from_g(float(acoustics.G))  # type: ignore[arg-type]
        )
        if sigma not in self._by_sigma:
            self._by_sigma[sigma] = self._next
            self.new.append((f"ground zone sigma={sigma:.6g}", sigma))
            self._next += 1
        return self._by_sigma[sigma]


def read_ground_zones_geojson(path: str | Path, table: ZoneMaterial) -> list[GroundZone]:
    """GeoJSON zones -> GroundZones (one per polygon part); ValueError naming ``features.<i>``."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read GeoJSON ({exc})") from None
    features = data.get("features") if isinstance(data, dict) else None
    if not isinstance(features, list):
        raise ValueError(f"{path}: expected a GeoJSON FeatureCollection")
    if len(features) > MAX_ZONES:
        raise ValueError(f"{path}: {len(features):,} features; the limit is {MAX_ZONES:,}")
    out: list[GroundZone] = []
    for i, feature in enumerate(features):
        where = f"{path}: features.{i}"
        props = (feature.get("properties") if isinstance(feature, dict) else None) or {}
        polys, problem = geometry_from_geojson(feature.get("geometry") if isinstance(feature, dict) else None)
        if problem:
            raise ValueError(f"{where}: {problem}")
        try:
            acoustics = _ZoneAcoustics.model_validate(
                {k: props[k] for k in ("flow_resistivity", "G", "material") if k in props}
            )
        except ValueError as exc:
            raise ValueError(f"{where}: {_first_error(exc)}") from None
        mat = table.index(acoustics, where)
        name = str(props.get("name", f"zone {i}"))
        out += [_zone(poly, mat, name) for poly in polys or []]
    return out


def _first_error(exc: Exception) -> str:
    errors = getattr(exc, "errors", None)
    if callable(errors):
        first: dict[str, Any] = errors()[0]
        loc = ".".join(str(v) for v in first.get("loc", ()))
        return f"{loc + ': ' if loc else ''}{first.get('msg', exc)}"
    return str(exc)


def _zone(poly: Any, material: int, name: str) -> GroundZone:
    exterior = np.asarray(poly.exterior.coords, dtype=np.float64)[:-1, :2].copy()
    holes = [np.asarray(r.coords, dtype=np.float64)[:-1, :2].copy() for r in poly.interiors]
    return GroundZone(polygon=exterior, holes=holes, material=material, name=name)


def ground_zones_from_spec(
    spec: GroundZonesSpec, base_dir: str | Path | None, names: dict[str, int], n_materials: int
) -> tuple[list[GroundZone], list[tuple[str, float]]]:
    """(zones in painting order, new materials (name, flow resistivity) to append to the table)."""
    table = ZoneMaterial(names, n_materials)
    zones: list[GroundZone] = []
    if spec.file is not None:
        path = Path(spec.file)
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        zones += read_ground_zones_geojson(path, table)
    for i, z in enumerate(spec.zones):
        poly, _ = polygon_from_rings(z.polygon, z.holes)
        zones.append(_zone(poly, table.index(z, f"zones.{i}"), z.name or f"zone {i}"))
    return zones, table.new


def zone_material_at(zones: list[GroundZone], xy: np.ndarray, base: np.ndarray) -> np.ndarray:
    """Material (N,) int64 at plan points xy (N, 2): the last zone containing the point, else ``base``."""
    from bentray.scenes.gis_geometry import shapely_module

    shapely = shapely_module("ground zones")
    out = np.array(base, dtype=np.int64, copy=True)
    for z in zones:
        poly = shapely.Polygon(z.polygon, [np.asarray(h) for h in z.holes])
        inside = np.asarray(shapely.intersects_xy(poly, xy[:, 0], xy[:, 1]), dtype=bool)
        out[inside] = z.material
    return out

"""Job-file models for scene surfaces (terrain, buildings, materials) and their conversion to
:class:`bentray.engine.surfaces.SceneSurfaces`.

Models (pydantic v2, unknown keys and NaN/inf rejected; validators only check, never rewrite):
``scene.terrain`` -> :class:`TerrainSpec`, ``scene.buildings`` -> :class:`BuildingsSpec` (a GeoJSON file,
inline ``footprints`` and/or closed ``obstacles`` meshes), ``scene.materials`` -> list of
:class:`MaterialSpec`. Material names are looked up in ``scene.materials``; ``rigid`` (index 0) always
exists. Cross-field checks that need the files or the domain run in :func:`surfaces_from_specs` and
raise :class:`SceneSpecError` (or the reader's :class:`SceneFileError`) naming the job field.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from bentray.engine.errors import JobInputError
from bentray.engine.surfaces import Footprint, HeightGrid, Material, SceneSurfaces, TriangleSurface
from bentray.scenes.barrier_models import BarrierSpec, barriers_from_specs, read_barriers_geojson
from bentray.scenes.bounds import MAX_LENGTH_M, Coord, Vec2, json_coordinate_problem
from bentray.scenes.geometry import box_pairs, terrain_height_at, terrain_xy_bounds
from bentray.scenes.gis_frame import shift_footprint, shift_terrain, shift_zone
from bentray.scenes.gis_geometry import (
    footprint_from_polygon,
    footprint_polygon,
    overlapping_pairs,
    points_in_polygon,
    polygon_from_rings,
)
from bentray.scenes.ground_zones import GroundZonesSpec, ground_zones_from_spec
from bentray.scenes.terrain_io import (
    DEFAULT_STOREY_HEIGHT_M,
    MAX_BUILDING_HEIGHT_M,
    MAX_FOOTPRINTS,
    MAX_POLYGON_VERTICES,
    TERRAIN_FORMATS,
    SceneFileError,
    read_footprints_geojson,
    read_obstacle_mesh,
    read_terrain,
)

__all__ = [
    "COVERAGE_SAMPLES",
    "RIGID",
    "MaterialSpec",
    "TerrainSpec",
    "FootprintSpec",
    "ObstacleSpec",
    "BuildingsSpec",
    "SceneSpecError",
    "material_reference_errors",
    "surfaces_from_specs",
    "surface_problems",
    "footprint_base_z",
    "footprint_bases",
    "check_points_above_ground",
    "resolve_source_heights",
]

RIGID = "rigid"  # material 0: acoustically rigid, always defined
# A triangle-mesh terrain must cover the domain's xy box; checked on a COVERAGE_SAMPLES^2 lattice of
# points (edges included) plus the box corners: gaps narrower than box size / 64 can go unnoticed.
COVERAGE_SAMPLES = 65
_NAME = r"^[A-Za-z0-9][A-Za-z0-9 ._-]{0,63}$"


class SceneSpecError(JobInputError):
    """The scene's surfaces are valid files but do not fit together (outside the domain, overlapping,
    undefined material, a point below the ground or inside a building)."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class MaterialSpec(_Model):
    """A named ground or facade material: Delany-Bazley flow resistivity in Pa s/m^2, null = rigid."""

    name: str = Field(pattern=_NAME)
    flow_resistivity: float | None = Field(gt=0)

    @field_validator("name")
    @classmethod
    def _not_rigid(cls, value: str) -> str:
        if value == RIGID:
            raise ValueError(f"{RIGID!r} is built in (material 0, flow_resistivity null); choose another name")
        return value


class TerrainSpec(_Model):
    """Terrain file (relative paths resolve against the job file's folder). ``format`` defaults to the
    suffix; ``origin`` (x, y of z[0, 0]) and ``spacing`` (dx, dy) in metres only for ``.npy``."""

    file: str = Field(min_length=1)
    format: Literal["asc", "npy", "npz", "obj", "stl", "ply"] | None = None
    origin: Vec2 | None = None
    spacing: tuple[float, float] | None = None
    material: str | None = None

    @property
    def effective_format(self) -> str:
        return self.format or Path(self.file).suffix.lstrip(".").lower()

    @field_validator("spacing")
    @classmethod
    def _positive(cls, value: tuple[float, float] | None) -> tuple[float, float] | None:
        if value is not None and min(value) <= 0:
            raise ValueError(f"spacing must be > 0 along x and y, got {list(value)}")
        if value is not None and max(value) > MAX_LENGTH_M:
            raise ValueError(f"spacing must be at most {MAX_LENGTH_M:g} m, got {list(value)}")
        return value

    @model_validator(mode="after")
    def _format_and_grid(self) -> TerrainSpec:
        fmt = self.effective_format
        if fmt not in TERRAIN_FORMATS:
            raise ValueError(
                f"cannot tell the terrain format from {self.file!r}; set format to one of {', '.join(TERRAIN_FORMATS)}"
            )
        given = [k for k in ("origin", "spacing") if getattr(self, k) is not None]
        if fmt == "npy" and len(given) != 2:
            raise ValueError("a .npy terrain holds heights only: give origin [x, y] and spacing [dx, dy] in metres")
        if fmt != "npy" and given:
            raise ValueError(f"{' and '.join(given)} only apply to .npy terrain; a .{fmt} file carries its own")
        return self


class FootprintSpec(_Model):
    """An inline building or barrier: a polygon [[x, y], ...] (either orientation, closing vertex optional)
    with optional ``holes`` (courtyards, same form), ``height_m`` above ``base_z`` (default: the lowest
    terrain under the polygon) or ``levels`` storeys of ``scene.buildings.storey_height_m``."""

    polygon: list[Vec2] = Field(min_length=3, max_length=MAX_POLYGON_VERTICES)
    holes: list[list[Vec2]] = Field(default_factory=list, max_length=1000)
    height_m: float | None = Field(default=None, gt=0, lt=MAX_BUILDING_HEIGHT_M)
    levels: float | None = Field(default=None, gt=0, le=300)
    base_z: Coord | None = None
    material: str | None = None
    name: str | None = Field(default=None, max_length=100)

    @model_validator(mode="after")
    def _valid(self) -> FootprintSpec:
        if (self.height_m is None) == (self.levels is None):
            raise ValueError("give exactly one of height_m (metres) and levels (storeys)")
        _, problem = polygon_from_rings(self.polygon, self.holes)
        if problem:
            raise ValueError(problem)
        return self

    def height(self, storey_height_m: float) -> float:
        """Roof height above the base in metres (``height_m``, or ``levels`` x storey_height_m)."""
        return float(self.height_m) if self.height_m is not None else float(self.levels or 0) * storey_height_m


class ObstacleSpec(_Model):
    """A closed obstacle mesh (OBJ/STL/PLY; watertight, outward normals, not self-intersecting)."""

    file: str = Field(min_length=1)
    format: Literal["obj", "stl", "ply"] | None = None
    name: str | None = Field(default=None, max_length=100)
    material: str | None = None  # a name from scene.materials (default rigid)


class BuildingsSpec(_Model):
    """Buildings and barriers: a GeoJSON ``file`` of footprints, inline ``footprints``, closed ``obstacles``;
    thin diffracting ``barriers`` (polylines with a height) inline or as a GeoJSON ``barriers_file``
    (scenes/barrier_models.py)."""

    file: str | None = Field(default=None, min_length=1)
    footprints: list[FootprintSpec] = Field(default_factory=list, max_length=MAX_FOOTPRINTS)
    obstacles: list[ObstacleSpec] = Field(default_factory=list, max_length=1000)
    barriers: list[BarrierSpec] = Field(default_factory=list, max_length=MAX_FOOTPRINTS)
    barriers_file: str | None = Field(default=None, min_length=1, max_length=255)
    # metres per storey for `levels` / GeoJSON `building:levels`
    storey_height_m: float = Field(default=DEFAULT_STOREY_HEIGHT_M, gt=0, le=20)

    @field_validator("file", "barriers_file")
    @classmethod
    def _geojson(cls, value: str | None) -> str | None:
        if value is not None and Path(value).suffix.lower() not in (".geojson", ".json"):
            raise ValueError(f"buildings file must be GeoJSON (.geojson or .json), got {value!r}")
        return value

    @model_validator(mode="after")
    def _something(self) -> BuildingsSpec:
        if self.file is None and not self.footprints and not self.obstacles and not self.barriers:
            if self.barriers_file is None:
                raise ValueError("give a GeoJSON file, footprints or obstacles, or barriers (or leave buildings out)")
        for i, fp in enumerate(self.footprints):
            if not fp.height(self.storey_height_m) < MAX_BUILDING_HEIGHT_M:
                raise ValueError(
                    f"footprints.{i}: {fp.levels:g} levels x {self.storey_height_m:g} m is not below "
                    f"{MAX_BUILDING_HEIGHT_M:g} m"
                )
        return self


class _Box(Protocol):
    """Anything with ``min`` and ``max`` (x, y, z) in metres, e.g. :class:`bentray.scenes.schema.Domain`."""

    @property
    def min(self) -> Sequence[float]: ...

    @property
    def max(self) -> Sequence[float]: ...


def material_reference_errors(
    terrain: TerrainSpec | None, buildings: BuildingsSpec | None, materials: Sequence[MaterialSpec]
) -> list[tuple[tuple[str | int, ...], str]]:
    """(location relative to ``scene``, reason) for duplicate material names and undefined references
    in the job itself (GeoJSON files are checked when read). For the schema's Scene validator."""
    errors: list[tuple[tuple[str | int, ...], str]] = []
    names = [RIGID]
    for i, m in enumerate(materials):
        if m.name in names:
            errors.append((("materials", i, "name"), f"duplicate material name {m.name!r}"))
        names.append(m.name)
    defined = ", ".join(names)
    if terrain is not None and terrain.material is not None and terrain.material not in names:
        errors.append((("terrain", "material"), f"material {terrain.material!r} is not defined ({defined})"))
    for kind in ("footprints", "obstacles"):
        for i, item in enumerate(getattr(buildings, kind) if buildings is not None else []):
            if item.material is not None and item.material not in names:
                errors.append(
                    (("buildings", kind, i, "material"), f"material {item.material!r} is not defined ({defined})")
                )
    return errors


def footprint_bases(
    terrain: HeightGrid | TriangleSurface | None, footprints: Sequence[Footprint], flat_z: float
) -> np.ndarray:
    """Ground level (F,) in metres of each footprint: ``base_z`` if set, else an estimate of the lowest
    terrain height under the polygon (its vertices, points every half terrain spacing along its edges and
    the terrain nodes inside it; ``flat_z`` without terrain). NaN where the terrain does not cover it."""
    out = np.array([flat_z if fp.base_z is None else fp.base_z for fp in footprints], dtype=np.float64)
    todo = [k for k, fp in enumerate(footprints) if fp.base_z is None]
    if terrain is None or not todo:
        return out
    lo = np.array([footprints[k].polygon.min(axis=0) for k in todo])
    hi = np.array([footprints[k].polygon.max(axis=0) for k in todo])
    inside_z: list[np.ndarray] = []
    if isinstance(terrain, HeightGrid):
        step = 0.5 * min(float(np.min(np.diff(terrain.x))), float(np.min(np.diff(terrain.y))))
        for n, k in enumerate(todo):  # the grid window under each footprint's bounding box
            j0, j1 = int(np.searchsorted(terrain.x, lo[n, 0])), int(np.searchsorted(terrain.x, hi[n, 0], "right"))
            i0, i1 = int(np.searchsorted(terrain.y, lo[n, 1])), int(np.searchsorted(terrain.y, hi[n, 1], "right"))
            gx, gy = np.meshgrid(terrain.x[j0:j1], terrain.y[i0:i1])
            nodes = np.column_stack([gx.ravel(), gy.ravel()])
            inside = points_in_polygon(footprint_polygon(footprints[k]), nodes)
            inside_z.append(terrain.z[i0:i1, j0:j1].ravel()[inside])
    else:
        e = terrain.vertices[terrain.triangles][:, :, :2]
        step = 0.5 * float(np.median(np.linalg.norm(np.roll(e, -1, axis=1) - e, axis=2)))
        xy = terrain.vertices[:, :2]
        iv, ifp = box_pairs(xy, xy, lo, hi)
        for n, k in enumerate(todo):
            v = iv[ifp == n]
            inside_z.append(terrain.vertices[v[points_in_polygon(footprint_polygon(footprints[k]), xy[v])], 2])
    for n, k in enumerate(todo):
        samples = []
        for poly in [footprints[k].polygon, *footprints[k].holes]:
            a, b = poly, np.roll(poly, -1, axis=0)
            samples.append(a)
            for m in range(poly.shape[0]):
                count = max(int(np.ceil(np.linalg.norm(b[m] - a[m]) / step)), 1)
                samples.append(a[m] + (np.arange(1, count)[:, None] / count) * (b[m] - a[m]))
        edge_z = terrain_height_at(terrain, np.concatenate(samples))
        out[k] = min(float(np.min(edge_z)), float(np.min(inside_z[n], initial=np.inf)))
    return out


def footprint_base_z(terrain: HeightGrid | TriangleSurface | None, footprint: Footprint, flat_z: float) -> float:
    """One footprint's ground level in metres (see :func:`footprint_bases`)."""
    return float(footprint_bases(terrain, [footprint], flat_z)[0])


def _resolve(base_dir: str | Path | None, file: str) -> Path:
    path = Path(file)
    return path if path.is_absolute() or base_dir is None else Path(base_dir) / path


def _fmt(values) -> str:
    return "(" + ", ".join(f"{v:g}" for v in values) + ")"


def surfaces_from_specs(
    terrain: TerrainSpec | None,
    buildings: BuildingsSpec | None,
    materials: Sequence[MaterialSpec] | None,
    base_dir: str | Path | None,
    domain: _Box,
    prefix: str = "scene",
    *,
    ground_zones: GroundZonesSpec | None = None,
    offset: tuple[float, float] | None = None,
) -> SceneSurfaces:
    """Read and check the scene's surface files and inline footprints; return the engine container.

    domain : the scene box (``min``, ``max`` in metres). Checks: material names defined and unique;
    terrain covers the domain's xy box, stays inside [min z, max z); every footprint vertex strictly
    inside the xy box, roofs below max z, no two footprints overlapping (touching walls are fine);
    obstacle vertices strictly inside the box. ``ground_zones``: zones painted over the ground (their
    flow resistivities / G values appended to the material table). ``offset`` (x0, y0): subtracted from every
    plan coordinate read (a CRS scene localised by :func:`bentray.scenes.gis_frame.localise_job`; the
    domain is then already local). Raises SceneFileError (unreadable or
    invalid file) or SceneSpecError, each line starting with the job field (``scene.terrain.file: ...``).
    """
    materials = list(materials or [])
    dmin = np.asarray(domain.min, dtype=np.float64)
    dmax = np.asarray(domain.max, dtype=np.float64)
    errors = [
        f"{prefix}.{'.'.join(map(str, loc))}: {why}"
        for loc, why in material_reference_errors(terrain, buildings, materials)
    ]
    if errors:
        raise SceneSpecError("\n".join(errors))
    table = [Material(RIGID, None)] + [Material(m.name, m.flow_resistivity) for m in materials]
    index = {m.name: i for i, m in enumerate(table)}
    surfaces = SceneSurfaces(materials=table)
    if ground_zones is not None:
        try:
            zones, new_materials = ground_zones_from_spec(ground_zones, base_dir, index, len(table))
        except ValueError as exc:
            raise SceneSpecError(f"{prefix}.ground_zones: {exc}") from None
        table += [Material(name, sigma) for name, sigma in new_materials]
        surfaces.ground_zones = [shift_zone(z, offset) for z in zones] if offset else zones

    if terrain is not None:
        field = f"{prefix}.terrain.file"
        try:
            grid = read_terrain(
                _resolve(base_dir, terrain.file), terrain.effective_format, terrain.origin, terrain.spacing
            )
        except SceneFileError as exc:
            raise SceneFileError(f"{field}: {exc}") from None
        grid.default_material = index[terrain.material or RIGID]
        if offset:
            shift_terrain(grid, offset)
        errors += [f"{field}: {why}" for why in _terrain_problems(grid, dmin, dmax)]
        surfaces.terrain = grid

    labelled: list[tuple[str, Footprint]] = []
    if buildings is not None:
        if buildings.file is not None:
            field = f"{prefix}.buildings.file"
            problem = json_coordinate_problem(_resolve(base_dir, buildings.file))
            if problem is not None:  # before any geometry: no extent can overflow
                raise SceneFileError(f"{field}: {problem}")
            try:
                read = read_footprints_geojson(_resolve(base_dir, buildings.file), index, buildings.storey_height_m)
            except SceneFileError as exc:
                raise SceneFileError(f"{field}: {exc}") from None
            labelled += [(f"{field}: {fp.name!r}", shift_footprint(fp, offset) if offset else fp) for fp in read]
        for i, spec in enumerate(buildings.footprints):
            poly, _ = polygon_from_rings(spec.polygon, spec.holes)
            assert poly is not None  # checked by FootprintSpec
            fp = footprint_from_polygon(
                poly,
                height_m=spec.height(buildings.storey_height_m),
                base_z=spec.base_z,
                material=index[spec.material or RIGID],
                name=spec.name or f"footprint {i}",
            )
            if offset:
                shift_footprint(fp, offset)
            labelled.append((f"{prefix}.buildings.footprints.{i}" + (f" ({spec.name!r})" if spec.name else ""), fp))
        for i, ob in enumerate(buildings.obstacles):
            field = f"{prefix}.buildings.obstacles.{i}.file"
            try:
                vertices, faces = read_obstacle_mesh(_resolve(base_dir, ob.file), ob.format)
            except SceneFileError as exc:
                raise SceneFileError(f"{field}: {exc}") from None
            if offset:
                vertices = vertices - np.array([offset[0], offset[1], 0.0])
            # strictly inside, except that a base may stand on the flat ground (z = domain min z)
            outside = ~(
                np.all((vertices > dmin) & (vertices < dmax), axis=1)
                | (
                    np.all((vertices[:, :2] > dmin[:2]) & (vertices[:, :2] < dmax[:2]), axis=1)
                    & (vertices[:, 2] == dmin[2])
                )
            )
            if np.any(outside):
                errors.append(
                    f"{field}: {int(outside.sum())} vertices lie outside the domain (first "
                    f"{_fmt(vertices[np.argmax(outside)])}); the domain is {_fmt(dmin)} to {_fmt(dmax)}"
                )
            surfaces.obstacles.append((vertices, faces))
            surfaces.obstacle_materials.append(index[ob.material or RIGID])
    errors += _footprint_problems(labelled, surfaces.terrain, dmin, dmax)
    if buildings is not None and (buildings.barriers or buildings.barriers_file):
        errors += _read_barriers(buildings, surfaces, base_dir, dmin, dmax, prefix, offset)
    if errors:
        raise SceneSpecError("\n".join(errors))
    surfaces.footprints = [fp for _, fp in labelled]
    return surfaces


def _read_barriers(
    buildings: BuildingsSpec,
    surfaces: SceneSurfaces,
    base_dir: str | Path | None,
    dmin: np.ndarray,
    dmax: np.ndarray,
    prefix: str,
    offset: tuple[float, float] | None,
) -> list[str]:
    """Inline and file barriers into ``surfaces.barriers``; the domain problems, each naming its field."""
    specs = list(buildings.barriers)
    labels = [f"{prefix}.buildings.barriers.{i}" + (f" ({b.name!r})" if b.name else "") for i, b in enumerate(specs)]
    if buildings.barriers_file is not None:
        field = f"{prefix}.buildings.barriers_file"
        try:
            read = read_barriers_geojson(_resolve(base_dir, buildings.barriers_file))
        except SceneFileError as exc:
            raise SceneFileError(f"{field}: {exc}") from None
        specs += read
        labels += [f"{field}: {b.name!r}" for b in read]
    terrain = surfaces.terrain

    def ground_z(xy: np.ndarray) -> np.ndarray:
        return terrain_height_at(terrain, xy) if terrain is not None else np.full(len(xy), float(dmin[2]))

    barriers, problems = barriers_from_specs(specs, labels, dmin, dmax, ground_z, offset)
    surfaces.barriers = barriers
    return problems


def surface_problems(surfaces: SceneSurfaces, domain_min, domain_max) -> list[str]:
    """The geometric checks of :func:`surfaces_from_specs` on a ready container (e.g. a built-in scene):
    one line per problem, footprints labelled by name; empty when everything fits the domain."""
    dmin = np.asarray(domain_min, dtype=np.float64)
    dmax = np.asarray(domain_max, dtype=np.float64)
    problems = (
        [f"terrain: {why}" for why in _terrain_problems(surfaces.terrain, dmin, dmax)] if surfaces.terrain else []
    )
    labelled = [(f"footprint {fp.name!r}", fp) for fp in surfaces.footprints]
    return problems + _footprint_problems(labelled, surfaces.terrain, dmin, dmax)


def _terrain_problems(grid: HeightGrid | TriangleSurface, dmin: np.ndarray, dmax: np.ndarray) -> list[str]:
    lo, hi = terrain_xy_bounds(grid)
    if np.any(lo > dmin[:2]) or np.any(hi < dmax[:2]):
        return [
            f"the terrain covers x {lo[0]:g}..{hi[0]:g}, y {lo[1]:g}..{hi[1]:g} m but the domain's xy box is "
            f"x {dmin[0]:g}..{dmax[0]:g}, y {dmin[1]:g}..{dmax[1]:g} m: the terrain must cover it"
        ]
    problems = []
    if isinstance(grid, TriangleSurface):
        u = np.linspace(dmin[0], dmax[0], COVERAGE_SAMPLES)
        v = np.linspace(dmin[1], dmax[1], COVERAGE_SAMPLES)
        probe = np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)
        gap = np.isnan(terrain_height_at(grid, probe))
        if np.any(gap):
            problems.append(
                f"the terrain mesh has a hole over the domain: no triangle above {_fmt(probe[np.argmax(gap)])} "
                f"({int(gap.sum())} of {gap.size} sample points uncovered)"
            )
        z = grid.vertices[:, 2]
    else:
        z = grid.z
    if z.max() >= dmax[2]:
        problems.append(f"the terrain reaches z = {z.max():g} m, not below the domain top (max z = {dmax[2]:g} m)")
    if z.min() < dmin[2]:
        problems.append(
            f"the terrain goes down to z = {z.min():g} m, below the domain bottom (min z = {dmin[2]:g} m): "
            "lower domain.min z"
        )
    return problems


def _footprint_problems(
    labelled: list[tuple[str, Footprint]],
    terrain: HeightGrid | TriangleSurface | None,
    dmin: np.ndarray,
    dmax: np.ndarray,
) -> list[str]:
    problems = []
    bases = footprint_bases(terrain, [fp for _, fp in labelled], dmin[2])
    for (label, fp), base in zip(labelled, bases, strict=True):
        outside = ~np.all((fp.polygon > dmin[:2]) & (fp.polygon < dmax[:2]), axis=1)
        if np.any(outside):
            problems.append(
                f"{label}: vertex {_fmt(fp.polygon[np.argmax(outside)])} is outside the domain's xy box "
                f"x {dmin[0]:g}..{dmax[0]:g}, y {dmin[1]:g}..{dmax[1]:g} m"
            )
            continue
        if fp.base_z is not None and fp.base_z < dmin[2]:
            problems.append(f"{label}: base_z = {fp.base_z:g} m is below the domain bottom (min z = {dmin[2]:g} m)")
        if base + fp.height_m >= dmax[2]:
            problems.append(
                f"{label}: the roof at z = {base + fp.height_m:g} m is not below the domain top (max z = {dmax[2]:g} m)"
            )
    if len(labelled) > 1 and not problems:
        for i, j in overlapping_pairs([footprint_polygon(fp) for _, fp in labelled]):
            problems.append(f"{labelled[i][0]} overlaps {labelled[j][0]}; footprints may touch but not overlap")
    return problems


def _solid_angle_sum(points: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Generalised winding number (N,) of closed triangle soups around points (Van Oosterom-Strackee)."""
    out = np.zeros(points.shape[0])
    chunk = max(1, 2_000_000 // max(tri.shape[0], 1))
    for s in range(0, points.shape[0], chunk):
        r = tri[None, :, :, :] - points[s : s + chunk, None, None, :]  # (n, F, 3, 3)
        length = np.linalg.norm(r, axis=3)
        a, b, c = r[:, :, 0], r[:, :, 1], r[:, :, 2]
        la, lb, lc = length[:, :, 0], length[:, :, 1], length[:, :, 2]
        num = np.einsum("nfd,nfd->nf", a, np.cross(b, c))
        den = (
            la * lb * lc
            + np.einsum("nfd,nfd->nf", a, b) * lc
            + np.einsum("nfd,nfd->nf", b, c) * la
            + np.einsum("nfd,nfd->nf", c, a) * lb
        )
        out[s : s + chunk] = (2.0 * np.arctan2(num, den)).sum(axis=1) / (4.0 * np.pi)
    return out


def check_points_above_ground(
    surfaces: SceneSurfaces,
    points: np.ndarray | Sequence[Sequence[float]],
    names: Sequence[str],
    *,
    flat_ground_z: float | None = None,
) -> None:
    """Raise SceneSpecError (one line per bad point) unless every point is strictly above the ground and
    outside every building and obstacle.

    points : (N, 3) metres, world frame; names : N job-field names (e.g. ``sources.0.position``).
    flat_ground_z : ground height when the scene has no terrain (domain min z); None skips that test
    (footprints without base_z then stand on z = 0).
    Ground: bilinear on a height grid, linear on terrain triangles. Buildings: the point's xy in the
    closed footprint and z at or below the roof (the base as in :func:`footprint_bases`).
    Obstacles: winding number above 1/2.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(names) != p.shape[0]:
        raise ValueError(f"{p.shape[0]} points but {len(names)} names")
    bad: dict[int, str] = {}
    if surfaces.terrain is not None:
        ground = terrain_height_at(surfaces.terrain, p[:, :2])
    else:
        ground = np.full(p.shape[0], np.nan if flat_ground_z is None else float(flat_ground_z))
    for k in range(p.shape[0]):
        if surfaces.terrain is not None and np.isnan(ground[k]):
            bad[k] = "is outside the terrain's xy extent"
        elif not np.isnan(ground[k]) and p[k, 2] <= ground[k]:
            depth = ground[k] - p[k, 2]
            where = "on the ground" if depth == 0 else f"{depth:.3g} m below the ground"
            bad[k] = f"is {where} (ground at z = {ground[k]:g} m)"
    flat_z = 0.0 if flat_ground_z is None else float(flat_ground_z)
    bases = footprint_bases(surfaces.terrain, surfaces.footprints, flat_z)
    for fp, base in zip(surfaces.footprints, bases, strict=True):
        lo, hi = fp.polygon.min(axis=0), fp.polygon.max(axis=0)
        near = np.flatnonzero(np.all((p[:, :2] >= lo) & (p[:, :2] <= hi), axis=1))
        if near.size == 0:
            continue
        tol = 1e-9 * max(float(np.ptp(fp.polygon, axis=0).max()), 1.0)
        inside = points_in_polygon(footprint_polygon(fp), p[near, :2], margin=-tol)
        roof = base + fp.height_m
        for k in near[inside & (p[near, 2] <= roof)]:
            bad.setdefault(int(k), f"is inside building {fp.name!r} (roof at z = {roof:g} m)")
    for i, (vertices, faces) in enumerate(surfaces.obstacles):
        winding = _solid_angle_sum(p, vertices[faces])
        for k in np.flatnonzero(winding > 0.5):
            bad.setdefault(int(k), f"is inside obstacle {i}")
    if bad:
        raise SceneSpecError("\n".join(f"{names[k]}: {_fmt(p[k])} {bad[k]}" for k in sorted(bad)))


def resolve_source_heights(job: Any, surfaces: SceneSurfaces | None) -> Any:
    """The job with every source given as ``position`` [x, y] + ``height_above_ground_m`` turned into an
    absolute [x, y, ground + h] (ground: the terrain, bilinear / linear in its triangles, or the flat ground
    at domain min z); other sources unchanged. Returns ``job`` itself when nothing needs resolving.
    Raises SceneSpecError naming ``sources.<i>.position`` when the terrain does not cover the point."""
    todo = [i for i, s in enumerate(job.sources) if len(s.position) == 2]
    if not todo:
        return job
    xy = np.array([job.sources[i].position for i in todo], dtype=np.float64)
    if surfaces is not None and surfaces.terrain is not None:
        ground = terrain_height_at(surfaces.terrain, xy)
    else:
        ground = np.full(len(todo), float(job.scene.box.min[2]))
    bad = [
        f"sources.{i}.position: {_fmt(xy[n])} is outside the terrain" for n, i in enumerate(todo) if np.isnan(ground[n])
    ]
    if bad:
        raise SceneSpecError("\n".join(bad))
    sources = list(job.sources)
    for n, i in enumerate(todo):
        z = float(ground[n]) + float(sources[i].height_above_ground_m)
        sources[i] = sources[i].model_copy(update={"position": (float(xy[n, 0]), float(xy[n, 1]), z)})
    return job.model_copy(update={"sources": sources})


def scene_surfaces(scene: Any, base_dir: str | Path | None) -> SceneSurfaces | None:
    """The surfaces of a job's ``scene`` (a validated ``Scene``): a built-in scene's own, or its terrain,
    buildings and ground zones read from the specs and files under ``base_dir`` (CRS inputs shifted to the
    local frame); None for flat ground only. The job's scene stage and the submit-time checks both use
    this, so they read the same files the same way."""
    if scene.builtin is not None:
        if not scene.has_surfaces:
            return None
        from bentray.scenes.library.registry import get_builtin

        return get_builtin(scene.builtin, scene.resolution).surfaces
    if scene.terrain is None and scene.buildings is None and scene.ground_zones is None:
        return None
    return surfaces_from_specs(
        scene.terrain,
        scene.buildings,
        scene.materials,
        base_dir,
        scene.box,
        prefix="scene",
        ground_zones=scene.ground_zones,
        offset=scene.local_origin if scene.crs is not None else None,
    )

"""Readers for scene input files: terrain (height grids and triangle meshes), closed obstacle meshes and
building footprints. Each returns the plain containers of :mod:`bentray.engine.surfaces`.

Every problem raises :class:`SceneFileError` whose message starts with the file name and says what is
wrong (with the line number for text formats). World frame, metres, z up; plan coordinates are the
scene's own metric x, y (GeoJSON files too: no geographic projection is applied).

Formats
- ESRI ASCII grid ``.asc``: header ``ncols``, ``nrows``, ``xllcorner`` | ``xllcenter``, ``yllcorner`` |
  ``yllcenter``, ``cellsize`` (or ``dx`` and ``dy``), optional ``NODATA_value``; then ``nrows`` lines of
  ``ncols`` heights, the first line the northernmost row. Each value is the height at its cell centre
  (``xllcorner + (j + 1/2) cellsize``; with ``xllcenter`` at ``xllcenter + j cellsize``). The returned
  grid has y increasing (rows reversed).
- ``.npy``: heights only, shape (ny, nx), row i at y = origin_y + i spacing_y (south to north); origin and
  spacing come from the job. ``.npz``: keys ``z``, ``origin`` (2,), ``spacing`` (2,), or ``x``, ``y``, ``z``.
- OBJ / STL / PLY through trimesh (``process=False``): bit-identical vertices are merged (STL stores each
  corner separately), then the checks of :mod:`bentray.scenes.mesh_checks` run.
- GeoJSON FeatureCollection of Polygon or MultiPolygon features (holes allowed) with a ``height`` property
  (m, 0 < h < 1000) or ``building:levels`` (x the storey height, default 3 m), optional ``base_z`` (m),
  ``material`` (a name from scene.materials) and ``name``. Validity is shapely's (the ``gis`` extra).
"""

from __future__ import annotations

import json
import re
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from bentray.engine.errors import JobInputError
from bentray.engine.surfaces import Footprint, HeightGrid, TriangleSurface
from bentray.scenes.geometry import CandidateLimitError
from bentray.scenes.gis_geometry import footprint_from_polygon, geometry_from_geojson
from bentray.scenes.mesh_checks import (
    basic_mesh_problem,
    closed_mesh_problem,
    height_field_problem,
    merge_duplicate_vertices,
    orient_ccw_from_above,
)

__all__ = [
    "MAX_FILE_BYTES",
    "MAX_TERRAIN_SAMPLES",
    "MAX_MESH_TRIANGLES",
    "MAX_FOOTPRINTS",
    "MAX_POLYGON_VERTICES",
    "MAX_BUILDING_HEIGHT_M",
    "DEFAULT_STOREY_HEIGHT_M",
    "TERRAIN_FORMATS",
    "MESH_FORMATS",
    "SceneFileError",
    "read_esri_ascii",
    "read_height_npy",
    "read_height_npz",
    "read_terrain_mesh",
    "read_obstacle_mesh",
    "read_footprints_geojson",
    "feature_height",
    "read_terrain",
]

# ---------------------------------------------------------------------------------------------
# Limits, each with the reason
# ---------------------------------------------------------------------------------------------
# Input files are read whole into memory; a 25M-sample ASCII grid at ~16 characters a value is 400 MB.
MAX_FILE_BYTES = 512 * 2**20
# 25M heights (a 5,000 x 5,000 grid) are 200 MB of float64; the mesh builder thins the grid to the media
# spacing anyway, so larger grids only cost memory and reading time.
MAX_TERRAIN_SAMPLES = 25_000_000
# The mesh checks (numpy, ~1 kB of temporaries per triangle) took 11 s for a 318k-triangle terrain and
# 6 s for a 328k-triangle closed mesh on the 2-core dev machine; 500k keeps a job's input check under
# about 20 s and 0.5 GB. The paper's largest scene has 16,000 surface triangles.
MAX_MESH_TRIANGLES = 500_000
# Footprint overlap checks are pairwise on candidate pairs; 10,000 buildings is a small town.
MAX_FOOTPRINTS = 10_000
MAX_POLYGON_VERTICES = 10_000
# The tallest building is 830 m; a footprint of 1 km or more is a unit mistake (mm, feet x 1000).
MAX_BUILDING_HEIGHT_M = 1000.0
# Storey height for ``building:levels`` (OpenStreetMap): 3 m, the usual floor-to-floor height of housing
# and offices (the value noise-mapping guidance uses when only the number of storeys is known).
DEFAULT_STOREY_HEIGHT_M = 3.0

TERRAIN_FORMATS = ("asc", "npy", "npz", "obj", "stl", "ply")
MESH_FORMATS = ("obj", "stl", "ply")


class SceneFileError(JobInputError):
    """A scene input file is missing, unreadable, too large or geometrically invalid."""


def _fail(path: Path | str, message: str) -> SceneFileError:
    return SceneFileError(f"{path}: {message}")


def _check_size(path: Path) -> None:
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise _fail(path, "file not found") from None
    except OSError as exc:
        raise _fail(path, f"cannot read: {exc.strerror or exc}") from None
    if not path.is_file():
        raise _fail(path, "not a regular file")
    if size > MAX_FILE_BYTES:
        raise _fail(path, f"file is {size / 2**20:.0f} MiB; the limit is {MAX_FILE_BYTES // 2**20} MiB")


def _check_samples(path: Path, ny: int, nx: int) -> None:
    if nx < 2 or ny < 2:
        raise _fail(path, f"a height grid needs at least 2 x 2 samples, got {ny} rows x {nx} columns")
    if nx * ny > MAX_TERRAIN_SAMPLES:
        raise _fail(
            path,
            f"{ny} x {nx} = {nx * ny:,} height samples; the limit is {MAX_TERRAIN_SAMPLES:,} "
            "(resample the grid: the mesh follows the media spacing, not the raw samples)",
        )


def _check_heights(path: Path, z: np.ndarray, where: Callable[[int, int], str]) -> None:
    """NaN or infinite heights -> error naming the count and the first location (``where(i, j)``)."""
    bad = ~np.isfinite(z)
    if np.any(bad):
        i, j = np.argwhere(bad)[0]
        raise _fail(path, f"{int(bad.sum())} heights are missing (NaN, infinite or NODATA); the first at {where(i, j)}")


# ---------------------------------------------------------------------------------------------
# Height grids
# ---------------------------------------------------------------------------------------------
_ASC_KEYS = {
    "ncols",
    "nrows",
    "xllcorner",
    "xllcenter",
    "yllcorner",
    "yllcenter",
    "cellsize",
    "dx",
    "dy",
    "nodata_value",
}
_NUMBER_START = re.compile(r"^[-+.0-9]|^(nan|inf)", re.IGNORECASE)


def read_esri_ascii(path: str | Path) -> HeightGrid:
    """ESRI ASCII grid -> HeightGrid with y increasing (the file's first data line is the northern row)."""
    path = Path(path)
    _check_size(path)
    try:
        text = path.read_text(encoding="ascii")
    except UnicodeDecodeError as exc:
        raise _fail(path, f"not an ASCII text file (byte {exc.start})") from None
    lines = text.splitlines()
    header: dict[str, float] = {}
    n = 0
    while n < len(lines):
        tokens = lines[n].split()
        if not tokens:
            n += 1
            continue
        if _NUMBER_START.match(tokens[0]):
            break
        key = tokens[0].lower()
        if key not in _ASC_KEYS:
            raise _fail(
                path,
                f"line {n + 1}: unknown header key {tokens[0]!r} (expected one of ncols, nrows, "
                "xllcorner, xllcenter, yllcorner, yllcenter, cellsize, dx, dy, NODATA_value)",
            )
        if len(tokens) != 2:
            raise _fail(path, f"line {n + 1}: expected '{tokens[0]} <number>'")
        if key in header:
            raise _fail(path, f"line {n + 1}: duplicate header key {tokens[0]!r}")
        try:
            header[key] = float(tokens[1])
        except ValueError:
            raise _fail(path, f"line {n + 1}: {tokens[0]} value {tokens[1]!r} is not a number") from None
        n += 1
    for key in ("ncols", "nrows"):
        if key not in header:
            raise _fail(path, f"header lacks {key}")
        if not header[key].is_integer() or header[key] < 1:
            raise _fail(path, f"{key} must be a positive integer, got {header[key]:g}")
    nx, ny = int(header["ncols"]), int(header["nrows"])
    origin: list[float] = []
    for axis in ("x", "y"):
        corner, center = f"{axis}llcorner", f"{axis}llcenter"
        if (corner in header) == (center in header):
            raise _fail(path, f"header needs exactly one of {corner} and {center}")
        origin.append(header[corner] if corner in header else header[center])
    if "cellsize" in header:
        if "dx" in header or "dy" in header:
            raise _fail(path, "header gives both cellsize and dx/dy")
        dx = dy = header["cellsize"]
    elif "dx" in header and "dy" in header:
        dx, dy = header["dx"], header["dy"]
    else:
        raise _fail(path, "header lacks cellsize (or dx and dy)")
    if not (np.isfinite(dx) and np.isfinite(dy) and dx > 0 and dy > 0):
        raise _fail(path, f"cell size must be a positive number, got {dx:g} x {dy:g}")
    if not all(np.isfinite(origin)):
        raise _fail(path, "lower-left coordinates must be finite numbers")
    _check_samples(path, ny, nx)
    nodata = header.get("nodata_value")
    z = np.empty((ny, nx), dtype=np.float64)
    row_line = np.zeros(ny, dtype=np.int64)  # 1-based file line of each data row
    row = 0
    for k in range(n, len(lines)):
        tokens = lines[k].split()
        if not tokens:
            continue
        if row == ny:
            raise _fail(path, f"line {k + 1}: more data rows than nrows = {ny}")
        if len(tokens) != nx:
            raise _fail(path, f"line {k + 1}: data row {row + 1} has {len(tokens)} values; ncols is {nx}")
        try:
            z[row] = np.array(tokens, dtype=np.float64)
        except ValueError:
            bad = next(k for k, t in enumerate(tokens) if not _is_float(t))
            raise _fail(path, f"line {k + 1}, value {bad + 1}: {tokens[bad]!r} is not a number") from None
        row_line[row] = k + 1
        row += 1
    if row < ny:
        raise _fail(path, f"only {row} data rows; nrows is {ny}")
    if nodata is not None:
        z[z == nodata] = np.nan
    x0 = origin[0] + (0.5 * dx if "xllcorner" in header else 0.0)
    y0 = origin[1] + (0.5 * dy if "yllcorner" in header else 0.0)
    x = x0 + dx * np.arange(nx, dtype=np.float64)
    y = y0 + dy * np.arange(ny, dtype=np.float64)

    def where(i: int, j: int) -> str:
        return f"line {row_line[i]}, column {j + 1} (x={x[j]:g}, y={y[ny - 1 - i]:g})"

    _check_heights(path, z, where)
    return HeightGrid(x=x, y=y, z=np.ascontiguousarray(z[::-1]))


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _grid_from_origin(path: Path, z: np.ndarray, origin_xy: ArrayLike, spacing_xy: ArrayLike) -> HeightGrid:
    origin = np.asarray(origin_xy, dtype=np.float64).reshape(-1)
    spacing = np.asarray(spacing_xy, dtype=np.float64).reshape(-1)
    if origin.shape != (2,) or not np.all(np.isfinite(origin)):
        raise _fail(path, f"origin must be 2 finite numbers (x, y), got {origin.tolist()}")
    if spacing.shape != (2,) or not np.all(np.isfinite(spacing)) or np.any(spacing <= 0):
        raise _fail(path, f"spacing must be 2 positive numbers (dx, dy), got {spacing.tolist()}")
    ny, nx = z.shape
    x = origin[0] + spacing[0] * np.arange(nx, dtype=np.float64)
    y = origin[1] + spacing[1] * np.arange(ny, dtype=np.float64)
    return HeightGrid(x=x, y=y, z=z)


def _height_array(path: Path, z: Any, name: str) -> np.ndarray:
    if not isinstance(z, np.ndarray) or z.dtype.kind not in "iuf":
        kind = getattr(z, "dtype", type(z).__name__)
        raise _fail(path, f"{name} must be a numeric array, got {kind}")
    if z.ndim != 2:
        raise _fail(path, f"{name} must be a 2D array (ny, nx), got shape {z.shape}")
    _check_samples(path, *z.shape)
    heights: np.ndarray = np.array(z, dtype=np.float64)
    _check_heights(path, heights, lambda i, j: f"{name}[{i}, {j}]")
    return heights


def read_height_npy(path: str | Path, origin: ArrayLike, spacing: ArrayLike) -> HeightGrid:
    """``.npy`` heights (ny, nx), row i at y = origin[1] + i spacing[1]; origin, spacing (2,) metres."""
    path = Path(path)
    _check_size(path)
    try:
        z = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise _fail(path, f"not a readable .npy array ({exc})") from None
    return _grid_from_origin(path, _height_array(path, z, "the array"), origin, spacing)


def _npz_member_shape(archive: Any, key: str) -> tuple[int, ...]:
    """Shape of one array of an open .npz, read from its .npy header without inflating the data."""
    with archive.zip.open(f"{key}.npy") as member:
        version = np.lib.format.read_magic(member)
        if version == (1, 0):
            shape, _, _ = np.lib.format.read_array_header_1_0(member)
        else:
            shape, _, _ = np.lib.format.read_array_header_2_0(member)
    return tuple(int(n) for n in shape)


def read_height_npz(path: str | Path) -> HeightGrid:
    """``.npz`` with ``z`` (ny, nx) and either ``origin``/``spacing`` (2,) or ``x`` (nx,) / ``y`` (ny,)."""
    path = Path(path)
    _check_size(path)
    try:
        archive = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise _fail(path, f"not a readable .npz archive ({exc})") from None
    with archive:
        keys = set(archive.files)
        allowed = [{"z", "origin", "spacing"}, {"x", "y", "z"}]
        if keys not in allowed:
            raise _fail(path, f"expected keys z, origin, spacing or x, y, z; found {', '.join(sorted(keys)) or 'none'}")
        try:
            for key in keys:  # sizes from the headers first: a compressed archive can inflate enormously
                shape = _npz_member_shape(archive, key)
                if int(np.prod(shape)) > MAX_TERRAIN_SAMPLES:
                    raise _fail(path, f"{key} has shape {shape}: more than {MAX_TERRAIN_SAMPLES:,} values")
            arrays = {k: archive[k] for k in keys}
        except (ValueError, OSError, KeyError) as exc:
            if isinstance(exc, SceneFileError):
                raise
            raise _fail(path, f"cannot read arrays ({exc})") from None
    z = _height_array(path, arrays["z"], "z")
    if "origin" in keys:
        return _grid_from_origin(path, z, arrays["origin"], arrays["spacing"])
    ny, nx = z.shape
    axes = {}
    for name, n in (("x", nx), ("y", ny)):
        a = np.asarray(arrays[name], dtype=np.float64)
        if a.shape != (n,):
            raise _fail(path, f"{name} must have shape ({n},) to match z of shape {z.shape}, got {a.shape}")
        if not np.all(np.isfinite(a)) or np.any(np.diff(a) <= 0):
            raise _fail(path, f"{name} must be finite and strictly increasing")
        axes[name] = a
    return HeightGrid(x=axes["x"], y=axes["y"], z=z)


# ---------------------------------------------------------------------------------------------
# Triangle meshes
# ---------------------------------------------------------------------------------------------
def _load_mesh(path: Path, file_format: str | None) -> tuple[np.ndarray, np.ndarray]:
    _check_size(path)
    fmt = (file_format or path.suffix.lstrip(".")).lower()
    if fmt not in MESH_FORMATS:
        raise _fail(path, f"unsupported mesh format {fmt!r}; use one of {', '.join(MESH_FORMATS)}")
    try:
        import trimesh
    except ImportError:
        raise _fail(path, "reading OBJ/STL/PLY needs trimesh: pip install 'bentray[scenes]'") from None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # trimesh warns on odd but readable files; we check ourselves
            mesh = trimesh.load_mesh(str(path), file_type=fmt, process=False)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise _fail(path, f"cannot read as {fmt.upper()}: {exc}") from None
    vertices = np.array(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.array(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    if faces.size == 0:
        raise _fail(path, f"no triangles found (is this a valid {fmt.upper()} file?)")
    if faces.shape[0] > MAX_MESH_TRIANGLES:
        raise _fail(path, f"{faces.shape[0]:,} triangles; the limit is {MAX_MESH_TRIANGLES:,}")
    problem = basic_mesh_problem(vertices, faces)
    if problem:
        raise _fail(path, problem)
    return merge_duplicate_vertices(vertices, faces)


def read_terrain_mesh(path: str | Path, file_format: str | None = None) -> TriangleSurface:
    """OBJ/STL/PLY terrain -> TriangleSurface (triangles re-ordered counter-clockwise from above).
    The mesh must be a height field (see :func:`bentray.scenes.mesh_checks.height_field_problem`)."""
    path = Path(path)
    vertices, faces = _load_mesh(path, file_format)
    problem = basic_mesh_problem(vertices, faces)  # merging can collapse a triangle
    if problem is None:
        try:
            problem = height_field_problem(vertices, faces)
        except CandidateLimitError as exc:
            problem = f"too many overlapping triangles to check: {exc}"
    if problem:
        raise _fail(path, f"terrain mesh: {problem}")
    return TriangleSurface(vertices=vertices, triangles=orient_ccw_from_above(vertices, faces))


def read_obstacle_mesh(path: str | Path, file_format: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """OBJ/STL/PLY closed obstacle -> (vertices (V, 3) float64, faces (F, 3) int64), outward normals.
    Checks: watertight, edge-manifold, consistently oriented, positive volume per shell, no face pair
    without a shared vertex intersecting (see :mod:`bentray.scenes.mesh_checks`)."""
    path = Path(path)
    vertices, faces = _load_mesh(path, file_format)
    problem = basic_mesh_problem(vertices, faces)
    if problem is None:
        try:
            problem = closed_mesh_problem(vertices, faces)
        except CandidateLimitError as exc:
            problem = f"too many overlapping triangles to check: {exc}"
    if problem:
        raise _fail(path, f"obstacle mesh: {problem}")
    return vertices, faces


# ---------------------------------------------------------------------------------------------
# GeoJSON footprints
# ---------------------------------------------------------------------------------------------
def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not allowed (non-finite number)")


def _number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and bool(np.isfinite(value))


def read_footprints_geojson(
    path: str | Path, materials: Mapping[str, int] | None = None, storey_height_m: float = DEFAULT_STOREY_HEIGHT_M
) -> list[Footprint]:
    """GeoJSON FeatureCollection of Polygon / MultiPolygon features -> Footprints.

    materials : material name -> index in SceneSurfaces.materials (default {"rigid": 0}); a feature's
    ``material`` must be one of them. Height: the ``height`` property (metres, a number or a numeric string
    such as OpenStreetMap's ``"12"`` / ``"12 m"``) or else ``building:levels`` x ``storey_height_m``.
    Polygons may have holes (courtyards); a MultiPolygon becomes one Footprint per part, named
    ``name part k``. Conversions (not checks): closing and consecutive duplicate vertices dropped, exterior
    counter-clockwise and holes clockwise, a third coordinate ignored. Validity is shapely's
    (``features.7: Self-intersection at (x, y)``).
    """
    path = Path(path)
    _check_size(path)
    materials = dict(materials) if materials is not None else {"rigid": 0}
    try:
        data = json.loads(path.read_text(encoding="utf-8"), parse_constant=_reject_constant)
    except UnicodeDecodeError as exc:
        raise _fail(path, f"not UTF-8 text (byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise _fail(path, f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    except ValueError as exc:
        raise _fail(path, f"invalid JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("type") != "FeatureCollection":
        raise _fail(path, 'expected a GeoJSON object with "type": "FeatureCollection"')
    features = data.get("features")
    if not isinstance(features, list):
        raise _fail(path, '"features" must be a list')
    if len(features) > MAX_FOOTPRINTS:
        raise _fail(path, f"{len(features):,} features; the limit is {MAX_FOOTPRINTS:,}")
    out: list[Footprint] = []
    for i, feature in enumerate(features):
        out += _footprints(path, i, feature, materials, storey_height_m)
    return out


_HEIGHT_TEXT = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?|\.[0-9]+)\s*(?:m)?\s*$")


def feature_height(props: Mapping[str, Any], storey_height_m: float) -> tuple[float | None, str | None]:
    """Building height in metres from GeoJSON properties: ``height`` (number or numeric string, metres) or
    ``building:levels`` x storey_height_m. Returns (height, None) or (None, reason)."""
    height = props.get("height")
    if height is not None:
        if isinstance(height, str) and _HEIGHT_TEXT.match(height):
            height = float(_HEIGHT_TEXT.match(height)[1])  # type: ignore[index]
        if not _number(height):
            return None, f'property "height" must be a number (metres), got {height!r}'
        value = float(height)
    else:
        levels = props.get("building:levels")
        if isinstance(levels, str) and _HEIGHT_TEXT.match(levels):
            levels = float(_HEIGHT_TEXT.match(levels)[1])  # type: ignore[index]
        if levels is None:
            return None, 'give a "height" property (metres) or "building:levels"'
        if not _number(levels) or levels <= 0:
            return None, f'property "building:levels" must be a positive number, got {levels!r}'
        value = float(levels) * storey_height_m
    if not 0.0 < value < MAX_BUILDING_HEIGHT_M:
        return None, f"height {value:g} m must be > 0 and < {MAX_BUILDING_HEIGHT_M:g} m"
    return value, None


def _footprints(path: Path, i: int, feature: Any, materials: dict[str, int], storey_height_m: float) -> list[Footprint]:
    label = f"features.{i}"
    if not isinstance(feature, dict) or feature.get("type") != "Feature":
        raise _fail(path, f'{label}: expected an object with "type": "Feature"')
    props: Any = feature.get("properties") or {}
    if not isinstance(props, dict):
        raise _fail(path, f'{label}: "properties" must be an object')
    name = props.get("name")
    if name is not None:
        label += f" ({name!r})"
    geometry = feature.get("geometry")
    if _vertex_count(geometry) > MAX_POLYGON_VERTICES:
        raise _fail(path, f"{label}: more than {MAX_POLYGON_VERTICES:,} vertices")
    polys, problem = geometry_from_geojson(geometry)
    if problem:
        raise _fail(path, f"{label}: {problem}")
    assert polys is not None
    height, problem = feature_height(props, storey_height_m)
    if problem:
        raise _fail(path, f"{label}: {problem}")
    assert height is not None
    base_z: Any = props.get("base_z")
    if base_z is not None and not _number(base_z):
        raise _fail(path, f'{label}: property "base_z" must be a number (metres) or null, got {base_z!r}')
    material = props.get("material", "rigid")
    if material not in materials:
        raise _fail(
            path, f"{label}: material {material!r} is not defined in scene.materials (defined: {', '.join(materials)})"
        )
    base = str(name) if name is not None else f"feature {i}"
    return [
        footprint_from_polygon(
            poly,
            height_m=height,
            base_z=None if base_z is None else float(base_z),
            material=int(materials[material]),
            name=base if len(polys) == 1 else f"{base} part {k}",
        )
        for k, poly in enumerate(polys)
    ]


def _vertex_count(geometry: Any) -> int:
    """Positions in a Polygon / MultiPolygon geometry object (0 when malformed; for the limit only)."""
    if not isinstance(geometry, dict) or not isinstance(geometry.get("coordinates"), list):
        return 0
    parts = geometry["coordinates"] if geometry.get("type") == "MultiPolygon" else [geometry["coordinates"]]
    return sum(len(ring) for part in parts if isinstance(part, list) for ring in part if isinstance(ring, list))


# ---------------------------------------------------------------------------------------------
# Dispatch
# ---------------------------------------------------------------------------------------------
def read_terrain(
    path: str | Path, file_format: str | None = None, origin: ArrayLike | None = None, spacing: ArrayLike | None = None
) -> HeightGrid | TriangleSurface:
    """Read a terrain file by format (default: the file suffix): asc, npy (needs origin and spacing), npz,
    obj, stl, ply."""
    path = Path(path)
    fmt = (file_format or path.suffix.lstrip(".")).lower()
    if fmt not in TERRAIN_FORMATS:
        raise _fail(path, f"unknown terrain format {fmt!r}; use one of {', '.join(TERRAIN_FORMATS)}")
    if fmt == "npy":
        if origin is None or spacing is None:
            raise _fail(path, "a .npy terrain holds heights only: origin and spacing must be given")
        return read_height_npy(path, origin, spacing)
    if origin is not None or spacing is not None:
        raise _fail(path, f"origin and spacing are only for .npy terrain; a .{fmt} file carries its own")
    if fmt == "asc":
        return read_esri_ascii(path)
    if fmt == "npz":
        return read_height_npz(path)
    return read_terrain_mesh(path, fmt)

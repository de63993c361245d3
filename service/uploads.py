"""Checks of uploaded scene files (terrain, buildings GeoJSON, obstacle meshes, grid profiles).

An upload is read with the same reader the engine uses, so a file that passes here is one the job
can load; a file that does not is refused at upload time (HTTP 422) with the reader's reason.
The kind of a file is given (``terrain``, ``buildings``, ``ground_zones``, ``obstacle``, ``grid``) or
follows from its suffix; a triangle mesh of unknown role (``mesh``) must read as an obstacle or as a
terrain. A GeoJSON file is ``buildings`` by default: ground zones (``scene.ground_zones.file``, polygons
with ``G``, ``flow_resistivity`` or ``material``) are uploaded as an asset with ``kind=ground_zones``, or
with the job, where the field naming the file gives the kind.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

import numpy as np

from bentray.engine.errors import BentrayError

__all__ = ["UPLOAD_KINDS", "UploadKind", "check_upload", "default_kind"]

UploadKind = Literal["terrain", "buildings", "ground_zones", "obstacle", "grid", "mesh"]
UPLOAD_KINDS: tuple[str, ...] = ("terrain", "buildings", "ground_zones", "obstacle", "grid", "mesh")
_KIND_SUFFIXES: dict[str, tuple[str, ...]] = {
    "terrain": ("asc", "npy", "npz", "obj", "stl", "ply"),
    "buildings": ("geojson", "json"),
    "ground_zones": ("geojson", "json"),
    "obstacle": ("obj", "stl", "ply"),
    "grid": ("npz", "vti"),
    "mesh": ("obj", "stl", "ply"),
}


def default_kind(name: str) -> UploadKind | None:
    """The kind a suffix implies (``.npz`` is a terrain unless it holds ``c``: see :func:`check_upload`)."""
    suffix = Path(name).suffix.lstrip(".").lower()
    if suffix in ("asc", "npy", "npz"):
        return "terrain"
    if suffix in ("geojson", "json"):
        return "buildings"
    if suffix in ("obj", "stl", "ply"):
        return "mesh"
    if suffix == "vti":
        return "grid"
    return None


def _npz_keys(path: Path) -> set[str]:
    try:
        with np.load(path, allow_pickle=False) as archive:
            return set(archive.files)
    except (ValueError, OSError) as exc:
        raise ValueError(f"not a readable .npz archive ({exc})") from None


def _check_grid(path: Path) -> None:
    if path.suffix.lower() == ".npz":
        keys = _npz_keys(path)
        if not {"c", "origin", "spacing"} <= keys:
            raise ValueError(f"a grid profile .npz needs arrays c, origin, spacing; found {', '.join(sorted(keys))}")
        with np.load(path, allow_pickle=False) as archive:
            c = archive["c"]
            if c.ndim != 3 or min(c.shape) < 2:
                raise ValueError(f"c must be a 3D array with at least 2 points per axis, got shape {c.shape}")
        return
    import pyvista as pv

    try:
        grid = pv.read(str(path))
    except Exception as exc:  # VTK raises many types for malformed files
        raise ValueError(f"cannot read as VTK image data: {exc}") from None
    if "c" not in grid.point_data:
        raise ValueError("a grid profile .vti needs a point array named 'c'")


def _check_geojson(path: Path) -> None:
    from bentray.scenes.terrain_io import read_footprints_geojson

    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        features = data.get("features", []) if isinstance(data, dict) else []
        names = {
            f.get("properties", {}).get("material")
            for f in features
            if isinstance(f, dict) and isinstance(f.get("properties"), dict)
        }
    except (ValueError, UnicodeDecodeError):
        names = set()
    materials = {"rigid": 0} | {n: i + 1 for i, n in enumerate(sorted(n for n in names if isinstance(n, str)))}
    read_footprints_geojson(path, materials)


class _AnyMaterial(dict[str, int]):
    """Every material name is known (index 0): the upload does not know the job's ``scene.materials``."""

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str)

    def __missing__(self, key: str) -> int:
        return 0


def _check_ground_zones(path: Path) -> None:
    """Read as the engine reads ``scene.ground_zones.file`` (shapely validity, one of G, flow_resistivity
    or material per feature); material names are checked against the job's materials when it runs."""
    from bentray.scenes.ground_zones import ZoneMaterial, read_ground_zones_geojson

    table = ZoneMaterial({}, 1)
    table.names = _AnyMaterial()
    read_ground_zones_geojson(path, table)


def check_upload(path: Path, kind: UploadKind) -> str:
    """Read ``path`` as a file of ``kind``; return the kind it was accepted as.

    Raises ValueError with the reason (what is wrong with the file, without its server-side path).
    """
    from bentray.scenes.terrain_io import read_obstacle_mesh, read_terrain

    suffix = path.suffix.lstrip(".").lower()
    if suffix not in _KIND_SUFFIXES[kind]:
        raise ValueError(
            f"a {kind} file must end in one of {', '.join('.' + s for s in _KIND_SUFFIXES[kind])}, got {path.name!r}"
        )
    try:
        if kind == "terrain" and suffix == "npz" and "c" in _npz_keys(path):
            kind = "grid"
        if kind == "terrain":
            if suffix == "npy":  # heights only: origin and spacing come with the job
                try:
                    z = np.load(path, mmap_mode="r", allow_pickle=False)
                except (ValueError, OSError) as exc:
                    raise ValueError(f"not a readable .npy array ({exc})") from None
                if z.ndim != 2 or min(z.shape) < 2:
                    raise ValueError(f"terrain heights must be a 2D array of at least 2 x 2, got shape {z.shape}")
            else:
                read_terrain(path)
        elif kind == "buildings":
            _check_geojson(path)
        elif kind == "ground_zones":
            _check_ground_zones(path)
        elif kind == "obstacle":
            read_obstacle_mesh(path)
        elif kind == "grid":
            _check_grid(path)
        else:  # a mesh: an obstacle or a terrain
            try:
                read_obstacle_mesh(path)
                return "obstacle"
            except BentrayError as obstacle_error:
                try:
                    read_terrain(path)
                    return "terrain"
                except BentrayError as terrain_error:
                    first, second = _strip(obstacle_error, path), _strip(terrain_error, path)
                    raise ValueError(first if first == second else f"{first}; as a terrain: {second}") from None
    except BentrayError as exc:
        raise ValueError(_strip(exc, path)) from None
    return kind


def _strip(exc: Exception, path: Path) -> str:
    """The reader's message without the server-side folder (readers prefix messages with the path)."""
    text = " ".join(str(exc).split())
    for prefix in (f"{path}: ", f"{path}:", str(path)):
        if text.startswith(prefix):
            return text[len(prefix) :].strip()
    return text.replace(str(path.parent) + "/", "")

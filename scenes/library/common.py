"""What every built-in scene shares: the :class:`BuiltinScene` record, surface-triangle counting, a
rounding-stable digest of the generated geometry, and small generators (height grids, profiles).

Built-in scenes are generated, not stored: each module under ``scenes/library/`` builds its surfaces
from a fixed seed with ``numpy.random.default_rng(seed).random`` (uniform draws only, whose stream
numpy keeps stable) and closed-form shapes, so anyone can rebuild them bit for bit.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from bentray.engine.surfaces import Footprint, HeightGrid, SceneSurfaces
from bentray.scenes.geometry import terrain_height_at

__all__ = [
    "RESOLUTIONS",
    "Resolution",
    "BuiltinScene",
    "check_resolution",
    "footprint_triangles",
    "surface_stats",
    "surfaces_digest",
    "height_grid",
    "sources_above_ground",
    "standard_atmosphere_profile",
    "log_profile",
    "fluctuating_profile",
    "Rng",
]

Resolution = Literal["medium", "high"]
RESOLUTIONS: tuple[str, ...] = ("medium", "high")


class Rng:
    """Seeded uniform draws (only ``Generator.random``, the stream numpy keeps stable across versions)."""

    def __init__(self, seed: int) -> None:
        self._gen = np.random.default_rng(seed)

    def uniform(self, low: float, high: float, size: int | tuple[int, ...] | None = None) -> Any:
        return low + (high - low) * self._gen.random(size)


@dataclass
class BuiltinScene:
    """A generated scene ready for a job.

    name, description : for ``bentray scenes`` and reports; resolution : 'medium' or 'high'.
    domain_min, domain_max : (3,) metres, world frame, z up (terrain inside [min z, max z)).
    surfaces : terrain, footprints and materials (material 0 rigid).
    sources : (S, 3) float64 default source positions in metres, above ground and outside buildings.
    profile : a ProfileSpec-compatible dict (``scenes/profile_models.py``).
    wind : suggested ``wind`` job key for scenes defined with wind (A-UW/A-DW), else None.
    stats : surface triangle counts, buildings, grid shape, height range, seed.
    """

    name: str
    description: str
    resolution: str
    domain_min: tuple[float, float, float]
    domain_max: tuple[float, float, float]
    surfaces: SceneSurfaces
    sources: np.ndarray
    profile: dict[str, Any]
    wind: dict[str, Any] | None = None
    stats: dict[str, Any] = field(default_factory=dict)


def check_resolution(resolution: str) -> Resolution:
    if resolution not in RESOLUTIONS:
        raise ValueError(f"resolution must be one of {', '.join(RESOLUTIONS)}, got {resolution!r}")
    return resolution  # type: ignore[return-value]


def footprint_triangles(fp: Footprint) -> int:
    """Nominal surface triangles of a prism: two per wall (one quad per polygon edge) plus k - 2 for the roof."""
    k = int(fp.polygon.shape[0])
    return 2 * k + (k - 2)


def surface_stats(surfaces: SceneSurfaces, seed: int | None) -> dict[str, Any]:
    """Counts for ``bentray scenes`` and the README table. Terrain triangles: two per grid square (flat
    ground: the domain bottom's two); building triangles: :func:`footprint_triangles`. These are the
    input surfaces, before the conforming mesh re-triangulates the ground around the footprints."""
    terrain = surfaces.terrain
    if terrain is None:
        n_terrain, shape, z_range = 2, None, None
    elif isinstance(terrain, HeightGrid):
        n_terrain = 2 * (terrain.x.size - 1) * (terrain.y.size - 1)
        shape = [int(terrain.y.size), int(terrain.x.size)]
        z_range = [float(terrain.z.min()), float(terrain.z.max())]
    else:
        n_terrain, shape = int(terrain.triangles.shape[0]), None
        z_range = [float(terrain.vertices[:, 2].min()), float(terrain.vertices[:, 2].max())]
    n_buildings = sum(footprint_triangles(fp) for fp in surfaces.footprints)
    return {
        "surface_triangles": n_terrain + n_buildings,
        "terrain_triangles": n_terrain,
        "building_triangles": n_buildings,
        "buildings": len(surfaces.footprints),
        "grid_shape": shape,
        "terrain_z_range_m": z_range,
        "materials": [m.name for m in surfaces.materials],
        "seed": seed,
    }


def _micrometres(a: Any) -> bytes:
    """Integer micrometres, little-endian: insensitive to last-ulp differences between math libraries
    (a value would have to sit within 1e-15 m of a rounding boundary to flip)."""
    return np.rint(np.asarray(a, dtype=np.float64) * 1e6).astype("<i8").tobytes()


def surfaces_digest(surfaces: SceneSurfaces, sources: np.ndarray) -> str:
    """SHA-256 (hex, first 16 characters) of the generated geometry rounded to micrometres: terrain axes,
    heights and materials, every footprint (polygon, height, base, material) and the sources."""
    h = hashlib.sha256()
    t = surfaces.terrain
    if isinstance(t, HeightGrid):
        for a in (t.x, t.y, t.z):
            h.update(_micrometres(a))
        if t.material is not None:
            h.update(np.asarray(t.material, dtype="<i8").tobytes())
        h.update(str(t.default_material).encode())
    elif t is not None:
        h.update(_micrometres(t.vertices))
        h.update(np.asarray(t.triangles, dtype="<i8").tobytes())
    for fp in surfaces.footprints:
        h.update(_micrometres(fp.polygon))
        h.update(_micrometres([fp.height_m]))
        h.update(b"base:lowest" if fp.base_z is None else _micrometres([fp.base_z]))
        h.update(f"{fp.material}:{fp.name}".encode())
    for m in surfaces.materials:
        h.update(f"{m.name}:{m.flow_resistivity}".encode())
    h.update(_micrometres(sources))
    return h.hexdigest()[:16]


def height_grid(
    x_range: tuple[float, float],
    y_range: tuple[float, float],
    n_squares: tuple[int, int],
    height: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> HeightGrid:
    """Regular HeightGrid with (nx, ny) squares over the ranges; ``height(X, Y)`` on (ny+1, nx+1) meshgrids."""
    x = np.linspace(x_range[0], x_range[1], n_squares[0] + 1)
    y = np.linspace(y_range[0], y_range[1], n_squares[1] + 1)
    xx, yy = np.meshgrid(x, y)
    return HeightGrid(x=x, y=y, z=np.ascontiguousarray(height(xx, yy), dtype=np.float64))


def sources_above_ground(surfaces: SceneSurfaces, xy_height: list[tuple[float, float, float]]) -> np.ndarray:
    """(S, 3) source positions: (x, y) with z = terrain height there + the given height above ground."""
    xy = np.array([(x, y) for x, y, _ in xy_height], dtype=np.float64)
    above = np.array([h for _, _, h in xy_height], dtype=np.float64)
    ground = terrain_height_at(surfaces.terrain, xy) if surfaces.terrain is not None else np.zeros(len(xy))
    return np.column_stack([xy, ground + above])


def standard_atmosphere_profile(top_z: float) -> dict[str, Any]:
    """1976 US Standard Atmosphere troposphere, T = 288.15 K - 0.0065 K/m z, as a linear ``table`` profile
    from z = 0 to top_z (exact: the table is linear in z)."""
    return {
        "kind": "table",
        "z": [0.0, float(top_z)],
        "temperature_k": [288.15, 288.15 - 0.0065 * float(top_z)],
        "interpolation": "linear",
    }


def log_profile(b: float) -> dict[str, Any]:
    """A-LD (b = +1, night) or A-LU (b = -1, day): c = 340 + b ln(z / 1 m + 1), z absolute."""
    return {"kind": "log", "c0": 340.0, "b": float(b), "z_g": 1.0}


def fluctuating_profile(b: float, seed: int) -> dict[str, Any]:
    """A-LU+F / A-LD+F: the log profile plus 0.5 m/s RMS Gaussian-spectrum fluctuations (64 modes)."""
    return {"kind": "fluctuating", "base": log_profile(b), "rms": 0.5, "n_modes": 64, "seed": int(seed)}

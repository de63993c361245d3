"""Shading of camera rays (plain numpy): surfaces by height and material with a sun direction, the sky by the
ray's final direction. Colours are linear RGB in [0, 1]; no physics here beyond Lambert's cosine law."""

from __future__ import annotations

import numpy as np

from bentray.engine.surfaces import HeightGrid, SceneSurfaces

__all__ = ["LOST_RGB", "shade_sky", "shade_surface", "surface_materials", "surface_normals"]

LOST_RGB = np.array([1.0, 0.0, 1.0])  # rays that were lost or ran out of steps: magenta, counted in the stats
_HORIZON = np.array([0.86, 0.90, 0.96])
_ZENITH = np.array([0.22, 0.42, 0.82])
_BELOW = np.array([0.55, 0.58, 0.62])  # rays leaving the domain downward through a side (no ground there)
_SUN = np.array([1.0, 0.95, 0.80])
# surface colours by material index (cycled): rigid grey-beige, then sand, snow-grey, green, brick, water
_MATERIALS = np.array(
    [[0.62, 0.58, 0.52], [0.86, 0.72, 0.50], [0.80, 0.82, 0.86], [0.42, 0.55, 0.30], [0.66, 0.36, 0.28]]
)
_CHECKER_M = 10.0  # ground checkerboard (plan metres): makes the mirage's image inversion visible
_AMBIENT = 0.35


def shade_sky(direction: np.ndarray, sun: np.ndarray) -> np.ndarray:
    """(n, 3) sky colour for final unit directions (n, 3): a gradient from the horizon to the zenith by the
    elevation (square-root law), a grey for downward directions and a sun glow ``(d . sun)^256``."""
    dz = np.clip(direction[:, 2], -1.0, 1.0)
    t = np.sqrt(np.clip(np.arcsin(dz) / (np.pi / 2), 0.0, 1.0))[:, None]
    rgb = (1.0 - t) * _HORIZON + t * _ZENITH
    rgb = np.where((dz < 0.0)[:, None], _BELOW, rgb)
    glow = np.clip(direction @ sun, 0.0, 1.0) ** 256
    return np.clip(rgb + glow[:, None] * _SUN, 0.0, 1.0)


def surface_normals(
    points: np.ndarray, surfaces: SceneSurfaces | None, lo: np.ndarray, hi: np.ndarray, ground_z: np.ndarray
) -> np.ndarray:
    """(n, 3) unit normals of the surface at hit points (n, 3): the ground's (flat: +z; terrain: central
    differences of its height function, 0.25 m apart), a roof's (+z) or the nearest building wall's (its
    footprint edge's outward normal) for points more than 5 cm above the ground. ground_z : (n,) ground
    height under each point (m)."""
    n = np.zeros_like(points)
    n[:, 2] = 1.0
    if surfaces is None:
        return n
    if surfaces.terrain is not None:
        from bentray.engine.mesh.terrain import terrain_height_function

        height = terrain_height_function(surfaces.terrain, lo, hi)
        e = 0.25
        xy = points[:, :2]
        dx = (height(xy + [e, 0.0]) - height(xy - [e, 0.0])) / (2 * e)
        dy = (height(xy + [0.0, e]) - height(xy - [0.0, e])) / (2 * e)
        n = np.column_stack([-dx, -dy, np.ones(len(xy))])
        n /= np.linalg.norm(n, axis=1)[:, None]
    above = points[:, 2] > ground_z + 0.05
    if surfaces.footprints and np.any(above):
        idx = np.nonzero(above)[0]
        n[idx] = _building_normals(points[idx], surfaces, ground_z[idx])
    return n


def surface_materials(points: np.ndarray, surfaces: SceneSurfaces | None, ground_z: np.ndarray) -> np.ndarray:
    """(n,) material index at hit points (n, 3): the terrain's (a height grid's square, else its default), or
    the nearest building's for points more than 5 cm above the ground; 0 over flat ground. (The kernels stop a
    camera ray at its first reflecting face before recording that face, so the material is found here.)"""
    out = np.zeros(len(points), np.int64)
    if surfaces is None:
        return out
    terrain = surfaces.terrain
    if terrain is not None:
        out[:] = terrain.default_material
        grid_material = terrain.material if isinstance(terrain, HeightGrid) else None
        if isinstance(terrain, HeightGrid) and grid_material is not None and grid_material.ndim == 2:
            j = np.clip(np.searchsorted(terrain.x, points[:, 0]) - 1, 0, grid_material.shape[1] - 1)
            i = np.clip(np.searchsorted(terrain.y, points[:, 1]) - 1, 0, grid_material.shape[0] - 1)
            out[:] = grid_material[i, j]
    above = points[:, 2] > ground_z + 0.05
    if surfaces.footprints and np.any(above):
        mats = np.array([fp.material for fp in surfaces.footprints])
        centres = np.array([np.mean(np.asarray(fp.polygon, float), axis=0) for fp in surfaces.footprints])
        k = np.argmin(np.linalg.norm(points[above, None, :2] - centres[None], axis=2), axis=1)
        out[above] = mats[k]
    return out


def _building_normals(points: np.ndarray, surfaces: SceneSurfaces, ground_z: np.ndarray) -> np.ndarray:
    """Normals at hit points above the ground: +z within 5 cm of a roof, else the nearest wall edge's."""
    a_list, b_list, roof_list = [], [], []
    for fp in surfaces.footprints:
        base = fp.base_z if fp.base_z is not None else float("nan")
        for ring in [fp.polygon, *fp.holes]:
            ring = np.asarray(ring, float)
            a_list.append(ring)
            b_list.append(np.roll(ring, -1, axis=0))
            roof_list.append(np.full(len(ring), base + fp.height_m if base == base else fp.height_m))
    a = np.concatenate(a_list)
    b = np.concatenate(b_list)
    roof = np.concatenate(roof_list)
    ab = b - a
    length2 = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
    ap = points[:, None, :2] - a[None, :, :]
    u = np.clip(np.sum(ap * ab[None], axis=2) / length2[None], 0.0, 1.0)
    closest = a[None] + u[:, :, None] * ab[None]
    dist = np.linalg.norm(points[:, None, :2] - closest, axis=2)
    k = np.argmin(dist, axis=1)
    edge = ab[k]
    out = np.column_stack([edge[:, 1], -edge[:, 0], np.zeros(len(k))])  # outward for a CCW ring
    out /= np.maximum(np.linalg.norm(out, axis=1), 1e-300)[:, None]
    # a roof: the point is within 5 cm of the edge's roof height (footprints without base_z: roof above z 0
    # or above the local ground), or inside the footprint rather than on its boundary
    on_roof = (np.abs(points[:, 2] - roof[k]) < 0.05) | (np.abs(points[:, 2] - (ground_z + roof[k])) < 0.05)
    on_roof |= dist[np.arange(len(k)), k] > 0.05
    out[on_roof] = [0.0, 0.0, 1.0]
    return out


def shade_surface(
    points: np.ndarray, normals: np.ndarray, material: np.ndarray, sun: np.ndarray, z_range: tuple[float, float]
) -> np.ndarray:
    """(n, 3) colour of surface hits: the material's colour (index cycled through a small palette), lighter
    with height over ``z_range`` (m), a faint 10 m checkerboard, times ``ambient + (1 - ambient) max(0, n.sun)``."""
    base = _MATERIALS[np.asarray(material, np.int64) % len(_MATERIALS)]
    z0, z1 = z_range
    lift = np.clip((points[:, 2] - z0) / max(z1 - z0, 1e-9), 0.0, 1.0)[:, None]
    base = base * (0.85 + 0.3 * lift)
    cx = np.floor(points[:, 0] / _CHECKER_M).astype(np.int64)
    cy = np.floor(points[:, 1] / _CHECKER_M).astype(np.int64)
    checker = np.where(((cx + cy) & 1) == 0, 1.0, 0.82)[:, None]
    lambert = np.clip(normals @ sun, 0.0, 1.0)[:, None]
    return np.clip(base * checker * (_AMBIENT + (1.0 - _AMBIENT) * lambert), 0.0, 1.0)

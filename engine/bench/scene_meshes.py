"""Media meshes of the built-in scenes for the bench (Table 3, throughput, Fig. 8), built by
engine/mesh/terrain.py ``build_terrain_mesh``.

Sizing (fixed here so bench runs compare like with like): horizontal spacing = the scene's terrain grid
spacing (the surface is kept exactly; ``horizontal_spacing_m`` overrides it); vertical layers = the
curvature rule (delta 1e-4, the 3D default; thinnest layer 1 cm) on the profile's column at the domain
centre, mapped to terrain-following sigma levels. The traced quantity is the scene's profile (wind, where
a scene suggests one, is left out: the bench times the media traversal). Rays: ``count`` directions
spread evenly over the sphere from the scene's first source, as the paper's benchmarks launch them.

Every failure (a builder that raises, a missing function, a source outside the mesh) becomes a
:class:`SceneUnavailable` with the reason, so the bench reports "skipped: <reason>" for those rows.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bentray.engine.bench.common import sphere_directions
from bentray.engine.constants import CURVE_QUANTITY
from bentray.engine.mesh.cells import CellMesh

__all__ = ["SceneMesh", "SceneUnavailable", "build_scene_mesh", "SCENE_NAMES"]

SCENE_NAMES = ("desert", "christmas", "reservoir", "ridge", "flat")
VERTICAL_DELTA = 1e-3
VERTICAL_D_MIN_M = 0.01


class SceneUnavailable(RuntimeError):
    """A scene mesh could not be built; ``str(exc)`` is the reason shown in the report."""


@dataclass
class SceneMesh:
    """A built scene mesh and a ray fan from its first source."""

    name: str
    mesh: CellMesh
    origins: np.ndarray
    directions: np.ndarray
    start_cells: np.ndarray
    build_s: float
    stats: dict[str, Any] = field(default_factory=dict)

    @property
    def surfaces(self) -> int:
        """Reflecting boundary faces: ground, walls and roofs (the scene's surface triangles in the mesh)."""
        nbf = self.stats.get("n_boundary_faces", {})
        return int(nbf.get("ground", 0) + nbf.get("walls", 0) + nbf.get("roofs", 0))


def _native_spacing(surfaces: Any, lo: np.ndarray, hi: np.ndarray) -> float:
    from bentray.engine.surfaces import HeightGrid

    terrain = surfaces.terrain
    if isinstance(terrain, HeightGrid) and len(terrain.x) > 1 and len(terrain.y) > 1:
        return float(min(np.min(np.diff(terrain.x)), np.min(np.diff(terrain.y))))
    return float(np.max(hi[:2] - lo[:2]) / 50.0)


def build_scene_mesh(
    name: str,
    count: int,
    *,
    resolution: str = "medium",
    curve: str = "parabolic",
    horizontal_spacing_m: float | None = None,
    surfaces: Any = None,
) -> SceneMesh:
    """Build the terrain mesh of built-in scene ``name`` and a fan of ``count`` rays from its first source.

    surfaces : replaces the scene's own SceneSurfaces (Fig. 8 varies the terrain resolution).
    Raises SceneUnavailable (with the reason) when anything in the chain fails.
    """
    try:
        from bentray.engine.mesh.sizing import curvature_layers
        from bentray.engine.mesh.terrain import build_terrain_mesh, locate_in_terrain_mesh
        from bentray.scenes.library.registry import get_builtin
        from bentray.scenes.profile_models import profile_from_spec

        scene = get_builtin(name, resolution)
        profile = profile_from_spec(scene.profile)
        surf = scene.surfaces if surfaces is None else surfaces
        lo = np.asarray(scene.domain_min, float)
        hi = np.asarray(scene.domain_max, float)
        quantity = CURVE_QUANTITY[curve]
        centre = 0.5 * (lo + hi)

        def m_at_z(z: np.ndarray) -> np.ndarray:
            z = np.atleast_1d(np.asarray(z, float))
            return profile.quantity(
                quantity, np.column_stack([np.full(len(z), centre[0]), np.full(len(z), centre[1]), z])
            )

        z_levels = curvature_layers(
            lo[2], hi[2], m_at_z, delta=VERTICAL_DELTA, d_min=VERTICAL_D_MIN_M, d_max=float(hi[2] - lo[2])
        )
        sigma = (z_levels - lo[2]) / (hi[2] - lo[2])
        sigma[0], sigma[-1] = 0.0, 1.0
        h = horizontal_spacing_m if horizontal_spacing_m is not None else _native_spacing(surf, lo, hi)
        t0 = time.perf_counter()
        tet = build_terrain_mesh(
            surf, lo, hi, lambda p: profile.quantity(quantity, p), horizontal_spacing=h, layer_levels=sigma
        )
        build_s = time.perf_counter() - t0
        src = np.asarray(scene.sources, float)[:1]
        cell = locate_in_terrain_mesh(tet, src)
        if cell[0] < 0:
            raise SceneUnavailable(f"{name}: source {src[0].tolist()} is not inside the terrain mesh")
    except SceneUnavailable:
        raise
    except Exception as exc:  # noqa: BLE001 - any failure of the builder chain is reported, not fatal
        raise SceneUnavailable(f"{name}: {type(exc).__name__}: {' '.join(str(exc).split())[:200]}") from exc
    dirs = sphere_directions(count)
    stats = dict(tet.stats)
    stats.update({"horizontal_spacing_m": h, "layers": int(len(sigma) - 1), "profile": profile.kind})
    return SceneMesh(
        name=name,
        mesh=tet.cells,
        origins=np.repeat(src, count, axis=0),
        directions=dirs,
        start_cells=np.repeat(cell, count),
        build_s=build_s,
        stats=stats,
    )

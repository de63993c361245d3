"""Scene surfaces handed from the scene readers (scenes/) to the mesh builders (engine/mesh/).

Plain numpy containers, no I/O: readers in ``bentray.scenes`` validate files and build these; the
terrain-following mesh builder consumes them. World frame, metres, z up.

Materials: every surface carries a ground material index into ``SceneSurfaces.materials``; material
0 is always rigid (flow resistivity None). The index ends up on each reflecting mesh face
(``CellMesh.face_material``) so the field stage can look up the reflection coefficient.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Material:
    """A ground or facade material: Delany-Bazley flow resistivity in Pa s/m^2 (None = rigid)."""

    name: str
    flow_resistivity: float | None = None


@dataclass
class HeightGrid:
    """Terrain heights on a regular grid.

    x : (nx,) float64 strictly increasing, metres; y : (ny,) float64 strictly increasing, metres.
    z : (ny, nx) float64 ground height at (x[j], y[i]) in metres (row i is y[i]); finite everywhere.
    material : (ny - 1, nx - 1) int64 per grid square, or None (= ``default_material`` everywhere).
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    material: np.ndarray | None = None
    default_material: int = 0


@dataclass
class TriangleSurface:
    """A terrain given as triangles (a height field: at most one surface point above each (x, y)).

    vertices : (V, 3) float64 metres; triangles : (T, 3) int64, counter-clockwise seen from above.
    material : (T,) int64 per triangle, or None (= ``default_material``).
    """

    vertices: np.ndarray
    triangles: np.ndarray
    material: np.ndarray | None = None
    default_material: int = 0


@dataclass
class Footprint:
    """A building or barrier: a vertical prism standing on the terrain.

    polygon : (k, 2) float64 x, y of a simple polygon, counter-clockwise, not closed (first != last).
    height_m : height of the roof above ``base_z``; base_z : ground level of the footprint in metres
    (None: the lowest terrain height under the polygon). material : index of the walls and roof.
    name : for error messages and reports. holes : courtyards, each (h, 2) float64 clockwise, not closed,
    strictly inside the polygon and pairwise disjoint (air columns open to the sky).
    """

    polygon: np.ndarray
    height_m: float
    base_z: float | None = None
    material: int = 0
    name: str = ""
    holes: list[np.ndarray] = field(default_factory=list)


@dataclass
class Barrier:
    """A thin noise barrier (diffraction only, not meshed): polyline (k, 2) float64 x, y metres (k >= 2),
    a vertical screen from base_z to base_z + height_m (m); name for messages and reports."""

    polyline: np.ndarray
    height_m: float
    base_z: float
    name: str = ""


@dataclass
class GroundZone:
    """A plan-view zone of ground with its own material: polygon (k, 2) counter-clockwise, holes (h, 2)
    clockwise, rings not closed, metres; material : index into SceneSurfaces.materials. Later zones win
    where zones overlap; ground faces take the zone under their centroid."""

    polygon: np.ndarray
    holes: list[np.ndarray] = field(default_factory=list)
    material: int = 0
    name: str = ""


@dataclass
class SceneSurfaces:
    """Everything solid in a scene: terrain (or None for flat ground at domain.min z), footprints,
    closed obstacle meshes (vertices (V, 3), faces (F, 3); watertight, outward normals) and the
    material table (index 0 is rigid)."""

    terrain: HeightGrid | TriangleSurface | None = None
    footprints: list[Footprint] = field(default_factory=list)
    obstacles: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    obstacle_materials: list[int] = field(default_factory=list)  # material index per obstacle (empty: rigid)
    materials: list[Material] = field(default_factory=lambda: [Material("rigid", None)])
    ground_zones: list[GroundZone] = field(default_factory=list)  # ground materials by zone (painted in order)
    barriers: list[Barrier] = field(default_factory=list)  # thin screens: diffraction only (engine/diffraction)

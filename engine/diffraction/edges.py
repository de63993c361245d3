"""The scene's diffracting edges and line-of-sight walls, from SceneSurfaces.

- Barriers (thin screens): per polyline segment a top edge (n = 2: a half-plane, face 0 pointing down
  the screen) and at both ends of the polyline a vertical end edge (n = 2, face 0 along the screen).
- Buildings (vertical prisms of footprints with flat roofs): per footprint edge a roof edge (n = 3/2:
  roof and wall meet at a right angle; face 0 is the roof, pointing into the footprint), and per convex
  vertex a vertical corner edge from the base to the roof (n = (2 pi - interior angle) / pi; face 0 along
  the wall to the previous vertex), from the base to the top (the lateral paths' ground reflection is
  their image-source path, engine/diffraction/paths.py, ``lateral``). Reflex vertices do not diffract
  into the open. Holes are ignored
  (courtyards are not diffraction paths here).
- Terrain crests: edges of the triangulated height grid where the two triangles turn away from each
  other (a convex bend) by more than ``TERRAIN_CREST_MIN_DEG`` (engine/constants.py) between their normals.

Walls (W, 6) rows ``x1, y1, x2, y2, z_bottom, z_top`` with their obstacle index (barriers first, then
buildings) feed :func:`bentray.engine.diffraction.kernels.walls_blocking`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from bentray.engine.constants import TERRAIN_CREST_MIN_DEG
from bentray.engine.diffraction.wedge import Edge
from bentray.engine.surfaces import Footprint, HeightGrid, SceneSurfaces

__all__ = ["EDGE_BARRIER_END", "EDGE_BARRIER_TOP", "EDGE_CORNER", "EDGE_ROOF", "EDGE_TERRAIN", "Obstacle",
           "SceneEdges", "scene_edges", "terrain_crests"]  # fmt: skip

EDGE_BARRIER_TOP = 0
EDGE_BARRIER_END = 1
EDGE_ROOF = 2
EDGE_CORNER = 3
EDGE_TERRAIN = 4


@dataclass
class Obstacle:
    """One barrier or building: its edges (with kinds), name, and for buildings the roof-edge pairs that
    face each other across the roof (double diffraction) and the corner pairs sharing a wall (double
    lateral diffraction), as index pairs into ``edges``."""

    name: str
    kind: str  # "barrier" | "building"
    edges: list[Edge] = field(default_factory=list)
    kinds: list[int] = field(default_factory=list)
    roof_pairs: list[tuple[int, int]] = field(default_factory=list)
    corner_pairs: list[tuple[int, int]] = field(default_factory=list)


@dataclass
class SceneEdges:
    """Obstacles (barriers first, then buildings), walls (W, 6) with owner (W,) int64, terrain crests."""

    obstacles: list[Obstacle]
    walls: np.ndarray
    owner: np.ndarray
    crests: list[Edge]

    @property
    def n_edges(self) -> int:
        return sum(len(o.edges) for o in self.obstacles) + len(self.crests)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _barrier(poly: np.ndarray, base: float, top: float, name: str) -> tuple[Obstacle, list[list[float]]]:
    ob = Obstacle(name, "barrier")
    walls = []
    for i in range(len(poly) - 1):
        a, b = poly[i], poly[i + 1]
        d = _unit(np.array([b[0] - a[0], b[1] - a[1], 0.0]))
        length = float(np.hypot(*(b - a)))
        ob.edges.append(Edge(np.array([a[0], a[1], top]), d, np.array([0.0, 0.0, -1.0]), 2.0, 0.0, length))
        ob.kinds.append(EDGE_BARRIER_TOP)
        walls.append([a[0], a[1], b[0], b[1], base, top])
    up = np.array([0.0, 0.0, 1.0])
    for end, nxt in ((poly[0], poly[1]), (poly[-1], poly[-2])):
        along = _unit(np.array([nxt[0] - end[0], nxt[1] - end[1], 0.0]))
        ob.edges.append(Edge(np.array([end[0], end[1], base]), up, along, 2.0, 0.0, top - base))
        ob.kinds.append(EDGE_BARRIER_END)
    return ob, walls


def _building(fp: Footprint, base: float, name: str) -> tuple[Obstacle, list[list[float]]]:
    poly = np.asarray(fp.polygon, float)
    if _signed_area(poly) < 0:
        poly = poly[::-1]
    top = base + float(fp.height_m)
    ob = Obstacle(name, "building")
    walls = []
    k = len(poly)
    up = np.array([0.0, 0.0, 1.0])
    dirs = []
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        d = _unit(np.array([b[0] - a[0], b[1] - a[1], 0.0]))
        dirs.append(d)
        inward = np.array([-d[1], d[0], 0.0])  # left of a counter-clockwise edge
        ob.edges.append(Edge(np.array([a[0], a[1], top]), d, inward, 1.5, 0.0, float(np.hypot(*(b - a)))))
        ob.kinds.append(EDGE_ROOF)
        walls.append([a[0], a[1], b[0], b[1], base, top])
    corner_index = {}
    for i in range(k):
        to_prev = -dirs[i - 1]
        to_next = dirs[i]
        turn = float(dirs[i - 1][0] * dirs[i][1] - dirs[i - 1][1] * dirs[i][0])
        if turn <= 0:  # reflex (or straight) vertex: no exterior wedge
            continue
        interior = float(np.arccos(np.clip(to_prev @ to_next, -1.0, 1.0)))
        n = (2.0 * np.pi - interior) / np.pi
        corner_index[i] = len(ob.edges)
        ob.edges.append(Edge(np.array([poly[i][0], poly[i][1], base]), up, to_prev, n, 0.0, top - base))
        ob.kinds.append(EDGE_CORNER)
    for i in range(k):  # roof edges facing each other (antiparallel): over-the-roof double diffraction
        for j in range(i + 1, k):
            if dirs[i] @ dirs[j] < -0.99:
                ob.roof_pairs.append((i, j))
        if i in corner_index and (i + 1) % k in corner_index:  # corners sharing wall i
            ob.corner_pairs.append((corner_index[i], corner_index[(i + 1) % k]))
    return ob, walls


def _signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def scene_edges(surfaces: SceneSurfaces, footprint_bases: list[float]) -> SceneEdges:
    """Edges and walls of the scene (module docstring); footprint_bases (m) the base of each footprint."""
    obstacles: list[Obstacle] = []
    walls: list[list[float]] = []
    owner: list[int] = []
    for b in surfaces.barriers:
        ob, w = _barrier(np.asarray(b.polyline, float), b.base_z, b.base_z + b.height_m, b.name)
        owner += [len(obstacles)] * len(w)
        obstacles.append(ob)
        walls += w
    for fp, base in zip(surfaces.footprints, footprint_bases, strict=True):
        ob, w = _building(fp, float(base), fp.name)
        owner += [len(obstacles)] * len(w)
        obstacles.append(ob)
        walls += w
    crests = terrain_crests(surfaces.terrain) if isinstance(surfaces.terrain, HeightGrid) else []
    return SceneEdges(
        obstacles, np.asarray(walls, float).reshape(-1, 6), np.asarray(owner, np.int64).reshape(-1), crests
    )


def terrain_crests(grid: HeightGrid, min_deg: float = TERRAIN_CREST_MIN_DEG) -> list[Edge]:
    """Crest edges of a height grid split into triangles along one diagonal per square: the grid edges
    and diagonals whose two triangles bend convexly by more than min_deg; wedge n = (2 pi - interior) / pi
    with the interior angle pi - bend (the ground is the solid), face 0 along the triangle on the
    edge's right."""
    x, y, z = np.asarray(grid.x, float), np.asarray(grid.y, float), np.asarray(grid.z, float)
    ny, nx = z.shape
    pts = np.stack(np.meshgrid(x, y), axis=-1).reshape(-1, 2)
    verts = np.column_stack([pts, z.reshape(-1)])
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    tris = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    nrm = np.cross(verts[tris[:, 1]] - verts[tris[:, 0]], verts[tris[:, 2]] - verts[tris[:, 0]])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    edge_map: dict[tuple[int, int], list[int]] = {}
    for t, tri in enumerate(tris):
        for u, v in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            edge_map.setdefault((min(u, v), max(u, v)), []).append(t)
    out = []
    cos_min = np.cos(np.radians(min_deg))
    for (u, v), ts in edge_map.items():
        if len(ts) != 2:
            continue
        n1, n2 = nrm[ts[0]], nrm[ts[1]]
        if n1 @ n2 > cos_min:
            continue
        p, q = verts[u], verts[v]
        e = _unit(q - p)
        mid = 0.5 * (p + q)
        far1 = verts[[w for w in tris[ts[0]] if w not in (u, v)][0]]
        # convex (a crest) when the other triangle's far vertex lies below the first triangle's plane
        far2 = verts[[w for w in tris[ts[1]] if w not in (u, v)][0]]
        if (far2 - mid) @ n1 >= 0:
            continue
        bend = float(np.arccos(np.clip(n1 @ n2, -1.0, 1.0)))
        f0 = far1 - mid
        f0 = _unit(f0 - (f0 @ e) * e)
        if np.cross(e, f0) @ n1 < 0:  # air on the positive side of face 0 (about e)
            e = -e
        out.append(Edge(p if e @ (q - p) > 0 else q, e, f0, (np.pi + bend) / np.pi, 0.0, float(np.linalg.norm(q - p))))
    return out

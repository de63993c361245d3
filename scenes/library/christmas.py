"""``christmas``: a village of 40 buildings on gently rolling snow-covered ground (the paper's Christmas
benchmark, Table 1: 8,000 surface triangles at medium and 16,000 at high resolution).

1 km x 1 km x 300 m box. Terrain: three seeded broad hills (2-6 m, sigma 150-300 m) on a slight tilt,
3 to 11 m high, on 62 x 61 (medium) or 88 x 88 (high) grid squares, snow (flow resistivity
20 kPa s/m^2). Two streets cross at a 25 m-radius square at the origin; a town hall (20 x 14 m, 12 m)
and a cross-shaped church (14 m) face the square; 38 houses (rectangles and L shapes, 5.5-9.5 m high,
rotated up to 5 degrees) line the streets within 260 m of the square, at least 2 m apart. Buildings
are the same at both resolutions and stand on the lowest ground under them (base_z None); walls and
roofs rigid. One source 1.5 m above the square's centre (carol singers); A-LD+F (winter night).
"""

from __future__ import annotations

import numpy as np

from bentray.engine.surfaces import Footprint, Material, SceneSurfaces
from bentray.scenes.library.common import (
    BuiltinScene,
    Rng,
    check_resolution,
    fluctuating_profile,
    height_grid,
    sources_above_ground,
    surface_stats,
)

__all__ = ["SEED", "christmas", "village_footprints", "village_ground"]

SEED = 2016_002
DOMAIN_MIN = (-500.0, -500.0, 0.0)
DOMAIN_MAX = (500.0, 500.0, 300.0)
_SQUARES = {"medium": (62, 61), "high": (88, 88)}
N_HOUSES = 38
SQUARE_RADIUS_M = 25.0
_STREET_REACH_M = 260.0  # houses within this distance of the square along each street
_GAP_M = 2.0  # minimum clearance between buildings (bounding circles)


def village_ground(x: np.ndarray, y: np.ndarray, seed: int = SEED) -> np.ndarray:
    """Ground height in metres at plan positions x, y: 5 m + three hills + a tilt below 0.4 %."""
    rng = Rng(seed)
    centres = rng.uniform(-500.0, 500.0, (3, 2))
    heights = rng.uniform(2.0, 6.0, 3)
    sigmas = rng.uniform(150.0, 300.0, 3)
    tilt = rng.uniform(-0.004, 0.004, 2)
    z = 5.0 + tilt[0] * x + tilt[1] * y
    for k in range(3):
        r2 = (x - centres[k, 0]) ** 2 + (y - centres[k, 1]) ** 2
        z = z + heights[k] * np.exp(-0.5 * r2 / sigmas[k] ** 2)
    return np.asarray(z)


def _place(local: np.ndarray, centre: tuple[float, float], angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.asarray(local @ np.array([[c, s], [-s, c]]) + np.asarray(centre))


def _rectangle(w: float, d: float) -> np.ndarray:
    return np.array([[-w / 2, -d / 2], [w / 2, -d / 2], [w / 2, d / 2], [-w / 2, d / 2]])


def _l_shape(w: float, d: float, cut_w: float, cut_d: float) -> np.ndarray:
    """A w x d rectangle without its (cut_w x cut_d) north-east corner, counter-clockwise."""
    return np.array(
        [[-w / 2, -d / 2], [w / 2, -d / 2], [w / 2, d / 2 - cut_d], [w / 2 - cut_w, d / 2 - cut_d],
         [w / 2 - cut_w, d / 2], [-w / 2, d / 2]]
    )  # fmt: skip


def _cross(nave: float, nave_w: float, transept: float, transept_w: float) -> np.ndarray:
    """A Latin-cross church plan along x, counter-clockwise (12 vertices)."""
    a, b, c, d = nave / 2, nave_w / 2, transept / 2, transept_w / 2
    x0 = a / 3  # the crossing sits east of the nave's middle
    return np.array(
        [[-a, -b], [x0 - d, -b], [x0 - d, -c], [x0 + d, -c], [x0 + d, -b], [a, -b],
         [a, b], [x0 + d, b], [x0 + d, c], [x0 - d, c], [x0 - d, b], [-a, b]]
    )  # fmt: skip


def village_footprints(seed: int = SEED) -> list[Footprint]:
    """The 40 buildings (town hall, church, 38 houses), counter-clockwise polygons, material 0 (rigid)."""
    rng = Rng(seed + 1)
    buildings = [
        Footprint(_place(_rectangle(20.0, 14.0), (40.0, 36.0), 0.0), 12.0, name="town hall"),
        Footprint(_place(_cross(32.0, 10.0, 22.0, 8.0), (-46.0, -40.0), 0.0), 14.0, name="church"),
    ]
    circles = [(np.array([40.0, 36.0]), 12.3), (np.array([-46.0, -40.0]), 17.0)]
    slots = []
    for street in (0, 1):  # 0: along x (y = 0); 1: along y (x = 0)
        for side in (-1.0, 1.0):
            for pos in np.arange(-_STREET_REACH_M, _STREET_REACH_M + 1.0, 22.0):
                if abs(pos) >= SQUARE_RADIUS_M + 20.0:
                    slots.append((street, side, float(pos)))
    order = np.argsort(rng.uniform(0.0, 1.0, len(slots)), kind="stable")
    for n in order:
        if len(buildings) == N_HOUSES + 2:
            break
        street, side, pos = slots[n]
        w, d = rng.uniform(8.0, 14.0), rng.uniform(9.0, 15.0)  # along / across the street
        setback = rng.uniform(8.0, 11.0) + d / 2  # street half-width 6 m plus a front garden
        along = pos + rng.uniform(-3.0, 3.0)
        centre = np.array([along, side * setback]) if street == 0 else np.array([side * setback, along])
        angle = (0.0 if street == 0 else np.pi / 2) + np.deg2rad(rng.uniform(-5.0, 5.0))
        l_shaped = rng.uniform(0.0, 1.0) < 0.25
        cut = (rng.uniform(0.35, 0.5) * w, rng.uniform(0.35, 0.5) * d)
        height = rng.uniform(5.5, 9.5)
        radius = 0.5 * np.hypot(w, d)
        if any(np.hypot(*(centre - c)) < radius + r + _GAP_M for c, r in circles):
            continue
        local = _l_shape(w, d, *cut) if l_shaped else _rectangle(w, d)
        circles.append((centre, radius))
        buildings.append(
            Footprint(_place(local, tuple(centre), angle), float(height), name=f"house {len(buildings) - 1}")
        )
    return buildings


def christmas(resolution: str = "medium") -> BuiltinScene:
    """The village: about 8,000 (medium) or 16,000 (high) surface triangles including walls and roofs."""
    resolution = check_resolution(resolution)
    grid = height_grid(
        (DOMAIN_MIN[0], DOMAIN_MAX[0]), (DOMAIN_MIN[1], DOMAIN_MAX[1]), _SQUARES[resolution], village_ground
    )
    grid.default_material = 1
    surfaces = SceneSurfaces(
        terrain=grid,
        footprints=village_footprints(),
        materials=[Material("rigid", None), Material("snow", 20e3)],
    )
    return BuiltinScene(
        name="christmas",
        description=(
            "a village of 40 buildings (town hall, church, 38 houses) on snow-covered hills, 1 km x 1 km; "
            "source 1.5 m up in the village square; A-LD+F"
        ),
        resolution=resolution,
        domain_min=DOMAIN_MIN,
        domain_max=DOMAIN_MAX,
        surfaces=surfaces,
        sources=sources_above_ground(surfaces, [(0.0, 0.0, 1.5)]),
        profile=fluctuating_profile(1.0, seed=SEED),
        stats=surface_stats(surfaces, seed=SEED),
    )

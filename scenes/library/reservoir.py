"""``reservoir``: a steep, winding valley closed by a dam, with a lake behind it (the paper's Reservoir
benchmark, Table 1: 4,000 surface triangles; Fig. 9 shows its two sources).

2 km x 2 km x 600 m box. The valley runs along y, its floor falling 2 % from z = 42 m (y = +1000) to 2 m
(y = -1000) and meandering +-80 m in x. Cross-section: floor + 200 m (1 - sech(d / 120 m)), d the
distance from the valley axis: slopes up to 40 degrees, rims 200 m above the floor, with seeded 0-6 m
roughness on the slopes. A straight 10 m-thick gravity dam (a footprint named "dam", base on the
valley floor at z = 22 m, crest at 72 m) crosses the valley at y = 0; upstream the lake fills the
valley to z = 67 m (the terrain is flat there). Grid: 45 x 45 squares (medium, 44 m) or 63 x 63
(high). Materials: lake squares rigid, the rest grassland (200 kPa s/m^2). Sources 2 m above the lake
(y = +500 m) and 2 m above the valley floor downstream (y = -600 m); A-LD night profile.
"""

from __future__ import annotations

import numpy as np

from bentray.engine.surfaces import Footprint, Material, SceneSurfaces
from bentray.scenes.library.common import (
    BuiltinScene,
    Rng,
    check_resolution,
    height_grid,
    log_profile,
    sources_above_ground,
    surface_stats,
)

__all__ = ["SEED", "reservoir", "valley_height", "valley_axis_x", "LAKE_LEVEL_M", "DAM_CREST_M", "DAM_SEAT_M"]

SEED = 2016_003
DOMAIN_MIN = (-1000.0, -1000.0, 0.0)
DOMAIN_MAX = (1000.0, 1000.0, 600.0)
_SQUARES = {"medium": (45, 45), "high": (63, 63)}
SLOPE_HEIGHT_M = 200.0
SLOPE_WIDTH_M = 120.0
DAM_Y_M = 0.0
DAM_THICKNESS_M = 10.0
LAKE_LEVEL_M = 67.0
DAM_CREST_M = 72.0
DAM_SEAT_M = 3.0  # the dam ends where the slope is this far below its crest (margin for grid interpolation)


def valley_floor(y: np.ndarray | float) -> np.ndarray:
    """Valley floor height (m): 2 m at y = -1000 rising 2 % upstream."""
    return np.asarray(2.0 + 0.02 * (np.asarray(y, dtype=np.float64) + 1000.0))


def valley_axis_x(y: np.ndarray | float, seed: int = SEED) -> np.ndarray:
    """x of the valley axis (m) at y: a seeded meander of amplitude 80 m and wavelength 1.6 km."""
    phase = Rng(seed).uniform(0.0, 2.0 * np.pi)
    return np.asarray(80.0 * np.sin(2.0 * np.pi * np.asarray(y, dtype=np.float64) / 1600.0 + phase))


def _natural(x: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
    rng = Rng(seed + 1)
    d = x - valley_axis_x(y, seed)
    slope = 1.0 - 1.0 / np.cosh(d / SLOPE_WIDTH_M)  # 0 on the axis, -> 1 on the rims
    rough = np.zeros(np.broadcast(x, y).shape)
    for _ in range(6):  # six random plane waves, 150-400 m long, 0.5 m each: |rough| <= 3 m, mean 0
        k = 2.0 * np.pi / rng.uniform(150.0, 400.0)
        theta, phi = rng.uniform(0.0, 2.0 * np.pi), rng.uniform(0.0, 2.0 * np.pi)
        rough += 0.5 * np.cos(k * (x * np.cos(theta) + y * np.sin(theta)) + phi)
    return np.asarray(valley_floor(y) + SLOPE_HEIGHT_M * slope + (3.0 + rough) * slope)


def valley_height(x: np.ndarray, y: np.ndarray, seed: int = SEED) -> np.ndarray:
    """Ground height (m) at plan positions: the natural valley, filled to the lake level upstream of the dam."""
    z = _natural(x, y, seed)
    lake = (np.asarray(y) > DAM_Y_M) & (z < LAKE_LEVEL_M)
    return np.where(lake, LAKE_LEVEL_M, z)


def _dam(seed: int) -> Footprint:
    """A straight dam across the valley at y = 0, reaching into each slope up to where the ground is
    DAM_SEAT_M below the crest (a footprint's roof must stay above the terrain under it; the few metres
    left between the dam's end and the slope are far below the crest and closed by the slope itself)."""
    floor = float(valley_floor(DAM_Y_M))
    x0 = float(valley_axis_x(DAM_Y_M, seed))
    t = DAM_THICKNESS_M / 2
    # widest half-width whose two long edges and a fine sampling of the footprint stay DAM_SEAT_M below
    # the crest (the roughness makes the slope uneven, so search rather than use the smooth formula)
    xs = np.linspace(0.0, 600.0, 6001)
    ys = np.linspace(DAM_Y_M - t, DAM_Y_M + t, 5)
    limit = DAM_CREST_M - DAM_SEAT_M
    ok = np.ones_like(xs, dtype=bool)
    for sign in (-1.0, 1.0):
        for y in ys:
            ok &= _natural(x0 + sign * xs, np.full_like(xs, y), seed) < limit
    half = float(xs[np.argmin(ok)] - 0.1) if not ok.all() else float(xs[-1])
    polygon = np.array(
        [[x0 - half, DAM_Y_M - t], [x0 + half, DAM_Y_M - t], [x0 + half, DAM_Y_M + t], [x0 - half, DAM_Y_M + t]]
    )
    return Footprint(polygon=polygon, height_m=DAM_CREST_M - floor, base_z=floor, material=0, name="dam")


def reservoir(resolution: str = "medium") -> BuiltinScene:
    """The reservoir valley: 4,060 (medium) or 7,948 (high) surface triangles."""
    resolution = check_resolution(resolution)
    grid = height_grid(
        (DOMAIN_MIN[0], DOMAIN_MAX[0]), (DOMAIN_MIN[1], DOMAIN_MAX[1]), _SQUARES[resolution], valley_height
    )
    at_lake = grid.z == LAKE_LEVEL_M
    lake_square = at_lake[:-1, :-1] & at_lake[1:, :-1] & at_lake[:-1, 1:] & at_lake[1:, 1:]
    grid.material = np.where(lake_square, 0, 1).astype(np.int64)
    grid.default_material = 1
    surfaces = SceneSurfaces(
        terrain=grid, footprints=[_dam(SEED)], materials=[Material("rigid", None), Material("grassland", 200e3)]
    )
    sources = [(float(valley_axis_x(500.0)), 500.0, 2.0), (float(valley_axis_x(-600.0)), -600.0, 2.0)]
    return BuiltinScene(
        name="reservoir",
        description=(
            "a 200 m-deep winding valley with a 50 m dam and a lake, 2 km x 2 km; sources 2 m above the lake "
            "and above the valley floor downstream; A-LD"
        ),
        resolution=resolution,
        domain_min=DOMAIN_MIN,
        domain_max=DOMAIN_MAX,
        surfaces=surfaces,
        sources=sources_above_ground(surfaces, sources),
        profile=log_profile(1.0),
        stats=surface_stats(surfaces, seed=SEED),
    )

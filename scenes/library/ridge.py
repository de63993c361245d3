"""``ridge``: the A-UW / A-DW hill of docs/physics.md §7, a 2D ridge h(x) = H L^2 / (x^2 + L^2) running
along y, with the log-law wind plus the potential-flow speed-up over it.

docs/physics.md §7 gives the shape but no numbers; we use H = 40 m and L = 200 m (H / L = 0.2: small enough for
the linear speed-up theory, du = u_ref H / L = 0.2 u_ref at the crest, and steep enough to matter).
Two sources 2 m above the ground, 800 m either side of the crest: with the wind along +x the left one
sends its rays downwind over the ridge (A-DW), the right one upwind (A-UW).
"""

from __future__ import annotations

import numpy as np

from bentray.engine.surfaces import SceneSurfaces
from bentray.scenes.library.common import (
    BuiltinScene,
    check_resolution,
    height_grid,
    sources_above_ground,
    standard_atmosphere_profile,
    surface_stats,
)

__all__ = ["RIDGE_HEIGHT_M", "RIDGE_HALF_WIDTH_M", "RIDGE_WIND", "ridge", "ridge_height"]

RIDGE_HEIGHT_M = 40.0  # H
RIDGE_HALF_WIDTH_M = 200.0  # L: the height is H/2 at x = +-L
DOMAIN_MIN = (-1500.0, -200.0, 0.0)
DOMAIN_MAX = (1500.0, 200.0, 600.0)
# Suggested wind key (log law u*/K ln(z/z_g) along +x plus the ridge speed-up); the wind schema is wired
# elsewhere, the geometry keys repeat H and L so the wind model and the terrain cannot disagree.
RIDGE_WIND = {
    "kind": "ridge",
    "u_star": 0.5,
    "z_g": 0.1,
    "direction_deg": 0.0,
    "height_m": RIDGE_HEIGHT_M,
    "half_width_m": RIDGE_HALF_WIDTH_M,
}
_SQUARES = {"medium": (150, 8), "high": (300, 16)}  # 20 m x 50 m and 10 m x 25 m grid squares


def ridge_height(x: np.ndarray) -> np.ndarray:
    """h(x) = H L^2 / (x^2 + L^2) in metres; x metres from the crest (crest line x = 0)."""
    return RIDGE_HEIGHT_M * RIDGE_HALF_WIDTH_M**2 / (np.asarray(x) ** 2 + RIDGE_HALF_WIDTH_M**2)


def ridge(resolution: str = "medium") -> BuiltinScene:
    """The A-UW / A-DW ridge on a 3 km x 400 m x 600 m box; medium 150 x 8 grid squares, high 300 x 16."""
    resolution = check_resolution(resolution)
    grid = height_grid(
        (DOMAIN_MIN[0], DOMAIN_MAX[0]),
        (DOMAIN_MIN[1], DOMAIN_MAX[1]),
        _SQUARES[resolution],
        lambda x, y: ridge_height(x),
    )
    surfaces = SceneSurfaces(terrain=grid)
    return BuiltinScene(
        name="ridge",
        description=(
            f"2D ridge h(x) = H L^2/(x^2 + L^2), H = {RIDGE_HEIGHT_M:g} m, L = {RIDGE_HALF_WIDTH_M:g} m (A-UW/A-DW); "
            "sources 2 m up at x = -800 and +800 m; 1976 standard atmosphere plus wind along +x"
        ),
        resolution=resolution,
        domain_min=DOMAIN_MIN,
        domain_max=DOMAIN_MAX,
        surfaces=surfaces,
        sources=sources_above_ground(surfaces, [(-800.0, 0.0, 2.0), (800.0, 0.0, 2.0)]),
        profile=standard_atmosphere_profile(DOMAIN_MAX[2]),
        wind=dict(RIDGE_WIND),
        stats=surface_stats(surfaces, seed=None),
    )

"""``desert``: a 2 km x 2 km field of dunes (the paper's Desert benchmark, Table 1: 8,000 surface triangles
at medium and 16,000 at high resolution).

Terrain: six seeded transverse dune trains (asymmetric: a gentle windward slope over 3/4 of the
wavelength, a steep lee face over 1/4, C1-smooth crests and troughs, crest height modulated along the
crest) plus three star dunes (Gaussian mounds), sampled on 64 x 64 (medium, 31.25 m) or 90 x 90 (high,
22.2 m) grid squares. Heights about 2 to 30 m; ground sandy soil (flow resistivity 400 kPa s/m^2).
One source 2 m above the ground at the centre; day-time A-LU+F profile, as in the paper's Fig. 14.
"""

from __future__ import annotations

import numpy as np

from bentray.engine.surfaces import Material, SceneSurfaces
from bentray.scenes.library.common import (
    BuiltinScene,
    Rng,
    check_resolution,
    fluctuating_profile,
    height_grid,
    sources_above_ground,
    surface_stats,
)

__all__ = ["SEED", "desert", "dune_height"]

SEED = 2016_001
DOMAIN_MIN = (-1000.0, -1000.0, 0.0)
DOMAIN_MAX = (1000.0, 1000.0, 400.0)
_SQUARES = {"medium": (64, 64), "high": (90, 90)}
_N_TRAINS = 6
_N_STARS = 3


def _parameters(seed: int) -> dict[str, np.ndarray]:
    rng = Rng(seed)
    n, m = _N_TRAINS, _N_STARS
    return {
        "theta": rng.uniform(-0.35, 0.35, n),  # rad: wave vector about +x (the prevailing wind)
        "wavelength": rng.uniform(220.0, 480.0, n),
        "amplitude": rng.uniform(3.0, 9.0, n),
        "phase": rng.uniform(0.0, 1.0, n),  # in wavelengths
        "crest_length": rng.uniform(500.0, 1200.0, n),  # modulation along the crest
        "crest_phase": rng.uniform(0.0, 2.0 * np.pi, n),
        "star_xy": rng.uniform(-800.0, 800.0, (m, 2)),
        "star_height": rng.uniform(10.0, 20.0, m),
        "star_sigma": rng.uniform(80.0, 150.0, m),
    }


def _asymmetric(u: np.ndarray) -> np.ndarray:
    """Dune cross-section over one wavelength u in [0, 1): 0 at the trough, 1 at the crest (u = 3/4)."""
    g = np.where(u < 0.75, u * (0.5 / 0.75), 0.5 + (u - 0.75) * 2.0)
    return np.sin(np.pi * g) ** 2


def dune_height(x: np.ndarray, y: np.ndarray, seed: int = SEED) -> np.ndarray:
    """Ground height in metres (>= 0) at plan positions x, y (metres, same shape)."""
    p = _parameters(seed)
    z = np.zeros(np.broadcast(x, y).shape)
    for k in range(_N_TRAINS):
        c, s = np.cos(p["theta"][k]), np.sin(p["theta"][k])
        along = (x * c + y * s) / p["wavelength"][k] + p["phase"][k]
        across = -x * s + y * c
        crest = 0.65 + 0.35 * np.cos(2.0 * np.pi * across / p["crest_length"][k] + p["crest_phase"][k])
        z += p["amplitude"][k] * _asymmetric(along - np.floor(along)) * crest
    for k in range(_N_STARS):
        r2 = (x - p["star_xy"][k, 0]) ** 2 + (y - p["star_xy"][k, 1]) ** 2
        z += p["star_height"][k] * np.exp(-0.5 * r2 / p["star_sigma"][k] ** 2)
    return z


def desert(resolution: str = "medium") -> BuiltinScene:
    """Dunes on a 2 km x 2 km x 400 m box: 8,192 terrain triangles (medium) or 16,200 (high)."""
    resolution = check_resolution(resolution)
    grid = height_grid(
        (DOMAIN_MIN[0], DOMAIN_MAX[0]), (DOMAIN_MIN[1], DOMAIN_MAX[1]), _SQUARES[resolution], dune_height
    )
    grid.default_material = 1
    surfaces = SceneSurfaces(terrain=grid, materials=[Material("rigid", None), Material("sand", 400e3)])
    return BuiltinScene(
        name="desert",
        description="2 km x 2 km of seeded dunes (2-30 m), sandy ground; source 2 m up at the centre; A-LU+F",
        resolution=resolution,
        domain_min=DOMAIN_MIN,
        domain_max=DOMAIN_MAX,
        surfaces=surfaces,
        sources=sources_above_ground(surfaces, [(0.0, 0.0, 2.0)]),
        profile=fluctuating_profile(-1.0, seed=SEED),
        stats=surface_stats(surfaces, seed=SEED),
    )

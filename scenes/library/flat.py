"""``flat``: flat rigid ground at z = 0, the default scene of the example job (A-LD ray fan)."""

from __future__ import annotations

import numpy as np

from bentray.engine.surfaces import SceneSurfaces
from bentray.scenes.library.common import BuiltinScene, check_resolution, log_profile, surface_stats

__all__ = ["flat"]

DOMAIN_MIN = (-50.0, -50.0, 0.0)
DOMAIN_MAX = (4000.0, 50.0, 2600.0)


def flat(resolution: str = "medium") -> BuiltinScene:
    """Flat rigid ground (no terrain: the domain bottom), a 4 km x 100 m x 2.6 km box, one source 1.5 m
    above the ground, A-LD. ``resolution`` is accepted for uniformity and changes nothing."""
    check_resolution(resolution)
    surfaces = SceneSurfaces()
    return BuiltinScene(
        name="flat",
        description="flat rigid ground at z = 0 (the domain bottom); source 1.5 m above it; A-LD night profile",
        resolution=resolution,
        domain_min=DOMAIN_MIN,
        domain_max=DOMAIN_MAX,
        surfaces=surfaces,
        sources=np.array([[0.0, 0.0, 1.5]]),
        profile=log_profile(1.0),
        stats=surface_stats(surfaces, seed=None),
    )

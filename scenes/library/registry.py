"""The built-in scene registry: ``scene.builtin`` names, :func:`get_builtin` and the ``bentray scenes`` table."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from bentray.scenes.library.christmas import christmas
from bentray.scenes.library.common import RESOLUTIONS, BuiltinScene, check_resolution
from bentray.scenes.library.desert import desert
from bentray.scenes.library.flat import flat
from bentray.scenes.library.reservoir import reservoir
from bentray.scenes.library.ridge import ridge

__all__ = ["BUILTIN_SCENES", "RESOLUTIONS", "BuiltinScene", "get_builtin", "scene_table", "describe_profile"]

BUILTIN_SCENES: dict[str, Callable[[str], BuiltinScene]] = {
    "flat": flat,
    "ridge": ridge,
    "desert": desert,
    "christmas": christmas,
    "reservoir": reservoir,
}


def get_builtin(name: str, resolution: str = "medium") -> BuiltinScene:
    """Generate the named built-in scene ('medium' or 'high' resolution); ValueError names the choices."""
    if name not in BUILTIN_SCENES:
        raise ValueError(f"unknown builtin scene {name!r}; known scenes: {', '.join(BUILTIN_SCENES)}")
    return BUILTIN_SCENES[name](check_resolution(resolution))


def describe_profile(profile: dict[str, Any]) -> str:
    """Short text for a profile dict, e.g. ``log (b=-1) + fluctuations (rms 0.5 m/s)``."""
    kind = profile.get("kind")
    if kind == "fluctuating":
        return f"{describe_profile(profile['base'])} + fluctuations (rms {profile.get('rms', 0.5):g} m/s)"
    if kind == "log":
        return f"log (b={profile.get('b', 1.0):g})"
    if kind == "table" and "temperature_k" in profile:
        return "standard atmosphere (table)"
    return str(kind)


def scene_table(resolution: str = "medium") -> list[dict[str, Any]]:
    """One row per built-in scene for ``bentray scenes``: name, domain size (m), surface triangles,
    buildings, sources, default profile (and wind), description."""
    rows = []
    for name in BUILTIN_SCENES:
        scene = get_builtin(name, resolution)
        size = [hi - lo for lo, hi in zip(scene.domain_min, scene.domain_max, strict=True)]
        rows.append(
            {
                "name": name,
                "resolution": resolution,
                "domain_m": "x".join(f"{s:g}" for s in size),
                "triangles": scene.stats["surface_triangles"],
                "buildings": scene.stats["buildings"],
                "sources": int(scene.sources.shape[0]),
                "profile": describe_profile(scene.profile) + (" + wind" if scene.wind else ""),
                "description": scene.description,
            }
        )
    return rows

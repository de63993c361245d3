"""Ready-made jobs on the built-in scenes: the scene's default profile, wind and sources with a full
3D ray fan. Used by the README's Table 1, ``bentray bench`` and the examples."""

from __future__ import annotations

from typing import Any

from bentray.scenes.library.registry import get_builtin
from bentray.scenes.schema import Job


def builtin_job_spec(
    name: str,
    *,
    resolution: str = "medium",
    elevations: int = 100,
    azimuths: int = 100,
    elevation_deg: tuple[float, float] = (-45.0, 45.0),
    max_time_s: float = 10.0,
    max_reflections: int = 3,
    with_wind: bool = True,
    all_sources: bool = False,
    outputs: list[str] | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """Job JSON for builtin ``name``: elevations x azimuths rays (azimuth 0..360, end excluded) from the
    scene's first source (or every source), its default profile, its suggested wind (if any and
    ``with_wind``). ``extra`` keys (solver, field, ...) are merged in."""
    scene = get_builtin(name, resolution)
    sources = scene.sources if all_sources else scene.sources[:1]
    spec: dict[str, Any] = {
        "name": f"{name}-{resolution}",
        "scene": {"builtin": name, "resolution": resolution},
        "profile": scene.profile,
        "sources": [{"position": [float(v) for v in p]} for p in sources],
        "rays": {
            "elevation_deg": {"min": elevation_deg[0], "max": elevation_deg[1], "count": elevations},
            "azimuth_deg": {"min": 0.0, "max": 360.0 * (1 - 1 / azimuths), "count": azimuths},
            "max_time_s": max_time_s,
            "max_reflections": max_reflections,
        },
        "outputs": outputs or ["rays", "report"],
    }
    if with_wind and scene.wind is not None:
        spec["wind"] = dict(scene.wind)
    spec.update(extra)
    return spec


def builtin_job(name: str, **kwargs: Any) -> Job:
    """The validated :class:`Job` of :func:`builtin_job_spec`."""
    return Job.model_validate(builtin_job_spec(name, **kwargs))

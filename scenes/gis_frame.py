"""Job preparation for a scene in a projected CRS: move everything to the local frame the engine works in.

With ``scene.crs`` set, every plan coordinate of the job (domain, sources, receivers, the field grid's origin, inline
footprints and ground zones, and the contents of the terrain, buildings, obstacle and zone files) is in
that CRS. :func:`localise_job` picks the local origin (``scene.local_origin`` if given, else
:func:`bentray.scenes.crs.choose_local_origin` of the domain's lower-left corner) and returns the job with
domain, sources, receivers and field grid shifted by it, plus the :class:`LocalFrame` that the report carries back
(``report.json["georeference"]``, read by ``bentray export``). Scene geometry is shifted as it is read
(:func:`bentray.scenes.scene_models.surfaces_from_specs` with ``offset``), so error messages about it
give local coordinates. Profile and wind coordinates (a hot spot's centre, a grid profile's origin, a
ridge's position) are *not* shifted: they are local metres, relative to the reported local origin.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bentray.engine.surfaces import Footprint, GroundZone, HeightGrid, TriangleSurface
from bentray.scenes.crs import LocalFrame, choose_local_origin, parse_crs

__all__ = ["localise_job", "shift_terrain", "shift_footprint", "shift_zone"]


def localise_job(job: Any) -> tuple[Any, LocalFrame]:
    """(job in the local frame, frame). A job without ``scene.crs`` comes back unchanged with the identity
    frame; a localised job has ``scene.local_origin`` set (so its files are shifted when read)."""
    scene = job.scene
    if getattr(scene, "crs", None) is None:
        return job, LocalFrame()
    box = scene.box
    origin = tuple(scene.local_origin) if scene.local_origin is not None else choose_local_origin(box.min[:2])
    x0, y0 = float(origin[0]), float(origin[1])
    frame = LocalFrame(origin=(x0, y0), crs_wkt=parse_crs(scene.crs).to_wkt())

    def xy(p: Any) -> tuple[float, ...]:
        return (float(p[0]) - x0, float(p[1]) - y0, *(float(v) for v in p[2:]))

    domain = scene.domain.model_copy(update={"min": xy(scene.domain.min), "max": xy(scene.domain.max)})
    scene = scene.model_copy(update={"domain": domain, "local_origin": (x0, y0)})
    sources = [s.model_copy(update={"position": xy(s.position)}) for s in job.sources]
    update: dict[str, Any] = {"scene": scene, "sources": sources}
    if job.field is not None:
        update["field"] = job.field.model_copy(update={"origin": xy(job.field.origin)})
    if getattr(job, "receivers", None):
        update["receivers"] = [
            r.model_copy(update={"position": xy(r.position)} if r.position is not None else {"xy": xy(r.xy)})
            for r in job.receivers
        ]
    return job.model_copy(update=update), frame


def shift_terrain(grid: HeightGrid | TriangleSurface, offset: tuple[float, float]) -> HeightGrid | TriangleSurface:
    """The terrain with its plan coordinates minus ``offset`` (in place; returned for chaining)."""
    if isinstance(grid, HeightGrid):
        grid.x = grid.x - offset[0]
        grid.y = grid.y - offset[1]
    else:
        grid.vertices = grid.vertices - np.array([offset[0], offset[1], 0.0])
    return grid


def shift_footprint(fp: Footprint, offset: tuple[float, float]) -> Footprint:
    """The footprint (exterior and holes) minus ``offset`` (in place; returned)."""
    off = np.asarray(offset, dtype=np.float64)
    fp.polygon = fp.polygon - off
    fp.holes = [h - off for h in fp.holes]
    return fp


def shift_zone(zone: GroundZone, offset: tuple[float, float]) -> GroundZone:
    """The ground zone minus ``offset`` (in place; returned)."""
    off = np.asarray(offset, dtype=np.float64)
    zone.polygon = zone.polygon - off
    zone.holes = [h - off for h in zone.holes]
    return zone

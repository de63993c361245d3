"""The checks of a validated job that need its files or evaluate its medium (one place for CLI and service).

:func:`scene_problems` reads the scene's surfaces (terrain, buildings, obstacles), checks that they fit
the domain and each other (no overlapping footprints), that every source is above the ground and outside
buildings, and that the medium is air-like (:mod:`bentray.scenes.media_checks`). It returns one
``field.path: reason`` line per problem: ``bentray run`` prints them with exit status 2, the service
answers them as a 422 at submit time (in its validation process, under a time limit), so a job that
would fail in the worker for one of these reasons is refused before it is queued.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["scene_problems"]


def _lines(exc: BaseException) -> list[str]:
    return [line for line in (" ".join(part.split()) for part in str(exc).splitlines()) if line] or [
        f"scene: {type(exc).__name__}"
    ]


def scene_problems(job: Any, base_dir: str | Path | None) -> list[str]:
    """Problems of ``job`` (a validated :class:`bentray.scenes.schema.Job`) with files under ``base_dir``."""
    import numpy as np

    from bentray.engine.errors import BentrayError
    from bentray.scenes.media_checks import media_problems
    from bentray.scenes.scene_models import check_points_above_ground, scene_surfaces

    scene = job.scene
    problems: list[str] = []
    surfaces = None
    try:
        surfaces = scene_surfaces(scene, base_dir)  # as the job's scene stage reads them
    except (BentrayError, ValueError, OSError) as exc:
        problems += _lines(exc)
    if surfaces is not None:
        # sources given by height above the ground (2D position) are above it by construction
        absolute = [i for i, s in enumerate(job.sources) if len(s.position) == 3]
        positions = np.array([job.sources[i].position for i in absolute], dtype=np.float64).reshape(-1, 3)
        try:
            check_points_above_ground(
                surfaces,
                positions,
                [f"sources.{i}.position" for i in absolute],
                flat_ground_z=float(scene.box.min[2]) if surfaces.terrain is None else None,
            )
        except (BentrayError, ValueError) as exc:
            problems += _lines(exc)
    problems += media_problems(job, base_dir)
    return problems

"""``bentray render``: a job's pinhole camera through its media mesh, written as a PNG.

    bentray render JOB.json --out IMAGE.png [--threads N] [--width W --height H] [--device cpu|cuda|auto]

The job needs a ``camera`` (scenes/camera_models.py); ``--width`` / ``--height`` / ``--device`` override the
camera's resolution and ``solver.device``. Beside the PNG, ``IMAGE.json`` holds the pixel counts (surface,
sky, lost), the mesh and the timings. Exit status as for ``bentray run`` (2: invalid job, naming the field).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

__all__ = ["add_render", "cmd_render"]


def cmd_render(args: argparse.Namespace) -> int:
    from bentray.clients.cli import CommandError, _check, _load, _set_threads

    job_path = Path(args.job)
    job = _load(job_path)
    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise CommandError(f"--out {out}: expected a .png file name", code=2)
    if out.exists() and out.is_dir():
        raise CommandError(f"--out {out} is a directory", code=2)
    if args.threads is not None:
        _set_threads(args.threads)
    updates: dict[str, object] = {}
    if job.camera is not None and (args.width is not None or args.height is not None):
        cam = job.camera.model_dump()
        cam.update({k: v for k, v in (("width", args.width), ("height", args.height)) if v is not None})
        updates["camera"] = cam
    if args.device is not None:
        updates["solver"] = {**job.solver.model_dump(), "device": args.device}
    if updates:
        from pydantic import ValidationError

        from bentray.scenes.schema import Job, format_validation_error

        try:
            job = Job.model_validate({**job.model_dump(), **updates})
        except ValidationError as exc:
            raise CommandError(f"{job_path}: invalid job:\n{format_validation_error(exc)}", code=2) from None
    _check(job, job_path)

    from bentray.engine.errors import JobInputError
    from bentray.engine.render.image import render_job, write_png

    t0 = time.perf_counter()
    try:
        outcome = render_job(job, job_path.absolute().parent)
    except JobInputError as exc:
        raise CommandError(f"{job_path}: invalid job:\n{exc}", code=2) from None
    write_png(outcome, out)
    stats_path = out.with_suffix(".json")
    stats_path.write_text(json.dumps(outcome.stats, indent=1, default=str))
    s = outcome.stats
    print(
        f"render {job.name}: {s['pixels']:,} rays in {time.perf_counter() - t0:.2f} s on {s['device']} "
        f"({s['surface']:,} surface, {s['sky']:,} sky, {s['lost']:,} lost; mesh {s['mesh']}, {s['mesh_cells']:,} cells)"
    )
    print(f"  wrote: {out}, {stats_path}")
    return 0


def add_render(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from bentray.clients.cli import _positive_int

    p = sub.add_parser(
        "render",
        help="render the job's camera through its media mesh (mirages) into a PNG",
        description="Shoot one ray per pixel of the job's camera through its media mesh and write a PNG.",
    )
    p.add_argument("job", help="job file with a 'camera' (see scenes/examples/mirage-*.json)")
    p.add_argument("--out", required=True, help="output PNG (IMAGE.json with the stats is written beside it)")
    p.add_argument("--threads", type=_positive_int, default=None, help="numba threads (default: all)")
    p.add_argument("--width", type=_positive_int, default=None, help="override camera.width (pixels)")
    p.add_argument("--height", type=_positive_int, default=None, help="override camera.height (pixels)")
    p.add_argument("--device", choices=["cpu", "cuda", "auto"], default=None, help="override solver.device")
    p.set_defaults(func=cmd_render)

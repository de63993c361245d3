"""Stage timings of one job, wall and CPU seconds, with the trace split into traversal and beam deposits.

    python -m bentray.engine.bench.stages scenes/examples/ridge-wind-map.json [--rounds 2]

Runs the job's stages in order in this process (as :func:`bentray.engine.run.run_prepared` does, writing
nothing) and prints one row per stage: wall seconds, CPU seconds of this process (all threads) and the
Numba compilation inside the stage. The trace runs twice per round on the same mesh and rays: with the
job's beam field (the deposits of engine/kernels/beams.py) and without a field; the difference is what
the deposits cost. Rounds are interleaved; the table keeps each stage's best round. CPU seconds are the
steadier figure on a shared machine (wall time waits for other work).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

__all__ = ["main", "stage_table"]


def _timed(rows: dict[str, list[float]], name: str, fn: Callable[[], Any]) -> Any:
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    best = rows.get(name)
    if best is None or cpu < best[1]:
        rows[name] = [wall, cpu]
    return out


def stage_table(job_file: Path, rounds: int = 2) -> dict[str, list[float]]:
    """{stage: [wall s, cpu s]} of the job's stages (module docstring), best of ``rounds``."""
    import copy

    from bentray.engine import stages
    from bentray.engine.diffraction.stage import stage_diffraction
    from bentray.engine.diffraction.terrain import stage_terrain_screening
    from bentray.engine.executors import LocalExecutor
    from bentray.engine.run import prepare_medium, prepare_scene
    from bentray.engine.shadow_stage import stage_refractive_shadow
    from bentray.engine.stages import StageLog
    from bentray.engine.wave_stage import stage_wave_field
    from bentray.scenes.schema import Job

    spec = json.loads(Path(job_file).read_text())
    rows: dict[str, list[float]] = {}
    log = StageLog()

    def quiet(stage: str, fraction: float) -> None:
        return None

    job, _, surfaces = _timed(rows, "scene", lambda: prepare_scene(Job.model_validate(spec), job_file.parent, log))
    profile, wind, media = _timed(rows, "mesh", lambda: prepare_medium(job, job_file.parent, surfaces, log, quiet))
    plans = {}
    for name in ("trace (field)", "trace (no field)"):
        s = dict(spec)
        if name == "trace (no field)":
            s.pop("field", None)
            s["outputs"] = [o for o in s.get("outputs", []) if o != "field"]
        j, _, _ = prepare_scene(Job.model_validate(s), job_file.parent, StageLog())
        fan = stages.launch_fan(j)
        cells = stages.stage_locate(j, media, surfaces, fan.source, log)
        setup = stages.stage_field_setup(j, profile, media.mesh, surfaces, fan.source, log)
        plans[name] = (j, stages.build_plan(j, profile, wind, fan, cells, setup), fan, setup)
    traced = None
    for _ in range(rounds):
        for name, (j, plan, fan, _) in plans.items():
            out = _timed(rows, name, partial(stages.stage_trace, j, plan, fan, LocalExecutor(), quiet, StageLog()))
            traced = out if name == "trace (field)" else traced
    j, _, _, setup = plans["trace (field)"]
    assert traced is not None
    base = _timed(rows, "field", lambda: stages.stage_field(j, profile, surfaces, traced, setup, log))
    recv = stages.stage_receivers(j, traced, setup, log)
    for _ in range(rounds):
        fa, rc = copy.deepcopy(base), copy.deepcopy(recv)
        for stage_name, stage_fn in (
            ("diffraction", stage_diffraction),
            ("terrain_screening", stage_terrain_screening),
            ("wave_field", stage_wave_field),
            ("refractive_shadow", stage_refractive_shadow),
        ):
            _timed(rows, stage_name, partial(stage_fn, j, profile, wind, surfaces, setup, fa, rc, StageLog()))
    field, nofield = rows["trace (field)"], rows["trace (no field)"]
    rows["deposits (difference)"] = [field[0] - nofield[0], field[1] - nofield[1]]
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("job", type=Path)
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args(argv)
    rows = stage_table(a.job, a.rounds)
    print(f"{'stage':24s} {'wall s':>8s} {'cpu s':>8s}")
    for name, (wall, cpu) in rows.items():
        print(f"{name:24s} {wall:8.2f} {cpu:8.2f}")


if __name__ == "__main__":
    main()

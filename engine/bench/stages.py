"""Stage timings of one job, wall and CPU seconds, with the trace split into traversal and beam deposits.

    python -m bentray.engine.bench.stages scenes/examples/ridge-wind-map.json [--rounds 2]

Runs the job's stages in order in this process (as :func:`bentray.engine.run.run_prepared` does, writing
nothing) and prints one row per stage: wall seconds, CPU seconds of this process (all threads) and the
Numba compilation inside the stage. The trace runs three times per round on the same mesh and rays: with the
job's beam field, with the same field moved 1000 km sideways (the rays carry their paraxial derivatives and are cut
into chord samples, but no chord reaches the grid's columns: until 2026-12-04 it was moved 100 km up, which left
every chord's column search running) and without a field. ``field (difference)`` is what the
field costs in all; ``deposits (difference)`` what the deposits themselves cost (engine/kernels/beams.py:
the chord search, each point's beam, the per-band terms and the amplitudes, computed on a chord's first
deposit). Rounds are interleaved; the table keeps each stage's best round. CPU seconds are the
steadier figure on a shared machine (wall time waits for other work). Below the table: the beam deposits of
the trace (the sum of the field's per-point hit counts: one deposit is one chord's beam added at one point),
the chord samples (about the rays' total length over the chord length) and deposits per CPU-second of the
difference. ``--save FILE.npz`` writes the traced beam field (normalised energies / pressures, weights, hits;
receivers' too) for a bit-for-bit comparison of two checkouts (``--compare A.npz B.npz``).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["compare", "main", "stage_table"]


def _timed(rows: dict[str, list[float]], name: str, fn: Callable[[], Any]) -> Any:
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    best = rows.get(name)
    if best is None or cpu < best[1]:
        rows[name] = [wall, cpu]
    return out


def _beam_arrays(traced: Any) -> dict[str, np.ndarray]:
    """The traced beam field's arrays (BeamBuffers.collapsed and .receivers), by name."""
    out: dict[str, np.ndarray] = {}
    buffers = traced.buffers
    for part in ("collapsed", "receivers"):
        obj = getattr(buffers, part, None)
        if obj is None:
            continue
        for key, val in vars(obj).items():
            if isinstance(val, np.ndarray):
                out[f"{part}.{key}"] = val
    return out


def compare(a: Path, b: Path) -> int:
    """Print, per array of two ``--save`` files, whether it is bit-identical, else its largest relative
    difference (and the largest level difference in dB of the energies); 0 when all are identical."""
    fa, fb = np.load(a), np.load(b)
    bad = 0
    for key in sorted(set(fa.files) | set(fb.files)):
        if key not in fa.files or key not in fb.files:
            print(f"{key}: only in one file")
            bad += 1
            continue
        x, y = fa[key], fb[key]
        if x.shape == y.shape and np.array_equal(x, y):
            print(f"{key}: identical {x.shape}")
            continue
        bad += 1
        if x.shape != y.shape:
            print(f"{key}: shapes {x.shape} {y.shape}")
            continue
        scale = np.maximum(np.abs(x), np.abs(y))
        rel = np.where(scale > 0, np.abs(x - y) / np.where(scale > 0, scale, 1.0), 0.0)
        line = f"{key}: max relative difference {float(rel.max()):.3e}"
        if "energy" in key or "powered" in key:
            with np.errstate(divide="ignore", invalid="ignore"):
                d_db = np.abs(10.0 * np.log10(np.abs(y)) - 10.0 * np.log10(np.abs(x)))
            ok = np.isfinite(d_db)
            line += f", max |dL| {float(d_db[ok].max()) if ok.any() else 0.0:.3e} dB"
        print(line)
    return 0 if bad == 0 else 1


def stage_table(job_file: Path, rounds: int = 2, save: Path | None = None) -> dict[str, list[float]]:
    """{stage: [wall s, cpu s]} of the job's stages (module docstring), best of ``rounds``; ``save``: write
    the traced beam field there (npz). Extra rows: ``deposits`` and ``samples`` as [count, 0]."""
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
    for name in ("trace (field)", "trace (field elsewhere)", "trace (no field)"):
        s = dict(spec)
        if name == "trace (no field)":
            s.pop("field", None)
            s["outputs"] = [o for o in s.get("outputs", []) if o != "field"]
        j, _, _ = prepare_scene(Job.model_validate(s), job_file.parent, StageLog())
        fan = stages.launch_fan(j)
        cells = stages.stage_locate(j, media, surfaces, fan.source, log)
        setup = stages.stage_field_setup(j, profile, media.mesh, surfaces, fan.source, log)
        plan = stages.build_plan(j, profile, wind, fan, cells, setup)
        if name == "trace (field elsewhere)":  # the same field 1000 km away: samples and paraxial rays, no search
            from bentray.engine.beam_field import BeamBuffers

            assert isinstance(plan.field, BeamBuffers), "the job has no beam field"
            bg = plan.field.bgrid
            plan.field.bgrid = bg._replace(origin=bg.origin + np.array([1e6, 0.0, 0.0]))
        plans[name] = (j, plan, fan, setup)
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
    field, away, nofield = rows["trace (field)"], rows["trace (field elsewhere)"], rows["trace (no field)"]
    rows["field (difference)"] = [field[0] - nofield[0], field[1] - nofield[1]]
    rows["deposits (difference)"] = [field[0] - away[0], field[1] - away[1]]
    arrays = _beam_arrays(traced)
    hits = sum(float(v.sum()) for k, v in arrays.items() if k.endswith(".hits"))
    chord_m = getattr(getattr(traced.buffers, "tables", None), "chord_m", 0.0)
    samples = float(traced.result.length_m.sum()) / chord_m if chord_m else 0.0
    rows["deposits"] = [hits, 0.0]
    rows["samples"] = [samples, 0.0]
    if save is not None:
        np.savez(save, **arrays)  # type: ignore[arg-type]  # numpy stubs type the kwargs as allow_pickle
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("job", type=Path, nargs="?")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--save", type=Path, default=None, help="write the traced beam field (npz)")
    ap.add_argument("--compare", type=Path, nargs=2, default=None, help="compare two --save files")
    a = ap.parse_args(argv)
    if a.compare is not None:
        raise SystemExit(compare(*a.compare))
    if a.job is None:
        ap.error("a job file is required")
    rows = stage_table(a.job, a.rounds, a.save)
    counts = {k: rows.pop(k)[0] for k in ("deposits", "samples")}
    print(f"{'stage':24s} {'wall s':>8s} {'cpu s':>8s}")
    for name, (wall, cpu) in rows.items():
        print(f"{name:24s} {wall:8.2f} {cpu:8.2f}")
    dep_cpu = rows["deposits (difference)"][1]
    rate = counts["deposits"] / dep_cpu if dep_cpu > 0 else float("nan")
    print(f"beam deposits {counts['deposits']:.0f}, chord samples ~{counts['samples']:.0f}, {rate:.3g} deposits/CPU-s")


if __name__ == "__main__":
    main()

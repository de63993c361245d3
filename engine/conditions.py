"""Jobs with ``conditions``: one propagation per meteorological condition, combined into period levels
and Lden (the formulas: :mod:`bentray.scenes.condition_models`).

What is shared, and why:

- the scene (terrain, buildings, ground zones) is read once;
- the media mesh is built once per distinct medium (profile and wind); conditions with the same medium
  reuse it (a mesh is refined for its own medium, so a different profile gets its own mesh);
- within a condition, the sources are split into emission groups (sources with the same
  ``period_offsets_db``). Each group is traced on the condition's mesh: every ray is still traced once,
  so the split costs no extra tracing, and it keeps each group's levels apart so the per-period emission
  can be applied to them.

The outcome has one field with, per condition, ``spl_<band>hz__<name>`` and ``spl_a__<name>`` (all
sources at their ``power_db``), and the A-weighted ``l_day``, ``l_evening``, ``l_night`` and ``l_den``
(dB(A)); receivers.csv has the same per condition (incoherent levels) and the four indicators. Points a
condition leaves without a level (NaN) stay NaN in the indicators. ``rays.csv`` lists the rays of every
condition and group in order (the report gives each one's ray range).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bentray.engine.executors import Executor
from bentray.engine.export.lden import energy_sum, lden
from bentray.engine.field_sources import COMBINATION
from bentray.engine.result import JobOutcome, concat_traces
from bentray.engine.run import Prepared, ProgressFn, prepare_medium, prepare_scene, run_prepared
from bentray.engine.stages import StageLog
from bentray.scenes.condition_models import PERIODS, Condition, condition_job, medium_key
from bentray.scenes.schema import Job

__all__ = ["ConditionRun", "emission_groups", "run_conditions"]


@dataclass
class ConditionRun:
    """One condition's outcome per emission group (groups in the order of :func:`emission_groups`)."""

    condition: Condition
    outcomes: list[JobOutcome]
    mesh_reused_from: str | None


def emission_groups(job: Job) -> list[tuple[tuple[float, float, float], list[int]]]:
    """[(per-period offsets (day, evening, night) dB, source indices)], in order of first appearance."""
    groups: dict[tuple[float, float, float], list[int]] = {}
    for i, src in enumerate(job.sources):
        key = src.period_offsets_db.as_tuple() if src.period_offsets_db is not None else (0.0, 0.0, 0.0)
        groups.setdefault(key, []).append(i)
    return list(groups.items())


def _energy(level: np.ndarray) -> np.ndarray:
    return np.power(10.0, np.asarray(level, float) / 10.0)


def _level(energy: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.asarray(10.0 * np.log10(energy), float)


def _period_levels(
    job: Job, per_condition: list[list[np.ndarray]], offsets: list[tuple[float, float, float]]
) -> dict[str, np.ndarray]:
    """l_day, l_evening, l_night, l_den (dB) from per condition, per group A-weighted levels (dB)."""
    out: dict[str, np.ndarray] = {}
    for p, period in enumerate(PERIODS):
        total = None
        for cond, levels in zip(job.conditions, per_condition, strict=True):
            e = sum(_energy(level + off[p]) for level, off in zip(levels, offsets, strict=True))
            part = cond.occurrence.share(period) * np.asarray(e, float)
            total = part if total is None else total + part
        assert total is not None
        out[f"l_{period}"] = _level(total)
    out["l_den"] = lden(
        out["l_day"],
        out["l_evening"],
        out["l_night"],
        hours=job.periods.hours,
        penalties_db=job.periods.penalties_db,
    )
    return out


def _combine_fields(job: Job, runs: list[ConditionRun], offsets: list[tuple[float, float, float]]) -> Any:
    first = runs[0].outcomes[0].field
    if first is None:
        return None
    arrays: dict[str, np.ndarray] = {}
    spl_names = [k for k in first.arrays if k.startswith("spl_")]
    per_condition: list[list[np.ndarray]] = []
    for run in runs:
        name = run.condition.name
        fields: list[Any] = [o.field for o in run.outcomes]
        for key in spl_names:
            arrays[f"{key}__{name}"] = energy_sum([f.arrays[key] for f in fields])
        per_condition.append([f.arrays["spl_a"] for f in fields])
        if "field_source" in fields[0].arrays:  # what produced the level (engine/field_sources.py), per condition
            codes = np.asarray([f.arrays["field_source"] for f in fields])
            same = np.all(codes == codes[0], axis=0)
            arrays[f"field_source__{name}"] = np.where(same, codes[0], COMBINATION).astype(codes.dtype)
    if "inside_solid" in first.arrays:
        arrays["inside_solid"] = first.arrays["inside_solid"]  # geometry: the same in every condition
    arrays.update(_period_levels(job, per_condition, offsets))
    field_data = dict(first.field_data)
    field_data["conditions"] = (
        "spl_*__<condition>: levels of all sources at their power_db under that condition; l_day, l_evening, "
        "l_night: A-weighted period levels (dB(A)), conditions combined in energy with their occurrences and "
        "each source's period offsets; l_den: Lden with period hours "
        f"{list(job.periods.hours)} and penalties {list(job.periods.penalties_db)} dB"
    )
    field_data["condition_names"] = [run.condition.name for run in runs]
    stats = {"per_condition": {run.condition.name: getattr(run.outcomes[0].field, "stats", {}) for run in runs}}
    preview = dict(first.preview)
    preview["title"] = f"{job.name}: Lden over {len(runs)} conditions"
    from bentray.engine.field import FieldArrays

    combined = FieldArrays(grid=first.grid, arrays=arrays, field_data=field_data, stats=stats, preview=preview)
    return combined


def _combine_receivers(job: Job, runs: list[ConditionRun], offsets: list[tuple[float, float, float]]) -> Any:
    first = runs[0].outcomes[0].receivers
    if first is None:
        return None
    from bentray.engine.beam_field import ReceiverTable

    base = ["id", "x_m", "y_m", "z_m"]
    per_condition: list[list[np.ndarray]] = []
    columns = list(base)
    values: dict[str, np.ndarray] = {}
    spl_cols = [c for c in first.columns if c.startswith("spl_inc_") or c == "spl_a_inc"]
    for run in runs:
        name = run.condition.name
        tables: list[Any] = [o.receivers for o in run.outcomes]
        for col in spl_cols:
            key = f"{col}__{name}"
            values[key] = energy_sum([np.array([row[col] for row in t.rows], float) for t in tables])
            columns.append(key)
        per_condition.append([np.array([row["spl_a_inc"] for row in t.rows], float) for t in tables])
    indicators = _period_levels(job, per_condition, offsets)
    columns += list(indicators)
    values.update(indicators)
    rows = []
    for i, row in enumerate(first.rows):
        out = {k: row[k] for k in base}
        out.update({k: float(values[k][i]) for k in columns if k not in base})
        rows.append(out)
    stats = dict(first.stats)
    stats["levels"] = "incoherent levels per condition (spl_*_inc__<condition>) and l_day/l_evening/l_night/l_den"
    return ReceiverTable(columns, rows, stats)


def run_conditions(job: Job, base_dir: Path | None, *, progress: ProgressFn, executor: Executor) -> JobOutcome:
    """Run every condition of ``job`` (see the module docstring) and combine them into one outcome."""
    t0 = time.perf_counter()
    scene_log = StageLog()
    progress("scene", 0.0)
    local, frame, surfaces = prepare_scene(job, base_dir, scene_log)
    groups = emission_groups(local)
    offsets = [g[0] for g in groups]
    media_by_key: dict[str, tuple[str, Prepared]] = {}
    runs: list[ConditionRun] = []
    n_steps = len(local.conditions) * len(groups)
    for c, cond in enumerate(local.conditions):
        cjob = condition_job(local, cond)
        key = medium_key(cjob)
        reused_from = None
        if key in media_by_key:
            reused_from, base = media_by_key[key]
            prepared = Prepared(cjob, frame, base.profile, base.wind, surfaces, base.media, base.log)
        else:
            log = scene_log.copy()
            profile, wind, media = prepare_medium(cjob, base_dir, surfaces, log, lambda s, f: None)
            prepared = Prepared(cjob, frame, profile, wind, surfaces, media, log)
            media_by_key[key] = (cond.name, prepared)
        outcomes = []
        for g, (_, members) in enumerate(groups):
            step = c * len(groups) + g

            def sub_progress(stage: str, fraction: float, step: int = step) -> None:
                progress(stage, (step + fraction) / n_steps)

            gjob = cjob.model_copy(
                update={
                    "sources": [cjob.sources[i] for i in members],
                    "eigenrays": cjob.eigenrays.model_copy(update={"enabled": "off"}),
                }  # fmt: skip
            )
            sub = Prepared(gjob, frame, prepared.profile, prepared.wind, surfaces, prepared.media, prepared.log)
            outcomes.append(run_prepared(sub, progress=sub_progress, executor=executor))
        runs.append(ConditionRun(cond, outcomes, reused_from))
    return _combine(local, runs, groups, offsets, time.perf_counter() - t0)


def _combine(
    job: Job,
    runs: list[ConditionRun],
    groups: list[tuple[tuple[float, float, float], list[int]]],
    offsets: list[tuple[float, float, float]],
    wall_s: float,
) -> JobOutcome:
    parts = []
    ray_ranges: dict[str, list[list[int]]] = {}
    start = 0
    for run in runs:
        ray_ranges[run.condition.name] = []
        for (_, members), outcome in zip(groups, run.outcomes, strict=True):
            trace = outcome.trace
            trace.source = np.asarray(members, np.int64)[trace.source]  # back to the job's source indices
            parts.append(trace)
            ray_ranges[run.condition.name].append([start, start + trace.n_rays])
            start += trace.n_rays
    first = runs[0].outcomes[0]
    report = dict(first.report)
    report["stages"] = dict(first.report["stages"])
    report["stages"]["conditions"] = (
        f"ran: {len(runs)} conditions x {len(groups)} emission groups; "
        f"{sum(r.mesh_reused_from is None for r in runs)} media meshes built, "
        f"{sum(r.mesh_reused_from is not None for r in runs)} reused; eigenrays skipped in condition runs"
    )
    report["stages"]["eigenrays"] = "skipped: not run per condition (run a job without conditions for arrivals)"
    report["conditions"] = {
        run.condition.name: {
            "occurrence": run.condition.occurrence.model_dump(),
            "mesh": f"reused from condition {run.mesh_reused_from!r}" if run.mesh_reused_from else "built",
            "profile": run.outcomes[0].report["profile"],
            "wind": run.outcomes[0].report.get("wind"),
            "groups": [
                {
                    "sources": members,
                    "period_offsets_db": list(off),
                    "rays": ray_ranges[run.condition.name][g],
                    "timings_s": o.report["timings_s"],
                    "stages": o.report["stages"],
                }
                for g, ((off, members), o) in enumerate(zip(groups, run.outcomes, strict=True))
            ],
        }
        for run in runs
    }
    report["periods"] = job.periods.model_dump(mode="json")
    report["rays_note"] = "rays.csv lists the rays of every condition and group in the order of report.conditions"
    trace = concat_traces(parts)
    report["rays"] = dict(report["rays"])
    report["rays"].update(
        {
            "total": trace.n_rays,
            "by_status": trace.status_counts(),
            "reflections_total": int(trace.reflections.sum()),
            "tet_crossings_total": int(trace.crossings.sum()),
        }
    )
    report["timings_s"] = dict(first.report["timings_s"])
    report["timings_s"]["conditions_total"] = wall_s
    field = _combine_fields(job, runs, offsets)
    if field is not None:
        report["field"] = field.stats
    receivers = _combine_receivers(job, runs, offsets)
    if receivers is not None:
        report["receivers"] = receivers.stats
    return JobOutcome(
        trace=trace,
        mesh_geometry=first.mesh_geometry,
        report=report,
        field=field,
        receivers=receivers,
        arrivals=None,
    )

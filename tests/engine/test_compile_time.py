"""Compilation time measured from numba's compile events (engine/compile_time.py) and reported per stage.

A fresh, uncached function compiles inside the timer (counted, with positive seconds) and not on its
second call; a job's report carries ``compile_s`` (per compiling stage plus ``total``) beside timings_s.
"""

from __future__ import annotations

import numba

from bentray.engine.compile_time import compile_timer


def _fresh_function():  # a new dispatcher each call: never in any cache
    @numba.jit(nopython=True, cache=False)
    def add_one(x):
        return x + 1.0

    return add_one


def _tiny_job():
    """A three-ray job over flat ground (a second or less once the kernels are cached)."""
    from bentray.scenes.schema import Job

    return Job.model_validate(
        {
            "name": "tiny",
            "scene": {"domain": {"min": [-50, -50, 0], "max": [400, 50, 200]}, "ground": {"kind": "flat"}},
            "profile": {"kind": "homogeneous"},
            "sources": [{"position": [0, 0, 1.5]}],
            "rays": {"elevation_deg": {"min": -10, "max": 10, "count": 3}, "max_time_s": 0.5, "max_reflections": 2},
            "outputs": ["report"],
        }
    )


def test_a_compile_is_timed_and_a_second_call_is_not() -> None:
    fn = _fresh_function()
    with compile_timer() as first:
        assert fn(1.0) == 2.0
    assert first.functions >= 1 and first.seconds > 0.0
    with compile_timer() as second:
        assert fn(2.0) == 3.0
    assert second.functions == 0 and second.seconds == 0.0


def test_nested_timers_both_see_the_compile_and_time_it_once() -> None:
    fn = _fresh_function()
    with compile_timer() as outer:
        with compile_timer() as inner:
            fn(1.0)
    assert inner.functions == outer.functions >= 1
    assert abs(inner.seconds - outer.seconds) <= 1e-3 * max(outer.seconds, 1.0)


def test_stage_log_records_compile_seconds_of_the_stage_only() -> None:
    from bentray.engine.stages import StageLog

    log = StageLog()
    with log.timed("quiet"):
        pass
    fn = _fresh_function()
    with log.timed("compiles"):
        fn(1.0)
    assert "quiet" not in log.compile_s
    assert 0.0 < log.compile_s["compiles"] <= log.timings["compiles"]
    assert log.compiled_functions >= 1


def test_report_has_compile_seconds_beside_the_timings() -> None:
    from bentray.engine.run import run_job

    job = _tiny_job()
    report = run_job(job).report
    compiled = report["compile_s"]
    assert set(compiled) <= set(report["timings_s"]) | {"total"}
    assert compiled["total"] == sum(v for k, v in compiled.items() if k != "total")
    for stage, seconds in compiled.items():
        if stage != "total":
            assert 0.0 <= seconds <= report["timings_s"][stage]
    assert report["compiled_functions"] >= 0


def test_stage_log_compiling_counts_a_self_timed_stage() -> None:
    """A stage that sets its own timing (diffraction, terrain screening, wave, shadow) gets its compilation
    counted, and its time raised to include it when the compile fell outside its own clock."""
    from bentray.engine.stages import StageLog

    log = StageLog()
    fn = _fresh_function()
    with log.compiling("self_timed"):
        fn(1.0)
        log.timings["self_timed"] = 1e-9  # the stage's own clock missed the compile
    assert log.compile_s["self_timed"] > 0.0
    assert log.compile_s["self_timed"] <= log.timings["self_timed"]
    with log.compiling("nothing"):
        pass
    assert "nothing" not in log.compile_s and "nothing" not in log.timings


def test_report_keeps_the_mesh_stage_compile() -> None:
    """run_prepared carries the compilation of the stages before it (scene, profile, mesh) into the report: it
    used to start a new log with their timings only, and a first run's mesh-kernel compilation was lost."""
    from bentray.engine.executors import LocalExecutor
    from bentray.engine.run import Prepared, prepare_medium, prepare_scene, run_prepared
    from bentray.engine.stages import StageLog

    job = _tiny_job()
    log = StageLog()
    job, frame, surfaces = prepare_scene(job, None, log)
    profile, wind, media = prepare_medium(job, None, surfaces, log, lambda stage, fraction: None)
    log.timings["mesh"] = 1.0  # as if the mesh stage had compiled its kernels for 0.25 s of its 1 s
    log.compile_s["mesh"] = 0.25
    log.compiled_functions += 3
    before = log.compiled_functions
    outcome = run_prepared(
        Prepared(job, frame, profile, wind, surfaces, media, log), progress=lambda s, f: None, executor=LocalExecutor()
    )
    assert outcome.report["compile_s"]["mesh"] == 0.25
    assert outcome.report["compiled_functions"] >= before

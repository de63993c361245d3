"""`bentray warmup`: miniature copies of the jobs, and a second run that compiles nothing."""

from __future__ import annotations

import json
import re

from bentray.clients.cli import main
from bentray.clients.warmup_cli import MAX_COUNT, MAX_FIELD_POINTS, miniature, warmup_specs

JOB = {
    "name": "tiny",
    "scene": {"domain": {"min": [-50, -50, 0], "max": [400, 50, 200]}, "ground": {"kind": "flat"}},
    "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
    "sources": [{"position": [0, 0, 1.5]}],
    "rays": {"elevation_deg": {"min": -10, "max": 10, "count": 41}, "max_time_s": 0.5, "max_reflections": 2},
    "field": {"origin": [0, -20, 1], "spacing": [20, 20, 5], "shape": [10, 3, 8], "frequencies_hz": [500]},
    "outputs": ["field", "report"],
}


def test_miniature_shrinks_the_fan_and_the_grid_only() -> None:
    mini = miniature(JOB)
    assert mini["rays"]["elevation_deg"]["count"] == MAX_COUNT
    assert mini["field"]["shape"] == [MAX_FIELD_POINTS, 3, MAX_FIELD_POINTS]

    # the same extent: first and last points where the full grid has them
    def last(f):
        return [o + (n - 1) * h for o, n, h in zip(f["origin"], f["shape"], f["spacing"], strict=True)]

    assert mini["field"]["origin"] == JOB["field"]["origin"]
    assert last(mini["field"]) == [float(v) for v in last(JOB["field"])]
    assert mini["profile"] == JOB["profile"] and mini["outputs"] == JOB["outputs"]
    assert JOB["rays"]["elevation_deg"]["count"] == 41  # the input is not changed


def test_the_builtin_list_holds_the_readme_example_and_every_builtin_scene() -> None:
    from bentray.scenes.library.registry import BUILTIN_SCENES

    labels = [label for label, _, _ in warmup_specs([], builtin=True)]
    assert "example ridge-wind-map.json" in labels
    assert {f"scene {name}" for name in BUILTIN_SCENES} <= set(labels)


def test_warmup_then_nothing_left_to_compile(tmp_path, capsys) -> None:
    job = tmp_path / "job.json"
    job.write_text(json.dumps(JOB))
    assert main(["warmup", "--no-builtin", str(job)]) == 0
    first = capsys.readouterr().out
    assert re.search(r"job\.json: [\d.]+ s, compiled \d+ function\(s\) in [\d.]+ s", first), first
    assert main(["warmup", "--no-builtin", str(job)]) == 0
    second = capsys.readouterr().out
    assert "compiled 0 function(s) in 0.0 s" in second, second


def test_an_unreadable_job_exits_2(tmp_path, capsys) -> None:
    assert main(["warmup", "--no-builtin", str(tmp_path / "missing.json")]) == 2
    assert "cannot read the job" in capsys.readouterr().err

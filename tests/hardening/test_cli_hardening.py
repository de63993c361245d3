"""Issue 15, ``bentray run``: bad files exit 2 naming the field (never a traceback, never exit 1), the
1e308 footprint answers at once, SIGTERM leaves no staging folder beside --out, and a hypothesis
property test of the job schema through ``bentray run --check``."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from bentray.clients.cli import main
from tests.hardening.conftest import HILL, REPO, base_job, below_terrain_job, huge_footprint_job, overlapping_job

FIELD_LINE = re.compile(r"^[\w.]*\w[\w.]*: \S|^[\w.]*\.: \S")  # "field.path: reason" (keys may be empty)


def _run(tmp_path: Path, job: dict | str, capsys, *extra: str) -> tuple[int, str]:
    path = tmp_path / "job.json"
    path.write_text(job if isinstance(job, str) else json.dumps(job), encoding="utf-8")
    rc = main(["run", str(path), "--out", str(tmp_path / "out"), *extra])
    return rc, capsys.readouterr().err


def _field_lines(err: str) -> list[str]:
    return [line for line in err.splitlines()[1:] if line.strip()]


def test_huge_footprint_exits_2_within_a_second(tmp_path, capsys):
    _run(tmp_path, "{}", capsys)  # imports (pydantic models, numpy) are not part of the answer time
    t0 = time.perf_counter()
    rc, err = _run(tmp_path, huge_footprint_job(), capsys)
    assert time.perf_counter() - t0 < 1.0
    assert rc == 2 and "scene.buildings.footprints.0.polygon.0.0: " in err


def test_huge_footprint_does_not_hang_the_console_command(tmp_path):
    """Without pytest's warnings-as-errors the overflow used to spin in the overlap check forever."""
    (tmp_path / "job.json").write_text(json.dumps(huge_footprint_job()))
    cmd = [sys.executable, "-m", "bentray.clients.cli", "run", str(tmp_path / "job.json"), "--out", str(tmp_path / "o")]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "scene.buildings.footprints.0.polygon.0.0: " in proc.stderr


@pytest.mark.parametrize(
    "text, field",
    [
        ("[" * 10_000 + "]" * 10_000, "the JSON nests deeper than 64 levels"),
        ('{"name": ' + "9" * 5000 + "}", "an integer of 5,000 digits"),
    ],
    ids=["deep", "huge-int"],
)
def test_unreadable_json_exits_2(tmp_path, capsys, text, field):
    rc, err = _run(tmp_path, text, capsys)
    assert rc == 2 and field in err and "Traceback" not in err


def test_nul_file_name_and_overflowing_shape_exit_2(tmp_path, capsys):
    job = base_job()
    job["scene"]["terrain"] = {"file": "hill\u0000.asc"}
    rc, err = _run(tmp_path, job, capsys)
    assert rc == 2 and "scene.terrain.file: " in err
    job = base_job()
    job["field"] = {"origin": [0, 0, 1], "spacing": [1, 1, 1], "shape": [2**62, 4, 1]}
    rc, err = _run(tmp_path, job, capsys)
    assert rc == 2 and "field.shape.0: " in err and "Traceback" not in err


def test_scene_errors_exit_2_with_the_field(tmp_path, capsys):
    (tmp_path / "hill.asc").write_bytes(HILL.read_bytes())
    rc, err = _run(tmp_path, below_terrain_job(), capsys, "--check")
    assert rc == 2 and _field_lines(err)[0].startswith("sources.0.position: (0, 0, 1) is ")
    rc, err = _run(tmp_path, overlapping_job(), capsys, "--check")
    assert rc == 2 and _field_lines(err) == [
        "scene.buildings.footprints.0 overlaps scene.buildings.footprints.1; footprints may touch but not overlap"
    ]
    job = base_job()
    job["profile"]["b"] = -1e6
    rc, err = _run(tmp_path, job, capsys, "--check")
    assert rc == 2 and _field_lines(err)[0].startswith("profile.b: ")
    rc, err = _run(tmp_path, base_job(), capsys, "--check")
    assert rc == 0 and not (tmp_path / "out").exists()


def test_sigterm_during_the_write_leaves_no_staging_folder(tmp_path):
    job = base_job()
    job["rays"]["elevation_deg"]["count"] = 5
    (tmp_path / "job.json").write_text(json.dumps(job))
    script = textwrap.dedent(
        f"""
        import os, signal, sys, time
        from bentray.engine import writers
        from bentray.clients.cli import main
        real = writers.write_rays_csv
        def slow(trace, path):
            real(trace, path)
            os.kill(os.getpid(), signal.SIGTERM)  # the stop arrives while the outputs are being staged
            time.sleep(5)
        writers.write_rays_csv = slow
        sys.exit(main(["run", {str(tmp_path / "job.json")!r}, "--out", {str(tmp_path / "out")!r}]))
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 143, (proc.returncode, proc.stderr[-2000:])
    assert "terminated" in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["job.json"]  # no .out.*.tmp, no half-written out/


# ---------------------------------------------------------------------------------------------
# Property: any job-shaped input through bentray run's validation exits 0 or 2, never a traceback
# ---------------------------------------------------------------------------------------------
_KEY_CHARS = "abcdefghijklmnopqrstuvwxyz_0123456789"
_NUMBERS = st.one_of(
    st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=False, allow_infinity=False),
    st.sampled_from([0, -1, 1e308, -1e308, 5e-324, 2**32, 2**63, 10**25]),
)
_LEAVES = st.one_of(_NUMBERS, st.booleans(), st.none(), st.text(max_size=8))
_VALUES = st.recursive(
    _LEAVES,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(_KEY_CHARS, max_size=6), inner, max_size=3),
    max_leaves=12,
)


def _paths(value, prefix=()):
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _paths(v, (*prefix, i))


_BASE = base_job()
_BASE_PATHS = [p for p in _paths(_BASE) if p]


@st.composite
def mutated_jobs(draw):
    job = base_job()
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(_BASE_PATHS))
        target = job
        try:
            for key in path[:-1]:
                target = target[key]
            target[path[-1]] = draw(_VALUES)
        except (KeyError, IndexError, TypeError):
            pass
    return job


@settings(
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
    phases=[Phase.explicit, Phase.reuse, Phase.generate, Phase.shrink],  # no explain phase (libcst warnings)
)
@given(mutated_jobs())
def test_bentray_run_validation_property(tmp_path, capsys, job):
    rc, err = _run(tmp_path, job, capsys, "--check")
    assert "Traceback" not in err
    assert rc in (0, 2), err
    if rc == 2:
        lines = _field_lines(err) or err.splitlines()
        assert lines and all(FIELD_LINE.match(line) for line in lines), err

"""preview.png drawn in a child process (engine/preview_process.py).

Oracle: the same outcome written without a worker (the parent draws with ``write_preview_png``): the child's
file must be byte-identical, and every failure of the child (cannot start, dies, hangs, answers nonsense)
must give that same file from the parent, with the reason, and leave no process behind.
"""

from __future__ import annotations

import json
import re
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from bentray.engine import preview_process
from bentray.engine.field import FieldArrays
from bentray.engine.field_buffers import FieldGrid
from bentray.engine.preview_process import PreviewWorker
from bentray.engine.result import JobOutcome
from bentray.engine.writers import write_outcome
from tests.engine.test_writers import _trace


def _field_outcome(shape=(24, 10, 6), bad_ground: bool = False) -> JobOutcome:
    rng = np.random.default_rng(3)
    grid = FieldGrid(origin=np.array([-100.0, -40.0, 0.0]), spacing=np.array([10.0, 8.0, 5.0]), shape=shape)
    spl = 40.0 + 40.0 * rng.random(shape)
    spl[0, 0, 0] = np.nan  # a point without a level
    preview = {"source_xyz": [0.0, 0.0, 2.0], "receiver_z": 4.0, "title": "child test"}
    if bad_ground:  # field.vti is fine; the preview's ground heights cannot be shaped (nx, ny)
        preview.update(ground_z=np.zeros(7), receiver_height_m=2.0)
    field = FieldArrays(grid=grid, arrays={"spl_a": spl}, field_data={}, stats={}, preview=preview)
    return JobOutcome(trace=_trace(False), mesh_geometry=None, report={"job": "preview"}, field=field)


@pytest.fixture(scope="module")
def parent_png(tmp_path_factory) -> bytes:
    out = tmp_path_factory.mktemp("parent") / "res"
    write_outcome(_field_outcome(), ["field", "report"], out)
    return (out / "preview.png").read_bytes()


def _no_warning_write(outcome, out, worker):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a fallback warns: here it must not happen
        return write_outcome(outcome, ["field", "report"], out, preview_worker=worker)


def test_child_draws_the_same_file(tmp_path, parent_png):
    worker = PreviewWorker.start()
    written = _no_warning_write(_field_outcome(), tmp_path / "res", worker)
    assert [p.name for p in written] == ["field.vti", "preview.png", "report.json"]
    assert worker.fallback_reason is None
    assert worker.process is not None and worker.process.returncode == 0  # it ran and answered "ok"
    assert (tmp_path / "res" / "preview.png").read_bytes() == parent_png
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"]  # staging (and the request pickle) removed


@pytest.mark.parametrize(
    ("command", "reason"),
    [
        ([sys.executable, "-c", "import sys; sys.exit(3)"], "exited early|status 3"),
        ([sys.executable, "-c", "import sys; sys.stdin.readline(); print('maybe')"], "failed.*maybe"),
        ([sys.executable, "-c", "import sys, time; sys.stdin.readline(); time.sleep(60)"], "did not answer"),
        (["/nonexistent/python-for-bentray"], "did not start"),
    ],
    ids=["dies", "nonsense", "hangs", "cannot-start"],
)
def test_failed_child_falls_back_to_the_parent(tmp_path, parent_png, command, reason):
    worker = PreviewWorker.start(command=command, timeout_s=2.0)
    if "exit(3)" in " ".join(command) and worker.process is not None:
        worker.process.wait(timeout=10)  # make the early exit certain before the request
    with pytest.warns(RuntimeWarning, match="drawn in this process"):
        write_outcome(_field_outcome(), ["field", "report"], tmp_path / "res", preview_worker=worker)
    assert worker.fallback_reason is not None
    assert re.search(reason, worker.fallback_reason), worker.fallback_reason
    assert (tmp_path / "res" / "preview.png").read_bytes() == parent_png
    assert worker.process is None or worker.process.poll() is not None  # nothing left running


def test_bad_data_raises_the_parents_error_and_writes_nothing(tmp_path):
    worker = PreviewWorker.start()
    out = tmp_path / "res"
    with pytest.raises(ValueError, match="cannot reshape array of size 7"):
        with pytest.warns(RuntimeWarning, match=r"failed \(status 1\): error ValueError: cannot reshape"):
            write_outcome(_field_outcome(bad_ground=True), ["field", "report"], out, preview_worker=worker)
    assert list(tmp_path.iterdir()) == []  # neither res/ nor the staging directory
    assert worker.process is not None and worker.process.poll() is not None


def test_close_stops_a_waiting_child():
    worker = PreviewWorker.start()
    assert worker.process is not None and worker.process.poll() is None  # waiting for a request
    worker.close()
    assert worker.process.poll() is not None
    worker.close()  # idempotent


def test_child_without_a_request_exits_cleanly():
    worker = PreviewWorker.start()
    assert worker.process is not None and worker.process.stdin is not None
    worker.process.stdin.close()  # the parent's job failed: end of input, no request
    assert worker.process.wait(timeout=60) == 0
    worker.close()


@pytest.mark.parametrize(
    ("text", "started"),
    [
        (json.dumps({"outputs": ["field", "report"]}), True),
        (json.dumps({"outputs": ["rays", "report"]}), False),
        (json.dumps({"name": "no outputs: the default has no field"}), False),
        ("{not json", False),
        ("[" * 100_000, False),  # nesting: the glance gives up, validation reports it
    ],
)
def test_cli_starts_the_child_only_for_a_field(tmp_path, monkeypatch, text, started):
    from bentray.clients import cli

    calls: list[object] = []
    monkeypatch.setattr(preview_process.PreviewWorker, "start", classmethod(lambda cls: calls.append(cls)))
    job = tmp_path / "job.json"
    job.write_text(text)
    cli._start_preview(job)
    assert bool(calls) is started
    assert cli._start_preview(Path(tmp_path / "missing.json")) is None


def test_working_directory_cannot_shadow_the_childs_imports(tmp_path, monkeypatch, parent_png):
    """``python -P``: a matplotlib.py where the user runs bentray is not imported by the child."""
    (tmp_path / "matplotlib.py").write_text("raise SystemExit(7)\n")
    monkeypatch.chdir(tmp_path)
    worker = PreviewWorker.start()
    _no_warning_write(_field_outcome(), tmp_path / "res", worker)
    assert worker.fallback_reason is None
    assert (tmp_path / "res" / "preview.png").read_bytes() == parent_png

"""Scale-out on Dask distributed: a 2-process LocalCluster against the local executor (the oracle).

Rays are traced independently, so a ray traced on a worker must be bit-for-bit the ray traced here.
The field is summed in batch order on every executor; inside a batch the slots follow the numba thread
count, so: equal thread counts -> bit-for-bit equal fields; different counts -> equal to 1e-12 relative
(the documented tolerance; measured <= 1e-14, and p_re/p_im relative to |p|: a part near zero
alone differs by up to 5e-13 of itself). A worker killed while batches run must not change the
result (the scheduler reschedules its batch). The sweep command is checked against direct runs.
"""

from __future__ import annotations

import copy
import csv
import importlib
import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from bentray.clients.cli import dask_address, main  # noqa: E402
from bentray.clients.sweep_cli import SweepError, parse_values, set_dotted  # noqa: E402
from bentray.engine.batches import BatchResult  # noqa: E402
from bentray.engine.dask_executor import (  # noqa: E402
    DaskExecutor,
    InOrderSum,
    aligned_arrays,
    disconnect,
    task_numba_threads,
)
from bentray.engine.executors import LocalExecutor, make_executor  # noqa: E402
from bentray.engine.field_buffers import FieldBuffers, FieldGrid  # noqa: E402
from bentray.engine.run import run_job  # noqa: E402
from bentray.engine.trace_plan import BaselineSpec, TracePlan  # noqa: E402
from bentray.scenes.schema import Job  # noqa: E402
from bentray.service.settings import Settings  # noqa: E402

FIELD_RTOL = 1e-12  # different numba thread counts reorder the per-batch slot sums (engine/dask_executor.py)
RAY_FIELDS = ("position", "direction", "time_s", "length_m", "reflections", "status", "crossings")


def _spec(
    mode: str = "incoherent", sources: list[list[float]] | None = None, el: int = 31, az: int = 21, **solver
) -> dict:
    return {
        "name": "dask",
        "scene": {
            "domain": {"min": [-20, -60, 0], "max": [300, 60, 120]},
            "ground": {"kind": "flat", "flow_resistivity": 200.0},
        },
        "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
        "sources": [{"position": p} for p in (sources or [[0.0, 0.0, 2.0]])],
        "rays": {
            "elevation_deg": {"min": -30, "max": 30, "count": el},
            "azimuth_deg": {"min": -20, "max": 20, "count": az},
            "max_time_s": 1.0,
            "max_reflections": 4,
        },
        "solver": solver,
        "field": {
            "origin": [10, -20, 1],
            "spacing": [10, 10, 2],
            "shape": [25, 5, 3],
            "frequencies_hz": [125, 1000],
            "mode": mode,
            "method": "voxels",  # the voxel accumulator (beams: one batch per source)
        },
        "outputs": ["rays", "field", "report"],
    }


def _job(*args, **kwargs) -> Job:
    return Job.model_validate(_spec(*args, **kwargs))


def _assert_same(local, other, rtol: float) -> None:
    for name in RAY_FIELDS:
        np.testing.assert_array_equal(getattr(local.trace, name), getattr(other.trace, name), err_msg=name)
    assert local.field.arrays.keys() == other.field.arrays.keys()
    for key, arr in local.field.arrays.items():
        got = other.field.arrays[key]
        finite = np.isfinite(arr)
        np.testing.assert_array_equal(finite, np.isfinite(got), err_msg=key)
        if rtol == 0.0:
            np.testing.assert_array_equal(got, arr, err_msg=key)
        elif key.startswith(("p_re_", "p_im_")):  # a part of p near zero: relative to |p| (measured 3e-15)
            band = key[5:]
            amplitude = np.hypot(local.field.arrays["p_re_" + band], local.field.arrays["p_im_" + band])
            assert np.all(np.abs(got[finite] - arr[finite]) <= rtol * amplitude[finite]), key
        else:
            np.testing.assert_allclose(got[finite], arr[finite], rtol=rtol, atol=0.0, err_msg=key)


@pytest.fixture(scope="module")
def local_runs() -> dict[str, object]:
    # traced first, here: compiles (or loads) the kernels into the numba cache the workers then load
    return {mode: run_job(_job(mode, batch_rays=100), executor=LocalExecutor()) for mode in ("incoherent", "coherent")}


@pytest.fixture(scope="module")
def client(local_runs):
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    dask_client = distributed.Client(cluster, set_as_default=False)
    dask_client.run(importlib.import_module, "bentray.engine.run")  # import (and set the numba cache) now
    yield dask_client
    disconnect(cluster.scheduler_address)
    dask_client.close()
    cluster.close()


# --- no cluster needed --------------------------------------------------------------------------
def test_batches_never_straddle_sources():
    n_per, n_src = 7, 3
    z = np.zeros((n_per * n_src, 3))
    plan = TracePlan(
        mesh=None,
        curve="parabolic",
        c_ref=340.0,
        wind=None,
        origins=z,
        directions=z,
        start_cells=np.zeros(n_per * n_src, np.int64),
        max_time_s=1.0,
        max_reflections=1,
        max_steps=1,
        path_samples=0,
        source=np.repeat(np.arange(n_src), n_per),
    )
    assert plan.batches(3) == [(0, 3), (3, 6), (6, 7), (7, 10), (10, 13), (13, 14), (14, 17), (17, 20), (20, 21)]
    assert plan.batches(100) == [(0, 7), (7, 14), (14, 21)]
    plan.source = None  # no source index: plain blocks
    assert plan.batches(10) == [(0, 10), (10, 20), (20, 21)]


def test_in_order_sum_gives_the_bits_of_summing_at_the_end():
    # partial fields pushed out of order (as Dask returns them) must be added in batch order
    rng = np.random.default_rng(7)
    grid = FieldGrid(np.zeros(3), np.ones(3), (4, 3, 2))

    def parts() -> list[BatchResult]:
        out = []
        for a in range(0, 60, 10):
            buf = FieldBuffers(
                "incoherent",
                grid,
                np.zeros((0, 2)),
                np.zeros(2),
                np.arange(2),
                np.ones((1, 2, 2, 2)),
                np.array([0.0, 1.0, 0.0, 1.0]),
                1.0,
                n_slots=1,
            )
            buf.energy[:] = rng.lognormal(0.0, 8.0, buf.energy.shape)  # wide range: order changes the bits
            buf.hits[:] = rng.integers(0, 5, buf.hits.shape)
            out.append(BatchResult(a, a + 10, trace=None, field=buf))
        return out

    base = parts()
    fresh = lambda: [BatchResult(p.start, p.stop, None, copy.deepcopy(p.field)) for p in base]  # noqa: E731
    pushed = fresh()
    fold = InOrderSum([(p.start, p.stop) for p in pushed])
    for i in (3, 1, 0, 5, 2, 4):
        fold.push(pushed[i])
    assert [p.field is not None for p in pushed] == [True] + [False] * 5
    at_end = fresh()
    for p in at_end[1:]:
        at_end[0].field.add(p.field)
    np.testing.assert_array_equal(pushed[0].field.energy, at_end[0].field.energy)
    np.testing.assert_array_equal(pushed[0].field.hits, at_end[0].field.hits)
    backwards = fresh()[::-1]
    for p in backwards[1:]:
        backwards[0].field.add(p.field)
    assert not np.array_equal(backwards[0].field.energy, at_end[0].field.energy)  # order matters: the check can fail


def test_unaligned_arrays_are_realigned():
    # Dask can hand a task views at odd byte offsets; numba would compile every kernel again for them
    raw = np.frombuffer(bytearray(8 * 12 + 1), dtype=np.float64, offset=1, count=12)
    assert not raw.flags.aligned
    grid = FieldGrid(raw[:3], np.ones(3), (1, 1, 1))
    plan = TracePlan(
        mesh=(raw.reshape(3, 4), np.zeros(2)),
        curve="parabolic",
        c_ref=340.0,
        wind=(0, raw),
        origins=raw.reshape(4, 3),
        directions=np.zeros((4, 3)),
        start_cells=np.zeros(4, np.int64),
        max_time_s=1.0,
        max_reflections=1,
        max_steps=1,
        path_samples=0,
        baseline=BaselineSpec("rk4", "mesh", "n2", (0, raw), 1.0, 1e-8, raw[:3], np.ones(3), 0.0, "open"),
        field=grid,
    )
    out = aligned_arrays(plan)
    arrays = [
        out.mesh[0],
        out.wind[1],
        out.origins,
        out.baseline.exact_spec[1],
        out.baseline.domain_min,
        out.field.origin,
    ]
    assert all(a.flags.aligned for a in arrays)
    for a in arrays:
        np.testing.assert_array_equal(a.reshape(-1), raw[: a.size])
    assert out.directions is plan.directions  # aligned arrays are not copied


def test_task_threads_and_sweep_arguments():
    import numba  # after bentray: its import sets the (keyed) NUMBA_CACHE_DIR that worker processes share

    assert task_numba_threads(1, budget=8) == min(8, numba.config.NUMBA_NUM_THREADS)
    assert task_numba_threads(4, budget=2) == 1
    assert parse_values("-1,-0.5,0,on") == [("-1", -1), ("-0.5", -0.5), ("0", 0), ("on", "on")]
    with pytest.raises(SweepError):
        parse_values("1,,2")
    with pytest.raises(SweepError):
        parse_values("../x")
    spec = {"profile": {"b": 1.0}, "sources": [{"position": [0, 0, 1]}]}
    assert set_dotted(spec, "sources.0.position.2", 5.0)["sources"][0]["position"] == [0, 0, 5.0]
    assert set_dotted(spec, "solver.batch_rays", 10)["solver"] == {"batch_rays": 10}
    assert spec == {"profile": {"b": 1.0}, "sources": [{"position": [0, 0, 1]}]}  # not mutated
    with pytest.raises(SweepError, match="sources.3"):
        set_dotted(spec, "sources.3.position", 1)


# --- LocalCluster (2 worker processes) ---------------------------------------------------------
@pytest.mark.parametrize("mode", ["incoherent", "coherent"])
def test_same_field_and_rays_as_local_with_progress_per_batch(client, local_runs, mode):
    import numba

    local = local_runs[mode]
    stages: list[tuple[str, float]] = []
    # same numba thread count per batch as here: bit-for-bit the local result
    same = run_job(
        _job(mode, batch_rays=100),
        executor=DaskExecutor(client, numba_threads=numba.get_num_threads()),
        progress=lambda s, f: stages.append((s, f)),
    )
    _assert_same(local, same, rtol=0.0)
    assert same.report["batches"] == {"count": 7, "batch_rays": 100, "executor": "dask"}
    assert "2 worker(s)" in same.report["stages"]["trace"]
    fractions = [f for _, f in stages]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    assert sum(1 for s, _ in stages if s == "trace") == 1 + 7  # start + one per finished batch
    # one numba thread per batch (other slot order) and another batching: the documented tolerance
    other = run_job(_job(mode, batch_rays=250), executor=DaskExecutor(client, numba_threads=1))
    _assert_same(local, other, rtol=FIELD_RTOL)


@pytest.mark.slow  # 11 s warm (+8 s of its own local runs)
def test_many_sources_fan_out_as_separate_tasks(client):
    # 200 sources x 6 rays: one batch per source (ranges never straddle sources), every ray counted
    xs = np.linspace(0.0, 200.0, 200)
    sources = [[float(x), float(10.0 * np.sin(x)), 2.0] for x in xs]
    job = _job(sources=sources, el=3, az=2)
    local = run_job(job, executor=LocalExecutor())
    dask = run_job(job, executor=DaskExecutor(client, numba_threads=1))
    assert dask.report["batches"]["count"] == 200
    assert dask.report["rays"]["total"] == 1200 == sum(dask.report["rays"]["by_status"].values())
    np.testing.assert_array_equal(dask.trace.source, np.repeat(np.arange(200), 6))
    _assert_same(local, dask, rtol=FIELD_RTOL)


def test_worker_killed_mid_job_is_rescheduled(client, local_runs):
    pids = client.run(os.getpid)  # worker address -> process id
    killed: dict[str, object] = {}
    progress: list[float] = []

    def on_progress(stage: str, fraction: float) -> None:
        if stage != "trace":
            return
        progress.append(fraction)
        if len(progress) < 2 or killed:  # after the first finished batch, once
            return
        busy = [addr for addr, keys in client.processing().items() if keys and addr in pids]
        if busy:
            killed["keys"] = list(client.processing()[busy[0]])
            killed["pid"] = pids[busy[0]]
            os.kill(pids[busy[0]], signal.SIGKILL)

    job = _job("incoherent", batch_rays=10)  # 66 batches: both workers stay busy for a while
    reference = run_job(job, executor=LocalExecutor())
    outcome = run_job(job, executor=DaskExecutor(client, numba_threads=1), progress=on_progress)
    assert killed.get("keys"), "no busy worker to kill: the job finished before the first batch was reported"
    assert killed["pid"] not in client.run(os.getpid).values()  # that process is gone (the nanny restarts one)
    assert len(progress) == 1 + 66
    _assert_same(reference, outcome, rtol=FIELD_RTOL)
    np.testing.assert_allclose(
        outcome.field.arrays["tl_1000hz"], local_runs["incoherent"].field.arrays["tl_1000hz"], rtol=FIELD_RTOL
    )


def test_scheduler_address_is_read_by_the_cli_and_the_service_settings(monkeypatch):
    # the engine reads no configuration: the CLI (and the service settings) turn the variable into an executor
    monkeypatch.setenv("BENTRAY_DASK_SCHEDULER", "tcp://from-env:8786")
    assert dask_address(None) == "tcp://from-env:8786"
    assert dask_address(" tcp://elsewhere:1 ") == "tcp://elsewhere:1"  # the flag wins
    assert Settings.from_env().dask_scheduler == "tcp://from-env:8786"
    monkeypatch.setenv("BENTRAY_DASK_SCHEDULER", "  ")
    assert dask_address(None) is None and Settings.from_env().dask_scheduler is None
    monkeypatch.delenv("BENTRAY_DASK_SCHEDULER")
    assert dask_address(None) is None and Settings.from_env().dask_scheduler is None


def test_scheduler_from_the_environment(client, local_runs, monkeypatch, tmp_path):
    monkeypatch.setenv("BENTRAY_DASK_SCHEDULER", client.scheduler.address)
    assert run_job(_job("incoherent", batch_rays=100)).report["batches"]["executor"] == "local"
    outcome = run_job(_job("incoherent", batch_rays=100), executor=make_executor(dask_address(None)))
    assert outcome.report["batches"]["executor"] == "dask"
    _assert_same(local_runs["incoherent"], outcome, rtol=FIELD_RTOL)
    job_path = tmp_path / "job.json"
    job_path.write_text(json.dumps(_spec(el=11, az=5)), encoding="utf-8")
    assert main(["run", str(job_path), "--out", str(tmp_path / "run")]) == 0  # no --dask: the variable
    report = json.loads((tmp_path / "run" / "report.json").read_text(encoding="utf-8"))
    assert report["batches"]["executor"] == "dask"


def test_run_and_sweep_commands_on_the_cluster(client, tmp_path, capsys):
    job_path = tmp_path / "job.json"
    job_path.write_text(json.dumps(_spec(el=11, az=5)), encoding="utf-8")
    address = client.scheduler.address
    assert main(["run", str(job_path), "--out", str(tmp_path / "run"), "--dask", address]) == 0
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    assert report["batches"]["executor"] == "dask" and report["rays"]["total"] == 55

    out = tmp_path / "sweep"
    assert (
        main(
            ["sweep", str(job_path), "--param", "profile.b", "--values", "-1,0,1", "--out", str(out), "--dask", address]
        )
        == 0
    )
    with open(out / "sweep.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["value"] for r in rows] == ["-1", "0", "1"]
    for row in rows:
        assert (out / f"profile.b={row['value']}" / "field.vti").is_file()
        direct = run_job(
            Job.model_validate(set_dotted(_spec(el=11, az=5), "profile.b", json.loads(row["value"]))),
            executor=LocalExecutor(),
        )
        assert int(row["rays_total"]) == 55 == sum(int(row[f"rays_{s}"]) for s in direct.trace.status_counts())
        for status, n in direct.trace.status_counts().items():
            assert int(row[f"rays_{status}"]) == n
        tl = direct.field.arrays["tl_1000hz"]
        assert row["field_array"] == "tl_1000hz"
        # csv keeps 6 decimals; the worker's field agrees to 1e-12 relative
        finite = tl[np.isfinite(tl)]
        assert abs(float(row["field_mean_db"]) + 10 * np.log10(np.mean(10 ** (-finite / 10)))) < 1e-5  # energy mean
    # the three profiles differ, so the sweep really set the parameter
    assert len({r["field_mean_db"] for r in rows}) == 3
    assert "3 jobs on Dask scheduler" in capsys.readouterr().out
    assert not Path(out / "profile.b=-1" / "rays.csv").stat().st_size == 0

"""The executor seam: the engine takes its executor from the caller (it reads no configuration)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from bentray.engine.executors import Executor, LocalExecutor, make_executor
from bentray.engine.trace_plan import BaselineSpec


def test_local_executor_is_the_default_and_satisfies_the_protocol(monkeypatch):
    monkeypatch.setenv("BENTRAY_DASK_SCHEDULER", "tcp://must-not-be-read:1")  # the engine ignores it
    for address in (None, "", "   "):
        executor = make_executor(address)
        assert isinstance(executor, LocalExecutor) and isinstance(executor, Executor)
    assert executor.name == "local" and "numba threads" in executor.describe()


def test_an_address_gives_the_dask_executor_without_connecting():
    pytest.importorskip("distributed")
    from bentray.engine.dask_executor import DaskExecutor

    executor = make_executor(" tcp://127.0.0.1:1 ")  # nothing listens there: construction must not connect
    assert isinstance(executor, DaskExecutor) and isinstance(executor, Executor)
    assert executor.address == "tcp://127.0.0.1:1" and executor.name == "dask"


def test_baseline_spec_is_typed_and_travels_by_pickle():
    spec = BaselineSpec("rk4", "mesh", "n2", None, 1.0, 1e-8, np.zeros(3), np.ones(3), 0.0, "open")
    back = pickle.loads(pickle.dumps(spec))
    assert back.method == "rk4" and back.exact_spec is None and back.top == "open"
    np.testing.assert_array_equal(back.domain_max, np.ones(3))
    with pytest.raises(AttributeError):
        spec.method = "euler"  # immutable

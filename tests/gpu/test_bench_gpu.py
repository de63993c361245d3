"""Issue 17: ``bentray bench --only gpu`` without a CUDA device says so and exits cleanly (status 0), building
nothing; with a device the section's table holds the CPU and GPU rows (tests/gpu/test_cuda_device.py covers the
kernel itself there)."""

from __future__ import annotations

import pytest

from bentray.clients.cli import main
from bentray.engine.gpu import device


def test_bench_gpu_without_a_device_says_so_and_exits_0(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(device, "cuda_status", lambda: (False, "no CUDA device (numba.cuda.is_available() is False)"))
    assert main(["bench", "--only", "gpu", "--quick", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "gpu: skipped: no CUDA device" in out
    report = (tmp_path / "report.md").read_text()
    assert "No CUDA device here" in report
    assert not list(tmp_path.glob("gpu*.csv"))  # no table: nothing was measured


def test_bench_gpu_under_the_simulator_is_not_a_device(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(device, "cuda_status", lambda: (True, "numba CUDA simulator (NUMBA_ENABLE_CUDASIM=1)"))
    monkeypatch.setenv("NUMBA_ENABLE_CUDASIM", "1")
    assert main(["bench", "--only", "gpu", "--quick", "--out", str(tmp_path)]) == 0
    assert "gpu: skipped: only numba's CUDA simulator is on" in capsys.readouterr().out


@pytest.mark.parametrize("requested, n, expected", [("cpu", 10**7, "cpu"), ("auto", 10, "cpu")])
def test_device_choice_without_a_device(requested, n, expected, monkeypatch):
    monkeypatch.setattr(device, "cuda_status", lambda: (False, "no CUDA device"))
    assert device.resolve_device(requested, n)[0] == expected


def test_cuda_without_a_device_is_an_error_naming_solver_device(monkeypatch):
    from bentray.engine.errors import JobInputError

    monkeypatch.setattr(device, "cuda_status", lambda: (False, "no CUDA device"))
    with pytest.raises(JobInputError, match=r"^solver\.device: 'cuda' cannot run here: no CUDA device"):
        device.resolve_device("cuda", 100)


def test_auto_picks_cuda_only_on_a_device_and_a_large_job(monkeypatch):
    monkeypatch.setattr(device, "cuda_status", lambda: (True, "CUDA device X"))
    monkeypatch.delenv("NUMBA_ENABLE_CUDASIM", raising=False)
    assert device.resolve_device("auto", device.AUTO_MIN_RAYS - 1)[0] == "cpu"
    assert device.resolve_device("auto", device.AUTO_MIN_RAYS)[0] == "cuda"


def test_cuda_for_a_job_with_a_voxel_field_or_paths_is_an_error_naming_solver_device():
    from types import SimpleNamespace

    from bentray.engine.batches import _on_cuda
    from bentray.engine.errors import JobInputError

    assert not _on_cuda(SimpleNamespace(device="cpu", field=object(), path_samples=0, n_rays=10))
    for plan in (
        SimpleNamespace(device="cuda", field=object(), path_samples=0, n_rays=10),
        SimpleNamespace(device="cuda", field=None, path_samples=400, n_rays=10),
    ):
        with pytest.raises(
            JobInputError, match=r"^solver\.device: 'cuda' traces final ray states and beam fields only"
        ):
            _on_cuda(plan)  # type: ignore[arg-type]
    # auto keeps such a job on the CPU without asking for a device
    assert not _on_cuda(SimpleNamespace(device="auto", field=object(), path_samples=0, n_rays=10**7))


def test_cuda_takes_a_beam_field_job(monkeypatch):
    from types import SimpleNamespace

    import numpy as np

    from bentray.engine.batches import _on_cuda
    from bentray.engine.beam_field import BeamBuffers, no_beam_args

    monkeypatch.setattr(device, "cuda_status", lambda: (True, "CUDA device X"))
    monkeypatch.delenv("NUMBA_ENABLE_CUDASIM", raising=False)
    g, _, t, pg, _, pts = no_beam_args()
    beams = BeamBuffers("incoherent", None, g, t, np.zeros((0, 1)), 1, pg, pts)
    assert _on_cuda(SimpleNamespace(device="cuda", field=beams, path_samples=0, n_rays=10))  # type: ignore[arg-type]
    assert _on_cuda(SimpleNamespace(device="auto", field=beams, path_samples=0, n_rays=device.AUTO_MIN_RAYS))  # type: ignore[arg-type]
    assert not _on_cuda(SimpleNamespace(device="auto", field=beams, path_samples=0, n_rays=10))  # type: ignore[arg-type]

"""Issue 17: the CUDA kernel compiles for a real device (sm_90 PTX) with every shared CPU-jitted step it calls,
beam hooks and float64 atomics included, without a device and without the simulator (``python -m
tests.gpu.ptx_check`` in a subprocess). Skipped when numba-cuda or NVRTC / NVVM (the nvidia-cuda-nvrtc /
nvidia-cuda-nvcc wheels) are missing. Several minutes on a loaded machine: slow."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("numba_cuda", reason="numba-cuda (the gpu extra) is not installed")

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_cuda_kernel_compiles_to_ptx_without_a_device():
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    proc = subprocess.run(
        [sys.executable, "-m", "tests.gpu.ptx_check"], cwd=REPO, env=env, capture_output=True, text=True, timeout=900
    )
    if proc.returncode != 0 and ("libnvrtc" in proc.stderr or "libnvvm" in proc.stderr):
        pytest.skip("NVRTC / NVVM not installed (pip install nvidia-cuda-nvrtc nvidia-cuda-nvcc)")
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["ptx_chars"] > 10_000
    # the beam accumulation is lowered to float64 atomics (weight, hits, energy, s_re, s_im; grid and receivers)
    assert out["f64_atomic_adds"] >= 5, out

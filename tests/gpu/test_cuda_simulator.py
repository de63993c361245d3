"""Issue 17: the CUDA traversal kernel (engine/gpu/kernel.py) against the CPU kernels, under numba's CUDA
simulator. Each case runs ``python -m tests.gpu.sim_compare CASE`` in a subprocess with NUMBA_ENABLE_CUDASIM=1,
so the simulator flag never reaches the rest of the suite. Slabs (A-LD, parabolic, ground reflections), slabs
traced with the circular curve in a log-law wind, tetrahedra (3D fan, reflections) and a terrain-following mesh
(the example hill, wind, reflections off the terrain): every final ray state (position, direction, travel
time, arc length, status, reflections, crossings, nudges, first reflection's material) must be bit-identical.
Under the simulator the kernel's shared steps run as the same CPU code, so bit identity is the right bar here;
what it tests is that the CUDA loop takes the same steps as trace_slots. A real device is tested in
tests/gpu/test_cuda_device.py (skipped without one).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("numba_cuda", reason="numba-cuda (the gpu extra) is not installed")

REPO = Path(__file__).resolve().parents[2]


def _run(case: str) -> dict:
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1"}
    proc = subprocess.run(
        [sys.executable, "-m", "tests.gpu.sim_compare", case],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("case", ["slabs", "slabs_circular_wind", "tets", "terrain"])
def test_cuda_kernel_matches_the_cpu_kernels_bit_for_bit(case):
    out = _run(case)
    assert "simulator" in out["device"]
    rays = out["rays"]
    assert len(rays) >= 5
    bad = [(i, r) for i, r in enumerate(rays) if not (r["identical"] and r["first_reflection_material_equal"])]
    assert not bad, bad
    # the cases exercise what they are meant to: crossings everywhere, reflections in every case
    assert all(r["counts_cpu"][2] > 0 for r in rays[:1])
    assert sum(r["counts_cpu"][1] for r in rays) > 0


def test_render_on_the_cuda_path_matches_the_cpu_path():
    out = _run("render")
    assert out["devices"] == ["cpu", "cuda"]
    assert out["identical"] and out["hit_equal"], out
    assert out["surface"] > 0 and out["sky"] > 0  # the view holds both the ground and the mirage's sky


def test_bentray_run_with_solver_device_cuda_matches_cpu():
    out = _run("run")
    assert out["identical"], out
    assert out["rays"] == 5 and out["reflections"] > 0


def test_launch_views_pass_empty_per_ray_arrays_whole():
    """engine/gpu/tracer.launch_views: rows a..b of the per-ray arrays, an empty (n, 0) one (f_weights without
    directivity) and the arrays of another length untouched. Slicing the empty one crashed every launch without
    directivity on a real device (numba-cuda refuses a slice into an empty allocation), which the simulator
    cannot show; the identity is the guard."""
    from bentray.engine.gpu.tracer import launch_views

    n = 10
    per_ray = np.arange(3 * n, dtype=float).reshape(n, 3)
    empty = np.zeros((n, 0))
    other = np.arange(4.0)
    views = launch_views((per_ray, empty, other), 2, 7, n)
    assert np.array_equal(views[0], per_ray[2:7])
    assert views[1] is empty and views[2] is other

"""Compile the CUDA traversal kernel to PTX for a real device, without a device (no simulator).

``python -m tests.gpu.ptx_check`` prints one JSON line: the PTX size and the compile time. This checks what the
simulator cannot: that numba-cuda types and lowers the kernel and every shared CPU-jitted step it calls for the
CUDA target. It needs NVRTC / NVVM (pip wheels nvidia-cuda-nvrtc, nvidia-cuda-nvcc); tests/gpu/test_cuda_ptx.py
skips when they are missing. numba-cuda asks the current device for its compute capability when it compiles a
called function as a device function; with no device, that one query is answered with (9, 0) here.
"""

from __future__ import annotations

import json
import time
import types

import numba
import numpy as np

import bentray  # noqa: F401


def main() -> dict:
    import numba.cuda.dispatcher as dispatcher
    from numba import cuda

    from bentray.engine.constants import COUNT_SIZE, STATE_SIZE
    from bentray.engine.gpu.kernel import trace_rays_cuda
    from bentray.engine.kernels.traverse import PAR_OUT_SIZE, RayParams, Rays
    from bentray.engine.mesh.cells import CellMesh

    cc = (9, 0)
    dispatcher.get_current_device = lambda: types.SimpleNamespace(compute_capability=cc)  # no device here
    n, k = 2, 4
    mesh = CellMesh(
        np.zeros((n, k, 4)),
        np.zeros((n, k), np.int64),
        np.zeros((n, k), np.int64),
        np.zeros(n),
        np.zeros((n, 3)),
        np.zeros((n, 3)),
        np.ones(n),
        np.zeros((n, k), np.int64),
    )
    prm = RayParams(0, 340.0, 0, np.zeros(4), 1.0, 1, 10, False, 1.0)
    rays = Rays(
        np.zeros((n, 3)),
        np.zeros((n, 3)),
        np.zeros(n, np.int64),
        np.zeros((n, 0)),
        np.zeros((n, 1)),
        np.zeros((n, 1), np.int64),
        np.zeros((n, STATE_SIZE)),
        np.zeros((n, COUNT_SIZE), np.int64),
        np.zeros((0, PAR_OUT_SIZE)),
    )
    # beam arguments of a semicoherent field with receivers (the types are the same for every mode and for
    # no_beam_args(): one compiled kernel)
    from bentray.engine.beam_field import BeamBuffers, bin_points, no_beam_args
    from bentray.engine.field_buffers import FieldGrid
    from bentray.engine.gpu.beam_device import BeamScratch
    from bentray.engine.kernels.beams import BEAM_SEMICOHERENT

    g, _, t, _, _, _ = no_beam_args(2)
    g = g._replace(mode=BEAM_SEMICOHERENT)
    buf = BeamBuffers("semicoherent", FieldGrid(np.zeros(3), np.ones(3), (2, 2, 2)), g, t, np.zeros((n, 2)), 1,
                      g, bin_points(np.ones((3, 3))))  # fmt: skip
    scr = BeamScratch(np.zeros((n, 2, 2)), np.zeros((n, 2, 2)), np.zeros((n, 2)))
    args = (mesh, prm, rays, *buf.kernel_args(), scr)
    sig = tuple(numba.typeof(a) for a in args)
    assert sig == tuple(numba.typeof(a) for a in (mesh, prm, rays, *no_beam_args(2), scr))
    t0 = time.perf_counter()
    ptx, _ = cuda.compile_ptx(trace_rays_cuda.py_func, sig, cc=cc)
    atomics = [ln.strip().split()[0] for ln in ptx.splitlines() if ".add.f64" in ln and ("atom" in ln or "red" in ln)]
    return {
        "ptx_chars": len(ptx),
        "compile_s": time.perf_counter() - t0,
        "cc": list(cc),
        "f64_atomic_adds": len(atomics),
        "atomic_kinds": sorted(set(atomics)),
    }


if __name__ == "__main__":
    print(json.dumps(main()))

"""Host side of the CUDA traversal: the mesh copied to the device once per job, rays in, final states out, and
with a beam field (beam_field.BeamBuffers) its accumulators in and out once per call.

Timings are kept apart (seconds): ``mesh_transfer`` (0 when the job's mesh is already on the device),
``rays_transfer`` (inputs to the device, the zeroed beam accumulators included), ``compile`` (the kernel's
first launch in this process for these argument types: numba-cuda compiles on first use), ``kernel`` (the
launches, synchronised) and ``copy_back`` (states, and the beam accumulators: one copy per call).

Rays go to the device in launches of at most :data:`LAUNCH_RAYS` rays (the per-thread beam scratch is sized for
one launch); all launches of a call add into the same beam accumulators.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from numba import cuda

from bentray.engine.beam_field import NO_HESSIAN, BeamBuffers, no_beam_args
from bentray.engine.constants import COUNT_SIZE, CURVE_CODES, STATE_SIZE
from bentray.engine.field_buffers import REFLECTION_RECORD_CAP
from bentray.engine.gpu.beam_device import BeamScratch
from bentray.engine.gpu.device import simulator_enabled
from bentray.engine.gpu.kernel import THREADS_PER_BLOCK, trace_rays_cuda
from bentray.engine.kernels.beams import BeamAcc
from bentray.engine.kernels.traverse import PAR_OUT_SIZE, RayParams, Rays
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.mesh.hessian import hessian_of
from bentray.engine.result import TraceResult
from bentray.engine.tracer import _trace_result, ray_inputs
from bentray.engine.wind import WIND_NONE, check_wind

__all__ = ["LAUNCH_RAYS", "device_mesh", "launch_views", "trace_cuda"]

_SIM = simulator_enabled()
# rays per kernel launch: the beam scratch holds 5 F doubles per thread (F bands: 10 MB at 8 bands)
LAUNCH_RAYS = 1 << 15


def _dev(a: np.ndarray) -> Any:
    """A device copy of ``a``. Under the simulator: a plain numpy copy (the simulator does not unwrap its fake
    device arrays inside the kernel's NamedTuple arguments, and the shared CPU-jitted steps need real arrays)."""
    a = np.ascontiguousarray(a)
    return a.copy() if _SIM else cuda.to_device(a)


def _empty(shape: tuple[int, ...], dtype: Any) -> Any:
    return np.empty(shape, dtype=dtype) if _SIM else cuda.device_array(shape, dtype=dtype)


def _host(a: Any) -> np.ndarray:
    return np.array(a) if _SIM else a.copy_to_host()


def _dev_tuple(t: Any) -> Any:
    """A NamedTuple with its arrays copied to the device (scalars kept)."""
    return type(t)(*(_dev(a) if isinstance(a, np.ndarray) else a for a in t))


# the last job's mesh on the device: (host mesh, device mesh). One job traces its batches over one mesh, so a
# job copies it once; a Dask worker keeps the mesh of the plan it was sent for as long as batches of that plan come.
_MESH_CACHE: list[tuple[CellMesh, CellMesh]] = []


def device_mesh(mesh: CellMesh) -> tuple[CellMesh, float]:
    """(the CellMesh with every array on the device, seconds spent copying: 0 when it was there already)."""
    if _MESH_CACHE and _MESH_CACHE[0][0] is mesh:
        return _MESH_CACHE[0][1], 0.0
    t0 = time.perf_counter()
    dev = CellMesh(*(_dev(a) for a in mesh))
    cuda.synchronize()
    _MESH_CACHE[:] = [(mesh, dev)]
    return dev, time.perf_counter() - t0


def launch_views(arrays: Any, a: int, b: int, n: int) -> list[Any]:
    """Rows a..b of each per-ray array (first axis n) of ``arrays``, the others as they are. An empty per-ray
    array (f_weights without directivity: (n, 0)) is passed whole: numba-cuda refuses to slice an empty device
    allocation ("non-empty slice into empty slice"; every launch without directivity crashed on an H200), and
    the kernel reads that array only when it has a column per band."""
    return [r[a:b] if r.shape[0] == n and r.size else r for r in arrays]


def trace_cuda(
    mesh: CellMesh,
    curve: str,
    c_ref: float,
    origins: np.ndarray,
    directions: np.ndarray,
    start_cells: np.ndarray,
    *,
    max_time_s: float,
    max_reflections: int,
    max_steps: int = 10_000_000,
    wind: tuple[int, np.ndarray] | None = None,
    refl_cap: int = 1,
    beams: BeamBuffers | None = None,
    smooth_beams: bool = True,
) -> tuple[TraceResult, dict[str, float]]:
    """Final ray states of tracer.trace (no voxel field, paths or paraxial state) computed by the CUDA kernel,
    and the beam field when ``beams`` is given.

    Same inputs and frames as :func:`bentray.engine.tracer.trace`; refl_cap : first reflections recorded per
    ray (incidence cosine, face material; REFLECTION_RECORD_CAP with beams, as on the CPU: the beams' ground
    factors read them). beams : accumulators with one slot (``BeamBuffers.like(weights, n_slots=1)``; its
    ``ray_amp`` the per-ray directivity factors or None), filled in place (``beams.acc``, ``beams.p_acc``
    replaced by the device's sums; the caller collapses them as after tracer.trace); smooth_beams : as in
    tracer.trace. Returns (TraceResult with
    launch angles NaN, timings in seconds).
    """
    origins, directions, start_cells = ray_inputs(curve, origins, directions, start_cells, max_time_s)
    wind_code, wind_params = check_wind(wind)
    n = origins.shape[0]
    f_weights = np.zeros((n, 0))
    if beams is not None:
        if curve != "parabolic":
            raise ValueError("paraxial rays and beam fields need the parabolic curve")
        if beams.n_slots != 1:
            raise ValueError("the device accumulates beams into one slot: pass BeamBuffers.like(weights, n_slots=1)")
        if beams.ray_amp is not None:
            if beams.ray_amp.shape != (n, beams.bgrid.omega.shape[0]):
                raise ValueError("directivity factors must have one row per ray and one column per band")
            f_weights = np.ascontiguousarray(beams.ray_amp, dtype=np.float64)
        refl_cap = max(refl_cap, REFLECTION_RECORD_CAP)
        b_args = beams.kernel_args()
        b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts = b_args
        if smooth_beams and wind_code == WIND_NONE:  # the smooth medium's paraxial state, as trace() does
            if b_tabs.hessian.shape[0] != mesh.n_cells:
                b_tabs = b_tabs._replace(hessian=hessian_of(mesh))
        elif b_tabs.hessian.shape[0]:
            b_tabs = b_tabs._replace(hessian=NO_HESSIAN)
        b_args = (b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts)
    else:
        b_args = no_beam_args()
    timings: dict[str, float] = {}
    dmesh, timings["mesh_transfer"] = device_mesh(mesh)
    t0 = time.perf_counter()
    prm = RayParams(
        CURVE_CODES[curve],
        float(c_ref),
        wind_code,
        _dev(np.asarray(wind_params, dtype=np.float64)),
        float(max_time_s),
        int(max_reflections),
        int(max_steps),
        False,
        1.0,
    )
    rays = Rays(
        _dev(origins),
        _dev(directions),
        _dev(start_cells),
        _dev(f_weights),
        _dev(np.zeros((n, refl_cap))),
        _dev(np.zeros((n, refl_cap), dtype=np.int64)),
        _empty((n, STATE_SIZE), np.float64),
        _empty((n, COUNT_SIZE), np.int64),
        _dev(np.zeros((0, PAR_OUT_SIZE))),
    )
    b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts = (_dev_tuple(a) for a in b_args)
    n_f = int(b_args[0].omega.shape[0])
    rows = max(min(n, LAUNCH_RAYS), 1)
    b_scr = BeamScratch(
        _empty((rows, 2, n_f), np.float64), _empty((rows, 2, n_f), np.float64), _empty((rows, n_f), np.float64)
    )
    cuda.synchronize()
    timings["rays_transfer"] = time.perf_counter() - t0
    beam_args = (b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts, b_scr)
    t0 = time.perf_counter()
    compile_fn = getattr(trace_rays_cuda, "compile", None)  # the simulator has none (nothing to compile)
    typeof_fn = getattr(trace_rays_cuda, "typeof_pyval", None)
    if compile_fn is not None and typeof_fn is not None:
        # numba-cuda compiles for these argument types without launching; a no-op once compiled
        compile_fn(tuple(typeof_fn(a) for a in (dmesh, prm, rays, *beam_args)))
    timings["compile"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    for a in range(0, n, LAUNCH_RAYS):
        b = min(a + LAUNCH_RAYS, n)
        part = Rays(*launch_views(rays, a, b, n))
        blocks = (b - a + THREADS_PER_BLOCK - 1) // THREADS_PER_BLOCK
        trace_rays_cuda[blocks, THREADS_PER_BLOCK](dmesh, prm, part, *beam_args)
    cuda.synchronize()
    timings["kernel"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if beams is not None:
        beams.acc = BeamAcc(*(_host(x) for x in b_acc))
        beams.p_acc = BeamAcc(*(_host(x) for x in p_acc))
    host = Rays(
        origins,
        directions,
        start_cells,
        np.zeros((n, 0)),
        _host(rays.refl_cos),
        _host(rays.refl_mat),
        _host(rays.out_state),
        _host(rays.out_counts),
        np.zeros((0, PAR_OUT_SIZE)),
    )
    timings["copy_back"] = time.perf_counter() - t0
    return _trace_result(host, None, True, False), timings

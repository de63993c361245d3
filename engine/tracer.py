"""Python wrapper around the traversal kernel: validates inputs, allocates outputs, decodes states."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

import numba
import numpy as np

from bentray.engine.beam_field import NO_HESSIAN, BeamBuffers, no_beam_args
from bentray.engine.constants import (
    BOUNDARY_REFLECT,
    COUNT_CROSSINGS,
    COUNT_NUDGES,
    COUNT_REFLECTIONS,
    COUNT_SAMPLES,
    COUNT_SIZE,
    COUNT_STATUS,
    COUNT_STEPS,
    CURVE_CODES,
    STATE_D,
    STATE_LENGTH,
    STATE_SIZE,
    STATE_TIME,
    STATE_X,
)
from bentray.engine.errors import MaterialTableError
from bentray.engine.field_buffers import REFLECTION_RECORD_CAP, FieldBuffers, no_field_tuple
from bentray.engine.kernels.beams import Beam
from bentray.engine.kernels.field import FieldAcc
from bentray.engine.kernels.lean import trace_block_lanes
from bentray.engine.kernels.traverse import PAR_OUT_SIZE, PathBuffers, RayParams, Rays, trace_rays
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.mesh.hessian import hessian_of
from bentray.engine.mesh.packed import packed_cells
from bentray.engine.result import RayPaths, TraceResult
from bentray.engine.wind import WIND_NONE, check_wind

KERNELS = ("auto", "generic", "lean")
# Lean kernel (kernels/lean.py): rays in flight per thread (its stages run across them, four at a time as
# vectors), with each ray's next cell record prefetched once its exit face is known for meshes whose packed
# records exceed LEAN_CACHED_BYTES (they come from memory; smaller ones stay in cache, where a prefetch is
# wasted work). Desert (195 MB of records), one thread: 1 lane 120-128 ns per crossing, 8 lanes with prefetch
# 50 ns; A-LD slabs (0.9 MB): 1 lane 59 ns, 8 lanes without prefetch 49 ns, with 52 ns (2026-12-05; docs/physics.md
# section 9). `bentray bench --only throughput` times them; every setting gives the same bits.
LEAN_LANES = 8
# Rays a thread takes from the lean kernel's shared queue at a time (neighbouring launch directions together;
# kernels/lean.py: threads share one queue, so none drains its lanes before the last rays are handed out).
LEAN_CHUNK = 16
LEAN_CACHED_BYTES = 8 << 20


def path_capacity(path_samples: int, max_reflections: int) -> int:
    """Per-ray sample slots: time samples (each long segment may add one extra), reflections, ends."""
    return 2 * int(path_samples) + min(int(max_reflections), 10_000) + 8


def ray_inputs(
    curve: str, origins: np.ndarray, directions: np.ndarray, start_cells: np.ndarray, max_time_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Checked, C-contiguous (n, 3) float64 origins and directions and (n,) int64 start cells for a
    traversal kernel; ValueError for an unknown curve, mismatched lengths or a non-positive time."""
    if curve not in CURVE_CODES:
        raise ValueError(f"unknown curve {curve!r}; expected one of {sorted(CURVE_CODES)}")
    origins = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    start_cells = np.ascontiguousarray(start_cells, dtype=np.int64).reshape(-1)
    n = origins.shape[0]
    if directions.shape[0] != n or start_cells.shape[0] != n:
        raise ValueError("origins, directions and start_cells must have the same length")
    if not (max_time_s > 0.0):
        raise ValueError("max_time_s must be positive")
    return origins, directions, start_cells


class _FieldArgs(NamedTuple):
    """What the traversal kernel takes for the field: accumulators, band weights (n, n_f), the number of
    accumulator slots, the beam arguments (no_beam_args() without beams) and the number of reflection
    records kept per ray (REFLECTION_RECORD_CAP with a field, 1 without)."""

    fld: FieldAcc
    f_weights: np.ndarray
    n_slots: int
    beam: tuple[Any, ...]
    refl_cap: int


def check_material_table(mesh: CellMesh, field: FieldBuffers) -> None:
    """Raise MaterialTableError unless ``field``'s ground table (q2tab (n_mat, n_band, n_cos, n_r)) has a
    row for every material index the mesh's reflecting faces carry and a band for every ``band_of`` entry.

    The field kernel reads the table by these indices without a bounds check (an index past the table
    reads foreign memory or crashes the process), so the wrapper checks once per call (one pass over the
    (n_cells, K) face materials, about 1 ms per million faces)."""
    n_mat, n_band = int(field.q2tab.shape[0]), int(field.q2tab.shape[1])
    used = mesh.face_material[mesh.neighbours == BOUNDARY_REFLECT]
    if used.size:
        lo, hi = int(used.min()), int(used.max())
        if lo < 0:
            raise MaterialTableError(f"the mesh's reflecting faces carry a negative material index ({lo})")
        if hi >= n_mat:
            raise MaterialTableError(
                f"the mesh's reflecting faces use {hi + 1} materials (indices 0..{hi}) but the field's ground "
                f"table has {n_mat}"
            )
    if field.band_of.size and (int(field.band_of.min()) < 0 or int(field.band_of.max()) >= n_band):
        raise MaterialTableError(
            f"the field's band_of reaches band index {int(field.band_of.max())} but the ground table has {n_band} bands"
        )


def _field_args(
    field: FieldBuffers | BeamBuffers | None, n: int, curve: str, paraxial: bool, record_reflections: bool = False
) -> _FieldArgs:
    """Kernel field arguments for ``n`` rays; ValueError when the field's weights do not have one row per ray
    (paraxial rays and beams: every analytic curve, docs/physics.md §10). Reflection records: with a
    field, or when ``record_reflections`` (eigenrays) asks for them."""
    if field is not None and field.weights.shape[0] != n:
        raise ValueError("field weights must have one row per ray")
    if isinstance(field, BeamBuffers):
        fld, f_weights = no_field_tuple(n)
        if field.ray_amp is not None:  # directivity: per-ray amplitude factors travel as the beams' f_weights
            if field.ray_amp.shape != (n, field.bgrid.omega.shape[0]):
                raise ValueError("directivity factors must have one row per ray and one column per band")
            f_weights = np.ascontiguousarray(field.ray_amp, dtype=np.float64)
        return _FieldArgs(fld, f_weights, field.n_slots, field.kernel_args(), REFLECTION_RECORD_CAP)
    if field is not None:
        return _FieldArgs(field.kernel_tuple(), field.weights, field.n_slots, no_beam_args(), REFLECTION_RECORD_CAP)
    fld, f_weights = no_field_tuple(n)
    refl_cap = REFLECTION_RECORD_CAP if record_reflections else 1
    return _FieldArgs(fld, f_weights, 4 * int(numba.get_num_threads()), no_beam_args(), refl_cap)


def _path_buffers(n: int, path_samples: int, max_reflections: int) -> PathBuffers:
    """Path sample buffers for ``n`` rays: ``path_capacity`` rows per ray (pts (n cap, 3) m, t s, s m),
    or one dummy row of each and cap 1 when ``path_samples`` is 0 (no recording)."""
    record = path_samples > 0
    cap = path_capacity(path_samples, max_reflections) if record else 1
    n_rows = n * cap if record else 1
    return PathBuffers(np.zeros((n_rows, 3)), np.zeros(n_rows), np.zeros(n_rows), cap)


def _ray_paths(paths: PathBuffers, samples: np.ndarray) -> RayPaths:
    """Pack the recorded samples (``samples[i]`` (n,) of ray i, in its rows [i cap, i cap + samples[i]))
    into a RayPaths: offsets (n + 1,) and the samples of ray i at [offsets[i], offsets[i + 1])."""
    n = len(samples)
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(samples, out=offsets[1:])
    keep = (np.arange(paths.cap)[None, :] < samples[:, None]).reshape(-1)
    return RayPaths(offsets=offsets, points=paths.pts[keep], time_s=paths.t[keep], length_m=paths.s[keep])


def _trace_result(rays: Rays, paths: RayPaths | None, with_reflections: bool, paraxial: bool) -> TraceResult:
    """Decode the kernel's per-ray outputs (state, counts, reflection records, paraxial state) into a
    TraceResult; launch angles NaN and source 0 (the caller fills them in)."""
    n = rays.out_state.shape[0]
    state, counts = rays.out_state, rays.out_counts
    nan = np.full(n, np.nan)
    return TraceResult(
        source=np.zeros(n, dtype=np.int64),
        elevation_deg=nan.copy(),
        azimuth_deg=nan.copy(),
        position=state[:, STATE_X : STATE_X + 3].copy(),
        direction=state[:, STATE_D : STATE_D + 3].copy(),
        time_s=state[:, STATE_TIME].copy(),
        length_m=state[:, STATE_LENGTH].copy(),
        reflections=counts[:, COUNT_REFLECTIONS].copy(),
        status=counts[:, COUNT_STATUS].astype(np.int8),
        crossings=counts[:, COUNT_CROSSINGS].copy(),
        nudges=counts[:, COUNT_NUDGES].copy(),
        paths=paths,
        steps=counts[:, COUNT_STEPS].copy(),
        reflection_cos=rays.refl_cos if with_reflections else None,
        reflection_material=rays.refl_mat if with_reflections else None,
        paraxial=rays.out_par if paraxial else None,
    )


def lean_applies(
    curve: str,
    path_samples: int,
    field: FieldBuffers | BeamBuffers | None,
    wind_code: int,
    paraxial: bool,
    record_reflections: bool,
) -> bool:
    """Whether a trace is the lean kernel's case: parabolic curve, no path recording, no field or beams,
    no wind, no paraxial state, no reflection records."""
    plain = path_samples <= 0 and field is None and wind_code == WIND_NONE
    return curve == "parabolic" and plain and not paraxial and not record_reflections


def lean_queue(n: int, chunk: int = LEAN_CHUNK) -> tuple[np.ndarray, int, int]:
    """The lean kernel's ray queue for rays 0..n-1: (taken, n, chunk), taken a (1,) int64 counter at 0 that
    every thread's kernel call moves by ``chunk`` rays (neighbouring launch directions) per take."""
    if int(chunk) < 1:
        raise ValueError(f"chunk must be at least 1, got {chunk!r}")
    return np.zeros(1, dtype=np.int64), int(n), int(chunk)


def trace_lean(
    mesh: CellMesh,
    c_ref: float,
    origins: np.ndarray,
    directions: np.ndarray,
    start_cells: np.ndarray,
    *,
    max_time_s: float,
    max_reflections: int,
    max_steps: int = 10_000_000,
    prefetch: int | None = None,
    lanes: int | None = None,
) -> TraceResult:
    """The plain parabolic trace on the lean kernel (kernels/lean.py): the final states of :func:`trace`
    bit for bit, without paths, field, wind or paraxial state. Arguments as in :func:`trace`; lanes : rays
    in flight per thread, >= 1 (None: LEAN_LANES), and prefetch : 0 or 1 (None: 1 for meshes whose packed
    records exceed LEAN_CACHED_BYTES, else 0). The mesh's packed records
    (mesh/packed.py) are built on the first trace of a mesh and kept while it lives. Returns a TraceResult
    with launch angles NaN (the caller fills them in)."""
    origins, directions, start_cells = ray_inputs("parabolic", origins, directions, start_cells, max_time_s)
    packed = packed_cells(mesh)
    from_memory = packed.rec.nbytes > LEAN_CACHED_BYTES
    lanes = LEAN_LANES if lanes is None else lanes
    prefetch = int(from_memory and lanes > 1) if prefetch is None else prefetch
    if prefetch not in (0, 1):
        raise ValueError(f"prefetch must be 0 or 1, got {prefetch!r}")
    if int(lanes) < 1:
        raise ValueError(f"lanes must be at least 1, got {lanes!r}")
    n = origins.shape[0]
    rays = Rays(
        origins,
        directions,
        start_cells,
        np.zeros((n, 0)),
        np.zeros((n, 1)),
        np.zeros((n, 1), dtype=np.int64),
        np.zeros((n, STATE_SIZE)),
        np.zeros((n, COUNT_SIZE), dtype=np.int64),
        np.full((0, PAR_OUT_SIZE), np.nan),
    )
    limits = (float(max_time_s), int(max_reflections), int(max_steps), int(prefetch), int(lanes))
    args = (packed, mesh, float(c_ref), limits, origins, directions, start_cells, rays.out_state, rays.out_counts)
    queue = lean_queue(n)
    threads = max(1, min(int(numba.get_num_threads()), -(-n // LEAN_CHUNK)))
    if threads <= 1:
        trace_block_lanes(*args, queue)
    else:  # one kernel call per thread on the shared queue (the kernel releases the GIL)
        with ThreadPoolExecutor(max_workers=threads) as pool:
            list(pool.map(lambda _: trace_block_lanes(*args, queue), range(threads)))
    return _trace_result(rays, None, False, False)


def trace(
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
    path_samples: int = 0,
    field: FieldBuffers | BeamBuffers | None = None,
    wind: tuple[int, np.ndarray] | None = None,
    paraxial: bool | str = False,
    record_reflections: bool = False,
    kernel: str = "auto",
    smooth_beams: bool = True,
) -> TraceResult:
    """Trace rays through ``mesh`` with the given curve kind.

    origins, directions : (n, 3) float64, metres / unit vectors, world frame.
    start_cells : (n,) int64 cell containing each origin (-1: not in the mesh -> status lost).
    path_samples : samples per ray for rays.vtp (0: no path recording, no path buffers).
    field : accumulators to fill along the curves (None: no accumulation, no field arrays); when
        given, the result also carries each ray's first reflections (incidence cosine, face material).
    wind : (code, params) of engine.wind.wind_spec, or None (no wind: code 0 and an empty array go to the
        kernel). With wind each ray traces the effective medium c + u(x) . e, e its unit horizontal launch
        azimuth (physics.md section 7); ``mesh`` carries c alone (no per-cell wind arrays).
    field may also be a beam_field.BeamBuffers (beam fields; every analytic curve).
    record_reflections : return each ray's first reflections (incidence cosine, face material) even
        without a field (eigenray amplitudes; any curve).
    paraxial : also return each ray's final paraxial state (TraceResult.paraxial, (n, 13): X_el, X_az,
        P_el, P_az, |p|; every analytic curve; docs/physics.md §10).
    kernel : "auto" (the lean kernel, kernels/lean.py, for a plain parabolic trace: no paths, field, wind,
        paraxial state or reflection records; the generic one otherwise), "generic" or "lean" (ValueError
        when the trace is not the lean kernel's case). Both give bit-identical final states.
    smooth_beams : with beams (parabolic curve, no wind), carry the paraxial state through the smooth medium
        of the mesh's per-cell Hessians (mesh/hessian.py; docs/physics.md §11) instead of the piecewise-linear
        mesh's face kicks; False: the exact kicks (measurements). The rays themselves are the same.
        ``paraxial="smooth"`` returns that state without beams (parabolic, no wind; otherwise as True).
    Returns a TraceResult with launch angles left at NaN (the caller fills them in).
    """
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    origins, directions, start_cells = ray_inputs(curve, origins, directions, start_cells, max_time_s)
    wind_code, wind_params = check_wind(wind)
    if paraxial not in (False, True, "smooth"):
        raise ValueError(f"paraxial must be False, True or 'smooth', got {paraxial!r}")
    smooth_par = paraxial == "smooth"
    paraxial = bool(paraxial)
    if kernel != "generic" and lean_applies(curve, path_samples, field, wind_code, paraxial, record_reflections):
        return trace_lean(
            mesh,
            c_ref,
            origins,
            directions,
            start_cells,
            max_time_s=max_time_s,
            max_reflections=max_reflections,
            max_steps=max_steps,
        )
    if kernel == "lean":
        raise ValueError("kernel='lean' traces only the parabolic curve without paths, field, wind or paraxial state")
    n = origins.shape[0]
    record = path_samples > 0
    path_buf = _path_buffers(n, path_samples, max_reflections)
    dt_sample = max_time_s / max(path_samples, 1)
    if isinstance(field, FieldBuffers):
        check_material_table(mesh, field)
    fa = _field_args(field, n, curve, paraxial, record_reflections)
    smooth = (isinstance(field, BeamBuffers) and smooth_beams) or smooth_par
    b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts = fa.beam
    if smooth and curve == "parabolic" and wind_code == WIND_NONE:
        if b_tabs.hessian.shape[0] != mesh.n_cells:  # not given with the field (stages.field_setup gives it)
            b_tabs = b_tabs._replace(hessian=hessian_of(mesh))
    elif b_tabs.hessian.shape[0]:  # smooth_beams=False: the template's Hessians are not used
        b_tabs = b_tabs._replace(hessian=NO_HESSIAN)
    fa = fa._replace(beam=(b_grid, b_acc, b_tabs, p_grid, p_acc, b_pts))
    prm = RayParams(
        CURVE_CODES[curve],
        float(c_ref),
        wind_code,
        wind_params,
        float(max_time_s),
        int(max_reflections),
        int(max_steps),
        record,
        float(dt_sample),
    )
    rays = Rays(
        origins,
        directions,
        start_cells,
        fa.f_weights,
        np.zeros((n, fa.refl_cap)),
        np.zeros((n, fa.refl_cap), dtype=np.int64),
        np.zeros((n, STATE_SIZE)),
        np.zeros((n, COUNT_SIZE), dtype=np.int64),
        np.full((n if paraxial else 0, PAR_OUT_SIZE), np.nan),
    )
    trace_rays(mesh, prm, fa.fld, path_buf, rays, fa.n_slots, Beam(*fa.beam))
    paths = _ray_paths(path_buf, rays.out_counts[:, COUNT_SAMPLES]) if record else None
    return _trace_result(rays, paths, field is not None or record_reflections, paraxial)

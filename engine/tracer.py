"""Python wrapper around the traversal kernel: validates inputs, allocates outputs, decodes states."""

from __future__ import annotations

import numba
import numpy as np

from bentray.engine.beam_field import BeamBuffers, no_beam_args
from bentray.engine.constants import (
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
from bentray.engine.field_buffers import REFLECTION_RECORD_CAP, FieldBuffers, no_field_tuple
from bentray.engine.kernels.traverse import PAR_OUT_SIZE, PathBuffers, RayParams, Rays, trace_rays
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.result import RayPaths, TraceResult
from bentray.engine.wind import check_wind


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
    paraxial: bool = False,
    record_reflections: bool = False,
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
    field may also be a beam_field.BeamBuffers (beam fields; parabolic curve only).
    record_reflections : return each ray's first reflections (incidence cosine, face material) even
        without a field (eigenray amplitudes; any curve).
    paraxial : also return each ray's final paraxial state (TraceResult.paraxial, (n, 13): X_el, X_az,
        P_el, P_az, |p|; parabolic curve only; docs/physics.md §10).
    Returns a TraceResult with launch angles left at NaN (the caller fills them in).
    """
    origins, directions, start_cells = ray_inputs(curve, origins, directions, start_cells, max_time_s)
    wind_code, wind_params = check_wind(wind)
    n = origins.shape[0]
    record = path_samples > 0
    cap = path_capacity(path_samples, max_reflections) if record else 1
    n_slots = n * cap if record else 1
    path_pts = np.zeros((n_slots, 3))
    path_t = np.zeros(n_slots)
    path_s = np.zeros(n_slots)
    dt_sample = max_time_s / max(path_samples, 1)
    out_state = np.zeros((n, STATE_SIZE))
    out_counts = np.zeros((n, COUNT_SIZE), dtype=np.int64)
    beam = no_beam_args()
    if (paraxial or isinstance(field, BeamBuffers)) and curve != "parabolic":
        raise ValueError("paraxial rays and beam fields need the parabolic curve")
    if isinstance(field, BeamBuffers):
        if field.weights.shape[0] != n:
            raise ValueError("field weights must have one row per ray")
        fld, f_weights = no_field_tuple(n)
        n_slots = field.n_slots
        beam = field.kernel_args()
        refl_cap = REFLECTION_RECORD_CAP
    elif field is not None:
        if field.weights.shape[0] != n:
            raise ValueError("field weights must have one row per ray")
        fld, f_weights, n_slots = field.kernel_tuple(), field.weights, field.n_slots
        refl_cap = REFLECTION_RECORD_CAP
    else:
        fld, f_weights = no_field_tuple(n)
        n_slots = 4 * int(numba.get_num_threads())
        refl_cap = REFLECTION_RECORD_CAP if record_reflections else 1
    refl_cos = np.zeros((n, refl_cap))
    refl_mat = np.zeros((n, refl_cap), dtype=np.int64)
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
    out_par = np.full((n if paraxial else 0, PAR_OUT_SIZE), np.nan)
    rays = Rays(origins, directions, start_cells, f_weights, refl_cos, refl_mat, out_state, out_counts, out_par)
    trace_rays(mesh, prm, fld, PathBuffers(path_pts, path_t, path_s, cap), rays, n_slots, *beam)
    paths = None
    if record:
        counts = out_counts[:, COUNT_SAMPLES]
        offsets = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        keep = (np.arange(cap)[None, :] < counts[:, None]).reshape(-1)
        paths = RayPaths(offsets=offsets, points=path_pts[keep], time_s=path_t[keep], length_m=path_s[keep])
    nan = np.full(n, np.nan)
    return TraceResult(
        source=np.zeros(n, dtype=np.int64),
        elevation_deg=nan.copy(),
        azimuth_deg=nan.copy(),
        position=out_state[:, STATE_X : STATE_X + 3].copy(),
        direction=out_state[:, STATE_D : STATE_D + 3].copy(),
        time_s=out_state[:, STATE_TIME].copy(),
        length_m=out_state[:, STATE_LENGTH].copy(),
        reflections=out_counts[:, COUNT_REFLECTIONS].copy(),
        status=out_counts[:, COUNT_STATUS].astype(np.int8),
        crossings=out_counts[:, COUNT_CROSSINGS].copy(),
        nudges=out_counts[:, COUNT_NUDGES].copy(),
        paths=paths,
        steps=out_counts[:, COUNT_STEPS].copy(),
        reflection_cos=refl_cos if field is not None or record_reflections else None,
        reflection_material=refl_mat if field is not None or record_reflections else None,
        paraxial=out_par if paraxial else None,
    )

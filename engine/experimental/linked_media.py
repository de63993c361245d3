"""Python wrapper of the linked-surface traversal (Appendix C): validates, allocates, returns a TraceResult.

The mesh comes from engine/experimental/linked_mesh.py ``build_linked_mesh``; the kernel is
engine/experimental/traverse_linked.py. Results compare directly with ``engine.tracer.trace`` on the embedded
(terrain-following) mesh. No field accumulation and no wind (see the kernel's docstring).
"""

from __future__ import annotations

import numpy as np

from bentray.engine.constants import CURVE_CODES
from bentray.engine.experimental.linked_mesh import LinkedMesh
from bentray.engine.experimental.traverse_linked import trace_linked_rays
from bentray.engine.result import TraceResult, gather_paths, kernel_trace_result
from bentray.engine.tracer import path_capacity, ray_inputs

__all__ = ["trace_linked"]


def trace_linked(
    lm: LinkedMesh,
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
    surface_tests: np.ndarray | None = None,
) -> TraceResult:
    """Trace rays through a linked mesh with the given curve kind (as ``tracer.trace``).

    origins, directions : (n, 3) float64, metres / direction vectors, world frame.
    start_cells : (n,) int64 cell of each origin (``linked.locate_in_linked_mesh``; -1 -> status lost).
    path_samples : samples per ray for rays.vtp (0: none).
    surface_tests : optional (n,) int64 output: ray-triangle tests made by each ray.
    Returns a TraceResult (launch angles NaN; reflection_cos / reflection_material None).
    """
    origins, directions, start_cells = ray_inputs(curve, origins, directions, start_cells, max_time_s)
    n = origins.shape[0]
    if surface_tests is not None and surface_tests.shape != (n,):
        raise ValueError("surface_tests must have shape (n,)")
    record = path_samples > 0
    cap = path_capacity(path_samples, max_reflections) if record else 1
    slots = n * cap if record else 1
    path_pts, path_t, path_s = np.zeros((slots, 3)), np.zeros(slots), np.zeros(slots)
    out_state = np.zeros((n, 8))
    out_counts = np.zeros((n, 7), dtype=np.int64)
    m = lm.cells
    trace_linked_rays(
        m.planes,
        m.neighbours,
        m.neighbour_face,
        m.media_ref,
        m.ref_point,
        m.gradient,
        m.size,
        *lm.kernel_links(),
        CURVE_CODES[curve],
        float(c_ref),
        origins,
        directions,
        start_cells,
        float(max_time_s),
        int(max_reflections),
        int(max_steps),
        record,
        float(max_time_s / max(path_samples, 1)),
        cap,
        path_pts,
        path_t,
        path_s,
        out_state,
        out_counts,
    )
    if surface_tests is not None:
        surface_tests[:] = out_counts[:, 6]
    paths = gather_paths(path_pts, path_t, path_s, out_counts[:, 5], cap) if record else None
    return kernel_trace_result(
        out_state,
        status=out_counts[:, 0],
        reflections=out_counts[:, 1],
        crossings=out_counts[:, 2],
        nudges=out_counts[:, 3],
        steps=out_counts[:, 4],
        paths=paths,
    )

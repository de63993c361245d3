"""The trace plan: everything a ray batch needs, as plain arrays (picklable: sent once to scale-out workers)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from bentray.engine.beam_field import BeamBuffers
from bentray.engine.field_buffers import FieldBuffers
from bentray.engine.mesh.cells import CellMesh

__all__ = ["BaselineSpec", "TracePlan"]


class BaselineSpec(NamedTuple):
    """How a numerical baseline traces (the job's solver resolved; keyword arguments of
    :func:`bentray.engine.baselines.trace_numerical.trace_numerical`).

    method : "euler" | "euler_adaptive" | "rk4" | "dopri5"; media : "exact" | "mesh".
    quantity : the mesh's linear quantity ("n2" | "c" | "n"); exact_spec : (code, params) of the closed-form
    profile for media "exact", else None. step_m : first / fixed step, metres of arc; tolerance : local error
    per step. domain_min, domain_max : (3,) float64 metres, world frame; ground_z : flat ground height (m);
    top : "open" | "reflect" (the domain top).

    A NamedTuple (not a frozen dataclass) so that ``dask_executor.aligned_arrays`` can rebuild it.
    """

    method: str
    media: str
    quantity: str
    exact_spec: tuple[int, np.ndarray] | None
    step_m: float
    tolerance: float
    domain_min: np.ndarray
    domain_max: np.ndarray
    ground_z: float
    top: str


@dataclass
class TracePlan:
    """Everything a ray batch needs, as plain arrays (picklable: sent once to scale-out workers).

    origins, directions : (n, 3) float64, metres / unit vectors, world frame; start_cells : (n,) int64.
    wind : (code, params) of the wind for the kernels, or None.
    field : accumulator template (zero-size weights are taken per batch from ``field_weights``) or None.
    baseline : None for the analytic curves, else the numerical method (:class:`BaselineSpec`).
    source : (n,) int64 source index per ray (source-major); None: one source.
    """

    mesh: CellMesh
    curve: str
    c_ref: float
    wind: tuple[int, np.ndarray] | None
    origins: np.ndarray
    directions: np.ndarray
    start_cells: np.ndarray
    max_time_s: float
    max_reflections: int
    max_steps: int
    path_samples: int
    field: FieldBuffers | BeamBuffers | None = None
    field_weights: np.ndarray | None = None
    baseline: BaselineSpec | None = None
    source: np.ndarray | None = None
    ray_amplitudes: np.ndarray | None = None  # (n, F) source directivity per ray (beams; None: omni)
    device: str = "cpu"  # solver.device: "cpu" | "cuda" | "auto" (engine/gpu/device.py; states and beam fields)

    @property
    def n_rays(self) -> int:
        return int(self.origins.shape[0])

    def batches(self, batch_rays: int) -> list[tuple[int, int]]:
        """Consecutive [start, stop) ray ranges: per source, then blocks of at most ``batch_rays`` rays
        of its launch fan (a range never straddles two sources; rays are source-major)."""
        n = self.n_rays
        size = max(int(batch_rays), 1)
        if self.source is None or n == 0:
            return [(a, min(a + size, n)) for a in range(0, n, size)] or [(0, 0)]
        cuts = np.concatenate([[0], np.nonzero(np.diff(self.source))[0] + 1, [n]]).tolist()
        spans = zip(cuts[:-1], cuts[1:], strict=True)
        return [(a, min(a + size, hi)) for lo, hi in spans for a in range(lo, hi, size)]

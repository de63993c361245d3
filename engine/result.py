"""Result containers handed from the engine to the writers (plain numpy, no pydantic)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bentray.engine.constants import STATE_D, STATE_LENGTH, STATE_TIME, STATE_X, STATUS_NAMES


@dataclass
class RayPaths:
    """Polylines sampled on the true ray curves (not chords of long segments).

    offsets : (n_rays + 1,) int64 -- points of ray i are ``points[offsets[i]:offsets[i+1]]``.
    points : (M, 3) float64, metres, world frame.
    time_s : (M,) float64, travel time at each sample.
    length_m : (M,) float64, arc length at each sample.
    """

    offsets: np.ndarray
    points: np.ndarray
    time_s: np.ndarray
    length_m: np.ndarray


@dataclass
class TraceResult:
    """Final state of every ray of a job (one row per ray), plus optional sampled paths.

    source : (n,) int64 source index; elevation_deg, azimuth_deg : (n,) launch angles in degrees
    (elevation above the horizontal, azimuth counter-clockwise from +x).
    position : (n, 3) metres; direction : (n, 3) unit tangent; time_s, length_m : (n,);
    reflections : (n,) int64; status : (n,) int8 (codes in constants.STATUS_NAMES);
    crossings : (n,) int64 cell-to-cell steps; nudges : (n,) int64 re-locations after rounding.
    """

    source: np.ndarray
    elevation_deg: np.ndarray
    azimuth_deg: np.ndarray
    position: np.ndarray
    direction: np.ndarray
    time_s: np.ndarray
    length_m: np.ndarray
    reflections: np.ndarray
    status: np.ndarray
    crossings: np.ndarray
    nudges: np.ndarray
    paths: RayPaths | None = None
    steps: np.ndarray | None = None  # (n,) int64 curve segments per ray (cells entered + reflections)
    # (n, R) incidence cosine |T.m| and face material of each ray's first R reflections (field runs only)
    reflection_cos: np.ndarray | None = None
    reflection_material: np.ndarray | None = None
    # (n, 13) final paraxial state when asked for: X_el, X_az (m/rad), P_el, P_az (1/rad; p = n T), |p| = n
    paraxial: np.ndarray | None = None

    @property
    def n_rays(self) -> int:
        return int(self.status.shape[0])

    def status_counts(self) -> dict[str, int]:
        """Rays by end status; every status name is present (zero counts included)."""
        return {name: int(np.count_nonzero(self.status == code)) for code, name in STATUS_NAMES.items()}


@dataclass
class MeshGeometry:
    """Cell geometry for mesh.vtu: points and cells of one VTK cell type.

    points : (P, 3) metres; connectivity : (C, k) int64; cell_type : "tetra" (k=4) or "hexahedron"
    (k=8, VTK ordering); cell_data : arrays of length C (e.g. the traced quantity and its gradient);
    field_data : text written beside them (legends, units), shown by ParaView's information panel.
    """

    points: np.ndarray
    connectivity: np.ndarray
    cell_type: str
    cell_data: dict[str, np.ndarray] = field(default_factory=dict)
    field_data: dict[str, str] = field(default_factory=dict)


@dataclass
class JobOutcome:
    """Everything a job produced, before writing."""

    trace: TraceResult
    mesh_geometry: MeshGeometry | None
    report: dict[str, Any]
    field: Any | None = None  # engine.field.FieldArrays when the job asked for a field
    receivers: Any | None = None  # engine.beam_field.ReceiverTable when the job lists receivers
    arrivals: Any | None = None  # engine.eigenray_stage.ArrivalTable when the eigenray search ran


def concat_traces(parts: list[TraceResult]) -> TraceResult:
    """One TraceResult from consecutive ray batches (in ray order); paths are re-offset."""
    if not parts:
        raise ValueError("no trace batches to combine")
    if len(parts) == 1:
        return parts[0]

    def cat(name: str) -> np.ndarray | None:
        arrays = [getattr(p, name) for p in parts]
        if any(a is None for a in arrays):
            return None
        return np.concatenate(arrays, axis=0)

    paths = None
    if all(p.paths is not None for p in parts):
        offsets = [np.zeros(1, dtype=np.int64)]
        base = 0
        for p in parts:
            assert p.paths is not None
            offsets.append(p.paths.offsets[1:] + base)
            base += int(p.paths.offsets[-1])
        paths = RayPaths(
            offsets=np.concatenate(offsets),
            points=np.concatenate([p.paths.points for p in parts if p.paths is not None]),
            time_s=np.concatenate([p.paths.time_s for p in parts if p.paths is not None]),
            length_m=np.concatenate([p.paths.length_m for p in parts if p.paths is not None]),
        )
    required: dict[str, Any] = {  # the always-present arrays (cat gives None only for optional ones)
        name: cat(name)
        for name in (
            "source",
            "elevation_deg",
            "azimuth_deg",
            "position",
            "direction",
            "time_s",
            "length_m",
            "reflections",
            "status",
            "crossings",
            "nudges",
        )
    }
    return TraceResult(
        **required,
        paths=paths,
        steps=cat("steps"),
        reflection_cos=cat("reflection_cos"),
        reflection_material=cat("reflection_material"),
        paraxial=cat("paraxial"),
    )


def gather_paths(
    path_pts: np.ndarray, path_t: np.ndarray, path_s: np.ndarray, counts: np.ndarray, cap: int
) -> RayPaths:
    """RayPaths from the kernels' fixed-capacity path buffers: ray i wrote ``counts[i]`` samples into
    slots ``[i * cap, i * cap + counts[i])``."""
    n = counts.shape[0]
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=offsets[1:])
    keep = (np.arange(cap)[None, :] < counts[:, None]).reshape(-1)
    return RayPaths(offsets=offsets, points=path_pts[keep], time_s=path_t[keep], length_m=path_s[keep])


def kernel_trace_result(
    out_state: np.ndarray,
    *,
    status: np.ndarray,
    reflections: np.ndarray,
    crossings: np.ndarray,
    nudges: np.ndarray,
    steps: np.ndarray,
    paths: RayPaths | None = None,
    **extra: Any,
) -> TraceResult:
    """TraceResult from a kernel's (n, STATE_SIZE) final states (columns constants.STATE_*) and its per-ray
    counters; launch angles are left NaN and sources 0 (the job fills them in)."""
    n = out_state.shape[0]
    nan = np.full(n, np.nan)
    return TraceResult(
        source=np.zeros(n, dtype=np.int64),
        elevation_deg=nan.copy(),
        azimuth_deg=nan.copy(),
        position=out_state[:, STATE_X : STATE_X + 3].copy(),
        direction=out_state[:, STATE_D : STATE_D + 3].copy(),
        time_s=out_state[:, STATE_TIME].copy(),
        length_m=out_state[:, STATE_LENGTH].copy(),
        reflections=reflections.copy(),
        status=status.astype(np.int8),
        crossings=crossings.copy(),
        nudges=nudges.copy(),
        paths=paths,
        steps=steps.copy(),
        **extra,
    )

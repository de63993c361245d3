"""Axis-aligned box overlap candidates for the mesh builders and mesh checks (plain numpy, no scene schema).

The one bucketed overlap search: the linked-surface link table, the closed-surface checks of obstacle
meshes and the scene checks (``scenes.geometry`` re-exports it) use it. World frame, metres.
"""

from __future__ import annotations

import numpy as np

__all__ = ["GEOMETRY_REL_TOL", "MAX_BOX_COORDINATE", "MAX_CANDIDATE_PAIRS", "CandidateLimitError", "box_pairs"]

# Orientation and containment tests treat anything within GEOMETRY_REL_TOL x (scene size) of a line or
# plane as "on" it: 1e-9 of a 2 km scene is 2 micrometres, far below any survey accuracy and far above
# float64 rounding of coordinates (~1e-13 m at km scale), so touching is never mistaken for crossing.
GEOMETRY_REL_TOL = 1e-9
# Candidate pairs the bucketed overlap search may generate before giving up (about 16 bytes each plus
# temporaries: 20M pairs ~ 1 GB). A well-formed input yields a few pairs per element.
MAX_CANDIDATE_PAIRS = 20_000_000
# Grid cells per axis of the bucketing grid (keys stay inside int64 in 3D).
_MAX_CELLS_PER_AXIS = 1 << 16
# Box coordinates beyond this are refused: differences and squares of coordinates up to 1e150 stay finite
# (a 1e308 coordinate made the extent overflow to inf and the cell-size loop spin on NaN forever).
MAX_BOX_COORDINATE = 1e150


class CandidateLimitError(ValueError):
    """The overlap search would need more than MAX_CANDIDATE_PAIRS candidate pairs."""


def _registrations(lo: np.ndarray, hi: np.ndarray, origin: np.ndarray, h: float, dims: np.ndarray):
    """Cell keys of every grid cell each box touches: (box ids, keys), both int64."""
    i0 = np.clip(np.floor((lo - origin) / h).astype(np.int64), 0, dims - 1)
    i1 = np.clip(np.floor((hi - origin) / h).astype(np.int64), 0, dims - 1)
    span = i1 - i0 + 1
    counts = np.prod(span, axis=1)
    total = int(counts.sum())
    box = np.repeat(np.arange(lo.shape[0], dtype=np.int64), counts)
    local = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    key = np.zeros(total, dtype=np.int64)
    stride = 1
    for axis in range(lo.shape[1]):
        s = span[box, axis]
        key += (i0[box, axis] + local % s) * stride
        local //= s
        stride *= int(dims[axis])
    return box, key


def box_pairs(
    lo_a: np.ndarray, hi_a: np.ndarray, lo_b: np.ndarray | None = None, hi_b: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs of axis-aligned boxes that overlap (closed boxes, padded by GEOMETRY_REL_TOL).

    lo_a, hi_a : (Na, d) float64, d = 2 or 3; lo_b, hi_b : (Nb, d) or None for a self-join.
    Returns (ia, ib) int64 arrays, unique pairs; for a self-join only ia < ib.
    Uniform-grid bucketing (cell size about the median box size): near-linear for well-shaped inputs.
    Raises CandidateLimitError beyond MAX_CANDIDATE_PAIRS and ValueError for a coordinate that is not finite
    or beyond MAX_BOX_COORDINATE in magnitude.
    """
    self_join = lo_b is None or hi_b is None
    if self_join:
        lo_b, hi_b = lo_a, hi_a
    assert lo_b is not None and hi_b is not None
    for arr in (lo_a, hi_a, lo_b, hi_b):
        if arr.size and not (np.all(np.isfinite(arr)) and np.abs(arr).max() <= MAX_BOX_COORDINATE):
            raise ValueError(f"box coordinates must be finite and at most {MAX_BOX_COORDINATE:g} in magnitude")
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if lo_a.shape[0] == 0 or lo_b.shape[0] == 0:
        return empty
    origin = np.minimum(lo_a.min(axis=0), lo_b.min(axis=0))
    top = np.maximum(hi_a.max(axis=0), hi_b.max(axis=0))
    extent = float(np.max(top - origin))
    pad = GEOMETRY_REL_TOL * max(extent, 1.0)
    lo_a, hi_a, lo_b, hi_b = lo_a - pad, hi_a + pad, lo_b - pad, hi_b + pad
    n_boxes = lo_a.shape[0] + lo_b.shape[0]
    h = max(
        float(np.median((hi_a - lo_a).max(axis=1))),
        float(np.median((hi_b - lo_b).max(axis=1))),
        (extent + 2 * pad) / _MAX_CELLS_PER_AXIS,
        1e-300,
    )
    grid_origin = origin - pad
    for _ in range(4096):  # h doubles each round: finite inputs break out long before h overflows
        dims = np.floor((top + pad - grid_origin) / h).astype(np.int64) + 1
        span_a = np.prod(np.floor((hi_a - lo_a) / h) + 2, axis=1).sum()
        span_b = np.prod(np.floor((hi_b - lo_b) / h) + 2, axis=1).sum()
        if span_a + span_b <= 16 * n_boxes + 64:
            break
        h *= 2.0  # a few huge boxes would otherwise register in very many cells
    else:
        raise ValueError("box_pairs: no cell size fits the boxes (non-finite extent)")
    box_a, key_a = _registrations(lo_a, hi_a, grid_origin, h, dims)
    box_b, key_b = _registrations(lo_b, hi_b, grid_origin, h, dims)
    order_b = np.argsort(key_b, kind="stable")
    key_b, box_b = key_b[order_b], box_b[order_b]
    start = np.searchsorted(key_b, key_a, side="left")
    stop = np.searchsorted(key_b, key_a, side="right")
    n_pairs = stop - start
    total = int(n_pairs.sum())
    if total > MAX_CANDIDATE_PAIRS:
        raise CandidateLimitError(f"the overlap search needs {total:,} candidate pairs (limit {MAX_CANDIDATE_PAIRS:,})")
    ia = np.repeat(box_a, n_pairs)
    cell = np.repeat(key_a, n_pairs)
    offset = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(n_pairs) - n_pairs, n_pairs)
    ib = box_b[np.repeat(start, n_pairs) + offset]
    keep = ia < ib if self_join else np.ones(ia.shape, dtype=bool)
    ia, ib, cell = ia[keep], ib[keep], cell[keep]
    overlap = np.all((lo_a[ia] <= hi_b[ib]) & (lo_b[ib] <= hi_a[ia]), axis=1)
    ia, ib, cell = ia[overlap], ib[overlap], cell[overlap]
    # report each pair once: in the cell holding the lower corner of the boxes' intersection
    corner = np.clip(np.floor((np.maximum(lo_a[ia], lo_b[ib]) - grid_origin) / h).astype(np.int64), 0, dims - 1)
    strides = np.concatenate([[1], np.cumprod(dims[:-1])]).astype(np.int64)
    once = corner @ strides == cell
    code = np.sort(ia[once] * np.int64(lo_b.shape[0]) + ib[once])
    return code // lo_b.shape[0], code % lo_b.shape[0]

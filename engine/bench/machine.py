"""The machine's own limits for the traversal, measured in the same run: memory bandwidth and arithmetic.

- **Memory**: a STREAM-like triad ``a[i] = b[i] + q c[i]`` on one core over arrays far larger than the
  caches (3 x 64 MB by default); bandwidth = 24 bytes per element / time (STREAM's count; the write-allocate
  read of ``a`` is not counted), best of ``repeats``.
- **Arithmetic**: independent chains (8 accumulators, so latency is hidden) of multiply-adds, square roots,
  divisions and log1p on one core; seconds per operation, best of ``repeats``.

From these, :func:`crossing_bounds` turns a mesh into two lower bounds for one cell crossing: *memory* =
the cache lines one cell's records span (every array's row, counted with its true byte offsets, averaged
over cells) times 64 B / bandwidth (a crossing that always misses every cache), and *arithmetic* = the
per-crossing operation counts of the parabolic walk (``CROSSING_OPS``: the issue-18 count for a tet, about
215 flops, 9 square roots, 17 divisions and 1 log1p, less the closed-form arc length's 7 divisions and log1p
and plus about 20 flops for the Gauss-Legendre arc length that replaced it in most segments) times the
measured costs. The lean kernel reads packed records (mesh/packed.py), whose lines per cell give a second
memory bound. The traversal's measured ns
per crossing against both lets readers compare across machines.

The microkernels are compiled here with ``numba.jit(nopython=True)`` and no on-disk cache (they are tiny,
compile in well under a second, and so never need the engine's source-keyed cache folder).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numba
import numpy as np

__all__ = ["CROSSING_OPS", "crossing_bounds", "measure_machine"]

# per tet crossing of the parabolic walk: flops (+, -, *), square roots, divisions, log1p (issue 18's count
# with the arc length by 3-point Gauss-Legendre quadrature: parabolic.arc_length)
CROSSING_OPS = {"flops": 235, "sqrt": 9, "div": 10, "log1p": 0}
LINE = 64


@numba.jit(nopython=True, cache=False, nogil=True)
def _triad(a: np.ndarray, b: np.ndarray, c: np.ndarray, q: float) -> None:
    for i in range(a.shape[0]):
        a[i] = b[i] + q * c[i]


@numba.jit(nopython=True, cache=False, nogil=True, error_model="numpy")
def _chains(kind: int, n: int, x0: float) -> float:
    """n iterations of 8 independent chains: kind 0 multiply-add (2 flops), 1 sqrt, 2 division, 3 log1p."""
    a0, a1, a2, a3 = x0, x0 + 0.1, x0 + 0.2, x0 + 0.3
    a4, a5, a6, a7 = x0 + 0.4, x0 + 0.5, x0 + 0.6, x0 + 0.7
    m = 0.9999999
    k = 1e-9
    for _ in range(n):
        if kind == 0:
            a0 = a0 * m + k
            a1 = a1 * m + k
            a2 = a2 * m + k
            a3 = a3 * m + k
            a4 = a4 * m + k
            a5 = a5 * m + k
            a6 = a6 * m + k
            a7 = a7 * m + k
        elif kind == 1:
            a0 = math.sqrt(a0 + k)
            a1 = math.sqrt(a1 + k)
            a2 = math.sqrt(a2 + k)
            a3 = math.sqrt(a3 + k)
            a4 = math.sqrt(a4 + k)
            a5 = math.sqrt(a5 + k)
            a6 = math.sqrt(a6 + k)
            a7 = math.sqrt(a7 + k)
        elif kind == 2:
            a0 = 1.0 / (a0 + k)
            a1 = 1.0 / (a1 + k)
            a2 = 1.0 / (a2 + k)
            a3 = 1.0 / (a3 + k)
            a4 = 1.0 / (a4 + k)
            a5 = 1.0 / (a5 + k)
            a6 = 1.0 / (a6 + k)
            a7 = 1.0 / (a7 + k)
        else:
            a0 = math.log1p(a0)
            a1 = math.log1p(a1)
            a2 = math.log1p(a2)
            a3 = math.log1p(a3)
            a4 = math.log1p(a4)
            a5 = math.log1p(a5)
            a6 = math.log1p(a6)
            a7 = math.log1p(a7)
    return a0 + a1 + a2 + a3 + a4 + a5 + a6 + a7


def _best(fn: Any, repeats: int) -> float:
    best = math.inf
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def measure_machine(repeats: int = 5, triad_mb: int = 64, chain_iters: int = 4_000_000) -> dict[str, float]:
    """Single-core memory bandwidth and operation costs (module docstring), best of ``repeats``.

    Returns triad_gb_s (10^9 B/s), and seconds per operation: flop_s (one + or *), sqrt_s, div_s, log1p_s.
    Runs on the calling thread (numba threads are not used).
    """
    n = triad_mb * 1024 * 1024 // 8
    a, b, c = np.ones(n), np.ones(n), np.full(n, 2.0)  # written: no first-touch page faults in the timing
    _triad(a, b, c, 3.0)  # compile, and one untimed pass
    t_triad = _best(lambda: _triad(a, b, c, 3.0), repeats)
    costs: dict[str, float] = {"triad_gb_s": 24.0 * n / t_triad / 1e9}
    for kind, name, ops in ((0, "flop_s", 16), (1, "sqrt_s", 8), (2, "div_s", 8), (3, "log1p_s", 8)):
        _chains(kind, 4, 0.5)  # compile (the first call compiles all kinds: one signature)
        iters = chain_iters if kind < 3 else chain_iters // 4
        costs[name] = _best(lambda k=kind, it=iters: _chains(k, it, 0.5), repeats) / (iters * ops)
    return costs


def _row_lines(arr: np.ndarray) -> float:
    """Mean number of 64-byte cache lines one row (first axis) of ``arr`` spans, from its real addresses."""
    if arr.shape[0] == 0:
        return 0.0
    row = arr.strides[0]
    width = int(np.prod(arr.shape[1:])) * arr.itemsize if arr.ndim > 1 else arr.itemsize
    base = arr.ctypes.data
    starts = base + row * np.arange(min(arr.shape[0], 4096), dtype=np.int64)
    first = starts // LINE
    last = (starts + width - 1) // LINE
    return float(np.mean(last - first + 1))


def crossing_bounds(mesh: Any, costs: dict[str, float]) -> dict[str, float]:
    """Lower bounds (ns) for one cell crossing on ``mesh`` (a CellMesh) from ``measure_machine`` costs.

    lines_per_cell : cache lines the walk's records of one cell span (planes, neighbours, neighbour_face,
    media_ref, ref_point, gradient, size); memory_ns : lines_per_cell x 64 B at the triad bandwidth;
    packed_lines / packed_memory_ns : the same for the lean kernel's packed record (mesh/packed.py);
    arithmetic_ns : CROSSING_OPS at the measured operation costs.
    """
    from bentray.engine.mesh.packed import record_width

    arrays = (mesh.planes, mesh.neighbours, mesh.neighbour_face, mesh.media_ref, mesh.ref_point, mesh.gradient)
    lines = sum(_row_lines(a) for a in (*arrays, mesh.size))
    memory_ns = lines * LINE / (costs["triad_gb_s"] * 1e9) * 1e9
    ops = CROSSING_OPS
    arith_s = (
        ops["flops"] * costs["flop_s"]
        + ops["sqrt"] * costs["sqrt_s"]
        + ops["div"] * costs["div_s"]
        + ops["log1p"] * costs["log1p_s"]
    )
    packed_lines = record_width(mesh.planes.shape[1]) * 8 / LINE
    return {
        "lines_per_cell": lines,
        "memory_ns": memory_ns,
        "packed_lines": packed_lines,
        "packed_memory_ns": packed_lines * LINE / (costs["triad_gb_s"] * 1e9) * 1e9,
        "arithmetic_ns": arith_s * 1e9,
    }

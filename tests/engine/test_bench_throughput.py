"""The throughput section's pieces: the machine microkernels, the per-crossing bounds and the interleaved
kernel timing (no speed is asserted: speeds are the bench's output). The bounds are checked against
hand counts: a slab cell's records span a known number of cache lines."""

from __future__ import annotations

import math

import numpy as np

from bentray.engine.bench.machine import CROSSING_OPS, _row_lines, crossing_bounds, measure_machine


def test_machine_costs_are_positive_and_finite() -> None:
    costs = measure_machine(repeats=1, triad_mb=8, chain_iters=20_000)
    assert set(costs) == {"triad_gb_s", "flop_s", "sqrt_s", "div_s", "log1p_s"}
    assert all(math.isfinite(v) and v > 0.0 for v in costs.values())


def test_row_lines_counts_real_cache_line_spans() -> None:
    buf = np.zeros(64 * 20 + 8, dtype=np.uint8)
    off = (-buf.ctypes.data) % 64  # a 64-byte-aligned start
    aligned = np.frombuffer(buf[off : off + 64 * 16].data, dtype=np.float64).reshape(16, 8)  # 64-B rows
    assert _row_lines(aligned) == 1.0
    shifted = np.frombuffer(buf[off + 8 : off + 8 + 64 * 16].data, dtype=np.float64).reshape(16, 8)
    assert _row_lines(shifted) == 2.0  # every row straddles a line boundary
    small = np.frombuffer(buf[off : off + 8 * 64].data, dtype=np.float64)  # 1-D: one 8-byte item per row
    assert _row_lines(small) == 1.0


def test_bounds_scale_with_the_measured_costs() -> None:
    from bentray.engine.mesh.slabs import build_slab_mesh

    mesh = build_slab_mesh(np.zeros(3), np.array([10.0, 10.0, 10.0]), np.linspace(0, 10, 50), lambda z: 1 + 0 * z)
    costs = {"triad_gb_s": 10.0, "flop_s": 1e-9, "sqrt_s": 2e-9, "div_s": 3e-9, "log1p_s": 4e-9}
    b = crossing_bounds(mesh, costs)
    # slabs: 6 faces -> planes 192 B (3-4 lines), neighbours and neighbour_face 48 B (1-2 lines each),
    # ref_point and gradient 24 B (1-2 lines each), media_ref and size 8 B (1 line each)
    assert 10.0 <= b["lines_per_cell"] <= 16.0
    assert math.isclose(b["memory_ns"], b["lines_per_cell"] * 64 / 10.0)
    # the lean kernel's packed record: 6 x 6 + 8 = 44 doubles, padded to 48 = 6 whole lines
    assert b["packed_lines"] == 6.0 and math.isclose(b["packed_memory_ns"], 6 * 64 / 10.0)
    ops = CROSSING_OPS
    expected = ops["flops"] * 1.0 + ops["sqrt"] * 2.0 + ops["div"] * 3.0 + ops["log1p"] * 4.0
    assert math.isclose(b["arithmetic_ns"], expected)


def test_interleaved_kernel_timing_returns_every_kernel_with_equal_results() -> None:
    """Every kernel of still air reaches the same final states; the wind row really traced with the wind (its
    states differ, and equal a separate generic trace with that wind)."""
    from bentray.engine.bench.breakdown import _stratified_scene
    from bentray.engine.bench.throughput import KERNELS, WIND_KERNEL, measure_kernels, scene_wind
    from bentray.engine.tracer import trace

    sc = _stratified_scene(60)
    compiled: dict[str, float] = {}
    timed = measure_kernels(sc, 1, rounds=2, repeats=1, compiled=compiled)
    assert list(timed) == list(KERNELS) and set(compiled) == set(KERNELS)
    first = timed["generic"][1]
    for kernel, (elapsed, res) in timed.items():
        assert elapsed > 0.0
        if kernel != WIND_KERNEL:
            assert np.array_equal(res.position, first.position) and np.array_equal(res.crossings, first.crossings)
    windy = timed[WIND_KERNEL][1]
    assert not np.array_equal(windy.position, first.position)
    ref = trace(sc.mesh, "parabolic", 340.0, sc.origins, sc.directions, sc.start_cells, kernel="generic",
                wind=scene_wind(sc.name), max_time_s=10.0, max_reflections=3)  # fmt: skip
    assert np.array_equal(windy.position, ref.position)

"""The generic kernel on Python threads (traverse.trace_rays / trace_slots) and its borrowed inputs.

Oracles:
- the same trace on one thread: traverse.trace_rays splits the accumulator slots into contiguous ranges,
  one per thread, and each slot's rays and accumulators belong to that slot alone, so one thread and two
  (n_slots = 5: ranges of 2 and 3 slots) must give bit-identical final states, path samples, reflection
  records and beam accumulators (a slot skipped or traced twice would change them);
- numpy itself for kernels/borrow.py: a borrowed struct reads and writes the caller's arrays, strided
  views and nested named tuples included, and holds no reference (the arrays' reference counts in Python
  are unchanged after the call).
"""

from __future__ import annotations

import sys
from typing import NamedTuple

import numba
import numpy as np
import pytest

import bentray  # noqa: F401
from bentray.engine import beam_field
from bentray.engine.kernels.borrow import borrow
from bentray.engine.media import build_media
from bentray.engine.tracer import trace
from bentray.scenes.field_models import FieldSpec
from bentray.scenes.profile_models import profile_from_spec
from bentray.scenes.schema import Job

LO = np.array([-20.0, -60.0, 0.0])
HI = np.array([620.0, 60.0, 150.0])
SRC = np.array([0.0, 0.0, 2.0])


def _trace_on(threads: int):
    job = Job.model_validate(
        {
            "name": "threads",
            "scene": {"domain": {"min": LO.tolist(), "max": HI.tolist()}, "ground": {"kind": "flat"}},
            "profile": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
            "sources": [{"position": SRC.tolist()}],
            "rays": {"elevation_deg": {"min": -5, "max": 5, "count": 3}, "max_time_s": 1.7, "max_reflections": 6},
            "solver": {"curve": "parabolic", "representation": "slabs"},
            "outputs": ["report"],
        }
    )
    profile = profile_from_spec(job.profile)
    media = build_media(profile, "parabolic", job.solver, LO, HI, ground="reflect", top=job.scene.top.kind)
    el_axis, az_axis = np.linspace(-6.0, 6.0, 31), np.linspace(-4.0, 4.0, 7)
    el, az = np.meshgrid(el_axis, az_axis, indexing="ij")  # the launch fan's order (stages.launch_fan)
    el, az = np.radians(el.ravel()), np.radians(az.ravel())
    dirs = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    spec = FieldSpec.model_validate(
        {
            "origin": [20.0, -10.0, 1.5],
            "spacing": [10.0, 5.0, 3.0],
            "shape": [58, 5, 3],
            "frequencies_hz": [250.0],
            "mode": "coherent",
            "absorption": False,
        }  # fmt: skip
    )
    template = beam_field.prepare(
        spec,
        elevation_deg=el_axis,
        azimuth_deg=az_axis,
        n_rays=el.size,
        source_index=np.zeros(el.size, int),
        source_powers_w=None,
        materials=[None],
        max_reflections=6,
        c_ref=profile.c_ref,
        ground_sound_speed=340.0,
        n_face_materials=1,
    )
    buffers = template.like(template.weights, n_slots=5)
    cells = media.locate(SRC[None])
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        res = trace(
            media.mesh,
            "parabolic",
            profile.c_ref,
            np.repeat(SRC[None], el.size, axis=0),
            dirs,
            np.full(el.size, cells[0]),
            max_time_s=1.7,
            max_reflections=6,
            path_samples=8,
            field=buffers,
        )
    finally:
        numba.set_num_threads(before)
    return res, buffers


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two numba threads")
def test_two_threads_give_the_one_thread_trace_bit_for_bit():
    one, acc_one = _trace_on(1)
    two, acc_two = _trace_on(2)
    assert one.paths is not None and two.paths is not None
    for name in ("position", "direction", "time_s", "length_m", "status", "reflections", "crossings"):
        np.testing.assert_array_equal(getattr(two, name), getattr(one, name), err_msg=name)
    np.testing.assert_array_equal(two.paths.points, one.paths.points)
    np.testing.assert_array_equal(two.paths.offsets, one.paths.offsets)
    for k, (a, b) in enumerate(zip(acc_one.acc, acc_two.acc, strict=True)):
        np.testing.assert_array_equal(b, a, err_msg=f"BeamAcc field {k}")
    field = acc_one.collapse().collapsed
    assert field.p is not None and int(np.count_nonzero(field.p[0])) > 600  # beams reached 772 of 870 points
    assert int(np.count_nonzero(np.asarray(one.reflections))) > 150  # 203 of 217 rays reflect


class _Inner(NamedTuple):
    a: np.ndarray
    k: int


class _Outer(NamedTuple):
    inner: _Inner
    grid: np.ndarray
    out: np.ndarray
    pair: tuple[np.ndarray, np.ndarray]


@numba.njit(cache=False)
def _use_borrowed(o):
    o = borrow(o)
    total = 0.0
    for i in range(o.inner.a.shape[0]):
        total += o.inner.a[i] * o.inner.k
    for i in range(o.grid.shape[0]):
        for j in range(o.grid.shape[1]):
            total += o.grid[i, j]
    o.out[0] = total
    o.pair[1][:] = o.pair[0] + 1.0
    return total


def test_borrowed_structs_read_and_write_the_callers_arrays_and_hold_no_reference():
    rng = np.random.default_rng(3)
    a = rng.normal(size=7)
    base = rng.normal(size=(6, 8))
    grid = base[::2, 1::3]  # strided, not contiguous
    out = np.zeros(1)
    src, dst = rng.normal(size=4), np.zeros(4)
    _use_borrowed(_Outer(_Inner(a, 3), grid, out, (src, dst)))  # compiled here (compilation keeps references)
    refs = [sys.getrefcount(x) for x in (a, grid, out, src, dst)]
    total = _use_borrowed(_Outer(_Inner(a, 3), grid, out, (src, dst)))
    expected = float(np.sum(a * 3)) + float(np.sum(grid))
    assert total == pytest.approx(expected, rel=1e-14)
    assert out[0] == total
    np.testing.assert_array_equal(dst, src + 1.0)
    assert [sys.getrefcount(x) for x in (a, grid, out, src, dst)] == refs

"""The lean traversal (engine/kernels/lean.py) against the generic kernel: bit-identical final ray states.

The lean kernel is the generic walk without wind, field, paths and paraxial state, with faces that cannot
be exits skipped, packed cell records and interleaved lanes with prefetches: its arithmetic is unchanged, so
every final state (position, direction, time, length, status, reflections, crossings, nudges, segments) must
be *equal*, not close, on slabs, Delaunay tetrahedra (rays from a mesh vertex: the nudge and slide paths) and
the desert terrain, for one lane and several, with and without prefetch, 1,000+ rays each.
``trace(kernel="auto")`` must pick the lean kernel exactly for the plain parabolic case.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from bentray.engine.bench.common import sphere_directions
from bentray.engine.result import TraceResult
from bentray.engine.tracer import lean_applies, lean_queue, trace, trace_lean

FIELDS = ("position", "direction", "time_s", "length_m", "status", "reflections", "crossings", "nudges", "steps")


def _assert_identical(generic: TraceResult, lean: TraceResult) -> None:
    for name in FIELDS:
        a, b = getattr(generic, name), getattr(lean, name)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        bad = ~((a == b) | (np.isnan(a) & np.isnan(b)) if a.dtype.kind == "f" else (a == b))
        assert not bad.any(), f"{name}: {int(bad.sum())} of {len(a)} rays differ (first ray {np.argmax(bad)})"


def _compare(mesh: Any, o: np.ndarray, d: np.ndarray, cells: np.ndarray, **kw: Any) -> TraceResult:
    kw = {"max_time_s": 10.0, "max_reflections": 3, **kw}
    generic = trace(mesh, "parabolic", 340.0, o, d, cells, kernel="generic", **kw)
    for prefetch, lanes in ((0, 1), (1, 1), (0, 3), (1, 8)):
        _assert_identical(generic, trace_lean(mesh, 340.0, o, d, cells, prefetch=prefetch, lanes=lanes, **kw))
    _assert_identical(generic, trace(mesh, "parabolic", 340.0, o, d, cells, **kw))  # auto -> lean
    return generic


@pytest.fixture(scope="module")
def slabs():
    from bentray.engine.bench.breakdown import _stratified_scene

    return _stratified_scene(1200)


def test_slabs_bit_identical(slabs) -> None:
    sc = slabs
    res = _compare(sc.mesh, sc.origins, sc.directions, sc.start_cells, max_reflections=30)
    assert res.crossings.sum() > 100_000 and res.reflections.sum() > 0


def test_slabs_every_end_status(slabs) -> None:
    """A short time limit, no reflections allowed, then a step limit: each stop condition in both kernels."""
    sc = slabs
    short = _compare(sc.mesh, sc.origins, sc.directions, sc.start_cells, max_time_s=0.3, max_reflections=0)
    counts = short.status_counts()
    assert counts["time_limit"] and counts["reflection_limit"] and counts["exited"]
    capped = _compare(sc.mesh, sc.origins, sc.directions, sc.start_cells, max_time_s=3.0, max_steps=60)
    assert capped.status_counts()["step_limit"] == len(sc.origins)


def test_tets_bit_identical_from_an_interior_point_and_a_vertex() -> None:
    from bentray.engine.mesh.fcc import fcc_resample
    from bentray.engine.mesh.tets import build_tet_mesh

    lo, hi, h = np.zeros(3), np.array([200.0, 160.0, 120.0]), 18.0
    pts = fcc_resample(lo, hi, lambda x: np.full(len(x), h), d_min=h, d_max=h)
    n2 = lambda x: 1.0 + 2e-3 * x[:, 2] - 4e-4 * x[:, 0] + 1e-5 * x[:, 1] * x[:, 2] / 100.0  # noqa: E731
    tm = build_tet_mesh(lo, hi, pts, n2, spacing=lambda x: np.full(len(x), h))
    from bentray.engine.mesh.cells import locate_points

    d = sphere_directions(1200)
    inner = np.nonzero(np.all((tm.points > lo + 40) & (tm.points < hi - 40), axis=1))[0]
    starts = [np.array([97.3, 81.1, 33.7]), tm.points[inner[0]]]  # inside a cell; on a mesh vertex
    for src in starts:
        o = np.tile(src, (len(d), 1))
        cells = locate_points(tm.cells, o)
        res = _compare(tm.cells, o, d, cells, max_time_s=2.0, max_reflections=10)
        assert res.status_counts()["lost"] == 0


def test_rare_paths_bit_identical() -> None:
    """Nudges (a cell with no exit: lost after MAX_NUDGES_IN_A_ROW + 1), grazing launches a micrometre above
    the ground (slides along it) and a strong downward-refracting gradient (n^2 from 27 to 1): the rare-event
    paths."""
    from bentray.engine.constants import BOUNDARY_OPEN, FACE_UNUSED
    from bentray.engine.mesh.cells import CellMesh
    from bentray.engine.mesh.slabs import build_slab_mesh, locate_in_slabs

    planes = np.zeros((1, 4, 4))
    planes[0, 0] = [-1.0, 0.0, 0.0, 0.0]
    neighbours = np.full((1, 4), FACE_UNUSED, dtype=np.int64)
    neighbours[0, 0] = BOUNDARY_OPEN
    one = CellMesh(planes, neighbours, np.full((1, 4), -1, np.int64), np.ones(1), np.zeros((1, 3)), np.zeros((1, 3)),
                   np.ones(1), np.zeros((1, 4), np.int64))  # fmt: skip
    nudged = _compare(one, np.array([[1.0, 0, 0]]), np.array([[1.0, 0, 0]]), np.array([0]), max_time_s=1.0)
    assert nudged.nudges[0] > 0
    lo, hi = np.array([-50.0, -50.0, 0.0]), np.array([4000.0, 50.0, 2600.0])
    el = np.radians(np.linspace(-1e-3, 1e-3, 1001))
    d = np.column_stack([np.cos(el), np.zeros_like(el), np.sin(el)])
    z = np.concatenate([[0.0], np.geomspace(1e-6, 2600, 200)])
    mesh = build_slab_mesh(lo, hi, z, lambda zz: 1 + 0.01 * zz)
    o = np.tile([0, 0, 1e-6], (len(d), 1))
    _compare(mesh, o, d, locate_in_slabs(z, o), max_time_s=1.0, max_reflections=10)
    z = np.linspace(0, 2600, 51)
    mesh = build_slab_mesh(lo, hi, z, lambda zz: 1.0 + 1e-2 * (2600.0 - zz))
    d = sphere_directions(1001)
    o = np.tile([0, 0, 10], (len(d), 1))
    bounced = _compare(mesh, o, d, locate_in_slabs(z, o), max_time_s=10.0, max_reflections=10_000)
    assert bounced.reflections.sum() > 0


def test_desert_terrain_bit_identical() -> None:
    from bentray.engine.bench.scene_meshes import SceneUnavailable, build_scene_mesh

    try:
        sc = build_scene_mesh("desert", 1000)
    except SceneUnavailable as exc:  # pragma: no cover - the terrain builder is part of the install
        pytest.fail(f"desert terrain mesh unavailable: {exc}")
    res = _compare(sc.mesh, sc.origins, sc.directions, sc.start_cells)
    assert res.crossings.sum() > 50_000


def test_lanes_take_rays_that_start_outside_the_mesh_in_their_stride(slabs) -> None:
    """Rays with no start cell finish as lost at once, wherever they fall among the lanes' refills."""
    sc = slabs
    cells = sc.start_cells[:300].copy()
    cells[[0, 1, 2, 7, 8, 100, 101, 102, 103, 104, 105, 106, 107, 108, 299]] = -1
    res = _compare(sc.mesh, sc.origins[:300], sc.directions[:300], cells)
    assert res.status_counts()["lost"] == 15 and res.steps[cells < 0].max() == 0


def test_packed_records_copy_the_mesh_exactly_on_cache_lines(slabs) -> None:
    from bentray.engine.mesh.packed import pack_cells, packed_cells, record_width

    m = sc_mesh = slabs.mesh
    pc = pack_cells(m)
    k = m.planes.shape[1]
    assert pc.k_faces == k and pc.rec.shape == (m.n_cells, record_width(k)) and record_width(4) == 32
    assert pc.rec.ctypes.data % 64 == 0 and pc.rec.strides[0] % 64 == 0
    assert np.array_equal(pc.rec[:, : 4 * k].reshape(m.planes.shape), m.planes)
    assert np.array_equal(pc.rec[:, 4 * k : 4 * k + 3], m.gradient)
    assert np.array_equal(pc.rec[:, 4 * k + 3 : 4 * k + 6], m.ref_point)
    assert np.array_equal(pc.rec[:, 4 * k + 6], m.media_ref) and np.array_equal(pc.rec[:, 4 * k + 7], m.size)
    assert np.array_equal(pc.rec[:, 4 * k + 8 : 5 * k + 8].astype(np.int64), m.neighbours)
    assert np.array_equal(pc.rec[:, 5 * k + 8 : 6 * k + 8].astype(np.int64), m.neighbour_face)
    assert packed_cells(sc_mesh) is packed_cells(sc_mesh)  # built once per mesh


def test_packed_records_go_with_their_mesh() -> None:
    """A worker keeps no records of a finished job's mesh: the cache entry goes when the mesh's planes do."""
    import gc

    from bentray.engine.bench.breakdown import _stratified_scene
    from bentray.engine.mesh import packed

    sc = _stratified_scene(10)
    key = id(sc.mesh.planes)
    packed.packed_cells(sc.mesh)
    assert key in packed._CACHE
    del sc
    gc.collect()
    assert key not in packed._CACHE


def test_auto_picks_the_lean_kernel_only_for_the_plain_parabolic_trace() -> None:
    assert lean_applies("parabolic", 0, None, 0, False, False)
    assert not lean_applies("circular", 0, None, 0, False, False)
    assert not lean_applies("parabolic", 10, None, 0, False, False)  # paths
    assert not lean_applies("parabolic", 0, None, 1, False, False)  # wind
    assert not lean_applies("parabolic", 0, None, 0, True, False)  # paraxial
    assert not lean_applies("parabolic", 0, None, 0, False, True)  # reflection records


@pytest.mark.parametrize("chunk", [1, 3, 16])
def test_threads_sharing_one_queue_trace_every_ray_once(slabs, chunk: int) -> None:
    """Three threads run the kernel on one queue (the atomic counter hands out ``chunk`` rays per take): the
    outputs equal one thread's, bit for bit, every ray of the range traced once, none outside it touched."""
    from concurrent.futures import ThreadPoolExecutor

    from bentray.engine.constants import COUNT_SIZE, STATE_SIZE
    from bentray.engine.kernels.lean import trace_block_lanes
    from bentray.engine.mesh.packed import packed_cells

    sc = slabs
    n = sc.origins.shape[0]
    lo = 37  # the queue starts at taken[0]: rays below it are not the queue's
    limits = (10.0, 3, 10_000_000, 0, 4)

    def run(threads: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        state = np.full((n, STATE_SIZE), -7.0)
        counts = np.full((n, COUNT_SIZE), -7, dtype=np.int64)
        queue = (np.array([lo], dtype=np.int64), n, chunk)
        args = (packed_cells(sc.mesh), sc.mesh, 340.0, limits, sc.origins, sc.directions, sc.start_cells, state, counts)
        with ThreadPoolExecutor(max_workers=threads) as pool:
            list(pool.map(lambda _: trace_block_lanes(*args, queue), range(threads)))
        return state, counts, queue[0]

    one_state, one_counts, taken = run(1)
    assert taken[0] >= n
    assert (one_state[:lo] == -7.0).all() and (one_counts[:lo] == -7).all()
    assert (one_counts[lo:] >= 0).all() and one_counts[lo:].sum() > 0
    for _ in range(3):  # interleavings differ from run to run; every one must give the same outputs
        state, counts, taken = run(3)
        assert taken[0] >= n
        np.testing.assert_array_equal(state, one_state)
        np.testing.assert_array_equal(counts, one_counts)


def test_lean_queue_refuses_an_empty_chunk() -> None:
    with pytest.raises(ValueError, match="chunk must be at least 1"):
        lean_queue(10, chunk=0)
    taken, hi, chunk = lean_queue(10)
    assert taken.tolist() == [0] and hi == 10 and chunk >= 1


def test_kernel_lean_refuses_what_it_cannot_trace(slabs) -> None:
    sc = slabs
    for bad in ({"prefetch": 2}, {"lanes": 0}):
        with pytest.raises(ValueError, match="prefetch must be|lanes must be"):
            trace_lean(sc.mesh, 340.0, sc.origins[:2], sc.directions[:2], sc.start_cells[:2], max_time_s=1.0,
                       max_reflections=1, **bad)  # fmt: skip
    with pytest.raises(ValueError, match="kernel='lean' traces only"):
        trace(sc.mesh, "parabolic", 340.0, sc.origins[:2], sc.directions[:2], sc.start_cells[:2], max_time_s=1.0,
              max_reflections=1, path_samples=5, kernel="lean")  # fmt: skip
    with pytest.raises(ValueError, match="kernel must be one of"):
        trace(sc.mesh, "parabolic", 340.0, sc.origins[:2], sc.directions[:2], sc.start_cells[:2], max_time_s=1.0,
              max_reflections=1, kernel="fast")  # fmt: skip

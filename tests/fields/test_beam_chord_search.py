"""A chord's candidate points (engine/kernels/beams.py ``deposit_chord``): narrowing each column to the indices
between the chord's end planes, and its ground images to those within reach of the mirror plane, changes no
number. Oracle: tests/reference/beam_deposit.py, the search as it was (every point of the chord's box, every
image scanned upward), accumulators compared bit for bit.

Chords: straight-ray samples (free-field paraxial derivatives) in random directions over a sloping, bumpy
terrain grid with mirror planes, including exactly horizontal and exactly vertical tangents, rays going down and
up, chords that start below the ground plane, a steep slope and a nearly vertical mirror plane (the image range
is then not narrowed), in the incoherent mode with the Fresnel floor and in the semicoherent mode without it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bentray.engine.acoustics.ground import build_q_table
from bentray.engine.beam_field import _new_acc, beam_grid
from bentray.engine.field_buffers import FieldGrid
from bentray.engine.kernels import beams
from bentray.engine.kernels.beams import BeamTables
from tests.reference.beam_deposit import deposit_chord_scan

FREQS = np.array([125.0, 1000.0])


def _terrain(fg: FieldGrid, rng: np.random.Generator, steep: bool) -> tuple[np.ndarray, np.ndarray]:
    """Ground height under each column (m) and its tangent plane (nx, ny, 4): unit normal (up) and offset."""
    nx, ny, _ = fg.shape
    x = fg.origin[0] + np.arange(nx) * fg.spacing[0]
    y = fg.origin[1] + np.arange(ny) * fg.spacing[1]
    xx, yy = np.meshgrid(x, y, indexing="ij")
    slope = 1.5 if steep else 0.08
    h = slope * (xx - x[0]) + 6.0 * np.exp(-((xx - x[nx // 2]) ** 2 + (yy - y[ny // 2]) ** 2) / 900.0)
    gx, gy = np.gradient(h, fg.spacing[0], fg.spacing[1])
    n = np.stack([-gx, -gy, np.ones_like(h)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    if steep:
        n[0, 0] = [1.0, 0.0, 1e-12]  # a nearly vertical plane: no image range
        n[0, 0] /= np.linalg.norm(n[0, 0])
    ground = np.stack([xx, yy, h], axis=-1)
    d = np.sum(n * ground, axis=-1) + rng.normal(0.0, 0.05, h.shape)
    return h, np.ascontiguousarray(np.concatenate([n, d[..., None]], axis=-1))


def _record(x: np.ndarray, t: np.ndarray, arc: float, e1: np.ndarray, e2: np.ndarray) -> np.ndarray:
    r = np.zeros(beams.SAMPLE_SIZE)
    r[beams.S_X : beams.S_X + 3] = x
    r[beams.S_T : beams.S_T + 3] = t
    r[beams.S_TIME] = arc / 340.0
    r[beams.S_ARC] = arc
    r[beams.S_X1 : beams.S_X1 + 3] = arc * e1
    r[beams.S_X2 : beams.S_X2 + 3] = arc * e2
    r[beams.S_P1 : beams.S_P1 + 3] = e1
    r[beams.S_P2 : beams.S_P2 + 3] = e2
    r[beams.S_SLOW] = 1.0 / 340.0
    return r


def _chords(rng: np.random.Generator, fg: FieldGrid, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    lo = fg.origin
    hi = fg.origin + (np.array(fg.shape) - 1) * fg.spacing
    out = []
    specials = [(0.0, 0.3), (math.pi / 2, 0.0), (-math.pi / 2, 0.0), (0.0, 0.0), (-0.3, math.pi)]
    for m in range(n):
        el, az = specials[m] if m < len(specials) else (rng.uniform(-1.4, 1.4), rng.uniform(-math.pi, math.pi))
        d = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        e1 = np.array([-math.sin(el) * math.cos(az), -math.sin(el) * math.sin(az), math.cos(el)])
        e2 = np.array([-math.sin(az), math.cos(az), 0.0])
        arc = rng.uniform(30.0, 1500.0)
        mid = rng.uniform(lo, hi) + np.array(
            [0.0, 0.0, rng.choice([rng.uniform(-5.0, 25.0), rng.uniform(25.0, 150.0)])]
        )
        length = rng.uniform(2.0, 12.0)
        a = mid - 0.5 * length * d
        b = mid + 0.5 * length * d
        out.append((_record(a, d, arc, e1, e2), _record(b, d, arc + length, e1, e2)))
    return out


@pytest.mark.parametrize(("mode", "fresnel_k", "steep"), [("incoherent", 0.108, False), ("semicoherent", 0.0, True)])
def test_chord_search_matches_full_scan(mode: str, fresnel_k: float, steep: bool) -> None:
    rng = np.random.default_rng(11 if steep else 7)
    fg = FieldGrid(np.array([-100.0, -60.0, 1.0]), np.array([20.0, 15.0, 5.0]), (14, 9, 12))
    h, mirror = _terrain(fg, rng, steep)
    grid = beam_grid(fg, mode, FREQS, 340.0, (0.02, 0.05), 0.3, 2, z_offset=h, fresnel_k=fresnel_k, mirror=mirror)
    q = build_q_table(list(FREQS), [None, 200_000.0], c=340.0)
    tabs = BeamTables(q.table, q.grid, np.array([1e-4, 4e-3]), 10.0, np.zeros((0, 9)))
    acc = _new_acc(grid, fg.n_points, 1)
    ref = _new_acc(grid, fg.n_points, 1)
    refl_cos = np.array([0.3, 0.0])
    refl_mat = np.array([1, 0], np.int64)
    amp0 = np.ones(FREQS.size)
    work = np.zeros(beams.WORK_SIZE)
    terms = np.zeros(beams.PB_SIZE)
    total = 0
    far = 0  # chords chord_far rejects
    direct = 0  # the same chords without mirror planes: the images' share is total - direct
    flat = grid._replace(mirror=np.zeros((0, 0, 4)))
    scratch = _new_acc(grid, fg.n_points, 1)
    for sa, sb in _chords(rng, fg, 600):
        n_refl = int(rng.integers(0, 2))
        sa[beams.S_NREFL] = sb[beams.S_NREFL] = n_refl
        group = beams.group_index(grid.n_refl, n_refl, 0)
        launch_cos = 0.9
        outs = []
        for a in (acc, ref):
            s_a, s_b = sa.copy(), sb.copy()  # each search computes the amplitudes on its first deposit
            amp_a, amp_b = np.zeros((2, FREQS.size)), np.zeros((2, FREQS.size))
            chord = (s_a, s_b, amp_a, amp_b, group, 1, launch_cos, tabs, refl_cos, refl_mat, amp0)
            if a is acc:
                outs.append(beams.deposit_chord(grid, a, 0, chord, work, terms))
            else:
                outs.append(deposit_chord_scan(grid, a, 0, chord))
        assert outs[0] == outs[1]
        if beams.chord_far(grid, sa, sb):  # the traversal's pre-test (columns and BeamGrid.z_top) drops no term
            far += 1
            assert outs[0] == 0
        total += outs[0]
        chord = (sa.copy(), sb.copy(), np.zeros((2, FREQS.size)), np.zeros((2, FREQS.size)), group, 1, launch_cos)
        direct += deposit_chord_scan(flat, scratch, 0, chord + (tabs, refl_cos, refl_mat, amp0))
    assert direct > 300 and total - direct > 200  # the chords reach the grid: points and images
    assert steep or far > 50  # and some do not (above the grid's top; the steep grid's top is above them all)
    for name in acc._fields:
        assert np.array_equal(getattr(acc, name), getattr(ref, name)), name

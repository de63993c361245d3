"""Beam deposits: the per-band amplitudes computed on a chord's first deposit give the same bits as computing
them at every sample (engine/kernels/beams.py, docs/physics.md §11).

The kernels compute a sample's amplitude (absorption and the Q of its reflections) only when a chord ending or
starting there deposits, find each reflection's Q-table cell once for all bands, and skip the exact reach of a
chord whose box, widened by a square-root-free bound, misses the grid. None of this may change a number:

- ``_amplitude`` against the formulation it replaced (one ``q_lookup`` per band and reflection), bit for bit,
  on random arcs, incidence cosines and material sequences (rigid faces included);
- a ray (straight, with its exact free-field paraxial derivatives, one soft-ground reflection, partly outside the
  grid) through ``ray_sample`` against a brute-force reference: every chord's amplitudes computed eagerly with the
  old formulation and its beam evaluated at *every* grid point (no search box), summed in chord order; the
  accumulators (weights, hits, energies, coherent sums) must be equal bit for bit.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from bentray.engine.acoustics.ground import build_q_table, q_lookup
from bentray.engine.beam_field import _new_acc, beam_grid, bin_points
from bentray.engine.field_buffers import FieldGrid
from bentray.engine.kernels import beams
from bentray.engine.kernels.beams import BeamTables

FREQS = np.array([125.0, 500.0, 2000.0])
ALPHA = np.array([2e-4, 1e-3, 8e-3])


@nb.njit(cache=False)
def _amplitude_per_band(tabs, arc, n_refl, refl_cos, refl_mat, out):
    """The amplitude as the kernels formed it before: per band, exp(-alpha s / 2) times one Q per reflection."""
    for f in range(out.shape[1]):
        re = math.exp(-0.5 * tabs.alpha[f] * arc)
        im = 0.0
        for j in range(min(n_refl, refl_cos.shape[0])):
            mat = refl_mat[j]
            if mat <= 0:
                continue
            qr, qi = q_lookup(tabs.q_table, tabs.q_grid, mat, f, refl_cos[j], arc)
            re, im = re * qr - im * qi, re * qi + im * qr
        out[0, f] = re
        out[1, f] = im


@nb.njit(cache=False)
def _amplitude_now(tabs, arc, n_refl, refl_cos, refl_mat, out):
    beams._amplitude(tabs, arc, n_refl, refl_cos, refl_mat, out)


def _tables() -> BeamTables:
    q = build_q_table(list(FREQS), [None, 20_000.0, 300_000.0], c=340.0)
    return BeamTables(q.table, q.grid, ALPHA.copy(), 4.0, np.zeros((0, 9)))


def test_amplitude_matches_per_band_lookup() -> None:
    tabs = _tables()
    rng = np.random.default_rng(3)
    a = np.zeros((2, FREQS.size))
    b = np.zeros((2, FREQS.size))
    for _ in range(400):
        n_refl = int(rng.integers(0, 5))
        refl_cos = rng.uniform(-0.05, 1.05, 3)  # beyond [0, 1] too: the table clamps
        refl_mat = rng.integers(0, 3, 3).astype(np.int64)
        arc = float(rng.choice([0.0, rng.uniform(0.1, 3000.0)]))
        _amplitude_per_band(tabs, arc, n_refl, refl_cos, refl_mat, a)
        _amplitude_now(tabs, arc, n_refl, refl_cos, refl_mat, b)
        assert np.array_equal(a, b), (arc, n_refl, refl_cos, refl_mat)


def _ray_samples(src: np.ndarray, el: float, az: float, ds: float, s_max: float) -> list[tuple]:
    """Samples (x, T, time, arc, par, slow, n_refl, start_new, cos) of a straight ray in c = 340 m/s over the
    plane z = 0 (mirrored there, the reflection sample twice: incoming end, outgoing start)."""
    c = 340.0
    d = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    de = np.array([-math.sin(el) * math.cos(az), -math.sin(el) * math.sin(az), math.cos(el)])
    da = np.array([-math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), 0.0])
    s_hit = -src[2] / d[2] if d[2] < 0 else math.inf
    arcs = sorted({*np.arange(0.0, s_max, ds).tolist(), s_hit} - {math.inf})
    out = []
    for s in arcs:
        m = np.array([1.0, 1.0, -1.0]) if s > s_hit else np.ones(3)
        x = (src + s * d) * m
        par = np.concatenate([s * de * m, s * da * m, de * m, da * m])  # X1, X2, P1, P2 (n = 1)
        n_refl = 1 if s > s_hit else 0
        out.append((x, d * m, s / c, s, par, 1.0 / c, n_refl, False, abs(d[2])))
        if s == s_hit:
            m = np.array([1.0, 1.0, -1.0])
            par = np.concatenate([s * de * m, s * da * m, de * m, da * m])
            out.append((x * m, d * m, s / c, s, par, 1.0 / c, 1, True, abs(d[2])))
    return out


def _record(x, t, time, arc, par, slow) -> np.ndarray:
    r = np.zeros(beams.SAMPLE_SIZE)
    r[beams.S_X : beams.S_X + 3] = x
    r[beams.S_T : beams.S_T + 3] = t
    r[beams.S_TIME] = time
    r[beams.S_ARC] = arc
    r[beams.S_X1 : beams.S_X1 + 6] = par[:6]
    r[beams.S_P1 : beams.S_P1 + 6] = par[6:]
    r[beams.S_SLOW] = slow
    return r


def test_lazy_amplitudes_match_eager_brute_force() -> None:
    tabs = _tables()
    fg = FieldGrid(np.array([40.0, -30.0, 0.5]), np.array([10.0, 6.0, 2.0]), (26, 11, 9))
    grid = beam_grid(fg, "semicoherent", FREQS, 340.0, (0.05, 0.1), 0.3, 2)
    acc = _new_acc(grid, fg.n_points, 1)
    beam = beams.Beam(grid, acc, tabs, grid, _new_acc(grid, 0, 1), bin_points(np.zeros((0, 3))))
    src = np.array([0.0, 0.0, 12.0])
    el, az = math.radians(-4.0), math.radians(3.0)
    samples = _ray_samples(src, el, az, 4.0, 330.0)
    launch_cos = math.cos(el)
    refl_cos = np.zeros(2)
    refl_mat = np.zeros(2, np.int64)
    ray = beams.new_ray(FREQS.size)
    total = 0
    for x, t, time, arc, par, slow, n_refl, start_new, cos in samples:
        if n_refl:
            refl_cos[0], refl_mat[0] = cos, 1
        total += beams.ray_sample(
            beam, 0, ray, x, t, time, arc, slow, par, (n_refl, refl_cos, refl_mat, launch_cos), start_new
        )
    assert total > 200  # the ray passes through the grid, before and after its reflection

    # reference: eager amplitudes (the old formulation), every point of the grid, chords in order
    ref = _new_acc(grid, fg.n_points, 1)
    amp_a = np.zeros((2, FREQS.size))
    amp_b = np.zeros((2, FREQS.size))
    terms = np.zeros(beams.PB_SIZE)
    nx, ny, nz = fg.shape
    pts = [
        (((i * ny + j) * nz + k), fg.origin + np.array([i, j, k]) * fg.spacing)
        for i in range(nx)
        for j in range(ny)
        for k in range(nz)
    ]
    prev = None
    for x, t, time, arc, par, slow, n_refl, start_new, _ in samples:
        rec = _record(x, t, time, arc, par, slow)
        _amplitude_per_band(tabs, arc, n_refl, refl_cos, refl_mat, amp_b)
        if prev is not None and not start_new:
            group = beams.group_index(grid.n_refl, n_refl, 0)
            chord = (prev, rec, amp_a, amp_b, group, 0, launch_cos)
            for v, p in pts:
                if not beams.point_beam_terms(grid, chord, p[0], p[1], p[2], terms):
                    continue
                w, u = terms[beams.PB_W], terms[beams.PB_U]
                ref.weight[0, group, v] += w
                ref.hits[0, v] += 1.0
                for f in range(FREQS.size):
                    ref.energy[0, group, f, v] += beams.band_energy(
                        amp_a[0, f], amp_a[1, f], amp_b[0, f], amp_b[1, f], u, w, terms[beams.PB_REL_I]
                    )
                    re, im = beams.band_coherent(
                        amp_a[0, f],
                        amp_a[1, f],
                        amp_b[0, f],
                        amp_b[1, f],
                        u,
                        0,
                        grid.omega[f],
                        terms[beams.PB_TAU],
                        terms[beams.PB_AMP],
                    )
                    ref.s_re[0, group, f, v] += re
                    ref.s_im[0, group, f, v] += im
        prev = rec
        amp_a, amp_b = amp_b.copy(), amp_a
    assert float(ref.hits.sum()) == total
    for name in ("weight", "hits", "energy", "s_re", "s_im"):
        assert np.array_equal(getattr(acc, name), getattr(ref, name)), name

"""Beam-field deposits on the device: the CPU's beam steps (engine/kernels/beams.py), accumulated with atomics.

What runs here is only what differs from the CPU: the accumulation. The sample record (caustic count, amplitude,
ground reflection factors on a chord's first deposit: ``beams.sample_record`` / ``beams.sample_shift`` /
``beams.chord_amplitudes``), the search box of a chord (``beams.chord_box``, ``beams.points_box``) and its
candidate ranges (``beams._slab_k_range``, ``beams._image_k_range``), a point's beam (``beams.point_beam``: hat
weight, intensity, travel time, foot interpolation) and its per-band terms (``beams.band_energy``,
``beams.band_coherent``) are the CPU's own CPU-jitted functions, which numba-cuda compiles as device functions
(engine/gpu/kernel.py's docstring).
The CPU adds the terms with ``+=`` into its thread's slot; here every thread adds them into the one accumulator
slot (slot 0 of each BeamAcc array) with ``cuda.atomic.add``.

Reduction order: a point's sums receive their terms in the order the device's atomics happen to run (threads and
blocks in no defined order), so the accumulated sums are not bit-reproducible from run to run, and differ from
the CPU's (rays summed in slot order) by floating-point rounding of the reordered sums only: each term itself is
the CPU's (bit-identical under numba's simulator; to FMA / libdevice rounding on a device). Measured under the
simulator: tests/gpu/test_cuda_field_simulator.py.

Per-ray work arrays: the per-band amplitude arrays of a ray (``BeamRay.amp_last`` / ``amp_cur`` / ``amp0``, F bands,
not a compile-time size) are rows of :class:`BeamScratch` in global memory, one row per thread of a launch; the
fixed-size ones are ``cuda.local.array`` in the kernel.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numba import cuda as _cuda

from bentray.engine.kernels import beams, curves, paraxial
from bentray.engine.kernels.beams import BEAM_COHERENT, BEAM_INCOHERENT, BEAM_OFF, PB_AMP, PB_REL_I, PB_TAU, PB_U, PB_W
from bentray.engine.kernels.traverse import _p_at

__all__ = ["BeamScratch", "beam_segment_device", "ray_sample_device"]

cuda: Any = _cuda  # numba.cuda's atomic / local are injected at run time (no type information)


class BeamScratch(NamedTuple):
    """Per-thread amplitude rows of a launch (row t for thread t): amp_last, amp_cur (T, 2, F); amp0 (T, F)."""

    amp_last: np.ndarray
    amp_cur: np.ndarray
    amp0: np.ndarray


@cuda.jit(device=True)
def _add_atomic(grid, acc, chord, v, terms):
    """``beams._accumulate`` with atomics into slot 0 (the device's one accumulator): the same per-band terms
    (the chord's amplitudes first computed where not yet, as on the CPU: ``beams.chord_amplitudes``)."""
    beams.chord_amplitudes(chord)
    amp_a = chord[2]
    amp_b = chord[3]
    group = chord[4]
    kmah = chord[5]
    w = terms[PB_W]
    u = terms[PB_U]
    cuda.atomic.add(acc.weight, (0, group, v), w)
    cuda.atomic.add(acc.hits, (0, v), 1.0)
    n_f = grid.omega.shape[0]
    if grid.mode != BEAM_COHERENT:
        rel_i = terms[PB_REL_I]
        for f in range(n_f):
            e = beams.band_energy(amp_a[0, f], amp_a[1, f], amp_b[0, f], amp_b[1, f], u, w, rel_i)
            cuda.atomic.add(acc.energy, (0, group, f, v), e)
        if acc.near_w.shape[0] > 0:
            near = terms[beams.PB_NEAR]
            cuda.atomic.add(acc.near_w, (0, 0, group, v), near)
            cuda.atomic.add(acc.near_w, (0, 1, group, v), w * rel_i)
            if near > 0.0:
                for f in range(n_f):
                    e = beams.band_energy(amp_a[0, f], amp_a[1, f], amp_b[0, f], amp_b[1, f], u, near, 1.0)
                    cuda.atomic.add(acc.near_amp, (0, group, f, v), e)
    if grid.mode != BEAM_INCOHERENT:
        tau = terms[PB_TAU]
        amp = terms[PB_AMP]
        for f in range(n_f):
            re, im = beams.band_coherent(
                amp_a[0, f], amp_a[1, f], amp_b[0, f], amp_b[1, f], u, kmah, grid.omega[f], tau, amp
            )
            cuda.atomic.add(acc.s_re, (0, group, f, v), re)
            cuda.atomic.add(acc.s_im, (0, group, f, v), im)


@cuda.jit(device=True)
def _beam_atomic(grid, acc, chord, tc, px, py, pz, v, terms):
    """The beam of the chord at point (px, py, pz) (``beams.point_beam`` on the chord's values tc = (ta, tb, gc))
    added atomically to point v; True when the chord owns the point."""
    if not beams.write_terms(terms, beams.point_beam(tc[0], tc[1], tc[2], chord[6], px, py, pz)):
        return False
    _add_atomic(grid, acc, chord, v, terms)
    return True


@cuda.jit(device=True)
def _deposit_chord_atomic(grid, acc, chord, scratch, terms):
    """``beams.deposit_chord`` with atomic accumulation: the same search box, candidate ranges
    (``beams._slab_k_range``, ``beams._image_k_range``), points, images and terms; points and images in two
    passes (the order of atomics is undefined anyway)."""
    i0, i1, j0, j1, z_lo, z_hi = beams.chord_box(grid, chord[0], chord[1])
    if i0 > i1 or j0 > j1:
        return 0
    ta = beams.sample_values(chord[0])
    tb = beams.sample_values(chord[1])
    tc = (ta, tb, beams.grid_values(grid))
    ny = grid.shape[1]
    nz = grid.shape[2]
    dz = grid.spacing[2]
    count = 0
    for i in range(i0, i1 + 1):
        px = grid.origin[0] + i * grid.spacing[0]
        for j in range(j0, j1 + 1):
            py = grid.origin[1] + j * grid.spacing[1]
            zo = grid.origin[2] + grid.z_offset[i, j]
            k0, k1 = beams._index_range(z_lo, z_hi, zo, dz, nz)
            if k0 <= k1:
                k0, k1 = beams._slab_k_range(ta, tb, (px, py, zo), (0.0, 0.0, dz), k0, k1)
            for k in range(k0, k1 + 1):
                if _beam_atomic(grid, acc, chord, tc, px, py, zo + k * dz, (i * ny + j) * nz + k, terms):
                    count += 1
    if grid.mirror.shape[0] > 0:
        count += _deposit_mirrored_atomic(grid, acc, chord, tc, terms, (i0, i1, j0, j1, z_lo, z_hi))
    return count


@cuda.jit(device=True)
def _deposit_mirrored_atomic(grid, acc, chord, tc, terms, box):
    """The ground images of ``beams.deposit_chord`` with atomic accumulation: the same columns (the box one wider
    each way), index ranges and per-image tests (``beams.mirror_point``'s, inline), the same terms."""
    i0, i1, j0, j1, z_lo, z_hi = box
    nx = grid.shape[0]
    ny = grid.shape[1]
    nz = grid.shape[2]
    dz = grid.spacing[2]
    reach = 0.5 * (z_hi - z_lo)
    count = 0
    for i in range(max(i0 - 1, 0), min(i1 + 1, nx - 1) + 1):
        px = grid.origin[0] + i * grid.spacing[0]
        for j in range(max(j0 - 1, 0), min(j1 + 1, ny - 1) + 1):
            py = grid.origin[1] + j * grid.spacing[1]
            zo = grid.origin[2] + grid.z_offset[i, j]
            m = (grid.mirror[i, j, 0], grid.mirror[i, j, 1], grid.mirror[i, j, 2], grid.mirror[i, j, 3])
            n0, n1 = beams._image_k_range(tc[0], tc[1], px, py, zo, dz, nz, m, reach, (z_lo, z_hi))
            for k in range(n0, n1 + 1):
                pz = zo + k * dz
                h = m[0] * px + m[1] * py + m[2] * pz - m[3]
                if h < 0.0 or h > reach:
                    if pz > zo + 2.0 * reach + dz:
                        break
                    continue
                qz = pz - 2.0 * h * m[2]
                if qz < z_lo or qz > z_hi:
                    continue
                if _beam_atomic(grid, acc, chord, tc, px - 2.0 * h * m[0], py - 2.0 * h * m[1], qz,
                                (i * ny + j) * nz + k, terms):  # fmt: skip
                    count += 1
    return count


@cuda.jit(device=True)
def _deposit_points_atomic(grid, acc, pts, chord, scratch, terms):
    """``beams.deposit_points`` with atomic accumulation."""
    i0, i1, j0, j1, k0, k1 = beams.points_box(grid, pts, chord[0], chord[1])
    count = 0
    ny = pts.bin_shape[1]
    nz = pts.bin_shape[2]
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            for k in range(k0, k1 + 1):
                b = (i * ny + j) * nz + k
                for e in range(pts.bin_start[b], pts.bin_start[b + 1]):
                    v = pts.bin_items[e]
                    if beams.point_beam_terms(grid, chord, pts.xyz[v, 0], pts.xyz[v, 1], pts.xyz[v, 2], terms):
                        _add_atomic(grid, acc, chord, v, terms)
                        count += 1
    return count


@cuda.jit(device=True)
def ray_sample_device(beam, ray, x, tangent, time, arc, slow, par, refl, start_new):
    """``beams.ray_sample`` on the device (no slot: the accumulators' slot 0, atomically). Arguments as there."""
    reached = 0
    if beams.sample_record(ray, x, tangent, time, arc, slow, par, refl[0], start_new):
        n_refl = refl[0]
        launch_cos = refl[3]
        kmah = ray.ist[1]
        grid = beam.grid
        tabs = beam.tabs
        if grid.mode != BEAM_OFF and not beams.chord_far(grid, ray.last, ray.cur):  # as beams.ray_sample
            group = beams.chord_group(grid.n_refl, n_refl, kmah)
            chord = beams.ray_chord(ray, group, kmah, launch_cos, tabs, refl)
            reached = _deposit_chord_atomic(grid, beam.acc, chord, ray.work, ray.terms)
        if beam.pts.xyz.shape[0] > 0:
            group = beams.chord_group(beam.p_grid.n_refl, n_refl, kmah)
            chord = beams.ray_chord(ray, group, kmah, launch_cos, tabs, refl)
            reached += _deposit_points_atomic(beam.p_grid, beam.p_acc, beam.pts, chord, ray.work, ray.terms)
    beams.sample_shift(ray)
    return reached


@cuda.jit(device=True)
def beam_segment_device(beam, bray, prm, cs, x, d, seg, par, scratch, refl):
    """``traverse._beam_segment`` on the device: beam samples inside a segment longer than the chord length."""
    param, t, s, ds, smooth_cell = seg
    par_tmp, p_tmp, xs, ts = scratch
    chord = beam.tabs.chord_m
    if ds <= chord:
        return
    n_int = int(ds / chord)
    for j in range(1, n_int + 1):
        sig = param * j / (n_int + 1)
        dsj = curves.evaluate(prm.curve, cs, x, d, sig, xs, ts)
        tj = t + curves.time_at(prm.curve, cs, sig, prm.c_ref)
        if smooth_cell >= 0:  # the smooth medium (traverse._beam_segment)
            for q in range(paraxial.PAR_SIZE):
                par_tmp[q] = par[q]
            paraxial.smooth_advance(par_tmp, beam.tabs.hessian, smooth_cell, sig)
        else:
            paraxial.advanced_copy(par, sig, par_tmp)
        nj = _p_at(cs, sig, p_tmp)
        ray_sample_device(beam, bray, xs, ts, tj, s + dsj, nj / prm.c_ref, par_tmp, refl, False)

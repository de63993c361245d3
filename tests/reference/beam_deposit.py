"""The beam field's chord search as it was before its candidate ranges (engine/kernels/beams.py, 2026-12-04):
the oracle of tests/fields/test_beam_chord_search.py.

Every column of the chord's box (``beams.chord_box``), every point of the column's height range, then, where the
grid has mirror planes, every column of the box widened by one, scanning each column's images upward from its
lowest point until one is beyond reach (``beams.mirror_point``). Each candidate's beam through
``beams.point_beam_terms`` and added with ``beams._accumulate``, all points before all images. The engine's
``deposit_chord`` must give the same accumulators bit for bit: its index ranges only skip candidates that cannot
be owned, and its per-column order (a point before its own image) keeps each point's sums in the same order.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from bentray.engine.kernels import beams


@nb.njit(cache=False)
def deposit_chord_scan(grid, acc, slot, chord):
    """Reference ``beams.deposit_chord`` (same arguments but the work arrays); returns the contributions added."""
    terms = np.zeros(beams.PB_SIZE)
    img = np.zeros(3)
    i0, i1, j0, j1, z_lo, z_hi = beams.chord_box(grid, chord[0], chord[1])
    nx = grid.shape[0]
    ny = grid.shape[1]
    nz = grid.shape[2]
    count = 0
    for i in range(i0, i1 + 1):
        px = grid.origin[0] + i * grid.spacing[0]
        for j in range(j0, j1 + 1):
            py = grid.origin[1] + j * grid.spacing[1]
            zo = grid.origin[2] + grid.z_offset[i, j]
            k0, k1 = beams._index_range(z_lo, z_hi, zo, grid.spacing[2], nz)
            for k in range(k0, k1 + 1):
                if beams.point_beam_terms(grid, chord, px, py, zo + k * grid.spacing[2], terms):
                    beams.chord_amplitudes(chord)
                    beams._accumulate(
                        grid, acc, slot, chord[2], chord[3], chord[4], chord[5], (i * ny + j) * nz + k, terms
                    )
                    count += 1
    if grid.mirror.shape[0] == 0 or i0 > i1 or j0 > j1:
        return count
    reach = 0.5 * (z_hi - z_lo)
    for i in range(max(i0 - 1, 0), min(i1 + 1, nx - 1) + 1):
        px = grid.origin[0] + i * grid.spacing[0]
        for j in range(max(j0 - 1, 0), min(j1 + 1, ny - 1) + 1):
            py = grid.origin[1] + j * grid.spacing[1]
            zo = grid.origin[2] + grid.z_offset[i, j]
            for k in range(nz):
                pz = zo + k * grid.spacing[2]
                if not beams.mirror_point(grid, i, j, px, py, pz, reach, img):
                    if pz > zo + 2.0 * reach + grid.spacing[2]:
                        break
                    continue
                if img[2] < z_lo or img[2] > z_hi:
                    continue
                if beams.point_beam_terms(grid, chord, img[0], img[1], img[2], terms):
                    beams.chord_amplitudes(chord)
                    beams._accumulate(
                        grid, acc, slot, chord[2], chord[3], chord[4], chord[5], (i * ny + j) * nz + k, terms
                    )
                    count += 1
    return count

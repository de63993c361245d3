"""Compiled per-cell least-squares systems for the cell gradients (gradients.py; paper Sec. 5.3, Eq. 11-13).

``cell_centroids`` and ``lsq_systems`` do in one pass per cell what ``gradients.lsq_gradients`` does with
batched numpy: the normal equations A = sum_k w_k^2 (x_k - x_0)(x_k - x_0)^T, b = sum_k w_k^2 (x_k - x_0)
(m_k - m_0), in the same floating-point operations and order as the numpy formula (so A and b are
bit-identical to it), and the accept / fall back decision lambda_min >= rcond_min lambda_max.

Most cells are decided from the invariants of the positive semi-definite A (eigenvalues l0 <= l1 <= l2,
trace tr, sum of principal 2x2 minors i2, determinant det): l0 >= 4 det / tr^2 and l2 <= tr, so
4 det >= c (1 + INVARIANT_MARGIN) tr^3 accepts (c = rcond_min); l0 <= 3 det / i2 and l2 >= tr / 3, so
9 det <= c (1 - INVARIANT_MARGIN) tr i2 rejects. Their rounding (~1e-14 tr^3 in det) moves neither test by
more than ~1e-9 l2 where it could matter, far inside the margin's c 1e-3 l2. The other cells (about 12 % on
the README mesh) take the closed-form (trigonometric: Smith 1961) extreme eigenvalues, whose absolute error
is at most ~1e-7 lambda_max (acos loses half the digits where two eigenvalues nearly coincide); a cell
whose lambda_min - rcond_min lambda_max lies within EIG_MARGIN lambda_max of zero is marked undecided
(status 2): the caller decides it with LAPACK's eigvalsh exactly as the numpy formula does, and every
decision is the numpy formula's. The 3x3 solves stay in numpy (LAPACK gesv, bit-identical).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from bentray.engine.constants import NJIT_FLAGS

# Half-width of the undecided band of lambda_min - rcond_min lambda_max, relative to lambda_max: 100x the
# worst-case error of the closed-form eigenvalues (~1e-7 lambda_max), 1 % of the default rcond_min.
EIG_MARGIN = 1e-5
# Relative margin of the invariant tests (module docstring): they decide only cells at least 0.1 % of
# rcond_min away from the threshold, which no rounding in them can reach.
INVARIANT_MARGIN = 1e-3

LSQ_ACCEPT = 0  # least squares well posed: solve A g = b
LSQ_REJECT = 1  # fewer than 3 usable neighbours, or lambda_min < rcond_min lambda_max: fall back
LSQ_UNDECIDED = 2  # within EIG_MARGIN of the threshold: decide with LAPACK eigvalsh


@nb.njit(**NJIT_FLAGS)
def _centroids(points, tets, values, centroids, media_ref):  # pragma: no cover - compiled
    for t in range(tets.shape[0]):
        v0, v1, v2, v3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        for i in range(3):  # numpy's mean over 4 items: added in order, then / 4
            centroids[t, i] = (((points[v0, i] + points[v1, i]) + points[v2, i]) + points[v3, i]) / 4.0
        media_ref[t] = (((values[v0] + values[v1]) + values[v2]) + values[v3]) / 4.0


def cell_centroids(points: np.ndarray, tets: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (T, 3) metres and media_ref (T,) = mean of the 4 vertex values, bit-identical to
    ``points[tets].mean(axis=1)`` and ``values[tets].mean(axis=1)``.

    points : (P, 3) float64 metres; tets : (T, 4) int64; values : (P,) float64.
    """
    centroids = np.empty((len(tets), 3))
    media_ref = np.empty(len(tets))
    _centroids(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(tets, dtype=np.int64),
               np.ascontiguousarray(values, dtype=np.float64), centroids, media_ref)  # fmt: skip
    return centroids, media_ref


@nb.njit(**NJIT_FLAGS)
def _sym3_extreme_eigenvalues(a00, a01, a02, a11, a12, a22):  # pragma: no cover - compiled
    """(lambda_min, lambda_max) of the symmetric 3x3 matrix, closed form (trigonometric)."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    d0, d1, d2 = a00 - q, a11 - q, a22 - q
    p2 = d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * p1
    if p2 == 0.0:
        return q, q
    p = math.sqrt(p2 / 6.0)
    b00, b11, b22 = d0 / p, d1 / p, d2 / p
    b01, b02, b12 = a01 / p, a02 / p, a12 / p
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    r = min(1.0, max(-1.0, r))
    phi = math.acos(r) / 3.0
    return q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0), q + 2.0 * p * math.cos(phi)


@nb.njit(**NJIT_FLAGS)
def _lsq_systems(x0, m0, nbrs, weighted, rcond_min, a, b, status):  # pragma: no cover - compiled
    n, kmax = nbrs.shape
    rows = np.empty((kmax, 3))
    rhs = np.empty(kmax)
    for c in range(n):
        count = 0
        for k in range(kmax):
            j = nbrs[c, k]
            if j < 0:
                j = 0  # numpy gathers cell 0 and weights it 0
            dx0, dx1, dx2 = x0[j, 0] - x0[c, 0], x0[j, 1] - x0[c, 1], x0[j, 2] - x0[c, 2]
            dm = m0[j] - m0[c]
            dist = math.sqrt((dx0 * dx0 + dx1 * dx1) + dx2 * dx2)  # numpy's norm over 3 items, in order
            valid = nbrs[c, k] >= 0 and dist > 0.0
            if valid:
                count += 1
                w = 1.0 / dist if weighted else 1.0
            else:
                w = 0.0
            rows[k, 0], rows[k, 1], rows[k, 2] = dx0 * w, dx1 * w, dx2 * w
            rhs[k] = dm * w
        for i in range(3):  # einsum "nki,nkj->nij" and "nki,nk->ni": products summed over k in order
            for j in range(i, 3):
                s = 0.0
                for k in range(kmax):
                    s += rows[k, i] * rows[k, j]
                a[c, i, j] = s
                a[c, j, i] = s
            s = 0.0
            for k in range(kmax):
                s += rows[k, i] * rhs[k]
            b[c, i] = s
        if count < 3:
            status[c] = LSQ_REJECT
            continue
        a00, a01, a02, a11, a12, a22 = a[c, 0, 0], a[c, 0, 1], a[c, 0, 2], a[c, 1, 1], a[c, 1, 2], a[c, 2, 2]
        tr = a00 + a11 + a22
        det = a00 * (a11 * a22 - a12 * a12) - a01 * (a01 * a22 - a12 * a02) + a02 * (a01 * a12 - a11 * a02)
        if tr > 0.0 and 4.0 * det >= rcond_min * (1.0 + INVARIANT_MARGIN) * tr * tr * tr:
            status[c] = LSQ_ACCEPT
            continue
        i2 = (a00 * a11 - a01 * a01) + (a00 * a22 - a02 * a02) + (a11 * a22 - a12 * a12)
        if tr > 0.0 and 9.0 * det <= rcond_min * (1.0 - INVARIANT_MARGIN) * tr * i2:
            status[c] = LSQ_REJECT
            continue
        lo, hi = _sym3_extreme_eigenvalues(a00, a01, a02, a11, a12, a22)
        gap = lo - rcond_min * hi
        if abs(gap) <= EIG_MARGIN * abs(hi) or not hi > 0.0:
            status[c] = LSQ_UNDECIDED
        elif gap > 0.0:
            status[c] = LSQ_ACCEPT
        else:
            status[c] = LSQ_REJECT


def lsq_systems(
    centroids: np.ndarray, centroid_values: np.ndarray, neighbours: np.ndarray, weighted: bool, rcond_min: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normal equations and closed-form decision of the least-squares cell gradients.

    centroids : (n, 3) float64 metres; centroid_values : (n,) float64; neighbours : (n, K) int64 (negative:
    ignored); weighted : rows weighted by 1 / |x_k - x_0|. Returns a (n, 3, 3), b (n, 3) (bit-identical to
    ``gradients.lsq_gradients``' einsums) and status (n,) int8: LSQ_ACCEPT, LSQ_REJECT or LSQ_UNDECIDED.
    """
    n = len(centroids)
    a = np.empty((n, 3, 3))
    b = np.empty((n, 3))
    status = np.empty(n, dtype=np.int8)
    _lsq_systems(np.ascontiguousarray(centroids, dtype=np.float64),
                 np.ascontiguousarray(centroid_values, dtype=np.float64),
                 np.ascontiguousarray(neighbours, dtype=np.int64), bool(weighted), float(rcond_min), a, b,
                 status)  # fmt: skip
    return a, b, status


@nb.njit(**NJIT_FLAGS)
def _green_gauss_systems(points, tets, cells, values, e, dm):  # pragma: no cover - compiled
    for n in range(cells.shape[0]):
        t = cells[n]
        v0 = tets[t, 0]
        for i in range(3):
            vi = tets[t, i + 1]
            for k in range(3):
                e[n, i, k] = points[vi, k] - points[v0, k]
            dm[n, i] = values[vi] - values[v0]


def green_gauss_systems(
    points: np.ndarray, tets: np.ndarray, cells: np.ndarray, values: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The P1 gradient systems e g = dm of the listed cells, as ``gradients.green_gauss_gradients``
    builds them: e (n, 3, 3) rows p_i - p_0 (metres), dm (n, 3) m_i - m_0.

    points : (P, 3) float64 metres; tets : (T, 4) int64; cells : (n,) int64 cell ids; values : (P,) float64.
    """
    e = np.empty((len(cells), 3, 3))
    dm = np.empty((len(cells), 3))
    _green_gauss_systems(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(tets, dtype=np.int64),
                         np.ascontiguousarray(cells, dtype=np.int64), np.ascontiguousarray(values, dtype=np.float64),
                         e, dm)  # fmt: skip
    return e, dm

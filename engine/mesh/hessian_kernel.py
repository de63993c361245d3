"""Compiled per-cell geometry and Hessian assembly for engine/mesh/hessian.py (one pass per cell).

The same quantities as the batched-numpy formulas kept in tests/reference/hessian_numpy.py (the oracle): a
convex cell's vertices (three of its face planes meeting inside every other used face), each face's area (the
polygon of its vertices, ordered by angle about their mean and fanned into triangles), the vertex centroid, the
cell's volume (sum of face area x centroid-to-plane distance / 3), and the interior Hessian
``sym(sum_f A_f dg_f n_f^T / (V_c + V_nb))`` with the face moments ``M = sum_f A_f n_f n_f^T`` over the inner and
over all used faces (for the boundary scaling, which stays in numpy: LAPACK's pseudo-inverse, few cells).

What differs from the numpy oracle is rounding only: a vertex here is Cramer's rule on the three planes
(``(d_a n_b x n_c + d_b n_c x n_a + d_c n_a x n_b) / det``) where numpy's batched solve factorises, and sums
run in cell order, and a triangle's area skips the angle sort (its fan has the same three edges in any order).
Measured against the oracle, relative to each cell's largest entry: 3.2e-12 at worst on a 28,017-tet test mesh;
on the consultant example's 1.76 million tetrahedra 2.8e-10 at worst and 3.0e-11 at the 99.9th percentile (the
vertices of near-degenerate cells, where the two solves round differently), centroids to 2.5e-11 m;
tests/mesh/test_hessian_kernel.py holds 1e-9. The vertex test's tolerance (1e-9 of the plane offsets) is the
oracle's. On that mesh the numpy formulas took 16.5-18.8 s (14 s in the vertices and areas, through (n, V, 3)
temporaries), this 1.3-1.6 s with the boundary cells' pseudo-inverses.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from bentray.engine.constants import FACE_UNUSED, NJIT_FLAGS

__all__ = ["cell_geometry"]

# |det| of the three unit normals below which a triple of faces has no vertex (the oracle's threshold)
DET_MIN = 1e-12
# a vertex lies on / inside a plane within this fraction of the cell's largest plane offset (at least 1 m)
ON_PLANE_REL = 1e-9


@nb.njit(**NJIT_FLAGS)
def _triples(k):
    """(C(k, 3), 3) face triples in itertools.combinations order (the oracle's vertex slots)."""
    n = k * (k - 1) * (k - 2) // 6
    out = np.empty((n, 3), np.int64)
    s = 0
    for a in range(k):
        for b in range(a + 1, k):
            for c in range(b + 1, k):
                out[s, 0] = a
                out[s, 1] = b
                out[s, 2] = c
                s += 1
    return out


@nb.njit(**NJIT_FLAGS)
def cell_geometry(planes, neighbours, gradient):
    """Per-cell geometry and interior Hessian.

    planes : (n, K, 4) unit outward normal and offset (n.x = d, m); neighbours : (n, K) int (FACE_UNUSED for an
    unused slot, < 0 for a boundary face); gradient : (n, 3) the traced quantity's gradient per cell.
    Returns (centre (n, 3) m, areas (n, K) m^2, volume (n,) m^3, half (n, 3, 3) = sum_f w_f dg_f n_f^T per m^2
    (not yet symmetrised), m_all (n, 3, 3), m_inner (n, 3, 3) m^2, ok (n,) bool: False for a cell without a
    vertex (its planes bound nothing)). Allocates its outputs and one small work buffer.
    """
    n = planes.shape[0]
    k = planes.shape[1]
    triples = _triples(k)
    nv = triples.shape[0]
    pts = np.empty((nv, 3))
    valid = np.zeros(nv, np.bool_)
    ang = np.empty(nv)
    order = np.empty(nv, np.int64)
    centre = np.zeros((n, 3))
    areas = np.zeros((n, k))
    volume = np.zeros(n)
    ok = np.ones(n, np.bool_)
    for i in range(n):
        scale = 1.0
        for f in range(k):
            scale = max(scale, abs(planes[i, f, 3]))
        tol = ON_PLANE_REL * scale
        cnt = 0
        cx = cy = cz = 0.0
        for s in range(nv):
            valid[s] = False
            a = triples[s, 0]
            b = triples[s, 1]
            c = triples[s, 2]
            if neighbours[i, a] == FACE_UNUSED or neighbours[i, b] == FACE_UNUSED or neighbours[i, c] == FACE_UNUSED:
                continue
            # n_b x n_c, n_c x n_a, n_a x n_b
            ax, ay, az = planes[i, a, 0], planes[i, a, 1], planes[i, a, 2]
            bx, by, bz = planes[i, b, 0], planes[i, b, 1], planes[i, b, 2]
            qx, qy, qz = planes[i, c, 0], planes[i, c, 1], planes[i, c, 2]
            bc0 = by * qz - bz * qy
            bc1 = bz * qx - bx * qz
            bc2 = bx * qy - by * qx
            det = ax * bc0 + ay * bc1 + az * bc2
            if not abs(det) > DET_MIN:
                continue
            ca0 = qy * az - qz * ay
            ca1 = qz * ax - qx * az
            ca2 = qx * ay - qy * ax
            ab0 = ay * bz - az * by
            ab1 = az * bx - ax * bz
            ab2 = ax * by - ay * bx
            da = planes[i, a, 3]
            db = planes[i, b, 3]
            dc = planes[i, c, 3]
            px = (da * bc0 + db * ca0 + dc * ab0) / det
            py = (da * bc1 + db * ca1 + dc * ab1) / det
            pz = (da * bc2 + db * ca2 + dc * ab2) / det
            inside = True
            for f in range(k):
                if neighbours[i, f] == FACE_UNUSED:
                    continue
                if planes[i, f, 0] * px + planes[i, f, 1] * py + planes[i, f, 2] * pz - planes[i, f, 3] > tol:
                    inside = False
                    break
            if not inside:
                continue
            pts[s, 0] = px
            pts[s, 1] = py
            pts[s, 2] = pz
            valid[s] = True
            cnt += 1
            cx += px
            cy += py
            cz += pz
        if cnt == 0:
            ok[i] = False
            continue
        cx /= cnt
        cy /= cnt
        cz /= cnt
        centre[i, 0] = cx
        centre[i, 1] = cy
        centre[i, 2] = cz
        vol = 0.0
        for f in range(k):
            if neighbours[i, f] == FACE_UNUSED:
                continue
            mx, my, mz, md = planes[i, f, 0], planes[i, f, 1], planes[i, f, 2], planes[i, f, 3]
            # the face's vertices, their mean, and angles in an in-plane frame (u, w)
            m_cnt = 0
            fx = fy = fz = 0.0
            for s in range(nv):
                if valid[s] and abs(pts[s, 0] * mx + pts[s, 1] * my + pts[s, 2] * mz - md) <= tol:
                    order[m_cnt] = s
                    m_cnt += 1
                    fx += pts[s, 0]
                    fy += pts[s, 1]
                    fz += pts[s, 2]
            area = 0.0
            if m_cnt >= 3:
                fx /= m_cnt
                fy /= m_cnt
                fz /= m_cnt
            if m_cnt > 3:  # a triangle's fan has the same three edges in any order: no angles needed
                hx, hy, hz = (1.0, 0.0, 0.0) if abs(mx) < 0.9 else (0.0, 1.0, 0.0)
                ux = my * hz - mz * hy
                uy = mz * hx - mx * hz
                uz = mx * hy - my * hx
                un = math.sqrt(ux * ux + uy * uy + uz * uz)
                ux /= un
                uy /= un
                uz /= un
                wx = my * uz - mz * uy
                wy = mz * ux - mx * uz
                wz = mx * uy - my * ux
                for t in range(m_cnt):
                    s = order[t]
                    rx = pts[s, 0] - fx
                    ry = pts[s, 1] - fy
                    rz = pts[s, 2] - fz
                    ang[t] = math.atan2(rx * wx + ry * wy + rz * wz, rx * ux + ry * uy + rz * uz)
                # insertion sort of the face's vertices by angle (a handful)
                for t in range(1, m_cnt):
                    a_t = ang[t]
                    o_t = order[t]
                    r = t - 1
                    while r >= 0 and ang[r] > a_t:
                        ang[r + 1] = ang[r]
                        order[r + 1] = order[r]
                        r -= 1
                    ang[r + 1] = a_t
                    order[r + 1] = o_t
            if m_cnt >= 3:
                for t in range(m_cnt):
                    s0 = order[t]
                    s1 = order[(t + 1) % m_cnt]
                    r0x, r0y, r0z = pts[s0, 0] - fx, pts[s0, 1] - fy, pts[s0, 2] - fz
                    r1x, r1y, r1z = pts[s1, 0] - fx, pts[s1, 1] - fy, pts[s1, 2] - fz
                    kx = r0y * r1z - r0z * r1y
                    ky = r0z * r1x - r0x * r1z
                    kz = r0x * r1y - r0y * r1x
                    area += 0.5 * abs(kx * mx + ky * my + kz * mz)
            areas[i, f] = area
            vol += area * abs(md - (mx * cx + my * cy + mz * cz))
        volume[i] = vol / 3.0
    half = np.zeros((n, 3, 3))
    m_all = np.zeros((n, 3, 3))
    m_inner = np.zeros((n, 3, 3))
    for i in range(n):
        if not ok[i]:
            continue
        for f in range(k):
            nb_ = neighbours[i, f]
            if nb_ == FACE_UNUSED:
                continue
            a_f = areas[i, f]
            inner = nb_ >= 0
            w = a_f / (volume[i] + volume[nb_]) if inner else 0.0
            for r in range(3):
                dg = gradient[nb_, r] - gradient[i, r] if inner else 0.0
                for c in range(3):
                    mm = planes[i, f, r] * planes[i, f, c] * a_f
                    m_all[i, r, c] += mm
                    if inner:
                        m_inner[i, r, c] += mm
                        half[i, r, c] += w * dg * planes[i, f, c]
    return centre, areas, volume, half, m_all, m_inner, ok

"""n and grad n from a CellMesh's per-cell linear media model, with the cell found by walking.

With ``media='mesh'`` the numerical integrators see exactly the media the analytic tracer sees: inside
cell i the traced quantity is linear, ``m(x) = media_ref[i] + gradient[i] . (x - ref_point[i])``, with
m = n^2, c or n (``QUANTITY_CODES``, the same integers as the curve codes of constants.CURVE_QUANTITY).
It converts to the refractive index ``n = c_ref / c`` and its gradient by the chain rule:

    n2: n = sqrt(m),  grad n = grad m / (2 n)
    c:  n = c_ref / m, grad n = -c_ref grad m / m^2
    n:  n = m,         grad n = grad m

The cell containing a point is found by walking from a nearby cell (the ray's current cell) toward
the most violated face plane, as the analytic traversal re-locates rays; shared faces hold identical
planes of opposite sign, so the walk never oscillates across one face. A point beyond a boundary face
stops the walk in the last cell (its linear model is extrapolated; the tracer treats the crossing as a
boundary event). Arrays are those of ``engine.mesh.cells.CellMesh`` (metres, world frame).
"""

from __future__ import annotations

import math

import numba as nb

from bentray.engine.constants import CURVE_CIRCULAR, CURVE_NLINEAR, CURVE_PARABOLIC, FACE_UNUSED, NJIT_FLAGS

__all__ = ["QUANTITY_CODES", "WALK_FAILED", "WALK_INSIDE", "walk", "mesh_n_and_grad", "mesh_n_and_grad_at"]

QUANTITY_N2 = CURVE_PARABOLIC
QUANTITY_C = CURVE_CIRCULAR
QUANTITY_N = CURVE_NLINEAR
QUANTITY_CODES = {"n2": QUANTITY_N2, "c": QUANTITY_C, "n": QUANTITY_N}

WALK_INSIDE = -1  # walk result: the point is inside (or within eps of) the returned cell
WALK_FAILED = -2  # walk result: no convergence within WALK_MAX_MOVES (a cycle: degenerate mesh)
# A step of an integrator near the ground of a graded slab mesh can cross thousands of micrometre
# layers; one cell per move, so the cap is large. Walks in a convex mesh terminate; the cap only
# turns a degenerate cycle into the ``lost`` status instead of a hang.
WALK_MAX_MOVES = 1_000_000


@nb.njit(**NJIT_FLAGS)
def walk(planes, neighbours, cell, x, eps):
    """Walk from ``cell`` to the cell containing ``x`` (3,) metres.

    A face counts as violated when ``m . x - h > eps`` (eps in metres, >= 0). Returns
    ``(cell, face, moves)``: face = WALK_INSIDE when x is inside ``cell``; a face index when x lies
    beyond that boundary face of ``cell`` (neighbours[cell, face] is BOUNDARY_OPEN or BOUNDARY_REFLECT);
    WALK_FAILED when the walk did not converge. ``moves`` counts the cells crossed.
    """
    moves = 0
    for _ in range(WALK_MAX_MOVES):
        worst = eps
        worst_face = WALK_INSIDE
        for f in range(planes.shape[1]):
            if neighbours[cell, f] == FACE_UNUSED:
                continue
            d = planes[cell, f, 0] * x[0] + planes[cell, f, 1] * x[1] + planes[cell, f, 2] * x[2] - planes[cell, f, 3]
            if d > worst:
                worst = d
                worst_face = f
        if worst_face == WALK_INSIDE:
            return cell, WALK_INSIDE, moves
        nxt = neighbours[cell, worst_face]
        if nxt < 0:
            return cell, worst_face, moves
        cell = nxt
        moves += 1
    return cell, WALK_FAILED, moves


@nb.njit(**NJIT_FLAGS)
def mesh_n_and_grad(planes, neighbours, media_ref, ref_point, gradient, quantity, c_ref, cell, x, out_grad):
    """Refractive index n at ``x`` (3,) from the linear model of the cell containing it.

    ``cell`` is a hint (a cell near x, normally the ray's current cell). Writes grad n (1/m) into
    ``out_grad`` (3,) and returns ``(n, cell_found)``; n is NaN when the walk failed, and <= 0 or NaN
    for unphysical media (the tracer's ``lost`` status).
    """
    return mesh_n_and_grad_at(planes, neighbours, media_ref, ref_point, gradient, quantity, c_ref, cell, x, out_grad, 0)


@nb.njit(**NJIT_FLAGS)
def mesh_n_and_grad_at(planes, neighbours, media_ref, ref_point, gradient, quantity, c_ref, cell, x, out, k):
    """:func:`mesh_n_and_grad` writing grad n into ``out[k:k+3]`` (no array view in the hot path)."""
    if cell < 0:
        out[k] = math.nan
        out[k + 1] = math.nan
        out[k + 2] = math.nan
        return math.nan, cell
    cell, face, _ = walk(planes, neighbours, cell, x, 0.0)
    if face == WALK_FAILED:
        out[k] = math.nan
        out[k + 1] = math.nan
        out[k + 2] = math.nan
        return math.nan, cell
    gx = gradient[cell, 0]
    gy = gradient[cell, 1]
    gz = gradient[cell, 2]
    m = (
        media_ref[cell]
        + gx * (x[0] - ref_point[cell, 0])
        + gy * (x[1] - ref_point[cell, 1])
        + gz * (x[2] - ref_point[cell, 2])
    )
    if quantity == QUANTITY_N2:
        n = math.sqrt(m) if m > 0.0 else math.nan
        f = 1.0 / (2.0 * n)
    elif quantity == QUANTITY_C:
        n = c_ref / m
        f = -c_ref / (m * m)
    else:
        n = m
        f = 1.0
    out[k] = f * gx
    out[k + 1] = f * gy
    out[k + 2] = f * gz
    return n, cell

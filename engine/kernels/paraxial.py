"""Paraxial rays for the parabolic curve: exact launch-angle derivatives of what the tracer computes.

State ``par`` (12,) float64: ``X_1 = par[0:3]``, ``X_2 = par[3:6]`` (dx/dgamma_k, metres per radian) and
``P_1 = par[6:9]``, ``P_2 = par[9:12]`` (dp/dgamma_k, p = n T, per radian), gamma = (elevation,
azimuth). Inside one cell the parabolic map ``x(sigma) = x0 + p0 sigma + g sigma^2 / 4``,
``p(sigma) = p0 + g sigma / 2`` is affine in (x0, p0), so (docs/physics.md §10):

- launch from a point source: ``X_k = 0``, ``P_k = n0 dd0/dgamma_k``;
- inside a cell at fixed sigma: ``X_k(sigma) = X_k + P_k sigma``, ``P_k`` constant;
- leaving through a face (plane m.x = h) at sigma_f, the neighbouring ray meets the face
  ``d sigma_k = -(m.X_k)/(m.p)`` later; the derivatives *on the face* are
  ``X_k += p d sigma_k``, ``P_k += (g/2) d sigma_k`` (:func:`onto_face`);
- every segment starts by re-evaluating n at the entry point with the (new) cell's model and keeping
  the direction: ``p' = n'(x) p / |p|``; its derivative is
  ``P_k' = (g'.X_k)/(2 n') d + (n'/|p|) (P_k - d (d.P_k))`` (:func:`restart`); where n^2 is continuous
  this is the identity, and it is exact for the piecewise-linear media the mesh carries;
- specular reflection with R = I - 2 m m^T: ``X_k -> R X_k`` (X_k lies in the plane after
  :func:`onto_face`), ``P_k -> R P_k``.

With wind the per-cell gradient is taken at the middle of the chord through the cell, which depends on
the entry state; that dependence is not differentiated (first order in the cell size), nor are the
rare slide and nudge moves (counted in the ray's nudges).
"""

from __future__ import annotations

import math

import numba as nb

from bentray.engine.constants import NJIT_FLAGS

PAR_SIZE = 12


@nb.njit(inline="always", **NJIT_FLAGS)
def launch(par, d, n0):
    """Point-source launch: X = 0, P_k = n0 dd/dgamma_k for d = (cos el cos az, cos el sin az, sin el).

    d : (3,) unit launch direction (elevation and azimuth are recovered from it).
    """
    ch = math.sqrt(d[0] * d[0] + d[1] * d[1])  # cos el
    if ch > 0.0:
        ca = d[0] / ch
        sa = d[1] / ch
    else:
        ca = 1.0
        sa = 0.0
    se = d[2]
    for i in range(6):
        par[i] = 0.0
    # d/d el = (-sin el cos az, -sin el sin az, cos el);  d/d az = (-cos el sin az, cos el cos az, 0)
    par[6] = -n0 * se * ca
    par[7] = -n0 * se * sa
    par[8] = n0 * ch
    par[9] = -n0 * ch * sa
    par[10] = n0 * ch * ca
    par[11] = 0.0


@nb.njit(inline="always", **NJIT_FLAGS)
def advance(par, sigma):
    """X_k += P_k sigma (in place): the derivatives at parameter sigma of the current cell's curve."""
    for i in range(3):
        par[i] += par[6 + i] * sigma
        par[3 + i] += par[9 + i] * sigma


@nb.njit(inline="always", **NJIT_FLAGS)
def advanced_copy(par, sigma, out):
    """out = the derivatives at parameter sigma (par unchanged)."""
    for i in range(3):
        out[i] = par[i] + par[6 + i] * sigma
        out[3 + i] = par[3 + i] + par[9 + i] * sigma
        out[6 + i] = par[6 + i]
        out[9 + i] = par[9 + i]


@nb.njit(inline="always", **NJIT_FLAGS)
def onto_face(par, plane, p, g, max_dsig):
    """Derivatives on the face plane (m, h) reached with slowness vector p: see the module docstring.

    max_dsig : bound on |d sigma_k| (inf: exact). A ray that crosses a face between two cells nearly
    tangentially has |m.p| -> 0 and d sigma_k -> inf: the exact derivative of the piecewise-linear medium
    there is a kick (g_old - g_new)/2 d sigma_k that a continuous medium does not have; on terrain-following
    tets it flips tubes (spurious caustics, speckled maps). The traversal passes inf (exact) except when the
    state feeds beams and the face is slanted (constants.BEAM_KICK_BOUND_NZ): then cell size / n (the ridge
    map's point noise 1.7 -> 0.16 dB). trace(paraxial=True) without beams always gets the exact derivatives.
    """
    mp = plane[0] * p[0] + plane[1] * p[1] + plane[2] * p[2]
    if mp == 0.0:
        return
    for k in range(2):
        o = 3 * k
        mx = plane[0] * par[o] + plane[1] * par[o + 1] + plane[2] * par[o + 2]
        dsig = -mx / mp
        if dsig > max_dsig:
            dsig = max_dsig
        elif dsig < -max_dsig:
            dsig = -max_dsig
        for i in range(3):
            par[o + i] += p[i] * dsig
            par[6 + o + i] += 0.5 * g[i] * dsig


@nb.njit(inline="always", **NJIT_FLAGS)
def restart(par, d, p_norm, n_new, g_new):
    """Derivatives of the restart ``p' = n_new(x) d`` with d = p/|p| (p_norm = |p| before, n_new after)."""
    if not (p_norm > 0.0 and n_new > 0.0):
        return
    scale = n_new / p_norm
    for k in range(2):
        o = 3 * k
        gx = g_new[0] * par[o] + g_new[1] * par[o + 1] + g_new[2] * par[o + 2]
        dp = d[0] * par[6 + o] + d[1] * par[7 + o] + d[2] * par[8 + o]
        along = 0.5 * gx / n_new
        for i in range(3):
            par[6 + o + i] = along * d[i] + scale * (par[6 + o + i] - d[i] * dp)


@nb.njit(inline="always", **NJIT_FLAGS)
def reflect(par, m):
    """Specular reflection of the derivatives off the plane with unit normal m (after onto_face)."""
    for k in range(4):
        o = 3 * k
        dot = m[0] * par[o] + m[1] * par[o + 1] + m[2] * par[o + 2]
        for i in range(3):
            par[o + i] -= 2.0 * dot * m[i]

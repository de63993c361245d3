"""One straight edge of a rigid wedge: its frame, the diffracted path of a point source (Keller's cone), the
UTD field along it, and the geometrical-acoustics field of the wedge (direct + face reflections).

Frames and units: world frame, metres; wavenumbers k (F,) rad/m; pressures relative to the 1 m
free-field amplitude (the free field is exp(i k R) / R), time factor exp(-i w t).

Edge frame: the edge line ``point + y e``; ``face0`` the unit vector lying in face 0, perpendicular to the
edge, pointing away from the edge; angles phi measured from face 0 about e (right hand), through the air,
0 <= phi <= n pi (the wedge's exterior angle; the solid fills (n pi, 2 pi)). A thin screen is n = 2, a
rectangular building's roof edge or vertical corner n = 3/2. A finite edge covers ``y_min <= y <= y_max``:
its diffracted field is the infinite edge's times the share of the stationary-phase (Fresnel-zone)
integral along the edge that falls on the segment (:func:`bentray.engine.diffraction.kernels.fresnel_segment`):
1 in the middle of a long edge, 1/2 where the stationary point is at an end, -> 0 beyond it, so the field
fades continuously past the end of an edge instead of switching off.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bentray.engine.diffraction.kernels import EPS_ON_BOUNDARY, fresnel_segment, wedge_coefficients

__all__ = [
    "DiffractedLeg",
    "Edge",
    "boundary_min",
    "boundary_share",
    "cross",
    "cylindrical",
    "diffracted_field",
    "edge_legs",
    "finite_share",
    "geometric_field",
    "rows_dot",
    "share_near_boundary",
    "utd_field",
]

_TOL = EPS_ON_BOUNDARY  # rad: a point this close to a geometric boundary gets half of that wave


class Edge(NamedTuple):
    """A straight rigid wedge edge (module docstring): point (3,), direction e (3,) unit, face0 (3,) unit
    perpendicular to e, exterior angle n pi (n in (1, 2]), extent y_min..y_max metres along e.

    A batch of edges, one per point, has point, direction and face0 (N, 3) (same n and extent): the
    functions here and :func:`bentray.engine.diffraction.paths.edge_paths` then pair edge i with point i
    (terrain screening, one crest per path)."""

    point: np.ndarray
    direction: np.ndarray
    face0: np.ndarray
    n: float = 2.0
    y_min: float = -np.inf
    y_max: float = np.inf


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.cross(a, b) of vectors (3,) or rows (N, 3), the same arithmetic without numpy's axis moves."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def rows_dot(v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """v @ a for one vector a (3,); the row-wise dot products for a batch a (N, 3) with v (N, 3)."""
    if a.ndim == 1:
        return v @ a
    return np.einsum("...i,...i->...", v, a)


def cylindrical(edge: Edge, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rho, phi in [0, 2 pi), y) of points xyz (..., 3) about the edge (m, rad, m); a batch of edges
    (class Edge) pairs edge i with point i."""
    e = np.asarray(edge.direction, float)
    a = np.asarray(edge.face0, float)
    b = cross(e, a)
    d = np.asarray(xyz, float) - np.asarray(edge.point, float)
    x1, x2, y = rows_dot(d, a), rows_dot(d, b), rows_dot(d, e)
    return np.hypot(x1, x2), np.mod(np.arctan2(x2, x1), 2.0 * np.pi), y


class DiffractedLeg(NamedTuple):
    """The straight diffracted path source -> edge point -> receiver, arrays (N,): s_in (source to edge
    point, m), s_out (edge point to receiver, m), phi_in / phi_out (rad), sin_b0 (sine of the angle between
    the path and the edge), y_e (the edge point along e, m), share (complex, the finite edge's share)."""

    s_in: np.ndarray
    s_out: np.ndarray
    phi_in: np.ndarray
    phi_out: np.ndarray
    sin_b0: np.ndarray
    y_e: np.ndarray
    share: np.ndarray


def edge_legs(edge: Edge, src: np.ndarray, rec: np.ndarray, k_share: float, share: bool = True) -> DiffractedLeg:
    """The stationary (Keller-cone) path over an edge from sources src (N, 3) or (3,) to receivers rec
    (N, 3). k_share (rad/m): the wavenumber of the finite-edge share (the band's; shares differ little
    between bands except right at an edge end, see :func:`diffracted_field`); share=False leaves it 1
    (the caller computes it per band with :func:`finite_share`)."""
    rho0, phi0, y0 = cylindrical(edge, src)
    rho, phi, y = cylindrical(edge, rec)
    rho0, phi0, y0, rho, phi, y = (np.array(v, float) for v in np.broadcast_arrays(rho0, phi0, y0, rho, phi, y))
    rho0 = np.maximum(rho0, 1e-9)
    rho = np.maximum(rho, 1e-9)
    y_e = y0 + (y - y0) * rho0 / (rho0 + rho)
    s_in = np.hypot(rho0, y_e - y0)
    s_out = np.hypot(rho, y - y_e)
    sin_b0 = rho0 / s_in
    leg = DiffractedLeg(s_in, s_out, phi0, phi, sin_b0, y_e, np.ones(rho.shape, complex))
    if share and (np.isfinite(edge.y_min) or np.isfinite(edge.y_max)):
        leg = leg._replace(share=finite_share(edge, leg, k_share))
    return leg


def finite_share(edge: Edge, leg: DiffractedLeg, k_share: float, a_min: np.ndarray | None = None) -> np.ndarray:
    """The finite edge's share (complex, (N,)) of the stationary-phase integral for the straight paths leg
    at wavenumber k_share (rad/m); a_min: :func:`boundary_min` of the leg's angles if already known."""
    y_e, s_in, s_out, sin_b0 = leg.y_e, leg.s_in, leg.s_out, leg.sin_b0
    # phase k l(y) ~ k l_e + (k/2) sin^2 b0 (1/s_in + 1/s_out) (y - y_e)^2 = (pi/2) u^2
    scale = np.sqrt(k_share * sin_b0**2 * (1.0 / s_in + 1.0 / s_out) / np.pi)
    u1 = np.ascontiguousarray(np.maximum((edge.y_min - y_e) * scale, -1e12) if np.isfinite(edge.y_min)
                              else np.full(y_e.shape, -1e12)).reshape(-1)  # fmt: skip
    u2 = np.ascontiguousarray(np.minimum((edge.y_max - y_e) * scale, 1e12) if np.isfinite(edge.y_max)
                              else np.full(y_e.shape, 1e12)).reshape(-1)  # fmt: skip
    out = np.empty(u1.shape, complex)
    fresnel_segment(u1, u2, out)
    share = out.reshape(y_e.shape)
    dist_l = s_in * s_out * sin_b0**2 / (s_in + s_out)
    inside = (y_e >= edge.y_min) & (y_e <= edge.y_max)
    if a_min is None:
        a_min = boundary_min(edge.n, leg.phi_out, leg.phi_in)
    return share_near_boundary(share, inside, (k_share * dist_l) * a_min)


def boundary_min(n: float, phi: np.ndarray, phip: np.ndarray) -> np.ndarray:
    """min over the four UTD terms of a(beta) = 2 cos^2((2 n pi N - beta) / 2) (k L a is the transition
    function's argument; small near a shadow or reflection boundary), independent of k."""
    a_min = np.full(np.shape(phi), np.inf)
    for beta in (phi - phip, phi + phip):
        for sgn in (1.0, -1.0):
            big_n = np.floor((beta + sgn * np.pi) / (2.0 * n * np.pi) + 0.5)
            a_min = np.minimum(a_min, 2.0 * np.cos(0.5 * (2.0 * n * np.pi * big_n - beta)) ** 2)
    return a_min


def share_near_boundary(share: np.ndarray, inside: np.ndarray, x_min: np.ndarray) -> np.ndarray:
    """:func:`boundary_share` given x_min = k L min a (:func:`boundary_min`)."""
    return np.where(inside, share + (1.0 - share) * np.exp(-x_min), share)


def boundary_share(
    share: np.ndarray, inside: np.ndarray, n: float, phi: np.ndarray, phip: np.ndarray, kl: np.ndarray
) -> np.ndarray:
    """The finite edge's share near a shadow or reflection boundary (small UTD argument X = k L a): there
    the diffracted wave's jump must meet the whole geometric wave it replaces, so while the stationary
    point lies on the edge the share tends to 1 (weight exp(-X)); farther from the boundaries the ends'
    share applies in full. (min_i kl a_i = kl min_i a_i exactly: rounding is monotonic, kl >= 0.)"""
    return share_near_boundary(share, inside, kl * boundary_min(n, phi, phip))


def utd_field(
    n: float | np.ndarray,
    leg: DiffractedLeg,
    k: np.ndarray,
    phase_m: np.ndarray | None = None,
) -> np.ndarray:
    """UTD diffracted pressure (F, N) along legs (point source of unit 1 m amplitude): D exp(i k l) /
    sqrt(s_in s_out (s_in + s_out)) times the finite-edge share. phase_m (N,): the phase path length (m,
    c_ref x travel time along curved legs; default s_in + s_out)."""
    s_in = np.ascontiguousarray(leg.s_in, float).reshape(-1)
    s_out = np.ascontiguousarray(leg.s_out, float).reshape(-1)
    m = s_in.size
    nn = np.ascontiguousarray(np.broadcast_to(np.asarray(n, float), (m,)))
    dist_l = s_in * s_out * np.asarray(leg.sin_b0, float).reshape(-1) ** 2 / (s_in + s_out)
    d = np.empty((len(k), m), complex)
    wedge_coefficients(
        nn,
        np.ascontiguousarray(leg.phi_out, float).reshape(-1),
        np.ascontiguousarray(leg.phi_in, float).reshape(-1),
        np.ascontiguousarray(dist_l),
        np.ascontiguousarray(leg.sin_b0, float).reshape(-1),
        np.ascontiguousarray(k, float),
        d,
    )
    ell = (s_in + s_out) if phase_m is None else np.asarray(phase_m, float).reshape(-1)
    spread = 1.0 / np.sqrt(s_in * s_out * (s_in + s_out))
    return d * np.exp(1j * np.asarray(k, float)[:, None] * ell[None, :]) * (spread * leg.share.reshape(-1))[None, :]


def diffracted_field(edge: Edge, src: np.ndarray, rec: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Straight-path UTD diffracted pressure (F, N) of one edge, source src (3,) or (N, 3), receivers (N, 3)."""
    rec = np.atleast_2d(np.asarray(rec, float))
    k = np.atleast_1d(np.asarray(k, float))
    out = np.empty((len(k), rec.shape[0]), complex)
    for f, kf in enumerate(k):  # the finite-edge share depends (a little) on k
        leg = edge_legs(edge, np.asarray(src, float), rec, float(kf))
        out[f] = utd_field(edge.n, leg, np.array([kf]))[0]
    return out


def geometric_field(edge: Edge, src: np.ndarray, rec: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Geometrical acoustics of the infinite rigid wedge (F, N): the direct wave where |phi - phi'| < pi,
    the face-0 image where phi + phi' < pi, the face-n image where phi + phi' > (2 n - 1) pi; half of each
    on its boundary (where the UTD term supplies the other half)."""
    rec = np.atleast_2d(np.asarray(rec, float))
    k = np.atleast_1d(np.asarray(k, float))
    src = np.asarray(src, float)
    rho0, phi0, y0 = cylindrical(edge, src)
    rho, phi, y = cylindrical(edge, rec)
    n = edge.n
    out = np.zeros((len(k), rec.shape[0]), complex)
    dy2 = (y - y0) ** 2
    waves = (
        (phi - phi0, np.pi - np.abs(phi - phi0)),
        (phi + phi0, np.pi - (phi + phi0)),
        (phi + phi0 - 2 * n * np.pi, (phi + phi0) - (2 * n - 1) * np.pi),
    )
    for ang, lit in waves:
        w = np.where(lit > _TOL, 1.0, np.where(lit >= -_TOL, 0.5, 0.0))
        r = np.sqrt(rho**2 + rho0**2 - 2 * rho * rho0 * np.cos(ang) + dy2)
        on = w > 0
        out[:, on] += w[on] * np.exp(1j * k[:, None] * r[None, on]) / r[None, on]
    return out

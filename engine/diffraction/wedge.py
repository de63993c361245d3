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
    "boundary_share",
    "cylindrical",
    "diffracted_field",
    "edge_legs",
    "geometric_field",
    "utd_field",
]

_TOL = EPS_ON_BOUNDARY  # rad: a point this close to a geometric boundary gets half of that wave


class Edge(NamedTuple):
    """A straight rigid wedge edge (module docstring): point (3,), direction e (3,) unit, face0 (3,) unit
    perpendicular to e, exterior angle n pi (n in (1, 2]), extent y_min..y_max metres along e."""

    point: np.ndarray
    direction: np.ndarray
    face0: np.ndarray
    n: float = 2.0
    y_min: float = -np.inf
    y_max: float = np.inf


def cylindrical(edge: Edge, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rho, phi in [0, 2 pi), y) of points xyz (..., 3) about the edge (m, rad, m)."""
    e = np.asarray(edge.direction, float)
    a = np.asarray(edge.face0, float)
    b = np.cross(e, a)
    d = np.asarray(xyz, float) - np.asarray(edge.point, float)
    x1, x2, y = d @ a, d @ b, d @ e
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


def edge_legs(edge: Edge, src: np.ndarray, rec: np.ndarray, k_share: float) -> DiffractedLeg:
    """The stationary (Keller-cone) path over an edge from sources src (N, 3) or (3,) to receivers rec
    (N, 3). k_share (rad/m): the wavenumber of the finite-edge share (the band's; shares differ little
    between bands except right at an edge end, see :func:`diffracted_field`)."""
    rho0, phi0, y0 = cylindrical(edge, src)
    rho, phi, y = cylindrical(edge, rec)
    rho0, phi0, y0, rho, phi, y = (np.array(v, float) for v in np.broadcast_arrays(rho0, phi0, y0, rho, phi, y))
    rho0 = np.maximum(rho0, 1e-9)
    rho = np.maximum(rho, 1e-9)
    y_e = y0 + (y - y0) * rho0 / (rho0 + rho)
    s_in = np.hypot(rho0, y_e - y0)
    s_out = np.hypot(rho, y - y_e)
    sin_b0 = rho0 / s_in
    share = np.ones(rho.shape, complex)
    if np.isfinite(edge.y_min) or np.isfinite(edge.y_max):
        # phase k l(y) ~ k l_e + (k/2) sin^2 b0 (1/s_in + 1/s_out) (y - y_e)^2 = (pi/2) u^2
        scale = np.sqrt(k_share * sin_b0**2 * (1.0 / s_in + 1.0 / s_out) / np.pi)
        u1 = np.ascontiguousarray(np.maximum((edge.y_min - y_e) * scale, -1e12) if np.isfinite(edge.y_min)
                                  else np.full(rho.shape, -1e12)).reshape(-1)  # fmt: skip
        u2 = np.ascontiguousarray(np.minimum((edge.y_max - y_e) * scale, 1e12) if np.isfinite(edge.y_max)
                                  else np.full(rho.shape, 1e12)).reshape(-1)  # fmt: skip
        out = np.empty(u1.shape, complex)
        fresnel_segment(u1, u2, out)
        share = out.reshape(rho.shape)
        dist_l = s_in * s_out * sin_b0**2 / (s_in + s_out)
        inside = (y_e >= edge.y_min) & (y_e <= edge.y_max)
        share = boundary_share(share, inside, edge.n, phi, phi0, k_share * dist_l)
    return DiffractedLeg(s_in, s_out, phi0, phi, sin_b0, y_e, share)


def boundary_share(
    share: np.ndarray, inside: np.ndarray, n: float, phi: np.ndarray, phip: np.ndarray, kl: np.ndarray
) -> np.ndarray:
    """The finite edge's share near a shadow or reflection boundary (small UTD argument X = k L a): there
    the diffracted wave's jump must meet the whole geometric wave it replaces, so while the stationary
    point lies on the edge the share tends to 1 (weight exp(-X)); farther from the boundaries the ends'
    share applies in full."""
    x_min = np.full(np.shape(phi), np.inf)
    for beta in (phi - phip, phi + phip):
        for sgn in (1.0, -1.0):
            big_n = np.floor((beta + sgn * np.pi) / (2.0 * n * np.pi) + 0.5)
            x_min = np.minimum(x_min, kl * 2.0 * np.cos(0.5 * (2.0 * n * np.pi * big_n - beta)) ** 2)
    return np.where(inside, share + (1.0 - share) * np.exp(-x_min), share)


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

"""Diffracted paths over one edge with ground reflections on each side: the four image combinations.

For a source S and a receiver R on either side of an edge, each above its own local ground plane
(heights g_s under the source, g_r under the receiver; flat, horizontal), the paths over the edge are
S -> E -> R, S' -> E -> R, S -> E -> R', S' -> E -> R' with the images S' = (x_s, y_s, 2 g_s - z_s),
R' likewise. Each ground reflection carries the Weyl-van der Pol spherical-wave coefficient
(:func:`bentray.engine.acoustics.ground.spherical_wave_coefficient`, Delany-Bazley impedance) at its own
angle and path length: for S' -> E, ``cos th = (z_E - g_s + z_s - g_s) / |S' E|`` and ``R2 = |S' E|``
(the leg's unfolded length), the same on the receiver side. The standards (ISO 9613-2, CNOSSOS-EU,
Nord2000) build the barrier-over-ground case the same way.

Each combination's diffracted wave is the UTD wave of :mod:`bentray.engine.diffraction.wedge` along
legs that are straight or curved (:mod:`bentray.engine.diffraction.legs`): the angles phi, phi' at the
edge come from the legs' tangents there, so the shadow boundary is the curved ray that grazes the edge
and the diffracted phase meets the geometric one on it. ``geometric=True`` adds the geometric waves that
belong to the same zone: the direct wave where the (S, R) combination is lit, and the ground-reflected
wave once, from (S', R) when its ground point lies on the source side of the edge or from (S, R') when
on the receiver side (the two are the same ray; (S', R') has no geometric ray). Face reflections of the
wedge itself are left to the beams.

Results are per combination, so the caller sums them coherently (tones, coherent maps) or adds their
energies (incoherent maps): ``field`` (4, F, N) complex, relative to the 1 m free-field amplitude.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bentray.engine.acoustics.ground import ground_impedance, spherical_wave_coefficient
from bentray.engine.diffraction.legs import Legs, straight_legs
from bentray.engine.diffraction.wedge import DiffractedLeg, Edge, edge_legs, utd_field

__all__ = ["GroundSide", "LegModel", "edge_paths"]

# legs a -> b ((N, 3) each) -> Legs; the default is straight at c_ref
LegModel = Callable[[np.ndarray, np.ndarray], Legs]


@dataclass(frozen=True)
class GroundSide:
    """Flat local ground under one end of the path: height z (m, scalar or (N,)) and flow resistivity
    (Pa s/m^2; None = rigid). ``reflect=False``: no image on this side (e.g. a roof or no ground)."""

    z: float | np.ndarray
    flow_resistivity: float | None = 2e5
    reflect: bool = True


def _angle(edge: Edge, v: np.ndarray) -> np.ndarray:
    """Angle (rad, [0, 2 pi)) of directions v (N, 3) about the edge, from face 0."""
    e = np.asarray(edge.direction, float)
    a = np.asarray(edge.face0, float)
    b = np.cross(e, a)
    return np.mod(np.arctan2(v @ b, v @ a), 2.0 * np.pi)


def _q(f_hz: np.ndarray, c: float, side: GroundSide, cos_t: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """(F, N) spherical-wave coefficients."""
    z = ground_impedance(f_hz, side.flow_resistivity)[:, None]
    k = (2.0 * np.pi * f_hz / c)[:, None]
    return spherical_wave_coefficient(z, np.clip(cos_t, 0.0, 1.0)[None, :], k, np.maximum(r2, 1e-9)[None, :])


def edge_paths(
    edge: Edge,
    src: np.ndarray,
    rec: np.ndarray,
    f_hz: np.ndarray,
    c_ref: float,
    src_ground: GroundSide | None,
    rec_ground: GroundSide | None,
    legs: LegModel | None = None,
    geometric: bool = False,
) -> np.ndarray:
    """Diffracted (+ geometric) pressure of the four image combinations, (4, F, N) complex.

    src (3,) or (N, 3), rec (N, 3) metres; f_hz (F,) band centres; c_ref (m/s) the phase speed (k =
    2 pi f / c_ref, phases 2 pi f t along curved legs); grounds None: no reflection on that side.
    Combination order: (S, R), (S', R), (S, R'), (S', R'); absent images give zeros."""
    rec = np.atleast_2d(np.asarray(rec, float))
    src = np.broadcast_to(np.asarray(src, float), rec.shape).copy()
    f_hz = np.atleast_1d(np.asarray(f_hz, float))
    k = 2.0 * np.pi * f_hz / c_ref
    leg_fn: LegModel = legs if legs is not None else (lambda a, b: straight_legs(a, b, c_ref))
    n_pts = rec.shape[0]
    out = np.zeros((4, len(f_hz), n_pts), complex)
    sides = []
    for side, pts in ((src_ground, src), (rec_ground, rec)):
        imgs = [(pts, None)]
        if side is not None and side.reflect:
            g = np.broadcast_to(np.asarray(side.z, float), (n_pts,))
            im = pts.copy()
            im[:, 2] = 2.0 * g - pts[:, 2]
            imgs.append((im, g))
        sides.append(imgs)
    for ci, (si, ri) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
        if si >= len(sides[0]) or ri >= len(sides[1]):
            continue
        s_pts, gs = sides[0][si]
        r_pts, gr = sides[1][ri]
        straight = edge_legs(edge, s_pts, r_pts, float(k[len(k) // 2]))
        e_pts = np.asarray(edge.point, float) + straight.y_e[:, None] * np.asarray(edge.direction, float)
        leg_a = leg_fn(s_pts, e_pts)
        leg_b = leg_fn(e_pts, r_pts)
        e = np.asarray(edge.direction, float)
        sin_b0 = np.linalg.norm(np.cross(leg_a.t_end, e), axis=1)
        leg = DiffractedLeg(
            leg_a.length,
            leg_b.length,
            _angle(edge, -leg_a.t_end),
            _angle(edge, leg_b.t_start),
            np.maximum(sin_b0, 1e-12),
            straight.y_e,
            straight.share,
        )
        p = np.empty((len(k), n_pts), complex)
        for f in range(len(k)):  # the finite-edge share depends a little on k
            if np.isfinite(edge.y_min) or np.isfinite(edge.y_max):
                leg = leg._replace(share=edge_legs(edge, s_pts, r_pts, float(k[f])).share)
            p[f] = utd_field(edge.n, leg, k[f : f + 1], phase_m=c_ref * (leg_a.time + leg_b.time))[0]
        if gs is not None:
            assert src_ground is not None
            p *= _q(f_hz, c_ref, src_ground, (e_pts[:, 2] - gs + src[:, 2] - gs) / leg_a.length, leg_a.length)
        if gr is not None:
            assert rec_ground is not None
            p *= _q(f_hz, c_ref, rec_ground, (e_pts[:, 2] - gr + rec[:, 2] - gr) / leg_b.length, leg_b.length)
        if geometric and ci < 3:
            p += _geometric(edge, ci, s_pts, r_pts, leg, f_hz, c_ref, leg_fn, src, rec, gs, gr, src_ground, rec_ground)
        out[ci] = p
    return out


def _geometric(
    edge: Edge,
    ci: int,
    s_pts: np.ndarray,
    r_pts: np.ndarray,
    leg: DiffractedLeg,
    f_hz: np.ndarray,
    c_ref: float,
    leg_fn: LegModel,
    src: np.ndarray,
    rec: np.ndarray,
    gs: np.ndarray | None,
    gr: np.ndarray | None,
    src_ground: GroundSide | None,
    rec_ground: GroundSide | None,
) -> np.ndarray:
    """The combination's geometric wave (module docstring), weight 1 lit, 1/2 on the boundary, 0 shadowed."""
    lit = np.pi - np.abs(leg.phi_out - leg.phi_in)
    w = np.where(lit > 1e-12, 1.0, np.where(lit >= -1e-12, 0.5, 0.0))
    if ci > 0:  # one ground-reflected ray: keep it in the combination whose side holds its ground point
        d = r_pts - s_pts
        g = gs if ci == 1 else gr
        assert g is not None
        t = (g - s_pts[:, 2]) / np.where(d[:, 2] != 0, d[:, 2], 1e-300)
        ground_pt = s_pts + t[:, None] * d
        e_pt = np.asarray(edge.point, float) + leg.y_e[:, None] * np.asarray(edge.direction, float)
        along = np.einsum("ij,ij->i", ground_pt[:, :2] - e_pt[:, :2], (rec - src)[:, :2])
        w = w * ((along < 0) if ci == 1 else (along >= 0))
    out = np.zeros((len(f_hz), s_pts.shape[0]), complex)
    on = w > 0
    if not np.any(on):
        return out
    direct = leg_fn(s_pts[on], r_pts[on])
    k = 2.0 * np.pi * f_hz / c_ref
    p = w[on] * np.exp(1j * k[:, None] * (c_ref * direct.time)[None, :]) / direct.length[None, :]
    if ci > 0:
        side = src_ground if ci == 1 else rec_ground
        assert side is not None
        cos_t = (src[on, 2] - (gs if ci == 1 else gr)[on] + rec[on, 2] - (gs if ci == 1 else gr)[on]) / direct.length
        p = p * _q(f_hz, c_ref, side, cos_t, direct.length)
    out[:, on] = p
    return out

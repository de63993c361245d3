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

A leg in a refractive shadow (upward refraction: its arc would dip below its side's ground plane, the
plane of that side's images) is attenuated by the decay of the creeping wave along the ground between
its tangent points (:mod:`bentray.engine.diffraction.leg_shadow`), the same factor for the direct and
the image combination of that side, computed from the real end points; the leg model supplies it
(``shadow``, :class:`bentray.engine.diffraction.legs.ProfileLegs`), straight legs have none.

Results are per combination, so the caller sums them coherently (tones, coherent maps) or adds their
energies (incoherent maps): ``field`` (4, F, N) complex, relative to the 1 m free-field amplitude.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bentray.engine.acoustics.ground import ground_impedance, spherical_wave_coefficient
from bentray.engine.diffraction.kernels import EPS_ON_BOUNDARY, fresnel_segment, wedge_coefficients
from bentray.engine.diffraction.legs import Legs, straight_legs
from bentray.engine.diffraction.wedge import (
    DiffractedLeg,
    Edge,
    boundary_min,
    cross,
    cylindrical,
    edge_legs,
    finite_share,
    rows_dot,
    share_near_boundary,
    utd_field,
)

__all__ = ["GroundSide", "LegModel", "double_edge_paths", "edge_paths"]

# legs a -> b ((N, 3) each) -> Legs; the default is straight at c_ref
LegModel = Callable[[np.ndarray, np.ndarray], Legs]


@dataclass(frozen=True)
class GroundSide:
    """Flat local ground under one end of the path: height z (m, scalar or (N,)) and flow resistivity
    (Pa s/m^2; None = rigid). ``reflect=False``: no image on this side (e.g. a roof or no ground)."""

    z: float | np.ndarray
    flow_resistivity: float | None = 2e5
    reflect: bool = True


MIN_LEG_M = 1e-6  # shortest leg of a diffracted path (m); see double_edge_paths


def _angle(edge: Edge, v: np.ndarray) -> np.ndarray:
    """Angle (rad, [0, 2 pi)) of directions v (N, 3) about the edge (or edge i for row i of a batch), from
    face 0."""
    e = np.asarray(edge.direction, float)
    a = np.asarray(edge.face0, float)
    b = cross(e, a)
    return np.mod(np.arctan2(rows_dot(v, b), rows_dot(v, a)), 2.0 * np.pi)


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
    visible_only: bool = False,
    lateral: bool = False,
) -> np.ndarray:
    """Diffracted (+ geometric) pressure of the four image combinations, (4, F, N) complex.

    visible_only: zero where the source or the receiver (or its image) is not in the air sector of the
    wedge (0 <= phi <= n pi): the edge cannot see it (e.g. a receiver behind a building, below its roof,
    seen from the front roof edge: that path goes over both roof edges, :func:`double_edge_paths`).
    lateral: a vertical edge: all four combinations share its (plan-view) shadow boundary, so only (S, R)
    and (S', R) are kept, the latter with the coefficient of the whole unfolded path (angle
    (z_s - g + z_r - g) / R2, R2 = s_in + s_out): on the boundary that is the ground-reflected geometric
    wave's, which the diffracted wave must meet; rec_ground is not used.

    edge: one edge, or a batch of N (class Edge: edge i for point i; not with visible_only).
    src (3,) or (N, 3), rec (N, 3) metres; f_hz (F,) band centres; c_ref (m/s) the phase speed (k =
    2 pi f / c_ref, phases 2 pi f t along curved legs); grounds None: no reflection on that side.
    Combination order: (S, R), (S', R), (S, R'), (S', R'); absent images give zeros."""
    rec = np.atleast_2d(np.asarray(rec, float))
    src = np.broadcast_to(np.asarray(src, float), rec.shape).copy()
    f_hz = np.atleast_1d(np.asarray(f_hz, float))
    if visible_only and not geometric:  # evaluate only where some combination sees both ends (speed)
        assert np.ndim(edge.point) == 1, "visible_only takes one edge, not a batch"
        mask = _any_seen(edge, src, rec, src_ground, rec_ground)
        if not mask.all():
            out_all = np.zeros((4, len(f_hz), rec.shape[0]), complex)
            if mask.any():
                out_all[:, :, mask] = edge_paths(edge, src[mask], rec[mask], f_hz, c_ref, _subset(src_ground, mask),
                                                 _subset(rec_ground, mask), legs, False, True, lateral)  # fmt: skip
            return out_all
    k = 2.0 * np.pi * f_hz / c_ref
    leg_fn: LegModel = legs if legs is not None else (lambda a, b: straight_legs(a, b, c_ref))
    n_pts = rec.shape[0]
    out = np.zeros((4, len(f_hz), n_pts), complex)
    sides = []
    for side, pts in ((src_ground, src), (rec_ground, rec)):
        imgs: list[tuple[np.ndarray, np.ndarray | None]] = [(pts, None)]
        if side is not None and side.reflect:
            g = np.broadcast_to(np.asarray(side.z, float), (n_pts,))
            im = pts.copy()
            im[:, 2] = 2.0 * g - pts[:, 2]
            imgs.append((im, g))
        sides.append(imgs)
    for ci, (si, ri) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1))):
        if si >= len(sides[0]) or ri >= len(sides[1]) or (lateral and ri > 0):
            continue
        s_pts, gs = sides[0][si]
        r_pts, gr = sides[1][ri]
        straight = edge_legs(edge, s_pts, r_pts, float(k[len(k) // 2]), share=False)
        e_pts = np.asarray(edge.point, float) + straight.y_e[:, None] * np.asarray(edge.direction, float)
        leg_a = leg_fn(s_pts, e_pts)
        leg_b = leg_fn(e_pts, r_pts)
        leg_a = leg_a._replace(length=np.maximum(leg_a.length, MIN_LEG_M))  # a point on the edge: finite
        leg_b = leg_b._replace(length=np.maximum(leg_b.length, MIN_LEG_M))
        e = np.asarray(edge.direction, float)
        sin_b0 = np.linalg.norm(cross(leg_a.t_end, e), axis=1)
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
        finite = bool(np.isfinite(edge.y_min) or np.isfinite(edge.y_max))
        a_min = boundary_min(edge.n, straight.phi_out, straight.phi_in) if finite else None
        for f in range(len(k)):  # the finite-edge share depends a little on k
            if finite:
                leg = leg._replace(share=finite_share(edge, straight, float(k[f]), a_min))
            p[f] = utd_field(edge.n, leg, k[f : f + 1], phase_m=c_ref * (leg_a.time + leg_b.time))[0]
        if visible_only:
            p *= (_seen(_angle(edge, s_pts - e_pts), edge.n) * _seen(_angle(edge, r_pts - e_pts), edge.n))[None, :]
        if gs is not None and lateral:
            assert src_ground is not None
            r2 = leg_a.length + leg_b.length
            p *= _q(f_hz, c_ref, src_ground, (rec[:, 2] - gs + src[:, 2] - gs) / r2, r2)
        elif gs is not None:
            assert src_ground is not None
            p *= _q(f_hz, c_ref, src_ground, (e_pts[:, 2] - gs + src[:, 2] - gs) / leg_a.length, leg_a.length)
        if gr is not None:
            assert rec_ground is not None
            p *= _q(f_hz, c_ref, rec_ground, (e_pts[:, 2] - gr + rec[:, 2] - gr) / leg_b.length, leg_b.length)
        _apply_shadow(p, leg_fn, src, e_pts, src_ground, f_hz)  # a leg in a refractive shadow: its creeping
        _apply_shadow(p, leg_fn, e_pts, rec, rec_ground, f_hz)  # wave's decay (module docstring)
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
        g_side = gs if ci == 1 else gr
        assert g_side is not None
        cos_t = (src[on, 2] - g_side[on] + rec[on, 2] - g_side[on]) / direct.length
        p = p * _q(f_hz, c_ref, side, cos_t, direct.length)
    _apply_shadow(p, leg_fn, src[on], rec[on], _subset(rec_ground if ci == 2 else src_ground, on), f_hz)
    out[:, on] = p
    return out


def _apply_shadow(
    p: np.ndarray, leg_fn: LegModel, a: np.ndarray, b: np.ndarray, side: GroundSide | None, f_hz: np.ndarray
) -> None:
    """Multiply p (F, N) in place by the refractive-shadow amplitude of the legs a -> b ((N, 3) m, real end
    points) over the side's ground plane (:mod:`bentray.engine.diffraction.leg_shadow`), when the leg
    model has one (``shadow``: curved legs of an upward-refracting profile) and the side has a reflecting
    ground; nothing otherwise (straight legs, downward refraction, lit legs: the values are untouched)."""
    shadow = getattr(leg_fn, "shadow", None)
    if shadow is None or side is None or not side.reflect or p.shape[-1] == 0:
        return
    z = np.broadcast_to(np.asarray(side.z, float), (p.shape[-1],))
    amp = shadow(a, b, z, f_hz, side.flow_resistivity)
    if amp is not None:
        p *= amp


def _images(side: GroundSide | None, pts: np.ndarray) -> list[tuple[np.ndarray, np.ndarray | None]]:
    imgs: list[tuple[np.ndarray, np.ndarray | None]] = [(pts, None)]
    if side is not None and side.reflect:
        g = np.broadcast_to(np.asarray(side.z, float), (pts.shape[0],)).copy()
        im = pts.copy()
        im[:, 2] = 2.0 * g - pts[:, 2]
        imgs.append((im, g))
    return imgs


def _subset(side: GroundSide | None, mask: np.ndarray) -> GroundSide | None:
    """The ground side restricted to the masked points (per-point heights sliced)."""
    if side is None or np.ndim(side.z) == 0:
        return side
    return GroundSide(np.asarray(side.z, float)[mask], side.flow_resistivity, side.reflect)


def _any_seen(
    edge: Edge,
    src: np.ndarray,
    rec: np.ndarray,
    src_ground: GroundSide | None,
    rec_ground: GroundSide | None,
    src_only: bool = False,
    rec_only: bool = False,
    slack: float = 0.05,
) -> np.ndarray:
    """(N,) bool, conservative: some image combination may see the source (and/or the receiver) from the
    edge (straight Keller point; ``slack`` rad of margin for curved legs). Only a filter: the exact
    visibility weights are applied afterwards."""
    n = edge.n
    out = np.zeros(rec.shape[0], bool)
    s_phis = [None if rec_only else cylindrical(edge, s_pts)[1] for s_pts, _ in _images(src_ground, src)]
    r_phis = [None if src_only else cylindrical(edge, r_pts)[1] for r_pts, _ in _images(rec_ground, rec)]
    for phi0 in s_phis:
        for phi in r_phis:
            ok = np.ones(rec.shape[0], bool)
            if phi0 is not None:
                ok &= (phi0 <= n * np.pi + slack) | (phi0 >= 2 * np.pi - slack)
            if phi is not None:
                ok &= (phi <= n * np.pi + slack) | (phi >= 2 * np.pi - slack)
            out |= ok
    return out


def _seen(phi: np.ndarray, n: float) -> np.ndarray:
    """Visibility weight of a direction at angle phi (rad, [0, 2 pi)) from a wedge of exterior angle n pi:
    1 in the air sector, 0 in the solid, 1/2 exactly on a face plane (within EPS_ON_BOUNDARY): there the
    wave that takes over beyond the face (the next edge's) carries its other half, as on a shadow
    boundary; map points at exactly roof height are common."""
    tol = EPS_ON_BOUNDARY
    on = (phi <= tol) | (phi >= 2.0 * np.pi - tol) | (np.abs(phi - n * np.pi) <= tol)
    return np.where(on, 0.5, np.where(phi < n * np.pi, 1.0, 0.0))


def _clamp_angle(phi: np.ndarray, n: float) -> np.ndarray:
    """Angles within 1e-9 of the faces (rounding of a grazing direction) onto [0, n pi]."""
    phi = np.where(phi > 2.0 * np.pi - 1e-9, 0.0, phi)
    return np.where((phi > n * np.pi) & (phi < n * np.pi + 1e-9), n * np.pi, phi)


def double_edge_paths(
    e1: Edge,
    e2: Edge,
    src: np.ndarray,
    rec: np.ndarray,
    f_hz: np.ndarray,
    c_ref: float,
    src_ground: GroundSide | None,
    rec_ground: GroundSide | None,
    legs: LegModel | None = None,
    lateral: bool = False,
) -> np.ndarray:
    """Double diffraction S -> E1 -> E2 -> R over two parallel (or antiparallel) edges sharing a face (the
    two roof edges of a flat roof, two corners of one wall), four image combinations, (4, F, N) complex.

    Edge points from the unfolded straight path (Keller's law on both edges). Field (UTD, grazing
    incidence on E2 along the shared face counts half, Kouyoumjian and Pathak):
    ``D1 (1/2) D2 exp(i k (s1 + s2 + s3)) / sqrt(s1 s2 s3 (s1 + s2 + s3))`` with
    ``L1 = s1 s2 sin^2 b / (s1 + s2)`` and, for the astigmatic wave leaving E1 (principal radii s2 and
    s1 + s2, edge-plane radius s1 + s2), ``L2 = s2 s3 sin^2 b / (s2 + s3)``: with it the double wave's jump on
    E2's shadow boundary is exactly the single wave of E1 it replaces (the flat roof's plane behind the
    building: continuous). Zero where the
    source cannot see E1 or the receiver cannot see E2 (outside their air sectors). The legs S -> E1 and
    E2 -> R follow ``legs`` (curved), E1 -> E2 runs along the face (straight). The receiver-side ground
    coefficient is taken on the unfolded leg E1 -> R' (angle and length), the one E1's single wave has on
    E2's shadow boundary, where the two must meet. lateral (vertical edges): (S, R) and (S', R) only, the
    latter with the whole unfolded path's coefficient, as in :func:`edge_paths`."""
    rec = np.atleast_2d(np.asarray(rec, float))
    src = np.broadcast_to(np.asarray(src, float), rec.shape).copy()
    f_hz = np.atleast_1d(np.asarray(f_hz, float))
    if rec.shape[0]:  # evaluate only where some combination sees E1 from S and E2 from R (speed)
        mask = _any_seen(e1, src, rec, src_ground, None, src_only=True) & _any_seen(
            e2, src, rec, None, None if lateral else rec_ground, rec_only=True
        )
        if not mask.all():
            out_all = np.zeros((4, len(f_hz), rec.shape[0]), complex)
            if mask.any():
                out_all[:, :, mask] = double_edge_paths(e1, e2, src[mask], rec[mask], f_hz, c_ref,
                                                        _subset(src_ground, mask), _subset(rec_ground, mask), legs,
                                                        lateral)  # fmt: skip
            return out_all
    k = 2.0 * np.pi * f_hz / c_ref
    leg_fn: LegModel = legs if legs is not None else (lambda a, b: straight_legs(a, b, c_ref))
    n_pts = rec.shape[0]
    out = np.zeros((4, len(f_hz), n_pts), complex)
    ea = np.asarray(e1.direction, float)
    p1, p2 = np.asarray(e1.point, float), np.asarray(e2.point, float)
    # e2's point in e1's along-edge coordinate, and the perpendicular offset between the two lines
    y2_0 = float((p2 - p1) @ ea)
    sign2 = float(np.sign(np.asarray(e2.direction, float) @ ea))
    gap = float(np.linalg.norm((p2 - p1) - y2_0 * ea))
    for ci, (s_pts, gs) in enumerate(_images(src_ground, src)):
        for ri, (r_pts, gr) in enumerate(_images(None if lateral else rec_ground, rec)):
            rho_s = np.linalg.norm(cross(s_pts - p1, ea), axis=1)
            rho_r = np.linalg.norm(cross(r_pts - p2, ea), axis=1)
            ys = (s_pts - p1) @ ea
            yr = (r_pts - p1) @ ea
            tot = rho_s + gap + rho_r
            y1 = ys + (yr - ys) * rho_s / tot
            y2 = ys + (yr - ys) * (rho_s + gap) / tot
            q1 = p1 + y1[:, None] * ea
            q2 = p1 + y2[:, None] * ea + ((p2 - p1) - y2_0 * ea)
            leg_a = leg_fn(s_pts, q1)
            leg_c = leg_fn(q2, r_pts)
            # legs shorter than MIN_LEG_M (a point on an edge, a zero-width roof) are clipped: UTD is not
            # valid there anyway, and the level stays finite instead of dividing by zero
            s2 = np.maximum(np.linalg.norm(q2 - q1, axis=1), MIN_LEG_M)
            s1, s3 = np.maximum(leg_a.length, MIN_LEG_M), np.maximum(leg_c.length, MIN_LEG_M)
            sin_b = np.maximum(np.linalg.norm(cross(leg_a.t_end, ea), axis=1), 1e-12)
            mid = (q2 - q1) / np.maximum(s2, 1e-300)[:, None]
            phi1_in = _angle(e1, -leg_a.t_end)
            phi1_out = _clamp_angle(_angle(e1, mid), e1.n)
            phi2_in = _clamp_angle(_angle(e2, -mid), e2.n)
            phi2_out = _angle(e2, leg_c.t_start)
            seen = _seen(phi1_in, e1.n) * _seen(phi2_out, e2.n)
            l1 = s1 * s2 * sin_b**2 / (s1 + s2)
            l2 = s2 * s3 * sin_b**2 / (s2 + s3)  # the astigmatic wave from E1: caustics at E1 and s1 + s2 back
            d1 = np.empty((len(k), n_pts), complex)
            d2 = np.empty((len(k), n_pts), complex)
            nn1 = np.full(n_pts, e1.n)
            nn2 = np.full(n_pts, e2.n)
            wedge_coefficients(nn1, phi1_out, phi1_in, l1, sin_b, k, d1)
            wedge_coefficients(nn2, phi2_out, phi2_in, l2, sin_b, k, d2)
            phase = c_ref * (leg_a.time + leg_c.time) + s2
            share = np.ones((len(k), n_pts), complex)
            ends = (
                (e1, y1, s1, s2 + s3, phi1_out, phi1_in, l1),
                (e2, sign2 * (y2 - y2_0), s1 + s2, s3, phi2_out, phi2_in, l2),
            )
            near = [((y_loc >= edge.y_min) & (y_loc <= edge.y_max), boundary_min(edge.n, phi, phip))
                    for edge, y_loc, _, _, phi, phip, _ in ends]  # fmt: skip
            for f in range(len(k)):
                for (edge, y_loc, s_a, s_b, _, _, dist_l), (inside, a_min) in zip(ends, near, strict=True):
                    sh = _share(edge, y_loc, sin_b, s_a, s_b, float(k[f]))
                    share[f] *= share_near_boundary(sh, inside, (float(k[f]) * dist_l) * a_min)
            p = 0.5 * d1 * d2 * np.exp(1j * k[:, None] * phase[None, :]) / np.sqrt(s1 * s2 * s3 * (s1 + s2 + s3))
            p *= share * seen[None, :]
            _apply_shadow(p, leg_fn, src, q1, src_ground, f_hz)  # legs in a refractive shadow (module docstring)
            _apply_shadow(p, leg_fn, q2, rec, rec_ground, f_hz)
            if gs is not None and lateral:
                assert src_ground is not None
                r2 = s1 + s2 + s3
                p *= _q(f_hz, c_ref, src_ground, (rec[:, 2] - gs + src[:, 2] - gs) / r2, r2)
            elif gs is not None:
                assert src_ground is not None
                p *= _q(f_hz, c_ref, src_ground, (q1[:, 2] - gs + src[:, 2] - gs) / s1, s1)
            if gr is not None:  # on the unfolded leg from E1 (E2 -> R on its straight continuation): on E2's
                assert rec_ground is not None  # shadow boundary the same coefficient as E1's single wave
                r2 = np.linalg.norm(r_pts - q1, axis=1)
                p *= _q(f_hz, c_ref, rec_ground, (q1[:, 2] - gr + rec[:, 2] - gr) / r2, r2)
            out[ci + 2 * ri] = p
    return out


def _share(edge: Edge, y: np.ndarray, sin_b: np.ndarray, s_a: np.ndarray, s_b: np.ndarray, k: float) -> np.ndarray:
    """The finite edge's share of the stationary-phase integral (see wedge.py) at edge coordinate y."""
    if not (np.isfinite(edge.y_min) or np.isfinite(edge.y_max)):
        return np.ones(y.shape, complex)
    scale = np.sqrt(k * sin_b**2 * (1.0 / s_a + 1.0 / s_b) / np.pi)
    u1 = np.ascontiguousarray((edge.y_min - y) * scale if np.isfinite(edge.y_min) else np.full(y.shape, -1e12))
    u2 = np.ascontiguousarray((edge.y_max - y) * scale if np.isfinite(edge.y_max) else np.full(y.shape, 1e12))
    out = np.empty(y.shape, complex)
    fresnel_segment(u1, u2, out)
    return out

"""Legs of diffracted paths (source -> edge point, edge point -> receiver) as straight lines or as the
closed-form circular rays of a linear sound-speed fit (docs/physics.md §3).

In ``c(z) = c_a + g (z - z_a)`` every ray is an arc of a circle centred on the line where c = 0,
``z_c = z_a - c_a / g``; between two points A, B there is one such arc (in the vertical plane through
them). With ``h`` the horizontal distance and A at x = 0: centre ``x_c = (h^2 + (z_B - z_c)^2 - (z_A -
z_c)^2) / (2 h)``, radius ``R = hypot(x_c, z_A - z_c)``, arc length ``R |psi_B - psi_A|`` (psi the polar
angles about the centre) and travel time ``t = arccosh(1 + g^2 |AB|^2 / (2 c_A c_B)) / |g|`` (written with
log1p, no cancellation). Tangents at both ends are perpendicular to the radii, oriented from A to B. A
leg with |g| |AB| / c below STRAIGHT_REL, or a vertical leg, is straight (the arc's sag is below 1e-9
of its length).

:func:`fit_linear_c` fits the gradient by least squares to the effective sound speed (profile plus the
wind along the leg's horizontal direction) sampled along the chord and just above it: the profile is
linear over each leg at best approximately, so the fit is what makes "the leg follows the job's profile"
concrete; refraction then changes the legs' travel times and the angles at the edge, hence the path
difference.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

__all__ = ["STRAIGHT_REL", "Legs", "ProfileLegs", "circular_legs", "fit_linear_c", "straight_legs"]

STRAIGHT_REL = 1e-9  # |g| |AB| / c below this: straight (relative sag ~ |g| |AB| / (8 c))
N_FIT_SAMPLES = 9  # chord samples of the least-squares fit (the profile's curvature over one leg)
# Each chord sample is also taken FIT_LIFT above the chord, FIT_LIFT = max(FIT_LIFT_MIN_M, FIT_LIFT_REL x
# chord): about an arc's sag for typical gradients, and it gives a level leg a vertical gradient to fit
# (upwards only: below the chord may be under the ground, where an above-ground profile is undefined).
FIT_LIFT_MIN_M = 0.5
FIT_LIFT_REL = 0.02


class Legs(NamedTuple):
    """Per leg (N,): arc length (m), travel time (s), unit tangents at the start and at the end (N, 3)."""

    length: np.ndarray
    time: np.ndarray
    t_start: np.ndarray
    t_end: np.ndarray


def straight_legs(a: np.ndarray, b: np.ndarray, c: float | np.ndarray) -> Legs:
    """Straight legs a -> b ((N, 3) m) at sound speed c (m/s, scalar or (N,))."""
    d = np.asarray(b, float) - np.asarray(a, float)
    length = np.linalg.norm(d, axis=-1)
    t = d / np.maximum(length, 1e-300)[..., None]
    return Legs(length, length / np.asarray(c, float), t, t.copy())


def circular_legs(a: np.ndarray, b: np.ndarray, c_a: np.ndarray, g: np.ndarray) -> Legs:
    """Circular legs a -> b ((N, 3) m) in c = c_a + g (z - z_a) (c_a (N,) m/s, g (N,) 1/s); see module."""
    a = np.atleast_2d(np.asarray(a, float))
    b = np.atleast_2d(np.asarray(b, float))
    a, b = np.broadcast_arrays(a, b)
    c_a = np.broadcast_to(np.asarray(c_a, float), a.shape[:1])
    g = np.broadcast_to(np.asarray(g, float), a.shape[:1])
    out = straight_legs(a, b, c_a)
    length, time, t_a, t_b = (np.array(v) for v in out)
    d = b - a
    chord = np.linalg.norm(d, axis=1)
    h = np.hypot(d[:, 0], d[:, 1])
    curved = (np.abs(g) * chord / c_a > STRAIGHT_REL) & (h > 1e-9 * np.maximum(chord, 1e-300))
    if np.any(curved):
        i = np.nonzero(curved)[0]
        gi, ci, hi = g[i], c_a[i], h[i]
        za = np.zeros_like(hi)
        zb = d[i, 2]
        cb = ci + gi * zb
        if np.any(cb <= 0):
            raise ValueError("the linear sound-speed fit reaches c <= 0 on a leg")
        zc = -ci / gi
        xc = (hi**2 + (zb - zc) ** 2 - (za - zc) ** 2) / (2.0 * hi)
        radius = np.hypot(xc, za - zc)
        psi_a = np.arctan2(za - zc, 0.0 - xc)
        psi_b = np.arctan2(zb - zc, hi - xc)
        dpsi = np.mod(psi_b - psi_a + np.pi, 2.0 * np.pi) - np.pi
        length[i] = radius * np.abs(dpsi)
        eps = gi**2 * chord[i] ** 2 / (2.0 * ci * cb)
        time[i] = np.log1p(eps + np.sqrt(eps * (2.0 + eps))) / np.abs(gi)
        horiz = np.column_stack([d[i, 0] / hi, d[i, 1] / hi])
        for ends, (x0, z0), tang in (("a", (0.0, za), t_a), ("b", (hi, zb), t_b)):
            del ends
            rx, rz = x0 - xc, z0 - zc  # radius vector (along, up)
            tx, tz = -rz, rx  # perpendicular; orient along the chord
            sgn = np.sign(tx * hi + tz * zb)
            tx, tz = tx * sgn / radius, tz * sgn / radius
            tang[i] = np.column_stack([tx * horiz[:, 0], tx * horiz[:, 1], tz])
    return Legs(length, time, t_a, t_b)


def fit_linear_c(
    c_eff: Callable[[np.ndarray, np.ndarray], np.ndarray], a: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares linear fit c ~ c_a + g (z - z_a) of the effective sound speed along chords a -> b.

    c_eff(points (M, 3), unit horizontal directions (M, 2)) -> (M,) m/s, e.g. the profile plus the wind
    along the direction. Returns (c_a (N,), g (N,)): the fit's value at a and its gradient."""
    a = np.atleast_2d(np.asarray(a, float))
    b = np.atleast_2d(np.asarray(b, float))
    a, b = np.broadcast_arrays(a, b)
    s = np.linspace(0.0, 1.0, N_FIT_SAMPLES)
    chord = np.linalg.norm(b - a, axis=1)
    lift = np.maximum(FIT_LIFT_MIN_M, FIT_LIFT_REL * chord)  # vertical spread: a level leg still sees dc/dz
    pts = a[:, None, :] + s[None, :, None] * (b - a)[:, None, :]
    pts = np.concatenate([pts, pts + lift[:, None, None] * np.array([0.0, 0.0, 1.0])], axis=1)
    d = b[:, :2] - a[:, :2]
    hn = np.linalg.norm(d, axis=1, keepdims=True)
    e = np.where(hn > 0, d / np.maximum(hn, 1e-300), np.array([1.0, 0.0]))
    m = pts.shape[1]
    cs = np.asarray(c_eff(pts.reshape(-1, 3), np.repeat(e, m, axis=0)), float).reshape(pts.shape[:2])
    dz = pts[:, :, 2] - a[:, None, 2]
    zm = dz.mean(axis=1, keepdims=True)
    cm = cs.mean(axis=1, keepdims=True)
    var = ((dz - zm) ** 2).sum(axis=1)
    g = ((dz - zm) * (cs - cm)).sum(axis=1) / var
    return cm[:, 0] - g * zm[:, 0], g


class ProfileLegs:
    """The leg model of a job's profile: circular legs of the linear-c fit (:func:`fit_linear_c`,
    :func:`circular_legs`), plus :meth:`shadow`, the refractive-shadow amplitude of a leg
    (:mod:`.leg_shadow`). Called as a LegModel: (a (N, 3), b (N, 3)) m -> Legs.

    c_eff(points (M, 3) m, unit horizontal directions (M, 2)) -> (M,) m/s: the profile plus the wind
    along the direction; stratified: c_eff depends on the height alone (one limiting-ray column per
    plane height); azimuthal: it depends on the direction (a wind)."""

    def __init__(
        self, c_eff: Callable[[np.ndarray, np.ndarray], np.ndarray], stratified: bool = True, azimuthal: bool = False
    ) -> None:
        self.c_eff = c_eff
        self.stratified = stratified
        self.azimuthal = azimuthal
        self._rays: dict = {}

    def __call__(self, a: np.ndarray, b: np.ndarray) -> Legs:
        ca, g = fit_linear_c(self.c_eff, a, b)
        return circular_legs(a, b, ca, g)

    def shadow(
        self, a: np.ndarray, b: np.ndarray, z0: np.ndarray | float, f_hz: np.ndarray, flow_resistivity: float | None
    ) -> np.ndarray | None:
        """(F, N) amplitude factor of legs a -> b ((N, 3) m, real end points) whose side's ground plane is
        z = z0 (m, scalar or (N,)) with that flow resistivity (Pa s/m^2, None: rigid), at bands f_hz (F,)
        Hz; None when no leg is in a refractive shadow (:mod:`.leg_shadow`)."""
        from bentray.engine.diffraction.leg_shadow import leg_shadow

        a = np.atleast_2d(np.asarray(a, float))
        b = np.atleast_2d(np.asarray(b, float))
        a, b = np.broadcast_arrays(a, b)
        z = np.broadcast_to(np.asarray(z0, float), (a.shape[0],))
        return leg_shadow(self.c_eff, a, b, z, f_hz, flow_resistivity, self.stratified, self.azimuthal, self._rays)[1]

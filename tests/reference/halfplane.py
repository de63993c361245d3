"""Independent reference: a point source and a thin rigid half-plane in free field, exact.

Shares no code with the engine. Time factor exp(-i w t); pressure normalised so the free field is
exp(i k R) / R (|p| = 1 at 1 m; TL = -20 log10 |p| re 1 m free field).

Frame of the edge: cylindrical coordinates (rho, phi, y) about the edge line (y along it), phi measured
from one face of the screen through the air, 0 < phi < 2 pi (the screen occupies phi = 0 = 2 pi).
``EdgeFrame`` maps world points to these coordinates.

Exact solution = geometrical acoustics + the Biot-Tolstoy-Medwin edge integral (Svensson, Fred and
Vanderkooy 1999, JASA 106:2331; frequency-domain line-integral form of Svensson et al. 2009), exact for
an infinite rigid wedge, here with exterior angle 2 pi (nu = pi / (2 pi) = 1/2; Macdonald's half-plane):

    p = p_geo + p_d,   p_d = -(nu / (4 pi)) int_{-inf}^{inf} sum_i beta_i(y') exp(i k (m + l)) / (m l) dy',
    beta_i = sin(nu phi_i) / (cosh(nu eta) - cos(nu phi_i)),  phi_i = pi +- phi0 +- phi (4 terms),
    eta = acosh((m l + (y' - y0)(y' - y)) / (rho0 rho)),

m, l the distances from the source and from the receiver to the edge point y'; p_geo the direct wave
where |phi - phi0| < pi and the specular image where phi + phi0 < pi or > 3 pi, each with weight 1/2
exactly on its boundary (where its beta term vanishes identically: the delta-like limit of beta is
what makes p continuous across the boundaries). Quadrature: a logarithmic grid in |y' - y_apex| near
the apex point (resolves the near-singular beta close to the boundaries), Simpson on a uniform grid
(40 points per wavelength of the 2k oscillation) further out, a smooth cos^2 taper over the outer
half of +-40 max(rho0, rho, lambda) (the integrand decays as exp(2 i k |y'|) / |y'|^3).

Asymptotics used by the tests: Keller's GTD deep in the shadow, total = incident / 2 on the shadow
boundary (-6 dB), Maekawa's 10 log10(3 + 20 N), N = 2 delta / lambda, within 1-2 dB for N > 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import simpson

C0_DEFAULT = 340.0


@dataclass(frozen=True)
class EdgeFrame:
    """A half-plane in world coordinates (m): a point on its edge, the edge direction, and the unit
    vector lying in the screen, perpendicular to the edge, pointing from the edge into the screen
    (e.g. a vertical screen below a horizontal edge at height h: point (0, 0, h), edge (0, 1, 0),
    into_screen (0, 0, -1))."""

    point: tuple[float, float, float] = (0.0, 0.0, 0.0)
    edge: tuple[float, float, float] = (0.0, 1.0, 0.0)
    into_screen: tuple[float, float, float] = (0.0, 0.0, -1.0)

    def cylindrical(self, xyz: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rho, phi in [0, 2 pi), y) of points xyz (..., 3) in this frame."""
        e = np.asarray(self.edge, float)
        e = e / np.linalg.norm(e)
        a = np.asarray(self.into_screen, float)
        a = a - (a @ e) * e
        a = a / np.linalg.norm(a)
        b = np.cross(e, a)
        d = np.asarray(xyz, float) - np.asarray(self.point, float)
        x1, x2, y = d @ a, d @ b, d @ e
        return np.hypot(x1, x2), np.mod(np.arctan2(x2, x1), 2.0 * np.pi), y


def pressure_cyl(
    f_hz: float,
    rho0: float,
    phi0: float,
    y0: float,
    rho: ArrayLike,
    phi: ArrayLike,
    y: ArrayLike,
    c0: float = C0_DEFAULT,
) -> np.ndarray:
    """Total pressure, source (rho0, phi0, y0), receivers (rho, phi, y) broadcast together; m, rad."""
    rho, phi, y = np.broadcast_arrays(*(np.asarray(v, float) for v in (rho, phi, y)))
    if rho0 <= 0 or np.any(rho <= 0):
        raise ValueError("source and receivers must be off the edge (rho > 0)")
    if not (0 < phi0 < 2 * np.pi) or np.any((phi <= 0) | (phi >= 2 * np.pi)):
        raise ValueError("phi must lie in (0, 2 pi): points on the screen itself are excluded")
    out = np.empty(rho.shape, complex)
    for idx in np.ndindex(rho.shape):
        args = (f_hz, rho0, phi0, y0, float(rho[idx]), float(phi[idx]), float(y[idx]), c0)
        out[idx] = geometric_cyl(*args) + btm_diffracted(*args)
    return out


def pressure(
    f_hz: float,
    source: ArrayLike,
    receivers: ArrayLike,
    frame: EdgeFrame | None = None,
    c0: float = C0_DEFAULT,
) -> np.ndarray:
    """Total complex pressure re 1 m free field at receivers (..., 3) (world metres); shape (...)."""
    frame = EdgeFrame() if frame is None else frame
    rho0, phi0, y0 = frame.cylindrical(source)
    rho, phi, y = frame.cylindrical(receivers)
    return pressure_cyl(f_hz, float(rho0), float(phi0), float(y0), rho, phi, y, c0)


def tl(
    f_hz: float,
    source: ArrayLike,
    receivers: ArrayLike,
    frame: EdgeFrame | None = None,
    c0: float = C0_DEFAULT,
) -> np.ndarray:
    """Transmission loss -20 log10 |p| (dB re 1 m free field) at receivers (..., 3); shape (...)."""
    return -20.0 * np.log10(np.abs(pressure(f_hz, source, receivers, frame, c0)))


def path_difference(source: ArrayLike, receiver: ArrayLike, frame: EdgeFrame | None = None) -> float:
    """delta = (shortest path over the edge) - (straight line), m (positive in the shadow too)."""
    frame = EdgeFrame() if frame is None else frame
    rho0, _, y0 = frame.cylindrical(source)
    rho, _, y = frame.cylindrical(receiver)
    over = float(np.hypot(rho + rho0, y - y0))
    return over - float(np.linalg.norm(np.asarray(receiver, float) - np.asarray(source, float)))


def maekawa_db(fresnel_number: ArrayLike) -> np.ndarray:
    """Maekawa's barrier attenuation 10 log10(3 + 20 N), N = 2 delta / lambda (shadow side), dB."""
    return 10.0 * np.log10(3.0 + 20.0 * np.asarray(fresnel_number, float))


_TOL = 1e-12  # rad: a receiver this close to a geometric boundary is on it


def btm_diffracted(
    f_hz: float,
    rho0: float,
    phi0: float,
    y0: float,
    rho: float,
    phi: float,
    y: float,
    c0: float = C0_DEFAULT,
    ppw: int = 40,
    extent: float = 40.0,
) -> complex:
    """Diffracted pressure of a rigid half-plane, BTM edge integral (module docstring); complex."""
    k = 2.0 * np.pi * f_hz / c0
    lam = c0 / f_hz
    nu = 0.5
    ya = y0 + (y - y0) * rho0 / (rho0 + rho)  # apex: the point of the shortest path over the edge
    big_y = extent * max(rho0, rho, lam)
    a_in = 0.25 * min(rho0, rho, lam)
    u_in = np.geomspace(1e-10 * a_in, a_in, 401)
    n_out = int(np.ceil((big_y - a_in) / (0.5 * lam) * ppw)) | 1
    u_out = np.linspace(a_in, big_y, n_out)
    taper = np.where(u_out < 0.5 * big_y, 1.0, np.cos(0.5 * np.pi * (u_out - 0.5 * big_y) / (0.5 * big_y)) ** 2)
    angles = [nu * (np.pi + s0 * phi0 + s1 * phi) for s0 in (1.0, -1.0) for s1 in (1.0, -1.0)]
    angles = [a for a in angles if not (abs(np.sin(a)) < _TOL and np.cos(a) > 0)]  # on a boundary: 0

    def integrand(t: np.ndarray) -> np.ndarray:
        m = np.sqrt(rho0**2 + (t - y0) ** 2)
        ell = np.sqrt(rho**2 + (t - y) ** 2)
        x = np.maximum((m * ell + (t - y0) * (t - y)) / (rho0 * rho), 1.0)
        # cosh(nu eta) - cos(a) = 2 sinh^2(nu eta / 2) + 2 sin^2(a / 2) (no cancellation near the apex)
        sh2 = np.sinh(0.5 * nu * np.arccosh(x)) ** 2
        beta = sum(np.sin(a) / (2.0 * sh2 + 2.0 * np.sin(0.5 * a) ** 2) for a in angles)
        return beta * np.exp(1j * k * (m + ell)) / (m * ell)

    total = 0j
    for side in (1.0, -1.0):
        total += simpson(integrand(ya + side * u_in) * u_in, x=np.log(u_in))
        total += simpson(integrand(ya + side * u_out) * taper, x=u_out)
    return complex(-(nu / (4.0 * np.pi)) * total)


def geometric_cyl(
    f_hz: float, rho0: float, phi0: float, y0: float, rho: float, phi: float, y: float, c0: float = C0_DEFAULT
) -> complex:
    """Geometrical-acoustics field of a rigid half-plane: the direct wave where |phi - phi0| < pi, the
    image (specular reflection) where phi + phi0 < pi or > 3 pi; half of each exactly on its boundary."""
    k = 2.0 * np.pi * f_hz / c0
    out = 0j
    dy2 = (y - y0) ** 2
    for ang, lit in ((phi - phi0, np.pi - abs(phi - phi0)), (phi + phi0, abs(phi + phi0 - 2 * np.pi) - np.pi)):
        w = 1.0 if lit > _TOL else (0.5 if lit >= -_TOL else 0.0)
        if w:
            r = np.sqrt(rho**2 + rho0**2 - 2 * rho * rho0 * np.cos(ang) + dy2)
            out += w * np.exp(1j * k * r) / r
    return complex(out)


def gtd_diffracted(f_hz: float, rho0: float, phi0: float, rho: float, phi: float, c0: float = C0_DEFAULT) -> complex:
    """Keller's GTD edge-diffracted wave, source and receiver in one plane normal to the edge (y = y0):
    D exp(i k (rho + rho0)) / sqrt(rho rho0 (rho + rho0)), D = -exp(i pi/4) / (2 sqrt(2 pi k))
    [sec((phi - phi0)/2) + sec((phi + phi0)/2)]; valid k rho >> 1 away from the boundaries."""
    k = 2.0 * np.pi * f_hz / c0
    d = -np.exp(0.25j * np.pi) / (2.0 * np.sqrt(2.0 * np.pi * k))
    d *= 1.0 / np.cos(0.5 * (phi - phi0)) + 1.0 / np.cos(0.5 * (phi + phi0))
    return complex(d * np.exp(1j * k * (rho + rho0)) / np.sqrt(rho * rho0 * (rho + rho0)))

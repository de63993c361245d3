"""Creeping waves in the shadow of upward refraction: the residue series of the linear-k^2 atmosphere.

Model (Pierce, "Acoustics", 1981, ch. 9-8 / 9-9; Berry and Daigle 1988, JASA 83:2047; Embleton 1996,
JASA 100:31). A point source at height z_s over a locally reacting plane ground (normalised impedance Z,
time factor exp(-i w t)) in a stratified medium with

    k(z)^2 = k0^2 (1 + a z),   a > 0   (sound speed decreasing with height: upward refraction;
                                        c = c0 / sqrt(1 + a z) ~ c0 (1 - a z / 2), i.e. dc/dz = -a c0 / 2).

The height equation phi'' + (k(z)^2 - kappa^2) phi = 0 has the solution that radiates upward
(exp(+i int k_z dz) as z -> inf)

    phi(z) = Ai(zeta + e^{-i pi/3} l z),   l = (k0^2 a)^(1/3),   kappa^2 = k0^2 - l^2 e^{i pi/3} zeta,

and the ground condition phi'(0) + i beta phi(0) = 0 (beta = k0 / Z) gives the eigenvalue equation

    Ai'(zeta) + q Ai(zeta) = 0,   q = i beta e^{i pi/3} / l

(rigid ground q = 0: zeta_n = a'_n, the zeros of Ai'). Its roots are complex for any ground (Im kappa_n > 0:
every mode decays with range: creeping waves, no trapped modes). The Green's function has no branch cut
(Ai is entire), so the field is the residue series

    p(r, z) = i pi sum_n phi_n(z_s) phi_n(z) H0^(1)(kappa_n r) / N_n,
    N_n = int_0^inf phi_n^2 dz = (Ai'(zeta_n)^2 - zeta_n Ai(zeta_n)^2) / (e^{-i pi/3} l)

(bilinear norm, the integral continued along the anti-Stokes line), normalised so that p ~ exp(i k R)/R
near the source: |p|^2 is the energy re the free field at 1 m. The series is exact for this medium; it
converges fast in the shadow (term n decays as exp(-Im kappa_n r), Im kappa_n ~ l^2 |a'_n| sin(60 deg) /
(2 k0)) and slowly in the lit zone, where ray theory (the beam field) gives the level instead.

Roots: Newton on Ai' + q Ai from the rigid zeros a'_n with q continued from 0 (|q| <= 1), or on
Ai + (1/q) Ai' from the soft zeros a_n with 1/q continued from 0 (|q| > 1); the result is checked
(relative residual, distinct roots) and a failure raises ``RuntimeError``. Airy values are taken in
log form (``airye`` scaling where Re w >= 0) so that heights of hundreds of metres at kHz neither
overflow nor underflow.

The real profile (:func:`profile_modes`): the same residue series with height functions of the sampled
c(h) itself (Numerov upward from the ground, each mode continued above its own top height as linear
k^2 with the local gradient), roots continued from the linear-k^2 modes of :func:`creeping_layer_guess`.
Validated against the closed form in linear k^2 and, for c = 340 - ln(1 + z), against the GFPE at
100 Hz (robust) and 500 Hz (depends on the top-height cap: docs/physics.md §15, open).

Fallback fit (:func:`fit_linear_k2`): ``a`` such that the model's limiting ray -- x(h) = 2 sqrt(h / a)
in linear k^2 -- reaches the source and receiver heights over the real profile's shadow-boundary
distance X(z_s) + X(z_r): a = 4 (sqrt z_s + sqrt z_r)^2 / (X(z_s) + X(z_r))^2. The model's shadow
boundary is then the ray-theory one and the fit depends on z_s and z_r, not on the range; for a log
profile it is far too deep far into the shadow (docs/physics.md §15), hence only a fallback.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import ai_zeros, airy, airye, hankel1e

__all__ = [
    "CreepingModes",
    "LimitingRay",
    "ProfileModes",
    "creeping_modes",
    "creeping_pressure",
    "creeping_layer_guess",
    "creeping_terms",
    "fit_linear_k2",
    "limiting_ray",
    "profile_height_functions",
    "profile_modes",
    "profile_pressure",
]

SoundSpeedOfHeight = Callable[[np.ndarray], np.ndarray]  # heights above ground (m, (n,)) -> c (m/s, (n,))

_E_M60 = np.exp(-1j * np.pi / 3.0)  # e^{-i pi/3}
_E_P60 = np.exp(1j * np.pi / 3.0)
DEFAULT_MODES = 60
_ROOT_RESIDUAL = 1e-9
N_KEPT = 6  # modes that must be followed to the real profile; higher ones may be dropped
NEWTON_TOL = 1e-8  # root steps below this fraction of l^2 end the Newton iteration (kappa^2 spacing ~ l^2)
TOP_EXPONENT = 12.0  # e-folds of growth of a mode above which its radiation condition is set


@cache
def _airy_zeros(n: int) -> tuple[np.ndarray, np.ndarray]:
    a, ap, _, _ = ai_zeros(n)  # zeros of Ai and of Ai' (real, negative, increasing |.|)
    return a, ap


def _log_ai(w: np.ndarray) -> np.ndarray:
    """log Ai(w) (complex, principal branch of the exponent), any shape; Ai(w) = exp(result)."""
    w = np.asarray(w, complex)
    out = np.empty(w.shape, complex)
    right = w.real >= 0.0
    if right.any():
        wr = w[right]
        out[right] = np.log(airye(wr)[0]) - (2.0 / 3.0) * wr * np.sqrt(wr)
    if (~right).any():
        out[~right] = np.log(airy(w[~right])[0])
    return out


@dataclass(frozen=True)
class CreepingModes:
    """Residue-series modes of one frequency and one linear-k^2 medium.

    zeta (n_modes,) complex roots of Ai' + q Ai; kappa (n_modes,) horizontal wavenumbers (1/m, Im > 0);
    weight (n_modes,) i pi / N_n (1/m); l (1/m) the Airy scale (k0^2 a)^(1/3); k0 (1/m); a (1/m);
    residual: max relative residual |Ai' + q Ai| / ((1 + |q|) (|Ai| + |Ai'| / sqrt(1 + |zeta|))) of the roots.
    """

    zeta: np.ndarray
    kappa: np.ndarray
    weight: np.ndarray
    l: float  # noqa: E741 - the Airy scale, Pierce's notation
    k0: float
    a: float
    q: complex
    residual: float


def _newton(z0: np.ndarray, steps: np.ndarray, soft: bool) -> np.ndarray:
    """Continue the roots z0 of F(z; 0) = 0 along the parameter values ``steps`` (complex, ending at the
    target). Rigid start (soft False): F = Ai' + s Ai. Soft start: F = Ai + s Ai'."""
    z = z0.astype(complex)
    for s in steps:
        for _ in range(40):
            ai, aip, _, _ = airy(z)
            if soft:
                f, df = ai + s * aip, aip + s * z * ai
            else:
                f, df = aip + s * ai, z * ai + s * aip
            dz = f / df
            z = z - dz
            if np.all(np.abs(dz) <= 1e-13 * (1.0 + np.abs(z))):
                break
    return z


def creeping_modes(
    frequency_hz: float, a: float, c0: float, impedance: complex | None, n_modes: int = DEFAULT_MODES
) -> CreepingModes:
    """The first ``n_modes`` residue-series modes (module docstring) at one frequency.

    frequency_hz (Hz, > 0); a (1/m, > 0) the linear-k^2 coefficient; c0 (m/s) the ground sound speed;
    impedance: normalised ground impedance Z (Re Z > 0, Im Z >= 0, exp(-i w t)) or None (rigid).
    Raises RuntimeError when the continuation does not converge to distinct roots.
    """
    if not (frequency_hz > 0 and a > 0 and c0 > 0 and n_modes >= 1):
        raise ValueError("frequency_hz, a, c0 and n_modes must be > 0")
    k0 = 2.0 * math.pi * frequency_hz / c0
    ell = (k0 * k0 * a) ** (1.0 / 3.0)
    beta = 0.0 if impedance is None or not np.isfinite(impedance) else k0 / complex(impedance)
    q = 1j * beta * _E_P60 / ell
    zeros_soft, zeros_rigid = _airy_zeros(n_modes)
    n_steps = int(min(60, max(1, math.ceil(abs(q) / 0.02)))) if abs(q) <= 1.0 else 0
    if abs(q) <= 1.0:
        zeta = _newton(zeros_rigid, q * np.linspace(0.0, 1.0, n_steps + 1)[1:], soft=False) if q != 0 else zeros_rigid
    else:
        p = 1.0 / q
        n_steps = int(min(60, max(1, math.ceil(abs(p) / 0.02))))
        zeta = _newton(zeros_soft, p * np.linspace(0.0, 1.0, n_steps + 1)[1:], soft=True)
    zeta = np.asarray(zeta, complex)
    ai, aip, _, _ = airy(zeta)
    residual = float(
        np.max(np.abs(aip + q * ai) / ((1.0 + abs(q)) * (np.abs(ai) + np.abs(aip) / np.sqrt(1.0 + np.abs(zeta)))))
    )
    order = np.argsort(np.abs(zeta))
    gaps = np.abs(np.diff(zeta[order]))
    if residual > _ROOT_RESIDUAL or (gaps.size and gaps.min() < 1e-6) or not np.all(np.isfinite(zeta)):
        raise RuntimeError(f"creeping-wave root continuation failed (q = {q:.4g}, residual {residual:.2e})")
    zeta = zeta[order]
    ai, aip = ai[order], aip[order]
    kappa = np.sqrt(k0 * k0 - ell * ell * _E_P60 * zeta)
    kappa = np.where(kappa.imag < 0.0, -kappa, kappa)
    norm = (aip * aip - zeta * ai * ai) / (_E_M60 * ell)
    weight = 1j * np.pi / norm
    return CreepingModes(zeta=zeta, kappa=kappa, weight=weight, l=ell, k0=k0, a=a, q=complex(q), residual=residual)


def creeping_terms(modes: CreepingModes, zs: float, ranges_m: ArrayLike, zr_m: ArrayLike) -> np.ndarray:
    """Terms of the residue series, shape (n, n_modes) complex (p = sum over the last axis).

    zs: source height (m, >= 0); ranges_m (n,) horizontal ranges (m, > 0); zr_m (n,) receiver heights
    (m, >= 0), both above the (flat) ground.
    """
    r = np.asarray(ranges_m, float).ravel()
    zr = np.asarray(zr_m, float).ravel()
    if r.shape != zr.shape:
        raise ValueError(f"ranges_m and zr_m must have the same length, got {r.shape} and {zr.shape}")
    if np.any(~np.isfinite(r)) or np.any(r <= 0.0) or np.any(~np.isfinite(zr)) or np.any(zr < 0.0) or zs < 0.0:
        raise ValueError("ranges must be finite and > 0, heights finite and >= 0 (m)")
    c = _E_M60 * modes.l
    log_s = _log_ai(modes.zeta + c * zs)  # (m,)
    log_r = _log_ai(modes.zeta[None, :] + c * zr[:, None])  # (n, m)
    x = modes.kappa[None, :] * r[:, None]
    log_h = np.log(hankel1e(0, x)) + 1j * x
    return np.exp(log_s[None, :] + log_r + log_h) * modes.weight[None, :]


def creeping_pressure(modes: CreepingModes, zs: float, ranges_m: ArrayLike, zr_m: ArrayLike) -> np.ndarray:
    """Complex pressure re 1 m free field of the residue series (module docstring), shape (n,)."""
    return creeping_terms(modes, zs, ranges_m, zr_m).sum(axis=1)


# ---------------------------------------------------------------------------------------------
# The limiting ray of a stratified profile and the linear-k^2 fit
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LimitingRay:
    """The ray that grazes the ground in a stratified c(h), tabulated against the height h (m).

    upward: True when c(h) < c(h_g) for every tabulated height above h_g (the ray leaves the ground
    and never turns back down below ``h_max``); h_g (m): the height up to which c stays at its ground
    value (0 for a profile that decreases from the ground; z_g for the log-law wind, which is 0 below
    z_g): the limiting ray grazes the top of that layer. c_ground (m/s) = c(h_g).
    ``x_of_h(h)`` gives the horizontal distance (m) from the grazing point to height h along the ray
    (0 below h_g, nan above the first height where the ray would turn, i.e. c(h) >= c_ground).
    """

    h: np.ndarray
    x: np.ndarray
    h_g: float
    c_ground: float
    upward: bool

    def x_of_h(self, heights: ArrayLike) -> np.ndarray:
        hh = np.asarray(heights, float)
        u = np.sqrt(np.maximum(hh - self.h_g, 0.0))
        uu = np.sqrt(np.maximum(self.h - self.h_g, 0.0))
        out = np.interp(u, uu, self.x, right=np.nan)
        return np.where(hh <= self.h_g, 0.0, out)


_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)


def limiting_ray(c_of_h: SoundSpeedOfHeight, h_max: float, n_intervals: int = 256) -> LimitingRay:
    """Tabulate the grazing ray of c(h) from the ground to ``h_max`` (m).

    Snell: cos theta(h) = c(h) / c_ground, dx/dh = cot theta. With h = h_g + u^2 the integrand
    2 u cot theta is finite at the grazing point (c drops linearly there), and each of ``n_intervals``
    equal steps in u is integrated with 8-point Gauss-Legendre. ``c_of_h`` maps heights above the
    ground (m, (n,)) to sound speeds (m/s, (n,)).
    """
    if not (np.isfinite(h_max) and h_max > 0):
        raise ValueError("h_max must be finite and > 0 (m)")
    probe = np.concatenate([[0.0], np.geomspace(1e-4, h_max, 400)])
    cp = np.asarray(c_of_h(probe), float)
    if cp.shape != probe.shape or not np.all(np.isfinite(cp) & (cp > 0)):
        raise ValueError("c_of_h must return finite sound speeds > 0 (m/s), one per height")
    c_ground = float(cp[0])
    flat = np.flatnonzero(cp < c_ground * (1.0 - 1e-12))
    h_g = 0.0
    if flat.size and flat[0] > 1:  # c stays at its ground value up to some height: bisect for its top
        h_g = _bisect_top(c_of_h, float(probe[flat[0] - 1]), float(probe[flat[0]]), c_ground * (1.0 - 1e-12))
    upward = flat.size > 0 and bool(np.all(cp[flat[0] :] < c_ground * (1.0 - 1e-12)))
    u_max = math.sqrt(max(h_max - h_g, 0.0))
    edges = np.linspace(0.0, u_max, n_intervals + 1)
    mid, half = 0.5 * (edges[1:] + edges[:-1]), 0.5 * np.diff(edges)
    u = (mid[:, None] + half[:, None] * _GL_X[None, :]).ravel()
    if flat.size == 0:  # c never below its ground value at the probes (downward refraction, homogeneous air)
        # if c >= c_ground at a node of the first interval, that piece is inf and every x above the ground
        # nan, whatever the other nodes give (_ray_span): the full table, without its 8 n_intervals
        # evaluations of c (the consultant example's downward case: 4,362 columns, diffraction 7.2 -> 4.9 s)
        u0 = u[: _GL_X.size]
        if np.any(np.asarray(c_of_h(h_g + u0 * u0), float) >= c_ground):
            x = np.full(n_intervals + 1, np.nan)
            x[0] = 0.0
            return LimitingRay(h=h_g + edges * edges, x=x, h_g=h_g, c_ground=c_ground, upward=False)
    x = _ray_span(np.asarray(c_of_h(h_g + u * u), float), u, half, c_ground)
    return LimitingRay(h=h_g + edges * edges, x=x, h_g=h_g, c_ground=c_ground, upward=bool(upward))


_BISECT_STEPS = 60  # halvings of the bracket of the flat layer's top (past double precision's 52)
_BISECT_LEVELS = 6  # halvings decided per call of c_of_h (63 midpoints)


def _bisect_top(c_of_h: SoundSpeedOfHeight, lo: float, hi: float, below: float) -> float:
    """The top (m) of the layer where c stays at its ground value, between lo (c not below ``below``) and hi
    (c below it): _BISECT_STEPS halvings, ``mid = 0.5 (lo + hi)``, hi = mid where c(mid) < below, else
    lo = mid; returns lo.

    The same midpoints and decisions as one halving per call, made _BISECT_LEVELS at a time: each call
    evaluates the whole tree of midpoints the next levels can reach (63, in heap order: node i's halves are
    2i + 1 where c < below, 2i + 2 where not), then walks it. c_of_h is pointwise, so the result is the
    one-at-a-time bisection's bit for bit in 10 calls instead of 60 (columns over terrain whose plane lies
    below the ground there, where c is flat up to the ground: 376 of the consultant upward case's 4,872,
    0.38 ms each instead of about 1.5 ms)."""
    done = 0
    while done < _BISECT_STEPS:
        levels = min(_BISECT_LEVELS, _BISECT_STEPS - done)
        brackets = [(lo, hi)]
        mids: list[float] = []
        for _ in range(levels):
            nxt = []
            for a, b in brackets:
                m = 0.5 * (a + b)
                mids.append(m)
                nxt += [(a, m), (m, b)]
            brackets = nxt
        c = np.asarray(c_of_h(np.array(mids)), float)
        i = 0
        for _ in range(levels):
            if float(c[i]) < below:
                hi = mids[i]
                i = 2 * i + 1
            else:
                lo = mids[i]
                i = 2 * i + 2
        done += levels
    return lo


def _ray_span(c: np.ndarray, u: np.ndarray, half: np.ndarray, c_ground: float) -> np.ndarray:
    """x at the interval edges (n + 1,) m from the sound speeds c (8 n,) m/s at the Gauss-Legendre nodes u
    (8 n,) sqrt(m) of n intervals of half-widths ``half`` (n,): 8-point quadrature of 2 u cot theta per
    interval, summed; nan from the first interval where the ray turns (c >= c_ground at a node) upward."""
    cos_t = c / c_ground
    sin2 = 1.0 - cos_t * cos_t
    with np.errstate(divide="ignore", invalid="ignore"):
        integrand = np.where(sin2 > 0.0, 2.0 * u * cos_t / np.sqrt(sin2), np.inf)
    pieces = (integrand.reshape(half.size, -1) * _GL_W[None, :]).sum(axis=1) * half
    x = np.concatenate([[0.0], np.cumsum(pieces)])
    x[~np.isfinite(x)] = np.nan
    return x


def fit_linear_k2(ray: LimitingRay, zs: float, zr: ArrayLike) -> np.ndarray:
    """The linear-k^2 coefficient a (1/m) whose limiting ray joins z_s and z_r over the real profile's
    shadow-boundary distance X(z_s) + X(z_r) (module docstring); shape of ``zr``; nan where the real
    ray does not reach the height (no shadow there)."""
    zr = np.asarray(zr, float)
    total = ray.x_of_h(np.array([zs]))[0] + ray.x_of_h(zr)
    geo = np.sqrt(max(zs - ray.h_g, 0.0)) + np.sqrt(np.maximum(zr - ray.h_g, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = 4.0 * geo * geo / (total * total)
    return np.where(np.isfinite(a) & (a > 0.0), a, np.nan)


# ---------------------------------------------------------------------------------------------
# The residue series of the real profile: Numerov from the ground, linear-k^2 Airy tail above z_top
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ProfileModes:
    """Residue-series modes of a stratified k^2(z) sampled on a uniform grid ``z`` (n_z,) from the
    ground; above its own top height ``top`` (m,) each mode's medium continues as linear k^2
    (``k2_top`` (m,) 1/m^2 and gradient ``gamma_top`` (m,) 1/m^3 there) and the mode as A Ai(v(z)).

    kappa (m,) horizontal wavenumbers (Im > 0); weight (m,) i pi / N_n; phi (n_z, m) the height
    functions on the grid (phi(0) = 1; used below ``top``); tail (m,) the amplitudes A;
    residual: max relative mismatch of the roots at z_top; k0 (1/m) the ground wavenumber.
    """

    z: np.ndarray
    kappa: np.ndarray
    weight: np.ndarray
    phi: np.ndarray
    tail: np.ndarray
    top: np.ndarray
    k2_top: np.ndarray
    gamma_top: np.ndarray
    residual: float
    k0: float


def _v_top(
    k2_top: np.ndarray | float, gamma: np.ndarray | float, kappa2: np.ndarray, dz: np.ndarray | float
) -> np.ndarray:
    """Airy argument of the linear-k^2 tail, dz = z - z_top (m): e^{-i pi/3} (g^(1/3) dz + (k2_top -
    kappa^2) / g^(2/3))."""
    g3 = np.cbrt(gamma)
    return _E_M60 * (g3 * dz + (k2_top - kappa2) / (g3 * g3))


def _numerov(k2: np.ndarray, h: float, kappa2: np.ndarray, beta: complex) -> np.ndarray:
    """phi'' = -(k^2 - kappa^2) phi upward from phi(0) = 1, phi'(0) = -i beta (Numerov, step h; the
    stable direction: creeping modes grow with height). Returns phi (n_z, m)."""
    n = k2.size
    f = k2[:, None] - kappa2[None, :]  # (n, m)
    c = h * h / 12.0
    p0 = np.ones(kappa2.size, complex)
    d0 = np.full(kappa2.size, -1j * beta, complex)
    f0, f1 = f[0], f[1]
    df0 = (f1 - f0) / h
    dd0 = -f0 * p0
    ddd0 = -df0 * p0 - f0 * d0
    p1 = p0 + h * d0 + 0.5 * h * h * dd0 + h**3 / 6.0 * ddd0 + h**4 / 24.0 * (-2.0 * df0 * d0 - f0 * dd0)
    out = np.empty((n, kappa2.size), complex)
    out[0], out[1] = p0, p1
    a_ = 2.0 * (1.0 - 5.0 * c * f)
    b_ = 1.0 + c * f
    for j in range(1, n - 1):
        out[j + 1] = (a_[j] * out[j] - b_[j - 1] * out[j - 1]) / b_[j + 1]
    return out


def _at_top(phi: np.ndarray, h: float, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """phi and phi' (4th-order central difference) of each mode (column) at its own grid index."""
    cols = np.arange(idx.size)
    p = phi[idx, cols]
    d = (-phi[idx + 2, cols] + 8.0 * phi[idx + 1, cols] - 8.0 * phi[idx - 1, cols] + phi[idx - 2, cols]) / (12.0 * h)
    return p, d


def _mismatch(
    phi_t: np.ndarray, dphi_t: np.ndarray, k2_top: np.ndarray, gamma: np.ndarray, kappa2: np.ndarray
) -> np.ndarray:
    """1 - phi' Ai / (phi d Ai') at each mode's top: zero when phi continues as the upgoing Ai tail."""
    ai, aip, _, _ = airy(_v_top(k2_top, gamma, kappa2, 0.0))
    d = _E_M60 * np.cbrt(gamma)
    return 1.0 - dphi_t * ai / (phi_t * d * aip)


def _profile_modes(
    frequency_hz: float,
    c_of_h: SoundSpeedOfHeight,
    impedance: complex | None,
    z_top: float,
    guess_a: float,
    n_modes: int = 12,
    n_grid: int = 401,
    n_continuation: int = 4,
) -> ProfileModes:
    """Residue-series modes of the stratified profile c(h) (``c_of_h``: heights above ground in m ->
    m/s) from the ground up, each mode continued above its own top height as linear k^2 with the local
    gradient (floored at 1e-7 k0^2 per m, a tail that still radiates upward).

    Mode n's top is min(z_top, (TOP_EXPONENT / (2 sin 60deg |zeta_n|))^2 / l) with zeta_n, l of the
    guess: above it the upgoing solution outgrows the other one by more than exp(TOP_EXPONENT), so the
    radiation condition can no longer be resolved there -- and the mode's eigenvalue no longer depends
    on the medium there. The roots are continued from those of the linear-k^2 model ``guess_a`` (1/m,
    :func:`creeping_modes`) along k^2_s = (1 - s) k^2_lin + s k^2, s: 0 -> 1, with Newton at each step
    (analytic mismatch, finite-difference derivative); a step is accepted when every mode converged,
    none merged and none moved by more than 0.3 of its distance to the nearest other root, else
    halved; once the step is below 1/32, modes beyond the first N_KEPT that fail are dropped instead
    (RuntimeError when the step falls below 1e-4).
    """
    if not (frequency_hz > 0 and z_top > 0 and guess_a > 0 and n_grid >= 16):
        raise ValueError("frequency_hz, z_top and guess_a must be > 0, n_grid >= 16")
    z = np.linspace(0.0, z_top, n_grid)
    h = float(z[1] - z[0])
    c = np.asarray(c_of_h(z), float)
    if c.shape != z.shape or not np.all(np.isfinite(c) & (c > 0)):
        raise ValueError("c_of_h must return finite sound speeds > 0 (m/s), one per height")
    omega = 2.0 * math.pi * frequency_hz
    k2_real = (omega / c) ** 2
    k0 = omega / c[0]
    lin = creeping_modes(frequency_hz, guess_a, float(c[0]), impedance, n_modes)
    k2_lin = k0 * k0 * (1.0 + guess_a * z)
    beta = 0.0 if impedance is None or not np.isfinite(impedance) else k0 / complex(impedance)
    floor = 1e-7 * k0 * k0
    scale = lin.l * lin.l
    tops = np.minimum(z_top, (TOP_EXPONENT / (math.sqrt(3.0) * np.abs(lin.zeta))) ** 2 / lin.l)
    idx = np.clip(np.rint(tops / h).astype(int), 4, n_grid - 3)

    def medium(s: float, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        k2 = (1.0 - s) * k2_lin + s * k2_real
        grad = np.maximum((k2[idx + 1] - k2[idx - 1]) / (2.0 * h), floor)
        return k2, k2[idx], grad

    def mismatch(k2v: np.ndarray, s: float, idx: np.ndarray) -> np.ndarray:
        k2, k2t, gt = medium(s, idx)
        pt, dt = _at_top(_numerov(k2, h, k2v, beta), h, idx)
        return _mismatch(pt, dt, k2t, gt, k2v)

    def newton(k2v: np.ndarray, s: float, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-mode Newton; returns the roots and which converged (finite, step <= NEWTON_TOL l^2)."""
        done = np.zeros(k2v.size, bool)
        for _ in range(15):
            f0 = mismatch(k2v, s, idx)
            step_h = 1e-7 * scale
            df = (mismatch(k2v + step_h, s, idx) - f0) / step_h
            step = f0 / df
            good = np.isfinite(step)
            k2v = np.where(good & ~done, k2v - np.where(good, step, 0.0), k2v)
            done |= good & (np.abs(step) <= NEWTON_TOL * scale)
            if done.all():
                break
        return k2v, done

    kap2 = lin.kappa**2
    s_now, ds, tries = 0.0, 1.0 / n_continuation, 0
    while s_now < 1.0 and tries < 200:
        tries += 1
        s_next = min(1.0, s_now + ds)
        trial, done = newton(kap2, s_next, idx)
        spacing = np.min(np.abs(kap2[:, None] - kap2[None, :]) + np.eye(kap2.size) * 1e300, axis=1)
        fine = done & (np.abs(trial - kap2) < 0.3 * spacing)
        if fine.all():
            kap2, s_now = trial, s_next
            ds = min(2.0 * ds, 0.5)
        elif ds < 1.0 / 32.0 and fine[:N_KEPT].all():
            kap2, idx = kap2[fine], idx[fine]  # drop the higher modes that cannot be followed
        else:
            ds *= 0.5
            if ds < 1e-4:
                break
    if s_now < 1.0:
        raise RuntimeError(f"creeping-wave root continuation stalled at s = {s_now:.3g} ({frequency_hz:g} Hz)")
    k2, k2t, gt = medium(1.0, idx)
    phi = _numerov(k2, h, kap2, beta)
    pt, dt = _at_top(phi, h, idx)
    resid = np.abs(_mismatch(pt, dt, k2t, gt, kap2))
    kappa = np.sqrt(kap2)
    kappa = np.where(kappa.imag < 0.0, -kappa, kappa)
    if resid.max() > 1e-6 or not np.all(kappa.imag > 0.0):
        raise RuntimeError(f"creeping-wave roots failed their residual check ({frequency_hz:g} Hz)")
    v_t = _v_top(k2t, gt, kap2, 0.0)
    ai, aip, _, _ = airy(v_t)
    tail = pt / ai
    d = _E_M60 * np.cbrt(gt)
    from scipy.integrate import simpson  # here, not at import: scipy.integrate pulls scipy.optimize (~0.14 s)

    inner = np.array([simpson(phi[: i + 1, n] ** 2, x=z[: i + 1]) for n, i in enumerate(idx)])
    outer = -(tail * tail) * (v_t * ai * ai - aip * aip) / d
    return ProfileModes(
        z=z,
        kappa=kappa,
        weight=1j * np.pi / (inner + outer),
        phi=phi,
        tail=tail,
        top=z[idx],
        k2_top=k2t,
        gamma_top=gt,
        residual=float(resid.max()),
        k0=k0,
    )


def profile_modes(
    frequency_hz: float,
    c_of_h: SoundSpeedOfHeight,
    impedance: complex | None,
    z_top: float,
    guess_a: float,
    n_modes: int = 12,
    n_grid: int = 401,
    n_continuation: int = 4,
) -> ProfileModes:
    """Residue-series modes of a stratified profile (see ``_profile_modes`` for the method; trial
    continuation steps that overflow are refused there, so floating-point warnings are silenced)."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _profile_modes(frequency_hz, c_of_h, impedance, z_top, guess_a, n_modes, n_grid, n_continuation)


def profile_height_functions(modes: ProfileModes, heights: ArrayLike) -> np.ndarray:
    """phi_n(h) at heights h (m, (n,)) -> (n, m) complex: cubic interpolation of the Numerov values
    below each mode's top, its Airy tail above."""
    from scipy.interpolate import CubicSpline  # here, not at import (see _profile_modes)

    h = np.asarray(heights, float).ravel()
    inner = CubicSpline(modes.z, modes.phi, axis=0)(np.minimum(h, modes.z[-1]))  # (n, m)
    dz = np.maximum(h[:, None] - modes.top[None, :], 0.0)
    v = _v_top(modes.k2_top[None, :], modes.gamma_top[None, :], (modes.kappa**2)[None, :], dz)
    tail = modes.tail[None, :] * airy(v)[0]
    return np.where(h[:, None] <= modes.top[None, :], inner, tail)


def profile_pressure(modes: ProfileModes, zs: float, ranges_m: ArrayLike, zr_m: ArrayLike) -> np.ndarray:
    """Complex pressure re 1 m free field of the profile's residue series, shape (n,)."""
    r = np.asarray(ranges_m, float).ravel()
    ps = profile_height_functions(modes, np.array([zs]))[0]
    pr = profile_height_functions(modes, zr_m)
    x = modes.kappa[None, :] * r[:, None]
    hk = hankel1e(0, x) * np.exp(1j * x)
    return (pr * hk * (ps * modes.weight)[None, :]).sum(axis=1)


def creeping_layer_guess(c_of_h: SoundSpeedOfHeight, frequency_hz: float) -> float:
    """Linear-k^2 coefficient a (1/m) of the secant sound-speed gradient over the creeping layer
    0..delta, delta = |a'_1| / l(a) (the first mode's Airy height scale), solved by fixed-point
    iteration: the starting medium of the root continuation in :func:`profile_modes`. nan when c does
    not decrease over the layer."""
    c0 = float(np.asarray(c_of_h(np.array([0.0])), float)[0])
    k0 = 2.0 * math.pi * frequency_hz / c0
    a1 = abs(float(_airy_zeros(1)[1][0]))
    delta, a = 1.0, math.nan
    for _ in range(30):
        drop = c0 - float(np.asarray(c_of_h(np.array([delta])), float)[0])
        if not drop > 0:
            return math.nan
        a = 2.0 * drop / (c0 * delta)
        new = a1 / (k0 * k0 * a) ** (1.0 / 3.0)
        if abs(new - delta) <= 1e-6 * delta:
            break
        delta = new
    return a

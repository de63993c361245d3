"""Refractive-shadow attenuation of one leg of a diffracted path (docs/physics.md §14, "Legs in a
refractive shadow").

A leg A -> B (source -> edge point, edge point -> receiver; real end points, not images) over its side's
ground plane z = z_0 (the plane the four-path images of :mod:`.paths` use there) lies in A's refractive
shadow when B is beyond the ray that grazes the plane: with X(h) the horizontal span of the limiting ray
from its grazing point up to the height h (:func:`bentray.engine.acoustics.creeping.limiting_ray`, the
job's effective profile on the column above A, in the leg's direction), the shadow distance is

    d = h_AB - X(z_A - z_0) - X(z_B - z_0)      (h_AB the leg's horizontal length),

the same criterion as the refractive-shadow stage's (range > X(z_s) + X(z_r)). d > 0 means no ray joins
A and B (the leg's circular arc of :mod:`.legs` would dip below the plane; the arc of the leg's linear
fit is not used for this test: over a log profile its gradient is the chord's, weaker than at the
ground, and it put the shadow boundary of a 4 m edge twice as far out as the profile's own grazing ray).
Across the shadow the field is the creeping wave along the ground. Keller's geometrical theory of
diffraction for a convex surface (the flat-earth equivalent of a downward-decreasing c) gives it the
decay exp(-Im kappa_1 d) over the ground between the two tangent points, kappa_1 the least attenuated
residue-series mode of the linear-k^2 medium k^2 = k_0^2 (1 + a z) over the side's impedance ground
(:func:`bentray.engine.acoustics.creeping.creeping_modes`). Its a is the secant of the column's profile
over the mode's own layer 0..delta, delta = |zeta_1| / l (l = (k_0^2 a)^(1/3), zeta_1 the ground's root),
solved by fixed-point iteration (as ``creeping_layer_guess``, with the ground's root instead of the
rigid one). The leg's amplitude factor (per band) is

    A = exp(-Im kappa_1 max(d, 0))

1 in the lit zone and on the shadow boundary, so it is continuous, and it grows by Im kappa_1 per metre
(0.04 dB/m at 100 Hz to 0.4 dB/m at 1 kHz over grass in c = 340 - ln(1 + z)): neighbouring points
differ by far less than 1 dB. Against the wavenumber integral's decay of that profile's shadow
(tests/shadows/test_leg_shadow.py) the rate is 20-55 % high, i.e. deep in the shadow the leg errs on
the quiet side and the shadow stage's own level (keep the larger) takes over; the launching loss of the
creeping wave at the tangent points (a few dB in the penumbra) is left out, which errs on the loud side
near the boundary. The roots depend on the ground only through q = i e^{i pi/3} (k_0 / a)^(1/3) / Z,
tabulated per (band, flow resistivity) in u = (k_0 / a)^(1/3) and interpolated (cubic in log u).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cache

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline

from bentray.engine.acoustics.creeping import LimitingRay, creeping_modes, limiting_ray
from bentray.engine.acoustics.ground import delany_bazley_impedance

__all__ = ["creeping_rate", "layer_rate", "layer_rates", "leg_shadow"]

_U_MIN, _U_MAX, _U_N = 0.1, 3000.0, 90  # table of u = (k0 / a)^(1/3) (dimensionless), log-spaced
_MODES = 6  # modes searched for the least attenuated one
_C_TABLE = 340.0  # the speed the table is built with (only k0 / a matters for the root; see module)
H_MAX_M = 400.0  # limiting rays are tabulated to this height above the plane; ends above it: no shadow
RAY_INTERVALS = 512  # limiting_ray's sqrt-height steps
AZ_STEP_DEG = 2.0  # with wind: directions of the tabulated limiting rays (interpolated between)
Z_STEP_M = 0.25  # plane heights sharing one column
LAYER_ITERATIONS = 40  # fixed-point steps of the creeping layer's height


@cache
def _root_table(frequency_hz: float, flow_resistivity: float | None) -> CubicSpline | None:
    """Spline of (Re, Im) of the least attenuated root zeta_1 e^{i pi/3} against log u; None: rigid
    ground (q = 0, one constant root)."""
    if flow_resistivity is None:
        return None
    k0 = 2.0 * math.pi * frequency_hz / _C_TABLE
    z = complex(delany_bazley_impedance(frequency_hz, flow_resistivity))
    us = np.geomspace(_U_MIN, _U_MAX, _U_N)
    vals = np.empty((us.size, 2))
    for i, u in enumerate(us):
        m = creeping_modes(frequency_hz, k0 / u**3, _C_TABLE, z, _MODES)
        j = int(np.argmin(m.kappa.imag))
        w = np.exp(1j * math.pi / 3.0) * m.zeta[j]
        vals[i] = (w.real, w.imag)
    return CubicSpline(np.log(us), vals, axis=0)


@cache
def _rigid_root() -> complex:
    m = creeping_modes(100.0, 1e-3, _C_TABLE, None, 1)
    return complex(np.exp(1j * math.pi / 3.0) * m.zeta[0])


def creeping_rate(frequency_hz: float, a: np.ndarray, c0: np.ndarray, flow_resistivity: float | None) -> np.ndarray:
    """Im kappa_1 (1/m, (N,)) of the least attenuated creeping mode in k^2 = k0^2 (1 + a z) (a (N,) 1/m,
    > 0; c0 (N,) m/s the ground speed) over Delany-Bazley ground (flow resistivity Pa s/m^2, None:
    rigid) at one frequency (Hz)."""
    a = np.asarray(a, float)
    k0 = 2.0 * math.pi * frequency_hz / np.asarray(c0, float)
    ell2 = (k0 * k0 * a) ** (2.0 / 3.0)
    table = _root_table(float(frequency_hz), flow_resistivity)
    if table is None:
        w = np.full(a.shape, _rigid_root())
    else:
        u = np.clip((k0 / a) ** (1.0 / 3.0), _U_MIN, _U_MAX)
        v = table(np.log(u))
        w = v[..., 0] + 1j * v[..., 1]
    kappa = np.sqrt(k0 * k0 - ell2 * w + 0j)
    return np.abs(kappa.imag)


def layer_rate(
    c_of_h: Callable[[np.ndarray], np.ndarray], frequency_hz: float, flow_resistivity: float | None
) -> float:
    """Im kappa_1 (1/m) of the module docstring for the column c_of_h (heights above the plane, m -> m/s)
    at one frequency (Hz); 0 where c does not decrease over the creeping layer (no decay)."""
    return float(layer_rates(c_of_h, [frequency_hz], flow_resistivity)[0])


def layer_rates(
    c_of_h: Callable[[np.ndarray], np.ndarray], frequencies_hz: ArrayLike, flow_resistivity: float | None
) -> np.ndarray:
    """:func:`layer_rate` at several frequencies (Hz, (F,)) of one column -> (F,) 1/m.

    Each band's fixed point of the layer height delta is iterated as in the module docstring (a from the
    drop c(0) - c(delta), delta = |zeta_1| / l, at most LAYER_ITERATIONS steps, stop at 1e-6 relative);
    the bands advance in lockstep, so each step asks ``c_of_h`` once for the heights of the bands still
    iterating instead of once per band (the column's sound speed dominated the consultant example's
    diffraction stage: ~47 us a call, mostly numpy overhead). The arithmetic per band is the scalar one,
    unchanged, so the rates equal one band at a time wherever c_of_h is pointwise (each height's speed
    independent of the others in the call; tests/shadows/test_leg_shadow.py)."""
    freqs = [float(f) for f in np.atleast_1d(np.asarray(frequencies_hz, float))]
    c0 = float(np.asarray(c_of_h(np.array([0.0])), float)[0])
    k0 = [2.0 * math.pi * f / c0 for f in freqs]
    tables = [_root_table(f, flow_resistivity) for f in freqs]
    delta = [1.0] * len(freqs)
    a = [math.nan] * len(freqs)
    flat = [False] * len(freqs)  # c does not decrease over the layer: no decay
    live = list(range(len(freqs)))  # bands still iterating
    for _ in range(LAYER_ITERATIONS):
        if not live:
            break
        c_d = np.asarray(c_of_h(np.array([delta[i] for i in live])), float)
        still = []
        for i, c_i in zip(live, c_d, strict=True):
            drop = c0 - float(c_i)
            if not drop > 0.0:
                flat[i] = True
                continue
            a[i] = 2.0 * drop / (c0 * delta[i])
            ell = (k0[i] * k0[i] * a[i]) ** (1.0 / 3.0)
            table = tables[i]
            if table is None:
                w = _rigid_root()
            else:
                v = table(math.log(min(max((k0[i] / a[i]) ** (1.0 / 3.0), _U_MIN), _U_MAX)))
                w = complex(v[0], v[1])
            new = abs(w) / ell  # |zeta_1| = |w|
            if abs(new - delta[i]) <= 1e-6 * delta[i]:
                continue  # converged: a[i] is final
            delta[i] = min(new, H_MAX_M)
            still.append(i)
        live = still
    out = np.zeros(len(freqs))
    for i, f in enumerate(freqs):
        if not flat[i]:
            out[i] = float(creeping_rate(f, np.array([a[i]]), np.array([c0]), flow_resistivity)[0])
    return out


class _Column:
    """One column's limiting ray and its per-band creeping rates (cached by :func:`leg_shadow`)."""

    def __init__(self, c_of_h: Callable[[np.ndarray], np.ndarray]) -> None:
        self.c_of_h = c_of_h
        self.ray: LimitingRay = limiting_ray(c_of_h, H_MAX_M, RAY_INTERVALS)
        # no height above the plane is reached by the grazing ray (c rises at once: downward refraction). With
        # h_g = 0, X is then nan above the plane, so every leg of the column (one end above it) is lit; with
        # h_g > 0 a leg below h_g has X = 0 and a finite span, so its rate would be read
        self.never_grazes = self.ray.h_g == 0.0 and not bool(np.any(np.isfinite(self.ray.x[1:])))
        self.rates: dict[tuple[float, float | None], float] = {}

    def rates_at(self, f_hz: np.ndarray, flow_resistivity: float | None) -> list[float]:
        """The creeping rates (1/m) at the bands f_hz (Hz), the missing ones computed together."""
        missing = [float(f) for f in f_hz if (float(f), flow_resistivity) not in self.rates]
        if missing:
            for f, r in zip(missing, layer_rates(self.c_of_h, missing, flow_resistivity), strict=True):
                self.rates[(f, flow_resistivity)] = float(r)
        return [self.rates[(float(f), flow_resistivity)] for f in f_hz]


_KEY_HEIGHTS = np.array([0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0, 256.0])


def _content_keys(
    c_eff: Callable[[np.ndarray, np.ndarray], np.ndarray], b: np.ndarray, keys: np.ndarray, azimuthal: bool
) -> np.ndarray:
    """Keys (bin, c at _KEY_HEIGHTS rounded to 1e-7 m/s) of the columns (bin, z0, x, y) rows of keys."""
    m = keys.shape[0]
    ang = np.radians(b * AZ_STEP_DEG) if azimuthal else np.zeros(m)
    e = np.repeat(np.column_stack([np.cos(ang), np.sin(ang)]), _KEY_HEIGHTS.size, axis=0)
    pts = np.column_stack([np.repeat(keys[:, 2], _KEY_HEIGHTS.size), np.repeat(keys[:, 3], _KEY_HEIGHTS.size),
                           (keys[:, 1][:, None] + _KEY_HEIGHTS[None, :]).ravel()])  # fmt: skip
    c = np.asarray(c_eff(pts, e), float).reshape(m, _KEY_HEIGHTS.size)
    return np.column_stack([b, np.round(c * 1e7)])


def _column(
    c_eff: Callable[[np.ndarray, np.ndarray], np.ndarray], z0: float, x: float, y: float, ang: float
) -> _Column:
    """The column above (x, y) from the plane z0, in the horizontal direction ang (rad)."""
    e = np.array([[math.cos(ang), math.sin(ang)]])

    def c_of_h(hh: np.ndarray) -> np.ndarray:
        hh = np.asarray(hh, float).ravel()
        pts = np.column_stack([np.full(hh.size, x), np.full(hh.size, y), z0 + hh])
        return np.asarray(c_eff(pts, np.repeat(e, hh.size, axis=0)), float)

    return _Column(c_of_h)


def leg_shadow(
    c_eff: Callable[[np.ndarray, np.ndarray], np.ndarray],
    a_pts: np.ndarray,
    b_pts: np.ndarray,
    z0: np.ndarray,
    f_hz: np.ndarray,
    flow_resistivity: float | None,
    stratified: bool = True,
    azimuthal: bool = False,
    columns: dict[tuple[float, ...], _Column] | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """(d (N,) m, A (F, N) or None) of the module docstring for legs a -> b ((N, 3) m, real end points)
    over the planes z = z0 (N,) m at the bands f_hz (F,) Hz over Delany-Bazley ground (Pa s/m^2, None:
    rigid). A is None where no leg is in a shadow (every factor 1: the caller multiplies nothing).
    d is -inf (lit, no shadow counted) where the column has no limiting ray up to those heights
    (downward refraction, a turning point below them), where both ends lie on or below the plane or one
    above H_MAX_M, and for a vertical leg; an end below the plane counts as on it (X = 0).

    c_eff(points (M, 3) m, unit horizontal directions (M, 2)) -> (M,) m/s. Columns are shared:
    stratified profiles use one column per plane height (rounded to Z_STEP_M), others the column above
    the end nearer its plane (the plane is its ground), shared by columns of the same sound speeds at
    _KEY_HEIGHTS (a terrain-following profile: one column); ``azimuthal`` (a wind): X and the rate are
    interpolated linearly between directions AZ_STEP_DEG apart (no steps between neighbouring points).
    columns: the cache of columns, filled here (one per job)."""
    a_pts = np.atleast_2d(np.asarray(a_pts, float))
    b_pts = np.atleast_2d(np.asarray(b_pts, float))
    n = a_pts.shape[0]
    z0 = np.broadcast_to(np.asarray(z0, float), (n,))
    f_hz = np.atleast_1d(np.asarray(f_hz, float))
    dxy = b_pts[:, :2] - a_pts[:, :2]
    h = np.hypot(dxy[:, 0], dxy[:, 1])
    # an end on or below the plane (an edge point in a valley below the source's ground) counts as on it:
    # X(0) = 0, continuous with the ends just above it
    ha, hb = np.maximum(a_pts[:, 2] - z0, 0.0), np.maximum(b_pts[:, 2] - z0, 0.0)
    d = np.full(n, -np.inf)
    ok = (h > 1e-9) & (np.maximum(ha, hb) > 0.0) & (np.maximum(ha, hb) < H_MAX_M)
    if not np.any(ok):
        return d, None
    az = np.degrees(np.arctan2(dxy[:, 1], dxy[:, 0]))
    if azimuthal:
        lo = np.floor(az / AZ_STEP_DEG)
        wt = az / AZ_STEP_DEG - lo
        bins = [(lo, 1.0 - wt), (lo + 1.0, wt)]
    else:
        bins = [(np.zeros(n), np.ones(n))]
    if stratified:
        zkey = np.round(z0 / Z_STEP_M) * Z_STEP_M
        xy = np.zeros((n, 2))
    else:  # the column above the end nearer its plane, whose ground the plane is (terrain-following profiles)
        zkey = z0
        xy = np.where((ha <= hb)[:, None], a_pts[:, :2], b_pts[:, :2])
    span = np.zeros(n)
    idx = np.nonzero(ok)[0]
    pending = []  # (column, its legs, their bin weights): rates are taken once the dark legs are known
    cache = columns if columns is not None else {}
    for b, w in bins:
        keys = np.column_stack([b, zkey, xy])[idx]
        if not stratified:  # columns with the same sound speeds share one entry (terrain-following: all)
            keys = _content_keys(c_eff, b[idx], keys, azimuthal)
        uniq, inv = np.unique(keys, axis=0, return_inverse=True)
        inv = np.asarray(inv).ravel()
        for u, key in enumerate(uniq):
            sel = idx[inv == u]
            k = tuple(float(v) for v in key)
            col = cache.get(k)
            if col is None:
                first = (
                    (k[1], k[2], k[3])
                    if stratified
                    else (float(zkey[sel[0]]), float(xy[sel[0], 0]), float(xy[sel[0], 1]))
                )
                col = _column(c_eff, *first, math.radians(k[0] * AZ_STEP_DEG) if azimuthal else 0.0)
                cache[k] = col
            span[sel] += w[sel] * (col.ray.x_of_h(ha[sel]) + col.ray.x_of_h(hb[sel]))
            pending.append((col, sel, w[sel]))
    dd = h[idx] - span[idx]
    d[idx] = np.where(np.isfinite(dd), dd, -np.inf)
    dark = d > 0.0
    if not np.any(dark):
        return d, None
    # the creeping rates only where a leg is dark (a lit leg's rate is never read), accumulated over the
    # columns in the same order as the spans, so a dark leg's rate is the sum it always was
    rate = np.zeros((f_hz.size, n))
    for col, sel, w_sel in pending:
        if col.never_grazes or not np.any(dark[sel]):  # never_grazes: span nan, every leg lit
            continue
        for fi, r in enumerate(col.rates_at(f_hz, flow_resistivity)):
            rate[fi, sel] += w_sel * r
    amp = np.ones((f_hz.size, n))
    amp[:, dark] = np.exp(-rate[:, dark] * d[dark][None, :])
    return d, amp

"""The field of a point source in a stratified medium over impedance ground by the wavenumber integral
(fast field program, FFP): the refractive-shadow model of engine/acoustics/refractive_shadow.py.

Model (Jensen, Kuperman, Porter, Schmidt, "Computational Ocean Acoustics", ch. 4; Salomons,
"Computational Atmospheric Acoustics", ch. 5 / App. F). Time factor exp(-i w t). With the height equation

    g'' + (k(z)^2 - kappa^2) g = -2 delta(z - z_s),   g'(0) + i beta g(0) = 0 (beta = k0 / Z),

g upgoing at the top, the field re the free field at 1 m is p(r, z) = int_0^inf g(z; kappa) J0(kappa r)
kappa dkappa (homogeneous air: g = i exp(i k_z |z - z_s|) / k_z, Sommerfeld's identity), and for
kappa r >> 1

    p(r, z) = (2 pi r)^(-1/2) e^{-i pi/4} int g(z; kappa) sqrt(kappa) e^{i kappa r} dkappa,

evaluated as one FFT over kappa = k0 + j dkappa - i eps (the contour below the real axis, eps = EPS_PERIOD /
period, undone by e^{eps r}, which keeps the wrap-around of the periodic sum e^{-EPS_PERIOD} small), for
all ranges r = m dr at once; dr = lambda / 2 (kappa from 0 to 2 k0: every propagating angle), the period
PERIOD_FACTOR x r_max. g = -2 phi_<(z_<) phi_>(z_>) / W: phi_< from the ground up (phi(0) = 1, phi'(0) =
-i beta), phi_> from the top down, W their Wronskian at the source (5-point differences); both by
Numerov (4th order, h <= lambda / POINTS_PER_WAVELENGTH, the source on the grid), each in its stable
direction for real kappa (phi_> is the upgoing solution: it does not grow above its turning point, so
the top condition is well conditioned, unlike the leaky modes' of the residue series, docs/physics.md
§15). The top: the profile continues up to z_top, then an absorbing layer of thickness z_top / 2 in which
k^2 -> k^2 (1 + i ((z - z_top) / D)^2), phi_> = 0 at its top. Receivers between grid points: 4-point
Lagrange interpolation of phi.

Exact for the medium (up to the discretisation): no mode truncation, no fitted profile. Its numerical
parameters (z_top, h, dr, period) are converged parameters: the result must not change when they do
(tests/shadows/test_shadow_gfpe.py). Cost: (z_top x 1.5 / h) x N complex Numerov steps, N = the FFT
length (PERIOD_FACTOR r_max / dr rounded up to a power of 2), i.e. proportional to f^2 r_max z_top. Each
row is one compiled pass (engine/acoustics/numerov_kernel.py): 1.8 ns per step, 0.16 s at 500 Hz and
0.62 s at 1 kHz for 1 km and z_top = 200 m (8.9e7 and 3.5e8 steps; quiet core, 2026-12-05); the numpy rows
before it took 9.8 ns per step (0.87 s at 500 Hz in the same run).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from bentray.engine.acoustics.numerov_kernel import numerov_row

__all__ = ["FfpField", "POINTS_PER_WAVELENGTH", "ffp_cells", "ffp_field"]

POINTS_PER_WAVELENGTH = 12.0  # Numerov height step lambda / 12
PERIOD_FACTOR = 4.0  # FFT period / largest range
EPS_PERIOD = 5.0  # contour offset x period (3 / 5 / 10 / 20: deepest 1 kHz level 122.0 / 121.8 / 121.2 / 136 dB)
LAYER_STRENGTH = 1.0  # absorbing layer: k^2 (1 + i A u^2), u = 0..1 over the layer
_RESCALE_EVERY = 40  # rows between renormalisations of phi_> above the stored heights, and checks within them
RENORMALISE_ABOVE = 1e100  # |phi| beyond which the recursions renormalise within the stored heights

SoundSpeedOfHeight = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class FfpField:
    """The reduced field psi(r) = p(r) e^{-i k0 r} (re the free field at 1 m) on ranges ``ranges_m`` (m,)
    (m = 0..N-1, dr apart) for each height of ``heights_m`` (h,): psi (h, m) complex; k0 (1/m) the ground
    wavenumber; cells: the Numerov steps done (heights x kappa samples), the cost measure."""

    ranges_m: np.ndarray
    heights_m: np.ndarray
    psi: np.ndarray
    k0: float
    cells: int

    def pressure(self, ranges_m: ArrayLike, height_index: np.ndarray) -> np.ndarray:
        """Complex p at ranges (n,) m and heights ``heights_m[height_index]`` (n,): linear interpolation
        of the smooth psi (dr = lambda / 2) times e^{i k0 r}."""
        r = np.asarray(ranges_m, float).ravel()
        hi = np.asarray(height_index, int).ravel()
        out = np.empty(r.size, complex)
        for k in np.unique(hi):
            sel = hi == k
            row = self.psi[k]
            out[sel] = np.interp(r[sel], self.ranges_m, row.real) + 1j * np.interp(r[sel], self.ranges_m, row.imag)
        return out * np.exp(1j * self.k0 * r)


def _renormalise(prev: np.ndarray, cur: np.ndarray, stored: dict[int, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Divide a Numerov recursion's last two rows, and the rows it has stored, by |cur| wherever that exceeds
    RENORMALISE_ABOVE (per wavenumber; the stored rows are replaced). Over the stored heights an evanescent
    wavenumber's solution grows like exp(sqrt(kappa^2 - k^2) z) and overflowed to inf (then nan) for receivers
    tens of metres above the source at a few hundred Hz: a map's whole band came out nan. The Green's function
    takes phi_< and phi_> only in ratios to their own rows at the source (the Wronskian), so one factor per
    wavenumber on every row of a solution cancels; rows far below the growth underflow to 0, where the field
    they carry is below double precision anyway. Below the threshold nothing is touched (bit for bit)."""
    big = np.abs(cur) > RENORMALISE_ABOVE
    if not big.any():
        return prev, cur
    s = np.where(big, np.abs(cur), 1.0)
    for key in stored:  # new arrays, not in place: prev is often a stored row itself (it would be divided twice)
        stored[key] = stored[key] / s
    return prev / s, cur / s


def _grid(frequency_hz: float, c_ground: float, zs: float, z_top: float) -> tuple[float, int]:
    lam = c_ground / frequency_hz
    h = lam / POINTS_PER_WAVELENGTH
    if zs > 0:
        h = zs / max(1, math.ceil(zs / h))  # the source on the grid
    n = int(math.ceil(1.5 * z_top / h)) + 3
    return h, n


def ffp_cells(frequency_hz: float, c_ground: float, zs: float, r_max: float, z_top: float) -> int:
    """The Numerov steps (heights x kappa samples) of :func:`ffp_field`: its cost measure."""
    h, n = _grid(frequency_hz, c_ground, zs, z_top)
    dr = c_ground / frequency_hz / 2.0
    return n * int(2 ** math.ceil(math.log2(PERIOD_FACTOR * r_max / dr)))


def ffp_field(
    frequency_hz: float,
    c_of_h: SoundSpeedOfHeight,
    impedance: complex | None,
    zs: float,
    heights_m: ArrayLike,
    r_max: float,
    z_top: float,
    *,
    row_step: Callable[..., None] = numerov_row,
) -> FfpField:
    """The field of the module docstring at ``heights_m`` (m above the ground, (h,)) for ranges to
    ``r_max`` (m). c_of_h: heights above the ground (m, (n,)) -> sound speed (m/s, (n,)); impedance:
    normalised ground impedance Z (exp(-i w t)) or None (rigid); zs: source height (m, >= 0); z_top (m):
    where the absorbing layer starts (above every receiver, and above the limiting ray at r_max for the
    shadow field to be converged). row_step: one Numerov row (engine/acoustics/numerov_kernel.py; the tests
    pass its numpy form)."""
    zr = np.asarray(heights_m, float).ravel()
    if not (frequency_hz > 0 and r_max > 0 and zs >= 0 and np.all(zr >= 0)):
        raise ValueError("frequency_hz and r_max must be > 0, heights >= 0 (m)")
    if not z_top > max(zs, float(zr.max(initial=0.0))):
        raise ValueError(f"z_top ({z_top:g} m) must lie above the source and every receiver")
    c_ground = float(np.asarray(c_of_h(np.array([0.0])), float)[0])
    k0 = 2.0 * math.pi * frequency_hz / c_ground
    h, n = _grid(frequency_hz, c_ground, zs, z_top)
    z = np.arange(n) * h
    depth = 0.5 * z_top
    c = np.asarray(c_of_h(np.minimum(z, 1.5 * z_top)), float)
    if c.shape != z.shape or not np.all(np.isfinite(c) & (c > 0)):
        raise ValueError("c_of_h must return finite sound speeds > 0 (m/s), one per height")
    u = np.clip((z - z_top) / depth, 0.0, None)
    k2 = (2.0 * math.pi * frequency_hz / c) ** 2 * (1.0 + 1j * LAYER_STRENGTH * u * u)
    dr = c_ground / frequency_hz / 2.0
    n_k = int(2 ** math.ceil(math.log2(PERIOD_FACTOR * r_max / dr)))
    period = n_k * dr
    dk = 2.0 * math.pi / period
    eps = EPS_PERIOD / period
    kap = k0 + (np.arange(n_k) - n_k // 2) * dk - 1j * eps
    kap2 = kap * kap
    beta = 0.0 if impedance is None or not np.isfinite(impedance) else k0 / complex(impedance)
    js = int(round(zs / h))
    jr = np.floor(zr / h).astype(int)
    # the rows each recursion must keep: the source's derivative stencil, the rows 0..2 (a source on the ground),
    # and the interpolation stencils of the receivers it serves: phi_< those at or below the source, phi_> those
    # above (memory: rows x n_k). phi_< is marched only as high as its rows: marched to receivers far above the
    # source, its evanescent wavenumbers grew so much that their renormalisation underflowed the source's rows to
    # 0 and the Wronskian became 0 / 0 (the night-noise-map example's 500 Hz band was nan).
    source_rows = {js + o for o in range(-2, 3)} | {0, 1, 2}
    below = zr <= zs
    keep = {j for j in source_rows | {int(j) + o for j in jr[below] for o in range(-1, 4)} if j >= 0}
    keep_dn = {j for j in source_rows | {int(j) + o for j in jr[~below] for o in range(-1, 4)} if j >= 0}
    j_hi = max(keep) + 2  # phi_<'s top row
    j_hi_dn = max(keep_dn) + 2  # phi_>'s stored rows lie at and below this one
    cc = h * h / 12.0
    # phi_< up from the ground (Taylor start to 4th order, then Numerov)
    up: dict[int, np.ndarray] = {}
    f0, f1 = k2[0] - kap2, k2[1] - kap2
    p0 = np.ones(n_k, complex)
    d0 = -1j * beta
    dd0 = -f0 * p0
    df = (f1 - f0) / h
    p1 = p0 + h * d0 + 0.5 * h * h * dd0 + h**3 / 6.0 * (-df * p0 - f0 * d0) + h**4 / 24.0 * (-2 * df * d0 - f0 * dd0)
    up[0], up[1] = p0, p1
    pm, pc = p0, p1
    for j in range(1, j_hi):
        pn = np.empty(n_k, complex)  # a new row: stored rows are kept by reference
        row_step(k2[j], k2[j - 1], k2[j + 1], kap2, cc, pc, pm, pn)
        pm, pc = pc, pn
        if j % _RESCALE_EVERY == 0:  # evanescent wavenumbers grow without bound: renormalise (_renormalise)
            pm, pc = _renormalise(pm, pc, up)
        if j + 1 in keep:
            up[j + 1] = pc
    # phi_> down from the top of the layer (phi = 0 there)
    dn: dict[int, np.ndarray] = {}
    p_next = np.zeros(n_k, complex)
    p_cur = np.ones(n_k, complex)
    j = n - 2
    lo = 0
    while j > lo:
        p_prev = np.empty(n_k, complex)
        row_step(k2[j], k2[j + 1], k2[j - 1], kap2, cc, p_cur, p_next, p_prev)
        p_next, p_cur = p_cur, p_prev
        j -= 1
        if j <= j_hi_dn:
            if j % _RESCALE_EVERY == 0:
                p_next, p_cur = _renormalise(p_next, p_cur, dn)
            if j in keep_dn:
                dn[j] = p_cur
        elif j % _RESCALE_EVERY == 0:
            s = np.abs(p_cur) + 1e-300
            p_cur, p_next = p_cur / s, p_next / s
    if js == 0:  # a source on the ground: the ground condition and a one-sided difference
        d_up = np.full(n_k, -1j * beta, complex)
        d_dn = (-3.0 * dn[0] + 4.0 * dn[1] - dn[2]) / (2.0 * h)
    elif js == 1:
        d_up = (up[2] - up[0]) / (2.0 * h)
        d_dn = (dn[2] - dn[0]) / (2.0 * h)
    else:
        d_up = (-up[js + 2] + 8.0 * up[js + 1] - 8.0 * up[js - 1] + up[js - 2]) / (12.0 * h)
        d_dn = (-dn[js + 2] + 8.0 * dn[js + 1] - 8.0 * dn[js - 1] + dn[js - 2]) / (12.0 * h)
    wr = up[js] * d_dn - d_up * dn[js]
    ranges = np.arange(n_k) * dr
    pre = np.sqrt(1.0 / (2.0 * math.pi * np.maximum(ranges, dr))) * np.exp(-1j * math.pi / 4.0) * dk
    pre = pre * np.exp(eps * ranges)
    sq = np.sqrt(kap)
    psi = np.empty((zr.size, n_k), complex)
    for i, (zri, j0) in enumerate(zip(zr, jr, strict=True)):
        t = zri / h - j0
        w = (-t * (t - 1) * (t - 2) / 6, (t + 1) * (t - 1) * (t - 2) / 2, -(t + 1) * t * (t - 2) / 2,
             (t + 1) * t * (t - 1) / 6)  # fmt: skip
        offs = (-1, 0, 1, 2) if j0 >= 1 else (0, 1, 2, 3)
        if j0 < 1:  # below the first interior node: shift the stencil up (t measured from node 0)
            t = zri / h
            w = ((1 - t) * (2 - t) * (3 - t) / 6, t * (2 - t) * (3 - t) / 2, -t * (1 - t) * (3 - t) / 2,
                 t * (t - 1) * (t - 2) / 6)  # fmt: skip
            j0 = 0
        if zri <= zs:
            phi = sum(wk * up[j0 + o] for wk, o in zip(w, offs, strict=True))
            g = -2.0 * phi * dn[js] / wr
        else:
            phi = sum(wk * dn[j0 + o] for wk, o in zip(w, offs, strict=True))
            g = -2.0 * up[js] * phi / wr
        spec = np.where(kap.real > 0.0, g * sq, 0.0)
        psi[i] = pre * np.fft.ifft(np.fft.ifftshift(spec)) * n_k
    return FfpField(ranges_m=ranges, heights_m=zr, psi=psi, k0=k0, cells=int(n * n_k))

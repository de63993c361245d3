"""Ground impedance and reflection coefficients for a locally reacting ground (docs/physics.md §8).

Time convention ``exp(-i w t)`` throughout: a wave travelling a distance R carries ``exp(+i k R)``, and a
passive porous ground has ``Re Z > 0`` and ``Im Z > 0`` (a stiffness-like surface impedance).

Model chain:
- Delany-Bazley normalised surface impedance Z (Z_s / rho0 c0) of a semi-infinite rigid-frame porous
  ground from its flow resistivity (the one-parameter model of Embleton, Piercy and Daigle 1983):

      Z = 1 + 9.08 (f / sigma_k)^-0.75 + i 11.9 (f / sigma_k)^-0.73,   sigma_k = sigma / 1000  (kPa s/m^2)

  We use this f/sigma form rather than the original Delany-Bazley ``X = rho0 f / sigma`` form because it
  is the one that outdoor-sound literature tabulates effective flow resistivities for (and Nord2000
  uses): it carries no air density, so Z does not silently change with the atmosphere. The two agree
  within 1 % (Re Z) and 2 % (Im Z) for rho0 = 1.21 kg/m^3 (tested). The model's validity range is about
  0.01 < rho0 f / sigma < 1.
- plane-wave coefficient ``R_p = (Z cos th - 1) / (Z cos th + 1)``, th the angle from the normal;
- Weyl-van der Pol spherical-wave coefficient ``Q = R_p + (1 - R_p) F(w)``,
  ``F(w) = 1 + i sqrt(pi) w wofz(w)``, numerical distance ``w = sqrt(i k R2 / 2) (1/Z + cos th)``
  with ``sqrt(i) = (1 + i)/sqrt(2)`` (the branch that makes ``exp(i k R2)`` the outgoing image wave).

Rigid ground is ``flow_resistivity=None`` (Z = inf): then R_p = Q = 1 exactly.

The Numba field kernel looks |Q|^2 up in a table (:func:`build_q2_table`, :func:`q2_lookup`) that is
regular in ``ln(cos th + 1e-4)`` and ``ln R2``: near grazing |Q|^2 varies on a scale
``d cos th ~ 1/sqrt(k R2)``, which a grid uniform in cos th would need thousands of points to resolve.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numba as nb
import numpy as np
from numpy.typing import ArrayLike
from scipy.special import wofz

from bentray.engine.constants import NJIT_FLAGS
from bentray.engine.kernels.llvm_inline import njit_inline

__all__ = [
    "COS_EPS",
    "DEFAULT_N_COS",
    "DEFAULT_N_R",
    "DEFAULT_SOUND_SPEED",
    "Q2Table",
    "build_q2_table",
    "delany_bazley_impedance",
    "ground_impedance",
    "ground_wave_function",
    "image_source_intensity_ratio",
    "image_source_pressure",
    "numerical_distance",
    "plane_wave_coefficient",
    "q2_lookup",
    "spherical_wave_coefficient",
]

DEFAULT_SOUND_SPEED = 343.0  # m/s, air at 20 C
_SQRT_PI = math.sqrt(math.pi)
# |w| above which F(w) is evaluated from its asymptotic series instead of 1 + i sqrt(pi) w wofz(w):
# the direct form cancels to ~1e-16 absolute while F ~ 1/(2 w^2); at |w| = 30 the 6-term series is
# exact to ~1e-17 relative (next term 135135 / (2 |w|^2)^7), the direct form to ~4e-13.
_W_ASYMPTOTIC = 30.0
# Above this |w| the surface-wave pole term of F (lower half-plane) is dropped: w^2 would overflow, and
# the term is exp(-|w|^2 cos(2 arg w)) small unless arg w lies within 1e-297 of -45 degrees.
_W_POLE_MAX = 1e150


def delany_bazley_impedance(frequency_hz: ArrayLike, flow_resistivity: ArrayLike) -> np.ndarray:
    """Normalised Delany-Bazley surface impedance Z = Z_s / (rho0 c0), time factor exp(-i w t).

    Parameters
    ----------
    frequency_hz : array_like, Hz, > 0.
    flow_resistivity : array_like, effective flow resistivity sigma in Pa s/m^2 (SI), > 0; broadcast
        with ``frequency_hz``. Typical values: snow 1e4-3e4, grass 1.5e5-3e5, compacted soil 2e6-5e6.

    Returns
    -------
    complex128 ndarray of the broadcast shape, with Re Z > 1 and Im Z > 0.
    """
    f = np.asarray(frequency_hz, dtype=np.float64)
    sigma = np.asarray(flow_resistivity, dtype=np.float64)
    if not np.all(np.isfinite(f)) or np.any(f <= 0.0):
        raise ValueError("frequency_hz must be finite and > 0")
    if not np.all(np.isfinite(sigma)) or np.any(sigma <= 0.0):
        raise ValueError("flow_resistivity must be finite and > 0 (Pa s/m^2)")
    x = f / (sigma * 1e-3)  # f / sigma with sigma in kPa s/m^2
    return (1.0 + 9.08 * x**-0.75) + 1j * (11.9 * x**-0.73)


def ground_impedance(frequency_hz: ArrayLike, flow_resistivity: float | None) -> np.ndarray:
    """Delany-Bazley Z, or complex infinity (rigid ground) when ``flow_resistivity`` is None.

    Returns complex128 ndarray with the shape of ``frequency_hz``.
    """
    if flow_resistivity is None:
        f = np.asarray(frequency_hz, dtype=np.float64)
        if not np.all(np.isfinite(f)) or np.any(f <= 0.0):
            raise ValueError("frequency_hz must be finite and > 0")
        return np.full(f.shape, complex(math.inf, 0.0), dtype=np.complex128)
    return delany_bazley_impedance(frequency_hz, flow_resistivity)


def _as_impedance(z: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(Z as complex128, mask of rigid entries). Rigid = infinite Z; a finite Z needs Re Z > 0; NaN is refused."""
    z = np.asarray(z, dtype=np.complex128)
    rigid = np.isinf(z.real) | np.isinf(z.imag)
    if np.any(np.isnan(z.real) | np.isnan(z.imag)) or np.any(z.real[~rigid] <= 0.0):
        raise ValueError("Z must have Re Z > 0 (passive ground), or be infinite (rigid)")
    return z, rigid


def _check_cos(cos_theta: ArrayLike) -> np.ndarray:
    c = np.asarray(cos_theta, dtype=np.float64)
    if not np.all((c >= 0.0) & (c <= 1.0)):
        raise ValueError("cos_theta must lie in [0, 1] (angle from the ground normal)")
    return c


def plane_wave_coefficient(z: ArrayLike, cos_theta: ArrayLike) -> np.ndarray:
    """Plane-wave reflection coefficient ``R_p = (Z cos th - 1)/(Z cos th + 1)``.

    z : normalised impedance (complex, Re > 0, or inf for rigid); cos_theta : cos of the incidence angle
    from the normal, in [0, 1]. Broadcast; returns complex128. Rigid entries give exactly 1.
    """
    z, rigid = _as_impedance(z)
    c = _check_cos(cos_theta)
    zc = np.where(rigid, 1.0, z) * c  # placeholder 1 where rigid (overwritten below)
    rp = (zc - 1.0) / (zc + 1.0)
    return np.where(rigid, 1.0 + 0.0j, rp)


def ground_wave_function(w: ArrayLike) -> np.ndarray:
    """Boundary-loss factor ``F(w) = 1 + i sqrt(pi) w wofz(w)`` (complex128, shape of ``w``).

    For ``|w| > 30`` the asymptotic series ``F ~ -sum_n (2n-1)!! / (2 w^2)^n`` is used, plus the
    surface-wave pole term ``2 i sqrt(pi) w exp(-w^2)`` where ``Im w < 0`` (from
    ``wofz(w) = 2 exp(-w^2) - wofz(-w)``); F -> 0 as |w| -> inf without overflow. ``F(0) = 1``.
    Intended for ``-pi/4 < arg w < 3 pi/4`` (passive ground); elsewhere F grows like exp(|w|^2).
    """
    w = np.asarray(w, dtype=np.complex128)
    out = np.empty(w.shape, dtype=np.complex128)
    aw = np.abs(w)
    small = aw <= _W_ASYMPTOTIC
    ws = w[small]
    out[small] = 1.0 + 1j * _SQRT_PI * ws * wofz(ws)
    big = ~small
    if np.any(big):
        wb = w[big]
        v = 0.5 * (1.0 / wb) ** 2  # 1 / (2 w^2), computed without forming w^2
        series = np.zeros_like(wb)
        term = np.ones_like(wb)
        for n in range(1, 7):
            term = term * (2 * n - 1) * v
            series += term
        fb = -series
        pole = (wb.imag < 0.0) & (np.abs(wb) < _W_POLE_MAX)
        if np.any(pole):
            wp = wb[pole]
            w2 = wp * wp
            keep = w2.real < 700.0  # exp(-700) ~ 1e-304: beyond, the term underflows anyway
            term_p = np.zeros_like(wp)
            term_p[keep] = 2j * _SQRT_PI * wp[keep] * np.exp(-w2[keep])
            fb[pole] += term_p
        out[big] = fb
    return out


def numerical_distance(z: ArrayLike, cos_theta: ArrayLike, k: ArrayLike, r2: ArrayLike) -> np.ndarray:
    """``w = sqrt(i k R2 / 2) (1/Z + cos th)`` with ``sqrt(i) = (1+i)/sqrt(2)``; rigid Z gives ``1/Z = 0``.

    k : wavenumber (rad/m, > 0); r2 : image-source distance (m, > 0). Broadcast; complex128.
    """
    z, rigid = _as_impedance(z)
    c = _check_cos(cos_theta)
    k = np.asarray(k, dtype=np.float64)
    r2 = np.asarray(r2, dtype=np.float64)
    if not np.all(k > 0.0) or not np.all(np.isfinite(k)):
        raise ValueError("k must be finite and > 0 (rad/m)")
    if not np.all(r2 > 0.0) or not np.all(np.isfinite(r2)):
        raise ValueError("r2 must be finite and > 0 (m)")
    beta = np.where(rigid, 0.0 + 0.0j, 1.0 / np.where(rigid, 1.0, z))
    return (0.5 + 0.5j) * np.sqrt(k * r2) * (beta + c)


def spherical_wave_coefficient(z: ArrayLike, cos_theta: ArrayLike, k: ArrayLike, r2: ArrayLike) -> np.ndarray:
    """Weyl-van der Pol spherical-wave reflection coefficient ``Q = R_p + (1 - R_p) F(w)``.

    Parameters (broadcast together)
    ----------
    z : normalised surface impedance, complex, Re Z > 0; non-finite (inf) for rigid ground.
    cos_theta : cos of the angle of incidence from the ground normal at the specular point, [0, 1].
    k : wavenumber 2 pi f / c, rad/m, > 0.
    r2 : source-image to receiver distance (the unfolded path length), m, > 0.

    Returns
    -------
    complex128 ndarray; exactly 1 for rigid entries.
    """
    z, rigid = _as_impedance(z)
    w = numerical_distance(z, cos_theta, k, r2)
    rp = plane_wave_coefficient(z, cos_theta)
    q = rp + (1.0 - rp) * ground_wave_function(w)
    return np.where(np.broadcast_to(rigid, q.shape), 1.0 + 0.0j, q)


def _image_geometry(
    source: ArrayLike, receivers: ArrayLike, ground_z: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s = np.asarray(source, dtype=np.float64)
    r = np.asarray(receivers, dtype=np.float64)
    if s.shape != (3,):
        raise ValueError(f"source must have shape (3,), got {s.shape}")
    if r.ndim != 2 or r.shape[1] != 3:
        raise ValueError(f"receivers must have shape (N, 3), got {r.shape}")
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(r))):
        raise ValueError("source and receivers must be finite")
    g = float(ground_z)
    if s[2] < g or np.any(r[:, 2] < g):
        raise ValueError("source and receivers must lie on or above the ground plane z = ground_z")
    d = r - s
    r1 = np.sqrt(np.einsum("ij,ij->i", d, d))
    if np.any(r1 <= 0.0):
        raise ValueError("a receiver coincides with the source")
    height_sum = (s[2] - g) + (r[:, 2] - g)
    r2 = np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2 + height_sum**2)
    cos_theta = np.divide(height_sum, r2, out=np.zeros_like(r2), where=r2 > 0.0)
    return r1, r2, np.clip(cos_theta, 0.0, 1.0)


def _wavenumber(frequency_hz: float, c: float) -> float:
    f = float(frequency_hz)
    if not (math.isfinite(f) and f > 0.0):
        raise ValueError("frequency_hz must be finite and > 0")
    if not (math.isfinite(c) and c > 0.0):
        raise ValueError("c must be finite and > 0 (m/s)")
    return 2.0 * math.pi * f / c


def image_source_pressure(
    source: ArrayLike,
    receivers: ArrayLike,
    frequency_hz: float,
    flow_resistivity: float | None,
    c: float = DEFAULT_SOUND_SPEED,
    ground_z: float = 0.0,
) -> np.ndarray:
    """Complex pressure over a flat impedance plane: ``p = exp(i k R1)/R1 + Q exp(i k R2)/R2``.

    Homogeneous air, time factor exp(-i w t), unit source strength (|p| = 1 at 1 m in free field).

    Parameters
    ----------
    source : (3,) float, m, world frame, at or above ``ground_z``.
    receivers : (N, 3) float, m, at or above ``ground_z``, none at the source.
    frequency_hz : float, Hz.
    flow_resistivity : Delany-Bazley sigma in Pa s/m^2, or None for rigid ground (Q = 1).
    c : sound speed, m/s.  ground_z : height of the horizontal ground plane, m.

    Returns
    -------
    (N,) complex128, Pa per unit source amplitude (1/m).
    """
    k = _wavenumber(frequency_hz, c)
    r1, r2, cos_theta = _image_geometry(source, receivers, ground_z)
    z = ground_impedance(frequency_hz, flow_resistivity)
    q = spherical_wave_coefficient(z, cos_theta, k, r2)
    return np.exp(1j * k * r1) / r1 + q * np.exp(1j * k * r2) / r2


def image_source_intensity_ratio(
    source: ArrayLike,
    receivers: ArrayLike,
    frequency_hz: float,
    flow_resistivity: float | None,
    c: float = DEFAULT_SOUND_SPEED,
    ground_z: float = 0.0,
) -> np.ndarray:
    """Incoherent (energy) sum ``1/R1^2 + |Q|^2/R2^2`` (1/m^2), same arguments as :func:`image_source_pressure`.

    Multiply by ``W / (4 pi)`` (source power W) for intensity in W/m^2. Returns (N,) float64.
    """
    k = _wavenumber(frequency_hz, c)
    r1, r2, cos_theta = _image_geometry(source, receivers, ground_z)
    z = ground_impedance(frequency_hz, flow_resistivity)
    q = spherical_wave_coefficient(z, cos_theta, k, r2)
    return 1.0 / r1**2 + np.abs(q) ** 2 / r2**2


# ---------------------------------------------------------------------------------------------
# |Q|^2 lookup table for the Numba field kernel
# ---------------------------------------------------------------------------------------------
class Q2Table(NamedTuple):
    """|Q|^2 sampled on a regular grid in ``u = ln(cos th + COS_EPS)`` and ``ln R2``.

    table : (n_mat, n_freq, n_cos, n_r) float64, |Q|^2 (dimensionless) for material m and band b.
    grid : (5,) float64 ``[u_min, u_step, ln_r_min, ln_r_step, cos_eps]``: node i is
        ``cos th = exp(u_min + i u_step) - cos_eps`` (from 0 to 1), node j is
        ``R2 = exp(ln_r_min + j ln_r_step)`` metres.
    """

    table: np.ndarray
    grid: np.ndarray


# Grid along cos th: uniform in ln(cos th + COS_EPS). Near grazing |Q|^2 changes on the scale
# d cos ~ max(cos, |1/Z|, 1/sqrt(k R2)) (the plane-wave coefficient turns over at cos ~ |1/Z|, F(w) is
# smooth in ln w for |w| >> 1 and w ~ sqrt(k R2) cos), i.e. *relative* steps in cos down to a floor of
# about 1/sqrt(k R2) >= 5e-4 (8 kHz, 20 km). COS_EPS = 1e-4 puts that floor below all of them.
# Grids uniform in cos (or sqrt(cos)) measured 10-50x worse at the same size.
COS_EPS = 1e-4
# Default resolution, chosen by measurement: over the octave bands 63 Hz - 8 kHz (exact midbands),
# sigma in {1e4, 5e4, 2e5, 2e6, 2e7} Pa s/m^2, R2 log-uniform in [0.5, 2e4] m and cos th both uniform and
# log-uniform down to 1e-7 (80,000 random points per material and band), the largest error of the
# bilinear lookup in |Q|^2 was (n_cos x n_r): 129 x 257: 9.4e-4; 193 x 289: 6.5e-4; 193 x 321: 5.4e-4
# (0.5 MB per material and band; checked below 1e-3 in tests/acoustics/test_ground.py). The worst case
# is hard ground (2e7) at grazing incidence and long range, where |Q|^2 reaches about 4.
DEFAULT_N_COS = 193
DEFAULT_N_R = 321


def build_q_table(
    frequencies_hz: Sequence[float] | np.ndarray,
    flow_resistivities: Sequence[float | None],
    n_cos: int = DEFAULT_N_COS,
    n_r: int = DEFAULT_N_R,
    r_min: float = 0.5,
    r_max: float = 2.0e4,
    c: float = DEFAULT_SOUND_SPEED,
) -> Q2Table:
    """Tabulate the complex spherical-wave coefficient Q for each material and band.

    Same nodes and arguments as :func:`build_q2_table`; the table is (n_mat, n_freq, n_cos, n_r, 2)
    float64 with Re Q in [..., 0] and Im Q in [..., 1] (rigid materials: exactly 1 + 0i). The beam
    field multiplies these per reflection (coherent sums need the phase of Q, not only |Q|^2).
    """
    freqs = np.asarray(frequencies_hz, dtype=np.float64)
    if freqs.ndim != 1 or freqs.size == 0:
        raise ValueError("frequencies_hz must be a non-empty 1-D sequence")
    if len(flow_resistivities) == 0:
        raise ValueError("flow_resistivities must list at least one material")
    if n_cos < 2 or n_r < 2:
        raise ValueError("n_cos and n_r must be >= 2")
    if not (0.0 < r_min < r_max and math.isfinite(r_max)):
        raise ValueError("need 0 < r_min < r_max < inf")
    u_min = math.log(COS_EPS)
    u_step = (math.log(1.0 + COS_EPS) - u_min) / (n_cos - 1)
    ln_r_min = math.log(r_min)
    ln_r_step = (math.log(r_max) - ln_r_min) / (n_r - 1)
    cos_nodes = np.clip(np.exp(u_min + np.arange(n_cos) * u_step) - COS_EPS, 0.0, 1.0)
    cos_nodes[0], cos_nodes[-1] = 0.0, 1.0
    r_nodes = np.exp(ln_r_min + np.arange(n_r) * ln_r_step)
    table = np.empty((len(flow_resistivities), freqs.size, n_cos, n_r, 2), dtype=np.float64)
    for m, sigma in enumerate(flow_resistivities):
        z_all = ground_impedance(freqs, sigma)
        for b in range(freqs.size):
            k = _wavenumber(freqs[b], c)
            q = spherical_wave_coefficient(z_all[b], cos_nodes[:, None], k, r_nodes[None, :])
            table[m, b, :, :, 0] = q.real
            table[m, b, :, :, 1] = q.imag
    grid = np.array([u_min, u_step, ln_r_min, ln_r_step, COS_EPS], dtype=np.float64)
    return Q2Table(table=table, grid=grid)


def build_q2_table(
    frequencies_hz: Sequence[float] | np.ndarray,
    flow_resistivities: Sequence[float | None],
    n_cos: int = DEFAULT_N_COS,
    n_r: int = DEFAULT_N_R,
    r_min: float = 0.5,
    r_max: float = 2.0e4,
    c: float = DEFAULT_SOUND_SPEED,
) -> Q2Table:
    """Tabulate |Q|^2 for each material (flow resistivity, None = rigid) and frequency band.

    Parameters
    ----------
    frequencies_hz : (n_freq,) Hz, > 0 (use the exact band midband frequencies).
    flow_resistivities : (n_mat,) Pa s/m^2, or None for a rigid material (its |Q|^2 is exactly 1).
    n_cos, n_r : grid nodes along ln(cos th + COS_EPS) over cos th in [0, 1] and along ln R2 over
        [ln r_min, ln r_max].
    r_min, r_max : R2 range, m; lookups outside are clamped to the end nodes.
    c : sound speed for k = 2 pi f / c, m/s.

    Returns
    -------
    :class:`Q2Table` (table (n_mat, n_freq, n_cos, n_r) float64 of |Q|^2, grid (5,) float64).
    """
    q = build_q_table(frequencies_hz, flow_resistivities, n_cos, n_r, r_min, r_max, c)
    return Q2Table(table=q.table[..., 0] ** 2 + q.table[..., 1] ** 2, grid=q.grid)


@njit_inline
def _table_cell(grid: np.ndarray, n_cos: int, n_r: int, cos_theta: float, r: float):
    """Lower node (i, j) and fractions (tu, tr) in [0, 1] of the table cell holding (cos_theta, r).

    The axes of :func:`build_q_table` / :func:`build_q2_table`: ln(cos th + cos_eps) with cos th clamped to
    [0, 1], and ln R2 (r <= 0 is treated as r_min), both clamped at the end nodes. Returns (i, tu, j, tr).
    """
    c = min(max(cos_theta, 0.0), 1.0)
    fu = (math.log(c + grid[4]) - grid[0]) / grid[1]
    fu = min(max(fu, 0.0), n_cos - 1.0)
    i = min(int(fu), n_cos - 2)
    tu = fu - i
    fr = (math.log(r) - grid[2]) / grid[3] if r > 0.0 else 0.0
    fr = min(max(fr, 0.0), n_r - 1.0)
    j = min(int(fr), n_r - 2)
    tr = fr - j
    return i, tu, j, tr


@nb.njit(**NJIT_FLAGS)
def q_lookup(table: np.ndarray, grid: np.ndarray, mat: int, band: int, cos_theta: float, r: float):
    """Bilinear interpolation of complex Q from :func:`build_q_table` (same axes as :func:`q2_lookup`).

    Returns (Re Q, Im Q). mat and band must index the table (the caller checks them once per job).
    """
    i, tu, j, tr = _table_cell(grid, table.shape[2], table.shape[3], cos_theta, r)
    return q_at_cell(table, mat, band, i, tu, j, tr)


@njit_inline
def q_at_cell(table: np.ndarray, mat: int, band: int, i: int, tu: float, j: int, tr: float):
    """:func:`q_lookup` in a cell already found by :func:`_table_cell` (the cell depends on neither the
    material nor the band: a caller looking up every band at one (cos th, R) finds it once)."""
    out_re = 0.0
    out_im = 0.0
    for part in range(2):
        a = table[mat, band, i, j, part] + (table[mat, band, i, j + 1, part] - table[mat, band, i, j, part]) * tr
        b = (
            table[mat, band, i + 1, j, part]
            + (table[mat, band, i + 1, j + 1, part] - table[mat, band, i + 1, j, part]) * tr
        )
        if part == 0:
            out_re = a + (b - a) * tu
        else:
            out_im = a + (b - a) * tu
    return out_re, out_im


@nb.njit(**NJIT_FLAGS)
def q2_lookup(table: np.ndarray, grid: np.ndarray, mat: int, band: int, cos_theta: float, r: float) -> float:
    """Bilinear interpolation of |Q|^2 in (ln(cos th + cos_eps), ln R2), clamped at the table ends.

    table, grid : from :func:`build_q2_table`; mat, band : material and band indices (not checked);
    cos_theta : cos of the incidence angle from the normal (clamped to [0, 1]); r : R2 in metres
    (r <= 0 is treated as r_min). Returns |Q|^2 (float64); NaN inputs give NaN.
    """
    i, tu, j, tr = _table_cell(grid, table.shape[2], table.shape[3], cos_theta, r)
    a = table[mat, band, i, j] + (table[mat, band, i, j + 1] - table[mat, band, i, j]) * tr
    b = table[mat, band, i + 1, j] + (table[mat, band, i + 1, j + 1] - table[mat, band, i + 1, j]) * tr
    return a + (b - a) * tu

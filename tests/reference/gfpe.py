"""Independent reference: the Green's function parabolic equation (GFPE), 2D, over impedance ground.

Shares no code with the engine. Gilbert and Di 1993 (JASA 94:2343); Salomons, Computational
Atmospheric Acoustics (2001), ch. 10 and App. H. Time factor exp(-i w t).

Field: p(r, z) = psi(r, z) exp(i k_a r) / sqrt(r) (the far-field axisymmetric form of a point source;
with the starters below a homogeneous free field gives p = exp(i k R) / R, i.e. |p| = 1 at 1 m), k_a =
w / c_ref. One range step dr:

    psi(r + dr, z) = exp(i dr dk(z)) { (1/2pi) int [Psi(k) + R(k) Psi(-k)] P(k) exp(i k z) dk
                                       + 2 i beta Psi(beta) P(beta) exp(-i beta z) },

Psi(k) = int_0^inf psi(z) exp(-i k z) dz, P(k) = exp(i dr (sqrt(k_a^2 - k^2) - k_a)) (Im sqrt >= 0),
R(k) = (k Z - k_a) / (k Z + k_a), beta = k_a / Z (the surface-wave pole; its term is kept when
Im beta < 0, i.e. Im Z > 0, the wave is then bound to the ground), dk(z) = w / c(z) - k_a plus the
absorbing layer i A ((z - z_t) / D)^2 above z_t (thickness D). Rigid ground: R = 1, no surface term.

Discretisation: a staggered vertical grid z_j = (j + 1/2) dz, j = 0..N-1 (the mirror image of the grid is
the grid itself, so the rigid case is an exact even extension), FFTs of length M >= 2N (zero padding holds
the image half). Receivers are read off the spectrum exactly at their heights (no interpolation) and
output ranges by a side step from the last full step (the march itself does not depend on the outputs).

Starters (spectra Psi_0(k) = sqrt(i / k_a) g(k / k_a) at z_s, plus the image C Psi_0(k) at -z_s with the
normal-incidence coefficient C = (Z - 1)/(Z + 1) as in Salomons: the image's tail in z > 0 at r = 0 is
radiated straight up; the angle-dependent R(|k|) there would put the pole's long e^{-i beta z} tail into
the starter and costs 3-6 dB over grass): ``"wide"`` (default) g(s) = sqrt(2 pi) (1 - s^2)^(-1/4),
tapered to 0 between 55 and 75 degrees (the exact far-field point-source amplitude at elevation asin(s)
under p = psi exp(i k_a r)/sqrt(r)); ``"gaussian"`` Salomons' Gaussian starter sqrt(i k_a)
exp(-k_a^2 (z - z_s)^2 / 2) (far-field amplitude exp(-sin^2(th)/2): -0.3 dB at 15 degrees, -1.1 dB at
30 degrees); ``"second_order"`` Salomons' (1.3717 - 0.3701 k_a^2 (z - z_s)^2) exp(-k_a^2 (z - z_s)^2 / 3)
sqrt(i k_a).

Valid range: low elevation angles as seen from the source (< ~30-40 degrees; the phase screen is a
narrow-angle approximation in a refracting medium; in homogeneous air the wide starter is within
0.3 dB up to 50 degrees, the Gaussian one loses 1.9 dB at 30 degrees), ranges r >> wavelength
(the 1/sqrt(r) axisymmetric form: error O(1/(k r))), stratified c(z) (range-independent), flat ground,
levels down to about 80 dB below the free field (deeper refractive shadows reach the floor set by the
absorbing layer's residual reflection: -90 to -115 dB re free field at 500 Hz with the defaults).
Accuracy (tests/reference/test_gfpe.py): homogeneous air, 100-1000 Hz, 50-1000 m, against the image
source, <= 0.01 dB (rigid) and <= 0.11 dB (grass) away from interference dips; halving dr and dz in
the log profiles changes levels by <= 0.2 dB away from dips; reciprocity (source 2 m / receiver 10 m
swapped) holds within 0.33 dB in the log profiles at 100-500 Hz, 100-1000 m; against exact Airy normal
modes (linear k^2, normal_modes.py) <= 0.02 dB over rigid ground for dc/dz <= 0.05 1/s to 1 km, <= 0.09 dB
over grass (surface wave included; 100 and 250 Hz, dc/dz = 0.05 1/s); for a strong
gradient (c +5 % over 100 m, arrivals up to 15 degrees) the narrow-angle phase screen drifts in phase:
single points off by up to 3 dB at 1 km (500 Hz; 0.04 dB to 300 m), energy means still within 0.01 dB.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft
from numpy.typing import ArrayLike

from tests.reference.image_source import delany_bazley

Profile = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class GfpeGrid:
    """Numerical parameters actually used (metres): vertical step, range step, top of the physical
    region (absorbing layer starts there), layer thickness, FFT length, number of grid points."""

    dz: float
    dr: float
    z_top: float
    layer: float
    fft_len: int
    n_z: int
    c_ref: float


def _starter_spectrum(kind: str, s: np.ndarray) -> np.ndarray:
    a = np.abs(s)
    if kind == "gaussian":
        return np.sqrt(2.0 * np.pi) * np.exp(-0.5 * s**2)
    if kind == "second_order":
        return np.sqrt(3.0 * np.pi) * np.exp(-0.75 * s**2) * ((1.3717 - 0.3701 * 1.5) + 0.3701 * 2.25 * s**2)
    if kind == "wide":
        s1, s2 = np.sin(np.radians(55.0)), np.sin(np.radians(75.0))
        taper = np.where(a <= s1, 1.0, np.where(a >= s2, 0.0, np.cos(0.5 * np.pi * (a - s1) / (s2 - s1)) ** 2))
        inside = a < s2
        g = np.zeros_like(s)
        g[inside] = np.sqrt(2.0 * np.pi) * (1.0 - s[inside] ** 2) ** -0.25 * taper[inside]
        return g
    raise ValueError(f"starter must be 'wide', 'gaussian' or 'second_order', got {kind!r}")


def gfpe_pressure(
    profile_c: Profile,
    f_hz: float,
    zs: float,
    ranges_m: ArrayLike,
    zr_m: ArrayLike,
    flow_resistivity: float | None = None,
    *,
    impedance: complex | None = None,
    c_ref: float | None = None,
    dz: float | None = None,
    dr: float | None = None,
    z_top: float | None = None,
    layer: float | None = None,
    layer_strength: float = 1.0,
    starter: str = "wide",
    return_grid: bool = False,
    barrier: tuple[float, float] | None = None,
) -> np.ndarray | tuple[np.ndarray, GfpeGrid]:
    """Complex pressure re 1 m free field, shape (len(ranges_m), len(zr_m)).

    Parameters
    ----------
    profile_c : callable, heights above ground z (m, ndarray) -> effective sound speed c(z) (m/s).
    f_hz : frequency, Hz.
    zs : source height above ground, m (> 0).
    ranges_m : horizontal ranges, m (> 0, any order).
    zr_m : receiver heights, m (>= 0, below ``z_top``).
    flow_resistivity : Delany-Bazley flow resistivity sigma, Pa s/m^2; None (and no ``impedance``) = rigid.
    impedance : normalised ground impedance Z (exp(-i w t), Im Z > 0), overrides ``flow_resistivity``.
    c_ref : reference sound speed of k_a = w / c_ref, m/s (default c(zs)).
    dz, dr : vertical and range steps, m (defaults lambda/10 and 5 lambda, lambda = c_ref / f).
    z_top : height where the absorbing layer begins, m (default max(50, 3 max(zs, zr) + 10 lambda,
        0.3 max(ranges))); the layer is ``layer`` thick (default max(50 lambda, 30 m)).
    layer_strength : A of the layer, 1/m (imaginary wavenumber at its top).
    starter : "wide" (default), "gaussian" or "second_order" (see module docstring).
    return_grid : also return the GfpeGrid actually used.
    barrier : (range r_b, height h_b) m of a thin screen: the field is set to 0 below h_b at r_b (Salomons
        ch. 10: a thin rigid barrier in the GFPE, valid for receivers at low angles behind it; dr is shortened
        to put r_b on a step). Outputs at ranges before r_b ignore it.
    """
    ranges = np.asarray(ranges_m, float).ravel()
    zr = np.asarray(zr_m, float).ravel()
    if zs <= 0 or np.any(ranges <= 0) or np.any(zr < 0):
        raise ValueError("zs and ranges must be > 0, receiver heights >= 0")
    if not f_hz > 0:
        raise ValueError("f_hz must be > 0")
    omega = 2.0 * np.pi * f_hz
    c_ref = float(np.asarray(profile_c(np.array([zs]))).ravel()[0]) if c_ref is None else float(c_ref)
    if not (np.isfinite(c_ref) and c_ref > 0):
        raise ValueError("profile_c must return finite sound speeds > 0 (m/s); c_ref must be > 0")
    ka = omega / c_ref
    lam = c_ref / f_hz
    dz = lam / 10.0 if dz is None else float(dz)
    dr = 5.0 * lam if dr is None else float(dr)
    if barrier is not None:
        if not (barrier[0] > 0 and barrier[1] > 0):
            raise ValueError("barrier range and height must be > 0 (m)")
        dr = barrier[0] / np.ceil(barrier[0] / dr)
    if z_top is None:
        z_top = max(50.0, 3.0 * max(zs, zr.max()) + 10.0 * lam, 0.3 * ranges.max())
    layer = max(50.0 * lam, 30.0) if layer is None else float(layer)
    if zr.max() >= z_top or zs >= z_top:
        raise ValueError("source and receivers must lie below z_top")
    n = int(np.ceil((z_top + layer) / dz))
    m_len = sfft.next_fast_len(2 * n)
    z = (np.arange(n) + 0.5) * dz
    k = 2.0 * np.pi * sfft.fftfreq(m_len, dz)
    half = np.exp(0.5j * k * dz)  # staggered-grid phase
    neg = (-np.arange(m_len)) % m_len

    if impedance is None and flow_resistivity is not None:
        impedance = complex(delany_bazley(f_hz, flow_resistivity))
    if impedance is not None and not np.isinf(impedance) and not complex(impedance).imag > 0:
        raise ValueError("impedance must have Im Z > 0 (exp(-i w t)); use None for rigid ground")
    if impedance is None or np.isinf(impedance):
        refl = np.ones(m_len, complex)
        c_img = 1.0 + 0j
        beta = None
    else:
        zg = complex(impedance)
        refl = (k * zg - ka) / (k * zg + ka)
        c_img = (zg - 1.0) / (zg + 1.0)
        beta = ka / zg
        if beta.imag >= 0.0:
            beta = None  # no bound surface wave

    def kz(kk: np.ndarray | complex) -> np.ndarray | complex:
        q = np.sqrt(ka**2 - np.asarray(kk, complex) ** 2)
        return np.where(q.imag < 0, -q, q)

    kz_k = kz(k)
    kz_b = complex(kz(beta)) if beta is not None else 0.0

    def dk_of(zz: np.ndarray) -> np.ndarray:
        c = np.asarray(profile_c(zz), float)
        if c.shape != zz.shape or not np.all(np.isfinite(c) & (c > 0)):
            raise ValueError("profile_c must return finite sound speeds > 0 (m/s), one per height")
        out = (omega / c - ka).astype(complex)
        above = zz > z_top
        out[above] += 1j * layer_strength * ((zz[above] - z_top) / layer) ** 2
        return out

    dk_grid = dk_of(z)
    dk_rec = dk_of(zr)
    e_beta_grid = np.exp(-1j * beta * z) if beta is not None else None
    e_beta_rec = np.exp(-1j * beta * zr) if beta is not None else None
    chunk = max(1, int(2**22 // m_len))  # receivers per block of the spectral read-out (<= 64 MiB)
    e_rec = np.exp(1j * np.outer(zr, k)) if zr.size <= chunk else None  # (nzr, M), kept when small

    def synth(spec: np.ndarray) -> np.ndarray:
        """(1/M) sum_m spec_m exp(i k_m z_r) at the receiver heights."""
        if e_rec is not None:
            return e_rec @ spec / m_len
        return np.concatenate(
            [np.exp(1j * np.outer(zr[i : i + chunk], k)) @ spec / m_len for i in range(0, zr.size, chunk)]
        )

    def transform(psi: np.ndarray) -> tuple[np.ndarray, complex]:
        """(Psi(k) + R(k) Psi(-k)) exp(i k dz/2) / dz on the FFT grid, and 2 i beta Psi(beta).

        Midpoint sums on the staggered grid plus the Euler-Maclaurin end correction -(dz^2/24) g'(0) of
        each integrand g (psi'(0) = -i beta psi(0) from the boundary condition, psi(0) extrapolated
        linearly): the half-line transforms are then 4th-order in dz (2nd-order without it, which
        accumulates over many steps over impedance ground; exact mirror, no correction, when rigid).
        """
        f = sfft.fft(psi, m_len)
        spec = f + refl * half**2 * f[neg]
        if beta is None:
            return spec, 0.0
        p0 = 1.5 * psi[0] - 0.5 * psi[1]
        d0 = -1j * beta * p0
        c = -(dz**2) / 24.0
        spec = spec + half * c * ((d0 - 1j * k * p0) + refl * (d0 + 1j * k * p0)) / dz
        amp = 2j * beta * (dz * np.sum(psi * e_beta_grid) + c * (d0 - 1j * beta * p0))
        return spec, amp

    def step(psi: np.ndarray) -> np.ndarray:
        spec, amp = transform(psi)
        out = sfft.ifft(spec * prop)[:n]
        if beta is not None:
            out = out + amp * prop_b * e_beta_grid
        return out * screen

    def read(psi: np.ndarray, h: float) -> np.ndarray:
        """Field at the receiver heights a distance h (0 <= h < dr) beyond psi, exact in z."""
        spec, amp = transform(psi)
        out = synth(spec * np.exp(1j * h * (kz_k - ka)) / half)
        if beta is not None:
            out = out + amp * np.exp(1j * h * (kz_b - ka)) * e_beta_rec
        return out * np.exp(1j * h * dk_rec)

    # starter at r = 0
    g = _starter_spectrum(starter, k / ka) * np.sqrt(1j / ka)
    spec0 = g * (np.exp(-1j * k * zs) + c_img * np.exp(1j * k * zs))
    psi = sfft.ifft(spec0 * half)[:n] / dz
    prop = np.exp(1j * dr * (kz_k - ka))
    prop_b = np.exp(1j * dr * (kz_b - ka)) if beta is not None else 0.0
    screen = np.exp(1j * dr * dk_grid)

    order = np.argsort(ranges)
    out = np.empty((ranges.size, zr.size), complex)
    r_now = 0.0
    for idx in order:
        r_out = ranges[idx]
        while r_now + dr <= r_out + 1e-9 * dr:
            psi = step(psi)
            r_now += dr
            if barrier is not None and abs(r_now - barrier[0]) <= 1e-6 * dr:
                psi = np.where(z < barrier[1], 0.0, psi)
        psi_r = read(psi, r_out - r_now)
        out[idx] = psi_r * np.exp(1j * ka * r_out) / np.sqrt(r_out)
    grid = GfpeGrid(dz=dz, dr=dr, z_top=z_top, layer=layer, fft_len=m_len, n_z=n, c_ref=c_ref)
    return (out, grid) if return_grid else out


def gfpe_tl(
    profile_c: Profile,
    f_hz: float,
    zs: float,
    ranges_m: ArrayLike,
    zr_m: ArrayLike,
    flow_resistivity: float | None = None,
    **kwargs: object,
) -> np.ndarray:
    """Transmission loss -20 log10 |p| in dB re 1 m free field, shape (len(ranges_m), len(zr_m)).

    Same arguments as ``gfpe_pressure`` (keyword options: impedance, c_ref, dz, dr, z_top, layer,
    layer_strength, starter). Valid at low elevation angles (< ~30-40 degrees from the source), r >> lambda.
    """
    p = gfpe_pressure(profile_c, f_hz, zs, ranges_m, zr_m, flow_resistivity, **kwargs)
    return -20.0 * np.log10(np.abs(p))


def homogeneous(c0: float = 340.0) -> Profile:
    """c(z) = c0."""
    return lambda z: np.full(np.shape(z), float(c0))


def log_profile(c0: float = 340.0, b: float = 1.0, z_g: float = 1.0) -> Profile:
    """c(z) = c0 + b ln(z / z_g + 1) (the README's ``log`` profile; b > 0 downward refraction)."""
    return lambda z: c0 + b * np.log(np.asarray(z, float) / z_g + 1.0)

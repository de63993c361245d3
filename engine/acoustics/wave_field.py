"""The full wave field of point sources in a range-independent scene: the wavenumber integral everywhere.

The stage of engine/wave_stage.py calls :func:`wave_pressure`: for each source and band, the complex
pressure (re the free field at 1 m, time factor exp(-i w t), the beams' convention) at every point, from the
fast-field wavenumber integral of engine/acoustics/wavenumber.py (``ffp_field``) of the source column's
effective sound-speed profile over the impedance ground. The same integral as the refractive-shadow model
(engine/acoustics/refractive_shadow.py), here read in the lit zone too: it is exact for a stratified medium
over flat ground (no ray theory, so no Airy transition at turning points, no caustic, no penumbra:
docs/physics.md §18).

Geometry: the integral is axisymmetric about the vertical through the source. A point at horizontal range r
and height z above the ground gets the (r, z) answer whatever its azimuth; heights are grouped to
``_HEIGHT_STEP_M`` (one FFT over the wavenumbers per distinct height). With a wind (the kernel form of
``scenes.wind_models.wind_from_spec``, horizontally uniform: the log law) the effective sound speed
c + u . e_r along the point's azimuth is used, per azimuth bin of ``azimuth_bin_deg`` (one integral per bin and
band), as the shadow stage does.

Valid where the asymptotic form of J0 holds: k r >= ``MIN_KR`` (``valid`` is False nearer the source's
vertical; those points keep the beams). Atmospheric absorption: the factor 10^(-alpha R / 20) on the
pressure, alpha the ISO 9613-1 coefficient (dB/m) and R the straight source-point distance.

The integral's top (:func:`wave_top_height`): above every point (2 x the highest + 20 m), at least
``TOP_WAVELENGTHS`` wavelengths (the absorbing layer, half as thick, must be many wavelengths deep to
absorb; 120 m at 100 Hz is converged, 60 m is not), above the vertex of the highest ray that comes back
to the ground within the largest range (downward refraction: 2 x its height + 20 m; 1.25 x left errors of
up to 4 dB at 500 Hz for the log profile), and above the limiting ray at that range (upward refraction, the
shadow model's rule); where neither applies (homogeneous air, no wind) at least STRAIGHT_TOP_FRACTION x the
largest range + 20 m (40 wavelengths alone, 27 m at 500 Hz, left the 1 km level over grass 22 dB too high:
the absorbing layer's residual echo at grazing angles; 60 m 1.2 dB, 150 m 0.01 dB). The result must not
depend on it
(tests/fields/test_wave_field_gfpe.py checks a doubled top).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from bentray.engine.acoustics.absorption import absorption_db_per_m
from bentray.engine.acoustics.creeping import limiting_ray
from bentray.engine.acoustics.refractive_shadow import TOP_MAX_M, column_sound_speed, shadow_top_height
from bentray.engine.acoustics.wavenumber import ffp_cells, ffp_field
from bentray.engine.profiles import Profile

__all__ = [
    "BAND_FRACTIONS",
    "DEFAULT_BAND_POINTS",
    "MIN_KR",
    "TOP_WAVELENGTHS",
    "WaveBands",
    "WaveField",
    "band_nodes",
    "wave_band_energy",
    "wave_cells",
    "wave_pressure",
    "wave_top_height",
]

Wind = tuple[int, np.ndarray]
MIN_KR = 20.0  # points nearer the source's vertical (k r < MIN_KR) are left to the beams
TOP_WAVELENGTHS = 40.0  # the integral's top at least this many wavelengths high
STRAIGHT_TOP_FRACTION = 0.15  # no turning ray and no shadow (homogeneous air): the top at least this x r_max + 20 m
TURN_MARGIN = 2.0  # the top: this x the vertex height of the ray that comes back to the ground at r_max, + 20 m
_HEIGHT_STEP_M = 0.05  # point heights grouped to this step (one FFT per distinct height)
_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)
# Band averages (:func:`band_nodes`): bands per octave of each band width, and the default number of Gauss
# nodes per band (docs/physics.md §18, "Band levels"; chosen by the convergence measured there)
BAND_FRACTIONS = {"octave": 1, "third_octave": 3}
DEFAULT_BAND_POINTS = 7
_G10 = 10.0**0.3  # the base-10 octave ratio of IEC 61260-1


@dataclass(frozen=True)
class WaveField:
    """Per source and band: p (n_src, n_f, n) complex pressure re the free field at 1 m (0 where not
    ``valid``); valid (n_src, n) bool (k r >= MIN_KR at every band's wavenumber and height >= 0); z_top_m:
    the largest top used (m); cells: the integrals' Numerov steps, summed; seconds (n_f,): wall time per band,
    summed over sources and azimuth bins."""

    p: np.ndarray
    valid: np.ndarray
    z_top_m: float
    cells: int
    seconds: np.ndarray


def _hop(c_of_h: Callable[[np.ndarray], np.ndarray], top_h: float) -> float:
    """Horizontal distance from the ground up to the vertex and back of the ray whose vertex is at ``top_h``
    (m), Snell along c(h) (cos theta = c(h) / c(top_h)), h = top_h - u^2 to take the turning point's
    square-root singularity: inf where the ray from the ground does not turn there (c(h) >= c(top_h) below)."""
    ch = float(np.asarray(c_of_h(np.array([top_h])), float)[0])
    u = 0.5 * math.sqrt(top_h) * (_GL_X + 1.0)
    wu = 0.5 * math.sqrt(top_h) * _GL_W
    cos_t = np.asarray(c_of_h(top_h - u * u), float) / ch
    sin2 = 1.0 - cos_t * cos_t
    if np.any(sin2[u > 1e-9 * math.sqrt(top_h)] <= 0.0):
        return math.inf
    return float(2.0 * np.sum(wu * 2.0 * u * cos_t / np.sqrt(np.maximum(sin2, 1e-300))))


def _turning_height(c_of_h: Callable[[np.ndarray], np.ndarray], r_max: float) -> float:
    """The smallest vertex height (m) whose ray hop exceeds r_max (downward refraction), 0 where no ray of
    the profile turns below TOP_MAX_M within r_max (then no returning ray sets a height)."""
    heights = np.geomspace(0.5, TOP_MAX_M, 96)
    last = 0.0
    for h in heights:
        x = _hop(c_of_h, float(h))
        if math.isfinite(x) and x > r_max:
            return float(h)
        if math.isfinite(x):
            last = float(h)
    return last


def wave_top_height(
    c_of_h: Callable[[np.ndarray], np.ndarray], frequency_hz: float, zs: float, r_max: float, zr_max: float
) -> float:
    """The integral's top (m above the ground): the module docstring's rule, at most TOP_MAX_M (or 2 x the
    highest point + 20 m if that is higher)."""
    c0 = float(np.asarray(c_of_h(np.array([0.0])), float)[0])
    lam = c0 / frequency_hz
    top = max(2.0 * max(zr_max, zs) + 20.0, TOP_WAVELENGTHS * lam)
    h_turn = _turning_height(c_of_h, r_max)
    if h_turn > 0.0:
        top = max(top, TURN_MARGIN * h_turn + 20.0)
    upward = limiting_ray(c_of_h, 100.0, 64).upward
    if upward:  # a refractive shadow: above its limiting ray at r_max
        top = max(top, shadow_top_height(c_of_h, zs, r_max, zr_max))
    if h_turn <= 0.0 and not upward:  # no refraction sets it: the layer's residual echo arrives at ~2 top / r
        top = max(top, STRAIGHT_TOP_FRACTION * r_max + 20.0)
    return float(max(min(top, TOP_MAX_M), 2.0 * max(zr_max, zs) + 20.0))


def wave_cells(frequency_hz: float, c_ground: float, zs: float, r_max: float, z_top: float) -> int:
    """The Numerov steps of one integral (engine/acoustics/wavenumber.ffp_cells): the cost measure."""
    return ffp_cells(frequency_hz, c_ground, zs, r_max, z_top)


def band_nodes(
    frequency_hz: float, band: str = "octave", points: int = DEFAULT_BAND_POINTS
) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies (Hz, (points,)) and weights ((points,), summing to 1) of the band average of the band
    centred on ``frequency_hz``: Gauss-Legendre in ln f over [f G^(-1/2b), f G^(1/2b)], G = 10^0.3 (IEC
    61260-1 base-10 ratio), b = 1 ("octave") or 3 ("third_octave"); uniform weight in ln f (a pink spectrum
    inside the band). An odd ``points`` puts a node on f itself (the coherent band's frequency)."""
    if band not in BAND_FRACTIONS:
        raise ValueError(f"band must be one of {sorted(BAND_FRACTIONS)}, got {band!r}")
    if not (int(points) == points and points >= 1) or not frequency_hz > 0:
        raise ValueError("points must be an integer >= 1 and frequency_hz > 0")
    x, w = np.polynomial.legendre.leggauss(int(points))
    half = math.log(_G10) / (2.0 * BAND_FRACTIONS[band])
    return float(frequency_hz) * np.exp(half * x), 0.5 * w


@dataclass(frozen=True)
class WaveBands:
    """Band averages of :func:`wave_band_energy`: energy (n_src, n_b, n): the band mean of |p|^2 (re the free
    field at 1 m, each node with its own ISO 9613-1 absorption; 0 where not ``valid``); p_centre (n_src, n_b, n)
    complex: the field at each band's own frequency, or None where not asked; valid (n_src, n) bool (at the
    lowest node of every band); frequencies_hz (n_b, points) the nodes; z_top_m the largest top (m); cells:
    Numerov steps, summed; seconds (n_b,) wall time per band (all its integrals)."""

    energy: np.ndarray
    p_centre: np.ndarray | None
    valid: np.ndarray
    frequencies_hz: np.ndarray
    z_top_m: float
    cells: int
    seconds: np.ndarray


def wave_band_energy(
    profile: Profile,
    sources_xyz: ArrayLike,
    points_xyz: ArrayLike,
    ground_z: float,
    flow_resistivity_pa_s_m2: float | None,
    bands_hz: ArrayLike,
    wind: Wind | None = None,
    *,
    band: str = "octave",
    points: int = DEFAULT_BAND_POINTS,
    centre: bool = False,
    absorption: tuple[float, float, float] | None = None,
    azimuth_bin_deg: float = 5.0,
) -> WaveBands:
    """Band levels from the wave field: per source and band, sum_i w_i |p(f_i)|^2 over :func:`band_nodes`
    (docs/physics.md §18, "Band levels"), each |p(f_i)|^2 one :func:`wave_pressure` integral (its own top,
    absorption and ground impedance). ``centre``: also return p at each band's frequency (a node when
    ``points`` is odd, else one more integral). Arguments as :func:`wave_pressure`; bands_hz (n_b,) Hz."""
    srcs = np.asarray(sources_xyz, float).reshape(-1, 3)
    pts = np.asarray(points_xyz, float).reshape(-1, 3)
    fb = np.asarray(bands_hz, float).ravel()
    n_s, n_b, n = srcs.shape[0], fb.size, pts.shape[0]
    energy = np.zeros((n_s, n_b, n))
    p_c = np.zeros((n_s, n_b, n), complex) if centre else None
    valid = np.ones((n_s, n), bool)
    nodes = np.zeros((n_b, int(points)))
    seconds = np.zeros(n_b)
    top, cells = 0.0, 0
    for b, f in enumerate(fb):
        nodes[b], w = band_nodes(float(f), band, points)
        todo = list(nodes[b])
        at = int(np.argmin(np.abs(nodes[b] - f)))
        if centre and abs(nodes[b][at] - f) > 1e-9 * f:
            todo.append(float(f))
            at = len(todo) - 1
        for i, fi in enumerate(todo):
            one = wave_pressure(profile, srcs, pts, ground_z, flow_resistivity_pa_s_m2, [fi], wind,
                                absorption=absorption, azimuth_bin_deg=azimuth_bin_deg)  # fmt: skip
            valid &= one.valid
            if i < w.size:
                energy[:, b] += w[i] * np.abs(one.p[:, 0]) ** 2
            if centre and i == at:
                assert p_c is not None
                p_c[:, b] = one.p[:, 0]
            top, cells = max(top, one.z_top_m), cells + one.cells
            seconds[b] += float(one.seconds.sum())
    energy[~np.broadcast_to(valid[:, None, :], energy.shape)] = 0.0
    return WaveBands(energy=energy, p_centre=p_c, valid=valid, frequencies_hz=nodes, z_top_m=top, cells=cells,
                     seconds=seconds)  # fmt: skip


def wave_pressure(
    profile: Profile,
    sources_xyz: ArrayLike,
    points_xyz: ArrayLike,
    ground_z: float,
    flow_resistivity_pa_s_m2: float | None,
    frequencies_hz: ArrayLike,
    wind: Wind | None = None,
    *,
    absorption: tuple[float, float, float] | None = None,
    azimuth_bin_deg: float = 5.0,
    z_top_m: float | None = None,
) -> WaveField:
    """The complex field of each source at each point by the wavenumber integral (module docstring).

    profile: the job's stratified Profile (world frame); sources_xyz (n_src, 3) m; points_xyz (n, 3) m;
    ground_z (m): the flat ground's height; flow_resistivity_pa_s_m2: Delany-Bazley sigma (None: rigid);
    frequencies_hz (n_f,); wind: kernel form (code, params) or None; absorption: (temperature C,
    humidity %, pressure kPa) for ISO 9613-1, None = none; azimuth_bin_deg: with wind, the bin width;
    z_top_m: the top (m above the ground), None = :func:`wave_top_height` per source, bin and band.
    """
    from bentray.engine.acoustics.ground import delany_bazley_impedance

    srcs = np.asarray(sources_xyz, float).reshape(-1, 3)
    pts = np.asarray(points_xyz, float).reshape(-1, 3)
    freqs = np.asarray(frequencies_hz, float).ravel()
    if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(srcs)) and math.isfinite(ground_z)):
        raise ValueError("sources, points and ground height must be finite (m)")
    if freqs.size == 0 or not np.all(np.isfinite(freqs) & (freqs > 0)):
        raise ValueError("frequencies_hz must be finite and > 0")
    n, n_f = pts.shape[0], freqs.size
    p = np.zeros((srcs.shape[0], n_f, n), complex)
    valid = np.zeros((srcs.shape[0], n), bool)
    seconds = np.zeros(n_f)
    top_used, cells = 0.0, 0
    with_wind = wind is not None and int(wind[0]) != 0
    alpha = np.asarray(absorption_db_per_m(freqs, *absorption), float) if absorption is not None else np.zeros(n_f)
    import time

    for s, src in enumerate(srcs):
        zs = float(src[2] - ground_z)
        if not zs >= 0.0:
            raise ValueError(f"source {s} is below the ground (height {zs:g} m)")
        dxy = pts[:, :2] - src[None, :2]
        r = np.hypot(dxy[:, 0], dxy[:, 1])
        zr = pts[:, 2] - ground_z
        c0 = float(column_sound_speed(profile, src, ground_z)(np.array([0.0]))[0])
        k_min = 2.0 * math.pi * float(freqs.min()) / c0
        ok = (zr >= 0.0) & (k_min * r >= MIN_KR)
        valid[s] = ok
        if not ok.any():
            continue
        slant = np.hypot(r, zr - zs)
        az = np.degrees(np.arctan2(dxy[:, 1], dxy[:, 0]))
        bins = np.round(az / azimuth_bin_deg).astype(int) if with_wind else np.zeros(n, int)
        for b in np.unique(bins[ok]):
            sel = np.flatnonzero(ok & (bins == b))
            ang = math.radians(b * azimuth_bin_deg) if with_wind else 0.0
            e = np.array([math.cos(ang), math.sin(ang), 0.0])
            c_of_h = column_sound_speed(profile, src, ground_z, e, wind if with_wind else None)
            heights = np.round(np.maximum(zr[sel], 0.0) / _HEIGHT_STEP_M) * _HEIGHT_STEP_M
            uniq, inv = np.unique(heights, return_inverse=True)
            r_max = float(r[sel].max()) + 10.0
            for k, f in enumerate(freqs):
                t0 = time.perf_counter()
                top = (
                    z_top_m if z_top_m is not None else wave_top_height(c_of_h, float(f), zs, r_max, float(uniq.max()))
                )
                imp = (
                    None
                    if flow_resistivity_pa_s_m2 is None
                    else complex(delany_bazley_impedance(f, flow_resistivity_pa_s_m2))
                )
                fld = ffp_field(float(f), c_of_h, imp, zs, uniq, r_max, top)
                p[s, k, sel] = fld.pressure(r[sel], inv) * 10.0 ** (-alpha[k] * slant[sel] / 20.0)
                top_used, cells = max(top_used, top), cells + fld.cells
                seconds[k] += time.perf_counter() - t0
    return WaveField(p=p, valid=valid, z_top_m=top_used, cells=cells, seconds=seconds)

"""Levels in the shadow of upward refraction: creeping waves plus turbulent scattering, per point.

The function the field stage calls (docs/physics.md, "Refractive shadows"): for a source and a set of
points it returns, per frequency, the energy re the free field at 1 m of

- the creeping-wave field: the field of the source in the job's own stratified effective profile over
  the impedance ground by the wavenumber integral (engine/acoustics/wavenumber.py: exact for the
  medium, no mode truncation; its top is set above the limiting ray's height at the farthest point, so
  the result does not depend on it: docs/physics.md §15; ``ShadowField.method`` "wavenumber_integral"),
  and
- the turbulent scattering into the shadow (engine/acoustics/scattering.py) when the job has a
  ``turbulence`` key, added incoherently,

and ``applies``: whether the point is in the ray-theory shadow of the profile, i.e. beyond the limiting
ray that grazes the ground (range > X(z_s) + X(z_r), X from Snell's law along the source column's
profile at the point's azimuth). Outside ``applies`` every returned energy is 0: the lit zone belongs
to the beam field, and this model adds nothing there.

Frame: the profile is sampled on the vertical through the source (range-independent medium, flat
ground model), heights above the local ground (source above ``source_ground_z``, each point above its
own ``ground_z``), horizontal range from the source. With a wind (the engine's kernel form from
``scenes.wind_models.wind_from_spec``) the effective sound speed c + u . e_r along each point's
azimuth e_r is used, per azimuth bin: upwind directions refract upward and get shadows.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from bentray.engine.acoustics.creeping import limiting_ray
from bentray.engine.acoustics.ground import delany_bazley_impedance
from bentray.engine.acoustics.scattering import scattered_energy
from bentray.engine.acoustics.wavenumber import ffp_field
from bentray.engine.profiles import Profile
from bentray.engine.wind import wind_along

__all__ = ["ShadowField", "column_sound_speed", "refractive_shadow_energy", "upward_refracting"]

Wind = tuple[int, np.ndarray]
TOP_MARGIN = 1.25  # the wavenumber integral's top: this x the limiting ray's height at the farthest point + 20 m
TOP_MAX_M = 2000.0  # ... at most (a limiting ray that turns back sets no height: then 2 x the highest point + 50 m)
_HEIGHT_STEP_M = 0.05  # receiver heights are grouped to this step (one FFT per distinct height)


@dataclass(frozen=True)
class ShadowField:
    """Per-point shadow levels (n points, n_f frequencies).

    energy_rel (n_f, n): |p|^2 re the free field at 1 m, creeping + scattered where ``applies``, else 0;
    creeping (n_f, n), scattered (n_f, n): the two parts (0 outside ``applies``; scattered 0 without
    turbulence); applies (n,) bool: in the ray-theory refractive shadow; boundary_range_m (n,): the
    shadow boundary's horizontal range at the point's height and azimuth (inf where there is none);
    method (n_f,) tuple of "wavenumber_integral" per frequency ("none" where no point is in a shadow);
    z_top_m: the largest top height used (m), cells: the wavenumber integral's Numerov steps, summed.
    """

    energy_rel: np.ndarray
    creeping: np.ndarray
    scattered: np.ndarray
    applies: np.ndarray
    boundary_range_m: np.ndarray
    method: tuple[str, ...]
    z_top_m: float = 0.0
    cells: int = 0


def column_sound_speed(
    profile: Profile,
    source_xyz: ArrayLike,
    source_ground_z: float,
    azimuth_unit: ArrayLike | None = None,
    wind: Wind | None = None,
) -> Callable[[np.ndarray], np.ndarray]:
    """c_eff(h) (m/s) on the vertical through the source, h in metres above ``source_ground_z``:
    ``profile.sound_speed`` plus, with a wind, u . e along the horizontal unit ``azimuth_unit``."""
    sx, sy = float(np.asarray(source_xyz, float)[0]), float(np.asarray(source_xyz, float)[1])
    e = np.array([1.0, 0.0, 0.0]) if azimuth_unit is None else np.asarray(azimuth_unit, float)

    def c_of_h(h: np.ndarray) -> np.ndarray:
        hh = np.asarray(h, float).ravel()
        pts = np.column_stack([np.full(hh.size, sx), np.full(hh.size, sy), source_ground_z + hh])
        c = np.asarray(profile.sound_speed(pts), float)
        if wind is not None and int(wind[0]) != 0:
            c = c + wind_along(int(wind[0]), np.asarray(wind[1], float), pts, e)
        return c

    return c_of_h


def upward_refracting(
    profile: Profile,
    source_xyz: ArrayLike,
    source_ground_z: float,
    azimuths_deg: ArrayLike,
    wind: Wind | None = None,
    h_max: float = 100.0,
) -> np.ndarray:
    """Per azimuth (degrees, counter-clockwise from +x): True when c_eff decreases from the ground up to
    ``h_max`` (m) on the source column, i.e. the ray grazing the ground leaves it and a refractive shadow
    exists in that direction (the stage can be skipped where every entry is False). Shape of azimuths."""
    az = np.asarray(azimuths_deg, float)
    out = np.zeros(az.shape, bool)
    for i, a in np.ndenumerate(az):
        e = np.array([math.cos(math.radians(a)), math.sin(math.radians(a)), 0.0])
        out[i] = limiting_ray(column_sound_speed(profile, source_xyz, source_ground_z, e, wind), h_max, 64).upward
    return out


def _impedance(f: float, flow_resistivity: float | None) -> complex | None:
    return None if flow_resistivity is None else complex(delany_bazley_impedance(f, flow_resistivity))


def shadow_top_height(c_of_h: Callable[[np.ndarray], np.ndarray], zs: float, r_max: float, zr_max: float) -> float:
    """The wavenumber integral's top z_top (m above the ground): TOP_MARGIN x the height H of the limiting
    ray at range r_max (X(H) = r_max - X(z_s): the field at the ground there is fed from that height) + 20 m,
    at least 2 x the highest point + 20 m, at most TOP_MAX_M."""
    tall = limiting_ray(c_of_h, TOP_MAX_M, 1024)
    need = r_max - float(tall.x_of_h(np.array([zs]))[0])
    x = np.where(np.isfinite(tall.x), tall.x, np.inf)
    reach = np.flatnonzero(x >= need)
    height = float(tall.h[reach[0]]) if reach.size else TOP_MAX_M
    return float(min(TOP_MAX_M, max(TOP_MARGIN * height + 20.0, 2.0 * zr_max + 20.0)))


def _creeping_energy(
    c_of_h: Callable[[np.ndarray], np.ndarray],
    f: float,
    zs: float,
    r: np.ndarray,
    zr: np.ndarray,
    flow_resistivity: float | None,
    z_top: float | None,
) -> tuple[np.ndarray, float, int]:
    """|p|^2 of the source's field at (r, zr) by the wavenumber integral, the top used (m) and its cells."""
    heights = np.round(np.maximum(zr, 0.0) / _HEIGHT_STEP_M) * _HEIGHT_STEP_M
    uniq, inv = np.unique(heights, return_inverse=True)
    r_max = float(r.max()) + 10.0
    top = z_top if z_top is not None else shadow_top_height(c_of_h, zs, r_max, float(uniq.max()))
    field = ffp_field(f, c_of_h, _impedance(f, flow_resistivity), zs, uniq, r_max, top)
    return np.abs(field.pressure(r, inv)) ** 2, top, field.cells


def refractive_shadow_energy(
    profile: Profile,
    source_xyz: ArrayLike,
    points_xyz: ArrayLike,
    ground_z: ArrayLike,
    source_ground_z: float,
    flow_resistivity_pa_s_m2: float | None,
    frequencies_hz: ArrayLike,
    turbulence: tuple[float, float] | None = None,
    wind: Wind | None = None,
    *,
    azimuth_bin_deg: float = 5.0,
    z_top_m: float | None = None,
    creeping: bool = True,
) -> ShadowField:
    """Creeping-wave and scattered energy in the refractive shadow (module docstring).

    profile: the job's Profile (world frame); source_xyz (3,) m; points_xyz (n, 3) m; ground_z (n,) m the
    ground height under each point; source_ground_z (m) the ground under the source;
    flow_resistivity_pa_s_m2: Delany-Bazley sigma (Pa s/m^2) of the ground, None = rigid;
    frequencies_hz (n_f,); turbulence: (C_T^2 in K^2 m^-2/3, C_v^2 in m^4/3 s^-2) or None (no
    scattering); wind: the kernel form (code, params) or None; azimuth_bin_deg: with wind, points are
    grouped by azimuth in bins this wide (each bin one profile and one wavenumber integral per band);
    z_top_m: the wavenumber integral's top (m above the ground), None = :func:`shadow_top_height` (a
    converged parameter: the result must not depend on it once it is above the limiting ray's height);
    creeping: False leaves the creeping part 0 (no integral: the wave-field stage already holds it) and
    returns the scattered part and ``applies`` alone. Cost: one wavenumber integral per (bin, frequency),
    proportional to f^2 x range x top height (engine/acoustics/wavenumber.py: 0.3 s at 100 Hz, 13 s at
    500 Hz, 60 s at 1 kHz to 1 km).
    """
    src = np.asarray(source_xyz, float).reshape(3)
    pts = np.asarray(points_xyz, float).reshape(-1, 3)
    gz = np.broadcast_to(np.asarray(ground_z, float), (pts.shape[0],))
    freqs = np.asarray(frequencies_hz, float).ravel()
    if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(gz)) and np.all(np.isfinite(src))):
        raise ValueError("source, points and ground heights must be finite (m)")
    if freqs.size == 0 or not np.all(np.isfinite(freqs) & (freqs > 0)):
        raise ValueError("frequencies_hz must be finite and > 0")
    n, n_f = pts.shape[0], freqs.size
    with_creeping = bool(creeping)
    zs = float(src[2] - source_ground_z)
    if not zs >= 0.0:
        raise ValueError(f"the source is below the ground (height {zs:g} m)")
    dxy = pts[:, :2] - src[None, :2]
    r = np.hypot(dxy[:, 0], dxy[:, 1])
    zr = pts[:, 2] - gz
    creeping_part = np.zeros((n_f, n))
    scattered = np.zeros((n_f, n))
    applies = np.zeros(n, bool)
    boundary = np.full(n, np.inf)
    methods: list[str] = ["none"] * n_f
    top_used, cells = 0.0, 0
    with_wind = wind is not None and int(wind[0]) != 0
    az = np.degrees(np.arctan2(dxy[:, 1], dxy[:, 0]))
    bins = np.round(az / azimuth_bin_deg).astype(int) if with_wind else np.zeros(n, int)
    valid = (r > 0.0) & (zr >= 0.0)
    h_max = float(max(zs, zr[valid].max() if valid.any() else 0.0)) * 1.5 + 10.0
    c_plain = column_sound_speed(profile, src, source_ground_z)(np.array([0.0]))[0]
    first = True
    for b in np.unique(bins[valid]):
        sel = np.flatnonzero(valid & (bins == b))
        ang = math.radians(b * azimuth_bin_deg) if with_wind else 0.0
        e = np.array([math.cos(ang), math.sin(ang), 0.0])
        c_of_h = column_sound_speed(profile, src, source_ground_z, e, wind if with_wind else None)
        ray = limiting_ray(c_of_h, h_max, 512)
        if not ray.upward:
            continue
        xb = ray.x_of_h(np.array([zs]))[0] + ray.x_of_h(zr[sel])
        boundary[sel] = np.where(np.isfinite(xb), xb, np.inf)
        in_shadow = np.isfinite(xb) & (r[sel] > xb)
        idx = sel[in_shadow]
        applies[idx] = True
        if idx.size == 0:
            continue
        for k, f in enumerate(freqs):
            if with_creeping:
                energy, top, n_cells = _creeping_energy(
                    c_of_h, float(f), zs, r[idx], zr[idx], flow_resistivity_pa_s_m2, z_top_m
                )
                creeping_part[k, idx] = energy
                top_used, cells = max(top_used, top), cells + n_cells
            if first and with_creeping:
                methods[k] = "wavenumber_integral"
            if turbulence is not None:
                slant = np.hypot(r[idx], zr[idx] - zs)
                scattered[k, idx] = scattered_energy(float(f), slant, turbulence[0], turbulence[1], c_plain)
        first = False
    return ShadowField(
        energy_rel=creeping_part + scattered,
        creeping=creeping_part,
        scattered=scattered,
        applies=applies,
        boundary_range_m=boundary,
        method=tuple(methods),
        z_top_m=top_used,
        cells=cells,
    )

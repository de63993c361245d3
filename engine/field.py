"""The field stage: from a job's ``field`` spec to kernel accumulators, and from accumulators to arrays.

Conventions (also written into field.vti's field data):
- Each ray carries the power of its launch solid angle: ``W * Omega_i / (4 pi)``; Omega_i is the cell
  of the (elevation, azimuth) launch grid around the ray (half a step each side, clipped at +-90 deg).
- Incoherent: energy E (J) per voxel, intensity ``I = E c / V`` (c the local sound speed at the grid
  point, V the voxel volume), ``tl = -10 log10(I / I_1m)`` with ``I_1m = W / (4 pi)`` the free-field
  intensity at 1 m, ``spl = 10 log10(I / 1e-12 W/m^2)`` (dB re 20 uPa in air, the intensity level).
- Coherent: arrivals grouped by reflection count. Per group the amplitude follows from the ray
  density (the energy flux that neighbouring rays of the fan carry through the voxel, i.e. ray-tube
  spreading averaged over the voxel), the phase from the exact travel time of the ray passing nearest
  to the grid point (carried to the point along its tangent), times the product of spherical-wave
  reflection coefficients Q of that ray's reflections and the absorption amplitude:
  ``p = sum_g sqrt(I_g / I_1m) exp(-a s_g / 2) prod Q exp(i w t_g)``, normalised so that |p| = 1 at
  1 m in free field; time factor exp(-i w t). Two arrivals with the same reflection count in one voxel
  (a caustic) are merged: the amplitude keeps their energy, the phase is the nearer ray's.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np

from bentray.engine.acoustics.absorption import absorption_db_per_m
from bentray.engine.acoustics.ground import build_q2_table, delany_bazley_impedance, spherical_wave_coefficient
from bentray.engine.acoustics.weighting import a_weighting_db
from bentray.engine.constants import BOUNDARY_REFLECT
from bentray.engine.field_buffers import MAX_COHERENT_GROUPS, FieldBuffers, FieldGrid, FieldReduced
from bentray.engine.mesh.cells import CellMesh
from bentray.engine.result import TraceResult
from bentray.scenes.field_models import FieldSpec

P_REF_INTENSITY = 1e-12  # W/m^2, reference intensity of SPL
W_REF = 1e-12  # W, reference sound power
GROUND_MATERIAL = 1  # material index of a soft flat ground (0 is rigid)
# Fewer ray passes than this through a voxel: its level carries a sampling error of a dB or more
# (the image-source tests reach 0.25 dB with >= 300 passes); the report counts such points.
UNDER_SAMPLED_HITS = 10


def fan_spacing_advice(
    spec: FieldSpec, sources: np.ndarray, elevation_deg: np.ndarray, azimuth_deg: np.ndarray
) -> dict[str, float]:
    """Distance between neighbouring rays at the grid point farthest from any source, against the grid
    spacing: rays farther apart than a voxel leave voxels empty (speckled maps)."""
    lo = np.asarray(spec.origin, float)
    hi = spec.upper_corner
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    r = float(np.max(np.linalg.norm(corners[:, None, :] - np.asarray(sources, float)[None], axis=2)))
    steps = [np.radians(np.diff(a).max()) for a in (elevation_deg, azimuth_deg) if len(a) > 1]
    step = max(steps) if steps else 0.0
    return {
        "farthest_point_m": r,
        "ray_spacing_there_m": r * step,
        "smallest_grid_spacing_m": float(np.min(spec.spacing)),
    }


@dataclass
class FieldArrays:
    """What the field stage produced: point arrays (C order, shape (nx, ny, nz)) and report stats."""

    grid: FieldGrid
    arrays: dict[str, np.ndarray]
    field_data: dict[str, Any]
    stats: dict[str, Any]
    preview: dict[str, Any] = dataclasses.field(default_factory=dict)  # source_xyz, receiver_z, title

    def preview_array(self) -> tuple[str, str]:
        """(array name, colour-bar label) shown in preview.png: A-weighted SPL, else TL at ~1 kHz."""
        if "l_den" in self.arrays:  # a job with conditions (engine/conditions.py)
            return "l_den", "Lden (dB(A))"
        if "spl_a" in self.arrays:
            return "spl_a", "SPL (dB(A))"
        tl = [k for k in self.arrays if k.startswith("tl_")]
        freqs = np.array([float(k[3:-2]) for k in tl])
        name = tl[int(np.argmin(np.abs(np.log(freqs / 1000.0))))]
        return name, f"TL at {name[3:-2]} Hz (dB re 1 m)"


def launch_solid_angles(elevation_deg: np.ndarray, azimuth_deg: np.ndarray) -> np.ndarray:
    """Omega / (4 pi) per ray of the launch grid, ordered elevation-major like stages.launch_fan.

    elevation_deg (n_el,), azimuth_deg (n_az,), evenly spaced, each with at least 2 values.
    """
    el = np.radians(np.asarray(elevation_deg, float))
    az = np.radians(np.asarray(azimuth_deg, float))
    d_el = el[1] - el[0]
    lo = np.clip(el - 0.5 * d_el, -0.5 * np.pi, 0.5 * np.pi)
    hi = np.clip(el + 0.5 * d_el, -0.5 * np.pi, 0.5 * np.pi)
    band = np.sin(hi) - np.sin(lo)
    d_az = min(az[1] - az[0], 2.0 * np.pi / len(az))
    return (band[:, None] * np.full(len(az), d_az)[None, :]).reshape(-1) / (4.0 * np.pi)


def tag_ground_material(mesh: CellMesh, ground_z: float, material: int) -> CellMesh:
    """A copy of ``mesh`` whose reflecting faces on the plane z = ground_z carry ``material``."""
    normal_down = mesh.planes[:, :, 2] < -1.0 + 1e-12
    on_plane = np.abs(mesh.planes[:, :, 3] + ground_z) <= 1e-9 * max(1.0, abs(ground_z))
    ground = (mesh.neighbours == BOUNDARY_REFLECT) & normal_down & on_plane
    face_material = mesh.face_material.copy()
    face_material[ground] = material
    return mesh._replace(face_material=face_material)


def energy_absorption(spec: FieldSpec) -> np.ndarray:
    """Energy absorption coefficient per band (1/m): alpha_dB * ln(10) / 10 (0 if absorption is off)."""
    if not spec.absorption:
        return np.zeros(len(spec.frequencies_hz))
    a_db = absorption_db_per_m(
        np.asarray(spec.frequencies_hz, float), spec.temperature_c, spec.humidity_percent, spec.pressure_kpa
    )
    return np.asarray(a_db, float) * math.log(10.0) / 10.0


def prepare(
    spec: FieldSpec,
    *,
    ray_weights: np.ndarray,
    source_index: np.ndarray,
    source_powers_w: np.ndarray | None,
    materials: list[float | None],
    max_reflections: int,
    ground_sound_speed: float,
    n_slots: int | None = None,
) -> FieldBuffers:
    """Allocate the accumulators for a job.

    ray_weights : (n,) Omega/(4 pi) per ray; source_index : (n,) int; source_powers_w : (n_src, n_f) W
    or None. materials : flow resistivity (Pa s/m^2) per face material index, None = rigid (index 0).
    ground_sound_speed (m/s) sets k in the ground table. With several powered sources a
    second set of bands accumulates the powered energy (SPL);
    the first set always holds unit-power energy (TL).
    """
    grid = FieldGrid(
        np.asarray(spec.origin, float),
        np.asarray(spec.spacing, float),
        (int(spec.shape[0]), int(spec.shape[1]), int(spec.shape[2])),
    )
    n_f = len(spec.frequencies_hz)
    alpha = energy_absorption(spec)
    q2 = build_q2_table(np.asarray(spec.frequencies_hz, float), materials, c=ground_sound_speed)
    q2tab, q2ax = q2.table, q2.grid
    n_slots = int(numba.get_num_threads() if n_slots is None else n_slots)  # 0: a template, no accumulators
    h = spec.sample_fraction * float(np.min(spec.spacing))
    if spec.mode == "coherent":
        groups = min(int(max_reflections), MAX_COHERENT_GROUPS - 1) + 1
        return FieldBuffers(
            "coherent",
            grid,
            ray_weights[:, None],
            alpha[:1],
            np.zeros(1, np.int64),
            q2tab,
            q2ax,
            h,
            n_slots,
            n_groups=groups,
        )
    weights = np.repeat(ray_weights[:, None], n_f, axis=1)
    band_of = np.arange(n_f)
    alphas = alpha
    if source_powers_w is not None and source_powers_w.shape[0] > 1:
        weights = np.hstack([weights, ray_weights[:, None] * source_powers_w[source_index]])
        band_of = np.concatenate([band_of, band_of])
        alphas = np.concatenate([alpha, alpha])
    return FieldBuffers("incoherent", grid, weights, alphas, band_of, q2tab, q2ax, h, n_slots)


def _level(x: np.ndarray) -> np.ndarray:
    """10 log10(x) with NaN where x <= 0 (no energy reached the voxel)."""
    out = np.full(x.shape, np.nan)
    pos = x > 0
    out[pos] = 10.0 * np.log10(x[pos])
    return out


def finalize(
    spec: FieldSpec,
    buffers: FieldBuffers,
    sound_speed: np.ndarray,
    trace: TraceResult,
    source_powers_w: np.ndarray | None,
    materials: list[float | None],
) -> FieldArrays:
    """Turn accumulators into named point arrays (tl_*, spl_*, spl_a, p_re_*/p_im_*, ray_hits)."""
    grid = buffers.grid
    reduced = buffers.reduce()
    shape = grid.shape
    n_f = len(spec.frequencies_hz)
    labels = spec.labels
    to_i = sound_speed / grid.voxel_volume  # E (J) -> I (W/m^2)
    arrays: dict[str, np.ndarray] = {}
    if spec.mode == "incoherent":
        assert reduced.energy is not None
        unit_i = reduced.energy[:n_f] * to_i  # intensity per watt of source power
        rel = unit_i * 4.0 * np.pi  # I / I_1m
        for f, lab in enumerate(labels):
            arrays[f"tl_{lab}hz"] = -_level(rel[f])
        spl = None
        if source_powers_w is not None:
            if source_powers_w.shape[0] > 1:
                powered_i = reduced.energy[n_f:] * to_i
            else:
                powered_i = unit_i * source_powers_w[0][:, None]
            spl = _level(powered_i / P_REF_INTENSITY)
    else:
        p = coherent_pressure(spec, reduced, sound_speed, trace, materials)
        spl = None
        for f, lab in enumerate(labels):
            arrays[f"tl_{lab}hz"] = -_level(np.abs(p[f]) ** 2)
            arrays[f"p_re_{lab}hz"] = p[f].real
            arrays[f"p_im_{lab}hz"] = p[f].imag
        if source_powers_w is not None:
            spl = _level((np.abs(p) ** 2) / (4.0 * np.pi) * source_powers_w[0][:, None] / P_REF_INTENSITY)
    if spl is not None:
        for f, lab in enumerate(labels):
            arrays[f"spl_{lab}hz"] = spl[f]
        a_w = np.asarray(a_weighting_db(np.asarray(spec.frequencies_hz, float)), float)
        lin = np.where(np.isfinite(spl), 10.0 ** ((spl + a_w[:, None]) / 10.0), 0.0)
        arrays["spl_a"] = _level(lin.sum(axis=0))
    arrays["ray_hits"] = reduced.hits
    arrays = {k: np.asarray(v, float).reshape(shape) for k, v in arrays.items()}
    hits = reduced.hits
    stats = {
        "mode": spec.mode,
        "points": grid.n_points,
        "shape": list(shape),
        "frequencies_hz": list(spec.frequencies_hz),
        "sample_length_m": float(buffers.fgeo[6]),
        "accumulator_bytes": int(buffers.nbytes),
        "accumulator_slots": buffers.n_slots,
        "points_without_rays": int(np.count_nonzero(hits == 0)),
        "points_under_sampled": int(np.count_nonzero((hits > 0) & (hits < UNDER_SAMPLED_HITS))),
        "under_sampled_below_hits": UNDER_SAMPLED_HITS,
        "ray_hits_median": float(np.median(hits)),
        "ray_hits_min_nonzero": float(hits[hits > 0].min()) if np.any(hits > 0) else 0.0,
    }
    field_data = {
        "units": "tl_*: dB re free field at 1 m; spl_*: dB re 1e-12 W/m^2 (intensity level); "
        "spl_a: A-weighted total (IEC 61672-1); p_re/p_im: pressure relative to the 1 m free-field "
        "amplitude, time factor exp(-i w t); ray_hits: ray passes per voxel",
        "grid": "point (i,j,k) at origin + (i,j,k)*spacing, metres, world frame; voxel of size spacing "
        "centred on each point; NaN: no ray reached the voxel",
        "mode": spec.mode,
        "frequencies_hz": [float(f) for f in spec.frequencies_hz],
        "absorption": f"ISO 9613-1 at {spec.temperature_c:g} C, {spec.humidity_percent:g} %RH, "
        f"{spec.pressure_kpa:g} kPa"
        if spec.absorption
        else "none",
    }
    return FieldArrays(grid=grid, arrays=arrays, field_data=field_data, stats=stats)


def coherent_pressure(
    spec: FieldSpec, reduced: FieldReduced, sound_speed: np.ndarray, trace: TraceResult, materials: list[float | None]
) -> np.ndarray:
    """(n_f, n_vox) complex pressure relative to the 1 m free-field amplitude (see module docstring).

    sound_speed : (n_vox,) m/s at the grid points (intensity I = E c / V; wavenumber of Q's ground wave).
    """
    assert reduced.group_energy is not None and reduced.ray is not None
    assert reduced.time_s is not None and reduced.length_m is not None
    freqs = np.asarray(spec.frequencies_hz, float)
    alpha = energy_absorption(spec)
    n_vox = reduced.hits.shape[0]
    p = np.zeros((len(freqs), n_vox), dtype=complex)
    to_i = sound_speed / float(np.prod(spec.spacing))
    for g in range(reduced.group_energy.shape[0]):
        ok = (reduced.ray[g] >= 0) & (reduced.group_energy[g] > 0)
        if not np.any(ok):
            continue
        vox = np.nonzero(ok)[0]
        amp = np.sqrt(reduced.group_energy[g, vox] * to_i[vox] * 4.0 * np.pi)
        s = reduced.length_m[g, vox]
        t = reduced.time_s[g, vox]
        rays = reduced.ray[g, vox]
        c_vox = sound_speed[vox]
        for f, freq in enumerate(freqs):
            term = amp * np.exp(-0.5 * alpha[f] * s) * np.exp(1j * 2.0 * np.pi * freq * t)
            if g > 0 and trace.reflection_cos is not None and trace.reflection_material is not None:
                k = 2.0 * np.pi * freq / c_vox  # wavenumber at the receiver for the ground-wave term
                for j in range(min(g, trace.reflection_cos.shape[1])):
                    cos_j = trace.reflection_cos[rays, j]
                    mat_j = trace.reflection_material[rays, j]
                    for mat, sigma in enumerate(materials):
                        hit = mat_j == mat
                        if sigma is None or not np.any(hit):
                            continue
                        z = delany_bazley_impedance(freq, sigma)
                        term[hit] = term[hit] * spherical_wave_coefficient(z, cos_j[hit], k[hit], s[hit])
            p[f, vox] += term
    return p

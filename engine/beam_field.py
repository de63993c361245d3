"""The beam-field stage: from a job's ``field`` spec to beam accumulators, and from them to level arrays.

Method (docs/physics.md §10-11): every ray carries its paraxial derivatives; the traversal cuts it
into chords and sums a geometric (hat) beam per chord onto the field points (engine/kernels/beams.py).
Per arrival group (reflection count x caustic count) the accumulators hold the weighted sums and the
sum of hat weights; :meth:`BeamBuffers.collapse` divides one source's sums by
``max(sum of weights, W_FLOOR)`` and combines the groups:

- ``coherent``: ``p = sum_g S_g / W_g`` (complex, relative to the 1 m free-field amplitude, time
  factor exp(-i w t)); TL = -20 log10 |p|;
- ``incoherent``: ``I / I_1m = sum_g E_g / W_g`` (arrival energies; the noise-map default);
- ``semicoherent``: coherent within the direct + first-reflection groups (the source's image pair),
  energies of the others added: ``|p_0 + p_1|^2 + sum_{g >= 2} |p_g|^2``.

A source's fan is one batch (the normalisation needs all of its rays); sources add incoherently for
SPL (each with its power per band) and coherently (unit amplitude) for TL and p in coherent mode.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba
import numpy as np

from bentray.engine.acoustics.ground import build_q_table
from bentray.engine.acoustics.weighting import a_weighting_db
from bentray.engine.field_buffers import FieldGrid
from bentray.engine.kernels.beams import (
    BEAM_COHERENT,
    BEAM_INCOHERENT,
    BEAM_MODES,
    BEAM_OFF,
    N_KMAH,
    W_FLOOR,
    BeamAcc,
    BeamGrid,
    BeamTables,
)

if TYPE_CHECKING:
    from bentray.engine.field import FieldArrays
    from bentray.scenes.field_models import FieldSpec

P_REF_INTENSITY = 1e-12  # W/m^2, reference intensity of SPL

# Reflection-count groups kept apart (0, 1, 2, >= 3 reflections). Memory per slot:
# groups x N_KMAH x bands x points x 8 bytes (x 2 for complex sums).
MAX_REFLECTION_GROUPS = 4


@dataclass
class BeamCollapsed:
    """One batch's (one source's) normalised field: p (F, V) complex (coherent part, or None),
    energy (F, V) incoherent part relative to I_1m (or None), weight (V,) the largest group weight sum
    and hits (V,) beam contributions per point; powers (F,) W of the source per band (or None)."""

    p: np.ndarray | None
    energy: np.ndarray | None
    weight: np.ndarray
    hits: np.ndarray
    powered: np.ndarray | None  # (F, V) W/m^2 per band with the source's power (None: no power given)


class BeamBuffers:
    """Beam accumulators of a job or of one ray batch, with the FieldBuffers interface the batch
    machinery uses (``like``, ``collapse``, ``add``, ``nbytes``, ``n_slots``, ``weights``, ``grid``).

    weights : (n_rays, F) the source power per band of each ray (W; zeros when no power was given,
    then only TL is written). The kernel tuple is (BeamGrid, BeamAcc, BeamTables).
    """

    def __init__(
        self, mode: str, grid: FieldGrid, bgrid: BeamGrid, tables: BeamTables, weights: np.ndarray, n_slots: int
    ) -> None:
        if mode not in BEAM_MODES:
            raise ValueError(f"unknown beam field mode {mode!r}")
        self.mode = mode
        self.grid = grid
        self.bgrid = bgrid
        self.tables = tables
        self.weights = np.ascontiguousarray(weights, dtype=np.float64)
        self.n_slots = int(n_slots)
        self.collapsed: BeamCollapsed | None = None
        n_v = grid.n_points
        n_f = bgrid.omega.shape[0]
        n_g = bgrid.n_refl * N_KMAH
        s = self.n_slots
        coh = bgrid.mode != BEAM_INCOHERENT
        inc = bgrid.mode != BEAM_COHERENT
        self.acc = BeamAcc(
            np.zeros((s, n_g, n_f, n_v) if coh else (0, 0, 0, 0)),
            np.zeros((s, n_g, n_f, n_v) if coh else (0, 0, 0, 0)),
            np.zeros((s, n_g, n_f, n_v) if inc else (0, 0, 0, 0)),
            np.zeros((s, n_g, n_v)),
            np.zeros((s, n_v)),
        )

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self.acc))

    def kernel_args(self) -> tuple[BeamGrid, BeamAcc, BeamTables]:
        return self.bgrid, self.acc, self.tables

    def like(self, weights: np.ndarray, n_slots: int | None = None) -> BeamBuffers:
        """Fresh accumulators for another batch (slots: n_slots, else this one's, else the thread count)."""
        return BeamBuffers(
            self.mode, self.grid, self.bgrid, self.tables, weights, n_slots or self.n_slots or numba.get_num_threads()
        )

    def collapse(self, ray_offset: int = 0) -> BeamBuffers:
        """Sum the slots in order, normalise each group and combine the groups (see the module docstring)."""
        del ray_offset  # beams keep no ray ids
        acc = self.acc
        weight = acc.weight.sum(axis=0)  # (G, V)
        norm = 1.0 / np.maximum(weight, W_FLOOR)
        n_refl = self.bgrid.n_refl
        p = None
        energy = None
        if self.bgrid.mode != BEAM_INCOHERENT:
            s = (acc.s_re.sum(axis=0) + 1j * acc.s_im.sum(axis=0)) * norm[:, None, :]  # (G, F, V)
            if self.bgrid.mode == BEAM_COHERENT:
                p = s.sum(axis=0)
            else:  # semicoherent: groups of 0 and 1 reflections coherently, the others as energies
                pair = min(2, n_refl) * N_KMAH
                p = s[:pair].sum(axis=0)
                e_rest = (acc.energy.sum(axis=0)[pair:] * norm[pair:, None, :]).sum(axis=0)
                energy = e_rest
        else:
            energy = (acc.energy.sum(axis=0) * norm[:, None, :]).sum(axis=0)
        rel = np.zeros((self.bgrid.omega.shape[0], self.grid.n_points))
        if p is not None:
            rel += np.abs(p) ** 2
        if energy is not None:
            rel += energy
        power = self.weights[0] if self.weights.shape[0] else np.zeros(rel.shape[0])
        powered = rel * (power[:, None] / (4.0 * math.pi)) if np.any(power > 0) else None
        self.collapsed = BeamCollapsed(
            p=p, energy=energy, weight=weight.max(axis=0), hits=acc.hits.sum(axis=0), powered=powered
        )
        self.acc = BeamAcc(*(np.zeros((0,) * a.ndim) for a in acc))
        self.n_slots = 1
        self.weights = np.zeros((0, self.weights.shape[1]))
        return self

    def add(self, other: BeamBuffers) -> None:
        """Add another collapsed batch (another source): pressures and energies sum."""
        a, b = self.collapsed, other.collapsed
        if a is None or b is None:
            raise ValueError("add() combines collapsed batches (call collapse() first)")
        if a.p is not None and b.p is not None:
            a.p = a.p + b.p
        if a.energy is not None and b.energy is not None:
            a.energy = a.energy + b.energy
        a.weight = np.maximum(a.weight, b.weight)
        a.hits = a.hits + b.hits
        if b.powered is not None:
            a.powered = b.powered if a.powered is None else a.powered + b.powered


def beam_grid(
    grid: FieldGrid,
    mode: str,
    frequencies_hz: np.ndarray,
    c_ref: float,
    dgamma: tuple[float, float],
    w_min: float,
    max_reflections: int,
    z_offset: np.ndarray | None = None,
) -> BeamGrid:
    """The kernel's BeamGrid (see engine/kernels/beams.py for the meaning of each entry)."""
    nx, ny, _ = grid.shape
    return BeamGrid(
        np.asarray(grid.origin, float),
        np.asarray(grid.spacing, float),
        np.asarray(grid.shape, np.int64),
        np.zeros((nx, ny)) if z_offset is None else np.ascontiguousarray(z_offset, float).reshape(nx, ny),
        2.0 * math.pi * np.asarray(frequencies_hz, float),
        float(c_ref),
        np.asarray(dgamma, float),
        float(w_min),
        int(min(max(max_reflections, 0), MAX_REFLECTION_GROUPS - 1) + 1),
        BEAM_MODES[mode],
    )


def beam_tables(
    frequencies_hz: np.ndarray, materials: list[float | None], alpha: np.ndarray, chord_m: float, sound_speed: float
) -> BeamTables:
    """Complex ground table per (material, band), absorption per band (1/m) and the chord length (m)."""
    q = build_q_table(np.asarray(frequencies_hz, float), materials, c=sound_speed)
    return BeamTables(q.table, q.grid, np.asarray(alpha, float), float(chord_m))


def launch_steps(elevation_deg: np.ndarray, azimuth_deg: np.ndarray) -> tuple[float, float]:
    """Launch-grid steps (rad) for the hat beams: a one-value axis spans a full turn (2 pi), so a single
    azimuth fan is a vertical fan whose beams extend sideways with the tube's own width."""
    el = np.radians(np.asarray(elevation_deg, float))
    az = np.radians(np.asarray(azimuth_deg, float))
    d_el = float(el[1] - el[0]) if el.size > 1 else math.pi
    d_az = float(az[1] - az[0]) if az.size > 1 else 2.0 * math.pi
    return d_el, d_az


def no_beam_args(n_f: int = 1) -> tuple[BeamGrid, BeamAcc, BeamTables]:
    """Kernel arguments of the same types with beams off (tiny arrays, mode BEAM_OFF)."""
    g = BeamGrid(
        np.zeros(3),
        np.ones(3),
        np.ones(3, np.int64),
        np.zeros((1, 1)),
        np.zeros(n_f),
        1.0,
        np.ones(2),
        1.0,
        1,
        BEAM_OFF,
    )
    z4 = np.zeros((0, 0, 0, 0))
    acc = BeamAcc(z4, z4, z4, np.zeros((0, 0, 0)), np.zeros((0, 0)))
    t = BeamTables(np.zeros((1, n_f, 2, 2, 2)), np.zeros(5), np.zeros(n_f), 1.0)
    return g, acc, t


def default_chord_m(spacing: np.ndarray) -> float:
    """Chord length (m): twice the smallest grid spacing, within [1, 10] m (straight chords of a
    curved ray deviate by kappa l^2 / 8: 0.4 mm for 10 m at a 30 km radius of curvature)."""
    return float(min(max(2.0 * float(np.min(spacing)), 1.0), 10.0))


def default_min_width_m(frequencies_hz: np.ndarray, c: float) -> float:
    """Smallest beam half-width (m): half a wavelength at the bands' geometric-mean frequency."""
    f = np.asarray(frequencies_hz, float)
    return float(0.5 * c / math.exp(float(np.mean(np.log(f)))))


def prepare(
    spec: FieldSpec,
    *,
    elevation_deg: np.ndarray,
    azimuth_deg: np.ndarray,
    n_rays: int,
    source_index: np.ndarray,
    source_powers_w: np.ndarray | None,
    materials: list[float | None],
    max_reflections: int,
    c_ref: float,
    ground_sound_speed: float,
    n_face_materials: int,
    ground_z: np.ndarray | None = None,
) -> BeamBuffers:
    """The beam accumulator template of a job (no slots: each batch allocates its own).

    elevation_deg, azimuth_deg : the launch grid's axes (degrees); source_index : (n_rays,) int;
    source_powers_w : (n_src, F) W or None; materials : flow resistivity per face material (None rigid);
    n_face_materials : 1 + the largest material index the mesh's faces carry (checked against the table:
    a mismatch would read past it). ground_z : (nx, ny) ground height (m) under each grid column for
    ``heights = "above_ground"`` (None: absolute heights).
    """
    if n_face_materials > len(materials):
        raise ValueError(
            f"the mesh's faces use {n_face_materials} materials but the ground table has {len(materials)}"
        )
    grid = FieldGrid(np.asarray(spec.origin, float), np.asarray(spec.spacing, float), tuple(spec.shape))
    freqs = np.asarray(spec.frequencies_hz, float)
    w_min = spec.beam_min_width_m if spec.beam_min_width_m is not None else default_min_width_m(freqs, c_ref)
    chord = spec.chord_m if spec.chord_m is not None else default_chord_m(grid.spacing)
    bgrid = beam_grid(
        grid, spec.mode, freqs, c_ref, launch_steps(elevation_deg, azimuth_deg), w_min, max_reflections, ground_z
    )
    from bentray.engine.field import energy_absorption  # the field stage's ISO 9613-1 per band

    tables = beam_tables(freqs, materials, energy_absorption(spec), chord, ground_sound_speed)
    if source_powers_w is not None:
        weights = np.ascontiguousarray(source_powers_w[np.asarray(source_index)], float)
    else:
        weights = np.zeros((n_rays, freqs.size))
    return BeamBuffers(spec.mode, grid, bgrid, tables, weights, 0)


def _level(x: np.ndarray) -> np.ndarray:
    out = np.full(x.shape, np.nan)
    pos = x > 0
    out[pos] = 10.0 * np.log10(x[pos])
    return out


def finalize(spec: FieldSpec, buffers: BeamBuffers) -> FieldArrays:
    """Named point arrays (tl_*, p_re_*/p_im_*, spl_*, spl_a, beam_weight, beam_hits) and report stats."""
    from bentray.engine.field import FieldArrays

    col = buffers.collapsed
    if col is None:
        raise ValueError("finalize() needs the collapsed field of all batches")
    grid = buffers.grid
    labels = spec.labels
    rel = np.zeros((len(labels), grid.n_points))
    arrays: dict[str, np.ndarray] = {}
    if col.p is not None:
        rel += np.abs(col.p) ** 2
    if col.energy is not None:
        rel += col.energy
    for f, lab in enumerate(labels):
        arrays[f"tl_{lab}hz"] = -_level(rel[f])
        if col.p is not None:
            arrays[f"p_re_{lab}hz"] = col.p[f].real
            arrays[f"p_im_{lab}hz"] = col.p[f].imag
    if col.powered is not None:
        spl = _level(col.powered / P_REF_INTENSITY)
        for f, lab in enumerate(labels):
            arrays[f"spl_{lab}hz"] = spl[f]
        a_w = np.asarray(a_weighting_db(np.asarray(spec.frequencies_hz, float)), float)
        lin = np.where(np.isfinite(spl), 10.0 ** ((spl + a_w[:, None]) / 10.0), 0.0)
        arrays["spl_a"] = _level(lin.sum(axis=0))
    arrays["beam_weight"] = col.weight
    arrays["beam_hits"] = col.hits
    arrays = {k: np.asarray(v, float).reshape(grid.shape) for k, v in arrays.items()}
    reached = col.hits > 0
    stats = {
        "method": "beams",
        "mode": spec.mode,
        "points": grid.n_points,
        "shape": list(grid.shape),
        "frequencies_hz": list(spec.frequencies_hz),
        "chord_m": float(buffers.tables.chord_m),
        "beam_min_width_m": float(buffers.bgrid.w_min),
        "launch_steps_rad": [float(v) for v in buffers.bgrid.dgamma],
        "points_without_beams": int(np.count_nonzero(~reached)),
        "points_partially_covered": int(np.count_nonzero(reached & (col.weight < W_FLOOR))),
        "reflection_groups": int(buffers.bgrid.n_refl),
    }
    field_data = {
        "units": "tl_*: dB re free field at 1 m; spl_*: dB re 1e-12 W/m^2 (intensity level); spl_a: A-weighted "
        "total (IEC 61672-1); p_re/p_im: pressure relative to the 1 m free-field amplitude, time factor "
        "exp(-i w t); beam_weight: largest per-group sum of hat weights (>= 0.5: fully covered); beam_hits: "
        "beam contributions per point",
        "grid": "point (i,j,k) at origin + (i,j,k)*spacing, metres, world frame; NaN: no beam reached the point",
        "method": "geometric (hat) beams around paraxial rays, normalised per arrival group",
        "mode": spec.mode,
        "frequencies_hz": [float(f) for f in spec.frequencies_hz],
        "absorption": f"ISO 9613-1 at {spec.temperature_c:g} C, {spec.humidity_percent:g} %RH, {spec.pressure_kpa:g} kPa"
        if spec.absorption
        else "none",
    }
    return FieldArrays(grid=grid, arrays=arrays, field_data=field_data, stats=stats)

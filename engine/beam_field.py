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
from typing import TYPE_CHECKING, Any

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
    BEAM_SEMICOHERENT,
    N_KMAH,
    W_FLOOR,
    BeamAcc,
    BeamGrid,
    BeamPoints,
    BeamTables,
)

if TYPE_CHECKING:
    from bentray.engine.field import FieldArrays
    from bentray.scenes.field_models import FieldSpec

P_REF_INTENSITY = 1e-12  # W/m^2, reference intensity of SPL

# Reflection-count groups kept apart (0, 1, 2, >= 3 reflections). Memory per slot:
# groups x N_KMAH x bands x points x 8 bytes (x 2 for complex sums).
MAX_REFLECTION_GROUPS = 4
NO_MIRROR = np.zeros((0, 0, 4))  # BeamGrid.mirror without ground images
NO_HESSIAN = np.zeros((0, 9))  # BeamTables.hessian without a mesh: the exact kicks of the piecewise-linear mesh


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


def _new_acc(bgrid: BeamGrid, n_points: int, n_slots: int) -> BeamAcc:
    n_f = bgrid.omega.shape[0]
    n_g = bgrid.n_refl * N_KMAH
    coh = bgrid.mode != BEAM_INCOHERENT
    inc = bgrid.mode != BEAM_COHERENT
    s = n_slots
    near = bgrid.mode == BEAM_INCOHERENT and bgrid.fresnel_k > 0.0
    return BeamAcc(
        np.zeros((s, n_g, n_f, n_points) if coh else (0, 0, 0, 0)),
        np.zeros((s, n_g, n_f, n_points) if coh else (0, 0, 0, 0)),
        np.zeros((s, n_g, n_f, n_points) if inc else (0, 0, 0, 0)),
        np.zeros((s, n_g, n_points)),
        np.zeros((s, n_points)),
        np.zeros((s, n_g, n_f, n_points) if near else (0, 0, 0, 0)),
        np.zeros((s, 2, n_g, n_points) if near else (0, 0, 0, 0)),
    )


def _empty_acc() -> BeamAcc:
    z4 = np.zeros((0, 0, 0, 0))
    return BeamAcc(z4, z4, z4, np.zeros((0, 0, 0)), np.zeros((0, 0)), z4, z4)


def _normalised(
    acc: BeamAcc, n_refl: int, mode: int, pooled: bool = False
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
    """Slots summed, groups normalised and combined: (p (F, V) or None, energy (F, V) or None, weight (V,)).

    pooled (an incoherent map with Fresnel-widened beams): the energy is normalised by the coverage of all groups
    together, not group by group; a widened beam straddles the points where its neighbours change group (one more
    reflection), so each group covers a point only in part while the groups together cover it once, and a
    normalisation per group would count it up to twice. weight is then that pooled coverage.

    BEAM_SEMICOHERENT storage (receivers) returns the coherent sum over all groups *and* the energy sum over
    all groups; the field's semicoherent mode is formed by the caller from the split returned here."""
    weight = acc.weight.sum(axis=0)  # (G, V)
    # a deficit (0.5 <= W < 1: neighbours already reflected) is repaired, below 0.5 the field fades; W > 1
    # (overlapping bundles: facets of a terrain, widths floored at a caustic) is a sum of arrivals, kept
    norm = 1.0 / np.clip(weight, W_FLOOR, 1.0)
    p = None
    energy = None
    if mode != BEAM_INCOHERENT:
        p = (acc.s_re.sum(axis=0) + 1j * acc.s_im.sum(axis=0)) * norm[:, None, :]  # (G, F, V)
    if pooled and mode == BEAM_INCOHERENT:
        total = weight.sum(axis=0)  # (V,)
        energy = acc.energy.sum(axis=0)  # (G, F, V)
        if acc.near_w.shape[0]:
            near_w = acc.near_w.sum(axis=0)  # (2, G, V)
            near_amp = acc.near_amp.sum(axis=0)  # (G, F, V)
            h = near_w[0]
            # the widened spreading times the nearest rays' amplitude factors, blended in as their own tubes
            # cover the point (h from 0.25 to 0.75), the widened beams' own mean where they do not
            blend = np.clip((h - 0.25) / 0.5, 0.0, 1.0)[:, None, :]
            local = near_w[1][:, None, :] * near_amp / np.maximum(h, 1e-300)[:, None, :]
            energy = blend * local + (1.0 - blend) * energy
        energy = energy * (1.0 / np.clip(total, W_FLOOR, 1.0))[None, None, :]
        return None, energy, total
    if mode != BEAM_COHERENT:
        energy = acc.energy.sum(axis=0) * norm[:, None, :]
    return p, energy, weight.max(axis=0)


@dataclass
class ReceiverLevels:
    """One batch's (one source's) receiver levels: p (F, P) coherent pressure re 1 m free field, energy
    (F, P) incoherent intensity re I_1m, weight (P,), hits (P,), powered_coh / powered_inc (F, P) W/m^2 with
    the source's power (None without powers)."""

    p: np.ndarray
    energy: np.ndarray
    weight: np.ndarray
    hits: np.ndarray
    powered_coh: np.ndarray | None
    powered_inc: np.ndarray | None


class BeamBuffers:
    """Beam accumulators of a job or of one ray batch, with the FieldBuffers interface the batch
    machinery uses (``like``, ``collapse``, ``add``, ``nbytes``, ``n_slots``, ``weights``, ``grid``).

    grid : the field grid (None: receivers only; bgrid.mode is then BEAM_OFF); receivers : (P, 3) points
    (None: none), their constants in ``pgrid`` (BEAM_SEMICOHERENT storage: coherent and incoherent levels).
    weights : (n_rays, F) the source power per band of each ray (W; zeros when no power was given, then
    only TL is written). The kernel arguments are (BeamGrid, BeamAcc, BeamTables, BeamGrid, BeamAcc,
    BeamPoints).
    """

    def __init__(
        self,
        mode: str,
        grid: FieldGrid | None,
        bgrid: BeamGrid,
        tables: BeamTables,
        weights: np.ndarray,
        n_slots: int,
        pgrid: BeamGrid | None = None,
        points: BeamPoints | None = None,
    ) -> None:
        if mode not in BEAM_MODES:
            raise ValueError(f"unknown beam field mode {mode!r}")
        self.mode = mode
        self.grid = grid
        self.bgrid = bgrid
        self.tables = tables
        # receivers: each beam's own tube, no images (the Fresnel floor is the incoherent map's)
        self.pgrid = (
            pgrid if pgrid is not None else bgrid._replace(mode=BEAM_SEMICOHERENT, fresnel_k=0.0, mirror=NO_MIRROR)
        )
        self.points = points if points is not None else bin_points(np.zeros((0, 3)))
        self.weights = np.ascontiguousarray(weights, dtype=np.float64)
        # (n_rays, F) per-ray amplitude factors of the sources' directivity for this batch (None: omni)
        self.ray_amp: np.ndarray | None = None
        self.n_slots = int(n_slots)
        self.collapsed: BeamCollapsed | None = None
        self.receivers: ReceiverLevels | None = None
        self.settings: FieldSpec | None = None  # bands and absorption (the field spec, or receiver_settings)
        s = self.n_slots
        self.acc = _new_acc(bgrid, grid.n_points, s) if grid is not None else _empty_acc()
        n_p = self.points.xyz.shape[0]
        self.p_acc = _new_acc(self.pgrid, n_p, s) if n_p else _empty_acc()

    @property
    def nbytes(self) -> int:
        return int(sum(a.nbytes for a in self.acc) + sum(a.nbytes for a in self.p_acc))

    def kernel_args(self) -> tuple[BeamGrid, BeamAcc, BeamTables, BeamGrid, BeamAcc, BeamPoints]:
        return self.bgrid, self.acc, self.tables, self.pgrid, self.p_acc, self.points

    def like(self, weights: np.ndarray, n_slots: int | None = None) -> BeamBuffers:
        """Fresh accumulators for another batch (slots: n_slots, else this one's, else the thread count)."""
        out = BeamBuffers(
            self.mode,
            self.grid,
            self.bgrid,
            self.tables,
            weights,
            n_slots or self.n_slots or numba.get_num_threads(),
            self.pgrid,
            self.points,
        )
        out.settings = self.settings
        return out

    def collapse(self, ray_offset: int = 0) -> BeamBuffers:
        """Sum the slots in order, normalise each group and combine the groups (see the module docstring)."""
        del ray_offset  # beams keep no ray ids
        n_f = self.bgrid.omega.shape[0]
        power = self.weights[0] if self.weights.shape[0] else np.zeros(n_f)
        powered = np.any(power > 0)
        if self.grid is not None:
            grid = self.grid
            p_g, e_g, weight = _normalised(self.acc, self.bgrid.n_refl, self.bgrid.mode, self.bgrid.fresnel_k > 0.0)
            p = None
            energy = None
            if self.bgrid.mode == BEAM_COHERENT:
                assert p_g is not None
                p = p_g.sum(axis=0)
            elif self.bgrid.mode == BEAM_INCOHERENT:
                assert e_g is not None
                energy = e_g.sum(axis=0)
            else:  # semicoherent: groups of 0 and 1 reflections coherently, the others as energies
                assert p_g is not None and e_g is not None
                pair = min(2, self.bgrid.n_refl) * N_KMAH
                p = p_g[:pair].sum(axis=0)
                energy = e_g[pair:].sum(axis=0)
            rel = np.zeros((n_f, grid.n_points))
            if p is not None:
                rel += np.abs(p) ** 2
            if energy is not None:
                rel += energy
            self.collapsed = BeamCollapsed(
                p=p,
                energy=energy,
                weight=weight,
                hits=self.acc.hits.sum(axis=0),
                powered=rel * (power[:, None] / (4.0 * math.pi)) if powered else None,
            )
        if self.points.xyz.shape[0]:
            p_g, e_g, weight = _normalised(self.p_acc, self.pgrid.n_refl, BEAM_SEMICOHERENT)
            assert p_g is not None and e_g is not None
            p = p_g.sum(axis=0)
            energy = e_g.sum(axis=0)
            scale = power[:, None] / (4.0 * math.pi)
            self.receivers = ReceiverLevels(
                p=p,
                energy=energy,
                weight=weight,
                hits=self.p_acc.hits.sum(axis=0),
                powered_coh=np.abs(p) ** 2 * scale if powered else None,
                powered_inc=energy * scale if powered else None,
            )
        self.acc = _empty_acc()
        self.p_acc = _empty_acc()
        self.n_slots = 1
        self.weights = np.zeros((0, self.weights.shape[1]))
        return self

    def add(self, other: BeamBuffers) -> None:
        """Add another collapsed batch (another source): pressures and energies sum."""
        a, b = self.collapsed, other.collapsed
        if a is not None and b is not None:
            if a.p is not None and b.p is not None:
                a.p = a.p + b.p
            if a.energy is not None and b.energy is not None:
                a.energy = a.energy + b.energy
            a.weight = np.maximum(a.weight, b.weight)
            a.hits = a.hits + b.hits
            if b.powered is not None:
                a.powered = b.powered if a.powered is None else a.powered + b.powered
        ra, rb = self.receivers, other.receivers
        if ra is not None and rb is not None:
            ra.p = ra.p + rb.p
            ra.energy = ra.energy + rb.energy
            ra.weight = np.maximum(ra.weight, rb.weight)
            ra.hits = ra.hits + rb.hits
            if rb.powered_coh is not None and rb.powered_inc is not None:
                ra.powered_coh = rb.powered_coh if ra.powered_coh is None else ra.powered_coh + rb.powered_coh
                ra.powered_inc = rb.powered_inc if ra.powered_inc is None else ra.powered_inc + rb.powered_inc


def bin_points(xyz: np.ndarray, target_per_bin: float = 4.0) -> BeamPoints:
    """Bin receiver points (P, 3) on a regular grid of cubes (about ``target_per_bin`` points per occupied
    bin on average, at most 2 million bins) for the chord search."""
    xyz = np.ascontiguousarray(np.asarray(xyz, float).reshape(-1, 3))
    if xyz.shape[0] == 0:
        return BeamPoints(xyz, np.zeros(3), 1.0, np.ones(3, np.int64), np.zeros(2, np.int64), np.zeros(0, np.int64))
    lo = xyz.min(axis=0)
    extent = np.maximum(xyz.max(axis=0) - lo, 1e-6)
    vol = float(np.prod(np.maximum(extent, 1.0)))
    size = max((vol * target_per_bin / xyz.shape[0]) ** (1.0 / 3.0), float(extent.max()) / 120.0, 1.0)
    shape = np.maximum(np.floor(extent / size).astype(np.int64) + 1, 1)
    idx = np.minimum(np.floor((xyz - lo) / size).astype(np.int64), shape - 1)
    flat = (idx[:, 0] * shape[1] + idx[:, 1]) * shape[2] + idx[:, 2]
    order = np.argsort(flat, kind="stable")
    counts = np.bincount(flat, minlength=int(np.prod(shape)))
    start = np.zeros(counts.size + 1, np.int64)
    np.cumsum(counts, out=start[1:])
    return BeamPoints(xyz, lo.astype(float), float(size), shape, start, order.astype(np.int64))


def beam_grid(
    grid: FieldGrid,
    mode: str,
    frequencies_hz: np.ndarray,
    c_ref: float,
    dgamma: tuple[float, float],
    w_min: float,
    max_reflections: int,
    z_offset: np.ndarray | None = None,
    fresnel_k: float = 0.0,
    mirror: np.ndarray | None = None,
    fan_extent: tuple[float, float] = (math.pi, 2.0 * math.pi),
) -> BeamGrid:
    """The kernel's BeamGrid (see engine/kernels/beams.py for the meaning of each entry)."""
    nx, ny, _ = grid.shape
    z_off = np.zeros((nx, ny)) if z_offset is None else np.ascontiguousarray(z_offset, float).reshape(nx, ny)
    return BeamGrid(
        np.asarray(grid.origin, float),
        np.asarray(grid.spacing, float),
        np.asarray(grid.shape, np.int64),
        z_off,
        2.0 * math.pi * np.asarray(frequencies_hz, float),
        float(c_ref),
        np.asarray(dgamma, float),
        float(w_min),
        int(min(max(max_reflections, 0), MAX_REFLECTION_GROUPS - 1) + 1),
        BEAM_MODES[mode],
        float(fresnel_k),
        0.25 * np.asarray(fan_extent, float),
        NO_MIRROR if mirror is None else np.ascontiguousarray(mirror, float).reshape(nx, ny, 4),
        float(grid.origin[2] + (np.max(z_off) if z_off.size else 0.0) + (grid.shape[2] - 1) * grid.spacing[2]),
    )


def beam_tables(
    frequencies_hz: np.ndarray, materials: list[float | None], alpha: np.ndarray, chord_m: float, sound_speed: float
) -> BeamTables:
    """Complex ground table per (material, band), absorption per band (1/m) and the chord length (m)."""
    q = build_q_table([float(f) for f in np.asarray(frequencies_hz, float)], materials, c=sound_speed)
    return BeamTables(q.table, q.grid, np.asarray(alpha, float), float(chord_m), NO_HESSIAN)


def launch_steps(elevation_deg: np.ndarray, azimuth_deg: np.ndarray) -> tuple[float, float]:
    """Launch-grid steps (rad) for the hat beams: a one-value axis spans a full turn (2 pi), so a single
    azimuth fan is a vertical fan whose beams extend sideways with the tube's own width."""
    el = np.radians(np.asarray(elevation_deg, float))
    az = np.radians(np.asarray(azimuth_deg, float))
    d_el = float(el[1] - el[0]) if el.size > 1 else math.pi
    d_az = float(az[1] - az[0]) if az.size > 1 else 2.0 * math.pi
    return d_el, d_az


def fan_extent(elevation_deg: np.ndarray, azimuth_deg: np.ndarray) -> tuple[float, float]:
    """Angular extent (rad) of the launch grid along elevation and azimuth: n_k Dgamma_k, the rays' span and half
    a step either side (a one-value axis: pi and 2 pi, its step as :func:`launch_steps` takes it)."""
    d_el, d_az = launch_steps(elevation_deg, azimuth_deg)
    return float(np.size(elevation_deg) * d_el), float(np.size(azimuth_deg) * d_az)


def no_beam_args(n_f: int = 1) -> tuple[BeamGrid, BeamAcc, BeamTables, BeamGrid, BeamAcc, BeamPoints]:
    """Kernel arguments of the same types with beams off (tiny arrays, mode BEAM_OFF, no points)."""
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
        0.0,
        np.zeros(2),
        NO_MIRROR,
        math.inf,
    )
    t = BeamTables(np.zeros((1, n_f, 2, 2, 2)), np.zeros(5), np.zeros(n_f), 1.0, NO_HESSIAN)
    return g, _empty_acc(), t, g, _empty_acc(), bin_points(np.zeros((0, 3)))


def default_chord_m(spacing: np.ndarray) -> float:
    """Chord length (m): twice the smallest grid spacing, within [1, 10] m (straight chords of a
    curved ray deviate by kappa l^2 / 8: 0.4 mm for 10 m at a 30 km radius of curvature)."""
    return float(min(max(2.0 * float(np.min(spacing)), 1.0), 10.0))


def default_min_width_m(frequencies_hz: np.ndarray, c: float) -> float:
    """Smallest beam half-width (m): half a wavelength at the bands' geometric-mean frequency."""
    f = np.asarray(frequencies_hz, float)
    return float(0.5 * c / math.exp(float(np.mean(np.log(f)))))


def widens_incoherent_beams(spec: FieldSpec | None) -> bool:
    """Whether a field's beams are Fresnel-widened (an incoherent map with ``incoherent_width = "fresnel"``)."""
    return spec is not None and spec.mode == "incoherent" and spec.incoherent_width == "fresnel"


def _incoherent_floor(
    spec: FieldSpec | None, frequencies_hz: np.ndarray, c_ref: float, ground_planes: np.ndarray | None
) -> tuple[float, np.ndarray | None]:
    """(fresnel_k, mirror planes) of BeamGrid: ``lambda / pi`` at the highest band and the
    ground planes for an incoherent map with ``incoherent_width = "fresnel"``, else (0, None)."""
    if spec is None or not widens_incoherent_beams(spec):
        return 0.0, None
    f = float(np.max(np.asarray(frequencies_hz, float)))
    return (c_ref / f) / math.pi, ground_planes


def prepare(
    spec: FieldSpec | None,
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
    ground_planes: np.ndarray | None = None,
    receivers_xyz: np.ndarray | None = None,
    receiver_bands: list[float] | None = None,
) -> BeamBuffers:
    """The beam accumulator template of a job (no slots: each batch allocates its own).

    elevation_deg, azimuth_deg : the launch grid's axes (degrees); source_index : (n_rays,) int;
    source_powers_w : (n_src, F) W or None; materials : flow resistivity per face material (None rigid);
    n_face_materials : 1 + the largest material index the mesh's faces carry (checked against the table:
    a mismatch would read past it). ground_z : (nx, ny) ground height (m) under each grid column for
    ``heights = "above_ground"`` (None: absolute heights). ground_planes : (nx, ny, 4) the ground's tangent plane
    under each column (unit normal up, offset: ``n.x = d``), the images of an incoherent map's Fresnel-floored
    beams (None: no images). spec None: receivers only, with the default
    bands and absorption of :func:`receiver_settings`. receivers_xyz : (P, 3) receiver points (m) or None.
    """
    if n_face_materials > len(materials):
        raise ValueError(f"the mesh's faces use {n_face_materials} materials but the ground table has {len(materials)}")
    settings = spec if spec is not None else receiver_settings(receiver_bands)
    grid = (
        FieldGrid(
            np.asarray(spec.origin, float),
            np.asarray(spec.spacing, float),
            (int(spec.shape[0]), int(spec.shape[1]), int(spec.shape[2])),
        )
        if spec is not None
        else None
    )
    freqs = np.asarray(settings.frequencies_hz, float)
    w_min = settings.beam_min_width_m if settings.beam_min_width_m is not None else default_min_width_m(freqs, c_ref)
    chord = (
        settings.chord_m
        if settings.chord_m is not None
        else default_chord_m(grid.spacing if grid is not None else np.array([2.5]))
    )
    bgrid = beam_grid(
        grid if grid is not None else FieldGrid(np.zeros(3), np.ones(3), (1, 1, 1)),
        settings.mode,
        freqs,
        c_ref,
        launch_steps(elevation_deg, azimuth_deg),
        w_min,
        max_reflections,
        ground_z,
        *_incoherent_floor(spec, freqs, c_ref, ground_planes),
        fan_extent(elevation_deg, azimuth_deg),
    )
    if grid is None:
        bgrid = bgrid._replace(mode=BEAM_OFF)
    points = bin_points(receivers_xyz) if receivers_xyz is not None and len(receivers_xyz) else None
    from bentray.engine.field import energy_absorption  # the field stage's ISO 9613-1 per band

    tables = beam_tables(freqs, materials, energy_absorption(settings), chord, ground_sound_speed)
    if source_powers_w is not None:
        weights = np.ascontiguousarray(source_powers_w[np.asarray(source_index)], float)
    else:
        weights = np.zeros((n_rays, freqs.size))
    buffers = BeamBuffers(
        settings.mode, grid, bgrid, tables, weights, 0, bgrid._replace(mode=BEAM_SEMICOHERENT), points
    )
    buffers.settings = settings
    return buffers


def receiver_settings(frequencies_hz: list[float] | None = None) -> FieldSpec:
    """Band and absorption settings of receivers in a job without a field: the FieldSpec defaults
    (octave bands 63 Hz - 8 kHz, or the bands the sources give powers for; ISO 9613-1 at 15 C, 70 %,
    101.325 kPa)."""
    from bentray.scenes.field_models import FieldSpec

    extra = {"frequencies_hz": sorted(frequencies_hz)} if frequencies_hz else {}
    return FieldSpec(origin=(0.0, 0.0, 0.0), spacing=(1.0, 1.0, 1.0), shape=(1, 1, 1), mode="semicoherent", **extra)


@dataclass
class ReceiverTable:
    """Receiver levels for receivers.csv and the report: one row per receiver (dict of columns)."""

    columns: list[str]
    rows: list[dict[str, Any]]
    stats: dict[str, Any]


def finalize_receivers(spec: FieldSpec | None, buffers: BeamBuffers, ids: list[str], xyz: np.ndarray) -> ReceiverTable:
    """Per receiver: coherent and incoherent TL per band (dB re 1 m free field), SPL per band and
    A-weighted when the sources have powers, the beam weight and contributions (0: no beam reached it)."""
    settings = spec if spec is not None else (buffers.settings or receiver_settings())
    rec = buffers.receivers
    if rec is None:
        raise ValueError("finalize_receivers() needs the collapsed receiver levels")
    labels = settings.labels
    a_w = np.asarray(a_weighting_db(np.asarray(settings.frequencies_hz, float)), float)
    tl_coh = -_level(np.abs(rec.p) ** 2)
    tl_inc = -_level(rec.energy)
    columns = ["id", "x_m", "y_m", "z_m", "beam_weight", "beam_hits"]
    columns += [f"tl_coh_{lab}hz" for lab in labels] + [f"tl_inc_{lab}hz" for lab in labels]
    spl: dict[str, np.ndarray] = {}
    if rec.powered_coh is not None and rec.powered_inc is not None:
        for kind, arr in (("coh", rec.powered_coh), ("inc", rec.powered_inc)):
            lv = _level(arr / P_REF_INTENSITY)
            spl[kind] = lv
            columns += [f"spl_{kind}_{lab}hz" for lab in labels]
            lin = np.where(np.isfinite(lv), 10.0 ** ((lv + a_w[:, None]) / 10.0), 0.0).sum(axis=0)
            spl[f"a_{kind}"] = _level(lin)
        columns += ["spl_a_coh", "spl_a_inc"]
    rows = []
    for i, rid in enumerate(ids):
        row: dict[str, Any] = {
            "id": rid,
            "x_m": float(xyz[i, 0]),
            "y_m": float(xyz[i, 1]),
            "z_m": float(xyz[i, 2]),
            "beam_weight": float(rec.weight[i]),
            "beam_hits": int(rec.hits[i]),
        }
        for f, lab in enumerate(labels):
            row[f"tl_coh_{lab}hz"] = float(tl_coh[f, i])
            row[f"tl_inc_{lab}hz"] = float(tl_inc[f, i])
        for kind in ("coh", "inc"):
            if kind in spl:
                for f, lab in enumerate(labels):
                    row[f"spl_{kind}_{lab}hz"] = float(spl[kind][f, i])
                row[f"spl_a_{kind}"] = float(spl[f"a_{kind}"][i])
        rows.append(row)
    stats = {
        "count": len(ids),
        "without_beams": int(np.count_nonzero(rec.hits == 0)),
        "partially_covered": int(np.count_nonzero((rec.hits > 0) & (rec.weight < W_FLOOR))),
        "frequencies_hz": [float(f) for f in settings.frequencies_hz],
        "levels": "coherent (tl_coh, spl_coh) and incoherent (tl_inc, spl_inc) from the beam field",
    }
    return ReceiverTable(columns, rows, stats)


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
    if grid is None:
        raise ValueError("finalize() needs a field grid (this job has receivers only)")
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
        "absorption": (
            f"ISO 9613-1 at {spec.temperature_c:g} C, {spec.humidity_percent:g} %RH, {spec.pressure_kpa:g} kPa"
            if spec.absorption
            else "none"
        ),
    }
    return FieldArrays(grid=grid, arrays=arrays, field_data=field_data, stats=stats)

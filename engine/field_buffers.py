"""Per-thread field accumulators handed to the traversal kernel, and their reduction.

The kernel writes accumulator slot ``acc`` only from the thread that runs that slot (rays are
interleaved over slots), so there are no shared writes; :meth:`FieldBuffers.reduce` sums energies
and picks the nearest coherent record over slots. With the same slot count the result is bit-for-bit
reproducible; across slot counts it differs only by floating-point summation order (~1e-15 relative).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from bentray.engine.kernels.field import FGEO_SIZE, FIELD_COHERENT, FIELD_INCOHERENT, FIELD_OFF, FieldAcc

# Reflections remembered per ray for the ground factors (incoherent) and the coherent Q product.
# Beyond it, further reflections still reflect but keep the ground factor of the first 32.
REFLECTION_RECORD_CAP = 32
# Coherent arrival groups: 0, 1, ..., MAX_GROUPS - 1 reflections; more reflections share the last group.
MAX_COHERENT_GROUPS = 8


@dataclass
class FieldGrid:
    """Regular grid of field points: point (i, j, k) at origin + (i, j, k) * spacing, metres, world frame."""

    origin: np.ndarray
    spacing: np.ndarray
    shape: tuple[int, int, int]

    @property
    def n_points(self) -> int:
        return int(np.prod(self.shape))

    def points(self) -> np.ndarray:
        """(n_points, 3) coordinates in C order of an (nx, ny, nz) array."""
        axes = [self.origin[a] + self.spacing[a] * np.arange(self.shape[a]) for a in range(3)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)

    @property
    def voxel_volume(self) -> float:
        return float(np.prod(self.spacing))


@dataclass
class FieldReduced:
    """Accumulators summed over slots. energy (n_f, n_vox) J per unit of ray weight; hits (n_vox,);
    coherent: group_energy (G, n_vox), time_s, length_m (G, n_vox) at the grid point, ray (G, n_vox)
    (-1: no sample of that group in the voxel)."""

    energy: np.ndarray | None
    hits: np.ndarray
    group_energy: np.ndarray | None = None
    time_s: np.ndarray | None = None
    length_m: np.ndarray | None = None
    ray: np.ndarray | None = None


class FieldBuffers:
    """Allocates the kernel's accumulators for ``n_slots`` threads.

    weights : (n_rays, n_f) float64 power per accumulated band (W); alpha : (n_f,) energy absorption
    (1/m); band_of : (n_f,) physical band index of each accumulated band (for the ground table
    q2tab (n_mat, n_band, n_cos, n_r) with axes q2ax). h_sample : sub-interval length in metres of arc.
    """

    def __init__(
        self,
        mode: str,
        grid: FieldGrid,
        weights: np.ndarray,
        alpha: np.ndarray,
        band_of: np.ndarray,
        q2tab: np.ndarray,
        q2ax: np.ndarray,
        h_sample: float,
        n_slots: int,
        n_groups: int = 1,
    ) -> None:
        if mode not in ("incoherent", "coherent"):
            raise ValueError(f"unknown field mode {mode!r}")
        self.mode = mode
        self.grid = grid
        self.n_slots = int(n_slots)
        self.h_sample = float(h_sample)
        self.n_groups = int(n_groups)
        n_vox = grid.n_points
        self.weights = np.ascontiguousarray(weights, dtype=np.float64)
        n_f = self.weights.shape[1]
        self.fgeo = np.zeros(FGEO_SIZE)
        self.fgeo[0:3] = grid.origin
        self.fgeo[3:6] = 1.0 / np.asarray(grid.spacing, float)
        self.fgeo[6] = float(h_sample)
        self.fshape = np.asarray(grid.shape, dtype=np.int64)
        self.alpha = np.ascontiguousarray(alpha, dtype=np.float64)
        self.band_of = np.ascontiguousarray(band_of, dtype=np.int64)
        self.q2tab = np.ascontiguousarray(q2tab, dtype=np.float64)
        self.q2ax = np.ascontiguousarray(q2ax, dtype=np.float64)
        self.hits = np.zeros((self.n_slots, n_vox))
        if mode == "incoherent":
            self.code = FIELD_INCOHERENT
            self.energy = np.zeros((self.n_slots, n_f, n_vox))
            g, nv = 1, 1
        else:
            self.code = FIELD_COHERENT
            self.energy = np.zeros((1, n_f, 1))
            g, nv = int(n_groups), n_vox
        self.c_energy = np.zeros((self.n_slots, g, nv))
        self.c_perp2 = np.full((self.n_slots, g, nv), np.inf)
        self.c_time = np.zeros((self.n_slots, g, nv))
        self.c_length = np.zeros((self.n_slots, g, nv))
        self.c_ray = np.full((self.n_slots, g, nv), -1, dtype=np.int64)

    @property
    def nbytes(self) -> int:
        return sum(
            a.nbytes
            for a in (self.energy, self.hits, self.c_energy, self.c_perp2, self.c_time, self.c_length, self.c_ray)
        )

    def kernel_tuple(self) -> FieldAcc:
        """The kernels' view of these accumulators (kernels.field.FieldAcc; arrays shared, not copied)."""
        return FieldAcc(
            np.int64(self.code),  # type: ignore[arg-type]  # an int64 in both constructors: one numba type
            self.fgeo,
            self.fshape,
            self.alpha,
            self.band_of,
            self.q2tab,
            self.q2ax,
            self.energy,
            self.hits,
            self.c_energy,
            self.c_perp2,
            self.c_time,
            self.c_length,
            self.c_ray,
        )

    def like(self, weights: np.ndarray, n_slots: int | None = None) -> FieldBuffers:
        """Fresh (zeroed) accumulators with the same grid and tables for another set of rays (a batch).

        Slots: ``n_slots``, else this object's, else (a template built with 0 slots) this process's numba
        thread count."""
        return FieldBuffers(
            self.mode,
            self.grid,
            weights,
            self.alpha,
            self.band_of,
            self.q2tab,
            self.q2ax,
            self.h_sample,
            n_slots or self.n_slots or numba.get_num_threads(),
            self.n_groups,
        )

    def collapse(self, ray_offset: int = 0) -> FieldBuffers:
        """Sum the slots into one (in slot order) and shift coherent ray ids by ``ray_offset``: the partial
        field of a ray batch, ready for :meth:`add`. Returns self (one slot, weights dropped)."""
        n_vox = self.hits.shape[1]
        self.hits = self.hits.sum(axis=0, keepdims=True)
        if self.code == FIELD_INCOHERENT:
            self.energy = self.energy.sum(axis=0, keepdims=True)
        else:
            best = np.argmin(self.c_perp2, axis=0)[None]
            for name in ("c_perp2", "c_time", "c_length", "c_ray"):
                setattr(self, name, np.take_along_axis(getattr(self, name), best, axis=0))
            self.c_energy = self.c_energy.sum(axis=0, keepdims=True)
            self.c_ray = np.where(self.c_ray >= 0, self.c_ray + int(ray_offset), -1)
        self.n_slots = 1
        self.weights = np.zeros((0, self.weights.shape[1]))
        assert self.hits.shape == (1, n_vox)
        return self

    def add(self, other: FieldBuffers) -> None:
        """Add another collapsed batch (later in ray order) into this collapsed one: sums, and the nearest
        coherent sample (ties keep the earlier batch, so the order of batches fixes the result)."""
        if self.n_slots != 1 or other.n_slots != 1:
            raise ValueError("add() combines collapsed batches (call collapse() first)")
        self.hits += other.hits
        if self.code == FIELD_INCOHERENT:
            self.energy += other.energy
            return
        self.c_energy += other.c_energy
        closer = other.c_perp2 < self.c_perp2
        for name in ("c_perp2", "c_time", "c_length", "c_ray"):
            mine = getattr(self, name)
            mine[closer] = getattr(other, name)[closer]

    def reduce(self) -> FieldReduced:
        hits = self.hits.sum(axis=0)
        if self.code == FIELD_INCOHERENT:
            return FieldReduced(energy=self.energy.sum(axis=0), hits=hits)
        best = np.argmin(self.c_perp2, axis=0)[None]  # (1, G, n_vox) slot of the nearest sample
        pick = lambda a: np.take_along_axis(a, best, axis=0)[0]  # noqa: E731
        ray = pick(self.c_ray)
        return FieldReduced(
            energy=None,
            hits=hits,
            group_energy=self.c_energy.sum(axis=0),
            time_s=np.where(ray >= 0, pick(self.c_time), np.nan),
            length_m=np.where(ray >= 0, pick(self.c_length), np.nan),
            ray=ray,
        )


def no_field_tuple(n_rays: int) -> tuple[FieldAcc, np.ndarray]:
    """A FIELD_OFF FieldAcc with minimal dummy arrays (the same types as a real one), and (n_rays, 0) weights."""
    z3 = np.zeros((1, 1, 1))
    fld = FieldAcc(
        np.int64(FIELD_OFF),  # type: ignore[arg-type]  # an int64 in both constructors: one numba type
        np.zeros(FGEO_SIZE),
        np.ones(3, dtype=np.int64),
        np.zeros(0),
        np.zeros(0, dtype=np.int64),
        np.ones((1, 1, 2, 2)),
        np.array([0.0, 1.0, 0.0, 1.0]),
        z3.copy(),
        np.zeros((1, 1)),
        z3.copy(),
        z3.copy(),
        z3.copy(),
        z3.copy(),
        np.full((1, 1, 1), -1, dtype=np.int64),
    )
    return fld, np.zeros((n_rays, 0))

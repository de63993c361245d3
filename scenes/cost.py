"""A cost model of a validated job, evaluated before any work starts (the service's 422, the CLI's exit 2).

Every estimate is an upper-bound style count from the job alone (no mesh is built), in bytes or in
elementary operations, with the formula stated where it is computed:

- ``paths_bytes``: recorded ray paths, ``rays x path_samples x PATH_SAMPLE_BYTES`` (measured: 20,000
  rays x 400 samples held 828 MB, i.e. 103.5 B per sample with the result arrays and the VTK copy).
- ``field_bytes``: the field accumulators, one set per thread plus the collapsed total and one batch's
  partial. Voxels: ``(threads + 2) x points x (bands + 1) x 8 B`` incoherent; coherent mode keeps 5
  records of 8 B per arrival group (at most 8) and point. Beams (the default method): per point,
  3 x (reflection groups, at most 4) KMAH groups x bands x (2 coherent + 1 incoherent arrays) x 8 B.
- ``rays_bytes``: the per-ray final state, ``rays x RAY_STATE_BYTES``.
- ``field_deposits``: field samples. Voxels: ``rays x crossings x (grid diagonal + 2 x largest cell) /
  h`` where h = sample_fraction x smallest field spacing (segments are cut into pieces of length h where
  they pass the grid). Beams: ``crossings x (4 x points x sources + 8 x rays x (grid diagonal + 2 x
  largest cell) / chord)`` (the beams of a fan tile space; a stencil per chord).
  crossings = min(max_reflections + 1, 1 + c_max max_time_s / smallest domain extent): each reflection
  can bring the ray back through the grid.
- ``ray_steps``: ``rays x max_steps`` is a bound nobody reaches, so the work estimate of the trace is
  ``rays x crossings x cells per crossing`` with cells per crossing = domain diagonal / (largest extent
  / 200) (the tets default smallest cell; adaptive sizings make few cells where the medium is smooth, so
  ``solver.d_min_m`` does not enter), capped by ``max_steps``.
- ``eigenray_steps``: the eigenray search (engine/eigenrays.py) per (source, receiver) pair it runs: a
  bracket fan of ``eigenrays.elevations`` rays plus single-ray Newton probes, at most
  :data:`EIGENRAY_PROBES_PER_REFLECTION` x (max_reflections + 1) probes of 1 ray (parabolic curve:
  paraxial Jacobian) or 5 rays (other curves: central differences), each ray costed like a fan ray
  (crossings x cells per crossing). Measured with a wrapped ``eigenrays._trace_to`` over 4 receivers at
  50-900 m and homogeneous, linear-c and log (b = +-1) profiles: 11-1132 probe calls and 731-1872 rays per
  pair (721-elevation fan), i.e. at most 164 probes per reflection count allowed. Wall reflections
  (lateral eigenrays) add one fan and its probes per wall the search takes for a pair (the same test,
  ``engine.eigenrays.wall_images``, over the inline footprints).
- ``shadow_solves`` / ``shadow_seconds``: the refractive-shadow stage (engine/shadow_stage.py): one
  wavenumber integral per source, band and (with wind) 5-degree azimuth bin the field points and
  receivers cover as seen from the source, each ``engine/acoustics/wavenumber.ffp_cells`` (heights x
  wavenumbers, ~ f^2 x range x top height) x SHADOW_SECONDS_PER_CELL, with the range the farthest point
  from the source and the top 0.25 x that range + 20 m (the log profile b = -1's limiting ray is 145 m
  high at 1 km; capped at 2 km as in the stage); 0 where no source can see
  upward refraction from the job alone (no wind and a homogeneous or downward-refracting profile), with
  ``field.refractive_shadow`` "off", or with "auto" above the stage's own limit (it then skips itself).
- ``wave_seconds``: the wave-field stage (engine/wave_stage.py): per band it runs (:func:`wave_cost`: 'auto'
  the bands lowest first within WAVE_AUTO_MAX_SECONDS, 'on' all, none where :func:`wave_blockers` says it
  cannot apply), sources x azimuth bins x (the band's frequencies: 1, or N Gauss nodes for band averages,
  :func:`wave_frequencies`) x ``ffp_cells`` x WAVE_SECONDS_PER_CELL, the top 0.3 x range + 20 m
  (at least 2 x the highest point + 20 m and 40 wavelengths); over ``CostLimits.wave_seconds`` a line naming
  ``field.wave_model``.
- ``mesh_seconds``: the media-mesh build (:func:`estimate_mesh`), ``cells x MESH_SECONDS_PER_CELL`` of
  the mesher the job gets (measured on a 2-core machine shared with other work, 2026-12-01,
  ``python -m bentray.engine.bench.mesh_time``: build time was proportional to the cell count, see
  :data:`MESH_SECONDS_PER_CELL`). Cells, from the job and the engine's own sizing code, nothing meshed:
  tets (a profile that varies in 3D, or the ridge wind over flat ground): the FCC resampling's own
  up-front point count (``engine/mesh/fcc.estimate_point_count`` of the sizing field that
  ``engine/media.py`` computes, at most the resampler's 2M points) x TET_CELLS_PER_POINT; terrain
  (terrain, buildings or ground zones): 3 tets per prism, ``2 x area / h^2`` triangles (h: the terrain's
  own spacing or ``solver.d_max_m`` if smaller, else largest extent / 32; x BUILDINGS_TRIANGLE_FACTOR
  with buildings) x the layers the curvature (or gradient) rule gives on the column at the domain
  centre. Slabs and uniform media (no 3D mesh),
  obstacle meshes (fTetWild) and exact-media baselines are not estimated (0 s). A profile or terrain
  read from a file is estimated only when the file is at hand (``base_dir``; the service checks
  again once the files are uploaded).

:func:`cost_problems` compares them with :class:`CostLimits` and returns one ``field.path: reason``
line per exceeded budget, with the estimate and the limit in the text.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from dataclasses import field as dc_field
from pathlib import Path
from typing import Any

__all__ = [
    "DEFAULT_MESH_SECONDS",
    "DEFAULT_PATH_RAYS",
    "MESH_SECONDS_PER_CELL",
    "CostEstimate",
    "CostLimits",
    "MeshEstimate",
    "cost_problems",
    "estimate_cost",
    "estimate_mesh",
    "machine_memory_bytes",
    "mesh_problems",
    "records_paths",
    "shadow_cost",
    "wave_blockers",
    "wave_cost",
    "wave_frequencies",
]

PATH_SAMPLE_BYTES = 104  # measured, see the module docstring
RAY_STATE_BYTES = 200  # final position, direction, time, length, status, indices, launch angles
DEFAULT_PATH_RAYS = 2_000  # paths are recorded by default only up to this many rays (~83 MB at 400 samples)
_C_MAX_M_S = 1000.0  # the media check's upper sound speed (scenes.media_checks.C_MAX_M_S)
# Media-mesh build seconds per cell, measured with engine/bench/mesh_time.py on 2 shared cores (fit data
# in the README, "Cost model"): least squares t = -0.34 s + 94.9 us x cells (tets, 3.9k-523k cells) and
# t = 0.67 s + 15.6 us x cells (terrain, 391k-5.1M cells); the largest per-cell time above 10k cells
# rounded up, is the rate used (98 us and 19.4 us).
MESH_SECONDS_PER_CELL = {"tets": 100e-6, "terrain": 20e-6}
# Tets built per point of fcc.estimate_point_count (boundary samples included): measured 5.9-6.2.
TET_CELLS_PER_POINT = 6.0
# Buildings refine the terrain mesher's triangles along walls: measured 1.52x on christmas (40 buildings).
BUILDINGS_TRIANGLE_FACTOR = 1.6
ESTIMATE_NODES = 100_000  # sizing-grid nodes of the tets estimate (the engine's grid: up to 1e6)
FCC_MAX_POINTS = 2_000_000  # engine/mesh/fcc.fcc_resample's max_points: more is refused by the mesher
# eigenray probes per (source, receiver) pair and allowed reflection count: the measured largest (164, module
# docstring) rounded up
EIGENRAY_PROBES_PER_REFLECTION = 200
DEFAULT_MESH_SECONDS = 600.0  # default budget of one job's mesh build (BENTRAY_MAX_MESH_SECONDS)
# The refractive-shadow stage's wavenumber integral: measured 6.3e-8 s per cell (1 kHz, 1 km, 3.5e8 cells in
# 21.8 s on a loaded core, 2026-12-02); rounded up.
# Since 2026-12-05 each Numerov row is one compiled pass (engine/acoustics/numerov_kernel.py): 1.8 ns per cell on a
# quiet core. The rates here are kept: the 'auto' limits and the budgets below were chosen with them, and lowering
# them would change which bands and bins 'auto' runs (a product decision, not a speed-up).
SHADOW_SECONDS_PER_CELL = 1e-7
SHADOW_AUTO_MAX_SOLVES = 16  # engine/shadow_stage.py's 'auto' limits: integrals ...
SHADOW_AUTO_MAX_SECONDS = 600.0  # ... and estimated seconds (shadow_cost)
DEFAULT_SHADOW_SECONDS = 1800.0  # budget of the refractive-shadow stage of one job
# The wave-field stage (engine/wave_stage.py): the same wavenumber integral over every point; measured 1.0e-7 s
# per cell (500 Hz, 1 km, top 60 m: 2.66e7 cells in 2.6 s; 300 m: 1.33e8 in 10 s, 2026-12-02, loaded 2-core box)
# Band averages (7 nodes, 1 km, one source, quiet machine, load ~1): 100 Hz octave 2.0-3.1e7 cells in 0.3-0.5 s CPU,
# 500 Hz 2.4-7.5e8 cells in 2.9-9.0 s (12 ns per cell); 1e-7 kept for the shared machine's load (10-13).
WAVE_SECONDS_PER_CELL = 1e-7
WAVE_AUTO_MAX_SECONDS = 120.0  # 'auto': the bands, lowest first, while their estimated seconds add up to this
DEFAULT_WAVE_SECONDS = 1800.0  # budget of the wave stage of one job ('on')
# profile kinds that vary with z only (engine Profile.stratified): slabs, no 3D mesh, over flat ground
_STRATIFIED_KINDS = (
    "homogeneous",
    "linear_c",
    "linear_n",
    "linear_n2",
    "log",
    "mirage_inferior",
    "mirage_superior",
    "table",
)


def _default_mesh_seconds() -> float:
    """BENTRAY_MAX_MESH_SECONDS if set to a positive number (the CLI reads it too), else the default."""
    raw = os.environ.get("BENTRAY_MAX_MESH_SECONDS", "").strip()
    try:
        value = float(raw) if raw else DEFAULT_MESH_SECONDS
    except ValueError:
        return DEFAULT_MESH_SECONDS
    return value if math.isfinite(value) and value > 0 else DEFAULT_MESH_SECONDS


def records_paths(job: Any) -> bool:
    """Whether the job records sampled ray paths: ``rays.record_paths`` if given; else when 'paths' is
    an output, or 'rays' is and the job has at most :data:`DEFAULT_PATH_RAYS` rays."""
    if job.rays.record_paths is not None:
        return bool(job.rays.record_paths)
    if "paths" in job.outputs:
        return True
    return "rays" in job.outputs and job.n_rays <= DEFAULT_PATH_RAYS


def machine_memory_bytes() -> int:
    """Physical memory of this machine in bytes (0 when unknown)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 0


@dataclass(frozen=True)
class CostLimits:
    """Budgets of one job. memory_bytes: all estimated arrays together; field_deposits and ray_steps:
    elementary operations (about 1e8 per core-second each)."""

    memory_bytes: int = 8 * 2**30
    field_deposits: float = 2e10
    ray_steps: float = 5e10
    threads: int = os.cpu_count() or 1
    mesh_seconds: float = dc_field(default_factory=_default_mesh_seconds)
    shadow_seconds: float = DEFAULT_SHADOW_SECONDS
    wave_seconds: float = DEFAULT_WAVE_SECONDS


@dataclass(frozen=True)
class CostEstimate:
    paths_bytes: int
    field_bytes: int
    rays_bytes: int
    field_deposits: float
    ray_steps: float
    eigenray_steps: float = 0.0
    shadow_solves: int = 0
    shadow_seconds: float = 0.0
    wave_seconds: float = 0.0

    @property
    def memory_bytes(self) -> int:
        return self.paths_bytes + self.field_bytes + self.rays_bytes


def estimate_cost(job: Any, threads: int) -> CostEstimate:
    """The estimates of the module docstring for a validated job, ``threads`` numba threads."""
    n_rays = int(job.n_rays)
    box = job.scene.box
    extent = [float(b - a) for a, b in zip(box.min, box.max, strict=True)]
    diagonal = math.sqrt(sum(e * e for e in extent))
    crossings = min(job.rays.max_reflections + 1, 1.0 + _C_MAX_M_S * job.rays.max_time_s / max(min(extent), 1e-9))
    paths = n_rays * job.solver.path_samples * PATH_SAMPLE_BYTES if records_paths(job) else 0
    field_bytes = 0
    deposits = 0.0
    spec = job.field
    if spec is not None:
        n_points = spec.n_points
        n_bands = len(spec.frequencies_hz)
        method = getattr(spec, "method", "voxels")
        grid_diag = math.sqrt(sum(((n - 1) * s) ** 2 for n, s in zip(spec.shape, spec.spacing, strict=True)))
        cell = job.solver.d_max_m if job.solver.d_max_m is not None else max(extent)
        near_grid = grid_diag + 2.0 * min(cell, diagonal)  # path length of one crossing near the grid
        if method == "beams":
            # engine/beam_field.py: per slot, (reflection groups <= 4) x (KMAH 3) x bands x points x 8 B for
            # each of the coherent (2 arrays) and incoherent (1) sums, plus two per-point arrays; Fresnel-widened
            # incoherent maps add the nearest rays' amplitude sums (1 per band) and two per-group sums
            groups = 3 * (min(job.rays.max_reflections, 3) + 1)
            widened = spec.mode == "incoherent" and getattr(spec, "incoherent_width", "tube") == "fresnel"
            arrays = {"coherent": 2, "incoherent": 2 if widened else 1}.get(spec.mode, 3)
            per_group = 3 if widened else 1
            field_bytes = (threads + 2) * n_points * (groups * n_bands * arrays + per_group * groups + 1) * 8
            chord = spec.chord_m if spec.chord_m is not None else min(max(2.0 * min(spec.spacing), 1.0), 10.0)
            # each chord deposits into the points its beam owns: on average a few per point of the grid
            # and crossing for every source (the beams of a fan tile space), plus a stencil per chord
            deposits = crossings * (4.0 * n_points * len(job.sources) + 8.0 * n_rays * near_grid / chord)
        else:
            if spec.mode == "coherent":
                groups = min(job.rays.max_reflections, 7) + 1
                field_bytes = (threads + 2) * n_points * (groups * 5 + 1) * 8
            else:
                powered = sum(1 for s in job.sources if s.power_db is not None)
                acc = n_bands * (2 if powered > 1 else 1)
                field_bytes = (threads + 2) * n_points * (acc + 1) * 8
            h = spec.sample_fraction * min(spec.spacing)
            deposits = n_rays * crossings * near_grid / h
    d_min = max(extent) / 200.0
    steps_per_ray = min(float(job.rays.max_steps), crossings * max(diagonal / d_min, 1.0))
    steps = n_rays * steps_per_ray
    eigen_steps = _eigenray_rays(job) * steps_per_ray
    # a job with conditions runs once per condition (engine/conditions.py) and keeps each condition's and
    # emission group's levels (per-point arrays, a few per band) until they are combined
    runs = max(1, len(getattr(job, "conditions", None) or []))
    if runs > 1:
        n_groups = len({s.period_offsets_db.as_tuple() if s.period_offsets_db else None for s in job.sources})
        kept = runs * n_groups * (spec.n_points * (4 * len(spec.frequencies_hz) + 4) * 8 if spec is not None else 0)
        paths, field_bytes = paths * runs, field_bytes + kept
        deposits, steps, n_rays = deposits * runs, steps * runs, n_rays * runs
    solves, seconds = shadow_cost(job)
    return CostEstimate(
        paths,
        int(field_bytes),
        n_rays * RAY_STATE_BYTES,
        float(deposits),
        float(steps),
        eigenray_steps=float(eigen_steps),
        shadow_solves=solves * runs,
        shadow_seconds=seconds * runs,
        wave_seconds=sum(wave_cost(job)[1]) * runs,
    )


def _eigenray_rays(job: Any) -> float:
    """Rays the eigenray search traces (module docstring), 0 when the job does not run it."""
    from bentray.engine.eigenray_stage import eigenray_decision

    receivers = getattr(job, "receivers", None) or []
    if not receivers or eigenray_decision(job) is not None:
        return 0.0
    pairs = len(receivers) * len(job.sources)
    rays_per_probe = 1 if job.solver.mesh_curve == "parabolic" else 5
    probes = EIGENRAY_PROBES_PER_REFLECTION * (job.rays.max_reflections + 1) * rays_per_probe
    fans = pairs + _wall_fans(job)
    return float(fans * (job.eigenrays.elevations + probes))


def _wall_fans(job: Any) -> int:
    """Wall fans of the eigenray search: (source, receiver, wall) triples that engine.eigenrays.wall_images
    accepts (the same test, vectorised over the walls), over the inline footprints' walls (a buildings file
    is not read here)."""
    import numpy as np

    from bentray.engine.eigenrays import WALL_MARGIN

    buildings = getattr(job.scene, "buildings", None)
    if buildings is None or not buildings.footprints:
        return 0
    rows = []
    for fp in buildings.footprints:
        ring = np.asarray(fp.polygon, float)[:, :2]
        if np.allclose(ring[0], ring[-1]):
            ring = ring[:-1]
        x, y = ring[:, 0], ring[:, 1]
        if float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) < 0.0:
            ring = ring[::-1]  # counter-clockwise: outside on the right of each edge
        rows.append(np.column_stack([ring, np.roll(ring, -1, axis=0)]))
    w = np.concatenate(rows)
    a, d = w[:, :2], w[:, 2:] - w[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    ok = length > 0
    a, d, length = a[ok], d[ok], length[ok]
    normal = np.column_stack([d[:, 1], -d[:, 0]]) / length[:, None]
    fans = 0
    for src in job.sources:
        s = np.array([src.position[0], src.position[1]], float)
        ds = np.einsum("ij,ij->i", s - a, normal)
        for rec in job.receivers:
            r = np.asarray(rec.horizontal, float)
            dr = np.einsum("ij,ij->i", r - a, normal)
            front = (ds > 0.0) & (dr > 0.0)
            if not np.any(front):
                continue
            img = r - 2.0 * dr[:, None] * normal
            u = ds / np.where(front, ds + dr, 1.0)
            hit = s + u[:, None] * (img - s)
            along = np.einsum("ij,ij->i", hit - a, d) / length**2
            fans += int(np.count_nonzero(front & (along >= -WALL_MARGIN) & (along <= 1.0 + WALL_MARGIN)))
    return fans


def _may_refract_upward(job: Any) -> bool:
    """False only where the job alone rules upward refraction out: no wind and a homogeneous or
    downward-refracting profile (log b >= 0, linear_c alpha >= 0, linear_n / linear_n2 alpha <= 0)."""
    if getattr(job, "wind", None) is not None:
        return True
    p = job.profile
    kind = getattr(p, "kind", None)
    if kind == "homogeneous":
        return False
    if kind == "log":
        return float(p.b) < 0.0
    if kind == "linear_c":
        return float(p.alpha) < 0.0
    if kind in ("linear_n", "linear_n2"):
        return float(p.alpha) > 0.0
    return True


def _azimuth_bins(src_xy: tuple[float, float], xy: list[tuple[float, float, float, float]]) -> int:
    """5-degree azimuth bins that boxes (xmin, ymin, xmax, ymax) cover as seen from src_xy (72 when a box
    holds the source): an upper count from the box corners."""
    bins: set[int] = set()
    for x0, y0, x1, y1 in xy:
        if x0 <= src_xy[0] <= x1 and y0 <= src_xy[1] <= y1:
            return 72
        az = [math.degrees(math.atan2(y - src_xy[1], x - src_xy[0])) for x in (x0, x1) for y in (y0, y1)]
        lo, hi = min(az), max(az)
        if hi - lo > 180.0:  # the box straddles the -x axis
            az = [a + 360.0 if a < 0 else a for a in az]
            lo, hi = min(az), max(az)
        bins.update(range(math.floor(lo / 5.0), math.ceil(hi / 5.0) + 1))
    return min(len(bins), 72)


def shadow_cost(job: Any, apply_auto: bool = True) -> tuple[int, float]:
    """(wavenumber integrals, estimated seconds) of the refractive-shadow stage (module docstring); (0, 0)
    where it will not run, including (``apply_auto``) 'auto' above SHADOW_AUTO_MAX_SOLVES or
    SHADOW_AUTO_MAX_SECONDS."""
    from bentray.engine.acoustics.wavenumber import ffp_cells

    spec = job.field
    setting = getattr(spec, "refractive_shadow", "auto") if spec is not None else "auto"
    has_field = spec is not None and getattr(spec, "method", "voxels") == "beams"
    receivers = list(getattr(job, "receivers", None) or [])
    if setting == "off" or not (has_field or receivers) or not _may_refract_upward(job):
        return 0, 0.0
    bands = [float(f) for f in spec.frequencies_hz] if spec is not None else [63.0 * 2**i for i in range(8)]
    boxes = []
    if has_field:
        lo = spec.origin
        hi = [o + (n - 1) * d for o, n, d in zip(spec.origin, spec.shape, spec.spacing, strict=True)]
        boxes.append((lo[0], lo[1], hi[0], hi[1]))
    boxes += [(x, y, x, y) for x, y in (r.horizontal for r in receivers)]
    solves, seconds = 0, 0.0
    for src in job.sources:
        sx, sy = float(src.position[0]), float(src.position[1])
        bins = _azimuth_bins((sx, sy), boxes) if job.wind is not None else 1
        r_max = max(math.hypot(x - sx, y - sy) for x0, y0, x1, y1 in boxes for x in (x0, x1) for y in (y0, y1))
        r_max = max(r_max, 1.0) + 10.0
        top = min(2000.0, 0.25 * r_max + 20.0)
        solves += bins * len(bands)
        seconds += bins * sum(ffp_cells(f, 340.0, 2.0, r_max, top) for f in bands) * SHADOW_SECONDS_PER_CELL
    if apply_auto and setting == "auto" and (solves > SHADOW_AUTO_MAX_SOLVES or seconds > SHADOW_AUTO_MAX_SECONDS):
        return 0, 0.0
    return solves, seconds


_WAVE_WIND_KINDS = ("log",)  # horizontally uniform winds (the ridge wind varies along x)


def wave_blockers(job: Any) -> list[str]:
    """Why the wave-field stage (engine/wave_stage.py) cannot apply to the job: [] for a range-independent
    scene (flat ground of one material, no terrain, buildings, barriers, obstacles or ground zones, an open
    top, a stratified profile, no wind or a log-law wind, omnidirectional sources) with a beam field (any
    mode: incoherent maps get band averages, :func:`wave_frequencies`)."""
    out: list[str] = []
    spec = job.field
    if spec is None or getattr(spec, "method", "beams") != "beams":
        out.append("it needs a beam field (field with method 'beams')")
    scene = job.scene
    if scene.builtin is not None or scene.terrain is not None:
        out.append("the scene has terrain (the integral needs flat ground)")
    b = scene.buildings
    if b is not None and (b.file or b.footprints or b.obstacles or b.barriers or b.barriers_file):
        out.append("the scene has buildings, barriers or obstacles (range-dependent)")
    if scene.ground_zones is not None:
        out.append("the scene has ground zones (the integral needs one ground material)")
    if scene.top.kind != "open":
        out.append("scene.top is 'reflect' (the integral's top absorbs)")
    if getattr(job.profile, "kind", None) not in _STRATIFIED_KINDS:
        out.append(f"profile kind {getattr(job.profile, 'kind', None)!r} is not stratified (range-dependent)")
    if job.wind is not None and getattr(job.wind, "kind", None) not in _WAVE_WIND_KINDS:
        out.append(f"wind kind {job.wind.kind!r} varies along the ground (range-dependent)")
    if any(s.directivity is not None for s in job.sources):
        out.append("a source has a directivity (the integral is of an omnidirectional point source)")
    return out


def _wave_boxes(job: Any) -> tuple[float, float]:
    """(largest horizontal range from any source to the field's corners or a receiver + 10 m, highest field
    point above the domain bottom) in metres."""
    spec = job.field
    lo = [float(v) for v in spec.origin]
    hi = [o + (n - 1) * d for o, n, d in zip(spec.origin, spec.shape, spec.spacing, strict=True)]
    r_max = 1.0
    for src in job.sources:
        sx, sy = float(src.position[0]), float(src.position[1])
        r_max = max(r_max, *(math.hypot(x - sx, y - sy) for x in (lo[0], hi[0]) for y in (lo[1], hi[1])))
        for rec in getattr(job, "receivers", None) or []:  # the stage evaluates the receivers too
            r_max = max(r_max, math.hypot(rec.horizontal[0] - sx, rec.horizontal[1] - sy))
    z_hi = hi[2] if spec.heights == "above_ground" else hi[2] - float(job.scene.box.min[2])
    return r_max + 10.0, max(z_hi, 0.0)


def wave_frequencies(job: Any, f_hz: float) -> list[float]:
    """The frequencies (Hz) whose wavenumber integrals the wave-field stage runs for the band ``f_hz``: the
    band's Gauss nodes (engine/acoustics/wave_field.band_nodes, ``field.wave_band_points`` of them) where the
    map is incoherent or the job has receivers (their incoherent columns), plus the band's own frequency where
    a coherent or semicoherent map or the receivers' coherent columns need it and it is not a node (even
    counts); the band's frequency alone for a coherent or semicoherent map without receivers."""
    from bentray.engine.acoustics.wave_field import band_nodes

    spec = job.field
    inc_map = spec.mode == "incoherent"
    with_rec = bool(getattr(job, "receivers", None))
    if not (inc_map or with_rec):
        return [float(f_hz)]
    nodes = [float(x) for x in band_nodes(float(f_hz), spec.wave_band, int(spec.wave_band_points))[0]]
    if (not inc_map or with_rec) and min(abs(x - f_hz) for x in nodes) > 1e-9 * f_hz:
        nodes.append(float(f_hz))
    return nodes


def wave_cost(job: Any) -> tuple[list[float], list[float]]:
    """(bands, estimated seconds per band) of the wave-field stage as it would run: 'auto' takes the bands
    lowest first while their seconds add up to WAVE_AUTO_MAX_SECONDS (none in homogeneous air without
    wind, where the beams are exact), 'on' every band, 'off' or a job it
    cannot apply to (:func:`wave_blockers`) none. Per band: sources x azimuth bins (5 degrees, with wind)
    x the sum over :func:`wave_frequencies` (one frequency, or the band's Gauss nodes for band averages) of
    ``ffp_cells`` (f^2 x range x top) x WAVE_SECONDS_PER_CELL, the top max(0.3 x range + 20 m,
    2 x the highest point + 20 m, 40 wavelengths) (the stage's own rule, engine/acoustics/wave_field.py, is
    at most this for the profiles of the tests: 66 m for linear c = 340 + 0.1 z to 1 km)."""
    from bentray.engine.acoustics.wavenumber import ffp_cells

    spec = job.field
    setting = getattr(spec, "wave_model", "off") if spec is not None else "off"
    if setting == "off" or wave_blockers(job):
        return [], []
    if setting == "auto" and job.wind is None and getattr(job.profile, "kind", None) == "homogeneous":
        return [], []  # homogeneous air: the beams are the image-source field (nothing to correct)
    r_max, z_hi = _wave_boxes(job)
    bands = sorted(float(f) for f in spec.frequencies_hz)
    boxes = [(float(spec.origin[0]), float(spec.origin[1]), *(o + (n - 1) * d for o, n, d in
             zip(spec.origin[:2], spec.shape[:2], spec.spacing[:2], strict=True)))]  # fmt: skip
    out_b: list[float] = []
    out_s: list[float] = []
    total = 0.0
    for f in bands:
        sec = 0.0
        for fi in wave_frequencies(job, f):
            top = min(2000.0, max(0.3 * r_max + 20.0, 2.0 * z_hi + 20.0, 40.0 * 340.0 / fi))
            for src in job.sources:
                bins = _azimuth_bins((float(src.position[0]), float(src.position[1])), boxes) if job.wind else 1
                zs = float(src.position[2]) - float(job.scene.box.min[2]) if len(src.position) == 3 else 2.0
                sec += bins * ffp_cells(fi, 340.0, max(zs, 0.0), r_max, top) * WAVE_SECONDS_PER_CELL
        if setting == "auto" and total + sec > WAVE_AUTO_MAX_SECONDS:
            break
        total += sec
        out_b.append(f)
        out_s.append(sec)
    return out_b, out_s


@dataclass(frozen=True)
class MeshEstimate:
    """The media-mesh build of a job: mesher ("tets", "terrain", or "none" when no 3D mesh is built or it
    is not estimated), estimated cells and seconds, and how the cells were counted (``basis``).
    ``known`` is False when a file the estimate needs was not at hand."""

    mesher: str
    cells: float
    seconds: float
    basis: str
    known: bool = True


def _needs_file(spec: Any) -> bool:
    """True when a profile spec (or its base) reads a file (``path``)."""
    while spec is not None:
        if getattr(spec, "path", None) is not None:
            return True
        spec = getattr(spec, "base", None)
    return False


def _none(basis: str, known: bool = True) -> MeshEstimate:
    return MeshEstimate("none", 0.0, 0.0, basis, known)


def _mesh_time(mesher: str, cells: float, basis: str) -> MeshEstimate:
    return MeshEstimate(mesher, float(cells), float(cells) * MESH_SECONDS_PER_CELL[mesher], basis)


def estimate_mesh(job: Any, base_dir: str | Path | None = None) -> MeshEstimate:
    """Cells and build seconds of the job's media mesh (module docstring); nothing is meshed. A job with
    ``conditions`` builds one mesh per distinct medium (engine/conditions.py): their cells and seconds add.
    """
    conditions = getattr(job, "conditions", None) or []
    if not conditions:
        return _estimate_one_mesh(job, base_dir)
    from bentray.scenes.condition_models import condition_job, medium_key

    media: dict[str, Any] = {}
    for cond in conditions:
        cjob = condition_job(job, cond)
        media.setdefault(medium_key(cjob), cjob)
    parts = [_estimate_one_mesh(cjob, base_dir) for cjob in media.values()]
    return MeshEstimate(
        parts[0].mesher,
        float(sum(p.cells for p in parts)),
        float(sum(p.seconds for p in parts)),
        f"{len(parts)} media meshes (one per distinct condition medium): " + "; ".join(p.basis for p in parts),
        all(p.known for p in parts),
    )


def _estimate_one_mesh(job: Any, base_dir: str | Path | None = None) -> MeshEstimate:
    """Cells and build seconds of one media mesh (module docstring); nothing is meshed.

    ``base_dir``: the folder of the files the job names (None: files are not read, and a job whose
    profile or terrain is a file gets ``known=False``).
    """
    import numpy as np

    from bentray.engine.constants import CURVE_QUANTITY
    from bentray.engine.errors import JobInputError
    from bentray.engine.media import DEFAULT_SLAB_D_MIN, DEFAULT_TET_D_MAX_FRACTION, _sizing_params

    solver = job.solver
    if solver.is_baseline and solver.media == "exact":
        return _none("exact media: one box cell")
    box = job.scene.box
    lo = np.asarray(box.min, float)
    hi = np.asarray(box.max, float)
    ext = hi - lo
    extent = float(np.max(ext))
    quantity = CURVE_QUANTITY[solver.mesh_curve]
    scene = job.scene
    surfaces = _builtin_surfaces(scene)
    if (surfaces is not None and surfaces.obstacles) or (scene.buildings is not None and _has_obstacles(scene)):
        return _none("obstacle meshes (fTetWild) are not estimated")
    have_files = base_dir is not None
    profile = wind = None
    if not _needs_file(job.profile) or have_files:
        profile, wind = _media(job, base_dir)
    if scene.has_surfaces:
        native = None
        if surfaces is not None and surfaces.terrain is not None:
            from bentray.engine.media import _native_spacing

            native = _native_spacing(surfaces)
        elif scene.terrain is not None:
            if not have_files:
                return _none("terrain file: estimated once it is uploaded", known=False)
            native = _terrain_file_spacing(job, base_dir)
        h = native if native is not None else extent * DEFAULT_TET_D_MAX_FRACTION / 4.0
        if solver.d_max_m is not None:
            h = min(h, float(solver.d_max_m))
        triangles = min(2.0 * float(ext[0] * ext[1]) / (h * h), 2.0 * FCC_MAX_POINTS)
        if scene.buildings is not None or (surfaces is not None and surfaces.footprints):
            triangles *= BUILDINGS_TRIANGLE_FACTOR
        if profile is None:
            return _none("profile file: estimated once it is uploaded", known=False)
        try:
            _, tol, _, d_max = _sizing_params(solver, "tets", extent)
        except JobInputError:
            return _none("invalid sizing (refused by the mesher)")
        v_min = solver.d_min_m if solver.d_min_m is not None else DEFAULT_SLAB_D_MIN * 1e3
        layers = _column_layers(profile, wind, solver, quantity, lo, hi, tol, v_min, d_max)
        cells = 3.0 * triangles * layers
        return _mesh_time("terrain", cells, f"{triangles:,.0f} triangles (spacing {h:.3g} m) x {layers} layers x 3")
    kind = str(getattr(job.profile, "kind", ""))
    stratified = kind in _STRATIFIED_KINDS and (job.wind is None or job.wind.kind != "ridge")
    if solver.representation in ("uniform", "slabs") or (solver.representation == "auto" and stratified):
        return _none("no 3D mesh (uniform or slab media)")
    if profile is None:
        return _none("profile file: estimated once it is uploaded", known=False)
    from bentray.engine.mesh.fcc import FCC_DENSITY, clamped_spacing, estimate_point_count
    from bentray.engine.mesh.sizing import sizing_grid_spacing
    from bentray.engine.wind import sizing_quantity

    try:
        rule, tol, d_min, d_max = _sizing_params(solver, "tets", extent)
    except JobInputError:
        return _none("invalid sizing (refused by the mesher)")

    def quantity_at(p: Any) -> Any:
        return profile.quantity(quantity, p)

    size_q = sizing_quantity(profile.sound_speed, profile.c_ref, wind, quantity) if wind is not None else quantity_at
    size_n = (
        sizing_quantity(profile.sound_speed, profile.c_ref, wind, "n")
        if wind is not None
        else (lambda p: profile.quantity("n", p))
    )
    native_step = getattr(profile, "spacing", None)
    grid_step = float(np.min(native_step)) if native_step is not None and np.ndim(native_step) == 1 else None
    # the engine's sizing grid has up to 1e6 nodes; ESTIMATE_NODES keep this estimate well under a second
    coarse = float(np.prod(ext) / ESTIMATE_NODES) ** (1.0 / 3.0)
    grid_step = max(grid_step if grid_step is not None else 0.5 * d_min, coarse)
    spacing = sizing_grid_spacing(
        size_q, size_n, lo, hi, rule=rule, tolerance=tol, d_min=d_min, d_max=d_max, grid_step=grid_step
    )
    points = estimate_point_count(lo, hi, clamped_spacing(spacing, d_min, d_max), FCC_DENSITY)
    capped = min(points, float(FCC_MAX_POINTS))
    return _mesh_time(
        "tets",
        capped * TET_CELLS_PER_POINT,
        f"{points:,.0f} FCC points (sizing {rule} {tol:g}, d {d_min:.3g}-{d_max:.3g} m) x {TET_CELLS_PER_POINT:g}",
    )


def _builtin_surfaces(scene: Any) -> Any:
    if scene.builtin is None:
        return None
    from bentray.scenes.library.registry import get_builtin

    return get_builtin(scene.builtin, scene.resolution).surfaces


def _has_obstacles(scene: Any) -> bool:
    return bool(getattr(scene.buildings, "obstacles", None))


def _media(job: Any, base_dir: str | Path | None) -> tuple[Any, Any]:
    from bentray.engine.stages import StageLog, stage_profile

    try:
        return stage_profile(job, Path(base_dir) if base_dir is not None else None, StageLog())
    except (ValueError, OSError):  # a file that cannot be read: its own check says why
        return None, None


def _terrain_file_spacing(job: Any, base_dir: str | Path | None) -> float | None:
    from bentray.engine.media import _native_spacing
    from bentray.engine.stages import load_surfaces

    try:
        surfaces = load_surfaces(job, Path(base_dir) if base_dir is not None else None)
    except (ValueError, OSError):
        return None
    return _native_spacing(surfaces) if surfaces is not None else None


def _column_layers(
    profile: Any, wind: Any, solver: Any, quantity: str, lo: Any, hi: Any, tol: float, v_min: float, d_max: float
) -> int:
    """Layers of the terrain mesher's column (engine/media.build_terrain_media's rule, same parameters)."""
    import numpy as np

    from bentray.engine.mesh.sizing import curvature_layers, gradient_layers
    from bentray.engine.wind import sizing_quantity

    column = getattr(profile, "base", profile)
    qfn = sizing_quantity(profile.sound_speed, profile.c_ref, wind, quantity) if wind is not None else None
    centre = 0.5 * (lo + hi)

    def at(z: Any, fn: Any) -> Any:
        z = np.atleast_1d(np.asarray(z, float))
        return fn(np.column_stack([np.full(len(z), centre[0]), np.full(len(z), centre[1]), z]))

    try:
        if solver.effective_sizing == "gradient":
            levels = gradient_layers(
                lo[2], hi[2], lambda z: at(z, lambda p: profile.quantity("n", p)), epsilon=tol, d_min=v_min, d_max=d_max
            )
        else:
            fn = qfn or (lambda p: column.quantity(quantity, p))
            levels = curvature_layers(lo[2], hi[2], lambda z: at(z, fn), delta=tol, d_min=v_min, d_max=d_max)
    except ValueError:  # more than MAX_LAYERS: the mesher refuses it too
        return 2_000_000
    return max(len(levels) - 1, 1)


def mesh_problems(job: Any, limits: CostLimits, base_dir: str | Path | None = None) -> list[str]:
    """A ``field.path: reason`` line when the estimated mesh build exceeds ``limits.mesh_seconds``."""
    est = estimate_mesh(job, base_dir)
    if not est.known or est.seconds <= limits.mesh_seconds:
        return []
    if est.mesher == "tets":
        field, hint = "solver.d_min_m", "raise solver.d_min_m or the sizing tolerance (solver.delta / solver.epsilon)"
    else:
        field, hint = "solver.d_max_m", "use a coarser solver.d_max_m, a coarser terrain or a smaller domain"
    per = 1e6 * MESH_SECONDS_PER_CELL[est.mesher]
    return [
        f"{field}: the {est.mesher} mesh needs an estimated {est.cells:.3g} cells ({est.basis}), about "
        f"{est.seconds:.3g} s to build at {per:g} us per cell; the limit is {limits.mesh_seconds:g} s: {hint}"
    ]


def _gb(n: float) -> str:
    return f"{n / 2**30:.3g} GiB"


def cost_problems(job: Any, limits: CostLimits, base_dir: str | Path | None = None) -> list[str]:
    """``field.path: reason`` lines for every budget of ``limits`` the job's estimate exceeds (the mesh
    build: only where no file is needed unless ``base_dir`` resolves the job's files, see
    :func:`mesh_problems`)."""
    est = estimate_cost(job, limits.threads)
    lines: list[str] = []
    if est.memory_bytes > limits.memory_bytes:
        parts = {"paths": est.paths_bytes, "field": est.field_bytes, "rays": est.rays_bytes}
        biggest = max(parts, key=lambda k: parts[k])
        field = {"paths": "rays.record_paths", "field": "field.shape", "rays": "rays"}[biggest]
        hint = {
            "paths": "set rays.record_paths to false, or lower solver.path_samples or the ray count",
            "field": "use fewer field points or bands (split the map into tiles)",
            "rays": "use fewer rays",
        }[biggest]
        lines.append(
            f"{field}: the job needs an estimated {_gb(est.memory_bytes)} of memory (paths {_gb(est.paths_bytes)}, "
            f"field {_gb(est.field_bytes)} for {limits.threads} threads, rays {_gb(est.rays_bytes)}); the limit "
            f"is {_gb(limits.memory_bytes)}: {hint}"
        )
    if est.field_deposits > limits.field_deposits:
        lines.append(
            f"field.spacing: an estimated {est.field_deposits:.3g} field samples (rays x grid crossings x path "
            f"length near the grid / (sample_fraction x smallest spacing)); the limit is "
            f"{limits.field_deposits:.3g}: use a coarser spacing, a larger field.sample_fraction or fewer rays"
        )
    if est.ray_steps > limits.ray_steps:
        lines.append(
            f"rays: an estimated {est.ray_steps:.3g} cell crossings (rays x domain crossings x diagonal / smallest "
            f"cell); the limit is {limits.ray_steps:.3g}: use fewer rays, fewer reflections, a shorter "
            "max_time_s or a larger solver.d_min_m"
        )
    if est.eigenray_steps > limits.ray_steps:
        lines.append(
            f"eigenrays.enabled: the eigenray search needs an estimated {est.eigenray_steps:.3g} cell crossings "
            f"(source-receiver pairs x (eigenrays.elevations + {EIGENRAY_PROBES_PER_REFLECTION} probes per "
            f"reflection allowed) x crossings per ray); the limit is {limits.ray_steps:.3g}: use fewer receivers, "
            "fewer eigenrays.elevations or rays.max_reflections, or set eigenrays.enabled to 'off'"
        )
    if est.shadow_seconds > limits.shadow_seconds:
        lines.append(
            f"field.refractive_shadow: the refractive-shadow stage needs an estimated {est.shadow_solves} "
            f"wavenumber integrals (sources x bands x 5-degree azimuth bins with wind), about "
            f"{est.shadow_seconds:.3g} s (f^2 x range x top height cells at {SHADOW_SECONDS_PER_CELL:g} s each); "
            f"the limit is {limits.shadow_seconds:g} s: use 'auto' (skips the stage above its limit), 'off', "
            "fewer or lower bands, fewer sources or a smaller map"
        )
    if est.wave_seconds > limits.wave_seconds:
        lines.append(
            f"field.wave_model: the wave-field stage needs an estimated {est.wave_seconds:.3g} s (sources x bands x "
            f"azimuth bins wavenumber integrals, f^2 x range x top height cells at {WAVE_SECONDS_PER_CELL:g} s "
            f"each); the limit is {limits.wave_seconds:g} s: use 'auto' (the bands that fit), 'off', fewer or "
            "lower bands, fewer sources or a smaller map"
        )
    lines.extend(mesh_problems(job, limits, base_dir))
    return lines

"""The refractive-shadow stage: levels where upward refraction (or upwind propagation) leaves the ground
in a ray-theory shadow, from the field diffracted along the ground (creeping waves, computed by the
wavenumber integral of the source column's profile) plus turbulent scattering
(:func:`bentray.engine.acoustics.refractive_shadow.refractive_shadow_energy`), merged into the field after
the diffraction stage.

Per source, per point: the model's energy (creeping wave + scattering, relative to the 1 m free field)
where the point lies beyond the limiting ray of the source's effective sound-speed column (its
``applies`` mask). The sources' energies add (``powered`` with each source's power).

Merge without double counting (:func:`bentray.engine.field_sources.combine`, mode "replace"): at a shadow
point and band the level becomes the larger of the two estimates of the same field, the beam/diffraction
level (beams leak a little past the limiting ray, and are right near it) and the shadow model (right
deep in the shadow, where the beams have nothing). The two are equal where they cross, so the merged
level is continuous; the lit zone (no ``applies``) is untouched. With several sources a point keeps the
larger of the two totals (exact for one source). Skipped when no source sees upward refraction in any
direction that reaches the points.

Limits stated: the model is stratified and flat-ground (heights above the local ground under each point
and under the source); terrain and buildings shadow through the diffraction stage, not here.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from bentray.engine.acoustics.refractive_shadow import refractive_shadow_energy, upward_refracting
from bentray.engine.acoustics.weighting import a_weighting_db
from bentray.engine.diffraction.stage import _field_points, _ground
from bentray.engine.field_sources import COMBINATION, NONE, REFRACTIVE_SHADOW, Contribution, combine
from bentray.engine.field_sources import counts as source_counts
from bentray.scenes.cost import SHADOW_AUTO_MAX_SECONDS, SHADOW_AUTO_MAX_SOLVES, shadow_cost

__all__ = ["SHADOW_AUTO_MAX_SOLVES", "stage_refractive_shadow"]

_LAST_RUN: dict[str, float] = {}  # the wavenumber integrals' top (m) and cells of the last energy call (report)
_AZIMUTH_BIN_DEG = 5.0  # refractive_shadow_energy's default azimuth bin with wind
_AZIMUTH_PROBES = 36  # directions tested for upward refraction when deciding whether the stage is needed


def _needed(job: Any, profile: Any, wind: Any, ground_z: Any) -> bool:
    if profile.kind == "homogeneous" and wind is None:
        return False
    az = np.linspace(0.0, 360.0, _AZIMUTH_PROBES, endpoint=False) if wind is not None else np.array([0.0])
    for src in job.sources:
        s = np.asarray(src.position, float)
        g = float(ground_z(s[None, :2])[0])
        if np.any(upward_refracting(profile, s, g, az, wind)):
            return True
    return False


def _mode_solves(job: Any, wind: Any, field_arrays: Any, setup: Any) -> int:
    """Upper estimate of the stage's wavenumber integrals: per source, bands x the 5-degree azimuth bins the points
    cover (one bin without wind)."""
    pts = []
    if field_arrays is not None:
        pts.append(np.asarray(field_arrays.grid.points(), float)[:, :2])
    if setup.receivers_xyz is not None:
        pts.append(np.asarray(setup.receivers_xyz, float)[:, :2])
    if not pts:
        return 0
    xy = np.concatenate(pts)
    n_f = len(job.field.frequencies_hz) if job.field is not None else 8
    total = 0
    for src in job.sources:
        bins = 1
        if wind is not None:
            d = xy - np.asarray(src.position, float)[None, :2]
            az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
            bins = int(np.unique(np.round(az / _AZIMUTH_BIN_DEG)).size)
        total += bins * n_f
    return total


def _shadow_energy(
    job: Any, profile: Any, wind: Any, pts: np.ndarray, f_hz: np.ndarray, ground_z: Any, sigma: float | None,
    powers: np.ndarray | None, no_creep: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:  # fmt: skip
    """(rel (F, V), powered (F, V) W/m^2 or None, applies (V,)) summed over the sources; in the bands of
    ``no_creep`` (F,) bool (those the wave-field stage produced) the scattered part alone (0 without
    turbulence), no wavenumber integral."""
    n_f, n = f_hz.size, pts.shape[0]
    rel = np.zeros((n_f, n))
    powered = np.zeros((n_f, n)) if powers is not None else None
    applies = np.zeros(n, bool)
    turb = job.turbulence
    t = (float(turb.c_t2), float(turb.c_v2)) if turb is not None else None
    gz = ground_z(pts[:, :2])
    _LAST_RUN.update(z_top_m=0.0, cells=0)
    for s, src in enumerate(job.sources):
        xyz = np.asarray(src.position, float)
        sg = float(ground_z(xyz[None, :2])[0])
        skip = np.zeros(n_f, bool) if no_creep is None else np.asarray(no_creep, bool)
        for rows, creeping in ((~skip, True), (skip, False)):
            if not rows.any() or (not creeping and t is None):
                continue
            sf = refractive_shadow_energy(profile, xyz, pts, gz, sg, sigma, f_hz[rows], t, wind, creeping=creeping)
            _LAST_RUN["z_top_m"] = max(_LAST_RUN["z_top_m"], sf.z_top_m)
            _LAST_RUN["cells"] += sf.cells
            rel[rows] += sf.energy_rel
            if powered is not None and powers is not None:
                powered[rows] += sf.energy_rel * (powers[s][rows][:, None] / (4.0 * math.pi))
            applies |= sf.applies
    return rel, powered, applies


def _weight(old_rel: np.ndarray, new_rel: np.ndarray, applies: np.ndarray) -> np.ndarray:
    """(F, V) 1 where the point is in a shadow and the shadow model's level is the larger."""
    old = np.where(np.isfinite(old_rel), old_rel, 0.0)
    return (applies[None, :] & (new_rel > old)).astype(float)


def _codes(old: np.ndarray, w: np.ndarray, had_level: np.ndarray) -> np.ndarray:
    every = w.min(axis=0) >= 1.0
    some = w.max(axis=0) > 0.0
    code = np.where(every, REFRACTIVE_SHADOW, np.where(some & had_level, COMBINATION, old))
    code = np.where(some & ~had_level & ~every, REFRACTIVE_SHADOW, code)
    return code.astype(np.uint8)


def _rel_of(arrays: dict[str, np.ndarray], labels: list[str]) -> np.ndarray:
    tl = np.stack([np.asarray(arrays[f"tl_{lab}hz"], float).reshape(-1) for lab in labels])
    return np.where(np.isfinite(tl), 10.0 ** (-tl / 10.0), 0.0)


Energy = tuple[np.ndarray, np.ndarray | None, np.ndarray]


def _apply_field(
    job: Any, profile: Any, wind: Any, surfaces: Any, setup: Any, field_arrays: Any, energy: Energy | None = None,
    done: Any = frozenset(),
) -> dict[str, Any]:  # fmt: skip
    spec = job.field
    ground_z, sigma = _ground(job, surfaces)
    labels = list(spec.labels)
    f_hz = np.asarray(spec.frequencies_hz, float)
    solid = np.asarray(field_arrays.arrays["inside_solid"], bool).reshape(-1)
    if energy is None:
        pts = _field_points(job, field_arrays, ground_z)
        no_creep = np.array([lab in done for lab in labels])
        energy = _shadow_energy(job, profile, wind, pts, f_hz, ground_z, sigma, setup.powers, no_creep)
    rel_new, powered, applies = energy
    applies &= ~solid
    old_rel = _rel_of(field_arrays.arrays, labels)
    w = _weight(old_rel, rel_new, applies)
    old_code = np.asarray(field_arrays.arrays["field_source"]).reshape(-1)
    contribs = [Contribution(REFRACTIVE_SHADOW, rel_new, w, powered=powered)]
    wave_rows = np.array([lab in done for lab in labels])
    if wave_rows.any():  # the wave field's bands: rel_new is the scattered part alone there, added
        w[wave_rows] = 0.0
        ws = (wave_rows[:, None] & applies[None, :] & (rel_new > 0)).astype(float)
        contribs.append(Contribution(REFRACTIVE_SHADOW, rel_new, ws, powered=powered, mode="add"))
        w = np.maximum(w, ws)  # for the codes
    coherent = spec.mode != "incoherent"
    combine(field_arrays.arrays, labels, np.asarray(a_weighting_db(f_hz), float), contribs, coherent, solid)
    code = _codes(old_code, w, old_rel.max(axis=0) > 0)
    code[solid] = NONE
    field_arrays.arrays["field_source"] = code.reshape(field_arrays.grid.shape)
    counts = source_counts(code, solid)
    field_arrays.stats["field_source"] = counts
    return {"points_in_shadow": int(np.count_nonzero(applies)), "field_source": counts}


def _apply_receivers(
    job: Any, profile: Any, wind: Any, surfaces: Any, setup: Any, receivers: Any, energy: Energy | None = None
) -> dict[str, Any]:
    from bentray.engine.field_sources import combine_receiver_rows

    ground_z, sigma = _ground(job, surfaces)
    f_hz = np.asarray(receivers.stats["frequencies_hz"], float)
    labels = [c[len("tl_inc_") : -2] for c in receivers.columns if c.startswith("tl_inc_")]
    if energy is None:
        pts = np.asarray(setup.receivers_xyz, float)
        energy = _shadow_energy(job, profile, wind, pts, f_hz, ground_z, sigma, setup.powers)
    rel_new, powered, applies = energy
    old_code = np.array([r.get("field_source", NONE) for r in receivers.rows], np.uint8)
    conts = []
    ws = []
    for kind in ("coh", "inc"):
        old = np.stack([[r[f"tl_{kind}_{lab}hz"] for r in receivers.rows] for lab in labels]).astype(float)
        old_rel = np.where(np.isfinite(old), 10.0 ** (-old / 10.0), 0.0)
        w = _weight(old_rel, rel_new, applies)
        ws.append((w, old_rel.max(axis=0) > 0))
        conts.append(Contribution(REFRACTIVE_SHADOW, rel_new, w, powered=powered))
    combine_receiver_rows(receivers.rows, labels, np.asarray(a_weighting_db(f_hz), float), [conts[0]], [conts[1]])
    code = _codes(old_code, *ws[1])
    for i, r in enumerate(receivers.rows):
        r["field_source"] = int(code[i])
    receivers.stats["field_source"] = source_counts(code)
    return {"in_shadow": int(np.count_nonzero(applies)), "field_source": source_counts(code)}


def stage_refractive_shadow(
    job: Any, profile: Any, wind: Any, surfaces: Any, setup: Any, field_arrays: Any, receivers: Any, log: Any,
    field_done_labels: Any = (),
) -> dict[str, Any] | None:  # fmt: skip
    """Run the stage on the field arrays and receiver rows in place (module docstring); returns the
    report's ``refractive_shadow`` section (None when skipped; the reason is in log.stages).
    field_done_labels: band labels the wave-field stage (engine/wave_stage.py) produced on the field grid;
    the integral there already holds the shadow's creeping waves, so this stage leaves those bands of the
    map alone unless turbulence is given (then it adds only the scattered part there); receivers keep all."""
    done = set(field_done_labels)
    if field_arrays is None and receivers is None:
        log.stages["refractive_shadow"] = "skipped: no field and no receivers"
        return None
    if field_arrays is not None and "field_source" not in field_arrays.arrays:
        log.stages["refractive_shadow"] = "skipped: voxel fields carry no per-point source codes"
        return None
    setting = job.field.refractive_shadow if job.field is not None else "auto"
    if setting == "off":
        log.stages["refractive_shadow"] = "skipped: field.refractive_shadow is 'off'"
        return None
    ground_z, _ = _ground(job, surfaces)
    if not _needed(job, profile, wind, ground_z):
        log.stages["refractive_shadow"] = "skipped: no upward refraction from any source (no refractive shadow); " + (
            "turbulence given but unused" if job.turbulence is not None else "turbulence off"
        )
        return None
    if done and field_arrays is not None and done >= set(job.field.labels):
        if job.turbulence is None and receivers is None:
            log.stages["refractive_shadow"] = (
                "skipped: the wave-field stage produced every band of the map (its integral includes the shadow)"
            )
            return None
    solves = _mode_solves(job, wind, field_arrays, setup)
    if setting == "auto" and solves > SHADOW_AUTO_MAX_SOLVES:
        log.stages["refractive_shadow"] = (
            f"skipped: about {solves} wavenumber integrals (sources x bands x azimuth bins) is over the 'auto' "
            f"limit of {SHADOW_AUTO_MAX_SOLVES}; set field.refractive_shadow to 'on' to run it"
        )
        return None
    if setting == "auto":
        _, seconds = shadow_cost(job, apply_auto=False)
        if seconds > SHADOW_AUTO_MAX_SECONDS:
            log.stages["refractive_shadow"] = (
                f"skipped: an estimated {seconds:.3g} s (~ f^2 x range x height per integral) is over the 'auto' "
                f"limit of {SHADOW_AUTO_MAX_SECONDS:g} s; set field.refractive_shadow to 'on' to run it"
            )
            return None
    t0 = time.perf_counter()
    out: dict[str, Any] = {
        "method": "creeping waves (wavenumber integral of the source column's profile) + turbulent scattering",
        "turbulence": job.turbulence.model_dump() if job.turbulence is not None else None,
    }
    with_rec = receivers is not None and setup.receivers_xyz is not None
    e_field = e_rec = None
    if field_arrays is not None and with_rec and not done:
        f_hz = np.asarray(job.field.frequencies_hz, float)
        if np.array_equal(f_hz, np.asarray(receivers.stats["frequencies_hz"], float)):
            # one wavenumber integral per band for the map and the receivers together
            ground_z, sigma = _ground(job, surfaces)
            pts = _field_points(job, field_arrays, ground_z)
            n = pts.shape[0]
            both = np.concatenate([pts, np.asarray(setup.receivers_xyz, float)])
            rel, powered, applies = _shadow_energy(job, profile, wind, both, f_hz, ground_z, sigma, setup.powers)
            e_field = (rel[:, :n], None if powered is None else powered[:, :n], applies[:n])
            e_rec = (rel[:, n:], None if powered is None else powered[:, n:], applies[n:])
    if field_arrays is not None:
        out["field"] = _apply_field(job, profile, wind, surfaces, setup, field_arrays, e_field, done)
    if with_rec:
        out["receivers"] = _apply_receivers(job, profile, wind, surfaces, setup, receivers, e_rec)
    out["seconds"] = time.perf_counter() - t0
    out["z_top_m"], out["cells"] = _LAST_RUN.get("z_top_m", 0.0), _LAST_RUN.get("cells", 0)
    log.timings["refractive_shadow"] = out["seconds"]
    n = out.get("field", {}).get("points_in_shadow", 0)
    log.stages["refractive_shadow"] = f"ran: {n} field points in a refractive shadow; creeping waves" + (
        " + turbulent scattering" if job.turbulence is not None else " (turbulence off)"
    )
    return out

"""The wave-field stage: in a range-independent scene, the field of every band whose cost fits comes from the
wavenumber integral of each source's effective sound-speed column (engine/acoustics/wave_field.py), not from
the beams.

Why: ray theory (the beams, and the eigenrays they agree with) misses the wave field where rays turn a few
metres above the ground, inside their Airy transition (downward refraction: 4.8 dB at 100 Hz over 60-980 m
for the log profile b = +1), and in the penumbra next to a refractive shadow (upward refraction, 500 Hz).
The integral is exact for a stratified medium over flat impedance ground (docs/physics.md §18).

When (:func:`bentray.scenes.cost.wave_blockers`, :func:`bentray.scenes.cost.wave_cost`): ``field.wave_model``
"auto" (default) where the scene is range-independent and the map is coherent or semicoherent, for the bands,
lowest first, whose estimated seconds add up to at most WAVE_AUTO_MAX_SECONDS; "on" every band (a job it
cannot apply to is refused at validation, naming the field); "off" never. Receivers (with a field in the
job): in the stage's bands their coherent columns come from the wave field at the band's frequency (each
source's |p|^2 summed), their incoherent columns from its band averages, and the eigenray columns are the
eigenrays'.

Merge (:func:`bentray.engine.field_sources.combine`, mode "replace", weight 1): in the stage's bands, at every
field point outside solids with k r >= MIN_KR from every source (nearer a source's vertical the beams stay),
TL, p and SPL become the wave field's. Sources: mode "coherent" sums the unit-amplitude pressures (as the
beams do for TL and p); "semicoherent" adds each source's |p|^2 (each source's own field coherent, its ground
reflection included); SPL adds the sources' powered |p|^2 in both, as the beams do. field_source becomes WAVE
where every band came from it, COMBINATION where some bands did. The refractive-shadow stage then skips these
bands (the integral already holds the creeping waves of the shadow: no double counting); turbulent scattering
(``turbulence``), which the integral does not hold, is still added there in the shadow by that stage.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from bentray.engine.acoustics.wave_field import MIN_KR, wave_band_energy, wave_pressure
from bentray.engine.acoustics.weighting import a_weighting_db
from bentray.engine.diffraction.stage import _field_points, _ground
from bentray.engine.field_sources import COMBINATION, NONE, WAVE, Contribution, combine
from bentray.engine.field_sources import counts as source_counts
from bentray.scenes.cost import WAVE_AUTO_MAX_SECONDS, wave_blockers, wave_cost

__all__ = ["stage_wave_field"]


def _absorption(spec: Any) -> tuple[float, float, float] | None:
    return (
        (float(spec.temperature_c), float(spec.humidity_percent), float(spec.pressure_kpa)) if spec.absorption else None
    )


def stage_wave_field(
    job: Any, profile: Any, wind: Any, surfaces: Any, setup: Any, field_arrays: Any, receivers: Any, log: Any
) -> dict[str, Any] | None:
    """Run the stage on the field arrays in place (module docstring); returns the report's ``wave_field``
    section (with ``bands_hz``: the bands it produced) or None when skipped (the reason in log.stages)."""
    spec = job.field
    setting = spec.wave_model if spec is not None else "off"
    if field_arrays is None:
        log.stages["wave_field"] = "skipped: no field grid (receivers keep the beams and eigenrays)"
        return None
    if setting == "off":
        log.stages["wave_field"] = "skipped: field.wave_model is 'off' (beams only)"
        return None
    if "field_source" not in field_arrays.arrays:
        log.stages["wave_field"] = "skipped: voxel fields carry no per-point source codes"
        return None
    blockers = wave_blockers(job)
    if blockers:
        log.stages["wave_field"] = "skipped: " + "; ".join(blockers) + " (the beams give every band)"
        return None
    if not getattr(profile, "stratified", False):
        log.stages["wave_field"] = "skipped: the profile is not stratified (the beams give every band)"
        return None
    if setting == "auto" and wind is None and getattr(profile, "kind", None) == "homogeneous":
        log.stages["wave_field"] = "skipped: homogeneous air without wind (the beams are the image-source field)"
        return None
    bands, est = wave_cost(job)
    if not bands:
        log.stages["wave_field"] = (
            f"skipped: even the lowest band's wavenumber integral (an estimated "
            f"{wave_cost_lowest(job):.3g} s) is over the 'auto' limit of {WAVE_AUTO_MAX_SECONDS:g} s; "
            "set field.wave_model to 'on' to run it"
        )
        return None
    t0 = time.perf_counter()
    labels_all = list(spec.labels)
    f_all = np.asarray(spec.frequencies_hz, float)
    use = np.array([float(f) in bands for f in f_all])
    ground_z, sigma = _ground(job, surfaces)
    pts = _field_points(job, field_arrays, ground_z)
    srcs = np.array([np.asarray(s.position, float) for s in job.sources])
    gz = float(ground_z(srcs[:1, :2])[0])
    with_rec = receivers is not None and setup.receivers_xyz is not None and bool(receivers.rows)
    inc_map = spec.mode == "incoherent"
    n_field = pts.shape[0]
    if with_rec:  # one integral per frequency for the map and the receivers together
        pts = np.concatenate([pts, np.asarray(setup.receivers_xyz, float)])
    band_kw = {"band": spec.wave_band, "points": int(spec.wave_band_points)}
    energy = p_c = nodes = None
    if inc_map or with_rec:  # band levels (incoherent map, receivers' incoherent columns): N frequencies a band
        wb = wave_band_energy(profile, srcs, pts, gz, sigma, f_all[use], wind, centre=not inc_map or with_rec,
                              absorption=_absorption(spec), **band_kw)  # fmt: skip
        energy, p_c, valid_all, nodes = wb.energy, wb.p_centre, wb.valid, wb.frequencies_hz
        z_top, cells, band_seconds = wb.z_top_m, wb.cells, wb.seconds
    else:
        wf_all = wave_pressure(profile, srcs, pts, gz, sigma, f_all[use], wind, absorption=_absorption(spec))
        p_c, valid_all, z_top = wf_all.p, wf_all.valid, wf_all.z_top_m
        cells, band_seconds = wf_all.cells, wf_all.seconds
    pts = pts[:n_field]
    solid = np.asarray(field_arrays.arrays["inside_solid"], bool).reshape(-1)
    ok = valid_all[:, :n_field].all(axis=0) & ~solid
    n_f, n = f_all.size, pts.shape[0]
    rel = np.zeros((n_f, n))
    p_tot = None
    if inc_map:
        assert energy is not None
        per_source = energy[:, :, :n_field]  # (S, F_use, V): band means of |p|^2
        rel[use] = per_source.sum(axis=0)
    else:
        assert p_c is not None
        p_map = p_c[:, :, :n_field]
        p_tot = np.zeros((n_f, n), complex)
        p_tot[use] = p_map.sum(axis=0)
        per_source = np.abs(p_map) ** 2
        rel[use] = np.abs(p_tot[use]) ** 2 if spec.mode == "coherent" else per_source.sum(axis=0)
    powered = None
    if setup.powers is not None:
        powered = np.zeros((n_f, n))
        pw = np.asarray(setup.powers, float)[:, use]  # (S, F_use) W
        powered[use] = np.einsum("sfv,sf->fv", per_source, pw) / (4.0 * math.pi)
    w = (use[:, None] & ok[None, :]).astype(float)
    old_code = np.asarray(field_arrays.arrays["field_source"]).reshape(-1)
    contrib = Contribution(WAVE, rel, w, powered=powered, p=p_tot)
    combine(field_arrays.arrays, labels_all, np.asarray(a_weighting_db(f_all), float), [contrib],
            spec.mode == "coherent", solid)  # fmt: skip
    every = bool(use.all())
    code = np.where(ok, np.where(every | (old_code == NONE), WAVE, COMBINATION), old_code).astype(np.uint8)
    code[solid] = NONE
    field_arrays.arrays["field_source"] = code.reshape(field_arrays.grid.shape)
    counts = source_counts(code, solid)
    field_arrays.stats["field_source"] = counts
    rec = None
    if with_rec:
        assert p_c is not None and energy is not None
        rec = _apply_receivers(receivers, setup, f_all, use, p_c[:, :, n_field:], energy[:, :, n_field:],
                               valid_all[:, n_field:])  # fmt: skip
    seconds = time.perf_counter() - t0
    log.timings["wave_field"] = seconds
    n_pts = int(spec.wave_band_points)
    band_words = f"{spec.wave_band.replace('_', '-')} band averages over {n_pts} frequencies"
    what = f"the map's band levels from {band_words}" if inc_map else "the map at each band's frequency (coherent)"
    if with_rec:
        what += f"; receivers' incoherent columns from {band_words}, coherent ones at the band's frequency"
    beams_bands = [lab for lab, u in zip(labels_all, use, strict=True) if not u]
    log.stages["wave_field"] = (
        f"ran: bands {', '.join(lab for lab, u in zip(labels_all, use, strict=True) if u)} Hz from the wavenumber "
        f"integral (range-independent scene, field.wave_model '{setting}'): {what}"
        + (f"; bands {', '.join(beams_bands)} Hz keep the beams (over the 'auto' cost limit)" if beams_bands else "")
        + f"; {int(np.count_nonzero(~ok & ~solid))} points near a source's vertical (k r < {MIN_KR:g}) keep the beams"
    )
    return {
        "method": "wavenumber integral (fast field program) of each source's effective sound-speed column over the "
        "impedance ground, exact for the stratified medium",
        "bands_hz": [float(f) for f in f_all[use]],
        "beam_bands_hz": [float(f) for f in f_all[~use]],
        "map": "band average (incoherent)" if inc_map else "band frequency (coherent)",
        "band_average": None
        if nodes is None
        else {
            "band": spec.wave_band,
            "points": n_pts,
            "rule": "Gauss-Legendre in ln f over the band (IEC 61260-1 base-10 edges), mean of |p|^2",
            "used_for": (["map"] if inc_map else []) + (["receivers' incoherent columns"] if with_rec else []),
            "frequencies_hz": {f"{f:g}": [float(x) for x in row] for f, row in zip(f_all[use], nodes, strict=True)},
        },
        "estimated_seconds_per_band": {f"{f:g}": float(s) for f, s in zip(bands, est, strict=True)},
        "seconds_per_band": {f"{f:g}": float(s) for f, s in zip(f_all[use], band_seconds, strict=True)},
        "sources_sum": "coherent (pressures)" if spec.mode == "coherent" else "incoherent (each source coherent)",
        "points": int(np.count_nonzero(ok)),
        "points_kept_beams": int(np.count_nonzero(~ok & ~solid)),
        "z_top_m": z_top,
        "cells": cells,
        "seconds": seconds,
        "field_source": counts,
        "receivers": rec,
    }


def _apply_receivers(
    receivers: Any, setup: Any, f_all: np.ndarray, use: np.ndarray, p: np.ndarray, energy: np.ndarray,
    valid: np.ndarray,
) -> dict[str, Any]:  # fmt: skip
    """The receivers' columns in the stage's bands from the wave field: coherent (tl_coh_, spl_coh_, spl_a_coh)
    from each source's |p|^2 at the band's frequency, incoherent (tl_inc_, spl_inc_, spl_a_inc) from each
    source's band mean of |p|^2, both summed over sources. p (S, F_use, P) complex, energy (S, F_use, P), valid
    (S, P): the stage's integrals at the receivers; f_all (F,) the field's bands, ``use`` (F,) those the stage
    produced."""
    from bentray.engine.field_sources import combine_receiver_rows

    labels = [c[len("tl_inc_") : -2] for c in receivers.columns if c.startswith("tl_inc_")]
    f_rec = np.asarray(receivers.stats["frequencies_hz"], float)
    if not np.array_equal(f_rec, f_all):
        return {"rows": 0, "bands_hz": [], "why": "the receivers' bands differ from the map's"}
    ok = np.asarray(valid.all(axis=0), bool)
    a_w = np.asarray(a_weighting_db(f_rec), float)
    w = (use[:, None] & ok[None, :]).astype(float)
    contribs = []
    for per_source in (np.abs(p) ** 2, energy):
        rel = np.zeros((f_rec.size, ok.size))
        rel[use] = per_source.sum(axis=0)
        powered = None
        if setup.powers is not None:
            powered = np.zeros((f_rec.size, ok.size))
            pw = np.asarray(setup.powers, float)[:, use]
            powered[use] = np.einsum("sfv,sf->fv", per_source, pw) / (4.0 * math.pi)
        contribs.append(Contribution(WAVE, rel, w, powered=powered))
    code = combine_receiver_rows(receivers.rows, labels, a_w, [contribs[0]], [contribs[1]])
    receivers.stats["field_source"] = source_counts(code)
    return {"rows": int(np.count_nonzero(ok)), "bands_hz": [float(f) for f in f_rec[use]],
            "columns": "coherent (band frequency) and incoherent (band average)"}  # fmt: skip


def wave_cost_lowest(job: Any) -> float:
    """Estimated seconds of the lowest band alone (for the skip reason)."""
    from bentray.engine.acoustics.wavenumber import ffp_cells
    from bentray.scenes.cost import WAVE_SECONDS_PER_CELL, _wave_boxes

    r_max, z_hi = _wave_boxes(job)
    f = min(float(x) for x in job.field.frequencies_hz)
    top = min(2000.0, max(0.3 * r_max + 20.0, 2.0 * z_hi + 20.0, 40.0 * 340.0 / f))
    return len(job.sources) * ffp_cells(f, 340.0, 2.0, r_max, top) * WAVE_SECONDS_PER_CELL

"""The eigenray stage of a job: arrivals at every receiver (arrivals.csv) and their levels (receivers.csv).

Plain Python over :mod:`bentray.engine.eigenrays`: one search per (source, receiver), on the job's own mesh,
curve, wind and ray limits; amplitudes per band with the beam field's ground table and absorption, so
the eigenray levels and the beam levels at a receiver are computed from the same physics and can be
compared (tl_eig_* beside tl_* in receivers.csv).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from bentray.engine import beam_field
from bentray.scenes.directivity_models import DirectivitySpec, launch_direction, ray_amplitudes
from bentray.scenes.field_models import band_label
from bentray.scenes.receiver_models import AUTO_EIGENRAY_PAIRS
from bentray.scenes.schema import Job

if TYPE_CHECKING:  # the search itself loads in run_eigenrays: a job without receivers never imports it
    from bentray.engine.eigenrays import EigenraySearch, RayModel

ARRIVAL_COLUMNS = [
    "receiver",
    "source",
    "arrival",
    "frequency_hz",
    "time_s",
    "amplitude",
    "phase_rad",
    "reflections",
    "caustics",
    "launch_elevation_deg",
    "launch_azimuth_deg",
    "path_length_m",
    "spreading",
    "miss_m",
]


@dataclass
class ArrivalTable:
    """Rows of arrivals.csv (one per arrival and band, columns ARRIVAL_COLUMNS), per-receiver eigenray
    levels (tl_coh / tl_inc (F, P) dB re 1 m free field, NaN where no arrival), counts and failures."""

    rows: list[dict[str, Any]]
    tl_coh: np.ndarray
    tl_inc: np.ndarray
    arrivals: np.ndarray
    failures: list[list[str]]
    stats: dict[str, Any]

    columns = ARRIVAL_COLUMNS


def eigenray_decision(job: Job) -> str | None:
    """None when the job runs the eigenray search, else the reason it does not (for the report)."""
    spec = job.eigenrays
    pairs = len(job.receivers) * len(job.sources)
    if not job.receivers:
        return "skipped: no receivers in the job"
    if spec.enabled == "off":
        return "skipped: eigenrays.enabled is 'off'"
    if spec.enabled == "auto" and pairs > AUTO_EIGENRAY_PAIRS:
        return (
            f"skipped: {pairs} source-receiver pairs is over the 'auto' limit of {AUTO_EIGENRAY_PAIRS} "
            "(set eigenrays.enabled to 'on')"
        )
    if job.solver.is_baseline:
        return f"skipped: solver.curve {job.solver.curve!r} is a numerical baseline"
    return None


def _levels(searches: list[EigenraySearch], n_f: int, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coherent and incoherent TL (F,) dB re 1 m over all sources' arrivals at one receiver."""
    p = np.zeros(n_f, complex)
    e = np.zeros(n_f)
    for search in searches:
        for a in search.arrivals:
            if a.amplitude.size:
                p += a.amplitude * np.exp(1j * omega * a.time_s)
                e += np.abs(a.amplitude) ** 2
    with np.errstate(divide="ignore"):
        tl_coh = np.where(np.abs(p) > 0, -20.0 * np.log10(np.abs(p) + 1e-300), np.nan)
        tl_inc = np.where(e > 0, -10.0 * np.log10(e + 1e-300), np.nan)
    return tl_coh, tl_inc


def _rows(rid: str, src: int, search: EigenraySearch, freqs: np.ndarray) -> list[dict[str, Any]]:
    rows = []
    for n, a in enumerate(search.arrivals):
        for f, hz in enumerate(freqs):
            amp = complex(a.amplitude[f]) if a.amplitude.size else complex(a.spreading)
            rows.append(
                {
                    "receiver": rid,
                    "source": src,
                    "arrival": n,
                    "frequency_hz": float(hz),
                    "time_s": repr(a.time_s),  # full precision: arrival times are exact to ~1e-12 s
                    "amplitude": abs(amp),
                    "phase_rad": math.atan2(amp.imag, amp.real),
                    "reflections": a.reflections,
                    "caustics": a.caustics,
                    "launch_elevation_deg": a.elevation_deg,
                    "launch_azimuth_deg": a.azimuth_deg,
                    "path_length_m": a.length_m,
                    "spreading": a.spreading,
                    "miss_m": a.miss_m,
                }
            )
    return rows


def _apply_directivity(spec: DirectivitySpec | None, labels: list[str], search: EigenraySearch) -> None:
    """Scale each arrival's amplitude by the source's directivity toward its launch direction."""
    if spec is None:
        return
    for a in search.arrivals:
        if a.amplitude.size:
            a.amplitude = (
                a.amplitude * ray_amplitudes(spec, labels, launch_direction(a.elevation_deg, a.azimuth_deg))[0]
            )


def run_eigenrays(
    job: Job,
    models: list[RayModel],
    receivers_xyz: np.ndarray,
    frequencies_hz: np.ndarray,
) -> ArrivalTable:
    """Search every (source, receiver) pair; models : one RayModel per source (job order)."""
    from bentray.engine.eigenrays import SearchSettings, find_eigenrays

    spec = job.eigenrays
    settings = SearchSettings(
        elevations=spec.elevations, tolerance_m=spec.tolerance_m, max_iterations=spec.max_iterations
    )
    freqs = np.asarray(frequencies_hz, float)
    labels = [band_label(f) for f in freqs]
    omega = 2.0 * math.pi * freqs
    n_p = receivers_xyz.shape[0]
    tl_coh = np.full((freqs.size, n_p), np.nan)
    tl_inc = np.full((freqs.size, n_p), np.nan)
    counts = np.zeros(n_p, np.int64)
    failures: list[list[str]] = [[] for _ in range(n_p)]
    rows: list[dict[str, Any]] = []
    for i, rec in enumerate(job.receivers):
        searches = []
        for s, model in enumerate(models):
            search = find_eigenrays(model, receivers_xyz[i], job.rays.max_time_s, settings)
            _apply_directivity(job.sources[s].directivity, labels, search)
            searches.append(search)
            rows += _rows(rec.id, s, search, freqs)
            counts[i] += len(search.arrivals)
            failures[i] += [
                f"source {s}: bracket at elevation {fl.elevation_deg:.4g} deg ({fl.reflections} reflections): "
                f"{fl.reason}"
                for fl in search.failures
            ]
        tl_coh[:, i], tl_inc[:, i] = _levels(searches, freqs.size, omega)
    stats = {
        "receivers": n_p,
        "sources": len(models),
        "arrivals": int(counts.sum()),
        "receivers_without_arrivals": int(np.count_nonzero(counts == 0)),
        "not_converged": {job.receivers[i].id: failures[i] for i in range(n_p) if failures[i]},
        "method": (
            "brackets in a vertical fan of "
            f"{spec.elevations} elevations in each receiver's azimuth"
            + (
                f" and toward its image in each wall (of the {models[0].walls.shape[0]} building walls) that faces "
                "both source and receiver"
                if models and models[0].walls.shape[0]
                else ""
            )
            + f", Newton with the paraxial Jacobian, converged to {spec.tolerance_m:g} m"
        ),
    }
    return ArrivalTable(rows, tl_coh, tl_inc, counts, failures, stats)


def merge_into_receivers(table: beam_field.ReceiverTable, arrivals: ArrivalTable, labels: list[str]) -> None:
    """Add the eigenray columns to receivers.csv: arrivals, failures, tl_eig_coh_* and tl_eig_inc_*."""
    extra = ["eigenrays", "eigenray_failures"]
    extra += [f"tl_eig_coh_{lab}hz" for lab in labels] + [f"tl_eig_inc_{lab}hz" for lab in labels]
    table.columns += extra
    for i, row in enumerate(table.rows):
        row["eigenrays"] = int(arrivals.arrivals[i])
        row["eigenray_failures"] = len(arrivals.failures[i])
        for f, lab in enumerate(labels):
            row[f"tl_eig_coh_{lab}hz"] = float(arrivals.tl_coh[f, i])
            row[f"tl_eig_inc_{lab}hz"] = float(arrivals.tl_inc[f, i])
    table.stats["eigenray_levels"] = "tl_eig_coh / tl_eig_inc: coherent and incoherent sums over the eigenrays"

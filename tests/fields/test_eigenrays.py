"""Eigenrays (engine/eigenrays.py, arrivals.csv) against closed forms.

Oracles:
- linear c(z) = c0 + g z (tests/reference/linear_c.py): the circle's closed-form travel time between two
  points (self-checked against quadrature of ds / c along the explicit arc) for the direct arrival, and
  Fermat's stationary points over the ground point for the one-reflection arrivals. The tracer follows
  the same circles cell by cell (solver.curve circular, slab mesh of c), so times must agree to 1e-9 s
  (measured: 1e-14 s direct, 1e-11 s reflected, the oracle's root finding).
- homogeneous air over grass: the image source (times R1 / c and R2 / c, spreading 1 / R, the reflected
  amplitude Q(cos th, R2) / R2 with the exact Weyl-van der Pol Q).
- the beam field's own receiver levels (receivers.csv): computed from the same physics by a different
  route (hat beams of the neighbouring rays); measured agreement 0.05 dB, 0.2 dB in interference dips.
"""

from __future__ import annotations

import csv
import math
from functools import cache

import numpy as np
import pytest

from bentray.engine.acoustics.absorption import absorption_db_per_m
from bentray.engine.acoustics.ground import ground_impedance, spherical_wave_coefficient
from bentray.engine.eigenrays import RayModel, SearchSettings, find_eigenrays
from bentray.engine.media import build_media
from bentray.engine.run import run_job
from bentray.engine.writers import write_outcome
from bentray.scenes.profile_models import profile_from_spec
from bentray.scenes.schema import Job
from tests.reference.linear_c import reflected_times, travel_time, travel_time_quadrature

C_LIN = 340.0
SRC = np.array([0.0, 0.0, 2.0])
TIME_TOL_S = 1e-9  # the bound for arrival times


def test_linear_c_oracle_closed_form_matches_quadrature() -> None:
    a = np.array([0.0, 0.0, 2.0])
    for g in (0.1, -0.1, 0.5):
        for b in ([300.0, 40.0, 1.5], [80.0, -10.0, 30.0], [5.0, 0.0, 0.1]):
            t_closed = travel_time(a, np.array(b), C_LIN, g)
            assert abs(t_closed - travel_time_quadrature(a, np.array(b), C_LIN, g)) < 1e-12


def _linear_model(g: float, curve: str = "circular") -> RayModel:
    job = Job.model_validate(
        {
            "name": "eig",
            "scene": {"domain": {"min": [-20, -100, 0], "max": [600, 100, 120]}, "ground": {"kind": "flat"}},
            "profile": {"kind": "linear_c", "c0": C_LIN, "alpha": g},
            "sources": [{"position": SRC.tolist()}],
            "rays": {"elevation_deg": {"min": -5, "max": 5, "count": 3}, "max_time_s": 3.0, "max_reflections": 20},
            "solver": {"curve": curve},
            "outputs": ["report"],
        }
    )
    profile = profile_from_spec(job.profile)
    lo = np.asarray(job.scene.box.min, float)
    hi = np.asarray(job.scene.box.max, float)
    media = build_media(profile, curve, job.solver, lo, hi, ground="reflect", top=job.scene.top.kind)
    cell = int(media.locate(SRC[None])[0])
    return RayModel(media.mesh, curve, float(profile.c_ref), SRC, cell, 20)


@pytest.mark.parametrize("receiver", [(100.0, 0.0, 1.5), (300.0, 40.0, 1.5), (520.0, -30.0, 4.0)])
def test_linear_c_arrival_times_match_the_closed_form_circle(receiver: tuple[float, float, float]) -> None:
    """Downward refraction (g = +0.1 /s): the direct arrival and every one-reflection arrival (Fermat's
    stationary points; several branches at longer ranges, one past a caustic) within 1e-9 s."""
    g = 0.1
    r = np.array(receiver)
    search = find_eigenrays(_linear_model(g), r, 3.0)
    assert not search.failures
    direct = [a for a in search.arrivals if a.reflections == 0]
    assert len(direct) == 1
    assert abs(direct[0].time_s - travel_time(SRC, r, C_LIN, g)) < TIME_TOL_S
    once = sorted(a.time_s for a in search.arrivals if a.reflections == 1)
    expected = reflected_times(SRC, r, C_LIN, g)
    assert len(once) == len(expected)
    assert np.max(np.abs(np.array(once) - np.array(expected))) < TIME_TOL_S
    for a in search.arrivals:
        assert a.miss_m <= SearchSettings().tolerance_m


def test_a_root_next_to_a_grazing_branch_boundary_is_found() -> None:
    """Nearly homogeneous (g = 1e-4 /s), receiver at 500 m: the direct root (-0.06 deg) and the ray that
    grazes the ground at the receiver's range (-0.23 deg) lie in one 0.25 deg fan interval whose ends
    differ in reflection count; the interval is split until they are apart (before the split the direct
    arrival was missed)."""
    g = 1e-4
    r = np.array([500.0, 0.0, 1.5])
    search = find_eigenrays(_linear_model(g), r, 3.0)
    assert not search.failures
    assert sorted(a.reflections for a in search.arrivals) == [0, 1]
    assert abs(search.arrivals[0].time_s - travel_time(SRC, r, C_LIN, g)) < TIME_TOL_S
    assert abs(search.arrivals[1].time_s - reflected_times(SRC, r, C_LIN, g)[0]) < TIME_TOL_S


def test_upward_refraction_shadow_has_no_eigenray_and_says_so() -> None:
    """g = -0.1 /s: the geometric shadow starts near sqrt(2 R zs) + sqrt(2 R zr) = 218 m (R = c / |g|);
    a receiver at 300 m has no eigenray, one at 100 m has its direct and reflected arrivals."""
    model = _linear_model(-0.1)
    assert find_eigenrays(model, np.array([300.0, 0.0, 1.5]), 3.0).arrivals == []
    near = find_eigenrays(model, np.array([100.0, 0.0, 1.5]), 3.0)
    assert sorted(a.reflections for a in near.arrivals) == [0, 1]
    assert abs(near.arrivals[0].time_s - travel_time(SRC, np.array([100.0, 0.0, 1.5]), C_LIN, -0.1)) < TIME_TOL_S


GRASS = 200_000.0
C_HOM = 343.0
POINTS = [(50.0, 0.0, 1.5), (150.0, 10.0, 4.0), (300.0, -20.0, 1.5), (600.0, 0.0, 4.0), (900.0, 30.0, 2.0)]


def _job(profile: dict, eigenrays: dict | None = None) -> Job:
    spec = {
        "name": "eig",
        "scene": {
            "domain": {"min": [-20, -100, 0], "max": [1000, 100, 150]},
            "ground": {"kind": "flat", "flow_resistivity": GRASS},
        },
        "profile": profile,
        "sources": [{"position": SRC.tolist()}],
        "rays": {
            "elevation_deg": {"min": -60, "max": 60, "count": 601},
            "azimuth_deg": {"min": -10, "max": 10, "count": 21},
            "max_time_s": 4.0,
            "max_reflections": 20,
        },
        "receivers": [{"id": f"R{i}", "position": list(p)} for i, p in enumerate(POINTS)],
        "outputs": ["report"],
    }
    if eigenrays is not None:
        spec["eigenrays"] = eigenrays
    return Job.model_validate(spec)


@cache
def _homogeneous():
    return run_job(_job({"kind": "homogeneous", "c0": C_HOM}))


def _arrivals_by_receiver(outcome) -> dict[str, dict[int, list[dict]]]:
    out: dict[str, dict[int, list[dict]]] = {}
    for row in outcome.arrivals.rows:
        out.setdefault(row["receiver"], {}).setdefault(row["arrival"], []).append(row)
    return out


def test_homogeneous_arrivals_are_the_image_source_ones() -> None:
    """Direct and ground-reflected arrivals: times R / c (1e-12 s), spreading 1 / R (1e-9 relative), the
    reflected amplitude and phase those of the exact spherical-wave Q / R2 per band, within the ground
    table's interpolation: 0.05 dB and 0.01 rad (measured 0.001 dB, 1e-4 rad; command: the test)."""
    outcome = _homogeneous()
    by_rec = _arrivals_by_receiver(outcome)
    freqs = np.array(sorted({row["frequency_hz"] for row in outcome.arrivals.rows}))
    z = ground_impedance(freqs, GRASS)
    # ISO 9613-1 at the receiver defaults (15 C, 70 %, 101.325 kPa): amplitude factor exp(-alpha s / 2)
    alpha = np.asarray(absorption_db_per_m(freqs, 15.0, 70.0, 101.325), float) * math.log(10.0) / 10.0
    for i, p in enumerate(POINTS):
        r = np.array(p)
        arrivals = by_rec[f"R{i}"]
        assert len(arrivals) == 2
        r1 = float(np.linalg.norm(r - SRC))
        r2 = float(np.linalg.norm(r - SRC * [1, 1, -1]))
        direct, reflected = arrivals[0], arrivals[1]
        assert direct[0]["reflections"] == 0 and reflected[0]["reflections"] == 1
        assert abs(float(direct[0]["time_s"]) - r1 / C_HOM) < 1e-12
        assert abs(float(reflected[0]["time_s"]) - r2 / C_HOM) < 1e-12
        assert abs(direct[0]["spreading"] * r1 - 1.0) < 1e-9
        assert abs(reflected[0]["spreading"] * r2 - 1.0) < 1e-9
        cos_th = (r[2] + SRC[2]) / r2
        q = spherical_wave_coefficient(z, cos_th, 2 * math.pi * freqs / C_HOM, r2)
        assert np.allclose([row["amplitude"] for row in direct], np.exp(-0.5 * alpha * r1) / r1, rtol=1e-9)
        amp = np.array([row["amplitude"] for row in reflected]) * r2 / np.exp(-0.5 * alpha * r2)
        phase = np.array([row["phase_rad"] for row in reflected])
        assert np.max(np.abs(20 * np.log10(amp / np.abs(q)))) < 0.05
        assert np.max(np.abs(np.angle(np.exp(1j * (phase - np.angle(q)))))) < 0.01


def test_eigenray_levels_agree_with_the_beam_levels() -> None:
    """receivers.csv carries both: incoherent within 0.1 dB (measured 0.031 dB); coherent within 0.1 dB
    (measured 0.010 dB) where the level is not in an interference dip (coherent TL less than 6 dB above
    the incoherent; in the dips measured up to 0.2 dB)."""
    table = _homogeneous().receivers
    labels = [c[len("tl_coh_") :] for c in table.columns if c.startswith("tl_coh_")]
    for row in table.rows:
        assert row["eigenrays"] == 2 and row["eigenray_failures"] == 0
        for lab in labels:
            assert abs(row[f"tl_inc_{lab}"] - row[f"tl_eig_inc_{lab}"]) < 0.1
            if row[f"tl_coh_{lab}"] - row[f"tl_inc_{lab}"] < 6.0:
                assert abs(row[f"tl_coh_{lab}"] - row[f"tl_eig_coh_{lab}"]) < 0.1


def test_arrivals_csv_is_written_with_full_precision_times(tmp_path) -> None:
    outcome = _homogeneous()
    written = write_outcome(outcome, ["report"], tmp_path / "out")
    names = [p.name for p in written]
    assert "arrivals.csv" in names and "receivers.csv" in names
    with (tmp_path / "out" / "arrivals.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert set(rows[0]) >= {"receiver", "source", "arrival", "time_s", "amplitude", "phase_rad", "reflections",
                            "launch_elevation_deg", "launch_azimuth_deg", "caustics"}  # fmt: skip
    r1 = float(np.linalg.norm(np.array(POINTS[0]) - SRC))
    assert abs(float(rows[0]["time_s"]) - r1 / C_HOM) < 1e-12
    assert "ran:" in outcome.report["stages"]["eigenrays"]


def test_a_search_that_cannot_converge_is_reported_per_receiver() -> None:
    """One Newton iteration to 1e-12 m cannot converge: every bracket is reported under its receiver in
    the report (never dropped silently), and receivers.csv counts the failures."""
    outcome = run_job(_job({"kind": "homogeneous", "c0": C_HOM}, {"max_iterations": 1, "tolerance_m": 1e-12}))
    stats = outcome.report["eigenrays"]
    failed = stats["not_converged"]
    rows = {row["id"]: row for row in outcome.receivers.rows}
    for rid, row in rows.items():
        assert row["eigenrays"] + row["eigenray_failures"] >= 1
        if row["eigenray_failures"]:
            assert len(failed[rid]) == row["eigenray_failures"]
            assert "iterations" in failed[rid][0] or "stalled" in failed[rid][0]
    assert sum(row["eigenray_failures"] for row in rows.values()) > 0


def test_eigenrays_off_and_over_the_limit() -> None:
    outcome = run_job(_job({"kind": "homogeneous", "c0": C_HOM}, {"enabled": "off"}))
    assert outcome.arrivals is None
    assert outcome.report["stages"]["eigenrays"].startswith("skipped: eigenrays.enabled is 'off'")
    spec = _job({"kind": "homogeneous", "c0": C_HOM}).model_dump()
    spec["receivers"] = [{"id": f"P{i}", "position": [10.0 + i * 0.1, 0.0, 1.5]} for i in range(5001)]
    spec["eigenrays"] = {"enabled": "on"}
    with pytest.raises(ValueError, match="eigenrays.enabled"):
        Job.model_validate(spec)

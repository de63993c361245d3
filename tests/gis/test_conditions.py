"""Meteorological conditions and per-period emission inside one job (issue 14).

Oracle, independent of engine/conditions.py: one plain job per (condition, source), each run without
conditions, and the CNOSSOS-EU / END combination written out here by hand:

    E_p(x) = sum_c occ_(c,p) sum_s 10^((L_(c,s)(x) + o_(s,p)) / 10),  L_p = 10 lg E_p,
    Lden = 10 lg((12 * 10^(L_d/10) + 4 * 10^((L_e + 5)/10) + 8 * 10^((L_n + 10)/10)) / 24).

The condition job traces the same rays on the same mesh, so the levels agree to rounding: asserted 1e-9
dB, on the field and on receivers.csv. A second case checks that two conditions with the same medium share
one mesh (the report says so) and give identical levels.
"""

from __future__ import annotations

import math
from functools import cache
from typing import Any

import numpy as np
import pytest

from bentray.engine.run import run_job
from bentray.scenes.schema import Job, JobFileError

DOWN = {"kind": "linear_c", "c0": 340.0, "alpha": 0.1}
HOMOG = {"kind": "homogeneous", "c0": 340.0}
OCC = {"down": (0.3, 0.6, 1.0), "homog": (0.7, 0.4, 0.0)}
NIGHT_QUIETER = {"day": 0.0, "evening": -3.0, "night": -10.0}
XS = 20.0 + 15.0 * np.arange(12)


def _base(sources: list[dict[str, Any]], profile: dict[str, Any]) -> dict[str, Any]:
    return {
        "name": "conditions",
        "scene": {"domain": {"min": [-10, -20, 0], "max": [220, 20, 60]}, "ground": {"flow_resistivity": 200000}},
        "profile": profile,
        "sources": sources,
        "rays": {
            "elevation_deg": {"min": -60, "max": 60, "count": 241},
            "azimuth_deg": {"min": 0, "max": 0, "count": 1},
            "max_time_s": 1.5,
            "max_reflections": 3,
        },
        "field": {
            "origin": [float(XS[0]), 0.0, 2.0],
            "spacing": [float(XS[1] - XS[0]), 1.0, 1.0],
            "shape": [len(XS), 1, 1],
            "frequencies_hz": [500.0, 1000.0],
            "mode": "incoherent",
            "method": "beams",
            # beams in every condition: the wave stage would give the refracting condition band levels (ground
            # interference included) and homogeneous air the beams' energy sum, not one quantity to compare
            "wave_model": "off",
        },
        "receivers": [{"id": "r1", "position": [80.0, 0.0, 4.0]}, {"id": "r2", "position": [170.0, 0.0, 1.5]}],
        "outputs": ["field", "report"],
    }


SOURCES = [
    {"position": [0.0, 0.0, 2.0], "power_db": {"500": 100.0, "1000": 97.0}},
    {"position": [5.0, 0.0, 0.8], "power_db": {"500": 95.0, "1000": 99.0}, "period_offsets_db": NIGHT_QUIETER},
]


def _condition(name: str, profile: dict[str, Any]) -> dict[str, Any]:
    d, e, n = OCC[name]
    return {"name": name, "profile": profile, "occurrence": {"day": d, "evening": e, "night": n}}


@cache
def _conditions_outcome():
    job = _base(SOURCES, HOMOG)
    job["conditions"] = [_condition("down", DOWN), _condition("homog", HOMOG)]
    return run_job(Job.model_validate(job))


@cache
def _single(profile_name: str, source: int):
    src = {k: v for k, v in SOURCES[source].items() if k != "period_offsets_db"}
    out = run_job(Job.model_validate(_base([src], DOWN if profile_name == "down" else HOMOG)))
    field = np.asarray(out.field.arrays["spl_a"], float).ravel()
    rec = np.array([row["spl_a_inc"] for row in out.receivers.rows], float)
    return field, rec


def _by_hand(which: int) -> dict[str, np.ndarray]:
    offsets = [(0.0, 0.0, 0.0), (0.0, -3.0, -10.0)]
    levels = {}
    for p, period in enumerate(("day", "evening", "night")):
        e = 0.0
        for name in ("down", "homog"):
            for s in range(2):
                e = e + OCC[name][p] * 10.0 ** ((_single(name, s)[which] + offsets[s][p]) / 10.0)
        with np.errstate(divide="ignore"):
            levels[period] = 10.0 * np.log10(e)
    levels["den"] = 10.0 * np.log10(
        (
            12 * 10 ** (levels["day"] / 10)
            + 4 * 10 ** ((levels["evening"] + 5) / 10)
            + 8 * 10 ** ((levels["night"] + 10) / 10)
        )
        / 24
    )
    return levels


@pytest.mark.parametrize("period", ["day", "evening", "night", "den"])
def test_field_indicators_equal_the_hand_combination_of_single_jobs(period):
    got = np.asarray(_conditions_outcome().field.arrays[f"l_{period}"], float).ravel()
    ref = _by_hand(0)[period]
    assert np.array_equal(np.isnan(got), np.isnan(ref))
    ok = np.isfinite(ref)
    assert ok.sum() >= len(XS) - 2  # the check covers the line, not an empty set
    np.testing.assert_allclose(got[ok], ref[ok], rtol=0, atol=1e-9)


def test_receiver_indicators_equal_the_hand_combination():
    table = _conditions_outcome().receivers
    ref = _by_hand(1)
    for period in ("day", "evening", "night", "den"):
        got = np.array([row[f"l_{period}"] for row in table.rows], float)
        np.testing.assert_allclose(got, ref[period], rtol=0, atol=1e-9)
    assert "spl_a_inc__down" in table.columns and "spl_a_inc__homog" in table.columns


def test_per_condition_levels_and_the_report():
    out = _conditions_outcome()
    down = np.asarray(out.field.arrays["spl_a__down"], float).ravel()
    both = 10 * np.log10(10 ** (_single("down", 0)[0] / 10) + 10 ** (_single("down", 1)[0] / 10))
    np.testing.assert_allclose(down, both, rtol=0, atol=1e-9)
    rep = out.report
    assert set(rep["conditions"]) == {"down", "homog"}
    assert [g["sources"] for g in rep["conditions"]["down"]["groups"]] == [[0], [1]]
    assert rep["conditions"]["homog"]["mesh"] == "built"  # another medium: its own mesh
    assert rep["rays"]["total"] == out.trace.n_rays == 2 * 2 * 241
    assert sorted(set(out.trace.source.tolist())) == [0, 1]
    # downward refraction is louder far away than homogeneous air (a sanity check on the wiring)
    homog = np.asarray(out.field.arrays["spl_a__homog"], float).ravel()
    assert np.nanmean(down[-4:] - homog[-4:]) > 0.0


def test_conditions_with_the_same_medium_share_the_mesh():
    job = _base(SOURCES[:1], HOMOG)
    job["conditions"] = [
        {"name": "a", "occurrence": {"day": 0.5, "evening": 0.5, "night": 0.25}},
        {"name": "b", "wind": "none", "occurrence": {"day": 0.5, "evening": 0.5, "night": 0.75}},
    ]
    out = run_job(Job.model_validate(job))
    assert out.report["conditions"]["b"]["mesh"] == "reused from condition 'a'"
    a = np.asarray(out.field.arrays["spl_a__a"], float)
    b = np.asarray(out.field.arrays["spl_a__b"], float)
    assert np.array_equal(a, b, equal_nan=True)
    # one medium: every period level is that medium's level, Lden = L + 10 lg((12 + 4 * 10^0.5 + 8 * 10) / 24)
    den = np.asarray(out.field.arrays["l_den"], float)
    expected = a + 10 * math.log10((12 + 4 * 10**0.5 + 8 * 10) / 24)
    np.testing.assert_allclose(den[np.isfinite(a)], expected[np.isfinite(a)], rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    ("change", "where", "what"),
    [
        (lambda j: j["conditions"][1]["occurrence"].update(night=0.5), "conditions", "night occurrences sum to 1.5"),
        (lambda j: j["conditions"][1].update(name="down"), "conditions.1.name", "used twice"),
        (lambda j: j.update(conditions=[]), "sources.1.period_offsets_db", "lists none"),
        (lambda j: j["sources"][0].pop("power_db"), "conditions", "every source needs power_db"),
        (lambda j: j.update(periods={"hours": [12, 4, 9]}), "periods", "sum to 24"),
        (lambda j: j["conditions"][0]["occurrence"].update(day=1.2), "conditions.0.occurrence.day", "less than"),
    ],
)
def test_bad_conditions_are_refused_with_the_field_path(change, where, what):
    from pydantic import ValidationError

    from bentray.scenes.schema import format_validation_error

    job = _base([dict(s) for s in SOURCES], HOMOG)
    job["conditions"] = [_condition("down", DOWN), _condition("homog", HOMOG)]
    change(job)
    with pytest.raises((ValidationError, JobFileError)) as err:
        Job.model_validate(job)
    text = format_validation_error(err.value) if isinstance(err.value, ValidationError) else str(err.value)
    assert where in text and what in text, text


def test_the_cost_model_counts_every_condition():
    from bentray.scenes.cost import estimate_cost, estimate_mesh

    single = Job.model_validate(_base(SOURCES[:1], DOWN))
    job = _base(SOURCES[:1], DOWN)
    job["conditions"] = [_condition("down", DOWN), _condition("homog", HOMOG)]
    both = Job.model_validate(job)
    one, two = estimate_cost(single, 2), estimate_cost(both, 2)
    assert two.ray_steps == pytest.approx(2 * one.ray_steps) and two.field_deposits == pytest.approx(
        2 * one.field_deposits
    )
    assert two.field_bytes > one.field_bytes
    mesh = estimate_mesh(both)
    assert mesh.basis.startswith("2 media meshes")

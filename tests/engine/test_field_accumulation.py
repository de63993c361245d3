"""Field accumulation invariants: energy conservation along the curves, SPL/TL bookkeeping,
determinism, and refraction filling (A-LD) or emptying (A-LU) the region near the ground.

Conservation is exact by construction (each sub-interval deposits its closed-form travel time), so a
grid that contains every ray's whole path must hold exactly sum_i w_i T (no absorption) or
sum_i w_i (1 - exp(-a c T)) / (a c) (homogeneous air with absorption, midpoint rule: error ~ (a h)^2).
"""

from __future__ import annotations

import numpy as np
import pytest

from bentray.engine.field import energy_absorption, launch_solid_angles
from bentray.engine.field_buffers import FieldBuffers
from bentray.engine.field_sources import REFRACTIVE_SHADOW
from bentray.engine.run import run_job
from bentray.scenes.schema import Job

SOURCE = [0.0, 0.0, 30.0]


def _job(
    profile: dict,
    *,
    max_time: float,
    field: dict,
    sources=None,
    el=(-89.0, 89.0, 60),
    az=(0.0, 354.0, 60),
    ground: dict | None = None,
    name: str = "acc",
) -> Job:
    return Job.model_validate(
        {
            "name": name,
            "scene": {"domain": {"min": [-100, -100, 0], "max": [1500, 100, 300]}, "ground": ground or {}},
            "profile": profile,
            "sources": sources or [{"position": SOURCE}],
            "rays": {
                "elevation_deg": {"min": el[0], "max": el[1], "count": el[2]},
                "azimuth_deg": {"min": az[0], "max": az[1], "count": az[2]},
                "max_time_s": max_time,
                "max_reflections": 3,
            },
            "field": field,
            "outputs": ["field", "report"],
        }
    )


def _cube(freqs=(500.0,), absorption=False, **extra) -> dict:
    return {
        "origin": [-20.0, -20.0, 10.0],
        "spacing": [1.0, 1.0, 1.0],
        "shape": [41, 41, 41],
        "frequencies_hz": list(freqs),
        "absorption": absorption,
        "method": "voxels",  # these tests check the voxel accumulator (energy per voxel, ray hits)
        **extra,
    }


def _captured_energy(monkeypatch) -> dict:
    """Capture the reduced accumulators of the next run (the public arrays are intensities)."""
    box: dict = {}
    original = FieldBuffers.reduce

    def spy(self):
        box["reduced"] = original(self)
        box["buffers"] = self
        return box["reduced"]

    monkeypatch.setattr(FieldBuffers, "reduce", spy)
    return box


@pytest.mark.parametrize(
    "profile",
    [
        {"kind": "homogeneous", "c0": 340.0},
        {"kind": "log", "b": 1.0},
        {"kind": "linear_c", "c0": 340.0, "alpha": 0.5},
    ],
    ids=["uniform", "log-slabs", "linear-c-slabs"],
)
def test_energy_is_conserved_when_the_grid_holds_every_path(profile, monkeypatch) -> None:
    box = _captured_energy(monkeypatch)
    t_max = 0.05  # ~17 m: every path stays inside the 40 m cube around the source
    job = _job(profile, max_time=t_max, field=_cube())
    run_job(job)
    weights = launch_solid_angles(job.rays.elevation_deg.values(), job.rays.azimuth_deg.values())
    total = box["reduced"].energy.sum()
    assert total == pytest.approx(weights.sum() * t_max, rel=1e-12)
    # the fan's cells reach the poles (89 + half of a 3.02 degree step > 90): the whole sphere, unit power
    assert weights.sum() == pytest.approx(1.0, rel=1e-12)


def test_absorbed_energy_matches_the_closed_form(monkeypatch) -> None:
    box = _captured_energy(monkeypatch)
    t_max, c = 0.05, 340.0
    job = _job(
        {"kind": "homogeneous", "c0": c},
        max_time=t_max,
        field=_cube(freqs=(1000.0, 8000.0), absorption=True, humidity_percent=20.0),
    )
    run_job(job)
    weights = launch_solid_angles(job.rays.elevation_deg.values(), job.rays.azimuth_deg.values())
    a = energy_absorption(job.field)
    expected = weights.sum() * (1.0 - np.exp(-a * c * t_max)) / (a * c)
    # midpoint rule over sub-intervals of h <= 0.5 m: relative error (a h)^2 / 24 (2.2e-5 at 8 kHz)
    h = box["buffers"].fgeo[6]
    got = box["reduced"].energy.sum(axis=1)
    assert np.all(np.abs(got / expected - 1.0) <= 2 * (a * h) ** 2 / 24), (got, expected)
    assert a[1] > 10 * a[0] > 0  # the test is not vacuous: 8 kHz is absorbed much more


def test_spl_is_power_level_minus_tl_and_sources_add(monkeypatch) -> None:
    field = {
        "method": "voxels",
        "origin": [-10.0, -10.0, 20.0],
        "spacing": [2.0, 2.0, 2.0],
        "shape": [11, 11, 11],
        "frequencies_hz": [125.0, 1000.0],
        "absorption": False,
    }
    a = {"position": [-4.0, 0.0, 30.0], "power_db": {"125": 100.0, "1000": 90.0}}
    b = {"position": [4.0, 1.0, 28.0], "power_db": {"125": 80.0, "1000": 95.0}}
    hom = {"kind": "homogeneous", "c0": 340.0}
    one = run_job(_job(hom, max_time=0.05, field=field, sources=[a])).field.arrays
    for lab, lw in (("125", 100.0), ("1000", 90.0)):
        ok = np.isfinite(one[f"tl_{lab}hz"])
        np.testing.assert_allclose(
            one[f"spl_{lab}hz"][ok], lw - one[f"tl_{lab}hz"][ok] - 10 * np.log10(4 * np.pi), atol=1e-9
        )
    only_b = run_job(_job(hom, max_time=0.05, field=field, sources=[b])).field.arrays
    both = run_job(_job(hom, max_time=0.05, field=field, sources=[a, b])).field.arrays
    for lab in ("125", "1000"):
        ok = np.isfinite(one[f"spl_{lab}hz"]) & np.isfinite(only_b[f"spl_{lab}hz"])
        summed = 10 * np.log10(10 ** (one[f"spl_{lab}hz"][ok] / 10) + 10 ** (only_b[f"spl_{lab}hz"][ok] / 10))
        np.testing.assert_allclose(both[f"spl_{lab}hz"][ok], summed, atol=1e-9)
    # A-weighted total from the bands: -16.1 dB at 125 Hz, 0 at 1 kHz (exact midband A-weights)
    ok = np.isfinite(both["spl_a"])
    from bentray.engine.acoustics.weighting import a_weighting_db

    w = a_weighting_db(np.array([125.0, 1000.0]))
    manual = 10 * np.log10(10 ** ((both["spl_125hz"] + w[0]) / 10) + 10 ** ((both["spl_1000hz"] + w[1]) / 10))
    np.testing.assert_allclose(both["spl_a"][ok], manual[ok], atol=1e-9)


def test_field_is_deterministic() -> None:
    job = _job(
        {"kind": "log", "b": -1.0},
        max_time=0.05,
        field=_cube(freqs=(250.0,)),
        ground={"kind": "flat", "flow_resistivity": 300000.0},
    )
    first = run_job(job).field.arrays
    second = run_job(job).field.arrays
    for name in first:
        np.testing.assert_array_equal(first[name], second[name])


@pytest.mark.slow  # two field jobs on a long fan: 12 s warm
def test_downward_refraction_fills_the_upward_shadow() -> None:
    """A-LD (log, b = +1) reaches 4 m above the ground at 500-1000 m; A-LU (b = -1) leaves it in the
    geometric shadow: no ray passes there, and the level there is the refractive-shadow model's
    (engine/shadow_stage.py; field_source 3), far below the lit case's. (Until the shadow stage existed this
    test asserted NaN levels there; it was left asserting that, and failed, until 2026-12-05.)"""
    field = {
        "method": "voxels",
        "origin": [50.0, 0.0, 4.0],
        "spacing": [10.0, 2.0, 2.0],
        "shape": [96, 1, 1],
        "frequencies_hz": [500.0],
        "absorption": False,
    }
    src = [{"position": [0.0, 0.0, 2.0]}]
    arrays = {}
    for b in (1.0, -1.0):
        job = _job(
            {"kind": "log", "b": b},
            max_time=3.5,
            field=field,
            sources=src,
            el=(-10.0, 30.0, 400),
            az=(-0.5, 0.5, 11),
            name=f"b{int(b)}",
        )
        arrays[b] = run_job(job).field.arrays
    x = 50.0 + 10.0 * np.arange(96)
    far = x >= 500.0
    assert np.all(arrays[1.0]["ray_hits"].ravel()[far] > 0)
    assert np.all(np.isfinite(arrays[1.0]["tl_500hz"].ravel()[far]))
    assert np.all(arrays[-1.0]["ray_hits"].ravel()[far] == 0)
    assert np.all(arrays[-1.0]["field_source"].ravel()[far] == REFRACTIVE_SHADOW)
    shadow_tl = arrays[-1.0]["tl_500hz"].ravel()[far]
    assert np.all(np.isfinite(shadow_tl))
    assert np.all(shadow_tl > arrays[1.0]["tl_500hz"].ravel()[far] + 40.0)  # measured 107-159 dB against 43-55
    near = x <= 60.0  # both reach the first voxels directly
    assert np.all(arrays[-1.0]["ray_hits"].ravel()[near] > 0)

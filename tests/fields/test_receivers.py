"""Receivers (``receivers`` in the job, receivers.csv): beam levels at named points.

Reference: the image source over grass (homogeneous air, source 2 m), coherent and incoherent. Also: a
receiver on a field grid point gets the grid's level to rounding (same beams, same sums), and bad
receivers are refused with the field path.
"""

from __future__ import annotations

import csv
from functools import cache

import numpy as np
import pytest

from bentray.engine.acoustics.ground import image_source_intensity_ratio, image_source_pressure
from bentray.engine.errors import JobInputError
from bentray.engine.run import run_job
from bentray.engine.writers import write_outcome
from bentray.scenes.schema import Job

C0 = 340.0
SOFT = 200_000.0
SRC = np.array([0.0, 0.0, 2.0])
POINTS = [(37.0, 0.0, 1.5), (120.0, 3.0, 4.0), (333.0, -5.0, 1.5), (640.0, 0.0, 2.5)]


def _spec(receivers, field=True):
    spec = {
        "name": "receivers",
        "scene": {
            "domain": {"min": [-20, -60, 0], "max": [1020, 60, 120]},
            "ground": {"kind": "flat", "flow_resistivity": SOFT},
        },
        "profile": {"kind": "homogeneous", "c0": C0},
        "sources": [{"position": SRC.tolist(), "power_db": {"250": 100, "1000": 100}}],
        "rays": {
            "elevation_deg": {"min": -45.0, "max": 15.0, "count": 601},
            "azimuth_deg": {"min": -2.0, "max": 2.0, "count": 5},
            "max_time_s": 3.1,
            "max_reflections": 2,
        },
        "receivers": receivers,
        "outputs": ["report"],
    }
    if field:
        spec["field"] = {
            "origin": [37.0, 0.0, 1.5],
            "spacing": [83.0, 1.0, 1.0],
            "shape": [2, 1, 1],
            "frequencies_hz": [250.0, 1000.0],
            "absorption": False,
            "mode": "coherent",
        }
        spec["outputs"] = ["field", "report"]
    return spec


@cache
def _outcome():
    recs = [{"id": f"r{i}", "position": list(p)} for i, p in enumerate(POINTS)]
    recs.append({"id": "above", "xy": [200.0, 0.0], "height_above_ground_m": 3.0})
    return run_job(Job.model_validate(_spec(recs)))


def test_receiver_levels_match_image_source():
    out = _outcome()
    rows = {r["id"]: r for r in out.receivers.rows}
    pts = np.array([*POINTS, (200.0, 0.0, 3.0)])
    ids = [f"r{i}" for i in range(len(POINTS))] + ["above"]
    for f in (250.0, 1000.0):
        p = image_source_pressure(SRC, pts, f, SOFT, c=C0)
        e = image_source_intensity_ratio(SRC, pts, f, SOFT, c=C0)
        for k, rid in enumerate(ids):
            ref_coh = -20 * np.log10(abs(p[k]))
            ref_inc = -10 * np.log10(e[k])
            assert abs(rows[rid][f"tl_inc_{f:g}hz"] - ref_inc) < 0.5, (rid, f)
            if ref_coh - ref_inc < 6.0:  # outside interference dips
                assert abs(rows[rid][f"tl_coh_{f:g}hz"] - ref_coh) < 0.5, (rid, f)


def test_receiver_on_a_grid_point_gets_the_grid_level():
    out = _outcome()
    rows = {r["id"]: r for r in out.receivers.rows}
    for f in (250.0, 1000.0):
        grid_tl = out.field.arrays[f"tl_{f:g}hz"].ravel()
        assert rows["r0"][f"tl_coh_{f:g}hz"] == pytest.approx(grid_tl[0], abs=1e-9)


def test_receivers_csv_written(tmp_path):
    out = _outcome()
    write_outcome(out, ["field", "report"], tmp_path / "res")
    with (tmp_path / "res" / "receivers.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["id"] for r in rows] == ["r0", "r1", "r2", "r3", "above"]
    assert float(rows[4]["z_m"]) == pytest.approx(3.0)
    assert "spl_a_coh" in rows[0] and "spl_a_inc" in rows[0]


def test_receiver_outside_the_domain_is_refused_with_its_path():
    recs = [{"id": "a", "position": [10.0, 0.0, 2.0]}, {"id": "b", "position": [5000.0, 0.0, 2.0]}]
    with pytest.raises(ValueError, match=r"receivers\.1\.position"):
        Job.model_validate(_spec(recs))


def test_receiver_below_ground_is_refused_with_its_path():
    recs = [{"id": "a", "position": [10.0, 0.0, -1.0]}]
    with pytest.raises(ValueError, match=r"receivers\.0\.position"):
        Job.model_validate(_spec(recs))


def test_receivers_without_a_field():
    recs = [{"id": "a", "position": [120.0, 3.0, 4.0]}]
    out = run_job(Job.model_validate(_spec(recs, field=False)))
    assert out.field is None
    row = out.receivers.rows[0]
    e = image_source_intensity_ratio(SRC, np.array([[120.0, 3.0, 4.0]]), 1000.0, SOFT, c=C0)[0]
    # default bands include 1 kHz; default absorption is on (ISO 9613-1 at 15 C, 70 %): < 0.1 dB at 120 m
    assert abs(row["tl_inc_1000hz"] + 10 * np.log10(e)) < 0.6
    _ = JobInputError

"""Lateral eigenrays: single reflections off building walls (engine/eigenrays.py, "Wall reflections").

Oracle: the image-source method for a rigid vertical wall over rigid ground in homogeneous air. The source
S, its ground image S_g, and their mirror images in the wall's plane give four arrivals at a receiver in
front of the wall: direct |r - S|, ground |r - S_g|, wall |r - S_w| and wall + ground |r - S_wg| (over c),
with spreading 1 / R each (rigid: |Q| = 1), provided the specular point lies on the wall. Asserted: the
four arrival times to 1e-9 s (the issue's eigenray bound), spreading to 1e-6 relative, and the reflection
counts (wall and ground reflections both count); a receiver whose wall image is not seen through the wall
(the specular point beyond the wall's end) gets only the direct and ground arrivals, and a wall with the
source behind it is not searched (no fan traced for it). Measured: times within 1.4e-17..5.6e-17 s,
spreading within 3e-13 relative; 10 arrivals at 3 receivers, the whole job 5.6 s on 2 shared cores.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from bentray.engine.eigenrays import wall_images
from bentray.engine.run import run_job
from bentray.scenes.cost import _wall_fans, estimate_cost
from bentray.scenes.schema import Job

C = 340.0
SRC = np.array([-12.0, 6.0, 2.0])
# building 20 m x 30 m x 10 m, counter-clockwise; its west wall is x = 0, y in [0, 30]
BUILDING = [[0.0, 0.0], [20.0, 0.0], [20.0, 30.0], [0.0, 30.0]]
RECEIVERS = [(-20.0, 24.0, 1.5), (-6.0, 28.0, 4.0), (-4.0, 70.0, 1.5)]


@cache
def _job() -> Job:
    return Job.model_validate(
        {
            "name": "eig-walls",
            "scene": {
                "domain": {"min": [-60, -40, 0], "max": [40, 80, 30]},
                "ground": {"kind": "flat"},
                "buildings": {"footprints": [{"polygon": BUILDING, "height_m": 10}]},
            },
            "profile": {"kind": "homogeneous", "c0": C},
            "sources": [{"position": SRC.tolist()}],
            "rays": {
                "elevation_deg": {"min": -10, "max": 10, "count": 5},
                "azimuth_deg": {"min": 0, "max": 0, "count": 1},
                "max_time_s": 0.6,
                "max_reflections": 4,
            },
            "receivers": [{"id": f"R{i}", "position": list(p)} for i, p in enumerate(RECEIVERS)],
            "eigenrays": {"enabled": "on"},
            "outputs": ["report"],
        }
    )


@cache
def _outcome():
    return run_job(_job())


def _images(r: np.ndarray) -> list[tuple[float, int]]:
    """(distance, reflections) of the image sources seen at r, the wall image only where its specular
    point is on the wall (x = 0, 0 <= y <= 30, 0 <= z <= 10)."""
    out = []
    for s, k in ((SRC, 0), (SRC * [1, 1, -1], 1)):
        out.append((float(np.linalg.norm(r - s)), k))
        sw = s * [-1, 1, 1]  # mirror in the wall's plane x = 0
        hit = sw + (-sw[0] / (r[0] - sw[0])) * (r - sw)  # where the line sw -> r crosses x = 0
        if 0.0 <= hit[1] <= 30.0 and abs(hit[2]) <= 10.0:
            out.append((float(np.linalg.norm(r - sw)), k + 1))
    return sorted(out)


def test_wall_images_are_picked_by_the_specular_point():
    walls = np.array([[0, 30, 0, 0, 0, 10], [0, 0, 20, 0, 0, 10], [20, 0, 20, 30, 0, 10], [20, 30, 0, 30, 0, 10]],
                     float)  # fmt: skip
    # the west wall (0, 30) -> (0, 0) has its outside at x < 0: only it faces the source
    imgs = wall_images(SRC, np.array(RECEIVERS[0]), walls)
    assert len(imgs) == 1 and np.allclose(imgs[0], [20.0, 24.0, 1.5])
    assert wall_images(SRC, np.array(RECEIVERS[2]), walls) == []  # specular point at y = 54 > 30


def test_the_cost_model_counts_the_wall_fans():
    # R0 and R1 see the west wall, R2 does not: two wall fans besides the three in-plane ones
    assert _wall_fans(_job()) == 2
    job = _job()
    per_fan = estimate_cost(job, 2).eigenray_steps / 5
    assert per_fan > 0 and estimate_cost(job.model_copy(update={"receivers": job.receivers[2:]}), 2).eigenray_steps == (
        per_fan
    )


@pytest.mark.parametrize("i", range(len(RECEIVERS)))
def test_wall_arrivals_are_the_image_source_ones(i):
    out = _outcome()
    rows = [r for r in out.arrivals.rows if r["receiver"] == f"R{i}"]
    rows = [r for r in rows if r["frequency_hz"] == rows[0]["frequency_hz"]]  # one row per arrival and band
    got = sorted((float(r["time_s"]), int(r["reflections"]), float(r["spreading"])) for r in rows)
    want = _images(np.array(RECEIVERS[i]))
    assert len(got) == len(want), (got, want)
    for (t, k, spread), (dist, k_want) in zip(got, want, strict=True):
        assert abs(t - dist / C) < 1e-9
        assert k == k_want
        assert abs(spread * dist - 1.0) < 1e-6
    assert not out.arrivals.failures[i]


def test_the_cost_models_wall_count_is_the_search_test():
    """scenes.cost._wall_fans (vectorised over walls) counts exactly the walls engine.eigenrays.wall_images
    takes, over random receivers around two buildings (one given clockwise)."""
    rng = np.random.default_rng(7)
    second = [[30.0, 40.0], [30.0, 55.0], [45.0, 55.0], [45.0, 40.0]]  # clockwise
    recs = rng.uniform([-55, -35], [35, 75], size=(40, 2))
    spec = _job().model_dump(mode="json", exclude_none=True)
    spec["scene"]["buildings"] = {
        "footprints": [{"polygon": BUILDING, "height_m": 10}, {"polygon": second, "height_m": 6}]
    }
    spec["receivers"] = [{"id": f"q{i}", "position": [float(x), float(y), 1.5]} for i, (x, y) in enumerate(recs)]
    job = Job.model_validate(spec)
    walls = []
    for ring in (np.array(BUILDING), np.array(second)[::-1]):
        for a, b in zip(ring, np.roll(ring, -1, axis=0), strict=True):
            walls.append([a[0], a[1], b[0], b[1], 0.0, 10.0])
    loop = sum(len(wall_images(SRC, np.array([x, y, 1.5]), np.array(walls))) for x, y in recs)
    assert loop > 5 and _wall_fans(job) == loop

"""Shared inputs of the hardening tests: the README's A-LD fan job as a dict, and ways to mutate it."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "scenes" / "examples" / "a-ld-fan.json"
HILL = REPO / "scenes" / "examples" / "hill.asc"
# a closed tetrahedron with outward normals whose base face lies on z = 0
TETRA_OBJ = "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def base_job() -> dict:
    return copy.deepcopy(json.loads(EXAMPLE.read_text()))


def huge_footprint_job() -> dict:
    """The probe's hang: a footprint with coordinates near +-1e308."""
    job = base_job()
    job["scene"]["buildings"] = {
        "footprints": [{"polygon": [[1e308, -1e308], [-1e308, -1e308], [0, 1e308]], "height_m": 5.0}]
    }
    return job


def overlapping_job() -> dict:
    job = base_job()
    square = [[100, -10], [120, -10], [120, 10], [100, 10]]
    shifted = [[110, -10], [130, -10], [130, 10], [110, 10]]
    job["scene"]["buildings"] = {
        "footprints": [{"polygon": square, "height_m": 10.0}, {"polygon": shifted, "height_m": 10.0}]
    }
    return job


def below_terrain_job() -> dict:
    """hill.asc is ~5-40 m high near the origin: a source at z = 1 m is below it."""
    job = base_job()
    job["scene"] = {"domain": {"min": [-500, -500, 0], "max": [500, 500, 300]}, "terrain": {"file": "hill.asc"}}
    job["sources"] = [{"position": [0, 0, 1.0]}]
    return job


def field_job(spacing: float, shape=(2, 2, 1), method: str = "voxels") -> dict:
    """A small field job; the probe's unbounded case is the voxel method (segments cut into pieces of
    sample_fraction x spacing)."""
    job = base_job()
    job["rays"]["azimuth_deg"] = {"min": -10, "max": 10, "count": 3}
    job["field"] = {"origin": [100, 0, 1], "spacing": [spacing] * 3, "shape": list(shape), "method": method}
    job["outputs"] = ["field", "report"]
    return job


@pytest.fixture
def job() -> dict:
    return base_job()

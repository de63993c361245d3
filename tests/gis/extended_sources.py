"""Shared by the line- and area-source tests: the levels of a set of point sources (the pieces of an
extended source) on a receiver line, from an incoherent beam field in homogeneous air over rigid ground."""

from __future__ import annotations

from typing import Any

import numpy as np


def beam_levels_on_a_line(
    name: str, sources: list[dict[str, Any]], domain: dict[str, list[float]], xs: np.ndarray, zr: float
) -> np.ndarray:
    """SPL (dB) at 500 Hz at the points (xs, 0, zr) m: one job, every piece a source with its own fan
    (41 x 61 rays over -60..60 deg elevation and -90..90 deg azimuth), no absorption."""
    from bentray.engine.run import run_job
    from bentray.scenes.schema import Job

    job = {
        "name": name,
        "scene": {"domain": domain},  # rigid flat ground at the domain bottom
        "profile": {"kind": "homogeneous", "c0": 340.0},
        "sources": sources,
        "rays": {
            "elevation_deg": {"min": -60, "max": 60, "count": 41},
            "azimuth_deg": {"min": -90, "max": 90, "count": 61},
            "max_time_s": 1.0,
            "max_reflections": 2,
        },
        "field": {
            "origin": [float(xs[0]), 0.0, zr],
            "spacing": [float(xs[1] - xs[0]), 1.0, 1.0],
            "shape": [len(xs), 1, 1],
            "frequencies_hz": [500.0],
            "absorption": False,
            "mode": "incoherent",
            "method": "beams",
        },
        "outputs": ["field", "report"],
    }
    out = run_job(Job.model_validate(job))
    assert out.field is not None
    return np.asarray(out.field.arrays["spl_500hz"], float).ravel()

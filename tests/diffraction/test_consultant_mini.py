"""A small consultant-style map (600 m DEM with a 15 m hill, 6 buildings, a fan 3 m above the ground,
levels 4 m above the ground, 58 x 58 points): with the diffraction stage and the terrain screening behind
the hill (engine/diffraction/terrain.py), no air point is left without a level.

Measured (this session, `bentray run`, 2-core machine under load): homogeneous air 36.7 % of the air
points without a beam, 0.6 % without a level after the stage (hill shadow); downward refraction (log
b = 1) 26.6 % -> 0.0 %; whole run 27 s / 37 s, diffraction stage 6.8 s (8.8 s before the visibility
pre-filter) / 13.7 s, peak RSS 0.37 / 0.97 GB. With terrain screening (lead, 2026-12-02): homogeneous
0.6 % -> 0 % (the stage's points and seconds are in the report's terrain_screening section).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bentray.engine.run import run_job
from bentray.scenes.schema import Job


def _inputs(d: Path) -> None:
    n, cell = 61, 10.0
    x = (np.arange(n) + 0.5) * cell
    gx, gy = np.meshgrid(x, x)
    z = 100.0 + 15.0 * np.exp(-(((gx - 330) / 60) ** 2 + ((gy - 300) / 120) ** 2))
    rows = "\n".join(" ".join(f"{v:.3f}" for v in z[::-1][i]) for i in range(n))
    header = f"ncols {n}\nnrows {n}\nxllcorner 0\nyllcorner 0\ncellsize {cell:g}\nNODATA_value -9999\n"
    (d / "dem.asc").write_text(header + rows + "\n")
    blocks = [(150, 250, 40, 60, 12.0), (230, 150, 30, 30, 9.0), (220, 380, 25, 40, 15.0),
              (420, 200, 30, 30, 9.0), (100, 420, 40, 20, 6.0), (400, 430, 30, 50, 12.0)]  # fmt: skip
    feats = [
        {"type": "Feature", "properties": {"height": h, "name": f"b{i}"},
         "geometry": {"type": "Polygon", "coordinates": [[[a, b], [a + w, b], [a + w, b + e], [a, b + e], [a, b]]]}}
        for i, (a, b, w, e, h) in enumerate(blocks)
    ]  # fmt: skip
    (d / "buildings.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": feats}))


@pytest.mark.slow
def test_consultant_map_has_levels_behind_buildings(tmp_path: Path) -> None:
    _inputs(tmp_path)
    job = {
        "name": "consultant-mini",
        "scene": {
            "domain": {"min": [10, 10, 0], "max": [600, 600, 200]},
            "terrain": {"file": "dem.asc", "material": "grass"},
            "materials": [{"name": "grass", "flow_resistivity": 200000.0}],
            "buildings": {"file": "buildings.geojson"},
        },
        "profile": {"kind": "homogeneous"},
        "sources": [{"position": [80, 300], "height_above_ground_m": 3.0, "power_db": {"500": 100, "1000": 100}}],
        "rays": {
            "elevation_deg": {"min": -40, "max": 60, "count": 51},
            "azimuth_deg": {"min": -180, "max": 179, "count": 120},
            "max_time_s": 2.0,
            "max_reflections": 2,
        },
        "field": {
            "origin": [15, 15, 4.0],
            "spacing": [10, 10, 1],
            "shape": [58, 58, 1],
            "heights": "above_ground",
            "frequencies_hz": [500, 1000],
        },  # fmt: skip
        "outputs": ["field", "report"],
    }
    out = run_job(Job.model_validate(job), base_dir=tmp_path)
    a = out.field.arrays
    air = a["inside_solid"] == 0
    before = np.count_nonzero((a["beam_hits"] == 0) & air) / np.count_nonzero(air)
    after = np.count_nonzero(~np.isfinite(a["tl_1000hz"]) & air) / np.count_nonzero(air)
    print(
        f"\n air points without a level: {before:.1%} (beams) -> {after:.1%} (with diffraction and terrain screening)"
    )
    print(out.report.get("terrain_screening"), out.report["stages"].get("terrain_screening"))
    assert before > 0.2 and after == 0.0
    assert out.report["terrain_screening"]["points_filled"] > 0
    assert np.all(np.isnan(a["tl_1000hz"][~air]))
    assert out.report["diffraction"]["field"]["field_source"]["diffracted"] > 1000

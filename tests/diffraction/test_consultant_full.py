"""Issue 13's consultant case at full size, re-run: a 2 km x 2 km DEM (a valley behind a rim, a hill),
15 buildings (a factory hall and 14 houses), an industrial fan 3 m above the ground beside the hall,
levels 4 m above the ground on a 20 m raster (100 x 100 points) and 56 facade receivers (4 per house,
2 m in front of each facade's middle, 4 m above the ground), under homogeneous air, downward refraction
(log b = +1) and upward refraction (log b = -1, the refractive-shadow stage forced on).

The inputs are committed as ``scenes/examples/consultant-{dem.asc,buildings.geojson}`` with one job per
condition (``scenes/examples/consultant-{homogeneous,downward,upward}.json``); this module writes them
(``python -m tests.diffraction.test_consultant_full``), and its slow test checks that the committed
files are what it writes, runs each job and asserts: no point in the air without a level, every facade
receiver with a level, and (upward) that the refractive-shadow stage ran and gave a level to every
point of its shadow, behind the buildings too. Time and memory per condition: printed by the test and
stated in the README (measured with ``/usr/bin/time -v bentray run scenes/examples/consultant-*.json``,
2026-12-02, load 8-11 on 2 cores): air points without a beam 42.8 / 35.8 / 93.7 %, without a level 0 in
each condition, 56 of 56 facades with a level; wall 78 / 251 / 247 s (CPU 34 / 47 / 83 s), peak RSS
0.40 / 1.96 / 2.02 GB; upward: the refractive-shadow stage 85 s for 9,877 shadow points (2 bands).
With legs in a refractive shadow decaying (engine/diffraction/leg_shadow.py; measured 2026-12-02 with
tests/diffraction/consultant_levels.py, load ~11): of the 5,352 points the diffraction stage models (5,344 in
the profile's shadow), the diffracted level is below the shadow stage's own level at 4,721 (500 Hz) /
4,808 (1 kHz), median 89 / 191 dB below (it was median 0.2 dB from homogeneous air, 60-150 dB above);
final codes diffracted 337, refractive shadow 8,569, combination 477; still 0 air points without a
level and 56 of 56 facades; upward wall 211 s (user 109 s, diffraction stage 99 s), peak RSS 2.02 GB.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "scenes" / "examples"
CONDITIONS = {
    "homogeneous": {"kind": "homogeneous"},
    "downward": {"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0},
    "upward": {"kind": "log", "c0": 340.0, "b": -1.0, "z_g": 1.0},
}
FAN = (560.0, 1000.0)
# (x0, y0, width, depth, height): the factory hall first, then the houses
BLOCKS = [
    (600, 960, 90, 60, 12.0),
    (760, 900, 20, 14, 7.0), (780, 1080, 16, 12, 6.0), (900, 980, 24, 16, 9.0),
    (860, 1250, 18, 12, 7.5), (1040, 1420, 20, 14, 8.0), (1010, 1640, 16, 16, 6.5),
    (1480, 980, 22, 14, 7.0), (1600, 1100, 18, 12, 6.0), (1720, 860, 20, 16, 9.0),
    (1560, 1500, 16, 12, 6.5), (400, 600, 20, 14, 7.0), (300, 1400, 18, 14, 8.0),
    (1200, 400, 24, 16, 9.0), (1850, 1750, 18, 12, 6.0),
]  # fmt: skip


def terrain_z(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Ground height (m): 100 m plain, a 25 m hill at (1000, 1500), a rim ridge along x = 1300 (+8 m) and
    a valley east of it falling 20 m."""
    hill = 25.0 * np.exp(-(((x - 1000.0) / 150.0) ** 2 + ((y - 1500.0) / 200.0) ** 2))
    rim = 8.0 * np.exp(-(((x - 1300.0) / 40.0) ** 2))
    valley = -20.0 / (1.0 + np.exp(-(x - 1400.0) / 40.0))
    return 100.0 + hill + rim + valley


def write_inputs(d: Path) -> None:
    """consultant-dem.asc (ESRI ASCII, 103 x 103 cells of 20 m) and consultant-buildings.geojson into d."""
    n, cell = 103, 20.0
    c = (np.arange(n) + 0.5) * cell - 30.0  # cell centres -20 .. 2020 cover the domain 0 .. 2000
    gx, gy = np.meshgrid(c, c)
    z = terrain_z(gx, gy)
    rows = "\n".join(" ".join(f"{v:.2f}" for v in z[::-1][i]) for i in range(n))
    header = f"ncols {n}\nnrows {n}\nxllcorner -30\nyllcorner -30\ncellsize {cell:g}\nNODATA_value -9999\n"
    (d / "consultant-dem.asc").write_text(header + rows + "\n")
    feats = []
    for i, (a, b, w, e, h) in enumerate(BLOCKS):
        ring = [[a, b], [a + w, b], [a + w, b + e], [a, b + e], [a, b]]
        name = "factory-hall" if i == 0 else f"house-{i}"
        feats.append({"type": "Feature", "properties": {"height": h, "name": name},
                      "geometry": {"type": "Polygon", "coordinates": [ring]}})  # fmt: skip
    (d / "consultant-buildings.geojson").write_text(
        json.dumps({"type": "FeatureCollection", "features": feats}, indent=1)
    )


def facade_receivers() -> list[dict]:
    """56 receivers: 2 m in front of the middle of each facade of the 14 houses, 4 m above the ground."""
    out = []
    for i, (a, b, w, e, _h) in enumerate(BLOCKS[1:], start=1):
        for side, (x, y) in {"s": (a + w / 2, b - 2), "e": (a + w + 2, b + e / 2),
                             "n": (a + w / 2, b + e + 2), "w": (a - 2, b + e / 2)}.items():  # fmt: skip
            out.append({"id": f"house-{i}-{side}", "xy": [x, y], "height_above_ground_m": 4.0})
    return out


def job(condition: str) -> dict:
    """The job of one condition (module docstring); files relative to scenes/examples."""
    spec = {
        "name": f"consultant-{condition}",
        "scene": {
            "domain": {"min": [0, 0, 0], "max": [2000, 2000, 400]},
            "terrain": {"file": "consultant-dem.asc", "material": "grass"},
            "materials": [{"name": "grass", "flow_resistivity": 200000.0}],
            "buildings": {"file": "consultant-buildings.geojson"},
        },
        "profile": CONDITIONS[condition],
        "sources": [
            {"position": list(FAN), "height_above_ground_m": 3.0, "name": "fan", "power_db": {"500": 100, "1000": 100}}
        ],  # fmt: skip
        "rays": {
            "elevation_deg": {"min": -40, "max": 60, "count": 51},
            "azimuth_deg": {"min": -180, "max": 179, "count": 120},
            "max_time_s": 5.0,
            "max_reflections": 2,
        },
        "field": {
            "origin": [10, 10, 4.0],
            "spacing": [20, 20, 1],
            "shape": [100, 100, 1],
            "heights": "above_ground",
            "frequencies_hz": [500, 1000],
        },
        "receivers": facade_receivers(),
        "eigenrays": {"enabled": "off"},
        "outputs": ["field", "report"],
    }
    if condition == "upward":
        spec["field"]["refractive_shadow"] = "on"
    return spec


def write_examples(d: Path = EXAMPLES) -> None:
    write_inputs(d)
    for cond in CONDITIONS:
        (d / f"consultant-{cond}.json").write_text(json.dumps(job(cond), indent=1) + "\n")


def test_committed_examples_are_the_generated_ones(tmp_path: Path) -> None:
    write_examples(tmp_path)
    for p in sorted(tmp_path.iterdir()):
        assert (EXAMPLES / p.name).read_text() == p.read_text(), f"{p.name}: rerun python -m {__name__}"


def _peak_rss_gb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # kB on Linux


@pytest.mark.slow
@pytest.mark.parametrize("condition", list(CONDITIONS))
def test_every_air_point_and_facade_gets_a_level(condition: str) -> None:
    from bentray.engine.field_sources import REFRACTIVE_SHADOW
    from bentray.engine.run import run_job
    from bentray.scenes.schema import Job

    spec = json.loads((EXAMPLES / f"consultant-{condition}.json").read_text())
    t0 = time.perf_counter()
    out = run_job(Job.model_validate(spec), base_dir=EXAMPLES)
    wall = time.perf_counter() - t0
    a = out.field.arrays
    air = a["inside_solid"] == 0
    beams = np.count_nonzero((a["beam_hits"] == 0) & air) / np.count_nonzero(air)
    missing = {lab: int(np.count_nonzero(~np.isfinite(a[f"tl_{lab}hz"]) & air)) for lab in ("500", "1000")}
    rows = out.receivers.rows
    facade_missing = [r["id"] for r in rows if not all(np.isfinite(r[f"tl_inc_{lab}hz"]) for lab in ("500", "1000"))]
    stages = {k: round(float(v), 1) for k, v in out.report.get("timings_s", {}).items() if isinstance(v, float)}
    print(
        f"\n{condition}: air points without a beam {beams:.1%}, without a level {missing}; facades without a level "
        f"{len(facade_missing)} of {len(rows)}; wall {wall:.0f} s, peak RSS {_peak_rss_gb():.2f} GB; stages {stages}; "
        f"refractive_shadow: {out.report['stages'].get('refractive_shadow')}"
    )
    assert len(rows) == 56
    assert all(v == 0 for v in missing.values()), missing
    assert not facade_missing, facade_missing
    assert np.all(np.isnan(a["tl_1000hz"][~air]))
    if condition == "upward":
        assert out.report["stages"]["refractive_shadow"].startswith("ran:")
        code = np.asarray(a["field_source"])
        assert out.report["refractive_shadow"]["field"]["points_in_shadow"] > 0.9 * np.count_nonzero(air)
        assert np.count_nonzero(code >= REFRACTIVE_SHADOW) > 0.3 * np.count_nonzero(air)


if __name__ == "__main__":
    write_examples(Path(sys.argv[1]) if len(sys.argv) > 1 else EXAMPLES)

"""Beam fields in refracting atmospheres against the GFPE oracle (tests/reference/gfpe.py, checked by
itself against the image source in tests/reference/test_gfpe.py).

Downward and upward log profiles (c = 340 + b ln(z + 1), b = +-1), linear c (340 +- 0.1 z), over grass
(200 kPa s/m^2), source 2 m, receivers 1.5 m, 20 m - 1 km, coherent, with a vertical fan (one azimuth).
Compared: points the beams cover (beam_weight >= 0.5: outside the geometric shadow, where ray acoustics
has no level; diffraction into shadows is a later stage) and not in an interference dip of the oracle
(more than 6 dB below its running median over 50 m). Asserted: mean |difference| <= 1 dB at 100 and 500
Hz. Measured with 1,201 rays (mean |difference| over the compared points), with the beams' paraxial state in
the smooth medium (2026-12-03; docs/physics.md §11, "Smooth-medium paraxial state"; with the mesh's exact face
kicks, 2026-12-02, in brackets): upward log 0.47 (0.66) dB at 100 Hz (29 lit points, 20-76 m) and 3.81 (4.32)
dB at 500 Hz; upward linear 0.53 (0.52) and 8.70 (8.71) dB (100 compared points); downward log 5.16 (5.15) /
2.17 (2.15) dB and downward linear 3.28 (3.28) / 4.34 (4.34) dB at 100 / 500 Hz. The cases that do not
meet 1 dB are strict xfails: the target is not reached
(open in issue 12). Downward, the beams are too loud at long range (log, 100 Hz: TL_beams - TL_GFPE = -3.5 /
-5.3 / -8.4 dB at 200-400 / 400-700 / 700-1000 m), and so is exact ray theory:
test_downward_beams_are_ray_theory checks the beams against the eigenray sums at the same receivers (0.24 dB
mean coherent at 100 Hz), while the eigenrays themselves miss the GFPE by 4.8 dB (100 Hz) and 1.8 dB (500 Hz)
over 60-980 m. The beam_weight of 5-25 there is several branches lumped in one group and summed (W > 1 is not
divided); a per-branch normalisation was measured and did not help (5.24 dB at 100 Hz; docs/physics.md §11).
The gap is ray theory's in a duct thinner than its Airy transition length (about 5 m at 100 Hz): a wave
treatment is needed, not another beam sum. These jobs set ``field.wave_model`` "off" (the beams alone); the
product's default field in these cases is the wave stage's (tests/fields/test_wave_field_gfpe.py: 0.04-0.11 dB).
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from scipy.ndimage import median_filter

from bentray.engine.run import run_job
from bentray.scenes.schema import Job
from tests.reference.gfpe import gfpe_tl

XS = 20.0 + 2.0 * np.arange(491)
ZS, ZR = 2.0, 1.5
GRASS = 200_000.0
PROFILES = {
    "log_down": ({"kind": "log", "c0": 340.0, "b": 1.0, "z_g": 1.0}, lambda z: 340.0 + np.log(z + 1.0)),
    "log_up": ({"kind": "log", "c0": 340.0, "b": -1.0, "z_g": 1.0}, lambda z: 340.0 - np.log(z + 1.0)),
    "linear_down": ({"kind": "linear_c", "c0": 340.0, "alpha": 0.1}, lambda z: 340.0 + 0.1 * z),
    "linear_up": ({"kind": "linear_c", "c0": 340.0, "alpha": -0.1}, lambda z: 340.0 - 0.1 * z),
}


def _spec(name: str, f: float) -> dict:
    """The comparison job: vertical fan over grass, a line of field points at ZR."""
    return {
        "name": f"gfpe-{name}",
        "scene": {
            "domain": {"min": [-20, -20, 0], "max": [1020, 20, 300]},
            "ground": {"kind": "flat", "flow_resistivity": GRASS},
        },
        "profile": PROFILES[name][0],
        "sources": [{"position": [0.0, 0.0, ZS]}],
        "rays": {
            "elevation_deg": {"min": -30.0, "max": 30.0, "count": 1201},
            "azimuth_deg": {"min": 0.0, "max": 0.0, "count": 1},
            "max_time_s": 3.2,
            "max_reflections": 8,
        },
        "field": {
            "origin": [XS[0], 0.0, ZR],
            "spacing": [2.0, 1.0, 1.0],
            "shape": [XS.size, 1, 1],
            "frequencies_hz": [f],
            "absorption": False,
            "mode": "coherent",
            "wave_model": "off",  # the beams alone: this module documents ray theory's limit
        },
        "outputs": ["field", "report"],
    }


@cache
def _beams(name: str, f: float):
    job = Job.model_validate(_spec(name, f))
    return run_job(job)


def _compare(name: str, f: float) -> dict:
    out = _beams(name, f)
    tl = out.field.arrays[f"tl_{f:g}hz"].ravel()
    w = out.field.arrays["beam_weight"].ravel()
    ref = gfpe_tl(PROFILES[name][1], f, ZS, XS, np.array([ZR]), flow_resistivity=GRASS)[:, 0]
    dips = ref - median_filter(ref, size=25, mode="nearest") >= 6.0
    ok = (w >= 0.5) & ~dips
    d = np.abs(tl - ref)[ok]
    return {"compared": int(ok.sum()), "mean_db": float(d.mean()), "p90_db": float(np.percentile(d, 90))}


MET = {("log_up", 100.0), ("linear_up", 100.0)}
CASES = [
    pytest.param(
        name,
        f,
        marks=() if (name, f) in MET else (pytest.mark.slow, pytest.mark.xfail(strict=True, reason="over 1 dB")),
    )
    for name in PROFILES
    for f in (100.0, 500.0)
]


@pytest.mark.parametrize(("name", "f"), CASES)
def test_beams_match_gfpe_outside_shadows(name, f):
    res = _compare(name, f)
    assert res["compared"] >= 20, res  # upward refraction: the lit zone is short (29 points for log, b = -1)
    assert res["mean_db"] <= 1.0, res


EIG_RANGES = (140.0, 300.0, 460.0, 620.0, 780.0, 940.0)


@cache
def _beams_and_eigenrays(name: str, f: float):
    """The same job with receivers at EIG_RANGES (1.5 m) and a fine eigenray bracket (7,201 elevations: the
    default 721 misses the grazing multi-bounce arrivals, 16 of 24 at 800 m)."""
    spec = _spec(name, f)
    spec["name"] = f"eig-{name}"
    spec["receivers"] = [{"id": f"r{int(x)}", "position": [x, 0.0, ZR]} for x in EIG_RANGES]
    spec["eigenrays"] = {"enabled": "on", "elevations": 7201}
    job = Job.model_validate(spec)
    return run_job(job).receivers.rows


@pytest.mark.slow
def test_downward_beams_are_ray_theory():
    """Where the beams miss the GFPE downward, they still agree with exact ray theory: the coherent and
    incoherent sums over the eigenrays at the same receivers (Newton-refined, docs/physics.md §12), so the gap
    is ray theory's own (low-angle rays turning 2-20 m above the ground, inside the Airy transition length
    near a turning point, about 5 m at 100 Hz), not the beams' per-group bookkeeping. Measured (log, b = +1,
    100 Hz, 24 ranges 60-980 m): beams - eigenrays 0.24 dB mean (max 0.70) coherent, 0.14 dB incoherent
    (the six ranges here: 0.28 dB mean, max 0.70, coherent); eigenrays - GFPE 4.8 dB mean (ray theory 4.4 dB
    too loud on average, about 10 dB near 800 m). With both tubes in the smooth medium (2026-12-03, docs/physics.md
    §11), the six ranges: 0.16 dB mean, max 0.41, coherent; 0.10 dB mean incoherent (the 24 ranges not
    re-measured). About 3 minutes (7,201 bracket rays per receiver)."""
    rows = _beams_and_eigenrays("log_down", 100.0)
    coh = np.array([abs(r["tl_coh_100hz"] - r["tl_eig_coh_100hz"]) for r in rows])
    inc = np.array([abs(r["tl_inc_100hz"] - r["tl_eig_inc_100hz"]) for r in rows])
    assert all(r["eigenray_failures"] == 0 and r["eigenrays"] >= 2 for r in rows), rows
    assert rows[-1]["eigenrays"] >= 20, rows[-1]  # the multi-bounce arrivals at 940 m (30 measured)
    assert coh.mean() <= 0.5 and coh.max() <= 1.0, coh
    assert inc.mean() <= 0.3, inc

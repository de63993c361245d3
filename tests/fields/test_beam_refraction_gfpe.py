"""Beam fields in refracting atmospheres against the GFPE oracle (tests/reference/gfpe.py, checked by
itself against the image source in tests/reference/test_gfpe.py).

Downward and upward log profiles (c = 340 + b ln(z + 1), b = +-1), linear c (340 +- 0.1 z), over grass
(200 kPa s/m^2), source 2 m, receivers 1.5 m, 20 m - 1 km, coherent, with a vertical fan (one azimuth).
Compared: points the beams cover (beam_weight >= 0.5: outside the geometric shadow, where ray acoustics
has no level; diffraction into shadows is a later stage) and not in an interference dip of the oracle
(more than 6 dB below its running median over 50 m). Asserted: mean |difference| <= 1 dB at 100 and 500
Hz. Measured with 1,201 rays (mean |difference| over the compared points): upward log 0.66 dB at 100 Hz
(29 lit points, 20-76 m) and 4.3 dB at 500 Hz; upward linear 0.55 dB at 100 Hz and 7.8 dB at 500 Hz;
downward log 5.2 / 2.2 dB and downward linear 3.3 / 4.3 dB at 100 / 500 Hz. The cases that do not meet
1 dB are strict xfails: the target is not reached yet (open in issue 12: the per-group sums where several
branches of one reflection and caustic count overlap, beam_weight 5-25 at 200 m - 1 km downward).
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


@cache
def _beams(name: str, f: float):
    spec, _ = PROFILES[name]
    job = Job.model_validate(
        {
            "name": f"gfpe-{name}",
            "scene": {
                "domain": {"min": [-20, -20, 0], "max": [1020, 20, 300]},
                "ground": {"kind": "flat", "flow_resistivity": GRASS},
            },
            "profile": spec,
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
            },
            "outputs": ["field", "report"],
        }
    )
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

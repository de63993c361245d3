"""An incoherent noise map over terrain from beams: no holes where beams reach, no speckle.

The README's job (built-in ``ridge`` scene, 1976 standard atmosphere, 100 dB source 800 m upwind of the
crest) with its fan (361 x 121 rays over -20..40 degrees elevation and +-30 degrees azimuth), mapped 4 m
above the ground (``heights = "above_ground"``) on a 20 m grid inside the fan's azimuth sector. Checks:
every point a beam reached has a level; the map's point-to-point noise, |L - median of its 3 x 3
neighbourhood| over the fully covered interior, is below 0.5 dB on average (the voxel method's maps varied
by 3-6 dB point to point). Over the terrain-following tets, rays crossing slanted tet faces nearly
tangentially got large exact paraxial kicks from the per-cell gradient jumps, which flipped tubes (spurious
caustics: 1.7 dB point noise); beams now bound that kick on slanted faces (constants.BEAM_KICK_BOUND_NZ;
the exact derivatives stay for trace(paraxial=True) and on horizontal faces): 0.16 dB without wind. The
same map over flat ground (slab mesh) is smooth too: asserted below. With the ridge wind the map stays at
1.21 dB (3.8 dB p95, 663 interior points; strict xfail; measured by ``_point_noise(_noise_map(wind=True)...)``
below, 25 min on the loaded machine): normalising the beams per branch (gamma_hat-keyed
branch slots, docs/physics.md §11) made it 1.33 dB (3.9 dB p95), so the speckle is not the groups' bookkeeping,
and it is not the wind's paraxial state either: the exact derivatives of the chord-middle wind gradient grew
beam tubes to 1e6-1e9 m/rad near the ground; beams now drop them (paraxial.drop_gradient_terms, tubes
70-840 m/rad, docs/physics.md §10) and the map went from 1.23 to 1.21 dB only. Nor is it the job's reflection
cap (max_reflections 12: 1.29 dB, 3.9 dB p95) or the caustic floor (beam_min_width_m 5: 1.21 dB). Diagnosed (§11,
"Torn ray map"): the traced rays themselves are scrambled below the fan step near the ground with this wind, so
neighbouring rays bound no tube and the hat beams neither tile nor agree: reduced case (x -700..-100 m, y +-100 m,
500 Hz, azimuth +-10 deg at the default 0.5 deg step) 1.11 dB with wind, 0.27 dB without, 1.12 dB with the same
wind over flat ground, 1.22 dB when every group is divided by its weight sum; beam weights 0.38-2.8 with 3-13
contributions between points 5 m apart on the centre line. Open: the wind's per-cell model, not the beams.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import median_filter

from bentray.engine.run import run_job
from bentray.scenes.schema import Job

EXAMPLE = Path(__file__).resolve().parents[2] / "scenes" / "examples" / "ridge-wind-map.json"


def _noise_map(wind: bool, terrain: bool = True):
    spec = json.loads(EXAMPLE.read_text())
    if not wind:
        spec.pop("wind")
    if not terrain:
        spec["scene"] = {"domain": {"min": [-1500, -200, 0], "max": [1500, 200, 600]}, "ground": {"kind": "flat"}}
    spec["field"] = {
        "origin": [-700.0, -200.0, 4.0],
        "spacing": [20.0, 20.0, 1.0],
        "shape": [61, 21, 1],
        "frequencies_hz": [125, 250, 500, 1000],
        "mode": "incoherent",
        "heights": "above_ground",
        "receiver_height_m": 4.0,
    }
    spec["outputs"] = ["field", "report"]
    return run_job(Job.model_validate(spec))


@pytest.fixture(scope="module")
def noise_map():
    return _noise_map(wind=False, terrain=False)


def _point_noise(arrays) -> tuple[np.ndarray, np.ndarray]:
    level = arrays["spl_a"][:, :, 0]
    full = arrays["beam_weight"][:, :, 0] >= 0.5
    inner = full.copy()
    inner[[0, -1], :] = False
    inner[:, [0, -1]] = False
    # a point counts only when its whole 3 x 3 neighbourhood is fully covered
    inner &= median_filter(full.astype(float), size=3, mode="constant") >= 1.0
    noise = np.abs(level - median_filter(np.nan_to_num(level, nan=-1e9), size=3, mode="nearest"))[inner]
    return noise, inner


def test_no_holes_where_beams_reach(noise_map):
    arrays = noise_map.field.arrays
    reached = arrays["beam_hits"][:, :, 0] > 0
    level = arrays["spl_a"][:, :, 0]
    assert reached.mean() > 0.5
    assert np.all(np.isfinite(level[reached]))


def test_map_is_smooth_over_flat_ground(noise_map):
    noise, inner = _point_noise(noise_map.field.arrays)
    assert inner.sum() > 200
    assert float(noise.mean()) < 0.5, (float(noise.mean()), float(np.percentile(noise, 95)))


@pytest.mark.slow
def test_map_is_smooth_over_the_ridge():
    """The ridge without wind, terrain-following tets: measured 0.16 dB mean, 0.68 dB p95 (1.7 dB before
    beams bounded the paraxial kick of near-tangential crossings of slanted faces)."""
    noise, inner = _point_noise(_noise_map(wind=False).field.arrays)
    assert inner.sum() > 200
    assert float(noise.mean()) < 0.5, (float(noise.mean()), float(np.percentile(noise, 95)))


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="the ridge wind: 1.21 dB mean, 3.8 dB p95 (a torn ray map, not the beams: docs/physics.md §11)",
)
def test_map_is_smooth_with_the_ridge_wind():
    noise, inner = _point_noise(_noise_map(wind=True).field.arrays)
    assert inner.sum() > 200
    assert float(noise.mean()) < 0.5, (float(noise.mean()), float(np.percentile(noise, 95)))

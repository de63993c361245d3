"""Fields against the image-source solution (docs/physics.md §8).

Homogeneous air (c = 340 m/s), flat ground, source at 2 m, receiver lines at 1.5 m. The references
are independent closed forms: 1/R1^2 + |Q|^2/R2^2 (incoherent) and |exp(ikR1)/R1 + Q exp(ikR2)/R2|
(coherent), with Q the spherical-wave coefficient of acoustics.ground (itself checked against the exact
impedance-plane integral in tests/acoustics/test_ground.py).

Two receiver lines keep the fans small: "near" 10..100 m at 1 m spacing and "far" 100..500 m at 5 m
spacing; each fan is dense enough to put at least a few hundred rays through every 1 m^2 voxel
cross-section (asserted through ray_hits before comparing levels).
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from scipy.signal import find_peaks

from bentray.engine.acoustics.ground import ground_impedance, image_source_pressure, spherical_wave_coefficient
from bentray.engine.run import run_job
from bentray.scenes.schema import Job

C0 = 340.0
SOURCE = np.array([0.0, 0.0, 2.0])
RECEIVER_Z = 1.5
SOFT = 200_000.0  # Pa s/m^2, grass
LINES = {
    # name: elevation (min, max, count), azimuth (min, max, count), x0, nx, dx, max_time_s
    "near": ((-22.0, 0.6, 680), (-2.9, 2.9, 175), 10.0, 91, 1.0, 0.33),
    "far": ((-2.4, 0.4, 425), (-0.3, 0.3, 91), 100.0, 81, 5.0, 1.6),
}
FREQS = (125.0, 500.0, 1000.0, 2000.0)
MIN_HITS = 300
TOL_DB = 1.0


def _job(line: str, mode: str, sigma: float | None) -> Job:
    (el0, el1, n_el), (az0, az1, n_az), x0, nx, dx, t_max = LINES[line]
    return Job.model_validate(
        {
            "name": f"image-{line}-{mode}",
            "scene": {
                "domain": {"min": [-50, -50, 0], "max": [600, 50, 60]},
                "ground": {"kind": "flat", "flow_resistivity": sigma},
            },
            "profile": {"kind": "homogeneous", "c0": C0},
            "sources": [{"position": SOURCE.tolist()}],
            "rays": {
                "elevation_deg": {"min": el0, "max": el1, "count": n_el},
                "azimuth_deg": {"min": az0, "max": az1, "count": n_az},
                "max_time_s": t_max,
                "max_reflections": 2,
            },
            "field": {
                "origin": [x0, 0.0, RECEIVER_Z],
                "spacing": [dx, 1.0, 1.0],
                "shape": [nx, 1, 1],
                "frequencies_hz": list(FREQS),
                "absorption": False,
                "mode": mode,
                "method": "voxels",  # the voxel accumulator (beams: one batch per source)
            },
            "outputs": ["field", "report"],
        }
    )


@cache
def _run(line: str, mode: str, sigma: float | None):
    outcome = run_job(_job(line, mode, sigma))
    x0, nx, dx = LINES[line][2:5]
    x = x0 + dx * np.arange(nx)
    receivers = np.column_stack([x, np.zeros(nx), np.full(nx, RECEIVER_Z)])
    return outcome, receivers


def _geometry(receivers: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    d = receivers - SOURCE
    r1 = np.linalg.norm(d, axis=1)
    r2 = np.hypot(np.hypot(d[:, 0], d[:, 1]), SOURCE[2] + receivers[:, 2])
    return r1, r2, (SOURCE[2] + receivers[:, 2]) / r2


@pytest.mark.parametrize("sigma", [None, SOFT], ids=["rigid", "soft"])
@pytest.mark.parametrize("line", ["near", "far"])
def test_incoherent_level_matches_image_source(line: str, sigma: float | None) -> None:
    outcome, receivers = _run(line, "incoherent", sigma)
    arrays = outcome.field.arrays
    hits = arrays["ray_hits"].ravel()
    assert hits.min() >= MIN_HITS, f"under-sampled voxel: {hits.min()} ray passes"
    r1, r2, cos_th = _geometry(receivers)
    for f in FREQS:
        if sigma is None:
            q2 = 1.0
        else:
            q = spherical_wave_coefficient(ground_impedance(f, sigma), cos_th, 2 * np.pi * f / C0, r2)
            q2 = np.abs(q) ** 2
        tl_ref = -10.0 * np.log10(1.0 / r1**2 + q2 / r2**2)
        err = arrays[f"tl_{f:g}hz"].ravel() - tl_ref
        assert np.max(np.abs(err)) < TOL_DB, f"{f} Hz: worst {np.max(np.abs(err)):.2f} dB"


def _away_from_dips(p_ref: np.ndarray, r1: np.ndarray, r2: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Points where the two arrivals do not cancel by more than 6 dB (outside interference dips).

    Inside a dip the level is the small difference of two nearly equal arrivals, so a 2 % amplitude
    error of either (the voxel-averaged ray density) moves it by several dB: that is where the dip
    test below checks positions instead of levels.
    """
    return np.abs(p_ref) >= 0.5 * (1.0 / r1 + np.abs(q) / r2)


@pytest.mark.parametrize("sigma", [None, SOFT], ids=["rigid", "soft"])
@pytest.mark.parametrize("line", ["near", "far"])
def test_coherent_level_matches_image_source(line: str, sigma: float | None) -> None:
    outcome, receivers = _run(line, "coherent", sigma)
    arrays = outcome.field.arrays
    r1, r2, cos_th = _geometry(receivers)
    checked = 0
    for f in FREQS:
        p_ref = image_source_pressure(SOURCE, receivers, f, sigma, c=C0)
        q = (
            np.ones(len(r2))
            if sigma is None
            else spherical_wave_coefficient(ground_impedance(f, sigma), cos_th, 2 * np.pi * f / C0, r2)
        )
        ok = _away_from_dips(p_ref, r1, r2, q)  # over soft ground at long range: may be empty
        tl = arrays[f"tl_{f:g}hz"].ravel()
        err = tl[ok] + 20.0 * np.log10(np.abs(p_ref[ok]))
        assert np.all(np.abs(err) < TOL_DB), f"{f} Hz: worst {np.max(np.abs(err)):.2f} dB"
        p = arrays[f"p_re_{f:g}hz"].ravel() + 1j * arrays[f"p_im_{f:g}hz"].ravel()
        np.testing.assert_allclose(-20 * np.log10(np.abs(p)), tl, rtol=0, atol=1e-9)
        checked += int(ok.sum())
    assert checked > 50


def test_coherent_dips_where_image_source_puts_them() -> None:
    """Rigid ground, 1 and 2 kHz on the near line (1 m voxels): every interference minimum of the
    reference deeper than 6 dB is matched by one of the field within one voxel, and vice versa."""
    outcome, receivers = _run("near", "coherent", None)
    for f in (1000.0, 2000.0):
        ref = -np.abs(image_source_pressure(SOURCE, receivers, f, None, c=C0))
        field = outcome.field.arrays[f"tl_{f:g}hz"].ravel()
        ref_min = list(find_peaks(-20 * np.log10(-ref), prominence=6.0)[0])  # dips deeper than 6 dB
        field_min = list(find_peaks(field, prominence=6.0)[0])
        assert len(ref_min) >= 2, "the test geometry should produce interference dips"
        assert len(field_min) == len(ref_min), (f, ref_min, field_min)
        assert all(abs(a - b) <= 1 for a, b in zip(ref_min, field_min, strict=True)), (f, ref_min, field_min)

"""Issue 17: the mirage image test. A camera's rays go through the job's media mesh (engine/render).

- homogeneous medium over flat ground: the first ground row of every image column matches the straight-ray
  prediction (ray against the domain box, computed here), within 1 pixel row;
- inferior mirage V-IM (n^2 = mu0^2 + mu1^2 (1 - exp(-beta z))): a ray of the stratified medium keeps its
  horizontal slowness n cos(e) (the invariant of the closed-form parabolic segments, docs/physics.md §2: g is
  vertical in every slab, so p's horizontal part is constant, and |p| = n), so a ray leaving the camera at
  height h with elevation e reaches the ground only if n(h) cos(e) <= n(0); the others turn back up and see the
  sky. The predicted first ground row of every column (from the exact profile, not the mesh) must match the
  render within 1 row, and lie well below the homogeneous medium's (the displaced horizon image).
"""

from __future__ import annotations

import math

import numpy as np

from bentray.engine.render.camera import pixel_directions
from bentray.engine.render.image import render_job
from bentray.scenes.camera_models import Camera
from bentray.scenes.schema import Job

LO = np.array([0.0, -25.0, 0.0])
HI = np.array([400.0, 25.0, 50.0])
EYE = np.array([2.0, 0.0, 2.0])
MU0, MU1, BETA = 1.000233, 0.4584, 2.303  # the paper's V-IM (engine/profiles.py defaults)


def _job(profile: dict, pitch_deg: float, fov_deg: float = 20.0, w: int = 64, h: int = 48) -> Job:
    look = EYE + 100.0 * np.array([math.cos(math.radians(pitch_deg)), 0.0, math.sin(math.radians(pitch_deg))])
    return Job.model_validate(
        {
            "name": "horizon",
            "scene": {"domain": {"min": LO.tolist(), "max": HI.tolist()}},
            "profile": profile,
            "sources": [{"position": EYE.tolist()}],
            "rays": {"elevation_deg": {"min": 0, "max": 0, "count": 1}, "max_time_s": 5.0, "max_reflections": 0},
            "camera": {"position": EYE.tolist(), "look_at": look.tolist(), "fov_deg": fov_deg, "width": w, "height": h},
        }
    )


def _first_ground_row(mask: np.ndarray) -> np.ndarray:
    """(W,) index of the first True row of each column (H when none)."""
    h = mask.shape[0]
    return np.where(mask.any(axis=0), np.argmax(mask, axis=0), h)


def _straight_ground(camera: Camera) -> np.ndarray:
    """(H, W) True where the straight ray from the eye meets the ground z = LO z before any other domain face."""
    d = pixel_directions(camera)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_lo = np.where(d < 0, (LO - EYE) / d, np.inf)
        t_hi = np.where(d > 0, (HI - EYE) / d, np.inf)
    t_ground = t_lo[:, 2]
    t_other = np.minimum(np.minimum(t_lo[:, 0], t_lo[:, 1]), np.min(t_hi, axis=1))
    return (t_ground < t_other).reshape(camera.height, camera.width)


def _n(z: float) -> float:
    return math.sqrt(MU0 * MU0 + MU1 * MU1 * -math.expm1(-BETA * z))


def test_homogeneous_flat_ground_horizon_matches_the_straight_rays():
    job = _job({"kind": "homogeneous"}, pitch_deg=0.0)
    out = render_job(job)
    expected = _first_ground_row(_straight_ground(job.camera))
    got = _first_ground_row(out.hit)
    assert 10 < expected.min() and expected.max() < 38  # the horizon line is inside the image
    assert np.max(np.abs(got - expected)) <= 1, (got, expected)
    assert out.stats["lost"] == 0
    # below the line only ground, above it only sky (a clean line, no stray pixels)
    rows = np.arange(out.hit.shape[0])[:, None]
    assert np.array_equal(out.hit, rows >= got[None, :])


def test_inferior_mirage_displaces_the_horizon_as_snell_predicts():
    job = _job({"kind": "mirage_inferior"}, pitch_deg=-24.0)
    out = render_job(job)
    d = pixel_directions(job.camera)
    cos_e = np.hypot(d[:, 0], d[:, 1]).reshape(job.camera.height, job.camera.width)
    critical = _n(0.0) / _n(float(EYE[2]))
    expected = _first_ground_row(cos_e <= critical)
    got = _first_ground_row(out.hit)
    assert 8 < expected.min() and expected.max() < 40  # the critical angle (~24.5 deg down) is in the image
    assert np.max(np.abs(got - expected)) <= 1, (got, expected)
    # a straight-ray (homogeneous) medium would show ground in every pixel of this downward view
    homogeneous = _straight_ground(job.camera)
    assert homogeneous.all()
    assert (~out.hit).sum() > 0.25 * out.hit.size
    # the mirage shows the sky: rays above the line end going up, as mirror images (final elevation > 0)
    sky = ~out.hit
    assert np.all(out.direction[sky][:, 2] > 0.0)
    assert out.stats["lost"] == 0

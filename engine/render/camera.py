"""Pinhole-camera rays: one unit direction per pixel centre (plain numpy; world frame, metres)."""

from __future__ import annotations

import math

import numpy as np

from bentray.scenes.camera_models import Camera

__all__ = ["camera_basis", "pixel_directions"]


def camera_basis(camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(forward, right, up) unit vectors (3,) of the camera: forward toward look_at, right = forward x up,
    up = right x forward (the image's up, orthogonal to forward)."""
    pos = np.asarray(camera.position, float)
    forward = np.asarray(camera.look_at, float) - pos
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(camera.up, float))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return forward, right, up


def pixel_directions(camera: Camera) -> np.ndarray:
    """(height * width, 3) float64 unit directions through the pixel centres, row-major from the top-left
    pixel: pixel (i, j) (row i from the top, column j from the left) looks along
    ``forward + sx right + sy up`` with ``sx = (2 (j + 1/2) / W - 1) tan(fov/2) W / H`` and
    ``sy = (1 - 2 (i + 1/2) / H) tan(fov/2)`` (fov the vertical field of view)."""
    forward, right, up = camera_basis(camera)
    w, h = camera.width, camera.height
    tan_half = math.tan(math.radians(camera.fov_deg) / 2.0)
    sx = (2.0 * (np.arange(w) + 0.5) / w - 1.0) * tan_half * (w / h)
    sy = (1.0 - 2.0 * (np.arange(h) + 0.5) / h) * tan_half
    d = forward[None, None, :] + sx[None, :, None] * right[None, None, :] + sy[:, None, None] * up[None, None, :]
    d = d.reshape(-1, 3)
    return d / np.linalg.norm(d, axis=1)[:, None]

"""The ``camera`` of a job: a pinhole camera for ``bentray render`` (one ray per pixel through the media mesh).

Frames and units: world frame, metres, degrees; z up. The image has ``height`` rows (row 0 at the top) and
``width`` columns (column 0 at the left); pixel centres are shot. Bounded so that no input can exhaust a
worker: at most :data:`MAX_PIXELS` rays (the rays are traced in batches of at most
:data:`bentray.engine.render.image.RENDER_BATCH_RAYS`, so memory stays bounded too).
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic_core import PydanticCustomError

from bentray.scenes.bounds import Vec3

__all__ = ["MAX_IMAGE_SIDE", "MAX_PIXELS", "Camera", "Sun"]

MAX_IMAGE_SIDE = 4096  # pixels along one side
MAX_PIXELS = 1_048_576  # 1024 x 1024 rays per image (the paper's Fig. 11 shoots 512 x 512)


class Sun(BaseModel):
    """Sun direction for the shading: elevation above the horizon and azimuth counter-clockwise from +x (deg)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    elevation_deg: float = Field(default=35.0, ge=0.0, le=90.0)
    azimuth_deg: float = Field(default=135.0, ge=-360.0, le=360.0)

    def direction(self) -> tuple[float, float, float]:
        """Unit vector toward the sun, world frame."""
        el, az = math.radians(self.elevation_deg), math.radians(self.azimuth_deg)
        return (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))


class Camera(BaseModel):
    """Pinhole camera: ``position`` looking at ``look_at``, ``up`` the world direction that is up in the image,
    ``fov_deg`` the vertical field of view, ``width`` x ``height`` pixels (one ray each)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    position: Vec3
    look_at: Vec3
    up: Vec3 = (0.0, 0.0, 1.0)
    fov_deg: float = Field(default=40.0, ge=0.01, le=170.0)
    width: int = Field(default=320, ge=1, le=MAX_IMAGE_SIDE)
    height: int = Field(default=240, ge=1, le=MAX_IMAGE_SIDE)
    sun: Sun = Field(default_factory=Sun)

    @model_validator(mode="after")
    def _check_camera(self) -> Camera:
        if self.width * self.height > MAX_PIXELS:
            n = self.width * self.height
            raise PydanticCustomError(
                "value_error", f"width x height = {n:,} pixels is over the limit of {MAX_PIXELS:,} (one ray per pixel)"
            )
        view = [b - a for a, b in zip(self.position, self.look_at, strict=True)]
        vn = math.sqrt(sum(v * v for v in view))
        if not vn > 1e-9:
            raise PydanticCustomError("value_error", "look_at must differ from position")
        un = math.sqrt(sum(u * u for u in self.up))
        if not un > 0.0:
            raise PydanticCustomError("value_error", "up must not be the zero vector")
        cos = abs(sum(v * u for v, u in zip(view, self.up, strict=True))) / (vn * un)
        if cos > 1.0 - 1e-9:
            raise PydanticCustomError("value_error", "up must not be parallel to the view direction")
        return self

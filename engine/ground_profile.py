"""Profiles measured from the ground: c(x, y, z) = base(x, y, z - h(x, y)).

Atmospheric profiles are laws of the height above the ground (the log law of a night-time inversion,
the surface layer of a daytime lapse), so over terrain the job's profile follows the terrain by
default (``scene.profile_heights = "above_ground"``); ``"absolute"`` keeps the paper's c(z) in world z.
Heights below the ground (points inside buildings, never traced) are clamped to the ground value.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from bentray.engine.profiles import Profile

GroundHeight = Callable[[np.ndarray], np.ndarray]  # xy (N, 2) metres -> ground z (N,) metres
_COLUMN_MIN = 16  # points from which a vertical column's ground height is looked up once


class AboveGround(Profile):
    """``base`` evaluated at the height above the ground ``z - h(x, y)`` (metres, clamped at 0).

    ground_height : xy (N, 2) -> (N,) ground z; flat : True when h is a constant (the profile then stays
    stratified and slabs still represent it). Gradients: central differences of the shifted values
    (the base class), which carry the terrain slope's contribution.
    """

    def __init__(self, base: Profile, ground_height: GroundHeight, *, flat: bool) -> None:
        super().__init__(c_ref=base.c_ref, stratified=base.stratified and flat)
        self.base_profile = base
        self.ground_height = ground_height
        self.kind = base.kind  # type: ignore[misc]  # reports and representation choice see the base kind
        self._native = base._native  # type: ignore[misc]

    def heights(self, p: np.ndarray) -> np.ndarray:
        """Points with z replaced by the height above the ground (clamped at 0).

        A vertical column (every point at the same x and y, as the limiting rays and wavenumber integrals of
        the shadow stages ask for: thousands of heights at a time) looks its ground height up once; the
        lookup is per point, so the heights are the same bit for bit."""
        q = np.array(p, dtype=np.float64, copy=True)
        xy = q[:, :2]
        column = len(q) > _COLUMN_MIN and xy[-1, 0] == xy[0, 0] and xy[-1, 1] == xy[0, 1]  # cheap test first
        if column and bool(np.all(xy == xy[0])):
            ground = np.broadcast_to(self.ground_height(xy[:1]), (len(q),))
        else:
            ground = self.ground_height(xy)
        q[:, 2] = np.maximum(q[:, 2] - ground, 0.0)
        return q

    def _m(self, p: np.ndarray) -> np.ndarray:
        return self.base_profile._m(self.heights(p))

    @property
    def base(self) -> Profile:
        """The stratified part (a fluctuating profile's base), also measured from the ground."""
        inner = getattr(self.base_profile, "base", None)
        if inner is None:
            return self
        return AboveGround(inner, self.ground_height, flat=self.stratified)

    def describe(self) -> dict[str, Any]:
        return {**self.base_profile.describe(), "heights": "above the ground", "stratified": self.stratified}

"""The ``receivers`` key of a job: named points where levels are computed (receivers.csv).

Each receiver has an ``id`` and either an absolute ``position`` [x, y, z] (metres, world frame) or a
horizontal position ``xy`` [x, y] with ``height_above_ground_m`` (resolved against the terrain, or the flat
ground at the domain bottom, when the job runs). Levels come from the beam field (docs/physics.md §11):
per band, coherent and incoherent, transmission loss and SPL, A-weighted totals.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

MAX_RECEIVERS = 100_000
# |coordinate| bound: finite, and far beyond any local domain (projected CRS inputs are localised first)
COORD_BOUND = 1e7


class Receiver(BaseModel):
    """One receiver point (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    id: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.:\-]+$")
    position: tuple[float, float, float] | None = None
    xy: tuple[float, float] | None = None
    height_above_ground_m: float | None = Field(default=None, ge=0.0, le=10_000.0)

    @model_validator(mode="after")
    def _one_placement(self) -> Receiver:
        if self.position is not None:
            if self.xy is not None or self.height_above_ground_m is not None:
                raise ValueError("give either position or xy with height_above_ground_m, not both")
            coords = self.position
        else:
            if self.xy is None or self.height_above_ground_m is None:
                raise ValueError("give position [x, y, z], or xy [x, y] with height_above_ground_m")
            coords = (*self.xy, 0.0)
        if any(abs(c) > COORD_BOUND for c in coords):
            raise ValueError(f"coordinates must lie within +-{COORD_BOUND:g} m")
        return self

    @property
    def horizontal(self) -> tuple[float, float]:
        if self.position is not None:
            return (self.position[0], self.position[1])
        assert self.xy is not None
        return self.xy


# at most this many (source, receiver) pairs get an eigenray search when ``eigenrays.enabled`` is "auto";
# "on" allows up to MAX_EIGENRAY_PAIRS (each pair traces a bracket fan of ``elevations`` rays and a few
# hundred single-ray probes)
AUTO_EIGENRAY_PAIRS = 200
MAX_EIGENRAY_PAIRS = 5_000


class EigenraySpec(BaseModel):
    """The ``eigenrays`` key: eigenray search at the receivers (arrivals.csv; docs/physics.md §12).

    enabled : "auto" (search when the job lists receivers and sources x receivers <= AUTO_EIGENRAY_PAIRS),
    "on" (always, up to MAX_EIGENRAY_PAIRS pairs) or "off". elevations : rays of the vertical bracket fan
    (elevation step 180 / elevations deg). tolerance_m : convergence, the largest distance at which the
    eigenray passes the receiver. max_iterations : Newton iterations per bracket.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    enabled: Literal["auto", "on", "off"] = "auto"
    elevations: int = Field(default=721, ge=31, le=20_001)
    tolerance_m: float = Field(default=1e-8, ge=1e-12, le=1.0)
    max_iterations: int = Field(default=40, ge=1, le=200)
